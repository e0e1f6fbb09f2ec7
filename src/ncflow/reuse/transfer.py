"""Source attributes carried to the target through the correspondence of a result of ``ncflow match``.

Every target vertex j corresponds to the point of the rest source surface given by
``map_tgt_to_src.npz``: source face ``face[j]`` and barycentric coordinates ``bary[j]``
(DESIGN.md, "Output contract"). A per-vertex attribute of the source is read there:

* continuous values (any (Vs, C) float array, PLY float properties): barycentric interpolation
  (:func:`ncflow.reuse.carry.interpolate`), exact for functions linear on each source triangle;
* labels (integers): :func:`transfer_labels`, by default the barycentric-weighted majority of the
  face's three corner labels (``"majority"``), else the corner of largest weight (``"nearest"``);
* colours (PLY ``red green blue [alpha]``): barycentric, clipped to the range, written as bytes;
* texture coordinates (OBJ with ``vt``, face-varying, with seams): :func:`transfer_uv`, one chart
  per target point and no target triangle across a seam;
* skin weights: :func:`ncflow.reuse.weights.transfer_skin_weights` (barycentric carry, clamped,
  renormalised, unreliable vertices inpainted);
* landmarks (JSON: vertex ids or points): :func:`carry_landmarks`, moved with the flowed source
  and projected onto the target surface.

:func:`transfer` is the one entry of ``ncflow transfer``: it reads a result folder and an
attribute file, carries the attribute and writes it for the target. ``docs/transfer.md`` has the
formats, the rules and examples.

Over 500 lines: one module per command; the six attribute kinds (values, labels, UVs with seams,
PLY properties, landmarks, skin weights) share the map reading, the output checks and the dispatch.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError
from ncflow.geometry.barycentric import surface_points, vertex_surface_points
from ncflow.geometry.closest import closest_points_on_surface
from ncflow.io.atomic import check_output_file
from ncflow.io.landmarks import landmark_arrays, read_landmarks, write_landmarks
from ncflow.io.meshes import load_mesh
from ncflow.io.obj_uv import read_obj_uv, write_obj_uv
from ncflow.io.ply_properties import PLY_TYPES, PlyVertexProperties, read_ply_vertex_properties, write_ply_properties
from ncflow.io.result import CONTRACT_FILES, read_result
from ncflow.io.vertex_arrays import read_vertex_array, write_vertex_array
from ncflow.reuse.carry import interpolate, nearest_corner

__all__ = [
    "KINDS",
    "LABEL_RULES",
    "TransferSummary",
    "UVTransfer",
    "carry_landmarks",
    "resolve_kind",
    "summary_line",
    "transfer",
    "transfer_labels",
    "transfer_properties",
    "transfer_uv",
]

KINDS = ("auto", "values", "labels", "weights", "uv", "colors", "landmarks")
LABEL_RULES = ("majority", "nearest")
COLOR_CHANNELS = ("red", "green", "blue", "alpha")
OWN_GEOMETRY = ("x", "y", "z", "nx", "ny", "nz")
"""PLY vertex properties that are the target's own geometry and are not transferred."""

SEAM_RATIO = 2.0
"""A target corner is across a UV seam from its face's reference corner when its own UV lies more
than this many times farther from the reference's UV than its UV in the reference's chart does."""

WEIGHT_SUM_TOL = 1e-3

# attribute-file suffix -> (kinds it can hold, output suffixes)
_FAMILIES = {
    ".npy": (("values", "labels", "weights"), (".npy", ".txt")),
    ".txt": (("values", "labels", "weights"), (".npy", ".txt")),
    ".obj": (("uv",), (".obj",)),
    ".ply": (("colors",), (".ply",)),
    ".json": (("landmarks",), (".json",)),
}


# ----------------------------------------------------------------------------------------------
# Labels


def transfer_labels(
    labels: Int[np.ndarray, "Vs ..."],
    source_faces: Int[np.ndarray, "Fs 3"],
    face: Int[np.ndarray, " Vt"],
    bary: Float[np.ndarray, "Vt 3"],
    rule: str = "majority",
) -> Int[np.ndarray, "Vt ..."]:
    """Integer labels of the source read at the target's mapped points (each column on its own).

    ``"majority"`` (default): each distinct label among the face's three corners scores the sum of
    the barycentric weights of the corners that carry it, and the best score wins (ties: the
    corner of larger weight, then the first corner). This is the argmax of the barycentrically
    interpolated one-hot label functions, so a label region's border runs where its interpolated
    indicator crosses ½ — the same reading as for continuous values, and it does not flip a point
    to a label held by one corner against two corners that together outweigh it.
    ``"nearest"``: the label of the corner of largest weight
    (:func:`ncflow.reuse.carry.nearest_corner`).

    Returns:
        (Vt,) or (Vt, C) labels, the dtype of ``labels``.
    """
    if rule == "nearest":
        return nearest_corner(labels, source_faces, face, bary)
    if rule != "majority":
        raise InputError(f"unknown label rule {rule!r}; use one of {', '.join(LABEL_RULES)}")
    labels = np.asarray(labels)
    lab = labels.reshape(labels.shape[0], -1)
    corners = lab[np.asarray(source_faces)[np.asarray(face)]]  # (Vt, 3, C)
    b = np.asarray(bary, dtype=np.float64)[:, :, None]  # (Vt, 3, 1)
    same = corners[:, :, None, :] == corners[:, None, :, :]  # (Vt, 3, 3, C): corner k vs corner m
    score = np.sum(same * b[:, None, :, :], axis=2)  # (Vt, 3, C)
    best = score >= score.max(axis=1, keepdims=True) - 1e-12
    pick = np.argmax(np.where(best, b, -1.0), axis=1)  # (Vt, C): first of the largest weight among the best
    out = np.take_along_axis(corners, pick[:, None, :], axis=1)[:, 0, :]
    return out.reshape((out.shape[0],) + labels.shape[1:])


# ----------------------------------------------------------------------------------------------
# Texture coordinates


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
    own = interpolate(t, uf, face, bary)  # (Vt, 2)
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


# ----------------------------------------------------------------------------------------------
# PLY properties


def _color_scale(values: np.ndarray, ptype: str) -> float:
    """The full-intensity value of a colour channel: the integer type's maximum; 1 for float 0–1, else 255."""
    code = PLY_TYPES[ptype][1]
    if code[0] in "iu":
        return float(np.iinfo(code).max)
    return 1.0 if values.size == 0 or float(np.max(values)) <= 1.0 else 255.0


def transfer_properties(
    properties: PlyVertexProperties,
    source_faces: Int[np.ndarray, "Fs 3"],
    face: Int[np.ndarray, " Vt"],
    bary: Float[np.ndarray, "Vt 3"],
    rule: str = "majority",
) -> list[tuple[str, str, np.ndarray]]:
    """PLY vertex properties of the source carried to the target: [(name, PLY type, (Vt,) values)].

    Positions and normals (:data:`OWN_GEOMETRY`) are the target's own and are skipped. Colour
    channels (:data:`COLOR_CHANNELS`) are interpolated, clipped to [0, full intensity] (an integer
    type's maximum; for float channels 1 when every value is at most 1, else 255) and written as
    ``uchar``; other integer properties are labels (:func:`transfer_labels`, type kept); other
    float properties are values (barycentric, type kept).
    """
    out = []
    for name, ptype in zip(properties.names, properties.types):
        if name in OWN_GEOMETRY:
            continue
        values = properties.values[name]
        if name in COLOR_CHANNELS:
            full = _color_scale(values, ptype)
            c = interpolate(values.astype(np.float64) / full, source_faces, face, bary)
            out.append((name, "uchar", np.round(np.clip(c, 0.0, 1.0) * 255.0).astype(np.uint8)))
        elif values.dtype.kind in "iu":
            out.append((name, ptype, transfer_labels(values.astype(np.int64), source_faces, face, bary, rule)))
        else:
            out.append((name, ptype, interpolate(values, source_faces, face, bary)))
    return out


# ----------------------------------------------------------------------------------------------
# Landmarks


def carry_landmarks(
    vertex: Int[np.ndarray, " n"],
    point: Float[np.ndarray, "n 3"],
    source_vertices: Float[np.ndarray, "Vs 3"],
    source_faces: Int[np.ndarray, "Fs 3"],
    deformed_source: Float[np.ndarray, "Vs 3"],
    target_vertices: Float[np.ndarray, "Vt 3"],
    target_faces: Int[np.ndarray, "Ft 3"],
) -> dict[str, np.ndarray]:
    """Landmarks of the source surface carried to the target surface.

    A landmark is a point of the rest source surface: a vertex (``vertex[i] ≥ 0``; the lowest-index
    face containing it, one-hot barycentrics) or ``point[i]`` snapped to the closest point of the
    surface. It moves with the flowed source (same face and barycentrics on ``deformed_source``)
    and is projected onto the target surface (exact closest point,
    :func:`ncflow.geometry.closest.closest_points_on_surface`).

    Returns:
        dict of arrays, one row per landmark: ``source_face`` (n,), ``source_bary`` (n, 3),
        ``source_point`` (n, 3) the point on the rest source, ``snap_distance`` (n,) from the given
        point to it (0 for vertices), ``moved_point`` (n, 3) on the flowed source, ``face`` (n,),
        ``bary`` (n, 3) and ``point`` (n, 3) on the target, ``distance`` (n,) from the moved point
        to the target, ``vertex`` (n,) the target vertex nearest to ``point``.
    """
    from scipy.spatial import cKDTree

    sv = np.asarray(source_vertices, dtype=np.float64)
    sf = np.asarray(source_faces, dtype=np.int64)
    n = vertex.shape[0]
    s_face = np.zeros(n, dtype=np.int64)
    s_bary = np.zeros((n, 3))
    snap = np.zeros(n)
    is_v = vertex >= 0
    if np.any(is_v):
        s_face[is_v], s_bary[is_v] = vertex_surface_points(vertex[is_v], sf, sv.shape[0])
    if np.any(~is_v):
        snap[~is_v], s_face[~is_v], b = closest_points_on_surface(point[~is_v], sv, sf)
        b = np.clip(b, 0.0, None)
        s_bary[~is_v] = b / b.sum(axis=1, keepdims=True)
    moved = surface_points(deformed_source, sf, s_face, s_bary)
    dist, t_face, t_bary = closest_points_on_surface(moved, target_vertices, target_faces)
    t_bary = np.clip(t_bary, 0.0, None)
    t_bary /= t_bary.sum(axis=1, keepdims=True)
    t_point = surface_points(target_vertices, target_faces, t_face, t_bary)
    nearest = cKDTree(np.asarray(target_vertices, dtype=np.float64)).query(t_point)[1]
    return {
        "source_face": s_face,
        "source_bary": s_bary,
        "source_point": surface_points(sv, sf, s_face, s_bary),
        "snap_distance": snap,
        "moved_point": moved,
        "face": t_face,
        "bary": t_bary,
        "point": t_point,
        "distance": dist,
        "vertex": np.asarray(nearest, dtype=np.int64),
    }


def _landmark_record(landmarks, carried: dict[str, np.ndarray], n_target: int) -> dict:
    """The JSON record of carried landmarks (schema in docs/transfer.md)."""
    entries = []
    for i, m in enumerate(landmarks):
        entries.append(
            {
                "name": m.name,
                "point": carried["point"][i],
                "face": carried["face"][i],
                "bary": carried["bary"][i],
                "vertex": carried["vertex"][i],
                "distance": carried["distance"][i],
                "source": {
                    "vertex": m.vertex,
                    "point": None if m.point is None else list(m.point),
                    "face": carried["source_face"][i],
                    "bary": carried["source_bary"][i],
                    "surface_point": carried["source_point"][i],
                    "snap_distance": carried["snap_distance"][i],
                },
            }
        )
    return {"landmarks": entries, "n_target_vertices": n_target}


# ----------------------------------------------------------------------------------------------
# The command


@dataclasses.dataclass(frozen=True)
class TransferSummary:
    """What :func:`transfer` wrote.

    Attributes:
        out: the written file.
        kind: the attribute kind (``values``, ``labels``, ``weights``, ``uv``, ``colors``, ``landmarks``).
        n_target: target vertices.
        details: kind-specific counts (``columns``; ``inpainted``; ``seam_faces``; ``properties``;
            ``landmarks``, ``max_snap_distance``, ``max_distance``).
    """

    out: Path
    kind: str
    n_target: int
    details: dict


def resolve_kind(attributes: str | os.PathLike, kind: str, out: str | os.PathLike) -> str:
    """The attribute kind from the file's suffix and ``kind``, checked against the output's suffix.

    Raises:
        InputError: an unknown kind or suffix, a kind the file cannot hold, or an output format
            the kind cannot be written as.
    """
    if kind not in KINDS:
        raise InputError(f"unknown kind {kind!r}; use one of {', '.join(KINDS)}")
    suffix = Path(attributes).suffix.lower()
    if suffix not in _FAMILIES:
        raise InputError(
            f"unsupported attribute file {suffix or '(no suffix)'!r}; use .npy/.txt (one row per source vertex), "
            ".obj (UVs), .ply (colours, properties) or .json (landmarks)",
            attributes,
        )
    kinds, outputs = _FAMILIES[suffix]
    if kind != "auto" and kind not in kinds:
        raise InputError(
            f"--kind {kind} does not apply to a {suffix} file (use auto or {', '.join(kinds)})", attributes
        )
    out_suffix = Path(out).suffix.lower()
    if out_suffix not in outputs:
        raise InputError(
            f"a {suffix} attribute is written as {' or '.join(outputs)}, not {out_suffix or 'no suffix'}", out
        )
    return kind if kind != "auto" or len(kinds) > 1 else kinds[0]


def _target_mesh(res: dict, target, result_dir) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) of the target: the result's target.ply, else the ``target`` mesh file."""
    if res["target_vertices"] is not None:
        if target is not None:
            raise InputError("--target is only for results without target.ply; this result has one", target)
        return res["target_vertices"], res["target_faces"]
    if target is None:
        raise InputError(
            "the result has no target.ply (an older result); give the target mesh with --target", result_dir
        )
    mesh = load_mesh(target)
    if mesh.n_vertices != res["n_target"]:
        raise InputError(
            f"the target has {mesh.n_vertices} vertices but the result's map has {res['n_target']} target vertices",
            target,
        )
    return mesh.vertices, mesh.faces


def _check_out(out: Path, result_dir: Path, overwrite: bool) -> Path:
    """The output file checked before any work (not a folder, writable, not a result file; --overwrite)."""
    real = check_output_file(out, option="--out")
    if real.exists() and not overwrite:
        raise InputError("exists (use --overwrite to replace it)", out)
    root = Path(os.path.realpath(result_dir))
    if root in real.parents and real.relative_to(root).parts[0] in CONTRACT_FILES:
        raise InputError("is a file of the result folder; write the transfer elsewhere", out)
    return real


def _array_transfer(kind, attributes, n_source, res, target, result_dir, rule, max_distance, max_normal_angle):
    """(array to write, kind, details) for .npy / .txt attributes."""
    arr = read_vertex_array(attributes, n_source)
    face, bary, sf = res["map_face"], res["map_bary"], res["source_faces"]
    if kind == "auto":
        kind = "labels" if arr.dtype.kind == "i" else "values"
    details: dict = {"columns": 1 if arr.ndim == 1 else int(arr.shape[1])}
    if kind == "labels":
        if arr.dtype.kind == "f":
            if not np.all(arr == np.round(arr)) or np.any(np.abs(arr) > 2**62):
                raise InputError("--kind labels needs integer values", attributes)
            arr = arr.astype(np.int64)
        return transfer_labels(arr, sf, face, bary, rule), kind, details
    if kind == "values":
        return interpolate(arr.astype(np.float64), sf, face, bary), kind, details
    w = arr.astype(np.float64).reshape(n_source, -1)
    sums = w.sum(axis=1)
    if np.any(w < -1e-9) or np.any(np.abs(sums - 1.0) > WEIGHT_SUM_TOL):
        bad = int(np.argmax((w < -1e-9).any(axis=1) | (np.abs(sums - 1.0) > WEIGHT_SUM_TOL)))
        raise InputError(
            f"skin weights must be non-negative with rows summing to 1 (row {bad} sums to {sums[bad]:.6g}); "
            "use --kind values for other arrays",
            attributes,
        )
    from ncflow.reuse.weights import transfer_skin_weights

    tv, tf = _target_mesh(res, target, result_dir)
    weights, reliable = transfer_skin_weights(
        w,
        res["frames"][0],
        sf,
        res["deformed_source"],
        tv,
        tf,
        face,
        bary,
        max_distance=max_distance,
        max_normal_angle=max_normal_angle,
    )
    details["inpainted"] = int(np.sum(~np.asarray(reliable)))
    return np.asarray(weights, dtype=np.float64), kind, details


def transfer(
    result_dir: str | os.PathLike,
    attributes: str | os.PathLike,
    out: str | os.PathLike,
    *,
    kind: str = "auto",
    target: str | os.PathLike | None = None,
    label_rule: str = "majority",
    max_distance: float | None = None,
    max_normal_angle: float | None = None,
    overwrite: bool = False,
) -> TransferSummary:
    """Carry a source attribute file to the target of a match result and write it.

    Args:
        result_dir: a result folder of ``ncflow match`` (its ``map_tgt_to_src.npz``, frame 0 as the
            rest source, ``deformed_source.ply`` and ``target.ply`` are used).
        attributes: ``.npy``/``.txt`` (one row per source vertex), ``.obj`` (the source with face
            -varying UVs), ``.ply`` (the source with vertex colours / properties) or ``.json``
            (landmarks); the source vertex count (and for OBJ the faces) must be the result's.
        out: the output file: ``.npy``/``.txt`` for arrays, ``.obj`` for UVs, ``.ply`` for PLY
            properties, ``.json`` for landmarks.
        kind: ``"auto"`` (from the file: integers are labels, floats values) or one of
            :data:`KINDS`; ``"weights"`` must be asked for.
        target: the target mesh, only for a result without ``target.ply``.
        label_rule: ``"majority"`` or ``"nearest"`` (:func:`transfer_labels`).
        max_distance: skin weights only: passed to ``transfer_skin_weights``.
        max_normal_angle: skin weights only: passed to ``transfer_skin_weights`` (degrees).
        overwrite: replace an existing ``out``.

    Returns:
        :class:`TransferSummary`.

    Raises:
        InputError: one line naming the bad file or option; nothing is written.
    """
    result_dir, attributes, out = Path(result_dir), Path(attributes), Path(out)
    kind = resolve_kind(attributes, kind, out)
    if label_rule not in LABEL_RULES:
        raise InputError(f"unknown label rule {label_rule!r}; use one of {', '.join(LABEL_RULES)}")
    for option, value in (("--max-distance", max_distance), ("--max-normal-angle", max_normal_angle)):
        if value is not None and kind != "weights":
            raise InputError(f"{option} applies to --kind weights only")
    real_out = _check_out(out, result_dir, overwrite)
    res = read_result(result_dir, check_animation=False)
    n_source, n_target = res["n_source"], res["n_target"]
    if target is not None:  # checked whatever the kind needs
        _target_mesh(res, target, result_dir)
    sv, sf, face, bary = res["frames"][0], res["source_faces"], res["map_face"], res["map_bary"]
    if kind in ("auto", "values", "labels", "weights"):
        arr, kind, details = _array_transfer(
            kind, attributes, n_source, res, target, result_dir, label_rule, max_distance, max_normal_angle
        )
        write_vertex_array(real_out, arr)
    elif kind == "uv":
        mesh = read_obj_uv(attributes)
        if mesh.vertices.shape[0] != n_source or not np.array_equal(mesh.faces, sf):
            raise InputError(
                f"its {mesh.vertices.shape[0]} vertices and {mesh.faces.shape[0]} faces are not the result's source "
                f"({n_source} vertices, {sf.shape[0]} faces, same order): give the source mesh that was matched",
                attributes,
            )
        tv, tf = _target_mesh(res, target, result_dir)
        uv = transfer_uv(sv, sf, mesh.uvs, mesh.uv_faces, face, bary, tf)
        write_obj_uv(real_out, tv, tf, uv.uvs, uv.uv_faces)
        details = {"seam_faces": uv.n_seam_faces}
    elif kind == "colors":
        props = read_ply_vertex_properties(attributes)
        if props.n_vertices != n_source:
            raise InputError(f"has {props.n_vertices} vertices but the result's source has {n_source}", attributes)
        carried = transfer_properties(props, sf, face, bary, label_rule)
        if not carried:
            raise InputError("no vertex properties to transfer (only positions and normals)", attributes)
        tv, tf = _target_mesh(res, target, result_dir)
        write_ply_properties(real_out, tv, tf, carried)
        details = {"properties": [name for name, _, _ in carried]}
    else:
        landmarks = read_landmarks(attributes, n_source)
        tv, tf = _target_mesh(res, target, result_dir)
        vertex, point = landmark_arrays(landmarks)
        carried = carry_landmarks(vertex, point, sv, sf, res["deformed_source"], tv, tf)
        write_landmarks(real_out, _landmark_record(landmarks, carried, n_target))
        details = {
            "landmarks": len(landmarks),
            "max_snap_distance": float(carried["snap_distance"].max()),
            "max_distance": float(carried["distance"].max()),
        }
    return TransferSummary(out=out, kind=kind, n_target=n_target, details=details)


def summary_line(summary: TransferSummary) -> str:
    """The one line ``ncflow transfer`` prints."""
    d = summary.details
    extra = {
        "values": lambda: f", {d['columns']} column(s)",
        "labels": lambda: f", {d['columns']} column(s)",
        "weights": lambda: (
            f", {d['columns']} joints, {d['inpainted']} vert{'ex' if d['inpainted'] == 1 else 'ices'} inpainted"
        ),
        "uv": lambda: f", {d['seam_faces']} faces re-expressed across UV seams",
        "colors": lambda: f", properties {' '.join(d['properties'])}",
        "landmarks": lambda: f", {d['landmarks']} landmarks (largest distance to the target {d['max_distance']:.3g})",
    }[summary.kind]()
    return f"wrote {summary.out}: {summary.n_target} target vertices, kind {summary.kind}{extra}"
