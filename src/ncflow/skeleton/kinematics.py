"""Forward kinematics with unit dual quaternions and pose interpolation (paper §4.3, Eqs. 18–20).

Convention
----------
A pose is one rotation per joint, r_j (unit quaternion, identity at rest), and one global
translation s̃ of the root (the paper's s̃). The rotation of joint j rotates everything distal to
j about j; rotations of leaf joints move no bone.

* Local DQ of joint j: L_j = DQ(r_j, o_j) with o_j = P_j − P_parent(j) (rest offset); for the
  root L_0 = DQ(r_0, P_0 + s̃): the whole skeleton turns about P_0, then moves by s̃.
* World DQ (frame of joint j): G_j = G_parent(j) L_j. At rest G_j is the translation by P_j;
  posed, joint j sits at G_j(0).
* Bone b = (a → c) is rigidly attached to the frame of its parent joint a, so it moves by
  T_b(t) T_b(0)⁻¹ with T_b(t) = G_a(t) — the full rigid motion, twist about the bone included.

Interpolation at time t ∈ [0, 1]:

* ``"sclerp"`` (default, the paper): L_j(t) = ScLERP(t; L_j^rest, L_j^posed) for every joint,
  composed down the tree. For a non-root joint this is DQ(slerp(1 → r_j; t), o_j); the root
  follows the screw motion from DQ(1, P_0) to DQ(r_0, P_0 + s̃). Bone lengths are preserved
  at every t.
* ``"slerp"`` (ARC-Flow-style baseline): the world frames are interpolated separately,
  rotation by SLERP from the rest to the posed world rotation and position (joint location)
  linearly. Same end points; bone lengths are not preserved in between.

Both take the shorter way: a rotation quaternion with w < 0 is interpolated as −r (the same
rotation), which equals pinning w ≥ 0 as the authors' release does; every joint turns by at
most π over t ∈ [0, 1].

All functions take the (static) :class:`~ncflow.skeleton.Skeleton` plus JAX arrays, follow the
dtype of the pose, and are jit/vmap/grad-friendly (vmap over t or over poses).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ncflow.geometry.skeleton import Skeleton
from ncflow.skeleton.dualquat import (
    dq_from_rt,
    dq_inverse,
    dq_mul,
    dq_rotation,
    dq_transform_point,
    dq_translation,
    lerp,
    quat_normalize,
    sclerp,
    slerp,
)

INTERPOLATIONS = ("sclerp", "slerp")


class Pose(NamedTuple):
    """Pose parameters (a pytree).

    Attributes:
        rotations: (J, 4) one quaternion per joint in the skeleton's internal order (normalised
            on use, so raw parameters are fine; the zero vector counts as the identity).
        translation: (3,) global root translation s̃.
    """

    rotations: Float[Array, "J 4"]
    translation: Float[Array, " 3"]


def rest_pose(skeleton: Skeleton, dtype=None) -> Pose:
    """The identity pose: all rotations (1, 0, 0, 0), no translation."""
    dtype = np.dtype(dtype or jnp.result_type(float))
    rot = np.zeros((skeleton.n_joints, 4), dtype)
    rot[:, 0] = 1.0
    return jax.device_put(Pose(rot, np.zeros(3, dtype)))


def _offsets(skeleton: Skeleton, dtype) -> Array:
    return jnp.asarray(skeleton.offsets, dtype)


def local_dqs(skeleton: Skeleton, pose: Pose) -> Float[Array, "J 8"]:
    """Local DQs L_j = DQ(r_j, o_j) (root: DQ(r_0, P_0 + s̃)) of a pose."""
    rot = quat_normalize(pose.rotations)
    off = _offsets(skeleton, rot.dtype)
    off = off.at[0].add(jnp.asarray(pose.translation, rot.dtype))
    return dq_from_rt(rot, off)


def _rest_local_dqs(skeleton: Skeleton, dtype) -> Array:
    off = _offsets(skeleton, dtype)
    return dq_from_rt(jnp.zeros((skeleton.n_joints, 4), dtype).at[:, 0].set(1.0), off)


def compose_tree(skeleton: Skeleton, local: Float[Array, "J 8"]) -> Float[Array, "J 8"]:
    """World DQs G_j = G_parent(j) L_j, computed level by level (one batched product per depth)."""
    world = local
    parents = skeleton.parents
    for level in skeleton.levels[1:]:
        world = world.at[level].set(dq_mul(world[parents[level]], local[level]))
    return world


def forward_kinematics(skeleton: Skeleton, pose: Pose) -> Float[Array, "J 8"]:
    """World DQs of all joint frames in a pose (the rest pose gives translations by P_j)."""
    return compose_tree(skeleton, local_dqs(skeleton, pose))


def joint_positions(world: Float[Array, "... J 8"]) -> Float[Array, "... J 3"]:
    """Joint locations G_j(0) of world DQs."""
    return dq_translation(world)


def _check_interp(interp: str) -> None:
    if interp not in INTERPOLATIONS:
        raise ValueError(f"interp must be one of {INTERPOLATIONS}, got {interp!r}")


def interpolate_world(
    skeleton: Skeleton, pose: Pose, t: Float[ArrayLike, ""], interp: str = "sclerp"
) -> Float[Array, "J 8"]:
    """World DQs of the joint frames at time t ∈ [0, 1] between rest (t = 0) and ``pose`` (t = 1).

    ``interp="sclerp"``: ScLERP of every local DQ, composed by FK (paper Eq. 19–20).
    ``interp="slerp"``: world rotations by SLERP, world joint positions linearly (baseline).
    """
    _check_interp(interp)
    posed_local = local_dqs(skeleton, pose)
    dtype = posed_local.dtype
    t = jnp.asarray(t, dtype)
    rest_local = _rest_local_dqs(skeleton, dtype)
    if interp == "sclerp":
        return compose_tree(skeleton, sclerp(t, rest_local, posed_local))
    rest_world = compose_tree(skeleton, rest_local)
    posed_world = compose_tree(skeleton, posed_local)
    rot = slerp(t, dq_rotation(rest_world), dq_rotation(posed_world))
    pos = lerp(t, dq_translation(rest_world), dq_translation(posed_world))
    return dq_from_rt(rot, pos)


def interpolate_joints(
    skeleton: Skeleton, pose: Pose, t: Float[ArrayLike, ""], interp: str = "sclerp"
) -> Float[Array, "J 3"]:
    """Joint positions at time t (see :func:`interpolate_world`)."""
    return joint_positions(interpolate_world(skeleton, pose, t, interp))


def bone_frames(world: Float[Array, "... J 8"], skeleton: Skeleton) -> Float[Array, "... B 8"]:
    """T_b = G_parent(b): the frame each bone is attached to (bone b ends at joint b + 1)."""
    return world[..., skeleton.parents[1:], :]


def bone_motions(
    skeleton: Skeleton, pose: Pose, t: Float[ArrayLike, ""], interp: str = "sclerp"
) -> Float[Array, "B 8"]:
    """Rigid motion of every bone from rest to time t, M_b(t) = T_b(t) T_b(0)⁻¹ (identity at t = 0).

    Rotation (including twist about the bone) and translation; a rest point p of bone b is at
    M_b(t) p at time t (:func:`move_bone_points`).
    """
    world_t = interpolate_world(skeleton, pose, t, interp)
    dtype = world_t.dtype
    rest = compose_tree(skeleton, _rest_local_dqs(skeleton, dtype))
    return dq_mul(bone_frames(world_t, skeleton), dq_inverse(bone_frames(rest, skeleton)))


def move_bone_points(motions: Float[Array, "... B 8"], points: Float[Array, "B n 3"]) -> Float[Array, "... B n 3"]:
    """Apply each bone's motion M_b to its rest points: (B, 8) × (B, n, 3) → (B, n, 3)."""
    return dq_transform_point(motions[..., :, None, :], points)


def rigid_reference(
    skeleton: Skeleton,
    pose: Pose,
    points: Float[Array, "B n 3"],
    times: Float[ArrayLike, " T"],
    interp: str = "sclerp",
) -> Float[Array, "T B n 3"]:
    """Rigid reference positions of bone samples at several times (the p_k(t) of paper Eq. 20)."""
    motions = jax.vmap(lambda t: bone_motions(skeleton, pose, t, interp))(jnp.asarray(times))
    return move_bone_points(motions, jnp.asarray(points, motions.dtype))
