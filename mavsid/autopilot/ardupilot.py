"""ArduPilot's facts: SYSTEMID, servo and motor outputs, the thrust curve, logging advice,
the rate controller's parameter names and the parameter file MAVProxy loads.

What ArduPilot's firmware defines and mavsid relies on, each with the source file it comes
from (the facts carry over, never the code): SYSTEMID's axis numbering (``SID_AXIS``), its
settings' parameter and log-field names, the ``SERVOn_FUNCTION`` numbers of control
surfaces and motors, the motor output and thrust curve (``MOT_*``) and what to fly and log
for identification. Message and field names per version are in the channel presets
(:mod:`mavsid.autopilot.presets`), mode numbers in :mod:`mavsid.autopilot.modes`, motor
geometry in :mod:`mavsid.autopilot.mixers`.

Examples
--------
>>> sid_axis(1), sid_axis(10), sid_axis(13)
(('roll', 'input angle'), ('roll', 'mixer'), ('thrust', 'mixer'))
>>> SID_MIXER_AXIS["pitch"]
11
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from types import MappingProxyType

import numpy as np

from mavsid.axes import AXES
from mavsid.errors import ConfigError

__all__ = [
    "COPTER_LOG_BITS",
    "HARMONIC_NOTCH_PARAMS",
    "IMU_GYRO_FIELDS",
    "PLANE_LOG_BITS",
    "PLANE_SURFACE_DEG",
    "PWM_SPAN",
    "RATE_AXIS",
    "RATE_CDEG_SCALE",
    "RATE_FILTER_SUFFIXES",
    "RC_MAP_AP",
    "SERVO_FUNCTIONS",
    "SIDS_FIELDS",
    "SID_IDENTIFIES",
    "SID_MIXER_AXIS",
    "SID_PARAMS",
    "SYSTEMID_MODE",
    "SYSTEM_ID_DELAY_S",
    "TELEMETRY_NOTE",
    "angle_p_param",
    "before_rate",
    "excitation_advice",
    "filter_params",
    "firmware_version",
    "injects_into_mixer",
    "is_plane",
    "is_quadplane",
    "log_bit_text",
    "logging_advice",
    "longer_advice",
    "motor_channels",
    "param_file_text",
    "pwm_to_thrust",
    "rate_naming",
    "rate_prefix",
    "rate_target_logs_injection",
    "sid_axis",
    "thrust_curve",
    "whole_param",
]

# --------------------------------------------------------------------------- SYSTEMID

#: the flight mode that injects the chirp (ArduCopter/mode.h, Mode::Number::SYSTEMID = 25)
SYSTEMID_MODE = "SYSTEMID"
#: ArduCopter waits this long after entering SYSTEMID before injecting
#: (ArduCopter/mode_systemid.cpp, SYSTEM_ID_DELAY 1.0 s)
SYSTEM_ID_DELAY_S = 1.0
#: where SID_AXIS 1-12 inject, in groups of three (roll, pitch, yaw), and 13 (thrust):
#: ArduCopter/mode_systemid.cpp, SID_AXIS @Values (1-3 Input, 4-6 Recovery, 7-9 Rate,
#: 10-12 Mixer roll/pitch/yaw, 13 Mixer Thrust; 14-19 the position controller's axes)
_INJECTION = ("input angle", "recovery angle", "rate", "mixer")
#: what a chirp at each injection point identifies: the mixer input is the plant's input;
#: upstream of it the plant is still measured, against the waveform (SIDD.Targ) as
#: reference, through the controllers that carry the chirp to the mixer input
SID_IDENTIFIES: Mapping[str, str] = MappingProxyType({
    "mixer": "the plant (injected at its input)",
    "rate": "the plant through the rate controller (against SIDD.Targ), and the rate loop",
    "recovery angle": "the plant through the attitude and rate controllers (against "
                      "SIDD.Targ), and the attitude loop",
    "input angle": "the plant through the attitude and rate controllers (against SIDD.Targ), "
                   "and the attitude loop with its input shaping",
})
#: axis -> the SID_AXIS that adds the chirp to the mixer input (10, 11, 12)
SID_MIXER_AXIS: Mapping[str, int] = MappingProxyType({a: 10 + i for i, a in enumerate(AXES)})
#: SIDS record field -> run setting (ArduCopter/Log.cpp, log_SysIdSetup: Ax Mag FSt FSp TFin
#: TC TR TFout)
SIDS_FIELDS: Mapping[str, str] = MappingProxyType({
    "Ax": "axis", "Mag": "magnitude", "FSt": "f_start_hz", "FSp": "f_stop_hz",
    "TFin": "t_fade_in_s", "TC": "t_const_freq_s", "TR": "t_record_s", "TFout": "t_fade_out_s",
})
#: SYSTEMID parameter -> run setting (ArduCopter/mode_systemid.cpp, var_info SID_*)
SID_PARAMS: Mapping[str, str] = MappingProxyType({
    "SID_AXIS": "axis", "SID_MAGNITUDE": "magnitude", "SID_F_START_HZ": "f_start_hz",
    "SID_F_STOP_HZ": "f_stop_hz", "SID_T_FADE_IN": "t_fade_in_s", "SID_T_REC": "t_record_s",
    "SID_T_FADE_OUT": "t_fade_out_s",
})


def sid_axis(number: int) -> tuple[str, str]:
    """ArduCopter ``SID_AXIS`` -> (axis, injection point).

    Examples
    --------
    >>> sid_axis(7), sid_axis(12), sid_axis(14)
    (('roll', 'rate'), ('yaw', 'mixer'), ('other', 'SID_AXIS 14'))
    """
    if 1 <= number <= 12:
        return AXES[(number - 1) % 3], _INJECTION[(number - 1) // 3]
    if number == 13:
        return "thrust", "mixer"
    return "other", f"SID_AXIS {number}"


def injects_into_mixer(number: int) -> bool:
    """Whether ``SID_AXIS`` ``number`` adds its waveform to the mixer input (10-13): the
    rate controller is bypassed, and the rate target it logs meanwhile is its answer to the
    disturbed rate, not a command (the attitude and rate injections, 1-9, add to a target).

    Examples
    --------
    >>> [injects_into_mixer(n) for n in (1, 7, 9, 10, 12, 13, 14)]
    [False, False, False, True, True, True, False]
    """
    return sid_axis(number)[1] == "mixer"



def firmware_version(firmware: str | None) -> tuple[int, int] | None:
    """(major, minor) of an ArduPilot banner (``"ArduCopter V4.5.7 (abc)"``), None without one.

    Examples
    --------
    >>> firmware_version("ArduCopter V4.5.7 (mavsid00)"), firmware_version("PX4 v1.14.0")
    ((4, 5), None)
    """
    got = re.search(r"Ardu\w+ V(\d+)\.(\d+)", firmware or "")
    return (int(got[1]), int(got[2])) if got else None


def rate_target_logs_injection(firmware: str | None) -> bool | None:
    """Whether the rate target RATE logs (``RDes/PDes/YDes``) carries a rate injection
    (``SID_AXIS`` 7-9), by firmware version; None when the version does not say.

    ArduCopter 4.5+ logs ``rate_bf_targets()``, the attitude controller's target plus the
    SYSTEMID rate (``_ang_vel_body + _sysid_ang_vel_body``), written after the mode set it
    (libraries/AC_AttitudeControl/AC_AttitudeControl.h, ``Write_Rate``). 4.0-4.4 add the
    SYSTEMID rate to the target member inside ``rate_controller_run``, which the attitude
    controller overwrites later in the loop, before RATE is written: the log holds the
    attitude controller's target alone.

    Examples
    --------
    >>> [rate_target_logs_injection(f) for f in ("ArduCopter V4.6.2", "ArduCopter V4.4.4",
    ...                                          "ArduCopter V3.6.12", None)]
    [True, False, None, None]
    """
    version = firmware_version(firmware)
    if version is None or version < (4, 0):  # (SYSTEMID came with 4.0)
        return None
    return version >= (4, 5)

# --------------------------------------------------------------------------- inputs

#: IMU gyro field per body rate (libraries/AP_InertialSensor/LogStructure.h, IMU GyrX/Y/Z,
#: rad/s): the independent measurement a rate channel is checked by
IMU_GYRO_FIELDS: Mapping[str, str] = MappingProxyType({"p": "GyrX", "q": "GyrY", "r": "GyrZ"})
#: per axis: the parameter mapping an RC input channel to it and its default channel
#: (libraries/RC_Channel/RC_Channel.cpp, RCMAP_ROLL 1, RCMAP_PITCH 2, RCMAP_YAW 4)
RC_MAP_AP: Mapping[str, tuple[str, int]] = MappingProxyType({
    "roll": ("RCMAP_ROLL", 1), "pitch": ("RCMAP_PITCH", 2), "yaw": ("RCMAP_YAW", 4)})

# --------------------------------------------------------------------------- outputs

#: ArduPlane's surface demand (degrees) of a full deflection: its controllers' outputs are
#: centidegrees limited to ±4500 (libraries/APM_Control/AP_RollController.cpp)
PLANE_SURFACE_DEG = 45.0

#: Canonical input -> ArduPilot servo function (``SERVOn_FUNCTION``,
#: libraries/SRV_Channel/SRV_Channel.h Aux_servo_function_t), its name, and whether it is an
#: angle output (-1..1 about ``SERVOn_TRIM``) rather than a range (0..1 from ``SERVOn_MIN``).
SERVO_FUNCTIONS: Mapping[str, tuple[int, str, bool]] = MappingProxyType({
    "u_roll": (4, "aileron", True),
    "u_pitch": (19, "elevator", True),
    "u_yaw": (21, "rudder", True),
    "u_thrust": (70, "throttle", False),
})
#: ``SERVOn_FUNCTION`` of motors 1-8 and 9-12 (SRV_Channel.h: k_motor1..8 = 33..40,
#: k_motor9..12 = 82..85)
_MOTOR_FUNCTIONS = (*range(33, 41), *range(82, 86))

#: ArduPilot's defaults for a multirotor's spin range and thrust-curve exponent
#: (AP_Motors_Thrust_Linearization: MOT_SPIN_MIN 0.15, MOT_SPIN_MAX 0.95, MOT_THST_EXPO 0.65)
_SPIN_DEFAULT = (0.15, 0.95)
_EXPO_DEFAULT = 0.65
#: the widest PWM range (µs) an output's end points can stand for
PWM_SPAN = (1.0, 3000.0)


def whole_param(params: Mapping[str, float], key: str) -> int | None:
    """A parameter as a whole number; None when absent or not a finite number (a damaged
    log's).

    >>> whole_param({"A": 2.0}, "A"), whole_param({"A": float("nan")}, "A"), whole_param({}, "A")
    (2, None, None)
    """
    value = params.get(key)
    try:
        return int(value) if value is not None and math.isfinite(value) else None
    except (TypeError, OverflowError):
        return None


def motor_channels(params: Mapping[str, float], n_motors: int) -> list[int]:
    """The output (servo channel, 1-based) of each motor: the lowest-numbered one whose
    ``SERVOn_FUNCTION`` is that motor's (33-40: motors 1-8, 82-85: motors 9-12), when the log
    has them for any motor; motor ``i`` on output ``i`` otherwise (ArduCopter's default, the
    only layout before ``SERVOn_FUNCTION``, and what a .tlog whose ground station fetched
    some parameters only can say).

    Raises
    ------
    ConfigError
        ``SERVOn_FUNCTION`` parameters that give no output to one of the motors.

    Examples
    --------
    >>> motor_channels({}, 4)
    [1, 2, 3, 4]
    >>> motor_channels({"SERVO5_FUNCTION": 33, "SERVO6_FUNCTION": 34, "SERVO7_FUNCTION": 35,
    ...                 "SERVO8_FUNCTION": 36, "SERVO1_FUNCTION": 0}, 4)
    [5, 6, 7, 8]
    """
    outputs: dict[int, int] = {}
    for key in params:
        m = re.fullmatch(r"SERVO(\d+)_FUNCTION", key)
        fn = whole_param(params, key) if m else None
        if m and fn is not None:
            n = int(m.group(1))
            outputs[fn] = min(n, outputs.get(fn, n))
    functions = [_MOTOR_FUNCTIONS[i] if i < 8 else 82 + i - 8 for i in range(n_motors)]
    if not set(outputs) & set(_MOTOR_FUNCTIONS):  # (none, or not all downloaded)
        return list(range(1, n_motors + 1))
    got = [outputs.get(fn) for fn in functions]
    missing = [i for i, o in enumerate(got) if o is None]
    if missing:
        raise ConfigError(
            f"no output carries motor(s) {', '.join(str(i + 1) for i in missing)} of "
            f"{n_motors} (SERVOn_FUNCTION {', '.join(str(functions[i]) for i in missing)}): "
            "the frame (FRAME_CLASS/FRAME_TYPE) and the outputs disagree")
    return [int(o) for o in got if o is not None]


def thrust_curve(params: Mapping[str, float]) -> tuple[tuple[float, ...], list[str]]:
    """The ``(pwm_min, pwm_max, spin_min, spin_max, expo)`` :func:`pwm_to_thrust` uses, and a
    note for each value of the log it could not use (a damaged parameter: ArduPilot's own
    default taken instead; the exponent clipped to [-1, 1], as ArduPilot clips it).

    Examples
    --------
    >>> thrust_curve({"MOT_SPIN_MIN": 0.1, "MOT_SPIN_MAX": 0.9, "MOT_THST_EXPO": 0.5})
    ((1000.0, 2000.0, 0.1, 0.9, 0.5), [])
    >>> for note in thrust_curve({"MOT_SPIN_MIN": float("nan"), "MOT_THST_EXPO": 3.0})[1]:
    ...     print(note)
    MOT_SPIN_MIN nan, MOT_SPIN_MAX 0.95: not a spin range (0 <= min < max <= 1): 0.15, 0.95 assumed
    MOT_THST_EXPO 3 clipped to 1, as ArduPilot does
    """
    notes: list[str] = []

    def number(name: str, default: float) -> float:
        try:
            return float(params.get(name, default))
        except (TypeError, ValueError):
            return math.nan

    lo, hi = number("MOT_PWM_MIN", 0.0), number("MOT_PWM_MAX", 0.0)
    if not hi > lo > 0:  # ArduCopter < 3.5 (and MOT_PWM_* = 0): the throttle channel's range
        lo, hi = number("RC3_MIN", 0.0), number("RC3_MAX", 0.0)
    if not hi > lo > 0:
        lo, hi = 1000.0, 2000.0
    elif not PWM_SPAN[0] <= lo < hi <= PWM_SPAN[1]:
        notes.append(f"PWM range {lo:g}..{hi:g} us is no output's: 1000..2000 assumed")
        lo, hi = 1000.0, 2000.0
    # ArduCopter < 3.4: THR_MIN (0-1000) is the lowest throttle in flight; <= 3.3 (THR_MIN,
    # no MOT_SPIN_*/MOT_THST_EXPO): THR_MAX (0-1000) the top, and no thrust-curve exponent
    # (outputs taken as linear in thrust)
    old = "THR_MIN" in params and "MOT_SPIN_MIN" not in params
    names = ("THR_MIN", "THR_MAX") if old else ("MOT_SPIN_MIN", "MOT_SPIN_MAX")
    spin_min = (number("THR_MIN", 150.0) / 1000.0 if old
                else number("MOT_SPIN_MIN", number("THR_MIN", 150.0) / 1000.0))
    spin_max = (number("MOT_SPIN_MAX", number("THR_MAX", 950.0) / 1000.0) if old
                else number("MOT_SPIN_MAX", _SPIN_DEFAULT[1]))
    if not 0.0 <= spin_min < spin_max <= 1.0:
        scale = 1000.0 if old else 1.0
        notes.append(f"{names[0]} {spin_min * scale:g}, {names[1]} {spin_max * scale:g}: not a "
                     f"spin range (0 <= min < max <= {scale:g}): {_SPIN_DEFAULT[0] * scale:g}, "
                     f"{_SPIN_DEFAULT[1] * scale:g} assumed")
        spin_min, spin_max = _SPIN_DEFAULT
    expo = number("MOT_THST_EXPO", 0.0 if old else _EXPO_DEFAULT)
    if not math.isfinite(expo):
        notes.append(f"MOT_THST_EXPO {expo:g}: {_EXPO_DEFAULT:g} assumed")
        expo = _EXPO_DEFAULT
    elif not -1.0 <= expo <= 1.0:
        clipped = min(max(expo, -1.0), 1.0)
        notes.append(f"MOT_THST_EXPO {expo:g} clipped to {clipped:g}, as ArduPilot does")
        expo = clipped
    return (lo, hi, spin_min, spin_max, expo), notes


def pwm_to_thrust(pwm: np.ndarray, params: Mapping[str, float]) -> np.ndarray:
    """Motor PWM (µs) -> normalised thrust 0..1 through ArduPilot's output and thrust curve.

    ``actuator = (pwm - MOT_PWM_MIN) / (MOT_PWM_MAX - MOT_PWM_MIN)``, then the spin range
    ``r = (actuator - MOT_SPIN_MIN) / (MOT_SPIN_MAX - MOT_SPIN_MIN)`` and the thrust curve
    ``thrust = (1 - MOT_THST_EXPO)·r + MOT_THST_EXPO·r²`` (battery scaling ignored). A PWM
    range of 0 (ArduPilot's "use RC3 range"), or none (ArduCopter < 3.5), takes
    ``RC3_MIN``/``RC3_MAX``, else 1000..2000 µs; ``MOT_SPIN_MIN`` absent (ArduCopter < 3.4)
    takes ``THR_MIN``/1000. Such a log (``THR_MIN``, no ``MOT_SPIN_*``: ArduCopter 3.2's
    parameter table has ``THR_MIN``/``THR_MAX`` and neither) takes ``THR_MAX``/1000 for the
    top of the range and, without ``MOT_THST_EXPO``, outputs linear in thrust (exponent 0;
    the old ``MOT_TCRV_*`` curve is not modelled). Damaged values: :func:`thrust_curve`.

    Examples
    --------
    >>> pwm_to_thrust(np.array([1000.0, 2000.0]), {"MOT_SPIN_MIN": 0, "MOT_SPIN_MAX": 1}).tolist()
    [0.0, 1.0]
    """
    (lo, hi, spin_min, spin_max, expo), _ = thrust_curve(params)
    actuator = (np.asarray(pwm, dtype=float) - lo) / (hi - lo)
    r = np.clip((actuator - spin_min) / (spin_max - spin_min), 0.0, 1.0)
    return (1.0 - expo) * r + expo * r * r


# --------------------------------------------------------------------------- logging

#: ArduCopter LOG_BITMASK: bit -> name (ArduCopter/defines.h, MASK_LOG_*; bit 14 INAV and
#: 16 are unused). ATTITUDE_FAST logs ATT, RATE and the PIDs at loop rate
#: (ArduCopter/Copter.cpp loop_rate_logging), ATTITUDE_MED at 10 Hz; in SYSTEMID both give
#: every loop, FAST alone every 2nd, MED alone every 4th (ArduCopter/mode_systemid.cpp)
COPTER_LOG_BITS: Mapping[int, str] = MappingProxyType({
    0: "ATTITUDE_FAST", 1: "ATTITUDE_MED", 2: "GPS", 3: "PM", 4: "CTUN", 5: "NTUN",
    6: "RCIN", 7: "IMU", 8: "CMD", 9: "CURRENT", 10: "RCOUT", 11: "OPTFLOW", 12: "PID",
    13: "COMPASS", 15: "CAMERA", 17: "MOTBATT", 18: "IMU_FAST", 19: "IMU_RAW",
    20: "VIDEO_STABILISATION", 21: "FTN_FAST",
})
#: ArduPlane LOG_BITMASK: bit -> name (ArduPlane/defines.h, MASK_LOG_*). The attitude and
#: the PIDR/PIDP/PIDY (PIQR/PIQP/PIQY in VTOL flight) records: ATTITUDE_FULLRATE at loop
#: rate, ATTITUDE_FAST at 25 Hz, ATTITUDE_MED at 10 Hz (ArduPlane/ArduPlane.cpp
#: update_logging10/25, Log_Write_FullRate)
PLANE_LOG_BITS: Mapping[int, str] = MappingProxyType({
    0: "ATTITUDE_FAST", 1: "ATTITUDE_MED", 2: "GPS", 3: "PM", 4: "CTUN", 5: "NTUN",
    7: "IMU", 8: "CMD", 9: "CURRENT", 10: "COMPASS", 11: "TECS", 12: "CAMERA", 13: "RC",
    14: "SONAR", 19: "IMU_RAW", 20: "ATTITUDE_FULLRATE", 21: "VIDEO_STABILISATION",
    22: "NOTCH_FULLRATE",
})


def log_bit_text(bits: Mapping[int, str], name: str) -> str:
    """``bit 0 ATTITUDE_FAST (+1)``: a LOG_BITMASK bit as a user sets it.

    >>> log_bit_text(PLANE_LOG_BITS, "ATTITUDE_FULLRATE")
    'bit 20 ATTITUDE_FULLRATE (+1048576)'
    """
    bit = next(b for b, n in bits.items() if n == name)
    return f"bit {bit} {name} (+{1 << bit})"


# --------------------------------------------------------------------------- advice


def is_plane(platform: str | None) -> bool:
    """Whether the platform text (``autopilot vehicle firmware [quadplane]``) names an
    ArduPlane log.

    >>> is_plane("ardupilot plane ArduPlane V4.3.8 (abc)"), is_plane("ArduCopter V4.5.7")
    (True, False)
    """
    return bool(platform) and bool(re.search(r"\bplane\b|ArduPlane", str(platform), re.I))


def is_quadplane(platform: str | None) -> bool:
    """Whether the platform text names an ArduPlane QuadPlane's VTOL flight."""
    return bool(platform) and str(platform).endswith("quadplane")


def before_rate(platform: str | None) -> bool:
    """Whether the platform text names an ArduCopter older than 3.3 (no RATE record).

    >>> before_rate("ardupilot copter ArduCopter V3.2.1 (abc)"), before_rate("ArduCopter V3.3")
    (True, False)
    """
    return bool(platform) and bool(re.search(r"ArduCopter V3\.[0-2]\b", str(platform)))


def excitation_advice(axis: str, platform: str | None) -> str:
    """What to fly next time to excite ``axis`` on this ArduPilot vehicle.

    >>> excitation_advice("roll", "ardupilot")[:48]
    'fly a SYSTEMID mixer chirp on roll (SID_AXIS 10)'
    >>> excitation_advice("yaw", "ardupilot plane ArduPlane V4.5.7 quadplane")[:60]
    'fly sharp stick doublets or a 3-2-1-1 on yaw in QACRO or QST'
    """
    if is_quadplane(platform):
        return (f"fly sharp stick doublets or a 3-2-1-1 on {axis} in QACRO or QSTABILIZE "
                "(ArduPlane has no SYSTEMID mode)")
    if is_plane(platform):
        return (f"fly sharp stick doublets or a 3-2-1-1 on {axis} in ACRO or MANUAL (ArduPlane "
                "has no SYSTEMID mode)")
    if before_rate(platform):
        return (f"fly sharp stick doublets on {axis} in a non-self-levelling mode (ACRO; "
                "ArduCopter 3.x has no SYSTEMID mode)")
    return (f"fly a SYSTEMID mixer chirp on {axis} (SID_AXIS {SID_MIXER_AXIS.get(axis, '?')}) "
            f"or sharp stick doublets on {axis} in a non-self-levelling mode (ACRO)")


def longer_advice(platform: str | None) -> str:
    """What to fly when the excitation was too short, on this ArduPilot vehicle.

    >>> longer_advice("ardupilot")
    'fly longer excitation (a 20-s SYSTEMID chirp or 30 s of doublets)'
    """
    if is_plane(platform) or before_rate(platform):
        return "fly longer excitation (30 s of doublets or 3-2-1-1s)"
    return "fly longer excitation (a 20-s SYSTEMID chirp or 30 s of doublets)"


def logging_advice(platform: str | None) -> str:
    """Which logging setting to change to log body rates and controller outputs fast.

    >>> print(logging_advice("ardupilot"))  # doctest: +NORMALIZE_WHITESPACE
    ArduPilot: set LOG_BITMASK bit 0 ATTITUDE_FAST (+1) with bit 1 ATTITUDE_MED (+2) so that
    RATE, the body rates and the rate controller's outputs, is logged at loop rate
    """
    full = log_bit_text(PLANE_LOG_BITS, "ATTITUDE_FULLRATE")
    fast, med = (log_bit_text(COPTER_LOG_BITS, n) for n in ("ATTITUDE_FAST", "ATTITUDE_MED"))
    if is_quadplane(platform):
        return (f"ArduPlane: set LOG_BITMASK {full} so that PIQR/PIQP/PIQY (the body rates "
                "and the VTOL rate controllers' outputs) are logged at loop rate "
                "(ATTITUDE_FAST logs them at 25 Hz)")
    if is_plane(platform):
        return (f"ArduPlane: set LOG_BITMASK {full} so that PIDR/PIDP/PIDY (the body rates "
                "and the roll/pitch/yaw controllers' outputs) are logged at loop rate "
                "(ATTITUDE_FAST logs them at 25 Hz)")
    if before_rate(platform):
        return ("ArduCopter before 3.3 logs no RATE record and RCOU at 10 Hz: fly 3.3 or later "
                f"with LOG_BITMASK {fast} and {med} (RATE at loop rate)")
    return (f"ArduPilot: set LOG_BITMASK {fast} with {med} so that RATE, the body rates and "
            "the rate controller's outputs, is logged at loop rate")


#: what a ground station's telemetry log holds (ArduPilot's stream-rate parameters,
#: libraries/GCS_MAVLink/GCS_Common.cpp: SRn_EXTRA1 streams ATTITUDE, SRn_RC_CHAN
#: SERVO_OUTPUT_RAW)
TELEMETRY_NOTE = ("a .tlog holds what the telemetry streams sent (ArduPilot SRn_EXTRA1: "
                  "ATTITUDE, SRn_RC_CHAN: SERVO_OUTPUT_RAW; at most 50 Hz): fit the flight "
                  "controller's own log from its SD card instead")


# --------------------------------------------------------------------------- rate controller

#: the axis in the rate and attitude controllers' parameter names (ATC_RAT_RLL_P, STB_PIT_P)
RATE_AXIS: Mapping[str, str] = MappingProxyType({"roll": "RLL", "pitch": "PIT", "yaw": "YAW"})
#: ArduCopter <= 3.3's rate PIDs (``RATE_*``) act on centidegrees/s and output on the ±4500
#: motor scale: their gains are this many times the ``ATC_RAT_*`` ones
RATE_CDEG_SCALE = (18000.0 / math.pi) / 4500.0

#: the rate-controller parameter families, by naming (AC_AttitudeControl's ``ATC_RAT_*``
#: from Copter 3.4; an ArduPlane QuadPlane's VTOL controller ``Q_A_RAT_*``; Copter <= 3.3's
#: ``RATE_*``; "ATC_RAT_FILT" is 3.5-4.0's ``ATC_RAT_*`` with a single ``FILT``)
_RATE_FAMILY = MappingProxyType({"ATC_RAT": "ATC_RAT", "ATC_RAT_FILT": "ATC_RAT",
                                 "Q_A_RAT": "Q_A_RAT", "RATE": "RATE"})
_ANGLE_FAMILY = MappingProxyType({"ATC_RAT": "ATC_ANG", "ATC_RAT_FILT": "ATC_ANG",
                                  "Q_A_RAT": "Q_A_ANG", "RATE": "STB"})


def rate_prefix(axis: str, naming: str = "ATC_RAT") -> str:
    """The prefix of one axis's rate-PID parameters in a naming family.

    Examples
    --------
    >>> rate_prefix("roll"), rate_prefix("yaw", "Q_A_RAT"), rate_prefix("pitch", "RATE")
    ('ATC_RAT_RLL_', 'Q_A_RAT_YAW_', 'RATE_PIT_')
    """
    return f"{_RATE_FAMILY[naming]}_{RATE_AXIS[axis]}_"


def angle_p_param(axis: str, naming: str = "ATC_RAT") -> str:
    """The attitude loop's P around one axis's rate loop, in the same family.

    Examples
    --------
    >>> angle_p_param("roll"), angle_p_param("pitch", "RATE"), angle_p_param("yaw", "Q_A_RAT")
    ('ATC_ANG_RLL_P', 'STB_PIT_P', 'Q_A_ANG_YAW_P')
    """
    return f"{_ANGLE_FAMILY[naming]}_{RATE_AXIS[axis]}_P"


def rate_naming(params: Mapping[str, float], axis: str) -> str:
    """Which rate-controller family a log's parameters use for ``axis``: ``ATC_RAT``
    (also when none is present: the defaults), ``Q_A_RAT`` or ``RATE``.

    Examples
    --------
    >>> rate_naming({"Q_A_RAT_RLL_P": 0.2}, "roll"), rate_naming({"RATE_YAW_P": 0.2}, "yaw")
    ('Q_A_RAT', 'RATE')
    """
    for naming in ("ATC_RAT", "Q_A_RAT", "RATE"):
        pre = rate_prefix(axis, naming)
        if any(k.startswith(pre) for k in params):
            return naming
    return "ATC_RAT"


#: the gyro's low-pass filter, which shapes the rate loop's response as its gains do
GYRO_FILTER_PARAM = "INS_GYRO_FILTER"


#: the harmonic notch's enable switch and centre frequency
#: (libraries/Filter/HarmonicNotchFilter.cpp, INS_HNTCH_ENABLE, INS_HNTCH_FREQ)
HARMONIC_NOTCH_PARAMS = ("INS_HNTCH_ENABLE", "INS_HNTCH_FREQ")
#: the rate PID's target, derivative and error filters (AC_PID, ``_FLTT`` ``_FLTD`` ``_FLTE``)
RATE_FILTER_SUFFIXES = ("FLTT", "FLTD", "FLTE")


def filter_params(params: Mapping[str, float], axis: str) -> list[str]:
    """The parameters that set the cut-offs (Hz) of the filters acting on ``axis``'s gyro
    and rate loop: the gyro filter (``INS_GYRO_FILTER``), the rate PID's
    ``ATC_RAT_<AX>_FLTT/FLTD/FLTE`` and the harmonic notch (``INS_HNTCH_FREQ``, when
    ``INS_HNTCH_ENABLE``).

    Examples
    --------
    >>> filter_params({"INS_HNTCH_ENABLE": 1}, "roll")  # doctest: +NORMALIZE_WHITESPACE
    ['INS_GYRO_FILTER', 'ATC_RAT_RLL_FLTT', 'ATC_RAT_RLL_FLTD', 'ATC_RAT_RLL_FLTE',
     'INS_HNTCH_FREQ']
    >>> filter_params({}, "yaw")[-1]
    'ATC_RAT_YAW_FLTE'
    """
    names = [GYRO_FILTER_PARAM, *(rate_prefix(axis) + s for s in RATE_FILTER_SUFFIXES)]
    enable, freq = HARMONIC_NOTCH_PARAMS
    if params.get(enable, 0) > 0:
        names.append(freq)
    return names


def is_rate_setting(name: str) -> bool:
    """Whether parameter ``name`` shapes the rate loop's response: any rate-PID parameter of
    one of the families (gains, filters, limits), the attitude P around it, or the gyro
    filter. A change of one in flight starts a new setting of the closed-loop response.

    Examples
    --------
    >>> [is_rate_setting(n) for n in ("ATC_RAT_PIT_D", "RATE_YAW_IMAX", "STB_RLL_P",
    ...                                "Q_A_RAT_RLL_FLTT", "INS_GYRO_FILTER", "ATC_ACCEL_R_MAX")]
    [True, True, True, True, True, False]
    """
    if name == GYRO_FILTER_PARAM:
        return True
    return any(name.startswith(rate_prefix(axis, naming)) or name == angle_p_param(axis, naming)
               for naming in _RATE_FAMILY for axis in RATE_AXIS)


def param_file_text(values: Mapping[str, float], header: Sequence[str]) -> str:
    """A parameter file MAVProxy (``param load``) and Mission Planner load: ``#`` comment
    lines, then one ``NAME VALUE`` line per parameter.

    Examples
    --------
    >>> print(param_file_text({"ATC_RAT_RLL_P": 0.1235}, ["from flight.bin"]), end="")
    # from flight.bin
    ATC_RAT_RLL_P 0.1235
    """
    lines = [f"# {h}" for h in header]
    lines += [f"{name} {value:.7g}" for name, value in values.items()]
    return "\n".join(lines) + "\n"
