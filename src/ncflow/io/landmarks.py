"""Landmark files (JSON): named points of a mesh, given as vertex ids or as 3-D points; read and write.

Input schema (validated strictly; anything else is one :class:`~ncflow.errors.InputError` line
naming the file and the entry):

* an object with exactly one key, ``"landmarks"``, holding a non-empty list of entries
  ``{"name": "left_wrist", "vertex": 812}`` or ``{"name": "nose", "point": [0.01, 1.62, 0.09]}``:
  ``name`` an optional non-empty string (at most :data:`MAX_NAME_CHARS` characters; default the
  entry's position, ``"0"``, ``"1"``, …), exactly one of ``vertex`` (a 0-based vertex index, an
  integer — not ``3.0``, not ``true``) and ``point`` (three finite numbers), no other key;
* or a plain non-empty list of such vertex indices and points: ``[812, 40, [0.0, 1.6, 0.1]]``.

Names are unique; at most :data:`MAX_LANDMARKS` entries; the file is at most
:data:`MAX_LANDMARK_BYTES`. Vertex indices are checked against the mesh's vertex count.

:func:`write_landmarks` writes the carried landmarks as strict JSON (``{"landmarks": [...], ...}``,
no NaN), atomically; the record's fields are documented where they are made
(:func:`ncflow.retarget.attributes.carry_landmarks`) and in ``docs/transfer.md``.
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path

import numpy as np

from ncflow.errors import InputError, first_line
from ncflow.io.arrays import check_finite_tree, dumps_strict, json_safe
from ncflow.io.atomic import atomic_write_text
from ncflow.io.files import check_input_file, parse_json_text, short_repr

MAX_LANDMARKS = 100_000
MAX_NAME_CHARS = 256
MAX_LANDMARK_BYTES = 64 * 2**20


@dataclasses.dataclass(frozen=True)
class Landmark:
    """One landmark as given: a name and either a vertex index or a point (the other is None)."""

    name: str
    vertex: int | None = None
    point: tuple[float, float, float] | None = None


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(float(value))


def _entry(item, k: int, n_vertices: int, path) -> Landmark:
    """One entry (an object, an index or a point) as a :class:`Landmark`."""
    where = f"landmark {k}"
    name = str(k)
    if isinstance(item, dict):
        extra = sorted(set(item) - {"name", "vertex", "point"})
        if extra:
            raise InputError(f"{where}: unknown key {extra[0][:40]!r} (allowed: name, vertex, point)", path)
        if ("vertex" in item) == ("point" in item):
            raise InputError(f"{where}: give exactly one of 'vertex' and 'point'", path)
        if "name" in item:
            name = item["name"]
            if not isinstance(name, str) or not name.strip() or len(name) > MAX_NAME_CHARS:
                raise InputError(f"{where}: 'name' must be a non-empty string of at most {MAX_NAME_CHARS} chars", path)
        item = item["vertex"] if "vertex" in item else item["point"]
    if _is_int(item):
        if not 0 <= item < n_vertices:
            raise InputError(
                f"{where} ({name[:40]!r}): vertex {short_repr(item, 40)} is out of range [0, {n_vertices - 1}] "
                f"(0-based; the mesh has {n_vertices} vertices)",
                path,
            )
        return Landmark(name=name, vertex=int(item))
    if isinstance(item, list) and len(item) == 3 and all(_is_number(x) for x in item):
        return Landmark(name=name, point=tuple(float(x) for x in item))
    raise InputError(f"{where}: expected a vertex index (integer) or a point (3 finite numbers)", path)


def read_landmarks(path: str | os.PathLike, n_vertices: int) -> list[Landmark]:
    """The landmarks of a JSON file (schema in the module docstring), vertex ids checked against ``n_vertices``.

    Raises:
        InputError: one line naming the file (and the entry).
    """
    path = Path(path)
    check_input_file(path, "landmark", (".json",))
    size = os.stat(path).st_size
    if size > MAX_LANDMARK_BYTES:
        raise InputError(f"is {size} bytes, more than the limit of {MAX_LANDMARK_BYTES}", path)
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read text ({first_line(exc)[:80]})", path) from None
    data = parse_json_text(text, path)
    if isinstance(data, dict):
        if set(data) != {"landmarks"}:
            extra = sorted(set(data) - {"landmarks"})
            why = f"unknown key {extra[0][:40]!r}" if extra else "no 'landmarks' key"
            raise InputError(f'expected {{"landmarks": [...]}} ({why})', path)
        data = data["landmarks"]
    if not isinstance(data, list):
        raise InputError('expected a list of landmarks or {"landmarks": [...]}', path)
    if not data:
        raise InputError("no landmarks (empty list)", path)
    if len(data) > MAX_LANDMARKS:
        raise InputError(f"{len(data)} landmarks, more than the limit of {MAX_LANDMARKS}", path)
    out = [_entry(item, k, int(n_vertices), path) for k, item in enumerate(data)]
    names = [m.name for m in out]
    if len(set(names)) != len(names):
        seen: set[str] = set()
        dup = next(n for n in names if n in seen or seen.add(n))
        raise InputError(f"landmark name {dup[:40]!r} is used twice", path)
    return out


def landmark_arrays(landmarks: list[Landmark]) -> tuple[np.ndarray, np.ndarray]:
    """(vertex (n,) int64, -1 where a point is given; point (n, 3) float64, NaN where a vertex is given)."""
    vertex = np.array([-1 if m.vertex is None else m.vertex for m in landmarks], dtype=np.int64)
    point = np.array([(np.nan,) * 3 if m.point is None else m.point for m in landmarks], dtype=np.float64)
    return vertex, point.reshape(-1, 3)


def write_landmarks(path: str | os.PathLike, record: dict) -> None:
    """Write a landmark record (a dict with a ``"landmarks"`` list) as strict JSON, atomically.

    Raises:
        ResultError: a non-finite number (nothing is written).
    """
    check_finite_tree(record, "landmarks")
    atomic_write_text(path, dumps_strict(json_safe(record)[0]))
