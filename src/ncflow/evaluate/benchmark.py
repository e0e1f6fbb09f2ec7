"""Benchmark runner: match and evaluate every pair of a ``pairs.csv`` (per method), then report.

Input: a csv with columns ``name, source, target, skeleton, gt`` and optionally ``gt_format`` and
``dataset`` (the file :func:`ncflow.synthetic.pairs.write_pairs` / ``ncflow make-pairs`` writes);
paths are relative to the csv. ``gt`` is ``identity``, a ground-truth file, or two template
``.vts`` files separated by ``;`` (with ``gt_format`` ``template``). Every row is checked (columns,
files, names) before anything runs.

Layout of ``OUT``::

    runs/<method>/config.json          the method's configuration (a later run must match it)
    runs/<method>/<pair>/              the output contract of ncflow match, plus
    runs/<method>/<pair>/evaluation.json and eval_*.png   (ncflow evaluate)
    runs/<method>/<pair>/run_manifest.json   what the run was made from (inputs' hashes, versions)
    report.json, report.md, curves_<dataset>.png

Manifests: every run folder holds ``run_manifest.json`` (:func:`run_manifest`): the SHA-256 of
its input files (source, target, skeleton, ground truth), the ground-truth format, the geodesic
method, the ncflow version and the method's configuration, written after the match (``match``
part) and again after the evaluation (``evaluation`` part).

Resuming: a run is skipped only when its manifest matches the current one in full and its
``evaluation.json`` exists; a run whose manifest matches in its ``match`` part and whose result is
complete (``metrics.json`` present; results are written atomically) is only evaluated; anything
else (no manifest, an input file changed, another ncflow version or configuration) is matched and
evaluated again (its earlier evaluation removed first). So an interrupted benchmark continues
where it stopped when the same command is run again, and never reuses a run of other inputs. A
run that fails (a training error, bad input found late, a worker process that crashed) is
recorded in the report and the others go on; running the command again retries it. The report
is always written at the end (without the curve plots if drawing them fails).

Methods: one (``ncflow``: the given configuration) or, with ``ablations=True``, the paper's Table 1
rows as configuration variants of the given configuration (:data:`ABLATIONS`).

Over 500 lines: the csv reader, the run manifests, the resumable runs and the crash-tolerant
executor are one protocol over the run folders and are kept together.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import json
import os
import re
import time
from collections.abc import Callable
from pathlib import Path

from ncflow.config import Config, config_to_dict, with_metric
from ncflow.errors import InputError
from ncflow.evaluate.aggregate import run_row
from ncflow.evaluate.report import write_benchmark_report
from ncflow.evaluate.score import EVALUATION_FILE, EVALUATION_PLOTS
from ncflow.io.atomic import atomic_write_text
from ncflow.io.ground_truth import GT_FORMATS

REQUIRED_COLUMNS = ("name", "source", "target", "skeleton", "gt")
OPTIONAL_COLUMNS = ("gt_format", "dataset")

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
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")


# ----------------------------------------------------------------------------------------------
# Pairs


@dataclasses.dataclass(frozen=True)
class PairSpec:
    """One row of a pairs csv, paths resolved against the csv's folder.

    ``gt`` is ``"identity"``, a path, or a pair of paths (template maps).
    """

    name: str
    source: str
    target: str
    skeleton: str
    gt: str | tuple[str, str]
    gt_format: str | None
    dataset: str


def _resolve(base: Path, value: str) -> str:
    p = Path(value)
    return str(p if p.is_absolute() else base / p)


def _parse_row(row: dict, line: int, base: Path, path: Path) -> PairSpec:
    where = f"line {line}"
    values = {k: (row.get(k) or "").strip() for k in REQUIRED_COLUMNS + OPTIONAL_COLUMNS}
    for key in REQUIRED_COLUMNS:
        if not values[key]:
            raise InputError(f"{where}: empty {key!r}", path)
    name = values["name"]
    if not _NAME_RE.match(name):
        raise InputError(
            f"{where}: pair name {name!r} must be letters, digits, '.', '_' or '-' (it names a folder)", path
        )
    files = {k: _resolve(base, values[k]) for k in ("source", "target", "skeleton")}
    fmt = values["gt_format"] or None
    if fmt is not None and fmt not in GT_FORMATS:
        raise InputError(f"{where}: unknown gt_format {fmt!r}; use one of {', '.join(GT_FORMATS)}", path)
    gt: str | tuple[str, str]
    if fmt == "identity" or (fmt is None and values["gt"].lower() == "identity"):
        gt = "identity"
    elif fmt == "template":
        parts = [s.strip() for s in values["gt"].split(";") if s.strip()]
        if len(parts) != 2:
            raise InputError(f"{where}: gt_format template needs two .vts files separated by ';'", path)
        gt = (_resolve(base, parts[0]), _resolve(base, parts[1]))
    else:
        gt = _resolve(base, values["gt"])
    for key, file in list(files.items()) + [
        ("gt", g) for g in ((gt,) if isinstance(gt, str) else gt) if g != "identity"
    ]:
        if not os.path.isfile(file):
            raise InputError(f"{where}: {key} file not found: {file}", path)
    return PairSpec(name, files["source"], files["target"], files["skeleton"], gt, fmt, values["dataset"] or "default")


def read_pairs_csv(path: str | os.PathLike) -> list[PairSpec]:
    """Read and check a pairs csv: required columns, non-empty values, existing files, unique names.

    Raises:
        InputError: one line naming the csv (and the line) on the first problem.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("no such file", path)
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            header = [h.strip() for h in (reader.fieldnames or [])]
            reader.fieldnames = header
            missing = [c for c in REQUIRED_COLUMNS if c not in header]
            if missing:
                raise InputError(
                    f"missing column(s) {', '.join(missing)} "
                    f"(expected {', '.join(REQUIRED_COLUMNS + OPTIONAL_COLUMNS)})",
                    path,
                )
            rows = [
                (reader.line_num, row)
                for row in reader
                if any((v or "").strip() for v in row.values() if isinstance(v, str))
            ]
    except (UnicodeDecodeError, csv.Error) as exc:
        raise InputError(f"cannot read csv ({str(exc).splitlines()[0]})", path) from None
    if not rows:
        raise InputError("no pairs listed", path)
    pairs = [_parse_row(row, line, path.parent, path) for line, row in rows]
    seen: set[str] = set()
    for p in pairs:
        if p.name in seen:
            raise InputError(f"duplicate pair name {p.name!r} (names label the run folders)", path)
        seen.add(p.name)
    return pairs


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


def ablation_config(config: Config, metric: str, interp: str, constraints: str) -> Config:
    """``config`` with its data term(s), skeleton interpolation and bone-constraint mode replaced."""
    cfg = with_metric(config, metric)
    cfg = dataclasses.replace(cfg, interp=interp)
    return dataclasses.replace(cfg, constraints=dataclasses.replace(cfg.constraints, mode=constraints))


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


MANIFEST_FILE = "run_manifest.json"


def _evaluation_done(run_dir: Path) -> bool:
    path = run_dir / EVALUATION_FILE
    if not path.is_file():
        return False
    try:
        return "headline" in json.loads(path.read_text())
    except (OSError, ValueError):
        return False


def file_sha256(path: str | os.PathLike) -> str:
    """SHA-256 of a file's bytes (hex)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def run_manifest(task: RunTask) -> dict:
    """What a run is made from: ``{"match": {...}, "evaluation": {...}}``.

    ``match``: SHA-256 of source, target and skeleton, the ncflow version and the method's
    configuration. ``evaluation``: SHA-256 of the ground-truth file(s) (``identity`` has none),
    the ground-truth format and the geodesic method (plus the match part's inputs, through the
    run). Equal manifests mean a finished run can be reused.
    """
    from ncflow import __version__

    p = task.pair
    gts = [] if p.gt == "identity" else ([p.gt] if isinstance(p.gt, str) else list(p.gt))
    return {
        "format": 1,
        "match": {
            "ncflow_version": __version__,
            "source_sha256": file_sha256(p.source),
            "target_sha256": file_sha256(p.target),
            "skeleton_sha256": file_sha256(p.skeleton),
            "config": json.loads(json.dumps(config_to_dict(task.config))),
        },
        "evaluation": {
            "ncflow_version": __version__,
            "gt": "identity" if not gts else [file_sha256(g) for g in gts],
            "gt_format": p.gt_format,
            "geodesic_method": task.geodesic_method,
        },
    }


def _read_manifest(run_dir: Path) -> dict | None:
    try:
        data = json.loads((run_dir / MANIFEST_FILE).read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


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
    from ncflow.match.matcher import Matcher

    p = task.pair
    result = Matcher(p.source, p.target, p.skeleton, task.config, quiet=True).run()
    result.save(task.run_dir, overwrite=True)


def _evaluate(task: RunTask) -> dict:
    """Evaluate the run folder against the pair's ground truth; writes evaluation.json (last) and plots."""
    from ncflow.evaluate.score import evaluate_result, write_evaluation

    p = task.pair
    ev = evaluate_result(task.run_dir, p.source, p.target, p.gt, p.gt_format, geodesic_method=task.geodesic_method)
    return write_evaluation(
        ev, plots=task.plots, extra={"benchmark": {"method": task.method, "pair": p.name, "dataset": p.dataset}}
    )


def run_task(task: RunTask) -> dict:
    """Do what is left of one run; never raises for a failed run (except on interruption).

    Returns:
        ``{"method", "pair", "status", "seconds", "error"}`` with status ``"skipped"`` (already
        evaluated, same manifest), ``"evaluated"`` (result of the same inputs found, evaluation
        added), ``"matched"`` (matched and evaluated) or ``"failed"`` (``error`` holds one line).
    """
    t0 = time.perf_counter()
    run_dir = Path(task.run_dir)
    out = {"method": task.method, "pair": task.pair.name, "status": "skipped", "seconds": 0.0, "error": None}
    try:
        manifest = run_manifest(task)
        old = _read_manifest(run_dir) or {}
        same_match = old.get("match") == manifest["match"] and (run_dir / "metrics.json").is_file()
        if same_match and old.get("evaluation") == manifest["evaluation"] and _evaluation_done(run_dir):
            return out
        if same_match:
            out["status"] = "evaluated"
        else:
            if run_dir.is_dir():
                _drop_evaluation(run_dir)  # it scored an earlier result (or other inputs)
            _match(task)
            _write_manifest(run_dir, manifest, evaluated=False)
            out["status"] = "matched"
        _evaluate(task)
        _write_manifest(run_dir, manifest, evaluated=True)
    except Exception as exc:  # noqa: BLE001 -- a failed run is recorded, the benchmark goes on
        text = str(exc).splitlines()[0] if str(exc) else ""
        out.update(status="failed", error=f"{type(exc).__name__}: {text[:300]}".rstrip(": "))
    finally:
        # every pair compiles its own executables (other shapes); kept for the whole process they
        # exhausted the address-space mappings after ~14 pairs (LLVM "Unable to allocate section memory")
        import jax

        jax.clear_caches()
    out["seconds"] = time.perf_counter() - t0
    return out


def _crashed(task: RunTask, why: str) -> dict:
    return {"method": task.method, "pair": task.pair.name, "status": "failed", "seconds": 0.0, "error": why}


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
        if old != json.loads(json.dumps(config_to_dict(m.config))):
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


def _execute(
    tasks: list[RunTask],
    jobs: int,
    log: Callable[[str], None],
    describe: Callable[[dict], str],
    worker: Callable[[RunTask], dict] | None = None,
) -> list[dict]:
    """Run the tasks in this process (jobs = 1) or in a spawn process pool; log each as it ends.

    A worker process that dies (a crash, the kernel's out-of-memory killer) breaks the pool: the
    runs it took down are retried one at a time, each in a fresh process, and a run whose process
    dies again is recorded as failed; the others go on.
    """
    worker = run_task if worker is None else worker
    outcomes: list[dict] = []

    def done(o: dict) -> None:
        outcomes.append(o)
        log(f"[{len(outcomes)}/{len(tasks)}] {describe(o)}")

    if jobs <= 1:
        for t in tasks:
            try:
                o = worker(t)
            except Exception as exc:  # noqa: BLE001 -- run_task records failures itself; belt and braces
                o = _crashed(t, f"{type(exc).__name__}: {str(exc)[:300]}")
            done(o)
        return outcomes
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed
    from concurrent.futures.process import BrokenProcessPool

    context = multiprocessing.get_context("spawn")
    lost: list[RunTask] = []
    with ProcessPoolExecutor(max_workers=jobs, mp_context=context) as pool:
        futures = {pool.submit(worker, t): t for t in tasks}
        try:
            for f in as_completed(futures):
                try:
                    done(f.result())
                except BrokenProcessPool:
                    lost.append(futures[f])
                except Exception as exc:  # noqa: BLE001 -- e.g. a result that cannot be unpickled
                    done(_crashed(futures[f], f"{type(exc).__name__}: {str(exc)[:300]}"))
        except BaseException:
            for f in futures:
                f.cancel()
            raise
    for t in lost:  # one at a time, each in its own process: a crash takes down only its own run
        with ProcessPoolExecutor(max_workers=1, mp_context=context) as solo:
            try:
                done(solo.submit(worker, t).result())
            except BrokenProcessPool:
                done(_crashed(t, "the worker process crashed (killed, or out of memory)"))
            except Exception as exc:  # noqa: BLE001
                done(_crashed(t, f"{type(exc).__name__}: {str(exc)[:300]}"))
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
        if o.get("status") != "failed" and _evaluation_done(run_dir):
            rows.append(
                {**base, "status": "ok", "error": None, **run_row(json.loads((run_dir / EVALUATION_FILE).read_text()))}
            )
        else:
            rows.append({**base, "status": "failed", "error": o.get("error") or "not run"})
    return rows


def share_tissues(tasks: list[RunTask], out: Path, log: Callable[[str], None] = print) -> list[RunTask]:
    """Tetrahedralise each distinct source once, before the runs fan out, and point every run that
    uses it at that exact tissue (``tissue.file``), so methods and ``--jobs`` see the same tetrahedra
    (fTetWild is not deterministic). The tissues go to ``out/tissue/<sha256>.npz``.
    """
    from ncflow.io.meshes import load_mesh
    from ncflow.match.prepare import source_tissue, uses_tissue, working_source
    from ncflow.tissue import write_tissue_file

    done: dict = {}
    shared = []
    for task in tasks:
        cfg = task.config
        if not uses_tissue(cfg) or cfg.tissue.file:
            shared.append(task)
            continue
        t = cfg.tissue
        key = (task.pair.source, t.edge_length_fac, t.epsilon, t.split_passes, cfg.working_vertices)
        if key not in done:
            _, _, work = working_source(load_mesh(task.pair.source), cfg)
            c, info = source_tissue(work, cfg)
            path = out / "tissue" / f"{info['sha256']}.npz"
            if not path.exists():
                write_tissue_file(path, c)
            log(f"tissue of {Path(task.pair.source).name}: {c.shape[0]} samples, shared by its runs ({path.name[:12]})")
            done[key] = str(path)
        shared.append(
            dataclasses.replace(task, config=dataclasses.replace(cfg, tissue=dataclasses.replace(t, file=done[key])))
        )
    return shared


def run_benchmark(
    pairs_csv: str | os.PathLike,
    out_dir: str | os.PathLike,
    config: Config,
    *,
    ablations: bool = False,
    jobs: int = 1,
    plots: bool = True,
    geodesic_method: str = "auto",
    log: Callable[[str], None] = print,
) -> BenchmarkResult:
    """Match and evaluate every pair (per method), resuming finished runs, and write the report.

    Args:
        pairs_csv: the pairs file (see the module docstring).
        out_dir: the benchmark folder (created).
        config: the configuration (the ``ncflow`` method, or the base of the ablation variants).
        ablations: run the Table 1 variants (:data:`ABLATIONS`) instead of one method.
        jobs: worker processes (spawn); 1 runs everything in this process.
        plots: write the per-run plots and the report's curve plots.
        geodesic_method: see :func:`ncflow.evaluate.geodesic_errors`.
        log: where progress lines go.

    Returns:
        :class:`BenchmarkResult`.

    Raises:
        InputError: bad csv, bad ``jobs``, or runs in ``out_dir`` made with another configuration;
            raised before anything runs or is written.
    """
    if jobs < 1:
        raise InputError(f"--jobs must be at least 1 (got {jobs})")
    pairs = read_pairs_csv(pairs_csv)
    methods = benchmark_methods(config, ablations)
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError("exists and is not a folder", out)
    _check_method_configs(out, methods)
    _write_method_configs(out, methods)
    tasks = [
        RunTask(m.id, p, m.config, str(out / "runs" / m.id / p.name), plots, geodesic_method)
        for p in pairs
        for m in methods
    ]
    tasks = share_tissues(tasks, out, log)
    rows_so_far: dict = {}

    def describe(o: dict) -> str:
        run_dir = out / "runs" / o["method"] / o["pair"]
        if o["status"] != "failed" and _evaluation_done(run_dir):
            rows_so_far[(o["method"], o["pair"])] = run_row(json.loads((run_dir / EVALUATION_FILE).read_text()))
        return _describe(o, rows_so_far)

    outcomes = _execute(tasks, jobs, log, describe)
    rows = _collect_rows(tasks, {(o["method"], o["pair"]): o for o in outcomes})
    kwargs = {"pairs_csv": str(pairs_csv), "n_pairs": len(pairs)}
    try:
        report = write_benchmark_report(out, rows, [m.to_dict() for m in methods], plots=plots, **kwargs)
    except Exception as exc:  # noqa: BLE001 -- the report is always written: without the plots then
        if not plots:
            raise
        log(f"could not draw the curve plots ({type(exc).__name__}: {str(exc)[:200]}); writing the report without")
        report = write_benchmark_report(out, rows, [m.to_dict() for m in methods], plots=False, **kwargs)
    return BenchmarkResult(report, outcomes)
