"""Reading a preset's channels from a log: field expressions, units, quaternions, outputs.

A :class:`~mavsid.autopilot.presets.Channel` names a message field and its unit;
:func:`evaluate` gives its samples in SI units, :func:`first_of` the first of several a log
has, :func:`servo_inputs` and :func:`motor_thrusts` a plane's servo and a multirotor's
motor outputs. Which field is which signal, per autopilot, is in
:mod:`mavsid.autopilot.presets`.

Examples
--------
>>> from mavsid.data import MessageTable, RawLog, SourceInfo
>>> t = MessageTable("RATE", {"R": np.array([90.0, 180.0])}, time_s=np.arange(2.0),
...                  units={"R": "deg/s"})
>>> raw = RawLog(SourceInfo("x.bin", "dataflash", 0), {"RATE": t})
>>> evaluate(raw, Channel("RATE", "R", "deg/s"))[1].round(4).tolist()
[1.5708, 3.1416]
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Iterable

import numpy as np

from mavsid.autopilot.ardupilot import (
    PWM_SPAN,
    SERVO_FUNCTIONS,
    motor_channels,
    pwm_to_thrust,
    thrust_curve,
)
from mavsid.autopilot.mixers import Mixer
from mavsid.autopilot.presets import TRANSFORMS, UNIT_TO_SI, Channel, Preset
from mavsid.data import MessageTable, RawLog
from mavsid.errors import (
    ConfigError,
    DataQualityWarning,
    LogFormatError,
    MavsidError,
    MissingMessageError,
)
from mavsid.numerics.rotations import quat_to_euler

__all__ = [
    "column",
    "evaluate",
    "first_of",
    "motor_thrusts",
    "resolve",
    "rows_of",
    "servo_inputs",
    "source_text",
    "to_si",
    "unit_origin",
]

_INDEXED = re.compile(r"^(\w+)\[(\d+)\]$")


def column(table: MessageTable, name: str) -> np.ndarray | None:
    """One column (``name``, or element ``i`` of an array field as ``name[i]``) as float64
    numbers (:meth:`MessageTable.numbers`), scaled by the multiplier the log declares; None
    when the table lacks it, it is not one value per record, or it holds no numbers.

    Examples
    --------
    >>> tab = MessageTable("X", {"a": np.array([1, 2]), "q": np.ones((2, 4)),
    ...                          "s": np.array(["x", "y"], object)}, np.zeros(2),
    ...                    multipliers={"a": 0.5})
    >>> column(tab, "a").tolist(), column(tab, "q[3]").tolist(), column(tab, "s")
    ([0.5, 1.0], [1.0, 1.0], None)
    """
    base, k = name, None
    if name not in table.columns:
        m = _INDEXED.match(name)
        if not m or m.group(1) not in table.columns:
            return None
        base, k = m.group(1), int(m.group(2))
    raw = np.asarray(table.columns[base])
    if len(raw) != len(table) or raw.ndim != (1 if k is None else 2) or (
            k is not None and k >= raw.shape[1]):
        return None
    try:
        col = table.numbers(base)
    except LogFormatError:
        return None
    out = col if k is None else col[:, k]
    mult = table.multipliers.get(base, 1.0)
    return out * mult if mult not in (None, 1.0) else out


def resolve(table: MessageTable, expr: str) -> tuple[np.ndarray, str] | None:
    """Evaluate a field expression; returns the values and the first column's name."""
    for alternative in expr.split("|"):
        parts = [p.strip() for p in alternative.split("+")]
        cols = [c for c in (column(table, p) for p in parts) if c is not None]
        if len(cols) == len(parts):
            return np.sum(cols, axis=0), parts[0]
    return None


def _quaternion(table: MessageTable, fld: str) -> np.ndarray | None:
    col = table.columns.get(fld)
    if col is not None and np.ndim(col) == 2 and np.shape(col)[1] == 4:
        return np.asarray(col, dtype=np.float64)
    parts = [column(table, f"{fld}[{i}]") for i in range(4)]
    if any(p is None for p in parts):
        return None
    return np.column_stack(parts)  # type: ignore[arg-type]


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
        return values * UNIT_TO_SI[unit.strip()]
    except KeyError:
        raise ConfigError(f"{what or 'channel'}: unknown unit {unit!r}") from None


def rows_of(table: MessageTable, instance: int | None = None) -> np.ndarray | None:
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
    if declared is not None and declared.strip() in UNIT_TO_SI:
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
        if all(column(table, p) is not None for p in parts):
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
        axis = TRANSFORMS[channel.transform]
        values = quat_to_euler(q)[:, axis]
    else:
        got = resolve(table, channel.field)
        if got is None:
            raise MissingMessageError(
                f"{channel.message}.{channel.field}", available=table.columns, what="field"
            )
        values, first = got
        values = to_si(values, _unit_of(table, first, channel)[0], what)
    values = values * channel.scale
    t = np.asarray(table.time_s, dtype=np.float64)
    ok = np.isfinite(t) & np.isfinite(values)
    rows = rows_of(table, channel.instance)
    if rows is not None:
        ok &= rows
    return t[ok], values[ok]


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
    >>> from mavsid.autopilot.presets import get_preset
    >>> from mavsid.data import MessageTable, RawLog, SourceInfo
    >>> t = np.arange(3.0)
    >>> pwm = {"C1": np.array([1500.0, 1900, 1300]), "C2": np.full(3, 1500.0),
    ...        "C4": np.full(3, 1500.0)}
    >>> params = {"SERVO1_FUNCTION": 4, "SERVO2_FUNCTION": 19, "SERVO4_FUNCTION": 21,
    ...           "SERVO1_MIN": 1100, "SERVO1_TRIM": 1500, "SERVO1_MAX": 1900}
    >>> raw = RawLog(SourceInfo("p.bin", "dataflash", 0), {"RCOU": MessageTable("RCOU", pwm, t)},
    ...              params=params, vehicle="plane")
    >>> got = servo_inputs(raw, get_preset("ardupilot-plane-servo"))
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
        got = resolve(table, expr)
        if got is None:
            raise MissingMessageError(f"{ch.message}.{expr} ({label}, SERVO{n})",
                                      available=table.columns, what="field")
        pwm, first = got
        lo = float(params.get(f"SERVO{n}_MIN", 1100.0))
        trim = float(params.get(f"SERVO{n}_TRIM", 1500.0))
        hi = float(params.get(f"SERVO{n}_MAX", 1900.0))
        # (a range output's trim is usually its minimum: a throttle idles there)
        if not (hi > trim > lo if angle else hi > lo) or not (
                PWM_SPAN[0] <= lo and hi <= PWM_SPAN[1]):
            if name == "u_thrust":  # (optional: the attitude axes do not need it)
                continue
            raise ConfigError(f"{raw.source.path}: SERVO{n}_MIN/TRIM/MAX {lo:g}/{trim:g}/{hi:g} "
                              f"are not increasing PWMs within {PWM_SPAN[0]:g}..{PWM_SPAN[1]:g} "
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


def motor_thrusts(raw: RawLog, preset: Preset, mixer: Mixer) -> tuple[np.ndarray, np.ndarray]:
    """``(time_s, thrust)`` of each motor, shape ``(n, n_motors)``, from the PWM channel, in
    record order."""
    assert preset.motors is not None
    ch = preset.motors
    table = raw[ch.message]
    cols = []
    for i, out in enumerate(motor_channels(raw.params, mixer.n_motors), start=1):
        got = resolve(table, ch.field.replace("{i}", str(out)))
        if got is None:
            raise MissingMessageError(
                f"{ch.message}.{ch.field.replace('{i}', str(out))} (motor {i} of {mixer.name})",
                available=table.columns, what="field",
            )
        cols.append(got[0])
    pwm = np.column_stack(cols)
    t = np.asarray(table.time_s, dtype=np.float64)
    ok = np.isfinite(t) & np.all(np.isfinite(pwm), axis=1)
    rows = rows_of(table, ch.instance)
    if rows is not None:
        ok &= rows
    notes = thrust_curve(raw.params)[1]
    if notes:
        warnings.warn(f"{raw.source.path}: motor parameters that are no motor's (damaged?): "
                      f"{'; '.join(notes)}", DataQualityWarning, stacklevel=3)
    return t[ok], pwm_to_thrust(pwm[ok], raw.params)
