"""The matcher end to end on a small bent-capsule pair (different triangulations)."""

import dataclasses
import json

import numpy as np
import pytest

from ncflow.cli import main
from ncflow.config import apply_overrides, preset
from ncflow.errors import InputError
from ncflow.evaluate import auc, closest_points_on_surface, geodesic_errors
from ncflow.geometry.mesh import Mesh
from ncflow.geometry.overlap import self_overlap
from ncflow.io.meshes import save_mesh
from ncflow.io.result import read_result
from ncflow.matcher.inputs import check_precision, check_sizes, diameter, load_inputs, size_ratio
from ncflow.matcher.prepare import prepare
from ncflow.matcher.steps import Matcher, match
from ncflow.skeleton import Skeleton, save_skeleton
from ncflow.synthetic.shapes import bend, capsule

BEND = 70.0


def small_config(steps=(60, 90), **overrides):
    cfg = apply_overrides(
        preset("fast"),
        [
            "flow.width=64",
            "flow.depth=3",
            "flow.gso_width=16",
            "flow.gso_depth=1",
            "sampling.bone_samples=10",
            "sampling.tissue_samples=64",
            "sampling.surface_edges=256",
            "compress=600",
            "frames=5",
        ]
        + [f"{k}={v}" for k, v in overrides.items()],
    )
    phases = tuple(dataclasses.replace(p, steps=n) for p, n in zip(cfg.phases, steps))
    return dataclasses.replace(cfg, phases=phases)


@pytest.fixture(scope="module")
def pair():
    vs, fs = capsule(radius=0.4, length=3.0, n_around=12, n_along=18)
    vt_rest, ft = capsule(radius=0.4, length=3.0, n_around=14, n_along=15, diagonal="left")
    src = Mesh(vs, fs, "source")
    tgt = Mesh(bend(vt_rest, BEND), ft, "target")
    skel = Skeleton.from_arrays(np.array([[0, 0, -1.6], [0, 0, 0.0], [0, 0, 1.6]]), np.array([-1, 0, 1]))
    # ground truth: each target vertex is the bent image of its rest position, which lies on the
    # source capsule up to faceting; its closest point on the source mesh is the true match
    _, gt_face, gt_bary = closest_points_on_surface(vt_rest, vs, fs)
    return src, tgt, skel, gt_face, gt_bary


@pytest.fixture(scope="module")
def mdmm_result(pair):
    src, tgt, skel, *_ = pair
    return match(src, tgt, skel, small_config(), quiet=True)


def test_correspondence_beats_nearest_neighbour_of_unaligned_shapes(pair, mdmm_result):
    src, tgt, skel, gt_face, gt_bary = pair
    r = mdmm_result
    err = geodesic_errors(src, r.maps["map_face"], r.maps["map_bary"], gt_face, gt_bary)
    # baseline: nearest source point of each target vertex with the shapes as given (unaligned)
    _, nn_face, nn_bary = closest_points_on_surface(tgt.vertices, src.vertices, src.faces)
    err_nn = geodesic_errors(src, nn_face, nn_bary, gt_face, gt_bary)
    ours, baseline = auc(err, 0.2), auc(err_nn, 0.2)
    assert ours > baseline + 0.15, (ours, baseline)
    # the fitted skeleton bends its second bone by about the true angle
    d0 = skel.positions[2] - skel.positions[1]
    d1 = r.skeleton_target.positions[2] - r.skeleton_target.positions[1]
    angle = np.degrees(np.arccos(d0 @ d1 / np.linalg.norm(d0) / np.linalg.norm(d1)))
    assert abs(angle - BEND) < 15.0


def test_mdmm_meets_tolerance_and_soft_mode_does_not(pair, mdmm_result):
    src, tgt, skel, *_ = pair
    # The capsule is bent smoothly, not at a hinge, so its ground truth is not rigid around the
    # bones and the constraints must fight the match: a test of the MDMM machinery itself, run
    # with the paper's field (the skeleton-driven field would carry most of the bend). No tissue term:
    # fTetWild's tetrahedra differ from call to call (std::random_device in its shuffles), and with
    # them this run's violation (0.76-1.03 eps over four runs at 150 steps).
    paper_field = {"flow.skinning": "false", "sampling.tissue_samples": "0"}
    c = match(src, tgt, skel, small_config((90, 135), **paper_field), quiet=True).metrics["constraints"]
    eps = c["eps"]
    g_mdmm = max(c["max_g_endpoint"], c["max_g_trajectory"])
    # the soft weight was chosen where the soft baseline matched this pair about as well as MDMM
    # (mean error to the analytic bend 0.060 vs 0.056 when chosen); a stiffer weight trades
    # matching for rigidity
    soft = match(
        src,
        tgt,
        skel,
        small_config((90, 135), **paper_field, **{"constraints.mode": "soft", "constraints.soft_weight": 0.001}),
        quiet=True,
    )
    cs = soft.metrics["constraints"]
    g_soft = max(cs["max_g_endpoint"], cs["max_g_trajectory"])
    # measured on this run (225 steps; g from 200 fresh samples per bone, pose refitted with the final
    # multiplier weights; MDMM aiming at 0.7 eps): MDMM 0.68 eps, soft 8.2 eps, the same in every run
    assert g_mdmm <= eps, g_mdmm / eps
    assert g_soft > 2.5 * g_mdmm, (g_soft / eps, g_mdmm / eps)
    # the default (skeleton-driven field) on the same pair: measured 1.14 eps, the smooth bend's
    # non-rigidity shared between the pose and the network
    d = mdmm_result.metrics["constraints"]
    assert max(d["max_g_endpoint"], d["max_g_trajectory"]) <= 1.5 * eps


def test_frames_start_at_source_and_field_moves_other_points(pair, mdmm_result):
    src, *_ = pair
    r = mdmm_result
    np.testing.assert_allclose(r.frames[0], src.vertices, atol=1e-12)
    np.testing.assert_allclose(r.frames[-1], r.deformed_source, atol=1e-12)
    assert np.all(np.isfinite(r.frames))
    # the trained field moves any point set: the source's own vertices reproduce the result
    np.testing.assert_allclose(r.flow(src.vertices), r.deformed_source, atol=1e-5)
    # and a denser set (edge midpoints) lands between the flowed end points
    mid = 0.5 * (src.vertices[src.faces[:, 0]] + src.vertices[src.faces[:, 1]])
    moved = r.flow(mid)
    ends = 0.5 * (r.deformed_source[src.faces[:, 0]] + r.deformed_source[src.faces[:, 1]])
    assert np.median(np.linalg.norm(moved - ends, axis=1)) < 0.05


def _write_inputs(tmp_path, pair):
    src, tgt, skel, *_ = pair
    paths = tmp_path / "source.ply", tmp_path / "target.obj", tmp_path / "skeleton.tgf"
    save_mesh(paths[0], src.vertices, src.faces)
    save_mesh(paths[1], tgt.vertices, tgt.faces)
    save_skeleton(paths[2], skel)
    return [str(p) for p in paths]


def _cli_config(tmp_path, seed):
    cfg = tmp_path / f"cfg{seed}.toml"
    cfg.write_text(
        # no rigid placement or pose search: the capsule pair needs neither, and test_ahead.py and
        # test_invariance.py run them end to end (bit-identical reruns, placement in metrics.json)
        f'seed = {seed}\ncompress = 500\nframes = 4\nplacement = "none"\npose_search = false\n'
        "[flow]\nwidth = 16\ndepth = 2\ngso_width = 8\ngso_depth = 1\n"
        "[sampling]\nbone_samples = 8\ntissue_samples = 32\nsurface_edges = 128\n"
    )
    return str(cfg)


def test_cli_match_writes_contract_and_is_reproducible(tmp_path, pair, capsys):
    s, t, k = _write_inputs(tmp_path, pair)
    outs = {}
    for name, seed in [("a", 1), ("b", 1), ("c", 2)]:
        out = tmp_path / name
        rc = main(
            [
                "match",
                s,
                t,
                "--skeleton",
                k,
                "--out",
                str(out),
                "--config",
                _cli_config(tmp_path, seed),
                "--steps",
                "12",
                "--metric",
                "varifold",
                "--quiet",
            ]
        )
        assert rc == 0
        outs[name] = out
    res = read_result(outs["a"])
    src, tgt, *_ = pair
    assert res.n_source == src.n_vertices and res.n_target == tgt.n_vertices and res.n_frames == 4
    np.testing.assert_allclose(res.frames[0], src.vertices, atol=1e-5)  # PLY stores float32
    assert res.p2p_src_to_tgt.max() < tgt.n_vertices and res.p2p_tgt_to_src.max() < src.n_vertices
    metrics = json.loads((outs["a"] / "metrics.json").read_text())
    assert metrics["seed"] == 1 and metrics["config"]["flow"]["width"] == 16
    assert sum(p["steps"] for p in metrics["phases"]) == 12
    assert {p["metric"] for p in metrics["phases"]} == {"varifold"}
    # the 70° bend pushes the capsule's inner side through itself (2 % of its area), the straight
    # source does not: the skeleton-driven field takes its bone weights at the start
    weights = metrics["skinning_weights"]
    assert weights["setting"] == "auto" and weights["mode"] == "start"
    assert weights["source_overlap"] == 0.0
    assert weights["target_overlap"] == pytest.approx(self_overlap(tgt.vertices, tgt.faces), abs=2e-3)  # PLY: float32
    assert weights["target_overlap"] > 0.015
    for f in ["p2p_src_to_tgt.txt", "p2p_tgt_to_src.txt"]:
        assert (outs["a"] / f).read_bytes() == (outs["b"] / f).read_bytes()
    assert (outs["a"] / "deformed_source.ply").read_bytes() == (outs["b"] / "deformed_source.ply").read_bytes()
    assert (outs["a"] / "deformed_source.ply").read_bytes() != (outs["c"] / "deformed_source.ply").read_bytes()


@pytest.mark.parametrize(
    "case, message",
    [
        ("unreadable", "the vertex element must declare"),  # faceless: read as a point cloud
        ("skeleton_outside", "skeleton does not fit"),
        ("skeleton_as_mesh", "unsupported skeleton format"),
        ("degenerate", "none of its"),
        ("bad_setting", "flow.width must be at least 1"),
        ("target_in_millimetres", "target_mm.ply: the target is 1.01e+03x the size of the source"),
    ],
)
def test_cli_match_bad_input_one_line_error_no_output(tmp_path, pair, capsys, case, message):
    s, t, k = _write_inputs(tmp_path, pair)
    extra = []
    if case == "unreadable":
        t = str(tmp_path / "broken.ply")
        (tmp_path / "broken.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n")
    elif case == "skeleton_outside":
        far = Skeleton.from_arrays(np.array([[50.0, 0, 0], [50.0, 0, 2.0]]), np.array([-1, 0]))
        k = str(tmp_path / "far.json")
        save_skeleton(k, far)
    elif case == "skeleton_as_mesh":
        k = t
    elif case == "degenerate":
        src = pair[0]
        v = src.vertices.copy()
        v[:, :2] = 0.0  # the capsule flattened onto its axis: not one face with an area
        s = str(tmp_path / "degenerate.ply")
        save_mesh(s, v, src.faces)
    elif case == "bad_setting":
        extra = ["--set", "flow.width=0"]
    elif case == "target_in_millimetres":
        t = str(tmp_path / "target_mm.ply")
        save_mesh(t, pair[1].vertices * 1000.0, pair[1].faces)
    out = tmp_path / "out"
    rc = main(["match", s, t, "--skeleton", k, "--out", str(out), "--steps", "5", "--quiet"] + extra)
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert message in err and len(err.splitlines()) == 1
    assert not out.exists()


@pytest.mark.parametrize("k", [0.5, 1.7, 1000.0])
def test_size_ratio_is_the_scale_between_the_meshes(pair, k):
    src, tgt, *_ = pair
    assert size_ratio(tgt, Mesh(tgt.vertices * k + 3.0, tgt.faces)) == pytest.approx(k, rel=1e-9)
    # another triangulation of the same capsule, bent: area kept to a few percent
    assert size_ratio(src, tgt) == pytest.approx(1.0, abs=0.05)


@pytest.mark.parametrize("k, warned", [(1.0, False), (1.2, False), (0.85, False), (1.5, True), (0.7, True)])
def test_size_check_warns_beyond_a_quarter(pair, k, warned):
    src = pair[0]
    warnings = check_sizes(src, Mesh(src.vertices * k, src.faces, "t"))
    assert len(warnings) == int(warned)
    if warned:
        assert f"{k:.3g}x the size of the source" in warnings[0]


@pytest.mark.parametrize("k", [2.2, 0.4, 25.4, 1e-3])
def test_size_check_refuses_another_scale_naming_the_target(pair, k):
    src = pair[0]
    message = f"^scaled.obj: the target is {k:.3g}x the size of the source .*different units"
    with pytest.raises(InputError, match=message):
        check_sizes(src, Mesh(src.vertices * k, src.faces, "scaled.obj"))


def _one_side(mesh, keep_share):
    """The faces of ``mesh`` whose centres lie on the +x side of a plane leaving about ``keep_share`` of them,
    and their vertices only (a scan seen from one side, along the capsule's length)."""
    centres = mesh.vertices[mesh.faces].mean(axis=1)
    faces = mesh.faces[centres[:, 0] >= np.quantile(centres[:, 0], 1.0 - keep_share)]
    used, faces = np.unique(faces, return_inverse=True)
    return Mesh(mesh.vertices[used], faces.reshape(-1, 3), "view.ply")


@pytest.mark.parametrize("share", [0.5, 0.2])
def test_a_view_from_one_side_is_a_partial_target_of_the_same_size_not_another_scale(pair, share):
    src = pair[0]
    view = _one_side(src, share)
    area = size_ratio(src, view) ** 2
    assert area == pytest.approx(share, abs=0.08)  # what the size check alone would call 0.45-0.7x
    (note,) = check_sizes(src, view)
    assert f"shows about {area:.0%} of the source's surface area" in note and "partial view" in note


def test_a_quarter_of_the_surface_cut_across_the_length_is_a_partial_target(pair):
    """Cut across the capsule's length too (half its diameter, a quarter of its area): open where the source
    is closed, so a partial view, not another scale; the same quarter closed (capped: a whole small
    capsule) is still another scale, and the quarter in millimetres is refused."""
    src = pair[0]
    half = _one_side(src, 0.5)
    centres = half.vertices[half.faces].mean(axis=1)
    axis = np.argmax(np.ptp(src.vertices, axis=0))
    keep = centres[:, axis] > np.median(centres[:, axis])
    used, faces = np.unique(half.faces[keep], return_inverse=True)
    quarter = Mesh(half.vertices[used], faces.reshape(-1, 3), "quarter.ply")
    assert size_ratio(src, quarter) ** 2 == pytest.approx(0.25, abs=0.08)
    across = diameter(quarter.vertices) / diameter(src.vertices)
    assert across < 1.0 / 1.25  # beyond what a view along the whole length may lack
    (note,) = check_sizes(src, quarter)
    assert "partial view" in note
    small = Mesh(src.vertices * 0.45, src.faces, "small.ply")
    with pytest.raises(InputError, match="different units"):
        check_sizes(src, small)
    with pytest.raises(InputError, match="different units"):
        check_sizes(src, Mesh(quarter.vertices * 1000.0, quarter.faces, "quarter_mm.ply"))


def test_a_partial_view_in_other_units_is_still_refused(pair):
    src = pair[0]
    view = _one_side(src, 0.5)
    with pytest.raises(InputError, match="different units"):
        check_sizes(src, Mesh(view.vertices * 1000.0, view.faces, "view_mm.ply"))


@pytest.mark.parametrize("which", ["target", "source", "both"])
def test_a_mesh_wound_inside_out_is_matched_wound_as_the_other(pair, which):
    """Against the problem of the pair as given: the target's edge tables (what its measures are
    built from) wind as the source's, the target kept as given for the outputs."""
    src, tgt, skel, *_ = pair
    cfg = small_config(placement="none", pose_search="false")
    given = prepare(src, tgt, skel, cfg)
    assert given.warnings == ()
    s = Mesh(src.vertices, src.faces[:, ::-1], "s") if which in ("source", "both") else src
    t = Mesh(tgt.vertices, tgt.faces[:, ::-1], "t") if which in ("target", "both") else tgt
    problem = prepare(s, t, skel, cfg)
    assert problem.target.faces is t.faces
    turned = [w for w in problem.warnings if "wind the other way" in w]
    assert len(turned) == (which != "both")
    assert [w for w in problem.warnings if w not in turned] == []
    ref, got = given.target_topology, problem.target_topology
    np.testing.assert_array_equal(got.edges, ref.edges)
    np.testing.assert_array_equal(got.edge_faces, ref.edge_faces)
    # the target winds as the source (reversed source: reversed signs)
    np.testing.assert_array_equal(got.edge_signs, ref.edge_signs * (-1 if which in ("source", "both") else 1))


def test_what_the_reader_changed_is_a_warning_of_the_match(pair):
    src, tgt, skel, *_ = pair
    cfg = small_config(placement="none", pose_search="false")
    s = Mesh(src.vertices, src.faces, "s.obj", notes=("3 of 9 faces have [4] corners: split into triangles",))
    problem = prepare(s, tgt, skel, cfg)
    assert problem.warnings == ("s.obj: 3 of 9 faces have [4] corners: split into triangles",)


def test_a_mesh_far_from_the_origin_for_its_size_is_warned_of(pair):
    src = pair[0]
    assert check_precision(src, "source") == []
    far = Mesh(src.vertices + [4.0e6, 0.0, 0.0], src.faces)  # a 3.8-unit capsule at survey coordinates
    (warning,) = check_precision(far, "target")
    assert warning.startswith("target: the target is 3.") and "lies 4e+06 from the origin" in warning
    assert "about 1 digits" in warning


def test_a_mesh_split_at_seams_is_welded_for_the_match_with_a_warning(pair):
    src, tgt, skel, *_ = pair
    cfg = small_config(placement="none", pose_search="false")
    soup = Mesh(src.vertices[src.faces].reshape(-1, 3), np.arange(3 * src.n_faces).reshape(-1, 3), "soup.ply")
    given, problem = prepare(src, tgt, skel, cfg), prepare(soup, tgt, skel, cfg)
    n = 3 * src.n_faces
    (warning,) = problem.warnings
    assert warning.startswith(
        f"soup.ply: repaired for the match (the outputs keep its vertices): welded {n - src.n_vertices}"
    )
    # the match computes on the welded mesh (the source's own vertices, first copies), the outputs on the soup's
    first_copies = src.faces.reshape(-1)[problem.source_repair.vertex_origin]
    np.testing.assert_allclose(problem.working.vertices, given.working.vertices[first_copies], atol=1e-12)
    assert problem.source_vertices.shape == (n, 3) and problem.source is soup
    assert problem.source_topology.edges.shape == given.source_topology.edges.shape
    assert not problem.source_topology.has_boundary


def test_meshes_given_as_objects_are_validated(pair):
    src, tgt, skel, *_ = pair
    with pytest.raises(InputError, match="^huge: coordinates as large as"):
        load_inputs(src, Mesh(tgt.vertices * 1e31, tgt.faces, "huge"), skel)


def test_nan_during_training_is_reported_not_written(tmp_path, pair):
    src, tgt, skel, *_ = pair
    cfg = small_config(steps=(3, 0), placement="none", pose_search="false")  # the training is what is tested
    cfg = dataclasses.replace(cfg, phases=tuple(dataclasses.replace(p, lr=1e30) for p in cfg.phases))
    from ncflow.matcher.steps import TrainingError

    with pytest.raises(TrainingError, match="non-finite"):
        Matcher(src, tgt, skel, cfg, quiet=True).run()


def test_config_file_errors(tmp_path):
    from ncflow.config import load_config

    bad = tmp_path / "c.toml"
    bad.write_text("[flow]\nwidht = 3\n")
    with pytest.raises(InputError, match="unknown setting"):
        load_config(bad)
    bad.write_text("[flow\n")
    with pytest.raises(InputError, match="cannot parse"):
        load_config(bad)
    with pytest.raises(InputError, match="unknown preset"):
        load_config(None, "turbo")


def test_phase_constraint_weight(tmp_path, pair):
    from ncflow.config import load_config

    bad = tmp_path / "c.toml"
    bad.write_text('[[phases]]\nmetric = "varifold"\nsteps = 5\nconstraint_weight = -1\n')
    with pytest.raises(InputError, match="constraint_weight"):
        load_config(bad)
    # a phase with weight 0 has no constraint term and leaves the multipliers at zero
    src, tgt, skel, *_ = pair
    cfg = small_config(steps=(4, 4), placement="none", pose_search="false")
    cfg = dataclasses.replace(cfg, phases=tuple(dataclasses.replace(p, constraint_weight=0.0) for p in cfg.phases))
    r = match(src, tgt, skel, cfg, quiet=True)
    assert all(h["constraint"] == 0.0 for h in r.metrics["phases"])
    bones = r.metrics["constraints"]["bones"]
    assert all(b["multiplier_endpoint"] == 0.0 and b["multiplier_trajectory"] == 0.0 for b in bones)
    assert r.metrics["config"]["phases"][0]["constraint_weight"] == 0.0


def test_output_motion_is_the_flow_of_the_source_and_of_fresh_bone_samples(pair, mdmm_result):
    """The output phase flows the source and the bone samples in one program: the same states as
    flowing each on its own (:func:`ncflow.flow.flow_points`), the samples those of the key."""
    import jax
    import jax.numpy as jnp

    from ncflow.flow import flow_points
    from ncflow.matcher.programs import FINAL_BONE_SAMPLES, output_flow_program
    from ncflow.matcher.result import output_motion
    from ncflow.skeleton import sample_bones

    src, _, skel, *_ = pair
    r = mdmm_result
    points = 0.3 * src.vertices[:101]  # any points: the field is defined everywhere (an odd count: padded)
    times = np.array([0.0, 0.3, 0.5, 1.0])
    key = jax.random.key(3)
    program = output_flow_program(skel, None, (0.1, 0.9), r.n_times)
    normals = np.zeros_like(points)  # the field takes its weights at the current place: normals unread
    frames, bones, states = output_motion(r.field, points, normals, times, r.n_times, skel, None, key, program)
    expected = sample_bones(skel, key, FINAL_BONE_SAMPLES, dtype=np.float32).points
    np.testing.assert_allclose(np.asarray(bones), np.asarray(expected), atol=1e-6)  # compiled apart: rounding
    assert frames.shape == (4, 101, 3) and states.shape == (r.n_times, skel.n_bones, FINAL_BONE_SAMPLES, 3)
    alone = np.asarray(
        flow_points(r.field, jnp.asarray(points, jnp.float32), r.n_times, times=jnp.asarray(times, jnp.float32))
    )
    np.testing.assert_allclose(frames, alone, atol=1e-5)
    np.testing.assert_allclose(frames[0], points, atol=1e-6)
    grid = np.asarray(flow_points(r.field, bones.reshape(-1, 3), r.n_times))
    np.testing.assert_allclose(np.asarray(states), grid.reshape(states.shape), atol=1e-5)
    assert np.abs(np.asarray(states)[-1] - np.asarray(bones)).max() > 1e-3  # the samples did move
