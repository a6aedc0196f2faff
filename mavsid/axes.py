"""The axis vocabulary, defined once: axis names, their body rates and their inputs.

Every stage names signals with these words: a :class:`~mavsid.data.FlightData` has the
states :data:`STATE_NAMES` (angles in rad, body rates in rad/s) and the inputs
:data:`INPUT_NAMES` (normalised controller outputs); an axis ``roll`` is modelled by its rate
``p`` driven by ``u_roll``. What an autopilot calls an axis (ArduPilot's ``SID_AXIS``
numbers, PX4's topic fields) is in :mod:`mavsid.autopilot`.

Examples
--------
>>> AXES, RATE_OF["pitch"], INPUT_OF["yaw"]
(('roll', 'pitch', 'yaw'), 'q', 'u_yaw')
>>> AXIS_OF_RATE["r"], STATE_UNITS["p"]
('yaw', 'rad/s')
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

__all__ = ["AXES", "AXIS_OF_RATE", "INPUT_NAMES", "INPUT_OF", "RATES", "RATE_OF", "STATE_NAMES",
           "STATE_UNITS", "THRUST_INPUT"]

#: the three attitude axes, in column order
AXES: tuple[str, ...] = ("roll", "pitch", "yaw")
#: the body rate of each axis (rad/s), in column order
RATES: tuple[str, ...] = ("p", "q", "r")
#: axis -> its body rate
RATE_OF: Mapping[str, str] = MappingProxyType(dict(zip(AXES, RATES, strict=True)))
#: body rate -> its axis
AXIS_OF_RATE: Mapping[str, str] = MappingProxyType(dict(zip(RATES, AXES, strict=True)))
#: axis -> the normalised input (the rate controller's output) that drives it
INPUT_OF: Mapping[str, str] = MappingProxyType({a: f"u_{a}" for a in AXES})
#: the collective thrust input (0..1)
THRUST_INPUT = "u_thrust"
#: canonical state names, in FlightData column order
STATE_NAMES: tuple[str, ...] = (*AXES, *RATES)
#: each state's SI unit
STATE_UNITS: Mapping[str, str] = MappingProxyType(
    {**dict.fromkeys(AXES, "rad"), **dict.fromkeys(RATES, "rad/s")})
#: canonical input names, in FlightData column order (all dimensionless)
INPUT_NAMES: tuple[str, ...] = (*INPUT_OF.values(), THRUST_INPUT)
