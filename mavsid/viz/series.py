"""The pieces every mavsid recording is built from: the timeline, colours, one scalar
series sent whole, a series' line style, a static 2-D line plot, a linked time view and an
``.rrd`` file that reports a failed write as an ``OSError``."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterable, Iterator, Sequence
from typing import Final

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

__all__ = [
    "AGGREGATION",
    "APPLICATION_ID",
    "TIMELINE",
    "format_number",
    "joined",
    "new_recording",
    "plot2d",
    "rrd_file",
    "send_series",
    "style_series",
    "time_column",
    "time_view",
    "write_errors",
]

APPLICATION_ID = "mavsid"
TIMELINE = "flight_time"

MEASURED = (200, 200, 200)
ONE_STEP = (70, 140, 255)
TARGET = (255, 220, 60)
FREE_RUN = (255, 150, 40)
INPUT = (90, 200, 110)
COHERENCE = (180, 120, 255)
GRID = (90, 90, 90)
AXIS_COLOURS = {"roll": (230, 80, 80), "pitch": (80, 200, 90), "yaw": (80, 140, 255)}


def new_recording(recording_id: str | None = None) -> rr.RecordingStream:
    """A fresh recording stream for mavsid (not made the global default), whose only
    timeline is :data:`TIMELINE`."""
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
    rec.set_log_time_enabled(False)
    rec.set_log_tick_enabled(False)
    return rec


def time_column(t: np.ndarray) -> rr.TimeColumn:
    return rr.TimeColumn(TIMELINE, duration=np.asarray(t, dtype=float))


def send_series(rec: rr.RecordingStream, path: str, t: np.ndarray, v: np.ndarray) -> None:
    """One scalar series, rows with a non-finite time dropped."""
    t = np.asarray(t, dtype=float)
    v = np.asarray(v, dtype=float)
    ok = np.isfinite(t)
    if not ok.any():
        return
    rr.send_columns(
        path, indexes=[time_column(t[ok])], columns=rr.Scalars.columns(scalars=v[ok]), recording=rec
    )


def joined(parts: Iterable[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate (time, value) pieces with a NaN value between them (a gap in the plot)."""
    ts: list[np.ndarray] = []
    vs: list[np.ndarray] = []
    for t, v in parts:
        if ts:
            ts.append(np.array([0.5 * (ts[-1][-1] + t[0])]))
            vs.append(np.array([np.nan]))
        ts.append(np.asarray(t, dtype=float))
        vs.append(np.asarray(v, dtype=float))
    if not ts:
        return np.zeros(0), np.zeros(0)
    return np.concatenate(ts), np.concatenate(vs)


#: How a time series is drawn where several samples share a pixel (zoomed out): the
#: band between their min and max. rerun's default averages them, and a chirp's fast part
#: (an 18-Hz sine of ±0.2 over a few pixels) drew as a flat line.
AGGREGATION: Final = "MinMax"


def style_series(rec: rr.RecordingStream, path: str, colour: Sequence[int], name: str) -> None:
    rec.log(path, rr.SeriesLines(colors=[colour], names=[name], aggregation_policy=AGGREGATION),
            static=True)



# --------------------------------------------------------------------------- 2-D plots


#: A 2-D plot's label layout, in plot units (a plot is 200 wide): tick labels below the
#: x axis and left of the y axis, far enough that the lowest y label and the first x label
#: do not overlap; legend entries one text line apart; the Bode panels (magnitude, phase,
#: coherence) apart by their x labels and a margin (at 6 and 12 units they overlapped at
#: the viewer's default zoom).
X_LABEL_GAP, Y_LABEL_GAP, LEGEND_STEP, PANEL_GAP = 9.0, 22.0, 11.0, 32.0


def plot2d(
    rec: rr.RecordingStream,
    path: str,
    series: Sequence[tuple[str, np.ndarray, np.ndarray, Sequence[int]]],
    *,
    xlog: bool,
    x_ticks: Sequence[float] | np.ndarray,
    y_ticks: Sequence[float] | np.ndarray,
    x_unit: str,
    y_unit: str,
    origin_y: float = 0.0,
    height: float = 100.0,
    y_range: tuple[float, float] | None = None,
    legend: bool = False,
) -> None:
    """A static line plot drawn with 2-D primitives (rerun time-series views plot against
    time only). Plot space: x in [0, 200], y from ``origin_y`` down to ``origin_y - height``
    (rerun's 2-D y axis points down, so values are flipped). ``legend`` names each series
    in its colour at the plot's top right."""
    xs_all = [np.asarray(x, dtype=float) for _, x, _, _ in series]
    ys_all = [np.asarray(y, dtype=float) for _, _, y, _ in series]

    def fx(x: np.ndarray) -> np.ndarray:
        return np.log10(x) if xlog else x

    x_lo, x_hi = fx(np.array([min(x_ticks), max(x_ticks)]))
    if y_range is None:
        finite = np.concatenate([y[np.isfinite(y)] for y in ys_all] + [np.asarray(y_ticks)])
        y_lo, y_hi = float(finite.min()), float(finite.max())
    else:
        y_lo, y_hi = y_range
    y_hi = y_hi if y_hi > y_lo else y_lo + 1.0

    def px(x: np.ndarray) -> np.ndarray:
        return 200.0 * (fx(x) - x_lo) / (x_hi - x_lo)

    def py(y: np.ndarray) -> np.ndarray:
        return origin_y + height * (1.0 - (np.clip(y, y_lo, y_hi) - y_lo) / (y_hi - y_lo))

    grid: list[np.ndarray] = []
    labels_at: list[tuple[float, float]] = []
    labels: list[str] = []
    for xt in x_ticks:
        x = float(px(np.array([xt]))[0])
        grid.append(np.array([[x, origin_y], [x, origin_y + height]]))
        labels_at.append((x, origin_y + height + X_LABEL_GAP))
        labels.append(f"{xt:g}{x_unit}")
    for yt in y_ticks:
        if y_lo <= yt <= y_hi:
            y = float(py(np.array([yt]))[0])
            grid.append(np.array([[0.0, y], [200.0, y]]))
            labels_at.append((-Y_LABEL_GAP, y))
            labels.append(f"{yt:g}{y_unit}")
    rec.log(f"{path}/grid", rr.LineStrips2D(grid, colors=[GRID], radii=0.15), static=True)
    rec.log(
        f"{path}/ticks",
        rr.Points2D(labels_at, labels=labels, radii=0.1, colors=[GRID], show_labels=True),
        static=True,
    )
    for (name, _, _, colour), xv, yv in zip(series, xs_all, ys_all, strict=True):
        ok = np.isfinite(xv) & np.isfinite(yv) & (xv > 0 if xlog else np.isfinite(xv))
        if ok.sum() < 1:
            continue
        pts = np.c_[px(xv[ok]), py(yv[ok])]
        entity = f"{path}/{name.replace(' ', '_')}"
        rec.log(
            entity,
            rr.LineStrips2D([pts], colors=[colour], radii=0.6, labels=[name], show_labels=False),
            static=True,
        )
        if len(pts) < 30:  # few points (fit vs horizon): mark them
            rec.log(f"{entity}/points", rr.Points2D(pts, colors=[colour], radii=1.2),
                    static=True)
    if legend:
        at = [(200.0 + Y_LABEL_GAP, origin_y + 4.0 + LEGEND_STEP * i)
              for i in range(len(series))]
        rec.log(
            f"{path}/legend",
            rr.Points2D(at, labels=[name for name, *_ in series], radii=1.5,
                        colors=[colour for *_, colour in series], show_labels=True),
            static=True,
        )


def format_number(x: float) -> str:
    return "–" if not np.isfinite(x) else f"{x:.4g}"



def time_view(origin: str, name: str, focus: tuple[float, float] | None = None,
               **kw: object) -> rrb.TimeSeriesView:
    """A time plot whose time axis moves with every other one (zoom one, all follow),
    showing ``focus`` (seconds) when given, else the whole flight."""
    from rerun.encodings import TimeRange, TimeRangeBoundary

    shown = None if focus is None else TimeRange(
        start=TimeRangeBoundary.absolute(seconds=focus[0]),
        end=TimeRangeBoundary.absolute(seconds=focus[1]))
    return rrb.TimeSeriesView(origin=origin, name=name,
                              axis_x=rrb.TimeAxis(link="LinkToGlobal", view_range=shown),
                              **kw)  # type: ignore[arg-type]



@contextlib.contextmanager
def write_errors() -> Iterator[None]:
    """rerun reports a failed write (a full disk, ``/dev/full``) as a ``RuntimeError`` naming
    the OS error: raised here as an ``OSError``, which :func:`mavsid.outputs.atomic_path`
    turns into one line naming the output."""
    try:
        yield
    except RuntimeError as exc:
        text = str(exc)
        if "os error" not in text and "write" not in text.lower():
            raise
        raise OSError(text.rsplit(": ", 1)[-1]) from None



@contextlib.contextmanager
def rrd_file(path: str | os.PathLike[str], bp: rrb.Blueprint) -> Iterator[rr.RecordingStream]:
    """A recording saved to ``path`` with the blueprint ``bp``, flushed and closed when the
    block ends (:func:`write_errors`)."""
    rec = new_recording()
    with write_errors():
        rec.save(os.fspath(path), default_blueprint=bp)
        yield rec
        rec.flush()
        rec.disconnect()
