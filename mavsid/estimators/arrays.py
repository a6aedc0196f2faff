"""Arrays in: one array or a list of records -> 2-D float records, named columns, segments.

What the array API (:func:`~mavsid.estimators.identification.identify`,
:func:`~mavsid.estimators.regression.regress`) does with its arguments before fitting: each
record becomes a samples-first 2-D array, its columns get names, and for
:func:`records` each record becomes one :class:`~mavsid.data.Segment` (the unit rows never
cross).

Examples
--------
>>> [a.shape for a in as_records([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]], "x")]
[(3, 2)]
>>> column_names(None, 2, "u", "input_names")
('u1', 'u2')
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from mavsid.data import Segment
from mavsid.errors import ConfigError

__all__ = ["as_records", "column_names", "records"]


def as_records(a: Any, what: str) -> list[np.ndarray]:
    """One array, or a list of records (numpy arrays, or ragged lists) -> list of 2-D float
    arrays, samples first."""
    if isinstance(a, (list, tuple)) and a and all(isinstance(e, np.ndarray) for e in a):
        parts = list(a)
    else:
        try:
            parts = [np.asarray(a, dtype=float)]
        except ValueError:  # ragged: a list of records of different lengths
            parts = list(a) if isinstance(a, (list, tuple)) else []
        if not parts:
            raise ConfigError(f"{what} must be an array or a list of arrays") from None
    out = []
    for i, part in enumerate(parts):
        arr = np.asarray(part, dtype=float)
        if arr.ndim == 1:
            arr = arr[:, None]
        if arr.ndim != 2 or arr.shape[0] == 0:
            raise ConfigError(f"{what} record {i}: expected (samples, columns), got shape "
                              f"{arr.shape}")
        out.append(arr)
    return out


def column_names(given: Sequence[str] | None, k: int, stem: str, what: str) -> tuple[str, ...]:
    if given is None:
        return (stem,) if k == 1 else tuple(f"{stem}{i + 1}" for i in range(k))
    names = tuple(given)
    if len(names) != k:
        raise ConfigError(f"{what}: {len(names)} names for {k} columns")
    if len(set(names)) != len(names):
        raise ConfigError(f"{what}: duplicate names {names}")
    return names


def records(x: Any, u: Any = None, dt: float = 1.0, *, state_names: Sequence[str] | None = None,
            input_names: Sequence[str] | None = None) -> list[Segment]:
    """Arrays -> one :class:`~mavsid.data.Segment` per record (the unit rows never cross).

    Parameters
    ----------
    x : array_like (n,) or (n, nx), or a list of them
        Measured states, one row per sample. Several records: a list of numpy arrays.
    u : array_like (n,) or (n, nu), or a list of them (as many as ``x``), optional
    dt : float
        Sample time (s).
    state_names, input_names : sequence of str, optional
        Default ``x`` (``x1, x2, …``) and ``u`` (``u1, u2, …``).

    Examples
    --------
    >>> import numpy as np
    >>> segs = records([np.array([0.0, 1.0, 2.0]), np.array([5.0, 6.0])],
    ...                [np.ones(3), np.zeros(2)], dt=0.1)
    >>> [len(s) for s in segs], segs[0].state_names, segs[1].input_names
    ([3, 2], ('x',), ('u',))
    """
    if not dt > 0:
        raise ConfigError(f"dt must be > 0 s, got {dt}")
    xs = as_records(x, "x")
    us = [np.empty((len(a), 0)) for a in xs] if u is None else as_records(u, "u")
    if len(us) != len(xs):
        raise ConfigError(f"x has {len(xs)} records, u has {len(us)}")
    for i, (a, b) in enumerate(zip(xs, us, strict=True)):
        if len(a) != len(b):
            raise ConfigError(f"record {i}: x has {len(a)} samples, u has {len(b)}")
    sn = column_names(state_names, xs[0].shape[1], "x", "state_names")
    inn = column_names(input_names, us[0].shape[1], "u", "input_names")
    clash = set(sn) & set(inn)
    if clash:
        raise ConfigError(f"names used for both a state and an input: {sorted(clash)}")
    out = []
    for i, (a, b) in enumerate(zip(xs, us, strict=True)):
        if a.shape[1] != len(sn) or b.shape[1] != len(inn):
            raise ConfigError(f"record {i}: {a.shape[1]} state and {b.shape[1]} input columns, "
                              f"record 0 has {len(sn)} and {len(inn)}")
        out.append(Segment(np.arange(len(a)) * float(dt), a, b, sn, inn, float(dt), "all",
                           "array", meta={"record": i}))
    return out


# --------------------------------------------------------------------------- the core
