"""FlightData -> well-excited windows, each kept or rejected with reasons that carry numbers.

Two sources of windows, per axis (``roll``, ``pitch``, ``yaw``; the plant input is
``u_<axis>``, the output the body rate ``p``/``q``/``r``, or the angle when a log has no
rates):

``sysid``
    ArduPilot SYSTEMID runs (``FlightData.sysid_runs``, found by alignment from
    SIDS/SIDD, or SYSTEMID mode + SID_* parameters in a .tlog). The window is the injected
    chirp; ``SID_AXIS`` 1–12 name the axis (angle, recovery, rate or mixer injection), 13 is
    mixer thrust, which excites no attitude axis and is reported, not kept.
``scan``
    Sliding windows (``window_s`` long, every ``step_s``) inside each contiguous block, for
    axes without a SYSTEMID run (or all axes with ``scan=True``).

How a window is measured (response, command, injection, input power, band coverage,
conditioning, coherence, flight state; the score) is :mod:`mavsid.excitation_scores`; the
gates it must pass and the reasons a rejection gives, :mod:`mavsid.excitation_gates`.

Adjacent kept scan windows are merged, and a merged window's quiet head and tail (where the
input stays within the power gate of its level in a quiet first/last 0.5 s) are trimmed;
when the merged window fails a gate its parts are reported as they were.
:func:`find_segments` returns every window's :class:`WindowReport`; :func:`select_segments`
turns the kept ones into :class:`~mavsid.data.Segment` objects for the estimators.

Examples
--------
>>> import numpy as np
>>> from mavsid.data import FlightData, SourceInfo
>>> rng = np.random.default_rng(0)
>>> n, dt = 6000, 0.01
>>> t = np.arange(n) * dt
>>> u = 0.002 * rng.standard_normal(n)
>>> u[2000:4000] += 0.1 * np.sign(np.sin(2 * np.pi * 0.7 * t[2000:4000]))   # 20 s of doublets
>>> p = np.zeros(n)
>>> for k in range(1, n):
...     p[k] = 0.95 * p[k - 1] + 0.5 * u[k - 1]
>>> x = np.column_stack([np.zeros(n), np.zeros(n), np.zeros(n), p])
>>> fd = FlightData(t, x, u[:, None], ("roll", "pitch", "yaw", "p"), ("u_roll",),
...                 ("rad",) * 3 + ("rad/s",), ("1",), dt, np.array([[0, n]]),
...                 {"armed": np.ones(n, bool), "airborne": np.ones(n, bool)},
...                 SourceInfo("sim", "synthetic", 0), "test")
>>> kept = [w for w in find_segments(fd, axis="roll") if w.kept]
>>> [(round(w.start_s, 1), round(w.stop_s, 1), w.source) for w in kept]
[(20.0, 40.0, 'scan')]
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from mavsid.autopilot.ardupilot import SID_IDENTIFIES, sid_axis
from mavsid.axes import AXES
from mavsid.data import FlightData, Segment, SysidRun
from mavsid.errors import ConfigError
from mavsid.excitation_gates import gates, kept_reason, rejected
from mavsid.excitation_scores import (
    AxisSignals,
    ScanOptions,
    airborne,
    axis_signals,
    metrics,
    moving_mean,
    score,
    window_stats,
)
from mavsid.reasons import Reason, group, injected_nothing

__all__ = [
    "AXES",
    "ScanOptions",
    "WindowReport",
    "find_segments",
    "format_reports",
    "select_segments",
]


@dataclass(frozen=True)
class WindowReport:
    """One window on one axis: where, how good, kept or not and why.

    ``start_s``/``stop_s`` are the first and last sample times (log clock); ``i0``/``i1``
    the ``[start, stop)`` sample indices into the FlightData. ``checks`` are the gates a
    rejected window failed, as values; ``reasons`` the sentences made from them (or why it
    was kept), then notes (the SYSTEMID run's settings, a merge). ``sysid`` is the SYSTEMID
    run a ``"sysid"`` window lies in, ``axis_from_data`` the axis its input shows when that
    differs from the run's ``SID_AXIS``; ``merged_windows`` how many overlapping scan windows
    a kept window was merged from (0: not merged).
    """

    axis: str
    start_s: float
    stop_s: float
    score: float
    kept: bool
    source: str
    reasons: tuple[str, ...]
    i0: int
    i1: int
    metrics: Mapping[str, float] = field(default_factory=dict)
    checks: tuple[Reason, ...] = ()
    sysid: SysidRun | None = None
    axis_from_data: str | None = None
    merged_windows: int = 0

    @property
    def meta(self) -> dict[str, object]:
        """The window's SYSTEMID run (``sid_axis injection sysid``, its settings, and
        ``axis_from_data``) or merge (``merged_windows``) as JSON; empty for others."""
        out: dict[str, object] = {}
        if self.sysid is not None:
            sid = self.sysid.sid_axis
            out.update(sid_axis=sid, injection=sid_axis(sid)[1], sysid=self.sysid.settings())
            if self.axis_from_data is not None:
                out["axis_from_data"] = self.axis_from_data
        if self.merged_windows:
            out["merged_windows"] = self.merged_windows
        return out

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dict (``axis start_s stop_s score kept source reasons reason_kinds
        checks metrics meta``): ``reasons`` the sentences, ``checks`` the gates failed as
        :meth:`Reason.to_dict <mavsid.reasons.Reason.to_dict>`."""
        return {
            "axis": self.axis,
            "start_s": round(self.start_s, 6),
            "stop_s": round(self.stop_s, 6),
            "score": _json_float(self.score),
            "kept": bool(self.kept),
            "source": self.source,
            "reasons": list(self.reasons),
            "reason_kinds": [r.kind for r in self.checks],
            "checks": [r.to_dict() for r in self.checks],
            "metrics": {k: _json_float(v) for k, v in self.metrics.items()},
            "meta": self.meta,
        }


def _json_float(x: float) -> float | None:
    return round(float(x), 6) if math.isfinite(x) else None


def _report(ax: AxisSignals, fd: FlightData, i0: int, i1: int, opts: ScanOptions, air: np.ndarray,
            source: str, run: SysidRun | None = None,
            stats: Mapping[str, Any] | None = None) -> WindowReport:
    band = None
    if run is not None and run.f_start_hz is not None and run.f_stop_hz is not None:
        band = (float(run.f_start_hz), float(run.f_stop_hz))
    st = window_stats(ax, fd, air, opts, [i0], i1 - i0)[0] if stats is None else stats
    m = metrics(ax, fd, i0, i1, opts, band, st)
    checks = tuple(gates(ax, fd, i0, i1, m, opts, st, source == "scan"))
    kept = not checks
    return WindowReport(
        ax.name, float(fd.time_s[i0]), float(fd.time_s[i1 - 1]), score(m), kept, source,
        (kept_reason(ax, m),) if kept else rejected(checks), i0, i1, m, checks, run,
    )


def _block_parts(fd: FlightData, t0: float, t1: float) -> list[tuple[int, int]]:
    """``[i0, i1)`` pieces of the time span ``[t0, t1]``, one per block it touches."""
    out = []
    for a, b in fd.blocks:
        i0 = int(np.searchsorted(fd.time_s[a:b], t0, side="left")) + a
        i1 = int(np.searchsorted(fd.time_s[a:b], t1, side="right")) + a
        if i1 - i0 >= 2:
            out.append((i0, i1))
    return out


def _sysid_windows(fd: FlightData, axes: Sequence[str], axes_cache: Mapping[str, AxisSignals],
                   opts: ScanOptions, air: np.ndarray) -> list[WindowReport]:
    out: list[WindowReport] = []
    for run in fd.sysid_runs:
        sid = run.sid_axis
        name, injection = sid_axis(sid)
        from_data: str | None = None
        notes: list[str] = []
        if run.settings_from == "PARAM_VALUE" and name in AXES:
            found = _excited_axis(fd, run, opts, air)
            if found is not None and found != name:
                notes.append(
                    f"SID_AXIS {sid} ({name}) comes from a parameter message sent before the "
                    f"run, but only the {found} input is excited: taken as a {found} run"
                )
                name = from_data = found
        if name not in AXES:
            if axes == AXES:  # only when every axis was asked for
                off = (Reason("not_attitude_axis", {"sid_axis": float(sid)},
                              {"axis": name, "injection": injection}),)
                for i0, i1 in _block_parts(fd, run.start_s, run.stop_s):
                    out.append(WindowReport(
                        name, float(fd.time_s[i0]), float(fd.time_s[i1 - 1]), float("nan"),
                        False, "sysid", rejected(off), i0, i1, {}, off, run, from_data))
            continue
        if name not in axes:
            continue
        if not run.injected:  # (one line: the gates would only say so in many words)
            nothing = (injected_nothing(run),)
            for i0, i1 in _block_parts(fd, run.start_s, run.stop_s):
                out.append(WindowReport(
                    name, float(fd.time_s[i0]), float(fd.time_s[i1 - 1]), float("nan"),
                    False, "sysid", rejected(nothing), i0, i1, {}, nothing, run, from_data))
            continue
        nan = float("nan")
        for i0, i1 in _block_parts(fd, run.start_s, run.stop_s):
            rep = replace(_report(axes_cache[name], fd, i0, i1, opts, air, "sysid", run),
                          axis_from_data=from_data)
            mag = nan if run.magnitude is None else run.magnitude
            note = (f"SYSTEMID {injection} {name} chirp, SID_AXIS {sid}, magnitude {mag:g}, "
                    f"{nan if run.f_start_hz is None else run.f_start_hz:g}–"
                    f"{nan if run.f_stop_hz is None else run.f_stop_hz:g} Hz")
            if injection in SID_IDENTIFIES:
                note += f": identifies {SID_IDENTIFIES[injection]}"
            out.append(replace(rep, reasons=(*rep.reasons, note, *notes)))
    return out


def _excited_axis(fd: FlightData, run: SysidRun, opts: ScanOptions,
                  air: np.ndarray) -> str | None:
    """The one attitude axis whose input passes the power gate during a run, if exactly one."""
    parts = _block_parts(fd, run.start_s, run.stop_s)
    excited = []
    for a in AXES:
        ax = axis_signals(fd, a, opts, air)
        if ax.u_hp is None or not parts:
            continue
        rms = math.sqrt(sum(float(np.sum(ax.u_hp[i0:i1] ** 2)) for i0, i1 in parts)
                        / sum(i1 - i0 for i0, i1 in parts))
        if rms >= opts.power_ratio * ax.floor:
            excited.append(a)
    return excited[0] if len(excited) == 1 else None


def _trim(ax: AxisSignals, fd: FlightData, i0: int, i1: int, opts: ScanOptions) -> tuple[int, int]:
    """Drop the quiet head and tail of a merged window.

    An end is trimmed only when its first (last) 0.5 s is quiet (input RMS below the power
    gate, ``power_ratio`` × noise floor); the trimmed end is where the input, smoothed over
    50 ms, first departs from its median over that quiet 0.5 s by more than the gate.
    """
    assert ax.u is not None and ax.u_hp is not None
    n = max(3, round(0.5 / fd.dt))
    if i1 - i0 < 3 * n:
        return i0, i1
    u, hp = ax.u[i0:i1], ax.u_hp[i0:i1]
    k = max(1, round(0.05 / fd.dt))
    thr = opts.power_ratio * ax.floor
    a, b = 0, u.size
    if np.sqrt(np.mean(hp[:n] ** 2)) < thr:
        head = moving_mean(np.abs(u - np.median(u[:n])), k) > thr
        a = int(np.argmax(head)) if head.any() else 0
    if np.sqrt(np.mean(hp[-n:] ** 2)) < thr:
        tail = moving_mean(np.abs(u - np.median(u[-n:])), k) > thr
        b = u.size - int(np.argmax(tail[::-1])) if tail.any() else u.size
    return (i0 + a, i0 + b) if b - a >= n else (i0, i1)


#: windows measured in one call of :func:`window_stats` (bounds the transforms kept: ~4 MB)
_BATCH = 64


def _scan_windows(fd: FlightData, ax: AxisSignals, opts: ScanOptions, air: np.ndarray,
                  exclude: Sequence[tuple[int, int]]) -> list[WindowReport]:
    win = max(8, round(opts.window_s / fd.dt))
    step = max(1, round(opts.step / fd.dt))
    reports: list[WindowReport] = []
    for a, b in fd.blocks:
        a, b = int(a), int(b)
        if b - a < win:
            starts = [a] if b - a >= 8 else []
        else:
            starts = list(range(a, b - win + 1, step))
            if starts[-1] + win < b:
                starts.append(b - win)
        starts = [s for s in starts if not any(s < x1 and x0 < min(b, s + win)
                                               for x0, x1 in exclude)]
        if b - a < win:  # one window, shorter
            reports += [_report(ax, fd, s, b, opts, air, "scan") for s in starts]
            continue
        for k in range(0, len(starts), _BATCH):
            batch = starts[k : k + _BATCH]
            for s, st in zip(batch, window_stats(ax, fd, air, opts, batch, win), strict=True):
                reports.append(_report(ax, fd, s, s + win, opts, air, "scan", None, st))
    return _merge(fd, ax, reports, opts, air)


def _merge(fd: FlightData, ax: AxisSignals, reports: list[WindowReport], opts: ScanOptions,
           air: np.ndarray) -> list[WindowReport]:
    """Merge runs of overlapping kept windows (within one block) and trim their quiet ends."""
    out: list[WindowReport] = []
    run: list[WindowReport] = []

    def flush() -> None:
        if not run:
            return
        i0, i1 = run[0].i0, max(r.i1 for r in run)
        j0, j1 = _trim(ax, fd, i0, i1, opts)
        merged = replace(_report(ax, fd, j0, j1, opts, air, "scan"), merged_windows=len(run))
        if merged.kept:
            out.append(replace(merged, reasons=(
                *merged.reasons,
                f"merged from {len(run)} overlapping {opts.window_s:g}-s windows"
                + (f", quiet ends trimmed ({fd.time_s[i0]:.2f}–{fd.time_s[i1 - 1]:.2f} s before)"
                   if (j0, j1) != (i0, i1) else ""),
            )))
        else:  # the whole fails where its parts passed: keep the parts as they were
            out.extend(run)
        run.clear()

    block_of = np.searchsorted(fd.blocks[:, 1], [r.i0 for r in reports], side="right")
    for r, blk in zip(reports, block_of, strict=True):
        if r.kept and run and r.i0 <= run[-1].i1 and blk == np.searchsorted(
                fd.blocks[:, 1], run[-1].i0, side="right"):
            run.append(r)
            continue
        flush()
        if r.kept:
            run.append(r)
        else:
            out.append(r)
    flush()
    return out


def find_segments(
    flight: FlightData,
    axis: str | Sequence[str] | None = None,
    *,
    scan: bool | None = None,
    options: ScanOptions | None = None,
) -> list[WindowReport]:
    """Every window considered, kept or rejected, with reasons.

    Parameters
    ----------
    flight : FlightData
    axis : str or sequence of str, optional
        ``"roll"``, ``"pitch"``, ``"yaw"``; default all three.
    scan : bool, optional
        Scan sliding windows: default only for axes without a SYSTEMID run; True for all
        axes (outside their SYSTEMID runs), False never.
    options : ScanOptions, optional

    Returns
    -------
    list of WindowReport
        Sorted by axis (roll, pitch, yaw, then others), then start time.

    Raises
    ------
    ConfigError
        Unknown axis.
    """
    opts = options or ScanOptions()
    axes = AXES if axis is None else ((axis,) if isinstance(axis, str) else tuple(axis))
    for a in axes:
        if a not in AXES:
            raise ConfigError(f"unknown axis {a!r} (choose from {', '.join(AXES)})")
    air = airborne(flight)
    cache = {a: axis_signals(flight, a, opts, air) for a in axes}
    reports = _sysid_windows(flight, axes, cache, opts, air)
    for a in axes:
        mine = [(r.i0, r.i1) for r in reports if r.axis == a and r.source == "sysid"]
        if scan is False or (scan is None and mine):
            continue
        if cache[a].u is None or cache[a].y is None:
            n = flight.time_s.size
            missing = tuple(gates(cache[a], flight, 0, n, {}, opts, {}, False, False))
            reports.append(WindowReport(a, float(flight.time_s[0]), float(flight.time_s[-1]),
                                        0.0, False, "scan", rejected(missing), 0, n, {},
                                        missing))
            continue
        found = _scan_windows(flight, cache[a], opts, air, mine)
        if not found and not mine:
            n = flight.time_s.size
            longest = int(np.max(flight.blocks[:, 1] - flight.blocks[:, 0]))
            little = (Reason("too_little_data", {"samples": float(longest),
                                                 "seconds": longest * flight.dt,
                                                 "need_samples": 8.0}),)
            found = [WindowReport(
                a, float(flight.time_s[0]), float(flight.time_s[-1]), 0.0, False, "scan",
                rejected(little), 0, n, {}, little)]
        reports += found
    order = {a: i for i, a in enumerate(AXES)}
    reports.sort(key=lambda r: (order.get(r.axis, len(AXES)), r.start_s))
    return reports


def select_segments(
    flight: FlightData,
    axis: str | Sequence[str] | None = None,
    reports: Sequence[WindowReport] | None = None,
    **kwargs: Any,
) -> list[Segment]:
    """The kept windows as :class:`~mavsid.data.Segment` objects for the estimators.

    Each segment carries every state and input column of the flight, the log's parameters
    (``params``) and, for SYSTEMID runs, the run (``sysid``); ``meta`` the preset and the
    window's metrics.

    Parameters
    ----------
    reports : sequence of WindowReport, optional
        From :func:`find_segments` (computed when omitted, with ``axis`` and ``kwargs``).
    """
    reps = find_segments(flight, axis, **kwargs) if reports is None else reports
    out = []
    for r in reps:
        if not r.kept:
            continue
        meta = {"preset": flight.preset, "metrics": dict(r.metrics)}
        out.append(Segment(
            time_s=flight.time_s[r.i0:r.i1].copy(),
            states=flight.states[r.i0:r.i1].copy(),
            inputs=flight.inputs[r.i0:r.i1].copy(),
            state_names=flight.state_names,
            input_names=flight.input_names,
            dt=flight.dt,
            axis=r.axis,
            source=r.source,
            score=r.score,
            log=flight.source.path,
            reasons=r.reasons,
            meta=meta,
            params=dict(flight.params),
            sysid=r.sysid,
        ))
    return out


def format_reports(reports: Sequence[WindowReport], show_all: bool = False) -> str:
    """Human-readable table: SYSTEMID and kept windows in full, rejected scan windows
    grouped by the kind of their first failed gate (every window with ``show_all``).

    Examples
    --------
    >>> gate = Reason("input_below_floor", {"rms": 2e-4, "need_ratio": 5.0, "floor": 1e-3},
    ...               {"input": "u_roll"})
    >>> r = WindowReport("roll", 1.0, 6.0, 0.1, False, "scan", ("rejected: " + gate.message,),
    ...                  0, 9, checks=(gate,))
    >>> print(format_reports([r]))
    axis    start_s   stop_s  score  kept  source  reasons
    roll: 1 scan window(s) rejected: 1× input RMS below noise floor
    """
    lines = [f"{'axis':6s} {'start_s':>8s} {'stop_s':>8s} {'score':>6s}  kept  source  reasons"]
    hidden: dict[str, list[WindowReport]] = {}
    for r in reports:
        if r.kept or r.source == "sysid" or show_all or not r.checks:
            score = f"{r.score:6.2f}" if math.isfinite(r.score) else "     -"
            lines.append(
                f"{r.axis:6s} {r.start_s:8.2f} {r.stop_s:8.2f} {score}  "
                f"{'yes' if r.kept else 'no':4s}  {r.source:6s}  {r.reasons[0]}"
            )
            lines += [f"{'':47s}{x}" for x in r.reasons[1:]]
        else:
            hidden.setdefault(r.axis, []).append(r)
    for axis, windows in hidden.items():
        detail = ", ".join(group([r.checks[0] for r in windows]))
        lines.append(f"{axis}: {len(windows)} scan window(s) rejected: {detail}")
    return "\n".join(lines)
