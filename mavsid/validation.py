"""Validate a fitted model by rollout on held-out segments.

Small one-step errors compound, so a model is judged by what it predicts ``k`` steps ahead
and in free run (its own predictions fed back, measured inputs only), on segments it was not
fitted on. :func:`validate` computes, per predicted state:

- fit % (normalised RMSE) against prediction horizon, one step to free run;
- RMSE of the one-step and free-run predictions;
- eigenvalues of the identified dynamics and whether they are stable (when the model
  exposes them);
- autocorrelation of the one-step residuals and their cross-correlation with the inputs,
  with the confidence band of a white residual;
- for SYSTEMID (chirp) segments, the measured frequency response with its coherence next to
  the model's response to the same input.

Fit % is ``100 * (1 - ||y - yhat|| / ||y - mean(y)||)`` (100 perfect, 0 no better than the
mean, negative worse). Over several segments the sums of squares are pooled, each segment's
output taken about its own mean.

Each held-out segment starts from its own measured state, and an affine model (a constant
term ``1`` among its features) runs with the segment's own trim: the constant term
re-estimated on the segment, one number per output, by least squares on its free run
(:func:`segment_trim`). A rate plant is nearly an integrator (a yaw pole under 1 1/s), so a
trim that moves between windows (battery, centre of gravity, a yaw I-term, wind) makes a free
run with the training windows' trim drift away however right the dynamics are; the trim is a
nuisance, like the initial state, not what the model claims. The free run with the model's
own trim is kept too (``fit_free_run_own_trim``).

Examples
--------
>>> import numpy as np
>>> y = np.array([0.0, 1.0, 2.0, 3.0])
>>> float(fit_percent(y, y))
100.0
>>> float(fit_percent(y, np.full(4, 1.5)))
0.0
>>> round(float(fit_percent(y, y + 0.5)), 2)
55.28
"""

from __future__ import annotations

import functools
import statistics
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol, TypeVar, runtime_checkable

import numpy as np

from mavsid.axes import RATE_OF
from mavsid.data import Segment, demean
from mavsid.errors import ConfigError, NoExcitationError
from mavsid.numerics.spectra import density, segment_ffts
from mavsid.numerics.stats import chi2_sf

__all__ = [
    "DEFAULT_HORIZONS_S",
    "FrequencyResponse",
    "Model",
    "ResidualTest",
    "SegmentValidation",
    "Validation",
    "eigenvalues",
    "fit_percent",
    "fit_sums",
    "frequency_response",
    "horizon_label",
    "residual_test",
    "rmse",
    "segment_trim",
    "validate",
]

#: Prediction horizons (seconds) at which fit % is reported besides one step and free run.
DEFAULT_HORIZONS_S: tuple[float, ...] = (0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0)


@runtime_checkable
class Model(Protocol):
    """What validation needs of a fitted model (see ``mavsid.estimators``)."""

    @property
    def state_names(self) -> tuple[str, ...]: ...

    @property
    def input_names(self) -> tuple[str, ...]: ...

    @property
    def dt(self) -> float: ...

    @property
    def delay(self) -> int: ...

    @property
    def params(self) -> dict[str, float]: ...

    def simulate(self, segment: Segment) -> np.ndarray: ...

    def predict(self, segment: Segment, horizon: int = 1) -> np.ndarray: ...


# --------------------------------------------------------------------------- measures


def fit_percent(y: np.ndarray, yhat: np.ndarray) -> np.ndarray:
    """Fit % per column: ``100 * (1 - ||y - yhat|| / ||y - mean(y)||)``.

    Rows where ``yhat`` (or ``y``) is not finite are left out. A column without finite rows,
    or whose measured output is constant, gives NaN.

    Parameters
    ----------
    y, yhat : numpy.ndarray, shape (n,) or (n, m)
        Measured and predicted outputs.

    Returns
    -------
    numpy.ndarray
        Shape ``()`` for 1-D input, ``(m,)`` otherwise.
    """
    err, norm = fit_sums(y, yhat)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = 100.0 * (1.0 - np.sqrt(err / norm))
    out = np.where(norm > 0, out, np.nan)
    return out if np.ndim(y) > 1 else out.reshape(())


def fit_sums(y: np.ndarray, yhat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two sums :func:`fit_percent` is made of, per column, over the rows where both
    are finite: the squared errors ``sum((y - yhat)**2)`` and the squared deviations of
    ``y`` about its mean. Summed over several pieces (segments, delays) they give the fit %
    of the pieces pooled.

    Examples
    --------
    >>> import numpy as np
    >>> err, norm = fit_sums(np.array([1.0, 2.0, 3.0, np.nan]), np.array([1.0, 2.0, 4.0, 0.0]))
    >>> float(err[0]), float(norm[0])
    (1.0, 2.0)
    """
    y2 = np.asarray(y, dtype=float).reshape(len(y), -1)
    p2 = np.asarray(yhat, dtype=float).reshape(len(yhat), -1)
    ok = np.isfinite(y2) & np.isfinite(p2)
    with np.errstate(over="ignore", invalid="ignore"):  # (a diverging free run: inf, said so)
        err = np.where(ok, (y2 - p2) ** 2, 0.0).sum(axis=0)
    count = ok.sum(axis=0)
    mean = np.where(ok, y2, 0.0).sum(axis=0) / np.maximum(count, 1)
    norm = np.where(ok, (y2 - mean) ** 2, 0.0).sum(axis=0)
    return err, np.where(count > 0, norm, 0.0)


def rmse(y: np.ndarray, yhat: np.ndarray) -> np.ndarray:
    """Root-mean-square error per column over rows where both are finite.

    Examples
    --------
    >>> import numpy as np
    >>> float(rmse(np.array([1.0, 2.0, np.nan]), np.array([2.0, 1.0, 0.0])))
    1.0
    """
    y2 = np.asarray(y, dtype=float).reshape(len(y), -1)
    p2 = np.asarray(yhat, dtype=float).reshape(len(yhat), -1)
    ok = np.isfinite(y2) & np.isfinite(p2)
    sq = np.where(ok, (y2 - p2) ** 2, 0.0).sum(axis=0)
    n = ok.sum(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(n > 0, np.sqrt(sq / np.maximum(n, 1)), np.nan)
    return out if np.ndim(y) > 1 else out.reshape(())


def horizon_label(seconds: float) -> str:
    """The key used for a horizon in reports and JSON (``0.5`` -> ``'0.5s'``).

    Examples
    --------
    >>> horizon_label(0.5), horizon_label(2.0), horizon_label(0.025)
    ('0.5s', '2s', '0.025s')
    """
    return f"{seconds:g}s"


def eigenvalues(model: object) -> tuple[np.ndarray | None, bool | None]:
    """Eigenvalues of the identified dynamics and whether they are stable.

    Uses ``model.eigenvalues`` (an array or a method) or else the state matrix ``model.A``.
    Discrete-time models are stable when every ``|lambda| <= 1``; models with a true
    ``continuous`` attribute when every ``Re(lambda) <= 0`` (marginally stable counts: a rate
    plant is close to an integrator, and an integrator's model — from its measured frequency
    response, or a bounded fit at its bound — is not an unstable one). ``(None, None)`` when
    the model exposes neither.
    """
    value: Any = getattr(model, "eigenvalues", None)
    if callable(value):
        value = value()
    if value is None:
        a = getattr(model, "A", None)
        if a is None:
            return None, None
        a = np.atleast_2d(np.asarray(a, dtype=float))
        value = np.linalg.eigvals(a)
    lam = np.atleast_1d(np.asarray(value, dtype=complex))
    if not lam.size:
        return lam, None
    if getattr(model, "continuous", False):
        return lam, bool(np.all(lam.real <= 0))
    return lam, bool(np.all(np.abs(lam) <= 1.0))


# --------------------------------------------------------------------------- results


@dataclass(frozen=True)
class SegmentValidation:
    """Predictions on one held-out segment.

    Attributes
    ----------
    start_s, stop_s : float
        First and last sample time (log clock, s).
    time_s : numpy.ndarray, shape (n,)
    measured, one_step, free_run : numpy.ndarray, shape (n, ny)
        Measured outputs, one-step-ahead and free-run predictions (NaN where unavailable).
    fit_one_step, fit_free_run : numpy.ndarray, shape (ny,)
        Fit % on this segment alone.
    source : str
        The segment's source (``"sysid"`` or ``"scan"``).
    trim_shift : numpy.ndarray, shape (ny,)
        The segment's own trim less the model's (the constant term's coefficient, in its
        units; zeros for a model without one), see :func:`segment_trim`.
    fit_free_run_own_trim : numpy.ndarray, shape (ny,)
        Fit % of the free run with the model's own trim.
    """

    start_s: float
    stop_s: float
    time_s: np.ndarray
    measured: np.ndarray
    one_step: np.ndarray
    free_run: np.ndarray
    fit_one_step: np.ndarray
    fit_free_run: np.ndarray
    source: str = ""
    trim_shift: np.ndarray = field(default_factory=lambda: np.zeros(0))
    fit_free_run_own_trim: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass(frozen=True)
class ResidualTest:
    """Whiteness of the one-step residuals and their independence from the inputs.

    Attributes
    ----------
    lags : numpy.ndarray, shape (L+1,)
        0 .. L samples.
    autocorr : numpy.ndarray, shape (L+1, ny)
        Normalised residual autocorrelation (1 at lag 0).
    cross_lags : numpy.ndarray, shape (2L+1,)
        -L .. L samples; positive lag: input leads the residual.
    crosscorr : numpy.ndarray, shape (2L+1, nu, ny)
        Normalised cross-correlation of each input with each residual.
    band : float
        Half-width of the confidence band of a white residual (``z / sqrt(n)``).
    confidence : float
        Confidence level of ``band``.
    n : int
        Number of residual samples used.
    """

    lags: np.ndarray
    autocorr: np.ndarray
    cross_lags: np.ndarray
    crosscorr: np.ndarray
    band: float
    confidence: float
    n: int

    @property
    def autocorr_outside(self) -> np.ndarray:
        """Fraction of lags >= 1 outside the band, per output."""
        return np.mean(np.abs(self.autocorr[1:]) > self.band, axis=0)

    @property
    def crosscorr_outside(self) -> np.ndarray:
        """Fraction of lags outside the band, per (input, output)."""
        return np.mean(np.abs(self.crosscorr) > self.band, axis=0)

    def ljung_box(self, lags: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Ljung–Box statistic ``Q = n(n+2) Σ_{k=1..h} r_k² / (n-k)`` and its p-value
        (χ² with ``h`` degrees of freedom) per output, over lags 1..``h`` (default: all).

        A small p-value (< 0.01) says the residuals are not white: the model leaves
        structure unexplained, and its σ (which assume white residuals) are optimistic.

        Examples
        --------
        >>> rng = np.random.default_rng(1)
        >>> e = rng.standard_normal((5000, 1))
        >>> float(residual_test([e], [e]).ljung_box(20)[1][0]) > 0.01
        True
        >>> float(residual_test([np.cumsum(e, axis=0)], [e]).ljung_box(20)[1][0]) < 1e-6
        True
        """
        h = int(self.lags[-1]) if lags is None else min(int(lags), int(self.lags[-1]))
        n = float(self.n)
        if h < 1 or n <= h + 1:
            nan = np.full(self.autocorr.shape[1], np.nan)
            return nan, nan
        k = self.lags[1 : h + 1].astype(float)
        r = np.nan_to_num(self.autocorr[1 : h + 1])
        q = n * (n + 2) * np.sum(r**2 / (n - k)[:, None], axis=0)
        return q, chi2_sf(q, h)


@dataclass(frozen=True)
class FrequencyResponse:
    """Measured and model frequency response from one input to one output.

    Attributes
    ----------
    input_name, output_name : str
    freq_hz : numpy.ndarray, shape (nf,)
    measured : numpy.ndarray (complex), shape (nf,)
        H1 estimate ``S_uy / S_uu`` from the measured data.
    coherence : numpy.ndarray, shape (nf,)
        Magnitude-squared coherence of the measured input and output (0..1).
    model : numpy.ndarray (complex), shape (nf,)
        The same estimator applied to the model's free-run output on the same input.
    band_hz : tuple of float or None
        The chirp's frequency band when the segments declare it.
    """

    input_name: str
    output_name: str
    freq_hz: np.ndarray
    measured: np.ndarray
    coherence: np.ndarray
    model: np.ndarray
    band_hz: tuple[float, float] | None = None


@dataclass(frozen=True)
class Validation:
    """Everything :func:`validate` measured for one model on held-out segments.

    Attributes
    ----------
    state_names, input_names : tuple of str
    dt : float
    horizons : numpy.ndarray of int, shape (nh,)
        Prediction horizons in samples (1 first).
    fit_vs_horizon : numpy.ndarray, shape (nh, ny)
        Pooled fit % at each horizon.
    fit_free_run : numpy.ndarray, shape (ny,)
        Pooled free-run fit %, each segment with its own trim (see the module's notes).
    rmse_one_step, rmse_free_run : numpy.ndarray, shape (ny,)
        In the outputs' units.
    eigenvalues : numpy.ndarray or None
    stable : bool or None
    residuals : ResidualTest
    frequency : tuple of FrequencyResponse
        One per chirp-excited (input, output) pair; empty without SYSTEMID segments.
    segments : tuple of SegmentValidation
    fit_free_run_own_trim : numpy.ndarray, shape (ny,)
        Pooled free-run fit % with the model's own trim on every segment (equal to
        ``fit_free_run`` for a model without a constant term).
    """

    state_names: tuple[str, ...]
    input_names: tuple[str, ...]
    dt: float
    horizons: np.ndarray
    fit_vs_horizon: np.ndarray
    fit_free_run: np.ndarray
    rmse_one_step: np.ndarray
    rmse_free_run: np.ndarray
    eigenvalues: np.ndarray | None
    stable: bool | None
    residuals: ResidualTest
    frequency: tuple[FrequencyResponse, ...] = ()
    segments: tuple[SegmentValidation, ...] = field(default_factory=tuple)
    fit_free_run_own_trim: np.ndarray | None = None

    @property
    def horizons_s(self) -> np.ndarray:
        """Horizons in seconds."""
        return self.horizons * self.dt

    @property
    def fit_one_step(self) -> np.ndarray:
        """Pooled one-step fit %, per output."""
        return self.fit_vs_horizon[0]

    def fit_at(self, seconds: float) -> np.ndarray:
        """Fit % at the horizon nearest ``seconds`` (NaN when none is within 10 %)."""
        k = max(1, round(seconds / self.dt))
        i = int(np.argmin(np.abs(self.horizons - k)))
        if abs(self.horizons[i] - k) > 0.1 * k:
            return np.full(len(self.state_names), np.nan)
        return self.fit_vs_horizon[i]

    def fit_summary(self, state: str, horizons_s: Sequence[float] = (0.5,)) -> dict[str, float]:
        """``{"one_step": .., "0.5s": .., "free_run": ..}`` for one output (NaN -> None-safe)."""
        j = self.state_names.index(state)
        out = {"one_step": float(self.fit_one_step[j])}
        for h in horizons_s:
            out[horizon_label(h)] = float(self.fit_at(h)[j])
        out["free_run"] = float(self.fit_free_run[j])
        return out


# --------------------------------------------------------------------------- computation


def _columns(segment: Segment, names: Sequence[str], what: str) -> np.ndarray:
    """The columns ``names`` of the segment's states or inputs."""
    have = segment.state_names if what == "state" else segment.input_names
    data = segment.states if what == "state" else segment.inputs
    missing = [n for n in names if n not in have]
    if missing:
        raise ConfigError(
            f"segment {segment.start_s:.2f}-{segment.stop_s:.2f} s has no {what} "
            f"{', '.join(missing)} that the model uses (it has: {', '.join(have)})"
        )
    return np.asarray(data[:, [have.index(n) for n in names]], dtype=float)


def _as_2d(a: np.ndarray, n: int, ny: int, what: str) -> np.ndarray:
    out = np.asarray(a, dtype=float)
    if out.ndim == 1:
        out = out[:, None]
    if out.shape != (n, ny):
        raise ConfigError(f"model {what} returned shape {out.shape}, expected {(n, ny)}")
    return out


F = TypeVar("F", bound=Callable[..., Any])


def _quiet_divergence(func: F) -> F:
    """``func`` run without numpy's overflow and invalid-value warnings: a diverging model's
    rollout overflows by design, and the result says so (``diverges``), not a warning."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with np.errstate(over="ignore", invalid="ignore"):
            return func(*args, **kwargs)

    return wrapper  # type: ignore[return-value]


@_quiet_divergence
def segment_trim(model: Any, segment: Segment,
                 free: np.ndarray | None = None) -> tuple[Any, np.ndarray]:
    """``model`` with its constant term (feature ``1``) re-estimated on ``segment``: the
    shift, one number per output, that brings its free run closest to the measured states
    (least squares; the free run is linear in it), as the initial state is taken from the
    segment. Returns the model and the shift; the model unchanged (and zeros) when it has no
    constant term, is not affine in its states, or the shift is not finite.

    ``free``: the model's free run on the segment, if already simulated.

    Examples
    --------
    >>> from mavsid.estimators.model import Model as M
    >>> m = M(("p",), ("u",), ("p", "u", "1"), np.array([[0.9], [1.0], [0.0]]), dt=0.01)
    >>> u = np.zeros((50, 1))
    >>> y = m.simulate_inputs(u)  # the model's own free run, trim 0
    >>> seg = Segment(np.arange(50) * 0.01, y + 0.5, u, ("p",), ("u",), 0.01, "all", "scan")
    >>> _, shift = segment_trim(m, seg)  # held 0.5 higher: a trim of 0.1 keeps it there
    >>> round(float(shift[0]), 6)
    0.05
    """
    features = tuple(getattr(model, "features", ()) or ())
    names = tuple(model.state_names)
    ny = len(names)
    none = np.zeros(ny)
    if "1" not in features or not getattr(model, "is_affine", False) \
            or not hasattr(model, "__dataclass_fields__"):
        return model, none
    k = features.index("1")
    y = _columns(segment, names, "state")

    def shifted(shift: np.ndarray) -> Any:
        coef = np.array(model.coef, dtype=float)
        coef[k] += shift
        return replace(model, coef=coef)

    def run(m: Any) -> np.ndarray:
        return np.asarray(m.simulate(segment), dtype=float).reshape(len(y), ny)

    base = run(model) if free is None else free
    # each output's response to a unit step of its constant term: (n, ny, ny)
    g = np.stack([run(shifted(np.eye(ny)[j])) - base for j in range(ny)], axis=-1)
    ok = np.isfinite(y).all(axis=1) & np.isfinite(base).all(axis=1) \
        & np.isfinite(g).all(axis=(1, 2))
    if ok.sum() < 2:
        return model, none
    with np.errstate(all="ignore"):
        shift = np.linalg.lstsq(g[ok].reshape(-1, ny), (y - base)[ok].ravel(), rcond=None)[0]
    if not np.all(np.isfinite(shift)):
        return model, none
    return shifted(shift), shift


def _horizon_samples(dt: float, horizons_s: Sequence[float]) -> np.ndarray:
    ks = {1} | {max(1, round(h / dt)) for h in horizons_s}
    return np.array(sorted(ks), dtype=int)


@_quiet_divergence
def validate(
    model: Model,
    segments: Sequence[Segment],
    *,
    horizons_s: Sequence[float] = DEFAULT_HORIZONS_S,
    max_lag: int = 50,
    confidence: float = 0.99,
    fft_window_s: float = 4.0,
) -> Validation:
    """Roll ``model`` out on held-out ``segments`` and measure how well it predicts.

    Parameters
    ----------
    model : Model
        A fitted model (``state_names``, ``input_names``, ``dt``, ``simulate``, ``predict``).
    segments : sequence of Segment
        Held-out data; each must carry the model's states and inputs at the model's ``dt``.
    horizons_s : sequence of float
        Horizons (s) for fit % besides one step; rounded to whole samples.
    max_lag : int
        Largest lag (samples) of the residual correlations.
    confidence : float
        Confidence level of the residual-whiteness band.
    fft_window_s : float
        Welch window length (s) of the frequency-response estimate.

    Returns
    -------
    Validation

    Raises
    ------
    NoExcitationError
        No segments given.
    ConfigError
        A segment lacks a state or input the model uses, or its step differs from the
        model's.
    """
    if not segments:
        raise NoExcitationError("no validation segments to validate the model on")
    names = tuple(model.state_names)
    ny = len(names)
    for seg in segments:
        if not np.isclose(seg.dt, model.dt, rtol=1e-3):
            raise ConfigError(
                f"segment {seg.start_s:.2f}-{seg.stop_s:.2f} s has dt {seg.dt:g} s, "
                f"the model dt {model.dt:g} s"
            )
    horizons = _horizon_samples(model.dt, horizons_s)
    err_h = np.zeros((len(horizons), ny))
    norm_h = np.zeros((len(horizons), ny))
    err_free, norm_free = np.zeros(ny), np.zeros(ny)
    err_own, norm_own = np.zeros(ny), np.zeros(ny)
    sq1, n1, sqf, nf = np.zeros(ny), np.zeros(ny), np.zeros(ny), np.zeros(ny)
    per_segment: list[SegmentValidation] = []
    free_runs: list[np.ndarray] = []
    for seg in segments:
        y = _columns(seg, names, "state")
        _columns(seg, model.input_names, "input")
        n = len(seg)
        own = _as_2d(model.simulate(seg), n, ny, "simulate")
        fitted, shift = segment_trim(model, seg, own)  # (this segment's trim)
        one = np.full((n, ny), np.nan)
        many = getattr(fitted, "predict_horizons", None)  # (every horizon, inputs filtered once)
        preds = (many(seg, [int(k) for k in horizons]) if many is not None
                 else [fitted.predict(seg, horizon=int(k)) for k in horizons])
        for i, (k, raw) in enumerate(zip(horizons, preds, strict=True)):
            pred = _as_2d(raw, n, ny, "predict")
            if k == 1:
                one = pred
            e, m = fit_sums(y, pred)
            err_h[i] += e
            norm_h[i] += m
        free = own if fitted is model else _as_2d(fitted.simulate(seg), n, ny, "simulate")
        free_runs.append(free)
        e, m = fit_sums(y, free)
        err_free += e
        norm_free += m
        e, m = fit_sums(y, own)
        err_own += e
        norm_own += m
        for pred, sq, cnt in ((one, sq1, n1), (free, sqf, nf)):
            ok = np.isfinite(y) & np.isfinite(pred)
            sq += np.where(ok, (y - pred) ** 2, 0.0).sum(axis=0)
            cnt += ok.sum(axis=0)
        per_segment.append(
            SegmentValidation(
                start_s=seg.start_s,
                stop_s=seg.stop_s,
                time_s=np.asarray(seg.time_s, dtype=float),
                measured=y,
                one_step=one,
                free_run=free,
                fit_one_step=np.atleast_1d(fit_percent(y, one)),
                fit_free_run=np.atleast_1d(fit_percent(y, free)),
                source=seg.source,
                trim_shift=shift,
                fit_free_run_own_trim=np.atleast_1d(fit_percent(y, own)),
            )
        )
    with np.errstate(divide="ignore", invalid="ignore"):
        fit_h = np.where(norm_h > 0, 100.0 * (1.0 - np.sqrt(err_h / norm_h)), np.nan)
        fit_free = np.where(norm_free > 0, 100.0 * (1.0 - np.sqrt(err_free / norm_free)), np.nan)
        fit_own = np.where(norm_own > 0, 100.0 * (1.0 - np.sqrt(err_own / norm_own)), np.nan)
        rmse1 = np.where(n1 > 0, np.sqrt(sq1 / np.maximum(n1, 1)), np.nan)
        rmsef = np.where(nf > 0, np.sqrt(sqf / np.maximum(nf, 1)), np.nan)
    lam, stable = eigenvalues(model)
    residuals = residual_test(
        [s.measured - s.one_step for s in per_segment],
        [_columns(seg, model.input_names, "input") for seg in segments],
        max_lag=max_lag,
        confidence=confidence,
    )
    chirps = [
        (seg, free) for seg, free in zip(segments, free_runs, strict=True) if seg.source == "sysid"
    ]
    frequency = _chirp_responses(model, chirps, fft_window_s) if chirps else ()
    return Validation(
        state_names=names,
        input_names=tuple(model.input_names),
        dt=float(model.dt),
        horizons=horizons,
        fit_vs_horizon=fit_h,
        fit_free_run=fit_free,
        rmse_one_step=rmse1,
        rmse_free_run=rmsef,
        eigenvalues=lam,
        stable=stable,
        residuals=residuals,
        frequency=frequency,
        segments=tuple(per_segment),
        fit_free_run_own_trim=fit_own,
    )


def residual_test(
    residuals: Sequence[np.ndarray],
    inputs: Sequence[np.ndarray],
    *,
    max_lag: int = 50,
    confidence: float = 0.99,
) -> ResidualTest:
    """Residual autocorrelation and input–residual cross-correlation, pooled over segments.

    Lagged products never pair samples of different segments. Each segment's residuals and
    inputs are taken about their own means; rows with a non-finite residual are dropped
    (only a leading run is expected: the samples a prediction needs to start).

    Parameters
    ----------
    residuals : sequence of numpy.ndarray, each (n_i, ny)
    inputs : sequence of numpy.ndarray, each (n_i, nu)
    max_lag : int
    confidence : float

    Returns
    -------
    ResidualTest

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> t = residual_test([rng.standard_normal((4000, 1))], [rng.standard_normal((4000, 1))])
    >>> bool(t.autocorr[0, 0] == 1.0), bool(t.autocorr_outside[0] < 0.05)
    (True, True)
    """
    ny = residuals[0].shape[1] if residuals else 0
    nu = inputs[0].shape[1] if inputs else 0
    lags = np.arange(max_lag + 1)
    cross_lags = np.arange(-max_lag, max_lag + 1)
    acc = np.zeros((max_lag + 1, ny))
    ccc = np.zeros((2 * max_lag + 1, nu, ny))
    ee = np.zeros(ny)
    uu = np.zeros(nu)
    total = 0
    for e_raw, u_raw in zip(residuals, inputs, strict=True):
        ok = np.all(np.isfinite(e_raw), axis=1) & np.all(np.isfinite(u_raw), axis=1)
        e = e_raw[ok] - e_raw[ok].mean(axis=0)
        u = u_raw[ok] - u_raw[ok].mean(axis=0)
        n = len(e)
        if n < 2:
            continue
        total += n
        ee += (e**2).sum(axis=0)
        uu += (u**2).sum(axis=0)
        for k in lags[lags < n]:
            acc[k] += (e[: n - k] * e[k:]).sum(axis=0)
        for i, k in enumerate(cross_lags):
            if abs(k) >= n:
                continue
            if k >= 0:  # u_t with e_{t+k}
                ccc[i] += u[: n - k].T @ e[k:]
            else:
                ccc[i] += u[-k:].T @ e[: n + k]
    with np.errstate(divide="ignore", invalid="ignore"):
        autocorr = np.where(ee > 0, acc / ee, np.nan)
        scale = np.sqrt(np.outer(uu, ee))
        crosscorr = np.where(scale > 0, ccc / scale, np.nan)
    z = statistics.NormalDist().inv_cdf(0.5 + confidence / 2.0)
    band = z / np.sqrt(total) if total else np.nan
    return ResidualTest(lags, autocorr, cross_lags, crosscorr, float(band), confidence, total)


def _band(segment: Segment) -> tuple[float, float] | None:
    """The chirp band of a segment's SYSTEMID run (Hz), if it declares one."""
    run = segment.sysid
    lo, hi = (None, None) if run is None else (run.f_start_hz, run.f_stop_hz)
    if lo is not None and hi is not None and hi > lo > 0:
        return float(lo), float(hi)
    return None


def frequency_response(
    u: Sequence[np.ndarray],
    y: Sequence[np.ndarray],
    yhat: Sequence[np.ndarray],
    dt: float,
    *,
    window_s: float = 4.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """H1 frequency-response estimates of measured and model output, pooled over segments.

    Welch cross- and auto-spectra (Hann window of ``window_s``, half overlap) of every
    segment are averaged, weighted by segment length.

    Parameters
    ----------
    u, y, yhat : sequence of numpy.ndarray, each (n_i,)
        Input, measured output and model output per segment.
    dt : float
        Sample step (s).
    window_s : float
        Window length (s), shortened to the longest segment.

    Returns
    -------
    freq_hz, measured, coherence, model : numpy.ndarray

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(1)
    >>> u = rng.standard_normal(8000)
    >>> y = 2.0 * u  # a pure gain
    >>> f, h, coh, hm = frequency_response([u], [y], [y], 0.01, window_s=2.0)
    >>> bool(np.allclose(np.abs(h[1:]), 2.0) and np.all(coh[1:] > 0.99))
    True
    """
    longest = max(len(s) for s in u)
    nperseg = max(8, min(round(window_s / dt), longest))
    fs = 1.0 / dt
    suu: Any = 0.0
    syy: Any = 0.0
    suy: Any = 0.0 + 0.0j
    sum_m: Any = 0.0 + 0.0j
    weight = 0.0
    freq: np.ndarray = np.zeros(0)
    diverged = False  # a segment long enough but for the model's non-finite prediction
    for ui, yi, mi in zip(u, y, yhat, strict=True):
        measured_ok = np.isfinite(ui) & np.isfinite(yi)
        ok = measured_ok & np.isfinite(mi)
        ui, yi, mi = ui[ok], yi[ok], mi[ok]
        if len(ui) < nperseg:
            diverged |= int(measured_ok.sum()) >= nperseg
            continue
        w = float(len(ui))
        # each signal's windows transformed once (scipy.signal.welch / csd to rounding)
        fu, fy, fm = (segment_ffts(v, nperseg, detrend=demean) for v in (ui, yi, mi))
        freq = np.fft.rfftfreq(nperseg, 1.0 / fs)
        puu = density(fu, fu, fs, nperseg).real
        pyy = density(fy, fy, fs, nperseg).real
        puy = density(fu, fy, fs, nperseg)
        pum = density(fu, fm, fs, nperseg)
        suu = suu + w * puu
        syy = syy + w * pyy
        suy = suy + w * puy
        sum_m = sum_m + w * pum
        weight += w
    if weight == 0:
        raise NoExcitationError(
            "the model's prediction is not a finite number on the held-out data (it diverges)"
            if diverged else
            f"segments shorter than the {window_s:g} s frequency-response window"
        )
    suu_a, syy_a = np.asarray(suu), np.asarray(syy)
    with np.errstate(divide="ignore", invalid="ignore"):
        measured = np.asarray(suy) / suu_a
        model = np.asarray(sum_m) / suu_a
        coherence = np.abs(np.asarray(suy)) ** 2 / (suu_a * syy_a)
    return freq, measured, np.nan_to_num(coherence, nan=0.0), model


def _chirp_responses(
    model: Model, chirps: Sequence[tuple[Segment, np.ndarray]], window_s: float
) -> tuple[FrequencyResponse, ...]:
    """Frequency responses of the axis's input to its body rate on SYSTEMID segments."""
    out: list[FrequencyResponse] = []
    pairs: list[tuple[str, str]] = []
    axes = {seg.axis for seg, _ in chirps}
    for axis in sorted(axes):
        u_name = f"u_{axis}" if f"u_{axis}" in model.input_names else model.input_names[0]
        rate = RATE_OF.get(axis, "")
        y_name = rate if rate in model.state_names else model.state_names[0]
        if (u_name, y_name) not in pairs:
            pairs.append((u_name, y_name))
    for u_name, y_name in pairs:
        j = model.state_names.index(y_name)
        us, ys, ms = [], [], []
        band = None
        for seg, free in chirps:
            us.append(_columns(seg, [u_name], "input")[:, 0])
            ys.append(_columns(seg, [y_name], "state")[:, 0])
            ms.append(free[:, j])
            band = band or _band(seg)
        longest = max(len(s) for s in us)
        if longest * model.dt < 1.0:
            continue
        freq, h, coh, hm = frequency_response(
            us, ys, ms, model.dt, window_s=min(window_s, longest * model.dt)
        )
        out.append(FrequencyResponse(u_name, y_name, freq, h, coh, hm, band))
    return tuple(out)
