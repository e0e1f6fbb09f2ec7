"""The frames of a sequence: a folder, a glob pattern or a list of files, in natural sort order.

``frame_files("capture/")`` lists the mesh and point-cloud files of a folder (:data:`FOLDER_SUFFIXES`:
:data:`~ncflow.io.meshes.MESH_SUFFIXES`, ``.xyz`` and ``.npy``, not ``.txt``, which a folder's notes
use too; hidden files skipped) in natural order (``f2`` before ``f10``); a pattern with ``*``, ``?`` or ``[``
is expanded the same way (``.txt`` clouds included); a list is taken in the order given. Each frame's
outputs are named after its file's stem, so two frames with one stem are refused.
"""

from __future__ import annotations

import glob
import os
import re
from collections.abc import Sequence
from pathlib import Path

from ncflow.errors import InputError
from ncflow.io.meshes import MESH_SUFFIXES
from ncflow.io.points import POINT_SUFFIXES

__all__ = ["FOLDER_SUFFIXES", "MAX_FRAMES", "frame_files", "natural_key"]

FOLDER_SUFFIXES = MESH_SUFFIXES + (".xyz", ".npy")
"""The frame files a folder's listing takes."""

MAX_FRAMES = 100_000
"""The most frames one run takes."""

_DIGITS = re.compile(r"(\d+)")
_STEM = re.compile(r"^[^.\x00-\x1f\x7f][^\x00-\x1f\x7f]{0,199}$")


def natural_key(name: str) -> tuple:
    """Sort key of a file name with its digit runs compared as numbers (``f2`` < ``f10``)."""
    return tuple((0, int(p), p) if p.isdigit() else (1, 0, p.lower()) for p in _DIGITS.split(name) if p)


def _is_mesh(path: Path, suffixes: tuple[str, ...] = FOLDER_SUFFIXES) -> bool:
    return path.suffix.lower() in suffixes and not path.name.startswith(".")


def frame_files(frames: str | os.PathLike | Sequence[str | os.PathLike]) -> list[Path]:
    """The frame files of a sequence, in order (module docstring).

    Raises:
        InputError: no frame found, a folder entry that is missing or not a file, more than
            :data:`MAX_FRAMES` frames, a stem that is not a plain file name or occurs twice.
    """
    if isinstance(frames, (str, os.PathLike)):
        given = str(frames)
        if Path(given).is_dir():
            with os.scandir(given) as it:
                found = [Path(e.path) for e in it if e.is_file() and _is_mesh(Path(e.name))]
            what = f"the folder has no mesh or point-cloud files ({', '.join(FOLDER_SUFFIXES)})"
        elif any(c in given for c in "*?["):
            found = [
                Path(p)
                for p in glob.glob(given)
                if Path(p).is_file() and _is_mesh(Path(p), MESH_SUFFIXES + POINT_SUFFIXES)
            ]
            what = "the pattern matches no mesh or point-cloud file"
        else:
            found = [Path(given)]
            what = ""
        paths = sorted(found, key=lambda p: natural_key(p.name)) if what else found
        if not paths:
            raise InputError(what, given)
    else:
        paths = [Path(p) for p in frames]
        if not paths:
            raise InputError("no frames given")
    if len(paths) > MAX_FRAMES:
        raise InputError(f"{len(paths)} frames: at most {MAX_FRAMES} in one run", paths[0].parent)
    seen: dict[str, Path] = {}
    for p in paths:
        if not p.is_file():
            raise InputError("no such frame file", p)
        if not _STEM.match(p.stem):
            raise InputError(
                "a frame's outputs are named after its stem: it must not start with a dot, hold "
                "control characters or exceed 200 characters",
                p,
            )
        if p.stem in seen:
            raise InputError(f"two frames named {p.stem!r} ({seen[p.stem]} and this one): stems must differ", p)
        seen[p.stem] = p
    return paths
