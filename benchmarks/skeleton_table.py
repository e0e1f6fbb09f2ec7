"""The suggested skeletons measured against true ones (docs/skeleton-suggest.md, "Measured"): generated
characters (seeds 0–2), a sphere and a torus, and, with ``--pairs DIR``, the sources of pairs made by
``benchmarks/hard_pairs.sh`` with their drawn skeletons. Per mesh: vertices, joints (true), leaves, "tip"
(the largest distance from a true limb tip to the nearest suggested leaf, share of the diagonal), "base"
(the same for the true joints where limbs leave a branch joint: mean and largest), inside (share of joints with winding
number > 1/2), exchangeable limb pairs (suggested / true: what the pose search can try swapped), seconds.

Usage: python benchmarks/skeleton_table.py [--pairs hard/pairs NAME ...]
"""

from __future__ import annotations

import sys
import time

import numpy as np
import trimesh

from ncflow.geometry.winding import winding_numbers
from ncflow.matcher.pose_hypotheses import exchangeable_limbs
from ncflow.skeleton.suggest import suggest_skeleton
from ncflow.synthetic.characters import make_character


def _leaves(parents: np.ndarray) -> np.ndarray:
    return np.setdiff1d(np.arange(parents.shape[0]), parents[1:])


def _bases(parents: np.ndarray) -> np.ndarray:
    kids = np.bincount(parents[parents >= 0], minlength=parents.shape[0])
    return np.asarray([j for j in range(parents.shape[0]) if parents[j] >= 0 and kids[parents[j]] >= 2])


def row(name: str, v: np.ndarray, f: np.ndarray, true=None) -> str:
    t0 = time.perf_counter()
    sk = suggest_skeleton(v, f).skeleton
    seconds = time.perf_counter() - t0
    parents = np.asarray(sk.parents)
    diag = float(np.linalg.norm(np.ptp(v, axis=0)))
    inside = float(np.mean(np.abs(winding_numbers(sk.positions, v[f])) > 0.5))
    cells = [name, f"{v.shape[0]}", f"{sk.n_joints} ({true.n_joints if true is not None else '–'})"]
    cells.append(f"{_leaves(parents).size}")
    if true is not None:
        tp = np.asarray(true.parents)
        leaves = sk.positions[_leaves(parents)]
        tip = max(np.linalg.norm(leaves - true.positions[j], axis=1).min() for j in _leaves(tp)) / diag
        base = [np.linalg.norm(sk.positions - true.positions[j], axis=1).min() / diag for j in _bases(tp)]
        cells += [f"{tip:.3f}", f"{np.mean(base):.3f} / {np.max(base):.3f}"]
        cells.append(f"{len(exchangeable_limbs(sk))} / {len(exchangeable_limbs(true))}")
    else:
        cells += ["–", "–", f"{len(exchangeable_limbs(sk))}"]
    cells += [f"{inside:.2f}", f"{seconds:.2f}"]
    return "| " + " | ".join(cells) + " |"


def main() -> None:
    print("| mesh | vertices | joints (true) | leaves | tip | base (mean / max) | exchangeable | inside | seconds |")
    print("|---|---|---|---|---|---|---|---|---|")
    for kind in ("humanoid", "hand", "quadruped"):
        for seed in (0, 1, 2):
            ch = make_character(kind, seed)
            print(row(f"{kind} {seed}", ch.mesh.vertices, ch.mesh.faces, ch.skeleton), flush=True)
    for name, mesh in (("sphere", trimesh.creation.icosphere(3)), ("torus", trimesh.creation.torus(1.0, 0.3))):
        print(row(name, np.asarray(mesh.vertices), np.asarray(mesh.faces)), flush=True)
    if len(sys.argv) > 2 and sys.argv[1] == "--pairs":
        from ncflow.geometry.mesh import repaired_mesh
        from ncflow.io.meshes import load_mesh
        from ncflow.io.skeletons import load_skeleton

        for name in sys.argv[3:]:
            folder = f"{sys.argv[2]}/{name}/pair_000"
            src = repaired_mesh(load_mesh(f"{folder}/source.ply"))[0]
            print(row(name, src.vertices, src.faces, load_skeleton(f"{folder}/source_skeleton.tgf")), flush=True)


if __name__ == "__main__":
    main()
