"""The BVH writer (ncflow.io.bvh): a hand-written file, read back by bvhio (an independent reader) against
NumPy forward kinematics, safe names, refused inputs; ``ncflow rig --bvh`` against the result's joints."""

from __future__ import annotations

import bvhio
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ncflow.errors import ResultError
from ncflow.io.bvh import bvh_names, write_bvh

BIND = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 2.0, 0.0], [1.0, 1.0, 0.0]])
PARENTS = np.array([-1, 0, 1, 1])


def forward_kinematics(bind, parents, quats, root):
    """(K, J, 3) joint positions and (K, J, 3, 3) world rotations: world_j = world_parent R_j,
    p_j = p_parent + world_parent (bind_j − bind_parent)."""
    k, nj, _ = quats.shape
    local = Rotation.from_quat(quats.reshape(-1, 4)).as_matrix().reshape(k, nj, 3, 3)
    world, pos = np.zeros((k, nj, 3, 3)), np.zeros((k, nj, 3))
    for j in range(nj):
        p = parents[j]
        if p < 0:
            world[:, j], pos[:, j] = local[:, j], root
        else:
            world[:, j] = world[:, p] @ local[:, j]
            pos[:, j] = pos[:, p] + np.einsum("kab,b->ka", world[:, p], bind[j] - bind[p])
    return pos, world


def read_back(path, frames):
    """bvhio's world joint positions per frame, by joint name (bvhio turns each joint's frame toward its
    child, so its joint rotations are not ncflow's; the positions are the file's meaning)."""
    root = bvhio.readAsHierarchy(str(path))
    out = []
    for k in range(frames):
        root.loadPose(k, recursive=True)
        out.append({j.Name: np.array(j.PositionWorld) for j, _, _ in root.layout()})
    return out


def motion_rotations(path, n_joints):
    """(K, J, 3, 3) the local rotations of the MOTION lines (channels in hierarchy order, which is joint
    order for these skeletons), as intrinsic Z-X-Y Euler degrees."""
    text = path.read_text().split("MOTION")[1].splitlines()[3:]
    values = np.array([[float(v) for v in line.split()] for line in text if line.strip()])
    euler = values[:, 3:].reshape(len(values), n_joints, 3)
    return (
        Rotation.from_euler("ZXY", euler.reshape(-1, 3), degrees=True).as_matrix().reshape(len(values), n_joints, 3, 3)
    )


def test_hand_written_file(tmp_path):
    """Two frames of a two-joint chain: the text a reader sees, line by line."""
    quats = np.zeros((2, 2, 4))
    quats[..., 3] = 1.0
    quats[1, 0] = Rotation.from_euler("z", 90, degrees=True).as_quat()
    root = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]])
    path = write_bvh(tmp_path / "a.bvh", BIND[:2], PARENTS[:2], ["hips", "head"], quats, root, 0.5)
    assert path.read_text().splitlines() == [
        "HIERARCHY",
        "ROOT hips",
        "{",
        "  OFFSET 0 0 0",
        "  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation",
        "  JOINT head",
        "  {",
        "    OFFSET 0 1 0",
        "    CHANNELS 3 Zrotation Xrotation Yrotation",
        "    End Site",
        "    {",
        "      OFFSET 0 0 0",
        "    }",
        "  }",
        "}",
        "MOTION",
        "Frames: 2",
        "Frame Time: 0.5",
        "0 0 0 0 0 0 0 0 0",
        "1 2 3 90 0 0 0 0 0",
    ]
    (_, f1) = read_back(path, 2)
    np.testing.assert_allclose(f1["head"], [0.0, 2.0, 3.0], atol=1e-6)  # (1, 2, 3) + Rz(90°) (0, 1, 0)


def test_bvhio_reads_back_the_motion(tmp_path):
    """Random rotations on a branched skeleton: bvhio's world positions are NumPy's, and the channels give
    back every local rotation (leaves' too, which no position shows)."""
    k = 4
    quats = Rotation.random(k * 4, random_state=3).as_quat().reshape(k, 4, 4)
    root = np.random.default_rng(3).normal(size=(k, 3))
    path = write_bvh(tmp_path / "b.bvh", BIND, PARENTS, ["hips", "spine top", "head", None], quats, root, 1 / 30)
    pos, _ = forward_kinematics(BIND, PARENTS, quats, root)
    names = ["hips", "spine_top", "head", "joint3"]
    for i, frame in enumerate(read_back(path, k)):
        assert list(frame) == names
        for j, name in enumerate(names):
            np.testing.assert_allclose(frame[name], pos[i, j], atol=1e-6)
    local = Rotation.from_quat(quats.reshape(-1, 4)).as_matrix().reshape(k, 4, 3, 3)
    np.testing.assert_allclose(motion_rotations(path, 4), local, atol=1e-7)


def test_names_are_safe_and_unique():
    assert bvh_names(["left arm", "left arm", "{x}", None, "", "a.b:c-d"]) == [
        "left_arm",
        "left_arm_2",
        "x",
        "joint3",
        "joint4",
        "a.b:c-d",
    ]


@pytest.mark.parametrize(
    "change, message",
    [
        ({"parents": np.array([-1, 2, 0, 1])}, "topological"),
        ({"parents": np.array([-1, 0, -1, 1])}, "topological"),
        ({"names": ["a", "b"]}, "in number"),
        ({"root_positions": np.full((2, 3), np.nan)}, "non-finite"),
        ({"frame_time": 0.0}, "frame time"),
    ],
)
def test_refused(tmp_path, change, message):
    quats = np.tile([0.0, 0.0, 0.0, 1.0], (2, 4, 1))
    args = {
        "bind_positions": BIND,
        "parents": PARENTS,
        "names": ["a", "b", "c", "d"],
        "rotations": quats,
        "root_positions": np.zeros((2, 3)),
        "frame_time": 0.1,
    } | change
    with pytest.raises(ResultError, match=message):
        write_bvh(tmp_path / "x.bvh", **args)
    assert not (tmp_path / "x.bvh").exists()


def test_a_deep_chain_is_written_in_linear_size(tmp_path):
    """A chain of 5,000 joints (deeper than Python's recursion limit): every joint written, one motion
    value per channel, and the file stays linear in size (indentation stops growing)."""
    nj = 5000
    bind = np.column_stack([np.zeros(nj), np.arange(nj, dtype=float), np.zeros(nj)])
    quats = np.tile([0.0, 0.0, 0.0, 1.0], (2, nj, 1))
    path = write_bvh(tmp_path / "chain.bvh", bind, np.arange(nj) - 1, [None] * nj, quats, np.zeros((2, 3)), 0.1)
    lines = path.read_text().splitlines()
    assert sum(line.lstrip().startswith("JOINT ") for line in lines) == nj - 1
    assert len(lines[-1].split()) == 6 + 3 * (nj - 1)
    assert path.stat().st_size < 600 * nj  # about 400 bytes a joint; indented in full, about 125 MB
