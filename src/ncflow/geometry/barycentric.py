"""Surface points as (face, barycentric) pairs: positions, vertices as surface points, rounding to a vertex.

A surface point is a face index f and barycentric coordinates (b0, b1, b2), b ≥ 0, Σb = 1; the
point is Σ_k b_k x_{F[f, k]} (docs/evaluation.md, "Conventions"). Correspondence maps, ground
truth and retriangulated targets are all written in this form. :func:`vertex_surface_points`
puts a vertex on the lowest-index face containing it, with a one-hot barycentric vector;
:func:`round_to_vertex` takes the corner with the largest weight (the vertex maps ``p2p_*`` of the
output contract).
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Float, Int


def surface_points(
    vertices: Float[np.ndarray, "V ..."],
    faces: Int[np.ndarray, "F 3"],
    face: Int[np.ndarray, " n"],
    bary: Float[np.ndarray, "n 3"],
) -> Float[np.ndarray, "n ..."]:
    """Positions Σ_k b_k x_{F[f, k]} of surface points (face, barycentric).

    ``vertices`` may be any per-vertex values (V, ...) — colours, weights, texture coordinates: the
    result is their barycentric interpolation, exact for values linear on each triangle.
    """
    v = np.asarray(vertices, dtype=np.float64)
    tri = v[np.asarray(faces)[np.asarray(face, dtype=np.int64)]]
    return np.einsum("nk,nk...->n...", np.asarray(bary, dtype=np.float64), tri)


def vertex_surface_points(
    vertex: Int[np.ndarray, " n"], faces: Int[np.ndarray, "F 3"], n_vertices: int | None = None
) -> tuple[Int[np.ndarray, " n"], Float[np.ndarray, "n 3"]]:
    """Vertices as surface points: the lowest-index face containing each vertex, one-hot barycentrics.

    Raises:
        ValueError: a vertex is out of range or belongs to no face.
    """
    faces = np.asarray(faces, dtype=np.int64)
    vertex = np.asarray(vertex, dtype=np.int64)
    nv = int(faces.max()) + 1 if n_vertices is None else int(n_vertices)
    if vertex.size and (vertex.min() < 0 or vertex.max() >= nv):
        raise ValueError(f"vertex index out of range [0, {nv})")
    # first face (and corner) of every vertex: scan faces in reverse so the lowest index wins
    first_face = np.full(nv, -1, dtype=np.int64)
    first_corner = np.full(nv, -1, dtype=np.int64)
    f_idx = np.repeat(np.arange(faces.shape[0]), 3)[::-1]
    corner = np.tile(np.arange(3), faces.shape[0])[::-1]
    flat = faces.reshape(-1)[::-1]
    first_face[flat] = f_idx
    first_corner[flat] = corner
    face = first_face[vertex]
    if np.any(face < 0):
        bad = int(vertex[np.argmax(face < 0)])
        raise ValueError(f"vertex {bad} belongs to no face")
    bary = np.zeros((vertex.size, 3))
    bary[np.arange(vertex.size), first_corner[vertex]] = 1.0
    return face, bary


def round_to_vertex(
    faces: Int[np.ndarray, "F 3"], face: Int[np.ndarray, " n"], bary: Float[np.ndarray, "n 3"]
) -> Int[np.ndarray, " n"]:
    """Vertex-level rounding of surface points: the corner with the largest barycentric weight.

    Args:
        faces: (F, 3) triangles of the surface.
        face: (n,) face index of each point.
        bary: (n, 3) barycentric coordinates of each point in its face.

    Returns:
        (n,) vertex indices; ties go to the first corner of the face.
    """
    faces = np.asarray(faces, dtype=np.int64)
    face = np.asarray(face, dtype=np.int64)
    corner = np.argmax(np.asarray(bary), axis=1)
    return faces[face, corner]
