"""The data section of a ULog: every topic's records found and gathered, as pyulog does.

Two readers share the work (:func:`parse` picks):

- *The compiled pass* (``_scan.ulog_plain``, where the package was built with a C
  compiler: see :func:`read_plain`) reads a log with nothing unusual in it in one go:
  definitions, formats flattened to record layouts, subscriptions, every data message
  gathered into its topic's records, each table's times; it accounts for the commonest
  damage as the Python reader does (data messages without subscription or of a wrong
  size skipped, an implausible header followed by a sync magic, a sync magic inside a
  message of an unknown type). The few info, text, dropout and parameter-change messages
  are read by the Python reader's code. Anything else (a message cut inside the
  definitions, a format or parameter that does not parse plainly, garbage without a sync
  magic after it, a repeated subscription, a payload too short for its fields, odd
  appended-data offsets, more fields than a read keeps) and it returns nothing and:
- *the Python reader* (:class:`Reader`), pyulog's rules on damaged files one by one, reads
  the log: definitions and every message that is not topic data are parsed in Python; the
  data messages (``D``, nearly all of a log) are framed by a compiled loop (or numpy) and
  decoded with numpy.

Where the first returns, the second returns the same (tests: every shared and simulated
log, and logs damaged at random, read both ways; every ULog test runs three ways: the
compiled pass, the Python reader with the compiled walk, and with numpy's).

For the Python reader on a small log the fixed costs weigh most: a thousand or two
definition messages and a hundred topics. They are kept down so: the plain parameters
(``float`` or ``int32_t`` key, 4-byte value: nearly all) are found in runs, as data
messages are (see *Framing*), and decoded in one batch, names at once and values as arrays;
``M`` and ``Q`` messages, which are only checked, are seen without decoding when plainly
valid; a format's size is summed as its fields are parsed; a topic's layout is built once
per read; the times of all tables are converted, and checked for running backwards, in one
go.

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
   keeps: sync messages (any payload) and ``M``/``Q`` messages :func:`.checked` accepts
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
data messages written out, sync messages and the ``M`` / ``Q`` messages :func:`.checked`
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

Examples
--------
>>> raw = b"ULog\\x01\\x12\\x35\\x01" + bytes(8)
>>> fmt = b"a:uint64_t timestamp;"
>>> raw += bytes([len(fmt), 0]) + b"F" + fmt
>>> raw += bytes([4, 0]) + b"A" + bytes([0, 7, 0]) + b"a"  # message id 7: topic a
>>> raw += bytes([10, 0]) + b"D" + bytes([7, 0]) + (5_000_000).to_bytes(8, "little")
>>> parsed = Reader(raw, "a.ulg", None).run()
>>> [(name, fields["timestamp"].tolist()) for name, _, fields in parsed.data]
[('a', [5000000])]
"""

from __future__ import annotations

import functools
import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mavsid.errors import LogFormatError
from mavsid.readers import ulog_messages as msg
from mavsid.readers.files import LogPath
from mavsid.readers.ulog_definitions import Definitions, Parsed, garbage_end, other_message
from mavsid.readers.ulog_layout import (
    Fields,
    LayoutKey,
    data_sizes,
    format_cycle,
    format_widths,
    known_layout,
    layout_key,
    stamp_offset,
)
from mavsid.readers.ulog_messages import (
    HEAD,
    MAX_UNKNOWN_SIZE,
    BadPayload,
    Buffer,
    ShortPayload,
    checked,
    decode_text,
    u16,
)
from mavsid.readers.ulog_spec import SYNC

__all__ = ["PLAIN", "Reader", "parse", "read_plain"]

#: message types read in the data section
_DATA_TYPES = frozenset(b"IMPQALCDOS")
_KNOWN_TYPE = np.zeros(256, bool)
_KNOWN_TYPE[list(b"FDIMPQARLCOSB")] = True
#: types of the messages a run of data messages may cross (see :meth:`Reader.bridged`)
_CARRIER = np.zeros(256, bool)
_CARRIER[list(b"SMQ")] = True
#: a data message followed by one of these types may start a run
_RUN_ON = _CARRIER.copy()
_RUN_ON[0x44] = True
_NO_LIMIT = 1 << 62
#: bytes of the file scanned at a time for message candidates
_BLOCK = 1 << 20
#: runs of data messages kept apart before they are joined (bounds the memory per run)
_MAX_CHUNKS = 4096
#: data messages the compiled walk writes out per call (its output arrays' length)
_WALK_ROOM = 1 << 16
#: read the logs with nothing unusual in one compiled pass (see read_plain); off: Reader only
PLAIN = True
_LOST = "no subscription found for message id {}"
#: data messages met: their positions, sizes, message ids and subscriptions (see Reader.chunk)
_Run = tuple[NDArray[np.int64], NDArray[np.uint16], NDArray[np.uint16], NDArray[np.int32]]


@dataclass
class _Sub:
    """One subscription (``A`` message): a topic instance's message id and record layout."""

    msg_id: int
    multi_id: int
    name: str
    size: int  # the record size
    ts_offset: int  # bytes before ``timestamp`` (the record size if there is none)


class Reader:
    """One pass over a mapped ULog (see the module's *Framing*)."""

    def __init__(self, buf: Buffer, path: LogPath, topics: set[str] | None) -> None:
        self.buf = buf  # the mmap (bytes-like, with .find)
        self.u8 = np.frombuffer(buf, np.uint8)
        self.n = self.u8.size
        self.path = path
        self.topics = topics
        self.out = Parsed()
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
        self.keys: dict[str, LayoutKey] = {}  # topic -> its layout's key (layout_key)
        # data messages met: (positions, sizes, ids, their subscriptions), and how many
        self.chunks: list[_Run] = []
        self.pending: list[tuple[int, int, int, int]] = []
        self.count = self.taken = 0
        self.room: tuple[NDArray[np.int64], NDArray[np.uint16], NDArray[np.uint16]] | None = None
        self.u64 = (np.ndarray((self.n - 7,), "<u8", buffer=buf, strides=(1,))
                    if self.n >= 8 else np.zeros(0, np.uint64))  # fmt: skip

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
        widths = format_widths(self.out.formats, self.out.basic_sizes)
        out[list(data_sizes(self.out.formats, widths))] = True
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
        size = u16(u8, p + 0)
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
        self.cand, self.csize, self.cmsg = p, size, u16(u8, p + 3)
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
                size, kind = HEAD(buf, q)
                end = q + 3 + size
                if end > stop or not (kind == 0x53 or ((kind == 0x4D or kind == 0x51)
                                                       and checked(buf, q, end))):
                    break
                q = end
            out.append(q == stop)
        return out

    # ------------------------------------------------------------------ subscriptions
    def record(self, name: str) -> tuple[int, int]:
        """A topic's record size and timestamp offset (:func:`known_layout`), its layout's key
        kept for :meth:`decode`."""
        key = self.keys.get(name)
        if key is None:
            out = self.out
            # (most formats hold basic types only: their own text is the whole key)
            key = self.keys[name] = ((name, out.definitions[name]),) if (
                name in out.basic_sizes) else layout_key(name, out.formats, out.definitions)
        layout = known_layout(key)
        return layout[3], stamp_offset(layout)

    def subscribe(self, data: bytes) -> None:
        if len(data) < 3:
            raise ShortPayload
        multi_id, msg_id = data[0], data[1] | data[2] << 8
        name = decode_text(data[3:])
        try:
            size, offset = self.record(name)
        except (KeyError, ValueError, TypeError):
            raise BadPayload from None
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
            size, kind = HEAD(buf, pos)
            end = pos + 3 + size
            if kind == 0x44 and size >= 2 and end <= n and end <= until:
                if msg.compiled is not None:  # the run walked in C, one message after the other
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
            if kind == 0x53 or ((kind == 0x4D or kind == 0x51) and checked(buf, pos, end)):
                pos = end  # sync: nothing to keep; M, Q: only checked
                continue
            data = buf[pos + 3 : end]
            try:
                if kind in _DATA_TYPES:
                    self.message(kind, pos, size, data)
                elif kind == 0 or size == 0 or size > MAX_UNKNOWN_SIZE:
                    end = self.resync(pos, until)
                elif self.has_sync and size >= 8 and (k := data.find(SYNC)) >= 0:
                    out.corrupt = True  # sync magic inside a message of an unknown type
                    out.skipped += k + 8
                    end = pos + 3 + k + 8
            except ShortPayload:
                return end
            except BadPayload:
                self.out.problem("file corruption detected while reading file data")
            pos = end

    def walk(self, pos: int, until: int) -> tuple[int, int]:
        """The data messages from ``pos`` (one), one after the other, sync and checked ``M`` /
        ``Q`` messages stepped over, walked by the compiled loop (``_scan.ulog_data``) up to
        the first other message or ``until``: taken as a run (:meth:`chunk`). Returns
        :meth:`chunk`'s stop (0, or where the section ends) and where the walk stopped."""
        assert msg.compiled is not None
        room = self.room
        if room is None:
            size = min((self.n - pos) // 5 + 1, _WALK_ROOM)  # (a data message: 5 bytes or more)
            room = self.room = (np.empty(size, np.int64), np.empty(size, np.uint16),
                                np.empty(size, np.uint16))
        while True:
            k, nxt = msg.compiled.ulog_data(self.buf, pos, min(until, self.n), *room)
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

    def chunk(self, pos: NDArray[np.int64], size: NDArray[np.uint16],
              ids: NDArray[np.uint16]) -> int:
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

    def joined(self) -> _Run:
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
            nxt = garbage_end(self.buf, self.u8, pos + 1, _DATA_TYPES, until)
        self.out.skipped += nxt - pos
        return nxt

    def message(self, kind: int, pos: int, size: int, data: bytes) -> None:
        """One message of the data section other than a run of data messages."""
        if kind == 0x44:  # D that is no candidate
            if size < 2:
                raise ShortPayload
            if self.chunk(np.array([pos]), np.array([size], np.uint16),
                          np.array([data[0] | data[1] << 8], np.uint16)):
                raise ShortPayload
        elif kind == 0x41:  # A
            self.subscribe(data)
        else:  # (O and P: their time, the last timestamp so far, is set in resolve())
            other_message(self.out, kind, data, self.count)

    # ------------------------------------------------------------------ all
    def run(self) -> Parsed:
        """Read the whole log: the header and definitions, then the data section."""
        definitions = Definitions(self.buf, self.path, self.out)
        start = definitions.read()
        self.offsets = definitions.offsets
        basic = self.out.basic_sizes  # (only the nested formats can hold a cycle)
        cycle = format_cycle({k: v for k, v in self.out.formats.items() if k not in basic})
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

    def resolve(self) -> tuple[NDArray[np.int64], NDArray[np.signedinteger]]:
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
                self.out.problem(_LOST.format(m))
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

    def decode(self, pos: NDArray[np.int64], sub: NDArray[np.signedinteger]) -> None:
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
                          Fields(records, counts[k], known_layout(self.keys[s.name]))))
        items.sort(key=lambda d: (d[0], d[1]))
        self.out.data = items


def parse(buf: Buffer, path: LogPath, topics: set[str] | None) -> Parsed:
    """Read the file's bytes ``buf`` (see the module's *Framing*): by the compiled pass where
    it takes the log, else by :class:`Reader`; any failure is one
    :class:`~mavsid.errors.LogFormatError` naming the file."""
    try:
        return read_plain(buf, topics) or Reader(buf, path, topics).run()
    except RecursionError:
        raise LogFormatError("not a readable ULog (definitions nested without end)",
                             path=path) from None
    except MemoryError:
        raise LogFormatError("not a readable ULog (out of memory)", path=path) from None


def read_plain(buf: Buffer, topics: set[str] | None) -> Parsed | None:
    """A log with nothing unusual in it read in one compiled pass (``_scan.ulog_plain``);
    None for any other (read by :class:`Reader`, pyulog's rules on damaged files), or
    where the package was built without a C compiler. "Unusual" is all but the commonest
    damage, which the compiled pass accounts for as :class:`Reader` does: data messages
    without subscription or of a wrong size (skipped), an implausible header followed by
    a sync magic, a sync magic inside a message of an unknown type (read on after it). It
    leaves the few info, text, dropout and parameter-change messages to :func:`other_message`;
    one it would fail on sends the log to :class:`Reader` too."""
    if msg.compiled is None or not PLAIN:
        return None
    got = msg.compiled.ulog_plain(buf, topics)
    if got is None:
        return None
    start_us, last_us, appended, truncated, params, rare, tables, times, skipped, corrupt, \
        lost = got
    out = Parsed(start_us=start_us, last_us=last_us, appended=bool(appended),
                 truncated=truncated, initial_params=params, skipped=skipped,
                 corrupt=bool(corrupt), problems=[_LOST.format(m) for m in lost])
    try:
        for kind, pos, size, stamp in rare:
            other_message(out, kind, buf[pos + 3 : pos + 3 + size], stamp)
    except (ShortPayload, BadPayload):
        return None
    whole = np.frombuffer(times, np.float64)
    ends = itertools.accumulate(count for *_, count in tables)
    out.data = [(name, multi_id, Fields(raw, count, layout))
                for name, multi_id, layout, raw, count in tables]  # (sorted as decode sorts)
    out.times = [whole[end - count : end]
                 for (*_, count), end in zip(tables, ends, strict=True)]
    out.floats = True
    return out

