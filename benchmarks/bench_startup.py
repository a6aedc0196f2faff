"""Start-up cost of the command line against a bare interpreter, in fresh processes.

    python benchmarks/bench_startup.py [--runs 5]

Prints min and median wall time of ``python -c pass``, ``mavsid --version``, ``mavsid --help``
and ``mavsid fit`` on the small bundled fixture, and each one's excess over the bare
interpreter (what importing mavsid costs), cold and warm (first run vs the rest).
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _time(argv: list[str], runs: int) -> list[float]:
    out = []
    for _ in range(runs):
        t = time.perf_counter()
        subprocess.run(argv, cwd=ROOT, capture_output=True, check=False)
        out.append(time.perf_counter() - t)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--runs", type=int, default=5)
    runs = ap.parse_args().runs
    py = [sys.executable]
    cases = {
        "python -c pass": [*py, "-c", "pass"],
        "mavsid --version": [*py, "-m", "mavsid.cli", "--version"],
        "mavsid --help": [*py, "-m", "mavsid.cli", "--help"],
        "mavsid fit sysid_roll.bin": [*py, "-m", "mavsid.cli", "fit",
                                      str(ROOT / "fixtures" / "sysid_roll.bin")],
    }
    times = {name: _time(argv, runs) for name, argv in cases.items()}
    bare = min(times["python -c pass"])
    print(f"{'command':28} {'cold':>7} {'min':>7} {'median':>7}  beyond the interpreter")
    for name, ts in times.items():
        print(f"{name:28} {ts[0]:7.3f} {min(ts):7.3f} {statistics.median(ts):7.3f}  "
              f"{min(ts) - bare:+.3f} s ({min(ts) / bare:.1f}x)")


if __name__ == "__main__":
    main()
