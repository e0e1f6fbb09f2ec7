"""Normal Cycles of triangle meshes (paper §3.2, §4.2, Algorithm 1, Appendix A; DESIGN.md "Normal Cycles").

Every unique edge e = (a, b), a < b, is a generalised point at its midpoint c_e carrying the
15-vector w_e = ‖φ_e‖ (φ̂_e, 0) ∧ (0, ν_e) ∈ Λ²R⁶, with φ_e = x_b − x_a and ν_e the sum over the
incident faces of ±(unit face normal), + when the face runs a → b. Only 9 of its 15 coordinates
are non-zero and they form the outer product φ_e ⊗ ν_e, so ⟨w_e, w_e'⟩ = (φ_e·φ_e')(ν_e·ν_e'); we
store those 9 numbers. Open surfaces add, at each boundary vertex v, a point carrying
u_v = Σ of the unit boundary-edge directions pointing *away from v* (the paper's outward
orientation, independent of vertex numbering, so meshes of different connectivity compare
consistently); it lives in 3 further coordinates orthogonal to the edge terms. A mesh's
representation is therefore centres (E + Bv, 3) and weights (E + Bv, 12) with rows
[φ⊗ν, 0, 0, 0] for edges and [0, …, 0, u] for boundary vertices.

With the spatial kernel κ(c, c') = exp(−‖c − c'‖²/(2σ²)),

    ⟨X, Y⟩ = Σ_{p ∈ X} Σ_{q ∈ Y} κ(c_p, c_q) ⟨w_p, w_q⟩,   d(X, Y) = ⟨X,X⟩ + ⟨Y,Y⟩ − 2⟨X,Y⟩.

The paper's π²/4 factor (Eq. 14) is omitted, as in the authors' release: it scales d uniformly.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ncflow.geometry.topology import Topology
from ncflow.measures.kernels import DEFAULT_BLOCK, kernel_self_sum, kernel_sum

Scale = float | Float[Array, ""]  # a kernel scale: a number, or a traced scalar inside jit


def safe_normalize(v: Float[ArrayLike, "... 3"]) -> tuple[Float[Array, "... 3"], Float[Array, ...]]:
    """(v/‖v‖, ‖v‖), with (0, 0) for vectors shorter than ~1e-18 (float64) / 1e-15 (float32); NaN-free gradients."""
    sq = jnp.sum(v * v, axis=-1)
    tiny = jnp.asarray(1e-36 if v.dtype == jnp.float64 else 1e-30, v.dtype)
    ok = sq > tiny
    norm = jnp.sqrt(jnp.where(ok, sq, 1.0))
    unit = jnp.where(ok[..., None], v / norm[..., None], 0.0)
    return unit, jnp.where(ok, norm, 0.0)


class NormalCycle(eqx.Module):
    """Generalised points of a Normal Cycle: centres (N, 3) and weights (N, 12) (see module docstring)."""

    centers: Float[Array, "N 3"]
    weights: Float[Array, "N 12"]

    @property
    def size(self) -> int:
        return int(self.centers.shape[0])


def normal_cycle(vertices: Float[ArrayLike, "V 3"], topology: Topology) -> NormalCycle:
    """The Normal Cycle representation of a mesh (Algorithm 1), differentiable in the vertices.

    Args:
        vertices: (V, 3) positions.
        topology: the mesh's edge tables (:func:`ncflow.mesh.mesh_topology`), built once.
    """
    v = jnp.asarray(vertices)
    edges = np.asarray(topology.edges)
    faces_of = np.asarray(topology.edge_faces)
    signs = np.asarray(topology.edge_signs)
    n_faces = int(topology.faces.shape[0])
    tri = v[np.asarray(topology.faces)]
    normals, _ = safe_normalize(jnp.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]))
    normals = jnp.concatenate([normals, jnp.zeros((1, 3), v.dtype)])
    slot = np.where(faces_of < 0, n_faces, faces_of)
    nu = jnp.sum(signs[..., None].astype(v.dtype) * normals[slot], axis=1)
    phi = v[edges[:, 1]] - v[edges[:, 0]]
    edge_w = (phi[:, :, None] * nu[:, None, :]).reshape(-1, 9)
    centers = 0.5 * (v[edges[:, 0]] + v[edges[:, 1]])
    weights = jnp.concatenate([edge_w, jnp.zeros((edges.shape[0], 3), v.dtype)], axis=1)
    if topology.has_boundary:
        bv = np.asarray(topology.boundary_vertices)
        nb = np.asarray(topology.boundary_neighbors)
        valid = nb >= 0
        away, _ = safe_normalize(v[np.where(valid, nb, bv[:, None])] - v[bv][:, None, :])
        u = jnp.sum(jnp.where(valid[..., None], away, 0.0), axis=1)
        bw = jnp.concatenate([jnp.zeros((bv.size, 9), v.dtype), u], axis=1)
        centers = jnp.concatenate([centers, v[bv]])
        weights = jnp.concatenate([weights, bw])
    return NormalCycle(centers=centers, weights=weights)


def _nc_features(x: NormalCycle, sigma: Scale) -> tuple[Float[Array, "N 3"], Float[Array, "N 12"]]:
    return x.centers / (math.sqrt(2.0) * sigma), x.weights


def normal_cycle_inner(
    x: NormalCycle, y: NormalCycle, sigma: Scale, block: tuple[int, int] = DEFAULT_BLOCK
) -> Float[Array, ""]:
    """⟨X, Y⟩ = Σ_pq exp(−‖c_p − c_q‖²/(2σ²)) ⟨w_p, w_q⟩ (edge terms + boundary-vertex terms)."""
    if x is y:
        return kernel_self_sum(*_nc_features(x, sigma), block=block)
    return kernel_sum(*_nc_features(x, sigma), *_nc_features(y, sigma), block=block)


def normal_cycle_distance(
    x: NormalCycle, y: NormalCycle, sigma: Scale, block: tuple[int, int] = DEFAULT_BLOCK
) -> Float[Array, ""]:
    """d(X, Y) = ⟨X,X⟩ + ⟨Y,Y⟩ − 2⟨X,Y⟩ (all three terms evaluated)."""
    return (
        normal_cycle_inner(x, x, sigma, block)
        + normal_cycle_inner(y, y, sigma, block)
        - 2.0 * normal_cycle_inner(x, y, sigma, block)
    )
