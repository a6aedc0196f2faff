"""DataFlash tables to a :class:`~mavsid.data.RawLog`: times, units, parameters, texts,
modes, vehicle and firmware (shared by the binary and the text reader).

Time: ``time_s`` is ``TimeUS * 1e-6`` (old logs: ``TimeMS * 1e-3``, except GPS messages, whose
``TimeMS`` is GPS time of week; a PX4 sdlog2 ``.px4log``: its ``TIME.StartTime``, µs since
boot, written at the start of each logging cycle). A message without such a field gets the
time of the latest timestamped record before it in the file (NaN before the first one,
:func:`hold_forward`); the choice is a hold, not an interpolation, so that a parameter or text
is never stamped with a time it was not yet written at. Times are kept as logged: after a
reboot or in concatenated logs they go backwards (:func:`backwards_steps`).

FMTU/UNIT/MULT give per-field units and multipliers as metadata; the multipliers are *not*
applied, and none is given for fields the format character already scales.

Examples
--------
>>> vehicle_and_firmware(["ArduPlane V4.5.7 (6a2f8a5e)"], {})
('plane', 'ArduPlane V4.5.7 (6a2f8a5e)')
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import replace

import numpy as np

from mavsid.autopilot.modes import ardupilot_modes
from mavsid.data import (
    MessageTable,
    ModeChange,
    ParamChange,
    RawLog,
    SourceInfo,
    TextMessage,
    param_changes,
)
from mavsid.errors import DataQualityWarning
from mavsid.readers import dataflash_spec as dfspec
from mavsid.readers.dataflash_formats import Definition

__all__ = [
    "assemble",
    "backwards_steps",
    "hold_forward",
    "mode_names",
    "vehicle_and_firmware",
    "window_mask",
]


_BACKWARDS_S = 0.5  # a time step back larger than this is a discontinuity


def _units(
    tables: Mapping[str, Mapping[str, np.ndarray]], defs_by_name: Mapping[str, Definition]
) -> tuple[dict[str, dict[str, str]], dict[str, dict[str, float]]]:
    """Per-message field units and multipliers from FMTU/UNIT/MULT."""
    unit_of: dict[str, str] = {}
    mult_of: dict[str, float] = {}
    if "UNIT" in tables and {"Id", "Label"} <= set(tables["UNIT"]):
        for i, label in zip(tables["UNIT"]["Id"].tolist(), tables["UNIT"]["Label"].tolist(),
                            strict=True):
            if (key := _id_char(i)) is not None:
                unit_of[key] = str(label)
    if "MULT" in tables and {"Id", "Mult"} <= set(tables["MULT"]):
        for i, mult in zip(tables["MULT"]["Id"].tolist(), tables["MULT"]["Mult"].tolist(),
                           strict=True):
            value = _number(mult)
            if (key := _id_char(i)) is not None and value is not None:
                mult_of[key] = float(f"{value:.7g}")
    units: dict[str, dict[str, str]] = {}
    mults: dict[str, dict[str, float]] = {}
    fmtu = tables.get("FMTU", {})
    if not {"FmtType", "UnitIds"} <= set(fmtu):
        return units, mults
    type_names: dict[int, str] = {}
    for name, d in defs_by_name.items():
        type_names.setdefault(d.type, name)
    mult_ids = fmtu.get("MultIds")
    for k, (ftype, uids) in enumerate(zip(fmtu["FmtType"].tolist(), fmtu["UnitIds"].tolist(),
                                          strict=True)):
        number = _number(ftype)
        target = type_names.get(int(number)) if number is not None else None
        if target is None or not isinstance(uids, str):
            continue
        d = defs_by_name[target]
        mids = str(mult_ids[k]) if mult_ids is not None else ""
        u, mm = units.setdefault(target, {}), mults.setdefault(target, {})
        for col, i in d.fields:
            if i < len(uids) and unit_of.get(uids[i]):
                u[col] = unit_of[uids[i]]
            ch = d.format[i]
            if (i < len(mids) and dfspec.FORMAT_CHARS[ch].multiplier is None
                    and dfspec.FORMAT_CHARS[ch].kind in ("int", "float")):
                mult = mult_of.get(mids[i])
                if mult:
                    mm[col] = mult
    return units, mults


_VEHICLES = (("ArduCopter", "copter"), ("ArduPlane", "plane"), ("ArduRover", "rover"),
             ("Rover", "rover"), ("ArduSub", "sub"), ("AntennaTracker", "tracker"),
             ("Blimp", "blimp"), ("Heli", "heli"), ("Copter", "copter"), ("Plane", "plane"))


_FIRMWARE_RE = re.compile(r"^(?:Ardu\w+|APM:\w+|Rover|Blimp|AntennaTracker)\b.*?\d+\.\d+")


# VER.BU build type -> vehicle
_BUILD_TYPES = {1: "rover", 2: "copter", 3: "plane", 4: "tracker", 7: "sub", 12: "blimp",
                13: "heli"}


def _number(value: object) -> float | None:
    """A metadata value as a finite float, or None (a log may define PARM, MODE, VER ...
    with another layout: strings or arrays where numbers belong).

    Examples
    --------
    >>> _number(3), _number("2.5"), _number("fast"), _number(float("nan"))
    (3.0, 2.5, None, None)
    """
    if isinstance(value, (bytes, list, tuple, np.ndarray)):
        return None
    try:
        out = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError, OverflowError):
        return None
    return out if np.isfinite(out) else None


def _id_char(value: object) -> str | None:
    """A UNIT/MULT id (a character code, or the character itself in text logs)."""
    if isinstance(value, str):
        return value[:1] or None
    number = _number(value)
    return None if number is None else chr(int(number) % 256)


def vehicle_and_firmware(
    texts: Sequence[str], tables: Mapping[str, Mapping[str, np.ndarray]]
) -> tuple[str | None, str | None]:
    """Vehicle kind (plus frame when a ``Frame:`` text names it) and firmware banner.

    Examples
    --------
    >>> vehicle_and_firmware(["ArduCopter V4.6.2 (1ebd4d99)", "Frame: QUAD/X"], {})
    ('copter QUAD/X', 'ArduCopter V4.6.2 (1ebd4d99)')
    """
    firmware = next((t for t in texts if _FIRMWARE_RE.match(t)), None)
    ver = tables.get("VER", {})
    if firmware is None and "FWS" in ver and len(ver["FWS"]):
        firmware = str(ver["FWS"][0]) or None
    vehicle = None
    if "BU" in ver and len(ver["BU"]) and (build := _number(ver["BU"][0])) is not None:
        vehicle = _BUILD_TYPES.get(int(build))
    if vehicle is None and firmware:
        vehicle = next((v for key, v in _VEHICLES if key in firmware), None)
    frame = next((t.split(":", 1)[1].strip() for t in texts if t.startswith("Frame:")), None)
    if vehicle and frame:
        vehicle = f"{vehicle} {frame}"
    return vehicle, firmware


def mode_names(vehicle: str | None) -> dict[int, str]:
    """Mode number -> name for the vehicle type (:mod:`mavsid.autopilot.modes`)."""
    return dict(ardupilot_modes(vehicle) or {})


def _modes(table: Mapping[str, np.ndarray] | None, time_s: np.ndarray | None,
           vehicle: str | None) -> tuple[ModeChange, ...]:
    if not table or time_s is None:
        return ()
    names = mode_names(vehicle)
    by_name = {v.upper(): k for k, v in names.items()}
    out = []
    num = table.get("ModeNum", table.get("Mode"))
    if num is None:
        return ()
    for t, m in zip(time_s.tolist(), num.tolist(), strict=True):
        if isinstance(m, str):  # text logs print the mode name
            out.append(ModeChange(float(t), by_name.get(m.upper(), -1), m.upper()))
        elif (number := _number(m)) is not None:
            out.append(ModeChange(float(t), int(number), names.get(int(number))))
    return tuple(out)


#: Untimed types that head every log (definitions, units, parameters, texts): placed at the
#: first timed record like events, but not worth a note.
_HEADER_TYPES = frozenset({"FMT", "FMTU", "UNIT", "MULT", "PARM", "MSG", "VER"})


#: Untimed event records (old logs): placed at the first timed record when written before it.
#: Sampled data (ATT...) written before any clock stays untimed.
_EVENT_TYPES = frozenset({"EV", "MODE", "ERR", "CMD", "ARM", "EVT"})


def _backfill(
    times: Mapping[str, np.ndarray],
    meta_times: Mapping[str, np.ndarray],
    defs_by_name: Mapping[str, Definition],
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], int]:
    """Event and header records of untimed types written before the first timed record get
    its time.

    An untimed record takes the time of the latest timed record before it (see
    :func:`hold_forward`); those at the head of the log have none and would be lost — an
    ARM event there would leave the whole flight "disarmed". The nearest timed record is
    the first one. Returns both time tables and how many records were placed.

    Examples
    --------
    >>> d = {"EV": Definition(13, "EV", 4, "B", ("Id",)),
    ...      "ATT": Definition(1, "ATT", 11, "Ih", ("TimeMS", "Roll"))}
    >>> t = {"EV": np.array([np.nan, 5.0]), "ATT": np.array([2.0, 5.0])}
    >>> new, _, n = _backfill(t, t, d)
    >>> new["EV"].tolist(), n
    ([2.0, 5.0], 1)
    >>> meta = {"EV": np.array([np.nan, 5.0]), "MODE": np.array([np.nan, 4.0])}
    >>> new, m, n = _backfill(t, meta, d)    # the first timed record is ATT's, at 2 s
    >>> m["EV"].tolist(), n
    ([2.0, 5.0], 1)
    """
    # each table's first time in file order (a later record's garbage time cannot pull
    # it earlier); the earliest of those is the log's first timed record
    finite = [f for table in (times, meta_times) for v in table.values()
              if (f := _first_finite(v)) is not None]
    if not finite:
        return dict(times), dict(meta_times), 0
    first = min(finite)
    placed = 0

    def fill(table: Mapping[str, np.ndarray], count: bool) -> dict[str, np.ndarray]:
        nonlocal placed
        out = {}
        for name, t in table.items():
            d = defs_by_name.get(name)
            t = np.asarray(t, dtype=float)
            if (d is not None and d.time_field is None and name in _HEADER_TYPES | _EVENT_TYPES
                    and t.size and not np.isfinite(t[0])):  # (only untimed types: none else)
                head = ~np.logical_or.accumulate(np.isfinite(t))
                t = np.where(head, first, t)
                if count and name in _EVENT_TYPES:
                    placed += int(head.sum())
            out[name] = t
        return out

    meta = fill(meta_times, True)
    own = meta if times is meta_times else {
        k: fill({k: v}, k not in meta_times)[k] for k, v in times.items()}
    return own, meta, placed


def _first_finite(v: np.ndarray) -> float | None:
    """The first finite value of ``v`` (as float), or None.

    Examples
    --------
    >>> _first_finite(np.array([np.nan, 2.0, 1.0])), _first_finite(np.array([np.nan]))
    (2.0, None)
    """
    v = np.asarray(v, dtype=float)
    if v.size and np.isfinite(v[0]):  # nearly always: no pass over the column
        return float(v[0])
    ok = np.isfinite(v)
    return float(v[np.argmax(ok)]) if ok.any() else None


def assemble(
    source: SourceInfo,
    columns: Mapping[str, Mapping[str, np.ndarray]],
    times: Mapping[str, np.ndarray],
    defs_by_name: Mapping[str, Definition],
    wanted: Iterable[str] | None,
    meta_columns: Mapping[str, Mapping[str, np.ndarray]] | None = None,
    meta_times: Mapping[str, np.ndarray] | None = None,
    banner: Sequence[str] = (),
    declared: Mapping[str, tuple[str, ...]] | None = None,
    autopilot: str = "ardupilot",
) -> RawLog:
    """Build the :class:`RawLog` from decoded columns (shared by the binary and text readers).

    ``columns``/``times`` hold the messages to return; ``meta_*`` the full-log PARM, MSG,
    MODE, VER and FMTU/UNIT/MULT tables used for parameters, texts, modes and units;
    ``banner`` extra lines (text logs' preamble) searched for the firmware after the texts;
    ``declared`` the fields of tables read for their times only; ``autopilot`` the one the
    log's definitions name (:func:`~mavsid.readers.dataflash_formats.autopilot_of`).
    """
    declared = declared or {}
    meta_columns = meta_columns if meta_columns is not None else columns
    meta_times = meta_times if meta_times is not None else times
    times, meta_times, placed = _backfill(times, meta_times, defs_by_name)
    if placed:
        note = (f"{placed} record(s) without a time field written before the first timed "
                "record (e.g. an ARM event or the first MODE) placed at that record's time")
        source = replace(source, notes=(*source.notes, note))
        warnings.warn(f"{source.path}: {note}", DataQualityWarning, stacklevel=3)
    units, mults = _units(meta_columns, defs_by_name)
    messages = {
        name: MessageTable(name, dict(cols), times[name], units.get(name, {}),
                           mults.get(name, {}), declared.get(name, ()))
        for name, cols in columns.items()
        if wanted is None or name in wanted
    }
    params: dict[str, float] = {}
    parm = meta_columns.get("PARM", {})
    if "Name" in parm and "Value" in parm:
        names, values = parm["Name"], parm["Value"]
        if values.dtype.kind == "f" and names.dtype.kind == "O":  # the usual layout: at once
            ok = np.isfinite(values)
            params = {str(name): value for name, value in
                      zip(names[ok].tolist(), values[ok].astype(float).tolist(), strict=True)}
        else:
            for name, value in zip(names.tolist(), values.tolist(), strict=True):
                if (number := _number(value)) is not None:  # another layout: not a number
                    params[str(name)] = number
    changes: tuple[ParamChange, ...] = ()
    if "Name" in parm and "Value" in parm and "PARM" in meta_times:  # (in the log's order)
        numbers = [_number(v) for v in parm["Value"].tolist()]
        changes = param_changes({}, [
            (t, str(name), v) for t, name, v in
            zip(meta_times["PARM"].tolist(), parm["Name"].tolist(), numbers, strict=True)
            if v is not None])
    texts: tuple[TextMessage, ...] = ()
    msg = meta_columns.get("MSG", {})
    if "Message" in msg:
        texts = tuple(TextMessage(float(t), str(s)) for t, s in
                      zip(meta_times["MSG"].tolist(), msg["Message"].tolist(), strict=True))
    vehicle, firmware = vehicle_and_firmware([t.text for t in texts] + list(banner),
                                             meta_columns)
    modes = _modes(meta_columns.get("MODE"), meta_times.get("MODE"), vehicle)
    return RawLog(source, messages, params=params, texts=texts, modes=modes,
                  autopilot=autopilot, vehicle=vehicle, firmware=firmware,
                  param_changes=changes)


def backwards_steps(time_s: np.ndarray, where: np.ndarray) -> list[tuple[int, float, float]]:
    """``(where, from_s, to_s)`` for each step back in time of more than 0.5 s (NaN ignored).

    Examples
    --------
    >>> backwards_steps(np.array([1.0, 2.0, np.nan, 0.1, 0.2]), np.arange(5))
    [(3, 2.0, 0.1)]
    """
    out: list[tuple[int, float, float]] = []
    last_t, step = np.nan, 1 << 16  # in slices, to keep the temporaries small
    for k in range(0, time_s.size, step):
        ok = np.flatnonzero(np.isfinite(time_s[k : k + step])) + k
        t = np.concatenate([[last_t], time_s[ok]]) if np.isfinite(last_t) else time_s[ok]
        w = np.concatenate([[-1], ok]) if np.isfinite(last_t) else ok
        for i in np.flatnonzero(np.diff(t) < -_BACKWARDS_S).tolist():
            out.append((int(where[w[i + 1]]), float(t[i]), float(t[i + 1])))
        if t.size:
            last_t = t[-1]
    return out


def window_mask(t: np.ndarray, start: float | None, stop: float | None) -> np.ndarray | None:
    """Boolean mask of ``start <= t <= stop`` (None when no bound is given).

    Examples
    --------
    >>> window_mask(np.array([0.0, 1.0, np.nan, 2.0]), 0.5, None).tolist()
    [False, True, False, True]
    """
    if start is None and stop is None:
        return None
    keep = np.isfinite(t)
    if start is not None:
        keep &= t >= start
    if stop is not None:
        keep &= t <= stop
    return keep


def hold_forward(times: np.ndarray, timed: np.ndarray) -> np.ndarray:
    """Each entry's own time where ``timed``, else the latest timed entry's before it (NaN
    before the first).

    Examples
    --------
    >>> hold_forward(np.array([np.nan, 1.0, np.nan, 3.0]), np.array([0, 1, 0, 1], bool))
    array([nan,  1.,  1.,  3.])
    """
    prev = np.where(timed, np.arange(timed.size), -1)
    np.maximum.accumulate(prev, out=prev)
    out = times[np.maximum(prev, 0)]
    out[prev < 0] = np.nan
    return out
