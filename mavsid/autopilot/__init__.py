"""Everything mavsid knows about the autopilots' firmware, in one package.

Adding a firmware (or a firmware version's new names) touches only this package:

=============================  ==========================================================
module                         holds
=============================  ==========================================================
:mod:`~.ardupilot`             ArduPilot: SYSTEMID (``SID_AXIS`` numbering, SIDS fields,
                               SID_* parameters), ``SERVOn_FUNCTION`` outputs, the motor
                               thrust curve (``MOT_*``), logging and flying advice
:mod:`~.px4`                   PX4: logger profile (``SDLOG_PROFILE``), flying advice
:mod:`~.modes`                 flight-mode numbers and names (ArduPilot, PX4)
:mod:`~.presets`               channel presets: which message field is which state and
                               input, per autopilot, version and log format
:mod:`~.mixers`                multirotor motor geometry (``FRAME_CLASS``/``FRAME_TYPE``)
:mod:`~.config`                user presets and mixers from a TOML file
=============================  ==========================================================

The functions here choose the autopilot from a *platform text*: the flight's autopilot,
vehicle and firmware banner, with ``quadplane`` after them for a QuadPlane's VTOL flight
(``"ardupilot plane ArduPlane V4.3.8 (abc) quadplane"``, ``"PX4 v1.14.0"``).

Examples
--------
>>> logging_advice("PX4").startswith("PX4: set SDLOG_PROFILE")
True
>>> excitation_advice("roll", "ardupilot")[:48]
'fly a SYSTEMID mixer chirp on roll (SID_AXIS 10)'
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from mavsid.autopilot import ardupilot, px4

__all__ = ["excitation_advice", "filter_cutoffs", "is_rate_setting", "logging_advice",
           "longer_advice"]


def excitation_advice(axis: str, platform: str | None) -> str:
    """What to fly next time to excite ``axis``, on this autopilot.

    >>> excitation_advice("yaw", "px4")[:52]
    'fly sharp stick doublets or a 3-2-1-1 on yaw in ACRO'
    """
    if px4.is_px4(platform):
        return px4.excitation_advice(axis)
    return ardupilot.excitation_advice(axis, platform)


def filter_cutoffs(params: Mapping[str, float], axis: str) -> dict[str, float]:
    """The configured filters' cut-offs (name -> Hz) acting on ``axis``'s gyro and rate
    loop, by either autopilot's names (:func:`.ardupilot.filter_params`, then
    :func:`.px4.filter_params`; a log holds one firmware's parameters). Zero (off) is
    left out.

    >>> filter_cutoffs({"INS_GYRO_FILTER": 20, "ATC_RAT_RLL_FLTD": 0, "ATC_RAT_RLL_FLTT": 20},
    ...                "roll")
    {'INS_GYRO_FILTER': 20.0, 'ATC_RAT_RLL_FLTT': 20.0}
    >>> filter_cutoffs({"IMU_GYRO_CUTOFF": 30, "IMU_GYRO_NF_FREQ": 0}, "yaw")
    {'IMU_GYRO_CUTOFF': 30.0}
    """
    out: dict[str, float] = {}
    for name in (*ardupilot.filter_params(params, axis), *px4.filter_params()):
        v = params.get(name)
        if v is not None and math.isfinite(v) and v > 0:
            out[name] = float(v)
    return out


def is_rate_setting(name: str, platform: str | None) -> bool:
    """Whether parameter ``name`` shapes the rate loop's response on this autopilot (its
    change in flight starts a new setting).

    >>> is_rate_setting("MC_ROLLRATE_P", "px4"), is_rate_setting("MC_ROLLRATE_P", "ardupilot")
    (True, False)
    """
    if px4.is_px4(platform):
        return px4.is_rate_setting(name)
    return ardupilot.is_rate_setting(name)


def longer_advice(platform: str | None) -> str:
    """What to fly when the excitation was too short, on this autopilot.

    >>> longer_advice("px4")
    'fly longer excitation (30 s of doublets or 3-2-1-1s in ACRO)'
    """
    if px4.is_px4(platform):
        return px4.longer_advice()
    return ardupilot.longer_advice(platform)


def logging_advice(platform: str | None, telemetry: bool = False) -> str:
    """Which logging setting to change to log body rates and controller outputs fast.

    ``telemetry``: the logs are a ground station's MAVLink telemetry (``.tlog``), whose
    rates are the streams', not the on-board log's: the advice says so and names the
    on-board log's setting for the log to fit instead.

    Examples
    --------
    >>> logging_advice("ArduPilot", telemetry=True).split(":")[0]
    'a .tlog holds what the telemetry streams sent (ArduPilot SRn_EXTRA1'
    """
    if telemetry:
        return ardupilot.TELEMETRY_NOTE + "; " + logging_advice(platform)
    if px4.is_px4(platform):
        return px4.logging_advice()
    return ardupilot.logging_advice(platform)
