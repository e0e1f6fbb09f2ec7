"""Bone samples: geometry (cylinders, axial range, axis share), distribution, keys, motion."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats
from scipy.spatial.transform import Rotation

from ncflow.skeleton import Pose, Skeleton, bone_motions, interpolate_joints, move_bone_points, sample_bones
from ncflow.skeleton.samples import n_axis_samples

POS = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 2.0, 0.5], [0.7, 1.5, 0.0], [1.2, 2.0, 0.1], [-0.6, -0.4, 0.2]])
PAR = np.array([-1, 0, 1, 1, 3, 0])
RADII = np.array([np.nan, 0.05, np.nan, 0.2, np.nan, 0.15])  # per child joint; NaN = default 0.1
SKEL = Skeleton.from_arrays(POS, PAR, radii=RADII)
RHO = np.array([0.05, 0.1, 0.2, 0.1, 0.15])  # per bone

draw = jax.jit(lambda key: sample_bones(SKEL, key).points)


def cylinder_coords(points, start, end):
    """Axial fraction z/L and radial distance of points (B, n, 3) w.r.t. segments start→end (B, 3)."""
    axis = end - start
    length = np.linalg.norm(axis, axis=1)
    rel = points - start[:, None, :]
    z = np.einsum("bni,bi->bn", rel, axis) / length[:, None] ** 2
    radial = np.linalg.norm(rel - z[..., None] * axis[:, None, :], axis=-1)
    return z, radial, length


def test_samples_lie_in_their_cylinders_with_20_percent_on_axis():
    s = sample_bones(SKEL, jax.random.key(0))
    pts = np.asarray(s.points)
    assert pts.shape == (5, 50, 3)
    assert s.on_axis.sum() == 10 and np.all(s.on_axis[:10]) and not np.any(s.on_axis[10:])
    z, radial, length = cylinder_coords(pts, POS[PAR[1:]], POS[1:])
    assert np.all(z >= 0.1 - 1e-12) and np.all(z <= 0.9 + 1e-12)
    assert np.all(radial <= RHO[:, None] * length[:, None] + 1e-12)
    # axis samples: on the axis, evenly spaced over 10 %-90 %
    np.testing.assert_allclose(radial[:, :10], 0.0, atol=1e-14)
    np.testing.assert_allclose(z[:, :10], np.broadcast_to(np.linspace(0.1, 0.9, 10), (5, 10)), atol=1e-14)
    # the others fill the cylinder: off the axis, out to near the radius
    assert np.all(radial[:, 10:] > 0)
    assert np.all(radial[:, 10:].max(axis=1) > 0.7 * RHO * length)
    np.testing.assert_allclose(pts, np.asarray(draw(jax.random.key(0))), atol=1e-14)  # jit: same up to FMA rounding


def test_explicit_radius_and_ranges():
    s = sample_bones(SKEL, jax.random.key(1), 20, radius=0.3, axis_fraction=0.25, axial_range=(0.2, 0.5))
    z, radial, length = cylinder_coords(np.asarray(s.points), POS[PAR[1:]], POS[1:])
    assert s.on_axis.sum() == 5
    assert np.all((z > 0.2 - 1e-12) & (z < 0.5 + 1e-12))
    assert np.all(radial <= 0.3 * length[:, None] + 1e-12)
    assert radial.max() > 0.2 * length.min()  # radius 0.3 is used, not the skeleton's per-bone values
    per_bone = np.array([0.01, 0.02, 0.03, 0.04, 0.05])
    s = sample_bones(SKEL, jax.random.key(1), 20, radius=per_bone)
    _, radial, length = cylinder_coords(np.asarray(s.points), POS[PAR[1:]], POS[1:])
    assert np.all(radial <= per_bone[:, None] * length[:, None] + 1e-12)
    assert [n_axis_samples(n) for n in (2, 5, 10, 50, 51, 100)] == [2, 2, 2, 10, 10, 20]
    with pytest.raises(ValueError):
        sample_bones(SKEL, jax.random.key(0), 1)


def test_keys_reproduce_and_differ():
    a = np.asarray(draw(jax.random.key(3)))
    b = np.asarray(draw(jax.random.key(3)))
    c = np.asarray(draw(jax.random.key(4)))
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a[:, :10], c[:, :10])  # axis samples are deterministic
    assert np.all(np.linalg.norm(a[:, 10:] - c[:, 10:], axis=-1) > 0)  # every random sample is new
    # a split key (the "fresh each step" use) gives yet other samples
    d = np.asarray(draw(jax.random.split(jax.random.key(3))[1]))
    assert np.all(np.linalg.norm(a[:, 10:] - d[:, 10:], axis=-1) > 0)


def test_random_samples_are_uniform_in_the_cylinder():
    arm = Skeleton.from_arrays([[0.0, 0, 0], [0.3, 1.8, -0.6]], [-1, 0])
    s = sample_bones(arm, jax.random.key(7), 4000, axis_fraction=0.0)  # at least 2 on the axis
    pts = np.asarray(s.points)[0, 2:]
    (z,), (radial,), (length,) = (x for x in cylinder_coords(pts[None], arm.positions[:1], arm.positions[1:]))
    r_max = 0.1 * length
    assert stats.kstest((z - 0.1) / 0.8, "uniform").pvalue > 1e-3
    assert stats.kstest((radial / r_max) ** 2, "uniform").pvalue > 1e-3  # uniform over the disc
    e1 = (arm.positions[1] - arm.positions[0]) / length
    u = np.cross(e1, [1.0, 0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(e1, u)
    ang = np.arctan2(pts @ v, pts @ u)  # the angle in an independent perpendicular frame
    assert stats.kstest((ang + np.pi) / (2 * np.pi), "uniform").pvalue > 1e-3


def test_moved_samples_stay_in_the_moved_cylinders():
    rng = np.random.default_rng(0)
    q = Rotation.from_rotvec(rng.normal(size=(6, 3))).as_quat(scalar_first=True)
    pose = Pose(jnp.asarray(q), jnp.asarray([0.3, -0.2, 1.0]))

    @jax.jit
    def moved_and_joints(key, t):
        pts = sample_bones(SKEL, key).points
        return move_bone_points(bone_motions(SKEL, pose, t), pts), interpolate_joints(SKEL, pose, t)

    rest = cylinder_coords(np.asarray(draw(jax.random.key(9))), POS[PAR[1:]], POS[1:])
    for t in (0.5, 1.0):
        moved, joints = (np.asarray(x) for x in moved_and_joints(jax.random.key(9), t))
        z, radial, _ = cylinder_coords(moved, joints[PAR[1:]], joints[1:])
        np.testing.assert_allclose(z, rest[0], atol=1e-12)  # same cylinder coordinates after the motion
        np.testing.assert_allclose(radial, rest[1], atol=1e-12)


def test_dtype():
    s32 = sample_bones(SKEL, jax.random.key(0), 10, dtype=jnp.float32)
    assert s32.points.dtype == jnp.float32
    s64 = sample_bones(SKEL, jax.random.key(0), 10, dtype=jnp.float64)
    assert s64.points.dtype == jnp.float64
    assert s64.flat().shape == (50, 3)
