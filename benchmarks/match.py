"""Default preset on the demo pair and on the MANO pair: wall time, time per step, DESIGN.md metrics.

Pairs:
* ``demo``: ``ncflow.pairs.make_pair("humanoid", seed=0)`` — the pair ``ncflow demo`` uses
  (re-triangulated target, exact face+barycentric ground truth);
* ``mano``: ../shared/data/mano/pair_01_01r_01_02r (778 vertices, open at the wrist, same
  connectivity so the ground truth is the identity); skeleton = MANO ``J_regressor`` applied to the
  source vertices plus one fingertip bone per finger (tip vertices 320, 443, 672, 555, 744), from
  ../shared/data/mano/mano_right.npz. Skipped when the data is not there.

Usage: python benchmarks/match.py [--pairs demo,mano] [--preset fast] [--seed 0] [--set key=value ...]
Prints a Markdown table; ``--json FILE`` also writes the numbers.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
MANO_DIR = os.path.join(HERE, "..", "..", "shared", "data", "mano")


def demo_pair():
    from ncflow.synthetic.pairs import make_pair

    p = make_pair("humanoid", seed=0)
    return p.source, p.target, p.skeleton, p.ground_truth


def mano_pair():
    from ncflow.evaluate import load_ground_truth
    from ncflow.io.meshes import load_mesh
    from ncflow.skeleton import Skeleton

    pair_dir = os.path.join(MANO_DIR, "pair_01_01r_01_02r")
    model = np.load(os.path.join(MANO_DIR, "mano_right.npz"))
    src = load_mesh(os.path.join(pair_dir, "01_01r.obj"))
    tgt = load_mesh(os.path.join(pair_dir, "01_02r.obj"))
    joints = np.asarray(model["J_regressor"]) @ src.vertices
    parents = np.asarray(model["kintree_table"])[0].astype(np.int64)
    parents[0] = -1
    tips, tip_parents = [320, 443, 672, 555, 744], [3, 6, 9, 12, 15]
    skel = Skeleton.from_arrays(
        np.concatenate([joints, src.vertices[tips]]),
        np.concatenate([parents, tip_parents]),
        name="mano J_regressor + tips",
    )
    return src, tgt, skel, load_ground_truth("identity", src, tgt)


PAIRS = {"demo": demo_pair, "mano": mano_pair}


def run(name: str, cfg) -> dict:
    from ncflow.evaluate import evaluate_correspondence
    from ncflow.matcher.steps import Matcher

    src, tgt, skel, gt = PAIRS[name]()
    t0 = time.perf_counter()
    result = Matcher(src, tgt, skel, cfg, quiet=True).run()
    wall = time.perf_counter() - t0
    ev = evaluate_correspondence(
        src,
        tgt,
        result.maps["map_face"],
        result.maps["map_bary"],
        gt.face,
        gt.bary,
        deformed_vertices=result.deformed_source,
        frames=result.frames,
        gt_index=gt.target_index,
    )["summary"]
    c = result.metrics["constraints"]
    return {
        "pair": name,
        "n_source": src.n_vertices,
        "n_target": tgt.n_vertices,
        "n_bones": skel.n_bones,
        "steps": cfg.total_steps,
        "wall_seconds": wall,
        "setup_seconds": result.metrics["timings"]["setup"],
        "pose_search_seconds": result.metrics["timings"].get("pose_search", 0.0),
        "train_seconds": result.metrics["timings"]["train"],
        "outputs_seconds": result.metrics["timings"]["outputs"],
        "seconds_per_step": result.metrics["timings"]["per_step"],
        "geodesic_mean": ev["geodesic"]["mean"],
        "geodesic_auc": ev["geodesic"]["auc"],
        "chamfer_auc": ev["chamfer"]["auc"],
        "conformal_auc": ev["conformal"]["auc"],
        "max_violation_ratio": c["max_violation_ratio"],
        "bones_satisfied": sum(b["satisfied"] for b in c["bones"]),
    }


def main() -> None:
    from ncflow.config import apply_overrides, preset

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pairs", default="demo,mano")
    ap.add_argument("--preset", default="fast")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--json")
    args = ap.parse_args()
    cfg = apply_overrides(preset(args.preset), [f"seed={args.seed}"] + args.set)
    rows = []
    for name in args.pairs.split(","):
        if name == "mano" and not os.path.exists(os.path.join(MANO_DIR, "mano_right.npz")):
            print(f"skipping {name}: no data in {MANO_DIR}")
            continue
        rows.append(run(name, cfg))
        print(json.dumps(rows[-1]), flush=True)
    print(f"\npreset {args.preset}, seed {args.seed}, overrides {args.set or 'none'}\n")
    print(
        "| pair | V src / tgt | bones | steps | wall [s] | s/step | geodesic mean | geodesic AUC | Chamfer AUC "
        "| conformal AUC | max g/ε | bones ≤ ε |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['pair']} | {r['n_source']} / {r['n_target']} | {r['n_bones']} | {r['steps']} | "
            f"{r['wall_seconds']:.0f} | {r['seconds_per_step']:.3f} | {r['geodesic_mean']:.4f} | "
            f"{r['geodesic_auc']:.3f} | {r['chamfer_auc']:.3f} | "
            f"{r['conformal_auc']:.3f} | {r['max_violation_ratio']:.2f} | {r['bones_satisfied']}/{r['n_bones']} |"
        )
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)


if __name__ == "__main__":
    main()
