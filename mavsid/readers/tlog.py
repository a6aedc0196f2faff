"""Read MAVLink telemetry logs (``.tlog``) into a :class:`~mavsid.data.RawLog`, vectorised.

A ``.tlog`` is what a ground station (Mission Planner, QGroundControl, MAVProxy) records: each
record is an 8-byte big-endian receive time in microseconds (the ground station's wall clock)
followed by one MAVLink frame as it came off the link:

- v1: ``0xFE len seq sysid compid msgid payload crc(2)``
- v2: ``0xFD len incompat compat seq sysid compid msgid(3) payload crc(2) [signature(13)]``;
  the payload's trailing zero bytes are truncated on the wire.

Message definitions (ids, field names, wire order, array lengths, CRC_EXTRA) come from a
pymavlink dialect (``ardupilotmega`` by default: :mod:`~mavsid.readers.mavlink_dialect`).
Decoding never builds one Python object per frame: the valid frames are found at once
(:mod:`~mavsid.readers.tlog_frames`); each message id's frames are then viewed through a
structured dtype in wire order (short v2 payloads zero-padded, as MAVLink specifies) and
split into columns by field name. The file is memory-mapped, not copied, and its pages are
handed back as the scan and each table are done: the read's peak stays under twice the
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

import re
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mavsid.autopilot.modes import ardupilot_modes, px4_mode_name, vehicle_class
from mavsid.data import (
    MessageTable,
    ModeChange,
    ParamChange,
    RawLog,
    SourceInfo,
    TextMessage,
    param_changes,
)
from mavsid.errors import DataQualityWarning, LogFormatError
from mavsid.readers.files import LogPath, mapped, refuse_options
from mavsid.readers.mavlink_dialect import MessageDef, field_units, load_dialect
from mavsid.readers.tlog_frames import Frames, in_blocks, payloads, release, scan_frames

__all__ = ["MessageDef", "load_dialect", "read"]

_TIME_JUMP_S = 3600.0  # a forward step in receive time larger than this counts as a jump
_UNIX_USEC = 1e15  # a time_usec above this (31 years) is a UNIX time, not time since boot
_MAV_AUTOPILOT = {3: "ardupilot", 12: "px4"}
_MAV_AUTOPILOT_INVALID, _MAV_TYPE_GCS = 8, 6


# ----------------------------------------------------------------------------- decoding


def _own_times(buf: NDArray[np.uint8], frames: Frames, groups: dict[int, NDArray[np.int64]],
               defs: dict[int, MessageDef]) -> dict[int, NDArray[np.float64] | None]:
    """Per message id its own clock in seconds, None when it has none (or a UNIX time).

    Gathered a block of the file at a time for all ids together, the pages behind handed
    back: each page is mapped once, and never all of the file at once."""
    fields = {i: mdef.dtype.fields[mdef.time_field][:2]  # type: ignore[index]
              for i in groups if (mdef := defs[i]).time_field is not None}
    raw = {i: np.zeros((groups[i].size, base.itemsize), np.uint8)
           for i, (base, _) in fields.items()}
    for a, b in in_blocks(buf, frames.payload):
        for i, (base, offset) in fields.items():
            rows = groups[i]
            ra, rb = np.searchsorted(rows, (a, b)).tolist()
            if rb > ra:
                raw[i][ra:rb] = payloads(buf, frames, rows[ra:rb], base.itemsize, offset)
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
    frames: Frames,
    rows: NDArray[np.int64],
    mdef: MessageDef,
    time_s: NDArray[np.float64],
    units: dict[str, str],
) -> MessageTable:
    """Decode one message type's frames (``rows`` ascending: file order) into a table.

    The payloads are gathered a block of the file at a time (:func:`in_blocks`, the pages
    behind handed back) and each block's fields copied into columns made beforehand: the
    whole type's raw records never exist beside its columns (a 100 MB .tlog's read peaked
    ~10 MB higher with them)."""
    dtype = mdef.dtype
    columns: dict[str, NDArray[Any]] = {
        name: np.empty((rows.size, *dtype.fields[name][0].shape),  # type: ignore[index]
                       dtype.fields[name][0].base)  # type: ignore[index]
        for name in mdef.fields}  # fmt: skip
    for a, b in in_blocks(buf, frames.payload[rows]):
        rec = payloads(buf, frames, rows[a:b], dtype.itemsize).view(dtype)[:, 0]
        for name, column in columns.items():
            column[a:b] = rec[name]
    for name in mdef.strings:
        columns[name] = _strings(columns[name])
    columns["_sysid"] = frames.sysid[rows].astype(np.uint8)
    columns["_compid"] = frames.compid[rows].astype(np.uint8)
    columns["_recv_time_s"] = frames.recv_s[rows]
    return MessageTable(mdef.name, columns, time_s, units={**units, "_recv_time_s": "s"})


# ----------------------------------------------------------------------------- reading


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


def _mode_names(autopilot: int, mav_type: int) -> Callable[[int], str | None]:
    """mode number -> name (or None), from the ArduPilot and PX4 mode tables
    (:mod:`mavsid.autopilot.modes`)."""
    if autopilot == 12:
        return px4_mode_name
    table = ardupilot_modes(mav_type) if autopilot == 3 else None
    return lambda mode: table.get(mode) if table else None


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


def read(path: LogPath, messages: Sequence[str] | None = None, start: float | None = None,
         stop: float | None = None, dialect: str = "ardupilotmega", **options: object
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
    **options
        No other applies (a ConfigError names any given).

    Raises
    ------
    LogFormatError
        Empty or unreadable file, or no valid MAVLink frame in it.
    ConfigError
        Unknown dialect, or another option given.

    Warns
    -----
    DataQualityWarning
        Bytes skipped (garbage, bad CRC, truncation), frames of message ids the dialect does
        not define, receive times running backwards or jumping.
    """
    refuse_options(path, options, "MAVLink .tlog files")
    defs = load_dialect(dialect)
    with mapped(path) as raw:
        buf = np.frombuffer(raw, np.uint8)
        try:
            return _read(path, buf, buf.size, defs, messages, start, stop, dialect)
        finally:
            del buf  # (no view of the map left: it closes at once)


def _read(
    path: LogPath,
    buf: NDArray[np.uint8],
    size: int,
    defs: dict[int, MessageDef],
    messages: Sequence[str] | None,
    start: float | None,
    stop: float | None,
    dialect: str,
) -> RawLog:
    """:func:`read` of the file's bytes ``buf``."""
    frames = scan_frames(buf, size, defs)
    if not frames.payload.size:
        raise LogFormatError("no valid MAVLink frame found (not a .tlog?)", path=path)

    groups = _groups(frames.msgid)
    own = _own_times(buf, frames, groups, defs)
    release(buf, 0, size)
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
        tables[mdef.name] = _table(buf, frames, rows, mdef, time_s, field_units(dialect, i))
        release(buf, 0, size)  # the pages this table touched

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


def _span(frames: Frames, offsets: NDArray[np.float64], main: int | None,
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



def _window(table: MessageTable, lo: float, hi: float) -> MessageTable:
    """Rows of ``table`` with ``lo <= time_s <= hi``."""
    keep = (table.time_s >= lo) & (table.time_s <= hi)
    columns = {n: c[keep] for n, c in table.columns.items()}
    return MessageTable(table.name, columns, table.time_s[keep], table.units)


def _quality_notes(frames: Frames, dialect: str) -> list[str]:
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
