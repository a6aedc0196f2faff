"""One ULog message's payload, decoded as pyulog decodes it.

A message is ``uint16 size, uint8 type`` (:data:`HEAD`) and ``size`` bytes of payload. This
module holds what reads one payload other than topic data: info and parameter payloads
(:func:`info`), the ``M`` / ``Q`` messages that are only checked (:func:`checked`), format
definitions (:func:`parse_format`), texts (:func:`decode_text`), and the two ways a payload
fails as it fails pyulog (:class:`ShortPayload`, :class:`BadPayload`).

:data:`compiled` is the compiled module (``_scan``, built by ``setup.py``) every ULog module
reads it from, or None where the package was built without a C compiler: then numpy does
its work (tests set it to None to read the logs that way too).

Examples
--------
>>> HEAD(b"\\x05\\x00F", 0)
(5, 70)
>>> info(bytes([11]) + b"int32_t MAV" + struct.pack("<i", 2))
('int32_t', 'MAV', 2)
"""

from __future__ import annotations

import mmap
import struct
from types import ModuleType

import numpy as np
from numpy.typing import NDArray

from mavsid.readers.ulog_spec import BASIC_TYPES

_scan: ModuleType | None
try:  # the loops compiled (setup.py); absent where the package was built without a C
    from mavsid.readers import _scan  # compiler: numpy's and Python's then
except ImportError:  # pragma: no cover - depends on the build
    _scan = None
#: the compiled loops (see the module's text)
compiled: ModuleType | None = _scan

__all__ = ["HEAD", "MAX_UNKNOWN_SIZE", "TYPE_SIZE", "BadPayload", "Buffer", "Field", "InfoValue",
           "ShortPayload", "checked", "compiled", "decode_text", "info", "parse_format",
           "parse_format_fast", "u16", "unpack_value"]

#: a message's header: (payload size, type) at a position of a buffer
HEAD = struct.Struct("<HB").unpack_from
#: an unknown message type with a size above this is taken as corruption (pyulog's rule)
MAX_UNKNOWN_SIZE = 10000
#: bytes of each basic type
TYPE_SIZE = {kind: t.size for kind, t in BASIC_TYPES.items()}

#: a mapped ULog file, or its bytes
Buffer = bytes | mmap.mmap
Field = tuple[str, int, str]  # type, array size (0: scalar), name
#: an info or parameter value as the payload has it: a number of a basic type, a text
#: (``char[N]``), or the raw bytes of an array or of a damaged type (as pyulog keeps them)
InfoValue = int | float | str | bytes


class ShortPayload(Exception):
    """A payload too short for its fixed fields: pyulog's ``struct.error``, which ends the
    section being read (in the definitions: counted as corruption)."""


class BadPayload(Exception):
    """A payload that does not parse (pyulog's IndexError, KeyError, ValueError): the
    message is skipped and the file marked corrupt."""


def decode_text(raw: bytes) -> str:
    """A payload's text: UTF-8, invalid bytes dropped.

    Examples
    --------
    >>> decode_text(b"ok\\xff")
    'ok'
    """
    return raw.decode("utf-8", "ignore")


def unpack_value(code: str, raw: bytes) -> int | float:
    """The one value of ``struct`` code ``code`` that ``raw`` holds exactly.

    Examples
    --------
    >>> unpack_value("H", b"\\x01\\x02")
    513
    """
    if len(raw) != struct.calcsize("<" + code):
        raise ShortPayload
    value: int | float = struct.unpack("<" + code, raw)[0]
    return value
def info(data: bytes, multiple: bool = False) -> tuple[str, str, InfoValue]:
    """An info, info-multiple or parameter payload: (type, key, value).

    Examples
    --------
    >>> info(bytes([13]) + b"float MC_RATE" + struct.pack("<f", 0.5))
    ('float', 'MC_RATE', 0.5)
    >>> info(bytes([14]) + b"char[3] ver_hw" + b"abc")[2]
    'abc'
    """
    if multiple:
        data = data[1:]
    if not data:
        raise ShortPayload
    words = decode_text(data[1 : 1 + data[0]]).split(" ")
    if len(words) < 2:
        raise BadPayload
    kind, key, raw = words[0], words[1], data[1 + data[0] :]
    if kind.startswith("char["):
        return kind, key, decode_text(raw)
    if kind in BASIC_TYPES:
        return kind, key, unpack_value(BASIC_TYPES[kind].code, raw)
    return kind, key, raw  # an array or a damaged type: raw bytes, as pyulog keeps them


def checked(buf: Buffer, pos: int, end: int) -> bool:
    """Whether the ``M`` or ``Q`` message at ``pos`` (a byte, then an info: key length,
    key ``type name``, value) is one pyulog reads without error, seen without decoding it:
    a text (type ``char[N]``) or a 4-byte parameter value. False: not known to be.

    Examples
    --------
    >>> checked(b"\\0\\0M" + bytes([0, 9]) + b"char[1] ab", 0, 15)
    True
    >>> checked(b"\\0\\0Q" + bytes([0, 7]) + b"float x" + bytes(4), 0, 16)
    True
    >>> checked(b"\\0\\0Q" + bytes([0, 7]) + b"float x" + bytes(3), 0, 15)
    False
    """
    if end - pos < 5:
        return False
    key = pos + 5
    stop = key + buf[pos + 4]
    if stop > end:
        return False
    if buf[key : key + 5] == b"char[":
        return bool(buf.find(b" ", key + 5, stop) >= 0)
    if end - stop != 4:
        return False
    return (stop - key >= 6 and buf[key : key + 6] == b"float ") or (
        stop - key >= 8 and buf[key : key + 8] == b"int32_t ")


def parse_format(data: bytes) -> tuple[str, tuple[Field, ...], int]:
    """A format definition ``name:type field;type[n] field;...``: its name, fields and
    size in bytes when all its fields are of basic types (else -1: nested formats, sized
    by :func:`~mavsid.readers.ulog_layout.format_widths`). Kept for the process as
    :func:`~mavsid.readers.ulog_layout.known_format`.

    Examples
    --------
    >>> parse_format(b"att:uint64_t timestamp;float[4] q;")
    ('att', (('uint64_t', 0, 'timestamp'), ('float', 4, 'q')), 24)
    >>> parse_format(b"esc:uint64_t timestamp;report[2] r;")[2]
    -1
    """
    parts = decode_text(data).split(":")
    if len(parts) < 2:
        raise BadPayload
    fields = []
    size = 0
    for item in parts[1].split(";"):
        if not item:
            continue
        kind, space, rest = item.partition(" ")
        if not space:
            raise BadPayload
        name = rest.partition(" ")[0]  # the second word, as pyulog takes it
        a = kind.find("[")
        if a < 0:
            fields.append((kind, 0, name))
            width = TYPE_SIZE.get(kind)
            size = -1 if width is None or size < 0 else size + width
            continue
        try:
            count = int(kind[a + 1 : kind.find("]")])
        except ValueError:
            raise BadPayload from None
        if not 0 <= count <= 0xFFFF:
            raise BadPayload
        kind = kind[:a]
        fields.append((kind, count, name))
        width = TYPE_SIZE.get(kind)
        size = -1 if width is None or size < 0 else size + width * (count or 1)
    return parts[0], tuple(fields), size


def parse_format_fast(data: bytes) -> tuple[str, tuple[Field, ...], int]:
    """:func:`parse_format`, compiled where the package was (``_scan.ulog_format``: the
    same objects, ~2.6x faster: building them is most of the rest; the tests compare the
    two)."""
    if compiled is None:
        return parse_format(data)
    try:
        return compiled.ulog_format(data, TYPE_SIZE)
    except ValueError:
        raise BadPayload from None


def u16(u8: NDArray[np.uint8], at: NDArray[np.int64]) -> NDArray[np.uint16]:
    """The little-endian ``uint16`` at each byte position ``at`` (``at`` is reused).

    Examples
    --------
    >>> u16(np.array([1, 2, 3], np.uint8), np.array([0, 1]))
    array([513, 770], dtype=uint16)
    """
    low = u8.take(at).astype(np.uint16)
    at += 1
    low |= u8.take(at).astype(np.uint16) << 8
    return low


