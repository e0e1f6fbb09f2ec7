"""Step 2 of a match: place the target rigidly on the source and search the skeleton pose that explains
it (:mod:`ncflow.matcher.placement`, :mod:`ncflow.matcher.pose_search`) — the two together, since a rigid fit
alone is pulled by the limbs of an articulated target — kept in the cache folder per pair.

:func:`place` returns a :class:`Placed`; a match that starts from an earlier result (a sequence's next
frame) takes that result's placement and pose instead of searching (:meth:`Placed.of_result`).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from scipy.spatial.transform import Rotation

from ncflow.io.atomic import computed_once
from ncflow.io.files import read_npz_arrays
from ncflow.jit.cache import cache_root
from ncflow.matcher.placement import Placement, place_target, placement_candidates
from ncflow.matcher.pose_search import PoseSearchResult, search_poses
from ncflow.matcher.prepare import Setup, skinning_width
from ncflow.skeleton import Skeleton
from ncflow.skeleton.kinematics import Pose


@dataclasses.dataclass(frozen=True)
class Placed:
    """Where the target sits and the pose the skeleton starts from.

    Attributes:
        placement: the rigid motion that places the target on the source (normalised coordinates).
        initial_pose: the pose the training starts from (None: the rest pose).
        pose_search: what the pose search found (None when it did not run).
        trials: per placement candidate tried, its angle and articulated score.
        placement_seconds: wall time of the placement (its pose searches excluded).
        pose_search_seconds: wall time of the pose search(es).
        setup_cache: whether the placement and the pose search were read back from the cache folder
            (``hit``) and its entry (``file``, None when not kept; :func:`place_and_pose_cached`).
    """

    placement: Placement
    initial_pose: Pose | None = None
    pose_search: PoseSearchResult | None = None
    trials: tuple[dict, ...] = ()
    placement_seconds: float = 0.0
    pose_search_seconds: float = 0.0
    setup_cache: dict = dataclasses.field(default_factory=lambda: {"hit": False, "file": None})

    @classmethod
    def of_result(cls, result) -> Placed:
        """The placement and the trained pose of an earlier :class:`~ncflow.matcher.result.MatchResult`,
        searched no further (a warm start).
        """
        return cls(result.placement or Placement.identity(), result.state.pose)


def searches_pose(config) -> bool:
    """Whether the matcher searches the skeleton's initial pose (``pose_search`` with ``flow.skinning``)."""
    return bool(config.pose_search and config.flow.skinning)


CHAIN_SIGMA = 0.1
"""Kernel scale of the chain search (normalised units; :func:`ncflow.matcher.pose_search.search_chains`)."""


def chain_sigma(config, skin_aware: bool) -> float | None:
    """The chain search's kernel scale when ``pose_chains`` asks for it (``auto``: where the bone weights
    see the skin, ``skin_aware``), else None.
    """
    on = config.pose_chains == "on" or (config.pose_chains == "auto" and skin_aware)
    return CHAIN_SIGMA if on and searches_pose(config) else None


CLOSE_SCORE = 0.03
"""Pose scores of two placements within this share of the better one are a close call (:func:`close_call`)."""

CLOSE_ANGLE = 90.0
"""... when two of them also turn the target this many degrees apart (two facings, not one)."""


def close_call(placements: list[Placement], scores: list[float]) -> list[int]:
    """The placements whose pose scores are within :data:`CLOSE_SCORE` of the best one, when one of them turns
    the target at least :data:`CLOSE_ANGLE` degrees from the best (the target's front and back nearly tie: one
    beam search's sampling of Diracs can decide it), else none.
    """
    best = int(np.argmin(scores))
    near = [i for i, s in enumerate(scores) if s - scores[best] <= CLOSE_SCORE * abs(scores[best])]

    def angle(i):
        return float(np.degrees(Rotation.from_matrix(placements[best].rotation.T @ placements[i].rotation).magnitude()))

    return near if any(angle(i) >= CLOSE_ANGLE for i in near) else []


def place_and_pose(
    src_v, src_f, tgt_v, tgt_f, skeleton: Skeleton, config, message=lambda text: None, skin_aware: bool = False
):
    """The target's placement and the source skeleton's initial pose (normalised coordinates).

    With ``placement = "auto"`` and the pose search on (``pose_search`` and ``flow.skinning``), each
    of :func:`~ncflow.matcher.placement.placement_candidates` (the target as given first) gets its
    own pose search and the lowest articulated score wins (two facings that nearly tie, :func:`close_call`,
    are searched once more with the next seed's Diracs, each keeping its better pose); without the search,
    the best rigid fit
    (:func:`~ncflow.matcher.placement.place_target`). ``skin_aware``: the search scores poses with the
    bone weights the training will use when they see the skin (``flow.skinning_weights`` "surface",
    :func:`~ncflow.matcher.pose_search.search_poses`). Returns (placement, pose search result or None,
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

    def search(chosen, seed):
        return search_poses(
            skeleton,
            src_v,
            src_f,
            [placements[i].apply(tgt_v) for i in chosen],
            tgt_f,
            skinning_width=skinning_width(config, skeleton),
            seed=seed,
            skin_aware=skin_aware,
            chain_sigma=chain_sigma(config, skin_aware),
            exchange_fingers=config.pose_exchanges,
        )

    results = search(range(len(placements)), config.seed)
    close = close_call(placements, [r.score for r in results])
    if close:  # a second look, on other Diracs, for the facings that nearly tie: the better of the two searches
        message("two facings explain the target almost equally: searching their poses again ...")
        for i, again in zip(close, search(close, config.seed + 1)):
            if again.score < results[i].score:
                results[i] = again
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
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256(f"{jax.__version__} {np.__version__}".encode())
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def _setup_key(src_v, src_f, tgt_v, tgt_f, skeleton: Skeleton, config, skin_aware: bool = False) -> str:
    h = hashlib.sha256()
    for a in (src_v, tgt_v, skeleton.positions):
        h.update(np.ascontiguousarray(a, np.float64).tobytes())
        h.update(repr(np.shape(a)).encode())
    for a in (src_f, tgt_f, skeleton.parents):
        h.update(np.ascontiguousarray(a, np.int64).tobytes())
        h.update(repr(np.shape(a)).encode())
    settings = (
        config.placement,
        searches_pose(config),
        skinning_width(config, skeleton),
        config.seed,
        skin_aware,
        chain_sigma(config, skin_aware),
        config.pose_exchanges,
    )
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


def place_and_pose_cached(
    src_v, src_f, tgt_v, tgt_f, skeleton: Skeleton, config, message=lambda text: None, skin_aware: bool = False
):
    """:func:`place_and_pose`, kept in the cache folder (``setup/``) with ``setup_cache`` on: a run on
    the same pair (the same normalised working source, target and skeleton, placement and pose
    search settings, seed and ncflow code) with other training settings reads the placement and the
    pose found back instead of searching again (on the shared MANO pair, about 23 of a warm
    ``--steps 3`` run's 29 s). The entry holds the values themselves, so the results are those of
    a run without it, bit for bit. Returns what :func:`place_and_pose` returns (the seconds the
    search took now, ~0 when read back) and ``{"hit", "file"}``.
    """

    def compute():
        return place_and_pose(src_v, src_f, tgt_v, tgt_f, skeleton, config, message, skin_aware)

    if not config.setup_cache or (config.placement != "auto" and not searches_pose(config)):
        return compute(), {"hit": False, "file": None}
    t0 = time.perf_counter()
    path = cache_root() / "setup" / f"{_setup_key(src_v, src_f, tgt_v, tgt_f, skeleton, config, skin_aware)}.npz"
    value, entry, hit = computed_once(
        path, compute, functools.partial(_read_setup, n_joints=skeleton.n_joints), _write_setup
    )
    if hit:
        value = (*value[:3], time.perf_counter() - t0, 0.0)
    return value, {"hit": hit, "file": None if entry is None else str(entry)}


def place(setup: Setup, config, message=lambda text: None) -> Placed:
    """The placement of the target and the skeleton's initial pose (:func:`place_and_pose_cached`; the
    search sees the skin as the training's bone weights do, :func:`ncflow.matcher.prepare.skinning_weight_mode`).
    """
    (placement, search, trials, t_place, t_search), cache = place_and_pose_cached(
        setup.working.vertices,
        setup.working.faces,
        setup.target_vertices,
        setup.target_faces,
        setup.skeleton_normalized,
        config,
        message,
        skin_aware=setup.skinning_weights["mode"] == "surface",
    )
    return Placed(placement, None if search is None else search.pose, search, trials, t_place, t_search, cache)


def place_suggested(setup: Setup, config, message=lambda text: None) -> tuple[Setup, Placed]:
    """:func:`place` for a problem whose skeleton was suggested in several ways (``setup.alternatives``,
    :func:`ncflow.matcher.prepare.suggested_skeletons`): the first placed and its pose searched as
    :func:`place` does, each other's pose searched **at the first one's placement** (the facing is the
    first skeleton's to choose: a skeleton whose joints allow a wrong explanation, a body turned round with
    its knees bent backwards, cannot win by it), and the one whose pose explains the target best (lowest
    pose-search score, comparable across skeletons: the same source and target Diracs, each posed source's
    distance to the target) kept, with every candidate's score in ``skeleton_suggested["candidates"]`` and
    the seconds of all in the returned :class:`Placed`. A problem with one skeleton, or without a pose
    search, is :func:`place` of ``setup`` (the first suggestion).
    """
    if not setup.alternatives or not searches_pose(config):
        return setup, place(setup, config, message)
    message(f"searching the pose with suggested skeleton 1 of {len(setup.alternatives) + 1} ...")
    first = place(setup, config, message)
    tried = [(setup, first)]
    held = dataclasses.replace(config, placement="none")
    angle = first.placement.to_dict()["angle_degrees"]
    for k, alternative in enumerate(setup.alternatives):
        message(f"searching the pose with suggested skeleton {k + 2} of {len(setup.alternatives) + 1} ...")
        placed_target = first.placement.apply(alternative.target_vertices)
        at = place(dataclasses.replace(alternative, target_vertices=placed_target), held, message)
        trial = {"angle_degrees": angle, "rigid_score": first.placement.score, "pose_score": at.pose_search.score}
        tried.append((alternative, dataclasses.replace(at, placement=first.placement, trials=(trial,))))
    scores = [placed.pose_search.score for _, placed in tried]
    best = int(np.argmin(scores))
    candidates = [
        {"bases": s.skeleton_suggested["bases"], "n_joints": s.skeleton.n_joints, "pose_score": float(score)}
        for (s, _), score in zip(tried, scores)
    ]
    chosen, placed = tried[best]
    info = dict(chosen.skeleton_suggested, candidates=candidates)
    placed = dataclasses.replace(  # the time of every candidate's placement and search
        placed,
        placement_seconds=sum(p.placement_seconds for _, p in tried),
        pose_search_seconds=sum(p.pose_search_seconds for _, p in tried),
    )
    return dataclasses.replace(chosen, skeleton_suggested=info, alternatives=()), placed
