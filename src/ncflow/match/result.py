"""The result of a match: the outputs in the user's coordinates (DESIGN.md "Output contract").

After training, the full source is flowed by the trained field (frames on a uniform time grid),
the output pose is refitted on fresh bone samples with the final multiplier weights, the skeleton
is interpolated per frame, the target is projected onto the flowed source for the correspondence,
and everything is mapped back through the normalisation. :class:`MatchResult` holds it all and
writes the output contract (:meth:`MatchResult.save`).
"""

from __future__ import annotations

import dataclasses
import os
import platform
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ncflow import __version__
from ncflow.config import config_to_dict
from ncflow.flow import flow_points, hermite, integrate, time_grid
from ncflow.geometry.mesh import Mesh
from ncflow.geometry.normalize import Normalization
from ncflow.io.fallback import save_result
from ncflow.io.result import ResultFolder
from ncflow.jit.buckets import pad_points
from ncflow.jit.cache import jit_run_once
from ncflow.losses import bone_constraints
from ncflow.match.correspondence import correspondence_maps
from ncflow.match.placement import Placement
from ncflow.match.pose_fit import constraint_fit_weights, fit_pose
from ncflow.match.prepare import DTYPE
from ncflow.match.train import TrainingError
from ncflow.skeleton import Skeleton, interpolate_joints, rigid_reference, sample_bones
from ncflow.skeleton.kinematics import Pose


@dataclasses.dataclass
class MatchResult:
    """Everything a match produced, in the user's coordinates.

    Attributes:
        source, target: the input meshes.
        skeleton: the source skeleton; ``skeleton_target`` the fitted target pose of it.
        deformed_source: (V, 3) source vertices flowed to t = 1.
        frame_times: (K,) times in [0, 1]; ``frames`` (K, V, 3) the interpolation.
        skeleton_frames: (K, J, 3) joint positions per frame.
        maps: correspondence (:func:`ncflow.match.correspondence.correspondence_maps`).
        metrics: losses, per-bone constraints, timings, config, versions, seed.
        normalization: the similarity used for training.
        placement: the rigid motion that placed the target on the source for training (normalised
            coordinates); outputs are moved back along it, so they end on the target as given.
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

    def flow(self, points: np.ndarray, times: np.ndarray | None = None) -> np.ndarray:
        """Move any points (user coordinates, e.g. a higher-resolution source) by the trained field.

        Returns (N, 3) at t = 1, or (Q, N, 3) at the given times (the target's placement included,
        as in :attr:`frames`).
        """
        p = jnp.asarray(self.normalization.apply(np.asarray(points, np.float64)), DTYPE)
        if times is None:
            out = np.asarray(flow_points(self.field, p, self.n_times)[-1], np.float64)
            out = self._placed_back(out[None], np.ones(1))[0]
        else:
            out = np.asarray(flow_points(self.field, p, self.n_times, times=jnp.asarray(times, DTYPE)), np.float64)
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
        )

    def save(self, out_dir: str | os.PathLike, overwrite: bool = False, *, shown=None) -> Path:
        """Write the output contract into ``out_dir``, atomically; when the disk fails, a copy is kept under
        the system's temporary folder and the :class:`~ncflow.errors.ResultError` names it
        (:func:`ncflow.io.fallback.save_result`; ``shown``: the folder as the user named it).
        """
        return save_result(self.to_folder(), out_dir, overwrite=overwrite, shown=shown)


FINAL_BONE_SAMPLES = 200  # per bone, for the reported g_k (fresh samples, so an estimate of the integral)


def output_flow_program(skeleton, radii, n_times: int):
    """The compiled program of :func:`output_motion`: ``(field, points, times, key)`` → the frames
    (Q, N, 3) of ``points`` at ``times``, FINAL_BONE_SAMPLES fresh samples per bone (B, n, 3) and
    their grid states (T, B, n, 3). Built once per problem, so that it can be compiled ahead
    (:mod:`ncflow.jit.ahead`).
    """

    @eqx.filter_jit
    def output_flow(field, points, times, key):
        bones = sample_bones(skeleton, key, FINAL_BONE_SAMPLES, radius=radii, dtype=DTYPE).points
        xs, vs = integrate(field, jnp.concatenate([points, bones.reshape(-1, 3)]), n_times)
        m = points.shape[0]
        return hermite(xs[:, :m], vs[:, :m], times), bones, xs[:, m:].reshape(n_times, *bones.shape)

    return output_flow


def output_motion(field, source: np.ndarray, frame_times: np.ndarray, n_times: int, skeleton, radii, key, program=None):
    """The trained flow of everything the outputs need, in one compiled program: the source's
    frames (Q, V, 3) at ``frame_times`` (cubic Hermite between grid states, exact at grid times) and
    FINAL_BONE_SAMPLES fresh samples per bone (B, n, 3) with their grid states (T, B, n, 3). The
    source is padded to a size bucket (:func:`ncflow.jit.buckets.pad_points`, copies of its first vertex;
    each trajectory is independent) so that sources of similar size share the program; the bone
    samples ride along with the source (flowing them separately compiled the flow twice).
    ``program``: :func:`output_flow_program` of (skeleton, radii, n_times), when already built.
    """
    program = program or output_flow_program(skeleton, radii, n_times)
    frames, bones, states = program(field, *output_flow_inputs(source, frame_times), key)
    return np.asarray(frames[:, : source.shape[0]], np.float64), bones, states


def output_frame_times(config) -> np.ndarray:
    """(Q,) the times of the output frames: ``config.frames`` uniform times in [0, 1]."""
    return np.linspace(0.0, 1.0, config.frames)


def output_flow_inputs(source: np.ndarray, frame_times: np.ndarray) -> tuple:
    """The points (the source padded to its size bucket) and times :func:`output_motion` flows."""
    return pad_points(np.asarray(source, DTYPE)), np.asarray(frame_times, DTYPE)


def output_refit_program(skeleton, config):
    """The compiled program of :func:`final_pose`: ``(pose, bones, states, lam, cw, frame_times)`` →
    (pose, g^EP, g^TR, joints). Built once per problem, so that it can be compiled ahead.
    """
    c = config.constraints
    n_times, interp = config.flow.n_times, config.interp

    @jit_run_once
    def output_refit(pose, bones, xs, lam, cw, frame_times):
        times = time_grid(n_times, DTYPE)
        fw = constraint_fit_weights(n_times, bones.shape[0], DTYPE, lam[0] * cw[0], lam[1] * cw[1], c.trajectory_weight)
        pose = fit_pose(skeleton, pose, bones, xs, times, interp, iterations=3, weights=fw)
        g_ep, g_tr = bone_constraints(xs, rigid_reference(skeleton, pose, bones, times, interp))
        joints = jax.vmap(lambda t: interpolate_joints(skeleton, pose, t, interp))(frame_times)
        return pose, g_ep, g_tr, joints

    return output_refit


def final_pose(arrays, config, pose: Pose, bones, states, lam, cw, frame_times: np.ndarray, program=None):
    """The output pose, its (g^EP, g^TR) and the joint positions (Q, J, 3) at ``frame_times``: the
    training pose refined on the fresh bone samples ``bones`` (B, n, 3) flowed to ``states``
    (T, B, n, 3) (:func:`output_motion`; the per-step fit sees only a few samples) with the final
    multiplier weights, then interpolated from rest. One compiled program, independent of the
    source's size (run op by op it dispatched ~250 small executables: 20 s on a hand).
    ``program``: :func:`output_refit_program` of (skeleton, config), when already built.
    """
    program = program or output_refit_program(arrays.skeleton, config)
    pose, g_ep, g_tr, joints = program(pose, bones, states, lam, cw, np.asarray(frame_times, DTYPE))
    return pose, np.asarray(g_ep, np.float64), np.asarray(g_tr, np.float64), np.asarray(joints, np.float64)


@dataclasses.dataclass(frozen=True)
class OutputPrograms:
    """The output phase's two programs (:func:`output_flow_program`, :func:`output_refit_program`)."""

    flow: Any
    refit: Any

    @classmethod
    def build(cls, arrays, config) -> OutputPrograms:
        """Both programs of a problem (nothing is compiled yet)."""
        return cls(
            output_flow_program(arrays.skeleton, arrays.radii, config.flow.n_times),
            output_refit_program(arrays.skeleton, config),
        )

    def compile(self, field, source: np.ndarray, config, key, pose: Pose, n_bones: int) -> None:
        """Compile both for a field of ``field``'s structure and a source of ``source``'s size,
        without running them: the arguments :func:`build_result` passes (``pose``, ``key`` and the
        field's values do not matter).
        """
        frame_times = output_frame_times(config)
        self.flow.lower(field, *output_flow_inputs(source, frame_times), key).compile()
        bones = jnp.zeros((n_bones, FINAL_BONE_SAMPLES, 3), DTYPE)
        states = jnp.zeros((config.flow.n_times, *bones.shape), DTYPE)
        lam, cw = jnp.zeros((2, n_bones), DTYPE), jnp.zeros(2, DTYPE)
        self.refit.lower(pose, bones, states, lam, cw, np.asarray(frame_times, DTYPE)).compile()


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
    problem, arrays, targets, config, params, pose: Pose, lam, cw, history, key, timings, programs=None
) -> MatchResult:
    """Flow the full source, refit the pose, interpolate the skeleton, project the target; metrics.
    ``programs``: the problem's :class:`OutputPrograms`, when already built (and perhaps compiled).

    Raises:
        TrainingError: the trained flow produced non-finite positions.
    """
    cfg = config
    norm = problem.normalization
    source, target, skeleton = problem.source, problem.target, problem.skeleton
    src_v = problem.source_vertices
    frame_times = output_frame_times(cfg)
    programs = programs or OutputPrograms.build(arrays, cfg)
    frames_n, bones, states = output_motion(
        params.flow, src_v, frame_times, cfg.flow.n_times, arrays.skeleton, arrays.radii, key, programs.flow
    )
    frames_n[0] = src_v  # t = 0 is the source exactly
    deformed_n = frames_n[-1]  # Hermite output at a grid time is the grid state: the state at t = 1
    if not np.all(np.isfinite(frames_n)):
        raise TrainingError("the trained flow produced non-finite positions")
    pose, g_ep, g_tr, joints = final_pose(arrays, cfg, pose, bones, states, lam, cw, frame_times, programs.refit)
    src_r, tgt_r = problem.source_repair, problem.target_repair
    maps = correspondence_maps(src_v, src_r.input_faces, deformed_n, problem.target_points, tgt_r.input_faces)
    maps["map_face"] = src_r.face_origin[maps["map_face"]]  # the face of the source as given
    pivot = src_v.mean(axis=0)
    frames_n = move_back(problem.placement, frames_n, frame_times, pivot)
    joints = move_back(problem.placement, joints, frame_times, pivot)
    deformed_n = frames_n[-1]
    eps = cfg.constraints.eps
    names = skeleton.names or tuple(f"joint {j}" for j in range(skeleton.n_joints))
    bones = [
        {
            "bone": f"{names[skeleton.parents[j]]} -> {names[j]}",
            "g_endpoint": float(g_ep[j - 1]),
            "g_trajectory": float(g_tr[j - 1]),
            "rms_distance_endpoint": float(np.sqrt(g_ep[j - 1]) / norm.scale),
            "satisfied": bool(g_ep[j - 1] <= eps and g_tr[j - 1] <= eps),
            "multiplier_endpoint": float(lam[0, j - 1]),
            "multiplier_trajectory": float(lam[1, j - 1]),
        }
        for j in range(1, skeleton.n_joints)
    ]
    metrics = {
        "ncflow_version": __version__,
        "seed": cfg.seed,
        "source": source.name,
        "target": target.name,
        "skeleton": skeleton.name,
        "n_source_vertices": source.n_vertices,
        "n_working_vertices": int(problem.working.vertices.shape[0]),
        "n_target_vertices": target.n_vertices,
        "n_bones": skeleton.n_bones,
        "phases": history,
        "constraints": {
            "mode": cfg.constraints.mode,
            "eps": eps,
            "units": "g = mean squared distance in normalised units (source volume 4*pi/3); rms_distance in user units",
            "max_g_endpoint": float(g_ep.max()),
            "max_g_trajectory": float(g_tr.max()),
            "max_violation_ratio": float(max(g_ep.max(), g_tr.max()) / eps),
            "all_satisfied": bool(np.all(g_ep <= eps) and np.all(g_tr <= eps)),
            "bones": bones,
        },
        "correspondence": {
            "mean_distance_target_to_flowed_source": float(np.mean(maps["dist_tgt_to_src"]) / norm.scale),
            "mean_distance_flowed_source_to_target": float(np.mean(maps["dist_src_to_tgt"]) / norm.scale),
        },
        "compression": {f"{k[0]} sigma={k[1]:g}": v[2] for k, v in targets.items()},
        "repair": {"source": dict(src_r.counts), "target": dict(tgt_r.counts)},
        "tissue": problem.tissue_info,
        "normalization": norm.to_dict(),
        "placement": problem.placement.to_dict(norm.scale),
        "warnings": list(problem.warnings),
        "timings": dict(timings),
        "config": config_to_dict(cfg),
        "versions": _versions(),
    }
    return MatchResult(
        source=source,
        target=target,
        skeleton=skeleton,
        skeleton_target=skeleton.with_positions(norm.invert(joints[-1])),
        deformed_source=norm.invert(deformed_n),
        frame_times=frame_times,
        frames=norm.invert(frames_n),
        skeleton_frames=norm.invert(joints),
        maps=maps,
        metrics=metrics,
        normalization=norm,
        field=params.flow,
        n_times=cfg.flow.n_times,
        placement=problem.placement,
        pivot=pivot,
    )


def move_back(placement: Placement | None, states: np.ndarray, times: np.ndarray, pivot: np.ndarray) -> np.ndarray:
    """States (K, N, 3) at ``times`` (K,), trained against the placed target, moved along the rigid
    motion from the identity (t = 0) to the placement's inverse (t = 1); untouched when the target
    was not moved.
    """
    if placement is None or not placement.moved:
        return states
    return np.stack([placement.back_along(s, float(t), pivot) for s, t in zip(states, times)])
