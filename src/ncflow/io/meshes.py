"""Reading and writing triangle meshes: OBJ, PLY, OFF, STL and glTF/GLB (through trimesh).

:func:`load_mesh` never reorders vertices. Exactly coincident vertices are merged ("welded") only
for the formats that store split vertices by construction (STL triangle soups, glTF/GLB seam
duplicates), or when asked, and the map back to the file's vertices is kept in
:attr:`~ncflow.geometry.mesh.Mesh.file_index`. Polygons other than triangles are refused (with
their count) rather than triangulated silently, and every mesh is validated
(:func:`~ncflow.geometry.mesh.validate_mesh`). :func:`save_mesh` is the one mesh writer: by suffix,
in the given vertex order, atomically, at float32 (through trimesh) or float64 precision.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError
from ncflow.geometry.mesh import Mesh, _check_finite_and_range, validate_mesh, weld_vertices
from ncflow.io.atomic import atomic_path, atomic_write_bytes, atomic_write_text
from ncflow.io.files import check_input_file

MESH_SUFFIXES = (".obj", ".ply", ".off", ".stl", ".glb", ".gltf")


_WELD_BY_DEFAULT = (".stl", ".glb", ".gltf")


def _declared_polygon_sizes(path: Path) -> np.ndarray | None:
    """Number of corners of every face as written in an OBJ/OFF/ASCII-PLY file (None if unknown)."""
    suffix = path.suffix.lower()
    try:
        if suffix == ".obj":
            sizes = []
            with open(path, errors="replace") as fh:
                for line in fh:
                    if line.startswith("f ") or line.startswith("f\t"):
                        sizes.append(len(line.split()) - 1)
            return np.asarray(sizes, dtype=np.int64)
        if suffix == ".off":
            with open(path, errors="replace") as fh:
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
            with open(path, errors="replace") as fh:
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


MESH_PRECISIONS = ("float32", "float64")


def save_mesh(
    path: str | os.PathLike,
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    *,
    precision: str = "float32",
) -> None:
    """Write a triangle mesh, vertex order kept, atomically (:func:`~ncflow.io.atomic.atomic_path`).

    Args:
        path: the file; the format comes from the suffix. Its folder is created.
        vertices: (V, 3) coordinates, all finite.
        faces: (F, 3) vertex indices, 0-based.
        precision: ``"float32"``: through trimesh (.ply, .obj, .off, .stl, .glb; PLY, STL and GLB
            store float32 coordinates, OBJ 8 and OFF 10 decimals). ``"float64"``: without losing a
            bit, .ply (binary little-endian, ``double`` coordinates, ``int`` indices, header comment
            ``ncflow pair (float64 vertices)``) or .obj (``repr`` of every coordinate, 17
            significant digits) only.

    Raises:
        InputError: non-finite coordinates, an unknown precision, or a suffix that ``"float64"``
            cannot write.
    """
    if precision not in MESH_PRECISIONS:
        raise InputError(f"mesh precision must be one of {', '.join(MESH_PRECISIONS)}, got {precision!r}", path)
    if precision == "float64":
        _save_mesh_float64(path, vertices, faces)
        return
    import trimesh

    vertices = np.asarray(vertices, dtype=np.float64)
    if not np.all(np.isfinite(vertices)):
        raise InputError("refusing to write non-finite vertex coordinates", path)
    mesh = trimesh.Trimesh(vertices=vertices, faces=np.asarray(faces, dtype=np.int64), process=False)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        mesh.export(str(tmp))


def _save_mesh_float64(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray) -> None:
    """The ``precision="float64"`` writer of :func:`save_mesh` (binary PLY of doubles, or OBJ with ``repr``)."""
    suffix = Path(path).suffix.lower()
    if suffix not in (".ply", ".obj"):
        raise InputError(f"float64 meshes are written as .ply or .obj, not {suffix or '(no suffix)'!r}", path)
    v = np.ascontiguousarray(vertices, dtype="<f8")
    f = np.asarray(faces, dtype=np.int64)
    if not np.all(np.isfinite(v)):
        raise InputError("refusing to write non-finite vertex coordinates", path)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".ply":
        header = (
            "ply\nformat binary_little_endian 1.0\ncomment ncflow pair (float64 vertices)\n"
            f"element vertex {v.shape[0]}\nproperty double x\nproperty double y\nproperty double z\n"
            f"element face {f.shape[0]}\nproperty list uchar int vertex_indices\nend_header\n"
        )
        rec = np.zeros(f.shape[0], dtype=[("n", "u1"), ("idx", "<i4", (3,))])
        rec["n"] = 3
        rec["idx"] = f
        atomic_write_bytes(path, header.encode("ascii") + v.tobytes() + rec.tobytes())
    else:
        lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in v.tolist()]
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f.tolist()]
        atomic_write_text(path, "\n".join(lines) + "\n")
