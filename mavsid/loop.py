"""The loop stage: the vehicle's rate controller rebuilt from its parameters, the identified
plant put inside it (the closed-loop twin), and what the loop does with the logged gains.

One rate-controller implementation per autopilot, shared by the simulator
(:mod:`mavsid.synthetic.controller`), the closed-loop twin and the loop analysis:

- ArduPilot ``AC_PID`` (:class:`RatePID`): target low-passed at ``FLTT``, error
  ``target - measured`` low-passed at ``FLTE`` (0 = off), derivative of the filtered error
  low-passed at ``FLTD``; ``out = P·err + I + D·derr + FF·target`` with ``|I| ≤ IMAX``; when
  ``SMAX`` > 0 the P and D terms are scaled down so that their slew rate stays near ``SMAX``
  (an approximation of ArduPilot's slew limiter, see :class:`RatePID`);
- PX4 multicopter rate control (:class:`PX4RatePID`): ``out = K·P·err + I - K·D·ṁ + FF·target``
  with the derivative taken on the measured rate (``ṁ``, low-passed at ``IMU_DGYRO_CUTOFF``),
  the integrator gain ``K·I`` scaled down for large errors and limited to ``MC_*R_INT_LIM``.

:func:`controller_from_params` rebuilds one axis's controller from a log's parameters
(ArduPilot ``ATC_RAT_{RLL,PIT,YAW}_*``, the 3.x ``RATE_{RLL,PIT,YAW}_*`` names, the 3.5–4.0
single ``FILT``, ``SCHED_LOOP_RATE``, ``INS_GYRO_FILTER``; PX4 ``MC_{ROLL,PITCH,YAW}RATE_*``,
``MC_{RR,PR,YR}_INT_LIM``, ``IMU_GYRO_CUTOFF``, ``IMU_DGYRO_CUTOFF``, ``IMU_GYRO_RATEMAX``);
a parameter the log lacks takes the autopilot's documented default and is listed in
``defaults_used``.

The gyro low-pass (``INS_GYRO_FILTER``, ``IMU_GYRO_CUTOFF``) and any notch sit between the
rotating body and what the controller reads; the logged rate (``RATE.R``,
``vehicle_angular_velocity``) is already filtered, so a plant identified from it to the
logged rate includes them: the twin feeds the plant model's output straight to the PID.

The closed-loop twin (:func:`closed_loop_fit`) drives the controller with the logged rate
target (``RATE.RDes/PDes/YDes``, ``PIDR.Tar``, PX4 ``vehicle_rates_setpoint``) plus any
SYSTEMID mixer injection (``SIDD.Targ`` during ``SID_AXIS`` 10–12), closes the loop through
the identified plant at the controller's loop rate (the plant re-discretised there when the
log is slower), and compares the simulated rate and controller output with the measured
ones on the held-out blocks. Its baseline is "the rate follows its target after the best
delay" (the delay chosen on the training blocks).

Examples
--------
>>> c = controller_from_params({"ATC_RAT_RLL_P": 0.1, "ATC_RAT_RLL_I": 0.1}, "roll")
>>> c.autopilot, c.gains.p, c.gains.d, c.loop_hz
('ardupilot', 0.1, 0.0036, 400.0)
>>> c.defaults_used[:3]
('ATC_RAT_RLL_D', 'ATC_RAT_RLL_FF', 'ATC_RAT_RLL_IMAX')
>>> pid = c.new_pid(0.0025)
>>> round(pid.update(target=1.0, measured=0.0), 5)   # P*err + I*err*dt on the first sample
0.10025
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from mavsid import dsp
from mavsid.errors import ConfigError, MavsidError

if TYPE_CHECKING:
    from mavsid.data import FlightData, Segment
    from mavsid.estimators.model import Model

__all__ = [
    "AXIS_RATE",
    "AxisController",
    "ClosedLoopFit",
    "LinearPlant",
    "LoopAnalysis",
    "PX4RateGains",
    "PX4RatePID",
    "RateGains",
    "RatePID",
    "TuneAnalysis",
    "TwinSignals",
    "analyse_loop",
    "analyse_model",
    "analyse_plant",
    "baseline_fit",
    "closed_loop_fit",
    "compare_response",
    "controller_from_params",
    "controller_polys",
    "controller_tf",
    "format_tune",
    "frd_margins",
    "margins_on_frf",
    "measured_responses",
    "plant_from_model",
    "replay_controller",
    "simulate_closed_loop",
    "suggest_gains",
    "sysid_spans",
    "tune",
    "tune_analysis",
    "twin_messages",
    "twin_signals",
]

AXES = ("roll", "pitch", "yaw")
AXIS_RATE = {"roll": "p", "pitch": "q", "yaw": "r"}
_AP = {"roll": "RLL", "pitch": "PIT", "yaw": "YAW"}
_PX4 = {"roll": "ROLL", "pitch": "PITCH", "yaw": "YAW"}
_PX4_LIM = {"roll": "RR", "pitch": "PR", "yaw": "YR"}
#: ArduCopter 3.x rate PIDs act on centidegrees/s and output on the ±4500 motor scale
_AP3_SCALE = (18000.0 / math.pi) / 4500.0


def _alpha(cutoff_hz: float, dt: float) -> float:
    """First-order low-pass gain per step (1 = no filtering)."""
    if cutoff_hz <= 0:
        return 1.0
    rc = 1.0 / (2 * np.pi * cutoff_hz)
    return dt / (dt + rc)


# --------------------------------------------------------------------------- ArduPilot


@dataclass(frozen=True)
class RateGains:
    """One axis of ArduPilot's ``ATC_RAT_<AX>_*`` (P, I, D per rad/s to a normalised output;
    ``imax`` normalised; filters in Hz, 0 = off; ``smax`` the P+D slew limit, 0 = off)."""

    p: float
    i: float
    d: float
    ff: float
    imax: float
    fltt: float
    fltd: float
    flte: float
    smax: float = 0.0


#: slew-limiter constants: slew rate low-passed at this cut-off (Hz), the P+D modifier never
#: below this fraction
_SLEW_FILTER_HZ = 25.0
_SLEW_MIN_MOD = 0.1


class RatePID:
    """ArduPilot ``AC_PID``-style rate controller for one axis.

    ``SMAX`` (when > 0): the slew rate of the P+D output, low-passed at 25 Hz, above ``SMAX``
    scales P and D by ``SMAX / slew`` (never below 0.1). ArduPilot's limiter also tracks the
    slew peaks over a window; this keeps only the filtered rate (an approximation).

    Examples
    --------
    >>> pid = RatePID(RateGains(0.1, 0.0, 0.0, 0.2, 0.5, 0.0, 0.0, 0.0), dt=0.01)
    >>> [round(pid.update(1.0, 0.5), 3) for _ in range(2)]   # P*err + FF*target
    [0.25, 0.25]
    """

    def __init__(self, gains: RateGains, dt: float) -> None:
        self.g = gains
        self.dt = dt
        self.a_t = _alpha(gains.fltt, dt)
        self.a_e = _alpha(gains.flte, dt)
        self.a_d = _alpha(gains.fltd, dt)
        self.a_s = _alpha(_SLEW_FILTER_HZ, dt)
        self.target = 0.0
        self.error = 0.0
        self.deriv = 0.0
        self.integ = 0.0
        self.slew = 0.0
        self.pd_last = 0.0
        self.reset = True

    def update(self, target: float, measured: float) -> float:
        """One step: target and measured rate (rad/s) -> normalised output."""
        g = self.g
        if self.reset:
            self.target = target
            self.error = target - measured
            self.deriv = 0.0
            self.reset = False
        else:
            self.target += self.a_t * (target - self.target)
            err_prev = self.error
            self.error += self.a_e * ((self.target - measured) - self.error)
            self.deriv += self.a_d * ((self.error - err_prev) / self.dt - self.deriv)
        self.integ = min(max(self.integ + g.i * self.error * self.dt, -g.imax), g.imax)
        if g.smax > 0:
            pd = g.p * self.error + g.d * self.deriv
            self.slew += self.a_s * (abs(pd - self.pd_last) / self.dt - self.slew)
            self.pd_last = pd
            mod = max(_SLEW_MIN_MOD, min(1.0, g.smax / self.slew)) if self.slew > 0 else 1.0
            return mod * pd + self.integ + g.ff * self.target
        return g.p * self.error + self.integ + g.d * self.deriv + g.ff * self.target

    def run(self, target: np.ndarray, measured: np.ndarray) -> np.ndarray | None:
        """The outputs of :meth:`update` over whole sequences from a fresh controller (after
        :meth:`preset`), without feedback: its filters are first-order recursions
        (``scipy.signal.lfilter``) and the integrator a running sum. None when the slew
        limiter is on or the integrator would reach ``±IMAX`` (callers then step)."""
        g = self.g
        tg, ym = np.asarray(target, dtype=float), np.asarray(measured, dtype=float)
        n = tg.size
        if not self.reset or g.smax > 0 or n == 0 or ym.size != n:
            return None

        def low(x: np.ndarray, a: float, x0: float) -> np.ndarray:
            """``y[0] = x0``, then ``y[k] = y[k-1] + a (x[k] - y[k-1])``."""
            y = np.empty(n)
            y[0] = x0
            if n > 1:
                y[1:] = dsp.lfilter([a], [1.0, a - 1.0], x[1:], zi=[(1.0 - a) * x0])
            return y

        tf = low(tg, self.a_t, float(tg[0]))
        err = low(tf - ym, self.a_e, float(tg[0] - ym[0]))
        rate = np.zeros(n)
        rate[1:] = np.diff(err) / self.dt
        deriv = low(rate, self.a_d, 0.0)
        integ = np.cumsum(np.concatenate([[self.integ], g.i * err * self.dt]))[1:]
        if np.any(np.abs(integ) > g.imax):
            return None
        return np.asarray(g.p * err + integ + g.d * deriv + g.ff * tf)

    def preset(self, target: float, measured: float, output: float) -> None:
        """Before the first :meth:`update`: set the integrator so that the first output of
        ``update(target, measured)`` is ``output`` (within ``±IMAX``)."""
        g = self.g
        err = target - measured
        i0 = output - g.p * err - g.ff * target - g.i * err * self.dt
        self.integ = min(max(i0, -g.imax), g.imax)

    def adjust_integrator(self, delta: float) -> None:
        """Add ``delta`` to the integrator (within ``±IMAX``)."""
        self.integ = min(max(self.integ + delta, -self.g.imax), self.g.imax)


# --------------------------------------------------------------------------- PX4


@dataclass(frozen=True)
class PX4RateGains:
    """One axis of PX4's ``MC_<AX>RATE_*``: P, I, D, FF and the gain ``K`` multiplying P, I
    and D; ``int_lim`` the integrator limit (``MC_<AX>R_INT_LIM``); ``dgyro_hz`` the cut-off
    of the low-pass on the measured rate's derivative (``IMU_DGYRO_CUTOFF``, 0 = off)."""

    p: float
    i: float
    d: float
    ff: float
    k: float = 1.0
    int_lim: float = 0.3
    dgyro_hz: float = 30.0


#: PX4 reduces the integration for rate errors approaching this (rad/s)
_PX4_I_ERR = math.radians(400.0)


class PX4RatePID:
    """PX4 multicopter rate controller for one axis (derivative on measurement).

    Examples
    --------
    >>> pid = PX4RatePID(PX4RateGains(0.2, 0.0, 0.0, 0.1, k=0.5), dt=0.004)
    >>> round(pid.update(1.0, 0.0), 3)   # K*P*err + FF*target
    0.2
    """

    def __init__(self, gains: PX4RateGains, dt: float) -> None:
        self.g = gains
        self.dt = dt
        fs = 1.0 / dt
        cut = gains.dgyro_hz if 0 < gains.dgyro_hz < 0.5 * fs else 0.0
        self.accel_filter = dsp.Lowpass2p(cut, fs, 1)
        self.integ = 0.0
        self.last = 0.0
        self.reset = True

    def update(self, target: float, measured: float) -> float:
        """One step: target and measured rate (rad/s) -> normalised torque."""
        g = self.g
        if self.reset:
            self.last = measured
            self.reset = False
        accel = float(self.accel_filter.advance((measured - self.last) / self.dt))
        self.last = measured
        err = target - measured
        out = g.k * g.p * err + self.integ - g.k * g.d * accel + g.ff * target
        factor = max(0.0, 1.0 - (err / _PX4_I_ERR) ** 2)
        i_new = self.integ + factor * g.k * g.i * err * self.dt
        self.integ = min(max(i_new, -g.int_lim), g.int_lim)
        return out

    def preset(self, target: float, measured: float, output: float) -> None:
        """Set the integrator so that the first output of ``update(target, measured)`` is
        ``output`` (within the integrator limit)."""
        g = self.g
        err = target - measured
        i0 = output - g.k * g.p * err - g.ff * target
        self.integ = min(max(i0, -g.int_lim), g.int_lim)

    def adjust_integrator(self, delta: float) -> None:
        """Add ``delta`` to the integrator (within its limit)."""
        self.integ = min(max(self.integ + delta, -self.g.int_lim), self.g.int_lim)


class PID(Protocol):
    """What the twin needs of a rate controller."""

    def update(self, target: float, measured: float) -> float: ...

    def preset(self, target: float, measured: float, output: float) -> None: ...

    def adjust_integrator(self, delta: float) -> None: ...


# --------------------------------------------------------------------------- from parameters


@dataclass(frozen=True)
class AxisController:
    """One axis's rate controller as the log's parameters define it.

    Attributes
    ----------
    autopilot : str
        ``"ardupilot"`` or ``"px4"``.
    axis : str
    gains : RateGains or PX4RateGains
        In the twin's units (rad/s in, normalised output).
    loop_hz : float
        Rate the controller runs at (``SCHED_LOOP_RATE``; PX4 ``IMU_GYRO_RATEMAX``).
    gyro_filter_hz : float
        The gyro low-pass ahead of the controller (``INS_GYRO_FILTER``, ``IMU_GYRO_CUTOFF``);
        part of the identified plant when the plant maps to the logged (filtered) rate.
    notch_hz : float
        Centre of a configured static gyro notch (0: none configured).
    params : Mapping[str, float]
        Every parameter used, by the vehicle's own name, as the log has it (or the default).
    defaults_used : tuple of str
        Parameters the log lacks, taken at their documented defaults.
    naming : str
        ``"ATC_RAT"`` (ArduPilot >= 3.4), ``"Q_A_RAT"`` (an ArduPlane QuadPlane's VTOL
        controller), ``"ATC_RAT_FILT"`` (3.5-4.0 single filter),
        ``"RATE"`` (ArduCopter <= 3.3, centidegree scale) or ``"MC"`` (PX4).
    angle_p : float
        The attitude loop's P (1/s) around the rate loop (``ATC_ANG_*_P``, 3.x ``STB_*_P``,
        PX4 ``MC_*_P``): a mixer injection's broken loop includes it.
    """

    autopilot: str
    axis: str
    gains: RateGains | PX4RateGains
    loop_hz: float
    gyro_filter_hz: float = 0.0
    notch_hz: float = 0.0
    params: Mapping[str, float] = field(default_factory=dict)
    defaults_used: tuple[str, ...] = ()
    naming: str = "ATC_RAT"
    angle_p: float = 0.0

    def new_pid(self, dt: float | None = None) -> RatePID | PX4RatePID:
        """A fresh controller stepping every ``dt`` (default ``1 / loop_hz``)."""
        step = 1.0 / self.loop_hz if dt is None else dt
        if isinstance(self.gains, PX4RateGains):
            return PX4RatePID(self.gains, step)
        return RatePID(self.gains, step)

    def to_dict(self) -> dict[str, Any]:
        """JSON form: autopilot, loop rate, filters, parameters and the defaults used."""
        return {
            "autopilot": self.autopilot,
            "axis": self.axis,
            "loop_hz": self.loop_hz,
            "gyro_filter_hz": self.gyro_filter_hz,
            "notch_hz": self.notch_hz,
            "naming": self.naming,
            "angle_p": self.angle_p,
            "params": dict(self.params),
            "defaults_used": list(self.defaults_used),
        }


#: Loop rates (Hz) a flight controller runs at (ArduPilot's SCHED_LOOP_RATE 50-2000, PX4's
#: IMU_GYRO_RATEMAX up to 8000); a logged one outside is damaged and the default is used
_LOOP_HZ_RANGE = (50.0, 8000.0)

#: ArduCopter 4.x defaults (ATC_RAT_*), per axis: P, I, D, FF, IMAX, FLTT, FLTE, FLTD, SMAX
_AP_DEFAULTS = {
    "roll": (0.135, 0.135, 0.0036, 0.0, 0.5, 20.0, 0.0, 20.0, 0.0),
    "pitch": (0.135, 0.135, 0.0036, 0.0, 0.5, 20.0, 0.0, 20.0, 0.0),
    "yaw": (0.18, 0.018, 0.0, 0.0, 0.5, 20.0, 2.5, 0.0, 0.0),
}
_AP_FIELDS = ("P", "I", "D", "FF", "IMAX", "FLTT", "FLTE", "FLTD", "SMAX")
#: ArduCopter 3.3 defaults (RATE_*): P, I, D, IMAX (centi), FILT_HZ
_AP3_DEFAULTS = {
    "roll": (0.15, 0.1, 0.004, 1000.0, 20.0),
    "pitch": (0.15, 0.1, 0.004, 1000.0, 20.0),
    "yaw": (0.2, 0.02, 0.0, 1000.0, 5.0),
}
#: PX4 v1.14 defaults: P, I, D, FF, K, INT_LIM
_PX4_DEFAULTS = {
    "roll": (0.15, 0.2, 0.003, 0.0, 1.0, 0.3),
    "pitch": (0.15, 0.2, 0.003, 0.0, 1.0, 0.3),
    "yaw": (0.2, 0.1, 0.0, 0.0, 1.0, 0.3),
}
#: PX4 v1.14 attitude P defaults (MC_ROLL_P, MC_PITCH_P, MC_YAW_P)
_PX4_ANGLE_P = {"roll": 6.5, "pitch": 6.5, "yaw": 2.8}
_AP_LOOP_HZ = 400.0
_AP_GYRO_FILTER_HZ = 20.0
_PX4_GYRO_CUTOFF_HZ = 40.0
_PX4_DGYRO_CUTOFF_HZ = 30.0
_PX4_LOOP_HZ = 400.0  # IMU_GYRO_RATEMAX default; pre-1.11 firmware ran the loop at 250 Hz
_PX4_OLD_LOOP_HZ = 250.0


def _is_px4(params: Mapping[str, float]) -> bool:
    return any(k.startswith(("MC_ROLLRATE_", "MC_PITCHRATE_", "MC_YAWRATE_")) for k in params)


def _angle_p(params: Mapping[str, float], name: str, default: float,
             used: dict[str, float]) -> float:
    """The attitude P (recorded in ``used``; not a rate-controller default: the twin follows
    the logged rate target and does not need it, only the loop analysis at the mixer)."""
    value = params.get(name)
    ok = value is not None and math.isfinite(float(value)) and float(value) >= 0
    used[name if ok else f"{name} (default)"] = float(value) if ok else default  # type: ignore[arg-type]
    return float(value) if ok else default  # type: ignore[arg-type]


def controller_from_params(
    params: Mapping[str, float], axis: str, autopilot: str | None = None
) -> AxisController:
    """Rebuild one axis's rate controller from a log's parameters.

    Parameters
    ----------
    params : Mapping[str, float]
        The log's parameters (``RawLog.params`` / ``FlightData.params``).
    axis : str
        ``roll``, ``pitch`` or ``yaw``.
    autopilot : str, optional
        ``"ardupilot"`` or ``"px4"``; default from the parameter names (PX4 when any
        ``MC_*RATE_*`` is present).

    Raises
    ------
    ConfigError
        Unknown axis or autopilot, or a gain that is negative or not finite.

    Examples
    --------
    >>> c = controller_from_params({"MC_ROLLRATE_P": 0.2, "MC_ROLLRATE_K": 0.5}, "roll")
    >>> c.autopilot, c.gains.p, c.gains.k, "MC_ROLLRATE_I" in c.defaults_used
    ('px4', 0.2, 0.5, True)
    >>> round(controller_from_params({"RATE_RLL_P": 0.15}, "roll").gains.p, 6)  # 3.x: cdeg scale
    0.190986
    """
    if axis not in AXES:
        raise ConfigError(f"axis must be one of {', '.join(AXES)}, got {axis!r}")
    kind = autopilot or ("px4" if _is_px4(params) else "ardupilot")
    if kind not in ("ardupilot", "px4"):
        raise ConfigError(f"no rate-controller model for autopilot {kind!r} (ardupilot, px4)")
    used: dict[str, float] = {}
    defaults: list[str] = []

    def get(name: str, default: float) -> float:
        if name in params and params[name] is not None and math.isfinite(float(params[name])):
            value = float(params[name])
        else:
            value = float(default)
            defaults.append(name)
        if value < 0:
            raise ConfigError(f"parameter {name} = {value:g} must be >= 0")
        used[name] = value
        return value

    def get_rate(name: str, default: float) -> float:
        """A loop rate (Hz): the default where the log's is outside what a flight controller
        runs (a damaged parameter; it sets how many controller steps are simulated)."""
        value = get(name, default)
        if not _LOOP_HZ_RANGE[0] <= value <= _LOOP_HZ_RANGE[1]:
            value = used[name] = float(default)
            defaults.append(name)
        return value

    if kind == "px4":
        pre = f"MC_{_PX4[axis]}RATE_"
        p, i, d, ff, k, lim = _PX4_DEFAULTS[axis]
        gains: RateGains | PX4RateGains = PX4RateGains(
            get(pre + "P", p), get(pre + "I", i), get(pre + "D", d), get(pre + "FF", ff),
            get(pre + "K", k), get(f"MC_{_PX4_LIM[axis]}_INT_LIM", lim),
            get("IMU_DGYRO_CUTOFF", _PX4_DGYRO_CUTOFF_HZ),
        )
        old = "IMU_GYRO_RATEMAX" not in params and "IMU_GYRO_CUTOFF" not in params
        loop = get_rate("IMU_GYRO_RATEMAX", _PX4_OLD_LOOP_HZ if old else _PX4_LOOP_HZ)
        gyro = get("IMU_GYRO_CUTOFF", _PX4_GYRO_CUTOFF_HZ)
        notch = float(params.get("IMU_GYRO_NF0_FRQ", params.get("IMU_GYRO_NF_FREQ", 0.0)) or 0)
        ang = _angle_p(params, f"MC_{_PX4[axis]}_P", _PX4_ANGLE_P[axis], used)
        return AxisController("px4", axis, gains, loop or _PX4_LOOP_HZ, gyro, notch, used,
                              tuple(defaults), "MC", ang)
    ax = _AP[axis]
    modern = any(k.startswith(f"ATC_RAT_{ax}_") for k in params)
    # an ArduPlane QuadPlane's VTOL controller: the same AC_AttitudeControl, its parameters
    # named Q_A_* (Q_A_RAT_RLL_P ...)
    quadplane = not modern and any(k.startswith(f"Q_A_RAT_{ax}_") for k in params)
    legacy = not modern and not quadplane and any(k.startswith(f"RATE_{ax}_") for k in params)
    if legacy:
        p, i, d, imax, filt = _AP3_DEFAULTS[axis]
        pre = f"RATE_{ax}_"
        filt_name = pre + "FILT_HZ" if pre + "FILT_HZ" in params else pre + "FILT"
        f = get(filt_name, filt)
        gains = RateGains(
            round(get(pre + "P", p) * _AP3_SCALE, 9), round(get(pre + "I", i) * _AP3_SCALE, 9),
            round(get(pre + "D", d) * _AP3_SCALE, 9), 0.0,
            round(get(pre + "IMAX", imax) / 4500.0, 9), 0.0, f, f,
        )
        naming = "RATE"
    else:
        pre = f"Q_A_RAT_{ax}_" if quadplane else f"ATC_RAT_{ax}_"
        vals = dict(zip(_AP_FIELDS, _AP_DEFAULTS[axis], strict=True))
        if pre + "FLTE" not in params and pre + "FILT" in params:
            # 3.5-4.0: one filter on the error, the derivative taken of the filtered error
            f = get(pre + "FILT", 20.0)
            vals.update(FLTT=0.0, FLTE=f, FLTD=0.0)
            names: tuple[str, ...] = ("P", "I", "D", "FF", "IMAX")
            naming = "ATC_RAT_FILT"
        else:
            names = _AP_FIELDS
            naming = "Q_A_RAT" if quadplane else "ATC_RAT"
        for n in names:
            vals[n] = get(pre + n, vals[n])
        gains = RateGains(vals["P"], vals["I"], vals["D"], vals["FF"], vals["IMAX"],
                          vals["FLTT"], vals["FLTD"], vals["FLTE"], vals["SMAX"])
    loop = get_rate("SCHED_LOOP_RATE", _AP_LOOP_HZ)
    gyro = get("INS_GYRO_FILTER", _AP_GYRO_FILTER_HZ)
    notch = 0.0
    if params.get("INS_HNTCH_ENABLE", 0):
        notch = float(params.get("INS_HNTCH_FREQ", 0.0) or 0.0)
    elif params.get("INS_NOTCH_ENABLE", 0):
        notch = float(params.get("INS_NOTCH_FREQ", 0.0) or 0.0)
    ang_name = (f"STB_{ax}_P" if legacy else f"Q_A_ANG_{ax}_P" if quadplane
                else f"ATC_ANG_{ax}_P")
    ang = _angle_p(params, ang_name, 4.5, used)
    return AxisController("ardupilot", axis, gains, loop, gyro, notch, used, tuple(defaults),
                          naming, ang)


# --------------------------------------------------------------------------- the plant


@dataclass(frozen=True)
class LinearPlant:
    """A discrete single-output plant ``x⁺ = A x + B (u + u_offset) + E w``, ``y = C x``.

    ``u`` is the axis's controller output (mixer input, normalised); ``w`` the model's other
    inputs, taken as measured; ``u_offset`` the model's bias expressed as an input offset.
    """

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    dt: float
    e: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    u_offset: float = 0.0
    other_inputs: tuple[str, ...] = ()

    def initial_state(self, y0: float, u0: float, w0: np.ndarray | None = None) -> np.ndarray:
        """A state in equilibrium with the input ``u0`` (and ``w0``) as far as the plant
        allows, moved (least norm) so that its output is ``y0``."""
        n = self.a.shape[0]
        forcing = self.b * (u0 + self.u_offset)
        if w0 is not None and self.e.size:
            forcing = forcing + self.e @ w0
        try:
            x = np.linalg.solve(np.eye(n) - self.a, forcing)
            if not np.all(np.isfinite(x)) or np.linalg.cond(np.eye(n) - self.a) > 1e8:
                raise np.linalg.LinAlgError
        except np.linalg.LinAlgError:
            x = np.zeros(n)
        cc = self.c.reshape(1, n)
        return x + (np.linalg.pinv(cc) @ np.array([y0 - float((cc @ x)[0])])).ravel()


def _continuous_blocks(model: Model) -> tuple[np.ndarray, np.ndarray, list[int], list[int]]:
    """Continuous-time ``(A, B_exo)`` of a linear model, with the feature indices of states
    and of exogenous terms (inputs and bias)."""
    states, exo, other = model._split
    if other:
        raise ConfigError("the closed-loop twin needs a linear model (no library terms)")
    n = len(model.state_names)
    a = model.A
    b = model.coef[exo].T if exo else np.zeros((n, 0))
    if model.continuous:
        return a, b, states, exo
    m = b.shape[1]
    big = np.zeros((n + m, n + m))
    big[:n, :n], big[:n, n:], big[n:, n:] = a, b, np.eye(m)
    ev = np.linalg.eigvals(a)
    if np.any(np.abs(ev.imag) > 1e-12) or np.any(ev.real <= 0):
        raise ConfigError("the model's discrete poles have no continuous-time equivalent "
                          "(negative or complex); the twin runs at the model's own step")
    if n == 1:  # the logarithm of [[a, b], [0, I]] in closed form: [[ln a, b ln a/(a-1)], 0]
        pole = float(a[0, 0])
        gain = _log_ratio(pole)
        return (np.array([[math.log(pole)]]) / model.dt, b * gain / model.dt, states, exo)
    log = dsp.logm(big) / model.dt
    return log[:n, :n], log[:n, n:], states, exo


def _log_ratio(a: float) -> float:
    """``ln(a) / (a - 1)`` (1 at ``a = 1``), accurate near 1."""
    x = a - 1.0
    if abs(x) < 1e-5:
        return 1.0 - x / 2.0 + x * x / 3.0
    return math.log(a) / x


def _at_step(model: Model, dt: float) -> Model:
    """The linear model re-discretised (zero-order hold) at step ``dt``, delay kept in s."""
    if not model.continuous and math.isclose(model.dt, dt, rel_tol=1e-9):
        return model
    a, b, states, exo = _continuous_blocks(model)
    n, m = a.shape[0], b.shape[1]
    big = np.zeros((n + m, n + m))
    big[:n, :n], big[:n, n:] = a, b
    if n == 1:  # the exponential of [[A, B], [0, 0]] dt in closed form
        x = float(a[0, 0]) * dt
        e = np.eye(n + m)
        e[0, 0] = math.exp(x)
        e[0, 1:] = b[0] * dt * (math.expm1(x) / x if x != 0.0 else 1.0)
    else:
        e = dsp.expm(big * dt)
    coef = np.zeros_like(model.coef)
    for j in states:
        coef[j] = e[:n, :n][:, model.state_names.index(model.features[j])]
    for k, j in enumerate(exo):
        coef[j] = e[:n, n + k]
    steps = model.delay_s / dt
    whole = math.floor(steps + 1e-9)
    frac = steps - whole if steps - whole > 1e-9 else 0.0
    return replace(model, coef=coef, dt=dt, continuous=False, delay=whole, delay_frac=frac,
                   covariance=None, coef_stderr=None)


def plant_from_model(model: Any, axis: str, dt: float | None = None) -> LinearPlant:
    """The identified plant of ``axis`` as a :class:`LinearPlant` at step ``dt`` (default
    the model's own): input filters and delay included, the bias as an input offset.

    ``model`` is a :class:`mavsid.estimators.Model` (linear features).

    Raises
    ------
    ConfigError
        The model is not linear, does not predict the axis's rate from its input, or cannot
        be re-discretised at ``dt``.
    """
    from mavsid.estimators import library

    rate, u_name = AXIS_RATE[axis], f"u_{axis}"
    if not all(hasattr(model, a) for a in ("features", "coef", "statespace_matrices",
                                           "_split")):
        raise ConfigError(f"the {axis} model is not a mavsid estimators.Model: no loop model")
    if rate not in model.state_names or u_name not in model.input_names:
        raise ConfigError(f"the {axis} model does not map {u_name} to {rate}")
    if not library.is_linear(model.features):
        raise ConfigError("the closed-loop twin needs a linear model (no library terms)")
    m = _at_step(model, model.dt if dt is None else dt)
    a, bmat, cmat, dmat, ins, _ = m.statespace_matrices()  # numpy: no python-control here
    row = m.state_names.index(rate)
    c = np.asarray(cmat, dtype=float)[row]
    if np.any(np.abs(np.asarray(dmat, dtype=float)[row]) > 0):
        raise ConfigError("the model's output reacts to its input within the same step")
    j = ins.index(u_name)
    others = tuple(k for k in ins if k != u_name)
    e = bmat[:, [ins.index(k) for k in others]] if others else np.zeros((a.shape[0], 0))
    # bias c[rate] as the input offset that produces it: B_plant * u0 = c
    offset = 0.0
    if library.BIAS in m.features:
        fb, fu = m.features.index(library.BIAS), m.features.index(u_name)
        bu = float(m.coef[fu, row])
        if bu != 0:
            offset = float(m.coef[fb, row]) / bu
    return LinearPlant(a, bmat[:, j].copy(), c, m.dt, e, offset, others)


# --------------------------------------------------------------------------- simulation


def simulate_closed_loop(
    plant: LinearPlant,
    pid: PID,
    target: np.ndarray,
    *,
    injection: np.ndarray | None = None,
    others: np.ndarray | None = None,
    substeps: int = 1,
    rate: np.ndarray | None = None,
    u: np.ndarray | None = None,
    warmup: int = 0,
    limit: float = 1.0,
    lag: int = 0,
    meas_delay: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Close the loop: the controller follows ``target`` through ``plant``.

    Each sample holds the target, injection and other inputs for ``substeps``
    plant/controller steps (the plant's ``dt`` times ``substeps`` is the data step).

    Parameters
    ----------
    plant : LinearPlant
    pid : RatePID or PX4RatePID
        A fresh controller at the plant's step.
    target : (n,) rate target (rad/s).
    injection : (n,), optional
        Added to the controller output before the ``±limit`` clip (SYSTEMID mixer axes).
    others : (n, len(plant.other_inputs)), optional
        The model's other inputs, as measured.
    rate, u : (n,), optional
        Measured rate and mixer input. They set the initial conditions: the first
        ``warmup`` samples drive the controller with the measured rate and the plant with the
        measured input (no feedback); the integrator is then corrected so that the
        controller's output matches the measured one, and the plant's state moved (least
        norm) to the measured rate. Without warm-up, the plant starts in equilibrium at the
        first sample and the integrator is preset from the first measured output.
    warmup : int
        Samples used for the initial conditions; the returned arrays start after them.
    limit : float
        The mixer input's clip.
    lag : int
        Controller steps between a target (and injection) sample and the step that first
        uses it (ArduCopter: 1, see :func:`replay_controller`).
    meas_delay : float
        Controller steps (0-1) by which the rate the controller reads lags the plant's output
        (linear interpolation with the step before; see :func:`replay_controller`).

    Returns
    -------
    rate, u : numpy.ndarray, shape (n - warmup,)
        Simulated rate and mixer input (controller output plus injection, clipped), sampled
        at the first sub-step of each sample.

    Notes
    -----
    An ArduPilot controller without slew limiter runs, after its first step, as one linear
    system in blocks of steps (:func:`_linear_run`, four times faster on the SITL flight)
    unless its integrator's or the output's clip would bind; then step by step. The same
    numbers to rounding (``tests/test_loop.py``).

    Examples
    --------
    >>> plant = LinearPlant(np.array([[1.0]]), np.array([0.01]), np.array([1.0]), 0.01)
    >>> pid = RatePID(RateGains(2.0, 0.0, 0.0, 0.0, 0.5, 0.0, 0.0, 0.0), 0.01)
    >>> y, u = simulate_closed_loop(plant, pid, np.ones(2000))
    >>> round(float(y[-1]), 4)   # an integrator under P control reaches its target
    1.0
    """
    n = len(target)
    inj = np.zeros(n) if injection is None else np.asarray(injection, dtype=float)
    w = np.zeros((n, 0)) if others is None else np.asarray(others, dtype=float).reshape(n, -1)
    a, b, c, e = plant.a, plant.b, plant.c, plant.e
    off = plant.u_offset
    tg = _lagged(np.repeat(np.asarray(target, dtype=float), substeps), lag)
    ij = _lagged(np.repeat(inj, substeps), lag)
    ew = (np.repeat(w @ e.T, substeps, axis=0) if w.shape[1]
          else np.zeros((n * substeps, a.shape[0])))
    ym = np.zeros(n) if rate is None else np.asarray(rate, dtype=float)
    um = np.zeros(n) if u is None else np.asarray(u, dtype=float)
    warmup = min(max(0, warmup), n - 1) if rate is not None and u is not None else 0
    x = plant.initial_state(float(ym[0]), float(um[0]), w[0] if n and w.shape[1] else None)
    if u is not None and n:
        pid.preset(float(tg[0]), float(ym[0]), float(um[0] - ij[0]))
    j = 0
    tau = _reads(meas_delay)[0]
    y_prev = float(ym[0]) if n else 0.0
    if warmup:
        outs = np.empty(warmup)
        for k in range(warmup):
            for s in range(substeps):
                y_now = float(ym[k])
                out = pid.update(float(tg[j]), (1.0 - tau) * y_now + tau * y_prev)
                y_prev = y_now
                if s == 0:
                    outs[k] = out
                x = a @ x + b * (float(um[k]) + off) + ew[j]
                j += 1
        last = max(1, min(10, warmup // 2))
        resid = (um[:warmup] - ij[: warmup * substeps: substeps]) - outs
        pid.adjust_integrator(float(np.mean(resid[-last:])))
        cc = c.reshape(1, -1)
        x = x + (np.linalg.pinv(cc) @ np.array([ym[warmup] - float((cc @ x)[0])])).ravel()
    steps = (n - warmup) * substeps
    y_all, u_all = np.empty(steps), np.empty(steps)
    tgl, ijl = tg.tolist(), ij.tolist()  # Python floats: no numpy scalar per step
    rows = list(ew) if w.shape[1] else None  # no other inputs: nothing to add

    def stepped(i0: int, i1: int, x: np.ndarray, y_prev: float) -> tuple[np.ndarray, float]:
        """Steps ``i0`` to ``i1`` (from the first after the warm-up), one at a time."""
        for jj in range(j + i0, j + i1):
            y = float(c @ x)
            seen = (1.0 - tau) * y + tau * y_prev
            y_prev = y
            uk = min(max(pid.update(tgl[jj], seen) + ijl[jj], -limit), limit)
            y_all[jj - j], u_all[jj - j] = y, uk
            x = a @ x + b * (uk + off)
            if rows is not None:
                x = x + rows[jj]
        return x, y_prev

    if isinstance(pid, RatePID) and pid.g.smax <= 0 and steps > 4 * _BLOCK:
        # the first step one at a time (a fresh controller starts from its inputs), the rest
        # as one linear system unless the integrator's or the output's clip binds
        x, y_prev = stepped(0, 1, x, y_prev)
        if not _linear_steps(pid, plant, x, y_prev, tau, limit, tg[j + 1:j + steps],
                             ij[j + 1:j + steps],
                             ew[j + 1:j + steps] if rows is not None else None,
                             y_all[1:], u_all[1:]):
            stepped(1, steps, x, y_prev)
    else:
        stepped(0, steps, x, y_prev)
    return y_all[::substeps].copy(), u_all[::substeps].copy()


#: steps per block of :func:`_linear_run`
_BLOCK = 32


def _linear_run(f: np.ndarray, g: np.ndarray, h: np.ndarray, k: np.ndarray, s0: np.ndarray,
                w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Outputs ``h·s[i] + k·w[i]`` of ``s[i+1] = f·s[i] + g·w[i]`` from ``s0`` over the rows of
    ``w``, and the last state, in blocks of :data:`_BLOCK` steps: one small product per block
    carries the state (``fᵐ``), the steps inside every block at once (``h·fⁱ`` and the
    inputs' ``h·fⁱ⁻¹⁻ˡ·g``). The same numbers as stepping, to rounding."""
    m = _BLOCK
    n, ns, nw = w.shape[0], f.shape[0], w.shape[1]
    nb = -(-n // m)
    wb = np.zeros((nb * m, nw))
    wb[:n] = w
    wb = wb.reshape(nb, m, nw)
    powers = [np.eye(ns)]
    for _ in range(m):
        powers.append(f @ powers[-1])
    hf = np.stack([h @ powers[i] for i in range(m)])  # (m, ny, ns)
    hfg = np.stack([h @ powers[i] @ g for i in range(m)])  # (m, ny, nw)
    kern = np.zeros((m, m, h.shape[0], nw))
    for i in range(1, m):
        kern[i, :i] = hfg[i - 1::-1]  # l < i: h·f^(i-1-l)·g
    gam = np.stack([powers[m - 1 - i] @ g for i in range(m)])  # (m, ns, nw)
    flat = wb.reshape(nb, m * nw)
    v = flat @ gam.transpose(1, 0, 2).reshape(ns, m * nw).T  # (nb, ns)
    fm = powers[m]
    states = np.empty((nb + 1, ns))
    states[0] = s0
    for i in range(nb):
        states[i + 1] = fm @ states[i] + v[i]
    ny = h.shape[0]
    y = (states[:nb] @ hf.reshape(m * ny, ns).T
         + flat @ kern.transpose(1, 3, 0, 2).reshape(m * nw, m * ny)).reshape(nb, m, ny)
    y = (y + wb @ k.T).reshape(nb * m, ny)[:n]
    last = states[n // m]
    for row in w[(n // m) * m:]:
        last = f @ last + g @ row
    return y, last


def _linear_steps(pid: RatePID, plant: LinearPlant, x: np.ndarray, y_prev: float, tau: float,
                  limit: float, tg: np.ndarray, ij: np.ndarray, ew: np.ndarray | None,
                  y_out: np.ndarray, u_out: np.ndarray) -> bool:
    """:func:`simulate_closed_loop`'s steps after the first (the controller past its reset,
    no slew limiter) as one linear system, :func:`_linear_run`: the rates and outputs into
    ``y_out`` and ``u_out`` and the controller's state updated, or False (nothing changed)
    when the integrator's ``±IMAX`` or the output's ``±limit`` would bind on some step."""
    gn, dt = pid.g, pid.dt
    a, b, c = plant.a, plant.b, plant.c
    n = a.shape[0]
    # state: x (n), y_prev, target filter T, error E, derivative D, integrator I
    ns = n + 5
    iy, it, ie, i_d, ii = n, n + 1, n + 2, n + 3, n + 4
    ext = ew is not None
    nw = 3 + (n if ext else 0)  # inputs: target, injection, 1 (offset), other inputs
    # each quantity of a step as a row over [state, inputs]
    z = np.zeros(ns + nw)
    y = z.copy()
    y[:n] = c
    seen = (1.0 - tau) * y
    seen[iy] += tau
    t_new = z.copy()
    t_new[it] = 1.0 - pid.a_t
    t_new[ns] = pid.a_t
    e_new = -pid.a_e * seen
    e_new[ie] += 1.0 - pid.a_e
    e_new += pid.a_e * t_new
    d_new = pid.a_d / dt * e_new
    d_new[ie] -= pid.a_d / dt
    d_new[i_d] += 1.0 - pid.a_d
    i_new = gn.i * dt * e_new
    i_new[ii] += 1.0
    out = gn.p * e_new + i_new + gn.d * d_new + gn.ff * t_new
    u = out.copy()
    u[ns + 1] += 1.0
    fg = np.zeros((ns, ns + nw))
    fg[:n] = np.outer(b, u)
    fg[:n, :n] += a
    fg[:n, ns + 2] += b * plant.u_offset
    if ext:
        fg[:n, ns + 3:] += np.eye(n)
    fg[iy], fg[it], fg[ie], fg[i_d], fg[ii] = y, t_new, e_new, d_new, i_new
    hk = np.stack([y, u, i_new])
    s0 = np.r_[x, y_prev, pid.target, pid.error, pid.deriv, pid.integ]
    steps = tg.size
    w = np.empty((steps, nw))
    w[:, 0], w[:, 1], w[:, 2] = tg, ij, 1.0
    if ext:
        w[:, 3:] = ew
    with np.errstate(all="ignore"):
        outs, last = _linear_run(fg[:, :ns], fg[:, ns:], hk[:, :ns], hk[:, ns:], s0, w)
    if not (np.all(np.isfinite(outs)) and np.all(np.abs(outs[:, 2]) <= gn.imax)
            and np.all(np.abs(outs[:, 1]) <= limit)):
        return False
    y_out[:steps], u_out[:steps] = outs[:, 0], outs[:, 1]
    pid.target, pid.error, pid.deriv, pid.integ = (float(v) for v in last[it:])
    return True


def _reads(meas_delay: float) -> tuple[float, list[float], list[float]]:
    """A measurement delay of ``meas_delay`` loops, held to 0-1: ``τ`` and the rate the
    controller reads as a filter of the plant's output, ``(1 − τ) + τz⁻¹`` (numerator and
    denominator in descending powers of z).

    Examples
    --------
    >>> _reads(0.2)
    (0.2, [0.8, 0.2], [1.0, 0.0])
    """
    tau = min(max(float(meas_delay), 0.0), 1.0)
    return tau, [1.0 - tau, tau], [1.0, 0.0]


def _lagged(x: np.ndarray, lag: int) -> np.ndarray:
    """``x`` delayed by ``lag`` samples, the first value held before it."""
    if lag <= 0 or not x.size:
        return x
    return np.concatenate([np.full(min(lag, x.size), x[0]), x[: max(0, x.size - lag)]])


def replay_controller(
    ctrl: AxisController, dt: float, target: np.ndarray, rate: np.ndarray, output: np.ndarray,
    injection: np.ndarray | None = None, lag: int = 0, substeps: int = 1,
    meas_delay: float = 0.0,
) -> np.ndarray:
    """The rebuilt controller fed the *measured* rate: its output (mixer input minus the
    injection) sample by sample, to compare with the logged one.

    This checks the controller alone (its parameters, and ``lag``: ArduCopter runs the rate
    controller at the start of each loop on the target and injection its attitude controller
    and SYSTEMID set in the loop before, and logs them when they are set: 1 loop).
    ``substeps`` controller steps per sample (``lag`` counts them) hold the measured rate.
    ``meas_delay`` (controller steps, 0-1): the rate the controller reads lags the logged one
    by that fraction of a step (linear interpolation with the step before): a log may stamp
    the gyro sample a little apart from the one the controller used (the SITL flight's
    replay: 96.2 % at 0, 97.7 % at 0.2 of its 400 Hz loop).

    Examples
    --------
    >>> c = controller_from_params({}, "roll")
    >>> t = np.sin(np.arange(200) * 0.05); y = 0.9 * t
    >>> u = replay_controller(c, 0.0025, t, y, np.zeros(200))
    >>> u.shape
    (200,)
    """
    n = len(target)
    inj = np.zeros(n) if injection is None else np.asarray(injection, dtype=float)
    tg = _lagged(np.repeat(np.asarray(target, dtype=float), substeps), lag)
    ij = _lagged(np.repeat(inj, substeps), lag)[::substeps]
    ym = np.repeat(np.asarray(rate, dtype=float), substeps)
    tau = _reads(meas_delay)[0]
    if tau > 0 and ym.size:
        ym = (1.0 - tau) * ym + tau * np.concatenate([ym[:1], ym[:-1]])
    pid = ctrl.new_pid(dt / substeps)
    pid.preset(float(tg[0]), float(rate[0]), float(output[0] - ij[0]))
    whole = pid.run(tg, ym) if isinstance(pid, RatePID) else None  # (no feedback here)
    out = whole if whole is not None else np.array(
        [pid.update(float(a), float(b)) for a, b in zip(tg, ym, strict=True)])
    out = out[::substeps]
    # the first output has no derivative term and an unfiltered error: the integrator takes
    # the offset that leaves, measured once the controller's filters have settled
    settle = min(round(SETTLE_S / dt), n // 2)
    early = slice(settle, min(settle + 20, n))
    return out + float(np.mean((output - ij - out)[early]))


#: time (s) after which the controller's own filters (FLTE 2.5 Hz: 64 ms) have settled
SETTLE_S = 0.25


# --------------------------------------------------------------------------- log signals


@dataclass(frozen=True)
class TwinSignals:
    """What the twin needs from a log besides states and inputs, on a flight's time grid.

    Attributes
    ----------
    target : Mapping[str, numpy.ndarray]
        Rate target (rad/s) per axis the log has one for.
    injection : Mapping[str, numpy.ndarray]
        SYSTEMID mixer injection (normalised) per axis; zeros outside the runs.
    sources : Mapping[str, str]
        Where each came from (``"RATE.RDes"``...).
    rate_injection : Mapping[str, numpy.ndarray]
        SYSTEMID rate-axis injection (rad/s, ``SID_AXIS`` 7-9, part of the rate target).
    """

    target: Mapping[str, np.ndarray]
    injection: Mapping[str, np.ndarray]
    sources: Mapping[str, str] = field(default_factory=dict)
    rate_injection: Mapping[str, np.ndarray] = field(default_factory=dict)


def _on_grid(t: np.ndarray, v: np.ndarray, grid: np.ndarray, hold: bool) -> np.ndarray:
    """Samples put on ``grid``: interpolated or held; NaN outside their span."""
    order = np.argsort(t, kind="stable")
    t, v = t[order], v[order]
    keep = np.concatenate([[True], np.diff(t) > 0]) if t.size else np.zeros(0, bool)
    t, v = t[keep], v[keep]
    if t.size < 2:
        return np.full(grid.shape, np.nan)
    if hold:
        i = np.searchsorted(t, grid + 1e-9, side="right") - 1
        out = v[np.clip(i, 0, None)].astype(float)
    else:
        out = np.interp(grid, t, v)
    out[(grid < t[0] - 1e-9) | (grid > t[-1] + 1e-9)] = np.nan
    return out


def twin_messages() -> set[str]:
    """The messages :func:`twin_signals` reads (rate targets, SYSTEMID injection), of every
    format: a caller reading the log anyway reads them in the same pass."""
    from mavsid.channels import INJECTION_CHANNEL, TARGET_CHANNELS

    return {ch.message for chans in TARGET_CHANNELS.values() for ch in chans} | {
        INJECTION_CHANNEL.message}


def twin_signals(flight: FlightData, raw: Any = None) -> TwinSignals:
    """Rate targets and SYSTEMID mixer injections of ``flight``, from its log (re-read for
    the few messages needed unless ``raw`` is given).

    Targets come from the first of :data:`mavsid.channels.TARGET_CHANNELS` the log has;
    mixer injections from ``SIDD.Targ`` during the SYSTEMID runs on ``SID_AXIS`` 10-12.
    """
    from mavsid.channels import INJECTION_CHANNEL, TARGET_CHANNELS, evaluate, first_of

    if raw is None:
        from mavsid.readers import read_log

        path = flight.source.path
        if not path or not os.path.exists(path):
            return TwinSignals({}, {})
        wanted = twin_messages()
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            raw = read_log(path, messages=sorted(wanted))
    grid = flight.time_s
    targets: dict[str, np.ndarray] = {}
    sources: dict[str, str] = {}
    for axis in AXES:
        got = first_of(raw, TARGET_CHANNELS[AXIS_RATE[axis]], f"target {axis}")
        if got is not None:
            ch, t, v = got
            scale = dict(flight.meta.get("scales") or {}).get(ch.message, 1.0)  # type: ignore[call-overload]
            targets[axis] = _on_grid(t, v * scale, grid, hold=True)
            sources[f"target_{axis}"] = f"{ch.message}.{ch.field}"
    injection: dict[str, np.ndarray] = {}
    runs = [r for r in flight.meta.get("sysid_runs", ()) or ()  # type: ignore[attr-defined]
            if int(r.get("axis", 0)) in (7, 8, 9, 10, 11, 12)]
    rate_injection: dict[str, np.ndarray] = {}
    if runs and INJECTION_CHANNEL.message in raw.messages:
        try:
            t, v = evaluate(raw, INJECTION_CHANNEL, "SYSTEMID injection")
        except MavsidError:
            t = np.zeros(0)
        if t.size >= 2:
            held = np.nan_to_num(_on_grid(t, v, grid, hold=True))
            src = f"{INJECTION_CHANNEL.message}.{INJECTION_CHANNEL.field}"
            for r in runs:
                sid = int(r["axis"])
                axis = AXES[(sid - 1) % 3]
                inside = (grid >= float(r["start_s"]) - 1e-9) & (grid <= float(r["stop_s"]) + 1e-9)
                if sid >= 10:
                    inj = injection.setdefault(axis, np.zeros(grid.shape))
                    inj[inside] = held[inside]
                    sources[f"injection_{axis}"] = src
                else:  # rate axes: the waveform (deg/s) is added to the rate target
                    inj = rate_injection.setdefault(axis, np.zeros(grid.shape))
                    inj[inside] = np.radians(held[inside])
                    sources[f"rate_injection_{axis}"] = src
    return TwinSignals(targets, injection, sources, rate_injection)


# --------------------------------------------------------------------------- the twin's fit


@dataclass(frozen=True)
class TwinBlock:
    """One held-out block: measured and simulated rate and controller output."""

    time_s: np.ndarray
    target: np.ndarray
    rate: np.ndarray
    rate_twin: np.ndarray
    output: np.ndarray
    output_twin: np.ndarray
    baseline: np.ndarray


@dataclass(frozen=True)
class ClosedLoopFit:
    """How well the closed-loop twin reproduces the held-out blocks of one axis.

    Attributes
    ----------
    fit_percent : float
        Fit % of the simulated rate against the measured one (NRMSE, as elsewhere).
    output_fit_percent : float
        Fit % of the simulated controller output (mixer input minus any SYSTEMID
        injection, which both share) against the measured one.
    baseline_percent : float
        Fit % of "the rate follows its target after ``baseline_delay_s``".
    baseline_delay_s : float
        The baseline's delay, chosen on the training blocks.
    open_loop_percent : float
        The open-loop free-run fit % of the same blocks, for comparison.
    defaults_used : tuple of str
        Controller parameters the log lacks, taken at documented defaults.
    controller : Mapping
        :meth:`AxisController.to_dict`.
    substeps : int
        Controller steps per data sample (the plant re-discretised when > 1).
    lag_loops : int
        Controller loops between a logged target (and injection) and its use.
    measurement_delay_loops : float
        Part of a loop by which the rate the controller reads lags the logged rate (chosen,
        as ``lag_loops``, by the controller replay on the training blocks).
    target_source, injection_source : str
    blocks : tuple of TwinBlock
    """

    fit_percent: float
    output_fit_percent: float
    baseline_percent: float
    baseline_delay_s: float
    defaults_used: tuple[str, ...] = ()
    open_loop_percent: float = float("nan")
    controller: Mapping[str, Any] = field(default_factory=dict)
    substeps: int = 1
    lag_loops: int = 0
    measurement_delay_loops: float = 0.0
    target_source: str = ""
    injection_source: str = ""
    blocks: tuple[TwinBlock, ...] = field(default=(), repr=False)

    def to_dict(self) -> dict[str, Any]:
        """JSON form (without the per-block arrays)."""
        return {
            "fit_percent": self.fit_percent,
            "output_fit_percent": self.output_fit_percent,
            "baseline_percent": self.baseline_percent,
            "baseline_delay_s": self.baseline_delay_s,
            "open_loop_percent": self.open_loop_percent,
            "defaults_used": list(self.defaults_used),
            "controller": dict(self.controller),
            "substeps": self.substeps,
            "lag_loops": self.lag_loops,
            "measurement_delay_loops": self.measurement_delay_loops,
            "target_source": self.target_source,
            "injection_source": self.injection_source,
            "blocks": [[float(b.time_s[0]), float(b.time_s[-1])] for b in self.blocks],
        }


def _pooled_fit(y: Sequence[np.ndarray], yhat: Sequence[np.ndarray]) -> float:
    from mavsid.validation import fit_percent

    if not y:
        return float("nan")
    return float(fit_percent(np.concatenate(y), np.concatenate(yhat)))


#: longest delay (s) the baseline tries
BASELINE_MAX_DELAY_S = 0.5


def baseline_fit(
    train: Sequence[tuple[np.ndarray, np.ndarray]],
    held_out: Sequence[tuple[np.ndarray, np.ndarray]],
    dt: float,
    max_delay_s: float = BASELINE_MAX_DELAY_S,
) -> tuple[float, float, list[np.ndarray]]:
    """"The rate follows its target after the best delay": the delay (whole samples up to
    ``max_delay_s``) that fits the training blocks best, and the fit % it gives on the
    held-out ones.

    Parameters
    ----------
    train, held_out : sequence of (target, rate) pairs, each (n_i,)
    dt : float

    Returns
    -------
    fit_percent, delay_s, predictions (one per held-out block, NaN before the delay)

    Examples
    --------
    >>> t = np.sin(np.arange(400) * 0.05)
    >>> y = np.concatenate([[0.0] * 3, t[:-3]])       # the target, 3 samples late
    >>> fit, delay, _ = baseline_fit([(t, y)], [(t, y)], dt=0.01)
    >>> round(fit, 6), delay
    (100.0, 0.03)
    """
    from mavsid.validation import _fit_sums

    def shifted(x: np.ndarray, d: int) -> np.ndarray:
        out = np.full(x.shape, np.nan)  # (a block shorter than the delay: all unknown)
        if d < len(x):
            out[d:] = x[: len(x) - d]
        return out

    longest = max((len(t) for t, _ in (*train, *held_out)), default=0)
    max_d = max(0, min(round(max_delay_s / dt), longest - 2))
    pool = train or held_out

    def score(d: int) -> float:
        err = norm = 0.0
        for t, y in pool:
            e, n = _fit_sums(y, shifted(t, d))
            err, norm = err + float(e[0]), norm + float(n[0])
        return -err / norm if norm > 0 else -np.inf

    best, best_d = -np.inf, 0
    for d in _baseline_candidates(pool, max_d):
        sc = score(d)
        if sc > best:
            best, best_d = sc, d
    preds = [shifted(t, best_d) for t, _ in held_out]
    fit = _pooled_fit([y for _, y in held_out], preds)
    return fit, best_d * dt, preds


def _baseline_candidates(pool: Sequence[tuple[np.ndarray, np.ndarray]], max_d: int
                         ) -> range | list[int]:
    """The delays :func:`baseline_fit` scores exactly, in increasing order: every one up to
    ``max_d`` when a block holds a non-finite sample, else those whose score, from running
    sums and one dot product per delay and block (rounding differs from the exact sums),
    is within a rounding margin of the best: the exact scores of these choose the same
    delay as those of all (the rest are far below)."""
    blocks = [(np.asarray(t, dtype=float), np.asarray(y, dtype=float)) for t, y in pool]
    if not all(np.all(np.isfinite(t)) and np.all(np.isfinite(y)) for t, y in blocks):
        return range(max_d + 1)
    err = np.zeros(max_d + 1)
    norm = np.zeros(max_d + 1)
    scale = 0.0
    for t, y in blocks:
        n = y.size
        k = min(max_d, n - 1) + 1  # delays with samples left
        if n == 0 or k <= 0:
            continue
        s1 = np.cumsum(y[::-1])[::-1][:k]  # sum over i >= d of y[i]
        s2 = np.cumsum((y * y)[::-1])[::-1][:k]
        t2 = np.cumsum(t * t)[::-1][:k]  # sum over i < n - d of t[i]
        cross = np.array([y[d:] @ t[:n - d] for d in range(k)])
        err[:k] += s2 - 2.0 * cross + t2
        norm[:k] += s2 - s1 * s1 / (n - np.arange(k))
        scale += float(y @ y + t @ t)
    with np.errstate(divide="ignore", invalid="ignore"):
        approx = np.where(norm > 0, -err / norm, -np.inf)
    if not np.any(np.isfinite(approx)):
        return range(max_d + 1)
    best = float(np.max(approx[np.isfinite(approx)]))
    margin = 1e-7 * scale / float(np.min(norm[norm > 0])) + 1e-9 * abs(best)
    return [int(d) for d in np.flatnonzero(~(approx < best - margin))]


@dataclass(frozen=True)
class _Block:
    """A segment located on its flight, with up to ``warm`` samples before it."""

    seg: Segment
    ctrl: AxisController
    warm: int
    target: np.ndarray
    injection: np.ndarray
    rate: np.ndarray
    u: np.ndarray
    inputs: np.ndarray
    input_names: tuple[str, ...]


#: measured samples before a block (s) used for the twin's initial conditions
WARMUP_S = 0.5


#: target/injection lags (controller loops) tried
LAGS = (0, 1, 2)
#: measurement delays (controller loops) tried when the log is at the loop rate: the rate
#: the controller read may lag the logged one by part of a loop (the gyro sample stamped
#: apart from the one used); the shortest within MEAS_DELAY_TOL (fit %) of the best replay
MEAS_DELAYS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5)
MEAS_DELAY_TOL = 0.1
#: ArduCopter uses a target one loop after logging it (see :func:`replay_controller`)
_DEFAULT_LAG = {"ardupilot": 1, "px4": 0}


def closed_loop_fit(
    model: Any,
    axis: str,
    train: Sequence[Segment],
    held_out: Sequence[Segment],
    flights: Sequence[FlightData],
    signals: Sequence[TwinSignals] | None = None,
    open_loop_percent: float = float("nan"),
) -> ClosedLoopFit:
    """Run the closed-loop twin of ``axis`` on the held-out blocks.

    The controller is rebuilt from the parameters of the flight each block comes from; it
    follows the logged rate target (plus the SYSTEMID mixer injection) through the plant
    model at the controller's loop rate, from the measured rate and controller output at
    the block's start. The lag between a logged target and its use (0-2 loops) is the one
    whose controller replay (:func:`replay_controller`) matches the training blocks best
    (without training blocks: ArduPilot's 1 loop, PX4's 0); then, for a log at the loop
    rate, the measurement delay (:data:`MEAS_DELAYS`) the same way.

    Raises
    ------
    ConfigError
        No rate target in the logs, a model the twin cannot run, or no block on a flight's
        grid.
    """
    from mavsid.validation import fit_percent

    sigs = list(signals) if signals is not None else [twin_signals(fd) for fd in flights]
    tr = _locate(train, axis, flights, sigs)
    val = _locate(held_out, axis, flights, sigs)
    if not val:
        from mavsid.channels import TARGET_CHANNELS

        names = [f"{c.message}.{c.field}" for c in TARGET_CHANNELS[AXIS_RATE[axis]]]
        raise ConfigError(f"{axis}: no rate target logged for the held-out blocks "
                          f"({', '.join(names[:-1])} or {names[-1]})")
    ctrl = val[0].ctrl
    dt = val[0].seg.dt
    substeps = max(1, round(ctrl.loop_hz * dt))
    lag = _DEFAULT_LAG[ctrl.autopilot]
    meas_delay = 0.0

    def replayed(cand: int, tau: float) -> float:
        """The controller replay's fit % on the training blocks."""
        out = [(b.u - _lagged(np.repeat(b.injection, substeps), cand)[::substeps],
                replay_controller(b.ctrl, dt, b.target, b.rate, b.u, b.injection, cand,
                                  substeps, tau))
               for b in tr]
        out = [(m[b.warm:], r[b.warm:]) for b, (m, r) in zip(tr, out, strict=True)]
        return _pooled_fit([o[0] for o in out], [o[1] for o in out])

    if tr:
        scores = [replayed(cand, 0.0) for cand in LAGS]
        if np.any(np.isfinite(scores)):
            lag = LAGS[int(np.nanargmax(scores))]
            if substeps == 1:  # (a sample held over several steps has no sub-step timing)
                by_tau = [(scores[LAGS.index(lag)], 0.0)]
                by_tau += [(replayed(lag, tau), tau) for tau in MEAS_DELAYS[1:]]
                best = max(sc for sc, _ in by_tau if np.isfinite(sc))
                meas_delay = min(tau for sc, tau in by_tau
                                 if np.isfinite(sc) and sc >= best - MEAS_DELAY_TOL)
    try:
        plant = plant_from_model(model, axis, dt / substeps)
    except ConfigError:
        if substeps == 1:
            raise
        substeps = 1
        plant = plant_from_model(model, axis, dt)
    ys, yts, us, uts, blocks = [], [], [], [], []
    for b in val:
        y_sim, u_sim = simulate_closed_loop(
            plant, b.ctrl.new_pid(dt / substeps), b.target, injection=b.injection,
            others=_others(b, plant), substeps=substeps, rate=b.rate, u=b.u, warmup=b.warm,
            lag=lag, meas_delay=meas_delay,
        )
        w = b.warm
        inj = _lagged(np.repeat(b.injection, substeps), lag)[::substeps][w:]
        ys.append(b.rate[w:])
        yts.append(y_sim)
        us.append(b.u[w:] - inj)
        uts.append(u_sim - inj)
        blocks.append((b.seg.time_s, b.target[w:], b.rate[w:], y_sim, b.u[w:], u_sim))
    b_fit, b_delay, b_pred = baseline_fit([(b.target[b.warm:], b.rate[b.warm:]) for b in tr],
                                          [(b.target[b.warm:], b.rate[b.warm:]) for b in val],
                                          dt)
    twin_blocks = tuple(
        TwinBlock(t, tg, y, ysim, u, usim, bp)
        for (t, tg, y, ysim, u, usim), bp in zip(blocks, b_pred, strict=True)
    )
    k = flights.index(next(fd for fd in flights if fd.index_of(val[0].seg) is not None))
    return ClosedLoopFit(
        fit_percent=_pooled_fit(ys, yts),
        output_fit_percent=float(fit_percent(np.concatenate(us), np.concatenate(uts))),
        baseline_percent=b_fit,
        baseline_delay_s=b_delay,
        defaults_used=ctrl.defaults_used,
        open_loop_percent=open_loop_percent,
        controller=ctrl.to_dict(),
        substeps=substeps,
        lag_loops=lag,
        measurement_delay_loops=meas_delay,
        target_source=sigs[k].sources.get(f"target_{axis}", ""),
        injection_source=sigs[k].sources.get(f"injection_{axis}", ""),
        blocks=twin_blocks,
    )


def _others(b: _Block, plant: LinearPlant) -> np.ndarray | None:
    """The model's other inputs, as measured over the block and its warm-up."""
    if not plant.other_inputs:
        return None
    return np.column_stack([b.inputs[:, b.input_names.index(n)] for n in plant.other_inputs])


def _locate(segments: Sequence[Segment], axis: str, flights: Sequence[FlightData],
            sigs: Sequence[TwinSignals]) -> list[_Block]:
    """The segments found on a flight with a rate target, with their twin signals and the
    measured samples before them (within the flight's contiguous block)."""
    rate, u_name = AXIS_RATE[axis], f"u_{axis}"
    out = []
    for seg in segments:
        for k, fd in enumerate(flights):
            i = fd.index_of(seg)
            if i is None or axis not in sigs[k].target or u_name not in fd.input_names:
                continue
            first = max((int(a) for a, _ in fd.blocks if a <= i), default=0)
            warm = min(i - first, round(WARMUP_S / fd.dt))
            sl = slice(i - warm, i + len(seg))
            tgt = sigs[k].target[axis][sl]
            ok = np.isfinite(tgt)
            if not ok[warm:].all():
                break
            if not ok[:warm].all():  # no target before the block: no warm-up
                warm = 0
                sl = slice(i, i + len(seg))
                tgt = tgt[-len(seg):]
            inj_full = sigs[k].injection.get(axis)
            inj = inj_full[sl] if inj_full is not None else np.zeros(len(tgt))
            ctrl = controller_from_params(fd.params, axis, _autopilot(fd))
            out.append(_Block(
                seg, ctrl, warm, tgt, inj, fd.states[sl, fd.state_names.index(rate)],
                fd.inputs[sl, fd.input_names.index(u_name)], fd.inputs[sl], fd.input_names,
            ))
            break
    return out


def _autopilot(flight: FlightData) -> str | None:
    """``"px4"`` or ``"ardupilot"`` from the flight's metadata, None when unknown."""
    ap = str(flight.meta.get("autopilot") or "").lower()
    if "px4" in ap:
        return "px4"
    if "ardupilot" in ap or "apm" in ap:
        return "ardupilot"
    if flight.source.format == "ulog":
        return "px4"
    return None


# --------------------------------------------------------------------------- loop analysis


def _first_order_z(cutoff_hz: float, dt: float) -> tuple[list[float], list[float]]:
    """The ``_alpha`` low pass as ``(num, den)`` in z⁻¹ (unity when off)."""
    a = _alpha(cutoff_hz, dt)
    return ([a, 0.0], [1.0, -(1.0 - a)]) if a < 1.0 else ([1.0], [1.0])


def controller_tf(ctrl: AxisController, dt: float | None = None) -> tuple[Any, Any]:
    """Discrete transfer functions of the rate controller at its loop step: ``(C_fb, C_t)``,
    output per measured rate (negated: ``u = C_t·target − C_fb·rate``) and per target.

    They are exactly :class:`RatePID` / :class:`PX4RatePID` without limits (integrator
    ``I·dt/(1 − z⁻¹)``, derivative ``(1 − z⁻¹)/dt``, first-order filters ``α/(1 − (1−α)z⁻¹)``,
    PX4's biquad on the derivative).

    Examples
    --------
    >>> cfb, ct = controller_tf(controller_from_params({}, "roll"))
    >>> round(float(abs(cfb(np.exp(1j * 2 * np.pi * 1.0 * 0.0025)))), 3)   # |C| at 1 Hz
    0.136
    """
    step = 1.0 / ctrl.loop_hz if dt is None else dt
    return _controller_tf(ctrl.gains, float(step))


@functools.lru_cache(maxsize=64)
def _controller_tf(g: RateGains | PX4RateGains, step: float) -> tuple[Any, Any]:
    """:func:`controller_tf` by gains and step, cached: the report's σ draws and the loop
    section ask for the same controller dozens of times (python-control's polynomial
    arithmetic, ~5 ms a call). The systems are never modified in place."""
    import control

    one = control.tf([1.0], [1.0], step)
    integ = control.tf([step, 0.0], [1.0, -1.0], step)  # dt / (1 - z^-1)
    deriv = control.tf([1.0, -1.0], [step, 0.0], step)  # (1 - z^-1) / dt
    if isinstance(g, PX4RateGains):
        fd = one
        if 0 < g.dgyro_hz < 0.5 / step:
            b, a = dsp.lowpass2p_coefficients(g.dgyro_hz, 1.0 / step)
            fd = control.tf(list(b), list(a), step)
        pi = g.k * g.p * one + g.k * g.i * integ
        return pi + g.k * g.d * fd * deriv, pi + g.ff * one
    ft = control.tf(*_first_order_z(g.fltt, step), step)
    fe = control.tf(*_first_order_z(g.flte, step), step)
    fd = control.tf(*_first_order_z(g.fltd, step), step)
    pid = fe * (g.p * one + g.i * integ + g.d * fd * deriv)
    return pid, pid * ft + g.ff * ft


_Poly = tuple[np.ndarray, np.ndarray]


def _tf_add(p: _Poly, q: _Poly) -> _Poly:
    """``p + q`` of two SISO transfer functions ``(num, den)`` (python-control's sum)."""
    return _trim((np.polyadd(np.polymul(p[0], q[1]), np.polymul(q[0], p[1])),
                  np.polymul(p[1], q[1])))


def _tf_mul(p: _Poly, q: _Poly) -> _Poly:
    """``p · q`` of two SISO transfer functions ``(num, den)``."""
    return _trim((np.polymul(p[0], q[0]), np.polymul(p[1], q[1])))


def _tf_gain(k: float, p: _Poly) -> _Poly:
    """``k · p``."""
    return _trim((k * np.asarray(p[0], dtype=float), np.asarray(p[1], dtype=float)))


def _tf_at(p: _Poly, z: np.ndarray) -> np.ndarray:
    """The transfer function ``(num, den)`` at the points ``z``."""
    return np.polyval(p[0], z) / np.polyval(p[1], z)


def _trim(p: _Poly) -> _Poly:
    """``p`` as python-control's transfer functions keep one: no leading zero coefficients,
    and ``0 / 1`` for a zero numerator (so that adding it does not raise the order)."""
    num, den = (np.trim_zeros(np.asarray(x, dtype=float), "f") for x in p)
    return (num, den) if num.size else (np.zeros(1), np.ones(1))


def controller_polys(ctrl: AxisController, dt: float | None = None) -> tuple[_Poly, _Poly]:
    """:func:`controller_tf` as numpy polynomials, ``((num, den) of C_fb, (num, den) of
    C_t)`` in descending powers of z: the same sums and products of the same parts, without
    python-control (``tests/test_loop.py`` checks the coefficients against it).

    Examples
    --------
    >>> (bf, af), _ = controller_polys(controller_from_params({}, "roll"))
    >>> z = np.exp(2j * np.pi * 1.0 * 0.0025)
    >>> round(float(abs(np.polyval(bf, z) / np.polyval(af, z))), 3)   # |C| at 1 Hz
    0.136
    """
    step = 1.0 / ctrl.loop_hz if dt is None else dt
    return _controller_polys(ctrl.gains, float(step))


@functools.lru_cache(maxsize=64)
def _controller_polys(g: RateGains | PX4RateGains, step: float) -> tuple[_Poly, _Poly]:
    """:func:`controller_polys` by gains and step, cached (callers never modify them)."""
    one: _Poly = (np.array([1.0]), np.array([1.0]))
    integ: _Poly = (np.array([step, 0.0]), np.array([1.0, -1.0]))
    deriv: _Poly = (np.array([1.0, -1.0]), np.array([step, 0.0]))
    if isinstance(g, PX4RateGains):
        fd = one
        if 0 < g.dgyro_hz < 0.5 / step:
            b, a = dsp.lowpass2p_coefficients(g.dgyro_hz, 1.0 / step)
            fd = (np.asarray(b, dtype=float), np.asarray(a, dtype=float))
        pi = _tf_add(_tf_gain(g.k * g.p, one), _tf_gain(g.k * g.i, integ))
        fb = _tf_add(pi, _tf_gain(g.k * g.d, _tf_mul(fd, deriv)))
        return fb, _tf_add(pi, _tf_gain(g.ff, one))
    ft, fe, fd = ((np.asarray(x, dtype=float), np.asarray(y, dtype=float))
                  for x, y in (_first_order_z(c, step) for c in (g.fltt, g.flte, g.fltd)))
    inner = _tf_add(_tf_add(_tf_gain(g.p, one), _tf_gain(g.i, integ)),
                    _tf_gain(g.d, _tf_mul(fd, deriv)))
    pid = _tf_mul(fe, inner)
    return pid, _tf_add(_tf_mul(pid, ft), _tf_gain(g.ff, ft))


@dataclass(frozen=True)
class LoopAnalysis:
    """The rate loop of one axis with given gains.

    Attributes
    ----------
    gain_margin_db, phase_margin_deg, crossover_hz : float
        Of the loop transfer ``L = C_fb·P`` (crossover: where ``|L| = 1``).
    bandwidth_hz : float
        −3 dB bandwidth of the closed loop from rate target to rate.
    peak_db : float
        Largest closed-loop gain.
    disturbance_bandwidth_hz : float
        Where the sensitivity ``1/(1+L)`` reaches −3 dB.
    phase_delay_s : float
        Phase delay of the closed loop at twice the −180° frequency (``-phase/ω``, at the
        bandwidth when that is not reached).
    rise_time_s, overshoot_percent : float
        Of the closed-loop step response.
    freq_hz, magnitude_db, phase_deg : numpy.ndarray
        The closed-loop response from rate target to rate.
    stderr : Mapping[str, float]
        One-σ of each figure from the plant's parameter covariance.
    loop_response, closed_response : numpy.ndarray
        Complex ``L`` and ``T`` at ``freq_hz``.
    mixer_loop_response : numpy.ndarray
        The broken loop a mixer injection measures: the rate loop and the attitude loop
        around it (``angle_p``), ``(C_fb + C_t·angle_p·dt/(1−z⁻¹))·P``.
    mixer_margins : Mapping[str, float]
        ``gain_db``, ``phase_deg``, ``crossover_hz`` of that loop.
    """

    gain_margin_db: float
    phase_margin_deg: float
    crossover_hz: float
    bandwidth_hz: float
    peak_db: float
    disturbance_bandwidth_hz: float
    phase_delay_s: float
    rise_time_s: float
    overshoot_percent: float
    freq_hz: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    magnitude_db: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    phase_deg: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    stderr: Mapping[str, float] = field(default_factory=dict)
    loop_response: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, complex))
    closed_response: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, complex))
    mixer_loop_response: np.ndarray = field(repr=False,
                                            default_factory=lambda: np.zeros(0, complex))
    mixer_margins: Mapping[str, float] = field(default_factory=dict)

    def figures(self) -> dict[str, float]:
        """The scalar figures by name."""
        return {k: float(getattr(self, k)) for k in _FIGURES}

    def to_dict(self) -> dict[str, Any]:
        """The JSON form ``mavsid tune --json`` gives per axis (margins, closed loop)."""
        return {
            "margins": {"gain_db": self.gain_margin_db, "phase_deg": self.phase_margin_deg,
                        "crossover_hz": self.crossover_hz},
            "closed_loop": {
                "bandwidth_hz": self.bandwidth_hz, "peak_db": self.peak_db,
                "disturbance_bandwidth_hz": self.disturbance_bandwidth_hz,
                "phase_delay_s": self.phase_delay_s, "rise_time_s": self.rise_time_s,
                "overshoot_percent": self.overshoot_percent,
                "frequency_hz": self.freq_hz.tolist(),
                "magnitude_db": self.magnitude_db.tolist(),
                "phase_deg": self.phase_deg.tolist(),
            },
            "mixer_margins": dict(self.mixer_margins),
            "loop": {
                "frequency_hz": self.freq_hz.tolist(),
                "magnitude_db": (20 * np.log10(np.abs(self.loop_response))).tolist(),
                "phase_deg": np.degrees(np.unwrap(np.angle(self.loop_response))).tolist(),
            },
            "stderr": dict(self.stderr),
        }


_FIGURES = ("gain_margin_db", "phase_margin_deg", "crossover_hz", "bandwidth_hz", "peak_db",
            "disturbance_bandwidth_hz", "phase_delay_s", "rise_time_s", "overshoot_percent")


def _crossing(f: np.ndarray, mag_db: np.ndarray, level: float, rising: bool) -> float:
    """First frequency where ``mag_db`` crosses ``level`` (log-interpolated), NaN if never."""
    above = mag_db >= level
    now, before = (above[1:], above[:-1]) if rising else (~above[1:], ~above[:-1])
    idx = np.flatnonzero(now & ~before)
    if not idx.size:
        return float("nan")
    i = int(idx[0])
    x0, x1 = np.log(f[i]), np.log(f[i + 1])
    y0, y1 = mag_db[i], mag_db[i + 1]
    return float(np.exp(x0 + (level - y0) * (x1 - x0) / (y1 - y0))) if y1 != y0 else float(f[i])


def frequency_response(system: Any, z: np.ndarray) -> np.ndarray:
    """A single-input single-output python-control system's response at the points ``z``,
    through its transfer-function polynomials (python-control evaluates a state space with
    one linear solve per point, far slower for thousands of points).

    Examples
    --------
    >>> import control
    >>> sys = control.ss(control.tf([0.5], [1.0, -0.9], 0.01))
    >>> z = np.exp(2j * np.pi * np.array([0.1, 10.0]) * 0.01)
    >>> bool(np.allclose(frequency_response(sys, z), np.ravel(sys(z))))
    True
    """
    if hasattr(system, "A"):
        a, b, c, d = (np.asarray(x, dtype=float) for x in
                      (system.A, system.B, system.C, system.D))
        if a.size == 0:
            return np.full(z.shape, float(d.ravel()[0]), dtype=complex)
        num, den = _ss2tf(a, b, c, float(d.ravel()[0]))
    else:
        num = np.asarray(system.num[0][0], dtype=float)
        den = np.asarray(system.den[0][0], dtype=float)
    return np.polyval(num, z) / np.polyval(den, z)


def loop_margins(loop: Any, dt: float, n: int = 4000) -> tuple[float, float, float]:
    """``(gain margin (ratio), phase margin (deg), gain-crossover (rad/s))`` of a discrete
    open loop, read off its frequency response on a dense log grid up to Nyquist (crossings
    interpolated between grid points; the smallest margins when there are several), as
    ``control.stability_margins`` gives them but without its per-call spline fits (about
    100× faster: the report samples the loop dozens of times per axis).

    Examples
    --------
    >>> import control
    >>> dt = 0.0025
    >>> loop = control.tf([0.0, 0.02], [1.0, -1.0], dt) * control.tf([1.0], [1.0, 0.0, 0.0], dt)
    >>> gm, pm, wc = loop_margins(loop, dt)
    >>> ref = control.stability_margins(loop)
    >>> bool(abs(pm - ref[1]) < 0.05 and abs(wc - ref[4]) / ref[4] < 1e-3
    ...      and abs(gm - ref[0]) / ref[0] < 1e-3)
    True
    """
    f = _margin_grid(dt, n)
    return _margins_of(f, frequency_response(loop, np.exp(2j * np.pi * f * dt)))


def _margin_grid(dt: float, n: int = 4000) -> np.ndarray:
    """The frequencies (Hz) :func:`loop_margins` reads a loop on."""
    return np.geomspace(1e-3 / dt, 0.4999 / dt, n)


def _margins_of(f: np.ndarray, resp: np.ndarray) -> tuple[float, float, float]:
    """:func:`loop_margins` from the loop's response ``resp`` at ``f`` (Hz)."""
    mag = np.abs(resp)
    logf = np.log(f)
    pm, wc = float("inf"), float("nan")
    for i in np.flatnonzero((mag[:-1] >= 1.0) & (mag[1:] < 1.0) | (mag[:-1] < 1.0)
                            & (mag[1:] >= 1.0)):
        x = (0.0 - np.log(mag[i])) / (np.log(mag[i + 1]) - np.log(mag[i]))
        ang = np.angle(resp[i]) + x * np.angle(resp[i + 1] / resp[i])
        deg = float(np.degrees(ang)) % 360.0 - 360.0  # in (-360, 0]
        margin = 180.0 + deg
        if margin < pm:
            pm, wc = margin, float(np.exp(logf[i] + x * (logf[i + 1] - logf[i])) * 2 * np.pi)
    gm = float("inf")
    im = resp.imag
    for i in np.flatnonzero(np.sign(im[:-1]) * np.sign(im[1:]) < 0):
        x = im[i] / (im[i] - im[i + 1])
        re = resp.real[i] + x * (resp.real[i + 1] - resp.real[i])
        if re < 0:
            gm = min(gm, 1.0 / abs(re))
    return gm, (pm if np.isfinite(pm) else float("inf")), wc


def _db(gain_margin: float) -> float:
    """A gain margin in dB (inf when the phase never crosses -180°)."""
    ok = np.isfinite(gain_margin) and gain_margin > 0
    return float(20 * np.log10(gain_margin)) if ok else float("inf")


def analyse_loop(plant_ss: Any, ctrl: AxisController, lag: int = 0,
                 freq_hz: np.ndarray | None = None, meas_delay: float = 0.0) -> LoopAnalysis:
    """Margins, bandwidths and step metrics of ``ctrl`` around ``plant_ss`` (a discrete
    python-control system at the controller's loop step, rate per controller output).

    ``lag`` loops of delay on the target path (see :func:`replay_controller`);
    ``meas_delay`` (0-1 loop) on the measured rate the controller reads (``(1 − τ) + τz⁻¹``,
    :attr:`ClosedLoopFit.measurement_delay_loops`).
    """
    import control

    dt = float(plant_ss.dt)
    cfb, ct = controller_tf(ctrl, dt)
    if lag:
        ct = ct * control.tf([1.0], [1.0] + [0.0] * lag, dt)
    tau, num, den = _reads(meas_delay)
    if tau:
        cfb = cfb * control.tf(num, den, dt)
    p = control.ss(plant_ss)
    cfb_ss, ct_ss = control.ss(cfb), control.ss(ct)
    loop_tf = cfb_ss * p
    # at the mixer the attitude loop closes too: rate target = angle_p * -(integral of rate)
    integ = control.tf([dt, 0.0], [1.0, -1.0], dt)
    mixer_loop = (cfb + ct * ctrl.angle_p * integ) * control.tf(plant_ss)
    closed = control.feedback(p, cfb_ss) * ct_ss
    sens = control.feedback(control.ss([], [], [], [[1.0]], dt), loop_tf)
    f = np.geomspace(0.1, 0.45 / dt, 400) if freq_hz is None else np.asarray(freq_hz)
    w = 2 * np.pi * f
    import warnings

    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # python-control's method fall-backs
        gm, pm, wcp = loop_margins(loop_tf, dt)
        zs = np.exp(1j * w * dt)
        t_resp = frequency_response(closed, zs)
        s_resp = frequency_response(sens, zs)
        l_resp = frequency_response(loop_tf, zs)
        m_resp = frequency_response(mixer_loop, zs)
        mgm, mpm, mwc = loop_margins(mixer_loop, dt)
    mag, ph, bw, dbw, phase_delay = _closed_figures(f, t_resp, s_resp)
    rise, over = _step_metrics(closed, dt)
    return LoopAnalysis(
        gain_margin_db=_db(gm),
        phase_margin_deg=float(pm), crossover_hz=float(wcp / (2 * np.pi)),
        bandwidth_hz=bw, peak_db=float(np.max(mag)), disturbance_bandwidth_hz=dbw,
        phase_delay_s=phase_delay, rise_time_s=rise, overshoot_percent=over,
        freq_hz=f, magnitude_db=mag, phase_deg=ph,
        loop_response=np.asarray(l_resp).ravel(), closed_response=np.asarray(t_resp).ravel(),
        mixer_loop_response=np.asarray(m_resp).ravel(),
        mixer_margins={"gain_db": _db(mgm), "phase_deg": float(mpm),
                       "crossover_hz": float(mwc / (2 * np.pi))},
    )


def _closed_figures(f: np.ndarray, t_resp: np.ndarray, s_resp: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, float, float, float]:
    """``(magnitude dB, phase deg, bandwidth, disturbance bandwidth, phase delay)`` of a
    closed loop from its responses ``T`` and ``S`` at ``f`` (see :class:`LoopAnalysis`)."""
    mag = 20 * np.log10(np.abs(t_resp))
    ph = np.degrees(np.unwrap(np.angle(t_resp)))
    bw = _crossing(f, mag - mag[0], -3.0, rising=False)
    dbw = _crossing(f, 20 * np.log10(np.abs(s_resp)), -3.0, rising=True)
    i180 = np.flatnonzero(ph <= -180.0)
    if i180.size:
        f2 = 2 * f[i180[0]] if 2 * f[i180[0]] <= f[-1] else f[i180[0]]
        phase_delay = float(-np.interp(f2, f, ph) / (360 * f2))
    elif np.isfinite(bw):
        phase_delay = float(-np.interp(bw, f, ph) / (360 * bw))
    else:
        phase_delay = float("nan")
    return mag, ph, bw, dbw, phase_delay


def _ss2tf(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: float = 0.0) -> _Poly:
    """``scipy.signal.ss2tf`` of a single-input single-output state space (its formula:
    ``den = poly(A)``, ``num = poly(A − B·C) + (D − 1)·den``)."""
    a = np.atleast_2d(np.asarray(a, dtype=float))
    b, c = np.asarray(b, dtype=float).reshape(-1, 1), np.asarray(c, dtype=float).reshape(1, -1)
    den = np.poly(a)
    return np.poly(a - b @ c) + (float(d) - 1.0) * den, den


def loop_figures(plant: LinearPlant, ctrl: AxisController, lag: int = 0,
                 freq_hz: np.ndarray | None = None, meas_delay: float = 0.0
                 ) -> dict[str, float]:
    """:meth:`LoopAnalysis.figures` of :func:`analyse_loop` for a :class:`LinearPlant` at
    the controller's step, with numpy polynomials instead of python-control systems (no
    state-space products, feedback or simulation objects): the same figures to rounding
    (``tests/test_loop.py`` checks 1e-6), about 10× faster, for :func:`analyse_model`'s
    draws of the coefficients."""
    return analyse_plant(plant, ctrl, lag, freq_hz, meas_delay, responses=False).figures()


def analyse_plant(plant: LinearPlant, ctrl: AxisController, lag: int = 0,
                  freq_hz: np.ndarray | None = None, meas_delay: float = 0.0,
                  responses: bool = True) -> LoopAnalysis:
    """:func:`analyse_loop` of a :class:`LinearPlant` at the controller's step in numpy (the
    controller from :func:`controller_polys`, each response the product of its parts'):
    what ``fit --report`` and ``tune`` use, without importing python-control. Margins,
    crossovers and the step's figures equal :func:`analyse_loop`'s to rounding; bandwidth,
    peak and the responses equal python-control's point-by-point evaluation (``analyse_loop``
    goes through one polynomial ratio of the whole closed loop, off by up to 0.5 %).
    ``responses=False`` leaves out the broken loop at the mixer and its margins."""
    dt = 1.0 / ctrl.loop_hz
    (bf, af), (bt, at) = controller_polys(ctrl, dt)
    if lag:
        at = np.polymul(at, [1.0] + [0.0] * lag)
    tau, num, den = _reads(meas_delay)
    if tau:
        bf, af = np.polymul(bf, num), np.polymul(af, den)
    bp, ap = _ss2tf(plant.a, plant.b, plant.c)
    f = np.geomspace(0.1, 0.45 / dt, 400) if freq_hz is None else np.asarray(freq_hz)
    fm = _margin_grid(dt)

    def loop_at(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = np.polyval(bp, z) / np.polyval(ap, z)
        return p, p * np.polyval(bf, z) / np.polyval(af, z)

    mixer: dict[str, float] = {}
    m_resp = np.zeros(0, complex)
    with np.errstate(all="ignore"):
        zm = np.exp(2j * np.pi * fm * dt)
        gm, pm, wcp = _margins_of(fm, loop_at(zm)[1])
        zs = np.exp(2j * np.pi * f * dt)
        p, lz = loop_at(zs)
        ctz = np.polyval(bt, zs) / np.polyval(at, zs)
        t_resp = p * ctz / (1.0 + lz)
        mag, ph, bw, dbw, phase_delay = _closed_figures(f, t_resp, 1.0 / (1.0 + lz))
        t = np.arange(0.0, 2.0, dt)
        y = _closed_step(plant, (bf, af), (bt, at), t.size)
        if responses:
            # at the mixer the attitude loop closes too: target = angle_p · −∫rate
            def mixer_at(z: np.ndarray, p: np.ndarray, lz: np.ndarray,
                         ctz: np.ndarray) -> np.ndarray:
                return lz + ctz * ctrl.angle_p * (dt * z / (z - 1.0)) * p

            m_resp = mixer_at(zs, p, lz, ctz)
            pmz, lmz = loop_at(zm)
            mgm, mpm, mwc = _margins_of(
                fm, mixer_at(zm, pmz, lmz, np.polyval(bt, zm) / np.polyval(at, zm)))
            mixer = {"gain_db": _db(mgm), "phase_deg": float(mpm),
                     "crossover_hz": float(mwc / (2 * np.pi))}
    rise, over = _step_figures(t, y)
    return LoopAnalysis(
        gain_margin_db=_db(gm), phase_margin_deg=float(pm),
        crossover_hz=float(wcp / (2 * np.pi)), bandwidth_hz=bw, peak_db=float(np.max(mag)),
        disturbance_bandwidth_hz=dbw, phase_delay_s=phase_delay, rise_time_s=rise,
        overshoot_percent=over, freq_hz=f, magnitude_db=mag, phase_deg=ph,
        loop_response=lz if responses else np.zeros(0, complex),
        closed_response=t_resp if responses else np.zeros(0, complex),
        mixer_loop_response=m_resp, mixer_margins=mixer)


def _closed_step(plant: LinearPlant, fb: tuple[np.ndarray, np.ndarray],
                 tg: tuple[np.ndarray, np.ndarray], n: int) -> np.ndarray:
    """``n`` samples of the unit-step response of ``P·C_t / (1 + C_fb·P)`` (``fb``, ``tg``:
    ``C_fb``, ``C_t`` as ``(num, den)`` in z), simulated in state space: plant, feedback and
    target filter states side by side (a single polynomial of the closed loop would carry
    the integrators' cancelling pole-zero pair at z = 1 and drift)."""
    ap, bp, cp = plant.a, plant.b.reshape(-1, 1), plant.c.reshape(1, -1)
    af, bf, cf, df = dsp.tf2ss(*fb)
    at, bt, ct, dt_ = dsp.tf2ss(*tg)
    npl, nf, nt = ap.shape[0], af.shape[0], at.shape[0]
    a = np.zeros((npl + nf + nt,) * 2)
    a[:npl, :npl] = ap - bp @ (df @ cp)
    a[:npl, npl:npl + nf] = -bp @ cf
    a[:npl, npl + nf:] = bp @ ct
    a[npl:npl + nf, :npl] = bf @ cp
    a[npl:npl + nf, npl:npl + nf] = af
    a[npl + nf:, npl + nf:] = at
    b = np.concatenate([bp @ dt_, np.zeros((nf, 1)), bt]).ravel()
    c = np.concatenate([cp.ravel(), np.zeros(nf + nt)])
    # blocks of m steps: y[jm + i] = c·Aⁱ·x[jm] + c·(I + … + Aⁱ⁻¹)·b, x[(j+1)m] = Aᵐ·x[jm] + sₘ
    m = 32
    rows = np.empty((m, a.shape[0]))
    sums = np.empty(m)
    row, acc = c.copy(), 0.0
    for i in range(m):
        rows[i], sums[i] = row, acc
        acc += float(row @ b)
        row = row @ a
    power, s = np.eye(a.shape[0]), np.zeros(a.shape[0])
    for _ in range(m):
        s = a @ s + b
        power = a @ power
    x = np.zeros(a.shape[0])
    y = np.empty(-(-n // m) * m)
    for j in range(0, y.size, m):
        y[j:j + m] = rows @ x + sums
        x = power @ x + s
    return y[:n]


def _step_metrics(closed: Any, dt: float, horizon_s: float = 2.0) -> tuple[float, float]:
    """10-90 % rise time (s) and overshoot (%) of the closed loop's unit step."""
    import control

    t = np.arange(0.0, horizon_s, dt)
    y = np.asarray(control.step_response(closed, T=t).outputs, dtype=float).ravel()
    return _step_figures(t, y)


def _step_figures(t: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """:func:`_step_metrics` of a step response ``y`` at times ``t``."""
    final = float(np.mean(y[-max(1, len(y) // 10):]))
    if not np.all(np.isfinite(y)) or abs(final) < 1e-9:
        return float("nan"), float("nan")
    r = y / final
    i10, i90 = np.flatnonzero(r >= 0.1), np.flatnonzero(r >= 0.9)
    rise = float(t[i90[0]] - t[i10[0]]) if i10.size and i90.size else float("nan")
    return rise, float(max(0.0, 100.0 * (np.max(r) - 1.0)))


def plant_statespace(model: Any, axis: str, dt: float) -> Any:
    """The axis's plant (controller output -> rate) as a discrete python-control system at
    step ``dt`` (filters and delay included; bias and other inputs left out)."""
    import control

    pl = plant_from_model(model, axis, dt)
    return control.ss(pl.a, pl.b.reshape(-1, 1), pl.c.reshape(1, -1), 0.0, dt)


def analyse_model(model: Any, axis: str, ctrl: AxisController, lag: int = 0,
                  samples: int = 40, seed: int = 0, meas_delay: float = 0.0) -> LoopAnalysis:
    """:func:`analyse_plant` of the identified plant, with one-σ uncertainties from
    ``samples`` draws of the model's coefficients from their covariance."""
    dt = 1.0 / ctrl.loop_hz
    base = analyse_plant(plant_from_model(model, axis, dt), ctrl, lag, meas_delay=meas_delay)
    cov = getattr(model, "covariance", None)
    rate = AXIS_RATE[axis]
    if cov is None or samples < 2 or rate not in model.state_names:
        return base
    j = model.state_names.index(rate)
    c = np.nan_to_num(np.asarray(cov[j], dtype=float))
    rng = np.random.default_rng(seed)
    draws = []
    for _ in range(samples):
        coef = model.coef.copy()
        coef[:, j] = rng.multivariate_normal(model.coef[:, j], c, check_valid="ignore")
        try:
            m = replace(model, coef=coef)
            draws.append(loop_figures(plant_from_model(m, axis, dt), ctrl, lag, base.freq_hz,
                                      meas_delay))
        except (MavsidError, ValueError, np.linalg.LinAlgError):
            continue
    if len(draws) < 2:
        return base
    finite = {k: [d[k] for d in draws if np.isfinite(d[k])] for k in _FIGURES}
    err = {k: float(np.std(v)) if v else math.nan for k, v in finite.items()}
    return replace(base, stderr=err)


def _scaled(ctrl: AxisController, k: float) -> AxisController:
    g = ctrl.gains
    if isinstance(g, PX4RateGains):
        return replace(ctrl, gains=replace(g, p=g.p * k, i=g.i * k, d=g.d * k))
    return replace(ctrl, gains=replace(g, p=g.p * k, i=g.i * k, d=g.d * k))


def _as_plant(plant: Any) -> LinearPlant:
    """A :class:`LinearPlant` as it is, or one of a discrete python-control state space
    (no feedthrough)."""
    if isinstance(plant, LinearPlant):
        return plant
    d = np.asarray(plant.D, dtype=float)
    if d.size and np.any(d != 0):
        raise ConfigError("the plant must have no feedthrough (D = 0)")
    return LinearPlant(np.atleast_2d(np.asarray(plant.A, dtype=float)),
                       np.asarray(plant.B, dtype=float).ravel(),
                       np.asarray(plant.C, dtype=float).ravel(), float(plant.dt))


def suggest_gains(plant_ss: Any, ctrl: AxisController, target_pm_deg: float = 50.0,
                  lag: int = 0, meas_delay: float = 0.0
                  ) -> tuple[dict[str, float], LoopAnalysis] | None:
    """P, I and D scaled together (ratios and filters kept) so that the loop's phase margin
    is ``target_pm_deg``; the vehicle's parameter names and units, and the predicted loop
    (:func:`analyse_plant`). None when no scale in [0.05, 20] reaches it with a stable loop.
    ``plant_ss``: a :class:`LinearPlant` or a discrete python-control state space at the
    controller's step. (``lag``, ``meas_delay``: :func:`analyse_loop`.)"""
    plant = _as_plant(plant_ss)
    dt = 1.0 / ctrl.loop_hz
    tau, num, den = _reads(meas_delay)
    # P, I and D scaled by k scale C_fb, so the loop, by k: one state space and one
    # response on the margins' grid serve every k (the closed loop's state matrix is
    # A − k·B·C / (1 + k·D)); the same margins as building each scaled loop, to rounding
    cfb, _ = controller_polys(ctrl, dt)
    if tau:
        cfb = _tf_mul(cfb, (np.asarray(num), np.asarray(den)))
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
    fm = _margin_grid(dt)
    with np.errstate(all="ignore"):
        zm = np.exp(2j * np.pi * fm * dt)
        unit_resp = plant_response(plant, fm) * _tf_at(cfb, zm)

    def pm(k: float) -> float:
        closed = a - k * (b @ c)
        if np.any(np.abs(np.linalg.eigvals(closed)) >= 1.0):
            return -1e9  # unstable closed loop
        with np.errstate(all="ignore"):
            margin = _margins_of(fm, k * unit_resp)[1]
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
    new = _scaled(ctrl, lo)
    result = analyse_plant(plant, new, lag, meas_delay=tau)
    if not (np.isfinite(result.phase_margin_deg) and result.gain_margin_db > 0):
        return None
    return gain_params(new), result


def margins_on_frf(plant_frf: Any, ctrl: AxisController) -> dict[str, float]:
    """Margins of ``ctrl`` around a measured plant FRF (controller output -> rate): the loop
    ``C_fb(e^{jωT})·P̂(f)`` over the FRF's coherent band, a check on a model's promise that
    does not go through the model (NaN where the band holds no crossover)."""
    m = plant_frf.coherent & np.isfinite(plant_frf.response)
    nan = {"gain_db": float("nan"), "phase_deg": float("nan"), "crossover_hz": float("nan")}
    if m.sum() < 8:
        return nan
    f, p = plant_frf.freq_hz[m], plant_frf.response[m]
    dt = 1.0 / ctrl.loop_hz
    cfb, _ = controller_polys(ctrl, dt)
    loop_resp = _tf_at(cfb, np.exp(2j * np.pi * f * dt)) * p
    band = replace(plant_frf, freq_hz=f, response=loop_resp, coherence=np.ones(f.size),
                   error=plant_frf.error[m])
    got = frd_margins(band)
    return got if f[0] < got["crossover_hz"] < f[-1] else nan


def gain_params(ctrl: AxisController) -> dict[str, float]:
    """The controller's P, I, D in the vehicle's own parameter names and units."""
    g = ctrl.gains
    if ctrl.autopilot == "px4":
        pre = f"MC_{_PX4[ctrl.axis]}RATE_"
        k = g.k if isinstance(g, PX4RateGains) else 1.0
        return {pre + "P": g.p, pre + "I": g.i, pre + "D": g.d, pre + "K": k}
    ax = _AP[ctrl.axis]
    if ctrl.naming == "RATE":
        return {f"RATE_{ax}_{n}": round(v / _AP3_SCALE, 6)
                for n, v in (("P", g.p), ("I", g.i), ("D", g.d))}
    pre = "Q_A_RAT" if ctrl.naming == "Q_A_RAT" else "ATC_RAT"
    return {f"{pre}_{ax}_{n}": round(v, 6) for n, v in (("P", g.p), ("I", g.i), ("D", g.d))}


# --------------------------------------------------------------------------- measured loop


def sysid_spans(flight: FlightData, axis: str) -> list[tuple[int, int, int]]:
    """Grid index ranges ``[i0, i1)`` of the flight's SYSTEMID runs on ``axis`` (cut at the
    first gap), with their ``SID_AXIS``: 1-3 angle, 4-6 recovery, 7-9 rate, 10-12 mixer."""
    out = []
    t = flight.time_s
    for run in flight.meta.get("sysid_runs", ()) or ():  # type: ignore[attr-defined]
        sid = int(run.get("axis", 0) or 0)
        if not 1 <= sid <= 12 or AXES[(sid - 1) % 3] != axis:
            continue
        i0 = int(np.searchsorted(t, float(run["start_s"])))
        i1 = int(np.searchsorted(t, float(run["stop_s"]), side="right"))
        for a, b in flight.blocks:
            if a <= i0 < b:
                i1 = min(i1, int(b))
                break
        if i1 - i0 > 8:
            out.append((i0, i1, sid))
    return out


def measured_responses(fit: Any, flights: Sequence[FlightData],
                       signals: Sequence[TwinSignals] | None = None, lag: int = 0,
                       which: Sequence[str] = ("plant", "loop", "closed_loop")
                       ) -> dict[str, Any]:
    """Frequency responses measured on the axis's SYSTEMID runs (whole runs, not the
    train/validation blocks: a chirp's low frequencies need the long windows):

    - ``"plant"``: controller output (mixer input) -> rate; with the injection as reference
      on mixer runs (:func:`mavsid.frequency.frf`), H1 otherwise;
    - ``"loop"``: the broken loop ``L = −c/u`` (``c`` the controller's part of the mixer
      input ``u``) where the injection is at the mixer (``SID_AXIS`` 10-12);
    - ``"closed_loop"``: rate target -> rate where the injection is in the target
      (``SID_AXIS`` 1-9; with the injection as reference on rate axes 7-9).

    Each is a :class:`mavsid.frequency.FRF` on the runs' chirp band; absent without runs.
    ``fit`` is the axis's :class:`mavsid.pipeline.AxisFit` or the axis's name; ``which``
    the responses wanted.
    """
    from mavsid.frequency import frf

    axis = fit if isinstance(fit, str) else fit.axis
    rate, u_name = AXIS_RATE[axis], f"u_{axis}"
    sigs = list(signals) if signals is not None else [twin_signals(fd) for fd in flights]
    mixer: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    other: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]] = []
    bands, dt = [], 0.0
    for fd, sg in zip(flights, sigs, strict=True):
        if rate not in fd.state_names or u_name not in fd.input_names:
            continue
        for i0, i1, sid in sysid_spans(fd, axis):
            runs: list[Any] = list(fd.meta.get("sysid_runs") or ())  # type: ignore[call-overload]
            run = next(r for r in runs if int(r.get("axis", 0) or 0) == sid)
            lo, hi = run.get("f_start_hz"), run.get("f_stop_hz")
            if lo and hi:
                bands.append((float(lo), float(hi)))
            dt = fd.dt
            y = fd.states[i0:i1, fd.state_names.index(rate)]
            u = fd.inputs[i0:i1, fd.input_names.index(u_name)]
            if sid >= 10 and axis in sg.injection:
                mixer.append((u, y, _lagged(sg.injection[axis], lag)[i0:i1]))
            elif axis in sg.target and np.all(np.isfinite(sg.target[axis][i0:i1])):
                ref = sg.rate_injection.get(axis)
                other.append((u, y, sg.target[axis][i0:i1],
                              ref[i0:i1] if ref is not None and 7 <= sid <= 9 else None))
    out: dict[str, Any] = {}
    if not dt:
        return out
    grid: dict[str, Any] = {}
    if bands:  # only the injected band: a noise-free log is coherent beyond it too
        grid = {"f_min_hz": min(b[0] for b in bands),
                "f_max_hz": min(max(b[1] for b in bands), 0.4 / dt)}
    refs = [r[3] for r in other]
    use_ref = bool(other) and all(r is not None for r in refs)
    try:
        if "plant" not in which:
            pass
        elif mixer:
            out["plant"] = frf([r[0] for r in mixer], [r[1] for r in mixer], dt,
                               reference=[r[2] for r in mixer], names=(u_name, rate), **grid)
        elif other:
            out["plant"] = frf([r[0] for r in other], [r[1] for r in other], dt,
                               reference=refs if use_ref else None,  # type: ignore[arg-type]
                               names=(u_name, rate), **grid)
    except MavsidError:
        pass
    if mixer and "loop" in which:
        try:
            out["loop"] = frf([r[0] for r in mixer], [-(r[0] - r[2]) for r in mixer], dt,
                              reference=[r[2] for r in mixer], names=(u_name, f"-c_{axis}"),
                              **grid)
        except MavsidError:
            pass
    if other and "closed_loop" in which:
        try:
            out["closed_loop"] = frf([r[2] for r in other], [r[1] for r in other], dt,
                                     reference=refs if use_ref else None,  # type: ignore[arg-type]
                                     names=(f"target_{axis}", rate), **grid)
        except MavsidError:
            pass
    return out


#: Least coherent frequencies an injection's FRF needs to choose the model structure.
FRF_STRUCTURE_MIN_POINTS = 20
#: Delay shifts (samples, each way) :class:`FrfStructure` tries around each candidate.
FRF_STRUCTURE_SHIFT = 2.0
#: FRF error floor (fraction): the composite's bias on a noise-free chirp (leakage where
#: the sweep is fast: 1 % median, 5 % in gain and 4 deg in phase at worst below 12 Hz)
FRF_STRUCTURE_FLOOR = 0.03


def plant_response(plant: LinearPlant, freq_hz: np.ndarray) -> np.ndarray:
    """``C (zI − A)⁻¹ B`` of a :class:`LinearPlant` at ``freq_hz``.

    Examples
    --------
    >>> p = LinearPlant(np.array([[0.9]]), np.array([0.5]), np.array([1.0]), 0.01)
    >>> h = plant_response(p, np.array([0.0]))
    >>> bool(np.isclose(h[0], 0.5 / (1 - 0.9)))
    True
    """
    z = np.exp(2j * np.pi * np.asarray(freq_hz, dtype=float) * plant.dt)
    return _tf_at(_ss2tf(plant.a, plant.b, plant.c), z)


class FrfStructure:
    """A ``choose_structure`` for :func:`mavsid.estimators.fit_axis`: the candidate lag and
    delay whose first-order model best matches an FRF measured against an injection, and
    that FRF's own estimate of the coefficients (:meth:`estimate`).

    On closed-loop data the one-step (and free-run) scores are biased by the noise the
    feedback puts into the input: with 1 deg/s of gyro noise fed back they chose a 10 ms
    motor lag and 7-8 ms of delay for a 15 ms lag and 5 ms delay, the closed-loop bandwidth
    then 10-12 % high. An FRF against the injection (``S_ry / S_ru``) is not biased by the
    feedback. Each candidate lag (its filters, its best one-step delay shifted by up to
    :data:`FRF_STRUCTURE_SHIFT` samples in ``delay_step`` steps) is fitted to the FRF in the
    frequency domain, ``H ≈ b z R(z) / (z − a)`` (``R`` the candidate's filters and delay;
    ``b`` solved exactly for each pole ``a`` on a grid), weighted by the FRF's random error
    ``ε`` (with a floor, :data:`FRF_STRUCTURE_FLOOR`); the lowest
    ``mean(|H − G|² / (|H| ε)²)`` wins. Calling it returns None (keep the one-step choice)
    for an FRF that is not referenced to an injection, with under
    :data:`FRF_STRUCTURE_MIN_POINTS` coherent frequencies, or for models that are not one
    rate from one input.
    """

    def __init__(self, measured: Any, axis: str, delay_step: float = 0.125) -> None:
        ok = (measured.coherent & np.isfinite(measured.response)
              & np.isfinite(measured.error) & (measured.error > 0))
        self.axis, self.delay_step = axis, delay_step
        self.f, self.h = measured.freq_hz[ok], measured.response[ok]
        self.usable = (bool(getattr(measured, "referenced", False))
                       and self.f.size >= FRF_STRUCTURE_MIN_POINTS)
        self.w = 1.0 / (np.abs(self.h) ** 2 * (measured.error[ok] ** 2 + FRF_STRUCTURE_FLOOR**2))

    def _fit(self, model: Model, shifts: np.ndarray, damping: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Cost and gain ``b`` (shift x pole) of ``model``'s structure with its delay
        shifted by ``shifts`` (samples), for the poles ``exp(-damping dt)``; and the poles."""
        rate, u_name = AXIS_RATE[self.axis], f"u_{self.axis}"
        if (not self.usable or model.state_names != (rate,) or model.continuous
                or set(model.features) - {rate, u_name, "1"} or u_name not in model.features):
            return None
        unit = np.zeros_like(model.coef)
        unit[model.features.index(u_name), 0] = 1.0  # a = 0, b = 1: R(z) / z
        try:
            r = plant_response(plant_from_model(replace(model, coef=unit), self.axis), self.f)
        except (MavsidError, ValueError, np.linalg.LinAlgError):
            return None
        f, h, w, dt = self.f, self.h, self.w, float(model.dt)
        z = np.exp(2j * np.pi * f * dt)
        poles = np.exp(-damping * dt)
        # with q = z R e^{-jωs dt} / (z - a) and the best b for each (s, a), the cost is
        # (Σ w|h|² − (Σ w Re(q̄ h))² / Σ w|q|²) / m: Σ w|q|² does not depend on the shift
        # and Σ w q̄ h over the frequencies is one product of (shift x f) and (f x pole)
        zr = z * r
        gram = (w * np.abs(zr) ** 2) @ (1.0 / np.abs(z[:, None] - poles[None, :]) ** 2)
        rot = np.exp(2j * np.pi * np.outer(shifts, f) * dt)
        cross = (rot @ ((w * np.conj(zr) * h)[:, None] / np.conj(z[:, None] - poles[None, :]))
                 ).real
        with np.errstate(divide="ignore", invalid="ignore"):
            cost = (np.sum(w * np.abs(h) ** 2) - cross**2 / gram[None, :]) / f.size
            gain = cross / gram[None, :]
        if not np.any(np.isfinite(cost)):
            return None
        return cost, gain, poles

    def _score(self, model: Model) -> tuple[float, float] | None:
        """(lowest cost, delay in samples) of one candidate over its delay shifts and poles."""
        d0 = float(model.delay + model.delay_frac)
        shifts = np.arange(-min(d0, FRF_STRUCTURE_SHIFT), FRF_STRUCTURE_SHIFT + 1e-9,
                           self.delay_step)
        got = self._fit(model, shifts, _FRF_DAMPING)
        if got is None:
            return None
        cost = got[0]
        i = np.unravel_index(int(np.nanargmin(cost)), cost.shape)[0]
        return float(np.nanmin(cost)), round(d0 + float(shifts[i]), 9)

    def __call__(self, models: Mapping[float, Model]) -> tuple[float, float] | None:
        """The best candidate's (lag s, delay samples) among ``models`` (per lag, its
        least-squares model at its best one-step delay)."""
        best: tuple[float, float, float] | None = None
        for lag, model in models.items():
            got = self._score(model)
            if got is not None and (best is None or got[0] < best[0]):
                best = (got[0], lag, got[1])
        return None if best is None else (best[1], best[2])

    def estimate(self, model: Model) -> Model | None:
        """``model`` with its pole and gain fitted to the FRF instead (its structure and
        trim kept): the estimate the feedback does not bias, for comparison; None where
        the FRF cannot give one."""
        got = self._fit(model, np.zeros(1), _FRF_DAMPING)
        if got is None:
            return None
        k = int(np.nanargmin(got[0][0]))
        lo, hi = _FRF_DAMPING[max(k - 1, 0)], _FRF_DAMPING[min(k + 1, _FRF_DAMPING.size - 1)]
        got = self._fit(model, np.zeros(1), np.linspace(lo, hi, 81))  # finer about the best
        if got is None:
            return None
        cost, gain, poles = got
        k = int(np.nanargmin(cost[0]))
        coef = np.array(model.coef, dtype=float, copy=True)
        coef[model.features.index(AXIS_RATE[self.axis]), 0] = poles[k]
        coef[model.features.index(f"u_{self.axis}"), 0] = gain[0, k]
        return replace(model, coef=coef)


#: Damping values (1/s) of the poles :class:`FrfStructure` tries.
_FRF_DAMPING = np.linspace(-2.0, 80.0, 165)


def compare_response(measured: Any, freq_hz: np.ndarray, response: np.ndarray
                     ) -> dict[str, Any]:
    """Median and largest |error| in dB and degrees of a predicted response against a
    measured FRF over the measured one's coherent band (NaN when none)."""
    m = measured.coherent & (measured.freq_hz >= freq_hz[0]) & (measured.freq_hz <= freq_hz[-1])
    if not m.any():
        return {"median_db": float("nan"), "max_db": float("nan"),
                "median_deg": float("nan"), "max_deg": float("nan"), "band_hz": None}
    f = measured.freq_hz[m]
    pred = np.interp(f, freq_hz, response.real) + 1j * np.interp(f, freq_hz, response.imag)
    ratio = measured.response[m] / pred
    db = np.abs(20 * np.log10(np.abs(ratio)))
    deg = np.abs(np.degrees(np.angle(ratio)))
    return {"median_db": float(np.median(db)), "max_db": float(np.max(db)),
            "median_deg": float(np.median(deg)), "max_deg": float(np.max(deg)),
            "band_hz": [float(f.min()), float(f.max())]}


def frd_margins(measured: Any, freq_hz: np.ndarray | None = None,
                response: np.ndarray | None = None) -> dict[str, float]:
    """Gain and phase margin of a measured broken-loop FRF over its coherent band; with
    ``freq_hz`` and ``response``, those of that (predicted) response over the same band, for
    a like-for-like comparison. The margins are ``control.stability_margins`` of
    ``control.frd(h, ω)`` (:func:`_frd_margins`: its interpolation and root finding, without
    importing python-control; ``tests/test_frequency.py`` compares)."""
    m = measured.coherent & np.isfinite(measured.response)
    nan = {"gain_db": float("nan"), "phase_deg": float("nan"), "crossover_hz": float("nan")}
    if m.sum() < 4:
        return nan
    f = measured.freq_hz[m]
    h = measured.response[m]
    if freq_hz is not None and response is not None:
        h = np.interp(f, freq_hz, response.real) + 1j * np.interp(f, freq_hz, response.imag)
    gm, pm, wc = _frd_margins(h, 2 * np.pi * f)
    return {"gain_db": _db(gm), "phase_deg": float(pm), "crossover_hz": float(wc / (2 * np.pi))}


def _frd_margins(h: np.ndarray, w: np.ndarray) -> tuple[float, float, float]:
    """``(gain margin, phase margin (deg), gain crossover (rad/s))`` of a frequency response
    ``h`` at ``w`` (rad/s) as python-control's ``stability_margins`` of a smoothed FRD gives
    them: a parametric interpolating spline through the real and imaginary parts (its
    weights ``1/(|h| + 0.001)`` do not enter an interpolating fit), the −180° and unit-gain
    crossings between the points located by Brent's method on it; the smallest ``|log GM|``
    and ``|PM|``."""
    order = np.argsort(w, kind="stable")
    w, h = np.asarray(w, dtype=float)[order], np.asarray(h, dtype=complex)[order]
    at = dsp.interpolating_spline(w, h)  # (FITPACK's s=0 curve: the weights do not enter)

    def arg(x: float) -> float:
        return float(np.angle(-at(x)))

    def mod(x: float) -> float:
        return float(np.abs(at(x))) - 1.0

    hw = at(w)
    idx = np.where(np.diff(np.sign(np.angle(-hw))))[0]
    idx = idx[np.real(hw[idx]) <= 0]
    w180 = np.array([dsp.brent_root(arg, w[i], w[i + 1]) for i in idx])
    idx = np.where(np.diff(np.sign(np.abs(hw) - 1.0)))[0]
    wc = np.array([dsp.brent_root(mod, w[i], w[i + 1]) for i in idx])
    with np.errstate(all="ignore"):
        gms = 1.0 / np.abs(at(w180)) if w180.size else np.zeros(0)
        pms = (np.remainder(np.angle(at(wc), deg=True), 360.0) - 180.0 if wc.size
               else np.zeros(0))
        gm = float("inf")
        if gms.size and not np.isinf(gms).all():
            lg = np.abs(np.log(gms))
            gm = float(gms[lg == np.min(lg)][0])
    if not pms.size:
        return gm, float("inf"), float("nan")
    i = int(np.flatnonzero(np.abs(pms) == np.min(np.abs(pms)))[0])
    return gm, float(pms[i]), float(wc[i])


# --------------------------------------------------------------------------- tune


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
    from mavsid.frequency import fit_tf

    out: dict[str, Any] = {}
    known = getattr(result, "twins", None)  # (those the fit read, else once for every axis)
    signals = (list(known) if known is not None and len(known) == len(result.flights)
               else [twin_signals(fd) for fd in result.flights])
    for axis, fit in result.axes.items():
        entry: dict[str, Any] = {}
        fd = result.flights[0]
        try:
            ctrl = controller_from_params(fd.params, axis, _autopilot(fd))
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
                    k = _scale_of(got[0], ctrl)
                    check = margins_on_frf(plant, _scaled(ctrl, k))
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


def _scale_of(gains: Mapping[str, float], ctrl: AxisController) -> float:
    """The P/I/D scale :func:`suggest_gains` applied (from its P)."""
    new_p = next(v for k, v in gains.items() if k.endswith("_P"))
    old_p = ctrl.gains.p if ctrl.naming != "RATE" else ctrl.gains.p / _AP3_SCALE
    return float(new_p / old_p) if old_p else 1.0


def _figure(v: float | None, fmt: str, unit: str, sd: float | None = None) -> str:
    """A loop figure as ``mavsid tune`` prints it, with its σ; ``none`` where it does not
    exist (a loop whose gain never crosses 1 has no phase margin nor crossover; an unstable
    one no rise time).

    Examples
    --------
    >>> _figure(34.12, ".1f", "deg", 1.5), _figure(float("inf"), ".1f", "deg", 1.5)
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
            return _figure(v, fmt, unit, sd.get(key))

        lines.append(
            f"{axis}: phase margin {pm(m['phase_deg'], 'phase_margin_deg', '.1f', 'deg')}, "
            f"gain margin {pm(m['gain_db'], 'gain_margin_db', '.1f', 'dB')}, crossover "
            f"{pm(m['crossover_hz'], 'crossover_hz', '.2f', 'Hz')}; closed-loop bandwidth "
            f"{pm(c['bandwidth_hz'], 'bandwidth_hz', '.2f', 'Hz')}, peak "
            f"{_figure(c['peak_db'], '.1f', 'dB')}, rise "
            f"{_figure(c['rise_time_s'] * 1e3, '.0f', 'ms')}, overshoot "
            f"{_figure(c['overshoot_percent'], '.0f', '%')}")
        if "loop_frf_margins" in e:
            mm, pr = e["loop_frf_margins"], e["loop_predicted_margins"]
            cmp_ = e["loop_frf_vs_predicted"]
            lines.append(
                f"  at the mixer (rate and attitude loops): measured phase margin "
                f"{_figure(mm['phase_deg'], '.1f', 'deg')} at "
                f"{_figure(mm['crossover_hz'], '.2f', 'Hz')}, predicted "
                f"{_figure(pr['phase_deg'], '.1f', 'deg')} at "
                f"{_figure(pr['crossover_hz'], '.2f', 'Hz')}; prediction within "
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
