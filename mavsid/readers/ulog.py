"""Read PX4 ULog files (``.ulg``) into a :class:`~mavsid.data.RawLog`, through pyulog.

pyulog already decodes each topic with one ``np.frombuffer`` over its raw bytes; this reader
keeps those arrays as they are (no copy) and adds what the rest of mavsid needs:

- one table per topic instance: ``topic`` for ``multi_id`` 0, ``topic[N]`` otherwise, with
  pyulog's field names (``timestamp``, ``xyz[0]``, ``q[3]``, nested ``a.b``);
- ``time_s``: ``timestamp_sample`` where the topic has it (when the sensor sampled), else
  ``timestamp`` (when it was published), µs → s on the vehicle's boot clock;
- ``params``: the initial parameters, updated by every parameter change in the log;
- ``texts``: logged (and tagged logged) messages, ``severity`` the syslog level 0–7;
- ``modes``: each change of ``vehicle_status.nav_state``, named by PX4's ``NAVIGATION_STATE``;
- ``SourceInfo.notes``: dropouts (count and total length), appended (crash-dump) data,
  parameter changes, topics whose time runs backwards, and pyulog's corruption findings.

A file pyulog flags as corrupt is still returned with pyulog's values and one
:class:`~mavsid.errors.DataQualityWarning`; one it cannot parse at all raises
:class:`~mavsid.errors.LogFormatError`. pyulog's own diagnostics, which it prints, are
captured into the notes instead.

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

import contextlib
import io
import os
import re
import struct
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mavsid.data import MessageTable, ModeChange, RawLog, SourceInfo, TextMessage
from mavsid.errors import DataQualityWarning, LogFormatError
from mavsid.readers.tlog import vehicle_class

__all__ = ["NAV_STATES", "read", "table_name"]

#: PX4 ``vehicle_status.nav_state`` values whose meaning has not changed across releases
#: (the others were renamed or freed over time and are left unnamed).
NAV_STATES: dict[int, str] = {
    0: "MANUAL", 1: "ALTCTL", 2: "POSCTL", 3: "AUTO_MISSION", 4: "AUTO_LOITER",
    5: "AUTO_RTL", 10: "ACRO", 12: "DESCEND", 13: "TERMINATION", 14: "OFFBOARD",
    15: "STAB", 17: "AUTO_TAKEOFF", 18: "AUTO_LAND", 19: "AUTO_FOLLOW_TARGET",
    20: "AUTO_PRECLAND", 21: "ORBIT", 22: "AUTO_VTOL_TAKEOFF",
}  # fmt: skip

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


def _parse(path: str | os.PathLike[str], topics: list[str] | None) -> tuple[Any, list[str]]:
    """Run pyulog; returns the ULog and the lines pyulog printed (its diagnostics)."""
    from pyulog import ULog
    from pyulog.core import ULogException

    printed = io.StringIO()
    try:
        with contextlib.redirect_stdout(printed):
            ulog = ULog(os.fspath(path), topics, disable_str_exceptions=True)
    except OSError as exc:
        raise LogFormatError(f"cannot read: {exc.strerror or exc}", path=path) from None
    except (ULogException, ValueError, IndexError, KeyError, struct.error, EOFError) as exc:
        raise LogFormatError(f"not a readable ULog ({exc})", path=path) from None
    lines = [line.strip() for line in printed.getvalue().splitlines() if line.strip()]
    return ulog, lines


def _time_s(data: dict[str, NDArray[Any]]) -> NDArray[np.float64]:
    """``timestamp_sample`` if present, else ``timestamp``, in seconds (NaN if neither)."""
    for key in ("timestamp_sample", "timestamp"):
        if key in data:
            return data[key].astype(np.float64) / 1e6
    n = len(next(iter(data.values()))) if data else 0
    return np.full(n, np.nan)


def _texts(ulog: Any) -> list[TextMessage]:
    """Logged and tagged logged messages in time order; severity from the ASCII level."""
    entries = list(ulog.logged_messages)
    for tagged in ulog.logged_messages_tagged.values():
        entries.extend(tagged)
    texts = []
    for m in entries:
        level = int(m.log_level)
        severity = level - ord("0") if ord("0") <= level <= ord("7") else level
        texts.append(TextMessage(m.timestamp / 1e6, m.message, severity))
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


def _params(ulog: Any) -> tuple[dict[str, float], int]:
    """Initial parameters with later changes applied; and the number of changes."""
    params = {str(k): float(v) for k, v in ulog.initial_parameters.items()}
    for _, name, value in ulog.changed_parameters:
        params[str(name)] = float(value)
    return params, len(ulog.changed_parameters)


def _firmware(info: dict[str, Any]) -> str | None:
    """``PX4 v1.14.0 (board)`` from ``ver_sw_release`` (0xMMmmpptt), else the git hash."""
    name = str(info.get("sys_name", "PX4"))
    board = f" ({info['ver_hw']})" if info.get("ver_hw") else ""
    release = info.get("ver_sw_release")
    if isinstance(release, int) and release > 0 and (release >> 24) > 0:
        major, minor, patch = release >> 24, (release >> 16) & 0xFF, (release >> 8) & 0xFF
        return f"{name} v{major}.{minor}.{patch}{board}"
    sw = info.get("ver_sw")
    return f"{name} {sw}{board}" if sw else None


def _window(table: MessageTable, lo: float, hi: float) -> MessageTable:
    """Rows of ``table`` with ``lo <= time_s <= hi``."""
    keep = (table.time_s >= lo) & (table.time_s <= hi)
    columns = {n: c[keep] for n, c in table.columns.items()}
    return MessageTable(table.name, columns, table.time_s[keep], table.units)


def _base(name: str) -> str:
    """Topic name without its ``[N]`` instance suffix."""
    match = _INSTANCE.match(name)
    return match.group(1) if match else name


def _wanted_topics(messages: Sequence[str] | None) -> tuple[list[str] | None, set[str] | None]:
    """pyulog's topic filter (base names, plus vehicle_status for the modes) and the wanted
    table names (``topic`` wants every instance, ``topic[N]`` only that one)."""
    if messages is None:
        return None, None
    return sorted({_base(n) for n in messages} | {_MODE_TOPIC}), set(messages)


def read(
    path: str | os.PathLike[str],
    messages: Sequence[str] | None = None,
    start: float | None = None,
    stop: float | None = None,
) -> RawLog:
    """Read a PX4 ULog into a :class:`~mavsid.data.RawLog`.

    Parameters
    ----------
    path : path-like
        The ``.ulg`` file.
    messages : sequence of str, optional
        Topics to load (``topic`` for all its instances or ``topic[N]``); default all.
        pyulog then skips the others' data, which is faster.
    start, stop : float, optional
        Keep only samples (and texts, mode changes) with ``start <= time_s <= stop``
        (seconds since boot).

    Raises
    ------
    LogFormatError
        Empty or unreadable file, one pyulog cannot parse, or one without any topic sample
        or parameter (when all topics were asked for).

    Warns
    -----
    DataQualityWarning
        pyulog found corruption (skipped bytes, data of unknown message ids, wrong sizes).
    """
    try:
        size = os.path.getsize(path)
    except OSError as exc:
        raise LogFormatError(f"cannot read: {exc.strerror or exc}", path=path) from None
    if size == 0:
        raise LogFormatError("empty file", path=path)
    topics, wanted = _wanted_topics(messages)
    ulog, printed = _parse(path, topics)
    if messages is None and not ulog.data_list and not ulog.initial_parameters:
        raise LogFormatError("no ULog data (no topic samples, no parameters)", path=path)

    tables: dict[str, MessageTable] = {}
    for d in ulog.data_list:
        name = table_name(d.name, d.multi_id)
        units = {k: "us" for k in ("timestamp", "timestamp_sample") if k in d.data}
        tables[name] = MessageTable(name, d.data, _time_s(d.data), units)
    params, n_changes = _params(ulog)
    texts = _texts(ulog)
    modes = _modes(tables.get(_MODE_TOPIC))
    if start is not None or stop is not None:
        lo = -np.inf if start is None else start
        hi = np.inf if stop is None else stop
        tables = {n: _window(t, lo, hi) for n, t in tables.items()}
        texts = [m for m in texts if lo <= m.time_s <= hi]
        modes = [m for m in modes if lo <= m.time_s <= hi]
    if wanted is not None:
        tables = {n: t for n, t in tables.items() if n in wanted or _base(n) in wanted}

    notes = _notes(ulog, tables, n_changes)
    problems = list(dict.fromkeys(printed))
    if ulog.file_corruption or problems:
        detail = "; ".join(problems[:3])
        if len(problems) > 3:
            detail += f" (+{len(problems) - 3} more)"
        notes.append("pyulog found corruption" + (f": {detail}" if detail else ""))
        warnings.warn(f"{path}: {notes[-1]}", DataQualityWarning, stacklevel=2)
    info = ulog.msg_info_dict
    return RawLog(
        source=SourceInfo(str(path), "ulog", size, 0, tuple(notes)),
        messages=tables,
        params=params,
        texts=tuple(texts),
        modes=tuple(modes),
        autopilot="px4",
        vehicle=vehicle_class(int(params["MAV_TYPE"])) if "MAV_TYPE" in params else None,
        firmware=_firmware(info),
    )


def _notes(ulog: Any, tables: dict[str, MessageTable], n_changes: int) -> list[str]:
    """Data-quality notes: dropouts, appended data, parameter changes, time running back."""
    notes = []
    if ulog.dropouts:
        total = sum(int(d.duration) for d in ulog.dropouts)
        notes.append(f"{len(ulog.dropouts)} dropouts, {total} ms in all")
    if ulog.has_data_appended:
        notes.append("has appended data (crash dump)")
    if n_changes:
        notes.append(f"{n_changes} parameter changes during the log")
    backwards = [n for n, t in tables.items() if len(t) > 1 and np.any(np.diff(t.time_s) < 0)]
    if backwards:
        shown = ", ".join(backwards[:5]) + (" ..." if len(backwards) > 5 else "")
        notes.append(f"time runs backwards in {len(backwards)} topics ({shown})")
    return notes
