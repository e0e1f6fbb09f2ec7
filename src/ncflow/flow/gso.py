"""GSO-Net: a small network predicting a local rotation R(x, t) ∈ SO(3) for the surface distortion term.

Paper §4.4 and Eq. 22 (the GSO-Net φ); DESIGN.md "Soft tissue"; reference-notes §7.2.

Network: an MLP R⁴ → R⁶ on [x, y, z, t] (a *deformed* point at grid time t, raw t), ``depth``
hidden layers of ``width`` units (default 3 × 128, as the release), tanh-approximate GELU,
identity output, Equinox's default initialisation U(−1/√fan_in, 1/√fan_in). Its output o is
mapped to the 6-D rotation code (Zhou et al. 2019)

    ō = s · o + (1, 0, 0, 0, 1, 0),      s = ``out_scale`` = 0.1,

and Gram–Schmidt gives R = [a, b, a × b] (columns), a = ō₀:₃/‖ō₀:₃‖,
b = normalize(ō₃:₆ − (a·ō₃:₆) a). The bias (1,0,0, 0,1,0) is the code of the identity, so a
fresh net predicts rotations close to the identity (measured: at most ≈1° on standard-normal
inputs). The authors' release adds (1,0,0, 1,0,0) instead — both halves parallel, so its second
column is set by the small perpendicular part of the network output and a fresh net returns
rotations of 12°–111° (reference-notes §7.2); we do not reproduce that bug.

Lipschitz normalisation (release: per-layer row scaling by min(1, softplus(c)/Σ_j|W_ij|) with a
trainable c initialised to the largest absolute row sum, plus a penalty Π softplus(c) with weight
1e-10) is **not** implemented. At initialisation that scaling is (almost) the identity; later it
only caps rows whose absolute sum grows past softplus(c), while c is itself trained and the 1e-10
penalty barely restrains it. We judged the extra parametrisation not worth it.
:meth:`GSONet.lipschitz_bound` returns out_scale × Π_ℓ ‖W_ℓ‖_∞ (the Lipschitz constant of the
code map in the ∞-norm is at most this times 1.13^depth, 1.13 bounding the slope of GELU), for
monitoring or for an explicit penalty if one is wanted.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

IDENTITY_6D = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0)
"""The 6-D code of the identity rotation: first two columns of I."""
DEFAULT_GSO_WIDTH = 128
DEFAULT_GSO_DEPTH = 3
DEFAULT_OUT_SCALE = 0.1


def _normalize(v: Float[Array, "*batch 3"]) -> Float[Array, "*batch 3"]:
    """v/‖v‖ with a floor on ‖v‖² (NaN-free; the codes here are never near zero in practice)."""
    sq = jnp.sum(v * v, axis=-1, keepdims=True)
    tiny = jnp.asarray(1e-36 if v.dtype == jnp.float64 else 1e-30, v.dtype)
    return v / jnp.sqrt(jnp.maximum(sq, tiny))


def rotation_from_6d(code: Float[Array, "*batch 6"]) -> Float[Array, "*batch 3 3"]:
    """Gram–Schmidt of a 6-D code into a rotation matrix R = [a, b, a × b] (columns), det R = +1.

    a = normalize(code[0:3]), b = normalize(code[3:6] − (a·code[3:6]) a). The code
    (1, 0, 0, 0, 1, 0) maps to the identity.
    """
    u, w = code[..., 0:3], code[..., 3:6]
    a = _normalize(u)
    b = _normalize(w - jnp.sum(a * w, axis=-1, keepdims=True) * a)
    c = jnp.cross(a, b)
    return jnp.stack([a, b, c], axis=-1)


class GSONet(eqx.Module):
    """R_φ(x, t): MLP [x, t] → ō ∈ R⁶ → Gram–Schmidt rotation (see the module docstring).

    Called as ``net(x, t)`` with points x (N, 3) and one scalar time t; returns rotations (N, 3, 3).
    The parameters' dtype is chosen at construction (float32 by default); outputs follow JAX type
    promotion of inputs and parameters.
    """

    mlp: eqx.nn.MLP
    out_scale: float = eqx.field(static=True, default=DEFAULT_OUT_SCALE)

    def __init__(
        self,
        key: PRNGKeyArray,
        width: int = DEFAULT_GSO_WIDTH,
        depth: int = DEFAULT_GSO_DEPTH,
        dtype=jnp.float32,
        out_scale: float = DEFAULT_OUT_SCALE,
    ):
        self.mlp = eqx.nn.MLP(
            in_size=4, out_size=6, width_size=width, depth=depth, activation=jax.nn.gelu, dtype=dtype, key=key
        )
        self.out_scale = float(out_scale)

    def codes(self, x: Float[Array, "N 3"], t: Float[Array, ""] | float) -> Float[Array, "N 6"]:
        """ō = s · MLP([x, t]) + (1, 0, 0, 0, 1, 0), (N, 6)."""
        tt = jnp.broadcast_to(jnp.asarray(t, dtype=x.dtype), x.shape[:-1] + (1,))
        o = jax.vmap(self.mlp)(jnp.concatenate([x, tt], axis=-1))
        return self.out_scale * o + jnp.asarray(IDENTITY_6D, dtype=o.dtype)

    def __call__(self, x: Float[Array, "N 3"], t: Float[Array, ""] | float) -> Float[Array, "N 3 3"]:
        """Rotations (N, 3, 3) at points x (N, 3) and time t (scalar)."""
        return rotation_from_6d(self.codes(x, t))

    def lipschitz_bound(self) -> Float[Array, ""]:
        """Π_ℓ ‖W_ℓ‖_∞ (largest absolute row sum per layer), times ``out_scale``."""
        bound = jnp.asarray(self.out_scale, dtype=self.mlp.layers[0].weight.dtype)
        for layer in self.mlp.layers:
            bound = bound * jnp.max(jnp.sum(jnp.abs(layer.weight), axis=1))
        return bound
