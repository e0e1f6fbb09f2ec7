"""Soft-tissue sampling: fTetWild tetrahedralisation, longest-edge splitting, keyed centroid sampling
(ncflow.tissue; paper §4.4; reference-notes §7.1)."""

import os
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ncflow import tissue
from ncflow.errors import InputError
from ncflow.geometry.mesh import enclosed_volume
from ncflow.geometry.topology import close_boundary, mesh_topology
from ncflow.synthetic.shapes import sphere, tube
from ncflow.tissue import (
    sample_tissue,
    soft_tissue,
    split_tets,
    tet_centroids,
    tet_volumes,
    tetrahedralize_surface,
)


def winding_number(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Generalised winding number of a closed, outward-oriented surface (van Oosterom–Strackee)."""
    tri = vertices[faces]  # (F, 3, 3)
    a = tri[None, :, 0] - points[:, None]
    b = tri[None, :, 1] - points[:, None]
    c = tri[None, :, 2] - points[:, None]
    la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
    num = np.einsum("pfi,pfi->pf", a, np.cross(b, c))
    den = la * lb * lc + np.einsum("pfi,pfi->pf", a, b) * lc + np.einsum("pfi,pfi->pf", b, c) * la
    den += np.einsum("pfi,pfi->pf", c, a) * lb
    return (2.0 * np.arctan2(num, den)).sum(axis=1) / (4.0 * np.pi)


@pytest.fixture(scope="module")
def sphere_tets(tmp_path_factory):
    v, f = sphere(3)
    workdir = tmp_path_factory.mktemp("cwd_sphere")
    cwd = os.getcwd()
    os.chdir(workdir)
    try:
        tv, tt = tetrahedralize_surface(v, f)
        assert os.getcwd() == str(workdir)
    finally:
        os.chdir(cwd)
    return v, f, tv, tt, workdir


@pytest.fixture(scope="module")
def tube_tets(tmp_path_factory):
    v, f = tube(radius=0.5, length=2.0, n_around=24, n_along=12)
    workdir = tmp_path_factory.mktemp("cwd_tube")
    cwd = os.getcwd()
    os.chdir(workdir)
    try:
        tv, tt = tetrahedralize_surface(v, f)
    finally:
        os.chdir(cwd)
    return v, f, tv, tt, workdir


@pytest.mark.parametrize("fixture", ["sphere_tets", "tube_tets"])
def test_tets_fill_the_enclosed_volume(fixture, request):
    v, f, tv, tt, workdir = request.getfixturevalue(fixture)
    assert tv.dtype == np.float64 and tt.dtype == np.int64 and tt.shape[1] == 4
    assert tt.min() >= 0 and tt.max() < tv.shape[0]
    vol = tet_volumes(tv, tt)
    assert np.all(vol > 0)
    closed_v, closed_f = close_boundary(v, f)
    assert mesh_topology(closed_f).has_boundary is False
    reference = enclosed_volume(v, f)
    # default envelope epsilon = 5e-3 × bbox diagonal: the tet boundary hugs the surface within ~2 %
    assert vol.sum() == pytest.approx(reference, rel=0.03)
    centroids = tet_centroids(tv, tt)
    w = winding_number(centroids, closed_v, closed_f)
    assert np.all(w > 0.5), (w.min(), np.sum(w <= 0.5))
    # fTetWild's side file did not leak into the working directory
    assert os.listdir(workdir) == []
    assert not os.path.exists(os.path.join(os.getcwd(), "__tracked_surface.stl"))


def test_open_tube_is_closed_by_caps(tube_tets):
    v, f, tv, tt, _ = tube_tets
    assert mesh_topology(f).has_boundary
    # the capped tube (fans to the loop centroids) is a 24-gon prism: volume = polygon area × length
    polygon_area = 0.5 * 24 * 0.5**2 * np.sin(2 * np.pi / 24)
    assert enclosed_volume(v, f) == pytest.approx(polygon_area * 2.0, rel=1e-12)
    vol = tet_volumes(tv, tt).sum()
    assert vol == pytest.approx(polygon_area * 2.0, rel=0.03)
    # the tets reach both caps
    z = tet_centroids(tv, tt)[:, 2]
    assert z.min() < -0.8 and z.max() > 0.8


def test_split_reduces_volume_spread_and_keeps_total(sphere_tets):
    _, _, tv, tt, _ = sphere_tets
    before = tet_volumes(tv, tt)
    sv, st = split_tets(tv, tt, volume_factor=1.25, passes=3)
    after = tet_volumes(sv, st)
    assert st.shape[0] > tt.shape[0]
    assert np.all(after > 0)
    assert after.max() / after.mean() < before.max() / before.mean()
    assert after.max() / after.mean() < 2.0
    assert abs(after.sum() - before.sum()) <= 1e-10
    assert np.array_equal(sv[: tv.shape[0]], tv)  # input vertices kept, midpoints appended
    # with the edge-ratio criterion as well, at least as many tets get split
    sv2, st2 = split_tets(tv, tt, volume_factor=1.25, passes=1, edge_ratio=1.25)
    _, st1 = split_tets(tv, tt, volume_factor=1.25, passes=1)
    assert st2.shape[0] >= st1.shape[0]
    assert abs(tet_volumes(sv2, st2).sum() - before.sum()) <= 1e-10


def test_single_tet_bisects_at_longest_edge_into_halves():
    v = np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    t = np.array([[0, 1, 2, 3]])
    vol = tet_volumes(v, t)[0]
    assert vol == pytest.approx(0.5)
    # the mean of a single tet is itself: a factor below 1 flags it
    sv, st = split_tets(v, t, volume_factor=0.9, passes=1)
    assert st.shape == (2, 4) and sv.shape == (5, 3)
    # longest edge is (1, 2) (length √10) → midpoint (1.5, 0.5, 0)
    np.testing.assert_allclose(sv[4], [1.5, 0.5, 0.0])
    halves = tet_volumes(sv, st)
    np.testing.assert_allclose(halves, [0.25, 0.25], rtol=0, atol=1e-15)
    assert {tuple(sorted(row)) for row in st.tolist()} == {(0, 2, 3, 4), (0, 1, 3, 4)}
    # two passes split both halves again: four quarters
    sv4, st4 = split_tets(v, t, volume_factor=0.9, passes=2)
    np.testing.assert_allclose(tet_volumes(sv4, st4), np.full(4, 0.125), rtol=0, atol=1e-15)
    # a factor above 1 flags nothing: unchanged
    sv0, st0 = split_tets(v, t, volume_factor=1.5, passes=3)
    assert np.array_equal(st0, t) and np.array_equal(sv0, v)


def test_shared_longest_edge_gets_one_midpoint():
    # two tets sharing their longest edge (0, 1)
    v = np.array([[0.0, 0, 0], [4.0, 0, 0], [2.0, 1, 0], [2.0, 0, 1], [2.0, 0, -1]])
    t = np.array([[0, 1, 2, 3], [0, 1, 4, 2]])
    assert np.all(tet_volumes(v, t) > 0)
    sv, st = split_tets(v, t, volume_factor=0.5, passes=1)
    assert sv.shape == (6, 3) and st.shape == (4, 4)
    np.testing.assert_allclose(sv[5], [2.0, 0.0, 0.0])


def test_sampling_is_keyed_and_without_replacement():
    centroids = jnp.asarray(np.random.default_rng(0).normal(size=(500, 3)))
    a = sample_tissue(jax.random.key(1), centroids, 200)
    b = sample_tissue(jax.random.key(1), centroids, 200)
    c = sample_tissue(jax.random.key(2), centroids, 200)
    assert a.shape == (200, 3) and a.dtype == centroids.dtype
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert not np.array_equal(np.asarray(a), np.asarray(c))
    # every sample is one of the centroids, none twice
    rows = {tuple(r) for r in np.asarray(centroids).tolist()}
    drawn = [tuple(r) for r in np.asarray(a).tolist()]
    assert all(r in rows for r in drawn) and len(set(drawn)) == 200
    # n ≥ K: all centroids, each once
    everything = np.asarray(sample_tissue(jax.random.key(3), centroids, 10_000))
    assert everything.shape == (500, 3)
    assert {tuple(r) for r in everything.tolist()} == rows
    # jit-compatible with a static n
    jitted = jax.jit(sample_tissue, static_argnums=2)(jax.random.key(1), centroids, 200)
    np.testing.assert_array_equal(np.asarray(jitted), np.asarray(a))


def test_sample_tissue_of_padded_centroids_draws_real_rows_only():
    """Centroids padded to a size bucket: the draw takes the real rows of the same permutation, so it
    equals the unpadded draw when nothing is padded, never returns a padding row and never one twice.
    """
    rng = np.random.default_rng(0)
    real = rng.normal(size=(300, 3)) + 5.0  # padding rows are zeros: far from every real row
    padded = jnp.asarray(np.vstack([real, np.zeros((212, 3))]))
    valid = jnp.asarray(np.arange(512) < 300)
    key = jax.random.key(4)
    unpadded = sample_tissue(key, jnp.asarray(real), 256)
    np.testing.assert_array_equal(
        np.asarray(sample_tissue(key, jnp.asarray(real), 256, jnp.ones(300, bool))), np.asarray(unpadded)
    )
    drawn = np.asarray(jax.jit(sample_tissue, static_argnums=2)(key, padded, 256, valid))
    rows = {tuple(r) for r in real.tolist()}
    assert drawn.shape == (256, 3) and all(tuple(r) in rows for r in drawn.tolist())
    assert len({tuple(r) for r in drawn.tolist()}) == 256
    # over many keys every real row is drawn about equally often (uniform without replacement)
    counts = np.zeros(300)
    index = {tuple(r): i for i, r in enumerate(real.tolist())}
    for k in range(40):
        for r in np.asarray(sample_tissue(jax.random.key(k), padded, 150, valid)).tolist():
            counts[index[tuple(r)]] += 1
    assert counts.sum() == 40 * 150 and 5 <= counts.min() and counts.max() <= 35  # mean 20


def test_soft_tissue_pipeline_on_sphere(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    v, f = sphere(2)
    result = soft_tissue(v, f, passes=2)
    assert result.tets.shape[0] > result.n_tets_initial
    np.testing.assert_allclose(result.centroids, tet_centroids(result.vertices, result.tets))
    np.testing.assert_allclose(result.volumes, tet_volumes(result.vertices, result.tets))
    assert result.volumes.sum() == pytest.approx(enclosed_volume(v, f), rel=0.04)
    assert os.listdir(tmp_path) == []


def test_bad_surfaces_raise_input_errors():
    flat_v = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    flat_f = np.array([[0, 1, 2], [0, 2, 3], [0, 2, 1], [0, 3, 2]])
    # fTetWild itself segfaults on this input: it must be refused before the call
    with pytest.raises(InputError, match="flat"):
        tetrahedralize_surface(flat_v, flat_f)
    v, f = sphere(1)
    with pytest.raises(InputError, match="face indices"):
        tetrahedralize_surface(v, f + v.shape[0])
    bad = v.copy()
    bad[0, 0] = np.nan
    with pytest.raises(InputError, match="non-finite"):
        tetrahedralize_surface(bad, f)
    with pytest.raises(InputError, match="edge_length_fac"):
        tetrahedralize_surface(v, f, edge_length_fac=0.0)


def test_thin_slab_that_fills_nothing_raises(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    from ncflow.synthetic.shapes import rounded_box

    v, f = rounded_box(2.0, 0.0, 2)
    v = v * np.array([1.0, 1.0, 1e-4])  # far thinner than the envelope: fTetWild keeps no tet
    with pytest.raises(InputError, match="no tetrahedra"):
        tetrahedralize_surface(v, f)
    assert os.listdir(tmp_path) == []


def test_missing_pytetwild_is_an_input_error(monkeypatch):
    import importlib.util

    tissue._ftetwild_extension.cache_clear()
    monkeypatch.delitem(sys.modules, "pytetwild.PyfTetWildWrapper", raising=False)
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a, **k: None)
    try:
        with pytest.raises(InputError, match="pytetwild"):
            tetrahedralize_surface(*sphere(1))
    finally:
        tissue._ftetwild_extension.cache_clear()
