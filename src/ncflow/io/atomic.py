"""Atomic writing of one file: write a temporary sibling, then move it into place.

A reader never sees a half-written file and an earlier file at the destination stays intact until
the new one is complete: the content goes to a hidden temporary file in the same folder
(``.STEM.tmp-PID-TOKEN.SUFFIX``; the suffix is kept so that writers which choose the format from
the name, such as trimesh, matplotlib or :func:`numpy.savez`, still see it), :func:`os.replace`
moves it over the destination, and the temporary file is removed if anything fails. The temporary
file is created by the writer itself (not by :func:`tempfile.mkstemp`), so the final file gets the
usual permissions (``0o666`` minus the umask).

The whole result folder of :func:`ncflow.io.result.write_result` is made atomic the same way one
level up (a temporary folder renamed into place); its single files go through these helpers too.
"""

from __future__ import annotations

import contextlib
import os
import uuid
from collections.abc import Iterator
from pathlib import Path


def temporary_sibling(path: str | os.PathLike) -> Path:
    """A fresh hidden name beside ``path`` with the same suffix: ``DIR/.STEM.tmp-PID-TOKEN.SUFFIX``."""
    path = Path(path)
    return path.with_name(f".{path.stem}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}{path.suffix}")


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary sibling of ``path`` to write to; move it to ``path`` when the block succeeds.

    If the block raises (or the move fails) the temporary file is removed, the exception propagates
    and ``path`` is left as it was. The parent folder must exist.

    Example:
        >>> with atomic_path(out / "map.npz") as tmp:  # doctest: +SKIP
        ...     np.savez(tmp, face=face, bary=bary)
    """
    path = Path(path)
    tmp = temporary_sibling(path)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_path`)."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` to ``path`` atomically, as :meth:`pathlib.Path.write_text` would (see :func:`atomic_path`)."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)
