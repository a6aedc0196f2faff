"""Fit time against the number of rows, and L1 on the Gram against cvxpy on the raw rows.

Run: ``python benchmarks/bench_fit.py [--max-rows 1000000] [--repeat 3] [--cpu]``.

Columns (seconds, best of ``--repeat``):

* ``gram``        forming ZᵀZ, ZᵀY once (the only step that reads every row)
* ``ls solve``    least squares from the Gram (mavsid.estimators.solve)
* ``lstsq rows``  the incumbent: numpy.linalg.lstsq on the raw rows
* ``fit()``       LeastSquares.fit on segments end to end (rows, Gram, identifiability,
                  Newey–West covariance, 50-replicate block bootstrap)
* ``l1 gram``     Lasso on the Gram's square root, 40 features (cvxpy + CLARABEL)
* ``l1 rows``     the same lasso posed by cvxpy on the raw rows (CLARABEL)

Then the structure search: ``fit_axis`` with its delay/lag search against the
fixed-structure fit (the same model with the chosen filters and delay given), at 12k, 48k and
192k rows of a plant behind a 20 Hz gyro filter (1 kHz), a 15 ms motor lag and 3 samples of
delay; the ratio is what the search adds. ``refit each`` times the incumbent way of scoring
the same candidates (rows, Gram and solve rebuilt per candidate).

Timings are printed, never asserted.
"""

from __future__ import annotations

import argparse
import time
import warnings
from collections.abc import Callable

import numpy as np
from scipy import signal

from mavsid.data import Segment
from mavsid.estimators import Lasso, LeastSquares, Structure, fit_axis, solve
from mavsid.estimators.base import Gram
from mavsid.estimators.regressors import InputFilter
from mavsid.estimators.select import (
    DEFAULT_DELAY_STEP,
    DEFAULT_LAGS_S,
    DEFAULT_MAX_DELAY_S,
    _slow_mse,
    lag_filter,
)

N_FEATURES_L1 = 40


#: The clock timings read: wall time, or this process's CPU time with ``--cpu`` (steadier on
#: a machine other work shares).
CLOCK: list[Callable[[], float]] = [time.perf_counter]


def best_of(fn: Callable[[], object], repeat: int) -> float:
    out = np.inf
    clock = CLOCK[0]
    for _ in range(repeat):
        t0 = clock()
        fn()
        out = min(out, clock() - t0)
    return out


def problem(n: int, p: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    z = rng.standard_normal((n, p))
    theta = np.zeros((p, 1))
    theta[: max(3, p // 8), 0] = rng.uniform(0.5, 2.0, max(3, p // 8))
    return z, z @ theta + 0.01 * rng.standard_normal((n, 1))


def segments(n: int, seed: int = 0) -> tuple[list[Segment], Structure]:
    """A first-order plant, n rows split over 4 segments."""
    rng = np.random.default_rng(seed)
    segs = []
    for _ in range(4):
        m = n // 4 + 1
        u = np.repeat(rng.standard_normal(m // 8 + 1), 8)[:m] * 0.05
        w = 1e-3 * rng.standard_normal(m)
        # p[k+1] = 0.99 p[k] + 0.7 u[k] + w[k]
        p = signal.lfilter([0.0, 1.0], [1.0, -0.99], 0.7 * u + w)
        segs.append(Segment(np.arange(m) * 0.0025, p[:, None], u[:, None], ("p",), ("u_roll",),
                            0.0025, "roll", "sysid"))
    return segs, Structure(("p",), ("p", "u_roll", "1"))


def rate_segments(n: int, seed: int = 0) -> list[Segment]:
    """Roll-rate records behind a gyro filter, a motor lag and a delay; n rows over 4."""
    rng = np.random.default_rng(seed)
    dt = 0.0025
    gyro = InputFilter(20.0, 2, "INS_GYRO_FILTER", rate_hz=1000.0)
    out = []
    for _ in range(4):
        m = n // 4 + 1
        u = np.repeat(rng.standard_normal(m // 8 + 1), 8)[:m] * 0.05
        seen = lag_filter(0.015)[0].apply(gyro.apply(u, dt), dt)
        seen = np.concatenate([np.full(3, seen[0]), seen[:-3]])
        p = signal.lfilter([0.0, 1.0], [1.0, -0.99], 0.7 * seen + 1e-3 * rng.standard_normal(m))
        out.append(Segment(np.arange(m) * dt, p[:, None], u[:, None], ("p",), ("u_roll",), dt,
                           "roll", "sysid", meta={"params": {"INS_GYRO_FILTER": 20.0}}))
    return out


def refit_each(segs: list[Segment], st: Structure) -> None:
    """The incumbent search: every (lag, delay) candidate refitted from its rows."""
    dt = segs[0].dt
    top = round(DEFAULT_MAX_DELAY_S / dt)
    for lag in DEFAULT_LAGS_S:
        if lag and lag * np.pi / dt <= 1.0:
            continue
        s2 = Structure(st.outputs, st.features, st.inputs, filters=st.filters + lag_filter(lag))
        scan = {float(d): _slow_mse(segs, s2, float(d)) for d in range(top + 1)}
        d0 = int(min(scan, key=lambda k: scan[k] or np.inf))
        for d in np.arange(max(d0 - 1, 0), min(d0 + 1, top) + 1e-9, DEFAULT_DELAY_STEP):
            _slow_mse(segs, s2, float(d))


def search_table(repeat: int) -> None:
    print(f"\n{'rows':>9} {'search fit':>11} {'fixed fit':>10} {'ratio':>6} {'refit each':>11}"
          f"   chosen")
    for n in (12_000, 48_000, 192_000):
        segs = rate_segments(n)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            m = fit_axis(segs, "roll")
            t_search = best_of(lambda segs=segs: fit_axis(segs, "roll"), repeat)
            fixed = {"filters": m.filters, "delay": m.delay + m.delay_frac, "lags_s": None}
            t_fixed = best_of(lambda segs=segs, fixed=fixed: fit_axis(segs, "roll", **fixed),
                              repeat)
            gyro = tuple(f for f in m.filters if f.source == "INS_GYRO_FILTER")
            st = Structure(("p",), ("p", "u_roll", "1"), filters=gyro)
            t_old = best_of(lambda segs=segs, st=st: refit_each(segs, st), 1)
        chosen = (f"lag {m.provenance['lag_s']:g} s, delay {m.delay + m.delay_frac:g} "
                  f"samples")
        print(f"{n:9d} {t_search:11.3f} {t_fixed:10.3f} {t_search / t_fixed:6.2f} "
              f"{t_old:11.3f}   {chosen}")
    clock = "CPU" if CLOCK[0] is time.process_time else "wall"
    print(f"(fit_axis defaults: ls, Newey-West + 100-replicate bootstrap, output-error "
          f"refinement; best of {repeat}, {clock} time; truth: lag 0.015 s, delay 3 samples)")


def lasso_rows(z: np.ndarray, y: np.ndarray, alpha: float) -> np.ndarray:
    """The incumbent: the same lasso posed on the raw rows."""
    import cvxpy as cp

    s = np.sqrt((z**2).mean(axis=0))
    th = cp.Variable(z.shape[1])
    obj = cp.sum_squares(z @ th - y[:, 0]) / len(z) + alpha * cp.norm1(cp.multiply(s, th))
    cp.Problem(cp.Minimize(obj)).solve(solver="CLARABEL")
    return np.asarray(th.value)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max-rows", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--l1-rows-max", type=int, default=100_000,
                    help="largest N for cvxpy on raw rows (slow)")
    ap.add_argument("--search-only", action="store_true",
                    help="only the structure-search table")
    ap.add_argument("--cpu", action="store_true",
                    help="time by the process's CPU time instead of the wall clock")
    args = ap.parse_args()
    if args.cpu:
        CLOCK[0] = time.process_time
    if args.search_only:
        search_table(args.repeat)
        return
    sizes = [n for n in (10_000, 100_000, 1_000_000) if n <= args.max_rows]
    st40 = Structure(("y",), tuple(f"x{i}" for i in range(N_FEATURES_L1)))
    alpha = 1e-3
    print(f"{'rows':>9} {'gram':>8} {'ls solve':>9} {'lstsq rows':>11} {'fit()':>8} "
          f"{'l1 gram':>8} {'l1 rows':>8} {'rows/gram(l1)':>14}")
    for n in sizes:
        z, y = problem(n, N_FEATURES_L1)
        t_gram = best_of(lambda z=z, y=y: Gram.of(z, y), args.repeat)
        g = Gram.of(z, y)
        t_solve = best_of(lambda g=g: solve(g), args.repeat)
        t_lstsq = best_of(lambda z=z, y=y: np.linalg.lstsq(z, y, rcond=None), args.repeat)
        segs, st = segments(n)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t_fit = best_of(lambda segs=segs, st=st: LeastSquares(st, n_bootstrap=50).fit(segs),
                            args.repeat)
        est = Lasso(st40, alpha=alpha)
        est._solve(g, alpha, st40)  # first call builds the cvxpy problem (not timed)
        t_l1 = best_of(lambda g=g, est=est: est._solve(g, alpha, st40), args.repeat)
        if n <= args.l1_rows_max:
            t_l1_rows = best_of(lambda z=z, y=y: lasso_rows(z, y, alpha), 1)
            ratio = f"{t_l1_rows / t_l1:14.1f}"
            rows_txt = f"{t_l1_rows:8.3f}"
        else:
            rows_txt, ratio = f"{'skipped':>8}", f"{'-':>14}"
        print(f"{n:9d} {t_gram:8.4f} {t_solve:9.5f} {t_lstsq:11.4f} {t_fit:8.3f} "
              f"{t_l1:8.4f} {rows_txt} {ratio}")
    print(f"(gram/lstsq columns: {N_FEATURES_L1} features; fit(): 3-feature first-order plant; "
          f"l1 alpha={alpha:g}; best of {args.repeat})")
    search_table(args.repeat)


if __name__ == "__main__":
    main()
