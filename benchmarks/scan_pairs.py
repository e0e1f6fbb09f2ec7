"""The scan development set (issue 45): every pair of a pairs CSV again with its target made scan-like.

    python benchmarks/scan_pairs.py PAIRS.csv OUT.csv [--cases view0 view1 ...] [--only NAME ...] [--seed K]

Cases (each a target beside the pair's, ``target_<case>.ply`` / ``.xyz``, with ``gt_<case>.npz`` holding the
ground truth of the points kept: ``target_index`` into the new target):

* ``view0``, ``view1``, ``view2``: what one orthographic depth camera sees (:func:`ncflow.synthetic.scans.single_view`),
  looking across the target's longest axis from three directions 120° apart (the first drawn from the seed);
* ``quarter``: ``view0`` cut further to the half of it on one side of its centre (about a quarter of the
  surface);
* ``holes``: four holes, balls around random surface points grown until 15 % of the area is gone;
* ``noise``: every vertex moved by Gaussian noise of σ = 0.4 % of the bounding-box diagonal;
* ``view0_cloud``: ``view0``'s vertices as a point cloud with noise of 0.2 % and 2 % flying pixels;
* ``holes_noise``: ``holes`` with the noise of ``noise``.

OUT.csv is the input CSV with these rows (names suffixed ``_<case>``) for ``ncflow benchmark``; the
complete pair's own row is kept first so that one benchmark gives both.
"""

from __future__ import annotations

import argparse
import csv
import os
import sys
from pathlib import Path

import numpy as np

from ncflow.geometry.mesh import face_areas
from ncflow.io.files import read_npz_arrays
from ncflow.io.meshes import load_mesh, save_mesh
from ncflow.synthetic.scans import single_view

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from cloud_pairs import write_pairs  # noqa: E402

CASES = ("view0", "view1", "view2", "quarter", "holes", "noise", "view0_cloud", "holes_noise")


def _truth(root: Path, row: dict, n_target: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    gt = read_npz_arrays(root / row["gt"], ("face", "bary"), ("target_index",))
    index = gt.get("target_index", np.arange(n_target))
    return gt["face"], gt["bary"], np.asarray(index)


def _kept_faces(v: np.ndarray, f: np.ndarray, keep: np.ndarray):
    """(vertices, faces, original index of each vertex kept) of the faces ``keep``."""
    faces = f[keep]
    used = np.unique(faces)
    renumber = np.full(v.shape[0], -1, np.int64)
    renumber[used] = np.arange(used.size)
    return v[used], renumber[faces], used


def _view_direction(v: np.ndarray, k: int, rng_angle: float) -> np.ndarray:
    axes = np.linalg.svd(v - v.mean(0), full_matrices=False)[2]
    angle = rng_angle + 2.0 * np.pi * k / 3.0
    return np.cos(angle) * axes[1] + np.sin(angle) * axes[2]


def _holes(v: np.ndarray, f: np.ndarray, rng: np.random.Generator, share: float = 0.15, n: int = 4) -> np.ndarray:
    """Faces kept after ``n`` holes grown together (balls around random face centres) to ``share`` of the area."""
    areas = face_areas(v, f)
    centres = v[f].mean(1)
    seeds = centres[rng.choice(f.shape[0], n, replace=False, p=areas / areas.sum())]
    dist = np.min(np.linalg.norm(centres[:, None] - seeds[None], axis=2), axis=1)
    order = np.argsort(dist)
    cut = np.searchsorted(np.cumsum(areas[order]), share * areas.sum())
    keep = np.ones(f.shape[0], bool)
    keep[order[: cut + 1]] = False
    return keep


def scan_rows(row: dict, root: Path, cases, rng: np.random.Generator) -> list[dict]:
    target = load_mesh(root / row["target"])
    v, f = target.vertices, target.faces
    diag = float(np.linalg.norm(v.max(0) - v.min(0)))
    face, bary, index = _truth(root, row, target.n_vertices)
    truth = np.full(target.n_vertices, -1, np.int64)
    truth[index] = np.arange(index.size)
    folder = Path(row["target"]).parent
    angle = float(rng.uniform(0.0, 2.0 * np.pi))
    out = []

    def emit(case: str, vertices, faces, origin, cloud: bool = False, extra=None):
        rows = truth[origin]
        has = rows >= 0
        gt_name = folder / f"gt_{case}.npz"
        np.savez(root / gt_name, face=face[rows[has]], bary=bary[rows[has]], target_index=np.flatnonzero(has))
        if cloud:
            pts = vertices if extra is None else np.vstack([vertices, extra])
            name = folder / f"target_{case}.xyz"
            np.savetxt(root / name, pts, fmt="%.9g")
        else:
            name = folder / f"target_{case}.ply"
            save_mesh(root / name, vertices, faces)
        out.append(dict(row, name=f"{row['name']}_{case}", target=str(name), gt=str(gt_name)))

    views = {}
    for k in range(3):
        views[k] = single_view(v, f, _view_direction(v, k, angle))
    for case in cases:
        if case.startswith("view") and not case.endswith("cloud"):
            emit(case, *_kept_faces(v, f, views[int(case[4])]))
        elif case == "quarter":
            keep = views[0].copy()
            centres = v[f].mean(1)
            axis = np.linalg.svd(v - v.mean(0), full_matrices=False)[2][0]
            side = (centres - centres[keep].mean(0)) @ axis
            keep &= side > 0
            emit(case, *_kept_faces(v, f, keep))
        elif case == "holes":
            emit(case, *_kept_faces(v, f, _holes(v, f, rng)))
        elif case == "noise":
            emit(case, v + rng.normal(scale=0.004 * diag, size=v.shape), f, np.arange(v.shape[0]))
        elif case == "holes_noise":
            hv, hf, origin = _kept_faces(v, f, _holes(v, f, rng))
            emit(case, hv + rng.normal(scale=0.004 * diag, size=hv.shape), hf, origin)
        elif case == "view0_cloud":
            cv, _, origin = _kept_faces(v, f, views[0])
            cv = cv + rng.normal(scale=0.002 * diag, size=cv.shape)
            lo, hi = cv.min(0), cv.max(0)
            pad = 0.25 * (hi - lo)
            flying = rng.uniform(lo - pad, hi + pad, size=(int(round(0.02 * cv.shape[0])), 3))
            emit(case, cv, None, origin, cloud=True, extra=flying)
        else:
            raise SystemExit(f"unknown case {case!r}; use {', '.join(CASES)}")
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("pairs")
    p.add_argument("out")
    p.add_argument("--cases", nargs="+", default=list(CASES))
    p.add_argument("--only", nargs="+", default=None)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-complete", action="store_true", help="leave the complete pairs' rows out")
    args = p.parse_args(argv)
    src = Path(args.pairs)
    root = src.parent
    rows = [r for r in csv.DictReader(open(src, newline="")) if args.only is None or r["name"] in args.only]
    out_rows = []
    for i, r in enumerate(rows):
        rng = np.random.default_rng([args.seed, i])
        out_rows += ([] if args.no_complete else [dict(r)]) + scan_rows(r, root, args.cases, rng)
    write_pairs(Path(args.out), out_rows, root)
    return 0


if __name__ == "__main__":
    sys.exit(main())
