"""Reading and writing triangle meshes: OBJ, PLY, OFF, STL and glTF/GLB (through trimesh).

:func:`load_mesh` never reorders vertices. Exactly coincident vertices are merged ("welded") only
for the formats that store split vertices by construction (STL triangle soups, glTF/GLB seam
duplicates), or when asked, and the map back to the file's vertices is kept in
:attr:`~ncflow.geometry.mesh.Mesh.file_index`. OBJ files are read by :func:`ncflow.io.obj.read_obj`
(trimesh would split their vertices by material), the other formats through trimesh. Polygons
(quads from a modelling package) are split into triangles without new vertices, and said so:
:attr:`~ncflow.geometry.mesh.Mesh.notes` counts them (OFF and ASCII PLY face sizes are read before
trimesh splits them; a binary PLY is counted by its header's face count), and the matcher repeats
it as a warning. Every mesh is validated
(:func:`~ncflow.geometry.mesh.validate_mesh`). :func:`save_mesh` is the one mesh writer: by suffix,
in the given vertex order, atomically, at float32 (through trimesh) or float64 precision.

Hostile files: materials and textures are never loaded (ncflow needs only the geometry), and the
resources a file names (glTF buffers) are read through a resolver confined to the file's folder
(:func:`ncflow.io.files.read_confined`: no ``..``, absolute paths, schemes, links out of the folder
or special files). A glTF/GLB is checked from its JSON before trimesh decodes it: every accessor
must fit in its buffer (:func:`~ncflow.io.gltf.document.check_accessor_sizes`), and the scene may
instance meshes at most :data:`MAX_MESH_INSTANCES` times with at most :data:`MAX_MESH_TRIANGLES`
triangles in all; the same limits are checked on the loaded scene of every format before its
instances are merged into one mesh.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError, first_line
from ncflow.geometry.mesh import Mesh, _check_finite_and_range, validate_mesh, weld_vertices
from ncflow.io.atomic import atomic_path, atomic_write_bytes, atomic_write_text
from ncflow.io.files import MAX_ARRAY_BYTES, check_input_file, read_confined
from ncflow.io.gltf.document import (
    DocumentReader,
    check_accessor_sizes,
    get_field,
    load_document,
    malformed,
    node_hierarchy,
)
from ncflow.io.obj import read_obj

MESH_SUFFIXES = (".obj", ".ply", ".off", ".stl", ".glb", ".gltf")

MAX_MESH_INSTANCES = 1_000
"""Most mesh (primitive) instances a scene file may place (glTF nodes sharing a mesh count once each)."""

MAX_MESH_TRIANGLES = 10_000_000
"""Most triangles a mesh file may give, all instances counted."""


_WELD_BY_DEFAULT = (".stl", ".glb", ".gltf")


def _declared_polygon_sizes(path: Path) -> np.ndarray | None:
    """Number of corners of every face as written in an OFF or ASCII-PLY file (None if unknown)."""
    suffix = path.suffix.lower()
    try:
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
            header = _ply_header(path)
            if "format ascii" not in header:
                return None
            nv, nf = _ply_count(header, "vertex"), _ply_count(header, "face")
            if nv is None or nf is None:
                return None
            with open(path, errors="replace") as fh:
                body = fh.read().split("end_header", 1)[1].strip().splitlines()
            return np.asarray([int(ln.split()[0]) for ln in body[nv : nv + nf]], dtype=np.int64)
    except (OSError, ValueError, IndexError, OverflowError):
        return None
    return None


def _ply_header(path: Path) -> str:
    """The text of a PLY file's header (up to ``end_header`` within its first 4 kB; empty if unreadable)."""
    try:
        with open(path, "rb") as fh:
            return fh.read(4096).split(b"end_header")[0].decode("ascii", "replace")
    except OSError:
        return ""


def _ply_count(header: str, element: str) -> int | None:
    """The count a PLY header declares for ``element`` (None if it declares none)."""
    found = re.search(rf"element {element} (\d+)", header)
    return int(found.group(1)) if found else None


def _confined_resolver(path: Path):
    """A trimesh resolver that reads only regular files inside ``path``'s folder (refusals are kept)."""
    import trimesh.resolvers

    class ConfinedResolver(trimesh.resolvers.Resolver):
        """Resources of one mesh file, confined to its folder (:func:`~ncflow.io.files.read_confined`)."""

        def __init__(self, folder: Path, prefix: str, unquote: bool):
            self.folder, self.prefix, self.unquote = folder, prefix, unquote
            self.refused: list[str] = []

        def get(self, name):
            name = str(name)
            try:
                return read_confined(
                    self.folder, os.path.join(self.prefix, name), MAX_ARRAY_BYTES, unquote=self.unquote
                )
            except ValueError as exc:
                self.refused.append(f"refusing external file {name[:80]!r} ({exc})")
                raise FileNotFoundError(name) from None

        def namespaced(self, namespace):
            return ConfinedResolver(self.folder, os.path.join(self.prefix, str(namespace)), self.unquote)

        def keys(self):
            return iter(())

        def write(self, name, data):
            raise PermissionError("ncflow does not write beside input meshes")

    return ConfinedResolver(path.parent, "", path.suffix.lower() == ".gltf")


def _primitive_triangles(doc, prim) -> int:
    """Triangles a primitive makes, from its accessor counts (0 for points and lines)."""
    mode = get_field(prim, "mode")
    mode = 4 if mode is None else mode
    if mode not in (4, 5, 6):
        return 0
    accessors = doc.accessors or []
    index = get_field(prim, "indices")
    if index is None:
        index = get_field(get_field(prim, "attributes"), "POSITION")
    if not isinstance(index, int) or not 0 <= index < len(accessors):
        return 0
    n = int(get_field(accessors[index], "count", 0) or 0)
    return n // 3 if mode == 4 else max(n - 2, 0)


def mesh_instance_counts(doc) -> tuple[int, int]:
    """(mesh primitive instances, triangles after instancing) over every node of a document with a mesh."""
    meshes = doc.meshes or []
    per_mesh = {}
    instances = triangles = 0
    for node in doc.nodes or []:
        m = get_field(node, "mesh")
        if not isinstance(m, int) or not 0 <= m < len(meshes):
            continue
        if m not in per_mesh:
            prims = get_field(meshes[m], "primitives") or []
            per_mesh[m] = (len(prims), sum(_primitive_triangles(doc, p) for p in prims))
        instances += per_mesh[m][0]
        triangles += per_mesh[m][1]
    return instances, triangles


def _check_gltf_before_loading(path: Path) -> None:
    """Accessor sizes, resource URIs (:func:`~ncflow.io.gltf.document.load_document`), the node forest and
    instance counts of a glTF/GLB, from its JSON (nothing decoded).
    """
    doc = load_document(path)
    reader = DocumentReader(doc, path)
    with malformed(path):
        check_accessor_sizes(doc, reader)
        node_hierarchy(doc, reader)  # a forest: no cycles or shared children for trimesh to walk
        _check_instances(*mesh_instance_counts(doc), path)


def _check_instances(instances: int, triangles: int, path: Path) -> None:
    """InputError beyond :data:`MAX_MESH_INSTANCES` instances or :data:`MAX_MESH_TRIANGLES` triangles."""
    if instances > MAX_MESH_INSTANCES:
        raise InputError(f"the scene places {instances} mesh instances, more than {MAX_MESH_INSTANCES}", path)
    if triangles > MAX_MESH_TRIANGLES:
        raise InputError(
            f"the scene has {triangles} triangles (instances counted), more than {MAX_MESH_TRIANGLES}", path
        )


def _scene_to_mesh(scene, path: Path):
    """One mesh from a loaded trimesh scene, after checking its instance and triangle counts."""
    nodes = list(scene.graph.nodes_geometry)
    triangles = 0
    for node in nodes:
        geometry = scene.geometry.get(scene.graph[node][1])
        triangles += len(getattr(geometry, "faces", ()))
    _check_instances(len(nodes), triangles, path)
    to_mesh = getattr(scene, "to_mesh", None)  # trimesh >= 4.5; older: dump(concatenate=True)
    return to_mesh() if to_mesh is not None else scene.dump(concatenate=True)


def _load_trimesh(path: Path, suffix: str):
    """The file through trimesh as one mesh (no materials, confined resources, instance limits)."""
    import trimesh

    if suffix in (".gltf", ".glb"):
        _check_gltf_before_loading(path)
    resolver = _confined_resolver(path)
    try:
        scene = trimesh.load(
            str(path), force="scene", resolver=resolver, skip_materials=True, process=False, maintain_order=True
        )
        return _scene_to_mesh(scene, path)
    except InputError:
        raise
    except Exception:
        if resolver.refused:
            raise InputError(resolver.refused[0], path) from None
        raise


def _mesh_arrays(loaded, path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3) float64, faces int64) of what trimesh loaded; InputError for other shapes."""
    try:
        vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64)
        faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    except (TypeError, ValueError, OverflowError) as exc:
        raise InputError(f"cannot read mesh ({first_line(exc)[:100]})", path) from None
    if vertices.size == 0:
        vertices = vertices.reshape(0, 3)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise InputError(f"vertices must have 3 coordinates, got an array of shape {vertices.shape}", path)
    return vertices, faces


def _trimesh_or_error(path: Path, suffix: str, sizes: np.ndarray | None):
    """:func:`_load_trimesh`, its many kinds of errors turned into one-line InputErrors."""
    try:
        return _load_trimesh(path, suffix)
    except InputError:
        raise
    except IndexError:
        raise InputError("cannot read mesh (corrupt or truncated file)", path) from None
    except Exception as exc:  # trimesh raises many kinds of errors for broken files
        msg = first_line(exc)
        if "outside the range" in msg or "out of bounds" in msg:
            raise InputError("face index out of range", path) from None
        if suffix == ".off" and sizes is not None and np.any(sizes > 3) and np.unique(sizes).size > 1:
            raise InputError(
                "polygons of several sizes in an OFF file, which trimesh cannot split; triangulate the mesh first",
                path,
            ) from None
        raise InputError(f"cannot read mesh ({msg[:100]})", path) from None


def load_mesh(path: str | os.PathLike, *, weld: bool | None = None, validate: bool = True) -> Mesh:
    """Read a triangle mesh from OBJ, PLY, OFF, STL, glTF or GLB (polygons split into triangles,
    counted in :attr:`~ncflow.geometry.mesh.Mesh.notes`).

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
    path = Path(path)
    suffix = check_input_file(path, "mesh", MESH_SUFFIXES)
    if suffix == ".obj":
        vertices, faces, sizes = read_obj(path)
    else:
        sizes = _declared_polygon_sizes(path)
        if sizes is not None and np.any(sizes < 3):
            bad = sizes[sizes < 3]
            raise InputError(f"{bad.size} of {sizes.size} faces have fewer than 3 corners (first: {int(bad[0])})", path)
        vertices, faces = _mesh_arrays(_trimesh_or_error(path, suffix, sizes), path)
    polygons = 0 if sizes is None else int(np.sum(sizes > 3))
    if faces.size == 0:
        raise InputError("no faces (a point cloud or an empty file?)", path)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise InputError(f"non-triangular faces (shape {faces.shape})", path)
    notes = ()
    split = (
        "(a quad along the diagonal from its first corner, larger polygons as fans from it); the outputs use the "
        "triangles"
    )
    declared = _ply_count(_ply_header(path), "face") if sizes is None and suffix == ".ply" else None
    if declared is not None and faces.shape[0] > declared:  # a binary PLY: its polygons' sizes unread
        notes = (f"its {declared} faces became {faces.shape[0]} triangles: polygons split {split}",)
    if polygons:
        if faces.shape[0] != int(np.sum(sizes - 2)):
            raise InputError(f"cannot split its {polygons} polygon faces into triangles", path)
        kinds = np.unique(sizes[sizes > 3])
        shown = ", ".join(str(k) for k in kinds[:5].tolist()) + (", ..." if kinds.size > 5 else "")
        notes = (f"{polygons} of {sizes.size} faces have [{shown}] corners: split into triangles {split}",)
    file_index = np.arange(vertices.shape[0])
    if weld is None:
        weld = suffix in _WELD_BY_DEFAULT
    if validate:
        _check_finite_and_range(vertices, faces, str(path))
    if weld:
        vertices, faces, file_index = weld_vertices(vertices, faces)
    mesh = Mesh(vertices=vertices, faces=faces, name=str(path), file_index=file_index, notes=notes)
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
