"""The closed-loop response of a flight: how well the vehicle followed its own commands.

Needs far less than the plant does: a rate target and the rate (and, where logged, the
attitude target and the attitude). Per axis and controller loop (``rate``: rate target ->
rate; ``attitude``: commanded -> estimated roll/pitch angle):

- **step response** by regularised (Tikhonov) deconvolution of target -> actual over many
  overlapping windows (as PIDtoolbox does): each window with enough target activity gives
  ``H = Y X* / (|X|^2 + λ mean|X|^2)``, whose inverse transform is an impulse response and
  its running sum a step response; the mean of the windows is the estimate, its band
  ``± 2 σ / sqrt(n_independent)`` from the spread of the windows (``n_independent`` the
  windows' span over one window length: half-overlapped windows are not independent);
- rise time (10-90 %), overshoot and 5 % settling time of that mean (python-control's
  ``step_info``);
- the closed-loop **frequency response** target -> actual (:func:`mavsid.frequency.frf`)
  with coherence: the -3 dB bandwidth and the phase delay there;
- **tracking**: the error's RMS, and the delay that best aligns actual with target (none
  when the best lies at the edge of the searched range, or the actual leads the target);
- **noise**: gyro and controller-output spectra with the configured filters' cut-offs
  (:func:`mavsid.autopilot.filter_cutoffs`);
- **settings**: where the rate-controller parameters change in flight (the log's
  :attr:`~mavsid.data.RawLog.param_changes`: DataFlash ``PARM`` records, ULog parameter
  changes, MAVLink ``PARAM_VALUE``), one response per setting.

Honest limits: every result carries the band the log's rate resolves (``band_hz``: from one
over the window to the Nyquist frequency of the slower of target and actual); below
:data:`MIN_RATE_HZ` nothing is estimated and the verdict says why. Where the rate target is
known not to be a command — inside a SYSTEMID run that injects into the mixer
(:func:`mavsid.autopilot.ardupilot.injects_into_mixer`), where it is the controller's
answer to the disturbed rate — it is left out of target -> rate, and said so (a
:class:`~mavsid.reasons.Reason` of kind ``target_not_exogenous``); a step that starts far
below zero is flagged ``feedback_dominated`` (the target answers the actual).

Examples
--------
A first-order loop (time constant 30 ms) driven by a random target, sampled at 200 Hz:

>>> import numpy as np
>>> rng = np.random.default_rng(1)
>>> dt = 0.005
>>> target = np.repeat(rng.standard_normal(600), 20)   # held steps, 0.1 s each
>>> a = np.exp(-dt / 0.03)
>>> actual = np.zeros_like(target)
>>> for k in range(1, target.size):
...     actual[k] = a * actual[k - 1] + (1 - a) * target[k - 1]
>>> step = step_response(target, actual, dt)
>>> step.windows > 20, bool(abs(step.response[-1] - 1.0) < 0.05)
(True, True)
>>> k = np.searchsorted(step.time_s, 0.03)               # 1 - e^-1 after one time constant
>>> bool(abs(step.response[k] - (1 - np.exp(-1))) < 0.08)
True
"""

from __future__ import annotations

import itertools
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from mavsid.axes import AXES, RATE_OF
from mavsid.data import FlightData, RawLog
from mavsid.errors import MissingMessageError, NoExcitationError
from mavsid.frequency import FRF, frf
from mavsid.loop.injection import InjectionInTarget
from mavsid.numerics.spectra import welch
from mavsid.reasons import Reason

__all__ = [
    "AXES",
    "MIN_RATE_HZ",
    "FlightResponse",
    "LoopResponse",
    "Setting",
    "Spectrum",
    "StepResponse",
    "bandwidth",
    "best_delay",
    "flight_response",
    "loop_response",
    "read_response",
    "step_metrics",
    "step_response",
]

_OUTPUT = {"roll": "u_roll", "pitch": "u_pitch", "yaw": "u_yaw"}

#: below this logging rate (Hz) of target or actual nothing is estimated
MIN_RATE_HZ = 8.0
#: deconvolution windows (s) and the response length shown (s), per loop
WINDOW_S = {"rate": 4.0, "attitude": 8.0}
RESPONSE_S = {"rate": 0.5, "attitude": 1.5}
#: a window counts when its target's standard deviation reaches this (rad/s, rad)
MIN_ACTIVITY = {"rate": 0.05, "attitude": 0.01}
#: Tikhonov regularisation, relative to the mean diagonal of the window's Gram matrix
REGULARISATION = 1e-4
#: the step's median band half-width (of a unit step) above which its rise time, overshoot
#: and settling time are not given
MAX_BAND = 0.2
#: a step whose first tenth lies below minus this, band included, is not the loop's: no
#: loop answers a step by moving the other way that far at once (the target then follows the
#: actual through the outer loop, with no commands of its own to speak of)
MAX_DIP = 0.2
#: fewest windows behind a step response
MIN_WINDOWS = 3
#: longest delay (s) searched when aligning actual with target
MAX_DELAY_S = 0.25


# --------------------------------------------------------------------------- results


@dataclass(frozen=True)
class StepResponse:
    """A step response estimated from data, with its band.

    Attributes
    ----------
    time_s, response, lower, upper : numpy.ndarray
        Time after the step (s), the windows' mean response and its band (±2 standard
        errors of the mean).
    windows : int
        Windows averaged.
    window_s : float
        Length of one window (s).
    span_s : float
        Time the windows cover (s).
    method : str
        How it was estimated.
    """

    time_s: np.ndarray
    response: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    windows: int
    window_s: float
    span_s: float
    method: str = "Tikhonov deconvolution per window"

    def to_dict(self) -> dict[str, object]:
        """JSON form."""
        return {"time_s": _floats(self.time_s), "response": _floats(self.response),
                "lower": _floats(self.lower), "upper": _floats(self.upper),
                "windows": self.windows, "window_s": self.window_s, "span_s": self.span_s,
                "method": self.method}


@dataclass(frozen=True)
class Spectrum:
    """A power spectral density (unit²/Hz) and the cut-offs marked on it (name -> Hz)."""

    name: str
    freq_hz: np.ndarray
    psd: np.ndarray
    cutoffs: Mapping[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, object]:
        """JSON form."""
        return {"name": self.name, "frequency_hz": _floats(self.freq_hz),
                "psd": _floats(self.psd), "cutoffs_hz": dict(self.cutoffs)}


@dataclass(frozen=True)
class LoopResponse:
    """One controller loop of one axis: how the actual followed the target.

    Attributes
    ----------
    axis, loop : str
        ``roll``/``pitch``/``yaw``; ``rate`` or ``attitude``.
    target, actual : str
        Where the signals came from (``RATE.RDes``, ``RATE.R`` ...).
    rate_hz : float
        Sample rate worked at: the slower of target's and actual's logging rates.
    band_hz : (float, float) or None
        The band that rate and the window length resolve.
    verdict : str
        One line: what was found, or why nothing could be said.
    step : StepResponse or None
    rise_s, overshoot_pct, settling_s : float or None
        Of the step response's mean.
    frequency : FRF or None
        Target -> actual, with coherence.
    bandwidth_hz, phase_delay_s : float or None
        Where ``|T|`` first falls 3 dB below its low-frequency level inside the coherent
        band, and ``-phase / (2π f)`` there.
    tracking_rms : float or None
        RMS of target - actual over the used samples (rad/s or rad).
    delay_s : float or None
        The shift of actual that best aligns it with target; None when not found.
    delay_note : str
        Why no delay was found ("" when one was).
    left_out_s : float
        Seconds of usable target and actual left out because the target there was known
        not to be a command (inside a SYSTEMID mixer injection).
    reasons : tuple of Reason
        Structured findings behind the verdict (kinds ``target_not_exogenous``,
        ``feedback_dominated``).
    rate_injection : InjectionInTarget or None
        On an axis with a SYSTEMID rate injection (``SID_AXIS`` 7-9): whether the logged
        target carried it (else it was added to the target), the coefficient that said so
        and what decided.
    time_s, target_series, actual_series : numpy.ndarray
        The signals on the working grid (NaN where not used), for plots.
    """

    axis: str
    loop: str
    target: str
    actual: str
    rate_hz: float
    band_hz: tuple[float, float] | None
    verdict: str
    step: StepResponse | None = None
    rise_s: float | None = None
    overshoot_pct: float | None = None
    settling_s: float | None = None
    frequency: FRF | None = None
    bandwidth_hz: float | None = None
    phase_delay_s: float | None = None
    tracking_rms: float | None = None
    delay_s: float | None = None
    delay_note: str = ""
    left_out_s: float = 0.0
    reasons: tuple[Reason, ...] = ()
    rate_injection: InjectionInTarget | None = None
    time_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    target_series: np.ndarray = field(default_factory=lambda: np.zeros(0))
    actual_series: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def ok(self) -> bool:
        """Whether a step response was estimated."""
        return self.step is not None

    @property
    def feedback_dominated(self) -> bool:
        """Whether the step is flagged as not the loop's own (the target answers the actual)."""
        return any(r.kind == "feedback_dominated" for r in self.reasons)

    def to_dict(self) -> dict[str, object]:
        """JSON form (``axes.<axis>.<loop>`` of the command's output)."""
        return {
            "target": self.target, "actual": self.actual, "rate_hz": self.rate_hz,
            "band_hz": list(self.band_hz) if self.band_hz else None,
            "verdict": self.verdict,
            "step": self.step.to_dict() if self.step else None,
            "windows": self.step.windows if self.step else 0,
            "method": self.step.method if self.step else None,
            "rise_s": self.rise_s, "overshoot_pct": self.overshoot_pct,
            "settling_s": self.settling_s, "bandwidth_hz": self.bandwidth_hz,
            "phase_delay_s": self.phase_delay_s, "tracking_rms": self.tracking_rms,
            "delay_s": self.delay_s, "delay_note": self.delay_note or None,
            "left_out_s": self.left_out_s, "feedback_dominated": self.feedback_dominated,
            "reasons": [r.to_dict() for r in self.reasons],
            "rate_injection": self.rate_injection.to_dict() if self.rate_injection else None,
            "frequency": self.frequency.to_dict() if self.frequency else None,
        }


@dataclass(frozen=True)
class Setting:
    """A span of the flight with one set of rate-controller parameters.

    ``changed`` holds the parameters that differ from the setting before (name -> value).
    """

    start_s: float
    stop_s: float
    changed: Mapping[str, float]
    loops: tuple[LoopResponse, ...] = ()

    def to_dict(self) -> dict[str, object]:
        """JSON form."""
        return {"start_s": self.start_s, "stop_s": self.stop_s, "changed": dict(self.changed),
                "axes": _axes_dict(self.loops)}


@dataclass(frozen=True)
class FlightResponse:
    """The closed-loop response of one log: every loop, the noise, the settings."""

    log: str
    autopilot: str
    preset: str
    loops: tuple[LoopResponse, ...]
    spectra: Mapping[str, tuple[Spectrum, ...]]
    settings: tuple[Setting, ...] = ()
    notes: tuple[str, ...] = ()

    def loop(self, axis: str, loop: str = "rate") -> LoopResponse | None:
        """The response of ``axis``'s ``loop``, if worked out."""
        return next((r for r in self.loops if r.axis == axis and r.loop == loop), None)

    @property
    def ok(self) -> bool:
        """Whether any loop has a step response."""
        return any(r.ok for r in self.loops)

    def to_dict(self) -> dict[str, object]:
        """JSON form: ``axes.<axis>.<loop>``, spectra, settings."""
        return {
            "log": self.log, "autopilot": self.autopilot, "preset": self.preset,
            "axes": _axes_dict(self.loops),
            "spectra": {ax: [s.to_dict() for s in sp] for ax, sp in self.spectra.items()},
            "settings": [s.to_dict() for s in self.settings],
            "notes": list(self.notes),
        }


def _axes_dict(loops: Sequence[LoopResponse]) -> dict[str, dict[str, object]]:
    out: dict[str, dict[str, object]] = {}
    for r in loops:
        out.setdefault(r.axis, {})[r.loop] = r.to_dict()
    return out


def _floats(x: np.ndarray) -> list[float | None]:
    return [float(v) if math.isfinite(v) else None for v in np.asarray(x, float).tolist()]


# --------------------------------------------------------------------------- estimation


def step_response(target: np.ndarray | Sequence[np.ndarray],
                  actual: np.ndarray | Sequence[np.ndarray], dt: float, *,
                  window_s: float = 4.0, response_s: float = 0.5, fir_s: float | None = None,
                  min_activity: float = 0.0, regularisation: float = REGULARISATION
                  ) -> StepResponse:
    """The step response of ``actual`` to ``target`` by deconvolution over windows.

    In each window the impulse response ``h`` (``fir_s`` long) and an offset are fitted to
    ``actual[k] = Σ_j h[j] target[k - j] + c`` by least squares with a Tikhonov (ridge)
    penalty on ``h``; its running sum is the window's step response. The band is the
    windows' mean ± the root sum of squares of two standard errors of the mean and of the
    change of the mean when the deconvolution is cut at half its length (what truncating
    the loop's slow tail does to the part shown).

    Parameters
    ----------
    target, actual : numpy.ndarray or sequence of them
        Finite samples (one contiguous stretch per array) at step ``dt``.
    window_s : float
        Window length (s); windows overlap by half.
    response_s : float
        Length of the response returned (s).
    fir_s : float, optional
        Length of the impulse response estimated (default three times ``response_s``): it
        must hold most of the loop's response (its integrator's slow tail too), a shorter
        one biases the early part to make up for it.
    min_activity : float
        Windows whose target's standard deviation is below this are discarded.
    regularisation : float
        Tikhonov λ relative to the mean diagonal of the window's Gram matrix.

    Raises
    ------
    NoExcitationError
        Fewer than :data:`MIN_WINDOWS` windows with enough target activity.
    """
    targets = [target] if isinstance(target, np.ndarray) else list(target)
    actuals = [actual] if isinstance(actual, np.ndarray) else list(actual)
    n = max(8, round(window_s / dt))
    shown = max(2, round(response_s / dt) + 1)
    m = min(n // 2, max(shown, round((fir_s or 3 * response_s) / dt) + 1))
    shown = min(shown, m)
    m_half = max(shown, m // 2)
    full, half = [], []
    for x, y in zip(targets, actuals, strict=True):
        if x.size < n:
            continue
        for s in range(0, x.size - n + 1, n // 2):
            xs, ys = x[s:s + n], y[s:s + n]
            if not np.std(xs) >= max(min_activity, 1e-12):
                continue
            gram, rhs = _normal_equations(xs, ys, m)
            ridge = regularisation * np.trace(gram[:m, :m]) / m
            gram[np.arange(m), np.arange(m)] += ridge
            full.append(np.cumsum(np.linalg.solve(gram, rhs)[:shown]))
            keep = np.r_[np.arange(m_half), m]  # (the same rows, fewer taps)
            sub = gram[np.ix_(keep, keep)]
            half.append(np.cumsum(np.linalg.solve(sub, rhs[keep])[:shown]))
    if len(full) < MIN_WINDOWS:
        raise NoExcitationError(f"{len(full)} window(s) of {n * dt:.3g} s with target "
                                f"activity (std >= {min_activity:g}); {MIN_WINDOWS} needed")
    stack = np.array(full)
    mean = stack.mean(axis=0)
    span = len(full) * n / 2 * dt + n / 2 * dt
    independent = max(1.0, span / (n * dt))
    sem = stack.std(axis=0, ddof=1) / math.sqrt(independent)
    cut = np.abs(mean - np.mean(half, axis=0))
    band = np.hypot(2.0 * sem, cut)
    return StepResponse(np.round(np.arange(shown) * dt, 9), mean, mean - band, mean + band,
                        len(full), n * dt, span)


def _normal_equations(x: np.ndarray, y: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray]:
    """``(XᵀX, Xᵀy)`` of ``y[k] = Σ_j h[j] x[k - j] + c`` (``j < m``) over the samples
    ``k >= m - 1`` with a full history, from the Toeplitz structure (``O(n m + m²)``).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> x, y, m = rng.standard_normal(50), rng.standard_normal(50), 7
    >>> rows = np.arange(m - 1, 50)
    >>> big = np.column_stack([x[rows[:, None] - np.arange(m)], np.ones(rows.size)])
    >>> g, b = _normal_equations(x, y, m)
    >>> bool(np.allclose(g, big.T @ big) and np.allclose(b, big.T @ y[rows]))
    True
    """
    n = x.size
    g = np.empty((m + 1, m + 1))
    first = np.correlate(x, x[m - 1:], mode="valid")[::-1]
    g[0, :m] = first
    a, b = x[m - 2::-1][: m - 1], x[n - 1:n - m:-1]  # x[m-2-i], x[n-1-i]
    for i in range(m - 1):  # G[i+1, j+1] = G[i, j] + a_i a_j - b_i b_j (j >= i)
        g[i + 1, i + 1:m] = g[i, i:m - 1] + a[i] * a[i:] - b[i] * b[i:]
    upper = np.triu(g[:m, :m])
    g[:m, :m] = upper + np.triu(upper, 1).T
    csum = np.concatenate([[0.0], np.cumsum(x)])
    j = np.arange(m)
    g[:m, m] = g[m, :m] = csum[n - j] - csum[m - 1 - j]
    g[m, m] = n - m + 1
    rhs = np.empty(m + 1)
    rhs[:m] = np.correlate(x, y[m - 1:], mode="valid")[::-1]
    rhs[m] = y[m - 1:].sum()
    return g, rhs


def step_metrics(step: StepResponse) -> tuple[float | None, float | None, float | None]:
    """Rise time (10-90 %, s), overshoot (%) and 5 % settling time (s) of ``step``'s mean,
    by python-control's ``step_info``; None where the response does not settle positive."""
    import control

    y = step.response
    final = float(np.mean(y[-max(2, y.size // 5):]))
    if not final > 0.1:
        return None, None, None
    info = control.step_info(y, T=step.time_s, SettlingTimeThreshold=0.05,
                             RiseTimeLimits=(0.1, 0.9), yfinal=final)
    def num(v: float) -> float | None:
        return float(v) if math.isfinite(v) else None

    return num(info["RiseTime"]), num(info["Overshoot"]), num(info["SettlingTime"])


def bandwidth(r: FRF) -> tuple[float | None, float | None]:
    """The closed loop's -3 dB frequency inside the coherent band (Hz), and the phase delay
    there (s): None when ``|T|`` does not fall 3 dB within the band."""
    ok = r.coherent & np.isfinite(r.response)
    if ok.sum() < 3:
        return None, None
    f, mag = r.freq_hz[ok], np.abs(r.response[ok])
    level = float(np.median(mag[: max(1, f.size // 10)]))
    below = np.flatnonzero(mag < level * 10 ** (-3 / 20))
    if below.size == 0 or below[0] == 0:
        return None, None
    k = int(below[0])
    # log-interpolated crossing between the last point above and the first below
    lo, hi = mag[k - 1], mag[k]
    frac = (math.log(lo) - math.log(level * 10 ** (-3 / 20))) / max(math.log(lo / hi), 1e-12)
    fb = float(np.exp(np.log(f[k - 1]) + frac * (np.log(f[k]) - np.log(f[k - 1]))))
    phase = np.unwrap(np.angle(r.response[ok]))
    ph = float(np.interp(fb, f, phase))
    return fb, -ph / (2 * np.pi * fb)


def best_delay(target: Sequence[np.ndarray], actual: Sequence[np.ndarray], dt: float,
               max_delay_s: float = MAX_DELAY_S) -> tuple[float | None, str]:
    """The shift (s, >= 0) of ``actual`` that best correlates it with ``target``, and why
    there is none.

    The cross-correlation is searched over ``±max_delay_s`` and its peak refined by a
    parabola. No delay is found (None, with the reason) when nothing correlates, when the
    peak lies at the edge of the searched range (the best shift may lie beyond it: not a
    measurement) or when the actual leads the target (the target follows the actual).

    Examples
    --------
    A smooth random target, the actual a copy of it 30 ms, 400 ms and -50 ms later
    (100 Hz samples):

    >>> rng = np.random.default_rng(0)
    >>> x = np.convolve(rng.standard_normal(3000), np.ones(20) / 20, mode="same")
    >>> delay, why = best_delay([x[:-3]], [np.r_[np.zeros(3), x[:-6]]], 0.01)
    >>> round(delay, 3), why
    (0.03, '')
    >>> best_delay([x[:-40]], [np.r_[np.zeros(40), x[:-80]]], 0.01)
    (None, 'the correlation peaks at the edge of the ±250 ms searched')
    >>> best_delay([x[:-5]], [x[5:]], 0.01)
    (None, 'the actual leads the target by 50 ms (the target answers the actual)')
    """
    n = max(1, round(max_delay_s / dt))
    lags = np.arange(-n, n + 1)
    score = np.zeros(lags.size)
    for x, y in zip(target, actual, strict=True):
        x, y = x - x.mean(), y - y.mean()
        for i, lag in enumerate(lags):
            if abs(lag) >= x.size:
                continue
            if lag >= 0:
                score[i] += float(np.dot(x[: x.size - lag], y[lag:]))
            else:
                score[i] += float(np.dot(x[-lag:], y[: y.size + lag]))
    if not np.any(score > 0):
        return None, "target and actual do not correlate"
    k = int(np.argmax(score))
    if k in (0, lags.size - 1):
        return None, (f"the correlation peaks at the edge of the ±{max_delay_s * 1e3:.0f} ms "
                      "searched")
    a, b, c = score[k - 1], score[k], score[k + 1]
    den = a - 2 * b + c
    shift = 0.5 * (a - c) / den if den < 0 else 0.0
    delay = float(round((lags[k] + shift) * dt, 9))
    if lags[k] < 0:
        return None, (f"the actual leads the target by {-delay * 1e3:.3g} ms (the target "
                      "answers the actual)")
    return max(0.0, delay), ""


def _stretches(mask: np.ndarray, min_len: int) -> list[tuple[int, int]]:
    """``(start, stop)`` of the runs of True in ``mask`` at least ``min_len`` long."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return [(int(a), int(b)) for a, b in zip(starts, stops, strict=True) if b - a >= min_len]


def loop_response(axis: str, loop: str, time_s: np.ndarray, target: np.ndarray,
                  actual: np.ndarray, rate_hz: float, *, names: tuple[str, str] = ("", ""),
                  usable: np.ndarray | None = None) -> LoopResponse:
    """The response of one loop from its target and actual on a uniform grid ``time_s``.

    ``rate_hz`` is the slower of the two signals' logging rates: the grid is thinned to it
    (held or interpolated samples between records are no data). ``usable`` masks the
    samples to use (airborne, inside one block). Never raises for lack of data: the verdict
    says what is missing.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(0, 20, 0.1)
    >>> r = loop_response("roll", "rate", t, np.sin(t), np.sin(t), rate_hz=5.0)
    >>> r.ok, r.verdict
    (False, 'rate: logged at 5 Hz (< 8 Hz): nothing can be said about the loop')
    """
    dt = float(np.median(np.diff(time_s))) if time_s.size > 1 else 0.0
    base = LoopResponse(axis, loop, names[0], names[1], float(rate_hz), None, "")
    if not (dt > 0 and rate_hz >= MIN_RATE_HZ):
        return _with(base, verdict=f"{loop}: logged at {rate_hz:.3g} Hz (< {MIN_RATE_HZ:g} Hz): "
                     "nothing can be said about the loop")
    k = max(1, round(1.0 / (rate_hz * dt)))
    t, x, y = time_s[::k], target[::k], actual[::k]
    ok = np.isfinite(x) & np.isfinite(y)
    if usable is not None:
        ok &= np.asarray(usable, bool)[::k]
    step_dt = dt * k
    response_s = max(RESPONSE_S[loop], 6 * step_dt)
    window_s = max(WINDOW_S[loop], 9 * (round(response_s / step_dt) + 1) * step_dt)
    band = (float(f"{1.0 / window_s:.3g}"), float(f"{0.5 / step_dt:.4g}"))
    series = dict(time_s=t, target_series=np.where(ok, x, np.nan),
                  actual_series=np.where(ok, y, np.nan))
    base = _with(base, band_hz=band, **series)
    runs = _stretches(ok, 8)
    if not runs:
        return _with(base, verdict=f"{loop}: no stretch of target and actual together "
                     "(airborne, both logged)")
    xs = [x[a:b] for a, b in runs]
    ys = [y[a:b] for a, b in runs]
    err = np.concatenate([xi - yi for xi, yi in zip(xs, ys, strict=True)])
    rms = float(np.sqrt(np.mean(err**2)))
    delay, why = best_delay(xs, ys, step_dt)
    base = _with(base, tracking_rms=rms, delay_s=delay, delay_note=why)
    try:
        step = step_response(xs, ys, step_dt, window_s=window_s,
                             response_s=response_s,
                             min_activity=MIN_ACTIVITY[loop])
    except NoExcitationError as exc:
        return _with(base, verdict=f"{loop}: no step response: {exc}")
    spread = float(np.median(step.upper - step.lower) / 2)
    lead = max(1, step.response.size // 10)
    dip = float(np.min(step.response[:lead]))
    fed_back = bool(np.min(step.upper[:lead]) < -MAX_DIP)
    reasons = (Reason("feedback_dominated", {"dip": dip, "max_dip": MAX_DIP}),) if fed_back else ()
    measurable = spread <= MAX_BAND and not fed_back
    rise, over, settle = step_metrics(step) if measurable else (None, None, None)
    fr: FRF | None = None
    fb = delay_fb = None
    try:
        fr = frf(xs, ys, step_dt, windows_s=tuple(w for w in (1.0, 2.0, 4.0, 8.0)
                                                   if w >= 12 * step_dt) or (window_s,),
                 names=(names[0] or "target", names[1] or "actual"))
        fb, delay_fb = bandwidth(fr)
    except NoExcitationError:
        fr = None
    slow = (" (the log's rate shows only the slow part of the response)"
            if band[1] < 10 else "")
    where = ("bandwidth " + (f"{fb:.3g} Hz" if fb is not None else
                             "not reached in the coherent band") if fr is not None else
             "no frequency response")
    wide = (f"; band ±{spread:.2g} (median) too wide for rise time and overshoot"
            if spread > MAX_BAND else "")
    wide += "".join(f"; {r.message}" for r in reasons)
    verdict = (f"{loop}: {step.windows} windows of {step.window_s:.3g} s ({step.span_s:.0f} s); "
               f"{where}; resolves {band[0]:g}-{band[1]:g} Hz{slow}{wide}")
    return _with(base, verdict=verdict, step=step, rise_s=rise, overshoot_pct=over,
                 settling_s=settle, frequency=fr, bandwidth_hz=fb, phase_delay_s=delay_fb,
                 reasons=reasons)


def _left_out(r: LoopResponse, seconds: float, spans: str) -> LoopResponse:
    """``r`` with ``seconds`` of target and actual said to be left out over ``spans``
    (where the target is not a command), in its reasons and verdict.

    Examples
    --------
    >>> r = LoopResponse("roll", "rate", "RATE.RDes", "RATE.R", 100.0, None, "rate: no step")
    >>> got = _left_out(r, 36.4, "SYSTEMID mixer injection SID_AXIS 10 (34.0-46.0 s)")
    >>> print(got.verdict)  # doctest: +NORMALIZE_WHITESPACE
    rate: no step; 36 s left out of RATE.RDes -> RATE.R (SYSTEMID mixer injection SID_AXIS 10
    (34.0-46.0 s)): the rate target there is the controller's answer to the injected
    disturbance, not a command
    >>> got.left_out_s, got.reasons[0].kind
    (36.4, 'target_not_exogenous')
    """
    why = Reason("target_not_exogenous", {"left_out_s": round(seconds, 3)},
                 {"target": r.target, "actual": r.actual, "spans": spans})
    return _with(r, left_out_s=round(seconds, 3), reasons=(why, *r.reasons),
                 verdict=f"{r.verdict}; {why.message}")


def _with(r: LoopResponse, **changes: object) -> LoopResponse:
    return replace(r, **changes)  # type: ignore[arg-type]


# --------------------------------------------------------------------------- a flight


def _native_rate(raw: RawLog, source: str) -> float | None:
    """The logging rate (Hz) of the message ``source`` (``MSG.field``) names
    (:func:`mavsid.info.median_rate_hz`); None when it is not logged periodically."""
    from mavsid.info import median_rate_hz

    tab = raw.messages.get(source.split(".")[0])
    hz = float("nan") if tab is None else median_rate_hz(tab)
    return hz if math.isfinite(hz) else None


def _dense(raw: RawLog, sources: Sequence[str], grid: np.ndarray, rate_hz: float
           ) -> np.ndarray:
    """Grid samples where every message of ``sources`` (``MSG.field``) is logged at about
    ``rate_hz``: between two of its records at most two periods apart (ArduCopter logs RATE
    at 100 Hz in SYSTEMID and 10 Hz otherwise: the slow stretches in between are no data at
    the fast rate). A source whose message the log does not have leaves the mask alone.

    Examples
    --------
    >>> from mavsid.data import MessageTable, SourceInfo
    >>> t = np.r_[np.arange(0, 1, 0.01), np.arange(1, 3, 0.1)]
    >>> raw = RawLog(SourceInfo("a", "dataflash", 0), {"RATE": MessageTable("RATE", {}, t)})
    >>> m = _dense(raw, ["RATE.R"], np.arange(0, 3, 0.01), 100.0)
    >>> bool(m[:99].all()), bool(m[110:].any())
    (True, False)
    """
    ok = np.ones(grid.shape, bool)
    for source in sources:
        tab = raw.messages.get(source.split(".")[0])
        if tab is None or len(tab.time_s) < 2:
            continue
        t = np.unique(np.asarray(tab.time_s, float)[np.isfinite(tab.time_s)])
        i = np.clip(np.searchsorted(t, grid, side="right"), 1, t.size - 1)
        ok &= (t[i] - t[i - 1]) <= 2.0 / rate_hz
    return ok


def _attitude_pair(raw: RawLog, axis: str, grid: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, tuple[str, str], float] | None:
    """The attitude target and attitude of ``axis`` logged together
    (:data:`mavsid.autopilot.presets.ATTITUDE_PAIRS`) on ``grid`` (rad, interpolated; NaN
    outside their span), their sources and their logging rate; None when the log has none."""
    from mavsid.autopilot.presets import ATTITUDE_PAIRS
    from mavsid.channels import first_of

    for pair in ATTITUDE_PAIRS.get(axis, ()):
        got = [first_of(raw, [ch], f"{axis} attitude loop") for ch in pair]
        names = (f"{pair[0].message}.{pair[0].field}", f"{pair[1].message}.{pair[1].field}")
        hz = _native_rate(raw, names[0])
        if got[0] is None or got[1] is None or hz is None:
            continue
        series = []
        for _, ts, v in (got[0], got[1]):
            order = np.argsort(ts, kind="stable")
            series.append(np.interp(grid, ts[order], v[order], left=np.nan, right=np.nan))
        return series[0], series[1], names, hz
    return None


def _spectra(flight: FlightData, axis: str, usable: np.ndarray) -> tuple[Spectrum, ...]:
    """Gyro and controller-output spectra of ``axis`` over the longest usable stretch, at
    the signals' logging rates."""
    rates = flight.native_rate_hz
    out = []
    from mavsid.autopilot import filter_cutoffs

    cut = filter_cutoffs(flight.params, axis)
    for name, values, unit in (
            (RATE_OF[axis], flight.series(RATE_OF[axis]), "gyro"),
            (_OUTPUT[axis], flight.series(_OUTPUT[axis]), "output")):
        if values is None:
            continue
        hz = float(rates.get(name) or 1.0 / flight.dt)
        k = max(1, round(1.0 / (hz * flight.dt)))
        ok = (usable & np.isfinite(values))[::k]
        runs = _stretches(ok, 64)
        if not runs:
            continue
        a, b = max(runs, key=lambda r: r[1] - r[0])
        v = values[::k][a:b]
        f, p = welch(v, 1.0 / (flight.dt * k), nperseg=min(512, v.size))
        out.append(Spectrum(f"{unit} {name}", f, p, cut))
    return tuple(out)


def _usable(flight: FlightData) -> np.ndarray:
    """Airborne samples (armed when the log says nothing of airborne)."""
    for key in ("airborne", "armed"):
        flag = flight.flags.get(key)
        if flag is not None and np.any(flag):
            return np.asarray(flag, bool)
    return np.ones(flight.time_s.shape, bool)


def _settings(raw: RawLog, span: tuple[float, float], platform: str | None
              ) -> list[tuple[float, dict[str, float]]]:
    """``(time, changed)`` where rate-controller parameters change inside ``span``
    (:attr:`RawLog.param_changes` that :func:`mavsid.autopilot.is_rate_setting`; changes
    within one second are one)."""
    from mavsid.autopilot import is_rate_setting

    changes: list[tuple[float, dict[str, float]]] = []
    for c in raw.param_changes:
        if not (span[0] < c.time_s < span[1] and is_rate_setting(c.name, platform)):
            continue
        if changes and c.time_s - changes[-1][0] < 1.0:
            changes[-1][1][c.name] = c.value
        else:
            changes.append((c.time_s, {c.name: c.value}))
    return changes


def _not_commanded(flight: FlightData) -> tuple[np.ndarray, str]:
    """Samples where the rate target is known not to be a command, and which spans they are:
    inside a SYSTEMID run that injected into the mixer
    (:func:`~mavsid.autopilot.ardupilot.injects_into_mixer`), and one response length after
    it (the loop's answer to its last instants). There the rate controller is bypassed and
    its rate target is its answer to the disturbed rate: target -> rate measures the
    feedback, not the tracking. Runs injecting into a target (attitude or rate) stay.

    Examples
    --------
    >>> from mavsid.data import SysidRun
    >>> t = np.arange(0.0, 10.0, 0.01)
    >>> runs = (SysidRun(2.0, 4.0, "SIDS", axis=10), SysidRun(6.0, 7.0, "SIDS", axis=1))
    >>> class F:  # (the two fields read)
    ...     time_s, sysid_runs = t, runs
    >>> mask, spans = _not_commanded(F())  # type: ignore[arg-type]
    >>> round(float(mask.sum()) * 0.01, 2), spans
    (2.51, 'SYSTEMID mixer injection SID_AXIS 10 (2.0-4.0 s)')
    """
    from mavsid.autopilot.ardupilot import injects_into_mixer

    t = flight.time_s
    mask = np.zeros(t.shape, bool)
    spans = []
    for r in flight.sysid_runs:
        if r.injected and injects_into_mixer(r.sid_axis):
            mask |= (t >= r.start_s) & (t <= r.stop_s + RESPONSE_S["rate"])
            spans.append(f"{r.sid_axis} ({r.start_s:.1f}-{r.stop_s:.1f} s)")
    return mask, ("SYSTEMID mixer injection SID_AXIS " + ", ".join(spans)) if spans else ""


def flight_response(flight: FlightData, raw: RawLog, axes: Sequence[str] = AXES
                    ) -> FlightResponse:
    """Every loop of ``axes`` of an aligned flight, its spectra and its settings.

    ``raw`` is the log as read with the rate targets (:func:`read_response` reads both).

    Raises
    ------
    MissingMessageError
        The log has neither a rate target nor a commanded attitude on any axis.
    """
    from mavsid.loop.twin import twin_signals

    signals = twin_signals(flight, raw)
    cmd = flight.commanded
    if not signals.target and not cmd:
        from mavsid.autopilot.presets import DESIRED_CHANNELS, TARGET_CHANNELS

        names = sorted({f"{c.message}.{c.field}" for c in TARGET_CHANNELS["p"]}
                       | {f"{c.message}.{c.field}" for c in DESIRED_CHANNELS["roll"]})
        raise MissingMessageError(", ".join(names), what="rate target nor commanded "
                                  "attitude among", path=flight.source.path)
    usable = _usable(flight)
    rates = flight.native_rate_hz
    state_src = flight.sources
    cmd_src = flight.commanded_from
    grid = 1.0 / flight.dt
    fed, spans = _not_commanded(flight)

    def one(mask: np.ndarray) -> list[LoopResponse]:
        loops = []
        for axis in axes:
            rate = RATE_OF[axis]
            actual = flight.series(rate)
            if axis not in signals.target or actual is None:
                loops.append(LoopResponse(
                    axis, "rate", "", rate, 0.0, None, "rate: no rate target logged on this "
                    "axis (RATE.*Des, PIDx.Tar, vehicle_rates_setpoint, ATTITUDE_TARGET)"))
            else:
                src = signals.sources.get(f"target_{axis}", "")
                target = np.asarray(signals.target[axis], float)
                hz = min(_native_rate(raw, src) or grid, float(rates.get(rate) or grid), grid)
                actual_src = str(state_src.get(rate, rate))
                dense = _dense(raw, [src, actual_src], flight.time_s, hz)
                cut = mask & dense & fed & np.isfinite(target) & np.isfinite(actual)
                got = loop_response(axis, "rate", flight.time_s, target, actual, hz,
                                    names=(src, actual_src), usable=mask & dense & ~fed)
                if cut.any():
                    got = _left_out(got, float(cut.sum()) * flight.dt, spans)
                if axis in signals.injection_in_target:
                    got = replace(got, rate_injection=signals.injection_in_target[axis])
                loops.append(got)
            if axis == "yaw":
                continue  # (the commanded heading is a rate: the rate loop is its loop)
            att = flight.series(axis)
            hz = min(float(rates.get(axis) or grid), grid)
            fast = _attitude_pair(raw, axis, flight.time_s)
            if fast is not None and fast[3] > 1.5 * hz:  # (logged faster together)
                target, actual, names, hz = fast
                hz = min(hz, grid)
                dense = _dense(raw, names, flight.time_s, hz)
                loops.append(loop_response(axis, "attitude", flight.time_s, target, actual, hz,
                                           names=names, usable=mask & dense))
            elif axis in cmd and att is not None:
                names = (str(cmd_src.get(axis, "commanded")), str(state_src.get(axis, axis)))
                dense = _dense(raw, names, flight.time_s, hz)
                loops.append(loop_response(
                    axis, "attitude", flight.time_s, np.asarray(cmd[axis], float), att, hz,
                    names=names, usable=mask & dense))
        return loops

    loops = one(usable)
    spectra = {axis: _spectra(flight, axis, usable) for axis in axes}
    span = (float(flight.time_s[0]), float(flight.time_s[-1]))
    changes = _settings(raw, span, flight.autopilot or raw.autopilot)
    settings: list[Setting] = []
    if changes:
        edges = [span[0], *[c[0] for c in changes], span[1]]
        labels: list[dict[str, float]] = [{}, *[c[1] for c in changes]]
        for (a, b), changed in zip(itertools.pairwise(edges), labels, strict=True):
            inside = usable & (flight.time_s >= a) & (flight.time_s < b)
            settings.append(Setting(a, b, changed, tuple(one(inside))))
    notes = []
    if not any(r.ok for r in loops):
        notes.append("no loop has enough target activity or a fast enough log for a step "
                     "response")
    return FlightResponse(flight.source.path, flight.autopilot or "unknown",
                          flight.preset, tuple(loops), spectra, tuple(settings), tuple(notes))


def read_response(path: str | os.PathLike[str], axes: Sequence[str] = AXES, *,
                  preset: str | None = None, presets: Mapping[str, object] | None = None,
                  mixers: Mapping[str, object] | None = None) -> FlightResponse:
    """Read and align ``path`` with the rate and attitude targets, and work out its
    :func:`flight_response`.

    Raises
    ------
    MavsidError
        The log cannot be read or aligned, or has no rate target.
    """
    from mavsid.align import read_flight
    from mavsid.autopilot.presets import ATTITUDE_PAIRS, DESIRED_CHANNELS
    from mavsid.loop.twin import twin_messages

    attitude = {c.message for chans in DESIRED_CHANNELS.values() for c in chans}
    attitude |= {c.message for pairs in ATTITUDE_PAIRS.values() for p in pairs for c in p}
    flight, raw = read_flight(path, preset, None, presets=presets or None,  # type: ignore[arg-type]
                              mixers=mixers or None,  # type: ignore[arg-type]
                              also=sorted(twin_messages() | attitude))
    return flight_response(flight, raw, axes)

