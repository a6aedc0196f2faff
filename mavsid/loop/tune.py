"""Gains for a target phase margin (:func:`suggest_gains`) and the per-axis loop report
``mavsid tune`` gives (:func:`tune`, :func:`tune_analysis`): the logged gains' loop, the
measured responses, the suggestion under its stated limits and next-flight advice, as data
(the text is :func:`mavsid.cli_format.format_tune`'s).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from mavsid.errors import ConfigError, MavsidError
from mavsid.loop.analysis import (
    LoopAnalysis,
    analyse_model,
    analyse_plant,
    compare_response,
    controller_polys,
    frd_margins,
    loop_statespace,
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
from mavsid.loop.limits import Limits, LoopCheck, check_loop, limit_rows, twin_step
from mavsid.loop.plant import LinearPlant, as_plant, plant_from_model, plant_response
from mavsid.loop.twin import twin_signals

if TYPE_CHECKING:
    from mavsid.frequency import FRF
    from mavsid.pipeline_results import AxisFit, FitResult

__all__ = [
    "LOOP_MISMATCH_DB",
    "LOOP_MISMATCH_DEG",
    "MIN_CHIRP_TOP_HZ",
    "SUGGESTION_CHECK_DEG",
    "TuneAnalysis",
    "chirp_top_hz",
    "param_file",
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
    a, b, c = loop_statespace(plant, cfb)
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


def _advice(axis: str, fit: AxisFit, ctrl: AxisController, bandwidth_hz: float,
            plant_frf: FRF | None, chirp_top: float) -> list[str]:
    """What to change next flight, from what this one showed (``chirp_top``: the band's top
    the loop needs, :func:`chirp_top_hz`, the number the next flight names too)."""
    out: list[str] = []
    rate_hz = 1.0 / fit.validation.dt
    if np.isfinite(bandwidth_hz) and rate_hz < 5 * bandwidth_hz:
        out.append(
            f"{axis}: the log's {rate_hz:.0f} Hz cannot resolve a {bandwidth_hz:.1f} Hz rate "
            "loop: log rates at the loop rate (ArduPilot LOG_BITMASK ATTITUDE_FAST and "
            "PID, or INS_RAW_LOG_OPT; PX4 SDLOG_PROFILE 'high rate' / 'system identification')")
    if plant_frf is not None:
        band = plant_frf.band()
        want_lo, want_hi = 0.5, chirp_top
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


def tune(result: FitResult, target_pm_deg: float = 50.0, samples: int = 40,
         measured_out: dict[str, dict[str, Any]] | None = None,
         analyses_out: dict[str, LoopAnalysis] | None = None,
         limits: Limits | None = None) -> dict[str, Any]:
    """Per fitted axis of a :class:`mavsid.pipeline.FitResult`: the loop with the logged
    gains (margins, closed loop, uncertainties), the plant FRF and TF fit for SYSTEMID data,
    gains for ``target_pm_deg`` (only when the axis's verdict is ``good``) and next-flight
    advice. The JSON form of ``mavsid tune --json``.

    The suggestion (:func:`_suggestion`) is made only when the plant passed its gates and
    the suggested loop meets every limit of ``limits`` (:mod:`mavsid.loop.limits`; its
    ``target_pm_deg`` is ``target_pm_deg``); otherwise ``gains`` is empty and
    ``no_gains_reason`` says why in one line.

    ``measured_out``, when given, receives per axis the :func:`measured_responses` used (the
    FRF objects), so that a caller plotting them does not measure them again; likewise
    ``analyses_out`` the :class:`LoopAnalysis` with the logged gains (its responses)."""
    from mavsid.frequency import fit_tf, measured_responses

    limits = replace(limits or Limits(), target_pm_deg=target_pm_deg)
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
        entry.update(_suggestion(axis, fit, ctrl, an, entry, plant, measured.get("loop"),
                                 lag, tau, limits))
        entry["advice"] = _advice(axis, fit, ctrl, an.bandwidth_hz, plant,
                                  entry["chirp_top_hz"])
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
    them from, or the error that stopped it. ``mavsid fit``'s report worker works it out
    before it draws and hands it back for the ``.rrd`` (:mod:`mavsid.outputs`)."""

    report: dict[str, Any] = field(default_factory=dict)
    measured: dict[str, dict[str, Any]] = field(default_factory=dict)
    analyses: dict[str, Any] = field(default_factory=dict)
    error: str | None = None
    target_pm_deg: float = 50.0


def tune_analysis(result: FitResult, target_pm_deg: float = 50.0) -> TuneAnalysis:
    """:func:`tune` of ``result`` (20 σ draws) with what a report plots; an error that stops
    it is kept in :attr:`TuneAnalysis.error`, not raised."""
    out = TuneAnalysis(target_pm_deg=target_pm_deg)
    try:
        out.report = tune(result, target_pm_deg, samples=20, measured_out=out.measured,
                          analyses_out=out.analyses)
    except (MavsidError, ValueError, np.linalg.LinAlgError) as exc:
        out.error = str(exc)
    return out


#: the suggestion's aim, said beside its margins
AIM = "the rate loop flown: rate PID, the vehicle's filters and delay, identified plant"
#: the measured loop at the mixer and the predicted one disagree when their phase margins
#: differ by more than this many σ (the two σ combined)
MARGIN_AGREE_SIGMA = 3.0
#: the twin's step response of the suggested gains and the predicted one agree within this
#: (fraction of the step, largest difference over the first second)
TWIN_STEP_TOL = 0.05
#: significant digits of a suggested gain (a change of at most 0.05 %, 0.01 deg of margin)
GAIN_DIGITS = 4


def _sig(v: float, digits: int = GAIN_DIGITS) -> float:
    """``v`` to ``digits`` significant digits.

    >>> _sig(0.123456), _sig(0.0)
    (0.1235, 0.0)
    """
    return float(f"{v:.{digits}g}")


def _trusted_top(fit: AxisFit, plant_frf: FRF | None) -> tuple[float | None, str]:
    """The top of the band the plant is trusted over (Hz) and what it is: the SYSTEMID
    frequency response's coherent band when one was measured, else 0.4 × the log's rate
    (what its samples resolve). None when a SYSTEMID run has no coherent band."""
    if plant_frf is not None:
        band = plant_frf.band()
        if band is None:
            return None, "the SYSTEMID frequency response has no coherent band"
        return float(band[1]), f"coherent SYSTEMID band {band[0]:.2g}-{band[1]:.3g} Hz"
    rate = 1.0 / fit.validation.dt
    return 0.4 * rate, f"no SYSTEMID run: 0.4 × the log's {rate:.0f} Hz"


def _margin_sigma(measured: FRF, crossover_hz: float) -> float:
    """One σ (deg) of a phase margin read off a measured broken-loop FRF: its normalised
    random error at the crossover with the estimator's bias floor
    (:data:`mavsid.frequency.FRF_STRUCTURE_FLOOR`), as an angle (NaN without a crossover)."""
    from mavsid.frequency import FRF_STRUCTURE_FLOOR

    m = measured.coherent & np.isfinite(measured.error)
    if not m.any() or not np.isfinite(crossover_hz):
        return math.nan
    err = float(np.interp(crossover_hz, measured.freq_hz[m], measured.error[m]))
    return math.degrees(math.atan(math.hypot(err, FRF_STRUCTURE_FLOOR)))


def _loop_agreement(entry: Mapping[str, Any], an: LoopAnalysis,
                    measured: FRF | None) -> dict[str, float] | None:
    """The phase margin at the mixer measured and predicted (like for like over the
    measured band), their σ and whether they agree within :data:`MARGIN_AGREE_SIGMA`."""
    if measured is None or "loop_frf_margins" not in entry:
        return None
    mm, pr = entry["loop_frf_margins"], entry["loop_predicted_margins"]
    if not (np.isfinite(mm["phase_deg"]) and np.isfinite(pr["phase_deg"])):
        return None
    s_meas = _margin_sigma(measured, mm["crossover_hz"])
    s_pred = float(an.stderr.get("phase_margin_deg", 0.0) or 0.0)
    sigma = math.hypot(s_meas if np.isfinite(s_meas) else 0.0, s_pred)
    diff = float(mm["phase_deg"] - pr["phase_deg"])
    return {"measured_deg": float(mm["phase_deg"]), "predicted_deg": float(pr["phase_deg"]),
            "measured_sigma_deg": s_meas, "predicted_sigma_deg": s_pred,
            "difference_deg": diff,
            "agree": bool(abs(diff) <= MARGIN_AGREE_SIGMA * max(sigma, 0.5))}


def _gain_rows(ctrl: AxisController, new: Mapping[str, float], capped: bool
               ) -> list[dict[str, Any]]:
    """``{"name", "current", "suggested", "ratio", "capped"}`` of each gain that changes."""
    rows = []
    for name, cur in gain_params(ctrl).items():
        sug = new.get(name, cur)
        if sug == cur:
            continue
        rows.append({"name": name, "current": float(cur), "suggested": float(sug),
                     "ratio": float(sug / cur) if cur else math.nan, "capped": capped})
    return rows


def _next_flight(axis: str, ctrl: AxisController, *, wanted: float | None = None,
                 max_step: float = 2.0, band_hz: float | None = None,
                 refused: bool = False) -> str:
    """The next flight to fly for ``axis``: with the suggested gains (capped: then tune
    again), or, refused, a chirp over the band the crossover needs."""
    chirp = (f"a SYSTEMID mixer chirp on {axis} (SID_AXIS {10 + AXES.index(axis)})"
             if ctrl.autopilot == "ardupilot" else
             f"the system-identification flight task on {axis} (MC_SYSID)")
    if wanted is not None:
        return (f"fly these gains and {chirp}, then tune again from that log: the loop "
                f"wants ×{wanted:.2g} in all, more than one flight's ×{max_step:g} step")
    if band_hz is not None:
        stop = (f" with SID_F_STOP_HZ {band_hz:.0f}" if ctrl.autopilot == "ardupilot"
                else f" up to {band_hz:.0f} Hz")
        return f"fly {chirp}{stop}, so the band covers twice the crossover"
    if refused:
        return f"fly {chirp} with more amplitude, or simplify the frame's loop before tuning"
    return f"fly these gains and {chirp} to measure the loop they close"


#: the lowest top of the band a SYSTEMID chirp is advised to sweep to (Hz)
MIN_CHIRP_TOP_HZ = 20.0


def chirp_top_hz(crossovers_hz: Iterable[float], rate_hz: float, limits: Limits) -> float:
    """The top of the band (whole Hz) the next SYSTEMID chirp should sweep to, for the
    crossover limit to trust the loop: the largest of ``crossovers_hz`` (the gains flown and
    those suggested; NaN ignored) over :attr:`Limits.band_fraction`, at least
    :data:`MIN_CHIRP_TOP_HZ`, at most what the log's ``rate_hz`` resolves (0.4 of it). The
    one number the advice and the next flight name (``SID_F_STOP_HZ``).

    Examples
    --------
    >>> chirp_top_hz([15.4, 11.7], 400.0, Limits()), chirp_top_hz([4.9], 400.0, Limits())
    (31.0, 20.0)
    >>> chirp_top_hz([15.4], 50.0, Limits()), chirp_top_hz([float("nan")], 400.0, Limits())
    (20.0, 20.0)
    """
    need = max((c for c in crossovers_hz if math.isfinite(c)), default=0.0)
    top = math.ceil(max(need / limits.band_fraction, MIN_CHIRP_TOP_HZ))
    return float(min(top, math.floor(0.4 * rate_hz)))


def _values(ctrl: AxisController, k: float) -> dict[str, float]:
    """The gains scaled by ``k``, in the vehicle's names, to :data:`GAIN_DIGITS` digits."""
    return {n: _sig(v) for n, v in gain_params(scaled(ctrl, k)).items()}


#: the limits a smaller step than the phase-margin target's may be searched under (the
#: trusted band's is not: a crossover above it asks for a measurement, not lower gains)
_SEARCHED = ("phase margin", "gain margin", "sensitivity peak Ms", "closed-loop peak",
             "gain crossovers", "closed loop stable")


def _within_limits(plant: LinearPlant, ctrl: AxisController, lag: int, tau: float,
                   limits: Limits, top: float, k_hi: float
                   ) -> tuple[float, LoopCheck] | None:
    """The largest gain scale in ``[1 / max_step, k_hi]`` whose loop meets the stability
    limits (:data:`_SEARCHED`; each loosens as the gains come down), and its check (without
    the step: :func:`check_loop`'s ``step=False``): ``k_hi`` itself when it does; None when
    not even the smallest step does. Geometric bisection to 0.5 %."""
    def check(k: float) -> tuple[bool, LoopCheck]:
        c = check_loop(plant, _rebuilt(ctrl, _values(ctrl, k)), lag, tau, step=False)
        rows = limit_rows(c, c, limits, top)
        return all(r["ok"] for r in rows if r["name"] in _SEARCHED), c

    ok, c = check(k_hi)
    if ok:
        return k_hi, c
    lo = 1.0 / limits.max_step
    ok, c_lo = check(lo)
    if not ok or lo >= k_hi:
        return None
    hi = k_hi
    while hi / lo > 1.005:
        mid = math.sqrt(lo * hi)
        ok, c = check(mid)
        if ok:
            lo, c_lo = mid, c
        else:
            hi = mid
    return lo, c_lo


def _rebuilt(ctrl: AxisController, values: Mapping[str, float]) -> AxisController:
    """``ctrl`` with its gains set to ``values`` (the vehicle's names and units), rebuilt
    from parameters as the vehicle would read them."""
    return controller_from_params({**ctrl.params, **values}, ctrl.axis, ctrl.autopilot)


def _suggestion(axis: str, fit: AxisFit, ctrl: AxisController, an: LoopAnalysis,
                entry: Mapping[str, Any], plant_frf: Any, loop_frf: Any, lag: int,
                tau: float, limits: Limits) -> dict[str, Any]:
    """The suggestion's part of :func:`tune`'s entry: ``gains`` (rows of
    :func:`_gain_rows`, empty with ``no_gains_reason`` when none is admissible), ``limits``
    (:func:`limit_rows` for the current and the suggested loop), ``aim``,
    ``loop_agreement``, ``twin_step``, ``next_flight`` and ``suggested`` (name -> value)."""
    out: dict[str, Any] = {"aim": AIM, "gains": [], "suggested": {},
                           "max_step": limits.max_step}
    plant = plant_from_model(fit.model, axis, 1.0 / ctrl.loop_hz)
    current = check_loop(plant, ctrl, lag, tau)
    rate_hz = 1.0 / fit.validation.dt
    out["chirp_top_hz"] = chirp_top_hz([current.crossover_hz], rate_hz, limits)
    top, band_text = _trusted_top(fit, plant_frf)
    out["trusted_band"] = {"top_hz": top, "what": band_text}
    out["current_loop"] = current.to_dict()
    agreement = _loop_agreement(entry, an, loop_frf)
    if agreement is not None:
        out["loop_agreement"] = agreement

    def refuse(reason: str, **extra: Any) -> dict[str, Any]:
        out.setdefault("limits", limit_rows(current, None, limits, top or math.nan))
        out["no_gains_reason"] = reason
        out["suggested_note"] = f"no gains suggested: {reason}"
        out.update(extra)
        return out

    level = entry.get("verdict", "not identified")
    if level != "good":
        return refuse(f"the plant model is {level}")
    if entry.get("gains_mismatch"):
        return refuse("the logged gains they would scale do not describe this flight")
    if top is None:
        return refuse(band_text, next_flight=_next_flight(axis, ctrl,
                                                          band_hz=out["chirp_top_hz"]))
    if agreement is not None and not agreement["agree"]:
        return refuse(
            f"the phase margin at the mixer measured ({agreement['measured_deg']:.0f} deg) and "
            f"predicted ({agreement['predicted_deg']:.0f} deg) differ by more than "
            f"{MARGIN_AGREE_SIGMA:g} σ: the model does not describe the loop flown")
    got = suggest_gains(plant, ctrl, limits.target_pm_deg, lag, tau)
    if got is None:
        return refuse(f"no P/I/D scale gives {limits.target_pm_deg:g} deg phase margin "
                      "with a stable loop")
    wanted = scale_of(got[0], ctrl)
    k = min(max(wanted, 1.0 / limits.max_step), limits.max_step)
    capped = k != wanted
    found = _within_limits(plant, ctrl, lag, tau, limits, top, k)
    limited_by: list[str] = []
    if found is not None and found[0] != k:
        limited_by = [r["name"] for r in limit_rows(current, check_loop(
            plant, _rebuilt(ctrl, _values(ctrl, k)), lag, tau, step=False), limits, top)
            if not r["ok"] and r["name"] in _SEARCHED]
        k, capped = found[0], False
    values = _values(ctrl, k)
    new = _rebuilt(ctrl, values)
    suggested = check_loop(plant, new, lag, tau)  # (with its step, the search's had none)
    # (the chirp to cover the crossover of the gains flown and of the ones suggested)
    out["chirp_top_hz"] = chirp_top_hz([current.crossover_hz, suggested.crossover_hz],
                                       rate_hz, limits)
    rows = limit_rows(current, suggested, limits, top)
    out["limits"] = rows
    out["suggested_loop_check"] = suggested.to_dict()
    out["wanted_ratio"] = wanted
    out["capped"] = capped
    if limited_by:
        out["limited_by"] = limited_by
    twin = twin_step(plant, new, lag, tau, horizon_s=float(suggested.step_time_s[-1]) + 1e-9)
    n = min(twin.size, suggested.step.size)
    gap = float(np.max(np.abs(twin[:n] - suggested.step[:n]))) if n else math.nan
    out["twin_step"] = {"time_s": suggested.step_time_s[:n].tolist(),
                        "rate": twin[:n].tolist(), "max_difference": gap,
                        "agree": bool(gap <= TWIN_STEP_TOL)}
    failed = [r for r in rows if not r["ok"]]
    if failed:
        band = (out["chirp_top_hz"] if any(r["name"] == "crossover" for r in failed)
                else None)
        what = ("capped at ×" + f"{k:.2g}, " if capped else "")
        broken = " and ".join(
            f"{r['name']} {_value_text(r['suggested'])}{' ' + r['unit'] if r['unit'] else ''}"
            f", limit {r['limit']}" for r in failed)
        return refuse(f"{what}the suggested loop fails its limits: {broken}",
                      next_flight=_next_flight(axis, ctrl, band_hz=band, refused=True))
    if not gap <= TWIN_STEP_TOL:
        return refuse(f"flown in the closed-loop twin the suggested gains' step differs from "
                      f"the predicted one by {gap:.0%} of the step")
    out["gains"] = _gain_rows(ctrl, values, capped)
    if not out["gains"]:
        return refuse(f"no gain changes within one flight's ×{limits.max_step:g} step")
    out["suggested"] = {r["name"]: r["suggested"] for r in out["gains"]}
    out["suggested_loop"] = {kk: v for kk, v in got[1].to_dict().items() if kk != "stderr"}
    out["next_flight"] = _next_flight(axis, ctrl, wanted=wanted if capped else None,
                                      max_step=limits.max_step)
    if capped:
        out["suggested_note"] = (f"capped: the loop wants ×{wanted:.2g}, one flight changes "
                                 f"the gains by ×{k:.2g} at most")
    if limited_by:
        out["suggested_note"] = (
            f"held at ×{k:.2g} by the {' and '.join(limited_by)} limits: the "
            f"{limits.target_pm_deg:g} deg target alone wants ×{wanted:.2g}")
    if plant_frf is not None:
        check = margins_on_frf(plant_frf, new)
        out["suggested_check"] = check
        promised = suggested.phase_margin_deg
        if abs(check["phase_deg"] - promised) > SUGGESTION_CHECK_DEG:
            out["suggested_note"] = (
                f"on the measured frequency response these gains give "
                f"{check['phase_deg']:.0f} deg, not {promised:.0f}: the model is uncertain "
                "near the new crossover; step the gains up gradually")
    return out


def _value_text(v: float | bool | None) -> str:
    """A limit's value as the reason prints it.

    >>> _value_text(1.23456), _value_text(True), _value_text(float("inf"))
    ('1.23', 'yes', 'none')
    """
    if isinstance(v, bool):
        return "yes" if v else "no"
    if v is None or not math.isfinite(v):
        return "none"
    return f"{v:.3g}"


def param_file(report: Mapping[str, Any], log: str, when: str | None = None) -> str:
    """The parameter file of :func:`tune`'s suggestions: only the changed gains, after a
    comment header (log, date, and per axis the margins before and after). ArduPilot:
    ``NAME VALUE`` lines (:func:`mavsid.autopilot.ardupilot.param_file_text`); PX4: a
    QGroundControl ``.params`` file (:func:`mavsid.autopilot.px4.param_file_text`).

    Raises
    ------
    ConfigError
        No axis has a suggestion (the reasons, per axis, in one line).
    """
    import datetime

    from mavsid.autopilot import ardupilot, px4

    values: dict[str, float] = {}
    now = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
    header = [f"mavsid tune of {log}", f"written {when or now}"]
    autopilot = "ardupilot"
    for axis, e in report.items():
        if not e.get("gains"):
            continue
        autopilot = e.get("controller", {}).get("autopilot", autopilot)
        before = e["current_loop"]
        after = e["suggested_loop_check"]
        header.append(
            f"{axis}: phase margin {before['phase_margin_deg']:.1f} -> "
            f"{after['phase_margin_deg']:.1f} deg, gain margin {before['gain_margin_db']:.1f} "
            f"-> {after['gain_margin_db']:.1f} dB, crossover {before['crossover_hz']:.3g} -> "
            f"{after['crossover_hz']:.3g} Hz"
            + (f" (capped at x{e['gains'][0]['ratio']:.2g})" if e.get("capped") else ""))
        values.update({g["name"]: g["suggested"] for g in e["gains"]})
    if not values:
        why = "; ".join(f"{a}: {e.get('no_gains_reason') or e.get('error', 'none')}"
                        for a, e in report.items())
        raise ConfigError(f"no gains suggested, no parameter file written ({why})")
    if autopilot == "px4":
        return px4.param_file_text(values, header)
    return ardupilot.param_file_text(values, header)
