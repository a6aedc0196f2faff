"""The DataFlash binary format: the facts its reader and the simulator's writer share.

A record is ``0xA3 0x95 <type id>`` followed by its little-endian payload. The FMT record
(type 128, 89 bytes, format ``BBnNZ``) declares each type's id, length, name, format
characters and column names. Each format character has a storage type and a presentation:
``c C e E`` hold the value times 100 and ``L`` times 1e7 (a latitude or longitude); pymavlink
presents them multiplied by 0.01 and 1e-7.

The compiled header scan (``mavsid/readers/_scan.c``) has its own copy of the two header
bytes; tests/test_dataflash.py checks that it agrees with :data:`HEAD`.

Examples
--------
>>> payload_size("QfB"), payload_size("a")
(13, 64)
>>> FORMAT_CHARS["L"].multiplier, FORMAT_CHARS["L"].scale
(1e-07, 10000000.0)
>>> build_record(0x81, "Bh", 1, -2).hex()
'a3958101feff'
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

__all__ = [
    "FMT_COLUMNS",
    "FMT_FORMAT",
    "FMT_LENGTH",
    "FMT_TYPE",
    "FORMAT_CHARS",
    "HEAD",
    "FormatChar",
    "build_fmt",
    "build_record",
    "payload_dtype",
    "payload_size",
]

#: the two bytes that open every record
HEAD = b"\xa3\x95"
#: the FMT record: its type id, payload format, columns and length (header included)
FMT_TYPE = 0x80
FMT_FORMAT = "BBnNZ"
FMT_COLUMNS = ("Type", "Length", "Name", "Format", "Columns")
FMT_LENGTH = 89


@dataclass(frozen=True)
class FormatChar:
    """How one DataFlash format character is stored and presented."""

    dtype: str  # numpy dtype of the stored value (little-endian)
    kind: str  # "int", "float", "str" or "array"
    code: str  # the ``struct`` code of the stored value
    multiplier: float | None = None  # scaling pymavlink applies (c C e E L)

    @property
    def scale(self) -> float | None:
        """Stored counts per presented unit (100 for ``c``), or None when stored as shown."""
        return None if self.multiplier is None else 1.0 / self.multiplier


#: format character -> storage and presentation
FORMAT_CHARS: Mapping[str, FormatChar] = {
    "a": FormatChar("(32,)<i2", "array", "64s"),
    "b": FormatChar("<i1", "int", "b"),
    "B": FormatChar("<u1", "int", "B"),
    "g": FormatChar("<f2", "float", "e"),
    "h": FormatChar("<i2", "int", "h"),
    "H": FormatChar("<u2", "int", "H"),
    "i": FormatChar("<i4", "int", "i"),
    "I": FormatChar("<u4", "int", "I"),
    "f": FormatChar("<f4", "float", "f"),
    "d": FormatChar("<f8", "float", "d"),
    "n": FormatChar("S4", "str", "4s"),
    "N": FormatChar("S16", "str", "16s"),
    "Z": FormatChar("S64", "str", "64s"),
    "c": FormatChar("<i2", "float", "h", 0.01),
    "C": FormatChar("<u2", "float", "H", 0.01),
    "e": FormatChar("<i4", "float", "i", 0.01),
    "E": FormatChar("<u4", "float", "I", 0.01),
    "L": FormatChar("<i4", "float", "i", 1.0e-7),
    "M": FormatChar("<i1", "int", "b"),
    "q": FormatChar("<i8", "int", "q"),
    "Q": FormatChar("<u8", "int", "Q"),
}

_CHAR_SIZES = {c: np.dtype(spec.dtype).itemsize for c, spec in FORMAT_CHARS.items()}


def payload_size(fmt: str) -> int:
    """Bytes of a payload of format ``fmt`` (known characters only; no dtype is built)."""
    return sum(_CHAR_SIZES[c] for c in fmt)


@lru_cache(maxsize=4096)
def payload_dtype(fmt: str) -> np.dtype:
    """Packed structured dtype of a payload of format ``fmt``, fields named ``f0, f1, ...``.

    Examples
    --------
    >>> payload_dtype("Qc").itemsize, payload_dtype("Qc").names
    (10, ('f0', 'f1'))
    """
    names, formats, offsets, ofs = [], [], [], 0
    for i, ch in enumerate(fmt):
        dt = np.dtype(FORMAT_CHARS[ch].dtype)
        names.append(f"f{i}")
        formats.append(dt)
        offsets.append(ofs)
        ofs += dt.itemsize
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": ofs})


def _struct_format(fmt: str) -> str:
    return "<" + "".join(FORMAT_CHARS[c].code if c in FORMAT_CHARS else c for c in fmt)


def build_record(msg_type: int, fmt: str, *values: object) -> bytes:
    """One binary record (header + packed payload), for tests and synthetic logs.

    Scaled characters take the *raw* stored integer (e.g. centidegrees for ``c``).
    """
    packed = []
    for ch, v in zip(fmt, values, strict=True):
        if isinstance(v, str):
            v = v.encode()
        if ch == "a" and not isinstance(v, bytes):
            v = np.asarray(v, "<i2").tobytes()
        packed.append(v)
    return HEAD + bytes((msg_type,)) + struct.pack(_struct_format(fmt), *packed)


def build_fmt(msg_type: int, name: str, fmt: str, columns: str) -> bytes:
    """The FMT record that defines ``msg_type``.

    Examples
    --------
    >>> len(build_fmt(0x81, "TST", "Qf", "TimeUS,X")) == FMT_LENGTH
    True
    """
    length = 3 + struct.calcsize(_struct_format(fmt))
    return build_record(FMT_TYPE, FMT_FORMAT, msg_type, length, name, fmt, columns)
