"""The sequence-wide outputs of ``ncflow track``, written from the good frames' records once every frame is
done: ``skeleton_frames.json``, ``animation.glb``, ``animation.bvh`` and ``metrics.json``
(:mod:`ncflow.track.animation` for the motion; each file written atomically).

``skeleton_frames.json``: ``names``, ``parents``, ``bones`` ((B, 2) parent and child joint of each
bone), ``rest`` (the source skeleton's joints), ``fps`` and per good frame its ``stem``, ``index``,
``time`` (index / fps), ``joints`` (J × 3, user coordinates) and ``bone_transforms`` (B × 4 × 4: the
rigid motion of each bone from the rest pose to the frame, the transform of its parent joint).
``animation.bvh`` has one frame per input frame; a failed frame holds the pose before it. ``source.ply``
(the source at rest) and ``target.ply`` (the last good frame) let ``ncflow view`` show the folder alone.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ncflow import __version__
from ncflow.config import Config, config_to_dict
from ncflow.flow.islands import surface_skin
from ncflow.geometry.mesh import Mesh
from ncflow.geometry.rigid import dense_weights, linear_blend_skinning
from ncflow.io.atomic import atomic_path, atomic_write_text
from ncflow.io.bvh import write_bvh
from ncflow.io.gltf.document import unique_names
from ncflow.io.gltf.rig_writer import write_rig_glb
from ncflow.io.meshes import load_mesh, save_mesh
from ncflow.io.points import save_target
from ncflow.skeleton import Skeleton
from ncflow.track.animation import SequenceMotion, morph_corrections, sequence_motion

__all__ = ["key_errors", "write_sequence_outputs"]


def key_errors(
    source_vertices: np.ndarray, motion: SequenceMotion, morphs: np.ndarray, registered: np.ndarray
) -> np.ndarray:
    """(K,) largest distance, per key, between the skinned and corrected source (float32, as stored in
    the GLB) and the registered shape.
    """
    w = dense_weights(motion.joints, motion.weights.astype(np.float32), motion.transforms.shape[1])
    v = np.asarray(source_vertices, np.float32).astype(np.float64)
    out = np.empty(morphs.shape[0])
    for k in range(morphs.shape[0]):
        moved = linear_blend_skinning(v + morphs[k].astype(np.float32), w, motion.transforms[k])
        out[k] = float(np.max(np.linalg.norm(moved - registered[k], axis=1)))
    return out


def _skeleton_json(skel: Skeleton, names: list[str], ok: list[dict], motion: SequenceMotion, fps: float) -> dict:
    bones = np.asarray(skel.bones)
    frames = []
    for k, rec in enumerate(ok):
        frames.append(
            {
                "stem": rec["stem"],
                "index": rec["index"],
                "time": rec["index"] / fps,
                "joints": rec["joints"],
                "bone_transforms": motion.transforms[k][bones[:, 0]].tolist(),
            }
        )
    return {
        "format": "ncflow-track-skeleton/1",
        "names": names,
        "parents": np.asarray(skel.parents).tolist(),
        "bones": bones.tolist(),
        "rest": np.asarray(skel.positions).tolist(),
        "fps": fps,
        "frames": frames,
    }


def _held(indices: list[int], n: int) -> np.ndarray:
    """(n,) for every frame index the position in ``indices`` of the last good frame at or before it
    (the first good frame before any).
    """
    pos = np.searchsorted(np.asarray(indices), np.arange(n), side="right") - 1
    return np.maximum(pos, 0)


def write_sequence_outputs(
    out: Path,
    source: Mesh,
    skel: Skeleton,
    records: list[dict],
    config: Config,
    options: dict,
    seconds: float,
    n_resumed: int,
    last_target: Mesh,
) -> dict:
    """Write the sequence-wide files of a track from its frame ``records`` (in frame order); return the
    metrics written.
    """
    t0 = time.perf_counter()
    fps = float(options["fps"])
    for i, rec in enumerate(records):
        rec["index"] = i
    ok = [r for r in records if r["status"] == "ok"]
    registered = np.stack([load_mesh(out / "registered" / f"{r['stem']}.ply").vertices for r in ok])
    joints = np.asarray([r["joints"] for r in ok], np.float64)
    names = unique_names(list(skel.names or [None] * skel.n_joints))
    seen = ok[0].get("weight_mode") == "surface"  # the frames' bone weights saw the skin
    normals = surface_skin(source.vertices, source.faces, skel.positions, skel.parents) if seen else None
    motion = sequence_motion(
        source.vertices, skel.positions, skel.parents, registered, joints, config.flow.skinning_width, normals
    )
    morphs = morph_corrections(source.vertices, motion, registered)
    key_times = np.asarray([r["index"] for r in ok], np.float64) / fps
    with atomic_path(out / "animation.glb") as tmp:
        write_rig_glb(
            tmp,
            vertices=source.vertices,
            faces=source.faces,
            joint_positions=skel.positions,
            parents=skel.parents,
            names=names,
            joints=motion.joints,
            weights=motion.weights,
            key_times=key_times,
            rotations=motion.rotations,
            root_translations=motion.root_positions,
            morph_targets=morphs,
            name="ncflow track",
        )
    held = _held([r["index"] for r in ok], len(records))
    with atomic_path(out / "animation.bvh") as tmp:
        write_bvh(
            tmp, skel.positions, skel.parents, names, motion.rotations[held], motion.root_positions[held], 1 / fps
        )
    atomic_write_text(out / "skeleton_frames.json", json.dumps(_skeleton_json(skel, names, ok, motion, fps)))
    with atomic_path(out / "source.ply") as tmp:
        save_mesh(tmp, source.vertices, source.faces)
    with atomic_path(out / "target.ply") as tmp:
        save_target(tmp, last_target.vertices, last_target.faces)
    diag = float(np.linalg.norm(np.ptp(source.vertices, axis=0)))
    errors = key_errors(source.vertices, motion, morphs, registered)
    metrics = _metrics(source, skel, records, ok, config, options, errors / diag, seconds, n_resumed)
    metrics["timings"]["outputs"] = time.perf_counter() - t0
    atomic_write_text(out / "metrics.json", json.dumps(metrics, indent=1))
    return metrics


def _metrics(source, skel, records, ok, config, options, key_error, seconds, n_resumed) -> dict:
    warm = [r for r in ok if r.get("warm")]
    return {
        "format": "ncflow-track/1",
        "ncflow_version": __version__,
        "source": source.name,
        "skeleton": skel.name,
        "n_frames": len(records),
        "n_ok": len(ok),
        "n_failed": len(records) - len(ok),
        "n_warm": len(warm),
        "n_fell_back": sum(bool(r.get("fell_back")) for r in ok),
        "n_resumed": n_resumed,
        "max_violation_ratio": max(r["max_violation_ratio"] for r in ok),
        "frames": [
            {
                k: r.get(k)
                for k in (
                    "stem",
                    "index",
                    "status",
                    "error",
                    "warm",
                    "fell_back",
                    "fell_back_reason",
                    "kept",
                    "seconds",
                    "data",
                    "data_ratio",
                    "fit_ratio",
                    "fit",
                    "max_violation_ratio",
                    "all_bones_within_tolerance",
                )
                if k in r
            }
            for r in records
        ],
        "animation": {
            "n_keys": len(ok),
            "fps": options["fps"],
            "max_key_error": float(np.max(key_error)),
            "units": "largest distance between the GLB's skinned, corrected mesh at a key and the registered shape, "
            "× the source's bounding-box diagonal",
        },
        "options": options,
        "timings": {
            "total": seconds,
            "first_frame": ok[0]["seconds"] if not ok[0].get("warm") else None,
            "mean_warm_frame": float(np.mean([r["seconds"] for r in warm])) if warm else None,
        },
        "config": config_to_dict(config),
    }
