"""Builders of hostile logs: each returns the bytes of one file that once made
mavsid crash, hang or exhaust memory. Used by the fuzz tests and ``benchmarks/bench_hostile.py``.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from mavsid.readers.dataflash_spec import build_fmt, build_record

ROOT = Path(__file__).resolve().parents[2]
FIXTURES = ROOT / "fixtures"


def fmt_churn(size: int) -> bytes:
    """One type redefined (another layout and column names each time) before every record."""
    out = bytearray()
    k = 0
    while len(out) < size:
        out += build_fmt(0x81, "CHN", "Qf", f"TimeUS,V{k}")
        out += build_record(0x81, "Qf", 1000 * k, float(k))
        k += 1
    return bytes(out)


def header_flood(size: int) -> bytes:
    """``A3 95 80`` (a DataFlash FMT header) repeated."""
    return b"\xa3\x95\x80" * (size // 3)


def text_flood(size: int) -> bytes:
    """A text log of one FMT line and then short records, many of undefined types."""
    head = b"FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns\n" \
           b"FMT, 129, 15, TST, Qf, TimeUS,V\n"
    body = b"A,1\nTST,1\nB\n" * ((size - len(head)) // 12)
    return head + body


def header_and_records(n: int = 2000) -> bytes:
    """A small valid log (TST at 100 Hz) used as a base by other builders."""
    out = bytearray(build_fmt(0x81, "TST", "Qf", "TimeUS,V"))
    for k in range(n):
        out += build_record(0x81, "Qf", 10_000 * k, float(k))
    return bytes(out)


def metadata_redefined() -> bytes:
    """MODE, PARM and VER defined with layouts unlike ArduPilot's (strings for numbers,
    missing fields)."""
    out = bytearray()
    out += build_fmt(0x81, "PARM", "QZZ", "TimeUS,Name,Value")
    out += build_fmt(0x82, "MODE", "QZ", "TimeUS,Mode")
    out += build_fmt(0x83, "VER", "QZZ", "TimeUS,BU,FWS")
    out += build_fmt(0x84, "TST", "Qf", "TimeUS,V")
    out += build_record(0x81, "QZZ", 1, "RATE_P", "fast")
    out += build_record(0x82, "QZ", 2, "LOITER")
    out += build_record(0x83, "QZZ", 3, "copter", "ArduCopter V4")
    for k in range(10):
        out += build_record(0x84, "Qf", 10_000 * k, float(k))
    return bytes(out)


def set_tlog_field(data: bytes, msg_name: str, field: str, values: dict[int, float]) -> bytes:
    """A copy of a .tlog with ``field`` of the ``k``-th ``msg_name`` frames (keys of
    ``values``) set, frames re-encoded by pymavlink so that their CRC is valid."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    mav = mavlink.MAVLink(None)
    mav.robust_parsing = True
    out = bytearray()
    pos, k = 0, 0
    while pos + 8 < len(data):
        stx = data[pos + 8]
        if stx == 0xFD:
            n = 8 + 10 + data[pos + 9] + 2 + (13 if data[pos + 10] & 1 else 0)
        else:
            n = 8 + 6 + data[pos + 9] + 2
        frame = data[pos + 8 : pos + n]
        msgs = mav.parse_buffer(bytes(frame)) or []
        if msgs and msgs[0].get_type() == msg_name:
            if k in values:
                m = msgs[0]
                setattr(m, field, values[k])
                enc = mavlink.MAVLink(None, srcSystem=m.get_srcSystem(),
                                      srcComponent=m.get_srcComponent())
                enc.seq = m.get_seq()
                frame = m.pack(enc)
            k += 1
        out += data[pos : pos + 8] + frame
        pos += n
    out += data[pos:]
    return bytes(out)


def dataflash_time_outlier(base: bytes, name: str | None, value: int, last: int = 1) -> bytes:
    """A copy of a .bin with ``TimeUS`` of the ``last`` final records of ``name`` (of every
    type with a leading ``TimeUS`` when None) set to ``value``."""
    from mavsid.readers.dataflash_formats import read_definitions
    from mavsid.readers.dataflash_scan import find_headers

    a = np.frombuffer(base, np.uint8)
    cand, types = find_headers(a)
    table = read_definitions(a, cand[types == 0x80][cand[types == 0x80] <= a.size - 89])
    out = bytearray(base)
    for d in table.defs:
        if (name is None or d.name == name) and d.columns[:1] == ("TimeUS",) \
                and d.format[:1] == "Q":
            for p in cand[types == d.type][-last:].tolist():
                out[p + 3 : p + 11] = struct.pack("<Q", value)
    return bytes(out)


# --------------------------------------------------------------------------- ULog

def _ulog_msg(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), kind[0]) + payload


def ulog_file(formats: list[str], params: list[tuple[str, bytes]] = (),  # type: ignore[assignment]
              topic: str | None = "att", samples: int = 50, also: tuple[str, ...] = ()) -> bytes:
    """A small valid ULog (version 1): ``formats`` ("name:type field;..."), parameters
    ``(key, 4 value bytes)`` with key "type NAME", and ``samples`` records of ``topic``
    (whose format must be ``uint64_t timestamp;float roll;``) at 100 Hz."""
    out = bytearray(b"ULog\x01\x12\x35\x01" + struct.pack("<Q", 0))
    out += _ulog_msg(b"B", bytes(40))
    for f in formats:
        out += _ulog_msg(b"F", f.encode())
    for key, value in params:
        out += _ulog_msg(b"P", bytes([len(key)]) + key.encode() + value)
    if topic is not None:
        out += _ulog_msg(b"A", struct.pack("<BH", 0, 0) + topic.encode())
    for i, name in enumerate(also, start=1):  # subscribed too, with one 16-byte record each
        out += _ulog_msg(b"A", struct.pack("<BH", 0, i) + name.encode())
        out += _ulog_msg(b"D", struct.pack("<H", i) + bytes(16))
    if topic is not None:
        for k in range(samples):
            out += _ulog_msg(b"D", struct.pack("<HQf", 0, 10_000 * k, 0.01 * k))
    return bytes(out)


ATT_FORMAT = "att:uint64_t timestamp;float roll;"


def ulog_self_reference() -> bytes:
    """A format whose field has its own type (pyulog: RecursionError)."""
    return ulog_file([ATT_FORMAT, "loop:uint64_t timestamp;loop inner;"], also=("loop",))


def ulog_mutual_reference() -> bytes:
    """Two formats that contain each other."""
    return ulog_file([ATT_FORMAT, "ping:uint64_t timestamp;pong x;", "pong:ping y;"],
                     also=("ping",))


def ulog_damaged_parameter() -> bytes:
    """A parameter whose type string was damaged ("flxat"): its value is raw bytes."""
    return ulog_file([ATT_FORMAT], [("float MC_ROLL_P", struct.pack("<f", 6.5)),
                                    ("flxat MC_PITCH_P", struct.pack("<f", 6.5))])
