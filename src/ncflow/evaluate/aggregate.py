"""Benchmark statistics: one table row per run, mean ± standard deviation per method and dataset, curve bands.

:func:`run_row` extracts the headline values, timings and cumulative curves of one
``evaluation.json``; :func:`aggregate_rows` gives the mean and sample standard deviation
(ddof = 1) of every value per method and dataset (and over all datasets), and the largest bone
violation over the pairs; :func:`mean_curve_band` gives the mean cumulative curve with a
bootstrap confidence band of the mean (percentile method, seeded).
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Float

from ncflow.evaluate.formatting import as_number

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


# (value, column title, format spec) of the benchmark report's tables
TABLE_COLUMNS = (
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
    match, ev = as_number(t.get("match")), as_number(t.get("evaluate")) + as_number(t.get("plots", 0.0))
    row = {k: as_number(h.get(k)) for k in _ROW_VALUES[:7]}
    row.update(match_seconds=match, evaluate_seconds=ev, wall_seconds=match + ev)
    row["curves"] = {m: np.asarray([as_number(x) for x in c["pck"]]) for m, c in (record.get("curves") or {}).items()}
    row["tau_max"] = {m: as_number(c.get("tau_max")) for m, c in (record.get("curves") or {}).items()}
    return row


def mean_std(values: list[float]) -> dict:
    """Mean and sample std (ddof = 1) of the finite values: ``{"mean", "std", "n"}`` (NaN where undefined)."""
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
                entry[key] = mean_std([r[key] for r in ok])
            bones = np.asarray([r["max_bone_violation_ratio"] for r in ok], dtype=np.float64)
            bones = bones[np.isfinite(bones)]
            entry["max_bone_violation_ratio"]["max"] = float(bones.max()) if bones.size else float("nan")
            out.append(entry)
    return out
