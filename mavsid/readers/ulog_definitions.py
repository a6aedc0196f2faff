"""A ULog's header and definitions section, and :class:`Parsed`, what a read gathers.

The file opens with the magic, a version byte and the start time (:meth:`Definitions.header`),
then the definitions: flag bits, formats, info and the initial parameters, up to the first
subscription or logged text, where the data section begins
(:mod:`~mavsid.readers.ulog_data`). Both sections' messages other than topic data and
subscriptions are read by :func:`other_message` into :class:`Parsed`, with pyulog's rules.

The plain parameters (``float`` or ``int32_t`` key, 4-byte value: nearly all of a log's
thousand or two) are found in runs, as data messages are (see
:mod:`~mavsid.readers.ulog_data`'s *Framing*), and decoded in one batch, names at once and
values as arrays; ``M`` and ``Q`` messages, which are only checked, are seen without
decoding when plainly valid.

Examples
--------
>>> out = Parsed()
>>> raw = b"ULog\\x01\\x12\\x35\\x01" + bytes(8) + b"\\x0a\\x00Fa:float x;"
>>> reader = Definitions(raw, "a.ulg", out)
>>> reader.read(), out.formats
(29, {'a': (('float', 0, 'x'),)})
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from mavsid.errors import LogFormatError
from mavsid.readers import ulog_messages as msg
from mavsid.readers.files import LogPath
from mavsid.readers.ulog_layout import Fields, known_format
from mavsid.readers.ulog_messages import (
    HEAD,
    MAX_UNKNOWN_SIZE,
    BadPayload,
    Buffer,
    Field,
    InfoValue,
    ShortPayload,
    checked,
    decode_text,
    info,
    u16,
    unpack_value,
)
from mavsid.readers.ulog_spec import MAGIC

__all__ = ["PLAIN_WINDOW", "Definitions", "Parsed", "Text", "garbage_end", "other_message"]

#: a parameter key's type as the payload has it (after size, type and key length)
_FLOAT, _INT32 = np.frombuffer(b"float ", np.uint8), np.frombuffer(b"int32_t ", np.uint8)
_FLOAT_AT, _INT32_AT = np.arange(4, 10), np.arange(4, 12)
#: message types read in the definitions section
_DEF_TYPES = frozenset(b"FIMPQBALC")
#: bytes of the definitions scanned at a time for plain parameters
PLAIN_WINDOW = 1 << 16


@dataclass
class Text:
    """A logged text (``L``, or tagged ``C``) as the payload has it."""

    time_us: int
    message: str
    level: int


@dataclass
class Parsed:
    """What a ULog holds, as pyulog has it."""

    start_us: int = 0
    last_us: int = 0
    info: dict[str, InfoValue] = field(default_factory=dict)
    formats: dict[str, tuple[Field, ...]] = field(default_factory=dict)
    definitions: dict[str, bytes] = field(default_factory=dict)  # each format's own text
    basic_sizes: dict[str, int] = field(default_factory=dict)  # formats of basic types only
    initial_params: dict[str, InfoValue] = field(default_factory=dict)
    changed_params: list[tuple[int, str, InfoValue]] = field(default_factory=list)
    logged: list[Text] = field(default_factory=list)
    tagged: dict[int, list[Text]] = field(default_factory=dict)
    dropouts: list[tuple[int, int]] = field(default_factory=list)  # (time µs, duration ms)
    appended: bool = False
    corrupt: bool = False
    problems: list[str] = field(default_factory=list)
    skipped: int = 0
    truncated: int = 0
    data: list[tuple[str, int, Fields]] = field(default_factory=list)
    times: list[NDArray[np.float64]] | None = None  # each table's, where already made
    floats: bool = False  # the initial parameters are all floats already

    def problem(self, text: str) -> None:
        """Corruption found, said once per kind."""
        self.corrupt = True
        if text not in self.problems:
            self.problems.append(text)


def other_message(out: Parsed, kind: int, data: bytes, mark: int) -> None:
    """A message that is neither data nor a subscription (nor a format or a parameter of
    the definitions), into ``out``: texts, info; dropouts and parameter changes marked
    with ``mark`` (the data messages before them, or the time); sync: nothing to keep.
    Raises :class:`ShortPayload` or :class:`BadPayload` as pyulog would fail on the payload."""
    if kind == 0x4C:  # L
        if len(data) < 9:
            raise ShortPayload
        level, stamp = struct.unpack_from("<BQ", data)
        out.logged.append(Text(stamp, decode_text(data[9:]), level))
    elif kind == 0x43:  # C
        if len(data) < 11:
            raise ShortPayload
        level, tag, stamp = struct.unpack_from("<BHQ", data)
        out.tagged.setdefault(tag, []).append(Text(stamp, decode_text(data[11:]), level))
    elif kind == 0x4F:  # O
        out.dropouts.append((mark, int(unpack_value("H", data))))
    elif kind == 0x49:  # I
        _, key, value = info(data)
        out.info[key] = value
    elif kind == 0x4D:  # M
        info(data, multiple=True)
    elif kind == 0x50:  # P
        _, key, value = info(data)
        out.changed_params.append((mark, key, value))
    elif kind == 0x51:  # Q
        if not data:
            raise ShortPayload
        info(data[1:])



def garbage_end(buf: Buffer, u8: NDArray[np.uint8], q: int, known: frozenset[int],
                limit: int | None) -> int:
    """First position from ``q`` that is not an implausible header of an unknown type
    (type 0, size 0 or > 10000; in the data section also: whose message fits below
    ``limit``), which pyulog would step over one byte at a time.

    Examples
    --------
    >>> raw = bytes(40) + b"\\x01\\x00I"
    >>> garbage_end(raw, np.frombuffer(raw, np.uint8), 0, frozenset(b"I"), None)
    40
    """
    n, width = u8.size, 256
    top = n if limit is None else min(n, limit)
    for _ in range(8):  # most runs are short: a few steps in Python first
        if q + 3 > n:
            return q
        size, kind = HEAD(buf, q)
        if kind in known or (kind and size and size <= MAX_UNKNOWN_SIZE) or (
                limit is not None and q + 3 + size > top):
            return q
        q += 1
    table = np.zeros(256, bool)
    table[list(known)] = True
    while q + 3 <= n:
        hi = min(n - 2, q + width)
        t = u8[q + 2 : hi + 2]
        s = u8[q:hi].astype(np.int64) | u8[q + 1 : hi + 1].astype(np.int64) << 8
        plain = ~table[t] & ((t == 0) | (s == 0) | (s > MAX_UNKNOWN_SIZE))
        if limit is not None:
            plain &= np.arange(q, hi) + 3 + s <= min(n, limit)
        stop = np.flatnonzero(~plain)
        if stop.size:
            return q + int(stop[0])
        q, width = hi, min(width * 4, 1 << 20)
    return q


def _joined(u8: NDArray[np.uint8], start: NDArray[np.int64],
            length: NDArray[np.int64]) -> list[str] | None:
    """The texts ``u8[start:start + length]`` (UTF-8, invalid bytes dropped) decoded at
    once: None if one holds a space or a newline (the separator), or they are too long.

    Examples
    --------
    >>> u8 = np.frombuffer(b"abc de\\xff", np.uint8)
    >>> _joined(u8, np.array([0, 4]), np.array([2, 3])), _joined(u8, np.array([0]), np.array([5]))
    (['ab', 'de'], None)
    """
    total = int(length.sum())
    if total >= 1 << 24:
        return None
    owner = np.repeat(np.arange(start.size), length)
    ends = np.cumsum(length + 1)
    inner = np.arange(total) + owner  # where each byte goes, each text followed by "\n"
    text = u8[inner - (ends - length - 1)[owner] + start[owner]]
    if ((text == 10) | (text == 32)).any():
        return None
    joined = np.full(int(ends[-1]) if ends.size else 0, 10, np.uint8)
    joined[inner] = text
    # decoding the whole drops the same bytes as decoding each (the newline is ASCII)
    return joined.tobytes().decode("utf-8", "ignore").split("\n")[:-1]



class Definitions:
    """The header and definitions section of a mapped ULog (or its bytes), read into
    ``out``; :attr:`offsets`: where appended data begins (flag bits)."""

    def __init__(self, buf: Buffer, path: LogPath, out: Parsed) -> None:
        self.buf = buf
        self.u8 = np.frombuffer(buf, np.uint8)
        self.n = self.u8.size
        self.path = path
        self.out = out
        self.offsets: list[int] = []
        self.plo = self.phi = -1  # the window of plain parameters scanned (plain_run)
        self.pcand = self.pafter = self.pbreaks = np.zeros(0, np.int64)

    def read(self) -> int:
        """Read the header and the definitions; the data section's start."""
        self.header()
        return self.definitions()

    # ------------------------------------------------------------------ header
    def header(self) -> None:
        if self.n < 16:
            raise LogFormatError("not a readable ULog (Invalid file format (Header too short))",
                                 path=self.path)
        if bytes(self.buf[:7]) != MAGIC:
            raise LogFormatError("not a readable ULog (Invalid file format (Failed to parse "
                                 "header))", path=self.path)
        if self.buf[7] > 1:
            self.out.problems.append("unknown file version")
        self.out.start_us = self.out.last_us = struct.unpack_from("<Q", self.buf, 8)[0]

    # ------------------------------------------------------------------ definitions
    def definitions(self) -> int:
        """Read formats, info, parameters and flag bits; the data section's start."""
        plain: list[int] = []  # parameters with a 4-byte value, read in batches
        try:
            return self.definitions_walk(plain)
        finally:
            self.parameters(plain)

    def definitions_walk(self, plain: list[int]) -> int:
        """:meth:`definitions`' walk; the positions of parameters whose payload has room
        for a 4-byte value only are put in ``plain``, read by :meth:`parameters` before
        any other parameter (the order of the values is the file's)."""
        out, n, buf, pos = self.out, self.n, self.buf, 16
        while pos < n:
            if n - pos < 3:
                self.out.problem("file corruption detected while reading file definitions")
                return n
            size, kind = HEAD(buf, pos)
            end = pos + 3 + size
            if kind == 0x50:
                if end <= n and size == buf[pos + 3] + 5:  # the common parameter
                    pos = self.plain_run(pos, plain)
                    continue
                self.parameters(plain)
            elif kind in (0x41, 0x4C, 0x43):  # A, L, C: the data section begins
                return pos
            elif (kind == 0x4D or kind == 0x51) and end <= n and checked(buf, pos, end):
                # M, Q: only checked (the run of them that follows, at once where compiled)
                pos = end if msg.compiled is None else msg.compiled.ulog_infos(buf, end, n)
                continue
            data = self.buf[pos + 3 : min(end, n)]
            try:
                if kind == 0x49 or kind == 0x4D or kind == 0x51:  # I, M, Q
                    other_message(out, kind, data, 0)
                elif kind == 0x46:  # F
                    name, fields, size = known_format(data)
                    out.formats[name] = fields
                    out.definitions[name] = data
                    if size >= 0:
                        out.basic_sizes[name] = size
                    else:
                        out.basic_sizes.pop(name, None)
                elif kind == 0x50:  # P
                    _, key, value = info(data)
                    out.initial_params[key] = value
                elif kind == 0x42:  # B
                    self.flag_bits(pos, size, data)
                elif kind == 0 or size == 0 or size > MAX_UNKNOWN_SIZE:
                    self.out.problem("file corruption detected while reading file definitions")
                    nxt = garbage_end(self.buf, self.u8, pos + 1, _DEF_TYPES, None)
                    out.skipped += nxt - pos
                    pos = nxt
                    continue
            except (ShortPayload, BadPayload):
                self.out.problem("file corruption detected while reading file definitions")
            pos = end
        return min(pos, n)

    def plain_run(self, pos: int, plain: list[int]) -> int:
        """The run of parameters with a 4-byte value (size: key length + 5) that starts at
        ``pos`` (one): their positions put in ``plain``; the position after them. Found as
        runs of data messages are (see *Framing*): the candidates of a window of the file
        from ``pos`` (type byte ``P``, that size, the message inside the file) and where
        one's successor is not the next; each window is scanned once, the walk's later
        parameters in it looked up."""
        if not self.plo <= pos < self.phi:
            u8, n = self.u8, self.n
            hi = min(pos + PLAIN_WINDOW, n - 7)  # (a plain parameter takes 8 bytes or more)
            at = np.flatnonzero(u8[pos + 2 : hi + 2] == 0x50)
            at += pos
            size = u16(u8, at + 0).astype(np.int64)
            keep = size == u8.take(at + 3).astype(np.int64) + 5
            at = at[keep]
            after = at + 3
            after += size[keep]
            keep = after <= n
            at, after = at[keep], after[keep]
            self.pcand, self.pafter = at, after
            self.pbreaks = np.flatnonzero(np.append(after[:-1] != at[1:], True))
            self.plo, self.phi = pos, hi
        cand = self.pcand
        i = int(cand.searchsorted(pos))
        if i == cand.size or cand[i] != pos:  # (none: a window starts at a candidate)
            plain.append(pos)
            return pos + 3 + HEAD(self.buf, pos)[0]
        b = int(self.pbreaks[self.pbreaks.searchsorted(i)])
        plain += cand[i : b + 1].tolist()
        return int(self.pafter[b])

    def parameters(self, plain: list[int]) -> None:
        """The parameters at ``plain`` (whose payload is the key and a 4-byte value), in
        order, then ``plain`` emptied. When every key is ``float name`` or ``int32_t name``
        (one space), the names are gathered and decoded at once and the values read as
        arrays; otherwise each is read on its own (:meth:`parameter`)."""
        if not plain:
            return
        u8, at = self.u8, np.array(plain, np.int64)
        plain.clear()
        length = u8[at + 3].astype(np.int64)
        value = at + 4 + length
        is_float = u8[at + 4] == ord("f")  # (a byte of the key or the value: in the file)
        skip = np.where(is_float, 6, 8)  # "float " or "int32_t "
        names = None
        if (length >= skip).all() and (u8[at[is_float, None] + _FLOAT_AT] == _FLOAT).all() \
                and (u8[at[~is_float, None] + _INT32_AT] == _INT32).all():
            names = _joined(u8, at + 4 + skip, length - skip)
        if names is None:
            for p in at.tolist():
                self.parameter(p)
            return
        floats = np.ndarray((self.n - 3,), "<f4", buffer=self.buf, strides=(1,))[value]
        ints = np.ndarray((self.n - 3,), "<i4", buffer=self.buf, strides=(1,))[value]
        self.out.initial_params.update(zip(names, np.where(
            is_float, floats.astype(object), ints.astype(object)).tolist(), strict=True))

    def parameter(self, pos: int) -> None:
        """One parameter message of the definitions (pyulog's rules)."""
        try:
            _, key, value = info(self.buf[pos + 3 : pos + 3 + HEAD(self.buf, pos)[0]])
            self.out.initial_params[key] = value
        except (ShortPayload, BadPayload):
            self.out.problem("file corruption detected while reading file definitions")

    def flag_bits(self, pos: int, size: int, data: bytes) -> None:
        if pos != 16:
            self.out.problems.append("FLAGS_BITS message must be the first message")
        if size > 40:
            self.out.problems.append("flag bits message is longer than expected")
        if len(data) < 40:
            raise ShortPayload
        incompat = data[8:16]
        offsets = list(struct.unpack_from("<3Q", data, 16))
        while offsets and offsets[-1] == 0:
            offsets.pop()
        if incompat[0] & ~1 or any(incompat[1:]):
            raise LogFormatError("not a readable ULog (Unknown incompatible flag set: cannot "
                                 "parse the log)", path=self.path)
        self.out.appended = bool(incompat[0] & 1)
        self.offsets = offsets

