"""Checked opening of input files: existence and suffix, JSON objects, ``.npy`` / ``.npz`` arrays, resources.

The small readers the format modules start from. Each failure (a missing file, a directory or
another non-regular file, an unsupported suffix, invalid or too deeply nested JSON, a missing
array) is one :class:`~ncflow.errors.InputError` line naming the file. Hostile files are refused
before anything large is allocated:

* ``.npy`` arrays and ``.npz`` members are read without pickles, object arrays are refused, and
  the shape in every array header is checked against the bytes the file (or the zip member)
  actually holds before the array is allocated;
* an ``.npz`` archive is opened through :mod:`zipfile`: its members' uncompressed sizes (from the
  zip directory) must total at most :data:`MAX_ARRAY_BYTES` (or the caller's smaller limit) and
  only the arrays the caller needs are inflated;
* a resource that a file refers to by name (a glTF buffer, an OBJ material library) is read only
  when it is a regular file inside the referring file's folder (:func:`read_confined`): no ``..``,
  absolute paths, drive letters, URI schemes, percent-encoded separators, or symbolic links that
  lead out of the folder.
"""

from __future__ import annotations

import hashlib
import math
import os
import re
import stat
from pathlib import Path

from ncflow.errors import InputError, first_line

MAX_ARRAY_BYTES = 2 * 2**30
"""Largest total uncompressed size of the arrays read from one ``.npz`` / ``.npy`` file (2 GiB)."""

_VALUE_CHARS = 80
_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.\-]*:")
_ENCODED_SEPARATOR = re.compile(r"%(2f|5c|00)", re.IGNORECASE)


def short_repr(value, limit: int = _VALUE_CHARS) -> str:
    """``repr`` of a value cut to about ``limit`` characters (for quoting file contents in messages)."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def dtype_text(dtype) -> str:
    """A NumPy dtype read from a file, quoted for a message and cut short (a structured dtype's text
    runs to thousands of characters).
    """
    return short_repr(str(dtype), 40)


def file_sha256(path: str | os.PathLike) -> str:
    """SHA-256 of a file's bytes (hex)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def check_regular_file(path: str | os.PathLike, what: str) -> Path:
    """Raise :class:`InputError` unless ``path`` is an existing regular file (not a folder, FIFO or device)."""
    p = Path(path)
    try:
        mode = os.stat(p).st_mode
    except FileNotFoundError:
        raise InputError("no such file", p) from None
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot read file ({first_line(exc)})", p) from None
    if stat.S_ISDIR(mode):
        raise InputError(f"is a directory, expected a {what} file", p)
    if not stat.S_ISREG(mode):
        raise InputError(f"is not a regular file (a FIFO, socket or device?), expected a {what} file", p)
    return p


def check_input_file(path: str | os.PathLike, what: str, suffixes: tuple[str, ...]) -> str:
    """Raise :class:`InputError` unless ``path`` is an existing regular file with one of ``suffixes``.

    Returns the lower-case suffix.
    """
    p = check_regular_file(path, what)
    suffix = p.suffix.lower()
    if suffix not in suffixes:
        raise InputError(f"unsupported {what} format {suffix or '(no suffix)'!r}; use one of {', '.join(suffixes)}", p)
    return suffix


def parse_json_text(text: str, path) -> object:
    """``json.loads`` with every failure (syntax, nesting too deep, integers too long) as one InputError."""
    import json

    try:
        return json.loads(text)
    except RecursionError:
        raise InputError("not valid JSON (nested too deeply)", path) from None
    except ValueError as exc:  # JSONDecodeError, and int() refusing a number of thousands of digits
        raise InputError(f"not valid JSON ({first_line(exc)[:_VALUE_CHARS]})", path) from None


def read_json_object(path: str | os.PathLike, expected: str = "a JSON object") -> dict:
    """Parse a JSON file whose top level must be an object; one-line :class:`InputError` otherwise."""
    p = check_regular_file(path, "JSON")
    try:
        text = p.read_text()
    except OSError as exc:
        raise InputError(f"cannot read file ({exc.strerror or exc})", p) from None
    except UnicodeDecodeError as exc:
        raise InputError(f"not valid JSON ({first_line(exc)[:_VALUE_CHARS]})", p) from None
    data = parse_json_text(text, p)
    if not isinstance(data, dict):
        raise InputError(f"expected {expected}", p)
    return data


# ----------------------------------------------------------------------------------------------
# .npy / .npz


def _read_npy_header(fh):
    """(shape, fortran order, dtype) of the ``.npy`` stream ``fh`` (any format version)."""
    from numpy.lib import format as npf

    version = npf.read_magic(fh)
    if version == (1, 0):
        return npf.read_array_header_1_0(fh)
    if version in ((2, 0), (3, 0)):
        return npf.read_array_header_2_0(fh)
    raise ValueError(f"unsupported .npy format version {version}")


def read_npy_stream(fh, size: int, what: str, path, max_bytes: int = MAX_ARRAY_BYTES):
    """One array from an open ``.npy`` stream of ``size`` bytes, its header checked before allocating.

    Args:
        fh: binary stream positioned at the ``.npy`` magic.
        size: bytes the stream holds (the file size, or a zip member's uncompressed size).
        what: how messages call the array (``"array 'face'"``).
        path: the file, for messages.
        max_bytes: largest accepted array.

    Raises:
        InputError: a malformed header, an object dtype, a zero-size item type, or data shorter
            than the header declares or larger than ``max_bytes``.
    """
    import numpy as np

    try:
        shape, fortran, dtype = _read_npy_header(fh)
    except Exception as exc:
        raise InputError(f"{what}: malformed .npy header ({first_line(exc)[:_VALUE_CHARS]})", path) from None
    if not isinstance(shape, tuple) or not all(isinstance(n, int) and n >= 0 for n in shape):
        raise InputError(f"{what}: malformed .npy header (shape {short_repr(shape, 40)})", path)
    if dtype.hasobject:
        raise InputError(f"{what}: object arrays are not accepted (they need pickles)", path)
    if dtype.itemsize == 0:
        raise InputError(f"{what}: zero-size item type {dtype_text(dtype)}", path)
    count = math.prod(int(s) for s in shape)
    nbytes = count * dtype.itemsize
    if nbytes > max_bytes:
        raise InputError(f"{what}: declares {nbytes} bytes of data, over the limit of {max_bytes}", path)
    if nbytes > size - fh.tell():
        raise InputError(f"{what}: truncated (its header declares more data than the file holds)", path)
    buf = bytearray(nbytes)
    view, got = memoryview(buf), 0
    while got < nbytes:
        n = fh.readinto(view[got:])
        if not n:
            raise InputError(f"{what}: truncated (its header declares more data than the file holds)", path)
        got += n
    return np.frombuffer(buf, dtype=dtype, count=count).reshape(shape, order="F" if fortran else "C")


def read_npy_array(path: str | os.PathLike, max_bytes: int = MAX_ARRAY_BYTES):
    """The array of a ``.npy`` file (no pickles, header checked against the file size before allocating)."""
    p = check_regular_file(path, ".npy")
    try:
        with open(p, "rb") as fh:
            return read_npy_stream(fh, os.fstat(fh.fileno()).st_size, "array", p, max_bytes)
    except OSError as exc:
        raise InputError(f"cannot read .npy array ({first_line(exc)})", p) from None


def _npz_members(zf) -> dict:
    """Array name → zip member (``name.npy`` members are named ``name``, as :func:`numpy.load` does)."""
    members = {}
    for info in zf.infolist():
        key = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
        members.setdefault(key, info)
    return members


def _names(keys) -> str:
    """A short list of array names for messages."""
    keys = sorted(keys)
    text = ", ".join(k if len(k) <= 40 else k[:37] + "..." for k in keys[:10]) + (", ..." if len(keys) > 10 else "")
    return text or "none"


def read_npz_arrays(
    path: str | os.PathLike,
    required: tuple[str, ...] = (),
    optional: tuple[str, ...] | None = None,
    *,
    max_bytes: int = MAX_ARRAY_BYTES,
) -> dict:
    """Arrays of a ``.npz`` archive (no pickles), checking that ``required`` ones are present.

    Args:
        path: the archive.
        required: arrays that must be present.
        optional: the other arrays to read when present (None: every array of the archive).
        max_bytes: largest total uncompressed size of the arrays read (from the zip directory,
            checked before anything is inflated).

    Raises:
        InputError: not a zip archive, a missing array, arrays too large, a malformed member.
    """
    import zipfile

    p = check_regular_file(path, ".npz")
    if not zipfile.is_zipfile(p):
        raise InputError("cannot read .npz archive (not a zip file)", p)
    try:
        with zipfile.ZipFile(p) as zf:
            members = _npz_members(zf)
            for key in required:
                if key not in members:
                    raise InputError(f"missing array {short_repr(key)} (found: {_names(members)})", p)
            wanted = [k for k in members if optional is None or k in required or k in optional]
            total = sum(members[k].file_size for k in wanted)
            if total > max_bytes:
                raise InputError(f"arrays would inflate to {total} bytes, over the limit of {max_bytes}", p)
            arrays = {}
            for key in wanted:
                with zf.open(members[key]) as fh:
                    arrays[key] = read_npy_stream(fh, members[key].file_size, f"array {short_repr(key)}", p, max_bytes)
    except InputError:
        raise
    except Exception as exc:  # zipfile / zlib / bz2 / lzma raise many kinds of errors for broken archives
        raise InputError(f"cannot read .npz archive ({first_line(exc)[:_VALUE_CHARS]})", p) from None
    return arrays


# ----------------------------------------------------------------------------------------------
# resources referred to by name


def confined_path(folder: str | os.PathLike, name: str, *, unquote: bool = False) -> str:
    """The real path of resource ``name`` inside ``folder``; ``ValueError`` (the reason) when it may leave it.

    Refused: empty names, NUL characters, percent-encoded separators, URI schemes and drive
    letters, absolute paths, ``..`` segments, and names whose real path (symbolic links resolved)
    is outside the folder's real path. ``unquote``: ``name`` is a URI reference (percent-decoded
    after the checks on its raw form).
    """
    import urllib.parse

    if not isinstance(name, str) or not name.strip():
        raise ValueError("an empty name")
    if _ENCODED_SEPARATOR.search(name):
        raise ValueError("a percent-encoded separator")
    if unquote:
        name = urllib.parse.unquote(name)
    if "\x00" in name:
        raise ValueError("a NUL character")
    if _SCHEME.match(name):
        raise ValueError("a URI scheme or drive letter (only files beside it are read)")
    if name.startswith(("/", "\\")) or os.path.isabs(name):
        raise ValueError("an absolute path (only files beside it are read)")
    if ".." in re.split(r"[\\/]", name):
        raise ValueError("a '..' segment (only files beside it are read)")
    root = os.path.realpath(folder)
    real = os.path.realpath(os.path.join(root, name))
    if os.path.commonpath([root, real]) != root or real == root:
        raise ValueError("a link out of its folder (only files beside it are read)")
    return real


def read_confined(folder: str | os.PathLike, name: str, limit: int, *, unquote: bool = False) -> bytes:
    """At most ``limit`` bytes of resource ``name``, a regular file inside ``folder`` (:func:`confined_path`).

    Raises:
        ValueError: the name is refused, or it is not a regular file (the reason, without sizes).
        OSError: it cannot be read.
    """
    real = confined_path(folder, name, unquote=unquote)
    # O_NONBLOCK: opening a FIFO must not wait for a writer; the type is checked on what was opened
    fd = os.open(real, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOFOLLOW", 0))
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise ValueError("not a regular file")
        fh = os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise
    with fh:
        return fh.read(max(0, int(limit)))
