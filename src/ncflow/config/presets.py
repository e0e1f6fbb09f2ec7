"""The presets: ``fast`` (the default, for a 2-core CPU) and ``paper`` (the paper's and the release's settings).

* ``fast`` — tuned for a 2-core CPU: a narrow flow net plus the skeleton-driven velocities
  (``flow.skinning``), few bone/tissue samples per step, a short Varifold phase then Normal Cycles
  coarse → fine (``metric = "auto"``: a stage whose σ is below the source's edge length takes the
  Varifold at four points a face instead, :func:`ncflow.matcher.stages.stage_metric`), target
  compressed per length scale, MDMM aiming at 0.7 ε.
* ``paper`` — the paper/release settings (reference-notes §10): width-256 depth-6 flow net,
  50 samples per bone, 2000 tissue samples, 2000 Varifold steps (σ 0.5 → 0.25) then 2000 Normal
  Cycle steps (σ 0.25 → 0.1) and 1000 fine-tuning steps, AdaBelief-cautious with lr 3e-3.
  Hours on a CPU; meant for a GPU.
"""

from __future__ import annotations

import typing

from ncflow.config.quoting import quote
from ncflow.config.settings import (
    Config,
    ConstraintConfig,
    FlowConfig,
    PhaseConfig,
    SamplingConfig,
    TissueConfig,
    WeightsConfig,
)
from ncflow.errors import InputError


def _fast() -> Config:
    return Config(
        preset="fast",
        phases=(
            PhaseConfig(name="varifold", metric="varifold", steps=150, sigmas=(0.25,), lr=3e-3, warmup=10),
            PhaseConfig(
                metric="auto",
                steps=250,
                sigmas=(0.25, 0.1),
                lr=3e-3,
                lr_end=3e-4,
                warmup=10,
            ),
        ),
    )


def _paper() -> Config:
    return Config(
        preset="paper",
        flow=FlowConfig(width=256, depth=6, n_times=10, gso_width=128, gso_depth=3, skinning=False),
        sampling=SamplingConfig(bone_samples=50, tissue_samples=2000, surface_edges=0),
        phases=(
            PhaseConfig(
                name="varifold",
                metric="varifold",
                steps=2000,
                sigmas=(0.5, 0.25),
                lr=3e-3,
                warmup=100,
                trajectory=False,
            ),
            PhaseConfig(
                name="normal-cycles",
                metric="normal-cycles",
                steps=2000,
                sigmas=(0.25, 0.1),
                lr=3e-3,
                lr_end=1e-4,
                warmup=100,
            ),
            PhaseConfig(name="fine-tune", metric="normal-cycles", steps=1000, sigmas=(0.1,), lr=1e-4, warmup=100),
        ),
        constraints=ConstraintConfig(eps=3e-4, margin=1.0),
        weights=WeightsConfig(surface=20.0, tissue=10.0),
        tissue=TissueConfig(edge_length_fac=0.05, epsilon=1e-3, split_passes=2),
        compress=6000,
        working_vertices=6000,
        frames=100,
    )


PRESETS: dict[str, typing.Callable[[], Config]] = {"fast": _fast, "paper": _paper}


def preset(name: str) -> Config:
    """A preset configuration by name (``fast`` or ``paper``)."""
    if name not in PRESETS:
        raise InputError(f"unknown preset {quote(name)}; choose from {', '.join(PRESETS)}")
    return PRESETS[name]()
