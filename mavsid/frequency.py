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

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from mavsid.autopilot.ardupilot import sid_axis
from mavsid.axes import RATE_OF
from mavsid.errors import MavsidError, NoExcitationError
from mavsid.loop.plant import plant_from_model, plant_response
from mavsid.loop.twin import lagged, twin_signals
from mavsid.numerics.spectra import segment_ffts

if TYPE_CHECKING:
    from mavsid.data import FlightData
    from mavsid.estimators.model import Model
    from mavsid.loop.twin import TwinSignals
    from mavsid.pipeline_results import AxisFit

__all__ = ["FRF", "FRF_STRUCTURE_FLOOR", "FRF_STRUCTURE_MIN_POINTS", "FRF_STRUCTURE_SHIFT",
           "MIN_COHERENCE", "FrfStructure", "TFFit", "fit_tf", "frf", "measured_responses",
           "sysid_spans"]

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
    coherence_parts : for a referenced response, the composite γ² of the input and of the
        output with the reference (``coherence`` is their product); None otherwise.
    """

    freq_hz: np.ndarray
    response: np.ndarray
    coherence: np.ndarray
    error: np.ndarray
    windows_s: tuple[float, ...]
    input: str = "u"
    output: str = "y"
    referenced: bool = False
    coherence_parts: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def trust(self) -> np.ndarray:
        """The coherence a frequency is trusted by: for a referenced response the lower of
        the input's and the output's with the reference (each must hold: the reference must
        reach the plant's input and its output), otherwise ``coherence``."""
        if self.coherence_parts is None:
            return self.coherence
        return np.minimum(*self.coherence_parts)

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
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                      np.ndarray] | None:
    """Pooled Welch estimate of one window length: frequencies, ``H``, ``γ²`` and the
    effective number of averages per frequency (windows weighted by their input power);
    then ``γ²_ru`` and ``γ²_ry`` (both ``γ²`` without a reference).

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
        fu, fy = (segment_ffts(v, nper, starts=starts) for v in (u, y))
        fr = fu if rs is None else segment_ffts(r, nper, starts=starts)
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
    if rs is None:
        coh_ru = coh_ry = coh
    parts = (np.nan_to_num(np.clip(c, 0.0, 1.0)) for c in (coh_ru, coh_ry))
    return (freq, np.asarray(h), np.nan_to_num(coh),
            np.clip(np.nan_to_num(n_eff, nan=1.0), 1.0, None), *parts)


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
    pnum = np.zeros((2, n_freq))
    for win, freq, h, coh, n_avg, c_ru, c_ry in estimates:
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
        pnum += w8 * np.array([np.interp(grid, freq[ok], c[ok]) for c in (c_ru, c_ry)])
        wsum += w8
        wmax = np.maximum(wmax, w8)
    with np.errstate(divide="ignore", invalid="ignore"):
        response = num / wsum
        coherence = np.where(wsum > 0, cnum / wsum, 0.0)
        parts = np.nan_to_num(np.where(wsum > 0, pnum / wsum, 0.0))
        # the window lengths see the same data: their errors are correlated, so the
        # composite is credited with the best single window's error, not their combination
        error = 1.0 / np.sqrt(wmax)
    return FRF(grid, response, np.nan_to_num(coherence), error,
               tuple(w for w, *_ in estimates), *names, referenced=reference is not None,
               coherence_parts=(parts[0], parts[1]) if reference is not None else None)


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
    from scipy import optimize

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
        sol = optimize.least_squares(resid, np.array([k0, 1.0, tau0]), method="trf",
                                     bounds=([0.0, -50.0, 0.0], [np.inf, 500.0, max_delay_s]))
        if best is None or sol.cost < best.cost:
            best = sol
    assert best is not None
    cost = float(2 * best.cost / m.sum())
    return TFFit(float(best.x[0]), float(best.x[1]), float(best.x[2]), cost,
                 (float(f.min()), float(f.max())))


# --------------------------------------------------------------------------- from flights
# The frequency responses of a fitted axis measured on its flights' SYSTEMID runs, and the
# model-structure choice an injection's response gives the estimators.


def sysid_spans(flight: FlightData, axis: str) -> list[tuple[int, int, int]]:
    """Grid index ranges ``[i0, i1)`` of the flight's SYSTEMID runs on ``axis`` (cut at the
    first gap), with their ``SID_AXIS``: 1-3 angle, 4-6 recovery, 7-9 rate, 10-12 mixer."""
    out = []
    t = flight.time_s
    for run in flight.sysid_runs:
        sid = run.sid_axis
        if sid_axis(sid)[0] != axis:
            continue
        i0 = int(np.searchsorted(t, run.start_s))
        i1 = int(np.searchsorted(t, run.stop_s, side="right"))
        for a, b in flight.blocks:
            if a <= i0 < b:
                i1 = min(i1, int(b))
                break
        if i1 - i0 > 8:
            out.append((i0, i1, sid))
    return out


def measured_responses(fit: AxisFit | str, flights: Sequence[FlightData],
                       signals: Sequence[TwinSignals] | None = None, lag: int = 0,
                       which: Sequence[str] = ("plant", "loop", "closed_loop")
                       ) -> dict[str, FRF]:
    """Frequency responses measured on the axis's SYSTEMID runs (whole runs, not the
    train/validation blocks: a chirp's low frequencies need the long windows):

    - ``"plant"``: controller output (mixer input) -> rate; with the injection as reference
      on mixer runs (:func:`mavsid.frequency.frf`), H1 otherwise;
    - ``"loop"``: the broken loop ``L = −c/u`` (``c`` the controller's part of the mixer
      input ``u``) where the injection is at the mixer (``SID_AXIS`` 10-12);
    - ``"closed_loop"``: rate target -> rate where the injection is in the target
      (``SID_AXIS`` 1-9; with the injection as reference on rate axes 7-9).

    Each is a :class:`mavsid.frequency.FRF` on the runs' chirp band; absent without runs.
    ``fit`` is the axis's :class:`mavsid.pipeline.AxisFit` or the axis's name; ``which``
    the responses wanted.
    """
    axis = fit if isinstance(fit, str) else fit.axis
    rate, u_name = RATE_OF[axis], f"u_{axis}"
    sigs = list(signals) if signals is not None else [twin_signals(fd) for fd in flights]
    mixer: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    other: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]] = []
    bands, dt = [], 0.0
    for fd, sg in zip(flights, sigs, strict=True):
        if rate not in fd.state_names or u_name not in fd.input_names:
            continue
        for i0, i1, sid in sysid_spans(fd, axis):
            run = next(r for r in fd.sysid_runs if r.sid_axis == sid)
            lo, hi = run.f_start_hz, run.f_stop_hz
            if lo and hi:
                bands.append((float(lo), float(hi)))
            dt = fd.dt
            y = fd.states[i0:i1, fd.state_names.index(rate)]
            u = fd.inputs[i0:i1, fd.input_names.index(u_name)]
            if sid >= 10 and axis in sg.injection:
                mixer.append((u, y, lagged(sg.injection[axis], lag)[i0:i1]))
            elif axis in sg.target and np.all(np.isfinite(sg.target[axis][i0:i1])):
                ref = sg.rate_injection.get(axis)
                other.append((u, y, sg.target[axis][i0:i1],
                              ref[i0:i1] if ref is not None and 7 <= sid <= 9 else None))
    out: dict[str, Any] = {}
    if not dt:
        return out
    grid: dict[str, Any] = {}
    if bands:  # only the injected band: a noise-free log is coherent beyond it too
        grid = {"f_min_hz": min(b[0] for b in bands),
                "f_max_hz": min(max(b[1] for b in bands), 0.4 / dt)}
    refs = [r[3] for r in other]
    use_ref = bool(other) and all(r is not None for r in refs)
    try:
        if "plant" not in which:
            pass
        elif mixer:
            out["plant"] = frf([r[0] for r in mixer], [r[1] for r in mixer], dt,
                               reference=[r[2] for r in mixer], names=(u_name, rate), **grid)
        elif other:
            out["plant"] = frf([r[0] for r in other], [r[1] for r in other], dt,
                               reference=refs if use_ref else None,  # type: ignore[arg-type]
                               names=(u_name, rate), **grid)
    except MavsidError:
        pass
    if mixer and "loop" in which:
        try:
            out["loop"] = frf([r[0] for r in mixer], [-(r[0] - r[2]) for r in mixer], dt,
                              reference=[r[2] for r in mixer], names=(u_name, f"-c_{axis}"),
                              **grid)
        except MavsidError:
            pass
    if other and "closed_loop" in which:
        try:
            out["closed_loop"] = frf([r[2] for r in other], [r[1] for r in other], dt,
                                     reference=refs if use_ref else None,  # type: ignore[arg-type]
                                     names=(f"target_{axis}", rate), **grid)
        except MavsidError:
            pass
    return out


#: Least coherent frequencies an injection's FRF needs to choose the model structure.
FRF_STRUCTURE_MIN_POINTS = 20
#: Delay shifts (samples, each way) :class:`FrfStructure` tries around each candidate.
FRF_STRUCTURE_SHIFT = 2.0
#: FRF error floor (fraction): the composite's bias on a noise-free chirp (leakage where
#: the sweep is fast: 1 % median, 5 % in gain and 4 deg in phase at worst below 12 Hz)
FRF_STRUCTURE_FLOOR = 0.03


class FrfStructure:
    """A ``choose_structure`` for :func:`mavsid.estimators.fit_axis`: the candidate lag and
    delay whose first-order model best matches an FRF measured against an injection, and
    that FRF's own estimate of the coefficients (:meth:`estimate`).

    On closed-loop data the one-step (and free-run) scores are biased by the noise the
    feedback puts into the input: with 1 deg/s of gyro noise fed back they chose a 10 ms
    motor lag and 7-8 ms of delay for a 15 ms lag and 5 ms delay, the closed-loop bandwidth
    then 10-12 % high. An FRF against the injection (``S_ry / S_ru``) is not biased by the
    feedback. Each candidate lag (its filters, its best one-step delay shifted by up to
    :data:`FRF_STRUCTURE_SHIFT` samples in ``delay_step`` steps) is fitted to the FRF in the
    frequency domain, ``H ≈ b z R(z) / (z − a)`` (``R`` the candidate's filters and delay;
    ``b`` solved exactly for each pole ``a`` on a grid), weighted by the FRF's random error
    ``ε`` (with a floor, :data:`FRF_STRUCTURE_FLOOR`); the lowest
    ``mean(|H − G|² / (|H| ε)²)`` wins. Calling it returns None (keep the one-step choice)
    for an FRF that is not referenced to an injection, with under
    :data:`FRF_STRUCTURE_MIN_POINTS` coherent frequencies, or for models that are not one
    rate from one input.
    """

    def __init__(self, measured: FRF, axis: str, delay_step: float = 0.125) -> None:
        ok = (measured.coherent & np.isfinite(measured.response)
              & np.isfinite(measured.error) & (measured.error > 0))
        self.axis, self.delay_step = axis, delay_step
        self.f, self.h = measured.freq_hz[ok], measured.response[ok]
        self.usable = (bool(getattr(measured, "referenced", False))
                       and self.f.size >= FRF_STRUCTURE_MIN_POINTS)
        self.w = 1.0 / (np.abs(self.h) ** 2 * (measured.error[ok] ** 2 + FRF_STRUCTURE_FLOOR**2))

    def _fit(self, model: Model, shifts: np.ndarray, damping: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Cost and gain ``b`` (shift x pole) of ``model``'s structure with its delay
        shifted by ``shifts`` (samples), for the poles ``exp(-damping dt)``; and the poles."""
        rate, u_name = RATE_OF[self.axis], f"u_{self.axis}"
        if (not self.usable or model.state_names != (rate,) or model.continuous
                or set(model.features) - {rate, u_name, "1"} or u_name not in model.features):
            return None
        unit = np.zeros_like(model.coef)
        unit[model.features.index(u_name), 0] = 1.0  # a = 0, b = 1: R(z) / z
        try:
            r = plant_response(plant_from_model(replace(model, coef=unit), self.axis), self.f)
        except (MavsidError, ValueError, np.linalg.LinAlgError):
            return None
        f, h, w, dt = self.f, self.h, self.w, float(model.dt)
        z = np.exp(2j * np.pi * f * dt)
        poles = np.exp(-damping * dt)
        # with q = z R e^{-jωs dt} / (z - a) and the best b for each (s, a), the cost is
        # (Σ w|h|² − (Σ w Re(q̄ h))² / Σ w|q|²) / m: Σ w|q|² does not depend on the shift
        # and Σ w q̄ h over the frequencies is one product of (shift x f) and (f x pole)
        zr = z * r
        gram = (w * np.abs(zr) ** 2) @ (1.0 / np.abs(z[:, None] - poles[None, :]) ** 2)
        rot = np.exp(2j * np.pi * np.outer(shifts, f) * dt)
        cross = (rot @ ((w * np.conj(zr) * h)[:, None] / np.conj(z[:, None] - poles[None, :]))
                 ).real
        with np.errstate(divide="ignore", invalid="ignore"):
            cost = (np.sum(w * np.abs(h) ** 2) - cross**2 / gram[None, :]) / f.size
            gain = cross / gram[None, :]
        if not np.any(np.isfinite(cost)):
            return None
        return cost, gain, poles

    def _score(self, model: Model) -> tuple[float, float] | None:
        """(lowest cost, delay in samples) of one candidate over its delay shifts and poles."""
        d0 = float(model.delay + model.delay_frac)
        shifts = np.arange(-min(d0, FRF_STRUCTURE_SHIFT), FRF_STRUCTURE_SHIFT + 1e-9,
                           self.delay_step)
        got = self._fit(model, shifts, _FRF_DAMPING)
        if got is None:
            return None
        cost = got[0]
        i = np.unravel_index(int(np.nanargmin(cost)), cost.shape)[0]
        return float(np.nanmin(cost)), round(d0 + float(shifts[i]), 9)

    def __call__(self, models: Mapping[float, Model]) -> tuple[float, float] | None:
        """The best candidate's (lag s, delay samples) among ``models`` (per lag, its
        least-squares model at its best one-step delay)."""
        best: tuple[float, float, float] | None = None
        for lag, model in models.items():
            got = self._score(model)
            if got is not None and (best is None or got[0] < best[0]):
                best = (got[0], lag, got[1])
        return None if best is None else (best[1], best[2])

    def estimate(self, model: Model) -> Model | None:
        """``model`` with its pole and gain fitted to the FRF instead (its structure and
        trim kept): the estimate the feedback does not bias, for comparison; None where
        the FRF cannot give one."""
        got = self._fit(model, np.zeros(1), _FRF_DAMPING)
        if got is None:
            return None
        k = int(np.nanargmin(got[0][0]))
        lo, hi = _FRF_DAMPING[max(k - 1, 0)], _FRF_DAMPING[min(k + 1, _FRF_DAMPING.size - 1)]
        got = self._fit(model, np.zeros(1), np.linspace(lo, hi, 81))  # finer about the best
        if got is None:
            return None
        cost, gain, poles = got
        k = int(np.nanargmin(cost[0]))
        coef = np.array(model.coef, dtype=float, copy=True)
        coef[model.features.index(RATE_OF[self.axis]), 0] = poles[k]
        coef[model.features.index(f"u_{self.axis}"), 0] = gain[0, k]
        return replace(model, coef=coef)


#: Damping values (1/s) of the poles :class:`FrfStructure` tries.
_FRF_DAMPING = np.linspace(-2.0, 80.0, 165)
