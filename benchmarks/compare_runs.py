"""Two benchmark folders side by side, pair by pair: the largest bone violation, the bones beyond ε,
geodesic AUC and time (issue 49's before/after table).

Reads OUT/runs/<method>/<pair>/metrics.json and evaluation.json of each ``ncflow benchmark`` folder
(the same pairs file run with two versions of the code) and prints one markdown row per pair found in
both, then the largest violation, the worst AUC change and the time ratio over the pairs.

Usage: python benchmarks/compare_runs.py BEFORE_DIR AFTER_DIR [--method ncflow]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def run_numbers(run: Path) -> dict | None:
    """Largest g/ε, bones beyond ε (of all), geodesic AUC, match seconds and train s/step of one run folder."""
    metrics, evaluation = run / "metrics.json", run / "evaluation.json"
    if not (metrics.is_file() and evaluation.is_file()):
        return None
    m, e = json.loads(metrics.read_text()), json.loads(evaluation.read_text())
    c = m["constraints"]
    beyond = sum(max(b["g_endpoint"], b["g_trajectory"]) > c["eps"] for b in c["bones"])
    return {
        "violation": c["max_violation_ratio"],
        "beyond": f"{beyond}/{len(c['bones'])}",
        "auc": e["headline"]["geodesic_auc"],
        "seconds": m["timings"]["total"],
        "per_step": m["timings"].get("per_step"),
    }


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before", type=Path)
    ap.add_argument("after", type=Path)
    ap.add_argument("--method", default="ncflow")
    args = ap.parse_args(argv)
    rows = []
    for run in sorted((args.before / "runs" / args.method).iterdir()):
        b = run_numbers(run) if run.is_dir() else None
        a = run_numbers(args.after / "runs" / args.method / run.name) if b else None
        if a:
            rows.append((run.name, b, a))
    print(
        "| pair | max g/ε before | after | bones > ε before | after | geodesic AUC before | after | Δ "
        "| time [s] before | after | ratio |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name, b, a in rows:
        print(
            f"| {name} | {b['violation']:.2f} | {a['violation']:.2f} | {b['beyond']} | {a['beyond']} | "
            f"{b['auc']:.3f} | {a['auc']:.3f} | {a['auc'] - b['auc']:+.3f} | {b['seconds']:.0f} | {a['seconds']:.0f} | "
            f"{a['seconds'] / b['seconds']:.2f} |"
        )
    if rows:
        n = len(rows)
        worst = min(rows, key=lambda r: r[2]["auc"] - r[1]["auc"])
        mean_b, mean_a = (sum(r[i]["auc"] for r in rows) / n for i in (1, 2))
        over = [r[0] for r in rows if r[2]["violation"] > 1.0]
        print(
            f"\n{n} pairs. Largest violation before {max(r[1]['violation'] for r in rows):.2f}, after "
            f"{max(r[2]['violation'] for r in rows):.2f}; pairs over 1.0 after: {', '.join(over) or 'none'}. "
            f"Mean AUC before {mean_b:.4f}, after {mean_a:.4f}; "
            f"worst change {worst[2]['auc'] - worst[1]['auc']:+.3f} ({worst[0]}). Total time before "
            f"{sum(r[1]['seconds'] for r in rows):.0f} s, after {sum(r[2]['seconds'] for r in rows):.0f} s "
            f"(largest ratio {max(r[2]['seconds'] / r[1]['seconds'] for r in rows):.2f})."
        )


if __name__ == "__main__":
    main()
