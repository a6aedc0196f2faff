"""The report's answer per axis, first in the axis's section: the verdict, the current
against the suggested gains (or why none), the limits with their values for both, and one
figure — the step response and the broken loop's Bode, current and suggested overlaid,
crossover and phase margin marked. Made from :func:`mavsid.loop.tune.tune`'s entry.

Examples
--------
>>> html_ = gains_html("yaw", {"verdict": "good", "gains": [], "no_gains_reason": "why"})
>>> "no gains" in html_ and "why" in html_
True
"""

from __future__ import annotations

import html
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from mavsid.cli_format import gain_table, limit_table, tune_notes

__all__ = ["gains_figure", "gains_html", "sig_text"]

_COLOURS = {"current": "#555555", "suggested": "#1f77b4", "twin": "#ff7f0e"}


def sig_text(v: float | None, sd: float | None = None) -> str:
    """``v`` with as many digits as its σ carries (two of σ), ``v ± σ``; 4 significant
    digits without a σ; ``–`` when there is no value.

    Examples
    --------
    >>> sig_text(180.2345, 3.14), sig_text(0.0123456, 0.00021), sig_text(12.3456)
    ('180.2 ± 3.1', '0.01235 ± 0.00021', '12.35')
    """
    if v is None or not math.isfinite(v):
        return "–"
    if sd is None or not math.isfinite(sd) or sd <= 0:
        return f"{v:.4g}"
    decimals = max(0, 1 - math.floor(math.log10(sd)))
    return f"{v:.{decimals}f} ± {sd:.{decimals}f}"


def _table(rows: list[list[str]], names: int = 1) -> str:
    """An HTML table of text rows (header first); the first ``names`` columns left-aligned."""
    def cells(row: list[str], tag: str) -> str:
        return "".join(f'<{tag}{" class=name" if i < names else ""}>{html.escape(c)}</{tag}>'
                       for i, c in enumerate(row))
    head, *body = rows
    return ("<table><tr>" + cells(head, "th") + "</tr>"
            + "".join("<tr>" + cells(r, "td") + "</tr>" for r in body) + "</table>")


def gains_html(axis: str, e: Mapping[str, Any]) -> str:
    """The answer block of one axis (verdict, gain table or the one line why none, limits,
    the margins it is about, the next flight) as HTML."""
    if "error" in e:
        return f"<p>loop not analysed: {html.escape(str(e['error']))}</p>"
    verdict = str(e.get("verdict", "not identified"))
    parts = [f'<h3>{html.escape(axis)}: gains (verdict {html.escape(verdict)})</h3>']
    if e.get("gains"):
        parts.append(_table(gain_table(e["gains"])))
        if e.get("suggested_note"):
            parts.append(f"<p>{html.escape(str(e['suggested_note']))}</p>")
    else:
        parts.append(f"<p><b>no gains</b>: {html.escape(str(e.get('no_gains_reason', '–')))}"
                     "</p>")
    if e.get("limits"):
        parts.append(_table(limit_table(e["limits"]), names=2))
    notes = []
    if e.get("aim"):
        notes.append(f"the margins are those of {e['aim']}")
    agree = e.get("loop_agreement")
    if agree:
        notes.append(
            "at the mixer (rate and attitude loops) the phase margin is measured "
            f"{sig_text(agree['measured_deg'], agree['measured_sigma_deg'])} deg, predicted "
            f"{sig_text(agree['predicted_deg'], agree['predicted_sigma_deg'])} deg"
            + ("" if agree["agree"] else " (they disagree)"))
    notes += tune_notes(e)
    parts += [f'<p class="meta">{html.escape(n)}</p>' for n in notes]
    return "\n".join(parts)


def gains_figure(e: Mapping[str, Any]) -> Figure | None:
    """Step response and broken-loop Bode (``|L|``, phase) of the current and the
    suggested gains (the suggested also as flown in the twin), gain crossover and phase
    margin marked; None without the current loop's check."""
    cur = e.get("current_loop")
    if not cur:
        return None
    from mavsid.report import layout_panels, log_minor

    fig, axes = layout_panels("gains")  # (built beforehand in the report worker)
    step_ax, mag_ax, ph_ax = axes[0]
    loops = [("current", cur)]
    if e.get("suggested_loop_check"):
        loops.append(("suggested" if e.get("gains") else "suggested (refused)",
                      e["suggested_loop_check"]))
    for label, c in loops:
        colour = _COLOURS["current" if label == "current" else "suggested"]
        ls = "-" if label in ("current", "suggested") else ":"
        step_ax.plot(c["step"]["time_s"], c["step"]["rate"], color=colour, ls=ls, label=label)
        f = np.asarray(c["loop"]["frequency_hz"])
        mag_ax.semilogx(f, c["loop"]["magnitude_db"], color=colour, ls=ls, label=label)
        ph_ax.semilogx(f, c["loop"]["phase_deg"], color=colour, ls=ls, label=label)
        wc, pm = c["crossover_hz"], c["phase_margin_deg"]
        if wc is not None and math.isfinite(wc):
            mag_ax.axvline(wc, color=colour, lw=0.6, ls="--")
            ph_ax.axvline(wc, color=colour, lw=0.6, ls="--")
            if pm is not None and math.isfinite(pm):
                ph_ax.annotate("", xy=(wc, -180.0), xytext=(wc, -180.0 + pm),
                               arrowprops={"arrowstyle": "<->", "color": colour})
                ph_ax.text(wc * 1.1, -180.0 + pm / 2, f"PM {pm:.0f}°", color=colour,
                           fontsize=8)
    twin = e.get("twin_step")
    if twin and e.get("gains"):
        step_ax.plot(twin["time_s"], twin["rate"], color=_COLOURS["twin"], ls="--", lw=0.8,
                     label="suggested, twin")
    step_ax.set_xlabel("time [s]")
    step_ax.set_ylabel("rate per unit target step")
    step_ax.legend(fontsize=7, loc="lower right")
    mag_ax.axhline(0.0, color="#999999", lw=0.6)
    mag_ax.set_ylabel("|L| [dB]")
    ph_ax.axhline(-180.0, color="#999999", lw=0.6)
    ph_ax.set_ylabel("phase of L [deg]")
    for ax in (mag_ax, ph_ax):
        ax.set_xlabel("frequency [Hz]")
    for ax in (step_ax, mag_ax, ph_ax):
        ax.grid(True, alpha=0.3)
    mag_ax.set_ylim(-40, 40)
    top = e.get("trusted_band", {}).get("top_hz")
    if top:
        mag_ax.axvspan(0.5 * top, top, color="#f0c0c0", alpha=0.3, lw=0)
    mag_ax.set_title("broken rate loop (shaded: above half the trusted band)", fontsize=8)
    for ax in (mag_ax, ph_ax):  # (the minor ticks as two artists, decades plain numbers)
        log_minor(ax, grid=False)
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.16, top=0.9, wspace=0.3)
    return fig

