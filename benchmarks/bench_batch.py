"""Throughput of `mavsid batch` on a simulated fleet: a plain loop, then 1 and 2 local Dask
workers, in one run on this machine, and the scheduler's overhead per task.

    python benchmarks/bench_batch.py [--logs 50] [--keep DIR]

Prints logs/s for each, the ratio of each to the plain loop, the overhead per task
(Dask wall with 1 worker minus the loop's, per log), and the peak memory of the workers
(``peak_rss_mb`` of the tables: a worker holds one log's arrays at a time).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import shutil
import sys
import tempfile
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mavsid import cli
from mavsid.batch import log_task, run_batch


def _fleet(d: Path, n: int) -> list[str]:
    vehicles = ("quad", "heavy-x", "hexa")
    out = []
    for k in range(n):
        path = d / f"v{k % 5}" / f"flight{k:03d}.bin"
        path.parent.mkdir(parents=True, exist_ok=True)
        with contextlib.redirect_stdout(io.StringIO()):
            cli.main(["simulate", "-o", str(path), "--vehicle", vehicles[k % 3],
                      "--sid-axis", str(10 + k % 2), "--t-rec", "10", "--rate-hz", "200",
                      "--seed", str(k)])
        out.append(str(path))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--logs", type=int, default=50)
    ap.add_argument("--keep", help="folder to build (and keep) the fleet in")
    a = ap.parse_args()
    d = Path(a.keep or tempfile.mkdtemp(prefix="mavsid-fleet-"))
    t = time.perf_counter()
    logs = _fleet(d, a.logs)
    print(f"fleet: {len(logs)} simulated logs in {d} ({time.perf_counter() - t:.0f} s to make)")
    warnings.simplefilter("ignore")
    t = time.perf_counter()
    for p in logs:
        log_task(p)
    loop = time.perf_counter() - t
    print(f"plain loop        {len(logs) / loop:6.2f} logs/s  ({loop:.1f} s)  1.00x")
    walls = {}
    for workers in (1, 2):
        out = d / f"res{workers}.parquet"
        for f in d.glob(f"res{workers}*.parquet"):
            f.unlink()
        t = time.perf_counter()
        tables = run_batch([str(d)], out, workers=workers)
        walls[workers] = time.perf_counter() - t
        peak = tables["logs"]["peak_rss_mb"].max()
        print(f"dask, {workers} worker(s) {len(logs) / walls[workers]:6.2f} logs/s  "
              f"({walls[workers]:.1f} s)  {loop / walls[workers]:.2f}x  "
              f"peak worker memory {peak:.0f} MB")
    print(f"scheduler overhead per task (1 worker vs loop, incl. cluster start): "
          f"{(walls[1] - loop) / len(logs) * 1e3:.0f} ms")
    print(f"machine: {os.cpu_count()} cores, load {os.getloadavg()[0]:.2f}")
    if not a.keep:
        shutil.rmtree(d, ignore_errors=True)


if __name__ == "__main__":
    main()
