"""DataFlash text .log reader: values equal pymavlink's DFReader_text.

pymavlink raises on two shared text logs (its GPS clock needs a week field the old GPS
message lacks). For those the reference is pymavlink's own line parsing with its clock set-up
switched off (``DFReader_text.init_clock`` patched to do nothing), so the values still come
from pymavlink, not from this reader.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from helpers import ids, require_shared, shared_logs, shared_path
from test_dataflash import assert_matches, pymavlink_records

from mavsid.errors import DataQualityWarning, LogFormatError
from mavsid.readers import dftext, read_log, sniff_format

TEXT_LOGS = shared_logs(".log")
PYMAVLINK_FAILS = {"robert_lefebvre_octo_PM.log", "tradheli_brownout.log"}


def _read(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataQualityWarning)
        return read_log(path)


@pytest.mark.slow
@pytest.mark.parametrize("path", TEXT_LOGS, ids=ids(TEXT_LOGS))
def test_every_value_equals_pymavlink(path, monkeypatch):
    require_shared()
    assert sniff_format(path) == "dataflash-text"
    if path.name in PYMAVLINK_FAILS:
        with pytest.raises(TypeError):  # still true of pymavlink: else drop the patch
            pymavlink_records(path)
        from pymavlink import DFReader

        monkeypatch.setattr(DFReader.DFReader_text, "init_clock", lambda self: None)
    ref = pymavlink_records(path)
    log = _read(path)
    assert_matches(log, ref)
    assert log.autopilot == "ardupilot" and log.source.format == "dataflash-text"


def test_all_shared_text_logs_are_covered():
    require_shared()
    assert len(TEXT_LOGS) >= 5 and PYMAVLINK_FAILS <= {p.name for p in TEXT_LOGS}


def test_old_copter_log_metadata():
    path = shared_path("public", "ArduPilot__ardupilot", "nan.log")
    log = _read(path)
    assert log.firmware is not None and log.firmware.startswith("ArduCopter V3.1")
    assert log.vehicle == "copter"
    assert len(log.params) > 100
    assert [m.name for m in log.modes] == ["STABILIZE"] and log.modes[0].mode == 0
    imu = log["IMU"]
    np.testing.assert_array_equal(imu.time_s, imu["TimeMS"] * 1e-3)
    assert log.duration_s > 10


def test_brownout_log_reads_to_its_end():
    path = shared_path("public", "ArduPilot__ardupilot", "tradheli_brownout.log")
    log = _read(path)
    assert len(log["ATT"]) > 1000 and log.firmware is not None
    assert [m.name for m in log.modes][:2] == ["LOITER", "STABILIZE"]


FMT = "FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns\n"


def test_comma_only_delimiter_and_selection(tmp_path):
    path = tmp_path / "plain.log"
    path.write_text("FMT,128,89,FMT,BBnNZ,Type,Length,Name,Format,Columns\n"
                    "FMT,129,19,ATT,Qff,TimeUS,Roll,Pitch\n"
                    "FMT,130,19,RATE,Qff,TimeUS,R,P\n"
                    "ATT,1000000,1.5,-2\nRATE,1500000,3,4\nATT,2000000,2.5,-3\n")
    log = dftext.read(path, messages=["ATT"], start=1.5)
    assert set(log.messages) == {"ATT"}
    assert log["ATT"]["Roll"].tolist() == [2.5] and log["ATT"].time_s.tolist() == [2.0]


def test_bad_lines_are_skipped_and_reported_once(tmp_path):
    path = tmp_path / "bad.log"
    path.write_text(FMT + "FMT, 129, 15, ATT, Ih, TimeMS,V\n"
                    "ATT, 1, 2\nATT, x, 3\nATT, 4\nXYZ, 1, 2\nATT, 5, 6\n")
    with pytest.warns(DataQualityWarning) as rec:
        log = dftext.read(path)
    assert len(rec) == 1 and "2 line(s)" in str(rec[0].message)
    assert "without FMT" in str(rec[0].message)
    assert log["ATT"]["V"].tolist() == [2, 6]


@pytest.mark.parametrize("text", ["", "hello\nworld\n", "FMT, 128, 89\n"])
def test_nothing_decodable_is_a_log_format_error(tmp_path, text):
    path = tmp_path / "empty.log"
    path.write_text(text)
    with pytest.raises(LogFormatError, match=r"empty\.log"):
        dftext.read(path)


@pytest.mark.slow
def test_text_flood_is_read_in_bounded_memory(tmp_path) -> None:
    """Floods of short lines (undefined types, too few values) are skipped; the defined
    records still read; Python's memory stays a small multiple of the file (it was ~25x:
    one list per line). Process memory and time are measured in tests/fuzz."""
    import tracemalloc

    from fuzz import hostile

    path = tmp_path / "flood.log"
    path.write_bytes(hostile.text_flood(2_000_000)
                     + b"".join(b"TST, %d, %d.5\n" % (k * 1000, k) for k in range(10)))
    tracemalloc.start()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DataQualityWarning)
            log = read_log(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert log["TST"]["V"].tolist() == [k + 0.5 for k in range(10)]
    assert peak < 3 * 2_000_000 + 8_000_000  # (+ one slice of lines) it was ~25x the file


@pytest.mark.slow
@pytest.mark.parametrize("path", [p for p in TEXT_LOGS if p.name not in PYMAVLINK_FAILS],
                         ids=ids([p for p in TEXT_LOGS if p.name not in PYMAVLINK_FAILS]))
def test_duration_is_pymavlinks_span(path):
    """The log's span is pymavlink's: first to last timed record. A 3.1 log without a
    boot-time field is timed by GPS.T (ms since boot), as pymavlink does; by the GPS time of
    week it came out 117.2 s instead of 110.1 s (mechanical_fail.log: the first fix's time
    of week is 7.4 s stale)."""
    require_shared()
    from pymavlink import mavutil
    from pymavlink.DFReader import DFReaderClock_gps_interpolated

    from mavsid.info import summarize

    conn = mavutil.mavlink_connection(str(path))
    stamps = []
    while (msg := conn.recv_msg()) is not None:
        if msg.get_type() not in ("FMT", "PARM"):
            stamps.append(msg._timestamp)
    got = summarize(_read(path))["duration_s"]
    if isinstance(conn.clock, DFReaderClock_gps_interpolated) and not conn.clock.msg_rate:
        # no clock in the log at all (underpowered.log: no time field, no GPS record):
        # pymavlink counts records at an assumed 50 Hz; mavsid gives no span it cannot know
        assert got == 0.0
    else:
        assert got == pytest.approx(stamps[-1] - stamps[0], abs=0.01)
