"""The part of each bone inside its mesh (ncflow.skeleton.checks.inside_axial_ranges) and clear of other bones
(clear_axial_ranges), where its samples and rigid core go, and the warning for bones mostly outside."""

import numpy as np
import pytest

from ncflow.skeleton import Skeleton
from ncflow.skeleton.checks import (
    AXIS_PROBES,
    bones_partly_outside,
    clear_axial_ranges,
    flesh_radius,
    inside_axial_ranges,
    skin_vertices,
)
from ncflow.synthetic.shapes import capsule


def _capsule_and_skeleton():
    """A capsule along z over [−1.9, 1.9] (radius 0.4) and a skeleton of four bones: one from below the
    capsule (z = −3.9) up to its middle, one inside, one from the middle out sideways to x = 2.5, and one
    entirely beside the capsule.
    """
    v, f = capsule(radius=0.4, length=3.0, n_around=24, n_along=24)
    pos = np.array([[0, 0, -3.9], [0, 0, 0.0], [0, 0, 1.5], [2.5, 0, 0.0], [2.5, 0, 1.0]])
    return v, f, Skeleton.from_arrays(pos, np.array([-1, 0, 1, 1, 3]))


def test_each_bone_keeps_the_part_of_its_axis_inside_the_mesh():
    v, f, skel = _capsule_and_skeleton()
    ranges, inside = inside_axial_ranges(skel, v, f)
    z = np.linspace(0.1, 0.9, AXIS_PROBES)
    half = 0.5 * (z[1] - z[0])
    # bone 0 runs from z = −3.9 to 0: inside above z = −1.9, that is from a share 2/3.9 of its length
    cut = 2.0 / 3.9
    first = z[np.argmax(z >= cut)]
    np.testing.assert_allclose(ranges[0], [first - half, 0.9])
    assert inside[0] == pytest.approx(np.mean(z >= cut))
    np.testing.assert_allclose(ranges[1], [0.1, 0.9])  # inside: the default range
    assert inside[1] == 1.0
    # bone 2 leaves the capsule at x = 0.4, a share 0.16 of its length: the probes at 0.1 and 0.15 are inside
    np.testing.assert_allclose(ranges[2], [0.1, 0.15 + half])
    assert inside[2] == pytest.approx(2 / AXIS_PROBES)
    np.testing.assert_allclose(ranges[3], [0.1, 0.9])  # outside: the default range, share 0
    assert inside[3] == 0.0
    lines = bones_partly_outside(skel, inside)
    assert len(lines) == 3
    assert f"outside the source over {1 - inside[0]:.0%} of its length" in lines[0]
    assert "joint 1 -> joint 3 lies outside the source over 88% of its length" in lines[1]
    assert lines[2].endswith(
        "joint 3 -> joint 4 lies outside the source: nothing of it holds flesh, its samples lie in empty space"
    )
    assert bones_partly_outside(skel, np.ones(4)) == []


def test_flesh_radius_is_how_far_each_bones_skin_lies_from_it():
    v, f, skel = _capsule_and_skeleton()
    flesh = flesh_radius(skel, v)
    rings = np.linalg.norm(v[:, :2], axis=1)
    assert rings.max() == pytest.approx(0.4)  # the capsule's rings: radius 0.4 about the z axis
    assert flesh[1] == pytest.approx(0.4)  # bone 1 runs along the axis, inside: its skin is the rings
    assert 0.0 < flesh[0] < 0.4  # bone 0 runs on into the lower cap, whose skin comes closer
    assert np.isinf(flesh[3])  # no skin is nearest to the bone beside the capsule
    # brute force for bone 1: the 10th percentile of its own vertices' distances to the z axis
    own = skin_vertices(v, skel) == 1
    assert flesh[1] == pytest.approx(np.percentile(rings[own], 10))


def _pinch(gap: float, scale: float = 1.0, shift=(0.0, 0.0, 0.0)):
    """Two chains off a root at the origin, like a pinch's thumb and index: 0 → 1 → 2 along x (the second
    bone over x ∈ [1, 2]) and 0 → 3 → 4, whose last bone comes down the line x = 1.8 to ``gap`` above the
    first chain's axis (z = 0)."""
    pos = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [1.8, 0, 1.5], [1.8, 0, gap]], float) * scale + shift
    return Skeleton.from_arrays(pos, np.array([-1, 0, 1, 0, 3]))


def test_bones_whose_sample_cylinders_overlap_keep_only_their_clear_parts():
    """Bone 1 → 2 (the probe at share z of it is (1 + z, 0, 0)) and bone 3 → 4 (1.5 long, down x = 1.8 to the
    first one's axis; the probe at z is (1.8, 0, 1.5 − 1.5 z)) of two chains, radii 0.1·L each: a probe of
    one touches the other where it is nearer than the two radii together to the other's axis over its
    range [0.1, 0.9]; each keeps the longest run of probes that do not touch, the bones of one chain (sharing
    a joint) and the far bones keep their ranges."""
    skel = _pinch(0.0)
    ranges = np.tile([0.1, 0.9], (4, 1))
    lengths = np.asarray(skel.bone_lengths)
    got = clear_axial_ranges(skel, ranges, np.full(4, 0.1))
    reach = 0.1 * lengths[1] + 0.1 * lengths[3]  # 0.1 + 0.15
    z = np.linspace(0.1, 0.9, AXIS_PROBES)
    low = 1.5 - 0.9 * 1.5  # the lowest point of bone 3 → 4's range, above (1.8, 0, 0)
    d1 = np.hypot(1 + z - 1.8, low)
    assert (d1 < reach).any() and (d1 >= reach).any()
    np.testing.assert_allclose(got[1], [0.1, z[(d1 >= reach) & (z < 0.8)].max()])
    d3 = 1.5 - 1.5 * z  # over x ∈ [1.1, 1.9], bone 1 → 2's range: straight down
    np.testing.assert_allclose(got[3], [0.1, z[d3 >= reach].max()])
    np.testing.assert_allclose(got[[0, 2]], ranges[[0, 2]])


def test_clear_ranges_are_the_same_at_any_scale_and_placement_and_leave_apart_bones_alone():
    skel = _pinch(0.0)
    ranges, radii = np.tile([0.1, 0.9], (4, 1)), np.full(4, 0.1)
    got = clear_axial_ranges(skel, ranges, radii)
    assert (got != ranges).any()
    moved = clear_axial_ranges(_pinch(0.0, scale=0.01, shift=(3.0, -2.0, 5.0)), ranges, radii)
    np.testing.assert_allclose(moved, got)
    apart = clear_axial_ranges(_pinch(0.6), ranges, radii)  # 0.69 apart at the closest, the radii 0.19
    np.testing.assert_array_equal(apart, ranges)
    narrow = clear_axial_ranges(skel, ranges, np.full(4, 0.02))  # thinner cylinders: clear again
    np.testing.assert_array_equal(narrow, ranges)
    # a bone's range is what it measures against: the other bone cut short of the contact leaves it whole
    short = ranges.copy()
    short[3] = [0.1, 0.5]
    np.testing.assert_array_equal(clear_axial_ranges(skel, short, radii)[1], ranges[1])


def test_clear_ranges_in_blocks_of_bones_are_the_same(monkeypatch):
    """A bone at a time (a skeleton of many bones is probed in blocks) gives the ranges of one block."""
    import ncflow.skeleton.checks as checks

    skel, ranges, radii = _pinch(0.0), np.tile([0.1, 0.9], (4, 1)), np.full(4, 0.1)
    whole = clear_axial_ranges(skel, ranges, radii)
    monkeypatch.setattr(checks, "_CLEAR_CHUNK", 1)
    np.testing.assert_array_equal(clear_axial_ranges(skel, ranges, radii), whole)
