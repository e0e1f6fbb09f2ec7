"""What a partial target shows of the source: the weights of the partial data terms
(:mod:`ncflow.measures.partial`; docs/scans.md "Partial targets"; the paper's future work, §7).

A scan shows part of the shape: the side a camera saw, with holes where it saw nothing. Its open borders
that the source has no border at are *cuts* (a source's own border — MANO's open wrist — is matched by the
target's border there and is not a cut). After the placement and the pose search the source, posed by
linear blend skinning with the pose searched, lies on what the target shows; a source vertex p with
unit normal n, its closest target point y (distance d, target face normal n_y), is **not shown** when

* y lies on a cut (within δ/2 of one) and d > δ: the source goes on past the scan's border (the rest of
  a single view's silhouette, a hole), or
* n · n_y < −0.2 and d > δ: the nearest surface the target shows faces the other way (the far side of a
  limb seen from one side), or
* the target is a view from one side (its mean normal is long: :func:`ncflow.measures.partial.facing_weights`)
  and n faces away from that side's camera,

with weight ω = 1 − h((d − δ)/δ) in the first two cases, the back-face weight in the third (h the
smoothstep; 1 elsewhere), averaged over the source's vertex
rings twice so that the shown part has a smooth edge. δ = 2 % of the source's bounding-box diagonal
(a pose the search got to within δ counts as shown). The target's weight is 0 at its cut vertices.

A target whose cuts add up to more than :data:`CUT_SHARE` × the square root of its area (one hole of 0.2 %
of the area passes it; a closed or remeshed complete target has no cut) is *partial*: the weights are
computed and reported (``source_seen.txt``, ``metrics.json`` ``partial``). The data terms use them with
``partial = "on"`` (always) or ``"auto"`` (partial targets); the default ``"off"`` keeps the whole
measures — on the scan development set the restricted terms lost 0.003–0.058 geodesic AUC against the
whole ones on every case measured (docs/scans.md), the placement and pose search doing the partial work
(:func:`ncflow.measures.partial.facing_weights`).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from jaxtyping import Bool, Float, Int
from scipy.spatial import cKDTree

from ncflow.flow.bone_weights import skinning_weights
from ncflow.geometry.closest import closest_points_on_surface
from ncflow.geometry.mesh import face_areas, outward_vertex_normals
from ncflow.geometry.topology import Topology
from ncflow.matcher.pose_scorer import skinned
from ncflow.measures.partial import facing_weights
from ncflow.measures.varifold import Varifold, varifold
from ncflow.skeleton import Skeleton
from ncflow.skeleton.kinematics import Pose, rest_pose

CUT_SHARE = 0.15
"""``partial = "auto"`` uses the partial terms when the cuts' length exceeds this × √(target area)."""

DELTA = 0.02
"""δ as a share of the source's bounding-box diagonal."""

OWN_BORDER = 0.05
"""A target border vertex within this share of the diagonal of the posed source's border is the source's own."""


@dataclasses.dataclass(frozen=True)
class Shown:
    """What the target shows.

    Attributes:
        active: whether the partial data terms are used (setting ``partial``).
        partial: whether the target shows part of the source (its cuts are long enough, or ``partial`` is
            "on"): ``source`` and ``seen`` are then computed, for the record, whether used or not.
        source: (V,) ω per working-source vertex (1: shown).
        target: (W,) ω per target vertex (0 at a cut).
        info: the ``metrics.json`` record: setting, active, cut length / √area, shares.
        cuts: (C, 3) points along the target's cuts (placed, normalised coordinates).
        delta: δ (normalised units).
    """

    active: bool
    source: Float[np.ndarray, " V"]
    target: Float[np.ndarray, " W"]
    info: dict
    cuts: Float[np.ndarray, "C 3"] = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))
    delta: float = 0.0
    partial: bool = False

    @classmethod
    def whole(cls, n_source: int, n_target: int, info: dict | None = None) -> Shown:
        """Everything shown (the partial terms off)."""
        return cls(False, np.ones(n_source), np.ones(n_target), info or {"active": False})

    def seen(self, points, faces, target_vertices, target_faces) -> Float[np.ndarray, " V"]:
        """ω of another state of the source (``points`` on ``faces``, e.g. the trained flow's result at full
        resolution) against the placed target, by the same rule; all ones for a whole target.
        """
        if not self.partial:
            return np.ones(points.shape[0])
        normals = outward_vertex_normals(points, faces)
        return seen_weights(points, normals, faces, target_vertices, target_faces, self.cuts, self.delta)


def posed_source(
    skeleton: Skeleton,
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    pose: Pose | None,
    width: float,
) -> tuple[Float[np.ndarray, "V 3"], Float[np.ndarray, "V 3"]]:
    """The source's vertices and outward unit normals moved by ``pose`` (None: the rest pose) with the
    skeleton-driven field's distance bone weights of width ``width`` (linear blend skinning, as the pose
    search scores poses: :func:`ncflow.matcher.pose_scorer.skinned`).
    """
    normals = outward_vertex_normals(vertices, faces)
    pose = rest_pose(skeleton, jnp.float32) if pose is None else pose
    pos, bones = jnp.asarray(skeleton.positions, jnp.float32), np.asarray(skeleton.bones)
    w = skinning_weights(jnp.asarray(vertices, jnp.float32), pos[bones[:, 0]], pos[bones[:, 1]], width)
    x = Varifold(jnp.asarray(vertices, jnp.float32), jnp.asarray(normals, jnp.float32), jnp.ones(len(vertices)))
    moved = skinned(skeleton, w, x, pose)
    return np.asarray(moved.centers, np.float64), np.asarray(moved.normals, np.float64)


def border_edges(topology: Topology, keep: Bool[np.ndarray, " V"] | None = None) -> Int[np.ndarray, "n 2"]:
    """The border edges (one face) whose two ends are ``keep`` (None: all)."""
    e = np.asarray(topology.edges)[np.asarray(topology.boundary_edges, bool)]
    return e if keep is None else e[keep[e[:, 0]] & keep[e[:, 1]]]


def border_share(
    vertices: Float[np.ndarray, "V 3"], topology: Topology, keep: Bool[np.ndarray, " V"] | None = None
) -> float:
    """The length of the :func:`border_edges` over the square root of the mesh's area (0 when closed)."""
    e = border_edges(topology, keep)
    length = float(np.linalg.norm(vertices[e[:, 0]] - vertices[e[:, 1]], axis=1).sum())
    return length / np.sqrt(max(float(face_areas(vertices, np.asarray(topology.faces)).sum()), 1e-300))


def border_points(vertices: Float[np.ndarray, "V 3"], topology: Topology, keep: Bool[np.ndarray, " V"], step: float):
    """(n, 3) points every ``step`` along the border edges whose two ends are ``keep``."""
    e = border_edges(topology, keep)
    if e.size == 0:
        return np.zeros((0, 3))
    a, b = vertices[e[:, 0]], vertices[e[:, 1]]
    k = np.maximum(1, np.ceil(np.linalg.norm(b - a, axis=1) / step).astype(int))
    t = np.concatenate([np.arange(n) / n for n in k])
    rows = np.repeat(np.arange(e.shape[0]), k)
    return a[rows] + t[:, None] * (b - a)[rows]


def smoothed(
    values: Float[np.ndarray, " V"], faces: Int[np.ndarray, "F 3"], rounds: int = 2
) -> Float[np.ndarray, " V"]:
    """``values`` averaged over each vertex and its ring neighbours ``rounds`` times."""
    n = values.shape[0]
    f = np.asarray(faces)
    rows = np.concatenate([f[:, 0], f[:, 1], f[:, 2], f[:, 1], f[:, 2], f[:, 0], np.arange(n)])
    cols = np.concatenate([f[:, 1], f[:, 2], f[:, 0], f[:, 0], f[:, 1], f[:, 2], np.arange(n)])
    adj = sp.csr_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n))
    adj.data[:] = 1.0  # duplicates summed: each neighbour once
    deg = np.asarray(adj.sum(axis=1)).ravel()
    out = np.asarray(values, np.float64)
    for _ in range(rounds):
        out = (adj @ out) / deg
    return out


def seen_weights(
    points: Float[np.ndarray, "V 3"],
    normals: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    target_vertices: Float[np.ndarray, "W 3"],
    target_faces: Int[np.ndarray, "G 3"],
    cuts: Float[np.ndarray, "C 3"],
    delta: float,
) -> Float[np.ndarray, " V"]:
    """ω per source vertex (``points`` with ``normals``, the mesh of ``faces``) against the target mesh whose
    cut borders pass through ``cuts`` (the module docstring's rule).
    """
    d, face, bary = closest_points_on_surface(points, target_vertices, target_faces)
    tri = target_vertices[target_faces[face]]
    foot = np.einsum("nk,nkd->nd", bary, tri)
    n_y = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n_y /= np.maximum(np.linalg.norm(n_y, axis=1, keepdims=True), 1e-300)
    on_cut = cKDTree(cuts).query(foot)[0] < 0.5 * delta if cuts.shape[0] else np.zeros(len(points), bool)
    facing_away = np.einsum("nd,nd->n", normals, n_y) < -0.2
    u = np.clip((d - delta) / delta, 0.0, 1.0)
    omega = np.where(on_cut | facing_away, 1.0 - u * u * (3.0 - 2.0 * u), 1.0)
    target = varifold(jnp.asarray(target_vertices), np.asarray(target_faces))
    omega = np.minimum(omega, np.asarray(facing_weights(jnp.asarray(normals, target.normals.dtype), target)))
    return np.clip(smoothed(omega, faces), 0.0, 1.0)


def shown_parts(
    skeleton: Skeleton,
    source_vertices: Float[np.ndarray, "V 3"],
    source_faces: Int[np.ndarray, "F 3"],
    source_topology: Topology,
    target_vertices: Float[np.ndarray, "W 3"],
    target_topology: Topology,
    pose: Pose | None,
    width: float,
    setting: str = "off",
) -> Shown:
    """What the placed target (``target_vertices``, normalised, placed) shows of the source posed by
    ``pose`` (the module docstring): the weights when the target's cuts are long enough or ``setting`` is
    "on" (all ones otherwise), used by the data terms when ``setting`` is "on", or "auto" and the cuts are
    long enough; with "off" they are computed for the record only.
    """
    nv, nw = source_vertices.shape[0], target_vertices.shape[0]
    tb = np.asarray(target_topology.boundary_vertices)
    if setting != "on" and tb.size == 0:  # a closed target: no cut, nothing to pose
        return Shown.whole(
            nv, nw, {"setting": setting, "cut_length_per_sqrt_area": 0.0, "cut_vertices": 0, "active": False}
        )
    posed, normals = posed_source(skeleton, source_vertices, source_faces, pose, width)
    diag = float(np.linalg.norm(source_vertices.max(0) - source_vertices.min(0)))
    delta = DELTA * diag
    cut = np.zeros(nw, bool)
    if tb.size:
        cut[tb] = True
        sb = np.asarray(source_topology.boundary_vertices)
        if sb.size:
            near = cKDTree(posed[sb]).query(target_vertices[tb])[0] < OWN_BORDER * diag
            cut[tb[near]] = False
    cuts = border_points(target_vertices, target_topology, cut, 0.25 * delta)
    share = border_share(target_vertices, target_topology, cut)
    info = {"setting": setting, "cut_length_per_sqrt_area": share, "cut_vertices": int(cut.sum())}
    if setting != "on" and share <= CUT_SHARE:
        return Shown.whole(nv, nw, {**info, "active": False})
    omega = seen_weights(posed, normals, source_faces, target_vertices, np.asarray(target_topology.faces), cuts, delta)
    active = setting != "off"
    info = {**info, "active": active, "source_shown_share": shown_share(source_vertices, source_faces, omega)}
    return Shown(active, omega, np.where(cut, 0.0, 1.0), info, cuts, delta, partial=True)


def shown_share(
    vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"], weights: Float[np.ndarray, " V"]
) -> float:
    """The area-weighted mean of per-vertex ``weights`` (a face weighs the mean of its corners')."""
    a = face_areas(vertices, faces)
    return float(np.sum(a * np.asarray(weights)[faces].mean(axis=1)) / max(float(a.sum()), 1e-300))
