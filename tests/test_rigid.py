"""NumPy rigid maths (ncflow.geometry.rigid) against independent references: explicit formulas
(Rodrigues, the Hamilton product, quaternion matrices written out), brute-force compositions and
per-vertex loops, scipy round trips, and analytic motions."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ncflow.geometry import rigid

RNG_SEEDS = [0, 1, 2]


def rodrigues(axis: np.ndarray, angle: float) -> np.ndarray:
    """R = I + sin θ K + (1 − cos θ) K², K the cross-product matrix of the unit axis."""
    k = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * kx + (1 - np.cos(angle)) * kx @ kx


def matrix_of_wxyz(q: np.ndarray) -> np.ndarray:
    """The rotation matrix of a unit quaternion (w, x, y, z), written out."""
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z],
        ]
    )


def hamilton(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(w, x, y, z) product from the scalar/vector form (a0 b0 − a·b, a0 b + b0 a + a × b)."""
    return np.concatenate([[a[0] * b[0] - a[1:] @ b[1:]], a[0] * b[1:] + b[0] * a[1:] + np.cross(a[1:], b[1:])])


def random_tree(rng: np.random.Generator, n: int) -> np.ndarray:
    """Parents of a random tree in topological order (parents[j] < j)."""
    return np.array([-1] + [int(rng.integers(0, j)) for j in range(1, n)])


def random_rigid(rng: np.random.Generator, n: int) -> np.ndarray:
    m = np.tile(np.eye(4), (n, 1, 1))
    m[:, :3, :3] = Rotation.random(n, random_state=rng).as_matrix()
    m[:, :3, 3] = rng.normal(size=(n, 3))
    return m


# ----------------------------------------------------------------------------------------------
# rotations


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_quaternion_orders_and_explicit_matrix(seed):
    rng = np.random.default_rng(seed)
    q_wxyz = rng.normal(size=(6, 4)) * 3.0  # not unit: normalised on input
    q_xyzw = q_wxyz[:, [1, 2, 3, 0]]
    expected = np.stack([matrix_of_wxyz(q) for q in q_wxyz])
    np.testing.assert_allclose(rigid.quat_to_matrix(q_wxyz, scalar_first=True), expected, atol=1e-14)
    np.testing.assert_allclose(rigid.quat_to_matrix(q_xyzw, scalar_first=False), expected, atol=1e-14)
    # any batch shape; the sign of a quaternion does not matter
    batched = rigid.quat_to_matrix(q_wxyz.reshape(2, 3, 4), scalar_first=True)
    np.testing.assert_allclose(batched.reshape(6, 3, 3), expected, atol=1e-14)
    np.testing.assert_allclose(rigid.quat_to_matrix(-q_wxyz[0], scalar_first=True), expected[0], atol=1e-14)
    # axis-angle: q = (cos θ/2, sin θ/2 · axis)
    axis, angle = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5]), 2.3
    q = np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis])
    np.testing.assert_allclose(rigid.quat_to_matrix(q, scalar_first=True), rodrigues(axis, angle), atol=1e-14)
    np.testing.assert_allclose(rigid.rotvec_to_quat(angle * axis, scalar_first=True), q, atol=1e-15)
    np.testing.assert_allclose(rigid.rotvec_to_quat(angle * axis, scalar_first=False), q[[1, 2, 3, 0]], atol=1e-15)
    np.testing.assert_allclose(rigid.rotvec_to_matrix(angle * axis), rodrigues(axis, angle), atol=1e-14)


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_round_trips(seed):
    rng = np.random.default_rng(seed)
    rots = Rotation.random(50, random_state=rng)
    mats = rots.as_matrix()
    for scalar_first in (True, False):
        q = rigid.matrix_to_quat(mats, scalar_first=scalar_first)
        w = q[:, 0] if scalar_first else q[:, 3]
        assert np.all(w >= 0.0)
        np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-15)
        np.testing.assert_allclose(rigid.quat_to_matrix(q, scalar_first=scalar_first), mats, atol=1e-14)
        ref = rots.as_quat()  # scipy: (x, y, z, w)
        ref = np.where(ref[:, 3:] < 0, -ref, ref)
        np.testing.assert_allclose(q, ref[:, [3, 0, 1, 2]] if scalar_first else ref, atol=1e-15)
    rv = rots.as_rotvec()
    np.testing.assert_allclose(rigid.rotvec_to_matrix(rv), mats, atol=1e-14)
    q = rigid.rotvec_to_quat(rv, scalar_first=True)
    back = Rotation.from_quat(q, scalar_first=True).as_rotvec()
    np.testing.assert_allclose(back, rv, atol=1e-14)
    # a single matrix / quaternion keeps its shape
    assert rigid.matrix_to_quat(mats[0], scalar_first=True).shape == (4,)
    assert rigid.quat_to_matrix(q[0], scalar_first=True).shape == (3, 3)


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_quaternion_product_and_composition(seed):
    rng = np.random.default_rng(seed)
    a, b = rng.normal(size=(2, 8, 4))  # not unit: the product is not normalised
    prod = rigid.quat_multiply(a, b, scalar_first=True)
    np.testing.assert_allclose(prod, np.stack([hamilton(x, y) for x, y in zip(a, b)]), atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(prod, axis=1), np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    xyzw = rigid.quat_multiply(a[:, [1, 2, 3, 0]], b[:, [1, 2, 3, 0]], scalar_first=False)
    np.testing.assert_allclose(xyzw, prod[:, [1, 2, 3, 0]], atol=1e-14)
    # R(a ⊗ b) = R(a) R(b)
    np.testing.assert_allclose(
        rigid.quat_to_matrix(prod, scalar_first=True),
        rigid.quat_to_matrix(a, scalar_first=True) @ rigid.quat_to_matrix(b, scalar_first=True),
        atol=1e-14,
    )
    # rotation vectors: R(compose(u, v)) = R(u) R(v), angle in [0, π]
    u, v = rng.normal(size=(2, 8, 3)) * 2.0
    c = rigid.compose_rotvecs(u, v)
    np.testing.assert_allclose(
        rigid.rotvec_to_matrix(c), rigid.rotvec_to_matrix(u) @ rigid.rotvec_to_matrix(v), atol=1e-14
    )
    assert np.all(np.linalg.norm(c, axis=1) <= np.pi + 1e-12)
    np.testing.assert_array_equal(rigid.compose_rotvecs(np.zeros(3), np.zeros(3)), np.zeros(3))


def test_slerp_is_the_shorter_arc_at_constant_speed():
    axis = np.array([2.0, -1.0, 2.0]) / 3.0
    angle = 2.5  # 143°
    q0 = np.array([0.0, 0.0, 0.0, 1.0])
    q1 = np.concatenate([np.sin(angle / 2) * axis, [np.cos(angle / 2)]])
    for u in (0.0, 0.2, 0.5, 0.9, 1.0):
        q = rigid.quat_slerp(q0, q1, u, scalar_first=False)
        np.testing.assert_allclose(rigid.quat_to_matrix(q, scalar_first=False), rodrigues(axis, u * angle), atol=1e-14)
        # the sign of q1 does not matter (shorter arc), nor the order convention
        q_neg = rigid.quat_slerp(q0, -q1, u, scalar_first=False)
        np.testing.assert_allclose(q_neg, q, atol=1e-15)
        q_wxyz = rigid.quat_slerp(q0[[3, 0, 1, 2]], q1[[3, 0, 1, 2]], u, scalar_first=True)
        np.testing.assert_allclose(q_wxyz, q[[3, 0, 1, 2]], atol=1e-15)
    np.testing.assert_allclose(rigid.quat_slerp(-q0, q1, 0.0, scalar_first=False), -q0, atol=1e-15)  # u = 0: q0 itself


def test_trs_matrix_is_translate_rotate_scale():
    t = np.array([0.5, -1.0, 2.0])
    axis, angle = np.array([0.0, 1.0, 1.0]) / np.sqrt(2.0), 0.7
    q_xyzw = np.concatenate([np.sin(angle / 2) * axis, [np.cos(angle / 2)]])
    s = np.array([2.0, 0.5, -1.0])
    tm, rm, sm = np.eye(4), np.eye(4), np.diag(np.concatenate([s, [1.0]]))
    tm[:3, 3] = t
    rm[:3, :3] = rodrigues(axis, angle)
    np.testing.assert_allclose(rigid.trs_matrix(t, q_xyzw, s, scalar_first=False), tm @ rm @ sm, atol=1e-14)
    np.testing.assert_allclose(
        rigid.trs_matrix(t[None], q_xyzw[[3, 0, 1, 2]][None], s[None], scalar_first=True)[0], tm @ rm @ sm, atol=1e-14
    )


# ----------------------------------------------------------------------------------------------
# forward kinematics


def brute_force_world(local: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """World transform of each joint as the explicit product of the locals along its path from the root."""
    out = np.empty_like(local)
    for j in range(parents.shape[0]):
        chain, k = [], j
        while k >= 0:
            chain.append(k)
            k = parents[k]
        m = np.eye(4)
        for k in reversed(chain):  # root first
            m = m @ local[k]
        out[j] = m
    return out


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_forward_kinematics_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    parents = random_tree(rng, 12)
    local = random_rigid(rng, 12)
    local[:, :3, :3] *= rng.uniform(0.5, 2.0, size=(12, 1, 3))  # any affine locals (glTF scales)
    world = rigid.forward_kinematics(local, parents)
    np.testing.assert_allclose(world, brute_force_world(local, parents), atol=1e-12)
    # the same tree listed in another order: give a parents-first order
    perm = rng.permutation(12)
    inv = np.argsort(perm)
    parents_p = np.where(parents[perm] < 0, -1, inv[np.maximum(parents[perm], 0)])
    order = inv[np.arange(12)]  # old index i (topological) sits at inv[i]
    world_p = rigid.forward_kinematics(local[perm], parents_p, order=order)
    np.testing.assert_allclose(world_p, world[perm], atol=1e-12)
    if np.any(parents_p >= np.arange(12)):
        with pytest.raises(ValueError):
            rigid.forward_kinematics(local[perm], parents_p)


def test_joint_rotation_turns_the_subtree_about_the_joint():
    # a chain 0-1-2-3 with a branch 4 off joint 1; rotate joint 2 only, translate the root
    rest = np.array([[0, 0, 0], [0, 1, 0], [0, 2, 0], [0, 3, 0], [1, 1, 0]], dtype=float)
    parents = np.array([-1, 0, 1, 2, 1])
    rot = np.tile(np.eye(3), (5, 1, 1))
    rot[2] = rodrigues([1.0, 0.0, 1.0], 1.1)
    shift = np.array([0.3, -0.2, 0.1])
    world = rigid.forward_kinematics(rigid.joint_local_transforms(rest, parents, rot, shift), parents)
    moved = {2: True, 3: True}
    for j in range(5):
        if moved.get(j):
            expected = rot[2] @ (rest[j] - rest[2]) + rest[2] + shift
            np.testing.assert_allclose(world[j, :3, :3], rot[2], atol=1e-15)
        else:
            expected = rest[j] + shift
            np.testing.assert_allclose(world[j, :3, :3], np.eye(3), atol=0)
        np.testing.assert_allclose(world[j, :3, 3], expected, atol=1e-15)
    # skinning matrices take the rest joints to the posed joints, and points with them
    skin = rigid.skinning_matrices(world, rest)
    np.testing.assert_allclose(skin[:, :3, :3] @ rest[:, :, None] + skin[:, :3, 3:], world[:, :3, 3:], atol=1e-15)


# ----------------------------------------------------------------------------------------------
# skinning


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_linear_blend_skinning_matches_a_per_vertex_loop(seed):
    rng = np.random.default_rng(seed)
    n_v, n_j, k = 40, 7, 4
    x = rng.normal(size=(n_v, 3))
    transforms = random_rigid(rng, n_j)
    transforms[:, :3, :3] *= rng.uniform(0.5, 2.0, size=(n_j, 1, 1))
    dense = rng.uniform(size=(n_v, n_j)) * (rng.uniform(size=(n_v, n_j)) < 0.5)
    dense[:, 0] += 1e-3
    dense /= dense.sum(axis=1, keepdims=True)
    loop = np.array(
        [sum(dense[v, j] * (transforms[j] @ np.append(x[v], 1.0))[:3] for j in range(n_j)) for v in range(n_v)]
    )
    np.testing.assert_allclose(rigid.linear_blend_skinning(x, dense, transforms), loop, atol=1e-13)
    # glTF's sparse influences, a joint listed twice adds up
    joints = rng.integers(0, n_j, size=(n_v, k))
    joints[:, 1] = joints[:, 0]
    weights = rng.uniform(size=(n_v, k))
    weights /= weights.sum(axis=1, keepdims=True)
    loop = np.array(
        [
            sum(weights[v, i] * (transforms[joints[v, i]] @ np.append(x[v], 1.0))[:3] for i in range(k))
            for v in range(n_v)
        ]
    )
    np.testing.assert_allclose(rigid.sparse_linear_blend_skinning(x, joints, weights, transforms), loop, atol=1e-13)
    dw = rigid.dense_weights(joints, weights, n_j)
    np.testing.assert_allclose(dw.sum(axis=1), 1.0, atol=1e-15)
    np.testing.assert_allclose(
        dw[np.arange(n_v), joints[:, 0]],
        weights[:, 0]
        + weights[:, 1]
        + (joints[:, 2] == joints[:, 0]) * weights[:, 2]
        + (joints[:, 3] == joints[:, 0]) * weights[:, 3],
        atol=1e-15,
    )


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_dual_quaternion_skinning_of_one_rigid_bone_is_the_rigid_motion(seed):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(30, 3))
    transforms = random_rigid(rng, 4)
    w = np.zeros((30, 4))
    w[:, 2] = 1.0  # every vertex on one bone
    rigid_motion = x @ transforms[2, :3, :3].T + transforms[2, :3, 3]
    np.testing.assert_allclose(rigid.dual_quaternion_skinning(x, w, transforms), rigid_motion, atol=1e-13)
    np.testing.assert_allclose(rigid.linear_blend_skinning(x, w, transforms), rigid_motion, atol=1e-13)
    # several bones with one motion: any weights give that motion (DQS and LBS alike)
    same = np.repeat(transforms[2:3], 4, axis=0)
    w = rng.uniform(size=(30, 4))
    w /= w.sum(axis=1, keepdims=True)
    np.testing.assert_allclose(rigid.dual_quaternion_skinning(x, w, same), rigid_motion, atol=1e-13)
    np.testing.assert_allclose(rigid.linear_blend_skinning(x, w, same), rigid_motion, atol=1e-13)


def test_dual_quaternion_skinning_keeps_volume_where_lbs_collapses():
    """Half-way between the identity and a 180°-ish twist about z, LBS pulls points on the x axis
    towards the axis (candy wrapper); DQS turns them by half the angle at their radius."""
    x = np.array([[1.0, 0.0, 0.5]])
    turn = np.tile(np.eye(4), (2, 1, 1))
    turn[1, :3, :3] = rodrigues([0.0, 0.0, 1.0], np.radians(170.0))
    w = np.array([[0.5, 0.5]])
    dqs = rigid.dual_quaternion_skinning(x, w, turn)
    np.testing.assert_allclose(dqs[0], [np.cos(np.radians(85.0)), np.sin(np.radians(85.0)), 0.5], atol=1e-14)
    lbs = rigid.linear_blend_skinning(x, w, turn)
    assert np.linalg.norm(lbs[0, :2]) < 0.1
