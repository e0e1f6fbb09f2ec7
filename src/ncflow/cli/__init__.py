"""The ``ncflow`` command.

One module per command, listed in :data:`COMMANDS`; each defines ``register(subparsers)``, which
adds its parser and sets ``func`` (called with the parsed arguments, returning an exit code; the
work itself is one library call). :mod:`ncflow.cli.options` holds the options the matching
commands share. Heavy dependencies are imported inside ``run`` functions, so ``ncflow --help``
stays fast.
"""

from __future__ import annotations

import argparse
import sys

from ncflow import __version__
from ncflow.cli import (
    batch,
    benchmark,
    demo,
    distance,
    evaluate,
    make_pairs,
    make_shape,
    match,
    pose,
    rig,
    skeleton,
    track,
    transfer,
    view,
)
from ncflow.errors import NcflowError, first_line

__all__ = ["COMMANDS", "build_parser", "main"]


class Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (no usage block) with exit status 2."""

    def error(self, message: str):
        message = " ".join(message.split())
        if len(message) > 300:
            message = message[:299] + "…"
        self.exit(2, f"{self.prog}: error: {message}\n")


# the command table, in the order ``ncflow --help`` lists them
COMMANDS = (
    batch,
    benchmark,
    demo,
    distance,
    evaluate,
    make_pairs,
    make_shape,
    match,
    pose,
    rig,
    skeleton,
    track,
    transfer,
    view,
)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="ncflow",
        description="Correspondence-free matching and interpolation of articulated 3D shapes.",
    )
    parser.add_argument("--version", action="version", version=f"ncflow {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in COMMANDS:
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status (0 ok, 2 bad input, 1 internal failure).

    Every error is one line on stderr: bad options (argparse, status 2), bad input or an unusable
    output path (:class:`~ncflow.errors.NcflowError`, status 2), a failing disk or file system
    (:class:`OSError`, status 1). The JAX options a match wants from the start were set when ``ncflow``
    was imported, before this module (:func:`ncflow.jit.cache.prepare_jax`).
    """
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, or a one-line option error
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    try:
        return int(args.func(args) or 0)
    except NcflowError as exc:
        print(f"ncflow {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        reason = exc.strerror or first_line(exc)
        print(f"ncflow {args.command}: error: {where}{reason}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"ncflow {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
