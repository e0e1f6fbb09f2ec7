"""The scan development set's table (issue 45): one row per scan case of an ``ncflow benchmark`` folder.

    python benchmarks/scan_table.py RUN_DIR [--before DIR] [--complete NAME=AUC ...] [--method ncflow]

For each run ``RUN_DIR/runs/<method>/<pair>_<case>`` (``benchmarks/scan_pairs.py``'s names): geodesic AUC
of the kept target points, the complete pair's AUC (a row of the same folder named ``<pair>``, or
``--complete``) and the difference, the run's seconds, whether the partial terms were used and the share
of the source shown (``metrics.json`` ``partial``), and the **roughness** of the flowed source — the mean
umbrella-Laplacian length ‖x_v − mean of its ring‖ over the mean edge length, flowed over rest (1: as
smooth as the source; a flow that fits a noisy scan's noise raises it). ``--before``: another folder of
the same cases (another version of the code), its AUC beside. Then the mean and the worst case.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from ncflow.io.meshes import load_mesh

CASES = ("view0", "view1", "view2", "quarter", "holes", "noise", "view0_cloud", "holes_noise")


def roughness(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Mean ‖x_v − mean of its ring‖ over the mean edge length."""
    n = vertices.shape[0]
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.unique(np.sort(e, axis=1), axis=0)
    total, count = np.zeros((n, 3)), np.zeros(n)
    for a, b in ((0, 1), (1, 0)):
        np.add.at(total, e[:, a], vertices[e[:, b]])
        np.add.at(count, e[:, a], 1)
    used = count > 0
    lap = np.linalg.norm(vertices[used] - total[used] / count[used, None], axis=1)
    return float(lap.mean() / np.linalg.norm(vertices[e[:, 0]] - vertices[e[:, 1]], axis=1).mean())


def numbers(run: Path) -> dict | None:
    metrics, evaluation = run / "metrics.json", run / "evaluation.json"
    if not (metrics.is_file() and evaluation.is_file()):
        return None
    m, e = json.loads(metrics.read_text()), json.loads(evaluation.read_text())
    flowed = load_mesh(run / "deformed_source.ply")
    rest = load_mesh(run / "frames" / "frame_0000.ply")
    partial = m.get("partial") or {}
    return {
        "auc": e["headline"]["geodesic_auc"],
        "seconds": m["timings"]["total"],
        "active": partial.get("active"),
        "shown": partial.get("flowed_source_shown_share"),
        "rough": roughness(flowed.vertices, flowed.faces) / roughness(rest.vertices, rest.faces),
    }


def split(name: str) -> tuple[str, str | None]:
    for case in sorted(CASES, key=len, reverse=True):
        if name.endswith("_" + case):
            return name[: -len(case) - 1], case
    return name, None


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--before", type=Path)
    ap.add_argument("--complete", nargs="*", default=[])
    ap.add_argument("--method", default="ncflow")
    args = ap.parse_args(argv)
    runs = sorted(p for p in (args.run / "runs" / args.method).iterdir() if p.is_dir())
    complete = {k: float(v) for k, v in (c.split("=") for c in args.complete)}
    for run in runs:
        pair, case = split(run.name)
        got = numbers(run) if case is None else None
        if got is not None:
            complete[pair] = got["auc"]
    head = "| case | geodesic AUC | complete | Δ |" + (" before |" if args.before else "")
    print(head + " s | partial | shown | roughness |")
    print("|" + "---|" * (head.count("|") - 1 + 4))
    aucs, deltas = [], []
    for run in runs:
        pair, case = split(run.name)
        got = numbers(run)
        if case is None or got is None:
            continue
        full = complete.get(pair)
        delta = None if full is None else got["auc"] - full
        aucs.append((got["auc"], run.name))
        if delta is not None:
            deltas.append((delta, run.name))
        row = f"| {run.name} | {got['auc']:.3f} | {'' if full is None else f'{full:.3f}'} | "
        row += "" if delta is None else f"{delta:+.3f}"
        row += " |"
        if args.before:
            b = numbers(args.before / "runs" / args.method / run.name)
            row += f" {'' if b is None else format(b['auc'], '.3f')} |"
        shown = "" if got["shown"] is None else f"{got['shown']:.2f}"
        row += f" {got['seconds']:.0f} | {'on' if got['active'] else 'off'} | {shown} | {got['rough']:.2f} |"
        print(row)
    if aucs:
        worst = min(aucs)
        mean = np.mean([a for a, _ in aucs])
        print(f"\nmean geodesic AUC {mean:.3f} over {len(aucs)} cases; worst {worst[0]:.3f} ({worst[1]})")
    if deltas:
        d = min(deltas)
        print(f"largest loss against the complete pair {d[0]:+.3f} ({d[1]})")


if __name__ == "__main__":
    main()
