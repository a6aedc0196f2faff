"""DataFlash message definitions: FMT records, their fields, time fields and column layouts.

FMT records (type 128, 89 bytes) declare each type's length, name, format characters and
column names. :func:`read_definitions` parses every FMT record of a log into
:class:`Definitions` (a type may be redefined later in the log, e.g. in concatenated logs:
each record uses the definition in force at its position, or the type's first one);
:func:`column_layout` gives the decoded column of each field and :func:`time_slot` where a
record's boot time is stored.

Examples
--------
>>> d = Definition(0x81, "ATT", 3 + 8 + 4, "Qf", ("TimeUS", "Roll"))
>>> d.time_field, time_slot(d)
(('TimeUS', 0, 1e-06), (0, '<u8', 1e-06))
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from functools import cached_property, lru_cache

import numpy as np

from mavsid.readers import dataflash_spec as dfspec
from mavsid.readers.arrays import lookup, unique
from mavsid.readers.dataflash_scan import record_view, records_at

__all__ = [
    "FMT_DEFINITION",
    "Definition",
    "Definitions",
    "autopilot_of",
    "column_layout",
    "decode_text",
    "read_definitions",
    "time_slot",
]


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


def autopilot_of(defs: Iterable[Definition]) -> str:
    """The autopilot a DataFlash-format log's definitions name: ``px4`` for a PX4 sdlog2
    ``.px4log`` (its clock record ``TIME.StartTime``, written at the start of each logging
    cycle; ArduPilot's logs have none), else ``ardupilot``.

    >>> autopilot_of([Definition(0x81, "TIME", 3 + 8, "Q", ("StartTime",))])
    'px4'
    >>> autopilot_of([Definition(0x81, "ATT", 3 + 12, "Qf", ("TimeUS", "Roll"))])
    'ardupilot'
    """
    sdlog2 = any(d.time_field is not None and d.time_field[0] == "StartTime" for d in defs)
    return "px4" if sdlog2 else "ardupilot"


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


FMT_DEFINITION = Definition(dfspec.FMT_TYPE, "FMT", dfspec.FMT_LENGTH, dfspec.FMT_FORMAT,
                           dfspec.FMT_COLUMNS)


def decode_text(raw: bytes) -> str:
    """Bytes as pymavlink presents them: UTF-8, else Latin-1, cut at the first NUL."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("iso-8859-1")
    cut = text.find("\0")
    return text if cut < 0 else text[:cut]


@dataclass
class Definitions:
    """Every usable definition and, per type, where each takes effect."""

    defs: list[Definition] = field(default_factory=list)
    # type -> [(file offset of the FMT record, index into defs)], by offset
    by_type: dict[int, list[tuple[int, int]]] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)
    # offsets of FMT records whose text fields are plausible (evidence of a record there)
    plausible: list[int] = field(default_factory=list)


def read_definitions(a: np.ndarray, fmt_pos: np.ndarray) -> Definitions:
    """Parse the FMT records at ``fmt_pos`` (already known to be complete).

    Candidates whose name or format cannot be text are dropped with numpy first, and each
    distinct FMT payload is parsed once: a flood of header patterns or of one repeated
    definition costs no Python work per record.
    """
    out = Definitions()
    out.defs.append(FMT_DEFINITION)
    out.by_type[dfspec.FMT_TYPE] = [(-1, 0)]
    if fmt_pos.size == 0:
        return out
    payload = dfspec.FMT_LENGTH - 3
    # cheap first: the type is not FMT's and the name starts with a printable character
    head = lookup(a, fmt_pos + 5)
    fmt_pos = fmt_pos[(head >= 0x20) & (head < 0x7F) & (lookup(a, fmt_pos + 3) != dfspec.FMT_TYPE)]
    raw = record_view(a, np.dtype((np.uint8, payload)))
    keep = np.zeros(fmt_pos.size, bool)
    step = 1 << 16
    for k in range(0, fmt_pos.size, step):
        rec = raw[fmt_pos[k : k + step].astype(np.intp) + 3]
        keep[k : k + step] = (rec[:, 0] != dfspec.FMT_TYPE) & _text_ok(rec[:, 2:6], name=True) \
            & _text_ok(rec[:, 6:22], name=False)
    fmt_pos = fmt_pos[keep]
    if fmt_pos.size == 0:
        return out
    blobs = records_at(a, np.dtype((np.void, payload)), fmt_pos + 3)
    uniq, first, inverse = unique(blobs)
    del blobs
    recs = uniq.view(FMT_DEFINITION.payload_dtype).reshape(-1)
    index: dict[Definition, int] = {FMT_DEFINITION: 0}
    bad: dict[int, tuple[int, str]] = {}
    def_of = np.full(uniq.size, -1, np.int64)  # per distinct payload: index into defs
    plausible = np.zeros(uniq.size, bool)
    for u, (mtype, length, name, fmt, cols) in enumerate(recs.tolist()):
        sname = name.split(b"\0", 1)[0].decode("ascii")
        sfmt = fmt.split(b"\0", 1)[0].decode("ascii")
        plausible[u] = True
        columns = tuple(decode_text(cols).split(",")) if cols else ()
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


@lru_cache(maxsize=4096)
def column_layout(d: Definition) -> dict[str, tuple[str, str, np.dtype, tuple[int, ...]]]:
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


def time_slot(d: Definition) -> tuple[int, str, float]:
    """Payload offset, stored dtype and scale (s per count) of a timed definition's time."""
    tf = d.time_field
    assert tf is not None
    _, i, scale = tf
    ofs = sum(np.dtype(dfspec.FORMAT_CHARS[c].dtype).itemsize for c in d.format[:i])
    return ofs, dfspec.FORMAT_CHARS[d.format[i]].dtype, scale
