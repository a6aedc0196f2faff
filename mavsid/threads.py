"""One BLAS thread while mavsid computes.

mavsid's matrices are a few columns wide (a regression of a handful of features over
thousands of rows, a 17×200 by 200×165 frequency product): a BLAS library's threads only
wait on each other there. With OpenBLAS's default of one thread per core, that product took
23 ms instead of 0.16 ms on a 2-core machine, and `pipeline.fit` of the 104 MB SITL flight
2.5 s of CPU instead of 1.1 s. So the library's heavy entry points (:func:`mavsid.pipeline.
fit`, :func:`mavsid.pipeline.validate_logs`, :func:`mavsid.estimators.fit_axis`,
:func:`mavsid.estimators.identify`, :func:`mavsid.estimators.regress`) run with one BLAS
thread and give the caller's setting back when they return (:func:`one_blas_thread`; one
called from another limits nothing again);
the command line also sets the variables for the processes it starts (Dask workers). A count
the user set in one of :data:`BLAS_THREAD_VARS` is respected everywhere.

Examples
--------
>>> @one_blas_thread
... def work() -> int:
...     return 1
>>> work()
1
"""

from __future__ import annotations

import contextvars
import functools
import os
from collections.abc import Callable
from typing import Any, TypeVar

__all__ = ["BLAS_THREAD_VARS", "limit_process_blas", "one_blas_thread", "user_set"]

#: Variables that set the BLAS libraries' thread counts (OpenBLAS, OpenMP, MKL).
BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")

F = TypeVar("F", bound=Callable[..., Any])

#: Whether this context already runs inside :func:`one_blas_thread` (``pipeline.fit`` calls
#: ``fit_axis`` per axis: threadpoolctl, ~1.5 ms, is not asked again)
_LIMITED = contextvars.ContextVar("mavsid_one_blas_thread", default=False)


def user_set() -> bool:
    """Whether the user set a BLAS thread count (one of :data:`BLAS_THREAD_VARS`).

    Examples
    --------
    >>> isinstance(user_set(), bool)
    True
    """
    return any(os.environ.get(v) for v in BLAS_THREAD_VARS)


def one_blas_thread(func: F) -> F:
    """``func`` run with the BLAS libraries loaded by then limited to one thread, their
    counts restored when it returns or raises; as it is when the user set a count
    (:func:`user_set`), or inside another such call. Costs ~1.5 ms a call (threadpoolctl
    finds the libraries)."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        if _LIMITED.get() or user_set():
            return func(*args, **kwargs)
        from threadpoolctl import threadpool_limits

        token = _LIMITED.set(True)
        try:
            with threadpool_limits(1, user_api="blas"):
                return func(*args, **kwargs)
        finally:
            _LIMITED.reset(token)

    return wrapper  # type: ignore[return-value]


def limit_process_blas() -> None:
    """One BLAS thread for this process and the processes it starts (Dask workers), unless
    the user set a count (:func:`user_set`; on a busy 2-core machine a 33x200 by
    200x165 product took 8 ms with them, 0.7 ms without; `fit` of the 104 MB SITL flight
    1.1 s of CPU against 0.75 s)."""
    if user_set():
        return
    for v in BLAS_THREAD_VARS:
        os.environ[v] = "1"  # (children read it before they load numpy)
    from threadpoolctl import threadpool_limits

    threadpool_limits(1, user_api="blas")
