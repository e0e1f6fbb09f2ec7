"""The Dask cluster that ``ncflow batch`` and ``ncflow benchmark`` run their pairs on.

:func:`open_client` yields a :class:`distributed.Client`:

* by default a :class:`distributed.LocalCluster` of ``jobs`` worker processes (each under a nanny,
  which starts a new process when one dies), one task at a time per worker (``nthreads=1``);
* with ``scheduler`` an existing cluster: an address (``tcp://host:8786``, started by
  ``dask scheduler`` and ``dask worker`` or by dask-jobqueue) or the JSON file that
  ``dask scheduler --scheduler-file`` writes. Nothing is started or stopped there; a scheduler that
  does not answer within :data:`CONNECT_TIMEOUT` seconds is one :class:`~ncflow.errors.InputError`;
* with ``jobs=0`` one worker thread inside this process (no process isolation: a crash of a pair
  ends the batch; for debugging and profiling).

Threads. A match is one JAX computation at a time, so a worker runs one task (``nthreads=1``) and
its XLA runtime gets ``threads`` threads (``PJRT_NPROC``, the size of the XLA:CPU thread pool; default
1), so ``jobs`` workers use ``jobs × threads`` cores (a notice is logged when that exceeds the
machine's). The thread count is not derived from ``jobs`` on purpose: XLA splits some loops by
thread count, which changes the last bits of a result (measured: a placement score differs at 1e-6
between 1 and 2 threads), so with a fixed count ``--jobs 1`` and ``--jobs 2`` write byte-identical
results. One worker per core is also the better use of the cores for many pairs (measured on 2
cores, ``benchmarks/batch.py``: one worker keeps 0.9 of a core busy with 1 or with 2 XLA threads, two
workers finish the batch 1.6× sooner). BLAS/OpenMP stay at one thread (Dask's default for worker processes); Eigen's own
multi-threaded products are off (``--xla_cpu_multi_thread_eigen=false``). On a GPU the workers do
not preallocate device memory (``XLA_PYTHON_CLIENT_PREALLOCATE=false``), so several can share one
device.
Workers of an existing cluster are configured where they are started (see docs/batch.md).

Failures. The local scheduler gives up on a task at the first worker death
(``distributed.scheduler.allowed-failures = 0``) and hands out one task per worker at a time
(``worker-saturation = 1.0``, so a dying worker takes no queued task down with it); the retry is the
runner's own (:func:`ncflow.runs.batch.run_tasks`), so "retried once" means the same for an
exception, a crash and a killed worker, on any cluster.

Dask's log messages are silenced (``verbose`` shows them); the dashboard is started on request
(``dashboard``; it needs ``bokeh``).
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Callable, Iterator

from ncflow import __version__
from ncflow.errors import InputError, first_line

CONNECT_TIMEOUT = 5.0
"""Seconds to wait for an existing scheduler to answer."""

_DASK_LOGGERS = ("distributed", "bokeh", "tornado")

# scheduler settings of the local cluster (see the module docstring)
NANNY_ENVIRON = '{"MALLOC_TRIM_THRESHOLD_": None}'  # merged into Dask's defaults: that one unset
LOCAL_SCHEDULER_CONFIG = {
    "distributed.scheduler.allowed-failures": 0,
    "distributed.scheduler.worker-saturation": 1.0,
    # Dask's nanny sets MALLOC_TRIM_THRESHOLD_=65536 in its workers; any value switches off glibc's
    # dynamic mmap threshold, so XLA:CPU's large buffers are mapped and faulted in afresh on every
    # allocation: the pose search ran 4.5x slower (136 s against 30 s on a MANO pair). Unset.
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
}


def cpu_count() -> int:
    """Cores this process may use (affinity and cgroup quotas respected, through Dask)."""
    from dask.system import CPU_COUNT

    return max(1, int(CPU_COUNT))


def worker_environment(threads: int, base: dict | None = None) -> dict[str, str]:
    """Environment variables of a local worker process running JAX on ``threads`` threads.

    ``XLA_FLAGS`` of ``base`` (default ``os.environ``) are kept, the Eigen flag appended. Given to a
    ``dask worker`` command as well, it keeps its nanny from setting ``MALLOC_TRIM_THRESHOLD_``
    (see ``LOCAL_SCHEDULER_CONFIG``).
    """
    base = os.environ if base is None else base
    flags = base.get("XLA_FLAGS", "")
    if "xla_cpu_multi_thread_eigen" not in flags:
        flags = f"{flags} --xla_cpu_multi_thread_eigen=false".strip()
    return {
        "PJRT_NPROC": str(int(threads)),
        "XLA_FLAGS": flags,
        "XLA_PYTHON_CLIENT_PREALLOCATE": base.get("XLA_PYTHON_CLIENT_PREALLOCATE", "false"),
        "DASK_DISTRIBUTED__NANNY__PRE_SPAWN_ENVIRON": NANNY_ENVIRON,
    }


@contextlib.contextmanager
def quiet_dask(verbose: bool = False) -> Iterator[None]:
    """Dask's loggers (and warnings) at CRITICAL for the block, unless ``verbose``."""
    if verbose:
        yield
        return
    import warnings

    loggers = [logging.getLogger(name) for name in _DASK_LOGGERS]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", module=r"distributed(\..*)?")
            yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)


def _worker_version() -> str:

    return __version__


def _check_workers(client, address: str, log: Callable[[str], None]) -> int:
    """Refuse workers that run another ncflow version (results would not match their manifests)."""
    try:
        versions = client.run(_worker_version, on_error="return")
    except Exception as exc:  # noqa: BLE001 -- any failure to reach the workers is reported, not hidden
        raise InputError(f"cannot reach the workers of the Dask scheduler ({first_line(exc)})", address) from None
    bad = {w: v for w, v in versions.items() if v != __version__}
    if bad:
        worker, version = next(iter(bad.items()))
        shown = first_line(version) if isinstance(version, BaseException) else f"ncflow {version}"
        raise InputError(
            f"worker {worker} runs {shown}, this is ncflow {__version__}; install the same ncflow on the workers",
            address,
        )
    if not versions:
        log(f"no workers at {address} yet; the pairs wait until some join")
    return len(versions)


@contextlib.contextmanager
def open_client(
    jobs: int = 1,
    scheduler: str | None = None,
    *,
    threads: int = 1,
    dashboard: bool = False,
    verbose: bool = False,
    log: Callable[[str], None] = print,
) -> Iterator[tuple[object, dict]]:
    """A Dask client: a local cluster of ``jobs`` workers, or the existing cluster at ``scheduler``.

    Args:
        jobs: local worker processes (0: one worker thread in this process); ignored with ``scheduler``.
        threads: XLA threads of each local worker process.
        scheduler: address (``tcp://host:port``) or scheduler file (``.json``) of an existing cluster.
        dashboard: start the local cluster's dashboard (on port 8787, or another free one).
        verbose: let Dask's log messages through.
        log: where the dashboard address and notices go.

    Yields:
        ``(client, info)``; ``info`` describes the cluster for the run summary (``kind``, ``address``,
        ``workers``, ``threads_per_worker``, ``jax_threads``, ``dashboard``).

    Raises:
        InputError: ``scheduler`` is malformed or nothing answers there; workers of another ncflow version.
    """
    import dask
    from distributed import Client, LocalCluster

    with quiet_dask(verbose), contextlib.ExitStack() as stack:
        if scheduler:
            client = stack.enter_context(_connect(scheduler))
            workers = _check_workers(client, scheduler, log)
            info = {"kind": "scheduler", "address": str(client.scheduler.address), "workers": workers}
        else:
            if jobs < 0:
                raise InputError(f"--jobs must be at least 0 (got {jobs})")
            if threads < 1:
                raise InputError(f"--threads must be at least 1 (got {threads})")
            if max(jobs, 1) * threads > cpu_count():
                log(f"note: {max(jobs, 1)} workers x {threads} threads is more than the {cpu_count()} cores here")
            in_process = jobs == 0
            stack.enter_context(dask.config.set(LOCAL_SCHEDULER_CONFIG))
            kwargs = {} if in_process else {"env": worker_environment(threads)}
            cluster = stack.enter_context(
                LocalCluster(
                    n_workers=max(jobs, 1),
                    threads_per_worker=1,
                    processes=not in_process,
                    dashboard_address=":8787" if dashboard else None,
                    silence_logs=logging.INFO if verbose else logging.CRITICAL,
                    **kwargs,
                )
            )
            client = stack.enter_context(Client(cluster, set_as_default=False))
            info = {
                "kind": "in-process" if in_process else "local",
                "address": str(cluster.scheduler_address),
                "workers": max(jobs, 1),
                "threads_per_worker": 1,
                "jax_threads": None if in_process else threads,
            }
        link = _dashboard_link(client) if (dashboard or scheduler) else None
        info["dashboard"] = link
        if link:
            log(f"Dask dashboard: {link}")
        elif dashboard:
            log("no Dask dashboard: it needs bokeh (pip install 'bokeh>=3.1')")
        yield client, info


def _dashboard_link(client) -> str | None:
    try:
        return client.dashboard_link if client.scheduler_info().get("services", {}).get("dashboard") else None
    except Exception:  # noqa: BLE001 -- the link is a convenience
        return None


def check_address(address: str) -> str:
    """``address`` if it is a well-formed Dask address (known protocol, host and port), else one InputError.

    Checked before a client is made: a client of a malformed address fails late and noisily.
    """
    from distributed.comm.addressing import parse_address, parse_host_port
    from distributed.comm.registry import get_backend

    try:
        scheme, location = parse_address(address)
        get_backend(scheme)
        if scheme in ("tcp", "tls", "ws", "wss"):
            _, port = parse_host_port(location)
            if not 0 < int(port) < 65536:
                raise ValueError(f"port {port} out of range")
    except (ValueError, TypeError) as exc:
        raise InputError(
            f"not a Dask scheduler address ({first_line(exc)[:160]}); e.g. tcp://host:8786", address
        ) from None
    return address


@contextlib.contextmanager
def _connect(scheduler: str) -> Iterator[object]:
    """A client of the scheduler at ``scheduler`` (address or scheduler file), or one InputError line."""
    from distributed import Client

    kwargs: dict = {"timeout": CONNECT_TIMEOUT, "set_as_default": False}
    if scheduler.endswith(".json"):
        if not os.path.isfile(scheduler):
            raise InputError("no such scheduler file", scheduler)
        kwargs["scheduler_file"] = scheduler
    else:
        kwargs["address"] = check_address(scheduler)
    try:
        client = Client(**kwargs)
    except (OSError, TimeoutError) as exc:
        raise InputError(
            f"no Dask scheduler answers there within {CONNECT_TIMEOUT:g} s ({first_line(exc)[:160]})", scheduler
        ) from None
    except (ValueError, TypeError) as exc:
        raise InputError(f"not a Dask scheduler address ({first_line(exc)[:160]})", scheduler) from None
    try:
        yield client
    finally:
        with contextlib.suppress(Exception):
            client.close(timeout=CONNECT_TIMEOUT)
