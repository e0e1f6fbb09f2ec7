"""The matcher as plain steps (ncflow.matcher.steps): run one by one they give the result of ncflow.match bit
for bit, and a match may start from an earlier result (a warm start)."""

import dataclasses

import jax
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import ncflow
from ncflow.config import apply_overrides, preset, scale_steps
from ncflow.geometry.barycentric import surface_points
from ncflow.geometry.mesh import Mesh
from ncflow.matcher.place import Placed, place
from ncflow.matcher.placement import Placement
from ncflow.matcher.prepare import prepare
from ncflow.matcher.programs import build_programs
from ncflow.matcher.progress import Progress
from ncflow.matcher.result import build_result
from ncflow.matcher.steps import Matcher, WarmStart, run_keys
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


def test_a_short_warm_start_runs_on_the_programs_of_a_full_match(pair, config):
    """WarmStart(steps, lr) trains the last phase alone on the whole configuration's programs (shared with a
    full match: nothing compiled again) and ends where a match of a one-phase configuration of that phase
    ends, to float32 rounding (the two steps are programs of different data-term sets, compiled apart)."""
    src, tgt, skel = pair
    config = dataclasses.replace(config, flow=dataclasses.replace(config.flow, skinning_weights="current"))
    full = Matcher(src, tgt, skel, config, quiet=True)
    first = full.run()
    bent = Mesh(bend(src.vertices, 60.0), src.faces, "t2")
    steps, lr = 5, 2e-3
    start = WarmStart(first.state, first.placement, steps, lr)
    warm = Matcher(src, bent, skel, config, quiet=True, start=start, programs=full.programs)
    assert warm.programs is full.programs and [st.phase for st in warm.stages] == [len(config.phases) - 1] * len(
        warm.stages
    )
    assert sum(st.steps for st in warm.stages) == steps
    short = warm.run()
    last = config.phases[-1]
    phase = dataclasses.replace(last, name="warm", steps=steps, lr=min(lr, last.lr), warmup=min(last.warmup, 1))
    one_phase = dataclasses.replace(config, phases=(phase,))
    own = ncflow.match(src, bent, skel, one_phase, quiet=True, start=WarmStart(first.state, first.placement))
    np.testing.assert_allclose(short.deformed_source, own.deformed_source, atol=1e-5)
    # the same source points (a target vertex on a source vertex may name any face around it)
    points = [surface_points(src.vertices, src.faces, r.maps["map_face"], r.maps["map_bary"]) for r in (short, own)]
    np.testing.assert_allclose(points[0], points[1], atol=1e-5)
    assert short.metrics["phases"][-1]["data"] == pytest.approx(own.metrics["phases"][-1]["data"], rel=1e-4)
    assert np.abs(short.deformed_source - first.deformed_source).max() > 1e-3  # it trained
    assert short.frames.shape[0] == config.frames  # the configuration's output frames


def _fake_placed(setup, score: float) -> Placed:
    from ncflow.matcher.pose_search import PoseSearchResult
    from ncflow.skeleton.kinematics import rest_pose

    pose = rest_pose(setup.skeleton_normalized)
    return Placed(Placement.identity(), pose, PoseSearchResult(pose, score, 1.0, 1), (), 0.25, 1.5)


def test_a_suggested_skeleton_chosen_by_its_pose(pair, config, monkeypatch):
    """Without a skeleton and with ``skeleton_bases="choose"``, prepare suggests two (base joints on the limbs'
    first rings, and inside); the first is placed as ``place`` does, the second's pose searched at the first's
    placement alone (the target moved by it, no placement search), the one whose searched pose explains the
    target best kept with both scores recorded, and the other dropped; without a pose search the first is
    placed alone."""
    import ncflow.matcher.place as place_module
    from ncflow.matcher.place import place_suggested
    from ncflow.matcher.prepare import with_joints

    src, tgt, _ = pair
    assert prepare(src, tgt, None, config).alternatives == ()  # the default: the first way alone
    config = dataclasses.replace(config, skeleton_bases="choose")
    setup = prepare(src, tgt, None, config)
    assert len(setup.alternatives) == 1 and setup.skeleton_suggested["bases"] == "ring"
    assert setup.alternatives[0].skeleton_suggested["bases"] == "inside"
    turned = Placement(
        Rotation.from_euler("z", 90, degrees=True).as_matrix(), np.array([0.1, 0.0, 0.0]), 0.3, 0.5, True
    )
    scores = {"ring": 0.7, "inside": 0.4}
    calls = []

    def fake_place(s, cfg, message=None):
        calls.append((s.skeleton_suggested["bases"], cfg.placement, s.target_vertices))
        placed = _fake_placed(s, scores[s.skeleton_suggested["bases"]])
        return dataclasses.replace(placed, placement=turned) if cfg.placement == "auto" else placed

    monkeypatch.setattr(place_module, "place", fake_place)
    chosen, placed = place_suggested(setup, config)
    assert [c[:2] for c in calls] == [("ring", "auto"), ("inside", "none")]
    np.testing.assert_allclose(calls[0][2], setup.target_vertices)
    np.testing.assert_allclose(calls[1][2], turned.apply(setup.alternatives[0].target_vertices))
    assert placed.pose_search.score == 0.4 and placed.placement is turned
    assert placed.trials == ({"angle_degrees": pytest.approx(90.0), "rigid_score": 0.3, "pose_score": 0.4},)
    assert placed.pose_search_seconds == 2 * 1.5 and placed.placement_seconds == 2 * 0.25
    assert chosen.skeleton is setup.alternatives[0].skeleton and chosen.alternatives == ()
    np.testing.assert_allclose(chosen.target_vertices, setup.alternatives[0].target_vertices)
    info = chosen.skeleton_suggested
    assert info["bases"] == "inside"
    assert [(c["bases"], c["pose_score"]) for c in info["candidates"]] == [("ring", 0.7), ("inside", 0.4)]
    assert [c["n_joints"] for c in info["candidates"]] == [setup.skeleton.n_joints, chosen.skeleton.n_joints]
    scores["inside"] = 0.9
    kept, placed = place_suggested(setup, config)
    assert kept.skeleton is setup.skeleton and placed.placement is turned and placed.pose_search.score == 0.7
    calls.clear()
    off = dataclasses.replace(config, pose_search=False)
    first, _ = place_suggested(setup, off)
    assert [c[0] for c in calls] == ["ring"] and first is setup
    n = setup.alternatives[0].skeleton.n_joints
    if n != setup.skeleton.n_joints:
        assert with_joints(setup, n).skeleton is setup.alternatives[0].skeleton
    assert with_joints(setup, 10_000) is setup
