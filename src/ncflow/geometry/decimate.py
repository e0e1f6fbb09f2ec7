"""A working-resolution copy of a mesh whose vertices are a subset of the original's (issue 17).

Quadric-error decimation (fast-simplification, the library pyvista and trimesh use) chooses the
connectivity; each decimated vertex is then moved to a distinct original vertex near it, so the
working mesh is the original sampled at its own vertices: a field flowed over the working mesh
and over the full mesh agrees exactly at the vertices the two share. The snap moves a vertex by
about one original edge length, far below the length scales the training sees.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from jaxtyping import Float, Int


@dataclasses.dataclass(frozen=True)
class Decimation:
    """A working mesh made of original vertices.

    Attributes:
        vertices: (n, 3) working vertices, ``original[kept]``.
        faces: (m, 3) working triangles (indices into ``vertices``).
        kept: (n,) index of each working vertex in the original mesh.
    """

    vertices: Float[np.ndarray, "n 3"]
    faces: Int[np.ndarray, "m 3"]
    kept: Int[np.ndarray, " n"]


def decimate(vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"], max_vertices: int) -> Decimation:
    """At most about ``max_vertices`` vertices: the mesh itself when it is not larger.

    Args:
        vertices: (V, 3) original vertices.
        faces: (F, 3) original triangles.
        max_vertices: the working size (a closed surface has about twice as many faces).
    """
    import fast_simplification
    from scipy.spatial import cKDTree

    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    if v.shape[0] <= max_vertices:
        return Decimation(v, f, np.arange(v.shape[0], dtype=np.int64))
    dv, df = fast_simplification.simplify(v, f.astype(np.int32), target_count=max(4, 2 * int(max_vertices)))
    dv, df = np.asarray(dv, np.float64), np.asarray(df, np.int64)
    used = np.unique(df)
    remap = np.full(dv.shape[0], -1, np.int64)
    remap[used] = np.arange(used.size)
    dv, df = dv[used], remap[df]
    kept = _distinct_nearest(cKDTree(v), dv)
    df = df[(df[:, 0] != df[:, 1]) & (df[:, 1] != df[:, 2]) & (df[:, 0] != df[:, 2])]
    return Decimation(v[kept], df, kept)


def _distinct_nearest(tree, points: np.ndarray) -> np.ndarray:
    """For each point, the nearest tree point not taken by a point nearer to it (greedy by distance)."""
    k = min(16, tree.n)
    dist, idx = tree.query(points, k=k)
    dist, idx = dist.reshape(len(points), k), idx.reshape(len(points), k)
    out = np.full(len(points), -1, np.int64)
    taken = np.zeros(tree.n, bool)
    for i in np.argsort(dist[:, 0], kind="stable"):
        for j in idx[i]:
            if not taken[j]:
                out[i] = j
                taken[j] = True
                break
        if out[i] < 0:  # every one of its k nearest is taken: search further
            _, more = tree.query(points[i], k=tree.n)
            j = next(int(c) for c in np.atleast_1d(more) if not taken[c])
            out[i] = j
            taken[j] = True
    return out
