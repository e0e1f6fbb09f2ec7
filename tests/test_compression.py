"""Nyström compression (Algorithm 2): accuracy on a large mesh, monotone in m, reproducible."""

import numpy as np
import pytest

from ncflow.errors import InputError
from ncflow.geometry.topology import mesh_topology
from ncflow.measures import (
    compress_normal_cycle,
    compress_varifold,
    leverage_scores,
    normal_cycle,
    normal_cycle_distance,
    normal_cycle_inner,
    varifold,
    varifold_distance,
    varifold_inner,
)
from ncflow.synthetic.shapes import sphere


@pytest.fixture(scope="module")
def big_sphere():
    v, f = sphere(5)  # 20480 faces, 30720 edges
    return v, f, mesh_topology(f)


@pytest.mark.parametrize("metric", ["normal_cycles", "varifold"])
def test_compression_error_at_n_over_5_and_monotone_in_m(big_sphere, metric):
    v, f, topo = big_sphere
    if metric == "normal_cycles":
        y = normal_cycle(v, topo)
        compress = lambda m: compress_normal_cycle(y, m, sigma=0.1, seed=0)  # noqa: E731
    else:
        y = varifold(v, f)
        compress = lambda m: compress_varifold(y, m, sigma=0.1, seed=0)  # noqa: E731
    n = y.size
    errors = []
    for m in (n // 40, n // 20, n // 5):
        yc, rep = compress(m)
        assert rep.m == m == yc.size and rep.n == n
        errors.append(rep.relative_error)
    assert errors[2] <= 1e-2  # measured: ~1e-6 for both metrics
    assert errors[0] > errors[1] > errors[2]


@pytest.mark.parametrize("metric", ["normal_cycles", "varifold"])
def test_reported_error_is_the_metric_and_compressed_metric_is_close(metric):
    v, f = sphere(3)
    if metric == "normal_cycles":
        topo = mesh_topology(f)
        y, x = normal_cycle(v, topo), normal_cycle(v * 1.1 + 0.05, topo)
        yc, rep = compress_normal_cycle(y, y.size // 2, sigma=0.15, seed=2)
        dist = lambda a, b: float(normal_cycle_distance(a, b, 0.15))  # noqa: E731
        norm2 = float(normal_cycle_inner(y, y, 0.15))
    else:
        y, x = varifold(v, f), varifold(v * 1.1 + 0.05, f)
        yc, rep = compress_varifold(y, y.size // 2, sigma=0.15, seed=2)
        dist = lambda a, b: float(varifold_distance(a, b, 0.15, 0.5))  # noqa: E731
        norm2 = float(varifold_inner(y, y, 0.15, 0.5))
    # the reported error is d(Y, Y_c) / <Y, Y>
    assert rep.relative_error == pytest.approx(dist(y, yc) / norm2, rel=1e-6, abs=1e-12)
    assert 0 < rep.relative_error < 1e-2
    # and the compressed target gives nearly the same metric against another shape
    assert dist(x, yc) == pytest.approx(dist(x, y), rel=1e-2)


def test_compression_reproducible_and_seeded():
    v, f = sphere(3)
    y = normal_cycle(v, mesh_topology(f))
    a, ra = compress_normal_cycle(y, 300, sigma=0.2, seed=5, report_error=False)
    b, rb = compress_normal_cycle(y, 300, sigma=0.2, seed=5, report_error=False)
    c, rc = compress_normal_cycle(y, 300, sigma=0.2, seed=6, report_error=False)
    np.testing.assert_array_equal(ra.indices, rb.indices)
    np.testing.assert_array_equal(np.asarray(a.weights), np.asarray(b.weights))
    assert not np.array_equal(ra.indices, rc.indices)
    assert np.isnan(ra.relative_error)


def test_m_at_least_n_returns_the_measure_and_bad_m_raises():
    v, f = sphere(1)
    y = varifold(v, f)
    same, rep = compress_varifold(y, 10_000, sigma=0.3)
    assert same is y and rep.relative_error == 0.0
    with pytest.raises(InputError):
        compress_varifold(y, 0, sigma=0.3)


def test_leverage_scores_against_dense_formula():
    rng = np.random.default_rng(0)
    z = rng.normal(size=(40, 3))
    scores = leverage_scores(z, ridge=0.3, block_size=40, seed=0)  # one block: exact RLS
    k = np.exp(-((z[:, None] - z[None]) ** 2).sum(-1))
    np.testing.assert_allclose(scores, np.diag(k @ np.linalg.inv(k + 0.3 * np.eye(40))), rtol=1e-8)


def test_blocked_leverage_scores_are_each_blocks_dense_scores():
    """Blocks are runs of the seed's permutation (the last one shorter); each block's scores are its
    own dense ridge leverage scores."""
    z = np.random.default_rng(1).normal(size=(100, 3)) * 2.0
    scores = leverage_scores(z, ridge=0.2, block_size=30, seed=4)
    perm = np.random.default_rng(4).permutation(100)
    for start in range(0, 100, 30):
        idx = perm[start : start + 30]
        k = np.exp(-((z[idx, None] - z[None, idx]) ** 2).sum(-1))
        dense = np.diag(k @ np.linalg.inv(k + 0.2 * np.eye(idx.size)))
        np.testing.assert_allclose(scores[idx], dense, rtol=1e-8)


@pytest.mark.parametrize("metric", ["normal_cycles", "varifold"])
def test_rows_of_zero_weight_change_nothing(metric):
    """A mesh padded to its size buckets (degenerate faces and edges, boundary rows without
    neighbours: rows of zero weight) compresses to the same representatives, at their padded rows,
    with the same weights and reported error as the mesh itself."""
    from ncflow.jit.buckets import pad_mesh

    v, f = sphere(3)
    f = f[np.linalg.norm(v[f].mean(1) - [0.0, 0.0, 1.0], axis=1) > 0.5]  # a hole: boundary rows too
    topo = mesh_topology(f, v.shape[0])
    pv, ptopo = pad_mesh(v, topo)
    if metric == "varifold":
        y, yp = varifold(v, f), varifold(pv, ptopo.faces)
        a, ra = compress_varifold(y, 300, sigma=0.2, seed=3)
        b, rb = compress_varifold(yp, 300, sigma=0.2, seed=3)
    else:
        y, yp = normal_cycle(v, topo), normal_cycle(pv, ptopo)
        a, ra = compress_normal_cycle(y, 300, sigma=0.2, seed=3)
        b, rb = compress_normal_cycle(yp, 300, sigma=0.2, seed=3)
    assert yp.size > y.size and ra.n == rb.n == y.size
    # the real rows keep their order among the padded ones: the k-th row of weight is real row k
    live = np.flatnonzero(np.any(np.asarray(yp.weights).reshape(yp.size, -1) != 0, axis=1))
    np.testing.assert_array_equal(live[ra.indices], rb.indices)
    np.testing.assert_allclose(np.asarray(b.centers), np.asarray(a.centers), atol=1e-6)
    np.testing.assert_allclose(np.asarray(b.weights), np.asarray(a.weights), rtol=1e-3, atol=1e-6)
    assert rb.relative_error == pytest.approx(ra.relative_error, rel=1e-3, abs=1e-7)


def test_a_flat_measure_with_fewer_atoms_than_m_keeps_them_in_m_rows():
    """A box's Normal Cycle weighs nothing on its flat faces (the two normals of an edge cancel):
    with at most m rows of weight but more than m rows, compression keeps those rows exactly and
    returns m rows (zero-weight rows after them), so a compressed target's shape is always m rows.
    """
    from ncflow.synthetic.shapes import make_shape

    v, f = make_shape("box", 20)
    y = normal_cycle(v, mesh_topology(f))
    w = np.asarray(y.weights)
    live = np.flatnonzero(np.any(w != 0, axis=1))
    m = 2 * live.size
    assert y.size > m  # most rows weigh nothing
    c, rep = compress_normal_cycle(y, m, sigma=0.2)
    assert c.centers.shape[0] == m and rep.n == rep.m == live.size and rep.relative_error == 0.0
    np.testing.assert_array_equal(rep.indices, live)
    np.testing.assert_array_equal(np.asarray(c.weights)[: live.size], w[live])
    assert not np.any(np.asarray(c.weights)[live.size :])
    assert float(normal_cycle_inner(c, c, 0.2)) == pytest.approx(float(normal_cycle_inner(y, y, 0.2)), rel=1e-9)
