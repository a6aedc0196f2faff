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

__all__ = ["RATE_PROFILE_BITS", "RC_MAP_PX4", "SDLOG_PROFILE_BITS", "excitation_advice", "is_px4",
           "logging_advice", "longer_advice", "profile_bit_text"]

#: SDLOG_PROFILE, the logger's topic-set bitmask: bit -> the set it adds
#: (src/modules/logger/module.yaml ``SDLOG_PROFILE`` ``bit:``, and src/modules/logger/params.c
#: ``@bit`` before it; a bitmask since PX4 1.7, an enum 0-2 before)
SDLOG_PROFILE_BITS: Mapping[int, str] = MappingProxyType({
    0: "default set", 1: "estimator replay (EKF2)", 2: "thermal calibration",
    3: "system identification", 4: "high rate", 5: "debug", 6: "sensor comparison",
    7: "computer vision and avoidance", 8: "raw FIFO high-rate IMU (gyro)",
    9: "raw FIFO high-rate IMU (accel)", 10: "mavlink tunnel message logging",
    11: "high rate sensors",
})
#: the sets that log the rate controller at full rate, in the order advised: "high rate"
#: (src/modules/logger/logged_topics.cpp add_high_rate_topics: vehicle_angular_velocity,
#: vehicle_rates_setpoint, the torque setpoint or actuator_controls_0) and "system
#: identification" (add_system_identification_topics: vehicle_angular_velocity and the
#: torque setpoint or actuator_controls_0)
RATE_PROFILE_BITS: tuple[int, ...] = (4, 3)

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


def profile_bit_text(bit: int) -> str:
    """``'high rate' (bit 4, +16)``: an SDLOG_PROFILE bit as a user sets it.

    >>> profile_bit_text(3)
    "'system identification' (bit 3, +8)"
    """
    return f"'{SDLOG_PROFILE_BITS[bit]}' (bit {bit}, +{1 << bit})"


def logging_advice() -> str:
    """Which logger setting to change to log body rates and controller outputs fast.

    >>> print(logging_advice())  # doctest: +NORMALIZE_WHITESPACE
    PX4: set SDLOG_PROFILE to include 'high rate' (bit 4, +16) or 'system identification'
    (bit 3, +8) so that vehicle_angular_velocity and the torque/actuator setpoints are
    logged at full rate
    """
    first, second = (profile_bit_text(b) for b in RATE_PROFILE_BITS)
    return (f"PX4: set SDLOG_PROFILE to include {first} or {second} so that "
            "vehicle_angular_velocity and the torque/actuator setpoints are logged at full rate")
