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

import array
import functools
import itertools
import mmap
import os
import re
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property, lru_cache
from types import ModuleType

import numpy as np

from mavsid.autopilot.modes import ardupilot_modes
from mavsid.data import MessageTable, ModeChange, RawLog, SourceInfo, TextMessage
from mavsid.errors import ConfigError, DataQualityWarning, LogFormatError
from mavsid.readers import dataflash_spec as dfspec

_scan: ModuleType | None
try:  # the header scan compiled (setup.py); absent where the package was built without a C
    from mavsid.readers import _scan  # compiler: then the numpy scan, same results
except ImportError:  # pragma: no cover - depends on the build
    _scan = None

__all__ = [
    "Definition",
    "assemble",
    "backwards_steps",
    "hold_forward",
    "read",
    "vehicle_and_firmware",
    "window_mask",
]

_CHUNK = 1 << 20  # bytes scanned per step when looking for headers
# chunks scanned between releases of their file pages (8 MB: measured ~10 ms faster over
# 200 MB than 4, 16 or 32 MB)
_SCAN_RELEASE = 8
_NEAR = 16  # candidates looked at around a record when checking overlaps
_GATHER_BYTES = 1 << 18  # record bytes copied per slice when decoding one type
_BACKWARDS_S = 0.5  # a time step back larger than this is a discontinuity


# stored as presented: decoding is a plain copy (or a widening cast)
_PLAIN = frozenset(c for c, spec in dfspec.FORMAT_CHARS.items()
                   if spec.kind in ("int", "array") or c in "fd")

# always decoded: parameters, texts, modes, units, firmware
_META_NAMES = frozenset({"FMTU", "UNIT", "MULT", "PARM", "MSG", "MODE", "VER"})
#: columns that tell a message's instances apart, by name (decoded with the times by
#: ``times_only``, as are all one-byte integer columns; ``mavsid info`` groups rates by them)
INSTANCE_COLUMNS = ("I", "Instance", "C", "Id")
_FORMAT_ONLY = frozenset({"FMT", "FMTU", "UNIT", "MULT"})


@dataclass(frozen=True)
class Definition:
    """One message type as an FMT record defines it.

    Examples
    --------
    >>> d = Definition(0x81, "ATT", 3 + 8 + 4, "Qf", ("TimeUS", "Roll"))
    >>> d.payload_dtype.itemsize, d.fields
    (12, (('TimeUS', 0), ('Roll', 1)))
    """

    type: int
    name: str
    length: int  # bytes, header included
    format: str
    columns: tuple[str, ...]

    @cached_property
    def fields(self) -> tuple[tuple[str, int], ...]:
        """``(column name, index into format)`` in log order; a repeated name keeps its last
        position (as pymavlink does); columns beyond the format are ignored."""
        return _fields(self.columns, len(self.format))

    @property
    def payload_dtype(self) -> np.dtype:
        """Packed structured dtype of the payload, fields named ``f0, f1, ...``."""
        return dfspec.payload_dtype(self.format)

    def problem(self) -> str | None:
        """Why this definition cannot be used, or None."""
        bad = sorted({c for c in self.format if c not in dfspec.FORMAT_CHARS})
        if bad:
            return f"unknown format character(s) {''.join(bad)!r}"
        size = 3 + dfspec.payload_size(self.format)  # (no dtype built: a log defines hundreds)
        if size != self.length:
            return f"declared length {self.length} but format {self.format!r} needs {size}"
        return None

    @cached_property
    def time_field(self) -> tuple[str, int, float] | None:
        """``(column, format index, seconds per count)`` of the boot-time field, if any."""
        return _time_field(self.name, self.format, self.fields)


@lru_cache(maxsize=4096)
def _time_field(
    name: str, fmt: str, fields: tuple[tuple[str, int], ...]
) -> tuple[str, int, float] | None:
    index = dict(fields)
    if "TimeUS" in index and fmt[index["TimeUS"]] in "QqIi":
        return "TimeUS", index["TimeUS"], 1e-6
    if "TimeMS" in index and not name.startswith("GPS") and fmt[index["TimeMS"]] in "QqIi":
        return "TimeMS", index["TimeMS"], 1e-3
    if name == "TIME" and "StartTime" in index and fmt[index["StartTime"]] in "Qq":
        return "StartTime", index["StartTime"], 1e-6  # (PX4 sdlog2: each cycle's records follow it)
    return None


@lru_cache(maxsize=4096)
def _fields(columns: tuple[str, ...], n: int) -> tuple[tuple[str, int], ...]:
    last: dict[str, int] = {}
    for i, name in enumerate(columns[:n]):
        if name:
            last[name] = i
    seen: set[str] = set()
    out = []
    for name in columns[:n]:
        if name and name not in seen:
            seen.add(name)
            out.append((name, last[name]))
    return tuple(out)


_FMT_DEF = Definition(dfspec.FMT_TYPE, "FMT", dfspec.FMT_LENGTH, dfspec.FMT_FORMAT,
                      dfspec.FMT_COLUMNS)


# --------------------------------------------------------------------------- framing
def _index_dtype(n: int) -> type[np.signedinteger]:
    """Smallest integer type for byte offsets and record indices of an ``n``-byte file."""
    return np.int32 if n < 2**31 - 1024 else np.int64


_RELEASE_MIN = 1 << 22  # bytes of file pages worth a madvise call
_SPAN_BYTES = 1 << 24  # file bytes one gather slice may span


def _release(a: np.ndarray, lo: int, hi: int) -> None:
    """Tell the kernel that bytes ``lo..hi`` of the memory-mapped file ``a`` are not needed
    for now: their pages leave the process's resident set (they stay in the page cache and
    come back on the next touch, a minor fault). Without it, reading every record maps the
    whole file into the process, on top of the arrays decoded from it."""
    base = a.base.obj if isinstance(a.base, memoryview) else a.base
    if not isinstance(base, mmap.mmap) or not hasattr(mmap, "MADV_DONTNEED"):
        return
    lo = max(lo, 0) // mmap.PAGESIZE * mmap.PAGESIZE
    hi = min(hi, len(base))
    if hi - lo < _RELEASE_MIN:
        return
    try:
        base.madvise(mmap.MADV_DONTNEED, lo, hi - lo)
    except (OSError, ValueError):  # not supported here: only memory use differs
        pass


def _find_headers(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Offsets of every ``0xA3 0x95`` byte pair followed by a type byte, ascending, and
    those type bytes.

    Compiled (``mavsid/readers/_scan.c``: 16 bytes a step with SSE2, one pass over the file
    instead of the numpy scan's passes over its masks; a selective read ~1.2x faster) where
    the package was built with a C compiler for a machine with SSE2, else
    :func:`_find_headers_numpy`: the same offsets and types either way (tests). The file
    is scanned 8 MB at a time, each window's pages handed back once scanned; the result
    starts at a size for a record per ~40 bytes and grows when a file holds more.

    Examples
    --------
    >>> data = np.frombuffer(bytes([0xA3, 0x95, 7, 0xA3, 0x95, 0xA3, 0x95, 9, 0xA3]), np.uint8)
    >>> [v.tolist() for v in _find_headers(data)]
    [[0, 3, 5], [7, 163, 9]]
    """
    if _scan is None or not _scan.vectorised:  # (a byte loop is slower than numpy's)
        return _find_headers_numpy(a)
    n = a.size
    dt = _index_dtype(n)
    size = max(n // 40, 1024)
    found, types = np.empty(size, dt), np.empty(size, np.uint8)
    count, window, last = 0, _CHUNK * _SCAN_RELEASE, max(n - 2, 0)
    for start in range(0, last, window):
        pos, stop = start, min(start + window, last)
        while True:
            k, pos = _scan.pairs(a, pos, stop, found[count:], types[count:])
            count += k
            if pos == stop:
                break
            found = np.concatenate([found[:count], np.empty(found.size, dt)])
            types = np.concatenate([types[:count], np.empty(types.size, np.uint8)])
        _release(a, start, stop)
    return found[:count], types[:count]


def _find_headers_numpy(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_find_headers` without the compiled scan (a package built without a C
    compiler): numpy over the bytes.

    One pass over the file in cache-sized chunks. The pair is looked for as one 16-bit word,
    at even and at odd offsets (two compares, each over half as many items as a byte-wise
    compare); a pair cannot start at both offsets of one word (its second byte would be
    both ``0x95`` and ``0xA3``), so the two hit masks are OR-ed and scanned once, half the
    length of a per-byte mask, and the parity read back from the odd one. The masks are
    reused and the hits written straight into the result (grown by doubling when a file
    holds more headers than a log usually does), so that a cold read touches little fresh
    memory beyond the result itself.

    Examples
    --------
    >>> data = np.frombuffer(bytes([0xA3, 0x95, 7, 0xA3, 0x95, 0xA3, 0x95, 9, 0xA3]), np.uint8)
    >>> [v.tolist() for v in _find_headers_numpy(data)]
    [[0, 3, 5], [7, 163, 9]]
    """
    n = a.size
    dt = _index_dtype(n)
    half = _CHUNK // 2
    even, odd = np.empty(half, bool), np.empty(half, bool)
    size = max(n // 40, 1024)  # a log has a record per ~50 bytes
    found, types = np.empty(size, dt), np.empty(size, np.uint8)
    word = np.uint16(dfspec.HEAD[0] | dfspec.HEAD[1] << 8)  # the pair, read as a little-endian word
    count = 0
    for start in range(0, max(n - 2, 0), _CHUNK):
        limit = min(_CHUNK, n - 2 - start)  # pairs starting here; a header needs its type
        h = (limit + 1) // 2  # words at even offsets; bytes up to start + 2h <= n - 1
        hit = np.equal(a[start : start + 2 * h].view("<u2"), word, out=even[:h])
        at_odd = np.equal(a[start + 1 : start + 1 + 2 * h].view("<u2"), word, out=odd[:h])
        if limit % 2:  # the last odd offset is past this chunk's pairs
            at_odd[h - 1] = False
        hit |= at_odd
        at = np.flatnonzero(hit)
        k = at.size
        if count + k > found.size:
            grow = max(found.size, k)
            found = np.concatenate([found[:count], np.empty(grow, dt)])
            types = np.concatenate([types[:count], np.empty(grow, np.uint8)])
        parity = at_odd[at]
        at *= 2
        at += parity  # offsets in this chunk
        np.add(at, start, out=found[count : count + k], casting="unsafe")
        at += start + 2
        np.take(a, at, out=types[count : count + k])
        count += k
        if (start // _CHUNK) % _SCAN_RELEASE == _SCAN_RELEASE - 1:
            _release(a, start - (_SCAN_RELEASE - 1) * _CHUNK, start)
    return found[:count], types[:count]


def _decode_text(raw: bytes) -> str:
    """Bytes as pymavlink presents them: UTF-8, else Latin-1, cut at the first NUL."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("iso-8859-1")
    cut = text.find("\0")
    return text if cut < 0 else text[:cut]


def _strings(raw: np.ndarray) -> np.ndarray:
    """``S`` array -> object array of ``str`` (each distinct value decoded once)."""
    if raw.size == 0:
        return np.zeros(raw.shape, dtype=object)
    uniq, _, inverse = _unique(raw.reshape(-1))
    table = np.empty(len(uniq), dtype=object)
    table[:] = [_decode_text(b) for b in uniq.tolist()]
    return table[inverse.reshape(raw.shape)]


def _unique(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sorted distinct values of a 1-d ``x``, the index of each one's first occurrence and
    the index of each element's value: ``np.unique(x, return_index=True,
    return_inverse=True)`` without its import of ``numpy.ma`` (~7 ms of a cold read).

    Examples
    --------
    >>> [v.tolist() for v in _unique(np.array([3, 1, 3, 2]))]
    [[1, 2, 3], [1, 3, 0], [2, 0, 2, 1]]
    """
    order = np.argsort(x, kind="stable")
    s = x[order]
    new = np.ones(s.size, bool)
    if s.size > 1:
        new[1:] = s[1:] != s[:-1]
    inverse = np.empty(s.size, np.intp)
    inverse[order] = np.cumsum(new) - 1
    return s[new], order[new], inverse


@dataclass
class _Definitions:
    """Every usable definition and, per type, where each takes effect."""

    defs: list[Definition] = field(default_factory=list)
    # type -> [(file offset of the FMT record, index into defs)], by offset
    by_type: dict[int, list[tuple[int, int]]] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)
    # offsets of FMT records whose text fields are plausible (evidence of a record there)
    plausible: list[int] = field(default_factory=list)


def _read_definitions(a: np.ndarray, fmt_pos: np.ndarray) -> _Definitions:
    """Parse the FMT records at ``fmt_pos`` (already known to be complete).

    Candidates whose name or format cannot be text are dropped with numpy first, and each
    distinct FMT payload is parsed once: a flood of header patterns or of one repeated
    definition costs no Python work per record.
    """
    out = _Definitions()
    out.defs.append(_FMT_DEF)
    out.by_type[dfspec.FMT_TYPE] = [(-1, 0)]
    if fmt_pos.size == 0:
        return out
    payload = dfspec.FMT_LENGTH - 3
    # cheap first: the type is not FMT's and the name starts with a printable character
    head = _lookup(a, fmt_pos + 5)
    fmt_pos = fmt_pos[(head >= 0x20) & (head < 0x7F) & (_lookup(a, fmt_pos + 3) != dfspec.FMT_TYPE)]
    raw = _record_view(a, np.dtype((np.uint8, payload)))
    keep = np.zeros(fmt_pos.size, bool)
    step = 1 << 16
    for k in range(0, fmt_pos.size, step):
        rec = raw[fmt_pos[k : k + step].astype(np.intp) + 3]
        keep[k : k + step] = (rec[:, 0] != dfspec.FMT_TYPE) & _text_ok(rec[:, 2:6], name=True) \
            & _text_ok(rec[:, 6:22], name=False)
    fmt_pos = fmt_pos[keep]
    if fmt_pos.size == 0:
        return out
    blobs = _records(a, np.dtype((np.void, payload)), fmt_pos + 3)
    uniq, first, inverse = _unique(blobs)
    del blobs
    recs = uniq.view(_FMT_DEF.payload_dtype).reshape(-1)
    index: dict[Definition, int] = {_FMT_DEF: 0}
    bad: dict[int, tuple[int, str]] = {}
    def_of = np.full(uniq.size, -1, np.int64)  # per distinct payload: index into defs
    plausible = np.zeros(uniq.size, bool)
    for u, (mtype, length, name, fmt, cols) in enumerate(recs.tolist()):
        sname = name.split(b"\0", 1)[0].decode("ascii")
        sfmt = fmt.split(b"\0", 1)[0].decode("ascii")
        plausible[u] = True
        columns = tuple(_decode_text(cols).split(",")) if cols else ()
        d = Definition(int(mtype), sname, int(length), sfmt, columns)
        problem = d.problem()
        if problem is not None:
            at = int(first[u])
            if d.type not in bad or at < bad[d.type][0]:
                bad[d.type] = (at, f"type {d.type} ({d.name}): {problem}")
            continue
        if d not in index:
            index[d] = len(out.defs)
            out.defs.append(d)
        def_of[u] = index[d]
    out.plausible = fmt_pos[plausible[inverse]].tolist()
    # where each type's definition changes, in file order
    ids = def_of[inverse]
    usable = ids >= 0
    pos, ids = fmt_pos[usable].astype(np.int64), ids[usable]
    types = a[pos + 3].astype(np.int64)
    order = np.lexsort((pos, types))
    pos, ids, types = pos[order], ids[order], types[order]
    change = np.ones(pos.size, bool)
    change[1:] = (types[1:] != types[:-1]) | (ids[1:] != ids[:-1])
    for t, p, i in zip(types[change].tolist(), pos[change].tolist(), ids[change].tolist(),
                       strict=True):
        out.by_type.setdefault(t, []).append((p, i))
    out.problems = [msg for t, (_, msg) in sorted(bad.items()) if t not in out.by_type]
    return out


def _text_ok(chars: np.ndarray, name: bool) -> np.ndarray:
    """Rows of ``chars`` (fixed-width byte fields) that decode as an FMT name (printable
    ASCII, not blank) or format (ASCII) up to their first NUL."""
    ended = np.cumsum(chars == 0, axis=1) > 0  # at or after the first NUL
    if not name:
        return np.all(ended | (chars < 0x80), axis=1)
    printable = (chars >= 0x20) & (chars < 0x7F)
    solid = printable & (chars != 0x20)
    return np.all(ended | printable, axis=1) & np.any(~ended & solid, axis=1)


def _lookup(table: np.ndarray, index: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``table[index]`` for a compact integer ``index``, in slices (numpy indexes with
    ``intp`` far faster than with small integer types, and a whole ``intp`` copy of the
    index would be large).

    Examples
    --------
    >>> _lookup(np.array([10, 20, 30]), np.array([2, 0, 2], np.uint8)).tolist()
    [30, 10, 30]
    """
    if out is None:
        out = np.empty(index.shape, table.dtype)
    step = 1 << 16
    for k in range(0, index.size, step):
        np.take(table, index[k : k + step].astype(np.intp), out=out[k : k + step])
    return out


def _counts(index: np.ndarray, size: int) -> np.ndarray:
    """``np.bincount(index, minlength=size)`` of a compact integer index, in slices.

    Examples
    --------
    >>> _counts(np.array([0, 2, 2], np.uint8), 4).tolist()
    [1, 0, 2, 0]
    """
    out = np.zeros(size, np.int64)
    step = 1 << 16
    for k in range(0, index.size, step):
        out += np.bincount(index[k : k + step].astype(np.intp), minlength=size)
    return out


def _group(key: np.ndarray, size: int, dtype: np.dtype) -> dict[int, np.ndarray]:
    """Indices of each value of ``key`` (``0 <= key < size``), ascending, for the values
    present: stable radix sorts of cache-sized slices, each value's indices written
    straight into its preallocated result.

    Examples
    --------
    >>> {k: v.tolist() for k, v in _group(np.array([2, 0, 2, 1]), 3, np.dtype(np.int32)).items()}
    {0: [1], 1: [3], 2: [0, 2]}
    """
    small = key.astype(np.uint8 if size <= 256 else np.uint16 if size <= 1 << 16 else np.int32)
    step = 1 << 16
    counts = [np.bincount(small[k : k + step].astype(np.intp), minlength=size)
              for k in range(0, small.size, step)]
    total = np.sum(counts, axis=0) if counts else np.zeros(size, np.int64)
    out = {i: np.empty(int(total[i]), dtype) for i in np.flatnonzero(total).tolist()}
    filled = dict.fromkeys(out, 0)
    for k, count in zip(range(0, small.size, step), counts, strict=True):
        order = np.argsort(small[k : k + step], kind="stable").astype(dtype)
        order += np.asarray(k, dtype)
        bounds = [0, *np.cumsum(count).tolist()]
        for i in np.flatnonzero(count).tolist():
            at = filled[i]
            out[i][at : at + int(count[i])] = order[bounds[i] : bounds[i + 1]]
            filled[i] = at + int(count[i])
    return out


def _select(wanted: np.ndarray, index: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """``np.flatnonzero(wanted[index]).astype(dtype)`` for a compact integer ``index``, in
    slices (no full-length mask nor ``intp`` copy: the result is the only fresh memory, and
    only as much of it as is found).

    Examples
    --------
    >>> _select(np.array([False, True, True]), np.array([1, 0, 2, 0], np.int16),
    ...         np.dtype(np.int32)).tolist()
    [0, 2]
    """
    out = np.empty(index.size, dtype)
    found = 0
    step = 1 << 16
    for k in range(0, index.size, step):
        hit = np.flatnonzero(np.take(wanted, index[k : k + step].astype(np.intp)))
        hit += k
        out[found : found + hit.size] = hit
        found += hit.size
    return out[:found]


def _record_view(a: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """Overlapping view: element ``k`` is ``dtype`` read at byte ``k`` of the file."""
    count = a.size - dtype.itemsize + 1
    if count <= 0:
        return np.zeros(0, dtype)
    return np.ndarray((count,), dtype=dtype, buffer=a, offset=0, strides=(1,))


def _records(a: np.ndarray, dtype: np.dtype, offsets: np.ndarray) -> np.ndarray:
    """Copy the ``dtype`` items starting at ``offsets`` (one plain-bytes gather)."""
    raw = _record_view(a, np.dtype((np.void, dtype.itemsize)))[offsets.astype(np.intp)]
    return raw.view(dtype)


def _sweep(
    pos: np.ndarray, types: np.ndarray, table: _Definitions, lengths: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The definition of each candidate ``pos`` (index into ``table.defs``, -1: type
    undefined) and its forward evidence (the next candidate starts where it ends, by
    ``lengths``: per definition, one more entry for -1), in one pass of cache-sized slices
    (each type converted to an index once, both looked up from it).

    A type's first definition applies up to its next FMT record (also before the first one,
    so that a log whose first FMT records are damaged still decodes). The log is cut into
    epochs at each redefinition; a 256-entry table per epoch then gives its candidates their
    definitions and lengths.

    Examples
    --------
    >>> table = _Definitions(defs=[_FMT_DEF, Definition(1, "A", 5, "h", ("V",))],
    ...                      by_type={128: [(-1, 0)], 1: [(-1, 1)]})
    >>> defid, fwd = _sweep(np.array([0, 5, 10]), np.array([1, 1, 7], np.uint8), table,
    ...                     np.array([89, 5, 0]))
    >>> defid.tolist(), fwd.tolist()
    ([1, 1, -1], [True, True, False])
    """
    m = pos.size
    dt = np.int16 if len(table.defs) < 2**15 else np.int32
    events = sorted((p, t, i) for t, e in table.by_type.items() for p, i in e[1:])
    # per epoch: candidate range and type -> definition table (None: ``defid`` given)
    epochs: list[tuple[int, int, np.ndarray | None]]
    if len(events) > 4096:  # pathological: per-type lookup instead of a big table
        defid = _assign_per_type(pos, types, table, dt)
        epochs = [(0, m, None)]
    else:
        defid = np.empty(m, dt)
        lut = np.full(256, -1, dt)
        for t, entries in table.by_type.items():
            lut[t] = entries[0][1]
        starts = np.array([p for p, _, _ in events], pos.dtype)
        edges = [0, *np.searchsorted(pos, starts, side="left").tolist(), m]
        epochs = [(edges[0], edges[1], lut.copy())]
        for k, (_, t, i) in enumerate(events, start=1):
            lut[t] = i
            epochs.append((edges[k], edges[k + 1], lut.copy()))
    fwd = np.zeros(m, bool)
    step = 1 << 16
    for lo, hi, of_type in epochs:
        length_of = lengths if of_type is None else lengths[of_type]
        for k in range(lo, hi, step):
            e = min(k + step, hi)
            if of_type is None:
                key = defid[k:e].astype(np.intp)
            else:
                key = types[k:e].astype(np.intp)
                np.take(of_type, key, out=defid[k:e])
            ends = np.take(length_of, key)
            ends += pos[k:e]
            j = min(e, m - 1) - k  # the last candidate has no next one
            np.equal(ends[:j], pos[k + 1 : k + 1 + j], out=fwd[k : k + j])
    return defid, fwd


def _assign_per_type(
    pos: np.ndarray, types: np.ndarray, table: _Definitions, dt: type[np.signedinteger]
) -> np.ndarray:
    first = np.full(256, -1, dt)
    for t, entries in table.by_type.items():
        first[t] = entries[0][1]
    defid = first[types]
    order = np.argsort(types, kind="stable")
    bounds = np.concatenate([[0], np.cumsum(np.bincount(types, minlength=256))])
    for t, entries in table.by_type.items():
        if len(entries) > 1:
            sel = order[bounds[t] : bounds[t + 1]]
            starts = np.array([p for p, _ in entries], np.int64)
            ids = np.array([i for _, i in entries], dt)
            k = np.searchsorted(starts, pos[sel], side="right") - 1
            defid[sel] = ids[np.maximum(k, 0)]
    return defid


def _chain(pos: np.ndarray, end: np.ndarray) -> np.ndarray:
    """Greedy chain from the first node: indices of the nodes it visits (see
    :func:`_chain_mask`)."""
    return np.flatnonzero(_chain_mask(pos, end)).astype(pos.dtype)


def _chain_mask(pos: np.ndarray, end: np.ndarray) -> np.ndarray:
    """Greedy chain from the first node: which nodes it visits.

    Each node is followed by the first node at or after its end. Runs of nodes that end
    exactly where the next one starts are taken whole; the successors of the other
    ("irregular") nodes are found at once, and a plain walk hops from run to run, once per
    irregular node at most.
    """
    m = pos.size
    irr = np.flatnonzero(end[:-1] != pos[1:])
    if irr.size == 0:
        return np.ones(m, bool)
    after = np.searchsorted(pos, end[irr], side="left")  # where the chain goes on
    # compact int arrays (not lists): bounded memory however many irregular nodes there are
    next_irr = array.array("q", np.searchsorted(irr, after, side="left").tobytes())
    after_a = array.array("q", after.astype(np.int64).tobytes())
    irr_a = array.array("q", irr.astype(np.int64).tobytes())
    starts, stops = array.array("q"), array.array("q")
    c, k = 0, 0
    while True:  # c strictly increases: always progresses
        starts.append(c)
        if k >= len(irr_a):
            stops.append(m)
            break
        stops.append(irr_a[k] + 1)
        c = after_a[k]
        if c >= m:
            break
        k = next_irr[k]
    # runs are disjoint and ascending: off before each run, on along it, off after the last
    edges = np.empty(2 * len(starts) + 2, np.int64)
    edges[0], edges[-1] = 0, m
    edges[1:-1:2] = np.frombuffer(starts, np.int64)
    edges[2:-1:2] = np.frombuffer(stops, np.int64)
    on = np.zeros(edges.size - 1, bool)
    on[1::2] = True
    return np.repeat(on, np.diff(edges))


def _near(
    idx: np.ndarray, span: int, flag: np.ndarray | None,
    hit: Callable[[int, np.ndarray], np.ndarray], size: int | None = None,
) -> np.ndarray:
    """For each candidate index in ``idx``: is one of the ``|span|`` candidates before
    (``span < 0``) or after it ``flag``-ged and satisfying ``hit``?

    ``hit(k, nb)`` receives the first position ``k`` in ``idx`` of a block and the
    neighbours' indices (shape ``(block, |span|)``) and returns a boolean array of that
    shape. Headers inside one record are few, so a short look-around replaces a search over
    all candidates. ``flag`` None stands for every one of ``size`` candidates (default: as
    many as ``flag`` has).
    """
    size = flag.size if flag is not None else size
    assert size is not None
    out = np.zeros(idx.size, bool)
    steps = np.arange(1, abs(span) + 1) * (1 if span > 0 else -1)
    block = 1 << 12  # bounded temporaries, whatever the number of such candidates
    for k in range(0, idx.size, block):
        nb = idx[k : k + block, None] + steps
        valid = (nb >= 0) & (nb < size)
        nb = np.clip(nb, 0, size - 1)
        if flag is not None:
            valid &= flag[nb]
        out[k : k + block] = np.any(valid & hit(k, nb), axis=1)
    return out


@dataclass
class _Framing:
    """The header candidates and which of them are records.

    Candidates that are not records (header patterns inside a record, garbage) stay in
    place, marked by the definition index ``len(defs)`` (:attr:`none`): a log has few, and
    leaving them costs no copy of the full-length arrays.
    """

    pos: np.ndarray  # offsets of the candidates, ascending
    defid: np.ndarray  # their definition index; ``none`` for those that are not records
    skip_at: np.ndarray  # offsets of the byte ranges no record covers
    skip_len: np.ndarray  # and their sizes
    none: int  # the definition index of a candidate that is not a record
    count: int  # how many candidates are records

    def records(self) -> tuple[np.ndarray, np.ndarray]:
        """Offsets and definition indices of the records alone."""
        if self.count == self.pos.size:
            return self.pos, self.defid
        keep = self.defid != self.none
        return self.pos[keep], self.defid[keep]


def _frame(a: np.ndarray, cand: np.ndarray, types: np.ndarray, table: _Definitions) -> _Framing:
    """The accepted records among the header candidates ``cand`` (see the module doc).

    Nearly every candidate of a log is followed by the next one exactly where it ends; only
    the others (*suspects*: header-like bytes inside a record, garbage, the last record,
    undefined types) need the evidence rules, so these are evaluated on the suspects alone
    and the full-length flags are set from them: few passes over the candidates and little
    fresh memory, which is what a cold read pays for.
    """
    n = a.size
    m = cand.size
    lengths = np.array([d.length for d in table.defs] + [0], cand.dtype)
    # definitions and forward evidence (the next header starts where this record ends: the
    # common case, checked on the very next candidate; only the rest needs a binary search)
    defid, fwd = _sweep(cand, types, table, lengths)
    end = _Ends(cand, defid, lengths)  # undefined (-1) -> the sentinel 0
    sus = np.flatnonzero(~fwd).astype(cand.dtype)  # not followed at once (few, in a log)
    # outside ``sus`` a candidate is known (defined types have a length), complete (it ends
    # at the next candidate), has forward and backward evidence: a node
    known = end[sus] > cand[sus]
    complete = known & (end[sus] <= n)
    # backward evidence of the suspects: the candidate before ends here, or a suspect's
    # end is found further on
    has_in = np.zeros(sus.size, bool)
    has_in[sus > 0] = fwd[sus[sus > 0] - 1]
    rest = sus[complete]
    j = np.searchsorted(cand, end[rest], side="left")
    found = j < m
    found[found] = cand[j[found]] == end[rest[found]]
    fwd[rest[found]] = True
    at = np.searchsorted(sus, j[found])  # found candidates that are suspects themselves
    inside = at < sus.size
    inside[inside] = sus[at[inside]] == j[found][inside]
    has_in[at[inside]] = True
    del rest, j, found, at, inside
    fwd_sus = fwd[sus]
    backed_sus = (fwd_sus | has_in) & known
    backed = np.ones(m, bool)
    backed[sus] = backed_sus
    node_sus = complete & backed_sus
    # a lone record between two stretches of garbage has neither kind of evidence: take it
    # unless it lies inside the declared span of a backed header (e.g. a cut last record)
    # (FMT records need plausible content instead, below)
    weak = sus[complete & ~backed_sus & (types[sus] != dfspec.FMT_TYPE)]
    weak = weak[~_near(weak, -_NEAR, backed,
                       lambda k, nb: end[nb] > cand[weak[k : k + nb.shape[0]], None])]
    # ... and that has no other header inside it (not one of a flood of header patterns)
    weak = weak[~_near(weak, _NEAR, None,
                       lambda k, nb: cand[nb] < end[weak[k : k + nb.shape[0]]][:, None], m)]
    node = backed  # reused: every candidate outside ``sus`` is a node
    node[sus] = node_sus
    node[weak] = True
    plausible = np.searchsorted(cand, np.array(table.plausible, cand.dtype))
    node[plausible] = True
    del backed, backed_sus, node_sus, known, complete, has_in
    # a record with backward evidence only must not swallow one with forward evidence, nor
    # an FMT record whose content checks out (garbage on both sides of it leaves it no chain,
    # and its own header bytes can look like a defined type's header just before it)
    back_only = sus[node[sus] & ~fwd_sus]
    fwd[plausible] = True  # now: forward evidence or plausible content
    swallows = _near(back_only, _NEAR, fwd,
                     lambda k, nb: cand[nb] < end[back_only[k : k + nb.shape[0]]][:, None])
    node[back_only[swallows]] = False
    del fwd, fwd_sus, swallows, plausible
    # a node may break the chain only where it is a suspect or the next one is not a node
    skip = np.flatnonzero(~node).astype(cand.dtype)
    _, starts, stops = _chain_nodes(cand, end, node, (sus, skip - 1), skip, mask=False)
    del node
    skipped = _run_gaps(n, cand, end, starts, stops)
    none = len(table.defs)
    defid[_outside_runs(m, starts, stops)] = none  # (``defid`` is this function's own)
    return _Framing(cand, defid, *skipped, none=none, count=int((stops - starts).sum()))


class _Ends:
    """End offsets of header candidates (offset + their definition's length; 0 for an
    undefined type), computed for the candidates asked for: the framing needs them for a
    few, and a full-length array would be fresh memory a cold read pays for.

    Examples
    --------
    >>> e = _Ends(np.array([0, 5]), np.array([1, -1]), np.array([9, 3, 0]))
    >>> e[np.array([0, 1])].tolist(), e[:1].tolist()
    ([3, 5], [3])
    """

    def __init__(self, cand: np.ndarray, defid: np.ndarray, lengths: np.ndarray) -> None:
        self.cand, self.defid, self.lengths = cand, defid, lengths

    def __getitem__(self, idx: np.ndarray | slice) -> np.ndarray:
        ends = self.lengths[self.defid[idx]]
        ends += self.cand[idx]
        return ends


def _outside_runs(m: int, starts: np.ndarray, stops: np.ndarray) -> np.ndarray:
    """Indices ``0..m-1`` outside the ranges ``starts[k]..stops[k]`` (ascending, disjoint).

    Examples
    --------
    >>> _outside_runs(10, np.array([1, 6]), np.array([3, 8])).tolist()
    [0, 3, 4, 5, 8, 9]
    """
    lo = np.concatenate([[0], stops]).astype(np.int64)
    hi = np.concatenate([starts, [m]]).astype(np.int64)
    size = np.maximum(hi - lo, 0)
    total = int(size.sum())
    return np.arange(total, dtype=np.int64) + np.repeat(lo - (np.cumsum(size) - size), size)


def _chain_nodes(
    pos: np.ndarray, end: np.ndarray | _Ends, node: np.ndarray,
    suspects: Sequence[np.ndarray] | None = None, skip: np.ndarray | None = None,
    mask: bool = True,
) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
    """:func:`_chain_mask` over the ``node`` candidates only, without copying them out:
    which candidates the chain visits, and the runs it takes whole (``starts``, ``stops``:
    candidate index ranges, each record of a run ending where the next one starts).

    A node is *regular* when the next candidate is a node starting where it ends; the chain
    takes runs of regular nodes whole and looks up, for each other node, the first node at
    or after its end (skipping the few candidates that are not nodes).

    Examples
    --------
    >>> pos, end = np.array([0, 3, 5, 6, 9]), np.array([3, 6, 6, 9, 12])
    >>> keep, starts, stops = _chain_nodes(pos, end, np.array([1, 1, 0, 1, 1], bool))
    >>> keep.tolist(), starts.tolist(), stops.tolist()
    ([True, True, False, True, True], [0, 3], [2, 5])

    ``suspects`` (arrays of candidate indices) and ``skip`` (the non-nodes, ascending), when
    given, spare the passes over all candidates: only suspects may be irregular. Without
    ``mask`` only the runs are returned (the mask is None).
    """
    m = pos.size
    none = np.zeros(0, np.int64)
    if m == 0:
        return np.zeros(0, bool), none, none
    if suspects is None:
        regular = np.zeros(m, bool)
        np.equal(end[:-1], pos[1:], out=regular[:-1])
        regular[:-1] &= node[1:]
        irr = np.flatnonzero(node & ~regular)  # never empty when a node exists: the last one
        del regular
    else:  # only these may be irregular
        some = np.concatenate([s[(s >= 0) & (s < m)] for s in suspects]).astype(np.int64)
        irr = _unique(some[node[some]])[0]
        nxt = np.minimum(irr + 1, m - 1)
        irr = irr[(irr == m - 1) | (end[irr] != pos[nxt]) | ~node[nxt]]
    if irr.size == 0:
        return np.zeros(m, bool) if mask else None, none, none
    if skip is None:
        skip = np.flatnonzero(~node)  # candidates that are not nodes (few)
    # per non-node: the first index after its run of consecutive non-nodes
    brk = np.flatnonzero(np.diff(skip) != 1)
    run_end = np.repeat(np.append(skip[brk], skip[-1:]) + 1 if skip.size else skip,
                        np.diff(np.concatenate([[0], brk + 1, [skip.size]])))

    def next_node(j: np.ndarray) -> np.ndarray:  # first node at index >= j
        k = np.searchsorted(skip, j)
        inside = k < skip.size
        inside[inside] = skip[k[inside]] == j[inside]
        out = j.copy()
        out[inside] = run_end[k[inside]]
        return out

    after = next_node(np.searchsorted(pos, end[irr], side="left"))  # where the chain goes on
    next_irr = array.array("q", np.searchsorted(irr, after, side="left").astype(np.int64)
                           .tobytes())
    after_a = array.array("q", after.astype(np.int64).tobytes())
    irr_a = array.array("q", irr.astype(np.int64).tobytes())
    starts, stops = array.array("q"), array.array("q")
    c = int(next_node(np.zeros(1, np.int64))[0])
    k = int(np.searchsorted(irr, c))
    while c < m:  # c strictly increases: always progresses
        starts.append(c)
        stops.append(irr_a[k] + 1)
        c = after_a[k]
        if c >= m:
            break
        k = next_irr[k]
    first, last = np.frombuffer(starts, np.int64), np.frombuffer(stops, np.int64)
    if not mask:
        return None, first, last
    edges = np.empty(2 * first.size + 2, np.int64)
    edges[0], edges[-1] = 0, m
    edges[1:-1:2] = first
    edges[2:-1:2] = last
    on = np.zeros(edges.size - 1, bool)
    on[1::2] = True
    return np.repeat(on, np.diff(edges)), first, last


def _run_gaps(
    n: int, pos: np.ndarray, end: np.ndarray | _Ends, starts: np.ndarray, stops: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_skipped_regions` of the records in runs ``starts..stops`` of candidates
    (records within a run leave no gap: only the runs' edges are looked at)."""
    if starts.size == 0:
        return pos[:0], pos[:0]
    return _skipped_regions(n, pos[starts], end[stops - 1])


# --------------------------------------------------------------------------- decoding
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


def _gather_by_block(
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
        _release(a, lo, lo + _BLOCK_BYTES)
    for d, _, out in jobs:  # once per column, not per slice
        layout = _layout(d)
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
    as the records are passed (see :func:`_release`); without ``quiet``, float columns
    copied as stored may keep signalling NaNs (the caller quiets them,
    :func:`_quiet_nans`).
    """
    layout = _layout(d)
    if out is None:
        out = _alloc_columns(pos.size, {c: (dt, shape) for c, (_, _, dt, shape) in layout.items()})
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
            recs = {f: _field_view(a, pdt, f)[at] for f, _, _ in fields}
        else:
            recs = _records(a, pdt, pos[k:stop] + 3)
        for f, ch, col in fields:
            if ch is None:
                col[k:stop] = recs[f]
                if quiet and col.dtype.kind == "f":
                    _quiet_nans(col[k:stop])
            else:
                _column_into(recs[f], ch, d.name, col[k:stop])
        k = stop
        if release and k < pos.size and int(pos[k]) - done >= _RELEASE_MIN:
            _release(a, done, int(pos[k]))
            done = int(pos[k])
    if release:
        _release(a, done, a.size)
    return out


_DIRECT = 4  # fields gathered one by one when they hold at most 1/4 of a record's bytes


def _field_view(a: np.ndarray, payload: np.ndarray | np.dtype, name: str) -> np.ndarray:
    """Overlapping view: element ``k`` is field ``name`` of a ``payload`` read at byte
    ``k`` of the file.

    Examples
    --------
    >>> dt = np.dtype({"names": ["f0", "f1"], "formats": ["<u1", "<u2"], "offsets": [0, 1]})
    >>> _field_view(np.arange(6, dtype=np.uint8), dt, "f1")[[0, 2]].tolist()
    [513, 1027]
    """
    fdt, ofs = np.dtype(payload).fields[name][:2]  # type: ignore[index]
    count = a.size - ofs - fdt.itemsize + 1
    if count <= 0:
        return np.zeros(0, fdt)
    return np.ndarray((count,), dtype=fdt, buffer=a, offset=ofs, strides=(1,))


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


def _gather_times(a: np.ndarray, d: Definition, pos: np.ndarray) -> np.ndarray | None:
    """Boot time (s) of the records of ``d`` at ``pos``, or None when ``d`` has none."""
    tf = d.time_field
    if tf is None:
        return None
    _, i, scale = tf
    dt = np.dtype(dfspec.FORMAT_CHARS[d.format[i]].dtype)
    ofs = sum(np.dtype(dfspec.FORMAT_CHARS[c].dtype).itemsize for c in d.format[:i])
    return _records(a, dt, pos + 3 + ofs).astype(np.float64) * scale


# --------------------------------------------------------------------------- metadata
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


def _mode_names(vehicle: str | None) -> dict[int, str]:
    """Mode number -> name for the vehicle type (:mod:`mavsid.autopilot.modes`)."""
    return dict(ardupilot_modes(vehicle) or {})


def _modes(table: Mapping[str, np.ndarray] | None, time_s: np.ndarray | None,
           vehicle: str | None) -> tuple[ModeChange, ...]:
    if not table or time_s is None:
        return ()
    names = _mode_names(vehicle)
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
) -> RawLog:
    """Build the :class:`RawLog` from decoded columns (shared by the binary and text readers).

    ``columns``/``times`` hold the messages to return; ``meta_*`` the full-log PARM, MSG,
    MODE, VER and FMTU/UNIT/MULT tables used for parameters, texts, modes and units;
    ``banner`` extra lines (text logs' preamble) searched for the firmware after the texts;
    ``declared`` the fields of tables read for their times only.
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
    texts: tuple[TextMessage, ...] = ()
    msg = meta_columns.get("MSG", {})
    if "Message" in msg:
        texts = tuple(TextMessage(float(t), str(s)) for t, s in
                      zip(meta_times["MSG"].tolist(), msg["Message"].tolist(), strict=True))
    vehicle, firmware = vehicle_and_firmware([t.text for t in texts] + list(banner),
                                             meta_columns)
    modes = _modes(meta_columns.get("MODE"), meta_times.get("MODE"), vehicle)
    return RawLog(source, messages, params=params, texts=texts, modes=modes,
                  autopilot="ardupilot", vehicle=vehicle, firmware=firmware)


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


def _skipped_regions(n: int, pos: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Offsets and sizes of the byte ranges not covered by accepted records."""
    inner = pos[1:] - end[:-1]
    k = np.flatnonzero(inner > 0)
    starts = np.concatenate([[0], end[k], [end[-1]]])
    sizes = np.concatenate([[pos[0]], inner[k], [n - end[-1]]])
    keep = sizes > 0
    return starts[keep], sizes[keep]


# --------------------------------------------------------------------------- entry point
def read(
    path: str | os.PathLike[str],
    messages: Sequence[str] | None = None,
    start: float | None = None,
    stop: float | None = None,
    times_only: bool = False,
    **options: object,
) -> RawLog:
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
    if options:
        names = ", ".join(sorted(options))
        raise ConfigError(f"{spath}: option(s) {names} do not apply to DataFlash .bin logs")
    try:
        with open(spath, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            if size == 0:
                raise LogFormatError("empty file", path=spath)
            buf: mmap.mmap | bytes = (
                mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) if size >= 1 << 16
                else f.read()
            )
    except OSError as exc:
        raise LogFormatError(f"cannot open: {exc.strerror or exc}", path=spath) from None
    try:
        return _read_buffer(spath, np.frombuffer(buf, dtype=np.uint8), messages, start, stop,
                            times_only)
    finally:
        if isinstance(buf, mmap.mmap):
            try:
                buf.close()
            except BufferError:  # a view is still referenced somewhere: leave it to the GC
                pass


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
    cand, types = _find_headers(a)
    fmt_at = np.flatnonzero(types == dfspec.FMT_TYPE)  # (few)
    fmt_pos = cand[fmt_at]
    table = _read_definitions(a, fmt_pos[fmt_pos <= n - dfspec.FMT_LENGTH])
    framing = _frame(a, cand, types, table)
    _release(a, 0, n)
    # definitions only from FMT records that are part of the log (rarely differs; FMT is
    # definition 0, that of every FMT record and of no other type)
    fmt_kept = fmt_pos[framing.defid[fmt_at] == 0]
    plausible = np.array(table.plausible, fmt_kept.dtype)
    at = np.minimum(np.searchsorted(fmt_kept, plausible), max(fmt_kept.size - 1, 0))
    if plausible.size and (fmt_kept.size == 0 or np.any(fmt_kept[at] != plausible)):
        table = _read_definitions(a, fmt_kept)
        framing = _frame(a, cand, types, table)
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
        sel = _select(decode, framing.defid, idx_dt)
        defid = _lookup(framing.defid, sel)
        where = _lookup(framing.pos, sel)
    members = _group(defid, ndefs + 1, idx_dt)
    members.pop(ndefs, None)  # the candidates that are not records
    del defid
    windowed = start is not None or stop is not None
    # per definition: indices into the decoded records (``sel``), their offsets and times
    groups: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray | None]] = {}
    first: dict[int, int] = {}  # each definition's first record (orders the messages)
    for i, k in members.items():
        d = table.defs[i]
        first[i] = int(k[0])
        pos = _lookup(where, k)
        t = _gather_times(a, d, pos) if windowed and d.name not in _META_NAMES else None
        if t is not None:  # timed records outside the window are not decoded
            keep = window_mask(t, start, stop)
            assert keep is not None
            k, pos, t = k[keep], pos[keep], t[keep]
        groups[i] = (k, pos, t)
    del members
    _release(a, 0, n)
    # records without a time field hold the time of the latest timed record before them
    untimed = [i for i in groups if not timed[i]]
    src: tuple[np.ndarray, np.ndarray] = (np.zeros(0, idx_dt), np.zeros(0))
    if untimed:
        k = _sorted_concat([groups[i][0] for i in untimed])
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
        parts, dropped = _bounded_layouts(parts)
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
    only = {name: {c for c, (_, ch, _, _) in _layout(d).items()
                   if c in INSTANCE_COLUMNS or ch in "BbM"
                   or (d.time_field is not None and c == d.time_field[0])}
            for name, (d, *_) in single.items() if skeleton(name)}
    jobs: list[tuple[Definition, np.ndarray, dict[str, np.ndarray]]] = []
    prefilled: dict[str, tuple[dict[str, np.ndarray], Callable[[], np.ndarray]]] = {}
    for name, parts in all_parts.items():
        if name in single:
            d, _, pos, t = single[name]
            keep_cols = only.get(name)
            cols = _alloc_columns(pos.size, {c: (dt, shape)
                                             for c, (_, _, dt, shape) in _layout(d).items()
                                             if keep_cols is None or c in keep_cols})
            jobs.append((d, pos, cols))
            prefilled[name] = (cols, functools.partial(_times_of, d, cols) if t is None
                               else functools.partial(np.asarray, t))
        elif (plan := _plan_message(a, parts)) is not None:
            jobs.extend(plan[1])
            prefilled[name] = (plan[0], plan[2])
    _gather_by_block(a, jobs)
    del jobs
    for name, parts in all_parts.items():
        if name in prefilled:
            cols, times_of = prefilled.pop(name)
            t = times_of()
        else:
            cols, t = _decode_message(a, parts)
        keys = parts[0][1] if len(parts) == 1 else _sorted_concat([p[1] for p in parts])
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
                    declared=declared)


def _sorted_concat(parts: Sequence[np.ndarray]) -> np.ndarray:
    """Ascending arrays joined in ascending order (sorted only when they interleave: parts
    that follow one another in the file need no sort).

    Examples
    --------
    >>> _sorted_concat([np.array([5, 6]), np.array([1, 2])]).tolist()
    [1, 2, 5, 6]
    """
    parts = sorted(parts, key=lambda p: p[0] if p.size else -1)
    out = np.concatenate(parts)
    if out.size > 1 and bool(np.any(out[1:] < out[:-1])):
        out.sort(kind="stable")
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


def _held_times(
    a: np.ndarray,
    framing: _Framing,
    table: _Definitions,
    timed: np.ndarray,
    rows: np.ndarray,
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """Times of the records ``rows`` (ascending; of definitions without a time field): that
    of the nearest earlier record that has one, read from the file (NaN before the first);
    and those source records with their times."""
    # the source is nearly always a few records back: look there first
    src = np.full(rows.size, -1, framing.pos.dtype)
    todo = np.arange(rows.size)
    for back in range(1, _NEAR + 1):
        if not todo.size:
            break
        before = rows[todo] - back
        todo = todo[before >= 0]  # none before: no source
        before = before[before >= 0]
        hit = _lookup(timed, framing.defid[before])
        src[todo[hit]] = before[hit]
        todo = todo[~hit]
    if todo.size:  # the rest (e.g. the FMT records heading a log): a search back in bulk
        is_timed = _lookup(timed, framing.defid[: int(rows[todo[-1]]) + 1])
        prev = np.where(is_timed, np.arange(is_timed.size, dtype=framing.pos.dtype), -1)
        del is_timed
        np.maximum.accumulate(prev, out=prev)
        src[todo] = prev[rows[todo]]
        del prev
    out = np.full(rows.size, np.nan)
    has = src >= 0
    need, _, inverse = _unique(src[has])
    t = np.empty(need.size)
    # one gather per place and kind of time field (not per definition: a log may hold
    # thousands of definitions)
    ids, _, id_of = _unique(framing.defid[need])
    slots: dict[tuple[int, str, float], int] = {}
    slot_of = np.array([slots.setdefault(_time_slot(table.defs[i]), len(slots))
                        for i in ids.tolist()], np.int64)[id_of]
    order = np.argsort(slot_of, kind="stable")
    bounds = np.searchsorted(slot_of[order], np.arange(len(slots) + 1))
    for (ofs, dtype, scale), j in slots.items():
        k = order[bounds[j] : bounds[j + 1]]
        t[k] = _records(a, np.dtype(dtype), framing.pos[need[k]] + 3 + ofs) * scale
    out[has] = t[inverse]
    return out, (need, t)


def _time_slot(d: Definition) -> tuple[int, str, float]:
    """Payload offset, stored dtype and scale (s per count) of a timed definition's time."""
    tf = d.time_field
    assert tf is not None
    _, i, scale = tf
    ofs = sum(np.dtype(dfspec.FORMAT_CHARS[c].dtype).itemsize for c in d.format[:i])
    return ofs, dfspec.FORMAT_CHARS[d.format[i]].dtype, scale


_MAX_UNION = 4  # a message's merged table may hold this many times its records' own cells


def _bounded_layouts(
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


def _decode_message(
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
        return cols, _times_of(d, cols) if t is None else t
    plan = _plan_message(a, parts)
    if plan is None:
        parts = sorted(parts, key=lambda part: int(part[1][0]) if part[1].size else -1)
        decoded = [(d, k, _gather_into(a, d, p)) for d, k, p, _ in parts]
        return _merge([(d, k, cols, _times_of(d, cols) if t is None else t)
                       for (d, k, cols), (_, _, _, t) in zip(decoded, parts, strict=True)])
    out, jobs, finish = plan
    for d, pos, own in jobs:
        _gather_into(a, d, pos, own)
    return out, finish()


_Plan = tuple[dict[str, np.ndarray], list[tuple[Definition, np.ndarray, dict[str, np.ndarray]]],
              Callable[[], np.ndarray]]


def _plan_message(
    a: np.ndarray, parts: list[tuple[Definition, np.ndarray, np.ndarray, np.ndarray | None]]
) -> _Plan | None:
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
        kinds = [_layout(d).get(c) for d, _, _, _ in parts]
        like = next(k[2:] for k in kinds if k is not None)
        dtypes = [k[2] if k is not None and k[3] == like[1] else _filler(like)[0]
                  for k in kinds]
        obj = any(k is not None and k[2].kind == "O" for k in kinds)
        specs[c] = (np.dtype(object) if obj else np.result_type(*dtypes), like[1])
        fill[c] = _filler(like)[1]
    out = _alloc_columns(total, specs)
    jobs = []
    at = 0
    for (d, _, pos, _), size in zip(parts, sizes, strict=True):
        layout = _layout(d)
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
                _times_of(d, own, out=into)
            else:
                t = _gather_times(a, d, pos) if t is None else t
                assert t is not None
                into[...] = t
            at += pos.size
        return t_out

    return out, jobs, finish


def _times_of(
    d: Definition, cols: Mapping[str, np.ndarray], out: np.ndarray | None = None
) -> np.ndarray:
    """Boot time (s) of decoded records of a definition that has a time field (written
    into ``out`` when given)."""
    tf = d.time_field
    assert tf is not None
    name, _, scale = tf
    return np.multiply(cols[name], scale, out=out, dtype=np.float64)


@lru_cache(maxsize=4096)
def _layout(d: Definition) -> dict[str, tuple[str, str, np.dtype, tuple[int, ...]]]:
    """Column -> (payload field, format character, decoded dtype, per-row shape) for ``d``."""
    out = {}
    for column, i in d.fields:
        ch = d.format[i]
        spec = dfspec.FORMAT_CHARS[ch]
        dt = np.dtype(spec.dtype)
        shape: tuple[int, ...] = ()
        if spec.kind == "str":
            dt = np.dtype(object)
        elif spec.multiplier is not None:
            dt = np.dtype(np.float64)
        elif ch == "g":
            dt = np.dtype(np.float32)
        elif (sub := dt.subdtype) is not None:
            dt, shape = sub[0].newbyteorder("="), sub[1]
        else:
            dt = dt.newbyteorder("=")
        out[column] = (f"f{i}", ch, dt, shape)
    return out


def _alloc_columns(
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
    >>> cols = _alloc_columns(3, {"a": (np.dtype("<u8"), ()), "b": (np.dtype("<i2"), (2,))})
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
    """:func:`_decode_message` for parts whose records interleave: decoded ``(definition,
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
