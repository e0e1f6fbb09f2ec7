"""Flow-Net fields and the fixed-grid integrator (DESIGN.md "Flow"; reference-notes §8)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

from ncflow.flow import (
    DivFreeFlowField,
    FlowField,
    divergence,
    flow_points,
    hermite,
    integrate,
    make_flow_field,
    time_grid,
)
from ncflow.geometry.mesh import enclosed_volume
from ncflow.synthetic.shapes import sphere

KEY = jax.random.key(0)


def _np_gelu(x):
    return 0.5 * x * (1.0 + np.tanh(np.sqrt(2.0 / np.pi) * (x + 0.044715 * x**3)))


def _np_mlp(mlp, z):
    for i, layer in enumerate(mlp.layers):
        z = z @ np.asarray(layer.weight).T + np.asarray(layer.bias)
        if i < len(mlp.layers) - 1:
            z = _np_gelu(z)
    return z


def _np_heun(field_np, x0, n_times):
    """The recursion of DESIGN.md "Flow", written out in NumPy."""
    h = 1.0 / (n_times - 1)
    x, v = x0.copy(), field_np(x0, 0.0)
    xs, vs = [x], [v]
    for k in range(n_times - 1):
        x_pred = x + h * v
        v_next = field_np(x_pred, (k + 1) * h)
        x = x + 0.5 * h * (v + v_next)
        v = v_next
        xs.append(x)
        vs.append(v)
    return np.stack(xs), np.stack(vs)


# ---------------------------------------------------------------------------------------------
# Fields


def test_flow_field_matches_numpy_forward():
    field = FlowField(KEY, width=16, depth=3, dtype=jnp.float64)
    assert len(field.mlp.layers) == 4  # depth hidden layers -> depth + 1 linear layers
    assert float(field.alpha) == pytest.approx(0.1)
    x = np.random.default_rng(1).normal(size=(7, 3))
    t = 0.3
    ref = 0.1 * _np_mlp(field.mlp, np.concatenate([x, np.full((7, 1), t)], axis=1))
    np.testing.assert_allclose(np.asarray(field(jnp.asarray(x), t)), ref, rtol=1e-12, atol=1e-14)
    rev = FlowField(KEY, width=16, depth=3, dtype=jnp.float64, reverse_time=True)
    ref_rev = 0.1 * _np_mlp(rev.mlp, np.concatenate([x, np.full((7, 1), 1 - t)], axis=1))
    np.testing.assert_allclose(np.asarray(rev(jnp.asarray(x), t)), ref_rev, rtol=1e-12, atol=1e-14)


def test_field_dtype_follows_construction():
    for div_free in (False, True):
        f32 = make_flow_field(KEY, width=8, depth=1, div_free=div_free)  # float32 default
        assert f32.alpha.dtype == jnp.float32
        assert all(leaf.dtype == jnp.float32 for leaf in jax.tree.leaves(eqx.filter(f32, eqx.is_array)))
        out = eqx.filter_jit(f32)(jnp.ones((4, 3), jnp.float32), 0.5)
        assert out.shape == (4, 3) and out.dtype == jnp.float32
        xs, vs = eqx.filter_jit(integrate)(f32, jnp.ones((4, 3), jnp.float32), 4)
        assert xs.dtype == vs.dtype == jnp.float32 and xs.shape == (4, 4, 3)
    assert isinstance(make_flow_field(KEY, 8, 1, div_free=True), DivFreeFlowField)
    assert isinstance(make_flow_field(KEY, 8, 1, div_free=False), FlowField)


def test_div_free_field_is_curl_of_potential_and_divergence_free():
    field = make_flow_field(KEY, width=24, depth=2, div_free=True, dtype=jnp.float64, alpha=0.7)
    x = jnp.asarray(np.random.default_rng(2).normal(size=(50, 3)))
    potential = eqx.filter_jit(field.potential)
    velocity = eqx.filter_jit(field)
    div_of = eqx.filter_jit(lambda p, t: divergence(field, p, t))
    for t in map(jnp.asarray, (0.0, 0.37, 1.0)):
        # curl against central finite differences of the potential A
        d = 1e-5
        jac = np.zeros((50, 3, 3))  # [n, i, j] = dA_i/dx_j
        for j in range(3):
            e = np.zeros(3)
            e[j] = d
            jac[:, :, j] = (np.asarray(potential(x + e, t)) - np.asarray(potential(x - e, t))) / (2 * d)
        curl = np.stack([jac[:, 2, 1] - jac[:, 1, 2], jac[:, 0, 2] - jac[:, 2, 0], jac[:, 1, 0] - jac[:, 0, 1]], 1)
        np.testing.assert_allclose(np.asarray(velocity(x, t)), 0.7 * curl, rtol=1e-6, atol=1e-9)
        div = np.asarray(div_of(x, t))
        assert np.max(np.abs(div)) < 1e-10
    # the standard field is not divergence free
    std = make_flow_field(KEY, width=24, depth=2, dtype=jnp.float64)
    assert np.max(np.abs(np.asarray(divergence(std, x, 0.5)))) > 1e-3


def test_div_free_flow_preserves_volume_standard_does_not():
    # sphere(3): 642 vertices, 1280 faces, radius 1. Field width 32, depth 2; alpha scaled so that the
    # mean displacement at t = 1 is ~0.25; T = 20 grid times (the volume error is ~1e-5 here,
    # ~2e-5 at T = 10: the time discretisation, not the surface discretisation, dominates).
    v, f = sphere(3)
    vol0 = enclosed_volume(v, f)
    div_free = make_flow_field(KEY, width=32, depth=2, div_free=True, dtype=jnp.float64, alpha=4.0)
    x1 = np.asarray(flow_points(div_free, jnp.asarray(v), n_times=20)[-1])
    disp = np.linalg.norm(x1 - v, axis=1).mean()
    assert disp > 0.2
    assert abs(enclosed_volume(x1, f) / vol0 - 1.0) < 1e-3

    std = make_flow_field(KEY, width=32, depth=2, dtype=jnp.float64, alpha=1.7)
    y1 = np.asarray(flow_points(std, jnp.asarray(v), n_times=20)[-1])
    assert np.linalg.norm(y1 - v, axis=1).mean() > 0.2
    assert abs(enclosed_volume(y1, f) / vol0 - 1.0) > 1e-2


# ---------------------------------------------------------------------------------------------
# Integrator


def test_linear_ode_second_order_against_expm():
    a = np.array([[0.0, -2.0, 0.3], [2.0, 0.0, 0.0], [0.1, 0.0, -0.5]])
    x0 = np.random.default_rng(3).normal(size=(20, 3))
    errs = {}
    for n in (21, 41):
        xs, _ = integrate(lambda x, t: x @ a.T, jnp.asarray(x0), n)
        ref = np.stack([x0 @ scipy.linalg.expm(a * t).T for t in np.linspace(0, 1, n)])
        errs[n] = np.max(np.abs(np.asarray(xs) - ref))
    assert 3.8 < errs[21] / errs[41] < 4.2  # halving h divides the error by 4: O(h²)
    assert errs[41] < 1e-2  # ≈ 10·h² here (h = 1/40, ‖A‖ ≈ 2)


def test_recursion_matches_numpy_loop_nonlinear_time_dependent():
    w = np.array([[0.7, -0.3, 0.2], [0.1, 0.9, -0.4], [-0.5, 0.2, 0.6]])

    def field_np(x, t):
        return np.sin(x @ w + 2.0 * t) * (1.0 + t**2) + np.cos(3.0 * t) * x[:, ::-1]

    def field_jax(x, t):
        return jnp.sin(x @ w + 2.0 * t) * (1.0 + t**2) + jnp.cos(3.0 * t) * x[:, ::-1]

    x0 = np.random.default_rng(4).normal(size=(30, 3))
    for n in (2, 7, 10):
        xs, vs = integrate(field_jax, jnp.asarray(x0), n)
        rxs, rvs = _np_heun(field_np, x0, n)
        np.testing.assert_allclose(np.asarray(xs), rxs, rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(np.asarray(vs), rvs, rtol=1e-13, atol=1e-13)

    # and with the network field itself
    net = make_flow_field(KEY, width=16, depth=2, dtype=jnp.float64, alpha=1.0)
    xs, vs = integrate(net, jnp.asarray(x0), 10)
    rxs, rvs = _np_heun(lambda x, t: np.asarray(net(jnp.asarray(x), t)), x0, 10)
    np.testing.assert_allclose(np.asarray(xs), rxs, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(np.asarray(vs), rvs, rtol=1e-12, atol=1e-13)


def test_checkpoint_flag_same_values_and_gradients():
    field = make_flow_field(KEY, width=8, depth=1, dtype=jnp.float64, alpha=1.0)
    x0 = jnp.asarray(np.random.default_rng(5).normal(size=(6, 3)))

    def loss(fld, ckpt):
        xs, vs = integrate(fld, x0, 5, checkpoint=ckpt)
        return jnp.sum(xs[-1] ** 2) + jnp.sum(vs**2)

    v0, g0 = eqx.filter_jit(eqx.filter_value_and_grad(loss))(field, False)
    v1, g1 = eqx.filter_jit(eqx.filter_value_and_grad(loss))(field, True)
    assert float(v0) == pytest.approx(float(v1), rel=1e-14)
    for a, b in zip(jax.tree.leaves(eqx.filter(g0, eqx.is_array)), jax.tree.leaves(eqx.filter(g1, eqx.is_array))):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-14)


# ---------------------------------------------------------------------------------------------
# Dense output


def test_hermite_exact_on_cubic_data_and_on_grid():
    rng = np.random.default_rng(6)
    c = rng.normal(size=(4, 5, 3))  # p(t) = c0 + c1 t + c2 t² + c3 t³ per point
    n = 10
    tk = np.linspace(0, 1, n)
    xs = sum(c[i][None] * tk[:, None, None] ** i for i in range(4))
    vs = sum(i * c[i][None] * tk[:, None, None] ** (i - 1) for i in range(1, 4))
    tq = np.concatenate([rng.uniform(0, 1, 40), [0.0, 1.0, 0.5 / (n - 1)]])
    ref = sum(c[i][None] * tq[:, None, None] ** i for i in range(4))
    out = np.asarray(hermite(jnp.asarray(xs), jnp.asarray(vs), jnp.asarray(tq)))
    assert out.shape == (43, 5, 3)
    np.testing.assert_allclose(out, ref, rtol=1e-12, atol=1e-12)
    # grid times (two different roundings of k/(T−1)) give the grid states bit for bit
    for grid in (np.asarray(time_grid(n, jnp.float64)), np.linspace(0, 1, n), np.arange(n) * (1.0 / (n - 1))):
        np.testing.assert_array_equal(np.asarray(hermite(jnp.asarray(xs), jnp.asarray(vs), jnp.asarray(grid))), xs)


def test_hermite_of_integrated_flow_exact_for_quadratic_trajectories():
    # F(x, t) = b + c t does not depend on x: the trajectories x0 + b t + c t²/2 are quadratic, the
    # trapezoidal step is exact for them and the stored slopes are exact, so the Hermite interpolant
    # is exact between grid points.
    b, c = np.array([0.3, -1.0, 0.5]), np.array([2.0, 0.7, -1.5])
    x0 = np.random.default_rng(7).normal(size=(9, 3))
    xs, vs = integrate(lambda x, t: jnp.broadcast_to(jnp.asarray(b + c * t), x.shape), jnp.asarray(x0), 6)
    tq = np.linspace(0.013, 0.991, 37)
    ref = x0[None] + b * tq[:, None, None] + 0.5 * c * tq[:, None, None] ** 2
    np.testing.assert_allclose(np.asarray(hermite(xs, vs, jnp.asarray(tq))), ref, rtol=1e-13, atol=1e-13)


def test_hermite_linear_ode_off_grid_error_bound():
    a = np.array([[0.0, -2.0, 0.3], [2.0, 0.0, 0.0], [0.1, 0.0, -0.5]])
    x0 = np.random.default_rng(8).normal(size=(10, 3))
    xs, vs = integrate(lambda x, t: x @ a.T, jnp.asarray(x0), 41)
    tq = np.random.default_rng(9).uniform(0, 1, 30)
    ref = np.stack([x0 @ scipy.linalg.expm(a * t).T for t in tq])
    grid_ref = np.stack([x0 @ scipy.linalg.expm(a * t).T for t in np.linspace(0, 1, 41)])
    grid_err = np.max(np.abs(np.asarray(xs) - grid_ref))
    err = np.max(np.abs(np.asarray(hermite(xs, vs, jnp.asarray(tq))) - ref))
    assert err < 1.1 * grid_err + 1e-5  # interpolation adds O(h⁴) on top of the O(h²) grid error


# ---------------------------------------------------------------------------------------------
# Moving other point sets


def test_flow_points_equals_integrate():
    field = make_flow_field(KEY, width=16, depth=2, dtype=jnp.float64, alpha=1.0)
    pts = jnp.asarray(np.random.default_rng(10).normal(size=(23, 3)))
    xs, vs = integrate(field, pts, 10)
    np.testing.assert_allclose(np.asarray(flow_points(field, pts)), np.asarray(xs), rtol=1e-14, atol=1e-15)
    # chunked (with padding: 23 = 2·10 + 3) gives the same rows
    chunked = flow_points(field, pts, chunk_size=10)
    np.testing.assert_allclose(np.asarray(chunked), np.asarray(xs), rtol=1e-14, atol=1e-15)
    # a subset flowed alone moves exactly like inside the larger set (resolution-agnostic)
    np.testing.assert_allclose(np.asarray(flow_points(field, pts[:5])), np.asarray(xs[:, :5]), rtol=1e-14, atol=1e-15)
    tq = jnp.asarray([0.0, 0.05, 0.5, 0.77, 1.0])
    np.testing.assert_allclose(
        np.asarray(flow_points(field, pts, times=tq)), np.asarray(hermite(xs, vs, tq)), rtol=1e-14, atol=1e-15
    )
