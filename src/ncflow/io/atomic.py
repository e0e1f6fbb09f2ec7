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
Temporary folders are made by :func:`staging_dir` with :func:`os.mkdir` (not
:func:`tempfile.mkdtemp`, whose 0700 would become the final folder's mode), so a finished folder
has the usual ``0o777`` minus the umask.

Before any work, a command checks where it will write with :func:`check_output_dir` (a folder)
or :func:`check_output_file` (one file): the path is resolved (symbolic links followed), must not
be an existing file (or a folder, for a file), lie under a file, be the current folder or one of
its ancestors, and its nearest existing folder must be writable with roughly enough free space.
Each problem is one :class:`~ncflow.errors.InputError` line naming the path.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import uuid
from collections.abc import Iterator
from pathlib import Path

from ncflow.errors import InputError


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


def computed_once(path: str | os.PathLike, compute, read, write):
    """``compute()``, kept in the file ``path`` (a cache entry ncflow owns): read back with
    ``read(path)`` when the entry exists and reads (a broken one is computed again), else computed
    and written atomically with ``write(temporary_path, value)``. Processes computing one entry at
    once take a lock (``path`` with the suffix ``.lock``), so one computes and the others read its
    entry. An unwritable folder only means computing without it.

    Returns:
        (value, the entry's path or None where none was written or read, whether it was read back).
    """
    import fcntl

    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        lock = open(path.with_suffix(".lock"), "a")
    except OSError:
        return compute(), None, False
    with lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if path.exists():
            try:
                return read(path), path, True
            except Exception:  # a broken entry is computed again
                pass
        value = compute()
        try:
            with atomic_path(path) as tmp:
                write(tmp, value)
        except OSError:
            return value, None, False
        return value, path, False


# ----------------------------------------------------------------------------------------------
# Where a command writes


def staging_dir(final: str | os.PathLike) -> Path:
    """Create and return a fresh hidden folder beside ``final``: ``DIR/.NAME.tmp-PID-TOKEN``.

    Made with :func:`os.mkdir`, so it (and the folder it becomes when renamed to ``final``) has
    the usual mode ``0o777`` minus the umask. The parent must exist.
    """
    final = Path(final)
    tmp = final.with_name(f".{final.name}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}")
    os.mkdir(tmp)
    return tmp


def move_into_place(tmp: str | os.PathLike, out_dir: str | os.PathLike, owned) -> None:
    """Move the finished folder ``tmp`` (made by :func:`staging_dir`) to ``out_dir``.

    An absent ``out_dir``: one rename. An existing folder: ``tmp`` is first renamed into it (a
    hidden entry, same file system), then every entry of ``tmp`` and every existing entry whose
    name ``owned(name)`` accepts (the files this writer owns) is swapped by rename, the earlier ones
    parked in a hidden folder inside ``out_dir`` and removed at the end. Any error puts the earlier
    entries back and removes the new ones. Other entries of ``out_dir`` are never touched; a new
    entry whose name ``owned`` does not accept is refused (the caller writes only its own names).

    Args:
        tmp: the finished folder, a sibling of ``out_dir``.
        out_dir: the destination folder (resolved: not a symbolic link).
        owned: ``name -> bool``, the names this writer may replace or remove.
    """
    tmp, out_dir = Path(tmp), Path(out_dir)
    if not out_dir.exists():
        os.rename(tmp, out_dir)
        return
    token = uuid.uuid4().hex[:8]
    staged = out_dir / f".{out_dir.name}.new-{token}"
    parked = out_dir / f".{out_dir.name}.old-{token}"
    os.rename(tmp, staged)
    moved_old: list[str] = []
    placed: list[str] = []
    try:
        new_names = sorted(os.listdir(staged))
        if not all(owned(n) for n in new_names):  # pragma: no cover - a writer's own mistake
            raise ValueError(f"refusing to place entries the writer does not own: {new_names}")
        old_names = sorted(n for n in os.listdir(out_dir) if n not in (staged.name, parked.name) and owned(n))
        os.mkdir(parked)
        for name in sorted(set(new_names) | set(old_names)):
            dst = out_dir / name
            if os.path.lexists(dst):
                os.rename(dst, parked / name)
                moved_old.append(name)
            if name in new_names:
                os.rename(staged / name, dst)
                placed.append(name)
    except BaseException:
        for name in reversed(placed):
            with contextlib.suppress(OSError):
                os.rename(out_dir / name, staged / name)
        for name in reversed(moved_old):
            with contextlib.suppress(OSError):
                os.rename(parked / name, out_dir / name)
        remove_tree(staged)
        with contextlib.suppress(OSError):
            os.rmdir(parked)  # empty when every earlier entry went back; otherwise kept, never deleted
        raise
    remove_tree(parked)  # the writer's own earlier entries only
    remove_tree(staged)


def remove_tree(path: str | os.PathLike) -> None:
    """Remove ``path``: a symbolic link is unlinked (never followed), a folder removed with its content."""
    path = Path(path)
    if path.is_symlink() or path.is_file():
        path.unlink(missing_ok=True)
    elif path.is_dir():
        shutil.rmtree(path, ignore_errors=True)


def resolve_output(path: str | os.PathLike) -> Path:
    """``path`` with ``~`` expanded and every symbolic link resolved; a broken link is refused."""
    text = os.fspath(path)
    if not str(text).strip():
        raise InputError("the output path is empty")
    if "\x00" in str(text):
        raise InputError("the output path contains a NUL character")
    raw = Path(text).expanduser()
    if raw.is_symlink() and not raw.exists():
        raise InputError("is a broken symbolic link", path)
    return Path(os.path.realpath(raw))


def _nearest_existing(path: Path, shown) -> Path:
    """The nearest existing ancestor of ``path`` (itself when it exists); refused when it is not a folder."""
    probe = path
    while not (probe.exists() or probe.is_symlink()):
        if probe.parent == probe:
            break
        probe = probe.parent
    if probe != path and not probe.is_dir():
        raise InputError(f"is under {probe}, which is not a folder", shown)
    return probe


def _check_space_and_access(folder: Path, shown, need_bytes: int) -> None:
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InputError(f"cannot write into {folder} (permission denied)", shown)
    if need_bytes > 0:
        try:
            free = shutil.disk_usage(folder).free
        except OSError:
            return
        if free < need_bytes:
            raise InputError(
                f"not enough free space on the disk of {folder}: {free / 2**20:.1f} MiB free, "
                f"about {need_bytes / 2**20:.1f} MiB needed",
                shown,
            )


def check_output_dir(
    path: str | os.PathLike,
    *,
    overwrite: bool = False,
    reuse: bool = False,
    must_exist: bool = False,
    allow_cwd: bool = False,
    need_bytes: int = 0,
    option: str = "--out",
) -> Path:
    """Check, before any work, a folder that a command will write; return it resolved.

    Args:
        path: the folder as the user gave it (a symbolic link is followed: its target is checked
            and returned).
        overwrite: an existing non-empty folder is allowed (the writer replaces only its own files).
        reuse: an existing non-empty folder is allowed (a benchmark resumes in it).
        must_exist: the folder must exist (``ncflow evaluate`` adds files to a result folder).
            Without ``reuse`` or ``must_exist`` the folder's parent must be writable too (the
            output is staged in a hidden sibling folder and renamed into place).
        allow_cwd: the current folder (or an ancestor) is allowed.
        need_bytes: rough free space needed on its disk.
        option: the option's name, for the messages.

    Raises:
        InputError: one line naming ``path``: an existing file, a path under a file, a broken
            link, the current folder or an ancestor of it, an occupied folder without
            ``overwrite``, no write permission, or too little free space.
    """
    real = resolve_output(path)
    if real.exists() and not real.is_dir():
        raise InputError(f"{option} exists and is not a folder", path)
    if must_exist and not real.is_dir():
        raise InputError(f"{option}: no such folder", path)
    if not allow_cwd:
        cwd = Path(os.path.realpath(os.getcwd()))
        if real == cwd or real in cwd.parents:
            raise InputError(
                f"{option} is the current folder or one of its parents; give a new or dedicated folder", path
            )
    folder = _nearest_existing(real, path)
    if real.is_dir() and not (overwrite or reuse or must_exist):
        try:
            occupied = any(os.scandir(real))
        except OSError as exc:
            raise InputError(f"cannot list the folder ({exc.strerror or exc})", path) from None
        if occupied:
            raise InputError(
                f"{option} exists and is not empty (use --overwrite to replace ncflow's files in it)", path
            )
    _check_space_and_access(folder, path, need_bytes)
    if not (reuse or must_exist) and real.parent != real:  # the folder is staged beside itself, then renamed
        _check_space_and_access(_nearest_existing(real.parent, path), path, 0)
    return real


def check_output_file(path: str | os.PathLike, *, need_bytes: int = 0, option: str = "output") -> Path:
    """Check, before any work, a file that a command will write (replacing an earlier file); return it resolved.

    Raises:
        InputError: one line naming ``path``: an existing folder, a path under a file, a broken
            link, no write permission in its folder, or too little free space.
    """
    real = resolve_output(path)
    if real.is_dir():
        raise InputError(f"{option} is a folder, expected a file name", path)
    folder = _nearest_existing(real.parent, path)
    if real.parent.exists() and not real.parent.is_dir():
        raise InputError(f"is under {real.parent}, which is not a folder", path)
    _check_space_and_access(folder, path, need_bytes)
    return real
