"""Remeshing: closed-surface checks, Delaunay flips, relaxation on a surface, marching cubes with retries.

:func:`mesh_implicit` meshes the zero level set of an implicit function (the procedural
characters); :func:`retriangulate_mesh` gives another triangulation of a mesh whose every vertex
lies on the original surface, as (face, barycentric) coordinates — the exact ground truth of
retriangulated targets. Both extract a surface by marching cubes (scikit-image, Lewiner), check it
(:func:`check_closed_surface`: one closed, consistently wound 2-manifold component, with the
expected Euler characteristic), try other grid offsets when the check fails, then alternate
tangential area-weighted relaxation with re-projection onto the surface
(:func:`relax_on_surface`) and Delaunay edge flips (:func:`delaunay_flip`).

Over 500 lines: one concept, the two extractors and the steps they share.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError
from ncflow.geometry.barycentric import surface_points
from ncflow.geometry.closest import _project, closest_points_on_surface
from ncflow.geometry.topology import close_boundary, mesh_topology
from ncflow.geometry.winding import signed_volume, winding_numbers


def directed_edges(faces: Int[np.ndarray, "F 3"]) -> Int[np.ndarray, "3*F 2"]:
    """The directed edges of the faces, in three blocks: 0→1 of every face, then 1→2, then 2→0.

    Edge ``k · F + i`` belongs to face ``i``.
    """
    return np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])


def euler_characteristic(vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"]) -> int:
    """Euler characteristic V − E + F of a triangle mesh: 2 for a sphere, 1 for a disk.

    trimesh's ``euler_number``: referenced vertices, unique undirected edges, faces.
    """
    import trimesh

    return int(trimesh.Trimesh(np.asarray(vertices), np.asarray(faces, dtype=np.int64), process=False).euler_number)


def check_closed_surface(vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"]) -> str | None:
    """None if the mesh is a closed, consistently wound, single-component 2-manifold surface;
    otherwise what is wrong.

    Checks: no face repeats a vertex; every directed edge occurs once and its reverse occurs
    (each edge in exactly two faces, wound oppositely); every vertex is used; the faces form one
    edge-connected component; the faces around every vertex form a single fan.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    faces = np.asarray(faces, dtype=np.int64)
    nv = int(np.asarray(vertices).shape[0])
    nf = faces.shape[0]
    if nf == 0:
        return "no faces"
    if np.any(faces[:, 0] == faces[:, 1]) or np.any(faces[:, 1] == faces[:, 2]) or np.any(faces[:, 2] == faces[:, 0]):
        return "a face repeats a vertex"
    directed = directed_edges(faces)  # blocks: edges 0->1, 1->2, 2->0 of every face
    key = directed[:, 0] * nv + directed[:, 1]
    order = np.argsort(key)
    skey = key[order]
    if np.any(skey[1:] == skey[:-1]):
        return "a directed edge is used twice (inconsistent winding or a non-manifold edge)"
    rev = directed[:, 1] * nv + directed[:, 0]
    pos = np.minimum(np.searchsorted(skey, rev), skey.size - 1)
    if not np.all(skey[pos] == rev):
        return "open boundary (an edge has one face)"
    if np.unique(faces).size != nv:
        return "unreferenced vertices"
    twin = order[pos]  # index of the reversed edge
    face_of = np.arange(3 * nf) % nf
    adj = coo_matrix((np.ones(3 * nf), (face_of, face_of[twin])), shape=(nf, nf))
    n_comp, _ = connected_components(adj, directed=False)
    if n_comp != 1:
        return f"{n_comp} connected components"
    # around vertex a, the face with edge a->b is followed by the face with edge a->c, c the
    # third corner; in a manifold these successors form one cycle per vertex
    third = np.concatenate([faces[:, 2], faces[:, 0], faces[:, 1]])
    nxt_key = directed[:, 0] * nv + third
    succ = order[np.searchsorted(skey, nxt_key)]
    graph = coo_matrix((np.ones(3 * nf), (np.arange(3 * nf), succ)), shape=(3 * nf, 3 * nf))
    _, label = connected_components(graph, directed=True, connection="weak")
    cycles_per_vertex = np.bincount(directed[np.unique(label, return_index=True)[1], 0], minlength=nv)
    if np.any(cycles_per_vertex > 1):
        return f"{int(np.sum(cycles_per_vertex > 1))} non-manifold vertices"
    return None


def delaunay_flip(
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    *,
    max_passes: int = 10,
    max_dihedral: float = 60.0,
) -> Int[np.ndarray, "F 3"]:
    """Flip edges of a closed, consistently wound mesh towards the (intrinsic-ish) Delaunay condition.

    An edge (a, b) with opposite corners c, d is flipped to (c, d) when the angles at c and d
    sum to more than π, the two faces meet at a dihedral angle below ``max_dihedral`` degrees,
    the edge (c, d) does not exist yet, both a and b keep at least three neighbours and neither
    new face turns against the old ones. Vertices do not move; winding is kept.

    Returns:
        (F, 3) the new faces.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).copy()
    nv, nf = v.shape[0], f.shape[0]
    cos_max = np.cos(np.radians(max_dihedral))

    def normal(tri):
        return np.cross(tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :])

    for _ in range(max_passes):
        directed = directed_edges(f)
        key = directed[:, 0] * nv + directed[:, 1]
        order = np.argsort(key)
        skey = key[order]
        rev = directed[:, 1] * nv + directed[:, 0]
        twin = order[np.minimum(np.searchsorted(skey, rev), skey.size - 1)]
        e = np.flatnonzero(directed[:, 0] < directed[:, 1])
        a, b = directed[e, 0], directed[e, 1]
        f1, k1 = e % nf, e // nf
        f2, k2 = twin[e] % nf, twin[e] // nf
        c = f[f1, (k1 + 2) % 3]
        d = f[f2, (k2 + 2) % 3]

        def angle(at, p, q):
            u, w = v[p] - v[at], v[q] - v[at]
            cosv = np.einsum("ij,ij->i", u, w) / np.maximum(
                np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1), 1e-300
            )
            return np.arccos(np.clip(cosv, -1.0, 1.0))

        excess = angle(c, a, b) + angle(d, a, b) - np.pi
        n1, n2 = normal(v[f[f1]]), normal(v[f[f2]])
        n1 /= np.maximum(np.linalg.norm(n1, axis=1, keepdims=True), 1e-300)
        n2 /= np.maximum(np.linalg.norm(n2, axis=1, keepdims=True), 1e-300)
        cand = np.flatnonzero((excess > 1e-9) & (np.einsum("ij,ij->i", n1, n2) > cos_max))
        if cand.size == 0:
            break
        cand = cand[np.argsort(-excess[cand], kind="stable")]
        edges = set(np.minimum(directed[:, 0], directed[:, 1]) * nv + np.maximum(directed[:, 0], directed[:, 1]))
        valence = np.bincount(f.reshape(-1), minlength=nv)
        used = np.zeros(nf, dtype=bool)
        flipped = 0
        for i in cand.tolist():
            fa, fb = int(f1[i]), int(f2[i])
            if used[fa] or used[fb]:
                continue
            ai, bi, ci, di = int(a[i]), int(b[i]), int(c[i]), int(d[i])
            cd = min(ci, di) * nv + max(ci, di)
            if ci == di or cd in edges or valence[ai] <= 3 or valence[bi] <= 3:
                continue
            t1 = np.array([ai, di, ci])
            t2 = np.array([di, bi, ci])
            m1, m2 = normal(v[t1]), normal(v[t2])
            if m1 @ n1[i] <= 0 or m2 @ n1[i] <= 0 or m1 @ n2[i] <= 0 or m2 @ n2[i] <= 0:
                continue
            f[fa], f[fb] = t1, t2
            used[fa] = used[fb] = True
            edges.discard(min(ai, bi) * nv + max(ai, bi))
            edges.add(cd)
            valence[ai] -= 1  # valence counts faces; a closed mesh has as many faces as edges around a vertex
            valence[bi] -= 1
            valence[ci] += 1
            valence[di] += 1
            flipped += 1
        if flipped == 0:
            break
    return f


def _vertex_normals_from_gradient(fn, x: np.ndarray, eps: float) -> np.ndarray:
    g = np.empty_like(x)
    for i in range(3):
        e = np.zeros(3)
        e[i] = eps
        g[:, i] = (fn(x + e) - fn(x - e)) / (2 * eps)
    return g


def _project_to_level(fn, x: np.ndarray, eps: float, iterations: int = 3) -> np.ndarray:
    for _ in range(iterations):
        f = fn(x)
        g = _vertex_normals_from_gradient(fn, x, eps)
        x = x - (f / np.maximum(np.sum(g * g, axis=1), 1e-300))[:, None] * g
    return x


def _area_centroids(x: np.ndarray, faces: np.ndarray) -> np.ndarray:
    tri = x[faces]
    c = tri.mean(axis=1)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    num = np.zeros_like(x)
    den = np.zeros(x.shape[0])
    for k in range(3):
        np.add.at(num, faces[:, k], area[:, None] * c)
        np.add.at(den, faces[:, k], area)
    return num / np.maximum(den, 1e-300)[:, None]


def relax_on_surface(
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    project: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    iterations: int = 8,
    step: float = 0.8,
) -> Float[np.ndarray, "V 3"]:
    """Tangential area-weighted centroid relaxation with re-projection onto a surface.

    Args:
        vertices: (V, 3) initial vertex positions of the mesh to relax.
        faces: (F, 3) vertex indices of its triangles (connectivity is kept).
        project: maps points (n, 3) to (their projection onto the surface (n, 3), unit surface
            normals there (n, 3)).
        iterations: rounds of (move towards the area-weighted centroid of the incident faces,
            tangentially; project back).
        step: fraction of the tangential move taken per round.

    Returns:
        (V, 3) relaxed vertices, on the surface.
    """
    x, n = project(np.asarray(vertices, dtype=np.float64))
    faces = np.asarray(faces, dtype=np.int64)
    for _ in range(iterations):
        d = _area_centroids(x, faces) - x
        d -= np.sum(d * n, axis=1)[:, None] * n
        x, n = project(x + step * d)
    return x


def _grid_points(origin: np.ndarray, shape: tuple[int, int, int], h: float) -> np.ndarray:
    """(n, 3) points ``origin + h · (i, j, k)`` of a grid of ``shape`` nodes, in C order (i slowest)."""
    axes = [origin[i] + h * np.arange(shape[i]) for i in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def _closed_marching_cubes(
    sample: Callable[[np.ndarray, tuple[int, int, int]], np.ndarray],
    lower: np.ndarray,
    upper: np.ndarray,
    h: float,
    offset: Callable[[int], np.ndarray],
    max_attempts: int,
    *,
    euler: int | None,
    inside: np.ndarray | None = None,
) -> tuple[np.ndarray | None, np.ndarray | None, str]:
    """Marching cubes with retries on shifted grids: the extraction step of the two remeshers.

    Used by :func:`mesh_implicit` and :func:`retriangulate_mesh`. Attempt k (0 ≤ k <
    ``max_attempts``) uses the grid of cell size ``h`` from ``lower − 2h + offset(k) · h`` to past
    ``upper + 2h``, takes ``sample(origin, shape)`` (values (shape) on its nodes, negative inside),
    moves values within 1e-9 h of 0 off the level set, extracts the zero level set (scikit-image,
    Lewiner) and accepts it when it is one closed, consistently wound 2-manifold component
    (:func:`check_closed_surface`) with Euler characteristic ``euler`` (None: any) whose winding
    number is at least ½ at every ``inside`` point. The accepted mesh is oriented outward
    (positive :func:`signed_volume`).

    Returns:
        (vertices (V, 3), faces (F, 3), "") on success, else (None, None, what was wrong with the
        last attempt).
    """
    from skimage.measure import marching_cubes

    problem = ""
    for attempt in range(max_attempts):
        origin = lower - 2.0 * h + offset(attempt) * h
        shape = tuple(int(x) for x in np.ceil((upper + 2.0 * h - origin) / h).astype(np.int64) + 1)
        values = sample(origin, shape)
        tiny = 1e-9 * h
        values = np.where(np.abs(values) < tiny, tiny, values)  # no grid value exactly on the level set
        v, f, _, _ = marching_cubes(values, 0.0, spacing=(h, h, h), method="lewiner")
        v = v.astype(np.float64) + origin
        f = f.astype(np.int64)
        problem = check_closed_surface(v, f) or ""
        if not problem and euler is not None:
            chi = euler_characteristic(v, f)
            if chi != euler:
                problem = f"Euler characteristic {chi} instead of {euler}: parts fused or holes"
        if not problem and inside is not None:
            wn = np.abs(winding_numbers(np.asarray(inside, dtype=np.float64).reshape(-1, 3), v[f]))
            if np.any(wn < 0.5):
                problem = f"{int(np.sum(wn < 0.5))} of the given inside points are outside: thin parts were lost"
        if not problem:
            if signed_volume(v, f) < 0:
                f = f[:, ::-1].copy()
            return v, f, ""
    return None, None, problem


def mesh_implicit(
    fn: Callable[[np.ndarray], np.ndarray],
    lower: Float[np.ndarray, " 3"],
    upper: Float[np.ndarray, " 3"],
    resolution: float,
    *,
    offset: Float[np.ndarray, " 3"] | None = None,
    relax_iterations: int = 8,
    euler: int | None = 2,
    inside: Float[np.ndarray, "n 3"] | None = None,
    max_attempts: int = 4,
) -> tuple[Float[np.ndarray, "V 3"], Int[np.ndarray, "F 3"]]:
    """Closed triangle mesh of the zero level set of ``fn`` (negative inside) inside a box.

    Marching cubes (scikit-image, Lewiner) on a grid of ``resolution`` cells along the box's
    largest side (cell size h, padded by two cells, shifted by ``offset`` · h), oriented outward,
    then :func:`relax_on_surface` with Newton projection onto ``fn = 0`` and
    :func:`delaunay_flip` (twice). If the extracted surface is not one closed manifold component
    with Euler characteristic ``euler`` (2: a sphere; None: any) enclosing all the ``inside``
    points (e.g. the joints of a skeleton: thin parts lost by a coarse grid leave them outside),
    the grid is shifted and tried again, ``max_attempts`` times in all.

    Raises:
        InputError: no attempt gave such a surface (the grid is too coarse for the thinnest part
            or the narrowest gap: raise ``resolution``).
    """
    lower = np.asarray(lower, dtype=np.float64)
    upper = np.asarray(upper, dtype=np.float64)
    h = float(np.max(upper - lower)) / float(resolution)
    off0 = np.zeros(3) if offset is None else np.asarray(offset, dtype=np.float64)
    v, f, problem = _closed_marching_cubes(
        lambda origin, shape: fn(_grid_points(origin, shape, h)).reshape(shape),
        lower,
        upper,
        h,
        # further attempts shift the grid along a low-discrepancy sequence
        lambda attempt: np.mod(off0 + attempt * np.array([0.618034, 0.414214, 0.732051]), 1.0),
        max_attempts,
        euler=euler,
        inside=inside,
    )
    if problem:
        raise InputError(
            f"marching cubes at resolution {resolution:g} gave no single closed surface of the expected "
            f"topology ({problem}; {max_attempts} grid offsets tried); use a higher resolution"
        )
    eps = 1e-3 * h

    def project(p):
        p = _project_to_level(fn, p, eps)
        g = _vertex_normals_from_gradient(fn, p, eps)
        return p, g / np.linalg.norm(g, axis=1, keepdims=True)

    half = max(1, relax_iterations // 2)
    v = relax_on_surface(v, f, project, iterations=half)
    f = delaunay_flip(v, f)
    v = relax_on_surface(v, f, project, iterations=relax_iterations - half)
    f = delaunay_flip(v, f)
    return v, f


def _surface_samples(v: np.ndarray, f: np.ndarray, spacing: float) -> np.ndarray:
    """Points on every triangle on a barycentric lattice whose step is at most ``spacing``."""
    tri = v[f]
    longest = np.max(np.linalg.norm(tri[:, [1, 2, 0]] - tri, axis=2), axis=1)
    m = np.maximum(1, np.ceil(longest / spacing).astype(np.int64))
    out = [v]
    for k in np.unique(m):
        if k == 1:
            continue
        ii, jj = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
        keep = ii + jj <= k
        b = np.stack([ii[keep], jj[keep], k - ii[keep] - jj[keep]], axis=1) / k
        out.append(np.einsum("sk,tkd->tsd", b, tri[m == k]).reshape(-1, 3))
    return np.concatenate(out)


def _pseudo_normal_sign(
    points: np.ndarray, v: np.ndarray, f: np.ndarray, face: np.ndarray, bary: np.ndarray, tol: float = 1e-9
) -> np.ndarray:
    """+1 outside / -1 inside a closed, consistently wound mesh, from the angle-weighted pseudo-normal
    of the closest feature (face, edge or vertex; Bærentzen & Aanæs 2005).
    """
    tri = v[f]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
    # angle-weighted vertex normals
    vn = np.zeros_like(v)
    for k in range(3):
        a, b, c = tri[:, k], tri[:, (k + 1) % 3], tri[:, (k + 2) % 3]
        e1, e2 = b - a, c - a
        cosang = np.einsum("ij,ij->i", e1, e2) / np.maximum(
            np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1), 1e-300
        )
        np.add.at(vn, f[:, k], np.arccos(np.clip(cosang, -1.0, 1.0))[:, None] * fn)
    topo = mesh_topology(f, v.shape[0])
    en = fn[topo.edge_faces[:, 0]] + np.where(
        topo.edge_faces[:, 1:2] >= 0, fn[np.maximum(topo.edge_faces[:, 1], 0)], 0.0
    )
    zero = bary <= tol
    nz = zero.sum(axis=1)
    normal = fn[face].copy()
    at_vertex = nz == 2
    if np.any(at_vertex):
        corner = np.argmax(~zero[at_vertex], axis=1)
        normal[at_vertex] = vn[f[face[at_vertex], corner]]
    on_edge = nz == 1
    if np.any(on_edge):
        opp = np.argmax(zero[on_edge], axis=1)
        fe = f[face[on_edge]]
        a = fe[np.arange(fe.shape[0]), (opp + 1) % 3]
        b = fe[np.arange(fe.shape[0]), (opp + 2) % 3]
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        key = topo.edges[:, 0] * v.shape[0] + topo.edges[:, 1]
        idx = np.searchsorted(key, lo * v.shape[0] + hi)
        normal[on_edge] = en[idx]
    foot = surface_points(v, f, face, bary)
    return np.where(np.einsum("ij,ij->i", points - foot, normal) < 0, -1.0, 1.0)


def _signed_distance_grid(v: np.ndarray, f: np.ndarray, origin: np.ndarray, shape: tuple, h: float) -> np.ndarray:
    """Signed distance (negative inside) to a closed mesh on a grid, exact within a band of ~2 cells
    (sign from pseudo-normals), clamped to ±band outside it (one sign per connected region of
    the grid outside the band, by winding number).
    """
    from scipy import ndimage
    from scipy.spatial import cKDTree

    grid = _grid_points(origin, shape, h)
    spacing = 0.5 * h
    samples = _surface_samples(v, f, spacing)
    band = 2.0 * h
    near, _ = cKDTree(samples).query(grid, distance_upper_bound=band + spacing)
    in_band = np.isfinite(near)
    values = np.full(grid.shape[0], band)
    idx = np.flatnonzero(in_band)
    dist, face, bary = closest_points_on_surface(grid[idx], v, f)
    values[idx] = _pseudo_normal_sign(grid[idx], v, f, face, bary) * dist
    labels, n = ndimage.label(~in_band.reshape(shape))
    labels = labels.reshape(-1)
    if n:
        first = np.unique(labels, return_index=True)[1][1:]  # first grid point of regions 1..n
        sign = np.where(winding_numbers(grid[first], v[f]) > 0.5, -1.0, 1.0)
        out = ~in_band
        values[out] = band * sign[labels[out] - 1]
    return values.reshape(shape)


def _largest_component_faces(faces: np.ndarray, nv: int) -> np.ndarray:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if faces.shape[0] == 0:
        return faces
    e = directed_edges(faces)
    g = coo_matrix((np.ones(e.shape[0]), (e[:, 0], e[:, 1])), shape=(nv, nv))
    _, label = connected_components(g, directed=False)
    big = np.argmax(np.bincount(label[faces[:, 0]]))
    return faces[label[faces[:, 0]] == big]


def _remove_fins(faces: np.ndarray, nv: int) -> np.ndarray:
    """Repeatedly drop faces with two or more boundary edges and the faces at vertices where
    several boundary loops meet, until the open surface is a manifold with boundary.
    """
    for _ in range(50):
        e = np.sort(directed_edges(faces), axis=1)
        key = e[:, 0] * nv + e[:, 1]
        _, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
        per_face = (cnt[inv] == 1).reshape(3, -1).sum(axis=0)
        boundary = e[cnt[inv] == 1]
        deg = np.bincount(boundary.reshape(-1), minlength=nv)
        pinch = deg > 2
        bad = (per_face >= 2) | np.any(pinch[faces], axis=1)
        if not np.any(bad):
            return faces
        faces = faces[~bad]
    return faces


def retriangulate_mesh(
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    resolution: float = 48,
    *,
    seed: int = 0,
    relax_iterations: int = 8,
    max_attempts: int = 4,
) -> tuple[Float[np.ndarray, "W 3"], Int[np.ndarray, "G 3"], Int[np.ndarray, " W"], Float[np.ndarray, "W 3"]]:
    """A different triangulation of a surface, with every new vertex on the surface.

    The surface is closed first if it has holes (:func:`ncflow.geometry.topology.close_boundary`); its signed
    distance is sampled on a grid of ``resolution`` cells along the largest extent (shifted by a
    seeded sub-cell offset), marching cubes extracts a closed mesh (of the input's topology: if
    it is not one closed manifold component with the input's Euler characteristic, other seeded
    offsets are tried, ``max_attempts`` in all), which is relaxed
    tangentially with re-projection onto the surface. Every vertex is finally projected onto
    the surface (face + barycentrics). For an open input, the vertices that land on the caps
    added to close it are removed (with their faces, and any fins or pinched vertices left on
    the new boundary), so the result is open where the input is.

    Returns:
        (new vertices (W, 3) on the surface, new faces (G, 3), for every new vertex the face of
        the input it lies on (W,) and its barycentric coordinates (W, 3)).

    Raises:
        InputError: the grid is too coarse for the surface's thinnest part.
    """
    v0 = np.asarray(vertices, dtype=np.float64)
    f0 = np.asarray(faces, dtype=np.int64)
    v, f = close_boundary(v0, f0)
    n_open_faces = f0.shape[0]
    lo, hi = v.min(axis=0), v.max(axis=0)
    h = float(np.max(hi - lo)) / float(resolution)
    mv, mf, problem = _closed_marching_cubes(
        lambda origin, shape: _signed_distance_grid(v, f, origin, shape, h),
        lo,
        hi,
        h,
        lambda attempt: np.random.default_rng([int(seed), 0xE7, attempt]).uniform(0.0, 1.0, size=3),
        max_attempts,
        euler=euler_characteristic(v, f),
    )
    if problem:
        raise InputError(
            f"retriangulation at resolution {resolution:g} failed ({problem}, {max_attempts} grid offsets tried); "
            "the surface has parts or gaps thinner than the grid: use a higher target resolution"
        )
    tri0 = v[f]
    normals = np.cross(tri0[:, 1] - tri0[:, 0], tri0[:, 2] - tri0[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)

    def project(p):
        _, face, bary = _project(p, v, f)
        return surface_points(v, f, face, bary), normals[face]

    half = max(1, relax_iterations // 2)
    mv = relax_on_surface(mv, mf, project, iterations=half)
    mf = delaunay_flip(mv, mf)
    mv = relax_on_surface(mv, mf, project, iterations=relax_iterations - half)
    mf = delaunay_flip(mv, mf)
    _, face, bary = _project(mv, v, f)
    keep_v = face < n_open_faces
    if not np.all(keep_v):
        mf = mf[np.all(keep_v[mf], axis=1)]
        mf = _remove_fins(mf, mv.shape[0])
        mf = _largest_component_faces(mf, mv.shape[0])
    used = np.unique(mf)
    remap = np.full(mv.shape[0], -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    face, bary = face[used], bary[used]
    return surface_points(v0, f0, face, bary), remap[mf], face, bary
