"""Options shared by the commands that run the matcher (``match``, ``demo``, ``benchmark``): preset,
configuration file, seed, steps, frames, ``--set`` overrides and the ablation switches.
"""

from __future__ import annotations

import argparse


def add_config_arguments(p: argparse.ArgumentParser) -> None:
    """Options shared by ``match``, ``demo`` and ``benchmark``: preset, config file and ablation switches."""
    p.add_argument("--preset", default=None, help="configuration preset: fast (default) or paper")
    p.add_argument("--config", metavar="FILE", help="TOML/YAML configuration file (overrides the preset)")
    p.add_argument("--seed", type=int, help="random seed (default 0)")
    p.add_argument("--steps", type=int, help="total optimisation steps (phases scaled proportionally)")
    p.add_argument("--frames", type=int, help="number of interpolation frames written (default 20)")
    p.add_argument(
        "--metric",
        choices=["varifold", "normal-cycles", "varifold+normal-cycles"],
        help="data term(s): ablation switch (default varifold then normal-cycles)",
    )
    p.add_argument("--interp", choices=["sclerp", "slerp"], help="skeleton interpolation (default sclerp)")
    p.add_argument("--constraints", choices=["mdmm", "soft"], help="bone constraints: MDMM (default) or soft penalty")
    p.add_argument("--optimizer", choices=["adabelief", "vectoradam"], help="optimiser (default adabelief)")
    p.add_argument(
        "--div-free",
        action="store_true",
        help="divergence-free (volume-preserving) flow field (turns flow.skinning off)",
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override any setting, e.g. --set flow.width=96 --set constraints.eps=1e-4",
    )


def config_from_args(args: argparse.Namespace):
    """The effective configuration: preset → file → flags → --set overrides."""
    import dataclasses

    from ncflow.config import apply_overrides, load_config, scale_steps, validate_config, with_metric
    from ncflow.errors import InputError

    cfg = load_config(args.config, args.preset)
    if args.seed is not None:
        cfg = dataclasses.replace(cfg, seed=args.seed)
    if args.frames is not None:
        cfg = dataclasses.replace(cfg, frames=args.frames)
    if args.metric:
        cfg = with_metric(cfg, args.metric)
    if args.interp:
        cfg = dataclasses.replace(cfg, interp=args.interp)
    if args.constraints:
        cfg = dataclasses.replace(cfg, constraints=dataclasses.replace(cfg.constraints, mode=args.constraints))
    if args.optimizer:
        cfg = dataclasses.replace(cfg, optimizer=args.optimizer)
    if args.div_free:
        cfg = dataclasses.replace(cfg, flow=dataclasses.replace(cfg.flow, div_free=True, skinning=False))
    cfg = apply_overrides(cfg, args.set)
    if args.steps is not None:
        if args.steps < 1:
            raise InputError(f"--steps must be at least 1 (got {args.steps})")
        cfg = scale_steps(cfg, args.steps)
    return validate_config(cfg)
