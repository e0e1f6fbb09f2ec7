"""Which finger goes wrong? Per-finger geodesic error of every hand pair of a benchmark report.

For every pair of PAIRS_CSV (datasets ``mano`` and ``hand`` unless --datasets says otherwise) with an
evaluated run in REPORT_DIR/runs/<method>/<name>/: the geodesic error of each target vertex with ground truth (the
distance on the source between the point the run mapped it to and its true point, over √area of the
source: :func:`ncflow.evaluate.metrics.geodesic_errors`, as ``ncflow evaluate`` computes it, with the
solver the run's ``evaluation.json`` names), grouped by the source bone nearest the vertex's true
source point (``bone_rigidity.nearest_bones``, as ``regions.py`` does). Bones are grouped by chain: the
palm joint is the first joint from the root with more than one child; the bones from the root to it
and the bones leaving it (the metacarpals) are the palm, the rest of each chain that leaves it is a
finger. Fingers are named after the first joint of their chain when the skeleton has joint names,
by MANO's joint order (index, middle, little, ring, thumb) when the skeleton has MANO's tree (MANO
pairs and the procedural hand, whose joints follow it), else finger1, finger2, ... in skeleton order.

Prints a markdown table (per pair: the geodesic AUC of evaluation.json, then each finger's mean error;
then the share of each finger's vertices beyond --tau) and a summary: mean and 10th-percentile AUC,
the worst pair, and per finger the number of pairs where it is the worst group and where its mean
error exceeds --tau. Writes the numbers to REPORT_DIR/fingers.json (or --json PATH).

    python benchmarks/fingers.py REPORT_DIR PAIRS_CSV [--method M] [--datasets mano,hand] [--tau 0.2] [--json PATH]

(--method: one method folder of REPORT_DIR/runs/; default every one, each with its own tables; fingers.json
holds per method the summary, the per-pair numbers and the pairs without a run.)
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import re
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from bone_rigidity import nearest_bones  # noqa: E402

#: column order of named fingers; other names follow in skeleton order, the palm last
FINGER_ORDER = ("thumb", "index", "middle", "ring", "little")
PALM = "palm"
#: MANO's parent table (16 joints: wrist; index, middle, little, ring, thumb, three joints each)
MANO_PARENTS = (-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14)
TAU = 0.2


def _children(parents: np.ndarray) -> list[list[int]]:
    """The children of each joint, in joint order: (J,) parents → J lists."""
    out: list[list[int]] = [[] for _ in parents]
    for j, p in enumerate(parents):
        if p >= 0:
            out[int(p)].append(j)
    return out


def _chain_name(joint_name: str) -> str:
    """A finger name from the name of its chain's first joint: ``index1`` → ``index``, ``Thumb_01`` → ``thumb``."""
    return re.sub(r"[\s_.\-]*\d+$", "", joint_name).strip().lower() or joint_name


def _mano_like_names(parents: np.ndarray) -> tuple[str, ...] | None:
    """MANO's joint names when the first 16 joints have MANO's parent table (and any further joints are leaves)."""
    from ncflow.io.mano import MANO_JOINT_NAMES

    parents = [int(p) for p in parents]
    if len(parents) < 16 or tuple(parents[:16]) != MANO_PARENTS or any(p >= 16 for p in parents[16:]):
        return None
    return tuple(MANO_JOINT_NAMES) + tuple("" for _ in parents[16:])


def finger_groups(parents, names=None) -> tuple[list[str], np.ndarray]:
    """Group the bones of a skeleton into fingers and the palm.

    Args:
        parents: (J,) parent of each joint, −1 for the root, parents before children (a
            :class:`ncflow.skeleton.Skeleton`'s order); bone b is (parents[b + 1], b + 1).
        names: (J,) joint names or None.

    Returns:
        (group names: the fingers in skeleton order, then ``"palm"``; (J − 1,) group index of each
        bone). The palm joint is the first joint from the root with more than one child; the bones
        from the root down to it and the bones leaving it are the palm; every other bone belongs to
        the finger of the chain (child of the palm joint) it lies on. A chain that is a single bone
        keeps that bone as its finger.
    """
    parents = np.asarray(parents, dtype=np.int64)
    children = _children(parents)
    palm = 0
    while len(children[palm]) == 1:
        palm = children[palm][0]
    if names is None or not any(names):
        names = _mano_like_names(parents)
    chains = children[palm]
    labels = [_chain_name(names[c]) if names and names[c] else f"finger{k + 1}" for k, c in enumerate(chains)]
    labels = [lab if labels.count(lab) == 1 else f"{lab}{k + 1}" for k, lab in enumerate(labels)]
    group = np.full(parents.size, len(chains), dtype=np.int64)
    for k, c in enumerate(chains):
        stack = list(children[c])
        group[c] = k if not stack else len(chains)
        while stack:
            j = stack.pop()
            group[j] = k
            stack.extend(children[j])
    return labels + [PALM], group[1:]


def finger_joint_errors(errors, parents, names=None) -> dict:
    """The largest joint error of each group of :func:`finger_groups`: (J,) per-joint errors → {group name:
    the largest error over the joints its bones end at (bone b ends at joint b + 1), or None without one}.
    """
    labels, group = finger_groups(parents, names)
    errors = np.asarray(errors, dtype=np.float64)
    joints = [np.flatnonzero(group == k) + 1 for k in range(len(labels))]
    return {label: float(errors[j].max()) if j.size else None for label, j in zip(labels, joints, strict=True)}


def vertex_groups(points: np.ndarray, positions: np.ndarray, parents, bone_group: np.ndarray) -> np.ndarray:
    """The group of the bone nearest each point: (n, 3) points, (J, 3) joints, (J,) parents, (J − 1,) groups → (n,)."""
    parents = np.asarray(parents, dtype=np.int64)
    nearest = nearest_bones(np.asarray(points, dtype=np.float64), positions[parents[1:]], positions[1:])[0]
    return np.asarray(bone_group)[nearest]


def group_errors(errors: np.ndarray, groups: np.ndarray, names: list[str], tau: float = TAU) -> dict:
    """Per group: ``n`` vertices, ``mean`` error and ``share_beyond`` (share of errors > tau).

    Args:
        errors: (n,) errors (NaN: left out; +inf counts, as in ``ncflow evaluate``).
        groups: (n,) group index of each error, into ``names``.
        names: group names.
        tau: the threshold of the share.

    Returns:
        {name: {"n", "mean", "share_beyond"}} for every name (mean and share NaN when no vertex).
    """
    from ncflow.evaluate.metrics import error_summary

    errors, groups = np.asarray(errors, dtype=np.float64), np.asarray(groups)
    out = {}
    for k, name in enumerate(names):
        e = errors[(groups == k) & ~np.isnan(errors)]
        mean = error_summary(e, tau)["mean"]
        out[name] = {"n": int(e.size), "mean": mean, "share_beyond": float(np.mean(e > tau)) if e.size else math.nan}
    return out


def pair_fingers(row: dict, root: Path, run: Path, tau: float = TAU) -> dict:
    """The per-finger errors of one pair: a row of the pairs csv (paths relative to root) and its run folder.

    Returns:
        ``name``, ``dataset``, ``auc`` (geodesic AUC of the run's evaluation.json), ``mean`` (its geodesic
        mean), ``mean_recomputed`` (the mean of the errors computed here), ``groups`` (from
        :func:`group_errors`) and ``worst`` (the group of largest mean error).
    """
    from ncflow.evaluate.metrics import geodesic_errors
    from ncflow.geometry.barycentric import surface_points
    from ncflow.io.ground_truth import load_ground_truth
    from ncflow.io.meshes import load_mesh
    from ncflow.skeleton import load_skeleton

    evaluation = json.loads((run / "evaluation.json").read_text())
    summary = evaluation["summary"]
    source, target = load_mesh(root / row["source"]), load_mesh(root / row["target"])
    skeleton = load_skeleton(root / row["skeleton"])
    gt = load_ground_truth(root / row["gt"], source, target, row.get("gt_format") or None)
    found = np.load(run / "map_tgt_to_src.npz")
    face, bary = found["face"].astype(np.int64), found["bary"].astype(np.float64)
    if face.shape != (target.n_vertices,):
        raise ValueError(f"{run}: the map has {face.shape[0]} entries, the target {target.n_vertices} vertices")
    method = (summary.get("geodesic_solver") or {}).get("method", "auto")
    errors = geodesic_errors(source, face[gt.target_index], bary[gt.target_index], gt.face, gt.bary, method=method)
    names, bone_group = finger_groups(skeleton.parents, skeleton.names)
    truth = surface_points(source.vertices, source.faces, gt.face, gt.bary)
    groups = group_errors(errors, vertex_groups(truth, skeleton.positions, skeleton.parents, bone_group), names, tau)
    means = {k: v["mean"] for k, v in groups.items() if v["n"]}
    return {
        "name": row["name"],
        "dataset": row.get("dataset", ""),
        "auc": evaluation["headline"]["geodesic_auc"],
        "mean": evaluation["headline"]["geodesic_mean"],
        "mean_recomputed": float(np.mean(errors[~np.isnan(errors)])),
        "groups": groups,
        "worst": max(means, key=means.get) if means else None,
    }


def summarize(pairs: list[dict], tau: float = TAU) -> dict:
    """Mean and 10th-percentile AUC, the worst pair, and per group the pairs where it is worst / above tau.

    Args:
        pairs: results of :func:`pair_fingers`.
        tau: the mean-error threshold.

    Returns:
        ``n_pairs``, ``mean_auc``, ``p10_auc``, ``worst_pair`` (lowest AUC), ``worst_finger_count``
        ({group: pairs where its mean error is the largest}), ``mean_above_tau_count`` ({group: pairs
        where its mean error > tau}), ``tau``.
    """
    aucs = np.array([p["auc"] if p["auc"] is not None else np.nan for p in pairs], dtype=np.float64)
    groups = column_order([g for p in pairs for g in p["groups"]])
    ok = ~np.isnan(aucs)
    return {
        "n_pairs": len(pairs),
        "mean_auc": float(np.mean(aucs[ok])) if ok.any() else math.nan,
        "p10_auc": float(np.percentile(aucs[ok], 10)) if ok.any() else math.nan,
        "worst_pair": pairs[int(np.nanargmin(aucs))]["name"] if ok.any() else None,
        "worst_finger_count": {g: sum(p["worst"] == g for p in pairs) for g in groups},
        "mean_above_tau_count": {
            g: sum(g in p["groups"] and p["groups"][g]["mean"] > tau for p in pairs) for g in groups
        },
        "tau": float(tau),
    }


def column_order(names) -> list[str]:
    """Group names in table order: :data:`FINGER_ORDER` first, other fingers as met, the palm last."""
    names = list(dict.fromkeys(names))
    known = [n for n in FINGER_ORDER if n in names]
    return known + [n for n in names if n not in known and n != PALM] + ([PALM] if PALM in names else [])


def _cell(x, fmt: str) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, fmt)


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|---" * len(header) + "|"] + ["| " + " | ".join(r) + " |" for r in rows]


def markdown(pairs: list[dict], summary: dict) -> str:
    """The tables (mean error per finger; share beyond tau) and the summary lines, as markdown text."""
    groups = column_order([g for p in pairs for g in p["groups"]])
    tau = summary["tau"]

    def cells(p: dict, key: str, fmt: str) -> list[str]:
        return [p["name"], _cell(p["auc"], ".3f")] + [_cell(p["groups"].get(g, {}).get(key), fmt) for g in groups]

    head = ["pair", "geodesic AUC"] + groups
    lines = ["Mean geodesic error (/ √area of the source) per finger", ""]
    lines += _table(head + ["worst"], [cells(p, "mean", ".3f") + [p["worst"] or "-"] for p in pairs])
    lines += ["", f"Share of each finger's vertices with error > {tau:g}", ""]
    lines += _table(head, [cells(p, "share_beyond", ".1%") for p in pairs])
    lines += [
        "",
        f"{summary['n_pairs']} pairs: mean AUC {_cell(summary['mean_auc'], '.3f')}, "
        f"10th percentile {_cell(summary['p10_auc'], '.3f')}, worst pair {summary['worst_pair']}",
        "",
    ]
    counts = [
        ["worst finger of (pairs)"] + [str(summary["worst_finger_count"][g]) for g in groups],
        [f"mean error > {tau:g} (pairs)"] + [str(summary["mean_above_tau_count"][g]) for g in groups],
    ]
    return "\n".join(lines + _table([""] + groups, counts)) + "\n"


def _json_safe(x):
    """x with every non-finite float replaced by None (strict JSON)."""
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_json_safe(v) for v in x]
    return None if isinstance(x, float) and not math.isfinite(x) else x


def score_method(runs: Path, rows: list[dict], root: Path, tau: float = TAU) -> tuple[list[dict], list[str]]:
    """:func:`pair_fingers` of every row (pairs csv rows, paths relative to root) with an evaluated run in runs/<name>/.

    Returns:
        (the results, the names of the rows without an evaluated run).
    """
    results, missing = [], []
    for row in rows:
        run = runs / row["name"]
        if not (run / "evaluation.json").is_file() or not (run / "map_tgt_to_src.npz").is_file():
            missing.append(row["name"])
            continue
        r = pair_fingers(row, root, run, tau)
        if r["mean"] is not None and not math.isclose(r["mean"], r["mean_recomputed"], rel_tol=1e-6, abs_tol=1e-9):
            print(f"note: {r['name']}: mean error {r['mean_recomputed']:.6f} here, {r['mean']:.6f} in evaluation.json")
        results.append(r)
    return results, missing


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("report", metavar="REPORT_DIR", help="ncflow benchmark folder (runs/<method>/<pair>/)")
    ap.add_argument("pairs_csv", metavar="PAIRS_CSV", help="the pairs file the benchmark ran")
    ap.add_argument("--method", help="method folder under runs/ (default: every one, e.g. ncflow)")
    ap.add_argument("--datasets", default="mano,hand", help="datasets to score (default mano,hand; 'all': every row)")
    ap.add_argument("--tau", type=float, default=TAU, help=f"error threshold (default {TAU:g})")
    ap.add_argument("--json", help="where to write the numbers (default REPORT_DIR/fingers.json)")
    args = ap.parse_args()
    csv_path = Path(args.pairs_csv)
    keep = None if args.datasets == "all" else set(args.datasets.split(","))
    rows = [r for r in csv.DictReader(open(csv_path, newline="")) if keep is None or r.get("dataset") in keep]
    runs = Path(args.report) / "runs"
    methods = [args.method] if args.method else sorted(p.name for p in runs.iterdir() if p.is_dir())
    record: dict = {"report": str(args.report), "pairs_csv": str(csv_path), "tau": args.tau, "methods": {}}
    for method in methods:
        results, missing = score_method(runs / method, rows, csv_path.parent, args.tau)
        if len(methods) > 1:
            print(f"\n## {method}\n")
        if missing:
            print(f"no evaluated run for {len(missing)} pairs: {', '.join(missing)}\n")
        if not results:
            print(f"no evaluated pairs of the datasets {args.datasets} in {runs / method}")
            continue
        summary = summarize(results, args.tau)
        print(markdown(results, summary), end="")
        record["methods"][method] = {"summary": summary, "pairs": results, "missing": missing}
    if not record["methods"]:
        sys.exit(f"no evaluated pairs in {runs}")
    out = Path(args.json) if args.json else Path(args.report) / "fingers.json"
    out.write_text(json.dumps(_json_safe(record), indent=1) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
