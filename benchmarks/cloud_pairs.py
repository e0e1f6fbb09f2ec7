"""Point-cloud targets for a benchmark: every pair of a pairs CSV again with its target as a bare point cloud.

    python benchmarks/cloud_pairs.py PAIRS.csv OUT.csv [--noise S] [--outliers F] [--only NAME ...] [--seed K]

For each row, ``<pair folder>/target_cloud[_tag].xyz`` holds the target's vertices without faces (so the
pair's ground truth holds, vertex for vertex), optionally moved by Gaussian noise of σ = S × the target's
bounding-box diagonal and followed by F × N "flying pixels" drawn uniformly in the box grown by a quarter
(ground truth then partial: ``gt_cloud[_tag].npz`` with ``target_index`` of the true points). OUT.csv is
the same CSV with those targets (name suffixed ``_cloud[_tag]``), for ``ncflow benchmark``.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

from ncflow.io.files import read_npz_arrays
from ncflow.io.meshes import load_mesh


def cloud_row(row: dict, root: Path, noise: float, outliers: float, rng: np.random.Generator, tag: str) -> dict:
    target = load_mesh(root / row["target"])
    v = target.vertices.copy()
    lo, hi = v.min(axis=0), v.max(axis=0)
    diag = float(np.linalg.norm(hi - lo))
    if noise:
        v = v + rng.normal(scale=noise * diag, size=v.shape)
    out = dict(row, name=f"{row['name']}_cloud{tag}")
    folder = Path(row["target"]).parent
    if outliers:
        k = int(round(outliers * v.shape[0]))
        pad = 0.25 * (hi - lo)
        v = np.vstack([v, rng.uniform(lo - pad, hi + pad, size=(k, 3))])
        gt = read_npz_arrays(root / row["gt"], ("face", "bary"), ("target_index",))
        index = gt.get("target_index", np.arange(target.n_vertices))
        gt_name = folder / f"gt_cloud{tag}.npz"
        np.savez(root / gt_name, face=gt["face"], bary=gt["bary"], target_index=index)
        out["gt"] = str(gt_name)
    name = folder / f"target_cloud{tag}.xyz"
    np.savetxt(root / name, v, fmt="%.9g")
    out["target"] = str(name)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("pairs")
    p.add_argument("out")
    p.add_argument("--noise", type=float, default=0.0)
    p.add_argument("--outliers", type=float, default=0.0)
    p.add_argument("--only", nargs="+", default=None)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    src = Path(args.pairs)
    root = src.parent
    rows = [r for r in csv.DictReader(open(src, newline="")) if args.only is None or r["name"] in args.only]
    tag = (f"_n{args.noise:g}" if args.noise else "") + (f"_o{args.outliers:g}" if args.outliers else "")
    rng = np.random.default_rng(args.seed)
    out_rows = [cloud_row(r, root, args.noise, args.outliers, rng, tag) for r in rows]
    write_pairs(Path(args.out), out_rows, root)
    return 0


def write_pairs(out: Path, rows: list[dict], root: Path) -> None:
    """A pairs CSV of ``rows`` whose file cells, relative to ``root``, are written as paths under it."""
    with open(out, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            w.writerow(
                {
                    k: (str(root / v) if k in ("source", "target", "skeleton", "gt", "target_motion") and v else v)
                    for k, v in r.items()
                }
            )
    print(f"{out}: {len(rows)} pairs")


if __name__ == "__main__":
    sys.exit(main())
