"""MAVLink .tlog reader against pymavlink: every shared .tlog, every message of the dialect,
signed and v1/v2 frames, and damaged files."""

from __future__ import annotations

import functools
import os
import struct
import warnings
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers import assert_info_matches_golden, ids, require_shared, shared_logs, shared_path
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mavsid.data import RawLog
from mavsid.errors import ConfigError, DataQualityWarning, LogFormatError
from mavsid.readers import read_log, sniff_format, tlog, tlog_frames

TLOGS = shared_logs(".tlog")
VTOL = ("public", "ArduPilot__UAVLogViewer", "vtol.tlog")


# ----------------------------------------------------------------------------- reference


def pymavlink_messages(path: str) -> tuple[list[Any], int, Any]:
    """pymavlink's ``mavlink_connection(path).recv_match()`` loop: the messages it returns
    (BAD_DATA and UNKNOWN_* left out), the number of BAD_DATA, and the connection."""
    from pymavlink import mavutil

    old = os.environ.get("MAVLINK20")
    os.environ["MAVLINK20"] = "1"  # decode with the v2 dialect, which also reads v1 frames
    try:
        conn = mavutil.mavlink_connection(path, dialect="ardupilotmega")
    finally:
        if old is None:
            del os.environ["MAVLINK20"]
        else:
            os.environ["MAVLINK20"] = old
    messages, bad = [], 0
    while (m := conn.recv_match()) is not None:
        kind = m.get_type()
        if kind == "BAD_DATA":
            bad += 1
        elif not kind.startswith("UNKNOWN"):
            messages.append(m)
    conn.close()
    return messages, bad, conn


pymavlink_stream = functools.cache(pymavlink_messages)


@functools.cache
def mavsid_read(path: str) -> tuple[RawLog, list[str]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        log = tlog.read(path)
    return log, [str(w.message) for w in caught if issubclass(w.category, DataQualityWarning)]


def decode_alone(raw: bytes, recv_s: float, kind: str) -> Any:
    """pymavlink's decoder applied to the one frame recorded at ``recv_s`` (found by its
    8-byte timestamp in the file), or None."""
    key = struct.pack(">Q", round(recv_s * 1e6))
    at = raw.find(key)
    while at >= 0:
        frame = raw[at + 8 :]
        if frame[:1] in (b"\xfe", b"\xfd"):
            signed = frame[0] == 0xFD and frame[2] & 1
            size = frame[1] + (8 if frame[0] == 0xFE else 12 + (13 if signed else 0))
            try:
                m = mavlink.MAVLink(None).decode(bytearray(frame[:size]))
            except mavlink.MAVError:
                m = None
            if m is not None and m.get_type() == kind:
                return m
        at = raw.find(key, at + 1)
    return None


def field_array(values: list[Any], like: np.ndarray) -> np.ndarray:
    """pymavlink's values of one field as an array shaped and typed like ours."""
    if like.dtype == object:
        out = np.empty(len(values), dtype=object)
        out[:] = values
        return out
    return np.asarray(values, dtype=like.dtype).reshape(like.shape)


def assert_same_rows(kind: str, ours: Any, ref: list[Any]) -> None:
    """Our table equals pymavlink's messages of one type, field by field."""
    assert len(ours) == len(ref), kind
    for name in ref[0].get_fieldnames():
        got = ours[name]
        want = field_array([getattr(m, name) for m in ref], got)
        if got.dtype.kind == "f":
            assert np.array_equal(got, want, equal_nan=True), f"{kind}.{name}"
        else:
            assert got.tolist() == want.tolist(), f"{kind}.{name}"
    assert ours["_sysid"].tolist() == [m.get_srcSystem() for m in ref], kind
    assert ours["_compid"].tolist() == [m.get_srcComponent() for m in ref], kind


def reference_with_missed(path: Path, log: RawLog) -> tuple[dict[str, list[Any]], int]:
    """pymavlink's messages by type, plus the frames its sequential parser skipped.

    pymavlink reads a .tlog strictly in sequence: after a truncated frame it consumes the
    following record as that frame's rest (BAD_DATA) and loses it. The scan keeps such
    records; each must be found in the file at its receive time and decode, alone, with
    pymavlink's own decoder to the same values. Returns the per-type lists (in file order)
    and how many such frames were added.
    """
    messages, bad, _ = pymavlink_stream(str(path))
    by_type: dict[str, list[Any]] = defaultdict(list)
    for m in messages:
        by_type[m.get_type()].append(m)
    raw = path.read_bytes() if bad else b""
    added = 0
    for kind, table in log.messages.items():
        ref, merged, j = by_type.get(kind, []), [], 0
        for k, recv in enumerate(table["_recv_time_s"].tolist()):
            if j < len(ref) and ref[j]._timestamp == recv:
                merged.append(ref[j])
                j += 1
                continue
            assert bad, f"{kind} row {k}: not returned by pymavlink in a file it found clean"
            alone = decode_alone(raw, recv, kind)
            assert alone is not None, f"{kind} row {k}: no such frame in the file"
            alone._timestamp = recv
            merged.append(alone)
            added += 1
        assert j == len(ref), f"{kind}: pymavlink returned {len(ref) - j} more frames"
        by_type[kind] = merged
    missing = set(by_type) - set(log.messages)
    assert not missing, f"pymavlink has types we lack: {sorted(missing)}"
    return by_type, added


# ----------------------------------------------------------------------------- shared logs


@pytest.mark.slow
@pytest.mark.parametrize("path", TLOGS, ids=ids(TLOGS))
def test_shared_tlog_matches_pymavlink(path: Path) -> None:
    require_shared()
    log, quality = mavsid_read(str(path))
    _, bad, conn = pymavlink_stream(str(path))
    by_type, added = reference_with_missed(path, log)

    for kind, ref in by_type.items():
        table = log[kind]
        assert_same_rows(kind, table, ref)
        assert table["_recv_time_s"].tolist() == [m._timestamp for m in ref], kind
        if "time_boot_ms" in table:
            want = np.array([m.time_boot_ms for m in ref], dtype=float) * 1e-3
            assert np.array_equal(table.time_s, want), kind
        elif "time_usec" in table:
            usec = np.array([m.time_usec for m in ref], dtype=float)
            if np.median(usec) < 1e15:  # time since boot, not a UNIX time
                assert np.array_equal(table.time_s, usec * 1e-6), kind

    # params, texts and modes of the main vehicle, as pymavlink sees them
    stream = sorted((m for ms in by_type.values() for m in ms), key=lambda m: m._timestamp)
    main = next(
        ((m.get_srcSystem(), m.get_srcComponent()) for m in stream
         if m.get_type() == "HEARTBEAT" and conn.probably_vehicle_heartbeat(m)),
        None,
    )  # fmt: skip
    assert main is not None
    assert dict(log.params) == conn.param_state[main].params
    texts = [m.text for m in stream
             if m.get_type() == "STATUSTEXT" and m.get_srcSystem() == main[0]]  # fmt: skip
    assert [t.text for t in log.texts] == texts
    beats = [m for m in stream if m.get_type() == "HEARTBEAT"
             and (m.get_srcSystem(), m.get_srcComponent()) == main]  # fmt: skip
    from pymavlink import mavutil

    changes = [(m.custom_mode, mavutil.mode_string_v10(m)) for i, m in enumerate(beats)
               if i == 0 or m.custom_mode != beats[i - 1].custom_mode]  # fmt: skip
    assert [(c.mode, c.name) for c in log.modes] == changes
    assert log.autopilot == {3: "ardupilot", 12: "px4"}[beats[0].autopilot]

    # damaged files warn once, with counts; clean ones do not
    assert (len(quality) == 1) == bool(bad or added), quality
    assert log.source.skipped_bytes == 0 if not bad else log.source.skipped_bytes > 0


def test_sitl_tlog_has_vehicle_clock_and_arrays() -> None:
    path = shared_path("sitl", "flightA_mixer.tlog")
    log, _ = mavsid_read(str(path))
    ref = [m for m in pymavlink_stream(str(path))[0] if m.get_type() == "ATTITUDE_QUATERNION"]
    att = log["ATTITUDE_QUATERNION"]
    assert att["repr_offset_q"].shape == (len(ref), 4)
    # messages without a clock of their own: receive time moved onto the vehicle clock by
    # the median offset pymavlink's ATTITUDE times give between the two clocks
    att_ref = [m for m in pymavlink_stream(str(path))[0] if m.get_type() == "ATTITUDE"]
    offset = np.median([m.time_boot_ms * 1e-3 - m._timestamp for m in att_ref])
    hb = log["HEARTBEAT"]
    vehicle = hb["_sysid"] == 1
    assert np.allclose(hb.time_s[vehicle], hb["_recv_time_s"][vehicle] + offset, atol=0.05)
    # the ground station's (no heartbeat here) take the vehicle's offset, the file having
    # one receive clock
    rc = log["RC_CHANNELS_OVERRIDE"]
    assert (rc["_sysid"] == 255).all()
    assert np.allclose(rc.time_s, rc["_recv_time_s"] + offset, atol=0.05)


def test_selected_messages_and_window_match_full_read() -> None:
    path = str(shared_path("sitl", "flightA_mixer.tlog"))
    full, _ = mavsid_read(path)
    part = tlog.read(path, messages=["ATTITUDE", "RAW_IMU"], start=100.0, stop=110.0)
    assert set(part.messages) == {"ATTITUDE", "RAW_IMU"}
    for name in part.messages:
        keep = (full[name].time_s >= 100.0) & (full[name].time_s <= 110.0)
        assert keep.sum() > 400
        for col in full[name].fields:
            assert np.array_equal(part[name][col], full[name][col][keep])
    assert dict(part.params) == dict(full.params)
    assert all(100.0 <= m.time_s <= 110.0 for m in part.modes + part.texts)


def test_read_log_dispatches_tlog_even_after_leading_garbage() -> None:
    path = shared_path("public", "ArduPilot__UAVLogViewer", "flight_logs.tlog")
    assert sniff_format(path) == "tlog"
    with pytest.warns(DataQualityWarning, match="skipped"):
        log = read_log(path)
    assert log.source.format == "tlog" and len(log["ATTITUDE"]) > 3000


# ----------------------------------------------------------------------------- synthetic

_INT_RANGE = {
    "int8_t": (-(2**7), 2**7 - 1), "uint8_t": (0, 2**8 - 1), "int16_t": (-(2**15), 2**15 - 1),
    "uint16_t": (0, 2**16 - 1), "int32_t": (-(2**31), 2**31 - 1), "uint32_t": (0, 2**32 - 1),
    "int64_t": (-(2**63), 2**63 - 1), "uint64_t": (0, 2**64 - 1),
    "uint8_t_mavlink_version": (0, 255),
}  # fmt: skip


def _random_value(rng: np.random.Generator, kind: str, count: int, zero: bool) -> Any:
    if kind == "char":
        n = 0 if zero else int(rng.integers(0, count + 1))
        return bytes(rng.integers(32, 127, n).astype(np.uint8))

    def one() -> Any:
        if zero:
            return 0
        if kind == "float":
            return float(np.float32(rng.normal() * 100))
        if kind == "double":
            return float(rng.normal() * 1e6)
        lo, hi = _INT_RANGE[kind]
        return int(lo + int(rng.integers(0, 2**62)) * (hi - lo) // (2**62 - 1))

    return [one() for _ in range(count)] if count else one()


def synthetic_tlog(path: Path, seed: int = 0) -> list[tuple[float, bytes]]:
    """Every message of the dialect, three times each: as MAVLink 1 where it fits, as
    MAVLink 2 with half its fields zero (truncated payloads), as signed MAVLink 2. Returns
    (receive time, frame) per record."""
    rng = np.random.default_rng(seed)
    records: list[tuple[int, bytes]] = []
    t0 = 1_700_000_000_000_000
    for msgid, cls in sorted(mavlink.mavlink_map.items()):
        lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
        for variant in range(3):
            args = [_random_value(rng, kind, lengths[name], variant == 1 and rng.random() < 0.5)
                    for name, kind in zip(cls.fieldnames, cls.fieldtypes, strict=True)]
            mav = mavlink.MAVLink(None, srcSystem=1 + variant, srcComponent=1 + msgid % 200)
            if variant == 2:
                mav.signing.secret_key = bytes(range(32))
                mav.signing.link_id = 3
                mav.signing.sign_outgoing = True
            frame = cls(*args).pack(mav, force_mavlink1=variant == 0 and msgid < 256)
            records.append((t0 + 1000 * len(records), bytes(frame)))
    path.write_bytes(b"".join(struct.pack(">Q", t) + f for t, f in records))
    return [(t * 1e-6, f) for t, f in records]


def decoded(records: list[tuple[float, bytes]]) -> dict[str, list[Any]]:
    """pymavlink's decoder on each frame alone, by type (the stream reader loses sync on
    short frames that follow MAVLink 2 frames, so it is not the reference here)."""
    out: dict[str, list[Any]] = defaultdict(list)
    for recv, frame in records:
        m = mavlink.MAVLink(None).decode(bytearray(frame))
        m._timestamp = recv
        out[m.get_type()].append(m)
    return out


def test_every_dialect_message_v1_v2_truncated_signed(tmp_path: Path) -> None:
    records = synthetic_tlog(tmp_path / "all.tlog")
    assert any(f[0] == 0xFD and f[2] & 1 for _, f in records)  # signed frames present
    assert any(f[0] == 0xFE for _, f in records)
    ref = decoded(records)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataQualityWarning)
        log = tlog.read(tmp_path / "all.tlog")
    assert set(log.messages) == set(ref) and len(ref) == len(mavlink.mavlink_map)
    for kind, msgs in ref.items():
        assert_same_rows(kind, log[kind], msgs)
        assert log[kind]["_recv_time_s"].tolist() == [m._timestamp for m in msgs]


@pytest.fixture(scope="module")
def vtol() -> tuple[bytes, list[Any], list[int]]:
    """vtol.tlog's bytes, pymavlink's messages and the record boundaries (file offsets)."""
    path = shared_path(*VTOL)
    raw = path.read_bytes()
    messages, bad, _ = pymavlink_stream(str(path))
    assert bad == 0
    # each record is 8 + frame bytes, back to back
    ends = np.cumsum([8 + len(m.get_msgbuf()) for m in messages]).tolist()
    assert ends[-1] == len(raw)
    return raw, messages, [0, *ends]


def _rows(log: RawLog) -> list[tuple[str, float, tuple[Any, ...]]]:
    """Every decoded row as (type, receive time, field values); by receive time, then type,
    rows of one type keeping their order."""
    rows = []
    for kind, t in log.messages.items():
        cols = [t[f].tolist() for f in t.fields if f != "_recv_time_s"]
        rows += [(kind, r, tuple(map(repr, v)))
                 for r, v in zip(t["_recv_time_s"].tolist(), zip(*cols, strict=True),
                                 strict=True)]  # fmt: skip
    return sorted(rows, key=lambda x: (x[1], x[0]))  # stable


def _read_bytes(tmp_path: Path, data: bytes) -> tuple[RawLog, list[str]]:
    path = tmp_path / "x.tlog"
    path.write_bytes(data)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        log = tlog.read(path)
    return log, [str(w.message) for w in caught if issubclass(w.category, DataQualityWarning)]


def test_bad_crc_frame_rejected_like_pymavlink(tmp_path: Path, vtol: Any) -> None:
    raw, messages, bounds = vtol
    data = bytearray(raw)
    k = next(k for k in range(1000, len(messages)) if len(messages[k].get_msgbuf()) > 20)
    data[bounds[k] + 8 + 12] ^= 0x55  # a payload byte of frame k
    log, quality = _read_bytes(tmp_path, bytes(data))
    got, bad, _ = pymavlink_messages(str(tmp_path / "x.tlog"))
    assert bad == 1
    assert len(got) == len(messages) - 1  # pymavlink: one BAD_DATA
    by_type: dict[str, list[Any]] = defaultdict(list)
    for m in got:
        by_type[m.get_type()].append(m)
    assert set(by_type) == set(log.messages)
    for kind, ref in by_type.items():
        assert_same_rows(kind, log[kind], ref)
    size = bounds[k + 1] - bounds[k]
    assert quality == [f"{tmp_path / 'x.tlog'}: skipped {size} bytes in 1 places "
                       "(garbage, bad CRC or truncated frames)"]  # fmt: skip


def test_garbage_between_records_is_skipped_and_counted(tmp_path: Path, vtol: Any) -> None:
    raw, _, bounds = vtol
    clean, _ = mavsid_read(str(shared_path(*VTOL)))
    rng = np.random.default_rng(3)
    junk = [bytes(rng.integers(0, 256, n).astype(np.uint8)) for n in (5, 300, 4000)]
    cuts = [bounds[10], bounds[5000], bounds[20000]]
    data = raw[: cuts[0]] + junk[0] + raw[cuts[0] : cuts[1]] + junk[1] + raw[cuts[1] : cuts[2]]
    data += junk[2] + raw[cuts[2] :]
    log, quality = _read_bytes(tmp_path, data)
    assert _rows(log) == _rows(clean)
    assert len(quality) == 1 and f"skipped {sum(map(len, junk))} bytes in 3 places" in quality[0]
    assert log.source.skipped_bytes == sum(map(len, junk))


def test_truncated_last_record(tmp_path: Path, vtol: Any) -> None:
    raw, messages, bounds = vtol
    cut = bounds[-2] + 20  # the last record, cut inside its frame
    log, quality = _read_bytes(tmp_path, raw[:cut])
    clean, _ = mavsid_read(str(shared_path(*VTOL)))
    last = messages[-1]
    expected = [r for r in _rows(clean) if not (r[0] == last.get_type()
                                                and r[1] == last._timestamp)]  # fmt: skip
    assert _rows(log) == expected
    assert len(quality) == 1 and "skipped 20 bytes in 1 places" in quality[0]


def test_receive_time_running_backwards_warns(tmp_path: Path, vtol: Any) -> None:
    raw, messages, bounds = vtol
    data = bytearray(raw)
    for k, back_s in ((100, 10.0), (9000, 5000.0)):
        t = round(messages[k]._timestamp * 1e6 - back_s * 1e6)
        data[bounds[k] : bounds[k] + 8] = struct.pack(">Q", t)
    ahead = round(messages[50]._timestamp * 1e6 + 7200e6)
    data[bounds[50] : bounds[50] + 8] = struct.pack(">Q", ahead)
    log, quality = _read_bytes(tmp_path, bytes(data))
    assert sum(len(t) for t in log.messages.values()) == len(messages)
    # back at 51, 100, 9000; more than an hour ahead at 50 and 9001
    assert len(quality) == 1
    assert "runs backwards 3 times and jumps forward by more than 3600 s 2 times" in quality[0]


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(4))
def test_random_byte_flips_lose_at_most_the_hit_frames(
    tmp_path: Path, vtol: Any, seed: int
) -> None:
    raw, messages, bounds = vtol
    clean, _ = mavsid_read(str(shared_path(*VTOL)))
    rng = np.random.default_rng(seed)
    data = bytearray(raw)
    hits = sorted(rng.choice(len(raw), size=25, replace=False).tolist())
    for at in hits:
        data[at] ^= int(rng.integers(1, 256))
    log, quality = _read_bytes(tmp_path, bytes(data))
    hit = {int(np.searchsorted(bounds, at, side="right")) - 1 for at in hits}
    # the clean file's row of each record (rows of a type are in file order)
    clean_rows = {kind: iter(_rows(RawLog(clean.source, {kind: t})))
                  for kind, t in clean.messages.items()}  # fmt: skip
    record_rows = [next(clean_rows[m.get_type()]) for m in messages]
    expected = Counter(r for k, r in enumerate(record_rows) if k not in hit)
    got = Counter(_rows(log))
    # every record not hit is decoded as in the clean file; hit ones are lost, or, when only
    # their receive-time prefix was hit, kept with another receive time
    assert not expected - got
    others = got - expected
    assert sum(others.values()) <= len(hit)
    hit_values = {(record_rows[k][0], record_rows[k][2]) for k in hit}
    assert all((kind, values) in hit_values for kind, _, values in others)
    assert len(quality) == 1


def test_unknown_message_ids_are_counted(tmp_path: Path, vtol: Any) -> None:
    raw, messages, bounds = vtol
    # a well-formed MAVLink 2 frame of an id ardupilotmega does not define
    frame = bytes([0xFD, 3, 0, 0, 0, 1, 1, 0x10, 0x27, 0x00, 1, 2, 3, 0x12, 0x34])
    data = raw[: bounds[7]] + struct.pack(">Q", 1) + frame + raw[bounds[7] :]
    log, quality = _read_bytes(tmp_path, data)
    assert sum(len(t) for t in log.messages.values()) == len(messages)
    assert quality == [f"{tmp_path / 'x.tlog'}: skipped 1 frames (23 bytes) of message ids "
                       "unknown to dialect 'ardupilotmega'"]  # fmt: skip
    assert log.source.skipped_bytes == 23


def test_empty_and_foreign_files_raise_log_format_error(tmp_path: Path) -> None:
    empty = tmp_path / "empty.tlog"
    empty.write_bytes(b"")
    with pytest.raises(LogFormatError, match=r"empty\.tlog: empty file"):
        tlog.read(empty)
    noise = tmp_path / "noise.tlog"
    rng = np.random.default_rng(0)
    noise.write_bytes(rng.integers(0, 0xFD, 65536).astype(np.uint8).tobytes())  # no magic
    with pytest.raises(LogFormatError, match="no valid MAVLink frame"):
        tlog.read(noise)
    with pytest.raises(LogFormatError):
        read_log(noise)
    with pytest.raises(LogFormatError, match="cannot open"):
        tlog.read(tmp_path / "missing.tlog")


def test_unknown_dialect_is_a_config_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no_such_dialect"):
        tlog.read(tmp_path / "x.tlog", dialect="no_such_dialect")


def test_an_option_of_another_format_is_a_config_error_naming_the_file(tmp_path: Path) -> None:
    """``read_log`` passes its options on: one the .tlog reader does not take is one
    ConfigError naming the file and the option, before the file is read."""
    path = tmp_path / "sysid_roll.tlog"
    synthetic_tlog(path)
    with pytest.raises(ConfigError, match=r"sysid_roll\.tlog: option\(s\) times_only do not "
                                          r"apply to MAVLink \.tlog files"):
        read_log(path, times_only=True)


def test_other_dialect_gives_its_messages(tmp_path: Path) -> None:
    records = synthetic_tlog(tmp_path / "all.tlog", seed=1)
    from pymavlink.dialects.v20 import common

    with pytest.warns(DataQualityWarning, match="unknown to dialect 'common'"):
        log = tlog.read(tmp_path / "all.tlog", dialect="common")
    ref = decoded(records)
    names = {cls.msgname for cls in common.mavlink_map.values()}
    assert set(log.messages) == names & set(ref)
    for kind in ("ATTITUDE", "PARAM_VALUE"):
        assert_same_rows(kind, log[kind], ref[kind])


def _write(path: Path, frames: list[bytes], t0_us: int = 1_700_000_000_000_000) -> None:
    path.write_bytes(b"".join(struct.pack(">Q", t0_us + 20_000 * k) + f
                              for k, f in enumerate(frames)))  # fmt: skip


def test_px4_vehicle_params_modes_and_chunked_texts(tmp_path: Path) -> None:
    vehicle = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    # PX4 custom_mode: main mode << 16 | sub mode << 24 (POSCTL = 3; AUTO = 4, LOITER = 3)
    modes = [3 << 16, 3 << 16, (4 << 16) | (3 << 24)]
    long_text = "".join(chr(65 + k % 26) for k in range(120))
    frames = [gcs.heartbeat_encode(6, 8, 0, 0, 0).pack(gcs)]
    for k, mode in enumerate(modes):
        frames.append(vehicle.heartbeat_encode(2, 12, 1, mode, 4).pack(vehicle))
        frames.append(vehicle.attitude_encode(5000 + 40 * k, 0.1, 0.2, 0.3, 0, 0, 0)
                      .pack(vehicle))  # fmt: skip
    # an INT32 parameter, sent byte-wise in the float as PX4 does; and a REAL32 one
    as_float = np.array([123456789], dtype=np.int32).view(np.float32)[0]
    frames.append(vehicle.param_value_encode(b"SYS_AUTOSTART", float(as_float), 6, 2, 0)
                  .pack(vehicle))  # fmt: skip
    frames.append(vehicle.param_value_encode(b"MC_ROLLRATE_P", 0.15, 9, 2, 1).pack(vehicle))
    for seq, start in enumerate(range(0, 120, 50)):
        chunk = long_text[start : start + 50].encode()
        frames.append(vehicle.statustext_encode(6, chunk, 7, seq).pack(vehicle))
    frames.append(vehicle.statustext_encode(4, b"short one", 0, 0).pack(vehicle))
    frames.append(gcs.statustext_encode(6, b"from the ground station", 0, 0).pack(gcs))
    path = tmp_path / "px4.tlog"
    _write(path, frames)

    log = tlog.read(path)
    assert log.autopilot == "px4" and log.vehicle == "copter"
    assert log.params["SYS_AUTOSTART"] == 123456789
    assert log.params["MC_ROLLRATE_P"] == pytest.approx(0.15)
    from pymavlink import mavutil

    assert [(m.mode, m.name) for m in log.modes] == [
        (modes[0], mavutil.interpret_px4_mode(0, modes[0])),
        (modes[2], mavutil.interpret_px4_mode(0, modes[2])),
    ]
    assert [(t.text, t.severity) for t in log.texts] == [(long_text, 6), ("short one", 4)]
    # records every 20 ms; each ATTITUDE (5.00 s, 5.04 s, 5.08 s on the vehicle clock) comes
    # 20 ms after a vehicle heartbeat, so these were at 4.98, 5.02, 5.06 s; the ground
    # station's heartbeat, first, at 4.96 s
    assert np.allclose(log["HEARTBEAT"].time_s, [4.96, 4.98, 5.02, 5.06], atol=1e-6)


# ----------------------------------------------------------------------------- info



def test_info_text_matches_golden() -> None:
    """``mavsid info`` text of vtol.tlog; rewritten only with MAVSID_UPDATE_GOLDEN=1."""
    path = shared_path(*VTOL)
    assert_info_matches_golden(mavsid_read(str(path))[0], path)


def test_info_json_agrees_with_pymavlink() -> None:
    from mavsid.info import summarize

    path = shared_path(*VTOL)
    summary = summarize(mavsid_read(str(path))[0])
    messages, _, conn = pymavlink_stream(str(path))
    assert {k: v["count"] for k, v in summary["messages"].items()} == Counter(
        m.get_type() for m in messages
    )
    assert summary["param_count"] == len(conn.param_state[(1, 1)].params)
    assert summary["text_count"] == sum(m.get_type() == "STATUSTEXT" for m in messages)
    assert summary["format"] == "tlog" and summary["skipped_bytes"] == 0
    assert summary["messages"]["ATTITUDE"]["fields"]["rollspeed"] == "rad/s"


@pytest.mark.parametrize("path", TLOGS, ids=ids(TLOGS))
def test_info_duration_is_pymavlinks_where_the_receive_clock_holds(path: Path) -> None:
    """pymavlink's notion of a tlog's span: first to last receive time. Where the receive
    clock was rewritten (the vehicles' own clocks span far more), the records' span stands."""
    from mavsid.info import summarize

    require_shared()
    messages, _, _ = pymavlink_stream(str(path))
    want = messages[-1]._timestamp - messages[0]._timestamp
    log, _ = mavsid_read(str(path))
    got = summarize(log)["duration_s"]
    own = [t.time_s[np.isfinite(t.time_s)] for t in log.messages.values()]
    own_span = max(float(t.max()) for t in own if t.size) - min(float(t.min()) for t in own
                                                                 if t.size)
    if log.span_s is not None:
        assert got == pytest.approx(want, abs=1e-3)
    else:  # the receive clock does not hold: the records' own span, far longer
        assert got == pytest.approx(own_span) and own_span > 2 * want


@pytest.mark.slow
def test_block_boundaries_lose_nothing(monkeypatch: pytest.MonkeyPatch, vtol: Any) -> None:
    """The scan works in blocks (16 MiB); with tiny blocks every kind of record straddles
    one, and the result is still pymavlink's."""
    monkeypatch.setattr(tlog_frames, "BLOCK", 997)
    path = shared_path(*VTOL)
    log = tlog.read(path)
    by_type: dict[str, list[Any]] = defaultdict(list)
    for m in vtol[1]:
        by_type[m.get_type()].append(m)
    assert set(log.messages) == set(by_type)
    for kind, ref in by_type.items():
        assert_same_rows(kind, log[kind], ref)
    assert log.source.skipped_bytes == 0


@pytest.mark.parametrize("fill", ["random", "magic"])
def test_pathological_bytes_give_a_clean_answer(tmp_path: Path, fill: str) -> None:
    """Random bytes, or nothing but MAVLink 2 magic bytes: a LogFormatError (or, should
    chance form a valid frame, a log with a warning), never another exception."""
    rng = np.random.default_rng(7)
    data = (rng.integers(0, 256, 1 << 20).astype(np.uint8).tobytes() if fill == "random"
            else b"\xfd" * (1 << 20))  # fmt: skip
    path = tmp_path / "x.tlog"
    path.write_bytes(data)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            log = tlog.read(path)
        except LogFormatError as exc:
            assert "no valid MAVLink frame" in str(exc)
            return
    assert sum(len(t) for t in log.messages.values()) < 5
    assert [w.category for w in caught] == [DataQualityWarning]


@pytest.mark.parametrize("mapped", [False, True])
def test_truncated_payload_at_the_end_of_the_file(tmp_path: Path, mapped: bool) -> None:
    """A MAVLink 2 frame whose payload is cut short (trailing zeros) as the file's last
    record: its missing bytes are read as zeros, not past the file's end, whether the file is
    read whole (small) or memory-mapped (64 KiB and more)."""
    records = synthetic_tlog(tmp_path / "all.tlog")
    full = {msgid: cls.unpacker.size for msgid, cls in mavlink.mavlink_map.items()}

    def cut(frame: bytes) -> int:  # payload bytes missing from a v2 frame
        msgid = int.from_bytes(frame[7:10], "little")
        return full[msgid] - frame[1] if frame[0] == 0xFD and not frame[2] & 1 else 0

    last = max(records, key=lambda r: cut(r[1]))
    assert cut(last[1]) > 8
    head = [r for r in records if r[1][0] == 0xFE][:50]
    body = b"".join(struct.pack(">Q", round(t * 1e6)) + f for t, f in head)
    copies = (1 << 16) // len(body) + 1 if mapped else 1
    data = body * copies + struct.pack(">Q", round(last[0] * 1e6)) + last[1]
    assert (len(data) >= 1 << 16) == mapped
    log, quality = _read_bytes(tmp_path, data)
    assert not any("skipped" in q for q in quality)  # (the copies' receive times go back)
    ref = decoded([last])
    kind = next(iter(ref))
    ours = log[kind]
    if kind in {mavlink.mavlink_map[f[5]].msgname for _, f in head}:  # v1 filler frames
        pytest.skip("the truncated message is also among the filler records")
    assert_same_rows(kind, ours, ref[kind])


def test_block_wise_gathers_give_the_whole_file_read(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Receive times, own clocks and payloads are gathered a block of the file at a time
    (the pages behind handed back, so a 100 MB .tlog's read no longer maps the whole file
    again: resident growth 252 -> 199 MB). With blocks of 64 kB (the SITL .tlog spans 185 of
    them) every table equals the one-block read, value for value."""
    path = str(shared_path("sitl", "flightA_mixer.tlog"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        whole = tlog.read(path)
        monkeypatch.setattr(tlog_frames, "BLOCK", 1 << 16)
        blocks = tlog.read(path)
    assert set(blocks.messages) == set(whole.messages)
    for name, table in whole.messages.items():
        other = blocks.messages[name]
        np.testing.assert_array_equal(other.time_s, table.time_s, err_msg=name)
        for col, values in table.columns.items():
            np.testing.assert_array_equal(other.columns[col], values, err_msg=f"{name}.{col}")
