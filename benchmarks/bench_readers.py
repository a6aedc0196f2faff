"""Reader benchmark: mavsid against pymavlink on the same data, in the same run.

    python benchmarks/bench_readers.py [--prefix-mb 30] [--copies 2] [--tlog-mb 100]
                                       [--ulog-mb 100] [--cold-runs 3] [--ref-runs 1]
                                       [--only dataflash|tlog|ulog]

Every DataFlash and .tlog figure is measured twice: **cold**, the first read in a fresh
interpreter (what a command-line run gets: fresh arrays fault their pages in), each in its
own child process, ``--cold-runs`` times (min, median and max printed); and **warm**, the
best of repeats of the same read in that child. Each child imports its library before the
clock starts (start-up is ``bench_startup.py``'s); whatever the read imports itself is
counted. Children run with one BLAS thread (:func:`child_env`), as the ``mavsid`` command
sets for itself before numpy loads: otherwise OpenBLAS's threads, started with numpy, spin
for the first ~0.1 s of a process and take a core from the first read (a cold 30-MB
selective read: 75-95 ms of wall time, 105-120 ms of CPU, against 64 ms with one thread).
Ratios are pymavlink's time over mavsid's (cold: median over median), both measured in this
run. The machine may be shared: the DataFlash reads compared are taken in turn (a
pymavlink run, ``--ref-runs`` of them, among mavsid's) and the load average is printed.

DataFlash: builds a >= 200 MB ``.bin`` by concatenating the shared ``.bin`` logs (the SITL
flight ``--copies`` times) in a temporary folder, then times

* mavsid ``read_log`` on the whole file: all messages, and ATT/RATE/IMU/RCOU only (what
  ``fit`` reads); the same with the numpy header scan a package built without a C compiler
  uses, instead of the compiled one (``mavsid/readers/_scan.c``);
* pymavlink (``mavlink_connection``, ``recv_match`` + ``to_dict``; with ``type=`` for the
  selective read, which pymavlink serves from its index of record offsets) on a prefix of
  ``--prefix-mb`` MB cut at a record header (a full pymavlink decode of 200 MB takes
  minutes); its time for the whole file is extrapolated from its MB/s on the prefix. mavsid
  is also timed on that prefix, so one ratio compares both on identical bytes.

MAVLink .tlog (``--tlog-mb``, default 100): every shared ``.tlog`` concatenated until the file
is that large; mavsid's reader against pymavlink's ``recv_match`` loop over all messages of
the whole file.

Memory: mavsid's peak against the arrays it returns, two ways: the peak of traced
allocations (``tracemalloc``, in a child of its own: Python objects and numpy arrays,
temporaries included) and the growth of the cold child's resident set (``VmHWM`` at the end
over ``VmRSS`` before the read: also the file's pages mapped while reading).

ULog: per shared ``.ulg`` and on a simulated long flight of ``--ulog-mb`` MB
(built in a temporary folder), mavsid's ``ulog.read`` against ``pyulog.ULog`` in the same
run, warm (best CPU time, the two in turn) and cold (first read in a fresh process, median
of ``--cold-runs``), mavsid reading the attitude topics only, mavsid as built without a C
compiler (the numpy walk instead of the compiled one), and mavsid's peak memory against
its returned arrays.

Each format has its own ``bench_<format>()``; ``main()`` calls them, so a section for another
format is one more function.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import tracemalloc
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
LOGS = ROOT.parent / "shared" / "logs"
MB = 1e6
ATTITUDE_TYPES = ["ATT", "RATE", "IMU", "RCOU"]


# --------------------------------------------------------------------------- helpers
def timed(fn: Callable[[], Any], repeat: int = 1) -> tuple[float, float, Any]:
    """Best wall and CPU (process) time of ``repeat`` calls, and the last result.

    Both are printed: on a shared machine the CPU time is the steadier of the two.
    """
    wall, cpu, result = float("inf"), float("inf"), None
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        result = fn()
        wall = min(wall, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    return wall, cpu, result


def peak_memory(fn: Callable[[], Any]) -> tuple[int, Any]:
    """Peak bytes allocated (tracemalloc: Python objects and numpy arrays) while ``fn`` runs."""
    tracemalloc.start()
    try:
        result = fn()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return peak, result


def decoded_bytes(log: Any) -> int:
    """Bytes held by the arrays a RawLog returns (object arrays: pointers only)."""
    return sum(t.time_s.nbytes + sum(c.nbytes for c in t.columns.values())
               for t in log.messages.values())


def quiet(fn: Callable[[], Any]) -> Callable[[], Any]:
    def run() -> Any:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return fn()
    return run


def report(title: str, rows: Sequence[tuple[str, str]]) -> None:
    print(f"\n{title}")
    width = max(len(k) for k, _ in rows)
    for k, v in rows:
        print(f"  {k:<{width}}  {v}")


def _proc_kb(key: str) -> int:
    """A ``/proc/self/status`` figure (kB; 0 where /proc is absent)."""
    try:
        with open("/proc/self/status") as f:
            return int(next(ln.split()[1] for ln in f if ln.startswith(key + ":")))
    except (OSError, StopIteration):
        return 0


# --------------------------------------------------------------------------- child runs
def _reader(who: str, fmt: str, path: Path, types: list[str] | None) -> Callable[[], Any]:
    """The read to time, its library imported (outside the timing)."""
    if who == "mavsid" and fmt == "tlog":
        from mavsid.readers import tlog

        tlog.load_dialect()  # the dialect import, as pymavlink's at its import
        return quiet(lambda: tlog.read(path, messages=types))
    if who in ("mavsid", "mavsid-numpy"):
        import mavsid.readers.dataflash  # noqa: F401  (read_log imports it on first use)
        from mavsid.readers import dataflash_scan, read_log

        if who == "mavsid-numpy":  # as built without a C compiler: the numpy header scan
            dataflash_scan._scan = None

        return quiet(lambda: read_log(path, messages=types))
    from pymavlink import DFReader, mavutil  # noqa: F401

    if fmt == "tlog":
        return lambda: pymavlink_tlog(path)
    return lambda: pymavlink_decode(path, types)


def child(argv: Sequence[str]) -> None:
    """In a fresh interpreter: one cold read, ``warm`` repeats, or a tracemalloc'd read;
    prints one JSON line."""
    who, fmt, path, kinds, warm, mode = argv
    types = kinds.split(",") if kinds != "-" else None
    read = _reader(who, fmt, Path(path), types)
    out: dict[str, Any] = {}
    if mode == "memory":
        peak, log = peak_memory(read)
        out.update(peak=peak, arrays=decoded_bytes(log))
    else:
        rss0 = _proc_kb("VmRSS")
        t0, c0 = time.perf_counter(), time.process_time()
        result = read()
        out.update(wall=time.perf_counter() - t0, cpu=time.process_time() - c0,
                   rss_growth=(_proc_kb("VmHWM") - rss0) * 1024,
                   count=result if isinstance(result, int)
                   else sum(len(t) for t in result.messages.values()),
                   arrays=0 if isinstance(result, int) else decoded_bytes(result))
        del result
        w, c, _ = timed(read, int(warm)) if int(warm) else (float("nan"),) * 3
        out.update(warm_wall=w, warm_cpu=c)
    print(json.dumps(out))


@dataclass(frozen=True)
class Figures:
    """One read measured in fresh children: cold wall/CPU of each run, best warm ones."""

    cold_wall: list[float]
    cold_cpu: list[float]
    warm_wall: float
    warm_cpu: float
    count: int
    arrays: int
    rss_growth: int

    @property
    def cold(self) -> float:
        """Median cold wall time."""
        return statistics.median(self.cold_wall)

    @property
    def cold_cpu_s(self) -> float:
        """Median cold CPU time (steadier than wall time on a loaded machine)."""
        return statistics.median(self.cold_cpu)

    def row(self, mb: float) -> str:
        """Cold min/median/max (wall s; CPU median), warm best, and MB/s of the cold median."""
        return (f"cold {min(self.cold_wall):6.3f}/{self.cold:6.3f}/{max(self.cold_wall):6.3f} s "
                f"(CPU {self.cold_cpu_s:6.3f}, {len(self.cold_wall)} run(s))  "
                f"warm {self.warm_wall:6.3f} s "
                f"(CPU {self.warm_cpu:6.3f})  {mb / self.cold:7.1f} MB/s cold  "
                f"{self.count} messages")


def child_env() -> dict[str, str]:
    """The environment of a child: this one, with the BLAS thread counts the ``mavsid``
    command sets (one thread) unless the user set one (:mod:`mavsid.threads`)."""
    from mavsid.threads import BLAS_THREAD_VARS, user_set

    env = dict(os.environ)
    if not user_set():
        env.update(dict.fromkeys(BLAS_THREAD_VARS, "1"))
    return env


def _spawn(args: list[str]) -> dict[str, Any]:
    proc = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child", *args],
                          capture_output=True, text=True, check=False, env=child_env())
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode or not lines:
        raise RuntimeError(f"child {args} failed: {proc.stderr.strip()[-2000:]}")
    return dict(json.loads(lines[-1]))


def measure(who: str, fmt: str, path: Path, types: list[str] | None, runs: int,
            warm: int) -> Figures:
    """``runs`` cold reads, each in a fresh child; the last child also repeats the read
    ``warm`` times."""
    return measure_in_turn([(who, path, runs)], fmt, types, warm)[0]


def measure_in_turn(reads: Sequence[tuple[str, Path, int]], fmt: str,
                    types: list[str] | None, warm: int) -> list[Figures]:
    """Cold reads ``(who, file, runs)`` in fresh children, taken in turn (round by round,
    a read with fewer runs spread evenly over the rounds) so that every figure sees the
    same spells of machine load; each read's last child also repeats it ``warm`` times."""
    kinds = ",".join(types) if types else "-"
    rounds = max(runs for _, _, runs in reads)
    res: list[list[dict[str, Any]]] = [[] for _ in reads]
    for k in range(rounds):
        for j, (who, path, runs) in enumerate(reads):
            # this read's runs fall on rounds int((i + 0.5) * rounds / runs)
            if len(res[j]) < runs and k >= int((len(res[j]) + 0.5) * rounds / runs):
                repeats = warm if len(res[j]) == runs - 1 else 0
                res[j].append(_spawn([who, fmt, str(path), kinds, str(repeats), "time"]))
    out = []
    for r in res:
        last = r[-1]
        out.append(Figures([x["wall"] for x in r], [x["cpu"] for x in r], last["warm_wall"],
                           last["warm_cpu"], last["count"], last["arrays"],
                           max(x["rss_growth"] for x in r)))
    return out


def memory(fmt: str, path: Path, types: list[str] | None) -> tuple[int, int]:
    """mavsid's tracemalloc peak and the bytes of arrays it returns (a child of its own)."""
    res = _spawn(["mavsid", fmt, str(path), ",".join(types) if types else "-", "0", "memory"])
    return res["peak"], res["arrays"]


def memory_row(peak: int, arrays: int, rss_growth: int) -> str:
    return (f"peak {peak / MB:.0f} MB = {peak / arrays:.2f}x the {arrays / MB:.0f} MB of "
            f"arrays returned (tracemalloc); resident set grows {rss_growth / MB:.0f} MB = "
            f"{rss_growth / arrays:.2f}x (cold)")


# --------------------------------------------------------------------------- DataFlash
def build_dataflash(folder: Path, copies: int) -> Path:
    """Concatenate the shared .bin logs (SITL ``copies`` times) into one file."""
    sitl = LOGS / "sitl" / "flightA_mixer.BIN"
    others = sorted(p for p in (LOGS / "public").rglob("*") if p.suffix.lower() == ".bin")
    out = folder / "concatenated.bin"
    with open(out, "wb") as dst:
        for src in [sitl] * copies + others:
            with open(src, "rb") as f:
                shutil.copyfileobj(f, dst, 1 << 24)
    return out


def cut_prefix(path: Path, size: float, folder: Path) -> Path:
    """The first ``size`` bytes of ``path``, ending just before a record header."""
    data = path.read_bytes()[: int(size)]
    end = data.rfind(b"\xa3\x95")
    out = folder / "prefix.bin"
    out.write_bytes(data[:end])
    return out


def pymavlink_decode(path: Path, types: list[str] | None) -> int:
    """Messages decoded by pymavlink with recv_match + to_dict."""
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(path))
    n = 0
    while True:
        m = conn.recv_match(type=types) if types else conn.recv_match()
        if m is None:
            break
        m.to_dict()
        n += 1
    conn.close()
    return n


def _load() -> str:
    """The 1-minute load average (other work on the machine slows every figure)."""
    try:
        return f"{os.getloadavg()[0]:.1f}"
    except OSError:
        return "?"


def bench_dataflash(prefix_mb: float, copies: int, runs: int, ref_runs: int = 1) -> None:
    if not (LOGS / "sitl" / "flightA_mixer.BIN").exists():
        print(f"skipping DataFlash: {LOGS} not present")
        return
    with tempfile.TemporaryDirectory() as tmp:
        big = build_dataflash(Path(tmp), copies)
        prefix = cut_prefix(big, prefix_mb * MB, Path(tmp))
        size, psize = big.stat().st_size / MB, prefix.stat().st_size / MB
        print(f"\nDataFlash: {big.name} {size:.1f} MB (SITL x{copies} + the other shared .bin), "
              f"pymavlink measured on the first {psize:.1f} MB; cold: min/median/max of "
              f"{runs} fresh processes ({ref_runs} for pymavlink), the four reads in turn; "
              "warm: best of 3 repeats (wall s); ratios: pymavlink's median over mavsid's")
        for label, types in (("all messages", None), ("ATT/RATE/IMU/RCOU", ATTITUDE_TYPES)):
            load = _load()
            ours, plain, pre, ref = measure_in_turn(
                [("mavsid", big, runs), ("mavsid-numpy", big, runs), ("mavsid", prefix, runs),
                 ("pymavlink", prefix, ref_runs)], "bin", types, 3)
            load += f"-{_load()}"
            peak, arrays = memory("bin", big, types)
            scale = size / psize
            report(f"  {label} (load {load})", [
                ("mavsid, whole file", ours.row(size)),
                ("  the same, numpy scan", plain.row(size) + "  (built without a C compiler)"),
                ("mavsid, prefix", pre.row(psize)),
                ("pymavlink, prefix", ref.row(psize)),
                ("pymavlink, whole file", f"cold {ref.cold * scale:6.1f} s  warm "
                                          f"{ref.warm_wall * scale:6.1f} s  (extrapolated at "
                                          "its MB/s on the prefix)"),
                ("ratio on the prefix", f"cold {ref.cold / pre.cold:5.0f}x  warm "
                                        f"{ref.warm_wall / pre.warm_wall:5.0f}x  CPU cold "
                                        f"{ref.cold_cpu_s / pre.cold_cpu_s:5.0f}x  warm "
                                        f"{ref.warm_cpu / pre.warm_cpu:5.0f}x  "
                                        "(identical bytes)"),
                ("ratio, whole file", f"cold {ref.cold * scale / ours.cold:5.0f}x  warm "
                                      f"{ref.warm_wall * scale / ours.warm_wall:5.0f}x  CPU "
                                      f"cold {ref.cold_cpu_s * scale / ours.cold_cpu_s:5.0f}x  "
                                      f"warm {ref.warm_cpu * scale / ours.warm_cpu:5.0f}x  "
                                      "(pymavlink extrapolated)"),
                ("cold ratio, spread", f"{ref.cold * scale / max(ours.cold_wall):5.0f}x .. "
                                       f"{ref.cold * scale / min(ours.cold_wall):5.0f}x  "
                                       "(on mavsid's slowest .. fastest cold run)"),
                ("  numpy scan", f"cold {ref.cold * scale / plain.cold:5.0f}x  warm "
                                 f"{ref.warm_wall * scale / plain.warm_wall:5.0f}x  (the compiled "
                                 f"scan {plain.cold / ours.cold:.2f}x faster cold, "
                                 f"{plain.warm_wall / ours.warm_wall:.2f}x warm)"),
                ("mavsid memory", memory_row(peak, arrays, ours.rss_growth)),
            ])


# --------------------------------------------------------------------------- tlog
def pymavlink_tlog(path: Path) -> int:
    """Messages pymavlink returns from a .tlog (recv_match loop; BAD_DATA and unknown ids
    not counted), decoding with the MAVLink 2 ardupilotmega dialect as mavsid does."""
    import os

    from pymavlink import mavutil

    os.environ["MAVLINK20"] = "1"
    conn = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
    n = 0
    while (m := conn.recv_match()) is not None:
        kind = m.get_type()
        n += kind != "BAD_DATA" and not kind.startswith("UNKNOWN")
    conn.close()
    return n


def bench_tlog(min_mb: float, runs: int) -> None:
    """Every shared .tlog concatenated (whole set repeated) to >= ``min_mb`` MB; mavsid's
    ``tlog.read`` against pymavlink over all messages of the whole file."""
    sources = sorted(LOGS.rglob("*.tlog"))
    if not sources:
        print(f"skipping tlog: {LOGS} not present")
        return
    chunk = b"".join(p.read_bytes() for p in sources)
    copies = max(1, -int(-min_mb * MB // len(chunk)))
    with tempfile.TemporaryDirectory() as tmp:
        big = Path(tmp) / "concatenated.tlog"
        big.write_bytes(chunk * copies)
        size = big.stat().st_size / MB
        ours = measure("mavsid", "tlog", big, None, runs, 3)
        peak, arrays = memory("tlog", big, None)
        ref = measure("pymavlink", "tlog", big, None, 1, 0)
    cpu = ref.cold_cpu_s / ours.cold_cpu_s
    report(f"tlog: {size:.1f} MB ({len(sources)} shared .tlog x {copies}), all messages; "
           f"cold: min/median/max of {runs} fresh processes, warm: best of 3 repeats (wall s)", [
        ("mavsid tlog.read", ours.row(size)),
        ("pymavlink recv_match", ref.row(size) + "  (cold only: its repeat costs the same)"),
        ("ratio (time)", f"cold {ref.cold / ours.cold:5.1f}x  warm "
                         f"{ref.cold / ours.warm_wall:5.1f}x  (CPU {cpu:5.1f}x cold; "
                         "goal >= 30x cold)"),
        ("ratio (messages/s)", f"cold {ref.cold / ours.cold * ours.count / ref.count:5.1f}x  "
                               "(pymavlink loses sync where a file starts with garbage after "
                               "another)"),
        ("mavsid memory", memory_row(peak, arrays, ours.rss_growth) + "  (goal <= 2x)"),
    ])  # fmt: skip


# --------------------------------------------------------------------------- ULog
ULOG_TOPICS = ["vehicle_attitude", "vehicle_angular_velocity", "vehicle_torque_setpoint",
               "actuator_controls_0", "vehicle_rates_setpoint"]  # fmt: skip
#: bytes of ULog the simulator writes per second of a px4-1.14 flight (about)
ULOG_BYTES_PER_S = 68_000

_COLD = """
import contextlib, io, os, sys, time, warnings
paths, which = sys.argv[1].split(os.pathsep), sys.argv[2]
if which == "pyulog":
    from pyulog import ULog
    def run(path):
        with contextlib.redirect_stdout(io.StringIO()):
            return ULog(path)
else:
    from mavsid.readers import ulog, ulog_messages
    if which == "mavsid-numpy":  # as built without a C compiler: the numpy walk
        ulog_messages.compiled = None
    def run(path):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return ulog.read(path)
t0, c0 = time.perf_counter(), time.process_time()
for path in paths:
    run(path)
print(time.perf_counter() - t0, time.process_time() - c0)
"""


def cold(path: Path | Sequence[Path], which: str, runs: int = 1) -> tuple[float, float]:
    """Wall and CPU time of the first read in a fresh process (imports not timed), of
    ``path`` or of several paths one after another: the medians of ``runs`` processes (one
    cold run moves by up to 2x on a shared machine)."""
    import subprocess
    import sys

    wall, cpu = [], []
    paths = [path] if isinstance(path, Path) else list(path)
    for _ in range(runs):
        out = subprocess.run([sys.executable, "-c", _COLD, os.pathsep.join(map(str, paths)),
                              which], check=True,
                             capture_output=True, text=True, cwd=ROOT,
                             env=child_env()).stdout.split()
        wall.append(float(out[0]))
        cpu.append(float(out[1]))
    return statistics.median(wall), statistics.median(cpu)


def warm_pair(a: Callable[[], Any], b: Callable[[], Any], repeat: int) -> tuple[float, float]:
    """Best CPU time of ``a`` and of ``b``, called in turn (a b a b ...) so that a drift of
    the machine's speed touches both."""
    best = [float("inf"), float("inf")]
    for _ in range(repeat):
        for k, fn in enumerate((a, b)):
            c0 = time.process_time()
            fn()
            best[k] = min(best[k], time.process_time() - c0)
    return best[0], best[1]


def build_big_ulog(folder: Path, min_mb: float) -> Path:
    """A >= ``min_mb`` MB ULog: a long simulated flight in PX4 1.14's topic set."""
    from mavsid.synthetic.run import scenario_from_options, simulate

    path = folder / "long_flight.ulg"
    duration = max(60.0, min_mb * MB / ULOG_BYTES_PER_S * 1.05)
    simulate(scenario_from_options(duration_s=duration), [path],
             layout="px4-1.14")
    return path


def bench_ulog(min_mb: float = 100.0, repeat: int = 5, runs: int = 3) -> None:
    """Per shared .ulg and on a >= ``min_mb`` MB simulated flight: mavsid's ``ulog.read``
    against ``pyulog.ULog`` measured in the same run, warm (best CPU of ``repeat``, in
    turn) and cold (first read in a fresh process, median of ``runs``); mavsid reading the
    attitude topics only; mavsid as built without a C compiler; mavsid's peak memory
    against the arrays it returns.

    mavsid keeps the formats and record layouts it parsed for the process (logs of one
    firmware repeat them): every warm figure but one is taken with them forgotten before
    each read, as for a log of a firmware not met before; the column "known" is the warm
    read with them kept (another log of the same firmware). The shared logs are also read
    all one after another in one fresh process each (pyulog, mavsid): what a batch over them
    waits, a format met in an earlier log then known."""
    import contextlib
    import io

    from pyulog import ULog

    from mavsid.readers import ulog, ulog_layout, ulog_messages

    paths = sorted(LOGS.rglob("*.ulg"))
    if not paths:
        print(f"skipping shared ULogs: {LOGS} not present")

    def plain(path: Path) -> Callable[[], Any]:
        def run() -> Any:
            with contextlib.redirect_stdout(io.StringIO()):
                return ULog(str(path))
        return run

    def forgetting(fn: Callable[[], Any]) -> Callable[[], Any]:
        def run() -> Any:  # a log of a firmware not met before: no format known
            for kept in (ulog_layout.known_format, ulog_layout.known_layout):
                kept.clear()
            return fn()
        return run

    def numpy_walk(path: Path) -> Callable[[], Any]:
        def run() -> Any:  # as built without a C compiler
            compiled, ulog_messages.compiled = ulog_messages.compiled, None
            try:
                return ulog.read(path)
            finally:
                ulog_messages.compiled = compiled
        return forgetting(quiet(run))

    # the per-file figures summed: warm, cold (pyulog, mavsid), selective, numpy walk, known
    totals = [0.0] * 8

    def measure(path: Path, n: int) -> tuple[str, str]:
        ref, ours = warm_pair(plain(path), forgetting(quiet(lambda: ulog.read(path))), n)
        sel, numpy_ = warm_pair(forgetting(quiet(lambda: ulog.read(path,
                                                                   messages=ULOG_TOPICS))),
                                numpy_walk(path), n)
        known = warm_pair(quiet(lambda: ulog.read(path)), quiet(lambda: ulog.read(path)), n)[1]
        (_, cold_ref), (_, cold_ours) = cold(path, "pyulog", runs), cold(path, "mavsid", runs)
        _, cold_numpy = cold(path, "mavsid-numpy", runs)
        for k, value in enumerate((ref, ours, cold_ref, cold_ours, sel, numpy_, cold_numpy,
                                   known)):
            totals[k] += value
        log = quiet(lambda: ulog.read(path))()
        arrays = decoded_bytes(log)
        del log
        peak, _ = peak_memory(forgetting(quiet(lambda: ulog.read(path))))
        return (path.name[:44], f"{path.stat().st_size / MB:7.1f} {ref:7.3f} {ours:7.3f} "
                                f"{ref / ours:6.1f}x  {cold_ref:7.3f} {cold_ours:7.3f} "
                                f"{cold_ref / cold_ours:6.1f}x  {ref / sel:6.1f}x  "
                                f"{ref / numpy_:6.1f}x {cold_ref / cold_numpy:6.1f}x  "
                                f"{ref / known:6.1f}x  {peak / max(arrays, 1):5.2f}x")  # fmt: skip

    header = ("file", "     MB  pyulog  mavsid  ratio   (warm, best CPU s)  pyulog  mavsid  "
                      f"ratio  (cold: median CPU s of {runs})  selective  numpy walk (warm, cold)  "
                      "known  peak/arrays")  # fmt: skip
    rows = [header] + [measure(path, repeat) for path in paths]
    if paths:
        ref, ours, cold_ref, cold_ours, sel, numpy_, cold_numpy, known = totals
        mb = sum(p.stat().st_size for p in paths) / MB
        rows.append((f"the {len(paths)} above, figures summed",
                     f"{mb:7.1f} {ref:7.3f} {ours:7.3f} "
                     f"{ref / ours:6.1f}x  {cold_ref:7.3f} {cold_ours:7.3f} "
                     f"{cold_ref / cold_ours:6.1f}x  {ref / sel:6.1f}x  "
                     f"{ref / numpy_:6.1f}x {cold_ref / cold_numpy:6.1f}x  "
                     f"{ref / known:6.1f}x"))  # fmt: skip
        # what a batch over them waits: one fresh process each, the logs one after another
        (_, batch_ref), (_, batch_ours) = cold(paths, "pyulog", runs), cold(paths, "mavsid", runs)
        rows.append((f"the {len(paths)} in one fresh process",
                     f"{mb:7.1f}                         {batch_ref:7.3f} {batch_ours:7.3f} "
                     f"{batch_ref / batch_ours:6.1f}x"))  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        big = build_big_ulog(Path(tmp), min_mb)
        rows.append(measure(big, 3))
    report(f"ULog: pyulog.ULog against mavsid ulog.read, same run; selective = full pyulog "
           f"/ mavsid on {', '.join(ULOG_TOPICS)}; numpy walk = pyulog / mavsid as built "
           "without a C compiler; peak = tracemalloc peak of mavsid's read "
           "/ bytes of its returned arrays (the memory map is not counted)", rows)


# --------------------------------------------------------------------------- main
def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--prefix-mb", type=float, default=30.0,
                        help="MB of the DataFlash file pymavlink decodes (default 30)")
    parser.add_argument("--copies", type=int, default=2, help="SITL log copies (default 2)")
    parser.add_argument("--tlog-mb", type=float, default=100.0,
                        help="size of the concatenated .tlog, MB (default 100)")
    parser.add_argument("--ulog-mb", type=float, default=100.0,
                        help="size of the simulated long ULog flight, MB (default 100)")
    parser.add_argument("--cold-runs", type=int, default=3,
                        help="fresh processes per cold figure (default 3)")
    parser.add_argument("--ref-runs", type=int, default=1,
                        help="fresh processes per cold pymavlink DataFlash figure (default 1: "
                             "its selective read takes seconds, all messages ~15 s)")
    parser.add_argument("--only", choices=["dataflash", "tlog", "ulog"],
                        help="run one format only")
    parser.add_argument("--child", nargs=6, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        child(args.child)
        return
    if args.only in (None, "dataflash"):
        bench_dataflash(args.prefix_mb, args.copies, args.cold_runs, args.ref_runs)
    if args.only in (None, "ulog"):
        bench_ulog(args.ulog_mb, runs=args.cold_runs)
    if args.only in (None, "tlog"):
        bench_tlog(args.tlog_mb, args.cold_runs)


if __name__ == "__main__":
    main()
