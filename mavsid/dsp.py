"""Signal-processing primitives on numpy: linear filtering, Butterworth low-pass design,
Welch spectra; and the matrix exponential and logarithm of a model's discretisation, by
``scipy.linalg`` (imported when first asked for).

The filters and spectra give the numbers of their scipy namesakes to rounding
(tests/test_dsp.py compares them); none has that function's full set of options, only those
mavsid uses.

- :func:`lfilter`: the difference equation ``Σ a_k y[n-k] = Σ b_k x[n-k]``: the numerator's
  sum by numpy, the recursion compiled (``mavsid._filter``; where the package was built
  without a C compiler, or for complex numbers, ``scipy.signal.lfilter``), with
  ``scipy.signal.lfilter``'s initial conditions ``zi`` (its transposed direct form II:
  ``zi`` adds to the right-hand side of the first samples).
- :func:`butter_lowpass` and :func:`lfilter_zi`: a digital Butterworth low-pass by the
  bilinear transform of the prewarped analog prototype, and its steady-state state;
  :class:`Lowpass2p`, the autopilots' streaming second-order one (gyro, rate derivative).
- :func:`segment_ffts`, :func:`density`, :func:`welch` and :func:`csd`: Welch's averaged,
  periodic-Hann-windowed, density-scaled one-sided spectra; the transforms of a signal's
  windows taken once serve every spectrum that signal is part of.
- :func:`expm` and :func:`logm`: ``scipy.linalg.expm`` and the real ``scipy.linalg.logm`` of
  a real square matrix, refusing infinities and NaN; the logarithm of a 1×1 matrix in
  closed form (scipy's takes about a millisecond, and a fit asks for dozens).

Examples
--------
>>> import numpy as np
>>> y = lfilter([0.5], [1.0, -0.5], np.ones(4))
>>> [float(v) for v in y]
[0.5, 0.75, 0.875, 0.9375]
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from mavsid.data import demean
from mavsid.errors import ConfigError

try:
    from mavsid import _filter
except ImportError:  # pragma: no cover - built without a C compiler: scipy's banded solve
    _filter = None  # type: ignore[assignment]

__all__ = ["Lowpass2p", "butter_lowpass", "csd", "density", "expm", "hann", "lfilter",
           "lfilter_zi", "logm", "lowpass2p_coefficients", "segment_ffts", "tf2ss", "tukey",
           "welch"]


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


def tf2ss(num: Sequence[float] | np.ndarray, den: Sequence[float] | np.ndarray
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``scipy.signal.tf2ss(num, den)`` of a proper single-input single-output transfer
    function: the controllable canonical form ``(A, B, C, D)``."""
    nu = np.atleast_1d(np.asarray(num, float))
    de = np.atleast_1d(np.asarray(den, float))
    if nu.ndim != 1 or de.ndim != 1 or nu.size > de.size or de[0] == 0:
        raise ValueError("tf2ss: a proper 1-D transfer function is needed")
    nu, de = nu / de[0], de / de[0]
    nu = np.r_[np.zeros(de.size - nu.size), nu]
    k = de.size - 1
    d = np.array([[nu[0]]])
    if k == 0:  # a static gain: scipy's zero-filled 1x1 state
        return np.zeros((1, 1)), np.zeros((1, 1)), np.zeros((1, 1)), d
    a = np.zeros((k, k))
    a[0] = -de[1:]
    a[np.arange(1, k), np.arange(k - 1)] = 1.0
    b = np.zeros((k, 1))
    b[0, 0] = 1.0
    c = (nu[1:] - nu[0] * de[1:]).reshape(1, k)
    return a, b, c, d


@functools.lru_cache(maxsize=32)
def hann(n: int) -> np.ndarray:
    """The periodic Hann window of ``n`` samples (``scipy.signal.get_window("hann", n)``)."""
    w = 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(n) / n)
    w.flags.writeable = False
    return w


@functools.lru_cache(maxsize=32)
def tukey(n: int, alpha: float = 0.25) -> np.ndarray:
    """The periodic Tukey window of ``n`` samples, cosine tapers over ``alpha`` of it
    (``scipy.signal.get_window(("tukey", alpha), n)``, ``scipy.signal.spectrogram``'s
    default): the symmetric window of ``n + 1`` samples without its last."""
    m = n + 1
    k = np.arange(m, dtype=float)
    width = int(np.floor(alpha * (m - 1) / 2.0))
    w = np.ones(m)
    head, tail = k[: width + 1], k[m - width - 1 :]
    w[: width + 1] = 0.5 * (1 + np.cos(np.pi * (-1 + 2.0 * head / alpha / (m - 1))))
    w[m - width - 1 :] = 0.5 * (1 + np.cos(np.pi * (-2.0 / alpha + 1
                                                    + 2.0 * tail / alpha / (m - 1))))
    w = w[:n]
    w.flags.writeable = False
    return w


def segment_ffts(x: np.ndarray, nperseg: int, noverlap: int | None = None,
                 detrend: Callable[[np.ndarray], np.ndarray] = demean,
                 window: np.ndarray | None = None, starts: np.ndarray | None = None
                 ) -> np.ndarray:
    """The one-sided transforms ``(windows, nperseg // 2 + 1)`` of ``x``'s windows of
    ``nperseg`` samples every ``nperseg - noverlap`` (default half overlap; or at the
    indices ``starts`` of a 1-D ``x``), each detrended then multiplied by ``window``
    (default :func:`hann`), as Welch's method takes them."""
    x = np.asarray(x, dtype=float)
    nperseg = min(int(nperseg), x.shape[-1])
    if starts is not None:
        segs = x[np.asarray(starts)[:, None] + np.arange(nperseg)]
    else:
        step = nperseg - (nperseg // 2 if noverlap is None else int(noverlap))
        segs = np.lib.stride_tricks.sliding_window_view(x, nperseg)[::step]
    win = hann(nperseg) if window is None else window
    return np.fft.rfft(detrend(segs) * win, axis=-1)


def density(xa: np.ndarray, xb: np.ndarray, fs: float, nperseg: int,
            average: bool = True, window: np.ndarray | None = None) -> np.ndarray:
    """The cross-spectral density ``S_ab`` of two :func:`segment_ffts` (the same windows and
    ``window``), one-sided, averaged over the windows (``average=False``: per window,
    ``(windows, f)``)."""
    win = hann(nperseg) if window is None else window
    p = np.conj(xa) * xb / (fs * float(np.sum(win**2)))
    p[..., 1:-1 if nperseg % 2 == 0 else None] *= 2.0
    return p.mean(axis=0) if average else p


def welch(x: np.ndarray, fs: float, nperseg: int, noverlap: int | None = None,
          detrend: Callable[[np.ndarray], np.ndarray] = demean
          ) -> tuple[np.ndarray, np.ndarray]:
    """``scipy.signal.welch(x, fs, nperseg=..., noverlap=..., detrend=...)`` (1-D ``x``,
    Hann window, density scaling, mean of the windows): frequencies and power density."""
    n = min(int(nperseg), np.shape(x)[-1])
    s = segment_ffts(x, n, noverlap, detrend)
    return np.fft.rfftfreq(n, 1.0 / fs), density(s, s, fs, n).real


def csd(x: np.ndarray, y: np.ndarray, fs: float, nperseg: int, noverlap: int | None = None,
        detrend: Callable[[np.ndarray], np.ndarray] = demean
        ) -> tuple[np.ndarray, np.ndarray]:
    """``scipy.signal.csd(x, y, ...)`` as :func:`welch` computes a power density."""
    n = min(int(nperseg), np.shape(x)[-1])
    return np.fft.rfftfreq(n, 1.0 / fs), density(segment_ffts(x, n, noverlap, detrend),
                                                 segment_ffts(y, n, noverlap, detrend), fs, n)


def _real_square(a: np.ndarray, name: str) -> np.ndarray:
    """``a`` as a float array, refused unless square and finite (never a NaN model)."""
    a = np.asarray(a, float)
    if a.ndim != 2 or a.shape[0] != a.shape[1]:
        raise ValueError(f"{name}: a square matrix, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: the matrix holds infinities or NaN")
    return a


def expm(a: np.ndarray) -> np.ndarray:
    """``scipy.linalg.expm(a)`` of a real square matrix.

    Examples
    --------
    >>> [round(float(v), 12) for v in expm(np.array([[0.0, 1.0], [0.0, 0.0]])).ravel()]
    [1.0, 1.0, 0.0, 1.0]
    >>> round(float(expm(np.array([[1.0]]))[0, 0]), 12)
    2.718281828459
    """
    a = _real_square(a, "expm")
    from scipy import linalg

    return np.asarray(linalg.expm(a))


def logm(a: np.ndarray) -> np.ndarray:
    """The real part of ``scipy.linalg.logm(a)``, the principal matrix logarithm, of a real
    square matrix (real itself when no eigenvalue is negative or zero: the stable,
    non-oscillating discrete models mavsid takes to continuous time); a 1×1 matrix's in
    closed form.

    Examples
    --------
    >>> round(float(logm(np.array([[np.e]]))[0, 0]), 12)
    1.0
    >>> [round(float(v), 12) + 0.0 for v in logm(np.array([[0.5, 0.25], [0.0, 1.0]])).ravel()]
    [-0.69314718056, 0.34657359028, 0.0, 0.0]
    """
    a = _real_square(a, "logm")
    if a.shape == (1, 1) and a[0, 0] > 0:
        return np.log(a)
    from scipy import linalg

    return np.asarray(np.real(linalg.logm(a)))
