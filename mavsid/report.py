"""A static HTML report of a fit: one self-contained file to attach to a tuning discussion.

Per axis: the parameter table (value ± σ, unit), fit % at one step / 0.5 s / free run,
stability, and figures embedded as SVG (matplotlib, no pyplot state): measured vs
one-step vs free-run on the validation segments with the input below, fit % against
horizon, residual autocorrelation with its confidence band, and, for SYSTEMID (chirp)
segments, the Bode magnitude and phase of measured and model response with the coherence.

Examples
--------
>>> html = render_html_page("t", ["<p>hello</p>"])
>>> html.startswith("<!DOCTYPE html>") and "<p>hello</p>" in html
True
"""

from __future__ import annotations

import base64
import contextlib
import functools
import html
import io
import os
import re
import threading
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import matplotlib as mpl
import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import FuncFormatter, NullLocator

from mavsid import __version__
from mavsid.channels import source_text
from mavsid.data import decimate
from mavsid.validation import Validation, horizon_label

if TYPE_CHECKING:
    from mavsid.loop.tune import TuneAnalysis
    from mavsid.pipeline_results import AxisFit, FitResult
    from mavsid.response import FlightResponse

    #: The loop analysis a report draws, or a function that returns it when first needed.
    _Analysis = TuneAnalysis | Callable[[], TuneAnalysis] | None

__all__ = ["figure_img", "loop_section", "render_html", "render_html_page",
           "response_section", "write_report", "write_response_report"]

#: the grids' opacity (major and, from :func:`log_minor`, minor lines)
_GRID_ALPHA = 0.3

_COLOURS = {"measured": "#333333", "one_step": "#2f6fde", "free_run": "#f08a12", "input": "#2a9d46"}

_CSS = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1100px; color: #222; }
h1 { font-size: 1.6em; } h2 { border-bottom: 1px solid #ccc; padding-bottom: .2em; }
table { border-collapse: collapse; margin: .5em 0 1em; }
td, th { border: 1px solid #ccc; padding: .25em .6em; text-align: right; }
th { background: #f3f3f3; } td.name, th.name { text-align: left; font-family: monospace; }
img { max-width: 100%; height: auto; display: block; margin: .5em 0; }
.row { display: flex; gap: 1em; align-items: flex-start; flex-wrap: wrap; }
.verdict-good { color: #1a7f37; } .verdict-usable { color: #9a6700; }
.verdict-not { color: #cf222e; }
.meta { color: #666; font-size: .9em; }
"""


def figure_img(fig: Figure) -> str:
    """A figure as an ``<img>`` tag with an SVG inlined (base64): vector lines that stay
    sharp at any zoom, text kept as text (``svg.fonttype`` none: no glyph outlines), no
    timestamp or random ids (the same result gives the same file). Drawing it costs less
    than rasterising a 90-dpi PNG, and the report is smaller."""
    buf = io.StringIO()
    with mpl.rc_context({"svg.fonttype": "none", "svg.hashsalt": "mavsid"}):
        fig.savefig(buf, format="svg", metadata={"Date": None})
    text = buf.getvalue()
    text = text[text.find("<svg"):]  # no XML prolog or doctype: what a data URI needs only
    data = base64.b64encode(text.encode("utf-8")).decode("ascii")
    return f'<img alt="figure" src="data:image/svg+xml;base64,{data}">'


def warm_up() -> None:
    """Build and draw each of the report's figure layouts once, empty: the first drawing in
    a process loads the fonts and the SVG backend, and a layout's first use builds its axes
    and tick objects (a large part of a report's first drawing), which a process waiting
    for its result (:class:`~mavsid.outputs.ReportWorker`) does beforehand: the report's
    figures then reuse them (see :func:`_panels`)."""
    for name, (figsize, rows, cols, kw) in _LAYOUTS.items():
        fig, axes = _panels(figsize, rows, cols, **kw)
        for ax in axes[:, _LOG_X.get(name, slice(0))].ravel():
            # (a linear axis stays linear: its figure only plots on it)
            ax.set_xscale("log")
        for ax in axes.ravel():
            ax.plot([0.1, 10.0], [0.0, 1.0], label="x")
            ax.set_title("x")
            ax.legend(fontsize=7)
        _layout(fig)
        figure_img(fig)


_POOL = threading.local()


def _panels(figsize: tuple[float, float], rows: int = 1, cols: int = 1,
            **kw: Any) -> tuple[Figure, np.ndarray]:
    """A figure of ``rows`` x ``cols`` axes (``fig.subplots(..., squeeze=False, **kw)``),
    the one drawn last with this layout emptied and handed out again when there is one:
    building axes (their ticks, spines and scales) was a third of the report's figure time,
    and a figure drawn again reuses its renderer's text metrics. Draw the figure before
    asking for the same layout again (every figure here goes to :func:`figure_img` at once).
    """
    pool: dict[str, tuple[Figure, np.ndarray]] = _POOL.__dict__.setdefault("figures", {})
    key = repr((figsize, rows, cols, sorted(kw.items())))
    if key in pool:
        fig, axes = pool[key]
        for ax in fig.axes:
            for art in (*ax.lines, *ax.collections, *ax.patches, *ax.texts):
                art.remove()
            legend = ax.get_legend()
            if legend is not None:
                legend.remove()
            ax.set_title("")
            ax.set_xlabel("")
            ax.set_ylabel("")
            ax.set_prop_cycle(None)  # the default colours from the first again
            ax.relim()
            ax.set_autoscale_on(True)
        return fig, axes
    fig = Figure(figsize=figsize)
    # its own Agg canvas: savefig then keeps the renderer, and with it the measured sizes
    # of the texts drawn before (tick labels, titles), from one use of the layout to the next
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, squeeze=False, **kw)
    pool[key] = (fig, axes)
    return fig, axes


_BODE_KW = {"sharex": "col", "gridspec_kw": {"height_ratios": [3, 2, 1.3]}}
#: the report's figure layouts: figure size (in), rows, columns, ``subplots`` keywords (a
#: Bode figure of three columns or more, rare, is sized where it is drawn)
_LAYOUTS: dict[str, tuple[tuple[float, float], int, int, dict[str, Any]]] = {
    "time": ((11, 4.5), 2, 1, {"sharex": True, "gridspec_kw": {"height_ratios": [3, 1]}}),
    "horizon": ((5.2, 3.4), 1, 1, {}),
    "residual": ((5.2, 4.6), 2, 1, {}),
    "bode1": ((11, 6), 3, 1, _BODE_KW),
    "bode2": ((11, 6), 3, 2, _BODE_KW),
    "twin": ((11, 3.2), 1, 1, {}),
    "gains": ((11, 3.4), 1, 3, {}),  # (mavsid.report_gains)
}
#: the layouts whose x axes are logarithmic: their columns that are
_LOG_X = {"horizon": slice(None), "bode1": slice(None), "bode2": slice(None),
          "gains": slice(1, None)}


def layout_panels(name: str) -> tuple[Figure, np.ndarray]:
    """:func:`_panels` of the layout ``name`` of :data:`_LAYOUTS` (built beforehand by
    :func:`warm_up`)."""
    figsize, rows, cols, kw = _LAYOUTS[name]
    return _panels(figsize, rows, cols, **kw)


_PLAIN = FuncFormatter(lambda x, _pos: f"{x:g}")


def log_minor(ax: Axes, grid: bool = True) -> None:
    """A log x axis's minor grid lines (unless not ``grid``) and tick marks (2-9 of each
    decade) as two artists, drawn as matplotlib draws them, instead of a tick object (five
    artists) per line: a third of the report's drawing went into the minor ticks of its log
    axes (``grid(True, alpha=_GRID_ALPHA)`` draws the major grid lines). Call it when the
    axis's limits are final."""
    lo, hi = sorted(ax.get_xlim())
    if not (lo > 0 and np.isfinite(hi)):
        return
    dec = np.arange(np.floor(np.log10(lo)), np.ceil(np.log10(hi)) + 1)
    xs = (np.arange(2, 10)[None, :] * 10.0 ** dec[:, None]).ravel()
    xs = xs[(xs >= lo) & (xs <= hi)]
    ax.xaxis.set_minor_locator(NullLocator())
    # decades as plain numbers ("0.1", "10"), not mathtext ("10⁻¹"): building matplotlib's
    # mathtext parser and laying out its boxes took a tenth of the report's figure time
    ax.xaxis.set_major_formatter(_PLAIN)
    trans = ax.get_xaxis_transform()  # x in data, y in axes fraction
    rc = mpl.rcParams
    lines = LineCollection([[(x, 0.0), (x, 1.0)] for x in xs], transform=trans,
                           colors=rc["grid.color"], linewidths=rc["grid.linewidth"],
                           linestyles=rc["grid.linestyle"], alpha=_GRID_ALPHA, zorder=1.5)
    if grid:
        ax.add_collection(lines, autolim=False)
    ticks = Line2D(xs, np.zeros(xs.size), transform=trans, ls="none", marker=3,  # TICKDOWN
                   markersize=rc["xtick.minor.size"], markeredgewidth=rc["xtick.minor.width"],
                   color=rc["xtick.color"], clip_on=False)
    ax.add_artist(ticks)


def _layout(fig: Figure, left: float = 0.85, right: float = 0.15, top: float = 0.35,
            bottom: float = 0.55, hspace: float = 0.3, wspace: float = 0.85) -> None:
    """Fixed margins in inches (``hspace``, ``wspace`` between panels, also inches) in place
    of ``tight_layout``, which draws every axis's ticks once more to measure them (about a
    quarter of the report's time). The margins fit the labels these figures carry: tick
    labels of a few digits, one y label, an x label and a title."""
    for ax in fig.axes:
        if ax.get_xscale() == "log":
            log_minor(ax)
    w, h = fig.get_size_inches()
    spec = fig.axes[0].get_subplotspec() if fig.axes else None
    rows, cols = spec.get_gridspec().get_geometry() if spec is not None else (1, 1)
    inner_w = w - left - right
    inner_h = h - top - bottom
    fig.subplots_adjust(left=left / w, right=1 - right / w, top=1 - top / h,
                        bottom=bottom / h,
                        wspace=wspace * cols / max(inner_w - wspace * (cols - 1), 1e-3),
                        hspace=hspace * rows / max(inner_h - hspace * (rows - 1), 1e-3))


#: Most samples a time-series curve keeps (a minimum and a maximum per pixel column of the
#: widest panel, 11 in at 90 dpi); :func:`mavsid.data.decimate` keeps each bucket's extremes
CURVE_POINTS = 2000


def _gapped(parts: Sequence[tuple[np.ndarray, np.ndarray]],
            max_points: int = CURVE_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """The pieces joined with a NaN between them (a gap in the line), each decimated to its
    share of ``max_points`` (its envelope kept: the picture at the figure's resolution)."""
    ts: list[np.ndarray] = []
    vs: list[np.ndarray] = []
    total = sum(len(t) for t, _ in parts)
    for t, v in parts:
        v = np.asarray(v, float)
        if total > max_points:
            i = decimate(v, max(16, int(max_points * len(v) / total)))
            t, v = np.asarray(t)[i], v[i]
        ts += [np.asarray(t, float), np.array([np.nan])]
        vs += [np.asarray(v, float), np.array([np.nan])]
    if not ts:
        return np.zeros(0), np.zeros(0)
    return np.concatenate(ts), np.concatenate(vs)


def _time_figure(fit: AxisFit) -> Figure:
    v = fit.validation
    j = v.state_names.index(fit.output)
    fig, axes = layout_panels("time")
    ax, ax_u = axes[:, 0]
    for kind in ("measured", "one_step", "free_run"):
        t, y = _gapped([(s.time_s, getattr(s, kind)[:, j]) for s in v.segments])
        ax.plot(t, y, color=_COLOURS[kind], lw=1.6 if kind == "measured" else 1.0,
                label=kind.replace("_", "-"))
    ax.set_ylabel(f"{fit.output}")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(f"{fit.axis}: validation segments (not used for fitting)", fontsize=10, y=1.0)
    for name in v.input_names:
        parts = [
            (s.time_s, s.inputs[:, s.input_names.index(name)])
            for s in fit.held_out
            if name in s.input_names
        ]
        if parts:
            ax_u.plot(*_gapped(parts), lw=0.8, label=name)
    ax_u.set_ylabel("input")
    ax_u.set_xlabel("log time [s]")
    ax_u.legend(loc="upper right", fontsize=8)
    _layout(fig, hspace=0.2)
    return fig


def _horizon_figure(v: Validation) -> Figure:
    fig, axes = layout_panels("horizon")
    ax = axes[0, 0]
    h = v.horizons_s
    for j, state in enumerate(v.state_names):
        ax.semilogx(h, np.clip(v.fit_vs_horizon[:, j], -100.0, 100.0), "o-", label=state)
        free = float(np.nan_to_num(v.fit_free_run[j], nan=-100.0))
        ax.axhline(min(max(free, -100.0), 100.0), ls="--", lw=0.8, color=f"C{j}")
    ax.set_xlabel("prediction horizon [s]")
    ax.set_ylabel("fit [%]")
    ax.set_title("fit vs horizon (dashed: free run)", fontsize=10, y=1.0)
    lo = np.nanmin(np.r_[v.fit_vs_horizon.ravel(), v.fit_free_run, 0.0])
    ax.set_ylim(max(lo, -100.0) - 5, 102)
    ax.grid(True, alpha=_GRID_ALPHA)
    ax.legend(fontsize=8)
    _layout(fig)
    return fig


def _residual_figure(v: Validation) -> Figure:
    r = v.residuals
    fig, axes = layout_panels("residual")
    ax, ax_u = axes[:, 0]
    for j, state in enumerate(v.state_names):
        ax.plot(r.lags * v.dt * 1e3, r.autocorr[:, j], ".-", ms=3, label=f"{state}")
        for i, name in enumerate(v.input_names):
            ax_u.plot(r.cross_lags * v.dt * 1e3, r.crosscorr[:, i, j], ".-", ms=3,
                      label=f"{name} → {state}")
    for a in (ax, ax_u):
        a.axhspan(-r.band, r.band, color="0.85", label=f"{r.confidence:.0%} band (white)")
        a.legend(fontsize=7)
    ax.set_title("one-step residuals: autocorrelation", fontsize=10, y=1.0)
    ax_u.set_title("input–residual cross-correlation", fontsize=10, y=1.0)
    ax_u.set_xlabel("lag [ms]")
    _layout(fig, hspace=0.6)
    return fig


def _semilogx(ax: Axes, f: np.ndarray, h: np.ndarray, colour: str, label: str | None = None,
              **kw: Any) -> None:
    """Magnitude (dB) on ``ax``; phase (deg) drawn by the caller from the same ``h``."""
    ax.semilogx(f, 20 * np.log10(np.abs(h) + 1e-12), color=colour, label=label, **kw)


def _bode_columns(fit: AxisFit, lp: TuneAnalysis | None) -> list[dict[str, Any]]:
    """The Bode figure's columns: each validation response (held-out chirp blocks, measured
    against the model), the loop analysis's curves added to the plant's (the SYSTEMID runs
    measured with the injection as reference, the TF fit; the model's own response when the
    validation has none), and the broken loop at the mixer, measured against predicted."""
    from mavsid.errors import MavsidError
    from mavsid.loop.plant import plant_from_model, plant_response

    v = fit.validation
    measured = lp.measured.get(fit.axis, {}) if lp is not None else {}
    entry = lp.report.get(fit.axis, {}) if lp is not None else {}
    an = lp.analyses.get(fit.axis) if lp is not None else None
    plant = measured.get("plant")
    cols: list[dict[str, Any]] = []
    for fr in v.frequency:
        lo, hi = fr.band_hz or (fr.freq_hz[1], fr.freq_hz[-1])
        sel = (fr.freq_hz >= lo) & (fr.freq_hz <= hi)
        cols.append({"title": f"{fr.input_name} → {fr.output_name}", "f": fr.freq_hz[sel],
                     "measured": ("measured", fr.measured[sel]), "coherence": fr.coherence[sel],
                     "curves": [("model", fr.freq_hz[sel], fr.model[sel],
                                 _COLOURS["free_run"])],
                     "plant": fr.input_name == f"u_{fit.axis}" and fr.output_name == fit.output})
    if plant is not None:
        col = next((c for c in cols if c["plant"]), None)
        if col is None:  # no validation response: the loop's plant column on its own
            curves = []
            with contextlib.suppress(MavsidError, ValueError):
                model = plant_response(plant_from_model(fit.model, fit.axis), plant.freq_hz)
                curves.append(("time-domain model", plant.freq_hz, model, _COLOURS["free_run"]))
            col = {"title": f"plant u_{fit.axis} → {fit.output}", "f": plant.freq_hz,
                   "measured": ("measured (SYSTEMID runs)", plant.response),
                   "coherence": plant.coherence, "curves": curves, "plant": True}
            cols.append(col)
        else:
            col["curves"].append(("measured, whole SYSTEMID runs", plant.freq_hz,
                                  plant.response, "#8c8c8c"))
        tf = entry.get("plant_tf")
        if isinstance(tf, dict):
            from mavsid.frequency import TFFit

            fitted = TFFit(tf["gain"], tf["pole"], tf["delay_s"], tf["cost"],
                           tuple(tf["band_hz"]))
            col["curves"].append(("TF fit", plant.freq_hz, fitted.response(plant.freq_hz),
                                  _COLOURS["one_step"]))
    lf = measured.get("loop")
    if lf is not None and an is not None:
        f = lf.freq_hz
        inside = (an.freq_hz >= f[0]) & (an.freq_hz <= f[-1])
        cols.append({"title": "broken loop at the mixer (rate and attitude loops)", "f": f,
                     "measured": ("measured", lf.response), "coherence": lf.coherence,
                     "curves": [("predicted (logged gains)", an.freq_hz[inside],
                                 an.mixer_loop_response[inside], _COLOURS["free_run"])],
                     "plant": False})
    return cols


def _bode_figure(fit: AxisFit, lp: TuneAnalysis | None = None) -> Figure | None:
    """One Bode figure per axis serving the validation and the loop analysis (see
    :func:`_bode_columns`): magnitude, phase and coherence rows; the measured response is
    drawn faint where its coherence is below 0.6."""
    cols = _bode_columns(fit, lp)
    if not cols:
        return None
    name = f"bode{len(cols)}"
    fig, axes = (layout_panels(name) if name in _LAYOUTS
                 else _panels((14, 6), 3, len(cols), **_BODE_KW))
    for i, col in enumerate(cols):
        mag, ph, coh = axes[0, i], axes[1, i], axes[2, i]
        f, (label, h), gamma = col["f"], col["measured"], col["coherence"]
        colour = _COLOURS["measured"]
        db = 20 * np.log10(np.abs(h) + 1e-12)
        deg = np.degrees(np.unwrap(np.angle(h)))
        trusted = gamma >= 0.6  # faint where the coherence says not to trust it
        mag.semilogx(f, db, color=colour, lw=0.6, alpha=0.35)
        ph.semilogx(f, deg, color=colour, lw=0.6, alpha=0.35)
        mag.semilogx(f, np.where(trusted, db, np.nan), color=colour,
                     label=f"{label} (coherence ≥ 0.6)")
        ph.semilogx(f, np.where(trusted, deg, np.nan), color=colour)
        for name, fc, hc, cc in col["curves"]:
            thin = {"lw": 0.8, "ls": "--"} if cc == "#8c8c8c" else {}
            _semilogx(mag, fc, hc, cc, name, **thin)
            ph.semilogx(fc, np.degrees(np.unwrap(np.angle(hc))), color=cc, **thin)
        coh.semilogx(f, gamma, color="#7a4fd6")
        coh.set_ylim(0, 1.05)
        mag.set_title(col["title"], fontsize=10, y=1.0)
        mag.set_ylabel("|H| [dB]")
        ph.set_ylabel("phase [deg]")
        coh.set_ylabel("coherence")
        coh.set_xlabel("frequency [Hz]")
        mag.legend(fontsize=7)
        for a in (mag, ph, coh):
            a.grid(True, alpha=_GRID_ALPHA)
    _layout(fig, hspace=0.2)
    return fig


def _num(x: float) -> str:
    return "–" if x is None or not np.isfinite(x) else f"{x:.4g}"


#: Parameters shown as "in force" in the report: the rate loop, its filters, the motors and
#: the SYSTEMID settings (ArduPilot), the rate controller and gyro filters (PX4).
_PARAMS_IN_FORCE = re.compile(
    r"^(ATC_RAT_|ATC_ACCEL_|ATC_INPUT_TC|INS_GYRO_FILTER|INS_HNTCH_|INS_LOG_BAT|MOT_|SID_|"
    r"FRAME|RATE_(RLL|PIT|YAW)_|LOG_BITMASK|SCHED_LOOP_RATE|MC_(ROLL|PITCH|YAW)RATE_|"
    r"MC_.*RATE_(P|I|D|K|FF)|IMU_GYRO_CUTOFF|IMU_DGYRO_CUTOFF|IMU_GYRO_RATEMAX|SDLOG_PROFILE|"
    r"SYS_AUTOSTART|CA_AIRFRAME)")


def _verdict_html(fit: AxisFit) -> str:
    v = fit.verdict
    if v is None:
        return ""
    cls = {"good": "verdict-good", "usable": "verdict-usable"}.get(v.level, "verdict-not")
    usable = f" (for {', '.join(v.usable_for)})" if v.usable_for else ""
    return (f'<p><b class="{cls}">{html.escape(v.level)}{html.escape(usable)}</b>: '
            f"{html.escape('; '.join(v.reasons))}</p>")


def _physical(fit: AxisFit) -> str:
    """What a tuner reads first (:func:`mavsid.physical.physical_rows`): time constant,
    bandwidth, effectiveness, delay, lag, filters, with σ where the model gives them."""
    from mavsid.physical import physical_rows

    body = "".join(f'<tr><td class="name">{html.escape(r.name)}</td><td>{_num(r.value)}</td>'
                   f"<td>{'' if np.isnan(r.sigma) else _num(r.sigma)}</td>"
                   f"<td>{html.escape(r.unit)}</td></tr>" for r in physical_rows(fit))
    return ('<table><tr><th class="name">physical parameter</th><th>value</th><th>σ</th>'
            f"<th>unit</th></tr>{body}</table>")


def _aircraft(result: FitResult) -> str:
    """The aircraft and log: vehicle, firmware, frame, span, SYSTEMID runs, channels, and the
    parameters in force."""
    parts = ["<h2>Aircraft and log</h2>"]
    for fd in result.flights:
        span = float(fd.time_s[-1] - fd.time_s[0]) if len(fd.time_s) else 0.0
        frame = ", ".join(f"{k} {fd.params[k]:g}" for k in ("FRAME_CLASS", "FRAME_TYPE", "FRAME",
                                                           "SYS_AUTOSTART", "CA_AIRFRAME")
                          if k in fd.params) or "–"
        sources, units_from = fd.sources, fd.units_from
        rows = [("log", os.path.basename(fd.source.path)),
                ("format", f"{fd.source.format}, {fd.source.size_bytes} bytes"),
                ("vehicle", fd.vehicle or "–"),
                ("autopilot / firmware", f"{fd.autopilot or '–'} / {fd.firmware or '–'}"),
                ("frame", frame), ("span used", f"{span:.1f} s at {1 / fd.dt:.0f} Hz"),
                ("channel preset", fd.preset),
                ("channels", ", ".join(f"{k} ← {source_text(v, units_from.get(k))}"
                                       for k, v in sources.items()))]
        for run in fd.sysid_runs:
            rows.append(("SYSTEMID run", ", ".join(
                f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}"
                for k, v in run.to_dict().items())))
        parts.append("<table>" + "".join(
            f'<tr><td class="name">{html.escape(k)}</td><td class="name">{html.escape(v)}</td>'
            "</tr>" for k, v in rows) + "</table>")
        shown = {k: v for k, v in sorted(fd.params.items()) if _PARAMS_IN_FORCE.match(k)}
        if shown:
            parts.append(_params_table(shown))
    return "\n".join(parts)


#: the parameters table's filter: rows whose name holds the typed text
_FILTER_JS = ("var q=this.value.toUpperCase();this.parentNode.querySelectorAll('tr.p')"
              ".forEach(function(r){r.style.display=r.cells[0].textContent.indexOf(q)<0?"
              "'none':''})")


def _params_table(params: Mapping[str, float]) -> str:
    """The parameters in force as a table, filtered by name as one types."""
    rows = "".join(f'<tr class="p"><td class="name">{html.escape(k)}</td><td>{v:g}</td></tr>'
                   for k, v in params.items())
    return ('<details><summary>parameters in force (' + str(len(params)) + ')</summary>'
            f'<div><input type="search" placeholder="filter by name" oninput="{_FILTER_JS}">'
            '<table><tr><th class="name">parameter</th><th>value</th></tr>'
            f"{rows}</table></div></details>")


def _axis_section(fit: AxisFit) -> list[str]:
    """An axis's section up to its Bode figure (:func:`_bode_img`): what needs no loop
    analysis."""
    m, v = fit.model, fit.validation
    stderr = getattr(m, "stderr", {}) or {}
    units = getattr(m, "units", {}) or {}
    from mavsid.physical import parameter_order

    # the continuous-time parameters, then the discrete-time coefficients
    rows = "".join(
        f'<tr><td class="name">{html.escape(k)}</td><td>{_num(m.params[k])}</td>'
        f"<td>{_num(stderr.get(k, np.nan))}</td><td>{html.escape(str(units.get(k, '')))}</td></tr>"
        for k in parameter_order(m.params)
    )
    keys = ("one_step", horizon_label(0.5), "free_run")
    fit_rows = "".join(
        f'<tr><td class="name">{html.escape(s)}</td>'
        + "".join(f"<td>{_num(v.fit_summary(s)[k])}</td>" for k in keys)
        + f"<td>{_num(v.rmse_one_step[j])}</td><td>{_num(v.rmse_free_run[j])}</td></tr>"
        for j, s in enumerate(v.state_names)
    )
    stable = {True: "stable", False: "UNSTABLE", None: "not reported"}[v.stable]
    eig = "" if v.eigenvalues is None else ", ".join(f"{z:.4g}" for z in v.eigenvalues)
    segs = ", ".join(f"{s.start_s:.2f}–{s.stop_s:.2f} s" for s in fit.held_out)
    train = ", ".join(f"{s.start_s:.2f}–{s.stop_s:.2f} s" for s in fit.train) or "–"
    parts = [
        f"<h2>{html.escape(fit.axis)}</h2>",
        _verdict_html(fit),
        _physical(fit),
        f'<p class="meta">estimator {html.escape(fit.estimator or "–")}; '
        f"dynamics {stable}{' (eigenvalues ' + html.escape(eig) + ')' if eig else ''}; "
        f"trained on {html.escape(train)}; validated on {html.escape(segs)}</p>",
        '<table><tr><th class="name">fitted parameter</th><th>value</th><th>σ</th>'
        f"<th>unit</th></tr>{rows}</table>",
        '<table><tr><th class="name">output</th><th>fit % one step</th><th>fit % 0.5 s</th>'
        "<th>fit % free run</th><th>RMSE one step</th><th>RMSE free run</th></tr>"
        f"{fit_rows}</table>",
        figure_img(_time_figure(fit)),
        '<div class="row">'
        + figure_img(_horizon_figure(v))
        + figure_img(_residual_figure(v))
        + "</div>",
    ]
    return parts


def _answer_html(axis: str, analysis: TuneAnalysis | None) -> list[str]:
    """The axis's gains, limits and their figure (:mod:`mavsid.report_gains`)."""
    from mavsid.report_gains import gains_figure, gains_html

    if analysis is None or axis not in analysis.report:
        return []
    entry = analysis.report[axis]
    fig = gains_figure(entry)
    return [gains_html(axis, entry), *([figure_img(fig)] if fig is not None else [])]


def _bode_img(fit: AxisFit, lp: _Analysis = None) -> list[str]:
    """The axis's Bode figure (none or one) with the loop's curves, ``lp`` called only now."""
    bode = _bode_figure(fit, lp() if callable(lp) else lp)
    return [] if bode is None else [figure_img(bode)]


def render_html_page(title: str, sections: Sequence[str]) -> str:
    """Wrap body sections into one standalone HTML document."""
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>\n"
        + "\n".join(sections)
        + "\n</body></html>\n"
    )


def axis_heads(result: FitResult) -> list[list[str]]:
    """Each axis's section (in the order of ``result.axes``) up to its Bode figure: its
    tables and its time, horizon and residual figures, what :func:`render_html` draws
    without the loop analysis; drawn elsewhere when it is given them (``heads``)."""
    return [_axis_section(f) for f in result.axes.values()]


def render_html(result: FitResult, lp: _Analysis = None,
                heads: Callable[[], list[list[str]]] | None = None) -> str:
    """The report of a :class:`~mavsid.pipeline.FitResult` as one HTML string (with ``lp``,
    :func:`mavsid.loop.tune.tune_analysis` or a function that returns it, called when the
    first Bode figure is drawn, after every axis's other figures: each axis's Bode figure
    carries the loop's curves too). ``heads``: a function returning :func:`axis_heads` of
    ``result`` (drawn by another process while this one draws the rest, asked for last)."""
    logs = ", ".join(html.escape(os.path.basename(p)) for p in result.logs)
    presets = ", ".join(sorted({html.escape(fd.preset) for fd in result.flights}))
    header = (
        f"<h1>mavsid fit: {logs}</h1>"
        f'<p class="meta">mavsid {__version__}; pipeline {html.escape(result.config.name)}; '
        f"channel preset {presets or '–'}. Fit % = 100·(1 − ‖y − ŷ‖ / ‖y − ȳ‖) on segments "
        "held out from fitting; free run feeds the model its own predictions with measured "
        "inputs, from each segment's first state and with its own trim (the constant term "
        "re-estimated on it).</p>"
    )
    summary_rows = "".join(
        f'<tr><td class="name">{html.escape(a)}</td><td class="name">{html.escape(f.output)}</td>'
        + "".join(
            f"<td>{_num(f.validation.fit_summary(f.output)[k])}</td>"
            for k in ("one_step", horizon_label(0.5), "free_run")
        )
        + "</tr>"
        for a, f in result.axes.items()
    )
    summary = (
        '<table><tr><th class="name">axis</th><th class="name">output</th>'
        "<th>fit % one step</th><th>fit % 0.5 s</th><th>fit % free run</th></tr>"
        f"{summary_rows}</table>"
    )
    verdicts = "".join(
        f'<tr><td class="name">{html.escape(a)}</td><td class="name">{html.escape(v.level)}'
        f'</td><td class="name">{html.escape("; ".join(v.reasons))}</td></tr>'
        for a, v in result.verdicts.items())
    verdict_table = ('<table><tr><th class="name">axis</th><th class="name">verdict</th>'
                     f'<th class="name">why</th></tr>{verdicts}</table>') if verdicts else ""
    # every axis's figures but the Bode ones first: ``lp`` is worked out, when it is, only
    # once they are drawn (given ``heads``, drawn elsewhere meanwhile: asked for last)
    first = axis_heads(result) if heads is None else None
    bodes = [_bode_img(f, lp) for f in result.axes.values()]
    analysis = lp() if callable(lp) else lp
    answers = [_answer_html(a, analysis) for a in result.axes]
    drawn = heads() if heads is not None else first
    assert drawn is not None
    # the answer first in each axis's section: the verdict, then the gains (or why none)
    axes = ["\n".join(head[:2] + answer + head[2:] + bode)
            for head, answer, bode in zip(drawn, answers, bodes, strict=True)]
    sections = [header, verdict_table, summary, _aircraft(result), *axes]
    return render_html_page(f"mavsid fit: {logs}", sections)


def write_report(result: FitResult, path: str | os.PathLike[str],
                 analysis: Callable[[], TuneAnalysis] | None = None,
                 heads: Callable[[], list[list[str]]] | None = None) -> None:
    """Write :func:`render_html` of ``result`` (and ``heads``) to ``path``, with
    :func:`loop_section`: the loop analysed once for both (one Bode figure per axis), by
    :func:`mavsid.loop.tune.tune_analysis` or by ``analysis`` — a function called when the
    first Bode figure is drawn, after every axis's other figures."""
    from mavsid.loop.tune import tune_analysis

    lp = functools.cache(analysis or (lambda: tune_analysis(result)))
    text = render_html(result, lp, heads)
    text = text.replace("\n</body></html>",
                        "\n" + loop_section(result, analysis=lp()) + "\n</body></html>")
    with open(path, "w", encoding="utf-8") as f:
        f.write(text)


# --------------------------------------------------------------------------- the loop


def _twin_figure(fit: AxisFit) -> Figure | None:
    cl = fit.closed_loop
    if cl is None or not cl.blocks:
        return None
    fig, axes = layout_panels("twin")
    ax = axes[0, 0]
    curves: tuple[tuple[str, str, str, float, str], ...] = (
        ("rate", "measured", _COLOURS["measured"], 0.8, "-"),
        ("rate_twin", "closed-loop twin", _COLOURS["free_run"], 0.8, "-"),
        ("baseline", "baseline (target, delayed)", "#999999", 0.6, "--"))
    for key, label, colour, lw, ls in curves:
        ax.plot(*_gapped([(b.time_s, getattr(b, key)) for b in cl.blocks]), label=label,
                color=colour, lw=lw, ls=ls)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"{fit.output} [rad/s]")
    ax.legend(fontsize=8, loc="upper right")
    ax.grid(True, alpha=0.3)
    _layout(fig, top=0.1)
    return fig


def loop_section(result: FitResult, target_pm_deg: float = 50.0, *,
                 analysis: TuneAnalysis | None = None) -> str:
    """The report's "loop" section: per axis the closed-loop twin against the measured rate
    and the baseline, the margins and bandwidth with the logged gains (± σ), suggested gains
    and next-flight advice. Given ``analysis`` (:func:`mavsid.loop.tune.tune_analysis`, as
    :func:`write_report` does) the Bode overlay of measured FRF, time-domain model and TF fit
    and the measured against the predicted broken loop are in each axis's section above (one
    figure); without it they are drawn here."""
    from mavsid.cli_format import format_tune
    from mavsid.loop.tune import tune_analysis

    lp = tune_analysis(result, target_pm_deg) if analysis is None else analysis
    if lp.error is not None:
        return f"<h2>loop</h2><p>loop analysis failed: {html.escape(lp.error)}</p>"
    report, responses = lp.report, lp.measured
    parts = ["<h2>loop</h2>",
             '<p class="meta">The identified plant inside the vehicle\'s rate controller, '
             "rebuilt from the log's parameters (mavsid.loop).</p>"]
    for axis, fit in result.axes.items():
        parts.append(f"<h3>{html.escape(axis)}</h3>")
        cl = fit.closed_loop
        if cl is not None:
            parts.append(
                f"<p>closed-loop twin on the held-out blocks: rate {_num(cl.fit_percent)} %, "
                f"controller output {_num(cl.output_fit_percent)} %; open loop "
                f"{_num(cl.open_loop_percent)} %; baseline (rate = target "
                f"{cl.baseline_delay_s * 1e3:.0f} ms later) {_num(cl.baseline_percent)} %"
                + (f"; defaults used: {html.escape(', '.join(cl.defaults_used))}"
                   if cl.defaults_used else "") + "</p>")
            twin = _twin_figure(fit)
            if twin is not None:
                parts.append(figure_img(twin))
        else:
            parts.append(f"<p>closed-loop twin not run: {html.escape(fit.closed_loop_note)}</p>")
        entry: dict[str, Any] = dict(report.get(axis, {}))
        if "error" in entry:
            parts.append(f"<p>loop not analysed: {html.escape(str(entry['error']))}</p>")
            continue
        text = format_tune({axis: entry}, answer=False)
        parts.append("<ul>" + "".join(f"<li>{html.escape(line.strip())}</li>"
                                      for line in text.splitlines()) + "</ul>")
        if "plant" not in responses.get(axis, {}):
            continue
        if analysis is not None:
            parts.append(f'<p class="meta">Bode of the plant (measured, time-domain model, TF '
                         f"fit) and of the broken loop at the mixer: in the {html.escape(axis)}"
                         " section's frequency-response figure.</p>")
            continue
        bode = _bode_figure(fit, lp)
        if bode is not None:
            parts.append(figure_img(bode))
    return "\n".join(parts)


# --------------------------------------------------------------------------- closed-loop response

_LOG_COLOURS = ("#2f6fde", "#f08a12", "#2a9d46", "#b04fc0")


def _response_time_figure(responses: Sequence[FlightResponse]) -> Figure | None:
    """Target and actual of every loop, one row each, time axes shared (per log a colour;
    several logs: each on its own clock)."""
    keys = list(dict.fromkeys((r.axis, r.loop) for fr in responses for r in fr.loops
                              if r.time_s.size))
    if not keys:
        return None
    fig = Figure(figsize=(11, 1.9 * len(keys) + 0.6))
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(keys), 1, squeeze=False, sharex=len(responses) == 1)[:, 0]
    for ax, (axis, loop) in zip(axes, keys, strict=True):
        for i, fr in enumerate(responses):
            r = fr.loop(axis, loop)
            if r is None or not r.time_s.size:
                continue
            keep = decimate(np.nan_to_num(r.actual_series), 6000)
            tag = f"{os.path.basename(fr.log)} " if len(responses) > 1 else ""
            ax.plot(r.time_s[keep], r.target_series[keep], color="#999999", lw=0.7,
                    label=f"{tag}target {r.target}")
            ax.plot(r.time_s[keep], r.actual_series[keep], lw=0.7,
                    color=_LOG_COLOURS[i % len(_LOG_COLOURS)], label=f"{tag}actual {r.actual}")
        ax.set_ylabel(f"{axis} {loop}\n[{'rad/s' if loop == 'rate' else 'rad'}]")
        ax.grid(alpha=_GRID_ALPHA)
        ax.legend(fontsize=7, loc="upper right")
    axes[-1].set_xlabel("log time (s)")
    fig.tight_layout()
    return fig


def _response_step_figure(responses: Sequence[FlightResponse], axis: str, loop: str
                          ) -> Figure | None:
    """The step responses of one loop with their bands, one per log, overlaid."""
    found = [(i, fr, r) for i, fr in enumerate(responses)
             if (r := fr.loop(axis, loop)) is not None and r.step is not None]
    if not found:
        return None
    fig = Figure(figsize=(5.4, 3.6))
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    for i, fr, r in found:
        assert r.step is not None
        s, colour = r.step, _LOG_COLOURS[i % len(_LOG_COLOURS)]
        ax.fill_between(s.time_s, s.lower, s.upper, color=colour, alpha=0.25, lw=0)
        ax.plot(s.time_s, s.response, color=colour,
                label=f"{os.path.basename(fr.log)}: {s.windows} windows")
    ax.axhline(1.0, color="#666666", lw=0.6, ls="--")
    ax.set_xlabel("time after the step (s)")
    ax.set_ylabel("response")
    ax.set_title(f"{axis} {loop}: step response (band: ±2 SE and truncation)", fontsize=9)
    ax.grid(alpha=_GRID_ALPHA)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def _response_spectrum_figure(responses: Sequence[FlightResponse], axis: str
                              ) -> Figure | None:
    """Gyro and controller-output spectra of one axis, the filters' cut-offs marked."""
    found = [(i, sp) for i, fr in enumerate(responses) for sp in fr.spectra.get(axis, ())
             if np.any(sp.psd > 0)]
    if not found:
        return None
    fig = Figure(figsize=(5.4, 3.6))
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    marked: dict[str, float] = {}
    for i, sp in found:
        ok = (sp.freq_hz > 0) & (sp.psd > 0)
        ls = "-" if sp.name.startswith("gyro") else ":"
        ax.loglog(sp.freq_hz[ok], sp.psd[ok], ls, lw=0.9,
                  color=_LOG_COLOURS[i % len(_LOG_COLOURS)],
                  label=sp.name + (f" ({i + 1})" if len(responses) > 1 else ""))
        marked.update(sp.cutoffs)
    at: dict[float, list[str]] = {}
    for name, hz in marked.items():
        at.setdefault(hz, []).append(name)
    for hz, names in at.items():
        ax.axvline(hz, color="#b04fc0", lw=0.7, ls="--")
        ax.text(hz, 1.0, f" {', '.join(names)} {hz:g} Hz", rotation=90, va="top", fontsize=6,
                transform=ax.get_xaxis_transform())
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("PSD (unit²/Hz)")
    ax.set_title(f"{axis}: gyro (solid) and controller output (dotted)", fontsize=9)
    ax.grid(alpha=_GRID_ALPHA, which="both")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def response_section(responses: Sequence[FlightResponse], title: str = "Closed-loop response"
                     ) -> str:
    """The closed-loop responses as HTML: a table of every loop's figures and verdict, the
    target and actual over time, per loop the step responses overlaid, per axis spectra."""
    def cell(v: float | None, scale: float = 1.0) -> str:
        return "–" if v is None else f"{v * scale:.3g}"

    rows = "".join(
        f'<tr><td class="name">{html.escape(os.path.basename(fr.log))}</td>'
        f'<td class="name">{r.axis}</td><td class="name">{r.loop}</td>'
        f"<td>{cell(r.rise_s, 1e3)}</td><td>{cell(r.overshoot_pct)}</td>"
        f"<td>{cell(r.settling_s, 1e3)}</td><td>{cell(r.bandwidth_hz)}</td>"
        f"<td>{cell(r.phase_delay_s, 1e3)}</td><td>{cell(r.delay_s, 1e3)}</td>"
        f'<td class="name">{html.escape(r.verdict)}</td></tr>'
        for fr in responses for r in fr.loops)
    parts = [f"<h2>{html.escape(title)}</h2>",
             '<p class="meta">Step responses by Tikhonov-regularised deconvolution of target '
             "to actual over half-overlapping windows with target activity (mean of the "
             "windows; band: two standard errors of the mean and the change when the "
             "deconvolution is cut at half its length). Bandwidth: where the measured "
             "closed-loop response first falls 3 dB, inside its coherent band.</p>",
             '<table><tr><th class="name">log</th><th class="name">axis</th>'
             '<th class="name">loop</th><th>rise ms</th><th>overshoot %</th>'
             "<th>settling ms</th><th>bandwidth Hz</th><th>phase delay ms</th>"
             f'<th>delay ms</th><th class="name">verdict</th></tr>{rows}</table>']
    for fr in responses:
        for st in fr.settings:
            changed = ", ".join(f"{k}={v:g}" for k, v in st.changed.items()) or "first"
            parts.append(f'<p class="meta">{html.escape(os.path.basename(fr.log))}: setting '
                         f"{st.start_s:.1f}–{st.stop_s:.1f} s ({html.escape(changed)}): "
                         + "; ".join(html.escape(f"{r.axis} {r.loop} rise "
                                                 f"{cell(r.rise_s, 1e3)} ms, overshoot "
                                                 f"{cell(r.overshoot_pct)} %")
                                     for r in st.loops if r.step is not None) + "</p>")
    time_fig = _response_time_figure(responses)
    if time_fig is not None:
        parts.append(figure_img(time_fig))
    keys = list(dict.fromkeys((r.axis, r.loop) for fr in responses for r in fr.loops))
    figs = [f for axis, loop in keys if (f := _response_step_figure(responses, axis, loop))]
    figs += [f for axis in dict.fromkeys(a for a, _ in keys)
             if (f := _response_spectrum_figure(responses, axis))]
    parts.append('<div class="row">' + "".join(figure_img(f) for f in figs) + "</div>")
    return "\n".join(parts)


def write_response_report(responses: Sequence[FlightResponse], path: str | os.PathLike[str],
                          *, title: str = "mavsid response", notes: Sequence[str] = ()
                          ) -> None:
    """Write the page of ``mavsid response``: :func:`response_section` of ``responses``,
    under ``notes`` (lines shown first: why a fit identified nothing, its verdicts)."""
    logs = ", ".join(os.path.basename(fr.log) for fr in responses)
    header = (f"<h1>{html.escape(title)}: {html.escape(logs)}</h1>"
              f'<p class="meta">mavsid {__version__}</p>')
    said = ("<ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in notes) + "</ul>"
            if notes else "")
    body = (response_section(responses) if responses else
            "<p>No closed-loop response either: the logs have no rate target nor "
            "commanded attitude.</p>")
    text = render_html_page(f"{title}: {logs}", [header, said, body])
    with open(path, "w", encoding="utf-8") as f:
        f.write(text)
