"""Sequences with exact ground truth: one procedural character moving through a large motion, every frame
its own triangulation (the development data of ``ncflow track``).

A :class:`Sequence` is a source (the character's rest mesh), its skeleton and N frames. The motion goes
through three key poses — a random pose A, a pose B with large flexions (and a named articulation when
given), a random pose C — blended joint by joint (slerp of each joint's rotation, smoothstep in time),
while the whole body turns by ``turn`` degrees about a seeded axis and travels ``travel`` × its
bounding-box diagonal (a body moving through space). Each frame is made as
:func:`ncflow.synthetic.pairs.make_pair` makes a retriangulated target: a marching-cubes mesh of the
rest shape on its own seeded grid offset, projected onto the rest surface (face + barycentrics: the
ground truth), and those surface points posed. ``jump_at`` makes the motion jump at one frame (the
body turned by another 120° and moved by half its diagonal from there on): the case where a warm
start is lost.
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Sequence as Sequence_
from pathlib import Path

import numpy as np
from jaxtyping import Float
from scipy.spatial.transform import Rotation

from ncflow.errors import InputError
from ncflow.geometry.barycentric import surface_points
from ncflow.geometry.closest import _project
from ncflow.geometry.mesh import Mesh
from ncflow.geometry.rigid import rotvec_to_matrix
from ncflow.io.gltf.skins import load_gltf_skin
from ncflow.io.ground_truth import GroundTruth, save_ground_truth
from ncflow.io.meshes import save_mesh
from ncflow.skeleton import Skeleton, save_skeleton
from ncflow.skeleton.kinematics import Pose
from ncflow.synthetic.articulations import articulate
from ncflow.synthetic.characters import make_character, pose_character, random_pose
from ncflow.synthetic.gltf import gltf_pair
from ncflow.synthetic.mano import MANO_TIP_VERTICES, mano_finger_pose, mano_forward, mano_skeleton
from ncflow.synthetic.motion import _pair_seed
from ncflow.synthetic.pairs import _ground_truth, identity_ground_truth, retriangulated_target

__all__ = ["Sequence", "blend_poses", "gltf_sequence", "make_sequence", "mano_sequence", "write_sequence"]

MAX_FRAMES = 10_000


@dataclasses.dataclass(frozen=True, eq=False)
class Sequence:
    """A source and N frames of it in motion, with exact ground truth per frame.

    Attributes:
        name: a label (the frames' stems start with it).
        source: the source mesh (the character at rest).
        skeleton: its skeleton.
        frames: N target meshes, each its own triangulation.
        ground_truth: per frame, the source point (face, barycentrics) of every frame vertex.
        joints: (N, J, 3) the skeleton's joints in every frame.
        source_frames: (N, V, 3) the source's vertices moved with every frame (the exact registration).
        info: how it was made (kind, seed, key poses' large joints, turn, travel, jump).
    """

    name: str
    source: Mesh
    skeleton: Skeleton
    frames: tuple[Mesh, ...]
    ground_truth: tuple[GroundTruth, ...]
    joints: Float[np.ndarray, "N J 3"]
    source_frames: Float[np.ndarray, "N V 3"]
    info: dict

    @property
    def stems(self) -> list[str]:
        """The frames' file stems: ``NAME_000``, ``NAME_001``, ..."""
        return [f"{self.name}_{k:03d}" for k in range(len(self.frames))]


def _rotations(pose: Pose) -> Rotation:
    q = np.asarray(pose.rotations, np.float64)  # (w, x, y, z)
    return Rotation.from_quat(q[:, [1, 2, 3, 0]])


def _slerp(ra: Rotation, rb: Rotation, s: float) -> Rotation:
    """Each rotation a fraction ``s`` of the way from ``ra`` to ``rb`` along the shorter arc."""
    return ra * Rotation.from_rotvec(float(s) * (ra.inv() * rb).as_rotvec())


def blend_poses(a: Pose, b: Pose, s: float) -> Pose:
    """The pose a fraction ``s`` ∈ [0, 1] of the way from ``a`` to ``b``: each joint's rotation slerped,
    the root translation interpolated linearly.
    """
    q = _slerp(_rotations(a), _rotations(b), s).as_quat()[:, [3, 0, 1, 2]]
    t = (1.0 - s) * np.asarray(a.translation, np.float64) + s * np.asarray(b.translation, np.float64)
    return Pose(q, t)


def _smoothstep(u: float) -> float:
    return u * u * (3.0 - 2.0 * u)


def _key_pose_at(keys: list[Pose], t: float) -> Pose:
    """The motion through the key poses at time t ∈ [0, 1] (equal time per segment, eased)."""
    n = len(keys) - 1
    seg = min(int(t * n), n - 1)
    return blend_poses(keys[seg], keys[seg + 1], _smoothstep(t * n - seg))


def make_sequence(
    kind: str,
    seed: int = 0,
    n_frames: int = 12,
    *,
    resolution: float | None = None,
    target_resolution: float | None = None,
    articulation: str | None = None,
    large_angle: tuple[float, float] = (60.0, 100.0),
    turn: float = 90.0,
    travel: float = 0.5,
    jump_at: int | None = None,
    skinning: str = "dqs",
) -> Sequence:
    """A procedural character (:func:`ncflow.synthetic.characters.make_character`) through N frames.

    Args:
        kind: ``"humanoid"``, ``"hand"`` or ``"quadruped"``.
        seed: the character, the key poses, the path and the frames' grids are drawn from it.
        n_frames: N ≥ 2.
        resolution: the source's marching-cubes resolution (default: the kind's).
        target_resolution: the frames' resolution (default 0.8 × the source's).
        articulation: a named articulation of key pose B (:func:`ncflow.synthetic.articulations.articulate`).
        large_angle: range (degrees) of key pose B's large flexions.
        turn: the whole body's turn over the sequence, degrees.
        travel: the distance it travels, × its bounding-box diagonal.
        jump_at: a frame index from which the body is turned by another 120° and moved by half its
            diagonal (None: a smooth motion).
        skinning: ``"dqs"`` or ``"lbs"``.

    Returns:
        :class:`Sequence`.
    """
    if not 2 <= int(n_frames) <= MAX_FRAMES:
        raise InputError(f"a sequence needs 2 to {MAX_FRAMES} frames, got {n_frames}")
    if jump_at is not None and not 0 < int(jump_at) < int(n_frames):
        raise InputError(f"jump_at must be a frame index after the first, got {jump_at}")
    ch = make_character(kind, seed, resolution)
    name = f"{kind}_seq_{int(seed):03d}"
    pose_a, _ = random_pose(ch, _pair_seed(seed, 11), large_joint=None, global_angle=0.0, global_translation=0.0)
    pose_b, info_b = random_pose(ch, _pair_seed(seed, 12), large_angle=large_angle, global_angle=0.0)
    if articulation is not None:
        pose_b, _ = articulate(ch.spec, pose_b, _pair_seed(seed, 13), articulation=articulation)
    pose_c, info_c = random_pose(ch, _pair_seed(seed, 14), large_angle=large_angle, global_angle=0.0)
    rng = np.random.default_rng(_pair_seed(seed, 15))
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    jump_axis = rng.normal(size=3)
    jump_axis /= np.linalg.norm(jump_axis)
    diag = float(np.linalg.norm(np.ptp(ch.vertices, axis=0)))
    centre = ch.vertices.mean(axis=0)
    t_res = 0.8 * ch.resolution if target_resolution is None else float(target_resolution)
    frames, truths, joints, moved = [], [], [], []
    for k in range(int(n_frames)):
        t = k / (n_frames - 1)
        posed = pose_character(ch, _key_pose_at([pose_a, pose_b, pose_c], t), skinning=skinning)
        rot = rotvec_to_matrix(np.radians(turn * t) * axis)
        shift = travel * t * diag * direction
        if jump_at is not None and k >= jump_at:
            rot = rotvec_to_matrix(np.radians(120.0) * jump_axis) @ rot
            shift = shift + 0.5 * diag * jump_axis[[1, 2, 0]]
        offset = np.random.default_rng(_pair_seed(seed, 100 + k)).uniform(0.0, 1.0, size=3)
        tv, tf = ch.remesh(t_res, offset=offset)
        _, face, bary = _project(tv, ch.vertices, ch.faces)
        points = surface_points(posed.vertices, ch.faces, face, bary)
        stem = f"{name}_{k:03d}"
        frames.append(
            Mesh((points - centre) @ rot.T + centre + shift, np.asarray(tf, np.int64), stem, np.arange(len(points)))
        )
        truths.append(_ground_truth(face, bary, stem))
        joints.append((posed.joints - centre) @ rot.T + centre + shift)
        moved.append((posed.vertices - centre) @ rot.T + centre + shift)
    source = Mesh(ch.vertices, ch.faces, f"{name}/source", np.arange(ch.vertices.shape[0]))
    info = {
        "kind": kind,
        "seed": int(seed),
        "n_frames": int(n_frames),
        "articulation": articulation,
        "large_joints": [info_b["large_joint"], info_c["large_joint"]],
        "turn_degrees": float(turn),
        "travel_diagonals": float(travel),
        "jump_at": None if jump_at is None else int(jump_at),
        "resolution": ch.resolution,
        "target_resolution": t_res,
        "n_source": int(ch.vertices.shape[0]),
        "n_target": [int(m.n_vertices) for m in frames],
    }
    return Sequence(name, source, ch.skeleton, tuple(frames), tuple(truths), np.stack(joints), np.stack(moved), info)


def mano_sequence(
    model,
    poses: Sequence_[int | str],
    n_frames: int = 12,
    *,
    seed: int = 0,
    turn: float = 60.0,
    travel: float = 0.3,
    target_resolution: float = 36.0,
    retriangulate: bool = True,
    name: str | None = None,
) -> Sequence:
    """The MANO hand moving through captured key poses (rows of ``hands_coeffs``, or ``"flat"`` / ``"fist"``),
    every frame retriangulated on its own grid (:func:`ncflow.synthetic.pairs.retriangulated_target`, seed
    ``seed + k``) with exact ground truth.

    Each finger joint's rotation is slerped from key to key (smoothstep in time, equal time per segment,
    MANO's pose blend shapes applied at every frame); the wrist turns by ``turn`` degrees about a seeded
    axis and the hand travels ``travel`` × its bounding-box diagonal. The source is the first key pose
    with MANO's skeleton and tip bones (as :func:`ncflow.synthetic.mano.mano_pair` makes it).

    Args:
        model: a :class:`ncflow.io.mano.ManoModel` (the user's MANO file, loaded).
        poses: two or more key poses (:func:`ncflow.synthetic.mano.mano_finger_pose`).
        n_frames: N ≥ 2.
        seed: the turn's axis, the path's direction and the frames' grids are drawn from it.
        turn: the wrist's turn over the sequence, degrees.
        travel: the distance travelled, × the bounding-box diagonal.
        target_resolution: cells of each frame's retriangulation grid along the hand's largest extent.
        retriangulate: False: every frame is the posed MANO mesh itself (identity ground truth).
        name: the frames' stem prefix (default ``mano_seq_<first>_<last>``).
    """
    if not 2 <= int(n_frames) <= MAX_FRAMES:
        raise InputError(f"a sequence needs 2 to {MAX_FRAMES} frames, got {n_frames}")
    if len(poses) < 2:
        raise InputError(f"a MANO sequence needs at least two key poses, got {len(poses)}")
    keys = [Rotation.from_rotvec(mano_finger_pose(model, p).reshape(-1, 3)) for p in poses]
    name = name or f"mano_seq_{poses[0]}_{poses[-1]}"
    rng = np.random.default_rng(_pair_seed(seed, 21))
    axis, direction = rng.normal(size=3), rng.normal(size=3)
    axis, direction = axis / np.linalg.norm(axis), direction / np.linalg.norm(direction)
    v0, j0 = mano_forward(model, keys[0].as_rotvec().reshape(-1))
    skeleton = mano_skeleton(model, j0, v0, MANO_TIP_VERTICES, name)
    rest_v, _ = mano_forward(model, np.zeros(3 * (model.n_joints - 1)))
    diag = float(np.linalg.norm(np.ptp(v0, axis=0)))
    n_seg = len(keys) - 1
    frames, truths, joints, moved = [], [], [], []
    for k in range(int(n_frames)):
        t = k / (n_frames - 1)
        seg = min(int(t * n_seg), n_seg - 1)
        theta = _slerp(keys[seg], keys[seg + 1], _smoothstep(t * n_seg - seg)).as_rotvec()
        verts, js = mano_forward(
            model, theta.reshape(-1), np.radians(turn * t) * axis, translation=travel * t * diag * direction
        )
        stem = f"{name}_{k:03d}"
        if retriangulate:
            tv, tf, gt = retriangulated_target(rest_v, model.faces, verts, target_resolution, seed + k, stem)
        else:
            tv, tf = verts, model.faces
            gt = identity_ground_truth(Mesh(verts, model.faces, stem), stem)
        frames.append(Mesh(tv, np.asarray(tf, np.int64), stem, np.arange(tv.shape[0])))
        truths.append(gt)
        joints.append(np.concatenate([js, verts[list(MANO_TIP_VERTICES)]])[skeleton.file_index])
        moved.append(verts)
    source = Mesh(v0, model.faces, f"{name}/source", np.arange(v0.shape[0]))
    info = {
        "kind": "mano",
        "model": model.name,
        "poses": [p if isinstance(p, str) else int(p) for p in poses],
        "seed": int(seed),
        "n_frames": int(n_frames),
        "turn_degrees": float(turn),
        "travel_diagonals": float(travel),
        "target_resolution": float(target_resolution) if retriangulate else None,
        "n_source": int(v0.shape[0]),
        "n_target": [int(m.n_vertices) for m in frames],
    }
    return Sequence(name, source, skeleton, tuple(frames), tuple(truths), np.stack(joints), np.stack(moved), info)


def gltf_sequence(
    path: str | os.PathLike,
    times: Sequence_[float],
    animation: str | int | None = None,
    *,
    source_time: float | None = None,
    target_resolution: float | None = None,
    seed: int = 0,
    name: str | None = None,
) -> Sequence:
    """An animated glTF character at the given clip ``times``, each frame retriangulated on its own grid
    offset (:func:`ncflow.synthetic.gltf.gltf_pair` with ``retriangulate``, seed ``seed + k``); the
    source is the character at ``source_time`` (default the first time) with its skin's skeleton.
    """
    times = [float(t) for t in times]
    if not 2 <= len(times) <= MAX_FRAMES:
        raise InputError(f"a sequence needs 2 to {MAX_FRAMES} frames, got {len(times)}")
    t0 = times[0] if source_time is None else float(source_time)
    name = name or f"{Path(path).stem.lower()}_seq"
    frames, truths, joints, pair = [], [], [], None
    rig = load_gltf_skin(path)
    moved = np.stack([rig.pose(t, animation).vertices for t in times])
    for k, t in enumerate(times):
        pair = gltf_pair(path, t0, t, animation, retriangulate=True, target_resolution=target_resolution, seed=seed + k)
        stem = f"{name}_{k:03d}"
        frames.append(Mesh(pair.target.vertices, pair.target.faces, stem, pair.target.file_index))
        truths.append(_ground_truth(pair.ground_truth.face, pair.ground_truth.bary, stem))
        joints.append(pair.target_joints)
    source = dataclasses.replace(pair.source, name=f"{name}/source")
    info = {
        "file": str(path),
        "animation": pair.info["animation"],
        "source_time": t0,
        "times": times,
        "n_frames": len(times),
        "n_source": int(source.n_vertices),
        "n_target": [int(m.n_vertices) for m in frames],
    }
    return Sequence(name, source, pair.skeleton, tuple(frames), tuple(truths), np.stack(joints), moved, info)


def write_sequence(
    seq: Sequence, directory: str | os.PathLike, fmt: str = "ply", frame_format: str | None = None
) -> dict:
    """Write a sequence: ``source.FMT``, ``skeleton.tgf``, ``frames/STEM.FRAME_FORMAT`` (default ``fmt``;
    ``"xyz"``: the frames' vertices alone, as a scanner's point clouds), ``gt/STEM.npz`` (face, bary,
    target_index), ``joints.npy`` (N, J, 3), ``source_frames.npy`` (N, V, 3) and ``sequence.json`` (its
    info and the files). Returns that record (file names relative to ``directory``).
    """
    out = Path(directory)
    frame_format = frame_format or fmt
    (out / "frames").mkdir(parents=True, exist_ok=True)
    (out / "gt").mkdir(exist_ok=True)
    save_mesh(out / f"source.{fmt}", seq.source.vertices, seq.source.faces, precision="float64")
    save_skeleton(out / "skeleton.tgf", seq.skeleton)
    frames = []
    for stem, mesh, gt in zip(seq.stems, seq.frames, seq.ground_truth):
        if frame_format == "xyz":
            np.savetxt(out / "frames" / f"{stem}.xyz", mesh.vertices, fmt="%.17g")
        else:
            save_mesh(out / "frames" / f"{stem}.{frame_format}", mesh.vertices, mesh.faces, precision="float64")
        save_ground_truth(out / "gt" / f"{stem}.npz", gt)
        frames.append({"stem": stem, "mesh": f"frames/{stem}.{frame_format}", "gt": f"gt/{stem}.npz"})
    np.save(out / "joints.npy", seq.joints)
    np.save(out / "source_frames.npy", seq.source_frames)
    record = {
        "name": seq.name,
        "source": f"source.{fmt}",
        "skeleton": "skeleton.tgf",
        "frames": frames,
        "joints": "joints.npy",
        "source_frames": "source_frames.npy",
        "info": seq.info,
    }
    (out / "sequence.json").write_text(json.dumps(record, indent=1))
    return record
