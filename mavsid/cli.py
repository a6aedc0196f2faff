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


def _add_segments(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "segments",
        help="list the well-excited windows of a log, and why the others were rejected",
    )
    p.add_argument("log", help="flight log (.bin, .log, .tlog, .ulg)")
    p.add_argument("--axis", choices=("roll", "pitch", "yaw"), help="one axis only")
    p.add_argument("--json", action="store_true", help="print a JSON list of windows")
    p.add_argument("--all", action="store_true", help="list every rejected scan window")
    p.add_argument("--scan", action="store_true",
                   help="scan sliding windows also on axes that have a SYSTEMID run")
    p.add_argument("--window", type=float, default=5.0, help="scan window length, s (5)")
    p.add_argument("--preset", help="channel preset name, or a TOML file of presets")
    p.add_argument("--rate", type=float, help="grid rate, Hz (default: the rate channel's)")
    p.set_defaults(handler=_segments)


def _segments(args: argparse.Namespace) -> int:
    import json

    from mavsid.align import load_flight
    from mavsid.channels import load_presets
    from mavsid.excitation import ScanOptions, find_segments, format_reports

    preset, presets, mixers = args.preset, None, None
    if preset and preset.lower().endswith(".toml"):
        presets, mixers = load_presets(preset)
        preset = None
    flight = load_flight(args.log, preset, args.rate, presets=presets, mixers=mixers)
    reports = find_segments(flight, args.axis, scan=True if args.scan else None,
                            options=ScanOptions(window_s=args.window))
    if args.json:
        print(json.dumps([r.to_dict() for r in reports], indent=1, ensure_ascii=False))
    else:
        span = flight.time_s[-1] - flight.time_s[0]
        print(f"{args.log}: preset {flight.preset}, {1 / flight.dt:.0f} Hz, {span:.1f} s, "
              f"{len(flight.blocks)} block(s)")
        print(format_reports(reports, show_all=args.all))
    return 0


SUBCOMMANDS.append(_add_segments)


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
