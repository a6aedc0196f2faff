"""Read PX4 ULog files (``.ulg``) into a :class:`~mavsid.data.RawLog`.

The reader gives the values pyulog gives (the reference the tests compare against field by
field), ten to seventy times faster. pyulog is not used at run time. The work is shared by
the modules of one concept each:

- :mod:`~mavsid.readers.ulog_spec`: the format's facts, shared with the simulator's writer;
- :mod:`~mavsid.readers.ulog_messages`: one message's payload (info, parameters, formats);
- :mod:`~mavsid.readers.ulog_layout`: formats flattened to record layouts, and a topic's
  columns over its records' bytes;
- :mod:`~mavsid.readers.ulog_definitions`: the header and the definitions section;
- :mod:`~mavsid.readers.ulog_data`: the data section (its *Framing*), and the compiled pass
  that reads a log with nothing unusual in it in one go;
- this module: the topics, parameters, texts and modes turned into a RawLog.

A table's columns are strided views over its records' bytes
(:class:`~mavsid.readers.ulog_layout.Fields`: no structured dtype is built), made when first
asked for: most of a log's hundred topics and thousands of fields are never looked at. The
file is mapped.

What the returned log holds:

- one table per topic instance: ``topic`` for ``multi_id`` 0, ``topic[N]`` otherwise, with
  pyulog's field names (``timestamp``, ``xyz[0]``, ``q[3]``, nested ``a.b``; padding fields
  kept, except those at the end of a format, which pyulog drops);
- ``time_s``: ``timestamp_sample`` where the topic has it (when the sensor sampled), else
  ``timestamp`` (when it was published), µs → s on the vehicle's boot clock;
- ``params``: the initial parameters, updated by every parameter change in the log;
- ``texts``: logged (and tagged logged) messages, ``severity`` the syslog level 0–7;
- ``modes``: each change of ``vehicle_status.nav_state``, named by PX4's ``NAVIGATION_STATE``;
- ``SourceInfo.notes``: dropouts (count and total length), appended (crash-dump) data,
  parameter changes, topics whose time runs backwards, corruption found, and a last
  message cut off by the end of the file; ``SourceInfo.skipped_bytes`` counts the bytes
  stepped over to resynchronise, those of data messages that could not be decoded (wrong
  size, no subscription) and a truncated last message.

Bad input is one :class:`~mavsid.errors.LogFormatError` naming the file: a bad header,
incompatible flags, formats that contain themselves (pyulog would recurse without end)
or nest too deeply, an empty log. A file with corruption is returned with what could be
decoded and one :class:`~mavsid.errors.DataQualityWarning`.

Examples
--------
>>> import os, tempfile
>>> with tempfile.NamedTemporaryFile(suffix=".ulg", delete=False) as f:
...     _ = f.write(b"ULog\\x01\\x12\\x35\\x01" + bytes(4))
>>> read(f.name)
Traceback (most recent call last):
...
mavsid.errors.LogFormatError: ...: not a readable ULog (Invalid file format (Header too short))
>>> os.unlink(f.name)
"""

from __future__ import annotations

import math
import re
import warnings
from collections.abc import Mapping, Sequence
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from mavsid.autopilot.modes import NAV_STATES, vehicle_class
from mavsid.data import (
    MessageTable,
    ModeChange,
    RawLog,
    SourceInfo,
    TextMessage,
    param_changes,
)
from mavsid.errors import DataQualityWarning, LogFormatError, first_few
from mavsid.readers.files import LogPath, mapped, refuse_options
from mavsid.readers.ulog_data import parse
from mavsid.readers.ulog_definitions import Parsed
from mavsid.readers.ulog_layout import Fields, field_index
from mavsid.readers.ulog_messages import InfoValue

__all__ = ["NAV_STATES", "read", "table_name"]

_MODE_TOPIC = "vehicle_status"
_INSTANCE = re.compile(r"^(.*)\[(\d+)\]$")


def table_name(topic: str, multi_id: int) -> str:
    """The table name of one topic instance.

    Examples
    --------
    >>> table_name("actuator_outputs", 0), table_name("actuator_outputs", 1)
    ('actuator_outputs', 'actuator_outputs[1]')
    """
    return topic if multi_id == 0 else f"{topic}[{multi_id}]"



def _times(tables: list[Fields]) -> list[NDArray[np.float64]]:
    """Per table, ``timestamp_sample`` if present, else ``timestamp``, in seconds (NaN if
    neither): the ``uint64`` ones (all in a real log) converted in one go, each table's
    a slice of the whole.

    Examples
    --------
    >>> from mavsid.readers.ulog_layout import new_layout
    >>> ts, x = (new_layout(((n, f"{n}:{t};".encode()),)) for n, t in
    ...          (("a", "uint64_t timestamp"), ("b", "float x")))
    >>> a = Fields(np.array([1_000_000, 2_500_000], "<u8").view(np.uint8), 2, ts)
    >>> b = Fields(np.array([7], "<f4").view(np.uint8), 1, x)
    >>> [t.tolist() for t in _times([a, b, a])]
    [[1.0, 2.5], [nan], [1.0, 2.5]]
    """
    out: list[NDArray[np.float64] | None] = []
    batch: list[NDArray[Any]] = []
    for data in tables:
        fields = field_index(data.layout)  # (looked up directly: a hundred tables)
        key = "timestamp_sample" if "timestamp_sample" in fields else "timestamp"
        column = data[key] if key in fields else None
        if column is None:
            out.append(np.full(data.count, np.nan))
        elif column.dtype == np.uint64:
            out.append(None)
            batch.append(column)
        else:
            out.append(column.astype(np.float64) / 1e6)
    if batch:
        whole = np.concatenate(batch, dtype=np.float64)
        whole /= 1e6
        ends = np.cumsum([len(c) for c in batch]).tolist()
        parts = iter([whole[e - len(c) : e] for c, e in zip(batch, ends, strict=True)])
        return [next(parts) if t is None else t for t in out]
    return [t for t in out if t is not None]


def _texts(parsed: Parsed) -> list[TextMessage]:
    """Logged and tagged logged messages in time order; severity from the ASCII level."""
    entries = list(parsed.logged)
    for tagged in parsed.tagged.values():
        entries.extend(tagged)
    texts = []
    for m in entries:
        level = m.level
        severity = level - ord("0") if ord("0") <= level <= ord("7") else level
        texts.append(TextMessage(m.time_us / 1e6, m.message, severity))
    return sorted(texts, key=lambda t: t.time_s)


def _modes(table: MessageTable | None) -> list[ModeChange]:
    """A ModeChange at the first sample and at each change of ``nav_state``."""
    if table is None or "nav_state" not in table or not len(table):
        return []
    state = table["nav_state"].astype(np.int64)
    change = np.flatnonzero(np.diff(state, prepend=-1) != 0)
    return [
        ModeChange(float(table.time_s[k]), int(state[k]), NAV_STATES.get(int(state[k])))
        for k in change.tolist()
    ]


def _number(value: InfoValue) -> float | None:
    """A parameter's value as float; None for what is not a number (a damaged type string
    leaves raw bytes)."""
    if isinstance(value, (bytes, bytearray, str)) or isinstance(value, bool):
        return None
    try:
        return float(value)
    except (TypeError, ValueError, OverflowError):
        return None


def _params(parsed: Parsed) -> tuple[dict[str, float], int, int]:
    """Initial parameters with later changes applied; the number of changes; and how many
    values were not numbers (skipped)."""
    initial = parsed.initial_params
    params: dict[str, float]
    if parsed.floats:  # (the compiled pass's: floats only)
        params = cast("dict[str, float]", initial.copy())
        entries = [(name, value) for _, name, value in parsed.changed_params]
    elif set(map(type, initial.values())) <= {float, int}:  # the common case: at once
        params = dict(zip(initial, map(float, initial.values()), strict=True))
        entries = [(name, value) for _, name, value in parsed.changed_params]
    else:
        params = {}
        entries = list(initial.items())
        entries += [(name, value) for _, name, value in parsed.changed_params]
    bad = 0
    for name, value in entries:
        if type(value) is float or type(value) is int:  # the common case, directly
            params[name] = float(value)
            continue
        number = _number(value)
        if number is None:
            bad += 1
        else:
            params[str(name)] = number
    return params, len(parsed.changed_params), bad


def _vehicle(mav_type: float | None) -> str | None:
    """The vehicle class of a ``MAV_TYPE`` parameter; None when absent or not a whole number
    (a damaged log's).

    >>> _vehicle(2), _vehicle(float("nan")), _vehicle(None)
    ('copter', None, None)
    """
    if isinstance(mav_type, (int, float)) and math.isfinite(mav_type):
        return vehicle_class(int(mav_type))
    return None


def _firmware(info: Mapping[str, InfoValue]) -> str | None:
    """``PX4 v1.14.0 (board)`` from ``ver_sw_release`` (0xMMmmpptt), else the git hash."""
    name = str(info.get("sys_name", "PX4"))
    board = f" ({info['ver_hw']!s})" if info.get("ver_hw") else ""
    release = info.get("ver_sw_release")
    if isinstance(release, int) and release > 0 and (release >> 24) > 0:
        major, minor, patch = release >> 24, (release >> 16) & 0xFF, (release >> 8) & 0xFF
        return f"{name} v{major}.{minor}.{patch}{board}"
    sw = info.get("ver_sw")
    return f"{name} {sw!s}{board}" if sw else None


def _window(table: MessageTable, lo: float, hi: float) -> MessageTable:
    """Rows of ``table`` with ``lo <= time_s <= hi``."""
    keep = (table.time_s >= lo) & (table.time_s <= hi)
    columns: Mapping[str, NDArray[Any]]
    if isinstance(table.columns, Fields):
        columns = table.columns.rows(keep)
    else:
        columns = {n: c[keep] for n, c in table.columns.items()}
    return MessageTable(table.name, columns, table.time_s[keep], table.units)


def _base(name: str) -> str:
    """Topic name without its ``[N]`` instance suffix."""
    match = _INSTANCE.match(name)
    return match.group(1) if match else name


def _wanted_topics(messages: Sequence[str] | None) -> tuple[set[str] | None, set[str] | None]:
    """The topics to decode (base names, plus vehicle_status for the modes) and the wanted
    table names (``topic`` wants every instance, ``topic[N]`` only that one)."""
    if messages is None:
        return None, None
    return {_base(n) for n in messages} | {_MODE_TOPIC}, set(messages)


def read(path: LogPath, messages: Sequence[str] | None = None, start: float | None = None,
         stop: float | None = None, **options: object) -> RawLog:
    """Read a PX4 ULog into a :class:`~mavsid.data.RawLog`.

    Parameters
    ----------
    path : path-like
        The ``.ulg`` file.
    messages : sequence of str, optional
        Topics to load (``topic`` for all its instances or ``topic[N]``); default all.
        The others' records are framed but not decoded, which is faster.
    start, stop : float, optional
        Keep only samples (and texts, mode changes) with ``start <= time_s <= stop``
        (seconds since boot).
    **options
        None applies to ULog (a ConfigError names any given).

    Raises
    ------
    LogFormatError
        Empty or unreadable file, a bad header or incompatible flags, formats that
        contain themselves, or one without any topic sample or parameter (when all
        topics were asked for).
    ConfigError
        An option was given.

    Warns
    -----
    DataQualityWarning
        Corruption found (bytes skipped to resynchronise, data of unknown message ids,
        wrong sizes, unreadable definitions), or parameter values of an unreadable type.
    """
    refuse_options(path, options, "PX4 ULog files")
    topics, wanted = _wanted_topics(messages)
    with mapped(path, populate=True) as buf:  # (a walk over all of it: mapped at once)
        size = len(buf)
        parsed = parse(buf, path, topics)
    if messages is None and not parsed.data and not parsed.initial_params:
        raise LogFormatError("no ULog data (no topic samples, no parameters)", path=path)

    tables: dict[str, MessageTable] = {}
    times = parsed.times
    if times is None:
        times = _times([data for _, _, data in parsed.data])
    for (topic, multi_id, data), time_s in zip(parsed.data, times, strict=True):
        name = table_name(topic, multi_id)
        units: dict[str, str] = dict.fromkeys(data.layout[5], "us")
        tables[name] = MessageTable(name, data, time_s, units)
    params, n_changes, bad_params = _params(parsed)
    initial = {k: v for k, value in parsed.initial_params.items()
               if (v := _number(value)) is not None}
    changes = param_changes(initial, [(t / 1e6, name, v) for t, name, value in
                                      parsed.changed_params if (v := _number(value)) is not None])
    texts = _texts(parsed)
    modes = _modes(tables.get(_MODE_TOPIC))
    # the log's span: the header's start time to the latest data timestamp
    span = (parsed.start_us / 1e6, max(parsed.last_us, parsed.start_us) / 1e6)
    if start is not None or stop is not None:
        lo = -np.inf if start is None else start
        hi = np.inf if stop is None else stop
        span = (max(span[0], lo), max(min(span[1], hi), max(span[0], lo)))
        tables = {n: _window(t, lo, hi) for n, t in tables.items()}
        texts = [m for m in texts if lo <= m.time_s <= hi]
        modes = [m for m in modes if lo <= m.time_s <= hi]
        changes = tuple(c for c in changes if lo <= c.time_s <= hi)
    if wanted is not None:
        tables = {n: t for n, t in tables.items() if n in wanted or _base(n) in wanted}

    notes = _notes(parsed, tables, n_changes)
    damage = []  # (said in one warning, as a damaged DataFlash file is: nothing silently lost)
    if bad_params:
        damage.append(f"{bad_params} parameter value(s) of an unreadable type skipped")
    problems = parsed.problems
    if parsed.corrupt or problems:
        detail = "; ".join(problems[:3])
        if len(problems) > 3:
            detail += f" (+{len(problems) - 3} more)"
        damage.append("file corruption found" + (f": {detail}" if detail else ""))
    if parsed.truncated:
        damage.append(f"last message truncated: {parsed.truncated} bytes ignored")
    notes += damage
    if damage:
        warnings.warn(f"{path}: {'; '.join(damage)}", DataQualityWarning, stacklevel=2)
    return RawLog(
        source=SourceInfo(str(path), "ulog", size, parsed.skipped + parsed.truncated,
                          tuple(notes)),
        messages=tables,
        params=params,
        texts=tuple(texts),
        modes=tuple(modes),
        autopilot="px4",
        vehicle=_vehicle(params.get("MAV_TYPE")),
        firmware=_firmware(parsed.info),
        span_s=span,
        param_changes=changes,
    )


def _notes(parsed: Parsed, tables: dict[str, MessageTable], n_changes: int) -> list[str]:
    """Data-quality notes: dropouts, appended data, parameter changes, time running back."""
    notes = []
    if parsed.dropouts:
        total = sum(duration for _, duration in parsed.dropouts)
        notes.append(f"{len(parsed.dropouts)} dropouts, {total} ms in all")
    if parsed.appended:
        notes.append("has appended data (crash dump)")
    if n_changes:
        notes.append(f"{n_changes} parameter changes during the log")
    backwards = _backwards(tables)
    if backwards:
        notes.append(f"time runs backwards in {len(backwards)} topics "
                     f"({first_few(backwards)})")
    return notes


def _backwards(tables: dict[str, MessageTable]) -> list[str]:
    """The tables whose time runs backwards somewhere, in order: all checked at once.

    Examples
    --------
    >>> def table(t):
    ...     return MessageTable("x", {}, np.array(t, float))
    >>> _backwards({"a": table([1, 2]), "b": table([0, 1, 0.5]), "c": table([1])})
    ['b']
    """
    timed = [(name, t.time_s) for name, t in tables.items() if t.time_s.size > 1]
    if not timed:
        return []
    lengths = np.array([t.size for _, t in timed])
    starts = np.cumsum(lengths) - lengths
    whole = np.concatenate([t for _, t in timed])
    back = np.flatnonzero(whole[1:] < whole[:-1])  # whole[i + 1] < whole[i]
    owner = np.searchsorted(starts, back, "right") - 1
    inside = back + 1 < starts[owner] + lengths[owner]  # i and i + 1 in one table
    # (not np.unique: its first call imports numpy.ma, 15 ms of a cold read)
    hit = np.bincount(owner[inside], minlength=len(timed))
    return [timed[k][0] for k in np.flatnonzero(hit).tolist()]
