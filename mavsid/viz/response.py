"""Closed-loop responses (:mod:`mavsid.response`) of one or more logs as a rerun recording:
target and actual per loop, step responses with their bands, spectra with the filters'
cut-offs, and a summary."""

from __future__ import annotations

import math
import os
import re
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from mavsid.viz.series import (
    COHERENCE,
    MEASURED,
    format_number,
    legend_layout,
    plot2d,
    plot_frame,
    rrd_file,
    send_series,
    style_series,
    time_panel,
    time_view,
)

if TYPE_CHECKING:
    from mavsid.response import FlightResponse

__all__ = ["log_response", "response_blueprint", "save_response_rrd"]


#: colours of the logs compared in a response recording (first log, second, ...)
LOG_COLOURS = ((70, 140, 255), (255, 150, 40), (90, 200, 110), (200, 90, 200))
LOG_COLOUR_NAMES = ("blue", "orange", "green", "purple")
#: a step response's series per log: the mean and its band
STEP_PARTS = ("mean", "lower", "upper")


def _log_tags(responses: Sequence[FlightResponse]) -> list[str]:
    """A short ASCII name per log (its file stem, with its index when two share one)."""
    stems = ["_".join(filter(None, re.split(r"[^A-Za-z0-9_.-]+",
                                            os.path.splitext(os.path.basename(r.log))[0])))
             or "log" for r in responses]
    return [s if stems.count(s) == 1 else f"{s}_{i}" for i, s in enumerate(stems)]


def _step_range(values: np.ndarray) -> tuple[float, float]:
    """A normalised step response's y range: 0 ... 1.5 widened on quarters to hold the
    values, within -1 ... 3 (a band's wild edge would squeeze the ticks of the rest: a
    range fitted to it put 0 ... 1.5 on a third of the plot, its labels overlapping).

    >>> _step_range(np.array([0.1, 1.2])), _step_range(np.array([-0.3, 1.7, np.nan]))
    ((0.0, 1.5), (-0.5, 1.75))
    >>> _step_range(np.array([-40.0, 9.0]))
    (-1.0, 3.0)
    """
    v = values[np.isfinite(values)]
    lo = float(np.floor(min(0.0, v.min(initial=0.0)) / 0.25) * 0.25)
    hi = float(np.ceil(max(1.5, v.max(initial=1.5)) / 0.25) * 0.25)
    return max(lo, -1.0), min(hi, 3.0)


Series2D = tuple[str, np.ndarray, np.ndarray, Sequence[int]]


def _axes(responses: Sequence[FlightResponse]) -> list[str]:
    """The axes of any loop of ``responses``, in order."""
    return list(dict.fromkeys(r.axis for fr in responses for r in fr.loops))


def _no_spectrum(axis: str) -> str:
    return (f"No spectrum for {axis}: no log has a stretch of its gyro or controller output "
            "in flight long enough for one.")


def _spectrum_plots(
    responses: Sequence[FlightResponse],
) -> dict[str, tuple[list[Series2D], tuple[float, float]]]:
    """Per axis with one, the spectra plot's series (each log's gyro and controller-output
    spectra [dB], then the filters' cut-offs within their band as vertical marks) and its
    y range (on whole 10 dB)."""
    spectra: dict[str, list[Series2D]] = {}
    cutoffs: dict[str, dict[str, float]] = {}
    for i, (fr, tag) in enumerate(zip(responses, _log_tags(responses), strict=True)):
        colour = LOG_COLOURS[i % len(LOG_COLOURS)]
        for axis, found in fr.spectra.items():
            for k, sp in enumerate(found):
                ok = (sp.freq_hz > 0) & (sp.psd > 0)
                if ok.sum() < 2:
                    continue
                shade = colour if k == 0 else tuple(min(255, c + 70) for c in colour)
                spectra.setdefault(axis, []).append(
                    (f"{tag} {sp.name}", sp.freq_hz[ok], 10 * np.log10(sp.psd[ok]), shade))
                cutoffs.setdefault(axis, {}).update(sp.cutoffs)
    out = {}
    for axis, series in spectra.items():
        lo = min(float(x.min()) for _, x, _, _ in series)
        hi = max(float(x.max()) for _, x, _, _ in series)
        ys = np.concatenate([y for *_, y, _ in series])
        y_lo, y_hi = float(np.floor(ys.min() / 10) * 10), float(np.ceil(ys.max() / 10) * 10)
        marks = [(f"{name} {hz:g} Hz", np.array([hz, hz]), np.array([y_lo, y_hi]), COHERENCE)
                 for name, hz in cutoffs.get(axis, {}).items() if lo <= hz <= hi]
        out[axis] = ([*series, *marks], (y_lo, y_hi))
    return out


def log_response(rec: rr.RecordingStream, responses: Sequence[FlightResponse],
                 notes: Sequence[str] = ()) -> None:
    """Closed-loop responses (:mod:`mavsid.response`) into ``rec``: per axis and loop the
    target and actual on the flight's timeline (``response/<axis>/<loop>/<log>/...``), the
    step responses with their bands overlaid per log (``step/<axis>/<loop>``, a 2-D plot),
    the gyro and controller-output spectra with the filters' cut-offs
    (``spectrum/<axis>``) and a summary of the verdicts, under ``notes`` (lines shown
    first: why a fit identified nothing)."""
    tags = _log_tags(responses)
    lines = [*(f"- {n}" for n in notes), *([""] if notes else []),
             "| log | axis | loop | rise ms | overshoot % | bandwidth Hz | verdict |",
             "|---|---|---|---|---|---|---|"]
    steps: dict[tuple[str, str], list[tuple[str, np.ndarray, np.ndarray, Sequence[int]]]] = {}
    for i, (fr, tag) in enumerate(zip(responses, tags, strict=True)):
        colour = LOG_COLOURS[i % len(LOG_COLOURS)]
        for r in fr.loops:
            base = f"response/{r.axis}/{r.loop}/{tag}"
            if r.time_s.size:
                send_series(rec, f"{base}/target", r.time_s, r.target_series)
                send_series(rec, f"{base}/actual", r.time_s, r.actual_series)
                style_series(rec, f"{base}/target", MEASURED, f"{tag} target {r.target}")
                style_series(rec, f"{base}/actual", colour, f"{tag} actual {r.actual}")
            if r.step is not None:
                s = r.step
                dim = tuple(c // 2 for c in colour)
                steps.setdefault((r.axis, r.loop), []).extend(
                    (f"{tag} {part}", s.time_s, y, shade) for part, y, shade in zip(
                        STEP_PARTS, (s.response, s.lower, s.upper), (colour, dim, dim),
                        strict=True))
            overshoot = r.overshoot_pct if r.overshoot_pct is not None else math.nan
            lines.append(f"| {tag} | {r.axis} | {r.loop} | "
                         f"{format_number((r.rise_s or math.nan) * 1e3)} | "
                         f"{format_number(overshoot)}"
                         f" | {format_number(r.bandwidth_hz or math.nan)} | {r.verdict} |")
    for (axis, loop), series in steps.items():
        end = max(float(x[-1]) for _, x, _, _ in series)
        lo, hi = _step_range(np.concatenate([y for _, _, y, _ in series]))
        plot2d(rec, f"step/{axis}/{loop}", series, xlog=False,
               x_ticks=np.linspace(0.0, end, 6).round(3),
               y_ticks=np.arange(lo, hi + 1e-9, 0.25 if hi - lo <= 2 else 0.5), x_unit=" s",
               y_unit="", y_range=(lo, hi), legend=True)
    plotted = _spectrum_plots(responses)
    for axis in _axes(responses):
        if axis not in plotted:
            rec.log(f"spectrum/{axis}", rr.TextDocument(_no_spectrum(axis)), static=True)
            continue
        series, (y_lo, y_hi) = plotted[axis]
        lo = min(float(x.min()) for _, x, _, _ in series)
        hi = max(float(x.max()) for _, x, _, _ in series)
        decades = 10.0 ** np.arange(np.floor(np.log10(lo)), np.ceil(np.log10(hi)) + 1)
        plot2d(rec, f"spectrum/{axis}", series, xlog=True, x_ticks=decades,
               y_ticks=np.arange(y_lo, y_hi + 1, 20), x_unit=" Hz", y_unit=" dB",
               y_range=(y_lo, y_hi), legend=True)
    rec.log("summary", rr.TextDocument("\n".join(lines), media_type=rr.MediaType.MARKDOWN),
            static=True)


def response_blueprint(responses: Sequence[FlightResponse]) -> rrb.Blueprint:
    """The layout of :func:`log_response`: the loops' target and actual on linked time
    axes (left), the step responses, spectra and summary (right)."""
    keys = list(dict.fromkeys((r.axis, r.loop) for fr in responses for r in fr.loops))
    # the logs' colours in the titles (rerun draws a legend over the data)
    tags = _log_tags(responses)
    actual = ", ".join(f"{tag} ({LOG_COLOUR_NAMES[i % len(LOG_COLOUR_NAMES)]})"
                       for i, tag in enumerate(tags))
    times = [time_view(f"response/{axis}/{loop}", f"{axis} {loop}: target (grey), actual "
                       f"{actual} [{'rad/s' if loop == 'rate' else 'rad'}]")
             for axis, loop in keys]
    plots: list[rrb.View] = []
    for axis, loop in keys:
        names = [f"{tag} {part}" for tag, fr in zip(tags, responses, strict=True)
                 if getattr(fr.loop(axis, loop), "step", None) is not None
                 for part in STEP_PARTS]
        if names:
            x_range, y_range = plot_frame(legend_rows=legend_layout(names)[0])
            plots.append(rrb.Spatial2DView(
                origin=f"step/{axis}/{loop}", name=f"{axis} {loop}: step response",
                visual_bounds=rrb.VisualBounds2D(x_range=x_range, y_range=y_range)))
    # framed as the step plots are (fitted to its content, rerun left the labels no room)
    spectra = _spectrum_plots(responses)
    for axis in _axes(responses):
        if axis not in spectra:
            plots.append(rrb.TextDocumentView(origin=f"spectrum/{axis}",
                                              name=f"{axis}: no spectra"))
            continue
        names = [name for name, *_ in spectra[axis][0]]
        x_range, y_range = plot_frame(legend_rows=legend_layout(names)[0])
        plots.append(rrb.Spatial2DView(
            origin=f"spectrum/{axis}", name=f"{axis}: spectra [dB]",
            visual_bounds=rrb.VisualBounds2D(x_range=x_range, y_range=y_range)))
    summary = rrb.TextDocumentView(origin="summary", name="summary")
    right = rrb.Vertical(summary, rrb.Tabs(*plots), row_shares=[1, 3]) if plots else summary
    left = rrb.Vertical(*times) if times else rrb.TextDocumentView(origin="summary")
    return rrb.Blueprint(rrb.Horizontal(left, right, column_shares=[3, 2]), time_panel(),
                         collapse_panels=True)


def save_response_rrd(responses: Sequence[FlightResponse], path: str | os.PathLike[str],
                      notes: Sequence[str] = ()) -> rrb.Blueprint:
    """Write :func:`log_response` of ``responses`` (and ``notes``) with its blueprint to an
    ``.rrd``."""
    bp = response_blueprint(responses)
    with rrd_file(path, bp) as rec:
        log_response(rec, responses, notes)
    return bp
