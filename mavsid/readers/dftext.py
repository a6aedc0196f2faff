"""ArduPilot DataFlash text logs (``.log``): the comma-separated form with FMT lines.

Each line is ``NAME, value, value, ...`` (delimiter ``", "``, or ``","`` in logs without
``"FMT, "``); ``FMT`` lines define a message's format characters and column names. Values are
those pymavlink presents for text logs: numbers as printed (no format-character scaling: the
text already holds scaled values), ``n N Z`` and the mode ``M`` as text. Lines before the first
FMT line (firmware banner, free RAM) are not records; a banner naming the firmware fills
``RawLog.firmware`` when no MSG record does. Unlike pymavlink, this reader does not derive a
clock from GPS time, so logs whose GPS messages lack a week field read fine.

Each message type's lines are split once and converted column by column with numpy; a line
with too few values or a value that does not parse is skipped, counted and reported in one
:class:`~mavsid.errors.DataQualityWarning`. Timing, parameters, texts and modes follow
:mod:`mavsid.readers.dataflash_assemble`, as for binary logs.

Examples
--------
>>> import os, tempfile
>>> text = ("FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns\\n"
...         "FMT, 129, 15, ATT, Icc, TimeMS,Roll,Pitch\\n"
...         "ATT, 1500, -1.25, 2.5\\n")
>>> with tempfile.NamedTemporaryFile("w", suffix=".log", delete=False) as f:
...     _ = f.write(text)
>>> log = read(f.name)
>>> log["ATT"]["Roll"].tolist(), log["ATT"].time_s.tolist()
([-1.25], [1.5])
>>> os.unlink(f.name)
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator, Sequence

import numpy as np

from mavsid.data import RawLog, SourceInfo
from mavsid.errors import DataQualityWarning, LogFormatError
from mavsid.readers import dataflash_spec as dfspec
from mavsid.readers.dataflash_assemble import (
    assemble,
    backwards_steps,
    hold_forward,
    window_mask,
)
from mavsid.readers.dataflash_formats import Definition
from mavsid.readers.files import LogPath, refuse_options

__all__ = ["read"]

_MAX_BYTES = 1 << 29  # text logs are small (Python splits every line): refuse larger ones


def _null_term(s: str) -> str:
    cut = s.find("\0")
    return s if cut < 0 else s[:cut]


def _convert(values: list[str], ch: str) -> tuple[np.ndarray, np.ndarray]:
    """Column of text values -> (array, ok mask) as pymavlink converts them."""
    kind = dfspec.FORMAT_CHARS[ch].kind
    n = len(values)
    if ch in "aM":  # pymavlink leaves these as the printed text
        out = np.empty(n, dtype=object)
        out[:] = values
        return out, np.ones(n, bool)
    if kind == "str":
        out = np.empty(n, dtype=object)
        out[:] = [_null_term(v) for v in values]
        return out, np.ones(n, bool)
    parse = int if kind == "int" else float
    dtype = np.int64 if kind == "int" else np.float64
    try:
        return np.array([parse(v) for v in values], dtype=dtype), np.ones(n, bool)
    except (ValueError, OverflowError):
        pass
    ok = np.ones(n, bool)
    out = np.zeros(n, dtype)
    for k, v in enumerate(values):
        try:
            out[k] = parse(v)
        except (ValueError, OverflowError):
            ok[k] = False
    return out, ok


def read(path: LogPath, messages: Sequence[str] | None = None, start: float | None = None,
         stop: float | None = None, **options: object) -> RawLog:
    """Read a DataFlash text log; same parameters and result as
    :func:`mavsid.readers.dataflash.read`.

    Raises
    ------
    LogFormatError
        The file cannot be opened or holds no FMT line or no decodable record.
    """
    spath = os.fspath(path)
    refuse_options(spath, options, "DataFlash text logs")
    try:
        size = os.path.getsize(spath)
        if size > _MAX_BYTES:
            raise LogFormatError(f"text log too large ({size} bytes)", path=spath)
        with open(spath, "rb") as f:
            raw = f.read()
    except OSError as exc:
        raise LogFormatError(f"cannot open: {exc.strerror or exc}", path=spath) from None
    text = raw.decode("utf-8", errors="replace")
    delim = ", " if "FMT, " in text else ","
    first = text.find("FMT" + delim)
    if first < 0:
        raise LogFormatError("no FMT line: not a DataFlash text log", path=spath)
    banner = [ln.strip() for ln in text[:first].splitlines() if ln.strip()]
    body = text[first:]
    del text, raw

    # pass 1: the definitions (FMT lines), so that pass 2 keeps only records it can decode
    defs: dict[str, list[tuple[int, Definition]]] = {}
    bad_lines = 0
    for k, line in _numbered_lines(body, "FMT" + delim):
        fields = _split(line, delim)
        d = _definition(fields, delim) if fields[0] == "FMT" else None
        if d is None:
            bad_lines += fields[0] == "FMT"
            continue
        defs.setdefault(d.name, []).append((k, d))
    defs.setdefault("FMT", []).insert(0, (-1, Definition(128, "FMT", 89, "BBnNZ", (
        "Type", "Length", "Name", "Format", "Columns"))))

    # pass 2: the records, a slice of lines at a time, each message's lines converted to
    # columns at once (memory follows the values, not one Python list per line)
    wanted = None if messages is None else set(messages)
    pieces: dict[str, list[tuple[np.ndarray, dict[str, np.ndarray]]]] = {}
    undefined = 0
    records: dict[str, list[tuple[int, list[str]]]] = {}

    def flush() -> None:
        nonlocal bad_lines
        for name, recs in records.items():
            cols, line_no, _, bad = _decode(recs, defs[name])
            bad_lines += bad
            pieces.setdefault(name, []).append((line_no, cols))
        records.clear()

    count = 0
    for k, line in _numbered_lines(body):
        fields = _split(line, delim)
        if len(fields) < 2:
            continue
        name = fields[0]
        if name not in defs:
            undefined += 1
            continue
        if name == "FMT" and _definition(fields, delim) is None:
            continue  # counted in pass 1
        records.setdefault(name, []).append((k, fields))
        count += 1
        if count >= _LINES_PER_SLICE:
            flush()
            count = 0
    flush()
    decoded: dict[str, tuple[np.ndarray, dict[str, np.ndarray], Definition]] = {}
    for name, parts in pieces.items():
        d = defs[name][-1][1]
        line_no = np.concatenate([ln for ln, _ in parts])
        cols = {c: np.concatenate([p[c] for _, p in parts]) for c in parts[0][1]}
        del parts[:]
        if line_no.size:
            decoded[name] = (line_no, cols, d)
    pieces.clear()
    if not decoded:
        raise LogFormatError("no decodable DataFlash text records", path=spath)
    # the records' times in file order (only decoded lines: others have none to give)
    where = np.sort(np.concatenate([line_no for line_no, _, _ in decoded.values()]))
    timeline = np.full(where.size, np.nan)
    timed_line = np.zeros(where.size, bool)
    for line_no, cols, d in decoded.values():
        if d.time_field is not None:
            tname, _, scale = d.time_field
            at = np.searchsorted(where, line_no)
            timeline[at] = cols[tname].astype(np.float64) * scale
            timed_line[at] = True
    gps_note = ""
    if timed_line.any():
        held = hold_forward(timeline, timed_line)
    else:
        held, gps_note = _gps_clock(decoded, where)
        if not gps_note:
            gps_note = ("no boot-time field (TimeUS/TimeMS) and no GPS time in this log: its "
                        "records have no time (counted, not given a rate or a span)")

    columns, times, defs_by_name = {}, {}, {}
    for name, (line_no, cols, d) in decoded.items():
        defs_by_name[name] = d
        times[name] = held[np.searchsorted(where, line_no)]
        columns[name] = cols
    meta_columns, meta_times = dict(columns), dict(times)
    if wanted is not None or start is not None or stop is not None:
        for name in list(columns):
            if wanted is not None and name not in wanted:
                del columns[name], times[name]
                continue
            keep = window_mask(times[name], start, stop)
            if keep is not None:
                columns[name] = {k: v[keep] for k, v in columns[name].items()}
                times[name] = times[name][keep]

    notes = [gps_note] if gps_note else []
    if bad_lines:
        notes.append(f"skipped {bad_lines} line(s) with missing or unparsable values")
    if undefined:
        notes.append(f"skipped {undefined} line(s) of message types without FMT")
    steps = backwards_steps(timeline, where)
    if steps:
        shown = ", ".join(f"line {w + 1} ({t0:.3f} s -> {t1:.3f} s)" for w, t0, t1 in steps[:5])
        notes.append(f"time goes backwards {len(steps)} time(s) (reboot or concatenated logs): "
                     f"{shown}")
    source = SourceInfo(spath, "dataflash-text", size, skipped_bytes=0, notes=tuple(notes))
    if notes:
        warnings.warn(f"{spath}: " + "; ".join(notes), DataQualityWarning, stacklevel=2)
    return assemble(source, columns, times, defs_by_name, wanted, meta_columns, meta_times,
                    banner=banner)


def _gps_clock(
    decoded: dict[str, tuple[np.ndarray, dict[str, np.ndarray], Definition]], where: np.ndarray
) -> tuple[np.ndarray, str]:
    """Times for a log with no boot-time field at all (ArduCopter 3.0/3.1 text logs): the GPS
    message's own milliseconds since boot (``GPS.T``, 3.1; pymavlink's clock for such logs),
    else the GPS receiver's time of week at each 3D fix; every record interpolated by its
    place in the file between them; records outside them stay untimed (NaN). (The time of
    week of a 3.1 log's first fix can be stale: seconds before the next.)

    Examples
    --------
    >>> gps = {"Status": np.array([1, 3, 3]), "Time": np.array([0, 1000, 2000])}
    >>> t, note = _gps_clock({"GPS": (np.array([1, 4, 8]), gps, None)},  # type: ignore[dict-item]
    ...                      np.array([1, 2, 4, 6, 8, 9]))
    >>> t.tolist()
    [nan, nan, 1.0, 1.5, 2.0, nan]
    >>> note.startswith("no boot-time field")
    True
    >>> gps["T"] = np.array([500, 700, 900])    # a 3.1 log: its boot clock, fix or not
    >>> t, _ = _gps_clock({"GPS": (np.array([1, 4, 8]), gps, None)},  # type: ignore[dict-item]
    ...                   np.array([1, 2, 4, 6, 8, 9]))
    >>> np.round(t, 3).tolist()
    [0.5, 0.567, 0.7, 0.8, 0.9, nan]
    """
    none = np.full(where.size, np.nan)
    gps = decoded.get("GPS")
    if gps is None:
        return none, ""
    line_no, cols, _ = gps
    if "T" in cols:  # (3.1) the GPS message's own boot clock, ms: every record has it
        boot = cols["T"].astype(np.float64)
        lines, secs = line_no[boot > 0], boot[boot > 0] * 1e-3
        source = "GPS.T (ms since boot) of {n} GPS records"
    else:
        clock = next((c for c in ("TimeMS", "Time", "GMS") if c in cols), None)
        if clock is None or "Status" not in cols:
            return none, ""
        ms = cols[clock].astype(np.float64)
        fix = (cols["Status"].astype(np.float64) >= 3) & (ms > 0)
        lines, secs = line_no[fix], ms[fix] * 1e-3
        source = "GPS time of week of {n} 3D fixes"
    if secs.size:  # keep a strictly increasing run of fixes (a week rollover ends it)
        keep = secs > np.maximum.accumulate(np.concatenate([[-np.inf], secs[:-1]]))
        lines, secs = lines[keep], secs[keep]
    if secs.size < 2:
        return none, ""
    pos = where.astype(np.float64)
    out = np.interp(pos, lines.astype(np.float64), secs)
    out[(pos < lines[0]) | (pos > lines[-1])] = np.nan
    note = (f"no boot-time field (TimeUS/TimeMS) in this log: records timed by the "
            f"{source.format(n=secs.size)}, interpolated by their place in the file; "
            "records before the first or after the last are untimed")
    return out, note


_LINES_PER_SLICE = 1 << 16  # records split and held before they are converted to columns


_SLICE_CHARS = 1 << 18  # text split into lines at a time


def _numbered_lines(body: str, prefix: str | None = None) -> Iterator[tuple[int, str]]:
    """``(line number, line)`` of ``body`` split at newlines, a slice of the text at a time
    (only the slice's lines exist at once); with ``prefix``, only the lines starting so."""
    k, at, n = 0, 0, len(body)
    while at <= n:
        nl = body.find("\n", min(at + _SLICE_CHARS, n))
        end = n if nl < 0 else nl
        lines = body[at:end].split("\n")
        if prefix is None:
            yield from enumerate(lines, k)
        else:
            yield from ((j, ln) for j, ln in enumerate(lines, k) if ln.startswith(prefix))
        k += len(lines)
        at = end + 1


def _split(line: str, delim: str) -> list[str]:
    fields = line.rstrip().split(delim)
    if len(fields) == 5 and fields[-1] == ",":  # an FMT line with empty format and columns
        fields[-1:] = ["", ""]
    return fields


def _definition(fields: list[str], delim: str) -> Definition | None:
    """The definition an FMT line gives, or None when it is malformed."""
    if len(fields) < 5:
        return None
    try:
        ftype, length = int(fields[1]), int(fields[2])
    except ValueError:
        return None
    name, fmt = fields[3].strip(), fields[4].strip()
    columns = ",".join(fields[5:]) if delim == "," else (fields[5] if len(fields) > 5 else "")
    if name == "FMT" and columns == "Type,Length,Name,Format":
        columns += ",Columns"  # some text logs omit it
    if not name or any(c not in dfspec.FORMAT_CHARS for c in fmt):
        return None
    cols = tuple(columns.split(",")) if columns else ()
    return Definition(ftype, name, length, fmt, cols)


def _decode(
    recs: list[tuple[int, list[str]]], versions: list[tuple[int, Definition]]
) -> tuple[dict[str, np.ndarray], np.ndarray, Definition, int]:
    """Columns of one message's lines (with the latest layout, earlier layouts dropped
    when they differ), their line numbers, the definition and the count of bad lines."""
    # the definition in force at each line: the latest FMT before it, else the first one
    starts = [k for k, _ in versions]
    line_no = np.array([k for k, _ in recs], np.int64)
    which = np.maximum(np.searchsorted(starts, line_no, side="right") - 1, 0)
    d = versions[-1][1]
    use = np.array([versions[w][1].format == d.format and versions[w][1].columns == d.columns
                    for w in which.tolist()], bool)
    width = len(d.format) + 1
    rows = [f for (_, f), u in zip(recs, use.tolist(), strict=True) if u and len(f) >= width]
    keep = np.array([u and len(f) >= width for (_, f), u in zip(recs, use.tolist(),
                                                                 strict=True)], bool)
    bad = int((~keep).sum())
    line_no = line_no[keep]
    ok = np.ones(len(rows), bool)
    cols: dict[str, np.ndarray] = {}
    for name, i in d.fields:
        cols[name], good = _convert([r[i + 1] for r in rows], d.format[i])
        ok &= good
    if not ok.all():
        bad += int((~ok).sum())
        cols = {k: v[ok] for k, v in cols.items()}
        line_no = line_no[ok]
    return cols, line_no, d, bad
