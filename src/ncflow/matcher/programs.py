"""Step 3 of a match: the compiled programs of a problem — the training's and the output phase's (the
flow of the source and of fresh bone samples, the refit of the output pose) — built once it is prepared
and compiled ahead while the target is placed (:mod:`ncflow.jit.ahead`).

Everything the programs depend on — the working source, the skeleton, the tissue centroids, the shapes
of the target measures, the configuration — is known after :func:`~ncflow.matcher.prepare.prepare`, so
:func:`build_programs` builds the training programs (:func:`~ncflow.matcher.train.training_programs`) and
the output programs (:class:`OutputPrograms`) then, and with ``compile_ahead`` a
background thread lowers and compiles them for stand-ins of the arguments they will get
(:func:`~ncflow.matcher.targets.target_stand_ins`) while the placement and the pose search run. Nothing is
run: the results are those of a match without it, bit for bit.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ncflow.flow import hermite, integrate, time_grid
from ncflow.jit.ahead import CompileAhead
from ncflow.jit.buckets import pad_points
from ncflow.jit.cache import jit_run_once
from ncflow.losses import bone_constraints
from ncflow.matcher.objective import Arrays, Settings
from ncflow.matcher.place import searches_pose
from ncflow.matcher.pose_fit import constraint_fit_weights, fit_pose
from ncflow.matcher.prepare import DTYPE, Setup
from ncflow.matcher.stages import Stage, build_stages
from ncflow.matcher.targets import target_stand_ins
from ncflow.matcher.train import TrainingPrograms, compile_step, training_programs
from ncflow.skeleton import interpolate_joints, rigid_reference, sample_bones
from ncflow.skeleton.kinematics import Pose, rest_pose

FINAL_BONE_SAMPLES = 200  # per bone, for the reported g_k (fresh samples, so an estimate of the integral)


def output_flow_program(skeleton, radii, ranges, n_times: int):
    """The compiled program of :func:`output_motion`: ``(field, points, normals, times, key)`` → the
    frames (Q, N, 3) of ``points`` (with their outward ``normals``, for bone weights that read them)
    at ``times``, FINAL_BONE_SAMPLES fresh samples per bone (B, n, 3) and their grid states
    (T, B, n, 3). Built once per problem, so that it can be compiled ahead
    (:mod:`ncflow.jit.ahead`).
    """

    @eqx.filter_jit
    def output_flow(field, points, normals, times, key):
        bones = sample_bones(skeleton, key, FINAL_BONE_SAMPLES, radius=radii, axial_range=ranges, dtype=DTYPE).points
        flat = bones.reshape(-1, 3)
        n = jnp.concatenate([normals, jnp.zeros((flat.shape[0], normals.shape[1]), normals.dtype)])  # samples: none
        xs, vs = integrate(field, jnp.concatenate([points, flat]), n_times, normals=n)
        m = points.shape[0]
        return hermite(xs[:, :m], vs[:, :m], times), bones, xs[:, m:].reshape(n_times, *bones.shape)

    return output_flow


def output_frame_times(config) -> np.ndarray:
    """(Q,) the times of the output frames: ``config.frames`` uniform times in [0, 1]."""
    return np.linspace(0.0, 1.0, config.frames)


def output_flow_inputs(source: np.ndarray, normals: np.ndarray, frame_times: np.ndarray) -> tuple:
    """The points and their normals (the source padded to its size bucket) and the times
    :func:`output_motion` flows.
    """
    return pad_points(np.asarray(source, DTYPE)), pad_points(np.asarray(normals, DTYPE)), np.asarray(frame_times, DTYPE)


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


@dataclasses.dataclass(frozen=True)
class OutputPrograms:
    """The output phase's two programs (:func:`output_flow_program`, :func:`output_refit_program`)."""

    flow: Any
    refit: Any

    @classmethod
    def build(cls, arrays, config) -> OutputPrograms:
        """Both programs of a problem (nothing is compiled yet)."""
        return cls(
            output_flow_program(arrays.skeleton, arrays.radii, arrays.ranges, config.flow.n_times),
            output_refit_program(arrays.skeleton, config),
        )

    def compile(self, field, source: np.ndarray, config, key, pose: Pose, n_bones: int, n_normal: int = 3) -> None:
        """Compile both for a field of ``field``'s structure and a source of ``source``'s size,
        without running them: the arguments :func:`build_result` passes (``pose``, ``key`` and the
        field's values do not matter; ``n_normal``: the columns of the start normals,
        :func:`ncflow.matcher.objective.start_normals`).
        """
        frame_times = output_frame_times(config)
        normals = np.zeros((len(source), n_normal))
        self.flow.lower(field, *output_flow_inputs(source, normals, frame_times), key).compile()
        bones = jnp.zeros((n_bones, FINAL_BONE_SAMPLES, 3), DTYPE)
        states = jnp.zeros((config.flow.n_times, *bones.shape), DTYPE)
        lam, cw = jnp.zeros((2, n_bones), DTYPE), jnp.zeros(2, DTYPE)
        self.refit.lower(pose, bones, states, lam, cw, np.asarray(frame_times, DTYPE)).compile()


@dataclasses.dataclass(frozen=True)
class Programs:
    """A problem's constant arrays, its stages and its programs.

    Attributes:
        arrays: the training dtype's padded arrays (:class:`~ncflow.matcher.objective.Arrays`).
        stages: the (phase, σ) stages of the configuration.
        training: the initialisation, optimiser and step (:class:`~ncflow.matcher.train.TrainingPrograms`).
        outputs: the output phase's programs.
        ahead: the thread compiling them (None with ``compile_ahead`` off).
    """

    arrays: Arrays
    stages: tuple[Stage, ...]
    training: TrainingPrograms
    outputs: OutputPrograms
    ahead: CompileAhead | None

    def wait(self, job: str) -> float:
        """Block until the thread has compiled ``job`` (``training``, ``outputs``); the seconds waited."""
        return self.ahead.wait(job) if self.ahead else 0.0

    def report(self) -> tuple[dict, dict | None]:
        """(the thread's seconds per job, ``{"errors": ...}``; both empty/None without the thread)."""
        if self.ahead is None:
            return {}, None
        return {f"compile_ahead_{job}": s for job, s in self.ahead.seconds.items()}, {"errors": dict(self.ahead.errors)}


def build_programs(setup: Setup, config, keys) -> Programs:
    """The programs of ``setup`` (nothing compiled yet), and with ``compile_ahead`` the thread that compiles
    them (``keys``: the run's initialisation, training and output keys).
    """
    stages = tuple(build_stages(config, setup.working_edge))
    arrays = Arrays.from_problem(setup)
    n_centroids = int(setup.centroids.shape[0])
    training = training_programs(arrays, list(stages), config, n_centroids, setup.skinning_weights["mode"])
    outputs = OutputPrograms.build(arrays, config)
    if not config.compile_ahead:
        return Programs(arrays, stages, training, outputs, None)
    k_init, k_train, k_eval = keys
    skeleton = arrays.skeleton
    rest = rest_pose(skeleton, DTYPE)
    start = rest if searches_pose(config) else None  # what the pose search hands over (its pose's shapes)
    stand_ins = target_stand_ins(setup, list(stages), config)

    def compile_training():
        compile_step(training, skeleton, list(stages), stand_ins, (k_init, k_train), start)

    def compile_outputs():
        field = training.init(k_init, start).flow
        n_normal = arrays.normals.shape[1]
        outputs.compile(field, setup.source_vertices, config, k_eval, rest, skeleton.n_bones, n_normal)

    ahead = CompileAhead([("training", compile_training), ("outputs", compile_outputs)])
    return Programs(arrays, stages, training, outputs, ahead)


def check_programs(programs: Programs, setup: Setup, config) -> None:
    """Raise ValueError unless ``programs`` were built for a problem like ``setup`` with ``config``'s stages
    (same working source, skeleton and bone-weight mode): what reusing them needs.
    """
    arrays = Arrays.from_problem(setup)
    stages = tuple(build_stages(config, setup.working_edge))
    metrics = tuple(dict.fromkeys(st.metric for st in stages))
    old, new = programs.arrays.skeleton, arrays.skeleton
    same = (
        programs.stages == stages
        and programs.training.settings
        == Settings.from_config(
            config, metrics, arrays.n_edges, setup.centroids.shape[0], setup.skinning_weights["mode"]
        )
        and programs.arrays.n_vertices == arrays.n_vertices
        and programs.arrays.n_edges == arrays.n_edges
        and np.array_equal(old.positions, new.positions)
        and np.array_equal(old.parents, new.parents)
        and np.array_equal(np.asarray(programs.arrays.source), np.asarray(arrays.source))
        and np.array_equal(np.asarray(programs.arrays.centroids), np.asarray(arrays.centroids))
        and programs.training.weight_mode == setup.skinning_weights["mode"]
    )
    if not same:
        raise ValueError("the programs were built for another source, skeleton or configuration")
