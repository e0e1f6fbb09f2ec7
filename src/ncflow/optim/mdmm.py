"""Inequality constraints g_k ≤ ε by the Modified Differential Method of Multipliers (Platt & Barr
1987; paper Eqs. 23–27, §4.5; DESIGN.md "Constraints (MDMM)"), and the soft-penalty baseline.

Convention (ours, the paper's sign): violation Γ_k = max(g_k − ε, 0) ≥ 0, multipliers λ_k ≥ 0,

    M(g, λ) = Σ_k λ_k Γ_k + (δ/2) Σ_k Γ_k²          (added to the loss),

gradient descent on the model parameters and ascent on λ with projection to λ ≥ 0:
λ ← max(0, λ + η_λ Γ). (The authors' release uses Γ' = −Γ and lets λ go negative, unclamped — the
same dynamics up to the sign of λ; reference-notes §9.1.) Since Γ = 0 on satisfied constraints,
their multipliers are not driven down; they stay where the violations left them.

Two ways to compose with an Optax optimiser on the model parameters:

* explicit: ``loss = L + mdmm_term(g, lam, eps, damping)`` with ``lam`` held outside the
  differentiated parameters, then ``lam = update_multipliers(lam, g, eps, lr)`` each step;
* reversed gradient: keep ``lam`` inside the parameter pytree and use
  ``mdmm_term(g, reverse_gradient(lam), ...)``. The identity :func:`reverse_gradient` negates the
  cotangent, so the optimiser's descent step is an ascent step in λ; follow every update with
  :func:`clamp_multipliers`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

__all__ = [
    "violation",
    "mdmm_term",
    "update_multipliers",
    "reverse_gradient",
    "clamp_multipliers",
    "soft_constraint_term",
]


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
    per = lam * gamma + 0.5 * damping * gamma * gamma
    if reduction == "sum":
        return jnp.sum(per)
    if reduction == "mean":
        return jnp.mean(per)
    raise ValueError(f"reduction must be 'sum' or 'mean', got {reduction!r}")


def update_multipliers(
    lam: Float[Array, " B"], g: Float[Array, " B"], eps: float | Float[Array, " B"], lr: float
) -> Float[Array, " B"]:
    """Projected ascent step λ ← max(0, λ + lr · Γ) (paper Eq. 27 with thresholding)."""
    return jnp.maximum(lam + lr * violation(g, eps), 0.0)


@jax.custom_vjp
def reverse_gradient(x: Array) -> Array:
    """Identity in the forward pass; the cotangent is negated in the backward pass."""
    return x


def _reverse_fwd(x):
    return x, None


def _reverse_bwd(_, ct):
    return (jax.tree.map(jnp.negative, ct),)


reverse_gradient.defvjp(_reverse_fwd, _reverse_bwd)


def clamp_multipliers(lam: Float[Array, " B"]) -> Float[Array, " B"]:
    """Projection onto λ ≥ 0 after an optimiser step (reversed-gradient formulation)."""
    return jnp.maximum(lam, 0.0)


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
