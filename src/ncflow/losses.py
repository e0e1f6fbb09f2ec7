"""Distortion terms and bone-constraint values of the matching objective: the only place they are written.

Paper §4.3–4.5, Eqs. 21–22; DESIGN.md "Soft tissue", "Constraints (MDMM)"; reference-notes §7.3,
§7.4, §9.

All terms take *flowed grid states* as produced by :func:`ncflow.flow.integrate` — arrays
(T, N, 3) with states[k] the points at t_k = k/(T−1), states[0] the start — and return scalars
(or per-bone vectors) in the dtype of the inputs.

* Soft tissue, L_soft (:func:`tissue_distortion`): every tissue sample p is flowed together with
  p + δe_x, p + δe_y, p + δe_z (:func:`tissue_stencil` builds the 4n points,
  :func:`split_stencil` splits the flowed result). With D_m(t) = x(p + δe_m, t) − x(p, t),
  D̂_m = D_m/‖D_m‖,

      ℓ(p, t) = Σ_{m,m'} (D̂_m·D̂_m' − [m = m'])² + Σ_m (δ − ‖D_m‖)²/δ²,

  L_soft = mean over t_1..t_{T−1} and samples. It vanishes exactly for rigid motions and
  penalises shear and any stretch (also uniform scaling: 3(1 − s)² for scale s). The release
  rotates D by the GSO rotation first; the expression is rotation-invariant, so we omit that
  (reference-notes §7.4), and we guard the normalisation instead of adding 1e-8 to D.
* Surface, L_surf (:func:`surface_distortion`, :func:`arap_energy`): ARAP edge energy against a
  rotation predicted per point by the GSO-Net (:class:`ncflow.flow.GSONet`), over source edges
  (i, j) and t_1..t_{T−1}:

      e_ij(t) = ‖(x_i(t) − x_j(t)) − R_i(t)(x_i − x_j)‖²,   R_i(t) = GSO(x_i(t), t),

  L_surf = mean over edges and times of ½(e_ij + e_ji). Uniform weights, no Procrustes fit
  (reference-notes §7.3). The release uses every edge every step; the paper draws 500 surface
  samples per epoch — :func:`sample_edges` + :func:`edge_points` give the edge-subset version.
* Bone constraints g_k (:func:`bone_constraints`; paper Eq. 21): mean squared distance of the
  flowed bone samples to their rigid reference (:func:`ncflow.skeleton.rigid_reference`), at the
  end time (g^EP) and over the interior grid times (g^TR). We use the **full squared 3-D distance**
  ‖s − s̄‖²; the release averages over the three coordinates as well (its value is 1/3 of ours),
  so a tolerance ε transferred from the release must be multiplied by 3 (release ε = 1e-4 ↔ 3e-4
  here).
* Leash, L_leash (:func:`leash_energy`; not in the paper): the mean squared Flow-Net velocity at
  the flowed bone samples over ε (:func:`ncflow.matcher.objective.leash_term` evaluates the network).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int, PRNGKeyArray

from ncflow.flow.integrate import time_grid
from ncflow.jit.buckets import draw_rows
from ncflow.measures.normal_cycles import safe_normalize

DEFAULT_TISSUE_DELTA = 0.01
"""Finite-difference step δ of the tissue stencil, in normalised units (the release's value)."""


# ----------------------------------------------------------------------------------------------
# soft tissue


def tissue_stencil(samples: Float[ArrayLike, "n 3"], delta: float = DEFAULT_TISSUE_DELTA) -> Float[Array, "4*n 3"]:
    """The 4n points to flow for n tissue samples: rows [p; p + δe_x; p + δe_y; p + δe_z].

    Block layout: rows 0..n−1 are the samples, rows (m+1)n..(m+2)n−1 the samples shifted along
    axis m. :func:`split_stencil` undoes it.
    """
    p = jnp.asarray(samples)
    shifts = delta * jnp.eye(3, dtype=p.dtype)
    return jnp.concatenate([p[None], p[None] + shifts[:, None, :]], axis=0).reshape(-1, 3)


def split_stencil(
    states: Float[ArrayLike, "T four_n 3"],
) -> tuple[Float[Array, "T four_n//4 3"], Float[Array, "T four_n//4 3 3"]]:
    """Flowed stencil states → (centres x(p, t) (T, n, 3), frames D (T, n, 3, 3)).

    frames[k, i, m] = x(p_i + δe_m, t_k) − x(p_i, t_k) (row m is D_m).
    """
    states = jnp.asarray(states)
    t, four_n, _ = states.shape
    s = states.reshape(t, 4, four_n // 4, 3)
    centres = s[:, 0]
    frames = jnp.moveaxis(s[:, 1:] - centres[:, None], 1, 2)  # (T, n, 3, 3)
    return centres, frames


def tissue_frame_energy(
    frames: Float[ArrayLike, "*batch 3 3"], delta: float = DEFAULT_TISSUE_DELTA
) -> Float[Array, "*batch"]:
    """ℓ = Σ_{m,m'} (D̂_m·D̂_m' − [m = m'])² + Σ_m (δ − ‖D_m‖)²/δ² per frame (rows D_m)."""
    unit, norm = safe_normalize(frames)
    gram = jnp.einsum("...mi,...ni->...mn", unit, unit)
    ortho = jnp.sum((gram - jnp.eye(3, dtype=gram.dtype)) ** 2, axis=(-2, -1))
    stretch = jnp.sum((delta - norm) ** 2, axis=-1) / (delta * delta)
    return ortho + stretch


def tissue_distortion(states: Float[ArrayLike, "T four_n 3"], delta: float = DEFAULT_TISSUE_DELTA) -> Float[Array, ""]:
    """L_soft: mean of :func:`tissue_frame_energy` over grid times t_1..t_{T−1} and samples.

    Args:
        states: flowed stencil points (T, 4n, 3), T ≥ 2, rows laid out by :func:`tissue_stencil`.
        delta: the stencil's δ (the same value used to build it).
    """
    _, frames = split_stencil(states)
    return jnp.mean(tissue_frame_energy(frames[1:], delta))


def leash_energy(velocities: Float[ArrayLike, "T n 3"], eps: float) -> Float[Array, ""]:
    """L_leash = mean over times and points of ‖r‖² / ε for Flow-Net velocities r (T, n, 3) at the bone samples."""
    r = jnp.asarray(velocities)
    return jnp.mean(jnp.sum(r * r, axis=-1)) / eps


# ----------------------------------------------------------------------------------------------
# surface (ARAP against the GSO rotation)


def arap_energy(
    rest: Float[Array, "V 3"],
    edges: Int[ArrayLike, "E 2"],
    states: Float[Array, "K V 3"],
    rotations: Float[Array, "K V 3 3"],
) -> Float[Array, ""]:
    """Mean over K times and E edges of ½(e_ij + e_ji), e_ij = ‖(x_i − x_j)(t) − R_i(t)(x_i − x_j)‖².

    Args:
        rest: rest positions x (V, 3) (the source vertices, or the points of :func:`edge_points`).
        edges: (E, 2) vertex pairs (i, j).
        states: positions x(t) at K times (K, V, 3) — pass grid states [1:] for L_surf.
        rotations: R(t) per time and point (K, V, 3, 3), e.g. from the GSO-Net.
    """
    edges = jnp.asarray(edges)
    i, j = edges[:, 0], edges[:, 1]
    rest_edge = rest[i] - rest[j]  # (E, 3)
    cur = states[:, i] - states[:, j]  # (K, E, 3)
    ri = jnp.einsum("keab,eb->kea", rotations[:, i], rest_edge)
    rj = jnp.einsum("keab,eb->kea", rotations[:, j], rest_edge)
    e_ij = jnp.sum((cur - ri) ** 2, axis=-1)
    e_ji = jnp.sum((cur - rj) ** 2, axis=-1)  # ‖(x_j − x_i)(t) − R_j(x_j − x_i)‖² = same with signs flipped
    return jnp.mean(0.5 * (e_ij + e_ji))


def surface_distortion(
    gso,
    rest: Float[ArrayLike, "V 3"],
    edges: Int[ArrayLike, "E 2"],
    states: Float[ArrayLike, "T V 3"],
) -> Float[Array, ""]:
    """L_surf: :func:`arap_energy` on grid times t_1..t_{T−1} with R_i(t_k) = gso(x_i(t_k), t_k).

    Args:
        gso: a rotation predictor ``gso(x (N, 3), t) -> (N, 3, 3)`` (:class:`ncflow.flow.GSONet`).
        rest: (V, 3) rest positions of the points.
        edges: (E, 2) index pairs (i, j) into the V points, the edges whose distortion is measured.
        states: (T, V, 3) flowed states of the points on the time grid t_0..t_{T−1}, T ≥ 2.
    """
    states = jnp.asarray(states)
    ts = time_grid(states.shape[0], states.dtype)
    later = states[1:]
    rotations = jax.vmap(gso)(later, ts[1:])  # (T−1, V, 3, 3)
    return arap_energy(jnp.asarray(rest, states.dtype), edges, later, rotations.astype(states.dtype))


def sample_edges(
    key: PRNGKeyArray, edges: Int[ArrayLike, "E 2"], n: int, valid: Bool[ArrayLike, " E"] | None = None
) -> Int[Array, "n 2"]:
    """N of the E edges drawn uniformly without replacement (all E in random order if n ≥ E); with
    ``valid`` (edges padded to a size bucket) only real edges (:func:`ncflow.jit.buckets.draw_rows`).
    """
    edges = jnp.asarray(edges)
    return edges[draw_rows(key, edges.shape[0], n, valid)]


def edge_points(
    vertices: Float[ArrayLike, "V 3"], edges: Int[ArrayLike, "n 2"]
) -> tuple[Float[Array, "2*n 3"], Int[np.ndarray, "n 2"]]:
    """Points to flow for an edge subset: (rows [x_i of every edge; x_j of every edge] (2n, 3),
    local edges [[k, n + k]] (n, 2)). Pass both to :func:`surface_distortion` with the flowed
    points' states; a vertex shared by several edges is flowed once per edge end (trajectories are
    independent, so the result equals the full-mesh energy restricted to these edges).
    """
    vertices = jnp.asarray(vertices)
    edges = jnp.asarray(edges)
    n = edges.shape[0]
    points = jnp.concatenate([vertices[edges[:, 0]], vertices[edges[:, 1]]], axis=0)
    local = np.stack([np.arange(n), n + np.arange(n)], axis=1)
    return points, local


# ----------------------------------------------------------------------------------------------
# bone constraints (paper Eq. 21)


def _check_bone_shapes(flowed, reference) -> None:
    if flowed.ndim != 4 or flowed.shape[-1] != 3 or flowed.shape != reference.shape:
        raise ValueError(
            f"bone constraints need flowed and reference arrays of equal shape (T, B, n, 3), got "
            f"{tuple(flowed.shape)} and {tuple(reference.shape)}"
        )


def bone_endpoint_constraint(
    flowed: Float[ArrayLike, " ..."], reference: Float[ArrayLike, " ..."]
) -> Float[Array, " B"]:
    """g_k^EP = mean over bone k's samples of ‖s(1) − s̄(1)‖² (full squared 3-D distance), (B,)."""
    flowed, reference = jnp.asarray(flowed), jnp.asarray(reference)
    _check_bone_shapes(flowed, reference)
    return jnp.mean(jnp.sum((flowed[-1] - reference[-1]) ** 2, axis=-1), axis=-1)


def bone_trajectory_constraint(
    flowed: Float[ArrayLike, " ..."], reference: Float[ArrayLike, " ..."]
) -> Float[Array, " B"]:
    """g_k^TR = mean over interior grid times t_1..t_{T−2} and bone k's samples of ‖s(t) − s̄(t)‖², (B,).

    With T = 2 there is no interior time and the value is 0.
    """
    flowed, reference = jnp.asarray(flowed), jnp.asarray(reference)
    _check_bone_shapes(flowed, reference)
    if flowed.shape[0] < 3:
        return jnp.zeros(flowed.shape[1], dtype=flowed.dtype)
    d2 = jnp.sum((flowed[1:-1] - reference[1:-1]) ** 2, axis=-1)  # (T−2, B, n)
    return jnp.mean(d2, axis=(0, 2))


def bone_constraints(
    flowed: Float[ArrayLike, " ..."], reference: Float[ArrayLike, " ..."]
) -> tuple[Float[Array, " B"], Float[Array, " B"]]:
    """(g^EP, g^TR) per bone — see :func:`bone_endpoint_constraint`, :func:`bone_trajectory_constraint`.

    Args:
        flowed: bone samples moved by the flow, grid states (T, B, n, 3).
        reference: their rigid reference at the same times (T, B, n, 3),
            e.g. :func:`ncflow.skeleton.rigid_reference` on the grid.
    """
    return bone_endpoint_constraint(flowed, reference), bone_trajectory_constraint(flowed, reference)
