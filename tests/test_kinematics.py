"""Forward kinematics and interpolation against an independent 4×4-matrix implementation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.linalg import expm, logm
from scipy.spatial.transform import Rotation, Slerp

from ncflow.skeleton import (
    Pose,
    Skeleton,
    dq_to_matrix,
    forward_kinematics,
    interpolate_joints,
    interpolate_world,
    load_skeleton,
    rest_pose,
    rigid_reference,
)

POS = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 2.0, 0.5], [0.7, 1.5, 0.0], [1.2, 2.0, 0.1], [-0.6, -0.4, 0.2]])
PAR = np.array([-1, 0, 1, 1, 3, 0])
SKEL = Skeleton.from_arrays(POS, PAR)
TIMES = jnp.linspace(0.0, 1.0, 11)

fk = jax.jit(lambda pose: forward_kinematics(SKEL, pose))
joints_at = jax.jit(interpolate_joints, static_argnums=(0, 3))  # (skeleton, pose, t, interp)
rigid_ref = jax.jit(rigid_reference, static_argnums=(0, 4))  # (skeleton, pose, points, times, interp)


def fk_joints(pose):
    return joints_at(SKEL, pose, 1.0, "sclerp")


path_sclerp = jax.jit(jax.vmap(lambda pose, t: interpolate_world(SKEL, pose, t, "sclerp"), in_axes=(None, 0)))
path_slerp = jax.jit(jax.vmap(lambda pose, t: interpolate_world(SKEL, pose, t, "slerp"), in_axes=(None, 0)))


def random_pose(seed, max_angle=2.5, translation=True):
    rng = np.random.default_rng(seed)
    rv = rng.normal(size=(SKEL.n_joints, 3))
    rv *= rng.uniform(0.1, max_angle, (SKEL.n_joints, 1)) / np.linalg.norm(rv, axis=1, keepdims=True)
    rot = Rotation.from_rotvec(rv)
    q = rot.as_quat(scalar_first=True)
    s = rng.normal(size=3) if translation else np.zeros(3)
    return Pose(jnp.asarray(q), jnp.asarray(s)), rot, s


def affine(r=None, t=None):
    m = np.eye(4)
    if r is not None:
        m[:3, :3] = r
    if t is not None:
        m[:3, 3] = t
    return m


def reference_frames(skel, local_mats):
    """World 4×4 frames by composing local matrices down the tree (internal order is topological)."""
    world = [None] * skel.n_joints
    for j in range(skel.n_joints):
        p = skel.parents[j]
        world[j] = local_mats[j] if p < 0 else world[p] @ local_mats[j]
    return np.stack(world)


def reference_locals(skel, rots, s):
    off = skel.offsets.copy()
    off[0] = off[0] + s
    return [affine(rots[j], off[j]) for j in range(skel.n_joints)]


# ----------------------------------------------------------------------------------------------


def test_rest_pose_frames_are_joint_translations():
    world = fk(rest_pose(SKEL, jnp.float64))
    np.testing.assert_allclose(dq_to_matrix(world), [affine(t=p) for p in POS], atol=1e-15)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fk_matches_matrix_composition(seed):
    pose, rot, s = random_pose(seed)
    world = np.asarray(dq_to_matrix(fk(pose)))
    ref = reference_frames(SKEL, reference_locals(SKEL, rot.as_matrix(), s))
    np.testing.assert_allclose(world, ref, atol=1e-12)


def test_rotation_of_a_joint_moves_exactly_its_distal_part_about_it():
    q = np.tile([1.0, 0, 0, 0], (6, 1))
    r = Rotation.from_rotvec([0.3, -1.1, 0.4])
    q[1] = r.as_quat(scalar_first=True)  # "spine": children 2, 3 and grand-child 4
    posed = np.asarray(fk_joints(Pose(jnp.asarray(q), jnp.zeros(3))))
    np.testing.assert_allclose(posed[[0, 1, 5]], POS[[0, 1, 5]], atol=1e-14)
    np.testing.assert_allclose(posed[[2, 3, 4]], POS[1] + (POS[[2, 3, 4]] - POS[1]) @ r.as_matrix().T, atol=1e-14)
    # a leaf rotation moves no joint
    q2 = np.tile([1.0, 0, 0, 0], (6, 1))
    q2[4] = r.as_quat(scalar_first=True)
    np.testing.assert_allclose(fk_joints(Pose(jnp.asarray(q2), jnp.zeros(3))), POS, atol=1e-14)
    # root rotation turns everything about P_0, then s̃ translates
    q3 = np.tile([1.0, 0, 0, 0], (6, 1))
    q3[0] = r.as_quat(scalar_first=True)
    s = np.array([0.5, -2.0, 1.0])
    got = fk_joints(Pose(jnp.asarray(q3), jnp.asarray(s)))
    np.testing.assert_allclose(got, POS[0] + (POS - POS[0]) @ r.as_matrix().T + s, atol=1e-14)


@pytest.mark.parametrize("seed", [3, 4])
def test_bone_lengths_preserved_along_sclerp_and_endpoints(seed):
    pose, rot, s = random_pose(seed)
    frames = path_sclerp(pose, TIMES)
    joints = np.asarray(dq_to_matrix(frames))[..., :3, 3]
    lengths = np.linalg.norm(joints[:, 1:] - joints[:, SKEL.parents[1:]], axis=-1)
    np.testing.assert_allclose(lengths, np.broadcast_to(SKEL.bone_lengths, lengths.shape), atol=1e-6)
    assert np.abs(lengths - SKEL.bone_lengths).max() < 1e-12  # in fact to rounding
    np.testing.assert_allclose(joints[0], POS, atol=1e-14)
    end = np.asarray(dq_to_matrix(fk(pose)))
    np.testing.assert_allclose(np.asarray(dq_to_matrix(frames[-1])), end, atol=1e-12)
    # both interpolations end at the same pose (frames, not just joints)
    np.testing.assert_allclose(np.asarray(dq_to_matrix(path_slerp(pose, TIMES)[-1])), end, atol=1e-12)
    np.testing.assert_allclose(np.asarray(dq_to_matrix(path_slerp(pose, TIMES)[0]))[:, :3, 3], POS, atol=1e-14)


def test_sclerp_interpolation_equals_local_slerp_and_root_screw():
    """Independent reference: per-joint scipy Slerp from the identity, composed by matrices; the
    root's local matrix follows the matrix exponential of t·log(rest⁻¹ posed)."""
    pose, rot, s = random_pose(5)
    frames = np.asarray(dq_to_matrix(path_sclerp(pose, TIMES)))
    mats = rot.as_matrix()
    root_rest = affine(t=POS[0])
    root_posed = affine(mats[0], POS[0] + s)
    log_root = np.real(logm(np.linalg.inv(root_rest) @ root_posed))
    for k, t in enumerate(np.asarray(TIMES)):
        rots_t = [
            Slerp([0, 1], Rotation.concatenate([Rotation.identity(), Rotation.from_matrix(m)]))(t).as_matrix()
            for m in mats
        ]
        local = reference_locals(SKEL, rots_t, np.zeros(3))
        local[0] = root_rest @ expm(t * log_root)
        np.testing.assert_allclose(frames[k], reference_frames(SKEL, local), atol=1e-9)


def test_two_bone_arm_sclerp_versus_world_slerp_lerp():
    """Paper Fig. 11: same end pose, different motion; the baseline breaks the bones mid-way."""
    arm = Skeleton.from_arrays([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]], [-1, 0, 1])
    z90 = Rotation.from_rotvec([0, 0, np.pi / 2]).as_quat(scalar_first=True)
    pose = Pose(jnp.asarray([z90, z90, [1.0, 0, 0, 0]]), jnp.zeros(3))
    joints = jax.jit(jax.vmap(lambda t: jnp.stack([interpolate_joints(arm, pose, t, i) for i in ("sclerp", "slerp")])))
    (sc, sl), (sc1, sl1) = np.asarray(joints(jnp.asarray([0.5, 1.0])))
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    # ScLERP: shoulder and elbow both turned by 45°: elbow on the unit circle, forearm along +y
    np.testing.assert_allclose(sc, [[0, 0, 0], [c, s, 0], [c, s + 1.0, 0]], atol=1e-14)
    # baseline: joints on the straight chords from rest (x axis) to the end pose
    np.testing.assert_allclose(sl, [[0, 0, 0], [0.5, 0.5, 0], [0.5, 0.5, 0]], atol=1e-14)
    assert np.abs(sc - sl).max() > 0.5
    np.testing.assert_allclose(np.linalg.norm(sc[1:] - sc[:-1], axis=1), [1, 1], atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(sl[1:] - sl[:-1], axis=1), [np.sqrt(0.5), 0.0], atol=1e-14)
    end = [[0, 0, 0], [0, 1, 0], [-1, 1, 0]]
    np.testing.assert_allclose(sc1, end, atol=1e-14)
    np.testing.assert_allclose(sl1, end, atol=1e-14)


def test_result_independent_of_joint_order_in_file(tmp_path):
    perm = np.array([3, 5, 0, 2, 4, 1])  # file line k holds joint perm[k] of POS
    line_of = np.argsort(perm)  # line holding POS joint j
    text_a = "\n".join(f"{j + 1} {x} {y} {z}" for j, (x, y, z) in enumerate(POS)) + "\n#\n"
    text_a += "\n".join(f"{PAR[j] + 1} {j + 1}" for j in range(1, 6)) + "\n"
    text_b = "\n".join(f"{k + 1} {x} {y} {z}" for k, (x, y, z) in enumerate(POS[perm])) + "\n#\n"
    text_b += "\n".join(f"{line_of[PAR[j]] + 1} {line_of[j] + 1}" for j in (4, 2, 5, 1, 3)) + "\n"
    (tmp_path / "a.tgf").write_text(text_a)
    (tmp_path / "b.tgf").write_text(text_b)
    a, b = load_skeleton(tmp_path / "a.tgf"), load_skeleton(tmp_path / "b.tgf")
    assert not np.array_equal(b.file_index, np.arange(6))
    _, rot, s = random_pose(6)
    q_file_a = rot.as_quat(scalar_first=True)  # per POS joint
    q_file_b = q_file_a[perm]  # per line of file b
    out = {}
    for name, skel, qf in (("a", a, q_file_a), ("b", b, q_file_b)):
        pose = Pose(jnp.asarray(skel.from_file_order(qf)), jnp.asarray(s))
        joints = np.stack([np.asarray(joints_at(skel, pose, t, "sclerp")) for t in (0.3, 1.0)])
        out[name] = np.stack([skel.to_file_order(j) for j in joints])
    np.testing.assert_allclose(out["b"], out["a"][:, perm], atol=1e-13)


def test_bone_motions_move_points_rigidly_with_twist():
    # twist of the head bone (3 -> 4) about its own axis: joint 3 turns about the arm->hand axis
    axis = (POS[4] - POS[3]) / np.linalg.norm(POS[4] - POS[3])
    twist = Rotation.from_rotvec(np.pi / 2 * axis)
    q = np.tile([1.0, 0, 0, 0], (6, 1))
    q[3] = twist.as_quat(scalar_first=True)
    pose = Pose(jnp.asarray(q), jnp.zeros(3))
    bone = 3  # (3 -> 4)
    side = np.cross(axis, [0.0, 0.0, 1.0])
    off_axis = POS[3] + 0.5 * (POS[4] - POS[3]) + 0.1 * side / np.linalg.norm(side)
    pts = jnp.asarray(np.broadcast_to(off_axis, (SKEL.n_bones, 4, 3)))  # shapes as below: one compile
    moved = np.asarray(rigid_ref(SKEL, pose, pts, TIMES, "sclerp"))[-1, bone, 0]
    np.testing.assert_allclose(moved, POS[3] + twist.apply(off_axis - POS[3]), atol=1e-14)  # twist applied ...
    assert np.linalg.norm(moved - off_axis) > 0.1
    np.testing.assert_allclose(fk_joints(pose), POS, atol=1e-14)  # ... though no joint moves


@pytest.mark.parametrize("interp", ["sclerp", "slerp"])
def test_rigid_reference_follows_bone_frames(interp):
    pose, rot, s = random_pose(7)
    rng = np.random.default_rng(0)
    pts = jnp.asarray(POS[SKEL.parents[1:], None, :] + rng.normal(size=(SKEL.n_bones, 4, 3)) * 0.1)
    ref = np.asarray(rigid_ref(SKEL, pose, pts, TIMES, interp))
    assert ref.shape == (TIMES.size, SKEL.n_bones, 4, 3)
    np.testing.assert_allclose(ref[0], pts, atol=1e-14)
    frames = np.asarray(dq_to_matrix((path_sclerp if interp == "sclerp" else path_slerp)(pose, TIMES)))
    for k in (3, 10):
        for b in range(SKEL.n_bones):
            a = SKEL.parents[b + 1]
            m = frames[k, a] @ affine(t=-POS[a])  # T_b(t) T_b(0)^-1
            np.testing.assert_allclose(ref[k, b], np.asarray(pts[b]) @ m[:3, :3].T + m[:3, 3], atol=1e-12)
    if interp == "sclerp":  # moved parent/child joints of each bone are the interpolated joints
        joints = frames[:, :, :3, 3]
        ends = np.asarray(
            rigid_ref(SKEL, pose, jnp.asarray(np.stack([POS[SKEL.parents[1:]], POS[1:]] * 2, 1)), TIMES, "sclerp")
        )
        np.testing.assert_allclose(ends[:, :, 0], joints[:, SKEL.parents[1:]], atol=1e-12)
        np.testing.assert_allclose(ends[:, :, 1], joints[:, 1:], atol=1e-12)


def test_gradients_at_rest_pose_are_finite_and_correct():
    pts = jnp.asarray(POS[SKEL.parents[1:], None, :] + 0.05)
    w = jnp.asarray(np.random.default_rng(1).normal(size=(5, SKEL.n_bones, 1, 3)))

    def loss(x):
        pose = Pose(x[:24].reshape(6, 4), x[24:])
        return jnp.sum(rigid_reference(SKEL, pose, pts, jnp.asarray([0.0, 0.25, 0.5, 0.75, 1.0])) * w)

    x0 = jnp.concatenate([rest_pose(SKEL, jnp.float64).rotations.reshape(-1), jnp.zeros(3)])
    vg = jax.jit(jax.value_and_grad(loss))  # one compile for the gradient and the differences
    grad = np.asarray(vg(x0)[1])
    assert np.all(np.isfinite(grad))
    eps = 1e-6
    for i in (1, 2, 7, 13, 22, 24, 26):  # rotation coordinates of several joints, translation
        e = np.zeros(x0.size)
        e[i] = eps
        fd = (vg(x0 + e)[0] - vg(x0 - e)[0]) / (2 * eps)
        np.testing.assert_allclose(grad[i], fd, atol=1e-6)
    assert np.abs(grad).max() > 0.1  # not trivially zero


def test_float32_pose_gives_float32():
    pose, _, _ = random_pose(8)
    p32 = Pose(pose.rotations.astype(jnp.float32), pose.translation.astype(jnp.float32))
    out = joints_at(SKEL, p32, 0.4, "sclerp")
    assert out.dtype == jnp.float32
    np.testing.assert_allclose(out, joints_at(SKEL, pose, 0.4, "sclerp"), atol=1e-5)
