"""Source attributes carried to the target through the correspondence of a result of ``ncflow match``.

Every target vertex j corresponds to the point of the rest source surface given by
``map_tgt_to_src.npz``: source face ``face[j]`` and barycentric coordinates ``bary[j]``
(DESIGN.md, "Output contract"). A per-vertex attribute of the source is read there:

* continuous values (any (Vs, C) float array, PLY float properties): barycentric interpolation
  (:func:`ncflow.geometry.barycentric.surface_points`), exact for functions linear on each source triangle;
* labels (integers): :func:`transfer_labels`, by default the barycentric-weighted majority of the
  face's three corner labels (``"majority"``), else the corner of largest weight (``"nearest"``);
* colours (PLY ``red green blue [alpha]``): barycentric, clipped to the range, written as bytes;
* texture coordinates (OBJ with ``vt``, face-varying, with seams):
  :func:`ncflow.retarget.uv.transfer_uv`, one chart per target point and no target triangle across a seam;
* skin weights: :func:`ncflow.retarget.weights.transfer_skin_weights` (barycentric carry, clamped,
  renormalised, unreliable vertices inpainted);
* landmarks (JSON: vertex ids or points): :func:`carry_landmarks`, moved with the flowed source
  and projected onto the target surface.

:func:`transfer` is the one entry of ``ncflow transfer``: it reads a result folder and an
attribute file, carries the attribute and writes it for the target. ``docs/transfer.md`` has the
formats, the rules and examples.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError
from ncflow.geometry.barycentric import round_to_vertex, surface_points, vertex_surface_points
from ncflow.geometry.closest import closest_points_on_surface
from ncflow.io.atomic import check_output_file
from ncflow.io.landmarks import landmark_arrays, read_landmarks, write_landmarks
from ncflow.io.obj_uv import read_obj_uv, write_obj_uv
from ncflow.io.ply_properties import PLY_TYPES, PlyVertexProperties, read_ply_vertex_properties, write_ply_properties
from ncflow.io.result import CONTRACT_FILES, read_result, result_target
from ncflow.io.vertex_arrays import read_vertex_array, write_vertex_array
from ncflow.retarget.uv import UVTransfer, transfer_uv
from ncflow.retarget.weights import transfer_skin_weights

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
    (:func:`ncflow.geometry.barycentric.round_to_vertex`).

    Returns:
        (Vt,) or (Vt, C) labels, the dtype of ``labels``.
    """
    if rule == "nearest":
        return labels[round_to_vertex(source_faces, face, bary)]
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
            c = surface_points(values.astype(np.float64) / full, source_faces, face, bary)
            out.append((name, "uchar", np.round(np.clip(c, 0.0, 1.0) * 255.0).astype(np.uint8)))
        elif values.dtype.kind in "iu":
            out.append((name, ptype, transfer_labels(values.astype(np.int64), source_faces, face, bary, rule)))
        else:
            out.append((name, ptype, surface_points(values, source_faces, face, bary)))
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


def _check_out(out: Path, result_dir: Path, overwrite: bool) -> Path:
    """The output file checked before any work (not a folder, writable, not a result file; --overwrite)."""
    real = check_output_file(out, option="--out")
    if real.exists() and not overwrite:
        raise InputError("exists (use --overwrite to replace it)", out)
    root = Path(os.path.realpath(result_dir))
    if root in real.parents and real.relative_to(root).parts[0] in CONTRACT_FILES:
        raise InputError("is a file of the result folder; write the transfer elsewhere", out)
    return real


def _array_transfer(kind, attributes, n_source, res, result_dir, rule, max_distance, max_normal_angle):
    """(array to write, kind, details) for .npy / .txt attributes."""
    arr = read_vertex_array(attributes, n_source)
    face, bary, sf = res.map_face, res.map_bary, res.source_faces
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
        return surface_points(arr.astype(np.float64), sf, face, bary), kind, details
    w = arr.astype(np.float64).reshape(n_source, -1)
    sums = w.sum(axis=1)
    if np.any(w < -1e-9) or np.any(np.abs(sums - 1.0) > WEIGHT_SUM_TOL):
        bad = int(np.argmax((w < -1e-9).any(axis=1) | (np.abs(sums - 1.0) > WEIGHT_SUM_TOL)))
        raise InputError(
            f"skin weights must be non-negative with rows summing to 1 (row {bad} sums to {sums[bad]:.6g}); "
            "use --kind values for other arrays",
            attributes,
        )

    tv, tf = result_target(res, None, result_dir)
    weights, reliable = transfer_skin_weights(
        w,
        res.frames[0],
        sf,
        res.deformed_source,
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
    n_source, n_target = res.n_source, res.n_target
    if target is not None:  # read once, and checked whatever the kind needs
        res.target_vertices, res.target_faces = result_target(res, target, result_dir, replace=False)
    sv, sf, face, bary = res.frames[0], res.source_faces, res.map_face, res.map_bary
    if kind in ("auto", "values", "labels", "weights"):
        arr, kind, details = _array_transfer(
            kind, attributes, n_source, res, result_dir, label_rule, max_distance, max_normal_angle
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
        tv, tf = result_target(res, None, result_dir)
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
        tv, tf = result_target(res, None, result_dir)
        write_ply_properties(real_out, tv, tf, carried)
        details = {"properties": [name for name, _, _ in carried]}
    else:
        landmarks = read_landmarks(attributes, n_source)
        tv, tf = result_target(res, None, result_dir)
        vertex, point = landmark_arrays(landmarks)
        carried = carry_landmarks(vertex, point, sv, sf, res.deformed_source, tv, tf)
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
