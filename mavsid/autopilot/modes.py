"""Flight-mode names of ArduPilot and PX4 (MAVLink modes, PX4's nav_state), without
importing pymavlink.

The readers name the modes a log records (DataFlash ``MODE`` records, a ``.tlog``'s
``HEARTBEAT.custom_mode``). The numbers are the autopilots' own mode enumerations, as
pymavlink presents them (``mavutil.mode_mapping_bynumber``, ``mavutil.interpret_px4_mode``;
``tests/test_autopilot_modes.py`` checks these tables against the installed pymavlink). Importing
``pymavlink.mavutil`` only for these tables cost a cold read ~40 ms.

Examples
--------
>>> ardupilot_modes("copter")[5], ardupilot_modes("heli")[0], ardupilot_modes("boat")
('LOITER', 'STABILIZE', None)
>>> px4_mode_name(4 << 16 | 4 << 24)
'MISSION'
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

__all__ = [
    "ARDUPILOT_MODES", "MAV_TYPE_MODES", "NAV_STATES", "VEHICLE_CLASSES", "ardupilot_modes",
    "px4_mode_name", "vehicle_class",
]


def _table(spec: str) -> Mapping[int, str]:
    """``"0 NAME, 1 OTHER"`` -> read-only ``{0: "NAME", 1: "OTHER"}``."""
    pairs = (item.split() for item in spec.split(","))
    return MappingProxyType({int(number): name for number, name in pairs})


#: vehicle class (the words :func:`mavsid.readers.dataflash_assemble.vehicle_and_firmware` gives)
#: -> mode number -> name
ARDUPILOT_MODES: Mapping[str, Mapping[int, str]] = MappingProxyType({
    "copter": _table(
        "0 STABILIZE, 1 ACRO, 2 ALT_HOLD, 3 AUTO, 4 GUIDED, 5 LOITER, 6 RTL, 7 CIRCLE,"
        " 8 POSITION, 9 LAND, 10 OF_LOITER, 11 DRIFT, 13 SPORT, 14 FLIP, 15 AUTOTUNE,"
        " 16 POSHOLD, 17 BRAKE, 18 THROW, 19 AVOID_ADSB, 20 GUIDED_NOGPS, 21 SMART_RTL,"
        " 22 FLOWHOLD, 23 FOLLOW, 24 ZIGZAG, 25 SYSTEMID, 26 AUTOROTATE, 27 AUTO_RTL,"
        " 28 TURTLE, 29 RATE_ACRO"),
    "plane": _table(
        "0 MANUAL, 1 CIRCLE, 2 STABILIZE, 3 TRAINING, 4 ACRO, 5 FBWA, 6 FBWB, 7 CRUISE,"
        " 8 AUTOTUNE, 10 AUTO, 11 RTL, 12 LOITER, 13 TAKEOFF, 14 AVOID_ADSB, 15 GUIDED,"
        " 16 INITIALISING, 17 QSTABILIZE, 18 QHOVER, 19 QLOITER, 20 QLAND, 21 QRTL,"
        " 22 QAUTOTUNE, 23 QACRO, 24 THERMAL, 25 LOITERALTQLAND, 26 AUTOLAND"),
    "rover": _table(
        "0 MANUAL, 1 ACRO, 2 LEARNING, 3 STEERING, 4 HOLD, 5 LOITER, 6 FOLLOW, 7 SIMPLE,"
        " 8 DOCK, 9 CIRCLE, 10 AUTO, 11 RTL, 12 SMART_RTL, 15 GUIDED, 16 INITIALISING"),
    "tracker": _table("0 MANUAL, 1 STOP, 2 SCAN, 4 GUIDED, 10 AUTO, 16 INITIALISING"),
    "sub": _table(
        "0 STABILIZE, 1 ACRO, 2 ALT_HOLD, 3 AUTO, 4 GUIDED, 7 CIRCLE, 9 SURFACE, 16 POSHOLD,"
        " 19 MANUAL"),
    "blimp": _table("0 LAND, 1 MANUAL, 2 VELOCITY, 3 LOITER, 4 RTL, 5 AUTO, 6 HOLD"),
})
ARDUPILOT_MODES = MappingProxyType({**ARDUPILOT_MODES, "heli": ARDUPILOT_MODES["copter"]})

#: MAVLink ``MAV_TYPE`` -> the ArduPilot mode table of that vehicle (the types pymavlink
#: maps; a type not listed has no table)
MAV_TYPE_MODES: Mapping[int, Mapping[int, str]] = MappingProxyType({
    **dict.fromkeys((2, 3, 4, 13, 14, 15, 29, 35), ARDUPILOT_MODES["copter"]),
    **dict.fromkeys((1, 19, 20, 21), ARDUPILOT_MODES["plane"]),
    **dict.fromkeys((10, 11), ARDUPILOT_MODES["rover"]),
    5: ARDUPILOT_MODES["tracker"],
    12: ARDUPILOT_MODES["sub"],
    7: ARDUPILOT_MODES["blimp"],
})


def ardupilot_modes(vehicle: str | int | None) -> Mapping[int, str] | None:
    """Mode number -> name of an ArduPilot vehicle, or None when it has no table.

    Parameters
    ----------
    vehicle
        A vehicle class (``"copter"``, ``"heli"``, ``"plane"``, ``"rover"``, ``"sub"``,
        ``"tracker"``, ``"blimp"``; a frame after a space is ignored) or a MAVLink
        ``MAV_TYPE`` number.

    Examples
    --------
    >>> ardupilot_modes("plane QUADPLANE")[19], ardupilot_modes(10)[4], ardupilot_modes(6)
    ('QLOITER', 'HOLD', None)
    """
    if vehicle is None:
        return None
    if not isinstance(vehicle, str):
        return MAV_TYPE_MODES.get(int(vehicle))
    words = vehicle.split()
    return ARDUPILOT_MODES.get(words[0]) if words else None


#: PX4 ``vehicle_status.nav_state`` values whose meaning has not changed across releases
#: (the others were renamed or freed over time and are left unnamed): a ULog's modes.
NAV_STATES: Mapping[int, str] = MappingProxyType({
    0: "MANUAL", 1: "ALTCTL", 2: "POSCTL", 3: "AUTO_MISSION", 4: "AUTO_LOITER",
    5: "AUTO_RTL", 10: "ACRO", 12: "DESCEND", 13: "TERMINATION", 14: "OFFBOARD",
    15: "STAB", 17: "AUTO_TAKEOFF", 18: "AUTO_LAND", 19: "AUTO_FOLLOW_TARGET",
    20: "AUTO_PRECLAND", 21: "ORBIT", 22: "AUTO_VTOL_TAKEOFF",
})  # fmt: skip

# PX4 custom_mode: main mode in bits 16..23, sub mode (AUTO's) in bits 24..31
_PX4_MAIN = {1: "MANUAL", 5: "ACRO", 8: "RATTITUDE", 7: "STABILIZED", 2: "ALTCTL",
             3: "POSCTL", 6: "OFFBOARD"}
_PX4_AUTO = 4
_PX4_AUTO_SUB = {4: "MISSION", 2: "TAKEOFF", 3: "LOITER", 8: "FOLLOWME", 5: "RTL", 6: "LAND",
                 7: "RTGS"}


def px4_mode_name(custom_mode: int) -> str:
    """Name of a PX4 ``custom_mode`` (``"UNKNOWN"`` when it names none).

    Examples
    --------
    >>> px4_mode_name(3 << 16), px4_mode_name(4 << 16 | 5 << 24), px4_mode_name(0)
    ('POSCTL', 'RTL', 'UNKNOWN')
    """
    main = (custom_mode >> 16) & 0xFF
    if main == _PX4_AUTO:
        return _PX4_AUTO_SUB.get((custom_mode >> 24) & 0xFF, "UNKNOWN")
    return _PX4_MAIN.get(main, "UNKNOWN")


#: MAV_TYPE -> vehicle class (the words the DataFlash reader uses for :data:`ARDUPILOT_MODES`)
VEHICLE_CLASSES = {
    1: "plane", 2: "copter", 3: "copter", 4: "heli", 5: "tracker", 7: "blimp", 10: "rover",
    11: "rover", 12: "sub", 13: "copter", 14: "copter", 15: "copter", 19: "plane",
    20: "plane", 21: "plane", 22: "plane", 23: "plane", 24: "plane", 25: "plane",
    29: "copter", 35: "copter",
}  # fmt: skip


def vehicle_class(mav_type: int) -> str | None:
    """The vehicle class of a MAVLink ``MAV_TYPE`` (also PX4's ``MAV_TYPE`` parameter).

    Examples
    --------
    >>> vehicle_class(2), vehicle_class(22), vehicle_class(11), vehicle_class(6)
    ('copter', 'plane', 'rover', None)
    """
    return VEHICLE_CLASSES.get(int(mav_type))
