"""Step 6 of a match: the result, the outputs in the user's coordinates (DESIGN.md "Output contract").

After training, the full source is flowed by the trained field (frames on a uniform time grid),
the output pose is refitted on fresh bone samples with the final multiplier weights, the skeleton
is interpolated per frame, the target is projected onto the flowed source for the correspondence,
and everything is mapped back through the normalisation (:func:`build_result`, which also assembles
every metric). :class:`MatchResult` holds it all, writes the output contract (:meth:`MatchResult.save`)
and keeps the trained state a later match may start from.
"""

from __future__ import annotations

import dataclasses
import os
import platform
import time
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ncflow import __version__
from ncflow.config import config_to_dict
from ncflow.flow import flow_points
from ncflow.geometry.mesh import Mesh
from ncflow.geometry.normalize import Normalization
from ncflow.io.fallback import save_result
from ncflow.io.result import ResultFolder
from ncflow.matcher.correspondence import correspondence_maps
from ncflow.matcher.objective import fit_start, start_normals
from ncflow.matcher.partial import Shown, shown_share
from ncflow.matcher.place import Placed
from ncflow.matcher.placement import Placement
from ncflow.matcher.prepare import DTYPE, Setup
from ncflow.matcher.programs import Programs, output_flow_inputs, output_frame_times
from ncflow.matcher.train import Trained, TrainingError, TrainState
from ncflow.optim.mdmm import Multipliers
from ncflow.skeleton import Skeleton
from ncflow.skeleton.kinematics import Pose
from ncflow.skeleton.reach import skin_stretch


@dataclasses.dataclass
class MatchResult:
    """Everything a match produced, in the user's coordinates.

    Attributes:
        source, target: the input meshes.
        skeleton: the source skeleton; ``skeleton_target`` the fitted target pose of it.
        deformed_source: (V, 3) source vertices flowed to t = 1.
        frame_times: (K,) times in [0, 1]; ``frames`` (K, V, 3) the interpolation.
        skeleton_frames: (K, J, 3) joint positions per frame.
        maps: correspondence (:func:`ncflow.matcher.correspondence.correspondence_maps`).
        metrics: losses, per-bone constraints, timings, config, versions, seed.
        normalization: the similarity used for training.
        placement: the rigid motion that placed the target on the source for training (normalised
            coordinates); outputs are moved back along it, so they end on the target as given.
        state: the trained state (networks, pose, multipliers), which a later match may start from
            (``ncflow.match(..., start=result)``).
        source_seen: (V,) how much the target shows each source vertex, in [0, 1]
            (:meth:`ncflow.matcher.partial.Shown.seen`; all ones for a whole target).
    """

    source: Mesh
    target: Mesh
    skeleton: Skeleton
    skeleton_target: Skeleton
    deformed_source: np.ndarray
    frame_times: np.ndarray
    frames: np.ndarray
    skeleton_frames: np.ndarray
    maps: dict
    metrics: dict
    normalization: Normalization
    field: Any = dataclasses.field(repr=False, default=None)
    n_times: int = 10
    placement: Placement | None = None
    pivot: np.ndarray | None = None
    state: TrainState | None = dataclasses.field(repr=False, default=None)
    skeleton_suggested: bool = False
    source_seen: np.ndarray | None = None

    def flow(
        self, points: np.ndarray, times: np.ndarray | None = None, normals: np.ndarray | None = None
    ) -> np.ndarray:
        """Move any points (user coordinates, e.g. a higher-resolution source) by the trained field.

        Returns (N, 3) at t = 1, or (Q, N, 3) at the given times (the target's placement included,
        as in :attr:`frames`). ``normals`` (N, 3): the outward surface normals at the points, read where
        the bone weights see the skin (``metrics["skinning_weights"]["mode"] == "surface"``; without
        them such points take the plain weights of the start), or (N, 3 + B) with the bones each point
        may not take, as the match's own (:func:`ncflow.flow.surface_skin` of the points' mesh).
        """
        p = jnp.asarray(self.normalization.apply(np.asarray(points, np.float64)), DTYPE)
        n = None if normals is None else jnp.asarray(normals, DTYPE)
        if times is None:
            out = np.asarray(flow_points(self.field, p, self.n_times, normals=n)[-1], np.float64)
            out = self._placed_back(out[None], np.ones(1))[0]
        else:
            t = jnp.asarray(times, DTYPE)
            out = np.asarray(flow_points(self.field, p, self.n_times, times=t, normals=n), np.float64)
            out = self._placed_back(out, np.asarray(times, np.float64))
        return self.normalization.invert(out)

    def _placed_back(self, states: np.ndarray, times: np.ndarray) -> np.ndarray:
        return move_back(self.placement, states, times, self.pivot)

    def to_folder(self) -> ResultFolder:
        """The output contract of this result (DESIGN.md "Output contract") as arrays."""
        return ResultFolder(
            deformed_source=self.deformed_source,
            source_faces=self.source.faces,
            maps=self.maps,
            frames=self.frames,
            frame_times=self.frame_times,
            metrics=self.metrics,
            skeleton_target=self.skeleton_target,
            skeleton_frames=self.skeleton_frames,
            joint_names=list(self.skeleton.names) if self.skeleton.names else None,
            target_vertices=self.target.vertices,
            target_faces=self.target.faces,
            skeleton_source=self.skeleton if self.skeleton_suggested else None,
            source_seen=self.source_seen,
        )

    def save(self, out_dir: str | os.PathLike, overwrite: bool = False, *, shown=None) -> Path:
        """Write the output contract into ``out_dir``, atomically; when the disk fails, a copy is kept under
        the system's temporary folder and the :class:`~ncflow.errors.ResultError` names it
        (:func:`ncflow.io.fallback.save_result`; ``shown``: the folder as the user named it).
        """
        return save_result(self.to_folder(), out_dir, overwrite=overwrite, shown=shown)


def output_motion(
    field, source: np.ndarray, normals: np.ndarray, frame_times: np.ndarray, n_times: int, skeleton, radii, key, program
):
    """The trained flow of everything the outputs need, in one compiled program (``program``:
    :func:`~ncflow.matcher.programs.output_flow_program` of (skeleton, radii, ranges, n_times)): the
    source's frames (Q, V, 3) at ``frame_times`` (cubic Hermite between grid states, exact at grid
    times; its outward vertex ``normals`` (V, 3) read by bone weights that see the skin) and
    FINAL_BONE_SAMPLES fresh samples per bone (B, n, 3) with their grid states (T, B, n, 3). The source
    is padded to a size bucket (:func:`ncflow.jit.buckets.pad_points`, copies of its first vertex; each
    trajectory is independent) so that sources of similar size share the program; the bone samples ride
    along with the source (flowing them separately compiled the flow twice).
    """
    frames, bones, states = program(field, *output_flow_inputs(source, normals, frame_times), key)
    return np.asarray(frames[:, : source.shape[0]], np.float64), bones, states


def final_pose(arrays, config, pose: Pose, bones, states, lam, cw, frame_times: np.ndarray, program):
    """The output pose, its (g^EP, g^TR) and the joint positions (Q, J, 3) at ``frame_times``: the
    training pose refined on the fresh bone samples ``bones`` (B, n, 3) flowed to ``states``
    (T, B, n, 3) (:func:`output_motion`; the per-step fit sees only a few samples) with the final
    multiplier weights, then interpolated from rest. One compiled program (``program``:
    :func:`~ncflow.matcher.programs.output_refit_program`), independent of the source's size (run op by
    op it dispatched ~250 small executables: 20 s on a hand).
    """
    pose, g_ep, g_tr, joints = program(pose, bones, states, lam, cw, np.asarray(frame_times, DTYPE))
    return pose, np.asarray(g_ep, np.float64), np.asarray(g_tr, np.float64), np.asarray(joints, np.float64)


def _versions() -> dict:
    import scipy
    import trimesh

    return {
        "python": platform.python_version(),
        "jax": jax.__version__,
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "trimesh": trimesh.__version__,
        "equinox": eqx.__version__,
        "platform": platform.platform(),
        "device": str(jax.devices()[0]),
    }


def build_result(
    setup: Setup,
    placed: Placed,
    trained: Trained,
    programs: Programs,
    targets: dict,
    config,
    key,
    timings: dict,
    shown: Shown | None = None,
) -> MatchResult:
    """Step 6 of a match: flow the full source, refit the pose, interpolate the skeleton, project the
    target, and every metric of ``metrics.json`` (``timings``: what the earlier steps measured; the
    output phase's seconds, the compile-ahead thread's and the total are added here); ``shown``: what the
    target shows (:mod:`ncflow.matcher.partial`), for ``source_seen`` of the flowed source.

    Raises:
        TrainingError: the trained flow produced non-finite positions.
    """
    t0 = time.perf_counter()
    waited = programs.wait("outputs")
    cfg, norm, state = config, setup.normalization, trained.state
    src_v = setup.source_vertices
    frame_times = output_frame_times(cfg)
    arrays, outputs = programs.arrays, programs.outputs
    normals = start_normals(src_v, setup.source.faces, setup)
    field = state.params.flow
    frames_n, bones, states = output_motion(
        field, src_v, normals, frame_times, cfg.flow.n_times, arrays.skeleton, arrays.radii, key, outputs.flow
    )
    frames_n[0] = src_v  # t = 0 is the source exactly
    deformed_n = frames_n[-1]  # Hermite output at a grid time is the grid state: the state at t = 1
    if not np.all(np.isfinite(frames_n)):
        raise TrainingError("the trained flow produced non-finite positions")
    cw = trained.phase_weights
    pose, g_ep, g_tr, joints = final_pose(
        arrays, cfg, fit_start(field, state.pose), bones, states, state.lam, cw, frame_times, outputs.refit
    )
    src_r, tgt_r = setup.source_repair, setup.target_repair
    target_points = placed.placement.apply(setup.target_points)
    tgt_faces = None if setup.target_cloud is not None else tgt_r.input_faces  # a cloud: nearest points
    maps = correspondence_maps(src_v, src_r.input_faces, deformed_n, target_points, tgt_faces)
    maps["map_face"] = src_r.face_origin[maps["map_face"]]  # the face of the source as given
    seen, partial = np.ones(src_v.shape[0]), {"active": False}
    if shown is not None:
        seen = shown.seen(
            deformed_n, setup.source.faces, placed.placement.apply(setup.target_vertices), setup.target_faces
        )
        partial = dict(shown.info, flowed_source_shown_share=shown_share(src_v, setup.source.faces, seen))
    pivot = src_v.mean(axis=0)
    stretch = skin_stretch(src_v, deformed_n, setup.skeleton_normalized)
    frames_n = move_back(placed.placement, frames_n, frame_times, pivot)
    joints = move_back(placed.placement, joints, frame_times, pivot)
    deformed_n = frames_n[-1]
    timings = dict(timings, outputs=time.perf_counter() - t0)
    metrics = _metrics(setup, placed, trained, programs, targets, cfg, g_ep, g_tr, maps, timings, waited, stretch)
    metrics["partial"] = partial
    return MatchResult(
        source=setup.source,
        target=setup.target,
        skeleton=setup.skeleton,
        skeleton_target=setup.skeleton.with_positions(norm.invert(joints[-1])),
        deformed_source=norm.invert(deformed_n),
        frame_times=frame_times,
        frames=norm.invert(frames_n),
        skeleton_frames=norm.invert(joints),
        maps=maps,
        metrics=metrics,
        normalization=norm,
        field=state.params.flow,
        n_times=cfg.flow.n_times,
        placement=placed.placement,
        pivot=pivot,
        state=state,
        skeleton_suggested=setup.skeleton_suggested is not None,
        source_seen=seen,
    )


def _bone_rows(
    skeleton: Skeleton, g_ep, g_tr, mult: Multipliers, eps: float, aim: float, scale: float, stretch: np.ndarray
) -> list[dict]:
    lam, g_mean = np.asarray(mult.lam), np.asarray(mult.g_mean)
    names = skeleton.bone_names
    return [
        {
            "bone": names[j - 1],
            "g_endpoint": float(g_ep[j - 1]),
            "g_trajectory": float(g_tr[j - 1]),
            "rms_distance_endpoint": float(np.sqrt(g_ep[j - 1]) / scale),
            "satisfied": bool(g_ep[j - 1] <= eps and g_tr[j - 1] <= eps),
            "multiplier_endpoint": float(lam[0, j - 1]),
            "multiplier_trajectory": float(lam[1, j - 1]),
            "held_in_training": bool(g_mean[0, j - 1] <= aim and g_mean[1, j - 1] <= aim),
            "skin_stretch": None if not np.isfinite(stretch[j - 1]) else float(stretch[j - 1]),
        }
        for j in range(1, skeleton.n_joints)
    ]


def bones_beyond_tolerance(rows: list[dict], eps: float) -> tuple[list[dict], str | None]:
    """The bones that end beyond ε (from :func:`_bone_rows`, largest violation first) and the warning
    that names them with g/ε and says which of two causes the run shows: still violated in training at
    the end (the running mean of g above the aim, its multipliers still growing: the data term out-pulls
    the constraint, as when the skeleton cannot reach the target) or held there (beyond ε only on the
    final fresh samples). None when every bone holds.
    """
    beyond = []
    for r in rows:
        ratio = max(r["g_endpoint"], r["g_trajectory"]) / eps
        if ratio > 1.0:
            beyond.append(
                {
                    "bone": r["bone"],
                    "violation_ratio": ratio,
                    "held_in_training": r["held_in_training"],
                    "multiplier": max(r["multiplier_endpoint"], r["multiplier_trajectory"]),
                }
            )
    beyond.sort(key=lambda b: -b["violation_ratio"])
    if not beyond:
        return beyond, None
    named = ", ".join(f"{b['bone']} ({b['violation_ratio']:.2g} ε)" for b in beyond[:5])
    more = f" and {len(beyond) - 5} more" if len(beyond) > 5 else ""
    pulled = [b for b in beyond if not b["held_in_training"]]
    if pulled:
        top = max(b["multiplier"] for b in pulled)
        cause = (
            f"{len(pulled)} of them still violated at the end of training, multipliers rising (up to {top:.3g}): "
            "the target pulls them off rigid; the skeleton may not reach it (a bone of another length, "
            "a joint the skeleton lacks, a limb the target misses)"
        )
    else:
        cause = (
            "held during training, beyond ε on the final fresh samples "
            "(constraints.margin: how far below ε training aims)"
        )
    return beyond, f"{len(beyond)} of {len(rows)} bones end beyond their tolerance ε: {named}{more}; {cause}"


def bones_out_of_reach(rows: list[dict], limit: float) -> tuple[list[dict], str | None]:
    """The bones whose skin the match stretched along them by more than ``limit`` or squeezed below
    1/``limit`` (``skin_stretch`` of :func:`_bone_rows`, :func:`ncflow.skeleton.reach.skin_stretch`; most
    changed first), and the warning that names them: the skeleton did not reach the target there, the
    skin was pulled along a bone that cannot change its length. None when there are none.
    """
    out = [
        {"bone": r["bone"], "skin_stretch": r["skin_stretch"]}
        for r in rows
        if r["skin_stretch"] is not None and abs(np.log(r["skin_stretch"])) > np.log(limit) + 1e-12
    ]
    out.sort(key=lambda b: -abs(np.log(b["skin_stretch"])))
    if not out:
        return out, None
    named = ", ".join(f"{b['bone']} (× {b['skin_stretch']:.2f})" for b in out[:5])
    more = f" and {len(out) - 5} more" if len(out) > 5 else ""
    return out, (
        f"the skeleton did not reach the target along {len(out)} of {len(rows)} bones: their skin was stretched "
        f"or squeezed along the bone by more than × {limit:g}: {named}{more}; the target's limb may be longer "
        "or shorter than the bone, or missing (constraints.reach_stretch)"
    )


def _metrics(setup, placed, trained, programs, targets, cfg, g_ep, g_tr, maps, timings, waited, stretch) -> dict:
    """Everything ``metrics.json`` says of a match."""
    norm, skeleton, eps = setup.normalization, setup.skeleton, cfg.constraints.eps
    ahead_seconds, compile_ahead = programs.report()
    timings.update(ahead_seconds)
    if programs.ahead:
        timings["compile_ahead_wait"] = timings.get("compile_ahead_wait", 0.0) + waited
    timings["total"] = sum(v for k, v in timings.items() if k in ("setup", "train", "outputs"))
    search = placed.pose_search
    aim = cfg.constraints.margin * eps
    bones = _bone_rows(skeleton, g_ep, g_tr, trained.state.multipliers, eps, aim, norm.scale, stretch)
    beyond, warning = bones_beyond_tolerance(bones, eps)
    unreached, reach_warning = bones_out_of_reach(bones, cfg.constraints.reach_stretch)
    warnings = list(setup.warnings) + ([warning] if warning and cfg.constraints.mode == "mdmm" else [])
    return {
        "ncflow_version": __version__,
        "seed": cfg.seed,
        "source": setup.source.name,
        "target": setup.target.name,
        "skeleton": skeleton.name,
        "skeleton_suggested": setup.skeleton_suggested,
        "n_source_vertices": setup.source.n_vertices,
        "n_working_vertices": int(setup.working.vertices.shape[0]),
        "n_target_vertices": setup.target.n_vertices,
        "n_bones": skeleton.n_bones,
        "phases": list(trained.history),
        "constraints": {
            "mode": cfg.constraints.mode,
            "eps": eps,
            "units": "g = mean squared distance in normalised units (source volume 4*pi/3); rms_distance in user units",
            "max_g_endpoint": float(g_ep.max()),
            "max_g_trajectory": float(g_tr.max()),
            "max_violation_ratio": float(max(g_ep.max(), g_tr.max()) / eps),
            "all_satisfied": bool(np.all(g_ep <= eps) and np.all(g_tr <= eps)),
            "bones": bones,
            "beyond_tolerance": beyond,
            "out_of_reach": unreached,
        },
        "correspondence": {
            "mean_distance_target_to_flowed_source": float(np.mean(maps["dist_tgt_to_src"]) / norm.scale),
            "mean_distance_flowed_source_to_target": float(np.mean(maps["dist_src_to_tgt"]) / norm.scale),
        },
        "compression": {f"{k[0]} sigma={k[1]:g}": v[2] for k, v in targets.items()},
        "repair": {"source": dict(setup.source_repair.counts), "target": dict(setup.target_repair.counts)},
        "tissue": setup.tissue_info,
        "normalization": norm.to_dict(),
        "placement": placed.placement.to_dict(norm.scale),
        "warnings": warnings + ([reach_warning] if reach_warning else []),
        "timings": timings,
        "config": config_to_dict(cfg),
        "versions": _versions(),
        "compile_ahead": compile_ahead,
        "rollbacks": list(trained.rollbacks),
        "pose_search": None if search is None else search.to_dict(),
        "placement_trials": list(placed.trials),
        "setup_cache": dict(placed.setup_cache),
        "skinning_weights": dict(setup.skinning_weights),
        "target_cloud": _cloud_summary(setup.target_cloud),
    }


def _cloud_summary(cloud: dict | None) -> dict | None:
    """``metrics.json``'s record of a point-cloud target (:func:`ncflow.matcher.inputs.cloud_surface`, its
    spacing in the target's units), the outliers as indices of points (the first 1000).
    """
    if cloud is None:
        return None
    out = {k: v for k, v in cloud.items() if k != "outliers"}
    out["outlier_indices"] = np.flatnonzero(cloud["outliers"])[:1000].tolist()
    return out


def move_back(placement: Placement | None, states: np.ndarray, times: np.ndarray, pivot: np.ndarray) -> np.ndarray:
    """States (K, N, 3) at ``times`` (K,), trained against the placed target, moved along the rigid
    motion from the identity (t = 0) to the placement's inverse (t = 1); untouched when the target
    was not moved.
    """
    if placement is None or not placement.moved:
        return states
    return np.stack([placement.back_along(s, float(t), pivot) for s, t in zip(states, times)])
