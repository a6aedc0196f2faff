"""Run one mavsid call on one file in a child process; report outcome, wall time and peak RSS.

The child prints one JSON line: ``{"outcome": "ok"|"error", "kind": ..., "message": ...}``;
anything else (a traceback, a crash, a timeout) is a failure of mavsid, not of the log.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

_CHILD = r"""
import atexit, json, sys, warnings


def _hwm():  # this interpreter's own peak RSS (ru_maxrss would count a big parent's pages)
    try:
        with open("/proc/self/status") as f:
            kb = next(ln.split()[1] for ln in f if ln.startswith("VmHWM:"))
        print("HWM_KB", kb, flush=True)
    except (OSError, StopIteration):
        pass


atexit.register(_hwm)
warnings.simplefilter("error", RuntimeWarning)
from mavsid.errors import MavsidError
op, path = sys.argv[1], sys.argv[2]
try:
    if op == "read":
        from mavsid.readers import read_log
        read_log(path)
    elif op == "info":  # as `mavsid info` reads (a .bin's other types for their times only)
        from mavsid.info import format_summary, read_for_summary, summarize
        format_summary(summarize(read_for_summary(path)))
    elif op == "segments":
        from mavsid.align import load_flight
        from mavsid.excitation import find_segments
        flight = load_flight(path)
        for axis in ("roll", "pitch", "yaw"):
            find_segments(flight, axis)
    elif op == "fit":
        from mavsid.pipeline import PipelineConfig, fit
        fit([path], PipelineConfig())
    elif op == "arrays":  # the size of the arrays read_log returns (for benchmarks)
        from mavsid.readers import read_log
        log = read_log(path)
        total = sum(c.nbytes for t in log.messages.values() for c in t.columns.values())
        total += sum(t.time_s.nbytes for t in log.messages.values())
        print(json.dumps({"outcome": "ok", "detail": f"{total / 1e6:.0f} MB of arrays"}))
        sys.exit(0)
    else:
        raise SystemExit("unknown op " + op)
    print(json.dumps({"outcome": "ok"}))
except MavsidError as exc:
    text = str(exc)
    print(json.dumps({"outcome": "error", "kind": type(exc).__name__, "message": text}))
"""


@dataclass(frozen=True)
class Outcome:
    ok: bool  # success or one typed MavsidError
    detail: str  # the error line, or what went wrong
    wall_s: float
    peak_rss_mb: float
    returncode: int
    cpu_s: float = float("nan")  # user + system time of the child


def run_case(op: str, path: Path, timeout_s: float) -> Outcome:
    """Run ``op`` (read, info, segments, fit) on ``path`` in a fresh interpreter; its peak
    RSS comes from ``os.wait4`` (that child's own resource usage)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONWARNINGS": "ignore"}
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-c", _CHILD, op, str(path)], env=env,
                                stdout=out, stderr=err, text=True)
        timer = threading.Timer(timeout_s, proc.kill)
        timer.start()
        try:
            _, status, usage = os.wait4(proc.pid, 0)
        finally:
            timer.cancel()
        proc.returncode = os.waitstatus_to_exitcode(status)  # reaped: keep Popen quiet
        wall = time.perf_counter() - t0
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read(), err.read()
    # the child's own high-water mark where /proc has it: a child forked from a big test
    # process (before its exec) would otherwise report the parent's pages as its peak
    hwm = [ln.split()[1] for ln in stdout.splitlines() if ln.startswith("HWM_KB ")]
    rss_mb = (int(hwm[-1]) if hwm else usage.ru_maxrss) / 1024  # kB on Linux
    cpu = usage.ru_utime + usage.ru_stime
    code = proc.returncode
    if code == -9 and wall >= timeout_s:
        return Outcome(False, f"timeout after {timeout_s:.0f} s", wall, rss_mb, code)
    lines = [ln for ln in stdout.splitlines() if ln.startswith("{")]
    if code != 0 or len(lines) != 1:
        tail = (stderr.strip().splitlines() or ["?"])[-1]
        return Outcome(False, f"exit {code}: {tail}", wall, rss_mb, code)
    res = json.loads(lines[0])
    if res["outcome"] == "ok":
        return Outcome(True, res.get("detail", "ok"), wall, rss_mb, 0, cpu)
    msg = res["message"]
    one_line = "\n" not in msg and "\r" not in msg
    return Outcome(one_line, f"{res['kind']}: {msg}", wall, rss_mb, 0, cpu)
