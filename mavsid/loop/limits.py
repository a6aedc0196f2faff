"""The limits a suggested rate loop must meet, the figures they are about, and the same
gains flown in the closed-loop twin.

A suggestion is admissible only when the loop the controller closes (the rate PID with the
vehicle's filters, the delay and the identified plant) meets every limit of
:class:`Limits`: phase margin at least the target, gain margin, sensitivity peak ``Ms``,
closed-loop peak, one gain crossover, that crossover inside the trusted band (at most half
its top: above it the plant is extrapolated) and a stable closed loop. :func:`check_loop`
computes the figures (the margins read off the loop's response on a dense grid,
:func:`mavsid.loop.analysis.grid_margins`; the step by ``control.step_response`` and
``control.step_info``);
:func:`limit_rows` sets them against the limits for the current and the suggested gains;
:func:`twin_step` flies a step through :func:`mavsid.loop.twin.simulate_closed_loop`.

Examples
--------
>>> from mavsid.loop.controllers import controller_from_params
>>> from mavsid.loop.plant import LinearPlant
>>> ctrl = controller_from_params({"ATC_RAT_RLL_P": 0.1, "ATC_RAT_RLL_I": 0.1}, "roll")
>>> plant = LinearPlant(np.array([[1.0]]), np.array([0.25]), np.array([1.0]), 0.0025)
>>> c = check_loop(plant, ctrl)
>>> c.crossovers, c.stable, round(c.phase_margin_deg)
(1, True, 105)
>>> [r["ok"] for r in limit_rows(c, c, Limits(target_pm_deg=50.0), 40.0)]
[True, True, True, True, True, True, True]
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mavsid.loop.analysis import controller_polys, grid_margins, loop_statespace
from mavsid.loop.controllers import AxisController, measurement_filter
from mavsid.loop.plant import LinearPlant, plant_response

__all__ = ["Limits", "LoopCheck", "check_loop", "limit_rows", "twin_step"]


@dataclass(frozen=True)
class Limits:
    """What a suggested loop must meet (PIDscope's gates and search limits, ArduPilot
    WebTools' rules of thumb).

    Attributes
    ----------
    target_pm_deg : float
        Phase margin the gains aim at and must reach (deg).
    min_gain_margin_db : float
    max_sensitivity : float
        Largest ``|1/(1+L)|`` (``Ms``; 2.0 is 6 dB).
    max_closed_peak_db : float
        Largest closed-loop gain from rate target to rate (dB).
    band_fraction : float
        The crossover at most this fraction of the trusted band's top.
    max_step : float
        One flight's change of the gains at most this factor either way (0.5-2× for 2).
    """

    target_pm_deg: float = 50.0
    min_gain_margin_db: float = 6.0
    max_sensitivity: float = 2.0
    max_closed_peak_db: float = 6.0
    band_fraction: float = 0.5
    max_step: float = 2.0


#: a phase margin this close under the target meets it (the gains' search and
#: python-control's root finding agree to about 0.01 deg)
PM_ROUNDING_DEG = 0.05


@dataclass(frozen=True)
class LoopCheck:
    """The figures of one rate loop the limits are about.

    Attributes
    ----------
    phase_margin_deg, gain_margin_db, crossover_hz : float
        Of ``L = C_fb·P`` (:func:`~mavsid.loop.analysis.grid_margins`, as
        ``control.stability_margins`` gives them; inf where there is no crossing).
    sensitivity_peak : float
        ``Ms = max |1/(1+L)|`` (``1 / stability margin``).
    closed_peak_db : float
        Largest gain of the closed loop from rate target to rate.
    crossovers : int
        How many times ``|L|`` crosses 1 below the Nyquist frequency.
    stable : bool
        Every closed-loop pole inside the unit circle.
    rise_time_s, settling_time_s, overshoot_percent : float
        Of the closed loop's unit step (``control.step_info``: 10-90 % rise, 2 % settling).
    step_time_s, step : numpy.ndarray
        That step response.
    freq_hz, loop_response : numpy.ndarray
        ``L`` on 300 frequencies to the Nyquist frequency (the broken loop's Bode).
    """

    phase_margin_deg: float
    gain_margin_db: float
    crossover_hz: float
    sensitivity_peak: float
    closed_peak_db: float
    crossovers: int
    stable: bool
    rise_time_s: float
    settling_time_s: float
    overshoot_percent: float
    step_time_s: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    step: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    freq_hz: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    loop_response: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, complex))

    def to_dict(self) -> dict[str, Any]:
        """The JSON form (figures, and the step response)."""
        return {"phase_margin_deg": self.phase_margin_deg,
                "gain_margin_db": self.gain_margin_db, "crossover_hz": self.crossover_hz,
                "sensitivity_peak": self.sensitivity_peak,
                "closed_peak_db": self.closed_peak_db, "crossovers": self.crossovers,
                "stable": self.stable, "rise_time_s": self.rise_time_s,
                "settling_time_s": self.settling_time_s,
                "overshoot_percent": self.overshoot_percent,
                "step": {"time_s": self.step_time_s.tolist(), "rate": self.step.tolist()},
                "loop": {"frequency_hz": self.freq_hz.tolist(),
                         "magnitude_db": (20 * np.log10(np.abs(self.loop_response))).tolist(),
                         "phase_deg": np.degrees(np.unwrap(np.angle(self.loop_response)))
                         .tolist()}}


def _closed_loop(plant: LinearPlant, ctrl: AxisController, lag: int, meas_delay: float
                 ) -> Any:
    """The closed loop from rate target to rate as a python-control system, for its step."""
    import control

    dt = 1.0 / ctrl.loop_hz
    (bf, af), (bt, at) = controller_polys(ctrl, dt)
    cfb, ct = control.tf(bf, af, dt), control.tf(bt, at, dt)
    if lag:
        ct = ct * control.tf([1.0], [1.0] + [0.0] * lag, dt)
    tau, num, den = measurement_filter(meas_delay)
    if tau:
        cfb = cfb * control.tf(num, den, dt)
    p = control.ss(plant.a, plant.b.reshape(-1, 1), plant.c.reshape(1, -1), [[0.0]], dt)
    return control.feedback(p, control.ss(cfb)) * control.ss(ct)


def check_loop(plant: LinearPlant, ctrl: AxisController, lag: int = 0,
               meas_delay: float = 0.0, horizon_s: float = 1.0, step: bool = True
               ) -> LoopCheck:
    """:class:`LoopCheck` of ``ctrl`` around ``plant`` (a :class:`LinearPlant` at the
    controller's step); ``lag`` loops of delay on the target path, ``meas_delay`` (0-1 loop)
    on the measured rate, as in :func:`mavsid.loop.analysis.analyse_plant`. ``step=False``
    leaves out the step response and its figures (NaN), which no limit reads: a search over
    gains needs only the rest."""
    dt = 1.0 / ctrl.loop_hz
    # the responses on a grid as polynomials in numpy (python-control's state-space
    # evaluation is 20x slower), the margins read off it (python-control's on an FRD of the
    # same loop fit a spline per call); the step by python-control
    f = np.geomspace(0.01, 0.499 / dt, 3000)
    z = np.exp(2j * np.pi * f * dt)
    (bf, af), (bt, at) = controller_polys(ctrl, dt)
    if lag:
        at = np.polymul(at, [1.0] + [0.0] * lag)
    tau, num, den = measurement_filter(meas_delay)
    cfb = (np.polymul(bf, num), np.polymul(af, den))
    with np.errstate(all="ignore"):
        p = plant_response(plant, f)
        lz = p * np.polyval(cfb[0], z) / np.polyval(cfb[1], z)
        mag = np.abs(lz)
        t_mag = np.abs(p * np.polyval(bt, z) / np.polyval(at, z) / (1.0 + lz))
        gms, pms, sms, _, wgcs, _ = grid_margins(f, lz)
        # the gain margin upwards: a loop with an integrator in the plant and one in the
        # controller sits at -180 deg near 0 Hz, a crossing a gain reduction never reaches
        gm = float(np.min(gms[gms > 1.0])) if np.any(gms > 1.0) else math.inf
        i = int(np.argmin(np.abs(pms))) if pms.size else -1
        pm = float(pms[i]) if i >= 0 else math.inf
        wgc = float(wgcs[i]) if 0 <= i < wgcs.size else math.nan
        sm = float(np.min(sms)) if sms.size else 1.0
    # the roots of 1 + L (the target path's integrator cancels in the closed loop)
    a, b, c = loop_statespace(plant, cfb if tau else (bf, af))
    stable = bool(np.all(np.abs(np.linalg.eigvals(a - b @ c)) < 1.0))
    t, y = np.zeros(0), np.zeros(0)
    info: dict[str, float] = {}
    if step:
        import control

        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore")  # python-control's fall-backs
            t = np.arange(0.0, horizon_s, dt)
            y = np.asarray(control.step_response(_closed_loop(plant, ctrl, lag, meas_delay),
                                                 T=t).outputs, dtype=float).ravel()
            info = control.step_info(y, T=t, SettlingTimeThreshold=0.02) if stable else {}
    crossings = int(np.count_nonzero(np.diff(np.sign(mag - 1.0)) != 0))
    gm_db = 20 * math.log10(gm) if np.isfinite(gm) and gm > 0 else math.inf
    return LoopCheck(
        phase_margin_deg=float(pm), gain_margin_db=float(gm_db),
        crossover_hz=float(wgc / (2 * np.pi)) if np.isfinite(wgc) else math.nan,
        sensitivity_peak=float(1.0 / sm) if sm > 0 else math.inf,
        closed_peak_db=float(20 * np.log10(np.max(t_mag))), crossovers=crossings,
        stable=stable, rise_time_s=float(info.get("RiseTime", math.nan)),
        settling_time_s=float(info.get("SettlingTime", math.nan)),
        overshoot_percent=float(info.get("Overshoot", math.nan)),
        step_time_s=t, step=y, freq_hz=f[::10], loop_response=lz[::10])


def limit_rows(current: LoopCheck, suggested: LoopCheck | None, limits: Limits,
               band_top_hz: float) -> list[dict[str, Any]]:
    """Each limit with its value for the current and the suggested loop and whether the
    suggested one (the current one without a suggestion) meets it: ``{"name", "limit",
    "unit", "current", "suggested", "ok"}``."""
    top = limits.band_fraction * band_top_hz
    specs: list[tuple[str, str, str, str, float]] = [
        ("phase margin", "phase_margin_deg", "deg", ">=",
         limits.target_pm_deg - PM_ROUNDING_DEG),
        ("gain margin", "gain_margin_db", "dB", ">=", limits.min_gain_margin_db),
        ("sensitivity peak Ms", "sensitivity_peak", "", "<=", limits.max_sensitivity),
        ("closed-loop peak", "closed_peak_db", "dB", "<=", limits.max_closed_peak_db),
        ("gain crossovers", "crossovers", "", "==", 1.0),
        ("crossover", "crossover_hz", "Hz", "<=", top),
        ("closed loop stable", "stable", "", "==", 1.0),
    ]
    shown = {"phase margin": limits.target_pm_deg}
    rows = []
    for name, key, unit, op, bound in specs:
        def ok(check: LoopCheck | None, key: str = key, op: str = op,
               bound: float = bound) -> bool:
            if check is None:
                return False
            v = float(getattr(check, key))
            if not math.isfinite(v) and key != "gain_margin_db":
                return False
            return v >= bound if op == ">=" else v <= bound if op == "<=" else v == bound

        def value(check: LoopCheck | None, key: str = key) -> float | bool | None:
            if check is None:
                return None
            v = getattr(check, key)
            return bool(v) if isinstance(v, (bool, np.bool_)) else float(v)

        limit_text = (f"{op.replace('>=', '≥').replace('<=', '≤').replace('==', '=')} "
                      f"{shown.get(name, bound):.3g}" + (f" {unit}" if unit else "")
                      if key != "stable" else "yes")
        if key == "crossover_hz":
            limit_text += f" (½ of {band_top_hz:.3g} Hz)"
        rows.append({"name": name, "limit": limit_text, "unit": unit,
                     "current": value(current), "suggested": value(suggested),
                     "ok": ok(suggested if suggested is not None else current),
                     "current_ok": ok(current)})
    return rows


def twin_step(plant: LinearPlant, ctrl: AxisController, lag: int = 0,
              meas_delay: float = 0.0, horizon_s: float = 1.0, amplitude: float = 0.1
              ) -> np.ndarray:
    """The unit-step response (per ``amplitude`` rad/s of target, small enough that no
    limit binds) of ``ctrl`` flown around ``plant`` in the closed-loop twin
    (:func:`mavsid.loop.twin.simulate_closed_loop`, the controller stepped sample by
    sample, its integrator and output limits on), at the controller's step."""
    from mavsid.loop.twin import simulate_closed_loop

    # the step of the linear loop, as the limits judge it: without the model's trim (a bias
    # an I-less controller never removes would otherwise offset the step by bias / P)
    plant = dataclasses.replace(plant, u_offset=0.0)
    n = round(horizon_s * ctrl.loop_hz)
    target = np.full(n + 1, amplitude)
    target[0] = 0.0
    rate, _ = simulate_closed_loop(plant, ctrl.new_pid(), target, lag=lag,
                                   meas_delay=meas_delay)
    return np.asarray(rate[1:], dtype=float) / amplitude
