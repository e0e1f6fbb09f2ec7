"""The placement + articulated pose search alone, against the target skeletons the pair generators write.

For every pair folder of the hard development set (``bash benchmarks/hard_pairs.sh DIR --pairs-only``;
each ``DIR/pairs/<name>/pair_000`` holds ``source.ply``, ``target.ply``, ``source_skeleton.tgf`` and
``target_skeleton.tgf``), runs :func:`ncflow.matcher.prepare.prepare` with the default preset (tissue
off: it does not enter the search) and prints the mean and largest distance between the joints of
the pose found and the target skeleton's (normalised units; the source is about 2 units across),
every placement candidate tried with its articulated score, and the seconds spent.

Usage: python benchmarks/pose_search.py DIR [NAME ...]
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

import numpy as np


def main() -> None:
    from ncflow.config import preset, validate_config
    from ncflow.matcher.place import place
    from ncflow.matcher.prepare import prepare
    from ncflow.skeleton import load_skeleton
    from ncflow.skeleton.kinematics import forward_kinematics, joint_positions

    if len(sys.argv) < 2:
        sys.exit(__doc__)
    root = Path(sys.argv[1]) / "pairs"
    names = sys.argv[2:] or sorted(p.name for p in root.iterdir() if (p / "pair_000").is_dir())
    cfg = preset("fast")
    cfg = validate_config(dataclasses.replace(cfg, sampling=dataclasses.replace(cfg.sampling, tissue_samples=0)))
    print("| pair | joint error mean / max | placements tried (angle: score) | s |")
    print("|---|---|---|---|")
    for name in names:
        p = root / name / "pair_000"
        t0 = time.perf_counter()
        prob = prepare(p / "source.ply", p / "target.ply", p / "source_skeleton.tgf", cfg)
        placed = place(prob, cfg)
        truth = placed.placement.apply(prob.normalization.apply(load_skeleton(p / "target_skeleton.tgf").positions))
        found = np.asarray(joint_positions(forward_kinematics(prob.skeleton_normalized, placed.pose_search.pose)))
        err = np.linalg.norm(found - truth, axis=1)
        tried = " ".join(f"{t['angle_degrees']:.0f}°: {t['pose_score']:.3f}" for t in placed.trials)
        print(f"| {name} | {err.mean():.3f} / {err.max():.3f} | {tried} | {time.perf_counter() - t0:.0f} |", flush=True)


if __name__ == "__main__":
    main()
