"""Checks of arrays and metrics about to be written, and strict JSON text of NumPy values.

The writers of the output contract (:mod:`ncflow.io.result`, :mod:`ncflow.io.gltf.writer`) check
shapes, index ranges, strictly increasing times and finiteness here before writing anything, and
the first offending value is named in a :class:`~ncflow.errors.ResultError`.

Every JSON file ncflow writes from a dict of results (``metrics.json``, ``evaluation.json``, the
benchmark's ``report.json``) goes through :func:`json_safe` (NumPy/JAX values to Python numbers and
lists, non-finite floats to ``null``) and :func:`dumps_strict` (one layout, ``indent=1``, never
``NaN``/``Infinity``).
"""

from __future__ import annotations

import json
import math
import numbers
import os
from typing import Any

import numpy as np

from ncflow.errors import ResultError


def check_finite(what: str, array: Any) -> None:
    """Raise :class:`ResultError` naming ``what`` and the first non-finite entry of a float ``array``."""
    arr = np.asarray(array)
    if arr.dtype.kind in "fc" and not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))
        where = tuple(int(i) for i in bad[0])
        raise ResultError(f"{what} has {bad.shape[0]} non-finite values (first at index {where}); refusing to write it")


def check_finite_tree(value: Any, where: str = "metrics") -> None:
    """Raise :class:`ResultError` at the first NaN/inf in a nested dict/list/array structure."""
    if isinstance(value, dict):
        for k, v in value.items():
            check_finite_tree(v, f"{where}[{k!r}]")
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            check_finite_tree(v, f"{where}[{i}]")
    elif isinstance(value, (bool, np.bool_, str, bytes)) or value is None:
        return
    elif isinstance(value, numbers.Number):
        if isinstance(value, numbers.Real) and not math.isfinite(float(value)):
            raise ResultError(f"{where} is {value}; refusing to write non-finite metrics")
    elif hasattr(value, "__array__") or isinstance(value, np.generic):
        check_finite(where, np.asarray(value))


def json_safe(value: Any, where: str = "") -> tuple[Any, list[str]]:
    """A JSON-ready copy of ``value`` with non-finite floats replaced by None.

    Dicts get string keys (``str(key)``), tuples become lists, NumPy and JAX arrays nested lists,
    NumPy scalars Python numbers, paths strings; other values are kept (and refused by
    :func:`dumps_strict` unless JSON knows them).

    Args:
        value: a nested structure of dicts, lists, tuples, arrays and scalars.
        where: the location prefix of ``value`` in the reported locations.

    Returns:
        (the copy, the dotted locations of the values that were non-finite, e.g. ``summary.volume_change[0]``).
    """
    replaced: list[str] = []

    def walk(v: Any, at: str) -> Any:
        if isinstance(v, dict):
            return {str(k): walk(x, f"{at}.{k}" if at else str(k)) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [walk(x, f"{at}[{i}]") for i, x in enumerate(v)]
        if isinstance(v, np.ndarray):
            return walk(v.tolist(), at)
        if isinstance(v, (bool, np.bool_)):
            return bool(v)
        if isinstance(v, (int, np.integer)):
            return int(v)
        if isinstance(v, (float, np.floating)):
            if math.isfinite(float(v)):
                return float(v)
            replaced.append(at)
            return None
        if isinstance(v, np.generic):
            return walk(v.item(), at)
        if isinstance(v, os.PathLike):
            return os.fspath(v)
        if hasattr(v, "__array__"):  # JAX and other array types
            return walk(np.asarray(v).tolist(), at)
        return v

    return walk(value, where), replaced


def _refuse(value: Any) -> Any:
    raise TypeError(f"cannot write {type(value).__name__} to JSON")


def dumps_strict(record: Any) -> str:
    """JSON text of a :func:`json_safe` record, ``indent=1``, ending in a newline.

    Raises:
        ValueError: a NaN or infinity is left (they must have been replaced or refused before).
        TypeError: a value JSON cannot represent.
    """
    return json.dumps(record, indent=1, allow_nan=False, default=_refuse) + "\n"


def as_frames(frames: Any, what: str = "frames") -> np.ndarray:
    """``frames`` as a finite float64 (K, V, 3) array, K ≥ 1, or a :class:`ResultError` naming ``what``."""
    arr = np.asarray(frames, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] == 0:
        raise ResultError(f"{what} must have shape (K, V, 3) with K ≥ 1, got {arr.shape}")
    check_finite(what, arr)
    return arr


def as_faces(faces: Any, n_vertices: int, what: str = "faces", allow_empty: bool = False) -> np.ndarray:
    """``faces`` as an int64 (F, 3) array, F ≥ 1 (F ≥ 0 with ``allow_empty``: a point cloud), indices in
    [0, n_vertices), or a :class:`ResultError`.
    """
    f = np.asarray(faces)
    if f.size == 0 and allow_empty:
        return np.zeros((0, 3), np.int64)
    if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0 or not np.issubdtype(f.dtype, np.integer):
        raise ResultError(f"{what} must be (F, 3) integers with F ≥ 1, got shape {f.shape} dtype {f.dtype}")
    if f.min() < 0 or f.max() >= n_vertices:
        raise ResultError(f"{what} indices span [{int(f.min())}, {int(f.max())}] but there are {n_vertices} vertices")
    return f.astype(np.int64)


def as_times(times: Any, k: int, what: str = "frame times") -> np.ndarray:
    """``times`` as a finite, strictly increasing float64 (k,) array, or a :class:`ResultError`."""
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    if t.shape != (k,):
        raise ResultError(f"{what} must have one value per frame ({k}), got shape {np.shape(times)}")
    check_finite(what, t)
    if k > 1 and not np.all(np.diff(t) > 0):
        raise ResultError(f"{what} must be strictly increasing")
    return t


def as_index(values: Any, n: int, upper: int, what: str) -> np.ndarray:
    """``values`` as an int64 (n,) array of indices in [0, upper), or a :class:`ResultError` naming ``what``."""
    arr = np.asarray(values)
    if arr.shape != (n,) or not np.issubdtype(arr.dtype, np.integer):
        raise ResultError(f"{what} must be ({n},) integers, got shape {arr.shape} dtype {arr.dtype}")
    if n and (arr.min() < 0 or arr.max() >= upper):
        raise ResultError(f"{what} indices span [{int(arr.min())}, {int(arr.max())}], expected 0-based in [0, {upper})")
    return arr.astype(np.int64)


# the old private name, still imported by ncflow.matcher.correspondence: remove once that imports check_finite
