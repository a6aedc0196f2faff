"""DataFlash decoding: records of one definition copied out of the file into columns.

Each type's records are copied out of the file through an overlapping view in cache-sized
slices (one fancy-indexing call per slice; a few narrow columns of wide records, field by
field) and every field is written straight into its preallocated column (a message's columns
are carved out of one allocation, :func:`alloc_columns`), a 64 MB block of the file at a time
for every message (:func:`gather_by_block`). A message defined with several layouts gets the
union of their columns (:func:`plan_message`, :func:`decode_message`).

Values are those pymavlink presents: format characters ``c C e E`` are divided by 100 and ``L``
by 1e7 (as pymavlink does it: ``value / (1 / multiplier)``), ``a`` is an ``int16[32]`` row,
``n N Z`` are ``str`` (UTF-8, else Latin-1, cut at the first NUL; ``FILE.Data`` stays raw
``bytes``), ``g`` is a half float (given as float32), ``M`` the raw mode number.

Examples
--------
>>> from mavsid.readers.dataflash_formats import Definition
>>> from mavsid.readers.dataflash_spec import build_record
>>> d = Definition(0x81, "TST", 3 + 8 + 2, "Qc", ("TimeUS", "Val"))
>>> a = np.frombuffer(build_record(0x81, "Qc", 1_500_000, -1234), np.uint8)
>>> cols, t = decode_message(a, [(d, np.array([0]), np.array([0]), None)])
>>> cols["Val"].tolist(), t.tolist()
([-12.34], [1.5])
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from mavsid.readers import dataflash_spec as dfspec
from mavsid.readers.arrays import unique
from mavsid.readers.dataflash_formats import Definition, column_layout, decode_text, time_slot
from mavsid.readers.dataflash_scan import RELEASE_MIN, field_view, records_at, release_pages

__all__ = [
    "Plan",
    "alloc_columns",
    "bounded_layouts",
    "decode_message",
    "gather_by_block",
    "gather_times",
    "plan_message",
    "times_of",
]


# stored as presented: decoding is a plain copy (or a widening cast)
_PLAIN = frozenset(c for c, spec in dfspec.FORMAT_CHARS.items()
                   if spec.kind in ("int", "array") or c in "fd")


_GATHER_BYTES = 1 << 18  # record bytes copied per slice when decoding one type


_SPAN_BYTES = 1 << 24  # file bytes one gather slice may span


def _strings(raw: np.ndarray) -> np.ndarray:
    """``S`` array -> object array of ``str`` (each distinct value decoded once)."""
    if raw.size == 0:
        return np.zeros(raw.shape, dtype=object)
    uniq, _, inverse = unique(raw.reshape(-1))
    table = np.empty(len(uniq), dtype=object)
    table[:] = [decode_text(b) for b in uniq.tolist()]
    return table[inverse.reshape(raw.shape)]


def _column_into(raw: np.ndarray, ch: str, message: str, out: np.ndarray) -> None:
    """Write one field of a structured gather into ``out``, as pymavlink presents it."""
    spec = dfspec.FORMAT_CHARS[ch]
    if spec.kind == "str":
        if message == "FILE" and ch == "Z":
            rows = np.ascontiguousarray(raw).view(np.uint8).reshape(raw.shape[0], -1)
            out[:] = [r.tobytes() for r in rows]
        else:
            out[...] = _strings(raw)
    elif spec.multiplier is not None:
        divisor = 1 / spec.multiplier  # pymavlink divides by this for accuracy
        if out.dtype == np.float64:
            np.true_divide(raw, divisor, out=out, dtype=np.float64)
        else:
            out[...] = np.true_divide(raw, divisor, dtype=np.float64)
    elif ch == "g" and out.dtype != np.float32:
        out[...] = raw.astype(np.float32)
    else:
        out[...] = raw


_BLOCK_BYTES = 1 << 26  # file bytes decoded (for every message) before their pages go back


def gather_by_block(
    a: np.ndarray, jobs: Sequence[tuple[Definition, np.ndarray, dict[str, np.ndarray]]],
) -> None:
    """:func:`_gather_into` for several jobs (definition, ascending record offsets, the
    columns to fill), a block of the file at a time for all of them, each block's pages
    released once it is done (so the file is mapped into the process about once, a block
    at a time, instead of once per message type)."""
    done = [0] * len(jobs)
    for lo in range(0, a.size, _BLOCK_BYTES):
        for j, (d, pos, out) in enumerate(jobs):
            k = done[j]
            stop = int(np.searchsorted(pos, lo + _BLOCK_BYTES))
            if stop > k:
                _gather_into(a, d, pos[k:stop], {c: v[k:stop] for c, v in out.items()},
                             release=False, quiet=False)
                done[j] = stop
        release_pages(a, lo, lo + _BLOCK_BYTES)
    for d, _, out in jobs:  # once per column, not per slice
        layout = column_layout(d)
        for c, v in out.items():
            if v.dtype.kind == "f" and layout[c][1] in _PLAIN:
                _quiet_nans(v)


def _gather_into(
    a: np.ndarray, d: Definition, pos: np.ndarray, out: dict[str, np.ndarray] | None = None,
    release: bool = True, quiet: bool = True,
) -> dict[str, np.ndarray]:
    """Decode the records of definition ``d`` at offsets ``pos`` into ``out`` (arrays of
    ``pos.size`` rows, allocated when not given).

    Records are copied out of the file in slices that fit a CPU cache, then each field
    is written straight into its column. With ``release``, the file's pages are handed back
    as the records are passed (see :func:`release_pages`); without ``quiet``, float columns
    copied as stored may keep signalling NaNs (the caller quiets them,
    :func:`_quiet_nans`).
    """
    layout = column_layout(d)
    if out is None:
        out = alloc_columns(pos.size, {c: (dt, shape) for c, (_, _, dt, shape) in layout.items()})
    # (payload field, format character or None when a plain copy does, column)
    fields = [(f, None if ch in _PLAIN and col.dtype != object else ch, col)
              for c, (f, ch, _, _) in layout.items() if (col := out.get(c)) is not None]
    step = max(1, _GATHER_BYTES // max(d.payload_dtype.itemsize, 1))
    # a few narrow fields of a wide record (times only): each gathered on its own from
    # the file, not the whole records
    pdt = d.payload_dtype
    spans: Mapping[str, tuple[np.dtype, int]] = pdt.fields or {}  # type: ignore[assignment]
    direct = _DIRECT * sum(int(spans[f][0].itemsize) for f, _, _ in fields) <= pdt.itemsize
    done = 0  # file bytes before this are not needed again for this definition
    k = 0
    while k < pos.size:
        # a slice of records that fits a cache and spans a bounded stretch of the file
        # (each record touched maps file pages into the process until released)
        stop = min(k + step, int(np.searchsorted(pos, pos[k] + _SPAN_BYTES)))
        stop = max(stop, k + 1)
        recs: Mapping[str, np.ndarray] | np.ndarray
        if direct:
            at = pos[k:stop].astype(np.intp)
            at += 3
            recs = {f: field_view(a, pdt, f)[at] for f, _, _ in fields}
        else:
            recs = records_at(a, pdt, pos[k:stop] + 3)
        for f, ch, col in fields:
            if ch is None:
                col[k:stop] = recs[f]
                if quiet and col.dtype.kind == "f":
                    _quiet_nans(col[k:stop])
            else:
                _column_into(recs[f], ch, d.name, col[k:stop])
        k = stop
        if release and k < pos.size and int(pos[k]) - done >= RELEASE_MIN:
            release_pages(a, done, int(pos[k]))
            done = int(pos[k])
    if release:
        release_pages(a, done, a.size)
    return out


_DIRECT = 4  # fields gathered one by one when they hold at most 1/4 of a record's bytes


def _quiet_nans(v: np.ndarray) -> None:
    """Replace signalling NaNs (a damaged float's bit pattern) by quiet NaN in place, as
    Python's ``struct`` does: numpy would warn ("invalid value") on every later cast.

    Examples
    --------
    >>> v = np.frombuffer(b"\\x01\\x00\\x80\\x7f", "<f4").copy()  # a signalling NaN
    >>> _quiet_nans(v); bool(v.view("<u4")[0] == np.float32("nan").view("<u4"))
    True
    """
    if v.size == 0:
        return
    with np.errstate(invalid="ignore"):
        if not np.isnan(np.max(v)):  # no NaN at all (the maximum keeps any): no mask
            return
        bad = v != v
    v[bad] = np.nan


def gather_times(a: np.ndarray, d: Definition, pos: np.ndarray) -> np.ndarray | None:
    """Boot time (s) of the records of ``d`` at ``pos``, or None when ``d`` has none."""
    if d.time_field is None:
        return None
    ofs, dtype, scale = time_slot(d)
    return records_at(a, np.dtype(dtype), pos + 3 + ofs).astype(np.float64) * scale


_MAX_UNION = 4  # a message's merged table may hold this many times its records' own cells


def bounded_layouts(
    parts: list[tuple[Definition, np.ndarray, np.ndarray, np.ndarray | None]],
) -> tuple[list[tuple[Definition, np.ndarray, np.ndarray, np.ndarray | None]], tuple[int, int]]:
    """The parts of one message worth merging, and (records, layouts) left out.

    Merging layouts gives the union of their columns; when a type is redefined with new
    columns again and again (damage or a hostile file), that union grows with the number
    of definitions and the table with its square. Then only the layout (set of columns)
    holding the most records is kept (the latest among equals).
    """
    if len(parts) <= 2:
        return parts, (0, 0)
    union: set[str] = set()
    cells = 0
    for d, k, _, _ in parts:
        cols = [c for c, _ in d.fields]
        union.update(cols)
        cells += k.size * max(len(cols), 1)
    rows = sum(k.size for _, k, _, _ in parts)
    if rows * len(union) <= _MAX_UNION * cells + (1 << 16):
        return parts, (0, 0)
    count: dict[tuple[str, ...], int] = {}
    latest: dict[tuple[str, ...], int] = {}
    for j, (d, k, _, _) in enumerate(parts):
        key = tuple(sorted(c for c, _ in d.fields))
        count[key] = count.get(key, 0) + k.size
        latest[key] = j
    best = max(count, key=lambda key: (count[key], latest[key]))
    kept = [p for p in parts if tuple(sorted(c for c, _ in p[0].fields)) == best]
    return kept, (rows - count[best], len(count) - 1)


def decode_message(
    a: np.ndarray, parts: list[tuple[Definition, np.ndarray, np.ndarray, np.ndarray | None]]
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """One message's columns and times from its parts ``(definition, file-order keys, record
    offsets, times)``.

    A message name defined more than once with different layouts (concatenated logs of
    different firmware) gets the union of the columns, in file order; a part lacking a
    column contributes NaN (numbers, arrays) or empty strings. Each part is decoded straight
    into its slice of the result when the parts follow one another in the file.
    """
    if len(parts) == 1:
        d, _, pos, t = parts[0]
        cols = _gather_into(a, d, pos)
        return cols, times_of(d, cols) if t is None else t
    plan = plan_message(a, parts)
    if plan is None:
        parts = sorted(parts, key=lambda part: int(part[1][0]) if part[1].size else -1)
        decoded = [(d, k, _gather_into(a, d, p)) for d, k, p, _ in parts]
        return _merge([(d, k, cols, times_of(d, cols) if t is None else t)
                      for (d, k, cols), (_, _, _, t) in zip(decoded, parts, strict=True)])
    out, jobs, finish = plan
    for d, pos, own in jobs:
        _gather_into(a, d, pos, own)
    return out, finish()


Plan = tuple[dict[str, np.ndarray], list[tuple[Definition, np.ndarray, dict[str, np.ndarray]]],
             Callable[[], np.ndarray]]


def plan_message(
    a: np.ndarray, parts: list[tuple[Definition, np.ndarray, np.ndarray, np.ndarray | None]]
) -> Plan | None:
    """The columns of a message defined with several layouts whose parts follow one another
    in the file (None when they interleave): the union of the columns, allocated, the
    columns a layout lacks filled; the gather jobs ``(definition, offsets, its slice of the
    columns)`` that fill the rest; and the function that gives the times once they ran."""
    parts = sorted(parts, key=lambda part: int(part[1][0]) if part[1].size else -1)
    keys = [k for _, k, _, _ in parts]
    ends = [(int(k[0]), int(k[-1])) for k in keys if k.size]
    if any(x[1] > y[0] for x, y in itertools.pairwise(ends)):
        return None
    names: list[str] = []
    for d, _, _, _ in parts:
        names.extend(c for c, _ in d.fields if c not in names)
    sizes = [k.size for k in keys]
    total = sum(sizes)
    specs: dict[str, tuple[np.dtype, tuple[int, ...]]] = {}
    fill: dict[str, object] = {}
    for c in names:
        kinds = [column_layout(d).get(c) for d, _, _, _ in parts]
        like = next(k[2:] for k in kinds if k is not None)
        dtypes = [k[2] if k is not None and k[3] == like[1] else _filler(like)[0]
                  for k in kinds]
        obj = any(k is not None and k[2].kind == "O" for k in kinds)
        specs[c] = (np.dtype(object) if obj else np.result_type(*dtypes), like[1])
        fill[c] = _filler(like)[1]
    out = alloc_columns(total, specs)
    jobs = []
    at = 0
    for (d, _, pos, _), size in zip(parts, sizes, strict=True):
        layout = column_layout(d)
        region = {c: v[at : at + size] for c, v in out.items()}
        own = {c: v for c, v in region.items() if c in layout and layout[c][3] == v.shape[1:]}
        jobs.append((d, pos, own))
        for c, v in region.items():
            if c not in own:  # a column this layout lacks (or has in another shape)
                v[...] = fill[c]
        at += size

    def finish() -> np.ndarray:
        t_out = np.empty(total)
        at = 0
        for (d, _, pos, t), (_, _, own) in zip(parts, jobs, strict=True):
            into = t_out[at : at + pos.size]
            tf = d.time_field
            if t is None and tf is not None and tf[0] in own:
                times_of(d, own, out=into)
            else:
                t = gather_times(a, d, pos) if t is None else t
                assert t is not None
                into[...] = t
            at += pos.size
        return t_out

    return out, jobs, finish


def times_of(
    d: Definition, cols: Mapping[str, np.ndarray], out: np.ndarray | None = None
) -> np.ndarray:
    """Boot time (s) of decoded records of a definition that has a time field (written
    into ``out`` when given)."""
    tf = d.time_field
    assert tf is not None
    name, _, scale = tf
    return np.multiply(cols[name], scale, out=out, dtype=np.float64)


def alloc_columns(
    rows: int, specs: Mapping[str, tuple[np.dtype, tuple[int, ...]]]
) -> dict[str, np.ndarray]:
    """Uninitialised columns of ``rows`` rows (name -> dtype and per-row shape), the numeric
    ones carved out of one allocation.

    A fresh array costs a page fault per 4 KiB page on first write, unless the kernel backs
    it with huge pages, which it does only for the 2 MiB-aligned stretches of a large
    allocation: one block per message instead of one array per column (most of them a few
    MB) makes a cold read fault its output in far fewer steps. The block is freed when
    every column is.

    Examples
    --------
    >>> cols = alloc_columns(3, {"a": (np.dtype("<u8"), ()), "b": (np.dtype("<i2"), (2,))})
    >>> cols["a"].shape, cols["b"].shape, cols["b"].dtype.str
    ((3,), (3, 2), '<i2')
    """
    sizes = {c: rows * dt.itemsize * int(np.prod(shape)) for c, (dt, shape) in specs.items()
             if dt.kind != "O"}
    offsets, total = {}, 0
    for c, size in sizes.items():
        offsets[c] = total
        total += -(-size // 64) * 64  # every column 64-byte aligned
    block = np.empty(total, np.uint8)
    out = {}
    for c, (dt, shape) in specs.items():
        if c in sizes:
            out[c] = block[offsets[c] : offsets[c] + sizes[c]].view(dt).reshape(rows, *shape)
        else:
            out[c] = np.empty((rows, *shape), dt)
    return out


def _filler(kind: tuple[np.dtype, tuple[int, ...]]) -> tuple[np.dtype, object]:
    """dtype and value that stand for a column a layout lacks: NaN, or an empty string."""
    return (np.dtype(object), "") if kind[0].kind == "O" else (np.dtype(np.float64), np.nan)


def _merge(
    parts: list[tuple[Definition, np.ndarray, dict[str, np.ndarray], np.ndarray]],
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """:func:`decode_message` for parts whose records interleave: decoded ``(definition,
    file-order keys, columns, times)`` concatenated, then put in file order."""
    rows = np.concatenate([r for _, r, _, _ in parts])
    times = np.concatenate([t for _, _, _, t in parts])
    order: np.ndarray | slice = slice(None)
    if np.any(rows[1:] < rows[:-1]):
        order = np.argsort(rows, kind="stable")
    names: list[str] = []
    for _, _, cols, _ in parts:
        names.extend(c for c in cols if c not in names)
    merged: dict[str, np.ndarray] = {}
    for c in names:
        like = next(cols[c] for _, _, cols, _ in parts if c in cols)
        pieces = [cols[c] if c in cols else _missing(like, r.size) for _, r, cols, _ in parts]
        if any(p.dtype.kind == "O" for p in pieces):
            pieces = [p.astype(object) for p in pieces]
        pieces = [p if p.shape[1:] == like.shape[1:] else _missing(like, p.shape[0])
                  for p in pieces]
        merged[c] = np.concatenate(pieces)[order]
    return merged, times[order]


def _missing(like: np.ndarray, n: int) -> np.ndarray:
    """Filler for a column one layout lacks: NaN (float) or empty string."""
    if like.dtype.kind == "O":
        out = np.empty((n, *like.shape[1:]), dtype=object)
        out[...] = ""
        return out
    return np.full((n, *like.shape[1:]), np.nan)
