"""The divergence guard of the training loop: rolls a stage back to its last healthy snapshot, at half
the learning rate, when the data term or the largest bone violation runs away
(``config.divergence_guard``).
"""

from __future__ import annotations

import numpy as np


class DivergenceGuard:
    """Watches a stage and rolls the optimisation back when it runs away.

    Two signals, each smoothed by an exponential moving average (weight ``smooth``) and compared
    with its best value in the stage (after ``settle`` steps, since a stage starts at a new σ):
    the data term d̄ (runs away when d̄ > ``factor``·best — the constraints overpowering the
    match) and the largest bone violation v̄ = max_k g_k/ε (runs away when v̄ > 5·``factor``·best
    and v̄ > ``min_violation`` — a bone torn apart, e.g. a finger drifting into a half-turn
    twist; watched from the second stage on, since the first starts from the identity flow,
    where every g_k is 0). While both are near their best (≤ 1.2·best) a snapshot of the state is taken every
    ``every`` steps. On a runaway :meth:`observe` answers ``"rollback"``: the caller restores
    :attr:`snapshot` and multiplies its learning rate by :attr:`lr_scale` (halved at each
    roll-back); after ``max_trips`` roll-backs in one stage it answers ``"stop"`` (restore and
    end the stage). A bone can also tear slowly, within the tolerance of a stage whose best was
    already poor: :meth:`end_stage` keeps the state each stage ended in, and when the run's last
    violation exceeds 5·``factor`` times the least violated earlier end (and ``min_violation``),
    :meth:`finish` hands back the latest earlier end within that bound (the most trained untorn
    state). ``factor`` = 0 disables it (always ``"ok"``).
    """

    def __init__(
        self,
        factor: float = 2.0,
        every: int = 20,
        smooth: float = 0.1,
        settle: int = 10,
        max_trips: int = 3,
        min_violation: float = 20.0,
    ):
        self.factor, self.every, self.smooth, self.settle = factor, every, smooth, settle
        self.max_trips, self.min_violation = max_trips, min_violation
        self.lr_scale = 1.0
        self.events: list[dict] = []
        self.ends: list[tuple[float, object, str]] = []
        self.start_stage(None)

    def start_stage(self, state, watch_violation: bool = True) -> None:
        """Reset for a new stage starting at ``state`` (the first snapshot)."""
        self.watch_violation = watch_violation
        self.ema: np.ndarray | None = None
        self.best = np.full(2, np.inf)
        self.seen = 0
        self.trips = 0
        self.snapshot = state
        self.snapshot_ema: np.ndarray | None = None

    def observe(self, data: float, state, step: int, violation: float = 0.0) -> str:
        """Feed the data term and the largest g_k/ε of the step just taken and the state after it."""
        if not self.factor:
            return "ok"
        x = np.array([data, violation], float)
        self.ema = x if self.ema is None else (1 - self.smooth) * self.ema + self.smooth * x
        self.seen += 1
        if self.seen <= self.settle:
            return "ok"
        self.best = np.minimum(self.best, self.ema)
        d, v = self.ema
        torn = self.watch_violation and v > 5 * self.factor * self.best[1] and v > self.min_violation
        if d > self.factor * self.best[0] or torn:
            self.trips += 1
            self.lr_scale *= 0.5
            self.events.append(
                {
                    "step": step,
                    "data_smoothed": float(d),
                    "data_best": float(self.best[0]),
                    "violation_smoothed": float(v),
                    "violation_best": float(self.best[1]),
                    "lr_scale": self.lr_scale,
                }
            )
            self.ema = self.snapshot_ema
            return "stop" if self.trips >= self.max_trips else "rollback"
        if self.seen % self.every == 0 and np.all(self.ema <= 1.2 * self.best):
            self.snapshot, self.snapshot_ema = state, self.ema
        return "ok"

    def end_stage(self, state, name: str) -> None:
        """Record the ``state`` stage ``name`` ended in and its smoothed largest violation."""
        if self.factor and self.ema is not None:
            self.ends.append((float(self.ema[1]), state, name))

    def finish(self, state, step: int):
        """The state the run outputs: ``state`` (the last stage's end), or the latest untorn earlier
        stage end when the last one's violation ran away (see the class docstring).
        """
        if len(self.ends) < 2:
            return state
        last, limit = self.ends[-1][0], 5 * self.factor * min(end[0] for end in self.ends[:-1])
        kept_violation, kept, name = [end for end in self.ends[:-1] if end[0] <= limit][-1]  # latest untorn end
        if last > limit and last > self.min_violation:
            self.events.append(
                {"step": step, "restored_stage_end": name, "violation_smoothed": last, "violation_best": kept_violation}
            )
            return kept
        return state
