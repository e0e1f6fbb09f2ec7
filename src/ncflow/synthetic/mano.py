"""Pairs from a MANO hand model that the user supplies: posing MANO and its skeleton.

:func:`mano_forward` poses the model as MANO defines it (identity blend shapes, pose blend
shapes, forward kinematics down the kinematic tree, linear blend skinning);
:func:`mano_finger_pose` reads a pose as a row of the model's captured poses, as PCA coefficients,
as axis-angle values or by name: ``"flat"`` (the template) or ``"fist"`` (:func:`mano_fist_pose`:
every finger joint flexed 70–90° about a flexion axis derived from the rest joints, the thumb
45–65° across the palm). :func:`mano_pair` makes a source/target pair with exact ground truth
(:mod:`ncflow.synthetic.pairs`): the same vertices (identity), or a retriangulated target mapped
through its barycentric coordinates on the rest surface. The skeleton is the 16 MANO joints plus
one tip bone per finger ending at a tip vertex. The model file is read by :mod:`ncflow.io.mano`
and never shipped.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np
from jaxtyping import Float

from ncflow.errors import InputError
from ncflow.geometry.mesh import Mesh
from ncflow.geometry.rigid import (
    forward_kinematics,
    joint_local_transforms,
    linear_blend_skinning,
    rotvec_to_matrix,
    skinning_matrices,
)
from ncflow.io.mano import MANO_JOINT_NAMES, ManoModel, load_mano
from ncflow.skeleton import Skeleton
from ncflow.synthetic.motion import move_target
from ncflow.synthetic.pairs import Pair, assemble_pair, identity_ground_truth, retriangulated_target

#: finger-tip vertices of the MANO right hand: index, middle, little, ring, thumb
MANO_TIP_VERTICES = (320, 443, 672, 555, 744)


_TIP_NAMES = ("index_tip", "middle_tip", "little_tip", "ring_tip", "thumb_tip")


#: named finger poses understood by :func:`mano_finger_pose` (and ``ncflow make-pairs --poses``)
MANO_NAMED_POSES = ("flat", "fist")

#: fist flexion (degrees) of each finger's three joints (MCP, PIP, DIP) and of the thumb's (CMC, MCP, IP)
FIST_FINGER_DEG = (80.0, 90.0, 70.0)
FIST_THUMB_DEG = (45.0, 45.0, 65.0)
#: the thumb curls towards the palm normal turned this many degrees towards the little finger
FIST_THUMB_ACROSS_DEG = 60.0


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def mano_flexion_axes(model: ManoModel) -> Float[np.ndarray, "15 3"]:
    """Flexion axes of MANO's 15 finger joints (rest frame, unit; a positive rotation closes the hand).

    From the rest joints J = J_regressor · v_template (MANO's joint order: wrist; index, middle,
    little, ring, thumb, three joints each, proximal first): the palm normal n is the normalised
    (index MCP − wrist) × (little MCP − wrist), turned to the side the fingers close to (the side
    ``hands_mean``, a slightly closed hand, flexes them towards, when the model has it). A joint's
    bone direction d is towards the next joint of its finger (the last joint keeps its incoming
    bone's direction) and its axis is d × b / |d × b| with b the bend direction: n for the four
    fingers, n turned :data:`FIST_THUMB_ACROSS_DEG` towards the little finger (across the palm) for
    the thumb — the rule of the procedural hand's hinges (:mod:`ncflow.synthetic.bodies`).

    Raises:
        InputError: a model without 16 joints in MANO's order.
    """
    if model.n_joints != 16 or not np.array_equal(model.parents, [-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14]):
        raise InputError("flexion axes need MANO's 16-joint hand (wrist + 5 fingers of 3 joints)", model.name)
    joints = model.J_regressor @ model.v_template
    n = _unit(np.cross(joints[1] - joints[0], joints[7] - joints[0]))
    across = joints[7] - joints[1]
    across = _unit(across - (across @ n) * n)
    axes = np.zeros((15, 3))

    def fill(normal):
        for j in range(1, 16):
            d = joints[j + 1] - joints[j] if j % 3 else joints[j] - joints[j - 1]
            if j >= 13:
                t = np.radians(FIST_THUMB_ACROSS_DEG)
                bend = np.cos(t) * normal + np.sin(t) * across
            else:
                bend = normal
            axes[j - 1] = _unit(np.cross(_unit(d), bend))

    fill(n)
    if model.hands_mean is not None and float(np.sum(axes[:12] * model.hands_mean.reshape(15, 3)[:12])) < 0.0:
        n = -n
        fill(n)
    return axes


def mano_fist_pose(
    model: ManoModel,
    finger_deg: Sequence[float] = FIST_FINGER_DEG,
    thumb_deg: Sequence[float] = FIST_THUMB_DEG,
) -> Float[np.ndarray, " 45"]:
    """The axis-angle finger pose of a fist: every finger joint flexed about its axis (:func:`mano_flexion_axes`).

    Args:
        model: the MANO model (16 joints).
        finger_deg: flexion of each finger's MCP, PIP and DIP joints (default 80°, 90°, 70°).
        thumb_deg: flexion of the thumb's CMC, MCP and IP joints (default 45°, 45°, 65°).

    Returns:
        (45,) axis-angle values: with MANO's right hand the fingertips end at 17–29 % (thumb 52 %) of
        their flat-hand distance to the centroid of the vertices skinned mostly to the wrist.
    """
    angles = np.radians(np.concatenate([np.tile(np.asarray(finger_deg, float).reshape(3), 4), thumb_deg]))
    return (mano_flexion_axes(model) * angles[:, None]).reshape(-1)


def mano_finger_pose(
    model: ManoModel,
    pose: int | str | Sequence[float] | np.ndarray,
    *,
    space: str = "pca",
    flat_hand_mean: bool = False,
) -> Float[np.ndarray, " P"]:
    """The 15 × 3 axis-angle finger pose (flattened) of a pose argument.

    Args:
        model: the MANO model.
        pose: an int selects row ``pose`` of ``hands_coeffs``; a name of :data:`MANO_NAMED_POSES`:
            ``"flat"`` (every finger joint at rest: the template's flat hand, whatever
            ``flat_hand_mean``), ``"fist"`` (:func:`mano_fist_pose`); an array is PCA coefficients
            (``space="pca"``; n ≤ 45 of them, using the first n components) or the 45 axis-angle
            values themselves (``space="axis_angle"``).
        space: ``"pca"`` or ``"axis_angle"``.
        flat_hand_mean: do not add ``hands_mean`` (PCA space only).

    Returns:
        θ = hands_mean + coeffs @ hands_components[:n] (PCA), or the given axis-angle values, or
        the named pose.
    """
    if space not in ("pca", "axis_angle"):
        raise InputError(f"pose space must be 'pca' or 'axis_angle', got {space!r}")
    n_f = 3 * (model.n_joints - 1)
    if isinstance(pose, str):
        if pose == "flat":
            return np.zeros(n_f)
        if pose == "fist":
            return mano_fist_pose(model)
        raise InputError(f"unknown MANO pose name {pose!r}; use an index, coefficients or one of {MANO_NAMED_POSES}")
    if isinstance(pose, (int, np.integer)) and not isinstance(pose, bool):
        if model.hands_coeffs is None:
            raise InputError(
                "the MANO model has no hands_coeffs: give pose coefficients instead of an index", model.name
            )
        if not 0 <= int(pose) < model.hands_coeffs.shape[0]:
            raise InputError(f"pose index {int(pose)} out of range [0, {model.hands_coeffs.shape[0] - 1}]", model.name)
        coeffs = model.hands_coeffs[int(pose)]
        space = "pca"
    else:
        coeffs = np.asarray(pose, dtype=np.float64).reshape(-1)
        if not np.all(np.isfinite(coeffs)):
            raise InputError("pose values must be finite")
    if space == "axis_angle":
        if coeffs.size != n_f:
            raise InputError(f"an axis-angle finger pose needs {n_f} values, got {coeffs.size}")
        return coeffs.copy()
    if model.hands_components is None:
        raise InputError(
            "the MANO model has no hands_components: give an axis-angle pose (space='axis_angle')", model.name
        )
    n = coeffs.size
    if n > model.hands_components.shape[0]:
        raise InputError(f"at most {model.hands_components.shape[0]} PCA coefficients, got {n}")
    theta = coeffs @ model.hands_components[:n]
    if not flat_hand_mean and model.hands_mean is not None:
        theta = theta + model.hands_mean
    return theta


def mano_forward(
    model: ManoModel,
    finger_pose: Float[np.ndarray, " P"],
    global_rotation: Float[np.ndarray, " 3"] | Sequence[float] | None = None,
    betas: Float[np.ndarray, " S"] | Sequence[float] | None = None,
    translation: Float[np.ndarray, " 3"] | Sequence[float] | None = None,
) -> tuple[Float[np.ndarray, "V 3"], Float[np.ndarray, "J 3"]]:
    """Pose MANO: pose blend shapes, forward kinematics down the kinematic tree, linear blend skinning.

    v_shaped = v_template + shapedirs · betas; J = J_regressor v_shaped; R_j = Rodrigues(θ_j) with
    θ_0 the global rotation; v_posed = v_shaped + posedirs · vec(R_1..J−1 − I); G_0 = [R_0 | J_0],
    G_j = G_parent [R_j | J_j − J_parent]; vertex = Σ_j w_j G_j [I | −J_j] v_posed (+ translation).
    The rigid maths are :mod:`ncflow.geometry.rigid`'s (Rodrigues through scipy, one forward
    kinematics, one linear blend skinning).

    Args:
        model: the MANO model.
        finger_pose: (P,) axis-angle finger pose, P = 3 (J − 1) (45 for MANO's 16 joints).
        global_rotation: (3,) axis-angle rotation of the wrist (default none).
        betas: (S,) identity shape coefficients, the first S of the model's (default: the template).
        translation: (3,) added to every vertex and joint (default none).

    Returns:
        (posed vertices (V, 3), posed joint positions (J, 3)).
    """
    nj = model.n_joints
    v = model.v_template
    if betas is not None:
        if model.shapedirs is None:
            raise InputError("the MANO model has no shapedirs: betas cannot be used", model.name)
        b = np.asarray(betas, dtype=np.float64).reshape(-1)
        v = v + model.shapedirs[:, :, : b.size] @ b
    joints = model.J_regressor @ v
    fp = np.asarray(finger_pose, dtype=np.float64).reshape(-1)
    if fp.size != 3 * (nj - 1):
        raise InputError(f"finger pose needs {3 * (nj - 1)} axis-angle values, got {fp.size}")
    g = np.zeros(3) if global_rotation is None else np.asarray(global_rotation, dtype=np.float64).reshape(3)
    rot = rotvec_to_matrix(np.concatenate([g, fp]).reshape(nj, 3))
    pose_map = (rot[1:] - np.eye(3)).reshape(-1)
    v_posed = v + model.posedirs @ pose_map
    world = forward_kinematics(joint_local_transforms(joints, model.parents, rot), model.parents)
    verts = linear_blend_skinning(v_posed, model.weights, skinning_matrices(world, joints))
    world_t = world[:, :3, 3].copy()
    if translation is not None:
        t = np.asarray(translation, dtype=np.float64).reshape(3)
        verts, world_t = verts + t, world_t + t
    return verts, world_t


def mano_skeleton(model: ManoModel, joints: np.ndarray, verts: np.ndarray, tips: Sequence[int], name: str) -> Skeleton:
    """MANO's 16 ``joints`` and one tip bone per finger ending at the vertex ``tips`` of ``verts``."""
    nj = model.n_joints
    tips = [int(t) for t in tips]
    if any(not 0 <= t < verts.shape[0] for t in tips):
        raise InputError(f"tip vertices must be in [0, {verts.shape[0] - 1}], got {tips}")
    names = list(MANO_JOINT_NAMES) if nj == 16 else [f"joint{j}" for j in range(nj)]
    if len(tips) == 5 and nj == 16:
        tip_parents = [3, 6, 9, 12, 15]
        names += list(_TIP_NAMES)
    else:  # one tip per leaf joint, in joint order
        leaves = [j for j in range(nj) if j not in set(model.parents.tolist())]
        if len(tips) != len(leaves):
            raise InputError(f"need one tip vertex per finger ({len(leaves)}), got {len(tips)}")
        tip_parents = leaves
        names += [f"tip{k}" for k in range(len(tips))]
    positions = np.concatenate([joints, verts[tips]])
    parents = np.concatenate([model.parents, np.asarray(tip_parents, dtype=np.int64)])
    return Skeleton.from_arrays(positions, parents, names, name=name)


def mano_pair(
    model_path: str | os.PathLike | ManoModel,
    pose_a: int | str | Sequence[float] | np.ndarray,
    pose_b: int | str | Sequence[float] | np.ndarray,
    *,
    global_rotation_a: Sequence[float] | None = None,
    global_rotation_b: Sequence[float] | None = None,
    betas: Sequence[float] | None = None,
    pose_space: str = "pca",
    flat_hand_mean: bool = False,
    tip_vertices: Sequence[int] = MANO_TIP_VERTICES,
    skeleton_joints: str = "fk",
    retriangulate: bool = False,
    target_resolution: float | None = None,
    seed: int = 0,
    name: str | None = None,
    target_rotation: float | tuple[float, float] | None = None,
    target_translation: float | tuple[float, float] | None = None,
) -> Pair:
    """A MANO hand in two poses (source = pose A, target = pose B) with exact ground truth.

    Args:
        model_path: the user's MANO model (``.npz`` or ``.pkl``, see :func:`load_mano`) or a loaded model.
        pose_a: the source pose: an index into ``hands_coeffs``, ``"flat"``, ``"fist"`` or explicit
            coefficients (see :func:`mano_finger_pose`).
        pose_b: the target pose, likewise (``pose_a="flat", pose_b="fist"``: a flat hand closing
            into a fist).
        global_rotation_a: axis-angle rotation of the source's wrist (default none).
        global_rotation_b: axis-angle rotation of the target's wrist (default none).
        betas: identity shape coefficients (default: the template).
        pose_space: how explicit poses are read: ``"pca"`` or ``"axis_angle"`` (:func:`mano_finger_pose`).
        flat_hand_mean: PCA poses without ``hands_mean`` (:func:`mano_finger_pose`).
        tip_vertices: one vertex per finger for the tip bones (index, middle, little, ring, thumb).
        skeleton_joints: ``"fk"`` (default): the 16 joints moved by forward kinematics, i.e. the
            centres the generating rigid transforms turn about; ``"regressor"``: J_regressor
            applied to the posed vertices (the convention of registered MANO datasets; in bent
            poses it is off the kinematic joints by a few millimetres). Target joints follow the
            same convention.
        retriangulate: give the target its own triangulation (:func:`retriangulate_mesh` of the
            rest surface — flat hand, no finger pose — at ``target_resolution`` cells along its
            largest extent, default 36, about 1.9k vertices for MANO's right hand; mapped to the
            posed target by its barycentric coordinates); default: same vertices, identity
            ground truth.
        target_resolution: cells of the retriangulation grid along the largest extent (default 36).
        seed: seed of the retriangulation grid offset and of the target motion.
        name: pair name (default ``mano_A_B``).
        target_rotation: turn the target (vertices and joints) by this many degrees (a number:
            exactly; a pair: uniform in the range) about a random axis through its vertex mean
            (:func:`ncflow.synthetic.pairs.move_target`; ``info["target_motion"]`` records it).
        target_translation: then move it by this fraction of the source's bounding-box diagonal.

    The skeleton is the 16 posed MANO joints (see ``skeleton_joints``; in the rest pose both
    conventions are J_regressor · vertices) plus one tip bone per finger ending at the tip
    vertex, in pose A.
    """
    if skeleton_joints not in ("fk", "regressor"):
        raise InputError(f"skeleton_joints must be 'fk' or 'regressor', got {skeleton_joints!r}")
    model = model_path if isinstance(model_path, ManoModel) else load_mano(model_path)
    fa = mano_finger_pose(model, pose_a, space=pose_space, flat_hand_mean=flat_hand_mean)
    fb = mano_finger_pose(model, pose_b, space=pose_space, flat_hand_mean=flat_hand_mean)
    va, ja = mano_forward(model, fa, global_rotation_a, betas)
    vb, jb = mano_forward(model, fb, global_rotation_b, betas)
    if skeleton_joints == "regressor":
        ja, jb = model.J_regressor @ va, model.J_regressor @ vb
    label = lambda p: str(int(p)) if isinstance(p, (int, np.integer)) else p if isinstance(p, str) else "custom"  # noqa: E731
    name = name or f"mano_{label(pose_a)}_{label(pose_b)}"
    source = Mesh(vertices=va, faces=model.faces, name=f"{name}/source", file_index=np.arange(va.shape[0]))
    skeleton = mano_skeleton(model, ja, va, tip_vertices, name)
    target_joints = np.concatenate([jb, vb[[int(t) for t in tip_vertices]]])[skeleton.file_index]
    info = {
        "model": model.name,
        "pose_a": pose_a if isinstance(pose_a, (int, np.integer, str)) else "custom",
        "pose_b": pose_b if isinstance(pose_b, (int, np.integer, str)) else "custom",
        "retriangulated": bool(retriangulate),
    }
    if retriangulate:
        rest_v, _ = mano_forward(model, np.zeros(3 * (model.n_joints - 1)), None, betas)
        tres = 36.0 if target_resolution is None else float(target_resolution)
        target_v, tf, gt = retriangulated_target(rest_v, model.faces, vb, tres, seed, f"{name}/gt")
        info["target_resolution"] = tres
    else:
        target_v, tf, gt = vb, model.faces, identity_ground_truth(source, f"{name}/gt")
    target_v, target_joints, motion = move_target(
        target_v, target_joints, va, seed, target_rotation, target_translation
    )
    if motion is not None:
        info["target_motion"] = motion
    return assemble_pair(
        name, source, skeleton, target_v, tf, gt, dataset="mano", target_joints=target_joints, info=info
    )
