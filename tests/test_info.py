"""``mavsid info`` and ``mavsid extract``: golden text, JSON checked against pymavlink, exports.

The golden file is rewritten only with ``MAVSID_UPDATE_GOLDEN=1`` (the test then skips, so an
update is always a deliberate, reviewed change).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import warnings
from collections import Counter
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from helpers import assert_info_matches_golden, shared_path
from test_dataflash import pymavlink_records, same_value

from mavsid.cli import main
from mavsid.data import MessageTable, RawLog, SourceInfo
from mavsid.errors import DataQualityWarning
from mavsid.info import format_summary, median_rate_hz, summarize
from mavsid.readers import read_log

SMALL = ("public", "ArduPilot__pymavlink", "test.BIN")
MODERN = ("public", "ArduPilot__MethodicConfigurator", "backend_log_80k.bin")


def _read(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataQualityWarning)
        return read_log(path)


@pytest.fixture(scope="module")
def small_ref():
    path = shared_path(*SMALL)
    return path, pymavlink_records(path)


# --------------------------------------------------------------------------- info
@pytest.mark.parametrize("parts", [SMALL, MODERN], ids=["test.BIN", "backend_log_80k.bin"])
def test_info_text_matches_golden(parts):
    path = shared_path(*parts)
    assert_info_matches_golden(_read(path), path)


def test_info_json_agrees_with_pymavlink(small_ref, capsys):
    path, ref = small_ref
    assert main(["info", str(path), "--json"]) == 0
    out, err = capsys.readouterr()
    s = json.loads(out)
    assert {k: v["count"] for k, v in s["messages"].items()} == {k: len(v)
                                                                  for k, v in ref.items()}
    for name, recs in ref.items():
        assert list(s["messages"][name]["fields"]) == [f for f in recs[0]
                                                        if f != "mavpackettype"]
    assert s["param_count"] == len({r["Name"] for r in ref["PARM"]})
    assert s["text_count"] == len(ref["MSG"])
    assert s["firmware"] == ref["MSG"][0]["Message"] and s["vehicle"] == "plane"
    assert [m["mode"] for m in s["modes"]] == [r["ModeNum"] for r in ref["MODE"]]
    assert s["format"] == "dataflash" and s["skipped_bytes"] == 24
    times = [r["TimeUS"] * 1e-6 for recs in ref.values() for r in recs if "TimeUS" in r]
    assert s["start_s"] == pytest.approx(min(times)) and s["end_s"] == pytest.approx(max(times))
    # the ATT rate: the median interval of pymavlink's own TimeUS stamps
    t = np.array([r["TimeUS"] for r in ref["ATT"]]) * 1e-6
    assert s["messages"]["ATT"]["rate_hz"] == pytest.approx(1 / np.median(np.diff(t)), rel=1e-5)
    assert err.startswith("warning: ") and err.count("\n") == 1


@pytest.mark.slow
def test_info_lists_the_sysid_runs_pymavlink_sees():
    from pymavlink import mavutil

    path = shared_path("sitl", "flightA_mixer.BIN")
    conn = mavutil.mavlink_connection(str(path))
    sids = []
    while (m := conn.recv_match(type="SIDS")) is not None:
        sids.append(m.to_dict())
    conn.close()
    runs = summarize(_read(path))["sysid_runs"]
    assert [r["axis"] for r in runs] == [s["Ax"] for s in sids] == [10, 11, 12, 13]
    starts = [s["TimeUS"] * 1e-6 for s in sids]
    for k, (run, ref) in enumerate(zip(runs, sids, strict=True)):
        # the injection starts after its run's SIDS record, and ends before the next one's
        assert starts[k] <= run["start_s"] < run["stop_s"] < [*starts, np.inf][k + 1]
        assert run["settings_from"] == "SIDS"
        assert run["f_stop_hz"] == pytest.approx(ref["FSp"])
        assert run["magnitude"] == pytest.approx(ref["Mag"])


def test_median_rate_counts_instances_separately():
    t = np.arange(0.0, 2.0, 0.0025)  # 400 Hz
    two = MessageTable("IMU", {"I": np.tile([0, 1], t.size)}, np.repeat(t, 2), {"I": "instance"})
    assert median_rate_hz(two) == pytest.approx(400.0)
    jitter = MessageTable("ATT", {}, np.cumsum(np.r_[0.1, np.full(9, 0.1), 5.0]))
    assert median_rate_hz(jitter) == pytest.approx(10.0)
    assert np.isnan(median_rate_hz(MessageTable("X", {}, np.array([1.0]))))


def test_summary_of_an_empty_log_is_json_safe():
    log = RawLog(SourceInfo("e.bin", "dataflash", 0), messages={})
    s = summarize(log)
    assert json.loads(json.dumps(s))["duration_s"] == 0.0 and s["messages"] == {}
    assert "0 types" in format_summary(s)


# --------------------------------------------------------------------------- extract
def test_extract_npz_holds_pymavlink_values(small_ref, tmp_path, capsys):
    path, ref = small_ref
    out = tmp_path / "x.npz"
    assert main(["extract", str(path), "--messages", "ATT,PARM,IMU", "-o", str(out)]) == 0
    data = np.load(out)  # no pickle needed
    assert sorted({k.split(".")[0] for k in data.files}) == ["ATT", "IMU", "PARM"]
    for name in ("ATT", "PARM", "IMU"):
        recs = ref[name]
        fields = [f for f in recs[0] if f != "mavpackettype"]
        assert [k.split(".", 1)[1] for k in data.files if k.startswith(name + ".")] == [
            *fields, "time_s"]
        for f in fields:
            col = data[f"{name}.{f}"].tolist()
            assert all(same_value(c, r[f]) for c, r in zip(col, recs, strict=True)), (name, f)
        np.testing.assert_allclose(data[f"{name}.time_s"],
                                   [r["TimeUS"] * 1e-6 for r in recs], rtol=0, atol=1e-9)


@pytest.mark.parametrize("suffix", [".parquet", ".csv"])
def test_extract_one_type_to_a_table(small_ref, tmp_path, suffix):
    path, ref = small_ref
    out = tmp_path / f"rcou{suffix}"
    assert main(["extract", str(path), "--messages", "RCOU", "--start", "82.5",
                 "-o", str(out)]) == 0
    frame = pd.read_parquet(out) if suffix == ".parquet" else pd.read_csv(out)
    recs = [r for r in ref["RCOU"] if r["TimeUS"] * 1e-6 >= 82.5]
    assert 0 < len(frame) == len(recs) < len(ref["RCOU"])
    assert list(frame.columns) == ["time_s"] + [f for f in recs[0] if f != "mavpackettype"]
    for f in frame.columns[1:]:
        assert frame[f].tolist() == [r[f] for r in recs]


def test_extract_errors_are_one_line_and_exit_1(small_ref, tmp_path, capsys):
    path, _ = small_ref
    cases = [
        ["extract", str(path), "-o", str(tmp_path / "all.csv")],  # many types to csv
        ["extract", str(path), "--messages", "NOPE", "-o", str(tmp_path / "n.npz")],
        ["extract", str(path), "-o", str(tmp_path / "x.txt")],
        ["extract", str(path), "--messages", "ATT", "-o", str(tmp_path / "no" / "x.npz")],
        ["info", str(tmp_path / "missing.bin")],
    ]
    for argv in cases:
        assert main(argv) == 1, argv
        err = capsys.readouterr().err
        lines = [ln for ln in err.splitlines() if not ln.startswith("warning: ")]
        assert len(lines) == 1 and lines[0].startswith("mavsid: error: "), (argv, err)
        # the file the user named, never the temporary one an output is written through
        assert ".tmp." not in lines[0], lines[0]
        assert any(Path(a).name in lines[0] for a in argv if "/" in a), lines[0]


def test_extract_flags_that_are_not_values_are_named(small_ref, tmp_path, capsys):
    """``--start nan`` kept every sample, silently; ``--messages ,,,`` said "log has no
    message '(any)'": each is now one line naming the flag, exit 1, nothing written."""
    path, _ = small_ref
    out = tmp_path / "x.npz"
    for flags, said in ((["--start", "nan"], "--start nan: not a time"),
                        (["--stop", "inf"], "--stop inf: not a time"),
                        (["--messages", ",,,"], "--messages ',,,' names no message type"),
                        (["--start", "10", "--stop", "5"], "--start 10 s is after --stop 5 s")):
        assert main(["extract", str(path), *flags, "-o", str(out)]) == 1
        lines = capsys.readouterr().err.splitlines()
        assert lines == [f"mavsid: error: {said}" + lines[0].split(said, 1)[1]], lines
        assert not out.exists()


def test_bad_input_via_the_console(tmp_path):
    bad = tmp_path / "garbage.bin"
    bad.write_bytes(b"\xa3\x95\x80" + bytes(200))
    proc = subprocess.run([sys.executable, "-m", "mavsid.cli", "info", str(bad)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1 and proc.stdout == ""
    assert proc.stderr.count("\n") == 1 and "garbage.bin" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_info_counts_of_every_small_log_agree_with_pymavlink(small_ref):
    path, ref = small_ref
    s = summarize(_read(path))
    assert Counter({k: v["count"] for k, v in s["messages"].items()}) == Counter(
        {k: len(v) for k, v in ref.items()})


def _every_bin() -> list:  # type: ignore[type-arg]
    from helpers import FIXTURES, shared_logs

    # (the 104 MB SITL flight too would leave its arrays' pages in this test process, and
    # the fuzz limits measure forked children's memory: bench_hostile.py covers big logs)
    return [p for p in (*sorted(FIXTURES.glob("*.bin")), *shared_logs(".bin"))
            if p.stat().st_size < 20_000_000]


@pytest.mark.parametrize("path", _every_bin(), ids=lambda p: p.name)
def test_info_reading_times_only_gives_the_same_summary(path) -> None:  # type: ignore[no-untyped-def]
    """`mavsid info` decodes a .bin's other message types for their times only: its summary
    (counts, rates per instance, fields and units, span, modes, channels) is the full read's."""
    from mavsid.info import read_for_summary

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        full = summarize(read_log(path))
        fast_log = read_for_summary(path)
        fast = summarize(fast_log)
    assert fast == full
    skeletons = [t for t in fast_log.messages.values() if t.declared]
    assert all(len(t.columns) <= len(t.declared) for t in skeletons)
    assert not fast_log.messages or any(len(t.columns) < len(t.declared) for t in skeletons)


def test_a_log_given_as_a_pipe_is_refused_at_once(tmp_path):
    """A FIFO nobody writes to made `mavsid fit` wait for ever; a pipe with the log in it
    (`mavsid info <(cat log.bin)`, /dev/stdin) was sniffed, then read from where sniffing
    stopped: "not a DataFlash .bin/.log, MAVLink .tlog or ULog .ulg file". Now one line saying
    what it is, at once."""
    fifo = tmp_path / "pipe.bin"
    os.mkfifo(fifo)
    proc = subprocess.run([sys.executable, "-m", "mavsid.cli", "fit", str(fifo), "-q"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1
    assert proc.stderr == (f"mavsid: error: {fifo}: a pipe or a device, not a file: save the "
                           "log to a file first\n")
    from helpers import FIXTURES

    piped = subprocess.run([sys.executable, "-m", "mavsid.cli", "info", "/dev/stdin"],
                           input=(FIXTURES / "sysid_roll.bin").read_bytes(),
                           capture_output=True, timeout=120)
    assert piped.returncode == 1 and b"/dev/stdin: a pipe or a device" in piped.stderr


def _with_instances(path: Path) -> Path:
    """A small DataFlash log with messages whose declared instance (unit ``#``) is no
    one-byte integer, as ArduCopter 4.5-4.7 writes them: AUXF.function (uint16), SCR.Name
    (text, two scripts each logged at 1 Hz) and a RASI whose instance is a uint32 field."""
    from mavsid.synthetic.dfwriter import MULTS, UNITS, DataFlashBuilder, MessageFormat

    b = DataFlashBuilder()
    for name in ("FMT", "FMTU", "UNIT", "MULT"):
        b.define(b.formats[name])
    b.add("UNIT", np.full(len(UNITS), -1), Id=[ord(k) for k in UNITS],
          Label=list(UNITS.values()), TimeUS=0)
    b.add("MULT", np.full(len(MULTS), -1), Id=[ord(k) for k in MULTS], Mult=list(MULTS.values()),
          TimeUS=0)
    extra = (MessageFormat(210, "AUXF", "QHBBB", ("TimeUS", "function", "pos", "source", "result"),
                           "s#---", "F----"),
             MessageFormat(211, "SCR", "QNIii", ("TimeUS", "Name", "Runtime", "Total", "Run"),
                           "s#---", "F----"),
             MessageFormat(212, "RASI", "QBfBI", ("TimeUS", "I", "H", "Use", "UpdateMS"),
                           "s---#", "F----"))
    for f in (b.formats["ATT"], *extra):
        b.define(f)
        b.add("FMTU", [-1], TimeUS=0, FmtType=f.type_id, UnitIds=f.units, MultIds=f.mults)
    t = np.arange(0, 10_000_000, 100_000)  # 10 s at 10 Hz
    b.add("ATT", t, Roll=np.zeros(t.size), Pitch=np.zeros(t.size), Yaw=np.zeros(t.size))
    b.add("AUXF", [2_000_000, 6_000_000], function=[153, 153], pos=[2, 0])
    s = np.arange(0, 10_000_000, 1_000_000)
    b.add("SCR", np.r_[s, s + 500_000], Name=["a.lua"] * s.size + ["b.lua"] * s.size,
          Runtime=np.ones(2 * s.size))
    b.add("RASI", s, I=np.zeros(s.size), UpdateMS=np.arange(s.size) * 1000)
    path.write_bytes(b.to_bytes())
    return path


def test_info_summarises_messages_whose_instance_is_no_byte(tmp_path, capsys):
    """``mavsid info`` shows what a message has (never stops on a field the summary reads
    but the read left out) and counts rates per instance: two scripts at 1 Hz each."""
    from mavsid.info import read_for_summary

    path = _with_instances(tmp_path / "auxf.bin")
    assert main(["info", str(path)]) == 0
    text = capsys.readouterr().out
    assert {"AUXF", "SCR", "RASI"} <= {line.split()[0] for line in text.splitlines()[8:]}
    assert main(["info", str(path), "--json"]) == 0
    messages = json.loads(capsys.readouterr().out)["messages"]
    assert messages["SCR"]["count"] == 20 and messages["SCR"]["rate_hz"] == 1.0
    assert messages["AUXF"]["count"] == 2
    assert "function" in messages["AUXF"]["fields"]
    # the same summary as from the whole log, read as pymavlink would see every field
    whole = summarize(read_log(str(path)))["messages"]
    fast = summarize(read_for_summary(str(path)))["messages"]
    assert {n: (m["count"], m["rate_hz"]) for n, m in whole.items()} == \
        {n: (m["count"], m["rate_hz"]) for n, m in fast.items()}


def test_summary_of_a_message_lacking_a_declared_field() -> None:
    """A table that declares a field it does not hold (a times-only read) is summarised
    with what it holds."""
    t = np.arange(0.0, 2.0, 0.01)
    tab = MessageTable("RASI", {"H": t, "I": np.zeros(t.size, np.uint8), "Use": t}, t,
                       {"UpdateMS": "instance"}, declared=("TimeUS", "I", "H", "Use", "UpdateMS"))
    sids = MessageTable("SIDS", {"Ax": np.array([1])}, np.array([1.0]),
                        declared=("TimeUS", "Ax", "Mag"))
    sidd = MessageTable("SIDD", {"Targ": np.array([0.0, 0.5, -0.5])}, np.array([1.1, 1.5, 2.0]))
    s = summarize(RawLog(SourceInfo("r.bin", "dataflash", 0),
                         {"RASI": tab, "SIDS": sids, "SIDD": sidd}))
    assert s["messages"]["RASI"]["rate_hz"] == 100.0
    assert s["sysid_runs"] == [{"start_s": 1.5, "stop_s": 2.0, "settings_from": "SIDS",
                                "axis": 1}]
    format_summary(s)
