"""Exceptions raised for bad user input, and the small readers that turn unreadable files into them.

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


def first_line(exc: BaseException) -> str:
    """The first line of an exception's message (its type name when it has none)."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


class ResultError(NcflowError, ValueError):
    """A result that must not be written (non-finite values, inconsistent shapes, occupied folder).

    The message is one line naming the offending array or file.
    """

    def __init__(self, message: str, path: str | os.PathLike | None = None):
        self.path = None if path is None else os.fspath(path)
        message = " ".join(str(message).split())
        super().__init__(f"{self.path}: {message}" if self.path else message)
