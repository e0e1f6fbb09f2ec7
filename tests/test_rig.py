"""``ncflow rig``: the target of a result as a skinned GLB (retarget/rig.py, io/gltf/rig_writer.py, cli/rig.py).

The result folder is built without training from a procedural humanoid pair with exact ground truth
(:func:`ncflow.synthetic.pairs.make_pair`, linear blend skinning, retriangulated target): the frames
are the character posed along the rotation-vector path from rest (frame 0, the source) to the target
pose (last frame), the skeleton frames are its joints, the map is the ground truth. The GLB is read
back with pygltflib (arrays decoded here) and with ncflow's own reader (``load_gltf_skin``).

Pose-back tolerance. Posing the target rig into the source pose cannot be exact: the target was
made by blending rigid bone motions (LBS), and blending their inverses is not the inverse of the
blend near joints. The reference is the ideal rig: the exact inverse bone transforms of the
generating pose and the generating weights carried exactly through the ground truth,
e_ref(v) = |Σ_j w_vj T_j⁻¹ y_v − x_v|. With the source's own skin (the generating weights, cut to 4
influences) the rig must reach 1.25 × e_ref in mean and 90th percentile (+1e-4 of the diagonal); with
weights derived from the skeleton alone (not the generating ones) 3 × e_ref in mean and 3 % of the
diagonal at every vertex. Measured (humanoid seed 1, 934 target vertices): source skin mean 0.061 %
of the diagonal (ideal 0.056 %), skeleton weights 0.11 %.
"""

from __future__ import annotations

import shutil

import numpy as np
import pygltflib
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from gltf_checks import accessor, assert_valid_gltf, node_world, skin_arrays
from ncflow.cli import main
from ncflow.errors import InputError
from ncflow.geometry.barycentric import surface_points
from ncflow.geometry.rigid import linear_blend_skinning, skinning_matrices
from ncflow.io.gltf.rig_writer import write_rig_glb
from ncflow.io.gltf.skins import load_gltf_skin, pose_gltf
from ncflow.io.result import ResultFolder, read_result, write_result
from ncflow.retarget.rig import joint_motion, rig_result
from ncflow.retarget.weights import gltf_skin_weights, limit_influences
from ncflow.skeleton.kinematics import Pose
from ncflow.synthetic.characters import make_character, pose_character, pose_world_transforms
from ncflow.synthetic.pairs import make_pair

K = 6


def _joint_weights(character) -> np.ndarray:
    """(V, J) generating weights per joint: bone b (ending at joint b + 1) moves with its parent joint."""
    parents = character.spec.parents
    w = np.zeros((character.vertices.shape[0], parents.shape[0]))
    np.add.at(w.T, parents[1:], character.weights.T)
    return w


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    """A result folder of a humanoid pair with exact ground truth, and the source as a skinned GLB."""
    root = tmp_path_factory.mktemp("rig")
    ch = make_character("humanoid", 1, 40)
    pair = make_pair("humanoid", 1, retriangulate=True, skinning="lbs", character=ch)
    pose_b = pair.info["pose_b"]
    rotvec = Rotation.from_quat(np.asarray(pose_b.rotations)[:, [1, 2, 3, 0]]).as_rotvec()
    times = np.linspace(0.0, 1.0, K)
    frames, joints = [], []
    for t in times:
        q = Rotation.from_rotvec(t * rotvec).as_quat()[:, [3, 0, 1, 2]]
        posed = pose_character(ch, Pose(q, t * np.asarray(pose_b.translation)), skinning="lbs")
        frames.append(posed.vertices)
        joints.append(posed.joints)
    frames, joints = np.stack(frames), np.stack(joints)
    gt = pair.ground_truth
    maps = {
        "map_face": gt.face,
        "map_bary": gt.bary,
        "p2p_tgt_to_src": ch.faces[gt.face, np.argmax(gt.bary, 1)],
        "p2p_src_to_tgt": cKDTree(pair.target.vertices).query(frames[-1])[1],
    }
    result = root / "result"
    write_result(
        result,
        ResultFolder(
            deformed_source=frames[-1],
            source_faces=ch.faces,
            maps=maps,
            frames=frames,
            frame_times=times,
            skeleton_target=ch.skeleton.with_positions(joints[-1]),
            skeleton_frames=joints,
            metrics={"config": {"flow": {"skinning_width": 0.05}}},
            target_vertices=pair.target.vertices,
            target_faces=pair.target.faces,
        ),
    )
    jw = _joint_weights(ch)
    j4, w4 = limit_influences(jw)
    skin = root / "source_skin.glb"
    write_rig_glb(
        skin,
        vertices=ch.vertices,
        faces=ch.faces,
        joint_positions=ch.skeleton.positions,
        parents=ch.skeleton.parents,
        names=list(ch.skeleton.names),
        joints=j4,
        weights=w4,
    )
    return {"root": root, "result": result, "skin": skin, "ch": ch, "pair": pair, "joints": joints, "frames": frames}


@pytest.fixture(scope="module")
def rigged(case):
    """The rig with the source's skin weights, and the rig with skeleton weights."""
    out = {}
    out["skin"] = rig_result(case["result"], case["root"] / "skin_rig.glb", source_skin=case["skin"])
    out["skeleton"] = rig_result(case["result"], case["root"] / "skeleton_rig.glb")
    return out


# ----------------------------------------------------------------------------------------------
# the rig


def test_weights_sum_to_one_and_bind_pose_is_the_target(case, rigged):
    res = read_result(case["result"], check_animation=False)
    target = res.target_vertices
    diag = np.linalg.norm(np.ptp(target, axis=0))
    for which, report in rigged.items():
        gltf, a = skin_arrays(report.path)
        assert report.weights_from == ("gltf skin" if which == "skin" else "skeleton")
        np.testing.assert_allclose(a["weights"].sum(1), 1.0, atol=1e-6)
        assert np.all(a["weights"] >= 0) and a["joints"].max() < len(gltf.skins[0].joints)
        np.testing.assert_array_equal(a["indices"], res.target_faces)
        # skinned through the node hierarchy and the inverse bind matrices, by hand
        world = node_world(gltf)[gltf.skins[0].joints]
        dense = np.zeros((a["position"].shape[0], world.shape[0]))
        np.add.at(dense, (np.repeat(np.arange(dense.shape[0]), 4), a["joints"].ravel()), a["weights"].ravel())
        posed = linear_blend_skinning(a["position"], dense, world @ a["ibm"])
        assert np.abs(posed - target).max() < 1e-5 * diag
        # and through ncflow's reader, forcing the node hierarchy (rest rotations given explicitly)
        rig = load_gltf_skin(report.path)
        again = rig.pose(joint_rotations=rig.rest_rotations[rig.joint_nodes], weld=False)
        assert np.abs(again.vertices - target).max() < 1e-5 * diag
        assert report.bind_error < 1e-5 * diag
        np.testing.assert_allclose(pose_gltf(report.path, weld=False).vertices, target, atol=1e-6 * diag)
        # joints at the fitted target skeleton, names kept
        np.testing.assert_allclose(again.joint_positions, res.skeleton_target.positions, atol=1e-6 * diag)
        assert again.names == list(res.joint_names)


def test_accessor_bounds_and_layout(rigged):
    gltf = pygltflib.GLTF2().load_binary(str(rigged["skin"].path))
    assert gltf.skins[0].skeleton == 0 and gltf.nodes[gltf.scenes[0].nodes[0]].name == "pelvis"
    for i, acc in enumerate(gltf.accessors):
        data = accessor(gltf, i)
        assert acc.min is not None and acc.max is not None, i
        assert list(data.min(0)) == acc.min and list(data.max(0)) == acc.max, i
    prim = gltf.meshes[0].primitives[0]
    assert gltf.bufferViews[gltf.accessors[prim.attributes.POSITION].bufferView].target == pygltflib.ARRAY_BUFFER
    assert gltf.bufferViews[gltf.accessors[prim.indices].bufferView].target == pygltflib.ELEMENT_ARRAY_BUFFER
    assert prim.material == 0 and gltf.materials[0].doubleSided
    normals = accessor(gltf, prim.attributes.NORMAL)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-6)
    # column-major inverse bind matrices: the translation in elements 12..14
    ibm = accessor(gltf, gltf.skins[0].inverseBindMatrices)
    np.testing.assert_array_equal(ibm[:, [3, 7, 11]], 0.0)
    np.testing.assert_array_equal(ibm[:, 15], 1.0)
    assert len(gltf.binary_blob()) % 4 == 0
    # pygltflib writes it back unchanged
    again = rigged["skin"].path.with_name("resaved.glb")
    gltf.save_binary(str(again))
    back = pygltflib.GLTF2().load_binary(str(again))
    assert back.binary_blob() == gltf.binary_blob() and back.accessors == gltf.accessors and back.nodes == gltf.nodes


def test_rigs_pass_the_khronos_validator(case, rigged):
    """The rigs (source skin weights and skeleton weights, each with its animation) and the skin written
    by ``write_rig_glb`` without an animation: no error, no warning.
    """
    assert_valid_gltf(rigged["skin"].path, rigged["skeleton"].path, case["skin"])


def test_pose_back_to_the_source(case, rigged):
    ch, pair = case["ch"], case["pair"]
    gt_points = pair.ground_truth_points()
    diag = np.linalg.norm(np.ptp(pair.target.vertices, axis=0))
    # the ideal rig: exact inverse transforms of the generating pose, generating weights through the GT
    world = pose_world_transforms(ch.spec.positions, ch.spec.parents, pair.info["pose_b"])
    inverse = np.linalg.inv(skinning_matrices(world, ch.spec.positions))
    carried = surface_points(_joint_weights(ch), ch.faces, pair.ground_truth.face, pair.ground_truth.bary)
    ref = np.linalg.norm(linear_blend_skinning(pair.target.vertices, carried, inverse) - gt_points, axis=1) / diag
    errors = {}
    for which, report in rigged.items():
        rig = load_gltf_skin(report.path)
        assert len(rig.animations) == 1 and rig.animations[0].duration == pytest.approx(2.0)
        assert rig.animations[0].n_channels == len(rig.joint_nodes) + 1  # rotations + the root's translation
        assert report.n_keys == K
        for k, t in enumerate(np.linspace(0.0, 2.0, K)):  # the clip's joints follow the skeleton frames
            at = rig.pose(time=float(t), weld=False)
            np.testing.assert_allclose(at.joint_positions, case["joints"][k], atol=1e-6 * diag)
        back = rig.pose(time=0.0, weld=False).vertices  # key 0: the source pose
        errors[which] = np.linalg.norm(back - gt_points, axis=1) / diag
    e = errors["skin"]
    assert e.mean() <= 1.25 * ref.mean() + 1e-4, (e.mean(), ref.mean())
    assert np.percentile(e, 90) <= 1.25 * np.percentile(ref, 90) + 1e-4
    e = errors["skeleton"]
    assert e.mean() <= 3.0 * ref.mean(), (e.mean(), ref.mean())
    assert e.max() <= 0.03
    # the clip is not the identity: the source pose is far from the target for many vertices
    assert np.mean(np.linalg.norm(pair.target.vertices - gt_points, axis=1) / diag) > 20 * ref.mean()


def test_joint_motion_recovers_rigid_rotations_with_twist():
    """A chain root → a → b → c with vertices rigidly attached to each joint's frame, moved by known
    rotations with twist: Kabsch at the root (two children), swing + mesh twist elsewhere, exact.
    """
    rng = np.random.default_rng(0)
    bind = np.array([[0, 0, 0], [1.0, 0, 0], [2.0, 0.3, 0], [2.5, 1.2, 0.2], [-0.5, 1.0, 0.0]])
    parents = np.array([-1, 0, 1, 2, 0])
    k = 4
    local = Rotation.from_rotvec(rng.normal(size=(k, 5, 3)) * 0.6).as_matrix()
    local[-1] = np.eye(3)  # last frame: the bind pose
    world_r = np.zeros_like(local)
    pos = np.zeros((k, 5, 3))
    for j in range(5):
        p = parents[j]
        world_r[:, j] = local[:, j] if p < 0 else world_r[:, p] @ local[:, j]
        pos[:, j] = bind[j] if p < 0 else pos[:, p] + np.einsum("kab,b->ka", world_r[:, p], bind[j] - bind[p])
    pos += rng.normal(size=(k, 1, 3))  # the root translates
    pos[-1] = bind
    cloud = rng.normal(size=(60, 3)) * 0.3
    owner = np.repeat([0, 1, 2], 20)
    rest_v = bind[owner] + cloud  # vertices around joints 0, 1, 2 (the ones with child bones)
    mesh = pos[:, owner] + np.einsum("knab,nb->kna", world_r[:, owner], rest_v - bind[owner])
    weights = np.zeros((60, 5))
    weights[np.arange(60), owner] = 1.0
    quats, world = joint_motion(bind, pos, parents, mesh_frames=mesh, vertex_weights=weights)
    for j in (0, 1, 2):
        np.testing.assert_allclose(world[:, j], world_r[:, j], atol=1e-9)
    # local rotations compose back to the world ones
    loc = Rotation.from_quat(quats.reshape(-1, 4)).as_matrix().reshape(k, 5, 3, 3)
    np.testing.assert_allclose(np.einsum("kab,kbc->kac", world[:, 0], loc[:, 1]), world[:, 1], atol=1e-9)
    # without the mesh: swing only, the bone direction still exact, the rotation the smallest one
    _, swing = joint_motion(bind, pos, parents)
    d = bind[2] - bind[1]
    np.testing.assert_allclose(np.einsum("kab,b->ka", swing[:, 1], d), pos[:, 2] - pos[:, 1], atol=1e-9)
    angle = Rotation.from_matrix(swing[:, 1]).magnitude()
    moved = pos[:, 2] - pos[:, 1]
    cos = moved @ d / np.linalg.norm(moved, axis=1) / np.linalg.norm(d)
    np.testing.assert_allclose(angle, np.arccos(np.clip(cos, -1, 1)), atol=1e-9)


# ----------------------------------------------------------------------------------------------
# the command and hostile inputs


def test_cli_writes_and_refuses_to_overwrite(case, capsys):
    out = case["root"] / "cli.glb"
    assert main(["rig", str(case["result"]), "--out", str(out), "--source-skin", str(case["skin"])]) == 0
    printed = capsys.readouterr().out
    assert "wrote" in printed and "934 vertices" in printed and "22 joints" in printed
    before = out.read_bytes()
    assert main(["rig", str(case["result"]), "--out", str(out), "--no-animation"]) == 2
    err = capsys.readouterr().err
    assert "--overwrite" in err and err.count("\n") == 1
    assert out.read_bytes() == before
    assert main(["rig", str(case["result"]), "--out", str(out), "--no-animation", "--overwrite"]) == 0
    assert not pygltflib.GLTF2().load_binary(str(out)).animations
    assert sorted(p.name for p in case["root"].iterdir() if p.name.startswith(".")) == []  # no temporaries


def test_cli_writes_the_motion_as_bvh(case, tmp_path, capsys):
    """``--bvh``: read back by bvhio, every joint of every frame where the result's skeleton_frames.json
    has it (within 1e-4 of the skeleton's size); refused without the animation, nothing written then.
    """
    import bvhio

    out, bvh = tmp_path / "rig.glb", tmp_path / "motion.bvh"
    assert main(["rig", str(case["result"]), "--out", str(out), "--bvh", str(bvh)]) == 0
    assert "motion.bvh" in capsys.readouterr().out
    res = read_result(case["result"], check_animation=False)
    frames = res.skeleton_frames
    size = np.linalg.norm(np.ptp(frames[-1], axis=0))
    names = list(res.joint_names or case["ch"].skeleton.names)
    root = bvhio.readAsHierarchy(str(bvh))
    assert [j.Name for j, _, _ in root.layout()][0] == names[0]
    for k in range(frames.shape[0]):
        root.loadPose(k, recursive=True)
        got = {j.Name: np.array(j.PositionWorld) for j, _, _ in root.layout()}
        np.testing.assert_allclose(np.array([got[n] for n in names]), frames[k], atol=1e-4 * size)
    assert (
        main(
            [
                "rig",
                str(case["result"]),
                "--out",
                str(tmp_path / "b.glb"),
                "--bvh",
                str(tmp_path / "b.bvh"),
                "--no-animation",
            ]
        )
        == 2
    )
    assert "BVH" in capsys.readouterr().err
    assert not (tmp_path / "b.glb").exists() and not (tmp_path / "b.bvh").exists()


@pytest.fixture
def copy_result(case, tmp_path):
    def make(drop=()):
        folder = tmp_path / "result"
        shutil.copytree(case["result"], folder)
        for name in drop:
            (folder / name).unlink()
        return folder

    return make


def _fails(capsys, argv, match, out):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and match in err, err
    assert not out.exists()
    assert [p for p in out.parent.iterdir() if p.name.startswith(".")] == []


def test_result_without_skeleton(copy_result, tmp_path, capsys):
    folder = copy_result(("skeleton_target.tgf", "skeleton_frames.json"))
    out = tmp_path / "out.glb"
    _fails(capsys, ["rig", str(folder), "--out", str(out)], "has no skeleton", out)


def test_result_without_target_mesh(case, copy_result, tmp_path, capsys):
    folder = copy_result(("target.ply",))
    out = tmp_path / "out.glb"
    _fails(capsys, ["rig", str(folder), "--out", str(out)], "--target", out)
    wrong = tmp_path / "wrong.ply"
    shutil.copy(case["result"] / "deformed_source.ply", wrong)  # the source's vertex count
    _fails(capsys, ["rig", str(folder), "--out", str(out), "--target", str(wrong)], "vertices but the result", out)
    target = tmp_path / "target.ply"
    shutil.copy(case["result"] / "target.ply", target)
    assert main(["rig", str(folder), "--out", str(out), "--target", str(target), "--no-animation"]) == 0


def test_bad_source_skins(case, tmp_path, capsys):
    ch = case["ch"]
    j4, w4 = limit_influences(_joint_weights(ch))
    common = {"joint_positions": ch.skeleton.positions, "parents": ch.skeleton.parents, "joints": j4, "weights": w4}
    names = list(ch.skeleton.names)
    out = tmp_path / "out.glb"
    # a different mesh: one vertex fewer
    keep = np.all(ch.faces != ch.vertices.shape[0] - 1, axis=1)
    short = tmp_path / "short.glb"
    write_rig_glb(
        short,
        vertices=ch.vertices[:-1],
        faces=ch.faces[keep],
        joint_positions=ch.skeleton.positions,
        parents=ch.skeleton.parents,
        names=names,
        joints=j4[:-1],
        weights=w4[:-1],
    )
    _fails(capsys, ["rig", str(case["result"]), "--out", str(out), "--source-skin", str(short)], "vertices", out)
    # the same vertex count, moved
    moved = tmp_path / "moved.glb"
    write_rig_glb(moved, vertices=ch.vertices * 1.01, faces=ch.faces, names=names, **common)
    _fails(capsys, ["rig", str(case["result"]), "--out", str(out), "--source-skin", str(moved)], "not the result", out)
    # joints the skeleton does not know
    renamed = tmp_path / "renamed.glb"
    write_rig_glb(
        renamed, vertices=ch.vertices, faces=ch.faces, names=[f"bone{j}" for j in range(len(names))], **common
    )
    _fails(capsys, ["rig", str(case["result"]), "--out", str(out), "--source-skin", str(renamed)], "none of", out)
    partly = tmp_path / "partly.glb"
    write_rig_glb(
        partly, vertices=ch.vertices, faces=ch.faces, names=names[:5] + ["x" + n for n in names[5:]], **common
    )
    _fails(capsys, ["rig", str(case["result"]), "--out", str(out), "--source-skin", str(partly)], "'xshoulder_l'", out)
    # not a glTF at all
    junk = tmp_path / "junk.glb"
    junk.write_bytes(b"glTF\x02\x00\x00\x00garbage")
    _fails(capsys, ["rig", str(case["result"]), "--out", str(out), "--source-skin", str(junk)], "junk.glb", out)


def test_bad_outputs_and_options(case, tmp_path, capsys):
    out = tmp_path / "out.gltf"
    _fails(capsys, ["rig", str(case["result"]), "--out", str(out)], ".glb", out)
    out = tmp_path / "out.glb"
    _fails(capsys, ["rig", str(case["result"]), "--out", str(out), "--max-angle", "200"], "--max-angle", out)
    _fails(capsys, ["rig", str(tmp_path / "missing"), "--out", str(out)], "no such result folder", out)
    with pytest.raises(InputError, match="clip length"):
        rig_result(case["result"], out, clip_seconds=0.0)


def test_skin_joint_stacked_on_a_named_joint_gives_it_its_weight(case, tmp_path):
    """A skin joint the skeleton does not name (``head_stack``, stacked on ``head``, as rigs have and as
    ``load_skeleton`` merges) passes its weights to that joint; anything else stays where it was.
    """
    ch = case["ch"]
    names = list(ch.skeleton.names)
    head = names.index("head")
    jw = _joint_weights(ch)
    extra = np.zeros((jw.shape[0], 1))
    moving = jw[:, head] > 0.5
    extra[moving, 0] = 0.5 * jw[moving, head]  # half of the head's weight moved to head_stack
    jw2 = np.concatenate([jw, extra], 1)
    jw2[moving, head] *= 0.5
    j4, w4 = limit_influences(jw2)
    path = tmp_path / "stacked.glb"
    write_rig_glb(
        path,
        vertices=ch.vertices,
        faces=ch.faces,
        joint_positions=np.concatenate([ch.skeleton.positions, ch.skeleton.positions[head : head + 1]]),
        parents=np.concatenate([ch.skeleton.parents, [head]]),
        names=names + ["head_stack"],
        joints=j4,
        weights=w4,
    )
    got = gltf_skin_weights(load_gltf_skin(path), case["frames"][0], names)
    written = np.zeros_like(jw2)  # the skin as written (4 influences), head_stack's column added to head's
    np.add.at(written, (np.repeat(np.arange(written.shape[0]), 4), j4.ravel()), w4.ravel())
    ref = written[:, :-1].copy()
    ref[:, head] += written[:, -1]
    assert written[:, -1].max() > 0.2  # the stacked joint did carry weight
    np.testing.assert_allclose(got, ref, atol=1e-6)
