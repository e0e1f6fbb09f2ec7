"""Checked opening of input files: existence and suffix, JSON objects, ``.npz`` archives.

The small readers the format modules start from. Each failure (a missing file, a directory, an
unsupported suffix, invalid JSON, a missing array) is one :class:`~ncflow.errors.InputError` line
naming the file; ``.npz`` archives are read without pickles.
"""

from __future__ import annotations

import os

from ncflow.errors import InputError, first_line


def check_input_file(path: str | os.PathLike, what: str, suffixes: tuple[str, ...]) -> str:
    """Raise :class:`InputError` unless ``path`` is an existing file with one of ``suffixes``.

    Returns the lower-case suffix.
    """
    from pathlib import Path

    p = Path(path)
    if not p.exists():
        raise InputError("no such file", p)
    if p.is_dir():
        raise InputError(f"is a directory, expected a {what} file", p)
    suffix = p.suffix.lower()
    if suffix not in suffixes:
        raise InputError(f"unsupported {what} format {suffix or '(no suffix)'!r}; use one of {', '.join(suffixes)}", p)
    return suffix


def read_json_object(path: str | os.PathLike, expected: str = "a JSON object") -> dict:
    """Parse a JSON file whose top level must be an object; one-line :class:`InputError` otherwise."""
    import json
    from pathlib import Path

    p = Path(path)
    try:
        data = json.loads(p.read_text())
    except OSError as exc:
        raise InputError(f"cannot read file ({exc.strerror or exc})", p) from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"not valid JSON ({exc})", p) from None
    if not isinstance(data, dict):
        raise InputError(f"expected {expected}", p)
    return data


def read_npz_arrays(path: str | os.PathLike, required: tuple[str, ...] = ()) -> dict:
    """All arrays of a ``.npz`` archive (no pickles), checking that ``required`` ones are present."""
    import zipfile
    from pathlib import Path

    import numpy as np

    p = Path(path)
    if not zipfile.is_zipfile(p):
        raise InputError("cannot read .npz archive (not a zip file)", p)
    try:
        with np.load(p, allow_pickle=False) as z:
            arrays = {k: np.asarray(z[k]) for k in z.files}
    except Exception as exc:
        raise InputError(f"cannot read .npz archive ({first_line(exc)})", p) from None
    for key in required:
        if key not in arrays:
            raise InputError(f"missing array {key!r} (found: {', '.join(sorted(arrays)) or 'none'})", p)
    return arrays
