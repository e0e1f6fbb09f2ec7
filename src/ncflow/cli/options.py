"""What the commands share: the matcher's options (``match``, ``demo``, ``batch``, ``benchmark``: preset,
configuration file, seed, steps, frames, ``--set`` overrides and the ablation switches), the cluster
options of ``batch`` and ``benchmark`` (``--jobs``, ``--scheduler``, ``--dashboard``), the checks
of integer and number options and the check of every output path before any work
(:func:`output_dir`, :func:`output_file`).
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

SEED_LIMIT = 2**32
MiB = 1 << 20


def check_int(value, option: str, lo: int | None = None, hi: int | None = None) -> int | None:
    """``value`` (None passes) as an int within [lo, hi]; else a one-line :class:`InputError` naming the option."""
    from ncflow.errors import InputError

    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int):
        raise InputError(f"{option} must be an integer (got {str(value)[:40]!r})")
    if lo is not None and value < lo:
        raise InputError(f"{option} must be at least {lo} (got {value})")
    if hi is not None and value > hi:
        raise InputError(f"{option} must be at most {hi} (got {value})")
    return value


def check_seed(value, option: str = "--seed", count: int = 1) -> int | None:
    """A seed (None passes): an integer with ``value + count - 1 < 2**32``."""
    return check_int(value, option, 0, SEED_LIMIT - max(1, count))


def gt_spec(values: list[str] | None, fmt: str | None):
    """The ground truth of ``--gt`` (one value, or two with ``--gt-format template``; None when not given)."""
    from ncflow.errors import InputError

    if values is None:
        if fmt is not None:
            raise InputError("--gt-format needs --gt")
        return None
    if len(values) == 2 and fmt == "template":
        return tuple(values)
    if len(values) != 1:
        raise InputError(f"--gt takes one value (two only with --gt-format template), got {len(values)}")
    return values[0]


def check_number(value, option: str, lo: float | None = None, hi: float | None = None, positive: bool = False):
    """``value`` (None passes) a finite number within [lo, hi] (above 0 with ``positive``)."""
    from ncflow.errors import InputError

    if value is None:
        return None
    if not math.isfinite(value):
        raise InputError(f"{option} must be finite (got {value})")
    if positive and not value > 0:
        raise InputError(f"{option} must be positive (got {value:g})")
    if lo is not None and value < lo:
        raise InputError(f"{option} must be at least {lo:g} (got {value:g})")
    if hi is not None and value > hi:
        raise InputError(f"{option} must be at most {hi:g} (got {value:g})")
    return value


def output_dir(
    path,
    *,
    overwrite: bool = False,
    reuse: bool = False,
    must_exist: bool = False,
    allow_cwd: bool = False,
    need_bytes: int = MiB,
    result: bool = False,
    option: str = "--out",
) -> Path:
    """Check a folder a command writes, before any work (:func:`ncflow.io.atomic.check_output_dir`).

    ``result``: the folder receives the output contract of ``ncflow match``; with ``overwrite``
    its contract names must hold what ncflow wrote there (:func:`ncflow.io.result.check_contract_entries`).
    Returns the resolved folder (symbolic links followed), which the command writes to.
    """
    from ncflow.io.atomic import check_output_dir

    real = check_output_dir(
        path,
        overwrite=overwrite,
        reuse=reuse,
        must_exist=must_exist,
        allow_cwd=allow_cwd,
        need_bytes=need_bytes,
        option=option,
    )
    if result and real.is_dir():
        from ncflow.io.result import check_contract_entries

        check_contract_entries(real, path)
    return real


def output_file(path, *, need_bytes: int = MiB, option: str = "output") -> Path:
    """Check a file a command writes, before any work (:func:`ncflow.io.atomic.check_output_file`)."""
    from ncflow.io.atomic import check_output_file

    return check_output_file(path, need_bytes=need_bytes, option=option)


def result_size_estimate(source, target, frames: int) -> int:
    """Rough bytes of a result folder: the frames and the animation are each about a source mesh per frame."""

    def size(p) -> int:
        try:
            return os.path.getsize(p) if isinstance(p, (str, os.PathLike)) else 0
        except OSError:
            return 0

    return 2 * (frames + 2) * size(source) + 2 * size(target) + MiB


def add_config_arguments(p: argparse.ArgumentParser) -> None:
    """Options shared by ``match``, ``demo``, ``batch`` and ``benchmark``: preset, config file and ablation switches."""
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
        "--weld",
        type=float,
        metavar="TOL",
        help="weld vertices closer than TOL x the mesh's size (bounding-box diagonal; at most 0.01) before "
        "matching; exactly coincident ones are always welded (repair.weld_tolerance)",
    )
    p.add_argument(
        "--tissue",
        metavar="FILE",
        help="reuse the exact soft tissue of an earlier run (the .npz its metrics.json names under tissue.cache_file)",
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override any setting, e.g. --set flow.width=96 --set constraints.eps=1e-4",
    )


def config_from_args(args: argparse.Namespace):
    """The effective configuration: preset → file → flags → --set overrides → --steps."""
    from ncflow.config import apply_overrides, load_config, with_options

    check_seed(args.seed)
    check_int(args.steps, "--steps", 1, 10**8)
    check_int(args.frames, "--frames", 2, 10**6)
    check_number(getattr(args, "weld", None), "--weld", lo=0.0, hi=0.01)
    cfg = load_config(args.config, args.preset)
    flags = {
        "seed": args.seed,
        "frames": args.frames,
        "metric": args.metric,
        "interp": args.interp,
        "constraints": args.constraints,
        "optimizer": args.optimizer,
        "div_free": args.div_free,
        "weld": getattr(args, "weld", None),
        "tissue_file": getattr(args, "tissue", None),
    }
    cfg = apply_overrides(with_options(cfg, **flags), args.set)
    return with_options(cfg, steps=args.steps)


def add_cluster_arguments(p: argparse.ArgumentParser) -> None:
    """Options shared by ``batch`` and ``benchmark``: where the pairs run (Dask) and how it reports."""
    p.add_argument(
        "--jobs",
        type=int,
        default=None,
        metavar="N",
        help="worker processes of the local Dask cluster, one pair each at a time (default: one per core, at "
        f"most {DEFAULT_MAX_JOBS}, the fastest measured); 0 runs the pairs in this process (no crash isolation; "
        "for debugging)",
    )
    p.add_argument(
        "--threads",
        type=int,
        default=None,
        metavar="T",
        help="JAX threads of each local worker (default 1; the same T gives byte-identical results whatever --jobs)",
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on an existing Dask cluster: its scheduler address (tcp://host:8786) or the JSON file of "
        "'dask scheduler --scheduler-file'; its workers need ncflow and see the same files (see docs/batch.md)",
    )
    p.add_argument("--dashboard", action="store_true", help="start the Dask dashboard and print its address")
    p.add_argument("--verbose", action="store_true", help="show Dask's log messages")


def cluster_from_args(args: argparse.Namespace) -> tuple[int, int, str | None]:
    """``(jobs, threads, scheduler)`` from ``--jobs``, ``--threads`` and ``--scheduler`` (checked: the local
    cluster's sizes are not given with ``--scheduler``, jobs in [0, 1024], threads in [1, 1024]).
    """
    from ncflow.errors import InputError

    check_int(args.jobs, "--jobs", 0, 1024)
    check_int(args.threads, "--threads", 1, 1024)
    scheduler = args.scheduler.strip() if args.scheduler else None
    if args.scheduler is not None and not scheduler:
        raise InputError("--scheduler needs an address, e.g. tcp://host:8786")
    if scheduler and (args.jobs is not None or args.threads is not None):
        raise InputError(
            "--jobs and --threads size the local cluster; with --scheduler the cluster's workers run the pairs"
        )
    jobs = default_jobs() if args.jobs is None else args.jobs
    return jobs, (1 if args.threads is None else args.threads), scheduler


DEFAULT_MAX_JOBS = 4
"""Default local workers at most: each holds its own JAX runtime and match (2–3 GB on a large pair)."""


def default_jobs() -> int:
    """One local worker per available core, at most :data:`DEFAULT_MAX_JOBS` (each with one JAX thread:
    8 pairs on 2 cores took 136 s with 2 × 1 against 214 s with 1 × 1 and 160 s with 1 × 2, and the
    results do not depend on the number of workers).
    """
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(cores, DEFAULT_MAX_JOBS))
