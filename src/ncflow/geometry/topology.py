"""Edge tables of triangle meshes, as the Normal Cycles need them, and the closing of boundary loops.

:func:`mesh_topology` builds a :class:`Topology`: the unique undirected edges (a, b), a < b, their
incident faces (up to four, so closed, open and mildly non-manifold meshes all work) with the sign
of each face's winding along the edge, and the boundary edges and vertices (docs/architecture.md,
"Normal Cycles"). It is built once per mesh and reused at every training step.
:func:`close_boundary` closes every boundary loop with a fan of triangles to the loop's centroid,
wound consistently with the surface: the enclosed volume of an open mesh (normalisation) and its
tetrahedralisation (:mod:`ncflow.tissue`) are taken of that closed surface.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from jaxtyping import Bool, Float, Int

from ncflow.errors import InputError


@dataclasses.dataclass(frozen=True)
class Topology:
    """Edge tables of a triangle mesh, as the Normal Cycle representation needs them.

    Attributes:
        faces: (F, 3) the faces the tables were built from.
        edges: (E, 2) unique undirected edges (a, b) with a < b, sorted lexicographically.
        edge_faces: (E, 4) incident faces in increasing order, padded with -1.
        edge_signs: (E, 4) +1 where the face runs a→b in its winding, -1 where it runs b→a,
            0 in padded slots.
        boundary_edges: (E,) bool, edges with exactly one incident face.
        boundary_vertices: (Bv,) sorted vertices on boundary edges.
        boundary_neighbors: (Bv, k) for each boundary vertex, the other ends of its boundary
            edges, padded with -1.
    """

    faces: Int[np.ndarray, "F 3"]
    edges: Int[np.ndarray, "E 2"]
    edge_faces: Int[np.ndarray, "E 4"]
    edge_signs: Int[np.ndarray, "E 4"]
    boundary_edges: np.ndarray
    boundary_vertices: Int[np.ndarray, " Bv"]
    boundary_neighbors: Int[np.ndarray, "Bv k"]

    @property
    def n_edges(self) -> int:
        return int(self.edges.shape[0])

    @property
    def has_boundary(self) -> bool:
        return bool(self.boundary_vertices.size)


def mesh_topology(faces: Int[np.ndarray, "F 3"], n_vertices: int | None = None, name: str | None = None) -> Topology:
    """Build the edge tables of a triangle mesh (closed, open, or non-manifold with ≤ 4 faces per edge).

    Precondition: at most four faces on an edge. Every mesh a user gives passes the intake step
    (:func:`ncflow.geometry.repair.repair_mesh`: at most two faces on an edge, and one fan per vertex,
    so that closing its holes by :func:`close_boundary` keeps at most two faces on an edge too).

    Raises:
        InputError: an edge is shared by more than four faces (a mesh that skipped the intake step).
    """
    faces = np.asarray(faces, dtype=np.int64)
    nf = faces.shape[0]
    nv = int(faces.max()) + 1 if n_vertices is None else int(n_vertices)
    directed = np.stack([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]], axis=1).reshape(-1, 2)
    face_of = np.repeat(np.arange(nf), 3)
    lo = directed.min(1)
    hi = directed.max(1)
    keep = lo != hi  # a face with a repeated vertex has a zero-length "edge": no edge at all
    lo, hi, face_of = lo[keep], hi[keep], face_of[keep]
    sign = np.where(directed[keep, 0] < directed[keep, 1], 1, -1)
    key = lo * nv + hi
    uniq, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    if counts.size and counts.max() > 4:
        worst = int(np.argmax(counts))
        raise InputError(
            f"non-manifold edge ({int(uniq[worst] // nv)}, {int(uniq[worst] % nv)}) is shared by "
            f"{int(counts[worst])} faces (at most 4 supported; repair the mesh first: ncflow.geometry.repair)",
            name,
        )
    edges = np.stack([uniq // nv, uniq % nv], axis=1)
    order = np.lexsort((face_of, inverse))
    group_start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    slot = np.arange(order.size) - group_start[inverse[order]]
    edge_faces = np.full((uniq.size, 4), -1, dtype=np.int64)
    edge_signs = np.zeros((uniq.size, 4), dtype=np.int64)
    edge_faces[inverse[order], slot] = face_of[order]
    edge_signs[inverse[order], slot] = sign[order]
    boundary = counts == 1
    bedges = edges[boundary]
    bverts = np.unique(bedges.reshape(-1))
    if bverts.size:
        ends = np.concatenate([bedges, bedges[:, ::-1]], axis=0)  # (v, neighbour) both ways
        ends = ends[np.lexsort((ends[:, 1], ends[:, 0]))]
        pos = np.searchsorted(bverts, ends[:, 0])
        deg = np.bincount(pos, minlength=bverts.size)
        start = np.concatenate([[0], np.cumsum(deg)[:-1]])
        neighbors = np.full((bverts.size, int(deg.max())), -1, dtype=np.int64)
        neighbors[pos, np.arange(ends.shape[0]) - start[pos]] = ends[:, 1]
    else:
        neighbors = np.zeros((0, 2), dtype=np.int64)
    return Topology(faces, edges, edge_faces, edge_signs, boundary, bverts, neighbors)


def pad_topology(topology: Topology, n_faces: int, n_edges: int, n_boundary: int | None = None) -> Topology:
    """The tables with rows appended that represent nothing, to ``n_faces`` faces, ``n_edges`` edges
    and ``n_boundary`` boundary vertices (default: as many as there are; a mesh without boundary
    keeps none): faces (0, 0, 0) and edges (0, 0) are degenerate (zero area and length, so zero
    weight in every measure), padded edges have no incident faces and are not boundary edges, and
    padded boundary vertices (vertex 0) have no neighbours. Shapes padded to a size bucket
    (:mod:`ncflow.jit.buckets`) let meshes of similar size share compiled programs.
    """
    t = topology
    n_boundary = t.boundary_vertices.size if n_boundary is None or not t.has_boundary else n_boundary
    extra_f, extra_e = n_faces - t.faces.shape[0], n_edges - t.n_edges
    extra_b = n_boundary - t.boundary_vertices.size
    if min(extra_f, extra_e, extra_b) < 0:
        raise ValueError("pad_topology pads; it cannot remove rows")

    def pad(a, extra, value):
        return np.concatenate([a, np.full((extra, *a.shape[1:]), value, a.dtype)])

    return Topology(
        faces=pad(t.faces, extra_f, 0),
        edges=pad(t.edges, extra_e, 0),
        edge_faces=pad(t.edge_faces, extra_e, -1),
        edge_signs=pad(t.edge_signs, extra_e, 0),
        boundary_edges=pad(t.boundary_edges, extra_e, False),
        boundary_vertices=pad(t.boundary_vertices, extra_b, 0),
        boundary_neighbors=pad(t.boundary_neighbors, extra_b, -1),
    )


def close_boundary(
    vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"]
) -> tuple[Float[np.ndarray, "W 3"], Int[np.ndarray, "G 3"]]:
    """Close every boundary loop with a fan of triangles to the loop's centroid.

    The caps are wound consistently with the adjacent faces, so a mesh that is closed except for
    holes (e.g. a hand open at the wrist) becomes a closed, consistently oriented surface. Used for
    the enclosed volume of open meshes and before tetrahedralisation. Vertices keep their indices;
    one centroid vertex per loop is appended.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    topo = mesh_topology(faces, vertices.shape[0])
    if not topo.has_boundary:
        return vertices, faces
    bidx = np.flatnonzero(topo.boundary_edges)
    a, b = topo.edges[bidx, 0], topo.edges[bidx, 1]
    s = topo.edge_signs[bidx, 0]
    # the face runs a->b when s = +1, so the cap must run b->a
    start = np.where(s > 0, b, a)
    end = np.where(s > 0, a, b)
    nv = vertices.shape[0]
    graph = coo_matrix((np.ones(a.size), (a, b)), shape=(nv, nv))
    _, label = connected_components(graph, directed=False)
    loops, loop_of_edge = np.unique(label[a], return_inverse=True)
    loop_of_edge = loop_of_edge.reshape(-1)
    # each loop's distinct vertices, all loops at once (a triangle soup has one loop per face)
    member = np.unique(np.stack([np.tile(loop_of_edge, 2), np.concatenate([a, b])], axis=1), axis=0)
    count = np.bincount(member[:, 0], minlength=loops.size)[:, None]
    centroids = np.stack(
        [np.bincount(member[:, 0], weights=vertices[member[:, 1], d], minlength=loops.size) for d in range(3)], axis=1
    ) / np.maximum(count, 1)
    cap = np.stack([start, end, nv + loop_of_edge], axis=1)
    return np.concatenate([vertices, centroids]), np.concatenate([faces, cap])


def vertex_components(
    faces: Int[np.ndarray, "F 3"], n_vertices: int, joined: Bool[np.ndarray, "F 3"] | None = None
) -> Int[np.ndarray, " V"]:
    """(V,) the connected component of each vertex, vertices joined through the faces' edges (a vertex in
    no face is a component of its own); labels 0, 1, … as SciPy numbers them. ``joined`` (F, 3): which of
    each face's edges (corner k to corner k + 1 mod 3) join their vertices (default: all).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    f = np.asarray(faces, np.int64).reshape(-1, 3)
    rows, cols = f.reshape(-1), f[:, [1, 2, 0]].reshape(-1)
    if joined is not None:
        keep = np.asarray(joined, bool).reshape(-1)
        rows, cols = rows[keep], cols[keep]
    graph = coo_matrix((np.ones(rows.size), (rows, cols)), shape=(n_vertices, n_vertices))
    return connected_components(graph, directed=False)[1]
