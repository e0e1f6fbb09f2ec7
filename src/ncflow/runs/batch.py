"""``ncflow batch``: match every pair of a csv on Dask; manifests and shared tissues for it and the benchmark.

``ncflow batch PAIRS.csv --out OUT`` matches every row of the csv (``name, source, target, skeleton``;
other columns ignored, :func:`ncflow.runs.pairs_csv.read_pairs_csv`) into ``OUT/<name>/``, no
ground truth needed. Layout of ``OUT``::

    <name>/                 the output contract of ncflow match, plus run_manifest.json
    tissue/<key>.npz        the soft tissue of each distinct source, shared by its pairs
    batch.json              the summary (always written, also when every pair failed or on Ctrl-C)

Each pair is a task of the engine (:func:`ncflow.runs.engine.run_tasks`) on a Dask cluster
(:func:`ncflow.runs.cluster.open_client`: a local cluster of worker processes, or an existing
one): a pair that raises or whose worker dies is retried once, then recorded as failed, and the
others go on.

Results are written per pair, atomically (:func:`ncflow.io.result.write_result`), by the worker that
matched it, then its manifest (``run_manifest.json``, :func:`match_manifest`: SHA-256 of source,
target and skeleton, the ncflow version and the configuration as far as it can change a result). A
pair is ``skipped`` when its folder holds a complete result (``metrics.json``) and a manifest equal
to the current one, so running the same command again retries only what failed or was not done, and
never reuses a result of other inputs.

Shared preparation (:func:`share_tissues`): each distinct source (by content and tissue settings) is
tetrahedralised once, as its own task before the pairs fan out, into ``OUT/tissue/<key>.npz``; every
pair of that source reads it (``tissue.file``), so the pairs, ``--jobs`` and a resumed batch all use
the same tetrahedra (fTetWild is not deterministic). A source whose tissue fails is not shared: its
pairs then fail (or succeed) on their own.

Determinism: every pair uses the configuration's seed, whatever worker runs it and in whatever order,
and local workers run JAX on a fixed number of threads whatever ``--jobs`` (:mod:`ncflow.runs.cluster`),
so ``--jobs 1`` and ``--jobs 2`` give byte-identical result files (``metrics.json`` differs in its timings).
"""

from __future__ import annotations

import dataclasses
import datetime
import hashlib
import json
import os
import time
from collections.abc import Callable
from pathlib import Path

from ncflow import __version__
from ncflow.config import Config, result_config
from ncflow.errors import InputError
from ncflow.io.atomic import atomic_write_text
from ncflow.io.files import file_sha256, read_npz_arrays
from ncflow.io.meshes import load_mesh
from ncflow.matcher.inputs import intake
from ncflow.matcher.prepare import source_tissue, uses_tissue, working_source
from ncflow.matcher.steps import Matcher
from ncflow.runs.cluster import open_client
from ncflow.runs.engine import RETRIES, Outcome, Task, error_line, run_tasks
from ncflow.runs.pairs_csv import PairSpec, read_pairs_csv
from ncflow.tissue import write_tissue_file

MANIFEST_FILE = "run_manifest.json"
SUMMARY_FILE = "batch.json"


# ----------------------------------------------------------------------------------------------
# Manifests


def match_manifest(source: str, target: str, skeleton: str | None, config: Config) -> dict:
    """What a match result is made from: the SHA-256 of its three input files (the skeleton's None when it
    is suggested), the ncflow version and :func:`result_config`. Equal manifests mean a finished result can
    be reused.
    """
    return {
        "ncflow_version": __version__,
        "source_sha256": file_sha256(source),
        "target_sha256": file_sha256(target),
        "skeleton_sha256": None if skeleton is None else file_sha256(skeleton),
        "config": result_config(config),
    }


def read_manifest(run_dir: str | os.PathLike) -> dict | None:
    """The manifest of a run folder, or None (missing or unreadable)."""
    try:
        data = json.loads((Path(run_dir) / MANIFEST_FILE).read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def write_manifest(run_dir: str | os.PathLike, manifest: dict) -> None:
    """Write ``run_manifest.json`` atomically."""
    atomic_write_text(Path(run_dir) / MANIFEST_FILE, json.dumps(manifest, indent=1) + "\n")


# ----------------------------------------------------------------------------------------------
# Shared preparation: one tissue per distinct source


@dataclasses.dataclass(frozen=True)
class TissueJob:
    """Tetrahedralise ``source`` with ``config``'s tissue settings into the tissue file ``path``."""

    source: str
    config: Config
    path: str


def tissue_key(source: str, config: Config) -> str | None:
    """Name of the shared tissue of a source: a digest of its content and the settings the tissue
    depends on; None when the run needs no shared tissue (no tissue term, or ``tissue.file`` given).
    """
    if not uses_tissue(config) or config.tissue.file:
        return None
    t = config.tissue
    spec = [file_sha256(source), config.working_vertices, t.edge_length_fac, t.epsilon, t.split_passes]
    return hashlib.sha256(json.dumps(spec).encode()).hexdigest()[:32]


def _tissue_file_ok(path: str) -> bool:
    """Whether ``path`` holds (K, 3) finite centroids (a shared tissue an earlier run wrote; the match
    checks it against its source again).
    """
    import numpy as np

    if not os.path.isfile(path):
        return False
    try:
        c = np.asarray(read_npz_arrays(path, ("centroids",), ())["centroids"])
    except (InputError, OSError, ValueError):
        return False
    return c.ndim == 2 and c.shape[1] == 3 and c.shape[0] > 0 and bool(np.isfinite(c).all())


def make_tissue_file(job: TissueJob) -> dict:
    """Write the tissue of ``job.source`` (the per-machine tissue cache's entry, else fTetWild) to
    ``job.path``; runs on a worker.
    """
    _, work = working_source(intake(load_mesh(job.source), "source", job.config)[0], job.config)
    c, info = source_tissue(work, job.config)
    write_tissue_file(job.path, c)
    return {"path": job.path, "n_centroids": int(c.shape[0]), "sha256": info["sha256"]}


def share_tissues(
    tasks: list, out: str | os.PathLike, log: Callable[[str], None] = print, client=None, throttle: bool = True
) -> list:
    """Tetrahedralise each distinct source once and point every task of it at that tissue.

    ``tasks`` are dataclasses with ``pair`` (a :class:`PairSpec`) and ``config``; returned with
    ``config.tissue.file`` set to ``out/tissue/<key>.npz`` (:func:`tissue_key`) where a tissue is
    used. With ``client`` the tissues are computed as tasks on its cluster (in parallel, retried like
    pairs; ``throttle`` as in :func:`~ncflow.runs.engine.run_tasks`), else in this process. A
    source whose tissue fails is left unshared (logged).
    """
    jobs: dict[str, TissueJob] = {}
    keys = []
    for task in tasks:
        key = tissue_key(task.pair.source, task.config)
        keys.append(key)
        if key is not None and key not in jobs:
            jobs[key] = TissueJob(task.pair.source, task.config, str(Path(out) / "tissue" / f"{key}.npz"))
    done = {key: job.path for key, job in jobs.items() if _tissue_file_ok(job.path)}  # made by an earlier run
    jobs = {key: job for key, job in jobs.items() if key not in done}
    if jobs:
        (Path(out) / "tissue").mkdir(parents=True, exist_ok=True)

    def note(key: str, ok: bool, value: dict | None, error: str | None) -> None:
        name = Path(jobs[key].source).name
        if ok:
            done[key] = jobs[key].path
            log(f"tissue of {name}: {value['n_centroids']} samples, shared by its pairs ({key[:12]})")
        else:
            log(f"tissue of {name} failed ({error}); its pairs prepare their own")

    if client is None:
        for key, job in jobs.items():
            try:
                note(key, True, make_tissue_file(job), None)
            except Exception as exc:  # noqa: BLE001 -- the pairs of this source report it themselves
                note(key, False, None, error_line(exc))
    elif jobs:
        run_tasks(
            client,
            [Task(f"tissue-{key}", make_tissue_file, job) for key, job in jobs.items()],
            on_done=lambda o: note(o.key[len("tissue-") :], o.status == "ok", o.value, o.error),
            unit="source",
            throttle=throttle,
        )
    shared = []
    for task, key in zip(tasks, keys):
        if key in done:
            cfg = task.config
            task = dataclasses.replace(
                task, config=dataclasses.replace(cfg, tissue=dataclasses.replace(cfg.tissue, file=done[key]))
            )
        shared.append(task)
    return shared


# ----------------------------------------------------------------------------------------------
# ncflow batch


@dataclasses.dataclass(frozen=True)
class PairJob:
    """Match ``pair`` with ``config`` into ``run_dir`` and record ``manifest`` there."""

    pair: PairSpec
    config: Config
    run_dir: str
    manifest: dict | None = None


def match_pair(job: PairJob) -> dict:
    """Match one pair and write its result and manifest (runs on a worker); returns a few numbers."""
    p = job.pair
    run_dir = Path(job.run_dir)
    try:
        (run_dir / MANIFEST_FILE).unlink(missing_ok=True)  # an earlier result of other inputs is not vouched for
        result = Matcher(p.source, p.target, p.skeleton, job.config, quiet=True).run()
        result.save(run_dir, overwrite=True)
        if job.manifest is not None:
            write_manifest(run_dir, job.manifest)
        m = result.metrics
        return {
            "steps": int(job.config.total_steps),
            "match_seconds": float(m["timings"]["total"]),
            "max_bone_violation_ratio": float(m["constraints"]["max_violation_ratio"]),
        }
    finally:
        # every pair compiles its own executables; kept for the whole worker they exhaust the
        # address-space mappings after ~14 pairs (LLVM "Unable to allocate section memory")
        import jax

        jax.clear_caches()


def _run_dir_problem(run_dir: Path) -> str | None:
    if run_dir.is_symlink():
        return "its result folder is a symbolic link; ncflow writes only folders it makes (remove it)"
    if run_dir.exists() and not run_dir.is_dir():
        return "its result folder is a file (remove it)"
    return None


def _finished(run_dir: Path, manifest: dict) -> bool:
    return read_manifest(run_dir) == manifest and (run_dir / "metrics.json").is_file()


@dataclasses.dataclass
class BatchResult:
    """``summary``: the content of ``batch.json``; ``path``: where it was written."""

    summary: dict
    path: Path

    @property
    def n_failed(self) -> int:
        """Number of pairs that failed (or were interrupted)."""
        return sum(r["status"] in ("failed", "interrupted") for r in self.summary["pairs"])


def _now() -> str:
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


def run_batch(
    pairs_csv: str | os.PathLike,
    out_dir: str | os.PathLike,
    config: Config,
    *,
    jobs: int = 1,
    threads: int = 1,
    scheduler: str | None = None,
    dashboard: bool = False,
    verbose: bool = False,
    progress: bool = True,
    log: Callable[[str], None] = print,
) -> BatchResult:
    """Match every pair of ``pairs_csv`` into ``out_dir/<name>/`` on Dask; write ``batch.json``.

    Args:
        pairs_csv: ``name, source, target, skeleton`` (+ any columns), paths relative to the csv.
        out_dir: the batch folder (created; reused to resume).
        config: the configuration of every match (its seed for every pair).
        jobs: local worker processes (0: in this process); ignored with ``scheduler``.
        threads: JAX threads of each local worker (:mod:`ncflow.runs.cluster`).
        scheduler: address or scheduler file of an existing Dask cluster.
        dashboard: start the local cluster's dashboard and print its address.
        verbose: let Dask's log messages through.
        progress: a progress bar over the pairs (on a terminal).
        log: where progress lines go.

    Returns:
        :class:`BatchResult`; pairs are ``ok``, ``skipped`` (finished earlier with the same inputs),
        ``failed`` (after a retry) or ``interrupted``.

    Raises:
        InputError: a bad csv, ``out_dir`` unusable, no scheduler at ``scheduler``; before any work.
        KeyboardInterrupt: after writing ``batch.json``.
    """
    pairs = read_pairs_csv(pairs_csv, ground_truth=False)
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError("exists and is not a folder", out)
    if config.tissue.file:
        config = dataclasses.replace(
            config, tissue=dataclasses.replace(config.tissue, file=os.path.abspath(config.tissue.file))
        )
    started, t0 = _now(), time.perf_counter()
    records = {
        p.name: {
            "name": p.name,
            "status": "interrupted",
            "attempts": 0,
            "seconds": 0.0,
            "error": None,
            "worker": None,
            "dir": p.name,
            "source": p.source,
            "target": p.target,
            "skeleton": p.skeleton,
        }
        for p in pairs
    }
    summary = {
        "format": 1,
        "ncflow_version": __version__,
        "pairs_csv": os.path.abspath(pairs_csv),
        "out": str(out.absolute()),
        "started": started,
        "cluster": None,
        "retries": RETRIES,
        "seed": config.seed,
        "config": result_config(config),
    }
    cluster = open_client(jobs, scheduler, threads=threads, dashboard=dashboard, verbose=verbose, log=log)
    with cluster as (client, info):
        summary["cluster"] = info
        out.mkdir(parents=True, exist_ok=True)
        path = out / SUMMARY_FILE
        try:
            throttle = info["kind"] != "scheduler"  # an existing cluster may grow with the queue (adapt)
            todo = _prepare_pairs(pairs, config, out, records, client, log, throttle)

            def done(o: Outcome) -> None:
                r = records[o.key]
                r.update(status=o.status, attempts=o.attempts, seconds=round(o.seconds, 3), error=o.error)
                r["worker"] = o.worker
                if o.value:
                    r.update(o.value)
                finished = sum(x["status"] != "interrupted" for x in records.values())
                tail = f" ({o.error})" if o.error else f" in {o.seconds:.1f} s"
                retried = f" after {o.attempts} attempts" if o.attempts > 1 else ""
                log(f"[{finished}/{len(records)}] {o.key}: {o.status}{retried}{tail}")

            tasks = [Task(j.pair.name, match_pair, j) for j in todo]
            run_tasks(client, tasks, on_done=done, progress=progress, throttle=throttle)
        finally:
            _write_summary(path, summary, records, t0)
    return BatchResult(summary, path)


def _prepare_pairs(pairs, config, out: Path, records: dict, client, log, throttle: bool) -> list[PairJob]:
    """Pairs to run (their tissue shared), the others recorded as skipped or failed."""
    todo = []
    for p in pairs:
        run_dir = out / p.name
        problem = _run_dir_problem(run_dir)
        if problem:
            records[p.name].update(status="failed", error=f"InputError: {problem}")
            continue
        todo.append(PairJob(p, config, str(run_dir), None))
    todo = share_tissues(todo, out, log, client, throttle)
    jobs = []
    for job in todo:
        try:
            p = job.pair
            manifest = {"format": 1, "match": match_manifest(p.source, p.target, p.skeleton, job.config)}
        except OSError as exc:
            records[job.pair.name].update(status="failed", error=f"InputError: cannot read an input ({exc.strerror})")
            continue
        if _finished(Path(job.run_dir), manifest):
            records[job.pair.name].update(status="skipped")
            continue
        jobs.append(dataclasses.replace(job, manifest=manifest))
    skipped = len(pairs) - len(jobs)
    if skipped:
        log(f"{skipped} of {len(pairs)} pairs need no run (finished earlier with the same inputs, or unusable)")
    return jobs


def _write_summary(path: Path, summary: dict, records: dict, t0: float) -> None:
    rows = list(records.values())
    summary["finished"] = _now()
    summary["wall_seconds"] = round(time.perf_counter() - t0, 3)
    summary["interrupted"] = any(r["status"] == "interrupted" for r in rows)
    summary["counts"] = {s: sum(r["status"] == s for r in rows) for s in ("ok", "skipped", "failed", "interrupted")}
    summary["pairs"] = rows
    atomic_write_text(path, json.dumps(summary, indent=1) + "\n")
