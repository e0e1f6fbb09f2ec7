"""Stages of a run: each phase of the configuration split into one stage per length scale σ, and the
learning-rate schedule of a phase (warm-up, then constant or cosine; reference-notes §10.2).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from ncflow.config import Config, PhaseConfig
from ncflow.optim.schedules import warmup_constant, warmup_cosine


@dataclasses.dataclass
class Stage:
    """One (phase, σ) stage: ``steps`` steps starting at step ``start`` of its phase."""

    phase: int
    phase_config: PhaseConfig
    metric: str
    sigma: float
    steps: int
    start: int  # step within the phase at which this stage starts


def build_stages(config: Config) -> list[Stage]:
    """The phases of ``config`` split evenly (rounded) into one stage per σ; empty stages are dropped."""
    stages = []
    for i, p in enumerate(config.phases):
        n = len(p.sigmas)
        bounds = np.linspace(0, p.steps, n + 1).round().astype(int)
        for k, sigma in enumerate(p.sigmas):
            if bounds[k + 1] > bounds[k]:
                stages.append(Stage(i, p, p.metric, float(sigma), int(bounds[k + 1] - bounds[k]), int(bounds[k])))
    return stages


def last_phase_stages(config: Config, steps: int, lr: float | None = None) -> list[Stage]:
    """The stages of ``config``'s last phase alone, shortened to ``steps`` steps at peak rate at most ``lr``
    (None: the phase's; warm-up at most a fifth of them), named "warm": a warm start's short training on
    the programs of the whole configuration (the stages keep the phase's index).
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
    short = build_stages(dataclasses.replace(config, phases=(phase,)))
    return [dataclasses.replace(st, phase=last) for st in short]


def phase_schedule(p: PhaseConfig) -> Callable[[int], float]:
    """Learning rate at step s of phase ``p`` (a Python float)."""
    if p.lr_end is None:
        sched = warmup_constant(p.lr, p.warmup)
    else:
        sched = warmup_cosine(p.lr, p.lr_end, p.warmup, max(p.steps, p.warmup + 1))
    return lambda s: float(sched(s))
