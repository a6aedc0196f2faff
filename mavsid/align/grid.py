"""The uniform time grid: laid only where every channel has data, split into blocks at
every gap, states interpolated and inputs held onto it.

Examples
--------
>>> i = np.array([0.0, 0.1, 0.2])
>>> resampled(i, np.array([1.0, 2.0, 3.0]), np.array([0.05, 0.5]), np.nan).tolist()
[1.5, nan]
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from mavsid.errors import ConfigError

if TYPE_CHECKING:
    from mavsid.align.series import Series

__all__ = ["MAX_GAP_SAMPLES", "MAX_GRID_PER_SAMPLE", "between_held", "held_known", "hold",
           "resampled", "sorted_unique", "uniform_grid"]

#: a channel pausing longer than this many of its own median sample intervals is a gap
MAX_GAP_SAMPLES = 4.0


#: grid points allowed per sample of the densest channel (a hard cap on the grid's size)
MAX_GRID_PER_SAMPLE = 50


def _gaps(series: list[Series], max_gap: float) -> np.ndarray:
    """Union of every channel's gaps as sorted, disjoint open intervals ``(k, 2)``."""
    spans = []
    for s in series:
        d = np.diff(s.t)
        i = np.flatnonzero(d > max_gap * s.median_dt)
        spans.append(np.column_stack([s.t[i], s.t[i + 1]]))
        if s.bad_t.size and s.t.size >= 2:  # between the kept samples around an excluded one
            j = np.clip(np.searchsorted(s.t, s.bad_t, side="right"), 1, s.t.size - 1)
            spans.append(np.column_stack([s.t[j - 1], s.t[j]]))
    if not spans:
        return np.empty((0, 2))
    g = np.concatenate(spans)
    if not g.size:
        return np.empty((0, 2))
    g = g[np.argsort(g[:, 0])]
    merged = [g[0].copy()]
    for a, b in g[1:]:
        if a <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], b)
        else:
            merged.append(np.array([a, b]))
    return np.asarray(merged)


def sorted_unique(x: np.ndarray) -> np.ndarray:
    """``np.unique(x)`` for integers that are nearly sorted already (runs that overlap a
    little): a stable sort (a merge of the runs) and the repeats dropped. numpy 2's
    ``np.unique`` hashes first: 0.35 s for the 400 000 grid indices of a 27-min flight,
    against 0.3 ms.

    Examples
    --------
    >>> sorted_unique(np.array([0, 1, 2, 1, 2, 3, 7, 7])).tolist()
    [0, 1, 2, 3, 7]
    """
    x = np.sort(x, kind="stable")
    keep = np.ones(x.size, bool)
    np.not_equal(x[1:], x[:-1], out=keep[1:])
    return x[keep]


def uniform_grid(series: list[Series], ref: Series, rate_hz: float | None, max_gap: float,
          path: str = "") -> tuple[np.ndarray, np.ndarray, float]:
    """Uniform grid times, ``[start, stop)`` blocks and the step.

    The grid is laid only where no channel has a gap (points inside a gap are never
    made), so its size follows the samples, whatever their time stamps claim; more than
    ``MAX_GRID_PER_SAMPLE`` points per sample of the densest channel is a ConfigError.
    """
    gaps = _gaps(series, max_gap)
    if rate_hz is None:
        d = np.diff(ref.t)
        ok = d <= max_gap * ref.median_dt
        dt = float(d[ok].mean()) if ok.any() else float("nan")
    else:
        if not 0 < rate_hz < math.inf:
            raise ConfigError(f"rate_hz must be a positive finite number, got {rate_hz}")
        dt = 1.0 / float(rate_hz)
    start = max(float(s.t[0]) for s in series)
    stop = min(float(s.t[-1]) for s in series)
    if rate_hz is not None and 0 < stop - start < dt:
        raise ConfigError(f"{path}: a grid step of {dt:.3g} s (rate_hz {rate_hz:g}) is longer "
                          f"than the {stop - start:.3g} s the channels share: choose a higher "
                          "rate_hz")
    if not np.isfinite(dt) or dt <= 0 or stop - start < dt:
        return np.empty(0), np.empty((0, 2), dtype=np.int64), dt
    n = int(np.floor((stop - start) / dt + 1e-9)) + 1
    # grid indices of the stretches between gaps, counted before anything is allocated
    inner = gaps[(gaps[:, 1] > start) & (gaps[:, 0] < stop)]
    lo_t = np.concatenate([[start], inner[:, 1]])
    hi_t = np.concatenate([inner[:, 0], [stop]])
    k_lo = np.clip(np.floor((lo_t - start) / dt) - 1, 0, n)
    k_hi = np.clip(np.ceil((hi_t - start) / dt) + 1, -1, n - 1)
    counts = np.maximum(k_hi - k_lo + 1, 0).astype(np.int64)
    total = int(counts.sum())
    samples = max(s.t.size for s in series)
    if total > MAX_GRID_PER_SAMPLE * samples + 1000:
        raise ConfigError(
            f"{path}: a grid step of {dt:.3g} s gives {total} points for at most {samples} "
            f"samples per channel (more than {MAX_GRID_PER_SAMPLE} per sample): choose a "
            "lower rate_hz"
        )
    starts = np.repeat(k_lo.astype(np.int64) - np.cumsum(counts) + counts, counts)
    k = sorted_unique(np.arange(total, dtype=np.int64) + starts)
    t = start + dt * k
    t = t[t <= stop]
    # index of the first gap starting at or after each time; inside a gap when that gap's
    # predecessor has not ended yet
    before = np.searchsorted(gaps[:, 0], t, side="left")  # gaps starting strictly before t
    inside = np.zeros(t.size, dtype=bool)
    has_prev = before > 0
    inside[has_prev] = t[has_prev] < gaps[before[has_prev] - 1, 1]
    # t exactly at a gap start is fine; t strictly between start and end is not
    keep = ~inside
    t, before = t[keep], before[keep]
    if not t.size:
        return t, np.empty((0, 2), dtype=np.int64), dt
    # a new block wherever a gap starts between two kept grid points
    idx = np.arange(t.size)
    cut = np.flatnonzero(np.diff(before) > 0) + 1
    edges = np.concatenate([[0], cut, [t.size]])
    blocks = np.column_stack([edges[:-1], edges[1:]])
    blocks = blocks[blocks[:, 1] - blocks[:, 0] >= 2]
    if not blocks.size:
        return np.empty(0), np.empty((0, 2), dtype=np.int64), dt
    sel = np.concatenate([idx[a:b] for a, b in blocks])
    lengths = blocks[:, 1] - blocks[:, 0]
    new_edges = np.concatenate([[0], np.cumsum(lengths)])
    return t[sel], np.column_stack([new_edges[:-1], new_edges[1:]]).astype(np.int64), dt


def _latest(ts: np.ndarray, t: np.ndarray, dt: float) -> np.ndarray:
    """Index of the latest of the sorted times ``ts`` at or before each time ``t`` (-1 before
    the first). "At" allows ``1e-6 * dt`` for the rounding of the grid times, so that a grid
    point meant to fall on a sample does not pick the one before it."""
    return np.searchsorted(ts, t + 1e-6 * dt, side="right") - 1


def hold(s: Series, t: np.ndarray, dt: float) -> np.ndarray:
    """Zero-order hold: the latest native sample at or before each time (the first before
    it; see :func:`_latest` for "at")."""
    return s.v[np.clip(_latest(s.t, t, dt), 0, None)]


def held_known(ts: np.ndarray, v: np.ndarray, t: np.ndarray, dt: float) -> np.ndarray:
    """Zero-order hold of samples ``v`` at sorted times ``ts`` on the grid ``t`` (step ``dt``),
    NaN where the value is not known: before the first sample, and where the latest sample
    lies more than two of the samples' median intervals (or of the grid's steps) back.

    Examples
    --------
    >>> held_known(np.array([0.0, 0.1, 0.2]), np.array([1.0, 2.0, 3.0]),
    ...            np.array([-0.1, 0.0, 0.15, 0.4, 0.5]), 0.05).tolist()
    [nan, 1.0, 2.0, 3.0, nan]
    """
    i = _latest(ts, t, dt)
    out = v[np.clip(i, 0, None)].astype(float)
    step = max(float(np.median(np.diff(ts))) if ts.size >= 2 else 0.0, dt)
    out[(i < 0) | (t - ts[np.clip(i, 0, None)] > 2 * step)] = np.nan
    return out


def between_held(s: Series, t: np.ndarray, dt: float) -> np.ndarray | None:
    """An input interpolated between the native samples its :func:`hold` puts on the grid
    ``t``, like the states, instead of held: a held input lags an interpolated state by up
    to a sample (its share depending on where the grid falls between the records), a delay
    a frequency response would take for the plant's. None when the grid holds fewer than two
    of its samples.

    Examples
    --------
    >>> from mavsid.align.series import Series
    >>> s = Series("u_roll", "RATE.ROut", np.array([0.0, 0.1, 0.2]), np.array([0.0, 1.0, 0.0]))
    >>> between_held(s, np.array([0.0, 0.05, 0.1, 0.15, 0.2]), 0.05).round(6).tolist()
    [0.0, 0.5, 1.0, 0.5, 0.0]
    """
    i = _latest(s.t, t, dt)
    first = np.concatenate([[True], i[1:] != i[:-1]]) & (i >= 0)
    if np.count_nonzero(first) < 2:
        return None
    return np.interp(t, s.t[i[first]], s.v[i[first]])


def resampled(ts: np.ndarray, v: np.ndarray, t: np.ndarray, fill: float) -> np.ndarray:
    """Samples ``v`` at times ``ts`` interpolated on the grid ``t``, ``fill`` outside their
    span and inside a gap of more than three of their usual intervals (and 50 ms) between
    two samples, where the signal is not known.

    Examples
    --------
    >>> resampled(np.array([0.0, 0.1, 0.2, 1.0, 1.1]), np.arange(5.0),
    ...            np.array([0.15, 0.6, 1.05, 2.0]), np.nan).tolist()
    [1.5, nan, 3.5, nan]
    """
    order = np.argsort(ts, kind="stable")
    ts = ts[order]
    out = np.interp(t, ts, v[order], left=fill, right=fill)
    if ts.size >= 2:
        gap = max(float(np.median(np.diff(ts))) * 3, 0.05)
        near = np.searchsorted(ts, t).clip(1, ts.size - 1)
        out[np.minimum(np.abs(t - ts[near]), np.abs(t - ts[near - 1])) > gap] = fill
    return out
