"""Pairs from an animated, skinned glTF character posed at two animation times.

:func:`gltf_pair` poses one skin (:mod:`ncflow.io.gltf.skins`) at two times of a clip: both poses
move the same welded vertices, so the ground truth is the identity, or, for a retriangulated
target, the barycentric coordinates of its vertices on the bind-pose surface. The skeleton is the
skin's joints at the first time, with joints stacked on their parent merged as ``ncflow pose``
does.
"""

from __future__ import annotations

import os
from pathlib import Path

from ncflow.geometry.mesh import Mesh
from ncflow.io.gltf.skins import gltf_skeleton, load_gltf_skin
from ncflow.synthetic.motion import move_target
from ncflow.synthetic.pairs import Pair, assemble_pair, identity_ground_truth, retriangulated_target


def gltf_pair(
    path: str | os.PathLike,
    time_a: float,
    time_b: float,
    animation: str | int | None = None,
    *,
    retriangulate: bool = False,
    target_resolution: float | None = None,
    seed: int = 0,
    skin: int | None = None,
    name: str | None = None,
    target_rotation: float | tuple[float, float] | None = None,
    target_translation: float | tuple[float, float] | None = None,
) -> Pair:
    """A skinned glTF character posed at two animation times (source at ``time_a``, target at ``time_b``).

    Posing, welding of seam duplicates and animation sampling are those of :mod:`ncflow.io.gltf`.
    The skeleton is the skin's joints at ``time_a`` with joints stacked on their parent merged
    (:func:`ncflow.io.gltf.skins.gltf_skeleton`, merged in the bind pose, as ``ncflow pose`` and
    :func:`ncflow.skeleton.load_skeleton` do). Ground truth: identity (same welded vertices), or,
    with ``retriangulate``, a retriangulation of the bind-pose surface (same connectivity as every
    pose; ``target_resolution`` cells along its largest extent, default 48) mapped to the target by
    its barycentric coordinates; ``seed`` is the retriangulation grid offset's.

    ``target_rotation`` (degrees: a number is exactly that angle, a pair a uniform range) and
    ``target_translation`` (a fraction of the source's bounding-box diagonal, likewise) turn the
    target and its joints about a random axis through its vertex mean and move it
    (:func:`ncflow.synthetic.pairs.move_target`, drawn from ``seed``; ``info["target_motion"]``).
    """
    rig = load_gltf_skin(path, skin)
    a = rig.pose(float(time_a), animation)
    b = rig.pose(float(time_b), animation)
    stem = Path(path).stem
    name = name or f"{stem}_{float(time_a):g}_{float(time_b):g}"
    skeleton, keep = gltf_skeleton(rig, float(time_a), animation, name=str(path))
    target_joints = b.joint_positions[keep][skeleton.file_index]
    source = Mesh(vertices=a.vertices, faces=a.faces, name=f"{name}/source", file_index=a.file_index)
    info = {
        "file": str(path),
        "animation": a.animation,
        "time_a": a.time,
        "time_b": b.time,
        "retriangulated": bool(retriangulate),
        "merged_joints": int(len(a.names) - keep.size),
    }
    if retriangulate:
        bind = rig.pose(None)  # same welded vertices and faces as every pose
        tres = 48.0 if target_resolution is None else float(target_resolution)
        target_v, tf, gt = retriangulated_target(bind.vertices, bind.faces, b.vertices, tres, seed, f"{name}/gt")
        info["target_resolution"] = tres
    else:
        target_v, tf, gt = b.vertices, b.faces, identity_ground_truth(source, f"{name}/gt")
    target_v, target_joints, motion = move_target(
        target_v, target_joints, a.vertices, seed, target_rotation, target_translation
    )
    if motion is not None:
        info["target_motion"] = motion
    return assemble_pair(name, source, skeleton, target_v, tf, gt, dataset=stem, target_joints=target_joints, info=info)
