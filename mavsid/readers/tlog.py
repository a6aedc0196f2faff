"""Read MAVLink telemetry logs (``.tlog``) into a :class:`~mavsid.data.RawLog`, vectorised.

A ``.tlog`` is what a ground station (Mission Planner, QGroundControl, MAVProxy) records: each
record is an 8-byte big-endian receive time in microseconds (the ground station's wall clock)
followed by one MAVLink frame as it came off the link:

- v1: ``0xFE len seq sysid compid msgid payload crc(2)``
- v2: ``0xFD len incompat compat seq sysid compid msgid(3) payload crc(2) [signature(13)]``;
  the payload's trailing zero bytes are truncated on the wire.

Message definitions (ids, field names, wire order, array lengths, CRC_EXTRA) come from a
pymavlink dialect (``ardupilotmega`` by default). Decoding never builds one Python object per
frame: every byte offset where a record could start is a candidate (its magic byte 8 bytes
on); candidates are checked by length, flags, a known message id and the X.25 CRC seeded
with the message's CRC_EXTRA, all as numpy operations grouped by frame length; overlapping
survivors are resolved in file order, preferring frames that chain into the next record.
Each message id's frames are then viewed through a structured dtype in wire order (short v2
payloads zero-padded, as MAVLink specifies) and split into columns by field name. The file is
memory-mapped, not copied, and its pages are handed back as the scan and each table are done;
what is kept per frame is compact (about 20 bytes): the read's peak stays under twice the
tables it returns.

Every table has the fields of the message (2-D arrays for array fields, ``str`` for char
arrays, decoded as pymavlink does) plus ``_sysid``, ``_compid`` and ``_recv_time_s`` (the
receive time, s); units are the dialect's, the message's instance field (``RAW_IMU.id``)
has unit ``"instance"``. ``MessageTable.time_s`` is the vehicle's clock:

- ``time_boot_ms`` × 1e-3 or ``time_usec`` × 1e-6 when the message has such a field (a
  ``time_usec`` whose median is over 1e15 µs is a UNIX time, not a boot time, and is not
  used);
- otherwise the receive time moved onto the vehicle's clock by the median offset between the
  two clocks over the time-stamped messages of the same vehicle (for systems that are no
  vehicle, such as the ground station: of the main vehicle), NaN when there are none. These
  times carry the link's latency and jitter: alignment should prefer messages with their own
  clock.

``PARAM_VALUE`` gives ``params``, ``STATUSTEXT`` the text messages (chunks joined), the
``HEARTBEAT``'s ``custom_mode`` the mode changes (names from the ArduPilot and PX4 mode
tables of :mod:`mavsid.autopilot.modes`, pymavlink's names) and ``autopilot`` — all of the
main vehicle: the first system whose heartbeat is neither a ground station, gimbal, ADS-B
receiver, onboard computer nor ``MAV_AUTOPILOT_INVALID``, as pymavlink picks it.

Bytes that form no valid frame (garbage, bad CRC, truncated records), frames of message ids
the dialect does not define and receive times that run backwards or jump by more than an hour
are counted: one :class:`~mavsid.errors.DataQualityWarning` and ``SourceInfo.notes``. A file
without a single valid frame raises :class:`~mavsid.errors.LogFormatError`.

Examples
--------
A two-record log from an ArduCopter quadrotor: a MAVLink 2 HEARTBEAT (its payload's trailing
zero truncated on the wire), then 20 ms later an ATTITUDE stamped 5 s after boot:

>>> import os, struct, tempfile
>>> from pymavlink.dialects.v20 import ardupilotmega as mavlink
>>> mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
>>> hb = mav.heartbeat_encode(type=2, autopilot=3, base_mode=81, custom_mode=0,
...                           system_status=4).pack(mav)
>>> att = mav.attitude_encode(5000, 0.1, -0.2, 1.5, 0.0, 0.0, 0.0).pack(mav)
>>> t0 = 1_700_000_000_000_000  # receive time, µs (ground station clock)
>>> with tempfile.NamedTemporaryFile(suffix=".tlog", delete=False) as f:
...     _ = f.write(struct.pack(">Q", t0) + hb + struct.pack(">Q", t0 + 20_000) + att)
>>> log = read(f.name)
>>> log["ATTITUDE"]["roll"].tolist(), log["ATTITUDE"].time_s.tolist()
([0.10000000149011612], [5.0])
>>> log["HEARTBEAT"]["_sysid"].tolist(), log.autopilot, log.vehicle
([1], 'ardupilot', 'copter')
>>> [(round(m.time_s, 6), m.mode, m.name) for m in log.modes]  # received at 4.98 s
[(4.98, 0, 'STABILIZE')]
>>> os.unlink(f.name)
"""

from __future__ import annotations

import functools
import importlib
import mmap
import os
import re
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mavsid.autopilot.modes import ardupilot_modes, px4_mode_name
from mavsid.data import (
    MessageTable,
    ModeChange,
    ParamChange,
    RawLog,
    SourceInfo,
    TextMessage,
    param_changes,
)
from mavsid.errors import ConfigError, DataQualityWarning, LogFormatError

__all__ = ["MessageDef", "load_dialect", "read", "vehicle_class"]

_PREFIX = 8  # receive-time bytes before every frame
_MAGIC_V1, _MAGIC_V2 = 0xFE, 0xFD
_IFLAG_SIGNED = 0x01
_SIGNATURE_LEN = 13
_TIME_JUMP_S = 3600.0  # a forward step in receive time larger than this counts as a jump
_UNIX_USEC = 1e15  # a time_usec above this (31 years) is a UNIX time, not time since boot
_MAV_AUTOPILOT = {3: "ardupilot", 12: "px4"}
_MAV_AUTOPILOT_INVALID, _MAV_TYPE_GCS = 8, 6

_STRUCT_TO_NUMPY = {
    "c": "S1", "b": "i1", "B": "u1", "h": "<i2", "H": "<u2", "i": "<i4", "I": "<u4",
    "q": "<i8", "Q": "<u8", "f": "<f4", "d": "<f8",
}  # fmt: skip


@dataclass(frozen=True)
class MessageDef:
    """How one MAVLink message is laid out on the wire (from a pymavlink dialect class).

    Parameters
    ----------
    msgid : int
    name : str
        e.g. ``"ATTITUDE"``.
    crc_extra : int
        Seed byte appended to the CRC, a hash of the message's definition.
    dtype : numpy.dtype
        Structured, little-endian, fields in wire order (sorted by size), itemsize equal to
        the full payload length.
    fields : tuple of str
        Field names in definition order (the column order).
    strings : frozenset of str
        Char-array fields, given as ``str``.
    time_field : str or None
        ``"time_boot_ms"`` or ``"time_usec"`` when the message carries the vehicle's clock.
    """

    msgid: int
    name: str
    crc_extra: int
    dtype: np.dtype[Any]
    fields: tuple[str, ...]
    strings: frozenset[str]
    time_field: str | None


@functools.lru_cache(maxsize=8)
def load_dialect(dialect: str = "ardupilotmega") -> dict[int, MessageDef]:
    """Message id -> :class:`MessageDef` for a pymavlink MAVLink 2 dialect.

    Parameters
    ----------
    dialect : str
        Module name under ``pymavlink.dialects.v20`` (``ardupilotmega``, ``common``,
        ``development`` ...).

    Raises
    ------
    ConfigError
        No such dialect.

    Examples
    --------
    >>> att = load_dialect()[30]
    >>> att.name, att.dtype.itemsize, att.fields[:2], att.time_field
    ('ATTITUDE', 28, ('time_boot_ms', 'roll'), 'time_boot_ms')
    """
    if not re.fullmatch(r"[A-Za-z0-9_]+", dialect):
        raise ConfigError(f"dialect {dialect!r}: not a pymavlink dialect name")
    try:
        module = importlib.import_module(f"pymavlink.dialects.v20.{dialect}")
    except ImportError:
        raise ConfigError(f"dialect {dialect!r}: no such pymavlink dialect") from None
    defs = {}
    for msgid, cls in module.mavlink_map.items():
        defs[int(msgid)] = _message_def(int(msgid), cls)
    return defs


def _message_def(msgid: int, cls: Any) -> MessageDef:
    """Build the wire dtype of one pymavlink message class from its struct format."""
    tokens = re.findall(r"(\d*)([a-zA-Z])", cls.unpacker.format.lstrip("<"))
    names = list(cls.ordered_fieldnames)
    if len(tokens) != len(names):
        raise ConfigError(f"{cls.msgname}: struct format does not match its fields")
    spec: list[tuple[Any, ...]] = []
    strings = set()
    for name, (count, code), array_len in zip(names, tokens, cls.array_lengths, strict=True):
        if code == "s" or code == "c":
            spec.append((name, f"S{int(count or 1)}"))
            strings.add(name)
        elif array_len:
            spec.append((name, _STRUCT_TO_NUMPY[code], (int(array_len),)))
        else:
            spec.append((name, _STRUCT_TO_NUMPY[code]))
    dtype = np.dtype(spec)
    if dtype.itemsize != cls.unpacker.size:
        raise ConfigError(f"{cls.msgname}: payload size mismatch")
    fields = tuple(cls.fieldnames)
    time_field = next((f for f in ("time_boot_ms", "time_usec") if f in fields), None)
    return MessageDef(
        msgid, cls.msgname, int(cls.crc_extra), dtype, fields, frozenset(strings), time_field
    )


# ----------------------------------------------------------------------------- CRC


def _crc_tables() -> tuple[NDArray[np.uint16], NDArray[np.uint16]]:
    """Lookup tables of the X.25 CRC (CRC-16/MCRF4XX, reflected polynomial 0x8408).

    The first advances the CRC by one byte: ``crc = (crc >> 8) ^ T1[(crc ^ byte) & 0xFF]``;
    the second by two bytes at once: ``crc = T2[crc ^ (byte0 | byte1 << 8)]``.
    """
    one = np.arange(256, dtype=np.uint32)
    for _ in range(8):
        one = np.where(one & 1, (one >> 1) ^ 0x8408, one >> 1)
    v = np.arange(65536, dtype=np.uint32)
    first = one[v & 0xFF]
    two = (first >> 8) ^ one[((v >> 8) ^ first) & 0xFF]
    return one.astype(np.uint16), two.astype(np.uint16)


_CRC_BYTE, _CRC_WORD = _crc_tables()


def _x25(rows: NDArray[np.uint8], extra: NDArray[np.uint8]) -> NDArray[np.uint16]:
    """X.25 CRC of each row of ``rows`` followed by its ``extra`` byte (one per row)."""
    data = np.column_stack([rows, extra])
    odd = data.shape[1] % 2
    words = np.ascontiguousarray(data[:, : data.shape[1] - odd]).view("<u2").T.copy()
    crc = np.full(data.shape[0], 0xFFFF, dtype=np.uint16)
    index = np.empty_like(crc)
    for word in words:
        np.bitwise_xor(crc, word, out=index)
        _CRC_WORD.take(index, out=crc)
    if odd:
        last = _CRC_BYTE.take((crc ^ data[:, -1]) & 0xFF)
        np.bitwise_xor(crc >> 8, last, out=crc)
    return crc


# ----------------------------------------------------------------------------- framing


@dataclass(frozen=True)
class _Frames:
    """Valid frames in file order and what had to be skipped around them."""

    payload: NDArray[np.signedinteger]  # payload start (int32 in files under 2 GiB)
    length: NDArray[np.uint8]  # payload bytes on the wire
    msgid: NDArray[np.int32]
    sysid: NDArray[np.uint8]
    compid: NDArray[np.uint8]
    recv_s: NDArray[np.float64]
    skipped_bytes: int  # not decoded
    garbage_bytes: int  # not decoded and not a frame of unknown id either
    gaps: int  # places with garbage
    unknown: int  # well-formed frames of ids the dialect does not define


def _windows(buf: NDArray[np.uint8], at: NDArray[np.integer], width: int) -> NDArray[np.uint8]:
    """Copy of ``buf[a:a+width]`` for every ``a`` in ``at``, one row each, zeros past the
    end of ``buf``.

    Gathered as items of ``width`` opaque bytes (one block copy per row) from an
    overlapping view, about twice as fast as indexing the rows of a sliding-window view
    (a byte-by-byte copy). ``buf`` is the file itself (memory-mapped): the few windows
    that run past its end are read from a zero-padded copy of its last bytes.

    Examples
    --------
    >>> _windows(np.arange(10, dtype=np.uint8), np.array([0, 7, 9]), 3).tolist()
    [[0, 1, 2], [7, 8, 9], [9, 0, 0]]
    """
    n = buf.size
    if width <= 0:
        return np.zeros((at.size, 0), np.uint8)
    if at.size and int(at.max()) > n - width:
        over = at > n - width
        out = np.empty((at.size, width), np.uint8)
        if not over.all():
            out[~over] = _windows(buf, at[~over], width)
        lo = max(n - width, 0)
        tail = np.zeros(n - lo + width, np.uint8)
        tail[: n - lo] = buf[lo:]
        out[over] = _windows(tail, at[over] - lo, width)
        return out
    rows = np.ndarray((n - width + 1,), dtype=np.dtype((np.void, width)), buffer=buf,
                      strides=(1,))
    return rows[at].view(np.uint8).reshape(-1, width)


def _release(buf: NDArray[np.uint8], lo: int, hi: int) -> None:
    """Hand bytes ``lo..hi`` of the memory-mapped file ``buf`` back to the kernel: their
    pages leave the process's resident set (they stay in the page cache and come back on
    the next touch), so that reading the file does not map all of it into the process on
    top of the tables decoded from it."""
    base = buf.base.obj if isinstance(buf.base, memoryview) else buf.base
    if not isinstance(base, mmap.mmap) or not hasattr(mmap, "MADV_DONTNEED"):
        return
    lo = max(lo, 0) // mmap.PAGESIZE * mmap.PAGESIZE
    hi = min(hi, len(base))
    if hi - lo < 1 << 20:
        return
    try:
        base.madvise(mmap.MADV_DONTNEED, lo, hi - lo)
    except (OSError, ValueError):  # not supported here: only memory use differs
        pass


def _offset_dtype(size: int) -> type[np.signedinteger]:
    """Integer type for byte offsets into a ``size``-byte file (room for a record's end)."""
    return np.int32 if size < 2**31 - 1024 else np.int64


_BLOCK = 1 << 24  # candidates are checked block by block: bounded memory, warm caches
_NONE = np.zeros(0, dtype=np.int64)
_MAX_RECORD = _PREFIX + 10 + 255 + 2 + _SIGNATURE_LEN


def _scan(buf: NDArray[np.uint8], size: int, defs: dict[int, MessageDef]) -> _Frames:
    """Find every valid record in ``buf`` (``size`` bytes).

    What is kept per frame is compact (offsets as ``int32`` in files under 2 GiB, ids and
    lengths as bytes): the frames' arrays stay well under the decoded tables' size."""
    ids = np.array(sorted(defs), dtype=np.int64)
    extras = np.array([defs[i].crc_extra for i in ids.tolist()], dtype=np.uint8)
    longest = np.array([defs[i].dtype.itemsize for i in ids.tolist()], dtype=np.int64)
    blocks = []
    for lo in range(0, size, _BLOCK):
        blocks.append(list(_scan_block(buf, size, lo, min(lo + _BLOCK, size), ids, extras,
                                       longest)))
        _release(buf, lo - _BLOCK, lo)  # the file pages scanned leave the resident set
    _release(buf, 0, size)
    fields = []
    for k in range(len(blocks[0]) if blocks else 0):  # joined a field at a time, freed as
        fields.append(np.concatenate([b[k] for b in blocks]))  # it goes (bounded peak)
        for b in blocks:
            b[k] = _NONE
    if not fields:
        fields = [_NONE] * 9
    pos_dt = _offset_dtype(size)
    del blocks
    start, end, hdr, mlen, msgid, sysid, compid, odd_start, odd_end = fields
    del fields
    valid = _resolve_overlaps(start, end, size)
    first, last = start[valid], end[valid]
    del start, end
    hdr = hdr[valid]
    mlen, sysid, compid, msgid = mlen[valid], sysid[valid], compid[valid], msgid[valid]
    odd = _unknown_frames(odd_start, odd_end, first, last, size)
    # gaps: bytes in neither a valid frame nor a frame of unknown id
    starts = np.concatenate([first, odd_start[odd]])
    order = np.argsort(starts, kind="stable")
    starts, ends = starts[order], np.concatenate([last, odd_end[odd]])[order]
    gaps = int(np.count_nonzero(starts[1:] != ends[:-1])) if starts.size else 0
    if starts.size:
        gaps += int(starts[0] != 0) + int(ends[-1] != size)
    recv_s = _streamed(buf, first, _PREFIX).view(">u8")[:, 0].astype(np.float64)
    recv_s *= 1e-6
    payload = first + np.asarray(_PREFIX, pos_dt)
    payload += hdr
    skipped = int(size - (last - first).sum(dtype=np.int64))
    del first, last, hdr
    return _Frames(
        payload=payload,
        length=mlen,
        msgid=msgid,
        sysid=sysid,
        compid=compid,
        recv_s=recv_s,
        skipped_bytes=skipped,
        garbage_bytes=int(size - (ends - starts).sum(dtype=np.int64)),
        gaps=gaps,
        unknown=int(np.count_nonzero(odd)),
    )


def _in_blocks(buf: NDArray[np.uint8], at: NDArray[np.integer]) -> Iterator[tuple[int, int]]:
    """Index ranges ``(a, b)`` of the ascending file offsets ``at``, one per :data:`_BLOCK`
    of the file; once the caller is done with a range the file's pages behind it are handed
    back, so that a gather over the whole file never maps all of it into the process again
    (a 100 MB .tlog's read peaked 100 MB higher)."""
    if not at.size:
        return
    edges = np.arange(int(at[0]) + _BLOCK, int(at[-1]) + 1, _BLOCK)
    a = 0
    for b in [*np.searchsorted(at, edges).tolist(), at.size]:
        if b > a:
            yield a, b
            _release(buf, int(at[a]) - _BLOCK, int(at[a]))
        a = b


def _streamed(buf: NDArray[np.uint8], at: NDArray[np.integer], width: int
              ) -> NDArray[np.uint8]:
    """:func:`_windows` of offsets ``at`` in ascending (file) order, a block at a time
    (:func:`_in_blocks`)."""
    out = np.empty((at.size, width), np.uint8)
    for a, b in _in_blocks(buf, at):
        out[a:b] = _windows(buf, at[a:b], width)
    return out


def _scan_block(
    buf: NDArray[np.uint8],
    size: int,
    lo: int,
    hi: int,
    ids: NDArray[np.int64],
    extras: NDArray[np.uint8],
    longest: NDArray[np.int64],
) -> tuple[NDArray[np.int64], ...]:
    """Candidate records starting in ``[lo, hi)``: the CRC-valid ones (start, end, header
    length, payload length, msgid, sysid, compid) and the well-formed ones of unknown id
    that chain on (start, end)."""
    top = min(hi + _MAX_RECORD, size)  # candidates up to here, to see chains leave the block
    magic = buf[lo + _PREFIX : top + _PREFIX]
    every = np.flatnonzero(magic >= _MAGIC_V2)  # 0xFD, 0xFE (or 0xFF, dropped next)
    every = lo + every[magic[every] != 0xFF].astype(np.int64)
    own = int(np.searchsorted(every, hi))
    slices = [_check(buf, size, every[a : min(a + _SLICE, own)], every, ids, extras, longest)
              for a in range(0, own, _SLICE)]  # fmt: skip
    if not slices:
        pos_dt = _offset_dtype(size)
        return tuple(np.zeros(0, dt) for dt in (pos_dt, pos_dt, np.uint8, np.uint8, np.int32,
                                                 np.uint8, np.uint8, pos_dt, pos_dt))
    return tuple(np.concatenate(parts) for parts in zip(*slices, strict=True))


_SLICE = 1 << 16  # candidates checked at once: bounded temporaries (~40 bytes each)


def _check(
    buf: NDArray[np.uint8],
    size: int,
    s: NDArray[np.int64],
    every: NDArray[np.int64],
    ids: NDArray[np.int64],
    extras: NDArray[np.uint8],
    longest: NDArray[np.int64],
) -> tuple[NDArray[np.int64], ...]:
    """:func:`_scan_block` for the candidates ``s`` (sorted), ``every`` being all candidate
    starts around them (for the chain check). A known id whose payload is longer than its
    message (a MAVLink 2 payload may be shorter, truncated, never longer) is no frame: that
    costs no CRC (a flood of 0xFE bytes is 0xFE-long "frames" of id 254, 9 bytes long)."""
    head = _windows(buf, s + _PREFIX, 10)
    v2 = head[:, 0] == _MAGIC_V2
    incompat = np.where(v2, head[:, 2], 0).astype(np.int64)
    mlen = head[:, 1].astype(np.int64)
    hdr = np.where(v2, 10, 6)
    end = s + _PREFIX + hdr + mlen + 2 + np.where(incompat & _IFLAG_SIGNED, _SIGNATURE_LEN, 0)
    keep = np.flatnonzero((end <= size) & ((incompat & ~_IFLAG_SIGNED) == 0))  # well-formed
    s, head, v2, mlen, hdr, end = s[keep], head[keep], v2[keep], mlen[keep], hdr[keep], end[keep]
    msgid = np.where(
        v2,
        head[:, 7].astype(np.int64) | (head[:, 8].astype(np.int64) << 8)
        | (head[:, 9].astype(np.int64) << 16),
        head[:, 5],
    )
    pos = np.minimum(np.searchsorted(ids, msgid), ids.size - 1)
    listed = ids[pos] == msgid
    known = listed & (mlen <= longest[pos])
    chained = (end == size) | _member(end, every)

    # CRC first of the candidates that chain into another candidate (or the file's end),
    # then of the others that do not lie inside a frame found valid by then
    crc_extra = extras[pos]
    ok = np.zeros(s.size, dtype=bool)
    ok[known & chained] = _crc_ok(buf, s, hdr, mlen, crc_extra, known & chained)
    rest = np.flatnonzero(known & ~chained)
    rest = rest[~_inside(s[rest], s[ok], end[ok])]
    ok[rest] = _crc_ok(buf, s, hdr, mlen, crc_extra, rest)
    odd = ~listed & chained  # well-formed frames of ids the dialect does not have
    sysid = np.where(v2, head[:, 5], head[:, 3]).astype(np.int64)
    compid = np.where(v2, head[:, 6], head[:, 4]).astype(np.int64)
    # compact types for what is kept per frame (offsets: int32 in files under 2 GiB; payload
    # length, header length and ids: bytes; message id: 24 bits)
    pos_dt = _offset_dtype(size)
    return (s[ok].astype(pos_dt), end[ok].astype(pos_dt), hdr[ok].astype(np.uint8),
            mlen[ok].astype(np.uint8), msgid[ok].astype(np.int32), sysid[ok].astype(np.uint8),
            compid[ok].astype(np.uint8), s[odd].astype(pos_dt), end[odd].astype(pos_dt))


def _crc_ok(
    buf: NDArray[np.uint8],
    s: NDArray[np.int64],
    hdr: NDArray[np.int64],
    mlen: NDArray[np.int64],
    crc_extra: NDArray[np.uint8],
    pick: NDArray[np.bool_] | NDArray[np.int64],
) -> NDArray[np.bool_]:
    """Whether the picked candidates' (mask or indices) CRC, from after the magic byte to
    the payload's end then CRC_EXTRA, matches the two bytes after the payload; computed in
    groups of equal length."""
    check = np.flatnonzero(pick) if pick.dtype == bool else pick
    crc_len = (hdr - 1 + mlen)[check]
    order = np.argsort(crc_len.astype(np.uint16), kind="stable")  # radix sort
    counts = np.bincount(crc_len)
    ok = np.zeros(check.size, dtype=bool)
    for width, part in enumerate(np.split(order, np.cumsum(counts)[:-1])):
        if not part.size:
            continue
        for lo in range(0, part.size, _CRC_CHUNK):  # chunks small enough to stay in cache
            sub = part[lo : lo + _CRC_CHUNK]
            rows = check[sub]
            body = s[rows] + _PREFIX + 1
            got = _x25(_windows(buf, body, width), crc_extra[rows])
            tail = _windows(buf, body + width, 2).astype(np.uint16)
            ok[sub] = got == (tail[:, 0] | (tail[:, 1] << 8))
    return ok


_CRC_CHUNK = 32768


def _member(x: NDArray[np.int64], ordered: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Whether each ``x`` is in the sorted array ``ordered``."""
    if not ordered.size:
        return np.zeros(x.shape, dtype=bool)
    return ordered[np.minimum(np.searchsorted(ordered, x), ordered.size - 1)] == x


def _inside(
    x: NDArray[np.int64], start: NDArray[np.int64], end: NDArray[np.int64]
) -> NDArray[np.bool_]:
    """Whether each ``x`` lies inside one of the records ``[start, end)`` (sorted by start)."""
    i = np.searchsorted(start, x, side="right") - 1
    return (i >= 0) & (end[np.maximum(i, 0)] > x) if start.size else np.zeros(x.size, bool)


def _resolve_overlaps(
    start: NDArray[np.int64], end: NDArray[np.int64], size: int
) -> NDArray[np.bool_]:
    """Which of these CRC-valid records (sorted by start) to keep so that none overlap.

    In a clean file records tile it exactly, and a chance CRC match can only start inside a
    real record, which comes first: keeping records in file order keeps the real ones. Where
    candidates overlap, those that chain (end where another candidate starts, or at the end
    of the file) are preferred, then the others in file order.
    """
    keep = np.ones(start.size, dtype=bool)
    if start.size < 2:
        return keep
    reach = np.maximum.accumulate(end)
    fresh = np.ones(start.size, dtype=bool)
    fresh[1:] = start[1:] >= reach[:-1]
    if fresh.all():
        return keep
    bounds = np.append(np.flatnonzero(fresh), start.size)
    chained = _member(end, start) | (end == size)
    for c in np.flatnonzero(np.diff(bounds) > 1).tolist():
        lo, hi = int(bounds[c]), int(bounds[c + 1])
        chosen: list[int] = []
        for preferred in (True, False):
            for k in range(lo, hi):
                if bool(chained[k]) == preferred and all(
                    end[k] <= start[j] or start[k] >= end[j] for j in chosen
                ):
                    chosen.append(k)
        keep[lo:hi] = False
        keep[chosen] = True
    return keep


def _unknown_frames(
    start: NDArray[np.int64],
    end: NDArray[np.int64],
    good_start: NDArray[np.int64],
    good_end: NDArray[np.int64],
    size: int,
) -> NDArray[np.bool_]:
    """Which well-formed frames of unknown message id (sorted by start) lie between valid
    records, chain on (end where a record starts, or at the end of the file) and do not
    overlap one another: frames of another dialect rather than garbage."""
    if not start.size:
        return np.zeros(0, dtype=bool)
    i = np.searchsorted(good_start, start, side="right")  # the valid record before: i - 1
    after_prev = np.concatenate([[0], good_end])[i] <= start
    fits = after_prev & (end <= np.append(good_start, size)[i])
    fits &= _member(end, good_start) | (end == size) | _member(end, start)
    pick = np.flatnonzero(fits)
    if pick.size > 1:  # drop any overlapping an earlier one
        clash = start[pick[1:]] < np.maximum.accumulate(end[pick])[:-1]
        pick = pick[np.concatenate([[True], ~clash])]
    keep = np.zeros(start.size, dtype=bool)
    keep[pick] = True
    return keep


# ----------------------------------------------------------------------------- decoding


def _payloads(
    buf: NDArray[np.uint8], frames: _Frames, rows: NDArray[np.int64], width: int, at: int = 0,
) -> NDArray[np.uint8]:
    """``width`` payload bytes from offset ``at`` of the given frames, zeros past their end
    (a MAVLink 2 payload is sent without its trailing zeros)."""
    raw = _windows(buf, frames.payload[rows] + at, width)
    length = frames.length[rows].astype(np.int64) - at
    short = np.flatnonzero(length < width)
    if short.size:
        cut = np.arange(width)[None, :] >= length[short, None]
        raw[short] = np.where(cut, 0, raw[short])
    return raw


def _own_times(buf: NDArray[np.uint8], frames: _Frames, groups: dict[int, NDArray[np.int64]],
               defs: dict[int, MessageDef]) -> dict[int, NDArray[np.float64] | None]:
    """Per message id its own clock in seconds, None when it has none (or a UNIX time).

    Gathered a block of the file at a time for all ids together, the pages behind handed
    back: each page is mapped once, and never all of the file at once."""
    fields = {i: mdef.dtype.fields[mdef.time_field][:2]  # type: ignore[index]
              for i in groups if (mdef := defs[i]).time_field is not None}
    raw = {i: np.zeros((groups[i].size, base.itemsize), np.uint8)
           for i, (base, _) in fields.items()}
    for a, b in _in_blocks(buf, frames.payload):
        for i, (base, offset) in fields.items():
            rows = groups[i]
            ra, rb = np.searchsorted(rows, (a, b)).tolist()
            if rb > ra:
                raw[i][ra:rb] = _payloads(buf, frames, rows[ra:rb], base.itemsize, offset)
    out: dict[int, NDArray[np.float64] | None] = {i: None for i in groups}
    for i, (base, _) in fields.items():
        value = raw.pop(i).view(base)[:, 0].astype(np.float64)
        if defs[i].time_field == "time_boot_ms":
            out[i] = value * 1e-3
        elif not (value.size and float(np.median(value)) > _UNIX_USEC):
            out[i] = value * 1e-6
    return out


def _strings(column: NDArray[Any]) -> NDArray[np.object_]:
    """Char arrays as ``str``: up to the first NUL, ASCII, undecodable bytes replaced."""
    uniq, inverse = np.unique(column, return_inverse=True)
    text = [b.split(b"\0", 1)[0].decode("ascii", errors="replace") for b in uniq.tolist()]
    out = np.empty(len(text), dtype=object)
    out[:] = text
    return out[inverse.ravel()]


def _table(
    buf: NDArray[np.uint8],
    frames: _Frames,
    rows: NDArray[np.int64],
    mdef: MessageDef,
    time_s: NDArray[np.float64],
    units: dict[str, str],
) -> MessageTable:
    """Decode one message type's frames (``rows`` ascending: file order) into a table.

    The payloads are gathered a block of the file at a time (:func:`_in_blocks`, the pages
    behind handed back) and each block's fields copied into columns made beforehand: the
    whole type's raw records never exist beside its columns (a 100 MB .tlog's read peaked
    ~10 MB higher with them)."""
    dtype = mdef.dtype
    columns: dict[str, NDArray[Any]] = {
        name: np.empty((rows.size, *dtype.fields[name][0].shape),  # type: ignore[index]
                       dtype.fields[name][0].base)  # type: ignore[index]
        for name in mdef.fields}  # fmt: skip
    for a, b in _in_blocks(buf, frames.payload[rows]):
        rec = _payloads(buf, frames, rows[a:b], dtype.itemsize).view(dtype)[:, 0]
        for name, column in columns.items():
            column[a:b] = rec[name]
    for name in mdef.strings:
        columns[name] = _strings(columns[name])
    columns["_sysid"] = frames.sysid[rows].astype(np.uint8)
    columns["_compid"] = frames.compid[rows].astype(np.uint8)
    columns["_recv_time_s"] = frames.recv_s[rows]
    return MessageTable(mdef.name, columns, time_s, units={**units, "_recv_time_s": "s"})


# ----------------------------------------------------------------------------- reading


def _load(path: str | os.PathLike[str]) -> tuple[NDArray[np.uint8], int, mmap.mmap | None]:
    """The file's bytes (memory-mapped, not copied; a small file read whole), its size and
    the map to close once read."""
    try:
        with open(path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            if size < 1 << 16:
                return np.frombuffer(f.read(), np.uint8), size, None
            mm = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
    except OSError as exc:
        raise LogFormatError(f"cannot read: {exc.strerror or exc}", path=path) from None
    if len(mm) != size:
        mm.close()
        raise LogFormatError("file changed while reading", path=path)
    return np.frombuffer(mm, np.uint8), size, mm


def _vehicles(hb: MessageTable | None) -> tuple[tuple[int, int, int, int] | None, set[int]]:
    """(sysid, compid, autopilot, type) of the first heartbeat that is probably a vehicle's
    (None if none is), and the system ids of all such heartbeats."""
    if hb is None:
        return None, set()
    vehicle = (
        (hb["_compid"] != _MAV_COMP_ID_GIMBAL)
        & ~np.isin(hb["type"], _NOT_VEHICLE_TYPES)
        & (hb["autopilot"] != _MAV_AUTOPILOT_INVALID)
    )
    rows = np.flatnonzero(vehicle)
    if not rows.size:
        return None, set()
    k = int(rows[0])
    main = (int(hb["_sysid"][k]), int(hb["_compid"][k]), int(hb["autopilot"][k]),
            int(hb["type"][k]))  # fmt: skip
    return main, set(hb["_sysid"][rows].tolist())


_MAV_COMP_ID_GIMBAL = 154
_NOT_VEHICLE_TYPES = (_MAV_TYPE_GCS, 18, 26, 27)  # GCS, onboard controller, gimbal, ADSB


def _of(table: MessageTable | None, sysid: int, compid: int) -> NDArray[np.bool_] | None:
    """Rows of ``table`` sent by one component (None when there is no table)."""
    if table is None:
        return None
    return (table["_sysid"] == sysid) & (table["_compid"] == compid)


def _params(table: MessageTable | None, vehicle: tuple[int, int, int, int]
            ) -> tuple[dict[str, float], tuple[ParamChange, ...]]:
    """PARAM_VALUE of the main vehicle: the last value of each name, and the values that
    changed one after its first (a ground station fetches every parameter when it
    connects; the vehicle answers each later PARAM_SET with a PARAM_VALUE).

    PX4 sends integer parameters byte-wise in the float (MAVLink's PARAM_ENCODE_BYTEWISE):
    for it, ``MAV_PARAM_TYPE_UINT32``/``INT32`` values are reinterpreted as integers.
    """
    rows = _of(table, *vehicle[:2])
    if table is None or rows is None:
        return {}, ()
    names = table["param_id"][rows]
    value = table["param_value"][rows].astype(np.float32)
    kind = table["param_type"][rows]
    out = value.astype(np.float64)
    if vehicle[2] == 12:
        for code, as_int in ((5, np.uint32), (6, np.int32)):
            pick = kind == code
            out[pick] = value[pick].view(as_int).astype(np.float64)
    records = zip(table.time_s[rows].tolist(), names.tolist(), out.tolist(), strict=True)
    return (dict(zip(names.tolist(), out.tolist(), strict=True)),
            param_changes({}, records))


def _texts(table: MessageTable | None, sysid: int | None) -> tuple[TextMessage, ...]:
    """STATUSTEXT messages of one system (all when None); chunked ones (``id`` != 0)
    joined in order."""
    if table is None:
        return ()
    out: list[TextMessage] = []
    pending: dict[tuple[int, int], int] = {}  # (sysid, id) -> index in out
    has_id = "id" in table
    rows = range(len(table)) if sysid is None else np.flatnonzero(table["_sysid"] == sysid)
    for k in rows:
        text, sev = str(table["text"][k]), int(table["severity"][k])
        key = (int(table["_sysid"][k]), int(table["id"][k]) if has_id else 0)
        if key[1] and key in pending and int(table["chunk_seq"][k]) > 0:
            i = pending[key]
            out[i] = TextMessage(out[i].time_s, out[i].text + text, out[i].severity)
            continue
        if key[1]:
            pending[key] = len(out)
        out.append(TextMessage(float(table.time_s[k]), text, sev))
    return tuple(out)


def _modes(hb: MessageTable | None, vehicle: tuple[int, int, int, int]) -> tuple[ModeChange, ...]:
    """A ModeChange each time the main vehicle's heartbeat ``custom_mode`` changes."""
    rows = _of(hb, *vehicle[:2])
    if hb is None or rows is None:
        return ()
    mode = hb["custom_mode"][rows].astype(np.int64)
    time_s = hb.time_s[rows]
    change = np.flatnonzero(np.diff(mode, prepend=-1) != 0)
    names = _mode_names(vehicle[2], vehicle[3])
    return tuple(
        ModeChange(float(time_s[k]), int(mode[k]), names(int(mode[k]))) for k in change.tolist()
    )


def _mode_names(autopilot: int, mav_type: int) -> Any:
    """mode number -> name (or None), from the ArduPilot and PX4 mode tables
    (:mod:`mavsid.autopilot.modes`)."""
    if autopilot == 12:
        return px4_mode_name
    table = ardupilot_modes(mav_type) if autopilot == 3 else None
    return lambda mode: table.get(mode) if table else None


#: MAV_TYPE -> vehicle class (the words the DataFlash reader uses)
_VEHICLE_CLASSES = {
    1: "plane", 2: "copter", 3: "copter", 4: "heli", 5: "tracker", 7: "blimp", 10: "rover",
    11: "rover", 12: "sub", 13: "copter", 14: "copter", 15: "copter", 19: "plane",
    20: "plane", 21: "plane", 22: "plane", 23: "plane", 24: "plane", 25: "plane",
    29: "copter", 35: "copter",
}  # fmt: skip


def vehicle_class(mav_type: int) -> str | None:
    """The vehicle class of a MAVLink ``MAV_TYPE`` (also PX4's ``MAV_TYPE`` parameter).

    Examples
    --------
    >>> vehicle_class(2), vehicle_class(22), vehicle_class(11), vehicle_class(6)
    ('copter', 'plane', 'rover', None)
    """
    return _VEHICLE_CLASSES.get(int(mav_type))


_FIRMWARE = re.compile(r"^(Ardu\w+|APM:\w+|PX4\w*|Rover|AntennaTracker|Blimp)\s+V?\d")
_FRAME = "Frame:"


def _groups(keys: NDArray[np.integer]) -> dict[int, NDArray[np.int64]]:
    """key -> indices of ``keys`` equal to it, in their original order."""
    if not keys.size:
        return {}
    small = 0 <= keys.min() and keys.max() < 2**16  # then a radix sort
    order = np.argsort(keys.astype(np.uint16) if small else keys, kind="stable")
    ordered = keys[order]
    cut = np.flatnonzero(ordered[1:] != ordered[:-1]) + 1
    firsts = np.concatenate([[0], cut])
    return dict(zip(ordered[firsts].tolist(), np.split(order, cut), strict=True))


def _clock_offsets(
    pieces: list[tuple[NDArray[np.integer], NDArray[np.float64]]],
    vehicles: set[int],
    main: int | None,
) -> NDArray[np.float64]:
    """Per system id, the offset (vehicle clock - receive time) to put frames without a
    clock of their own on a vehicle's clock.

    A vehicle's own offset is the median over its time-stamped frames; systems that are no
    vehicle (ground stations, companion computers) take the main vehicle's, since the file
    has one receive clock. Without any vehicle: the median over all time-stamped frames.
    """
    sysid = np.concatenate([p[0] for p in pieces]) if pieces else np.zeros(0, np.int64)
    diff = np.concatenate([p[1] for p in pieces]) if pieces else np.zeros(0)
    ok = np.isfinite(diff)
    sysid, diff = sysid[ok], diff[ok]
    if main is None:
        return np.full(256, float(np.median(diff)) if diff.size else np.nan)
    per = {sid: float(np.median(diff[rows])) for sid, rows in _groups(sysid).items()}
    offsets = np.full(256, per.get(main, np.nan))
    for sid in vehicles & set(per):
        offsets[sid] = per[sid]
    return offsets


def read(
    path: str | os.PathLike[str],
    messages: Sequence[str] | None = None,
    start: float | None = None,
    stop: float | None = None,
    dialect: str = "ardupilotmega",
) -> RawLog:
    """Read a MAVLink ``.tlog`` into a :class:`~mavsid.data.RawLog`.

    Parameters
    ----------
    path : path-like
        The ``.tlog`` file.
    messages : sequence of str, optional
        Message names to give tables for (default all); params, texts and modes are always
        read.
    start, stop : float, optional
        Keep only samples (and texts, mode changes) with ``start <= time_s <= stop``
        (seconds on the vehicle's clock).
    dialect : str
        pymavlink dialect (module under ``pymavlink.dialects.v20``).

    Raises
    ------
    LogFormatError
        Empty or unreadable file, or no valid MAVLink frame in it.
    ConfigError
        Unknown dialect.

    Warns
    -----
    DataQualityWarning
        Bytes skipped (garbage, bad CRC, truncation), frames of message ids the dialect does
        not define, receive times running backwards or jumping.
    """
    defs = load_dialect(dialect)
    buf, size, mm = _load(path)
    try:
        return _read(path, buf, size, defs, messages, start, stop, dialect)
    finally:
        del buf
        if mm is not None:
            try:
                mm.close()
            except BufferError:  # a view is still referenced somewhere: leave it to the GC
                pass


def _read(
    path: str | os.PathLike[str],
    buf: NDArray[np.uint8],
    size: int,
    defs: dict[int, MessageDef],
    messages: Sequence[str] | None,
    start: float | None,
    stop: float | None,
    dialect: str,
) -> RawLog:
    """:func:`read` of the file's bytes ``buf``."""
    if size == 0:
        raise LogFormatError("empty file", path=path)
    frames = _scan(buf, size, defs)
    if not frames.payload.size:
        raise LogFormatError("no valid MAVLink frame found (not a .tlog?)", path=path)

    groups = _groups(frames.msgid)
    own = _own_times(buf, frames, groups, defs)
    _release(buf, 0, size)
    hb_id = next((i for i in groups if defs[i].name == "HEARTBEAT"), None)
    vehicle, vehicle_ids = _vehicles(
        None if hb_id is None else
        _table(buf, frames, groups[hb_id], defs[hb_id], np.array([]), {})
    )  # fmt: skip
    offsets = _clock_offsets(
        [(frames.sysid[groups[i]], t - frames.recv_s[groups[i]])
         for i, t in own.items() if t is not None],
        vehicle_ids,
        vehicle[0] if vehicle else None,
    )  # fmt: skip

    wanted = None if messages is None else set(messages)
    always = {"HEARTBEAT", "PARAM_VALUE", "STATUSTEXT"}
    tables: dict[str, MessageTable] = {}
    for i in list(groups):
        rows = groups.pop(i)  # (each type's indices freed as its table is built)
        mdef = defs[i]
        if wanted is not None and mdef.name not in wanted | always:
            continue
        t = own[i]
        time_s = t if t is not None else frames.recv_s[rows] + offsets[frames.sysid[rows]]
        tables[mdef.name] = _table(buf, frames, rows, mdef, time_s, _units(dialect, i))
        _release(buf, 0, size)  # the pages this table touched

    hb, pv, st = (tables.get(n) for n in ("HEARTBEAT", "PARAM_VALUE", "STATUSTEXT"))
    texts = _texts(st, vehicle[0] if vehicle else None)
    firmware = next((m.text for m in texts if _FIRMWARE.match(m.text)), None)
    params, changes = _params(pv, vehicle) if vehicle else ({}, ())
    modes = _modes(hb, vehicle) if vehicle else ()
    span = _span(frames, offsets, vehicle[0] if vehicle else None,
                 [t for i, t in own.items() if t is not None])
    if start is not None or stop is not None:
        lo = -np.inf if start is None else start
        hi = np.inf if stop is None else stop
        if span is not None:
            span = (max(span[0], lo), max(min(span[1], hi), max(span[0], lo)))
        tables = {n: _window(t, lo, hi) for n, t in tables.items()}
        texts = tuple(m for m in texts if lo <= m.time_s <= hi)
        modes = tuple(m for m in modes if lo <= m.time_s <= hi)
        changes = tuple(c for c in changes if lo <= c.time_s <= hi)
    if wanted is not None:
        tables = {n: t for n, t in tables.items() if n in wanted}

    notes = _quality_notes(frames, dialect)
    if notes:
        warnings.warn(f"{path}: " + "; ".join(notes), DataQualityWarning, stacklevel=2)
    autopilot = _MAV_AUTOPILOT.get(vehicle[2], "unknown") if vehicle else "unknown"
    vehicle_name = vehicle_class(vehicle[3]) if vehicle else None
    frame = next((m.text[len(_FRAME):].strip() for m in texts if m.text.startswith(_FRAME)), "")
    if vehicle_name and frame:
        vehicle_name = f"{vehicle_name} {frame}"
    return RawLog(
        source=SourceInfo(str(path), "tlog", size, frames.skipped_bytes, tuple(notes)),
        messages=tables,
        params=params,
        texts=texts,
        modes=modes,
        autopilot=autopilot,
        vehicle=vehicle_name,
        firmware=firmware,
        span_s=span,
        param_changes=changes,
    )


def _span(frames: _Frames, offsets: NDArray[np.float64], main: int | None,
          own: Sequence[NDArray[np.float64]] = ()) -> tuple[float, float] | None:
    """The file's span as pymavlink has it (first to last receive time), on the main
    vehicle's clock. None (the span of the records' times then stands) when the receive
    clock runs backwards or jumps, when no frame carries a vehicle clock, or when more than
    1 % of the vehicles' own time stamps lie outside it (a file whose receive times were
    rewritten)."""
    recv = frames.recv_s
    step = np.diff(recv)
    offset = float(offsets[main] if main is not None else offsets[0])
    if not recv.size or not np.isfinite(offset) or np.any(step < 0) or np.any(
            step > _TIME_JUMP_S):
        return None
    lo, hi = float(recv[0] + offset), float(recv[-1] + offset)
    tol = max(2.0, 0.05 * (hi - lo))
    times = np.concatenate([t[np.isfinite(t)] for t in own]) if own else np.zeros(0)
    outside = np.count_nonzero((times < lo - tol) | (times > hi + tol))
    if outside > 0.01 * times.size:  # (a stray zero time stamp here and there is no reason)
        return None
    return lo, hi


@functools.lru_cache(maxsize=1024)
def _units(dialect: str, msgid: int) -> dict[str, str]:
    """Field units the dialect declares for one message; its instance field (e.g.
    ``RAW_IMU.id``, ``PID_TUNING.axis``) marked ``"instance"`` as DataFlash does."""
    cls = importlib.import_module(f"pymavlink.dialects.v20.{dialect}").mavlink_map[msgid]
    units = dict(getattr(cls, "fieldunits_by_name", {}) or {})
    if getattr(cls, "instance_field", None):
        units[cls.instance_field] = "instance"
    return units


def _window(table: MessageTable, lo: float, hi: float) -> MessageTable:
    """Rows of ``table`` with ``lo <= time_s <= hi``."""
    keep = (table.time_s >= lo) & (table.time_s <= hi)
    columns = {n: c[keep] for n, c in table.columns.items()}
    return MessageTable(table.name, columns, table.time_s[keep], table.units)


def _quality_notes(frames: _Frames, dialect: str) -> list[str]:
    """Counts of what was skipped or suspicious, one phrase each."""
    notes = []
    if frames.garbage_bytes:
        notes.append(
            f"skipped {frames.garbage_bytes} bytes in {frames.gaps} places "
            "(garbage, bad CRC or truncated frames)"
        )
    if frames.unknown:
        unknown_bytes = frames.skipped_bytes - frames.garbage_bytes
        notes.append(
            f"skipped {frames.unknown} frames ({unknown_bytes} bytes) of message ids "
            f"unknown to dialect {dialect!r}"
        )
    step = np.diff(frames.recv_s)
    back, jump = int(np.count_nonzero(step < 0)), int(np.count_nonzero(step > _TIME_JUMP_S))
    if back or jump:
        notes.append(
            f"receive time runs backwards {back} times and jumps forward by more than "
            f"{_TIME_JUMP_S:.0f} s {jump} times"
        )
    return notes
