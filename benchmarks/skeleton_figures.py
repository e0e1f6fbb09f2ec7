"""Pictures of suggested skeletons (docs/skeleton-suggest.md): generated characters, at rest and posed,
each with its suggested joints and bones (red) and its true skeleton (blue) over the mesh's vertices,
seen along the mesh's smallest principal axis; with ``--pairs``, the sources of pairs made by
``benchmarks/hard_pairs.sh`` (CesiumMan, Fox, MANO, ...) with their drawn skeleton (blue), the suggestion
from the source alone (red) and the one that also sees the target (green), as ``ncflow match`` makes it.

Usage: python benchmarks/skeleton_figures.py [OUT.png]   (default docs/suggested_skeletons.png)
       python benchmarks/skeleton_figures.py OUT.png --pairs hard/pairs cesiumman_half_cycle fox_walk ...
"""

from __future__ import annotations

import sys
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ncflow.skeleton.suggest import suggest_skeleton  # noqa: E402
from ncflow.synthetic.characters import make_character, pose_character  # noqa: E402

CASES = [
    ("humanoid", 0, None, "humanoid"),
    ("humanoid", 1, 3, "humanoid, posed"),
    ("hand", 0, None, "hand"),
    ("hand", 1, 5, "hand, posed"),
    ("quadruped", 0, None, "quadruped"),
    ("quadruped", 2, 7, "quadruped, posed"),
]


def _draw(ax, positions, parents, colour, label):
    for j, p in enumerate(parents):
        if p >= 0:
            seg = positions[[p, j]]
            ax.plot(seg[:, 0], seg[:, 1], color=colour, lw=2)
    ax.scatter(*positions.T, color=colour, s=14, label=label, zorder=3)


def _plane(vertices):
    """The mesh's centre and its two largest principal axes: the view that shows most of it."""
    centre = vertices.mean(0)
    _, _, vt = np.linalg.svd(vertices - centre, full_matrices=False)
    return centre, vt[:2].T


def pairs_figure(out: str, root: str, names: list[str]) -> None:
    """Each pair's source: drawn skeleton, suggestion alone, suggestion that sees the target."""
    from ncflow.geometry.mesh import repaired_mesh
    from ncflow.io.meshes import load_mesh
    from ncflow.io.skeletons import load_skeleton

    cols = min(3, len(names))
    rows = -(-len(names) // cols)
    fig = plt.figure(figsize=(5.5 * cols, 4.5 * rows))
    for k, name in enumerate(names):
        folder = f"{root}/{name}/pair_000"
        src = repaired_mesh(load_mesh(f"{folder}/source.ply"))[0]
        tgt = repaired_mesh(load_mesh(f"{folder}/target.ply"))[0]
        given = load_skeleton(f"{folder}/source_skeleton.tgf")
        alone = suggest_skeleton(src.vertices, src.faces).skeleton
        t0 = time.perf_counter()
        both = suggest_skeleton(src.vertices, src.faces, other_poses=[(tgt.vertices, tgt.faces)])
        seconds = time.perf_counter() - t0
        centre, axes = _plane(src.vertices)
        ax = fig.add_subplot(rows, cols, k + 1)
        ax.scatter(*((src.vertices - centre) @ axes).T, s=0.5, color="0.75")
        _draw(ax, (given.positions - centre) @ axes, np.asarray(given.parents), "tab:blue", "drawn")
        _draw(ax, (alone.positions - centre) @ axes, np.asarray(alone.parents), "tab:red", "suggested")
        sk = both.skeleton
        _draw(ax, (sk.positions - centre) @ axes, np.asarray(sk.parents), "tab:green", "suggested, seeing the target")
        ax.set_aspect("equal")
        ax.set_axis_off()
        ax.set_title(
            f"{name}: {alone.n_joints} / {sk.n_joints} joints ({given.n_joints} drawn), {seconds:.1f} s", fontsize=9
        )
        if k == 0:
            ax.legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=80)
    print(f"wrote {out}")


def main() -> None:
    out = sys.argv[1] if len(sys.argv) > 1 else "docs/suggested_skeletons.png"
    if len(sys.argv) > 3 and sys.argv[2] == "--pairs":
        pairs_figure(out, sys.argv[3], sys.argv[4:])
        return
    fig = plt.figure(figsize=(15, 9))
    for k, (kind, seed, pose_seed, title) in enumerate(CASES):
        ch = make_character(kind, seed)
        if pose_seed is None:
            v, f, joints = ch.mesh.vertices, ch.mesh.faces, ch.skeleton.positions
        else:
            posed = pose_character(ch, seed=pose_seed)
            v, f, joints = posed.vertices, ch.mesh.faces, posed.joints
        t0 = time.perf_counter()
        found = suggest_skeleton(v, f).skeleton
        seconds = time.perf_counter() - t0
        centre, axes = _plane(v)
        ax = fig.add_subplot(2, 3, k + 1)
        ax.scatter(*((v - centre) @ axes).T, s=0.5, color="0.7")
        _draw(ax, (joints - centre) @ axes, np.asarray(ch.skeleton.parents), "tab:blue", "true")
        _draw(ax, (found.positions - centre) @ axes, np.asarray(found.parents), "tab:red", "suggested")
        ax.set_aspect("equal")
        ax.set_axis_off()
        ax.set_title(f"{title}: {found.n_joints} joints suggested ({ch.skeleton.n_joints} true), {seconds:.2f} s")
        if k == 0:
            ax.legend(loc="lower left")
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
