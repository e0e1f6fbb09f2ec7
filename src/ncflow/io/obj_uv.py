"""Wavefront OBJ with face-varying texture coordinates (UVs): read and write, seams kept.

A textured OBJ lists positions (``v x y z``), texture coordinates (``vt u v``) and faces
whose corners name both (``f v/vt v/vt v/vt``, or ``v/vt/vn``; polygons are split into triangles
as :mod:`ncflow.io.obj` splits them, each corner keeping its UV). One vertex may carry different
UVs in different faces: that is a UV seam, and it must survive. :class:`TexturedMesh` therefore
keeps the UVs per face corner (``uv_faces`` (F, 3) into ``uvs`` (T, 2)) and the vertices and
faces exactly in the file's order.

Written here rather than read through trimesh: trimesh keeps one UV per vertex (the UVs of a
seam vertex are merged, or the vertex is split and the file's vertex order and count are lost),
and the transfer needs the file's vertices and the corners' UVs as written. Everything else a
textured OBJ may hold (normals, groups, materials, smoothing groups, lines, points) is skipped;
no material library or texture is opened.

Hostile files: the file size is limited (:data:`~ncflow.io.obj.MAX_OBJ_BYTES`), faces need at
least 3 corners, every corner must name a texture coordinate, indices (1-based, or negative = relative to the end, as
the format allows) must lie in range, and coordinates must be finite numbers. Each problem is one
:class:`~ncflow.errors.InputError` line naming the file and the line.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError
from ncflow.io.arrays import as_faces, check_finite
from ncflow.io.atomic import atomic_write_text
from ncflow.io.files import check_input_file
from ncflow.io.obj import check_indices, obj_lines, parse_index, parse_numbers


@dataclasses.dataclass(frozen=True, eq=False)
class TexturedMesh:
    """A triangle mesh with face-varying texture coordinates.

    Attributes:
        vertices: (V, 3) positions, in the file's order.
        faces: (F, 3) 0-based vertex indices, in the file's order.
        uvs: (T, 2) texture coordinates (u, v).
        uv_faces: (F, 3) 0-based indices into ``uvs`` of every face corner.
    """

    vertices: Float[np.ndarray, "V 3"]
    faces: Int[np.ndarray, "F 3"]
    uvs: Float[np.ndarray, "T 2"]
    uv_faces: Int[np.ndarray, "F 3"]


def read_obj_uv(path: str | os.PathLike) -> TexturedMesh:
    """Read an OBJ whose every face corner names a texture coordinate (``f v/vt ...``); polygons are
    split as :func:`~ncflow.io.obj.read_obj` splits them (fans from their first corner, in the file's
    order), so the faces are those of the mesh the match read.

    Returns:
        The :class:`TexturedMesh`: vertices and faces in the file's order, the corners' UVs.

    Raises:
        InputError: one line naming the file (and the line): too large, unreadable, a face of fewer
            than 3 corners, a corner without a texture coordinate, an index out of range, a
            non-number, NaN, no faces.
    """
    path = Path(path)
    check_input_file(path, "textured mesh", (".obj",))
    vertices: list[list[float]] = []
    uvs: list[list[float]] = []
    faces: list[list[int]] = []
    uv_faces: list[list[int]] = []
    face_lines: list[int] = []
    for lineno, tokens in obj_lines(path):  # the lines :func:`~ncflow.io.obj.read_obj` reads, read alike
        key = tokens[0]
        if key == "v":
            vertices.append(parse_numbers(tokens[1:], 3, 3, lineno, "v", path))
        elif key == "vt":
            uv = parse_numbers(tokens[1:], 1, 2, lineno, "vt", path)
            uvs.append(uv if len(uv) == 2 else [uv[0], 0.0])
        elif key == "f":
            corners = tokens[1:]
            if len(corners) < 3:
                raise InputError(f"line {lineno}: a face of {len(corners)} corners (at least 3 needed)", path)
            fv, ft = [], []
            for corner in corners:
                parts = corner.split("/")
                if len(parts) < 2 or not parts[1]:
                    raise InputError(
                        f"line {lineno}: face corner {corner[:40]!r} has no texture coordinate "
                        "(every corner needs v/vt)",
                        path,
                    )
                fv.append(parse_index(parts[0], len(vertices), lineno, "vertex", path))
                ft.append(parse_index(parts[1], len(uvs), lineno, "texture coordinate", path))
            for k in range(1, len(fv) - 1):  # a polygon as read_obj splits it: a fan from its first corner
                faces.append([fv[0], fv[k], fv[k + 1]])
                uv_faces.append([ft[0], ft[k], ft[k + 1]])
                face_lines.append(lineno)
    if not faces:
        raise InputError("no faces", path)
    f, ft = np.asarray(faces, dtype=np.int64), np.asarray(uv_faces, dtype=np.int64)
    check_indices(f, len(vertices), face_lines, "vertex", path)
    check_indices(ft, len(uvs), face_lines, "texture coordinate", path)
    return TexturedMesh(
        vertices=np.asarray(vertices, dtype=np.float64).reshape(-1, 3),
        faces=f,
        uvs=np.asarray(uvs, dtype=np.float64).reshape(-1, 2),
        uv_faces=ft,
    )


def write_obj_uv(
    path: str | os.PathLike,
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    uvs: Float[np.ndarray, "T 2"],
    uv_faces: Int[np.ndarray, "F 3"],
) -> None:
    """Write a triangle OBJ with face-varying UVs (``f v/vt v/vt v/vt``), atomically.

    Coordinates are written with 17 significant digits (they read back bit for bit).

    Raises:
        ResultError: non-finite coordinates or indices out of range (nothing is written).
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(uvs, dtype=np.float64)
    check_finite("vertices", v)
    check_finite("texture coordinates", t)
    f = as_faces(faces, v.shape[0], "faces") + 1
    ft = as_faces(uv_faces, t.shape[0], "texture-coordinate faces") + 1
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in v.tolist()]
    lines += [f"vt {a!r} {b!r}" for a, b in t.tolist()]
    lines += [f"f {a}/{p} {b}/{q} {c}/{r}" for (a, b, c), (p, q, r) in zip(f.tolist(), ft.tolist())]
    atomic_write_text(path, "\n".join(lines) + "\n")
