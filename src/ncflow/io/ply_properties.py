"""PLY files with per-vertex properties (colours, labels, scalars): read the vertex element, write a mesh with them.

:func:`read_ply_vertex_properties` reads every scalar property of a PLY file's ``vertex``
element — positions, normals, ``red``/``green``/``blue``/``alpha``, an integer ``label``, a float
``quality`` … — with its name, its PLY type and its values in the file's vertex order.
:func:`write_ply_properties` writes a triangle mesh with chosen vertex properties as binary
little-endian PLY.

Written here rather than read through trimesh: trimesh turns colours into RGBA bytes (adding an
alpha channel and losing float colours' type) and keeps the other properties only under a private
metadata key, while a transfer needs each property as written: its name, its type (integer
properties are labels, float properties values) and the file's vertex order.

Supported: ``format ascii 1.0``, ``binary_little_endian 1.0`` and ``binary_big_endian 1.0``;
the ``vertex`` element must be the first element (as every writer puts it) and hold scalar
properties only; types ``char uchar short ushort int uint float double`` and their sized aliases
(``int8`` … ``float64``). Only the vertex element is read; the faces that follow are not needed.

Hostile files: the header is at most :data:`MAX_HEADER_BYTES`, at most :data:`MAX_PROPERTIES`
properties, the vertex count is checked against the bytes the file holds before anything is
allocated, ASCII rows must have one number per property, integer properties must hold integers in
their type's range and float properties finite numbers. Each problem is one
:class:`~ncflow.errors.InputError` line naming the file.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError, ResultError, first_line
from ncflow.io.arrays import as_faces, check_finite
from ncflow.io.atomic import atomic_write_bytes
from ncflow.io.files import check_input_file

MAX_HEADER_BYTES = 65536
"""Longest PLY header read (bytes up to and including ``end_header``)."""

MAX_PROPERTIES = 256
"""Most properties the vertex element may declare."""

MAX_PLY_BYTES = 2**31
"""Largest PLY file read (2 GiB)."""

# PLY type name -> (canonical name, NumPy type code without byte order)
PLY_TYPES = {
    "char": ("char", "i1"),
    "int8": ("char", "i1"),
    "uchar": ("uchar", "u1"),
    "uint8": ("uchar", "u1"),
    "short": ("short", "i2"),
    "int16": ("short", "i2"),
    "ushort": ("ushort", "u2"),
    "uint16": ("ushort", "u2"),
    "int": ("int", "i4"),
    "int32": ("int", "i4"),
    "uint": ("uint", "u4"),
    "uint32": ("uint", "u4"),
    "float": ("float", "f4"),
    "float32": ("float", "f4"),
    "double": ("double", "f8"),
    "float64": ("double", "f8"),
}
_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}


@dataclasses.dataclass(frozen=True, eq=False)
class PlyVertexProperties:
    """The scalar properties of a PLY file's vertex element, in the file's order.

    Attributes:
        n_vertices: the vertex count.
        names: property names, as declared.
        types: their canonical PLY types (``uchar``, ``int``, ``float``, …).
        values: name → (n_vertices,) array of the type's NumPy dtype (native byte order).
    """

    n_vertices: int
    names: tuple[str, ...]
    types: tuple[str, ...]
    values: dict[str, np.ndarray]


def _read_header(path: Path) -> tuple[str, int, list[tuple[str, str]], int]:
    """(format, vertex count, [(name, canonical type)], byte offset of the data)."""
    with open(path, "rb") as fh:
        head = fh.read(MAX_HEADER_BYTES)
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        why = (
            "not a PLY file" if not head.startswith(b"ply") else f"no end_header in its first {MAX_HEADER_BYTES} bytes"
        )
        raise InputError(f"cannot read PLY ({why})", path)
    newline = head.find(b"\n", end)
    if newline < 0 or head[end + len(b"end_header") : newline].strip():
        raise InputError("cannot read PLY (malformed end_header line)", path)
    try:
        lines = head[:end].decode("ascii").splitlines()
    except UnicodeDecodeError:
        raise InputError("cannot read PLY (the header is not ASCII text)", path) from None
    fmt = None
    elements: list[tuple[str, int, list[tuple[str, str]]]] = []
    for lineno, line in enumerate(lines[1:], start=2):
        tokens = line.split()
        if not tokens or tokens[0] in ("comment", "obj_info"):
            continue
        key = tokens[0]
        if key == "format":
            if len(tokens) != 3 or tokens[1] not in _FORMATS or tokens[2] != "1.0":
                raise InputError(f"header line {lineno}: unsupported format {' '.join(tokens[1:])[:60]!r}", path)
            fmt = tokens[1]
        elif key == "element":
            if len(tokens) != 3 or not tokens[2].isdigit() or int(tokens[2]) > 2**40:
                raise InputError(f"header line {lineno}: malformed element line {line[:60]!r}", path)
            elements.append((tokens[1], int(tokens[2]), []))
        elif key == "property":
            if not elements:
                raise InputError(f"header line {lineno}: a property before any element", path)
            name, count, props = elements[-1]
            if len(tokens) == 5 and tokens[1] == "list":
                props.append((tokens[4], "list"))
            elif len(tokens) == 3 and tokens[1] in PLY_TYPES:
                props.append((tokens[2], PLY_TYPES[tokens[1]][0]))
            else:
                raise InputError(f"header line {lineno}: malformed property line {line[:60]!r}", path)
        else:
            raise InputError(f"header line {lineno}: unknown keyword {key[:40]!r}", path)
    if fmt is None:
        raise InputError("cannot read PLY (no format line)", path)
    if not elements or elements[0][0] != "vertex":
        raise InputError("the vertex element must be the first element of the PLY header", path)
    _, n, props = elements[0]
    names = [p for p, _ in props]
    if any(t == "list" for _, t in props):
        raise InputError("the vertex element has a list property; only scalar vertex properties are read", path)
    if not props or len(props) > MAX_PROPERTIES:
        raise InputError(f"the vertex element must declare 1 to {MAX_PROPERTIES} properties, got {len(props)}", path)
    if len(set(names)) != len(names):
        raise InputError("the vertex element declares a property name twice", path)
    return fmt, n, props, newline + 1


def read_ply_vertex_properties(path: str | os.PathLike) -> PlyVertexProperties:
    """Every scalar property of the vertex element of a PLY file (see the module docstring).

    Raises:
        InputError: one line naming the file.
    """
    path = Path(path)
    check_input_file(path, "PLY", (".ply",))
    size = os.stat(path).st_size
    if size > MAX_PLY_BYTES:
        raise InputError(f"is {size} bytes, more than the limit of {MAX_PLY_BYTES}", path)
    fmt, n, props, offset = _read_header(path)
    codes = [PLY_TYPES[t][1] for _, t in props]
    try:
        if _FORMATS[fmt] is None:
            table = _read_ascii_rows(path, offset, size, n, props)
        else:
            dtype = np.dtype([(f"p{k}", _FORMATS[fmt] + c) for k, c in enumerate(codes)])
            if n * dtype.itemsize > size - offset:
                raise InputError(f"truncated: {n} vertices need {n * dtype.itemsize} bytes after the header", path)
            with open(path, "rb") as fh:
                fh.seek(offset)
                data = fh.read(n * dtype.itemsize)
            rec = np.frombuffer(data, dtype=dtype, count=n)
            table = [rec[f"p{k}"].astype(c) for k, c in enumerate(codes)]
    except OSError as exc:
        raise InputError(f"cannot read file ({exc.strerror or first_line(exc)})", path) from None
    values = {}
    for (name, _), column in zip(props, table):
        if column.dtype.kind == "f" and not np.all(np.isfinite(column)):
            bad = int(np.argmax(~np.isfinite(column)))
            raise InputError(f"property {name[:40]!r} is NaN or infinite (first at vertex {bad}, 0-based)", path)
        values[name] = column
    return PlyVertexProperties(
        n_vertices=n, names=tuple(p for p, _ in props), types=tuple(t for _, t in props), values=values
    )


def _read_ascii_rows(path: Path, offset: int, size: int, n: int, props: list[tuple[str, str]]) -> list[np.ndarray]:
    """The vertex rows of an ASCII PLY as one array per property."""
    k = len(props)
    if 2 * n * k > size - offset:  # every value takes at least a digit and a separator
        raise InputError(f"truncated: {n} vertices of {k} values cannot fit in the file", path)
    table = np.zeros((n, k), dtype=np.float64)
    row = 0
    with open(path, "rb") as fh:
        fh.seek(offset)
        for raw in fh:
            if row == n:
                break
            tokens = raw.split()
            if not tokens:
                continue
            if len(tokens) != k:
                raise InputError(f"vertex {row}: {len(tokens)} values, but the header declares {k} properties", path)
            try:
                table[row] = [float(t) for t in tokens]
            except ValueError:
                raise InputError(f"vertex {row}: a value is not a number", path) from None
            row += 1
    if row != n:
        raise InputError(f"truncated: {row} of {n} vertex rows", path)
    out = []
    for j, (name, ptype) in enumerate(props):
        col = table[:, j]
        code = PLY_TYPES[ptype][1]
        if code[0] in "iu":
            info = np.iinfo(code)
            bad = ~np.isfinite(col) | (col != np.round(col)) | (col < info.min) | (col > info.max)
            if np.any(bad):
                v = int(np.argmax(bad))
                raise InputError(
                    f"property {name[:40]!r} ({ptype}) at vertex {v}: {col[v]:g} is not an integer in "
                    f"[{info.min}, {info.max}]",
                    path,
                )
        elif np.any(bad := ~(np.abs(col) <= np.finfo(code).max)):
            v = int(np.argmax(bad))
            raise InputError(
                f"property {name[:40]!r} ({ptype}) at vertex {v}: {col[v]:g} is not a finite {ptype}", path
            )
        out.append(col.astype(code))
    return out


def write_ply_properties(
    path: str | os.PathLike,
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    properties: list[tuple[str, str, np.ndarray]],
) -> None:
    """Write a triangle mesh with extra vertex properties as binary little-endian PLY, atomically.

    Args:
        path: the file.
        vertices: (V, 3) positions (written as ``float``).
        faces: (F, 3) triangles (``list uchar int vertex_indices``).
        properties: (name, PLY type, (V,) values) per extra vertex property, written after
            ``x y z`` in this order; values are cast to the type.

    Raises:
        ResultError: non-finite values, wrong shapes or indices out of range (nothing is written).
        InputError: a property name that is not one word or an unknown type.
    """
    v = np.asarray(vertices, dtype=np.float64)
    check_finite("vertices", v)
    nv = v.shape[0]
    f = as_faces(faces, nv, "faces")
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    header = ["ply", "format binary_little_endian 1.0", "comment written by ncflow transfer", f"element vertex {nv}"]
    header += [f"property float {c}" for c in "xyz"]
    for name, ptype, values in properties:
        if ptype not in PLY_TYPES or not name or len(name.split()) != 1 or name in ("x", "y", "z"):
            raise InputError(f"cannot write PLY property {name[:40]!r} of type {ptype[:20]!r}", path)
        arr = np.asarray(values)
        if arr.shape != (nv,):
            raise ResultError(f"property {name!r} must have one value per vertex ({nv}), got shape {arr.shape}")
        check_finite(f"property {name!r}", arr)
        fields.append((name, "<" + PLY_TYPES[ptype][1]))
        header.append(f"property {PLY_TYPES[ptype][0]} {name}")
    header += [f"element face {f.shape[0]}", "property list uchar int vertex_indices", "end_header"]
    rec = np.zeros(nv, dtype=fields)
    rec["x"], rec["y"], rec["z"] = v[:, 0], v[:, 1], v[:, 2]
    for name, _, values in properties:
        rec[name] = np.asarray(values)
    tri = np.zeros(f.shape[0], dtype=[("n", "u1"), ("idx", "<i4", (3,))])
    tri["n"] = 3
    tri["idx"] = f
    atomic_write_bytes(path, ("\n".join(header) + "\n").encode("ascii") + rec.tobytes() + tri.tobytes())
