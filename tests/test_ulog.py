"""PX4 ULog reader against pyulog: every shared .ulg field by field, selective loading,
damaged files; each test three ways: the compiled pass for plain logs (the Python reader for
the others), the Python reader with the compiled data walk, and with the numpy candidates
and runs a package built without a C compiler uses."""

from __future__ import annotations

import contextlib
import io
import struct
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers import (
    FIXTURES,
    assert_info_matches_golden,
    ids,
    require_shared,
    shared_logs,
    shared_path,
)
from pyulog import ULog

from mavsid.data import RawLog
from mavsid.errors import ConfigError, DataQualityWarning, LogFormatError
from mavsid.readers import (
    read_log,
    ulog,
    ulog_data,
    ulog_definitions,
    ulog_layout,
    ulog_messages,
    ulog_spec,
)

ULOGS = shared_logs(".ulg")
FIXTURE_ULOGS = sorted(FIXTURES.glob("*.ulg"))
PX4_ULOG_RS = ("public", "Auterion__px4-ulog-rs")


@pytest.fixture(autouse=True, params=["plain", "compiled", "numpy"])
def walk(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    """The log read by the compiled pass where it takes it (``_scan.ulog_plain``: "plain"),
    by the Python reader with its data section walked by ``_scan.ulog_data`` ("compiled";
    both where the package was built with a C compiler), or by the Python reader with the
    numpy candidates and runs (see ``ulog_data``'s *Framing*)."""
    if request.param != "numpy":
        if ulog_messages.compiled is None:
            pytest.skip("mavsid built without a C compiler: the numpy walk only")
        monkeypatch.setattr(ulog_data, "PLAIN", request.param == "plain")
    else:
        monkeypatch.setattr(ulog_messages, "compiled", None)
    return str(request.param)


def test_compiled_walk_takes_data_and_sync_messages_up_to_the_first_other() -> None:
    """``_scan.ulog_data`` directly: data messages written out, sync messages and ``M`` / ``Q``
    messages that carry nothing stepped over (``ulog_messages.checked`` on each), stopped by
    another type, a data message under 2 bytes, ``until``, the end of the buffer, or outputs
    without room (then resumed where it stopped)."""
    walk_fn = pytest.importorskip("mavsid.readers._scan").ulog_data  # (the fixture's
    # "numpy" run hides it from the reader only)

    def msg(kind: bytes, payload: bytes) -> bytes:
        return struct.pack("<HB", len(payload), kind[0]) + payload

    d1, d2 = msg(b"D", b"\x01\x00abc"), msg(b"D", b"\x02\x01")
    # sync, a text and a parameter default that carry nothing (stepped over, as checked
    # says), then an M whose value is not 4 bytes: it stops the walk
    sync = (msg(b"S", bytes(8)) + msg(b"M", b"\x00\x09char[1] ab")
            + msg(b"Q", b"\x01\x07float x" + bytes(4)))
    data = d1 + sync + d2 + d1 + msg(b"M", b"\x00\x07float x" + bytes(3)) + d1 + msg(
        b"D", b"\x05") + d1

    def run(start: int, until: int, room: int) -> tuple[list[int], list[int], list[int], int]:
        pos, size, ids_ = np.zeros(room, np.int64), np.zeros(room, np.uint16), np.zeros(
            room, np.uint16)
        k, reached = walk_fn(data, start, until, pos, size, ids_)
        return pos[:k].tolist(), size[:k].tolist(), ids_[:k].tolist(), reached

    a, b = len(d1), len(d1) + len(sync)
    c, stop_l = b + len(d2), b + len(d2) + len(d1)
    assert run(0, 1 << 40, 8) == ([0, b, c], [5, 2, 5], [1, 0x102, 1], stop_l)
    assert run(0, 1 << 40, 2) == ([0, b], [5, 2], [1, 0x102], c)  # no room: resume at c
    assert run(0, c, 8) == ([0, b], [5, 2], [1, 0x102], c)  # d1 at c would pass until
    after_l = stop_l + 3 + 12
    assert run(after_l, 1 << 40, 8)[1:] == ([5], [1], after_l + a)  # a 1-byte data message
    assert run(len(data) - a, 1 << 40, 8)[3] == len(data)  # up to the end
    assert run(len(data) - 2, 1 << 40, 8)[3] == len(data) - 2  # no room for a header
    assert run(0, len(data), 8)[3] == stop_l
    with pytest.raises(TypeError):
        walk_fn(data, 0, 10, np.zeros(4, np.int32), np.zeros(4, np.uint16),
                np.zeros(4, np.uint16))
    with pytest.raises(ValueError):
        walk_fn(data, len(data) + 1, 10, np.zeros(4, np.int64), np.zeros(4, np.uint16),
                np.zeros(4, np.uint16))


INFO_KEYS = [b"char[3] a", b"char[3]a", b"char[", b"float x", b"float ", b"floatx",
             b"int32_t n", b"int32_t", b"int32_tn", b"double d", b""]


def _random_info(rng: np.random.Generator) -> bytes:
    """An ``M`` or ``Q`` message near the forms ``ulog_messages.checked`` accepts: texts, 4-byte
    values, keys cut short or running past the message, spaces and none."""
    junk = rng.integers(0, 256, rng.integers(0, 3), dtype=np.uint8).tobytes()
    key = INFO_KEYS[rng.integers(len(INFO_KEYS))] + junk
    value = rng.integers(0, 256, rng.choice([4, 4, 0, 3, 5]), dtype=np.uint8).tobytes()
    length = len(key) if rng.random() < 0.6 else (len(key) + rng.integers(-2, 3)) % 256
    payload = bytes([rng.integers(0, 2), length]) + key + value
    if rng.random() < 0.3:
        payload = payload[: rng.integers(len(payload) - 3, len(payload))]
    return struct.pack("<HB", len(payload), ord(rng.choice(["M", "Q"]))) + payload


def test_compiled_walk_steps_over_the_info_messages_python_checks() -> None:
    """The compiled walk steps over an ``M`` / ``Q`` message exactly when ``ulog_messages.checked``
    accepts it (4 000 random ones)."""
    walk_fn = pytest.importorskip("mavsid.readers._scan").ulog_data
    rng = np.random.default_rng(7)
    d1 = struct.pack("<HBH", 5, ord("D"), 1) + b"abc"
    room = [np.zeros(4, np.int64), np.zeros(4, np.uint16), np.zeros(4, np.uint16)]
    taken = 0
    for _ in range(4000):
        info = _random_info(rng)
        data = d1 + info + d1
        k, _ = walk_fn(data, 0, len(data), *room)
        want = ulog_messages.checked(data, len(d1), len(d1) + len(info))
        assert k == (2 if want else 1), (info, want)
        taken += want
    assert 400 < taken < 3600, taken  # both outcomes met


@pytest.mark.slow
def test_compiled_info_runs_end_where_python_checks_stop() -> None:
    """``_scan.ulog_infos`` (the definitions' runs of ``M`` / ``Q`` messages) ends a run
    where stepping message by message with ``ulog_messages.checked`` does: 3 000 random runs of 0 to
    6 of them, then a format message, some with ``until`` inside."""
    infos = pytest.importorskip("mavsid.readers._scan").ulog_infos
    rng = np.random.default_rng(11)
    for _ in range(3000):
        data = b"".join(_random_info(rng) for _ in range(rng.integers(0, 7)))
        data += struct.pack("<HB", 4, ord("F")) + b"a:b;"
        until = len(data) if rng.random() < 0.7 else int(rng.integers(0, len(data) + 1))
        pos = 0
        while pos + 3 <= len(data):
            end = pos + 3 + int.from_bytes(data[pos : pos + 2], "little")
            if end > until or data[pos + 2] not in b"MQ" or not ulog_messages.checked(
                    data, pos, end):
                break
            pos = end
        assert infos(data, 0, until) == pos, data


def _formats_of(path: Path) -> list[bytes]:
    """The payloads of a ULog's format messages (its definitions section)."""
    raw, out, pos = path.read_bytes(), [], 16
    while pos + 3 <= len(raw):
        size, kind = struct.unpack_from("<HB", raw, pos)
        if kind in b"ALC":
            break
        if kind == ord("F"):
            out.append(raw[pos + 3 : pos + 3 + size])
        pos += 3 + size
    return out


@pytest.mark.slow
def test_the_compiled_format_parser_is_the_python_one() -> None:
    """``_scan.ulog_format`` gives ``parse_format``'s objects, or fails where it does: on
    every format of the shared and fixture ULogs, and on 20 000 of them damaged (bytes
    replaced by separators, brackets, digits, spaces, non-ASCII and invalid UTF-8)."""
    scan = pytest.importorskip("mavsid.readers._scan")
    texts = [t for p in [*ULOGS, *FIXTURE_ULOGS] for t in _formats_of(p)]
    texts += [b"", b":", b"a:", b"a:;;", b"a:float[]x;", b"a:float[3 x;", b"a:float]3[ x;",
              b"a:float[-1] x;", b"a:float[65536] x;", b"a:float[65535] x;", b"a:x[ 2 ] y;",
              b"a:float[2_0] x;", "a:float[\u0663] x;".encode(), b"a:b:c d;", b"a:float  x;"]
    assert len(texts) > 500
    rng = np.random.default_rng(3)
    alphabet = list(b":;[] 0123456789ab\xc3\xa9\xff\x80\xe2")
    for k in range(20_000):
        raw = bytearray(texts[k % len(texts)])
        for _ in range(rng.integers(1, 4)):
            if raw:
                raw[rng.integers(len(raw))] = alphabet[rng.integers(len(alphabet))]
        texts.append(bytes(raw))
    outcomes = set()
    for text in texts:
        try:
            want: Any = ulog_messages.parse_format(text)
        except ulog_messages.BadPayload:
            want = "bad"
        try:
            got: Any = scan.ulog_format(text, ulog_messages.TYPE_SIZE)
        except ValueError:
            got = "bad"
        assert got == want, text
        outcomes.add(want == "bad")
    assert outcomes == {True, False}


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


@pytest.mark.slow
@pytest.mark.parametrize("path", ULOGS, ids=ids(ULOGS))
def test_shared_ulog_matches_pyulog(path: Path) -> None:
    require_shared()
    assert_matches_pyulog(path)


@pytest.mark.parametrize("path", FIXTURE_ULOGS, ids=[p.name for p in FIXTURE_ULOGS])
def test_fixture_ulog_matches_pyulog(path: Path) -> None:
    assert_matches_pyulog(path)


def assert_matches_pyulog(path: Path) -> None:
    """Tables, parameters, texts, modes, span, dropouts and the corruption warning as
    pyulog has them."""
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
    assert log.span_s == (ref.start_timestamp / 1e6,
                          max(ref.last_timestamp, ref.start_timestamp) / 1e6)  # fmt: skip
    if ref.dropouts:
        total = sum(d.duration for d in ref.dropouts)
        assert f"{len(ref.dropouts)} dropouts, {total} ms in all" in log.source.notes


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


def test_an_option_is_a_config_error_naming_the_file() -> None:
    """``read_log`` passes its options on: the ULog reader takes none, and says so in one
    ConfigError naming the file and the option."""
    path = FIXTURE_ULOGS[0]
    with pytest.raises(ConfigError, match=rf"{path.name}: option\(s\) times_only do not "
                                          r"apply to PX4 ULog files"):
        read_log(path, times_only=True)


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
    with pytest.raises(LogFormatError, match="cannot open"):
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
    _same_as_pyulog_or_typed_error(path)


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


@pytest.mark.slow
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


def _parameter_ulog(keys: list[bytes]) -> bytes:
    """A small ULog whose definitions hold one parameter per key (4-byte values: the
    key's index as float32 for keys starting ``float``, else as int32)."""
    from fuzz import hostile

    out = bytearray(hostile.ulog_file([hostile.ATT_FORMAT], samples=3))
    params = b"".join(
        hostile._ulog_msg(b"P", bytes([len(key)]) + key
                          + struct.pack("<f" if key.startswith(b"f") else "<i", k))
        for k, key in enumerate(keys))  # fmt: skip
    at = out.index(b"att:") + len(hostile.ATT_FORMAT)  # after the format message
    return bytes(out[:at] + params + out[at:])


PLAIN_KEYS = [b"float MC_ROLL_P", b"int32_t MAV_TYPE", b"float MC_ROLL_P", b"int32_t ",
              b"float \xc3\xa9t\xc3", b"int32_t SYS_" + b"X" * 200]  # fmt: skip


@pytest.mark.parametrize("odd", [None, b"float A B", b"int32_t  TWO", b"flo", b"double D",
                                 b"float N\nL", b"int32_t", b"int32_tX Y", b""])
def test_parameters_read_at_once_are_pyulogs(tmp_path: Path, odd: bytes | None) -> None:
    """Plain parameters (``float name`` / ``int32_t name``, a 4-byte value) are decoded
    in one batch; a key that is not plain (a second word, a damaged or other type, a
    newline, no space) sends the batch through pyulog's general rules: same values,
    types and order as pyulog's (a repeated key: the last value, at the first place)."""
    keys = PLAIN_KEYS + ([] if odd is None else [odd, b"float AFTER"])
    path = tmp_path / "params.ulg"
    path.write_bytes(_parameter_ulog(keys))
    ref, _ = pyulog(path)
    log, _ = read(path)
    want = [(k, repr(v), type(v)) for k, v in ref.initial_parameters.items()]
    singly: list[int] = []

    class Reader(ulog_definitions.Definitions):
        def parameter(self, pos: int) -> None:
            singly.append(pos)
            super().parameter(pos)

    reader = Reader(path.read_bytes(), path, ulog_definitions.Parsed())
    reader.header()
    reader.definitions()
    assert bool(singly) == (odd is not None)  # the batch, or each on its own
    got = [(k, repr(v), type(v)) for k, v in reader.out.initial_params.items()]
    assert got == want
    numbers = {k: float(v) for k, v in ref.initial_parameters.items()
               if isinstance(v, (int, float))}  # fmt: skip
    assert log.params == numbers


def test_runs_of_plain_parameters_are_pyulogs(tmp_path: Path) -> None:
    """Runs of plain parameters are found at once, a window of the definitions at a time
    (``Definitions.plain_run``): over several windows, with a key of 255 bytes (a size above
    255) and bytes inside a key that look like a plain parameter's header, the reader's
    parameters are pyulog's, in its order."""
    keys = [b"float P%d" % k for k in range(8000)]
    keys[10] = b"float " + b"W" * 249
    keys[20] = keys[5000] = b"int32_t A_\x5f\x00PZ_B"  # "_\0" then "PZ": size 95 = 90 + 5
    path = tmp_path / "params.ulg"
    path.write_bytes(_parameter_ulog(keys))
    assert path.stat().st_size > 2 * ulog_definitions.PLAIN_WINDOW
    ref, _ = pyulog(path)
    reader = ulog_definitions.Definitions(path.read_bytes(), path, ulog_definitions.Parsed())
    reader.header()
    reader.definitions()
    want = [(k, repr(v), type(v)) for k, v in ref.initial_parameters.items()]
    assert [(k, repr(v), type(v)) for k, v in reader.out.initial_params.items()] == want
    assert not reader.out.problems


def test_a_read_imports_nothing_more() -> None:
    """A cold read (a fresh process, as the command line does it) imports no module the
    reader does not need: numpy.ma, pulled in by np.unique's first call, was 15 ms of a
    5 ms read of a small log."""
    import subprocess
    import sys

    code = ("import sys, warnings; warnings.simplefilter('ignore')\n"
            "from mavsid.readers import ulog\n"
            "before = set(sys.modules)\n"
            "ulog.read(sys.argv[1])\n"
            "print(sorted(set(sys.modules) - before))")
    for path in FIXTURE_ULOGS[:1]:
        out = subprocess.run([sys.executable, "-c", code, str(path)], check=True,
                             capture_output=True, text=True).stdout
        assert out.strip() == "[]", out


INFO_PAYLOADS = [bytes([9]) + b"char[3] ab" + b"xyz", bytes([7]) + b"char[3]" + b"xyz",
                 bytes([2]) + b"ch", bytes([7]) + b"float x" + bytes(4),
                 bytes([7]) + b"float x" + bytes(3), bytes([9]) + b"int32_t y" + bytes(4),
                 bytes([9]) + b"int32_t y" + bytes(8), bytes([40]) + b"char[1] z",
                 bytes([8]) + b"double d" + bytes(8), bytes([7]) + b"float\xff" + bytes(4),
                 b"", bytes([5]) + b"char[" + b" "]  # fmt: skip


@pytest.mark.parametrize("kind", [b"M", b"Q"])
@pytest.mark.parametrize("where", ["definitions", "parameters", "data"])
@pytest.mark.parametrize("payload", INFO_PAYLOADS, ids=range(len(INFO_PAYLOADS)))
def test_checked_info_messages_flag_what_pyulog_flags(
        tmp_path: Path, kind: bytes, where: str, payload: bytes) -> None:
    """``M`` and ``Q`` messages are only checked (plainly valid ones without decoding; in
    the definitions also between plain parameters, which are read in runs): one that
    pyulog cannot parse is corruption, as there; the tables and parameters are unchanged."""
    from fuzz import hostile

    raw = hostile.ulog_file([hostile.ATT_FORMAT], samples=5)
    message = hostile._ulog_msg(kind, b"\x00" + payload)
    at = raw.index(b"att:") + len(hostile.ATT_FORMAT) if where == "definitions" else \
        len(raw) - 17  # before the last data message (3 + 14 bytes)
    if where == "parameters":  # between plain parameters
        raw = _parameter_ulog([b"float A", b"int32_t B", b"float C"])
        at = raw.index(b"int32_t B") - 4  # (its header and key length before it)
    path = tmp_path / "info.ulg"
    path.write_bytes(raw[:at] + message + raw[at:])
    ref, printed = pyulog(path)
    log, quality = read(path)
    assert_tables_match(log, ref)
    assert log.params == {k: float(v) for k, v in ref.initial_parameters.items()}
    assert len(quality) == int(bool(ref.file_corruption or printed.strip())), quality


# ------------------------------------------------------------------ framing, truncation

def message_ends(raw: bytes) -> list[int]:
    """Where each message of a clean ULog ends: an independent walk over the headers
    (16-byte file header, then ``uint16 size, uint8 type`` and the payload)."""
    ends, pos = [], 16
    while pos + 3 <= len(raw):
        pos += 3 + int.from_bytes(raw[pos : pos + 2], "little")
        ends.append(pos)
    return ends


@pytest.mark.slow
@pytest.mark.parametrize("source", ["px4_hexa_doublets.ulg", "sample_log_small.ulg"])
@pytest.mark.parametrize("cut", [0.2, 0.55, 0.9, 1.0])
def test_truncated_last_message_is_counted(tmp_path: Path, source: str, cut: float) -> None:
    """A file cut inside its last message: the complete messages give pyulog's values and
    the partial one is counted (skipped bytes) and noted, not dropped silently."""
    src = FIXTURES / source if (FIXTURES / source).exists() else \
        shared_path("public", "PX4__pyulog", source)
    raw = src.read_bytes()
    ends = message_ends(raw)
    k = max(int(len(ends) * cut) - 1, 1)  # cut the k-th message (or the last) in its middle
    start, stop = ends[k - 1], ends[k]
    assert stop - start > 3
    at = start + (stop - start) // 2
    path = tmp_path / "cut.ulg"
    path.write_bytes(raw[:at])
    ref, _ = pyulog(path)
    log, said = read(path)
    assert_tables_match(log, ref)
    assert f"last message truncated: {at - start} bytes ignored" in log.source.notes
    assert any(f"last message truncated: {at - start} bytes ignored" in w for w in said)
    assert log.source.skipped_bytes == at - start
    whole, said = read(src)
    assert not any("truncated" in n for n in whole.source.notes)
    assert not any("truncated" in w for w in said)
    assert whole.source.skipped_bytes == 0


def test_selected_topics_match_pyulog_and_do_not_warn() -> None:
    """Topics not asked for are framed but neither decoded nor taken for corruption."""
    path = shared_path("public", "PX4__pyulog", "sample.ulg")
    ref, printed = pyulog(path, ["vehicle_attitude", "vehicle_status"])
    assert not ref.file_corruption and not printed.strip()
    log, quality = read(path, messages=["vehicle_attitude"])
    assert quality == []
    assert set(log.messages) == {"vehicle_attitude"}
    d = ref.get_dataset("vehicle_attitude")
    for field, want in d.data.items():
        assert np.array_equal(log["vehicle_attitude"][field], want)


def fake_header_ulog(samples: int = 400) -> bytes:
    """A valid ULog whose ``att`` records carry, in their float bytes, what looks like
    data-message headers of the right size and id (false framing candidates), and whose
    stream holds texts, parameter changes, dropouts and a second topic in between."""
    from fuzz.hostile import ATT_FORMAT, _ulog_msg, ulog_file

    out = bytearray(ulog_file([ATT_FORMAT, "rate:uint64_t timestamp;float[3] xyz;"],
                              [("float MC_ROLL_P", struct.pack("<f", 6.5))], topic=None))
    out += _ulog_msg(b"A", struct.pack("<BH", 0, 0) + b"att")
    out += _ulog_msg(b"A", struct.pack("<BH", 2, 7) + b"rate")
    fake = struct.pack("<HBH", 14, ord("D"), 0)  # a header of an att record, 5 bytes
    for k in range(samples):
        payload = fake[:4] if k % 3 == 0 else struct.pack("<f", 0.01 * k)
        out += _ulog_msg(b"D", struct.pack("<HQ", 0, 10_000 * k) + payload)
        if k % 7 == 0:
            out += _ulog_msg(b"D", struct.pack("<HQ", 7, 10_000 * k + 5) + fake + bytes(7))
        if k % 50 == 25:
            out += _ulog_msg(b"L", struct.pack("<BQ", ord("6"), 10_000 * k) + b"hello")
            out += _ulog_msg(b"O", struct.pack("<H", 20))
            out += _ulog_msg(b"P", bytes([15]) + b"float MC_ROLL_P" + struct.pack("<f", k))
    return bytes(out)


def test_a_field_of_every_basic_type_reads_as_pyulog(tmp_path: Path) -> None:
    """A topic with one field of each of the spec's basic types (the compiled pass keeps its
    own copy of the table): every walk reads pyulog's values."""
    from fuzz.hostile import _ulog_msg, ulog_file

    kinds = [k for k in ulog_spec.BASIC_TYPES if k != "char"]
    fields = "".join(f"{k} f_{k};" for k in kinds)
    out = bytearray(ulog_file(["all:uint64_t timestamp;" + fields], topic=None))
    out += _ulog_msg(b"A", struct.pack("<BH", 0, 3) + b"all")
    code = "<HQ" + "".join(ulog_spec.BASIC_TYPES[k].code for k in kinds)
    for i in range(20):
        values = [(i % 2 == 0) if k == "bool" else (i * 7 - 60) * (0.25 if k in ("float", "double")
                  else 1) for k in kinds]
        values = [abs(v) if k.startswith("uint") else v for k, v in zip(kinds, values, strict=True)]
        out += _ulog_msg(b"D", struct.pack(code, 3, 10_000 * (i + 1), *values))
    path = tmp_path / "basic.ulg"
    path.write_bytes(bytes(out))
    assert_matches_pyulog(path)
    log, _ = read(path)
    assert log["all"]["f_int16_t"].tolist()[:3] == [-60, -53, -46]


def test_false_candidates_inside_records_keep_pyulogs_framing(tmp_path: Path) -> None:
    path = tmp_path / "fake.ulg"
    path.write_bytes(fake_header_ulog())
    ref, printed = pyulog(path)
    log, quality = read(path)
    assert quality == [] and not printed.strip()
    assert_tables_match(log, ref)
    assert len(log["att"]) == 400 and len(log["rate[2]"]) == 58
    assert log.params["MC_ROLL_P"] == ref.changed_parameters[-1][2]
    assert f"{len(ref.dropouts)} dropouts, {20 * len(ref.dropouts)} ms in all" \
        in log.source.notes
    assert [t.text for t in log.texts] == [m.message for m in ref.logged_messages]


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(6))
def test_garbage_between_messages_resynchronises_as_pyulog(tmp_path: Path, seed: int) -> None:
    """Random bytes inserted between two messages (no sync message after them): pyulog
    steps over them; so does the reader, counting the bytes, with the same values."""
    raw = shared_path("public", "PX4__pyulog", "sample_log_small.ulg").read_bytes()
    ends = message_ends(raw)
    rng = np.random.default_rng(seed)
    at = ends[int(rng.integers(len(ends) // 4, len(ends) - 10))]
    junk = rng.integers(0, 256, int(rng.integers(1, 400))).astype(np.uint8).tobytes()
    path = tmp_path / "junk.ulg"
    path.write_bytes(raw[:at] + junk + raw[at:])
    got = _same_as_pyulog_or_typed_error(path)
    if got is not None:
        log, ref = got
        assert log.source.skipped_bytes >= (0 if not ref.file_corruption else 1)


@pytest.mark.slow
def test_huge_claimed_sizes_and_garbage_are_bounded(tmp_path: Path) -> None:
    """A megabyte of garbage and of maximal sizes after valid definitions: a result or one
    typed error, in linear time (no hang: each step moves forward)."""
    from fuzz.hostile import ATT_FORMAT, ulog_file

    head = ulog_file([ATT_FORMAT], samples=10)
    rng = np.random.default_rng(1)
    for tail in (rng.integers(0, 256, 1 << 20).astype(np.uint8).tobytes(),
                 b"\xff\xff\x00" * (1 << 18), b"\x01\x00X" * (1 << 18),
                 b"\xff\xffD" * (1 << 18)):  # fmt: skip
        path = tmp_path / "tail.ulg"
        path.write_bytes(head + tail)
        log, _ = read(path)
        assert len(log["att"]) >= 10


@pytest.mark.slow
@pytest.mark.parametrize("between", ["sync", "text"])
def test_data_messages_each_before_another_match_pyulog(tmp_path: Path, between: str) -> None:
    """Data messages each followed by a sync message (one-message runs for the numpy walk,
    their bookkeeping joined as it grows; one run for the compiled walk, which steps over
    sync messages) or by a logged text (every walk takes one message, kept as a single, not
    a run's bookkeeping each): pyulog's values and texts."""
    from fuzz.hostile import ATT_FORMAT, _ulog_msg, ulog_file

    out = bytearray(ulog_file([ATT_FORMAT], samples=0))
    other = (_ulog_msg(b"S", b"\x2f\x73\x13\x20\x25\x0c\xbb\x12") if between == "sync"
             else _ulog_msg(b"L", struct.pack("<BQ", ord("6"), 7) + b"x"))
    for k in range(10_000):
        out += _ulog_msg(b"D", struct.pack("<HQf", 0, 1000 * k, k / 7)) + other
    path = tmp_path / "short_runs.ulg"
    path.write_bytes(bytes(out))
    ref, _ = pyulog(path)
    log, quality = read(path)
    assert quality == []
    assert_tables_match(log, ref)
    assert len(log["att"]) == 10_000
    assert len(log.texts) == len(ref.logged_messages) == (10_000 if between == "text" else 0)


@pytest.mark.slow
def test_a_file_of_data_header_look_alikes_matches_pyulog(tmp_path: Path) -> None:
    """Every byte after the subscription is ``D``: every position is a framing candidate
    (size 0x4444 = the subscribed format's + 2, id 0x4444 subscribed); the candidates are
    found a block at a time, and the records are pyulog's."""
    from fuzz.hostile import ATT_FORMAT, _ulog_msg, ulog_file

    fmt = f"big:uint64_t timestamp;uint8_t[{0x4444 - 2 - 8}] x;"
    out = bytearray(ulog_file([ATT_FORMAT, fmt], topic=None))
    out += _ulog_msg(b"A", struct.pack("<BH", 0, 0x4444) + b"big")
    out += b"D" * (3 << 20)
    path = tmp_path / "look_alikes.ulg"
    path.write_bytes(bytes(out))
    ref, _ = pyulog(path)
    log, _ = read(path)
    assert_tables_match(log, ref)
    assert len(log["big"]) == (3 << 20) // 0x4447
    assert f"last message truncated: {(3 << 20) % 0x4447} bytes ignored" in log.source.notes


def _same_as_pyulog_or_typed_error(path):  # type: ignore[no-untyped-def]
    """A damaged file: where pyulog reads it, mavsid's tables equal pyulog's (returned with
    pyulog's object); where pyulog raises, mavsid raises LogFormatError (None)."""
    try:
        ref, _ = pyulog(path)
    except Exception:
        with pytest.raises(LogFormatError):
            read(path)
        return None
    log, _ = read(path)
    assert_tables_match(log, ref)
    return log, ref


def test_runs_across_sync_and_checked_messages_match_pyulog(tmp_path: Path) -> None:
    """Runs of data messages go on across sync messages (with the magic or not) and ``M`` /
    ``Q`` messages that carry nothing, and stop at those that do or that pyulog cannot read:
    a dropout, a parameter change, an ``M`` it reads with another type, a damaged ``Q``,
    and at last an ``M`` without its key, which ends pyulog's read (the data after it is
    not taken)."""
    from fuzz.hostile import ATT_FORMAT, _ulog_msg, ulog_file

    def record(k: int) -> bytes:
        return _ulog_msg(b"D", struct.pack("<HQf", 0, 10_000 * k, 0.01 * k))

    between = [
        _ulog_msg(b"S", bytes.fromhex("2f731320250cbb12")),
        _ulog_msg(b"S", b"xyz"),
        _ulog_msg(b"M", bytes([0, 11]) + b"char[3] ver" + b"abc"),
        _ulog_msg(b"Q", bytes([0, 7]) + b"float x" + struct.pack("<f", 1.5)),
        _ulog_msg(b"S", bytes(8)) + _ulog_msg(b"M", bytes([1, 9]) + b"int32_t n" + bytes(4)),
        _ulog_msg(b"O", struct.pack("<H", 40)),
        _ulog_msg(b"P", bytes([9]) + b"float X_Y" + struct.pack("<f", 2.0)),
        _ulog_msg(b"M", bytes([0, 11]) + b"uint8_t[2] v" + b"ab"),  # read by pyulog: not checked
        _ulog_msg(b"Q", bytes([0, 40]) + b"float"),  # damaged: corruption
    ]
    out = bytearray(ulog_file([ATT_FORMAT], topic=None))
    out += _ulog_msg(b"A", struct.pack("<BH", 0, 0) + b"att")
    k = 0
    for _ in range(3):
        for message in between:
            for _ in range(5):
                out += record(k)
                k += 1
            out += message
    out += record(k) + _ulog_msg(b"M", bytes([0])) + record(k + 1) + record(k + 2)
    path = tmp_path / "carriers.ulg"
    path.write_bytes(bytes(out))
    ref, _ = pyulog(path)
    log, _ = read(path)
    assert_tables_match(log, ref)
    assert len(log["att"]) == k + 1
    assert log.source.notes[0] == "3 dropouts, 120 ms in all"
    assert log.params["X_Y"] == 2.0


def test_formats_kept_for_the_process_never_mix_two_logs(tmp_path: Path) -> None:
    """Parsed formats and record layouts are kept between reads (logs of one firmware repeat
    them), keyed by the texts of a topic's format and of every format it nests: logs whose
    ``att`` has the same text but a nested type defined otherwise, or not at all, read one
    after another in one process (and again, in another order), each as pyulog reads it."""
    from fuzz.hostile import _ulog_msg, ulog_file

    att = "att:uint64_t timestamp;inner x;uint8_t[2] _padding0;"
    variants = {
        "two_floats": ("inner:float a;float b;", "<ff", (0.5, -2.0)),
        "int_and_bytes": ("inner:int32_t c;float d;uint8_t[4] e;", "<if4B", (-7, 1.5, 1, 2, 3, 4)),
        "undefined": (None, "<ff", (0.5, -2.0)),  # att nests a type the log never defines
    }
    paths = {}
    for name, (inner, code, values) in variants.items():
        out = bytearray(ulog_file([f for f in (inner, att) if f], topic=None,
                                  params=[("float MC_ROLL_P", struct.pack("<f", 6.5))]))
        out += _ulog_msg(b"A", struct.pack("<BH", 0, 0) + b"att")
        for k in range(20):
            out += _ulog_msg(b"D", struct.pack("<HQ", 0, 10_000 * k)
                             + struct.pack(code, *values))  # (trailing padding: not written)
        paths[name] = tmp_path / f"{name}.ulg"
        paths[name].write_bytes(bytes(out))
    for name in ("two_floats", "int_and_bytes", "undefined", "two_floats", "undefined",
                 "int_and_bytes"):
        got = _same_as_pyulog_or_typed_error(paths[name])
        if name == "undefined":  # pyulog reads the file, without the unreadable topic
            assert got is not None and "att" not in got[0].messages
        else:
            assert got is not None and len(got[0]["att"]) == 20
            assert sorted(got[0]["att"].columns) == sorted(
                ["timestamp", "x.a", "x.b"] if name == "two_floats"
                else ["timestamp", "x.c", "x.d"] + [f"x.e[{i}]" for i in range(4)])


def _content(table: Any) -> tuple[Any, bytes, bytes]:
    """A table's layout and bytes: its fields' names and types, records' bytes, times."""
    columns = table.columns
    return ([(name, columns[name].dtype.str) for name in columns], bytes(columns.raw),
            table.time_s.tobytes())


@pytest.mark.slow
def test_logs_read_in_threads_with_little_kept_are_each_their_own(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Logs read at once in threads (a threaded Dask worker), with a budget so small that
    kept formats and layouts are dropped all the time: every read equals the same log's
    read alone (each compared with pyulog elsewhere)."""
    from concurrent.futures import ThreadPoolExecutor

    require_shared()
    paths = ULOGS[:6]
    alone = {}
    for p in paths:
        log, _ = read(p)
        alone[p] = {name: _content(table) for name, table in log.messages.items()}
    for kept in (ulog_layout.known_format, ulog_layout.known_layout):
        monkeypatch.setattr(kept, "budget", 400)
        kept.clear()

    def check(p: Path) -> bool:
        got = ulog.read(p).messages
        return {name: _content(table) for name, table in got.items()} == alone[p]

    with warnings.catch_warnings(), ThreadPoolExecutor(6) as pool:  # (corruption warned)
        warnings.simplefilter("ignore", DataQualityWarning)
        assert all(pool.map(check, paths * 4))
    assert all(k.total <= 400 for k in (ulog_layout.known_format, ulog_layout.known_layout))


def _everything(path: Path, **kwargs: Any) -> Any:
    """All a read returns, as values to compare (tables' fields, types, bytes and times;
    parameters, texts, modes, span, notes, firmware) with its warnings; or its error."""
    try:
        log, quality = read(path, **kwargs)
    except LogFormatError as exc:
        return "error", str(exc)
    tables = {name: (_content(t), dict(t.units)) for name, t in log.messages.items()}
    return (tables, dict(log.params), log.texts, log.modes, log.span_s, log.source,
            log.firmware, log.vehicle, quality)


def _both_ways(path: Path, monkeypatch: pytest.MonkeyPatch, **kwargs: Any) -> tuple[Any, Any]:
    """The read by the compiled pass (where it takes the log) and by the Python reader."""
    with monkeypatch.context() as m:
        m.setattr(ulog_data, "PLAIN", True)
        plain = _everything(path, **kwargs)
        m.setattr(ulog_data, "PLAIN", False)
        return plain, _everything(path, **kwargs)


@pytest.mark.slow
@pytest.mark.parametrize("walk", ["plain"], indirect=True)
def test_the_compiled_pass_takes_real_logs_and_reads_them_as_the_python_reader(
        walk: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every shared ULog but the one with unsubscribed, garbage-filled data and the fixture are
    read by the compiled pass (with the commonest damage: data without subscription,
    resynchronisation at a sync magic), and it gives what the Python reader gives: all
    topics, some topics and instances, a time window."""
    scan = pytest.importorskip("mavsid.readers._scan")
    require_shared()
    for path in [*ULOGS, *FIXTURE_ULOGS]:
        taken = scan.ulog_plain(path.read_bytes(), None) is not None
        assert taken == (path.name != "corrupt_actuator_armed_wrong_size.ulg"), path.name
        for kwargs in ({}, {"messages": ["vehicle_attitude", "actuator_outputs[1]"]},
                       {"start": 30.0, "stop": 60.0}):
            plain, python = _both_ways(path, monkeypatch, **kwargs)
            assert plain == python, (path.name, kwargs)


@pytest.mark.slow
@pytest.mark.parametrize("walk", ["plain"], indirect=True)
@pytest.mark.parametrize("seed", range(4))
def test_damaged_logs_read_by_the_compiled_pass_as_by_the_python_reader(
        walk: str, monkeypatch: pytest.MonkeyPatch, tmp_path: Path, seed: int) -> None:
    """Logs damaged at random (bytes overwritten, in the definitions too, a block of garbage
    or of sync magics put in, headers rewritten, a cut, a block repeated): whether the
    compiled pass takes one or sends it to the Python reader, the read is the Python
    reader's, value for value, warning for warning, or the same error. Some of them must be
    taken (else this tests nothing)."""
    pytest.importorskip("mavsid.readers._scan")
    sources = [p for p in FIXTURE_ULOGS]
    if shared_logs(".ulg"):
        sources.append(shared_path("public", "roboto-ai__robologs-px4-actions", "test.ulg"))
    rng = np.random.default_rng(seed)
    taken = 0
    for k in range(28):
        base = sources[k % len(sources)].read_bytes()
        out = bytearray(base)
        start = int(rng.integers(16, len(out) - 64))
        how = k % 7
        if how == 6:  # a byte of the header or the definitions overwritten
            out[int(rng.integers(16, 4000))] = int(rng.integers(0, 256))
        elif how == 0:  # bytes overwritten
            at = rng.integers(start, len(out), 1 + int(rng.integers(0, 4)))
            out[at[0]] ^= 0xFF
            for a in at[1:]:
                out[int(a)] = int(rng.integers(0, 256))
        elif how == 1:  # garbage put in
            out[start:start] = rng.integers(0, 256, int(rng.integers(1, 300)), np.uint8).tobytes()
        elif how == 2:  # sync magics and garbage
            out[start:start] = (ulog_spec.SYNC + bytes(int(rng.integers(0, 7)))) * 3
        elif how == 3:  # a message header rewritten: another size or type
            out[start] = int(rng.integers(0, 256))
            out[start + 2] = int(rng.choice(list(b"DAOLCIMPQSFB\x00")))
        elif how == 4:  # cut
            out = out[:start]
        else:  # a block repeated
            out[start:start] = out[start : start + int(rng.integers(3, 2000))]
        path = tmp_path / f"damaged{k}.ulg"
        path.write_bytes(bytes(out))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DataQualityWarning)
            taken += ulog_data.read_plain(bytes(out), None) is not None
        plain, python = _both_ways(path, monkeypatch)
        assert plain == python, (k, how)
        if k % 4 == 0:
            plain, python = _both_ways(path, monkeypatch, messages=["vehicle_attitude"])
            assert plain == python, (k, how, "selective")
    assert taken >= 4


@pytest.mark.slow
@pytest.mark.parametrize("walk", ["plain"], indirect=True)
@pytest.mark.parametrize("layout", ["px4-1.14", "px4-1.11", "px4-1.8"])
def test_simulated_layouts_read_by_the_compiled_pass_as_by_the_python_reader(
        walk: str, monkeypatch: pytest.MonkeyPatch, tmp_path: Path, layout: str) -> None:
    """PX4's three topic sets as the simulator writes them, with records dropped and the
    last one cut: taken by the compiled pass, read as the Python reader reads them."""
    from mavsid.synthetic.faults import Faults
    from mavsid.synthetic.run import scenario_from_options, simulate

    scan = pytest.importorskip("mavsid.readers._scan")
    path = tmp_path / f"{layout}.ulg"
    simulate(scenario_from_options(manoeuvre="doublet", seed=3, duration_s=20), [path],
             faults=Faults.parse("drop=0.02,truncate=77", seed=2), layout=layout)
    assert scan.ulog_plain(path.read_bytes(), None) is not None
    plain, python = _both_ways(path, monkeypatch)
    assert plain == python
    assert "last message truncated" in python[-1][0]


@pytest.mark.slow
@pytest.mark.parametrize("walk", ["plain"], indirect=True)
def test_the_compiled_pass_is_bounded_on_hostile_nesting(
        walk: str, monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """Formats nesting an empty one 65535 × 65535 × 65535 times (no field: the pass must not
    walk the repetitions), and twenty topics of 60 000 fields each (more fields than the
    pass keeps for one read: it leaves the log to the Python reader, which keeps layouts
    within a budget): read as the Python reader reads them."""
    from fuzz.hostile import ATT_FORMAT, ulog_file

    scan = pytest.importorskip("mavsid.readers._scan")
    nested = ulog_file([ATT_FORMAT, "x:uint64_t timestamp;uint64_t v;y[65535] a;",
                        "y:z[65535] b;", "z:e[65535] c;", "e:"], also=("x",))
    wide = ulog_file([ATT_FORMAT] + [f"w{i}:uint64_t timestamp;uint8_t[60000] a;"
                                     for i in range(20)],
                     also=tuple(f"w{i}" for i in range(20)))
    for name, data, taken in (("nested", nested, True), ("wide", wide, False)):
        path = tmp_path / f"{name}.ulg"
        path.write_bytes(data)
        assert (scan.ulog_plain(data, None) is not None) == taken, name
        plain, python = _both_ways(path, monkeypatch)
        assert plain == python, name
    assert list(read(tmp_path / "nested.ulg")[0]["x"].columns) == ["timestamp", "v"]


def test_appended_data_claimed_past_any_file_is_pyulogs(tmp_path: Path) -> None:
    """Flag bits claiming appended data at an offset past 2**63 (a damaged header; the
    compiled walk took it as its end of section and failed to convert it): read as pyulog
    reads it, corruption flagged."""
    from fuzz.hostile import ATT_FORMAT, ulog_file

    data = bytearray(ulog_file([ATT_FORMAT]))
    data[19 + 8] = 1  # the flag bits' payload: incompatible flags at 8, offsets at 16
    data[19 + 16 : 19 + 24] = struct.pack("<Q", (1 << 63) + 5)
    path = tmp_path / "offset.ulg"
    path.write_bytes(bytes(data))
    got = _same_as_pyulog_or_typed_error(path)
    assert got is not None and len(got[0]["att"]) == 50
    assert "file corruption found" in read(path)[1][0]
