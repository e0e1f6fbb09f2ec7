"""``ncflow match``: correspondence-free matching and interpolation of two poses."""

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

    from ncflow.config import apply_overrides, load_config, validate_config, with_metric
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


def scale_steps(cfg, total: int):
    """Rescale the phases' step counts (and warm-ups) to ``total`` steps, keeping proportions."""
    import dataclasses

    old = cfg.total_steps
    steps = [max(1, round(p.steps * total / old)) if p.steps else 0 for p in cfg.phases]
    steps[-1] = max(1, total - sum(steps[:-1])) if total > sum(steps[:-1]) else steps[-1]
    phases = tuple(
        dataclasses.replace(p, steps=n, warmup=min(p.warmup, max(0, n // 5))) for p, n in zip(cfg.phases, steps)
    )
    return dataclasses.replace(cfg, phases=phases)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "match",
        help="match a source mesh with a skeleton to a target mesh; write correspondence, animation, target skeleton",
        description=(
            "Correspondence-free matching and interpolation of two poses of one character. Writes into "
            "--out: deformed_source.ply, p2p_src_to_tgt.txt, p2p_tgt_to_src.txt, map_tgt_to_src.npz, "
            "frames/, animation.glb, skeleton_target.tgf, skeleton_frames.json, metrics.json."
        ),
    )
    p.add_argument("source", help="source mesh (OBJ/PLY/OFF/STL/GLB)")
    p.add_argument("target", help="target mesh (any triangulation and resolution)")
    p.add_argument("--skeleton", required=True, help="skeleton of the source (TGF, JSON, or glTF/GLB skin)")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--overwrite", action="store_true", help="replace the contract files of an existing non-empty --out")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    add_config_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import os

    from ncflow.errors import InputError
    from ncflow.matcher import Matcher

    if os.path.isdir(args.out) and os.listdir(args.out) and not args.overwrite:
        raise InputError("output directory exists and is not empty (use --overwrite)", args.out)
    cfg = config_from_args(args)
    result = Matcher(args.source, args.target, args.skeleton, cfg, quiet=args.quiet).run()
    result.save(args.out, overwrite=args.overwrite)
    if not args.quiet:
        c = result.metrics["constraints"]
        t = result.metrics["timings"]
        print(f"wrote {args.out}")
        print(
            f"  {cfg.total_steps} steps in {t['train']:.1f} s ({t['per_step']:.3f} s/step), total {t['total']:.1f} s; "
            f"largest bone violation g/eps = {c['max_violation_ratio']:.3g} "
            f"({'all bones within tolerance' if c['all_satisfied'] else 'some bones above tolerance'})"
        )
    return 0
