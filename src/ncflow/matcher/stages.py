"""Stages of a run: each phase of the configuration split into one stage per length scale σ, and the
learning-rate schedule of a phase (warm-up, then constant or cosine; reference-notes §10.2).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from ncflow.config import Config, PhaseConfig
from ncflow.measures.registry import metric_key
from ncflow.optim.schedules import warmup_constant, warmup_cosine


@dataclasses.dataclass
class Stage:
    """One (phase, σ) stage: ``steps`` steps starting at step ``start`` of its phase; ``metric`` its data
    term's name in :data:`ncflow.measures.METRICS` (:func:`stage_metric`).
    """

    phase: int
    phase_config: PhaseConfig
    metric: str
    sigma: float
    steps: int
    start: int  # step within the phase at which this stage starts


COARSE_EDGE = 1.4
"""A stage of a ``metric = "auto"`` phase integrates the Varifold at four points a face when the source's
median edge is longer than this × its σ, and uses Normal Cycles otherwise (:func:`stage_metric`)."""


def stage_metric(p: PhaseConfig, sigma: float, edge: float | None) -> str:
    """The data term of phase ``p``'s stage at ``sigma`` (a name in :data:`ncflow.measures.METRICS`) for a
    working source of median edge ``edge`` (normalised units): the phase's metric at its quadrature, or
    for ``metric = "auto"`` Normal Cycles where ``edge`` ≤ :data:`COARSE_EDGE` · σ and else the Varifold
    at four points a face.

    Why: below a source's edge length neither term is what it is on a fine mesh. The Normal Cycle puts the
    curvature on the edges, so two triangulations of one surface are different measures whatever the
    quadrature (MANO, 0.155 median edge, σ = 0.1: the source at the truth scores 0.37 of ⟨Y, Y⟩ against 0.20
    after training onto its own retriangulation, each edge integrated at points 0.025 apart); the
    Varifold's bias is its one-point rule, and four points a face remove it (0.016 against 0.018: the truth
    scores better). Four points cost 16× the one-point rule's source term, so finer sources, where the bias
    is small, keep Normal Cycles (docs/tuning.md, "The last stage on coarse sources").
    """
    if p.metric != "auto":
        return metric_key(p.metric, p.quadrature)
    if edge is None:
        raise ValueError('a phase with metric "auto" needs the source\'s median edge')
    return "normal-cycles" if edge <= COARSE_EDGE * sigma else metric_key("varifold", 4)


def build_stages(config: Config, edge: float | None = None) -> list[Stage]:
    """The phases of ``config`` split evenly (rounded) into one stage per σ; empty stages are dropped.
    ``edge``: the working source's median edge (:attr:`ncflow.matcher.prepare.Setup.working_edge`), which
    ``metric = "auto"`` phases need (:func:`stage_metric`).
    """
    stages = []
    for i, p in enumerate(config.phases):
        n = len(p.sigmas)
        bounds = np.linspace(0, p.steps, n + 1).round().astype(int)
        for k, sigma in enumerate(p.sigmas):
            if bounds[k + 1] > bounds[k]:
                metric = stage_metric(p, float(sigma), edge)
                stages.append(Stage(i, p, metric, float(sigma), int(bounds[k + 1] - bounds[k]), int(bounds[k])))
    return stages


def last_phase_stages(config: Config, steps: int, lr: float | None = None, edge: float | None = None) -> list[Stage]:
    """The stages of ``config``'s last phase alone, shortened to ``steps`` steps at peak rate at most ``lr``
    (None: the phase's; warm-up at most a fifth of them), named "warm": a warm start's short training on
    the programs of the whole configuration (the stages keep the phase's index; ``edge`` as for
    :func:`build_stages`).
    """
    last = len(config.phases) - 1
    p = config.phases[last]
    phase = dataclasses.replace(
        p,
        name="warm",
        steps=int(steps),
        lr=p.lr if lr is None else min(float(lr), p.lr),
        warmup=min(p.warmup, max(0, int(steps) // 5)),
    )
    short = build_stages(dataclasses.replace(config, phases=(phase,)), edge)
    return [dataclasses.replace(st, phase=last) for st in short]


def phase_schedule(p: PhaseConfig) -> Callable[[int], float]:
    """Learning rate at step s of phase ``p`` (a Python float)."""
    if p.lr_end is None:
        sched = warmup_constant(p.lr, p.warmup)
    else:
        sched = warmup_cosine(p.lr, p.lr_end, p.warmup, max(p.steps, p.warmup + 1))
    return lambda s: float(sched(s))
