"""Distortion terms, GSO-Net and bone-constraint values (ncflow.losses, ncflow.flow.gso;
paper §4.3–4.5; reference-notes §7.2–7.4, §9)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ncflow.flow import FlowField, GSONet, flow_points, integrate, rotation_from_6d
from ncflow.flow.gso import IDENTITY_6D
from ncflow.geometry.topology import mesh_topology
from ncflow.losses import (
    arap_energy,
    bone_constraints,
    bone_endpoint_constraint,
    bone_trajectory_constraint,
    edge_points,
    leash_energy,
    sample_edges,
    split_stencil,
    surface_distortion,
    tissue_distortion,
    tissue_frame_energy,
    tissue_stencil,
)
from ncflow.synthetic.shapes import sphere

T = 5
TS = np.linspace(0.0, 1.0, T)

# compiled once per shape: much cheaper than JAX's op-by-op dispatch on this 2-core machine
surface_distortion_jit = eqx.filter_jit(surface_distortion)
call_jit = eqx.filter_jit(lambda net, x, t: net(x, jnp.asarray(t)))
arap_energy_jit = jax.jit(arap_energy)
tissue_distortion_jit = jax.jit(tissue_distortion, static_argnums=1)
codes_jit = eqx.filter_jit(lambda net, x, t: net.codes(x, jnp.asarray(t)))


def rotation_angle(r):
    """Rotation angle in radians of rotation matrices (..., 3, 3): arccos((tr R − 1)/2)."""
    cos = 0.5 * (jnp.trace(r, axis1=-2, axis2=-1) - 1.0)
    return jnp.arccos(jnp.clip(cos, -1.0, 1.0))


def random_rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def axis_angle(axis, angle) -> np.ndarray:
    k = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * kx + (1 - np.cos(angle)) * kx @ kx


def rigid_motion(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """States (T, N, 3) of x ↦ R(t) x + c(t) and the rotations R(t) (T, 3, 3)."""
    rots = np.stack([axis_angle([1.0, 2.0, -0.5], 1.3 * t) for t in TS])
    shifts = np.stack([np.array([0.3, -0.2, 0.7]) * t + 0.1 * t * t for t in TS])
    return np.einsum("kab,nb->kna", rots, points) + shifts[:, None], rots


def apply_linear(points: np.ndarray, maps) -> np.ndarray:
    return np.stack([points @ np.asarray(a).T for a in maps])


# ----------------------------------------------------------------------------------------------
# tissue term


@pytest.fixture
def samples():
    return np.random.default_rng(0).normal(size=(20, 3))


def test_stencil_layout_round_trips(samples):
    delta = 0.01
    pts = tissue_stencil(jnp.asarray(samples), delta)
    assert pts.shape == (80, 3)
    np.testing.assert_allclose(pts[:20], samples)
    np.testing.assert_allclose(pts[40:60], samples + [0.0, delta, 0.0])
    centres, frames = split_stencil(pts[None])
    np.testing.assert_allclose(centres[0], samples)
    np.testing.assert_allclose(frames[0], np.broadcast_to(delta * np.eye(3), (20, 3, 3)), atol=1e-15)


def test_tissue_term_vanishes_for_rigid_motion(samples):
    pts = np.asarray(tissue_stencil(jnp.asarray(samples)))
    states, _ = rigid_motion(pts)
    value = tissue_distortion_jit(jnp.asarray(states), 0.01)
    assert value.dtype == jnp.float64
    assert float(value) <= 1e-12
    grad = jax.jit(jax.grad(tissue_distortion))(jnp.asarray(states))
    assert np.all(np.isfinite(np.asarray(grad)))


def test_tissue_term_uniform_scale_is_three_one_minus_s_squared(samples):
    pts = np.asarray(tissue_stencil(jnp.asarray(samples), 0.01))
    for s in (0.8, 1.1, 1.5):
        states = apply_linear(pts, [np.eye(3)] + [s * np.eye(3)] * (T - 1))
        states += np.array([0.5, -1.0, 2.0])  # plus a translation: irrelevant
        assert float(tissue_distortion(jnp.asarray(states), 0.01)) == pytest.approx(3 * (1 - s) ** 2, rel=1e-9)
    # δ-independence of the scale value: the stretch term is relative
    pts2 = np.asarray(tissue_stencil(jnp.asarray(samples), 0.05))
    states2 = apply_linear(pts2, [np.eye(3)] + [1.2 * np.eye(3)] * (T - 1))
    assert float(tissue_distortion(jnp.asarray(states2), 0.05)) == pytest.approx(3 * 0.2**2, rel=1e-9)


def test_tissue_term_non_uniform_stretch_and_shear(samples):
    pts = np.asarray(tissue_stencil(jnp.asarray(samples)))
    # stretch along x by (1 + t): D_x = (1+t)δ e_x, orthogonal frame → ℓ = t²
    stretch = apply_linear(pts, [np.diag([1 + t, 1.0, 1.0]) for t in TS])
    value = float(tissue_distortion(jnp.asarray(stretch)))
    assert value > 0
    assert value == pytest.approx(np.mean(TS[1:] ** 2), rel=1e-9)
    # shear x += t·y: D_y = δ(t, 1, 0) → 2 t²/(1+t²) + (1 − √(1+t²))²
    shear = apply_linear(pts, [np.array([[1.0, t, 0], [0, 1, 0], [0, 0, 1]]) for t in TS])
    expected = np.mean([2 * t * t / (1 + t * t) + (1 - np.sqrt(1 + t * t)) ** 2 for t in TS[1:]])
    assert float(tissue_distortion(jnp.asarray(shear))) == pytest.approx(expected, rel=1e-9)


def test_tissue_frame_energy_direct_value():
    delta = 0.01
    frames = jnp.asarray([[2 * delta, 0, 0], [0, delta, 0], [0, 0, delta]])[None]
    assert float(tissue_frame_energy(frames, delta)[0]) == pytest.approx(1.0, rel=1e-12)


def test_tissue_term_float32_and_through_a_flow(samples):
    field = FlowField(jax.random.key(0), width=16, depth=2)  # float32 parameters
    pts = tissue_stencil(jnp.asarray(samples, jnp.float32))
    assert pts.dtype == jnp.float32

    def loss(f):
        xs, _ = integrate(f, pts, n_times=T)
        return tissue_distortion(xs)

    value, grads = eqx.filter_jit(eqx.filter_value_and_grad(loss))(field)
    assert value.dtype == jnp.float32
    assert 0.0 < float(value) < 1.0  # a small random field distorts a little
    g = jax.tree_util.tree_leaves(eqx.filter(grads, eqx.is_array))
    assert all(np.all(np.isfinite(np.asarray(x))) for x in g)
    assert any(float(jnp.abs(x).max()) > 0 for x in g)


# ----------------------------------------------------------------------------------------------
# GSO-Net


def test_rotation_from_6d_identity_and_known_rotation():
    np.testing.assert_allclose(rotation_from_6d(jnp.asarray(IDENTITY_6D, jnp.float64)), np.eye(3), atol=1e-15)
    r = random_rotation(np.random.default_rng(1))
    code = np.concatenate([r[:, 0], r[:, 1]]) * np.array([2.0, 2, 2, 1, 1, 1])  # scale does not matter
    code[3:] += 0.7 * r[:, 0]  # a component along the first column is removed by Gram–Schmidt
    np.testing.assert_allclose(rotation_from_6d(jnp.asarray(code)), r, atol=1e-12)


@pytest.mark.parametrize("dtype,tol", [(jnp.float64, 1e-10), (jnp.float32, 2e-6)])
def test_gso_outputs_are_proper_rotations(dtype, tol):
    # a large output scale makes the codes far from the identity: still rotations
    net = GSONet(jax.random.key(3), width=32, dtype=dtype, out_scale=10.0)
    x = jax.random.normal(jax.random.key(4), (500, 3), dtype)
    r = call_jit(net, x, jnp.asarray(0.3, dtype))
    assert r.shape == (500, 3, 3) and r.dtype == dtype
    rtr = jnp.einsum("nai,naj->nij", r, r)
    assert float(jnp.abs(rtr - jnp.eye(3, dtype=dtype)).max()) < tol
    assert float(jnp.abs(jnp.linalg.det(r) - 1).max()) < tol
    assert float(jnp.degrees(rotation_angle(r)).max()) > 30  # genuinely non-trivial rotations


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fresh_gso_net_is_near_identity(seed):
    net = GSONet(jax.random.key(seed))  # default: float32, 3 × 128
    x = 1.5 * jax.random.normal(jax.random.key(10 + seed), (1000, 3), jnp.float32)
    angles = jnp.concatenate([jnp.degrees(rotation_angle(call_jit(net, x, t))) for t in jnp.asarray([0.0, 0.5, 1.0])])
    assert float(angles.max()) < 3.0
    assert float(angles.mean()) > 0.0  # not exactly the identity: the net has an output to train
    # the release's bias (1,0,0, 1,0,0) would make both halves parallel: far from the identity
    release_bias = jnp.asarray([1.0, 0, 0, 1, 0, 0], jnp.float32) - jnp.asarray(IDENTITY_6D, jnp.float32)
    buggy = rotation_from_6d(codes_jit(net, x, jnp.asarray(0.0)) + release_bias)
    assert float(jnp.degrees(rotation_angle(buggy)).max()) > 10.0


def test_gso_init_is_keyed():
    a, b, c = GSONet(jax.random.key(5)), GSONet(jax.random.key(5)), GSONet(jax.random.key(6))
    la, lb, lc = (jax.tree_util.tree_leaves(eqx.filter(n, eqx.is_array)) for n in (a, b, c))
    assert all(np.array_equal(np.asarray(u), np.asarray(v)) for u, v in zip(la, lb))
    assert not all(np.array_equal(np.asarray(u), np.asarray(v)) for u, v in zip(la, lc))
    assert float(a.lipschitz_bound()) == pytest.approx(
        0.1 * np.prod([np.abs(np.asarray(l.weight)).sum(1).max() for l in a.mlp.layers]), rel=1e-5
    )


def constant_rotation_net(rot: np.ndarray, dtype=jnp.float64) -> GSONet:
    """A GSO-Net whose last layer ignores its input and outputs the code of ``rot`` everywhere."""
    net = GSONet(jax.random.key(0), width=8, dtype=dtype)
    code = jnp.asarray(np.concatenate([rot[:, 0], rot[:, 1]]), dtype)
    last = net.mlp.layers[-1]
    net = eqx.tree_at(lambda n: n.mlp.layers[-1].weight, net, jnp.zeros_like(last.weight))
    return eqx.tree_at(lambda n: n.mlp.layers[-1].bias, net, (code - jnp.asarray(IDENTITY_6D, dtype)) / net.out_scale)


# ----------------------------------------------------------------------------------------------
# surface ARAP term


@pytest.fixture(scope="module")
def small_mesh():
    v, f = sphere(1)
    return v, mesh_topology(f).edges


def test_arap_zero_for_rigid_motion_with_true_rotations(small_mesh):
    v, edges = small_mesh
    states, rots = rigid_motion(v)
    rotations = np.broadcast_to(rots[:, None], (T, v.shape[0], 3, 3))
    value = arap_energy_jit(jnp.asarray(v), jnp.asarray(edges), jnp.asarray(states[1:]), jnp.asarray(rotations[1:]))
    assert float(value) <= 1e-24
    # the same motion measured against the identity is penalised
    eye = np.broadcast_to(np.eye(3), rotations.shape)
    wrong = arap_energy_jit(jnp.asarray(v), jnp.asarray(edges), jnp.asarray(states[1:]), jnp.asarray(eye[1:]))
    assert float(wrong) > 1e-2

    # a rotation predictor given as any callable (the true R(t)) goes through surface_distortion
    def oracle(x, t):
        return jnp.broadcast_to(jnp.asarray(rots)[jnp.round(t * (T - 1)).astype(int)], (x.shape[0], 3, 3))

    assert float(surface_distortion_jit(oracle, jnp.asarray(v), edges, jnp.asarray(states))) <= 1e-24


def test_arap_through_the_gso_net(small_mesh):
    v, edges = small_mesh
    rot = axis_angle([0.2, -1.0, 0.4], 0.9)
    net = constant_rotation_net(rot)
    np.testing.assert_allclose(net(jnp.asarray(v), 0.5), np.broadcast_to(rot, (v.shape[0], 3, 3)), atol=1e-12)
    rigid = np.stack([v] + [v @ rot.T + np.array([0.1, 0.2, 0.3]) * t for t in TS[1:]])
    assert float(surface_distortion_jit(net, jnp.asarray(v), edges, jnp.asarray(rigid))) <= 1e-24
    # a non-rigid motion (uniform scale 1.2 after the rotation) is penalised: e = (0.2)² ‖edge‖²
    scaled = np.stack([v] + [1.2 * v @ rot.T for _ in TS[1:]])
    lengths2 = np.sum((v[edges[:, 0]] - v[edges[:, 1]]) ** 2, axis=1)
    expected = 0.04 * lengths2.mean()
    value = surface_distortion_jit(net, jnp.asarray(v), edges, jnp.asarray(scaled))
    assert float(value) == pytest.approx(expected, rel=1e-10)
    # a fresh net (≈ identity) on the identity motion: tiny but positive
    fresh = GSONet(jax.random.key(1))  # float32 parameters, float64 points: promoted to float64
    still = np.broadcast_to(v, (T,) + v.shape)
    small = float(surface_distortion_jit(fresh, jnp.asarray(v), edges, jnp.asarray(still)))
    assert 0.0 < small < 1e-3 * lengths2.mean()


def test_arap_hand_computed_two_edges():
    rest = jnp.asarray([[0.0, 0, 0], [1, 0, 0], [1, 1, 0]])
    edges = jnp.asarray([[0, 1], [1, 2]])
    rz90 = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    states = jnp.asarray([[[0.0, 0, 0], [2, 0, 0], [2, 1, 0]]])
    rotations = jnp.asarray([[np.eye(3), rz90, np.eye(3)]])
    # edge (0,1): e01 = ‖(−2,0,0) − (−1,0,0)‖² = 1, e10 = ‖(−2,0,0) − (0,−1,0)‖² = 5 → 3
    # edge (1,2): e12 = ‖(0,−1,0) − (1,0,0)‖² = 2,  e21 = 0 → 1;  mean = 2
    assert float(arap_energy(rest, edges, states, rotations)) == pytest.approx(2.0, abs=1e-14)
    # a second time at rest with identity rotations contributes 0: the mean over times halves it
    states2 = jnp.concatenate([states, rest[None]])
    rotations2 = jnp.concatenate([rotations, jnp.broadcast_to(jnp.eye(3), (1, 3, 3, 3))])
    assert float(arap_energy(rest, edges, states2, rotations2)) == pytest.approx(1.0, abs=1e-14)


def test_edge_subset_matches_full_mesh_restricted(small_mesh):
    v, edges = small_mesh
    field = FlowField(jax.random.key(2), width=16, depth=2, dtype=jnp.float64, alpha=1.0)
    net = GSONet(jax.random.key(3), width=16, dtype=jnp.float64, out_scale=1.0)
    sub = sample_edges(jax.random.key(7), jnp.asarray(edges), 25)
    assert sub.shape == (25, 2)
    assert len({tuple(e) for e in np.asarray(sub).tolist()}) == 25  # without replacement
    np.testing.assert_array_equal(np.asarray(sub), np.asarray(sample_edges(jax.random.key(7), jnp.asarray(edges), 25)))
    assert not np.array_equal(np.asarray(sub), np.asarray(sample_edges(jax.random.key(8), jnp.asarray(edges), 25)))
    points, local = edge_points(jnp.asarray(v), sub)
    assert points.shape == (50, 3) and local.shape == (25, 2)
    xs_full = flow_points(field, jnp.asarray(v), n_times=T)
    # trajectories are independent (tests/test_flow.py): flowing the 2n edge points equals gathering
    xs_sub = jnp.concatenate([xs_full[:, sub[:, 0]], xs_full[:, sub[:, 1]]], axis=1)
    np.testing.assert_array_equal(np.asarray(xs_sub[0]), np.asarray(points))
    a = surface_distortion_jit(net, points, local, xs_sub)
    b = surface_distortion_jit(net, jnp.asarray(v), sub, xs_full)
    assert float(a) > 0
    assert float(a) == pytest.approx(float(b), rel=1e-12)


# ----------------------------------------------------------------------------------------------
# bone constraints


def test_bone_constraints_against_numpy():
    rng = np.random.default_rng(4)
    flowed = rng.normal(size=(6, 4, 7, 3))
    reference = flowed + 0.1 * rng.normal(size=flowed.shape)
    g_ep, g_tr = bone_constraints(jnp.asarray(flowed), jnp.asarray(reference))
    d2 = np.sum((flowed - reference) ** 2, axis=-1)  # (T, B, n)
    np.testing.assert_allclose(g_ep, d2[-1].mean(axis=-1), rtol=1e-13)
    np.testing.assert_allclose(g_tr, d2[1:-1].mean(axis=(0, 2)), rtol=1e-13)
    assert g_ep.shape == (4,) and g_tr.shape == (4,)
    np.testing.assert_allclose(bone_endpoint_constraint(jnp.asarray(flowed), jnp.asarray(reference)), g_ep)
    np.testing.assert_allclose(bone_trajectory_constraint(jnp.asarray(flowed), jnp.asarray(reference)), g_tr)


def test_bone_constraints_full_squared_distance():
    # every sample of bone 1 is off by (0.1, 0.2, 0.2) at every time after 0: ‖·‖² = 0.09 (not 0.03)
    reference = np.zeros((4, 3, 5, 3))
    flowed = reference.copy()
    flowed[1:, 1] += np.array([0.1, 0.2, 0.2])
    flowed[0, 2] += 5.0  # the start time enters neither constraint
    g_ep, g_tr = bone_constraints(jnp.asarray(flowed), jnp.asarray(reference))
    np.testing.assert_allclose(g_ep, [0.0, 0.09, 0.0], atol=1e-15)
    np.testing.assert_allclose(g_tr, [0.0, 0.09, 0.0], atol=1e-15)
    # the end time enters only the endpoint constraint
    flowed[-1, 0] += 1.0
    g_ep, g_tr = bone_constraints(jnp.asarray(flowed), jnp.asarray(reference))
    assert float(g_ep[0]) == pytest.approx(3.0) and float(g_tr[0]) == 0.0
    # T = 2: no interior time
    g_ep2, g_tr2 = bone_constraints(jnp.asarray(flowed[[0, -1]]), jnp.asarray(reference[[0, -1]]))
    np.testing.assert_allclose(g_tr2, 0.0)
    np.testing.assert_allclose(g_ep2, g_ep)
    with pytest.raises(ValueError, match="T, B, n, 3"):
        bone_constraints(jnp.asarray(flowed), jnp.asarray(reference[:, :2]))


def test_bone_constraints_differentiable_float32():
    flowed = jnp.ones((3, 2, 4, 3), jnp.float32)
    reference = jnp.zeros((3, 2, 4, 3), jnp.float32)
    g = jax.grad(lambda f: jnp.sum(jnp.stack(bone_constraints(f, reference))))(flowed)
    assert g.dtype == jnp.float32
    # ∂g^EP_b/∂s = 2(s − s̄)/n at the end time; ∂g^TR_b/∂s = 2(s − s̄)/(n (T−2)) at interior times
    np.testing.assert_allclose(g[-1], 0.5)
    np.testing.assert_allclose(g[1], 0.5)
    np.testing.assert_allclose(g[0], 0.0)


def test_leash_energy_is_the_mean_squared_velocity_over_eps():
    r = np.random.default_rng(4).normal(size=(3, 7, 3))
    expected = sum(float(r[k, i] @ r[k, i]) for k in range(3) for i in range(7)) / 21 / 2e-3
    assert float(leash_energy(jnp.asarray(r), 2e-3)) == pytest.approx(expected, rel=1e-6)
    assert float(leash_energy(jnp.zeros((2, 4, 3)), 1e-4)) == 0.0
