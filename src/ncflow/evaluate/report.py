"""Evaluation reports: score a result folder, strict JSON, plots and headless renders, benchmark reports.

One result (``ncflow evaluate``)
--------------------------------
:func:`evaluate_result` reads a result folder (the output contract, :func:`ncflow.export.read_result`),
the two meshes and the ground truth, and computes every metric of docs/evaluation.md with
:func:`~ncflow.evaluate.evaluate_correspondence`: the geodesic error of ``map_tgt_to_src`` against the
ground truth, the Chamfer distance of ``deformed_source`` to the target, conformal distortion,
volume change and inverted triangles over all frames; the bone-constraint violation is read from
``metrics.json`` (``constraints``). :func:`write_evaluation` then writes into the folder

* ``evaluation.json`` — strict JSON (no NaN/Infinity: non-finite numbers are written as ``null``
  and their locations listed under ``non_finite_as_null``); keys: ``format``, ``inputs``, sizes,
  ``headline`` (the AUCs and means a table needs), ``summary`` (the full summary of
  :func:`~ncflow.evaluate.evaluate_correspondence`), ``bones``, ``curves`` (cumulative curves on 101
  thresholds, used by the benchmark's mean curves), ``timings``, ``plots``;
* ``eval_cumulative.png`` — cumulative curves: geodesic (τ 0–0.20), Chamfer (0–0.10, the mean of
  both directions' curves, so its AUC is the reported Chamfer AUC), conformal K − 1 (0–0.15), AUC in
  the legends;
* ``eval_geodesic_error.png`` — the target coloured by its per-vertex geodesic error (0 to 0.20,
  two views; grey: no ground truth);
* ``eval_color_transfer.png`` — a smooth colour function of the source (its normalised
  coordinates as RGB) on the source, transferred to the target through the predicted map and
  through the ground truth.

Plots are written first (temporary names, then renamed) and ``evaluation.json`` last, so a folder
with ``evaluation.json`` is completely evaluated. Figures are drawn with matplotlib's Agg canvas
(``matplotlib.figure.Figure``, no pyplot, no global backend change), headless.

Benchmark reports
-----------------
:func:`run_row` extracts one table row from an ``evaluation.json``; :func:`aggregate_rows` gives
mean ± standard deviation per method and dataset; :func:`write_benchmark_report` writes
``report.json``, ``report.md`` and ``curves_<dataset>.png`` (mean cumulative curve per method with a
95 % bootstrap confidence band of the mean across pairs, :func:`mean_curve_band`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError
from ncflow.evaluate.ground_truth import GroundTruth
from ncflow.evaluate.metrics import TAU_MAX, pck_curve
from ncflow.mesh import Mesh

__all__ = [
    "CURVE_METRICS",
    "EVALUATION_FILE",
    "EVALUATION_PLOTS",
    "Evaluation",
    "aggregate_rows",
    "bone_section",
    "cumulative_curves",
    "evaluate_result",
    "evaluation_text",
    "json_safe",
    "mean_curve_band",
    "plot_benchmark_curves",
    "plot_cumulative_curves",
    "render_color_transfer",
    "render_error_map",
    "run_row",
    "source_colors",
    "transfer_colors",
    "write_benchmark_report",
    "write_evaluation",
]

EVALUATION_FILE = "evaluation.json"
EVALUATION_PLOTS = {
    "cumulative": "eval_cumulative.png",
    "geodesic_error": "eval_geodesic_error.png",
    "color_transfer": "eval_color_transfer.png",
}
CURVE_METRICS = ("geodesic", "chamfer", "conformal")
_CURVE_TITLES = {
    "geodesic": "geodesic error / sqrt(area)",
    "chamfer": "Chamfer distance (unit cube)",
    "conformal": "conformal distortion K - 1",
}
_N_THRESHOLDS = 101
_NO_DATA_RGB = np.array([0.72, 0.72, 0.72])


# ----------------------------------------------------------------------------------------------
# Strict JSON


def json_safe(value: Any, where: str = "") -> tuple[Any, list[str]]:
    """A JSON-ready copy of ``value`` with non-finite floats replaced by None.

    Numpy scalars and arrays become Python numbers and lists, tuples become lists, Paths strings.

    Returns:
        (the copy, the dotted locations of the values that were non-finite, e.g. ``summary.volume_change[0]``).
    """
    replaced: list[str] = []

    def walk(v: Any, at: str) -> Any:
        if isinstance(v, dict):
            return {str(k): walk(x, f"{at}.{k}" if at else str(k)) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [walk(x, f"{at}[{i}]") for i, x in enumerate(v)]
        if isinstance(v, np.ndarray):
            return walk(v.tolist(), at)
        if isinstance(v, (bool, np.bool_)):
            return bool(v)
        if isinstance(v, (int, np.integer)):
            return int(v)
        if isinstance(v, (float, np.floating)):
            if math.isfinite(float(v)):
                return float(v)
            replaced.append(at)
            return None
        if isinstance(v, os.PathLike):
            return os.fspath(v)
        return v

    return walk(value, where), replaced


def _dump_strict(record: dict) -> str:
    """Serialise a JSON-safe record; refuses NaN/Infinity (they must have been replaced)."""
    return json.dumps(record, indent=1, allow_nan=False) + "\n"


def _atomic_write_text(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


# ----------------------------------------------------------------------------------------------
# Evaluating one result folder


@dataclasses.dataclass
class Evaluation:
    """Everything needed to write an evaluation (see :func:`evaluate_result`).

    Attributes:
        record: the content of ``evaluation.json`` before :func:`json_safe` (may hold NaN/inf).
        arrays: per-vertex / per-triangle arrays of :func:`~ncflow.evaluate.evaluate_correspondence`.
        source, target: the meshes.
        pred_face, pred_bary: the predicted source point of every target vertex.
        ground_truth: the ground truth.
        result_dir: the result folder.
    """

    record: dict
    arrays: dict
    source: Mesh
    target: Mesh
    pred_face: Int[np.ndarray, " Vt"]
    pred_bary: Float[np.ndarray, "Vt 3"]
    ground_truth: GroundTruth
    result_dir: Path


def _check_result_matches(result: dict, source: Mesh, target: Mesh) -> None:
    if result["n_source"] != source.n_vertices or not np.array_equal(result["source_faces"], source.faces):
        raise InputError(
            f"the result's source has {result['n_source']} vertices and {len(result['source_faces'])} faces, "
            f"this mesh has {source.n_vertices} and {source.n_faces} (not the source of this result)",
            source.name,
        )
    if result["n_target"] != target.n_vertices:
        raise InputError(
            f"the result maps {result['n_target']} target vertices, this mesh has {target.n_vertices} "
            "(not the target of this result)",
            target.name,
        )


def _number(value: Any) -> float:
    """A float from a JSON value (None and non-numbers become NaN)."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")


def bone_section(metrics: dict, scale: float) -> dict | None:
    """Bone-constraint violation from ``metrics.json`` (``constraints``), or None when absent.

    Per bone: g (endpoint, trajectory; normalised units as written by the matcher), the ratio
    max(g_endpoint, g_trajectory)/ε and the RMS distance of the samples to their rigid reference in
    unit-cube units (the matcher's user-unit value times ``scale``).
    """
    c = metrics.get("constraints")
    if not isinstance(c, dict):
        return None
    eps = _number(c.get("eps"))
    per_bone = []
    for b in c.get("bones") or []:
        if not isinstance(b, dict):
            continue
        g_ep, g_tr = _number(b.get("g_endpoint")), _number(b.get("g_trajectory"))
        per_bone.append(
            {
                "bone": b.get("bone"),
                "g_endpoint": g_ep,
                "g_trajectory": g_tr,
                "ratio": float(np.nanmax([g_ep, g_tr]) / eps) if np.isfinite([g_ep, g_tr]).any() else float("nan"),
                "rms_distance_unit_cube": _number(b.get("rms_distance_endpoint")) * scale,
                "satisfied": b.get("satisfied"),
            }
        )
    ratios = [b["ratio"] for b in per_bone if np.isfinite(b["ratio"])]
    max_ratio = _number(c.get("max_violation_ratio"))
    if not np.isfinite(max_ratio) and ratios:
        max_ratio = max(ratios)
    rms = [b["rms_distance_unit_cube"] for b in per_bone if np.isfinite(b["rms_distance_unit_cube"])]
    return {
        "mode": c.get("mode"),
        "eps": eps,
        "units": c.get("units"),
        "max_violation_ratio": max_ratio,
        "all_satisfied": c.get("all_satisfied"),
        "max_rms_distance_unit_cube": max(rms) if rms else float("nan"),
        "per_bone": per_bone,
    }


def cumulative_curves(arrays: dict, tau_max: dict | None = None, n_thresholds: int = _N_THRESHOLDS) -> dict[str, dict]:
    """Cumulative curves PCK(τ) of the geodesic, Chamfer and conformal errors.

    The Chamfer curve is the mean of the two directions' curves (its area is the mean of their
    AUCs, the reported Chamfer AUC). Metrics without data are left out.

    Returns:
        ``{metric: {"tau_max": τmax, "tau": [...], "pck": [...]}}``.
    """
    taus = dict(TAU_MAX, **(tau_max or {}))
    out: dict[str, dict] = {}

    def add(name: str, pck: np.ndarray, tau: np.ndarray) -> None:
        out[name] = {"tau_max": float(taus[name]), "tau": tau.tolist(), "pck": pck.tolist()}

    if "geodesic" in arrays:
        tau, pck = pck_curve(arrays["geodesic"], taus["geodesic"], n_thresholds)
        add("geodesic", pck, tau)
    if "chamfer_src_to_tgt" in arrays:
        tau, a = pck_curve(arrays["chamfer_src_to_tgt"], taus["chamfer"], n_thresholds)
        _, b = pck_curve(arrays["chamfer_tgt_to_src"], taus["chamfer"], n_thresholds)
        add("chamfer", 0.5 * (a + b), tau)
    if "conformal" in arrays:
        tau, pck = pck_curve(arrays["conformal"], taus["conformal"], n_thresholds)
        add("conformal", pck, tau)
    return out


def _headline(summary: dict, bones: dict | None) -> dict:
    def get(metric: str, key: str) -> float:
        return _number((summary.get(metric) or {}).get(key))

    vol = np.asarray(summary.get("volume_change", []), dtype=np.float64)
    inv = summary.get("inverted_triangles", [])
    return {
        "geodesic_auc": get("geodesic", "auc"),
        "chamfer_auc": get("chamfer", "auc"),
        "conformal_auc": get("conformal", "auc"),
        "geodesic_mean": get("geodesic", "mean"),
        "chamfer_mean": get("chamfer", "mean"),
        "conformal_mean": get("conformal", "mean"),
        "max_abs_volume_change": float(np.max(np.abs(vol))) if vol.size else float("nan"),
        "max_inverted_triangles": int(max(inv)) if inv else 0,
        "max_bone_violation_ratio": _number(bones["max_violation_ratio"]) if bones else None,  # None: no constraints
    }


def evaluate_result(
    result_dir: str | os.PathLike,
    source: str | os.PathLike | Mesh,
    target: str | os.PathLike | Mesh,
    gt: str | os.PathLike | tuple | list | GroundTruth,
    gt_format: str | None = None,
    *,
    geodesic_method: str = "auto",
) -> Evaluation:
    """Score a result folder of ``ncflow match`` against ground truth (nothing is written).

    Args:
        result_dir: the folder with the output contract.
        source, target: the meshes the result was computed from (paths or meshes).
        gt: ground truth: ``"identity"``, a file, a pair of template ``.vts`` files, or a
            :class:`GroundTruth` (see :func:`~ncflow.evaluate.load_ground_truth`).
        gt_format: the ground-truth format (default: from the suffix).
        geodesic_method: see :func:`~ncflow.evaluate.geodesic_errors`.

    Returns:
        :class:`Evaluation`.

    Raises:
        InputError: one line naming the file: missing or broken result files, meshes that are not
            the result's, ground truth of the wrong size or format.
    """
    from ncflow import __version__
    from ncflow.evaluate.ground_truth import load_ground_truth
    from ncflow.evaluate.metrics import evaluate_correspondence
    from ncflow.export import read_result
    from ncflow.mesh import load_mesh

    t0 = time.perf_counter()
    result_dir = Path(result_dir)
    result = read_result(result_dir)
    src = source if isinstance(source, Mesh) else load_mesh(source)
    tgt = target if isinstance(target, Mesh) else load_mesh(target)
    _check_result_matches(result, src, tgt)
    truth = gt if isinstance(gt, GroundTruth) else load_ground_truth(gt, src, tgt, gt_format)
    if truth.n_target != tgt.n_vertices:
        raise InputError(
            f"ground truth is for {truth.n_target} target vertices, the target has {tgt.n_vertices}", truth.name
        )
    out = evaluate_correspondence(
        src,
        tgt,
        result["map_face"],
        result["map_bary"],
        truth.face,
        truth.bary,
        deformed_vertices=result["deformed_source"],
        frames=result["frames"],
        gt_index=truth.target_index,
        geodesic_method=geodesic_method,
    )
    summary, arrays = out["summary"], out["arrays"]
    metrics = result["metrics"]
    bones = bone_section(metrics, summary["unit_cube_scale"])
    timings = metrics.get("timings") if isinstance(metrics.get("timings"), dict) else {}
    record = {
        "format": "ncflow-evaluation/1",
        "ncflow_version": __version__,
        "inputs": {
            "result_dir": str(result_dir),
            "source": src.name,
            "target": tgt.name,
            "gt": truth.name
            if isinstance(gt, GroundTruth)
            else (list(map(str, gt)) if isinstance(gt, (tuple, list)) else str(gt)),
            "gt_format": gt_format,
        },
        "n_source": src.n_vertices,
        "n_target": tgt.n_vertices,
        "n_frames": int(result["n_frames"]),
        "n_ground_truth": int(truth.target_index.size),
        "headline": _headline(summary, bones),
        "summary": summary,
        "bones": bones,
        "curves": cumulative_curves(arrays),
        "timings": {"match": timings.get("total"), "evaluate": time.perf_counter() - t0},  # match: from metrics.json
    }
    return Evaluation(record, arrays, src, tgt, result["map_face"], result["map_bary"], truth, result_dir)


def write_evaluation(evaluation: Evaluation, *, plots: bool = True, extra: dict | None = None) -> dict:
    """Write ``evaluation.json`` (last) and the PNG plots into the result folder.

    Args:
        evaluation: from :func:`evaluate_result`.
        plots: also draw the three PNGs (:data:`EVALUATION_PLOTS`).
        extra: more entries for ``evaluation.json`` (e.g. the benchmark's method and pair).

    Returns:
        the record as written (strict JSON: non-finite values are null, listed in
        ``non_finite_as_null``).
    """
    out_dir = evaluation.result_dir
    record = dict(evaluation.record)
    record.update(extra or {})
    t0 = time.perf_counter()
    written: dict[str, str] = {}
    tmps: list[tuple[Path, Path]] = []
    try:
        if plots:
            for key, draw in _plot_writers(evaluation).items():
                final = out_dir / EVALUATION_PLOTS[key]
                tmp = out_dir / f".{final.stem}.tmp-{os.getpid()}{final.suffix}"
                tmps.append((tmp, final))
                draw(tmp)
                written[key] = final.name
        record["plots"] = written
        record["timings"] = dict(record["timings"], plots=time.perf_counter() - t0)
        safe, replaced = json_safe(record)
        safe["non_finite_as_null"] = replaced
        text = _dump_strict(safe)
        for tmp, final in tmps:
            os.replace(tmp, final)
        _atomic_write_text(out_dir / EVALUATION_FILE, text)
    except OSError as exc:
        raise InputError(f"cannot write the evaluation ({exc.strerror or exc})", out_dir) from None
    finally:
        for tmp, _ in tmps:
            if tmp.exists():
                tmp.unlink()
    return safe


def _plot_writers(ev: Evaluation) -> dict:
    rec = ev.record
    aucs = {m: rec["headline"][f"{m}_auc"] for m in CURVE_METRICS}
    title = Path(rec["inputs"]["result_dir"]).name
    return {
        "cumulative": lambda p: plot_cumulative_curves(rec["curves"], aucs, p, title=title),
        "geodesic_error": lambda p: render_error_map(
            ev.target.vertices,
            ev.target.faces,
            ev.arrays["geodesic"],
            p,
            vmax=TAU_MAX["geodesic"],
            title=f"{title}: geodesic error on the target",
        ),
        "color_transfer": lambda p: render_color_transfer(
            ev.source, ev.target, ev.pred_face, ev.pred_bary, ev.ground_truth, p, title=title
        ),
    }


def _fmt(value: Any, spec: str = ".4f") -> str:
    v = _number(value)
    return format(v, spec) if np.isfinite(v) else "n/a"


def evaluation_text(record: dict) -> str:
    """A short human-readable summary of an evaluation record (a few lines)."""
    h, s = record["headline"], record["summary"]
    lines = [
        (
            f"evaluation of {record['inputs']['result_dir']}: source {record['n_source']} vertices, target "
            f"{record['n_target']} vertices ({record['n_ground_truth']} with ground truth), {record['n_frames']} frames"
        ),
        (
            f"  geodesic error / sqrt(area): mean {_fmt(h['geodesic_mean'])}, median "
            f"{_fmt(s['geodesic'].get('median'))}, AUC(0.20) {_fmt(h['geodesic_auc'], '.3f')}"
        ),
    ]
    if "chamfer" in s:
        lines.append(
            f"  Chamfer (unit cube): mean {_fmt(h['chamfer_mean'])}, AUC(0.10) {_fmt(h['chamfer_auc'], '.3f')} "
            f"(source->target {_fmt(s['chamfer_src_to_tgt'].get('auc'), '.3f')}, "
            f"target->source {_fmt(s['chamfer_tgt_to_src'].get('auc'), '.3f')})"
        )
    if "conformal" in s:
        lines.append(
            f"  conformal K-1 over all frames: mean {_fmt(h['conformal_mean'])}, AUC(0.15) "
            f"{_fmt(h['conformal_auc'], '.3f')}; max |volume change| {_fmt(h['max_abs_volume_change'], '.2%')}; "
            f"inverted triangles (max per frame, {s.get('inverted_mode')}) {h['max_inverted_triangles']}"
        )
    b = record.get("bones")
    if b:
        state = {True: "all bones within tolerance", False: "some bones above tolerance"}.get(
            b.get("all_satisfied"), ""
        )
        lines.append(
            f"  bones ({b.get('mode')}): largest violation g/eps {_fmt(b['max_violation_ratio'], '.3g')}, largest RMS "
            f"distance to the rigid motion {_fmt(b['max_rms_distance_unit_cube'], '.2e')} (unit cube) {state}".rstrip()
        )
    else:
        lines.append("  bones: no constraint values in metrics.json")
    if record.get("non_finite_as_null"):
        n = len(record["non_finite_as_null"])
        lines.append(
            f"  note: {n} non-finite value(s) written as null in {EVALUATION_FILE} (listed under non_finite_as_null)"
        )
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------------
# Plots and renders


def _figure(width: float, height: float):
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), dpi=100, layout="constrained")


def plot_cumulative_curves(curves: dict, aucs: dict, path: str | os.PathLike, title: str | None = None) -> None:
    """Cumulative curves (one panel per metric of :func:`cumulative_curves`), AUC in the legend; a PNG."""
    names = [m for m in CURVE_METRICS if m in curves]
    fig = _figure(4.0 * max(1, len(names)), 3.6)
    axes = fig.subplots(1, max(1, len(names)), squeeze=False)[0]
    for ax, name in zip(axes, names):
        c = curves[name]
        ax.plot(c["tau"], c["pck"], lw=2, color="C0", label=f"AUC {_fmt(aucs.get(name), '.3f')}")
        _curve_axes(ax, name, c["tau_max"])
        ax.legend(loc="lower right")
    if title:
        fig.suptitle(title)
    fig.savefig(path, format="png")


def _curve_axes(ax, name: str, tau_max: float) -> None:
    ax.set_xlim(0.0, tau_max)
    ax.set_ylim(0.0, 1.01)
    ax.set_xlabel(_CURVE_TITLES[name])
    ax.set_ylabel("fraction below threshold")
    ax.grid(alpha=0.3)


def _view_coordinates(vertices: np.ndarray) -> np.ndarray:
    """Model y-up coordinates to matplotlib's z-up frame by a proper rotation (x, -z, y)."""
    v = np.asarray(vertices, dtype=np.float64)
    return np.stack([v[:, 0], -v[:, 2], v[:, 1]], axis=1)


def _draw_mesh(ax, vertices: np.ndarray, faces: np.ndarray, face_rgb: np.ndarray, azim: float) -> None:
    """Lambert-shaded triangles (painter's order), equal aspect, no axes."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    p = _view_coordinates(vertices)
    tri = p[np.asarray(faces, dtype=np.int64)]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    el, az = np.radians(20.0), np.radians(azim)
    light = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    shade = 0.35 + 0.65 * np.abs(n @ light)
    ax.add_collection3d(Poly3DCollection(tri, facecolors=np.clip(face_rgb * shade[:, None], 0, 1), edgecolors="none"))
    lo, hi = p.min(0), p.max(0)
    side = np.maximum(hi - lo, 1e-3 * float(np.max(hi - lo)))  # flat shapes keep a visible box
    ax.set_xlim(lo[0], lo[0] + side[0])
    ax.set_ylim(lo[1], lo[1] + side[1])
    ax.set_zlim(lo[2], lo[2] + side[2])
    ax.set_box_aspect(tuple(side), zoom=1.3)  # equal scale on every axis
    ax.view_init(elev=20.0, azim=azim)
    ax.set_axis_off()


def _face_values(faces: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Per-face mean of per-vertex values (NaN if any corner is NaN)."""
    return np.asarray(values, dtype=np.float64)[np.asarray(faces, dtype=np.int64)].mean(axis=1)


def render_error_map(
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    errors: Float[np.ndarray, " V"],
    path: str | os.PathLike,
    vmax: float = TAU_MAX["geodesic"],
    title: str | None = None,
) -> None:
    """Render a mesh coloured by a per-vertex error (0 to ``vmax``, clipped; NaN grey), two views; a PNG."""
    import matplotlib

    cmap = matplotlib.colormaps["turbo"]
    fe = _face_values(faces, errors)
    rgb = cmap(np.clip(np.nan_to_num(fe, nan=0.0, posinf=vmax) / vmax, 0.0, 1.0))[:, :3]
    rgb[np.isnan(fe)] = _NO_DATA_RGB
    fig = _figure(10.0, 5.0)
    for k, azim in enumerate((-60.0, 120.0)):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        _draw_mesh(ax, vertices, faces, rgb, azim)
    mappable = matplotlib.cm.ScalarMappable(norm=matplotlib.colors.Normalize(0.0, vmax), cmap=cmap)
    fig.colorbar(mappable, ax=fig.axes, shrink=0.7, label="error (grey: no ground truth)")
    if title:
        fig.suptitle(title)
    fig.savefig(path, format="png")


def source_colors(vertices: Float[np.ndarray, "V 3"]) -> Float[np.ndarray, "V 3"]:
    """A smooth colour per vertex: the coordinates normalised to [0, 1] on the bounding box, as RGB."""
    v = np.asarray(vertices, dtype=np.float64)
    lo, hi = v.min(0), v.max(0)
    return (v - lo) / np.where(hi > lo, hi - lo, 1.0)


def transfer_colors(
    colors: Float[np.ndarray, "Vs 3"],
    faces: Int[np.ndarray, "Fs 3"],
    face: Int[np.ndarray, " n"],
    bary: Float[np.ndarray, "n 3"],
) -> Float[np.ndarray, "n 3"]:
    """Colours at source surface points (face, barycentric): the barycentric mix of the corners' colours."""
    corners = np.asarray(colors)[np.asarray(faces, dtype=np.int64)[np.asarray(face, dtype=np.int64)]]
    return np.einsum("nk,nkc->nc", np.asarray(bary, dtype=np.float64), corners)


def render_color_transfer(
    source: Mesh,
    target: Mesh,
    pred_face: Int[np.ndarray, " Vt"],
    pred_bary: Float[np.ndarray, "Vt 3"],
    ground_truth: GroundTruth,
    path: str | os.PathLike,
    title: str | None = None,
) -> None:
    """Source coloured by :func:`source_colors`, and the target coloured through the predicted map
    and through the ground truth (grey where there is none), side by side; a PNG."""
    cs = source_colors(source.vertices)
    pred = transfer_colors(cs, source.faces, pred_face, pred_bary)
    truth = np.tile(_NO_DATA_RGB, (target.n_vertices, 1))
    truth[ground_truth.target_index] = transfer_colors(cs, source.faces, ground_truth.face, ground_truth.bary)
    panels = [
        ("source", source, cs),
        ("target through the predicted map", target, pred),
        ("target through the ground truth", target, truth),
    ]
    fig = _figure(13.5, 4.8)
    for k, (label, mesh, vc) in enumerate(panels):
        ax = fig.add_subplot(1, 3, k + 1, projection="3d")
        _draw_mesh(ax, mesh.vertices, mesh.faces, np.asarray(vc)[mesh.faces].mean(axis=1), -60.0)
        ax.set_title(label)
    if title:
        fig.suptitle(f"{title}: colour transfer through the correspondence")
    fig.savefig(path, format="png")


# ----------------------------------------------------------------------------------------------
# Benchmark reports

_ROW_VALUES = (
    "geodesic_auc",
    "chamfer_auc",
    "conformal_auc",
    "geodesic_mean",
    "chamfer_mean",
    "conformal_mean",
    "max_bone_violation_ratio",
    "match_seconds",
    "evaluate_seconds",
    "wall_seconds",
)
_TABLE_COLUMNS = (
    ("geodesic_auc", "geodesic AUC", ".3f"),
    ("chamfer_auc", "Chamfer AUC", ".3f"),
    ("conformal_auc", "conformal AUC", ".3f"),
    ("geodesic_mean", "geodesic mean", ".4f"),
    ("chamfer_mean", "Chamfer mean", ".4f"),
    ("conformal_mean", "conformal mean", ".4f"),
)


def run_row(record: dict) -> dict:
    """One benchmark table row from an ``evaluation.json`` record (numbers as floats, NaN when null)."""
    h, t = record.get("headline", {}), record.get("timings", {})
    match, ev = _number(t.get("match")), _number(t.get("evaluate")) + _number(t.get("plots", 0.0))
    row = {k: _number(h.get(k)) for k in _ROW_VALUES[:7]}
    row.update(match_seconds=match, evaluate_seconds=ev, wall_seconds=match + ev)
    row["curves"] = {m: np.asarray([_number(x) for x in c["pck"]]) for m, c in (record.get("curves") or {}).items()}
    row["tau_max"] = {m: _number(c.get("tau_max")) for m, c in (record.get("curves") or {}).items()}
    return row


def _mean_std(values: list[float]) -> dict:
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    return {
        "mean": float(v.mean()) if v.size else float("nan"),
        "std": float(v.std(ddof=1)) if v.size > 1 else float("nan"),
        "n": int(v.size),
    }


def mean_curve_band(
    curves: Float[np.ndarray, "n k"], level: float = 0.95, n_boot: int = 1000, seed: int = 0
) -> tuple[Float[np.ndarray, " k"], Float[np.ndarray, " k"], Float[np.ndarray, " k"]]:
    """Mean of n curves and a bootstrap confidence band of the mean (percentile method).

    With one curve the band is the curve itself.

    Returns:
        (mean, lower, upper), each (k,).
    """
    c = np.asarray(curves, dtype=np.float64)
    mean = c.mean(axis=0)
    if c.shape[0] < 2:
        return mean, mean.copy(), mean.copy()
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, c.shape[0], size=(int(n_boot), c.shape[0]))
    boot = c[idx].mean(axis=1)
    alpha = 0.5 * (1.0 - level)
    return mean, np.quantile(boot, alpha, axis=0), np.quantile(boot, 1.0 - alpha, axis=0)


def aggregate_rows(rows: list[dict], methods: list[str]) -> list[dict]:
    """Mean ± sample standard deviation (ddof = 1) per method and dataset of the finished runs.

    ``rows`` carry ``method``, ``dataset``, ``status`` (``"ok"`` rows are aggregated, others counted
    as failed) and the values of :func:`run_row`. With more than one dataset each method also gets
    an ``"all"`` group. The largest bone violation is the maximum over the pairs (and its mean).

    Returns:
        one dict per (method, dataset): ``method``, ``dataset``, ``n``, ``n_failed`` and per value
        ``{"mean", "std", "n"}``; ``max_bone_violation_ratio`` also has ``"max"``.
    """
    datasets = sorted({r["dataset"] for r in rows})
    groups = datasets + (["all"] if len(datasets) > 1 else [])
    out = []
    for method in methods:
        for ds in groups:
            sel = [r for r in rows if r["method"] == method and (ds == "all" or r["dataset"] == ds)]
            ok = [r for r in sel if r["status"] == "ok"]
            if not sel:
                continue
            entry = {"method": method, "dataset": ds, "n": len(ok), "n_failed": len(sel) - len(ok)}
            for key in _ROW_VALUES:
                entry[key] = _mean_std([r[key] for r in ok])
            bones = np.asarray([r["max_bone_violation_ratio"] for r in ok], dtype=np.float64)
            bones = bones[np.isfinite(bones)]
            entry["max_bone_violation_ratio"]["max"] = float(bones.max()) if bones.size else float("nan")
            out.append(entry)
    return out


def plot_benchmark_curves(
    groups: dict[str, list[dict]], path: str | os.PathLike, title: str | None = None, labels: dict | None = None
) -> None:
    """Mean cumulative curve per method with a 95 % bootstrap band of the mean (Figs. 21–23 style).

    Args:
        groups: ``{method: [run rows]}`` (rows of :func:`run_row` with ``curves`` and ``tau_max``).
        path: the PNG.
        title: figure title.
        labels: display names of the methods.
    """
    fig = _figure(4.2 * len(CURVE_METRICS), 3.8)
    axes = fig.subplots(1, len(CURVE_METRICS), squeeze=False)[0]
    for ax, name in zip(axes, CURVE_METRICS):
        tau_max = TAU_MAX[name]
        for k, (method, rows) in enumerate(groups.items()):
            curves = [r["curves"][name] for r in rows if name in r["curves"] and np.all(np.isfinite(r["curves"][name]))]
            if not curves:
                continue
            tau_max = rows[0]["tau_max"].get(name, tau_max)
            tau = np.linspace(0.0, tau_max, len(curves[0]))
            mean, lo, hi = mean_curve_band(np.stack(curves))
            aucs = _mean_std([r[f"{name}_auc"] for r in rows])
            label = (labels or {}).get(method, method)
            std = "" if not np.isfinite(aucs["std"]) else f" ± {aucs['std']:.3f}"
            ax.plot(tau, mean, lw=2, color=f"C{k}", label=f"{label} ({aucs['mean']:.3f}{std}, n={len(curves)})")
            ax.fill_between(tau, lo, hi, color=f"C{k}", alpha=0.2, lw=0)
        _curve_axes(ax, name, tau_max)
        ax.legend(loc="lower right", fontsize=7, title="AUC mean ± std", title_fontsize=7)
    if title:
        fig.suptitle(title)
    fig.savefig(path, format="png")


def _cell(entry: dict, key: str, spec: str) -> str:
    v = entry[key]
    if not np.isfinite(v["mean"]):
        return "–"
    return f"{v['mean']:{spec}}" + (f" ± {v['std']:{spec}}" if np.isfinite(v["std"]) else "")


def _markdown(report: dict, labels: dict) -> str:
    lines = [
        "# ncflow benchmark",
        "",
        f"Pairs: `{report['pairs_csv']}` ({report['n_pairs']} pairs). Methods: "
        + ", ".join(f"{labels[m['id']]} (`runs/{m['id']}`)" for m in report["methods"])
        + ".",
        "",
        (
            "Values are mean ± sample standard deviation across pairs. AUCs of the cumulative curves: "
            "geodesic error / sqrt(source area) up to 0.20, Chamfer distance (unit cube) up to 0.10, conformal "
            "distortion K − 1 up to 0.15 (docs/evaluation.md). Bone g/ε: largest constraint value over the bones "
            "divided by ε, maximum over pairs. Seconds: matcher time (setup + training + outputs) plus evaluation."
        ),
        "",
    ]
    for ds in report["datasets"] + (["all"] if len(report["datasets"]) > 1 else []):
        entries = [e for e in report["summary"] if e["dataset"] == ds]
        lines += [
            f"## {ds}",
            "",
            "| method | n | " + " | ".join(c[1] for c in _TABLE_COLUMNS) + " | bone g/ε (max) | s/pair |",
            "|" + "---|" * (len(_TABLE_COLUMNS) + 4),
        ]
        for e in entries:
            cells = [_cell(e, key, spec) for key, _, spec in _TABLE_COLUMNS]
            bone = _fmt(e["max_bone_violation_ratio"]["max"], ".3g")
            n = f"{e['n']}" + (f" ({e['n_failed']} failed)" if e["n_failed"] else "")
            lines.append(
                f"| {labels[e['method']]} | {n} | "
                + " | ".join(cells)
                + f" | {bone} | {_cell(e, 'wall_seconds', '.1f')} |"
            )
        if ds in report["plots"]:
            lines += ["", f"![cumulative curves, {ds}]({report['plots'][ds]})"]
        lines.append("")
    lines += [
        "## Runs",
        "",
        "| method | pair | dataset | status | geodesic AUC | Chamfer AUC | conformal AUC | bone g/ε | s |",
        "|" + "---|" * 9,
    ]
    for r in report["runs"]:
        vals = [_fmt(r.get(k), ".3f") for k in ("geodesic_auc", "chamfer_auc", "conformal_auc")]
        lines.append(
            f"| {labels[r['method']]} | {r['pair']} | {r['dataset']} | {r['status']} | "
            + " | ".join(vals)
            + f" | {_fmt(r.get('max_bone_violation_ratio'), '.3g')} | {_fmt(r.get('wall_seconds'), '.1f')} |"
        )
    failed = [r for r in report["runs"] if r["status"] != "ok"]
    if failed:
        lines += ["", "## Failed runs", ""] + [f"- {r['method']}/{r['pair']}: {r.get('error')}" for r in failed]
    return "\n".join(lines) + "\n"


def write_benchmark_report(
    out_dir: str | os.PathLike,
    rows: list[dict],
    methods: list[dict],
    *,
    pairs_csv: str,
    n_pairs: int,
    plots: bool = True,
) -> dict:
    """Write ``report.json``, ``report.md`` and ``curves_<dataset>.png`` into ``out_dir``.

    Args:
        out_dir: the benchmark folder.
        rows: one per run: ``method``, ``pair``, ``dataset``, ``status`` (``"ok"`` or ``"failed"``),
            ``dir``, ``error`` and, for finished runs, the values of :func:`run_row`.
        methods: ``{"id", "label", "description", "config"}`` per method, in order.
        pairs_csv: the pairs file (for the record).
        n_pairs: number of pairs.
        plots: draw the curve plots.

    Returns:
        the report as written to ``report.json`` (strict JSON; see ``docs`` in the module docstring).
    """
    from ncflow import __version__

    out_dir = Path(out_dir)
    labels = {m["id"]: m["label"] for m in methods}
    ids = [m["id"] for m in methods]
    datasets = sorted({r["dataset"] for r in rows})
    plot_files: dict[str, str] = {}
    if plots:
        for ds in datasets + (["all"] if len(datasets) > 1 else []):
            groups = {
                m: [r for r in rows if r["method"] == m and r["status"] == "ok" and ds in ("all", r["dataset"])]
                for m in ids
            }
            groups = {m: g for m, g in groups.items() if g}
            if not groups:
                continue
            name = f"curves_{_slug(ds)}.png"
            tmp = out_dir / f".{name}.tmp-{os.getpid()}"
            try:
                plot_benchmark_curves(groups, tmp, title=f"dataset: {ds}", labels=labels)
                os.replace(tmp, out_dir / name)
            finally:
                if tmp.exists():
                    tmp.unlink()
            plot_files[ds] = name
    run_list = [{k: v for k, v in r.items() if k not in ("curves", "tau_max")} for r in rows]
    report = {
        "format": "ncflow-benchmark/1",
        "ncflow_version": __version__,
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "pairs_csv": str(pairs_csv),
        "n_pairs": int(n_pairs),
        "methods": methods,
        "datasets": datasets,
        "statistics": "mean and sample standard deviation (ddof=1; null for fewer than 2 pairs) over finished runs; "
        "curve bands: 95% bootstrap confidence band of the mean curve (1000 resamples)",
        "summary": aggregate_rows(rows, ids),
        "runs": run_list,
        "plots": plot_files,
    }
    markdown = _markdown(report, labels)
    safe, replaced = json_safe(report)
    safe["non_finite_as_null"] = replaced
    _atomic_write_text(out_dir / "report.json", _dump_strict(safe))
    _atomic_write_text(out_dir / "report.md", markdown)
    return safe


def _slug(text: str) -> str:
    import re

    return re.sub(r"[^A-Za-z0-9._-]+", "_", text) or "_"
