"""A skeleton for a mesh that has none (``ncflow skeleton suggest``): a tree of joints inside the mesh,
bones along its limbs, from the Reeb graph of its average geodesic distance.

1. **Average geodesic distance** (AGD): the mean of the heat-method geodesic distances
   (:class:`potpourri3d.MeshHeatMethodDistanceSolver`) from :data:`N_SOURCES` farthest-point samples of the
   surface. It is intrinsic (the same in any pose of the same body), smallest on the body's core and
   largest at the tips of its limbs, and its level sets are rings around limbs and torso.
2. **Reeb graph**: the faces are cut into bands of equal AGD (each band about :data:`BAND_EDGES` edge
   steps of AGD wide, so a band is never thinner than the mesh), each band's connected pieces become nodes at
   their area-weighted centroids (a ring's centroid lies on the limb's axis, inside), and pieces of
   neighbouring bands that share an edge are joined; a minimum spanning tree of that graph (edge length:
   the distance between centroids) makes it a tree even where the surface has handles.
3. **Pruning**: a branch from a leaf to a node of three or more branches shorter than
   :data:`PRUNE` of the bounding-box diagonal is removed (bumps, ears, clothing folds), again until none is.
4. **Joints**: the root at the branch node of smallest AGD (the body's centre); every chain between
   branch nodes and leaves is simplified (Douglas–Peucker at :data:`BEND` of the diagonal keeps its bends)
   and cut into bones of at most :data:`MAX_BONE`; a chain ending in a leaf (a limb, a finger, a tail)
   longer than :data:`LIMB` gets at least :data:`LIMB_BONES` bones; joints closer than :data:`MIN_BONE`
   along a chain are merged.
5. **Inside**: a joint the generalised winding number puts outside a closed mesh is moved to the middle
   of the mesh's inside along the inward normal at its nearest surface point.

Written by hand: the curve-skeleton libraries (mesh contraction in skeletor, CGAL's mean-curvature
skeleton) are GPL or C++, and give dense curves, not a joint tree; learned riggers need a GPU. Limits:
joints are placed by length and bends in this one pose, not where the body articulates (a straight arm
gets its elbow at a third of its length); a mesh with no limbs (a sphere) gets a short chain.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp
from jaxtyping import Float, Int
from scipy.sparse.csgraph import connected_components, minimum_spanning_tree

from ncflow.errors import InputError
from ncflow.geometry.closest import closest_points_on_surface
from ncflow.geometry.mesh import face_areas
from ncflow.geometry.skeleton import Skeleton
from ncflow.geometry.topology import mesh_topology, vertex_components
from ncflow.geometry.winding import signed_volume, winding_numbers

N_SOURCES = 12
"""Farthest-point samples whose geodesic distances are averaged (the AGD)."""
BAND_EDGES = 3.0
"""Width of an AGD band in mean AGD steps along an edge."""
PRUNE = 0.08
"""Leaf branches shorter than this share of the bounding-box diagonal are removed."""
BEND = 0.03
"""Douglas–Peucker tolerance along a chain (share of the diagonal): bends deeper than this keep a joint."""
MAX_BONE = 0.12
"""Longest bone (share of the diagonal)."""
MIN_BONE = 0.04
"""Joints closer than this along a chain (share of the diagonal) are merged."""
LIMB = 0.15
"""A chain ending in a leaf at least this long (share of the diagonal) is a limb ..."""
LIMB_BONES = 3
"""... and gets at least this many bones (upper, lower, extremity; a finger's phalanges)."""


@dataclasses.dataclass(frozen=True)
class SuggestedSkeleton:
    """A suggested skeleton and how it was found.

    Attributes:
        skeleton: the joint tree (root first), joints named ``root``, ``j1``, ...
        agd: (V,) the average geodesic distance of every vertex.
        n_nodes: nodes of the Reeb graph before pruning.
        n_leaves: leaves of the skeleton (limb tips).
        moved_inside: joints moved inside the mesh (step 5).
    """

    skeleton: Skeleton
    agd: Float[np.ndarray, " V"]
    n_nodes: int
    n_leaves: int
    moved_inside: int


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
    sources, nearest = [first], np.linalg.norm(v - v[first], axis=1)
    for _ in range(min(n_sources, v.shape[0]) - 1):
        sources.append(int(np.argmax(nearest)))
        nearest = np.minimum(nearest, np.linalg.norm(v - v[sources[-1]], axis=1))
    return np.mean([solver.compute_distance(i) for i in sources], axis=0)


def reeb_tree(
    vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"], f: Float[np.ndarray, " V"]
) -> tuple[Float[np.ndarray, "N 3"], Float[np.ndarray, " N"], list[set[int]]]:
    """The Reeb graph of ``f`` on bands of :data:`BAND_EDGES` edge steps, as a spanning tree: node centroids
    (N, 3), node values of ``f`` (N,) and the adjacency (one set of neighbours per node).
    """
    v, fc = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    topo = mesh_topology(fc, v.shape[0])
    lo, hi = float(f.min()), float(f.max())
    step = float(np.mean(np.abs(f[topo.edges[:, 0]] - f[topo.edges[:, 1]])))
    n_bands = max(4, int((hi - lo) / max(BAND_EDGES * step, 1e-30)))
    face_f = f[fc].mean(1)
    band = np.minimum(((face_f - lo) / max(hi - lo, 1e-30) * n_bands).astype(np.int64), n_bands - 1)
    nf = fc.shape[0]
    pairs = np.concatenate([topo.edge_faces[:, [k, k + 1]] for k in range(3)])  # faces sharing an edge
    pairs = pairs[np.all(pairs >= 0, axis=1)]
    fa, fb = pairs[:, 0], pairs[:, 1]
    inside_band = band[fa] == band[fb]
    links = sp.coo_matrix((np.ones(inside_band.sum()), (fa[inside_band], fb[inside_band])), shape=(nf, nf))
    n, label = connected_components(links, directed=False)
    area = face_areas(v, fc) + 1e-30
    weight = np.bincount(label, weights=area, minlength=n)
    centroids = np.stack([np.bincount(label, weights=area * c, minlength=n) for c in v[fc].mean(1).T], 1)
    centroids /= weight[:, None]
    values = np.bincount(label, weights=area * face_f, minlength=n) / weight
    joined = np.unique(np.sort(np.stack([label[fa], label[fb]], axis=1), axis=1), axis=0)
    a, b = joined[joined[:, 0] != joined[:, 1]].T  # each pair of neighbouring pieces once
    length = np.linalg.norm(centroids[a] - centroids[b], axis=1) + 1e-12
    graph = sp.coo_matrix((length, (a, b)), shape=(n, n)).tocsr()
    tree = minimum_spanning_tree(graph.maximum(graph.T)).tocoo()
    adjacency: list[set[int]] = [set() for _ in range(n)]
    for i, j in zip(tree.row.tolist(), tree.col.tolist(), strict=True):
        adjacency[i].add(j)
        adjacency[j].add(i)
    return centroids, values, adjacency


def _arc(points: np.ndarray) -> np.ndarray:
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
        branches = [(float(_arc(centroids[c])[-1]), c) for c in branches if len(adj[c[-1]]) > 2]
        if not branches:
            return adj
        length, chain = min(branches, key=lambda lc: lc[0])
        if length >= shortest:
            return adj
        for node in chain[:-1]:
            for other in adj[node]:
                adj[other].discard(node)
            adj[node] = set()


def _douglas_peucker(points: np.ndarray, tolerance: float) -> list[int]:
    """Indices of the points that a Douglas–Peucker simplification at ``tolerance`` keeps (ends included);
    a stack of spans, not recursion, so that a chain of any length is simplified.
    """
    last = points.shape[0] - 1
    keep, spans = {0, last}, [(0, last)]
    while spans:
        i, j = spans.pop()
        if j - i < 2:
            continue
        ab = points[j] - points[i]
        ab = ab / max(np.linalg.norm(ab), 1e-30)
        dist = np.linalg.norm(np.cross(points[i + 1 : j] - points[i], ab), axis=1)
        k = i + 1 + int(np.argmax(dist))
        if dist[k - i - 1] > tolerance:
            keep.add(k)
            spans += [(i, k), (k, j)]
    return sorted(keep)


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


def _chain_joints(points: np.ndarray, to_leaf: bool, diag: float) -> list[int]:
    """Indices along a chain's points (0 = its start, already a joint) that become joints."""
    arc = _arc(points)
    keep = set(_douglas_peucker(points, BEND * diag))
    n_bones = max(1, int(np.ceil(arc[-1] / (MAX_BONE * diag))))
    if to_leaf and arc[-1] >= LIMB * diag:
        n_bones = max(n_bones, LIMB_BONES)
    keep.update(int(np.argmin(np.abs(arc - arc[-1] * k / n_bones))) for k in range(1, n_bones))
    picked = [0]
    last = points.shape[0] - 1
    for k in sorted(keep - {0}):
        if k == last or arc[k] - arc[picked[-1]] >= MIN_BONE * diag:
            if k == last and len(picked) > 1 and arc[k] - arc[picked[-1]] < MIN_BONE * diag:
                picked.pop()
            picked.append(k)
    return picked[1:]


def _move_inside(joints: np.ndarray, vertices: np.ndarray, faces: np.ndarray, diag: float) -> tuple[np.ndarray, int]:
    """Joints outside the closed mesh moved to the middle of its inside along the inward normal at their
    nearest surface point (left where the ray finds no inside: an open or very thin mesh).
    """
    tri = vertices[faces]
    outside = np.flatnonzero(np.abs(winding_numbers(joints, tri)) < 0.5)
    if outside.size == 0:
        return joints, 0
    out = joints.copy()
    _, face_index, bary = closest_points_on_surface(joints[outside], vertices, faces)
    near = np.einsum("nk,nkd->nd", bary, tri[face_index])
    normals = np.cross(tri[face_index, 1] - tri[face_index, 0], tri[face_index, 2] - tri[face_index, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
    sign = 1.0 if signed_volume(vertices, faces) >= 0 else -1.0  # outward normals: inward is −n
    steps = np.linspace(0.0, 0.3 * diag, 61)[1:]
    moved = 0
    for k, j in enumerate(outside):
        probes = near[k] - sign * normals[k] * steps[:, None]
        inside = np.abs(winding_numbers(probes, tri)) >= 0.5
        if inside.any():
            first = int(np.argmax(inside))
            last = first + (int(np.argmin(inside[first:])) if not inside[first:].all() else inside[first:].size) - 1
            out[j] = 0.5 * (probes[first] + probes[last])
            moved += 1
    return out, moved


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


def suggest_skeleton(
    vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"], *, name: str | None = None
) -> SuggestedSkeleton:
    """A joint tree for a character mesh (module docstring); deterministic.

    Args:
        vertices: (V, 3) the mesh (repaired, :func:`ncflow.geometry.mesh.repaired_mesh`); of several
            connected pieces the largest by area carries the skeleton.
        faces: (F, 3) triangles.
        name: the skeleton's name.

    Raises:
        InputError: a mesh too small to have a shape (fewer than 20 faces).
    """
    v, fc = _largest_piece(np.asarray(vertices, np.float64), np.asarray(faces, np.int64))
    if fc.shape[0] < 20:
        raise InputError(f"the mesh has {fc.shape[0]} faces: too few to suggest a skeleton")
    diag = float(np.linalg.norm(np.ptp(v, axis=0)))
    agd = average_geodesic_distance(v, fc)
    centroids, values, adjacency = reeb_tree(v, fc, agd)
    adj = prune_branches(adjacency, centroids, PRUNE * diag)
    alive = [n for n, s in enumerate(adj) if s]
    if not alive:
        raise InputError("the mesh has no extent along which to place bones (its geodesic distances are flat)")
    branch = [n for n in alive if len(adj[n]) > 2]
    root = min(branch or alive, key=lambda n: values[n])
    joints, parents, index = [centroids[root]], [-1], {root: 0}
    for chain in _chains(adj, root):
        parent = index[chain[0]]
        to_leaf = len(adj[chain[-1]]) == 1
        for k in _chain_joints(centroids[chain], to_leaf, diag):
            node = chain[k]
            if node not in index:
                joints.append(centroids[node])
                parents.append(parent)
                index[node] = len(joints) - 1
            parent = index[node]
    positions, moved = _move_inside(np.asarray(joints), v, fc, diag)
    names = ["root"] + [f"j{k}" for k in range(1, len(joints))]
    skeleton = Skeleton.from_arrays(positions, np.asarray(parents), names, name=name)
    n_leaves = int(np.sum(np.bincount(np.asarray(parents[1:]), minlength=len(joints)) == 0))
    return SuggestedSkeleton(skeleton, agd, len(centroids), n_leaves, moved)
