"""PX4 ULog reader against pyulog: every shared .ulg field by field, selective loading,
damaged files."""

from __future__ import annotations

import contextlib
import io
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers import assert_info_matches_golden, ids, require_shared, shared_logs, shared_path
from pyulog import ULog

from mavsid.data import RawLog
from mavsid.errors import DataQualityWarning, LogFormatError
from mavsid.readers import read_log, ulog

ULOGS = shared_logs(".ulg")
PX4_ULOG_RS = ("public", "Auterion__px4-ulog-rs")


def pyulog(path: Path, topics: list[str] | None = None) -> tuple[ULog, str]:
    """pyulog's parse and what it printed."""
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        ref = ULog(str(path), topics)
    return ref, printed.getvalue()


def read(path: Path, **kwargs: Any) -> tuple[RawLog, list[str]]:
    """mavsid's read and its data-quality warnings."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        log = ulog.read(path, **kwargs)
    return log, [str(w.message) for w in caught if issubclass(w.category, DataQualityWarning)]


def name_of(d: Any) -> str:
    return d.name if d.multi_id == 0 else f"{d.name}[{d.multi_id}]"


def assert_tables_match(log: RawLog, ref: ULog) -> None:
    """Every pyulog topic instance is a table with the same fields, values and dtypes."""
    assert set(log.messages) == {name_of(d) for d in ref.data_list}
    for d in ref.data_list:
        table = log[name_of(d)]
        assert list(table.fields) == list(d.data), name_of(d)
        for field, want in d.data.items():
            got = table[field]
            assert got.dtype == want.dtype, f"{name_of(d)}.{field}"
            assert np.array_equal(got, want, equal_nan=want.dtype.kind == "f"), field
        clock = d.data.get("timestamp_sample", d.data.get("timestamp"))
        assert np.array_equal(table.time_s, np.asarray(clock, dtype=float) / 1e6), name_of(d)


@pytest.mark.parametrize("path", ULOGS, ids=ids(ULOGS))
def test_shared_ulog_matches_pyulog(path: Path) -> None:
    require_shared()
    ref, printed = pyulog(path)
    log, quality = read(path)
    assert_tables_match(log, ref)

    params = dict(ref.initial_parameters)
    for _, name, value in ref.changed_parameters:
        params[name] = value
    assert dict(log.params) == params
    logged = list(ref.logged_messages) + [m for ms in ref.logged_messages_tagged.values()
                                          for m in ms]  # fmt: skip
    want = sorted(((m.timestamp / 1e6, m.message, m.log_level - ord("0")) for m in logged),
                  key=lambda t: t[0])  # fmt: skip
    got = [(t.time_s, t.text, t.severity) for t in log.texts]
    assert [(text, sev) for _, text, sev in got] == [(text, sev) for _, text, sev in want]
    assert [t for t, _, _ in got] == pytest.approx([t for t, _, _ in want])

    status = next((d for d in ref.data_list if d.name == "vehicle_status" and d.multi_id == 0),
                  None)  # fmt: skip
    if status is not None:
        nav = status.data["nav_state"]
        at = [k for k in range(len(nav)) if k == 0 or nav[k] != nav[k - 1]]
        assert [(m.time_s, m.mode) for m in log.modes] == [
            (status.data["timestamp"][k] / 1e6, int(nav[k])) for k in at
        ]
    assert log.autopilot == "px4"
    if ref.dropouts:
        assert f"{len(ref.dropouts)} dropouts" in log.source.notes[0]
    if ref.has_data_appended:
        assert "has appended data (crash dump)" in log.source.notes
    # corruption pyulog finds (flag or printed diagnostics) -> one warning; else none
    assert len(quality) == int(bool(ref.file_corruption or printed.strip())), quality


def test_corrupt_px4_ulog_rs_logs_warn_and_keep_pyulog_values() -> None:
    for name in ("corrupt_actuator_armed_wrong_size.ulg", "corrupt_format_not_utf8.ulg",
                 "corrupt_unregistered_msg_id.ulg"):  # fmt: skip
        path = shared_path(*PX4_ULOG_RS, name)
        log, quality = read(path)
        assert len(quality) == 1 and "file corruption found" in quality[0]
        assert len(log["vehicle_attitude"]) > 250


def test_unordered_and_appended_samples() -> None:
    unordered = shared_path("public", "PX4__pyulog", "sample_unordered.ulg")
    log, _ = read(unordered)
    assert any("time runs backwards in 1 topics (actuator_controls_0)" in n
               for n in log.source.notes)  # fmt: skip
    appended = shared_path("public", "PX4__pyulog", "sample_appended_multiple.ulg")
    ref, _ = pyulog(appended)
    assert ref.has_data_appended
    log, _ = read(appended)
    assert_tables_match(log, ref)


def test_selected_topics_and_instances() -> None:
    path = shared_path(*PX4_ULOG_RS, "esc_status_log.ulg")
    ref, _ = pyulog(path, ["vehicle_attitude", "actuator_outputs"])
    log, _ = read(path, messages=["vehicle_attitude", "actuator_outputs[1]"])
    assert set(log.messages) == {"vehicle_attitude", "actuator_outputs[1]"}
    for d in ref.data_list:
        if name_of(d) in log.messages:
            for field, want in d.data.items():
                assert np.array_equal(log[name_of(d)][field], want)
    every, _ = read(path, messages=["actuator_outputs"])
    assert set(every.messages) == {"actuator_outputs", "actuator_outputs[1]",
                                   "actuator_outputs[2]"}  # fmt: skip
    full, _ = read(path)
    assert every.modes == full.modes and dict(every.params) == dict(full.params)


def test_time_window() -> None:
    path = shared_path("public", "PX4__pyulog", "sample.ulg")
    full, _ = read(path)
    part, _ = read(path, messages=["vehicle_attitude"], start=120.0, stop=130.0)
    t = full["vehicle_attitude"].time_s
    keep = (t >= 120.0) & (t <= 130.0)
    assert keep.sum() > 500
    assert np.array_equal(part["vehicle_attitude"]["q[0]"], full["vehicle_attitude"]["q[0]"][keep])
    assert all(120.0 <= m.time_s <= 130.0 for m in part.texts + part.modes)


def test_read_log_dispatches_ulog() -> None:
    log = read_log(shared_path("public", "PX4__pyulog", "sample_log_small.ulg"))
    assert log.source.format == "ulog" and "vehicle_angular_velocity" in log


def test_empty_and_header_only_files(tmp_path: Path) -> None:
    empty = tmp_path / "empty.ulg"
    empty.write_bytes(b"")
    with pytest.raises(LogFormatError, match="empty file"):
        ulog.read(empty)
    head = shared_path("public", "PX4__pyulog", "sample.ulg").read_bytes()[:16]
    header_only = tmp_path / "header.ulg"
    header_only.write_bytes(head)
    with pytest.raises(LogFormatError, match="no ULog data"):
        ulog.read(header_only)
    with pytest.raises(LogFormatError, match="cannot read"):
        ulog.read(tmp_path / "missing.ulg")


@pytest.mark.parametrize("cut", [0.001, 0.03, 0.5, 0.97])
def test_truncated_ulog_gives_pyulog_values_or_a_clean_error(tmp_path: Path, cut: float) -> None:
    raw = shared_path("public", "PX4__pyulog", "sample_appended_multiple.ulg").read_bytes()
    path = tmp_path / "cut.ulg"
    path.write_bytes(raw[: int(len(raw) * cut)])
    try:
        ref, _ = pyulog(path)
    except Exception:  # pyulog cannot read it: neither may we, but cleanly
        with pytest.raises(LogFormatError):
            read(path)
        return
    if not ref.data_list and not ref.initial_parameters:
        with pytest.raises(LogFormatError, match="no ULog data"):
            read(path)
        return
    log, _ = read(path)
    assert_tables_match(log, ref)


@pytest.mark.parametrize("seed", range(3))
def test_overwritten_block_gives_pyulog_values_or_a_clean_error(
    tmp_path: Path, seed: int
) -> None:
    raw = bytearray(shared_path("public", "PX4__pyulog", "sample_log_small.ulg").read_bytes())
    rng = np.random.default_rng(seed)
    at = int(rng.integers(16, len(raw) - 2000))
    raw[at : at + 1000] = rng.integers(0, 256, 1000).astype(np.uint8).tobytes()
    path = tmp_path / "hit.ulg"
    path.write_bytes(bytes(raw))
    try:
        ref, _ = pyulog(path)
    except Exception:
        with pytest.raises(LogFormatError):
            read(path)
        return
    log, _ = read(path)
    assert_tables_match(log, ref)


# ----------------------------------------------------------------------------- info

SMALL = ("public", "PX4__pyulog", "sample_log_small.ulg")


def test_info_text_matches_golden() -> None:
    """``mavsid info`` text of sample_log_small.ulg; rewritten only with
    MAVSID_UPDATE_GOLDEN=1."""
    path = shared_path(*SMALL)
    assert_info_matches_golden(read(path)[0], path)


def test_info_json_agrees_with_pyulog() -> None:
    from mavsid.info import summarize

    path = shared_path(*SMALL)
    summary = summarize(read(path)[0])
    ref, _ = pyulog(path)
    assert {k: v["count"] for k, v in summary["messages"].items()} == {
        name_of(d): len(d.data["timestamp"]) for d in ref.data_list
    }
    assert summary["param_count"] == len(ref.initial_parameters)
    assert summary["text_count"] == len(ref.logged_messages) + sum(
        len(v) for v in ref.logged_messages_tagged.values()
    )
    assert summary["notes"][0] == f"{len(ref.dropouts)} dropouts, " \
        f"{sum(d.duration for d in ref.dropouts)} ms in all"


@pytest.mark.parametrize("path", ULOGS, ids=ids(ULOGS))
def test_info_duration_is_pyulogs(path: Path) -> None:
    """The log's span as pyulog has it (header start to the last data timestamp), not the
    span of every topic's clock (a topic stamped 0 or in UNIX time made it 1.7e9 s)."""
    from mavsid.info import summarize

    ref, _ = pyulog(path)
    log, _ = read(path)
    want = (ref.last_timestamp - ref.start_timestamp) / 1e6
    assert summarize(log)["duration_s"] == pytest.approx(want, abs=1e-6)
    assert log.duration_s == pytest.approx(want, abs=1e-6)


def test_self_containing_formats_are_one_typed_error(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """pyulog expands nested formats recursively: a format containing itself (directly or
    through another) was a RecursionError out of it; now one LogFormatError naming the
    file and the chain."""
    from fuzz import hostile

    from mavsid.errors import LogFormatError

    for name, chain in (("ulog_self_reference", "loop -> loop"),
                        ("ulog_mutual_reference", "ping -> pong -> ping")):
        path = tmp_path / f"{name}.ulg"
        path.write_bytes(getattr(hostile, name)())
        with pytest.raises(LogFormatError, match=chain) as err:
            read_log(path)
        assert str(path) in str(err.value)


def test_a_damaged_parameter_type_is_skipped_and_counted(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from fuzz import hostile

    path = tmp_path / "param.ulg"
    path.write_bytes(hostile.ulog_damaged_parameter())
    with pytest.warns(DataQualityWarning, match="1 parameter value"):
        raw = read_log(path)
    assert raw.params == {"MC_ROLL_P": 6.5}
    assert len(raw["att"]) == 50
