"""Triangle meshes as arrays: the :class:`Mesh` type, validation, welding, face areas and enclosed volume.

Meshes are plain arrays: ``vertices`` (V, 3) float64 and ``faces`` (F, 3) int64, 0-based, in the
winding order of the file. Vertices are never reordered: :func:`weld_vertices` merges exactly
coincident vertices keeping first occurrences in order, and a mesh read with welding keeps the map
back to the file's vertices in :attr:`Mesh.file_index`. :func:`validate_mesh` is the check every
reader runs (finite coordinates, indices in range, a face with an area), raising one
:class:`~ncflow.errors.InputError` line; what can be repaired (zero-area, duplicate and
non-manifold faces, triangle soups) is repaired by :mod:`ncflow.geometry.repair`, the intake step
every mesh passes before it is matched. Reading and writing files is in
:mod:`ncflow.io.meshes`, edge tables in :mod:`ncflow.geometry.topology` and the normalising
similarity in :mod:`ncflow.geometry.normalize`.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError
from ncflow.geometry.repair import AREA_TOL, Repair, repair_mesh
from ncflow.geometry.topology import close_boundary
from ncflow.geometry.winding import signed_volume


@dataclasses.dataclass(frozen=True)
class Mesh:
    """A triangle mesh.

    Attributes:
        vertices: (V, 3) float64 coordinates.
        faces: (F, 3) int64 vertex indices, 0-based, consistently wound.
        name: where it came from (a file path) or a label; used in error messages.
        file_index: (V,) index of each vertex in the file's own vertex list (identity unless
            the reader welded duplicates).
        notes: what the reader changed that a user should hear of (polygons split into triangles).
    """

    vertices: Float[np.ndarray, "V 3"]
    faces: Int[np.ndarray, "F 3"]
    name: str | None = None
    file_index: Int[np.ndarray, " V"] | None = None
    notes: tuple[str, ...] = ()

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])


# ----------------------------------------------------------------------------------------------
# Reading and writing


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


def face_edge_lengths(vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"]) -> Float[np.ndarray, "F 3"]:
    """(F, 3) length of every triangle's edges (corner k to corner k − 1; an interior edge once per face)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    return np.linalg.norm(v[f] - v[np.roll(f, 1, axis=1)], axis=2)


def vertex_normals(vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"]) -> Float[np.ndarray, "V 3"]:
    """(V, 3) area-weighted unit vertex normals; zero for a vertex in no (non-degenerate) triangle."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    p = v[f]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])  # length = 2 × area
    out = np.zeros_like(v)
    for k in range(3):
        np.add.at(out, f[:, k], n)
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    return np.divide(out, norm, out=np.zeros_like(out), where=norm > 0)


def outward_vertex_normals(
    vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"]
) -> Float[np.ndarray, "V 3"]:
    """(V, 3) :func:`vertex_normals` turned to point out of the surface (:func:`orientation`: an
    inside-out mesh's are reversed); zero rows for a sheet, whose outside cannot be told.
    """
    return orientation(vertices, faces) * vertex_normals(vertices, faces)


COORDINATE_LIMIT = 1e30
"""The largest coordinate magnitude accepted: outputs are written in the input's units at float32
(largest finite value 3.4e38), with room for the flow to move points beyond the input's extent."""

SMALLEST_EXTENT = 1e-30
"""The smallest bounding-box diagonal accepted: well above float32's smallest normal number
(1.2e-38), so the outputs keep their seven digits."""


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
    if not np.issubdtype(faces.dtype, np.integer):
        raise InputError(f"face indices must be integers, got {faces.dtype}", name)
    if faces.shape[0] == 0:
        raise InputError("no faces", name)
    if faces.min() < 0 or faces.max() >= vertices.shape[0]:
        raise InputError(
            f"face index out of range: indices span [{int(faces.min())}, {int(faces.max())}] "
            f"but there are {vertices.shape[0]} vertices",
            name,
        )


def check_extent(vertices: Float[np.ndarray, "V 3"], name: str | None = None, what: str = "mesh") -> float:
    """Raise one :class:`InputError` line when finite coordinates lie beyond ±:data:`COORDINATE_LIMIT` or span
    less than :data:`SMALLEST_EXTENT` (what ncflow's float32 outputs can hold and resolve); the diagonal
    of their bounding box. ``what`` names the shape in the message ("mesh", "point cloud").
    """
    diag = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    largest = float(np.abs(vertices).max())
    if largest > COORDINATE_LIMIT:
        raise InputError(
            f"coordinates as large as {largest:.3g}: beyond ±{COORDINATE_LIMIT:g}, which ncflow's float32 "
            f"outputs cannot hold; scale the {what} down",
            name,
        )
    if diag < SMALLEST_EXTENT:
        raise InputError(
            f"the {what} is only {diag:.3g} across: below {SMALLEST_EXTENT:g}, which ncflow's float32 outputs "
            f"cannot resolve; scale the {what} up",
            name,
        )
    return diag


def validate_mesh(
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    name: str | None = None,
) -> None:
    """Check that a mesh can be read as one; raise :class:`InputError` with one line otherwise.

    Checks: (V, 3) finite coordinates within ±:data:`COORDINATE_LIMIT` on a mesh at least
    :data:`SMALLEST_EXTENT` across, (F, 3) faces with indices in range, and at least one face with
    an area. Defects that can be repaired (zero-area, duplicate or non-manifold faces, a triangle
    soup) are left to the intake step, :func:`ncflow.geometry.repair.repair_mesh`.
    """
    vertices = np.asarray(vertices)
    faces = np.asarray(faces)
    _check_finite_and_range(vertices, faces, name)
    diag = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    if diag == 0.0:
        raise InputError("all vertices coincide (zero-size mesh)", name)
    check_extent(vertices, name)
    if not np.any(face_areas(vertices, faces) > AREA_TOL * diag**2):
        raise InputError(f"none of its {faces.shape[0]} faces has an area (every face is degenerate)", name)


def repaired_mesh(mesh: Mesh, *, weld_tolerance: float = 0.0, min_component: float = 0.0) -> tuple[Mesh, Repair]:
    """The mesh after the intake step (:func:`ncflow.geometry.repair.repair_mesh`; its name and notes
    kept, :attr:`Mesh.file_index` leading to the file's vertices) and the repair, whose maps lead back
    to ``mesh``.
    """
    r = repair_mesh(
        mesh.vertices, mesh.faces, weld_tolerance=weld_tolerance, min_component=min_component, name=mesh.name
    )
    origin = r.vertex_origin if mesh.file_index is None else np.asarray(mesh.file_index)[r.vertex_origin]
    return Mesh(vertices=r.vertices, faces=r.faces, name=mesh.name, file_index=origin, notes=mesh.notes), r


# ----------------------------------------------------------------------------------------------
# Topology


def orientation(vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"], tol: float = 2e-3) -> int:
    """+1 when the faces wind outward (counter-clockwise seen from outside: normals point out), −1
    when inward (an inside-out mesh), 0 when the surface encloses too little volume to tell (a
    sheet): the sign of the signed volume after closing holes, decided when |volume| ≥ ``tol`` ·
    area^{3/2} (a sphere has 0.094, hands and bodies 0.03–0.04). A mesh with some faces wound
    against the rest takes the side most of its volume about its area centroid comes from.
    """
    areas = face_areas(vertices, faces)
    area = float(areas.sum())
    v, f = close_boundary(vertices, faces)
    # about the area centroid: a sum over faces wound both ways depends on the origin otherwise
    center = (areas @ np.asarray(vertices, dtype=np.float64)[faces].mean(axis=1)) / max(area, 1e-300)
    volume = signed_volume(v - center, f)
    if not abs(volume) >= tol * area**1.5:
        return 0
    return 1 if volume > 0 else -1


def enclosed_volume(vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"]) -> float:
    """Absolute volume enclosed by the surface; open surfaces are first closed by :func:`close_boundary`."""
    v, f = close_boundary(vertices, faces)
    tri = v[f]
    return float(abs(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0))


# ----------------------------------------------------------------------------------------------
# Normalisation
