"""Log a fit to rerun: data, predictions, segments, attitude, fit and frequency plots.

Every function takes an explicit :class:`rerun.RecordingStream`; nothing touches rerun's
global recording. Time series are sent whole with ``send_columns`` on the timeline
``time_ms`` (:data:`mavsid.viz.series.TIMELINE`: the log's own clock, milliseconds since
boot; rerun's automatic wall-clock ``log_time`` and ``log_tick`` timelines are switched
off). Entity layout:

====================================  ==================================================
entity                                content
====================================  ==================================================
``flight/<kind>/<name>``              every state and input of the flight by kind (``KINDS``:
                                      attitude, heading, rates, inputs, thrust; SI units)
``axes/<axis>/<state>/measured``      measured output on the validation segments
``axes/<axis>/<state>/one_step``      one-step-ahead prediction
``axes/<axis>/<state>/free_run``      free-run simulation (measured inputs only, the
                                      segment's own trim: :func:`mavsid.validation.segment_trim`)
``axes/<axis>/inputs/<name>``         the model's inputs on the validation segments
``segments/<axis>``                   text log: each segment's start and end, role, reasons
``segments/modes``                    text log: each flight-mode change, with the mode's name
``world/data``                        measured attitude (3-D transform, FRD body in NED)
``world/model/<axis>/<i>``            attitude with the model's free-run rate in place
                                      of the measured one, on validation segment i
                                      (roll 1.5 m right of the data, pitch 3 m, yaw 4.5 m)
``fit/<axis>``                        2-D plot: fit % against prediction horizon
``frequency/<axis>``                  2-D Bode plot: magnitude (dB) and phase (deg), measured vs
                                      model, and coherence, with legends
``bands/...``                         flight modes, airborne time, each axis's training,
                                      validation and rejected windows as bands
``summary``                           markdown table of parameters and fit %
====================================  ==================================================

Between segments every predicted series gets one NaN sample so that the viewer does not
draw a line across the gap. :func:`blueprint` lays all of this out; :func:`save_rrd` writes a
whole :class:`~mavsid.pipeline.FitResult` to an ``.rrd`` file.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from mavsid.axes import AXES, INPUT_OF, RATE_OF, RATES, STATE_UNITS, THRUST_INPUT
from mavsid.data import FlightData, Segment, decimate
from mavsid.estimators.select import is_lag_filter
from mavsid.numerics.rotations import euler_to_quat
from mavsid.physical import parameter_order, physical_rows
from mavsid.validation import FrequencyResponse, Validation, horizon_label
from mavsid.viz.series import (
    AXIS_COLOURS,
    COHERENCE,
    FREE_RUN,
    INPUT,
    MEASURED,
    ONE_STEP,
    PANEL_GAP,
    RANGE_MARGIN,
    TARGET,
    X_LABEL_GAP,
    format_number,
    joined,
    nice_range,
    plot2d,
    plot_frame,
    rrd_file,
    send_series,
    set_time,
    style_series,
    time_column,
    time_panel,
    time_view,
)

if TYPE_CHECKING:
    from mavsid.excitation import WindowReport
    from mavsid.pipeline_results import AxisFit, FitResult

__all__ = [
    "KINDS",
    "MAX_FLIGHT_POINTS",
    "Targets",
    "blueprint",
    "bode_note",
    "flight_ranges",
    "focus_span",
    "log_attitude",
    "log_bands",
    "log_fit_result",
    "log_flight",
    "log_flight_windows",
    "log_rate_targets",
    "log_segments",
    "log_summary",
    "log_validation",
    "merged_spans",
    "model_attitude",
    "rate_targets",
    "result_blueprint",
    "result_focus",
    "save_rrd",
    "series_kind",
    "target_axes",
    "value_ranges",
    "value_spans",
]

# --------------------------------------------------------------------------- flight data


#: The flight's series by kind, each on its own plot so that no scale flattens another
#: (yaw wraps over 6 rad, thrust sits near 0.4 while the other inputs are near 0).
KINDS: dict[str, tuple[str, ...]] = {
    "attitude": ("roll", "pitch"),
    "heading": ("yaw",),
    "rates": RATES,
    "inputs": tuple(INPUT_OF.values()),
    "thrust": (THRUST_INPUT,),
}
#: One colour per series: roll-like red, pitch-like green, yaw-like blue, thrust grey.
SERIES_COLOURS: dict[str, tuple[int, int, int]] = {
    **{name: AXIS_COLOURS[a] for a in AXES for name in (a, RATE_OF[a], INPUT_OF[a])},
    THRUST_INPUT: MEASURED,
}


def series_kind(name: str) -> str:
    return next((k for k, names in KINDS.items() if name in names), "other")


#: Most samples a flight's series keeps outside the segments (a plot a few thousand pixels
#: wide cannot show more; the segments keep every sample)
MAX_FLIGHT_POINTS = 20_000


def log_flight(rec: rr.RecordingStream, flight: FlightData, prefix: str = "flight",
               keep_spans: Iterable[tuple[float, float]]
               | Mapping[str, Iterable[tuple[float, float]]] = (), tag: str = "") -> None:
    """Every state and input of ``flight`` as time series, grouped by kind (``KINDS``: one
    plot each, one colour per series, names with units), and its attitude in 3-D.

    A long flight is decimated (:func:`decimate`) to about :data:`MAX_FLIGHT_POINTS` samples
    per series, its envelope kept, except inside ``keep_spans`` (the segments, seconds),
    which keep every sample: of every series, or, given a mapping from series name to spans,
    of that series in its own spans (a segment's own states and inputs). ``tag`` (one
    flight of several) goes into every entity path and series name, so that flights whose
    clocks overlap stay apart."""
    t = flight.time_s
    blocks = flight.blocks if len(flight.blocks) else np.array([[0, len(t)]])
    per_series = isinstance(keep_spans, Mapping)
    spans_of = dict(keep_spans) if isinstance(keep_spans, Mapping) else {}
    masks: dict[tuple[tuple[float, float], ...], np.ndarray] = {}

    def kept(spans: Iterable[tuple[float, float]]) -> np.ndarray:
        key = tuple(sorted((float(a), float(b)) for a, b in spans))
        if key not in masks:
            m = np.zeros(len(t), bool)
            for a, b in key:
                m[np.searchsorted(t, a):np.searchsorted(t, b, side="right")] = True
            masks[key] = m
        return masks[key]

    every = None if per_series else kept(keep_spans)  # type: ignore[arg-type]
    budget = MAX_FLIGHT_POINTS / max(len(t), 1)
    for names, data, units in ((flight.state_names, flight.states, flight.state_units),
                               (flight.input_names, flight.inputs, flight.input_units)):
        for j, name in enumerate(names):
            path = f"{prefix}/{series_kind(name)}/{name}" + (f"/{tag}" if tag else "")
            style_series(rec, path, SERIES_COLOURS.get(name, INPUT),
                   f"{name} [{units[j]}]" + (f" {tag}" if tag else ""))
            keep = every if every is not None else kept(spans_of.get(name, ()))
            parts = []
            for a, b in blocks:
                i = a + decimate(data[a:b, j], max(100, int(budget * (b - a))), keep[a:b])
                parts.append((t[i], data[i, j]))
            tt, vv = joined(parts)
            send_series(rec, path, tt, vv)
    if all(n in flight.state_names for n in AXES):
        idx = [flight.state_names.index(n) for n in AXES]
        log_attitude(rec, "world/data" + (f"/{tag}" if tag else ""), t, flight.states[:, idx],
                     colour=MEASURED)


def log_attitude(
    rec: rr.RecordingStream,
    path: str,
    time_s: np.ndarray,
    euler: np.ndarray,
    *,
    colour: Sequence[int] = MEASURED,
    offset_m: Sequence[float] = (0.0, 0.0, 0.0),
    max_rate_hz: float = 50.0,
    clear_after: bool = False,
) -> None:
    """Attitude ``(roll, pitch, yaw)`` [rad] as a 3-D transform carrying a small airframe.

    The airframe is drawn once (in body axes: x forward, y right, z down); its transform is
    sent as a column, decimated to at most ``max_rate_hz``. ``clear_after`` removes it
    after the last sample (a model's attitude exists only on its segment).
    """
    t_end = float(np.asarray(time_s, dtype=float)[-1]) if len(time_s) else 0.0
    time_s = np.asarray(time_s, dtype=float)
    if len(time_s) > 1:
        step = max(1, round(1.0 / (max_rate_hz * float(np.median(np.diff(time_s))))))
        time_s, euler = time_s[::step], euler[::step]
    quat = euler_to_quat(np.asarray(euler, dtype=float))[:, [1, 2, 3, 0]]  # (x, y, z, w)
    rr.send_columns(
        path,
        indexes=[time_column(time_s)],
        columns=rr.Transform3D.columns(
            quaternion=quat, translation=np.tile(np.asarray(offset_m, float), (len(quat), 1))
        ),
        recording=rec,
    )
    arm = 0.5
    airframe = rr.Arrows3D(
        vectors=[[arm, 0, 0], [-arm, 0, 0], [0, arm, 0], [0, -arm, 0], [0, 0, 0.25]],
        colors=[(255, 60, 60), colour, colour, colour, (60, 120, 255)],
        radii=0.02,
    )
    if not clear_after:
        rec.log(f"{path}/airframe", airframe, static=True)
        return
    set_time(rec, float(time_s[0]))
    rec.log(f"{path}/airframe", airframe)
    set_time(rec, t_end + 1e-3)
    rec.log(path, rr.Clear(recursive=True))
    rec.reset_time()


def model_attitude(segment: Segment, rate_name: str, rate_hat: np.ndarray) -> np.ndarray | None:
    """Integrate the Euler kinematics from the segment's first attitude, with the model's
    prediction of ``rate_name`` in place of the measured rate (the others measured)."""
    names = segment.state_names
    if not all(n in names for n in ("roll", "pitch", "yaw", "p", "q", "r")):
        return None
    rates = segment.states[:, [names.index(n) for n in ("p", "q", "r")]].copy()
    rates[:, "pqr".index(rate_name)] = np.where(
        np.isfinite(rate_hat), rate_hat, rates[:, "pqr".index(rate_name)]
    )
    phi, theta, psi = (float(v) for v in
                       segment.states[0, [names.index(n) for n in AXES]])
    dt = float(segment.dt)
    # roll and pitch step by step (each step needs the last), in Python floats: a numpy
    # call per step costs 10×; yaw feeds back into neither, so its steps follow from them
    # at once and add up in order (np.add.accumulate: the same sums as the loop's), a
    # quarter of the time of all three in the loop (0.11 -> 0.03 s, the SITL flight's)
    sin, cos, tan = math.sin, math.cos, math.tan
    phis, thetas = [phi], [theta]
    ps, qs, rs = rates[:-1].T.tolist()
    for p, q, r in zip(ps, qs, rs, strict=True):
        s, c = sin(phi), cos(phi)
        phi, theta = phi + dt * (p + (q * s + r * c) * tan(theta)), theta + dt * (q * c - r * s)
        phis.append(phi)
        thetas.append(theta)
    roll, pitch = np.array(phis), np.array(thetas)
    ct = np.cos(pitch[:-1])
    ct = np.where(np.abs(ct) > 1e-6, ct, 1e-6)
    turn = rates[:-1, 1] * np.sin(roll[:-1]) + rates[:-1, 2] * np.cos(roll[:-1])
    yaw = np.add.accumulate(np.r_[psi, dt * (turn / ct)])
    return np.column_stack([roll, pitch, yaw])


# --------------------------------------------------------------------------- segments


def log_segments(
    rec: rr.RecordingStream,
    axis: str,
    train: Sequence[Segment],
    held_out: Sequence[Segment],
    windows: Sequence[WindowReport] = (),
) -> None:
    """Segment boundaries as text-log entries with their role and reasons.

    ``windows`` (from :func:`mavsid.excitation.find_segments`) adds every rejected window
    with the reasons it was rejected (level ``WARN``).
    """
    rows: list[tuple[float, str, str]] = []
    for role, segs in (("train", train), ("validation", held_out)):
        for seg in segs:
            why = "; ".join(seg.reasons) if seg.reasons else seg.source
            rows.append(
                (seg.start_s, f"{axis} {role} segment starts ({seg.source}): {why}", "INFO")
            )
            rows.append((seg.stop_s, f"{axis} {role} segment ends", "DEBUG"))
    for w in windows:
        why = "; ".join(w.reasons)
        span = f"{axis} {w.source} window {w.start_s:.2f}-{w.stop_s:.2f} s"
        if not w.kept:
            rows.append((w.start_s, f"{span} rejected: {why}", "WARN"))
        elif not train and not held_out:
            rows.append((w.start_s, f"{span} kept: {why}", "INFO"))
            rows.append((w.stop_s, f"{axis} {w.source} window ends", "DEBUG"))
    if not rows:
        return
    rows.sort(key=lambda r: r[0])
    rr.send_columns(
        f"segments/{axis}",
        indexes=[time_column(np.array([r[0] for r in rows]))],
        columns=rr.TextLog.columns(text=[r[1] for r in rows], level=[r[2] for r in rows]),
        recording=rec,
    )


# --------------------------------------------------------------------------- bands

#: Band levels on the ``bands`` plot (top to bottom): one row per axis, then airborne, modes.
#: The bands' rows (y values) and the bands plot's y range: rows, not values, so the range
#: lies between two whole numbers, 0.15 apart, where rerun labels no tick at a band plot's
#: height (from 0 ... 4 it labelled a "0", the modes' row).
BAND_LEVELS = {"roll": 0.8, "pitch": 0.65, "yaw": 0.5, "airborne": 0.35, "mode": 0.2}
BAND_RANGE = (0.05, 0.95)
BAND_WIDTH = 6.0
REJECTED = (110, 110, 110)


def merged_spans(spans: Iterable[tuple[float, float]]) -> list[tuple[float, float]]:
    """Sorted spans with the overlapping ones joined.

    >>> merged_spans([(3.0, 4.0), (0.0, 1.0), (0.5, 2.0)])
    [(0.0, 2.0), (3.0, 4.0)]
    """
    out: list[tuple[float, float]] = []
    for a, b in sorted((float(a), float(b)) for a, b in spans):
        if out and a <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return out


def _band(rec: rr.RecordingStream, path: str, spans: Iterable[tuple[float, float]],
          level: float, colour: Sequence[int], name: str) -> None:
    """Spans of time as one thick horizontal bar per span at ``level`` (a Gantt row)."""
    parts = [(np.array([a, b]), np.array([level, level])) for a, b in merged_spans(spans) if b > a]
    if not parts:
        return
    rec.log(path, rr.SeriesLines(colors=[colour], names=[name], widths=[BAND_WIDTH]),
            static=True)
    send_series(rec, path, *joined(parts))


def value_spans(time_s: np.ndarray, values: np.ndarray) -> dict[int, list[tuple[float, float]]]:
    """Per value, the time spans over which an integer series holds it."""
    out: dict[int, list[tuple[float, float]]] = {}
    if len(values) == 0:
        return out
    edges = np.flatnonzero(np.diff(values)) + 1
    starts = np.r_[0, edges]
    stops = np.r_[edges, len(values)]
    for a, b in zip(starts, stops, strict=True):
        end = time_s[b] if b < len(time_s) else time_s[-1]
        out.setdefault(int(values[a]), []).append((float(time_s[a]), float(end)))
    return out


def _mode_colour(mode: int) -> tuple[int, int, int]:
    """A stable colour per flight-mode number, away from the series' red/green/blue."""
    palette = [(240, 200, 60), (60, 200, 200), (220, 120, 200), (250, 140, 90),
               (150, 150, 250), (170, 220, 120), (200, 170, 130), (120, 180, 240)]
    return palette[mode % len(palette)]


def log_bands(
    rec: rr.RecordingStream,
    flight: FlightData,
    segments: Mapping[str, tuple[Sequence[Segment], Sequence[Segment]]] = {},
    windows: Mapping[str, Sequence[WindowReport]] = {},
    tag: str = "",
) -> None:
    """Flight modes, airborne time, and per axis the training, validation and rejected
    windows as bands on one time plot (``bands/...``), its time axis linked to every other
    time plot so that they line up when zoomed.

    ``segments`` maps an axis to its ``(train, held_out)`` segments; ``windows`` adds the
    windows the excitation search kept (when no segments are given) or rejected.
    """
    t = flight.time_s
    if len(t) == 0:
        return
    sub = f"/{tag}" if tag else ""  # one flight of several: its own entities
    names = flight.mode_names
    mode = flight.flags.get("mode")
    if mode is not None and len(mode) == len(t):
        changes: list[tuple[float, str]] = []
        for m, spans in sorted(value_spans(t, np.asarray(mode)).items()):
            if m < 0:
                continue
            # a log's own text: the viewer's font has Latin glyphs only (others panic it)
            label = str(names.get(m) or m).encode("ascii", "replace").decode()
            _band(rec, f"bands/mode/{m}{sub}", spans, BAND_LEVELS["mode"], _mode_colour(m),
                  f"mode {label}")
            changes += [(a, f"mode {label} ({m})" + (f" {tag}" if tag else "")) for a, _ in spans]
        if changes:  # (the bands have no legend: it would cover them)
            changes.sort()
            rr.send_columns(f"segments/modes{sub}",
                            indexes=[time_column(np.array([a for a, _ in changes]))],
                            columns=rr.TextLog.columns(text=[c for _, c in changes],
                                                       level=["INFO"] * len(changes)),
                            recording=rec)
    air = flight.flags.get("airborne")
    if air is not None and len(air) == len(t):
        spans = value_spans(t, np.asarray(air, dtype=np.int64)).get(1, [])
        _band(rec, f"bands/airborne{sub}", spans, BAND_LEVELS["airborne"], MEASURED, "airborne")
    for axis in dict.fromkeys([*segments, *windows]):
        level = BAND_LEVELS.get(axis, 0.9)  # (an axis without a row: above them)
        colour = AXIS_COLOURS.get(axis, FREE_RUN)
        train, held_out = segments.get(axis, ((), ()))
        dim = tuple(int(c * 0.55) for c in colour)
        _band(rec, f"bands/{axis}/train{sub}", [(s.start_s, s.stop_s) for s in train],
              level, dim, f"{axis} training")
        _band(rec, f"bands/{axis}/validation{sub}", [(s.start_s, s.stop_s) for s in held_out],
              level, colour, f"{axis} validation")
        reports = windows.get(axis, ())
        if not train and not held_out:
            _band(rec, f"bands/{axis}/kept{sub}",
                  [(w.start_s, w.stop_s) for w in reports if w.kept],
                  level, colour, f"{axis} kept window")
        _band(rec, f"bands/{axis}/rejected{sub}",
              [(w.start_s, w.stop_s) for w in reports if not w.kept],
              level - 0.3, REJECTED, f"{axis} rejected window")


def result_focus(result: FitResult) -> tuple[float, float] | None:
    """:func:`focus_span` of a fit's segments."""
    return focus_span({a: (f.train, f.held_out) for a, f in result.axes.items()})


def focus_span(
    segments: Mapping[str, tuple[Sequence[Segment], Sequence[Segment]]] = {},
    windows: Mapping[str, Sequence[WindowReport]] = {},
) -> tuple[float, float] | None:
    """Where the viewer should open: the first validation segment, else the first training
    segment, else the first kept window (``None`` when there is none)."""
    for pick in (1, 0):
        spans = [(s.start_s, s.stop_s) for tr_ho in segments.values() for s in tr_ho[pick]]
        if spans:
            return min(spans)
    kept = [(w.start_s, w.stop_s) for ws in windows.values() for w in ws if w.kept]
    return min(kept) if kept else None


def _log_fit_plot(rec: rr.RecordingStream, axis: str, v: Validation) -> None:
    """Fit % against horizon per predicted state; free run drawn at twice the longest."""
    h = v.horizons_s
    xs = np.r_[h, 2.0 * h[-1]]
    series = []
    palette = [ONE_STEP, FREE_RUN, INPUT, COHERENCE]
    for j, state in enumerate(v.state_names):
        # a diverging model's fit % (-1e7) would ask for millions of ticks: floor at -100
        ys = np.clip(np.nan_to_num(np.r_[v.fit_vs_horizon[:, j], v.fit_free_run[j]],
                                   nan=-100.0), -100.0, 100.0)
        series.append((f"{state} fit", xs, ys, palette[j % len(palette)]))
    decades = 10.0 ** np.arange(np.floor(np.log10(h[0])), np.ceil(np.log10(xs[-1])) + 1)
    lo = np.nanmin([*(s[2] for s in series)]) if series else 0.0
    lo = float(min(0.0, np.floor(np.nan_to_num(lo, nan=0.0) / 20) * 20))
    plot2d(
        rec,
        f"fit/{axis}",
        series,
        xlog=True,
        x_ticks=decades,
        y_ticks=np.arange(lo, 101, 20),
        x_unit=" s",
        y_unit=" %",
        y_range=(lo, 100.0),
        legend=True,
    )
    note_y = 100.0 + 4 * X_LABEL_GAP  # (below the x tick labels: FIT_FRAME has room)
    rec.log(
        f"fit/{axis}/free_run_label",
        rr.Points2D([[150.0, note_y]], labels=["last point: free run"], show_labels=True,
                    radii=0.1),
        static=True,
    )


def _bode_bins(fr: FrequencyResponse) -> np.ndarray:
    """The frequencies of ``fr`` a Bode plot shows: those in the chirp's band."""
    band = fr.band_hz or (fr.freq_hz[1], fr.freq_hz[-1])
    return (fr.freq_hz >= band[0]) & (fr.freq_hz <= band[1])


def bode_note(fit: AxisFit) -> str | None:
    """Why ``fit`` has no Bode plot (:func:`log_validation` draws one per frequency response
    of its validation with two frequencies or more in the chirp's band), or None when it has
    one."""
    v = fit.validation
    if any(_bode_bins(fr).sum() >= 2 for fr in v.frequency):
        return None
    chirps = [s for s in fit.held_out if s.source == "sysid"]
    if not chirps:
        why = "no validation segment is a SYSTEMID run (a chirp): the Bode plot is measured on one"
    elif not v.frequency:
        why = (f"its {len(chirps)} SYSTEMID validation segment(s) are shorter than 1 s, too "
               "short for a frequency response")
    else:
        why = "the frequency response has fewer than two frequencies in the chirp's band"
    note = f"; against the injection: {fit.frequency_note}" if fit.frequency_note else ""
    return f"No Bode plot for {fit.axis}: {why}{note}."


def _log_frequency_plot(rec: rr.RecordingStream, axis: str, v: Validation) -> None:
    """Bode plot of measured and model response: magnitude (dB) on top, phase (deg) below
    it, coherence at the bottom, each with a legend."""
    for fr in v.frequency:
        sel = _bode_bins(fr)
        if sel.sum() < 2:
            continue
        f = fr.freq_hz[sel]

        def db(h: np.ndarray) -> np.ndarray:
            return np.clip(np.nan_to_num(20 * np.log10(np.abs(h) + 1e-12), nan=-200.0,
                                         posinf=200.0, neginf=-200.0), -200.0, 200.0)

        def deg(h: np.ndarray) -> np.ndarray:
            ok = np.isfinite(h)
            out = np.full(len(h), np.nan)
            if ok.any():
                out[ok] = np.degrees(np.unwrap(np.angle(h[ok])))
            return out

        mag, mod = db(fr.measured[sel]), db(fr.model[sel])
        ph, ph_mod = deg(fr.measured[sel]), deg(fr.model[sel])
        ticks = 10.0 ** np.arange(np.floor(np.log10(f[0])), np.ceil(np.log10(f[-1])) + 1)
        lo = float(np.floor(min(mag.min(), mod.min()) / 10) * 10)
        hi = float(np.ceil(max(mag.max(), mod.max()) / 10) * 10)
        both = np.r_[ph, ph_mod]
        both = both[np.isfinite(both)]
        p_lo = float(np.floor(both.min() / 90) * 90) if len(both) else -180.0
        p_hi = float(np.ceil(both.max() / 90) * 90) if len(both) else 0.0
        p_lo, p_hi = max(p_lo, -1080.0), min(max(p_hi, p_lo + 90.0), 1080.0)
        name = f"frequency/{axis}/{fr.output_name}_{fr.input_name}"
        plot2d(
            rec,
            f"{name}/magnitude",
            [("measured |H|", f, mag, MEASURED), ("model |H|", f, mod, FREE_RUN)],
            xlog=True,
            x_ticks=ticks,
            y_ticks=np.arange(lo, hi + 1, 10),
            x_unit=" Hz",
            y_unit=" dB",
            y_range=(lo, hi),
            legend=True,
        )
        step = 90.0 if p_hi - p_lo <= 360 else 180.0
        plot2d(
            rec,
            f"{name}/phase",
            [("measured phase", f, ph, MEASURED), ("model phase", f, ph_mod, FREE_RUN)],
            xlog=True,
            x_ticks=ticks,
            y_ticks=np.arange(p_lo, p_hi + 1, step),
            x_unit=" Hz",
            y_unit=" deg",
            origin_y=100.0 + PANEL_GAP,
            height=60.0,
            y_range=(p_lo, p_hi),
            legend=True,
        )
        plot2d(
            rec,
            f"{name}/coherence",
            [("coherence", f, fr.coherence[sel], COHERENCE)],
            xlog=True,
            x_ticks=ticks,
            y_ticks=(0.0, 0.5, 1.0),
            x_unit=" Hz",
            y_unit="",
            origin_y=160.0 + 2 * PANEL_GAP,
            height=40.0,
            y_range=(0.0, 1.0),
            legend=True,
        )


# --------------------------------------------------------------------------- validation


def log_validation(
    rec: rr.RecordingStream,
    axis: str,
    validation: Validation,
    segments: Sequence[Segment] = (),
    input_names: Sequence[str] = (),
) -> None:
    """Measured, one-step and free-run series, inputs, model attitude and the plots.

    Parameters
    ----------
    rec : rerun.RecordingStream
    axis : str
    validation : Validation
        From :func:`mavsid.validation.validate`.
    segments : sequence of Segment
        The held-out segments (same order as ``validation.segments``): their inputs are
        logged and, when they carry attitude and all body rates, the model's attitude.
    input_names : sequence of str
        Inputs to log (default the model's).
    """
    v = validation
    for j, state in enumerate(v.state_names):
        for kind, colour, pick in (
            ("measured", MEASURED, lambda s: s.measured),
            ("one_step", ONE_STEP, lambda s: s.one_step),
            ("free_run", FREE_RUN, lambda s: s.free_run),
        ):
            path = f"axes/{axis}/{state}/{kind}"
            unit = STATE_UNITS.get(state)
            style_series(rec, path, colour, f"{state} {kind.replace('_', '-')}"
                   + (f" [{unit}]" if unit else ""))
            t, y = joined((s.time_s, pick(s)[:, j]) for s in v.segments)
            send_series(rec, path, t, y)
    names = tuple(input_names) or v.input_names
    for name in names:
        parts = [
            (seg.time_s, seg.inputs[:, seg.input_names.index(name)])
            for seg in segments
            if name in seg.input_names
        ]
        if parts:
            path = f"axes/{axis}/inputs/{name}"
            style_series(rec, path, INPUT, name)
            send_series(rec, path, *joined(parts))
    rate = RATE_OF.get(axis, "")
    if rate in v.state_names and segments:
        j = v.state_names.index(rate)
        for i, (seg, sv) in enumerate(zip(segments, v.segments, strict=False)):
            att = model_attitude(seg, rate, sv.free_run[:, j])
            if att is not None:
                log_attitude(
                    rec,
                    f"world/model/{axis}/{i}",
                    seg.time_s,
                    att,
                    colour=AXIS_COLOURS.get(axis, FREE_RUN),
                    offset_m=(0.0, 1.5 * (1 + list(AXIS_COLOURS).index(axis)), 0.0)
                    if axis in AXIS_COLOURS else (0.0, 1.5, 0.0),
                    clear_after=True,
                )
    _log_fit_plot(rec, axis, v)
    _log_frequency_plot(rec, axis, v)


def _gains_markdown(entry: Mapping[str, Any]) -> list[str]:
    """An axis's suggested gains (current, suggested, ratio) or why none, in markdown."""
    from mavsid.cli_format import gain_table

    if entry.get("gains"):
        rows = gain_table(entry["gains"])
        out = ["| " + " | ".join(rows[0]) + " |", "|---" * len(rows[0]) + "|"]
        out += ["| " + " | ".join(r) + " |" for r in rows[1:]]
        note = entry.get("suggested_note")
        return out + (["", str(note)] if note else []) + [""]
    return [f"no gains: {entry.get('no_gains_reason') or entry.get('error', '–')}", ""]


def log_summary(rec: rr.RecordingStream, fits: Sequence[AxisFit],
                gains: Mapping[str, Mapping[str, Any]] | None = None) -> None:
    """A markdown document: per axis the verdict, the gains (``gains``: the per-axis entries
    of :func:`mavsid.loop.tune.tune`, when worked out), the model structure (delay, lag,
    filters), every parameter ± σ with its unit, and fit % on validation data."""
    lines = ["# mavsid fit", ""]
    for fit in fits:
        m, v = fit.model, fit.validation
        lines += [f"## {fit.axis}", ""]
        if fit.verdict is not None:
            lines += [f"**{fit.verdict.level}**: " + "; ".join(fit.verdict.reasons), ""]
        if gains and fit.axis in gains:
            lines += _gains_markdown(gains[fit.axis])
        prov = dict(getattr(m, "provenance", {}) or {})
        lag = prov.get("lag_s")
        filters = ", ".join(f"{f.source} {f.cutoff_hz:g} Hz" for f in getattr(m, "filters", ())
                            if not is_lag_filter(f.source))
        lines += [f"{fit.output}′ from u_{fit.axis}: {1 / v.dt:.0f} Hz, delay "
                  f"{float(getattr(m, 'delay_s', 0.0) or 0.0) * 1e3:.1f} ms"
                  + (f", input lag {float(lag) * 1e3:.0f} ms"
                     if isinstance(lag, (int, float)) and lag > 0 else "")
                  + (f", {filters}" if filters else "") + f"; estimator {fit.estimator}", ""]
        # what a tuner reads first, then the continuous- and discrete-time coefficients
        lines += ["| physical parameter | value | σ | unit |", "|---|---|---|---|"]
        lines += [f"| {r.name} | {format_number(r.value)} | "
                  f"{'' if np.isnan(r.sigma) else format_number(r.sigma)} | {r.unit} |"
                  for r in physical_rows(fit)]
        lines += ["", "| parameter | value | σ | unit |", "|---|---|---|---|"]
        stderr = getattr(m, "stderr", {}) or {}
        units = getattr(m, "units", {}) or {}
        for k in parameter_order(m.params):
            lines.append(f"| {k} | {format_number(m.params[k])} | "
                         f"{format_number(stderr.get(k, np.nan))} | {units.get(k, '')} |")
        lines += ["", "| output | " + " | ".join(_fit_keys()) + " |", "|---" * 4 + "|"]
        for state in v.state_names:
            s = v.fit_summary(state)
            lines.append(f"| {state} | "
                         + " | ".join(format_number(s[k]) for k in _fit_keys()) + " |")
        lines.append("")
    rec.log("summary", rr.TextDocument("\n".join(lines), media_type="text/markdown"), static=True)


def _fit_keys() -> tuple[str, ...]:
    return ("one_step", horizon_label(0.5), "free_run")


# --------------------------------------------------------------------------- layout


def _bands_view() -> rrb.TimeSeriesView:
    return time_view("bands", "modes & segments: roll, pitch, yaw rows (training dim, "
                     "validation bright, rejected grey), airborne, modes (named in segments)",
                     axis_y=rrb.ScalarAxis(range=BAND_RANGE, zoom_lock=True))


#: Colour names of the series, for the plots' titles (the plots have no legend).
_COLOUR_NAMES = {"roll": "red", "pitch": "green", "yaw": "blue"}


def _axis_views(axis: str, target: bool,
                view: Callable[..., rrb.TimeSeriesView] = time_view) -> rrb.Vertical:
    """An axis's tab: the bands, its predicted against measured rate, its input and, when
    logged, its rate target against the measured rate (each a ``view``)."""
    rate = RATE_OF.get(axis, axis)
    unit = STATE_UNITS.get(rate, "?")
    views: list[rrb.View] = [
        _bands_view(),
        view(f"axes/{axis}", f"{axis}: {rate} [{unit}]: measured (grey), one-step (blue), "
             "free-run (orange)", contents=["$origin/**", f"- axes/{axis}/inputs/**"]),
        view(f"axes/{axis}/inputs", f"{axis}: model input {INPUT_OF.get(axis, '')} [1] "
             "(green)"),
    ]
    if target:
        views.append(view(f"targets/{axis}", f"{axis}: {rate} target (yellow), measured "
                          "(grey) [rad/s]"))
    return rrb.Vertical(*views, row_shares=[1, 3, 2, 2][:len(views)], name=axis)


#: The Bode view's frame (:func:`mavsid.viz.series.plot_frame`): magnitude, phase and
#: coherence (:func:`_log_frequency_plot`), each with a one-row legend.
BODE_FRAME = (plot_frame(legend_rows=1)[0],
              (plot_frame(legend_rows=1)[1][0],
               plot_frame(160.0 + 2 * PANEL_GAP, 40.0, legend_rows=1)[1][1]))
#: The fit-% view's frame: one state a row of legend, the note under the x labels.
FIT_FRAME = plot_frame(legend_rows=1, below=3 * X_LABEL_GAP)


def blueprint(
    axes: Sequence[str],
    *,
    with_flight: bool = True,
    focus: tuple[float, float] | None = None,
    targets: Sequence[str] = (),
    y_ranges: Mapping[str, tuple[float, float]] = {},
    no_bode: Sequence[str] = (),
) -> rrb.Blueprint:
    """The layout: a tab per axis (predicted vs measured rate, input, rate target, under the
    modes-and-segments bands) and two of the flight by kind; beside them the summary and segments,
    the Bode plots, fit % vs horizon and the attitude.

    ``targets``: the axes that have a logged rate target, each given a plot of the target
    against the measured rate (:func:`log_rate_targets`).

    ``focus`` (seconds on the log clock, e.g. from :func:`focus_span`) is selected on the
    time panel, paused, and is the span every time plot opens on (their time axis is one),
    so that the viewer opens on a segment rather than on the whole log (or the minute
    before any segment).

    Each time plot is a few hundred pixels tall in a 1600 × 1000 window (ten stacked in one
    column were 45 pixels each: a tick at 0 and nothing else); none has a legend (rerun
    draws it over the data): titles name the colours. ``y_ranges`` (from
    :func:`value_ranges`) fixes a plot's y axis by its origin: without, rerun fits it to the
    data, on which a small range can get a single tick. ``no_bode``: the axes without a Bode
    plot, whose tab shows why (:func:`bode_note`) instead.
    """
    def view(origin: str, name: str, **kw: object) -> rrb.TimeSeriesView:
        shown = y_ranges.get(origin)
        if shown is not None:
            kw["axis_y"] = rrb.ScalarAxis(range=shown)
        return time_view(origin, name, legend=False, **kw)

    # the flight in two tabs: six plots in one column left each too short for its ticks
    angles = rrb.Vertical(
        _bands_view(),
        view("flight/attitude", "flight: roll (red), pitch (green) [rad]"),
        view("flight/heading", "flight: yaw (blue) [rad]"),
        row_shares=[1, 3, 2],
        name="flight: attitude",
    )
    rates = rrb.Vertical(
        _bands_view(),
        view("flight/rates", "flight: body rates p (red), q (green), r (blue) [rad/s]"),
        view("flight/inputs", "flight: controller outputs u_roll (red), u_pitch (green), "
             "u_yaw (blue) [1]"),
        view("flight/thrust", "flight: thrust u_thrust (grey) [1]"),
        row_shares=[1, 3, 3, 1.5],
        name="flight: rates, outputs",
    )
    tabs: list[rrb.Container | rrb.View] = [_axis_views(a, a in targets, view) for a in axes]
    left = rrb.Tabs(*tabs, *([angles, rates] if with_flight or not tabs else []))
    plots: list[rrb.View] = []
    for axis in axes:
        plots.append(rrb.TextDocumentView(origin=f"frequency/{axis}", name=f"{axis}: no Bode")
                     if axis in no_bode else rrb.Spatial2DView(
            origin=f"frequency/{axis}", name=f"{axis}: Bode |H|, phase, coherence",
            visual_bounds=rrb.VisualBounds2D(x_range=BODE_FRAME[0], y_range=BODE_FRAME[1])))
        plots.append(rrb.Spatial2DView(
            origin=f"fit/{axis}", name=f"{axis}: fit % vs horizon",
            visual_bounds=rrb.VisualBounds2D(x_range=FIT_FRAME[0], y_range=FIT_FRAME[1])))
    texts = rrb.Tabs(
        rrb.TextDocumentView(origin="summary", name="summary"),
        rrb.TextLogView(origin="segments", name="segments"),
        active_tab=0 if axes else 1,
    )
    attitude = rrb.Spatial3DView(
        origin="world", name="attitude: data (left) / model roll, pitch, yaw (right)"
    )
    # the Bode plot of the first axis in front: what a tuner looks at first
    right = (rrb.Vertical(texts, rrb.Tabs(*plots, attitude, active_tab=0), row_shares=[2, 3])
             if plots else rrb.Vertical(texts, attitude, row_shares=[1, 1]))
    return rrb.Blueprint(
        rrb.Horizontal(left, right, column_shares=[3, 2]),
        time_panel(focus),
        collapse_panels=True,
    )


def flight_ranges(flights: Sequence[FlightData]) -> dict[str, tuple[float, float]]:
    """Each flight plot's y range (:func:`mavsid.viz.series.nice_range`) by its origin: the
    flights' series by kind over the whole flight (what the flight tab is for); thrust on its
    own scale, 0 to 1 (a hover's 0.39 ... 0.40 otherwise gets no tick a short plot can
    label)."""
    pad = RANGE_MARGIN
    out: dict[str, tuple[float, float]] = {"flight/thrust": (-pad, 1.0 + pad)}
    for kind, names in KINDS.items():
        if kind == "thrust":
            continue
        found = [data[:, names_of.index(n)] for fd in flights
                 for names_of, data in ((fd.state_names, fd.states), (fd.input_names, fd.inputs))
                 for n in names if n in names_of]
        shown = nice_range(np.concatenate(found)) if found else None
        if shown is not None:
            out[f"flight/{kind}"] = shown
    return out


def value_ranges(result: FitResult) -> dict[str, tuple[float, float]]:
    """Each plot's y range (:func:`mavsid.viz.series.nice_range`) where the data's is known
    before the viewer opens, by the plot's origin: the flight's (:func:`flight_ranges`) and
    each axis's model inputs on its validation segments (inputs of ± 0.07 drew a plot ticked
    at 0 only). The predicted rates and the rate targets are left to rerun (a free run can
    diverge)."""
    out = flight_ranges(result.flights)
    for axis, fit in result.axes.items():
        found = [seg.inputs[:, seg.input_names.index(n)] for seg in fit.held_out
                 for n in fit.validation.input_names if n in seg.input_names]
        shown = nice_range(np.concatenate(found)) if found else None
        if shown is not None:
            out[f"axes/{axis}/inputs"] = shown
    return out


def result_blueprint(result: FitResult, targets: Targets, *,
                     flight: bool = True) -> rrb.Blueprint:
    """:func:`blueprint` of a fit or validation ``result`` (``targets``: its
    :func:`rate_targets`): opening on its first validation segment, with its y ranges
    (:func:`value_ranges`) -- the one layout of ``fit --rrd`` and ``view --model``."""
    return blueprint(list(result.axes), with_flight=flight, focus=result_focus(result),
                     targets=target_axes(targets), y_ranges=value_ranges(result),
                     no_bode=[a for a, f in result.axes.items() if bode_note(f) is not None])


def log_flight_windows(
    rec: rr.RecordingStream,
    flight: FlightData,
    windows: Mapping[str, Sequence[WindowReport]],
) -> None:
    """A flight without a model: its data, attitude and every window kept or rejected."""
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_DOWN, static=True)
    log_flight(rec, flight, keep_spans=[(w.start_s, w.stop_s) for ws in windows.values()
                                        for w in ws if w.kept])
    log_bands(rec, flight, windows=windows)
    for axis, reports in windows.items():
        log_segments(rec, axis, (), (), reports)


def _flight_tag(fd: FlightData, flights: Sequence[FlightData]) -> str:
    """"" for a single flight; else the log's file stem (ASCII, with its index when two share
    one): the name its entities and series carry."""
    if len(flights) < 2:
        return ""
    i = next(k for k, f in enumerate(flights) if f is fd)
    stem = os.path.splitext(os.path.basename(fd.source.path))[0]
    stem = "_".join(filter(None, re.split(r"[^A-Za-z0-9_.-]+", stem))) or "log"
    stems = [os.path.splitext(os.path.basename(f.source.path))[0] for f in flights]
    return stem if stems.count(stems[i]) == 1 else f"{stem}_{i}"


def log_fit_result(rec: rr.RecordingStream, result: FitResult, *, flight: bool = True,
                   targets: Targets | None = None,
                   gains: Mapping[str, Mapping[str, Any]] | None = None) -> None:
    """Everything of a pipeline result into ``rec`` (``targets``: :func:`rate_targets` of
    it, when already read; ``gains``: :func:`mavsid.loop.tune.tune`'s entries, shown in the
    summary)."""
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_DOWN, static=True)
    fits = list(result.axes.values())
    if flight:
        for fd in result.flights:
            def ours(segs: Sequence[Segment], fd: FlightData = fd) -> list[Segment]:
                one = len(result.flights) == 1
                return [s for s in segs if one or s.log == fd.source.path]

            mine = {f.axis: (ours(f.train), ours(f.held_out)) for f in fits}
            tag = _flight_tag(fd, result.flights)
            # every sample of the series an axis's model uses, inside that axis's segments
            spans: dict[str, list[tuple[float, float]]] = {}
            for f in fits:
                tr, ho = mine[f.axis]
                for name in (*f.validation.state_names, *f.validation.input_names):
                    spans.setdefault(name, []).extend((s.start_s, s.stop_s) for s in (*tr, *ho))
            log_flight(rec, fd, keep_spans=spans, tag=tag)
            # (a window does not say which log it came from: several logs, no window bands)
            log_bands(rec, fd, mine, {} if tag else {f.axis: f.windows for f in fits},
                      tag=tag)
    for fit in fits:
        log_segments(rec, fit.axis, fit.train, fit.held_out, fit.windows)
        log_validation(rec, fit.axis, fit.validation, fit.held_out)
        note = bode_note(fit)
        if note is not None:  # (the blueprint shows it where the Bode plot would be)
            rec.log(f"frequency/{fit.axis}", rr.TextDocument(note), static=True)
    log_rate_targets(rec, result, targets)
    log_summary(rec, fits, gains)


#: Each flight with its rate target per axis (:func:`rate_targets`).
Targets = list[tuple[FlightData, Mapping[str, np.ndarray]]]


def rate_targets(result: FitResult) -> Targets:
    """Each flight's logged rate target per fitted axis (rad/s on the flight's grid): the
    fit's twin signals, else read from the log (:func:`mavsid.loop.twin_signals`); a flight
    whose targets cannot be read has none."""
    from mavsid.errors import MavsidError
    from mavsid.loop import twin_signals

    out: Targets = []
    for k, fd in enumerate(result.flights):
        try:
            sig = result.twins[k] if result.twins is not None else twin_signals(fd)
        except (MavsidError, ValueError, OSError):
            continue
        found = {a: np.asarray(v, dtype=float) for a, v in sig.target.items()
                 if a in result.axes and len(v) == len(fd.time_s)}
        out.append((fd, found))
    return out


def target_axes(targets: Targets) -> list[str]:
    """The axes some flight has a rate target for, in axis order."""
    return [a for a in AXES if any(a in found for _, found in targets)]


def log_rate_targets(rec: rr.RecordingStream, result: FitResult,
                     targets: Targets | None = None) -> None:
    """Per fitted axis, the rate target the controller was given against the measured rate
    (``targets/AXIS/target``, ``targets/AXIS/measured``): how well the loop followed it, the
    closed-loop twin's reference. Decimated outside the axis's segments as
    :func:`log_flight` does."""
    for fd, found in rate_targets(result) if targets is None else targets:
        tag = _flight_tag(fd, result.flights)
        for axis, target in found.items():
            rate = RATE_OF.get(axis, axis)
            if rate not in fd.state_names:
                continue
            fit = result.axes[axis]
            spans = [(s.start_s, s.stop_s) for s in (*fit.train, *fit.held_out)
                     if len(result.flights) == 1 or s.log == fd.source.path]
            suffix, label = (f"/{tag}", f" {tag}") if tag else ("", "")
            measured = fd.states[:, fd.state_names.index(rate)]
            for kind, colour, values in (("target", TARGET, target),
                                         ("measured", MEASURED, measured)):
                path = f"targets/{axis}/{kind}{suffix}"
                style_series(rec, path, colour, f"{rate} {kind} [rad/s]{label}")
                send_series(rec, path, *_decimated(fd, values, spans))


def _decimated(fd: FlightData, values: np.ndarray,
               spans: Iterable[tuple[float, float]]) -> tuple[np.ndarray, np.ndarray]:
    """``(time, values)`` of one flight series decimated per block to about
    :data:`MAX_FLIGHT_POINTS` samples, every sample inside ``spans`` kept, a gap between
    blocks."""
    t = fd.time_s
    blocks = fd.blocks if len(fd.blocks) else np.array([[0, len(t)]])
    keep = np.zeros(len(t), bool)
    for a, b in spans:
        keep[np.searchsorted(t, a):np.searchsorted(t, b, side="right")] = True
    budget = MAX_FLIGHT_POINTS / max(len(t), 1)
    parts = []
    for a, b in blocks:
        i = a + decimate(values[a:b], max(100, int(budget * (b - a))), keep[a:b])
        parts.append((t[i], values[i]))
    return joined(parts)



def save_rrd(
    result: FitResult, path: str | os.PathLike[str], *, flight: bool = True,
    gains: Mapping[str, Mapping[str, Any]] | None = None,
) -> rrb.Blueprint:
    """Write ``result`` with its blueprint to an ``.rrd`` file (``gains``: as
    :func:`log_fit_result`); returns the blueprint."""
    targets = rate_targets(result)
    bp = result_blueprint(result, targets, flight=flight)
    with rrd_file(path, bp) as rec:
        log_fit_result(rec, result, flight=flight, targets=targets, gains=gains)
    return bp
