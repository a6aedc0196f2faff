"""The human-readable text of the loop commands (``mavsid tune``, the report's loop
section): made from the data :func:`mavsid.loop.tune.tune` returns."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

__all__ = ["figure", "format_tune"]

def figure(v: float | None, fmt: str, unit: str, sd: float | None = None) -> str:
    """A loop figure as ``mavsid tune`` prints it, with its σ; ``none`` where it does not
    exist (a loop whose gain never crosses 1 has no phase margin nor crossover; an unstable
    one no rise time).

    Examples
    --------
    >>> figure(34.12, ".1f", "deg", 1.5), figure(float("inf"), ".1f", "deg", 1.5)
    ('34.1 ± 1.5 deg', 'none')
    """
    if v is None or not math.isfinite(v):
        return "none"
    return f"{v:{fmt}}" + (f" ± {sd:{fmt}}" if sd is not None and math.isfinite(sd)
                           else "") + f" {unit}"


def format_tune(report: Mapping[str, Any]) -> str:
    """The text ``mavsid tune`` prints."""
    lines = []
    for axis, e in report.items():
        if "error" in e:
            lines.append(f"{axis}: loop not analysed: {e['error']}")
            continue
        m, c, sd = e["margins"], e["closed_loop"], e.get("stderr", {})

        def pm(v: float, key: str, fmt: str, unit: str,
               sd: Mapping[str, float] = sd) -> str:
            return figure(v, fmt, unit, sd.get(key))

        lines.append(
            f"{axis}: phase margin {pm(m['phase_deg'], 'phase_margin_deg', '.1f', 'deg')}, "
            f"gain margin {pm(m['gain_db'], 'gain_margin_db', '.1f', 'dB')}, crossover "
            f"{pm(m['crossover_hz'], 'crossover_hz', '.2f', 'Hz')}; closed-loop bandwidth "
            f"{pm(c['bandwidth_hz'], 'bandwidth_hz', '.2f', 'Hz')}, peak "
            f"{figure(c['peak_db'], '.1f', 'dB')}, rise "
            f"{figure(c['rise_time_s'] * 1e3, '.0f', 'ms')}, overshoot "
            f"{figure(c['overshoot_percent'], '.0f', '%')}")
        if "loop_frf_margins" in e:
            mm, pr = e["loop_frf_margins"], e["loop_predicted_margins"]
            cmp_ = e["loop_frf_vs_predicted"]
            lines.append(
                f"  at the mixer (rate and attitude loops): measured phase margin "
                f"{figure(mm['phase_deg'], '.1f', 'deg')} at "
                f"{figure(mm['crossover_hz'], '.2f', 'Hz')}, predicted "
                f"{figure(pr['phase_deg'], '.1f', 'deg')} at "
                f"{figure(pr['crossover_hz'], '.2f', 'Hz')}; prediction within "
                f"{cmp_['median_db']:.1f} dB / {cmp_['median_deg']:.1f} deg (median) over "
                f"{cmp_['band_hz'][0]:.2g}-{cmp_['band_hz'][1]:.2g} Hz")
        if e.get("gains_mismatch"):
            lines.append(f"  warning: {e['gains_mismatch']}")
        if e.get("suggested"):
            lines.append("  suggested: " + ", ".join(f"{k} {v:.4g}"
                                                     for k, v in e["suggested"].items()))
        if e.get("suggested_note"):
            lines.append(f"  {e['suggested_note']}")
        lines += [f"  advice: {a}" for a in e.get("advice", [])]
    return "\n".join(lines)
