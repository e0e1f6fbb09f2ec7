"""Partial targets: the restricted measures (against brute-force sums over the kept elements) and what a
half sphere shows of a sphere (against the analytic visibility)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from ncflow.geometry.topology import mesh_topology
from ncflow.matcher.partial import border_points, seen_weights, shown_parts, smoothed
from ncflow.measures import normal_cycle, normal_cycle_inner, restrict, varifold, varifold_inner
from ncflow.measures.partial import facing_weights, occlusion_cover, view_direction
from ncflow.skeleton import Skeleton


def _sphere(subdivisions=3):
    s = trimesh.creation.icosphere(subdivisions=subdivisions)
    return np.asarray(s.vertices, np.float64), np.asarray(s.faces, np.int64)


def _half(v, f, keep_vertex):
    """The faces whose three corners are kept, the vertices renumbered."""
    faces = f[np.all(keep_vertex[f], axis=1)]
    used = np.unique(faces)
    renumber = np.full(v.shape[0], -1)
    renumber[used] = np.arange(used.size)
    return v[used], renumber[faces]


def test_restrict_by_ones_is_the_measure():
    v, f = _sphere(2)
    topo = mesh_topology(f, v.shape[0])
    for x in (varifold(v, f), normal_cycle(v, topo)):
        r = restrict(x, topo, np.ones(v.shape[0]))
        np.testing.assert_array_equal(np.asarray(r.weights), np.asarray(x.weights))


@pytest.mark.parametrize("quadrature", [1, 4])
def test_restricted_varifold_is_the_varifold_of_the_faces_kept(quadrature):
    """With ω the indicator of a region, ⟨X_ω, Y⟩ is the inner product of the sub-mesh of the faces whose
    three corners are in the region (brute force: the sub-mesh's own varifold), at one or four points a face."""
    v, f = _sphere(3)
    keep = v[:, 2] > 0.1
    topo = mesh_topology(f, v.shape[0])
    y = varifold(v + [0.05, 0.0, 0.0], f)
    part = restrict(varifold(v, f, quadrature), topo, keep.astype(float))
    sub = varifold(*_half(v, f, keep), quadrature)
    for sigma in (0.2, 0.5):
        assert float(varifold_inner(part, y, sigma, 0.5)) == pytest.approx(
            float(varifold_inner(sub, y, sigma, 0.5)), rel=1e-10
        )
        assert float(varifold_inner(part, part, sigma, 0.5)) == pytest.approx(
            float(varifold_inner(sub, sub, sigma, 0.5)), rel=1e-10
        )


def test_restricted_normal_cycle_keeps_interior_edges_and_drops_the_cut():
    """ω = 0 at a cut's vertices: the cut's border edges and boundary-vertex terms (which read as a sharp
    rim) are left out and every edge away from the cut is kept with its own weight (brute force: the
    Normal Cycle of the sub-mesh, edges with both ends off the cut)."""
    v, f = _sphere(3)
    hv, hf = _half(v, f, v[:, 2] > 0.0)
    topo = mesh_topology(hf, hv.shape[0])
    assert topo.has_boundary
    omega = np.ones(hv.shape[0])
    omega[topo.boundary_vertices] = 0.0
    x = normal_cycle(hv, topo)
    part = restrict(x, topo, omega)
    w = np.asarray(part.weights)
    e = np.asarray(topo.edges)
    off_cut = (omega[e[:, 0]] > 0) & (omega[e[:, 1]] > 0)
    np.testing.assert_array_equal(w[: e.shape[0]][off_cut], np.asarray(x.weights)[: e.shape[0]][off_cut])
    assert np.all(w[: e.shape[0]][~off_cut] == 0.0)
    assert np.all(w[e.shape[0] :] == 0.0)  # no boundary-vertex term left
    # brute force: Σ_pq κ ⟨w_p, w_q⟩ over the kept rows only
    c = np.asarray(x.centers)
    keep = np.concatenate([off_cut, np.zeros(w.shape[0] - e.shape[0], bool)])
    wk, ck = np.asarray(x.weights)[keep], c[keep]
    sigma = 0.3
    kern = np.exp(-np.sum((ck[:, None] - ck[None]) ** 2, axis=-1) / (2 * sigma**2))
    assert float(normal_cycle_inner(part, part, sigma)) == pytest.approx(float(np.sum(kern * (wk @ wk.T))), rel=1e-9)


def test_smoothed_averages_over_rings_and_keeps_constants():
    v, f = _sphere(2)
    np.testing.assert_allclose(smoothed(np.full(v.shape[0], 0.7), f), 0.7)
    spike = np.zeros(v.shape[0])
    spike[0] = 1.0
    once = smoothed(spike, f, rounds=1)
    ring = np.unique(f[np.any(f == 0, axis=1)])
    assert once[0] == pytest.approx(1.0 / ring.size)  # itself and its neighbours
    assert np.all(once[np.setdiff1d(np.arange(v.shape[0]), ring)] == 0.0)


def test_border_points_lie_on_the_border_every_step():
    v, f = _sphere(3)
    hv, hf = _half(v, f, v[:, 2] > 0.0)
    topo = mesh_topology(hf, hv.shape[0])
    pts = border_points(hv, topo, np.ones(hv.shape[0], bool), 0.01)
    z_min = hv[topo.boundary_vertices, 2].max()
    assert np.all(pts[:, 2] <= z_min + 1e-12)  # on the rim's polygon
    e = np.asarray(topo.edges)[topo.boundary_edges]
    length = np.linalg.norm(hv[e[:, 0]] - hv[e[:, 1]], axis=1).sum()
    assert pts.shape[0] == pytest.approx(length / 0.01, rel=0.1)


def _one_bone():
    return Skeleton.from_arrays(np.array([[0.0, 0.0, -0.5], [0.0, 0.0, 0.5]]), np.array([-1, 0]))


def test_half_sphere_shows_the_half_it_has():
    """A sphere against the half of it with z > 0 (a camera above it): the far half (z below −2δ from the
    cut) is not shown, the half kept is, and the target's cut vertices weigh 0."""
    v, f = _sphere(4)
    hv, hf = _half(v, f, v[:, 2] > 0.0)
    shown = shown_parts(
        _one_bone(), v, f, mesh_topology(f, v.shape[0]), hv, mesh_topology(hf, hv.shape[0]), None, 0.1, "auto"
    )
    assert shown.active
    delta = shown.delta
    assert delta == pytest.approx(0.02 * np.linalg.norm(v.max(0) - v.min(0)))
    far = v[:, 2] < -2.5 * delta - 0.1  # beyond the ramp and the smoothing's reach
    near = v[:, 2] > 0.1  # beyond the smoothing's reach of the cut
    assert np.all(shown.source[far] < 0.02)
    assert np.all(shown.source[near] > 0.98)
    rim = mesh_topology(hf, hv.shape[0]).boundary_vertices
    assert np.all(shown.target[rim] == 0.0) and np.sum(shown.target == 0.0) == rim.size
    assert shown.info["source_shown_share"] == pytest.approx(0.5, abs=0.08)


def test_a_whole_target_and_a_source_border_leave_the_partial_terms_off():
    v, f = _sphere(3)
    topo = mesh_topology(f, v.shape[0])
    whole = shown_parts(_one_bone(), v, f, topo, v * 1.01, topo, None, 0.1, "auto")
    assert not whole.active and np.all(whole.source == 1.0) and np.all(whole.target == 1.0)
    # an open source (a cut sphere) against the same open shape: the target's border is the source's own
    hv, hf = _half(v, f, v[:, 2] > -0.5)
    ht = mesh_topology(hf, hv.shape[0])
    own = shown_parts(_one_bone(), hv, hf, ht, hv + [0.0, 0.0, 0.01], ht, None, 0.1, "auto")
    assert not own.active and own.info["cut_vertices"] == 0
    off = shown_parts(_one_bone(), v, f, topo, *_half_topo(v, f), None, 0.1, "off")
    auto = shown_parts(_one_bone(), v, f, topo, *_half_topo(v, f), None, 0.1, "auto")
    # "off": the data terms whole, what the half shows still computed for the record
    assert not off.active and off.partial and auto.active and auto.partial
    np.testing.assert_array_equal(off.source, auto.source)
    assert off.info["source_shown_share"] == auto.info["source_shown_share"] < 0.7


def _half_topo(v, f):
    hv, hf = _half(v, f, v[:, 2] > 0.0)
    return hv, mesh_topology(hf, hv.shape[0])


def test_a_limb_seen_from_one_side_is_shown_on_that_side_only():
    """A thin cylinder's far side faces away from the side a camera saw: not shown, though near."""
    cyl = trimesh.creation.cylinder(radius=0.3, height=3.0, sections=48)
    cyl = cyl.subdivide().subdivide()
    v, f = np.asarray(cyl.vertices), np.asarray(cyl.faces)
    n = np.asarray(cyl.vertex_normals)
    front = np.all(n[f][:, :, 1] > 0.2, axis=1)
    tv, tf = v, f[front]
    used = np.unique(tf)
    renumber = np.full(v.shape[0], -1)
    renumber[used] = np.arange(used.size)
    tv, tf = v[used], renumber[tf]
    cuts = border_points(tv, mesh_topology(tf, tv.shape[0]), np.ones(tv.shape[0], bool), 0.005)
    omega = seen_weights(v, n, f, tv, tf, cuts, 0.05)
    side = (np.abs(v[:, 2]) < 1.2) & (np.abs(n[:, 2]) < 0.5)  # the mantle, away from the caps
    assert np.all(omega[side & (n[:, 1] < -0.5)] < 0.05)
    assert np.all(omega[side & (n[:, 1] > 0.5)] > 0.95)


def test_facing_weights_cull_the_far_side_of_a_view_only():
    """Half a sphere (mean normal 0.5 along +z) culls the Diracs facing −z; a closed sphere culls nothing."""
    v, f = _sphere(3)
    hv, hf = _half(v, f, v[:, 2] > 0.0)
    half, whole = varifold(hv, hf), varifold(v, f)
    c = np.sum(np.asarray(half.weights)[:, None] * np.asarray(half.normals), 0) / np.sum(np.asarray(half.weights))
    assert np.linalg.norm(c) == pytest.approx(0.5, abs=0.07) and c[2] > 0  # a cap a little short of half: 0.5+
    n = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 0.6, -0.8], [0.0, 0.0, -0.2]])
    w = np.asarray(facing_weights(jnp.asarray(n, half.normals.dtype), half))
    u = np.clip((n @ (c / np.linalg.norm(c)) + 0.4) / 0.4, 0, 1)
    np.testing.assert_allclose(w, u * u * (3 - 2 * u), atol=1e-6)
    assert w[0] == pytest.approx(1.0) and w[1] == pytest.approx(0.0) and w[2] == pytest.approx(1.0, abs=0.02)
    np.testing.assert_array_equal(np.asarray(facing_weights(jnp.asarray(n, whole.normals.dtype), whole)), 1.0)


def test_a_capsule_seen_from_one_side_is_matched_its_far_side_following_the_skeleton(tmp_path, capsys):
    """A bent capsule seen from +y (a single view: half its surface, with a cut border) against the whole
    source: the partial terms are on, the map has a row for each of the view's points (no more), what the
    target shows is one side whole, and the far side keeps its shape and follows the bend."""
    from ncflow.cli import main
    from ncflow.geometry.mesh import face_areas
    from ncflow.io.meshes import save_mesh
    from ncflow.io.result import read_result
    from ncflow.skeleton import save_skeleton
    from ncflow.synthetic.scans import single_view
    from ncflow.synthetic.shapes import bend
    from test_defects import small_config_file, tapered_capsule_pair

    src, tgt, skel, _ = tapered_capsule_pair()
    keep = single_view(tgt.vertices, tgt.faces, np.array([0.0, -1.0, 0.0]), pixels=120)
    tv, tf = _kept_mesh(tgt.vertices, tgt.faces, keep)
    s, t, k = tmp_path / "source.ply", tmp_path / "view.ply", tmp_path / "skeleton.tgf"
    save_mesh(s, src.vertices, src.faces, precision="float64")
    save_mesh(t, tv, tf, precision="float64")
    save_skeleton(k, skel)
    out = tmp_path / "out"
    args = ["match", str(s), str(t), "--skeleton", str(k), "--out", str(out), "--steps", "30", "--set", "partial=auto"]
    assert main([*args, "--config", str(small_config_file(tmp_path))]) == 0, capsys.readouterr().err
    err = capsys.readouterr().err
    assert "partial data terms" in err
    res = read_result(out)
    assert res.n_target == tv.shape[0] and res.map_face.shape == (tv.shape[0],)
    metrics = res.metrics["partial"]
    assert metrics["active"] and 0.3 < metrics["source_shown_share"] < 0.7
    seen, rest = res.source_seen, src.vertices
    mantle = np.abs(rest[:, 2]) < 1.2
    # the capsule is round: turned about its axis by any angle and bent in the plane turned with it, it is the
    # same shape, so the side the camera saw may be any side of the source — but one side, whole. The turn is
    # read off the seen weights (their direction around the axis); the camera looked at the target's +y side.
    phi = np.arctan2(np.sum(seen[mantle] * rest[mantle, 1]), np.sum(seen[mantle] * rest[mantle, 0]))
    c, s_ = np.cos(np.pi / 2 - phi), np.sin(np.pi / 2 - phi)
    turned = rest @ np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]]).T
    assert np.mean(seen[mantle & (turned[:, 1] > 0.25)] > 0.5) > 0.9  # the side the camera saw
    assert np.mean(seen[mantle & (turned[:, 1] < -0.25)] < 0.5) > 0.9  # the far side
    # the far side follows the skeleton: near its bent rest place, its area kept
    far = mantle & (turned[:, 1] < -0.25)
    truth = bend(turned, 40.0)
    assert np.median(np.linalg.norm(res.deformed_source[far] - truth[far], axis=1)) < 0.15
    far_faces = np.all(far[src.faces], axis=1)
    ratio = face_areas(res.deformed_source, src.faces[far_faces]).sum() / face_areas(rest, src.faces[far_faces]).sum()
    assert 0.8 < ratio < 1.25


def _kept_mesh(v, f, keep):
    faces = f[keep]
    used = np.unique(faces)
    renumber = np.full(v.shape[0], -1)
    renumber[used] = np.arange(used.size)
    return v[used], renumber[faces]


def test_view_direction_is_the_depth_cameras_direction():
    """A depth view of an ellipsoid from an oblique direction: the fitted camera direction lies within 5° of
    the camera (its mean normal, pulled towards the long axes' flanks, does not need to); a closed ellipsoid
    is no view (mean normal ~0)."""
    from ncflow.synthetic.scans import single_view

    s = trimesh.creation.icosphere(subdivisions=4)
    v = np.asarray(s.vertices) * np.array([1.0, 0.45, 0.3])
    f = np.asarray(s.faces)
    look = np.array([0.5, -1.0, 0.7]) / np.linalg.norm([0.5, -1.0, 0.7])  # the camera looks along this
    hv, hf = _half(v, f, np.isin(np.arange(v.shape[0]), np.unique(f[single_view(v, f, look)])))
    d, strength = view_direction(varifold(hv, hf))
    assert float(strength) > 0.3
    assert np.degrees(np.arccos(float(np.asarray(d) @ -look))) < 5.0
    _, closed = view_direction(varifold(v, f))
    assert float(closed) < 0.02


def test_occlusion_cover_against_brute_force_and_two_sheets():
    """The cover by samples in front (the formula, pair by pair in NumPy), and two parallel sheets seen
    face on: the far sheet is covered (> 1), the near one hardly (< 0.05: its own neighbours, level with it)."""
    rng = np.random.default_rng(3)
    p, q = rng.normal(size=(7, 3)), rng.normal(size=(9, 3))
    present = (rng.uniform(size=9) > 0.3).astype(np.float64)
    d, h = np.array([0.0, 0.6, 0.8]), 0.4
    want = np.zeros(7)
    for i in range(7):
        for j in range(9):
            dz = (q[j] - p[i]) @ d
            flat = (q[j] - p[i]) - dz * d
            want[i] += present[j] * np.exp(-(flat @ flat) / (1.5 * h) ** 2) / (1 + np.exp(-(dz - 2.5 * h) / (0.5 * h)))
    got = occlusion_cover(jnp.asarray(p), jnp.asarray(q), jnp.asarray(present), jnp.asarray(d), h)
    np.testing.assert_allclose(np.asarray(got), want, rtol=1e-5, atol=1e-9)
    g = np.stack(np.meshgrid(np.arange(10) * 0.1, np.arange(10) * 0.1), -1).reshape(-1, 2)
    near, far = np.c_[g, np.ones(100)], np.c_[g, np.zeros(100)]
    both = jnp.asarray(np.vstack([near, far]))
    cover = np.asarray(occlusion_cover(both, both, jnp.ones(200), jnp.asarray([0.0, 0.0, 1.0]), 0.1))
    assert np.all(cover[100:] > 1.0) and np.all(cover[:100] < 0.05)


def test_what_a_view_hides_behind_its_surface_is_left_out():
    """Two stacked plates facing the camera against a view of the near one: the far plate's Diracs lose
    their weight, the near plate's keep it (> 0.9); against a closed target nothing changes."""
    from ncflow.matcher.pose_scorer import unhidden
    from ncflow.measures import Varifold

    g = np.stack(np.meshgrid(np.arange(12) * 0.1, np.arange(12) * 0.1), -1).reshape(-1, 2)
    up = np.tile([0.0, 0.0, 1.0], (144, 1))
    near = Varifold(jnp.asarray(np.c_[g, np.ones(144)]), jnp.asarray(up), jnp.full(144, 0.01))
    both = Varifold(
        jnp.concatenate([near.centers, near.centers - jnp.asarray([0.0, 0.0, 1.0])]),
        jnp.concatenate([near.normals, near.normals]),
        jnp.full(288, 0.01),
    )
    w = np.asarray(unhidden(both, near, 0.1).weights) / 0.01
    assert np.all(w[:144] > 0.9) and np.all(w[144:] < 0.05)
    v, f = _sphere(3)
    kept = unhidden(both, varifold(v, f), 0.1)
    np.testing.assert_array_equal(np.asarray(kept.weights), np.asarray(both.weights))
