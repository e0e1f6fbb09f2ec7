"""Repair of imperfect meshes: the one intake step every mesh passes before it is matched or measured.

Meshes from modelling tools, converters and scanners are rarely clean. :func:`repair_mesh` turns any
mesh with finite coordinates and faces in range into one that every later step can take: every edge
shared by at most two faces, every vertex a single fan, no zero-area, repeated or unreferenced
elements. In order:

1. **weld**: vertices at the same place become one (exactly, or within ``weld_tolerance`` × the
   bounding-box diagonal): a triangle soup or a mesh split at its texture seams is one surface again;
2. **degenerate faces** (a repeated corner, or area ≤ :data:`AREA_TOL` × diagonal²) are dropped;
3. **duplicate faces** (the same three corners, either winding) are dropped but the first;
4. **winding**: the faces of each orientable component are wound one way, the way most of its area
   already is (a patch wound against its neighbours is turned);
5. **non-manifold vertices and edges** are split: on an edge of more than two faces, the faces that
   bound one piece of the solid are paired (ordered by angle about the edge); then each vertex gets
   one copy per fan of faces joined through edges of two faces or such pairs, so the fins, flaps and
   pinches of a mesh come apart from the surface they touch; a face still left on an edge with more
   than two faces gets its own corners;
6. **small components** (their area below ``min_component`` of the whole), counted after the split so
   that a fin torn off a surface is a component of its own, are dropped, when asked;
7. unreferenced vertices are left out.

Nothing moves: every repaired vertex is an input vertex (:attr:`Repair.vertex_origin`) and every
repaired face an input face (:attr:`Repair.face_origin`) with the same corners, so a point of the
repaired surface (face, barycentric coordinates) is the same point of the input's, and outputs can be
written per input vertex and face. A clean mesh comes back as it is, array for array. What was done is
counted (:attr:`Repair.counts`) and said in one line (:meth:`Repair.summary`).

Written here rather than taken from trimesh or pymeshlab: trimesh's ``process``/``merge_vertices``
reorders and drops without keeping the maps back to the file, and neither splits non-manifold edges
into fans; every step here is vectorised NumPy/SciPy (connected components of the faces' corners), so
a 200k-vertex mesh is repaired in about a second.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError
from ncflow.geometry.closest import closest_points_on_surface
from ncflow.geometry.topology import vertex_components

AREA_TOL = 1e-12
"""Faces with area at most this × (bounding-box diagonal)² count as zero-area."""

MAX_WELD_TOLERANCE = 0.01
"""The largest ``weld_tolerance`` (a fraction of the bounding-box diagonal) accepted."""

_WELD_NEIGHBOURS = 8
"""A tolerance weld links each vertex to at most this many nearest ones within the tolerance (bounded
memory on a hostile file with thousands of vertices at one place; chains still join whole clusters)."""


@dataclasses.dataclass(frozen=True)
class Repair:
    """A mesh made fit for matching, with the maps back to the mesh it was made from.

    Attributes:
        vertices: (W, 3) float64 repaired vertices, each at the place of an input vertex.
        faces: (G, 3) int64 repaired triangles: every edge in at most two, every vertex one fan.
        vertex_origin: (W,) the input vertex each repaired vertex is (the first of a welded group;
            the same vertex for each copy of a split one).
        face_origin: (G,) the input face each repaired face is.
        flipped: (G,) bool, the faces wound against their input face (step 4).
        counts: what was done, by kind (every kind present, 0 when nothing).
    """

    vertices: Float[np.ndarray, "W 3"]
    faces: Int[np.ndarray, "G 3"]
    vertex_origin: Int[np.ndarray, " W"]
    face_origin: Int[np.ndarray, " G"]
    flipped: np.ndarray
    counts: dict

    @property
    def changed(self) -> bool:
        """Whether anything was repaired (vertices or faces other than the input's)."""
        return any(self.counts.values())

    @property
    def input_faces(self) -> Int[np.ndarray, "G 3"]:
        """(G, 3) the repaired faces in the input's vertex numbering (welded corners become the first
        vertex of their group)."""
        return self.vertex_origin[self.faces]

    def summary(self) -> str | None:
        """One line saying what was repaired and how much (None when nothing was)."""
        c = self.counts
        parts = [
            (c["welded"], f"welded {c['welded']} vertices lying where another does (a triangle soup or seams)"),
            (c["degenerate"], f"dropped {c['degenerate']} zero-area faces"),
            (c["duplicate"], f"dropped {c['duplicate']} duplicate faces"),
            (
                c["small_components"],
                f"left out {c['small_components']} small components ({c['small_component_faces']} faces)",
            ),
            (c["reoriented"], f"turned {c['reoriented']} faces wound against their neighbours"),
            (
                c["nonmanifold_edges"] + c["nonmanifold_vertices"],
                "split the mesh where "
                + " and ".join(
                    text
                    for n, text in (
                        (c["nonmanifold_edges"], f"{c['nonmanifold_edges']} edges are shared by more than two faces"),
                        (c["nonmanifold_vertices"], f"{c['nonmanifold_vertices']} vertices join separate fans"),
                    )
                    if n
                )
                + f" ({c['split_vertices']} vertices added)",
            ),
            (c["unreferenced"], f"left out {c['unreferenced']} vertices in no face"),
        ]
        said = [text for n, text in parts if n]
        return "; ".join(said) if said else None

    def points_from_input(
        self,
        input_vertices: Float[np.ndarray, "V 3"],
        input_faces: Int[np.ndarray, "F 3"],
        face: Int[np.ndarray, " n"],
        bary: Float[np.ndarray, "n 3"],
    ) -> tuple[Int[np.ndarray, " n"], Float[np.ndarray, "n 3"]]:
        """Surface points of the input mesh (input face, barycentric coordinates) as points of the
        repaired one: the same face where it was kept (its coordinates reversed where it was turned),
        else the closest point of the repaired surface (a point of a dropped zero-area or duplicate
        face lies on it already).
        """
        face = np.asarray(face, np.int64)
        bary = np.asarray(bary, np.float64)
        inverse = np.full(np.asarray(input_faces).shape[0], -1, np.int64)
        inverse[self.face_origin] = np.arange(self.face_origin.size)
        out_face = inverse[face]
        kept = out_face >= 0
        out_bary = np.where(self.flipped[np.maximum(out_face, 0)][:, None] & kept[:, None], bary[:, ::-1], bary)
        if not np.all(kept):
            corners = np.asarray(input_vertices, np.float64)[np.asarray(input_faces)[face[~kept]]]
            points = np.einsum("nk,nkd->nd", bary[~kept], corners)
            _, out_face[~kept], out_bary[~kept] = closest_points_on_surface(points, self.vertices, self.faces)
        return out_face, out_bary


def _bbox_diagonal(vertices: np.ndarray) -> float:
    return float(np.linalg.norm(vertices.max(0) - vertices.min(0))) if vertices.size else 0.0


def weld_groups(vertices: Float[np.ndarray, "V 3"], tolerance: float = 0.0) -> Int[np.ndarray, " V"]:
    """(V,) for each vertex the first vertex of its group: vertices at one place (within ``tolerance``,
    absolute, chained through neighbours) form a group.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    v = np.asarray(vertices, np.float64)
    n = v.shape[0]
    _, first, inverse = np.unique(v, axis=0, return_index=True, return_inverse=True)
    rep = first[inverse.reshape(-1)]
    if tolerance <= 0 or n < 2:
        return rep
    distinct = np.unique(rep)
    k = min(_WELD_NEIGHBOURS, distinct.size)
    dist, idx = cKDTree(v[distinct]).query(v[distinct], k=k, distance_upper_bound=tolerance)
    dist, idx = dist.reshape(distinct.size, k), idx.reshape(distinct.size, k)
    ok = np.isfinite(dist)
    rows = np.broadcast_to(np.arange(distinct.size)[:, None], idx.shape)[ok]
    graph = coo_matrix((np.ones(rows.size), (rows, idx[ok])), shape=(distinct.size, distinct.size))
    _, label = connected_components(graph, directed=False)
    first_of_label = np.full(label.max() + 1, n, np.int64)
    np.minimum.at(first_of_label, label, distinct)
    group_rep = np.empty(n, np.int64)
    group_rep[distinct] = first_of_label[label]
    return group_rep[rep]


def _edge_table(faces: np.ndarray, n_vertices: int):
    """Undirected edges of ``faces``: (for each of the 3F half-edges its edge id, whether it runs from
    the smaller vertex to the larger, the number of faces on each edge). Half-edge 3·f + k runs from
    corner k of face f to corner k + 1.
    """
    a = faces.reshape(-1)
    b = faces[:, [1, 2, 0]].reshape(-1)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    _, edge, count = np.unique(lo * np.int64(n_vertices) + hi, return_inverse=True, return_counts=True)
    return edge.reshape(-1), a < b, count


def _manifold_pairs(edge: np.ndarray, count: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pairs of half-edges on the edges of exactly two faces (one of each face)."""
    half = np.flatnonzero(count[edge] == 2)
    half = half[np.argsort(edge[half], kind="stable")]
    return half[0::2], half[1::2]


def _orient_components(faces: np.ndarray, areas: np.ndarray, pairs, forward: np.ndarray) -> np.ndarray:
    """(F,) bool: the faces to turn so that every orientable component is wound one way, the way most of
    its area is. Connected components of the double cover (face, side): two faces across an edge of two
    faces (``pairs`` of half-edges) are joined side to side when they run the edge the opposite way
    (consistent), across otherwise.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    nf = faces.shape[0]
    h1, h2 = pairs
    f1, f2 = h1 // 3, h2 // 3
    cross = forward[h1] == forward[h2]  # both run the edge the same way: wound against each other
    rows = np.concatenate([f1, f1 + nf])
    cols = np.concatenate([np.where(cross, f2 + nf, f2), np.where(cross, f2, f2 + nf)])
    graph = coo_matrix((np.ones(rows.size), (rows, cols)), shape=(2 * nf, 2 * nf))
    _, label = connected_components(graph, directed=False)
    side0, side1 = label[:nf], label[nf:]
    orientable = side0 != side1
    turned = orientable & (side1 < side0)  # one representative side per component
    _, comp = np.unique(np.minimum(side0, side1), return_inverse=True)
    comp = comp.reshape(-1)
    area_turned = np.bincount(comp, weights=areas * turned)
    area_all = np.bincount(comp, weights=areas)
    flip_turned = area_turned <= 0.5 * area_all  # keep the side most of the area is on
    return orientable & np.where(flip_turned[comp], turned, ~turned)


def _nonmanifold_pairs(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """On each edge of more than two faces, the pairs of faces that bound one piece of the solid, as
    pairs of half-edges: the faces are ordered by angle about the edge, and a face is joined to the next
    one when the wedge between them lies behind both (each face's normal points away from it). The body
    a fin stands on stays one surface; two closed surfaces touching along an edge each keep theirs.
    A face left out of every pair (a fin, a flap) is cut off along the edge.
    """
    edge, forward, count = _edge_table(faces, vertices.shape[0])
    half = np.flatnonzero(count[edge] > 2)
    corner = faces.reshape(-1)
    start, end = corner[half], corner[3 * (half // 3) + (half % 3 + 1) % 3]
    third = corner[3 * (half // 3) + (half % 3 + 2) % 3]
    lo, hi = np.where(forward[half], start, end), np.where(forward[half], end, start)
    d = vertices[hi] - vertices[lo]
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    w = vertices[third] - vertices[lo]
    w -= np.einsum("ij,ij->i", w, d)[:, None] * d
    order = np.lexsort((half, edge[half]))
    first = np.searchsorted(edge[half][order], edge[half][order], side="left")
    u = w[order][first]  # each edge's reference direction: its first face's
    u = u[np.argsort(order)]
    theta = np.arctan2(np.einsum("ij,ij->i", np.cross(d, u), w), np.einsum("ij,ij->i", u, w))
    order = np.lexsort((theta, edge[half]))
    e = edge[half][order]
    group_start = np.searchsorted(e, e, side="left")
    group_end = np.searchsorted(e, e, side="right")
    pos = np.arange(order.size)
    succ = np.where(pos + 1 < group_end, pos + 1, group_start)
    s = forward[half][order]
    join = ~s & s[succ]  # the wedge from a face running hi->lo to the next running lo->hi: behind both
    return half[order][join], half[order][succ][join]


_TURNED_HALF_EDGE = np.array([1, 0, 2])
"""Where half-edge k of a face lies once the face is turned ((a, b, c) → (c, b, a))."""


def _turn(faces: np.ndarray, turn: np.ndarray, pairs) -> tuple[np.ndarray, tuple]:
    """The faces with ``turn`` ones reversed, and the half-edge ``pairs`` renumbered to match."""

    def moved(h):
        f, k = h // 3, h % 3
        return np.where(turn[f], 3 * f + _TURNED_HALF_EDGE[k], h)

    return np.where(turn[:, None], faces[:, ::-1], faces), (moved(pairs[0]), moved(pairs[1]))


def _split_fans(faces: np.ndarray, n_vertices: int, pairs=None) -> tuple[np.ndarray, np.ndarray, int]:
    """Split every vertex into one copy per fan: connected components of the faces' corners, two corners
    of one vertex joined when their faces share an edge of exactly two faces at that vertex (``pairs``
    of half-edges on those edges; computed when not given). Returns (faces, for each vertex its
    original vertex, the number of vertices that had several fans); a vertex of one fan keeps its
    number, further copies are appended.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    nc = faces.size
    if pairs is None:
        edge, _, count = _edge_table(faces, n_vertices)
        pairs = _manifold_pairs(edge, count)
    h1, h2 = pairs
    nxt = lambda h: 3 * (h // 3) + (h % 3 + 1) % 3  # noqa: E731 -- the corner a half-edge runs to
    corner = faces.reshape(-1)
    same_start = corner[h1] == corner[h2]
    rows = np.concatenate([h1, nxt(h1)])
    cols = np.concatenate([np.where(same_start, h2, nxt(h2)), np.where(same_start, nxt(h2), h2)])
    graph = coo_matrix((np.ones(rows.size), (rows, cols)), shape=(nc, nc))
    _, label = connected_components(graph, directed=False)
    vertex_of_label = np.zeros(label.max() + 1, np.int64)
    vertex_of_label[label] = corner
    fans = np.bincount(vertex_of_label, minlength=n_vertices)
    # the fan holding a vertex's first corner keeps the vertex's number
    first_corner = np.full(n_vertices, nc, np.int64)
    np.minimum.at(first_corner, corner, np.arange(nc))
    keeps = np.zeros(label.max() + 1, bool)
    keeps[label[first_corner[first_corner < nc]]] = True
    extra = np.flatnonzero(~keeps)
    new_id = vertex_of_label.copy()
    new_id[extra] = n_vertices + np.arange(extra.size)
    origin = np.concatenate([np.arange(n_vertices), vertex_of_label[extra]])
    return new_id[label].reshape(-1, 3), origin, int(np.count_nonzero(fans > 1))


def _detach_crowded(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Faces beyond the first two on an edge of more than two faces get three corners of their own.
    Returns (faces, for each vertex its original vertex, the number of faces detached).
    """
    edge, _, count = _edge_table(faces, n_vertices)
    half = np.flatnonzero(count[edge] > 2)
    if half.size == 0:
        return faces, np.arange(n_vertices), 0
    order = half[np.lexsort((half // 3, edge[half]))]
    start = np.searchsorted(edge[order], edge[order], side="left")
    rank = np.arange(order.size) - start
    detach = np.unique(order[rank >= 2] // 3)
    out = faces.copy()
    out[detach] = n_vertices + np.arange(3 * detach.size).reshape(-1, 3)
    origin = np.concatenate([np.arange(n_vertices), faces[detach].reshape(-1)])
    return out, origin, int(detach.size)


def _component_labels(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """(F,) the connected component of each face (faces joined through shared vertices), numbered 0, 1, …"""
    return np.unique(vertex_components(faces, n_vertices)[faces[:, 0]], return_inverse=True)[1].reshape(-1)


def _face_keys(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """One key per face that is the same for the same three corners in any order (a number when the
    vertex count allows, else the sorted rows).
    """
    s = np.sort(faces, axis=1)
    if n_vertices < 2_000_000:  # n³ < 2⁶³
        n = np.int64(n_vertices)
        return (s[:, 0] * n + s[:, 1]) * n + s[:, 2]
    return s


def _face_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    p = vertices[faces]
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)


COUNTS = (
    "welded",
    "degenerate",
    "duplicate",
    "small_components",
    "small_component_faces",
    "reoriented",
    "nonmanifold_edges",
    "nonmanifold_vertices",
    "split_vertices",
    "detached_faces",
    "unreferenced",
)
"""What :attr:`Repair.counts` counts, in the order :meth:`Repair.summary` says it."""


def _kept_faces(v, wf, areas, diag: float, counts: dict) -> np.ndarray:
    """The faces that stay (steps 2–3): neither degenerate nor a duplicate of an earlier one."""
    nv = v.shape[0]
    repeated = (wf[:, 0] == wf[:, 1]) | (wf[:, 1] == wf[:, 2]) | (wf[:, 0] == wf[:, 2])
    keep = ~(repeated | (areas <= AREA_TOL * diag**2))
    counts["degenerate"] = int(np.count_nonzero(~keep))
    kept = np.flatnonzero(keep)
    _, first = np.unique(_face_keys(wf[kept], nv), axis=0, return_index=True)
    counts["duplicate"] = int(kept.size - first.size)
    return kept[np.sort(first)]


def _large_components(work: np.ndarray, n_vertices: int, areas: np.ndarray, min_component: float, counts: dict):
    """(F,) bool: the faces of the split mesh (step 6) in components of at least ``min_component`` of
    the area, and always those of the largest component (a mesh of many pieces, each under the share, is
    never emptied).
    """
    if min_component <= 0 or work.shape[0] == 0:
        return np.ones(work.shape[0], bool)
    comp = _component_labels(work, n_vertices)
    share = np.bincount(comp, weights=areas) / areas.sum()
    share[np.argmax(share)] = 1.0
    small = share[comp] < min_component
    counts["small_components"] = int(np.count_nonzero(share < min_component))
    counts["small_component_faces"] = int(np.count_nonzero(small))
    return ~small


def _wound_and_split(v, work, areas, counts: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Steps 4–5 on the kept faces: (faces wound one way per component and split where non-manifold,
    for each vertex its input vertex, which faces were turned).
    """
    nv = v.shape[0]
    edge, forward, edge_count = _edge_table(work, nv)
    pairs = _manifold_pairs(edge, edge_count)
    turn = _orient_components(work, areas, pairs, forward)
    counts["reoriented"] = int(np.count_nonzero(turn))
    work, pairs = _turn(work, turn, pairs)
    counts["nonmanifold_edges"] = int(np.count_nonzero(edge_count > 2))
    if counts["nonmanifold_edges"]:
        more = _nonmanifold_pairs(v, work)
        pairs = (np.concatenate([pairs[0], more[0]]), np.concatenate([pairs[1], more[1]]))
    work, origin, counts["nonmanifold_vertices"] = _split_fans(work, nv, pairs)
    if counts["nonmanifold_edges"]:  # splitting may leave an edge of more than two faces in a tangle
        work, origin2, counts["detached_faces"] = _detach_crowded(work, origin.size)
        origin = origin[origin2]
        if counts["detached_faces"]:
            work, origin3, _ = _split_fans(work, origin.size)
            origin = origin[origin3]
    counts["split_vertices"] = int(origin.size - nv)
    return work, origin, turn


def repair_mesh(
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    *,
    weld_tolerance: float = 0.0,
    min_component: float = 0.0,
    name: str | None = None,
) -> Repair:
    """The intake step (module docstring): a mesh every later step can take, with maps back to the input.

    Args:
        vertices: (V, 3) finite coordinates.
        faces: (F, 3) vertex indices in range.
        weld_tolerance: weld vertices closer than this × the bounding-box diagonal (0: exactly
            coincident vertices only; at most :data:`MAX_WELD_TOLERANCE`).
        min_component: leave out connected components (after the split) with less than this share of the
            area (0: keep all).
        name: the file, for the error message.

    Raises:
        InputError: nothing of the mesh is left with area (every face degenerate).
    """
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    nv = v.shape[0]
    if not 0.0 <= weld_tolerance <= MAX_WELD_TOLERANCE:
        raise InputError(f"the weld tolerance must be in [0, {MAX_WELD_TOLERANCE:g}] (got {weld_tolerance:g})", name)
    if not 0.0 <= min_component < 1.0:
        raise InputError(f"the smallest component share must be in [0, 1) (got {min_component:g})", name)
    diag = _bbox_diagonal(v)
    counts = dict.fromkeys(COUNTS, 0)
    group = weld_groups(v, weld_tolerance * diag)
    referenced = np.zeros(nv, bool)
    referenced[f.reshape(-1)] = True
    counts["welded"] = int(np.count_nonzero(referenced & (group != np.arange(nv))))
    counts["unreferenced"] = int(np.count_nonzero(~referenced))
    wf = group[f]
    areas = _face_areas(v, wf)
    kept = _kept_faces(v, wf, areas, diag, counts)
    if kept.size == 0:
        raise InputError(f"none of its {f.shape[0]} faces has an area (every face is degenerate)", name)
    work, origin, turn = _wound_and_split(v, wf[kept], areas[kept], counts)
    large = _large_components(work, origin.size, areas[kept], min_component, counts)
    work, kept, turn = work[large], kept[large], turn[large]
    used = np.zeros(origin.size, bool)
    used[work.reshape(-1)] = True
    new = np.cumsum(used) - 1
    vertex_origin = origin[used]
    return Repair(
        vertices=v[vertex_origin],
        faces=new[work],
        vertex_origin=vertex_origin,
        face_origin=kept,
        flipped=turn,
        counts=counts,
    )
