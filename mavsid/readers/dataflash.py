"""ArduPilot DataFlash binary logs (``.bin``): columnar, vectorised decoding.

A DataFlash log is a sequence of records ``0xA3 0x95 <type> <payload>``. FMT records (type 128,
89 bytes) declare each type's length, name, format characters and column names. This reader

1. memory-maps the file and finds every ``0xA3 0x95`` pair with numpy (the *candidates*);
2. reads the FMT definitions (a type may be redefined later in the log, e.g. in concatenated
   logs: each record uses the definition in force at its position, or the type's first one);
3. frames the log: a candidate is a record when its type is defined, it fits in the file, and
   either a header follows exactly where it ends (forward evidence) or the
   record before it ends exactly where it starts (backward evidence; a record with only
   backward evidence may not swallow a record with forward evidence), or it is a well-formed
   FMT record, or it has no evidence but lies outside the declared span of every header that
   has some and has no header inside its own span (a lone record between two stretches of
   garbage; not a header-like pattern inside a cut last record, nor one of a flood of header
   patterns). From the first record, each record is
   followed by the next one at or after its end, so garbage is skipped and reading resumes on
   the next valid record. The rules are evaluated on the few candidates not followed at once
   by the next one; every other candidate is a record of the chain;
4. decodes only the records asked for: each type's records are copied out of the file
   through an overlapping view in cache-sized slices (one fancy-indexing call per slice; a
   few narrow columns of wide records, field by field) and every field is written straight
   into its preallocated column (a message's columns are carved out of one allocation), a
   64 MB block of the file at a time for every message.

A cold read (the first in a process) pays for every fresh page it writes: the reader keeps
its temporaries few and small and writes results in place.

Values are those pymavlink presents: format characters ``c C e E`` are divided by 100 and ``L``
by 1e7 (as pymavlink does it: ``value / (1 / multiplier)``), ``a`` is an ``int16[32]`` row,
``n N Z`` are ``str`` (UTF-8, else Latin-1, cut at the first NUL; ``FILE.Data`` stays raw
``bytes``), ``g`` is a half float (given as float32), ``M`` the raw mode number. FMTU/UNIT/MULT
give per-field units and multipliers as metadata; the multipliers are *not* applied, and none
is given for fields the format character already scales.

Time: ``time_s`` is ``TimeUS * 1e-6`` (old logs: ``TimeMS * 1e-3``, except GPS messages, whose
``TimeMS`` is GPS time of week; a PX4 sdlog2 ``.px4log``: its ``TIME.StartTime``, µs since
boot, written at the start of each logging cycle). A message without such a field gets the
time of the latest timestamped record before it in the file (NaN before the first one); the
choice is a hold, not an interpolation, so that a parameter or text is never stamped with a
time it was not yet written at. Times are kept as logged: after a reboot or in concatenated
logs they go backwards; the reader notes where (``SourceInfo.notes``) and warns.

Examples
--------
>>> import os, tempfile
>>> from mavsid.readers.dataflash_spec import build_record, build_fmt
>>> data = build_fmt(0x81, "TST", "Qc", "TimeUS,Val") + build_record(0x81, "Qc", 1_500_000, -1234)
>>> with tempfile.NamedTemporaryFile(suffix=".bin", delete=False) as f:
...     _ = f.write(data)
>>> log = read(f.name)
>>> log["TST"]["Val"].tolist(), log["TST"].time_s.tolist()
([-12.34], [1.5])
>>> os.unlink(f.name)
"""

from __future__ import annotations

import functools
import os
import warnings
from collections.abc import Callable, Sequence

import numpy as np

from mavsid.data import RawLog, SourceInfo
from mavsid.errors import DataQualityWarning, LogFormatError
from mavsid.readers import dataflash_spec as dfspec
from mavsid.readers.arrays import group, lookup, select, sorted_concat, unique
from mavsid.readers.dataflash_assemble import (
    assemble,
    backwards_steps,
    hold_forward,
    vehicle_and_firmware,
    window_mask,
)
from mavsid.readers.dataflash_decode import (
    alloc_columns,
    bounded_layouts,
    decode_message,
    gather_by_block,
    gather_times,
    plan_message,
    times_of,
)
from mavsid.readers.dataflash_formats import (
    Definition,
    Definitions,
    autopilot_of,
    column_layout,
    read_definitions,
    time_slot,
)
from mavsid.readers.dataflash_framing import NEAR, Framing, frame
from mavsid.readers.dataflash_scan import find_headers, records_at, release_pages
from mavsid.readers.files import LogPath, mapped, refuse_options

__all__ = [
    "INSTANCE_COLUMNS",
    "Definition",
    "assemble",
    "backwards_steps",
    "hold_forward",
    "read",
    "vehicle_and_firmware",
    "window_mask",
]


# always decoded: parameters, texts, modes, units, firmware
_META_NAMES = frozenset({"FMTU", "UNIT", "MULT", "PARM", "MSG", "MODE", "VER"})


#: columns that tell a message's instances apart, by name (decoded with the times by
#: ``times_only``, as are all one-byte integer columns; ``mavsid info`` groups rates by them)
INSTANCE_COLUMNS = ("I", "Instance", "C", "Id")


_FORMAT_ONLY = frozenset({"FMT", "FMTU", "UNIT", "MULT"})


def read(path: LogPath, messages: Sequence[str] | None = None, start: float | None = None,
         stop: float | None = None, times_only: bool = False, **options: object) -> RawLog:
    """Read a DataFlash ``.bin`` log.

    Parameters
    ----------
    path : path-like
        The log.
    messages : sequence of str, optional
        Return only these message types (names absent from the log are ignored; asking
        ``RawLog`` for one raises :class:`~mavsid.errors.MissingMessageError`). Parameters,
        texts and modes are always read.
    start, stop : float, optional
        Keep only records with ``start <= time_s <= stop`` (seconds of ``TimeUS``); records
        without a time are then dropped. Parameters, texts and modes come from the whole log.
    times_only : bool
        Also return every other message type, with only its times and the columns that may
        tell instances apart (:data:`INSTANCE_COLUMNS` and one-byte integers) decoded and its
        fields listed in ``MessageTable.declared``:
        enough to count, time and describe them (``mavsid info``) at a fraction of the cost.
        None applies to DataFlash logs (``read_log`` passes other formats' options on).

    Returns
    -------
    RawLog

    Raises
    ------
    LogFormatError
        The file cannot be opened or holds no decodable record.
    ConfigError
        An option was given.

    Warns
    -----
    DataQualityWarning
        Once, when bytes were skipped, definitions were unusable, time went backwards or the
        log holds only format definitions.
    """
    spath = os.fspath(path)
    refuse_options(spath, options, "DataFlash .bin logs")
    with mapped(spath) as buf:
        return _read_buffer(spath, np.frombuffer(buf, dtype=np.uint8), messages, start, stop,
                            times_only)


def _read_buffer(
    path: str,
    a: np.ndarray,
    messages: Sequence[str] | None,
    start: float | None,
    stop: float | None,
    times_only: bool = False,
) -> RawLog:
    n = a.size
    notes: list[str] = []
    wanted = None if messages is None else set(messages)
    cand, types = find_headers(a)
    fmt_at = np.flatnonzero(types == dfspec.FMT_TYPE)  # (few)
    fmt_pos = cand[fmt_at]
    table = read_definitions(a, fmt_pos[fmt_pos <= n - dfspec.FMT_LENGTH])
    framing = frame(a, cand, types, table)
    release_pages(a, 0, n)
    # definitions only from FMT records that are part of the log (rarely differs; FMT is
    # definition 0, that of every FMT record and of no other type)
    fmt_kept = fmt_pos[framing.defid[fmt_at] == 0]
    plausible = np.array(table.plausible, fmt_kept.dtype)
    at = np.minimum(np.searchsorted(fmt_kept, plausible), max(fmt_kept.size - 1, 0))
    if plausible.size and (fmt_kept.size == 0 or np.any(fmt_kept[at] != plausible)):
        table = read_definitions(a, fmt_kept)
        framing = frame(a, cand, types, table)
    if framing.count == 0:
        raise LogFormatError("no DataFlash records found", path=path)
    skip_at, skip_len = framing.skip_at, framing.skip_len
    skipped = int(skip_len.sum())
    if skipped:
        lo = np.searchsorted(cand, skip_at[:1000].astype(cand.dtype))
        hi = np.searchsorted(cand, (skip_at[:1000] + skip_len[:1000]).astype(cand.dtype))
        inside = np.concatenate([cand[i:j] for i, j in zip(lo, hi, strict=True)])
        unknown = sorted(set(np.flatnonzero(np.bincount(a[inside + 2], minlength=256))
                             .tolist()) - set(table.by_type))
        shown = ", ".join(f"{int(o)}+{int(k)}" for o, k in zip(skip_at[:5], skip_len[:5],
                                                              strict=True))
        notes.append(f"skipped {skipped} undecodable byte(s) in {skip_at.size} region(s) "
                     f"(offset+size: {shown}{', ...' if skip_at.size > 5 else ''})"
                     + (f"; undefined type id(s) {unknown[:10]}" if unknown else ""))
    notes.extend(table.problems)
    del cand, types, fmt_at, fmt_pos, fmt_kept

    # the records to decode (all of them, or those of the types asked for and the metadata),
    # grouped by definition: a stable radix sort of small integers keeps file order
    ndefs = len(table.defs)

    def skeleton(name: str) -> bool:  # read for its times only
        return times_only and wanted is not None and name not in wanted \
            and name not in _META_NAMES
    # (one more entry: the candidates that are not records)
    timed = np.array([d.time_field is not None for d in table.defs] + [False])
    decode = np.array([wanted is None or times_only or d.name in wanted
                       or d.name in _META_NAMES for d in table.defs] + [False])
    idx_dt = framing.pos.dtype
    sel: np.ndarray | None = None  # indices of the decoded records (None: all candidates)
    defid = framing.defid
    where = framing.pos  # the decoded records' offsets
    if not decode[:ndefs].all():
        sel = select(decode, framing.defid, idx_dt)
        defid = lookup(framing.defid, sel)
        where = lookup(framing.pos, sel)
    members = group(defid, ndefs + 1, idx_dt)
    members.pop(ndefs, None)  # the candidates that are not records
    del defid
    windowed = start is not None or stop is not None
    # per definition: indices into the decoded records (``sel``), their offsets and times
    groups: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray | None]] = {}
    first: dict[int, int] = {}  # each definition's first record (orders the messages)
    for i, k in members.items():
        d = table.defs[i]
        first[i] = int(k[0])
        pos = lookup(where, k)
        t = gather_times(a, d, pos) if windowed and d.name not in _META_NAMES else None
        if t is not None:  # timed records outside the window are not decoded
            keep = window_mask(t, start, stop)
            assert keep is not None
            k, pos, t = k[keep], pos[keep], t[keep]
        groups[i] = (k, pos, t)
    del members
    release_pages(a, 0, n)
    # records without a time field hold the time of the latest timed record before them
    untimed = [i for i in groups if not timed[i]]
    src: tuple[np.ndarray, np.ndarray] = (np.zeros(0, idx_dt), np.zeros(0))
    if untimed:
        k = sorted_concat([groups[i][0] for i in untimed])
        held, src = _held_times(a, framing, table, timed, k if sel is None else sel[k])
        for i in untimed:
            k_i, pos_i, _ = groups[i]
            groups[i] = (k_i, pos_i, held[np.searchsorted(k, k_i)])
    # the times of the decoded records and of those whose time they hold, in file order,
    # for the backwards-steps check
    timeline = np.full(where.size, np.nan)
    inserts: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    if sel is None:
        timeline[src[0]] = src[1]
    elif src[0].size:  # sources that are not decoded themselves go in between
        at = np.searchsorted(sel, src[0])
        there = at < sel.size
        there[there] = sel[at[there]] == src[0][there]
        timeline[at[there]] = src[1][there]
        inserts = (at[~there], src[1][~there], framing.pos[src[0][~there]])
    by_name: dict[str, list[int]] = {}
    for i in sorted(groups, key=lambda i: first[i]):
        by_name.setdefault(table.defs[i].name, []).append(i)
    only_format = not set(by_name) - _FORMAT_ONLY
    if only_format and sel is not None:  # and the types not decoded?
        present = np.bincount(framing.defid, minlength=ndefs + 1)[:ndefs] > 0
        only_format = not {d.name for d, p in zip(table.defs, present, strict=True) if p} \
            - _FORMAT_ONLY
    del framing, sel, src

    columns: dict[str, dict[str, np.ndarray]] = {}
    time_s: dict[str, np.ndarray] = {}
    meta_columns: dict[str, dict[str, np.ndarray]] = {}
    meta_times: dict[str, np.ndarray] = {}
    defs_by_name: dict[str, Definition] = {}
    all_parts = {}
    for name, ids in by_name.items():
        parts = [(table.defs[i], *groups.pop(i)) for i in ids]
        parts, dropped = bounded_layouts(parts)
        if dropped[0]:
            notes.append(f"{name}: {dropped[0]} record(s) under {dropped[1]} other layout(s) "
                         "not decoded (the type is redefined with ever new columns)")
        defs_by_name[name] = parts[-1][0]
        all_parts[name] = parts
    # messages of one layout: decoded a stretch of the file at a time (each file page is
    # mapped into the process once, then handed back); the others one by one
    single = {name: parts[0] for name, parts in all_parts.items() if len(parts) == 1}
    # times only: the time field, and every column that may tell instances apart (by name,
    # or a one-byte integer: what the log declares an instance, unit "#", always is)
    only = {name: {c for c, (_, ch, _, _) in column_layout(d).items()
                   if c in INSTANCE_COLUMNS or ch in "BbM"
                   or (d.time_field is not None and c == d.time_field[0])}
            for name, (d, *_) in single.items() if skeleton(name)}
    jobs: list[tuple[Definition, np.ndarray, dict[str, np.ndarray]]] = []
    prefilled: dict[str, tuple[dict[str, np.ndarray], Callable[[], np.ndarray]]] = {}
    for name, parts in all_parts.items():
        if name in single:
            d, _, pos, t = single[name]
            keep_cols = only.get(name)
            cols = alloc_columns(pos.size, {c: (dt, shape)
                                            for c, (_, _, dt, shape) in column_layout(d).items()
                                             if keep_cols is None or c in keep_cols})
            jobs.append((d, pos, cols))
            prefilled[name] = (cols, functools.partial(times_of, d, cols) if t is None
                              else functools.partial(np.asarray, t))
        elif (plan := plan_message(a, parts)) is not None:
            jobs.extend(plan[1])
            prefilled[name] = (plan[0], plan[2])
    gather_by_block(a, jobs)
    del jobs
    for name, parts in all_parts.items():
        if name in prefilled:
            cols, finish = prefilled.pop(name)
            t = finish()
        else:
            cols, t = decode_message(a, parts)
        keys = parts[0][1] if len(parts) == 1 else sorted_concat([p[1] for p in parts])
        timeline[keys.astype(np.intp)] = t
        del parts, keys
        if name in _META_NAMES:
            meta_columns[name], meta_times[name] = cols, t
        if wanted is None or times_only or name in wanted:
            keep = window_mask(t, start, stop)
            if keep is not None and not keep.all():
                cols, t = {k: v[keep] for k, v in cols.items()}, t[keep]
            columns[name], time_s[name] = cols, t
    if inserts is not None:
        timeline = np.insert(timeline, inserts[0], inserts[1])
        where = np.insert(where, inserts[0], inserts[2])
    steps = backwards_steps(timeline, where)
    del timeline, where
    if steps:
        shown = ", ".join(f"byte {w} ({t0:.3f} s -> {t1:.3f} s)" for w, t0, t1 in steps[:5])
        notes.append(f"time goes backwards {len(steps)} time(s) (reboot or concatenated logs): "
                     f"{shown}")

    if only_format:
        notes.append("log holds only format definitions, no data records")
    source = SourceInfo(path, "dataflash", n, skipped_bytes=skipped, notes=tuple(notes))
    if notes:
        warnings.warn(f"{path}: " + "; ".join(notes), DataQualityWarning, stacklevel=3)
    declared = {name: tuple(c for c, _ in defs_by_name[name].fields)
                for name in columns if skeleton(name)}
    return assemble(source, columns, time_s, defs_by_name,
                    None if times_only else wanted, meta_columns, meta_times,
                    declared=declared, autopilot=autopilot_of(table.defs))


def _held_times(
    a: np.ndarray,
    framing: Framing,
    table: Definitions,
    timed: np.ndarray,
    rows: np.ndarray,
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """Times of the records ``rows`` (ascending; of definitions without a time field): that
    of the nearest earlier record that has one, read from the file (NaN before the first);
    and those source records with their times."""
    # the source is nearly always a few records back: look there first
    src = np.full(rows.size, -1, framing.pos.dtype)
    todo = np.arange(rows.size)
    for back in range(1, NEAR + 1):
        if not todo.size:
            break
        before = rows[todo] - back
        todo = todo[before >= 0]  # none before: no source
        before = before[before >= 0]
        hit = lookup(timed, framing.defid[before])
        src[todo[hit]] = before[hit]
        todo = todo[~hit]
    if todo.size:  # the rest (e.g. the FMT records heading a log): a search back in bulk
        is_timed = lookup(timed, framing.defid[: int(rows[todo[-1]]) + 1])
        prev = np.where(is_timed, np.arange(is_timed.size, dtype=framing.pos.dtype), -1)
        del is_timed
        np.maximum.accumulate(prev, out=prev)
        src[todo] = prev[rows[todo]]
        del prev
    out = np.full(rows.size, np.nan)
    has = src >= 0
    need, _, inverse = unique(src[has])
    t = np.empty(need.size)
    # one gather per place and kind of time field (not per definition: a log may hold
    # thousands of definitions)
    ids, _, id_of = unique(framing.defid[need])
    slots: dict[tuple[int, str, float], int] = {}
    slot_of = np.array([slots.setdefault(time_slot(table.defs[i]), len(slots))
                       for i in ids.tolist()], np.int64)[id_of]
    order = np.argsort(slot_of, kind="stable")
    bounds = np.searchsorted(slot_of[order], np.arange(len(slots) + 1))
    for (ofs, dtype, scale), j in slots.items():
        k = order[bounds[j] : bounds[j + 1]]
        t[k] = records_at(a, np.dtype(dtype), framing.pos[need[k]] + 3 + ofs) * scale
    out[has] = t[inverse]
    return out, (need, t)
