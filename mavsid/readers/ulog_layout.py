"""ULog formats flattened to record layouts, and a topic's columns over its records' bytes.

A format definition (``F`` message) names fields of the basic types of
:mod:`~mavsid.readers.ulog_spec` or of other formats, nested, and arrays of either. A topic's
*layout* is its format flattened as pyulog flattens it: field names (``xyz[0]``, ``a.b``),
their basic types, offsets and the record's size (:func:`new_layout`). :class:`Fields` gives
a topic's columns as strided views over its records, made when first asked for.

Formats parsed and layouts are kept for the process (within a budget of fields,
:class:`Kept`), keyed by the texts of a topic's format and of every format it nests
(:func:`layout_key`): the logs of one firmware repeat them, so a batch parses each once; two
logs that define a type differently never share a layout.

Examples
--------
>>> layout = new_layout((("att", b"att:uint64_t timestamp;float[2] q;"),))
>>> layout[0], layout[3]
(('timestamp', 'q[0]', 'q[1]'), 16)
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable, Hashable, Iterator, Mapping, Sequence
from typing import Any, Generic, TypeVar

import numpy as np
from numpy.typing import NDArray

from mavsid.readers.ulog_messages import TYPE_SIZE, BadPayload, Field, parse_format_fast
from mavsid.readers.ulog_spec import BASIC_TYPES

__all__ = ["Fields", "Kept", "Layout", "LayoutKey", "data_sizes", "field_index",
           "format_cycle", "format_widths", "known_format", "known_layout", "layout_key",
           "new_layout", "stamp_offset"]

_STAMPS = ("timestamp", "timestamp_sample")  # (fields in µs)
#: little-endian numpy dtypes of the basic types; each type's code (its place in
#: BASIC_TYPES, the code ``_scan.ulog_plain`` gives) and the dtype of each code
_DTYPE = {kind: t.dtype for kind, t in BASIC_TYPES.items()}
_CODE = {kind: code for code, kind in enumerate(BASIC_TYPES)}
_BY_CODE = tuple(_DTYPE.values())
_WIDTH = tuple(TYPE_SIZE.values())
#: a format flattening to more fields than a data message can hold bytes is never decoded
_MAX_FIELDS = 0xFFFF
#: fields of the parsed formats, and of the record layouts, kept per process (see Kept)
_KEPT_FIELDS = 1 << 19


_A = TypeVar("_A", bound=Hashable)
_R = TypeVar("_R")


class Kept(Generic[_A, _R]):
    """``fn`` with its results kept for the process, within a budget: each result weighs
    ``weight(result)`` (its fields), the oldest are dropped when the total would pass
    ``budget``, one heavier than the budget is not kept. Logs of one firmware repeat the
    same definitions (10 of the 13 shared ULogs share most of theirs), and a hostile
    stream of huge formats cannot grow the memory without bound.

    Examples
    --------
    >>> twice = Kept(lambda x: 2 * x, weight=lambda r: r, budget=10)
    >>> twice(3), twice(4), twice.total, twice(2), twice.total, twice(9), twice.total
    (6, 8, 8, 4, 4, 18, 4)
    """

    def __init__(self, fn: Callable[[_A], _R], weight: Callable[[_R], int],
                 budget: int = _KEPT_FIELDS) -> None:
        self.fn, self.weight, self.budget = fn, weight, budget
        self.kept: dict[_A, tuple[_R, int]] = {}
        self.total = 0
        self.lock = threading.Lock()  # (logs read in threads: a threaded Dask worker)
        functools.update_wrapper(self, fn)

    def __call__(self, arg: _A) -> _R:
        got = self.kept.get(arg)
        if got is not None:
            return got[0]
        result = self.fn(arg)
        w = self.weight(result)
        if w <= self.budget:
            with self.lock:
                if arg not in self.kept:
                    while self.kept and self.total + w > self.budget:
                        self.total -= self.kept.pop(next(iter(self.kept)))[1]
                    self.kept[arg] = result, w
                    self.total += w
        return result

    def clear(self) -> None:
        with self.lock:
            self.kept.clear()
            self.total = 0


@functools.lru_cache(maxsize=64)
def _indices(count: int) -> tuple[str, ...]:
    """The array suffixes ``[0]`` ... ``[count - 1]`` of a flattened field's names.

    Examples
    --------
    >>> _indices(3)
    ('[0]', '[1]', '[2]')
    """
    return tuple(f"[{i}]" for i in range(count))


#: :func:`~mavsid.readers.ulog_messages.parse_format_fast`, its results kept for the process
known_format = Kept(parse_format_fast, weight=lambda parsed: len(parsed[1]) + 1)


def format_cycle(formats: Mapping[str, Sequence[Field]]) -> list[str] | None:
    """A chain of formats that contain themselves (``a`` → ``b`` → ``a``); None if none.

    Examples
    --------
    >>> format_cycle({"a": [("b", 0, "x")], "b": [("a", 2, "y")]})
    ['a', 'b', 'a']
    >>> format_cycle({"a": [("float", 0, "x")]}) is None
    True
    """
    graph = {name: {kind for kind, _, _ in fields if kind not in BASIC_TYPES}
             for name, fields in formats.items()}  # fmt: skip
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def visit(node: str, chain: list[str]) -> list[str] | None:
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return [*chain, node, nxt][[*chain, node].index(nxt) :]
            if nxt in graph and state.get(nxt) is None and (got := visit(nxt, [*chain, node])):
                return got
        state[node] = 2
        return None

    for start in sorted(graph):
        if state.get(start) is None and (found := visit(start, [])):
            return found
    return None


def format_widths(formats: Mapping[str, Sequence[Field]], basic: dict[str, int]) -> dict[str, int]:
    """Each format's size in bytes (formats acyclic; a nested type not defined counts 0).
    ``basic``: the sizes of the formats of basic types only, known from :func:`known_format`
    (the others are summed here).

    Examples
    --------
    >>> nested = {"b": [("a", 2, "x"), ("float", 0, "y")], "a": [("uint8_t", 3, "z")]}
    >>> format_widths(nested, {"a": 3})
    {'a': 3, 'b': 10}
    """
    memo = dict(basic)

    def size(name: str) -> int:
        got = memo.get(name)
        if got is None:
            got = 0
            for kind, count, _ in formats.get(name, ()):
                width = TYPE_SIZE.get(kind)
                got += (size(kind) if width is None else width) * (count or 1)
            memo[name] = got
        return got

    for name in formats:
        size(name)
    return memo


def data_sizes(formats: Mapping[str, Sequence[Field]], widths: dict[str, int]) -> set[int]:
    """The payload sizes data messages of the formats can have: 2 (message id) + a
    format's size (``widths``, from :func:`format_widths`), with and without its trailing
    ``_padding`` fields.

    Examples
    --------
    >>> a = [("uint64_t", 0, "timestamp"), ("uint8_t", 3, "_padding0")]
    >>> sorted(data_sizes({"a": a}, {"a": 11}))
    [10, 13]
    """
    out: set[int] = set()
    for name, fields in formats.items():
        full = trimmed = widths[name]
        for kind, n, fname in reversed(fields):
            width = TYPE_SIZE.get(kind)
            width = (widths.get(kind, 0) if width is None else width) * (n or 1)
            if width and not fname.startswith("_padding"):
                break
            trimmed -= width
        out.update(s + 2 for s in (full, trimmed) if 0 < s <= 0xFFFF - 2)
    return out


#: what a layout depends on (see :func:`layout_key`)
LayoutKey = tuple[tuple[str, "bytes | None"], ...]


def layout_key(name: str, formats: Mapping[str, Sequence[Field]],
             definitions: Mapping[str, bytes]) -> LayoutKey:
    """What a topic's layout depends on: its format's text and those of the formats it
    nests (None for one not defined), in a fixed order: the key of :func:`known_layout`.

    Examples
    --------
    >>> fmts = {"a": (("b", 2, "x"),), "b": (("float", 0, "y"),)}
    >>> layout_key("a", fmts, {"a": b"a:b[2] x;", "b": b"b:float y;"})
    (('a', b'a:b[2] x;'), ('b', b'b:float y;'))
    >>> layout_key("a", {"a": (("c", 0, "z"),)}, {"a": b"a:c z;"})
    (('a', b'a:c z;'), ('c', None))
    """
    key: list[tuple[str, bytes | None]] = []
    seen: set[str] = set()
    stack = [name]
    while stack:
        node = stack.pop()
        if node in seen:
            continue
        seen.add(node)
        text = definitions.get(node)
        key.append((node, text))
        if text is not None:
            stack += [kind for kind, _, _ in reversed(formats[node]) if kind not in TYPE_SIZE]
    return tuple(key)


#: a record layout: field names, their types' codes (see _CODE), offsets, the record's
#: size, name -> index (see :func:`field_index`), and the time fields it has (of _STAMPS);
#: ``_scan.ulog_plain`` makes the same
Layout = tuple[tuple[str, ...], bytes, tuple[int, ...], int, dict[str, int], tuple[str, ...]]


def new_layout(key: LayoutKey) -> Layout:
    """A topic's record layout from its :func:`layout_key`: field names (nested types and
    arrays expanded; an empty one named ``f<index>``, as pyulog's dtype has it), their
    basic types' codes and offsets, the record's size and the names' index, trailing
    padding dropped; kept for the process as :func:`known_layout`. Raises KeyError (a nested
    type not defined), ValueError (repeated field names, which numpy refuses) or
    :class:`BadPayload` (more fields than a message can hold bytes).

    Examples
    --------
    >>> names, codes, offsets, size, index, stamps = new_layout((
    ...     ("a", b"a:uint64_t timestamp;b[2] r;uint8_t[2] _padding0;"),
    ...     ("b", b"b:float y;uint8_t _padding0;")))
    >>> names
    ('timestamp', 'r[0].y', 'r[0]._padding0', 'r[1].y', 'r[1]._padding0')
    >>> list(codes), offsets, size
    ([7, 8, 1, 8, 1], (0, 8, 12, 13, 17), 18)
    """
    formats = {}
    for node, text in key:
        if text is not None:
            formats[node] = known_format(text)[1]
    flat: dict[str, tuple[list[str], list[int]]] = {}

    def flatten(name: str) -> tuple[list[str], list[int]]:
        got = flat.get(name)
        if got is not None:
            return got
        names: list[str] = []
        kinds: list[int] = []
        for kind, count, fname in formats[name]:  # KeyError: an unknown type
            code = _CODE.get(kind)
            if code is not None:
                if not count:
                    names.append(fname)
                    kinds.append(code)
                    continue
                if len(names) + count > _MAX_FIELDS:
                    raise BadPayload
                names += map(fname.__add__, _indices(count))
                kinds += [code] * count
                continue
            inner, inner_kinds = flatten(kind)
            prefixes = [fname + index + "." for index in _indices(count)] if count else [
                fname + "."]
            if len(names) + len(prefixes) * len(inner) > _MAX_FIELDS:
                raise BadPayload
            names += [prefix + sub for prefix in prefixes for sub in inner]
            kinds += inner_kinds * len(prefixes)
        flat[name] = names, kinds
        return names, kinds

    name = key[0][0]
    names, kinds = flatten(name)
    m = len(names)
    while m and names[m - 1].startswith("_padding"):
        m -= 1
    names, kinds = names[:m], kinds[:m]
    if "" in names:
        names = [f or f"f{i}" for i, f in enumerate(names)]
    index = {f: i for i, f in enumerate(names)}
    if len(index) < m:
        raise ValueError(name)
    ends = np.cumsum([_WIDTH[k] for k in kinds]).tolist()
    size = ends[-1] if ends else 0  # (the format's size less the padding dropped)
    stamps = tuple(k for k in _STAMPS if k in index)
    return tuple(names), bytes(kinds), (0, *ends[:-1]) if ends else (), size, index, stamps


def field_index(layout: Layout) -> dict[str, int]:
    """A layout's field name -> index, made on first use where the compiled pass left it
    empty (most of a log's topics are never looked at by name); shared by the topic's
    tables.

    Examples
    --------
    >>> layout = (("a", "b"), b"\x08\x08", (0, 4), 8, {}, ())
    >>> field_index(layout), layout[4]
    ({'a': 0, 'b': 1}, {'a': 0, 'b': 1})
    """
    index = layout[4]
    if len(index) < len(layout[0]):
        index.update({name: at for at, name in enumerate(layout[0])})
    return index


#: :func:`new_layout`, its results kept for the process
known_layout = Kept(new_layout, weight=lambda layout: len(layout[0]) + 1)


def stamp_offset(layout: Layout) -> int:
    """Bytes before a record's ``timestamp`` (its size if it has none)."""
    at = field_index(layout).get("timestamp")
    return layout[3] if at is None else layout[2][at]


class Fields(Mapping[str, NDArray[Any]]):
    """A topic's columns over its records' bytes (``count`` records of the layout's size,
    one after the other, in any buffer: an array, a bytearray): field name -> that field of
    every record (a strided view, of the field's dtype), made when first asked for; no
    structured dtype is built.

    Examples
    --------
    >>> layout = new_layout((("a", b"a:uint64_t timestamp;float x;"),))
    >>> raw = np.frombuffer(np.array([(1, 0.5), (2, 1.5)], "<u8,<f4").tobytes(), np.uint8)
    >>> cols = Fields(raw, 2, layout)
    >>> list(cols), cols["x"].tolist(), len(cols), cols.rows(np.array([False, True]))["timestamp"]
    (['timestamp', 'x'], [0.5, 1.5], 2, array([2], dtype=uint64))
    """

    __slots__ = ("_views", "count", "layout", "raw")

    def __init__(self, raw: NDArray[np.uint8] | bytearray, count: int, layout: Layout) -> None:
        self.raw, self.count, self.layout = raw, count, layout
        self._views: dict[str, NDArray[Any]] = {}

    def __getitem__(self, name: str) -> NDArray[Any]:
        try:
            return self._views[name]
        except KeyError:
            at = field_index(self.layout).get(name) if isinstance(name, str) else None
            if at is None:
                raise KeyError(name) from None
            _, codes, offsets, size, _, _ = self.layout
            dtype = _BY_CODE[codes[at]]
            view = self._views[name] = np.ndarray(
                (self.count,), dtype, buffer=self.raw, offset=offsets[at], strides=(size,)
            ) if self.count else np.zeros(0, dtype)
            return view

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and name in field_index(self.layout)

    def __iter__(self) -> Iterator[str]:
        return iter(self.layout[0])

    def __len__(self) -> int:
        return len(self.layout[0])

    def __repr__(self) -> str:
        return f"Fields({list(self)!r})"

    def __reduce__(self) -> tuple[Any, ...]:
        return (Fields, (self.raw, self.count, self.layout))

    def rows(self, keep: NDArray[np.bool_]) -> Fields:
        """The records where ``keep`` holds."""
        if not self.count:
            return self
        raw = np.frombuffer(self.raw, np.uint8).reshape(self.count, -1)[keep]
        return Fields(raw.reshape(-1), len(raw), self.layout)


