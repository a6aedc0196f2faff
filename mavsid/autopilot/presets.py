"""Channel presets: which message field is which state and input, per autopilot and log format.

A :class:`Preset` names, for each canonical state (``roll pitch yaw`` in rad, ``p q r`` in
rad/s) and input (``u_roll u_pitch u_yaw`` normalised, ``u_thrust`` 0..1), the message and
field it comes from and the unit the field is in. :func:`choose_preset` picks the first
built-in preset whose messages the log has (most informative first);
:func:`mavsid.autopilot.config.load_presets` reads more from a TOML file. Reading a
channel's samples is :mod:`mavsid.channels`' job, alignment (:mod:`mavsid.align`) puts them
on one grid.

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
``px4-sdlog2``                DataFlash   PX4 sdlog2 .px4log: ATT Roll/Pitch/Yaw (rad) and
                                          RollRate/... (rad/s); ATTC Roll/Pitch/Yaw/Thrust
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
``px4-control-state``         ULog        control_state.q and .roll_rate/... (2016-2017
                                          logs without vehicle_attitude)
``px4-gyro``                  ULog        sensor_gyro.x/y/z only (2016-2017 logs with no
                                          attitude topic)
============================  ==========  =================================================

Presets with ``vehicles`` apply only to logs of those vehicle kinds (from the firmware
banner, e.g. ``ArduPlane V4.3.8`` -> ``plane``). A traditional helicopter (``FRAME_CLASS`` 6)
has no motor mixer to invert: its inputs are the rate controller's normalised outputs
(``ardupilot-rate``'s RATE.ROut/POut/YOut, as ArduCopter logs them for every frame); its
RCOU swashplate servos are not unmixed.

Examples
--------
>>> import numpy as np
>>> from mavsid.data import MessageTable, RawLog, SourceInfo
>>> att = MessageTable("ATTITUDE", {"roll": np.zeros(3)}, time_s=np.arange(3.0))
>>> servo = MessageTable("SERVO_OUTPUT_RAW", {"servo1_raw": np.zeros(3)}, time_s=np.arange(3.0))
>>> log = RawLog(SourceInfo("x.tlog", "tlog", 0), {"ATTITUDE": att, "SERVO_OUTPUT_RAW": servo})
>>> choose_preset(log).name
'mavlink-servo'
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from mavsid.autopilot.ardupilot import PLANE_SURFACE_DEG
from mavsid.autopilot.mixers import MIXERS, Mixer, frame_name, frame_of, matrix_mixer
from mavsid.axes import AXES, INPUT_NAMES, STATE_NAMES
from mavsid.data import RawLog
from mavsid.errors import ConfigError, MissingMessageError

__all__ = [
    "ATTITUDE_PAIRS",
    "DESIRED_CHANNELS",
    "INJECTION_CHANNEL",
    "PRESETS",
    "QUADPLANE",
    "TARGET_CHANNELS",
    "TRANSFORMS",
    "UNIT_TO_SI",
    "Channel",
    "Preset",
    "choose_preset",
    "get_preset",
    "mixer_for",
    "preset_messages",
    "vehicle_kind",
]

#: unit symbol as logs spell it -> factor to SI (rad, rad/s, dimensionless)
UNIT_TO_SI: dict[str, float] = {
    "rad": 1.0, "rad/s": 1.0, "deg": math.pi / 180, "degrees": math.pi / 180,
    "°": math.pi / 180, "degheading": math.pi / 180, "deg/s": math.pi / 180,
    "degrees/s": math.pi / 180,
    "°/s": math.pi / 180, "cdeg": math.pi / 18000, "centidegrees": math.pi / 18000,
    "cdeg/s": math.pi / 18000, "mrad/s": 1e-3, "1": 1.0, "": 1.0, "%": 0.01,
}


#: a channel's transforms: the Euler angle (its index) taken from a quaternion field
TRANSFORMS = {"quat_roll": 0, "quat_pitch": 1, "quat_yaw": 2}


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
        are the outputs whose ``SERVOn_FUNCTION`` carries each axis
        (:data:`mavsid.autopilot.ardupilot.SERVO_FUNCTIONS`)
        normalised through ``SERVOn_MIN/TRIM/MAX`` (:func:`mavsid.channels.servo_inputs`).
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

#: The preset of an ArduPlane QuadPlane's VTOL flight (its multicopter rate controller)
QUADPLANE = "ardupilot-quadplane"

#: built-in presets, most informative first (the order :func:`choose_preset` tries them)
PRESETS: dict[str, Preset] = {
    p.name: p
    for p in (
        Preset(
            "px4-sdlog2", _DF,
            states={"roll": _ch("ATT", "Roll", "rad"), "pitch": _ch("ATT", "Pitch", "rad"),
                    "yaw": _ch("ATT", "Yaw", "rad"), "p": _ch("ATT", "RollRate", "rad/s"),
                    "q": _ch("ATT", "PitchRate", "rad/s"), "r": _ch("ATT", "YawRate", "rad/s")},
            inputs={"u_roll": _ch("ATTC", "Roll"), "u_pitch": _ch("ATTC", "Pitch"),
                    "u_yaw": _ch("ATTC", "Yaw"), "u_thrust": _ch("ATTC", "Thrust", optional=True)},
            description="PX4 sdlog2 .px4log (< 1.5): ATT attitude and rates (rad, rad/s), "
                        "ATTC actuator controls; clock from TIME.StartTime",
        ),
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
        Preset(
            "px4-control-state", ("ulog",),
            states={
                "roll": _ch("control_state", "q", "1", transform="quat_roll"),
                "pitch": _ch("control_state", "q", "1", transform="quat_pitch"),
                "yaw": _ch("control_state", "q", "1", transform="quat_yaw"),
                "p": _ch("control_state", "roll_rate", "rad/s"),
                "q": _ch("control_state", "pitch_rate", "rad/s"),
                "r": _ch("control_state", "yaw_rate", "rad/s"),
            },
            inputs={k: replace(c, optional=True) for k, c in _PX4_AC0.items()},
            description="PX4 2016-2017 without vehicle_attitude: control_state's attitude and "
            "rates",
        ),
        Preset(
            "px4-gyro", ("ulog",),
            states={k: _ch("sensor_gyro", ax, "rad/s") for k, ax in zip("pqr", "xyz", strict=True)},
            description="PX4 2016-2017 logging no attitude: body rates from sensor_gyro "
            "(rotated to the body frame by its driver) only",
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
        _ch("ARSP", f"{px4.capitalize()}RateSP", "rad/s"),  # (PX4 sdlog2)
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
           _ch("vehicle_attitude_setpoint", "q_d", "1", transform=f"quat_{axis}"),
           _ch("ATSP", f"{axis.capitalize()}SP", "rad"))  # (PX4 sdlog2)
    for axis in AXES
}
#: The attitude target and the attitude logged together, per axis (roll, pitch), where a log
#: has them faster than the attitude alignment uses: ArduCopter >= 4.5 ANG.DesRoll/Roll
#: (deg), written with RATE at its rate (ATT stays at 10 Hz).
ATTITUDE_PAIRS: dict[str, tuple[tuple[Channel, Channel], ...]] = {
    axis: ((_ch("ANG", f"Des{axis.capitalize()}", "deg"), _ch("ANG", axis.capitalize(), "deg")),)
    for axis in ("roll", "pitch")
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
        found = matrix_mixer(key)
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
