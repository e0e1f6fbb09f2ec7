"""Adam-family optimisers with the cautious mask, as Optax ``GradientTransformation``s
(DESIGN.md "Optimiser"; reference-notes §10.1; paper §4.6).

Both optimisers are one chain over all parameters:

1. clip the gradient to global norm ``clip_norm`` (over every leaf);
2. a moment estimate u: AdaBelief (:func:`optax.scale_by_belief`) or VectorAdam
   (:func:`scale_by_vector_adam`);
3. the cautious mask (Liang et al. 2024, :func:`cautious`): per parameter array keep the
   components whose update agrees in sign with the gradient, u·g > 0, zero the others and divide
   by max(fraction kept, 10⁻³);
4. decoupled weight decay u ← u + wd·θ;
5. θ ← θ − η_t u, η_t a constant or a schedule of the step count (optax counts from 0).

VectorAdam pooling rule (Ling et al. 2022). A parameter array is treated as a set of 3-vectors
when :func:`is_vector_array` holds: its last axis has length 3 (e.g. a root translation (3,), a
per-point displacement (N, 3), the Flow-Net's output bias (3,)). For those, the second moment of a
row is the mean over steps of ‖g_row‖² — one value shared by the 3 components — and the cautious
mask keeps or drops whole rows by the sign of the row dot product u_row·g_row, the kept fraction
being counted in rows. Both are rotation invariant, so rotating the gradient rows (and parameters)
by R rotates the update rows by R. Every other array (matrices whose last axis is not 3,
quaternions (B, 4), scalars) falls back to Adam's per-component second moment and mask. A
different rule can be passed as ``is_vector``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from jaxtyping import Array

MIN_KEPT_FRACTION = 1e-3


def is_vector_array(x: Array) -> bool:
    """Default VectorAdam rule: an array whose last axis has length 3 is a stack of 3-vectors."""
    return jnp.ndim(x) >= 1 and jnp.shape(x)[-1] == 3


def _never_vector(x: Array) -> bool:
    return False


def _cautious_mask(u: Array, g: Array, pooled: bool) -> Array:
    """U masked by u·g > 0 (per component, or per row of 3 when ``pooled``) and divided by
    max(fraction kept, 10⁻³).
    """
    agree = jnp.sum(u * g, axis=-1, keepdims=True) if pooled else u * g
    keep = (agree > 0).astype(u.dtype)
    frac = jnp.mean(keep)
    return u * keep / jnp.maximum(frac, jnp.asarray(MIN_KEPT_FRACTION, u.dtype))


def cautious(
    inner: optax.GradientTransformation, is_vector: Callable[[Array], bool] = _never_vector
) -> optax.GradientTransformation:
    """Wrap a moment transform with the cautious mask (Liang et al. 2024).

    The gradient g entering this transform is compared with the update u that ``inner`` makes
    from it; per array, components (or, for arrays selected by ``is_vector``, rows of 3) with
    u·g ≤ 0 are zeroed and the rest divided by max(fraction kept, 10⁻³). A positive rescaling of g
    beforehand (clipping) does not change the mask.
    """

    def init_fn(params):
        return inner.init(params)

    def update_fn(updates, state, params=None):
        u, state = inner.update(updates, state, params)
        u = jax.tree.map(lambda ui, gi: _cautious_mask(ui, gi, bool(is_vector(ui))), u, updates)
        return u, state

    return optax.GradientTransformation(init_fn, update_fn)


class ScaleByVectorAdamState(NamedTuple):
    """Step count (int32 scalar), first moments mu (as params), second moments nu (per row of 3
    for vector arrays: shape (..., 1); otherwise as params).
    """

    count: Array
    mu: Any
    nu: Any


def scale_by_vector_adam(
    b1: float = 0.9,
    b2: float = 0.999,
    eps: float = 1e-8,
    is_vector: Callable[[Array], bool] = is_vector_array,
) -> optax.GradientTransformation:
    """VectorAdam (Ling et al. 2022): m ← b1 m + (1−b1) g; n ← b2 n + (1−b2) ‖g_row‖² for vector
    arrays (g² per component otherwise); u = m̂ / (√n̂ + eps) with bias corrections 1 − b^t.
    """

    def second(g: Array) -> Array:
        return jnp.sum(g * g, axis=-1, keepdims=True) if is_vector(g) else g * g

    def init_fn(params):
        mu = jax.tree.map(jnp.zeros_like, params)
        nu = jax.tree.map(lambda p: jnp.zeros_like(second(p)), params)
        return ScaleByVectorAdamState(count=jnp.zeros([], jnp.int32), mu=mu, nu=nu)

    def update_fn(updates, state, params=None):
        del params
        count = optax.safe_increment(state.count)
        mu = jax.tree.map(lambda g, m: b1 * m + (1 - b1) * g, updates, state.mu)
        nu = jax.tree.map(lambda g, n: b2 * n + (1 - b2) * second(g), updates, state.nu)

        def direction(m, n):
            t = count.astype(m.dtype)
            m_hat = m / (1 - jnp.asarray(b1, m.dtype) ** t)
            n_hat = n / (1 - jnp.asarray(b2, m.dtype) ** t)
            return m_hat / (jnp.sqrt(n_hat) + eps)

        u = jax.tree.map(direction, mu, nu)
        return u, ScaleByVectorAdamState(count=count, mu=mu, nu=nu)

    return optax.GradientTransformation(init_fn, update_fn)


def _clipped_decayed(
    core: optax.GradientTransformation,
    learning_rate: optax.ScalarOrSchedule,
    weight_decay: float,
    clip_norm: float | None,
    weight_decay_mask: Any,
) -> optax.GradientTransformation:
    """global-norm clip → ``core`` → decoupled weight decay → −η_t (the chain both optimisers share)."""
    return optax.chain(
        optax.clip_by_global_norm(clip_norm) if clip_norm is not None else optax.identity(),
        core,
        optax.add_decayed_weights(weight_decay, mask=weight_decay_mask),
        optax.scale_by_learning_rate(learning_rate),
    )


def adabelief_cautious(
    learning_rate: optax.ScalarOrSchedule,
    b1: float = 0.9,
    b2: float = 0.999,
    eps: float = 1e-16,
    weight_decay: float = 1e-4,
    clip_norm: float | None = 0.5,
    weight_decay_mask: Any = None,
) -> optax.GradientTransformation:
    """The authors' release optimiser (reference-notes §10.1): global-norm clip → AdaBelief
    (s uses the updated m; eps added to s and to √ŝ) → cautious mask per array → decoupled weight
    decay → −η_t. ``clip_norm=None`` disables clipping; ``weight_decay_mask`` (a pytree of bools or
    a callable, as :func:`optax.add_decayed_weights`) restricts the decay (default: all leaves).
    """
    core = cautious(optax.scale_by_belief(b1=b1, b2=b2, eps=eps, eps_root=eps))
    return _clipped_decayed(core, learning_rate, weight_decay, clip_norm, weight_decay_mask)


def vectoradam_cautious(
    learning_rate: optax.ScalarOrSchedule,
    b1: float = 0.9,
    b2: float = 0.999,
    eps: float = 1e-8,
    weight_decay: float = 1e-4,
    clip_norm: float | None = 0.5,
    weight_decay_mask: Any = None,
    is_vector: Callable[[Array], bool] = is_vector_array,
) -> optax.GradientTransformation:
    """The paper's optimiser (§4.6): global-norm clip → VectorAdam (rows of 3 share one second
    moment, see the module docstring) → cautious mask (per row of 3 for vector arrays, per
    component otherwise) → decoupled weight decay → −η_t. ``eps`` defaults to Adam's 10⁻⁸.
    """
    core = cautious(scale_by_vector_adam(b1=b1, b2=b2, eps=eps, is_vector=is_vector), is_vector=is_vector)
    return _clipped_decayed(core, learning_rate, weight_decay, clip_norm, weight_decay_mask)
