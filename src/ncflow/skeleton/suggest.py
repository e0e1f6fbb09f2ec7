"""A skeleton for a mesh that has none (``ncflow skeleton suggest``): a tree of joints inside the mesh,
bones along its limbs, from the Reeb graph of its average geodesic distance.

Steps 0–3 (the surface, the AGD, the Reeb graph, pruning, hubs and root) are :mod:`ncflow.skeleton.reeb`'s.

4. **Joints**: every chain of the limb tree between branch nodes and leaves is smoothed (:data:`SMOOTH`) and
   simplified (Douglas–Peucker at :data:`BEND` of the diagonal keeps its bends) and cut into bones of at most
   :data:`MAX_BONE` — between bands that lie further apart than that (a torso, a limb's first bone from its branch
   node) by joints on the bone, except inside a hand (:func:`_add_bone`); a chain ending in a leaf (a limb, a
   finger, a tail) longer than :data:`LIMB` gets at least :data:`LIMB_BONES` bones; joints closer than
   :data:`MIN_BONE` along a chain are merged. A limb that leaves the body at a branch node gets a joint at its base
   (:func:`_limb_joints`) — where it has left the body (``bases="ring"``), or moved into the body by the limb's
   radius if it is one of a pair (``bases="inside"``, :func:`_base_inward`: a shoulder, a hip, a knuckle), or the
   latter only for limbs in groups of four or more (``bases="auto"``, the default: fingers and toes; there the
   knuckle goes :data:`KNUCKLE` of the finger's length in, and the finger gets exactly three bones, cut at
   :data:`PHALANGES`, :func:`_finger_joints`) — and alike limbs from one node alike joints
   (:func:`_alike_limbs_alike`). **Other poses** of the same body (a match's target, a track's frames) show where a
   limb that is straight here articulates: where their alike limbs bend, at the same AGD below the tip, this limb is
   cut too (:func:`_bends_seen`), and then only by length where bones are still too long.
5. **Inside**: a limb's tip that the generalised winding number puts outside a closed mesh is moved back
   along its bone to just inside; any other joint outside to the middle of the mesh's inside along the
   inward normal at its nearest surface point.

Over 500 lines: one concept, the joints placed on a limb tree, whose steps share the tree's chains.

Written by hand: the curve-skeleton libraries (mesh contraction in skeletor, CGAL's mean-curvature
skeleton) are GPL or C++, and give dense curves, not a joint tree; learned riggers need a GPU. Limits:
without another pose, joints are placed by length and bends in this one pose, not where the body
articulates (a straight arm gets its elbow at a third of its length); a mesh with no limbs (a sphere) gets a
short chain.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError
from ncflow.geometry.closest import closest_points_on_surface
from ncflow.geometry.skeleton import Skeleton
from ncflow.geometry.winding import signed_volume, winding_numbers
from ncflow.skeleton.reeb import LimbTree, arc_lengths, limb_tree

BEND = 0.03
"""Douglas–Peucker tolerance along a chain (share of the diagonal): bends deeper than this keep a joint."""
MAX_BONE = 0.12
"""Longest bone (share of the diagonal)."""
MIN_BONE = 0.04
"""Joints closer than this along a chain (share of the diagonal) are merged."""
MATCH_LEVEL = 0.08
"""Limbs of the two poses whose tips' AGD (over the mean AGD) differ by less than this are alike."""
ALIKE = 1.5
"""Limbs from one node whose lengths are within this ratio get joints at the same shares of their length."""
SMOOTH = 3
"""Passes of a (1/4, 1/2, 1/4) smoothing of a chain's band centroids before its joints are chosen."""
LIMB = 0.15
"""A chain ending in a leaf at least this long (share of the diagonal) is a limb ..."""
LIMB_BONES = 3
"""... and gets at least this many bones (upper, lower, extremity; a finger's phalanges)."""
BASE_REACH = 0.7
"""A limb's base joint moves inward by at most this share of its distance (along the limb) from the branch
node it hangs from (:func:`_base_inward`)."""
GROUP = 4
"""Limbs in groups of at least this many alike ones from one node (a hand's fingers, a foot's toes) get their
base joints inside with ``bases="auto"``; a body's groups are pairs or threes (two arms and the head, two
legs and a tail), a hand's five or six (the fingers and the wrist)."""
KNUCKLE = 0.27
"""How far inside the palm a finger's knuckle lies with ``bases="auto"``, as a share of the finger's length out
of the body (from its web ring to its tip): the web lies about halfway along the proximal phalanx. Measured on
drawn hand skeletons against suggested fingers: MANO 0.34, the generated hands 0.21."""
PHALANGES = (0.25, 0.62)
"""Where a finger's two inner joints lie with ``bases="auto"``, as shares of its length out of the body (web ring
to tip). Measured as :data:`KNUCKLE`: MANO 0.16 and 0.55, the generated hands 0.33 and 0.68 (from the knuckle: a
proximal phalanx about 40–50 % of the finger, the middle one 30 %)."""
BASES = ("ring", "inside", "auto")
"""Where a limb's base joint goes (:func:`suggest_skeleton`): the first ring outside the body; a radius
further in for paired limbs; or that only for limbs in groups (:data:`GROUP`: fingers, toes), the first ring
elsewhere. None is right on every body (docs/skeleton-suggest.md): ``ncflow match`` without a skeleton uses
the setting ``skeleton_bases`` ("choose": the first two tried, the one whose pose explains the target best
kept)."""


@dataclasses.dataclass(frozen=True)
class SuggestedSkeleton:
    """A suggested skeleton and how it was found.

    Attributes:
        skeleton: the joint tree (root first), joints named ``root``, ``j1``, ...
        agd: (V,) the average geodesic distance of every vertex.
        n_nodes: nodes of the Reeb graph before pruning.
        n_leaves: leaves of the skeleton (limb tips).
        moved_inside: joints moved inside the mesh (step 5).
        bends_seen: chain points cut because the other pose bends its limb there (0 without one).
        bases: where limbs' base joints were put (:data:`BASES`).
    """

    skeleton: Skeleton
    agd: Float[np.ndarray, " V"]
    n_nodes: int
    n_leaves: int
    moved_inside: int
    bends_seen: int = 0
    bases: str = "ring"


def _douglas_peucker(points: np.ndarray, tolerance: float) -> list[int]:
    """Indices of the points that a Douglas–Peucker simplification at ``tolerance`` keeps (ends included);
    a stack of spans, not recursion, so that a chain of any length is simplified.
    """
    last = points.shape[0] - 1
    keep, spans = {0, last}, [(0, last)]
    while spans:
        i, j = spans.pop()
        if j - i < 2:
            continue
        ab = points[j] - points[i]
        ab = ab / max(np.linalg.norm(ab), 1e-30)
        dist = np.linalg.norm(np.cross(points[i + 1 : j] - points[i], ab), axis=1)
        k = i + 1 + int(np.argmax(dist))
        if dist[k - i - 1] > tolerance:
            keep.add(k)
            spans += [(i, k), (k, j)]
    return sorted(keep)


def _smoothed(points: np.ndarray) -> np.ndarray:
    """A chain's points smoothed by :data:`SMOOTH` passes of (1/4, 1/2, 1/4), its ends fixed: band pieces
    that zigzag across a limb do not become bends.
    """
    p = points.copy()
    for _ in range(SMOOTH):
        p[1:-1] = 0.25 * p[:-2] + 0.5 * p[1:-1] + 0.25 * p[2:]
    return p


def _chain_joints(points: np.ndarray, to_leaf: bool, diag: float, bends: tuple[int, ...] = ()) -> list[int]:
    """Indices along a chain's points (0 = its start, already a joint) that become joints. ``bends``: points
    where the other pose bends this limb (:func:`_bends_seen`); with them, the chain is cut there and at its
    own bends, and only bones longer than :data:`MAX_BONE` (and a limb of fewer than :data:`LIMB_BONES`
    bones, at its longest bone) are split further; without them, also at equal lengths.
    """
    arc = arc_lengths(points)
    last = points.shape[0] - 1
    keep = set(_douglas_peucker(points, BEND * diag))
    if bends:
        keep.update(k for k in bends if MIN_BONE * diag <= arc[k] <= arc[-1] - MIN_BONE * diag)
        limb = to_leaf and arc[-1] >= LIMB * diag
        while True:
            cuts = sorted(keep)
            spans = [(arc[b] - arc[a], a, b) for a, b in zip(cuts[:-1], cuts[1:], strict=True)]
            length, a, b = max(spans)
            if not (length > MAX_BONE * diag or (limb and len(spans) < LIMB_BONES)) or b - a < 2:
                break
            keep.add(int(a + np.argmin(np.abs(arc[a + 1 : b] - 0.5 * (arc[a] + arc[b])))) + 1)
    else:
        n_bones = max(1, int(np.ceil(arc[-1] / (MAX_BONE * diag))))
        if to_leaf and arc[-1] >= LIMB * diag:
            n_bones = max(n_bones, LIMB_BONES)
        keep.update(int(np.argmin(np.abs(arc - arc[-1] * k / n_bones))) for k in range(1, n_bones))
    picked = [0]
    for k in sorted(keep - {0}):
        if k == last or arc[k] - arc[picked[-1]] >= MIN_BONE * diag:
            if k == last and len(picked) > 1 and arc[k] - arc[picked[-1]] < MIN_BONE * diag:
                picked.pop()
            picked.append(k)
    return picked[1:]


def _first_band(arc: np.ndarray, diag: float) -> int:
    """The first point of a limb's chain (arc lengths ``arc`` from the branch node) at least half
    :data:`MIN_BONE` from the branch: where the limb has left the body (the last point if none is).
    """
    far = np.flatnonzero(arc >= 0.5 * MIN_BONE * diag)
    return int(far[0]) if far.size else arc.shape[0] - 1


def _limb_joints(points: np.ndarray, diag: float, bends: tuple[int, ...] = ()) -> list[int]:
    """:func:`_chain_joints` of a limb that leaves the body at a branch node, with a joint at its base: the
    first point at least half :data:`MIN_BONE` from the branch (the limb's first band: the shoulder, the
    hip, a finger's knuckle), so that the limb turns where it leaves the body and the bone from the branch
    node to the base (a clavicle, a pelvis bone, a metacarpal) goes with the body.
    """
    arc = arc_lengths(points)
    base = _first_band(arc, diag)
    if base >= points.shape[0] - 2 or arc[-1] - arc[base] < MIN_BONE * diag:
        return _chain_joints(points, True, diag, bends)
    rest = _chain_joints(points[base:], True, diag, tuple(k - base for k in bends if k > base))
    return [base] + [base + k for k in rest]


def _finger_joints(points: np.ndarray, diag: float, bends: tuple[int, ...] = ()) -> list[int]:
    """:func:`_limb_joints` of a finger (a limb of a group, :func:`_grouped_limbs`): a joint at its base and
    exactly three bones to the tip, as a drawn hand has (knuckle, two inner joints, tip), the inner joints at
    :data:`PHALANGES` of its length. Cut by length and every bend seen, a MANO finger got four to six bones:
    joints the pose search can bend where the finger cannot. The bends of the finger itself and of the other
    poses are not used: a finger's chain has 7–10 bands, and a bend found on them lay 0.1–0.2 of the finger
    from its joint, further than these shares (generated hands and MANO, docs/skeleton-suggest.md). A chain
    too short for three bones is cut as any limb (``bends`` are for that).
    """
    arc = arc_lengths(points)
    last = points.shape[0] - 1
    base = _first_band(arc, diag)
    if last - base < 3:
        return _limb_joints(points, diag, bends)
    share = (arc - arc[base]) / max(float(arc[-1] - arc[base]), 1e-30)
    cuts = [base]
    for i, s in enumerate(PHALANGES):
        room = range(cuts[-1] + 1, last - (len(PHALANGES) - i) + 1)  # leaves a point for every later cut
        cuts.append(min(room, key=lambda k: abs(share[k] - s)))
    return [*cuts, last]


def _base_inward(tree: LimbTree, chain: list[int], k: int, finger: bool = False) -> np.ndarray:
    """The base joint of a limb (point ``k`` of ``chain``, a limb that leaves the body at a branch node) moved
    back along the limb's axis by the limb's radius there, towards the branch node but at most
    :data:`BASE_REACH` of the way: the limb's first band lies where the limb has left the body (an armpit's,
    a crotch's, a finger's web ring), while a drawn skeleton turns the limb about a point inside the body on
    its axis (the shoulder, the hip, the knuckle), about a radius further in. Only for paired limbs
    (:func:`_paired_limbs`: a biped's neck joint is where the neck leaves the body); where another pose bends
    the limb at or above its base (:func:`_bends_seen`), the band keeps a joint too (the limb is seen to
    turn there) and this one is added above it. A ``finger``'s base goes :data:`KNUCKLE` of its length in
    instead of a radius.
    """
    points = _smoothed(tree.centroids[chain])
    arc = arc_lengths(points)
    ahead = np.flatnonzero(arc >= arc[k] + MIN_BONE * tree.diag)
    stop = ahead[0] if ahead.size else len(chain) - 1
    radius = float(np.median(tree.radii[chain[k : stop + 1]]))
    far = points[ahead[0]] if ahead.size else points[-1]
    axis = far - points[k]
    axis = axis / max(float(np.linalg.norm(axis)), 1e-30)
    base = tree.centroids[chain[k]]
    room = float(np.dot(base - points[0], axis))
    depth = KNUCKLE * float(arc[-1] - arc[k]) if finger else radius
    return base - min(depth, BASE_REACH * max(room, 0.0)) * axis


def _alike(a: float, b: float) -> bool:
    """Two limbs' lengths within :data:`ALIKE` of each other."""
    return bool(a <= ALIKE * b and b <= ALIKE * a)


def _alike_beside(tree: LimbTree) -> dict[int, int]:
    """For each limb (chain index of a chain ending in a leaf), how many alike limbs (:func:`_alike`) hang from
    the same node beside it.
    """
    length = [float(arc_lengths(tree.centroids[c])[-1]) for c in tree.chains]
    limbs = [c for c, chain in enumerate(tree.chains) if len(tree.adj[chain[-1]]) == 1]
    return {
        c: sum(r != c and tree.chains[r][0] == tree.chains[c][0] and _alike(length[r], length[c]) for r in limbs)
        for c in limbs
    }


def _paired_limbs(tree: LimbTree) -> set[int]:
    """The limbs (chain indices) that hang from a node with an alike limb beside them (:func:`_alike`): arms,
    legs, fingers — a biped's head has none. (Thickness does not tell them apart: a thumb is as thick at its
    base as a hand's wrist.)
    """
    return {c for c, n in _alike_beside(tree).items() if n >= 1}


def _grouped_limbs(tree: LimbTree) -> set[int]:
    """The limbs that hang from a node with at least :data:`GROUP` − 1 alike limbs beside them
    (:func:`_alike`): a hand's fingers, a foot's toes — not a pair of arms or legs.
    """
    return {c for c, n in _alike_beside(tree).items() if n >= GROUP - 1}


def _alike_limbs_alike(tree: LimbTree, picks: list[list[int]], kept: set[int] = frozenset()) -> list[list[int]]:
    """Limbs that hang from the same node and are alike in length (within :data:`ALIKE`: left and right
    legs, fingers) cut at the same shares of their length as the one of them with the most joints: a
    drawn skeleton gives alike limbs alike joints, and the pose search tries exchanging only limbs of one
    shape. The limbs in ``kept`` (fingers, cut by :func:`_finger_joints`) keep their cuts.
    """
    out = [list(p) for p in picks]
    arcs = [arc_lengths(tree.centroids[c]) for c in tree.chains]
    limbs = [c for c, chain in enumerate(tree.chains) if len(tree.adj[chain[-1]]) == 1]
    for start in {tree.chains[c][0] for c in limbs}:
        group = sorted((c for c in limbs if tree.chains[c][0] == start), key=lambda c: -len(picks[c]))
        for c in group:
            ref = next(r for r in group if _alike(arcs[r][-1], arcs[c][-1]))
            if ref == c or c in kept or len(picks[ref]) == len(picks[c]):
                continue
            share = arcs[c] / max(arcs[c][-1], 1e-30)
            cuts = [int(np.argmin(np.abs(share - arcs[ref][k] / arcs[ref][-1]))) for k in picks[ref][:-1]]
            for i in range(len(cuts)):  # one point each, in order (a short chain has few points)
                cuts[i] = max(cuts[i], cuts[i - 1] + 1 if i else 1)
            if not cuts or cuts[-1] < len(share) - 1:
                out[c] = [*cuts, len(share) - 1]
    return out


def _sharpest(points: np.ndarray, k: int) -> int:
    """Of the inner points ``k - 1``, ``k``, ``k + 1`` of a polyline, the one where it turns most: a bend
    found on the smoothed chain (which rounds a corner over its neighbours, most where the first band lies
    far from the branch node) put back on the band where the limb bends.
    """
    near = [j for j in (k - 1, k, k + 1) if 0 < j < points.shape[0] - 1]
    turn = [float(np.dot(_unit(points[j] - points[j - 1]), _unit(points[j + 1] - points[j]))) for j in near]
    return near[int(np.argmin(turn))]


def _unit(x: np.ndarray) -> np.ndarray:
    return x / max(float(np.linalg.norm(x)), 1e-30)


def _bends_seen(tree: LimbTree, other: LimbTree, sharpest: bool = False) -> dict[int, tuple[int, ...]]:
    """For each limb of ``tree`` (the chain's index), the chain points nearest in AGD to where the limbs of
    ``other`` (the same body in another pose) that end at about the same AGD bend (their Douglas–Peucker
    joints at :data:`BEND`), matched by their AGD below the limb's tip. The AGD is intrinsic, and along a
    limb away from the body it grows as the distance along the limb: a bend seen in the other pose (an
    elbow bent there, straight here) at some AGD below its tip marks the same place on this limb, whatever
    the bend did to the AGD elsewhere; limbs alike (left and right, fingers) share their bends, as their
    joints are alike. ``sharpest``: each bend put back on the band of the raw chain where it turns most
    (:func:`_sharpest`).
    """
    seen = []
    for chain in other.limbs():
        raw = other.centroids[chain]
        inner = _douglas_peucker(_smoothed(raw), BEND * other.diag)[1:-1]
        if sharpest:
            inner = [_sharpest(raw, k) for k in inner]
        tip = float(other.level[chain[-1]])
        seen.append((tip, [tip - float(other.level[chain[k]]) for k in inner]))
    out = {}
    for c, chain in enumerate(tree.chains):
        if len(tree.adj[chain[-1]]) != 1 or len(chain) < 3:
            continue
        depth = tree.level[chain[-1]] - tree.level[chain]  # AGD below the tip: about the distance along the limb
        found = set()
        for tip, bends in seen:
            if abs(tip - tree.level[chain[-1]]) > MATCH_LEVEL:
                continue
            for b in bends:
                if 0.0 < b < depth[0]:
                    found.add(int(np.argmin(np.abs(depth - b))))
        if found:
            out[c] = tuple(sorted(found))
    return out


def _add_bone(joints: list, parents: list, parent: int, at: np.ndarray, longest: float) -> int:
    """Append a joint at ``at`` below joint ``parent`` (lists changed in place) and return its index; a bone
    longer than ``longest`` is cut into equal bones by joints on it. Chain points are a limb tree's bands,
    and where bands are far apart — a torso, whose level sets of the AGD are few, or a limb's first bone from
    the branch node to where it has left the body — :func:`_chain_joints` has no point to cut at: the spine
    between the pelvis and the chest, a clavicle, the bone from the pelvis to a hip come out whole.
    """
    start = np.asarray(joints[parent])
    n = max(1, int(np.ceil(float(np.linalg.norm(at - start)) / longest - 1e-9)))  # longest = inf: 1
    for i in range(1, n + 1):
        joints.append(at if i == n else start + (at - start) * (i / n))
        parents.append(parent)
        parent = len(joints) - 1
    return parent


def _move_inside(
    joints: np.ndarray, parents: np.ndarray, vertices: np.ndarray, faces: np.ndarray, diag: float
) -> tuple[np.ndarray, int]:
    """Joints outside the closed mesh moved inside: a limb's tip (a leaf, whose last band is a cap at the
    surface) back along its bone to just past where the bone enters the mesh; any other joint to the middle
    of the mesh's inside along the inward normal at its nearest surface point (a torus's ring centroids lie
    in its hole). Left where no inside is found (an open or very thin mesh).
    """
    tri = vertices[faces]
    outside = np.flatnonzero(np.abs(winding_numbers(joints, tri)) < 0.5)
    if outside.size == 0:
        return joints, 0
    out = joints.copy()
    is_leaf = np.bincount(parents[parents >= 0], minlength=joints.shape[0]) == 0
    is_leaf[0] = False
    along = np.linspace(0.0, 1.0, 41)[1:]
    moved_back = set()
    for j in outside[is_leaf[outside]]:
        probes = joints[j] + along[:, None] * (joints[parents[j]] - joints[j])
        inside = np.abs(winding_numbers(probes, tri)) >= 0.5
        if inside.any():
            out[j] = probes[min(int(np.argmax(inside)) + 1, along.size - 1)]
            moved_back.add(int(j))
    outside = np.asarray([j for j in outside if int(j) not in moved_back], np.int64)
    moved = len(moved_back)
    if outside.size == 0:
        return out, moved
    _, face_index, bary = closest_points_on_surface(joints[outside], vertices, faces)
    near = np.einsum("nk,nkd->nd", bary, tri[face_index])
    normals = np.cross(tri[face_index, 1] - tri[face_index, 0], tri[face_index, 2] - tri[face_index, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
    sign = 1.0 if signed_volume(vertices, faces) >= 0 else -1.0  # outward normals: inward is −n
    steps = np.linspace(0.0, 0.3 * diag, 61)[1:]
    for k, j in enumerate(outside):
        probes = near[k] - sign * normals[k] * steps[:, None]
        inside = np.abs(winding_numbers(probes, tri)) >= 0.5
        if inside.any():
            first = int(np.argmax(inside))
            last = first + (int(np.argmin(inside[first:])) if not inside[first:].all() else inside[first:].size) - 1
            out[j] = 0.5 * (probes[first] + probes[last])
            moved += 1
    return out, moved


def suggest_skeleton(
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    *,
    name: str | None = None,
    other_poses: Sequence[tuple[Float[np.ndarray, "W 3"], Int[np.ndarray, "G 3"]]] = (),
    bases: str = "auto",
) -> SuggestedSkeleton:
    """A joint tree for a character mesh (module docstring); deterministic.

    Args:
        vertices: (V, 3) the mesh (repaired, :func:`ncflow.geometry.mesh.repaired_mesh`); of several
            connected pieces the largest by area carries the skeleton.
        faces: (F, 3) triangles.
        name: the skeleton's name.
        other_poses: the same body in other poses (a match's target, a sequence's frames: vertices, faces,
            each its own triangulation), whose bent limbs show where this mesh's straight ones articulate
            (:func:`_bends_seen`).
        bases: where a limb's base joint goes (:data:`BASES`): "ring", the limb's first ring outside the
            body; "inside", for a limb with an alike one beside it, a radius further in (:func:`_base_inward`),
            with the other poses' bends put back where their limbs turn most; "auto" (the default), that for
            limbs in groups of :data:`GROUP` or more (:func:`_grouped_limbs`: fingers, toes) and "ring"
            elsewhere.

    Raises:
        InputError: a mesh too small to have a shape (fewer than 20 faces).
    """
    return suggest_skeletons(vertices, faces, name=name, other_poses=other_poses, bases=(bases,))[0]


def suggest_skeletons(
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    *,
    name: str | None = None,
    other_poses: Sequence[tuple[Float[np.ndarray, "W 3"], Int[np.ndarray, "G 3"]]] = (),
    bases: Sequence[str] = BASES,
) -> list[SuggestedSkeleton]:
    """:func:`suggest_skeleton` for each of ``bases``, from one limb tree of the mesh and of each other pose.
    A way after the first whose joints make no valid skeleton is left out (the first raises).
    """
    for b in bases:
        if b not in BASES:
            raise ValueError(f"bases must be one of {BASES}, not {b!r}")
    tree = limb_tree(vertices, faces)
    others = [limb_tree(*other) for other in other_poses]
    found = [_joint_tree(tree, others, name, bases[0])]
    for b in bases[1:]:
        try:
            found.append(_joint_tree(tree, others, name, b))
        except InputError:
            continue
    return found


def _joint_tree(tree: LimbTree, others: list[LimbTree], name: str | None, bases: str) -> SuggestedSkeleton:
    """Steps 4–5 on the limb tree ``tree``, the other poses' trees showing the bends."""
    moved_in = {"ring": lambda _: set(), "inside": _paired_limbs, "auto": _grouped_limbs}[bases](tree)
    sharpened = set(range(len(tree.chains))) if bases == "inside" else moved_in  # bends put where limbs turn most
    bends: dict[int, tuple[int, ...]] = {}
    for other in others:
        seen = {
            sharpest: _bends_seen(tree, other, sharpest=sharpest) if chains else {}
            for sharpest, chains in ((True, sharpened), (False, set(range(len(tree.chains))) - sharpened))
        }
        for c in set(seen[True]) | set(seen[False]):
            bends[c] = tuple(sorted(set(bends.get(c, ())) | set(seen[c in sharpened].get(c, ()))))
    diag = tree.diag
    fingers = moved_in if bases == "auto" else set()
    picks = []
    for c, chain in enumerate(tree.chains):
        to_leaf = len(tree.adj[chain[-1]]) == 1
        points = _smoothed(tree.centroids[chain])
        if to_leaf and len(tree.adj[chain[0]]) > 2:
            picks.append((_finger_joints if c in fingers else _limb_joints)(points, diag, bends.get(c, ())))
        else:
            picks.append(_chain_joints(points, to_leaf, diag, bends.get(c, ())))
    picks = _alike_limbs_alike(tree, picks, kept=fingers)
    joints, parents, index = [tree.centroids[tree.root]], [-1], {tree.root: 0}
    hubs = {tree.chains[c][0] for c in _grouped_limbs(tree)}  # a hand: its palm and fingers are not cut
    in_hand = {0} if tree.root in hubs else set()
    for c, (chain, picked) in enumerate(zip(tree.chains, picks, strict=True)):
        parent = index[chain[0]]
        base = len(picked) > 1 and c in moved_in and len(tree.adj[chain[0]]) > 2
        for i, k in enumerate(picked):
            node = chain[k]
            if node not in index:
                at = tree.centroids[node]
                hand, first = parent in in_hand or node in hubs, len(joints)
                longest = np.inf if hand else MAX_BONE * diag
                if i == 0 and base:
                    inward = _base_inward(tree, chain, k, finger=c in fingers)
                    if c in fingers or not any(b <= k for b in bends.get(c, ())):
                        at = inward
                    elif np.linalg.norm(inward - at) > 1e-3 * diag:  # seen bending here: one inside too
                        parent = _add_bone(joints, parents, parent, inward, longest)
                parent = _add_bone(joints, parents, parent, at, longest)
                index[node] = parent
                if hand:
                    in_hand.update(range(first, len(joints)))
            parent = index[node]
    positions, moved = _move_inside(np.asarray(joints), np.asarray(parents), *tree.shape, diag)
    names = ["root"] + [f"j{k}" for k in range(1, len(joints))]
    skeleton = Skeleton.from_arrays(positions, np.asarray(parents), names, name=name)
    n_leaves = int(np.sum(np.bincount(np.asarray(parents[1:]), minlength=len(joints)) == 0))
    n_bends = sum(map(len, bends.values()))
    return SuggestedSkeleton(skeleton, tree.agd[: tree.n_given], len(tree.centroids), n_leaves, moved, n_bends, bases)
