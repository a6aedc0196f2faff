"""The gates a window must pass, each failed one a :class:`~mavsid.reasons.Reason` (its kind
and numbers, the message made from them), and the sentence a kept window gives.

The measures gated are :mod:`mavsid.excitation_scores`'; the windows,
:mod:`mavsid.excitation`.

Examples
--------
>>> gate = Reason("input_below_floor", {"rms": 2e-4, "need_ratio": 5.0, "floor": 1e-3},
...               {"input": "u_roll"})
>>> rejected([gate]) == ("rejected: " + gate.message,)
True
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from mavsid.data import FlightData
from mavsid.excitation_scores import AxisSignals, ScanOptions
from mavsid.reasons import Reason, format_number

__all__ = ["gates", "kept_reason", "rejected"]


def gates(ax: AxisSignals, fd: FlightData, i0: int, i1: int, m: Mapping[str, float],
           opts: ScanOptions, st: Mapping[str, Any], check_mode: bool,
           check_excitation: bool = True) -> list[Reason]:
    """Rejection reasons (empty: passes); ``st``: the window's :func:`window_stats`."""
    out: list[Reason] = []
    if ax.u is None:
        return [Reason("missing_channel", {}, {"channel": ax.u_name, "role": "input",
                                               "preset": fd.preset})]
    if ax.y is None:
        return [Reason("missing_channel", {}, {"channel": ax.y_name, "role": "output",
                                               "preset": fd.preset})]
    frac = float(st["airborne"])
    if frac < opts.min_airborne:
        out.append(Reason("not_airborne", {"grounded_pct": 100 * (1 - frac),
                                           "need_pct": 100 * opts.min_airborne}))
    mode = fd.flags.get("mode")
    k = int(st.get("mode_change", -1))
    if check_mode and mode is not None and k >= 0:
        names = fd.mode_names
        a, b = (names.get(int(v), str(int(v))) for v in (mode[i0 + k], mode[i0 + k + 1]))
        out.append(Reason("mode_change", {"at_s": float(fd.time_s[i0 + k + 1])},
                          {"from": str(a), "to": str(b)}))
    for ang in ("roll", "pitch"):
        if f"peak_{ang}" in st:
            peak = float(np.degrees(st[f"peak_{ang}"]))
            if peak > opts.max_angle_deg:
                out.append(Reason("attitude_bound", {"peak_deg": peak,
                                                     "bound_deg": opts.max_angle_deg},
                                  {"angle": ang}))
    sat = float(st["saturated"])
    if sat > opts.max_saturated:
        out.append(Reason("input_saturated", {"saturation": opts.saturation,
                                              "saturated_pct": 100 * sat,
                                              "limit_pct": 100 * opts.max_saturated},
                          {"input": ax.u_name}))
    ts = float(st.get("thrust_limits", math.nan))  # (NaN: no thrust, or never airborne)
    if ts > opts.max_saturated:
        out.append(Reason("thrust_limits", {"saturated_pct": 100 * ts,
                                            "limit_pct": 100 * opts.max_saturated}))
    if not check_excitation:
        return out
    if "power_ratio" not in m:
        out.append(Reason("too_short", {"samples": float(i1 - i0)}))
        return out
    names_uy = {"input": ax.u_name, "output": ax.y_name}
    ratio = m.get("response_ratio", math.nan)
    # (a SYSTEMID run with its injection logged is judged by the output's coherence with
    # the injection, below, not by these levels)
    by_level = "injection_rms" not in m
    if by_level and not math.isfinite(ratio):  # no output to judge by: the input's own level
        if m["power_ratio"] < opts.power_ratio:
            out.append(Reason("input_below_floor", {"rms": m["input_rms"],
                                                    "need_ratio": opts.power_ratio,
                                                    "floor": ax.floor}, names_uy))
    elif by_level and ratio < opts.power_ratio and not _commanded(m, opts):
        out.append(Reason("response_below_floor", {
            "rms": m["response_rms"], "need_ratio": opts.power_ratio,
            "floor": m["response_floor"], "input_ratio": m["power_ratio"]}, names_uy))
    cond = m.get("condition", math.inf)
    if not cond <= opts.max_condition:
        rho, share = m.get("correlation", math.nan), m.get("input_share", math.nan)
        cause = ("constant" if not math.isfinite(rho) else
                 "other_axis" if share < 0.5 else "feedback")
        out.append(Reason("ill_conditioned", {
            "condition": cond, "max_condition": opts.max_condition, "correlation": rho,
            "input_share_pct": 100 * share}, {**names_uy, "cause": cause}))
    if "injection_rms" in m:  # SYSTEMID: the output against the logged injection
        band = {"lo_hz": m["injection_lo_hz"], "hi_hz": m["injection_hi_hz"]}
        if m.get("injection_coverage", 0.0) < opts.min_coverage:
            out.append(Reason("injection_coverage", {
                "coverage_pct": 100 * m.get("injection_coverage", 0.0),
                "need_pct": 100 * opts.min_coverage, **band}, names_uy))
        if m.get("injection_coherence", 0.0) < opts.min_coherence:
            out.append(Reason("injection_coherence", {
                "coherence": m.get("injection_coherence", 0.0),
                "min_coherence": opts.min_coherence, **band}, names_uy))
        return out
    band = {"lo_hz": m.get("band_lo_hz", 0.0), "hi_hz": m.get("band_hi_hz", 0.0)}
    if m.get("coverage", 0.0) < opts.min_coverage and not _commanded(m, opts):
        out.append(Reason("coverage", {"coverage_pct": 100 * m.get("coverage", 0.0),
                                       "need_pct": 100 * opts.min_coverage, **band}))
    if m.get("coherence", 0.0) < opts.min_coherence:
        out.append(Reason("coherence", {"coherence": m.get("coherence", 0.0),
                                        "min_coherence": opts.min_coherence, **band},
                          names_uy))
    return out


def rejected(reasons: Sequence[Reason]) -> tuple[str, ...]:
    """The reasons as the report's sentences (``rejected: ...``)."""
    return tuple(f"rejected: {r.message}" for r in reasons)


def _commanded(m: Mapping[str, float], opts: ScanOptions) -> bool:
    """Whether the window's response follows the pilot's command (*command* in
    :mod:`mavsid.excitation_scores`)."""
    return (m.get("command_coherence", 0.0) >= opts.min_coherence
            and m.get("command_coverage", 0.0) >= opts.min_coverage)


def kept_reason(ax: AxisSignals, m: Mapping[str, float]) -> str:
    if "response_ratio" in m and math.isfinite(m["response_ratio"]):
        level = (f"{ax.y_name} response RMS {format_number(m['response_rms'])} = "
                 f"{m['response_ratio']:.0f}× its noise floor")
    else:
        level = f"input RMS {format_number(m['input_rms'])} = {m['power_ratio']:.0f}× noise floor"
    if "injection_rms" in m:
        return (
            f"kept: {level}; injection (SIDD.Targ) RMS {format_number(m['injection_rms'])} over "
            f"{m['injection_lo_hz']:.3g}–{m['injection_hi_hz']:.3g} Hz, coherent with "
            f"{ax.y_name} over {100 * m.get('injection_coverage', 0):.0f} % of it (mean "
            f"{m.get('injection_coherence', 0):.2f}); Gram condition "
            f"{format_number(m.get('condition', math.inf))}"
        )
    if "command_coherence" in m:
        what = "yaw rate" if ax.name == "yaw" else "attitude"
        source = f" ({ax.command_from})" if ax.command_from else ""
        level += (f", coherent with the commanded {what}{source} over "
                  f"{100 * m['command_coverage']:.0f} % of the band (mean "
                  f"{m['command_coherence']:.2f})")
    return (
        f"kept: {level}; band coverage {100 * m.get('coverage', 0):.0f} %; "
        f"{ax.u_name}→{ax.y_name} coherence {m.get('coherence', 0):.2f}; Gram condition "
        f"{format_number(m.get('condition', math.inf))}"
    )
