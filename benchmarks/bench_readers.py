"""Reader benchmark: mavsid against pymavlink on the same data, in the same run.

    python benchmarks/bench_readers.py [--prefix-mb 30] [--copies 2] [--tlog-mb 100]
                                       [--ulog-mb 100] [--only dataflash|tlog|ulog]

DataFlash: builds a >= 200 MB ``.bin`` by concatenating the shared ``.bin`` logs (the SITL
flight ``--copies`` times) in a temporary folder, then times

* mavsid ``read_log`` on the whole file: all messages, and ATT/RATE/IMU/RCOU only;
* pymavlink (``mavlink_connection``, ``recv_match`` + ``to_dict`` over the same messages) on a
  prefix of ``--prefix-mb`` MB cut at a record header (a full pymavlink decode of 200 MB takes
  minutes); its time for the whole file is extrapolated from its MB/s on the prefix. mavsid is
  also timed on that prefix, so one ratio compares both on identical bytes.

It prints MB/s, the ratios and mavsid's peak memory (tracemalloc) against the size of the
arrays it returns.

MAVLink .tlog (``--tlog-mb``, default 100): every shared ``.tlog`` concatenated until the file
is that large; mavsid's reader against pymavlink's ``recv_match`` loop over all messages of
the whole file. ULog: per shared ``.ulg`` and on a simulated long flight of ``--ulog-mb`` MB
(built in a temporary folder), mavsid's ``ulog.read`` against ``pyulog.ULog`` in the same
run, warm (best CPU time, the two in turn) and cold (first read in a fresh process), mavsid
reading the attitude topics only, and mavsid's peak memory against its returned arrays.

Each format has its own ``bench_<format>()``; ``main()`` calls them, so a section for another
format is one more function.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
import tracemalloc
import warnings
from collections.abc import Callable, Sequence
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


def bench_dataflash(prefix_mb: float, copies: int) -> None:
    from mavsid.readers import read_log

    if not (LOGS / "sitl" / "flightA_mixer.BIN").exists():
        print(f"skipping DataFlash: {LOGS} not present")
        return
    with tempfile.TemporaryDirectory() as tmp:
        big = build_dataflash(Path(tmp), copies)
        prefix = cut_prefix(big, prefix_mb * MB, Path(tmp))
        size, psize = big.stat().st_size / MB, prefix.stat().st_size / MB
        print(f"\nDataFlash: {big.name} {size:.1f} MB (SITL x{copies} + the other shared .bin), "
              f"pymavlink measured on the first {psize:.1f} MB")
        for label, types in (("all messages", None), ("ATT/RATE/IMU/RCOU", ATTITUDE_TYPES)):
            read = quiet(lambda p=big, t=types: read_log(p, messages=t))
            w_ours, c_ours, log = timed(read, repeat=3)
            n_ours = sum(len(t) for t in log.messages.values())
            arrays = decoded_bytes(log)
            del log
            peak, _ = peak_memory(read)
            w_pre, c_pre, _ = timed(quiet(lambda t=types: read_log(prefix, messages=t)), 3)
            w_ref, c_ref, n_ref = timed(lambda t=types: pymavlink_decode(prefix, t))
            w_full, c_full = w_ref * size / psize, c_ref * size / psize
            report(f"  {label}  (wall s / CPU s)", [
                ("mavsid, whole file", f"{w_ours:7.3f} / {c_ours:7.3f} s  "
                                       f"{size / w_ours:7.1f} / {size / c_ours:7.1f} MB/s  "
                                       f"{n_ours} messages"),
                ("mavsid, prefix", f"{w_pre:7.3f} / {c_pre:7.3f} s  "
                                   f"{psize / w_pre:7.1f} / {psize / c_pre:7.1f} MB/s"),
                ("pymavlink, prefix (measured)", f"{w_ref:7.2f} / {c_ref:7.2f} s  "
                                                 f"{psize / w_ref:7.2f} / {psize / c_ref:7.2f} "
                                                 f"MB/s  {n_ref} messages"),
                ("pymavlink, whole file", f"{w_full:7.1f} / {c_full:7.1f} s  "
                                          "(extrapolated at its MB/s on the prefix)"),
                ("ratio on the prefix", f"{w_ref / w_pre:5.0f}x / {c_ref / c_pre:5.0f}x"),
                ("ratio, whole file", f"{w_full / w_ours:5.0f}x / {c_full / c_ours:5.0f}x  "
                                      "(pymavlink extrapolated)"),
                ("mavsid peak memory", f"{peak / MB:.0f} MB = {peak / arrays:.2f}x the "
                                       f"{arrays / MB:.0f} MB of decoded arrays (tracemalloc)"),
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


def bench_tlog(min_mb: float) -> None:
    """Every shared .tlog concatenated (whole set repeated) to >= ``min_mb`` MB; mavsid's
    ``tlog.read`` against pymavlink over all messages of the whole file."""
    from mavsid.readers import tlog

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
        tlog.load_dialect()  # the dialect import, outside the timing (as pymavlink's)
        w_ours, c_ours, log = timed(quiet(lambda: tlog.read(big)), repeat=3)
        n_ours = sum(len(t) for t in log.messages.values())
        del log
        w_ref, c_ref, n_ref = timed(lambda: pymavlink_tlog(big))
    report(f"tlog: {size:.1f} MB ({len(sources)} shared .tlog x {copies}), all messages "
           "(wall s / CPU s)", [
        ("mavsid tlog.read", f"{w_ours:7.2f} / {c_ours:7.2f} s  {size / w_ours:6.1f} MB/s  "
                             f"{n_ours} messages"),
        ("pymavlink recv_match", f"{w_ref:7.2f} / {c_ref:7.2f} s  {size / w_ref:6.2f} MB/s  "
                                 f"{n_ref} messages"),
        ("ratio (time)", f"{w_ref / w_ours:5.1f}x / {c_ref / c_ours:5.1f}x  (goal >= 20x)"),
        ("ratio (messages/s)", f"{w_ref / w_ours * n_ours / n_ref:5.1f}x / "
                               f"{c_ref / c_ours * n_ours / n_ref:5.1f}x  (pymavlink loses "
                               "sync where a file starts with garbage after another)"),
    ])  # fmt: skip


# --------------------------------------------------------------------------- ULog
ULOG_TOPICS = ["vehicle_attitude", "vehicle_angular_velocity", "vehicle_torque_setpoint",
               "actuator_controls_0", "vehicle_rates_setpoint"]  # fmt: skip
#: bytes of ULog the simulator writes per second of a px4-1.14 flight (about)
ULOG_BYTES_PER_S = 68_000

_COLD = """
import contextlib, io, sys, time, warnings
path, which = sys.argv[1], sys.argv[2]
if which == "pyulog":
    from pyulog import ULog
    def run():
        with contextlib.redirect_stdout(io.StringIO()):
            return ULog(path)
else:
    from mavsid.readers import ulog
    def run():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return ulog.read(path)
t0, c0 = time.perf_counter(), time.process_time()
run()
print(time.perf_counter() - t0, time.process_time() - c0)
"""


def cold(path: Path, which: str) -> tuple[float, float]:
    """Wall and CPU time of the first read in a fresh process (imports not timed)."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _COLD, str(path), which], check=True,
                         capture_output=True, text=True, cwd=ROOT).stdout.split()
    return float(out[0]), float(out[1])


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


def bench_ulog(min_mb: float = 100.0, repeat: int = 5) -> None:
    """Per shared .ulg and on a >= ``min_mb`` MB simulated flight: mavsid's ``ulog.read``
    against ``pyulog.ULog`` measured in the same run, warm (best CPU of ``repeat``, in
    turn) and cold (first read in a fresh process); mavsid reading the attitude topics
    only; mavsid's peak memory against the arrays it returns."""
    import contextlib
    import io

    from pyulog import ULog

    from mavsid.readers import ulog

    paths = sorted(LOGS.rglob("*.ulg"))
    if not paths:
        print(f"skipping shared ULogs: {LOGS} not present")

    def plain(path: Path) -> Callable[[], Any]:
        def run() -> Any:
            with contextlib.redirect_stdout(io.StringIO()):
                return ULog(str(path))
        return run

    def measure(path: Path, n: int) -> tuple[str, str]:
        ref, ours = warm_pair(plain(path), quiet(lambda: ulog.read(path)), n)
        _, sel = warm_pair(lambda: None, quiet(lambda: ulog.read(path, messages=ULOG_TOPICS)),
                           n)
        (_, cold_ref), (_, cold_ours) = cold(path, "pyulog"), cold(path, "mavsid")
        log = quiet(lambda: ulog.read(path))()
        arrays = decoded_bytes(log)
        del log
        peak, _ = peak_memory(quiet(lambda: ulog.read(path)))
        return (path.name[:44], f"{path.stat().st_size / MB:7.1f} {ref:7.3f} {ours:7.3f} "
                                f"{ref / ours:6.1f}x  {cold_ref:7.3f} {cold_ours:7.3f} "
                                f"{cold_ref / cold_ours:6.1f}x  {ref / sel:6.1f}x  "
                                f"{peak / max(arrays, 1):5.2f}x")  # fmt: skip

    header = ("file", "     MB  pyulog  mavsid  ratio   (warm, best CPU s)  pyulog  mavsid  "
                      "ratio  (cold, CPU s)  selective  peak/arrays")  # fmt: skip
    rows = [header] + [measure(path, repeat) for path in paths]
    with tempfile.TemporaryDirectory() as tmp:
        big = build_big_ulog(Path(tmp), min_mb)
        rows.append(measure(big, 3))
    report(f"ULog: pyulog.ULog against mavsid ulog.read, same run; selective = full pyulog "
           f"/ mavsid on {', '.join(ULOG_TOPICS)}; peak = tracemalloc peak of mavsid's read "
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
    parser.add_argument("--only", choices=["dataflash", "tlog", "ulog"],
                        help="run one format only")
    args = parser.parse_args(argv)
    if args.only in (None, "dataflash"):
        bench_dataflash(args.prefix_mb, args.copies)
    if args.only in (None, "ulog"):
        bench_ulog(args.ulog_mb)
    if args.only in (None, "tlog"):
        bench_tlog(args.tlog_mb)


if __name__ == "__main__":
    main()
