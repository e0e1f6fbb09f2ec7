"""The matcher: correspondence-free matching and interpolation of two poses (paper §4, Eq. 22–27).

Pipeline (DESIGN.md "Pipeline"): :func:`~ncflow.match.prepare.prepare` (validate inputs, one
similarity normalises source, target and skeleton, topology, soft-tissue samples) →
:func:`~ncflow.match.targets.target_measures` (Varifold / Normal Cycles per length scale,
compressed) → :func:`~ncflow.match.train.train` (the flow net F_θ — with the ``fast`` preset a
:class:`~ncflow.flow.SkinnedField`: blended rigid bone velocities of a trained skeleton pose plus
the Flow-Net — the GSO rotation net and the per-bone multipliers, stage by stage, on the objective
of :mod:`ncflow.match.objective`) → :func:`~ncflow.match.result.build_result` (flow the full
source, interpolate frames and the skeleton, project the target for the correspondence) →
:class:`~ncflow.match.result.MatchResult` in the user's coordinates.
"""

from __future__ import annotations

import time

import jax

from ncflow.config import Config, preset, validate_config
from ncflow.jit.ahead import CompileAhead
from ncflow.jit.cache import configure_compilation_cache
from ncflow.match.objective import Arrays
from ncflow.match.prepare import DTYPE, Problem, prepare, searches_pose
from ncflow.match.progress import Progress
from ncflow.match.result import MatchResult, OutputPrograms, build_result
from ncflow.match.stages import build_stages
from ncflow.match.targets import target_measures, target_stand_ins
from ncflow.match.train import TrainingError, compile_step, train, training_programs
from ncflow.skeleton.kinematics import rest_pose

__all__ = ["Matcher", "MatchResult", "TrainingError", "match"]


class Matcher:
    """Precomputes everything for one (source, target, skeleton) and runs the optimisation.

    Args:
        source, target: meshes (or paths); the target may have any triangulation and resolution.
        skeleton: the source's skeleton (or a path: TGF, JSON, glTF).
        config: a :class:`~ncflow.config.Config` (default: the ``fast`` preset).
        quiet: no progress display.
        stream: where the progress display goes (default stderr).
    """

    def __init__(self, source, target, skeleton, config: Config | None = None, *, quiet: bool = False, stream=None):
        t0 = time.perf_counter()
        self.config = validate_config(config or preset("fast"))
        configure_compilation_cache(self.config.jit_cache)
        self.progress = Progress(self.config.total_steps, quiet, stream)
        self.keys = jax.random.split(jax.random.key(self.config.seed), 3)  # initialisation, training, outputs
        self.stages = build_stages(self.config)
        self.ahead: CompileAhead | None = None
        self.problem = prepare(
            source, target, skeleton, self.config, message=self.progress.message, before_search=self._programs
        )
        self.timings = {
            "setup": 0.0,
            "placement": self.problem.placement_seconds,
            "tissue": self.problem.tissue_seconds,
            "pose_search": self.problem.pose_search_seconds,
        }
        t1 = time.perf_counter()
        self.targets = target_measures(self.problem, self.stages, self.config, message=self.progress.message)
        self.timings["target"] = time.perf_counter() - t1
        self.timings["setup"] = time.perf_counter() - t0

    def _programs(self, problem: Problem) -> None:
        """The problem's arrays and compiled programs, built before the placement and the pose search
        (:func:`~ncflow.match.prepare.prepare`'s ``before_search``), and with ``compile_ahead`` a
        thread that compiles them meanwhile (:mod:`ncflow.jit.ahead`).
        """
        cfg = self.config
        self.arrays = Arrays.from_problem(problem)
        n_centroids = int(problem.centroids.shape[0])
        self.training = training_programs(self.arrays, self.stages, cfg, n_centroids, problem.skinning_weights["mode"])
        self.outputs = OutputPrograms.build(self.arrays, cfg)
        if not cfg.compile_ahead:
            return
        k_init, k_train, k_eval = self.keys
        skeleton = self.arrays.skeleton
        rest = rest_pose(skeleton, DTYPE)
        start = rest if searches_pose(cfg) else None  # what the pose search hands over (its pose's shapes)
        stand_ins = target_stand_ins(problem, self.stages, cfg)

        def training():
            compile_step(self.training, skeleton, self.stages, stand_ins, (k_init, k_train), start)

        def outputs():
            field = self.training.init(k_init, start).flow
            self.outputs.compile(field, problem.source_vertices, cfg, k_eval, rest, skeleton.n_bones)

        self.ahead = CompileAhead([("training", training), ("outputs", outputs)])

    def run(self) -> MatchResult:
        """Optimise, then build the result (user coordinates)."""
        cfg = self.config
        t_train = time.perf_counter()
        waited = self.ahead.wait("training") if self.ahead else 0.0
        self.progress.start = t_train
        k_init, k_train, k_eval = self.keys
        search = self.problem.pose_search
        initial_pose = None if search is None else search.pose
        params, pose, lam, cw, history, done, rollbacks = train(
            self.arrays,
            self.targets,
            self.stages,
            cfg,
            (k_init, k_train),
            self.progress,
            int(self.problem.centroids.shape[0]),
            initial_pose,
            self.problem.skinning_weights["mode"],
            self.training,
        )
        train_seconds = time.perf_counter() - t_train
        t_out = time.perf_counter()
        waited_outputs = self.ahead.wait("outputs") if self.ahead else 0.0
        result = build_result(
            self.problem,
            self.arrays,
            self.targets,
            cfg,
            params,
            pose,
            lam,
            cw,
            history,
            k_eval,
            self.timings,
            self.outputs,
        )
        timings = result.metrics["timings"]
        timings.update(train=train_seconds, per_step=train_seconds / max(done, 1), outputs=time.perf_counter() - t_out)
        if self.ahead:  # the thread's seconds per job, and how long the run waited for it
            timings.update({f"compile_ahead_{job}": s for job, s in self.ahead.seconds.items()})
            timings.update(compile_ahead_wait=waited + waited_outputs)
        result.metrics["compile_ahead"] = {"errors": dict(self.ahead.errors)} if self.ahead else None
        result.metrics["rollbacks"] = rollbacks
        result.metrics["pose_search"] = None if search is None else search.to_dict()
        result.metrics["placement_trials"] = list(self.problem.placement_trials)
        result.metrics["setup_cache"] = dict(self.problem.setup_cache)
        result.metrics["skinning_weights"] = dict(self.problem.skinning_weights)
        timings["total"] = sum(v for k, v in timings.items() if k in ("setup", "train", "outputs"))
        return result


def match(source, target, skeleton, config: Config | None = None, *, quiet: bool = False, stream=None) -> MatchResult:
    """Match ``source`` to ``target`` with the source's ``skeleton`` (meshes/skeleton or file paths).

    Returns a :class:`MatchResult` (call ``.save(out_dir)`` for the output contract).
    """
    return Matcher(source, target, skeleton, config, quiet=quiet, stream=stream).run()
