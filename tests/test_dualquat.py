"""Dual quaternions against 4×4 rigid matrices, scipy's Rotation and the matrix exponential."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.linalg import expm, logm
from scipy.spatial.transform import Rotation, Slerp

from ncflow.skeleton import dualquat as dq

PROP = settings(max_examples=40, deadline=None)
seeds = st.integers(0, 2**32 - 1)

# compiled once, reused by every example
mul = jax.jit(dq.dq_mul)
from_rt = jax.jit(dq.dq_from_rt)
to_mat = jax.jit(dq.dq_to_matrix)
from_mat = jax.jit(dq.dq_from_matrix)
transform = jax.jit(dq.dq_transform_point)
to_screw = jax.jit(dq.dq_to_screw)
from_screw = jax.jit(dq.dq_from_screw)
sclerp = jax.jit(dq.sclerp)
sclerp_many = jax.jit(jax.vmap(dq.sclerp, in_axes=(0, None, None)))
slerp_many = jax.jit(jax.vmap(dq.slerp, in_axes=(0, None, None)))
normalize = jax.jit(dq.dq_normalize)
quat_from_mat = jax.jit(dq.quat_from_matrix)


def rigid(seed, scale=3.0):
    """(scipy Rotation, translation, 4×4 matrix) from a seed."""
    rng = np.random.default_rng(seed)
    rot = Rotation.random(random_state=rng)
    t = rng.uniform(-scale, scale, 3)
    m = np.eye(4)
    m[:3, :3] = rot.as_matrix()
    m[:3, 3] = t
    return rot, t, m


def dq_of(rot, t):
    return from_rt(jnp.asarray(rot.as_quat(scalar_first=True)), jnp.asarray(t))


def twist_matrix(theta, d, l, m):
    """4×4 twist [[ω^, v], [0, 0]] of the screw (θ, d, l, m): ω = θ l, v = θ m + d l."""
    w = theta * np.asarray(l)
    v = theta * np.asarray(m) + d * np.asarray(l)
    out = np.zeros((4, 4))
    out[:3, :3] = [[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]
    out[:3, 3] = v
    return out


def same_motion(a, b, tol=1e-10):
    """Unit DQs a and b represent the same rigid motion (a = ±b)."""
    a, b = np.asarray(a), np.asarray(b)
    return min(np.abs(a - b).max(), np.abs(a + b).max()) < tol


# ----------------------------------------------------------------------------------------------
# construction, product, point transform


@PROP
@given(seeds)
def test_from_rt_is_the_rigid_matrix(seed):
    rot, t, m = rigid(seed)
    q = dq_of(rot, t)
    np.testing.assert_allclose(to_mat(q), m, atol=1e-12)
    np.testing.assert_allclose(dq.quat_to_matrix(q[:4]), rot.as_matrix(), atol=1e-12)
    # dual part is ½ (0, t) ⊗ r, translation read back
    np.testing.assert_allclose(dq.dq_translation(q), t, atol=1e-12)


@PROP
@given(seeds, seeds)
def test_product_is_matrix_product_and_stays_unit(s1, s2):
    ra, ta, ma = rigid(s1)
    rb, tb, mb = rigid(s2)
    ab = mul(dq_of(ra, ta), dq_of(rb, tb))
    np.testing.assert_allclose(to_mat(ab), ma @ mb, atol=1e-12)
    r, d = np.asarray(ab[:4]), np.asarray(ab[4:])
    assert abs(np.linalg.norm(r) - 1.0) < 1e-12
    assert abs(r @ d) < 1e-12


def test_quat_mul_is_the_hamilton_product_written_out():
    """The sign-table contraction against the sixteen products written out, on non-unit quaternions
    with broadcast leading axes, in float64 and float32.
    """
    rng = np.random.default_rng(3)
    a, b = rng.normal(size=(5, 1, 4)), rng.normal(size=(6, 4))

    def hamilton(p, q):
        (pw, px, py, pz), (qw, qx, qy, qz) = p, q
        return [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ]

    want = np.array([[hamilton(a[i, 0], b[j]) for j in range(6)] for i in range(5)])
    got = dq.quat_mul(a, b)
    assert got.shape == (5, 6, 4) and got.dtype == jnp.float64
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-14)
    got32 = dq.quat_mul(a.astype(np.float32), b.astype(np.float32))
    assert got32.dtype == jnp.float32
    np.testing.assert_allclose(got32, want, rtol=0, atol=1e-5)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_trig_series_match_the_closed_forms(dtype):
    """cos φ, sin φ/φ and (φ cos φ − sin φ)/φ³ on both sides of the switch to the Taylor series
    (the last one's closed form cancels for small φ: its own series there, four terms).
    """
    phi = np.array([1e-6, 1e-3, 0.05, 0.099, 0.101, 0.5, 0.99, 1.01, 2.0, 3.0])
    cos_, sinc, c3 = (np.asarray(v, np.float64) for v in dq._trig(jnp.asarray(phi**2, dtype)))
    p2 = phi**2
    series_c3 = -1 / 3 + p2 / 30 - p2**2 / 840 + p2**3 / 45360
    want_c3 = np.where(phi < 0.1, series_c3, (phi * np.cos(phi) - np.sin(phi)) / phi**3)
    tol = 1e-12 if dtype == np.float64 else 2e-6
    np.testing.assert_allclose(cos_, np.cos(phi), rtol=0, atol=tol)
    np.testing.assert_allclose(sinc, np.sin(phi) / phi, rtol=0, atol=tol)
    np.testing.assert_allclose(c3, want_c3, rtol=0, atol=tol)


@PROP
@given(seeds, seeds)
def test_point_transform_matches_matrix_and_sandwich(s1, s2):
    rot, t, m = rigid(s1)
    q = dq_of(rot, t)
    p = np.random.default_rng(s2).normal(size=(6, 3)) * 2
    expect = p @ m[:3, :3].T + m[:3, 3]
    np.testing.assert_allclose(transform(q, jnp.asarray(p)), expect, atol=1e-12)
    # the paper's sandwich Q (1 + ε p) Q̄ with Q̄ = (r*, −d*) (Eq. 35)
    r, d = q[:4], q[4:]
    pq = jnp.concatenate([jnp.zeros((6, 1)), jnp.asarray(p)], axis=1)
    dual = (
        dq.quat_mul(dq.quat_mul(r, pq), dq.quat_conj(r))
        + dq.quat_mul(d, dq.quat_conj(r))
        - dq.quat_mul(r, dq.quat_conj(d))
    )
    np.testing.assert_allclose(dual[:, 1:], expect, atol=1e-12)
    # inverse undoes it
    back = transform(dq.dq_inverse(q), transform(q, jnp.asarray(p)))
    np.testing.assert_allclose(back, p, atol=1e-12)


@PROP
@given(seeds)
def test_matrix_roundtrip(seed):
    rot, t, m = rigid(seed)
    q = from_mat(jnp.asarray(m))
    assert q[0] >= 0
    assert same_motion(q, dq_of(rot, t), 1e-12)
    np.testing.assert_allclose(to_mat(q), m, atol=1e-12)


@pytest.mark.parametrize("angle", [0.0, 1e-9, np.pi / 2, np.pi - 1e-7, np.pi])
@pytest.mark.parametrize("axis", [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, -2, 0.5]])
def test_quat_from_matrix_all_branches(angle, axis):
    rot = Rotation.from_rotvec(angle * np.asarray(axis, float) / np.linalg.norm(axis))
    q = np.asarray(quat_from_mat(jnp.asarray(rot.as_matrix())))
    ref = rot.as_quat(scalar_first=True)
    assert min(np.abs(q - ref).max(), np.abs(q + ref).max()) < 1e-9
    assert abs(np.linalg.norm(q) - 1) < 1e-12


def test_conjugates_and_normalize():
    rot, t, _ = rigid(7)
    q = dq_of(rot, t)
    np.testing.assert_allclose(dq.dq_conj(q), np.r_[q[0], -q[1:4], q[4], -q[5:]])
    np.testing.assert_allclose(dq.dq_dual_conj(q), np.r_[q[:4], -q[4:]])
    np.testing.assert_allclose(mul(q, dq.dq_conj(q)), dq.dq_identity(dtype=q.dtype), atol=1e-12)
    # normalisation: a scaled DQ with a spurious dual component along r comes back unit
    bad = 2.5 * q + jnp.concatenate([jnp.zeros(4), 0.1 * q[:4]])
    n = normalize(bad)
    assert same_motion(n, q, 1e-12)
    np.testing.assert_allclose(normalize(jnp.zeros(8)), dq.dq_identity(dtype=jnp.float64))
    g = jax.jit(jax.grad(lambda x: dq.dq_normalize(x).sum()))(jnp.zeros(8))
    assert np.all(np.isfinite(g))


# ----------------------------------------------------------------------------------------------
# screw parameters


def screw_oracle(m):
    """Screw parameters of a 4×4 rigid matrix with rotation angle in (0, π)."""
    rv = Rotation.from_matrix(m[:3, :3]).as_rotvec()
    theta = np.linalg.norm(rv)
    l = rv / theta
    t = m[:3, 3]
    d = t @ l
    p = np.linalg.lstsq(np.eye(3) - m[:3, :3], t - d * l, rcond=None)[0]  # a point on the axis
    return theta, d, l, np.cross(p, l)


@PROP
@given(seeds)
def test_screw_parameters_match_geometry_and_roundtrip(seed):
    rot, t, m = rigid(seed)
    assume(0.05 < rot.magnitude() < np.pi - 0.05)
    q = from_mat(jnp.asarray(m))  # w >= 0: angle <= π, like scipy's rotvec
    theta, d, l, mom = to_screw(q)
    th_ref, d_ref, l_ref, m_ref = screw_oracle(m)
    np.testing.assert_allclose(theta, th_ref, atol=1e-10)
    np.testing.assert_allclose(d, d_ref, atol=1e-9)
    np.testing.assert_allclose(l, l_ref, atol=1e-10)
    np.testing.assert_allclose(mom, m_ref, atol=1e-8)
    np.testing.assert_allclose(from_screw(theta, d, l, mom), q, atol=1e-12)
    # the screw is the matrix exponential of its twist
    np.testing.assert_allclose(expm(twist_matrix(th_ref, d_ref, l_ref, m_ref)), m, atol=1e-9)


@PROP
@given(
    st.floats(0.01, 2 * np.pi - 0.01),
    st.floats(-3, 3),
    st.tuples(*[st.floats(-1, 1)] * 3),
    st.tuples(*[st.floats(-2, 2)] * 3),
)
def test_screw_to_dq_to_screw(theta, d, axis, point):
    axis = np.asarray(axis)
    assume(np.linalg.norm(axis) > 0.1)
    l = axis / np.linalg.norm(axis)
    m = np.cross(point, l)
    q = from_screw(theta, d, jnp.asarray(l), jnp.asarray(m))
    r, dual = np.asarray(q[:4]), np.asarray(q[4:])
    assert abs(r @ r - 1) < 1e-12 and abs(r @ dual) < 1e-12
    np.testing.assert_allclose(to_mat(q), expm(twist_matrix(theta, d, l, m)), atol=1e-9)
    back = to_screw(q)
    for got, want in zip(back, (theta, d, l, m)):
        np.testing.assert_allclose(got, want, atol=1e-9)


def test_screw_of_pure_translation_and_identity():
    t = np.array([0.3, -1.2, 0.4])
    theta, d, l, m = to_screw(from_rt(jnp.array([1.0, 0, 0, 0]), jnp.asarray(t)))
    assert theta == 0 and abs(d - np.linalg.norm(t)) < 1e-14
    np.testing.assert_allclose(l, t / np.linalg.norm(t), atol=1e-14)
    np.testing.assert_allclose(m, 0)
    theta, d, l, m = to_screw(dq.dq_identity(dtype=jnp.float64))
    assert theta == 0 and d == 0 and np.all(np.asarray(l) == 0)


# ----------------------------------------------------------------------------------------------
# ScLERP


@PROP
@given(seeds, seeds, st.floats(0, 1))
def test_sclerp_is_matrix_exp_log_and_hits_endpoints(s1, s2, t):
    ra, ta, ma = rigid(s1)
    rb, tb, mb = rigid(s2)
    rel = np.linalg.inv(ma) @ mb
    assume(Rotation.from_matrix(rel[:3, :3]).magnitude() < np.pi - 0.05)  # principal log unique
    a, b = dq_of(ra, ta), dq_of(rb, tb)
    expect = ma @ expm(t * np.real(logm(rel)))
    np.testing.assert_allclose(to_mat(sclerp(t, a, b)), expect, atol=1e-8)
    np.testing.assert_allclose(sclerp(0.0, a, b), a, atol=1e-13)
    assert same_motion(sclerp(1.0, a, b), b, 1e-12)
    # hemisphere: −B is the same motion and gives the same path
    np.testing.assert_allclose(sclerp(t, a, -b), sclerp(t, a, b), atol=1e-13)


@PROP
@given(seeds, seeds)
def test_sclerp_constant_screw_velocity(s1, s2):
    ra, ta, _ = rigid(s1)
    rb, tb, _ = rigid(s2)
    a, b = dq_of(ra, ta), dq_of(rb, tb)
    path = sclerp_many(jnp.linspace(0.0, 1.0, 9), a, b)
    steps = mul(dq.dq_conj(path[:-1]), path[1:])  # relative motion of each equal time step
    mats = np.asarray(to_mat(steps))
    np.testing.assert_allclose(mats, np.broadcast_to(mats[0], mats.shape), atol=1e-10)
    # shortest path: the relative rotation turns by at most π over the whole interval
    rel = mul(dq.dq_conj(a), path[-1])
    assert Rotation.from_quat(np.asarray(rel[:4]), scalar_first=True).magnitude() <= np.pi + 1e-12
    # unit norm along the way
    np.testing.assert_allclose(np.linalg.norm(path[:, :4], axis=1), 1.0, atol=1e-12)


@pytest.mark.parametrize("theta", [0.3, 1e-2, 1e-4, 1e-6, 1e-9, 1e-13, 0.0])
def test_sclerp_near_zero_angle_matches_expm_and_is_continuous(theta):
    l = np.array([0.0, 0.6, 0.8])
    p = np.array([0.5, -0.2, 1.0])
    d = 0.7
    a = dq_of(*rigid(3)[:2])
    ma = np.asarray(to_mat(a))
    b = mul(a, from_screw(theta, d, jnp.asarray(l), jnp.asarray(np.cross(p, l))))
    for t in (0.25, 0.5, 0.9):
        got = np.asarray(to_mat(sclerp(t, a, b)))
        expect = ma @ expm(t * twist_matrix(theta, d, l, np.cross(p, l)))
        np.testing.assert_allclose(got, expect, atol=1e-12)
        # distance to the pure-translation limit shrinks with θ (continuity at θ = 0)
        limit = np.asarray(to_mat(sclerp(t, a, mul(a, from_rt(jnp.array([1.0, 0, 0, 0]), jnp.asarray(d * l))))))
        assert np.abs(got - limit).max() <= 5 * theta + 1e-13


def test_sclerp_near_half_turn():
    l = np.array([1.0, 2.0, -2.0]) / 3
    m = np.cross([0.3, 0.1, -0.4], l)
    ident = dq.dq_identity(dtype=jnp.float64)
    grad = jax.jit(jax.grad(lambda x: dq.sclerp(0.5, ident, x).sum()))
    for theta in (np.pi - 1e-3, np.pi - 1e-8, np.pi):
        b = from_screw(theta, 0.4, jnp.asarray(l), jnp.asarray(m))
        got = np.asarray(to_mat(sclerp(0.5, ident, b)))
        np.testing.assert_allclose(got, expm(0.5 * twist_matrix(theta, 0.4, l, m)), atol=1e-7)
        assert np.all(np.isfinite(grad(b)))


def test_sclerp_gradients_at_zero_angle():
    """Gradients are finite and equal finite differences where the relative rotation is exactly 0
    (B = A, and B = A · pure translation), for A = identity and a generic A."""
    w = jnp.asarray([0.2, -0.7, 0.4, 0.1, 0.5, -0.3])  # weights of the output
    pts = jnp.asarray([[1.0, 0.0, 0.0], [0.0, 1.0, 2.0]])

    def f(params, a):  # params = (rotvec, translation) of the relative motion, and t
        rel = dq.dq_from_rt(dq.quat_from_rotvec(params[:3]), params[3:6])
        out = dq.sclerp(params[6], a, dq.dq_mul(a, rel))
        return jnp.sum(dq.dq_transform_point(out, pts).reshape(-1) * w)

    f_jit, grad_f = jax.jit(f), jax.jit(jax.grad(f))
    grad_raw = jax.jit(jax.grad(lambda a, b, t: dq.sclerp(t, a, b).sum(), argnums=(0, 1, 2)))
    eps = 1e-6
    ident = dq.dq_identity(dtype=jnp.float64)
    for a in (ident, dq_of(*rigid(11)[:2])):
        for tr in (np.zeros(3), np.array([0.4, -0.3, 1.1])):
            x = jnp.concatenate([jnp.zeros(3), jnp.asarray(tr), jnp.asarray([0.35])])
            g = np.asarray(grad_f(x, a))
            fd = np.array([(f_jit(x + eps * e, a) - f_jit(x - eps * e, a)) / (2 * eps) for e in np.eye(7)])
            np.testing.assert_allclose(g, fd, atol=1e-6)
            # the raw 8-vector gradients w.r.t. A, B and t exactly at the singular point
            grads = grad_raw(a, mul(a, from_rt(jnp.array([1.0, 0, 0, 0]), jnp.asarray(tr))), 0.3)
            assert all(np.all(np.isfinite(gr)) for gr in grads)


def test_pow_log_exp_gradients_at_identity():
    ident = dq.dq_identity(dtype=jnp.float64)
    g_t = jax.jit(jax.grad(lambda t: dq.dq_pow(ident, t).sum()))(0.5)
    assert g_t == 0.0
    jac = jax.jit(jax.jacfwd(lambda q: jnp.concatenate(dq.dq_log(q))))(ident)
    assert np.all(np.isfinite(jac))
    # d log / d q at identity: ω = v, u = d_v  (first order)
    np.testing.assert_allclose(jac[:3, 1:4], np.eye(3), atol=1e-14)
    np.testing.assert_allclose(jac[3:, 5:8], np.eye(3), atol=1e-14)
    jac_e = jax.jit(jax.jacrev(lambda x: dq.dq_exp(x[:3], x[3:])))(jnp.zeros(6))
    assert np.all(np.isfinite(jac_e))
    np.testing.assert_allclose(jac_e[1:4, :3], np.eye(3), atol=1e-14)  # d exp/dω = I at 0
    np.testing.assert_allclose(jac_e[5:8, 3:], np.eye(3), atol=1e-14)


# ----------------------------------------------------------------------------------------------
# SLERP and the separate LERP/SLERP baseline


@PROP
@given(seeds, seeds)
def test_slerp_matches_scipy_along_shortest_arc(s1, s2):
    r0, _, _ = rigid(s1)
    r1, _, _ = rigid(s2)
    ts = np.linspace(0, 1, 7)
    ref = Slerp([0, 1], Rotation.concatenate([r0, r1]))(ts)  # scipy takes the shortest arc
    q0, q1 = jnp.asarray(r0.as_quat(scalar_first=True)), jnp.asarray(r1.as_quat(scalar_first=True))
    for qq1 in (q1, -q1):
        got = slerp_many(jnp.asarray(ts), q0, qq1)
        np.testing.assert_allclose(dq.quat_to_matrix(got), ref.as_matrix(), atol=1e-10)
    np.testing.assert_allclose(got[0], q0, atol=1e-13)


def test_seplerp_vs_sclerp():
    a = dq.dq_identity(dtype=jnp.float64)
    b = from_rt(dq.quat_from_axis_angle(jnp.array([0.0, 0, 1]), jnp.pi / 2), jnp.array([1.0, 1.0, 0.0]))
    sep = dq.seplerp(0.5, a, b)
    scl = sclerp(0.5, a, b)
    # same rotation half-way, translation exactly linear for the baseline, on the screw for ScLERP
    np.testing.assert_allclose(sep[:4], scl[:4], atol=1e-13)
    np.testing.assert_allclose(dq.dq_translation(sep), [0.5, 0.5, 0.0], atol=1e-13)
    assert np.abs(dq.dq_translation(scl) - np.array([0.5, 0.5, 0.0])).max() > 0.1
    for t in (0.0, 1.0):
        assert same_motion(dq.seplerp(t, a, b), sclerp(t, a, b), 1e-12)


def test_dtype_follows_inputs():
    rot, t, m = rigid(5)
    a32 = jnp.asarray(dq_of(rot, t), jnp.float32)
    b32 = jnp.asarray(dq_of(*rigid(6)[:2]), jnp.float32)
    out = sclerp(0.3, a32, b32)
    assert out.dtype == jnp.float32
    ref = sclerp(0.3, a32.astype(jnp.float64), b32.astype(jnp.float64))
    np.testing.assert_allclose(out, ref, atol=2e-6)
    g = jax.jit(jax.grad(lambda x: dq.sclerp(0.3, a32, x).sum()))(a32)
    assert g.dtype == jnp.float32 and np.all(np.isfinite(g))
