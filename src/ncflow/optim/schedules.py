"""Learning-rate schedules of the step count (DESIGN.md "Optimiser"; reference-notes §10.2).

A schedule maps a step count s (int, or an int array inside jit; optax counts from 0) to a
learning rate. Each training phase has its own warm-up: the training loop calls a phase's schedule
with the phase's own step count (:func:`ncflow.matcher.stages.phase_schedule`), so the first step of
each phase has η = 0 when it warms up.
"""

from __future__ import annotations

import jax.numpy as jnp
import optax
from jaxtyping import Array, Float, Int


def _warmup(peak: float, warmup_steps: int, s: Array) -> Array:
    """Peak · s / warmup_steps for s < warmup_steps (peak afterwards)."""
    if warmup_steps <= 0:
        return jnp.full_like(s, peak)
    return peak * jnp.minimum(s / warmup_steps, 1.0)


def warmup_cosine(peak: float, end: float, warmup_steps: int, total_steps: int) -> optax.Schedule:
    """Linear 0 → ``peak`` over s ∈ [0, warmup_steps], then cosine to ``end`` at s = total_steps:

        η(s) = end + (peak − end) · ½ (1 + cos(π (s − warmup_steps) / (total_steps − warmup_steps))),

    and ``end`` for s ≥ total_steps (total_steps counts the warm-up; reference-notes §10.2).
    """
    if total_steps <= warmup_steps:
        raise ValueError(f"total_steps ({total_steps}) must exceed warmup_steps ({warmup_steps})")

    def schedule(step: Int[Array, ""] | int) -> Float[Array, ""]:
        s = jnp.asarray(step, dtype=float)
        frac = jnp.clip((s - warmup_steps) / (total_steps - warmup_steps), 0.0, 1.0)
        cosine = end + (peak - end) * 0.5 * (1.0 + jnp.cos(jnp.pi * frac))
        return jnp.where(s < warmup_steps, _warmup(peak, warmup_steps, s), cosine)

    return schedule


def warmup_constant(peak: float, warmup_steps: int) -> optax.Schedule:
    """Linear 0 → ``peak`` over s ∈ [0, warmup_steps], then constant ``peak``."""

    def schedule(step: Int[Array, ""] | int) -> Float[Array, ""]:
        return _warmup(peak, warmup_steps, jnp.asarray(step, dtype=float))

    return schedule
