"""Advice a user acts on, checked against the firmware's own definitions.

Each table below is written from the firmware's source (cited), not from mavsid: a bit,
value or axis number mavsid advises must mean there what the advice says it means.
"""

from __future__ import annotations

import re

import pytest

from mavsid.autopilot import excitation_advice, logging_advice
from mavsid.autopilot.ardupilot import sid_axis

# PX4-Autopilot src/modules/logger/module.yaml, SDLOG_PROFILE ``bit:`` (params.c ``@bit``
# before it): the logger's topic sets
PX4_SDLOG_PROFILE = {
    0: "Default set (general log analysis)", 1: "Estimator replay (EKF2)",
    2: "Thermal calibration", 3: "System identification", 4: "High rate", 5: "Debug",
    6: "Sensor comparison", 7: "Computer Vision and Avoidance",
    8: "Raw FIFO high-rate IMU (Gyro)", 9: "Raw FIFO high-rate IMU (Accel)",
    10: "Mavlink tunnel message logging", 11: "High rate sensors",
}
# PX4-Autopilot src/modules/logger/logged_topics.cpp: the sets that log
# vehicle_angular_velocity and the torque setpoint (or actuator_controls_0) at full rate
PX4_FULL_RATE_SETS = {"System identification", "High rate"}

# ArduPilot ArduCopter/defines.h, MASK_LOG_*
COPTER_LOG_BITMASK = {
    0: "ATTITUDE_FAST", 1: "ATTITUDE_MED", 2: "GPS", 3: "PM", 4: "CTUN", 5: "NTUN",
    6: "RCIN", 7: "IMU", 8: "CMD", 9: "CURRENT", 10: "RCOUT", 11: "OPTFLOW", 12: "PID",
    13: "COMPASS", 14: "INAV", 15: "CAMERA", 17: "MOTBATT", 18: "IMU_FAST", 19: "IMU_RAW",
    20: "VIDEO_STABILISATION", 21: "FTN_FAST",
}
# ArduCopter/Copter.cpp loop_rate_logging: RATE is written at loop rate under this bit
COPTER_LOOP_RATE_BIT = "ATTITUDE_FAST"
# ArduPilot ArduPlane/defines.h, MASK_LOG_*
PLANE_LOG_BITMASK = {
    0: "ATTITUDE_FAST", 1: "ATTITUDE_MED", 2: "GPS", 3: "PM", 4: "CTUN", 5: "NTUN",
    7: "IMU", 8: "CMD", 9: "CURRENT", 10: "COMPASS", 11: "TECS", 12: "CAMERA", 13: "RC",
    14: "SONAR", 19: "IMU_RAW", 20: "ATTITUDE_FULLRATE", 21: "VIDEO_STABILISATION",
    22: "NOTCH_FULLRATE",
}
# ArduPlane/ArduPlane.cpp update_logging25/10: ATTITUDE_FAST is 25 Hz, ATTITUDE_MED 10 Hz;
# only ATTITUDE_FULLRATE writes the attitude and PID records at loop rate
PLANE_LOOP_RATE_BIT = "ATTITUDE_FULLRATE"

# ArduPilot ArduCopter/mode_systemid.cpp, SID_AXIS @Values
SID_AXIS_VALUES = {
    1: "Input Roll Angle", 2: "Input Pitch Angle", 3: "Input Yaw Angle",
    4: "Recovery Roll Angle", 5: "Recovery Pitch Angle", 6: "Recovery Yaw Angle",
    7: "Rate Roll", 8: "Rate Pitch", 9: "Rate Yaw", 10: "Mixer Roll", 11: "Mixer Pitch",
    12: "Mixer Yaw", 13: "Mixer Thrust", 14: "Measured Lateral Position",
    15: "Measured Longitudinal Position", 16: "Measured Lateral Velocity",
    17: "Measured Longitudinal Velocity", 18: "Input Lateral Velocity",
    19: "Input Longitudinal Velocity",
}

PX4 = "PX4 v1.14.0"
COPTER = "ardupilot copter ArduCopter V4.5.7 (abcdef)"
OLD_COPTER = "ardupilot copter ArduCopter V3.2.1 (abcdef)"
PLANE = "ardupilot plane ArduPlane V4.5.7 (abcdef)"
QUADPLANE = PLANE + " quadplane"


def _px4_bits(text: str) -> list[tuple[str, int, int]]:
    """Every ``'name' (bit N, +V)`` the advice names."""
    return [(m[1], int(m[2]), int(m[3]))
            for m in re.finditer(r"'([^']+)' \(bit (\d+), \+(\d+)\)", text)]


def _ap_bits(text: str) -> list[tuple[str, int, int]]:
    """Every ``bit N NAME (+V)`` the advice names."""
    return [(m[2], int(m[1]), int(m[3]))
            for m in re.finditer(r"bit (\d+) ([A-Z_]+) \(\+(\d+)\)", text)]


@pytest.mark.parametrize("telemetry", [False, True])
def test_px4_logging_advice_names_the_loggers_own_bits(telemetry: bool) -> None:
    text = logging_advice(PX4, telemetry=telemetry)
    bits = _px4_bits(text)
    assert bits and "SDLOG_PROFILE" in text
    for name, bit, value in bits:
        assert PX4_SDLOG_PROFILE[bit].lower() == name.lower(), (bit, name)
        assert value == 1 << bit
        assert PX4_SDLOG_PROFILE[bit] in PX4_FULL_RATE_SETS, name


@pytest.mark.parametrize("platform, table, loop_bit", [
    (COPTER, COPTER_LOG_BITMASK, COPTER_LOOP_RATE_BIT),
    (OLD_COPTER, COPTER_LOG_BITMASK, COPTER_LOOP_RATE_BIT),
    (PLANE, PLANE_LOG_BITMASK, PLANE_LOOP_RATE_BIT),
    (QUADPLANE, PLANE_LOG_BITMASK, PLANE_LOOP_RATE_BIT),
])
def test_ardupilot_logging_advice_names_the_vehicles_own_bits(platform: str, table: dict,
                                                              loop_bit: str) -> None:
    text = logging_advice(platform)
    bits = _ap_bits(text)
    assert bits and "LOG_BITMASK" in text
    for name, bit, value in bits:
        assert table[bit] == name, (bit, name)
        assert value == 1 << bit
    assert loop_bit in [name for name, _, _ in bits]  # the bit that logs at loop rate


@pytest.mark.parametrize("axis", ["roll", "pitch", "yaw"])
def test_systemid_advice_names_the_mixer_axis(axis: str) -> None:
    text = excitation_advice(axis, COPTER)
    number = int(re.search(r"SID_AXIS (\d+)", text)[1])  # type: ignore[index]
    assert SID_AXIS_VALUES[number] == f"Mixer {axis.capitalize()}"


@pytest.mark.parametrize("number", sorted(SID_AXIS_VALUES))
def test_sid_axis_reads_as_the_firmware_defines_it(number: int) -> None:
    axis, kind = sid_axis(number)
    words = SID_AXIS_VALUES[number].lower()
    if number <= 13:
        assert axis in words
        assert {"input angle": "input", "recovery angle": "recovery", "rate": "rate",
                "mixer": "mixer"}[kind] == words.split()[0]
    else:  # the position controller's axes: no attitude axis
        assert axis == "other"
