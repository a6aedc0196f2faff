"""Reader benchmark: mavsid against pymavlink on the same data, in the same run.

    python benchmarks/bench_readers.py [--prefix-mb 30] [--copies 2]

DataFlash: builds a >= 200 MB ``.bin`` by concatenating the shared ``.bin`` logs (the SITL
flight ``--copies`` times) in a temporary folder, then times

* mavsid ``read_log`` on the whole file: all messages, and ATT/RATE/IMU/RCOU only;
* pymavlink (``mavlink_connection``, ``recv_match`` + ``to_dict`` over the same messages) on a
  prefix of ``--prefix-mb`` MB cut at a record header (a full pymavlink decode of 200 MB takes
  minutes); its time for the whole file is extrapolated from its MB/s on the prefix. mavsid is
  also timed on that prefix, so one ratio compares both on identical bytes.

It prints MB/s, the ratios and mavsid's peak memory (tracemalloc) against the size of the
arrays it returns. Each format has its own ``bench_<format>()``; ``main()`` calls them, so a
section for another format is one more function.
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
def timed(fn: Callable[[], Any], repeat: int = 1) -> tuple[float, Any]:
    """Best wall time of ``repeat`` calls, and the last result."""
    best, result = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - t0)
    return best, result


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
            t_ours, log = timed(read, repeat=3)
            n_ours = sum(len(t) for t in log.messages.values())
            peak, _ = peak_memory(read)
            arrays = decoded_bytes(log)
            del log
            t_ours_prefix, _ = timed(quiet(lambda t=types: read_log(prefix, messages=t)), 3)
            t_ref_prefix, n_ref = timed(lambda t=types: pymavlink_decode(prefix, t))
            ref_rate = psize / t_ref_prefix
            t_ref_full = size / ref_rate
            report(f"  {label}", [
                ("mavsid, whole file", f"{t_ours:.3f} s  {size / t_ours:8.1f} MB/s  "
                                       f"{n_ours} messages"),
                ("mavsid, prefix", f"{t_ours_prefix:.3f} s  {psize / t_ours_prefix:8.1f} MB/s"),
                ("pymavlink, prefix (measured)", f"{t_ref_prefix:.2f} s  {ref_rate:8.2f} MB/s  "
                                                 f"{n_ref} messages"),
                ("pymavlink, whole file", f"{t_ref_full:.1f} s (extrapolated at its MB/s)"),
                ("ratio on the prefix", f"{t_ref_prefix / t_ours_prefix:.0f}x"),
                ("ratio on the whole file", f"{t_ref_full / t_ours:.0f}x (extrapolated pymavlink)"),
                ("mavsid peak memory", f"{peak / MB:.0f} MB = {peak / arrays:.2f}x the "
                                       f"{arrays / MB:.0f} MB of decoded arrays"),
            ])


# --------------------------------------------------------------------------- main
def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--prefix-mb", type=float, default=30.0,
                        help="MB of the DataFlash file pymavlink decodes (default 30)")
    parser.add_argument("--copies", type=int, default=2, help="SITL log copies (default 2)")
    args = parser.parse_args(argv)
    bench_dataflash(args.prefix_mb, args.copies)


if __name__ == "__main__":
    main()
