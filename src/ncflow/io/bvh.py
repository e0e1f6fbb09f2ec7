"""Skeleton motion as a Biovision Hierarchy file (``.bvh``): the writer.

Layout written (the common subset every BVH reader takes: Blender, MotionBuilder, three.js, bvhio):

* ``HIERARCHY``: one ``ROOT`` (joint 0) with ``CHANNELS 6 Xposition Yposition Zposition Zrotation
  Xrotation Yrotation`` and ``OFFSET 0 0 0`` (its position channels are its absolute position), every
  other joint a ``JOINT`` with ``CHANNELS 3 Zrotation Xrotation Yrotation`` and ``OFFSET`` = its bind
  position minus its parent's; a joint without children closes with ``End Site { OFFSET 0 0 0 }``
  (a zero-length tip: every joint of the skeleton, tips included, stays a joint with its name).
* The bind pose has every joint frame aligned with the world axes (as ``ncflow rig``'s GLB), so a joint
  at rest has zero rotation channels and the hierarchy alone reproduces the bind skeleton.
* ``MOTION``: one line per frame; rotations are the joint's local rotation as intrinsic Z-X-Y Euler
  angles in degrees (R = R_z R_x R_y, :meth:`scipy.spatial.transform.Rotation.as_euler` with "ZXY").

Forward kinematics of a frame: world_j = world_parent · R_j and p_j = p_parent + world_parent · OFFSET_j,
the root at its position channels. Names are made BVH-safe (no whitespace or braces) and unique.
Hand-written: BVH is a page of text; bvhio (the tests' independent reader) also writes it, but from its own
PyGLM joint objects, two more dependencies for what these hundred lines do.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
from jaxtyping import Float, Int
from scipy.spatial.transform import Rotation

from ncflow.errors import ResultError
from ncflow.io.gltf.document import unique_names

ROTATION_ORDER = "ZXY"
"""The Euler order of every joint's rotation channels (intrinsic; the channels list it in this order)."""


MAX_INDENT = 32
"""Indentation stops growing at this depth (whitespace means nothing to a reader; a 10,000-joint chain
indented in full would be quadratic in size)."""


def bvh_names(names: list[str | None] | tuple[str | None, ...]) -> list[str]:
    """Joint names a BVH reader takes: runs of whitespace, braces and other symbols become ``_``; missing
    names become ``joint{j}``; duplicates get suffixes (``name_2``).
    """
    cleaned = [None if not n else re.sub(r"[^0-9A-Za-z_.:\-]+", "_", str(n)).strip("_") or None for n in names]
    return unique_names(cleaned)


def write_bvh(
    path: str | os.PathLike,
    bind_positions: Float[np.ndarray, "J 3"],
    parents: Int[np.ndarray, " J"],
    names: list[str | None] | tuple[str | None, ...],
    rotations: Float[np.ndarray, "K J 4"],
    root_positions: Float[np.ndarray, "K 3"],
    frame_time: float,
) -> Path:
    """Write a skeleton's motion as BVH (layout in the module docstring).

    Args:
        path: output ``.bvh`` (written as given; callers wrap it in :func:`ncflow.io.atomic.atomic_path`).
        bind_positions: (J, 3) joint positions of the bind pose, topological order (root first).
        parents: (J,) parent of each joint, −1 for the root only, ``parents[j] < j``.
        names: J joint names (made BVH-safe and unique, :func:`bvh_names`).
        rotations: (K, J, 4) local joint rotations (x, y, z, w) relative to the bind pose, per frame.
        root_positions: (K, 3) the root joint's position per frame.
        frame_time: seconds between frames (> 0).

    Returns:
        The path written.

    Raises:
        ResultError: inconsistent shapes, a parent after its child, several roots, non-finite values.
    """
    bind = np.asarray(bind_positions, np.float64)
    par = np.asarray(parents, np.int64)
    quats = np.asarray(rotations, np.float64)
    root = np.asarray(root_positions, np.float64)
    nj = bind.shape[0]
    if bind.shape != (nj, 3) or par.shape != (nj,) or len(names) != nj or nj == 0:
        raise ResultError("BVH: the joints, parents and names disagree in number", path)
    if par[0] != -1 or np.any(par[1:] < 0) or np.any(par[1:] >= np.arange(1, nj)):
        raise ResultError("BVH: joints must be in topological order with one root first", path)
    k = quats.shape[0]
    if quats.shape != (k, nj, 4) or root.shape != (k, 3) or k == 0:
        raise ResultError("BVH: rotations (K, J, 4) and root positions (K, 3) must have one row per frame", path)
    if not (np.all(np.isfinite(bind)) and np.all(np.isfinite(quats)) and np.all(np.isfinite(root))):
        raise ResultError("BVH: non-finite joint positions or rotations", path)
    if not (np.isfinite(frame_time) and frame_time > 0):
        raise ResultError(f"BVH: the frame time must be a positive number of seconds, got {frame_time}", path)
    safe = bvh_names(list(names))
    children: list[list[int]] = [[] for _ in range(nj)]
    for j in range(1, nj):
        children[int(par[j])].append(j)

    lines = ["HIERARCHY"]
    rot = " ".join(f"{axis}rotation" for axis in ROTATION_ORDER)
    order: list[int] = []  # joints as the hierarchy lists them: their channels' order in a motion line
    depth = np.zeros(nj, np.int64)
    stack: list[tuple[int, bool]] = [(0, False)]  # (joint, close it): a stack, so any depth is written
    while stack:
        j, close = stack.pop()
        pad = "  " * min(int(depth[j]), MAX_INDENT)
        if close:
            if not children[j]:
                lines.extend([f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET 0 0 0", f"{pad}  }}"])
            lines.append(f"{pad}}}")
            continue
        order.append(j)
        offset = np.zeros(3) if j == 0 else bind[j] - bind[par[j]]
        lines += [f"{pad}{'ROOT' if j == 0 else 'JOINT'} {safe[j]}", f"{pad}{{", f"{pad}  OFFSET {_numbers(offset)}"]
        lines.append(f"{pad}  CHANNELS 6 Xposition Yposition Zposition {rot}" if j == 0 else f"{pad}  CHANNELS 3 {rot}")
        depth[children[j]] = depth[j] + 1
        stack.append((j, True))
        stack.extend((c, False) for c in reversed(children[j]))

    euler = Rotation.from_quat(quats.reshape(-1, 4)).as_euler(ROTATION_ORDER, degrees=True).reshape(k, nj, 3)
    lines += ["MOTION", f"Frames: {k}", f"Frame Time: {frame_time:.9g}"]
    for i in range(k):
        values = [root[i], *(euler[i, j] for j in order)]
        lines.append(" ".join(_numbers(v) for v in values))
    out = Path(path)
    out.write_text("\n".join(lines) + "\n", encoding="ascii")
    return out


def _numbers(values) -> str:
    return " ".join(f"{float(v) + 0.0:.9g}" for v in np.asarray(values).ravel())  # + 0.0: no "-0"
