"""``ncflow view``: one self-contained offline HTML page showing a result of ``ncflow match``."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "view",
        help="write one offline HTML page showing a match result: source, animation, target, skeleton, colours",
        description=(
            "Write one self-contained HTML file (no network, no server; open it in any current browser) that "
            "shows the source, the flowed source animated with a timeline slider and play/pause, and the target, "
            "side by side or overlaid; the skeleton on or off; colours carried through the correspondence "
            "(position colours or a checker); with --gt, the target coloured by its geodesic error on the "
            "tau_max = 0.20 scale of docs/evaluation.md, with a colour bar. Meshes above --max-vertices are shown "
            "decimated. The target is read from RESULT_DIR/target.ply (or --target for older results)."
        ),
    )
    p.add_argument(
        "result_dir",
        metavar="RESULT_DIR",
        help="folder written by ncflow match, or by ncflow track (its registered frames are played)",
    )
    p.add_argument("--out", metavar="FILE", help="the HTML file (default RESULT_DIR/view.html)")
    p.add_argument(
        "--gt",
        nargs="+",
        metavar="GT",
        help="ground truth for the error map: 'identity', a .vts/.txt/.npy/.npz file, or two .vts files with "
        "--gt-format template",
    )
    p.add_argument(
        "--gt-format",
        choices=["identity", "vts", "index", "npz", "template"],
        help="ground-truth format (default: from the suffix)",
    )
    p.add_argument("--target", metavar="MESH", help="the target mesh (default RESULT_DIR/target.ply)")
    p.add_argument(
        "--max-vertices",
        type=int,
        metavar="N",
        help="show source and target decimated to about N vertices when larger (default 60000)",
    )
    p.add_argument("--max-frames", type=int, metavar="N", help="embed at most N frames, evenly chosen (default 100)")
    p.add_argument("--title", help="title shown in the page (default: the folder's name)")
    p.add_argument(
        "--overwrite", action="store_true", help="replace an existing --out file that ncflow view did not write"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import os
    from pathlib import Path

    from ncflow.cli.options import MiB, check_int, gt_spec, output_file
    from ncflow.errors import InputError
    from ncflow.track.folder import is_track_folder, track_animation, track_as_result
    from ncflow.view.page import (
        DEFAULT_MAX_DISPLAY_FRAMES,
        DEFAULT_MAX_DISPLAY_VERTICES,
        check_view_output,
        write_page,
        write_view,
    )

    check_int(args.max_vertices, "--max-vertices", 100, 10**7)
    check_int(args.max_frames, "--max-frames", 2, 10**5)
    gt = gt_spec(args.gt, args.gt_format)
    out = Path(args.result_dir) / "view.html" if args.out is None else Path(args.out)
    output_file(out, need_bytes=16 * MiB, option="--out")
    check_view_output(out, args.overwrite)
    if is_track_folder(args.result_dir):  # a sequence of ncflow track: its registered frames, played
        if args.gt or args.target:
            raise InputError("--gt and --target are for a match result, not a track folder", args.result_dir)
        result = track_as_result(args.result_dir)
        path = write_page(
            result,
            out,
            animation=track_animation(args.result_dir, result),
            max_display_vertices=args.max_vertices or DEFAULT_MAX_DISPLAY_VERTICES,
            max_display_frames=args.max_frames or DEFAULT_MAX_DISPLAY_FRAMES,
            title=args.title if args.title is not None else Path(args.result_dir).resolve().name,
        )
        print(f"wrote {path} ({os.path.getsize(path) / 2**20:.1f} MiB); open it in a browser (works offline)")
        return 0
    path = write_view(
        args.result_dir,
        out,
        gt=gt,
        gt_format=args.gt_format,
        target=args.target,
        max_display_vertices=args.max_vertices or DEFAULT_MAX_DISPLAY_VERTICES,
        max_display_frames=args.max_frames or DEFAULT_MAX_DISPLAY_FRAMES,
        title=args.title,
        overwrite=args.overwrite,
    )
    print(f"wrote {path} ({os.path.getsize(path) / 2**20:.1f} MiB); open it in a browser (works offline)")
    return 0
