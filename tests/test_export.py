"""Output contract of ``ncflow match``: correspondence maps, frames, GLB animation, result folder.

Synthetic shapes: an icosphere (42 vertices, 80 faces) as the rest source, "flowed" by a known
rigid motion; targets are the flowed source itself (identical triangulation) or its midpoint
subdivision (every edge (a, b) gets a vertex at its midpoint), so the exact maps are known.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pygltflib
import pytest
import trimesh

import ncflow.io.result as export
from gltf_checks import assert_valid_gltf, validate_gltf
from ncflow.errors import InputError, ResultError
from ncflow.io.frames import read_skeleton_frames_json, write_frames, write_skeleton_frames_json
from ncflow.io.gltf.writer import write_animation_glb
from ncflow.io.meshes import load_mesh
from ncflow.io.result import CONTRACT_FILES, ResultFolder, read_result, write_result
from ncflow.matcher.correspondence import correspondence_maps
from ncflow.skeleton import Skeleton, load_skeleton


def _rotation(axis, angle: float) -> np.ndarray:
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


R = _rotation([1.0, 2.0, 2.0], 0.7)
T = np.array([0.3, -1.2, 2.0])


@pytest.fixture(scope="module")
def sphere():
    m = trimesh.creation.icosphere(subdivisions=1)
    rest = np.asarray(m.vertices, dtype=np.float64) * np.array([1.0, 0.8, 1.3])  # not symmetric
    return rest, np.asarray(m.faces, dtype=np.int64)


def _midpoint_subdivision(v: np.ndarray, f: np.ndarray):
    """Original vertices keep their indices; edge (a, b), a < b, gets vertex V + e at its midpoint."""
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    uniq, inv = np.unique(edges, axis=0, return_inverse=True)
    inv = inv.reshape(3, -1).T + v.shape[0]  # (F, 3): midpoint of edges 01, 12, 20
    a, b, c = f[:, 0], f[:, 1], f[:, 2]
    m01, m12, m20 = inv[:, 0], inv[:, 1], inv[:, 2]
    faces = np.concatenate([np.stack(x, 1) for x in ((a, m01, m20), (b, m12, m01), (c, m20, m12), (m01, m12, m20))])
    verts = np.concatenate([v, 0.5 * (v[uniq[:, 0]] + v[uniq[:, 1]])])
    return verts, faces, uniq


def _frames(rest: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """K frames of a rigid motion from the rest pose (t = 0) to R·x + T (t = 1)."""
    times = np.linspace(0.0, 1.0, k)
    frames = np.stack([rest @ _rotation([1.0, 2.0, 2.0], 0.7 * t).T + t * T for t in times])
    return frames, times


# ----------------------------------------------------------------------------------------------
# correspondence maps


def test_maps_identical_triangulation_are_identity(sphere):
    rest, faces = sphere
    flowed = rest @ R.T + T
    maps = correspondence_maps(rest, faces, flowed, flowed.copy(), faces)
    n = rest.shape[0]
    assert np.array_equal(maps["p2p_tgt_to_src"], np.arange(n))
    assert np.array_equal(maps["p2p_src_to_tgt"], np.arange(n))
    # one-hot barycentrics on the right corner of a face containing the vertex
    corner = np.argmax(maps["map_bary"], axis=1)
    assert np.array_equal(faces[maps["map_face"], corner], np.arange(n))
    np.testing.assert_allclose(maps["map_bary"].max(1), 1.0, atol=1e-12)
    np.testing.assert_allclose(maps["map_bary"].sum(1), 1.0, atol=1e-12)
    np.testing.assert_allclose(maps["map_points"], rest, atol=1e-12)  # foot point on the REST source
    np.testing.assert_allclose(maps["dist_tgt_to_src"], 0.0, atol=1e-12)
    np.testing.assert_allclose(maps["dist_src_to_tgt"], 0.0, atol=1e-12)
    # without target faces: nearest target vertex, same answer here
    maps2 = correspondence_maps(rest, faces, flowed, flowed, None)
    assert np.array_equal(maps2["p2p_src_to_tgt"], np.arange(n))


def test_maps_midpoint_subdivision(sphere):
    rest, faces = sphere
    flowed = rest @ R.T + T
    tv, tf, edges = _midpoint_subdivision(flowed, faces)
    n = rest.shape[0]
    maps = correspondence_maps(rest, faces, flowed, tv, tf)
    face, bary = maps["map_face"], maps["map_bary"]
    assert face.shape == (tv.shape[0],) and bary.shape == (tv.shape[0], 3)
    corners = faces[face]  # (Vt, 3)
    # original vertices: one-hot at themselves
    assert np.array_equal(corners[np.arange(n), np.argmax(bary[:n], 1)], np.arange(n))
    np.testing.assert_allclose(bary[:n].max(1), 1.0, atol=1e-12)
    # midpoint of edge (a, b): a face containing that edge, bary 0.5 at a and b, 0 at the third corner
    for j, (a, b) in enumerate(edges):
        row, c = bary[n + j], corners[n + j]
        w = {int(c[i]): row[i] for i in range(3)}
        assert set(w) >= {int(a), int(b)}, (j, c, a, b)
        assert w[int(a)] == pytest.approx(0.5, abs=1e-9) and w[int(b)] == pytest.approx(0.5, abs=1e-9)
        third = [v for v in w if v not in (a, b)]
        assert len(third) == 1 and w[third[0]] == pytest.approx(0.0, abs=1e-9)
        assert maps["p2p_tgt_to_src"][n + j] in (a, b)
    np.testing.assert_allclose(maps["map_points"][n:], 0.5 * (rest[edges[:, 0]] + rest[edges[:, 1]]), atol=1e-12)
    np.testing.assert_array_equal(maps["p2p_tgt_to_src"][:n], np.arange(n))
    # every flowed source vertex is a target vertex with the same index
    np.testing.assert_array_equal(maps["p2p_src_to_tgt"], np.arange(n))


# ----------------------------------------------------------------------------------------------
# frames and GLB


def _accessor(gltf: pygltflib.GLTF2, index: int) -> np.ndarray:
    acc = gltf.accessors[index]
    view = gltf.bufferViews[acc.bufferView]
    dtype = {pygltflib.FLOAT: np.float32, pygltflib.UNSIGNED_INT: np.uint32}[acc.componentType]
    width = {"SCALAR": 1, "VEC3": 3}[acc.type]
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    data = np.frombuffer(gltf.binary_blob(), dtype=dtype, count=acc.count * width, offset=start)
    return data.reshape(acc.count, width) if width > 1 else data


def test_write_frames(tmp_path, sphere):
    rest, faces = sphere
    frames, _ = _frames(rest, 3)
    paths = write_frames(tmp_path / "frames", frames, faces)
    assert [p.name for p in paths] == ["frame_0000.ply", "frame_0001.ply", "frame_0002.ply"]
    for k, p in enumerate(paths):
        m = load_mesh(p, validate=False)
        np.testing.assert_array_equal(m.faces, faces)
        np.testing.assert_allclose(m.vertices, frames[k], atol=1e-6)  # PLY stores float32


def test_glb_morph_animation(tmp_path, sphere):
    rest, faces = sphere
    rng = np.random.default_rng(0)
    frames, times = _frames(rest, 4)
    frames = frames + 0.05 * rng.standard_normal(frames.shape)  # non-rigid too
    frames[0] = rest
    skel = np.stack([np.array([[0.0, 0, 0], [0, 1, 0], [0, 2, 0]]) + k * 0.1 for k in range(4)])
    path = write_animation_glb(tmp_path / "a.glb", frames, faces, times, skel, np.array([-1, 0, 1]))
    gltf = pygltflib.GLTF2().load_binary(str(path))
    assert gltf.asset.version == "2.0"
    prim = gltf.meshes[0].primitives[0]
    assert prim.mode == pygltflib.TRIANGLES
    base = _accessor(gltf, prim.attributes.POSITION)
    np.testing.assert_array_equal(_accessor(gltf, prim.indices).reshape(-1, 3), faces)
    assert len(prim.targets) == 4
    for k, target in enumerate(prim.targets):
        acc = gltf.accessors[target["POSITION"]]
        delta = _accessor(gltf, target["POSITION"])
        np.testing.assert_allclose(base + delta, frames[k], atol=1e-5)
        np.testing.assert_allclose(acc.min, delta.min(0), rtol=0, atol=0)  # spec: min/max required
        np.testing.assert_allclose(acc.max, delta.max(0), rtol=0, atol=0)
    assert gltf.accessors[prim.attributes.POSITION].min == pytest.approx(base.min(0).tolist())
    # animation: LINEAR weights, key times scaled to a 2 s clip, one-hot outputs
    (anim,) = gltf.animations
    sampler = anim.samplers[0]
    assert sampler.interpolation == "LINEAR"
    np.testing.assert_allclose(_accessor(gltf, sampler.input), [0, 2 / 3, 4 / 3, 2], atol=1e-6)
    np.testing.assert_array_equal(_accessor(gltf, sampler.output).reshape(4, 4), np.eye(4))
    assert {(c.target.node, c.target.path) for c in anim.channels} == {(0, "weights"), (1, "weights")}
    # the skeleton as morphed LINES, one segment per bone
    sprim = gltf.meshes[1].primitives[0]
    assert sprim.mode == pygltflib.LINES
    np.testing.assert_array_equal(_accessor(gltf, sprim.indices), [0, 1, 1, 2])
    sbase = _accessor(gltf, sprim.attributes.POSITION)
    for k, target in enumerate(sprim.targets):
        np.testing.assert_allclose(sbase + _accessor(gltf, target["POSITION"]), skel[k], atol=1e-6)
    # trimesh sees the base mesh (frame 0)
    mesh = trimesh.load(str(path), force="mesh", process=False)
    assert mesh.vertices.shape == (rest.shape[0], 3) and mesh.faces.shape == faces.shape
    np.testing.assert_allclose(mesh.vertices, rest, atol=1e-6)
    scene = trimesh.load(str(path), process=False)
    assert isinstance(scene.geometry["ncflow"], trimesh.Trimesh)
    # times kept as seconds when asked
    write_animation_glb(tmp_path / "b.glb", frames, faces, times * 5, duration=None)
    g2 = pygltflib.GLTF2().load_binary(str(tmp_path / "b.glb"))
    np.testing.assert_allclose(_accessor(g2, g2.animations[0].samplers[0].input), times * 5, atol=1e-6)
    assert len(g2.meshes) == 1
    assert_valid_gltf(path, tmp_path / "b.glb")


def test_khronos_validator_finds_a_broken_accessor(tmp_path, sphere):
    """The validator check can fail: a GLB whose position accessor states a wrong bound is an error."""
    rest, faces = sphere
    frames, times = _frames(rest, 3)
    gltf = pygltflib.GLTF2().load_binary(str(write_animation_glb(tmp_path / "a.glb", frames, faces, times)))
    position = gltf.accessors[gltf.meshes[0].primitives[0].attributes.POSITION]
    position.max = [v + 1.0 for v in position.max]
    gltf.save_binary(str(tmp_path / "broken.glb"))
    (good, broken) = validate_gltf(tmp_path / "a.glb", tmp_path / "broken.glb")
    assert good["errors"] == 0
    assert broken["errors"] >= 1 and any(m[1] == "ACCESSOR_MAX_MISMATCH" for m in broken["messages"])


def test_glb_rejects_bad_times(tmp_path, sphere):
    rest, faces = sphere
    frames, _ = _frames(rest, 3)
    with pytest.raises(ResultError, match="strictly increasing"):
        write_animation_glb(tmp_path / "a.glb", frames, faces, np.array([0.0, 0.5, 0.5]))
    assert not (tmp_path / "a.glb").exists()


# ----------------------------------------------------------------------------------------------
# the result folder


def _result_inputs(sphere, k: int = 5) -> dict:
    rest, faces = sphere
    frames, times = _frames(rest, k)
    flowed = frames[-1]
    tv, tf, _ = _midpoint_subdivision(rest @ R.T + T, faces)
    maps = correspondence_maps(rest, faces, flowed, tv, tf)
    joints = np.array([[0.0, -0.8, 0.0], [0.0, 0.0, 0.0], [0.0, 0.8, 0.0], [0.5, 0.4, 0.0]])
    skel_rest = Skeleton.from_arrays(joints, [-1, 0, 1, 1], names=["root", "mid", "top", "side"])
    sk_frames = np.stack([skel_rest.positions @ _rotation([1.0, 2.0, 2.0], 0.7 * t).T + t * T for t in times])
    metrics = {
        "loss": {"final": np.float32(0.125), "history": np.array([1.0, 0.5, 0.25])},
        "bones": [{"g": 1e-4}, {"g": np.float64(2e-4)}],
        "seed": np.int64(7),
        "config": {"preset": "fast", "verbose": False, "note": None},
    }
    return dict(
        deformed_source=flowed,
        source_faces=faces,
        maps=maps,
        frames=frames,
        frame_times=times,
        skeleton_target=skel_rest.with_positions(sk_frames[-1]),
        skeleton_frames=sk_frames,
        metrics=metrics,
        target_vertices=tv,
        target_faces=tf,
    ), tv


def _leftovers(parent: Path, name: str) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if p.name.startswith(f".{name}."))


def test_write_then_read_result(tmp_path, sphere):
    rest, faces = sphere
    inputs, tv = _result_inputs(sphere)
    maps = inputs["maps"]
    out = write_result(tmp_path / "res", ResultFolder(**inputs))
    assert sorted(p.name for p in out.iterdir()) == sorted(
        set(CONTRACT_FILES) - {"skeleton_source.tgf", "source_seen.txt"}
    )
    assert _leftovers(tmp_path, "res") == []
    ns, nt, k = rest.shape[0], tv.shape[0], 5
    # deformed source
    m = load_mesh(out / "deformed_source.ply", validate=False)
    np.testing.assert_array_equal(m.faces, faces)
    np.testing.assert_allclose(m.vertices, inputs["deformed_source"], atol=1e-6)
    # p2p files: one 0-based index per line
    st = (out / "p2p_src_to_tgt.txt").read_text().splitlines()
    ts = (out / "p2p_tgt_to_src.txt").read_text().splitlines()
    assert len(st) == ns and len(ts) == nt
    st, ts = np.array([int(x) for x in st]), np.array([int(x) for x in ts])
    assert st.min() >= 0 and st.max() < nt and ts.min() >= 0 and ts.max() < ns
    assert ts.min() == 0 and st.min() == 0  # 0-based (vertex 0 maps to vertex 0 here)
    np.testing.assert_array_equal(st, maps["p2p_src_to_tgt"])
    np.testing.assert_array_equal(ts, maps["p2p_tgt_to_src"])
    # continuous map
    with np.load(out / "map_tgt_to_src.npz", allow_pickle=False) as npz:
        assert sorted(npz.files) == ["bary", "face"]
        assert npz["face"].shape == (nt,) and npz["face"].dtype.kind == "i"
        assert npz["bary"].shape == (nt, 3) and npz["bary"].dtype == np.float64
        np.testing.assert_array_equal(npz["face"], maps["map_face"])
        np.testing.assert_array_equal(npz["bary"], maps["map_bary"])
    # frames: frame 0 is the rest source, the last the deformed source
    names = sorted(p.name for p in (out / "frames").iterdir())
    assert names == [f"frame_{i:04d}.ply" for i in range(k)]
    f0 = load_mesh(out / "frames" / "frame_0000.ply", validate=False)
    np.testing.assert_allclose(f0.vertices, rest, atol=1e-6)
    np.testing.assert_array_equal(f0.faces, faces)
    # skeleton
    sk = load_skeleton(out / "skeleton_target.tgf")
    np.testing.assert_allclose(sk.positions, inputs["skeleton_target"].positions, atol=1e-12)
    np.testing.assert_array_equal(sk.parents, [-1, 0, 1, 1])
    tgf_lines = (out / "skeleton_target.tgf").read_text().splitlines()
    assert tgf_lines[0].startswith("1 ") and "2 4" in tgf_lines  # 1-based, bone mid -> side
    sj = json.loads((out / "skeleton_frames.json").read_text())
    assert sj["parents"] == [-1, 0, 1, 1] and sj["names"] == ["root", "mid", "top", "side"]
    assert np.asarray(sj["positions"]).shape == (k, 4, 3)
    np.testing.assert_allclose(sj["times"], np.linspace(0, 1, k))
    np.testing.assert_allclose(sj["positions"], inputs["skeleton_frames"], atol=1e-12)
    # metrics (numpy values converted) + frame times
    mj = json.loads((out / "metrics.json").read_text())
    assert mj["loss"] == {"final": 0.125, "history": [1.0, 0.5, 0.25]}
    assert mj["seed"] == 7 and mj["bones"][1]["g"] == 2e-4 and mj["config"]["note"] is None
    np.testing.assert_allclose(mj["frame_times"], np.linspace(0, 1, k))
    # animation
    gltf = pygltflib.GLTF2().load_binary(str(out / "animation.glb"))
    prim = gltf.meshes[0].primitives[0]
    base = _accessor(gltf, prim.attributes.POSITION)
    for i, target in enumerate(prim.targets):
        np.testing.assert_allclose(base + _accessor(gltf, target["POSITION"]), inputs["frames"][i], atol=1e-5)
    assert trimesh.load(str(out / "animation.glb"), force="mesh", process=False).vertices.shape == (ns, 3)
    assert_valid_gltf(out / "animation.glb")
    # read_result gives the same back
    r = read_result(out)
    assert (r.n_source, r.n_target, r.n_frames) == (ns, nt, k)
    np.testing.assert_array_equal(r.p2p_src_to_tgt, maps["p2p_src_to_tgt"])
    np.testing.assert_array_equal(r.p2p_tgt_to_src, maps["p2p_tgt_to_src"])
    np.testing.assert_array_equal(r.map_face, maps["map_face"])
    np.testing.assert_allclose(r.frames, inputs["frames"], atol=1e-6)
    np.testing.assert_allclose(r.frame_times, np.linspace(0, 1, k))
    np.testing.assert_array_equal(r.source_faces, faces)
    assert r.skeleton_target.n_joints == 4 and r.skeleton_frames.shape == (k, 4, 3)
    assert r.metrics["seed"] == 7
    np.testing.assert_allclose(r.target_vertices, tv, atol=1e-6)
    np.testing.assert_array_equal(r.target_faces, inputs["target_faces"])
    # written again from what was read: the same files (the one folder type both ways)
    again = r.write(tmp_path / "again")
    for name in ("map_tgt_to_src.npz", "p2p_src_to_tgt.txt", "p2p_tgt_to_src.txt", "skeleton_frames.json"):
        assert (again / name).read_bytes() == (out / name).read_bytes(), name
    # the dict of earlier versions, for one release, with a warning
    with pytest.warns(DeprecationWarning, match="use its attributes"):
        assert r["n_frames"] == k and r["map_face"] is r.map_face
    with pytest.warns(DeprecationWarning):
        legacy = r["skeleton_frames"]
    assert legacy["positions"] is r.skeleton_frames and list(legacy["names"]) == ["root", "mid", "top", "side"]


def test_result_without_target_mesh_reads_as_none(tmp_path, sphere):
    inputs, _ = _result_inputs(sphere, k=2)
    inputs.update(target_vertices=None, target_faces=None)
    out = write_result(tmp_path / "res", ResultFolder(**inputs))
    assert not (out / "target.ply").exists()
    r = read_result(out)
    assert r.target_vertices is None and r.target_faces is None


def test_target_mesh_must_match_the_maps(tmp_path, sphere):
    inputs, tv = _result_inputs(sphere, k=2)
    inputs.update(target_vertices=tv[:-1])
    with pytest.raises(ResultError, match="target has"):
        write_result(tmp_path / "res", ResultFolder(**inputs))
    assert not (tmp_path / "res").exists()


def test_result_without_skeleton(tmp_path, sphere):
    inputs, _ = _result_inputs(sphere, k=2)
    inputs.update(skeleton_target=None, skeleton_frames=None)
    out = write_result(tmp_path / "res", ResultFolder(**inputs))
    without = set(CONTRACT_FILES) - {
        "skeleton_target.tgf",
        "skeleton_frames.json",
        "skeleton_source.tgf",
        "source_seen.txt",
    }
    assert sorted(p.name for p in out.iterdir()) == sorted(without)
    r = read_result(out)
    assert r.skeleton_target is None and r.skeleton_frames is None and r.n_frames == 2


def test_result_with_a_suggested_source_skeleton(tmp_path, sphere):
    """A suggested source skeleton is written as skeleton_source.tgf and read back; an overwrite by a
    result with a given skeleton removes it (it is a contract entry)."""
    inputs, _ = _result_inputs(sphere, k=2)
    source_skeleton = inputs["skeleton_target"].with_positions(inputs["skeleton_target"].positions * 0.5)
    seen = np.linspace(0.0, 1.0, inputs["deformed_source"].shape[0])
    out = write_result(tmp_path / "res", ResultFolder(**inputs, skeleton_source=source_skeleton, source_seen=seen))
    assert sorted(p.name for p in out.iterdir()) == sorted(CONTRACT_FILES)
    np.testing.assert_allclose(read_result(out).source_seen, seen, atol=5e-5)  # four decimals
    back = read_result(out).skeleton_source
    np.testing.assert_allclose(back.positions, source_skeleton.positions, atol=1e-6)
    np.testing.assert_array_equal(back.parents, source_skeleton.parents)
    write_result(out, ResultFolder(**inputs), overwrite=True)
    assert not (out / "skeleton_source.tgf").exists() and read_result(out).skeleton_source is None
    assert not (out / "source_seen.txt").exists() and read_result(out).source_seen is None


@pytest.mark.parametrize("where", ["frames", "deformed", "bary", "metrics", "skeleton"])
def test_non_finite_is_refused_before_writing(tmp_path, sphere, where):
    inputs, _ = _result_inputs(sphere, k=3)
    if where == "frames":
        inputs["frames"] = inputs["frames"].copy()
        inputs["frames"][1, 5, 2] = np.nan
        match = r"frames has 1 non-finite values \(first at index \(1, 5, 2\)\)"
    elif where == "deformed":
        inputs["deformed_source"] = inputs["deformed_source"].copy()
        inputs["deformed_source"][3, 0] = np.inf
        match = "deformed source"
    elif where == "bary":
        inputs["maps"] = dict(inputs["maps"], map_bary=np.full_like(inputs["maps"]["map_bary"], np.nan))
        match = "bary"
    elif where == "metrics":
        inputs["metrics"]["bones"][1]["g"] = float("nan")
        match = r"metrics\['bones'\]\[1\]\['g'\] is nan"
    else:
        inputs["skeleton_frames"] = inputs["skeleton_frames"].copy()
        inputs["skeleton_frames"][2, 1, 1] = np.nan
        match = "skeleton frames"
    with pytest.raises(ResultError, match=match):
        write_result(tmp_path / "res", ResultFolder(**inputs))
    assert not (tmp_path / "res").exists()
    assert list(tmp_path.iterdir()) == []


def test_bad_maps_are_refused(tmp_path, sphere):
    inputs, tv = _result_inputs(sphere, k=2)
    bad = inputs["maps"]["p2p_src_to_tgt"].copy()
    bad[0] = tv.shape[0]
    inputs["maps"] = dict(inputs["maps"], p2p_src_to_tgt=bad)
    with pytest.raises(ResultError, match=r"p2p_src_to_tgt indices span .* expected 0-based"):
        write_result(tmp_path / "res", ResultFolder(**inputs))
    assert list(tmp_path.iterdir()) == []


def test_failure_mid_write_leaves_nothing(tmp_path, sphere, monkeypatch):
    inputs, _ = _result_inputs(sphere, k=3)
    calls = []

    def boom(path, *args, **kwargs):  # records what was already staged when it failed
        staged = Path(path).parent
        calls.append(sorted(p.name for p in staged.iterdir()))
        raise RuntimeError("disk full (injected)")

    monkeypatch.setattr(export, "write_animation_glb", boom)  # runs after the PLYs, npz and frames
    with pytest.raises(RuntimeError, match="injected"):
        write_result(tmp_path / "res", ResultFolder(**inputs))
    # it did fail mid-write: the meshes, maps and frames were already staged
    staged = ["deformed_source.ply", "frames", "map_tgt_to_src.npz", "p2p_src_to_tgt.txt", "p2p_tgt_to_src.txt"]
    staged = sorted([*staged, "target.ply"])
    assert calls[0] == staged
    assert not (tmp_path / "res").exists()
    assert list(tmp_path.iterdir()) == []
    # an existing result is left untouched by a failed overwrite
    monkeypatch.undo()
    out = write_result(tmp_path / "res", ResultFolder(**inputs))
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    monkeypatch.setattr(export, "write_animation_glb", boom)
    other = dict(inputs, frames=inputs["frames"] + 1.0)
    with pytest.raises(RuntimeError, match="injected"):
        write_result(out, ResultFolder(**other), overwrite=True)
    after = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == before
    assert _leftovers(tmp_path, "res") == []


def test_existing_folder_needs_overwrite(tmp_path, sphere):
    inputs, _ = _result_inputs(sphere, k=4)
    out = tmp_path / "res"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    with pytest.raises(ResultError, match="not empty"):
        write_result(out, ResultFolder(**inputs))
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    write_result(out, ResultFolder(**inputs), overwrite=True)
    assert (out / "notes.txt").read_text() == "mine"  # non-contract files are kept
    assert len(list((out / "frames").iterdir())) == 4
    # a shorter re-run replaces frames/ as a whole: no stale frames
    inputs3, _ = _result_inputs(sphere, k=3)
    write_result(out, ResultFolder(**inputs3), overwrite=True)
    assert sorted(p.name for p in (out / "frames").iterdir()) == [f"frame_{i:04d}.ply" for i in range(3)]
    assert read_result(out).n_frames == 3 and (out / "notes.txt").exists()
    assert _leftovers(tmp_path, "res") == []
    # an empty existing folder is fine without overwrite
    (tmp_path / "empty").mkdir()
    write_result(tmp_path / "empty", ResultFolder(**inputs3))
    assert (tmp_path / "empty" / "metrics.json").is_file()


def test_read_result_names_bad_files(tmp_path, sphere):
    inputs, tv = _result_inputs(sphere, k=2)
    out = write_result(tmp_path / "res", ResultFolder(**inputs))
    (out / "p2p_tgt_to_src.txt").write_text("0\n" * (tv.shape[0] - 1) + "999\n")
    with pytest.raises(InputError, match=r"p2p_tgt_to_src\.txt: indices span \[0, 999\]"):
        read_result(out)
    (out / "p2p_tgt_to_src.txt").write_text("0\n" * 3)
    with pytest.raises(InputError, match=rf"p2p_tgt_to_src\.txt: expected {tv.shape[0]} indices"):
        read_result(out)
    (out / "p2p_tgt_to_src.txt").unlink()
    with pytest.raises(InputError, match=r"p2p_tgt_to_src\.txt: missing result file"):
        read_result(out)
    out = write_result(tmp_path / "res2", ResultFolder(**inputs))
    np.savez(out / "map_tgt_to_src.npz", face=np.zeros(3, dtype=np.int64))
    with pytest.raises(InputError, match=r"map_tgt_to_src\.npz: missing array 'bary'"):
        read_result(out)
    maps = inputs["maps"]
    bary = np.array(maps["map_bary"], dtype=np.float64)
    bary[1] = [np.nan, 0.5, 0.5]
    np.savez(out / "map_tgt_to_src.npz", face=maps["map_face"], bary=bary)
    with pytest.raises(
        InputError, match=r"map_tgt_to_src\.npz: 'bary' has NaN or infinite values in 1 rows \(first: row 1\)"
    ):
        read_result(out)
    np.savez(out / "map_tgt_to_src.npz", face=maps["map_face"], bary=bary.astype(str))
    with pytest.raises(InputError, match=r"map_tgt_to_src\.npz: 'bary' must be a float array"):
        read_result(out)
    np.savez(out / "map_tgt_to_src.npz", face=maps["map_face"], bary=bary[:, :2])
    with pytest.raises(InputError, match=r"map_tgt_to_src\.npz: 'bary' must have shape \(\d+, 3\), got \(\d+, 2\)"):
        read_result(out)
    out = write_result(tmp_path / "res3", ResultFolder(**inputs))
    (out / "frames" / "frame_0000.ply").unlink()
    with pytest.raises(InputError, match=r"frames: frame numbers are not 0\.\.0 \(missing frame_0000\.ply\)"):
        read_result(out)
    out = write_result(tmp_path / "res4", ResultFolder(**inputs))
    (out / "skeleton_frames.json").write_text("{not json")
    with pytest.raises(InputError, match=r"skeleton_frames\.json: not valid JSON"):
        read_result(out)
    (out / "skeleton_frames.json").unlink()
    with pytest.raises(InputError, match=r"skeleton_frames\.json: missing result file"):
        read_result(out)
    with pytest.raises(InputError, match="no such result folder"):
        read_result(tmp_path / "nowhere")


def test_skeleton_frames_json_round_trip(tmp_path):
    pos = np.arange(2 * 3 * 3, dtype=np.float64).reshape(2, 3, 3)
    write_skeleton_frames_json(tmp_path / "s.json", pos, np.array([-1, 0, 1]), None, np.array([0.0, 1.0]))
    back = read_skeleton_frames_json(tmp_path / "s.json")
    np.testing.assert_array_equal(back["positions"], pos)
    np.testing.assert_array_equal(back["parents"], [-1, 0, 1])
    assert back["names"] is None and back["times"].tolist() == [0.0, 1.0]
    with pytest.raises(ResultError, match="expected 3 joint names"):
        write_skeleton_frames_json(tmp_path / "t.json", pos, np.array([-1, 0, 1]), ["a"], np.array([0.0, 1.0]))


def test_failed_swap_restores_previous_result(tmp_path, sphere, monkeypatch):
    inputs, _ = _result_inputs(sphere, k=2)
    out = write_result(tmp_path / "res", ResultFolder(**inputs))
    (out / "notes.txt").write_text("mine")
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    real_rename = export.os.rename

    def flaky_rename(src, dst):
        if Path(src).name.startswith(".res.tmp-"):  # moving the new result into place fails
            raise OSError("injected rename failure")
        return real_rename(src, dst)

    monkeypatch.setattr(export.os, "rename", flaky_rename)
    with pytest.raises(OSError, match="injected"):
        write_result(out, ResultFolder(**dict(inputs, frames=inputs["frames"] + 1.0)), overwrite=True)
    monkeypatch.undo()
    after = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == before
    assert _leftovers(tmp_path, "res") == []
