"""Sequences of the track development set: single-view scans (against an analytic visibility) and the MANO
hand between captured poses (against MANO's own forward kinematics, on the test's fake model)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from ncflow.errors import InputError
from ncflow.geometry.barycentric import surface_points
from ncflow.io.mano import load_mano
from ncflow.synthetic.mano import mano_finger_pose, mano_forward
from ncflow.synthetic.scans import scanned_sequence, single_view
from ncflow.synthetic.sequences import make_sequence, mano_sequence, write_sequence
from test_pairs import write_padded_fake_mano


def _two_spheres(shift: float):
    """A unit sphere at the origin and one of radius 1 at (shift, 0, −3): seen along +z, the second hides
    the part of the first within 1 of (shift, 0) in x, y."""
    a = trimesh.creation.icosphere(subdivisions=4)
    b = trimesh.creation.icosphere(subdivisions=4)
    v = np.concatenate([a.vertices, b.vertices + [shift, 0.0, -3.0]])
    f = np.concatenate([a.faces, b.faces + len(a.vertices)])
    return v, f, len(a.faces)


@pytest.mark.parametrize("shift", [1.0, 2.5])
def test_single_view_agrees_with_analytic_visibility(shift):
    v, f, n_a = _two_spheres(shift)
    seen = single_view(v, f, np.array([0.0, 0.0, 1.0]), pixels=200)
    c = v[f].mean(axis=1)
    normal = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    facing = normal[:, 2] < 0
    hidden_by_b = np.hypot(c[:, 0] - shift, c[:, 1]) < 1.0
    truth = facing & (~hidden_by_b | (np.arange(len(f)) >= n_a))
    # faces within a pixel or two of a silhouette (theirs or the occluder's rim) may go either way
    rim = (np.abs(np.hypot(c[:, 0] - shift, c[:, 1]) - 1.0) < 0.04) | (
        np.abs(normal[:, 2]) < 0.15 * np.linalg.norm(normal, axis=1)
    )
    assert np.mean(seen[~rim] == truth[~rim]) > 0.99
    assert seen[n_a:][facing[n_a:] & ~rim[n_a:]].all()  # nothing hides the near sphere's front
    assert not seen[~facing].any()


def test_scanned_sequence_keeps_exact_ground_truth_on_the_part_seen():
    seq = make_sequence("humanoid", 1, 3, resolution=40)
    scan = scanned_sequence(seq, seed=2)
    for k, (part, gt) in enumerate(zip(scan.frames, scan.ground_truth)):
        assert 0.25 < scan.info["scan"]["face_share"][k] < 0.75  # one side of a closed body
        assert part.n_vertices < seq.frames[k].n_vertices and gt.complete
        moved = surface_points(seq.source_frames[k], seq.source.faces, gt.face, gt.bary)
        np.testing.assert_allclose(moved, part.vertices, atol=1e-12)
        assert part.faces.max() < part.n_vertices
    # the camera is fixed: the same direction for every frame
    assert len(scan.info["scan"]["direction"]) == 3
    with pytest.raises(InputError, match="sees"):
        scanned_sequence(seq, seed=2, min_share=0.9)


def test_scanned_frames_write_as_point_clouds(tmp_path):
    seq = make_sequence("humanoid", 1, 2, resolution=40)
    record = write_sequence(scanned_sequence(seq, seed=0), tmp_path, frame_format="xyz")
    points = np.loadtxt(tmp_path / record["frames"][1]["mesh"])
    assert record["frames"][1]["mesh"].endswith(".xyz") and points.shape[1] == 3
    np.testing.assert_allclose(points, scanned_sequence(seq, seed=0).frames[1].vertices, atol=1e-12)


def test_mano_sequence_slerps_joints_between_captured_poses(tmp_path):
    model = load_mano(write_padded_fake_mano(tmp_path))
    seq = mano_sequence(model, [0, 1], 3, seed=0, turn=0.0, travel=0.0, retriangulate=False)
    # row 1 of the fake model turns the index MCP (joint 1) by 90° about z: halfway, by 45°
    half = mano_finger_pose(model, 1) / 2.0
    verts, joints = mano_forward(model, half)
    np.testing.assert_allclose(seq.source_frames[1], verts, atol=1e-12)
    np.testing.assert_allclose(seq.joints[1][:16], joints, atol=1e-12)
    np.testing.assert_allclose(seq.source_frames[2], mano_forward(model, mano_finger_pose(model, 1))[0], atol=1e-12)
    np.testing.assert_allclose(seq.source.vertices, seq.source_frames[0], atol=1e-15)
    for k, (frame, gt) in enumerate(zip(seq.frames, seq.ground_truth)):
        np.testing.assert_allclose(
            surface_points(seq.source_frames[k], seq.source.faces, gt.face, gt.bary), frame.vertices, atol=1e-12
        )
    # the wrist turns and the hand travels: the last frame is the pose turned about the wrist, then moved
    moved = mano_sequence(model, [0, 1], 3, seed=0, turn=40.0, travel=0.3, retriangulate=False)
    axis = Rotation.from_matrix(_best_rotation(seq.source_frames[2], moved.source_frames[2])).as_rotvec()
    assert math.degrees(np.linalg.norm(axis)) == pytest.approx(40.0, abs=1e-6)
    with pytest.raises(InputError, match="two key poses"):
        mano_sequence(model, [0], 3)


def _best_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Kabsch: the rotation R with b ≈ R (a − ā) + b̄."""
    u, _, vt = np.linalg.svd((a - a.mean(0)).T @ (b - b.mean(0)))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    return vt.T @ np.diag([1.0, 1.0, d]) @ u.T
