"""DataFlash bytes: the header scan and views of records in a memory-mapped log.

A DataFlash log is a sequence of records ``0xA3 0x95 <type> <payload>``. :func:`find_headers`
finds every ``0xA3 0x95`` pair (the *candidates* the framing chooses records from), compiled
where the package was built with a C compiler (``mavsid/readers/_scan.c``), else with numpy;
:func:`record_view`, :func:`records_at` and :func:`field_view` read fixed-size items at any
byte offset without copying the file; :func:`release_pages` hands a stretch of the mapped file
back to the kernel once it has been read, so that a whole-log read does not keep the file
resident on top of the arrays decoded from it.

Examples
--------
>>> data = np.frombuffer(bytes([0xA3, 0x95, 7, 0, 0xA3, 0x95, 9]), np.uint8)
>>> [v.tolist() for v in find_headers(data)]
[[0, 4], [7, 9]]
"""

from __future__ import annotations

import mmap
from types import ModuleType

import numpy as np

from mavsid.readers import dataflash_spec as dfspec

__all__ = [
    "RELEASE_MIN",
    "field_view",
    "find_headers",
    "find_headers_numpy",
    "record_view",
    "records_at",
    "release_pages",
]


_scan: ModuleType | None
try:  # the header scan compiled (setup.py); absent where the package was built without a C
    from mavsid.readers import _scan  # compiler: then the numpy scan, same results
except ImportError:  # pragma: no cover - depends on the build
    _scan = None


_CHUNK = 1 << 20  # bytes scanned per step when looking for headers


# chunks scanned between releases of their file pages (8 MB: measured ~10 ms faster over
# 200 MB than 4, 16 or 32 MB)
_SCAN_RELEASE = 8


def _index_dtype(n: int) -> type[np.signedinteger]:
    """Smallest integer type for byte offsets and record indices of an ``n``-byte file."""
    return np.int32 if n < 2**31 - 1024 else np.int64


RELEASE_MIN = 1 << 22  # bytes of file pages worth a madvise call


def release_pages(a: np.ndarray, lo: int, hi: int) -> None:
    """Tell the kernel that bytes ``lo..hi`` of the memory-mapped file ``a`` are not needed
    for now: their pages leave the process's resident set (they stay in the page cache and
    come back on the next touch, a minor fault). Without it, reading every record maps the
    whole file into the process, on top of the arrays decoded from it."""
    base = a.base.obj if isinstance(a.base, memoryview) else a.base
    if not isinstance(base, mmap.mmap) or not hasattr(mmap, "MADV_DONTNEED"):
        return
    lo = max(lo, 0) // mmap.PAGESIZE * mmap.PAGESIZE
    hi = min(hi, len(base))
    if hi - lo < RELEASE_MIN:
        return
    try:
        base.madvise(mmap.MADV_DONTNEED, lo, hi - lo)
    except (OSError, ValueError):  # not supported here: only memory use differs
        pass


def find_headers(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Offsets of every ``0xA3 0x95`` byte pair followed by a type byte, ascending, and
    those type bytes.

    Compiled (``mavsid/readers/_scan.c``: 16 bytes a step with SSE2, one pass over the file
    instead of the numpy scan's passes over its masks; a selective read ~1.2x faster) where
    the package was built with a C compiler for a machine with SSE2, else
    :func:`find_headers_numpy`: the same offsets and types either way (tests). The file
    is scanned 8 MB at a time, each window's pages handed back once scanned; the result
    starts at a size for a record per ~40 bytes and grows when a file holds more.

    Examples
    --------
    >>> data = np.frombuffer(bytes([0xA3, 0x95, 7, 0xA3, 0x95, 0xA3, 0x95, 9, 0xA3]), np.uint8)
    >>> [v.tolist() for v in find_headers(data)]
    [[0, 3, 5], [7, 163, 9]]
    """
    if _scan is None or not _scan.vectorised:  # (a byte loop is slower than numpy's)
        return find_headers_numpy(a)
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
        release_pages(a, start, stop)
    return found[:count], types[:count]


def find_headers_numpy(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`find_headers` without the compiled scan (a package built without a C
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
    >>> [v.tolist() for v in find_headers_numpy(data)]
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
            release_pages(a, start - (_SCAN_RELEASE - 1) * _CHUNK, start)
    return found[:count], types[:count]


def record_view(a: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """Overlapping view: element ``k`` is ``dtype`` read at byte ``k`` of the file."""
    count = a.size - dtype.itemsize + 1
    if count <= 0:
        return np.zeros(0, dtype)
    return np.ndarray((count,), dtype=dtype, buffer=a, offset=0, strides=(1,))


def records_at(a: np.ndarray, dtype: np.dtype, offsets: np.ndarray) -> np.ndarray:
    """Copy the ``dtype`` items starting at ``offsets`` (one plain-bytes gather)."""
    raw = record_view(a, np.dtype((np.void, dtype.itemsize)))[offsets.astype(np.intp)]
    return raw.view(dtype)


def field_view(a: np.ndarray, payload: np.ndarray | np.dtype, name: str) -> np.ndarray:
    """Overlapping view: element ``k`` is field ``name`` of a ``payload`` read at byte
    ``k`` of the file.

    Examples
    --------
    >>> dt = np.dtype({"names": ["f0", "f1"], "formats": ["<u1", "<u2"], "offsets": [0, 1]})
    >>> field_view(np.arange(6, dtype=np.uint8), dt, "f1")[[0, 2]].tolist()
    [513, 1027]
    """
    fdt, ofs = np.dtype(payload).fields[name][:2]  # type: ignore[index]
    count = a.size - ofs - fdt.itemsize + 1
    if count <= 0:
        return np.zeros(0, fdt)
    return np.ndarray((count,), dtype=fdt, buffer=a, offset=ofs, strides=(1,))
