"""The part of each bone inside its mesh (ncflow.skeleton.checks.inside_axial_ranges), where its samples
and rigid core go, and the warning for bones mostly outside."""

import numpy as np
import pytest

from ncflow.skeleton import Skeleton
from ncflow.skeleton.checks import (
    AXIS_PROBES,
    bones_partly_outside,
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
