"""The progress display of a match: phase, step, loss, largest bone violation and time left.

On a terminal a :mod:`tqdm` bar (one updating line, messages printed above it); on anything else
(a log file, a pipe, CI) plain lines, one every ~5 % of the steps, so logs stay readable; nothing
with ``quiet``.
"""

from __future__ import annotations

import sys
import time

from tqdm.auto import tqdm


class Progress:
    """Progress of ``total`` steps written to ``stream`` (default stderr).

    Args:
        total: number of steps.
        quiet: write nothing.
        stream: where to write; a terminal gets a tqdm bar, anything else plain lines.
    """

    def __init__(self, total: int, quiet: bool = False, stream=None):
        self.total = max(1, total)
        self.quiet = quiet
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.start = time.perf_counter()
        self.every = max(1, self.total // 20)
        self.bar = None

    def _bar(self):
        if self.bar is None:
            self.bar = tqdm(total=self.total, file=self.stream, dynamic_ncols=True, leave=True, unit="step")
        return self.bar

    def message(self, text: str) -> None:
        """One line of text (above the bar on a terminal)."""
        if self.quiet:
            return
        if self.tty and self.bar is not None:
            self.bar.write(text, file=self.stream)
        else:
            self.stream.write(text + "\n")
            self.stream.flush()

    def wants_update(self, done: int, last: bool = False) -> bool:
        """Whether step ``done`` should be reported (the caller then reads the loss off the device)."""
        return done % max(1, self.every // 4 or 1) == 0 or last or self.tty

    def update(self, done: int, phase: str, loss: float, violation: float) -> None:
        """Report step ``done`` of phase ``phase`` with its loss and largest g_k/ε."""
        if self.quiet:
            return
        if self.tty:
            bar = self._bar()
            bar.set_description_str(f"[{phase}]", refresh=False)
            bar.set_postfix_str(f"loss {loss:.4g}  max bone g/eps {violation:.3g}", refresh=False)
            bar.update(done - bar.n)
            return
        if done % self.every == 0 or done == self.total:
            elapsed = time.perf_counter() - self.start
            eta = elapsed / max(done, 1) * (self.total - done)
            self.stream.write(
                f"[{phase}] step {done}/{self.total}  loss {loss:.4g}  max bone g/eps {violation:.3g}  "
                f"elapsed {elapsed:.0f}s  ETA {eta:.0f}s\n"
            )
            self.stream.flush()

    def close(self) -> None:
        """End the bar (a no-op for plain lines)."""
        if self.bar is not None:
            self.bar.close()
            self.bar = None
