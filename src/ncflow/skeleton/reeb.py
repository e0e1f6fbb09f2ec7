"""The limb tree of a mesh: the Reeb graph of its average geodesic distance, pruned, with the pieces of
one wide part merged and a root at its centre (what :mod:`ncflow.skeleton.suggest` places joints on).

0. **The surface**: the largest connected piece (decimated to :data:`MAX_VERTICES` when larger); holes
   whose rims are short (a hand open at the wrist) closed by fans (:func:`_capped`); edges longer than
   :data:`EDGE` of the diagonal split at their midpoints (:func:`_even_edges`), so that a coarse or unevenly
   triangulated mesh has as many bands along a limb as a fine one.
1. **Average geodesic distance** (AGD): the mean of the heat-method geodesic distances
   (:class:`potpourri3d.MeshHeatMethodDistanceSolver`) from :data:`N_SOURCES` geodesic farthest-point
   samples of the surface. It is intrinsic (the same in any pose of the same body), smallest on the body's
   core and largest at the tips of its limbs, and its level sets are rings around limbs and torso.
2. **Reeb graph**: the faces are cut into bands of equal AGD (each at least :data:`BAND` of the diagonal and
   :data:`BAND_EDGES` edge steps of AGD wide, so a band is never thinner than the mesh), each band's pieces
   (its faces joined through shared vertices) become nodes at their area-weighted centroids (a ring's
   centroid lies on the limb's axis, inside), and pieces of neighbouring bands that share an edge are
   joined; a minimum spanning tree of that graph (edge length: the distance between centroids) makes it a
   tree even where the surface has handles.
3. **Pruning and hubs**: a branch from a leaf to a node of three or more branches shorter than
   :data:`PRUNE` of the diagonal (:func:`extent`) is removed (bumps, ears, clothing folds), again until none
   is; branch nodes of one wide part are merged (:func:`merge_hubs`); the root is the tree's centre among
   its branch nodes (:func:`_centre`).

Written by hand: the curve-skeleton libraries (mesh contraction in skeletor, CGAL's mean-curvature
skeleton) are GPL or C++, and give dense curves, not a joint tree.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp
from jaxtyping import Float, Int
from scipy.sparse.csgraph import connected_components, minimum_spanning_tree

from ncflow.errors import InputError
from ncflow.geometry.mesh import face_areas, face_edge_lengths
from ncflow.geometry.topology import close_boundary, mesh_topology, vertex_components

N_SOURCES = 24
"""Geodesic farthest-point samples whose geodesic distances are averaged (the AGD)."""

BAND_EDGES = 3.0
"""Least width of an AGD band in mean AGD steps along an edge ..."""

BAND = 0.025
"""... and in AGD as a share of the diagonal (the AGD grows about as the distance along a limb)."""

HUB = 1.4
"""Branch nodes joined by a chain shorter than this many times the wider end's radius are merged
(:func:`merge_hubs`): a palm's chains measure 0.6–1.25 radii, a torso's 1.6–1.9 on the development set."""

PRUNE = 0.08
"""Leaf branches shorter than this share of the diagonal (:func:`extent`) are removed."""

EDGE = 0.012
"""Longest edge (share of the diagonal) of the mesh the AGD is computed on; longer edges are split."""

MAX_VERTICES = 12_000
"""A larger mesh is decimated to about this many vertices first (quadric decimation, vertices kept)."""

MAX_FACES = 60_000
"""... unless splitting them would make more faces than this."""

CAP = 1.5
"""Holes whose rims are together shorter than this many diagonals are capped first."""


def extent(vertices: Float[np.ndarray, "V 3"]) -> float:
    """The diagonal of the points' box along their principal axes: the mesh's size, the same in any
    placement (every length below is a share of it).
    """
    v = np.asarray(vertices, np.float64)
    centred = v - v.mean(0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    return float(np.linalg.norm(np.ptp(centred @ vt.T, axis=0)))


def average_geodesic_distance(
    vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"], n_sources: int = N_SOURCES
) -> Float[np.ndarray, " V"]:
    """(V,) the mean heat-method geodesic distance from ``n_sources`` farthest-point samples (the first: the
    vertex farthest from the centroid, so the samples do not depend on the mesh's placement).
    """
    import potpourri3d as pp3d

    v = np.asarray(vertices, np.float64)
    solver = pp3d.MeshHeatMethodDistanceSolver(v, np.asarray(faces, np.int64))
    first = int(np.argmax(np.linalg.norm(v - v.mean(0), axis=1)))
    fields = [solver.compute_distance(first)]
    nearest = fields[0].copy()
    for _ in range(min(n_sources, v.shape[0]) - 1):
        fields.append(solver.compute_distance(int(np.argmax(nearest))))
        nearest = np.minimum(nearest, fields[-1])
    return np.mean(fields, axis=0)


def reeb_tree(
    vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"], f: Float[np.ndarray, " V"]
) -> tuple[Float[np.ndarray, "N 3"], Float[np.ndarray, " N"], Float[np.ndarray, " N"], list[set[int]]]:
    """The Reeb graph of ``f`` on bands (module docstring, step 2), as a spanning tree: node centroids (N, 3),
    node values of ``f`` (N,), node radii (N,: the pieces' area-weighted mean distance from their centroid,
    about a limb's radius for a ring) and the adjacency (one set of neighbours per node).
    """
    v, fc = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    topo = mesh_topology(fc, v.shape[0])
    lo, hi = float(f.min()), float(f.max())
    step = float(np.mean(np.abs(f[topo.edges[:, 0]] - f[topo.edges[:, 1]])))
    diag = extent(v)
    n_bands = max(4, int((hi - lo) / max(BAND_EDGES * step, BAND * diag, 1e-30)))
    face_f = f[fc].mean(1)
    band = np.minimum(((face_f - lo) / max(hi - lo, 1e-30) * n_bands).astype(np.int64), n_bands - 1)
    nf = fc.shape[0]
    pairs = np.concatenate([topo.edge_faces[:, [k, k + 1]] for k in range(3)])  # faces sharing an edge
    pairs = pairs[np.all(pairs >= 0, axis=1)]
    fa, fb = pairs[:, 0], pairs[:, 1]
    # a band's pieces: its faces joined through the vertices they share (a ring whose faces touch only at
    # corners, as on coarse or uneven triangulations, stays one piece)
    corner = (fc * n_bands + band[:, None]).ravel()
    keys, key_of = np.unique(corner, return_inverse=True)
    links = sp.coo_matrix(
        (np.ones(corner.size), (np.repeat(np.arange(nf), 3), nf + key_of)), shape=(nf + keys.size, nf + keys.size)
    )
    _, label = connected_components(links, directed=False)
    _, label = np.unique(label[:nf], return_inverse=True)
    n = int(label.max()) + 1
    area = face_areas(v, fc) + 1e-30
    weight = np.bincount(label, weights=area, minlength=n)
    centroids = np.stack([np.bincount(label, weights=area * c, minlength=n) for c in v[fc].mean(1).T], 1)
    centroids /= weight[:, None]
    values = np.bincount(label, weights=area * face_f, minlength=n) / weight
    spread = np.linalg.norm(v[fc].mean(1) - centroids[label], axis=1)
    radii = np.bincount(label, weights=area * spread, minlength=n) / weight
    joined = np.unique(np.sort(np.stack([label[fa], label[fb]], axis=1), axis=1), axis=0)
    a, b = joined[joined[:, 0] != joined[:, 1]].T  # each pair of neighbouring pieces once
    length = np.linalg.norm(centroids[a] - centroids[b], axis=1) + 1e-12
    graph = sp.coo_matrix((length, (a, b)), shape=(n, n)).tocsr()
    tree = minimum_spanning_tree(graph.maximum(graph.T)).tocoo()
    adjacency: list[set[int]] = [set() for _ in range(n)]
    for i, j in zip(tree.row.tolist(), tree.col.tolist(), strict=True):
        adjacency[i].add(j)
        adjacency[j].add(i)
    return centroids, values, radii, adjacency


def arc_lengths(points: np.ndarray) -> np.ndarray:
    """(n,) the length along a polyline (n, 3) from its first point to each."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])


def _leaf_branch(adjacency: list[set[int]], leaf: int) -> list[int]:
    """Nodes from ``leaf`` to the first node of three or more branches (included), or to the chain's end."""
    chain, prev, cur = [leaf], -1, leaf
    while True:
        ahead = [x for x in adjacency[cur] if x != prev]
        if not ahead or (cur != leaf and len(adjacency[cur]) != 2):
            return chain
        prev, cur = cur, ahead[0]
        chain.append(cur)


def prune_branches(adjacency: list[set[int]], centroids: np.ndarray, shortest: float) -> list[set[int]]:
    """Remove the shortest leaf branch that ends at a node of three or more branches while it is shorter
    than ``shortest`` (shortest first: of a tip split in two, the spur goes and the tip stays).
    """
    adj = [set(s) for s in adjacency]
    while True:
        branches = [_leaf_branch(adj, leaf) for leaf, s in enumerate(adj) if len(s) == 1]
        branches = [(float(arc_lengths(centroids[c])[-1]), c) for c in branches if len(adj[c[-1]]) > 2]
        if not branches:
            return adj
        length, chain = min(branches, key=lambda lc: lc[0])
        if length >= shortest:
            return adj
        for node in chain[:-1]:
            for other in adj[node]:
                adj[other].discard(node)
            adj[node] = set()


def merge_hubs(
    adjacency: list[set[int]], centroids: np.ndarray, values: np.ndarray, radii: np.ndarray, ratio: float
) -> tuple[np.ndarray, list[set[int]]]:
    """Branch nodes joined by a chain shorter than ``ratio`` times the larger radius of its two ends made one
    (shortest chain first): the pieces of one wide part of the body — a palm whose fingers leave it one
    after another, a chest whose arms and neck leave it at slightly different heights — become one joint
    from which the limbs hang, as in a drawn skeleton (and as the pose search needs to try alike limbs
    exchanged), while a torso, longer than it is wide, keeps its two ends. The merged node keeps the one of
    smaller ``values``, the larger radius, and sits at the mean of the merged nodes' centroids. Returns the
    centroids (a copy) and the adjacency.
    """
    adj = [set(n) for n in adjacency]
    pos = np.array(centroids, np.float64)
    radius = np.array(radii, np.float64)
    members = {n: [n] for n in range(len(adj))}
    while True:
        best = None
        for u in range(len(adj)):
            if len(adj[u]) < 3:
                continue
            for first in adj[u]:
                chain, prev, cur = [u, first], u, first
                while len(adj[cur]) == 2:
                    (cur, prev) = ([x for x in adj[cur] if x != prev][0], cur)
                    chain.append(cur)
                if len(adj[cur]) < 3 or cur == u:
                    continue
                length = float(arc_lengths(pos[chain])[-1])
                if length < ratio * max(radius[u], radius[cur]) and (best is None or length < best[0]):
                    best = (length, chain)
        if best is None:
            return pos, adj
        chain = best[1]
        keep, gone = sorted((chain[0], chain[-1]), key=lambda n: values[n])
        for node in chain[1:-1]:
            for other in adj[node]:
                adj[other].discard(node)
            adj[node] = set()
        adj[keep].discard(gone)
        adj[gone].discard(keep)
        for other in adj[gone]:
            adj[other].discard(gone)
            adj[other].add(keep)
            adj[keep].add(other)
        adj[gone] = set()
        members[keep] += members.pop(gone)
        radius[keep] = max(radius[keep], radius[gone])
        pos[keep] = np.mean(np.asarray(centroids)[members[keep]], axis=0)


def _chains(adjacency: list[set[int]], root: int) -> list[list[int]]:
    """The tree cut at the root and at every node of other than two branches: chains from their parent end."""
    out, stack, seen = [], [root], {root}
    while stack:
        start = stack.pop()
        for nxt in sorted(adjacency[start]):
            if nxt in seen:
                continue
            chain, prev, cur = [start, nxt], start, nxt
            seen.add(nxt)
            while len(adjacency[cur]) == 2:
                (ahead,) = [x for x in adjacency[cur] if x != prev]
                seen.add(ahead)
                chain.append(ahead)
                prev, cur = cur, ahead
            out.append(chain)
            stack.append(cur)
    return out


def _centre(adj: list[set[int]], centroids: np.ndarray, values: np.ndarray) -> int:
    """The root: the branch node from which the farthest leaf, along the tree, is nearest (the tree's centre
    among its branch nodes: a biped's pelvis, where a drawn skeleton has its root, rather than its chest,
    whose arms and head weigh on the AGD); ties to the smaller AGD. A tree without branches: its node of
    smallest AGD.
    """
    from scipy.sparse.csgraph import dijkstra

    alive = [n for n, s in enumerate(adj) if s]
    branch = [n for n in alive if len(adj[n]) > 2]
    if len(branch) < 2:
        return min(branch or alive, key=lambda n: values[n])
    rows = [i for i, s in enumerate(adj) for _ in s]
    cols = [j for s in adj for j in s]
    length = np.linalg.norm(centroids[rows] - centroids[cols], axis=1) + 1e-12
    graph = sp.coo_matrix((length, (rows, cols)), shape=(len(adj), len(adj))).tocsr()
    leaves = [n for n in alive if len(adj[n]) == 1]
    farthest = dijkstra(graph, indices=branch)[:, leaves].max(axis=1)
    return min(zip(farthest.tolist(), values[branch].tolist(), branch, strict=True))[2]


@dataclasses.dataclass(frozen=True)
class LimbTree:
    """A mesh's pruned Reeb tree: node centroids, node AGD (divided by the surface's mean AGD, so that two
    poses of one body in any units compare), node radii (a ring's mean distance from its centroid: about
    the limb's radius there; a merged hub keeps its first node's), neighbours, root, the chains from the
    root, and the mesh.
    """

    centroids: np.ndarray
    level: np.ndarray
    radii: np.ndarray
    adj: list[set[int]]
    root: int
    chains: list[list[int]]
    agd: np.ndarray
    diag: float
    shape: tuple[np.ndarray, np.ndarray]
    n_given: int

    def limbs(self) -> list[list[int]]:
        """The chains that end at a leaf (limbs, fingers, tails, the head)."""
        return [c for c in self.chains if len(self.adj[c[-1]]) == 1]


def limb_tree(vertices: np.ndarray, faces: np.ndarray) -> LimbTree:
    """Steps 1–3 and the root (module docstring) on the largest piece, capped and with edges split."""
    v, fc = _largest_piece(np.asarray(vertices, np.float64), np.asarray(faces, np.int64))
    if fc.shape[0] < 20:
        raise InputError(f"the mesh has {fc.shape[0]} faces: too few to suggest a skeleton")
    diag = extent(v)
    given = v
    if v.shape[0] > MAX_VERTICES:  # the skeleton needs the shape, not its detail
        from ncflow.geometry.decimate import decimate

        small = decimate(v, fc, MAX_VERTICES)
        v, fc = small.vertices, small.faces
    n_given = v.shape[0]
    v, fc = _capped(v, fc, diag)
    shape = (v, fc)
    v, fc = _even_edges(v, fc, EDGE * diag)
    agd = average_geodesic_distance(v, fc)
    centroids, values, radii, adjacency = reeb_tree(v, fc, agd)
    adj = prune_branches(adjacency, centroids, PRUNE * diag)
    centroids, adj = merge_hubs(adj, centroids, values, radii, HUB)
    alive = [n for n, s in enumerate(adj) if s]
    if not alive:
        raise InputError("the mesh has no extent along which to place bones (its geodesic distances are flat)")
    root = _centre(adj, centroids, values)
    area = np.bincount(fc.ravel(), weights=np.repeat(face_areas(v, fc), 3), minlength=v.shape[0])
    level = values / max(float(np.sum(area * agd) / max(area.sum(), 1e-30)), 1e-30)
    if given.shape[0] != n_given:
        from scipy.spatial import cKDTree

        agd = agd[cKDTree(v[:n_given]).query(given)[1]]
        n_given = given.shape[0]
    return LimbTree(centroids, level, radii, adj, root, _chains(adj, root), agd, diag, shape, n_given)


def _capped(v: np.ndarray, fc: np.ndarray, diag: float) -> tuple[np.ndarray, np.ndarray]:
    """The mesh with its holes closed by fans (:func:`~ncflow.geometry.topology.close_boundary`) when their
    rims are together shorter than :data:`CAP` diagonals: a hand open at the wrist or a limb cut at the
    scanner's edge ends in one tip instead of one per corner of its rim. A longer rim (a single view's
    silhouette) is left open.
    """
    topo = mesh_topology(fc, v.shape[0])
    if not topo.has_boundary:
        return v, fc
    rim = topo.edges[topo.boundary_edges]
    if float(np.linalg.norm(v[rim[:, 0]] - v[rim[:, 1]], axis=1).sum()) > CAP * diag:
        return v, fc
    return close_boundary(v, fc)


def _even_edges(v: np.ndarray, fc: np.ndarray, longest: float) -> tuple[np.ndarray, np.ndarray]:
    """The mesh with every edge longer than ``longest`` split at shared midpoints (trimesh's
    ``subdivide_to_size``: the shape is unchanged, no cracks, the given vertices keep their indices and come
    first), so that a coarse or unevenly triangulated mesh has as many AGD bands along a limb as a fine one.
    The length is raised where splitting to it would make far more than :data:`MAX_FACES` faces.
    """
    import trimesh.remesh

    edges = face_edge_lengths(v, fc)
    area = float(face_areas(v, fc).sum())
    longest = max(longest, float(np.sqrt(area / (0.433 * MAX_FACES))))
    if edges.max() <= longest:
        return v, fc
    try:
        out_v, out_f = trimesh.remesh.subdivide_to_size(v, fc, longest, max_iter=16)
    except ValueError:  # slivers that halving cannot bring below the length
        return v, fc
    return np.asarray(out_v, np.float64), np.asarray(out_f, np.int64)


def _largest_piece(v: np.ndarray, fc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The vertices and faces of the connected piece of largest area, reindexed."""
    label = vertex_components(fc, v.shape[0])
    area = face_areas(v, fc)
    piece = label[fc[:, 0]]
    if fc.shape[0] == 0 or np.all(piece == piece[0]):
        return v, fc
    keep = fc[piece == int(np.argmax(np.bincount(piece, weights=area)))]
    used, inverse = np.unique(keep, return_inverse=True)
    return v[used], inverse.reshape(-1, 3)
