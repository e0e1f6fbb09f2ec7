"""The task engine of ``ncflow batch`` and ``ncflow benchmark``: tasks on a Dask cluster, retried once.

:func:`run_tasks` submits each :class:`Task` to the cluster of a :class:`distributed.Client`
(:func:`ncflow.runs.cluster.open_client`) and waits for them in completion order, with a progress
bar over the tasks (tqdm, on a terminal):

* a task that raises, or whose worker process dies (a segfault, the out-of-memory killer, a kill),
  is submitted once more (``retries=1``) and then recorded as failed while the others go on; an
  :class:`~ncflow.errors.NcflowError` (bad input, a result folder that cannot be written) is not
  retried: it would fail the same way. The retry is the engine's own (the local scheduler gives up
  on a task at the first worker death, :mod:`ncflow.runs.cluster`), so ``attempts`` counts
  submissions the same way for an exception and for a crash;
* at most as many tasks are in flight as the cluster has worker threads (``throttle``, the local
  cluster), so a worker never holds a task queued behind the one it runs, which its death would
  take down too;
* Ctrl-C cancels the tasks left and propagates; the outcomes so far went to the caller's
  ``on_done``, so the caller can write its summary.

Test hook (not a feature): a worker process about to run the task whose key equals the environment
variable ``NCFLOW_TEST_KILL_TASK`` kills itself with SIGKILL; the tests use it to show that a dying
worker ends as a failed task after one retry, not as a hang.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import signal
import socket
import time
import uuid
from collections.abc import Callable, Sequence

from ncflow.errors import NcflowError, first_line

TEST_KILL_ENV = "NCFLOW_TEST_KILL_TASK"
RETRIES = 1
DIED = "the worker process crashed (killed, or out of memory)"


@dataclasses.dataclass(frozen=True)
class Task:
    """One unit of work: ``fn(arg)`` on a worker; ``fn`` is a module-level function (workers import it)
    returning a small JSON-able dict; ``key`` names the task (unique within a run).
    """

    key: str
    fn: Callable
    arg: object


@dataclasses.dataclass
class Outcome:
    """What became of a task: ``status`` ``ok`` | ``failed`` | ``interrupted``, the number of
    submissions (``attempts``), the seconds of the last attempt on its worker, the error line of a
    failure, the task's return value, and the worker (``host:pid``) of the last attempt.
    """

    key: str
    status: str
    attempts: int = 0
    seconds: float = 0.0
    error: str | None = None
    value: dict | None = None
    worker: str | None = None


def error_line(exc: BaseException) -> str:
    """``Type: first line`` of an exception, at most 300 characters."""
    text = first_line(exc)[:300] if str(exc) else ""
    return f"{type(exc).__name__}: {text}".rstrip(": ")


def _attempt(fn: Callable, arg, key: str) -> dict:
    """Run one task on a worker; exceptions become a record (ncflow's own errors marked as not worth a retry)."""
    if os.environ.get(TEST_KILL_ENV) == key:  # test hook, see the module docstring
        os.kill(os.getpid(), signal.SIGKILL)
    t0 = time.perf_counter()
    record = {"worker": f"{socket.gethostname()}:{os.getpid()}"}
    try:
        record.update(ok=True, value=fn(arg))
    except NcflowError as exc:  # bad input, an unusable result folder: the same again on a retry
        record.update(ok=False, retry=False, error=error_line(exc))
    except Exception as exc:  # noqa: BLE001 -- a failed task is recorded (and retried), the others go on
        record.update(ok=False, retry=True, error=error_line(exc))
    record["seconds"] = time.perf_counter() - t0
    return record


def _collect(future) -> dict:
    """The record of a finished future; a worker death or a lost task is a failure worth a retry."""
    from distributed import KilledWorker

    try:
        return future.result()
    except KilledWorker:
        return {"ok": False, "retry": True, "error": DIED}
    except Exception as exc:  # noqa: BLE001 -- e.g. a result that cannot be unpickled, a lost scheduler
        return {"ok": False, "retry": True, "error": error_line(exc)}


def _free_slots(client, in_flight: int) -> int:
    """Worker threads of the cluster now connected, less the tasks in flight (a restarting worker
    does not count, so no task queues up behind another on one worker).
    """
    try:
        return sum(client.nthreads().values()) - in_flight
    except Exception:  # noqa: BLE001 -- a slow scheduler: try again at the next poll
        return 0


def run_tasks(
    client,
    tasks: Sequence[Task],
    *,
    retries: int = RETRIES,
    on_done: Callable[[Outcome], None] | None = None,
    progress: bool = True,
    unit: str = "pair",
    throttle: bool = True,
    poll: float = 0.5,
) -> list[Outcome]:
    """Run the tasks on the cluster of ``client``; retry each failed one ``retries`` times.

    Args:
        client: a :class:`distributed.Client` (:func:`ncflow.runs.cluster.open_client`).
        tasks: the tasks (unique keys).
        retries: further submissions of a task that raised (not an NcflowError) or whose worker died.
        on_done: called in this process with each final outcome, in completion order.
        progress: a progress bar on stderr (tqdm; shown only on a terminal).
        unit: what the bar counts.
        throttle: keep at most as many tasks in flight as the cluster has worker threads connected,
            so that a worker never holds a queued task that its death would take down (and count as
            an attempt). Off: submit everything at once (for an adaptive cluster, which grows with the
            queue; a dying worker may then also fail a task queued behind the one that killed it).
        poll: seconds between looks at the tasks and the cluster while waiting.

    Returns:
        the outcomes in the order of ``tasks``.

    Raises:
        KeyboardInterrupt: after cancelling the tasks left (the outcomes so far went to ``on_done``).
    """
    from collections import deque

    from tqdm import tqdm

    if len({t.key for t in tasks}) != len(tasks):
        raise ValueError("task keys must be unique")
    attempts = {t.key: 0 for t in tasks}
    outcomes: dict[str, Outcome] = {}
    waiting = deque(tasks)
    running: dict = {}  # future -> task
    run_id = uuid.uuid4().hex[:8]

    def submit(t: Task) -> None:
        attempts[t.key] += 1
        key = f"ncflow-{run_id}-{t.key}-{attempts[t.key]}"
        running[client.submit(_attempt, t.fn, t.arg, t.key, key=key, retries=0)] = t

    def finish(t: Task, record: dict) -> None:
        outcome = Outcome(
            t.key,
            "ok" if record["ok"] else "failed",
            attempts[t.key],
            float(record.get("seconds", 0.0)),
            None if record["ok"] else record["error"],
            record.get("value"),
            record.get("worker"),
        )
        outcomes[t.key] = outcome
        bar.update(1)
        if on_done is not None:
            with tqdm.external_write_mode():
                on_done(outcome)

    bar = tqdm(total=len(tasks), unit=unit, disable=None if progress else True, dynamic_ncols=True)
    try:
        while waiting or running:
            free = _free_slots(client, len(running)) if throttle else len(waiting)
            while waiting and free > 0:
                submit(waiting.popleft())
                free -= 1
            done = [f for f in running if f.done()]
            if not done:
                time.sleep(poll)  # tasks running, or no worker free yet (starting, restarting, none joined)
                continue
            for future in done:
                t = running.pop(future)
                record = _collect(future)
                future.release()
                if not record["ok"] and record.get("retry") and attempts[t.key] <= retries:
                    waiting.appendleft(t)
                else:
                    finish(t, record)
    except BaseException:
        with contextlib.suppress(Exception):
            client.cancel(list(running), force=True)
        raise
    finally:
        bar.close()
    return [outcomes[t.key] for t in tasks]
