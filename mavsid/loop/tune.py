"""Gains for a target phase margin (:func:`suggest_gains`) and the per-axis loop report
``mavsid tune`` gives (:func:`tune`, :func:`tune_analysis`): the logged gains' loop, the
measured responses, the suggestion under its stated limits and next-flight advice, as data
(the text is :func:`mavsid.cli_format.format_tune`'s).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mavsid import dsp
from mavsid.errors import ConfigError, MavsidError
from mavsid.loop.analysis import (
    LoopAnalysis,
    analyse_model,
    analyse_plant,
    compare_response,
    controller_polys,
    frd_margins,
    margin_grid,
    margins_of,
    margins_on_frf,
)
from mavsid.loop.controllers import (
    AXES,
    AxisController,
    autopilot_of,
    controller_from_params,
    gain_params,
    measurement_filter,
    scale_of,
    scaled,
)
from mavsid.loop.plant import as_plant, plant_from_model, plant_response
from mavsid.loop.twin import twin_signals

__all__ = [
    "LOOP_MISMATCH_DB",
    "LOOP_MISMATCH_DEG",
    "SUGGESTION_CHECK_DEG",
    "TuneAnalysis",
    "suggest_gains",
    "tune",
    "tune_analysis",
]

def suggest_gains(plant_ss: Any, ctrl: AxisController, target_pm_deg: float = 50.0,
                  lag: int = 0, meas_delay: float = 0.0
                  ) -> tuple[dict[str, float], LoopAnalysis] | None:
    """P, I and D scaled together (ratios and filters kept) so that the loop's phase margin
    is ``target_pm_deg``; the vehicle's parameter names and units, and the predicted loop
    (:func:`analyse_plant`). None when no scale in [0.05, 20] reaches it with a stable loop.
    ``plant_ss``: a :class:`LinearPlant` or a discrete python-control state space at the
    controller's step (``lag``, ``meas_delay``: see :func:`analyse_plant`)."""
    plant = as_plant(plant_ss)
    dt = 1.0 / ctrl.loop_hz
    tau, num, den = measurement_filter(meas_delay)
    # P, I and D scaled by k scale C_fb, so the loop, by k: one state space and one
    # response on the margins' grid serve every k (the closed loop's state matrix is
    # A − k·B·C / (1 + k·D)); the same margins as building each scaled loop, to rounding
    cfb, _ = controller_polys(ctrl, dt)
    if tau:
        cfb = (np.polymul(cfb[0], num), np.polymul(cfb[1], den))
    # the plant, then the controller (python-control's ``C_fb * P``)
    ac, bc, cc, dc = dsp.tf2ss(*cfb)
    ap, bp, cp = plant.a, plant.b.reshape(-1, 1), plant.c.reshape(1, -1)
    n_p, n_c = ap.shape[0], ac.shape[0]
    a = np.zeros((n_p + n_c,) * 2)
    a[:n_p, :n_p] = ap
    a[n_p:, :n_p] = bc @ cp
    a[n_p:, n_p:] = ac
    b = np.concatenate([bp, np.zeros((n_c, 1))])
    c = np.concatenate([dc @ cp, cc], axis=1)
    fm = margin_grid(dt)
    with np.errstate(all="ignore"):
        zm = np.exp(2j * np.pi * fm * dt)
        unit_resp = plant_response(plant, fm) * np.polyval(cfb[0], zm) / np.polyval(cfb[1], zm)

    def pm(k: float) -> float:
        closed = a - k * (b @ c)
        if np.any(np.abs(np.linalg.eigvals(closed)) >= 1.0):
            return -1e9  # unstable closed loop
        with np.errstate(all="ignore"):
            margin = margins_of(fm, k * unit_resp)[1]
        return float(margin) if np.isfinite(margin) else 1e9

    ks = np.geomspace(0.05, 20.0, 25)
    vals = np.array([pm(k) for k in ks])
    ok = np.flatnonzero((vals[:-1] >= target_pm_deg) & (vals[1:] < target_pm_deg))
    if not ok.size:
        return None
    lo, hi = float(ks[ok[0]]), float(ks[ok[0] + 1])
    for _ in range(20):
        mid = np.sqrt(lo * hi)
        lo, hi = (mid, hi) if pm(mid) >= target_pm_deg else (lo, mid)
    new = scaled(ctrl, lo)
    result = analyse_plant(plant, new, lag, meas_delay=tau)
    if not (np.isfinite(result.phase_margin_deg) and result.gain_margin_db > 0):
        return None
    return gain_params(new), result


def _advice(axis: str, fit: Any, ctrl: AxisController, bandwidth_hz: float,
            plant_frf: Any) -> list[str]:
    """What to change next flight, from what this one showed."""
    out: list[str] = []
    rate_hz = 1.0 / fit.validation.dt
    if np.isfinite(bandwidth_hz) and rate_hz < 5 * bandwidth_hz:
        out.append(
            f"{axis}: the log's {rate_hz:.0f} Hz cannot resolve a {bandwidth_hz:.1f} Hz rate "
            "loop: log rates at the loop rate (ArduPilot LOG_BITMASK ATTITUDE_FAST and "
            "PID, or INS_RAW_LOG_OPT; PX4 SDLOG_PROFILE 'high rate' / 'system identification')")
    if plant_frf is not None:
        band = plant_frf.band()
        want_lo = 0.5
        want_hi = min(0.4 * rate_hz, max(3 * bandwidth_hz if np.isfinite(bandwidth_hz) else 20.0,
                                          20.0))
        if band is None:
            out.append(f"{axis}: no coherent band: raise SID_MAGNITUDE (PX4: the "
                       "system-identification chirp amplitude) and fly SID_AXIS "
                       f"{10 + AXES.index(axis)}")
        else:
            f_lo, f_hi = float(plant_frf.freq_hz[0]), float(plant_frf.freq_hz[-1])
            if band[0] > 1.2 * want_lo:
                why = ("the chirp started there" if band[0] <= 1.05 * f_lo
                       else "coherence is lost below: raise SID_MAGNITUDE or lengthen SID_T_REC")
                out.append(f"{axis}: coherent only from {band[0]:.2f} Hz ({why}): set "
                           f"SID_F_START_HZ {want_lo:g}")
            if band[1] < 0.8 * want_hi:
                why = ("the chirp stopped there" if band[1] >= 0.95 * f_hi
                       else "coherence is lost above: raise SID_MAGNITUDE")
                out.append(f"{axis}: coherent only up to {band[1]:.1f} Hz ({why}); the loop "
                           f"needs up to {want_hi:.0f} Hz: set SID_F_STOP_HZ {want_hi:.0f}")
    u = np.concatenate([s.inputs[:, s.input_names.index(f"u_{axis}")]
                        for s in (*fit.train, *fit.held_out)])
    peak = float(np.max(np.abs(u))) if u.size else 0.0
    if peak > 0.8:
        out.append(f"{axis}: the controller output reached {peak:.2f} of full scale: lower "
                   "SID_MAGNITUDE")
    if ctrl.defaults_used:
        out.append(f"{axis}: the log lacks {', '.join(ctrl.defaults_used)} (defaults assumed): "
                   "log the parameters")
    return out


def tune(result: Any, target_pm_deg: float = 50.0, samples: int = 40,
         measured_out: dict[str, dict[str, Any]] | None = None,
         analyses_out: dict[str, LoopAnalysis] | None = None) -> dict[str, Any]:
    """Per fitted axis of a :class:`mavsid.pipeline.FitResult`: the loop with the logged
    gains (margins, closed loop, uncertainties), the plant FRF and TF fit for SYSTEMID data,
    gains for ``target_pm_deg`` (only when the axis's verdict is ``good``) and next-flight
    advice. The JSON form of ``mavsid tune --json``.

    ``measured_out``, when given, receives per axis the :func:`measured_responses` used (the
    FRF objects), so that a caller plotting them does not measure them again; likewise
    ``analyses_out`` the :class:`LoopAnalysis` with the logged gains (its responses)."""
    from mavsid.frequency import fit_tf, measured_responses

    out: dict[str, Any] = {}
    known = getattr(result, "twins", None)  # (those the fit read, else once for every axis)
    signals = (list(known) if known is not None and len(known) == len(result.flights)
               else [twin_signals(fd) for fd in result.flights])
    for axis, fit in result.axes.items():
        entry: dict[str, Any] = {}
        fd = result.flights[0]
        try:
            ctrl = controller_from_params(fd.params, axis, autopilot_of(fd))
        except ConfigError as exc:  # (a damaged gain: this axis only)
            out[axis] = {"error": f"{fd.source.path}: {exc}"}
            continue
        lag = fit.closed_loop.lag_loops if fit.closed_loop is not None else 0
        tau = fit.closed_loop.measurement_delay_loops if fit.closed_loop is not None else 0.0
        entry["controller"] = ctrl.to_dict()
        try:
            an = analyse_model(fit.model, axis, ctrl, lag, samples=samples, meas_delay=tau)
        except (MavsidError, ValueError, np.linalg.LinAlgError) as exc:
            entry["error"] = str(exc)
            out[axis] = entry
            continue
        entry.update(an.to_dict())
        if analyses_out is not None:
            analyses_out[axis] = an
        plant = None
        measured = measured_responses(fit, result.flights, signals, lag=lag)
        if measured_out is not None:
            measured_out[axis] = measured
        if "plant" in measured:
            plant = measured["plant"]
            entry["plant_frf"] = plant.to_dict()
            try:
                entry["plant_tf"] = fit_tf(plant).to_dict()
            except MavsidError as exc:
                entry["plant_tf_note"] = str(exc)
        if "loop" in measured:
            entry["loop_frf"] = measured["loop"].to_dict()
            entry["loop_frf_margins"] = frd_margins(measured["loop"])
            entry["loop_predicted_margins"] = frd_margins(measured["loop"], an.freq_hz,
                                                          an.mixer_loop_response)
            entry["loop_frf_vs_predicted"] = compare_response(
                measured["loop"], an.freq_hz, an.mixer_loop_response)
        if "closed_loop" in measured:
            entry["closed_loop_frf"] = measured["closed_loop"].to_dict()
            entry["closed_loop_frf_vs_predicted"] = compare_response(
                measured["closed_loop"], an.freq_hz, an.closed_response)
        level = fit.verdict.level if fit.verdict is not None else "not identified"
        entry["verdict"] = level
        mismatch = _gains_mismatch(entry.get("loop_frf_vs_predicted"), ctrl)
        if mismatch:
            entry["gains_mismatch"] = mismatch
        if level != "good":
            entry["suggested"] = {}
            entry["suggested_note"] = f"no gains suggested: the plant model is {level}"
        elif mismatch:
            entry["suggested"] = {}
            entry["suggested_note"] = ("no gains suggested: the logged gains they would scale "
                                       "do not describe this flight")
        else:
            got = suggest_gains(plant_from_model(fit.model, axis, 1.0 / ctrl.loop_hz), ctrl,
                                target_pm_deg, lag, tau)
            if got is None:
                entry["suggested"] = {}
                entry["suggested_note"] = (f"no P/I/D scale gives {target_pm_deg:g} deg phase "
                                           "margin with a stable loop")
            else:
                entry["suggested"] = {k: float(v) for k, v in got[0].items()}
                entry["suggested_loop"] = {k: v for k, v in got[1].to_dict().items()
                                           if k != "stderr"}
                if plant is not None:
                    k = scale_of(got[0], ctrl)
                    check = margins_on_frf(plant, scaled(ctrl, k))
                    entry["suggested_check"] = check
                    if abs(check["phase_deg"] - target_pm_deg) > SUGGESTION_CHECK_DEG:
                        entry["suggested_note"] = (
                            f"on the measured frequency response these gains give "
                            f"{check['phase_deg']:.0f} deg, not {target_pm_deg:g}: the model "
                            "is uncertain near the new crossover; step the gains up gradually")
        entry["advice"] = _advice(axis, fit, ctrl, an.bandwidth_hz, plant)
        out[axis] = entry
    return out


#: a suggestion whose phase margin on the measured FRF differs more than this (deg) is flagged
SUGGESTION_CHECK_DEG = 5.0

#: the loop predicted from the logged gains and the model, against the loop measured in flight
#: (SYSTEMID at the mixer), median over the coherent band: off by more than this in gain (dB,
#: a factor 2) or phase (deg), the logged gains are not the ones flown (a damaged or changed
#: parameter). Simulated flights of every vehicle, with and without gyro noise: 0.15-0.6 dB
#: and 0.3-2 deg.
LOOP_MISMATCH_DB = 6.0
LOOP_MISMATCH_DEG = 30.0


def _gains_mismatch(compared: Mapping[str, Any] | None, ctrl: AxisController | None
                    ) -> str | None:
    """Why the loop analysed with the logged gains is not the loop flown (a measured loop
    far from the predicted one), or None.

    Examples
    --------
    >>> _gains_mismatch({"median_db": 0.4, "median_deg": 1.0}, None) is None
    True
    """
    if not compared:
        return None
    db, deg = compared.get("median_db", math.nan), compared.get("median_deg", math.nan)
    if not (db > LOOP_MISMATCH_DB or deg > LOOP_MISMATCH_DEG):  # (NaN: nothing measured)
        return None
    names = ", ".join(k for k in (ctrl.params if ctrl else {}) if k.endswith(("_P", "_I", "_D")))
    return (f"the loop predicted from the logged gains is {db:.1f} dB / {deg:.0f} deg (median) "
            "off the loop measured in flight: the logged rate-controller parameters do not "
            "describe this flight (damaged, or changed during it), so the margins above are "
            "not the flight's" + (f"; check {names}" if names else ""))


@dataclass
class TuneAnalysis:
    """The loop analysis of a result, computed once for a report (:func:`tune_analysis`):
    :func:`tune`'s per-axis report, the measured responses and the loop analyses it drew
    them from, or the error that stopped it. Computed where no plotting library is loaded:
    ``mavsid fit`` works it out while its report worker draws (:mod:`mavsid.outputs`)."""

    report: dict[str, Any] = field(default_factory=dict)
    measured: dict[str, dict[str, Any]] = field(default_factory=dict)
    analyses: dict[str, Any] = field(default_factory=dict)
    error: str | None = None
    target_pm_deg: float = 50.0


def tune_analysis(result: Any, target_pm_deg: float = 50.0) -> TuneAnalysis:
    """:func:`tune` of ``result`` (20 σ draws) with what a report plots; an error that stops
    it is kept in :attr:`TuneAnalysis.error`, not raised."""
    out = TuneAnalysis(target_pm_deg=target_pm_deg)
    try:
        out.report = tune(result, target_pm_deg, samples=20, measured_out=out.measured,
                          analyses_out=out.analyses)
    except (MavsidError, ValueError, np.linalg.LinAlgError) as exc:
        out.error = str(exc)
    return out
