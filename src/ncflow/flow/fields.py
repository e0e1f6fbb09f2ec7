"""Flow-Net: the time-dependent velocity field F_θ(x, t) of the neural ODE (paper Eq. 12, §4.6; DESIGN.md "Flow").

Standard field: F_θ(x, t) = α · MLP([x, t]), an MLP R⁴ → R³ with ``depth`` hidden layers of
``width`` units and (tanh-approximate) GELU activations, identity output, and a trainable scalar
output scale α initialised to 0.1. Weights and biases use Equinox's default initialisation,
U(−1/√fan_in, 1/√fan_in) (as the authors' release).

Divergence-free field (paper §4.1, volume preserving): F = α · ∇×A_θ with A_θ an MLP of the
same shape [x, t] → R³. The curl is taken from the 3×3 spatial Jacobian of A (``jax.jacfwd`` per
point, vmapped), so ∇·F = Σ_i ∂_i(∇×A)_i = 0 identically; numerically it vanishes up to float
rounding because the two mixed second derivatives of each A_k are computed separately.

Both fields are called as ``field(x, t)`` with points x (N, 3) and one scalar time t and return
velocities (N, 3). The parameters' dtype is chosen at construction (float32 by default); the
output follows JAX type promotion of inputs and parameters.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

DEFAULT_WIDTH = 256
DEFAULT_DEPTH = 6
ALPHA_INIT = 0.1


def _mlp(key: PRNGKeyArray, width: int, depth: int, dtype) -> eqx.nn.MLP:
    """MLP R⁴ → R³, ``depth`` hidden layers of ``width`` units (``depth + 1`` linear layers), GELU."""
    return eqx.nn.MLP(
        in_size=4, out_size=3, width_size=width, depth=depth, activation=jax.nn.gelu, dtype=dtype, key=key
    )


def _inputs(x: Float[Array, "N 3"], t: Float[Array, ""] | float, reverse_time: bool) -> Float[Array, "N 4"]:
    """Rows [x, t] (or [x, 1 − t]) in the dtype of x."""
    t = jnp.asarray(t, dtype=x.dtype)
    tt = 1.0 - t if reverse_time else t
    return jnp.concatenate([x, jnp.broadcast_to(tt, x.shape[:-1] + (1,))], axis=-1)


class _MLPField(eqx.Module):
    """Parameters shared by the fields: an MLP on [x, t], a trainable scale α, the time convention."""

    mlp: eqx.nn.MLP
    alpha: Float[Array, ""]
    reverse_time: bool = eqx.field(static=True, default=False)

    def __init__(
        self,
        key: PRNGKeyArray,
        width: int = DEFAULT_WIDTH,
        depth: int = DEFAULT_DEPTH,
        dtype=jnp.float32,
        alpha: float = ALPHA_INIT,
        reverse_time: bool = False,
    ):
        self.mlp = _mlp(key, width, depth, dtype)
        self.alpha = jnp.asarray(alpha, dtype=dtype)
        self.reverse_time = reverse_time


class FlowField(_MLPField):
    """F_θ(x, t) = α · MLP([x, t]) (DESIGN.md "Flow"; reference-notes §8.1).

    ``reverse_time=True`` feeds [x, 1 − t] instead, as the authors' release does (a reparametrisation
    of the input only; off by default).
    """

    def __call__(self, x: Float[Array, "N 3"], t: Float[Array, ""] | float) -> Float[Array, "N 3"]:
        """Velocities at points x (N, 3) and time t (scalar)."""
        return self.alpha * jax.vmap(self.mlp)(_inputs(x, t, self.reverse_time))


class DivFreeFlowField(_MLPField):
    """F_θ(x, t) = α · ∇×A_θ(x, t), A_θ an MLP [x, t] → R³; ∇·F = 0 (paper §4.1)."""

    def potential(self, x: Float[Array, "N 3"], t: Float[Array, ""] | float) -> Float[Array, "N 3"]:
        """The vector potential A_θ(x, t), (N, 3)."""
        return jax.vmap(self.mlp)(_inputs(x, t, self.reverse_time))

    def __call__(self, x: Float[Array, "N 3"], t: Float[Array, ""] | float) -> Float[Array, "N 3"]:
        """Velocities α ∇×A at points x (N, 3) and time t (scalar)."""
        t = jnp.asarray(t, dtype=x.dtype)
        tt = 1.0 - t if self.reverse_time else t

        def a_of_x(p: Float[Array, " 3"]) -> Float[Array, " 3"]:
            return self.mlp(jnp.concatenate([p, tt[None]]))

        jac = jax.vmap(jax.jacfwd(a_of_x))(x)  # (N, 3, 3), jac[n, i, j] = ∂A_i/∂x_j
        curl = jnp.stack(
            [jac[:, 2, 1] - jac[:, 1, 2], jac[:, 0, 2] - jac[:, 2, 0], jac[:, 1, 0] - jac[:, 0, 1]], axis=-1
        )
        return self.alpha * curl


def make_flow_field(
    key: PRNGKeyArray,
    width: int = DEFAULT_WIDTH,
    depth: int = DEFAULT_DEPTH,
    div_free: bool = False,
    dtype=jnp.float32,
    alpha: float = ALPHA_INIT,
    reverse_time: bool = False,
) -> FlowField | DivFreeFlowField:
    """A :class:`FlowField`, or a :class:`DivFreeFlowField` when ``div_free`` (volume-preserving flow)."""
    cls = DivFreeFlowField if div_free else FlowField
    return cls(key, width=width, depth=depth, dtype=dtype, alpha=alpha, reverse_time=reverse_time)


def divergence(field, x: Float[Array, "N 3"], t: Float[Array, ""] | float) -> Float[Array, " N"]:
    """∇·F at points x (N, 3) and time t: trace of the per-point spatial Jacobian (autodiff)."""

    def f_one(p: Float[Array, " 3"]) -> Float[Array, " 3"]:
        return field(p[None, :], t)[0]

    return jnp.trace(jax.vmap(jax.jacfwd(f_one))(x), axis1=-2, axis2=-1)
