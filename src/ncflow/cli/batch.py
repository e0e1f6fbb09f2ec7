"""``ncflow batch``: match every pair of a csv (no ground truth needed) on a local or existing Dask cluster."""

from __future__ import annotations

import argparse

from ncflow.cli.options import add_cluster_arguments, add_config_arguments


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "batch",
        help="match every pair of a csv into OUT/<name>/ on Dask (local worker processes or a cluster); resumable",
        description=(
            "For every row of PAIRS.csv (columns name, source, target, skeleton; other columns ignored; paths "
            "relative to the csv) run ncflow match into OUT/<name>/ (the output contract plus run_manifest.json). "
            "The pairs are tasks on Dask: a local cluster of --jobs worker processes, or an existing cluster "
            "(--scheduler). Each distinct source is tetrahedralised once, before the pairs fan out. A pair that "
            "raises or whose worker dies is retried once, then reported as failed while the others go on. "
            "OUT/batch.json lists every pair (ok, skipped, failed, interrupted) with its attempts, time and error; "
            "it is written also when pairs fail or on Ctrl-C. Running the same command again skips the pairs "
            "finished with the same inputs (files, configuration, seed, ncflow version) and retries the others."
        ),
    )
    p.add_argument("pairs", metavar="PAIRS.csv", help="pairs file: name,source,target,skeleton[,...]")
    p.add_argument("--out", required=True, metavar="DIR", help="batch folder (created; reused to resume)")
    add_cluster_arguments(p)
    add_config_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import sys

    from ncflow.cli.options import MiB, cluster_from_args, config_from_args, output_dir
    from ncflow.runs.batch import read_pairs_csv, run_batch

    jobs, threads, scheduler = cluster_from_args(args)
    pairs = read_pairs_csv(args.pairs, ground_truth=False)  # one-line error on a bad csv before anything else
    cfg = config_from_args(args)
    # an existing --out is reused (resume); it is checked (and a symbolic link resolved) before any run
    out = output_dir(args.out, reuse=True, need_bytes=len(pairs) * 4 * MiB)
    res = run_batch(
        args.pairs,
        out,
        cfg,
        jobs=jobs,
        threads=threads,
        scheduler=scheduler,
        dashboard=args.dashboard,
        verbose=args.verbose,
        log=lambda line: print(line, flush=True),
    )
    c = res.summary["counts"]
    print(
        f"{c['ok']} matched, {c['skipped']} already done, {c['failed']} failed"
        + (f", {c['interrupted']} not run" if c["interrupted"] else "")
        + f"; wrote {args.out}/batch.json"
    )
    if res.n_failed:
        print(
            f"ncflow batch: {res.n_failed} pair(s) failed (listed in batch.json); run the same command again to "
            "retry them",
            file=sys.stderr,
        )
        return 1
    return 0
