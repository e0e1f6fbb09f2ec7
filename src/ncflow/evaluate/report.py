"""The benchmark report: ``report.json``, ``report.md`` and ``curves_<dataset>.png`` in the benchmark folder.

:func:`write_benchmark_report` aggregates the runs (:mod:`ncflow.evaluate.aggregate`), draws the
mean curves per dataset (:mod:`ncflow.evaluate.plots`) and writes ``report.json`` — strict JSON
(:func:`~ncflow.io.arrays.json_safe`) with keys ``format``, ``ncflow_version``, ``created``,
``pairs_csv``, ``n_pairs``, ``methods``, ``datasets``, ``statistics``, ``summary`` (per method and
dataset), ``runs`` (per run), ``plots`` and ``non_finite_as_null`` — and ``report.md``, a table per
dataset, a table of the runs and the failed runs. Both files are written atomically.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from ncflow import __version__
from ncflow.evaluate.aggregate import TABLE_COLUMNS, aggregate_rows
from ncflow.evaluate.formatting import format_number
from ncflow.evaluate.plots import plot_benchmark_curves
from ncflow.io.arrays import dumps_strict, json_safe
from ncflow.io.atomic import atomic_path, atomic_write_text


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
            "| method | n | " + " | ".join(c[1] for c in TABLE_COLUMNS) + " | bone g/ε (max) | s/pair |",
            "|" + "---|" * (len(TABLE_COLUMNS) + 4),
        ]
        for e in entries:
            cells = [_cell(e, key, spec) for key, _, spec in TABLE_COLUMNS]
            bone = format_number(e["max_bone_violation_ratio"]["max"], ".3g")
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
        vals = [format_number(r.get(k), ".3f") for k in ("geodesic_auc", "chamfer_auc", "conformal_auc")]
        lines.append(
            f"| {labels[r['method']]} | {r['pair']} | {r['dataset']} | {r['status']} | "
            + " | ".join(vals)
            + f" | {format_number(r.get('max_bone_violation_ratio'), '.3g')}"
            + f" | {format_number(r.get('wall_seconds'), '.1f')} |"
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
            with atomic_path(out_dir / name) as tmp:
                plot_benchmark_curves(groups, tmp, title=f"dataset: {ds}", labels=labels)
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
    atomic_write_text(out_dir / "report.json", dumps_strict(safe))
    atomic_write_text(out_dir / "report.md", markdown)
    return safe


def _slug(text: str) -> str:
    import re

    return re.sub(r"[^A-Za-z0-9._-]+", "_", text) or "_"
