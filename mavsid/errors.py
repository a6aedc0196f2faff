"""Errors and warnings raised by mavsid.

Every error a user can provoke with bad input is a :class:`MavsidError`; the command line
prints it as one line and exits with code 1. The subclasses also derive from the builtin
exception a Python caller would expect (``ValueError``, ``KeyError`` ...), in the manner of
scikit-learn's ``NotFittedError``.

Examples
--------
>>> err = LogFormatError("no DataFlash records found", path="flight.bin", offset=0)
>>> str(err)
'flight.bin: no DataFlash records found (at byte 0)'
>>> isinstance(err, ValueError) and isinstance(err, MavsidError)
True

Text that comes from a log (message and field names, units, texts, a file name) may hold
control characters; every error's text is escaped (:func:`escape`), so it is one line that
cannot move the cursor, recolour or clear a terminal:

>>> str(LogFormatError("bad name 'A\\x1b[2J\\rB\\nC'", path="x.bin"))
"x.bin: bad name 'A\\\\x1b[2J\\\\rB\\\\nC'"
"""

from __future__ import annotations

import math
import numbers
import re
from collections.abc import Iterable, Sequence

__all__ = [
    "ConfigError",
    "DataQualityWarning",
    "ImplausibleModelError",
    "LogFormatError",
    "MavsidError",
    "MavsidWarning",
    "MissingMessageError",
    "NoExcitationError",
    "SolverError",
    "escape",
    "escape_lines",
    "finite_number",
    "first_few",
    "naming_file",
    "whole_number",
]


# C0 and C1 controls, DEL, and the invisible format characters that reorder or hide text
# (bidirectional overrides and isolates, zero-width characters, line/paragraph separators)
_UNSAFE = re.compile("[\x00-\x1f\x7f-\x9f\u200b-\u200f\u2028-\u202e\u2060-\u2069\ufeff]")
_NAMED = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}


def _escaped(match: re.Match[str]) -> str:
    ch = match.group()
    if ch in _NAMED:
        return _NAMED[ch]
    code = ord(ch)
    return f"\\x{code:02x}" if code < 0x100 else f"\\u{code:04x}"


def escape(text: object) -> str:
    """``text`` as one line safe for a terminal: control characters (newlines, carriage
    returns, escape sequences, C1 controls, bidirectional overrides) shown as ``\\n``,
    ``\\x1b`` ... Use it on every text from a log that is printed.

    Examples
    --------
    >>> escape("ATT\\x1b[31m\\r\\n")
    'ATT\\\\x1b[31m\\\\r\\\\n'
    >>> escape("plain text, °C, Ω") == "plain text, °C, Ω"
    True
    """
    return _UNSAFE.sub(_escaped, str(text))


def escape_lines(text: str) -> str:
    """Multi-line output (``mavsid info`` ...) with each line :func:`escape`-d: its own
    newlines kept, anything else that would move the cursor escaped.

    Examples
    --------
    >>> escape_lines("a\\rb\\nc")
    'a\\\\rb\\nc'
    """
    return "\n".join(escape(line) for line in text.split("\n"))


class MavsidError(Exception):
    """Base class of every error mavsid raises on purpose.

    Its text is :func:`escape`-d: one line, whatever the log put into it. ``details``
    holds further lines the command line prints below it (empty by default).
    """

    details: tuple[str, ...] = ()

    def __str__(self) -> str:
        return escape(super().__str__())


class LogFormatError(MavsidError, ValueError):
    """A file is not a log mavsid can read, or nothing decodable is in it.

    Parameters
    ----------
    message : str
        What is wrong, without the file name.
    path : str, optional
        The file; prefixed to the message.
    offset : int, optional
        Byte offset where the problem was found.
    """

    def __init__(self, message: str, path: object = None, offset: int | None = None) -> None:
        self.path = None if path is None else str(path)
        self.offset = offset
        self.reason = message
        text = message if self.path is None else f"{self.path}: {message}"
        if offset is not None:
            text += f" (at byte {offset})"
        super().__init__(text)


class MissingMessageError(MavsidError, KeyError):
    """A message type (or field) was asked for that the log does not have.

    Examples
    --------
    >>> str(MissingMessageError("RATE", available=["ATT", "IMU"]))
    "log has no message 'RATE' (it has: ATT, IMU)"
    >>> str(MissingMessageError("RATE", path="a.bin"))
    "a.bin: log has no message 'RATE'"
    """

    def __init__(self, name: str, available: Iterable[str] = (), what: str = "message",
                 path: object = None) -> None:
        self.name = name
        self.what = what
        self.available = sorted(available)
        self.path = None if path is None else str(path)
        shown = ", ".join(self.available[:40])
        if len(self.available) > 40:
            shown += f", ... ({len(self.available)} in all)"
        self.text = f"log has no {what} {name!r}" + (f" (it has: {shown})" if shown else "")
        if self.path is not None:
            self.text = f"{self.path}: {self.text}"
        super().__init__(self.text)

    def __str__(self) -> str:  # KeyError would quote the whole message
        return escape(self.text)


def naming_file(exc: MavsidError, path: object) -> MavsidError:
    """``exc``, or an error of the same type whose text starts with ``path`` when it does
    not name that file yet (the library's entry points use it: every error names the file).

    Examples
    --------
    >>> str(naming_file(MissingMessageError("ATT.Roll", what="field"), "a.bin"))
    "a.bin: log has no field 'ATT.Roll'"
    >>> str(naming_file(NoExcitationError("a.bin: nothing"), "a.bin"))
    'a.bin: nothing'
    """
    where = str(path)
    if not where or where in str(exc):
        return exc
    new: MavsidError
    if isinstance(exc, MissingMessageError):
        new = MissingMessageError(exc.name, exc.available, exc.what, path=where)
    elif isinstance(exc, LogFormatError):
        new = LogFormatError(exc.reason, path=where, offset=exc.offset)
    else:
        try:
            new = type(exc)(f"{where}: {exc}")
        except TypeError:  # a subclass with another signature: leave it
            return exc
    new.__cause__ = exc.__cause__
    return new


class NoExcitationError(MavsidError, ValueError):
    """The data cannot identify what was asked: no excitation, or unidentifiable parameters."""


class ImplausibleModelError(MavsidError, ValueError):
    """The data would give a physically absurd model (an aliased output, an effectiveness of
    the wrong sign, a pole faster than the sampling): refused with the reason."""


class ConfigError(MavsidError, ValueError):
    """A configuration file, preset or option is invalid."""


class SolverError(MavsidError, RuntimeError):
    """A numerical solver failed to produce a usable result."""


class MavsidWarning(UserWarning):
    """Base class of mavsid's warnings."""


class DataQualityWarning(MavsidWarning):
    """Data was skipped, repaired or is of doubtful use (corrupt bytes, low rates, gaps)."""


# --------------------------------------------------------------------------- checking input


def finite_number(value: object) -> bool:
    """Whether a value a user gave (TOML, JSON, a parameter) is a finite real number; a
    boolean is not one (Python and TOML count ``true`` as 1).

    Examples
    --------
    >>> finite_number(2), finite_number(0.5), finite_number(float("nan")), finite_number(True)
    (True, True, False, False)
    """
    return (isinstance(value, numbers.Real) and not isinstance(value, bool)
            and math.isfinite(value))


def whole_number(value: object) -> bool:
    """Whether a value a user gave is an integer (not a boolean, nor a float).

    Examples
    --------
    >>> whole_number(3), whole_number(3.0), whole_number(False)
    (True, False, False)
    """
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def first_few(items: Sequence[str], n: int = 5) -> str:
    """The first ``n`` of ``items``, comma-separated, ``...`` after them when there are more
    (a list in a one-line message).

    Examples
    --------
    >>> first_few(["a", "b", "c"], 2)
    'a, b ...'
    """
    return ", ".join(items[:n]) + (" ..." if len(items) > n else "")
