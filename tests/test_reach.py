"""The skin's stretch along each bone (ncflow.skeleton.reach) and the warning that names the bones the
skeleton did not reach (ncflow.matcher.result.bones_out_of_reach)."""

import numpy as np
from scipy.spatial.transform import Rotation

from ncflow.matcher.result import bones_out_of_reach
from ncflow.skeleton import Skeleton
from ncflow.skeleton.reach import skin_stretch, skin_vertices

# two bones along z (lengths 2 and 1.5) and a side bone along x (length 1)
POSITIONS = np.array([[0, 0, 0], [0, 0, 2.0], [0, 0, 3.5], [1.0, 0, 2.0]])
PARENTS = np.array([-1, 0, 1, 1])


def _skin(rng, n=60):
    """Vertices on cylinders of radius 0.1 around the middle 10 %–90 % of each bone, and their owners."""
    pts, owner = [], []
    for k, (a, b) in enumerate([(0, 1), (1, 2), (1, 3)]):
        pa, pb = POSITIONS[a], POSITIONS[b]
        e = (pb - pa) / np.linalg.norm(pb - pa)
        u = np.cross(e, [0.3, 0.5, 0.8])
        u /= np.linalg.norm(u)
        v = np.cross(e, u)
        t = rng.uniform(0.15, 0.85, n)
        ang = rng.uniform(0, 2 * np.pi, n)
        pts.append(pa + t[:, None] * (pb - pa) + 0.1 * (np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * v))
        owner.append(np.full(n, k))
    return np.concatenate(pts), np.concatenate(owner)


def test_skin_vertices_are_those_nearest_each_bone_away_from_its_ends():
    skel = Skeleton.from_arrays(POSITIONS, PARENTS)
    rest, owner = _skin(np.random.default_rng(0))
    np.testing.assert_array_equal(skin_vertices(rest, skel), owner)
    ends = np.array([[0, 0.1, 0.05], [0.05, 0.1, 3.45]])  # within 5 % of a bone's end
    np.testing.assert_array_equal(skin_vertices(ends, skel), [-1, -1])


def test_skin_stretch_is_the_scale_along_the_bone_whatever_the_rigid_motion():
    skel = Skeleton.from_arrays(POSITIONS, PARENTS)
    rng = np.random.default_rng(1)
    rest, owner = _skin(rng)
    axes = [np.array([0, 0, 1.0]), np.array([0, 0, 1.0]), np.array([1.0, 0, 0])]
    scales = [1.0, 1.4, 0.6]
    moved = rest.copy()
    for k, (s, e) in enumerate(zip(scales, axes, strict=True)):
        sel = owner == k
        c = rest[sel].mean(0)
        z = (rest[sel] - c) @ e
        local = rest[sel] - c + (s - 1.0) * z[:, None] * e  # stretched along the bone about the skin's centre
        turn = Rotation.from_rotvec(rng.normal(size=3))
        moved[sel] = turn.apply(local) + rng.normal(size=3)  # each skin its own rigid motion
    moved = 2.5 * moved + [1.0, -2.0, 0.5]  # a uniform scaling and shift of both changes nothing
    shift = np.array([1.0, -2.0, 0.5])
    got = skin_stretch(2.5 * rest + shift, moved, skel.with_positions(2.5 * POSITIONS + shift))
    # the best rotation of a stretched skin is the true one up to the asymmetry of its random vertices
    np.testing.assert_allclose(got, scales, rtol=1e-2)
    np.testing.assert_allclose(got, skin_stretch(rest, (moved - shift) / 2.5, skel), rtol=1e-9)
    # a skin of too few vertices cannot be told
    keep = np.concatenate([np.flatnonzero(owner != 2), np.flatnonzero(owner == 2)[:5]])
    got = skin_stretch(rest[keep], moved[keep], skel)
    assert np.isfinite(got[:2]).all() and np.isnan(got[2])


def test_bones_out_of_reach_are_named_most_changed_first():
    rows = [
        {"bone": "a -> b", "skin_stretch": 1.2},
        {"bone": "b -> c", "skin_stretch": 1.8},
        {"bone": "b -> d", "skin_stretch": 0.5},
        {"bone": "d -> e", "skin_stretch": None},
        {"bone": "e -> f", "skin_stretch": 1 / 1.5},  # at the limit: reached
    ]
    out, warning = bones_out_of_reach(rows, 1.5)
    assert out == [{"bone": "b -> d", "skin_stretch": 0.5}, {"bone": "b -> c", "skin_stretch": 1.8}]
    assert warning.startswith("the skeleton did not reach the target along 2 of 5 bones")
    assert "b -> d (× 0.50), b -> c (× 1.80)" in warning
    assert bones_out_of_reach(rows[:1] + rows[3:], 1.5) == ([], None)
