"""Wavefront OBJ geometry: positions and faces, in the file's order (polygons split into triangles).

Read here rather than through trimesh: trimesh splits an OBJ's vertices by material (``usemtl``) and
by normal or texture seams, so the vertices it returns are not the file's (a triangle OBJ of 5
vertices with two materials came back with 10, its faces reordered), and the output maps, which
number the file's vertices, would be wrong. Only ``v`` and ``f`` lines are read: a vertex is its
first three numbers (colours after them are skipped); a face corner is its position index
(``v``, ``v/vt``, ``v//vn``, ``v/vt/vn``; negative indices count back from the vertices read so far,
as the format allows); a polygon of k corners becomes the k − 2 triangles of a fan from its first
corner, in the file's order. Everything else (normals, texture coordinates, groups, objects,
materials, smoothing groups, lines, points) is skipped, and no material library or texture is
opened. ``#`` starts a comment anywhere on a line, and a line ending in a backslash continues on the next.

Hostile files: the file size is limited (:data:`MAX_OBJ_BYTES`) and read a line at a time as Latin-1
(only ASCII is parsed, and any byte decodes), indices must lie in range and coordinates must be
finite numbers; each problem is one :class:`~ncflow.errors.InputError` line naming the file and the
line.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ncflow.errors import InputError, first_line
from ncflow.io.files import check_input_file

MAX_OBJ_BYTES = 2**30
"""Largest OBJ file read (1 GiB)."""


def parse_numbers(tokens: list[str], lo: int, hi: int, lineno: int, what: str, path) -> list[float]:
    """The first ``hi`` numbers of ``tokens`` (at least ``lo``), finite; InputError otherwise."""
    if len(tokens) < lo:
        raise InputError(f"line {lineno}: '{what}' needs at least {lo} numbers, got {len(tokens)}", path)
    try:
        values = [float(t) for t in tokens[:hi]]
    except ValueError:
        raise InputError(f"line {lineno}: '{what}' has a value that is not a number", path) from None
    if not all(np.isfinite(values)):
        raise InputError(f"line {lineno}: '{what}' has a NaN or infinite value", path)
    return values


def parse_index(token: str, count: int, lineno: int, what: str, path) -> int:
    """A 1-based OBJ index as 0-based; a negative one counts back from the ``count`` items read so far.

    The upper bound of positive indices is checked once the whole file is read.
    """
    try:
        i = int(token)
    except ValueError:
        raise InputError(f"line {lineno}: {what} index {token[:40]!r} is not an integer", path) from None
    k = i - 1 if i > 0 else count + i
    if i == 0 or not 0 <= k < 2**40:
        raise InputError(f"line {lineno}: {what} index {token[:40]} is out of range", path)
    return k


def check_indices(index: np.ndarray, count: int, lines: list[int], what: str, path) -> None:
    """InputError naming the first face line whose ``what`` index is at least ``count``."""
    bad = np.any(index >= count, axis=1)
    if np.any(bad):
        k = int(np.argmax(bad))
        raise InputError(
            f"line {lines[k]}: {what} index {int(index[k].max()) + 1} is out of range (the file has {count} "
            f"{what}s; {int(bad.sum())} faces affected)",
            path,
        )


def obj_lines(path: Path):
    """(line number, tokens) of every line with content: comments cut, continuations joined. Read a
    line at a time (memory: one line), with any of the usual line endings, as Latin-1: only ASCII is
    parsed, and every byte decodes.
    """
    size = os.stat(path).st_size
    if size > MAX_OBJ_BYTES:
        raise InputError(f"is {size} bytes, more than the limit of {MAX_OBJ_BYTES}", path)
    pending: list[str] = []
    lineno = 0
    try:
        with open(path, encoding="latin-1") as fh:
            for lineno, line in enumerate(fh, start=1):
                line = line.split("#", 1)[0].rstrip()
                if line.endswith("\\"):
                    pending.append(line[:-1])
                    continue
                tokens = " ".join([*pending, line]).split()
                pending = []
                if tokens:
                    yield lineno, tokens
    except OSError as exc:
        raise InputError(f"cannot read file ({exc.strerror or first_line(exc)})", path) from None
    tokens = " ".join(pending).split()
    if tokens:
        yield lineno, tokens


def read_obj(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions and faces of an OBJ file, in its order.

    Returns:
        (vertices (V, 3) float64, faces (F, 3) int64 0-based (polygons as fans from their first
        corner), corners (P,) int64: the corner count of every face as written).

    Raises:
        InputError: one line naming the file (and the line): too large, unreadable, a face of
            fewer than 3 corners, an index out of range, a non-number, NaN.
    """
    path = Path(path)
    check_input_file(path, "mesh", (".obj",))
    vertices: list[list[float]] = []
    faces: list[list[int]] = []
    corners: list[int] = []
    face_lines: list[int] = []
    for lineno, tokens in obj_lines(path):
        key = tokens[0]
        if key == "v":
            vertices.append(parse_numbers(tokens[1:], 3, 3, lineno, "v", path))
        elif key == "f":
            ring = [parse_index(c.split("/")[0], len(vertices), lineno, "vertex", path) for c in tokens[1:]]
            if len(ring) < 3:
                raise InputError(f"line {lineno}: a face of {len(ring)} corners (at least 3 needed)", path)
            corners.append(len(ring))
            faces += [[ring[0], ring[k], ring[k + 1]] for k in range(1, len(ring) - 1)]
            face_lines += [lineno] * (len(ring) - 2)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    check_indices(f, len(vertices), face_lines, "vertex", path)
    return np.asarray(vertices, dtype=np.float64).reshape(-1, 3), f, np.asarray(corners, dtype=np.int64)
