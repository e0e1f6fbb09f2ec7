"""Inputs → the normalised problem the matcher trains on (DESIGN.md "Pipeline", first steps).

Loads and checks the meshes and the skeleton, repairs the meshes for the match (the intake step,
:func:`ncflow.match.inputs.intake`), fits the one similarity that normalises source,
target and skeleton (same identity, same scale), places the target rigidly on the source
(:mod:`ncflow.match.placement`) and searches the skeleton pose that explains it
(:mod:`ncflow.match.pose_search`) — the two together, since a rigid fit alone is pulled by the
limbs of an articulated target — builds the topology tables and draws the soft-tissue centroids
(fTetWild once per source, cached: :func:`ncflow.tissue.tissue_centroids`).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np
from jaxtyping import Float

from ncflow.geometry.decimate import Decimation, decimate
from ncflow.geometry.mesh import Mesh
from ncflow.geometry.normalize import Normalization, fit_normalization
from ncflow.geometry.overlap import self_overlap
from ncflow.geometry.repair import Repair
from ncflow.geometry.topology import Topology, mesh_topology
from ncflow.io.atomic import computed_once
from ncflow.io.files import read_npz_arrays
from ncflow.jit.cache import cache_root
from ncflow.match.inputs import check_inputs, intake, load_inputs
from ncflow.match.placement import Placement, place_target, placement_candidates
from ncflow.match.pose_search import PoseSearchResult, search_poses
from ncflow.skeleton import Skeleton
from ncflow.skeleton.kinematics import Pose
from ncflow.tissue import centroids_digest, load_tissue_file, tissue_centroids

DTYPE = jnp.float32  # training dtype (DESIGN.md: float32 for training)


@dataclasses.dataclass(frozen=True)
class Problem:
    """One matching problem in normalised coordinates.

    Attributes:
        source, target, skeleton: the inputs as given (user coordinates).
        normalization: the similarity applied to all three.
        source_vertices: (V, 3) normalised source vertices (float64), full resolution, every vertex of
            the source as given (the outputs have a row for each).
        working: the normalised source the training runs on (:func:`working_source`): the source after
            the intake step, or a decimated copy made of its vertices when it has more than
            ``working_vertices`` vertices.
        target_vertices: (W, 3) normalised vertices of the target after the intake step, placed on
            the source (float64): the mesh the data terms see.
        target_points: (Vt, 3) every vertex of the target as given, normalised and placed: the points
            the correspondence maps.
        source_repair, target_repair: the intake step's repairs (:func:`~ncflow.match.inputs.intake`),
            with the maps from the repaired meshes back to the given ones.
        placement: the rigid motion that placed them (:mod:`ncflow.match.placement`).
        skeleton_normalized: the skeleton in normalised coordinates.
        source_topology: edge table of the working source.
        target_topology: edge table of the target, its faces wound as the source's
            (:func:`~ncflow.match.inputs.target_faces_like_source`).
        bone_radii: (B,) bone-sample radius factor per bone.
        centroids: (K, 3) soft-tissue tet centroids of the normalised source ((0, 3) when disabled).
        tissue_info: how the centroids were obtained (cache hit, counts, seconds).
        warnings: what :func:`~ncflow.match.inputs.check_inputs` found (polygons split, a mesh far
            from the origin or split at seams, a target of somewhat another size or wound the other
            way, joints slightly outside the source surface).
        tissue_seconds: wall time of obtaining the centroids.
        placement_seconds: wall time of the placement (its pose searches excluded).
        pose_search: the skeleton pose found for the chosen placement (None when the search is off).
        pose_search_seconds: wall time of the pose search(es).
        placement_trials: per placement candidate tried, its angle and articulated score.
        setup_cache: whether the placement and the pose search were read back from the cache folder
            (``hit``) and its entry (``file``, None when not kept; :func:`place_and_pose_cached`).
        skinning_weights: the skeleton-driven field's weight mode and why
            (:func:`skinning_weight_mode`).
    """

    source: Mesh
    target: Mesh
    skeleton: Skeleton
    normalization: Normalization
    source_vertices: Float[np.ndarray, "V 3"]
    working: Decimation
    target_vertices: Float[np.ndarray, "W 3"]
    target_points: Float[np.ndarray, "Vt 3"]
    source_repair: Repair
    target_repair: Repair
    placement: Placement
    skeleton_normalized: Skeleton
    source_topology: Topology
    target_topology: Topology
    bone_radii: Float[np.ndarray, " B"]
    centroids: Float[np.ndarray, "K 3"]
    tissue_info: dict
    warnings: tuple[str, ...]
    tissue_seconds: float = 0.0
    placement_seconds: float = 0.0
    pose_search: PoseSearchResult | None = None
    pose_search_seconds: float = 0.0
    placement_trials: tuple[dict, ...] = ()
    setup_cache: dict = dataclasses.field(default_factory=lambda: {"hit": False, "file": None})
    skinning_weights: dict = dataclasses.field(
        default_factory=lambda: {
            "setting": "current",
            "mode": "current",
            "source_overlap": None,
            "target_overlap": None,
        }
    )


def skinning_width(config, skeleton: Skeleton) -> float:
    """τ of the skeleton-driven field's bone weights: ``flow.skinning_width`` × the median bone length."""
    return config.flow.skinning_width * float(np.median(skeleton.bone_lengths))


def uses_tissue(config) -> bool:
    """Whether the configuration trains with the soft-tissue term (samples and weight both on)."""
    return config.sampling.tissue_samples > 0 and config.weights.tissue > 0


def working_source(src: Mesh, config, message=lambda text: None) -> tuple[Normalization, Decimation]:
    """The source's normalisation and the normalised working copy the training runs on
    (:func:`~ncflow.geometry.decimate.decimate` to ``working_vertices``; the source itself when it is
    not larger). ``src``: the source after the intake step (:func:`~ncflow.match.inputs.intake`).
    """
    norm = fit_normalization(src.vertices, src.faces)
    if config.working_vertices is not None and src.n_vertices > config.working_vertices:
        message(f"decimating the source to about {config.working_vertices} vertices for training ...")
    return norm, decimate(norm.apply(src.vertices), src.faces, config.working_vertices or src.n_vertices)


def source_tissue(work: Decimation, config, message=lambda text: None) -> tuple[np.ndarray, dict]:
    """(K, 3) soft-tissue centroids of the working source and how they were obtained: none when the
    tissue term is off, the exact tissue of ``tissue.file`` when one is given, else
    :func:`~ncflow.tissue.tissue_centroids` (cached).
    """
    if not uses_tissue(config):
        return np.zeros((0, 3)), {"disabled": True}
    if config.tissue.file:
        c = load_tissue_file(config.tissue.file, work.vertices)
        return c, {"file": config.tissue.file, "n_centroids": int(c.shape[0]), "sha256": centroids_digest(c)}
    message("tetrahedralising the source for soft-tissue samples ...")
    return tissue_centroids(work.vertices, work.faces, config.tissue)


def searches_pose(config) -> bool:
    """Whether the matcher searches the skeleton's initial pose (``pose_search`` with ``flow.skinning``)."""
    return bool(config.pose_search and config.flow.skinning)


def place_and_pose(src_v, src_f, tgt_v, tgt_f, skeleton: Skeleton, config, message=lambda text: None):
    """The target's placement and the source skeleton's initial pose (normalised coordinates).

    With ``placement = "auto"`` and the pose search on (``pose_search`` and ``flow.skinning``), each
    of :func:`~ncflow.match.placement.placement_candidates` (the target as given first) gets its
    own pose search and the lowest articulated score wins; without the search, the best rigid fit
    (:func:`~ncflow.match.placement.place_target`). Returns (placement, pose search result or None,
    trials, placement seconds, pose-search seconds).
    """
    searching = searches_pose(config)
    t0 = time.perf_counter()
    if config.placement != "auto":
        placements = [Placement.identity()]
    elif searching:
        message("placing the target on the source ...")
        placements = placement_candidates(src_v, src_f, tgt_v, tgt_f, seed=config.seed)
    else:
        message("placing the target on the source ...")
        placements = [place_target(src_v, src_f, tgt_v, tgt_f, seed=config.seed)]
    t_place = time.perf_counter() - t0
    if not searching:
        return placements[0], None, (), t_place, 0.0
    t0 = time.perf_counter()
    message("searching the skeleton pose that explains the target ...")
    results = search_poses(
        skeleton,
        src_v,
        src_f,
        [pl.apply(tgt_v) for pl in placements],
        tgt_f,
        skinning_width=skinning_width(config, skeleton),
        seed=config.seed,
    )
    best = int(np.argmin([r.score for r in results]))
    trials = tuple(
        {"angle_degrees": pl.to_dict()["angle_degrees"], "rigid_score": pl.score, "pose_score": r.score}
        for pl, r in zip(placements, results)
    )
    return placements[best], results[best], trials, t_place, time.perf_counter() - t0


@functools.cache
def code_digest() -> str:
    """SHA-256 of ncflow's own source files and of the JAX and NumPy versions: part of the key of a
    cached result, so a changed algorithm never reads an entry of another.
    """
    import jax

    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256(f"{jax.__version__} {np.__version__}".encode())
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def _setup_key(src_v, src_f, tgt_v, tgt_f, skeleton: Skeleton, config) -> str:
    h = hashlib.sha256()
    for a in (src_v, tgt_v, skeleton.positions):
        h.update(np.ascontiguousarray(a, np.float64).tobytes())
        h.update(repr(np.shape(a)).encode())
    for a in (src_f, tgt_f, skeleton.parents):
        h.update(np.ascontiguousarray(a, np.int64).tobytes())
        h.update(repr(np.shape(a)).encode())
    settings = (config.placement, searches_pose(config), skinning_width(config, skeleton), config.seed)
    h.update(repr(settings).encode())
    h.update(code_digest().encode())
    return h.hexdigest()[:32]


def _write_setup(path, value) -> None:
    placement, search, trials, t_place, t_search = value
    arrays = {
        "rotation": placement.rotation,
        "translation": placement.translation,
        "scores": np.array([placement.score, placement.identity_score], np.float64),
        "moved": np.array(placement.moved),
        "trials": np.array(json.dumps(list(trials))),
        "seconds": np.array([t_place, t_search], np.float64),
    }
    if search is not None:
        arrays.update(
            pose_rotations=np.asarray(search.pose.rotations),
            pose_translation=np.asarray(search.pose.translation),
            search_scores=np.array([search.score, search.rest_score], np.float64),
            hypotheses=np.array(search.hypotheses, np.int64),
        )
    np.savez(path, **arrays)


def _read_setup(path, n_joints: int):
    """The entry :func:`_write_setup` wrote; raises (the entry is then computed again) on anything
    else: missing or misshapen arrays, non-finite numbers.
    """
    a = read_npz_arrays(path, ("rotation", "translation", "scores", "moved", "trials", "seconds"))
    shapes = {"rotation": (3, 3), "translation": (3,), "pose_rotations": (n_joints, 4), "pose_translation": (3,)}
    for name, shape in shapes.items():
        if name in a and (np.shape(a[name]) != shape or not np.all(np.isfinite(a[name]))):
            raise ValueError(f"{path}: {name} is not a finite {shape} array")
    score, identity_score = (float(x) for x in a["scores"])
    placement = Placement(
        np.asarray(a["rotation"], np.float64),
        np.asarray(a["translation"], np.float64),
        score,
        identity_score,
        bool(a["moved"]),
    )
    search = None
    if "pose_rotations" in a:
        pose = Pose(jnp.asarray(a["pose_rotations"]), jnp.asarray(a["pose_translation"]))
        score, rest_score = (float(x) for x in a["search_scores"])
        search = PoseSearchResult(pose, score, rest_score, int(a["hypotheses"]))
    trials = tuple(json.loads(str(a["trials"])))
    return placement, search, trials, *(float(x) for x in a["seconds"])


def place_and_pose_cached(src_v, src_f, tgt_v, tgt_f, skeleton: Skeleton, config, message=lambda text: None):
    """:func:`place_and_pose`, kept in the cache folder (``setup/``) with ``setup_cache`` on: a run on
    the same pair (the same normalised working source, target and skeleton, placement and pose
    search settings, seed and ncflow code) with other training settings reads the placement and the
    pose found back instead of searching again (on the shared MANO pair, about 23 of a warm
    ``--steps 3`` run's 29 s). The entry holds the values themselves, so the results are those of
    a run without it, bit for bit. Returns what :func:`place_and_pose` returns (the seconds the
    search took now, ~0 when read back) and ``{"hit", "file"}``.
    """

    def compute():
        return place_and_pose(src_v, src_f, tgt_v, tgt_f, skeleton, config, message)

    if not config.setup_cache or (config.placement != "auto" and not searches_pose(config)):
        return compute(), {"hit": False, "file": None}
    t0 = time.perf_counter()
    path = cache_root() / "setup" / f"{_setup_key(src_v, src_f, tgt_v, tgt_f, skeleton, config)}.npz"
    value, entry, hit = computed_once(
        path, compute, functools.partial(_read_setup, n_joints=skeleton.n_joints), _write_setup
    )
    if hit:
        value = (*value[:3], time.perf_counter() - t0, 0.0)
    return value, {"hit": hit, "file": None if entry is None else str(entry)}


def prepare(source, target, skeleton, config, message=lambda text: None, before_search=None) -> Problem:
    """Load, check and normalise the inputs; tissue centroids when the tissue term is on; then place
    the target and search the skeleton's pose.

    Args:
        source: the source mesh or its file.
        target: the target mesh or its file.
        skeleton: the source's skeleton or its file.
        config: a validated :class:`ncflow.config.Config`.
        message: called with one-line progress notes (warnings, tetrahedralisation).
        before_search: called with the problem as it stands before the placement and the pose
            search (the target not yet placed, ``placement`` the identity, no pose): everything the
            compiled programs depend on is known then (:mod:`ncflow.jit.ahead`).
    """
    src, tgt, skel = load_inputs(source, target, skeleton)
    (src_c, src_r, src_note), (tgt_c, tgt_r, tgt_note) = intake(src, "source", config), intake(tgt, "target", config)
    tgt_f, warnings = check_inputs(src_c, tgt_c, skel)
    warnings = src_note + tgt_note + warnings
    for w in warnings:
        message(f"warning: {w}")
    norm, work = working_source(src_c, config, message)
    skel_n = skel.with_positions(norm.apply(skel.positions))
    tgt_v = norm.apply(tgt_c.vertices)
    t0 = time.perf_counter()
    centroids, tissue_info = source_tissue(work, config, message)
    tissue_seconds = time.perf_counter() - t0
    source_topology = mesh_topology(work.faces, work.vertices.shape[0], name=src.name)
    target_topology = mesh_topology(tgt_f, tgt_c.n_vertices, name=tgt.name)
    weights = skinning_weight_mode(config, work.vertices, work.faces, tgt_c.vertices, tgt_f)
    if weights["mode"] == "start" and config.flow.skinning_weights == "auto":
        message(
            f"the target passes through itself ({weights['target_overlap']:.1%} of its area, the source "
            f"{weights['source_overlap']:.1%}): bone weights taken at each point's start"
        )
    problem = Problem(
        source=src,
        target=tgt,
        skeleton=skel,
        normalization=norm,
        source_vertices=norm.apply(src.vertices),
        working=work,
        target_vertices=tgt_v,
        target_points=norm.apply(tgt.vertices),
        source_repair=src_r,
        target_repair=tgt_r,
        placement=Placement.identity(),
        skeleton_normalized=skel_n,
        source_topology=source_topology,
        target_topology=target_topology,
        bone_radii=skel_n.bone_radii(config.sampling.bone_radius),
        centroids=centroids,
        tissue_info=tissue_info,
        warnings=tuple(warnings),
        tissue_seconds=tissue_seconds,
        skinning_weights=weights,
    )
    if before_search is not None:
        before_search(problem)
    (placement, search, trials, t_place, t_search), setup_cache = place_and_pose_cached(
        work.vertices, work.faces, tgt_v, tgt_f, skel_n, config, message
    )
    return dataclasses.replace(
        problem,
        target_vertices=placement.apply(tgt_v),
        target_points=placement.apply(problem.target_points),
        placement=placement,
        placement_seconds=t_place,
        pose_search=search,
        pose_search_seconds=t_search,
        placement_trials=trials,
        setup_cache=setup_cache,
    )


AUTO_OVERLAP = 0.005
"""``flow.skinning_weights = "auto"`` takes the weights at the start when the target's self-overlap
exceeds the source's by more than this share of the area."""


def skinning_weight_mode(config, source_vertices, source_faces, target_vertices, target_faces) -> dict:
    """Where the skeleton-driven field takes its bone weights (:class:`ncflow.flow.SkinnedField`).

    ``flow.skinning_weights`` "current" or "start" is used as it is. With "auto" (the default):
    "start" when the target passes through itself (:func:`ncflow.geometry.overlap.self_overlap`)
    over more than :data:`AUTO_OVERLAP` more of its area than the source does — a flow of space
    cannot make a surface pass through itself, so such a target (the fingertips of a captured or
    rigged fist sunk into the palm) needs the weights of the start; otherwise "current", the
    diffeomorphic flow. Returns ``{"setting", "mode", "source_overlap", "target_overlap"}``
    (overlaps None when not measured: a fixed setting, or no skeleton-driven field).
    """
    setting = config.flow.skinning_weights
    out = {"setting": setting, "mode": "current" if setting == "auto" else setting}
    out.update(source_overlap=None, target_overlap=None)
    if setting != "auto" or not config.flow.skinning:
        return out
    src, tgt = self_overlap(source_vertices, source_faces), self_overlap(target_vertices, target_faces)
    out.update(source_overlap=src, target_overlap=tgt)
    if tgt - src > AUTO_OVERLAP:
        out["mode"] = "start"
    return out
