"""The ``mavsid`` command line: each subcommand is one call into the library.

Exit codes: 0 success; 1 a :class:`~mavsid.errors.MavsidError` (printed as one line on
stderr, with a traceback only under ``--debug``); 2 usage errors.

Examples
--------
>>> main(["--version"])  # doctest: +ELLIPSIS
mavsid ...
0
"""

from __future__ import annotations

import argparse
import sys
import traceback
import warnings
from collections.abc import Callable, Sequence

from mavsid import __version__
from mavsid.errors import MavsidError, MavsidWarning

__all__ = ["build_parser", "main"]

Handler = Callable[[argparse.Namespace], int]


def _show_warning(message, category, filename, lineno, file=None, line=None):  # type: ignore[no-untyped-def]
    """Print mavsid's warnings as one plain line, others as Python would."""
    if issubclass(category, MavsidWarning):
        print(f"warning: {message}", file=sys.stderr)
    else:
        _default_showwarning(message, category, filename, lineno, file, line)


_default_showwarning = warnings.showwarning


# --------------------------------------------------------------------------- subcommands
# Each ``_add_<name>`` declares one subcommand and sets ``handler`` to a function that makes
# one library call and prints its result. Library modules are imported lazily so that
# ``mavsid --help`` stays fast.


SUBCOMMANDS: list[Callable[[argparse._SubParsersAction], None]] = []  # type: ignore[type-arg]


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every subcommand."""
    parser = argparse.ArgumentParser(
        prog="mavsid",
        description="Attitude-dynamics models from ArduPilot and PX4 flight logs.",
    )
    parser.add_argument("--version", action="store_true", help="print the version and exit")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for add in SUBCOMMANDS:
        add(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.version:
        print(f"mavsid {__version__}")
        return 0
    if not getattr(args, "handler", None):
        parser.print_help(sys.stderr)
        return 2
    handler: Handler = args.handler
    warnings.showwarning = _show_warning
    try:
        return handler(args)
    except MavsidError as exc:
        if args.debug:
            traceback.print_exc()
        print(f"mavsid: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("mavsid: interrupted", file=sys.stderr)
        return 130
    finally:
        warnings.showwarning = _default_showwarning


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
