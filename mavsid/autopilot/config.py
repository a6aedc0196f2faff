"""User channel presets and mixers from a TOML file.

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

"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from mavsid.autopilot.mixers import MIXERS, Mixer
from mavsid.autopilot.presets import TRANSFORMS, UNIT_TO_SI, Channel, Preset
from mavsid.axes import AXES
from mavsid.data import LOG_FORMATS
from mavsid.errors import ConfigError, finite_number, whole_number

__all__ = ["load_presets", "read_toml"]


def read_toml(path: str | os.PathLike[str]) -> dict[str, Any]:
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
    if not isinstance(unit, str) or (unit not in UNIT_TO_SI and unit != "pwm"):
        raise ConfigError(f"{where}: unknown unit {unit!r}")
    if (unit == "pwm") is not pwm:
        raise ConfigError(f"{where}: unit {unit!r}: " + (
            "motor and servo outputs are PWM (unit 'pwm')" if pwm else
            "only motors and servos take PWM (unit 'pwm')"))
    scale = spec.get("scale", 1.0)
    if not finite_number(scale) or scale == 0:
        raise ConfigError(f"{where}: scale must be a finite number other than 0")
    transform = spec.get("transform", "")
    if transform not in ("", *TRANSFORMS):
        raise ConfigError(f"{where}: unknown transform {transform!r} (known: "
                          f"{', '.join(TRANSFORMS)})")
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
        axes = ", ".join(AXES[k] for k in used)
        raise ConfigError(f"{where} cannot set {axes} and thrust apart (rank {rank} of "
                          f"{len(used) + 1})")
    return mixer


def load_presets(path: str | os.PathLike[str]) -> tuple[dict[str, Preset], dict[str, Mixer]]:
    """Read user presets and mixers from a TOML file (format in the module docstring).

    Returns
    -------
    presets, mixers : dict
        By name; pass ``presets`` to :func:`mavsid.autopilot.presets.choose_preset` /
        :func:`mavsid.align.align`.

    Raises
    ------
    ConfigError
        Unreadable file, invalid TOML, unknown keys, names or units.
    """
    doc = read_toml(path)
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
