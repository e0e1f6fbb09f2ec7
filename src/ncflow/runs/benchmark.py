"""Benchmark runner: match and evaluate every pair of a ``pairs.csv`` (per method), then report.

Input: a csv with columns ``name, source, target, skeleton, gt`` and optionally ``gt_format`` and
``dataset`` (the file :func:`ncflow.synthetic.pairs.write_pairs` / ``ncflow make-pairs`` writes);
paths are relative to the csv. ``gt`` is ``identity``, a ground-truth file, or two template
``.vts`` files separated by ``;`` (with ``gt_format`` ``template``). Every row is checked (columns,
files, names) before anything runs (:func:`ncflow.runs.pairs_csv.read_pairs_csv`).

Layout of ``OUT``::

    runs/<method>/config.json          the method's configuration (a later run must match it)
    runs/<method>/<pair>/              the output contract of ncflow match, plus
    runs/<method>/<pair>/evaluation.json and eval_*.png   (ncflow evaluate)
    runs/<method>/<pair>/run_manifest.json   what the run was made from (inputs' hashes, versions)
    tissue/<key>.npz                   the soft tissue of each distinct source, shared by its runs
    report.json, report.md, curves_<dataset>.png

Execution: every run (method × pair) is a task on Dask, through the engine of ``ncflow batch``
(:func:`ncflow.runs.batch.run_tasks`): a local cluster of ``jobs`` worker processes, or an
existing cluster (``scheduler``). A run that raises or whose worker process dies is retried once,
then recorded as failed in the report while the others go on; running the command again retries
it. Each distinct source is tetrahedralised once before the runs fan out
(:func:`ncflow.runs.batch.share_tissues`), so the methods and ``--jobs`` see the same tissue.

Manifests: every run folder holds ``run_manifest.json`` (:func:`run_manifest`): the ``match`` part
(:func:`ncflow.runs.batch.match_manifest`: SHA-256 of source, target and skeleton, the ncflow
version and the method's configuration as far as it changes a result), written after the match,
and the ``evaluation`` part (SHA-256 of the ground truth, its format, the geodesic method), added
after the evaluation.

Resuming: a run is skipped only when its manifest matches the current one in full and its
``evaluation.json`` exists; a run whose manifest matches in its ``match`` part and whose result is
complete (``metrics.json`` present; results are written atomically) is only evaluated; anything
else (no manifest, an input file changed, another ncflow version or configuration) is matched and
evaluated again (its earlier evaluation removed first). So an interrupted benchmark continues
where it stopped when the same command is run again, and never reuses a run of other inputs. The
report is always written at the end, also after Ctrl-C (runs not done are listed as failed,
``interrupted``), and without the curve plots if drawing them fails.

Methods: one (``ncflow``: the given configuration) or, with ``ablations=True``, the paper's Table 1
rows as configuration variants of the given configuration (:data:`ABLATIONS`).
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from collections.abc import Callable
from pathlib import Path

from ncflow import __version__
from ncflow.config import RESULT_NEUTRAL, Config, ablation_config, config_to_dict
from ncflow.errors import InputError
from ncflow.evaluate.aggregate import run_row
from ncflow.evaluate.report import write_benchmark_report
from ncflow.evaluate.score import EVALUATION_FILE, EVALUATION_PLOTS, evaluate_result, write_evaluation
from ncflow.io.atomic import atomic_write_text
from ncflow.matcher.steps import Matcher
from ncflow.runs.batch import MANIFEST_FILE, file_sha256, match_manifest, read_manifest, share_tissues
from ncflow.runs.cluster import open_client
from ncflow.runs.engine import Outcome, Task, run_tasks
from ncflow.runs.pairs_csv import GT_COLUMNS, OPTIONAL_COLUMNS, PAIR_COLUMNS, PairSpec, read_pairs_csv

__all__ = [
    "ABLATIONS",
    "MANIFEST_FILE",
    "BenchmarkResult",
    "Method",
    "PairSpec",
    "RunTask",
    "benchmark_methods",
    "file_sha256",
    "read_pairs_csv",
    "run_benchmark",
    "run_manifest",
    "run_task",
    "share_tissues",
]

REQUIRED_COLUMNS = PAIR_COLUMNS + GT_COLUMNS
assert OPTIONAL_COLUMNS == ("gt_format", "dataset")

# id, label, description, metric, interp, constraints (paper Table 1 rows)
ABLATIONS = (
    (
        "var-slerp-soft",
        "Var+SLERP+soft",
        "ARC-Flow style: Varifold only, world-space SLERP, soft bone constraints",
        "varifold",
        "slerp",
        "soft",
    ),
    ("var-dq", "Var+DQ", "Varifold only, dual-quaternion ScLERP, soft bone constraints", "varifold", "sclerp", "soft"),
    ("var-dq-co", "Var+DQ+CO", "Varifold only, ScLERP, MDMM-constrained bones", "varifold", "sclerp", "mdmm"),
    ("nc-dq-co", "NC+DQ+CO", "Normal Cycles only, ScLERP, MDMM-constrained bones", "normal-cycles", "sclerp", "mdmm"),
    (
        "full",
        "full",
        "Varifold then Normal Cycles, ScLERP, MDMM (the default)",
        "varifold+normal-cycles",
        "sclerp",
        "mdmm",
    ),
)
# ----------------------------------------------------------------------------------------------
# Methods


@dataclasses.dataclass(frozen=True)
class Method:
    """A configuration to benchmark: ``id`` names its folder, ``label`` its table row."""

    id: str
    label: str
    description: str
    config: Config

    def to_dict(self) -> dict:
        """The method as written to ``runs/<id>/config.json``: ``id``, ``label``, ``description``, ``config``."""
        return {
            "id": self.id,
            "label": self.label,
            "description": self.description,
            "config": config_to_dict(self.config),
        }


def benchmark_methods(config: Config, ablations: bool = False) -> list[Method]:
    """The methods of a benchmark: the given configuration, or the Table 1 variants of it."""
    if not ablations:
        return [Method("ncflow", "ncflow", "the given configuration", config)]
    return [Method(i, label, desc, ablation_config(config, m, it, c)) for i, label, desc, m, it, c in ABLATIONS]


# ----------------------------------------------------------------------------------------------
# One run


@dataclasses.dataclass(frozen=True)
class RunTask:
    """Match (unless done) and evaluate one pair with one method, into ``run_dir``."""

    method: str
    pair: PairSpec
    config: Config
    run_dir: str
    plots: bool = True
    geodesic_method: str = "auto"


def _evaluation_done(run_dir: Path) -> bool:
    path = run_dir / EVALUATION_FILE
    if not path.is_file():
        return False
    try:
        return "headline" in json.loads(path.read_text())
    except (OSError, ValueError):
        return False


def run_manifest(task: RunTask) -> dict:
    """What a run is made from: ``{"format": 1, "match": {...}, "evaluation": {...}}``.

    ``match``: :func:`ncflow.runs.batch.match_manifest` (SHA-256 of source, target and skeleton,
    the ncflow version, the method's configuration). ``evaluation``: SHA-256 of the ground-truth
    file(s) (``identity`` has none), the ground-truth format and the geodesic method (plus the match
    part's inputs, through the run). Equal manifests mean a finished run can be reused.
    """
    p = task.pair
    gts = [] if p.gt in (None, "identity") else ([p.gt] if isinstance(p.gt, str) else list(p.gt))
    return {
        "format": 1,
        "match": match_manifest(p.source, p.target, p.skeleton, task.config),
        "evaluation": {
            "ncflow_version": __version__,
            "gt": "identity" if not gts else [file_sha256(g) for g in gts],
            "gt_format": p.gt_format,
            "geodesic_method": task.geodesic_method,
        },
    }


def _write_manifest(run_dir: Path, manifest: dict, evaluated: bool) -> None:
    record = dict(manifest, evaluation=manifest["evaluation"] if evaluated else None)
    atomic_write_text(run_dir / MANIFEST_FILE, json.dumps(record, indent=1) + "\n")


def _drop_evaluation(run_dir: Path) -> None:
    """Remove the evaluation files ncflow wrote for an earlier result of this run (names it owns)."""
    for name in (EVALUATION_FILE, *EVALUATION_PLOTS.values()):
        path = run_dir / name
        if path.is_file() and not path.is_symlink():
            path.unlink()


def _match(task: RunTask) -> None:
    """Run the matcher and write the output contract (atomically) into the run folder."""
    p = task.pair
    result = Matcher(p.source, p.target, p.skeleton, task.config, quiet=True).run()
    result.save(task.run_dir, overwrite=True)


def _evaluate(task: RunTask) -> dict:
    """Evaluate the run folder against the pair's ground truth; writes evaluation.json (last) and plots."""
    p = task.pair
    ev = evaluate_result(task.run_dir, p.source, p.target, p.gt, p.gt_format, geodesic_method=task.geodesic_method)
    return write_evaluation(
        ev, plots=task.plots, extra={"benchmark": {"method": task.method, "pair": p.name, "dataset": p.dataset}}
    )


def run_task(task: RunTask) -> dict:
    """Do what is left of one run (on a worker); a failure raises (the engine records and retries it).

    Returns:
        ``{"method", "pair", "status", "seconds", "error"}`` with status ``"skipped"`` (already
        evaluated, same manifest), ``"evaluated"`` (result of the same inputs found, evaluation
        added) or ``"matched"`` (matched and evaluated); ``error`` None.
    """
    t0 = time.perf_counter()
    run_dir = Path(task.run_dir)
    out = {"method": task.method, "pair": task.pair.name, "status": "skipped", "seconds": 0.0, "error": None}
    try:
        manifest = run_manifest(task)
        old = read_manifest(run_dir) or {}
        same_match = old.get("match") == manifest["match"] and (run_dir / "metrics.json").is_file()
        if same_match and old.get("evaluation") == manifest["evaluation"] and _evaluation_done(run_dir):
            return out
        if same_match:
            out["status"] = "evaluated"
        else:
            if run_dir.is_dir():
                _drop_evaluation(run_dir)  # it scored an earlier result (or other inputs)
                (run_dir / MANIFEST_FILE).unlink(missing_ok=True)
            _match(task)
            _write_manifest(run_dir, manifest, evaluated=False)
            out["status"] = "matched"
        _evaluate(task)
        _write_manifest(run_dir, manifest, evaluated=True)
    finally:
        # every pair compiles its own executables (other shapes); kept for the whole process they
        # exhausted the address-space mappings after ~14 pairs (LLVM "Unable to allocate section memory")
        import jax

        jax.clear_caches()
    out["seconds"] = time.perf_counter() - t0
    return out


def _crashed(task: RunTask, why: str, attempts: int = 1) -> dict:
    return {
        "method": task.method,
        "pair": task.pair.name,
        "status": "failed",
        "seconds": 0.0,
        "error": why,
        "attempts": attempts,
    }


# ----------------------------------------------------------------------------------------------
# The benchmark


@dataclasses.dataclass
class BenchmarkResult:
    """``report``: the content of report.json; ``outcomes``: what this invocation did per run."""

    report: dict
    outcomes: list[dict]

    @property
    def n_failed(self) -> int:
        """Number of runs that failed."""
        return sum(o["status"] == "failed" for o in self.outcomes)


def _comparable(config: dict | None) -> dict | None:
    """A method configuration without the settings that never change a result (:data:`ncflow.config.RESULT_NEUTRAL`)."""
    if not isinstance(config, dict):
        return None
    return {k: v for k, v in config.items() if k not in RESULT_NEUTRAL}


def _check_method_configs(out: Path, methods: list[Method]) -> None:
    """Refuse to resume runs made with another configuration (before anything runs)."""
    for m in methods:
        path = out / "runs" / m.id / "config.json"
        if not path.is_file():
            continue
        try:
            old = json.loads(path.read_text()).get("config")
        except (OSError, ValueError, AttributeError):
            raise InputError("unreadable method configuration; remove it or use another --out", path) from None
        if _comparable(old) != _comparable(json.loads(json.dumps(config_to_dict(m.config)))):
            raise InputError(
                f"the runs of method {m.id!r} were made with another configuration; use another --out "
                "(or remove that method's folder) to run with this one",
                path,
            )


def _write_method_configs(out: Path, methods: list[Method]) -> None:
    for m in methods:
        d = out / "runs" / m.id
        d.mkdir(parents=True, exist_ok=True)
        if not (d / "config.json").is_file():
            atomic_write_text(d / "config.json", json.dumps(m.to_dict(), indent=1) + "\n")


def _task_key(task: RunTask) -> str:
    return f"{task.method}/{task.pair.name}"


def _execute(
    tasks: list[RunTask],
    jobs: int,
    log: Callable[[str], None],
    describe: Callable[[dict], str],
    worker: Callable[[RunTask], dict] | None = None,
    *,
    client=None,
    outcomes: list[dict] | None = None,
    progress: bool = True,
    throttle: bool = True,
) -> list[dict]:
    """Run the tasks on Dask (``client``, else a local cluster of ``jobs`` worker processes); log each
    as it ends. A run that raises or whose worker process dies is retried once, then recorded as
    failed (:func:`ncflow.runs.batch.run_tasks`); the others go on.

    ``outcomes``: a list the outcome dicts are appended to as they come (kept on Ctrl-C).
    """
    worker = run_task if worker is None else worker
    outcomes = [] if outcomes is None else outcomes
    by_key = {_task_key(t): t for t in tasks}

    def done(o: Outcome) -> None:
        t = by_key[o.key]
        if o.status == "ok":
            d = dict(o.value, attempts=o.attempts)
        else:
            d = _crashed(t, o.error, o.attempts)
        outcomes.append(d)
        log(f"[{len(outcomes)}/{len(tasks)}] {describe(d)}")

    run = [Task(_task_key(t), worker, t) for t in tasks]
    if client is not None:
        run_tasks(client, run, on_done=done, progress=progress, unit="run", throttle=throttle)
    else:
        with open_client(jobs, log=log) as (local, _):
            run_tasks(local, run, on_done=done, progress=progress, unit="run")
    return outcomes


def _describe(o: dict, rows: dict) -> str:
    head = f"{o['method']}/{o['pair']}: {o['status']}"
    if o["status"] == "failed":
        return f"{head} ({o['error']})"
    row = rows.get((o["method"], o["pair"]))
    if row is None:
        return head
    return (
        f"{head} in {o['seconds']:.1f} s; geodesic AUC {row['geodesic_auc']:.3f}, "
        f"Chamfer AUC {row['chamfer_auc']:.3f}, "
        f"conformal AUC {row['conformal_auc']:.3f}, bone g/eps {row['max_bone_violation_ratio']:.3g}"
    )


def _collect_rows(tasks: list[RunTask], outcomes: dict) -> list[dict]:
    rows = []
    for t in tasks:
        run_dir = Path(t.run_dir)
        base = {
            "method": t.method,
            "pair": t.pair.name,
            "dataset": t.pair.dataset,
            "dir": str(Path("runs") / t.method / t.pair.name),
        }
        o = outcomes.get((t.method, t.pair.name), {})
        if o and o.get("status") != "failed" and _evaluation_done(run_dir):
            rows.append(
                {**base, "status": "ok", "error": None, **run_row(json.loads((run_dir / EVALUATION_FILE).read_text()))}
            )
        else:
            rows.append({**base, "status": "failed", "error": o.get("error") or "not run (interrupted)"})
    return rows


def run_benchmark(
    pairs_csv: str | os.PathLike,
    out_dir: str | os.PathLike,
    config: Config,
    *,
    ablations: bool = False,
    jobs: int = 1,
    threads: int = 1,
    scheduler: str | None = None,
    dashboard: bool = False,
    verbose: bool = False,
    progress: bool = True,
    plots: bool = True,
    geodesic_method: str = "auto",
    log: Callable[[str], None] = print,
) -> BenchmarkResult:
    """Match and evaluate every pair (per method) on Dask, resuming finished runs, and write the report.

    Args:
        pairs_csv: the pairs file (see the module docstring).
        out_dir: the benchmark folder (created).
        config: the configuration (the ``ncflow`` method, or the base of the ablation variants).
        ablations: run the Table 1 variants (:data:`ABLATIONS`) instead of one method.
        jobs: local worker processes (0: in this process); ignored with ``scheduler``.
        threads: JAX threads of each local worker (:mod:`ncflow.runs.cluster`).
        scheduler: address or scheduler file of an existing Dask cluster
            (:func:`ncflow.runs.cluster.open_client`).
        dashboard: start the local cluster's dashboard and print its address.
        verbose: let Dask's log messages through.
        progress: a progress bar over the runs (on a terminal).
        plots: write the per-run plots and the report's curve plots.
        geodesic_method: see :func:`ncflow.evaluate.geodesic_errors`.
        log: where progress lines go.

    Returns:
        :class:`BenchmarkResult`.

    Raises:
        InputError: bad csv, bad ``jobs``, no scheduler at ``scheduler``, or runs in ``out_dir`` made
            with another configuration; raised before anything runs or is written.
        KeyboardInterrupt: after writing the report of what was done.
    """
    if jobs < 0:
        raise InputError(f"--jobs must be at least 0 (got {jobs})")
    pairs = read_pairs_csv(pairs_csv)
    methods = benchmark_methods(config, ablations)
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError("exists and is not a folder", out)
    _check_method_configs(out, methods)
    tasks = [
        RunTask(m.id, p, m.config, str(out / "runs" / m.id / p.name), plots, geodesic_method)
        for p in pairs
        for m in methods
    ]
    rows_so_far: dict = {}

    def describe(o: dict) -> str:
        run_dir = out / "runs" / o["method"] / o["pair"]
        if o["status"] != "failed" and _evaluation_done(run_dir):
            rows_so_far[(o["method"], o["pair"])] = run_row(json.loads((run_dir / EVALUATION_FILE).read_text()))
        return _describe(o, rows_so_far)

    outcomes: list[dict] = []
    cluster = open_client(jobs, scheduler, threads=threads, dashboard=dashboard, verbose=verbose, log=log)
    with cluster as (client, info):
        throttle = info["kind"] != "scheduler"  # an existing cluster may grow with the queue (adapt)
        _write_method_configs(out, methods)
        try:
            tasks = share_tissues(tasks, out, log, client, throttle)
            _execute(tasks, jobs, log, describe, client=client, outcomes=outcomes, progress=progress, throttle=throttle)
        finally:
            report = _report(out, tasks, outcomes, methods, pairs_csv, len(pairs), plots, log)
    return BenchmarkResult(report, outcomes)


def _report(out, tasks, outcomes, methods, pairs_csv, n_pairs, plots, log) -> dict:
    """Write the report (without the curve plots if drawing them fails)."""
    rows = _collect_rows(tasks, {(o["method"], o["pair"]): o for o in outcomes})
    kwargs = {"pairs_csv": str(pairs_csv), "n_pairs": n_pairs}
    try:
        return write_benchmark_report(out, rows, [m.to_dict() for m in methods], plots=plots, **kwargs)
    except Exception as exc:  # noqa: BLE001 -- the report is always written: without the plots then
        if not plots:
            raise
        log(f"could not draw the curve plots ({type(exc).__name__}: {str(exc)[:200]}); writing the report without")
        return write_benchmark_report(out, rows, [m.to_dict() for m in methods], plots=False, **kwargs)
