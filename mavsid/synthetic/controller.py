"""An ArduPilot-like multicopter attitude controller at loop rate, and the motor mixers.

Per axis, each loop:

1. angle target: the pilot's desired angle (or, for yaw, the integral of the desired rate) is
   approached with a first-order time constant ``ATC_INPUT_TC``; its rate of change is the
   body-rate feed-forward (``ATC_RATE_FF_ENAB``);
2. angle P: ``rate_target = ATC_ANG_*_P * (angle_target - angle) + feed-forward``;
3. rate PID: ArduPilot's ``AC_PID`` as :class:`mavsid.loop.RatePID` implements it (the one
   the closed-loop twin and the loop analysis use): target low-passed at ``FLTT``, error =
   target - measured (filtered gyro) low-passed at ``FLTE`` (0 = off), derivative of the
   filtered error low-passed at ``FLTD``; ``out = P*err + I + D*derr + FF*target``,
   ``|I| <= IMAX``;
4. the mixer input ``u = out + mixer injection`` is limited to [-1, 1] (RATE.ROut/POut/YOut).

Small-angle approximation: Euler-angle errors and rates are used as body-frame ones.

Examples
--------
>>> c = ControllerParams()
>>> c.params()["ATC_RAT_RLL_P"]
0.135
>>> pid = RatePID(c.rate_gains("roll"), dt=0.0025)
>>> round(pid.update(target=1.0, measured=0.0), 4)   # P*err + I*err*dt on the first sample
0.1353
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from mavsid.errors import ConfigError
from mavsid.loop.controllers import RateGains, RatePID

__all__ = [
    "FRAMES",
    "QUAD_X",
    "AttitudeController",
    "ControlStep",
    "ControllerParams",
    "RateGains",
    "RatePID",
    "motor_outputs",
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


@dataclass(frozen=True)
class ControllerParams:
    """Attitude-controller parameters with ArduPilot's meanings (defaults: ArduCopter-like).

    Rate gains act on rad/s and produce a normalised output; angle P is in 1/s.
    """

    rll_p: float = 0.135
    rll_i: float = 0.135
    rll_d: float = 0.0036
    rll_ff: float = 0.0
    rll_imax: float = 0.5
    rll_fltt: float = 20.0
    rll_fltd: float = 20.0
    rll_flte: float = 0.0
    pit_p: float = 0.135
    pit_i: float = 0.135
    pit_d: float = 0.0036
    pit_ff: float = 0.0
    pit_imax: float = 0.5
    pit_fltt: float = 20.0
    pit_fltd: float = 20.0
    pit_flte: float = 0.0
    yaw_p: float = 0.18
    yaw_i: float = 0.018
    yaw_d: float = 0.0
    yaw_ff: float = 0.0
    yaw_imax: float = 0.5
    yaw_fltt: float = 20.0
    yaw_fltd: float = 0.0
    yaw_flte: float = 2.5
    ang_rll_p: float = 4.5
    ang_pit_p: float = 4.5
    ang_yaw_p: float = 4.5
    input_tc: float = 0.15
    rate_ff_enab: bool = True
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

    def rate_gains(self, axis: str) -> RateGains:
        """The rate-PID gains of ``axis`` (``"roll"``, ``"pitch"``, ``"yaw"``)."""
        k = {"roll": "rll", "pitch": "pit", "yaw": "yaw"}[axis]
        g = {f: getattr(self, f"{k}_{f}") for f in ("p", "i", "d", "ff", "imax", "fltt",
                                                     "fltd", "flte")}
        return RateGains(**g)

    def angle_p(self, axis: str) -> float:
        """``ATC_ANG_<AX>_P`` (1/s)."""
        return float(getattr(self, f"ang_{ {'roll': 'rll', 'pitch': 'pit', 'yaw': 'yaw'}[axis]}_p"))

    def params(self) -> dict[str, float]:
        """ArduPilot parameter names and values."""
        out: dict[str, float] = {}
        for axis, pre in _PREFIX.items():
            g = self.rate_gains(axis)
            for f, name in (("p", "P"), ("i", "I"), ("d", "D"), ("ff", "FF"), ("imax", "IMAX"),
                            ("fltt", "FLTT"), ("fltd", "FLTD"), ("flte", "FLTE")):
                out[f"ATC_RAT_{pre}_{name}"] = float(getattr(g, f))
            out[f"ATC_ANG_{pre}_P"] = self.angle_p(axis)
        out["ATC_INPUT_TC"] = self.input_tc
        out["ATC_RATE_FF_ENAB"] = float(self.rate_ff_enab)
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


class AttitudeController:
    """Angle loop (input shaping, angle P, feed-forward) and the three rate PIDs.

    Examples
    --------
    >>> c = AttitudeController(ControllerParams())
    >>> step = c.update(np.array([0.1, 0.0, 0.0]), np.zeros(3), np.zeros(3))
    >>> [round(float(v), 4) for v in step.rate_target]   # ANG_P * err + shaped-target rate
    [0.6631, 0.0, 0.0]
    """

    def __init__(self, params: ControllerParams) -> None:
        self.params = params
        self.dt = 1.0 / params.loop_hz
        self.pids = [RatePID(params.rate_gains(ax), self.dt) for ax in _PREFIX]
        self.ang_p = np.array([params.angle_p(ax) for ax in _PREFIX])
        self.a_in = self.dt / (self.dt + params.input_tc)
        self.att_target = np.zeros(3)
        self.yaw_rate_target = 0.0

    def update(
        self,
        desired: np.ndarray,
        attitude: np.ndarray,
        gyro: np.ndarray,
        rate_injection: np.ndarray | None = None,
        feedforward: bool = True,
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
        """
        dt, a_in = self.dt, self.a_in
        ff = np.zeros(3)
        ff[:2] = (desired[:2] - self.att_target[:2]) * a_in / dt
        self.att_target[:2] += ff[:2] * dt
        self.yaw_rate_target += (desired[2] - self.yaw_rate_target) * a_in
        ff[2] = self.yaw_rate_target
        self.att_target[2] += self.yaw_rate_target * dt
        err = self.att_target - attitude
        err[2] = (err[2] + np.pi) % (2 * np.pi) - np.pi
        rate_target = self.ang_p * err + (ff if feedforward and self.params.rate_ff_enab else 0.0)
        if rate_injection is not None:
            rate_target = rate_target + rate_injection
        out = np.array([self.pids[j].update(float(rate_target[j]), float(gyro[j]))
                        for j in range(3)])
        return ControlStep(self.att_target.copy(), rate_target, out)


@dataclass(frozen=True)
class ControlStep:
    """What :meth:`AttitudeController.update` computed in one loop."""

    att_target: np.ndarray
    rate_target: np.ndarray
    pid_out: np.ndarray


def motor_outputs(throttle: np.ndarray, u: np.ndarray, factors: np.ndarray = QUAD_X
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Motor mixing: motor thrust demands (0-1) and the axis inputs they really realise.

    Parameters
    ----------
    throttle : numpy.ndarray, shape (n,)
        Collective throttle (0-1).
    u : numpy.ndarray, shape (n, 3)
        Roll, pitch, yaw mixer inputs.
    factors : numpy.ndarray, shape (motors, 3)
        The frame's roll, pitch and yaw factor of each motor (:data:`FRAMES`); quad-X.

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
    inverse = np.linalg.inv(mix) if mix.shape[0] == 4 else np.linalg.pinv(mix)
    realised = motors @ inverse.T
    return motors, realised[:, 1:]
