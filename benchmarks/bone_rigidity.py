"""How rigid is the ground-truth deformation around each bone? (a floor for the bone constraints)

For every bone, take the source surface points whose nearest bone (rest pose) is this one and
whose projection falls on the bone's 10 %–90 % section — the same axial range the bone samples
use — and their ground-truth positions on the target. Fit the best rigid motion (Kabsch) and
report the mean squared residual in units of the matcher's tolerance ε (normalised coordinates,
the matcher's normalisation). A flow that reproduces the ground truth on the surface cannot be
rigid to better than this around the bone; the constraint's samples lie closer to the axis
(radius 0.1 × length), so this is an indication, not a bound.

Usage: python benchmarks/bone_rigidity.py [--pairs demo,mano] [--eps 3e-4]
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))


def kabsch_residual(p: np.ndarray, q: np.ndarray) -> float:
    """Mean squared distance after the best rigid motion p → q (rows are points)."""
    pc, qc = p.mean(0), q.mean(0)
    u, _, vt = np.linalg.svd((p - pc).T @ (q - qc))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return float(np.mean(np.sum(((p - pc) @ r.T + qc - q) ** 2, axis=1)))


def nearest_bones(points: np.ndarray, heads: np.ndarray, tails: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The segment [heads[b], tails[b]] nearest each point (N,), and the (N, B) unclipped position of
    each point's projection along every segment (0 at the head, 1 at the tail).
    """
    ab = tails - heads
    t = np.einsum("nbk,bk->nb", points[:, None, :] - heads[None], ab) / np.maximum(np.sum(ab**2, axis=1), 1e-30)
    closest = heads[None] + np.clip(t, 0.0, 1.0)[..., None] * ab[None]
    return np.argmin(np.linalg.norm(points[:, None, :] - closest, axis=2), axis=1), t


def bone_rigidity(source, target, skeleton, gt, lo: float = 0.1, hi: float = 0.9) -> list[dict]:
    from ncflow.geometry.barycentric import surface_points
    from ncflow.geometry.normalize import fit_normalization

    norm = fit_normalization(source.vertices, source.faces)
    p = norm.apply(surface_points(source.vertices, source.faces, gt.face, gt.bary))
    q = norm.apply(np.asarray(target.vertices))
    joints = norm.apply(skeleton.positions)
    bones = skeleton.bones
    nearest, t = nearest_bones(p, joints[bones[:, 0]], joints[bones[:, 1]])
    rows = []
    for k in range(skeleton.n_bones):
        sel = (nearest == k) & (t[:, k] >= lo) & (t[:, k] <= hi)
        g = kabsch_residual(p[sel], q[sel]) if sel.sum() >= 4 else float("nan")
        rows.append({"bone": k, "points": int(sel.sum()), "g": g})
    return rows


def main() -> None:
    import match as bm

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", default="demo,mano")
    ap.add_argument("--eps", type=float, default=3e-4)
    args = ap.parse_args()
    for name in args.pairs.split(","):
        if name == "mano" and not os.path.isdir(bm.MANO_DIR):
            print(f"{name}: data not found, skipped")
            continue
        src, tgt, skel, gt = bm.PAIRS[name]()
        rows = bone_rigidity(src, tgt, skel, gt)
        print(f"\n{name}: ground-truth rigidity per bone, g/eps (surface points on the bone's 10-90 % section)\n")
        print("| bone | joints | points | g/ε |")
        print("|---|---|---|---|")
        for r in rows:
            k = r["bone"]
            print(f"| {k} | {skel.bones[k, 0]}→{skel.bones[k, 1]} | {r['points']} | {r['g'] / args.eps:.2f} |")
        g = np.array([r["g"] for r in rows]) / args.eps
        ok = np.isfinite(g)
        print(
            f"\n{name}: max {np.nanmax(g):.2f}, median {np.nanmedian(g):.2f}; "
            f"{int(np.sum(g[ok] > 1))} of {int(ok.sum())} bones above eps"
        )


if __name__ == "__main__":
    main()
