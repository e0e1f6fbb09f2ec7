"""Inequality constraints g_k ≤ ε by the Modified Differential Method of Multipliers (Platt & Barr
1987; paper Eqs. 23–27, §4.5; DESIGN.md "Constraints (MDMM)"), and the soft-penalty baseline.

Convention (ours, the paper's sign): violation Γ_k = max(g_k − ε, 0) ≥ 0, multipliers λ_k ≥ 0,

    M(g, λ) = Σ_k λ_k Γ_k + (δ/2) Σ_k Γ_k²          (added to the loss, :func:`mdmm_term`),

gradient descent on the model parameters, and ascent on λ held outside the differentiated
parameters. The ascent the matcher runs is :func:`ascend_multipliers` — a sign ascent
λ ← max(0, λ + η_t sign(g − target)) with the ramped rate of :func:`multiplier_rate`, rather than
the paper's proportional λ + η Γ (the reasons are in its docstring). (The authors' release uses
Γ' = −Γ and lets λ go negative, unclamped; reference-notes §9.1.) The soft mode is the ARC-Flow
baseline: a fixed-weight penalty, :func:`soft_constraint_term`.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float


def violation(g: Float[Array, " B"], eps: float | Float[Array, " B"]) -> Float[Array, " B"]:
    """Γ = max(g − ε, 0) (paper Eq. 26 in the sign convention above); 0 where g ≤ ε."""
    return jnp.maximum(g - eps, 0.0)


def mdmm_term(
    g: Float[Array, " B"],
    lam: Float[Array, " B"],
    eps: float | Float[Array, " B"],
    damping: float = 1.0,
    reduction: str = "sum",
) -> Float[Array, ""]:
    """Σ_k λ_k Γ_k + (δ/2) Σ_k Γ_k² (paper Eqs. 23/25 with quadratic damping δ = ``damping``).

    ``reduction="mean"`` divides by B (as the release does; the effective damping is then δ/B).
    Gradients flow to g (descent on the model) and to λ (∂/∂λ_k = Γ_k, or its negative through
    :func:`reverse_gradient`).
    """
    gamma = violation(g, eps)
    per = lam * gamma + 0.5 * damping * gamma**2
    if reduction == "sum":
        return jnp.sum(per)
    if reduction == "mean":
        return jnp.mean(per)
    raise ValueError(f"reduction must be 'sum' or 'mean', got {reduction!r}")


def multiplier_rate(lr: float, progress: Float[ArrayLike, "*batch"]) -> Float[ArrayLike, "*batch"]:
    """Step size η_t = 2 η · progress of the multiplier ascent (``progress`` = step / total steps in [0, 1]).

    The ramp lets the shape match first while λ is small and tightens the bones late; its mean over
    the run is η (``constraints.multiplier_lr``).
    """
    return lr * 2.0 * progress


def ascend_multipliers(
    lam: Float[Array, "*batch B"],
    g: Float[Array, "*batch B"],
    target: float | Float[Array, "*batch B"],
    rate: float | Float[ArrayLike, ""],
    active: float | Float[ArrayLike, ""] | Float[ArrayLike, "*#batch #B"] = 1.0,
) -> Float[Array, "*batch B"]:
    """The multiplier rule the matcher runs: λ ← max(0, λ + η_t · a · sign(g − target)).

    A normalised (sign) ascent on Eq. 27, projected on λ ≥ 0: every violated constraint gains η_t,
    every satisfied one loses η_t until its multiplier reaches 0 — unlike the proportional rule
    λ + η Γ of the paper, a constraint that is met releases its multiplier, and the step does not
    depend on the scale of g (the release moves its multipliers with sign-like Adam steps, the same
    normalisation; reference-notes §9.1). ``target`` is the level the constraint is held at (the
    matcher uses margin · ε, so that the values MDMM settles around stay under ε); ``active``
    (0 or 1, broadcast against ``lam``) freezes multipliers of constraints that are switched off
    in a phase.
    """
    return jnp.maximum(lam + rate * active * jnp.sign(g - target), 0.0)


def soft_constraint_term(
    g: Float[Array, " B"], weights: float | Float[Array, " B"], reduction: str = "sum"
) -> Float[Array, ""]:
    """Fixed-weight penalty Σ_k w_k g_k (ARC-Flow baseline; ``reduction="mean"`` divides by B)."""
    per = weights * g
    if reduction == "sum":
        return jnp.sum(per)
    if reduction == "mean":
        return jnp.mean(per)
    raise ValueError(f"reduction must be 'sum' or 'mean', got {reduction!r}")


def multiplier_ceiling(lr: float, n_steps: int) -> float:
    """The largest multiplier :func:`ascend_multipliers` alone reaches in a run of ``n_steps`` steps at the
    ramped rate of :func:`multiplier_rate` (step d at progress d / n_steps), rising every step:
    Σ_d 2η d / n = η (n − 1). A constraint the data term out-pulls for the whole run ends there (399 at
    the defaults: the Fox's root bone at 5.6 ε, benchmarks/RESULTS.md "Bones hold").
    """
    return float(lr) * max(int(n_steps) - 1, 0)


class Multipliers(NamedTuple):
    """What the multiplier rule carries from step to step (each (…, B), one entry per constraint).

    Attributes:
        lam: the multipliers λ ≥ 0.
        g_mean: the running mean of g that the rule reads (an exponential moving average); above the
            target at the end of training, its constraint was still violated there.
    """

    lam: Float[Array, "*batch B"]
    g_mean: Float[Array, "*batch B"]


def init_multipliers(lam: Float[ArrayLike, "*batch B"]) -> Multipliers:
    """The rule's state at the start: multipliers ``lam`` and no running mean (0)."""
    lam = jnp.asarray(lam)
    return Multipliers(lam, jnp.zeros_like(lam))


def update_multipliers(
    state: Multipliers,
    g: Float[Array, "*batch B"],
    target: float | Float[Array, "*batch B"],
    rate: float | Float[ArrayLike, ""],
    active: float | Float[ArrayLike, ""] | Float[ArrayLike, "*#batch #B"] = 1.0,
    *,
    decay: float = 0.9,
) -> Multipliers:
    """One step of the multiplier rule the matcher runs: the sign ascent of :func:`ascend_multipliers`
    read on the running mean of g,

        ḡ ← β ḡ + (1 − β) g,        λ ← max(0, λ + η_t · a · sign(ḡ − target)).

    Why the mean (benchmarks/RESULTS.md, "Bones hold"): g is estimated each step from a few fresh bone
    samples (``sampling.bone_samples``), a noisy and skewed estimate, and the sign ascent on it holds its
    *median* at the target, while its mean — what the final 200 fresh samples per bone measure — lies
    above (for an exponential spread, 1/ln 2 ≈ 1.44× the median). The running mean (β = ``decay``, about
    1/(1 − β) steps; 0: the step's own estimate) is an estimate of the mean that the sign can hold.
    ``active`` (0 or 1) freezes every part of the constraints switched off in a phase. ḡ starts at 0
    (:func:`init_multipliers`), below any target, while the ramp η_t is still near 0.
    """
    keep = jnp.asarray(active) > 0
    g_mean = jnp.where(keep, decay * state.g_mean + (1.0 - decay) * g, state.g_mean)
    lam = ascend_multipliers(state.lam, g_mean, target, rate, active)
    return Multipliers(lam, g_mean)
