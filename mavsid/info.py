"""Summary of a log for ``mavsid info``: what is in it, how fast, and what was skipped.

Works on any :class:`~mavsid.data.RawLog` (every reader's output). :func:`summarize` gives a
JSON-safe dict (``mavsid info --json``), :func:`format_summary` the text a person reads.

Rates are medians: for each message type the median interval between samples (per instance
when the type has an instance column, so two IMUs logged together count as one rate), as Hz,
for types sampled periodically only; parameters, events, texts and definitions are counted
and shown with ``-`` (see :func:`median_rate_hz`).
SYSTEMID runs are alignment's (:func:`mavsid.align.sysid.sysid_runs`): the span of each run's
injected waveform and its settings.

Examples
--------
>>> import numpy as np
>>> from mavsid.data import MessageTable, RawLog, SourceInfo
>>> t = np.arange(0, 1, 0.01)
>>> log = RawLog(SourceInfo("x.bin", "dataflash", 100),
...              {"RATE": MessageTable("RATE", {"R": t}, t, {"R": "deg/s"})})
>>> s = summarize(log)
>>> s["messages"]["RATE"]["count"], s["messages"]["RATE"]["rate_hz"]
(100, 100.0)
>>> print(format_summary(s).splitlines()[0])
x.bin
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from mavsid.channels import column, source_text
from mavsid.data import MessageTable, RawLog
from mavsid.errors import escape
from mavsid.readers.dataflash import INSTANCE_COLUMNS

__all__ = ["EVENT_TYPES", "declared_instance", "format_summary", "median_rate_hz",
           "read_for_summary", "summarize"]



def _num(x: float | None, digits: int | None = None) -> float | None:
    """JSON-safe float (None for NaN/inf), optionally rounded to ``digits`` significant."""
    if x is None or not math.isfinite(x):
        return None
    return float(f"{x:.{digits}g}") if digits else float(x)


def declared_instance(table: MessageTable) -> str | None:
    """The field the log declares as the instance (unit ``instance``), if any.

    >>> declared_instance(MessageTable("X", {"I": np.zeros(1)}, np.zeros(1), {"I": "instance"}))
    'I'
    """
    return next((n for n in table.fields if table.unit(n) == "instance"), None)


def _instance_column(table: MessageTable) -> np.ndarray | None:
    """The values that tell instances apart: the field declared an instance, else one of
    the usual names (an integer column); None when the table has neither."""
    declared = declared_instance(table)
    if declared is not None:
        got = column(table, declared)
        names = table.columns.get(declared)
        if got is None and names is not None and np.ndim(names) == 1 and len(names) == len(
                table):  # instances named by text (SCR.Name)
            return np.asarray(names)
        return got
    for name in INSTANCE_COLUMNS:
        if name in table.columns and np.asarray(table.columns[name]).dtype.kind in "iu":
            return column(table, name)
    return None


#: Record types that are written on events, never sampled (counted, not given a rate).
EVENT_TYPES = frozenset({"FMT", "FMTU", "UNIT", "MULT", "PARM", "PARAM_VALUE", "MSG", "EV",
                         "MODE", "CMD", "ERR", "ARM", "EVT", "VER", "STATUSTEXT", "SIDS",
                         "MISSION_ITEM_INT", "MISSION_ITEM", "COMMAND_LONG", "COMMAND_ACK"})


def median_rate_hz(table: MessageTable, span_s: float | None = None) -> float:
    """Median sample rate (Hz) of one message type, per instance when it has instances; NaN
    for a type that is not sampled periodically.

    Periodic: not an event type (:data:`EVENT_TYPES`), at least 4 samples, and sampled at
    its median rate (intervals up to 3 median ones) for at least 0.5 s (half of ``span_s``,
    the log's span, when that is shorter): a burst of records written together —
    definitions, parameters, texts at boot — has a huge median rate over a few
    milliseconds; a type logged only now and then (SYSTEMID runs) keeps its rate.

    Examples
    --------
    >>> t = np.repeat(np.arange(0.0, 1.0, 0.1), 2)  # two instances stamped together
    >>> tab = MessageTable("IMU", {"I": np.tile([0, 1], 10)}, t, {"I": "instance"})
    >>> round(median_rate_hz(tab), 6)
    10.0
    >>> burst = np.r_[np.arange(0.0, 0.01, 0.001), 50.0]  # ten at boot, one later
    >>> median_rate_hz(MessageTable("CMD", {}, burst)), median_rate_hz(MessageTable("X", {}, burst))
    (nan, nan)
    """
    if table.name in EVENT_TYPES:
        return float("nan")
    t = np.asarray(table.time_s, np.float64)
    inst = _instance_column(table)
    groups = [t] if inst is None else [t[inst == v] for v in _distinct(inst)]
    rates = []
    for g in groups:
        g = g[np.isfinite(g)]
        d = np.diff(g)
        d = d[d > 0]
        if d.size < 3:
            continue
        step = float(np.median(d))
        covered = np.count_nonzero(d <= 3 * step) * step  # time sampled at that rate, s
        if covered < (min(0.5, 0.5 * span_s) if span_s else 0.5):
            continue
        rates.append(1.0 / step)
    return float(np.median(rates)) if rates else float("nan")


def _distinct(values: np.ndarray) -> list[object]:
    """The distinct values of a column (numbers or text; NaN once)."""
    if values.dtype.kind in "biuf":
        return list(np.unique(values[~np.isnan(values)] if values.dtype.kind == "f" else values))
    return list(dict.fromkeys(values.tolist()))


def _span(log: RawLog) -> tuple[float | None, float | None]:
    if log.span_s is not None:
        return _num(log.span_s[0]), _num(log.span_s[1])
    lo, hi = math.inf, -math.inf
    for table in log.messages.values():
        t = table.time_s[np.isfinite(table.time_s)]
        if t.size:
            lo, hi = min(lo, float(t.min())), max(hi, float(t.max()))
    return (_num(lo), _num(hi)) if hi >= lo else (None, None)


def _sysid_runs(log: RawLog) -> tuple[list[dict[str, Any]], list[str]]:
    """Alignment's SYSTEMID runs (:func:`mavsid.align.sysid.sysid_runs`) as JSON-safe dicts
    (:meth:`SysidRun.to_dict <mavsid.data.SysidRun.to_dict>`), and a note when their records
    cannot be read."""
    from mavsid.align.sysid import sysid_runs
    from mavsid.errors import MavsidError

    try:
        runs = sysid_runs(log)
    except MavsidError as exc:
        return [], [f"SYSTEMID runs not read: {exc}"]
    return [{k: _num(v) if isinstance(v, float) else v for k, v in r.to_dict().items()}
            for r in runs], []


def read_for_summary(path: str | os.PathLike[str], **options: Any) -> RawLog:
    """Read ``path`` for :func:`summarize`: a DataFlash ``.bin`` with every message type but
    the ones alignment reads decoded for its times only (``times_only``: the same summary,
    a 1 GB log in a fraction of the time and memory); other formats whole.

    Examples
    --------
    >>> s = summarize(read_for_summary("fixtures/sysid_roll.bin"))
    >>> s["messages"]["RCIN"]["count"], len(s["messages"]["RCIN"]["fields"])
    (330, 15)
    """
    from mavsid.align import FLAG_MESSAGES
    from mavsid.autopilot.presets import preset_messages
    from mavsid.readers import read_log, sniff_format

    fmt = sniff_format(path)
    if fmt != "dataflash":
        return read_log(path, **options)
    log = read_log(path, messages=[*preset_messages(fmt), *FLAG_MESSAGES[fmt]],
                   times_only=True, **options)
    # a declared instance the times-only read left out (not a one-byte integer: ArduPilot
    # 4.5+'s AUXF.function, SCR.Name): those types whole, so that rates count per instance
    whole = [name for name, table in log.messages.items()
             if (inst := declared_instance(table)) is not None and inst not in table.columns]
    if not whole:
        return log
    full = read_log(path, messages=whole, **options)
    return replace(log, messages={**log.messages, **{n: full.messages[n] for n in whole
                                                     if n in full.messages}})


def summarize(log: RawLog) -> dict[str, Any]:
    """Everything ``mavsid info`` shows, as a JSON-safe dict.

    Keys: ``path, format, size_bytes, autopilot, firmware, vehicle, start_s, end_s,
    duration_s, messages`` (name -> ``count, rate_hz, fields`` (name -> unit or None)),
    ``modes`` (``time_s, mode, name``), ``param_count, text_count, sysid_runs`` (each run's
    ``start_s stop_s settings_from`` and settings, :class:`~mavsid.data.SysidRun`), ``channels``
    (the preset ``fit`` would use and per channel its SI ``unit``, ``source`` and the unit it
    is ``read_in`` with where that came from; or the ``error`` why none fits),
    ``skipped_bytes, notes``.
    """
    from mavsid.align import channel_units
    from mavsid.errors import MavsidError

    start, end = _span(log)
    runs, run_notes = _sysid_runs(log)
    try:  # the channels fit would read, and the unit each is read in (and why)
        preset, used = channel_units(log)
        channels: dict[str, Any] = {"preset": preset, "channels": used}
    except MavsidError as exc:
        channels = {"preset": None, "channels": {}, "error": str(exc)}
    messages: dict[str, dict[str, Any]] = {}
    for name in sorted(log.messages):
        table = log.messages[name]
        messages[name] = {
            "count": len(table),
            "rate_hz": _num(median_rate_hz(
                table, None if start is None or end is None else end - start), 6),
            "fields": {f: table.unit(f) for f in table.fields},
        }
    return {
        "path": log.source.path,
        "format": log.source.format,
        "size_bytes": log.source.size_bytes,
        "autopilot": log.autopilot,
        "firmware": log.firmware,
        "vehicle": log.vehicle,
        "start_s": start,
        "end_s": end,
        "duration_s": _num(log.duration_s),
        "messages": messages,
        "modes": [{"time_s": _num(m.time_s), "mode": m.mode, "name": m.name}
                  for m in log.modes],
        "param_count": len(log.params),
        "text_count": len(log.texts),
        "sysid_runs": runs,
        "channels": channels,
        "skipped_bytes": log.source.skipped_bytes,
        "notes": [*log.source.notes, *run_notes],
    }


def _fmt_time(t: float | None) -> str:
    return "?" if t is None else f"{t:.3f} s"


def format_summary(summary: Mapping[str, Any], max_fields: int | None = None) -> str:
    """The text ``mavsid info`` prints for a :func:`summarize` dict.

    ``max_fields`` shortens long field lists (None: all). Text from the log (names, units,
    notes, the firmware) is escaped: control characters are shown, never sent to the
    terminal (:func:`mavsid.errors.escape`).
    """
    s = summary
    e = escape
    lines = [
        f"{e(s['path'])}",
        f"  format      {e(s['format'])} ({s['size_bytes']} bytes), autopilot "
        f"{e(s['autopilot'])}",
        f"  firmware    {e(s['firmware'] or '?')}",
        f"  vehicle     {e(s['vehicle'] or '?')}",
        f"  time        {_fmt_time(s['start_s'])} .. {_fmt_time(s['end_s'])}"
        f" (duration {_fmt_time(s['duration_s'])})",
        f"  parameters  {s['param_count']}, texts {s['text_count']}, "
        f"skipped bytes {s['skipped_bytes']}",
    ]
    lines.append(f"  messages    {len(s['messages'])} types")
    width = max((len(e(n)) for n in s["messages"]), default=4)
    for name, m in s["messages"].items():
        rate = "    -   " if m["rate_hz"] is None else f"{m['rate_hz']:8.2f}"
        fields = [e(f) if u is None else f"{e(f)}[{e(u)}]" for f, u in m["fields"].items()]
        if max_fields is not None and len(fields) > max_fields:
            fields = [*fields[:max_fields], f"... ({len(m['fields'])} fields)"]
        lines.append(f"    {e(name):<{width}} {m['count']:>8} {rate} Hz  {' '.join(fields)}")
    lines.append(f"  modes       {len(s['modes'])} changes")
    for m in s["modes"]:
        lines.append(f"    {_fmt_time(m['time_s']):>12}  {m['mode']:>3} {e(m['name'] or '?')}")
    lines.append(f"  SYSTEMID    {len(s['sysid_runs'])} runs")
    for run in s["sysid_runs"]:
        settings = " ".join(f"{e(k)}={v:.6g}" if isinstance(v, float) else f"{e(k)}={e(v)}"
                            for k, v in run.items() if k not in ("start_s", "stop_s"))
        lines.append(f"    {_fmt_time(run['start_s']):>12} .. {_fmt_time(run['stop_s'])}  "
                     f"{settings}")
    ch = s.get("channels") or {}
    if ch.get("preset"):
        lines.append(f"  channels    preset {e(ch['preset'])} (what fit reads, in SI units)")
        for name, c in ch["channels"].items():
            lines.append(f"    {e(name):<8} [{e(c['unit'])}] <- "
                         f"{e(source_text(c['source'], c.get('read_in')))}")
    elif ch.get("error"):
        lines.append(f"  channels    none: {e(ch['error'])}")
    for note in s["notes"]:
        lines.append(f"  note: {e(note)}")
    return "\n".join(lines)
