"""The matcher: correspondence-free matching and interpolation of two poses (paper §4, Eq. 22–27), as
plain steps a caller can run one by one and re-enter.

1. :func:`~ncflow.matcher.prepare.prepare` — inputs → :class:`~ncflow.matcher.prepare.Setup` (loaded,
   repaired, checked, normalised; working source, tissue, edge tables);
2. :func:`~ncflow.matcher.programs.build_programs` — the compiled programs of the setup, compiled ahead in
   a thread while the next step runs;
3. :func:`~ncflow.matcher.place.place` — the target placed on the source and the skeleton's pose searched
   (:class:`~ncflow.matcher.place.Placed`), or taken from an earlier result (:meth:`Placed.of_result`);
   without a given skeleton and with ``skeleton_bases = "choose"`` it runs before step 2, once per
   suggested skeleton, and the skeleton whose pose explains the target best is kept
   (:func:`~ncflow.matcher.place.place_suggested`);
4. :func:`~ncflow.matcher.targets.target_measures` — the target's Varifold / Normal Cycles per length scale,
   compressed;
5. :func:`~ncflow.matcher.train.train` — the flow net F_θ (with the ``fast`` preset a skeleton-driven
   :class:`~ncflow.flow.SkinnedField`), the GSO rotation net and the per-bone multipliers, stage by stage
   (:class:`~ncflow.matcher.train.Trained`), from scratch or from an earlier result's state;
6. :func:`~ncflow.matcher.result.build_result` — the full source flowed, frames, skeleton, correspondence
   and every metric: a :class:`~ncflow.matcher.result.MatchResult` in the user's coordinates.

:func:`match` runs them in order; a sequence of matches hands each result to the next as ``start``.
"""

from __future__ import annotations

import dataclasses
import time

import jax
import numpy as np

from ncflow.config import Config, preset, validate_config
from ncflow.jit.cache import configure_compilation_cache
from ncflow.matcher.partial import Shown, shown_parts
from ncflow.matcher.place import Placed, place, place_suggested
from ncflow.matcher.placement import Placement
from ncflow.matcher.prepare import Setup, prepare, skinning_width, with_joints
from ncflow.matcher.programs import Programs, build_programs, check_programs
from ncflow.matcher.progress import Progress
from ncflow.matcher.result import MatchResult
from ncflow.matcher.result import build_result as build_result
from ncflow.matcher.stages import build_stages, last_phase_stages
from ncflow.matcher.targets import target_measures, target_stand_ins
from ncflow.matcher.train import TrainingError, TrainState, stage_placeholders, train

__all__ = ["Matcher", "MatchResult", "TrainingError", "WarmStart", "match", "run_keys"]


@dataclasses.dataclass(frozen=True)
class WarmStart:
    """What a match may start from besides a whole earlier result: a trained state and the placement of
    the new target (``ncflow track`` hands each frame the previous frame's state and a placement followed
    onto the new frame), and optionally a short training: the configuration's last phase alone, ``steps``
    steps at peak rate at most ``lr`` (:func:`~ncflow.matcher.stages.last_phase_stages`). The programs are
    still the whole configuration's, so a warm match can run on the programs of a full one.
    """

    state: TrainState
    placement: Placement
    steps: int | None = None
    lr: float | None = None


def run_keys(seed: int) -> tuple:
    """The run's three random keys, drawn from ``seed``: initialisation, training, outputs."""
    return tuple(jax.random.split(jax.random.key(seed), 3))


def match(
    source,
    target,
    skeleton,
    config: Config | None = None,
    *,
    quiet: bool = False,
    stream=None,
    start: MatchResult | WarmStart | None = None,
) -> MatchResult:
    """Match ``source`` to ``target`` with the source's ``skeleton`` (meshes/skeleton or file paths).

    Args:
        source: the source mesh (or its path).
        target: the target mesh (or its path), of any triangulation and resolution.
        skeleton: the source's skeleton (or a path: TGF, JSON, glTF), or None: one is suggested from the
            source (:func:`ncflow.skeleton.suggest.suggest_skeleton`) and written as ``skeleton_source.tgf``.
        config: a :class:`~ncflow.config.Config` (default: the ``fast`` preset).
        quiet: no progress display.
        stream: where the progress display goes (default stderr).
        start: an earlier result of the same source and skeleton to go on from (a warm start): its
            placement and trained pose replace the placement and the pose search, and the training
            starts from its networks and multipliers; or a :class:`WarmStart` (a state and a placement).

    Returns:
        a :class:`~ncflow.matcher.result.MatchResult` (``.save(out_dir)`` writes the output contract).
    """
    return Matcher(source, target, skeleton, config, quiet=quiet, stream=stream, start=start).run()


def shown_by(setup: Setup, placed: Placed, config: Config) -> Shown:
    """What the placed target shows of the working source posed as ``placed`` says (setting ``partial``;
    :func:`ncflow.matcher.partial.shown_parts`).
    """
    return shown_parts(
        setup.skeleton_normalized,
        np.asarray(setup.working.vertices),
        np.asarray(setup.working.faces),
        setup.source_topology,
        placed.placement.apply(setup.target_vertices),
        setup.target_topology,
        placed.initial_pose,
        skinning_width(config, setup.skeleton_normalized),
        config.partial,
    )


def apply_runtime_settings(config: Config) -> None:
    """What a match sets in JAX for the process: the persistent compilation cache of ``config.jit_cache``
    (from the first match on). The options that let pairs share compiled programs are JAX's at its start
    (:func:`ncflow.jit.cache.prepare_jax`, run by ``import ncflow``).
    """
    configure_compilation_cache(config.jit_cache)


class Matcher:
    """The steps of :func:`match` for one (source, target, skeleton): the constructor runs steps 1–4
    (the problem prepared, its programs compiling, the target placed and measured), :meth:`run` steps 5–6.

    ``programs``: the compiled programs of an earlier matcher of the same source, skeleton and
    configuration (its :attr:`programs`; they depend on nothing of the target), used instead of
    building and compiling them again — a sequence's frames share them.

    Attributes:
        config: the validated configuration.
        setup, programs, placed, targets: what steps 1–4 made; ``shown``: what the target shows of the
            source (:func:`shown_by`).
        stages: the stages trained (the configuration's, or a short warm start's last phase).
        timings: their seconds (``setup``, ``placement``, ``tissue``, ``pose_search``, ``target``).
    """

    def __init__(
        self,
        source,
        target,
        skeleton,
        config: Config | None = None,
        *,
        quiet: bool = False,
        stream=None,
        start: MatchResult | WarmStart | None = None,
        programs: Programs | None = None,
    ):
        t0 = time.perf_counter()
        self.config = validate_config(config or preset("fast"))
        apply_runtime_settings(self.config)
        self.keys = run_keys(self.config.seed)  # initialisation, training, outputs
        self.start = start
        short = isinstance(start, WarmStart) and start.steps is not None
        self.progress = Progress(int(start.steps) if short else self.config.total_steps, quiet, stream)
        self.setup = prepare(source, target, skeleton, self.config, message=self.progress.message)
        edge = self.setup.working_edge
        if short:
            self.stages = last_phase_stages(self.config, start.steps, start.lr, edge)
        else:
            self.stages = build_stages(self.config, edge)
        placed = None
        if start is not None:
            self.setup = with_joints(self.setup, np.asarray(start.state.pose.rotations).shape[0])
            placed = Placed.of_result(start)
        elif self.setup.alternatives:  # a suggested skeleton: the pose search chooses before programs are built
            self.setup, placed = place_suggested(self.setup, self.config, message=self.progress.message)
        self.programs = build_programs(self.setup, self.config, self.keys) if programs is None else programs
        if programs is not None:
            check_programs(programs, self.setup, self.config)
        self.placed = place(self.setup, self.config, message=self.progress.message) if placed is None else placed
        self.timings = {
            "setup": 0.0,
            "placement": self.placed.placement_seconds,
            "tissue": self.setup.tissue_seconds,
            "pose_search": self.placed.pose_search_seconds,
        }
        t1 = time.perf_counter()
        self.shown = shown_by(self.setup, self.placed, self.config)
        if self.shown.partial:
            self.progress.message(
                f"the target shows part of the source ({100 * self.shown.info['source_shown_share']:.0f} % of its "
                "area)" + (": partial data terms" if self.shown.active else "")
            )
        self.targets = target_measures(
            self.setup, self.placed, self.stages, self.config, message=self.progress.message, shown=self.shown
        )
        self.timings["target"] = time.perf_counter() - t1
        self.timings["setup"] = time.perf_counter() - t0

    def _placeholders(self) -> dict | None:
        """Targets of the right shape (stand-ins) for the data terms of the programs that no stage trained
        here reads (a short warm start's last phase reads one); None when every one is read.
        """
        read = {st.metric for st in self.stages}
        unread = [st for st in self.programs.stages if st.metric not in read]
        if not unread:
            return None
        return stage_placeholders(unread, target_stand_ins(self.setup, unread, self.config))

    def run(self) -> MatchResult:
        """Train, then build the result (user coordinates)."""
        cfg, programs = self.config, self.programs
        t_train = time.perf_counter()
        waited = programs.wait("training")
        self.progress.start = t_train
        k_init, k_train, k_eval = self.keys
        trained = train(
            programs.training,
            programs.arrays.skeleton,
            self.targets,
            list(self.stages),
            cfg,
            (k_init, k_train),
            self.progress,
            self.placed.initial_pose,
            start=None if self.start is None else self.start.state,
            placeholders=self._placeholders(),
        )
        train_seconds = time.perf_counter() - t_train
        timings = dict(self.timings, train=train_seconds, per_step=train_seconds / max(trained.steps, 1))
        if programs.ahead:
            timings["compile_ahead_wait"] = waited
        result = build_result(
            self.setup, self.placed, trained, programs, self.targets, cfg, k_eval, timings, shown=self.shown
        )
        for warning in result.metrics["warnings"][len(self.setup.warnings) :]:  # what the training left
            self.progress.message(f"warning: {warning}")
        return result
