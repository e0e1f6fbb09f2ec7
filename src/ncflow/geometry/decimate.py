"""A working-resolution copy of a mesh whose vertices are a subset of the original's.

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

from ncflow.geometry.repair import repair_mesh


@dataclasses.dataclass(frozen=True)
class Decimation:
    """A working mesh made of original vertices.

    Attributes:
        vertices: (n, 3) working vertices, ``original[kept]``.
        faces: (m, 3) working triangles (indices into ``vertices``).
        kept: (n,) index of each working vertex in the original mesh (distinct, but for the copies
            of a vertex the repair split where the decimation left a non-manifold vertex).
    """

    vertices: Float[np.ndarray, "n 3"]
    faces: Int[np.ndarray, "m 3"]
    kept: Int[np.ndarray, " n"]


def decimate(vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"], max_vertices: int) -> Decimation:
    """At most about ``max_vertices`` vertices: the mesh itself when it is not larger.

    Any mesh is taken: vertices in no face are left out, a mesh whose faces are already within the
    face budget (about twice ``max_vertices``, what a closed surface of that many vertices has) is
    kept whole, and the decimated mesh is repaired (:func:`~ncflow.geometry.repair.repair_mesh`:
    quadric decimation can leave zero-area faces and edges of more than two faces), so what comes
    back has every edge in at most two faces.

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
    used = np.unique(f)
    budget = max(4, 2 * int(max_vertices))
    if used.size <= max_vertices or f.shape[0] <= budget:  # nothing to decimate: the faces' vertices alone
        remap = np.full(v.shape[0], -1, np.int64)
        remap[used] = np.arange(used.size)
        return Decimation(v[used], remap[f], used)
    dv, df = fast_simplification.simplify(v, f.astype(np.int32), target_count=budget)
    dv, df = np.asarray(dv, np.float64), np.asarray(df, np.int64)
    used = np.unique(df)
    remap = np.full(dv.shape[0], -1, np.int64)
    remap[used] = np.arange(used.size)
    dv, df = dv[used], remap[df]
    kept = _distinct_nearest(cKDTree(v), dv)
    fixed = repair_mesh(v[kept], df)
    kept = kept[fixed.vertex_origin]
    return Decimation(v[kept], fixed.faces, kept)


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
