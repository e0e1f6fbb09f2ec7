"""Per-vertex attribute arrays: ``.npy`` and whitespace-separated ``.txt``, one row per vertex.

An attribute array holds one row per mesh vertex: shape (V,) or (V, C). Integers (and booleans)
are read as int64, floating-point numbers as float64; every other dtype (complex, strings,
structured records, objects) is refused.

``.npy``
    Read without pickles; the header is checked against the bytes the file holds before anything
    is allocated (:func:`ncflow.io.files.read_npy_array`) and against a limit that follows from
    the expected row count (at most :data:`MAX_COLUMNS` columns of 16 bytes per row).
``.txt``
    One row per line, numbers separated by spaces, tabs or commas; blank lines and lines starting
    with ``#`` are skipped. Every row has the same number of columns. A file whose numbers are all
    written as integers (no ``.``, exponent, ``nan`` or ``inf``) is read as int64, any other as
    float64. The file size is checked before reading (at most 40 characters per number on
    average), the array is allocated once from the first row's width, and reading stops at the
    first extra row, so memory stays bounded by the expected size (read line by line rather than
    with :func:`numpy.loadtxt`, which reads the whole file before its shape can be checked and
    names no line in its errors).

Every problem — a missing file, a wrong row count, a ragged row, a non-number, NaN or infinity, a
pickled or object array — is one :class:`~ncflow.errors.InputError` line naming the file (and the
line or entry). :func:`write_vertex_array` writes the same two formats atomically.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
from jaxtyping import Shaped

from ncflow.errors import InputError, first_line
from ncflow.io.arrays import check_finite
from ncflow.io.atomic import atomic_path, atomic_write_text
from ncflow.io.files import MAX_ARRAY_BYTES, check_input_file, dtype_text, read_npy_array

ARRAY_SUFFIXES = (".npy", ".txt")

MAX_COLUMNS = 4096
"""Most values per vertex (columns) an attribute array may have."""

_TEXT_BYTES_PER_VALUE = 40
_MAX_TEXT_BYTES = 2**30
_INTEGER_TOKEN = re.compile(r"^[+-]?\d+$")
_SEPARATORS = re.compile(r"[\s,]+")


def _as_attribute_dtype(arr: np.ndarray, path, where: str = "array") -> np.ndarray:
    """int64 for integers and booleans, float64 for floats; InputError for any other dtype."""
    kind = arr.dtype.kind
    if kind == "b":
        return arr.astype(np.int64)
    if kind in "iu":
        if kind == "u" and arr.dtype.itemsize == 8 and arr.size and int(arr.max()) > 2**62:
            raise InputError(f"{where}: integers above 2**62 are not accepted", path)
        return arr.astype(np.int64)
    if kind == "f":
        return arr.astype(np.float64)
    raise InputError(f"{where}: expected integers or floating-point numbers, got dtype {dtype_text(arr.dtype)}", path)


def _check_rows(arr: np.ndarray, n_rows: int, path, max_columns: int) -> np.ndarray:
    """The shape rules: (n_rows,) or (n_rows, C) with 1 ≤ C ≤ max_columns; floats finite."""
    if arr.ndim not in (1, 2) or (arr.ndim == 2 and not 1 <= arr.shape[1] <= max_columns):
        raise InputError(
            f"expected one row per vertex, shape ({n_rows},) or ({n_rows}, C) with C ≤ {max_columns}, "
            f"got shape {arr.shape}",
            path,
        )
    if arr.shape[0] != n_rows:
        raise InputError(f"has {arr.shape[0]} rows but the mesh has {n_rows} vertices (one row per vertex)", path)
    if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))
        row = int(bad[0][0])
        raise InputError(f"{bad.shape[0]} values are NaN or infinite (first in row {row}, 0-based)", path)
    return arr


def read_vertex_array(
    path: str | os.PathLike, n_rows: int, *, max_columns: int = MAX_COLUMNS
) -> Shaped[np.ndarray, "V ..."]:
    """One row per vertex from a ``.npy`` or ``.txt`` file (see the module docstring).

    Args:
        path: the file.
        n_rows: the number of rows expected (the mesh's vertex count).
        max_columns: most columns accepted.

    Returns:
        (n_rows,) or (n_rows, C) int64 (integers, booleans) or float64 (finite) array.

    Raises:
        InputError: one line naming the file.
    """
    path = Path(path)
    suffix = check_input_file(path, "attribute array", ARRAY_SUFFIXES)
    n_rows, max_columns = int(n_rows), int(max_columns)
    if suffix == ".npy":
        with open(path, "rb") as fh:
            magic = fh.read(6)
        if magic != b"\x93NUMPY":
            raise InputError("cannot read .npy array (not a NumPy .npy file)", path)
        limit = min(MAX_ARRAY_BYTES, n_rows * max_columns * 16 + 2**20)
        arr = _as_attribute_dtype(read_npy_array(path, max_bytes=limit), path)
    else:
        arr = _read_text_rows(path, n_rows, max_columns)
    return _check_rows(arr, n_rows, path, max_columns)


def _read_text_rows(path: Path, n_rows: int, max_columns: int) -> np.ndarray:
    """The rows of a whitespace-separated text file, bounded by the expected size."""
    limit = min(_MAX_TEXT_BYTES, n_rows * max_columns * _TEXT_BYTES_PER_VALUE + 2**20)
    size = os.stat(path).st_size
    if size > limit:
        raise InputError(f"is {size} bytes, more than {n_rows} rows of numbers can need ({limit})", path)
    out: np.ndarray | None = None
    integer = True
    row = 0
    try:
        with open(path, encoding="utf-8", errors="strict") as fh:
            for lineno, line in enumerate(fh, start=1):
                s = line.strip()
                if not s or s.startswith("#"):
                    continue
                tokens = _SEPARATORS.split(s)
                if out is None:
                    if len(tokens) > max_columns:
                        raise InputError(f"line {lineno}: {len(tokens)} values, more than {max_columns}", path)
                    width = len(tokens)
                    out = np.zeros((n_rows, width), dtype=np.int64)
                elif len(tokens) != width:
                    raise InputError(f"line {lineno}: {len(tokens)} values, but the first row has {width}", path)
                if row >= n_rows:
                    raise InputError(f"has more than {n_rows} rows but the mesh has {n_rows} vertices", path)
                if integer and not all(_INTEGER_TOKEN.match(t) for t in tokens):
                    integer = False
                    out = out.astype(np.float64)
                try:
                    values = [int(t) for t in tokens] if integer else [float(t) for t in tokens]
                except ValueError:
                    bad = next(t for t in tokens if not _is_number(t))
                    raise InputError(f"line {lineno}: not a number: {bad[:40]!r}", path) from None
                try:
                    out[row] = values
                except OverflowError:
                    raise InputError(f"line {lineno}: integer out of the 64-bit range", path) from None
                if not integer and not all(np.isfinite(out[row])):
                    raise InputError(f"line {lineno}: NaN or infinite value", path)
                row += 1
    except UnicodeDecodeError as exc:
        raise InputError(f"cannot read text ({first_line(exc)[:80]})", path) from None
    except OSError as exc:
        raise InputError(f"cannot read file ({exc.strerror or first_line(exc)})", path) from None
    if out is None:
        raise InputError("no rows (empty file?)", path)
    if row != n_rows:
        raise InputError(f"has {row} rows but the mesh has {n_rows} vertices (one row per vertex)", path)
    return out[:, 0] if out.shape[1] == 1 else out


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def write_vertex_array(path: str | os.PathLike, values: Shaped[np.ndarray, "V ..."]) -> None:
    """Write a (V,) or (V, C) array as ``.npy`` (no pickles) or ``.txt`` (one row per line), atomically.

    Integers are written as integers; floats in ``.txt`` with 17 significant digits (they read
    back bit for bit).

    Raises:
        InputError: an unsupported suffix.
        ResultError: non-finite values (nothing is written).
    """
    path = Path(path)
    arr = np.asarray(values)
    check_finite(f"the array for {path.name}", arr)
    suffix = path.suffix.lower()
    if suffix == ".npy":
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            np.save(fh, arr, allow_pickle=False)
        return
    if suffix != ".txt":
        raise InputError(f"unsupported array format {suffix or '(no suffix)'!r}; use .npy or .txt", path)
    rows = arr.reshape(arr.shape[0], -1)
    fmt = "{:d}" if arr.dtype.kind in "iub" else "{!r}"
    cast = int if arr.dtype.kind in "iub" else float
    text = "".join(" ".join(fmt.format(cast(x)) for x in r) + "\n" for r in rows.tolist())
    atomic_write_text(path, text)
