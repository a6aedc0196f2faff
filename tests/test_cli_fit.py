"""``mavsid fit``, ``validate`` and ``view`` from the command line."""

from __future__ import annotations

import contextlib
import io
import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from helpers import FIXTURES
from rerun.chunk import RrdReader

from mavsid import cli


@dataclass
class Result:
    returncode: int
    stdout: str
    stderr: str


def run(*argv: str) -> Result:
    """The command line, in this process (imports are paid once)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main(list(argv))
    return Result(code, out.getvalue(), err.getvalue())


def test_installed_command_runs_in_a_fresh_process() -> None:
    proc = subprocess.run([sys.executable, "-m", "mavsid.cli", "fit", "/nonexistent/f.bin"],
                          capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 1
    assert proc.stderr.strip() == "mavsid: error: /nonexistent/f.bin: cannot open: " \
        "No such file or directory"


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):  # type: ignore[no-untyped-def]
    out = tmp_path_factory.mktemp("cli")
    proc = run("fit", str(FIXTURES / "sysid_roll.bin"), "--json", "-o", str(out / "model.json"),
               "--rrd", str(out / "fit.rrd"), "--report", str(out / "fit.html"))
    assert proc.returncode == 0, proc.stderr
    return out, json.loads(proc.stdout)


@pytest.mark.slow
def test_fit_json_shape(fitted) -> None:  # type: ignore[no-untyped-def]
    _, doc = fitted
    assert list(doc["axes"]) == ["roll"]
    roll = doc["axes"]["roll"]
    assert set(roll["fit_percent"]) == {"one_step", "0.5s", "free_run"}
    assert all(isinstance(v, float) for v in roll["fit_percent"].values())
    assert set(roll["params"]) == set(roll["stderr"]) and roll["params"]
    for key in ("train_segments", "validation_segments"):
        assert roll[key] and all(len(span) == 2 and span[0] < span[1] for span in roll[key])
    train = roll["train_segments"]
    val = roll["validation_segments"]
    assert all(b[1] < v[0] or v[1] < b[0] for b in train for v in val)


def test_fit_writes_model_rrd_and_report(fitted) -> None:  # type: ignore[no-untyped-def]
    out, _ = fitted
    models = json.loads((out / "model.json").read_text())
    assert list(models["axes"]) == ["roll"]
    html = (out / "fit.html").read_text()
    assert html.startswith("<!DOCTYPE html>") and "data:image/svg+xml;base64," in html
    entities = {c.entity_path for c in RrdReader(out / "fit.rrd").stream().to_chunks()}
    assert {"/axes/roll/p/measured", "/axes/roll/p/free_run", "/segments/roll"} <= entities


def test_fit_text_table() -> None:
    proc = run("fit", str(FIXTURES / "sysid_roll.bin"))
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    # where each channel came from, in which SI unit, then the axis
    assert "p [rad/s] <- RATE.R" in lines[1] and "u_roll [1] <- RATE.ROut" in lines[1]
    assert lines[2].startswith("roll (p; ls;")
    assert any(line.strip().startswith("B[p,u_roll]") and "±" in line for line in lines)
    assert any(line.strip().startswith("fit %  one-step") and "free-run" in line
               for line in lines)


@pytest.mark.slow
def test_model_from_one_flight_predicts_the_next(fitted, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    out, doc = fitted
    # a second flight of the same simulated vehicle, different seed: every segment held out
    nxt = tmp_path / "next.bin"
    sim = run("simulate", "-o", str(nxt), "--manoeuvre", "sysid", "--axis", "roll",
              "--sid-axis", "10", "--seed", "11", "--t-rec", "20", "--rate-hz", "200")
    assert sim.returncode == 0, sim.stderr
    proc = run("validate", str(out / "model.json"), str(nxt), "--json")
    assert proc.returncode == 0, proc.stderr
    val = json.loads(proc.stdout)["axes"]["roll"]
    assert val["train_segments"] == [] and val["validation_segments"]
    assert val["params"] == doc["axes"]["roll"]["params"]
    # the next flight is predicted about as well as the held-out part of the first
    assert val["fit_percent"]["free_run"] > doc["axes"]["roll"]["fit_percent"]["free_run"] - 10
    assert val["fit_percent"]["one_step"] > 90


def test_a_systemid_stay_that_injected_nothing_is_refused_in_one_line(tmp_path: Path) -> None:
    from helpers import write_systemid_without_injection

    path = write_systemid_without_injection(tmp_path / "quiet.bin")
    proc = run("fit", str(path), "-q")
    assert proc.returncode == 1
    errors = [line for line in proc.stderr.splitlines() if line.startswith("mavsid: error:")]
    assert errors == [f"mavsid: error: {path}: roll: SYSTEMID mode (SID_AXIS 1) 38.0–47.6 s "
                      "injected nothing (SIDD.Targ is 0 throughout, SIDS not logged)"], proc.stderr


def test_segments_say_in_one_line_that_a_systemid_stay_injected_nothing(tmp_path: Path
                                                                        ) -> None:
    from helpers import write_systemid_without_injection

    path = write_systemid_without_injection(tmp_path / "quiet.bin")
    proc = run("segments", str(path), "--axis", "roll")
    assert proc.returncode == 0, proc.stderr
    rows = [line for line in proc.stdout.splitlines() if "sysid" in line]
    assert len(rows) == 1 and rows[0].endswith(
        "rejected: SYSTEMID mode (SID_AXIS 1) 38.0–47.6 s injected nothing (SIDD.Targ is 0 "
        "throughout, SIDS not logged)"), proc.stdout
    doc = json.loads(run("segments", str(path), "--axis", "roll", "--json").stdout)
    sysid = [w for w in doc if w["source"] == "sysid"]
    assert [w["reason_kinds"] for w in sysid] == [["injected_nothing"]]


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["fit", "/nonexistent/flight.bin"], "flight.bin"),
        (["fit", "EMPTY"], "empty file"),
        (["fit", "TEXT"], "not a DataFlash"),
        (["fit", str(FIXTURES / "hover.bin")], "nothing identifiable"),
        (["fit", str(FIXTURES / "sysid_roll.bin"), "--config", "BADTOML"], "not valid TOML"),
        (["fit", str(FIXTURES / "sysid_roll.bin"), "--preset", "nope"],
         "unknown channel preset 'nope'"),
        (["fit", str(FIXTURES / "sysid_roll.bin"), "--preset", "px4-torque"],
         "vehicle_attitude"),
        (["validate", "TEXT", str(FIXTURES / "sysid_roll.bin")], "not a mavsid model"),
        (["view", "EMPTY", "--save", "x.rrd"], "empty file"),
    ],
)
def test_bad_input_one_line_exit_1(argv: list[str], needle: str, tmp_path: Path) -> None:
    (tmp_path / "empty.bin").write_bytes(b"")
    (tmp_path / "text.bin").write_text("hello, this is not a log\n")
    (tmp_path / "bad.toml").write_text("[pipeline\n")
    subst = {"EMPTY": str(tmp_path / "empty.bin"), "TEXT": str(tmp_path / "text.bin"),
             "BADTOML": str(tmp_path / "bad.toml"), "x.rrd": str(tmp_path / "x.rrd")}
    proc = run(*[subst.get(a, a) for a in argv])
    assert proc.returncode == 1
    err = proc.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("mavsid: error:") and needle in err[0], err
    assert "Traceback" not in proc.stderr


def test_view_saves_flight_and_windows(tmp_path: Path) -> None:
    out = tmp_path / "view.rrd"
    proc = run("view", str(FIXTURES / "sysid_roll.bin"), "--save", str(out))
    assert proc.returncode == 0, proc.stderr
    entities = {c.entity_path for c in RrdReader(out).stream().to_chunks()}
    want = {"/flight/rates/p", "/flight/inputs/u_roll", "/flight/attitude/roll",
            "/world/data", "/segments/roll"}
    assert want <= entities


def test_view_with_model(fitted, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    out_dir, _ = fitted
    out = tmp_path / "view.rrd"
    proc = run("view", str(FIXTURES / "sysid_roll.bin"), "--model", str(out_dir / "model.json"),
               "--save", str(out))
    assert proc.returncode == 0, proc.stderr
    entities = {c.entity_path for c in RrdReader(out).stream().to_chunks()}
    assert {"/axes/roll/p/one_step", "/axes/roll/p/free_run"} <= entities


def _blueprint_ranges(rrd: Path) -> tuple[list[tuple[float, float]], list[tuple[float, float]],
                                          int]:
    """In a saved .rrd (times in s; the timeline counts ms): the spans the time axes show
    (a linked plot shows the shared axis's), the time panel's selection, and how many
    time axes are linked to the shared one."""
    from mavsid.viz.series import SHARED_VIEW, TICKS_PER_S

    reader = RrdReader(rrd)
    shown, selected, linked = [], [], 0
    for chunk in reader.stream(store=reader.blueprints()[0]).to_chunks():
        batch = chunk.to_record_batch()
        if "TimeAxis:view_range" in batch.schema.names:
            assert chunk.entity_path == f"/{SHARED_VIEW}/TimeAxis"
            shown += [(r[0]["start"] / TICKS_PER_S, r[0]["end"] / TICKS_PER_S)
                      for r in batch.column("TimeAxis:view_range").to_pylist() if r]
        if "TimeAxis:link" in batch.schema.names:
            linked += sum(r == [2] for r in batch.column("TimeAxis:link").to_pylist())
        if "TimePanelBlueprint:time_selection" in batch.schema.names:
            selected += [(r[0]["min"] / TICKS_PER_S, r[0]["max"] / TICKS_PER_S) for r in
                         batch.column("TimePanelBlueprint:time_selection").to_pylist() if r]
    return shown, selected, linked


def _y_ranges(rrd: Path) -> dict[str, tuple[float, float]]:
    """In a saved .rrd: the fixed y range of each time plot by its origin (not the bands)."""
    reader = RrdReader(rrd)
    origin, shown = {}, {}
    for chunk in reader.stream(store=reader.blueprints()[0]).to_chunks():
        batch = chunk.to_record_batch()
        if "ViewBlueprint:space_origin" in batch.schema.names:
            origin[chunk.entity_path] = batch.column("ViewBlueprint:space_origin").to_pylist()[0][0]
        if "ScalarAxis:range" in batch.schema.names:
            shown[chunk.entity_path.removesuffix("/ScalarAxis")] = tuple(
                batch.column("ScalarAxis:range").to_pylist()[0][0])
    return {origin[v]: r for v, r in shown.items() if origin[v] != "bands"}


def test_view_with_a_model_fixes_the_y_ranges_fit_does(fitted, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """``view --model`` sets the plots' y ranges as ``fit --rrd`` does (without, rerun fits a
    ± 0.07 input to a plot ticked at 0 only), each holding every value logged under it; the
    flight alone gets the flight's."""
    out_dir, _ = fitted
    log = str(FIXTURES / "sysid_roll.bin")
    out, bare = tmp_path / "view.rrd", tmp_path / "bare.rrd"
    assert run("view", log, "--model", str(out_dir / "model.json"), "--save",
               str(out)).returncode == 0
    assert run("view", log, "--save", str(bare)).returncode == 0
    got, fit = _y_ranges(out), _y_ranges(out_dir / "fit.rrd")
    assert {"flight/rates", "flight/inputs", "flight/thrust", "axes/roll/inputs"} <= set(got)
    assert {k: v for k, v in got.items() if k.startswith("flight/")} == {
        k: v for k, v in fit.items() if k.startswith("flight/")}
    assert set(fit) <= set(got)
    assert _y_ranges(bare) == {k: v for k, v in got.items() if k.startswith("flight/")}
    values: dict[str, list[float]] = {}
    for chunk in RrdReader(out).stream().to_chunks():
        batch = chunk.to_record_batch()
        if "Scalars:scalars" in batch.schema.names:
            values[chunk.entity_path] = [x[0] for x in batch.column("Scalars:scalars").to_pylist()
                                         if x and x[0] is not None]
    for origin, (lo, hi) in got.items():
        shown = [x for k, xs in values.items() if k.startswith(f"/{origin}/") for x in xs]
        assert shown, origin
        finite = np.array(shown)[np.isfinite(shown)]
        assert lo <= finite.min() and finite.max() <= hi, origin


def test_view_with_a_model_opens_on_the_first_validation_segment(fitted, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """Every time plot shows the first segment the model is validated on (as ``fit --rrd``
    does for its first validation segment), not the minute of the flight before it."""
    out_dir, _ = fitted
    model = str(out_dir / "model.json")
    log = str(FIXTURES / "sysid_roll.bin")
    held_out = json.loads(run("validate", model, log, "--json").stdout)["axes"]["roll"][
        "validation_segments"]
    first = tuple(min(held_out))
    assert first[0] > 20  # (the flight before it is long: opening on it shows no segment)
    out = tmp_path / "view.rrd"
    assert run("view", log, "--model", model, "--save", str(out)).returncode == 0
    shown, selected, linked = _blueprint_ranges(out)
    assert linked >= 3 and shown == [pytest.approx(first, abs=5e-4)]
    assert selected == [pytest.approx(first, abs=5e-4)]
    fit_shown, _, _ = _blueprint_ranges(out_dir / "fit.rrd")
    fit_first = tuple(min(json.loads(run("fit", log, "--json", "-q").stdout)["axes"]["roll"][
        "validation_segments"]))
    assert fit_shown == [pytest.approx(fit_first, abs=5e-4)]


def test_view_flags_are_mavsids_own(capsys) -> None:  # type: ignore[no-untyped-def]
    args = cli.build_parser().parse_args(["view", "x.bin", "--serve"])
    assert args.serve and args.bind == "127.0.0.1"
    for flag in ("headless", "connect", "save", "stdout", "url", "spawn"):
        assert hasattr(args, flag)
    with pytest.raises(SystemExit):
        cli.main(["view", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "0.0.0.0 offers the flight to the network" in text and "Rerun" not in text


@pytest.mark.parametrize(("flags", "said"), [
    (["--connect", "--url", "bogus://x"], "--url bogus://x: not a rerun viewer address"),
    (["--serve", "--bind", "999.1.1.1"], "--bind 999.1.1.1: cannot listen there"),
    ([], "no display for the rerun viewer"),  # (the viewer died after it began listening:
])                                           # a traceback, or "exited before listening")
def test_a_viewer_address_that_cannot_be_used_is_one_line(flags: list[str], said: str,
                                                          monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """A --url rerun does not take, or a --bind that is no address of this machine, were
    tracebacks from rerun or the socket layer after the log was read; so was a native
    viewer started with no display to open."""
    if not flags:
        monkeypatch.delenv("DISPLAY", raising=False)
        monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
        monkeypatch.setattr(sys, "platform", "linux")
    got = run("view", str(FIXTURES / "sysid_roll.bin"), *flags)
    assert got.returncode == 1 and got.stderr.startswith(f"mavsid: error: {said}")
    assert got.stderr.count("\n") == 1


def test_a_viewer_that_cannot_be_reached_is_one_line() -> None:
    """rerun says so as a RuntimeError when the recording is flushed (after ~6 s)."""
    from mavsid.viz.viewer import viewer_errors

    with pytest.raises(cli.ConfigError, match=r"--url rerun\+http://h:1/proxy: cannot reach"):
        with viewer_errors("--url rerun+http://h:1/proxy"):
            raise RuntimeError("gRPC has been unable to connect for 6s, uri: rerun+http://h:1")
    with pytest.raises(RuntimeError, match="other"), viewer_errors("rerun://h"):
        raise RuntimeError("other")


def _listening(port: int) -> list[str]:
    """Local addresses (hex, as in /proc/net/tcp*) listening on ``port``."""
    out = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with contextlib.suppress(OSError), open(table) as f:
            for line in f.read().splitlines()[1:]:
                local, state = line.split()[1], line.split()[3]
                addr, hexport = local.rsplit(":", 1)
                if state == "0A" and int(hexport, 16) == port:
                    out.append(addr)
    return out


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="needs Linux /proc/net/tcp")
def test_served_viewer_listens_on_localhost_only_and_stops_on_sigterm() -> None:
    """`view --serve`: the rerun server listens on 127.0.0.1 only, on free ports (not the
    fixed 9876/9090 another process may hold), and SIGTERM stops it and frees both ports."""
    import re
    import signal
    import time
    import urllib.parse

    proc = subprocess.Popen(
        [sys.executable, "-m", "mavsid.cli", "view", str(FIXTURES / "sysid_roll.bin"), "--serve"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        line = ""
        deadline = time.monotonic() + 120
        while "web viewer:" not in line and time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line and proc.poll() is not None:
                break
        assert "web viewer:" in line, proc.stderr.read() if proc.stderr else ""
        web = urllib.parse.urlsplit(line.split()[2])
        grpc = re.search(r":(\d+)/proxy", urllib.parse.unquote(web.query))
        assert web.hostname == "127.0.0.1" and grpc is not None
        ports = (int(web.port or 0), int(grpc.group(1)))
        loopback = {"0100007F", "00000000000000000000000001000000"}
        for port in ports:
            addrs = _listening(port)
            assert addrs and set(addrs) <= loopback, (port, addrs)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) in (0, 130)
        time.sleep(0.5)
        assert all(not _listening(port) for port in ports)
    finally:
        if proc.poll() is None:
            proc.kill()


@pytest.mark.slow
def test_a_non_utf8_terminal_gets_escapes_not_a_traceback() -> None:
    """LANG=C / an ASCII stdout: "→" and "×" in the output must not crash the command."""
    import os

    env = {**os.environ, "PYTHONIOENCODING": "ascii", "LANG": "C", "LC_ALL": "C"}
    outs = []
    for argv, code in ((["segments", str(FIXTURES / "sysid_roll.bin")], 0),
                       (["fit", str(FIXTURES / "hover.bin")], 1)):
        proc = subprocess.run([sys.executable, "-m", "mavsid.cli", *argv], env=env,
                              capture_output=True, text=True, encoding="ascii",
                              errors="strict", timeout=300)
        assert "Traceback" not in proc.stderr and "UnicodeEncodeError" not in proc.stderr
        assert proc.returncode == code, proc.stderr
        outs.append(proc.stdout + proc.stderr)
    assert "\\xd7" in outs[0] and "\\u2013" in outs[0]  # × and – escaped


def test_nothing_identifiable_is_one_line_and_the_verdicts() -> None:
    proc = run("fit", str(FIXTURES / "hover.bin"))
    assert proc.returncode == 1
    (line,) = proc.stderr.splitlines()
    assert line.startswith("mavsid: error: ") and "nothing identifiable (roll: " in line
    assert "mavsid segments" in line and "--all" in line
    head, *rest = proc.stdout.splitlines()
    assert head == "verdict:" and all(x.startswith("  ") for x in rest)
    assert {x.split(":")[0].strip() for x in rest[:3]} == {"roll", "pitch", "yaw"}
    assert sum(x.strip().startswith("next time:") for x in rest) == 1  # advice once


def test_validate_and_fit_help_describe_themselves(capsys) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(SystemExit):
        cli.main(["validate", "--help"])
    assert "re-discretised" in " ".join(capsys.readouterr().out.split())
    with pytest.raises(SystemExit):
        cli.main(["fit", "--help"])
    assert "stlsq" in capsys.readouterr().out


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.mark.slow
@pytest.mark.parametrize("quiet", [False, True])
def test_progress_bar_on_a_terminal_only(quiet: bool, tmp_path: Path) -> None:
    """On a terminal, fit shows a bar over its stages (each named as it starts), gone at the
    end; --quiet or a non-terminal stderr shows none."""
    from mavsid.pipeline import FIT_STAGES

    err = _Terminal()
    rrd = tmp_path / "f.rrd"
    argv = ["fit", str(FIXTURES / "sysid_roll.bin"), "--rrd", str(rrd), *(["--quiet"] * quiet)]
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        assert cli.main(argv) == 0
    text = err.getvalue()
    if quiet:
        assert text == ""
        assert run(*argv[:-1]).stderr == ""  # not a terminal: no bar either
        return
    frames = text.split("\r")
    for stage in ("reading", "roll: segments", "roll: fit", "roll: validation",
                  "roll: closed-loop twin", "pitch: segments", "yaw: closed-loop twin",
                  "f.rrd"):
        assert any(stage in f for f in frames), stage
    # the .rrd weighs as much as the fit before it (about as long): half the bar is left,
    # and so is an ETA, when it starts
    (writing,) = [f for f in frames if "f.rrd" in f]
    fitting = 1 + 3 * len(FIT_STAGES)
    assert f" {round(100 * fitting / (2 * fitting))}%|" in writing, writing
    elapsed, left = (int(m) * 60 + int(s) for m, s in
                     (x.split(":") for x in writing.rsplit("[", 1)[1].strip("]").split("<")))
    assert left >= elapsed - 1, writing  # (the time the fit took is still to come)
    assert frames[-1].strip() == ""  # the bar is cleared: the result stays readable


def test_a_warning_is_written_above_the_progress_bar() -> None:
    """A warning printed into the bar's line left a stale "0 %" bar on screen: it is
    written on a cleared line, the bar drawn again below it."""
    err = _Terminal()
    argv = ["fit", str(FIXTURES / "sysid_roll.bin"), "--preset", "ardupilot-rcou",
            "--axis", "roll"]
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        cli.main(argv)
    text = err.getvalue()
    at = text.index("warning: ")
    before = text[:at].split("\r")
    assert before[-1] == "" and before[-2].strip() == ""  # the bar's line cleared first
    after = text[at:].split("\n", 1)[1]
    assert after.startswith("\r") and "%|" in after.split("\r")[1]  # the bar again, below


def test_pipeline_reports_every_stage_even_skipped_ones() -> None:
    from mavsid.pipeline import FIT_STAGES, PipelineConfig, fit

    seen: list[str] = []
    fit([str(FIXTURES / "sysid_roll.bin")], PipelineConfig(), progress=seen.append)
    assert seen[0].startswith("reading ")
    assert seen[1:] == [f"{a}: {s}" for a in ("roll", "pitch", "yaw") for s in FIT_STAGES]


@pytest.mark.parametrize("command, second", [("info", "summarising"),
                                             ("segments", "scoring windows"),
                                             ("tune", "loop analysis")])
def test_info_segments_and_tune_show_their_stages_on_a_terminal(command: str, second: str) -> None:
    log = str(FIXTURES / "sysid_roll.bin")
    for quiet in (None, "--quiet", "-q"):
        err = _Terminal()
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
            assert cli.main([command, log, *([quiet] if quiet else [])]) == 0
        text = err.getvalue()
        assert (f"reading {log}" in text and second in text) is not bool(quiet)
        assert (text == "") is bool(quiet)



def test_fit_uses_the_preset_named() -> None:
    """``fit --preset NAME`` reads the log through that preset: the bundled flight's motor
    PWMs (RCOU, logged at 10 Hz) instead of its RATE outputs, which it says cannot resolve
    the rate loop."""
    proc = run("fit", str(FIXTURES / "sysid_roll.bin"), "--preset", "ardupilot-rcou",
               "--axis", "roll", "-q")
    assert proc.returncode == 1
    assert "inputs from RCOU are logged at 10.0 Hz" in proc.stderr
    assert "roll: not identified: rates/outputs logged at 10 Hz" in proc.stdout
    default = run("fit", str(FIXTURES / "sysid_roll.bin"), "--axis", "roll", "--json", "-q")
    assert json.loads(default.stdout)["presets"] == ["ardupilot-rate"]


def test_fit_takes_presets_from_a_toml_file(tmp_path: Path) -> None:
    """``fit --preset FILE.toml``: the file's presets and mixers, tried before the built-in
    ones (as ``segments --preset`` and a config's ``presets_file``)."""
    toml = tmp_path / "my.toml"
    toml.write_text(
        '[preset.my-rcou]\nformats = ["dataflash"]\nmixer = "my-quad"\n'
        'motors = { message = "RCOU", field = "C{i}", unit = "pwm" }\n'
        '[preset.my-rcou.states]\nroll = { message = "ATT", field = "Roll", unit = "deg" }\n'
        'p = { message = "RATE", field = "R", unit = "deg/s" }\n'
        '[mixer.my-quad]\nangle_deg = [45, -135, -45, 135]\nyaw = [1, 1, -1, -1]\n')
    proc = run("fit", str(FIXTURES / "sysid_roll.bin"), "--preset", str(toml), "--axis", "roll",
               "-q")
    assert "inputs from RCOU are logged at 10.0 Hz" in proc.stderr
    bad = run("fit", str(FIXTURES / "sysid_roll.bin"), "--preset", str(tmp_path / "no.toml"))
    assert bad.returncode == 1 and bad.stderr.count("\n") == 1 and "no.toml" in bad.stderr



def test_validating_a_diverging_or_foreign_model_says_so_in_one_line(tmp_path: Path) -> None:
    """A saved model edited to diverge (A_d 1e300) printed numpy's overflow warnings and
    "segments shorter than the 4 s frequency-response window"; an axis the tool does not
    know was taken and found no segment. Now: the verdict says the prediction diverges,
    stderr holds the one error line; the unknown axis is named."""
    model = tmp_path / "m.json"
    assert run("fit", str(FIXTURES / "sysid_roll.bin"), "-q", "-o", str(model)).returncode == 0
    data = json.loads(model.read_text())
    roll = data["axes"]["roll"]
    roll["coef"] = [[1e300] * len(row) for row in roll["coef"]]
    model.write_text(json.dumps(data))
    proc = subprocess.run([sys.executable, "-m", "mavsid", "validate", str(model),
                           str(FIXTURES / "sysid_roll.bin"), "-q"],
                          capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 1
    assert "roll: does not predict this flight: the model's prediction is not a finite " \
           "number on the held-out data (it diverges)" in proc.stdout
    assert proc.stderr.count("\n") == 1 and proc.stderr.startswith("mavsid: error: "), \
        proc.stderr
    data["axes"] = {"spin": roll}
    model.write_text(json.dumps(data))
    bad = run("validate", str(model), str(FIXTURES / "sysid_roll.bin"), "-q")
    assert bad.returncode == 1
    assert bad.stderr == f"mavsid: error: {model}: axis 'spin' is not one of roll, pitch, yaw\n"


def test_validate_fails_when_the_model_does_not_predict_the_flight(tmp_path: Path) -> None:
    """A pitch model of the small quad against a flight of the heavier X quad (another plant,
    fixtures/heavy_sysid.truth.json): no axis validates, exit 1, said as validation (not as
    a fit: no "not identified", no advice for the next flight), with the numbers; against a
    flight of the same plant it validates (exit 0)."""
    model = tmp_path / "pitch.json"
    assert run("fit", str(FIXTURES / "sysid_pitch.bin"), "--axis", "pitch", "-q",
               "-o", str(model)).returncode == 0
    other = run("validate", str(model), str(FIXTURES / "heavy_sysid.bin"), "-q")
    assert other.returncode == 1
    (line,) = [x for x in other.stdout.splitlines() if x.strip().startswith("pitch:")]
    assert line.strip().startswith("pitch: does not predict this flight: one step ")
    assert "free run" in line and "%" in line
    assert "not identified" not in other.stdout and "next time" not in other.stdout
    (err,) = other.stderr.splitlines()
    assert err.startswith(f"mavsid: error: {FIXTURES / 'heavy_sysid.bin'}: the model does not "
                          "predict this flight (pitch: one step ")
    same = run("validate", str(model), str(FIXTURES / "noisy_sysid.bin"), "-q", "--json")
    assert same.returncode == 0, same.stderr
    assert json.loads(same.stdout)["verdicts"]["pitch"]["level"] == "good"
    as_json = json.loads(run("validate", str(model), str(FIXTURES / "heavy_sysid.bin"),
                             "--json").stdout)
    assert "does not predict this flight" in as_json["error"]["message"]
    assert as_json["verdicts"]["pitch"]["numbers"]["fit_free_run_pct"] < 0


def test_fit_table_leads_with_the_physical_parameters() -> None:
    """Time constant (and its corner), effectiveness, delay and lag come before the
    regression's coefficients, the discrete-time ones last; the time constant is -1/A of
    the truth's plant within its σ (fixtures/sysid_roll.truth.json)."""
    proc = run("fit", str(FIXTURES / "sysid_roll.bin"), "--axis", "roll", "-q")
    lines = [x.strip() for x in proc.stdout.splitlines()]
    head = lines.index(next(x for x in lines if x.startswith("roll (p;")))
    first = [x.split()[0] for x in lines[head + 1:head + 4]]
    assert first == ["time", "effectiveness", "delay"]
    order = [x.split()[0] for x in lines[head + 4:] if "[" in x.split()[0]]
    assert order.index("A[p,p]") < order.index("A_d[p,p]")
    assert all("_d[" in n for n in order[order.index("A_d[p,p]"):])
    assert "input lag" in lines[head + 3] and " ms" in lines[head + 3]
    truth = json.loads((FIXTURES / "sysid_roll.truth.json").read_text())["axes"]["roll"]
    tau, _, sigma = lines[head + 1].split()[2:5]
    assert abs(float(tau) - 1 / truth["damping"]) < 3 * float(sigma)
    b, _, sb = lines[head + 2].split()[2:5]
    assert abs(float(b) - truth["effectiveness"]) < 3 * float(sb)


def _rows(lines: list[str]) -> list[list[str]]:
    """The rows of a markdown table's body (``lines`` from its header on)."""
    body = []
    for line in lines[2:]:
        if not line.startswith("|"):
            break
        body.append([c.strip() for c in line.strip("|").split("|")])
    return body


def test_viewer_summary_and_report_lead_with_the_physical_parameters(fitted) -> None:  # type: ignore[no-untyped-def]
    """The rerun summary's and the HTML report's first parameter row of an axis is its time
    constant (within 3σ of the truth's 1/damping), before B, delay and lag; the
    discrete-time coefficients come after the continuous-time ones (``A_d[p,p]`` led)."""
    import html as html_mod
    import re

    out_dir, _ = fitted
    truth = json.loads((FIXTURES / "sysid_roll.truth.json").read_text())["axes"]["roll"]
    docs = [x[0] for c in RrdReader(out_dir / "fit.rrd").stream().to_chunks()
            if c.entity_path == "/summary"
            for x in c.to_record_batch().column("TextDocument:text").to_pylist()]
    lines = docs[0].split("\n")[docs[0].split("\n").index("## roll"):]
    tables = [i for i, x in enumerate(lines) if x.startswith("| ") and "| value | σ |" in x]
    physical, fitted_rows = _rows(lines[tables[0]:]), _rows(lines[tables[1]:])
    assert lines[tables[0]].startswith("| physical parameter |")
    assert [r[0].split()[0] for r in physical[:4]] == ["time", "open-loop", "control", "input"]
    tau, sigma = float(physical[0][1]), float(physical[0][2])
    assert physical[0][3] == "s" and abs(tau - 1 / truth["damping"]) < 3 * sigma
    names = [r[0] for r in fitted_rows]
    assert names[0] == "A[p,p]" and all("_d[" in n for n in names[names.index("A_d[p,p]"):])

    page = (out_dir / "fit.html").read_text()
    section = page[page.index("<h2>roll</h2>"):]
    cells = [html_mod.unescape(re.sub(r"<[^>]+>", "", c))
             for c in re.findall(r'<td class="name">(.*?)</td>', section)]
    assert cells[0] == "time constant 1/damping"
    assert cells.index("control effectiveness B (u_roll → p′)") < cells.index("A[p,p]")
    fitted_names = [c for c in cells if re.fullmatch(r"\w+\[[\w,]+\]", c)][:len(names)]
    assert fitted_names == names
