"""Array operations over compact integer indices, in cache-sized slices.

A log's record indices and definition ids are kept in the smallest integer type that holds
them (``int16``/``int32``), and numpy indexes far faster with ``intp``: each function here
converts a slice at a time, so no full-length ``intp`` copy is ever made and the only fresh
memory is the result (what a cold read pays for).

Examples
--------
>>> lookup(np.array([10, 20, 30]), np.array([2, 0, 2], np.uint8)).tolist()
[30, 10, 30]
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["group", "lookup", "select", "sorted_concat", "unique"]


def unique(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sorted distinct values of a 1-d ``x``, the index of each one's first occurrence and
    the index of each element's value: ``np.unique(x, return_index=True,
    return_inverse=True)`` without its import of ``numpy.ma`` (~7 ms of a cold read).

    Examples
    --------
    >>> [v.tolist() for v in unique(np.array([3, 1, 3, 2]))]
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


def lookup(table: np.ndarray, index: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``table[index]`` for a compact integer ``index``, in slices (numpy indexes with
    ``intp`` far faster than with small integer types, and a whole ``intp`` copy of the
    index would be large).

    Examples
    --------
    >>> lookup(np.array([10, 20, 30]), np.array([2, 0, 2], np.uint8)).tolist()
    [30, 10, 30]
    """
    if out is None:
        out = np.empty(index.shape, table.dtype)
    step = 1 << 16
    for k in range(0, index.size, step):
        np.take(table, index[k : k + step].astype(np.intp), out=out[k : k + step])
    return out


def group(key: np.ndarray, size: int, dtype: np.dtype) -> dict[int, np.ndarray]:
    """Indices of each value of ``key`` (``0 <= key < size``), ascending, for the values
    present: stable radix sorts of cache-sized slices, each value's indices written
    straight into its preallocated result.

    Examples
    --------
    >>> {k: v.tolist() for k, v in group(np.array([2, 0, 2, 1]), 3, np.dtype(np.int32)).items()}
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


def select(wanted: np.ndarray, index: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """``np.flatnonzero(wanted[index]).astype(dtype)`` for a compact integer ``index``, in
    slices (no full-length mask nor ``intp`` copy: the result is the only fresh memory, and
    only as much of it as is found).

    Examples
    --------
    >>> select(np.array([False, True, True]), np.array([1, 0, 2, 0], np.int16),
    ...        np.dtype(np.int32)).tolist()
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


def sorted_concat(parts: Sequence[np.ndarray]) -> np.ndarray:
    """Ascending arrays joined in ascending order (sorted only when they interleave: parts
    that follow one another in the file need no sort).

    Examples
    --------
    >>> sorted_concat([np.array([5, 6]), np.array([1, 2])]).tolist()
    [1, 2, 5, 6]
    """
    parts = sorted(parts, key=lambda p: p[0] if p.size else -1)
    out = np.concatenate(parts)
    if out.size > 1 and bool(np.any(out[1:] < out[:-1])):
        out.sort(kind="stable")
    return out
