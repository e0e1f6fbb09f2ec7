"""The divergence guard of the training loop (matcher.DivergenceGuard)."""

import numpy as np

from ncflow.matcher.guard import DivergenceGuard


def _feed(guard, values, start=0):
    verdicts = []
    for i, v in enumerate(values):
        verdicts.append(guard.observe(float(v), ("state", start + i + 1), start + i + 1))
    return verdicts


def test_a_falling_data_term_never_trips_and_snapshots_follow():
    g = DivergenceGuard(2.0, every=5, smooth=0.5, settle=3)
    g.start_stage(("state", 0))
    values = (1.0 + 0.2 * np.sin(np.arange(40))) / (1.0 + 0.1 * np.arange(40))  # noisy decrease, 20 % noise
    assert set(_feed(g, values)) == {"ok"}
    assert g.lr_scale == 1.0 and g.events == []
    assert g.snapshot[1] % 5 == 0 and g.snapshot[1] >= 35  # snapshots taken on the every-5 grid


def test_a_runaway_rolls_back_to_the_last_healthy_snapshot_and_halves_the_rate():
    g = DivergenceGuard(2.0, every=5, smooth=1.0, settle=0)  # smooth=1: the average is the value
    g.start_stage(("state", 0))
    verdicts = _feed(g, [1.0] * 10 + [1.5, 1.9, 2.1])
    assert verdicts[:12] == ["ok"] * 12 and verdicts[12] == "rollback"
    assert g.snapshot == ("state", 10)  # step 15 was never reached; 1.5 > 1.2 best blocks no snapshot here
    assert g.lr_scale == 0.5
    assert g.events == [
        {
            "step": 13,
            "data_smoothed": 2.1,
            "data_best": 1.0,
            "violation_smoothed": 0.0,
            "violation_best": 0.0,
            "lr_scale": 0.5,
        }
    ]
    # after two more trips in the same stage it asks to stop
    assert _feed(g, [2.5], 13) == ["rollback"]
    assert _feed(g, [2.5], 14) == ["stop"]
    assert g.lr_scale == 0.125
    # a new stage forgets the best value (a new σ) but keeps the reduced rate
    g.start_stage(("state", 99))
    assert _feed(g, [5.0, 5.0]) == ["ok", "ok"] and g.lr_scale == 0.125


def test_a_torn_bone_rolls_back_even_when_the_data_term_is_fine():
    g = DivergenceGuard(2.0, every=5, smooth=1.0, settle=0, min_violation=20.0)
    g.start_stage(("state", 0))
    verdicts = [g.observe(1.0, ("state", i + 1), i + 1, v) for i, v in enumerate([3.0] * 10 + [25.0, 31.0])]
    # 25 < 5·2·3 = 30 is tolerated, 31 is not
    assert verdicts == ["ok"] * 11 + ["rollback"] and g.snapshot == ("state", 10)
    # a large violation relative to a small best, but below the absolute floor, is tolerated
    g2 = DivergenceGuard(2.0, every=5, smooth=1.0, settle=0, min_violation=20.0)
    g2.start_stage(None)
    assert [g2.observe(1.0, None, i, v) for i, v in enumerate([0.5] * 5 + [15.0])] == ["ok"] * 6
    # the first stage (identity flow at the start, every g = 0) does not watch the violation
    g2.start_stage(None, watch_violation=False)
    assert [g2.observe(1.0, None, i, v) for i, v in enumerate([0.5] * 5 + [60.0])] == ["ok"] * 6


def test_settle_steps_are_ignored_and_factor_zero_disables():
    g = DivergenceGuard(2.0, every=5, smooth=1.0, settle=3)
    g.start_stage(("state", 0))
    assert _feed(g, [0.01, 1.0, 1.0, 1.0, 1.0]) == ["ok"] * 5  # the first 3 values set no best
    off = DivergenceGuard(0.0)
    off.start_stage(None)
    assert set(_feed(off, [1.0, 100.0, 1e6])) == {"ok"}


def test_a_slow_tear_in_the_last_stage_hands_back_the_latest_untorn_stage_end():
    g = DivergenceGuard(2.0, every=5, smooth=1.0, settle=2, min_violation=20.0)
    stages = {
        "varifold": [0.5] * 10 + [2.0] * 5,  # ends at 2: the least violated end
        "nc 0.25": [6.0] * 10 + [5.0] * 5,  # ends at 5 (within 10x of 2): the latest untorn end
        "nc 0.1": [30.0 + 20.0 * i for i in range(15)],  # best 70 after settling: 310 is within 10x of it
    }
    for name, violations in stages.items():
        g.start_stage(("start", name), watch_violation=name != "varifold")
        assert [g.observe(1.0, ("in", name), i, v) for i, v in enumerate(violations)] == ["ok"] * 15
        g.end_stage(("end", name), name)
    assert g.finish(("end", "nc 0.1"), 45) == ("end", "nc 0.25")
    restored = {"step": 45, "restored_stage_end": "nc 0.25", "violation_smoothed": 310.0, "violation_best": 5.0}
    assert g.events == [restored]
    # an end torn itself is passed over for an earlier one
    g = DivergenceGuard(2.0, smooth=1.0, settle=0, min_violation=20.0)
    for name, v in (("a", 2.0), ("b", 25.0), ("c", 300.0)):
        g.start_stage(None)
        g.observe(1.0, None, 1, v)
        g.end_stage(("end", name), name)
    assert g.finish(("end", "c"), 3) == ("end", "a")


def test_finish_keeps_the_last_state_unless_it_tore():
    def run(last_violation, factor=2.0):
        g = DivergenceGuard(factor, smooth=1.0, settle=0, min_violation=20.0)
        for name, v in (("a", 3.0), ("b", last_violation)):
            g.start_stage(None)
            g.observe(1.0, None, 1, v)
            g.end_stage(("end", name), name)
        return g.finish(("end", "b"), 2), g.events

    assert run(29.0) == (("end", "b"), [])  # below 5·2·3 = 30
    assert run(31.0)[0] == ("end", "a")
    assert run(15.0)[0] == ("end", "b")  # ten times worse would be 30; and below the 20 floor anyway
    assert run(1e3, factor=0.0) == (("end", "b"), [])  # the guard off
