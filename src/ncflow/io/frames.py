"""The frames of a result: one PLY per frame (:func:`write_frames`) and the skeleton's joint positions per
frame as JSON (:func:`write_skeleton_frames_json`, :func:`read_skeleton_frames_json`), each file written
atomically.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError, ResultError
from ncflow.io.arrays import as_faces, as_frames, as_times
from ncflow.io.atomic import atomic_write_text
from ncflow.io.files import read_json_object
from ncflow.io.meshes import save_mesh


def write_frames(
    directory: str | os.PathLike, frames: Float[np.ndarray, "K V 3"], faces: Int[np.ndarray, "F 3"]
) -> list[Path]:
    """Write ``frame_0000.ply`` … ``frame_{K-1:04d}.ply`` (all with ``faces``) into ``directory``.

    Returns:
        The K paths written.

    Raises:
        ResultError: bad shapes or non-finite coordinates (checked before anything is written).
    """
    frames = as_frames(frames)
    faces = as_faces(faces, frames.shape[1])
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for k, v in enumerate(frames):
        path = directory / f"frame_{k:04d}.ply"
        save_mesh(path, v, faces)
        paths.append(path)
    return paths


def write_skeleton_frames_json(
    path: str | os.PathLike,
    positions: Float[np.ndarray, "K J 3"],
    parents: Int[np.ndarray, " J"],
    names: list[str] | tuple[str, ...] | None,
    times: Float[np.ndarray, " K"],
) -> Path:
    """Write ``{"names", "parents", "times", "positions"}``: joint positions (K, J, 3) per frame.

    ``parents`` are 0-based indices into the joint list (−1 for the root), in the same joint
    order as the positions (for :func:`write_result`: the skeleton's internal topological order,
    which is also the node order of ``skeleton_target.tgf``). ``names`` may be None (written as
    null).
    """
    pos = as_frames(positions, "skeleton frames")
    k, j, _ = pos.shape
    par = np.asarray(parents).reshape(-1)
    if par.shape != (j,) or not np.issubdtype(par.dtype, np.integer):
        raise ResultError(f"expected {j} integer parents (one per joint), got shape {par.shape}")
    if par.min() < -1 or par.max() >= j:
        raise ResultError(f"parents must be in [-1, {j}), got [{int(par.min())}, {int(par.max())}]")
    if names is not None and len(names) != j:
        raise ResultError(f"expected {j} joint names, got {len(names)}")
    t = as_times(times, k)
    rows = ",\n  ".join(json.dumps([[float(x) for x in p] for p in frame]) for frame in pos)
    parts = [
        f' "names": {json.dumps(None if names is None else [str(s) for s in names])}',
        f' "parents": {json.dumps([int(p) for p in par])}',
        f' "times": {json.dumps([float(x) for x in t])}',
        f' "positions": [\n  {rows}\n ]',
    ]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, "{\n" + ",\n".join(parts) + "\n}\n")
    return path


def read_skeleton_frames_json(path: str | os.PathLike) -> dict[str, Any]:
    """Read :func:`write_skeleton_frames_json` output: positions (K, J, 3), parents (J,), names, times (K,).

    Raises:
        InputError: one line naming the file and the problem.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("missing result file", path)
    data = read_json_object(path)
    for key in ("parents", "times", "positions"):
        if key not in data:
            raise InputError(f"missing key {key!r}", path)
    try:
        pos = np.asarray(data["positions"], dtype=np.float64)
        times = np.asarray(data["times"], dtype=np.float64)
        parents = np.asarray(data["parents"])
    except (TypeError, ValueError):
        raise InputError("'positions', 'times' and 'parents' must be numeric lists", path) from None
    if pos.ndim != 3 or pos.shape[2] != 3:
        raise InputError(f"'positions' must be (K, J, 3), got shape {pos.shape}", path)
    k, j, _ = pos.shape
    if times.shape != (k,):
        raise InputError(f"'times' has shape {times.shape}, expected ({k},)", path)
    if parents.shape != (j,) or (j and not np.issubdtype(parents.dtype, np.integer)):
        raise InputError(f"'parents' must be {j} integers, got shape {parents.shape}", path)
    if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(times))):
        raise InputError("non-finite joint positions or times", path)
    names = data.get("names")
    if names is not None and (not isinstance(names, list) or len(names) != j):
        raise InputError(f"'names' must be null or a list of {j} strings", path)
    return {"positions": pos, "parents": parents.astype(np.int64), "names": names, "times": times}
