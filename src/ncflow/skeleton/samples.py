"""Random samples on and around the bones of a skeleton (paper §4.3, Eq. 20–21).

DESIGN.md "Bone samples"; reference notes §6.1.

Bone b = (a → c) at rest, length L = ‖P_c − P_a‖, unit axis e₁, radius R_b = ρ_b L. Of the n
samples per bone, n_axis = max(2, ⌊f n⌋) (f = 0.2) lie on the axis at evenly spaced heights
z ∈ [0.1 L, 0.9 L]; the others are uniform in the cylinder of radius R_b over the same axial
range (z ~ U, r = R_b √U, angle ~ U[0, 2π)). The samples are drawn afresh from a JAX key on every
call; they move with their bone's rigid motion (:func:`ncflow.skeleton.bone_motions` and
:func:`ncflow.skeleton.move_bone_points`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from ncflow.geometry.skeleton import Skeleton

DEFAULT_SAMPLES_PER_BONE = 50
DEFAULT_RADIUS = 0.1
DEFAULT_AXIAL_RANGE = (0.1, 0.9)


class BoneSamples(NamedTuple):
    """Bone samples at rest.

    Attributes:
        points: (B, n, 3) rest positions; row b belongs to bone b (ending at joint b + 1).
        on_axis: (n,) True for the columns on the bone axis (the first ``n_axis``).
    """

    points: Float[Array, "B n 3"]
    on_axis: Bool[np.ndarray, " n"]

    def flat(self) -> Float[Array, "Bn 3"]:
        """(B·n, 3), bone-major."""
        return self.points.reshape(-1, 3)


def n_axis_samples(n: int, axis_fraction: float = 0.2) -> int:
    """Number of axis samples among n per bone: max(2, ⌊f n⌋), at most n."""
    return int(min(n, max(2, int(np.floor(axis_fraction * n + 1e-9)))))


def bone_axes(skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per bone: start P_a (B, 3), length L (B,), and an orthonormal frame e₁ (along the bone), e₂, e₃."""
    start = skeleton.positions[skeleton.parents[1:]]
    vec = skeleton.positions[1:] - start
    length = np.linalg.norm(vec, axis=1)
    e1 = vec / length[:, None]
    helper = np.eye(3)[np.argmin(np.abs(e1), axis=1)]  # coordinate axis least aligned with e₁
    e2 = np.cross(e1, helper)
    e2 /= np.linalg.norm(e2, axis=1, keepdims=True)
    e3 = np.cross(e1, e2)
    return start, length, e1, e2, e3


def sample_bones(
    skeleton: Skeleton,
    key: jax.Array,
    n: int = DEFAULT_SAMPLES_PER_BONE,
    *,
    radius: float | Float[ArrayLike, " B"] | None = None,
    axis_fraction: float = 0.2,
    axial_range: tuple[float, float] | Float[ArrayLike, "B 2"] = DEFAULT_AXIAL_RANGE,
    dtype=None,
) -> BoneSamples:
    """Draw n samples per bone (paper Eq. 21's spatial samples).

    Args:
        skeleton: the rest skeleton.
        key: a ``jax.random`` key; the same key gives the same samples.
        n: samples per bone (default 50).
        radius: radius factor ρ (cylinder radius ρ·L): a float for all bones, (B,) per bone, or
            None for the skeleton's per-bone values with 0.1 as the default.
        axis_fraction: share of samples on the axis (default 0.2; at least 2).
        axial_range: range of z / L (default 10 %–90 %), for all bones or (B, 2) one per bone
            (:func:`ncflow.skeleton.checks.inside_axial_ranges`: the part of each bone inside its mesh).
        dtype: float dtype of the result (default: JAX's default float).

    Returns:
        :class:`BoneSamples` with points (B, n, 3); the first ``n_axis`` of each bone on its axis.
    """
    if n < 2:
        raise ValueError(f"need at least 2 samples per bone, got {n}")
    dtype = dtype or jnp.result_type(float)
    ranges = np.broadcast_to(np.asarray(axial_range, np.float64), (skeleton.n_bones, 2))
    if not np.all((0.0 <= ranges[:, 0]) & (ranges[:, 0] <= ranges[:, 1]) & (ranges[:, 1] <= 1.0)):
        raise ValueError(f"axial_range must satisfy 0 <= lo <= hi <= 1, got {axial_range}")
    lo, hi = (jnp.asarray(ranges[:, i, None], dtype) for i in (0, 1))  # (B, 1)
    rho = skeleton.bone_radii(DEFAULT_RADIUS) if radius is None else radius
    rho = jnp.broadcast_to(jnp.asarray(rho, dtype), (skeleton.n_bones,))
    start, length, e1, e2, e3 = (jnp.asarray(x, dtype) for x in bone_axes(skeleton))
    n_axis = n_axis_samples(n, axis_fraction)
    n_rand = n - n_axis
    nb = skeleton.n_bones
    k_z, k_r, k_a = jax.random.split(key, 3)
    z_axis = lo + (hi - lo) * jnp.linspace(0.0, 1.0, n_axis, dtype=dtype)
    z_rand = lo + (hi - lo) * jax.random.uniform(k_z, (nb, n_rand), dtype)
    r_rand = jnp.sqrt(jax.random.uniform(k_r, (nb, n_rand), dtype)) * rho[:, None]
    ang = jax.random.uniform(k_a, (nb, n_rand), dtype, 0.0, 2.0 * np.pi)
    z = jnp.concatenate([z_axis, z_rand], axis=1) * length[:, None]  # (B, n)
    r = jnp.concatenate([jnp.zeros((nb, n_axis), dtype), r_rand * length[:, None]], axis=1)
    a = jnp.concatenate([jnp.zeros((nb, n_axis), dtype), ang], axis=1)
    points = (
        start[:, None, :]
        + z[..., None] * e1[:, None, :]
        + (r * jnp.cos(a))[..., None] * e2[:, None, :]
        + (r * jnp.sin(a))[..., None] * e3[:, None, :]
    )
    return BoneSamples(points, np.arange(n) < n_axis)
