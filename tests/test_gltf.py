"""glTF skin import and posing, checked against a tiny hand-built GLB with analytic poses.

The test file (written here with pygltflib): a box-shaped arm along x from 0 to 2 (cross-section
0.2 × 0.2 centred on y = 0, z = 0.5) skinned to a shoulder (x = 0) and an elbow (x = 1); the ring at
x = 1 is weighted half/half. Hierarchy::

    Armature (matrix: translation (0, 0, 0.5))
    ├── shoulder (joint)
    │   └── helper (not a joint, translation (0.5, 0, 0))
    │       └── elbow (joint, translation (0.5, 0, 0))
    │           └── wrist (joint, translation (1, 0, 0), no weights)
    ├── prop (not a joint of skin 0, translation (0, 3, 0))
    └── arm (mesh + skin 0, translation (5, 5, 5): must be ignored per the glTF spec)

Skin 0 lists its joints as [elbow, shoulder, wrist]. The mesh has two primitives: the tube sides
(12 vertices; interleaved, strided positions; float weights; u8 joints; u16 indices) and the two
end caps with their own seam-duplicate corners (8 vertices; u16 joints; normalised u8 weights;
u32 indices), so 20 file vertices weld to 12.

Clips: "bend" (elbow rotation LINEAR over t = 0, 1, 2: 0°, 120°, 120° about axis (1, 2, 2)/3;
shoulder translation LINEAR (0,0,0) → (0,2,0) over t ∈ [0, 2]); "step" (shoulder translation STEP,
sparse output accessor); "cubic" (shoulder translation CUBICSPLINE).
"""

from __future__ import annotations

import json
import math
import struct

import numpy as np
import pygltflib
import pytest

from gltf_checks import assert_valid_gltf
from ncflow.cli import main
from ncflow.errors import InputError
from ncflow.geometry.rigid import quat_to_matrix
from ncflow.geometry.skeleton import merge_zero_length_bones
from ncflow.io.gltf.animation import gltf_animations, interpolate_keyframes
from ncflow.io.gltf.skins import gltf_skeleton, load_gltf_skin, pose_gltf

AXIS = np.array([1.0, 2.0, 2.0]) / 3.0
ANGLE = math.radians(120.0)
ELBOW = np.array([1.0, 0.0, 0.5])
SHOULDER = np.array([0.0, 0.0, 0.5])
WRIST = np.array([2.0, 0.0, 0.5])
H = 0.1


def _rodrigues(axis: np.ndarray, angle: float) -> np.ndarray:
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def _quat(axis: np.ndarray, angle: float) -> list[float]:
    s = math.sin(angle / 2)
    return [*(s * axis), math.cos(angle / 2)]


def _ring(x: float) -> np.ndarray:
    return np.array([[x, -H, 0.5 - H], [x, H, 0.5 - H], [x, H, 0.5 + H], [x, -H, 0.5 + H]])


REST = np.concatenate([_ring(0.0), _ring(1.0), _ring(2.0)])  # the 12 welded vertices, file order
SHOULDER_W = np.array([1.0] * 4 + [0.5] * 4 + [0.0] * 4)  # weight of the shoulder per welded vertex


def _expected(shoulder_t: np.ndarray, elbow_r: np.ndarray) -> np.ndarray:
    """Analytic skinned positions of REST: shoulder moved by shoulder_t, elbow rotated by elbow_r."""
    by_shoulder = REST + shoulder_t
    by_elbow = ELBOW + (REST - ELBOW) @ elbow_r.T + shoulder_t
    w = SHOULDER_W[:, None]
    return w * by_shoulder + (1 - w) * by_elbow


class _Blob:
    """Collects buffer views / accessors into one GLB binary chunk."""

    def __init__(self, gltf: pygltflib.GLTF2):
        self.gltf = gltf
        self.data = bytearray()

    def view(self, raw: bytes, stride: int | None = None) -> int:
        while len(self.data) % 4:
            self.data.append(0)
        self.gltf.bufferViews.append(
            pygltflib.BufferView(buffer=0, byteOffset=len(self.data), byteLength=len(raw), byteStride=stride)
        )
        self.data.extend(raw)
        return len(self.gltf.bufferViews) - 1

    def accessor(self, array: np.ndarray, ctype: int, atype: str, normalized: bool = False, view=None, offset=0) -> int:
        array = np.asarray(array)
        if view is None:
            view = self.view(array.tobytes())
        self.gltf.accessors.append(
            pygltflib.Accessor(
                bufferView=view,
                byteOffset=offset,
                componentType=ctype,
                count=array.shape[0],
                type=atype,
                normalized=normalized,
            )
        )
        return len(self.gltf.accessors) - 1


def _arm_gltf() -> pygltflib.GLTF2:
    g = pygltflib.GLTF2(asset=pygltflib.Asset(version="2.0"))
    b = _Blob(g)
    f4, u1, u2, u4 = pygltflib.FLOAT, pygltflib.UNSIGNED_BYTE, pygltflib.UNSIGNED_SHORT, pygltflib.UNSIGNED_INT

    # nodes: 0 Armature, 1 shoulder, 2 helper, 3 elbow, 4 wrist, 5 prop, 6 arm
    arm_matrix = np.eye(4)
    arm_matrix[:3, 3] = SHOULDER
    g.nodes = [
        pygltflib.Node(name="Armature", matrix=arm_matrix.T.reshape(-1).tolist(), children=[1, 5, 6]),
        pygltflib.Node(name="shoulder", children=[2]),
        pygltflib.Node(name="helper", translation=[0.5, 0, 0], children=[3]),
        pygltflib.Node(name="elbow", translation=[0.5, 0, 0], children=[4]),
        pygltflib.Node(name="wrist", translation=[1.0, 0, 0]),
        pygltflib.Node(name="prop", translation=[0, 3.0, 0]),
        pygltflib.Node(name="arm", mesh=0, skin=0, translation=[5.0, 5.0, 5.0]),
    ]
    g.scenes = [pygltflib.Scene(nodes=[0])]
    g.scene = 0

    # skin 0: joints [elbow, shoulder, wrist]; inverse bind = translation by -(bind position)
    def ibm(points):
        m = np.tile(np.eye(4), (len(points), 1, 1))
        m[:, :3, 3] = -np.asarray(points)
        return np.ascontiguousarray(np.swapaxes(m, 1, 2)).astype(np.float32)  # column-major

    g.skins = [
        pygltflib.Skin(joints=[3, 1, 4], inverseBindMatrices=b.accessor(ibm([ELBOW, SHOULDER, WRIST]), f4, "MAT4")),
        # skin 1: [elbow, wrist, prop]: elbow and prop have no joint ancestor -> prop (shallower) is root
        pygltflib.Skin(
            joints=[3, 4, 5], inverseBindMatrices=b.accessor(ibm([ELBOW, WRIST, [0, 3.0, 0.5]]), f4, "MAT4")
        ),
    ]
    E, S = 0, 1  # skin indices of elbow and shoulder

    # primitive 0: tube sides, 12 vertices, positions interleaved with 4 bytes of padding (stride 16)
    pos = REST.astype(np.float32)
    interleaved = b"".join(p.tobytes() + b"\xab\xcd\xef\x01" for p in pos)
    pos_view = b.view(interleaved, stride=16)
    pos_acc = b.accessor(pos, f4, "VEC3", view=pos_view)
    joints0 = np.array([[S, 0, 0, 0]] * 4 + [[S, E, 0, 0]] * 4 + [[E, 0, 0, 0]] * 4, dtype=np.uint8)
    weights0 = np.array([[1, 0, 0, 0]] * 4 + [[0.5, 0.5, 0, 0]] * 4 + [[1, 0, 0, 0]] * 4, dtype=np.float32)
    sides = []
    for r in range(2):
        for k in range(4):
            a, c = 4 * r + k, 4 * r + (k + 1) % 4
            sides += [[a, c, c + 4], [a, c + 4, a + 4]]
    prim0 = pygltflib.Primitive(
        attributes=pygltflib.Attributes(
            POSITION=pos_acc,
            JOINTS_0=b.accessor(joints0, u1, "VEC4"),
            WEIGHTS_0=b.accessor(weights0, f4, "VEC4"),
        ),
        indices=b.accessor(np.array(sides, dtype=np.uint16).reshape(-1), u2, "SCALAR"),
    )
    # primitive 1: end caps with their own (seam-duplicate) corners
    cap_pos = np.concatenate([_ring(0.0), _ring(2.0)]).astype(np.float32)
    joints1 = np.array([[S, 0, 0, 0]] * 4 + [[E, 0, 0, 0]] * 4, dtype=np.uint16)
    weights1 = np.array([[255, 0, 0, 0]] * 8, dtype=np.uint8)
    caps = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7]], dtype=np.uint32).reshape(-1)
    prim1 = pygltflib.Primitive(
        attributes=pygltflib.Attributes(
            POSITION=b.accessor(cap_pos, f4, "VEC3"),
            JOINTS_0=b.accessor(joints1, u2, "VEC4"),
            WEIGHTS_0=b.accessor(weights1, u1, "VEC4", normalized=True),
        ),
        indices=b.accessor(caps, u4, "SCALAR"),
    )
    g.meshes = [pygltflib.Mesh(name="arm", primitives=[prim0, prim1])]

    # animations
    def sampler(times, values, interp, out_acc=None):
        t_acc = b.accessor(np.asarray(times, dtype=np.float32), f4, "SCALAR")
        values = np.asarray(values, dtype=np.float32)
        if out_acc is None:
            out_acc = b.accessor(values, f4, "VEC4" if values.shape[1] == 4 else "VEC3")
        return pygltflib.AnimationSampler(input=t_acc, output=out_acc, interpolation=interp)

    q0, q1 = [0, 0, 0, 1], _quat(AXIS, ANGLE)
    bend = pygltflib.Animation(
        name="bend",
        samplers=[
            sampler([0, 1, 2], [q0, q1, q1], "LINEAR"),
            sampler([0, 2], [[0, 0, 0], [0, 2, 0]], "LINEAR"),
        ],
        channels=[
            pygltflib.AnimationChannel(sampler=0, target=pygltflib.AnimationChannelTarget(node=3, path="rotation")),
            pygltflib.AnimationChannel(sampler=1, target=pygltflib.AnimationChannelTarget(node=1, path="translation")),
        ],
    )
    # STEP translation with a sparse output accessor: zeros, entries 1 and 2 replaced
    sp_idx = b.view(np.array([1, 2], dtype=np.uint16).tobytes())
    sp_val = b.view(np.array([[1, 0, 0], [3, 0, 0]], dtype=np.float32).tobytes())
    g.accessors.append(
        pygltflib.Accessor(
            componentType=f4,
            count=3,
            type="VEC3",
            sparse=pygltflib.Sparse(
                count=2,
                indices=pygltflib.AccessorSparseIndices(bufferView=sp_idx, componentType=u2),
                values=pygltflib.AccessorSparseValues(bufferView=sp_val),
            ),
        )
    )
    step = pygltflib.Animation(
        name="step",
        samplers=[sampler([0, 1, 2], None, "STEP", out_acc=len(g.accessors) - 1)],
        channels=[
            pygltflib.AnimationChannel(sampler=0, target=pygltflib.AnimationChannelTarget(node=1, path="translation"))
        ],
    )
    # CUBICSPLINE: keys t=0: (a0, v0, b0) = (0, 0, (4,0,0)); t=2: (a1, v1, b1) = (0, (2,0,0), 0)
    cubic_values = [[0, 0, 0], [0, 0, 0], [4, 0, 0], [0, 0, 0], [2, 0, 0], [0, 0, 0]]
    cubic = pygltflib.Animation(
        name="cubic",
        samplers=[sampler([0, 2], cubic_values, "CUBICSPLINE")],
        channels=[
            pygltflib.AnimationChannel(sampler=0, target=pygltflib.AnimationChannelTarget(node=1, path="translation"))
        ],
    )
    g.animations = [bend, step, cubic]

    g.buffers = [pygltflib.Buffer(byteLength=len(b.data))]
    g.set_binary_blob(bytes(b.data))
    return g


@pytest.fixture(scope="module")
def arm_glb(tmp_path_factory):
    path = tmp_path_factory.mktemp("gltf") / "arm.glb"
    _arm_gltf().save_binary(str(path))
    return path


def _shoulder_translation_bend(t: float) -> np.ndarray:
    return np.array([0.0, min(max(t, 0.0), 2.0), 0.0])


def _elbow_rotation_bend(t: float) -> np.ndarray:
    return _rodrigues(AXIS, ANGLE * min(max(t, 0.0), 1.0))  # slerp: the angle grows linearly


# ----------------------------------------------------------------------------------------------


def test_bind_pose_reproduces_rest_mesh_and_welds_seams(arm_glb):
    rig = load_gltf_skin(arm_glb)
    assert rig.positions.shape == (20, 3)  # both primitives concatenated
    assert rig.faces.shape == (20, 3)
    posed = pose_gltf(arm_glb)
    assert posed.vertices.shape == (12, 3)  # 8 cap corners welded onto the ring vertices
    assert posed.faces.shape == (20, 3)
    np.testing.assert_allclose(posed.vertices, REST, atol=1e-6)
    np.testing.assert_array_equal(posed.file_index, np.arange(12))
    np.testing.assert_allclose(rig.positions[posed.file_index], posed.vertices, atol=0)
    # the welded surface is closed: every edge has two faces, V - E + F = 2
    edges = np.sort(posed.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2) and 12 - counts.size + 20 == 2
    np.testing.assert_allclose(posed.joint_positions, [ELBOW, SHOULDER, WRIST], atol=1e-6)
    unwelded = pose_gltf(arm_glb, weld=False)
    assert unwelded.vertices.shape == (20, 3)
    # weights: normalised u8 255 -> 1.0, rows sum to 1
    np.testing.assert_allclose(rig.weights.sum(1), 1.0, atol=1e-12)


def test_rest_nodes_reproduce_bind_pose(arm_glb):
    rig = load_gltf_skin(arm_glb)
    posed = rig.pose(joint_rotations=np.tile([0.0, 0.0, 0.0, 1.0], (3, 1)))  # the nodes' own rotations
    np.testing.assert_allclose(posed.vertices, REST, atol=1e-6)
    # at t = 0 every animated channel is at its rest value too
    np.testing.assert_allclose(rig.pose(0.0, "bend").vertices, REST, atol=1e-6)


@pytest.mark.parametrize("t", [0.25, 1.0, 1.5])
def test_linear_clip_matches_analytic_pose(arm_glb, t):
    posed = pose_gltf(arm_glb, time=t, animation="bend")
    expected = _expected(_shoulder_translation_bend(t), _elbow_rotation_bend(t))
    np.testing.assert_allclose(posed.vertices, expected, atol=1e-6)
    assert posed.animation == "bend" and posed.time == t
    s = _shoulder_translation_bend(t)
    r = _elbow_rotation_bend(t)
    np.testing.assert_allclose(posed.joint_positions, [ELBOW + s, SHOULDER + s, ELBOW + s + r @ [1.0, 0, 0]], atol=1e-6)


def test_slerp_differs_from_normalised_lerp(arm_glb):
    """At t = 0.25 slerp gives 30° exactly; nlerp of (identity, 120°) would give about 27.8°."""
    q = interpolate_keyframes(
        np.array([0.0, 1.0]), np.array([[0, 0, 0, 1.0], _quat(AXIS, ANGLE)]), 0.25, "LINEAR", True
    )
    np.testing.assert_allclose(q, _quat(AXIS, ANGLE / 4), atol=1e-12)
    nlerp = 0.75 * np.array([0, 0, 0, 1.0]) + 0.25 * np.array(_quat(AXIS, ANGLE))
    assert abs(2 * math.acos(nlerp[3] / np.linalg.norm(nlerp)) - ANGLE / 4) > 0.03
    np.testing.assert_allclose(quat_to_matrix(q, scalar_first=False), _rodrigues(AXIS, ANGLE / 4), atol=1e-12)


def test_time_is_clamped_to_the_clip(arm_glb):
    rig = load_gltf_skin(arm_glb)
    before, after = rig.pose(-3.0, "bend"), rig.pose(99.0, "bend")
    np.testing.assert_allclose(before.vertices, REST, atol=1e-6)
    np.testing.assert_allclose(after.vertices, _expected(np.array([0, 2.0, 0]), _rodrigues(AXIS, ANGLE)), atol=1e-6)
    assert before.time == 0.0 and after.time == 2.0


def test_step_sampler_with_sparse_output(arm_glb):
    rig = load_gltf_skin(arm_glb)
    no_rotation = np.eye(3)
    for t, shift in [(0.5, [0, 0, 0]), (1.0, [1, 0, 0]), (1.99, [1, 0, 0]), (2.0, [3, 0, 0]), (5.0, [3, 0, 0])]:
        posed = rig.pose(t, "step")
        np.testing.assert_allclose(posed.vertices, _expected(np.array(shift, float), no_rotation), atol=1e-6)


def test_cubicspline_sampler(arm_glb):
    rig = load_gltf_skin(arm_glb)
    # t = 0.5: td = 2, u = 0.25; h10 = u³ - 2u² + u = 0.140625, h01 = -2u³ + 3u² = 0.15625
    # x = h10 · td · 4 + h01 · 2 = 1.125 + 0.3125 = 1.4375
    posed = rig.pose(0.5, "cubic")
    np.testing.assert_allclose(posed.vertices, _expected(np.array([1.4375, 0, 0]), np.eye(3)), atol=1e-6)
    # t = 1.5: u = 0.75; h10 = 0.046875, h01 = 0.84375 -> x = 0.375 + 1.6875 = 2.0625
    posed = rig.pose(1.5, "cubic")
    np.testing.assert_allclose(posed.vertices, _expected(np.array([2.0625, 0, 0]), np.eye(3)), atol=1e-6)
    # at the keyframe the value itself
    np.testing.assert_allclose(rig.pose(2.0, "cubic").vertices, REST + [2.0, 0, 0], atol=1e-6)


def test_ground_truth_is_consistent_between_times(arm_glb):
    """Vertex i at two times is the same body point: both equal that point's analytic motion."""
    rig = load_gltf_skin(arm_glb)
    a, b = rig.pose(0.25, "bend"), rig.pose(1.5, "bend")
    np.testing.assert_array_equal(a.faces, b.faces)
    np.testing.assert_array_equal(a.file_index, b.file_index)
    bind = rig.positions[a.file_index]
    for posed, t in [(a, 0.25), (b, 1.5)]:
        s, r = _shoulder_translation_bend(t), _elbow_rotation_bend(t)
        w = SHOULDER_W[:, None]
        np.testing.assert_allclose(
            posed.vertices, w * (bind + s) + (1 - w) * (ELBOW + (bind - ELBOW) @ r.T + s), atol=1e-6
        )
    # rigid parts move rigidly: distances within the shoulder ring and within the wrist ring are kept
    for ring in (slice(0, 4), slice(8, 12)):
        da = np.linalg.norm(a.vertices[ring, None] - a.vertices[None, ring], axis=-1)
        db = np.linalg.norm(b.vertices[ring, None] - b.vertices[None, ring], axis=-1)
        np.testing.assert_allclose(da, db, atol=1e-6)


def test_explicit_joint_rotations(arm_glb):
    q = np.tile([0.0, 0.0, 0.0, 1.0], (3, 1))
    q[0] = _quat(np.array([0, 0, 1.0]), math.pi / 2)  # elbow (skin joint 0): 90° about z
    posed = pose_gltf(arm_glb, joint_rotations=q)
    np.testing.assert_allclose(
        posed.vertices, _expected(np.zeros(3), _rodrigues(np.array([0, 0, 1.0]), math.pi / 2)), atol=1e-6
    )
    np.testing.assert_allclose(posed.joint_positions[2], [1.0, 1.0, 0.5], atol=1e-6)  # wrist
    # with a time: the rotation replaces the animated elbow rotation; the animated translation stays
    q[0] = [0, 0, 0, 2.0]  # not unit: normalised
    posed = pose_gltf(arm_glb, time=1.5, animation=0, joint_rotations=q)
    np.testing.assert_allclose(posed.vertices, REST + [0, 1.5, 0], atol=1e-6)
    with pytest.raises(InputError):
        pose_gltf(arm_glb, joint_rotations=np.zeros((3, 4)))
    with pytest.raises(InputError):
        pose_gltf(arm_glb, joint_rotations=np.zeros((2, 4)) + 1)


def _file_order(skeleton):
    """(positions, parents, names) of a skeleton in the order of the joint list it was built from."""
    internal = np.argsort(skeleton.file_index)  # internal index of the i-th listed joint
    parents = skeleton.parents[internal]
    parents = np.where(parents < 0, -1, skeleton.file_index[np.maximum(parents, 0)])
    return skeleton.positions[internal], parents, [skeleton.names[i] for i in internal]


def test_gltf_skeleton_matches_hierarchy(arm_glb):
    skel, keep = gltf_skeleton(arm_glb)
    np.testing.assert_array_equal(keep, [0, 1, 2])  # no stacked joints: all kept
    pos, parents, names = _file_order(skel)
    assert names == ["elbow", "shoulder", "wrist"]
    np.testing.assert_array_equal(parents, [1, -1, 0])  # the helper node between shoulder and elbow is skipped
    np.testing.assert_allclose(pos, [ELBOW, SHOULDER, WRIST], atol=1e-6)
    assert skel.name == str(arm_glb) and skel.label(0) == "joint 1 ('shoulder')"
    pos, parents, _ = _file_order(gltf_skeleton(arm_glb, time=1.0, animation="bend")[0])
    r = _rodrigues(AXIS, ANGLE)
    np.testing.assert_allclose(
        pos, [ELBOW + [0, 1, 0], SHOULDER + [0, 1, 0], ELBOW + [0, 1, 0] + r @ [1.0, 0, 0]], atol=1e-6
    )
    # a skin already read gives the same skeleton
    rig = load_gltf_skin(arm_glb)
    again = gltf_skeleton(rig, time=1.0, animation="bend", name="arm")[0]
    np.testing.assert_array_equal(_file_order(again)[0], pos)
    assert again.name == "arm"
    # skin 1 = [elbow, wrist, prop]: two joints without joint ancestor; prop is higher in the tree
    pos, parents, names = _file_order(gltf_skeleton(arm_glb, skin=1, merge=False)[0])
    assert names == ["elbow", "wrist", "prop"]
    np.testing.assert_array_equal(parents, [2, 0, -1])
    np.testing.assert_allclose(pos, [ELBOW, WRIST, [0, 3, 0.5]], atol=1e-6)


def test_animation_list_and_selection(arm_glb):
    clips = gltf_animations(arm_glb)
    assert [(c.index, c.name, c.start, c.end, c.n_channels) for c in clips] == [
        (0, "bend", 0.0, 2.0, 2),
        (1, "step", 0.0, 2.0, 1),
        (2, "cubic", 0.0, 2.0, 1),
    ]
    rig = load_gltf_skin(arm_glb)
    a, b, c = rig.pose(0.5, "cubic"), rig.pose(0.5, 2), rig.pose(0.5, "2")
    np.testing.assert_allclose(a.vertices, b.vertices, atol=0)
    np.testing.assert_allclose(a.vertices, c.vertices, atol=0)
    np.testing.assert_allclose(rig.pose(0.5).vertices, rig.pose(0.5, "bend").vertices, atol=0)  # first by default
    with pytest.raises(InputError, match="no animation named 'walk'"):
        rig.pose(0.5, "walk")
    with pytest.raises(InputError, match="out of range"):
        rig.pose(0.5, 3)
    with pytest.raises(InputError, match="finite"):
        rig.pose(float("nan"))


def test_gltf_json_with_data_uri(tmp_path):
    """The same file as .gltf JSON with an embedded base64 buffer poses the same."""
    import base64

    g = _arm_gltf()
    blob = g.binary_blob()
    g.buffers[0].uri = "data:application/octet-stream;base64," + base64.b64encode(blob).decode()
    g.set_binary_blob(None)
    path = tmp_path / "arm.gltf"
    path.write_text(g.to_json())
    posed = pose_gltf(path, time=0.25, animation="bend")
    np.testing.assert_allclose(
        posed.vertices, _expected(_shoulder_translation_bend(0.25), _elbow_rotation_bend(0.25)), atol=1e-6
    )


def test_bad_files(tmp_path):
    junk = tmp_path / "junk.glb"
    junk.write_bytes(b"this is not a glTF file at all")
    with pytest.raises(InputError, match="junk.glb: not a glTF 2.0 file"):
        pose_gltf(junk)
    truncated = tmp_path / "trunc.glb"
    truncated.write_bytes(b"glTF" + struct.pack("<II", 2, 100) + b"\x00" * 4)
    with pytest.raises(InputError, match="trunc.glb"):
        pose_gltf(truncated)
    g = _arm_gltf()
    g.skins = []
    for n in g.nodes:
        n.skin = None
    noskin = tmp_path / "noskin.glb"
    g.save_binary(str(noskin))
    with pytest.raises(InputError, match="has no skin"):
        gltf_skeleton(noskin)
    g = _arm_gltf()
    g.extensionsUsed = g.extensionsRequired = ["KHR_draco_mesh_compression"]
    draco = tmp_path / "draco.glb"
    g.save_binary(str(draco))
    with pytest.raises(InputError, match="KHR_draco_mesh_compression"):
        pose_gltf(draco)
    g = _arm_gltf()
    g.animations[0].samplers[0].interpolation = "n" * 3000  # found by the glTF fuzz test: quoted whole
    odd = tmp_path / "odd.glb"
    g.save_binary(str(odd))
    with pytest.raises(InputError, match="unknown interpolation 'nnn") as info:
        pose_gltf(odd, time=0.5, animation=g.animations[0].name)
    assert len(str(info.value)) < len(str(odd)) + 200


# ----------------------------------------------------------------------------------------------
# Command line


def test_cli_pose_writes_expected_mesh(arm_glb, tmp_path, capsys):
    import trimesh

    out = tmp_path / "out" / "posed.ply"
    assert main(["pose", str(arm_glb), "--time", "0.25", "--animation", "bend", "--out", str(out)]) == 0
    mesh = trimesh.load(str(out), process=False)
    expected = _expected(_shoulder_translation_bend(0.25), _elbow_rotation_bend(0.25))
    np.testing.assert_allclose(np.asarray(mesh.vertices), expected, atol=1e-6)
    assert np.asarray(mesh.faces).shape == (20, 3)
    assert "12 vertices" in capsys.readouterr().out
    assert sorted(p.name for p in out.parent.iterdir()) == ["posed.ply"]  # no temporary left behind


def test_cli_pose_writes_a_valid_glb(arm_glb, tmp_path):
    """A posed mesh saved as .glb (through trimesh) reads back with the same vertices and passes the
    Khronos validator.
    """
    import trimesh

    out = tmp_path / "posed.glb"
    assert main(["pose", str(arm_glb), "--time", "0.25", "--animation", "bend", "--out", str(out)]) == 0
    mesh = trimesh.load(str(out), force="mesh", process=False)
    expected = _expected(_shoulder_translation_bend(0.25), _elbow_rotation_bend(0.25))
    np.testing.assert_allclose(np.sort(np.asarray(mesh.vertices), axis=0), np.sort(expected, axis=0), atol=1e-6)
    assert_valid_gltf(out)


def test_cli_list(arm_glb, capsys):
    assert main(["pose", str(arm_glb), "--list"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 3
    assert lines[0].split("\t")[:3] == ["0", "bend", "2 s"]
    assert lines[2].split("\t")[1] == "cubic"


def test_cli_skeleton_out(arm_glb, tmp_path):
    from ncflow import skeleton

    mesh_out, skel_out = tmp_path / "m.ply", tmp_path / "s.json"
    assert main(["pose", str(arm_glb), "--time", "1", "--out", str(mesh_out), "--skeleton-out", str(skel_out)]) == 0
    assert mesh_out.exists() and skel_out.exists()
    skel = skeleton.load_skeleton(skel_out)
    r = _rodrigues(AXIS, ANGLE)
    expected = {
        "elbow": ELBOW + [0, 1, 0],
        "shoulder": SHOULDER + [0, 1, 0],
        "wrist": ELBOW + [0, 1, 0] + r @ [1.0, 0, 0],
    }
    assert sorted(skel.names) == sorted(expected)
    for j, name in enumerate(skel.names):
        np.testing.assert_allclose(skel.positions[j], expected[name], atol=1e-6)
    parent_name = {n: (skel.names[p] if p >= 0 else None) for n, p in zip(skel.names, skel.parents)}
    assert parent_name == {"shoulder": None, "elbow": "shoulder", "wrist": "elbow"}


def test_load_skeleton_and_convert_from_glb(arm_glb, tmp_path):
    from ncflow.skeleton import load_skeleton

    rig = load_gltf_skin(arm_glb)
    pos, parents, names = rig.joint_world(1.0, "bend")[:, :3, 3], rig.parents, rig.names
    skel = load_skeleton(arm_glb, time=1.0, animation="bend")
    by_name = {n: p for n, p in zip(names, pos)}
    assert set(skel.names) == set(names) and skel.parents[0] == -1
    np.testing.assert_allclose(skel.positions, [by_name[n] for n in skel.names], atol=1e-12)
    for j in range(1, skel.n_joints):  # same tree, by name
        assert names[parents[names.index(skel.names[j])]] == skel.names[skel.parents[j]]
    out = tmp_path / "arm.json"
    assert main(["skeleton", "convert", str(arm_glb), str(out), "--time", "1", "--animation", "bend"]) == 0
    data = json.loads(out.read_text())
    np.testing.assert_allclose(data["positions"], skel.positions, atol=1e-9)


def test_merge_zero_length_bones():
    # 0 root, 1 stacked on 0, 2 child of 1, 3 stacked on 2, 4 child of 3, 5 child of 1
    pos = np.array([[0, 0, 0], [0, 0, 0], [1, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]], dtype=float)
    keep, parents = merge_zero_length_bones(pos, np.array([-1, 0, 1, 2, 3, 1]))
    np.testing.assert_array_equal(keep, [0, 2, 4, 5])
    np.testing.assert_array_equal(parents, [-1, 0, 1, 0])
    keep, parents = merge_zero_length_bones(pos[[2, 4]], np.array([-1, 0]))  # nothing to merge
    np.testing.assert_array_equal(keep, [0, 1])
    np.testing.assert_array_equal(parents, [-1, 0])


@pytest.mark.parametrize(
    "make_args, message",
    [
        (lambda d, glb: ["pose", str(d / "junk.glb"), "--time", "0", "--out", str(d / "o.ply")], "not a glTF 2.0 file"),
        (
            lambda d, glb: ["pose", str(glb), "--time", "0", "--animation", "walk", "--out", str(d / "o.ply")],
            "no animation named",
        ),
        (lambda d, glb: ["pose", str(glb), "--time", "nan", "--out", str(d / "o.ply")], "finite"),
        (lambda d, glb: ["pose", str(glb), "--time", "soon", "--out", str(d / "o.ply")], "number"),
        (lambda d, glb: ["pose", str(d / "mesh.obj"), "--time", "0", "--out", str(d / "o.ply")], ".glb or .gltf"),
        (
            lambda d, glb: [
                "pose",
                str(glb),
                "--time",
                "0",
                "--out",
                str(d / "o.ply"),
                "--skeleton-out",
                str(d / "s.txt"),
            ],
            ".tgf or .json",
        ),
    ],
)
def test_cli_bad_input_exits_2_and_writes_nothing(arm_glb, tmp_path, capsys, make_args, message):
    (tmp_path / "junk.glb").write_bytes(b"\x00\x01 not gltf")
    (tmp_path / "mesh.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(make_args(tmp_path, arm_glb)) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err and err.startswith("ncflow pose: error:")
    assert sorted(p.name for p in tmp_path.iterdir()) == before
