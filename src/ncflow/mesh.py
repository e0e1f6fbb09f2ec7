"""Triangle meshes: reading, validation, topology tables and normalisation.

Meshes are plain arrays: ``vertices`` (V, 3) float64 and ``faces`` (F, 3) int64, 0-based, in the
winding order of the file. Reading never reorders vertices; exactly coincident vertices are
merged ("welded") only for the formats that store split vertices by construction (STL triangle
soups, glTF/GLB seam duplicates), or when asked, and the mapping back to the file's vertices is
kept in :attr:`Mesh.file_index`.
"""

from __future__ import annotations

import dataclasses
import os
import re
from pathlib import Path

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError, check_input_file

__all__ = [
    "Mesh",
    "Topology",
    "Normalization",
    "load_mesh",
    "save_mesh",
    "validate_mesh",
    "weld_vertices",
    "mesh_topology",
    "close_boundary",
    "enclosed_volume",
    "fit_normalization",
    "face_areas",
    "MESH_SUFFIXES",
]

MESH_SUFFIXES = (".obj", ".ply", ".off", ".stl", ".glb", ".gltf")
_WELD_BY_DEFAULT = (".stl", ".glb", ".gltf")
UNIT_BALL_VOLUME = 4.0 * np.pi / 3.0


@dataclasses.dataclass(frozen=True)
class Mesh:
    """A triangle mesh.

    Attributes:
        vertices: (V, 3) float64 coordinates.
        faces: (F, 3) int64 vertex indices, 0-based, consistently wound.
        name: where it came from (a file path) or a label; used in error messages.
        file_index: (V,) index of each vertex in the file's own vertex list (identity unless
            the reader welded duplicates).
    """

    vertices: Float[np.ndarray, "V 3"]
    faces: Int[np.ndarray, "F 3"]
    name: str | None = None
    file_index: Int[np.ndarray, " V"] | None = None

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])

    def with_vertices(self, vertices: Float[np.ndarray, "V 3"]) -> "Mesh":
        """The same connectivity with other vertex positions."""
        return dataclasses.replace(self, vertices=np.asarray(vertices, dtype=np.float64))


# ----------------------------------------------------------------------------------------------
# Reading and writing


def _declared_polygon_sizes(path: Path) -> np.ndarray | None:
    """Number of corners of every face as written in an OBJ/OFF/ASCII-PLY file (None if unknown)."""
    suffix = path.suffix.lower()
    try:
        if suffix == ".obj":
            sizes = []
            with open(path, "r", errors="replace") as fh:
                for line in fh:
                    if line.startswith("f ") or line.startswith("f\t"):
                        sizes.append(len(line.split()) - 1)
            return np.asarray(sizes, dtype=np.int64)
        if suffix == ".off":
            with open(path, "r", errors="replace") as fh:
                tokens = [ln.split("#")[0].split() for ln in fh]
            lines = [t for t in tokens if t]
            if not lines:
                return None
            head = lines[0]
            if head[0].upper().endswith("OFF"):
                head = head[1:] if len(head) > 1 else lines[1]
                start = 1 if len(lines[0]) > 1 else 2
            else:
                start = 1
            nv, nf = int(head[0]), int(head[1])
            face_lines = lines[start + nv : start + nv + nf]
            return np.asarray([int(t[0]) for t in face_lines], dtype=np.int64)
        if suffix == ".ply":
            with open(path, "rb") as fh:
                header = fh.read(4096).split(b"end_header")[0].decode("ascii", "replace")
            if "format ascii" not in header:
                return None
            m_v = re.search(r"element vertex (\d+)", header)
            m_f = re.search(r"element face (\d+)", header)
            if not (m_v and m_f):
                return None
            nv, nf = int(m_v.group(1)), int(m_f.group(1))
            with open(path, "r", errors="replace") as fh:
                body = fh.read().split("end_header", 1)[1].strip().splitlines()
            return np.asarray([int(ln.split()[0]) for ln in body[nv : nv + nf]], dtype=np.int64)
    except (OSError, ValueError, IndexError):
        return None
    return None


def load_mesh(path: str | os.PathLike, *, weld: bool | None = None, validate: bool = True) -> Mesh:
    """Read a triangle mesh from OBJ, PLY, OFF, STL, glTF or GLB.

    Args:
        path: the file.
        weld: merge exactly coincident vertices. ``None`` welds STL and glTF/GLB only (formats
            whose vertices are split at every face or UV seam) and keeps other files as written.
        validate: run :func:`validate_mesh` and raise on bad input.

    Returns:
        The mesh, vertices in file order (unless welded; see :attr:`Mesh.file_index`).

    Raises:
        InputError: one line naming the file and the problem.
    """
    import trimesh

    path = Path(path)
    suffix = check_input_file(path, "mesh", MESH_SUFFIXES)
    sizes = _declared_polygon_sizes(path)
    if sizes is not None and sizes.size and np.any(sizes != 3):
        bad = int(np.sum(sizes != 3))
        raise InputError(
            f"non-triangular faces: {bad} of {sizes.size} faces have {sorted(set(sizes[sizes != 3].tolist()))} "
            "corners; triangulate the mesh first",
            path,
        )
    try:
        loaded = trimesh.load(str(path), process=False, maintain_order=True, force="mesh")
    except IndexError:
        if suffix == ".obj":  # trimesh's OBJ reader indexes the vertex list with the face indices
            raise InputError("face index out of range", path) from None
        raise InputError("cannot read mesh (corrupt or truncated file)", path) from None
    except Exception as exc:  # trimesh raises many kinds of errors for broken files
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        if "outside the range" in msg or "out of bounds" in msg:
            raise InputError("face index out of range", path) from None
        raise InputError(f"cannot read mesh ({msg})", path) from None
    vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    if faces.size == 0:
        raise InputError("no faces (a point cloud or an empty file?)", path)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise InputError(f"non-triangular faces (shape {faces.shape})", path)
    file_index = np.arange(vertices.shape[0])
    if weld is None:
        weld = suffix in _WELD_BY_DEFAULT
    if validate:
        _check_finite_and_range(vertices, faces, str(path))
    if weld:
        vertices, faces, file_index = weld_vertices(vertices, faces)
    mesh = Mesh(vertices=vertices, faces=faces, name=str(path), file_index=file_index)
    if validate:
        validate_mesh(mesh.vertices, mesh.faces, name=mesh.name)
    return mesh


def save_mesh(path: str | os.PathLike, vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"]) -> None:
    """Write a triangle mesh (format from the suffix: .ply, .obj, .off, .stl, .glb), vertex order kept."""
    import trimesh

    vertices = np.asarray(vertices, dtype=np.float64)
    if not np.all(np.isfinite(vertices)):
        raise InputError("refusing to write non-finite vertex coordinates", path)
    mesh = trimesh.Trimesh(vertices=vertices, faces=np.asarray(faces, dtype=np.int64), process=False)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    mesh.export(str(path))


def weld_vertices(
    vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"], tol: float = 0.0
) -> tuple[Float[np.ndarray, "W 3"], Int[np.ndarray, "F 3"], Int[np.ndarray, " W"]]:
    """Merge coincident vertices.

    Args:
        vertices: (V, 3) positions.
        faces: (F, 3) indices.
        tol: vertices whose coordinates agree after rounding to ``tol`` are merged
            (0 merges exact duplicates only).

    Returns:
        (welded vertices (W, 3), re-indexed faces (F, 3), for each welded vertex the index of its
        first occurrence in the input). Vertices keep their first-occurrence order.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    key = vertices if tol <= 0 else np.round(vertices / tol)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    order = np.argsort(first)  # keep first-occurrence order
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    new_index = rank[inverse]
    return vertices[first[order]], new_index[np.asarray(faces)], first[order]


# ----------------------------------------------------------------------------------------------
# Validation


def face_areas(vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"]) -> Float[np.ndarray, " F"]:
    """Area of every triangle."""
    v = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    return 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)


def _check_finite_and_range(vertices: np.ndarray, faces: np.ndarray, name: str | None) -> None:
    if vertices.ndim != 2 or vertices.shape[1] != 3 or vertices.shape[0] == 0:
        raise InputError(f"expected (V, 3) vertex coordinates, got shape {vertices.shape}", name)
    bad = ~np.all(np.isfinite(vertices), axis=1)
    if np.any(bad):
        raise InputError(
            f"{int(bad.sum())} vertices have NaN or infinite coordinates (first: vertex {int(np.argmax(bad))})",
            name,
        )
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise InputError(f"non-triangular faces (shape {faces.shape})", name)
    if faces.shape[0] == 0:
        raise InputError("no faces", name)
    if faces.min() < 0 or faces.max() >= vertices.shape[0]:
        raise InputError(
            f"face index out of range: indices span [{int(faces.min())}, {int(faces.max())}] "
            f"but there are {vertices.shape[0]} vertices",
            name,
        )


def validate_mesh(
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    name: str | None = None,
    *,
    max_degenerate_fraction: float = 0.01,
    area_tol: float = 1e-12,
) -> None:
    """Check that a mesh is usable; raise :class:`InputError` with one line otherwise.

    Checks: (V, 3) finite coordinates, (F, 3) faces with indices in range, at least one face, at
    most ``max_degenerate_fraction`` of faces with area below ``area_tol`` × (bounding-box
    diagonal)², and no edge shared by more than 4 faces.
    """
    vertices = np.asarray(vertices)
    faces = np.asarray(faces)
    _check_finite_and_range(vertices, faces, name)
    diag = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    if diag == 0.0:
        raise InputError("all vertices coincide (zero-size mesh)", name)
    areas = face_areas(vertices, faces)
    degenerate = areas <= area_tol * diag**2
    n_deg = int(degenerate.sum())
    if n_deg > max_degenerate_fraction * faces.shape[0]:
        raise InputError(
            f"{n_deg} of {faces.shape[0]} faces have zero area (more than "
            f"{100 * max_degenerate_fraction:g}% allowed; first: face {int(np.argmax(degenerate))})",
            name,
        )
    mesh_topology(faces, vertices.shape[0], name=name)


# ----------------------------------------------------------------------------------------------
# Topology


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

    Raises:
        InputError: an edge is shared by more than four faces.
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
            f"{int(counts[worst])} faces (at most 4 supported)",
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
    centroids = np.stack(
        [
            vertices[np.unique(np.concatenate([a[loop_of_edge == k], b[loop_of_edge == k]]))].mean(0)
            for k in range(loops.size)
        ]
    )
    cap = np.stack([start, end, nv + loop_of_edge.reshape(-1)], axis=1)
    return np.concatenate([vertices, centroids]), np.concatenate([faces, cap])


def enclosed_volume(vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"]) -> float:
    """Absolute volume enclosed by the surface; open surfaces are first closed by :func:`close_boundary`."""
    v, f = close_boundary(vertices, faces)
    tri = v[f]
    return float(abs(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0))


# ----------------------------------------------------------------------------------------------
# Normalisation


@dataclasses.dataclass(frozen=True)
class Normalization:
    """One similarity x ↦ (x − center) · scale, shared by source and target; reversible.

    Attributes:
        center: (3,) the source's area-weighted surface centroid (user coordinates).
        scale: positive factor making the source enclose the volume of the unit ball (4π/3).
    """

    center: Float[np.ndarray, " 3"]
    scale: float

    def apply(self, points: Float[np.ndarray, "... 3"]) -> Float[np.ndarray, "... 3"]:
        """User coordinates → normalised coordinates."""
        return (np.asarray(points, dtype=np.float64) - self.center) * self.scale

    def invert(self, points: Float[np.ndarray, "... 3"]) -> Float[np.ndarray, "... 3"]:
        """Normalised coordinates → user coordinates."""
        return np.asarray(points, dtype=np.float64) / self.scale + self.center

    def to_dict(self) -> dict:
        return {"center": [float(c) for c in self.center], "scale": float(self.scale)}


def fit_normalization(
    vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"], target_volume: float = UNIT_BALL_VOLUME
) -> Normalization:
    """The similarity that centres a (source) mesh and scales it to enclose ``target_volume``.

    Centre: area-weighted centroid of the surface (independent of the triangulation). Scale:
    (target_volume / V)^(1/3) with V the enclosed volume (:func:`enclosed_volume`; open meshes
    are closed by fans to their boundary-loop centroids). A surface enclosing almost no volume
    (a flat sheet) is instead scaled to the surface area of the unit sphere, 4π.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    areas = face_areas(vertices, faces)
    centres = vertices[np.asarray(faces)].mean(1)
    total = areas.sum()
    center = (centres * areas[:, None]).sum(0) / total if total > 0 else vertices.mean(0)
    volume = enclosed_volume(vertices, faces)
    diag = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    if volume > 1e-6 * diag**3:
        scale = (target_volume / volume) ** (1.0 / 3.0)
    else:
        scale = float(np.sqrt(4.0 * np.pi / total))
    return Normalization(center=center, scale=float(scale))
