"""Placement checks of a skeleton against its mesh: joints that are not inside the surface.

:func:`check_inside` returns one warning line per joint outside the surface (generalised winding
number below ½) and farther from it than a tolerance relative to the mesh size, so joints placed
on the surface, as fingertip joints often are, pass. It works for open meshes too (a hand open at
the wrist), where it still tells inside from outside away from the holes. ``ncflow skeleton info``
prints these warnings, and the matcher refuses a skeleton whose joints lie far outside the source
(usually a skeleton in other coordinates than its mesh).
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Bool, Float, Int

from ncflow.geometry.skeleton import Skeleton, shared_joints
from ncflow.geometry.topology import mesh_topology
from ncflow.geometry.winding import winding_numbers
from ncflow.skeleton.samples import DEFAULT_AXIAL_RANGE, bone_axes


def _surface_distance(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    import trimesh

    dist = np.empty(points.shape[0])
    for k, p in enumerate(points):
        cp = trimesh.triangles.closest_point(triangles, np.broadcast_to(p, (triangles.shape[0], 3)))
        dist[k] = float(np.min(np.linalg.norm(cp - p, axis=1)))
    return dist


DEFAULT_TOLERANCES = (0.005, 0.05)
"""(surface_tol, far) of :func:`check_inside`."""


def check_inside(
    skeleton: Skeleton,
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    *,
    surface_tol: float = DEFAULT_TOLERANCES[0],
    far: float = DEFAULT_TOLERANCES[1],
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
    return check_inside_at(skeleton, vertices, faces, [(surface_tol, far)])[0]


def check_inside_at(
    skeleton: Skeleton,
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    tolerances: list[tuple[float, float]],
) -> list[list[str]]:
    """:func:`check_inside` at several (surface_tol, far) pairs, the joints' winding numbers and
    distances to the surface measured once (the costly part: every joint against every triangle).
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    tri = vertices[faces]
    diag = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    closed = not mesh_topology(faces, vertices.shape[0]).has_boundary
    pts = skeleton.positions
    outside = np.abs(winding_numbers(pts, tri)) < 0.5
    dist = _surface_distance(pts, tri)
    where = "the mesh" if closed else "the (open) mesh"
    return [
        [
            f"{skeleton.label(int(j))} is outside {where} (distance {dist[j]:.4g}, "
            f"{100 * dist[j] / diag:.1f}% of the mesh size)"
            for j in np.flatnonzero(outside & (dist > (surface_tol if closed else far) * diag))
        ]
        for surface_tol, far in tolerances
    ]


AXIS_PROBES = 17
"""Points per bone axis at which :func:`inside_axial_ranges` asks whether the bone is inside its mesh."""

_CLEAR_CHUNK = 1 << 20
"""Probe–bone pairs a block of :func:`clear_axial_ranges` (bounded memory for a skeleton of many bones)."""


def inside_axial_ranges(
    skeleton: Skeleton,
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    axial_range: tuple[float, float] = DEFAULT_AXIAL_RANGE,
) -> tuple[Float[np.ndarray, "B 2"], Float[np.ndarray, " B"]]:
    """Per bone, the part of ``axial_range`` (z / L) along which its axis is inside the mesh, and the
    share of the axis that is.

    :data:`AXIS_PROBES` points evenly spaced over ``axial_range`` on each bone's axis are inside where
    their generalised winding number is ½ or more in magnitude (a mesh wound inside out counts too;
    :func:`~ncflow.geometry.winding.winding_numbers`).
    A bone's range is its longest run of inside probes, widened by half a probe spacing at each end
    within ``axial_range`` — a bone that runs outside the body, as a root bone from the ground to the
    hips does in many rigs, keeps the samples (:func:`~ncflow.skeleton.samples.sample_bones`) and the
    rigid core (:class:`ncflow.flow.SkinnedField`) on its part inside the flesh. A bone entirely inside
    gets ``axial_range``; one with no inside probe also gets ``axial_range``, and a share of 0.

    Returns:
        ranges (B, 2) in [lo, hi] of ``axial_range``, and inside (B,) the share of inside probes.
    """
    lo, hi = axial_range
    z = np.linspace(lo, hi, AXIS_PROBES)
    start = skeleton.positions[skeleton.parents[1:]]
    vec = skeleton.positions[1:] - start
    probes = start[:, None, :] + z[None, :, None] * vec[:, None, :]  # (B, P, 3)
    tri = np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)]
    inside = np.abs(winding_numbers(probes.reshape(-1, 3), tri)).reshape(vec.shape[0], AXIS_PROBES) >= 0.5
    ranges = np.tile([lo, hi], (vec.shape[0], 1)).astype(np.float64)
    runs = _longest_runs(inside, np.broadcast_to(z, inside.shape), ranges, 0.5 * (hi - lo) / (AXIS_PROBES - 1))
    return runs, inside.mean(axis=1)


def _longest_runs(keep, z, ranges, widen: float):
    """Per row of ``keep`` (B, P) (the probes at shares ``z`` (B, P) of each bone's length, over its
    ``ranges`` (B, 2)): the longest run of kept probes, widened by ``widen`` at each end within the bone's
    range; the range itself where every probe or none is kept.
    """
    out = np.array(ranges, np.float64)
    for b, row in enumerate(keep):
        if row.all() or not row.any():
            continue
        edges = np.diff(np.concatenate([[0], row.astype(np.int8), [0]]))
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
        k = int(np.argmax(ends - starts))
        out[b] = max(ranges[b, 0], z[b, starts[k]] - widen), min(ranges[b, 1], z[b, ends[k]] + widen)
    return out


def clear_axial_ranges(
    skeleton: Skeleton, ranges: Float[np.ndarray, "B 2"], radii: Float[np.ndarray, " B"]
) -> Float[np.ndarray, "B 2"]:
    """Per bone, the part of ``ranges`` (z / L, e.g. :func:`inside_axial_ranges`') whose sample cylinder keeps
    clear of every other bone's that does not share a joint with it: radius ρ_b L_b (``radii`` ρ, as
    :func:`~ncflow.skeleton.samples.sample_bones` draws them). Where two bones' cylinders overlap — a
    captured pinch or fist whose fingertips press into each other, bones nearly touching — a point of both
    cannot move rigidly with each once they part, so neither bone is sampled (nor cored) there.

    :data:`AXIS_PROBES` points over each bone's range are clear where their distance to every such bone's
    axis (over its own range) is at least the sum of the two radii; the range kept is the longest clear run
    (not widened); a bone with no clear probe, or no probe in contact, keeps its range.
    """
    ranges = np.asarray(ranges, np.float64)
    pos, bones = np.asarray(skeleton.positions, np.float64), np.asarray(skeleton.bones)
    heads, vec = pos[bones[:, 0]], pos[bones[:, 1]] - pos[bones[:, 0]]
    n = vec.shape[0]
    if n < 2:
        return ranges.copy()
    t = np.linspace(0.0, 1.0, AXIS_PROBES)
    z = ranges[:, :1] + t[None, :] * (ranges[:, 1:] - ranges[:, :1])  # (B, P)
    probes = heads[:, None, :] + z[..., None] * vec[:, None, :]  # (B, P, 3)
    a, ab = heads + ranges[:, :1] * vec, (ranges[:, 1:] - ranges[:, :1]) * vec  # each bone's own range
    apart = ~shared_joints(skeleton.parents)
    reach = np.asarray(radii, np.float64) * np.asarray(skeleton.bone_lengths, np.float64)
    touching = np.zeros((n, AXIS_PROBES), bool)
    step = max(1, _CLEAR_CHUNK // (AXIS_PROBES * n))  # bones a block: (step · P, B, 3) at most
    for lo in range(0, n, step):
        rows = slice(lo, lo + step)
        dist = _segment_distances(probes[rows].reshape(-1, 3), a, ab)[1].reshape(-1, AXIS_PROBES, n)
        near = dist < reach[rows, None, None] + reach[None, None, :]
        touching[rows] = (near & apart[rows, None, :]).any(axis=2)
    return _longest_runs(~touching, z, ranges, 0.0)


RIM_POINTS = 12
"""Points around each probe's disc (at its radius and at half of it) where :func:`clear_joint_ranges` measures."""


def clear_joint_ranges(
    skeleton: Skeleton,
    ranges: Float[np.ndarray, "B 2"],
    radii: Float[np.ndarray, " B"],
    clearance: float,
    cored: Bool[np.ndarray, " B"] | None = None,
) -> Float[np.ndarray, "B 2"]:
    """Per bone and its parent bone (they meet at a joint and move apart when it bends), the parts of
    their ``ranges`` (z / L) whose sample cylinders (radius ρ_b L_b, ``radii`` ρ) keep clear of the other's
    rigid core: the capsule of radius ``clearance`` · ρ_o L_o around the other bone's range (the core and
    the part of its ramp where a point would still share the other bone's motion;
    :func:`ncflow.flow.bone_weights.core_clearance`). At a tight bend — a fist's knuckle, the long bone
    of a palm whose core's end cap reaches over the finger's first phalanx — a point in both cores is
    split between two motions and cannot stay rigid with either; neither bone is sampled (nor cored)
    there.

    Where the two conflict (a point of either cylinder, its axis, rim and half-rim at
    :data:`AXIS_PROBES` heights with :data:`RIM_POINTS` around, inside the other's capsule), the parent's
    range is cut back from the joint's end or the child's from its start, on that bone's probe heights,
    whichever clears with fewer of its :data:`AXIS_PROBES` steps lost (on a tie, the one that loses less
    length, then the parent); a pair no single cut clears is left as it was. Bones of one joint's children
    move alike and are not compared; bones that share no joint are :func:`clear_axial_ranges`' case.
    ``cored`` (B,) bool: the bones that have a core (default all); a bone without one only yields. Parents
    are visited before their children (the skeleton's order), so a bone cut at its start by its parent may
    still be cut at its end by its own children.
    """
    out = np.array(ranges, np.float64)
    par = np.asarray(skeleton.parents, np.int64)
    heads, length, e1, e2, e3 = (np.asarray(x, np.float64) for x in bone_axes(skeleton))
    vec = e1 * length[:, None]
    reach = np.asarray(radii, np.float64) * length
    core = reach * clearance * (np.ones(len(reach), bool) if cored is None else np.asarray(cored, bool))
    disc = _disc_offsets(e2, e3, reach)  # (B, D, 3)

    def conflict(o: int, b: int, ro: np.ndarray, rb: np.ndarray) -> bool:
        for x, y, rx, ry in ((o, b, ro, rb), (b, o, rb, ro)):
            if core[y] <= 0:
                continue
            z = np.linspace(rx[0], rx[1], AXIS_PROBES)
            pts = (heads[x] + z[:, None, None] * vec[x] + disc[x][None]).reshape(-1, 3)
            a, ab = heads[y] + ry[0] * vec[y], (ry[1] - ry[0]) * vec[y]
            if _segment_distances(pts, a[None], ab[None])[1].min() < core[y]:
                return True
        return False

    for j in range(1, par.shape[0]):  # parents first (the skeleton's order)
        b, o = j - 1, int(par[j]) - 1
        if o < 0 or not conflict(o, b, out[o], out[b]):
            continue
        cuts = []
        for who, which in ((o, 1), (b, 0)):
            z = np.linspace(out[who, 0], out[who, 1], AXIS_PROBES)[1:-1]
            for steps, end in enumerate(z[::-1] if which == 1 else z, start=1):
                trial = out[who].copy()
                trial[which] = end
                ro, rb = (trial, out[b]) if who == o else (out[o], trial)
                if not conflict(o, b, ro, rb):
                    length_lost = round(steps * (out[who, 1] - out[who, 0]) * length[who] / (length[o] + length[b]), 9)
                    cuts.append((steps, length_lost, who != o, who, which, end))
                    break
        if cuts:
            *_, who, which, end = min(cuts)
            out[who, which] = end
    return out


def _disc_offsets(e2: np.ndarray, e3: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """(B, 1 + 2·RIM_POINTS, 3) offsets from a bone's axis to its disc's centre, rim and half-rim, in the
    bone's cross-section frame e₂, e₃ (B, 3) from :func:`ncflow.skeleton.samples.bone_axes`.
    """
    ang = np.linspace(0.0, 2.0 * np.pi, RIM_POINTS, endpoint=False)
    ring = np.cos(ang)[None, :, None] * e2[:, None] + np.sin(ang)[None, :, None] * e3[:, None]  # (B, K, 3)
    r = reach[:, None, None]
    return np.concatenate([np.zeros_like(ring[:, :1]), r * ring, 0.5 * r * ring], axis=1)


def bones_partly_outside(skeleton: Skeleton, inside: Float[np.ndarray, " B"], share: float = 0.5) -> list[str]:
    """One warning line per bone whose axis lies inside the mesh over less than ``share`` of its length
    (``inside`` from :func:`inside_axial_ranges`), saying what the matcher does with it.
    """
    lines = []
    names = skeleton.bone_names
    for b in np.flatnonzero(np.asarray(inside) < share):
        name = f"bone {names[b]}"
        if inside[b] == 0:
            lines.append(f"{name} lies outside the source: nothing of it holds flesh, its samples lie in empty space")
        else:
            lines.append(
                f"{name} lies outside the source over {1 - inside[b]:.0%} of its length: its samples and rigid "
                "core cover the part inside"
            )
    return lines


def _segment_distances(x: np.ndarray, a: np.ndarray, ab: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, B) the place of each point's projection on each segment a → a + ab (its share of ab, unclipped)
    and the point's distance to the segment; x (N, 3), a and ab (B, 3).
    """
    u = np.einsum("vbi,bi->vb", x[:, None, :] - a[None], ab) / np.maximum(np.sum(ab * ab, 1), 1e-300)
    closest = a[None] + np.clip(u, 0.0, 1.0)[..., None] * ab[None]
    return u, np.linalg.norm(x[:, None, :] - closest, axis=-1)


def _nearest_bones(x: np.ndarray, skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(V,) each point's nearest bone segment, the place of its projection along that bone (z / L,
    unclipped) and its distance to the segment.
    """
    p = np.asarray(skeleton.positions, np.float64)
    bones = np.asarray(skeleton.bones)
    u, dist = _segment_distances(x, p[bones[:, 0]], p[bones[:, 1]] - p[bones[:, 0]])
    owner = np.argmin(dist, axis=1)
    rows = np.arange(x.shape[0])
    return owner, u[rows, owner], dist[rows, owner]


def _skin(x: np.ndarray, skeleton: Skeleton, axial_range: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    owner, along, dist = _nearest_bones(x, skeleton)
    lo, hi = axial_range
    return np.where((along >= lo) & (along <= hi), owner, -1), dist


def skin_vertices(
    rest: Float[np.ndarray, "V 3"], skeleton: Skeleton, axial_range: tuple[float, float] = DEFAULT_AXIAL_RANGE
) -> np.ndarray:
    """(V,) the bone whose skin each rest vertex is (its nearest bone segment), or −1 for a vertex whose
    projection on that segment falls outside ``axial_range`` (near a joint, where the skin of two bones
    bends with the joint).
    """
    return _skin(np.asarray(rest, np.float64), skeleton, axial_range)[0]


FLESH_QUANTILE = 10
"""The percentile of a bone's skin distances that :func:`flesh_radius` reports."""


def flesh_radius(
    skeleton: Skeleton, vertices: Float[np.ndarray, "V 3"], axial_range: tuple[float, float] = DEFAULT_AXIAL_RANGE
) -> Float[np.ndarray, " B"]:
    """(B,) how far each bone's skin lies from it: the :data:`FLESH_QUANTILE`-th percentile of the distances
    from its skin vertices (:func:`skin_vertices`) to its segment; inf for a bone with fewer than 3 skin
    vertices. The rigid cores of :class:`ncflow.flow.SkinnedField` stay inside it.
    """
    owner, dist = _skin(np.asarray(vertices, np.float64), skeleton, axial_range)
    out = np.full(skeleton.n_bones, np.inf)
    for k in range(skeleton.n_bones):
        d = dist[owner == k]
        if d.shape[0] >= 3:
            out[k] = np.percentile(d, FLESH_QUANTILE)
    return out
