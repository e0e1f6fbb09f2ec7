"""``ncflow benchmark``: match and evaluate every pair of a pairs.csv (optionally the Table 1 ablations)."""

from __future__ import annotations

import argparse

from ncflow.cli.options import add_cluster_arguments, add_config_arguments, config_from_args


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "benchmark",
        help="match + evaluate every pair of a pairs.csv, resumable; writes report.md / report.json and curve plots",
        description=(
            "For every row of PAIRS.csv (columns name, source, target, skeleton, gt[, gt_format, dataset]; paths "
            "relative to the csv, as written by ncflow make-pairs) and every method, run ncflow match into "
            "OUT/runs/<method>/<pair>/ and ncflow evaluate on it; then write OUT/report.md, OUT/report.json and "
            "OUT/curves_<dataset>.png with mean +- std of the AUCs and mean errors, the largest bone violation and "
            "the time per pair, per method and dataset. The runs are tasks on Dask (a local cluster of --jobs "
            "worker processes, or an existing cluster with --scheduler, as for ncflow batch); a run that raises or "
            "whose worker dies is retried once, then reported as failed. Runs already evaluated are skipped, so an "
            "interrupted benchmark continues when the same command is run again. --ablations runs the paper's "
            "Table 1 rows (Var+SLERP+soft, Var+DQ, Var+DQ+CO, NC+DQ+CO, full) as variants of the configuration."
        ),
    )
    p.add_argument("pairs", metavar="PAIRS.csv", help="pairs file (ncflow make-pairs writes one)")
    p.add_argument("--out", required=True, metavar="REPORT_DIR", help="benchmark folder (created; reused to resume)")
    p.add_argument(
        "--ablations",
        action="store_true",
        help="run the Table 1 variants (sets the metric, interpolation and constraint mode itself)",
    )
    p.add_argument(
        "--geodesic-method",
        choices=["auto", "exact", "heat", "dijkstra"],
        default="auto",
        help="geodesic solver of the evaluation (default auto)",
    )
    p.add_argument("--no-plots", action="store_true", help="no per-run plots and no curve plots")
    add_cluster_arguments(p)
    add_config_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import sys

    from ncflow.cli.options import MiB, cluster_from_args, output_dir
    from ncflow.errors import InputError
    from ncflow.runs.benchmark import read_pairs_csv, run_benchmark

    jobs, threads, scheduler = cluster_from_args(args)
    if args.ablations and (args.metric or args.interp or args.constraints):
        raise InputError("--ablations sets --metric, --interp and --constraints itself; leave them out")
    read_pairs_csv(args.pairs)  # one-line error on a bad csv before the configuration is built
    cfg = config_from_args(args)
    # an existing --out is reused (resume); it is checked (and a symbolic link resolved) before any run
    out = output_dir(args.out, reuse=True, need_bytes=64 * MiB)
    res = run_benchmark(
        args.pairs,
        out,
        cfg,
        ablations=args.ablations,
        jobs=jobs,
        threads=threads,
        scheduler=scheduler,
        dashboard=args.dashboard,
        verbose=args.verbose,
        plots=not args.no_plots,
        geodesic_method=args.geodesic_method,
        log=lambda line: print(line, flush=True),
    )
    _print_summary(res.report)
    print(f"wrote {args.out}/report.md and report.json")
    if res.n_failed:
        print(
            f"ncflow benchmark: {res.n_failed} run(s) failed (listed in report.md); "
            "run the same command again to retry them",
            file=sys.stderr,
        )
        return 1
    return 0


def _print_summary(report: dict) -> None:
    labels = {m["id"]: m["label"] for m in report["methods"]}
    for e in report["summary"]:
        bone = e["max_bone_violation_ratio"]["max"]
        print(
            f"{labels[e['method']]:>14} {e['dataset']:<12} n={e['n']}: geodesic AUC {_mean_std(e['geodesic_auc'])}, "
            f"Chamfer AUC {_mean_std(e['chamfer_auc'])}, conformal AUC {_mean_std(e['conformal_auc'])}, "
            f"bone g/eps max {'n/a' if bone is None else f'{bone:.3g}'}"
        )


def _mean_std(v: dict) -> str:
    if v["mean"] is None:
        return "n/a"
    return f"{v['mean']:.3f}" + ("" if v["std"] is None else f"±{v['std']:.3f}")
