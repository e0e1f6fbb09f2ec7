"""``ncflow view``: one self-contained HTML page that shows a result of ``ncflow match``, offline.

The page (docs/view.md) shows the source, the flowed source (animated with a timeline slider and
play/pause) and the target side by side, or the flowed source over a transparent target; the
skeleton on or off; colours carried through the correspondence (the source's positions as RGB, or
a 3-D checker of them, read on the target at the point each target vertex maps to); with
ground truth, the target coloured by its geodesic error with a colour bar on the τmax = 0.20 scale
of docs/evaluation.md; and for a partial target (a scan), the source coloured by what the target shows
of it (``source_seen.txt``, :mod:`ncflow.matcher.partial`).

Everything is inside the one file: the page script is three.js and the viewer bundled at build
time (``viewer/`` at the repository root, esbuild, shipped prebuilt as package data in
``ncflow/view/assets/viewer.js``; users need no node), the data are typed arrays in a
``<script type="application/json">`` element (positions quantised to uint16 in their bounding box,
frames delta-coded, bytes deflated and base64-encoded: :func:`encode_array`), and a
Content-Security-Policy forbids every network request. Meshes above the
display budget are decimated (:func:`ncflow.geometry.decimate.decimate`, whose kept vertices are
source vertices, so ``frames[:, kept]`` animates the decimated mesh exactly).
"""

from __future__ import annotations

import html
import json
import os
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from jaxtyping import Float, Int

from ncflow import __version__
from ncflow.errors import InputError, NcflowError
from ncflow.evaluate.metrics import auc, geodesic_errors
from ncflow.evaluate.plots import source_colors
from ncflow.geometry.barycentric import surface_points
from ncflow.geometry.cloud import point_spacing
from ncflow.geometry.decimate import decimate
from ncflow.geometry.mesh import Mesh
from ncflow.io.atomic import atomic_write_bytes, check_output_file
from ncflow.io.ground_truth import GroundTruth, load_ground_truth
from ncflow.io.result import ResultFolder, read_result, result_target
from ncflow.view.arrays import QUANT_LEVELS as _Q
from ncflow.view.arrays import decode_array, dequantize_positions, encode_array, quantize_positions

__all__ = [
    "DEFAULT_MAX_DISPLAY_FRAMES",
    "DEFAULT_MAX_DISPLAY_VERTICES",
    "VIEW_FORMAT",
    "check_view_output",
    "decode_array",
    "dequantize_positions",
    "encode_array",
    "error_colors",
    "geodesic_error_map",
    "quantize_positions",
    "render_page",
    "view_data",
    "viewer_script",
    "write_page",
    "write_view",
]

VIEW_FORMAT = "ncflow-view/1"
DEFAULT_MAX_DISPLAY_VERTICES = 60_000
DEFAULT_MAX_DISPLAY_FRAMES = 100
GENERATOR = "ncflow view"
NO_DATA_RGB = (154, 154, 154)  # target vertices without ground truth
_CSP = "default-src 'none'; script-src 'unsafe-inline'; style-src 'unsafe-inline'; img-src data:"


def _faces(faces: np.ndarray, n_vertices: int) -> dict[str, Any]:
    return encode_array(faces.reshape(-1), "uint16" if n_vertices <= 65536 else "uint32")


# ----------------------------------------------------------------------------------------------
# Colours


def error_colors(errors: Float[np.ndarray, " V"], tau_max: float) -> np.ndarray:
    """(V, 3) uint8: matplotlib's turbo on e / τmax clipped to [0, 1] (+inf at the top), NaN grey.

    The colour scale of ``eval_geodesic_error.png`` (:func:`ncflow.evaluate.plots.render_error_map`).
    """
    import matplotlib

    e = np.asarray(errors, np.float64)
    rgb = matplotlib.colormaps["turbo"](np.clip(np.nan_to_num(e, nan=0.0, posinf=tau_max) / tau_max, 0.0, 1.0))
    out = np.rint(rgb[:, :3] * 255).astype(np.uint8)
    out[np.isnan(e)] = NO_DATA_RGB
    return out


def _color_bar(errors: np.ndarray, tau_max: float, n_stops: int = 11) -> dict[str, Any]:
    """The colour bar of the error map: CSS stops, tick labels, and the summary of the errors."""
    import matplotlib

    rgb = matplotlib.colormaps["turbo"](np.linspace(0.0, 1.0, n_stops))[:, :3]
    stops = ["#{:02x}{:02x}{:02x}".format(*np.rint(c * 255).astype(int)) for c in rgb]
    ticks = [f"{x:.2f}" for x in np.linspace(0.0, tau_max, 5)]
    ticks[0], ticks[-1] = "0", f"\u2265 {tau_max:.2f}"
    have = ~np.isnan(errors)
    finite = errors[np.isfinite(errors)]
    summary = (
        f"mean {np.mean(finite):.3f} \u00b7 AUC({tau_max:.2f}) {auc(errors, tau_max):.3f} \u00b7 "
        f"{int(have.sum())} of {errors.size} target vertices with ground truth"
        if finite.size
        else "no finite errors"
    )
    return {
        "label": "geodesic error / \u221a(source area)",
        "tau_max": float(tau_max),
        "stops": stops,
        "ticks": ticks,
        "no_data": "#{:02x}{:02x}{:02x}".format(*NO_DATA_RGB),
        "summary": summary,
    }


# ----------------------------------------------------------------------------------------------
# Ground truth


def geodesic_error_map(
    source: Mesh,
    map_face: Int[np.ndarray, " Vt"],
    map_bary: Float[np.ndarray, "Vt 3"],
    truth: GroundTruth,
    method: str = "auto",
) -> Float[np.ndarray, " Vt"]:
    """(Vt,) geodesic error of every target vertex (:func:`ncflow.evaluate.metrics.geodesic_errors`); NaN without truth.

    Args:
        source: the rest source (frame 0 and the source faces).
        map_face: (Vt,) the result's ``map_tgt_to_src`` faces.
        map_bary: (Vt, 3) its barycentric coordinates.
        truth: ground truth for the same target (complete or partial).
        method: the geodesic solver (see :func:`~ncflow.evaluate.metrics.geodesic_errors`).
    """
    ti = np.asarray(truth.target_index, np.int64)
    out = np.full(np.asarray(map_face).shape[0], np.nan)
    out[ti] = geodesic_errors(source, map_face[ti], map_bary[ti], truth.face, truth.bary, method=method)
    return out


# ----------------------------------------------------------------------------------------------
# The page's data


def _frame_subset(n_frames: int, max_frames: int) -> np.ndarray:
    if n_frames <= max_frames:
        return np.arange(n_frames)
    return np.unique(np.rint(np.linspace(0, n_frames - 1, max_frames)).astype(np.int64))


def view_data(
    result: ResultFolder,
    *,
    errors: Float[np.ndarray, " Vt"] | None = None,
    tau_max: float = 0.20,
    max_display_vertices: int = DEFAULT_MAX_DISPLAY_VERTICES,
    max_display_frames: int = DEFAULT_MAX_DISPLAY_FRAMES,
    title: str | None = None,
    animation: tuple[bytes, Int[np.ndarray, " K"]] | None = None,
) -> dict[str, Any]:
    """The JSON object the page reads, from a loaded result (:func:`ncflow.io.result.read_result`).

    Args:
        result: a result folder read back, its ``target_vertices`` and ``target_faces`` set.
        errors: (Vt,) geodesic error per target vertex (NaN: no ground truth), or None.
        tau_max: the top of the error colour scale.
        max_display_vertices: meshes with more vertices are decimated to about this many.
        max_display_frames: more frames are subsampled to this many (first and last kept).
        title: shown in the page.
        animation: a skinned GLB of the source (``ncflow track``'s ``animation.glb``: the source's vertices
            in order, one clip) and per result frame the clip's key it shows (−1: none, the rest
            pose); the page then plays the clip's skinned mesh, evaluated by three.js, between
            those frames.

    Returns:
        ``{"format", "title", "times" (K',), "bbox" {"min", "max"}, "aspect" (3,), "frames"
        (K', 3, n) uint16 (coordinate planes, delta-coded over frames), "source" {n_vertices,
        n_vertices_original, kept, faces, ref}, "target" {the same, positions}, "skeleton"
        {parents, positions (K', J, 3) float32} or None, "error" {values (m,) float32 (NaN: no
        ground truth), colors (m, 3) uint8, colour-bar fields} or None, "animation" {glb (bytes) uint8,
        keys (K',) int: the clip key of each frame shown} or None, "seen" {values (n,) uint8: 255 × how
        much the target shows each kept source vertex (``source_seen.txt``)} or None (all of it)}``.
        Arrays are packed by :func:`encode_array`; positions are quantised in ``bbox``; ``ref`` are the rest source
        positions normalised to [0, 1] per axis (uint16 of 65535), read on the target at the point
        each target vertex maps to.
    """
    frames = np.asarray(result.frames, np.float64)
    faces = np.asarray(result.source_faces, np.int64)
    tv = np.asarray(result.target_vertices, np.float64)
    tf = np.asarray(result.target_faces, np.int64)
    pick = _frame_subset(frames.shape[0], max_display_frames)
    rest = frames[0]
    ref = source_colors(rest)  # positions in [0, 1] per axis: the colour and checker coordinates
    target_ref = np.clip(surface_points(ref, faces, result.map_face, result.map_bary), 0.0, 1.0)
    src = decimate(rest, faces, max_display_vertices)
    tgt_kept, tgt_faces, tgt_pos = target_display(tv, tf, max_display_vertices)
    shown = frames[pick][:, src.kept]
    lo = np.minimum(frames.min(axis=(0, 1)), tv.min(0))
    hi = np.maximum(frames.max(axis=(0, 1)), tv.max(0))
    extent = rest.max(0) - rest.min(0)
    data: dict[str, Any] = {
        "format": VIEW_FORMAT,
        "title": title or "",
        "times": [float(t) for t in np.asarray(result.frame_times, np.float64)[pick]],
        "bbox": {"min": [float(x) for x in lo], "max": [float(x) for x in hi]},
        "aspect": [float(x) for x in extent / max(float(extent.max()), 1e-300)],
        "frames": encode_array(quantize_positions(shown, lo, hi).transpose(0, 2, 1), "uint16", delta=True),
        "source": {
            "n_vertices": int(src.kept.size),
            "n_vertices_original": int(rest.shape[0]),
            "kept": encode_array(src.kept, "uint32"),
            "faces": _faces(src.faces, src.kept.size),
            "ref": encode_array(np.rint(ref[src.kept] * _Q), "uint16"),
        },
        "target": {
            "n_vertices": int(tgt_kept.size),
            "n_vertices_original": int(tv.shape[0]),
            "kept": encode_array(tgt_kept, "uint32"),
            "faces": _faces(tgt_faces, tgt_kept.size),
            "positions": encode_array(quantize_positions(tgt_pos, lo, hi), "uint16"),
            "ref": encode_array(np.rint(target_ref[tgt_kept] * _Q), "uint16"),
        },
        "skeleton": None,
        "error": None,
        "animation": None,
        "seen": None,
    }
    seen = result.source_seen
    if seen is not None and float(np.min(seen)) < 1.0:  # a partial target: what it shows of the source
        data["seen"] = {"values": encode_array(np.rint(np.clip(seen[src.kept], 0.0, 1.0) * 255), "uint8")}
    if animation is not None:
        glb, keys = animation
        data["animation"] = {
            "glb": encode_array(np.frombuffer(glb, np.uint8), "uint8"),
            "keys": [int(k) for k in np.asarray(keys, np.int64)[pick]],
        }
    if result.skeleton_frames is not None:
        data["skeleton"] = {
            "parents": [int(p) for p in result.skeleton_target.parents],
            "positions": encode_array(np.asarray(result.skeleton_frames)[pick], "float32"),
        }
    if errors is not None:
        e = np.asarray(errors, np.float64)
        data["error"] = {
            "values": encode_array(e[tgt_kept], "float32"),
            "colors": encode_array(error_colors(e[tgt_kept], tau_max), "uint8"),
            **_color_bar(e, tau_max),
        }
    return data


_TETRAHEDRON = np.array([[1.0, 1.0, 1.0], [1.0, -1.0, -1.0], [-1.0, 1.0, -1.0], [-1.0, -1.0, 1.0]]) / np.sqrt(3.0)
_TETRA_FACES = np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])


def target_display(
    vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"], budget: int
) -> tuple[Int[np.ndarray, " n"], Int[np.ndarray, "f 3"], Float[np.ndarray, "n 3"]]:
    """(kept (n,): the target vertex each shown vertex stands for, faces (f, 3), positions (n, 3)) of the
    target as the page shows it: a mesh decimated to about ``budget`` vertices; a point cloud (no faces)
    as a small tetrahedron around each point (half the cloud's spacing across; every point while
    4 × points fits the budget, else an even subset), so that the page draws it as it draws a mesh.
    """
    if faces.shape[0]:
        dec = decimate(vertices, faces, budget)
        return dec.kept, dec.faces, vertices[dec.kept]
    n = vertices.shape[0]
    shown = np.unique(np.linspace(0, n - 1, min(n, max(budget // 4, 1))).round().astype(np.int64))
    radius = 0.5 * point_spacing(vertices) if n > 3 else 1e-3
    kept = np.repeat(shown, 4)
    positions = (vertices[shown][:, None, :] + radius * _TETRAHEDRON[None]).reshape(-1, 3)
    tri = (_TETRA_FACES[None] + 4 * np.arange(shown.size)[:, None, None]).reshape(-1, 3)
    return kept, tri, positions


# ----------------------------------------------------------------------------------------------
# The page


def viewer_script() -> str:
    """The bundled page script (three.js + the viewer), shipped as package data."""
    try:
        return resources.files("ncflow.view").joinpath("assets/viewer.js").read_text(encoding="ascii")
    except (FileNotFoundError, OSError) as exc:  # an installation without its package data
        raise NcflowError(
            f"the viewer script is missing from the installation ({exc}); reinstall ncflow "
            "or rebuild it with viewer/build.sh"
        ) from None


def _script_json(data: dict[str, Any]) -> str:
    """JSON text that cannot end its ``<script>`` element early (``<``, ``>`` and ``&`` escaped)."""
    text = json.dumps(data, separators=(",", ":"), allow_nan=False, ensure_ascii=True)
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def render_page(data: dict[str, Any], script: str) -> str:
    """The whole HTML page: the data element, the inlined script, a policy forbidding network requests.

    Raises:
        ValueError: ``script`` would end its ``<script>`` element early.
    """
    if "</script" in script.lower():
        raise ValueError("the viewer script contains '</script' and cannot be inlined")
    title = html.escape(data.get("title") or "result").encode("ascii", "xmlcharrefreplace").decode("ascii")
    return (
        "<!DOCTYPE html>\n"
        '<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        f'<meta name="generator" content="{GENERATOR} {html.escape(__version__)}">\n'
        f'<meta http-equiv="Content-Security-Policy" content="{_CSP}">\n'
        '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
        f"<title>{title} &middot; ncflow view</title>\n</head>\n<body>\n"
        f'<script type="application/json" id="ncflow-data">{_script_json(data)}</script>\n'
        f"<script>{script}</script>\n</body>\n</html>\n"
    )


def check_view_output(path: str | os.PathLike, overwrite: bool = False) -> Path:
    """Check where the page goes, before any work; return it resolved.

    An existing file is replaced only when it is a page of ``ncflow view`` (its generator tag in
    the first KiB) or ``overwrite`` is set: ncflow does not replace a file it did not write.

    Raises:
        InputError: one line naming the path (also those of :func:`ncflow.io.atomic.check_output_file`).
    """
    real = check_output_file(path, option="--out")
    if real.exists() and not overwrite:
        try:
            with open(real, "rb") as fh:
                head = fh.read(1024)
        except OSError as exc:
            raise InputError(f"exists and cannot be read ({exc.strerror or exc})", path) from None
        if f'<meta name="generator" content="{GENERATOR} '.encode() not in head:
            raise InputError("exists and is not a page of ncflow view; pass --overwrite to replace it", path)
    return real


def _check_budget(value, what: str, lo: int) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lo:
        raise InputError(f"{what} must be an integer of at least {lo}, got {value!r}")


def _check_barycentric(bary: Float[np.ndarray, "Vt 3"], path: Path, tol: float = 1e-3) -> None:
    """Barycentric coordinates of points on their faces: components in [0, 1] and summing to 1 (± ``tol``)."""
    bad = np.any(bary < -tol, axis=1) | np.any(bary > 1 + tol, axis=1) | (np.abs(bary.sum(axis=1) - 1) > tol)
    if np.any(bad):
        j = int(np.argmax(bad))
        raise InputError(
            f"'bary' of target vertex {j} is {np.round(bary[j], 4).tolist()}, not barycentric coordinates "
            f"({int(bad.sum())} such rows)",
            path,
        )


def write_view(
    result_dir: str | os.PathLike,
    out_html: str | os.PathLike | None = None,
    *,
    gt: str | os.PathLike | tuple | list | None = None,
    gt_format: str | None = None,
    target: str | os.PathLike | None = None,
    max_display_vertices: int = DEFAULT_MAX_DISPLAY_VERTICES,
    max_display_frames: int = DEFAULT_MAX_DISPLAY_FRAMES,
    geodesic_method: str = "auto",
    title: str | None = None,
    overwrite: bool = False,
) -> Path:
    """Write the offline viewer page of a result folder (atomically); return its path.

    Args:
        result_dir: a folder written by ``ncflow match`` (:func:`ncflow.io.result.read_result`).
        out_html: the page (default ``RESULT_DIR/view.html``).
        gt: ground truth for the error map (see :func:`ncflow.io.ground_truth.load_ground_truth`),
            or None for no error map.
        gt_format: its format (default from the suffix).
        target: the target mesh, needed when the folder has no ``target.ply`` (older results);
            when given it replaces ``target.ply`` and must have the result's target vertex count.
        max_display_vertices: source and target above this size are shown decimated (≥ 100).
        max_display_frames: at most this many frames are embedded (≥ 2).
        geodesic_method: solver of the geodesic errors.
        title: the page's title (default: the folder's name).
        overwrite: replace an existing file that is not a page of ``ncflow view``.

    Raises:
        InputError: one line naming the file: a broken result folder, no target mesh, a target or
            ground truth that does not fit the result, an unusable output path. Nothing is written.
    """
    result_dir = Path(result_dir)
    _check_budget(max_display_vertices, "the vertex budget (--max-vertices)", 100)
    _check_budget(max_display_frames, "the frame budget (--max-frames)", 2)
    out = check_view_output(result_dir / "view.html" if out_html is None else out_html, overwrite)
    result = read_result(result_dir, check_animation=False)
    _check_barycentric(result.map_bary, result_dir / "map_tgt_to_src.npz")
    result.target_vertices, result.target_faces = result_target(result, target, result_dir)
    errors = None
    if gt is not None:
        source = Mesh(result.frames[0], result.source_faces, name=str(result_dir / "frames" / "frame_0000.ply"))
        tmesh = Mesh(result.target_vertices, result.target_faces, name=str(target or result_dir / "target.ply"))
        truth = load_ground_truth(gt, source, tmesh, gt_format)
        if truth.n_target != tmesh.n_vertices:
            raise InputError(f"is for {truth.n_target} target vertices, the target has {tmesh.n_vertices}", truth.name)
        errors = geodesic_error_map(source, result.map_face, result.map_bary, truth, method=geodesic_method)
    return write_page(
        result,
        out,
        errors=errors,
        max_display_vertices=max_display_vertices,
        max_display_frames=max_display_frames,
        title=title if title is not None else result_dir.resolve().name,
    )


def write_page(
    result: ResultFolder,
    out: Path,
    *,
    errors: Float[np.ndarray, " Vt"] | None = None,
    max_display_vertices: int = DEFAULT_MAX_DISPLAY_VERTICES,
    max_display_frames: int = DEFAULT_MAX_DISPLAY_FRAMES,
    title: str = "",
    animation: tuple[bytes, Int[np.ndarray, " K"]] | None = None,
) -> Path:
    """Write the page of a loaded result (its ``target_vertices`` / ``target_faces`` set; ``out`` checked
    by :func:`check_view_output`), atomically; return ``out``. ``ncflow track`` folders come here too, as a
    :class:`~ncflow.io.result.ResultFolder` of the registered frames (:func:`ncflow.track.folder.track_as_result`)
    with their ``animation`` (:func:`ncflow.track.folder.track_animation`; see :func:`view_data`).
    """
    _check_budget(max_display_vertices, "the vertex budget (--max-vertices)", 100)
    _check_budget(max_display_frames, "the frame budget (--max-frames)", 2)
    data = view_data(
        result,
        errors=errors,
        max_display_vertices=max_display_vertices,
        max_display_frames=max_display_frames,
        title=title,
        animation=animation,
    )
    page = render_page(data, viewer_script())
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out, page.encode("ascii"))
    return out
