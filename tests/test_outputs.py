"""Outputs never replace an input, are checked before the work, and are written atomically."""

from __future__ import annotations

import base64
import contextlib
import hashlib
import io
import json
import os
import shutil
import stat
import tempfile
import threading
from pathlib import Path

import pytest
from helpers import FIXTURES

from mavsid import cli


def _run(*argv: str) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = cli.main(list(argv))
    return code, err.getvalue()


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture()
def log(tmp_path: Path) -> Path:
    dst = tmp_path / "flight.bin"
    shutil.copy(FIXTURES / "sysid_roll.bin", dst)
    return dst


@pytest.mark.parametrize("flag", ["-o", "--rrd", "--report"])
def test_fit_never_overwrites_its_log(log: Path, flag: str) -> None:
    before = _digest(log)
    code, err = _run("fit", str(log), flag, str(log))
    assert code == 1 and "is an input of this command" in err and str(log) in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert _digest(log) == before


def test_a_link_to_the_log_is_the_log(log: Path, tmp_path: Path) -> None:
    link = tmp_path / "model.json"
    os.symlink(log, link)
    hard = tmp_path / "hard.json"
    os.link(log, hard)
    before = _digest(log)
    for out in (link, hard):
        code, err = _run("fit", str(log), "-o", str(out))
        assert code == 1 and "is an input" in err
    assert _digest(log) == before


def test_an_output_through_a_link_replaces_the_file_not_the_link(log: Path,
                                                                   tmp_path: Path) -> None:
    """The new file was renamed over the link itself: the link was gone, its file stale."""
    real = tmp_path / "real.json"
    real.write_text("old")
    link = tmp_path / "model.json"
    os.symlink(real, link)
    assert _run("fit", str(log), "-q", "-o", str(link))[0] == 0
    assert link.is_symlink() and os.readlink(link) == str(real)
    assert json.loads(real.read_text())["mavsid_models"] == 1


def test_an_output_that_is_a_pipe_is_written_in_place(log: Path, tmp_path: Path) -> None:
    """An output that exists and is no regular file (a FIFO, ``/dev/stdout``, a device) was
    replaced by a regular file renamed over it: as root, ``fit -o /dev/full`` turned the
    device into a JSON file. Now it is written in place."""
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    got: list[bytes] = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()), daemon=True)
    reader.start()
    try:
        code, err = _run("fit", str(log), "-q", "-o", str(fifo))
    finally:
        reader.join(timeout=30)
        if reader.is_alive():  # the command never opened the pipe: let the reader go (a
            with contextlib.suppress(OSError):  # blocking open would wait for a reader)
                os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
            reader.join(timeout=30)
    assert code == 0, err
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert json.loads(got[0])["mavsid_models"] == 1


def test_a_recording_that_cannot_be_written_is_one_line(log: Path, tmp_path: Path,
                                                        monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """rerun reports a failed write (a full disk) as a RuntimeError: it was a traceback."""
    import rerun as rr

    def full(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        raise RuntimeError("Failed to encode LogMsg: Failed to write: No space left on device "
                           "(os error 28)")

    monkeypatch.setattr(rr.RecordingStream, "save", full)
    out = tmp_path / "f.rrd"
    code, err = _run("fit", str(log), "-q", "--rrd", str(out))
    assert code == 1
    assert err == f"mavsid: error: {out}: cannot write: No space left on device (os error 28)\n"
    assert not out.exists() and not list(tmp_path.glob(".f.*"))


def test_extract_and_view_never_overwrite_their_log(log: Path) -> None:
    before = _digest(log)
    for argv in (("extract", str(log), "-o", str(log)),
                 ("view", str(log), "--save", str(log))):
        code, err = _run(*argv)
        assert code == 1 and "is an input" in err, argv
    assert _digest(log) == before


def test_unwritable_outputs_stop_before_the_fit(log: Path, tmp_path: Path) -> None:
    missing = tmp_path / "no" / "such" / "dir" / "fit.html"
    code, err = _run("fit", str(log), "--report", str(missing))
    assert code == 1 and "does not exist" in err and str(missing) in err
    code, err = _run("fit", str(log), "-o", str(tmp_path))
    assert code == 1 and "is a directory" in err


def test_a_failed_fit_leaves_the_old_output_alone(tmp_path: Path) -> None:
    """Outputs are replaced only when complete: a run that fails keeps the previous file,
    and no temporary file is left beside it."""
    out = tmp_path / "model.json"
    out.write_text("previous")
    code, _ = _run("fit", str(FIXTURES / "hover.bin"), "-o", str(out))
    assert code == 1
    assert out.read_text() == "previous"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.json"]
    code, _ = _run("fit", str(FIXTURES / "sysid_roll.bin"), "-o", str(out))
    assert code == 0 and out.read_text().startswith("{")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.json"]


# --------------------------------------------------------------------------- report worker
@pytest.fixture(scope="module")
def fitted():  # type: ignore[no-untyped-def]
    from toy_plants import toy_flight

    return toy_flight()[1]


@pytest.fixture(autouse=True)
def _tests_importable(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The toy result refers to classes of the tests' own modules: the worker imports them
    from here."""
    paths = [str(Path(__file__).parent), *filter(None, [os.environ.get("PYTHONPATH")])]
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(paths))


@pytest.fixture
def own_tmp(tmp_path: Path, monkeypatch):  # type: ignore[no-untyped-def]
    """A temporary folder of the test's own (tests run in parallel hand results over too)."""
    folder = tmp_path / "tmp"
    folder.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(folder))
    return folder


@pytest.mark.slow
@pytest.mark.usefixtures("own_tmp")
@pytest.mark.parametrize("fork", [True, False])
def test_the_report_worker_writes_the_report_drawn_here(fitted, tmp_path: Path, monkeypatch,  # type: ignore[no-untyped-def]
                                                        fork: bool) -> None:
    """The report drawn in the worker process, forked from this one (Linux) or a new
    interpreter (elsewhere), is the one drawn in this process, byte for byte (its SVG
    figures carry no date and no random ids)."""
    from mavsid import outputs, report
    from mavsid.outputs import ReportWorker

    if fork and not outputs.FORK:
        pytest.skip("no fork here")
    monkeypatch.setattr(outputs, "FORK", fork)
    here, there = tmp_path / "here.html", tmp_path / "there.html"
    report.write_report(fitted, here)
    with ReportWorker() as worker:
        assert worker.start(fitted, str(there), "fit.html")
        worker.wait()
    assert worker.returncode == 0
    assert there.read_bytes() == here.read_bytes()
    assert not list(Path(tempfile.gettempdir()).glob("mavsid-report-*"))  # (handed over)


@pytest.mark.slow
@pytest.mark.usefixtures("own_tmp")
def test_the_worker_hands_back_the_loop_analysis_it_drew(fitted, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """The worker works the loop analysis out before it draws (python-control imported
    while the logs are fitted) and hands it back for the ``.rrd``'s gains: the analysis is
    the one worked out here, the report the same bytes as one drawn here, and no temporary
    file is left."""
    from mavsid import report
    from mavsid.loop.tune import tune_analysis
    from mavsid.outputs import ReportWorker

    here, there = tmp_path / "here.html", tmp_path / "there.html"
    report.write_report(fitted, here)
    with ReportWorker() as worker:
        assert worker.start(fitted, str(there), "fit.html")
        got = worker.analysis()
        assert worker.analysis() is None  # (handed back once)
        worker.wait()
    assert got is not None and got.error is None and got.report
    assert (json.dumps(got.report, sort_keys=True, default=str)
            == json.dumps(tune_analysis(fitted).report, sort_keys=True, default=str))
    assert there.read_bytes() == here.read_bytes()
    assert not list(Path(tempfile.gettempdir()).glob("mavsid-report-*"))


@pytest.mark.slow
@pytest.mark.parametrize("worker", [True, False])
def test_the_rrd_shows_the_reports_gains_with_or_without_a_worker(
        log: Path, tmp_path: Path, monkeypatch, worker: bool) -> None:  # type: ignore[no-untyped-def]
    """``fit --rrd --report``: the ``.rrd`` is handed the loop analysis's per-axis entries
    (its summary shows the gains) whether the report is drawn by a worker or here (drawn
    here, the ``.rrd`` had none: what it showed depended on the machine's load)."""
    from mavsid.loop.tune import tune_analysis
    from mavsid.outputs import ReportWorker
    from mavsid.viz import recording

    handed: list[object] = []
    save = recording.save_rrd

    def spy(result, path, **kw):  # type: ignore[no-untyped-def]
        handed.append(kw.get("gains"))
        return save(result, path, **kw)

    monkeypatch.setattr(recording, "save_rrd", spy)
    monkeypatch.setattr(ReportWorker, "available", staticmethod(lambda: worker))
    code, err = _run("fit", str(log), "--quiet", "--rrd", str(tmp_path / "f.rrd"),
                     "--report", str(tmp_path / "f.html"))
    assert code == 0, err
    from mavsid import pipeline

    want = tune_analysis(pipeline.fit([str(log)])).report
    assert len(handed) == 1 and isinstance(handed[0], dict) and set(handed[0]) == set(want)
    assert all(handed[0][a].get("gains") == want[a].get("gains") for a in want)


@pytest.mark.slow
def test_a_result_that_cannot_be_handed_over_is_drawn_here(log: Path, tmp_path: Path,
                                                           monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """A temporary folder the result cannot be written to (full): the worker is not used,
    the command draws the report itself."""
    from mavsid import outputs
    from mavsid.outputs import ReportWorker

    mkstemp = tempfile.mkstemp

    def full(*args: object, **kw: object) -> tuple[int, str]:  # (the system's temporary folder)
        if kw.get("dir") is None:
            raise OSError(28, "No space left on device")
        return mkstemp(*args, **kw)  # type: ignore[call-overload,no-any-return]

    monkeypatch.setattr(ReportWorker, "available", staticmethod(lambda: True))
    monkeypatch.setattr(outputs.tempfile, "mkstemp", full)
    code, err = _run("fit", str(log), "--quiet", "--report", str(tmp_path / "f.html"))
    assert code == 0, err
    assert "<svg" in base64.b64decode(
        (tmp_path / "f.html").read_text().split("base64,")[1].split('"')[0]).decode()


@pytest.mark.slow
def test_a_report_the_worker_cannot_write_is_one_line(fitted, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    from mavsid.errors import ConfigError
    from mavsid.outputs import ReportWorker

    with ReportWorker() as worker:
        worker.start(fitted, str(tmp_path / "gone" / "x.html"), "fit.html")
        with pytest.raises(ConfigError, match=r"^fit\.html: cannot write: No such file"):
            worker.wait()


@pytest.mark.slow
def test_a_defect_in_the_worker_is_an_error_naming_the_report(capfd) -> None:  # type: ignore[no-untyped-def]
    """Not a result (a defect of the caller's): the worker prints its traceback, the
    command gets one MavsidError naming the output."""
    from mavsid.errors import MavsidError
    from mavsid.outputs import ReportWorker

    with ReportWorker() as worker:
        worker.start(42, os.devnull, "fit.html")
        assert worker.analysis() is None  # (the command works it out itself)
        with pytest.raises(MavsidError, match=r"^fit\.html: the report could not be drawn"):
            worker.wait()
    assert "Traceback" in capfd.readouterr().err


@pytest.mark.parametrize("fork", [True, False])
def test_a_command_that_stops_ends_its_worker(monkeypatch, fork: bool) -> None:  # type: ignore[no-untyped-def]
    from mavsid import outputs
    from mavsid.outputs import ReportWorker

    monkeypatch.setattr(outputs, "FORK", fork and outputs.FORK)
    with pytest.raises(RuntimeError), ReportWorker() as worker:
        raise RuntimeError("the fit failed")
    assert worker.returncode is not None


@pytest.mark.parametrize("fork", [True, False])
def test_an_interrupted_command_ends_its_worker_and_leaves_no_file(  # type: ignore[no-untyped-def]
        fitted, tmp_path: Path, own_tmp: Path, monkeypatch, fork: bool) -> None:
    """Ctrl-C while the worker draws the report: the worker is ended (and reaped), and
    neither the report's temporary file nor the result handed over is left."""
    from mavsid import outputs
    from mavsid.outputs import ReportWorker, atomic_path

    monkeypatch.setattr(outputs, "FORK", fork and outputs.FORK)
    out = tmp_path / "out"
    out.mkdir()
    with pytest.raises(KeyboardInterrupt), ReportWorker() as worker, \
            atomic_path(out / "fit.html") as tmp:
        assert worker.start(fitted, tmp, "fit.html")
        assert worker.returncode is None and os.path.exists(tmp)
        raise KeyboardInterrupt
    assert worker.returncode is not None
    assert list(out.iterdir()) == [] and list(own_tmp.iterdir()) == []


def test_fit_with_nothing_identified_still_writes_its_outputs(log: Path, tmp_path: Path) -> None:
    """``fit --report --rrd`` on a log without excitation: exit 1 with the one error line,
    and both outputs written whole (the verdicts and the closed-loop response), each said on
    stderr; no temporary file is left beside them."""
    out = tmp_path / "out"
    out.mkdir()
    code, err = _run("fit", str(FIXTURES / "hover.bin"), "--report", str(out / "f.html"),
                     "--rrd", str(out / "f.rrd"))
    lines = err.splitlines()
    assert code == 1 and lines[-1].startswith("mavsid: error: ") and len(lines) == 3
    assert all("no plant identified" in ln for ln in lines[:2])
    assert sorted(p.name for p in out.iterdir()) == ["f.html", "f.rrd"]
    html = (out / "f.html").read_text(encoding="utf-8")
    assert html.rstrip().endswith("</html>") and "not identified" in html
    assert (out / "f.rrd").stat().st_size > 0


@pytest.mark.parametrize(("cores", "load", "others", "started"),
                         [(2, 0.3, None, True), (2, 1.9, 1.8, False), (1, 0.0, 0.0, False),
                          (8, 6.5, None, True), (2, 1.4, 0.2, True), (2, 1.4, 0.9, False),
                          (2, 1.9, None, False)])
def test_a_worker_is_started_only_with_a_core_to_spare(
        monkeypatch, cores: int, load: float, others: float | None, started: bool) -> None:  # type: ignore[no-untyped-def]
    """The load average, or where it says busy (it also counts the user's own commands of
    the last minute) the other processes' use now."""
    from mavsid import outputs
    from mavsid.outputs import ReportWorker

    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(cores)), raising=False)
    monkeypatch.setattr(os, "getloadavg", lambda: (load, load, load))
    asked = []
    monkeypatch.setattr(outputs, "_others_busy", lambda s: asked.append(s) or others)
    assert ReportWorker.available() is started
    assert bool(asked) == (cores >= 2 and load > cores - 1)


def test_the_other_processes_use_is_measured(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Two /proc/stat readings 50 ms apart: 10 ticks on 2 CPUs, 4 of them idle -> 1.2 CPUs
    busy; no /proc/stat (not Linux) -> unknown."""
    from mavsid import outputs

    readings = iter([(1000, 600, 2), (1010, 604, 2)])
    monkeypatch.setattr(outputs, "_cpu_times", lambda: next(readings))
    assert outputs._others_busy(0.0) == pytest.approx(1.2)
    monkeypatch.setattr(outputs, "_cpu_times", lambda: None)
    assert outputs._others_busy(0.0) is None
    busy = []
    import threading

    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set():
            pass

    monkeypatch.undo()
    if outputs._cpu_times() is None:
        pytest.skip("no /proc/stat here")
    thread = threading.Thread(target=spin)  # (a spinning thread of this process: one CPU)
    thread.start()
    try:
        busy.append(outputs._others_busy(0.3))
    finally:
        stop.set()
        thread.join()
    assert busy[0] is not None and busy[0] >= 0.6


def test_what_is_drawn_aside_comes_from_another_process_or_is_drawn_here(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """:func:`outputs._drawn_aside`: the figures come back from the forked process (its
    process id in them, not this one's); a process that fails (here: drawing raises
    anywhere but in this process) leaves them to be drawn here; without fork, here."""
    from mavsid import outputs

    if not outputs.FORK:
        pytest.skip("no fork here")
    here = os.getpid()

    def drawn_by() -> list[int]:
        return [os.getpid()]

    def fails_elsewhere() -> list[int]:
        if os.getpid() != here:
            raise RuntimeError("not drawn")
        return [here]

    got = outputs._drawn_aside(drawn_by)()
    assert got != [here] and len(got) == 1
    assert outputs._drawn_aside(fails_elsewhere)() == [here]
    monkeypatch.setattr(outputs, "FORK", False)
    assert outputs._drawn_aside(drawn_by)() == [here]
