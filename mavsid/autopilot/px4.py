"""PX4's facts: what to fly and which logger profile to set for identification.

The uORB topics mavsid reads per PX4 generation are in the channel presets
(:mod:`mavsid.autopilot.presets`: ``vehicle_torque_setpoint`` from 1.14,
``actuator_controls_0`` before, ``vehicle_attitude`` rates before 1.10), the
``nav_state``/``custom_mode`` names in :mod:`mavsid.autopilot.modes`.

Examples
--------
>>> longer_advice()
'fly longer excitation (30 s of doublets or 3-2-1-1s in ACRO)'
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

__all__ = ["RC_MAP_PX4", "excitation_advice", "is_px4", "logging_advice", "longer_advice"]

#: per axis: the parameter mapping an RC input channel to it (src/modules/sensors/
#: module.yaml RC_MAP_ROLL/PITCH/YAW; 0, the default, maps none)
RC_MAP_PX4: Mapping[str, str] = MappingProxyType(
    {"roll": "RC_MAP_ROLL", "pitch": "RC_MAP_PITCH", "yaw": "RC_MAP_YAW"})


def is_px4(platform: str | None) -> bool:
    """Whether the platform text names a PX4 log.

    >>> is_px4("PX4 v1.14.0"), is_px4("ardupilot")
    (True, False)
    """
    return bool(platform) and "px4" in str(platform).lower()


def excitation_advice(axis: str) -> str:
    """What to fly next time to excite ``axis`` on a PX4 vehicle.

    >>> excitation_advice("yaw")[:52]
    'fly sharp stick doublets or a 3-2-1-1 on yaw in ACRO'
    """
    return (f"fly sharp stick doublets or a 3-2-1-1 on {axis} in ACRO (PX4 has no SYSTEMID "
            "chirp mode), with SDLOG_PROFILE logging the rate controller at full rate")


def longer_advice() -> str:
    """What to fly when the excitation was too short, on a PX4 vehicle."""
    return "fly longer excitation (30 s of doublets or 3-2-1-1s in ACRO)"


def logging_advice() -> str:
    """Which logger setting to change to log body rates and controller outputs fast.

    >>> logging_advice().startswith("PX4: set SDLOG_PROFILE")
    True
    """
    return ("PX4: set SDLOG_PROFILE to include 'high rate' (bit 1) or 'system identification'"
            " (bit 4) so that vehicle_angular_velocity and the torque/actuator setpoints are "
            "logged at 100 Hz or more")
