"""Evaluation metrics: closed forms, perfect results, known distortions, analytic geodesics."""

import numpy as np
import pytest
import trimesh

from ncflow.evaluate import (
    TAU_MAX,
    auc,
    bone_violation,
    chamfer_distances,
    closest_points_on_surface,
    conformal_distortion,
    error_summary,
    evaluate_correspondence,
    geodesic_errors,
    insert_surface_points,
    inverted_triangles,
    pair_geodesic_distances,
    pck_curve,
    point_triangle_closest,
    surface_points,
    triangle_singular_values,
    unit_cube_scale,
    vertex_surface_points,
    volume_change,
)
from ncflow.geometry.mesh import Mesh, face_areas
from ncflow.synthetic.shapes import capsule, sphere


def grid(n=9, size=2.0):
    """Flat square sheet in z = 0, (n × n) vertices, side ``size``."""
    s = np.linspace(-size / 2, size / 2, n)
    x, y = np.meshgrid(s, s, indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], 1)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    f = np.concatenate([np.stack([a, a + n, a + n + 1], 1), np.stack([a, a + n + 1, a + 1], 1)])
    return v, f.astype(np.int64)


def unit_sphere(subdivisions=3):
    v, f = sphere(subdivisions)
    return v / np.linalg.norm(v, axis=1, keepdims=True), f


def rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


# ----------------------------------------------------------------------------------------------
# PCK / AUC


def test_auc_closed_form_equals_numerical_integral():
    rng = np.random.default_rng(0)
    for tau in (0.2, 0.1, 0.15):
        e = rng.exponential(tau * 0.6, size=3000)
        e[:50] = np.inf  # failures count as misses
        e[50:60] = np.nan  # left out
        t, pck = pck_curve(e, tau, n_thresholds=100_001)
        numeric = np.trapezoid(pck, t) / tau
        assert auc(e, tau) == pytest.approx(numeric, abs=2e-5)
        finite = e[np.isfinite(e)]
        assert auc(e, tau) == pytest.approx(np.mean(np.maximum(0, 1 - finite / tau)) * finite.size / (finite.size + 50))


def test_pck_curve_and_summary_values():
    e = np.array([0.0, 0.05, 0.1, 0.3])
    t, pck = pck_curve(e, 0.2, n_thresholds=5)  # τ = 0, .05, .1, .15, .2
    np.testing.assert_allclose(t, [0, 0.05, 0.1, 0.15, 0.2])
    np.testing.assert_allclose(pck, [0.25, 0.5, 0.75, 0.75, 0.75])
    assert auc(e, 0.2) == pytest.approx((1 + 0.75 + 0.5 + 0) / 4)
    s = error_summary(np.array([0.1, np.nan, 0.3]), 0.2)
    assert s["n"] == 2 and s["n_nan"] == 1 and s["mean"] == pytest.approx(0.2) and s["median"] == pytest.approx(0.2)
    assert s["auc"] == pytest.approx(0.25)
    assert TAU_MAX == {"geodesic": 0.20, "chamfer": 0.10, "conformal": 0.15}


def test_unit_cube_scale():
    v = np.array([[0, 0, 0], [4, 1, 0], [1, 2, 0.5]], float)
    assert unit_cube_scale(v) == 0.25


# ----------------------------------------------------------------------------------------------
# Geodesics


def test_insert_surface_points_keeps_surface():
    v, f = unit_sphere(2)
    rng = np.random.default_rng(1)
    face = np.concatenate([rng.integers(0, len(f), 300), [3, 3, 3, 7]])
    bary = np.concatenate([rng.dirichlet([1, 1, 1], 300), np.eye(3)[[0, 1, 2]], [[0.5, 0.5, 0.0]]])
    v2, f2, ids = insert_surface_points(v, f, face, bary)
    assert face_areas(v2, f2).sum() == pytest.approx(face_areas(v, f).sum(), rel=1e-12)
    np.testing.assert_allclose(v2[ids], surface_points(v, f, face, bary), atol=1e-6)
    np.testing.assert_array_equal(ids[300:303], f[3])  # vertices stay vertices
    # consistent orientation: the refined mesh is still a closed, oriented surface
    assert trimesh.Trimesh(v2, f2, process=False).is_winding_consistent


def test_geodesic_error_zero_for_perfect_map():
    v, f = unit_sphere(3)
    src = Mesh(v, f)
    face, bary = vertex_surface_points(np.arange(len(v)), f)
    e = geodesic_errors(src, face, bary, face, bary)
    assert np.all(e == 0)
    assert auc(e, TAU_MAX["geodesic"]) == 1.0


def test_geodesic_exact_on_flat_sheet_matches_euclid():
    v, f = grid(11, 2.0)
    rng = np.random.default_rng(2)
    n = 400
    fa, fb = rng.integers(0, len(f), n), rng.integers(0, len(f), n)
    ba, bb = rng.dirichlet([1, 1, 1], n), rng.dirichlet([1, 1, 1], n)
    ba[:20] = [0.5, 0.5, 0.0]  # points on edges
    d, info = pair_geodesic_distances(v, f, fa, ba, fb, bb, method="exact")
    want = np.linalg.norm(surface_points(v, f, fa, ba) - surface_points(v, f, fb, bb), axis=1)
    assert info.n_exact == n - int(np.sum(want == 0))
    # inserted points are kept 1e-6 (in barycentrics) inside their face: edge points move ≤ 3e-7
    np.testing.assert_allclose(d, want, rtol=1e-9, atol=1e-6)
    # normalised: divided by sqrt(area) = 2
    e = geodesic_errors(Mesh(v, f), fa, ba, fb, bb, method="exact")
    np.testing.assert_allclose(e, want / 2.0, rtol=1e-9, atol=1e-6)


def _shift_on_sphere(x, v, f, arc, rng):
    """For each point x (on the unit sphere), the mesh point at great-circle arc ``arc`` in a random direction."""
    t = rng.normal(size=x.shape)
    t -= np.sum(t * x, 1, keepdims=True) * x
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    q = np.cos(arc) * x + np.sin(arc) * t  # on the unit sphere
    d, face, bary = closest_points_on_surface(q, v, f)  # foot point on the polyhedron (≈ radial)
    return face, bary


@pytest.mark.parametrize("arc,method,rtol", [(0.15, "auto", 0.01), (0.15, "exact", 0.01), (1.2, "heat", 0.03)])
def test_geodesic_error_of_shifted_map_on_sphere(arc, method, rtol):
    v, f = unit_sphere(3)  # 642 vertices; area → 4π as the mesh refines
    rng = np.random.default_rng(3)
    sel = rng.choice(len(v), 150, replace=False)
    gt_face, gt_bary = vertex_surface_points(sel, f)
    face, bary = _shift_on_sphere(v[sel], v, f, arc, rng)
    src = Mesh(v, f)
    e, info = geodesic_errors(src, face, bary, gt_face, gt_bary, method=method, return_info=True)
    # hand-computed: arc length (great circle through the foot point) over sqrt(area)
    p = surface_points(v, f, face, bary)
    true_arc = np.arccos(np.clip(np.sum(p / np.linalg.norm(p, axis=1, keepdims=True) * v[sel], 1), -1, 1))
    want = true_arc / np.sqrt(face_areas(v, f).sum())
    np.testing.assert_allclose(e, want, rtol=rtol)
    assert np.median(np.abs(e / want - 1)) < rtol / 2
    if method == "auto":
        assert info.n_exact == 150 and info.n_heat == 0
    if method == "heat":
        assert info.n_heat == 150


def test_geodesic_auto_uses_heat_for_far_pairs_and_inf_across_components():
    a, fa = unit_sphere(3)
    b = a + [5.0, 0, 0]
    v = np.concatenate([a, b])
    f = np.concatenate([fa, fa + len(a)])
    face, bary = vertex_surface_points(np.array([0, 1, len(a) + 2]), f)
    gface, gbary = vertex_surface_points(np.array([0, int(np.argmin(a @ a[1])), 3]), f)
    d, info = pair_geodesic_distances(v, f, face, bary, gface, gbary)
    assert d[0] == 0 and np.isinf(d[2]) and info.n_unreachable == 1
    assert info.n_heat == 1  # antipode: far, heat method
    exact, info = pair_geodesic_distances(v, f, face[1:2], bary[1:2], gface[1:2], gbary[1:2], method="exact")
    assert info.n_exact == 1 and exact[0] == pytest.approx(np.pi, rel=0.01)
    assert d[1] == pytest.approx(exact[0], rel=0.03)


def test_geodesic_exact_falls_back_on_non_manifold_mesh():
    # three triangles sharing the edge (0, 1): the exact solver needs a manifold mesh
    v = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -1, 0], [0.5, 0, 1.0]])
    f = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    one = np.array([[0, 0, 1.0]])
    d, info = pair_geodesic_distances(v, f, np.array([0]), one, np.array([1]), one, method="exact")
    assert info.n_exact == 0 and info.n_heat == 1 and "exact solver failed" in info.notes[0]
    assert d[0] == pytest.approx(2.0, rel=0.01)  # straight across the shared edge


# ----------------------------------------------------------------------------------------------
# Point-to-surface and Chamfer


def test_point_triangle_closest_regions():
    a, b, c = np.array([0.0, 0, 0]), np.array([1.0, 0, 0]), np.array([0.0, 1, 0])
    p = np.array([[0.2, 0.2, 0.7], [-1, -1, 0], [2, -0.5, 0], [0.5, -2, 1], [1, 1, 0], [-3, 0.5, 0]])
    n = len(p)
    d, bary = point_triangle_closest(p, np.tile(a, (n, 1)), np.tile(b, (n, 1)), np.tile(c, (n, 1)))
    np.testing.assert_allclose(d, [0.7, np.sqrt(2), np.sqrt(1.25), np.sqrt(5), np.sqrt(0.5), 3.0])
    np.testing.assert_allclose(bary[0], [0.6, 0.2, 0.2])
    np.testing.assert_allclose(bary[4], [0, 0.5, 0.5])
    # random triangles: never above a dense sampling of the triangle, and close to it
    rng = np.random.default_rng(4)
    tri = rng.normal(size=(200, 3, 3))
    q = rng.normal(size=(200, 3)) * 2
    d, bary = point_triangle_closest(q, tri[:, 0], tri[:, 1], tri[:, 2])
    g = np.linspace(0, 1, 61)
    u, w = np.meshgrid(g, g)
    keep = u + w <= 1
    bs = np.stack([1 - u[keep] - w[keep], u[keep], w[keep]], 1)
    samples = np.einsum("sk,tkd->tsd", bs, tri)
    sampled = np.linalg.norm(samples - q[:, None], axis=2).min(1)
    assert np.all(d <= sampled + 1e-12)
    assert np.all(sampled - d < 0.05 * np.linalg.norm(tri[:, 1] - tri[:, 0], axis=1).max())
    np.testing.assert_allclose(np.linalg.norm(np.einsum("nk,nkd->nd", bary, tri) - q, axis=1), d)


def test_closest_points_exact_on_nonuniform_mesh():
    s = trimesh.creation.icosphere(3)
    box = trimesh.creation.box(extents=[6, 6, 6])  # 12 huge triangles next to 1280 small ones
    m = trimesh.util.concatenate([s, box])
    v, f = np.asarray(m.vertices), np.asarray(m.faces)
    q = np.random.default_rng(5).uniform(-4, 4, size=(500, 3))
    d, face, bary = closest_points_on_surface(q, v, f)
    n = len(q)
    brute = np.stack(
        [point_triangle_closest(q, *(np.tile(v[f[t, k]], (n, 1)) for k in range(3)))[0] for t in range(len(f))], 1
    )
    np.testing.assert_allclose(d, brute.min(1), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(surface_points(v, f, face, bary) - q, axis=1), d, atol=1e-12)


def test_chamfer_zero_for_identical_and_known_offset():
    v, f = capsule(n_around=16, n_along=10)
    tgt = Mesh(v, f)
    a, b = chamfer_distances(v, f, tgt, scale=unit_cube_scale(v))
    assert np.abs(a).max() < 1e-12 and np.abs(b).max() < 1e-12
    gv, gf = grid(9, 2.0)
    lifted = gv + [0, 0, 0.05]
    a, b = chamfer_distances(lifted, gf, Mesh(gv, gf), scale=0.5)
    np.testing.assert_allclose(a, 0.025)
    np.testing.assert_allclose(b, 0.025)


# ----------------------------------------------------------------------------------------------
# Conformal distortion


def test_conformal_zero_for_rigid_motion_and_uniform_scaling():
    v, f = capsule(n_around=16, n_along=10)
    r = rotation([1, 2, 3], 0.8)
    frames = np.stack([v, v @ r.T + [1, -2, 3], 2.5 * v @ r.T])
    k1, mips = conformal_distortion(v, f, frames)
    assert k1.shape == (3, len(f))
    assert np.abs(k1).max() < 1e-7 and np.abs(mips).max() < 1e-12
    s1, s2 = triangle_singular_values(v, f, frames[2])
    np.testing.assert_allclose(s1, 2.5, rtol=1e-9)
    np.testing.assert_allclose(s2, 2.5, rtol=1e-9)


def test_conformal_known_stretch_and_general_map():
    v, f = grid(7, 2.0)
    stretched = v * [2.0, 1.0, 1.0]
    k1, mips = conformal_distortion(v, f, stretched)
    np.testing.assert_allclose(k1, 1.0, rtol=1e-12)  # s1/s2 = 2
    np.testing.assert_allclose(mips, 2 + 0.5 - 2, rtol=1e-12)
    # arbitrary deformation: compare with a direct SVD of J = Q P⁻¹
    rng = np.random.default_rng(6)
    x = v + rng.normal(scale=0.1, size=v.shape)
    s1, s2 = triangle_singular_values(v, f, x)
    t, d = v[f], x[f]
    p = np.stack([t[:, 1, :2] - t[:, 0, :2], t[:, 2, :2] - t[:, 0, :2]], 2)  # rest is planar: its own frame
    q = np.stack([d[:, 1] - d[:, 0], d[:, 2] - d[:, 0]], 2)
    sv = np.linalg.svd(q @ np.linalg.inv(p), compute_uv=False)
    np.testing.assert_allclose(s1, sv[:, 0], rtol=1e-10)
    np.testing.assert_allclose(s2, sv[:, 1], rtol=1e-10)
    k1, mips = conformal_distortion(v, f, x)
    np.testing.assert_allclose(k1, sv[:, 0] / sv[:, 1] - 1, rtol=1e-9)
    np.testing.assert_allclose(mips, sv[:, 0] / sv[:, 1] + sv[:, 1] / sv[:, 0] - 2, rtol=1e-8)


def test_conformal_collapsed_triangle_is_inf():
    v, f = grid(3, 2.0)
    x = v.copy()
    x[:, 1] = 0.0  # every triangle collapses to a segment
    k1, mips = conformal_distortion(v, f, x)
    assert np.all(np.isinf(k1)) and np.all(np.isinf(mips))


# ----------------------------------------------------------------------------------------------
# Plausibility


def test_inverted_triangles_reflection_and_fold():
    v, f = grid(7, 2.0)
    mirrored = v * [-1.0, 1.0, 1.0]
    assert inverted_triangles(v, f, mirrored, mode="global").all()
    # a planar mirror image is a 3-D rotation: no fold-over in the local mode
    assert not inverted_triangles(v, f, mirrored, mode="local").any()
    # fold: drag one interior vertex across its neighbours
    x = v.copy()
    c = 3 * 7 + 3
    x[c, :2] += [0.55, 0.1]
    folded = _signed_area_2d(x, f) < 0
    assert 0 < folded.sum() < 6
    np.testing.assert_array_equal(inverted_triangles(v, f, x, mode="local"), folded)
    np.testing.assert_array_equal(inverted_triangles(v, f, x, mode="global"), folded)


def _signed_area_2d(x, f):
    t = x[f][:, :, :2]
    return (t[:, 1, 0] - t[:, 0, 0]) * (t[:, 2, 1] - t[:, 0, 1]) - (t[:, 1, 1] - t[:, 0, 1]) * (t[:, 2, 0] - t[:, 0, 0])


def test_inverted_triangles_local_finds_folds_after_rotation():
    v, f = grid(25, 2.0)
    rng = np.random.default_rng(7)
    r = rotation([1, 2, 0.5], 2.5)  # 143°: the global test calls most of the sheet inverted
    for n_moved, scale in ((13, 0.16), (33, 0.08), (53, 0.24)):
        x = v.copy()
        k = rng.choice(len(v), n_moved, replace=False)
        x[k, :2] += rng.normal(scale=scale, size=(n_moved, 2))
        folded = _signed_area_2d(x, f) < 0
        assert folded.sum() > 5
        np.testing.assert_array_equal(inverted_triangles(v, f, x @ r.T), folded)
        assert inverted_triangles(v, f, x @ r.T, mode="global").sum() > len(f) // 2


def test_inverted_triangles_local_ignores_articulation():
    v, f = capsule(n_around=16, n_along=12)
    r = rotation([1, 0, 0], np.pi * 0.9)
    frames = np.stack([v, v @ r.T])
    assert inverted_triangles(v, f, frames, mode="global")[1].sum() > len(f) // 3
    assert inverted_triangles(v, f, frames, mode="local").sum() == 0


def test_volume_change_for_known_scaling():
    v, f = capsule(n_around=16, n_along=10)
    frames = np.stack([v, 1.1 * v, 0.5 * v + 3.0])
    np.testing.assert_allclose(volume_change(frames, f), [0.0, 1.1**3 - 1, 0.5**3 - 1], atol=1e-12)


def test_bone_violation():
    ref = np.zeros((2, 4, 3))
    flowed = ref.copy()
    flowed[1, :, 0] = [0.1, 0.2, 0.0, 0.1]
    g = bone_violation(flowed, ref)
    np.testing.assert_allclose(g, [0.0, (0.01 + 0.04 + 0.0 + 0.01) / 4])
    np.testing.assert_allclose(bone_violation(flowed, ref, scale=2.0), 4 * g)


# ----------------------------------------------------------------------------------------------
# Everything


def test_evaluate_correspondence_perfect_pair():
    v, f = capsule(n_around=16, n_along=10)
    src = Mesh(v, f)
    r = rotation([0, 1, 1], 0.6)
    tgt = Mesh(v @ r.T + [0.3, 0, 0], f)
    face, bary = vertex_surface_points(np.arange(len(v)), f)
    frames = np.stack([v, (v @ rotation([0, 1, 1], 0.3).T) + [0.15, 0, 0], tgt.vertices])
    out = evaluate_correspondence(src, tgt, face, bary, face, bary, frames=frames)
    s, arr = out["summary"], out["arrays"]
    assert s["geodesic"]["auc"] == 1.0 and s["geodesic"]["mean"] == 0.0
    assert s["chamfer"]["auc"] == pytest.approx(1.0) and s["chamfer"]["mean"] < 1e-12
    assert s["conformal"]["auc"] == pytest.approx(1.0, abs=1e-6) and s["mips"]["mean"] < 1e-12
    assert s["inverted_triangles"] == [0, 0, 0]
    np.testing.assert_allclose(s["volume_change"], 0.0, atol=1e-12)
    assert s["unit_cube_scale"] == pytest.approx(1 / np.max(v.max(0) - v.min(0)))
    assert arr["geodesic"].shape == (len(v),) and arr["conformal"].shape == (3, len(f))
    assert arr["chamfer_src_to_tgt"].shape == (len(v),) and arr["chamfer_tgt_to_src"].shape == (len(v),)


def test_evaluate_correspondence_partial_ground_truth_and_shift():
    v, f = unit_sphere(2)
    src = Mesh(v, f)
    pface, pbary = vertex_surface_points(np.arange(len(v)), f)
    nbr = f[pface, 1]  # predict a neighbouring vertex: error = edge length / sqrt(area)
    sel = np.arange(0, len(v), 3)
    nface, nbary = vertex_surface_points(nbr[sel], f)
    out = evaluate_correspondence(src, src, pface, pbary, nface, nbary, gt_index=sel)
    geo = out["arrays"]["geodesic"]
    assert np.isnan(geo[1]) and out["summary"]["geodesic"]["n"] == sel.size
    want = np.linalg.norm(v[sel] - v[nbr[sel]], axis=1) / np.sqrt(face_areas(v, f).sum())
    np.testing.assert_allclose(geo[sel], want, rtol=1e-9)  # an edge is a polyhedral geodesic
    assert "chamfer" not in out["summary"] and "conformal" not in out["summary"]


def test_evaluate_correspondence_rejects_bad_shapes():
    v, f = unit_sphere(1)
    src = Mesh(v, f)
    face, bary = vertex_surface_points(np.arange(len(v)), f)
    with pytest.raises(ValueError, match="predicted map"):
        evaluate_correspondence(src, src, face[:-1], bary[:-1], face, bary)
    with pytest.raises(ValueError, match="frames"):
        evaluate_correspondence(src, src, face, bary, face, bary, frames=np.zeros((2, 3, 3)))
