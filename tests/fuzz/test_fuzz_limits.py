"""Fuzz cases run in a subprocess, measured: each ends in success or one typed error line,
within 10 s per MB (plus the interpreter's start and the pipeline's fixed cost) and 5x the
file's size + 300 MB of peak memory (``ru_maxrss`` of that child, from ``os.wait4``).

Covers every reader and the ``info``, ``segments`` and ``fit`` library calls on mutated
logs, the hostile files of ``hostile.py`` (FMT churn, header and text floods, far-future times,
metadata of another layout, -inf in a CRC-valid .tlog) and a few runs of the command line.
The number of mutated cases follows ``MAVSID_FUZZ_BUDGET`` (seconds).
"""

from __future__ import annotations

import math
import os
import random
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from helpers import require_shared

from fuzz import hostile
from fuzz.budget import subprocess_cases
from fuzz.mutate import FIXTURES, MUTATORS, SEEDS, available_seeds, mutate, seed_bytes, suffix
from fuzz.runner import ROOT, run_case

S_PER_MB = 10.0
#: fixed cost allowed on top of 10 s/MB: a fresh interpreter importing numpy/scipy/pymavlink
#: (and, for segments/fit, the pipeline's fixed work), on a loaded 2-core machine
STARTUP_S = {"read": 15.0, "info": 15.0, "segments": 30.0, "fit": 60.0}
MEM_FACTOR, MEM_BASE_MB = 5.0, 300.0
OPS = ("read", "info", "segments", "fit")


def _mutated_cases() -> list[tuple[str, str, str, int]]:
    """``(op, seed, mutator, n)``: a fixed draw (same on every xdist worker)."""
    rng = random.Random(13)
    seeds, mutators = sorted(SEEDS), sorted(MUTATORS)
    return [(OPS[k % len(OPS)], rng.choice(seeds), rng.choice(mutators), rng.randrange(2**16))
            for k in range(subprocess_cases())]


def _check(op: str, path: Path) -> None:
    size_mb = path.stat().st_size / 1e6
    limit_s = S_PER_MB * size_mb + STARTUP_S[op]
    out = run_case(op, path, timeout_s=limit_s)
    assert out.ok, f"{op} {path.name}: {out.detail}"
    assert out.wall_s <= limit_s, f"{op} {path.name}: {out.wall_s:.1f} s > {limit_s:.1f} s"
    mem_limit = MEM_FACTOR * size_mb + MEM_BASE_MB
    assert out.peak_rss_mb <= mem_limit, \
        f"{op} {path.name}: peak {out.peak_rss_mb:.0f} MB > {mem_limit:.0f} MB"
    if out.detail != "ok":
        assert str(path) in out.detail, f"error does not name the file: {out.detail}"


@pytest.mark.slow
@pytest.mark.parametrize(("op", "seed", "mutator", "n"), _mutated_cases(),
                         ids=lambda v: str(v))
def test_mutated_case_within_limits(op: str, seed: str, mutator: str, n: int,
                                   tmp_path: Path) -> None:
    if seed not in available_seeds():
        require_shared()
        pytest.skip(f"seed {seed} absent")
    path = tmp_path / f"case{suffix(seed)}"
    path.write_bytes(mutate(seed, mutator, n))
    _check(op, path)


def _fixture_tlog() -> bytes:
    return (FIXTURES / "sysid_roll.tlog").read_bytes()


def _fixture_bin() -> bytes:
    return (FIXTURES / "sysid_roll.bin").read_bytes()


HOSTILE: dict[str, tuple[str, str, Callable[[], bytes]]] = {
    "fmt_churn": ("read", ".bin", lambda: hostile.fmt_churn(500_000)),
    "header_flood": ("read", ".bin", lambda: hostile.header_flood(10_000_000)),
    "text_flood": ("read", ".log", lambda: hostile.text_flood(10_000_000)),
    "metadata_redefined": ("info", ".bin", hostile.metadata_redefined),
    "timeus_2p40_tail": ("segments", ".bin", lambda: hostile.dataflash_time_outlier(
        _fixture_bin(), None, 2**40, last=3)),
    "time_boot_ms_2p32": ("segments", ".tlog", lambda: hostile.set_tlog_field(
        _fixture_tlog(), "ATTITUDE", "time_boot_ms", {k: 2**32 - 1 for k in range(1640, 1650)})),
    "one_timestamp": ("segments", ".tlog", lambda: hostile.set_tlog_field(
        _fixture_tlog(), "ATTITUDE", "time_boot_ms", {k: 1000 for k in range(100_000)})),
    "minus_inf_attitude": ("fit", ".tlog", lambda: hostile.set_tlog_field(
        _fixture_tlog(), "ATTITUDE", "rollspeed", {k: -math.inf for k in range(0, 10**5, 7)})),
    "ulog_self_reference": ("read", ".ulg", hostile.ulog_self_reference),
    "ulog_mutual_reference": ("info", ".ulg", hostile.ulog_mutual_reference),
    "ulog_damaged_parameter": ("info", ".ulg", hostile.ulog_damaged_parameter),
    "tlog_fe_flood": ("read", ".tlog", lambda: b"\xfe" * 10_000_000),
    "tlog_fd_flood": ("read", ".tlog", lambda: b"\xfd" * 10_000_000),
}


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(HOSTILE))
def test_hostile_file_within_limits(name: str, tmp_path: Path) -> None:
    op, ext, build = HOSTILE[name]
    path = tmp_path / f"{name}{ext}"
    path.write_bytes(build())
    _check(op, path)


@pytest.mark.slow
@pytest.mark.parametrize("case", ["info-garbage", "segments-truncated", "fit-bitflips"])
def test_cli_prints_one_line(case: str, tmp_path: Path) -> None:
    """The command line itself: exit 0, or exit 1 with one ``mavsid: error:`` line and no
    traceback (warnings are single lines too)."""
    op, what = case.split("-")
    data = {"garbage": lambda: random.Random(1).randbytes(50_000),
            "truncated": lambda: seed_bytes("fix_roll.bin")[:200_000],
            "bitflips": lambda: mutate("fix_roll.tlog", "bit_flips", 5)}[what]()
    path = tmp_path / f"{what}.bin"
    path.write_bytes(data)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-W", "error::RuntimeWarning", "-m", "mavsid.cli",
                           op, str(path)], capture_output=True, text=True, env=env,
                          timeout=120)
    assert proc.returncode in (0, 1), proc.stderr
    assert "Traceback" not in proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("mavsid: error:")]
    others = [ln for ln in proc.stderr.splitlines()
              if not ln.startswith(("mavsid: error:", "warning: "))]
    assert not others, proc.stderr
    if proc.returncode == 1:
        assert len(errors) == 1 and str(path) in errors[0]
