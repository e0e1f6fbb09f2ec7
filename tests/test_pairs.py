"""Pair builders: exact ground truth by construction, retriangulated targets, MANO posing against
hand-computed values (tiny fake models, .npz and chumpy .pkl), glTF pairs from a GLB written here,
and ``ncflow make-pairs`` files that re-load."""

from __future__ import annotations

import csv
import json
import math
import pickle
import sys
import types
from pathlib import Path

import numpy as np
import pygltflib
import pytest
import scipy.sparse
import trimesh

from ncflow.cli import main
from ncflow.errors import InputError
from ncflow.evaluate import closest_points_on_surface, load_ground_truth, surface_points
from ncflow.geometry.mesh import validate_mesh
from ncflow.geometry.remesh import check_closed_surface, retriangulate_mesh
from ncflow.geometry.rigid import quat_to_matrix
from ncflow.geometry.topology import mesh_topology
from ncflow.io.mano import load_mano
from ncflow.io.meshes import load_mesh
from ncflow.skeleton import load_skeleton
from ncflow.synthetic.bodies import KINDS
from ncflow.synthetic.characters import make_character, pose_character
from ncflow.synthetic.gltf import gltf_pair
from ncflow.synthetic.mano import (
    MANO_TIP_VERTICES,
    mano_finger_pose,
    mano_flexion_axes,
    mano_forward,
    mano_pair,
)
from ncflow.synthetic.motion import target_motion
from ncflow.synthetic.pairs import MOTION_CSV_COLUMNS, PAIRS_CSV_COLUMNS, make_pair, write_pairs
from ncflow.synthetic.shapes import capsule


@pytest.fixture(scope="module")
def built():
    """Per kind: the character, its retriangulated pair and its same-connectivity pair."""
    out = {}
    for kind in KINDS:
        ch = make_character(kind, 0)
        out[kind] = (ch, make_pair(kind, 0, character=ch), make_pair(kind, 0, retriangulate=False, character=ch))
    return out


def bone_angles(joints, parents):
    """Angle (degrees) between each bone and its parent bone, for every bone whose parent is a bone."""
    out = {}
    for c in range(1, len(parents)):
        j = parents[c]
        if j <= 0:
            continue
        d_in, d_out = joints[j] - joints[parents[j]], joints[c] - joints[j]
        cos = d_in @ d_out / (np.linalg.norm(d_in) * np.linalg.norm(d_out))
        out[c] = math.degrees(math.acos(np.clip(cos, -1, 1)))
    return out


def assert_exact(pair, posed_source_vertices):
    """Σ bary · posed source vertices is every target vertex (float64 rounding only)."""
    gt = pair.ground_truth
    assert gt.complete and gt.n_target == pair.target.n_vertices
    assert gt.face.min() >= 0 and gt.face.max() < pair.source.n_faces
    assert np.all(gt.bary >= 0)
    np.testing.assert_allclose(gt.bary.sum(axis=1), 1.0, atol=1e-12)
    tri = posed_source_vertices[pair.source.faces[gt.face]]
    expected = np.einsum("nk,nkd->nd", gt.bary, tri)
    np.testing.assert_allclose(pair.target.vertices, expected, rtol=0, atol=1e-9)
    return expected


# ----------------------------------------------------------------------------------------------
# procedural pairs


@pytest.mark.parametrize("kind", KINDS)
def test_retriangulated_ground_truth_is_exact(built, kind):
    ch, pair, _ = built[kind]
    posed_b = pose_character(ch, pair.info["pose_b"]).vertices
    assert_exact(pair, posed_b)
    # the ground-truth points lie on the source (rest) surface, and the source is the rest mesh
    np.testing.assert_array_equal(pair.source.vertices, ch.vertices)
    np.testing.assert_array_equal(pair.skeleton.positions, ch.skeleton.positions)
    rest_points = pair.ground_truth_points()
    d, _, _ = closest_points_on_surface(rest_points, ch.vertices, ch.faces)
    assert d.max() < 1e-12 * ch.spec.size
    # ... and close to the smooth shape (the target triangulates the same surface)
    assert np.max(np.abs(ch.sdf(rest_points))) < 0.01 * ch.spec.size


@pytest.mark.parametrize("kind", KINDS)
def test_retriangulated_target_is_a_different_clean_mesh(built, kind):
    ch, pair, _ = built[kind]
    src, tgt = pair.source, pair.target
    assert tgt.n_vertices != src.n_vertices
    assert tgt.n_faces != src.n_faces
    assert 600 <= tgt.n_vertices < src.n_vertices  # default: 0.8 × the source resolution
    assert pair.info["target_resolution"] == pytest.approx(0.8 * ch.resolution)
    validate_mesh(tgt.vertices, tgt.faces, name="target")
    assert check_closed_surface(tgt.vertices, tgt.faces) is None
    m = trimesh.Trimesh(tgt.vertices, tgt.faces, process=False)
    assert m.is_watertight and m.is_winding_consistent and m.volume > 0 and m.euler_number == 2
    assert pair.info["target_projection_flips"] == 0
    # its vertices are new points of the surface, not the source's vertices
    rest_points = pair.ground_truth_points()
    edge = np.mean(np.linalg.norm(src.vertices[src.faces[:, 0]] - src.vertices[src.faces[:, 1]], axis=1))
    nearest = np.min(np.linalg.norm(rest_points[:, None] - src.vertices[None], axis=2), axis=1)
    assert np.median(nearest) > 0.2 * edge
    assert np.mean(nearest < 1e-6 * edge) < 0.01


@pytest.mark.parametrize("kind", KINDS)
def test_same_connectivity_pair_has_identity_ground_truth(built, kind):
    ch, retri, pair = built[kind]
    assert pair.target.n_vertices == pair.source.n_vertices
    np.testing.assert_array_equal(pair.target.faces, pair.source.faces)
    gt = pair.ground_truth
    corner = np.argmax(gt.bary, axis=1)
    np.testing.assert_array_equal(pair.source.faces[gt.face, corner], np.arange(pair.source.n_vertices))
    np.testing.assert_array_equal(np.sort(gt.bary, axis=1), np.tile([0.0, 0.0, 1.0], (gt.bary.shape[0], 1)))
    posed_b = assert_exact(pair, pose_character(ch, pair.info["pose_b"]).vertices)
    # same pose B as the retriangulated pair of the same seed
    np.testing.assert_array_equal(posed_b, pose_character(ch, retri.info["pose_b"]).vertices)


@pytest.mark.parametrize("kind", KINDS)
def test_pair_has_large_joint_rotation_and_global_motion(built, kind):
    ch, pair, _ = built[kind]
    parents = pair.skeleton.parents
    before = bone_angles(pair.skeleton.positions, parents)
    after = bone_angles(pair.target_joints, parents)
    change = max(abs(after[c] - before[c]) for c in before)
    assert change >= 60.0 - 1e-9
    assert pair.info["large_angle_deg"] >= 60.0
    # the target skeleton is the FK of pose B: bone lengths kept
    np.testing.assert_allclose(pair.target_skeleton.bone_lengths, pair.skeleton.bone_lengths, rtol=1e-12)
    # a global rigid motion on top: the root moved
    assert np.linalg.norm(pair.target_joints[0] - pair.skeleton.positions[0]) > 1e-3 * ch.spec.size


def test_posed_source(built):
    ch, ref, _ = built["hand"]
    pair = make_pair("hand", 0, retriangulate=False, source_pose="random", character=ch)
    assert not np.allclose(pair.source.vertices, ch.vertices)
    posed_a = pose_character(ch, pair.info["pose_a"])
    np.testing.assert_array_equal(pair.source.vertices, posed_a.vertices)
    np.testing.assert_array_equal(pair.skeleton.positions, posed_a.joints)
    # the target's large joint is at rest in pose A, so the large rotation survives
    j = ch.skeleton.names.index(pair.info["large_joint"])
    np.testing.assert_array_equal(pair.info["pose_a"].rotations[j], [1.0, 0.0, 0.0, 0.0])
    before = bone_angles(pair.skeleton.positions, pair.skeleton.parents)
    after = bone_angles(pair.target_joints, pair.skeleton.parents)
    assert max(abs(after[c] - before[c]) for c in before) >= 60.0 - 1e-9
    assert_exact(pair, pose_character(ch, pair.info["pose_b"]).vertices)
    with pytest.raises(InputError, match="source_pose"):
        make_pair("hand", 0, source_pose="sideways", character=ch)
    with pytest.raises(InputError, match="not a"):
        make_pair("hand", 1, character=ch)


# ----------------------------------------------------------------------------------------------
# retriangulating an open mesh


def test_retriangulate_open_mesh():
    v, f = capsule(radius=0.5, length=2.0, n_around=24, n_along=16)
    # cut the south cap open: drop the faces at the south pole
    south = int(np.argmin(v[:, 2]))
    f = f[~np.any(f == south, axis=1)]
    keep = np.unique(f)
    remap = np.full(v.shape[0], -1)
    remap[keep] = np.arange(keep.size)
    v, f = v[keep], remap[f]
    assert mesh_topology(f, v.shape[0]).has_boundary
    nv, nf, face, bary = retriangulate_mesh(v, f, 30, seed=1)
    np.testing.assert_allclose(nv, surface_points(v, f, face, bary), atol=0)
    d, _, _ = closest_points_on_surface(nv, v, f)
    assert d.max() < 1e-12
    validate_mesh(nv, nf)
    m = trimesh.Trimesh(nv, nf, process=False)
    assert m.is_winding_consistent and m.body_count == 1
    assert not m.is_watertight and m.euler_number == 1  # a disk: one hole, as the input
    assert nv.shape[0] != v.shape[0]
    # deterministic
    again = retriangulate_mesh(v, f, 30, seed=1)
    assert np.array_equal(again[0], nv) and np.array_equal(again[1], nf)


# ----------------------------------------------------------------------------------------------
# MANO


MANO_PARENTS = [-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14]


def fake_mano_arrays():
    """A 24-vertex MANO-format model: vertices 0-15 are the joints (J_regressor picks them), 16-20
    finger tips, 21 a test vertex on the index finger, 22 and 23 test vertices on the wrist."""
    rng = np.random.default_rng(0)
    joints = np.zeros((16, 3))
    joints[0] = [0.1, 0.2, 0.3]
    for finger, x in enumerate([0.02, 0.0, -0.04, -0.02]):
        base = 1 + 3 * finger
        for k in range(3):
            joints[base + k] = joints[0] + [x, 0.0, 0.08 + 0.03 * k]
    for k in range(3):
        joints[13 + k] = joints[0] + [0.03 + 0.02 * k, -0.01, 0.02 + 0.02 * k]
    tips = joints[[3, 6, 9, 12, 15]] + [0.0, 0.0, 0.02]
    extra = np.array([joints[1] + [0.5, 0.2, 0.1], joints[0] + [0.0, 0.05, 0.0], joints[0] + [0.01, -0.05, 0.02]])
    v = np.concatenate([joints, tips, extra])
    nv = v.shape[0]
    weights = np.zeros((nv, 16))
    weights[np.arange(16), np.arange(16)] = 1.0
    weights[16 + np.arange(5), [3, 6, 9, 12, 15]] = 1.0
    weights[21, 1] = 1.0
    weights[22, 0] = 1.0
    weights[23, 0] = 1.0
    jreg = np.zeros((16, nv))
    jreg[np.arange(16), np.arange(16)] = 1.0
    posedirs = np.zeros((nv, 3, 135))
    posedirs[22, 0, 0] = 0.3  # x of vertex 22 follows (R_1 - I)[0, 0]
    shapedirs = np.zeros((nv, 3, 10))
    shapedirs[:, 2, 0] = 1.0  # beta_0 lifts everything along z
    components = 2.0 * np.eye(45)
    coeffs = np.zeros((3, 45))
    coeffs[1, 2] = (math.pi / 2) / 2.0  # joint 1 (index MCP): 90° about z
    coeffs[2] = rng.normal(size=45) * 0.1
    faces = np.stack([np.arange(nv - 2), np.arange(1, nv - 1), np.arange(2, nv)], axis=1)
    kintree = np.array([[2**32 - 1] + MANO_PARENTS[1:], list(range(16))], dtype=np.int64)
    return {
        "v_template": v,
        "faces": faces,
        "weights": weights,
        "J_regressor": jreg,
        "kintree_table": kintree,
        "posedirs": posedirs,
        "shapedirs": shapedirs,
        "hands_components": components,
        "hands_mean": np.zeros(45),
        "hands_coeffs": coeffs,
    }


TIPS = (16, 17, 18, 19, 20)


@pytest.fixture
def mano_npz(tmp_path):
    path = tmp_path / "mano_fake.npz"
    np.savez(path, **fake_mano_arrays())
    return path


def rot_z(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def test_mano_single_joint_rotation(mano_npz):
    arr = fake_mano_arrays()
    v, j = arr["v_template"], arr["v_template"][:16]
    pair = mano_pair(mano_npz, 0, 1, tip_vertices=TIPS)
    np.testing.assert_allclose(pair.source.vertices, v, atol=1e-15)  # row 0: rest
    tv = pair.target.vertices
    rz = rot_z(90.0)
    # the index finger (joints 1-3, its tip and vertex 21) turned 90° about joint 1
    moved = [1, 2, 3, 16, 21]
    np.testing.assert_allclose(tv[moved], (v[moved] - j[1]) @ rz.T + j[1], atol=1e-12)
    np.testing.assert_allclose(tv[21], j[1] + [-0.2, 0.5, 0.1], atol=1e-12)
    # pose blend shape: (R_1 - I)[0, 0] = cos 90° - 1 = -1 moves vertex 22 by -0.3 in x
    np.testing.assert_allclose(tv[22], v[22] + [-0.3, 0.0, 0.0], atol=1e-12)
    still = [0, 4, 5, 6, 7, 13, 17, 18, 19, 20, 23]
    np.testing.assert_allclose(tv[still], v[still], atol=1e-12)
    # skeleton: 16 joints + 5 tip bones, in the source pose; target joints by FK
    sk = pair.skeleton
    assert sk.n_joints == 21 and sk.n_bones == 20
    np.testing.assert_allclose(sk.positions[:16], j, atol=1e-15)
    np.testing.assert_allclose(sk.positions[16:], v[list(TIPS)], atol=1e-15)
    np.testing.assert_array_equal(sk.parents, MANO_PARENTS + [3, 6, 9, 12, 15])
    assert sk.names[0] == "wrist" and sk.names[16] == "index_tip"
    np.testing.assert_allclose(pair.target_joints[2], (j[2] - j[1]) @ rz.T + j[1], atol=1e-12)
    np.testing.assert_allclose(pair.target_joints[16], tv[16], atol=1e-15)
    # identity ground truth
    assert_exact(pair, tv)
    assert pair.dataset == "mano" and pair.name == "mano_0_1"


def test_mano_global_rotation_betas_and_pca(mano_npz):
    arr = fake_mano_arrays()
    model = load_mano(mano_npz)
    v, j0 = arr["v_template"], arr["v_template"][0]
    ry = np.array([[0, 0, 1.0], [0, 1, 0], [-1.0, 0, 0]])  # 90° about y
    verts, joints = mano_forward(model, np.zeros(45), global_rotation=[0.0, math.pi / 2, 0.0])
    np.testing.assert_allclose(verts, (v - j0) @ ry.T + j0, atol=1e-12)
    np.testing.assert_allclose(joints, (v[:16] - j0) @ ry.T + j0, atol=1e-12)
    shifted, _ = mano_forward(model, np.zeros(45), betas=[0.5])
    np.testing.assert_allclose(shifted, v + [0.0, 0.0, 0.5], atol=1e-12)
    # PCA: θ = mean + coeffs @ components[:n]; ints pick hands_coeffs rows
    np.testing.assert_allclose(mano_finger_pose(model, 2), arr["hands_coeffs"][2] @ arr["hands_components"])
    theta = mano_finger_pose(model, [0.1, 0.2])
    np.testing.assert_allclose(theta, np.r_[0.2, 0.4, np.zeros(43)])
    aa = np.arange(45) * 0.01
    np.testing.assert_allclose(mano_finger_pose(model, aa, space="axis_angle"), aa)
    with pytest.raises(InputError, match="out of range"):
        mano_finger_pose(model, 3)
    with pytest.raises(InputError, match="45"):
        mano_forward(model, np.zeros(44))
    p = mano_pair(model, 0, 2, global_rotation_b=[0, 0.3, 0], tip_vertices=TIPS, betas=[0.1])
    assert_exact(p, p.target.vertices)
    r = mano_pair(model, 1, 2, tip_vertices=TIPS, skeleton_joints="regressor")
    np.testing.assert_allclose(r.skeleton.positions[:16], arr["J_regressor"] @ r.source.vertices, atol=1e-15)
    np.testing.assert_allclose(r.target_joints[:16], arr["J_regressor"] @ r.target.vertices, atol=1e-15)


def test_mano_pkl_with_chumpy_objects(mano_npz, tmp_path, monkeypatch):
    arr = fake_mano_arrays()
    # a stand-in "chumpy" module, present only while pickling (as on the machine MANO was made on)
    chumpy = types.ModuleType("chumpy")
    ch_mod = types.ModuleType("chumpy.ch")

    class Ch:
        def __init__(self, x):
            self.x = x
            self._cache = {"junk": 1}

    Ch.__module__, Ch.__qualname__ = "chumpy.ch", "Ch"
    ch_mod.Ch = Ch
    chumpy.ch = ch_mod
    monkeypatch.setitem(sys.modules, "chumpy", chumpy)
    monkeypatch.setitem(sys.modules, "chumpy.ch", ch_mod)
    data = dict(arr)
    data["f"] = data.pop("faces").astype(np.uint32)
    data["shapedirs"] = Ch(arr["shapedirs"])
    data["hands_components"] = Ch(arr["hands_components"])
    data["J_regressor"] = scipy.sparse.csc_matrix(arr["J_regressor"])
    data["bs_style"] = "lbs"
    path = tmp_path / "MANO_RIGHT.pkl"
    path.write_bytes(pickle.dumps(data, protocol=2))
    monkeypatch.delitem(sys.modules, "chumpy")
    monkeypatch.delitem(sys.modules, "chumpy.ch")
    a, b = load_mano(path), load_mano(mano_npz)
    for key in (
        "v_template",
        "faces",
        "weights",
        "J_regressor",
        "posedirs",
        "shapedirs",
        "hands_components",
        "hands_mean",
        "hands_coeffs",
        "parents",
    ):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key))
    pa, pb = mano_pair(path, 0, 1, tip_vertices=TIPS), mano_pair(mano_npz, 0, 1, tip_vertices=TIPS)
    np.testing.assert_array_equal(pa.target.vertices, pb.target.vertices)


def test_mano_bad_files(tmp_path, mano_npz):
    arr = fake_mano_arrays()
    del arr["posedirs"]
    p = tmp_path / "broken.npz"
    np.savez(p, **arr)
    with pytest.raises(InputError, match="lacks posedirs"):
        load_mano(p)
    with pytest.raises(InputError, match="no such file"):
        load_mano(tmp_path / "missing.npz")
    (tmp_path / "x.obj").write_text("")
    with pytest.raises(InputError, match="npz or .pkl"):
        load_mano(tmp_path / "x.obj")
    with pytest.raises(InputError, match="tip vertices"):
        mano_pair(mano_npz, 0, 1, tip_vertices=(1, 2, 3, 4, 99))


# ----------------------------------------------------------------------------------------------
# glTF


def write_bending_capsule(path):
    """A capsule along z (z ∈ [-1.3, 1.3]) skinned to a root joint stacked on a shoulder joint at
    z = -1, an elbow at z = 0 and a wrist at z = 1; clip "bend" turns the elbow 0 → 90° about x over
    t ∈ [0, 1]. Vertices with z > 0.25 follow the elbow only, z < -0.25 the shoulder only."""
    v, f = capsule(radius=0.3, length=2.0, n_around=12, n_along=11)
    z = v[:, 2]
    w_elbow = np.clip((z + 0.25) / 0.5, 0.0, 1.0)
    g = pygltflib.GLTF2(asset=pygltflib.Asset(version="2.0"))
    data = bytearray()

    def accessor(array, ctype, atype):
        raw = np.ascontiguousarray(array).tobytes()
        while len(data) % 4:
            data.append(0)
        g.bufferViews.append(pygltflib.BufferView(buffer=0, byteOffset=len(data), byteLength=len(raw)))
        data.extend(raw)
        g.accessors.append(
            pygltflib.Accessor(bufferView=len(g.bufferViews) - 1, componentType=ctype, count=len(array), type=atype)
        )
        return len(g.accessors) - 1

    g.nodes = [
        pygltflib.Node(name="root", translation=[0, 0, -1.0], children=[1]),
        pygltflib.Node(name="shoulder", children=[2]),
        pygltflib.Node(name="elbow", translation=[0, 0, 1.0], children=[3]),
        pygltflib.Node(name="wrist", translation=[0, 0, 1.0]),
        pygltflib.Node(name="arm", mesh=0, skin=0),
    ]
    g.scenes = [pygltflib.Scene(nodes=[0, 4])]
    g.scene = 0
    bind = np.array([[0, 0, -1.0], [0, 0, -1.0], [0, 0, 0.0], [0, 0, 1.0]])
    ibm = np.tile(np.eye(4), (4, 1, 1))
    ibm[:, :3, 3] = -bind
    g.skins = [
        pygltflib.Skin(
            joints=[0, 1, 2, 3],
            inverseBindMatrices=accessor(
                np.swapaxes(ibm, 1, 2).astype(np.float32).reshape(4, 16), pygltflib.FLOAT, "MAT4"
            ),
        )
    ]
    joints = np.tile(np.array([1, 2, 0, 0], dtype=np.uint8), (v.shape[0], 1))
    weights = np.stack([1 - w_elbow, w_elbow, 0 * z, 0 * z], axis=1).astype(np.float32)
    g.meshes = [
        pygltflib.Mesh(
            primitives=[
                pygltflib.Primitive(
                    attributes=pygltflib.Attributes(
                        POSITION=accessor(v.astype(np.float32), pygltflib.FLOAT, "VEC3"),
                        JOINTS_0=accessor(joints, pygltflib.UNSIGNED_BYTE, "VEC4"),
                        WEIGHTS_0=accessor(weights, pygltflib.FLOAT, "VEC4"),
                    ),
                    indices=accessor(f.astype(np.uint32).reshape(-1), pygltflib.UNSIGNED_INT, "SCALAR"),
                )
            ]
        )
    ]
    s = math.sin(math.pi / 4)
    times = accessor(np.array([0.0, 1.0], dtype=np.float32), pygltflib.FLOAT, "SCALAR")
    rots = accessor(np.array([[0, 0, 0, 1], [s, 0, 0, s]], dtype=np.float32), pygltflib.FLOAT, "VEC4")
    g.animations = [
        pygltflib.Animation(
            name="bend",
            samplers=[pygltflib.AnimationSampler(input=times, output=rots, interpolation="LINEAR")],
            channels=[
                pygltflib.AnimationChannel(sampler=0, target=pygltflib.AnimationChannelTarget(node=2, path="rotation"))
            ],
        )
    ]
    g.buffers = [pygltflib.Buffer(byteLength=len(data))]
    g.set_binary_blob(bytes(data))
    g.save_binary(str(path))
    return v.astype(np.float32).astype(np.float64), f


def test_gltf_pair(tmp_path):
    path = tmp_path / "arm.glb"
    v, f = write_bending_capsule(path)
    pair = gltf_pair(path, 0.0, 1.0)
    assert pair.dataset == "arm" and pair.name == "arm_0_1"
    np.testing.assert_allclose(pair.source.vertices, v, atol=1e-12)
    np.testing.assert_array_equal(pair.target.faces, pair.source.faces)
    rx = np.array([[1, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])  # 90° about x
    forearm = v[:, 2] > 0.25
    upper = v[:, 2] < -0.25
    np.testing.assert_allclose(pair.target.vertices[forearm], v[forearm] @ rx.T, atol=1e-6)
    np.testing.assert_allclose(pair.target.vertices[upper], v[upper], atol=1e-6)
    assert_exact(pair, pair.target.vertices)
    # the stacked root is merged: shoulder, elbow, wrist
    assert pair.skeleton.n_joints == 3 and pair.info["merged_joints"] == 1
    np.testing.assert_allclose(pair.skeleton.positions, [[0, 0, -1.0], [0, 0, 0], [0, 0, 1.0]], atol=1e-12)
    np.testing.assert_allclose(pair.target_joints[2], [0, -1.0, 0], atol=1e-6)
    # load_skeleton and ``ncflow pose --skeleton-out`` merge the same joints (one shared function)
    for t, joints in [(0.0, pair.skeleton.positions), (1.0, pair.target_joints)]:
        loaded = load_skeleton(path, time=t)
        assert loaded.names == pair.skeleton.names
        np.testing.assert_array_equal(loaded.parents, pair.skeleton.parents)
        np.testing.assert_array_equal(loaded.positions, joints)
        out = tmp_path / f"pose_{t:g}"
        args = ["pose", str(path), "--time", str(t), "--out", str(out / "m.ply"), "--skeleton-out", str(out / "s.json")]
        assert main(args) == 0
        written = load_skeleton(out / "s.json")
        assert written.names == pair.skeleton.names
        np.testing.assert_allclose(written.positions, joints, atol=1e-15)

    retri = gltf_pair(path, 0.0, 1.0, retriangulate=True, target_resolution=24)
    assert retri.target.n_vertices != pair.target.n_vertices
    validate_mesh(retri.target.vertices, retri.target.faces)
    m = trimesh.Trimesh(retri.target.vertices, retri.target.faces, process=False)
    assert m.is_watertight and m.is_winding_consistent and m.euler_number == 2
    assert_exact(retri, pair.target.vertices)


# ----------------------------------------------------------------------------------------------
# writing and the command line


def read_rows(csv_path):
    with open(csv_path, newline="") as fh:
        reader = csv.DictReader(fh)
        assert reader.fieldnames == ["name", "source", "target", "skeleton", "gt", "gt_format", "dataset"]
        return list(reader)


def reload(csv_path, row):
    base = csv_path.parent
    src = load_mesh(base / row["source"])
    tgt = load_mesh(base / row["target"])
    sk = load_skeleton(base / row["skeleton"])
    gt = load_ground_truth(base / row["gt"], src, tgt, fmt=row["gt_format"])
    return src, tgt, sk, gt


def test_cli_procedural_pairs_reload(built, tmp_path):
    out = tmp_path / "pairs"
    assert main(["make-pairs", str(out), "--kind", "hand", "--n", "1", "--seed", "0"]) == 0
    csv_path = out / "pairs.csv"
    rows = read_rows(csv_path)
    assert len(rows) == 1 and rows[0]["name"] == "hand_000" and rows[0]["dataset"] == "hand"
    assert rows[0]["source"] == "pair_000/source.ply" and rows[0]["gt_format"] == "npz"
    src, tgt, sk, gt = reload(csv_path, rows[0])
    _, ref, _ = built["hand"]
    np.testing.assert_array_equal(src.vertices, ref.source.vertices)
    np.testing.assert_array_equal(tgt.vertices, ref.target.vertices)
    np.testing.assert_array_equal(tgt.faces, ref.target.faces)
    np.testing.assert_array_equal(gt.face, ref.ground_truth.face)
    np.testing.assert_allclose(gt.bary, ref.ground_truth.bary, atol=1e-15)
    np.testing.assert_array_equal(sk.positions, ref.skeleton.positions)
    np.testing.assert_array_equal(sk.parents, ref.skeleton.parents)
    tsk = load_skeleton(out / "pair_000" / "target_skeleton.tgf")
    np.testing.assert_array_equal(tsk.positions, ref.target_joints)


def write_padded_fake_mano(tmp_path):
    """The fake model padded to 745 vertices (the CLI uses MANO's tip vertices 320 … 744); returns its path."""
    arr = fake_mano_arrays()
    big = dict(arr)
    n_pad = 745 - arr["v_template"].shape[0]
    rng = np.random.default_rng(1)
    big["v_template"] = np.concatenate([arr["v_template"], arr["v_template"][0] + 0.01 * rng.normal(size=(n_pad, 3))])
    big["weights"] = np.concatenate([arr["weights"], np.tile(np.eye(16)[0], (n_pad, 1))])
    big["J_regressor"] = np.concatenate([arr["J_regressor"], np.zeros((16, n_pad))], axis=1)
    big["posedirs"] = np.concatenate([arr["posedirs"], np.zeros((n_pad, 3, 135))])
    big["shapedirs"] = np.concatenate([arr["shapedirs"], np.zeros((n_pad, 3, 10))])
    nv = 745
    big["faces"] = np.stack([np.arange(nv - 2), np.arange(1, nv - 1), np.arange(2, nv)], axis=1)
    model = tmp_path / "mano_big.npz"
    np.savez(model, **big)
    return model


def test_cli_mano_and_gltf(tmp_path, mano_npz):
    out = tmp_path / "mano"
    model = write_padded_fake_mano(tmp_path)
    nv = 745
    assert main(["make-pairs", str(out), "--mano", str(model), "--poses", "0,1,1,2", "--format", "obj"]) == 0
    rows = read_rows(out / "pairs.csv")
    assert [r["name"] for r in rows] == ["mano_0_1", "mano_1_2"]
    assert all(r["dataset"] == "mano" and r["target"].endswith("target.obj") for r in rows)
    src, tgt, sk, gt = reload(out / "pairs.csv", rows[0])
    assert src.n_vertices == tgt.n_vertices == nv and sk.n_bones == 20
    np.testing.assert_array_equal(src.faces[gt.face, np.argmax(gt.bary, axis=1)], np.arange(nv))

    glb = tmp_path / "arm.glb"
    write_bending_capsule(glb)
    out2 = tmp_path / "gltf"
    assert main(["make-pairs", str(out2), "--gltf", str(glb), "--times", "0,1,0.5,0", "--animation", "bend"]) == 0
    rows = read_rows(out2 / "pairs.csv")
    assert [r["name"] for r in rows] == ["arm_0_1", "arm_0.5_0"] and rows[0]["dataset"] == "arm"
    src, tgt, sk, gt = reload(out2 / "pairs.csv", rows[0])
    assert sk.n_joints == 3 and gt.complete
    np.testing.assert_allclose(surface_points(tgt.vertices, src.faces, gt.face, gt.bary), tgt.vertices, atol=1e-12)


def test_cli_errors(tmp_path, capsys):
    assert main(["make-pairs", str(tmp_path / "x"), "--gltf", "a.glb", "--times", "0,1,2"]) == 2
    assert "even number" in capsys.readouterr().err
    assert main(["make-pairs", str(tmp_path / "x"), "--n", "0"]) == 2
    assert main(["make-pairs", str(tmp_path / "x"), "--mano", str(tmp_path / "none.npz"), "--poses", "0,1"]) == 2
    assert "no such file" in capsys.readouterr().err


def test_write_pairs_layout(built, tmp_path):
    _, pair, same = built["quadruped"]
    path = write_pairs([pair, same], tmp_path / "w", fmt="obj")
    rows = read_rows(path)
    assert [r["source"] for r in rows] == ["pair_000/source.obj", "pair_001/source.obj"]
    for row, p in zip(rows, [pair, same]):
        src, tgt, sk, gt = reload(path, row)
        assert tgt.n_vertices == p.target.n_vertices and sk.n_joints == p.skeleton.n_joints
        np.testing.assert_allclose(gt.bary, p.ground_truth.bary, atol=1e-15)
        np.testing.assert_allclose(tgt.vertices, p.target.vertices, rtol=1e-6, atol=1e-6)  # OBJ text precision


# ----------------------------------------------------------------------------------------------
# targets turned and moved


def rotation_angle_deg(r):
    """Angle of a rotation matrix from its trace."""
    return math.degrees(math.acos(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0)))


def assert_moved_copy(moved, plain, angle_deg=None, shift_frac=None):
    """``moved`` is ``plain`` with its target turned and moved: target vertices and joints are
    R · (unmoved) + t to 1e-12, everything else (source, skeleton, faces, ground truth) identical."""
    m = moved.info["target_motion"]
    r, t = m["rotation"], m["translation"]
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-14)
    assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-14)
    np.testing.assert_allclose(r @ m["axis"], m["axis"], atol=1e-14)  # turns about its axis
    size = np.abs(plain.target.vertices).max()
    np.testing.assert_allclose(moved.target.vertices, plain.target.vertices @ r.T + t, rtol=0, atol=1e-12 * size)
    np.testing.assert_allclose(moved.target_joints, plain.target_joints @ r.T + t, rtol=0, atol=1e-12 * size)
    np.testing.assert_array_equal(moved.target.faces, plain.target.faces)
    np.testing.assert_array_equal(moved.ground_truth.face, plain.ground_truth.face)
    np.testing.assert_array_equal(moved.ground_truth.bary, plain.ground_truth.bary)
    np.testing.assert_array_equal(moved.source.vertices, plain.source.vertices)
    np.testing.assert_array_equal(moved.source.faces, plain.source.faces)
    np.testing.assert_array_equal(moved.skeleton.positions, plain.skeleton.positions)
    assert not np.allclose(moved.target.vertices, plain.target.vertices)
    if angle_deg is not None:
        assert rotation_angle_deg(r) == pytest.approx(angle_deg, abs=1e-6)
        assert m["angle_deg"] == pytest.approx(angle_deg, abs=1e-12)
    if shift_frac is not None:  # turned about its centroid, which moves by the shift
        diag = np.linalg.norm(np.ptp(plain.source.vertices, axis=0))
        centre_move = moved.target.vertices.mean(axis=0) - plain.target.vertices.mean(axis=0)
        np.testing.assert_allclose(centre_move, m["shift"], rtol=0, atol=1e-12 * size)
        assert np.linalg.norm(m["shift"]) == pytest.approx(shift_frac * diag, rel=1e-12)


def test_procedural_target_turned_and_moved(built):
    ch, plain, same = built["hand"]
    moved = make_pair("hand", 0, character=ch, target_rotation=90.0, target_translation=0.3)
    assert_moved_copy(moved, plain, angle_deg=90.0, shift_frac=0.3)
    # the ground truth is still exact: every target vertex is R · (Σ bary · posed source) + t
    m = moved.info["target_motion"]
    assert_exact(moved, pose_character(ch, moved.info["pose_b"]).vertices @ m["rotation"].T + m["translation"])
    # reproducible from the seed
    again = make_pair("hand", 0, character=ch, target_rotation=90.0, target_translation=0.3)
    np.testing.assert_array_equal(again.target.vertices, moved.target.vertices)
    # same connectivity, an angle range, rotation only
    turned = make_pair("hand", 0, retriangulate=False, character=ch, target_rotation=(30.0, 60.0))
    assert_moved_copy(turned, same, shift_frac=0.0)
    assert 30.0 <= rotation_angle_deg(turned.info["target_motion"]["rotation"]) <= 60.0
    # zero motion: no motion at all, the plain pair
    still = make_pair("hand", 0, retriangulate=False, character=ch, target_rotation=0.0, target_translation=0)
    assert "target_motion" not in still.info
    np.testing.assert_array_equal(still.target.vertices, same.target.vertices)


def test_target_motion_draws():
    c = np.array([1.0, 2.0, 3.0])
    assert target_motion(0, None, None, c, 1.0) is None and target_motion(0, 0.0, 0.0, c, 1.0) is None
    a, b, other = (target_motion(s, 180.0, 0.5, c, 2.0) for s in (7, 7, 8))
    for key in ("rotation", "translation", "axis", "shift"):
        np.testing.assert_array_equal(a[key], b[key])
    assert not np.allclose(a["axis"], other["axis"])
    np.testing.assert_allclose(a["rotation"], 2.0 * np.outer(a["axis"], a["axis"]) - np.eye(3), atol=1e-12)  # 180°
    np.testing.assert_allclose(a["rotation"] @ c + a["translation"], c + a["shift"], atol=1e-14)
    assert np.linalg.norm(a["shift"]) == pytest.approx(1.0, rel=1e-12)
    # uniform ranges
    draws = [target_motion(s, (10.0, 20.0), (0.1, 0.2), c, 1.0) for s in range(20)]
    assert all(10.0 <= d["angle_deg"] <= 20.0 and 0.1 <= np.linalg.norm(d["shift"]) <= 0.2 for d in draws)
    for bad in (181.0, -1.0, (20.0, 10.0), float("nan")):
        with pytest.raises(InputError, match="target rotation"):
            target_motion(0, bad, None, c, 1.0)
    with pytest.raises(InputError, match="target translation"):
        target_motion(0, None, -0.5, c, 1.0)


def test_mano_and_gltf_targets_turned_and_moved(mano_npz, tmp_path):
    plain = mano_pair(mano_npz, 0, 1, tip_vertices=TIPS)
    moved = mano_pair(mano_npz, 0, 1, tip_vertices=TIPS, target_rotation=180.0, target_translation=1.0, seed=2)
    assert_moved_copy(moved, plain, angle_deg=180.0, shift_frac=1.0)
    path = tmp_path / "arm.glb"
    write_bending_capsule(path)
    for retri in (False, True):
        plain = gltf_pair(path, 0.0, 1.0, retriangulate=retri, target_resolution=24, seed=3)
        moved = gltf_pair(
            path,
            0.0,
            1.0,
            retriangulate=retri,
            target_resolution=24,
            seed=3,
            target_rotation=45,
            target_translation=0.2,
        )
        assert_moved_copy(moved, plain, angle_deg=45.0, shift_frac=0.2)


def test_cli_moved_targets(built, tmp_path):
    from ncflow.runs.benchmark import read_pairs_csv

    out = tmp_path / "moved"
    args = ["make-pairs", str(out), "--kind", "hand", "--target-rotation", "90", "--target-translation", "0.3"]
    assert main(args) == 0
    with open(out / "pairs.csv", newline="") as fh:
        reader = csv.DictReader(fh)
        assert reader.fieldnames == list(PAIRS_CSV_COLUMNS + MOTION_CSV_COLUMNS)
        (row,) = list(reader)
    assert row["target_rotation_deg"] == "90" and row["target_motion"] == "pair_000/target_motion.json"
    motion = json.loads((out / row["target_motion"]).read_text())
    r, t = np.array(motion["rotation"]), np.array(motion["translation"])
    _, plain, _ = built["hand"]
    tgt = load_mesh(out / row["target"])
    np.testing.assert_allclose(tgt.vertices, plain.target.vertices @ r.T + t, rtol=0, atol=1e-12)
    tsk = load_skeleton(out / "pair_000" / "target_skeleton.tgf")
    np.testing.assert_allclose(tsk.positions, plain.target_joints @ r.T + t, rtol=0, atol=1e-12)
    gt = load_ground_truth(out / row["gt"], load_mesh(out / row["source"]), tgt, fmt="npz")
    np.testing.assert_array_equal(gt.face, plain.ground_truth.face)
    (spec,) = read_pairs_csv(out / "pairs.csv")  # the benchmark reads the extra columns fine
    assert spec.name == "hand_000"
    assert main(["make-pairs", str(tmp_path / "x"), "--target-rotation", "200"]) == 2
    assert main(["make-pairs", str(tmp_path / "x"), "--target-translation", "a,b"]) == 2


# ----------------------------------------------------------------------------------------------
# large articulations


def root_frame(pair, joints):
    """Joints in the character's rest frame: the target pose's root rotation and translation undone."""
    r0 = quat_to_matrix(pair.info["pose_b"].rotations[0], scalar_first=True)
    return (joints - pair.target_joints[0]) @ r0 + pair.skeleton.positions[0]


def test_more_large_joints():
    pair = make_pair("humanoid", 3, resolution=30, retriangulate=False, large_joints=3)
    names = pair.skeleton.names
    extra = pair.info["extra_large_joints"]
    assert len(extra) == 2 and len(set(extra + [pair.info["large_joint"]])) == 3
    assert set(extra) <= {"elbow_l", "elbow_r", "knee_l", "knee_r"}
    after = bone_angles(pair.target_joints, pair.skeleton.parents)
    child = {names[pair.skeleton.parents[c]]: c for c in range(1, len(names))}  # each hinge has one child
    for name, angle in zip(
        [pair.info["large_joint"]] + extra, [pair.info["large_angle_deg"]] + pair.info["extra_large_angles_deg"]
    ):
        assert 60.0 <= angle <= 100.0
        assert after[child[name]] == pytest.approx(angle, abs=1e-9)  # collinear bones at rest: the angle is the flexion
    # the same seed without extra joints: the same random pose elsewhere
    base = make_pair("humanoid", 3, resolution=30, retriangulate=False)
    assert base.info["large_joint"] == pair.info["large_joint"]
    changed = [
        j
        for j in range(len(names))
        if not np.array_equal(base.info["pose_b"].rotations[j], pair.info["pose_b"].rotations[j])
    ]
    assert sorted(names[j] for j in changed) == sorted(extra)
    with pytest.raises(InputError, match="large rotations"):
        make_pair("hand", 0, resolution=30, retriangulate=False, large_joints=5)
    with pytest.raises(InputError, match="at least 1"):
        make_pair("hand", 0, resolution=30, retriangulate=False, large_joints=0)


def test_hand_curl_and_posed_source():
    pair = make_pair("hand", 2, resolution=30, retriangulate=False, articulation="curl", source_pose="random")
    names, parents = pair.skeleton.names, pair.skeleton.parents
    assert pair.info["articulation"] == "curl" and len(pair.info["articulation_joints"]) == 15
    after = bone_angles(pair.target_joints, parents)
    for f in ("index", "middle", "ring", "little"):
        assert 70.0 - 1e-9 <= after[names.index(f"{f}3")] <= 100.0 + 1e-9  # PIP
        assert 45.0 - 1e-9 <= after[names.index(f"{f}_tip")] <= 70.0 + 1e-9  # DIP
        tip, wrist = names.index(f"{f}_tip"), 0
        flat = np.linalg.norm(pair.skeleton.positions[tip] - pair.skeleton.positions[wrist])
        assert np.linalg.norm(pair.target_joints[tip] - pair.target_joints[wrist]) < 0.6 * flat
    assert 30.0 - 1e-9 <= after[names.index("thumb3")] <= 50.0 + 1e-9
    # the posed source keeps every articulated joint at rest
    for name in pair.info["articulation_joints"]:
        np.testing.assert_array_equal(pair.info["pose_a"].rotations[names.index(name)], [1.0, 0.0, 0.0, 0.0])
    ch = make_character("hand", 2, 30)
    assert_exact(pair, pose_character(ch, pair.info["pose_b"]).vertices)


def test_humanoid_and_quadruped_articulations():
    cross = make_pair("humanoid", 1, resolution=30, retriangulate=False, articulation="cross")
    names = cross.skeleton.names
    j = root_frame(cross, cross.target_joints)
    rest = cross.skeleton.positions
    assert rest[names.index("hand_l"), 0] > 0 > rest[names.index("hand_r"), 0]
    assert j[names.index("hand_l"), 0] < rest[0, 0] < j[names.index("hand_r"), 0]  # each hand across the midline
    for side in ("l", "r"):  # forearms in front of the chest
        assert j[names.index(f"wrist_{side}"), 2] > rest[names.index("chest"), 2] + 0.1
    stride = make_pair("humanoid", 1, resolution=30, retriangulate=False, articulation="stride")
    j = root_frame(stride, stride.target_joints)
    thigh = np.linalg.norm(rest[names.index("knee_l")] - rest[names.index("hip_l")])
    assert abs(j[names.index("ankle_l"), 2] - j[names.index("ankle_r"), 2]) > 0.8 * thigh
    crouch = make_pair("humanoid", 1, resolution=30, retriangulate=False, articulation="crouch")
    after = bone_angles(crouch.target_joints, crouch.skeleton.parents)
    for side in ("l", "r"):
        assert 85.0 - 1e-9 <= after[names.index(f"ankle_{side}")] <= 110.0 + 1e-9  # knee bend
    gallop = make_pair("quadruped", 0, resolution=30, retriangulate=False, articulation="gallop")
    q = gallop.skeleton.names
    j = root_frame(gallop, gallop.target_joints)
    for side in ("l", "r"):
        assert j[q.index(f"fpaw_{side}"), 2] > j[q.index(f"shoulder_{side}"), 2] + 0.1
        assert j[q.index(f"hpaw_{side}"), 2] < j[q.index(f"hip_{side}"), 2] - 0.1
    with pytest.raises(InputError, match="no articulation 'curl' for the humanoid"):
        make_pair("humanoid", 1, resolution=30, retriangulate=False, articulation="curl")


# ----------------------------------------------------------------------------------------------
# MANO fist


def palm_centre(model, verts):
    """Centroid of the vertices skinned mostly to the wrist."""
    return verts[np.argmax(model.weights, axis=1) == 0].mean(axis=0)


def test_mano_fist_on_the_fake_model(mano_npz):
    model = load_mano(mano_npz)
    axes = mano_flexion_axes(model)
    # fake fingers point along +z, palm normal -y (index MCP - wrist) x (little MCP - wrist): axis = z x (-y) = +x
    np.testing.assert_allclose(axes[:12], np.tile([1.0, 0.0, 0.0], (12, 1)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(axes, axis=1), 1.0, atol=1e-12)
    fist = mano_finger_pose(model, "fist")
    deg = np.r_[np.tile([80.0, 90.0, 70.0], 4), [45.0, 45.0, 65.0]]
    np.testing.assert_allclose(fist.reshape(15, 3), axes * np.radians(deg)[:, None], atol=1e-15)
    np.testing.assert_array_equal(mano_finger_pose(model, "flat"), np.zeros(45))
    pair = mano_pair(model, "flat", "fist", tip_vertices=TIPS)
    assert pair.name == "mano_flat_fist" and pair.info["pose_b"] == "fist"
    np.testing.assert_allclose(pair.source.vertices, model.v_template, atol=1e-15)
    # the index finger curls in its own (y, z) plane: 80°, 170°, 240° accumulated
    j = model.v_template[:16]

    def seg(length, a):
        return length * np.array([0.0, -math.sin(math.radians(a)), math.cos(math.radians(a))])

    tip = j[1] + seg(0.03, 80) + seg(0.03, 170) + seg(0.02, 240)
    np.testing.assert_allclose(pair.target.vertices[16], tip, atol=1e-12)
    flat, closed = pair.source.vertices, pair.target.vertices
    d0 = np.linalg.norm(flat[list(TIPS)] - palm_centre(model, flat), axis=1)
    d1 = np.linalg.norm(closed[list(TIPS)] - palm_centre(model, closed), axis=1)
    assert np.all(d1 < 0.6 * d0)
    assert_exact(pair, closed)
    with pytest.raises(InputError, match="pose name"):
        mano_finger_pose(model, "open")


def test_cli_mano_flat_fist(tmp_path):
    model = write_padded_fake_mano(tmp_path)
    out = tmp_path / "fist"
    assert main(["make-pairs", str(out), "--mano", str(model), "--poses", "flat,fist", "--seed", "3"]) == 0
    (row,) = read_rows(out / "pairs.csv")
    assert row["name"] == "mano_flat_fist"
    tgt = load_mesh(out / row["target"])
    ref = mano_pair(model, "flat", "fist")
    np.testing.assert_array_equal(tgt.vertices, ref.target.vertices)


MANO_RIGHT = Path(__file__).resolve().parents[2] / "shared" / "data" / "mano" / "mano_right.npz"


@pytest.mark.skipif(not MANO_RIGHT.is_file(), reason="needs the shared MANO model")
def test_mano_fist_closes_the_real_hand():
    model = load_mano(MANO_RIGHT)
    axes = mano_flexion_axes(model)
    # the axes close the hand the way the captured mean pose does
    assert np.sum(axes[:12] * model.hands_mean.reshape(15, 3)[:12]) > 0
    pair = mano_pair(model, "flat", "fist", retriangulate=True, target_rotation=90.0, target_translation=0.5)
    flat, _ = mano_forward(model, np.zeros(45))
    closed, _ = mano_forward(model, mano_finger_pose(model, "fist"))
    np.testing.assert_allclose(pair.source.vertices, flat, atol=1e-15)
    tips = list(MANO_TIP_VERTICES)
    d0 = np.linalg.norm(flat[tips] - palm_centre(model, flat), axis=1)
    d1 = np.linalg.norm(closed[tips] - palm_centre(model, closed), axis=1)
    assert np.all(d1 < 0.6 * d0), d1 / d0
    m = pair.info["target_motion"]
    assert_exact(pair, closed @ m["rotation"].T + m["translation"])
