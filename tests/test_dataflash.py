"""DataFlash .bin reader: values equal pymavlink's, robustness on broken logs.

Reference: pymavlink (``mavutil.mavlink_connection(path)``, ``recv_match()``, ``to_dict()``),
every message type, every field, same counts, on every shared ``.bin`` pymavlink reads. The
104 MB SITL log is compared on a chosen set of types (the attitude, rate, SYSTEMID and
metadata messages, ~190k records) with ``recv_match(type=...)``, once per session; the small
logs on everything.
"""

from __future__ import annotations

import array
import math
import random
import warnings
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers import LOGS, ids, require_shared, shared_logs, shared_path
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mavsid.data import RawLog
from mavsid.errors import DataQualityWarning, LogFormatError, MissingMessageError
from mavsid.readers import (
    dataflash,
    dataflash_decode,
    dataflash_formats,
    dataflash_framing,
    dataflash_scan,
    dataflash_spec,
    read_log,
)
from mavsid.readers.dataflash_spec import build_fmt, build_record

BIN_LOGS = [p for p in shared_logs(".bin") if "sitl" not in p.parts]
SITL = ("sitl", "flightA_mixer.BIN")
SITL_TYPES = ["ATT", "RATE", "SIDS", "MODE", "PARM", "MSG", "RCOU", "RCIN", "CTUN", "VER",
              "FMT", "FMTU", "UNIT", "MULT", "PIDR", "BAT"]
SMALL = ("public", "ArduPilot__pymavlink", "test.BIN")


# --------------------------------------------------------------------------- reference
def pymavlink_records(path: Path, types: list[str] | None = None) -> dict[str, list[dict]]:
    """Every message pymavlink yields, as ``to_dict()``, grouped by type."""
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(path))
    out: dict[str, list[dict]] = defaultdict(list)
    while True:
        m = conn.recv_match(type=types) if types else conn.recv_match()
        if m is None:
            break
        out[m.get_type()].append(m.to_dict())
    conn.close()
    return dict(out)


def same_value(ours: Any, ref: Any) -> bool:
    """Equal value and Python type; NaN equals NaN; int16 arrays as lists."""
    if isinstance(ref, array.array):
        return list(ours) == list(ref)
    if isinstance(ref, float) and math.isnan(ref):
        return isinstance(ours, float) and math.isnan(ours)
    return type(ours) is type(ref) and ours == ref


def assert_matches(log: RawLog, ref: dict[str, list[dict]], types: list[str] | None = None):
    """Same types (all, or ``types``), counts, fields and values as pymavlink."""
    if types is None:
        assert set(log.messages) == set(ref)
    for name, recs in ref.items():
        table = log[name]
        assert len(table) == len(recs), name
        fields = [f for f in recs[0] if f != "mavpackettype"]
        assert list(table.fields) == fields, name
        for f in fields:
            ours = table[f].tolist()
            for k, rec in enumerate(recs):
                assert same_value(ours[k], rec[f]), (name, f, k, ours[k], rec[f])


@pytest.fixture(scope="module")
def sitl_pair():
    path = shared_path(*SITL)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataQualityWarning)
        log = read_log(path)
    return log, pymavlink_records(path, SITL_TYPES)


# --------------------------------------------------------------------------- equality
@pytest.mark.parametrize("path", BIN_LOGS, ids=ids(BIN_LOGS))
def test_every_value_equals_pymavlink(path):
    require_shared()
    ref = pymavlink_records(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataQualityWarning)
        log = read_log(path)
    assert log.autopilot == "ardupilot"
    assert_matches(log, ref)


def test_shared_bin_logs_are_all_covered():
    require_shared()
    names = {p.name for p in BIN_LOGS}
    assert {"test.BIN", "backend_log_80k.bin", "output.BIN", "minimal.bin"} <= names


@pytest.mark.slow
def test_sitl_log_equals_pymavlink_on_attitude_rate_sysid_types(sitl_pair):
    log, ref = sitl_pair
    assert set(ref) <= set(SITL_TYPES) and {"ATT", "RATE", "SIDS", "PARM"} <= set(ref)
    assert_matches(log, ref, types=SITL_TYPES)
    assert len(ref["RATE"]) > 100_000 and len(ref["SIDS"]) == 4


@pytest.mark.slow
def test_sitl_log_metadata(sitl_pair):
    log, ref = sitl_pair
    assert log.firmware == next(r["Message"] for r in ref["MSG"] if r["Message"].startswith(
        "ArduCopter"))
    assert log.vehicle is not None and log.vehicle.startswith("copter")
    last = {}
    for r in ref["PARM"]:
        last[r["Name"]] = r["Value"]
    assert log.params == pytest.approx(last)
    assert [m.mode for m in log.modes] == [r["ModeNum"] for r in ref["MODE"]]
    assert [m.name for m in log.modes].count("SYSTEMID") == 4
    assert [t.text for t in log.texts] == [r["Message"] for r in ref["MSG"]]
    att = log["ATT"]
    np.testing.assert_array_equal(att.time_s, att["TimeUS"] * 1e-6)
    assert log["RATE"].unit("R") == "deg/s" and log["ATT"].unit("Roll") == "deg"


@pytest.mark.slow
def test_selective_load_and_time_window_match_full_decode(sitl_pair):
    full, _ = sitl_pair
    path = shared_path(*SITL)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataQualityWarning)
        sel = read_log(path, messages=["ATT", "RATE", "SIDS", "NOPE"])
        win = read_log(path, messages=["RATE", "FMT"], start=100.0, stop=110.0)
    assert set(sel.messages) == {"ATT", "RATE", "SIDS"}
    for name in sel.messages:
        for f in full[name].fields:
            np.testing.assert_array_equal(sel[name][f], full[name][f])
    assert sel.params == full.params and sel.modes == full.modes
    t = full["RATE"].time_s
    keep = (t >= 100.0) & (t <= 110.0)
    np.testing.assert_array_equal(win["RATE"]["R"], full["RATE"]["R"][keep])
    assert win["RATE"].time_s.min() >= 100.0 and win["RATE"].time_s.max() <= 110.0
    with pytest.raises(MissingMessageError, match="NOPE"):
        sel["NOPE"]


# --------------------------------------------------------------------------- broken logs
def test_minimal_bin_salvages_the_fmt_and_warns_once():
    path = shared_path("public", "HatemslaH__rust_dataflash_parser", "minimal.bin")
    with pytest.warns(DataQualityWarning) as rec:
        log = read_log(path)
    assert len(rec) == 1
    msg = str(rec[0].message)
    assert "36" in msg and "89" in msg and "only format definitions" in msg
    assert set(log.messages) == {"FMT"} and log.source.skipped_bytes == 36


@pytest.mark.parametrize("parts", [("public", "ArduPilot__pymavlink", "test.BIN"),
                                   ("public", "ArduPilot__MethodicConfigurator",
                                    "backend_log_80k.bin")])
def test_cut_logs_warn_once_with_the_cut_offset(parts):
    path = shared_path(*parts)
    with pytest.warns(DataQualityWarning) as rec:
        log = read_log(path)
    assert len(rec) == 1
    size = path.stat().st_size
    cut = log.source.skipped_bytes
    assert 0 < cut < 100 and f"{size - cut}+{cut}" in str(rec[0].message)


@pytest.mark.parametrize(
    "content",
    [b"", b"\xa3\x95", b"\xa3\x95\x80" + bytes(40),
     np.random.default_rng(7).bytes(3000).replace(b"\xa3", b"\x00")],
    ids=["empty", "header-only", "fmt-header-zeros", "random-bytes"],
)
def test_nothing_decodable_is_a_log_format_error_naming_the_file(tmp_path, content):
    path = tmp_path / "bad.bin"
    path.write_bytes(content)
    with pytest.raises(LogFormatError, match=r"bad\.bin"):
        dataflash.read(path)


def test_fmt_only_log_is_empty_with_a_warning(tmp_path):
    path = tmp_path / "fmt_only.bin"
    path.write_bytes(build_fmt(0x81, "ATT", "Qf", "TimeUS,Roll")
                     + build_fmt(0x82, "RATE", "Qf", "TimeUS,R"))
    with pytest.warns(DataQualityWarning, match="only format definitions"):
        log = dataflash.read(path)
    assert set(log.messages) == {"FMT"} and len(log["FMT"]) == 2
    assert log.duration_s == 0.0


# --------------------------------------------------------------------------- synthetic logs
ALL_TYPES = ("bBhHiIfdnNZ", "cCeELMqQag")  # every format character; FMT holds <= 16


def _all_types_log() -> tuple[bytes, list[list[Any]]]:
    raw = [[-5, 250, -300, 60000, -70000, 4000000000, 1.5, -2.25, "abc", "sixteen chars!!",
            "text\0junk"],
           [-12345, 54321, -1234567, 3000000000, -353632123, 7, -(2**40), 2**63 + 5,
            list(range(-16, 16)), 0.333251953125]]
    data = b""
    for k, (chars, values) in enumerate(zip(ALL_TYPES, raw, strict=True)):
        columns = ",".join(f"F{c}" for c in chars)
        data += build_fmt(0x81 + k, f"ALL{k}", "Q" + chars, "TimeUS," + columns)
        data += build_record(0x81 + k, "Q" + chars, 2_000_000, *values)
    return data, raw


def test_every_format_character_is_presented_as_pymavlink_does(tmp_path):
    data, raw = _all_types_log()
    path = tmp_path / "all.bin"
    path.write_bytes(data)
    ref = pymavlink_records(path)
    log = dataflash.read(path)
    assert_matches(log, ref)
    # and by hand, for what the scaling means
    row = {f: log["ALL1"][f].tolist()[0] for f in log["ALL1"].fields}
    assert row["Fc"] == -123.45 and row["FL"] == -353632123 / (1 / 1e-7)
    assert row["Fa"] == list(range(-16, 16)) and row["Fg"] == raw[1][-1]
    assert log["ALL0"]["FZ"].tolist() == ["text"]
    assert log["ALL0"].time_s.tolist() == [2.0]


def test_units_and_multipliers_from_fmtu_unit_mult(tmp_path):
    data = (build_fmt(0x81, "ATT", "QfcB", "TimeUS,Roll,Pitch,I")
            + build_fmt(0x82, "UNIT", "QbZ", "TimeUS,Id,Label")
            + build_fmt(0x83, "MULT", "Qbd", "TimeUS,Id,Mult")
            + build_fmt(0x84, "FMTU", "QBNN", "TimeUS,FmtType,UnitIds,MultIds")
            + build_record(0x82, "QbZ", 1, ord("d"), "deg")
            + build_record(0x82, "QbZ", 1, ord("s"), "s")
            + build_record(0x82, "QbZ", 1, ord("#"), "instance")
            + build_record(0x83, "Qbd", 1, ord("F"), 1e-6)
            + build_record(0x83, "Qbd", 1, ord("B"), 0.01)
            + build_record(0x84, "QBNN", 1, 0x81, "sdd#", "FBB-")
            + build_record(0x81, "QfcB", 5, 1.0, 100, 0))
    path = tmp_path / "units.bin"
    path.write_bytes(data)
    att = dataflash.read(path)["ATT"]
    assert dict(att.units) == {"TimeUS": "s", "Roll": "deg", "Pitch": "deg", "I": "instance"}
    # the multiplier is metadata only; none for Pitch whose format character already scales
    assert dict(att.multipliers) == {"TimeUS": 1e-6, "Roll": 0.01}
    assert att["Roll"].tolist() == [1.0] and att["Pitch"].tolist() == [1.0]


def test_fmt_redefinition_mid_log_and_time_going_backwards(tmp_path):
    first = (build_fmt(0x81, "ATT", "Qcc", "TimeUS,Roll,Pitch")
             + b"".join(build_record(0x81, "Qcc", 10_000_000 + k, k, -k) for k in range(3)))
    second = (build_fmt(0x81, "ATT", "Qfff", "TimeUS,Roll,Pitch,Yaw")
              + b"".join(build_record(0x81, "Qfff", 1_000 + k, k, -k, 9) for k in range(2)))
    path = tmp_path / "concat.bin"
    path.write_bytes(first + second)
    with pytest.warns(DataQualityWarning, match="backwards 1 time") as rec:
        log = dataflash.read(path)
    assert len(rec) == 1 and any("backwards" in n for n in log.source.notes)
    att = log["ATT"]
    assert att["Roll"].tolist() == [0.0, 0.01, 0.02, 0.0, 1.0]
    assert np.isnan(att["Yaw"][:3]).all() and att["Yaw"][3:].tolist() == [9.0, 9.0]
    assert att.time_s.tolist() == [10.0, 10.000001, 10.000002, 0.001, 0.001001]
    assert log.source.skipped_bytes == 0


def test_unknown_types_and_garbage_between_records_are_skipped_and_counted(tmp_path):
    good = [build_record(0x81, "Qh", 1000 * k, k) for k in range(7)]
    data = (build_fmt(0x81, "X", "Qh", "TimeUS,V") + good[0] + good[1] + b"\x00\xff\xa3"
            + good[2] + build_record(0x90, "Q", 5) + good[3] + good[4][:7] + good[5]
            + good[6])
    path = tmp_path / "messy.bin"
    path.write_bytes(data)
    with pytest.warns(DataQualityWarning, match=r"undefined type id\(s\) \[144\]") as rec:
        log = dataflash.read(path)
    assert len(rec) == 1
    assert log["X"]["V"].tolist() == [0, 1, 2, 3, 5, 6]
    assert log.source.skipped_bytes == 3 + 11 + 7


def test_messages_without_time_hold_the_previous_time(tmp_path):
    data = (build_fmt(0x81, "T", "Q", "TimeUS") + build_fmt(0x82, "P", "Nf", "Name,Value")
            + build_record(0x82, "Nf", "A", 1.0) + build_record(0x81, "Q", 2_000_000)
            + build_record(0x82, "Nf", "B", 2.0))
    path = tmp_path / "hold.bin"
    path.write_bytes(data)
    log = dataflash.read(path)
    t = log["P"].time_s
    assert np.isnan(t[0]) and t[1] == 2.0  # data before any clock stay untimed
    # header records before the first timed record take its time (as an ARM event would)
    assert log["FMT"].time_s.tolist() == [2.0, 2.0]


# --------------------------------------------------------------------------- properties
def _decode_quietly(path: Path) -> RawLog | None:
    """Decode, letting only LogFormatError/DataQualityWarning through (None on the error)."""
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        try:
            log = dataflash.read(path)
        except LogFormatError:
            log = None
    assert all(issubclass(w.category, DataQualityWarning) for w in rec), [
        str(w.message) for w in rec]
    assert len(rec) <= 1
    return log


def _same_column(a: np.ndarray, b: np.ndarray) -> bool:
    if a.dtype.kind == "f":
        return np.array_equal(a, b, equal_nan=True)
    return a.shape == b.shape and bool(np.all(a == b))


def _assert_prefix(part: RawLog | None, full: RawLog) -> None:
    if part is None:
        return
    assert set(part.messages) <= set(full.messages)
    for name, table in part.messages.items():
        n = len(table)
        assert n <= len(full[name])
        for f in table.fields:
            assert _same_column(table[f], full[name][f][:n]), (name, f, n)


class _Small(tuple):
    """(bytes, full decode, record offsets, temp dir), with a short repr for hypothesis."""

    def __repr__(self) -> str:
        return "small_log"


@pytest.fixture(scope="module")
def small_log(tmp_path_factory):
    path = shared_path(*SMALL)
    data = path.read_bytes()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataQualityWarning)
        full = dataflash.read(path)
    from pymavlink import DFReader

    reader = DFReader.DFReader_binary(str(path))
    offsets = sorted(o for lst in reader.offsets for o in lst)
    reader.close()
    return _Small((data, full, offsets, tmp_path_factory.mktemp("cut")))


@pytest.mark.slow
def test_truncation_at_every_byte_of_the_first_and_last_kilobyte(small_log):
    data, full, _, tmp = small_log
    n = len(data)
    rng = random.Random(5)
    cuts = [*range(1, 1025), *range(n - 1024, n), *rng.sample(range(1025, n - 1024), 100)]
    path = tmp / "cut.bin"
    salvaged = 0
    for cut in cuts:
        path.write_bytes(data[:cut])
        part = _decode_quietly(path)
        _assert_prefix(part, full)
        salvaged += part is not None
    assert salvaged > len(cuts) * 0.9


@pytest.mark.slow
@settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck))
@given(data=st.data())
def test_garbage_between_records_loses_no_intact_record(small_log, data):
    raw, full, offsets, tmp = small_log
    boundaries = [o for o in offsets if 89 * 3 <= o < len(raw) - 24]  # after the first FMTs
    where = sorted(data.draw(st.lists(st.sampled_from(boundaries), min_size=1, max_size=3,
                                      unique=True)))
    junk = [data.draw(st.binary(min_size=1, max_size=120)) for _ in where]
    pieces, last = [], 0
    for w, j in zip(where, junk, strict=True):
        pieces += [raw[last:w], j]
        last = w
    pieces.append(raw[last:])
    path = tmp / "junk.bin"
    path.write_bytes(b"".join(pieces))
    log = _decode_quietly(path)
    assert log is not None
    assert set(log.messages) == set(full.messages)
    for name, table in full.messages.items():
        assert len(log[name]) == len(table), name
        for f in table.fields:
            assert _same_column(log[name][f], table[f]), (name, f)
    assert log.source.skipped_bytes == full.source.skipped_bytes + sum(map(len, junk))


def test_an_fmt_record_with_garbage_on_both_sides_is_kept(small_log):
    """Found by the test above: a header pair just before an FMT record (its own first bytes
    then look like a defined type's header) and one junk byte after it left the FMT record
    no chain; an FMT whose content checks out is never swallowed."""
    raw, full, offsets, tmp = small_log
    assert 267 in offsets and 356 in offsets
    path = tmp / "fmt_between_junk.bin"
    path.write_bytes(raw[:267] + b"\xa3\x95" + raw[267:356] + b"\x00" + raw[356:])
    log = _decode_quietly(path)
    assert log is not None
    assert {n: len(t) for n, t in log.messages.items()} == {
        n: len(t) for n, t in full.messages.items()}
    assert log.source.skipped_bytes == full.source.skipped_bytes + 3


def test_a_partial_record_inserted_as_garbage_does_not_swallow_the_next(small_log):
    raw, full, offsets, tmp = small_log
    k = offsets[len(offsets) // 2]
    nxt = offsets[len(offsets) // 2 + 1]
    partial = raw[k : k + (nxt - k) // 2]  # the first half of a real record
    path = tmp / "partial.bin"
    path.write_bytes(raw[:nxt] + partial + raw[nxt:])
    log = _decode_quietly(path)
    assert log is not None
    assert sum(map(len, log.messages.values())) == sum(map(len, full.messages.values()))


def test_shared_folder_layout():
    require_shared()
    assert (LOGS / "sitl").is_dir()


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 300), st.integers(1, 40)), min_size=1, max_size=40,
                unique_by=lambda x: x[0]))
def test_chain_follows_the_greedy_rule(nodes):
    """Reference: walk node by node, each followed by the first node at or after its end."""
    nodes.sort()
    pos = np.array([p for p, _ in nodes], np.int32)
    end = pos + np.array([n for _, n in nodes], np.int32)
    expected, i = [], 0
    while i < len(nodes):
        expected.append(i)
        i = next((k for k in range(i + 1, len(nodes)) if pos[k] >= end[i]), len(nodes))
    assert dataflash_framing.chain(pos, end).tolist() == expected


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 12), st.booleans()), min_size=1, max_size=60),
       st.integers(0, 2**32 - 1))
def test_chain_over_nodes_in_place_equals_chaining_the_nodes_copied_out(spans, seed):
    """``_chain_nodes`` (with and without the suspects it may be given) visits what the
    greedy chain of the nodes alone visits, and its runs cover exactly those candidates."""
    rng = random.Random(seed)
    pos = np.cumsum([0] + [rng.choice([1, 2, 3, 4]) for _ in spans[1:]]).astype(np.int32)
    end = pos + np.array([n for n, _ in spans], np.int32)
    node = np.array([b for _, b in spans], bool)
    expected = np.zeros(pos.size, bool)
    expected[np.flatnonzero(node)[dataflash_framing.chain(pos[node], end[node])]] = True
    fwd = np.zeros(pos.size, bool)
    fwd[:-1] = end[:-1] == pos[1:]
    skip = np.flatnonzero(~node).astype(np.int32)
    for args in ((), ((np.flatnonzero(~fwd), skip - 1), skip)):
        keep, starts, stops = dataflash_framing.chain_nodes(pos, end, node, *args)
        assert keep.tolist() == expected.tolist()
        runs = np.zeros(pos.size, bool)
        for a, b in zip(starts.tolist(), stops.tolist(), strict=True):
            runs[a:b] = True
            assert (end[a : b - 1] == pos[a + 1 : b]).all()  # a run leaves no gap
        assert runs.tolist() == expected.tolist()


def _frame_reference(a, cand, types, table):
    """The framing rules evaluated on every candidate with full-length flags (the
    implementation before the suspects-only one), as the reference it must equal."""
    n, m = a.size, cand.size
    lengths = np.array([d.length for d in table.defs] + [0], cand.dtype)
    defid = dataflash_framing.sweep(cand, types, table, lengths)[0]
    end = lengths[defid] + cand
    known = end > cand
    complete = known & (end <= n)
    fwd = np.zeros(m, bool)
    fwd[:-1] = end[:-1] == cand[1:]
    has_in = np.zeros(m + 1, bool)
    has_in[1:] = fwd
    rest = np.flatnonzero(complete & ~fwd)
    j = np.searchsorted(cand, end[rest], side="left")
    found = j < m
    found[found] = cand[j[found]] == end[rest[found]]
    fwd[rest[found]] = True
    has_in[j[found]] = True
    backed = (fwd | has_in[:m]) & known
    node = complete & backed
    weak = np.flatnonzero(complete & ~backed & (types != 0x80))
    near = dataflash_framing.near
    weak = weak[~near(weak, -16, backed,
                      lambda k, nb: end[nb] > cand[weak[k:k + nb.shape[0]], None])]
    weak = weak[~near(weak, 16, np.ones(m, bool),
                      lambda k, nb: cand[nb] < end[weak[k:k + nb.shape[0]], None])]
    node[weak] = True
    plausible = np.zeros(m, bool)
    plausible[np.searchsorted(cand, np.array(table.plausible, cand.dtype))] = True
    node |= plausible
    back = np.flatnonzero(node & ~fwd)
    node[back[near(back, 16, fwd | plausible,
                   lambda k, nb: cand[nb] < end[back[k:k + nb.shape[0]], None])]] = False
    keep = node.copy()
    keep[node] = False
    keep[np.flatnonzero(node)[dataflash_framing.chain(cand[node], end[node])]] = True
    return cand[keep], defid[keep]


@pytest.mark.slow
@pytest.mark.parametrize("mutator", ["bit_flips", "garbage", "splice", "corrupt_definitions",
                                     "repeat_definition", "header_flood", "truncate"])
def test_framing_on_suspects_equals_the_full_length_rules(mutator):
    """Mutated logs (the fuzz corpus's mutations of the shared and bundled .bin seeds):
    the records the reader accepts are those of the rules evaluated on every candidate,
    and the headers it finds are every ``A3 95`` pair of the file."""
    from fuzz import mutate

    seeds = [s for s in mutate.available_seeds() if s.endswith(".bin")]
    for seed in seeds:
        for k in range(4):
            data = mutate.mutate(seed, mutator, k)
            a = np.frombuffer(data, np.uint8)
            cand, types = dataflash_scan.find_headers(a)
            pairs = [i for i in range(len(data) - 2) if data[i:i + 2] == b"\xa3\x95"]
            assert cand.tolist() == pairs
            assert types.tolist() == [data[i + 2] for i in pairs]
            fmt = cand[types == 0x80]
            table = dataflash_formats.read_definitions(a, fmt[fmt <= a.size - 89])
            framing = dataflash_framing.frame(a, cand, types, table)
            pos, defid = _frame_reference(a, cand, types, table)
            got_pos, got_defid = framing.records()
            assert got_pos.tolist() == pos.tolist(), (seed, mutator, k)
            assert got_defid.tolist() == defid.tolist()
            assert framing.count == pos.size
            assert framing.pos.tolist() == cand.tolist()  # the others marked, in place
            assert set(framing.defid.tolist()) - set(defid.tolist()) <= {framing.none}


@pytest.mark.parametrize("parts", [SMALL, ("public", "ArduPilot__MethodicConfigurator",
                                            "backend_log_80k.bin")], ids=["pymavlink", "mc80k"])
def test_times_only_columns_equal_the_full_decode(parts):
    """The columns a times-only read decodes (gathered field by field from the file when
    they are a small part of the record) hold the full decode's values, NaN for NaN."""
    path = shared_path(*parts)
    full = _decode_quietly(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        light = read_log(path, messages=["ATT"], times_only=True)
    assert full is not None and set(light.messages) == set(full.messages)
    for name, table in light.messages.items():
        assert _same_column(table.time_s, full[name].time_s)
        for column in table.columns:
            assert _same_column(table[column], full[name][column]), (name, column)


def _compiled_or_skip() -> Any:
    if dataflash_scan._scan is None:
        pytest.skip("mavsid built without a C compiler: the numpy header scan only")
    return dataflash_scan._scan


@pytest.fixture(params=["compiled", "numpy"])
def scan(request, monkeypatch):
    """The header scan both ways: the compiled one (``_scan.c``) and the numpy one a package
    built without a C compiler uses."""
    if request.param == "compiled":
        _compiled_or_skip()
    else:
        monkeypatch.setattr(dataflash_scan, "_scan", None)
    return request.param


def test_the_compiled_header_scan_is_built():
    """Where a C compiler is (as on this project's machines and CI), ``pip install`` builds
    the scan: without it reads still work (numpy), ~1.2x slower, so a build that silently
    dropped it must not pass. (Tests run from a checkout import its sources: the README's
    ``pip install -e`` builds the extension beside them; after a plain ``pip install .``
    only the installed copy has it, and this test says so and skips.)"""
    import importlib.machinery
    import shutil
    import site
    import sysconfig

    compiler = (sysconfig.get_config_var("CC") or "cc").split()[0]
    if shutil.which(compiler) is None:
        pytest.skip(f"no C compiler ({compiler}): the numpy header scan is used")
    if dataflash_scan._scan is None:
        installed = [Path(d) / "mavsid" / "readers" / f"_scan{suffix}"
                     for d in site.getsitepackages()
                     for suffix in importlib.machinery.EXTENSION_SUFFIXES]
        if any(p.is_file() for p in installed):
            pytest.skip(f"these tests import {Path(dataflash.__file__).parent}, built without "
                        "its extension; the installed copy has it (pip install -e . builds it "
                        "here)")
    assert dataflash_scan._scan is not None, "mavsid.readers._scan was not built (see setup.py)"


def test_version_says_whether_the_readers_are_compiled(capsys: pytest.CaptureFixture[str]
                                                       ) -> None:
    """``mavsid --version`` tells a user whose reads are slower than the README's that the
    package was built without a C compiler."""
    from mavsid import cli

    assert cli.main(["--version"]) == 0
    out = capsys.readouterr().out
    assert ("(compiled readers)" in out) == (dataflash_scan._scan is not None)
    assert ("built without a C compiler" in out) == (dataflash_scan._scan is None)


@pytest.mark.parametrize("chunk", [4, 6, 64])
def test_header_search_finds_pairs_at_both_parities_across_chunks(monkeypatch, scan, chunk):
    """Every ``A3 95`` with a type byte after it is found once, at either parity, on either
    side of a chunk's (numpy) or window's (compiled: 8 chunks) end, in files of odd and even
    sizes (brute force as reference)."""
    monkeypatch.setattr(dataflash_scan, "_CHUNK", chunk)
    rng = np.random.default_rng(7)
    for size in [*range(0, 12), 63, 64, 65, 66, 127, 128, 129, 1001]:
        for _ in range(4):
            data = rng.choice(np.array([0xA3, 0x95, 0x81], np.uint8), size=size,
                              p=[0.4, 0.4, 0.2]).tobytes()
            cand, types = dataflash_scan.find_headers(np.frombuffer(data, np.uint8))
            pairs = [i for i in range(len(data) - 2) if data[i : i + 2] == b"\xa3\x95"]
            assert cand.tolist() == pairs, (chunk, size)
            assert types.tolist() == [data[i + 2] for i in pairs]


def test_a_scan_built_without_vectors_leaves_the_search_to_numpy(monkeypatch):
    """Built for a machine without SSE2 (ARM), the compiled scan would be a byte loop,
    slower than numpy's vectorised compares: the reader keeps numpy's scan there."""
    import types

    def refuse(*args: Any) -> None:
        raise AssertionError("the byte loop was used")

    monkeypatch.setattr(dataflash_scan, "_scan", types.SimpleNamespace(vectorised=0, pairs=refuse))
    data = b"\x00\xa3\x95\x81" * 10
    cand, types_ = dataflash_scan.find_headers(np.frombuffer(data, np.uint8))
    assert cand.tolist() == list(range(1, 40, 4)) and set(types_.tolist()) == {0x81}


def test_header_search_grows_past_its_estimate(scan):
    """A file denser in header patterns than a log (its result grows)."""
    data = bytes(3000) + b"\xa3\x95\x81" * 50_000 + b"\xa3\x95"
    cand, types = dataflash_scan.find_headers(np.frombuffer(data, np.uint8))
    assert cand.tolist() == list(range(3000, 3000 + 150_000, 3))
    assert set(types.tolist()) == {0x81}


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=300), st.integers(0, 300), st.integers(0, 300))
def test_compiled_pairs_equal_brute_force(data, start, room):
    """``_scan.pairs`` on any bytes, from any start, into outputs of any room: the pairs of
    the range in order, stopping at the first one without room (int32 and int64 offsets)."""
    pairs_fn = _compiled_or_skip().pairs
    last = len(data) - 2
    start = min(start, max(last, 0))
    if last < 0:
        with pytest.raises(ValueError):
            pairs_fn(data, 0, 0, np.empty(1, np.int32), np.empty(1, np.uint8))
        return
    want = [i for i in range(start, last) if data[i : i + 2] == b"\xa3\x95"]
    for dtype in (np.int32, np.int64):
        off, types = np.zeros(room, dtype), np.zeros(room + 3, np.uint8)
        count, reached = pairs_fn(data, start, last, off, types)
        assert off[:count].tolist() == want[:room]
        assert types[:count].tolist() == [data[i + 2] for i in want[:room]]
        assert reached == (want[room] if len(want) > room else last)


def test_the_compiled_scan_knows_the_header_of_the_spec():
    """``_scan.c`` keeps its own copy of the two header bytes: of every byte pair, it finds
    exactly the spec's :data:`~mavsid.readers.dataflash_spec.HEAD`."""
    pairs_fn = _compiled_or_skip().pairs
    first, second = np.divmod(np.arange(1 << 16), 1 << 8)
    data = np.column_stack([first, second, np.full(1 << 16, 0x81)]).astype(np.uint8).tobytes()
    off, types = np.zeros(1 << 16, np.int64), np.zeros((1 << 16) + 3, np.uint8)
    count, _ = pairs_fn(data, 0, len(data) - 2, off, types)
    found = {data[i : i + 2] for i in off[:count].tolist()}
    assert found == {dataflash_spec.HEAD}


def test_the_format_spec_agrees_with_pymavlink():
    """Every format character's storage (``struct`` code, and a numpy dtype of the same
    size) and multiplier as pymavlink's ``DFReader.FORMAT_TO_STRUCT`` has them; the FMT
    record's length as its format packs."""
    import struct

    from pymavlink import DFReader

    theirs = DFReader.FORMAT_TO_STRUCT
    assert set(dataflash_spec.FORMAT_CHARS) == set(theirs)
    for ch, spec in dataflash_spec.FORMAT_CHARS.items():
        code, mul, _ = theirs[ch]
        assert spec.code == code, ch
        assert np.dtype(spec.dtype).itemsize == struct.calcsize("<" + code), ch
        assert spec.multiplier == mul, ch
        assert (spec.scale is None) == (mul is None) and (mul is None or spec.scale * mul == 1)
    fmt_size = struct.calcsize("<" + "".join(theirs[c][0] for c in dataflash_spec.FMT_FORMAT))
    assert dataflash_spec.FMT_LENGTH == 3 + fmt_size


def test_the_simulators_writer_uses_the_spec(tmp_path):
    """A record of every scaled character, written by the simulator's writer in display
    units, reads back through pymavlink at those values (to the character's resolution)."""
    from pymavlink import DFReader

    from mavsid.synthetic.dfwriter import DataFlashBuilder, MessageFormat

    want = {"C1": -12.34, "C2": 12.34, "E1": -1234.56, "E2": 1234.56, "L1": -35.1234567,
            "B1": 7.0, "F1": 0.5}
    f = MessageFormat(0x90, "TSC", "QcCeELBf", ("TimeUS", *want))
    assert f.length == 3 + dataflash_spec.payload_size(f.fmt)
    b = DataFlashBuilder()
    b.define(f)
    b.add("TSC", [2_000_000], **{k: [v] for k, v in want.items()})
    data = b.to_bytes()
    assert data[:3] == dataflash_spec.HEAD + bytes((dataflash_spec.FMT_TYPE,))
    path = tmp_path / "spec.bin"
    path.write_bytes(data)
    msg = DFReader.DFReader_binary(str(path)).recv_match(type="TSC")
    assert msg is not None and msg.TimeUS == 2_000_000
    for (name, value), ch in zip(want.items(), f.fmt[1:], strict=True):
        step = dataflash_spec.FORMAT_CHARS[ch].multiplier or 1e-9
        assert getattr(msg, name) == pytest.approx(value, abs=step / 2 + 1e-12), name


def test_compiled_pairs_refuse_what_they_cannot_write():
    pairs_fn = _compiled_or_skip().pairs
    data = b"\xa3\x95\x81" * 4
    with pytest.raises(TypeError, match="int32 or int64"):
        pairs_fn(data, 0, 10, np.empty(4, np.float64), np.empty(4, np.uint8))
    with pytest.raises(TypeError, match="byte buffers"):
        pairs_fn(data, 0, 10, np.empty(4, np.int64), np.empty(4, np.uint16))
    with pytest.raises(ValueError, match="start <= stop"):
        pairs_fn(data, 0, 11, np.empty(4, np.int64), np.empty(4, np.uint8))
    with pytest.raises(ValueError, match="start <= stop"):
        pairs_fn(data, 5, 4, np.empty(4, np.int64), np.empty(4, np.uint8))
    with pytest.raises(BufferError):  # a read-only output
        pairs_fn(data, 0, 10, np.empty(4, np.int64), b"xxxx")


def test_compiled_and_numpy_header_scans_agree_on_shared_logs():
    """The compiled scan and the numpy one find the same headers in every shared .bin (the
    104-MB SITL flight among them: windows, page releases and growth on a real file)."""
    require_shared()
    _compiled_or_skip()
    paths = shared_logs(".bin")
    assert paths
    for path in paths:
        a = np.memmap(path, np.uint8, mode="r")
        got, ref = dataflash_scan.find_headers(a), dataflash_scan.find_headers_numpy(a)
        assert got[0].dtype == ref[0].dtype, path
        assert np.array_equal(got[0], ref[0]) and np.array_equal(got[1], ref[1]), path
        del a


def test_columns_from_one_block_are_independent():
    cols = dataflash_decode.alloc_columns(5, {"a": (np.dtype(np.uint8), ()),
                                        "b": (np.dtype(np.float64), ()),
                                        "s": (np.dtype(object), ()),
                                        "r": (np.dtype(np.int16), (32,))})
    cols["a"][:] = 255
    cols["b"][:] = -1.5
    cols["r"][:] = 7
    cols["s"][:] = "x"
    assert cols["a"].tolist() == [255] * 5 and cols["b"].tolist() == [-1.5] * 5
    assert cols["r"].shape == (5, 32) and (cols["r"] == 7).all()
    assert all(v.flags.c_contiguous and v.flags.aligned for v in cols.values())
    assert not np.shares_memory(cols["a"], cols["b"])


@pytest.mark.parametrize("body", [b"\xa3\x95\x81" * 100_000,
                                  (b"\xa3\x95\x81\xa3\x95" + bytes(range(3))) * 40_000,
                                  b"\xa3\x95" * 150_000], ids=["triples", "mixed", "pairs"])
def test_header_floods_stay_linear_in_memory(tmp_path, body):
    import tracemalloc

    data = build_fmt(0x81, "X", "Qh", "TimeUS,V") + body
    path = tmp_path / "flood.bin"
    path.write_bytes(data)
    tracemalloc.start()
    try:
        _decode_quietly(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 40 * len(data), peak / len(data)


# one message name redefined with other layouts: the union of the columns, in file order;
# a layout lacking a column (or holding it in another shape than its first holder) gives
# NaN or an empty string
_LAYOUTS = [("Qhf", "TimeUS,A,B"), ("QfN", "TimeUS,B,S"), ("Qa", "TimeUS,A"),
            ("QcZ", "TimeUS,A,S"), ("QIf", "TimeUS,C,B")]


def _written(ch: str, rng: random.Random) -> tuple[object, object]:
    """A raw value to pack for format character ``ch`` and the value a reader must give."""
    v: Any
    if ch == "h":
        v = rng.randrange(-30000, 30000)
        return v, v
    if ch == "I":
        v = rng.randrange(1 << 32)
        return v, v
    if ch == "f":
        v = rng.uniform(-1e3, 1e3)
        return v, float(np.float32(v))
    if ch == "c":
        v = rng.randrange(-30000, 30000)
        return v, v / 100
    if ch == "a":
        v = [rng.randrange(-1000, 1000) for _ in range(32)]
        return v, v
    v = f"s{rng.randrange(100)}"  # N, Z
    return v, v


@settings(max_examples=60, deadline=None)
@given(blocks=st.lists(st.tuples(st.integers(0, len(_LAYOUTS) - 1),
                                 st.sampled_from([0x81, 0x82]), st.integers(0, 6),
                                 st.booleans()), min_size=1, max_size=6),
       seed=st.integers(0, 2**32 - 1),
       messages=st.sampled_from([None, ["TST"], ["TST", "OTH"]]))
def test_redefined_layouts_give_every_written_value(tmp_path_factory, blocks, seed, messages):
    rng = random.Random(seed)
    data = bytearray(build_fmt(0x90, "OTH", "QH", "TimeUS,V"))
    written: list[tuple[str, int, dict[str, object]]] = []  # (layout, time us, column values)
    t_us = 1000
    for layout, mtype, count, other in blocks:
        fmt, cols = _LAYOUTS[layout]
        data += build_fmt(mtype, "TST", fmt, cols)
        for _ in range(count):
            t_us += rng.randrange(1, 100_000)
            pairs = [(t_us, t_us)] + [_written(ch, rng) for ch in fmt[1:]]
            data += build_record(mtype, fmt, *(raw for raw, _ in pairs))
            written.append((fmt, t_us, dict(zip(cols.split(","), (v for _, v in pairs),
                                                strict=True))))
            if other:
                data += build_record(0x90, "QH", t_us, 7)
    path = tmp_path_factory.mktemp("redef") / "redef.bin"
    path.write_bytes(bytes(data))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataQualityWarning)
        log = dataflash.read(path, messages=messages)
    if not written:
        assert "TST" not in log.messages
        return
    table = log["TST"]
    assert len(table) == len(written)
    assert table.time_s.tolist() == [t * 1e-6 for _, t, _ in written]
    shape_of = {"a": (32,)}
    first: dict[str, tuple[int, ...]] = {}  # column -> per-row shape in its first layout
    for fmt, _, values in written:
        for col, ch in zip(values, fmt, strict=True):
            first.setdefault(col, shape_of.get(ch, ()))
    assert set(table.columns) == set(first)
    for k, (fmt, _, values) in enumerate(written):
        chars = dict(zip(values, fmt, strict=True))
        for col, shape in first.items():
            got = table[col][k]
            if col in values and shape_of.get(chars[col], ()) == shape:
                want = values[col]
                assert (got.tolist() if isinstance(got, np.ndarray) else got) == want, (k, col)
            elif col == "S":
                assert got == "", (k, col)
            else:
                assert np.all(np.isnan(got)), (k, col)


# --------------------------------------------------------------------------- hostile files
# (each builds the file; time and memory are measured in tests/fuzz)


def test_fmt_churn_keeps_one_layout_and_says_so(tmp_path: Path) -> None:
    """A type redefined with new columns before every record: the merged table would grow
    with the square of the count; one layout is kept, the rest counted."""
    from fuzz import hostile

    path = tmp_path / "churn.bin"
    path.write_bytes(hostile.fmt_churn(60_000))
    n = len(path.read_bytes()) // (89 + 15)
    with pytest.warns(DataQualityWarning, match=r"CHN: \d+ record\(s\) under \d+ other layout"):
        log = read_log(path)
    table = log["CHN"]
    assert len(table.columns) == 2 and len(table) == 1  # the latest layout, its one record
    (name,) = [c for c in table.columns if c != "TimeUS"]
    assert table[name].tolist() == [float(name[1:])] and int(name[1:]) in (n - 1, n)


def test_fmt_churn_with_two_alternating_layouts_is_merged(tmp_path: Path) -> None:
    """Redefinitions that do not grow the union of columns keep every record."""
    data = bytearray()
    for k in range(3000):
        fmt = "Qf" if k % 2 else "Qi"
        data += build_fmt(0x81, "ALT", fmt, "TimeUS,V") + build_record(0x81, fmt, k, k)
    path = tmp_path / "alt.bin"
    path.write_bytes(bytes(data))
    log = read_log(path)
    assert log["ALT"]["V"].tolist() == [float(k) for k in range(3000)]


def test_header_flood_is_no_log(tmp_path: Path) -> None:
    from fuzz import hostile

    path = tmp_path / "flood.bin"
    path.write_bytes(hostile.header_flood(3_000_000))
    with pytest.raises(LogFormatError, match=r"flood\.bin: no DataFlash records"):
        read_log(path)


def test_header_flood_inside_a_log_is_skipped(tmp_path: Path) -> None:
    from fuzz import hostile

    good = hostile.header_and_records(500)
    path = tmp_path / "flooded.bin"
    path.write_bytes(good + hostile.header_flood(300_000) + good[89:])
    with pytest.warns(DataQualityWarning, match="skipped"):
        log = read_log(path)
    assert log["TST"]["V"].tolist() == [float(k) for k in range(500)] * 2


def test_metadata_with_another_layout_is_salvaged(tmp_path: Path) -> None:
    """PARM, MODE and VER defined with strings where numbers belong: no ValueError; the
    values that are numbers are kept."""
    from fuzz import hostile

    path = tmp_path / "meta.bin"
    path.write_bytes(hostile.metadata_redefined()
                     + build_fmt(0x85, "MULT", "QZZ", "TimeUS,Id,Mult")
                     + build_record(0x85, "QZZ", 5, "x", "y"))
    log = read_log(path)
    assert log.params == {}  # "fast" is no number
    assert log.firmware == "ArduCopter V4"
    assert [m.name for m in log.modes] == ["LOITER"]
    assert log["TST"]["V"].tolist() == [float(k) for k in range(10)]
    # numbers in text are still numbers
    data = (build_fmt(0x81, "PARM", "QNZ", "TimeUS,Name,Value")
            + build_record(0x81, "QNZ", 1, "RATE_P", "0.25"))
    path.write_bytes(data)
    assert read_log(path).params == {"RATE_P": 0.25}


def test_signalling_nan_is_read_as_nan_without_warnings(tmp_path: Path) -> None:
    """A flipped bit may make a float a signalling NaN: numpy warns on every later cast;
    the reader gives a quiet NaN as pymavlink does."""
    snan = np.frombuffer(b"\x01\x00\x80\x7f", "<f4")[0]
    data = build_fmt(0x81, "TST", "Qf", "TimeUS,V") + build_record(0x81, "Qf", 1, 1.0)
    data += bytes((0xA3, 0x95, 0x81)) + (2).to_bytes(8, "little") + snan.tobytes()
    path = tmp_path / "snan.bin"
    path.write_bytes(data)
    v = read_log(path)["TST"]["V"]
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        assert np.isnan(v.astype(np.float64)[1])


def test_the_autopilot_comes_from_the_format(tmp_path) -> None:
    # a PX4 sdlog2 .px4log is DataFlash-framed; its clock record TIME.StartTime names it
    px4 = tmp_path / "a.px4log"
    px4.write_bytes(build_fmt(0x81, "TIME", "Q", "StartTime") + build_fmt(0x82, "ATT", "f", "Roll")
                    + build_record(0x81, "Q", 1_000_000) + build_record(0x82, "f", 0.1))
    ap = tmp_path / "a.bin"
    ap.write_bytes(build_fmt(0x82, "ATT", "Qf", "TimeUS,Roll") + build_record(0x82, "Qf", 1, 0.1))
    assert dataflash.read(px4, messages=["ATT"]).autopilot == "px4"
    assert dataflash.read(ap).autopilot == "ardupilot"


def test_a_real_px4log_is_px4() -> None:
    from helpers import real_path

    log = dataflash.read(real_path("px4tools", "test", "log", "01_07_59.px4log"), messages=["ATT"])
    assert log.autopilot == "px4" and "MC_ROLLRATE_P" in log.params
