"""What one tracked frame hands the next: the bone-weight mode, the placement followed from frame to frame,
the trained state on disk, and the tests that say a warm start was lost (:func:`lost`: data term or fit
far above the recent frames', :func:`reference`; :func:`bones_held`) and which of a frame's two matches
is kept (:func:`better_match`).

Each frame is matched from the **source** (the map of frame k is source → frame k, so errors do not
accumulate); only the start of the optimisation is carried: the trained networks, pose (carried on at its
speed from the frame before, :func:`predicted_state`) and multipliers of the previous frame, handed to
:class:`ncflow.matcher.Matcher` as a :class:`ncflow.matcher.steps.WarmStart` with its placement, moved onto
the new frame by a trimmed rigid ICP (:func:`follow_placement`), and a short training (the last phase, at
peak rate :data:`WARM_LR`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Float
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from ncflow.config import Config
from ncflow.geometry.normalize import Normalization
from ncflow.matcher.placement import Placement
from ncflow.matcher.prepare import DTYPE
from ncflow.matcher.train import TrainState, init_params
from ncflow.optim.mdmm import init_multipliers
from ncflow.skeleton import Skeleton
from ncflow.skeleton.kinematics import rest_pose

__all__ = [
    "ICP_ITERATIONS",
    "LOST_FIT",
    "REFERENCE_FRAMES",
    "WARM_LR",
    "better_match",
    "bones_held",
    "final_data",
    "fixed_weights",
    "follow_placement",
    "load_state",
    "lost",
    "predicted_state",
    "reference",
    "save_state",
]

WARM_LR = 3e-3
"""Peak learning rate of a warm frame's training (at most the last phase's; cosine down to its end rate)."""
ICP_ITERATIONS = 30
"""Iterations of the trimmed ICP that follows the placement from frame to frame."""
ICP_TRIM = 2.5
"""Pairs farther apart than this × their median distance are left out of an ICP step."""
LOST_FIT = 0.02
"""A fit (mean distance from the frame to the registered source) below this × the source's bounding-box
diagonal never calls a warm start lost: the data term of a frame far from its match saturates (the
kernel's cross term vanishes), so a jump shows in the fit first."""
MAX_STEP_DEG = 60.0
"""A joint whose local rotation changed by more than this between the last two frames is not carried on by
:func:`predicted_state` (a turn that large between frames is a flip of the fit more likely than motion)."""
REFERENCE_FRAMES = 5
"""Good frames whose data terms and fits make the reference of the lost-warm-start test (:func:`reference`)."""


def fixed_weights(config: Config, skinning_weights: str) -> Config:
    """``config`` with ``flow.skinning_weights`` set (``"current"`` or ``"start"``)."""
    return dataclasses.replace(config, flow=dataclasses.replace(config.flow, skinning_weights=skinning_weights))


def final_data(result) -> float:
    """The data term at the end of a match's training (its last stage)."""
    return float(result.metrics["phases"][-1]["data"])


def _kabsch(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) minimising Σ |R a + t − b|² over paired rows (Kabsch, scipy's ``align_vectors``)."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    if a.shape[0] < 3:
        return np.eye(3), cb - ca
    rot = Rotation.align_vectors(b - cb, a - ca)[0].as_matrix()
    return rot, cb - rot @ ca


def follow_placement(
    previous: Placement,
    previous_placed: Float[np.ndarray, "N 3"],
    reference: Float[np.ndarray, "M 3"],
    target: Float[np.ndarray, "W 3"],
) -> Placement:
    """The placement of a new frame: ``previous`` moved so that the new ``target`` (normalised coordinates,
    not placed) lies on ``reference`` (the previous frame's flowed source, training coordinates).

    Starts from ``previous`` shifted by the change of the placed frames' centroids (``previous_placed``:
    the previous target, placed), then :data:`ICP_ITERATIONS` steps of trimmed point-to-point ICP.
    """
    y = np.asarray(target, np.float64)
    rot = np.asarray(previous.rotation, np.float64)
    t = np.asarray(previous.translation, np.float64)
    t = t + np.asarray(previous_placed, np.float64).mean(axis=0) - (y @ rot.T + t).mean(axis=0)
    tree = cKDTree(np.asarray(reference, np.float64))
    for _ in range(ICP_ITERATIONS):
        placed = y @ rot.T + t
        d, i = tree.query(placed)
        keep = d <= ICP_TRIM * max(float(np.median(d)), 1e-12)
        r_step, t_step = _kabsch(placed[keep], tree.data[i[keep]])
        rot, t = r_step @ rot, r_step @ t + t_step
    return Placement(rot, t, moved=True)


def _template(skeleton: Skeleton, norm: Normalization, config: Config, weight_mode: str) -> tuple:
    """A state of the structure a match with ``config`` trains, its skeleton normalised by the source's
    ``norm`` as the match normalises it (values unused).
    """
    skel = skeleton.with_positions(norm.apply(skeleton.positions))
    params = init_params(jax.random.key(0), config, skel, None, weight_mode, None)
    pose = rest_pose(skel, DTYPE)
    return params, pose, init_multipliers(jnp.zeros((2, skel.n_bones), DTYPE))


def save_state(path: str | Path, state: TrainState) -> None:
    """Write a trained state's arrays (Equinox's leaf serialisation: arrays only, no code)."""
    eqx.tree_serialise_leaves(path, (state.params, state.pose, state.multipliers))


def load_state(
    path: str | Path, skeleton: Skeleton, norm: Normalization, config: Config, weight_mode: str
) -> TrainState:
    """Read a state written by :func:`save_state` for ``skeleton`` (user coordinates), the source's
    normalisation ``norm`` (:func:`ncflow.geometry.normalize.fit_normalization` of the source after the
    intake step, as the match fits it) and ``config``.
    """
    params, pose, mult = eqx.tree_deserialise_leaves(path, _template(skeleton, norm, config, weight_mode))
    return TrainState(params, pose, mult)


def reference(records: list[dict]) -> dict | None:
    """What a warm frame's final data term and fit are compared with: the medians of the last
    :data:`REFERENCE_FRAMES` good frames' (both grow as the pose moves away from the source's, so the
    reference follows the sequence; a lost frame is a jump above it). None before any good frame.
    """
    ok = [r for r in records if r.get("status") == "ok"][-REFERENCE_FRAMES:]
    if not ok:
        return None
    return {"data": float(np.median([r["data"] for r in ok])), "fit": float(np.median([r["fit"] for r in ok]))}


def lost(result, ref: dict, lost_ratio: float, size: float) -> dict:
    """The lost-warm-start test of a warm frame's result against :func:`reference` (:mod:`ncflow.track.sequence`):
    ``data_ratio``, ``fit_ratio`` and whether the warm start is ``lost``.
    """
    data_ratio = final_data(result) / max(ref["data"], 1e-30)
    fit = result.metrics["correspondence"]["mean_distance_target_to_flowed_source"]
    fit_ratio = fit / max(ref["fit"], 1e-30)
    far = fit > LOST_FIT * size and fit_ratio > lost_ratio
    return {"data_ratio": data_ratio, "fit_ratio": fit_ratio, "lost": bool(data_ratio > lost_ratio or far)}


def bones_held(result) -> bool:
    """Every bone of ``result`` within its tolerance ε."""
    return bool(result.metrics["constraints"]["all_satisfied"])


def better_match(warm, full):
    """The frame's match kept of its warm one and its full one: the one whose bones hold when only one does,
    else the lower final data term.
    """
    if bones_held(warm) != bones_held(full):
        return warm if bones_held(warm) else full
    return full if final_data(full) < final_data(warm) else warm


def _rotations(quats: np.ndarray) -> Rotation:
    """Quaternions (w, x, y, z) as rotations, the zero vector as the identity (as the field reads them)."""
    q = np.array(quats, np.float64)
    q[np.linalg.norm(q, axis=1) < 1e-12] = (1.0, 0.0, 0.0, 0.0)
    return Rotation.from_quat(q, scalar_first=True)


def _carried_on(rotations: np.ndarray, before: np.ndarray, roots: np.ndarray) -> np.ndarray:
    """(J, 4) wxyz local rotations ``rotations`` turned once more by their change since ``before``
    (r ↦ r r_before⁻¹ r, the shortest arc), but the ``roots`` and joints that turned more than
    :data:`MAX_STEP_DEG`.
    """
    now = _rotations(rotations)
    step = now * _rotations(before).inv()
    ahead = (step * now).as_quat(scalar_first=True)
    keep = (np.degrees(step.magnitude()) <= MAX_STEP_DEG) & ~roots
    return np.where(keep[:, None], ahead, rotations)


def predicted_state(state: TrainState, before: TrainState | None) -> TrainState:
    """The start of the next warm frame: ``state`` (the last good frame's) with every joint but the root
    turned on at its speed since ``before`` (the good frame before it; None: ``state`` unchanged) — a
    constant-velocity prediction of the pose, so that a limb swinging fast between frames (a walk's legs)
    starts near where it will be instead of where it was. The root's turn and travel are the placement's
    (:func:`follow_placement`); the networks and multipliers are carried as they are. A field without a
    skeleton pose (``flow.skinning`` off) is carried unchanged.
    """
    field = state.params.flow
    if before is None or not hasattr(field, "pose"):
        return state
    roots = np.asarray(field.skeleton.parents) < 0

    def on(pose, old):
        r = np.asarray(pose.rotations, np.float64)
        ahead = _carried_on(r, np.asarray(old.rotations, np.float64), roots)
        return pose._replace(rotations=jnp.asarray(ahead, pose.rotations.dtype))

    params = eqx.tree_at(lambda p: p.flow.pose, state.params, on(field.pose, before.params.flow.pose))
    return TrainState(params, on(state.pose, before.pose), state.multipliers)
