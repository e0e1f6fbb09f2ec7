"""``ncflow evaluate``: score a result folder of ``ncflow match`` against ground truth; JSON + plots."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "evaluate",
        help="score a match result against ground truth (geodesic, Chamfer, conformal, bones); "
        "writes evaluation.json and plots",
        description=(
            "Read the output contract in RESULT_DIR, the source and target meshes and the ground truth, compute "
            "the metrics of docs/evaluation.md (geodesic error of map_tgt_to_src, Chamfer distance of "
            "deformed_source to the target, conformal distortion, volume change and inverted triangles over all "
            "frames, bone-constraint violation from metrics.json) and write into RESULT_DIR: evaluation.json "
            "(strict JSON; non-finite values as null), eval_cumulative.png (cumulative curves with AUC), "
            "eval_geodesic_error.png (the target coloured by its error) and eval_color_transfer.png (a colour "
            "function of the source carried to the target by the predicted map and by the ground truth)."
        ),
    )
    p.add_argument("result_dir", metavar="RESULT_DIR", help="folder written by ncflow match")
    p.add_argument("--source", required=True, help="the source mesh given to ncflow match")
    p.add_argument("--target", required=True, help="the target mesh given to ncflow match")
    p.add_argument(
        "--gt",
        required=True,
        nargs="+",
        metavar="GT",
        help="ground truth: 'identity', a .vts/.txt/.npy/.npz file, or two .vts files with --gt-format template",
    )
    p.add_argument(
        "--gt-format",
        choices=["identity", "vts", "index", "npz", "template"],
        help="ground-truth format (default: from the suffix)",
    )
    p.add_argument(
        "--geodesic-method",
        choices=["auto", "exact", "heat", "dijkstra"],
        default="auto",
        help="geodesic solver (default auto: exact polyhedral geodesics up to 0.25, heat method beyond)",
    )
    p.add_argument("--no-plots", action="store_true", help="write evaluation.json only")
    p.add_argument("--json", action="store_true", help="print one JSON object (the content of evaluation.json)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import json

    from ncflow.cli.options import MiB, gt_spec, output_dir
    from ncflow.evaluate.score import EVALUATION_FILE, evaluate_result, evaluation_text, write_evaluation

    # RESULT_DIR receives evaluation.json and the plots: checked before the evaluation runs (it may
    # be the current folder: evaluate adds files, it replaces nothing else)
    output_dir(args.result_dir, must_exist=True, allow_cwd=True, need_bytes=8 * MiB, option="RESULT_DIR")
    ev = evaluate_result(
        args.result_dir,
        args.source,
        args.target,
        gt_spec(args.gt, args.gt_format),
        args.gt_format,
        geodesic_method=args.geodesic_method,
    )
    record = write_evaluation(ev, plots=not args.no_plots)
    if args.json:
        print(json.dumps(record, allow_nan=False))
        return 0
    print(evaluation_text(record))
    files = [EVALUATION_FILE] + list(record["plots"].values())
    print(f"wrote {', '.join(files)} into {args.result_dir}")
    return 0
