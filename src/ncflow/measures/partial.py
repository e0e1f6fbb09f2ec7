"""The partial form of a surface measure: its Varifold or Normal Cycle restricted by a weight on its vertices
(docs/scans.md "Partial targets").

A scan shows part of a shape. Compared whole, the source's parts the scan does not show are pulled onto
what it shows, and the scan's cut borders — its holes' rims, the silhouette of a single view — look to a
Normal Cycle like the shape's own boundary (a sharp rim: a border edge has one face, ν_e = ±n). The partial
form keeps of each measure the part both shapes have: with a weight ω_v ∈ [0, 1] per vertex, every
generalised point p of the measure (a face's Dirac in a Varifold; an edge's, or a boundary vertex's, in a
Normal Cycle) carries the least weight of the vertices it lies on,

    X_ω = Σ_p ω_p w_p δ_{c_p},   ω_f = min_{v ∈ f} ω_v,   ω_e = min(ω_a, ω_b),   ω_v (boundary vertex v),

and the data term is d(X_ω, Y_ω') = ⟨X_ω, X_ω⟩ + ⟨Y_ω', Y_ω'⟩ − 2⟨X_ω, Y_ω'⟩ (paper Eq. 10 / 14 on the
restricted measures). On the source ω says what the target shows (0 on the far side of a single view, in
a hole): those parts then carry no mass and follow the skeleton and the regularisers alone. On the target ω
is 0 on the cut borders: the ring of faces and edges along a cut (whose edges would read as a rim) and the
cut's boundary-vertex terms are left out. ω ≡ 1 gives the measure unchanged. The weights are constants of
the data term (no gradient flows to them).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from ncflow.geometry.topology import Topology
from ncflow.measures.normal_cycles import NormalCycle
from ncflow.measures.varifold import Varifold


def restrict_varifold(x: Varifold, faces: Int[np.ndarray, "F 3"], vertex_weights: Float[ArrayLike, " V"]) -> Varifold:
    """The Varifold ``x`` of a mesh with faces ``faces`` restricted by ``vertex_weights``: face f's Dirac
    weighed by min over its vertices of ω.
    """
    w = jnp.asarray(vertex_weights, x.weights.dtype)
    omega = jnp.min(w[jnp.asarray(faces)], axis=1)
    return Varifold(centers=x.centers, normals=x.normals, weights=x.weights * omega)


def restrict_normal_cycle(x: NormalCycle, topology: Topology, vertex_weights: Float[ArrayLike, " V"]) -> NormalCycle:
    """The Normal Cycle ``x`` of a mesh with edge tables ``topology`` restricted by ``vertex_weights``: an
    edge's point weighed by the smaller ω of its ends, a boundary vertex's by its own.
    """
    w = jnp.asarray(vertex_weights, x.weights.dtype)
    edges = np.asarray(topology.edges)
    omega = jnp.minimum(w[edges[:, 0]], w[edges[:, 1]])
    if topology.has_boundary:
        omega = jnp.concatenate([omega, w[np.asarray(topology.boundary_vertices)]])
    return NormalCycle(centers=x.centers, weights=x.weights * omega[:, None])


def restrict(x: Varifold | NormalCycle, topology: Topology, vertex_weights: Float[ArrayLike, " V"]):
    """:func:`restrict_varifold` or :func:`restrict_normal_cycle`, by the type of ``x``."""
    if isinstance(x, Varifold):
        return restrict_varifold(x, topology.faces, vertex_weights)
    if isinstance(x, NormalCycle):
        return restrict_normal_cycle(x, topology, vertex_weights)
    raise TypeError(f"no partial form of {type(x).__name__}")


VIEW_STRENGTH = 0.2
"""A target whose area-weighted mean unit normal is longer than this is taken for a view from one side
(a closed surface's is 0; half a sphere's 0.5)."""


def facing_weights(normals: Float[Array, "N 3"], y: Varifold) -> Float[Array, " N"]:
    """Back-face weights of Diracs with unit ``normals`` against a target Varifold ``y`` seen from one side.

    A single view shows the surface that faces its camera: its normals lean towards the direction
    c = Σ_j b_j n_j / Σ_j b_j. When |c| > :data:`VIEW_STRENGTH` a Dirac weighs h((n · ĉ + 0.4) / 0.4)
    (h the smoothstep: 0 facing away from the camera, 1 facing it, a ramp across grazing angles);
    otherwise (a closed or nearly closed target) every weight is 1. Differentiable in ``normals``.
    """
    total = jnp.maximum(jnp.sum(y.weights), 1e-30)
    c = jnp.sum(y.weights[:, None] * y.normals, axis=0) / total
    strength = jnp.linalg.norm(c)
    u = jnp.clip((normals @ (c / jnp.maximum(strength, 1e-30)) + 0.4) / 0.4, 0.0, 1.0)
    return jnp.where(strength > VIEW_STRENGTH, u * u * (3.0 - 2.0 * u), 1.0)
