"""Scoring one result folder (``ncflow evaluate``): every metric of docs/evaluation.md, strict JSON and plots.

:func:`evaluate_result` reads a result folder (the output contract,
:func:`ncflow.io.result.read_result`), the two meshes and the ground truth, and computes every
metric of docs/evaluation.md with :func:`~ncflow.evaluate.evaluate_correspondence`: the geodesic
error of ``map_tgt_to_src`` against the ground truth, the Chamfer distance of ``deformed_source``
to the target, conformal distortion, volume change and inverted triangles over all frames; the
bone-constraint violation is read from ``metrics.json`` (``constraints``).
:func:`write_evaluation` then writes into the folder

* ``evaluation.json`` — strict JSON (no NaN/Infinity: non-finite numbers are written as ``null``
  and their locations listed under ``non_finite_as_null``, :func:`~ncflow.io.arrays.json_safe`); keys: ``format``,
  ``inputs``, sizes, ``headline`` (the AUCs and means a table needs), ``summary`` (the full summary
  of :func:`~ncflow.evaluate.evaluate_correspondence`), ``bones``, ``curves`` (cumulative curves on
  101 thresholds, used by the benchmark's mean curves), ``timings``, ``plots``;
* the figures of :mod:`ncflow.evaluate.plots`: ``eval_cumulative.png``,
  ``eval_geodesic_error.png`` and ``eval_color_transfer.png``.

Plots are written first (temporary names, then renamed) and ``evaluation.json`` last, so a folder
with ``evaluation.json`` is completely evaluated. :func:`evaluation_text` is the summary that
``ncflow evaluate`` prints.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import time
from pathlib import Path

import numpy as np
from jaxtyping import Float, Int

from ncflow import __version__
from ncflow.errors import InputError
from ncflow.evaluate.formatting import as_number, format_number
from ncflow.evaluate.metrics import TAU_MAX, evaluate_correspondence, pck_curve
from ncflow.evaluate.plots import EVALUATION_PLOTS, _plot_writers
from ncflow.geometry.cloud import PointCloud
from ncflow.geometry.mesh import Mesh
from ncflow.io.arrays import dumps_strict, json_safe
from ncflow.io.atomic import atomic_path, atomic_write_text
from ncflow.io.ground_truth import GroundTruth, load_ground_truth
from ncflow.io.meshes import load_mesh
from ncflow.io.points import load_target
from ncflow.io.result import ResultFolder, read_result

EVALUATION_FILE = "evaluation.json"
_N_THRESHOLDS = 101


# ----------------------------------------------------------------------------------------------
# Evaluating one result folder


@dataclasses.dataclass
class Evaluation:
    """Everything needed to write an evaluation (see :func:`evaluate_result`).

    Attributes:
        record: the content of ``evaluation.json`` before :func:`~ncflow.io.arrays.json_safe` (may hold NaN/inf).
        arrays: per-vertex / per-triangle arrays of :func:`~ncflow.evaluate.evaluate_correspondence`.
        source, target: the meshes.
        pred_face, pred_bary: the predicted source point of every target vertex.
        ground_truth: the ground truth.
        result_dir: the result folder.
    """

    record: dict
    arrays: dict
    source: Mesh
    target: Mesh | PointCloud
    pred_face: Int[np.ndarray, " Vt"]
    pred_bary: Float[np.ndarray, "Vt 3"]
    ground_truth: GroundTruth
    result_dir: Path


def _check_result_matches(result: ResultFolder, source: Mesh, target: Mesh | PointCloud) -> None:
    if result.n_source != source.n_vertices or not np.array_equal(result.source_faces, source.faces):
        raise InputError(
            f"the result's source has {result.n_source} vertices and {len(result.source_faces)} faces, "
            f"this mesh has {source.n_vertices} and {source.n_faces} (not the source of this result)",
            source.name,
        )
    if result.n_target != target.n_vertices:
        raise InputError(
            f"the result maps {result.n_target} target vertices, this mesh has {target.n_vertices} "
            "(not the target of this result)",
            target.name,
        )


def bone_section(metrics: dict, scale: float) -> dict | None:
    """Bone-constraint violation from ``metrics.json`` (``constraints``), or None when absent.

    Per bone: g (endpoint, trajectory; normalised units as written by the matcher), the ratio
    max(g_endpoint, g_trajectory)/ε and the RMS distance of the samples to their rigid reference in
    unit-cube units (the matcher's user-unit value times ``scale``).
    """
    c = metrics.get("constraints")
    if not isinstance(c, dict):
        return None
    eps = as_number(c.get("eps"))
    per_bone = []
    for b in c.get("bones") or []:
        if not isinstance(b, dict):
            continue
        g_ep, g_tr = as_number(b.get("g_endpoint")), as_number(b.get("g_trajectory"))
        per_bone.append(
            {
                "bone": b.get("bone"),
                "g_endpoint": g_ep,
                "g_trajectory": g_tr,
                "ratio": float(np.nanmax([g_ep, g_tr]) / eps) if np.isfinite([g_ep, g_tr]).any() else float("nan"),
                "rms_distance_unit_cube": as_number(b.get("rms_distance_endpoint")) * scale,
                "satisfied": b.get("satisfied"),
            }
        )
    ratios = [b["ratio"] for b in per_bone if np.isfinite(b["ratio"])]
    max_ratio = as_number(c.get("max_violation_ratio"))
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
        return as_number((summary.get(metric) or {}).get(key))

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
        "max_bone_violation_ratio": as_number(bones["max_violation_ratio"]) if bones else None,  # None: no constraints
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
        source: the source mesh the result was computed from (a path or a mesh).
        target: the target mesh (a path or a mesh).
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
    t0 = time.perf_counter()
    result_dir = Path(result_dir)
    result = read_result(result_dir)
    src = source if isinstance(source, Mesh) else load_mesh(source)
    tgt = target if isinstance(target, (Mesh, PointCloud)) else load_target(target)
    _check_result_matches(result, src, tgt)
    truth = gt if isinstance(gt, GroundTruth) else load_ground_truth(gt, src, tgt, gt_format)
    if truth.n_target != tgt.n_vertices:
        raise InputError(
            f"ground truth is for {truth.n_target} target vertices, the target has {tgt.n_vertices}", truth.name
        )
    out = evaluate_correspondence(
        src,
        tgt,
        result.map_face,
        result.map_bary,
        truth.face,
        truth.bary,
        deformed_vertices=result.deformed_source,
        frames=result.frames,
        gt_index=truth.target_index,
        geodesic_method=geodesic_method,
    )
    summary, arrays = out["summary"], out["arrays"]
    metrics = result.metrics
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
        "n_frames": int(result.n_frames),
        "n_ground_truth": int(truth.target_index.size),
        "headline": _headline(summary, bones),
        "summary": summary,
        "bones": bones,
        "curves": cumulative_curves(arrays),
        "timings": {"match": timings.get("total"), "evaluate": time.perf_counter() - t0},  # match: from metrics.json
    }
    return Evaluation(record, arrays, src, tgt, result.map_face, result.map_bary, truth, result_dir)


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
    try:
        with contextlib.ExitStack() as moves:  # the plots are moved into place when the block succeeds
            if plots:
                for key, draw in _plot_writers(evaluation).items():
                    final = out_dir / EVALUATION_PLOTS[key]
                    draw(moves.enter_context(atomic_path(final)))
                    written[key] = final.name
            record["plots"] = written
            record["timings"] = dict(record["timings"], plots=time.perf_counter() - t0)
            safe, replaced = json_safe(record)
            safe["non_finite_as_null"] = replaced
            text = dumps_strict(safe)
        atomic_write_text(out_dir / EVALUATION_FILE, text)
    except OSError as exc:
        raise InputError(f"cannot write the evaluation ({exc.strerror or exc})", out_dir) from None
    return safe


def evaluation_text(record: dict) -> str:
    """A short human-readable summary of an evaluation record (a few lines)."""
    h, s = record["headline"], record["summary"]
    lines = [
        (
            f"evaluation of {record['inputs']['result_dir']}: source {record['n_source']} vertices, target "
            f"{record['n_target']} vertices ({record['n_ground_truth']} with ground truth), {record['n_frames']} frames"
        ),
        (
            f"  geodesic error / sqrt(area): mean {format_number(h['geodesic_mean'])}, median "
            f"{format_number(s['geodesic'].get('median'))}, AUC(0.20) {format_number(h['geodesic_auc'], '.3f')}"
        ),
    ]
    if "chamfer" in s:
        lines.append(
            f"  Chamfer (unit cube): mean {format_number(h['chamfer_mean'])}, "
            f"AUC(0.10) {format_number(h['chamfer_auc'], '.3f')} "
            f"(source->target {format_number(s['chamfer_src_to_tgt'].get('auc'), '.3f')}, "
            f"target->source {format_number(s['chamfer_tgt_to_src'].get('auc'), '.3f')})"
        )
    if "conformal" in s:
        lines.append(
            f"  conformal K-1 over all frames: mean {format_number(h['conformal_mean'])}, AUC(0.15) "
            f"{format_number(h['conformal_auc'], '.3f')}; "
            f"max |volume change| {format_number(h['max_abs_volume_change'], '.2%')}; "
            f"inverted triangles (max per frame, {s.get('inverted_mode')}) {h['max_inverted_triangles']}"
        )
    b = record.get("bones")
    if b:
        state = {True: "all bones within tolerance", False: "some bones above tolerance"}.get(
            b.get("all_satisfied"), ""
        )
        lines.append(
            f"  bones ({b.get('mode')}): largest violation g/eps {format_number(b['max_violation_ratio'], '.3g')}, "
            f"largest RMS distance to the rigid motion {format_number(b['max_rms_distance_unit_cube'], '.2e')} "
            f"(unit cube) {state}".rstrip()
        )
    else:
        lines.append("  bones: no constraint values in metrics.json")
    if record.get("non_finite_as_null"):
        n = len(record["non_finite_as_null"])
        lines.append(
            f"  note: {n} non-finite value(s) written as null in {EVALUATION_FILE} (listed under non_finite_as_null)"
        )
    return "\n".join(lines)
