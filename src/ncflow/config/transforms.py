"""Every ``Config → Config`` transform: the ablation switches, the step count, the options of the command
line as Python keywords, and the configuration as a plain dict.
"""

from __future__ import annotations

import dataclasses
import json
import os

from ncflow.config.checks import validate_config
from ncflow.config.quoting import quote
from ncflow.config.settings import RESULT_NEUTRAL, Config
from ncflow.errors import InputError
from ncflow.io.files import file_sha256


def config_to_dict(config: Config) -> dict:
    """Plain nested dict (JSON/TOML-ready) of a configuration."""
    return dataclasses.asdict(config)


def result_config(config: Config) -> dict:
    """The configuration as far as it can change a result: without the settings that never do
    (:data:`ncflow.config.settings.RESULT_NEUTRAL`: a cache folder, compiling ahead), ``tissue.file`` given
    by its content (``sha256:<hex>``) rather than its path.
    """
    data = json.loads(json.dumps(config_to_dict(config)))
    for name in RESULT_NEUTRAL:
        data.pop(name, None)
    file = config.tissue.file
    if file:
        data["tissue"]["file"] = f"sha256:{file_sha256(file)}" if os.path.isfile(file) else str(file)
    return data


def with_metric(config: Config, metric: str) -> Config:
    """Ablation switch ``--metric``: 'varifold', 'normal-cycles' or 'varifold+normal-cycles' (the default)."""
    if metric == "varifold+normal-cycles":
        return config
    if metric not in ("varifold", "normal-cycles"):
        raise InputError(f"--metric must be varifold, normal-cycles or varifold+normal-cycles (got {quote(metric)})")
    phases = tuple(
        dataclasses.replace(p, metric=metric, quadrature=p.quadrature if metric == "varifold" else 1)
        for p in config.phases
    )
    return dataclasses.replace(config, phases=phases)


def scale_steps(cfg: Config, total: int) -> Config:
    """Rescale the phases' step counts (and warm-ups) to ``total`` steps, keeping proportions."""
    old = cfg.total_steps
    steps = [max(1, round(p.steps * total / old)) if p.steps else 0 for p in cfg.phases]
    steps[-1] = max(1, total - sum(steps[:-1])) if total > sum(steps[:-1]) else steps[-1]
    phases = tuple(
        dataclasses.replace(p, steps=n, warmup=min(p.warmup, max(0, n // 5))) for p, n in zip(cfg.phases, steps)
    )
    return dataclasses.replace(cfg, phases=phases)


def ablation_config(config: Config, metric: str, interp: str, constraints: str) -> Config:
    """``config`` with its data term(s), skeleton interpolation and bone-constraint mode replaced
    (one method of the paper's Table 1 ablations).
    """
    cfg = with_metric(config, metric)
    cfg = dataclasses.replace(cfg, interp=interp)
    return dataclasses.replace(cfg, constraints=dataclasses.replace(cfg.constraints, mode=constraints))


def with_options(
    config: Config,
    *,
    seed: int | None = None,
    frames: int | None = None,
    metric: str | None = None,
    interp: str | None = None,
    constraints: str | None = None,
    optimizer: str | None = None,
    div_free: bool = False,
    weld: float | None = None,
    tissue_file: str | None = None,
    steps: int | None = None,
) -> Config:
    """``config`` with the options of ``ncflow match`` that are given (None: unchanged), validated;
    ``steps`` rescales the phases last (:func:`scale_steps`), ``div_free`` turns ``flow.skinning`` off.
    """
    cfg = config
    if seed is not None:
        cfg = dataclasses.replace(cfg, seed=seed)
    if frames is not None:
        cfg = dataclasses.replace(cfg, frames=frames)
    if metric:
        cfg = with_metric(cfg, metric)
    if interp:
        cfg = dataclasses.replace(cfg, interp=interp)
    if constraints:
        cfg = dataclasses.replace(cfg, constraints=dataclasses.replace(cfg.constraints, mode=constraints))
    if optimizer:
        cfg = dataclasses.replace(cfg, optimizer=optimizer)
    if div_free:
        cfg = dataclasses.replace(cfg, flow=dataclasses.replace(cfg.flow, div_free=True, skinning=False))
    if weld is not None:
        cfg = dataclasses.replace(cfg, repair=dataclasses.replace(cfg.repair, weld_tolerance=weld))
    if tissue_file:
        cfg = dataclasses.replace(cfg, tissue=dataclasses.replace(cfg.tissue, file=str(tissue_file)))
    if steps is not None:
        cfg = scale_steps(cfg, steps)
    return validate_config(cfg)
