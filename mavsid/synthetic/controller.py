"""The simulator's own attitude and rate controllers, written from the autopilots' documented
behaviour, and the motor mixers.

This module is independent of the closed-loop twin's rebuild of the controller
(:mod:`mavsid.loop`): the simulator flies these classes, the twin rebuilds its own from the
log's parameters, and ``tests/test_synthetic_controller.py`` compares the two on the same
inputs, so a mistake in either shows.

ArduPilot (ArduCopter 4.x ``AC_AttitudeControl`` + ``AC_PID``), per axis and loop:

1. **input shaping** (``ATC_RATE_FF_ENAB`` 1): the attitude target first advances by the
   previous target rate; the new target rate moves it towards the desired angle with the
   square-root controller of gain ``1 / ATC_INPUT_TC`` and the acceleration limit
   ``ATC_ACCEL_{R,P}_MAX`` (0 = none), the change of rate per loop limited by that
   acceleration; yaw slews the target rate towards the pilot's rate with ``PILOT_Y_RATE_TC``
   and ``ATC_ACCEL_Y_MAX``; ``ATC_RATE_{R,P,Y}_MAX`` limit the rates (0 = none). With the
   feed-forward off (``ATC_RATE_FF_ENAB`` 0, SYSTEMID's recovery axes) the target *is* the
   desired angle and the target rate is zero;
2. **angle P**: ``ATC_ANG_*_P`` times the attitude error, through the square-root controller
   with half the axis's acceleration limit (clamped to 40-720 deg/s², yaw 10-120 deg/s²)
   when that limit is set; the target rate is added as feed-forward, then any SYSTEMID rate
   injection;
3. **rate PID** (:class:`ArduPilotPID`, ``AC_PID::update_all``): the target low-passed at
   ``FLTT``, the error ``target - gyro`` at ``FLTE``, the derivative of the filtered error at
   ``FLTD``; the integrator adds ``I * error * dt`` within ``±IMAX`` and, while the motors
   saturate (``limit``), only when that shrinks it; ``P`` and ``D`` are scaled by the slew
   limiter's modifier (``SMAX``, :class:`SlewLimiter`) computed from the previous loop's
   ``P + D``, and their sum limited to ``PDMX``; the output is ``P + I + D``, the
   feed-forward ``FF * target + D_FF * d(target)/dt`` goes to the mixer beside it;
4. the mixer input ``u = PID + FF + SYSTEMID mixer injection``, limited to [-1, 1]
   (RATE.ROut/POut/YOut).

PX4 (``RateControl::update`` of ``mc_rate_control``, :class:`PX4RatePID`): ``K * P * error
+ integral - K * D * d(rate)/dt + FF * target``, the derivative taken of the measured rate
and low-passed (``IMU_DGYRO_CUTOFF``, second order); the integrator, updated after the
output, adds ``(1 - (error / 400 deg/s)²) K I error dt`` (never negative), within
``±INT_LIM``, and not in a saturated direction.

Small-angle approximation: Euler-angle errors and rates are used as body-frame ones.

Examples
--------
>>> c = ControllerParams()
>>> c.params()["ATC_RAT_RLL_P"]
0.135
>>> pid = ArduPilotPID(c.rate_gains("roll"), dt=0.0025)
>>> round(pid.update(target=1.0, measured=0.0), 4)   # P*err + I*err*dt on the first sample
0.1353
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from mavsid.errors import ConfigError
from mavsid.numerics.filters import Lowpass2p

__all__ = [
    "FRAMES",
    "PID_LOG_FIELDS",
    "QUAD_X",
    "ArduPilotPID",
    "AttitudeController",
    "ControlStep",
    "ControllerParams",
    "PIDGains",
    "PX4Gains",
    "PX4RatePID",
    "SlewLimiter",
    "lowpass_alpha",
    "motor_outputs",
    "shape_angle",
    "shape_rate",
    "sqrt_controller",
]

_PREFIX = {"roll": "RLL", "pitch": "PIT", "yaw": "YAW"}

#: quad-X motor factors (rows: motors 1-4; columns: roll, pitch, yaw), ArduPilot numbering:
#: 1 front-right (CCW), 2 rear-left (CCW), 3 front-left (CW), 4 rear-right (CW)
QUAD_X = np.array(
    [
        [-0.5, 0.5, 0.5],
        [0.5, -0.5, 0.5],
        [0.5, 0.5, -0.5],
        [-0.5, -0.5, -0.5],
    ]
)

_H = 0.5  # (ArduPilot scales each axis's factors so the largest is 0.5)

#: multirotor frames the simulator flies: name -> ((FRAME_CLASS, FRAME_TYPE), motor factors,
#: rows motors 1..n, columns roll, pitch, yaw), written out from ArduPilot's AP_MotorsMatrix
#: tables, each axis scaled to 0.5 (normalise_rpy_factors)
FRAMES: dict[str, tuple[tuple[int, int], np.ndarray]] = {
    "quad-x": ((1, 1), QUAD_X),
    # motors at 90 CW, -90 CCW, -30 CW, 150 CCW, 30 CCW, -150 CW from the nose
    "hexa-x": ((2, 1), np.array([[-_H, 0, -_H], [_H, 0, _H], [_H / 2, _H, -_H],
                                 [-_H / 2, -_H, _H], [-_H / 2, _H, _H], [_H / 2, -_H, -_H]])),
    # coaxial arms left-front, rear, right-front; top propellers CW, bottom CCW
    "y6b": ((5, 10), np.array([[-_H, _H / 2, -_H], [-_H, _H / 2, _H], [0, -_H, -_H],
                               [0, -_H, _H], [_H, _H / 2, -_H], [_H, _H / 2, _H]])),
    # coaxial X8: 45 CCW, -45 CW, -135 CCW, 135 CW, -45 CCW, 45 CW, 135 CCW, -135 CW
    "octaquad-x": ((4, 1), np.array([[-_H, _H, _H], [_H, _H, -_H], [_H, -_H, _H],
                                     [-_H, -_H, -_H], [_H, _H, _H], [-_H, _H, -_H],
                                     [-_H, -_H, _H], [_H, -_H, -_H]])),
}

# --------------------------------------------------------------------------- shaping helpers


def lowpass_alpha(cutoff_hz: float, dt: float) -> float:
    """Gain per step of ArduPilot's first-order low-pass (``calc_lowpass_alpha_dt``):
    ``dt / (dt + 1 / (2π f))``; 1 (no filtering) for a cut-off or step that is not positive.

    >>> lowpass_alpha(0.0, 0.0025), round(lowpass_alpha(20.0, 0.0025), 6)
    (1.0, 0.239057)
    """
    if cutoff_hz <= 0 or dt <= 0:
        return 1.0
    return dt / (dt + 1.0 / (2.0 * math.pi * cutoff_hz))


def sqrt_controller(error: float, p: float, second_order_limit: float, dt: float) -> float:
    """ArduPilot's square-root controller: ``p * error`` near zero, ``sqrt(2 a (|e| - a / 2p²))``
    beyond the linear distance ``a / p²`` (``a`` the second-order limit, 0 = linear
    throughout), never more than ``|error| / dt`` (no overshoot within one step).

    >>> sqrt_controller(0.1, 4.5, 0.0, 0.0025), round(sqrt_controller(1.0, 4.5, 9.6, 0.0025), 4)
    (0.45, 3.8274)
    """
    if second_order_limit <= 0:
        rate = error * p
    elif p == 0:
        rate = math.copysign(math.sqrt(2.0 * second_order_limit * abs(error)), error)
    else:
        linear = second_order_limit / (p * p)
        if abs(error) > linear:
            rate = math.copysign(
                math.sqrt(2.0 * second_order_limit * (abs(error) - 0.5 * linear)), error)
        else:
            rate = error * p
    if dt > 0:
        bound = abs(error) / dt
        rate = min(max(rate, -bound), bound)
    return rate


def shape_rate(rate: float, desired: float, accel_max: float, dt: float, tc: float) -> float:
    """The next target rate slewed from ``rate`` towards ``desired``: with time constant ``tc``
    (> 0), then each step's change limited to ``accel_max * dt`` (when positive)
    (``AC_AttitudeControl::input_shaping_ang_vel``).

    >>> round(shape_rate(0.0, 1.0, 0.0, 0.0025, 0.15), 6), shape_rate(0.0, 1.0, 10.0, 0.01, 0.0)
    (0.016667, 0.1)
    """
    if tc > 0:
        desired = rate + sqrt_controller(desired - rate, 1.0 / max(tc, 0.01), 0.0, dt) * dt
    if accel_max > 0:
        step = accel_max * dt
        return min(max(desired, rate - step), rate + step)
    return desired


def shape_angle(error: float, tc: float, accel_max: float, rate: float, dt: float,
                rate_max: float = 0.0) -> float:
    """The next target rate that brings an angle error to zero with time constant ``tc`` and
    acceleration ``accel_max`` (``AC_AttitudeControl::input_shaping_angle``).

    >>> round(shape_angle(0.1, 0.15, 0.0, 0.0, 0.0025), 6)   # error / tc
    0.666667
    >>> round(shape_angle(0.1, 0.15, 19.2, 0.0, 0.0025), 6)  # one step of 19.2 rad/s²
    0.048
    """
    desired = sqrt_controller(error, 1.0 / max(tc, 0.01), accel_max, dt)
    if rate_max > 0:
        desired = min(max(desired, -rate_max), rate_max)
    return shape_rate(rate, desired, accel_max, dt, 0.0)


# --------------------------------------------------------------------------- ArduPilot AC_PID

#: PID records' fields (PIDR/PIDP/PIDY of ArduCopter 4.5+) in :attr:`ControlStep.terms`
PID_LOG_FIELDS = ("Tar", "Act", "Err", "P", "I", "D", "FF", "DFF", "Dmod", "SRate", "Flags")
#: PIDx.Flags bits: integrator held by the output limit, P+D limited by PDMX, filters reset
FLAG_LIMIT, FLAG_PD_LIMIT, FLAG_RESET = 1, 2, 4


@dataclass(frozen=True)
class PIDGains:
    """One axis of ArduPilot's ``ATC_RAT_<AX>_*``: P, I, D per rad/s to a normalised output,
    ``imax`` normalised, filters in Hz (0 = off), ``smax`` the P+D slew limit (0 = off),
    ``sr_tau`` its decay time constant (s), ``d_ff`` the target-derivative feed-forward,
    ``pd_max`` the P+D sum limit (PDMX, 0 = off)."""

    p: float
    i: float
    d: float
    ff: float = 0.0
    imax: float = 0.5
    fltt: float = 0.0
    flte: float = 0.0
    fltd: float = 0.0
    smax: float = 0.0
    sr_tau: float = 1.0
    d_ff: float = 0.0
    pd_max: float = 0.0


#: the slew limiter: half-cycle window (ms) of the slowest oscillation expected, the number of
#: exceedance events of each sign remembered, the modifier's gain on the excess, the cut-off
#: of the low-pass on the slew rate (Hz), the peak rate kept as a multiple of SMAX
_WINDOW_MS = 300
_N_EVENTS = 2
_MODIFIER_GAIN = 1.5
_SLEW_CUTOFF_HZ = 25.0
_PEAK_CAP = 10.0


class SlewLimiter:
    """ArduPilot's slew-rate limiter of a PID's P+D output (``SMAX``): the slew rate of the
    sample, low-passed at 25 Hz, is tracked by its positive and negative peaks (held for
    300 ms, then decaying with ``sr_tau``); while the mean of the peaks exceeds ``SMAX`` and
    the last exceedances came recently, P and D are scaled by ``SMAX / (SMAX + 1.5 excess)``.
    Time is the vehicle's clock in whole milliseconds, as the firmware's is.

    >>> s = SlewLimiter(smax=1.0, tau=1.0)   # P+D oscillating at 5 Hz, slewing at 3.1/s
    >>> mods = [s.modifier(0.1 * math.sin(2 * math.pi * 5 * k * 0.0025), 0.0025,
    ...                    10.0 + 0.0025 * k) for k in range(800)]
    >>> [round(mods[k], 3) for k in (0, 100, 200, 799)]   # 1 until two cycles exceeded SMAX
    [1.0, 1.0, 0.839, 0.255]
    """

    def __init__(self, smax: float, tau: float = 1.0) -> None:
        self.smax = smax
        self.tau = tau if tau > 0 else 1.0
        self.filtered = 0.0
        self.last_sample = 0.0
        self.max_pos = self.max_neg = 0.0
        self.max_pos_ms = self.max_neg_ms = 0
        self.pos_events = [0] * _N_EVENTS
        self.neg_events = [0] * _N_EVENTS
        self.pos_index = self.neg_index = 0
        self.pos_stored = self.neg_stored = False
        self.modifier_rate = 0.0
        self.output_rate = 0.0

    def modifier(self, sample: float, dt: float, now_s: float) -> float:
        """The P and D multiplier (0-1] after ``sample`` (the previous loop's P+D)."""
        if self.smax <= 0 or dt <= 0:
            self.output_rate = 0.0
            return 1.0
        self.filtered += lowpass_alpha(_SLEW_CUTOFF_HZ, dt) * (
            (sample - self.last_sample) / dt - self.filtered)
        self.last_sample = sample
        rate, smax = self.filtered, self.smax
        now = int(now_s * 1000.0)
        decay = min(dt, self.tau) / self.tau
        if not self.pos_stored and rate > smax:
            self.pos_index %= _N_EVENTS
            self.pos_events[self.pos_index] = now
            self.pos_index += 1
            self.pos_stored, self.neg_stored = True, False
        if not self.neg_stored and rate < -smax:
            self.neg_index %= _N_EVENTS
            self.neg_events[self.neg_index] = now
            self.neg_index += 1
            self.neg_stored, self.pos_stored = True, False
        oldest = min([now, *self.pos_events, *self.neg_events])
        if rate > self.max_pos:
            self.max_pos, self.max_pos_ms = min(rate, _PEAK_CAP * smax), now
        elif now - self.max_pos_ms > _WINDOW_MS:
            self.max_pos *= 1.0 - decay
        if rate < -self.max_neg:
            self.max_neg, self.max_neg_ms = min(-rate, _PEAK_CAP * smax), now
        elif now - self.max_neg_ms > _WINDOW_MS:
            self.max_neg *= 1.0 - decay
        raw = 0.5 * (self.max_pos + self.max_neg)
        modifier_input = raw
        late = now - oldest - (_N_EVENTS + 1) * _WINDOW_MS
        if late > 0:  # the exceedances are old: a transient, not an oscillation
            modifier_input *= math.exp(-0.001 * late / self.tau)
        attack = min(2.0 * decay, 1.0)
        self.modifier_rate = min((1 - attack) * self.modifier_rate + attack * modifier_input,
                                 modifier_input)
        self.output_rate = min((1 - attack) * self.output_rate + attack * raw, raw)
        if self.modifier_rate > smax:
            return smax / (smax + _MODIFIER_GAIN * (self.modifier_rate - smax))
        return 1.0


class ArduPilotPID:
    """ArduPilot's ``AC_PID`` as a rate controller for one axis (``update_all``).

    :meth:`update` returns P + I + D (what ``AC_PID`` returns); :attr:`feedforward` is the
    ``FF`` and ``D_FF`` terms the attitude controller passes to the mixer beside it;
    :attr:`log` the values of the axis's PID record after the step (:data:`PID_LOG_FIELDS`).

    Examples
    --------
    >>> pid = ArduPilotPID(PIDGains(0.1, 0.0, 0.0, ff=0.2), dt=0.01)
    >>> [round(pid.update(1.0, 0.5) + pid.feedforward, 3) for _ in range(2)]  # P*err + FF*target
    [0.25, 0.25]
    >>> pid = ArduPilotPID(PIDGains(1.0, 0.0, 0.0, pd_max=0.2), dt=0.01)
    >>> pid.update(1.0, 0.0), int(pid.log[PID_LOG_FIELDS.index("Flags")])  # PDMX and the reset
    (0.2, 6)
    """

    def __init__(self, gains: PIDGains, dt: float) -> None:
        self.dt = dt
        self.set_gains(gains)
        self.target = self.error = self.derivative = self.target_derivative = 0.0
        self.integrator = 0.0
        self.p_out = self.d_out = 0.0
        self.feedforward = 0.0
        self.log = np.zeros(len(PID_LOG_FIELDS))
        self.reset = True

    def set_gains(self, gains: PIDGains) -> None:
        """Use ``gains`` from the next loop on, the controller's state carried on (a
        parameter set in flight; the slew limiter starts again)."""
        self.g = gains
        self.a_t = lowpass_alpha(gains.fltt, self.dt)
        self.a_e = lowpass_alpha(gains.flte, self.dt)
        self.a_d = lowpass_alpha(gains.fltd, self.dt)
        self.slew = SlewLimiter(gains.smax, gains.sr_tau)

    def update(self, target: float, measured: float, limit: bool = False,
               now_s: float = 0.0) -> float:
        """One loop: target and measured rate (rad/s) -> P + I + D (normalised).

        ``limit``: the motors saturated on this axis in the previous loop (the integrator may
        then only shrink); ``now_s`` the vehicle's clock (s), for the slew limiter.
        """
        g, dt = self.g, self.dt
        was_reset = self.reset
        if self.reset:
            self.reset = False
            self.target = target
            self.error = target - measured
            self.derivative = self.target_derivative = 0.0
        else:
            target_last, error_last = self.target, self.error
            self.target += self.a_t * (target - self.target)
            self.error += self.a_e * ((self.target - measured) - self.error)
            self.derivative += self.a_d * ((self.error - error_last) / dt - self.derivative)
            self.target_derivative = (self.target - target_last) / dt
        if g.i != 0:
            shrinks = self.integrator * self.error < 0
            if not limit or shrinks:
                self.integrator = min(max(self.integrator + g.i * self.error * dt, -g.imax),
                                      g.imax)
        else:
            self.integrator = 0.0
        dmod = self.slew.modifier(self.p_out + self.d_out, dt, now_s)
        p_out, d_out = g.p * self.error * dmod, g.d * self.derivative * dmod
        pd_limited = g.pd_max > 0 and abs(p_out + d_out) > g.pd_max
        if pd_limited:
            scale = g.pd_max / abs(p_out + d_out)
            p_out, d_out = p_out * scale, d_out * scale
        self.p_out, self.d_out = p_out, d_out
        ff, dff = g.ff * self.target, g.d_ff * self.target_derivative
        self.feedforward = ff + dff
        flags = (FLAG_LIMIT if limit else 0) | (FLAG_PD_LIMIT if pd_limited else 0) | (
            FLAG_RESET if was_reset else 0)
        self.log = np.array([self.target, measured, self.error, p_out, self.integrator, d_out,
                             ff, dff, dmod, self.slew.output_rate, flags])
        return p_out + d_out + self.integrator


# --------------------------------------------------------------------------- PX4


@dataclass(frozen=True)
class PX4Gains:
    """One axis of PX4's ``MC_<AX>RATE_{P,I,D,FF,K}``, ``MC_<AX>R_INT_LIM`` and the
    derivative's low-pass cut-off ``IMU_DGYRO_CUTOFF`` (Hz, 0 = none)."""

    p: float
    i: float
    d: float
    ff: float = 0.0
    k: float = 1.0
    int_lim: float = 0.3
    dgyro_hz: float = 30.0


#: PX4 lowers the integration as the rate error approaches this (rad/s)
_PX4_I_REDUCTION = math.radians(400.0)


class PX4RatePID:
    """PX4's multicopter rate controller for one axis (``RateControl::update``).

    >>> pid = PX4RatePID(PX4Gains(0.2, 0.0, 0.0, ff=0.1, k=0.5), dt=0.004)
    >>> round(pid.update(1.0, 0.0), 3)   # K*P*err + FF*target
    0.2
    """

    def __init__(self, gains: PX4Gains, dt: float) -> None:
        self.g = gains
        self.dt = dt
        fs = 1.0 / dt
        cut = gains.dgyro_hz if 0 < gains.dgyro_hz < 0.5 * fs else 0.0
        self.accel_filter = Lowpass2p(cut, fs, 1)
        self.integral = 0.0
        self.last: float | None = None

    def update(self, target: float, measured: float, saturated_positive: bool = False,
               saturated_negative: bool = False) -> float:
        """One loop: rate setpoint and measured rate (rad/s) -> normalised torque."""
        g, dt = self.g, self.dt
        last = measured if self.last is None else self.last
        self.last = measured
        accel = float(self.accel_filter.advance((measured - last) / dt))
        error = target - measured
        out = g.k * g.p * error + self.integral - g.k * g.d * accel + g.ff * target
        e = min(error, 0.0) if saturated_positive else error
        e = max(e, 0.0) if saturated_negative else e
        factor = max(0.0, 1.0 - (e / _PX4_I_REDUCTION) ** 2)
        value = self.integral + factor * g.k * g.i * e * dt
        if math.isfinite(value):
            self.integral = min(max(value, -g.int_lim), g.int_lim)
        return out


# --------------------------------------------------------------------------- parameters


@dataclass(frozen=True)
class ControllerParams:
    """Attitude-controller parameters with ArduPilot's meanings (defaults: ArduCopter-like).

    Rate gains act on rad/s and produce a normalised output; angle P is in 1/s. The
    acceleration limits ``accel_*_max`` are in deg/s² (``ATC_ACCEL_*_MAX`` / 100; 0 = none,
    the simulator's default; ArduCopter's own is 1100 roll and pitch, 270 yaw), the rate
    limits ``rate_*_max`` in deg/s (0 = none); ``pilot_y_rate_tc`` is ``PILOT_Y_RATE_TC``.
    """

    rll_p: float = 0.135
    rll_i: float = 0.135
    rll_d: float = 0.0036
    rll_ff: float = 0.0
    rll_imax: float = 0.5
    rll_fltt: float = 20.0
    rll_fltd: float = 20.0
    rll_flte: float = 0.0
    rll_smax: float = 0.0
    rll_d_ff: float = 0.0
    rll_pdmx: float = 0.0
    pit_p: float = 0.135
    pit_i: float = 0.135
    pit_d: float = 0.0036
    pit_ff: float = 0.0
    pit_imax: float = 0.5
    pit_fltt: float = 20.0
    pit_fltd: float = 20.0
    pit_flte: float = 0.0
    pit_smax: float = 0.0
    pit_d_ff: float = 0.0
    pit_pdmx: float = 0.0
    yaw_p: float = 0.18
    yaw_i: float = 0.018
    yaw_d: float = 0.0
    yaw_ff: float = 0.0
    yaw_imax: float = 0.5
    yaw_fltt: float = 20.0
    yaw_fltd: float = 0.0
    yaw_flte: float = 2.5
    yaw_smax: float = 0.0
    yaw_d_ff: float = 0.0
    yaw_pdmx: float = 0.0
    ang_rll_p: float = 4.5
    ang_pit_p: float = 4.5
    ang_yaw_p: float = 4.5
    input_tc: float = 0.15
    rate_ff_enab: bool = True
    accel_r_max: float = 0.0
    accel_p_max: float = 0.0
    accel_y_max: float = 0.0
    rate_r_max: float = 0.0
    rate_p_max: float = 0.0
    rate_y_max: float = 0.0
    pilot_y_rate_tc: float = 0.15
    angle_max_deg: float = 30.0
    pilot_yaw_rate_degs: float = 202.5
    loop_hz: float = 400.0
    spin_min: float = 0.15
    spin_max: float = 0.95
    pwm_min: float = 1000.0
    pwm_max: float = 2000.0
    thst_expo: float = 0.65

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if not np.isfinite(float(value)) or float(value) < 0:
                raise ConfigError(f"controller parameter {name} must be finite and >= 0")
        if self.loop_hz <= 0 or self.input_tc <= 0:
            raise ConfigError("loop_hz and input_tc must be positive")

    def rate_gains(self, axis: str) -> PIDGains:
        """The rate-PID gains of ``axis`` (``"roll"``, ``"pitch"``, ``"yaw"``)."""
        k = {"roll": "rll", "pitch": "pit", "yaw": "yaw"}[axis]

        def v(f: str) -> float:
            return float(getattr(self, f"{k}_{f}"))

        return PIDGains(p=v("p"), i=v("i"), d=v("d"), ff=v("ff"), imax=v("imax"),
                        fltt=v("fltt"), flte=v("flte"), fltd=v("fltd"), smax=v("smax"),
                        d_ff=v("d_ff"), pd_max=v("pdmx"))

    def angle_p(self, axis: str) -> float:
        """``ATC_ANG_<AX>_P`` (1/s)."""
        return float(getattr(self, f"ang_{ {'roll': 'rll', 'pitch': 'pit', 'yaw': 'yaw'}[axis]}_p"))

    def accel_limits(self) -> np.ndarray:
        """Roll, pitch, yaw acceleration limits (rad/s², 0 = none)."""
        return np.radians([self.accel_r_max, self.accel_p_max, self.accel_y_max])

    def rate_limits(self) -> np.ndarray:
        """Roll, pitch, yaw rate limits (rad/s, 0 = none)."""
        return np.radians([self.rate_r_max, self.rate_p_max, self.rate_y_max])

    def params(self, full: bool = False) -> dict[str, float]:
        """ArduPilot parameter names and values.

        The rate PIDs' ``SMAX``, ``D_FF`` and ``PDMX``, the acceleration and rate limits and
        ``PILOT_Y_RATE_TC`` are listed when ``full`` (ArduCopter 4.5+ lists them all) or any
        of them is set (the default vehicle's parameters stay those it always had).
        """
        out: dict[str, float] = {}
        extended = full or any(getattr(self, f"{k}_{f}") for k in ("rll", "pit", "yaw")
                       for f in ("smax", "d_ff", "pdmx")) or any(
            getattr(self, n) for n in ("accel_r_max", "accel_p_max", "accel_y_max",
                                       "rate_r_max", "rate_p_max", "rate_y_max"))
        for axis, pre in _PREFIX.items():
            g = self.rate_gains(axis)
            names = [("p", "P"), ("i", "I"), ("d", "D"), ("ff", "FF"), ("imax", "IMAX"),
                     ("fltt", "FLTT"), ("fltd", "FLTD"), ("flte", "FLTE")]
            if extended:
                names += [("smax", "SMAX"), ("d_ff", "D_FF"), ("pd_max", "PDMX")]
            for f, name in names:
                out[f"ATC_RAT_{pre}_{name}"] = float(getattr(g, f))
            out[f"ATC_ANG_{pre}_P"] = self.angle_p(axis)
        out["ATC_INPUT_TC"] = self.input_tc
        out["ATC_RATE_FF_ENAB"] = float(self.rate_ff_enab)
        if extended:
            for ax in "RPY":
                out[f"ATC_ACCEL_{ax}_MAX"] = getattr(self, f"accel_{ax.lower()}_max") * 100.0
                out[f"ATC_RATE_{ax}_MAX"] = float(getattr(self, f"rate_{ax.lower()}_max"))
            out["PILOT_Y_RATE_TC"] = self.pilot_y_rate_tc
        out["ANGLE_MAX"] = self.angle_max_deg * 100.0
        out["PILOT_Y_RATE"] = self.pilot_yaw_rate_degs
        out["SCHED_LOOP_RATE"] = self.loop_hz
        out["MOT_SPIN_MIN"], out["MOT_SPIN_MAX"] = self.spin_min, self.spin_max
        out["MOT_PWM_MIN"], out["MOT_PWM_MAX"] = self.pwm_min, self.pwm_max
        out["MOT_THST_EXPO"] = self.thst_expo
        return out

    def motor_pwm(self, motors: np.ndarray) -> np.ndarray:
        """Motor thrust demands (0-1) -> ESC pulse widths (µs, whole), as ArduPilot's motor
        library outputs them: the thrust curve inverted (``MOT_THST_EXPO`` e: the actuator
        ``a`` with ``(1 - e) a + e a² = thrust``), then ``MOT_SPIN_*`` and ``MOT_PWM_*``.

        >>> c = ControllerParams()
        >>> c.motor_pwm(np.array([0.0, 1.0])).tolist()
        [1150.0, 1950.0]
        >>> a = (c.motor_pwm(np.array([0.5])) - 1150.0) / 800.0   # half the thrust
        >>> bool(abs((1 - 0.65) * a[0] + 0.65 * a[0] ** 2 - 0.5) < 0.002)
        True
        """
        thrust = np.clip(np.asarray(motors, dtype=float), 0.0, 1.0)
        e = self.thst_expo
        actuator = thrust if e <= 0 else (
            ((e - 1.0) + np.sqrt((1.0 - e) ** 2 + 4.0 * e * thrust)) / (2.0 * e))
        spin = self.spin_min + (self.spin_max - self.spin_min) * actuator
        return np.round(self.pwm_min + (self.pwm_max - self.pwm_min) * spin)


# --------------------------------------------------------------------------- attitude loop

#: the angle P's square-root controller: half the axis's acceleration limit, clamped (rad/s²)
_ANGLE_ACCEL_RANGE = ((math.radians(40.0), math.radians(720.0)),) * 2 + (
    (math.radians(10.0), math.radians(120.0)),)


def _limit_rates(rate: np.ndarray, limits: np.ndarray) -> np.ndarray:
    """``ang_vel_limit``: roll and pitch within an ellipse when both limits are set (each alone
    otherwise), yaw on its own (0 = no limit)."""
    out = rate.copy()
    lr, lp, ly = limits
    if lr > 0 and lp > 0:
        norm = math.hypot(out[0] / lr, out[1] / lp)
        if norm > 1:
            out[:2] /= norm
    else:
        for j, lim in ((0, lr), (1, lp)):
            if lim > 0:
                out[j] = min(max(out[j], -lim), lim)
    if ly > 0:
        out[2] = min(max(out[2], -ly), ly)
    return out


class AttitudeController:
    """Input shaping, angle P with feed-forward, and the three rate PIDs (ArduPilot).

    Examples
    --------
    >>> c = AttitudeController(ControllerParams())
    >>> step = c.update(np.array([0.1, 0.0, 0.0]), np.zeros(3), np.zeros(3))
    >>> [round(float(v), 4) for v in step.rate_target]   # the shaped target's rate: err / TC
    [0.6667, 0.0, 0.0]
    """

    def __init__(self, params: ControllerParams) -> None:
        self.dt = 1.0 / params.loop_hz
        self.pids = [ArduPilotPID(params.rate_gains(ax), self.dt) for ax in _PREFIX]
        self.set_params(params)
        self.att_target = np.zeros(3)
        self.rate_ff = np.zeros(3)  # the target's rate (feed-forward), rad/s

    def set_params(self, params: ControllerParams) -> None:
        """Use ``params`` from the next loop on (parameters set in flight): the gains,
        filters and limits change, the targets and the PIDs' state carry on.

        Raises
        ------
        ConfigError
            ``params`` runs at another loop rate.
        """
        if round(1.0 / params.loop_hz, 12) != round(self.dt, 12):
            raise ConfigError(f"the loop rate cannot change in flight ({params.loop_hz:g} Hz "
                              f"for {1.0 / self.dt:g} Hz)")
        self.params = params
        for pid, ax in zip(self.pids, _PREFIX, strict=True):
            pid.set_gains(params.rate_gains(ax))
        self.ang_p = np.array([params.angle_p(ax) for ax in _PREFIX])
        self.accel = params.accel_limits()
        self.rate_max = params.rate_limits()

    def _shape(self, desired: np.ndarray, feedforward: bool) -> None:
        """Advance the attitude target and its rate towards ``desired``."""
        p, dt = self.params, self.dt
        self.att_target += self.rate_ff * dt
        if not (feedforward and p.rate_ff_enab):
            self.att_target[:2] = desired[:2]
            self.att_target[2] += desired[2] * dt
            self.rate_ff = np.zeros(3)
            return
        ff = self.rate_ff.copy()
        for j in (0, 1):
            err = (desired[j] - self.att_target[j] + math.pi) % (2 * math.pi) - math.pi
            ff[j] = shape_angle(err, p.input_tc, float(self.accel[j]), float(ff[j]), dt)
        ff[2] = shape_rate(float(ff[2]), float(desired[2]), float(self.accel[2]), dt,
                           p.pilot_y_rate_tc)
        self.rate_ff = _limit_rates(ff, self.rate_max)

    def update(
        self,
        desired: np.ndarray,
        attitude: np.ndarray,
        gyro: np.ndarray,
        rate_injection: np.ndarray | None = None,
        feedforward: bool = True,
        limit: np.ndarray | None = None,
        now_s: float = 0.0,
    ) -> ControlStep:
        """One loop.

        Parameters
        ----------
        desired : (3,) desired roll, pitch angle (rad) and yaw rate (rad/s).
        attitude : (3,) estimated roll, pitch, yaw (rad).
        gyro : (3,) filtered body rates (rad/s).
        rate_injection : (3,), optional
            Added to the rate targets (rad/s): SYSTEMID rate axes.
        feedforward : bool
            Body-rate feed-forward of the shaped target (off in SYSTEMID recovery axes).
        limit : (3,) of bool, optional
            The motors saturated on each axis in the previous loop.
        now_s : float
            The vehicle's clock (s).
        """
        self._shape(desired, feedforward)
        err = self.att_target - attitude
        err[2] = (err[2] + np.pi) % (2 * np.pi) - np.pi
        correction = np.empty(3)
        for j in range(3):
            a = float(self.accel[j])
            lo, hi = _ANGLE_ACCEL_RANGE[j]
            correction[j] = (sqrt_controller(float(err[j]), float(self.ang_p[j]),
                                             min(max(a / 2.0, lo), hi), self.dt)
                             if a > 0 else float(self.ang_p[j] * err[j]))
        rate_target = _limit_rates(correction, self.rate_max) + self.rate_ff
        if rate_injection is not None:
            rate_target = rate_target + rate_injection
        sat = np.zeros(3, dtype=bool) if limit is None else limit
        out = np.empty(3)
        terms = np.empty((3, len(PID_LOG_FIELDS)))
        for j in range(3):
            pid = self.pids[j]
            out[j] = pid.update(float(rate_target[j]), float(gyro[j]), bool(sat[j]),
                                now_s) + pid.feedforward
            terms[j] = pid.log
        return ControlStep(self.att_target.copy(), rate_target, out, terms)


@dataclass(frozen=True)
class ControlStep:
    """What :meth:`AttitudeController.update` computed in one loop: the attitude target, the
    rate targets, the rate controllers' outputs (PID + feed-forward) and, per axis, the
    values of its PID record (:data:`PID_LOG_FIELDS`)."""

    att_target: np.ndarray
    rate_target: np.ndarray
    pid_out: np.ndarray
    terms: np.ndarray


def motor_outputs(throttle: np.ndarray, u: np.ndarray, factors: np.ndarray = QUAD_X,
                  failed: tuple[int, ...] = ()) -> tuple[np.ndarray, np.ndarray]:
    """Motor mixing: motor thrust demands (0-1) and the axis inputs they really realise.

    Parameters
    ----------
    throttle : numpy.ndarray, shape (n,)
        Collective throttle (0-1).
    u : numpy.ndarray, shape (n, 3)
        Roll, pitch, yaw mixer inputs.
    factors : numpy.ndarray, shape (motors, 3)
        The frame's roll, pitch and yaw factor of each motor (:data:`FRAMES`); quad-X.
    failed : tuple of int
        Motors (0-based) that give no thrust whatever their demand.

    Returns
    -------
    motors : numpy.ndarray, shape (n, motors)
        Demands limited to [0, 1].
    u_eff : numpy.ndarray, shape (n, 3)
        The roll/pitch/yaw the limited motors produce (equal to ``u`` unless saturated).

    Examples
    --------
    >>> m, ue = motor_outputs(np.array([0.4]), np.array([[0.1, 0.0, 0.0]]))
    >>> m.round(3).tolist(), ue.round(6).tolist()
    ([[0.35, 0.45, 0.45, 0.35]], [[0.1, 0.0, 0.0]])
    >>> m, ue = motor_outputs(np.array([0.4]), np.array([[0.0, 0.1, 0.0]]), FRAMES["hexa-x"][1])
    >>> m.round(3).tolist(), (ue.round(6) + 0.0).tolist()
    ([[0.4, 0.4, 0.45, 0.35, 0.45, 0.35]], [[0.0, 0.1, 0.0]])
    """
    mix = np.hstack([np.ones((factors.shape[0], 1)), factors])  # motors = mix @ (thr, r, p, y)
    cmd = np.column_stack([throttle, u])
    motors = np.clip(cmd @ mix.T, 0.0, 1.0)
    if failed:
        motors[:, list(failed)] = 0.0
    inverse = np.linalg.inv(mix) if mix.shape[0] == 4 else np.linalg.pinv(mix)
    realised = motors @ inverse.T
    return motors, realised[:, 1:]
