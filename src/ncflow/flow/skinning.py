"""Skeleton-driven flow: a Flow-Net plus the blended rigid velocities of the skeleton's bones.

    F(x, t) = Σ_b w_b(x, t) ξ_b(t)(x) + R_θ(x, t),

where R_θ is a Flow-Net (:class:`~ncflow.flow.FlowField`, the paper's Eq. 12 field, here the
residual), ξ_b(t)(x) = Ω_b(t)(x − c_b(t)) + ċ_b(t) the velocity field of bone b's rigid motion
M_b(t) = (R_b(t), c_b(t)) from rest to the pose (:func:`ncflow.skeleton.bone_motions`, ScLERP by
default; Ω_b = Ṙ_b R_bᵀ; joints with one child bone swing without twist,
:meth:`SkinnedField.swing_pose`), and w_b(x, t) = softmax_b(−d_b(x, t)/τ) soft assignment
weights from the distance d_b of x to bone b's segment posed at time t. A point that stays near the
middle of a bone is carried by that bone's rigid motion exactly (up to the integrator's error);
the weights blend neighbouring bones in a band of width ~τ around each joint, where the
relative motion of the two bones is small. The pose (joint rotations and root translation,
:class:`~ncflow.skeleton.kinematics.Pose`) is a trainable leaf of the module, so the data term
drives the skeleton directly.

Where the weights are taken (``weight_mode``):

* ``"current"`` (the class default): at the point's current place, w_b(x(t), t) — a velocity
  field of space, so the flow stays a diffeomorphism. Around a bending joint a point is handed
  from one bone to the other as it moves; but a part that comes near another limb's bone is taken
  over by that bone's motion, and no part can pass through another.
* ``"start"``: at the place the point starts from, w_b(x(0), 0), kept along its path (linear
  blend skinning's velocity). The velocity then depends on each point's start as well as on its
  place, so the motion is no longer a flow of space, and surfaces of different limbs can meet and
  pass through each other, as captured and rigged targets with self-contact do (a tucked
  fingertip of a MANO fist lies partly inside the palm: with ``"current"`` the palm takes the
  fingertip over, and its surface is left on its own middle phalanx; benchmarks/RESULTS.md,
  "Fists: bone weights at the start"). Each trajectory still depends only on its own start, so
  any point set (the full-resolution source, frames) is moved by the same trained field.
* ``"surface"``: as ``"start"``, with the weights of a surface point taken by
  :func:`~ncflow.flow.bone_weights.surface_skinning_weights` from its start and its normal there: a bone
  whose nearest point lies in front of the skin is left out. In a source whose limbs touch (a fist: the
  palm's skin under the fingertips is nearer the fingers' bones than its own), the plain weights give that
  skin to the touching limb, and straightening the limb tears it off its own part. A mesh's start normals may
  carry one more column per bone (:func:`ncflow.flow.islands.surface_skin`): 1 leaves the bone out
  for that point too, where :func:`~ncflow.flow.islands.skin_islands` finds its skin cut off from the
  bone's limb along the surface (a captured fist's fingertip sunk into the palm: its bone lies
  *behind* the palm's skin, where the front test cannot tell). Points without a normal (bone and
  tissue samples: a zero row) take the plain weights of ``"start"``.

The matcher chooses between them per pair (``flow.skinning_weights = "auto"``, see
:func:`ncflow.matcher.prepare.skinning_weight_mode`).

Rigid cores (``core``): inside the cylinder around each bone where its samples lie, the Flow-Net is
faded out (:func:`~ncflow.flow.bone_weights.core_gate`) and the weights are the bone's alone
(:func:`~ncflow.flow.bone_weights.core_weights`: near a bent joint the plain weights blend the
neighbouring bone's motion into the samples' ends), so the field there is that bone's rigid velocity.
On the integrator's grid the bones' motions are stepped in closed form
(:meth:`_GridSkinnedField.articulated_step`: each point moved by the blend of its bones' rigid motions
from t_k to t_{k+1}; :func:`ncflow.flow.integrate.integrate`), the Flow-Net by the Heun-type
recursion: a bone's samples then keep its rigid motion to rounding however far it turns over one of
the T − 1 steps, where the Heun recursion on the velocities left a fingertip that turns 270° over
nine steps hundreds of tolerances off rigid (and the constraints pulled the finger's pose back towards
less turn; benchmarks/RESULTS.md, session 34). Where weights blend (near joints) the closed-form steps
are first order in the step (the blend of rigid steps is not the step of the blended velocity).

This is not in the paper: there the Flow-Net alone has to produce the articulated motion and the
bone constraints (MDMM) make it rigid around the bones. With the small network and the few
hundred steps that fit a CPU budget, that leaves the bones several times the tolerance from
rigid; with the skeleton's velocities built in, the network only carries the non-articulated
remainder (skin sliding, bulging) and the constraints act on that remainder. ``flow.skinning``
turns it on (the ``fast`` preset) or off (the ``paper`` preset: the paper's field, a
diffeomorphism); ``flow.skinning_weights`` chooses ``weight_mode``.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ncflow.flow.bone_weights import (
    _HIGHEST,
    _core_table,
    _cored,
    _gate,
    _mm,
    _plain,
    _projection_terms,
    core_weights,
    skinning_weights,
    surface_skinning_weights,
)
from ncflow.flow.integrate import time_grid
from ncflow.skeleton import Skeleton
from ncflow.skeleton.dualquat import dq_rotation, dq_translation, quat_to_matrix
from ncflow.skeleton.kinematics import Pose, bone_motions, rest_pose
from ncflow.skeleton.samples import DEFAULT_AXIAL_RANGE


def bone_velocities(
    skeleton: Skeleton, pose: Pose, t: Float[ArrayLike, ""], interp: str = "sclerp", h: float = 1e-3
) -> tuple[Float[Array, "B 3 3"], Float[Array, "B 3"], Float[Array, "B 3 3"], Float[Array, "B 3"]]:
    """Each bone's rigid motion at time t, x ↦ R_b x + c_b, and its time derivative (Ṙ_b, ċ_b).

    Returns (R, c, Ṙ, ċ); the velocity of a point x carried by bone b is Ṙ_b R_bᵀ (x − c_b) + ċ_b.
    The derivative is the central difference with step ``h`` (the motions extend smoothly past
    [0, 1]); autodiff in t would double the forward kinematics' graph and its compile time, for a
    difference of O(h²) ≈ 1e-6 relative.
    """
    t = jnp.asarray(t, pose.rotations.dtype)
    m = jax.vmap(lambda s: bone_motions(skeleton, pose, s, interp))(jnp.stack([t, t - h, t + h]))
    r, c = quat_to_matrix(dq_rotation(m)), dq_translation(m)
    return r[0], c[0], (r[2] - r[1]) / (2 * h), (c[2] - c[1]) / (2 * h)


def swing_only(skeleton: Skeleton, pose: Pose) -> Pose:
    """``pose`` with the twist of every joint that has exactly one child bone removed: its rotation's
    vector part projected off the child bone's rest axis (:meth:`SkinnedField.swing_pose`).
    """
    par = np.asarray(skeleton.parents)[1:]  # parent of each bone's end joint
    single = np.bincount(par, minlength=skeleton.n_joints)[par] == 1
    off = np.asarray(skeleton.offsets)[1:][single]
    axes = np.zeros((skeleton.n_joints, 3))
    axes[par[single]] = off / np.linalg.norm(off, axis=1, keepdims=True)
    q = pose.rotations
    a = jnp.asarray(axes, q.dtype)
    v = q[:, 1:] - jnp.sum(q[:, 1:] * a, -1, keepdims=True) * a
    return Pose(jnp.concatenate([q[:, :1], v], -1), pose.translation)


class SkinnedField(eqx.Module):
    """F(x, t) = Σ_b w_b(x, t) ξ_b(t)(x) + residual(x, t) (see the module docstring).

    Args:
        residual: the Flow-Net R_θ (any ``field(x, t)``).
        skeleton: the source skeleton in the coordinates of the points (normalised, for training).
        pose: initial pose (default: the rest pose, so the field starts as the residual alone).
        width: τ of the weights, in the units of the points; held as a 0-d array (not a static
            number) so that one compiled program serves every skeleton, and never trained (the
            optimiser's ``"frozen"`` group, :func:`ncflow.matcher.train.parameter_labels`).
        interp: "sclerp" (default) or "slerp", as :func:`ncflow.skeleton.interpolate_world`.
        weight_mode: "current" (default), "start" or "surface" — where the bone weights are taken;
            see the module docstring. Only the integrator (:func:`ncflow.flow.integrate`, through
            :meth:`on_grid`) knows the starts and their normals: a direct call ``field(x, t)`` takes x
            as the start, without normals.
        core: (B,) radii of the bones' rigid cores (0: none), or None for no cores: the residual is
            faded out around every bone (:func:`~ncflow.flow.bone_weights.core_gate`), so that points in a
            core move with the skeleton alone; held as an array, never trained, like ``width``.
        core_outer: (B,) where the residual is whole again (default twice ``core``).
        core_ranges: (B, 2) the part of each bone (z / L) its core covers (default 10 %–90 %).
    """

    residual: eqx.Module
    pose: Pose
    width: Float[Array, ""]
    core: Float[Array, "B 4"] | None
    skeleton: Skeleton = eqx.field(static=True)
    interp: str = eqx.field(static=True, default="sclerp")
    weight_mode: str = eqx.field(static=True, default="current")

    def __init__(
        self,
        residual,
        skeleton: Skeleton,
        pose: Pose | None = None,
        width: float = 0.05,
        interp: str = "sclerp",
        dtype=jnp.float32,
        weight_mode: str = "current",
        core: Float[ArrayLike, " B"] | None = None,
        core_outer: Float[ArrayLike, " B"] | None = None,
        core_ranges: Float[ArrayLike, "B 2"] | None = None,
    ):
        if not width > 0:
            raise ValueError(f"width must be positive, got {width}")
        if weight_mode not in WEIGHT_MODES:
            raise ValueError(f"weight_mode must be one of {WEIGHT_MODES}, got {weight_mode!r}")
        if core is not None and (np.shape(core) != (skeleton.n_bones,) or not np.all(np.asarray(core) >= 0)):
            raise ValueError(f"core must hold {skeleton.n_bones} radii (0: none), got shape {np.shape(core)}")
        if core is not None and core_outer is not None:
            c, o = np.asarray(core), np.asarray(core_outer)
            if o.shape != c.shape or not np.all((c == 0) | (o > c)):
                raise ValueError("core_outer must exceed core for every bone with a core")
        self.residual = residual
        self.skeleton = skeleton
        self.pose = rest_pose(skeleton, dtype) if pose is None else pose
        self.width = jnp.asarray(width, dtype)
        if core is None:
            self.core = None
        else:
            ranges = DEFAULT_AXIAL_RANGE if core_ranges is None else core_ranges
            outer = 2.0 * np.asarray(core) if core_outer is None else np.asarray(core_outer)
            self.core = _core_table(skeleton.n_bones, core, outer, ranges, dtype)  # radius, outer, lo, hi
        self.interp = interp
        self.weight_mode = weight_mode

    def swing_pose(self) -> Pose:
        """The pose the bones move by: the trained pose with the twist of every joint that has
        exactly one child bone removed (its rotation's vector part projected off the bone's rest
        axis). Twist about a nearly round limb (a finger, a capsule) barely shows in the data
        term, and a trained twist drifts with the sign-like optimiser steps (a spin of a bone and
        an opposite turn of its child's bending axis look alike); the Flow-Net carries whatever
        twist the shapes need, and the fitted output skeleton keeps it.
        """
        return swing_only(self.skeleton, self.pose)

    def _motion(self, t):
        """(heads, tails, c, Ω, ċ, R) of every bone at time t: its posed segment, its velocity and its
        rotation from rest (x ↦ R x + c moves the rest bone to time t).
        """
        r, c, dr, dc = bone_velocities(self.skeleton, self.swing_pose(), t, self.interp)
        bones = np.asarray(self.skeleton.bones)
        rest = jnp.asarray(self.skeleton.positions, r.dtype)
        heads = jnp.einsum("bij,bj->bi", r, rest[bones[:, 0]], precision=_HIGHEST) + c
        tails = jnp.einsum("bij,bj->bi", r, rest[bones[:, 1]], precision=_HIGHEST) + c
        return heads, tails, c, jnp.einsum("bij,bkj->bik", dr, r, precision=_HIGHEST), dc, r  # Ω = Ṙ Rᵀ

    def weights(
        self,
        x: Float[Array, "N 3"],
        t: Float[Array, ""] | float,
        x0: Float[Array, "N 3"] | None = None,
        n0: Float[Array, "N C"] | None = None,
    ) -> Float[Array, "N B"]:
        """Bone weights of points x at time t that started at x0 (default x) with normals n0 there
        (default none: zero rows), by ``weight_mode`` (rows sum to 1).
        """
        if self.weight_mode == "current":
            heads, tails, *_ = self._motion(t)
            return skinning_weights(x, heads, tails, self._width())
        heads, tails, *_ = self._motion(jnp.zeros((), self.pose.rotations.dtype))
        return self._start_weights(x if x0 is None else x0, n0, heads, tails)

    def _start_weights(self, x0, n0, heads, tails):
        if self.weight_mode == "surface" and n0 is not None:
            return surface_skinning_weights(x0, jnp.asarray(n0, x0.dtype), heads, tails, self._width())
        return skinning_weights(x0, heads, tails, self._width())

    def _width(self) -> Float[Array, ""]:
        return jax.lax.stop_gradient(self.width)

    def skeleton_velocity(self, x: Float[Array, "N 3"], t: Float[Array, ""] | float) -> Float[Array, "N 3"]:
        """The articulated part Σ_b w_b ξ_b(x) at points x (N, 3) and time t (x taken as the start too)."""
        return _blend(x, self._motion(t), self._width(), None, self._core())

    def _core(self) -> Float[Array, "B 4"] | None:
        return None if self.core is None else jax.lax.stop_gradient(self.core)

    def __call__(self, x: Float[Array, "N 3"], t: Float[Array, ""] | float) -> Float[Array, "N 3"]:
        """Velocities at points x (N, 3) and time t (scalar), x taken as the start too."""
        motion = self._motion(t)
        return _blend(x, motion, self._width(), None, self._core()) + _gated(
            self.residual(x, t), x, motion, self._core()
        )

    def on_grid(
        self,
        n_times: int,
        dtype=None,
        x0: Float[Array, "N 3"] | None = None,
        n0: Float[Array, "N C"] | None = None,
    ) -> _GridSkinnedField:
        """The same field for the integrator's grid t_k = k/(T−1) and the start points ``x0`` (with
        their normals ``n0`` for ``weight_mode="surface"``; zero rows or None: no normal): the bones'
        motions at the T grid times are computed once (one batched forward kinematics) instead of at
        every evaluation, and with the weights of the start ("start", "surface") so are the weights of
        the (N, 3) start points (the returned field is then called on those N trajectories only).
        """
        times = time_grid(n_times, dtype or self.pose.rotations.dtype)
        motion = jax.vmap(self._motion)(times)
        fixed = None
        if self.weight_mode != "current" and x0 is not None:
            x0 = jnp.asarray(x0)
            heads, tails = motion[0][0], motion[1][0]  # bones at t_0 = 0
            fixed = core_weights(self._start_weights(x0, n0, heads, tails), x0, heads, tails, self._core())
        return _GridSkinnedField(self.residual, motion, self._width(), self._core(), n_times, fixed)


WEIGHT_MODES = ("current", "start", "surface")
"""Where a :class:`SkinnedField` takes its bone weights: at each point's current place or its start."""


def _current_weights(x, motion, width, core):
    """:func:`~ncflow.flow.bone_weights.core_weights` of the plain weights, both from one projection of x."""
    terms = _projection_terms(x, motion[0], motion[1])
    w = _plain(terms, width)
    return w if core is None else _cored(w, terms, core)


def _affine_blend(x, w, mats, offsets):
    """Σ_b w_b (M_b x + o_b) for (N, B) weights, (B, 3, 3) matrices and (B, 3) offsets, as two matrix products."""
    wx = (w[:, :, None] * x[:, None, :]).reshape(x.shape[0], -1)  # (N, 3B)
    return _mm(wx, jnp.swapaxes(mats, 1, 2).reshape(-1, 3).astype(x.dtype)) + _mm(w, offsets.astype(x.dtype))


def _blend(x, motion, width, fixed=None, core=None):
    heads, tails, c, omega, dc = motion[:5]
    w = (_current_weights(x, motion, width, core) if fixed is None else fixed).astype(x.dtype)  # (N, B)
    # Σ_b w_b (Ω_b x + k_b), k_b = ċ_b − Ω_b c_b
    return _affine_blend(x, w, omega, dc - jnp.einsum("bij,bj->bi", omega, c, precision=_HIGHEST))


class _GridSkinnedField(eqx.Module):
    """A :class:`SkinnedField` whose bone motions are tabulated at t_k = k/(T−1); called at a grid
    time (the integrator only evaluates there), it looks the motions up. With ``fixed`` (N, B)
    weights (those of the start points) it is called on those N trajectories only.
    """

    residual: eqx.Module
    motion: tuple
    width: Float[Array, ""]
    core: Array | None
    n_times: int = eqx.field(static=True)
    fixed: Array | None = None

    def _at(self, t):
        k = jnp.clip(jnp.round(jnp.asarray(t) * (self.n_times - 1)), 0, self.n_times - 1).astype(jnp.int32)
        return tuple(m[k] for m in self.motion)

    def __call__(self, x, t):
        motion = self._at(t)
        return _blend(x, motion, self.width, self.fixed, self.core) + _gated(self.residual(x, t), x, motion, self.core)

    def weights_at(self, x, k):
        """The bone weights (N, B) of points x at grid index k (those of the start when fixed)."""
        if self.fixed is not None:
            return self.fixed.astype(x.dtype)
        return _current_weights(x, tuple(m[k] for m in self.motion), self.width, self.core).astype(x.dtype)

    def articulated_velocity(self, x, k, w):
        """The articulated part of the velocity at grid index k, with the bone weights w (:meth:`weights_at`)."""
        return _blend(x, tuple(m[k] for m in self.motion), self.width, w)

    def residual_velocity(self, x, t):
        """The gated Flow-Net part of the velocity at grid time t."""
        return _gated(self.residual(x, t), x, self._at(t), self.core)

    def articulated_step(self, x, k, w):
        """Where the bones' motions carry points x from grid time t_k to t_{k+1}, exactly:
        Σ_b w_b (A_b x + d_b), A_b = R_b(t_{k+1}) R_b(t_k)ᵀ, d_b = c_b(t_{k+1}) − A_b c_b(t_k), with the weights
        w (N, B) at t_k (:meth:`weights_at`). A point of one bone (a rigid core) moves with that bone's rigid
        motion, however far the bone turns over the step.
        """
        r0, c0 = self.motion[5][k], self.motion[2][k]
        r1, c1 = self.motion[5][k + 1], self.motion[2][k + 1]
        a = jnp.einsum("bij,bkj->bik", r1, r0, precision=_HIGHEST)  # (B, 3, 3)
        return _affine_blend(x, w, a, c1 - jnp.einsum("bij,bj->bi", a, c0, precision=_HIGHEST))


def _gated(residual, x, motion, core):
    """The residual times :func:`~ncflow.flow.bone_weights.core_gate` of the bones posed by ``motion``
    (unchanged without cores; ``core`` (B, 4): radius, outer radius, axial range).
    """
    if core is None:
        return residual
    heads, tails, *_ = motion
    return residual * _gate(_projection_terms(x, heads, tails), core)[:, None]
