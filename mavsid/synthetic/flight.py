"""Fly the known plant with the ArduPilot-like controller: one closed-loop simulation.

:func:`fly` turns a :class:`Scenario` into a :class:`Flight` — every signal at loop rate —
which the writers (:mod:`mavsid.synthetic.dfwriter`, :mod:`mavsid.synthetic.tlogwriter`) turn
into log files and :meth:`Flight.truth` into the ground-truth sidecar.

Examples
--------
>>> sc = Scenario(manoeuvre="doublet", axis="roll", duration_s=3.0, seed=1)
>>> fl = fly(sc)
>>> fl.t_s.shape, fl.u.shape, round(fl.dt, 4)
((1200,), (1200, 3), 0.0025)
>>> fl.truth()["axes"]["roll"]["effectiveness"]
180.0
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from mavsid.errors import ConfigError
from mavsid.synthetic.controller import (
    FRAMES,
    PID_LOG_FIELDS,
    AttitudeController,
    ControllerParams,
    motor_outputs,
)
from mavsid.synthetic.plant import AXES, Lowpass2p, PlantParams, discretise
from mavsid.synthetic.sysid import MANOEUVRES, SysIdSettings, chirp, pilot_sticks

__all__ = ["ESC_TYPES", "GRAVITY", "MODE_STABILIZE", "MODE_SYSTEMID", "RCOU_CHANNELS", "Flight",
           "LogRates", "Scenario", "fly"]

GRAVITY = 9.80665
#: longest flight simulated (s)
MAX_DURATION_S = 3600.0
MODE_STABILIZE = 0
MODE_SYSTEMID = 25
_SID_AXIS_OF = {"roll": 10, "pitch": 11, "yaw": 12, "thrust": 13}
#: outputs an RCOU record holds (C1-C14)
RCOU_CHANNELS = 14
#: ESC protocols and their MOT_PWM_TYPE
ESC_TYPES = {"pwm": 0, "dshot150": 4}


@dataclass(frozen=True)
class LogRates:
    """Logging rates (Hz) of each DataFlash message; each must divide the loop rate.

    ``rate`` applies to RATE (and the PID and ANG records of the ``copter-4.6`` layout) and,
    in SYSTEMID, SIDD — loop rate with fast attitude logging; ``rate_idle``, when set, to
    RATE, PID and ANG outside SYSTEMID (ArduCopter 4.x logs them at the mode's rate while
    SYSTEMID runs — every 4th loop with ``LOG_BITMASK``'s ATTITUDE_MED bit only — and at
    10 Hz otherwise); ``tlog`` to the streamed MAVLink messages (ATTITUDE, SCALED_IMU,
    SERVO_OUTPUT_RAW, RC_CHANNELS).
    """

    rate: float = 400.0
    att: float = 10.0
    imu: float = 25.0
    rcou: float = 10.0
    rcin: float = 10.0
    tlog: float = 50.0
    rate_idle: float | None = None

    def step(self, name: str, loop_hz: float) -> int:
        """Loop samples between two records of ``name``."""
        if name == "rate_idle" and self.rate_idle is None:
            name = "rate"
        hz = float(getattr(self, name))
        k = round(loop_hz / hz) if hz > 0 else 0
        if hz <= 0 or k < 1 or abs(loop_hz / k - hz) > 1e-6 * hz:
            raise ConfigError(f"log rate {name}={hz} Hz must divide the loop rate {loop_hz} Hz")
        return int(k)


@dataclass(frozen=True)
class Scenario:
    """What to fly.

    Parameters
    ----------
    manoeuvre : str
        ``"sysid"`` (SYSTEMID runs), ``"doublet"``, ``"3211"``, ``"random"`` or ``"hover"``.
    axis : str
        ``"roll"``, ``"pitch"`` or ``"yaw"``: the pilot's stick axis, and the default mixer
        SYSTEMID axis.
    sysid : tuple of SysIdSettings
        SYSTEMID runs flown one after the other (``manoeuvre="sysid"``); default one mixer run
        on ``axis``.
    duration_s : float, optional
        Total length of the log (s); default: long enough for the runs plus ``hover_after_s``
        (sysid) or 20 s.
    hover_before_s, hover_after_s, gap_s : float
        Hover before the first run, after the last and between runs (s).
    stick_amplitude : float
        Pilot stick deflection (fraction of full stick).
    seed : int
        Seeds every random draw: equal scenarios give equal flights.
    plant, controller : PlantParams, ControllerParams
    frame : str
        The multirotor frame the motors are mixed for
        (:data:`~mavsid.synthetic.controller.FRAMES`; ``FRAME_CLASS``/``FRAME_TYPE``).
    rates : LogRates
    boot_s : float
        Time since boot (s) at the first logged sample.
    motor_output : int
        The output (``SERVOn``, RCOU ``Cn``) of motor 1, the others following it
        (``SERVOn_FUNCTION`` 33, 34, ...); the outputs before it carry nothing and log 0.
        ArduCopter's default is 1; a flight controller whose first outputs cannot run
        DShot has its ESCs on 9-12.
    esc : str
        ``"pwm"`` or ``"dshot150"`` (``MOT_PWM_TYPE`` 0 or 4; RCOU logs the same 1000-2000
        range either way).
    motor_failure_s : float, optional
        Seconds after the first logged sample at which motor 1 stops (a propeller or ESC
        lost): the vehicle rolls over. A SYSTEMID run then stops once the lean exceeds
        ``ANGLE_MAX`` ("SystemID Stopped: lean=..."; the mode stays SYSTEMID and its
        records go on, the waveform held); the vehicle disarms once on its back (or 2 s
        later: the crash check) and lies still, motors at ``MOT_PWM_MIN``, while logging
        continues.
    retune : (float, ControllerParams), optional
        ``(at_s, controller)``: seconds after the first logged sample the controller's
        parameters become ``controller``'s (set in flight from a ground station: the
        controller's state carries on, the logs record the changed parameters).
    """

    manoeuvre: str = "sysid"
    axis: str = "roll"
    sysid: tuple[SysIdSettings, ...] = ()
    duration_s: float | None = None
    hover_before_s: float = 3.0
    hover_after_s: float = 2.0
    gap_s: float = 3.0
    stick_amplitude: float = 0.3
    seed: int = 0
    plant: PlantParams = field(default_factory=PlantParams)
    controller: ControllerParams = field(default_factory=ControllerParams)
    frame: str = "quad-x"
    rates: LogRates = field(default_factory=LogRates)
    boot_s: float = 30.0
    motor_output: int = 1
    esc: str = "pwm"
    motor_failure_s: float | None = None
    retune: tuple[float, ControllerParams] | None = None

    def __post_init__(self) -> None:
        if self.manoeuvre not in ("sysid", *MANOEUVRES):
            raise ConfigError(
                f"unknown manoeuvre {self.manoeuvre!r} (choose from sysid, {', '.join(MANOEUVRES)})"
            )
        if self.axis not in AXES:
            raise ConfigError(f"axis must be one of {', '.join(AXES)}, got {self.axis!r}")
        if self.frame not in FRAMES:
            raise ConfigError(f"frame must be one of {', '.join(FRAMES)}, got {self.frame!r}")
        if self.duration_s is not None and not 0 < self.duration_s <= MAX_DURATION_S:
            raise ConfigError(
                f"duration must lie in (0, {MAX_DURATION_S:g}] s, got {self.duration_s}"
            )
        if self.seed < 0:
            raise ConfigError(f"seed must be >= 0, got {self.seed}")
        n_motors = FRAMES[self.frame][1].shape[0]
        if not 1 <= self.motor_output <= RCOU_CHANNELS - n_motors + 1:
            raise ConfigError(f"motor_output must be 1-{RCOU_CHANNELS - n_motors + 1} for "
                              f"{n_motors} motors, got {self.motor_output}")
        if self.motor_failure_s is not None and not 0 < self.motor_failure_s < self.length_s:
            raise ConfigError(f"motor failure at {self.motor_failure_s} s is outside the "
                              f"flight (0-{self.length_s:g} s)")
        if self.retune is not None:
            if not 0 < self.retune[0] < self.length_s:
                raise ConfigError(f"retune at {self.retune[0]} s is outside the flight "
                                  f"(0-{self.length_s:g} s)")
            if self.retune[1].loop_hz != self.controller.loop_hz:
                raise ConfigError("a retune cannot change the loop rate")
        if self.esc not in ESC_TYPES:
            raise ConfigError(f"esc must be one of {', '.join(ESC_TYPES)}, got {self.esc!r}")
        for name in ("rate", "att", "imu", "rcou", "rcin", "tlog", "rate_idle"):
            self.rates.step(name, self.controller.loop_hz)  # each must divide the loop rate
        if self.sysid and self.manoeuvre != "sysid":
            raise ConfigError("SYSTEMID settings given for a pilot manoeuvre")
        if self.runs and self.duration_s is not None and self.motor_failure_s is None:
            need = self.run_starts()[-1] + self.runs[-1].duration
            if self.duration_s < need:
                raise ConfigError(
                    f"duration {self.duration_s:g} s ends before the SYSTEMID run(s) finish "
                    f"(need at least {need:g} s)"
                )

    @property
    def runs(self) -> tuple[SysIdSettings, ...]:
        """The SYSTEMID runs to fly (none for pilot manoeuvres)."""
        if self.manoeuvre != "sysid":
            return ()
        return self.sysid or (SysIdSettings(axis=_SID_AXIS_OF[self.axis]),)

    def run_starts(self) -> list[float]:
        """Start of each run, seconds after the first logged sample."""
        starts, t = [], self.hover_before_s
        for r in self.runs:
            starts.append(t)
            t += r.duration + self.gap_s
        return starts

    @property
    def length_s(self) -> float:
        """Simulated length (s)."""
        if self.duration_s is not None:
            return float(self.duration_s)
        if self.runs:
            last = self.run_starts()[-1] + self.runs[-1].duration
            return last + self.hover_after_s
        return 20.0


@dataclass(frozen=True)
class Flight:
    """Every signal of one simulated flight at loop rate (samples first, SI units).

    Attributes
    ----------
    t_s : numpy.ndarray
        (n,) time since boot (s).
    rate_true, gyro_raw, gyro : numpy.ndarray
        (n, 3) true, measured and filtered body rates (rad/s).
    attitude, attitude_target : numpy.ndarray
        (n, 3) roll, pitch, yaw (rad).
    desired : numpy.ndarray
        (n, 3) desired roll, pitch angle (rad) and yaw rate (rad/s) before input shaping:
        pilot sticks plus any SYSTEMID angle injection.
    rate_target : numpy.ndarray
        (n, 3) rate-controller targets (rad/s), any SYSTEMID rate injection included.
    rate_injection : numpy.ndarray
        (n, 3) the SYSTEMID rate injection in them (rad/s; ``SID_AXIS`` 7-9, else zero).
    pid_out : numpy.ndarray
        (n, 3) rate-PID outputs, before any SYSTEMID mixer injection.
    u, u_eff : numpy.ndarray
        (n, 3) mixer inputs (RATE.ROut/POut/YOut), and what the motors realised.
    throttle : numpy.ndarray
        (n,) collective (0-1).
    motors, pwm : numpy.ndarray
        (n, motors) motor demands (0-1) in the frame's motor order, and their PWM (µs).
    accel : numpy.ndarray
        (n, 3) specific force (m/s²).
    sticks : numpy.ndarray
        (n, 4) roll, pitch, throttle, yaw (-1..1; throttle 0..1).
    mode : numpy.ndarray
        (n,) flight mode number.
    sid_time, sid_targ, sid_freq : numpy.ndarray
        (n,) SYSTEMID waveform clock, signal and frequency (NaN outside SYSTEMID).
    run_index : numpy.ndarray
        (n,) index of the SYSTEMID run, -1 outside.
    pid_terms : numpy.ndarray
        (n, 3, 11) float32, per axis the values of its PID record (PIDR, PIDP, PIDY, fields
        as in :data:`~mavsid.synthetic.controller.PID_LOG_FIELDS`; rates in rad/s).
    texts : tuple
        ((loop index, text), ...) the firmware's messages on events (a SYSTEMID run stopped
        by its lean limit).
    disarm_index : int or None
        The loop at which the vehicle disarmed after a crash (None: armed throughout).
    """

    scenario: Scenario
    dt: float
    t_s: np.ndarray
    rate_true: np.ndarray
    gyro_raw: np.ndarray
    gyro: np.ndarray
    attitude: np.ndarray
    attitude_target: np.ndarray
    desired: np.ndarray
    rate_target: np.ndarray
    rate_injection: np.ndarray
    pid_out: np.ndarray
    u: np.ndarray
    u_eff: np.ndarray
    throttle: np.ndarray
    motors: np.ndarray
    pwm: np.ndarray
    accel: np.ndarray
    sticks: np.ndarray
    mode: np.ndarray
    sid_time: np.ndarray
    sid_targ: np.ndarray
    sid_freq: np.ndarray
    run_index: np.ndarray
    pid_terms: np.ndarray
    texts: tuple[tuple[int, str], ...] = ()
    disarm_index: int | None = None

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def rc_in(self) -> np.ndarray:
        """RC input PWM (µs), shape (n, 8): C1 roll, C2 pitch, C3 throttle, C4 yaw, C5 the
        flight-mode switch (low STABILIZE, high SYSTEMID), C6-C8 centred."""
        st = self.sticks
        hover = self.scenario.plant.hover_throttle
        rc = np.full((len(self), 8), 1500.0)
        rc[:, 0] = 1500 + 500 * st[:, 0]
        rc[:, 1] = 1500 + 500 * st[:, 1]
        rc[:, 2] = 1500 + 1000 * (st[:, 2] - hover)
        rc[:, 3] = 1500 + 500 * st[:, 3]
        rc[:, 4] = np.where(self.mode == MODE_SYSTEMID, 1815, 1165)
        return np.round(rc)

    def retuned(self, params_of: Callable[[Flight], Mapping[str, float | int]]
                ) -> tuple[int, dict[str, float | int]] | None:
        """The loop index of the scenario's retune and the parameters it changes, named as
        ``params_of`` (a writer's parameters of a flight) names them; None without one.

        >>> from mavsid.synthetic.controller import ControllerParams
        >>> fl = fly(Scenario(manoeuvre="hover", duration_s=0.1,
        ...                   retune=(0.05, ControllerParams(rll_p=0.2))))
        >>> fl.retuned(Flight.params)
        (20, {'ATC_RAT_RLL_P': 0.2})
        """
        if self.scenario.retune is None:
            return None
        at_s, controller = self.scenario.retune
        before = params_of(self)
        after = params_of(replace(self, scenario=replace(self.scenario, controller=controller,
                                                         retune=None)))
        changed = {k: v for k, v in after.items() if before.get(k) != v}
        return round(at_s / self.dt), changed

    def params(self) -> dict[str, float]:
        """ArduPilot parameters describing this vehicle and run (PARM / PARAM_VALUE)."""
        sc = self.scenario
        p: dict[str, float] = {}
        p.update(sc.controller.params())
        p["INS_GYRO_FILTER"] = sc.plant.gyro_filter_hz
        p["INS_ACCEL_FILTER"] = 20.0
        p["MOT_THST_HOVER"] = sc.plant.hover_throttle
        p["FRAME_CLASS"], p["FRAME_TYPE"] = map(float, FRAMES[sc.frame][0])
        if sc.motor_output != 1 or sc.esc != "pwm":  # (the default vehicle lists neither)
            n_motors = FRAMES[sc.frame][1].shape[0]
            for out in range(1, RCOU_CHANNELS + 1):
                m = out - sc.motor_output
                p[f"SERVO{out}_FUNCTION"] = float(33 + m if 0 <= m < n_motors else 0)
            p["MOT_PWM_TYPE"] = float(ESC_TYPES[sc.esc])
        # RCIN, IMU, RCOU bits plus ATTITUDE_FAST/MED as SYSTEMID's logging rate implies:
        # both -> every loop, FAST -> every 2nd, MED -> every 4th, neither -> every 8th
        every_k = sc.rates.step("rate", sc.controller.loop_hz)
        att_bits = {1: 3, 2: 1, 4: 2}.get(every_k, 0)
        p["LOG_BITMASK"] = float(64 | 128 | 1024 | att_bits)
        p["FLTMODE1"] = float(MODE_STABILIZE)
        p["FLTMODE6"] = float(MODE_SYSTEMID)
        runs = sc.runs
        p.update((runs[-1] if runs else SysIdSettings(axis=_SID_AXIS_OF[sc.axis])).params())
        if not runs:
            p["SID_AXIS"] = 0.0
        return dict(sorted(p.items()))

    def run_windows(self) -> list[dict[str, Any]]:
        """Each SYSTEMID run: settings, mode entry/exit and the chirp's sweep window (s)."""
        out = []
        sc = self.scenario
        for i, (s, start) in enumerate(zip(sc.runs, sc.run_starts(), strict=True)):
            t0 = float(self.t_s[0]) + start
            out.append({
                "index": i,
                "sid_axis": s.axis,
                "injection": s.injection,
                "axis": s.target_axis,
                "settings": s.params(),
                "mode_enter_s": t0,
                "mode_exit_s": t0 + s.duration,
                "waveform_start_s": t0 + 1.0,
                "sweep_start_s": t0 + 1.0 + s.t_const_freq,
                "waveform_stop_s": t0 + 1.0 + s.t_rec,
            })
        return out

    def truth(self) -> dict[str, Any]:
        """The ground truth as a JSON-safe dict (see ``fixtures/README.md``)."""
        sc, pl = self.scenario, self.scenario.plant
        loop_hz = sc.controller.loop_hz
        axes: dict[str, Any] = {}
        for i, (ax, state, inp, fld, out_fld) in enumerate(
            zip(AXES, ("p", "q", "r"), ("u_roll", "u_pitch", "u_yaw"),
                ("RATE.ROut", "RATE.POut", "RATE.YOut"), ("RATE.R", "RATE.P", "RATE.Y"),
                strict=True)
        ):
            axes[ax] = {
                "state": state,
                "input": inp,
                "input_field": fld,
                "output_field": out_fld,
                "model": f"d{state}/dt = -damping*{state} + effectiveness*{inp}(t - delay_s)",
                "damping": pl.damping[i],
                "effectiveness": pl.effectiveness[i],
                "delay_s": pl.delay_s,
                "motor_tau_s": pl.motor_tau_s,
                "effective_delay_s": pl.delay_s + pl.motor_tau_s,
                "gyro_filter_hz": pl.gyro_filter_hz,
                "gyro_bias": pl.gyro_bias[i],
                "pole": -pl.damping[i],
                "dc_gain": pl.effectiveness[i] / pl.damping[i],
                "coupling": {
                    AXES[j]: pl.coupling[i][j] for j in range(3) if j != i and pl.coupling[i][j]
                },
                "units": {
                    "damping": "1/s",
                    "effectiveness": "rad/s^2 per unit",
                    "delay_s": "s",
                    "motor_tau_s": "s",
                    "effective_delay_s": "s",
                    "gyro_filter_hz": "Hz",
                    "gyro_bias": "rad/s",
                    "pole": "1/s",
                    "dc_gain": "rad/s per unit",
                },
            }
        sat = float(np.mean(np.any(np.abs(self.u_eff - self.u) > 1e-9, axis=1)))
        return {
            "format": "mavsid-truth/1",
            "generator": "mavsid simulate",
            "seed": sc.seed,
            "manoeuvre": sc.manoeuvre,
            "frame": sc.frame,
            "axis": sc.axis,
            "loop_hz": loop_hz,
            "t_start_s": float(self.t_s[0]),
            "t_stop_s": float(self.t_s[-1]),
            "axes": axes,
            "logged_rate": (
                "RATE.R/P/Y (deg/s), IMU.GyrX/Y/Z (rad/s) and MAVLink ATTITUDE.rollspeed/"
                "pitchspeed/yawspeed (rad/s) are the FILTERED gyro: true body rate + gyro_bias + "
                "white noise, passed through gyro_filter (2nd-order Butterworth, "
                "INS_GYRO_FILTER) at loop rate. SIDD.Gx/Gy/Gz (deg/s) are the UNFILTERED gyro. "
                "RATE.ROut/POut/YOut are the mixer inputs u that drive the plant (after delay_s "
                "and the motor lag motor_tau_s)."
            ),
            "gyro_filter": {
                "param": "INS_GYRO_FILTER",
                "type": "2nd-order Butterworth low pass, bilinear transform with pre-warping "
                "(ArduPilot LowPassFilter2p)",
                "cutoff_hz": pl.gyro_filter_hz,
                "sample_hz": loop_hz,
            },
            "motor": {"type": "first-order lag", "tau_s": pl.motor_tau_s,
                      "delay_s": pl.delay_s},
            "plant": pl.to_dict(),
            "plant_units": {
                "damping": "1/s", "effectiveness": "rad/s^2 per unit",
                "coupling": "rad/s^2 per unit", "motor_tau_s": "s", "delay_s": "s",
                "gyro_noise": "rad/s (std per loop sample)", "gyro_bias": "rad/s",
                "accel_noise": "m/s^2", "disturbance": "rad/s^2 (std, held per loop step)",
                "gyro_filter_hz": "Hz", "hover_throttle": "0-1",
            },
            "controller": sc.controller.params(),
            "log_rates_hz": {k: float(getattr(sc.rates, k))
                             for k in ("rate", "att", "imu", "rcou", "rcin", "tlog")},
            "sysid_runs": self.run_windows(),
            "saturated_fraction": sat,
        }


def _desired(sc: Scenario, n: int, dt: float, rng: np.random.Generator) -> np.ndarray:
    """Pilot sticks (n, 4): roll, pitch, throttle, yaw."""
    sticks = np.zeros((n, 4))
    sticks[:, 2] = sc.plant.hover_throttle
    if sc.manoeuvre not in ("sysid", "hover"):
        col = {"roll": 0, "pitch": 1, "yaw": 3}[sc.axis]
        sticks[:, col] = pilot_sticks(
            sc.manoeuvre, n, dt, rng, amplitude=sc.stick_amplitude, start_s=sc.hover_before_s
        )
    return sticks


#: the kinematics stop pitch this short of ±90° (the Euler angles' pole) in a roll-over
_PITCH_POLE = np.radians(89.0)
#: the vehicle disarms when it lies on its back (lean beyond this, degrees) or, at the latest,
#: when ArduCopter's crash check fires (this long after the lean limit was passed)
_ON_ITS_BACK_DEG = 100.0
_CRASH_CHECK_S = 2.0


class _Crash:
    """A motor failure and what follows: the SYSTEMID run stopped by its lean limit, the
    disarm, the vehicle lying still."""

    def __init__(self, sc: Scenario, n: int, dt: float) -> None:
        assert sc.motor_failure_s is not None
        self.fail_k = round(sc.motor_failure_s / dt)
        self.angle_max = sc.controller.angle_max_deg
        self.dt = dt
        self.n = n
        self.stopped = False
        self.stop_k = n
        self.disarm_k: int | None = None
        self.texts: list[tuple[int, str]] = []

    def failed(self, k: int) -> tuple[int, ...]:
        """The motors (0-based) without thrust at loop ``k``."""
        return (0,) if k >= self.fail_k else ()

    def disarmed(self, k: int) -> bool:
        return self.disarm_k is not None and k >= self.disarm_k

    def stops_run(self, k: int, att: np.ndarray, run_index: np.ndarray, inj_kind: np.ndarray,
                  sid_targ: np.ndarray) -> bool:
        """True once, at the loop where the lean first exceeds ANGLE_MAX after the failure
        (during a SYSTEMID run: the mode stops it); sets the disarm once on its back."""
        if k < self.fail_k or self.disarm_k is not None:
            return False
        lean = float(np.degrees(np.arccos(np.clip(np.cos(att[0]) * np.cos(att[1]), -1, 1))))
        if self.stopped:
            if lean > _ON_ITS_BACK_DEG or k >= self.stop_k + round(_CRASH_CHECK_S / self.dt):
                self.disarm_k = k
            return False
        if lean <= self.angle_max:
            return False
        self.stopped, self.stop_k = True, k
        if run_index[k] < 0:
            return False
        self.texts.append((k, f"SystemID Stopped: lean={lean:.5f} "
                              f"max={self.angle_max * 100.0:.3f}"))
        inj_kind[k:] = ""
        return True

    def hold_mode(self, k: int, mode: np.ndarray, run_index: np.ndarray, sid_time: np.ndarray,
                  sid_targ: np.ndarray, sid_freq: np.ndarray) -> None:
        """The stopped run's mode stays on to the end of the log: its clock runs on, its
        waveform and frequency hold their last values."""
        mode[k:], run_index[k:] = MODE_SYSTEMID, run_index[k]
        sid_time[k:] = sid_time[k] + np.arange(self.n - k) * self.dt
        sid_targ[k:], sid_freq[k:] = sid_targ[k - 1], sid_freq[k - 1]


def fly(sc: Scenario) -> Flight:
    """Simulate the closed loop of ``sc`` at the controller's loop rate."""
    ctl, pl = sc.controller, sc.plant
    dt = 1.0 / ctl.loop_hz
    n = round(sc.length_s / dt)
    if n < 8:
        raise ConfigError(f"duration {sc.length_s} s is too short")
    rng = np.random.default_rng(sc.seed)
    sticks = _desired(sc, n, dt, rng)
    t = sc.boot_s + np.arange(n) * dt

    # SYSTEMID schedule: waveform clock, signal and frequency per loop
    mode = np.full(n, MODE_STABILIZE, dtype=np.int64)
    sid_time = np.full(n, np.nan)
    sid_targ = np.zeros(n)
    sid_freq = np.full(n, np.nan)
    run_index = np.full(n, -1, dtype=np.int64)
    inj_axis = np.full(n, -1, dtype=np.int64)
    inj_kind = np.full(n, "", dtype=object)
    for i, (s, start) in enumerate(zip(sc.runs, sc.run_starts(), strict=True)):
        k0 = round(start / dt)
        k1 = min(n, k0 + int(np.floor(s.duration / dt)) + 1)
        if k0 >= n:
            break
        clock = (np.arange(k0, k1) - k0 + 1) * dt  # advanced before use, as the mode does
        targ, freq = chirp(clock, s)
        mode[k0:k1], sid_time[k0:k1], sid_targ[k0:k1] = MODE_SYSTEMID, clock, targ
        sid_freq[k0:k1], run_index[k0:k1] = freq, i
        inj_axis[k0:k1] = ("roll", "pitch", "yaw", "thrust").index(s.target_axis)
        inj_kind[k0:k1] = s.injection

    disc = discretise(pl, dt)
    noise = rng.standard_normal((n, 3)) * pl.gyro_noise
    acc_noise = rng.standard_normal((n, 3)) * pl.accel_noise
    dist = rng.standard_normal((n, 3)) * pl.disturbance
    bias = np.array(pl.gyro_bias)
    if pl.vibration > 0:  # frame vibration on the raw gyro, one phase per axis
        noise = noise + pl.vibration * np.sin(
            2 * np.pi * pl.vibration_hz * dt * np.arange(n)[:, None] + np.array([0.0, 2.1, 4.2]))
    gyro_filter = Lowpass2p(pl.gyro_filter_hz, ctl.loop_hz, 3)
    control = AttitudeController(ctl)
    x = np.zeros(disc.n_state)
    att = np.zeros(3)
    out = {k: np.zeros((n, 3)) for k in ("rate_true", "gyro_raw", "gyro", "attitude",
                                          "attitude_target", "desired", "rate_target", "pid_out",
                                          "u", "u_eff")}
    throttle = np.zeros(n)
    factors = FRAMES[sc.frame][1]
    motors = np.zeros((n, factors.shape[0]))
    n_hist = disc.delay_steps + 2  # ring buffer of u_eff[k-n-1 .. k]
    u_hist = np.zeros((n_hist, 3))
    # desired roll, pitch angle and yaw rate from the sticks (+ SYSTEMID angle injection)
    desired = sticks[:, [0, 1, 3]] * np.radians(
        [ctl.angle_max_deg, ctl.angle_max_deg, ctl.pilot_yaw_rate_degs])
    angle_inj = (inj_kind == "input_angle") | (inj_kind == "recovery_angle")
    rows = np.flatnonzero(angle_inj & (inj_axis < 3))
    desired[rows, inj_axis[rows]] += np.radians(sid_targ[rows])
    rate_inj = np.zeros((n, 3))
    rows = np.flatnonzero((inj_kind == "rate") & (inj_axis < 3))
    rate_inj[rows, inj_axis[rows]] = np.radians(sid_targ[rows])
    mixer_inj = np.zeros((n, 4))  # roll, pitch, yaw, thrust
    rows = np.flatnonzero(inj_kind == "mixer")
    mixer_inj[rows, inj_axis[rows]] = sid_targ[rows]
    feedforward = inj_kind != "recovery_angle"
    terms = np.zeros((n, 3, len(PID_LOG_FIELDS)), dtype=np.float32)
    limit = np.zeros(3, dtype=bool)  # the motors saturated on an axis in the previous loop
    crash = _Crash(sc, n, dt) if sc.motor_failure_s is not None else None
    retune_k = round(sc.retune[0] / dt) if sc.retune is not None else -1
    for k in range(n):
        if k == retune_k and sc.retune is not None:
            control.set_params(sc.retune[1])
        rate = x[:3]
        g_raw = rate + bias + noise[k]
        g = gyro_filter(g_raw)
        if crash is not None and crash.stops_run(k, att, run_index, inj_kind, sid_targ):
            desired[k:] = sticks[k:][:, [0, 1, 3]] * np.radians(
                [ctl.angle_max_deg, ctl.angle_max_deg, ctl.pilot_yaw_rate_degs])
            rate_inj[k:], mixer_inj[k:], feedforward[k:] = 0.0, 0.0, True
            crash.hold_mode(k, mode, run_index, sid_time, sid_targ, sid_freq)
        step = control.update(desired[k], att, g, rate_inj[k], bool(feedforward[k]), limit,
                              float(t[k]))
        terms[k] = step.terms
        thr = pl.hover_throttle + mixer_inj[k, 3]
        demand = step.pid_out + mixer_inj[k, :3]
        u = np.clip(demand, -1.0, 1.0)
        m, ue = motor_outputs(np.array([thr]), u[None, :], factors,
                              crash.failed(k) if crash is not None else ())
        limit = (np.abs(ue[0] - demand) > 1e-9) | (np.abs(demand) >= 1.0)
        if crash is not None and crash.disarmed(k):  # on its back, motors stopped
            m, ue, x = np.zeros_like(m), np.zeros_like(ue), np.zeros_like(x)
            rate = x[:3]
        # plant: x[k+1] from x[k] and the delayed realised inputs
        u_hist[k % n_hist] = ue[0]
        u_prev, u_now = u_hist[(k + 1) % n_hist], u_hist[(k + 2) % n_hist]
        x_next = (disc.phi @ x + disc.gamma_prev @ u_prev + disc.gamma_now @ u_now
                  + disc.gamma_w @ dist[k])
        if crash is not None and crash.disarmed(k):
            x_next = np.zeros_like(x)
        out["rate_true"][k], out["gyro_raw"][k], out["gyro"][k] = rate, g_raw, g
        out["attitude"][k], out["attitude_target"][k] = att, step.att_target
        out["rate_target"][k], out["pid_out"][k] = step.rate_target, step.pid_out
        out["u"][k], out["u_eff"][k] = u, ue[0]
        throttle[k], motors[k] = thr, m[0]
        # Euler kinematics with the mean rate over the step
        pm, qm, rm = 0.5 * (rate + x_next[:3])
        phi, theta = att[0], att[1]
        att = att + dt * np.array([
            pm + np.tan(theta) * (qm * np.sin(phi) + rm * np.cos(phi)),
            qm * np.cos(phi) - rm * np.sin(phi),
            (qm * np.sin(phi) + rm * np.cos(phi)) / np.cos(theta),
        ])
        att[2] = att[2] % (2 * np.pi)
        if crash is not None:  # (rolled over: roll wraps, pitch stays short of the pole)
            att[0] = (att[0] + np.pi) % (2 * np.pi) - np.pi
            att[1] = min(max(att[1], -_PITCH_POLE), _PITCH_POLE)
        x = x_next
    out["desired"][:] = desired
    accel = acc_noise.copy()
    accel[:, 2] += -GRAVITY * motors.mean(axis=1) / pl.hover_throttle
    pwm = ctl.motor_pwm(motors)
    if crash is not None and crash.disarm_k is not None:
        pwm[crash.disarm_k:] = ctl.pwm_min  # (disarmed outputs: MOT_PWM_MIN)
    return Flight(
        scenario=sc, dt=dt, t_s=t, throttle=throttle, motors=motors, pwm=pwm,
        accel=accel, sticks=sticks, mode=mode, sid_time=sid_time, sid_targ=sid_targ,
        sid_freq=sid_freq, run_index=run_index, pid_terms=terms, rate_injection=rate_inj,
        texts=tuple(crash.texts) if crash is not None else (),
        disarm_index=crash.disarm_k if crash is not None else None, **out,
    )
