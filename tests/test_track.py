"""``ncflow track``: a short generated sequence (small meshes, the smallest networks) tracked once, its outputs
checked against the sequence's exact ground truth and against readers of their own (the GLB decoded here
with pygltflib and skinned by hand, the BVH by bvhio, the Khronos validator); a broken frame, a jump that
loses the warm start, and a run interrupted and resumed."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pygltflib
import pytest
from scipy.spatial.transform import Rotation

from browser_checks import Page, browser_test
from gltf_checks import accessor, assert_valid_gltf
from ncflow.cli import main
from ncflow.config import apply_overrides, preset, scale_steps
from ncflow.errors import InputError
from ncflow.evaluate.metrics import auc, geodesic_errors
from ncflow.geometry.barycentric import surface_points
from ncflow.io.files import read_npz_arrays
from ncflow.io.gltf.rig_writer import write_rig_glb
from ncflow.io.meshes import load_mesh
from ncflow.synthetic.sequences import make_sequence, write_sequence
from ncflow.track import frame_files, track_sequence
from ncflow.track.frames import natural_key
from ncflow.view.page import decode_array
from tiny import TINY

N_SMOOTH = 4  # frames 0-3 move smoothly; frame 4 is broken, frame 5 a jump
SETTINGS = [*TINY, "compress=300", "pose_search=false"]


def _config():
    return scale_steps(apply_overrides(preset("fast"), SETTINGS), 60)


@pytest.fixture(scope="module")
def track(tmp_path_factory):
    root = tmp_path_factory.mktemp("track")
    seq = make_sequence("humanoid", 3, N_SMOOTH + 1, resolution=40, turn=40.0, travel=0.3, jump_at=N_SMOOTH)
    record = write_sequence(seq, root / "data")
    frames = [root / "data" / f["mesh"] for f in record["frames"]]
    broken = root / "data" / "frames" / "humanoid_seq_003_broken.ply"
    broken.write_text("ply\nformat ascii 1.0\nelement vertex 3\nend_header\n0 0\n")
    ordered = [*frames[:N_SMOOTH], broken, frames[N_SMOOTH]]
    out = root / "out"
    report = track_sequence(
        root / "data" / "source.ply", ordered, root / "data" / "skeleton.tgf", out, _config(), warm_steps=15, quiet=True
    )
    return {"root": root, "seq": seq, "frames": ordered, "out": out, "report": report}


def test_frames_are_listed_in_natural_order(tmp_path):
    for name in ["f10.ply", "f2.obj", "f1.off", "notes.txt", ".hidden.ply"]:
        (tmp_path / name).write_text("x")
    assert [p.name for p in frame_files(tmp_path)] == ["f1.off", "f2.obj", "f10.ply"]
    assert [p.name for p in frame_files(str(tmp_path / "f1*"))] == ["f1.off", "f10.ply"]
    assert [p.name for p in frame_files([tmp_path / "f10.ply", tmp_path / "f1.off"])] == ["f10.ply", "f1.off"]
    assert sorted(["a10", "a9", "a9b", "A2"], key=natural_key) == ["A2", "a9", "a9b", "a10"]
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "f1.ply").write_text("x")
    with pytest.raises(InputError, match="stems must differ"):
        frame_files([tmp_path / "f1.off", tmp_path / "sub" / "f1.ply"])
    with pytest.raises(InputError, match="no mesh or point-cloud files"):
        frame_files(_empty(tmp_path))
    with pytest.raises(InputError, match="no such frame"):
        frame_files([tmp_path / "missing.ply"])
    (tmp_path / "scan 01.ply").write_text("x")
    (tmp_path / "bad\x01.ply").write_text("x")
    assert [p.name for p in frame_files([tmp_path / "scan 01.ply"])] == ["scan 01.ply"]
    with pytest.raises(InputError, match="control characters"):
        frame_files([tmp_path / "bad\x01.ply"])


def _empty(tmp_path):
    d = tmp_path / "empty"
    d.mkdir()
    return d


def test_every_frame_is_mapped_from_the_source_against_ground_truth(track):
    seq, out, report = track["seq"], track["out"], track["report"]
    assert (report.n_frames, report.n_ok, report.n_failed) == (N_SMOOTH + 2, N_SMOOTH + 1, 1)
    metrics = json.loads((out / "metrics.json").read_text())
    frames = {f["stem"]: f for f in metrics["frames"]}
    diag = float(np.linalg.norm(np.ptp(seq.source.vertices, axis=0)))
    for k in range(N_SMOOTH):
        stem = seq.stems[k]
        assert frames[stem]["status"] == "ok" and frames[stem]["warm"] == (k > 0)
        pred = read_npz_arrays(out / "maps" / f"{stem}.npz", ("face", "bary"))
        gt = seq.ground_truth[k]
        e = geodesic_errors(seq.source, pred["face"], pred["bary"], gt.face, gt.bary)
        assert auc(e, 0.20) > 0.85, (stem, auc(e, 0.20))
        # the registered source lies on the frame where the true motion puts it
        reg = load_mesh(out / "registered" / f"{stem}.ply").vertices
        assert reg.shape == seq.source.vertices.shape
        assert np.mean(np.linalg.norm(reg - seq.source_frames[k], axis=1)) < 0.03 * diag
        # the map is the map from the source: the predicted source points, moved by the true motion, land near
        # the frame's vertices
        moved = surface_points(seq.source_frames[k], seq.source.faces, pred["face"], pred["bary"])
        assert np.median(np.linalg.norm(moved - seq.frames[k].vertices, axis=1)) < 0.03 * diag


def test_a_broken_frame_is_reported_and_the_next_starts_from_the_last_good_one(track):
    out, seq = track["out"], track["seq"]
    rec = json.loads((out / "records" / "humanoid_seq_003_broken.json").read_text())
    assert rec["status"] == "failed" and "humanoid_seq_003_broken.ply" in rec["error"]
    assert not (out / "maps" / "humanoid_seq_003_broken.npz").exists()
    after = json.loads((out / "records" / f"{seq.stems[N_SMOOTH]}.json").read_text())
    assert after["previous"] == seq.stems[N_SMOOTH - 1]


def test_a_jump_loses_the_warm_start_and_is_searched_again(track):
    out, seq = track["out"], track["seq"]
    rec = json.loads((out / "records" / f"{seq.stems[N_SMOOTH]}.json").read_text())
    assert rec["warm"] and rec["fell_back"] and max(rec["data_ratio"], rec["fit_ratio"]) > 3.0
    smooth = [json.loads((out / "records" / f"{s}.json").read_text()) for s in seq.stems[1:N_SMOOTH]]
    assert all(not r["fell_back"] and r["data_ratio"] <= 3.0 for r in smooth)
    # the search fits the frame where the warm start had lost it (how well it maps is the matcher's accuracy
    # on a turned target, measured by the benchmarks; these networks are the smallest)
    diag = float(np.linalg.norm(np.ptp(seq.source.vertices, axis=0)))
    assert rec["kept"] == "search" and rec["fit"] < 0.02 * diag


def _glb_at_key(path, k):
    """The GLB's mesh at animation key k, decoded and skinned here (morph targets, node TRS, skin)."""
    gltf = pygltflib.GLTF2().load_binary(str(path))
    prim = gltf.meshes[0].primitives[0]
    pos = accessor(gltf, prim.attributes.POSITION).astype(np.float64)
    n = len(gltf.nodes)
    rot = [np.asarray(nd.rotation or [0, 0, 0, 1], float) for nd in gltf.nodes]
    trans = [np.asarray(nd.translation or [0, 0, 0], float) for nd in gltf.nodes]
    weights = np.zeros(len(prim.targets))
    anim = gltf.animations[0]
    for ch in anim.channels:
        sampler = anim.samplers[ch.sampler]
        times = accessor(gltf, sampler.input)[:, 0]
        values = accessor(gltf, sampler.output).astype(np.float64)
        if ch.target.path == "weights":
            weights = values.reshape(len(times), -1)[k]
        elif ch.target.path == "rotation":
            rot[ch.target.node] = values[k]
        else:
            trans[ch.target.node] = values[k]
    for i, t in enumerate(prim.targets):
        pos = pos + weights[i] * accessor(gltf, t["POSITION"])
    world = [None] * n

    def visit(i, parent):
        local = np.eye(4)
        local[:3, :3] = Rotation.from_quat(rot[i]).as_matrix()
        local[:3, 3] = trans[i]
        world[i] = parent @ local
        for c in gltf.nodes[i].children or []:
            visit(c, world[i])

    for i in gltf.scenes[0].nodes:
        visit(i, np.eye(4))
    skin = gltf.skins[0]
    ibm = accessor(gltf, skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
    mats = np.stack([world[j] @ ibm[m] for m, j in enumerate(skin.joints)])
    joints = accessor(gltf, prim.attributes.JOINTS_0).astype(int)
    w = accessor(gltf, prim.attributes.WEIGHTS_0).astype(np.float64)
    blended = np.einsum("vi,viab->vab", w, mats[joints])
    return np.einsum("vab,vb->va", blended[:, :3, :3], pos) + blended[:, :3, 3], len(times)


def test_the_animation_is_the_registered_sequence(track):
    out, seq = track["out"], track["seq"]
    assert_valid_gltf(out / "animation.glb")
    good = [s for s in seq.stems]  # the broken frame is no key
    diag = float(np.linalg.norm(np.ptp(seq.source.vertices, axis=0)))
    for k, stem in enumerate(good):
        skinned, n_keys = _glb_at_key(out / "animation.glb", k)
        reg = load_mesh(out / "registered" / f"{stem}.ply").vertices
        np.testing.assert_allclose(skinned, reg, atol=1e-4 * diag)
    assert n_keys == len(good)
    frames = json.loads((out / "skeleton_frames.json").read_text())
    assert [f["stem"] for f in frames["frames"]] == good
    assert [f["index"] for f in frames["frames"]] == [0, 1, 2, 3, 5]
    rest = np.asarray(frames["rest"])
    for f in frames["frames"]:
        joints, moves = np.asarray(f["joints"]), np.asarray(f["bone_transforms"])
        for bone, m in zip(frames["bones"], moves):  # each bone's transform carries both its joints there
            np.testing.assert_allclose(rest[bone] @ m[:3, :3].T + m[:3, 3], joints[bone], atol=1e-6 * diag)
            np.testing.assert_allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3), atol=1e-9)


def test_the_bvh_reads_back_at_every_frame(track):
    import bvhio

    out = track["out"]
    frames = json.loads((out / "skeleton_frames.json").read_text())
    joints = {f["index"]: np.asarray(f["joints"]) for f in frames["frames"]}
    size = float(np.linalg.norm(np.ptp(np.asarray(frames["rest"]), axis=0)))
    root = bvhio.readAsHierarchy(str(out / "animation.bvh"))
    names = [j.Name for j, _, _ in root.layout()]
    assert len(names) == len(frames["names"])
    for k in range(N_SMOOTH + 2):
        root.loadPose(k, recursive=True)
        got = np.array([np.array(j.PositionWorld) for j, _, _ in root.layout()])
        held = k if k in joints else k - 1  # the broken frame holds the pose before it
        np.testing.assert_allclose(got, joints[held], atol=1e-4 * size)


def test_an_interrupted_run_resumes_with_the_same_results(track, tmp_path):
    out = tmp_path / "again"
    shutil.copytree(track["out"], out)
    seq = track["seq"]
    for stem in seq.stems[2:]:  # as if stopped after frame 1
        for folder, suffix in (("records", "json"), ("maps", "npz"), ("registered", "ply"), ("state", "eqx")):
            (out / folder / f"{stem}.{suffix}").unlink(missing_ok=True)
    (out / "metrics.json").unlink()
    seen = []
    data = track["root"] / "data"

    def again_in(folder, **options):
        return track_sequence(data / "source.ply", track["frames"], data / "skeleton.tgf", folder, _config(), **options)

    again = again_in(out, warm_steps=15, quiet=True, on_frame=lambda k, rec: seen.append(k))
    assert again.n_resumed == 2 and seen == [2, 3, 4, 5]
    for stem in seq.stems:
        a = np.load(track["out"] / "maps" / f"{stem}.npz")
        b = np.load(out / "maps" / f"{stem}.npz")
        np.testing.assert_array_equal(a["face"], b["face"])
        np.testing.assert_array_equal(a["bary"], b["bary"])
    # other settings: refused without --overwrite, nothing removed
    with pytest.raises(InputError, match="other inputs or settings"):
        again_in(out, warm_steps=16, quiet=True)
    assert (out / "maps" / f"{seq.stems[0]}.npz").is_file()


def test_cli_refuses_bad_options_in_one_line(track, tmp_path, capsys):
    data = track["root"] / "data"
    args = ["track", str(data / "source.ply"), str(data / "frames"), "--skeleton", str(data / "skeleton.tgf")]
    assert main([*args, "--out", str(tmp_path / "o"), "--warm-steps", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert "warm steps" in err and len(err.splitlines()) == 1
    assert main([*args, "--out", str(tmp_path / "o"), "--fps", "nan"]) == 2
    assert not (tmp_path / "o").exists()


def _triangle_rig() -> dict:
    """The arguments of write_rig_glb for one triangle bound to one joint."""
    return dict(
        vertices=np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]),
        faces=np.array([[0, 1, 2]]),
        joint_positions=np.zeros((1, 3)),
        parents=np.array([-1]),
        names=["root"],
        joints=np.zeros((3, 4), int),
        weights=np.tile([1.0, 0, 0, 0], (3, 1)),
    )


def test_rig_writer_refuses_bad_morph_targets(tmp_path):
    common = _triangle_rig()
    anim = dict(
        key_times=np.array([0.0, 1.0]), rotations=np.tile([0, 0, 0, 1.0], (2, 1, 1)), root_translations=np.zeros((2, 3))
    )
    from ncflow.errors import ResultError

    with pytest.raises(ResultError, match="morph targets must be finite"):
        write_rig_glb(tmp_path / "a.glb", **common, **anim, morph_targets=np.full((2, 3, 3), np.nan))
    with pytest.raises(ResultError, match="keyed to the animation"):
        write_rig_glb(tmp_path / "b.glb", **common, morph_targets=np.zeros((2, 3, 3)))
    assert not any(tmp_path.iterdir())


def test_view_plays_the_registered_frames(track, tmp_path):
    from test_view import _page_data, _positions

    out, seq = track["out"], track["seq"]
    page = tmp_path / "track.html"
    assert main(["view", str(out), "--out", str(page)]) == 0
    data = _page_data(page)
    frames = _positions(data["frames"], data)
    assert frames.shape[0] == len(seq.stems) + 1  # the rest pose, then every good frame
    span = np.ptp(np.asarray([data["bbox"]["min"], data["bbox"]["max"]]), axis=0).max()
    np.testing.assert_allclose(frames[0], seq.source.vertices, atol=1e-4 * span)
    last = load_mesh(out / "registered" / f"{seq.stems[-1]}.ply").vertices
    np.testing.assert_allclose(frames[-1], last, atol=1e-4 * span)
    assert main(["view", str(out), "--out", str(tmp_path / "b.html"), "--gt", "identity"]) == 2


@browser_test
def test_view_plays_animation_glb_in_chromium(track, browser, tmp_path):
    """The page of a track plays animation.glb as three.js's GLTFLoader and AnimationMixer pose it: at every
    key the skinned, morphed mesh is the registered frame (within 1e-4 of the diagonal: float32); between
    two keys it is the clip's pose (skeleton slerped, corrections blended), not the frames' straight blend,
    which the page shows again with the animation switched off."""
    from test_view import _page_data

    out = track["out"]
    page_file = tmp_path / "track.html"
    assert main(["view", str(out), "--out", str(page_file)]) == 0
    data = _page_data(page_file)
    stems = [f["stem"] for f in json.loads((out / "metrics.json").read_text())["frames"] if f["status"] == "ok"]
    assert data["animation"]["keys"] == list(range(-1, len(stems)))
    kept = decode_array(data["source"]["kept"])
    registered = [load_mesh(out / "registered" / f"{s}.ply").vertices[kept] for s in stems]
    diag = float(np.linalg.norm(np.ptp(registered[0], axis=0)))
    view = Page(browser, page_file)
    try:
        times = view.page.evaluate("window.ncflowViewer.times")

        def shown(t):
            view.page.evaluate(f"window.ncflowViewer.setTime({t})")
            return np.asarray(view.page.evaluate("window.ncflowViewer.flowPositions()")).reshape(-1, 3)

        assert view.page.is_checked("#ncv-glb")
        for k, reg in enumerate(registered):
            assert np.abs(shown(times[k + 1]) - reg).max() < 1e-4 * diag
        middle = shown(0.5 * (times[1] + times[2]))
        blend = 0.5 * (registered[0] + registered[1])
        assert np.abs(middle - blend).max() > 1e-3 * diag  # the clip's pose, not the straight blend
        assert np.abs(middle - blend).max() < 0.1 * diag
        assert view.page.evaluate("window.ncflowViewer.setAnimation(false)") is False
        assert np.abs(shown(0.5 * (times[1] + times[2])) - blend).max() < 1e-4 * diag  # uint16 frames
        assert view.errors == [] and view.requests == [view.url]
    finally:
        view.page.close()


def test_view_keys_follow_the_frames_shown(track, tmp_path):
    """With fewer frames shown than tracked, each shown frame names its own clip key (the rest pose none)."""
    from test_view import _page_data

    out = track["out"]
    n_good = json.loads((out / "metrics.json").read_text())["n_ok"]
    assert main(["view", str(out), "--out", str(tmp_path / "v.html"), "--max-frames", "3"]) == 0
    keys = _page_data(tmp_path / "v.html")["animation"]["keys"]
    assert len(keys) == 3 and keys[0] == -1 and keys[-1] == n_good - 1 and keys == sorted(set(keys))


@pytest.mark.filterwarnings("ignore:pygltflib does not support")
def test_view_refuses_a_broken_animation_glb(track, tmp_path, capsys):
    """An animation.glb that is not a skin of the source with one key per good frame: one line naming it, no
    page."""
    out = tmp_path / "t"
    shutil.copytree(track["out"], out)
    glb = out / "animation.glb"
    good = glb.read_bytes()
    capsys.readouterr()
    for broken in (b"glTF" + bytes(40), (track["root"] / "rig.glb")):
        if isinstance(broken, bytes):
            glb.write_bytes(broken)
        else:  # a valid GLB of another mesh: one triangle
            write_rig_glb(broken, **_triangle_rig())
            glb.write_bytes(broken.read_bytes())
        assert main(["view", str(out), "--out", str(tmp_path / "v.html")]) == 2
        err = capsys.readouterr().err
        assert "animation.glb" in err and err.count("\n") == 1, err
        assert not (tmp_path / "v.html").exists()
    glb.write_bytes(good)
    assert main(["view", str(out), "--out", str(tmp_path / "v.html")]) == 0


def test_the_match_kept_is_the_one_whose_bones_hold():
    from types import SimpleNamespace

    from ncflow.track.warm import better_match

    def result(held, data):
        return SimpleNamespace(metrics={"constraints": {"all_satisfied": held}, "phases": [{"data": data}]})

    warm, full = result(True, 0.5), result(False, 0.1)
    assert (
        better_match(warm, full) is warm
        and better_match(result(False, 0.1), result(True, 0.5)).metrics["constraints"]["all_satisfied"]
    )
    a, b = result(True, 0.5), result(True, 0.1)
    assert better_match(a, b) is b and better_match(b, a) is b


def test_a_warm_frame_that_tears_a_bone_is_searched_again(tmp_path, monkeypatch):
    """A warm frame with a bone beyond ε after a frame that held them all is matched again in full, and the
    match whose bones hold is kept (here every warm result is made to look torn)."""
    import ncflow.track.sequence as sequence
    import ncflow.track.warm as warm

    def held(result):
        return result.metrics["phases"][-1]["phase"] != "warm"

    monkeypatch.setattr(sequence, "bones_held", held)
    monkeypatch.setattr(warm, "bones_held", held)
    seq = make_sequence("humanoid", 4, 3, resolution=40, turn=10.0, travel=0.1)
    record = write_sequence(seq, tmp_path / "data")
    frames = [tmp_path / "data" / f["mesh"] for f in record["frames"]]
    out = tmp_path / "out"
    track_sequence(tmp_path / "data" / "source.ply", frames, tmp_path / "data" / "skeleton.tgf", out, _config(),
                   warm_steps=5, quiet=True)  # fmt: skip
    recs = [json.loads((out / "records" / f"{s}.json").read_text()) for s in seq.stems]
    assert not recs[0]["warm"] and recs[0]["fell_back_reason"] is None
    for r in recs[1:]:
        assert r["warm"] and r["fell_back"] and r["fell_back_reason"] == "bones" and r["kept"] == "search"


def test_generated_sequence_has_exact_ground_truth(track):
    """Every frame vertex is its ground-truth source point moved by the frame's motion (the source's vertices
    in ``source_frames``), every frame has its own triangulation, and the jump turns the body at once."""
    seq = track["seq"]
    for k, (frame, gt) in enumerate(zip(seq.frames, seq.ground_truth)):
        moved = surface_points(seq.source_frames[k], seq.source.faces, gt.face, gt.bary)
        np.testing.assert_allclose(moved, frame.vertices, atol=1e-9)
    assert len({f.n_vertices for f in seq.frames}) > 1
    step = [np.linalg.norm(seq.joints[k + 1] - seq.joints[k], axis=1).mean() for k in range(len(seq.frames) - 1)]
    assert step[N_SMOOTH - 1] > 3 * max(step[: N_SMOOTH - 1])


@pytest.mark.parametrize(
    "frames, message",
    [
        ([{"stem": "../../outside", "status": "ok"}], "not a file of the track"),
        ([1, 2], "not the metrics.json of a finished track"),
        ([{"stem": "a", "status": "ok"}, {"stem": "a", "status": "ok"}], "disagree"),
    ],
)
def test_view_reads_nothing_a_track_file_points_outside(track, tmp_path, frames, message):
    """A hostile metrics.json: a stem that leaves the folder, frames that are not records, a stem twice (one
    file loaded again and again) are refused in one line; nothing outside the folder is read."""
    from ncflow.track.folder import track_as_result

    out = tmp_path / "t"
    shutil.copytree(track["out"], out)
    (tmp_path / "outside.ply").write_bytes((out / "source.ply").read_bytes())
    metrics = json.loads((out / "metrics.json").read_text())
    metrics["frames"] = frames
    (out / "metrics.json").write_text(json.dumps(metrics))
    skel = json.loads((out / "skeleton_frames.json").read_text())
    skel["frames"] = [{"stem": f["stem"], "joints": skel["rest"]} for f in frames if isinstance(f, dict)]
    (out / "skeleton_frames.json").write_text(json.dumps(skel))
    with pytest.raises(InputError, match=message):
        track_as_result(out)
    assert main(["view", str(out), "--out", str(tmp_path / "v.html")]) == 2
    assert not (tmp_path / "v.html").exists()


@pytest.mark.parametrize(("setting", "expected"), [("auto", "auto"), ("ring", "ring"), ("choose", "auto")])
def test_a_sequence_without_a_skeleton_suggests_one_the_settings_way(tmp_path, monkeypatch, setting, expected):
    """``ncflow track`` without a skeleton suggests one for all frames with ``skeleton_bases``'s way of
    placing limbs' base joints ("choose", which needs one target, falls back to the default "auto"), the
    first, middle and last of five frames showing the other poses."""
    import dataclasses

    import trimesh

    import ncflow.track.sequence as sequence
    from ncflow.geometry.mesh import Mesh
    from ncflow.skeleton import Skeleton

    sphere = trimesh.creation.icosphere(2)
    paths = []
    for k in range(5):
        paths.append(tmp_path / f"frame_{k}.ply")
        trimesh.Trimesh(sphere.vertices * (1 + 0.1 * k), sphere.faces, process=False).export(paths[-1])
    seen = {}

    def fake(src, message, others, bases="auto"):
        seen.update(bases=bases, others=len(others))
        return Skeleton.from_arrays(np.array([[0, 0, 0], [0, 0, 0.5]], float), np.array([-1, 0])), {}

    monkeypatch.setattr(sequence, "suggested_skeleton", fake)
    config = dataclasses.replace(preset("fast"), skeleton_bases=setting)
    source = Mesh(np.asarray(sphere.vertices, float), np.asarray(sphere.faces, np.int64))
    _, _, suggested, _ = sequence._inputs(source, None, config, lambda text: None, paths)
    assert suggested and seen == {"bases": expected, "others": 3}


def test_a_warm_start_carries_each_joint_on_at_its_speed():
    """The predicted start of a warm frame turns every joint but the root once more by its turn between the
    last two frames (checked against rotation matrices R_k R_{k-1}ᵀ R_k), keeps the root, a joint that turned
    more than MAX_STEP_DEG, the translation, the networks and the multipliers, and is the state itself
    without an earlier frame."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    from ncflow.geometry.skeleton import Skeleton
    from ncflow.matcher.train import TrainState, init_params
    from ncflow.optim.mdmm import init_multipliers
    from ncflow.skeleton.kinematics import rest_pose
    from ncflow.track.warm import MAX_STEP_DEG, predicted_state

    skel = Skeleton.from_arrays([[0, 0, 0], [0, 1, 0], [0, 2, 0], [1, 1, 0]], [-1, 0, 1, 1])
    params = init_params(jax.random.key(0), _config(), skel)
    rng = np.random.default_rng(3)
    before_rot = Rotation.from_rotvec(rng.normal(size=(4, 3)) * 0.4)
    step = Rotation.from_rotvec(rng.normal(size=(4, 3)) * np.array([[0.2], [0.2], [0.2], [0.0]]))
    big = Rotation.from_rotvec([0.0, 0.0, np.radians(MAX_STEP_DEG + 5.0)])
    step = Rotation.concatenate([step[:3], big])
    now_rot = step * before_rot

    def state(rot, translation):
        pose = rest_pose(skel, jnp.float32)._replace(
            rotations=jnp.asarray(rot.as_quat(scalar_first=True), jnp.float32),
            translation=jnp.asarray(translation, jnp.float32),
        )
        p = eqx.tree_at(lambda q: q.flow.pose, params, pose)
        return TrainState(p, pose, init_multipliers(jnp.full((2, skel.n_bones), 0.5, jnp.float32)))

    now, before = state(now_rot, [0.1, 0.2, 0.3]), state(before_rot, [0.0, 0.0, 0.0])
    ahead = predicted_state(now, before)
    for pose in (ahead.params.flow.pose, ahead.pose):
        got = Rotation.from_quat(np.asarray(pose.rotations, np.float64), scalar_first=True).as_matrix()
        r_now, r_before = now_rot.as_matrix(), before_rot.as_matrix()
        want = [r_now[j] @ r_before[j].T @ r_now[j] for j in (1, 2)]
        np.testing.assert_allclose(got[1:3], want, atol=1e-5)
        np.testing.assert_allclose(got[[0, 3]], r_now[[0, 3]], atol=1e-5)  # the root; the joint that turned 65°
        np.testing.assert_array_equal(np.asarray(pose.translation), np.asarray(now.pose.translation))

    def kept(s):
        return s.params.flow.residual, s.params.gso, s.multipliers

    same = [a is b for a, b in zip(jax.tree.leaves(kept(ahead)), jax.tree.leaves(kept(now)))]
    assert same and all(same)
    assert predicted_state(now, None) is now
