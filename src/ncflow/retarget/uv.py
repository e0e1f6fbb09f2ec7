"""Texture coordinates carried to the target through the correspondence, seams kept.

A source OBJ has face-varying UVs: one chart per source face corner, so a vertex on a seam has
several. Each target vertex reads the UV of its own source face's corners (one chart per target
point, never averaged across a seam); a target triangle whose corners land in different charts has
its minority corners re-expressed in the chart of its reference corner, through a nearby seam edge
(exact when the charts meet by a translation, rotation or scale) or by continuing the chart linearly
past its edge, so that no target triangle straddles a seam in UV space.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from jaxtyping import Float, Int

from ncflow.geometry.barycentric import surface_points

__all__ = ["SEAM_RATIO", "UVTransfer", "transfer_uv"]

SEAM_RATIO = 2.0
"""A target corner is across a UV seam from its face's reference corner when its own UV lies more
than this many times farther from the reference's UV than its UV in the reference's chart does."""


@dataclasses.dataclass(frozen=True, eq=False)
class UVTransfer:
    """Face-varying texture coordinates of the target.

    Attributes:
        uvs: (Vt + R, 2) the first Vt rows are the target vertices' own UVs (vertex j's is row j),
            the other R are corners re-expressed in a neighbouring corner's chart.
        uv_faces: (Ft, 3) per target face corner, a row of ``uvs``.
        n_seam_faces: target faces with a corner re-expressed (faces that would straddle a seam).
    """

    uvs: Float[np.ndarray, "T 2"]
    uv_faces: Int[np.ndarray, "Ft 3"]
    n_seam_faces: int


def _plane_barycentric(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(n, 3) barycentric coordinates of p projected onto the plane of (a, b, c), not clipped (NaN if degenerate)."""
    v0, v1, v2 = b - a, c - a, p - a
    d00, d01, d11 = (np.einsum("ij,ij->i", x, y) for x, y in ((v0, v0), (v0, v1), (v1, v1)))
    d20, d21 = np.einsum("ij,ij->i", v2, v0), np.einsum("ij,ij->i", v2, v1)
    denom = d00 * d11 - d01 * d01
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.where(denom > 1e-300, (d11 * d20 - d01 * d21) / denom, np.nan)
        w = np.where(denom > 1e-300, (d00 * d21 - d01 * d20) / denom, np.nan)
    return np.stack([1.0 - v - w, v, w], axis=1)


def transfer_uv(
    source_vertices: Float[np.ndarray, "Vs 3"],
    source_faces: Int[np.ndarray, "Fs 3"],
    uvs: Float[np.ndarray, "T 2"],
    uv_faces: Int[np.ndarray, "Fs 3"],
    face: Int[np.ndarray, " Vt"],
    bary: Float[np.ndarray, "Vt 3"],
    target_faces: Int[np.ndarray, "Ft 3"],
) -> UVTransfer:
    """Face-varying texture coordinates of the target, seams respected.

    One chart per target point: target vertex j takes Σ_k bary[j, k] · uv of corner k of its
    source face ``face[j]`` — the UVs of that one face, never averaged across a seam.

    No target triangle across a seam: in a target face, corner k is tested against each other
    corner r by re-expressing k's rest source point in r's chart — projected onto the plane of r's
    source face and mapped by that face's affine UV map (barycentrics not clipped, so the chart is
    continued linearly past its edge). Corner k is across a seam from r when its own UV is more
    than :data:`SEAM_RATIO` times farther from r's UV than the re-expressed one (on one chart the
    two nearly agree; across a seam the own UV jumps to another part of the atlas). The reference
    corner of the face is the one consistent with the most corners (ties: the first), and the
    corners across a seam from it take a new row of ``uvs``: their own UV carried into the
    reference's chart by the 2-D similarity that maps one side of a nearby seam edge onto the other
    (:func:`_across_seam`; exact when the charts meet by a translation, rotation or scaling, as a
    cylinder's or a mirrored island's), or, where no seam edge nearby agrees with it, the projected
    estimate (off by the bend between the two source faces on a curved surface).

    Returns:
        :class:`UVTransfer`.
    """
    sv = np.asarray(source_vertices, dtype=np.float64)
    sf = np.asarray(source_faces, dtype=np.int64)
    t = np.asarray(uvs, dtype=np.float64)
    uf = np.asarray(uv_faces, dtype=np.int64)
    face = np.asarray(face, dtype=np.int64)
    tf = np.asarray(target_faces, dtype=np.int64)
    own = surface_points(t, uf, face, bary)  # (Vt, 2)
    points = surface_points(sv, sf, face, bary)  # rest source point of every target vertex
    fc = face[tf]  # (Ft, 3) source face of every corner
    scale = float(np.ptp(t, axis=0).max()) if t.size else 1.0
    tol = 1e-9 * max(scale, 1e-300)
    # re-expressed[r, k]: corner k's point in the chart of corner r's source face
    reexpressed = np.empty((tf.shape[0], 3, 3, 2))
    consistent = np.ones((tf.shape[0], 3, 3), dtype=bool)
    for r in range(3):
        g = fc[:, r]
        a, b, c = (sv[sf[g, i]] for i in range(3))
        for k in range(3):
            bk = _plane_barycentric(points[tf[:, k]], a, b, c)
            ok = np.all(np.isfinite(bk), axis=1)
            e = np.einsum("nk,nkd->nd", np.where(ok[:, None], bk, 0.0), t[uf[g]])
            e[~ok] = own[tf[~ok, k]]
            reexpressed[:, r, k] = e
            if k != r:
                u_r, u_k = own[tf[:, r]], own[tf[:, k]]
                d_own = np.linalg.norm(u_k - u_r, axis=1)
                d_re = np.linalg.norm(e - u_r, axis=1)
                consistent[:, r, k] = (fc[:, k] == g) | (d_own <= SEAM_RATIO * d_re + tol)
    ref = np.argmax(consistent.sum(axis=2), axis=1)  # (Ft,) first of the most consistent
    rows = np.arange(tf.shape[0])
    across = ~consistent[rows, ref]  # (Ft, 3)
    out_faces = tf.copy()
    ti, tk = np.nonzero(across)
    out_faces[ti, tk] = own.shape[0] + np.arange(ti.size)
    extra = reexpressed[ti, ref[ti], tk]
    if ti.size:
        u_r, u_k = own[tf[ti, ref[ti]]], own[tf[ti, tk]]
        mid = 0.5 * (points[tf[ti, ref[ti]]] + points[tf[ti, tk]])
        extra = _across_seam(sv, sf, t, uf, mid, u_k, u_r, extra)
    return UVTransfer(
        uvs=np.concatenate([own, extra.reshape(-1, 2)]),
        uv_faces=out_faces,
        n_seam_faces=int(np.any(across, axis=1).sum()),
    )


def _seam_edges(source_faces: np.ndarray, uvs: np.ndarray, uv_faces: np.ndarray):
    """Edges whose two faces give their ends different UVs: (vertex ends (E, 2), UVs of the ends on one side (E, 2, 2),
    on the other side (E, 2, 2)).
    """
    a, b = source_faces.reshape(-1), source_faces[:, [1, 2, 0]].reshape(-1)
    ua, ub = uvs[uv_faces.reshape(-1)], uvs[uv_faces[:, [1, 2, 0]].reshape(-1)]
    swap = a > b
    ends = np.stack([np.where(swap, b, a), np.where(swap, a, b)], axis=1)
    ends_uv = np.stack([np.where(swap[:, None], ub, ua), np.where(swap[:, None], ua, ub)], axis=1)
    order = np.lexsort((ends[:, 1], ends[:, 0]))
    ends, ends_uv = ends[order], ends_uv[order]
    pair = np.flatnonzero(np.all(ends[1:] == ends[:-1], axis=1))  # half-edges i, i + 1 of one edge
    seam = pair[np.any(ends_uv[pair] != ends_uv[pair + 1], axis=(1, 2))]
    return ends[seam], ends_uv[seam], ends_uv[seam + 1]


def _across_seam(sv, sf, uvs, uv_faces, mid, u_k, u_r, estimate, candidates: int = 8) -> np.ndarray:
    """UVs ``u_k`` (n, 2) carried across a seam into the chart of ``u_r`` through a seam edge near ``mid`` (n, 3).

    For each of the ``candidates`` seam edges nearest to ``mid`` and each direction, the 2-D
    similarity z ↦ q0 + (z − p0)(q1 − q0)/(p1 − p0) (complex numbers) maps the edge's UVs on one
    side (p0, p1) onto the other (q0, q1). The image of ``u_k`` closest to ``estimate`` (the
    projected re-expression) is taken when it is within half the estimate's distance from
    ``u_r``; otherwise the estimate is kept.
    """
    from scipy.spatial import cKDTree

    ends, side_a, side_b = _seam_edges(sf, uvs, uv_faces)
    if ends.shape[0] == 0:
        return estimate
    k = min(candidates, ends.shape[0])
    _, near = cKDTree(sv[ends].mean(axis=1)).query(mid, k=k)
    near = np.asarray(near).reshape(mid.shape[0], k)
    z = (u_k[:, 0] + 1j * u_k[:, 1])[:, None]
    best = estimate.copy()
    best_gap = np.full(mid.shape[0], np.inf)
    for p_side, q_side in ((side_a, side_b), (side_b, side_a)):
        p = p_side[near][..., 0] + 1j * p_side[near][..., 1]  # (n, k, 2) ends on the corner's side
        q = q_side[near][..., 0] + 1j * q_side[near][..., 1]
        span = p[..., 1] - p[..., 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            image = q[..., 0] + (z - p[..., 0]) * (q[..., 1] - q[..., 0]) / span
        image = np.where(np.abs(span) > 0, image, np.nan)
        gap = np.abs(image - (estimate[:, 0] + 1j * estimate[:, 1])[:, None])
        gap = np.where(np.isfinite(gap), gap, np.inf)
        pick = np.argmin(gap, axis=1)
        g = gap[np.arange(gap.shape[0]), pick]
        better = g < best_gap
        chosen = image[np.arange(gap.shape[0]), pick]
        best[better] = np.stack([chosen.real, chosen.imag], axis=1)[better]
        best_gap[better] = g[better]
    ok = best_gap <= 0.5 * np.linalg.norm(estimate - u_r, axis=1)
    return np.where(ok[:, None], best, estimate)
