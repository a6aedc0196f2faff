"""PX4's facts: what to fly and which logger profile to set for identification, the rate
controller's parameter names and QGroundControl's parameter file.

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

from collections.abc import Mapping, Sequence
from types import MappingProxyType

__all__ = ["GYRO_NOTCH_PARAMS", "INT_LIM_AXIS", "PARAM_TYPE_REAL32", "RATE_AXIS",
           "RATE_PROFILE_BITS", "RC_MAP_PX4", "SDLOG_PROFILE_BITS", "angle_p_param",
           "excitation_advice", "filter_params", "has_rate_params",
           "int_lim_param", "is_px4", "logging_advice", "longer_advice", "param_file_text",
           "profile_bit_text", "rate_prefix"]

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


# --------------------------------------------------------------------------- rate controller

#: the axis in the multicopter rate controller's parameter names (MC_ROLLRATE_P ...)
RATE_AXIS: Mapping[str, str] = MappingProxyType(
    {"roll": "ROLL", "pitch": "PITCH", "yaw": "YAW"})
#: the axis in the rate integrator limits' names (MC_RR_INT_LIM ...)
INT_LIM_AXIS: Mapping[str, str] = MappingProxyType({"roll": "RR", "pitch": "PR", "yaw": "YR"})
#: MAV_PARAM_TYPE_REAL32, the type column of a float in a QGroundControl parameter file
PARAM_TYPE_REAL32 = 9


def rate_prefix(axis: str) -> str:
    """The prefix of one axis's rate-controller parameters.

    Examples
    --------
    >>> rate_prefix("pitch"), int_lim_param("yaw"), angle_p_param("roll")
    ('MC_PITCHRATE_', 'MC_YR_INT_LIM', 'MC_ROLL_P')
    """
    return f"MC_{RATE_AXIS[axis]}RATE_"


def int_lim_param(axis: str) -> str:
    """The rate integrator's limit for ``axis``."""
    return f"MC_{INT_LIM_AXIS[axis]}_INT_LIM"


def angle_p_param(axis: str) -> str:
    """The attitude loop's P around ``axis``'s rate loop."""
    return f"MC_{RATE_AXIS[axis]}_P"


#: the multicopter rate controller's gains per axis (MC_ROLLRATE_P ... MC_ROLLRATE_FF)
RATE_GAINS = ("P", "I", "D", "K", "FF")
#: the gyro's and its derivative's low-pass filters, which shape the rate loop's response
GYRO_FILTER_PARAMS = ("IMU_GYRO_CUTOFF", "IMU_DGYRO_CUTOFF")
#: the gyro's static notch centre (src/modules/sensors/vehicle_angular_velocity:
#: IMU_GYRO_NF0_FRQ; IMU_GYRO_NF_FREQ in older releases)
GYRO_NOTCH_PARAMS = ("IMU_GYRO_NF0_FRQ", "IMU_GYRO_NF_FREQ")


def filter_params() -> list[str]:
    """The parameters that set the cut-offs (Hz) of the gyro filters, the same on every
    axis: the gyro and its derivative's low-pass (``IMU_GYRO_CUTOFF``,
    ``IMU_DGYRO_CUTOFF``) and the static notch (:data:`GYRO_NOTCH_PARAMS`).

    >>> filter_params()
    ['IMU_GYRO_CUTOFF', 'IMU_DGYRO_CUTOFF', 'IMU_GYRO_NF0_FRQ', 'IMU_GYRO_NF_FREQ']
    """
    return [*GYRO_FILTER_PARAMS, *GYRO_NOTCH_PARAMS]


def is_rate_setting(name: str) -> bool:
    """Whether parameter ``name`` shapes the rate loop's response: a rate gain
    (:data:`RATE_GAINS`), a rate integrator's limit, the attitude P around the rate loop,
    or a gyro filter. A change of one in flight starts a new setting of the closed-loop
    response.

    Examples
    --------
    >>> [is_rate_setting(n) for n in ("MC_YAWRATE_K", "MC_RR_INT_LIM", "MC_PITCH_P",
    ...                                "IMU_GYRO_CUTOFF", "MC_ROLLRATE_MAX")]
    [True, True, True, True, False]
    """
    return name in GYRO_FILTER_PARAMS or any(
        name in {*(rate_prefix(axis) + g for g in RATE_GAINS), int_lim_param(axis),
                 angle_p_param(axis)} for axis in RATE_AXIS)


def has_rate_params(params: Mapping[str, float]) -> bool:
    """Whether a log's parameters hold PX4's multicopter rate controller.

    >>> has_rate_params({"MC_YAWRATE_P": 0.2}), has_rate_params({"ATC_RAT_YAW_P": 0.2})
    (True, False)
    """
    prefixes = tuple(rate_prefix(a) for a in RATE_AXIS)
    return any(k.startswith(prefixes) for k in params)


def param_file_text(values: Mapping[str, float], header: Sequence[str],
                    vehicle_id: int = 1, component_id: int = 1) -> str:
    """A QGroundControl parameter file (``.params``): ``#`` comment lines ending in QGC's
    column header, then one tab-separated ``vehicle component name value type`` line per
    parameter (every value a float, ``MAV_PARAM_TYPE_REAL32``).

    Examples
    --------
    >>> text = param_file_text({"MC_ROLLRATE_P": 0.15}, ["from flight.ulg"])
    >>> text.splitlines()[:3], text.splitlines()[-1].split()
    (['# Onboard parameters for Vehicle 1', '#', '# from flight.ulg'], \
['1', '1', 'MC_ROLLRATE_P', '0.15', '9'])
    """
    lines = [f"# Onboard parameters for Vehicle {vehicle_id}", "#"]
    lines += [f"# {h}" for h in header]
    lines += ["#", "# Vehicle-Id Component-Id Name Value Type"]
    lines += [f"{vehicle_id}\t{component_id}\t{name}\t{value:.7g}\t{PARAM_TYPE_REAL32}"
              for name, value in values.items()]
    return "\n".join(lines) + "\n"
