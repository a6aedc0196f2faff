"""Linear filters on numpy: the difference equation with its recursion compiled, the
Butterworth low-pass design and the autopilots' streaming second-order low-pass.

Each function gives the numbers of its scipy namesake to rounding (tests/test_dsp.py compares
them); none has that function's full set of options, only those mavsid uses.

- :func:`lfilter`: the difference equation ``Σ a_k y[n-k] = Σ b_k x[n-k]``: the numerator's
  sum by numpy, the recursion compiled (``mavsid._filter``; where the package was built
  without a C compiler, or for complex numbers, ``scipy.signal.lfilter``), with
  ``scipy.signal.lfilter``'s initial conditions ``zi`` (its transposed direct form II:
  ``zi`` adds to the right-hand side of the first samples).
- :func:`butter_lowpass` and :func:`lfilter_zi`: a digital Butterworth low-pass by the
  bilinear transform of the prewarped analog prototype, and its steady-state state;
  :class:`Lowpass2p`, the autopilots' streaming second-order one (gyro, rate derivative).

Examples
--------
>>> import numpy as np
>>> y = lfilter([0.5], [1.0, -0.5], np.ones(4))
>>> [float(v) for v in y]
[0.5, 0.75, 0.875, 0.9375]
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any

import numpy as np

from mavsid.errors import ConfigError

try:
    from mavsid import _filter
except ImportError:  # pragma: no cover - built without a C compiler: scipy.signal.lfilter
    _filter = None  # type: ignore[assignment]

__all__ = ["Lowpass2p", "butter_lowpass", "lfilter", "lfilter_zi", "lowpass2p_coefficients"]


def _recurse(a: np.ndarray, rhs: np.ndarray) -> None:
    """The recursion ``y[k] = rhs[k] - Σ_{j≥1} a[j] y[k-j]`` (``a[0] = 1``) down each column of
    the Fortran-ordered ``rhs`` (n, m), in place: compiled for real numbers, else
    ``scipy.signal.lfilter([1], a, rhs)``."""
    if _filter is not None and rhs.dtype == np.float64 and rhs.flags.f_contiguous:
        _filter.recurse(np.ascontiguousarray(a, np.float64), rhs.T.reshape(-1), rhs.shape[0])
        return
    from scipy import signal  # (a build without a C compiler, or complex numbers)

    rhs[...] = signal.lfilter([1.0], a, rhs, axis=0)


def lfilter(b: Sequence[complex] | np.ndarray, a: Sequence[complex] | np.ndarray,
            x: np.ndarray, axis: int = -1,
            zi: Sequence[complex] | np.ndarray | None = None) -> np.ndarray:
    """``scipy.signal.lfilter(b, a, x, axis, zi)`` (with ``zi``: its first return, the
    output; the final state is not formed).

    ``zi`` has ``max(len(a), len(b)) - 1`` entries along ``axis`` (the other axes as ``x``'s
    or broadcastable to them)."""
    b_ = np.atleast_1d(np.asarray(b))
    a_ = np.atleast_1d(np.asarray(a))
    if a_.ndim != 1 or b_.ndim != 1 or not a_.size or a_[0] == 0:
        raise ValueError("lfilter: a and b must be 1-D with a[0] != 0")
    b_, a_ = b_ / a_[0], a_ / a_[0]
    x = np.asarray(x)
    dtype = np.result_type(b_, a_, x, 1.0, *(() if zi is None else (np.asarray(zi),)))
    xm = np.moveaxis(x, axis, 0)
    shape, n = xm.shape, xm.shape[0]
    cols = xm.reshape(n, -1)
    rhs = np.empty(cols.shape, dtype=dtype, order="F")
    np.multiply(b_[0], cols, out=rhs)
    for k in range(1, min(b_.size, n)):
        rhs[k:] += b_[k] * cols[:-k]
    if zi is not None:
        order = max(a_.size, b_.size) - 1
        z = np.moveaxis(np.asarray(zi, dtype=dtype), axis if np.ndim(zi) == x.ndim else 0, 0)
        z = np.broadcast_to(z.reshape(z.shape[0], -1) if z.ndim > 1 else z[:, None],
                            (order, cols.shape[1]))
        m = min(order, n)
        rhs[:m] += z[:m]
    p = a_.size - 1
    if p and n:
        _recurse(a_, rhs)
    return np.moveaxis(rhs.reshape(shape), 0, axis)


@functools.lru_cache(maxsize=64)
def butter_lowpass(order: int, cutoff_hz: float, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """``scipy.signal.butter(order, cutoff_hz, fs=fs)``: the digital Butterworth low-pass
    ``(b, a)`` (read-only arrays): the analog prototype's poles ``-exp(iπm/2N)``,
    ``m = -N+1, -N+3, ..., N-1``, scaled to the prewarped cut-off and mapped by the bilinear
    transform; the ``N`` zeros at ``z = -1``."""
    if order < 1 or not 0 < cutoff_hz < fs / 2:
        raise ValueError(f"butter_lowpass: order {order}, cut-off {cutoff_hz} Hz at {fs} Hz")
    warped = 4.0 * np.tan(np.pi * (2.0 * cutoff_hz / fs) / 2.0)  # the bilinear's fs = 2
    m = np.arange(-order + 1, order, 2)
    poles = -np.exp(1j * np.pi * m / (2 * order)) * warped
    gain = warped**order
    zd = (4.0 + poles) / (4.0 - poles)
    kd = gain * np.real(1.0 / np.prod(4.0 - poles))
    b = kd * np.poly(-np.ones(order))
    a = np.real(np.poly(zd))
    b, a = np.asarray(b, float), np.asarray(a, float)
    b.flags.writeable = a.flags.writeable = False
    return b, a


def lowpass2p_coefficients(cutoff_hz: float, sample_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Biquad ``(b, a)`` of a second-order Butterworth low pass (bilinear, pre-warped).

    This is the filter ArduPilot applies to the gyro (``INS_GYRO_FILTER``) and PX4 to the
    rate derivative (``IMU_DGYRO_CUTOFF``); raises :class:`~mavsid.errors.ConfigError` for a
    cut-off outside ``(0, sample_hz / 2)``.

    Examples
    --------
    >>> b, a = lowpass2p_coefficients(20.0, 400.0)
    >>> round(float(b.sum() / a.sum()), 6)   # unit DC gain
    1.0
    """
    if not 0 < cutoff_hz < sample_hz / 2:
        raise ConfigError(f"gyro filter cutoff {cutoff_hz} Hz must lie in (0, {sample_hz / 2})")
    b, a = butter_lowpass(2, cutoff_hz, sample_hz)  # bilinear transform, pre-warped
    return b.copy(), a.copy()


class Lowpass2p:
    """Streaming biquad (direct form II) over vectors, started at steady state on the first
    sample as ArduPilot's ``LowPassFilter2p`` is (a cut-off of 0: no filter).

    Examples
    --------
    >>> f = Lowpass2p(20.0, 400.0, 1)
    >>> [round(float(f(np.array([v]))[0]), 4) for v in (1.0, 1.0, 0.0, 0.0)]
    [1.0, 1.0, 0.9799, 0.9084]
    """

    def __init__(self, cutoff_hz: float, sample_hz: float, width: int) -> None:
        self.enabled = cutoff_hz > 0
        b, a = (lowpass2p_coefficients(cutoff_hz, sample_hz) if self.enabled
                else (np.array([1.0, 0, 0]), np.array([1.0, 0, 0])))
        self._k = tuple(float(v) for v in (*b, a[1], a[2]))  # b0, b1, b2, a1, a2
        self.d1: Any = np.zeros(width)
        self.d2: Any = np.zeros(width)
        self.started = False

    def __call__(self, x: np.ndarray) -> np.ndarray:
        if not self.enabled:
            return np.array(x, dtype=float)
        return np.asarray(self.advance(x), dtype=float)

    def advance(self, x: Any) -> Any:
        """One step of a vector or of a single float (a float out: a controller replayed
        sample by sample, ~10× faster than through one-element arrays)."""
        if not self.enabled:
            return x
        b0, b1, b2, a1, a2 = self._k
        if not self.started:
            # delay elements at the steady state for a constant input x
            self.d1 = self.d2 = x / (1.0 + a1 + a2)
            self.started = True
        d0 = x - a1 * self.d1 - a2 * self.d2
        y = b0 * d0 + b1 * self.d1 + b2 * self.d2
        self.d2, self.d1 = self.d1, d0
        return y


def lfilter_zi(b: np.ndarray, a: np.ndarray) -> np.ndarray:
    """``scipy.signal.lfilter_zi(b, a)``: the state of :func:`lfilter` at steady state for a
    unit step (scale it by the first sample to start a signal in steady state)."""
    b = np.asarray(b, float) / a[0]
    a = np.asarray(a, float) / a[0]
    n = max(a.size, b.size)
    a = np.r_[a, np.zeros(n - a.size)]
    b = np.r_[b, np.zeros(n - b.size)]
    if n == 1:
        return np.zeros(0)
    comp = np.zeros((n - 1, n - 1))
    comp[0] = -a[1:]
    comp[np.arange(1, n - 1), np.arange(n - 2)] = 1.0
    return np.asarray(np.linalg.solve(np.eye(n - 1) - comp.T, b[1:] - a[1:] * b[0]))
