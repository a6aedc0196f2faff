"""Heavy libraries are imported where they are used (no timing here: see
benchmarks/bench_startup.py). Each case runs in a fresh interpreter and lists the modules
loaded."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import FIXTURES

#: (scipy.signal and scipy.stats: 0.35 s of imports a plain fit does without, mavsid.numerics)
HEAVY = ("rerun", "matplotlib", "cvxpy", "control", "dask", "distributed", "statsmodels",
         "scipy.signal", "scipy.stats")


def _loaded(code: str, heavy: tuple[str, ...] = HEAVY) -> set[str]:
    probe = (f"import sys, json, contextlib, io, warnings\nwarnings.simplefilter('ignore')\n"
             f"{code}\nprint(json.dumps(sorted(m for m in {list(heavy)!r} if m in sys.modules)))")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    return set(json.loads(proc.stdout.strip().splitlines()[-1]))


@pytest.mark.parametrize("argv", [["--version"], ["--help"], ["fit", "--help"]])
def test_help_and_version_load_no_heavy_library(argv: list[str]) -> None:
    code = (f"from mavsid import cli\ntry:\n    with contextlib.redirect_stdout(io.StringIO()):"
            f"\n        cli.main({argv!r})\nexcept SystemExit:\n    pass")
    assert _loaded(code) == set()


@pytest.mark.slow
@pytest.mark.parametrize("name", ["sysid_roll.bin", "sysid_roll.tlog", "px4_hexa_doublets.ulg",
                                  "hexa_doublets.bin", "heavy_sysid.bin", "noisy_sysid.bin"])
def test_a_plain_fit_loads_neither_the_viewer_nor_plots_nor_cvxpy_nor_scipy_signal(
        name: str) -> None:
    """Each autopilot's path (a PX4 log replays PX4's rate controller): the filters and
    spectra are mavsid.numerics' (scipy.signal and scipy.stats: 0.35 s of imports); the
    output-error solver is scipy.optimize's and the matrix functions scipy.linalg's."""
    code = ("from mavsid import cli\nwith contextlib.redirect_stdout(io.StringIO()):\n"
            f"    assert cli.main(['fit', {str(FIXTURES / name)!r}]) == 0")
    assert _loaded(code, (*HEAVY, "scipy.optimize", "mavsid.synthetic")) == {"scipy.optimize"}


@pytest.mark.slow
def test_tune_loads_the_loop_libraries_but_not_the_viewer_nor_cvxpy_nor_dask() -> None:
    """``mavsid tune``: the suggested loop's limits are checked with python-control (which
    brings its own scipy.signal and matplotlib), the measured margins use scipy.interpolate and
    brentq; no viewer, no cvxpy, no Dask, no statsmodels."""
    code = ("from mavsid import cli\nwith contextlib.redirect_stdout(io.StringIO()):\n"
            f"    assert cli.main(['tune', {str(FIXTURES / 'sysid_roll.bin')!r}]) == 0")
    loaded = _loaded(code, (*HEAVY, "scipy.interpolate", "scipy.optimize"))
    assert {"control", "scipy.interpolate", "scipy.optimize"} <= loaded
    assert not loaded & {"rerun", "cvxpy", "dask", "distributed", "statsmodels"}


@pytest.mark.slow
@pytest.mark.parametrize("argv", [
    ["fit", "{missing}", "--rrd", "{out}.rrd", "--report", "{out}.html"],
    ["fit", "{folder}"],
    ["fit", "{text}", "--report", "{out}.html"],
    ["validate", "{missing}.json", "{log}", "--rrd", "{out}.rrd"],
    ["validate", "{log}.json", "{missing}"],
    ["tune", "{missing}"],
    ["segments", "{folder}"],
    ["view", "{missing}", "--save", "{out}.rrd"],
    ["info", "{text}"],
], ids=lambda argv: "-".join(a.strip("{}") for a in argv[:2]))
def test_an_input_that_cannot_be_read_is_refused_before_the_heavy_imports(
        argv: list[str], tmp_path: Path) -> None:
    """A mistyped log or model name, a folder or a file of no log format: one line, exit 1,
    before the fit's modules (scipy, the estimators: ~0.7 s), the viewer or the plots are
    imported and before a report worker starts (it imports the estimators first)."""
    text = tmp_path / "notes.bin"
    text.write_text("not a log\n")
    model = tmp_path / "model.bin.json"
    model.write_text("{}")
    names = {"missing": str(tmp_path / "missing.bin"), "folder": str(tmp_path),
             "text": str(text), "log": str(tmp_path / "model.bin"),
             "out": str(tmp_path / "out")}
    argv = [a.format(**names) for a in argv]
    code = ("from mavsid import cli\nerr = io.StringIO()\n"
            "with contextlib.redirect_stderr(err):\n"
            f"    code = cli.main({argv!r})\n"
            "said = err.getvalue().strip()\n"
            "assert code == 1 and len(said.splitlines()) == 1 and 'error: ' in said, said\n"
            f"assert any(p in said for p in {list(names.values())!r}), said")
    assert _loaded(code, (*HEAVY, "scipy", "mavsid.estimators", "mavsid.pipeline")) == set()
    assert not list(tmp_path.glob("out*"))


_BLAS_PROBE = """
import json, os, sys
import numpy  # (loaded before, as in a caller's process; the command line loads it after)
from mavsid.threads import limit_process_blas
from threadpoolctl import threadpool_info
before = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
limit_process_blas()
after = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
print(json.dumps({"before": before, "after": after, "env": os.environ.get("OPENBLAS_NUM_THREADS")}))
"""

_BLAS_FIRST = """
import json
from mavsid.threads import limit_process_blas
limit_process_blas()  # (numpy not loaded yet: the command line's order)
import numpy
from threadpoolctl import threadpool_info
print(json.dumps([i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]))
"""


@pytest.mark.slow
@pytest.mark.parametrize("user", [None, "2"])
def test_the_command_line_runs_one_blas_thread_unless_the_user_says(user: str | None) -> None:
    import os

    env = {k: v for k, v in os.environ.items()
           if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    if user:
        env["OPENBLAS_NUM_THREADS"] = user
    proc = subprocess.run([sys.executable, "-c", _BLAS_PROBE], capture_output=True, text=True,
                          timeout=120, env=env)
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout)
    assert got["before"], "numpy's BLAS not found by threadpoolctl"
    if user:
        assert got["after"] == [int(user)] * len(got["after"]) and got["env"] == user
    else:
        assert got["after"] == [1] * len(got["after"]) and got["env"] == "1"
    first = subprocess.run([sys.executable, "-c", _BLAS_FIRST], capture_output=True, text=True,
                           timeout=120, env=env)
    assert first.returncode == 0, first.stderr
    threads = json.loads(first.stdout)
    assert threads and threads == [int(user) if user else 1] * len(threads)


def _blas_threads() -> dict[str, int]:
    """Each loaded BLAS library's thread count, by its file."""
    from threadpoolctl import threadpool_info

    return {i["filepath"]: i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}


@pytest.mark.slow
@pytest.mark.parametrize("user", [None, "2"])
def test_the_library_fits_on_one_blas_thread_and_gives_the_callers_back(
        user: str | None, monkeypatch: pytest.MonkeyPatch) -> None:
    """pipeline.fit, validate_logs, estimators.fit_axis, identify and regress called from a
    user's code run one BLAS thread (a 17x200 by 200x165 product: 23 ms on two threads,
    0.16 ms on one) and leave the caller's count as it was; a count the user set is kept."""
    from threadpoolctl import threadpool_limits

    from mavsid import pipeline
    from mavsid.align import load_flight
    from mavsid.estimators import axis_fit, identification, regression
    from mavsid.excitation import find_segments, select_segments

    for v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.delenv(v, raising=False)
    if user:
        monkeypatch.setenv("OPENBLAS_NUM_THREADS", user)
    log = str(FIXTURES / "sysid_roll.bin")
    seen: list[dict[str, int]] = []
    with threadpool_limits(2, user_api="blas"):  # the caller's count (where it can be set)
        before = _blas_threads()
        assert 2 in before.values()
        inside = before if user else dict.fromkeys(before, 1)

        def kept() -> bool:
            now = _blas_threads()
            return {k: now[k] for k in before} == before
        result = pipeline.fit([log], pipeline.PipelineConfig(axes=("roll",)),
                              progress=lambda stage: seen.append(_blas_threads()))
        assert kept()
        pipeline.validate_logs({"roll": result.axes["roll"].model}, [log],
                               progress=lambda stage: seen.append(_blas_threads()))
        assert kept()
        original, original_solve = identification.identify_segments, regression.solve

        def spy(*args: object, **kwargs: object) -> object:
            seen.append(_blas_threads())
            return original(*args, **kwargs)  # type: ignore[arg-type]

        monkeypatch.setattr(axis_fit, "identify_segments", spy)
        monkeypatch.setattr(identification, "identify_segments", spy)
        monkeypatch.setattr(regression, "solve", lambda *a, **k: (
            seen.append(_blas_threads()), original_solve(*a, **k))[1])
        flight = load_flight(log)
        axis_fit.fit_axis(select_segments(flight, reports=find_segments(flight, "roll")),
                          "roll")
        assert kept()
        seg = select_segments(flight, reports=find_segments(flight, "roll"))[0]
        x = seg.states[:, [seg.state_names.index("p")]]
        u = seg.inputs[:, [seg.input_names.index("u_roll")]]
        identification.identify(x, u, seg.dt)
        regression.regress(np.column_stack([x[:-1], u[:-1]]), x[1:, 0])
        assert kept()
    assert len(seen) > 5 and all({k: t[k] for k in inside} == inside for t in seen), seen


def test_an_entry_point_called_from_another_does_not_limit_again(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """pipeline.fit calls fit_axis per axis: the BLAS libraries are looked up (threadpoolctl,
    ~1.5 ms) once for the whole fit, not again per axis."""
    import threadpoolctl

    from mavsid import pipeline

    for v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.delenv(v, raising=False)
    made: list[int] = []
    original = threadpoolctl.threadpool_limits

    def counted(*args: object, **kwargs: object) -> object:
        made.append(1)
        return original(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(threadpoolctl, "threadpool_limits", counted)
    result = pipeline.fit([str(FIXTURES / "sysid_roll.bin")])
    assert len(result.axes) >= 1 and made == [1]
