"""The valid MAVLink frames of a ``.tlog``, found at once over the whole file.

A record is an 8-byte big-endian receive time in microseconds, then one MAVLink frame:

- v1: ``0xFE len seq sysid compid msgid payload crc(2)``
- v2: ``0xFD len incompat compat seq sysid compid msgid(3) payload crc(2) [signature(13)]``.

Every byte offset where a record could start is a candidate (its magic byte 8 bytes on);
candidates are checked by length, flags, a known message id and the X.25 CRC seeded with the
message's CRC_EXTRA, all as numpy operations grouped by frame length; overlapping survivors
are resolved in file order, preferring frames that chain into the next record
(:func:`scan_frames`). What is kept per frame is compact (about 20 bytes,
:class:`Frames`), and the file's pages are handed back as the scan goes
(:func:`release`).

Examples
--------
>>> from pymavlink.dialects.v20 import ardupilotmega as mavlink
>>> from mavsid.readers.mavlink_dialect import load_dialect
>>> mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
>>> frame = mav.attitude_encode(5000, 0.1, -0.2, 1.5, 0.0, 0.0, 0.0).pack(mav)
>>> raw = np.frombuffer(bytes(8) + frame + b"junk", np.uint8)
>>> frames = scan_frames(raw, raw.size, load_dialect())
>>> frames.msgid.tolist(), frames.skipped_bytes
([30], 4)
"""

from __future__ import annotations

import mmap
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mavsid.readers.mavlink_dialect import MessageDef

__all__ = ["BLOCK", "PREFIX", "Frames", "in_blocks", "payloads", "release", "scan_frames",
           "windows"]

PREFIX = 8  # receive-time bytes before every frame
_MAGIC_V1, _MAGIC_V2 = 0xFE, 0xFD
_IFLAG_SIGNED = 0x01
_SIGNATURE_LEN = 13

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
class Frames:
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


def windows(buf: NDArray[np.uint8], at: NDArray[np.integer], width: int) -> NDArray[np.uint8]:
    """Copy of ``buf[a:a+width]`` for every ``a`` in ``at``, one row each, zeros past the
    end of ``buf``.

    Gathered as items of ``width`` opaque bytes (one block copy per row) from an
    overlapping view, about twice as fast as indexing the rows of a sliding-window view
    (a byte-by-byte copy). ``buf`` is the file itself (memory-mapped): the few windows
    that run past its end are read from a zero-padded copy of its last bytes.

    Examples
    --------
    >>> windows(np.arange(10, dtype=np.uint8), np.array([0, 7, 9]), 3).tolist()
    [[0, 1, 2], [7, 8, 9], [9, 0, 0]]
    """
    n = buf.size
    if width <= 0:
        return np.zeros((at.size, 0), np.uint8)
    if at.size and int(at.max()) > n - width:
        over = at > n - width
        out = np.empty((at.size, width), np.uint8)
        if not over.all():
            out[~over] = windows(buf, at[~over], width)
        lo = max(n - width, 0)
        tail = np.zeros(n - lo + width, np.uint8)
        tail[: n - lo] = buf[lo:]
        out[over] = windows(tail, at[over] - lo, width)
        return out
    rows = np.ndarray((n - width + 1,), dtype=np.dtype((np.void, width)), buffer=buf,
                      strides=(1,))
    return rows[at].view(np.uint8).reshape(-1, width)


def release(buf: NDArray[np.uint8], lo: int, hi: int) -> None:
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


BLOCK = 1 << 24  # candidates are checked block by block: bounded memory, warm caches
_NONE = np.zeros(0, dtype=np.int64)
_MAX_RECORD = PREFIX + 10 + 255 + 2 + _SIGNATURE_LEN


def scan_frames(buf: NDArray[np.uint8], size: int, defs: dict[int, MessageDef]) -> Frames:
    """Find every valid record in ``buf`` (``size`` bytes).

    What is kept per frame is compact (offsets as ``int32`` in files under 2 GiB, ids and
    lengths as bytes): the frames' arrays stay well under the decoded tables' size."""
    ids = np.array(sorted(defs), dtype=np.int64)
    extras = np.array([defs[i].crc_extra for i in ids.tolist()], dtype=np.uint8)
    longest = np.array([defs[i].dtype.itemsize for i in ids.tolist()], dtype=np.int64)
    blocks = []
    for lo in range(0, size, BLOCK):
        blocks.append(list(_scan_block(buf, size, lo, min(lo + BLOCK, size), ids, extras,
                                       longest)))
        release(buf, lo - BLOCK, lo)  # the file pages scanned leave the resident set
    release(buf, 0, size)
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
    recv_s = _streamed(buf, first, PREFIX).view(">u8")[:, 0].astype(np.float64)
    recv_s *= 1e-6
    payload = first + np.asarray(PREFIX, pos_dt)
    payload += hdr
    skipped = int(size - (last - first).sum(dtype=np.int64))
    del first, last, hdr
    return Frames(
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


def in_blocks(buf: NDArray[np.uint8], at: NDArray[np.integer]) -> Iterator[tuple[int, int]]:
    """Index ranges ``(a, b)`` of the ascending file offsets ``at``, one per :data:`BLOCK`
    of the file; once the caller is done with a range the file's pages behind it are handed
    back, so that a gather over the whole file never maps all of it into the process again
    (a 100 MB .tlog's read peaked 100 MB higher)."""
    if not at.size:
        return
    edges = np.arange(int(at[0]) + BLOCK, int(at[-1]) + 1, BLOCK)
    a = 0
    for b in [*np.searchsorted(at, edges).tolist(), at.size]:
        if b > a:
            yield a, b
            release(buf, int(at[a]) - BLOCK, int(at[a]))
        a = b


def _streamed(buf: NDArray[np.uint8], at: NDArray[np.integer], width: int
              ) -> NDArray[np.uint8]:
    """:func:`windows` of offsets ``at`` in ascending (file) order, a block at a time
    (:func:`in_blocks`)."""
    out = np.empty((at.size, width), np.uint8)
    for a, b in in_blocks(buf, at):
        out[a:b] = windows(buf, at[a:b], width)
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
    magic = buf[lo + PREFIX : top + PREFIX]
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
    head = windows(buf, s + PREFIX, 10)
    v2 = head[:, 0] == _MAGIC_V2
    incompat = np.where(v2, head[:, 2], 0).astype(np.int64)
    mlen = head[:, 1].astype(np.int64)
    hdr = np.where(v2, 10, 6)
    end = s + PREFIX + hdr + mlen + 2 + np.where(incompat & _IFLAG_SIGNED, _SIGNATURE_LEN, 0)
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
            body = s[rows] + PREFIX + 1
            got = _x25(windows(buf, body, width), crc_extra[rows])
            tail = windows(buf, body + width, 2).astype(np.uint16)
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




def payloads(
    buf: NDArray[np.uint8], frames: Frames, rows: NDArray[np.int64], width: int, at: int = 0,
) -> NDArray[np.uint8]:
    """``width`` payload bytes from offset ``at`` of the given frames, zeros past their end
    (a MAVLink 2 payload is sent without its trailing zeros)."""
    raw = windows(buf, frames.payload[rows] + at, width)
    length = frames.length[rows].astype(np.int64) - at
    short = np.flatnonzero(length < width)
    if short.size:
        cut = np.arange(width)[None, :] >= length[short, None]
        raw[short] = np.where(cut, 0, raw[short])
    return raw

