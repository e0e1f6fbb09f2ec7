"""Cost against resolution (issue 17): one motion at several resolutions, source and target both.

The pair is ``make_pair("humanoid", seed=SEED)`` (the demo's character and motion) with its
marching-cubes resolution chosen so that the source has about 1k, 3k, 12k, 50k and 200k vertices
(the target ~0.9× as many, its own triangulation, exact face + barycentric ground truth). Each
size runs in its own process (so the peak memory is that of one match) with the default preset,
the compilation cache of the first size kept for the others (what a user running many pairs
sees); the table gives the wall time of the match (generation and evaluation excluded), the
split setup / train / outputs, the peak resident memory of the process and the geodesic AUC
(on 2000 target vertices drawn with the seed, the same draw rule at every size).

Usage: python benchmarks/scaling.py [--sizes 1000,3000,12000,50000,200000] [--preset fast]
       [--set key=value ...] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import subprocess
import sys
import time

import numpy as np

SEED = 0
EVAL_POINTS = 2000  # target vertices scored (seeded draw): exact geodesics at 200k vertices cost


def resolution_for(n_vertices: int) -> float:
    """Marching-cubes resolution of the humanoid giving about ``n_vertices`` (measured: V ≈ r²)."""
    return math.sqrt(n_vertices)


def one(size: int, preset_name: str, overrides: list[str]) -> dict:
    from ncflow.config import apply_overrides, preset
    from ncflow.evaluate import evaluate_correspondence
    from ncflow.matcher.steps import Matcher
    from ncflow.synthetic.pairs import make_pair

    r = resolution_for(size)
    pair = make_pair("humanoid", seed=SEED, resolution=r, target_resolution=0.95 * r)
    cfg = apply_overrides(preset(preset_name), overrides)
    t0 = time.perf_counter()
    result = Matcher(pair.source, pair.target, pair.skeleton, cfg, quiet=True).run()
    wall = time.perf_counter() - t0
    gt = pair.ground_truth
    index = np.arange(pair.target.n_vertices) if gt.target_index is None else np.asarray(gt.target_index)
    pick = np.sort(np.random.default_rng(SEED).choice(index.size, size=min(EVAL_POINTS, index.size), replace=False))
    ev = evaluate_correspondence(
        pair.source,
        pair.target,
        result.maps["map_face"],
        result.maps["map_bary"],
        np.asarray(gt.face)[pick],
        np.asarray(gt.bary)[pick],
        gt_index=index[pick],
    )["summary"]
    t = result.metrics["timings"]
    return {
        "size": size,
        "n_source": pair.source.n_vertices,
        "n_target": pair.target.n_vertices,
        "n_working": result.metrics["n_working_vertices"],
        "wall_seconds": wall,
        "setup": t["setup"],
        "train": t["train"],
        "outputs": t["outputs"],
        "per_step": t["per_step"],
        "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2,
        "geodesic_auc": ev["geodesic"]["auc"],
        "device": result.metrics["versions"]["device"],
        "accelerator_peak_gb": _accelerator_peak_gb(),
    }


def _accelerator_peak_gb() -> float | None:
    """Peak memory the run held on the accelerator (GPU), ``None`` on the CPU."""
    import jax

    dev = jax.devices()[0]
    if dev.platform == "cpu":
        return None
    stats = dev.memory_stats() or {}
    peak = stats.get("peak_bytes_in_use")
    return None if peak is None else peak / 1024**3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="1000,3000,12000,50000,200000")
    ap.add_argument("--preset", default="fast")
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--json")
    ap.add_argument("--one", type=int, help=argparse.SUPPRESS)  # a single size, in this process
    args = ap.parse_args()
    if args.one:
        print("RESULT " + json.dumps(one(args.one, args.preset, args.set)), flush=True)
        return
    rows = []
    for size in (int(s) for s in args.sizes.split(",")):
        cmd = [sys.executable, __file__, "--one", str(size), "--preset", args.preset]
        for s in args.set:
            cmd += ["--set", s]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        line = next((x for x in proc.stdout.splitlines() if x.startswith("RESULT ")), None)
        if line is None:
            print(f"size {size} failed:\n{proc.stderr[-2000:]}", flush=True)
            continue
        rows.append(json.loads(line[7:]))
        print(json.dumps(rows[-1]), flush=True)
    if not rows:
        sys.exit(1)
    print(f"\npreset {args.preset}, overrides {args.set or 'none'}, device {rows[0]['device']}\n")
    print(
        "| V source / target | trained on | wall [s] | setup / train / outputs [s] | s/step "
        "| peak RSS [GB] | geodesic AUC |"
    )
    print("|---|---|---|---|---|---|---|")
    gpu = lambda r: "" if r.get("accelerator_peak_gb") is None else f" (GPU {r['accelerator_peak_gb']:.2f})"
    for r in rows:
        print(
            f"| {r['n_source']} / {r['n_target']} | {r['n_working']} | {r['wall_seconds']:.0f} | "
            f"{r['setup']:.0f} / {r['train']:.0f} / {r['outputs']:.0f} | {r['per_step']:.3f} | "
            f"{r['peak_rss_gb']:.2f}{gpu(r)} | {r['geodesic_auc']:.3f} |"
        )
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)


if __name__ == "__main__":
    main()
