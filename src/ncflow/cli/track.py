"""``ncflow track``: one source with its skeleton registered to every frame of a sequence, as one animation."""

from __future__ import annotations

import argparse

from ncflow.cli.options import add_config_arguments, config_from_args


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "track",
        help="register a source with its skeleton to every frame of a sequence; write maps, registered meshes, "
        "an animated GLB and a BVH",
        description=(
            "Match the source to every frame of a sequence: the first frame as ncflow match does (placement, pose "
            "search), every later frame starting from the previous one and trained briefly, each map anchored to the "
            "source (no drift); a frame whose warm start is lost (its data term far above the recent frames') is "
            "searched again. Writes into --out, frame by frame: maps/STEM.npz (face, bary of the source point of every "
            "frame vertex), registered/STEM.ply (the source's connectivity on the frame), records/STEM.json, "
            "state/STEM.eqx; then skeleton_frames.json, animation.glb (the source skinned to the skeleton, its motion "
            "as a skin animation, exact per-frame corrections as morph targets), animation.bvh and metrics.json. "
            "A run interrupted, or run again with the same inputs and settings, resumes where it stopped."
        ),
    )
    p.add_argument("source", help="source mesh (OBJ/PLY/OFF/STL/GLB)")
    p.add_argument(
        "frame_files",
        metavar="FRAMES",
        nargs="+",
        help="the frames: a folder (its mesh files in natural order), a quoted glob pattern, or the files in order",
    )
    p.add_argument(
        "--skeleton",
        help="skeleton of the source (TGF, JSON, or glTF/GLB skin); without it one is suggested from the source",
    )
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--warm-steps", type=int, default=None, help="training steps of a warm frame (default 50)")
    p.add_argument(
        "--lost-ratio",
        type=float,
        default=None,
        help="a warm frame whose final data term exceeds this many times the median of the last 5 good frames' is "
        "searched again (default 3)",
    )
    p.add_argument("--fps", type=float, default=None, help="frames per second of the animation (default 24)")
    p.add_argument(
        "--overwrite", action="store_true", help="start again in a folder that holds a track (instead of resuming)"
    )
    p.add_argument("--quiet", action="store_true", help="no progress display")
    add_config_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ncflow.track import track_sequence
    from ncflow.track.sequence import DEFAULT_FPS, LOST_RATIO, WARM_STEPS

    cfg = config_from_args(args)
    frames = args.frame_files[0] if len(args.frame_files) == 1 else args.frame_files
    report = track_sequence(
        args.source,
        frames,
        args.skeleton,
        args.out,
        cfg,
        warm_steps=WARM_STEPS if args.warm_steps is None else args.warm_steps,
        lost_ratio=LOST_RATIO if args.lost_ratio is None else args.lost_ratio,
        fps=DEFAULT_FPS if args.fps is None else args.fps,
        overwrite=args.overwrite,
        quiet=args.quiet,
    )
    if not args.quiet:
        m = report.metrics
        print(f"wrote {args.out}")
        print(
            f"  {report.n_ok} of {report.n_frames} frames registered ({report.n_resumed} read back, "
            f"{report.n_fell_back} searched again, {report.n_failed} failed) in {report.seconds:.1f} s; "
            f"largest bone violation g/eps = {m['max_violation_ratio']:.3g}"
        )
    return 0 if report.n_failed == 0 else 1
