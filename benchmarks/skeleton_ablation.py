"""What in a suggested skeleton costs a match? The drawn skeleton of each pair changed one way at a time, as a
new pairs CSV for ``ncflow benchmark`` (benchmarks/RESULTS.md, session 45):

* ``split T``: every bone longer than T of the source's bounding-box diagonal split at its middle — the joints
  in the middle of a thigh or a shin that a suggestion cut by length has and a drawn skeleton does not;
* ``drop T``: every inner joint farther than T of the diagonal from all joints of the skeleton that
  ``ncflow match`` would suggest for the pair (:func:`ncflow.skeleton.suggest.suggest_skeleton`, the target as
  the other pose) removed, its children hung from its parent — the shoulders and hips a suggestion misses.

Usage: python benchmarks/skeleton_ablation.py PAIRS.csv {split,drop} T OUT_DIR

Writes OUT_DIR/<name>.tgf for each row that has a skeleton and OUT_DIR/pairs.csv (the rows, their paths
absolute, the skeleton cell the new file); prints each row's joints before and after.
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np

from ncflow.geometry.skeleton import Skeleton, _breadth_first
from ncflow.io.meshes import load_mesh
from ncflow.io.skeletons import load_skeleton, save_skeleton
from ncflow.skeleton.suggest import suggest_skeleton


def split_long_bones(positions: np.ndarray, parents: np.ndarray, longest: float) -> tuple[np.ndarray, np.ndarray]:
    """(positions, parents) with every bone longer than ``longest`` split at its middle; parents first."""
    pos, par = list(positions), list(parents)
    for j in range(1, positions.shape[0]):
        if np.linalg.norm(positions[j] - positions[parents[j]]) > longest:
            pos.append(0.5 * (positions[j] + positions[parents[j]]))
            par.append(par[j])
            par[j] = len(pos) - 1
    return _parents_first(np.asarray(pos), np.asarray(par))


def drop_joints(positions: np.ndarray, parents: np.ndarray, drop: set[int]) -> tuple[np.ndarray, np.ndarray]:
    """(positions, parents) without the joints ``drop`` (not the root), each child hung from its nearest kept
    ancestor."""
    keep = [j for j in range(positions.shape[0]) if j not in drop]
    index = {j: k for k, j in enumerate(keep)}

    def kept_parent(j: int) -> int:
        j = int(parents[j])
        while j in drop:
            j = int(parents[j])
        return index[j]

    return positions[keep], np.asarray([-1] + [kept_parent(j) for j in keep[1:]])


def _parents_first(positions: np.ndarray, parents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The joints breadth first (a split bone's middle right after its parent's other children): the order of the
    skeletons session 45's runs used (``Skeleton.from_arrays`` would sort them too, in another order)."""
    order = _breadth_first(parents)
    index = {j: k for k, j in enumerate(order)}
    return positions[order], np.asarray([-1] + [index[int(parents[j])] for j in order[1:]])


def main() -> None:
    if len(sys.argv) != 5 or sys.argv[2] not in ("split", "drop"):
        sys.exit(__doc__)
    table, way, share, out = Path(sys.argv[1]), sys.argv[2], float(sys.argv[3]), Path(sys.argv[4])
    out.mkdir(parents=True, exist_ok=True)
    with open(table, newline="") as fh:
        rows = [{k: v for k, v in r.items() if k} for r in csv.DictReader(fh)]
    fields = list(rows[0])
    written = []
    for row in rows:
        if not row.get("skeleton"):
            continue
        row = {
            k: (str((table.parent / v).resolve()) if k in ("source", "target", "skeleton", "gt") and v else v)
            for k, v in row.items()
        }
        source = load_mesh(row["source"])
        given = load_skeleton(row["skeleton"])
        positions, parents = np.asarray(given.positions), np.asarray(given.parents)
        diag = float(np.linalg.norm(np.ptp(source.vertices, axis=0)))  # the bounding box's, as regions.py
        if way == "split":
            new_pos, new_par = split_long_bones(positions, parents, share * diag)
        else:
            target = load_mesh(row["target"])
            found = suggest_skeleton(source.vertices, source.faces, other_poses=[(target.vertices, target.faces)])
            suggested = np.asarray(found.skeleton.positions)
            far = np.linalg.norm(positions[:, None] - suggested[None], axis=-1).min(1) > share * diag
            inner = np.bincount(parents[1:], minlength=parents.shape[0]) > 0
            missed = {j for j in range(1, len(parents)) if far[j] and inner[j]}
            new_pos, new_par = drop_joints(positions, parents, missed)
        names = [f"j{k}" for k in range(new_pos.shape[0])]
        path = out / f"{row['name']}.tgf"
        save_skeleton(path, Skeleton.from_arrays(new_pos, new_par, names))
        print(f"{row['name']}: {positions.shape[0]} -> {new_pos.shape[0]} joints")
        written.append({**row, "skeleton": str(path.resolve())})
    with open(out / "pairs.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=fields)
        writer.writeheader()
        writer.writerows(written)


if __name__ == "__main__":
    main()
