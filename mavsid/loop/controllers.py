"""The vehicle's rate controller, one implementation per autopilot, and its rebuild from a
log's parameters.

- ArduPilot ``AC_PID`` (:class:`RatePID`): target low-passed at ``FLTT``, error
  ``target - measured`` low-passed at ``FLTE`` (0 = off), derivative of the filtered error
  low-passed at ``FLTD``; ``out = P·err + I + D·derr + FF·target + D_FF·dtarget`` with
  ``|I| ≤ IMAX`` (no integrator with ``I`` = 0) and the derivative of the filtered target;
  when ``SMAX`` > 0 the P and D terms are scaled down so that their slew rate stays near
  ``SMAX`` (an approximation of ArduPilot's slew limiter, see :class:`RatePID`), then both
  scaled so that ``|P + D| ≤ PDMX`` when ``PDMX`` > 0; while the output saturated in the
  previous loop (the motors' limit) the integrator may only shrink;
- PX4 multicopter rate control (:class:`PX4RatePID`): ``out = K·P·err + I - K·D·ṁ + FF·target``
  with the derivative taken on the measured rate (``ṁ``, low-passed at ``IMU_DGYRO_CUTOFF``),
  the integrator gain ``K·I`` scaled down for large errors and limited to ``MC_*R_INT_LIM``,
  no error integrated that pushes further in a saturated direction.

:func:`controller_from_params` rebuilds one axis's controller from a log's parameters
(ArduPilot ``ATC_RAT_{RLL,PIT,YAW}_*``, the 3.x ``RATE_{RLL,PIT,YAW}_*`` names, the 3.5–4.0
single ``FILT``, ``SCHED_LOOP_RATE``, ``INS_GYRO_FILTER``; PX4 ``MC_{ROLL,PITCH,YAW}RATE_*``,
``MC_{RR,PR,YR}_INT_LIM``, ``IMU_GYRO_CUTOFF``, ``IMU_DGYRO_CUTOFF``, ``IMU_GYRO_RATEMAX``);
a parameter the log lacks takes the autopilot's documented default and is listed in
``defaults_used``. :func:`gain_params` gives P, I, D back in the vehicle's own names.

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

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from mavsid.autopilot import ardupilot, px4
from mavsid.axes import AXES, RATE_OF
from mavsid.errors import ConfigError
from mavsid.numerics.filters import Lowpass2p, lfilter

if TYPE_CHECKING:
    from mavsid.data import FlightData

__all__ = [
    "AXES",
    "AXIS_RATE",
    "PID",
    "AxisController",
    "PX4RateGains",
    "PX4RatePID",
    "RateGains",
    "RatePID",
    "autopilot_of",
    "controller_from_params",
    "gain_params",
    "lowpass_alpha",
    "measurement_filter",
    "scale_of",
    "scaled",
]

#: the axes and each one's body rate (:mod:`mavsid.axes`)
AXIS_RATE = RATE_OF
_AP3_SCALE = ardupilot.RATE_CDEG_SCALE


def lowpass_alpha(cutoff_hz: float, dt: float) -> float:
    """First-order low-pass gain per step (1 = no filtering)."""
    if cutoff_hz <= 0:
        return 1.0
    rc = 1.0 / (2 * np.pi * cutoff_hz)
    return dt / (dt + rc)


@dataclass(frozen=True)
class RateGains:
    """One axis of ArduPilot's ``ATC_RAT_<AX>_*`` (P, I, D per rad/s to a normalised output;
    ``imax`` normalised; filters in Hz, 0 = off; ``smax`` the P+D slew limit, 0 = off;
    ``d_ff`` the target's derivative as feed-forward; ``pd_max`` the limit of ``|P + D|``,
    ``PDMX``, 0 = off)."""

    p: float
    i: float
    d: float
    ff: float
    imax: float
    fltt: float
    fltd: float
    flte: float
    smax: float = 0.0
    d_ff: float = 0.0
    pd_max: float = 0.0


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
        self.a_t = lowpass_alpha(gains.fltt, dt)
        self.a_e = lowpass_alpha(gains.flte, dt)
        self.a_d = lowpass_alpha(gains.fltd, dt)
        self.a_s = lowpass_alpha(_SLEW_FILTER_HZ, dt)
        self.target = 0.0
        self.error = 0.0
        self.deriv = 0.0
        self.integ = 0.0
        self.slew = 0.0
        self.pd_last = 0.0
        self.target_rate = 0.0
        #: the last :meth:`update`'s P, I, D, FF and D_FF terms
        self.terms = (0.0, 0.0, 0.0, 0.0, 0.0)
        self.reset = True

    def update(self, target: float, measured: float, saturation: int = 0) -> float:
        """One step: target and measured rate (rad/s) -> normalised output. ``saturation``:
        the sign of the output's clip in the previous loop (the motors' limit on this axis;
        0 none): ``AC_PID``'s integrator then may only shrink (its limit flag has no
        direction)."""
        g = self.g
        if self.reset:
            self.target = target
            self.error = target - measured
            self.deriv = self.target_rate = 0.0
            self.reset = False
        else:
            target_prev = self.target
            self.target += self.a_t * (target - self.target)
            self.target_rate = (self.target - target_prev) / self.dt
            err_prev = self.error
            self.error += self.a_e * ((self.target - measured) - self.error)
            self.deriv += self.a_d * ((self.error - err_prev) / self.dt - self.deriv)
        if not saturation or self.integ * self.error < 0:
            self.integ = min(max(self.integ + g.i * self.error * self.dt, -g.imax), g.imax)
        if g.smax > 0:
            pd = g.p * self.error + g.d * self.deriv
            self.slew += self.a_s * (abs(pd - self.pd_last) / self.dt - self.slew)
            self.pd_last = pd
            mod = max(_SLEW_MIN_MOD, min(1.0, g.smax / self.slew)) if self.slew > 0 else 1.0
        else:
            mod = 1.0
        p_out, d_out = mod * g.p * self.error, mod * g.d * self.deriv
        if g.pd_max > 0 and abs(p_out + d_out) > g.pd_max:
            scale = g.pd_max / abs(p_out + d_out)
            p_out, d_out = p_out * scale, d_out * scale
        self.terms = (p_out, self.integ, d_out, g.ff * self.target, g.d_ff * self.target_rate)
        return sum(self.terms)

    def run(self, target: np.ndarray, measured: np.ndarray) -> np.ndarray | None:
        """The outputs of :meth:`update` over whole sequences from a fresh controller (after
        :meth:`preset`), without feedback: its filters are first-order recursions
        (``scipy.signal.lfilter``) and the integrator a running sum. None when the slew
        limiter is on or the integrator would reach ``±IMAX`` (callers then step)."""
        terms = self.run_terms(target, measured)
        return None if terms is None else (terms[:, 0] + terms[:, 1] + terms[:, 2] + terms[:, 3]
                                          + terms[:, 4])

    def run_terms(self, target: np.ndarray, measured: np.ndarray) -> np.ndarray | None:
        """As :meth:`run`, the P, I, D, FF and D_FF terms apart: shape ``(n, 5)`` (None
        also with ``PDMX``)."""
        g = self.g
        tg, ym = np.asarray(target, dtype=float), np.asarray(measured, dtype=float)
        n = tg.size
        if not self.reset or g.smax > 0 or g.pd_max > 0 or n == 0 or ym.size != n:
            return None

        def low(x: np.ndarray, a: float, x0: float) -> np.ndarray:
            """``y[0] = x0``, then ``y[k] = y[k-1] + a (x[k] - y[k-1])``."""
            y = np.empty(n)
            y[0] = x0
            if n > 1:
                y[1:] = lfilter([a], [1.0, a - 1.0], x[1:], zi=[(1.0 - a) * x0])
            return y

        tf = low(tg, self.a_t, float(tg[0]))
        err = low(tf - ym, self.a_e, float(tg[0] - ym[0]))
        rate = np.zeros(n)
        rate[1:] = np.diff(err) / self.dt
        deriv = low(rate, self.a_d, 0.0)
        integ = np.cumsum(np.concatenate([[self.integ], g.i * err * self.dt]))[1:]
        if np.any(np.abs(integ) > g.imax):
            return None
        t_rate = np.zeros(n)
        t_rate[1:] = np.diff(tf) / self.dt
        return np.column_stack([g.p * err, integ, g.d * deriv, g.ff * tf, g.d_ff * t_rate])

    def preset(self, target: float, measured: float, output: float) -> None:
        """Before the first :meth:`update`: set the integrator so that the first output of
        ``update(target, measured)`` is ``output`` (within ``±IMAX``). With ``I`` = 0 there
        is no integrator (``AC_PID`` zeroes it): nothing is set."""
        g = self.g
        if g.i == 0:
            self.integ = 0.0
            return
        err = target - measured
        i0 = output - g.p * err - g.ff * target - g.i * err * self.dt
        self.integ = min(max(i0, -g.imax), g.imax)

    def adjust_integrator(self, delta: float) -> None:
        """Add ``delta`` to the integrator (within ``±IMAX``; none with ``I`` = 0)."""
        if self.g.i == 0:
            return
        self.integ = min(max(self.integ + delta, -self.g.imax), self.g.imax)


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
        self.accel_filter = Lowpass2p(cut, fs, 1)
        self.integ = 0.0
        self.last = 0.0
        #: the last :meth:`update`'s P, I, D, FF and (none) D_FF terms
        self.terms = (0.0, 0.0, 0.0, 0.0, 0.0)
        self.reset = True

    def update(self, target: float, measured: float, saturation: int = 0) -> float:
        """One step: target and measured rate (rad/s) -> normalised torque. ``saturation``:
        the sign of the output's clip in the previous loop (0 none): PX4 integrates no
        error that would push further that way (the control allocator's saturation
        flags)."""
        g = self.g
        if self.reset:
            self.last = measured
            self.reset = False
        accel = float(self.accel_filter.advance((measured - self.last) / self.dt))
        self.last = measured
        err = target - measured
        self.terms = (g.k * g.p * err, self.integ, -g.k * g.d * accel, g.ff * target, 0.0)
        out = g.k * g.p * err + self.integ - g.k * g.d * accel + g.ff * target
        e_i = min(err, 0.0) if saturation > 0 else max(err, 0.0) if saturation < 0 else err
        factor = max(0.0, 1.0 - (e_i / _PX4_I_ERR) ** 2)
        i_new = self.integ + factor * g.k * g.i * e_i * self.dt
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

    def update(self, target: float, measured: float, saturation: int = 0) -> float: ...

    def preset(self, target: float, measured: float, output: float) -> None: ...

    def adjust_integrator(self, delta: float) -> None: ...


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
    kind = autopilot or ("px4" if px4.has_rate_params(params) else "ardupilot")
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
        pre = px4.rate_prefix(axis)
        p, i, d, ff, k, lim = _PX4_DEFAULTS[axis]
        gains: RateGains | PX4RateGains = PX4RateGains(
            get(pre + "P", p), get(pre + "I", i), get(pre + "D", d), get(pre + "FF", ff),
            get(pre + "K", k), get(px4.int_lim_param(axis), lim),
            get("IMU_DGYRO_CUTOFF", _PX4_DGYRO_CUTOFF_HZ),
        )
        old = "IMU_GYRO_RATEMAX" not in params and "IMU_GYRO_CUTOFF" not in params
        loop = get_rate("IMU_GYRO_RATEMAX", _PX4_OLD_LOOP_HZ if old else _PX4_LOOP_HZ)
        gyro = get("IMU_GYRO_CUTOFF", _PX4_GYRO_CUTOFF_HZ)
        notch = float(params.get("IMU_GYRO_NF0_FRQ", params.get("IMU_GYRO_NF_FREQ", 0.0)) or 0)
        ang = _angle_p(params, px4.angle_p_param(axis), _PX4_ANGLE_P[axis], used)
        return AxisController("px4", axis, gains, loop or _PX4_LOOP_HZ, gyro, notch, used,
                              tuple(defaults), "MC", ang)
    # an ArduPlane QuadPlane's VTOL controller is the same AC_AttitudeControl, its
    # parameters named Q_A_* (Q_A_RAT_RLL_P ...)
    family = ardupilot.rate_naming(params, axis)
    quadplane, legacy = family == "Q_A_RAT", family == "RATE"
    if legacy:
        p, i, d, imax, filt = _AP3_DEFAULTS[axis]
        pre = ardupilot.rate_prefix(axis, "RATE")
        filt_name = pre + "FILT_HZ" if pre + "FILT_HZ" in params else pre + "FILT"
        f = get(filt_name, filt)
        gains = RateGains(
            round(get(pre + "P", p) * _AP3_SCALE, 9), round(get(pre + "I", i) * _AP3_SCALE, 9),
            round(get(pre + "D", d) * _AP3_SCALE, 9), 0.0,
            round(get(pre + "IMAX", imax) / 4500.0, 9), 0.0, f, f,
        )
        naming = "RATE"
    else:
        pre = ardupilot.rate_prefix(axis, family)
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
        extra = {}
        for n, attr in (("D_FF", "d_ff"), ("PDMX", "pd_max")):
            # (4.2+ and 4.5+: a log without them flew without them, not at a default)
            v = params.get(pre + n)
            if v is not None and math.isfinite(float(v)) and float(v) > 0:
                extra[attr] = used[pre + n] = float(v)
        gains = RateGains(vals["P"], vals["I"], vals["D"], vals["FF"], vals["IMAX"],
                          vals["FLTT"], vals["FLTD"], vals["FLTE"], vals["SMAX"], **extra)
    loop = get_rate("SCHED_LOOP_RATE", _AP_LOOP_HZ)
    gyro = get("INS_GYRO_FILTER", _AP_GYRO_FILTER_HZ)
    notch = 0.0
    if params.get("INS_HNTCH_ENABLE", 0):
        notch = float(params.get("INS_HNTCH_FREQ", 0.0) or 0.0)
    elif params.get("INS_NOTCH_ENABLE", 0):
        notch = float(params.get("INS_NOTCH_FREQ", 0.0) or 0.0)
    ang = _angle_p(params, ardupilot.angle_p_param(axis, family), 4.5, used)
    return AxisController("ardupilot", axis, gains, loop, gyro, notch, used, tuple(defaults),
                          naming, ang)


def gain_params(ctrl: AxisController) -> dict[str, float]:
    """The controller's P, I, D in the vehicle's own parameter names and units."""
    g = ctrl.gains
    if ctrl.autopilot == "px4":
        pre = px4.rate_prefix(ctrl.axis)
        k = g.k if isinstance(g, PX4RateGains) else 1.0
        return {pre + "P": g.p, pre + "I": g.i, pre + "D": g.d, pre + "K": k}
    pre = ardupilot.rate_prefix(ctrl.axis, ctrl.naming)
    scale = _AP3_SCALE if ctrl.naming == "RATE" else 1.0
    return {pre + n: round(v / scale, 6) for n, v in (("P", g.p), ("I", g.i), ("D", g.d))}


def scaled(ctrl: AxisController, k: float) -> AxisController:
    g = ctrl.gains
    if isinstance(g, PX4RateGains):
        return replace(ctrl, gains=replace(g, p=g.p * k, i=g.i * k, d=g.d * k))
    return replace(ctrl, gains=replace(g, p=g.p * k, i=g.i * k, d=g.d * k))


def scale_of(gains: Mapping[str, float], ctrl: AxisController) -> float:
    """The P/I/D scale :func:`suggest_gains` applied (from its P)."""
    new_p = next(v for k, v in gains.items() if k.endswith("_P"))
    old_p = ctrl.gains.p if ctrl.naming != "RATE" else ctrl.gains.p / _AP3_SCALE
    return float(new_p / old_p) if old_p else 1.0


def autopilot_of(flight: FlightData) -> str | None:
    """``"px4"`` or ``"ardupilot"`` from the flight's platform, None when unknown."""
    ap = (flight.autopilot or "").lower()
    if "px4" in ap:
        return "px4"
    if "ardupilot" in ap or "apm" in ap:
        return "ardupilot"
    if flight.source.format == "ulog":
        return "px4"
    return None


def measurement_filter(meas_delay: float) -> tuple[float, list[float], list[float]]:
    """A measurement delay of ``meas_delay`` loops, held to 0-1: ``τ`` and the rate the
    controller reads as a filter of the plant's output, ``(1 − τ) + τz⁻¹`` (numerator and
    denominator in descending powers of z).

    Examples
    --------
    >>> measurement_filter(0.2)
    (0.2, [0.8, 0.2], [1.0, 0.0])
    """
    tau = min(max(float(meas_delay), 0.0), 1.0)
    return tau, [1.0 - tau, tau], [1.0, 0.0]
