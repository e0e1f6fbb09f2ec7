"""Oriented varifolds of triangle meshes (paper §3.1; DESIGN.md "Varifold").

A mesh is the sum of Dirac masses at its face centres c_f carrying the unit normal n_f and the
area a_f. With the kernel

    k((c, n), (c', n')) = exp(−‖c − c'‖² / (2σ²)) · exp(n·n' / (2σ_n²)),

the inner product is ⟨X, Y⟩ = Σ_f Σ_g a_f b_g k(·,·) and the metric d(X, Y) = ⟨X,X⟩ + ⟨Y,Y⟩ − 2⟨X,Y⟩.
No π or other constant factor (as in the authors' release).

Implementation: for unit or non-unit n, exp(γ_n n·n') = e^{γ_n‖n‖²/2} e^{γ_n‖n'‖²/2} e^{−γ_n‖n−n'‖²/2},
so the sum is a Gaussian kernel sum (:func:`ncflow.measures.kernels.kernel_sum`) over the 6-D
features [c/(√2σ), n/(2σ_n)] with weights a·e^{‖n‖²/(4σ_n²)}.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from ncflow.measures.kernels import DEFAULT_BLOCK, kernel_self_sum, kernel_sum
from ncflow.measures.normal_cycles import Scale, safe_normalize


class Varifold(eqx.Module):
    """Weighted oriented Diracs: centres (N, 3), normals (N, 3), weights (N,).

    From a mesh the weights are face areas and the normals unit; a compressed varifold
    (:func:`ncflow.measures.compress_varifold`) has representative faces' centres and normals
    with fitted weights β.
    """

    centers: Float[Array, "N 3"]
    normals: Float[Array, "N 3"]
    weights: Float[Array, " N"]

    @property
    def size(self) -> int:
        return int(self.centers.shape[0])


def varifold(vertices: Float[ArrayLike, "V 3"], faces: Int[np.ndarray, "F 3"]) -> Varifold:
    """The varifold of a triangle mesh: face centres, unit normals and areas (differentiable in vertices)."""
    v = jnp.asarray(vertices)
    tri = v[jnp.asarray(faces)]
    cross = jnp.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals, norm = safe_normalize(cross)
    return Varifold(centers=tri.mean(axis=1), normals=normals, weights=0.5 * norm)


def varifold_features(
    x: Varifold, sigma: Scale, sigma_normal: Scale
) -> tuple[Float[Array, "N 6"], Float[Array, "N 1"]]:
    """Scaled 6-D features and weights for which the varifold kernel is exp(−‖z − z'‖²)."""
    z = jnp.concatenate([x.centers / (math.sqrt(2.0) * sigma), x.normals / (2.0 * sigma_normal)], axis=1)
    sq = jnp.sum(x.normals * x.normals, axis=1)
    w = x.weights * jnp.exp(sq / (4.0 * sigma_normal**2))
    return z, w[:, None]


def varifold_inner(
    x: Varifold, y: Varifold, sigma: Scale, sigma_normal: Scale = 0.5, block: tuple[int, int] = DEFAULT_BLOCK
) -> Float[Array, ""]:
    """⟨X, Y⟩ = Σ_ij a_i b_j exp(−‖c_i − c_j‖²/(2σ²)) exp(n_i·n_j/(2σ_n²))."""
    if x is y:
        return kernel_self_sum(*varifold_features(x, sigma, sigma_normal), block=block)
    return kernel_sum(
        *varifold_features(x, sigma, sigma_normal), *varifold_features(y, sigma, sigma_normal), block=block
    )


def varifold_distance(
    x: Varifold, y: Varifold, sigma: Scale, sigma_normal: Scale = 0.5, block: tuple[int, int] = DEFAULT_BLOCK
) -> Float[Array, ""]:
    """d(X, Y) = ⟨X,X⟩ + ⟨Y,Y⟩ − 2⟨X,Y⟩ (all three terms evaluated)."""
    return (
        varifold_inner(x, x, sigma, sigma_normal, block)
        + varifold_inner(y, y, sigma, sigma_normal, block)
        - 2.0 * varifold_inner(x, y, sigma, sigma_normal, block)
    )
