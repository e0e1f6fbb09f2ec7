"""Point clouds (scans without faces): XYZ / TXT text, ``.npy``, faceless PLY and OBJ; a PLY writer.

:func:`load_points` reads a :class:`~ncflow.geometry.cloud.PointCloud` in the file's point order,
with the normals the file gives (float64, zero-length ones kept; all zero means none):

* ``.xyz`` / ``.txt``: one point a line, ``x y z`` or ``x y z nx ny nz``, separated by spaces,
  tabs or commas; ``#`` starts a comment, blank lines are skipped; every data line must have the
  same count of values, 3 or 6 (read by :func:`numpy.loadtxt`; a problem is then named by its line);
* ``.npy``: a float or integer array of shape (N, 3) or (N, 6), its header checked before the data
  is read, never a pickle (:func:`ncflow.io.files.read_npy_array`);
* ``.ply``: the vertex element of a PLY that declares no faces (``x y z`` and, when declared,
  ``nx ny nz``; ASCII or binary, read by :func:`ncflow.io.ply_properties.read_ply_vertex_properties`
  rather than trimesh, which keeps normals only under a private metadata key, as a dict of columns
  for ASCII files and a structured array for binary ones);
* ``.obj``: the ``v`` lines of an OBJ without ``f`` lines (colours after ``x y z`` skipped); the
  ``vn`` lines are the normals when there are as many as ``v`` lines.

:func:`is_point_cloud_file` tells a point cloud from a mesh without reading the data, and
:func:`load_target` reads either. :func:`save_points` writes a binary PLY that :func:`load_points`
reads back.

Hostile files: at most :data:`MAX_POINTS` points, text files at most :data:`MAX_TEXT_BYTES`, OBJ and
PLY files within their readers' limits; non-numbers, NaN and infinities are refused; a file never
makes ncflow open another. Every problem is one :class:`~ncflow.errors.InputError` line naming the
file (and the line of a text file); the cloud is checked by :func:`~ncflow.geometry.cloud.validate_cloud`.
"""

from __future__ import annotations

import io
import os
import re
import warnings
from pathlib import Path

import numpy as np

from ncflow.errors import InputError, first_line
from ncflow.geometry.cloud import PointCloud, validate_cloud
from ncflow.geometry.mesh import Mesh
from ncflow.io.atomic import atomic_write_bytes
from ncflow.io.files import check_input_file, check_regular_file, dtype_text, read_npy_array
from ncflow.io.meshes import load_mesh, save_mesh
from ncflow.io.obj import MAX_OBJ_BYTES, obj_lines, parse_numbers
from ncflow.io.ply_properties import MAX_HEADER_BYTES, read_ply_vertex_properties

POINT_SUFFIXES = (".xyz", ".txt", ".npy")
"""Suffixes of files that are always point clouds (a ``.ply`` or ``.obj`` is one when it has no faces)."""

MAX_POINTS = 5_000_000
"""Most points a point-cloud file may hold."""

MAX_TEXT_BYTES = 2**30
"""Largest ``.xyz`` / ``.txt`` file read (1 GiB)."""

_READ_SUFFIXES = (*POINT_SUFFIXES, ".ply", ".obj")
_FACE_ELEMENTS = ("face", "tristrips")
_OBJ_FACE = re.compile(rb"(?:^|[\r\n])[ \t]*f[ \t]")
_OBJ_VERTEX = re.compile(rb"(?:^|[\r\n])[ \t]*v[ \t]")


def _cloud(points: np.ndarray, normals: np.ndarray | None, path: Path) -> PointCloud:
    """The validated cloud; normals that are all zero become None."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    if normals is not None:
        normals = np.ascontiguousarray(normals, dtype=np.float64)
        if normals.shape == points.shape and not np.any(normals):
            normals = None
    validate_cloud(points, normals, name=str(path))
    return PointCloud(points=points, normals=normals, name=str(path))


def _split(table: np.ndarray, path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """(points, normals or None) of an (N, 3) or (N, 6) table."""
    if table.shape[0] > MAX_POINTS:
        raise InputError(f"{table.shape[0]} points, more than the limit of {MAX_POINTS}", path)
    return table[:, :3], (table[:, 3:] if table.shape[1] == 6 else None)


def _read_text(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    size = os.stat(path).st_size
    if size > MAX_TEXT_BYTES:
        raise InputError(f"is {size} bytes, more than the limit of {MAX_TEXT_BYTES}", path)
    try:
        text = path.read_bytes().decode("latin-1").replace(",", " ")  # only ASCII is parsed; any byte decodes
    except OSError as exc:
        raise InputError(f"cannot read file ({exc.strerror or first_line(exc)})", path) from None
    try:  # the fast path (NumPy's C reader); any problem is found and named by _text_problem
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "input contained no data"
            table = np.loadtxt(io.StringIO(text), np.float64, comments="#", ndmin=2, max_rows=MAX_POINTS + 1)
    except ValueError as exc:
        raise _text_problem(text, path, first_line(exc)) from None
    if table.shape[0] == 0 or table.shape[1] not in (3, 6) or not np.all(np.isfinite(table)):
        raise _text_problem(text, path, f"an array of shape {table.shape}")
    return _split(table, path)


def _text_problem(text: str, path: Path, fallback: str) -> InputError:
    """The first problem of a text point file, with its line number (read a line at a time: slow)."""
    width = count = 0
    for lineno, line in enumerate(text.splitlines(), start=1):
        row = line.split("#", 1)[0].split()
        if not row:
            continue
        count += 1
        if not width and len(row) not in (3, 6):
            return InputError(f"line {lineno}: {len(row)} values; expected 3 (x y z) or 6 (x y z nx ny nz)", path)
        if width and len(row) != width:
            return InputError(f"line {lineno}: {len(row)} values, but the first data line has {width}", path)
        width = len(row)
        for token in row:
            try:
                value = float(token)
            except ValueError:
                return InputError(f"line {lineno}: {token[:40]!r} is not a number", path)
            if not np.isfinite(value):
                return InputError(f"line {lineno}: {token[:40]!r} is NaN or infinite", path)
    if not count:
        return InputError("no points (an empty file, or only comments)", path)
    return InputError(f"cannot read points ({fallback[:100]})", path)


def _read_npy(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    from numpy.lib import format as npf

    try:
        with open(path, "rb") as fh:
            version = npf.read_magic(fh)
            read = npf.read_array_header_1_0 if version == (1, 0) else npf.read_array_header_2_0
            shape, _, dtype = read(fh)
    except Exception as exc:  # numpy raises ValueError, OSError, SyntaxError... for broken headers
        raise InputError(f"malformed .npy header ({first_line(exc)[:80]})", path) from None
    if dtype.hasobject or dtype.kind not in "fiu":
        raise InputError(f"a point array must hold floats or integers, not {dtype_text(dtype)}", path)
    if not (isinstance(shape, tuple) and len(shape) == 2 and shape[1] in (3, 6)):
        raise InputError(f"a point array must have shape (N, 3) or (N, 6), not {str(shape)[:40]}", path)
    if shape[0] > MAX_POINTS:
        raise InputError(f"{shape[0]} points, more than the limit of {MAX_POINTS}", path)
    table = read_npy_array(path, max_bytes=MAX_POINTS * 6 * dtype.itemsize).astype(np.float64)
    if not np.all(np.isfinite(table)):
        row = int(np.argmax(~np.all(np.isfinite(table), axis=1)))
        raise InputError(f"row {row} (0-based) has a NaN or infinite value", path)
    return _split(table, path)


def _ply_elements(path: Path) -> dict[str, int] | None:
    """Element name → declared count, from a PLY header (None when it is no readable PLY header)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(MAX_HEADER_BYTES)
    except OSError:
        return None
    if not head.startswith(b"ply") or b"end_header" not in head:
        return None
    elements: dict[str, int] = {}
    for line in head.split(b"end_header", 1)[0].decode("ascii", "replace").splitlines():
        tokens = line.split()
        if len(tokens) == 3 and tokens[0] == "element" and tokens[2].isdigit():
            elements.setdefault(tokens[1], int(tokens[2]))
    return elements


def _read_ply(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    elements = _ply_elements(path) or {}
    faces = sum(elements.get(e, 0) for e in _FACE_ELEMENTS)
    if faces:
        raise InputError(f"has {faces} faces: a mesh, not a point cloud", path)
    if elements.get("vertex", 0) > MAX_POINTS:
        raise InputError(f"{elements['vertex']} points, more than the limit of {MAX_POINTS}", path)
    props = read_ply_vertex_properties(path)
    missing = [c for c in "xyz" if c not in props.values]
    if missing:
        raise InputError(f"the vertex element has no {', '.join(missing)} property", path)
    points = np.stack([props.values[c].astype(np.float64) for c in "xyz"], axis=1)
    normals = None
    if all(c in props.values for c in ("nx", "ny", "nz")):
        normals = np.stack([props.values[c].astype(np.float64) for c in ("nx", "ny", "nz")], axis=1)
    return points, normals


def _read_obj(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    rows: dict[str, list[list[str]]] = {"v": [], "vn": []}
    for lineno, tokens in obj_lines(path):
        key = tokens[0]
        if key == "f":
            raise InputError(f"line {lineno}: a face ('f' line): a mesh, not a point cloud", path)
        if key in rows:
            if len(tokens) < 4:
                parse_numbers(tokens[1:], 3, 3, lineno, key, path)  # raises: too few numbers
            rows[key].append(tokens[1:4])
            if len(rows["v"]) > MAX_POINTS:
                raise InputError(f"more than {MAX_POINTS} points (the limit)", path)
    if not rows["v"]:
        raise InputError("no points ('v' lines)", path)
    try:
        points, normals = (np.array(rows[k], dtype=np.float64).reshape(-1, 3) for k in ("v", "vn"))
        if not (np.all(np.isfinite(points)) and np.all(np.isfinite(normals))):
            raise ValueError("a NaN or infinite value")
    except ValueError:  # find and name the line (slow)
        for lineno, tokens in obj_lines(path):
            if tokens[0] in rows:
                parse_numbers(tokens[1:], 3, 3, lineno, tokens[0], path)
        raise InputError("cannot read its 'v' and 'vn' lines", path) from None
    return points, (normals if normals.shape == points.shape else None)


def load_points(path: str | os.PathLike) -> PointCloud:
    """Read a point cloud from ``.xyz``, ``.txt``, ``.npy``, a faceless ``.ply`` or a faceless ``.obj``.

    Returns:
        The cloud: points (N, 3) float64 in the file's order, normals (N, 3) float64 as the file
        gives them (None when it gives none or only zero vectors), name the path.

    Raises:
        InputError: one line naming the file (and the line of a text file); see the module docstring.
    """
    path = Path(path)
    suffix = check_input_file(path, "point cloud", _READ_SUFFIXES)
    reader = {".npy": _read_npy, ".ply": _read_ply, ".obj": _read_obj}.get(suffix, _read_text)
    points, normals = reader(path)
    return _cloud(points, normals, path)


def _obj_is_cloud(path: Path) -> bool:
    """Whether an OBJ has ``v`` lines and no ``f`` lines (read in blocks of whole lines)."""
    if os.stat(path).st_size > MAX_OBJ_BYTES:
        return False
    has_vertex, rest = False, b""
    with open(path, "rb") as fh:
        while True:
            chunk = fh.read(1 << 22)
            block = rest + chunk
            cut = max(block.rfind(b"\n"), block.rfind(b"\r")) + 1 if chunk else len(block)
            block, rest = block[:cut], block[cut:]
            if _OBJ_FACE.search(block):
                return False
            has_vertex = has_vertex or _OBJ_VERTEX.search(block) is not None
            if not chunk:
                return has_vertex


def is_point_cloud_file(path: str | os.PathLike) -> bool:
    """Whether ``path`` names a point cloud: a :data:`POINT_SUFFIXES` file, a PLY whose header declares
    no faces, or an OBJ with ``v`` lines and no ``f`` lines. False for other files and unreadable ones.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in POINT_SUFFIXES:
        return True
    if suffix not in (".ply", ".obj"):
        return False
    try:
        check_regular_file(path, "mesh")
        if suffix == ".obj":
            return _obj_is_cloud(path)
    except (InputError, OSError):
        return False
    elements = _ply_elements(path)
    return elements is not None and not any(elements.get(e, 0) for e in _FACE_ELEMENTS)


def load_target(path: str | os.PathLike) -> Mesh | PointCloud:
    """A point cloud (:func:`load_points`) when :func:`is_point_cloud_file`, else a mesh
    (:func:`ncflow.io.meshes.load_mesh`).
    """
    if is_point_cloud_file(path):
        return load_points(path)
    return load_mesh(path)


def save_points(path: str | os.PathLike, points: np.ndarray, normals: np.ndarray | None = None) -> None:
    """Write points (N, 3) and, when given, normals (N, 3) as a binary little-endian PLY of float32
    ``x y z [nx ny nz]`` with only a vertex element, atomically; its folder is created.

    Raises:
        InputError: wrong shapes or non-finite values (nothing is written).
    """
    p = np.asarray(points, dtype=np.float64)
    columns = [p] if normals is None else [p, np.asarray(normals, dtype=np.float64)]
    if any(c.ndim != 2 or c.shape != (p.shape[0], 3) for c in columns):
        raise InputError(f"points and normals must be (N, 3), got {[c.shape for c in columns]}", path)
    table = np.concatenate(columns, axis=1)
    if not np.all(np.isfinite(table)) or np.any(np.abs(table) > np.finfo(np.float32).max):
        raise InputError("refusing to write non-finite (or beyond float32) points or normals", path)
    names = ["x", "y", "z"] + ([] if normals is None else ["nx", "ny", "nz"])
    header = ["ply", "format binary_little_endian 1.0", "comment written by ncflow", f"element vertex {p.shape[0]}"]
    header += [f"property float {n}" for n in names] + ["end_header"]
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    data = ("\n".join(header) + "\n").encode("ascii") + np.ascontiguousarray(table, dtype="<f4").tobytes()
    atomic_write_bytes(path, data)


def save_target(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Write a match's target as given: a mesh (:func:`ncflow.io.meshes.save_mesh`), or without faces a
    point cloud (:func:`save_points`), which :func:`load_target` reads back as one.
    """
    if np.asarray(faces).size == 0:
        save_points(path, vertices)
    else:
        save_mesh(path, vertices, faces)
