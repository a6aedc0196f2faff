"""Frequency responses from data, with coherence, and transfer functions fitted to them.

:func:`frf` estimates ``H(f) = S_uy / S_uu`` (H1) with Welch averaging over overlapped Hann
windows of several lengths, pooled over segments, and combines the lengths into one
composite response (as CIFER does): at each frequency every window length's estimate is
weighted by the inverse square of its normalised random error
``ε = sqrt(1 - γ²) / (|γ| sqrt(2 n_d))`` (Bendat & Piersol), ``n_d`` the effective number of
averages at that frequency (a chirp excites each frequency in a few windows only: the
windows' participation ratio of input power), so that long windows rule at low frequency
and short, many-times-averaged ones above. Only frequencies
whose coherence reaches ``min_coherence`` (default 0.6) count as identified.

:func:`fit_tf` fits ``K e^{-τ s} / (s + a)`` (gain, pole, equivalent delay bounded to a
physical range) to the coherent band, weighted by coherence.

Examples
--------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> u = rng.standard_normal(20000)
>>> y = np.convolve(u, [0.0, 0.5, 0.25])[:20000]   # a known FIR, one-sample delay
>>> r = frf([u], [y], dt=0.01, windows_s=(2.0, 5.0))
>>> k = np.argmin(np.abs(r.freq_hz - 5.0))
>>> h = 0.5 * np.exp(-2j * np.pi * 5 * 0.01) + 0.25 * np.exp(-4j * np.pi * 5 * 0.01)
>>> bool(abs(r.response[k] - h) < 0.02 and r.coherence[k] > 0.99)
True
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from mavsid import dsp
from mavsid.errors import NoExcitationError

__all__ = ["FRF", "MIN_COHERENCE", "TFFit", "fit_tf", "frf"]

#: coherence (γ²) below which a frequency is not identified
MIN_COHERENCE = 0.6
#: periods of a frequency a window must hold for its estimate to count there
CYCLES = 4.0
#: Welch window lengths (s) combined by default
WINDOWS_S = (1.0, 2.0, 4.0, 8.0)


@dataclass(frozen=True)
class FRF:
    """A frequency response estimated from data.

    Attributes
    ----------
    freq_hz : (m,) frequencies (Hz), log-spaced.
    response : (m,) complex ``H(f)``.
    coherence : (m,) γ² of the composite.
    error : (m,) normalised random error of ``|H|`` (fraction).
    windows_s : window lengths combined.
    input, output : names of the signals.
    referenced : estimated against an injected reference (``S_ry / S_ru``: unbiased by
        the feedback on closed-loop data), not as H1.
    """

    freq_hz: np.ndarray
    response: np.ndarray
    coherence: np.ndarray
    error: np.ndarray
    windows_s: tuple[float, ...]
    input: str = "u"
    output: str = "y"
    referenced: bool = False

    @property
    def coherent(self) -> np.ndarray:
        """Mask of the frequencies whose coherence reaches :data:`MIN_COHERENCE`."""
        return self.coherence >= MIN_COHERENCE

    @property
    def magnitude_db(self) -> np.ndarray:
        """``20 log10 |H|``."""
        with np.errstate(divide="ignore"):
            return 20 * np.log10(np.abs(self.response))

    @property
    def phase_deg(self) -> np.ndarray:
        """Unwrapped phase (degrees)."""
        return np.degrees(np.unwrap(np.angle(self.response)))

    def band(self) -> tuple[float, float] | None:
        """Lowest and highest coherent frequency (Hz), None when none is."""
        f = self.freq_hz[self.coherent]
        return (float(f.min()), float(f.max())) if f.size else None

    def to_dict(self) -> dict[str, object]:
        """JSON form."""
        return {
            "input": self.input, "output": self.output,
            "frequency_hz": self.freq_hz.tolist(),
            "magnitude_db": [None if not np.isfinite(v) else float(v) for v in self.magnitude_db],
            "phase_deg": self.phase_deg.tolist(),
            "coherence": self.coherence.tolist(),
            "error": self.error.tolist(),
            "windows_s": list(self.windows_s),
            "band_hz": self.band(),
        }


def _starts(n: int, nper: int) -> np.ndarray:
    """Start indices of Welch windows of ``nper`` samples spanning all ``n``: evenly spaced,
    at least half-overlapped, the last ending on the last sample. (scipy's fixed half-step
    drops the tail that does not fill a whole step: up to half a window, on a chirp the
    end of its sweep, whose frequencies were then seen only under the taper's edge.)

    Examples
    --------
    >>> _starts(7999, 3200).tolist()
    [0, 1600, 3199, 4799]
    >>> _starts(8000, 3200).tolist()
    [0, 1600, 3200, 4800]
    """
    k = 1 + -(-(n - nper) // (nper // 2))
    return np.rint(np.linspace(0, n - nper, k)).astype(int)


def _welch(us: Sequence[np.ndarray], ys: Sequence[np.ndarray], rs: Sequence[np.ndarray] | None,
           nper: int, fs: float
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """Pooled Welch estimate of one window length: frequencies, ``H``, ``γ²`` and the
    effective number of averages per frequency (windows weighted by their input power).

    Hann windows of ``nper`` samples, demeaned, at least half-overlapped and spanning each
    segment to its last sample (:func:`_starts`). Without a reference ``H = S_uy / S_uu``
    (H1), ``γ² = |S_uy|² / (S_uu S_yy)``. With a reference ``r`` (an injected signal,
    uncorrelated with the noise the feedback puts in ``u``) ``H = S_ry / S_ru`` and
    ``γ² = γ²_ru · γ²_ry``: closed-loop data give the plant, not the inverse of the
    controller."""
    acc: dict[str, Any] = {}
    n_avg = 0
    refs = rs if rs is not None else us
    for u, y, r in zip(us, ys, refs, strict=True):
        ok = np.isfinite(u) & np.isfinite(y) & np.isfinite(r)
        u, y, r = u[ok], y[ok], r[ok]
        if len(u) < nper:
            continue
        starts = _starts(len(u), nper)
        fu, fy = (dsp.segment_ffts(v, nper, starts=starts) for v in (u, y))
        fr = fu if rs is None else dsp.segment_ffts(r, nper, starts=starts)
        pr = np.abs(fr) ** 2
        # per-window input power: a chirp excites a frequency in few windows only
        sums = {"rr": pr, "uu": pr if rs is None else np.abs(fu) ** 2, "yy": np.abs(fy) ** 2,
                "ru": np.conj(fr) * fu, "ry": np.conj(fr) * fy, "p2": pr**2}
        for key, val in sums.items():
            acc[key] = acc.get(key, 0.0) + val.sum(axis=0)
        n_avg += len(starts)
    if n_avg == 0:
        return None
    freq = np.fft.rfftfreq(nper, 1.0 / fs)
    with np.errstate(divide="ignore", invalid="ignore"):
        # effective number of averages at each frequency (participation ratio of the windows)
        n_eff = np.where(acc["p2"] > 0, acc["rr"] ** 2 / acc["p2"], 1.0)
        h = acc["ry"] / acc["ru"]
        coh_ry = np.abs(acc["ry"]) ** 2 / (acc["rr"] * acc["yy"])
        coh_ru = np.abs(acc["ru"]) ** 2 / (acc["rr"] * acc["uu"])
    coh = np.clip(coh_ry if rs is None else coh_ry * coh_ru, 0.0, 1.0)
    return freq, np.asarray(h), np.nan_to_num(coh), np.clip(np.nan_to_num(n_eff, nan=1.0), 1.0,
                                                              None)


def frf(
    u: Sequence[np.ndarray],
    y: Sequence[np.ndarray],
    dt: float,
    *,
    reference: Sequence[np.ndarray] | None = None,
    windows_s: Sequence[float] = WINDOWS_S,
    f_min_hz: float | None = None,
    f_max_hz: float | None = None,
    n_freq: int = 200,
    names: tuple[str, str] = ("u", "y"),
) -> FRF:
    """Composite H1 frequency response of ``y`` to ``u`` over several segments.

    Parameters
    ----------
    u, y : sequence of numpy.ndarray
        Input and output per segment (same sample step ``dt``).
    reference : sequence of numpy.ndarray, optional
        An injected signal per segment (SYSTEMID's waveform): ``H = S_ry / S_ru``, unbiased
        by the feedback on closed-loop data.
    windows_s : sequence of float
        Window lengths (s); those longer than the longest segment are skipped.
    f_min_hz, f_max_hz : float, optional
        Frequency grid (default: from 4 periods in the longest window to 0.4 × the rate).
    n_freq : int
        Points of the log-spaced grid.

    Raises
    ------
    NoExcitationError
        No segment is as long as the shortest window.
    """
    fs = 1.0 / dt
    longest = max((len(s) for s in u), default=0) * dt
    wins = [w for w in sorted(windows_s) if w <= longest] or ([longest] if longest > 0 else [])
    estimates = []
    for w in wins:
        got = _welch(u, y, reference, max(8, round(w / dt)), fs)
        if got is not None:
            estimates.append((w, *got))
    if not estimates:
        raise NoExcitationError("segments too short for a frequency response")
    lo = f_min_hz or CYCLES / max(w for w, *_ in estimates)
    hi = f_max_hz or 0.4 * fs
    grid = np.geomspace(lo, hi, n_freq)
    num = np.zeros(n_freq, complex)
    wsum = np.zeros(n_freq)
    wmax = np.zeros(n_freq)
    cnum = np.zeros(n_freq)
    for win, freq, h, coh, n_avg in estimates:
        with np.errstate(divide="ignore", invalid="ignore"):
            err = np.sqrt(1 - coh) / (np.sqrt(coh) * np.sqrt(2 * n_avg))
        ok = np.isfinite(h) & np.isfinite(err) & (freq > 0)
        if ok.sum() < 2:
            continue
        hi_i = np.interp(grid, freq[ok], h[ok].real) + 1j * np.interp(grid, freq[ok], h[ok].imag)
        ci = np.interp(grid, freq[ok], coh[ok])
        ei = np.interp(grid, freq[ok], err[ok])
        # a window resolves a frequency it holds several periods of (leakage otherwise)
        inside = (grid >= max(freq[ok][0], CYCLES / win)) & (grid <= freq[ok][-1])
        w8 = np.where(inside, 1.0 / np.maximum(ei, 1e-6) ** 2, 0.0)
        num += w8 * hi_i
        cnum += w8 * ci
        wsum += w8
        wmax = np.maximum(wmax, w8)
    with np.errstate(divide="ignore", invalid="ignore"):
        response = num / wsum
        coherence = np.where(wsum > 0, cnum / wsum, 0.0)
        # the window lengths see the same data: their errors are correlated, so the
        # composite is credited with the best single window's error, not their combination
        error = 1.0 / np.sqrt(wmax)
    return FRF(grid, response, np.nan_to_num(coherence), error,
               tuple(w for w, *_ in estimates), *names, referenced=reference is not None)


@dataclass(frozen=True)
class TFFit:
    """``K e^{-τ s} / (s + a)`` fitted to an FRF's coherent band.

    Attributes
    ----------
    gain : K (output unit per input unit per s).
    pole : a (1/s; the rate damping).
    delay_s : τ, bounded to ``[0, max_delay_s]``.
    cost : the weighted mean squared complex error relative to ``|H|``.
    band_hz : (low, high) band used.
    """

    gain: float
    pole: float
    delay_s: float
    cost: float
    band_hz: tuple[float, float]

    def response(self, freq_hz: np.ndarray) -> np.ndarray:
        """``H(j 2π f)`` of the fitted transfer function."""
        s = 2j * np.pi * np.asarray(freq_hz)
        return self.gain * np.exp(-self.delay_s * s) / (s + self.pole)

    def to_dict(self) -> dict[str, object]:
        """JSON form."""
        return {"gain": self.gain, "pole": self.pole, "delay_s": self.delay_s,
                "cost": self.cost, "band_hz": list(self.band_hz)}


def fit_tf(r: FRF, max_delay_s: float = 0.1) -> TFFit:
    """Fit ``K e^{-τ s}/(s + a)`` to the coherent band of ``r``, weighted by coherence.

    Raises
    ------
    NoExcitationError
        Fewer than 4 coherent frequencies.
    """
    from mavsid.estimators.output_error import box_least_squares

    m = r.coherent & np.isfinite(r.response)
    if m.sum() < 4:
        raise NoExcitationError(f"{r.input} -> {r.output}: fewer than 4 coherent frequencies")
    f, h, w = r.freq_hz[m], r.response[m], r.coherence[m]
    scale = np.abs(h)

    def resid(p: np.ndarray) -> np.ndarray:
        s = 2j * np.pi * f
        e = (p[0] * np.exp(-p[2] * s) / (s + p[1]) - h) / scale * np.sqrt(w)
        return np.concatenate([e.real, e.imag])

    w0 = 2 * np.pi * f
    k0 = float(np.median(np.abs(h) * w0))
    best = None
    for tau0 in (0.0, 0.01, 0.03):
        sol = box_least_squares(resid, np.array([k0, 1.0, tau0]),
                                np.array([0.0, -50.0, 0.0]),
                                np.array([np.inf, 500.0, max_delay_s]), np.ones(3),
                                max_nfev=300)  # (scipy's default for three)
        if best is None or sol.cost < best.cost:
            best = sol
    assert best is not None
    cost = float(2 * best.cost / m.sum())
    return TFFit(float(best.x[0]), float(best.x[1]), float(best.x[2]), cost,
                 (float(f.min()), float(f.max())))
