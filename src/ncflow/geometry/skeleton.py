"""The skeleton type and its validation (docs/architecture.md, "Skeleton").

A skeleton is a tree of joints: positions (J, 3) float64 and a parent array (J,) with −1 for the
single root. Bones are the pairs (parent(j), j) for every non-root joint j. Inside ncflow the
joints are stored in a topological order (root first, every parent before its children; joints
given in such an order keep it) and :attr:`Skeleton.file_index` maps back to the order of the
file. :func:`merge_zero_length_bones` drops joints stacked on their parent, as rigs often have
them. Validation takes time linear in the number of joints (sorting J log J), which is at most
:data:`MAX_JOINTS`.

The type is pure NumPy data, so it lives in ``geometry``, where the readers of
:mod:`ncflow.io.skeletons` (TGF, JSON, glTF) can build it; :mod:`ncflow.skeleton` re-exports it
beside the JAX kinematics.
"""

from __future__ import annotations

import dataclasses
import heapq
import os

import numpy as np
import numpy.typing as npt
from jaxtyping import Float, Int

from ncflow.errors import InputError

MAX_JOINTS = 10_000
"""Most joints a skeleton may have (characters have tens to a few hundred)."""


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
        positions: npt.ArrayLike,
        parents: npt.ArrayLike,
        names: list[str] | tuple[str, ...] | None = None,
        radii: npt.ArrayLike | None = None,
        *,
        name: str | os.PathLike | None = None,
        labels: list[str] | None = None,
    ) -> Skeleton:
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
    def bone_names(self) -> list[str]:
        """(B,) "parent -> child" per bone, by joint name or "joint j" (the names ``metrics.json`` uses)."""
        names = self.names or tuple(f"joint {j}" for j in range(self.n_joints))
        return [f"{names[self.parents[j]]} -> {names[j]}" for j in range(1, self.n_joints)]

    @property
    def bone_hops(self) -> Int[np.ndarray, "B B"]:
        """(B, B) how many joints lie between two bones along the tree: 0 for a bone and itself, 1 for
        bones that share a joint (parent and child, siblings), 2 for a bone and its grandchild, ...
        """
        from scipy.sparse.csgraph import shortest_path

        adjacent = shared_joints(self.parents) & ~np.eye(self.n_joints - 1, dtype=bool)
        return shortest_path(adjacent.astype(float), unweighted=True, directed=False).astype(np.int64)

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

    def with_positions(self, positions: Float[np.ndarray, "J 3"]) -> Skeleton:
        """Same tree with other joint positions (internal order), e.g. a posed skeleton."""
        return dataclasses.replace(self, positions=np.asarray(positions, dtype=np.float64))


# ----------------------------------------------------------------------------------------------
# validation


def shared_joints(parents: Int[np.ndarray, " J"]) -> np.ndarray:
    """(B, B) bool: whether two bones (parents[j] → j, j = 1..J−1, the order of :attr:`Skeleton.bones`)
    share a joint — parent and child, siblings; every bone shares with itself.
    """
    par = np.asarray(parents, np.int64)
    head, tail = par[1:], np.arange(1, par.shape[0])
    return (head[:, None] == head) | (head[:, None] == tail) | (tail[:, None] == head) | (tail[:, None] == tail)


def _default_labels(n: int, names=None) -> list[str]:
    """``joint i`` or ``joint i ('name')`` for messages (a name longer than 60 characters cut short)."""
    if names is None:
        return [f"joint {i}" for i in range(n)]
    cut = [s[:57] + "..." if isinstance(s, str) and len(s) > 60 else s for s in names[:n]]
    return [f"joint {i} ({cut[i]!r})" for i in range(n)]


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


def _breadth_first(parents: np.ndarray) -> list[int]:
    """Joints reachable from the roots (parent < 0), parents before children; O(J) (joints on a cycle are left out)."""
    parents = [int(p) for p in parents]
    children: list[list[int]] = [[] for _ in parents]
    for j, p in enumerate(parents):
        if p >= 0:
            children[p].append(j)
    order = [j for j, p in enumerate(parents) if p < 0]
    for j in order:  # the list grows while it is walked: a queue
        order.extend(children[j])
    return order


def validate_skeleton(
    positions: npt.ArrayLike,
    parents: npt.ArrayLike,
    name: str | os.PathLike | None = None,
    labels: list[str] | None = None,
) -> None:
    """Check a joint tree given in any order; raise :class:`InputError` (one line) otherwise.

    Checks: (J, 3) finite positions with 2 ≤ J ≤ :data:`MAX_JOINTS`; (J,) integer parents in
    [−1, J); exactly one root; no cycles (every joint reaches the root); no zero-length bone
    (shorter than 1e-9 of the skeleton's bounding-box diagonal). Linear in J.
    """
    positions = np.asarray(positions)
    parents = np.asarray(parents)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise InputError(f"expected (J, 3) joint positions, got shape {positions.shape}", name)
    n = positions.shape[0]
    if n < 2:
        raise InputError(f"a skeleton needs at least 2 joints (one bone), got {n}", name)
    if n > MAX_JOINTS:
        raise InputError(f"{n} joints, more than the {MAX_JOINTS} a skeleton may have", name)
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
    reach = np.zeros(n, dtype=bool)
    reach[_breadth_first(parents)] = True  # joints reachable from the root; a cycle is not
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


# ----------------------------------------------------------------------------------------------
# JSON


# ----------------------------------------------------------------------------------------------
# dispatch


# ----------------------------------------------------------------------------------------------
# placement against a mesh


def merge_zero_length_bones(
    positions: Float[np.ndarray, "J 3"], parents: Int[np.ndarray, " J"], rel_tol: float = 1e-6
) -> tuple[Int[np.ndarray, " K"], Int[np.ndarray, " K"]]:
    """Drop joints that coincide with their (kept) parent joint, re-attaching their children.

    Rigs often stack joints at one point (Fox.glb: ``_rootJoint`` and ``b_Root_00`` both at the
    origin); a skeleton for matching needs bones of positive length. Joints are visited
    parents first; a joint closer than ``rel_tol`` × (bounding-box diagonal of the joints) to its
    nearest kept ancestor is merged into it. The root is always kept.

    Args:
        positions: (J, 3) joint positions (use the bind pose so the choice is the same for every pose).
        parents: (J,) parent indices, -1 for the single root.
        rel_tol: merge distance, relative to the bounding-box diagonal of the joint positions.

    Returns:
        (kept joint indices (K,) in increasing order, their parents (K,) as indices into the kept list).
    """
    positions = np.asarray(positions, dtype=np.float64)
    parents = np.asarray(parents, dtype=np.int64)
    n = parents.shape[0]
    depth = np.full(n, n + 1, dtype=np.int64)  # joints on a cycle (unreachable) sort last
    for j in _breadth_first(parents):
        depth[j] = 0 if parents[j] < 0 else depth[parents[j]] + 1
    threshold = rel_tol * float(np.linalg.norm(np.ptp(positions, axis=0))) if n else 0.0
    rep = np.arange(n)  # kept joint each joint is represented by
    for j in np.argsort(depth, kind="stable"):
        p = parents[j]
        if p >= 0 and np.linalg.norm(positions[j] - positions[rep[p]]) <= threshold:
            rep[j] = rep[p]
    keep = np.flatnonzero(rep == np.arange(n))
    index = np.full(n, -1, dtype=np.int64)
    index[keep] = np.arange(keep.size)
    new_parents = np.where(parents[keep] < 0, -1, index[rep[np.maximum(parents[keep], 0)]])
    return keep, new_parents.astype(np.int64)
