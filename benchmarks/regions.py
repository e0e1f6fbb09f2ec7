"""Where does a match go wrong? Per-bone error of a run's target → source map, and its joint errors.

Each target vertex with ground truth is given the region of the source bone nearest to its true
source point (rest pose). For every region: the mean Euclidean distance between the source point the
run mapped the vertex to and the true one, over the source's bounding-box diagonal. When the pair
folder has the target's skeleton (``target_skeleton.tgf``, as the pair generators and
``benchmarks/hard_pairs.sh`` write), also the distance of each joint of the run's target skeleton
to it, over the target's diagonal. A tucked fingertip mapped onto its neighbour shows as one
fingertip region at 0.1–0.2 while the rest stays under 0.05.

Usage: python benchmarks/regions.py PAIR_DIR RUN_DIR [RUN_DIR ...]

PAIR_DIR holds ``source.ply``, ``target.ply``, ``source_skeleton.tgf`` and ``gt.npz`` (a folder of
``ncflow make-pairs``); each RUN_DIR is an ``ncflow match`` output folder for that pair.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))


def main() -> None:
    from bone_rigidity import nearest_bones
    from ncflow.geometry.barycentric import surface_points
    from ncflow.io.ground_truth import load_ground_truth
    from ncflow.io.meshes import load_mesh
    from ncflow.skeleton import load_skeleton

    if len(sys.argv) < 3:
        sys.exit(__doc__)
    pair, runs = Path(sys.argv[1]), [Path(r) for r in sys.argv[2:]]
    source, target = load_mesh(pair / "source.ply"), load_mesh(pair / "target.ply")
    skeleton = load_skeleton(pair / "source_skeleton.tgf")
    gt = load_ground_truth(pair / "gt.npz", source, target)
    bones = skeleton.bones
    names = [f"{a}-{b}" for a, b in bones.tolist()]
    truth = surface_points(source.vertices, source.faces, gt.face, gt.bary)
    region = nearest_bones(truth, skeleton.positions[bones[:, 0]], skeleton.positions[bones[:, 1]])[0]
    diag = np.linalg.norm(np.ptp(source.vertices, axis=0))
    truth_skeleton = pair / "target_skeleton.tgf"
    for k, run in enumerate(runs):
        print(f"run {k}: {run}")
    print("\n| run | " + " | ".join(names) + " | all |")
    print("|---" * (len(names) + 2) + "|")
    for k, run in enumerate(runs):
        m = np.load(run / "map_tgt_to_src.npz")
        mapped = surface_points(source.vertices, source.faces, m["face"][gt.target_index], m["bary"][gt.target_index])
        err = np.linalg.norm(mapped - truth, axis=1) / diag
        cells = [f"{err[region == b].mean():.3f}" if np.any(region == b) else "-" for b in range(len(names))]
        print(f"| {k} | " + " | ".join(cells) + f" | {err.mean():.3f} |")
    if truth_skeleton.is_file():
        true_skeleton = load_skeleton(truth_skeleton)
        true_joints = true_skeleton.positions
        tdiag = np.linalg.norm(np.ptp(target.vertices, axis=0))
        print("\njoint error / target diagonal (joint 0 first)")
        for k, run in enumerate(runs):
            if not (run / "skeleton_target.tgf").is_file():
                print(f"run {k}: no skeleton_target.tgf")
                continue
            found_skeleton = load_skeleton(run / "skeleton_target.tgf")
            if not np.array_equal(found_skeleton.parents, true_skeleton.parents):
                print(f"run {k}: its skeleton is not the target skeleton's tree")
                continue
            found = found_skeleton.positions
            print(f"run {k}: " + " ".join(f"{e:.3f}" for e in np.linalg.norm(found - true_joints, axis=1) / tdiag))


if __name__ == "__main__":
    main()
