"""``ncflow match``: correspondence-free matching and interpolation of two poses."""

from __future__ import annotations

import argparse

from ncflow.cli.options import add_config_arguments, config_from_args, output_dir, result_size_estimate


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "match",
        help="match a source mesh with a skeleton to a target mesh; write correspondence, animation, target skeleton",
        description=(
            "Correspondence-free matching and interpolation of two poses of one character. Writes into "
            "--out: deformed_source.ply, p2p_src_to_tgt.txt, p2p_tgt_to_src.txt, map_tgt_to_src.npz, "
            "frames/, animation.glb, skeleton_target.tgf, skeleton_frames.json, metrics.json (and "
            "skeleton_source.tgf when the source's skeleton was suggested)."
        ),
    )
    p.add_argument("source", help="source mesh (OBJ/PLY/OFF/STL/GLB)")
    p.add_argument("target", help="target mesh (any triangulation and resolution)")
    p.add_argument(
        "--skeleton",
        help="skeleton of the source (TGF, JSON, or glTF/GLB skin); without it one is suggested from the source "
        "(as ncflow skeleton suggest), named in a warning and written as skeleton_source.tgf",
    )
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--overwrite", action="store_true", help="replace the contract files of an existing non-empty --out")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    add_config_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ncflow.matcher.steps import Matcher

    cfg = config_from_args(args)
    # --out checked (and a symbolic link resolved) before any work
    out = output_dir(
        args.out,
        overwrite=args.overwrite,
        result=True,
        need_bytes=result_size_estimate(args.source, args.target, cfg.frames),
    )
    result = Matcher(args.source, args.target, args.skeleton, cfg, quiet=args.quiet).run()
    result.save(out, overwrite=args.overwrite, shown=args.out)
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
