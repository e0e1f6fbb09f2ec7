"""Exceptions raised for bad user input.

Every error that a user can cause by handing ncflow a bad file or a bad setting is an
:class:`InputError` whose message is one line naming the file (when there is one) and the
problem. The command-line tool prints that line and exits with status 2.
"""

from __future__ import annotations

import os


class NcflowError(Exception):
    """Base class of all ncflow errors."""


class InputError(NcflowError, ValueError):
    """Bad user input (a file or a setting); the message is one line.

    Args:
        message: what is wrong.
        path: the offending file, prefixed to the message when given.
    """

    def __init__(self, message: str, path: str | os.PathLike | None = None):
        self.path = None if path is None else os.fspath(path)
        message = " ".join(str(message).split())
        super().__init__(f"{self.path}: {message}" if self.path else message)


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
        raise InputError(
            f"unsupported {what} format {suffix or '(no suffix)'!r}; use one of {', '.join(suffixes)}", p
        )
    return suffix
