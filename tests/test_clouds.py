"""Point-cloud targets (issue 45, item 1): outliers, normals oriented outward, the surface made of a cloud,
and a match against a cloud whose outputs map every point; checked against analytic shapes and brute force."""

import json

import numpy as np
import pytest
from scipy.spatial import cKDTree

from ncflow.cli import main
from ncflow.errors import InputError
from ncflow.evaluate.score import evaluate_result
from ncflow.geometry.barycentric import surface_points
from ncflow.geometry.closest import closest_points_on_surface
from ncflow.geometry.cloud import (
    PointCloud,
    cloud_outliers,
    estimate_normals,
    exterior_signs,
    orient_normals,
    oriented_normals,
    point_spacing,
)
from ncflow.geometry.reconstruct import reconstruct_surface
from ncflow.geometry.topology import mesh_topology
from ncflow.geometry.winding import signed_volume
from ncflow.io.ground_truth import GroundTruth
from ncflow.io.meshes import save_mesh
from ncflow.io.points import load_target, save_points
from ncflow.io.result import read_result
from ncflow.matcher.prepare import prepare
from ncflow.skeleton import save_skeleton
from ncflow.track.frames import frame_files
from ncflow.view.page import target_display
from test_defects import small_config, small_config_file, tapered_capsule_pair


def sphere_points(n, seed=0):
    u = np.random.default_rng(seed).normal(size=(n, 3))
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def fibonacci_sphere(n):
    """n points spread evenly over the unit sphere (a scan's or a mesh's sampling, without random gaps)."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    a = np.pi * (1 + 5**0.5) * i
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(a), r * np.sin(a), z], axis=1)


def torus_points(n, major=1.0, minor=0.25, seed=0):
    """Points on a torus (a thin ring: the two sides of its tube are close) and their outward normals."""
    rng = np.random.default_rng(seed)
    a, b = rng.uniform(0, 2 * np.pi, (2, n))
    centre = np.stack([major * np.cos(a), major * np.sin(a), np.zeros(n)], axis=1)
    normal = np.stack([np.cos(a) * np.cos(b), np.sin(a) * np.cos(b), np.sin(b)], axis=1)
    return centre + minor * normal, normal


def test_flying_pixels_are_the_outliers():
    rng = np.random.default_rng(1)
    sphere = sphere_points(3000)
    far = rng.uniform(-3, 3, size=(40, 3))
    far = far[np.linalg.norm(far, axis=1) > 1.5]
    found = cloud_outliers(np.vstack([sphere, far]))
    assert found[len(sphere) :].all()
    assert found[: len(sphere)].sum() <= 3  # a random sampling has a few sparse spots


def test_a_cloud_whose_points_are_each_given_many_times_has_the_same_outliers():
    p = np.vstack([sphere_points(1000), [[3.0, 0.0, 0.0]]])
    once = cloud_outliers(p)
    assert once[-1] and once[:-1].sum() <= 2
    np.testing.assert_array_equal(cloud_outliers(np.repeat(p, 20, axis=0)), np.repeat(once, 20))


def test_estimated_normals_are_the_sphere_s_radial_directions_pointing_out():
    p = sphere_points(2000)
    n = oriented_normals(PointCloud(p))
    assert np.min(np.einsum("ij,ij->i", n, p)) > 0.95


def test_normals_of_a_thin_torus_are_oriented_outward_without_crossing_the_tube():
    p, truth = torus_points(6000)
    n = orient_normals(p, estimate_normals(p))
    dots = np.einsum("ij,ij->i", n, truth)
    assert np.mean(dots < 0) < 0.01
    assert np.mean(np.abs(dots) > 0.9) > 0.95


def test_normals_from_the_file_keep_their_signs_but_are_turned_out_when_inward():
    p, truth = torus_points(3000, seed=2)
    n = oriented_normals(PointCloud(p, -truth))  # a file whose normals all point in
    np.testing.assert_allclose(n, truth, atol=1e-12)


def test_the_outside_of_a_sealed_cloud_decides_the_signs_and_a_leaking_one_does_not_claim_to():
    p = sphere_points(4000, seed=3)
    radial = p.copy()
    flip = np.random.default_rng(0).random(len(p)) < 0.3
    given = np.where(flip[:, None], -radial, radial)
    signs = exterior_signs(p, given, point_spacing(p))
    decided = signs != 0
    assert decided.mean() > 0.95
    np.testing.assert_array_equal(signs[decided], np.where(flip, -1, 1)[decided])
    # a hemisphere is open: the outside reaches the inside, so most points are undecided or both ways
    half = p[p[:, 2] > 0]
    s = exterior_signs(half, half, point_spacing(half))
    assert np.mean(s == 1) < 0.9  # measured: 0 (no level seals it)


def test_the_surface_of_a_sphere_cloud_is_the_sphere_closed_and_wound_outward():
    p = fibonacci_sphere(4000)
    v, f = reconstruct_surface(p, p, point_spacing(p))
    r = np.linalg.norm(v, axis=1)
    assert np.abs(r - 1).max() < 0.01
    assert not mesh_topology(f, len(v)).boundary_edges.any()  # closed
    assert signed_volume(v, f) == pytest.approx(4 / 3 * np.pi, rel=0.03)


def test_a_half_seen_sphere_gives_an_open_surface_and_nothing_where_the_scan_saw_nothing():
    p = fibonacci_sphere(6000)
    half = p[p[:, 2] > 0]
    s = point_spacing(half)
    v, f = reconstruct_surface(half, half, s)
    assert mesh_topology(f, len(v)).boundary_edges.any()  # open at the cut
    assert v[:, 2].min() > -2.5 * s  # the band ends near the cut: no cap, no far side
    assert np.abs(np.linalg.norm(v, axis=1) - 1).max() < 0.02
    # the surface faces outward: its normals agree with the radial direction
    a, b, c = (v[f[:, k]] for k in range(3))
    fn = np.cross(b - a, c - a)
    assert np.einsum("ij,ij->", fn, (a + b + c) / 3) > 0


def test_a_cloud_too_small_flat_or_broken_is_refused_in_one_line_naming_it(tmp_path):
    src, _, skel = _capsule_pair()
    for points, said in (
        (sphere_points(50), "distinct points"),
        (np.c_[np.random.default_rng(0).random((500, 2)), np.zeros(500)], "plane"),
        (np.where(np.arange(300)[:, None] == 7, np.nan, sphere_points(300)), "non-finite"),
    ):
        with pytest.raises(InputError, match=said) as info:
            prepare(src, PointCloud(points, None, "scan.xyz"), skel, small_config(pose_search="false"))
        assert "scan.xyz" in str(info.value) and "\n" not in str(info.value)


def _capsule_pair():
    src, tgt, skel, truth = tapered_capsule_pair(16, 24)
    return src, (tgt.vertices, truth), skel


def test_a_match_against_a_point_cloud_maps_every_point_and_writes_the_cloud_as_the_target(tmp_path, capsys):
    src, (points, truth), skel = _capsule_pair()
    rng = np.random.default_rng(7)
    flying = rng.uniform(-3, 3, size=(6, 3)) + np.array([0, 0, 6.0])  # flying pixels beyond the bent capsule
    cloud = np.vstack([points, flying])
    s, t, k = tmp_path / "source.ply", tmp_path / "scan.xyz", tmp_path / "skeleton.tgf"
    save_mesh(s, src.vertices, src.faces, precision="float64")
    np.savetxt(t, cloud, fmt="%.12g")
    save_skeleton(k, skel)
    cfg = small_config_file(tmp_path)
    out = tmp_path / "out"
    rc = main(["match", str(s), str(t), "--skeleton", str(k), "--out", str(out), "--config", str(cfg), "--steps", "4"])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert f"a point cloud of {len(cloud)} points" in err and "6 outliers left out" in err
    res = read_result(out)
    assert res.n_target == len(cloud) and res.target_faces.shape == (0, 3)
    np.testing.assert_allclose(res.target_vertices, cloud, atol=1e-5 * 6)  # target.ply: the cloud, float32
    assert isinstance(load_target(out / "target.ply"), PointCloud)
    # every point of the file has its source point; the true ones land near their truth
    found = surface_points(src.vertices, src.faces, res.map_face, res.map_bary)
    assert np.all(np.isfinite(found))
    assert np.median(np.linalg.norm(found[: len(points)] - truth, axis=1)) < 0.15
    # source -> target: the nearest point of the cloud to each flowed source vertex (no faces to project on)
    _, nearest = cKDTree(cloud).query(res.deformed_source)
    np.testing.assert_array_equal(res.p2p_src_to_tgt, nearest)
    metrics = json.loads((out / "metrics.json").read_text())
    info = metrics["target_cloud"]
    assert info["n_points"] == len(cloud) and info["n_outliers"] == 6 and info["normals"] == "estimated"
    assert sorted(info["outlier_indices"]) == list(range(len(points), len(cloud)))
    # the page shows the cloud as a small tetrahedron per point, each coloured by its point
    kept, faces, positions = target_display(res.target_vertices, res.target_faces, 100_000)
    assert faces.shape == (4 * len(cloud), 3) and kept.shape == (4 * len(cloud),)
    np.testing.assert_allclose(positions.reshape(-1, 4, 3).mean(axis=1), res.target_vertices[kept[::4]], atol=1e-9)
    assert main(["view", str(out), "--out", str(tmp_path / "page.html")]) == 0
    assert (tmp_path / "page.html").stat().st_size > 10_000
    # scored against its ground truth (partial: the flying pixels have none); Chamfer to the nearest points
    _, face, bary = closest_points_on_surface(truth, src.vertices, src.faces)
    gt = GroundTruth(face=face, bary=bary, target_index=np.arange(len(points)), n_target=len(cloud), name="gt")
    ev = evaluate_result(out, s, t, gt)
    scale = ev.record["summary"]["unit_cube_scale"]
    np.testing.assert_allclose(
        ev.arrays["chamfer_src_to_tgt"], cKDTree(cloud).query(res.deformed_source)[0] * scale, rtol=1e-5, atol=1e-7
    )
    assert 0.5 < ev.record["headline"]["geodesic_auc"] <= 1.0


def test_a_point_cloud_target_given_as_an_object_and_its_saved_form_round_trip(tmp_path):
    p = sphere_points(500, seed=8) * 2.0
    path = tmp_path / "cloud.ply"
    save_points(path, p)
    back = load_target(path)
    assert isinstance(back, PointCloud) and back.faces.shape == (0, 3)
    np.testing.assert_allclose(back.vertices, p, atol=1e-6)


def test_a_folder_of_frames_lists_its_point_clouds_but_not_its_notes(tmp_path):
    for name in ("f10.xyz", "f2.npy", "f1.ply", "notes.txt", "f3.txt"):
        (tmp_path / name).write_text("")
    assert [p.name for p in frame_files(tmp_path)] == ["f1.ply", "f2.npy", "f10.xyz"]
    assert [p.name for p in frame_files(str(tmp_path / "f*"))] == ["f1.ply", "f2.npy", "f3.txt", "f10.xyz"]
