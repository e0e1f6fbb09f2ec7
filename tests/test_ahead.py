"""Compiling ahead (:mod:`ncflow.jit.ahead`): the stand-ins have the targets' shapes, every program
the thread compiles is compiled once (the main thread's first call finds it), and the results are
those of a match without it, bit for bit.
"""

import logging
import threading

import jax
import numpy as np
import pytest

from ncflow.config import apply_overrides, preset, scale_steps
from ncflow.geometry.mesh import Mesh
from ncflow.jit.ahead import CompileAhead
from ncflow.matcher.place import place
from ncflow.matcher.prepare import prepare
from ncflow.matcher.stages import build_stages
from ncflow.matcher.steps import Matcher
from ncflow.matcher.targets import source_rows, target_measures, target_stand_ins
from ncflow.skeleton import Skeleton
from ncflow.synthetic.shapes import bend, capsule
from tiny import TINY as TINY_SETTINGS

TINY = [*TINY_SETTINGS, "jit_cache=none"]


def _pair():
    vs, fs = capsule(radius=0.4, length=3.0, n_around=9, n_along=12)
    vt, ft = capsule(radius=0.4, length=3.0, n_around=10, n_along=11, diagonal="left")
    skel = Skeleton.from_arrays(np.array([[0, 0, -1.6], [0, 0, 0.0], [0, 0, 1.6]]), np.array([-1, 0, 1]))
    return Mesh(vs, fs, "source"), Mesh(bend(vt, 50.0), ft, "target"), skel


@pytest.mark.parametrize("compress", ["150", "none"])
def test_target_stand_ins_have_the_shapes_of_the_target_measures(compress):
    """Compressed (to ``compress`` rows) and padded to a size bucket, for every stage's metric (the
    fast preset's Varifold and, on this coarse capsule, four-point Varifold stages): the same trees,
    shapes and dtypes."""
    src, tgt, skel = _pair()
    cfg = apply_overrides(preset("fast"), [*TINY, f"compress={compress}", "pose_search=false"])
    setup = prepare(src, tgt, skel, cfg)
    stages = build_stages(cfg, setup.working_edge)
    stand = target_stand_ins(setup, stages, cfg)  # before the target is placed: as the thread gets it
    real = target_measures(setup, place(setup, cfg), stages, cfg)
    assert stand.keys() == real.keys() and {k[0] for k in real} == {"varifold", "varifold-q4"}  # a coarse capsule
    for key, (y, _, _) in real.items():
        s = stand[key][0]
        assert jax.tree_util.tree_structure(s) == jax.tree_util.tree_structure(y)
        assert [(a.shape, a.dtype) for a in jax.tree_util.tree_leaves(s)] == [
            (a.shape, a.dtype) for a in jax.tree_util.tree_leaves(y)
        ]
        rows = y.measure.centers.shape[0]
        assert y.source_weights.shape == (source_rows(setup),) and np.all(np.asarray(y.source_weights) == 1.0)
        unpadded = tgt.faces.shape[0] if key[0] == "varifold" else setup.target_topology.n_edges
        assert rows == 150 if compress == "150" else rows > unpadded  # padded to the bucket above


def _compiles(records, name):
    return sum(f"Compiling jit({name})" in r.getMessage() for r in records)


@pytest.mark.parametrize("pose_search", [True, False])
def test_compiled_ahead_once_and_results_unchanged(caplog, pose_search):
    """With ``compile_ahead`` the thread compiles the step, the initialisation and both output
    programs, and the run compiles none of them again (its calls find the thread's executables);
    without it each is compiled at its first call. The outputs are identical bit for bit."""
    src, tgt, skel = _pair()
    sets = [*TINY, "compress=200", f"pose_search={str(pose_search).lower()}"]
    results, counts = {}, {}
    previous = jax.config.jax_log_compiles
    jax.config.update("jax_log_compiles", True)
    try:
        for ahead in (True, False):
            cfg = scale_steps(apply_overrides(preset("fast"), [*sets, f"compile_ahead={str(ahead).lower()}"]), 3)
            caplog.clear()
            with caplog.at_level(logging.WARNING):
                m = Matcher(src, tgt, skel, cfg, quiet=True)
                results[ahead] = m.run()
            counts[ahead] = {
                n: _compiles(caplog.records, n) for n in ("step", "initial_params", "output_flow", "output_refit")
            }
    finally:
        jax.config.update("jax_log_compiles", previous)
    assert counts[True] == counts[False] == {"step": 1, "initial_params": 1, "output_flow": 1, "output_refit": 1}
    assert results[True].metrics["compile_ahead"] == {"errors": {}}
    assert {"compile_ahead_training", "compile_ahead_outputs", "compile_ahead_wait"} <= set(
        results[True].metrics["timings"]
    )
    assert (
        results[False].metrics["compile_ahead"] is None
        and "compile_ahead_wait" not in results[False].metrics["timings"]
    )
    a, b = results[True], results[False]
    np.testing.assert_array_equal(a.frames, b.frames)
    np.testing.assert_array_equal(a.skeleton_frames, b.skeleton_frames)
    np.testing.assert_array_equal(a.maps["map_points"], b.maps["map_points"])
    assert a.metrics["phases"] == b.metrics["phases"]


def test_compile_ahead_records_failures_and_waits():
    """A job that raises is recorded and does not stop the next; :meth:`wait` returns once a job is done."""
    gate = threading.Event()
    ran = []

    def slow():
        gate.wait(10)
        ran.append("slow")

    def broken():
        raise ValueError("no such shape")

    ahead = CompileAhead([("broken", broken), ("slow", slow)])
    ahead.wait("broken")
    assert ahead.errors == {"broken": "ValueError: no such shape"} and ran == []
    gate.set()
    ahead.wait("slow")
    assert ran == ["slow"] and set(ahead.seconds) == {"broken", "slow"}
