"""Read PX4 ULog files (``.ulg``) into a :class:`~mavsid.data.RawLog`.

The reader gives the values pyulog gives (the reference the tests compare against field by
field), ten to seventy times faster. pyulog is not used at run time. Two readers share the
work:

- *The compiled pass* (``_scan.ulog_plain``, where the package was built with a C
  compiler: see :func:`_plain`) reads a log with nothing unusual in it in one go:
  definitions, formats flattened to record layouts, subscriptions, every data message
  gathered into its topic's records, each table's times; it accounts for the commonest
  damage as the Python reader does (data messages without subscription or of a wrong
  size skipped, an implausible header followed by a sync magic, a sync magic inside a
  message of an unknown type). The few info, text, dropout and parameter-change messages
  are read by the Python reader's code. Anything else (a message cut inside the
  definitions, a format or parameter that does not parse plainly, garbage without a sync
  magic after it, a repeated subscription, a payload too short for its fields, odd
  appended-data offsets, more fields than a read keeps) and it returns nothing and:
- *the Python reader* (:class:`_Reader`), pyulog's rules on damaged files one by one, reads
  the log: definitions and every message that is not topic data are parsed in Python; the
  data messages (``D``, nearly all of a log) are framed by a compiled loop (or numpy) and
  decoded with numpy.

Where the first returns, the second returns the same (tests: every shared and simulated
log, and logs damaged at random, read both ways; every ULog test runs three ways: the
compiled pass, the Python reader with the compiled walk, and with numpy's).

A table's columns are strided views over its records' bytes (:class:`_Fields`: no
structured dtype is built), made when first asked for: most of a log's hundred topics and
thousands of fields are never looked at. The file is mapped.

For the Python reader on a small log the fixed costs weigh most: a thousand or two
definition messages and a hundred topics. They are kept down so: the plain parameters
(``float`` or ``int32_t`` key, 4-byte value: nearly all) are found in runs, as data
messages are (see *Framing*), and decoded in one batch, names at once and values as arrays;
``M`` and ``Q`` messages, which are only checked, are seen without decoding when plainly
valid; a format's size is summed as its fields are parsed; a topic's layout is built once
per read; the times of all tables are converted, and checked for running backwards, in one
go.

What the returned log holds:

- one table per topic instance: ``topic`` for ``multi_id`` 0, ``topic[N]`` otherwise, with
  pyulog's field names (``timestamp``, ``xyz[0]``, ``q[3]``, nested ``a.b``; padding fields
  kept, except those at the end of a format, which pyulog drops);
- ``time_s``: ``timestamp_sample`` where the topic has it (when the sensor sampled), else
  ``timestamp`` (when it was published), µs → s on the vehicle's boot clock;
- ``params``: the initial parameters, updated by every parameter change in the log;
- ``texts``: logged (and tagged logged) messages, ``severity`` the syslog level 0–7;
- ``modes``: each change of ``vehicle_status.nav_state``, named by PX4's ``NAVIGATION_STATE``;
- ``SourceInfo.notes``: dropouts (count and total length), appended (crash-dump) data,
  parameter changes, topics whose time runs backwards, corruption found, and a last
  message cut off by the end of the file; ``SourceInfo.skipped_bytes`` counts the bytes
  stepped over to resynchronise, those of data messages that could not be decoded (wrong
  size, no subscription) and a truncated last message.

Framing
-------
ULog has no sync bytes in its data stream: a message is ``uint16 size, uint8 type`` and
``size`` bytes of payload, and the next one starts right after it. The file is read as
pyulog reads it, one message after the other from the end of the definitions, but the
runs of consecutive data messages are taken in one step:

1. *Candidates*: every position ``p`` whose type byte ``p+2`` is ``'D'``, whose ``size``
   is one a data message of some format defined in the file can have (the format's size
   + 2, with or without its trailing padding; the message id is not looked at: the
   subscriptions are only known as the walk meets them), whose message ends inside
   the file and is followed by the header of a known message type (or the file's end).
   Its successor is ``next = p + 3 + size``. A candidate may be false (the byte pattern
   inside some payload) and a real message may be no candidate (a damaged one): both
   only cost Python steps, never correctness.
   Candidates are found one 1 MB block of the file at a time, when the walk reaches it,
   so that their arrays stay small whatever the file holds.
2. *Runs*: ``follows[i]`` is true when candidate ``i``'s successor is candidate ``i+1``.
   If candidate ``i`` is a true message start and ``follows[i]``, so is candidate ``i+1``
   (it is where the next message starts); by induction every candidate from ``i`` up to
   the first index ``b >= i`` with ``follows[b]`` false is a true message, in file
   order. One ``searchsorted`` finds ``b``; the run ``i..b`` is decoded at once.
   A break between candidates ``i`` and ``i+1`` is bridged when the messages from ``i``'s
   successor up to candidate ``i+1``, one right after the other, carry nothing the walk
   keeps: sync messages (any payload) and ``M``/``Q`` messages :func:`_checked` accepts
   (checked in Python, one step each, but the run goes on); the same induction holds.
3. *Steps*: at the end of a run (or at a position that is no candidate) one message is
   read in Python, with pyulog's rules: subscriptions, texts, parameters, dropouts, sync
   messages, a data message with no other (nor a sync, ``M`` or ``Q`` message) right
   after it (no run to look for: kept in a list, checked with the others at the end);
   an unknown type with an implausible header (type 0, size 0 or > 10000) resynchronises
   at the next sync message's magic, else (no sync in the rest of the file) one byte
   further; a message cut by the end of the file ends the read. The walk then goes on at
   the next position, which may start a run.

Where the package was built with a C compiler (``setup.py``), steps 1 and 2 are one compiled
loop instead (``_scan.ulog_data``): from a data message, the messages one after the other,
data messages written out, sync messages and the ``M`` / ``Q`` messages :func:`_checked`
accepts stepped over (as runs go on across them above), up to the first message of another
type, which step 3 reads; no candidates, no false ones. Same framing, same values (the tests
run both ways); ~1.15x faster on the shared logs, ~1.35x on a 100-MB flight.

Every position the walk visits is one pyulog visits, so the framing is pyulog's exactly.
The Python steps are as many as the messages that are not data plus the false candidates
inside the walked range (none in the shared real logs); in the worst case
(a hostile file made of false candidates or tiny unknown messages) the walk is one Python
step per message, like pyulog: linear, never endless (every step moves forward). Runs of
implausible headers (garbage) are skipped in vectorised windows.

Data messages are then grouped by subscription and gathered with one fancy index into a
view of the file as raw records of the topic's size at every byte (``np.ndarray(...,
strides=(1,))``, as ``void`` records), so each topic is one copy of its records. A data message
counts if its id is subscribed at that point and its size is exactly the format's; the
others are skipped and flagged as corruption, as pyulog does. pyulog's quirks on damaged
files are kept so that its values stay the reference there too: the data of each section
read (several with appended data) are taken at its end, a re-subscribed id keeps only its
last subscription's data, and a record of a topic without room for an 8-byte timestamp (a
damaged ``timestamp`` name) ends the section. Departures, on hostile files only: a message
that claims to reach back before itself (a corrupt header near the end of the definitions)
moves the read one byte forward, where pyulog may read the same bytes again; a format that
flattens to more fields than a data message can hold bytes (nested arrays) is an unreadable
subscription instead of minutes of expansion.

The Python reader keeps formats parsed and record layouts for the process (within a budget
of fields, :class:`_Kept`), keyed by the texts of a topic's format and of every format it
nests: the logs of one firmware repeat them, so a batch parses each once; two logs that
define a type differently never share a layout.

Bad input is one :class:`~mavsid.errors.LogFormatError` naming the file: a bad header,
incompatible flags, formats that contain themselves (pyulog would recurse without end)
or nest too deeply, an empty log. A file with corruption is returned with what could be
decoded and one :class:`~mavsid.errors.DataQualityWarning`.

Examples
--------
>>> import os, tempfile
>>> with tempfile.NamedTemporaryFile(suffix=".ulg", delete=False) as f:
...     _ = f.write(b"ULog\\x01\\x12\\x35\\x01" + bytes(4))
>>> read(f.name)
Traceback (most recent call last):
...
mavsid.errors.LogFormatError: ...: not a readable ULog (Invalid file format (Header too short))
>>> os.unlink(f.name)
"""

from __future__ import annotations

import functools
import itertools
import math
import mmap
import os
import re
import struct
import threading
import warnings
from collections.abc import Callable, Hashable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from types import ModuleType
from typing import Any, Generic, TypeVar

import numpy as np
from numpy.typing import NDArray

from mavsid.autopilot.modes import NAV_STATES
from mavsid.data import MessageTable, ModeChange, RawLog, SourceInfo, TextMessage
from mavsid.errors import DataQualityWarning, LogFormatError, first_few
from mavsid.readers.tlog import vehicle_class
from mavsid.readers.ulog_spec import BASIC_TYPES, MAGIC, SYNC

_scan: ModuleType | None
try:  # the data walk compiled (setup.py); absent where the package was built without a C
    from mavsid.readers import _scan  # compiler: then the candidates and runs of *Framing*
except ImportError:  # pragma: no cover - depends on the build
    _scan = None

__all__ = ["NAV_STATES", "read", "table_name"]

_MODE_TOPIC = "vehicle_status"
_STAMPS = ("timestamp", "timestamp_sample")  # (fields in µs)
_INSTANCE = re.compile(r"^(.*)\[(\d+)\]$")

#: a parameter key's type as the payload has it (after size, type and key length)
_FLOAT, _INT32 = np.frombuffer(b"float ", np.uint8), np.frombuffer(b"int32_t ", np.uint8)
_FLOAT_AT, _INT32_AT = np.arange(4, 10), np.arange(4, 12)
#: bytes of each basic type
_SIZE = {kind: t.size for kind, t in BASIC_TYPES.items()}
#: little-endian numpy dtypes of the basic types; each type's code (its place in
#: BASIC_TYPES, the code ``_scan.ulog_plain`` gives) and the dtype of each code
_DTYPE = {kind: t.dtype for kind, t in BASIC_TYPES.items()}
_CODE = {kind: code for code, kind in enumerate(BASIC_TYPES)}
_BY_CODE = tuple(_DTYPE.values())
_WIDTH = tuple(_SIZE.values())
#: message types read in the definitions section / in the data section
_DEF_TYPES = frozenset(b"FIMPQBALC")
_DATA_TYPES = frozenset(b"IMPQALCDOS")
_HEAD = struct.Struct("<HB").unpack_from
_KNOWN_TYPE = np.zeros(256, bool)
_KNOWN_TYPE[list(b"FDIMPQARLCOSB")] = True
#: types of the messages a run of data messages may cross (see :meth:`_Reader.bridged`)
_CARRIER = np.zeros(256, bool)
_CARRIER[list(b"SMQ")] = True
#: a data message followed by one of these types may start a run
_RUN_ON = _CARRIER.copy()
_RUN_ON[0x44] = True
#: an unknown message type with a size above this is taken as corruption (pyulog's rule)
_MAX_UNKNOWN_SIZE = 10000
#: a format flattening to more fields than a data message can hold bytes is never decoded
_MAX_FIELDS = 0xFFFF
#: fields of the parsed formats, and of the record layouts, kept per process (see _Kept)
_KEPT_FIELDS = 1 << 19
_NO_LIMIT = 1 << 62
#: bytes of the file scanned at a time for message candidates
_BLOCK = 1 << 20
#: bytes of the definitions scanned at a time for plain parameters
_PLAIN_WINDOW = 1 << 16
#: runs of data messages kept apart before they are joined (bounds the memory per run)
_MAX_CHUNKS = 4096
#: data messages the compiled walk writes out per call (its output arrays' length)
_WALK_ROOM = 1 << 16
#: read the logs with nothing unusual in one compiled pass (see _plain); off: _Reader only
_PLAIN = True
_LOST = "no subscription found for message id {}"


def table_name(topic: str, multi_id: int) -> str:
    """The table name of one topic instance.

    Examples
    --------
    >>> table_name("actuator_outputs", 0), table_name("actuator_outputs", 1)
    ('actuator_outputs', 'actuator_outputs[1]')
    """
    return topic if multi_id == 0 else f"{topic}[{multi_id}]"


# ------------------------------------------------------------------ message payloads
class _Stop(Exception):
    """A payload too short for its fixed fields: pyulog's ``struct.error``, which ends the
    section being read (in the definitions: counted as corruption)."""


class _Bad(Exception):
    """A payload that does not parse (pyulog's IndexError, KeyError, ValueError): the
    message is skipped and the file marked corrupt."""


Field = tuple[str, int, str]  # type, array size (0: scalar), name


def _text(raw: bytes) -> str:
    return raw.decode("utf-8", "ignore")


def _unpack(code: str, raw: bytes) -> Any:
    if len(raw) != struct.calcsize("<" + code):
        raise _Stop
    return struct.unpack("<" + code, raw)[0]


def _info(data: bytes, multiple: bool = False) -> tuple[str, str, Any]:
    """An info, info-multiple or parameter payload: (type, key, value).

    Examples
    --------
    >>> _info(bytes([13]) + b"float MC_RATE" + struct.pack("<f", 0.5))
    ('float', 'MC_RATE', 0.5)
    >>> _info(bytes([14]) + b"char[3] ver_hw" + b"abc")[2]
    'abc'
    """
    if multiple:
        data = data[1:]
    if not data:
        raise _Stop
    words = _text(data[1 : 1 + data[0]]).split(" ")
    if len(words) < 2:
        raise _Bad
    kind, key, raw = words[0], words[1], data[1 + data[0] :]
    if kind.startswith("char["):
        return kind, key, _text(raw)
    if kind in BASIC_TYPES:
        return kind, key, _unpack(BASIC_TYPES[kind].code, raw)
    return kind, key, raw  # an array or a damaged type: raw bytes, as pyulog keeps them


def _checked(buf: Any, pos: int, end: int) -> bool:
    """Whether the ``M`` or ``Q`` message at ``pos`` (a byte, then an info: key length,
    key ``type name``, value) is one pyulog reads without error, seen without decoding it:
    a text (type ``char[N]``) or a 4-byte parameter value. False: not known to be.

    Examples
    --------
    >>> _checked(b"\\0\\0M" + bytes([0, 9]) + b"char[1] ab", 0, 15)
    True
    >>> _checked(b"\\0\\0Q" + bytes([0, 7]) + b"float x" + bytes(4), 0, 16)
    True
    >>> _checked(b"\\0\\0Q" + bytes([0, 7]) + b"float x" + bytes(3), 0, 15)
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


_A = TypeVar("_A", bound=Hashable)
_R = TypeVar("_R")


class _Kept(Generic[_A, _R]):
    """``fn`` with its results kept for the process, within a budget: each result weighs
    ``weight(result)`` (its fields), the oldest are dropped when the total would pass
    ``budget``, one heavier than the budget is not kept. Logs of one firmware repeat the
    same definitions (10 of the 13 shared ULogs share most of theirs), and a hostile
    stream of huge formats cannot grow the memory without bound.

    Examples
    --------
    >>> twice = _Kept(lambda x: 2 * x, weight=lambda r: r, budget=10)
    >>> twice(3), twice(4), twice.total, twice(2), twice.total, twice(9), twice.total
    (6, 8, 8, 4, 4, 18, 4)
    """

    def __init__(self, fn: Callable[[_A], _R], weight: Callable[[_R], int],
                 budget: int = _KEPT_FIELDS) -> None:
        self.fn, self.weight, self.budget = fn, weight, budget
        self.kept: dict[_A, tuple[_R, int]] = {}
        self.total = 0
        self.lock = threading.Lock()  # (logs read in threads: a threaded Dask worker)
        functools.update_wrapper(self, fn)

    def __call__(self, arg: _A) -> _R:
        got = self.kept.get(arg)
        if got is not None:
            return got[0]
        result = self.fn(arg)
        w = self.weight(result)
        if w <= self.budget:
            with self.lock:
                if arg not in self.kept:
                    while self.kept and self.total + w > self.budget:
                        self.total -= self.kept.pop(next(iter(self.kept)))[1]
                    self.kept[arg] = result, w
                    self.total += w
        return result

    def clear(self) -> None:
        with self.lock:
            self.kept.clear()
            self.total = 0


@functools.lru_cache(maxsize=64)
def _indices(count: int) -> tuple[str, ...]:
    """The array suffixes ``[0]`` ... ``[count - 1]`` of a flattened field's names.

    Examples
    --------
    >>> _indices(3)
    ('[0]', '[1]', '[2]')
    """
    return tuple(f"[{i}]" for i in range(count))


def _parse_format(data: bytes) -> tuple[str, tuple[Field, ...], int]:
    """A format definition ``name:type field;type[n] field;...``: its name, fields and
    size in bytes when all its fields are of basic types (else -1: nested formats, sized
    by :func:`_widths`). Kept for the process as :func:`_format`.

    Examples
    --------
    >>> _format(b"att:uint64_t timestamp;float[4] q;")
    ('att', (('uint64_t', 0, 'timestamp'), ('float', 4, 'q')), 24)
    >>> _format(b"esc:uint64_t timestamp;report[2] r;")[2]
    -1
    """
    parts = _text(data).split(":")
    if len(parts) < 2:
        raise _Bad
    fields = []
    size = 0
    for item in parts[1].split(";"):
        if not item:
            continue
        kind, space, rest = item.partition(" ")
        if not space:
            raise _Bad
        name = rest.partition(" ")[0]  # the second word, as pyulog takes it
        a = kind.find("[")
        if a < 0:
            fields.append((kind, 0, name))
            width = _SIZE.get(kind)
            size = -1 if width is None or size < 0 else size + width
            continue
        try:
            count = int(kind[a + 1 : kind.find("]")])
        except ValueError:
            raise _Bad from None
        if not 0 <= count <= 0xFFFF:
            raise _Bad
        kind = kind[:a]
        fields.append((kind, count, name))
        width = _SIZE.get(kind)
        size = -1 if width is None or size < 0 else size + width * (count or 1)
    return parts[0], tuple(fields), size


def _parsed_format(data: bytes) -> tuple[str, tuple[Field, ...], int]:
    """:func:`_parse_format`, compiled where the package was (``_scan.ulog_format``: the
    same objects, ~2.6x faster: building them is most of the rest; the tests compare the
    two)."""
    if _scan is None:
        return _parse_format(data)
    try:
        return _scan.ulog_format(data, _SIZE)
    except ValueError:
        raise _Bad from None


_format = _Kept(_parsed_format, weight=lambda parsed: len(parsed[1]) + 1)


def _u16(u8: NDArray[np.uint8], at: NDArray[np.int64]) -> NDArray[np.uint16]:
    """The little-endian ``uint16`` at each byte position ``at`` (``at`` is reused).

    Examples
    --------
    >>> _u16(np.array([1, 2, 3], np.uint8), np.array([0, 1]))
    array([513, 770], dtype=uint16)
    """
    low = u8.take(at).astype(np.uint16)
    at += 1
    low |= u8.take(at).astype(np.uint16) << 8
    return low


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


def _cycle(formats: Mapping[str, Sequence[Field]]) -> list[str] | None:
    """A chain of formats that contain themselves (``a`` → ``b`` → ``a``); None if none.

    Examples
    --------
    >>> _cycle({"a": [("b", 0, "x")], "b": [("a", 2, "y")]})
    ['a', 'b', 'a']
    >>> _cycle({"a": [("float", 0, "x")]}) is None
    True
    """
    graph = {name: {kind for kind, _, _ in fields if kind not in BASIC_TYPES}
             for name, fields in formats.items()}  # fmt: skip
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def visit(node: str, chain: list[str]) -> list[str] | None:
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return [*chain, node, nxt][[*chain, node].index(nxt) :]
            if nxt in graph and state.get(nxt) is None and (got := visit(nxt, [*chain, node])):
                return got
        state[node] = 2
        return None

    for start in sorted(graph):
        if state.get(start) is None and (found := visit(start, [])):
            return found
    return None


def _widths(formats: Mapping[str, Sequence[Field]], basic: dict[str, int]) -> dict[str, int]:
    """Each format's size in bytes (formats acyclic; a nested type not defined counts 0).
    ``basic``: the sizes of the formats of basic types only, known from :func:`_format`
    (the others are summed here).

    Examples
    --------
    >>> _widths({"b": [("a", 2, "x"), ("float", 0, "y")], "a": [("uint8_t", 3, "z")]}, {"a": 3})
    {'a': 3, 'b': 10}
    """
    memo = dict(basic)

    def size(name: str) -> int:
        got = memo.get(name)
        if got is None:
            got = 0
            for kind, count, _ in formats.get(name, ()):
                width = _SIZE.get(kind)
                got += (size(kind) if width is None else width) * (count or 1)
            memo[name] = got
        return got

    for name in formats:
        size(name)
    return memo


def _sizes(formats: Mapping[str, Sequence[Field]], widths: dict[str, int]) -> set[int]:
    """The payload sizes data messages of the formats can have: 2 (message id) + a
    format's size (``widths``, from :func:`_widths`), with and without its trailing
    ``_padding`` fields.

    Examples
    --------
    >>> a = [("uint64_t", 0, "timestamp"), ("uint8_t", 3, "_padding0")]
    >>> sorted(_sizes({"a": a}, {"a": 11}))
    [10, 13]
    """
    out: set[int] = set()
    for name, fields in formats.items():
        full = trimmed = widths[name]
        for kind, n, fname in reversed(fields):
            width = _SIZE.get(kind)
            width = (widths.get(kind, 0) if width is None else width) * (n or 1)
            if width and not fname.startswith("_padding"):
                break
            trimmed -= width
        out.update(s + 2 for s in (full, trimmed) if 0 < s <= 0xFFFF - 2)
    return out


_Key = tuple[tuple[str, "bytes | None"], ...]


def _closure(name: str, formats: Mapping[str, Sequence[Field]],
             definitions: Mapping[str, bytes]) -> _Key:
    """What a topic's layout depends on: its format's text and those of the formats it
    nests (None for one not defined), in a fixed order: the key of :func:`_layout`.

    Examples
    --------
    >>> fmts = {"a": (("b", 2, "x"),), "b": (("float", 0, "y"),)}
    >>> _closure("a", fmts, {"a": b"a:b[2] x;", "b": b"b:float y;"})
    (('a', b'a:b[2] x;'), ('b', b'b:float y;'))
    >>> _closure("a", {"a": (("c", 0, "z"),)}, {"a": b"a:c z;"})
    (('a', b'a:c z;'), ('c', None))
    """
    key: list[tuple[str, bytes | None]] = []
    seen: set[str] = set()
    stack = [name]
    while stack:
        node = stack.pop()
        if node in seen:
            continue
        seen.add(node)
        text = definitions.get(node)
        key.append((node, text))
        if text is not None:
            stack += [kind for kind, _, _ in reversed(formats[node]) if kind not in _SIZE]
    return tuple(key)


#: a record layout: field names, their types' codes (see _CODE), offsets, the record's
#: size, name -> index (see :func:`_index`), and the time fields it has (of _STAMPS);
#: ``_scan.ulog_plain`` makes the same
_Layout = tuple[tuple[str, ...], bytes, tuple[int, ...], int, dict[str, int], tuple[str, ...]]


def _new_layout(key: _Key) -> _Layout:
    """A topic's record layout from its :func:`_closure`: field names (nested types and
    arrays expanded; an empty one named ``f<index>``, as pyulog's dtype has it), their
    basic types' codes and offsets, the record's size and the names' index, trailing
    padding dropped; kept for the process as :func:`_layout`. Raises KeyError (a nested
    type not defined), ValueError (repeated field names, which numpy refuses) or
    :class:`_Bad` (more fields than a message can hold bytes).

    Examples
    --------
    >>> names, codes, offsets, size, index, stamps = _new_layout((
    ...     ("a", b"a:uint64_t timestamp;b[2] r;uint8_t[2] _padding0;"),
    ...     ("b", b"b:float y;uint8_t _padding0;")))
    >>> names
    ('timestamp', 'r[0].y', 'r[0]._padding0', 'r[1].y', 'r[1]._padding0')
    >>> list(codes), offsets, size
    ([7, 8, 1, 8, 1], (0, 8, 12, 13, 17), 18)
    """
    formats = {}
    for node, text in key:
        if text is not None:
            formats[node] = _format(text)[1]
    flat: dict[str, tuple[list[str], list[int]]] = {}

    def flatten(name: str) -> tuple[list[str], list[int]]:
        got = flat.get(name)
        if got is not None:
            return got
        names: list[str] = []
        kinds: list[int] = []
        for kind, count, fname in formats[name]:  # KeyError: an unknown type
            code = _CODE.get(kind)
            if code is not None:
                if not count:
                    names.append(fname)
                    kinds.append(code)
                    continue
                if len(names) + count > _MAX_FIELDS:
                    raise _Bad
                names += map(fname.__add__, _indices(count))
                kinds += [code] * count
                continue
            inner, inner_kinds = flatten(kind)
            prefixes = [fname + index + "." for index in _indices(count)] if count else [
                fname + "."]
            if len(names) + len(prefixes) * len(inner) > _MAX_FIELDS:
                raise _Bad
            names += [prefix + sub for prefix in prefixes for sub in inner]
            kinds += inner_kinds * len(prefixes)
        flat[name] = names, kinds
        return names, kinds

    name = key[0][0]
    names, kinds = flatten(name)
    m = len(names)
    while m and names[m - 1].startswith("_padding"):
        m -= 1
    names, kinds = names[:m], kinds[:m]
    if "" in names:
        names = [f or f"f{i}" for i, f in enumerate(names)]
    index = {f: i for i, f in enumerate(names)}
    if len(index) < m:
        raise ValueError(name)
    ends = np.cumsum([_WIDTH[k] for k in kinds]).tolist()
    size = ends[-1] if ends else 0  # (the format's size less the padding dropped)
    stamps = tuple(k for k in _STAMPS if k in index)
    return tuple(names), bytes(kinds), (0, *ends[:-1]) if ends else (), size, index, stamps


def _index(layout: _Layout) -> dict[str, int]:
    """A layout's field name -> index, made on first use where the compiled pass left it
    empty (most of a log's topics are never looked at by name); shared by the topic's
    tables.

    Examples
    --------
    >>> layout = (("a", "b"), b"\x08\x08", (0, 4), 8, {}, ())
    >>> _index(layout), layout[4]
    ({'a': 0, 'b': 1}, {'a': 0, 'b': 1})
    """
    index = layout[4]
    if len(index) < len(layout[0]):
        index.update({name: at for at, name in enumerate(layout[0])})
    return index


_layout = _Kept(_new_layout, weight=lambda layout: len(layout[0]) + 1)


def _stamp_offset(layout: _Layout) -> int:
    """Bytes before a record's ``timestamp`` (its size if it has none)."""
    at = _index(layout).get("timestamp")
    return layout[3] if at is None else layout[2][at]


@dataclass
class _Sub:
    """One subscription (``A`` message): a topic instance's message id and record layout."""

    msg_id: int
    multi_id: int
    name: str
    size: int  # the record size
    ts_offset: int  # bytes before ``timestamp`` (the record size if there is none)


@dataclass
class _Text:
    time_us: int
    message: str
    level: int


@dataclass
class _Parsed:
    """What a ULog holds, as pyulog has it."""

    start_us: int = 0
    last_us: int = 0
    info: dict[str, Any] = field(default_factory=dict)
    formats: dict[str, tuple[Field, ...]] = field(default_factory=dict)
    definitions: dict[str, bytes] = field(default_factory=dict)  # each format's own text
    basic_sizes: dict[str, int] = field(default_factory=dict)  # formats of basic types only
    initial_params: dict[str, Any] = field(default_factory=dict)
    changed_params: list[tuple[int, str, Any]] = field(default_factory=list)
    logged: list[_Text] = field(default_factory=list)
    tagged: dict[int, list[_Text]] = field(default_factory=dict)
    dropouts: list[tuple[int, int]] = field(default_factory=list)  # (time µs, duration ms)
    appended: bool = False
    corrupt: bool = False
    problems: list[str] = field(default_factory=list)
    skipped: int = 0
    truncated: int = 0
    data: list[tuple[str, int, _Fields]] = field(default_factory=list)
    times: list[NDArray[np.float64]] | None = None  # each table's, where already made
    floats: bool = False  # the initial parameters are all floats already


class _Fields(Mapping[str, NDArray[Any]]):
    """A topic's columns over its records' bytes (``count`` records of the layout's size,
    one after the other, in any buffer: an array, a bytearray): field name -> that field of
    every record (a strided view, of the field's dtype), made when first asked for; no
    structured dtype is built.

    Examples
    --------
    >>> layout = _new_layout((("a", b"a:uint64_t timestamp;float x;"),))
    >>> raw = np.frombuffer(np.array([(1, 0.5), (2, 1.5)], "<u8,<f4").tobytes(), np.uint8)
    >>> cols = _Fields(raw, 2, layout)
    >>> list(cols), cols["x"].tolist(), len(cols), cols.rows(np.array([False, True]))["timestamp"]
    (['timestamp', 'x'], [0.5, 1.5], 2, array([2], dtype=uint64))
    """

    __slots__ = ("_views", "count", "layout", "raw")

    def __init__(self, raw: NDArray[np.uint8] | bytearray, count: int, layout: _Layout) -> None:
        self.raw, self.count, self.layout = raw, count, layout
        self._views: dict[str, NDArray[Any]] = {}

    def __getitem__(self, name: str) -> NDArray[Any]:
        try:
            return self._views[name]
        except KeyError:
            at = _index(self.layout).get(name) if isinstance(name, str) else None
            if at is None:
                raise KeyError(name) from None
            _, codes, offsets, size, _, _ = self.layout
            dtype = _BY_CODE[codes[at]]
            view = self._views[name] = np.ndarray(
                (self.count,), dtype, buffer=self.raw, offset=offsets[at], strides=(size,)
            ) if self.count else np.zeros(0, dtype)
            return view

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and name in _index(self.layout)

    def __iter__(self) -> Iterator[str]:
        return iter(self.layout[0])

    def __len__(self) -> int:
        return len(self.layout[0])

    def __repr__(self) -> str:
        return f"_Fields({list(self)!r})"

    def __reduce__(self) -> tuple[Any, ...]:
        return (_Fields, (self.raw, self.count, self.layout))

    def rows(self, keep: NDArray[np.bool_]) -> _Fields:
        """The records where ``keep`` holds."""
        if not self.count:
            return self
        raw = np.frombuffer(self.raw, np.uint8).reshape(self.count, -1)[keep]
        return _Fields(raw.reshape(-1), len(raw), self.layout)


def _other(out: _Parsed, kind: int, data: bytes, mark: int) -> None:
    """A message that is neither data nor a subscription (nor a format or a parameter of
    the definitions), into ``out``: texts, info; dropouts and parameter changes marked
    with ``mark`` (the data messages before them, or the time); sync: nothing to keep.
    Raises :class:`_Stop` or :class:`_Bad` as pyulog would fail on the payload."""
    if kind == 0x4C:  # L
        if len(data) < 9:
            raise _Stop
        level, stamp = struct.unpack_from("<BQ", data)
        out.logged.append(_Text(stamp, _text(data[9:]), level))
    elif kind == 0x43:  # C
        if len(data) < 11:
            raise _Stop
        level, tag, stamp = struct.unpack_from("<BHQ", data)
        out.tagged.setdefault(tag, []).append(_Text(stamp, _text(data[11:]), level))
    elif kind == 0x4F:  # O
        out.dropouts.append((mark, _unpack("H", data)))
    elif kind == 0x49:  # I
        _, key, value = _info(data)
        out.info[key] = value
    elif kind == 0x4D:  # M
        _info(data, multiple=True)
    elif kind == 0x50:  # P
        _, key, value = _info(data)
        out.changed_params.append((mark, key, value))
    elif kind == 0x51:  # Q
        if not data:
            raise _Stop
        _info(data[1:])


class _Reader:
    """One pass over a mapped ULog (see the module's *Framing*)."""

    def __init__(self, buf: Any, path: str | os.PathLike[str], topics: set[str] | None) -> None:
        self.buf = buf  # the mmap (bytes-like, with .find)
        self.u8 = np.frombuffer(buf, np.uint8)
        self.n = self.u8.size
        self.path = path
        self.topics = topics
        self.out = _Parsed()
        self.has_sync = True
        self.offsets: list[int] = []  # appended data (flag bits)
        # subscriptions: all seen; the active one per message id (-1 none); filtered ids
        self.subs: list[_Sub] = []
        self.active: dict[int, int] = {}  # message id -> subscription, in first order
        # message id -> active subscription, -2 filtered out (topics not asked for), -1 none
        self.lookup = np.full(1 << 16, -1, np.int32)
        self.filtered: set[int] = set()
        self.untimed: dict[int, int] = {}  # subscription -> record size, without timestamp
        self.final: list[int] = []  # subscriptions whose data is kept, pyulog's order
        self.keys: dict[str, _Key] = {}  # topic -> its layout's key (_closure)
        self.plo = self.phi = -1  # the window of plain parameters scanned (plain_run)
        self.pcand = self.pafter = self.pbreaks = np.zeros(0, np.int64)
        # data messages met: (positions, sizes, ids, their subscriptions), and how many
        self.chunks: list[tuple[NDArray[Any], NDArray[Any], NDArray[Any], NDArray[np.int32]]]
        self.chunks = []
        self.pending: list[tuple[int, int, int, int]] = []
        self.count = self.taken = 0
        self.room: tuple[NDArray[np.int64], NDArray[np.uint16], NDArray[np.uint16]] | None = None
        self.u64 = (np.ndarray((self.n - 7,), "<u8", buffer=buf, strides=(1,))
                    if self.n >= 8 else np.zeros(0, np.uint64))  # fmt: skip

    # ------------------------------------------------------------------ diagnostics
    def problem(self, text: str) -> None:
        self.out.corrupt = True
        if text not in self.out.problems:
            self.out.problems.append(text)

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

    # ------------------------------------------------------------------ garbage
    def garbage_end(self, q: int, known: frozenset[int], limit: int | None) -> int:
        """First position from ``q`` that is not an implausible header of an unknown type
        (type 0, size 0 or > 10000; in the data section also: whose message fits below
        ``limit``), which pyulog would step over one byte at a time."""
        u8, n, width = self.u8, self.n, 256
        top = n if limit is None else min(n, limit)
        for _ in range(8):  # most runs are short: a few steps in Python first
            if q + 3 > n:
                return q
            size, kind = _HEAD(self.buf, q)
            if kind in known or (kind and size and size <= _MAX_UNKNOWN_SIZE) or (
                    limit is not None and q + 3 + size > top):
                return q
            q += 1
        table = np.zeros(256, bool)
        table[list(known)] = True
        while q + 3 <= n:
            hi = min(n - 2, q + width)
            t = u8[q + 2 : hi + 2]
            s = u8[q:hi].astype(np.int64) | u8[q + 1 : hi + 1].astype(np.int64) << 8
            plain = ~table[t] & ((t == 0) | (s == 0) | (s > _MAX_UNKNOWN_SIZE))
            if limit is not None:
                plain &= np.arange(q, hi) + 3 + s <= min(n, limit)
            stop = np.flatnonzero(~plain)
            if stop.size:
                return q + int(stop[0])
            q, width = hi, min(width * 4, 1 << 20)
        return q

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
                self.problem("file corruption detected while reading file definitions")
                return n
            size, kind = _HEAD(buf, pos)
            end = pos + 3 + size
            if kind == 0x50:
                if end <= n and size == buf[pos + 3] + 5:  # the common parameter
                    pos = self.plain_run(pos, plain)
                    continue
                self.parameters(plain)
            elif kind in (0x41, 0x4C, 0x43):  # A, L, C: the data section begins
                return pos
            elif (kind == 0x4D or kind == 0x51) and end <= n and _checked(buf, pos, end):
                # M, Q: only checked (the run of them that follows, at once where compiled)
                pos = end if _scan is None else _scan.ulog_infos(buf, end, n)
                continue
            data = self.buf[pos + 3 : min(end, n)]
            try:
                if kind == 0x49 or kind == 0x4D or kind == 0x51:  # I, M, Q
                    _other(out, kind, data, 0)
                elif kind == 0x46:  # F
                    name, fields, size = _format(data)
                    out.formats[name] = fields
                    out.definitions[name] = data
                    if size >= 0:
                        out.basic_sizes[name] = size
                    else:
                        out.basic_sizes.pop(name, None)
                elif kind == 0x50:  # P
                    _, key, value = _info(data)
                    out.initial_params[key] = value
                elif kind == 0x42:  # B
                    self.flag_bits(pos, size, data)
                elif kind == 0 or size == 0 or size > _MAX_UNKNOWN_SIZE:
                    self.problem("file corruption detected while reading file definitions")
                    nxt = self.garbage_end(pos + 1, _DEF_TYPES, None)
                    out.skipped += nxt - pos
                    pos = nxt
                    continue
            except (_Stop, _Bad):
                self.problem("file corruption detected while reading file definitions")
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
            hi = min(pos + _PLAIN_WINDOW, n - 7)  # (a plain parameter takes 8 bytes or more)
            at = np.flatnonzero(u8[pos + 2 : hi + 2] == 0x50)
            at += pos
            size = _u16(u8, at + 0).astype(np.int64)
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
            return pos + 3 + _HEAD(self.buf, pos)[0]
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
            _, key, value = _info(self.buf[pos + 3 : pos + 3 + _HEAD(self.buf, pos)[0]])
            self.out.initial_params[key] = value
        except (_Stop, _Bad):
            self.problem("file corruption detected while reading file definitions")

    def flag_bits(self, pos: int, size: int, data: bytes) -> None:
        if pos != 16:
            self.out.problems.append("FLAGS_BITS message must be the first message")
        if size > 40:
            self.out.problems.append("flag bits message is longer than expected")
        if len(data) < 40:
            raise _Stop
        incompat = data[8:16]
        offsets = list(struct.unpack_from("<3Q", data, 16))
        while offsets and offsets[-1] == 0:
            offsets.pop()
        if incompat[0] & ~1 or any(incompat[1:]):
            raise LogFormatError("not a readable ULog (Unknown incompatible flag set: cannot "
                                 "parse the log)", path=self.path)
        self.out.appended = bool(incompat[0] & 1)
        self.offsets = offsets

    # ------------------------------------------------------------------ candidates
    def candidates(self, start: int) -> None:
        """Prepare the data-message candidates (see *Framing*): the sizes the file's
        subscriptions allow; each block's candidates are found when the walk gets there
        (:meth:`load`), so that memory stays bounded whatever the file holds."""
        self.start = start
        self.lo = self.hi = -1  # the block whose candidates are loaded
        self.cand = np.zeros(0, np.int64)
        self.csize = self.cmsg = np.zeros(0, np.uint16)
        self.breaks = np.zeros(0, np.int64)

    @functools.cached_property
    def allowed(self) -> NDArray[np.bool_]:
        """The data message sizes the file's formats allow, any message id (a filter only):
        made when :meth:`load` first needs it (the compiled walk has no candidates)."""
        out = np.zeros(1 << 16, bool)
        widths = _widths(self.out.formats, self.out.basic_sizes)
        out[list(_sizes(self.out.formats, widths))] = True
        return out

    def load(self, pos: int) -> None:
        """The candidates of the block of the file holding ``pos``: positions of type byte
        ``D`` whose size is one a format allows, whose message ends in the file and is
        followed by one of a known type or the file's end; their sizes and ids; the
        indices where a run of consecutive candidates breaks (the block's last one
        always)."""
        u8, n = self.u8, self.n
        self.flush()
        if self.chunks and self.cand.size > 4 * self.taken + _BLOCK // 64:
            # runs taken are views of the candidates: keep copies of them, not all these
            pos_, size_, ids_, sub_ = (np.concatenate(a) for a in zip(*self.chunks, strict=True))
            self.chunks = [(pos_, size_, ids_, sub_)]
        lo = self.start + (pos - self.start) // _BLOCK * _BLOCK
        hi = min(lo + _BLOCK, n - 4)  # a data message needs 5 bytes
        p = np.flatnonzero(u8[lo + 2 : hi + 2] == 0x44)
        p += lo
        # (``take`` on the contiguous bytes: much faster than indexing unaligned views)
        size = _u16(u8, p + 0)
        keep = self.allowed.take(size)  # (never 0)
        after = p + 5
        after += size  # the next message's type byte
        keep &= after <= n + 2  # the message ends in the file
        end = after >= n  # no room for another header
        np.minimum(after, n - 1, out=after)
        # and the message after it is of a known type, or the file ends: fewer false ones
        end |= _KNOWN_TYPE.take(u8.take(after))
        keep &= end
        p, size = p[keep], size[keep]
        self.cand, self.csize, self.cmsg = p, size, _u16(u8, p + 3)
        follows = np.zeros(self.cand.size, bool)
        nxt = self.cand[:-1] + 3
        nxt += self.csize[:-1]
        follows[:-1] = nxt == self.cand[1:]
        breaks = np.flatnonzero(~follows)
        if breaks.size > 1:  # a run goes on across the messages that carry nothing
            k = breaks[:-1]
            at = self.cand[k] + 3
            at += self.csize[k]
            crossed = _CARRIER.take(u8.take(at + 2, mode="clip"))  # (at: up to n)
            if crossed.any():
                k = k[crossed]
                crossed[crossed] = self.bridged(at[crossed].tolist(),
                                                self.cand[k + 1].tolist())
                breaks = np.concatenate([breaks[:-1][~crossed], breaks[-1:]])
        self.breaks = breaks
        self.lo, self.hi, self.taken = lo, hi, 0

    def bridged(self, at: list[int], to: list[int]) -> list[bool]:
        """Whether the messages from each ``at`` up to its ``to`` (the next data candidate)
        carry nothing the walk keeps, one right after the other: sync messages, and ``M``
        or ``Q`` messages :func:`_checked` accepts. A run of data messages goes on across
        them, as the walk would step over them (see *Framing*)."""
        buf, out = self.buf, []
        for q, stop in zip(at, to, strict=True):
            while q < stop:
                size, kind = _HEAD(buf, q)
                end = q + 3 + size
                if end > stop or not (kind == 0x53 or ((kind == 0x4D or kind == 0x51)
                                                       and _checked(buf, q, end))):
                    break
                q = end
            out.append(q == stop)
        return out

    # ------------------------------------------------------------------ subscriptions
    def record(self, name: str) -> tuple[int, int]:
        """A topic's record size and timestamp offset (:func:`_layout`), its layout's key
        kept for :meth:`decode`."""
        key = self.keys.get(name)
        if key is None:
            out = self.out
            # (most formats hold basic types only: their own text is the whole key)
            key = self.keys[name] = ((name, out.definitions[name]),) if (
                name in out.basic_sizes) else _closure(name, out.formats, out.definitions)
        layout = _layout(key)
        return layout[3], _stamp_offset(layout)

    def subscribe(self, data: bytes) -> None:
        if len(data) < 3:
            raise _Stop
        multi_id, msg_id = data[0], data[1] | data[2] << 8
        name = _text(data[3:])
        try:
            size, offset = self.record(name)
        except (KeyError, ValueError, TypeError):
            raise _Bad from None
        if self.topics is not None and name not in self.topics:
            self.filtered.add(msg_id)
            if self.lookup[msg_id] == -1:
                self.lookup[msg_id] = -2
            return
        self.active[msg_id] = self.lookup[msg_id] = len(self.subs)
        if offset + 8 > size:  # no room for the timestamp pyulog reads
            self.untimed[len(self.subs)] = size
        self.subs.append(_Sub(msg_id, multi_id, name, size, offset))

    def end_segment(self) -> None:
        """pyulog turns the subscriptions into data at the end of each section read
        (several with appended data), in reverse order of their first subscription."""
        for msg_id in reversed(list(self.active)):
            self.final.append(self.active[msg_id])
            self.lookup[msg_id] = -2 if msg_id in self.filtered else -1
        self.active.clear()

    # ------------------------------------------------------------------ the walk
    def data(self, pos: int, until: int, final: bool) -> int:
        """Walk the data section from ``pos`` to ``until`` (exclusive of a message that
        passes it); the position where the walk stopped."""
        n, out, buf = self.n, self.out, self.buf
        while True:
            if pos + 3 > n:
                if final and pos < n:
                    out.truncated = n - pos
                return max(pos, n)
            size, kind = _HEAD(buf, pos)
            end = pos + 3 + size
            if kind == 0x44 and size >= 2 and end <= n and end <= until:
                if _scan is not None:  # the run walked in C, one message after the other
                    stop_at, pos = self.walk(pos, until)
                    if stop_at:
                        return stop_at
                    continue
                if not self.untimed and (end + 3 > n or not _RUN_ON[buf[end + 2]]):
                    self.single(pos, size, buf[pos + 3] | buf[pos + 4] << 8)  # no run
                    pos = end
                    continue
                if not self.lo <= pos < self.hi and self.start <= pos < n - 4:
                    self.load(pos)
                cand = self.cand
                i = int(cand.searchsorted(pos))
                if i < cand.size and cand[i] == pos:  # a run of data messages
                    breaks, csize = self.breaks, self.csize
                    b = int(breaks[breaks.searchsorted(i)])
                    j = b if int(cand[b]) + 3 + int(csize[b]) <= until else i - 1 + int(
                        np.searchsorted(cand[i : b + 1] + 3 + csize[i : b + 1], until, "right"))
                    stop_at = self.chunk(cand[i : j + 1], csize[i : j + 1], self.cmsg[i : j + 1])
                    if stop_at:
                        return stop_at
                    pos = int(cand[j]) + 3 + int(csize[j])
                    continue
            if end > n:
                if final:
                    out.truncated = n - pos
                return n
            if end > until:
                return end
            if kind == 0x53 or ((kind == 0x4D or kind == 0x51) and _checked(buf, pos, end)):
                pos = end  # sync: nothing to keep; M, Q: only checked
                continue
            data = buf[pos + 3 : end]
            try:
                if kind in _DATA_TYPES:
                    self.message(kind, pos, size, data)
                elif kind == 0 or size == 0 or size > _MAX_UNKNOWN_SIZE:
                    end = self.resync(pos, until)
                elif self.has_sync and size >= 8 and (k := data.find(SYNC)) >= 0:
                    out.corrupt = True  # sync magic inside a message of an unknown type
                    out.skipped += k + 8
                    end = pos + 3 + k + 8
            except _Stop:
                return end
            except _Bad:
                self.problem("file corruption detected while reading file data")
            pos = end

    def walk(self, pos: int, until: int) -> tuple[int, int]:
        """The data messages from ``pos`` (one), one after the other, sync and checked ``M`` /
        ``Q`` messages stepped over, walked by the compiled loop (``_scan.ulog_data``) up to
        the first other message or ``until``: taken as a run (:meth:`chunk`). Returns
        :meth:`chunk`'s stop (0, or where the section ends) and where the walk stopped."""
        assert _scan is not None
        room = self.room
        if room is None:
            size = min((self.n - pos) // 5 + 1, _WALK_ROOM)  # (a data message: 5 bytes or more)
            room = self.room = (np.empty(size, np.int64), np.empty(size, np.uint16),
                                np.empty(size, np.uint16))
        while True:
            k, nxt = _scan.ulog_data(self.buf, pos, min(until, self.n), *room)
            if k == 1 and not self.untimed:  # one between others: no run's bookkeeping
                self.single(int(room[0][0]), int(room[1][0]), int(room[2][0]))
            elif k:
                stop_at = self.chunk(room[0][:k].copy(), room[1][:k].copy(), room[2][:k].copy())
                if stop_at:
                    return stop_at, nxt
            if k < room[0].size:  # stopped at another message, not for want of room
                return 0, nxt
            pos = nxt

    def single(self, pos: int, size: int, msg_id: int) -> None:
        """One data message between others (kept in a list, made a run by :meth:`flush`)."""
        sub = self.active.get(msg_id)
        if sub is None:
            sub = -2 if msg_id in self.filtered else -1
        self.pending.append((pos, size, msg_id, sub))
        self.count += 1
        self.taken += 1
        if len(self.pending) >= _MAX_CHUNKS:
            self.flush()

    def flush(self) -> None:
        """The single data messages met since the last run, as one run."""
        if self.pending:
            table = np.array(self.pending, np.int64).reshape(-1, 4)
            self.pending = []
            self.chunks.append((table[:, 0].copy(), table[:, 1].astype(np.uint16),
                                table[:, 2].astype(np.uint16), table[:, 3].astype(np.int32)))

    def chunk(self, pos: NDArray[np.int64], size: NDArray[Any], ids: NDArray[Any]) -> int:
        """Consecutive data messages with their subscriptions, checked later. Returns 0, or
        where the section ends (after a decodable record of a topic without room for a
        timestamp: pyulog's struct.error stops reading there); the rest is not taken."""
        self.flush()
        sub = self.lookup[ids]
        stop_at = 0
        if self.untimed:
            stop = np.zeros(pos.size, bool)
            for k, width in self.untimed.items():
                stop |= (sub == k) & (size == width + 2)
            if stop.any():
                end = int(np.argmax(stop)) + 1
                pos, size, ids, sub = pos[:end], size[:end], ids[:end], sub[:end]
                stop_at = int(pos[-1]) + 3 + int(size[-1])
        self.chunks.append((pos, size, ids, sub))
        self.count += pos.size
        self.taken += pos.size
        if len(self.chunks) >= _MAX_CHUNKS:  # many short runs (a hostile file): bounded
            self.chunks = [self.joined()]
        return stop_at

    def joined(self) -> tuple[NDArray[np.int64], NDArray[Any], NDArray[Any], NDArray[Any]]:
        """The chunks so far as one (positions, sizes, ids, subscriptions)."""
        self.flush()
        if not self.chunks:
            return (np.zeros(0, np.int64), np.zeros(0, np.uint16), np.zeros(0, np.uint16),
                    np.zeros(0, np.int32))
        if len(self.chunks) == 1:
            return self.chunks[0]
        pos, size, ids, sub = (np.concatenate(a) for a in zip(*self.chunks, strict=True))
        return pos, size, ids, sub

    def resync(self, pos: int, until: int) -> int:
        """After an implausible header at ``pos``: the next sync magic's end, or (none in the
        rest of the file) the next plausible header one byte at a time."""
        self.out.corrupt = True
        nxt = pos + 1
        if self.has_sync:
            k = self.buf.find(SYNC, pos + 1)
            if k >= 0:
                nxt = k + len(SYNC)
            else:
                self.has_sync = False
        if not self.has_sync:
            nxt = self.garbage_end(pos + 1, _DATA_TYPES, until)
        self.out.skipped += nxt - pos
        return nxt

    def message(self, kind: int, pos: int, size: int, data: bytes) -> None:
        """One message of the data section other than a run of data messages."""
        if kind == 0x44:  # D that is no candidate
            if size < 2:
                raise _Stop
            if self.chunk(np.array([pos]), np.array([size], np.uint16),
                          np.array([data[0] | data[1] << 8], np.uint16)):
                raise _Stop
        elif kind == 0x41:  # A
            self.subscribe(data)
        else:  # (O and P: their time, the last timestamp so far, is set in resolve())
            _other(self.out, kind, data, self.count)

    # ------------------------------------------------------------------ all
    def run(self) -> _Parsed:
        self.header()
        start = self.definitions()
        basic = self.out.basic_sizes  # (only the nested formats can hold a cycle)
        cycle = _cycle({k: v for k, v in self.out.formats.items() if k not in basic})
        if cycle:
            raise LogFormatError("message format " + " -> ".join(cycle) + " contains itself "
                                 "(a damaged or hostile definition)", path=self.path)
        self.candidates(start)
        pos = start
        if self.out.appended and self.offsets:
            for offset in self.offsets:
                pos = self.data(pos, offset, final=False)
                self.end_segment()
                if offset >= 1 << 63:
                    self.out.corrupt = True
                    break
                pos = offset
        self.data(pos, _NO_LIMIT, final=True)
        self.end_segment()
        self.decode(*self.resolve())
        return self.out

    def resolve(self) -> tuple[NDArray[np.int64], NDArray[Any]]:
        """Every data message of the walk against the subscription it met: the positions
        and subscriptions of the decodable ones (in file order); the last timestamp, and
        with it the time of each dropout and parameter change; corruption found."""
        out = self.out
        pos, size, ids, sub = self.joined()
        self.chunks = []
        if len(self.subs) < (1 << 15):
            sub = sub.astype(np.int16)
        # per subscription (and two zeros for -1, -2): record size, timestamp offset
        item = np.array([s.size for s in self.subs] + [0, 0], np.int32)
        offset = np.array([s.ts_offset for s in self.subs] + [0, 0], np.int32)
        valid = item[sub] == size.astype(np.int32) - 2
        if sub.size and sub.min() < 0:
            valid &= sub >= 0
        if not valid.all():
            wrong = ~valid & (sub >= 0)
            lost = sub == -1
            if wrong.any() or lost.any():
                out.corrupt = True
                out.skipped += int((size[wrong | lost].astype(np.int64) + 3).sum())
            for m in sorted(set(ids[lost].tolist())):
                self.problem(_LOST.format(m))
            pos, sub = pos[valid], sub[valid]
            counts = np.cumsum(valid)  # data messages before -> decodable ones before
            events = [int(counts[c - 1]) if c else 0 for c, *_ in out.dropouts] + \
                     [int(counts[c - 1]) if c else 0 for c, *_ in out.changed_params]
        else:
            events = [c for c, *_ in out.dropouts] + [c for c, *_ in out.changed_params]
        # pyulog's last timestamp: 8 bytes at the timestamp's offset, the maximum so far
        if (offset + 8 <= item)[:-2].all():
            at = offset[sub].astype(np.int64)
            at += pos
            at += 5
            stamps = self.u64[at]
            del at
        else:
            stamped = (offset + 8 <= item)[sub]
            stamps = np.zeros(pos.size, np.uint64)
            stamps[stamped] = self.u64[pos[stamped] + 5 + offset[sub[stamped]]]
        bounds = np.array(sorted({0, *events, pos.size}), np.int64)
        upto = dict.fromkeys(bounds.tolist(), out.start_us)
        if pos.size:
            maxima = np.maximum.accumulate(np.maximum.reduceat(stamps, bounds[:-1]))
            ends = bounds[1:].tolist()
            upto.update(zip(ends, (max(out.start_us, m) for m in maxima.tolist()), strict=True))
        out.last_us = upto[pos.size]
        k = len(out.dropouts)
        dropouts = zip(events[:k], out.dropouts, strict=True)
        changed = zip(events[k:], out.changed_params, strict=True)
        out.dropouts = [(upto[c], d) for c, (_, d) in dropouts]
        out.changed_params = [(upto[c], key, v) for c, (_, key, v) in changed]
        return pos, sub

    def decode(self, pos: NDArray[np.int64], sub: NDArray[np.int64]) -> None:
        """Gather each kept subscription's records: one fancy index per topic into a view
        of the file as raw records of its size at every byte (as ``void``: fast)."""
        at = pos[np.argsort(sub, kind="stable")]  # grouped by subscription, in file order
        at += 5
        counts = np.bincount(sub, minlength=len(self.subs)).tolist()
        first = [0, *np.cumsum(counts).tolist()]
        items = []
        for k in self.final:
            s = self.subs[k]
            width = s.size
            if not counts[k] or not width:
                continue
            raw = np.ndarray((self.n - width + 1,), f"V{width}", buffer=self.buf, strides=(1,))
            records = raw[at[first[k] : first[k + 1]]].view(np.uint8)
            items.append((s.name, s.multi_id,
                          _Fields(records, counts[k], _layout(self.keys[s.name]))))
        items.sort(key=lambda d: (d[0], d[1]))
        self.out.data = items


def _parse(path: str | os.PathLike[str], topics: set[str] | None) -> _Parsed:
    """Map the file and read it (see the module's *Framing*); any failure is one
    :class:`~mavsid.errors.LogFormatError` naming the file. (Mapped, not read into memory,
    even when small: a first read in a process maps the cached pages faster than it copies
    them into fresh ones.)"""
    try:
        with open(path, "rb") as f:
            if hasattr(mmap, "MAP_POPULATE"):  # read ahead at once (faults one by one: slow)
                buf = mmap.mmap(f.fileno(), 0, flags=mmap.MAP_SHARED | mmap.MAP_POPULATE,
                                prot=mmap.PROT_READ)
            else:
                buf = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
    except (OSError, ValueError) as exc:
        raise LogFormatError(f"cannot read: {getattr(exc, 'strerror', None) or exc}",
                             path=path) from None
    try:
        return _plain(buf, topics) or _Reader(buf, path, topics).run()
    except RecursionError:
        raise LogFormatError("not a readable ULog (definitions nested without end)",
                             path=path) from None
    except MemoryError:
        raise LogFormatError("not a readable ULog (out of memory)", path=path) from None
    finally:
        try:
            buf.close()
        except BufferError:  # a view still refers to it: closed when collected
            pass


def _plain(buf: Any, topics: set[str] | None) -> _Parsed | None:
    """A log with nothing unusual in it read in one compiled pass (``_scan.ulog_plain``);
    None for any other (read by :class:`_Reader`, pyulog's rules on damaged files), or
    where the package was built without a C compiler. "Unusual" is all but the commonest
    damage, which the compiled pass accounts for as :class:`_Reader` does: data messages
    without subscription or of a wrong size (skipped), an implausible header followed by
    a sync magic, a sync magic inside a message of an unknown type (read on after it). It
    leaves the few info, text, dropout and parameter-change messages to :func:`_other`;
    one it would fail on sends the log to :class:`_Reader` too."""
    if _scan is None or not _PLAIN:
        return None
    got = _scan.ulog_plain(buf, topics)
    if got is None:
        return None
    start_us, last_us, appended, truncated, params, rare, tables, times, skipped, corrupt, \
        lost = got
    out = _Parsed(start_us=start_us, last_us=last_us, appended=bool(appended),
                  truncated=truncated, initial_params=params, skipped=skipped,
                  corrupt=bool(corrupt), problems=[_LOST.format(m) for m in lost])
    try:
        for kind, pos, size, stamp in rare:
            _other(out, kind, buf[pos + 3 : pos + 3 + size], stamp)
    except (_Stop, _Bad):
        return None
    whole = np.frombuffer(times, np.float64)
    ends = itertools.accumulate(count for *_, count in tables)
    out.data = [(name, multi_id, _Fields(raw, count, layout))
                for name, multi_id, layout, raw, count in tables]  # (sorted as decode sorts)
    out.times = [whole[end - count : end]
                 for (*_, count), end in zip(tables, ends, strict=True)]
    out.floats = True
    return out


def _times(tables: list[_Fields]) -> list[NDArray[np.float64]]:
    """Per table, ``timestamp_sample`` if present, else ``timestamp``, in seconds (NaN if
    neither): the ``uint64`` ones (all in a real log) converted in one go, each table's
    a slice of the whole.

    Examples
    --------
    >>> ts, x = (_new_layout(((n, f"{n}:{t};".encode()),)) for n, t in
    ...          (("a", "uint64_t timestamp"), ("b", "float x")))
    >>> a = _Fields(np.array([1_000_000, 2_500_000], "<u8").view(np.uint8), 2, ts)
    >>> b = _Fields(np.array([7], "<f4").view(np.uint8), 1, x)
    >>> [t.tolist() for t in _times([a, b, a])]
    [[1.0, 2.5], [nan], [1.0, 2.5]]
    """
    out: list[NDArray[np.float64] | None] = []
    batch: list[NDArray[Any]] = []
    for data in tables:
        fields = _index(data.layout)  # (looked up directly: a hundred tables)
        key = "timestamp_sample" if "timestamp_sample" in fields else "timestamp"
        column = data[key] if key in fields else None
        if column is None:
            out.append(np.full(data.count, np.nan))
        elif column.dtype == np.uint64:
            out.append(None)
            batch.append(column)
        else:
            out.append(column.astype(np.float64) / 1e6)
    if batch:
        whole = np.concatenate(batch, dtype=np.float64)
        whole /= 1e6
        ends = np.cumsum([len(c) for c in batch]).tolist()
        parts = iter([whole[e - len(c) : e] for c, e in zip(batch, ends, strict=True)])
        return [next(parts) if t is None else t for t in out]
    return [t for t in out if t is not None]


def _texts(parsed: _Parsed) -> list[TextMessage]:
    """Logged and tagged logged messages in time order; severity from the ASCII level."""
    entries = list(parsed.logged)
    for tagged in parsed.tagged.values():
        entries.extend(tagged)
    texts = []
    for m in entries:
        level = m.level
        severity = level - ord("0") if ord("0") <= level <= ord("7") else level
        texts.append(TextMessage(m.time_us / 1e6, m.message, severity))
    return sorted(texts, key=lambda t: t.time_s)


def _modes(table: MessageTable | None) -> list[ModeChange]:
    """A ModeChange at the first sample and at each change of ``nav_state``."""
    if table is None or "nav_state" not in table or not len(table):
        return []
    state = table["nav_state"].astype(np.int64)
    change = np.flatnonzero(np.diff(state, prepend=-1) != 0)
    return [
        ModeChange(float(table.time_s[k]), int(state[k]), NAV_STATES.get(int(state[k])))
        for k in change.tolist()
    ]


def _number(value: Any) -> float | None:
    """A parameter's value as float; None for what is not a number (a damaged type string
    leaves raw bytes)."""
    if isinstance(value, (bytes, bytearray, str)) or isinstance(value, bool):
        return None
    try:
        return float(value)
    except (TypeError, ValueError, OverflowError):
        return None


def _params(parsed: _Parsed) -> tuple[dict[str, float], int, int]:
    """Initial parameters with later changes applied; the number of changes; and how many
    values were not numbers (skipped)."""
    initial = parsed.initial_params
    if parsed.floats:  # (the compiled pass's)
        params = initial.copy()
        entries = [(name, value) for _, name, value in parsed.changed_params]
    elif set(map(type, initial.values())) <= {float, int}:  # the common case: at once
        params = dict(zip(initial, map(float, initial.values()), strict=True))
        entries = [(name, value) for _, name, value in parsed.changed_params]
    else:
        params = {}
        entries = list(initial.items())
        entries += [(name, value) for _, name, value in parsed.changed_params]
    bad = 0
    for name, value in entries:
        if type(value) is float or type(value) is int:  # the common case, directly
            params[name] = float(value)
            continue
        number = _number(value)
        if number is None:
            bad += 1
        else:
            params[str(name)] = number
    return params, len(parsed.changed_params), bad


def _vehicle(mav_type: Any) -> str | None:
    """The vehicle class of a ``MAV_TYPE`` parameter; None when absent or not a whole number
    (a damaged log's).

    >>> _vehicle(2), _vehicle(float("nan")), _vehicle(None)
    ('copter', None, None)
    """
    if isinstance(mav_type, (int, float)) and math.isfinite(mav_type):
        return vehicle_class(int(mav_type))
    return None


def _firmware(info: dict[str, Any]) -> str | None:
    """``PX4 v1.14.0 (board)`` from ``ver_sw_release`` (0xMMmmpptt), else the git hash."""
    name = str(info.get("sys_name", "PX4"))
    board = f" ({info['ver_hw']})" if info.get("ver_hw") else ""
    release = info.get("ver_sw_release")
    if isinstance(release, int) and release > 0 and (release >> 24) > 0:
        major, minor, patch = release >> 24, (release >> 16) & 0xFF, (release >> 8) & 0xFF
        return f"{name} v{major}.{minor}.{patch}{board}"
    sw = info.get("ver_sw")
    return f"{name} {sw}{board}" if sw else None


def _window(table: MessageTable, lo: float, hi: float) -> MessageTable:
    """Rows of ``table`` with ``lo <= time_s <= hi``."""
    keep = (table.time_s >= lo) & (table.time_s <= hi)
    columns: Mapping[str, NDArray[Any]]
    if isinstance(table.columns, _Fields):
        columns = table.columns.rows(keep)
    else:
        columns = {n: c[keep] for n, c in table.columns.items()}
    return MessageTable(table.name, columns, table.time_s[keep], table.units)


def _base(name: str) -> str:
    """Topic name without its ``[N]`` instance suffix."""
    match = _INSTANCE.match(name)
    return match.group(1) if match else name


def _wanted_topics(messages: Sequence[str] | None) -> tuple[set[str] | None, set[str] | None]:
    """The topics to decode (base names, plus vehicle_status for the modes) and the wanted
    table names (``topic`` wants every instance, ``topic[N]`` only that one)."""
    if messages is None:
        return None, None
    return {_base(n) for n in messages} | {_MODE_TOPIC}, set(messages)


def read(
    path: str | os.PathLike[str],
    messages: Sequence[str] | None = None,
    start: float | None = None,
    stop: float | None = None,
) -> RawLog:
    """Read a PX4 ULog into a :class:`~mavsid.data.RawLog`.

    Parameters
    ----------
    path : path-like
        The ``.ulg`` file.
    messages : sequence of str, optional
        Topics to load (``topic`` for all its instances or ``topic[N]``); default all.
        The others' records are framed but not decoded, which is faster.
    start, stop : float, optional
        Keep only samples (and texts, mode changes) with ``start <= time_s <= stop``
        (seconds since boot).

    Raises
    ------
    LogFormatError
        Empty or unreadable file, a bad header or incompatible flags, formats that
        contain themselves, or one without any topic sample or parameter (when all
        topics were asked for).

    Warns
    -----
    DataQualityWarning
        Corruption found (bytes skipped to resynchronise, data of unknown message ids,
        wrong sizes, unreadable definitions), or parameter values of an unreadable type.
    """
    try:
        size = os.path.getsize(path)
    except OSError as exc:
        raise LogFormatError(f"cannot read: {exc.strerror or exc}", path=path) from None
    if size == 0:
        raise LogFormatError("empty file", path=path)
    topics, wanted = _wanted_topics(messages)
    parsed = _parse(path, topics)
    if messages is None and not parsed.data and not parsed.initial_params:
        raise LogFormatError("no ULog data (no topic samples, no parameters)", path=path)

    tables: dict[str, MessageTable] = {}
    times = parsed.times
    if times is None:
        times = _times([data for _, _, data in parsed.data])
    for (topic, multi_id, data), time_s in zip(parsed.data, times, strict=True):
        name = table_name(topic, multi_id)
        units: dict[str, str] = dict.fromkeys(data.layout[5], "us")
        tables[name] = MessageTable(name, data, time_s, units)
    params, n_changes, bad_params = _params(parsed)
    texts = _texts(parsed)
    modes = _modes(tables.get(_MODE_TOPIC))
    # the log's span: the header's start time to the latest data timestamp
    span = (parsed.start_us / 1e6, max(parsed.last_us, parsed.start_us) / 1e6)
    if start is not None or stop is not None:
        lo = -np.inf if start is None else start
        hi = np.inf if stop is None else stop
        span = (max(span[0], lo), max(min(span[1], hi), max(span[0], lo)))
        tables = {n: _window(t, lo, hi) for n, t in tables.items()}
        texts = [m for m in texts if lo <= m.time_s <= hi]
        modes = [m for m in modes if lo <= m.time_s <= hi]
    if wanted is not None:
        tables = {n: t for n, t in tables.items() if n in wanted or _base(n) in wanted}

    notes = _notes(parsed, tables, n_changes)
    damage = []  # (said in one warning, as a damaged DataFlash file is: nothing silently lost)
    if bad_params:
        damage.append(f"{bad_params} parameter value(s) of an unreadable type skipped")
    problems = parsed.problems
    if parsed.corrupt or problems:
        detail = "; ".join(problems[:3])
        if len(problems) > 3:
            detail += f" (+{len(problems) - 3} more)"
        damage.append("file corruption found" + (f": {detail}" if detail else ""))
    if parsed.truncated:
        damage.append(f"last message truncated: {parsed.truncated} bytes ignored")
    notes += damage
    if damage:
        warnings.warn(f"{path}: {'; '.join(damage)}", DataQualityWarning, stacklevel=2)
    return RawLog(
        source=SourceInfo(str(path), "ulog", size, parsed.skipped + parsed.truncated,
                          tuple(notes)),
        messages=tables,
        params=params,
        texts=tuple(texts),
        modes=tuple(modes),
        autopilot="px4",
        vehicle=_vehicle(params.get("MAV_TYPE")),
        firmware=_firmware(parsed.info),
        span_s=span,
    )


def _notes(parsed: _Parsed, tables: dict[str, MessageTable], n_changes: int) -> list[str]:
    """Data-quality notes: dropouts, appended data, parameter changes, time running back."""
    notes = []
    if parsed.dropouts:
        total = sum(duration for _, duration in parsed.dropouts)
        notes.append(f"{len(parsed.dropouts)} dropouts, {total} ms in all")
    if parsed.appended:
        notes.append("has appended data (crash dump)")
    if n_changes:
        notes.append(f"{n_changes} parameter changes during the log")
    backwards = _backwards(tables)
    if backwards:
        notes.append(f"time runs backwards in {len(backwards)} topics "
                     f"({first_few(backwards)})")
    return notes


def _backwards(tables: dict[str, MessageTable]) -> list[str]:
    """The tables whose time runs backwards somewhere, in order: all checked at once.

    Examples
    --------
    >>> def table(t):
    ...     return MessageTable("x", {}, np.array(t, float))
    >>> _backwards({"a": table([1, 2]), "b": table([0, 1, 0.5]), "c": table([1])})
    ['b']
    """
    timed = [(name, t.time_s) for name, t in tables.items() if t.time_s.size > 1]
    if not timed:
        return []
    lengths = np.array([t.size for _, t in timed])
    starts = np.cumsum(lengths) - lengths
    whole = np.concatenate([t for _, t in timed])
    back = np.flatnonzero(whole[1:] < whole[:-1])  # whole[i + 1] < whole[i]
    owner = np.searchsorted(starts, back, "right") - 1
    inside = back + 1 < starts[owner] + lengths[owner]  # i and i + 1 in one table
    # (not np.unique: its first call imports numpy.ma, 15 ms of a cold read)
    hit = np.bincount(owner[inside], minlength=len(timed))
    return [timed[k][0] for k in np.flatnonzero(hit).tolist()]
