"""Point clouds as arrays: the :class:`PointCloud` type, outliers, and normals oriented outward.

A scan is often a bare point cloud: points, perhaps with normals, no faces. ncflow matches one by
first making a surface of it (:mod:`ncflow.geometry.reconstruct`), which needs every point's normal
pointing out of the body:

* :func:`cloud_outliers` — "flying pixels": points whose mean distance to their k nearest neighbours
  is far beyond the cloud's typical spacing (a robust z-score on the log of that distance, the
  statistical outlier removal of PCL and Open3D);
* :func:`estimate_normals` — the normal of the plane fitted to each point's k nearest neighbours
  (smallest principal direction of their covariance; Hoppe et al. 1992, "Surface reconstruction
  from unorganized points", §3.2);
* :func:`orient_normals` — consistent signs by propagation along a minimum spanning tree of the
  k-nearest-neighbour graph weighted by 1 − |n_i · n_j| (Hoppe et al. 1992, §3.3) plus |n · e| at both
  ends of the edge e (an edge across a thin part, a finger's two sides, runs along the normals: the
  tree avoids it), each connected part then turned outward: the sign that makes Σ n_i · (p_i − c)
  positive over the part's points (c its centroid), which holds for any closed or partly seen body
  bulging outward;
* :func:`exterior_signs` — where the cloud is closed (a whole body sampled without holes), the outside
  is known: the cells of a grid not reached by the dilated points and connected to the grid's border;
  a normal points out when the smoothed distance to that outside falls along it. This overrides the
  propagation point by point when it decides for nearly every point (a sealed cloud); a cloud with a
  hole (a scan's single view, MANO's open wrist) leaks, and the propagation stands.

Written with NumPy and SciPy (cKDTree, minimum_spanning_tree, breadth_first_order): no library in
the stack estimates and orients normals (Open3D does, but it is a 100 MB dependency for three
functions).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from jaxtyping import Bool, Float

from ncflow.errors import InputError
from ncflow.geometry.mesh import check_extent

NEIGHBOURS = 12
"""Neighbours of a point for its normal, its orientation and its outlier test."""

MIN_POINTS = 100
"""Fewest distinct points a cloud may have to be matched (fewer cannot show a body's shape)."""

OUTLIER_Z = 4.0
"""A point whose log mean neighbour distance is this many robust deviations above the median is an outlier..."""

OUTLIER_FACTOR = 2.5
"""... when that distance is also this many times the median point's."""


@dataclasses.dataclass(frozen=True)
class PointCloud:
    """A point cloud (a scan without faces).

    Attributes:
        points: (N, 3) float64 coordinates, in the file's order.
        normals: (N, 3) float64 unit normals as the file gave them, or None (estimated when matched).
        name: where it came from (a file path) or a label; used in error messages.
    """

    points: Float[np.ndarray, "N 3"]
    normals: Float[np.ndarray, "N 3"] | None = None
    name: str | None = None

    @property
    def n_points(self) -> int:
        return int(self.points.shape[0])

    @property
    def n_vertices(self) -> int:
        """The number of points (a cloud's "vertices": one row of the target → source map each)."""
        return self.n_points

    @property
    def vertices(self) -> Float[np.ndarray, "N 3"]:
        """The points, under a mesh's name (code that reads a target's vertices takes a cloud too)."""
        return self.points

    @property
    def faces(self) -> np.ndarray:
        """(0, 3) no faces."""
        return np.zeros((0, 3), np.int64)


def validate_cloud(points: np.ndarray, normals: np.ndarray | None = None, name: str | None = None) -> None:
    """Raise one :class:`InputError` line unless ``points`` is an (N, 3) finite cloud of at least
    :data:`MIN_POINTS` distinct points spanning three dimensions, and ``normals``, when given, (N, 3) and finite.
    """
    p = np.asarray(points)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"points must have 3 coordinates, got an array of shape {p.shape}", name)
    if not np.all(np.isfinite(p)):
        raise InputError(f"{int(np.sum(~np.all(np.isfinite(p), axis=1)))} points have non-finite coordinates", name)
    distinct = np.unique(p, axis=0).shape[0] if p.shape[0] else 0
    if distinct < MIN_POINTS:
        raise InputError(
            f"only {distinct} distinct points: a point cloud needs at least {MIN_POINTS} to show a shape", name
        )
    diag = check_extent(p, name, "point cloud")
    centred = p - p.mean(axis=0)
    s = np.linalg.svd(centred / diag, compute_uv=False)
    if s[-1] < 1e-6 * s[0] * np.sqrt(p.shape[0]):
        raise InputError("the points lie in a plane or on a line: not the scan of a body", name)
    if normals is not None:
        n = np.asarray(normals)
        if n.shape != p.shape:
            raise InputError(f"normals of shape {n.shape} for {p.shape[0]} points", name)
        if not np.all(np.isfinite(n)):
            raise InputError("non-finite normals", name)


def _neighbours(points: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """(distances, indices), each (N, k): every point's k nearest other points."""
    from scipy.spatial import cKDTree

    k = min(k, points.shape[0] - 1)
    d, i = cKDTree(points).query(points, k=k + 1)
    return d[:, 1:], i[:, 1:]


def point_spacing(points: Float[np.ndarray, "N 3"]) -> float:
    """The cloud's typical spacing: the median distance from a point to its third nearest neighbour (about
    √(area per point) on a surface sampled at random; the nearest one is half that), repeated points counted once.
    """
    d, _ = _neighbours(np.unique(np.asarray(points, np.float64), axis=0), 3)
    return float(np.median(d[:, -1]))


def cloud_outliers(
    points: Float[np.ndarray, "N 3"], k: int = NEIGHBOURS, z: float = OUTLIER_Z
) -> Bool[np.ndarray, " N"]:
    """(N,) True for the outliers: log mean distance to the k nearest neighbours more than ``z`` robust
    deviations (1.4826 × the median absolute deviation) above the median, and that distance more than
    :data:`OUTLIER_FACTOR` × the median's (a regular sampling has a tiny deviation: its cap or seam is no
    outlier; a scan's border, with neighbours on one side, is about 1.4×). Repeated points count once.
    """
    distinct, back = np.unique(np.asarray(points, np.float64), axis=0, return_inverse=True)
    d, _ = _neighbours(distinct, k)
    m = np.log(np.maximum(d.mean(axis=1), 1e-300))
    med = np.median(m)
    mad = 1.4826 * np.median(np.abs(m - med))
    return ((m - med) > max(z * mad, np.log(OUTLIER_FACTOR)))[back.ravel()]


def estimate_normals(points: Float[np.ndarray, "N 3"], k: int = NEIGHBOURS) -> Float[np.ndarray, "N 3"]:
    """(N, 3) unit normals, unoriented: the smallest principal direction of each point's k nearest
    neighbours and itself.
    """
    p = np.asarray(points, np.float64)
    _, idx = _neighbours(p, k)
    nb = np.concatenate([p[:, None, :], p[idx]], axis=1)  # (N, k + 1, 3)
    nb = nb - nb.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", nb, nb)
    _, vecs = np.linalg.eigh(cov)  # ascending eigenvalues
    return vecs[:, :, 0]


def orient_normals(
    points: Float[np.ndarray, "N 3"], normals: Float[np.ndarray, "N 3"], k: int = NEIGHBOURS, propagate: bool = True
) -> Float[np.ndarray, "N 3"]:
    """``normals`` with signs made consistent along the k-nearest-neighbour graph's minimum spanning tree
    (weights 1 − |n_i · n_j|: the tree crosses where neighbouring planes agree; not with ``propagate``
    False, for normals a scanner gave), each connected part turned outward (see the module docstring).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree

    p = np.asarray(points, np.float64)
    n = np.asarray(normals, np.float64).copy()
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    _, idx = _neighbours(p, k)
    rows = np.repeat(np.arange(p.shape[0]), idx.shape[1])
    cols = idx.ravel()
    e = p[cols] - p[rows]
    e /= np.maximum(np.linalg.norm(e, axis=1, keepdims=True), 1e-300)
    across = np.abs(np.einsum("ij,ij->i", n[rows], e)) + np.abs(np.einsum("ij,ij->i", n[cols], e))
    w = 1.0 - np.abs(np.einsum("ij,ij->i", n[rows], n[cols])) + across + 1e-9  # > 0: a zero weight is no edge
    graph = coo_matrix((w, (rows, cols)), shape=(p.shape[0],) * 2).tocsr()
    graph = graph.maximum(graph.T)
    tree = minimum_spanning_tree(graph)
    tree = tree + tree.T
    n_parts, labels = connected_components(tree, directed=False)
    for part in range(n_parts):
        members = np.flatnonzero(labels == part)
        order, parent = breadth_first_order(tree, members[0], directed=False, return_predecessors=True)
        for v in order[1:] if propagate else ():  # parents come first in breadth-first order
            if n[v] @ n[parent[v]] < 0:
                n[v] = -n[v]
        centre = p[members].mean(axis=0)
        if np.einsum("ij,ij->", n[members], p[members] - centre) < 0:
            n[members] = -n[members]
    return n


def occupancy_grid(points: Float[np.ndarray, "N 3"], h: float, pad: int) -> tuple[np.ndarray, np.ndarray]:
    """(origin (3,), occupied (I, J, K) bool): a grid of cell ``h`` over the points' box grown by ``pad``
    cells on every side, the corner nearest to each point marked (corner (i, j, k) at origin + (i, j, k) h).
    """
    lo, hi = points.min(axis=0), points.max(axis=0)
    origin = lo - pad * h
    shape = np.ceil((hi - lo) / h).astype(int) + 2 * pad + 1
    occupied = np.zeros(tuple(int(v) for v in shape), bool)
    occupied[tuple(np.clip(np.rint((points - origin) / h).astype(int), 0, shape - 1).T)] = True
    return origin, occupied


SEAL_CELLS = 200
"""Most grid cells along the longest side of :func:`exterior_signs`' grid."""

SEALED = 0.9
"""Share of points :func:`exterior_signs` must decide for its signs to be used."""


SEAL_LEVELS = ((0.7, 2), (1.0, 2), (1.0, 3))
"""(cell size in spacings, dilation in cells) of :func:`exterior_signs`' grids, finest first."""


def exterior_signs(points: Float[np.ndarray, "N 3"], normals: Float[np.ndarray, "N 3"], spacing: float) -> np.ndarray:
    """(N,) +1 where ``normals[i]`` points out of the cloud's sealed body, −1 where in, 0 undecided (see the
    module docstring), from the finest grid of :data:`SEAL_LEVELS` that seals the cloud (decides
    :data:`SEALED` of the points; all zeros when none does): the points' cells dilated, the outside
    flood-filled from the grid's border, the Gaussian-smoothed distance to the outside differentiated at
    every point; decided where the gradient is clear and not across the normal.
    """
    from scipy import ndimage

    p = np.asarray(points, np.float64)
    extent = float(np.ptp(p, axis=0).max())
    signs = np.zeros(p.shape[0], np.int8)
    for cell, dilation in SEAL_LEVELS:
        h = max(cell * spacing, extent / SEAL_CELLS)
        origin, occupied = occupancy_grid(p, h, dilation + 3)
        occupied = ndimage.binary_dilation(occupied, iterations=dilation)
        labels, _ = ndimage.label(~occupied)
        outside = labels == labels[0, 0, 0]
        depth = ndimage.gaussian_filter(ndimage.distance_transform_edt(~outside).astype(np.float32), 1.0)
        grid = ((p - origin) / h).T
        grad = np.stack([ndimage.map_coordinates(g, grid, order=1) for g in np.gradient(depth)], axis=1)
        along = np.einsum("ij,ij->i", grad, np.asarray(normals, np.float64))
        size = np.linalg.norm(grad, axis=1)
        clear = (size > 0.1) & (np.abs(along) > 0.3 * size)
        signs = np.where(clear, -np.sign(along), 0.0).astype(np.int8)
        if np.mean(signs != 0) >= SEALED:
            return signs
    return np.zeros(p.shape[0], np.int8)


def file_normals(cloud: PointCloud, keep: Bool[np.ndarray, " N"]) -> bool:
    """Whether the normals the file gave are used: given, and none of the kept points' of zero length."""
    return cloud.normals is not None and bool(np.all(np.linalg.norm(cloud.normals[keep], axis=1) > 0))


def oriented_normals(
    cloud: PointCloud, keep: Bool[np.ndarray, " N"] | None = None, spacing: float | None = None
) -> Float[np.ndarray, "N 3"]:
    """(N, 3) unit normals of ``cloud`` pointing outward: the file's (:func:`file_normals`), made consistent,
    or estimated; points outside ``keep`` (outliers) take no part and get their nearest kept point's normal.
    ``spacing``: the kept points' :func:`point_spacing` when the caller has it.
    """
    p = cloud.points
    keep = np.ones(p.shape[0], bool) if keep is None else np.asarray(keep, bool)
    kept = p[keep]
    given = file_normals(cloud, keep)
    n = cloud.normals[keep] if given else estimate_normals(kept)
    n = orient_normals(kept, n, propagate=not given)
    if not given:
        signs = exterior_signs(kept, n, point_spacing(kept) if spacing is None else spacing)
        n = n * np.where(signs == 0, 1, signs)[:, None]
    out = np.empty_like(p)
    out[keep] = n
    if not np.all(keep):
        from scipy.spatial import cKDTree

        _, j = cKDTree(kept).query(p[~keep])
        out[~keep] = n[j]
    return out
