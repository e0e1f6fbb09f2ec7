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

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from ncflow.geometry.topology import Topology
from ncflow.measures.normal_cycles import NormalCycle
from ncflow.measures.varifold import Varifold


def restrict_varifold(x: Varifold, faces: Int[np.ndarray, "F 3"], vertex_weights: Float[ArrayLike, " V"]) -> Varifold:
    """The Varifold ``x`` of a mesh with faces ``faces`` restricted by ``vertex_weights``: face f's Diracs
    (one, or a quadrature's, face-major: :func:`ncflow.measures.varifold.varifold`) weighed by min over
    its vertices of ω.
    """
    w = jnp.asarray(vertex_weights, x.weights.dtype)
    omega = jnp.min(w[jnp.asarray(faces)], axis=1)
    omega = jnp.repeat(omega, x.weights.shape[0] // omega.shape[0])
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
    c, strength = view_direction(y)
    u = jnp.clip((normals @ c + 0.4) / 0.4, 0.0, 1.0)
    return jnp.where(strength > VIEW_STRENGTH, u * u * (3.0 - 2.0 * u), 1.0)


def view_strength(y: Varifold) -> Float[Array, ""]:
    """The length of ``y``'s area-weighted mean unit normal: 0 for a closed surface, 0.5 for half a sphere; a
    view from one side when over :data:`VIEW_STRENGTH`.
    """
    return jnp.linalg.norm(_mean_normal(y)[0])


def _mean_normal(y: Varifold):
    """(c, Σ b_j): ``y``'s area-weighted mean unit normal and its total weight."""
    total = jnp.maximum(jnp.sum(y.weights), 1e-30)
    return jnp.sum(y.weights[:, None] * y.normals, axis=0) / total, total


def view_direction(y: Varifold) -> tuple[Float[Array, " 3"], Float[Array, ""]]:
    """The unit camera direction ĉ of a target Varifold ``y`` seen from one side, and its
    :func:`view_strength` |c| (c its area-weighted mean unit normal).

    A depth camera sees the faces that face it: ĉ maximises Σ_j b_j log s(8 n_j · ĉ) (s the logistic
    function; every normal on the camera's side, the grazing ones at the silhouette included), 30 steps of
    ascent from c / |c|. On the humanoid's three views ĉ is 4–5° from the true camera direction, c 9–14°.
    """
    c, total = _mean_normal(y)
    strength = jnp.linalg.norm(c)

    def step(_, d):
        g = jnp.sum((y.weights * jax.nn.sigmoid(-8.0 * (y.normals @ d)))[:, None] * y.normals, axis=0) / total
        d = d + 2.0 * g
        return d / jnp.maximum(jnp.linalg.norm(d), 1e-30)

    return jax.lax.fori_loop(0, 30, step, c / jnp.maximum(strength, 1e-30)), strength


def occlusion_cover(
    points: Float[Array, "N 3"],
    occluders: Float[Array, "M 3"],
    present: Float[Array, " M"],
    direction: Float[Array, " 3"],
    spacing: Float[ArrayLike, ""],
) -> Float[Array, " N"]:
    """How much of the surface samples ``occluders`` (``present`` 1, padding 0) lies in front of each of
    ``points`` seen along ``direction`` (towards the camera): Σ_j exp(−|P(x_j − x_i)|² / r²) s((z_j − z_i − m) / w),
    P the projection across the direction, z the depth along it, s the logistic function, r = 1.5 h,
    m = 2.5 h, w = 0.5 h for a sample spacing h. Samples of the same sheet (within m in depth) do not occlude;
    one sample squarely in front gives a cover of about 1. Differentiable; written by hand (a soft z-buffer
    over a few hundred samples: no library renders a point set differentiably on the CPU).
    """
    h = jnp.asarray(spacing, points.dtype)
    z_i, z_j = points @ direction, occluders @ direction
    flat_i = points - z_i[:, None] * direction
    flat_j = occluders - z_j[:, None] * direction
    d2 = jnp.sum(flat_i**2, axis=1)[:, None] + jnp.sum(flat_j**2, axis=1)[None, :] - 2.0 * flat_i @ flat_j.T
    ahead = jax.nn.sigmoid((z_j[None, :] - z_i[:, None] - 2.5 * h) / (0.5 * h))
    return jnp.sum(jnp.exp(-d2 / (1.5 * h) ** 2) * ahead * present[None, :], axis=1)
