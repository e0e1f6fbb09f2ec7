"""The correspondence of a match, from the flowed source and the target (DESIGN.md "Output contract").

* ``map_tgt_to_src`` (the map that is scored): each target vertex y_j is projected onto the
  *flowed* source surface (exact closest point); the foot point is written as (source face,
  barycentric coordinates). The flow keeps the connectivity, so the same (face, bary) names a point
  of the *rest* source: Σ_k bary_k · rest[faces[face, k]].
* ``p2p_tgt_to_src``: the vertex-level rounding of that map — the corner of the foot face with the
  largest barycentric weight (ties: the first corner in the face's order); intrinsic to the
  triangulation, it differs from the Euclidean-nearest corner only in obtuse triangles.
* ``p2p_src_to_tgt``: each flowed source vertex is projected onto the *target surface* and rounded
  the same way, so the rounding does not depend on how densely the target is sampled; without
  target faces the nearest target vertex is used.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import ResultError
from ncflow.geometry.barycentric import round_to_vertex
from ncflow.geometry.closest import closest_points_on_surface
from ncflow.io.arrays import check_finite

if TYPE_CHECKING:
    pass


def correspondence_maps(
    rest_source_vertices: Float[np.ndarray, "Vs 3"],
    source_faces: Int[np.ndarray, "Fs 3"],
    flowed_source_vertices: Float[np.ndarray, "Vs 3"],
    target_vertices: Float[np.ndarray, "Vt 3"],
    target_faces: Int[np.ndarray, "Ft 3"] | None = None,
) -> dict[str, np.ndarray]:
    """Dense correspondence between a flowed source and the target (see the module docstring).

    Args:
        rest_source_vertices: (Vs, 3) source vertices before the flow.
        source_faces: (Fs, 3) source triangles (shared by rest and flowed source).
        flowed_source_vertices: (Vs, 3) source vertices flowed to t = 1, in the target's frame.
        target_vertices: (Vt, 3) target vertices.
        target_faces: (Ft, 3) target triangles; when None, ``p2p_src_to_tgt`` is the nearest
            target vertex instead of the rounding of the surface projection.

    Returns:
        dict with
        ``map_face`` (Vt,) int64 and ``map_bary`` (Vt, 3) float64: the foot point of every target
        vertex on the flowed source, as (source face, barycentric coordinates);
        ``map_points`` (Vt, 3): that point on the rest source;
        ``dist_tgt_to_src`` (Vt,): distance of each target vertex to the flowed source surface;
        ``p2p_tgt_to_src`` (Vt,) int64: source vertex per target vertex;
        ``p2p_src_to_tgt`` (Vs,) int64: target vertex per source vertex;
        ``dist_src_to_tgt`` (Vs,): distance of each flowed source vertex to the target surface
        (to the nearest target vertex when ``target_faces`` is None).
    """
    from scipy.spatial import cKDTree

    rest = np.asarray(rest_source_vertices, dtype=np.float64)
    flowed = np.asarray(flowed_source_vertices, dtype=np.float64)
    sf = np.asarray(source_faces, dtype=np.int64)
    tv = np.asarray(target_vertices, dtype=np.float64)
    if rest.shape != flowed.shape or rest.ndim != 2 or rest.shape[1] != 3:
        raise ResultError(f"rest and flowed source vertices must both be (V, 3), got {rest.shape} and {flowed.shape}")
    check_finite("flowed source vertices", flowed)
    check_finite("target vertices", tv)
    dist_t, face, bary = closest_points_on_surface(tv, flowed, sf)
    out = {
        "map_face": face.astype(np.int64),
        "map_bary": bary,
        "map_points": np.einsum("nk,nkd->nd", bary, rest[sf[face]]),
        "dist_tgt_to_src": dist_t,
        "p2p_tgt_to_src": round_to_vertex(sf, face, bary),
    }
    if target_faces is None:
        dist_s, nearest = cKDTree(tv).query(flowed)
        out["p2p_src_to_tgt"] = np.asarray(nearest, dtype=np.int64)
    else:
        tf = np.asarray(target_faces, dtype=np.int64)
        dist_s, tface, tbary = closest_points_on_surface(flowed, tv, tf)
        out["p2p_src_to_tgt"] = round_to_vertex(tf, tface, tbary)
    out["dist_src_to_tgt"] = np.asarray(dist_s, dtype=np.float64)
    return out
