"""Hostile-input benchmark: time and peak memory of mavsid on files built to hurt.

    python benchmarks/bench_hostile.py [--only NAME[,NAME]] [--boots 10] [--keep]

Each case is built in a temporary folder (nothing large is committed) and run in a fresh
subprocess (``tests/fuzz/runner.py``), whose wall time and peak RSS (``os.wait4``) are
printed with the file size and the ratios s/MB and peak/size:

* ``churn``: one DataFlash type redefined before every record (0.15, 0.5 and 5 MB);
* ``header_flood``: 10 MB of ``A3 95 80``; ``text_flood``: 10 MB of short text-log records;
* ``gigabyte``: the SITL flight ``../shared/logs/sitl/flightA_mixer.BIN`` repeated ``--boots``
  times (about 1 GB for ten boots), read by ``mavsid info`` (the summary), peak memory also
  against the size of the arrays the reader returns (measured in the same child).

Run it from a checkout before and after a change to compare (both on the same day:
timings on a shared machine drift).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from fuzz import hostile  # noqa: E402
from fuzz.runner import run_case  # noqa: E402

SITL = ROOT.parent / "shared" / "logs" / "sitl" / "flightA_mixer.BIN"


def _gigabyte(path: Path, boots: int) -> None:
    with open(SITL, "rb") as src, open(path, "wb") as out:
        for _ in range(boots):
            src.seek(0)
            shutil.copyfileobj(src, out, 1 << 24)


CASES: dict[str, tuple[str, str, Callable[[Path, argparse.Namespace], None]]] = {
    "churn_0.15MB": ("read", ".bin", lambda p, a: p.write_bytes(hostile.fmt_churn(150_000))),
    "churn_0.5MB": ("read", ".bin", lambda p, a: p.write_bytes(hostile.fmt_churn(500_000))),
    "churn_5MB": ("read", ".bin", lambda p, a: p.write_bytes(hostile.fmt_churn(5_000_000))),
    "header_flood_10MB": ("read", ".bin",
                          lambda p, a: p.write_bytes(hostile.header_flood(10_000_000))),
    "text_flood_10MB": ("read", ".log",
                        lambda p, a: p.write_bytes(hostile.text_flood(10_000_000))),
    "gigabyte": ("info", ".bin", lambda p, a: _gigabyte(p, a.boots)),
}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", help="comma-separated case names (default all)")
    ap.add_argument("--boots", type=int, default=10, help="copies of the SITL flight")
    ap.add_argument("--keep", action="store_true", help="keep the built files")
    args = ap.parse_args(argv)
    names = args.only.split(",") if args.only else list(CASES)
    tmp = Path(tempfile.mkdtemp(prefix="mavsid-hostile-"))
    print(f"{'case':<20} {'op':<5} {'MB':>8} {'wall s':>8} {'cpu s':>7} {'s/MB':>6} "
          f"{'peak MB':>8} {'peak/size':>9}  outcome")
    try:
        for name in names:
            op, ext, build = CASES[name]
            if name == "gigabyte" and not SITL.exists():
                print(f"{name:<20} skipped: {SITL} absent")
                continue
            path = tmp / f"{name}{ext}"
            build(path, args)
            size = path.stat().st_size / 1e6
            out = run_case(op, path, timeout_s=600)
            print(f"{name:<20} {op:<5} {size:8.1f} {out.wall_s:8.2f} {out.cpu_s:7.2f} "
                  f"{out.wall_s / size:6.2f} {out.peak_rss_mb:8.0f} "
                  f"{out.peak_rss_mb / size:9.2f}  {out.detail[:60]}")
            if name == "gigabyte":
                arrays = run_case("arrays", path, timeout_s=600)
                mb = float(arrays.detail.split()[0])
                print(f"{'':<20} read_log returns {mb:.0f} MB of arrays: info's peak is "
                      f"{out.peak_rss_mb / mb:.2f}x that")
            if not args.keep:
                path.unlink()
    finally:
        if not args.keep:
            shutil.rmtree(tmp, ignore_errors=True)
        else:
            print(f"files kept in {tmp}")


if __name__ == "__main__":
    main()
