"""Merged Diracs (ncflow.measures.merge) against brute-force NumPy Varifolds and exact invariants."""

import numpy as np
import pytest
import trimesh

from ncflow.matcher.placement import surface_diracs
from ncflow.measures.merge import merge_diracs


def face_diracs(mesh):
    return mesh.triangles_center, mesh.face_normals, mesh.area_faces


def inner(a, b, sigma, sigma_n=0.5):
    """⟨X, Y⟩ of two oriented Varifolds, every pair summed (NumPy, float64)."""
    d2 = ((a[0][:, None] - b[0][None]) ** 2).sum(-1)
    k = np.exp(-d2 / (2 * sigma**2)) * np.exp((a[1] @ b[1].T) / (2 * sigma_n**2))
    return float(a[2] @ k @ b[2])


def relative_distance(x, y, sigma):
    return (inner(x, x, sigma) - 2 * inner(x, y, sigma) + inner(y, y, sigma)) / inner(y, y, sigma)


@pytest.fixture(scope="module")
def sphere():
    return trimesh.creation.icosphere(subdivisions=4, radius=2.0)  # 5120 faces, edge ~0.16


def test_few_diracs_are_kept_as_given(sphere):
    c, n, w = face_diracs(sphere)
    out = merge_diracs(c, n, w, len(w))
    for a, b in zip(out, (c, n, w)):
        np.testing.assert_array_equal(a, b)


def test_no_area_gives_the_first_n_rows():
    c, n = np.zeros((10, 3)), np.tile([0.0, 0.0, 1.0], (10, 1))
    out = merge_diracs(c, n, np.zeros(10), 4)
    assert [a.shape[0] for a in out] == [4, 4, 4] and not out[2].any()


def test_mass_and_first_moment_are_kept(sphere):
    c, n, w = face_diracs(sphere)
    mc, mn, mw = merge_diracs(c, n, w, 400, seed=3)
    assert mc.shape == (400, 3) and mn.shape == (400, 3) and mw.shape == (400,)
    assert mw.sum() == pytest.approx(w.sum(), rel=1e-12)
    np.testing.assert_allclose(mw @ mc, w @ c, atol=1e-10)
    full = mw > 0
    np.testing.assert_allclose(np.linalg.norm(mn[full], axis=1), 1.0, atol=1e-12)
    # on a sphere a cluster's centre lies just inside the surface, its normal nearly radial
    r = np.linalg.norm(mc[full], axis=1)
    assert np.all(r < 2.0) and np.all(r > 1.9)
    assert np.all(np.einsum("ij,ij->i", mn[full], mc[full] / r[:, None]) > 0.99)


@pytest.mark.parametrize("sigma", [0.4, 0.2])
def test_merged_is_far_nearer_the_surface_than_drawn_faces(sphere, sigma):
    c, n, w = face_diracs(sphere)
    exact = (c, n, w)
    merged = merge_diracs(c, n, w, 600, seed=0)
    rng = np.random.default_rng(0)  # the rule it replaced: 600 faces drawn ∝ area, each total area / 600
    idx = rng.choice(len(w), size=600, p=w / w.sum())
    drawn = (c[idx], n[idx], np.full(600, w.sum() / 600))
    e_merged, e_drawn = relative_distance(merged, exact, sigma), relative_distance(drawn, exact, sigma)
    assert e_merged < 0.1 * e_drawn
    assert e_merged < 0.01


def test_the_two_sides_of_a_thin_part_are_not_merged():
    """Two facing sheets 0.05 apart (a thin finger's two sides, 4 × 1): no cluster takes faces of both, so
    every merged centre lies on a sheet (|z| = 0.025), none between them.
    """
    box = trimesh.creation.box(extents=(4.0, 1.0, 0.05))
    mesh = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(box.vertices, box.faces, 0.1))
    c, n, w = face_diracs(mesh)
    sheets = np.abs(n[:, 2]) > 0.9
    mc, mn, mw = merge_diracs(c[sheets], n[sheets], w[sheets], 100, seed=1)
    full = mw > 0
    np.testing.assert_allclose(np.abs(mc[full, 2]), 0.025, atol=1e-9)
    np.testing.assert_allclose(np.abs(mn[full, 2]), 1.0, atol=1e-9)


def test_seeded(sphere):
    c, n, w = face_diracs(sphere)
    a, b, other = (merge_diracs(c, n, w, 300, seed=s) for s in (5, 5, 6))
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    assert not np.array_equal(a[0], other[0])


def test_surface_diracs_merge_above_n(sphere):
    v, f = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    x = surface_diracs(v, f, 500, seed=2)
    assert x.centers.shape == (500, 3)
    assert float(np.asarray(x.weights).sum()) == pytest.approx(sphere.area, rel=1e-5)
    every = surface_diracs(v, f, 10**6)
    np.testing.assert_allclose(np.asarray(every.weights), sphere.area_faces, rtol=1e-5)
