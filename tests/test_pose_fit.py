"""The per-step articulated pose fit (matcher.fit_pose)."""

import jax
import jax.numpy as jnp
import numpy as np
from scipy.spatial.transform import Rotation

from ncflow.flow import time_grid
from ncflow.losses import bone_constraints
from ncflow.matcher.pose_fit import constraint_fit_weights, fit_pose
from ncflow.skeleton import Skeleton, rigid_reference, sample_bones
from ncflow.skeleton.kinematics import Pose, rest_pose

# a bent chain: root 0 -> 1 -> 2 -> 3 plus a side branch 1 -> 4
POS = np.array([[0.0, 0, 0], [0.0, 0.5, 0], [0.1, 0.9, 0.05], [0.15, 1.2, 0.0], [0.4, 0.6, 0.0]])
PARENTS = np.array([-1, 0, 1, 2, 1])
SKEL = Skeleton.from_arrays(POS, PARENTS)
TIMES = time_grid(6, jnp.float64)


def _samples(n=24):
    return sample_bones(SKEL, jax.random.key(3), n, radius=0.1, dtype=jnp.float64).points


def _twisted_pose(theta):
    """Joint 2 twisted by theta about its bone (2 -> 3), joint 1 bent by 0.6 rad about z."""
    q = np.tile([1.0, 0, 0, 0], (SKEL.n_joints, 1))
    axis = (SKEL.positions[3] - SKEL.positions[2]) / np.linalg.norm(SKEL.positions[3] - SKEL.positions[2])
    q[2] = Rotation.from_rotvec(theta * axis).as_quat(scalar_first=True)
    q[1] = Rotation.from_rotvec([0, 0, 0.6]).as_quat(scalar_first=True)
    return Pose(jnp.asarray(q), jnp.asarray([0.02, -0.01, 0.03]))


def _angle(q):
    q = np.asarray(q) / np.linalg.norm(q)
    return 2 * np.arccos(min(1.0, abs(q[0])))


@jax.jit
def _reference(pose, pts):
    """The bone samples' rigid reference (one program: op by op, each operation would be one)."""
    return rigid_reference(SKEL, pose, pts, TIMES, "sclerp")


@jax.jit
def _fit(flowed, pts, weights=None):
    """40 Gauss-Newton iterations from the rest pose (steps of at most 0.1)."""
    return fit_pose(SKEL, rest_pose(SKEL, jnp.float64), pts, flowed, TIMES, "sclerp", 40, 0.1, weights)


def test_fit_recovers_an_articulated_pose_with_twist():
    pts = _samples()
    true = _twisted_pose(0.3)
    flowed = _reference(true, pts)
    fitted = _fit(flowed, pts)
    np.testing.assert_allclose(np.asarray(_reference(fitted, pts)), np.asarray(flowed), atol=1e-8)
    np.testing.assert_allclose(np.asarray(fitted.translation), np.asarray(true.translation), atol=1e-8)
    for j in (0, 1, 2):  # every joint that carries a bone: the same rotation up to sign
        q, want = np.asarray(fitted.rotations[j]), np.asarray(true.rotations[j])
        np.testing.assert_allclose(abs(np.dot(q, want)), 1.0, atol=1e-10)
    np.testing.assert_allclose(_angle(fitted.rotations[2]), 0.3, atol=1e-6)  # the twist is recovered


def test_each_gauss_newton_step_is_capped_by_the_trust_region():
    pts = _samples()
    flowed = _reference(_twisted_pose(1.2), pts)
    rest = rest_pose(SKEL, jnp.float64)
    one = jax.jit(lambda x: fit_pose(SKEL, rest, pts, x, TIMES, "sclerp", iterations=1, max_step=0.01))(flowed)
    moved = np.abs(np.asarray(one.rotations) - np.asarray(rest.rotations)).max()
    assert 0.005 < moved <= 0.0101  # capped (then renormalised), yet it moves
    assert np.abs(np.asarray(one.translation)).max() <= 0.01 + 1e-12


def test_fit_weights_make_the_fit_objective_the_constraint_term():
    """Σ_t Σ_k w_tk mean_s ‖p̄ − x‖² equals Σ_k (1 + λ^EP_k) g^EP_k + τ (1 + λ^TR_k) g^TR_k."""
    rng = np.random.default_rng(0)
    pts = _samples(12)
    flowed = _reference(_twisted_pose(0.4), pts) + 0.02 * rng.standard_normal((6, 4, 12, 3))
    reference = _reference(rest_pose(SKEL, jnp.float64), pts)
    lam_ep, lam_tr, tau = rng.uniform(0, 50, 4), rng.uniform(0, 50, 4), 0.7
    w = np.asarray(constraint_fit_weights(6, 4, jnp.float64, lam_ep, lam_tr, tau))
    assert w.shape == (6, 4) and np.all(w[0] == 0)
    d2 = np.mean(np.sum((np.asarray(reference) - np.asarray(flowed)) ** 2, axis=-1), axis=-1)  # (T, B)
    g_ep, g_tr = (np.asarray(g) for g in bone_constraints(flowed, reference))
    want = np.sum((1 + lam_ep) * g_ep + tau * (1 + lam_tr) * g_tr)
    np.testing.assert_allclose(np.sum(w * d2), want, rtol=1e-12)


def test_a_heavier_endpoint_weight_fits_the_endpoint_better():
    """Interior states off the articulated path: weighting the endpoint pulls the fit to it."""
    pts = _samples()
    true = _twisted_pose(0.3)
    flowed = np.array(_reference(true, pts))
    flowed[1:-1] += np.array([0.05, -0.03, 0.04])  # the trajectory bulges; the endpoint is exact
    ends = []
    for lam_ep in (0.0, 100.0):
        w = constraint_fit_weights(6, 4, jnp.float64, lam_ep=jnp.full(4, lam_ep))
        fitted = _fit(jnp.asarray(flowed), pts, w)
        ref = _reference(fitted, pts)
        ends.append(float(np.max(np.asarray(bone_constraints(jnp.asarray(flowed), ref)[0]))))
    assert ends[1] < 0.05 * ends[0] and ends[0] > 1e-5, ends


def test_the_fit_of_a_skinned_field_starts_at_its_own_pose():
    """The per-step fit starts where the skeleton-driven field moves its bones (its swing pose), so the
    samples its rigid cores carry fit with g ≈ 0 in the training's two capped steps; from the previous
    step's pose (here: rest, the pose 0.6 rad away) the same steps stop short and leave g beyond ε, a
    violation the flow did not make.
    """
    from ncflow.flow import SkinnedField, flow_points, make_flow_field
    from ncflow.matcher.objective import fit_start

    pts = _samples()
    residual = make_flow_field(jax.random.key(0), width=8, depth=1, alpha=0.3, dtype=jnp.float64)
    field = SkinnedField(residual, SKEL, _twisted_pose(0.0), 0.02, dtype=jnp.float64, core=0.1 * SKEL.bone_lengths)
    flowed = flow_points(field, pts.reshape(-1, 3), TIMES.shape[0]).reshape(TIMES.shape[0], *pts.shape)
    rest = rest_pose(SKEL, jnp.float64)
    assert fit_start(residual, rest) is rest  # a plain Flow-Net: the previous step's pose

    def g_after_fit(start):
        pose = fit_pose(SKEL, start, pts, flowed, TIMES, "sclerp")
        return max(float(jnp.max(g)) for g in bone_constraints(flowed, _reference(pose, pts)))

    assert g_after_fit(fit_start(field, rest)) < 1e-10
    assert g_after_fit(rest) > 3e-4  # ε of the default preset
