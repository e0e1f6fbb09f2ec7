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

from ncflow.cache import configure_compilation_cache
from ncflow.config import Config, preset, validate_config
from ncflow.match.objective import Arrays
from ncflow.match.prepare import prepare
from ncflow.match.progress import Progress
from ncflow.match.result import MatchResult, build_result
from ncflow.match.stages import build_stages
from ncflow.match.targets import target_measures
from ncflow.match.train import TrainingError, train

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
        self.problem = prepare(source, target, skeleton, self.config, message=self.progress.message)
        self.timings = {
            "setup": 0.0,
            "placement": self.problem.placement_seconds,
            "tissue": self.problem.tissue_seconds,
            "pose_search": self.problem.pose_search_seconds,
        }
        t1 = time.perf_counter()
        self.stages = build_stages(self.config)
        self.targets = target_measures(self.problem, self.stages, self.config, message=self.progress.message)
        self.timings["target"] = time.perf_counter() - t1
        self.arrays = Arrays.from_problem(self.problem)
        self.timings["setup"] = time.perf_counter() - t0

    def run(self) -> MatchResult:
        """Optimise, then build the result (user coordinates)."""
        cfg = self.config
        t_train = time.perf_counter()
        self.progress.start = t_train
        k_init, k_train, k_eval = jax.random.split(jax.random.key(cfg.seed), 3)
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
        )
        train_seconds = time.perf_counter() - t_train
        t_out = time.perf_counter()
        result = build_result(
            self.problem, self.arrays, self.targets, cfg, params, pose, lam, cw, history, k_eval, self.timings
        )
        timings = result.metrics["timings"]
        timings.update(train=train_seconds, per_step=train_seconds / max(done, 1), outputs=time.perf_counter() - t_out)
        result.metrics["rollbacks"] = rollbacks
        result.metrics["pose_search"] = None if search is None else search.to_dict()
        result.metrics["placement_trials"] = list(self.problem.placement_trials)
        result.metrics["skinning_weights"] = dict(self.problem.skinning_weights)
        timings["total"] = sum(v for k, v in timings.items() if k in ("setup", "train", "outputs"))
        return result


def match(source, target, skeleton, config: Config | None = None, *, quiet: bool = False, stream=None) -> MatchResult:
    """Match ``source`` to ``target`` with the source's ``skeleton`` (meshes/skeleton or file paths).

    Returns a :class:`MatchResult` (call ``.save(out_dir)`` for the output contract).
    """
    return Matcher(source, target, skeleton, config, quiet=quiet, stream=stream).run()
