"""Merge the pairs.csv of every folder PAIRS/*/ into PAIRS/all.csv (paths relative to PAIRS; each row named
after its folder when the folder holds one pair; columns: the union).

    python benchmarks/merge_pairs.py PAIRS [--keep-names]
"""

import csv
import sys
from pathlib import Path

PATH_COLUMNS = ("source", "target", "skeleton", "gt", "target_motion")


def merge(root: Path, rename: bool = True) -> int:
    rows, columns = [], []
    for csv_path in sorted(root.glob("*/pairs.csv")):
        d = csv_path.parent.name
        for r in csv.DictReader(open(csv_path, newline="")):
            paths = {k: f"{d}/{r[k]}" for k in PATH_COLUMNS if r.get(k)}
            rows.append({**r, **paths, **({"name": d} if rename else {})})
            columns += [c for c in r if c not in columns]
    with open(root / "all.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=columns, restval="")
        w.writeheader()
        w.writerows(rows)
    return len(rows)


if __name__ == "__main__":
    root = Path(sys.argv[1])
    print(f"{root / 'all.csv'}: {merge(root, rename='--keep-names' not in sys.argv[2:])} pairs")
