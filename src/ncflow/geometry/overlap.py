"""Self-overlap: how much of a surface lies inside another part of the same surface.

A surface that passes through itself (a fingertip sunk into the palm of a captured or rigged fist,
an arm through the torso) cannot be reached from one that does not by a flow of space, which keeps
every surface free of self-intersections. :func:`self_overlap` measures it: each face's centre is
moved a little inwards (``offset`` × the bounding-box diagonal along the face's inward normal)
and the face counts as overlapped when that point is inside the closed surface more than once
(generalised winding number above 1.5, :func:`ncflow.geometry.winding.winding_numbers`; an open
surface is closed first by :func:`ncflow.geometry.topology.close_boundary`). The result is the
overlapped share of the area. Meshes larger than ``max_vertices`` are decimated first
(:func:`ncflow.geometry.decimate.decimate`), so the cost stays under a second at any resolution;
a mesh with far more faces than its vertices can carry as a surface (a hostile file: thousands of
faces on few vertices) is measured on an evenly strided subset of its faces, at most
``max_pairs`` / F of them, so the work stays bounded too.
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Float, Int

from ncflow.geometry.decimate import decimate
from ncflow.geometry.topology import close_boundary
from ncflow.geometry.winding import signed_volume, winding_numbers

DEFAULT_OFFSET = 0.003
"""Inward offset of the face centres, a fraction of the bounding-box diagonal."""
DEFAULT_MAX_VERTICES = 1000
"""Meshes with more vertices are decimated to this many before the test."""
DEFAULT_MAX_PAIRS = 20_000_000
"""At most this many (face centre, triangle) winding-number terms (about 4 s); a decimated surface
needs about 2000 × 2000."""


def self_overlap(
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    offset: float = DEFAULT_OFFSET,
    max_vertices: int = DEFAULT_MAX_VERTICES,
    max_pairs: int = DEFAULT_MAX_PAIRS,
) -> float:
    """Share of the surface area in [0, 1] that lies inside another part of the same surface.

    Args:
        vertices: (V, 3) positions.
        faces: (F, 3) triangles, wound consistently (either way round).
        offset: inward offset of the face centres, a fraction of the bounding-box diagonal.
        max_vertices: decimate larger meshes to this many vertices first.
        max_pairs: at most this many winding-number terms: beyond, an evenly strided subset of
            the faces is tested.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.shape[0] > max_vertices:
        work = decimate(v, f, max_vertices)
        v, f = work.vertices, work.faces
    cv, cf = close_boundary(v, f)
    tri = v[f]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    if not area.sum() > 0:
        return 0.0
    inward = -np.sign(signed_volume(cv, cf) or 1.0) * cross / np.maximum(2.0 * area, 1e-300)[:, None]
    diag = float(np.linalg.norm(v.max(0) - v.min(0)))
    n_query = max(1, min(f.shape[0], int(max_pairs) // max(1, cf.shape[0])))
    rows = np.unique(np.linspace(0, f.shape[0] - 1, n_query).round().astype(np.int64))
    query = tri[rows].mean(1) + offset * diag * inward[rows]
    w = np.abs(winding_numbers(query, cv[cf]))
    a = area[rows]
    return float(a[w > 1.5].sum() / a.sum()) if a.sum() > 0 else 0.0
