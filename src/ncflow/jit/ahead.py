"""Compile ahead: the training step and the output programs are compiled in a background thread
while the target is placed and the skeleton's pose searched (beyond the paper).

Most of a short match is compilation, and neither XLA's compiler nor the pose search keeps both
cores of a small machine busy (each alone about 1.6 of 2; measured in ``benchmarks/RESULTS.md``).
Everything the compiled programs depend on — the working source, the skeleton, the tissue
centroids, the shapes of the target measures, the configuration — is known before the target is
placed (:func:`~ncflow.matcher.prepare.prepare`'s ``before_search``), so the programs are built then
(:class:`~ncflow.matcher.train.TrainingPrograms`, :class:`~ncflow.matcher.result.OutputPrograms`) and a
thread lowers and compiles them (``lower(...).compile()``) for stand-ins of the arguments they will
get (:func:`~ncflow.matcher.targets.target_stand_ins`). That fills the caches a call fills, so the
first real call finds its executable; with the persistent compilation cache on, a warm run's
thread reads them back from disk instead. Nothing is run: the results are those of a match without
it, bit for bit. A failure in the thread is recorded (``metrics.json``: ``compile_ahead.errors``;
the thread's seconds per job are under ``timings``) and the program is then compiled when first
called, as without it.

Written by hand: JAX compiles on the calling thread, and no library schedules ahead-of-time
compilation of programs whose arguments do not exist yet.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable


class CompileAhead:
    """Run ``jobs`` (name, function without arguments) in turn in one background thread.

    :meth:`wait` blocks until a job is done (or failed); ``seconds`` and ``errors`` (job → message)
    say how each went. The thread is not a daemon: an interpreter that exits waits for the
    compilation under way rather than tearing XLA down beneath it.
    """

    def __init__(self, jobs: list[tuple[str, Callable[[], object]]]):
        self._done = {name: threading.Event() for name, _ in jobs}
        self.seconds: dict[str, float] = {}
        self.errors: dict[str, str] = {}
        self._thread = threading.Thread(target=self._run, args=(jobs,), name="ncflow-compile-ahead")
        self._thread.start()

    def _run(self, jobs) -> None:
        for name, job in jobs:
            t0 = time.perf_counter()
            try:
                job()
            except Exception as exc:  # the program is then compiled at its first call, as without the thread
                self.errors[name] = f"{type(exc).__name__}: {exc}"
            finally:
                self.seconds[name] = time.perf_counter() - t0
                self._done[name].set()

    def wait(self, name: str) -> float:
        """Block until job ``name`` has finished; returns the seconds waited."""
        t0 = time.perf_counter()
        self._done[name].wait()
        return time.perf_counter() - t0
