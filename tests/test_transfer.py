"""``ncflow transfer``: source attributes carried to the target through ``map_tgt_to_src.npz``.

Result folders are written here without training (``write_result``) from problems with an exact
map: a generated character and its re-triangulated, posed target (ground-truth face +
barycentrics), a plane and a tube cut by UV seams with targets of another triangulation, and a
rigidly moved sphere. Values are checked against independent references: a linear function of
the position evaluated at the ground-truth points, the body part whose skin weights dominate at
the ground-truth point, the analytic UVs of a plane and of a tube, the rigid motion of a landmark.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import struct
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from ncflow.cli import main
from ncflow.errors import InputError
from ncflow.geometry.barycentric import round_to_vertex, surface_points, vertex_surface_points
from ncflow.geometry.closest import closest_points_on_surface
from ncflow.io.landmarks import read_landmarks
from ncflow.io.meshes import save_mesh
from ncflow.io.obj_uv import read_obj_uv, write_obj_uv
from ncflow.io.ply_properties import read_ply_vertex_properties
from ncflow.io.result import ResultFolder, write_result
from ncflow.io.vertex_arrays import read_vertex_array, write_vertex_array
from ncflow.retarget.attributes import transfer, transfer_labels, transfer_uv
from ncflow.synthetic.characters import make_character, pose_character
from ncflow.synthetic.pairs import make_pair
from ncflow.synthetic.shapes import sphere, tube

HAS_WEIGHTS = importlib.util.find_spec("ncflow.retarget.weights") is not None


def _rotation(axis, angle: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    axis = np.asarray(axis, dtype=np.float64)
    return Rotation.from_rotvec(angle * axis / np.linalg.norm(axis)).as_matrix()


def _project(points, vertices, faces):
    _, face, bary = closest_points_on_surface(points, vertices, faces)
    bary = np.clip(bary, 0.0, None)
    return face, bary / bary.sum(axis=1, keepdims=True)


def _write_result(folder: Path, rest, faces, deformed, tv, tf, face, bary, *, with_target: bool = True) -> Path:
    """A result folder of an exact map: target vertex j ↔ source point (face[j], bary[j])."""
    maps = {
        "map_face": np.asarray(face, dtype=np.int64),
        "map_bary": np.asarray(bary, dtype=np.float64),
        "p2p_tgt_to_src": round_to_vertex(faces, face, bary),
        "p2p_src_to_tgt": cKDTree(tv).query(deformed)[1].astype(np.int64),
    }
    write_result(
        folder,
        ResultFolder(
            deformed_source=deformed,
            source_faces=faces,
            maps=maps,
            frames=np.stack([rest, deformed]),
            frame_times=np.array([0.0, 1.0]),
            target_vertices=tv if with_target else None,
            target_faces=tf if with_target else None,
        ),
    )
    return folder


def _run(capsys, *argv) -> tuple[int, str, str]:
    capsys.readouterr()
    rc = main(["transfer", *map(str, argv)])
    captured = capsys.readouterr()
    return rc, captured.out, captured.err


@pytest.fixture(scope="module")
def humanoid(tmp_path_factory):
    """A generated humanoid, its re-triangulated posed target and the result folder of the exact map."""
    ch = make_character("humanoid", 0)
    pair = make_pair("humanoid", 0, character=ch)
    posed = pose_character(ch, pair.info["pose_b"])
    gt = pair.ground_truth
    # the target is the ground-truth point of every vertex moved by the generating pose
    np.testing.assert_allclose(surface_points(posed.vertices, ch.faces, gt.face, gt.bary), pair.target.vertices)
    folder = tmp_path_factory.mktemp("humanoid") / "result"
    _write_result(
        folder, ch.vertices, ch.faces, posed.vertices, pair.target.vertices, pair.target.faces, gt.face, gt.bary
    )
    return SimpleNamespace(ch=ch, pair=pair, gt=gt, result=folder, rest_points=pair.ground_truth_points())


# ----------------------------------------------------------------------------------------------
# Values and labels


@pytest.mark.parametrize("suffix", [".npy", ".txt"])
def test_linear_function_is_reproduced_through_an_exact_map(humanoid, tmp_path, capsys, suffix):
    a = np.array([[0.3, -1.2], [2.0, 0.5], [-0.7, 1.1]])
    c = np.array([0.25, -4.0])
    values = humanoid.ch.vertices @ a + c  # (Vs, 2), linear in the position
    src = tmp_path / f"values{suffix}"
    write_vertex_array(src, values)
    out = tmp_path / f"target_values{suffix}"
    rc, stdout, err = _run(capsys, humanoid.result, src, "--out", out)
    assert rc == 0, err
    nt = humanoid.pair.target.n_vertices
    assert stdout.strip() == f"wrote {out}: {nt} target vertices, kind values, 2 column(s)"
    got = np.load(out, allow_pickle=False) if suffix == ".npy" else np.loadtxt(out)
    expected = humanoid.rest_points @ a + c  # the function at the ground-truth source points
    assert got.shape == (nt, 2)
    assert np.abs(got - expected).max() < 1e-6


def _chain_parts(parents: np.ndarray) -> np.ndarray:
    """Body part of every bone: the kinematic chain between branch joints it lies on (torso, head, limbs)."""
    parents = np.asarray(parents)
    n_children = np.bincount(parents[parents >= 0], minlength=parents.size)
    chain = []
    for bone in range(parents.size - 1):  # bone b ends at joint b + 1
        j = bone + 1
        while parents[parents[j]] >= 0 and n_children[parents[j]] == 1:
            j = parents[j]
        chain.append(j)
    return np.unique(chain, return_inverse=True)[1]


def test_body_part_labels_land_on_the_right_parts(humanoid, tmp_path, capsys):
    ch, gt = humanoid.ch, humanoid.gt
    part_of_bone = _chain_parts(ch.skeleton.parents)
    assert part_of_bone.max() + 1 == 6  # torso, head, two arms, two legs
    part_weights = np.zeros((ch.vertices.shape[0], part_of_bone.max() + 1))
    np.add.at(part_weights.T, part_of_bone, ch.weights.T)
    labels = np.argmax(part_weights, axis=1)
    # the right part of a target vertex: the part whose skin weights dominate at its ground-truth point
    right = np.argmax(np.einsum("nk,nkp->np", gt.bary, part_weights[ch.faces[gt.face]]), axis=1)
    src, out = tmp_path / "parts.txt", tmp_path / "target_parts.txt"
    write_vertex_array(src, labels)
    rc, stdout, err = _run(capsys, humanoid.result, src, "--out", out)
    assert rc == 0, err
    assert "kind labels" in stdout
    got = np.loadtxt(out, dtype=np.int64)
    assert np.mean(got == right) >= 0.99
    # a slightly wrong map (ground-truth points moved by 10 % of an edge, snapped back): still ≥ 98.5 %
    edge = np.linalg.norm(np.diff(ch.vertices[ch.faces[:, :2]], axis=1), axis=2).mean()
    moved = humanoid.rest_points + np.random.default_rng(0).normal(size=humanoid.rest_points.shape) * 0.1 * edge
    face, bary = _project(moved, ch.vertices, ch.faces)
    assert np.mean(transfer_labels(labels, ch.faces, face, bary) == right) >= 0.985


def test_label_rules_majority_and_nearest():
    faces = np.array([[0, 1, 2]])
    labels = np.array([[7, 1], [3, 1], [3, 2]])  # two columns, each voted on its own
    face = np.zeros(3, dtype=np.int64)
    bary = np.array([[0.4, 0.35, 0.25], [0.5, 0.5, 0.0], [0.2, 0.3, 0.5]])
    # corner 0 alone (0.4) against corners 1 + 2 (0.6): majority 3, nearest 7; ties go to the larger weight
    np.testing.assert_array_equal(transfer_labels(labels, faces, face, bary), [[3, 1], [7, 1], [3, 2]])
    np.testing.assert_array_equal(transfer_labels(labels, faces, face, bary, "nearest"), [[7, 1], [7, 1], [3, 2]])
    np.testing.assert_array_equal(transfer_labels(labels[:, 0], faces, face, bary), [3, 7, 3])


def test_array_round_trip_keeps_types_and_values(tmp_path):
    ints = np.array([[1, -2], [3, 2**40], [0, 7]])
    floats = np.array([0.1, -1e-300, 12345.678901234567])
    for suffix in (".npy", ".txt"):
        write_vertex_array(tmp_path / f"i{suffix}", ints)
        write_vertex_array(tmp_path / f"f{suffix}", floats)
        got_i, got_f = read_vertex_array(tmp_path / f"i{suffix}", 3), read_vertex_array(tmp_path / f"f{suffix}", 3)
        assert got_i.dtype == np.int64 and got_f.dtype == np.float64
        np.testing.assert_array_equal(got_i, ints)
        np.testing.assert_array_equal(got_f, floats)  # bit for bit, text included
    (tmp_path / "c.txt").write_text("# comment\n1, 2\n\n3 4\n5\t6\n")
    np.testing.assert_array_equal(read_vertex_array(tmp_path / "c.txt", 3), [[1, 2], [3, 4], [5, 6]])


# ----------------------------------------------------------------------------------------------
# Texture coordinates with seams


def _grid(n: int):
    """Unit-square grid of n × n vertices, two triangles per cell."""
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n), indexing="xy")
    v = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    f = np.concatenate([np.stack([a, a + 1, a + n + 1], 1), np.stack([a, a + n + 1, a + n], 1)])
    return v, f


def test_uv_seam_on_a_plane_is_respected_exactly(tmp_path, capsys):
    sv, sf = _grid(9)
    # two charts: faces left of x = 1/2 have uv = (x, y), faces right of it uv = (x + 10, y)
    right = sv[sf].mean(axis=1)[:, 0] > 0.5
    corner_uv = sv[sf][:, :, :2] + np.where(right, 10.0, 0.0)[:, None, None] * [1.0, 0.0]
    uvs, uv_faces = np.unique(corner_uv.reshape(-1, 2), axis=0, return_inverse=True)
    uv_faces = uv_faces.reshape(-1, 3)
    write_obj_uv(tmp_path / "source.obj", sv, sf, uvs, uv_faces)
    tv0, tf = _grid(7)
    tv0 = tv0 * 0.96 + 0.013  # another triangulation, vertices off the source's
    face, bary = _project(tv0, sv, sf)
    shift = np.array([0.2, -1.0, 3.0])
    result = _write_result(tmp_path / "result", sv, sf, sv + shift, tv0 + shift, tf, face, bary)
    out = tmp_path / "target.obj"
    rc, stdout, err = _run(capsys, result, tmp_path / "source.obj", "--out", out)
    assert rc == 0, err
    got = read_obj_uv(out)
    np.testing.assert_allclose(got.vertices, tv0 + shift, atol=1e-6)
    np.testing.assert_array_equal(got.faces, tf)
    # every vertex's own uv is its point's uv in the chart of its source face (never averaged)
    own = got.uvs[: tv0.shape[0]]
    np.testing.assert_allclose(own, tv0[:, :2] + np.where(right[face], 10.0, 0.0)[:, None] * [1.0, 0.0], atol=1e-6)
    # no target triangle straddles the seam: each face's corners read one chart, exactly
    offset = got.uvs[got.uv_faces] - tv0[tf][:, :, :2]  # (Ft, 3, 2): 0 or (10, 0) per corner
    np.testing.assert_allclose(offset, offset[:, :1].repeat(3, axis=1), atol=1e-6)
    straddling = int(np.sum(right[face][tf].any(axis=1) & ~right[face][tf].all(axis=1)))
    assert straddling > 0
    assert stdout.strip().endswith(f"{straddling} faces re-expressed across UV seams")


def _tube_uv(n_around: int, n_along: int):
    """UVs of ``tube``: u = column / n_around, v = row / (n_along - 1), with the seam column at u = 1."""
    _, f = tube(radius=0.5, length=2.0, n_around=n_around, n_along=n_along)
    row, col = f // n_around, f % n_around
    wrap = (col == 0) & (col.max(axis=1, keepdims=True) == n_around - 1)
    col = np.where(wrap, n_around, col)  # corners of the seam faces on column 0 read u = 1
    uv_faces = row * (n_around + 1) + col
    r, c = np.meshgrid(np.arange(n_along), np.arange(n_around + 1), indexing="ij")
    uvs = np.stack([c.ravel() / n_around, r.ravel() / (n_along - 1)], axis=1)
    return uvs, uv_faces


def test_uv_seam_of_a_tube_is_not_averaged(tmp_path):
    n = 24
    sv, sf = tube(radius=0.5, length=2.0, n_around=n, n_along=6)
    uvs, uv_faces = _tube_uv(n, 6)
    tv, tf = tube(radius=0.45, length=1.8, n_around=17, n_along=5)
    tv = tv @ _rotation([0, 0, 1], 0.05).T  # no target vertex on the seam line
    face, bary = _project(tv, sv, sf)
    points = surface_points(sv, sf, face, bary)
    # analytic uv of a point of the prism: facet i (between columns i and i + 1), fraction s along the chord
    theta = np.mod(np.arctan2(points[:, 1], points[:, 0]), 2 * np.pi)
    i = np.floor(theta / (2 * np.pi / n)).astype(int)
    p0, p1 = sv[i, :2], sv[(i + 1) % n, :2]
    s = np.einsum("ij,ij->i", points[:, :2] - p0, p1 - p0) / np.einsum("ij,ij->i", p1 - p0, p1 - p0)
    expected = np.stack([(i + s) / n, (points[:, 2] + 1.0) / 2.0], axis=1)
    uv = transfer_uv(sv, sf, uvs, uv_faces, face, bary, tf)
    np.testing.assert_allclose(uv.uvs[: tv.shape[0]], expected, atol=1e-12)
    u = uv.uvs[uv.uv_faces][:, :, 0]
    assert np.ptp(u, axis=1).max() < 2.5 / 17  # no triangle spans the atlas (a seam straddle spans ≈ 1)
    seam = np.ptp(expected[tf][:, :, 0], axis=1) > 0.5
    assert uv.n_seam_faces == int(seam.sum()) > 0
    # re-expressed corners are carried across the seam into the other side's chart: exactly analytic u ± 1
    re = uv.uv_faces >= tv.shape[0]
    u_re, u_true = uv.uvs[uv.uv_faces[re], 0], expected[tf[re], 0]
    np.testing.assert_allclose(np.abs(u_re - u_true), 1.0, atol=1e-12)
    np.testing.assert_allclose(uv.uvs[uv.uv_faces[re], 1], expected[tf[re], 1], atol=1e-12)


# ----------------------------------------------------------------------------------------------
# PLY colours and properties


def _ply_binary_big_endian(path: Path, vertices, faces, columns: list[tuple[str, str, str, np.ndarray]]) -> None:
    """A binary big-endian PLY with extra vertex properties (name, PLY type, NumPy code, values)."""
    header = ["ply", "format binary_big_endian 1.0", f"element vertex {len(vertices)}"]
    header += [f"property double {c}" for c in "xyz"] + [f"property {t} {n}" for n, t, _, _ in columns]
    header += [f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]
    rec = np.zeros(len(vertices), dtype=[("x", ">f8"), ("y", ">f8"), ("z", ">f8")] + [(n, c) for n, _, c, _ in columns])
    for k, name in enumerate("xyz"):
        rec[name] = vertices[:, k]
    for name, _, _, values in columns:
        rec[name] = values
    tri = b"".join(struct.pack(">Biii", 3, *map(int, f)) for f in faces)
    path.write_bytes(("\n".join(header) + "\n").encode() + rec.tobytes() + tri)


def test_ply_colours_labels_and_scalars_through_an_exact_map(humanoid, tmp_path, capsys):
    ch, gt = humanoid.ch, humanoid.gt
    lo, hi = ch.vertices.min(axis=0), ch.vertices.max(axis=0)
    rgb = 255.0 * (ch.vertices - lo) / (hi - lo)  # a colour linear in the position
    labels = np.argmax(ch.weights, axis=1).astype(np.int32)
    quality = ch.vertices[:, 1] * 2.0 - 1.0
    columns = [
        ("red", "uchar", ">u1", np.round(rgb[:, 0])),
        ("green", "uchar", ">u1", np.round(rgb[:, 1])),
        ("blue", "uchar", ">u1", np.round(rgb[:, 2])),
        ("label", "int", ">i4", labels),
        ("quality", "double", ">f8", quality),
        ("nx", "float", ">f4", np.zeros(len(labels))),
    ]
    src = tmp_path / "source.ply"
    _ply_binary_big_endian(src, ch.vertices, ch.faces, columns)
    out = tmp_path / "target.ply"
    rc, stdout, err = _run(capsys, humanoid.result, src, "--out", out)
    assert rc == 0, err
    assert "properties red green blue label quality" in stdout
    got = read_ply_vertex_properties(out)
    assert got.names == ("x", "y", "z", "red", "green", "blue", "label", "quality")
    assert got.types == ("float", "float", "float", "uchar", "uchar", "uchar", "int", "double")
    tgt = humanoid.pair.target
    np.testing.assert_allclose(np.stack([got.values[c] for c in "xyz"], 1), tgt.vertices, atol=1e-5)
    # colours: the linear colour at the ground-truth point, to the rounding of the source's and the output's bytes
    expected_rgb = 255.0 * (humanoid.rest_points - lo) / (hi - lo)
    got_rgb = np.stack([got.values[c] for c in ("red", "green", "blue")], 1).astype(float)
    assert np.abs(got_rgb - expected_rgb).max() <= 1.0
    np.testing.assert_allclose(got.values["quality"], humanoid.rest_points[:, 1] * 2.0 - 1.0, atol=1e-9)
    np.testing.assert_array_equal(got.values["label"], transfer_labels(labels, ch.faces, gt.face, gt.bary))
    import trimesh  # an independent reader of the written file

    m = trimesh.load(out, process=False)
    np.testing.assert_array_equal(m.faces, tgt.faces)
    np.testing.assert_array_equal(m.visual.vertex_colors[:, :3], got_rgb.astype(np.uint8))


def test_ply_colours_round_trip_through_the_identity_map(tmp_path, capsys):
    sv, sf = sphere(2)
    face, bary = vertex_surface_points(np.arange(len(sv)), sf, len(sv))
    result = _write_result(tmp_path / "result", sv, sf, sv * 1.5, sv * 1.5, sf, face, bary)
    rng = np.random.default_rng(3)
    rgba = rng.integers(0, 256, size=(len(sv), 4))
    text = ["ply", "format ascii 1.0", f"element vertex {len(sv)}"]
    text += [f"property float {c}" for c in "xyz"] + [f"property uchar {c}" for c in ("red", "green", "blue", "alpha")]
    text += [f"element face {len(sf)}", "property list uchar int vertex_indices", "end_header"]
    text += [" ".join(map(str, [*p, *c])) for p, c in zip(sv.tolist(), rgba.tolist())]
    text += [f"3 {a} {b} {c}" for a, b, c in sf.tolist()]
    (tmp_path / "colors.ply").write_text("\n".join(text) + "\n")
    rc, _, err = _run(capsys, result, tmp_path / "colors.ply", "--out", tmp_path / "out.ply")
    assert rc == 0, err
    got = read_ply_vertex_properties(tmp_path / "out.ply")
    np.testing.assert_array_equal(np.stack([got.values[c] for c in ("red", "green", "blue", "alpha")], 1), rgba)


# ----------------------------------------------------------------------------------------------
# Landmarks


@pytest.mark.parametrize("plain", [False, True])
def test_landmarks_follow_a_rigid_motion(tmp_path, capsys, plain):
    sv, sf = sphere(2)
    rot, shift = _rotation([1.0, 2.0, -0.5], 0.9), np.array([0.3, -2.0, 1.0])
    moved = sv @ rot.T + shift
    face, bary = vertex_surface_points(np.arange(len(sv)), sf, len(sv))
    result = _write_result(tmp_path / "result", sv, sf, moved, moved, sf, face, bary, with_target=False)
    tri = sv[sf[40]]
    normal = np.cross(tri[1] - tri[0], tri[2] - tri[0])
    foot = tri.mean(axis=0)
    off_surface = foot + 0.01 * normal / np.linalg.norm(normal)  # snaps back to the face centre
    if plain:
        doc = [17, off_surface.tolist()]
        names = ["0", "1"]
    else:
        doc = {"landmarks": [{"name": "tip", "vertex": 17}, {"name": "bump", "point": off_surface.tolist()}]}
        names = ["tip", "bump"]
    src = tmp_path / "marks.json"
    src.write_text(json.dumps(doc))
    out = tmp_path / "carried.json"
    rc, _, err = _run(capsys, result, src, "--out", out)
    assert rc == 2 and "give the target mesh with --target" in err  # this result has no target.ply
    save_mesh(tmp_path / "target.ply", moved, sf, precision="float64")
    rc, stdout, err = _run(capsys, result, src, "--out", out, "--target", tmp_path / "target.ply")
    assert rc == 0, err
    assert "2 landmarks" in stdout
    rec = json.loads(out.read_text())
    marks = rec["landmarks"]
    assert [m["name"] for m in marks] == names
    np.testing.assert_allclose(marks[0]["point"], sv[17] @ rot.T + shift, atol=1e-6)
    assert marks[0]["vertex"] == 17 and marks[0]["source"]["vertex"] == 17
    np.testing.assert_allclose(marks[1]["point"], foot @ rot.T + shift, atol=1e-6)
    assert marks[1]["face"] == 40 and marks[1]["source"]["face"] == 40
    np.testing.assert_allclose(marks[1]["bary"], [1 / 3] * 3, atol=1e-6)
    assert marks[1]["source"]["snap_distance"] == pytest.approx(0.01, abs=1e-6)  # frames are float32
    assert marks[1]["vertex"] in sf[40].tolist()
    assert max(m["distance"] for m in marks) < 1e-6
    assert rec["n_target_vertices"] == len(sv)


# ----------------------------------------------------------------------------------------------
# Skin weights


def test_weights_must_be_a_partition_of_unity(humanoid, tmp_path, capsys):
    w = humanoid.ch.weights.copy()
    w[5] *= 2.0
    np.save(tmp_path / "w.npy", w)
    rc, _, err = _run(capsys, humanoid.result, tmp_path / "w.npy", "--out", tmp_path / "o.npy", "--kind", "weights")
    assert rc == 2 and "row 5 sums to 2" in err
    assert not (tmp_path / "o.npy").exists()


@pytest.mark.skipif(not HAS_WEIGHTS, reason="ncflow.retarget.weights (transfer_skin_weights) is not written yet")
def test_weights_call_through_and_are_renormalised(humanoid, tmp_path, capsys):
    w = humanoid.ch.weights
    np.save(tmp_path / "w.npy", w)
    out = tmp_path / "tw.npy"
    rc, stdout, err = _run(capsys, humanoid.result, tmp_path / "w.npy", "--out", out, "--kind", "weights")
    assert rc == 0, err
    assert re.search(r", 21 joints, \d+ vert(ex|ices) inpainted$", stdout.strip())
    got = np.load(out)
    assert got.shape == (humanoid.pair.target.n_vertices, w.shape[1])
    assert got.min() >= 0.0
    np.testing.assert_allclose(got.sum(axis=1), 1.0, atol=1e-9)
    # through an exact map most target vertices are reliable and read the interpolated weights
    close = np.all(
        np.abs(got - surface_points(w, humanoid.ch.faces, humanoid.gt.face, humanoid.gt.bary)) < 1e-6, axis=1
    )
    assert close.mean() > 0.9


# ----------------------------------------------------------------------------------------------
# Hostile inputs: one line, exit 2, nothing written


def _hostile_files(tmp: Path, nv: int) -> dict[str, tuple[Path, list[str], str]]:
    """name -> (attribute file, extra options, expected text in the message)."""
    files = {}
    np.save(tmp / "rows.npy", np.zeros((nv + 1, 2)))
    files["rows"] = (tmp / "rows.npy", [], f"has {nv + 1} rows but the mesh has {nv} vertices")
    (tmp / "nan.txt").write_text("".join("1.0\n" for _ in range(nv - 1)) + "nan\n")
    files["nan"] = (tmp / "nan.txt", [], "NaN or infinite")
    (tmp / "ragged.txt").write_text("1 2\n3\n")
    files["ragged"] = (tmp / "ragged.txt", [], "line 2: 1 values, but the first row has 2")
    np.save(tmp / "pickled.npy", np.array([{"a": 1}] * nv, dtype=object), allow_pickle=True)
    files["pickle"] = (tmp / "pickled.npy", [], "object arrays are not accepted")
    (tmp / "fake.npy").write_bytes(b"not an array")
    files["fake_npy"] = (tmp / "fake.npy", [], "not a NumPy .npy file")
    (tmp / "float_labels.txt").write_text("".join("0.5\n" for _ in range(nv)))
    files["float_labels"] = (tmp / "float_labels.txt", ["--kind", "labels"], "--kind labels needs integer values")
    (tmp / "vt.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/2 3/1\n")
    files["obj_missing_vt"] = (tmp / "vt.obj", [], "line 5: texture coordinate index 2 is out of range")
    (tmp / "novt.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2 3/1\n")
    files["obj_no_vt"] = (tmp / "novt.obj", [], "has no texture coordinate")
    (tmp / "line.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nf 1/1 2/1\n")
    files["obj_line"] = (tmp / "line.obj", [], "line 6: a face of 2 corners")
    (tmp / "count.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 3/1\n")
    files["obj_count"] = (tmp / "count.obj", [], "are not the result's source")
    (tmp / "bad.json").write_text('{"landmarks": [{"name": "a", "vertex": 1}')
    files["json_syntax"] = (tmp / "bad.json", [], "not valid JSON")
    (tmp / "range.json").write_text(json.dumps({"landmarks": [{"name": "a", "vertex": nv}]}))
    files["json_range"] = (tmp / "range.json", [], f"vertex {nv} is out of range [0, {nv - 1}]")
    (tmp / "both.json").write_text(json.dumps([{"vertex": 1, "point": [0, 0, 0]}]))
    files["json_both"] = (tmp / "both.json", [], "exactly one of 'vertex' and 'point'")
    (tmp / "float_vertex.json").write_text(json.dumps([1.0]))
    files["json_float_vertex"] = (tmp / "float_vertex.json", [], "expected a vertex index (integer) or a point")
    (tmp / "dup.json").write_text(json.dumps({"landmarks": [{"name": "a", "vertex": 1}, {"name": "a", "vertex": 2}]}))
    files["json_duplicate"] = (tmp / "dup.json", [], "landmark name 'a' is used twice")
    (tmp / "nanpoint.json").write_text("[[0, NaN, 1]]")
    files["json_nan"] = (tmp / "nanpoint.json", [], "expected a vertex index (integer) or a point (3 finite numbers)")
    (tmp / "extra.json").write_text(json.dumps({"landmarks": [1], "units": "m"}))
    files["json_key"] = (tmp / "extra.json", [], "unknown key 'units'")
    (tmp / "huge.ply").write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\n"
        b"property uchar red\nend_header\n" + b"\0" * 64
    )
    files["ply_huge_count"] = (tmp / "huge.ply", [], "truncated: 4000000000 vertices need")
    (tmp / "few.ply").write_text("ply\nformat ascii 1.0\nelement vertex 2\nproperty float red\nend_header\n0.5\n1\n")
    files["ply_count"] = (tmp / "few.ply", [], f"has 2 vertices but the result's source has {nv}")
    (tmp / "noend.ply").write_bytes(b"ply\nformat ascii 1.0\n" + b"comment x\n" * 8000)
    files["ply_header"] = (tmp / "noend.ply", [], "no end_header in its first 65536 bytes")
    return files


HOSTILE = [
    "rows",
    "nan",
    "ragged",
    "pickle",
    "fake_npy",
    "float_labels",
    "obj_missing_vt",
    "obj_no_vt",
    "obj_line",
    "obj_count",
    "json_syntax",
    "json_range",
    "json_both",
    "json_float_vertex",
    "json_duplicate",
    "json_nan",
    "json_key",
    "ply_huge_count",
    "ply_count",
    "ply_header",
]


@pytest.fixture(scope="module")
def small_result(tmp_path_factory):
    sv, sf = sphere(1)
    face, bary = vertex_surface_points(np.arange(len(sv)), sf, len(sv))
    folder = tmp_path_factory.mktemp("small") / "result"
    return _write_result(folder, sv, sf, sv, sv, sf, face, bary), len(sv)


@pytest.mark.parametrize("case", HOSTILE)
def test_hostile_attribute_files_are_one_line_errors(small_result, tmp_path, capsys, case):
    result, nv = small_result
    path, extra, expected = _hostile_files(tmp_path, nv)[case]
    out = tmp_path / "out" / ("o" + {".json": ".json", ".obj": ".obj", ".ply": ".ply"}.get(path.suffix, ".npy"))
    rc, stdout, err = _run(capsys, result, path, "--out", out, *extra)
    assert rc == 2
    assert err.count("\n") == 1 and err.startswith("ncflow transfer: error: ") and str(path) in err
    assert expected in err
    assert not out.parent.exists() or not any(out.parent.iterdir())


def test_output_problems_are_refused_before_any_work(small_result, tmp_path, capsys):
    result, nv = small_result
    src = tmp_path / "v.npy"
    np.save(src, np.arange(nv, dtype=np.float64))
    (tmp_path / "taken.npy").write_bytes(b"keep")
    cases = [
        (["--out", tmp_path / "taken.npy"], "exists (use --overwrite to replace it)"),
        (["--out", result / "metrics.json"], "a .npy attribute is written as .npy or .txt"),
        (["--out", tmp_path / "v.obj"], "a .npy attribute is written as .npy or .txt, not .obj"),
        (["--out", tmp_path / "o.npy", "--kind", "uv"], "--kind uv does not apply to a .npy file"),
        (["--out", tmp_path / "o.npy", "--target", tmp_path / "t.ply"], "--target is only for results without"),
        (["--out", tmp_path], "is a folder"),
        (["--out", tmp_path / "o.npy", "--max-distance", "0.1"], "--max-distance applies to --kind weights only"),
        (["--out", tmp_path / "o.npy", "--kind", "weights", "--max-normal-angle", "200"], "at most 180"),
    ]
    for options, expected in cases:
        rc, _, err = _run(capsys, result, src, *options)
        assert rc == 2 and expected in err, (options, err)
        assert err.count("\n") == 1
    assert (tmp_path / "taken.npy").read_bytes() == b"keep"
    assert not (tmp_path / "o.npy").exists()
    rc, _, err = _run(capsys, result, src, "--out", tmp_path / "taken.npy", "--overwrite")
    assert rc == 0, err
    np.testing.assert_array_equal(np.load(tmp_path / "taken.npy"), np.arange(nv))
    with pytest.raises(InputError, match="is a file of the result folder"):
        transfer(result, src, result / "p2p_tgt_to_src.txt", overwrite=True)
    with pytest.raises(InputError, match="is a file of the result folder"):
        transfer(result, tmp_path / "c.ply", result / "frames" / "frame_0001.ply", overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


def test_readers_name_the_line_and_read_landmark_points(tmp_path):
    (tmp_path / "m.json").write_text(json.dumps({"landmarks": [{"vertex": 2}, {"name": "p", "point": [1, 2, 3.5]}]}))
    marks = read_landmarks(tmp_path / "m.json", 3)
    assert [(m.name, m.vertex, m.point) for m in marks] == [("0", 2, None), ("p", None, (1.0, 2.0, 3.5))]
    (tmp_path / "neg.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf -3/-3 -2/-2 -1/-1\n")
    m = read_obj_uv(tmp_path / "neg.obj")
    np.testing.assert_array_equal(m.faces, [[0, 1, 2]])
    np.testing.assert_array_equal(m.uv_faces, [[0, 1, 2]])
    (tmp_path / "nan.obj").write_text("v 0 0 0\nv 1 nan 0\n")
    with pytest.raises(InputError, match=r"nan\.obj: line 2: 'v' has a NaN or infinite value"):
        read_obj_uv(tmp_path / "nan.obj")


# ----------------------------------------------------------------------------------------------
# Fuzzing the readers: mutated valid files give a result or one short InputError line naming the file


FUZZ_SCALE = float(os.environ.get("NCFLOW_FUZZ_SCALE", "1"))
_EXTREME = [b"0", b"-1", b"nan", b"inf", b"1e309", b"4294967296", b"9223372036854775808", b"9" * 40, b"0.5", b"-3"]


@st.composite
def _mutated(draw, seed: bytes) -> bytes:
    data = bytearray(seed)
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["byte", "cut", "insert", "number", "number"]))
        i = draw(st.integers(0, max(len(data) - 1, 0)))
        j = min(len(data), i + draw(st.integers(0, 16)))
        if op == "byte" and data:
            data[i] = draw(st.integers(0, 255))
        elif op == "cut":
            del data[i:j]
        elif op == "insert":
            data[i:i] = draw(st.binary(max_size=16))
        else:
            spans = [m.span() for m in re.finditer(rb"-?\d+(?:\.\d+)?", bytes(data))]
            if spans:
                a, b = draw(st.sampled_from(spans))
                data[a:b] = draw(st.sampled_from(_EXTREME))
    return bytes(data)


def _seed_files() -> dict[str, tuple[bytes, object]]:
    obj = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\nf 2/2 4/1 3/3\n"
    ply = (
        b"ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
        b"property uchar red\nproperty int label\nelement face 2\nproperty list uchar int vertex_indices\n"
        b"end_header\n0 0 0 255 1\n1 0 0 0 2\n0 1 0 9 3\n1 1 0 7 4\n3 0 1 2\n3 1 3 2\n"
    )
    rec = np.zeros(4, dtype=[("x", "<f4"), ("red", "u1"), ("label", "<i2")])
    rec["label"] = [1, 2, 3, 4]
    ply_bin = (
        b"ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty uchar red\n"
        b"property short label\nend_header\n" + rec.tobytes()
    )
    marks = json.dumps({"landmarks": [{"name": "a", "vertex": 1}, {"name": "b", "point": [0.5, 1, 2]}]}).encode()
    return {
        "m.obj": (obj, read_obj_uv),
        "p.ply": (ply, read_ply_vertex_properties),
        "b.ply": (ply_bin, read_ply_vertex_properties),
        "l.json": (marks, lambda p: read_landmarks(p, 4)),
        "a.txt": (b"1 2.5\n3 4\n# c\n5 6e1\n7 8\n", lambda p: read_vertex_array(p, 4)),
    }


@pytest.mark.filterwarnings("error::RuntimeWarning")
@pytest.mark.parametrize("name", ["m.obj", "p.ply", "b.ply", "l.json", "a.txt"])
def test_mutated_attribute_files_never_raise_anything_else(tmp_path_factory, name):
    seed, read = _seed_files()[name]
    folder = tmp_path_factory.mktemp("fuzz")
    read(_write_bytes(folder / name, seed))  # the seed itself is valid

    @settings(max_examples=int(120 * FUZZ_SCALE), deadline=None, database=None, suppress_health_check=list(HealthCheck))
    @given(_mutated(seed))
    def run(data):
        path = _write_bytes(folder / name, data)
        try:
            read(path)
        except InputError as exc:
            msg = str(exc)
            assert "\n" not in msg and msg.startswith(str(path)) and len(msg) < len(str(path)) + 300, msg

    run()


def _write_bytes(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path
