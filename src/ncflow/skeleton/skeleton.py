"""The skeleton type, its file formats and its validation (DESIGN.md "Skeleton").

A skeleton is a tree of joints: positions (J, 3) float64 and a parent array (J,) with −1 for the
single root. Bones are the pairs (parent(j), j) for every non-root joint j. Inside ncflow the
joints are stored in a topological order (root first, every parent before its children; a file
that is already in such an order keeps it) and :attr:`Skeleton.file_index` maps back to the
order of the file.

Formats (chosen by suffix):

* TGF (libigl): node lines ``id x y z`` (extra columns ignored), a line ``#``, then edge lines
  ``a b`` (extra flag columns ignored; an optional second ``#`` ends them). Indices are 1-based,
  or 0-based when a 0 appears among them; nodes may be listed in any order, edges refer to the
  node ids. An edge ``a b`` makes a the parent of b; a file whose edge directions do not form a
  tree that way but whose bones do form one (as an undirected graph) is rooted at its first node,
  as libigl-based pipelines do. TGF stores neither names nor radii.
* JSON: ``{"names": [...], "parents": [...], "positions": [[x, y, z], ...], "radii": [...]}``;
  parents are 0-based indices into the file's lists, −1 for the root; ``names`` and ``radii``
  are optional; ``radii[j]`` is the radius factor ρ of the bone ending at joint j (null or
  absent: the default; ignored for the root).
* glTF / GLB: the joints of a skin (read by :func:`ncflow.gltf.gltf_skeleton`), in the rest
  pose or at a time of an animation.
"""

from __future__ import annotations

import dataclasses
import heapq
import json
import math
import os
from pathlib import Path

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError, check_input_file, read_json_object

__all__ = [
    "Skeleton",
    "SKELETON_SUFFIXES",
    "load_skeleton",
    "save_skeleton",
    "read_tgf",
    "read_skeleton_json",
    "write_tgf",
    "write_skeleton_json",
    "validate_skeleton",
    "check_inside",
]

SKELETON_SUFFIXES = (".tgf", ".json", ".glb", ".gltf")


@dataclasses.dataclass(frozen=True, eq=False)
class Skeleton:
    """A tree of joints in topological order (``parents[0] == -1``, ``parents[j] < j``).

    Build one with :meth:`from_arrays` (validates and sorts) or :func:`load_skeleton`. Per-joint
    arrays (poses, radii) are in this internal order; :meth:`from_file_order` and
    :meth:`to_file_order` convert. Skeletons hash by identity, so a skeleton can be a static
    argument of ``jax.jit``.

    Attributes:
        positions: (J, 3) float64 rest positions of the joints.
        parents: (J,) int64 parent of each joint, −1 for the root (joint 0).
        names: joint names, or None.
        radii: (J,) float64 radius factor ρ of the bone ending at each joint (NaN: use the
            default; entry 0, the root, is unused), or None.
        name: where it came from (a file path), used in messages.
        file_index: (J,) position of each joint in the file's (or the caller's) joint list.
        file_labels: how the file refers to each joint (e.g. ``node 3`` in a TGF), or None.
    """

    positions: Float[np.ndarray, "J 3"]
    parents: Int[np.ndarray, " J"]
    names: tuple[str, ...] | None = None
    radii: Float[np.ndarray, " J"] | None = None
    name: str | None = None
    file_index: Int[np.ndarray, " J"] | None = None
    file_labels: tuple[str, ...] | None = None

    @classmethod
    def from_arrays(
        cls,
        positions: Float[np.ndarray, "J 3"],
        parents: Int[np.ndarray, " J"],
        names: list[str] | tuple[str, ...] | None = None,
        radii: Float[np.ndarray, " J"] | None = None,
        *,
        name: str | os.PathLike | None = None,
        labels: list[str] | None = None,
    ) -> "Skeleton":
        """Validate joints given in any order and store them topologically sorted.

        Args:
            positions: (J, 3) joint positions.
            parents: (J,) parent indices into the same lists, −1 for the root.
            names: optional (J,) joint names.
            radii: optional (J,) bone radius factors (see the class docstring).
            name: the source file, for error messages.
            labels: how to call each joint in error messages (default ``joint i``).

        Raises:
            InputError: see :func:`validate_skeleton`.
        """
        name = None if name is None else os.fspath(name)
        positions = np.asarray(positions, dtype=np.float64)
        parents_arr = np.asarray(parents)
        validate_skeleton(positions, parents_arr, name=name, labels=labels)
        parents_arr = parents_arr.astype(np.int64)
        order = _topological_order(parents_arr)
        rank = np.empty_like(order)
        rank[order] = np.arange(order.size)
        new_parents = np.where(parents_arr[order] < 0, -1, rank[np.maximum(parents_arr[order], 0)])
        if names is not None:
            names = tuple(str(names[i]) for i in order)
        if radii is not None:
            radii = np.asarray(radii, dtype=np.float64)[order]
        file_labels = None if labels is None else tuple(labels[i] for i in order)
        return cls(
            positions[order], new_parents.astype(np.int64), names, radii, name, order.astype(np.int64), file_labels
        )

    # -- sizes and tables ------------------------------------------------------------------

    @property
    def n_joints(self) -> int:
        return int(self.parents.shape[0])

    @property
    def n_bones(self) -> int:
        return self.n_joints - 1

    @property
    def bones(self) -> Int[np.ndarray, "B 2"]:
        """(B, 2) bones (parent, child); bone b ends at joint b + 1."""
        child = np.arange(1, self.n_joints)
        return np.stack([self.parents[1:], child], axis=1)

    @property
    def offsets(self) -> Float[np.ndarray, "J 3"]:
        """Rest offsets o_j = P_j − P_parent(j); for the root its absolute position P_0."""
        off = self.positions - self.positions[np.maximum(self.parents, 0)]
        off[0] = self.positions[0]
        return off

    @property
    def bone_lengths(self) -> Float[np.ndarray, " B"]:
        return np.linalg.norm(self.offsets[1:], axis=1)

    @property
    def depth(self) -> Int[np.ndarray, " J"]:
        """Number of bones between each joint and the root."""
        depth = np.zeros(self.n_joints, dtype=np.int64)
        for j in range(1, self.n_joints):
            depth[j] = depth[self.parents[j]] + 1
        return depth

    @property
    def levels(self) -> tuple[np.ndarray, ...]:
        """Joints grouped by depth (level 0 is the root): the order in which FK can proceed."""
        depth = self.depth
        return tuple(np.flatnonzero(depth == d) for d in range(int(depth.max()) + 1))

    def bone_radii(self, default: float = 0.1) -> Float[np.ndarray, " B"]:
        """Radius factor ρ of every bone: the per-bone value when given, else ``default``."""
        if self.radii is None:
            return np.full(self.n_bones, float(default))
        r = self.radii[1:]
        return np.where(np.isfinite(r), r, float(default))

    def label(self, j: int) -> str:
        """Human-readable name of (internal) joint j, as the file calls it (name, node id or index)."""
        if self.file_labels is not None:
            return self.file_labels[j]
        fi = int(self.file_index[j]) if self.file_index is not None else int(j)
        if self.names is not None and self.names[j]:
            return f"joint {fi} ({self.names[j]!r})"
        return f"joint {fi}"

    def to_file_order(self, values: np.ndarray) -> np.ndarray:
        """Reorder a per-joint array (J, ...) from internal order to the file's order."""
        values = np.asarray(values)
        if self.file_index is None:
            return values
        out = np.empty_like(values)
        out[self.file_index] = values
        return out

    def from_file_order(self, values: np.ndarray) -> np.ndarray:
        """Reorder a per-joint array (J, ...) from the file's order to internal order."""
        values = np.asarray(values)
        return values if self.file_index is None else values[self.file_index]

    def with_positions(self, positions: Float[np.ndarray, "J 3"]) -> "Skeleton":
        """Same tree with other joint positions (internal order), e.g. a posed skeleton."""
        return dataclasses.replace(self, positions=np.asarray(positions, dtype=np.float64))


# ----------------------------------------------------------------------------------------------
# validation


def _default_labels(n: int, names=None) -> list[str]:
    if names is None:
        return [f"joint {i}" for i in range(n)]
    return [f"joint {i} ({names[i]!r})" for i in range(n)]


def _topological_order(parents: np.ndarray) -> np.ndarray:
    """Parents-before-children order, as close to the given order as possible (stable Kahn)."""
    n = parents.size
    children: list[list[int]] = [[] for _ in range(n)]
    for j, p in enumerate(parents):
        if p >= 0:
            children[p].append(j)
    heap = [j for j in range(n) if parents[j] < 0]
    heapq.heapify(heap)
    order = []
    while heap:
        j = heapq.heappop(heap)
        order.append(j)
        for c in children[j]:
            heapq.heappush(heap, c)
    return np.asarray(order, dtype=np.int64)


def validate_skeleton(
    positions: Float[np.ndarray, "J 3"],
    parents: Int[np.ndarray, " J"],
    name: str | os.PathLike | None = None,
    labels: list[str] | None = None,
) -> None:
    """Check a joint tree given in any order; raise :class:`InputError` (one line) otherwise.

    Checks: (J, 3) finite positions with J ≥ 2; (J,) integer parents in [−1, J); exactly one
    root; no cycles (every joint reaches the root); no zero-length bone (shorter than 1e-9 of the
    skeleton's bounding-box diagonal).
    """
    positions = np.asarray(positions)
    parents = np.asarray(parents)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise InputError(f"expected (J, 3) joint positions, got shape {positions.shape}", name)
    n = positions.shape[0]
    if n < 2:
        raise InputError(f"a skeleton needs at least 2 joints (one bone), got {n}", name)
    labels = labels or _default_labels(n)
    bad = ~np.all(np.isfinite(positions), axis=1)
    if bad.any():
        raise InputError(f"{labels[int(np.argmax(bad))]} has a NaN or infinite coordinate", name)
    if parents.shape != (n,):
        raise InputError(f"expected {n} parent indices (one per joint), got shape {parents.shape}", name)
    if not np.issubdtype(parents.dtype, np.integer):
        raise InputError("parent indices must be integers", name)
    out = (parents < -1) | (parents >= n)
    if out.any():
        j = int(np.argmax(out))
        raise InputError(f"{labels[j]} has parent {int(parents[j])}, out of range [-1, {n - 1}]", name)
    selfp = parents == np.arange(n)
    if selfp.any():
        raise InputError(f"{labels[int(np.argmax(selfp))]} is its own parent", name)
    roots = np.flatnonzero(parents < 0)
    if roots.size == 0:
        raise InputError("no root joint (parent -1): the bones form a cycle", name)
    if roots.size > 1:
        shown = ", ".join(labels[r] for r in roots[:5]) + (", ..." if roots.size > 5 else "")
        raise InputError(f"{roots.size} root joints ({shown}); a skeleton must be a single tree", name)
    # every joint must reach the root within n steps
    reach = parents < 0
    cur = parents.copy()
    for _ in range(n):
        reach |= cur < 0
        cur = np.where(cur < 0, -1, parents[np.maximum(cur, 0)])
        if reach.all():
            break
    if not reach.all():
        stuck = np.flatnonzero(~reach)
        shown = ", ".join(labels[j] for j in stuck[:5]) + (", ..." if stuck.size > 5 else "")
        raise InputError(f"cycle in the parent links: {shown} never reach the root", name)
    child = np.flatnonzero(parents >= 0)
    lengths = np.linalg.norm(positions[child] - positions[parents[child]], axis=1)
    diag = float(np.linalg.norm(positions.max(0) - positions.min(0)))
    zero = lengths <= 1e-9 * diag
    if zero.any():
        c = int(child[np.argmax(zero)])
        raise InputError(f"zero-length bone from {labels[int(parents[c])]} to {labels[c]}", name)


# ----------------------------------------------------------------------------------------------
# TGF


def read_tgf(path: str | os.PathLike) -> Skeleton:
    """Read a libigl TGF skeleton (see the module docstring for the accepted variants)."""
    path = Path(path)
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
                node_ids.append(int(tok[0]))
                coords.append([float(x) for x in tok[1:4]])
            else:
                if len(tok) < 2:
                    raise ValueError
                edges.append((int(tok[0]), int(tok[1]), lineno))
        except ValueError:
            want = "'id x y z'" if section == 0 else "'a b' (two node indices)"
            raise InputError(f"line {lineno}: expected {want}, got {line[:60]!r}", path) from None
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
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    except OSError as exc:
        raise InputError(f"cannot write file ({exc.strerror or exc})", path) from None


# ----------------------------------------------------------------------------------------------
# JSON


def read_skeleton_json(path: str | os.PathLike) -> Skeleton:
    """Read ``{"names", "parents", "positions", "radii"}`` (names and radii optional)."""
    path = Path(path)
    data = read_json_object(path, "a JSON object with 'positions' and 'parents'")
    for key in ("positions", "parents"):
        if key not in data:
            raise InputError(f"missing key {key!r}", path)
    try:
        positions = np.asarray(data["positions"], dtype=np.float64)
    except (TypeError, ValueError):
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
        except (TypeError, ValueError):
            raise InputError("'radii' must contain numbers or nulls", path) from None
        bad = np.isfinite(radii) & ~(radii > 0)
        bad |= np.isinf(radii)
        if bad.any():
            raise InputError(f"'radii' entry {int(np.argmax(bad))} must be a positive number or null", path)
    labels = _default_labels(n, names)
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


# ----------------------------------------------------------------------------------------------
# dispatch


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
        try:
            from ncflow.gltf import gltf_skeleton
        except ImportError as exc:
            raise InputError(f"glTF skeletons are not available ({exc})", path) from None
        from ncflow.gltf import merge_zero_length_bones

        positions, parents, names = gltf_skeleton(path, time=time, animation=animation)
        # rigs stack joints at one point; merge them (decided on the bind pose, so every time
        # of one file gives the same joint set)
        bind_positions = gltf_skeleton(path)[0] if time is not None else positions
        keep, parents = merge_zero_length_bones(bind_positions, parents)
        positions = np.asarray(positions)[keep]
        names = [names[k] for k in keep] if names is not None else None
        labels = _default_labels(len(parents), names)
        return Skeleton.from_arrays(positions, np.asarray(parents, dtype=np.int64), names, name=path, labels=labels)
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


# ----------------------------------------------------------------------------------------------
# placement against a mesh


def _winding_numbers(points: np.ndarray, triangles: np.ndarray, chunk: int = 200_000) -> np.ndarray:
    """Generalised winding number of each point w.r.t. a triangle soup (±1 inside a closed surface)."""
    out = np.zeros(points.shape[0])
    per = max(1, chunk // max(1, triangles.shape[0]))
    for s in range(0, points.shape[0], per):
        p = points[s : s + per, None, None, :]
        abc = triangles[None] - p  # (P, F, 3, 3)
        a, b, c = abc[:, :, 0], abc[:, :, 1], abc[:, :, 2]
        la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
        num = np.einsum("pfi,pfi->pf", a, np.cross(b, c))
        den = la * lb * lc + np.einsum("pfi,pfi->pf", a, b) * lc + np.einsum("pfi,pfi->pf", b, c) * la
        den += np.einsum("pfi,pfi->pf", c, a) * lb
        out[s : s + per] = 2.0 * np.arctan2(num, den).sum(axis=1) / (4.0 * np.pi)
    return out


def _surface_distance(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    import trimesh

    dist = np.empty(points.shape[0])
    for k, p in enumerate(points):
        cp = trimesh.triangles.closest_point(triangles, np.broadcast_to(p, (triangles.shape[0], 3)))
        dist[k] = float(np.min(np.linalg.norm(cp - p, axis=1)))
    return dist


def check_inside(
    skeleton: Skeleton,
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    *,
    surface_tol: float = 0.005,
    far: float = 0.05,
) -> list[str]:
    """Warnings (one line each) for joints that are not where a skeleton inside the mesh should be.

    A joint counts as outside when its generalised winding number w.r.t. the surface is below ½
    (for closed meshes the same answer as trimesh's ``contains``, without its rtree dependency;
    for open meshes, such as a hand open at the wrist, it still tells inside from outside away
    from the holes). Closed meshes: an outside joint farther than ``surface_tol`` × (bounding-box
    diagonal) from the surface is reported (joints placed on the surface, as fingertip joints
    often are, pass). Open meshes: an outside joint is reported when it is farther than
    ``far`` × diagonal from the surface.
    """
    from ncflow.mesh import mesh_topology

    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    tri = vertices[faces]
    diag = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    closed = not mesh_topology(faces, vertices.shape[0]).has_boundary
    pts = skeleton.positions
    outside = np.abs(_winding_numbers(pts, tri)) < 0.5
    dist = _surface_distance(pts, tri)
    warnings = []
    tol = (surface_tol if closed else far) * diag
    where = "the mesh" if closed else "the (open) mesh"
    for j in np.flatnonzero(outside & (dist > tol)):
        warnings.append(
            f"{skeleton.label(j)} is outside {where} (distance {dist[j]:.4g}, "
            f"{100 * dist[j] / diag:.1f}% of the mesh size)"
        )
    return warnings
