"""Channel presets: which message field is which state and input, per autopilot and log format.

A :class:`Preset` names, for each canonical state (``roll pitch yaw`` in rad, ``p q r`` in
rad/s) and input (``u_roll u_pitch u_yaw`` normalised, ``u_thrust`` 0..1), the message and
field it comes from and the unit the field is in. :func:`choose_preset` picks the first
built-in preset whose messages the log has (most informative first); :func:`load_presets`
reads more from a TOML file. Alignment (:mod:`mavsid.align`) does the conversion.

Field expressions (``Channel.field``) are tiny:

- ``"ROut"`` a column; ``"xyz[1]"`` element 1 of an array field (``xyz[1]`` column or the
  second column of a 2-D ``xyz``);
- ``"P+I+D"`` the sum of several columns;
- ``"C1|Chan1"`` alternatives: the first one the log has (field names change between
  firmware versions).

Built-in presets (in the order they are tried):

============================  ==========  =================================================
preset                        format      states / inputs
============================  ==========  =================================================
``ardupilot-quadplane``       DataFlash   ArduPlane QuadPlane, VTOL flight: ATT; PIQR/PIQP/
                                          PIQY Act (rad/s), P+I+D+FF (mixer input)
``ardupilot-plane-pid``       DataFlash   ArduPlane only: ATT; PIDR/PIDP/PIDY Act (deg/s),
                                          P+I+D+FF / 45 (surface demand in degrees)
``ardupilot-plane-servo``     DataFlash   ArduPlane only: ATT, IMU gyro; RCOU servos by
                                          SERVOn_FUNCTION through SERVOn_MIN/TRIM/MAX
``ardupilot-rate``            DataFlash   ATT Roll/Pitch/Yaw (deg), RATE R/P/Y (deg/s);
                                          RATE ROut/POut/YOut/AOut
``ardupilot-pid``             DataFlash   ATT, IMU GyrX/Y/Z (rad/s); PIDR/PIDP/PIDY P+I+D+FF
                                          (not for planes)
``ardupilot-rcou``            DataFlash   ATT (+ IMU gyro); RCOU motor PWM through the mixer
``ardupilot-mot``             DataFlash   ATT; MOT Mot1..n PWM (ArduCopter 3.1) via mixer
``ardupilot-att``             DataFlash   ATT only: no inputs (nothing to identify)
``mavlink-servo``             tlog        ATTITUDE (rad, rad/s); SERVO_OUTPUT_RAW PWM, mixer
``mavlink-att``               tlog        ATTITUDE only
``px4-torque``                ULog        vehicle_attitude.q, vehicle_angular_velocity.xyz;
                                          vehicle_torque_setpoint.xyz, -thrust_setpoint.xyz[2]
``px4-actuator-controls``     ULog        vehicle_attitude.q, vehicle_angular_velocity.xyz;
                                          actuator_controls_0.control[0..3]
``px4-legacy``                ULog        vehicle_attitude.q and .rollspeed/...;
                                          actuator_controls_0.control[0..3]
``px4-att``                   ULog        vehicle_attitude.q only
============================  ==========  =================================================

Presets with ``vehicles`` apply only to logs of those vehicle kinds (from the firmware
banner, e.g. ``ArduPlane V4.3.8`` -> ``plane``). A traditional helicopter (``FRAME_CLASS`` 6)
has no motor mixer to invert: its inputs are the rate controller's normalised outputs
(``ardupilot-rate``'s RATE.ROut/POut/YOut, as ArduCopter logs them for every frame); its
RCOU swashplate servos are not unmixed.

Mixers
------
Logs that only carry motor PWMs (``.tlog`` SERVO_OUTPUT_RAW, old RCOU/MOT) give inputs by
inverting the vehicle's motor mixer, as ArduPilot's ``AP_MotorsMatrix`` defines it. Motor
``i`` sits at ``angle_deg[i]`` from the nose (positive to the right) and spins with
``yaw[i]`` (+1 counter-clockwise, -1 clockwise); its roll factor is ``cos(angle + 90°)``,
pitch factor ``cos(angle)``, yaw factor ``yaw[i]`` (some frames give raw roll and pitch
factors instead); roll, pitch and yaw factors are each scaled so the largest is 0.5
(ArduPilot's ``normalise_rpy_factors``). The firmware sets each motor's thrust to
``u_thrust + u_roll·roll_i + u_pitch·pitch_i + u_yaw·yaw_i``; mavsid turns PWM back into
thrust (``MOT_PWM_MIN/MAX``, ``MOT_SPIN_MIN/MAX`` and the ``MOT_THST_EXPO`` thrust curve
from the log's parameters, ArduPilot defaults otherwise) and solves that linear system in
the least-squares sense, so ``u_roll`` etc. are on the scale of RATE.ROut. The frame comes
from ``FRAME_CLASS``/``FRAME_TYPE`` when the log has them (:data:`MIXERS`: every multirotor
matrix of ArduCopter 4.x), quad-X otherwise; motor ``i``'s output from ``SERVOn_FUNCTION``
(:func:`motor_channels`).

TOML presets
------------
::

    [preset.my-quad]
    formats = ["dataflash"]          # optional: formats it applies to
    requires = ["ATT", "RATE"]       # optional: default, every message used below
    mixer = "quad-x"                 # only for PWM inputs (``motors``)
    [preset.my-quad.states]
    roll = { message = "ATT", field = "Roll", unit = "deg" }
    p = { message = "RATE", field = "R", unit = "deg/s" }
    [preset.my-quad.inputs]
    u_roll = { message = "RATE", field = "ROut", scale = 1.0 }

    [mixer.my-hexa]                  # angle_deg and yaw (+1 CCW, -1 CW) per motor
    angle_deg = [90, -90, -30, 150, 30, -150]
    yaw = [-1, 1, -1, 1, 1, -1]
    [mixer.my-y6]                    # or raw roll and pitch factors (add_motor_raw's)
    roll = [-1, -1, 0, 0, 1, 1]
    pitch = [0.5, 0.5, -1, -1, 0.5, 0.5]
    yaw = [-1, 1, -1, 1, -1, 1]

    [preset.my-plane]                # servo PWMs by SERVOn_FUNCTION, for ArduPlane logs only
    vehicles = ["plane"]
    servos = { message = "RCOU", field = "C{i}", unit = "pwm" }
    [preset.my-plane.states]
    roll = { message = "ATT", field = "Roll", unit = "deg" }
    p = { message = "IMU", field = "GyrX", unit = "rad/s" }

Examples
--------
>>> import numpy as np
>>> from mavsid.data import MessageTable, RawLog, SourceInfo
>>> att = MessageTable("ATTITUDE", {"roll": np.zeros(3)}, time_s=np.arange(3.0))
>>> servo = MessageTable("SERVO_OUTPUT_RAW", {"servo1_raw": np.zeros(3)}, time_s=np.arange(3.0))
>>> log = RawLog(SourceInfo("x.tlog", "tlog", 0), {"ATTITUDE": att, "SERVO_OUTPUT_RAW": servo})
>>> choose_preset(log).name
'mavlink-servo'
>>> m = MIXERS["quad-x"]
>>> np.round(m.factors(), 3).tolist()[0]  # motor 1, front right: roll, pitch, yaw factors
[-0.5, 0.5, 0.5]
"""

from __future__ import annotations

import math
import os
import re
import warnings
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from mavsid.data import LOG_FORMATS, MessageTable, RawLog
from mavsid.errors import (
    ConfigError,
    DataQualityWarning,
    MavsidError,
    MissingMessageError,
    finite_number,
    whole_number,
)

__all__ = [
    "DESIRED_CHANNELS",
    "INJECTION_CHANNEL",
    "INPUT_NAMES",
    "MIXERS",
    "PLANE_SURFACE_DEG",
    "PRESETS",
    "QUADPLANE",
    "SERVO_FUNCTIONS",
    "STATE_NAMES",
    "TARGET_CHANNELS",
    "Channel",
    "Mixer",
    "Preset",
    "choose_preset",
    "evaluate",
    "first_of",
    "frame_name",
    "frame_of",
    "get_preset",
    "has_mixer",
    "load_presets",
    "mixer_for",
    "motor_channels",
    "motor_thrusts",
    "preset_messages",
    "pwm_to_thrust",
    "servo_inputs",
    "thrust_curve",
    "to_si",
    "vehicle_kind",
]

#: canonical state names, in FlightData column order, and their SI units
STATE_NAMES: tuple[str, ...] = ("roll", "pitch", "yaw", "p", "q", "r")
STATE_UNITS: dict[str, str] = {
    "roll": "rad", "pitch": "rad", "yaw": "rad", "p": "rad/s", "q": "rad/s", "r": "rad/s"
}
#: canonical input names, in FlightData column order (all dimensionless)
INPUT_NAMES: tuple[str, ...] = ("u_roll", "u_pitch", "u_yaw", "u_thrust")

# unit symbol as logs spell it -> factor to SI (rad, rad/s, dimensionless)
_UNIT_TO_SI: dict[str, float] = {
    "rad": 1.0, "rad/s": 1.0, "deg": math.pi / 180, "degrees": math.pi / 180,
    "°": math.pi / 180, "degheading": math.pi / 180, "deg/s": math.pi / 180,
    "degrees/s": math.pi / 180,
    "°/s": math.pi / 180, "cdeg": math.pi / 18000, "centidegrees": math.pi / 18000,
    "cdeg/s": math.pi / 18000, "mrad/s": 1e-3, "1": 1.0, "": 1.0, "%": 0.01,
}


@dataclass(frozen=True)
class Channel:
    """One canonical signal: where it is in the log and in what unit.

    Parameters
    ----------
    message : str
        Message (topic) name.
    field : str
        Field expression (see the module docstring): ``"R"``, ``"xyz[0]"``, ``"P+I+D"``,
        ``"C1|Chan1"``. For quaternion channels (``transform``), the 4-element field ``q``.
    unit : str
        Unit of the field when the log does not declare one (``deg``, ``deg/s``, ``rad``,
        ``rad/s``, ``cdeg``, ``1`` ...). A unit the log declares wins.
    scale : float
        Extra factor applied after the unit conversion (e.g. -1 for PX4 thrust along -z).
    transform : str
        ``""``, or ``"quat_roll"``/``"quat_pitch"``/``"quat_yaw"``: the Euler angle
        (ZYX, rad) of a Hamilton quaternion ``w x y z``.
    optional : bool
        The preset still applies when this channel is missing.
    instance : int, optional
        For multi-instance messages (a column with unit ``instance``, e.g. DataFlash IMU.I):
        which instance; default the lowest logged.
    """

    message: str
    field: str
    unit: str = "1"
    scale: float = 1.0
    transform: str = ""
    optional: bool = False
    instance: int | None = None


@dataclass(frozen=True)
class Mixer:
    """A multirotor's motor geometry, as ArduPilot's motor matrix defines it.

    Each motor is given either by its direction (``angle_deg``, as ArduPilot's ``add_motor``)
    or by raw roll and pitch factors (``roll``, ``pitch``, as ``add_motor_raw``), and by its
    yaw factor. :meth:`factors` scales each axis's factors so the largest is 0.5, as
    ArduPilot's ``normalise_rpy_factors`` does (roll, pitch and yaw each on its own).

    Parameters
    ----------
    name : str
    angle_deg : tuple of float
        Each motor's direction from the nose, degrees, positive to the right (motor 1 first);
        empty when ``roll`` and ``pitch`` are given.
    yaw : tuple of float
        Each motor's yaw factor: +1 counter-clockwise propeller, -1 clockwise.
    pitch_angle_deg : tuple of float, optional
        The direction its pitch factor is taken from when it differs from ``angle_deg``
        (ArduPilot's V-tail quads).
    roll, pitch : tuple of float, optional
        Raw roll and pitch factors (before scaling), instead of ``angle_deg``.
    """

    name: str
    angle_deg: tuple[float, ...]
    yaw: tuple[float, ...]
    pitch_angle_deg: tuple[float, ...] = ()
    roll: tuple[float, ...] = ()
    pitch: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        n = len(self.yaw)
        raw = bool(self.roll or self.pitch)
        ok = n >= 3 and (
            (raw and not self.angle_deg and not self.pitch_angle_deg
             and len(self.roll) == len(self.pitch) == n)
            or (not raw and len(self.angle_deg) == n
                and len(self.pitch_angle_deg) in (0, n)))
        if not ok:
            raise ConfigError(
                f"mixer {self.name!r}: need the same number (>= 3) of yaw factors and of "
                "angle_deg, or of roll and pitch factors"
            )

    @property
    def n_motors(self) -> int:
        """Number of motors."""
        return len(self.yaw)

    def factors(self) -> np.ndarray:
        """Roll, pitch and yaw factor of each motor, shape ``(n_motors, 3)``, each axis's
        largest magnitude 0.5 (an axis with no factor stays zero)."""
        if self.roll:
            roll, pitch = np.array(self.roll, float), np.array(self.pitch, float)
        else:
            a = np.deg2rad(np.asarray(self.angle_deg, dtype=float))
            b = np.deg2rad(np.asarray(self.pitch_angle_deg or self.angle_deg, dtype=float))
            roll, pitch = np.cos(a + np.pi / 2), np.cos(b)
        f = np.column_stack([roll, pitch, np.asarray(self.yaw, dtype=float)])
        f[np.abs(f) < 1e-9] = 0.0
        top = np.abs(f).max(axis=0)
        return 0.5 * f / np.where(top > 0, top, 1.0)

    def unmix(self, thrust: np.ndarray) -> np.ndarray:
        """Motor thrusts ``(n, n_motors)`` (0..1) -> ``(n, 4)`` u_roll, u_pitch, u_yaw, u_thrust.

        Least-squares inverse of ``thrust_i = u_thrust + f_i · (u_roll, u_pitch, u_yaw)``.

        Examples
        --------
        >>> m = MIXERS["quad-plus"]
        >>> u = np.array([[0.1, -0.05, 0.02, 0.4]])
        >>> motors = u[:, 3:] + u[:, :3] @ m.factors().T
        >>> np.allclose(m.unmix(motors), u)
        True
        """
        mix = np.column_stack([self.factors(), np.ones(self.n_motors)])
        return np.asarray(thrust, dtype=float) @ np.linalg.pinv(mix).T


_CW, _CCW = -1.0, 1.0


def _alternating(n: int, first: float = _CCW) -> tuple[float, ...]:
    return tuple(first if i % 2 == 0 else -first for i in range(n))


#: built-in mixers: ArduPilot's motor matrices (AP_MotorsMatrix, ArduCopter 4.x), motor 1
#: first; named by frame class and FRAME_TYPE (:func:`_ap_mixer`)
MIXERS: dict[str, Mixer] = {
    m.name: m
    for m in (
        Mixer("quad-plus", (90, -90, 0, 180), (_CCW, _CCW, _CW, _CW)),
        Mixer("quad-x", (45, -135, -45, 135), (_CCW, _CCW, _CW, _CW)),
        Mixer("quad-v", (45, -135, -45, 135), (0.7981, 1.0, -0.7981, -1.0)),
        Mixer("quad-h", (45, -135, -45, 135), (_CW, _CW, _CCW, _CCW)),
        Mixer("quad-vtail", (60, 0, -60, 0), (0.0, _CW, 0.0, _CCW), (60, -160, -60, 160)),
        Mixer("quad-atail", (60, 0, -60, 0), (0.0, _CCW, 0.0, _CW), (60, -160, -60, 160)),
        Mixer("quad-plusrev", (90, -90, 0, 180), (_CW, _CW, _CCW, _CCW)),
        Mixer("quad-bf-x", (135, 45, -135, -45), (_CW, _CCW, _CCW, _CW)),
        Mixer("quad-dji-x", (45, -45, -135, 135), _alternating(4)),
        Mixer("quad-cw-x", (45, 135, -135, -45), _alternating(4)),
        Mixer("quad-bf-x-rev", (135, 45, -135, -45), (_CCW, _CW, _CW, _CCW)),
        Mixer("quad-y4", (), (_CCW, _CW, _CCW, _CW), roll=(-1, 0, 0, 1), pitch=(1, -1, -1, 1)),
        Mixer("hexa-plus", (0, 180, -120, 60, -60, 120), (_CW, _CCW, _CW, _CCW, _CCW, _CW)),
        Mixer("hexa-x", (90, -90, -30, 150, 30, -150), (_CW, _CCW, _CW, _CCW, _CCW, _CW)),
        Mixer("hexa-h", (), (_CW, _CCW, _CW, _CCW, _CCW, _CW),
              roll=(-1, 1, 1, -1, -1, 1), pitch=(0, 0, 1, -1, 1, -1)),
        Mixer("hexa-dji-x", (30, -30, -90, -150, 150, 90), _alternating(6)),
        Mixer("hexa-cw-x", (30, 90, 150, -150, -90, -30), _alternating(6)),
        Mixer("octa-plus", (0, 180, 45, 135, -45, -135, -90, 90),
              (_CW, _CW, _CCW, _CCW, _CCW, _CCW, _CW, _CW)),
        Mixer("octa-x", (22.5, -157.5, 67.5, 157.5, -22.5, -112.5, -67.5, 112.5),
              (_CW, _CW, _CCW, _CCW, _CCW, _CCW, _CW, _CW)),
        Mixer("octa-v", (), (_CW, _CW, _CCW, _CCW, _CCW, _CCW, _CW, _CW),
              roll=(0.83, -0.67, 0.67, -0.5, 1.0, -0.83, -1.0, 0.5),
              pitch=(0.34, -0.32, -0.32, -1.0, 1.0, 0.34, 1.0, -1.0)),
        Mixer("octa-h", (), (_CW, _CW, _CCW, _CCW, _CCW, _CCW, _CW, _CW),
              roll=(-1, 1, -1, -1, 1, 1, 1, -1),
              pitch=(1, -1, 0.333, -1, 1, -0.333, 0.333, -0.333)),
        Mixer("octa-i", (), (_CW, _CW, _CCW, _CCW, _CCW, _CCW, _CW, _CW),
              roll=(0.333, -0.333, 1, 0.333, -0.333, -1, -1, 1),
              pitch=(-1, 1, -1, 1, -1, 1, -1, 1)),
        Mixer("octa-dji-x", (22.5, -22.5, -67.5, -112.5, -157.5, 157.5, 112.5, 67.5),
              _alternating(8)),
        Mixer("octa-cw-x", (22.5, 67.5, 112.5, 157.5, -157.5, -112.5, -67.5, -22.5),
              _alternating(8)),
        Mixer("octaquad-plus", (0, -90, 180, 90, -90, 0, 90, 180), _alternating(8)),
        Mixer("octaquad-x", (45, -45, -135, 135, -45, 45, 135, -135), _alternating(8)),
        Mixer("octaquad-v", (45, -45, -135, 135, -45, 45, 135, -135),
              (0.7981, -0.7981, 1.0, -1.0, 0.7981, -0.7981, 1.0, -1.0)),
        Mixer("octaquad-h", (45, -45, -135, 135, -45, 45, 135, -135), _alternating(8, _CW)),
        Mixer("octaquad-cw-x", (45, 45, 135, 135, -135, -135, -45, -45),
              (_CCW, _CW, _CW, _CCW, _CCW, _CW, _CW, _CCW)),
        Mixer("octaquad-bf-x", (135, 45, -135, -45, 135, 45, -135, -45),
              (_CW, _CCW, _CCW, _CW, _CCW, _CW, _CW, _CCW)),
        Mixer("octaquad-bf-x-rev", (135, 45, -135, -45, 135, 45, -135, -45),
              (_CCW, _CW, _CW, _CCW, _CW, _CCW, _CCW, _CW)),
        Mixer("dodecahexa-plus", (0, 0, 60, 60, 120, 120, 180, 180, -120, -120, -60, -60),
              (_CCW, _CW, _CW, _CCW, _CCW, _CW, _CW, _CCW, _CCW, _CW, _CW, _CCW)),
        Mixer("dodecahexa-x", (30, 30, 90, 90, 150, 150, -150, -150, -90, -90, -30, -30),
              (_CCW, _CW, _CW, _CCW, _CCW, _CW, _CW, _CCW, _CCW, _CW, _CW, _CCW)),
        Mixer("y6", (), (_CCW, _CW, _CCW, _CW, _CW, _CCW),
              roll=(-1, 1, 1, 0, -1, 0), pitch=(0.666, 0.666, 0.666, -1.333, 0.666, -1.333)),
        Mixer("y6b", (), _alternating(6, _CW),
              roll=(-1, -1, 0, 0, 1, 1), pitch=(0.5, 0.5, -1, -1, 0.5, 0.5)),
        Mixer("y6f", (), (_CCW, _CCW, _CCW, _CW, _CW, _CW),
              roll=(0, -1, 1, 0, -1, 1), pitch=(-1, 0.5, 0.5, -1, 0.5, 0.5)),
        Mixer("deca-plus", (0, 36, 72, 108, 144, 180, -144, -108, -72, -36), _alternating(10)),
        Mixer("deca-x", (18, 54, 90, 126, 162, -162, -126, -90, -54, -18), _alternating(10)),
    )
}

#: ArduPilot FRAME_TYPE -> the mixer name's suffix (AP_Motors_Class.h's motor_frame_type;
#: 16 and 17, no yaw torque, are QuadPlane frames)
_AP_TYPES = {0: "plus", 1: "x", 2: "v", 3: "h", 4: "vtail", 5: "atail", 6: "plusrev",
             10: "b", 11: "f", 12: "bf-x", 13: "dji-x", 14: "cw-x", 15: "i", 18: "bf-x-rev",
             19: "y4"}
#: ArduPilot FRAME_CLASS -> the mixer name's prefix (the classes with a motor matrix)
_AP_MATRIX_CLASSES = {1: "quad", 2: "hexa", 3: "octa", 4: "octaquad", 5: "y6", 12: "dodecahexa",
                      14: "deca"}


def _ap_mixer(key: tuple[int, int]) -> str | None:
    """The built-in mixer of an ArduPilot ``(FRAME_CLASS, FRAME_TYPE)``; None if none.

    >>> _ap_mixer((2, 1)), _ap_mixer((5, 1)), _ap_mixer((5, 10)), _ap_mixer((14, 14))
    ('hexa-x', 'y6', 'y6b', 'deca-x')
    >>> _ap_mixer((6, 0)) is None, _ap_mixer((1, 15)) is None
    (True, True)
    """
    cls, kind = _AP_MATRIX_CLASSES.get(key[0]), _AP_TYPES.get(key[1], "")
    if cls == "y6":  # Y6B and Y6F; every other type is the default Y6
        return "y6" + kind if kind in ("b", "f") else "y6"
    if cls == "deca" and kind == "cw-x":  # (ArduPilot's deca X and CW-X are one frame)
        kind = "x"
    name = f"{cls}-{kind}" if cls else ""
    return name if name in MIXERS else None


@dataclass(frozen=True)
class Preset:
    """Where a log keeps the states and inputs.

    Parameters
    ----------
    name : str
    formats : tuple of str
        Log formats it applies to (``dataflash``, ``dataflash-text``, ``tlog``, ``ulog``).
    states : Mapping[str, Channel]
        Canonical state name -> channel.
    inputs : Mapping[str, Channel]
        Canonical input name -> channel (empty for attitude-only presets).
    motors : Channel, optional
        PWM outputs: ``field`` is a template with ``{i}`` for the motor number (1-based),
        e.g. ``servo{i}_raw``; inputs are then computed through ``mixer``.
    mixer : str
        Mixer name, or ``"auto"``: from FRAME_CLASS/FRAME_TYPE, quad-X by default.
    requires : tuple of str
        Messages the log must have (with samples) for the preset to be chosen; default
        every non-optional channel's message.
    description : str
    servos : Channel, optional
        Servo PWM outputs (``field`` a template with ``{i}`` for the output number): inputs
        are the outputs whose ``SERVOn_FUNCTION`` carries each axis (:data:`SERVO_FUNCTIONS`)
        normalised through ``SERVOn_MIN/TRIM/MAX`` (:func:`servo_inputs`).
    vehicles : tuple of str
        Vehicle kinds (``RawLog.vehicle``'s first word: ``plane``, ``copter`` ...) the preset
        is for; empty: any.
    not_vehicles : tuple of str
        Vehicle kinds the preset is never chosen for.
    """

    name: str
    formats: tuple[str, ...]
    states: Mapping[str, Channel]
    inputs: Mapping[str, Channel] = field(default_factory=dict)
    motors: Channel | None = None
    mixer: str = "auto"
    requires: tuple[str, ...] = ()
    description: str = ""
    servos: Channel | None = None
    vehicles: tuple[str, ...] = ()
    not_vehicles: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for name in self.states:
            if name not in STATE_NAMES:
                raise ConfigError(f"preset {self.name!r}: unknown state {name!r}")
        for name in self.inputs:
            if name not in INPUT_NAMES:
                raise ConfigError(f"preset {self.name!r}: unknown input {name!r}")
        if not self.states:
            raise ConfigError(f"preset {self.name!r} defines no states")
        if not self.requires:
            chans = [c for c in (*self.states.values(), *self.inputs.values()) if not c.optional]
            chans += [c for c in (self.motors, self.servos) if c is not None]
            object.__setattr__(self, "requires", tuple(dict.fromkeys(c.message for c in chans)))

    @property
    def messages(self) -> tuple[str, ...]:
        """Every message the preset may read."""
        chans = [*self.states.values(), *self.inputs.values()]
        chans += [c for c in (self.motors, self.servos) if c is not None]
        return tuple(dict.fromkeys([*self.requires, *(c.message for c in chans)]))

    def applies_to(self, raw: RawLog) -> bool:
        """True when the log's format and vehicle fit and it has samples of every required
        message."""
        if self.formats and raw.source.format not in self.formats:
            return False
        kind = vehicle_kind(raw)
        if (self.vehicles and kind not in self.vehicles) or kind in self.not_vehicles:
            return False
        return all(m in raw.messages and len(raw.messages[m]) > 0 for m in self.requires)


def vehicle_kind(raw: RawLog) -> str:
    """The log's vehicle kind: ``RawLog.vehicle``'s first word, lower case (``""`` unknown).

    >>> from mavsid.data import RawLog, SourceInfo
    >>> vehicle_kind(RawLog(SourceInfo("x.bin", "dataflash", 0), {}, vehicle="plane"))
    'plane'
    """
    words = (raw.vehicle or "").split()
    return words[0].lower() if words else ""


def _ch(message: str, fld: str, unit: str = "1", **kw: Any) -> Channel:
    return Channel(message, fld, unit, **kw)


_DF = ("dataflash", "dataflash-text")
_ATT = {
    "roll": _ch("ATT", "Roll", "deg"),
    "pitch": _ch("ATT", "Pitch", "deg"),
    "yaw": _ch("ATT", "Yaw", "deg"),
}
_IMU_GYRO = {
    "p": _ch("IMU", "GyrX", "rad/s", optional=True),
    "q": _ch("IMU", "GyrY", "rad/s", optional=True),
    "r": _ch("IMU", "GyrZ", "rad/s", optional=True),
}
_MAV_ATT = {
    "roll": _ch("ATTITUDE", "roll", "rad"),
    "pitch": _ch("ATTITUDE", "pitch", "rad"),
    "yaw": _ch("ATTITUDE", "yaw", "rad"),
    "p": _ch("ATTITUDE", "rollspeed", "rad/s"),
    "q": _ch("ATTITUDE", "pitchspeed", "rad/s"),
    "r": _ch("ATTITUDE", "yawspeed", "rad/s"),
}
_PX4_Q = {
    "roll": _ch("vehicle_attitude", "q", "1", transform="quat_roll"),
    "pitch": _ch("vehicle_attitude", "q", "1", transform="quat_pitch"),
    "yaw": _ch("vehicle_attitude", "q", "1", transform="quat_yaw"),
}
_PX4_AV = {k: _ch("vehicle_angular_velocity", f"xyz[{i}]", "rad/s") for i, k in enumerate("pqr")}
_PX4_AC0 = {
    "u_roll": _ch("actuator_controls_0", "control[0]"),
    "u_pitch": _ch("actuator_controls_0", "control[1]"),
    "u_yaw": _ch("actuator_controls_0", "control[2]"),
    "u_thrust": _ch("actuator_controls_0", "control[3]", optional=True),
}

#: ArduPlane's surface demand (degrees) of a full deflection: its controllers' outputs are
#: centidegrees limited to ±4500 (libraries/APM_Control/AP_RollController.cpp)
PLANE_SURFACE_DEG = 45.0

#: The preset of an ArduPlane QuadPlane's VTOL flight (its multicopter rate controller)
QUADPLANE = "ardupilot-quadplane"

#: built-in presets, most informative first (the order :func:`choose_preset` tries them)
PRESETS: dict[str, Preset] = {
    p.name: p
    for p in (
        Preset(
            QUADPLANE, _DF,
            states={**_ATT, "p": _ch("PIQR", "Act", "rad/s"), "q": _ch("PIQP", "Act", "rad/s"),
                    "r": _ch("PIQY", "Act", "rad/s")},
            inputs={"u_roll": _ch("PIQR", "P+I+D+FF"), "u_pitch": _ch("PIQP", "P+I+D+FF"),
                    "u_yaw": _ch("PIQY", "P+I+D+FF")},
            vehicles=("plane",),
            description="ArduPlane QuadPlane in VTOL flight: ATT; PIQR/PIQP/PIQY Act (rad/s) "
                        "and P+I+D+FF (the multicopter mixer's roll/pitch/yaw input)",
        ),
        Preset(
            "ardupilot-plane-pid", _DF,
            states={**_ATT, "p": _ch("PIDR", "Act", "deg/s"), "q": _ch("PIDP", "Act", "deg/s"),
                    "r": _ch("PIDY", "Act", "deg/s")},
            inputs={
                "u_roll": _ch("PIDR", "P+I+D+FF", scale=1.0 / PLANE_SURFACE_DEG),
                "u_pitch": _ch("PIDP", "P+I+D+FF", scale=1.0 / PLANE_SURFACE_DEG),
                "u_yaw": _ch("PIDY", "P+I+D+FF", scale=1.0 / PLANE_SURFACE_DEG),
            },
            vehicles=("plane",),
            description="ArduPlane: ATT; PIDR/PIDP/PIDY Act (deg/s) and P+I+D+FF (surface "
                        "demand, degrees) / 45: normalised aileron, elevator, rudder",
        ),
        Preset(
            "ardupilot-plane-servo", _DF,
            states={**_ATT, **{k: replace(c, optional=False) for k, c in _IMU_GYRO.items()}},
            servos=_ch("RCOU", "C{i}|Chan{i}|Ch{i}", "pwm"),
            vehicles=("plane",),
            description="ArduPlane: ATT, IMU gyro; RCOU aileron/elevator/rudder/throttle "
                        "servos (SERVOn_FUNCTION) through SERVOn_MIN/TRIM/MAX",
        ),
        Preset(
            "ardupilot-rate", _DF,
            states={
                **_ATT,
                "p": _ch("RATE", "R", "deg/s"),
                "q": _ch("RATE", "P", "deg/s"),
                "r": _ch("RATE", "Y", "deg/s"),
            },
            inputs={
                "u_roll": _ch("RATE", "ROut"),
                "u_pitch": _ch("RATE", "POut"),
                "u_yaw": _ch("RATE", "YOut"),
                "u_thrust": _ch("RATE", "AOut", optional=True),
            },
            description="ArduCopter: ATT angles, RATE gyro rates and rate-controller outputs",
        ),
        Preset(
            "ardupilot-pid", _DF,
            states={**_ATT, **{k: replace(c, optional=False) for k, c in _IMU_GYRO.items()}},
            inputs={
                "u_roll": _ch("PIDR", "P+I+D+FF|P+I+D"),
                "u_pitch": _ch("PIDP", "P+I+D+FF|P+I+D"),
                "u_yaw": _ch("PIDY", "P+I+D+FF|P+I+D"),
            },
            not_vehicles=("plane",),  # (a plane's sums are degrees of surface: its own preset)
            description="older ArduPilot: ATT, IMU gyro, PID term sums as controller outputs",
        ),
        Preset(
            "ardupilot-rcou", _DF,
            states={**_ATT, **_IMU_GYRO},
            motors=_ch("RCOU", "C{i}|Chan{i}|Ch{i}", "pwm"),
            description="ArduPilot: ATT (+ IMU gyro); RCOU motor PWMs through the frame mixer",
        ),
        Preset(
            "ardupilot-mot", _DF,
            states={**_ATT, **_IMU_GYRO},
            motors=_ch("MOT", "Mot{i}", "pwm"),
            description="ArduCopter 3.1: ATT; MOT motor PWMs through the frame mixer",
        ),
        Preset(
            "ardupilot-att", _DF,
            states={**_ATT, **_IMU_GYRO},
            description="ArduPilot attitude only: no controller outputs logged",
        ),
        Preset(
            "mavlink-servo", ("tlog",),
            states=_MAV_ATT,
            motors=_ch("SERVO_OUTPUT_RAW", "servo{i}_raw", "pwm"),
            description="MAVLink: ATTITUDE; SERVO_OUTPUT_RAW motor PWMs through the mixer",
        ),
        Preset("mavlink-att", ("tlog",), states=_MAV_ATT, description="MAVLink ATTITUDE only"),
        Preset(
            "px4-torque", ("ulog",),
            states={**_PX4_Q, **_PX4_AV},
            inputs={
                "u_roll": _ch("vehicle_torque_setpoint", "xyz[0]"),
                "u_pitch": _ch("vehicle_torque_setpoint", "xyz[1]"),
                "u_yaw": _ch("vehicle_torque_setpoint", "xyz[2]"),
                "u_thrust": _ch("vehicle_thrust_setpoint", "xyz[2]", scale=-1.0, optional=True),
            },
            description="PX4 >= 1.14: attitude quaternion, angular velocity, torque setpoint",
        ),
        Preset(
            "px4-actuator-controls", ("ulog",),
            states={**_PX4_Q, **_PX4_AV},
            inputs=_PX4_AC0,
            description="PX4 1.10-1.13: angular velocity, actuator_controls_0",
        ),
        Preset(
            "px4-legacy", ("ulog",),
            states={
                **_PX4_Q,
                "p": _ch("vehicle_attitude", "rollspeed", "rad/s"),
                "q": _ch("vehicle_attitude", "pitchspeed", "rad/s"),
                "r": _ch("vehicle_attitude", "yawspeed", "rad/s"),
            },
            inputs=_PX4_AC0,
            description="PX4 < 1.10: vehicle_attitude rates, actuator_controls_0",
        ),
        Preset(
            "px4-att", ("ulog",),
            states={**_PX4_Q, **{k: replace(c, optional=True) for k, c in _PX4_AV.items()}},
            description="PX4 attitude only: no controller outputs logged",
        ),
    )
}


#: The rate controller's target per body rate (rad/s after conversion), the first one a log
#: has: what the closed-loop twin (:mod:`mavsid.loop`) follows. ArduPilot RATE.RDes/PDes/YDes
#: (deg/s), PIDR/PIDP/PIDY.Tar (rad/s, ArduPilot >= 4.0); PX4 vehicle_rates_setpoint (rad/s);
#: MAVLink ATTITUDE_TARGET body rates (rad/s).
TARGET_CHANNELS: dict[str, tuple[Channel, ...]] = {
    rate: (
        _ch("RATE", f"{des}Des", "deg/s"),
        _ch(pid.replace("PID", "PIQ"), "Tar", "rad/s"),  # (a QuadPlane's VTOL controller)
        _ch(pid, "Tar", "rad/s"),
        _ch("vehicle_rates_setpoint", px4, "rad/s"),
        _ch("ATTITUDE_TARGET", f"body_{px4}_rate", "rad/s"),
    )
    for rate, des, pid, px4 in (("p", "R", "PIDR", "roll"), ("q", "P", "PIDP", "pitch"),
                                ("r", "Y", "PIDY", "yaw"))
}
#: The commanded attitude per axis, where a log has it: from the pilot's sticks in the manual
#: modes, which the gyro's noise does not reach (the instruments of
#: :mod:`mavsid.estimators.instruments`). ArduPilot ATT.DesRoll/DesPitch/DesYaw (deg), logged
#: with the attitude; PX4 vehicle_attitude_setpoint's quaternion ``q_d`` (a ground station's
#: NAV_CONTROLLER_OUTPUT comes at a few Hz: not used). The commanded heading is the integral
#: of the pilot's yaw-rate stick: alignment takes its rate (:func:`mavsid.align.align`).
DESIRED_CHANNELS: dict[str, tuple[Channel, ...]] = {
    axis: (_ch("ATT", f"Des{axis.capitalize()}", "deg"),
           _ch("vehicle_attitude_setpoint", "q_d", "1", transform=f"quat_{axis}"))
    for axis in ("roll", "pitch", "yaw")
}
#: ArduPilot SYSTEMID's injected waveform (added to the mixer input on SID_AXIS 10-12)
INJECTION_CHANNEL = _ch("SIDD", "Targ")


# --------------------------------------------------------------------------- choosing


def choose_preset(raw: RawLog, presets: Mapping[str, Preset] | None = None) -> Preset:
    """The first preset (user presets first, then built-ins) that applies to ``raw``.

    Raises
    ------
    MissingMessageError
        No preset fits: the log has no attitude messages mavsid knows.
    """
    candidates = [*(presets or {}).values(), *PRESETS.values()]
    for preset in candidates:
        if preset.applies_to(raw):
            return preset
    wanted = sorted({p.states["roll"].message for p in candidates if "roll" in p.states})
    raise MissingMessageError(
        " or ".join(wanted) + f" (no channel preset fits this {raw.source.format} log)",
        available=raw.messages,
        path=raw.source.path,
    )


def get_preset(name: str, presets: Mapping[str, Preset] | None = None) -> Preset:
    """A preset by name from ``presets`` or the built-ins.

    Raises
    ------
    ConfigError
        Unknown name.
    """
    table = {**PRESETS, **(presets or {})}
    try:
        return table[name]
    except KeyError:
        raise ConfigError(
            f"unknown channel preset {name!r} (known: {', '.join(sorted(table))})"
        ) from None


def preset_messages(fmt: str | None = None, presets: Iterable[Preset] = ()) -> tuple[str, ...]:
    """Every message any preset for format ``fmt`` (all formats when None) may read.

    Examples
    --------
    >>> "RATE" in preset_messages("dataflash"), "RATE" in preset_messages("ulog")
    (True, False)
    """
    out: dict[str, None] = {}
    for p in (*presets, *PRESETS.values()):
        if fmt is None or not p.formats or fmt in p.formats:
            out.update(dict.fromkeys(p.messages))
    return tuple(out)


#: Motor count -> ArduPilot FRAME_CLASS (for logs older than FRAME_CLASS, ArduCopter < 3.5,
#: whose frame class was the firmware build).
_CLASS_BY_MOTORS = {4: 1, 6: 2, 8: 3}


def frame_of(params: Mapping[str, float], n_motors: int | None = None
             ) -> tuple[tuple[int, int], str]:
    """ArduPilot ``(FRAME_CLASS, FRAME_TYPE)`` and where it came from.

    ArduCopter >= 3.5 logs ``FRAME_CLASS``/``FRAME_TYPE``; 3.2-3.4 only ``FRAME`` (the
    orientation, numbered as ``FRAME_TYPE`` is: 0 plus, 1 X, ...), the class being the build
    (quad, hexa, octa): then taken from the motor outputs logged (``n_motors``), else quad.

    Examples
    --------
    >>> frame_of({"FRAME_CLASS": 2, "FRAME_TYPE": 0})
    ((2, 0), 'FRAME_CLASS/FRAME_TYPE')
    >>> frame_of({"FRAME": 0}, n_motors=6)
    ((2, 0), 'FRAME (ArduCopter < 3.5) and 6 motor outputs')
    >>> frame_of({})
    ((1, 1), 'no frame parameters (FRAME_CLASS/FRAME_TYPE or FRAME): quad-X assumed')
    """
    cls_p, type_p, frame_p = (_whole(params, k) for k in ("FRAME_CLASS", "FRAME_TYPE", "FRAME"))
    if cls_p is not None:
        if type_p is None and "FRAME_TYPE" in params:
            return (cls_p, 1), "FRAME_CLASS (FRAME_TYPE not a number: X assumed)"
        return (cls_p, 1 if type_p is None else type_p), "FRAME_CLASS/FRAME_TYPE"
    if frame_p is not None:
        cls = _CLASS_BY_MOTORS.get(n_motors or 0)
        where = (f"FRAME (ArduCopter < 3.5) and {n_motors} motor outputs" if cls else
                 "FRAME (ArduCopter < 3.5), class unknown: quad assumed")
        return (cls or 1, frame_p), where
    if {"FRAME_CLASS", "FRAME_TYPE", "FRAME"} & set(params):
        return (1, 1), "frame parameters that are not numbers (a damaged log): quad-X assumed"
    return (1, 1), "no frame parameters (FRAME_CLASS/FRAME_TYPE or FRAME): quad-X assumed"


def _whole(params: Mapping[str, float], key: str) -> int | None:
    """A parameter as a whole number; None when absent or not a finite number (a damaged
    log's).

    >>> _whole({"A": 2.0}, "A"), _whole({"A": float("nan")}, "A"), _whole({}, "A")
    (2, None, None)
    """
    value = params.get(key)
    try:
        return int(value) if value is not None and math.isfinite(value) else None
    except (TypeError, OverflowError):
        return None


#: ArduPilot FRAME_CLASS names (for messages about frames without a mixer here)
_FRAME_CLASSES = {1: "quad", 2: "hexa", 3: "octa", 4: "octaquad", 5: "Y6", 6: "heli",
                  7: "tri", 8: "single copter", 9: "coax copter", 10: "bicopter",
                  11: "dual heli", 12: "dodecahexa", 13: "heli quad", 14: "deca",
                  15: "scripting matrix", 16: "6-DoF scripting", 17: "dynamic scripting"}


def frame_name(key: tuple[int, int]) -> str:
    """A frame class's name, e.g. ``heli`` for FRAME_CLASS 6.

    >>> frame_name((6, 0)), frame_name((1, 16))
    ('heli', 'quad, type 16')
    """
    cls = _FRAME_CLASSES.get(key[0], f"class {key[0]}")
    return cls if key[0] not in _AP_MATRIX_CLASSES else f"{cls}, type {key[1]}"


def has_mixer(params: Mapping[str, float], n_motors: int | None = None) -> bool:
    """Whether the logged frame (:func:`frame_of`) has a motor mixer here.

    >>> has_mixer({"FRAME_CLASS": 1, "FRAME_TYPE": 1}), has_mixer({"FRAME_CLASS": 6})
    (True, False)
    """
    return _ap_mixer(frame_of(params, n_motors)[0]) is not None


def mixer_for(preset: Preset, params: Mapping[str, float], mixers: Mapping[str, Mixer] = MIXERS,
              n_motors: int | None = None) -> Mixer:
    """The mixer a preset uses: its own, else from the frame parameters (:func:`frame_of`),
    else quad-X.

    Examples
    --------
    >>> mixer_for(PRESETS["mavlink-servo"], {"FRAME_CLASS": 1, "FRAME_TYPE": 0}).name
    'quad-plus'
    >>> mixer_for(PRESETS["ardupilot-rcou"], {"FRAME": 1}).name   # ArduCopter 3.3
    'quad-x'
    """
    name = preset.mixer
    if name == "auto":
        key, _ = frame_of(params, n_motors)
        found = _ap_mixer(key)
        if found is None:
            raise ConfigError(f"preset {preset.name!r}: no mixer for FRAME_CLASS {key[0]} "
                              f"FRAME_TYPE {key[1]} ({frame_name(key)}); known frames: "
                              + ", ".join(sorted(MIXERS)))
        name = found
    try:
        return mixers[name]
    except KeyError:
        raise ConfigError(
            f"preset {preset.name!r}: unknown mixer {name!r} (known: {', '.join(sorted(mixers))})"
        ) from None


# --------------------------------------------------------------------------- evaluation

_INDEXED = re.compile(r"^(\w+)\[(\d+)\]$")


def _column(table: MessageTable, name: str) -> np.ndarray | None:
    """One column (``name`` or ``name[i]``) as float64, scaled by the declared multiplier."""
    if name in table.columns:
        col = np.asarray(table.columns[name])
        mult = table.multipliers.get(name, 1.0)
    else:
        m = _INDEXED.match(name)
        if not m or m.group(1) not in table.columns:
            return None
        col = np.asarray(table.columns[m.group(1)])
        if col.ndim != 2 or int(m.group(2)) >= col.shape[1]:
            return None
        col = col[:, int(m.group(2))]
        mult = table.multipliers.get(m.group(1), 1.0)
    if col.dtype.kind not in "biuf":
        return None
    out = col.astype(np.float64)
    return out * mult if mult not in (None, 1.0) else out


def _resolve(table: MessageTable, expr: str) -> tuple[np.ndarray, str] | None:
    """Evaluate a field expression; returns the values and the first column's name."""
    for alternative in expr.split("|"):
        parts = [p.strip() for p in alternative.split("+")]
        cols = [c for c in (_column(table, p) for p in parts) if c is not None]
        if len(cols) == len(parts):
            return np.sum(cols, axis=0), parts[0]
    return None


def _quaternion(table: MessageTable, fld: str) -> np.ndarray | None:
    col = table.columns.get(fld)
    if col is not None and np.ndim(col) == 2 and np.shape(col)[1] == 4:
        return np.asarray(col, dtype=np.float64)
    parts = [_column(table, f"{fld}[{i}]") for i in range(4)]
    if any(p is None for p in parts):
        return None
    return np.column_stack(parts)  # type: ignore[arg-type]


def quat_to_euler(q: np.ndarray) -> np.ndarray:
    """Hamilton quaternions ``(n, 4)`` (w, x, y, z) -> ZYX Euler angles ``(n, 3)`` in rad.

    The closed form, not :class:`scipy.spatial.transform.Rotation`: the same angles (to
    1e-13 rad; tests/test_channels.py checks it against scipy) 7x faster on a million rows.

    Examples
    --------
    >>> a = 0.3
    >>> quat_to_euler(np.array([[np.cos(a / 2), np.sin(a / 2), 0, 0]])).round(6).tolist()
    [[0.3, 0.0, 0.0]]
    """
    q = np.asarray(q, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):  # a zero quaternion gives NaN angles
        q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.column_stack([roll, pitch, yaw])


def to_si(values: np.ndarray, unit: str, what: str = "") -> np.ndarray:
    """Convert ``values`` in ``unit`` (as a log spells it) to rad, rad/s or dimensionless.

    Raises
    ------
    ConfigError
        Unknown unit.

    Examples
    --------
    >>> to_si(np.array([180.0]), "deg").tolist()
    [3.141592653589793]
    """
    try:
        return values * _UNIT_TO_SI[unit.strip()]
    except KeyError:
        raise ConfigError(f"{what or 'channel'}: unknown unit {unit!r}") from None


def _rows(table: MessageTable, instance: int | None = None) -> np.ndarray | None:
    """Rows of one source: one instance of a multi-instance message (the column whose unit
    is ``instance``; lowest unless given) and, in a .tlog, the system id sending most.
    None when all rows qualify."""
    keep = np.ones(len(table), dtype=bool)
    for name in table.fields:
        if table.unit(name) == "instance":
            col = np.asarray(table.columns[name])
            if col.size:
                keep &= col == (col.min() if instance is None else instance)
            break
    if "_sysid" in table.columns:
        ids = np.asarray(table.columns["_sysid"])
        if ids.size and np.any(ids != ids[0]):
            vals, counts = np.unique(ids, return_counts=True)
            keep &= ids == vals[np.argmax(counts)]
    return None if keep.all() else keep


def source_text(source: object, unit_from: object) -> str:
    """``RATE.R (deg/s, declared by the log)``: a channel's source and the unit it was read in
    (not repeated when the source already says it was inferred).

    >>> source_text("RATE.R", "deg/s, declared by the log")
    'RATE.R (deg/s, declared by the log)'
    >>> source_text("RATE.R (centideg/s, inferred)", "centideg/s, inferred")
    'RATE.R (centideg/s, inferred)'
    """
    text, unit = str(source), str(unit_from or "")
    return f"{text} ({unit})" if unit and unit not in text else text


def _unit_of(table: MessageTable, first: str, channel: Channel) -> tuple[str, str]:
    """``(unit, origin)`` of a channel's field: the log's declared unit when it has one
    mavsid knows, else the preset's."""
    declared = table.unit(first)
    if declared is not None and declared.strip() in _UNIT_TO_SI:
        return declared.strip(), "declared by the log"
    return channel.unit, "the preset's unit: the log declares none"


def unit_origin(raw: RawLog, channel: Channel) -> str:
    """The unit a channel's field is read in and where that unit came from, for people.

    Examples
    --------
    >>> from mavsid.data import MessageTable, RawLog, SourceInfo
    >>> t = MessageTable("RATE", {"R": np.zeros(2)}, time_s=np.arange(2.0), units={"R": "deg/s"})
    >>> raw = RawLog(SourceInfo("x.bin", "dataflash", 0), {"RATE": t})
    >>> unit_origin(raw, Channel("RATE", "R", unit="deg/s"))
    'deg/s, declared by the log'
    >>> bare = MessageTable("RATE", {"R": np.zeros(2)}, time_s=np.arange(2.0))
    >>> unit_origin(RawLog(SourceInfo("x.bin", "dataflash", 0), {"RATE": bare}),
    ...             Channel("RATE", "R", unit="deg/s"))
    "deg/s, the preset's unit: the log declares none"
    """
    if channel.transform.startswith("quat_"):
        return "rad, from the attitude quaternion"
    table = raw[channel.message]
    for alternative in channel.field.split("|"):
        parts = [p.strip() for p in alternative.split("+")]
        if all(_column(table, p) is not None for p in parts):
            return ", ".join(_unit_of(table, parts[0], channel))
    return ", ".join(_unit_of(table, "", channel))


def first_of(raw: RawLog, channels: Iterable[Channel], what: str = ""
             ) -> tuple[Channel, np.ndarray, np.ndarray] | None:
    """The first of ``channels`` the log has (the message with records, the field), with
    its :func:`evaluate` ``(time_s, values)``; None when it has none of them."""
    for ch in channels:
        if ch.message not in raw.messages or not len(raw.messages[ch.message]):
            continue
        try:
            t, v = evaluate(raw, ch, what)
        except MavsidError:
            continue
        if t.size >= 2:
            return ch, t, v
    return None


#: a channel's transforms: the Euler angle (its index) taken from a quaternion field
_TRANSFORMS = {"quat_roll": 0, "quat_pitch": 1, "quat_yaw": 2}


def evaluate(raw: RawLog, channel: Channel, what: str = "") -> tuple[np.ndarray, np.ndarray]:
    """A channel's samples in SI units: ``(time_s, values)`` in record order, NaN-free.

    Record order is time order except after a reboot or in concatenated logs (time jumps
    back) and for slightly unordered records; :func:`mavsid.align.align` deals with both.

    The unit the log declares for the field wins over ``channel.unit``.

    Raises
    ------
    MissingMessageError
        The message or field is absent.
    """
    table = raw[channel.message]
    if channel.transform.startswith("quat_"):
        q = _quaternion(table, channel.field)
        if q is None:
            raise MissingMessageError(f"{channel.message}.{channel.field}", table.columns, "field")
        axis = _TRANSFORMS[channel.transform]
        values = quat_to_euler(q)[:, axis]
    else:
        got = _resolve(table, channel.field)
        if got is None:
            raise MissingMessageError(
                f"{channel.message}.{channel.field}", available=table.columns, what="field"
            )
        values, first = got
        values = to_si(values, _unit_of(table, first, channel)[0], what)
    values = values * channel.scale
    t = np.asarray(table.time_s, dtype=np.float64)
    ok = np.isfinite(t) & np.isfinite(values)
    rows = _rows(table, channel.instance)
    if rows is not None:
        ok &= rows
    return t[ok], values[ok]


#: ArduPilot's defaults for a multirotor's spin range and thrust-curve exponent
#: (AP_Motors_Thrust_Linearization: MOT_SPIN_MIN 0.15, MOT_SPIN_MAX 0.95, MOT_THST_EXPO 0.65)
_SPIN_DEFAULT = (0.15, 0.95)
_EXPO_DEFAULT = 0.65
#: the widest PWM range (µs) an output's end points can stand for
_PWM_SPAN = (1.0, 3000.0)


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
    elif not _PWM_SPAN[0] <= lo < hi <= _PWM_SPAN[1]:
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


#: Canonical input -> ArduPilot servo function (``SERVOn_FUNCTION``,
#: SRV_Channel::Aux_servo_function_t), its name, and whether it is an angle output
#: (-1..1 about ``SERVOn_TRIM``) rather than a range (0..1 from ``SERVOn_MIN``).
SERVO_FUNCTIONS: dict[str, tuple[int, str, bool]] = {
    "u_roll": (4, "aileron", True),
    "u_pitch": (19, "elevator", True),
    "u_yaw": (21, "rudder", True),
    "u_thrust": (70, "throttle", False),
}


def servo_inputs(raw: RawLog, preset: Preset) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    """``(input, source, time_s, values)`` per canonical input from servo PWMs.

    Each axis's output is the lowest-numbered servo whose ``SERVOn_FUNCTION`` is the axis's
    function (:data:`SERVO_FUNCTIONS`). An angle output is normalised as ArduPilot's
    SRV_Channel maps it (``pwm_from_angle``): ``(pwm - TRIM) / (MAX - TRIM)`` above trim,
    ``(pwm - TRIM) / (TRIM - MIN)`` below, negated when ``SERVOn_REVERSED``; the throttle as a
    range, ``(pwm - MIN) / (MAX - MIN)``. A PWM of 0 (output not yet set) is no sample.

    Raises
    ------
    MissingMessageError
        No servo carries roll, pitch or yaw (``SERVOn_FUNCTION``), or its PWM field is absent.
    ConfigError
        An angle servo's ``SERVOn_MIN/TRIM/MAX`` are not increasing PWMs (a throttle's need only
        ``MIN < MAX``; one without is left out).

    Examples
    --------
    >>> from mavsid.data import MessageTable, RawLog, SourceInfo
    >>> t = np.arange(3.0)
    >>> pwm = {"C1": np.array([1500.0, 1900, 1300]), "C2": np.full(3, 1500.0),
    ...        "C4": np.full(3, 1500.0)}
    >>> params = {"SERVO1_FUNCTION": 4, "SERVO2_FUNCTION": 19, "SERVO4_FUNCTION": 21,
    ...           "SERVO1_MIN": 1100, "SERVO1_TRIM": 1500, "SERVO1_MAX": 1900}
    >>> raw = RawLog(SourceInfo("p.bin", "dataflash", 0), {"RCOU": MessageTable("RCOU", pwm, t)},
    ...              params=params, vehicle="plane")
    >>> got = servo_inputs(raw, PRESETS["ardupilot-plane-servo"])
    >>> got[0][1], got[0][3].tolist()
    ('RCOU.C1 (aileron, SERVO1)', [0.0, 1.0, -0.5])
    """
    assert preset.servos is not None
    ch, params = preset.servos, raw.params
    table = raw[ch.message]
    by_function: dict[int, int] = {}
    for key, value in sorted(params.items()):
        m = re.fullmatch(r"SERVO(\d+)_FUNCTION", key)
        if m and np.isfinite(value):
            number = int(m.group(1))
            by_function[int(value)] = min(number, by_function.get(int(value), number))
    t_all = np.asarray(table.time_s, dtype=np.float64)
    out = []
    for name, (fn, label, angle) in SERVO_FUNCTIONS.items():
        n = by_function.get(fn)
        if n is None:
            if name == "u_thrust":
                continue
            raise MissingMessageError(
                f"SERVOn_FUNCTION {fn} ({label})", what="parameter", path=raw.source.path,
                available=[k for k in params if re.fullmatch(r"SERVO\d+_FUNCTION", k)])
        expr = ch.field.replace("{i}", str(n))
        got = _resolve(table, expr)
        if got is None:
            raise MissingMessageError(f"{ch.message}.{expr} ({label}, SERVO{n})",
                                      available=table.columns, what="field")
        pwm, first = got
        lo = float(params.get(f"SERVO{n}_MIN", 1100.0))
        trim = float(params.get(f"SERVO{n}_TRIM", 1500.0))
        hi = float(params.get(f"SERVO{n}_MAX", 1900.0))
        # (a range output's trim is usually its minimum: a throttle idles there)
        if not (hi > trim > lo if angle else hi > lo) or not (
                _PWM_SPAN[0] <= lo and hi <= _PWM_SPAN[1]):
            if name == "u_thrust":  # (optional: the attitude axes do not need it)
                continue
            raise ConfigError(f"{raw.source.path}: SERVO{n}_MIN/TRIM/MAX {lo:g}/{trim:g}/{hi:g} "
                              f"are not increasing PWMs within {_PWM_SPAN[0]:g}..{_PWM_SPAN[1]:g} "
                              f"us: the {label} output cannot be normalised")
        rev = bool(params.get(f"SERVO{n}_REVERSED", 0.0))
        if angle:
            v = np.where(pwm >= trim, (pwm - trim) / (hi - trim), (pwm - trim) / (trim - lo))
            v = -v if rev else v
        else:
            v = (pwm - lo) / (hi - lo)
            v = 1.0 - v if rev else v
        ok = np.isfinite(t_all) & np.isfinite(pwm) & (pwm > 0)
        out.append((name, f"{ch.message}.{first} ({label}, SERVO{n})", t_all[ok], v[ok]))
    return out


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
        fn = _whole(params, key) if m else None
        if m and fn is not None:
            n = int(m.group(1))
            outputs[fn] = min(n, outputs.get(fn, n))
    functions = [33 + i if i < 8 else 82 + i - 8 for i in range(n_motors)]
    if not set(outputs) & {*range(33, 41), *range(82, 86)}:  # (none, or not all downloaded)
        return list(range(1, n_motors + 1))
    got = [outputs.get(fn) for fn in functions]
    missing = [i for i, o in enumerate(got) if o is None]
    if missing:
        raise ConfigError(
            f"no output carries motor(s) {', '.join(str(i + 1) for i in missing)} of "
            f"{n_motors} (SERVOn_FUNCTION {', '.join(str(functions[i]) for i in missing)}): "
            "the frame (FRAME_CLASS/FRAME_TYPE) and the outputs disagree")
    return [int(o) for o in got if o is not None]


def motor_thrusts(raw: RawLog, preset: Preset, mixer: Mixer) -> tuple[np.ndarray, np.ndarray]:
    """``(time_s, thrust)`` of each motor, shape ``(n, n_motors)``, from the PWM channel, in
    record order."""
    assert preset.motors is not None
    ch = preset.motors
    table = raw[ch.message]
    cols = []
    for i, out in enumerate(motor_channels(raw.params, mixer.n_motors), start=1):
        got = _resolve(table, ch.field.replace("{i}", str(out)))
        if got is None:
            raise MissingMessageError(
                f"{ch.message}.{ch.field.replace('{i}', str(out))} (motor {i} of {mixer.name})",
                available=table.columns, what="field",
            )
        cols.append(got[0])
    pwm = np.column_stack(cols)
    t = np.asarray(table.time_s, dtype=np.float64)
    ok = np.isfinite(t) & np.all(np.isfinite(pwm), axis=1)
    rows = _rows(table, ch.instance)
    if rows is not None:
        ok &= rows
    notes = thrust_curve(raw.params)[1]
    if notes:
        warnings.warn(f"{raw.source.path}: motor parameters that are no motor's (damaged?): "
                      f"{'; '.join(notes)}", DataQualityWarning, stacklevel=3)
    return t[ok], pwm_to_thrust(pwm[ok], raw.params)


# --------------------------------------------------------------------------- TOML


def _read_toml(path: str | os.PathLike[str]) -> dict[str, Any]:
    import tomllib

    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot open: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None


def _strings(spec: Mapping[str, Any], key: str, where: str,
             known: Iterable[str] | None = None) -> tuple[str, ...]:
    """``spec[key]`` (absent: empty), a list of strings, each one of ``known`` if given."""
    value = spec.get(key, [])
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ConfigError(f"{where}: {key} must be a list of strings")
    if known is not None:
        known = tuple(known)
        wrong = [v for v in value if v not in known]
        if wrong:
            raise ConfigError(f"{where}: unknown {key} {', '.join(map(repr, wrong))} (known: "
                              f"{', '.join(known)})")
    return tuple(value)


def _table(spec: Mapping[str, Any], key: str, where: str) -> Mapping[str, Any]:
    """``spec[key]`` (absent: empty), a TOML table."""
    value = spec.get(key, {})
    if not isinstance(value, Mapping):
        raise ConfigError(f"{where}: {key} must be a table")
    return value


def _channel_from(spec: Any, where: str, pwm: bool = False) -> Channel:
    """A TOML channel ``{ message, field, unit, scale, transform, optional, instance }``, every
    value checked; ``pwm``: motor or servo outputs (unit ``pwm``, the only unit they take,
    and the only channels that take it)."""
    if not isinstance(spec, Mapping) or "message" not in spec or "field" not in spec:
        raise ConfigError(f"{where}: needs a table with 'message' and 'field'")
    unknown = set(spec) - {"message", "field", "unit", "scale", "transform", "optional",
                           "instance"}
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}")
    for key in ("message", "field"):
        if not isinstance(spec[key], str) or not spec[key].strip():
            raise ConfigError(f"{where}: {key} must be a non-empty string")
    unit = spec.get("unit", "pwm" if pwm else "1")
    if not isinstance(unit, str) or (unit not in _UNIT_TO_SI and unit != "pwm"):
        raise ConfigError(f"{where}: unknown unit {unit!r}")
    if (unit == "pwm") is not pwm:
        raise ConfigError(f"{where}: unit {unit!r}: " + (
            "motor and servo outputs are PWM (unit 'pwm')" if pwm else
            "only motors and servos take PWM (unit 'pwm')"))
    scale = spec.get("scale", 1.0)
    if not finite_number(scale) or scale == 0:
        raise ConfigError(f"{where}: scale must be a finite number other than 0")
    transform = spec.get("transform", "")
    if transform not in ("", *_TRANSFORMS):
        raise ConfigError(f"{where}: unknown transform {transform!r} (known: "
                          f"{', '.join(_TRANSFORMS)})")
    optional = spec.get("optional", False)
    if not isinstance(optional, bool):
        raise ConfigError(f"{where}: optional must be true or false")
    inst = spec.get("instance")
    if inst is not None and not (whole_number(inst) and inst >= 0):
        raise ConfigError(f"{where}: instance must be a whole number >= 0")
    return Channel(spec["message"], spec["field"], unit, float(scale), transform, optional, inst)


#: the keys of a TOML mixer (each a list, one number per motor, motor 1 first)
_MIXER_KEYS = ("angle_deg", "pitch_angle_deg", "roll", "pitch", "yaw")


def _mixer_from(name: str, spec: Any, path: str | os.PathLike[str]) -> Mixer:
    """A TOML ``[mixer.NAME]`` table as a :class:`Mixer`: motor directions (``angle_deg``,
    optionally ``pitch_angle_deg``) or raw ``roll`` and ``pitch`` factors, and ``yaw``; each a
    list of finite numbers; the motors must set each axis they have factors for (a
    tricopter's yaw, all zeros, is its servo's) and the thrust apart.

    Examples
    --------
    >>> m = _mixer_from("t", {"roll": [-1, 1, 0], "pitch": [0.5, 0.5, -1], "yaw": [0, 0, 0]}, "x")
    >>> np.round(m.factors(), 2).tolist()[2]
    [0.0, -0.5, 0.0]
    >>> _mixer_from("t", {"angle_deg": [60, -60, 180], "yaw": [0, 0, 1]}, "f.toml")
    ... # doctest: +ELLIPSIS
    Traceback (most recent call last):
    mavsid.errors.ConfigError: f.toml: mixer 't' cannot set roll, pitch, yaw and thrust ...
    """
    where = f"{path}: mixer {name!r}"
    if not isinstance(spec, Mapping):
        raise ConfigError(f"{where}: must be a table")
    unknown = set(spec) - set(_MIXER_KEYS)
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(sorted(unknown))} "
                          f"(known: {', '.join(_MIXER_KEYS)})")
    lists: dict[str, tuple[float, ...]] = {}
    for key in _MIXER_KEYS:
        value = spec.get(key, [])
        # (a float is a number: TOML's nan and inf are refused as not finite, below)
        if not isinstance(value, list) or not all(finite_number(v) or isinstance(v, float)
                                                  for v in value):
            raise ConfigError(f"{where}: {key} must be a list of numbers, one per motor")
        lists[key] = tuple(float(v) for v in value)
        if not all(math.isfinite(v) for v in lists[key]):
            raise ConfigError(f"{where}: {key} holds a value that is not a finite number")
    try:
        mixer = Mixer(name, lists["angle_deg"], lists["yaw"], lists["pitch_angle_deg"],
                      lists["roll"], lists["pitch"])
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    factors = mixer.factors()
    used = [k for k in range(3) if factors[:, k].any()]
    rank = int(np.linalg.matrix_rank(np.column_stack([factors[:, used],
                                                      np.ones(mixer.n_motors)])))
    if rank < len(used) + 1:
        axes = ", ".join(("roll", "pitch", "yaw")[k] for k in used)
        raise ConfigError(f"{where} cannot set {axes} and thrust apart (rank {rank} of "
                          f"{len(used) + 1})")
    return mixer


def load_presets(path: str | os.PathLike[str]) -> tuple[dict[str, Preset], dict[str, Mixer]]:
    """Read user presets and mixers from a TOML file (format in the module docstring).

    Returns
    -------
    presets, mixers : dict
        By name; pass ``presets`` to :func:`choose_preset` / :func:`mavsid.align.align`.

    Raises
    ------
    ConfigError
        Unreadable file, invalid TOML, unknown keys, names or units.
    """
    doc = _read_toml(path)
    unknown = set(doc) - {"preset", "mixer"}
    if unknown:
        raise ConfigError(f"{path}: unknown table(s) {', '.join(sorted(unknown))}")
    for table in ("preset", "mixer"):
        if not isinstance(doc.get(table, {}), Mapping):
            raise ConfigError(f"{path}: {table} must be a table ([{table}.NAME])")
    mixers = {name: _mixer_from(name, spec, path) for name, spec in doc.get("mixer", {}).items()}
    presets: dict[str, Preset] = {}
    for name, spec in doc.get("preset", {}).items():
        where = f"{path}: preset {name!r}"
        if not isinstance(spec, Mapping):
            raise ConfigError(f"{where}: must be a table")
        unknown = set(spec) - {
            "formats", "states", "inputs", "motors", "mixer", "requires", "description",
            "servos", "vehicles", "not_vehicles",
        }
        if unknown:
            raise ConfigError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}")
        states = {k: _channel_from(v, f"{where} state {k}") for k, v in
                  _table(spec, "states", where).items()}
        inputs = {k: _channel_from(v, f"{where} input {k}") for k, v in
                  _table(spec, "inputs", where).items()}
        if "motors" in spec and "servos" in spec:
            raise ConfigError(f"{where}: motors (through a mixer) or servos, not both")
        motors = (_channel_from(spec["motors"], f"{where} motors", pwm=True)
                  if "motors" in spec else None)
        servos = (_channel_from(spec["servos"], f"{where} servos", pwm=True)
                  if "servos" in spec else None)
        mixer = spec.get("mixer", "auto")
        if not isinstance(mixer, str) or (mixer != "auto" and mixer not in mixers
                                          and mixer not in MIXERS):
            raise ConfigError(f"{where}: unknown mixer {mixer!r}")
        description = spec.get("description", "")
        if not isinstance(description, str):
            raise ConfigError(f"{where}: description must be a string")
        formats = _strings(spec, "formats", where, LOG_FORMATS)
        requires = _strings(spec, "requires", where)
        vehicles, not_vehicles = (tuple(v.lower() for v in _strings(spec, key, where))
                                  for key in ("vehicles", "not_vehicles"))
        try:
            presets[name] = Preset(name, formats, states, inputs, motors, mixer, requires,
                                   description, servos, vehicles, not_vehicles)
        except ConfigError as exc:
            raise ConfigError(f"{path}: {exc}") from None
    return presets, mixers
