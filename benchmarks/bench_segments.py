"""``mavsid segments`` end to end against the incumbent script, on the same log, in one run.

    python benchmarks/bench_segments.py [LOG] [--repeat 3]

Default LOG: the 104 MB ArduCopter SITL SYSTEMID flight in ``../shared/logs/sitl``.

* ``mavsid``     read only the needed messages, align on one grid, find and score windows
                 (:func:`mavsid.align.load_flight` + :func:`mavsid.excitation.find_segments`)
* ``pymavlink``  the incumbent: what a one-off script must do before it can even look for the
                 SYSTEMID windows — pymavlink ``recv_match`` over ATT, RATE, SIDS, SIDD and
                 MODE into numpy arrays (no alignment, no scoring)

Timings are printed (best of ``--repeat``) with their ratio, never asserted.
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np

LOG = Path(__file__).resolve().parents[1].parent / "shared/logs/sitl/flightA_mixer.BIN"


def run_mavsid(path: Path) -> int:
    from mavsid.align import load_flight
    from mavsid.excitation import find_segments

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return sum(r.kept for r in find_segments(load_flight(path)))


def run_pymavlink(path: Path) -> int:
    from pymavlink import mavutil

    types = ["ATT", "RATE", "SIDS", "SIDD", "MODE"]
    rows: dict[str, list[list[float]]] = {t: [] for t in types}
    m = mavutil.mavlink_connection(str(path))
    while (msg := m.recv_match(type=types)) is not None:
        d = msg.to_dict()
        rows[msg.get_type()].append([v for v in d.values() if isinstance(v, int | float)])
    m.close()
    arrays = {t: np.array(r) for t, r in rows.items()}
    return len(arrays["SIDS"])


def best(fn, path: Path, repeat: int) -> tuple[float, int]:
    times, out = [], 0
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn(path)
        times.append(time.perf_counter() - t0)
    return min(times), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", nargs="?", default=str(LOG))
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    path = Path(args.log)
    t_m, kept = best(run_mavsid, path, args.repeat)
    t_p, runs = best(run_pymavlink, path, args.repeat)
    print(f"{path.name}: {path.stat().st_size / 1e6:.0f} MB")
    print(f"mavsid    load+align+segments  {t_m:7.2f} s   ({kept} window(s) kept)")
    print(f"pymavlink read 5 message types {t_p:7.2f} s   ({runs} SIDS record(s))")
    print(f"ratio pymavlink / mavsid       {t_p / t_m:7.1f}x")


if __name__ == "__main__":
    main()
