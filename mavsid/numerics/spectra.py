"""Welch spectra on numpy: averaged, periodic-Hann-windowed, density-scaled one-sided
spectra whose windows' transforms, taken once per signal, serve every spectrum that signal is
part of; the Hann and Tukey windows.

Each function gives the numbers of its ``scipy.signal`` namesake to rounding
(tests/test_dsp.py compares them), with only the options mavsid uses.

Examples
--------
>>> import numpy as np
>>> f, p = welch(np.sin(2 * np.pi * 10 * np.arange(1000) / 100), 100.0, 200)
>>> float(f[np.argmax(p)])
10.0
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np

from mavsid.data import demean

__all__ = ["csd", "density", "hann", "segment_ffts", "tukey", "welch"]


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
