"""Bones that meet at a bend keep their samples out of each other's rigid core
(ncflow.skeleton.checks.clear_joint_ranges), checked against brute-force points of the sample cylinders."""

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

from ncflow.config import preset, validate_config
from ncflow.flow.bone_weights import CORE_CLEAR, core_clearance, core_memberships
from ncflow.geometry.mesh import Mesh
from ncflow.matcher.prepare import prepare
from ncflow.skeleton import Skeleton
from ncflow.skeleton.checks import AXIS_PROBES, clear_axial_ranges, clear_joint_ranges
from ncflow.synthetic.shapes import bend, capsule

CLEARANCE = core_clearance(1.0)


def _chain(lengths, bends_deg, scale=1.0, shift=(0.0, 0.0, 0.0)) -> Skeleton:
    """A chain from the origin along x, each next bone turned by its bend (degrees, about z)."""
    pos, d, heading = [np.zeros(3)], 0.0, 0.0
    for length, turn in zip(lengths, [0.0, *bends_deg], strict=True):
        heading += np.deg2rad(turn)
        pos.append(pos[-1] + length * np.array([np.cos(heading), np.sin(heading), 0.0]))
        d += length
    pos = np.array(pos) * scale + np.asarray(shift)
    return Skeleton.from_arrays(pos, np.arange(-1, len(lengths)))


def _cylinder(skel: Skeleton, b: int, lo_hi, radius: float, n: int, rng) -> np.ndarray:
    """n points uniform in bone b's sample cylinder over lo_hi (z / L) of radius factor ``radius``."""
    head = skel.positions[skel.parents[b + 1]]
    vec = skel.positions[b + 1] - head
    length = np.linalg.norm(vec)
    axis = vec / length
    u = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    z = rng.uniform(*lo_hi, n)
    r = radius * length * np.sqrt(rng.uniform(0, 1, n))
    a = rng.uniform(0, 2 * np.pi, n)
    return head + z[:, None] * vec + (r * np.cos(a))[:, None] * u + (r * np.sin(a))[:, None] * v


def _distance_to_part(x, skel, b, lo_hi) -> np.ndarray:
    head = skel.positions[skel.parents[b + 1]]
    vec = skel.positions[b + 1] - head
    t = np.clip((x - head) @ vec / (vec @ vec), *lo_hi)
    return np.linalg.norm(x - (head + t[:, None] * vec), axis=1)


def _gap(skel, ranges, radius, o, b, n=60_000) -> float:
    """The least distance of either bone's cylinder to the other's range, in units of that other's core
    radius (brute force): below CLEARANCE, a point of one lies in the other's core or the ramp it shares."""
    rng = np.random.default_rng(0)
    lengths = np.asarray(skel.bone_lengths)
    gaps = []
    for x, y in ((o, b), (b, o)):
        pts = _cylinder(skel, x, ranges[x], radius, n, rng)
        gaps.append(_distance_to_part(pts, skel, y, ranges[y]).min() / (radius * lengths[y]))
    return min(gaps)


def test_a_long_bone_bent_onto_a_short_one_gives_up_the_end_its_core_reaches_over():
    """A palm bone 1.92 long and a finger's first bone 0.5 long bent 104° at the knuckle, as in a fist: the
    palm's core, 0.19 thick, reaches over the finger's first part. Cutting the palm's end back costs it a
    smaller share than cutting the finger's start, so the palm's range ends earlier — as little earlier as
    the probes allow (a brute-force search over a fine grid agrees) — and the two keep clear."""
    skel = _chain([1.92, 0.5, 0.45], [104.0, 80.0])
    ranges = np.tile([0.1, 0.9], (3, 1))
    assert _gap(skel, ranges, 0.1, 0, 1) < 0.8  # deep in the palm's core before
    got = clear_joint_ranges(skel, ranges, np.full(3, 0.1), CLEARANCE)
    assert got[0, 0] == 0.1 and got[0, 1] < 0.9
    np.testing.assert_array_equal(got[1], [0.1, 0.9])  # the finger keeps its start; its end is its child's case
    assert _gap(skel, got, 0.1, 0, 1) >= CLEARANCE * 0.97
    # the brute-force least cut over a fine grid of the palm's end
    fine = [
        hi
        for hi in np.arange(0.9, 0.4, -0.0025)
        if _gap(skel, np.vstack([[0.1, hi], got[1:]]), 0.1, 0, 1, 8000) >= CLEARANCE
    ]
    spacing = 0.8 / (AXIS_PROBES - 1)
    assert fine[0] - spacing - 0.01 <= got[0, 1] <= fine[0] + 0.01


def test_equal_bones_bent_past_a_right_angle_cut_the_parent_and_a_straight_chain_stays_whole():
    skel = _chain([1.0, 1.0], [120.0])
    ranges = np.tile([0.1, 0.9], (2, 1))
    got = clear_joint_ranges(skel, ranges, np.full(2, 0.1), CLEARANCE)
    assert got[0, 1] < 0.9 and got[1, 0] == 0.1  # the same share either way: the parent yields
    assert _gap(skel, got, 0.1, 0, 1) >= CLEARANCE * 0.97
    for turn in (0.0, 30.0):  # clear already (straight: the cores' ends 0.2 apart, 0.136 needed)
        straight = _chain([1.0, 1.0], [turn])
        assert _gap(straight, ranges, 0.1, 0, 1) >= CLEARANCE
        np.testing.assert_array_equal(clear_joint_ranges(straight, ranges, np.full(2, 0.1), CLEARANCE), ranges)


@pytest.mark.parametrize(("turn", "lo"), [(110.0, 0.15), (120.0, 0.1), (130.0, 0.1), (130.0, 0.05)])
def test_a_tie_in_probe_steps_is_decided_by_steps_not_by_rounding(turn, lo):
    """Equal bones with the same range, bent symmetrically: either cut clears with the same number of probe
    steps and the same length, so the parent yields at every bend (comparing shares of the range as floats
    gave the child at 110° and 130°), by exactly whole probe steps, and the two then keep clear."""
    skel = _chain([1.0, 1.0], [turn])
    ranges = np.tile([lo, 1.0 - lo], (2, 1))
    got = clear_joint_ranges(skel, ranges, np.full(2, 0.1), CLEARANCE)
    np.testing.assert_array_equal(got[1], ranges[1])
    steps = (ranges[0, 1] - got[0, 1]) / ((ranges[0, 1] - ranges[0, 0]) / (AXIS_PROBES - 1))
    assert steps >= 1 and steps == pytest.approx(round(steps), abs=1e-9)
    assert _gap(skel, got, 0.1, 0, 1) >= CLEARANCE * 0.97


def test_joint_ranges_are_the_same_at_any_scale_and_placement_and_siblings_are_not_compared():
    ranges, radii = np.tile([0.1, 0.9], (3, 1)), np.full(3, 0.1)
    got = clear_joint_ranges(_chain([1.92, 0.5, 0.45], [104.0, 80.0]), ranges, radii, CLEARANCE)
    moved = clear_joint_ranges(
        _chain([1.92, 0.5, 0.45], [104.0, 80.0], 0.01, (3.0, -2.0, 5.0)), ranges, radii, CLEARANCE
    )
    np.testing.assert_allclose(moved, got)
    # two bones from one joint 10° apart overlap everywhere but move alike: left whole
    pos = np.array([[0, 0, 0], [1, 0, 0], [np.cos(0.17), np.sin(0.17), 0.0]])
    fan = Skeleton.from_arrays(pos, np.array([-1, 0, 0]))
    np.testing.assert_array_equal(clear_joint_ranges(fan, ranges[:2], radii[:2], CLEARANCE), ranges[:2])
    # a parent without a core (its axis outside the mesh) does not push its child away, but yields itself
    alone = clear_joint_ranges(
        _chain([1.92, 0.5, 0.45], [104.0, 80.0]), ranges, radii, CLEARANCE, np.array([False, True, True])
    )
    assert alone[0, 1] >= got[0, 1]


def test_the_clearance_is_where_a_cores_membership_falls_to_core_clear():
    """At core_clearance(ramp) core radii from a bone's range its membership (core_memberships, the
    field's) is CORE_CLEAR, for two ramps."""
    heads, tails = jnp.zeros((1, 3)), jnp.array([[1.0, 0.0, 0.0]])
    for ramp in (1.0, 0.5):
        c = core_clearance(ramp)
        x = jnp.array([[0.5, 0.1 * c, 0.0]])
        m = core_memberships(x, heads, tails, np.array([0.1]), np.array([0.1 * (1 + ramp)]), (0.1, 0.9))
        assert float(m[0, 0]) == pytest.approx(CORE_CLEAR, abs=1e-5)


def test_prepare_clears_the_joints_of_a_bent_source_unless_turned_off():
    """A capsule bent 110° in its middle with a two-bone skeleton along it: by default (``flow.clear_joints``)
    the matcher's bone ranges are clear_joint_ranges' of the ranges it has with the setting off, and they
    differ."""
    v, f = capsule(radius=0.4, length=3.0, n_around=24, n_along=48)
    v = bend(v, 110.0)
    a = np.deg2rad(110.0)
    pos = np.array([[0, 0, -1.4], [0, 0, 0], [0, np.sin(a) * 1.4, np.cos(a) * 1.4]])
    skel = Skeleton.from_arrays(pos, np.array([-1, 0, 1]))
    cfg = preset("fast")
    cfg = dataclasses.replace(cfg, weights=dataclasses.replace(cfg.weights, tissue=0.0))
    assert cfg.flow.clear_joints
    on = prepare(Mesh(v, f), Mesh(v, f), skel, validate_config(cfg))
    off_cfg = dataclasses.replace(cfg, flow=dataclasses.replace(cfg.flow, clear_joints=False))
    off = prepare(Mesh(v, f), Mesh(v, f), skel, validate_config(off_cfg))
    want = clear_joint_ranges(off.skeleton_normalized, off.bone_ranges, off.bone_radii, CLEARANCE, off.bone_inside > 0)
    np.testing.assert_allclose(on.bone_ranges, want)
    assert not np.allclose(on.bone_ranges, off.bone_ranges)
    np.testing.assert_allclose(
        off.bone_ranges, clear_axial_ranges(off.skeleton_normalized, off.bone_ranges, off.bone_radii)
    )
