"""The per-step articulated pose fit (DESIGN.md "Constraints (MDMM)"): the skeleton pose that best
explains the flowed bone samples, by warm-started Gauss–Newton with a trust region, weighted per bone
and time as the constraint term weighs them; it eliminates the pose from the constraints, so g_k
measures only the flow's departure from an articulated rigid motion.
"""

from __future__ import annotations

import jax
import jax.flatten_util
import jax.numpy as jnp

from ncflow.matcher.prepare import DTYPE
from ncflow.skeleton import Skeleton, rigid_reference
from ncflow.skeleton.kinematics import Pose


def fit_pose(
    skeleton: Skeleton,
    pose: Pose,
    rest_points,
    flowed,
    times,
    interp: str,
    iterations: int = 2,
    max_step: float = 0.02,
    weights=None,
) -> Pose:
    """Least-squares articulated fit of flowed bone samples: Gauss–Newton on the pose parameters.

    Minimises Σ_t Σ_k w_t,k Σ_s ‖p̄_k,s(t; pose) − x_k,s(t)‖² over the joint rotations and the root
    translation; ``weights`` (broadcastable to (T, B); default :func:`constraint_fit_weights` with
    equal multipliers, i.e. the endpoint counts as much as the whole interior trajectory, as in
    g^EP + g^TR). Warm-started from ``pose`` (Levenberg damping ∝ tr(JᵀJ)/P handles the gauge
    directions: quaternion scale, rotations of leaf joints; 1e-3 in the code); each step is capped at ``max_step`` per
    parameter (a trust region, so a poor flow early on cannot fling the skeleton). ``flowed``
    (T, B, n, 3) is treated as data.
    """
    flat0, unravel = jax.flatten_util.ravel_pytree(pose)
    n_times = flowed.shape[0]
    if weights is None:
        weights = constraint_fit_weights(n_times, flowed.shape[1], flowed.dtype)
    root = jnp.sqrt(jnp.broadcast_to(jnp.asarray(weights, flowed.dtype), flowed.shape[:2]))[:, :, None, None]

    def residual(flat):
        return (root * (rigid_reference(skeleton, unravel(flat), rest_points, times, interp) - flowed)).reshape(-1)

    def residual_twice(flat):
        r = residual(flat)
        return r, r

    def gauss_newton(_, flat):
        jac, r = jax.jacfwd(residual_twice, has_aux=True)(flat)  # the forward kinematics traced once
        a = jac.T @ jac
        mu = 1e-3 * jnp.trace(a) / a.shape[0] + 1e-12
        delta = jnp.linalg.solve(a + mu * jnp.eye(a.shape[0], dtype=a.dtype), jac.T @ r)
        delta = delta * jnp.minimum(1.0, max_step / (jnp.max(jnp.abs(delta)) + 1e-12))  # trust region
        new = unravel(flat - delta)
        rot = new.rotations / jnp.linalg.norm(new.rotations, axis=-1, keepdims=True)
        return jax.flatten_util.ravel_pytree(Pose(rot, new.translation))[0]

    return unravel(jax.lax.fori_loop(0, iterations, gauss_newton, flat0))


def constraint_fit_weights(n_times: int, n_bones: int, dtype=DTYPE, lam_ep=None, lam_tr=None, trajectory: float = 1.0):
    """(T, B) per-time, per-bone weights under which the pose fit minimises the constraint term.

    The constraint term is Σ_k (1 + λ^EP_k) g^EP_k + τ (1 + λ^TR_k) g^TR_k with g^TR the mean over the
    T − 2 interior grid times: the endpoint state gets weight 1 + λ^EP, each interior state
    τ (1 + λ^TR)/(T − 2), t = 0 none (its residual is zero). With no multipliers the endpoint counts
    as much as the whole interior trajectory.
    """
    lam_ep = jnp.zeros((n_bones,), dtype) if lam_ep is None else jnp.asarray(lam_ep, dtype)
    lam_tr = jnp.zeros((n_bones,), dtype) if lam_tr is None else jnp.asarray(lam_tr, dtype)
    interior = trajectory * (1.0 + lam_tr) / max(n_times - 2, 1)
    rows = [jnp.zeros((n_bones,), dtype)] + [interior] * (n_times - 2) + [1.0 + lam_ep]
    return jnp.stack(rows[-n_times:]).astype(dtype)
