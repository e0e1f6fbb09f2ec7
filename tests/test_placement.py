"""Rigid placement of the target (ncflow.matcher.placement): any rotation, exact identity when in place."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ncflow.geometry.normalize import fit_normalization
from ncflow.matcher.place import close_call
from ncflow.matcher.placement import Placement, candidate_rotations, place_target, surface_diracs
from ncflow.synthetic.pairs import make_pair


@pytest.fixture(scope="module")
def pair():
    p = make_pair("humanoid", seed=2, resolution=36, target_resolution=32)
    norm = fit_normalization(p.source.vertices, p.source.faces)
    return norm.apply(p.source.vertices), p.source.faces, norm.apply(p.target.vertices), p.target.faces


def _rms(a, b):
    return float(np.sqrt(((a - b) ** 2).sum(1).mean()))


@pytest.mark.parametrize("degrees", [90.0, 180.0])
def test_turned_and_moved_target_lands_where_the_unturned_one_does(pair, degrees):
    s, fs, t, ft = pair
    ref = place_target(s, fs, t, ft).apply(t)
    axis = np.array([0.3, 0.8, -0.5]) / np.linalg.norm([0.3, 0.8, -0.5])
    r = Rotation.from_rotvec(np.radians(degrees) * axis).as_matrix()
    moved = t @ r.T + np.array([0.9, -0.5, 0.4])
    placement = place_target(s, fs, moved, ft)
    assert placement.moved
    # the same placed target up to the refinement's accuracy (the body is ~3 units tall)
    assert _rms(placement.apply(moved), ref) < 0.03
    # and it sits on the source: its centroid within a few hundredths of the source's
    assert np.linalg.norm(placement.apply(moved).mean(0) - ref.mean(0)) < 0.03


def test_target_in_place_is_left_exactly_alone(pair):
    s, fs, _, _ = pair
    placement = place_target(s, fs, s, fs)  # the source itself is in place
    assert not placement.moved
    np.testing.assert_array_equal(placement.rotation, np.eye(3))
    np.testing.assert_array_equal(placement.translation, np.zeros(3))
    assert placement.score == placement.identity_score > 0.7  # < 1: the two sides are sampled independently


def test_back_along_is_a_rigid_path_from_identity_to_the_inverse():
    rng = np.random.default_rng(0)
    r = Rotation.from_rotvec([0.4, -1.9, 0.7]).as_matrix()
    pl = Placement(r, np.array([0.3, -0.2, 1.1]), moved=True)
    pts = rng.normal(size=(50, 3))
    pivot = np.array([0.1, 0.2, -0.3])
    np.testing.assert_allclose(pl.back_along(pts, 0.0, pivot), pts, atol=1e-12)
    np.testing.assert_allclose(pl.back_along(pts, 1.0, pivot), pl.invert(pts), atol=1e-12)
    np.testing.assert_allclose(pl.invert(pl.apply(pts)), pts, atol=1e-12)
    d0 = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    for t in (0.25, 0.5, 0.8):
        q = pl.back_along(pts, t, pivot)
        np.testing.assert_allclose(np.linalg.norm(q[:, None] - q[None], axis=-1), d0, atol=1e-12)  # rigid


def test_candidates_are_rotations_and_cover_the_principal_axis_flips(pair):
    s, fs, t, ft = pair
    x, y = surface_diracs(s, fs, 500), surface_diracs(t, ft, 500)
    rots = candidate_rotations(x, y)
    assert rots.shape == (1 + 24 + 60, 3, 3)
    np.testing.assert_allclose(rots @ np.swapaxes(rots, 1, 2), np.broadcast_to(np.eye(3), rots.shape), atol=1e-6)
    np.testing.assert_allclose(np.linalg.det(rots), 1.0, atol=1e-6)
    # the icosahedral net: every rotation is within ~45° of one of its members
    probe = Rotation.random(200, random_state=1)
    net = Rotation.from_matrix(rots[25:])
    worst = max(min((p * n.inv()).magnitude() for n in net) for p in probe)
    assert np.degrees(worst) < 46.0


def test_placement_setting_values():
    from ncflow.config import apply_overrides, preset
    from ncflow.errors import InputError

    assert preset("fast").placement == "auto" and preset("paper").placement == "auto"
    assert apply_overrides(preset("fast"), ["placement=none"]).placement == "none"
    with pytest.raises(InputError, match="placement"):
        apply_overrides(preset("fast"), ["placement=sideways"])


def test_placement_candidates_start_with_the_target_as_given_and_include_the_true_turn(pair):
    """The articulated search chooses among these: the identity must be there exactly (a standing
    figure must not be turned by its swung limbs), and so must the inverse of a real turn."""
    from ncflow.matcher.placement import placement_candidates

    s, fs, t, ft = pair
    axis = np.array([0.3, 0.8, -0.5]) / np.linalg.norm([0.3, 0.8, -0.5])
    turn = Rotation.from_rotvec(np.radians(150.0) * axis)
    moved = t @ turn.as_matrix().T + np.array([0.9, -0.5, 0.4])
    cands = placement_candidates(s, fs, moved, ft, count=3, min_relative_score=0.0)
    assert 1 <= len(cands) <= 3
    assert not cands[0].moved
    np.testing.assert_array_equal(cands[0].rotation, np.eye(3))
    np.testing.assert_array_equal(cands[0].translation, np.zeros(3))
    rots = [Rotation.from_matrix(c.rotation) for c in cands]
    # one of them is the rigid fit of the unturned target composed with the undone turn (the rigid fit
    # of an articulated pair is itself ~20° off the identity: the limbs pull it)
    ref = Rotation.from_matrix(place_target(s, fs, t, ft).rotation)
    assert min(np.degrees((r * turn * ref.inv()).magnitude()) for r in rots[1:]) < 5.0
    # and they are distinct
    for i in range(len(rots)):
        for j in range(i):
            assert np.degrees((rots[i] * rots[j].inv()).magnitude()) >= 10.0


def test_placement_candidates_leave_out_poor_rigid_fits(pair):
    """Refined fits scoring below ``min_relative_score`` × the best are not worth a pose search; the
    target as given is always kept."""
    from ncflow.matcher.placement import placement_candidates

    s, fs, t, ft = pair
    every = placement_candidates(s, fs, t, ft, count=6, min_relative_score=0.0)
    best = max(c.score for c in every)
    poor = [c.score for c in every[1:] if c.score < 0.8 * best]
    assert poor  # a body turned around fits rigidly worse: something to leave out
    kept = placement_candidates(s, fs, t, ft, count=6)
    assert not kept[0].moved and np.isclose(kept[0].score, every[0].score)
    assert [c.score for c in kept[1:]] == [c.score for c in every[1:] if c.score >= 0.8 * best]


def _turned(degrees, axis=(0.0, 1.0, 0.0)):
    r = Rotation.from_rotvec(np.radians(degrees) * np.asarray(axis)).as_matrix()
    return Placement(rotation=r, translation=np.zeros(3), score=0.5, identity_score=0.5, moved=True)


@pytest.mark.parametrize(
    "angles, scores, expected",
    [
        ((0, 165), (0.55, 0.547), [0, 1]),  # front and back within 3 %: searched again
        ((0, 31, 165), (0.5546, 0.5545, 0.5477), [0, 1, 2]),  # every near one, the same facing's too
        ((0, 165), (0.55, 0.50), []),  # the back clearly better
        ((0, 30), (0.50, 0.505), []),  # one facing, two nearby turns
        ((0,), (0.5,), []),
    ],
)
def test_a_close_call_is_two_facings_whose_pose_scores_nearly_tie(angles, scores, expected):
    assert close_call([_turned(a) for a in angles], list(scores)) == expected
