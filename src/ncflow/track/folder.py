"""A folder written by ``ncflow track``, read back: what ``ncflow view`` shows of it.

:func:`is_track_folder` tells a track from a match result (``track.json``); :func:`track_as_result` reads the
good frames into a :class:`~ncflow.io.result.ResultFolder` the viewer plays: frame 0 the source at rest, then
the registered source on every good frame (times evenly spaced), the skeleton's joints likewise, and as
the target the last good frame (``target.ply``) with its map. Only files of the folder's own layout are
read (``source.ply``, ``target.ply``, ``registered/``, ``maps/``, the JSON files); no path written in a
file is followed.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ncflow.errors import InputError
from ncflow.io.files import confined_path, read_json_object, read_npz_arrays
from ncflow.io.gltf.skins import load_gltf_skin
from ncflow.io.meshes import load_mesh
from ncflow.io.points import load_target
from ncflow.io.result import ResultFolder
from ncflow.skeleton import Skeleton

__all__ = ["MAX_ANIMATION_BYTES", "is_track_folder", "track_animation", "track_as_result"]

MAX_ANIMATION_BYTES = 256 * 2**20
"""``animation.glb`` files above this size are not embedded in a page (a page that size would not open)."""


def is_track_folder(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a folder written by ``ncflow track`` (it holds ``track.json``)."""
    return (Path(path) / "track.json").is_file()


def _good_stems(out: Path, metrics: dict, skel: dict) -> list[str]:
    """The stems of the good frames, the same in ``metrics.json`` and ``skeleton_frames.json``, distinct, and
    names of files inside the folder (a stem is a file name the track wrote, never a path to follow).
    """
    try:
        stems = [f["stem"] for f in metrics["frames"] if f.get("status") == "ok"]
        same = [f["stem"] for f in skel["frames"]] == stems
    except (KeyError, TypeError, AttributeError):
        raise InputError("is not the metrics.json of a finished track (no frames)", out / "metrics.json") from None
    if not stems or not same or len(set(map(str, stems))) != len(stems):
        raise InputError("the track's metrics.json and skeleton_frames.json disagree on its frames", out)
    for s in stems:
        try:
            if not isinstance(s, str) or Path(s).name != s:
                raise ValueError("not a file name")
            confined_path(out / "registered", f"{s}.ply")
        except ValueError as exc:
            raise InputError(
                f"names a frame {s!r} that is not a file of the track ({exc})", out / "metrics.json"
            ) from None
    return stems


def track_as_result(path: str | os.PathLike) -> ResultFolder:
    """The registered sequence of a track folder as a :class:`~ncflow.io.result.ResultFolder` (module docstring).

    Raises:
        InputError: a folder without ``metrics.json`` (an unfinished track) or with broken files.
    """
    out = Path(path)
    metrics = read_json_object(out / "metrics.json")
    skel = read_json_object(out / "skeleton_frames.json")
    stems = _good_stems(out, metrics, skel)
    meshes = [load_mesh(out / "registered" / f"{s}.ply") for s in stems]
    rest = load_mesh(out / "source.ply")
    if any(m.n_vertices != rest.n_vertices for m in meshes):
        raise InputError("a registered frame does not have the source's vertices", out / "registered")
    frames = np.stack([rest.vertices] + [m.vertices for m in meshes])
    try:
        joints = np.stack(
            [np.asarray(skel["rest"], np.float64)] + [np.asarray(f["joints"], np.float64) for f in skel["frames"]]
        )
        parents = np.asarray(skel["parents"], np.int64)
    except (KeyError, TypeError, ValueError):
        raise InputError("joints or parents missing or not numbers", out / "skeleton_frames.json") from None
    if joints.ndim != 3 or joints.shape[1:] != (parents.size, 3):
        raise InputError("joints and parents of different sizes", out / "skeleton_frames.json")
    maps = read_npz_arrays(out / "maps" / f"{stems[-1]}.npz", ("face", "bary"))
    target = load_target(out / "target.ply")
    if target.n_vertices != maps["face"].shape[0]:
        raise InputError(f"does not fit the last frame's map ({stems[-1]})", out / "target.ply")
    return ResultFolder(
        deformed_source=meshes[-1].vertices,
        source_faces=rest.faces,
        maps={"map_face": maps["face"], "map_bary": maps["bary"]},
        frames=frames,
        frame_times=np.linspace(0.0, 1.0, frames.shape[0]),
        metrics=metrics,
        skeleton_target=Skeleton.from_arrays(joints[-1], parents),
        skeleton_frames=joints,
        joint_names=skel.get("names"),
        target_vertices=target.vertices,
        target_faces=target.faces,
    )


def track_animation(path: str | os.PathLike, result: ResultFolder) -> tuple[bytes, np.ndarray] | None:
    """(``animation.glb``'s bytes, per frame of ``result`` (:func:`track_as_result`) the clip key it shows:
    −1 for the rest pose, then 0, 1, …) for the page to play, or None when the folder has no animation.
    The GLB is read by ncflow's hardened glTF reader first: it must be a skin of the source's vertices
    with a clip of one key per good frame.

    Raises:
        InputError: an ``animation.glb`` that is not that (one line naming it), or over
            :data:`MAX_ANIMATION_BYTES`.
    """
    glb = Path(path) / "animation.glb"
    if not glb.is_file():
        return None
    if glb.stat().st_size > MAX_ANIMATION_BYTES:
        raise InputError(f"is over {MAX_ANIMATION_BYTES // 2**20} MiB: too large to embed in a page", glb)
    rig = load_gltf_skin(glb)
    n_keys = result.frames.shape[0] - 1
    if rig.positions is None or rig.positions.shape[0] != result.frames.shape[1]:
        raise InputError("is not a skin of the track's source (another vertex count)", glb)
    if not rig.channels or any(c.times.shape[0] != n_keys for c in rig.channels[0]):
        raise InputError(f"has no clip of {n_keys} keys, one per good frame", glb)
    return glb.read_bytes(), np.arange(-1, n_keys)
