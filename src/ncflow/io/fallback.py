"""A finished result is never lost to a failing disk: :func:`save_result` writes the result folder and,
when that fails, keeps a copy under the system's temporary folder (:func:`save_fallback`) and names it.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from ncflow.errors import NcflowError, ResultError, first_line
from ncflow.io.atomic import remove_tree
from ncflow.io.result import MAP_KEYS, ResultFolder, write_result


def save_result(result: ResultFolder, out_dir: str | os.PathLike, *, overwrite: bool = False, shown=None) -> Path:
    """:func:`write_result`; when the disk fails, keep the result and say where it went.

    The write is atomic: on an :class:`OSError` (a full disk, a lost mount) nothing partial is left at
    ``out_dir`` and an earlier result there is intact. The result is then saved again under the
    system's temporary folder (:func:`save_fallback`) and a one-line :class:`ResultError` names that
    copy, so that the run need not be repeated.
    """
    shown = Path(out_dir) if shown is None else shown
    try:
        return write_result(out_dir, result, overwrite=overwrite)
    except OSError as exc:
        reason = exc.strerror or first_line(exc)
        copy = save_fallback(result)
        where = (
            f"the result was saved to {copy} instead (move it into place)"
            if copy is not None
            else "no fallback copy could be written either"
        )
        raise ResultError(f"cannot write the result ({reason}); nothing there was changed; {where}", shown) from None


def save_fallback(result: ResultFolder) -> Path | None:
    """Save a result under the system's temporary folder; returns the path, or None.

    First the whole output contract into ``TMP/ncflow-unsaved-XXXX/result``; if that fails too,
    the arrays alone (deformed source, faces, frames, times, maps; no pickle) into
    ``TMP/ncflow-unsaved-XXXX/result.npz``.
    """
    try:
        base = Path(tempfile.mkdtemp(prefix="ncflow-unsaved-"))
    except OSError:
        return None
    try:
        return Path(write_result(base / "result", result))
    except (OSError, NcflowError):
        remove_tree(base / "result")
    try:
        arrays = {
            "deformed_source": np.asarray(result.deformed_source),
            "source_faces": np.asarray(result.source_faces),
            "frames": np.asarray(result.frames),
            "frame_times": np.asarray(result.frame_times),
        }
        arrays.update({key: np.asarray(result.maps[key]) for key in MAP_KEYS if key in result.maps})
        np.savez(base / "result.npz", **arrays)
        return base / "result.npz"
    except Exception:  # noqa: BLE001 -- the last resort must not hide the original error
        remove_tree(base)
        return None
