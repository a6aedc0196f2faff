"""Heavy libraries are imported where they are used (no timing here: see
benchmarks/bench_startup.py). Each case runs in a fresh interpreter and lists the modules
loaded."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from helpers import FIXTURES

#: (scipy.signal and scipy.stats: 0.35 s of imports a plain fit does without, mavsid.dsp)
HEAVY = ("rerun", "matplotlib", "cvxpy", "control", "dask", "distributed", "statsmodels",
         "scipy.signal", "scipy.stats")


def _loaded(code: str) -> set[str]:
    probe = (f"import sys, json, contextlib, io, warnings\nwarnings.simplefilter('ignore')\n"
             f"{code}\nprint(json.dumps(sorted(m for m in {list(HEAVY)!r} if m in sys.modules)))")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    return set(json.loads(proc.stdout.strip().splitlines()[-1]))


@pytest.mark.parametrize("argv", [["--version"], ["--help"], ["fit", "--help"]])
def test_help_and_version_load_no_heavy_library(argv: list[str]) -> None:
    code = (f"from mavsid import cli\ntry:\n    with contextlib.redirect_stdout(io.StringIO()):"
            f"\n        cli.main({argv!r})\nexcept SystemExit:\n    pass")
    assert _loaded(code) == set()


def test_a_plain_fit_loads_neither_the_viewer_nor_plots_nor_cvxpy_nor_scipy_signal() -> None:
    code = ("from mavsid import cli\nwith contextlib.redirect_stdout(io.StringIO()):\n"
            f"    assert cli.main(['fit', {str(FIXTURES / 'sysid_roll.bin')!r}]) == 0")
    assert _loaded(code) == set()


_BLAS_PROBE = """
import json, os, sys
import numpy  # (loaded before, as in a caller's process; the command line loads it after)
from mavsid import cli
from threadpoolctl import threadpool_info
before = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
cli._one_blas_thread()
after = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
print(json.dumps({"before": before, "after": after, "env": os.environ.get("OPENBLAS_NUM_THREADS")}))
"""

_BLAS_FIRST = """
import json
from mavsid import cli
cli._one_blas_thread()  # (numpy not loaded yet: the command line's order)
import numpy
from threadpoolctl import threadpool_info
print(json.dumps([i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]))
"""


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
