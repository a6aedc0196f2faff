"""`mavsid batch` on a real dask LocalCluster of 2 worker processes.

Checks against single `mavsid fit` runs (the library call behind both), broken logs kept as
rows, resuming without redoing work, and a simulated fleet whose one aircraft's control
effectiveness steps down (a quad's plant replaced by a hexacopter's: 180 -> 130 rad/s² per
unit on roll) being flagged, while an unchanged aircraft is not.
"""

from __future__ import annotations

import contextlib
import io
import re
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
from helpers import FIXTURES, shared_path

from mavsid import cli
from mavsid.batch import read_tables, run_batch, trends
from mavsid.pipeline import fit

pytestmark = pytest.mark.filterwarnings("ignore")


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("fleet")
    for name in ("sysid_roll.bin", "doublets.bin", "hover.bin"):
        shutil.copy(FIXTURES / name, d / name)
    shutil.copy(shared_path("public", "ArduPilot__ardupilot", "nan.log"), d / "nan.log")
    (d / "broken.bin").write_bytes((FIXTURES / "sysid_roll.bin").read_bytes()[:3000])
    (d / "notes.txt").write_text("not a log: not picked up")
    return d


@pytest.mark.slow
def test_batch_equals_single_fits_records_failures_and_resumes(fleet: Path,
                                                               tmp_path: Path) -> None:
    out = tmp_path / "res.parquet"
    seen: list[str] = []
    tables = run_batch([fleet], out, workers=2, on_done=lambda row: seen.append(row["log"]))
    logs = tables["logs"].set_index("log")
    assert len(logs) == 5 and len(seen) == 5
    assert logs.loc[str(fleet / "broken.bin"), "status"] == "failed"
    assert str(fleet / "broken.bin") in logs.loc[str(fleet / "broken.bin"), "error"]
    assert logs.loc[str(fleet / "hover.bin"), "status"] == "nothing identified"
    assert logs.loc[str(fleet / "sysid_roll.bin"), "status"] == "ok"
    # the same numbers as a single fit of each log
    axes = tables["axes"]
    for name in ("sysid_roll.bin", "doublets.bin"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            single = fit([str(fleet / name)])
        for axis, f in single.axes.items():
            row = axes[(axes["log"] == str(fleet / name)) & (axes["axis"] == axis)].iloc[0]
            assert row["verdict"] == single.verdicts[axis].level
            for p, value in f.model.params.items():
                assert row[f"p:{p}"] == pytest.approx(value, rel=1e-9, abs=1e-12)
    assert set(tables["segments"]["role"]) == {"train", "validation"}
    # a rerun does no work; a new log is the only one fitted
    seen.clear()
    again = run_batch([fleet], out, workers=2, on_done=lambda row: seen.append(row["log"]))
    assert seen == [] and len(again["logs"]) == 5
    shutil.copy(FIXTURES / "sysid_pitch.bin", fleet / "sysid_pitch.bin")
    third = run_batch([fleet], out, workers=2, on_done=lambda row: seen.append(row["log"]))
    assert seen == [str(fleet / "sysid_pitch.bin")] and len(third["logs"]) == 6
    assert read_tables(out)["logs"]["schema_version"].eq(1).all()


def _simulate(path: Path, vehicle: str, seed: int) -> None:
    with contextlib.redirect_stdout(io.StringIO()):
        assert cli.main(["simulate", "-o", str(path), "--vehicle", vehicle, "--sid-axis", "10",
                         "--t-rec", "10", "--rate-hz", "200", "--seed", str(seed)]) == 0


@pytest.mark.slow
def test_a_step_in_one_aircrafts_effectiveness_is_flagged(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    logs.mkdir()
    plan = [("A", "quad"), ("A", "quad"), ("A", "hexa"), ("A", "hexa"),
            ("B", "quad"), ("B", "quad"), ("B", "quad"), ("B", "quad")]
    lines = ["log,vehicle,date"]
    for k, (craft, vehicle) in enumerate(plan):
        path = logs / f"{craft}{k}.bin"
        _simulate(path, vehicle, seed=20 + k)
        lines.append(f"{path},{craft},2026-0{1 + k % 4}-1{k}")
    mapping = tmp_path / "fleet.csv"
    mapping.write_text("\n".join(lines) + "\n")
    out, html = tmp_path / "fleet.parquet", tmp_path / "trends.html"
    rrd = tmp_path / "trends.rrd"
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()) as printed, contextlib.redirect_stderr(err):
        code = cli.main(["batch", str(logs), "-o", str(out), "--workers", "2",
                         "--vehicles", str(mapping), "--report", str(html), "--rrd", str(rrd),
                         "--quiet"])
    assert code == 0, err.getvalue()
    found = trends(read_tables(out)["axes"])
    flagged = found[found["changed"]]
    assert set(flagged["vehicle"]) == {"A"}
    b = flagged[flagged["param"] == "B[p,u_roll]"].iloc[0]
    assert b["before"] == pytest.approx(180.0, rel=0.08) and b["after"] == pytest.approx(
        130.0, rel=0.08)
    assert "change: A roll B[p,u_roll]" in printed.getvalue()
    assert "Change points" in html.read_text()
    # the same trend in rerun: B per flight on the flight and flight_date timelines
    from rerun.chunk import RrdReader

    axes = read_tables(out)["axes"]
    want = axes[(axes["vehicle"] == "A") & (axes["axis"] == "roll")].sort_values("flight_date")
    got: dict[str, list] = {}
    for chunk in RrdReader(rrd).stream().to_chunks():
        batch = chunk.to_record_batch()
        if (chunk.entity_path == "/trends/A/roll/B_p_u_roll/value"
                and "Scalars:scalars" in batch.schema.names):
            got["flight"] = batch.column("flight").to_pylist()
            got["B"] = [x[0] for x in batch.column("Scalars:scalars").to_pylist()]
            assert "flight_date" in batch.schema.names
        if chunk.entity_path == "/changes":
            got["changes"] = batch.column("TextLog:text").to_pylist()
    assert got["flight"] == list(range(len(want)))
    np.testing.assert_allclose(got["B"], want["p:B[p,u_roll]"].to_numpy(float))
    assert any("A roll B[p,u_roll]" in str(t) for t in got["changes"])


def test_batch_refuses_bad_outputs_and_workers(fleet: Path) -> None:
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        assert cli.main(["batch", str(fleet / "nan.log"), "-o", str(fleet / "nan.log")]) == 1
        assert cli.main(["batch", str(fleet), "-o", str(fleet / "x.parquet"),
                         "--workers", "0"]) == 1
    lines = err.getvalue().splitlines()
    assert len(lines) == 2 and "must be a .parquet file" in lines[0]
    assert "--workers 0" in lines[1]


def test_a_scheduler_that_cannot_be_reached_is_one_line(fleet: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """``--scheduler`` naming an address nobody listens on printed two tracebacks after the
    wait; now one line naming the address, exit 1."""
    import socket

    from mavsid import batch

    with socket.socket() as s:  # a port just freed: nothing listens there
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    monkeypatch.setattr(batch, "SCHEDULER_TIMEOUT_S", 1)
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        assert cli.main(["batch", str(fleet), "-o", str(fleet / "x.parquet"), "-q",
                         "--scheduler", f"tcp://127.0.0.1:{port}"]) == 1
    lines = err.getvalue().splitlines()
    assert len(lines) == 1 and f"--scheduler tcp://127.0.0.1:{port}: cannot connect" in lines[0]
    assert "Traceback" not in err.getvalue() and not (fleet / "x.parquet").exists()


@pytest.mark.parametrize(("text", "said"), [
    ("log,vehicle,date\nnan.log,q1,notadate\n", "line 2: date 'notadate' is not an ISO date"),
    ("log,vehicle\nnan.log,q1\nnan.log,q2\n", "line 3: nan.log is named again (line 2)"),
    (b"\xff\xfe\x00", "not a UTF-8 CSV file"),
])
def test_a_vehicles_file_that_cannot_be_meant_is_refused(tmp_path: Path, text, said) -> None:  # type: ignore[no-untyped-def]
    """A date that is no date was stored and sorted as text; a log named twice took the last
    line; a file that is not UTF-8 was a UnicodeDecodeError traceback."""
    from mavsid.batch import _mapping
    from mavsid.errors import ConfigError

    csv = tmp_path / "v.csv"
    (csv.write_bytes if isinstance(text, bytes) else csv.write_text)(text)
    with pytest.raises(ConfigError, match=re.escape(f"{csv}: {said}")):
        _mapping(csv)


@pytest.mark.slow
def test_a_vehicles_file_naming_logs_not_in_the_batch_warns(tmp_path: Path) -> None:
    """Names that match no log (a typo, another folder) were dropped silently: the run goes
    on, and a warning lists them."""
    from mavsid.errors import MavsidWarning

    logs = tmp_path / "logs"
    logs.mkdir()
    shutil.copy(FIXTURES / "sysid_roll.bin", logs / "a.bin")
    csv = tmp_path / "v.csv"
    csv.write_text("log,vehicle\na.bin,q1\nb.bin,q2\n")
    with pytest.warns(MavsidWarning, match=r"1 log\(s\) named that are not in this batch: b.bin"):
        tables = run_batch([logs], tmp_path / "out.parquet", vehicles=csv, workers=1)
    assert tables["logs"]["vehicle"].tolist() == ["q1"]


def test_entries_named_like_logs_that_are_no_files_are_said(tmp_path: Path) -> None:
    """A broken link or a FIFO named *.bin in a folder was dropped silently."""
    import os

    from mavsid.batch import find_logs
    from mavsid.errors import MavsidWarning

    shutil.copy(FIXTURES / "sysid_roll.bin", tmp_path / "a.bin")
    os.symlink(tmp_path / "gone.bin", tmp_path / "broken.bin")
    os.mkfifo(tmp_path / "pipe.tlog")
    with pytest.warns(MavsidWarning, match=r"2 entries named like logs skipped: .*broken\.bin "
                                           r"\(a broken link\), .*pipe\.tlog \(not a file\)"):
        assert find_logs([tmp_path]) == [str(tmp_path / "a.bin")]


def test_the_summary_names_each_failed_log_and_a_rerun_says_nothing_new(tmp_path: Path) -> None:
    """What a fleet operator reads: each log that failed or gave nothing, with its one-line
    reason; "nothing new" on a rerun with nothing to do; the verdict column called so
    (tables written when it was ``level`` still read); a trends page with a title, logs
    named relative to it and no ``NaN`` where a log has no error."""
    import pandas as pd

    logs = tmp_path / "flights"
    logs.mkdir()
    shutil.copy(FIXTURES / "sysid_roll.bin", logs / "sysid_roll.bin")
    shutil.copy(FIXTURES / "hover.bin", logs / "hover.bin")
    (logs / "broken.bin").write_bytes((FIXTURES / "sysid_roll.bin").read_bytes()[:3000])
    out, page = tmp_path / "out" / "res.parquet", tmp_path / "out" / "trends.html"
    out.parent.mkdir()

    def batch() -> list[str]:
        printed, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(printed), contextlib.redirect_stderr(err):
            code = cli.main(["batch", str(logs), "-o", str(out), "--workers", "2",
                             "--report", str(page), "-q"])
        assert code == 0, err.getvalue()
        return printed.getvalue().splitlines()

    first = batch()
    assert first[0] == f"3 log(s): 1 failed, 1 nothing identified, 1 ok; wrote {out}"
    failed = [x for x in first if x.startswith("  failed: ")]
    assert len(failed) == 1 and failed[0].startswith(f"  failed: {logs / 'broken.bin'}: ")
    assert len(failed[0]) > len(f"  failed: {logs / 'broken.bin'}: ") + 5  # (a reason)
    (nothing,) = [x for x in first if x.startswith("  nothing identified: ")]
    assert f"{logs / 'hover.bin'}: nothing identifiable (roll: " in nothing
    assert not any("sysid_roll.bin" in x for x in first[1:] if x.startswith("  "))
    again = batch()
    assert again[0].startswith(f"nothing new: all 3 log(s) are in {out} with these settings")
    axes = pd.read_parquet(out)
    assert "verdict" in axes and "level" not in axes
    assert set(axes["verdict"]) <= {"good", "usable", "not identified"}
    axes.rename(columns={"verdict": "level"}).to_parquet(out)  # (a table of before)
    assert list(read_tables(out)["axes"]["verdict"]) == list(axes["verdict"])
    html = page.read_text()
    assert "<h1>mavsid batch: 3 log(s)" in html
    assert "NaN" not in html and str(tmp_path) not in html
    assert "../flights/broken.bin" in html
