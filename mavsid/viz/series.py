"""The pieces every mavsid recording is built from: the timeline, colours, one scalar
series sent whole, a series' line style, a static 2-D line plot, a linked time view, the
time panel that sets the span those views open on, and an ``.rrd`` file that reports a
failed write as an ``OSError``.

The timeline, :data:`TIMELINE`, counts milliseconds on the log's clock (a rerun *sequence*
timeline): rerun 0.41 draws a sequence as a plain number (``#95 000``), a *duration* as
minutes and seconds (``+1m 35s``) and a *timestamp* as a clock time (``00:01:35``), while
mavsid's command line and report speak seconds. Milliseconds, not seconds, because a sequence
holds integers only; rounding moves a sample by at most 0.5 ms.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterable, Iterator, Sequence
from typing import Any, Final

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

__all__ = [
    "AGGREGATION",
    "ANCHOR_S",
    "APPLICATION_ID",
    "RANGE_MARGIN",
    "TIMELINE",
    "format_number",
    "joined",
    "legend_layout",
    "new_recording",
    "nice_range",
    "plot2d",
    "plot_frame",
    "rrd_file",
    "send_series",
    "set_time",
    "style_series",
    "ticks",
    "time_column",
    "time_panel",
    "time_view",
    "write_errors",
]

APPLICATION_ID = "mavsid"
#: The log's clock in milliseconds (a sequence timeline: see the module's docstring).
TIMELINE = "time_ms"
#: :data:`TIMELINE`'s ticks per second.
TICKS_PER_S = 1000

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


def ticks(t_s: np.ndarray | float) -> np.ndarray:
    """Seconds on the log's clock as :data:`TIMELINE`'s integer ticks (milliseconds).

    >>> ticks(np.array([95.0, 95.0004, 101.2506])).tolist()
    [95000, 95000, 101251]
    """
    return np.round(np.asarray(t_s, dtype=float) * TICKS_PER_S).astype(np.int64)


def time_column(t: np.ndarray) -> rr.TimeColumn:
    return rr.TimeColumn(TIMELINE, sequence=ticks(t))


def set_time(rec: rr.RecordingStream, t_s: float) -> None:
    """Log what follows at ``t_s`` seconds on :data:`TIMELINE`."""
    rec.set_time(TIMELINE, sequence=int(ticks(t_s)))


#: Each series starts with one NaN sample (a gap: nothing drawn) on a whole multiple of
#: this many seconds: rerun ticks a sequence plot from its earliest sample, and a flight
#: whose log starts at 127.184 s was ticked #127 184, #128 184, ... instead of #128 000.
ANCHOR_S = 10.0


def send_series(rec: rr.RecordingStream, path: str, t: np.ndarray, v: np.ndarray) -> None:
    """One scalar series, rows with a non-finite time dropped, after an anchor
    (:data:`ANCHOR_S`)."""
    t = np.asarray(t, dtype=float)
    v = np.asarray(v, dtype=float)
    ok = np.isfinite(t)
    if not ok.any():
        return
    t, v = t[ok], v[ok]
    first = float(np.floor(t.min() / ANCHOR_S) * ANCHOR_S)
    if ticks(first) < ticks(t.min()):
        t, v = np.r_[first, t], np.r_[np.nan, v]
    rr.send_columns(
        path, indexes=[time_column(t)], columns=rr.Scalars.columns(scalars=v), recording=rec
    )


#: A plot's y range reaches this share of itself beyond its outer ticks, so that their
#: labels (centred on the tick) are not cut by the plot's edge.
RANGE_MARGIN = 0.08


def nice_range(values: np.ndarray | Sequence[float]) -> tuple[float, float] | None:
    """A y range for a plot of ``values`` (``None`` without a finite value): the smallest
    one on whole steps of the decade below their spread that holds them, and a margin
    (:data:`RANGE_MARGIN`). rerun ticks a plot on decade steps and labels a step only when
    it is some 25 pixels tall: a 170-pixel plot of 0 ± 0.067 had one labelled tick, 0
    (steps of 0.1 fall outside, steps of 0.01 are 11 pixels apart); on -0.1 ... 0.1 it has
    three.

    Examples
    --------
    >>> nice_range([-0.067, 0.067]), nice_range([2.93, 3.06])
    ((-0.116, 0.116), (2.884, 3.116))
    >>> nice_range([0.39, 0.39]), nice_range([0.0]), nice_range([np.nan])
    ((0.292, 0.408), (-1.16, 1.16), None)
    """
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    if not x.size:
        return None
    lo, hi = float(x.min()), float(x.max())
    spread = hi - lo if hi > lo else abs(lo)
    if spread == 0.0:
        a, b = -1.0, 1.0
    else:
        step = 10.0 ** np.floor(np.log10(spread))
        a = float(np.floor(lo / step + 1e-9) * step)
        b = float(np.ceil(hi / step - 1e-9) * step)
    pad = RANGE_MARGIN * (b - a)
    return round(a - pad, 12) + 0.0, round(b + pad, 12) + 0.0


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


#: A 2-D plot's label layout, in plot units (a plot is 200 wide). rerun draws a label below
#: its point, at a fixed size in pixels (about 12 units high at 1.6 pixels per unit, the Bode
#: view's scale in a 1600 × 1000 window): x tick labels below the x axis, y tick labels left
#: of the y axis and raised by ``LABEL_RISE`` to sit on their grid line; the legend in rows
#: of ``LEGEND_COLUMNS`` above the plot (beside it, 11 units apart, its entries overlapped
#: each other and the data); stacked panels (Bode magnitude, phase, coherence) apart by the
#: upper one's x labels and the lower one's legend.
X_LABEL_GAP, Y_LABEL_GAP, LABEL_RISE = 8.0, 26.0, 6.0
LEGEND_STEP, LEGEND_COLUMNS, PANEL_GAP = 15.0, 3, 40.0


#: rerun's 2-D label text, in plot units at about 1.6 pixels per unit: 4.3 a character
#: and some padding (measured on screenshots of the Bode view).
LABEL_CHAR, LABEL_PAD = 4.3, 4.0
#: How far a plot's frame (:func:`plot2d`) reaches beyond its right edge: half the widest
#: x tick label ("100 Hz").
RIGHT_MARGIN = 22.0


def legend_layout(names: Sequence[str]) -> tuple[int, int]:
    """``(rows, columns)`` of a legend of ``names`` above a plot: up to
    :data:`LEGEND_COLUMNS` a row, fewer when a name would not fit its column.

    >>> legend_layout(["p fit"]), legend_layout(["a", "b", "c", "d"])
    ((1, 3), (2, 3))
    >>> legend_layout(["log gyro", "ATC_RAT_YAW_FLTT 20 Hz", "ATC_RAT_YAW_FLTD 20 Hz"])
    (2, 2)
    """
    if not names:
        return 0, LEGEND_COLUMNS
    widest = LABEL_CHAR * max(len(n) for n in names) + LABEL_PAD
    columns = max(1, min(LEGEND_COLUMNS, int((200.0 + RIGHT_MARGIN) // widest)))
    return -(-len(names) // columns), columns


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
    in its colour above the plot (:func:`legend_layout`, rows :data:`LEGEND_STEP` apart);
    :func:`plot_frame` is what a view must show of it."""
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
            labels_at.append((-Y_LABEL_GAP, y - LABEL_RISE))
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
    names = [name for name, *_ in series] if legend else []
    rows, columns = legend_layout(names)
    if names:
        at = [(200.0 * (i % columns + 0.5) / columns,
               origin_y - LEGEND_STEP * (rows - i // columns)) for i in range(len(names))]
        rec.log(
            f"{path}/legend",
            rr.Points2D(at, labels=names, radii=1.5,
                        colors=[colour for *_, colour in series], show_labels=True),
            static=True,
        )


def plot_frame(origin_y: float = 0.0, height: float = 100.0, legend_rows: int = 0,
               below: float = 0.0) -> tuple[tuple[float, float], tuple[float, float]]:
    """The ``(x, y)`` ranges of a :func:`plot2d` plot with its tick labels and a legend of
    ``legend_rows`` rows (and ``below`` more units under its x labels): a 2-D view's
    ``VisualBounds2D`` (fitted to its content, rerun leaves margins that shrank the text's
    room: the Bode legends overlapped).

    >>> plot_frame(legend_rows=1)
    ((-52.0, 222.0), (-19.0, 124.0))
    """
    top = origin_y - LEGEND_STEP * legend_rows - 4.0 if legend_rows else origin_y - 2 * LABEL_RISE
    return ((-Y_LABEL_GAP - 26.0, 200.0 + RIGHT_MARGIN),
            (top, origin_y + height + X_LABEL_GAP + 16.0 + below))


def format_number(x: float) -> str:
    return "–" if not np.isfinite(x) else f"{x:.4g}"



def time_view(origin: str, name: str, *, legend: bool = False,
              **kw: object) -> rrb.TimeSeriesView:
    """A time plot whose time axis is the viewer's shared one (zoom one, all follow; it opens
    on the span :func:`time_panel` sets). No legend unless ``legend``: rerun draws it over
    the data, so the name says which colour is which."""
    return rrb.TimeSeriesView(origin=origin, name=name,
                              axis_x=rrb.TimeAxis(link="LinkToGlobal"),
                              plot_legend=rrb.PlotLegend(corner="RightBottom", visible=legend),
                              **kw)  # type: ignore[arg-type]


#: The blueprint entity of the time axis that every linked time plot shares: the view rerun
#: keeps for "blueprint data shared between views" (``GLOBAL_VIEW_ID`` in the viewer's
#: source, rerun 0.41; no SDK call sets it). Unset, a linked plot opens on rerun's default,
#: ±1 000 ticks around the time cursor (±1 s here) at the log's start, where nothing is.
SHARED_VIEW: Final = "view/5c0dca6a-e63f-9cf7-f657-2602590474cc"


class _TimePanel(rrb.TimePanel):
    """rerun's time panel that also writes the shared time axis's span (seconds), or the
    whole recording when ``None``."""

    def __init__(self, shown: tuple[float, float] | None, **kw: Any) -> None:
        super().__init__(**kw)
        self.shown = shown

    def _log_to_stream(self, stream: rr.RecordingStream) -> None:
        from rerun.encodings import TimeRange, TimeRangeBoundary

        super()._log_to_stream(stream)
        if self.shown is None:
            start = end = TimeRangeBoundary.infinite()
        else:
            a, b = (int(x) for x in ticks(np.asarray(self.shown)))
            start, end = TimeRangeBoundary.absolute(seq=a), TimeRangeBoundary.absolute(seq=b)
        stream.log(f"{SHARED_VIEW}/TimeAxis",
                   rrb.archetypes.TimeAxis(view_range=TimeRange(start=start, end=end)))


def time_panel(focus: tuple[float, float] | None = None) -> rrb.TimePanel:
    """The time panel, collapsed to its play bar, paused on :data:`TIMELINE`; ``focus``
    (seconds) selected and the span every :func:`time_view` opens on (else the whole
    recording)."""
    selection = None if focus is None else rrb.components.AbsoluteTimeRange(
        *(int(x) for x in ticks(np.asarray(focus))))
    return _TimePanel(focus, timeline=TIMELINE, play_state="paused", state="collapsed",
                      time_selection=selection)



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
