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
import signal
import struct
import threading
import warnings
from collections.abc import Iterator, Sequence
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


#: Time pyulog may take: a fixed part plus this much per MB of file (far above its ~1 µs per
#: message) before the read is abandoned as hostile.
_PARSE_S, _PARSE_S_PER_MB = 20.0, 5.0
#: Definitions are read from the head of the file only (real ones take a few hundred kB).
_DEFINITIONS_MAX_BYTES = 64 << 20


def _format_cycle(path: str | os.PathLike[str]) -> list[str] | None:
    """A chain of message formats that contain themselves (``a`` → ``b`` → ``a``), found in
    the definitions at the head of the file; None when there is none.

    pyulog expands nested formats recursively: a format that contains itself, directly or
    through others, is a RecursionError (or an endless loop) there, so it is refused first.

    Examples
    --------
    >>> import tempfile
    >>> def msg(kind, text):
    ...     return struct.pack("<HB", len(text), ord(kind)) + text.encode()
    >>> body = msg("F", "a:uint64_t timestamp;b x;") + msg("F", "b:a y[2];")
    >>> with tempfile.NamedTemporaryFile(suffix=".ulg", delete=False) as f:
    ...     _ = f.write(b"ULog" + bytes(12) + body)
    >>> _format_cycle(f.name)
    ['a', 'b', 'a']
    """
    with open(path, "rb") as f:
        head = f.read(_DEFINITIONS_MAX_BYTES)
    graph: dict[str, set[str]] = {}
    pos = 16
    while pos + 3 <= len(head):
        size, kind = struct.unpack_from("<HB", head, pos)
        payload = head[pos + 3 : pos + 3 + size]
        pos += 3 + size
        if kind in (ord("A"), ord("D"), ord("L")):  # the data section has begun
            break
        if kind != ord("F"):
            continue
        name, _, fields = payload.decode("ascii", "replace").partition(":")
        types = {f.strip().split(" ")[0].split("[")[0] for f in fields.split(";") if f.strip()}
        graph.setdefault(name, set()).update(types)
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def visit(node: str, chain: list[str]) -> list[str] | None:
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return [*chain, node, nxt][[*chain, node].index(nxt):]
            if nxt in graph and state.get(nxt) is None and (got := visit(nxt, [*chain, node])):
                return got
        state[node] = 2
        return None

    for start in sorted(graph):
        if state.get(start) is None and (cycle := visit(start, [])):
            return cycle
    return None


@contextlib.contextmanager
def _time_limit(seconds: float) -> Iterator[None]:
    """Raise TimeoutError in the block after ``seconds`` (main thread on POSIX; elsewhere no
    limit can be set on a running parser, and the block runs unbounded)."""
    if (not hasattr(signal, "setitimer")
            or threading.current_thread() is not threading.main_thread()):
        yield
        return

    def expire(signum: int, frame: object) -> None:
        raise TimeoutError

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def _parse(path: str | os.PathLike[str], topics: list[str] | None) -> tuple[Any, list[str]]:
    """Run pyulog, bounded: returns the ULog and the lines pyulog printed (its diagnostics).

    Third-party parsing of an untrusted file: self-containing formats are refused before it
    runs, it gets a time limit proportional to the file, and whatever it raises becomes one
    :class:`~mavsid.errors.LogFormatError` naming the file.
    """
    from pyulog import ULog
    from pyulog.core import ULogException

    try:
        cycle = _format_cycle(path)
        size_mb = os.path.getsize(path) / 1e6
    except OSError as exc:
        raise LogFormatError(f"cannot read: {exc.strerror or exc}", path=path) from None
    if cycle:
        raise LogFormatError("message format " + " -> ".join(cycle) + " contains itself "
                             "(a damaged or hostile definition)", path=path)
    limit = _PARSE_S + _PARSE_S_PER_MB * size_mb
    printed = io.StringIO()
    try:
        with contextlib.redirect_stdout(printed), _time_limit(limit):
            ulog = ULog(os.fspath(path), topics, disable_str_exceptions=True)
    except OSError as exc:
        raise LogFormatError(f"cannot read: {exc.strerror or exc}", path=path) from None
    except TimeoutError:
        raise LogFormatError(f"pyulog did not finish within {limit:.0f} s (a damaged or "
                             "hostile file)", path=path) from None
    except (ULogException, ValueError, IndexError, KeyError, struct.error, EOFError) as exc:
        raise LogFormatError(f"not a readable ULog ({exc})", path=path) from None
    except RecursionError:
        raise LogFormatError("not a readable ULog (definitions nested without end)",
                             path=path) from None
    except MemoryError:
        raise LogFormatError("not a readable ULog (pyulog ran out of memory)",
                             path=path) from None
    except Exception as exc:  # any failure of the third-party parser
        raise LogFormatError(f"not a readable ULog ({type(exc).__name__}: {exc})",
                             path=path) from None
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


def _number(value: Any) -> float | None:
    """A parameter's value as float; None for what is not a number (a damaged type string
    leaves pyulog with raw bytes)."""
    if isinstance(value, (bytes, bytearray, str)) or isinstance(value, bool):
        return None
    try:
        return float(value)
    except (TypeError, ValueError, OverflowError):
        return None


def _params(ulog: Any) -> tuple[dict[str, float], int, int]:
    """Initial parameters with later changes applied; the number of changes; and how many
    values were not numbers (skipped)."""
    params: dict[str, float] = {}
    bad = 0
    entries = [(k, v) for k, v in ulog.initial_parameters.items()]
    entries += [(name, value) for _, name, value in ulog.changed_parameters]
    for name, value in entries:
        number = _number(value)
        if number is None:
            bad += 1
        else:
            params[str(name)] = number
    return params, len(ulog.changed_parameters), bad


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
    params, n_changes, bad_params = _params(ulog)
    texts = _texts(ulog)
    modes = _modes(tables.get(_MODE_TOPIC))
    # the log's span as pyulog has it: the header's start time to the latest data timestamp
    span = (ulog.start_timestamp / 1e6, max(ulog.last_timestamp, ulog.start_timestamp) / 1e6)
    if start is not None or stop is not None:
        lo = -np.inf if start is None else start
        hi = np.inf if stop is None else stop
        span = (max(span[0], lo), max(min(span[1], hi), max(span[0], lo)))
        tables = {n: _window(t, lo, hi) for n, t in tables.items()}
        texts = [m for m in texts if lo <= m.time_s <= hi]
        modes = [m for m in modes if lo <= m.time_s <= hi]
    if wanted is not None:
        tables = {n: t for n, t in tables.items() if n in wanted or _base(n) in wanted}

    notes = _notes(ulog, tables, n_changes)
    if bad_params:
        notes.append(f"{bad_params} parameter value(s) of an unreadable type skipped")
        warnings.warn(f"{path}: {notes[-1]}", DataQualityWarning, stacklevel=2)
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
        span_s=span,
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
