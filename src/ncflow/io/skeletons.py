"""Skeleton files: TGF and JSON read and written, the skins of glTF/GLB files read.

Formats (chosen by suffix):

* TGF (libigl): node lines ``id x y z`` (extra columns ignored), a line ``#``, then edge lines
  ``a b`` (extra flag columns ignored; an optional second ``#`` ends them). Indices are 1-based,
  or 0-based when a 0 appears among them; nodes may be listed in any order, edges refer to the
  node ids. An edge ``a b`` makes a the parent of b; a file whose edge directions do not form a
  tree that way but whose bones do form one (as an undirected graph) is rooted at its first node,
  as libigl-based pipelines do. TGF stores neither names nor radii; it is written 1-based.
* JSON: ``{"names": [...], "parents": [...], "positions": [[x, y, z], ...], "radii": [...]}``;
  parents are 0-based indices into the file's lists, −1 for the root; ``names`` and ``radii``
  are optional; ``radii[j]`` is the radius factor ρ of the bone ending at joint j (null or
  absent: the default; ignored for the root).
* glTF / GLB (read only): the joints of a skin (:func:`ncflow.io.gltf.skins.gltf_skeleton`), in
  the bind pose or at a time of an animation; joints stacked on their parent are merged
  (:func:`~ncflow.geometry.skeleton.merge_zero_length_bones`, decided on the bind pose, so every
  time of one file gives the same joints).

Every reader returns a validated :class:`~ncflow.geometry.skeleton.Skeleton` (joints sorted
topologically, the map back to the file's order kept) or raises one
:class:`~ncflow.errors.InputError` line naming the file. Hostile files are refused, not crashed on:
TGF node ids must be integers in [0, 2**63) and unique; JSON that is nested too deeply or holds
numbers too long to convert is refused; a skeleton has at most
:data:`~ncflow.geometry.skeleton.MAX_JOINTS` joints, and reading and validating take time linear
in the size of the file.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from ncflow.errors import InputError
from ncflow.geometry.skeleton import MAX_JOINTS, Skeleton, _default_labels
from ncflow.io.atomic import atomic_write_text
from ncflow.io.files import check_input_file, check_regular_file, read_json_object, short_repr
from ncflow.io.gltf.skins import gltf_skeleton

SKELETON_SUFFIXES = (".tgf", ".json", ".glb", ".gltf")


def read_tgf(path: str | os.PathLike) -> Skeleton:
    """Read a libigl TGF skeleton (see the module docstring for the accepted variants)."""
    path = check_regular_file(path, "TGF skeleton")
    try:
        text = path.read_text(errors="replace")
    except OSError as exc:
        raise InputError(f"cannot read file ({exc.strerror or exc})", path) from None
    node_ids: list[int] = []
    coords: list[list[float]] = []
    edges: list[tuple[int, int, int]] = []  # (a, b, line number)
    section = 0  # 0 nodes, 1 edges, 2 trailer
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line:
            continue
        if line.startswith("#"):
            section += 1
            continue
        if section >= 2:
            continue
        tok = line.split()
        try:
            if section == 0:
                if len(tok) < 4:
                    raise ValueError
                node_ids.append(_node_id(tok[0], lineno, path))
                coords.append([float(x) for x in tok[1:4]])
            else:
                if len(tok) < 2:
                    raise ValueError
                edges.append((_node_id(tok[0], lineno, path), _node_id(tok[1], lineno, path), lineno))
        except InputError:
            raise
        except ValueError:
            want = "'id x y z'" if section == 0 else "'a b' (two node indices)"
            raise InputError(f"line {lineno}: expected {want}, got {line[:60]!r}", path) from None
        if len(node_ids) > MAX_JOINTS:
            raise InputError(f"more than {MAX_JOINTS} nodes, the most a skeleton may have", path)
    if not node_ids:
        raise InputError("no node lines ('id x y z'); not a TGF skeleton?", path)
    if section == 0:
        raise InputError("no '#' line separating the nodes from the edges", path)
    if not edges:
        raise InputError("no edges (bones) after the '#' line", path)
    n = len(node_ids)
    ids = np.asarray(node_ids, dtype=np.int64)
    e = np.asarray([(a, b) for a, b, _ in edges], dtype=np.int64)
    labels = [f"node {i}" for i in node_ids]
    positional = np.array_equal(ids, np.arange(n)) or np.array_equal(ids, np.arange(1, n + 1))
    if positional:
        base = 0 if (ids[0] == 0 or (e == 0).any()) else 1
        idx = e - base
        bad = (idx < 0) | (idx >= n)
        if bad.any():
            k = int(np.argmax(bad.any(axis=1)))
            v = int(e[k][bad[k]][0])
            raise InputError(
                f"line {edges[k][2]}: edge refers to node {v}, out of range ({n} nodes, {base}-based)", path
            )
    else:
        uniq, counts = np.unique(ids, return_counts=True)
        if (counts > 1).any():
            raise InputError(f"duplicate node id {int(uniq[np.argmax(counts > 1)])}", path)
        lookup = {int(i): k for k, i in enumerate(node_ids)}
        idx = np.empty_like(e)
        for k, (a, b, lineno) in enumerate(edges):
            for col, v in enumerate((a, b)):
                if v not in lookup:
                    raise InputError(f"line {lineno}: edge refers to node {v}, which is not defined", path)
                idx[k, col] = lookup[v]
    coords_arr = np.asarray(coords, dtype=np.float64)
    parents = _parents_from_edges(idx, n, labels, [ln for *_, ln in edges], path)
    return Skeleton.from_arrays(coords_arr, parents, name=path, labels=labels)


def _node_id(token: str, lineno: int, path) -> int:
    """A TGF node id: an integer in [0, 2**63); ``ValueError`` when it is no integer, InputError when out of range."""
    if len(token) > 30:
        raise InputError(f"line {lineno}: node id {token[:40]!r}... is too long", path)
    value = int(token)
    if not 0 <= value < 2**63:
        raise InputError(f"line {lineno}: node id {value} is out of range [0, 2**63)", path)
    return value


def _parents_from_edges(idx: np.ndarray, n: int, labels: list[str], lines: list[int], path) -> np.ndarray:
    """Parent array from (a → b) edges; falls back to rooting an undirected tree at node 0."""
    seen: set[tuple[int, int]] = set()
    for (a, b), ln in zip(idx.tolist(), lines):
        if a == b:
            raise InputError(f"line {ln}: {labels[a]} is its own parent", path)
        key = (min(a, b), max(a, b))
        if key in seen:
            raise InputError(f"line {ln}: bone between {labels[a]} and {labels[b]} listed twice", path)
        seen.add(key)
    parents = np.full(n, -1, dtype=np.int64)
    directed_ok = True
    for a, b in idx.tolist():
        if parents[b] >= 0:
            directed_ok = False
            break
        parents[b] = a
    if directed_ok and int((parents < 0).sum()) == 1:
        return parents  # cycles and the rest are checked by validate_skeleton
    # not a tree as directed: accept an undirected spanning tree rooted at the first node
    if idx.shape[0] == n - 1:
        adj: list[list[int]] = [[] for _ in range(n)]
        for a, b in idx.tolist():
            adj[a].append(b)
            adj[b].append(a)
        und = np.full(n, -2, dtype=np.int64)
        und[0] = -1
        stack = [0]
        while stack:
            j = stack.pop()
            for c in adj[j]:
                if und[c] == -2:
                    und[c] = j
                    stack.append(c)
        if (und != -2).all():
            return und
    if not directed_ok:
        b = int(idx[:, 1][np.argmax(np.bincount(idx[:, 1], minlength=n) > 1)])
        raise InputError(f"{labels[b]} has two parents (edges must form a tree)", path)
    return parents  # no root / several roots / cycles: reported by validate_skeleton


def write_tgf(path: str | os.PathLike, skeleton: Skeleton) -> None:
    """Write a TGF file: nodes 1-based in internal (topological) order, edges ``parent child``."""
    lines = [f"{j + 1} {_fmt(p[0])} {_fmt(p[1])} {_fmt(p[2])}" for j, p in enumerate(skeleton.positions)]
    lines.append("#")
    lines += [f"{a + 1} {b + 1}" for a, b in skeleton.bones]
    lines.append("#")
    _write_text(path, "\n".join(lines) + "\n")


def _fmt(x: float) -> str:
    return repr(float(x))


def _write_text(path, text: str) -> None:
    """Write ``text`` atomically (its folder created); an OSError becomes one :class:`InputError` line."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, text)
    except OSError as exc:
        raise InputError(f"cannot write file ({exc.strerror or exc})", path) from None


def read_skeleton_json(path: str | os.PathLike) -> Skeleton:
    """Read ``{"names", "parents", "positions", "radii"}`` (names and radii optional)."""
    path = Path(path)
    data = read_json_object(path, "a JSON object with 'positions' and 'parents'")
    for key in ("positions", "parents"):
        if key not in data:
            raise InputError(f"missing key {key!r}", path)
    try:
        positions = np.asarray(data["positions"], dtype=np.float64)
    except (TypeError, ValueError, OverflowError, RecursionError):
        raise InputError("'positions' must be a list of [x, y, z] numbers", path) from None
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise InputError(f"'positions' must be a list of [x, y, z], got shape {positions.shape}", path)
    n = positions.shape[0]
    raw_parents = data["parents"]
    if not isinstance(raw_parents, list) or not all(
        isinstance(p, int) and not isinstance(p, bool) for p in raw_parents
    ):
        raise InputError("'parents' must be a list of integers (-1 for the root)", path)
    if len(raw_parents) != n:
        raise InputError(f"'parents' has {len(raw_parents)} entries but there are {n} positions", path)
    names = data.get("names")
    if names is not None:
        if not isinstance(names, list) or not all(isinstance(s, str) for s in names):
            raise InputError("'names' must be a list of strings", path)
        if len(names) != n:
            raise InputError(f"'names' has {len(names)} entries but there are {n} positions", path)
    radii = data.get("radii")
    if radii is not None:
        if not isinstance(radii, list) or len(radii) != n:
            raise InputError(f"'radii' must be a list of {n} numbers or nulls (one per joint)", path)
        try:
            radii = np.asarray([math.nan if r is None else float(r) for r in radii], dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            raise InputError("'radii' must contain numbers or nulls", path) from None
        bad = np.isfinite(radii) & ~(radii > 0)
        bad |= np.isinf(radii)
        if bad.any():
            raise InputError(f"'radii' entry {int(np.argmax(bad))} must be a positive number or null", path)
    labels = _default_labels(n, names)
    bad = [k for k, p in enumerate(raw_parents) if not -1 <= p < n]  # before int64: no OverflowError
    if bad:
        k = bad[0]
        raise InputError(f"{labels[k]} has parent {short_repr(raw_parents[k], 40)}, out of range [-1, {n - 1}]", path)
    parents = np.asarray(raw_parents, dtype=np.int64)
    return Skeleton.from_arrays(positions, parents, names, radii, name=path, labels=labels)


def write_skeleton_json(path: str | os.PathLike, skeleton: Skeleton) -> None:
    """Write the JSON format in internal (topological) order; names/radii when present."""
    parts = []
    if skeleton.names is not None:
        parts.append(f' "names": {json.dumps(list(skeleton.names))}')
    parts.append(f' "parents": {json.dumps([int(p) for p in skeleton.parents])}')
    rows = ",\n  ".join(json.dumps([float(x) for x in p]) for p in skeleton.positions)
    parts.append(f' "positions": [\n  {rows}\n ]')
    if skeleton.radii is not None:
        parts.append(f' "radii": {json.dumps([None if not np.isfinite(r) else float(r) for r in skeleton.radii])}')
    _write_text(path, "{\n" + ",\n".join(parts) + "\n}\n")


def load_skeleton(
    path: str | os.PathLike, *, time: float | None = None, animation: str | int | None = None
) -> Skeleton:
    """Read a skeleton from TGF, JSON, glTF or GLB (by suffix).

    Args:
        path: the file.
        time: glTF/GLB only: pose the skeleton at this animation time (seconds); rest pose if None.
        animation: glTF/GLB only: animation name or index.

    Raises:
        InputError: one line naming the file and the problem.
    """
    path = Path(path)
    suffix = check_input_file(path, "skeleton", SKELETON_SUFFIXES)
    if suffix in (".glb", ".gltf"):
        # rigs stack joints at one point: merged, decided on the bind pose (same joints at every time)
        return gltf_skeleton(path, time, animation, name=path)[0]
    if time is not None or animation is not None:
        raise InputError("a time or an animation can only be chosen for glTF/GLB skeletons", path)
    if suffix == ".tgf":
        return read_tgf(path)
    return read_skeleton_json(path)


def save_skeleton(path: str | os.PathLike, skeleton: Skeleton) -> None:
    """Write a skeleton as TGF (1-based) or JSON, by suffix."""
    suffix = Path(path).suffix.lower()
    if suffix == ".tgf":
        write_tgf(path, skeleton)
    elif suffix == ".json":
        write_skeleton_json(path, skeleton)
    else:
        raise InputError(f"cannot write skeletons as {suffix or '(no suffix)'!r}; use .tgf or .json", path)
