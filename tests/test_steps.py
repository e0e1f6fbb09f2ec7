"""The matcher as plain steps (ncflow.matcher.steps): run one by one they give the result of ncflow.match bit
for bit, and a match may start from an earlier result (a warm start)."""

import dataclasses

import jax
import numpy as np
import pytest

import ncflow
from ncflow.config import apply_overrides, preset, scale_steps
from ncflow.geometry.mesh import Mesh
from ncflow.matcher.place import Placed, place
from ncflow.matcher.prepare import prepare
from ncflow.matcher.programs import build_programs
from ncflow.matcher.progress import Progress
from ncflow.matcher.result import build_result
from ncflow.matcher.steps import run_keys
from ncflow.matcher.targets import target_measures
from ncflow.matcher.train import train
from ncflow.skeleton import Skeleton
from ncflow.synthetic.shapes import bend, capsule
from tiny import TINY as TINY_SETTINGS

TINY = [*TINY_SETTINGS, "compress=200"]


@pytest.fixture(scope="module")
def pair():
    vs, fs = capsule(radius=0.4, length=3.0, n_around=9, n_along=12)
    skel = Skeleton.from_arrays(np.array([[0, 0, -1.6], [0, 0, 0.0], [0, 0, 1.6]]), np.array([-1, 0, 1]))
    return Mesh(vs, fs, "source"), Mesh(bend(vs, 50.0), fs, "target"), skel


@pytest.fixture(scope="module")
def config():
    return scale_steps(apply_overrides(preset("fast"), TINY), 6)


def test_the_steps_one_by_one_are_the_match(pair, config):
    src, tgt, skel = pair
    whole = ncflow.match(src, tgt, skel, config, quiet=True)
    keys = run_keys(config.seed)
    setup = prepare(src, tgt, skel, config)
    programs = build_programs(setup, config, keys)
    placed = place(setup, config)
    targets = target_measures(setup, placed, list(programs.stages), config)
    progress = Progress(config.total_steps, quiet=True)
    trained = train(
        programs.training,
        setup.skeleton_normalized,
        targets,
        list(programs.stages),
        config,
        keys[:2],
        progress,
        placed.initial_pose,
    )
    assert trained.steps == config.total_steps and len(trained.history) == len(programs.stages)
    steps = build_result(setup, placed, trained, programs, targets, config, keys[2], {"setup": 0.0, "train": 0.0})
    np.testing.assert_array_equal(steps.deformed_source, whole.deformed_source)
    np.testing.assert_array_equal(steps.maps["map_bary"], whole.maps["map_bary"])
    np.testing.assert_array_equal(steps.skeleton_frames, whole.skeleton_frames)
    # every metric is assembled by build_result: the same keys as the match's, timings aside
    assert steps.metrics.keys() == whole.metrics.keys()
    assert {"pose_search", "placement_trials", "setup_cache", "compile_ahead", "rollbacks"} <= set(steps.metrics)
    assert steps.metrics["constraints"] == whole.metrics["constraints"]


def test_a_match_starts_from_an_earlier_result(pair, config):
    src, tgt, skel = pair
    first = ncflow.match(src, tgt, skel, config, quiet=True)
    assert first.state is not None and first.metrics["pose_search"] is not None
    # not a step of training: the warm start's field is the earlier one, so the flow is too
    frozen = dataclasses.replace(
        config, phases=tuple(dataclasses.replace(p, lr=0.0, lr_end=None) for p in config.phases)
    )
    again = ncflow.match(src, tgt, skel, frozen, quiet=True, start=first)
    np.testing.assert_allclose(again.deformed_source, first.deformed_source, atol=1e-6)
    assert again.placement == first.placement
    assert again.metrics["pose_search"] is None and again.metrics["placement_trials"] == []
    leaves = jax.tree_util.tree_leaves(again.state.params)
    np.testing.assert_array_equal(np.asarray(leaves[0]), np.asarray(jax.tree_util.tree_leaves(first.state.params)[0]))
    # with training it goes on from there: a second target a little further bent
    more = ncflow.match(src, Mesh(bend(src.vertices, 60.0), src.faces, "t2"), skel, config, quiet=True, start=first)
    assert np.isfinite(more.deformed_source).all()
    assert np.abs(more.deformed_source - first.deformed_source).max() > 1e-4
    assert Placed.of_result(first).initial_pose is first.state.pose
