"""The identification core on plain arrays: :func:`identify` (state-space models) and
:func:`regress` (equation-error regression), and the log path's :func:`fit_axis` built on it.

:func:`identify` turns arrays (one record, or a list of records fitted together) into the
same :class:`~mavsid.estimators.model.Model` the log pipeline returns: named parameters with
units and standard errors, free-run and k-step rollouts, validation, JSON and python-control
export. :func:`fit_axis` is what ``mavsid fit`` runs per axis: it names the axis's states and
inputs, takes the known filters from the log's parameters and calls the same core
(:func:`identify_segments`) that :func:`identify` calls.

:func:`regress` is ordinary equation-error regression of a measured quantity on regressors,
with the statistics of the flight-test literature (Klein & Morelli, *Aircraft System
Identification*, ch. 5): conventional standard errors ``s²(XᵀX)⁻¹``, the coloured-residual
correction, t-statistics, R², the predicted squared error (PSE) and stepwise or thresholded
structure selection.

Examples
--------
Two samples of ``x⁺ = a x + b u`` determine ``a`` and ``b``: ``1a + 1b = 2`` and
``2a + 0b = 1.8``.

>>> m = identify([1.0, 2.0, 1.8], [1.0, 0.0, 0.0], dt=1.0)
>>> round(m.params["A_d[x,x]"], 12), round(m.params["B_d[x,u]"], 12)
(0.9, 1.1)

An input that never moves cannot identify its effect:

>>> identify([1.0, 2.0, 1.8, 1.6], [0.0, 0.0, 0.0, 0.0], dt=1.0)
Traceback (most recent call last):
...
mavsid.errors.NoExcitationError: B_d[x,u] unidentifiable: u is zero in the selected segments
"""

from __future__ import annotations

import copy
import itertools
import math
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from mavsid.data import Segment
from mavsid.errors import ConfigError, DataQualityWarning, NoExcitationError, SolverError
from mavsid.estimators import library
from mavsid.estimators._base import Estimator, Gram, solve
from mavsid.estimators.least_squares import thresholded
from mavsid.estimators.model import Model
from mavsid.estimators.output_error import output_error_coef, refine_output_error
from mavsid.estimators.plausibility import check_rate_plant, check_sampled_rates
from mavsid.estimators.regressors import InputFilter, Structure, filters_from_params
from mavsid.estimators.select import (
    AXES,
    DEFAULT_DELAY_STEP,
    DEFAULT_LAGS_S,
    DEFAULT_MAX_DELAY_S,
    DEFAULT_STRUCTURE_TOL,
    ESTIMATORS,
    LAG_OE_TOL,
    LAG_PRUNE,
    ONE_STEP_NOISE,
    StructureChoice,
    make_estimator,
    search_structure,
    with_lag,
)
from mavsid.numerics.stats import bartlett_meat
from mavsid.threads import one_blas_thread

__all__ = [
    "DEFAULT_MAX_DELAY_SAMPLES",
    "RegressionResult",
    "fit_axis",
    "identify",
    "identify_segments",
    "log_params",
    "records",
    "regress",
]

#: Longest delay (samples) :func:`identify` searches with ``delay="search"``.
DEFAULT_MAX_DELAY_SAMPLES: int = 10

#: Settings of the ``ls`` estimator that leave its coefficients alone (a neighbouring lag's
#: fit then starts from the search's Gram).
_LS_SETTINGS_KEEPING_COEF = frozenset({"n_bootstrap", "hac", "random_state", "min_blocks"})


# --------------------------------------------------------------------------- arrays in


def _as_records(a: Any, what: str) -> list[np.ndarray]:
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


def _names(given: Sequence[str] | None, k: int, stem: str, what: str) -> tuple[str, ...]:
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
    xs = _as_records(x, "x")
    us = [np.empty((len(a), 0)) for a in xs] if u is None else _as_records(u, "u")
    if len(us) != len(xs):
        raise ConfigError(f"x has {len(xs)} records, u has {len(us)}")
    for i, (a, b) in enumerate(zip(xs, us, strict=True)):
        if len(a) != len(b):
            raise ConfigError(f"record {i}: x has {len(a)} samples, u has {len(b)}")
    sn = _names(state_names, xs[0].shape[1], "x", "state_names")
    inn = _names(input_names, us[0].shape[1], "u", "input_names")
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


def identify_segments(
    segments: Sequence[Segment],
    outputs: Sequence[str],
    features: Sequence[str],
    inputs: Sequence[str] = (),
    *,
    continuous: bool = False,
    estimator: str | Estimator = "ls",
    filters: Sequence[InputFilter] = (),
    delay: float | str = 0,
    delays: Iterable[float] | None = None,
    delay_step: float = DEFAULT_DELAY_STEP,
    max_delay_s: float | None = None,
    lags_s: Iterable[float] | None = None,
    structure_tol: float = DEFAULT_STRUCTURE_TOL,
    derivative: str = "savgol",
    window: int = 9,
    refine: str | None = None,
    oe_covariance: str = "newey-west",
    var_units: Mapping[str, str] | None = None,
    estimator_options: Mapping[str, object] | None = None,
    choose_structure: StructureChooser | None = None,
) -> Model:
    """Search the input structure (when asked), fit, refine: the one path every fit takes.

    Parameters are those of :func:`identify` (``segments`` instead of arrays; ``delay`` a
    number of samples or ``"search"``; ``max_delay_s`` the longest delay searched;
    ``estimator_options`` the estimator's settings). ``choose_structure``, when the
    structure is searched, receives per candidate lag (s) its least-squares model at its
    best one-step delay and returns the ``(lag_s, delay_samples)`` to fit instead, or None
    to keep the one-step choice (the pipeline passes one that scores the candidates against
    a frequency response measured from an injection, :class:`mavsid.frequency.FrfStructure`).
    A chooser with an ``estimate(model)`` method (the model's coefficients estimated another
    way, or None) has that estimate's spread join the covariance.
    :func:`fit_axis` calls this with an axis's names and the log's filters.
    """
    segments = list(segments)
    if not segments:
        raise NoExcitationError("no segments to fit")
    if refine not in ("auto", "oe", None):
        raise ConfigError(f"refine must be 'auto', 'oe' or None, got {refine!r}")
    if isinstance(estimator, str) and estimator not in ESTIMATORS:
        raise ConfigError(f"unknown estimator {estimator!r}; choose from {sorted(ESTIMATORS)}")
    dt = float(segments[0].dt)
    structure = Structure(outputs=tuple(outputs), features=tuple(features),
                          inputs=tuple(inputs), filters=tuple(filters), continuous=continuous,
                          derivative=derivative, window=window)
    search = isinstance(delay, str) or delays is not None or lags_s is not None
    if isinstance(delay, str) and delay != "search":
        raise ConfigError(f"delay must be a number of samples or 'search', got {delay!r}")
    lag, dly, scan = 0.0, 0.0, None
    picked: tuple[float, float] | None = None
    base = structure
    if search:
        choice = search_structure(
            segments, structure, delay=None if isinstance(delay, str) else float(delay),
            delays=delays, delay_step=delay_step,
            max_delay_s=DEFAULT_MAX_DELAY_SAMPLES * dt if max_delay_s is None else max_delay_s,
            lags_s=lags_s, structure_tol=structure_tol)
        structure, lag, dly, scan = choice.structure, choice.lag_s, choice.delay, choice.scan
        # a chooser (a frequency response against an injection) decides where there is one
        picked = (_pick(choice, base, dt, choose_structure)
                  if choose_structure is not None else None)
        if picked is not None:
            lag, dly = picked
            structure = with_lag(base, lag, dly)
    else:
        dly = float(delay)
        whole = int(np.floor(dly + 1e-9))
        structure = replace(structure, delay=whole, delay_frac=round(dly - whole, 9) % 1.0)
    if not isinstance(estimator, str) and estimator_options:
        raise ConfigError("estimator settings go into the Estimator instance, not identify")

    def fitted(st: Structure, cheap: bool = False) -> tuple[Model, float, SolverError | None]:
        """The estimator's model of ``st``, refined by output error when asked (with the
        refinement's cost; inf and the error when it failed). ``cheap``: without the
        bootstrap and with the plain covariance (the same coefficients and cost, for
        comparing candidates)."""
        # (an Estimator instance is copied: the caller's holds the chosen structure's fit)
        est = (make_estimator(estimator, st, **dict(estimator_options or {}))
               if isinstance(estimator, str) else copy.copy(estimator))
        if cheap and hasattr(est, "n_bootstrap"):
            est.n_bootstrap = 0
        est.fit(segments, st)
        m = est.model_
        if var_units:
            m = replace(m, var_units=dict(var_units))
        if not (refine == "oe" or (refine == "auto" and m.is_affine)):
            return m, math.nan, None
        constraints = est._constraints(st) if hasattr(est, "_constraints") else None
        try:  # (a cheap fit's covariance is not used: the plain one costs least)
            m = refine_output_error(m, segments, covariance="plain" if cheap else oe_covariance,
                                    bounds=constraints)
        except SolverError as exc:
            return m, math.inf, exc
        refinement: Any = dict(m.provenance)["refine"]
        return m, float(refinement["cost"]), None

    def neighbour(lg: float) -> tuple[Model, float, SolverError | None]:
        """A candidate lag (at its best delay) fitted as ``fitted(..., cheap=True)`` does,
        for its coefficients and cost: least squares from the search's Gram and, for a
        one-state affine model, the output-error optimum by exact-Jacobian Gauss–Newton;
        anything else through :func:`fitted`."""
        m0 = _search_ls_model(choice, base, dt, lg)
        if (m0 is None or estimator != "ls" or continuous
                or set(estimator_options or {}) - _LS_SETTINGS_KEEPING_COEF):
            return fitted(with_lag(base, lg, choice.by_lag[lg][1]), cheap=True)
        coef0 = m0.coef
        if not (refine == "oe" or (refine == "auto" and m0.is_affine)):
            return m0, math.nan, None
        # started from the chosen lag's refined pole (nearer than its own least squares)
        start = model.coef if np.array_equal(model.coef != 0, coef0 != 0) else coef0
        got = output_error_coef(replace(m0, coef=start), segments,
                                filtered=choice.inputs.get(lg))
        if got is None:
            return fitted(with_lag(base, lg, choice.by_lag[lg][1]), cheap=True)
        return replace(m0, coef=got[0]), got[1], None

    model, cost, failed = fitted(structure)
    scored: dict[float, tuple[Model, float, SolverError | None]] = {lag: (model, cost, failed)}
    floor = min(v[0] for v in choice.by_lag.values()) if search else math.nan  # best one step
    by_oe = (search and picked is None and math.isfinite(cost) and len(choice.by_lag) > 1
             and _one_step_noise(segments, outputs, floor) > ONE_STEP_NOISE)
    if by_oe:
        # noisy: the lag by the free-run cost (see ONE_STEP_NOISE), the delay per lag by one
        # step
        for lg, (mse, _) in choice.by_lag.items():
            if lg != lag and mse <= floor * (1 + LAG_PRUNE):
                scored[lg] = neighbour(lg)
        lowest = min(c for _, c, _ in scored.values())
        chosen = min(lg for lg, (_, c, _) in scored.items() if c <= lowest * (1 + LAG_OE_TOL))
        if chosen != lag:  # the chosen candidate fitted again with its bootstrap
            lag, dly = chosen, choice.by_lag[chosen][1]
            structure = with_lag(base, lag, dly)
            model, cost, failed = scored[lag] = fitted(structure)
    if failed is not None:
        if refine == "oe":
            raise failed
        name = estimator if isinstance(estimator, str) else estimator.name
        warnings.warn(f"{', '.join(outputs)}: {failed}; keeping the {name} estimate",
                      DataQualityWarning, stacklevel=3)
    neighbours: list[float] = []
    alike: list[float] = []
    if search and len(choice.by_lag) > 1 and failed is None:
        # the lag is resolved only to its grid: the coefficients' spread between the
        # neighbouring lags (each with its best delay) joins their covariance
        lags = sorted(choice.by_lag)
        i = lags.index(lag)
        neighbours = [lags[j] for j in (i - 1, i + 1) if 0 <= j < len(lags)]
        for lg in neighbours:  # (each refined as the chosen one is: the same kind of fit)
            if lg not in scored:
                scored[lg] = neighbour(lg)
        model = _with_structure_spread(model, [scored[lg][0] for lg in neighbours
                                               if scored[lg][2] is None])
        # lags the one-step score cannot tell from the best (within structure_tol of it)
        # are as plausible as the chosen one: the farthest of their fits joins too; so are
        # lags shorter than a sample when the chosen one is (a slow log holds a fraction of
        # a sample of delay and such a lag alike: at 25 Hz a plane's 30-ms servo lag came
        # back as none and B 11 % low at 6 σ)
        sub = lag < dt
        alike = [lg for lg, (mse, _) in choice.by_lag.items()
                 if lg != lag and lg not in neighbours
                 and (mse <= floor * (1 + structure_tol) or (sub and lg < dt))]
        for lg in alike:
            if lg not in scored:
                scored[lg] = neighbour(lg)
        far = _farthest(model, [scored[lg][0] for lg in alike if scored[lg][2] is None])
        if far is None:
            alike = []
        else:
            model = _with_structure_spread(model, [far])
    # the chooser's own estimate (a frequency response against an injection: not biased by
    # the feedback, the time-domain fit may be) joins the covariance as another spread
    estimate = getattr(choose_structure, "estimate", None)
    by_frf = estimate(model) if estimate is not None and failed is None else None
    source = getattr(choose_structure, "estimate_source", _FRF_SOURCE)
    if by_frf is not None:
        model = _with_structure_spread(model, [by_frf])
    if not isinstance(estimator, str):
        estimator.fit(segments, structure)
    prov = dict(model.provenance)
    if scan is not None:
        prov["structure_scan"] = scan
        prov["lag_chosen_by"] = ("frequency response" if picked is not None
                                 else "output error" if by_oe else "one step")
        prov["stderr_includes"] = ("statistical; the lag's grid resolution (the spread to "
                                   f"lags {', '.join(f'{x:g}' for x in neighbours)} s)"
                                   if neighbours else "statistical") + (
            f"; the lags the data cannot tell apart ({', '.join(f'{x:g}' for x in sorted(alike))}"
            " s)" if alike else "") + (
            f"; {source}" if by_frf is not None else "")
    if by_frf is not None:  # (what the verdict compares; JSON-friendly)
        prov["other_estimate"] = {
            "by": source, "params": {k: float(v) for k, v in by_frf.params.items()}}
    prov["filters"] = [f.to_dict() for f in structure.filters]
    prov["lag_s"] = lag
    prov["delay_s"] = dly * dt
    return replace(model, provenance=prov)


#: what a chooser's estimate is, unless it says (``estimate_source``)
_FRF_SOURCE = "the estimate from the frequency response against the injection"

#: ``choose_structure`` of :func:`identify_segments`: per candidate lag (s) its least-squares
#: model -> the (lag s, delay samples) to fit, or None.
StructureChooser = Callable[[Mapping[float, Model]], "tuple[float, float] | None"]


def _search_ls_model(choice: StructureChoice, base: Structure, dt: float, lag: float
                     ) -> Model | None:
    """The search's least-squares model of a candidate lag at its best delay (from the
    search's Gram), None when the search kept none."""
    coef = choice.ls_coef.get(lag)
    if coef is None:
        return None
    st = with_lag(base, lag, choice.by_lag[lag][1])
    return Model(st.outputs, st.inputs, st.features, coef, dt, delay=st.delay,
                 filters=st.filters, delay_frac=st.delay_frac)


def _pick(choice: StructureChoice, base: Structure, dt: float, chooser: StructureChooser
          ) -> tuple[float, float] | None:
    """``chooser``'s (lag, delay) among the search's candidates, None to keep its own."""
    models = {lg: m for lg in choice.ls_coef
              if (m := _search_ls_model(choice, base, dt, lg)) is not None}
    got = chooser(models) if len(models) > 1 else None
    if got is None or got[0] not in choice.by_lag:
        return None
    lag, dly = float(got[0]), max(float(got[1]), 0.0)
    return None if (lag, dly) == (choice.lag_s, choice.delay) else (lag, dly)


def _farthest(model: Model, others: Sequence[Model]) -> Model | None:
    """The model among ``others`` whose coefficients differ most from ``model``'s (the
    largest relative difference of any coefficient); None when there are none."""
    ref = np.asarray(model.coef, float)
    scale = np.where(ref != 0, np.abs(ref), np.inf)
    best, far = 0.0, None
    for o in others:
        if np.shape(o.coef) != ref.shape:
            continue
        d = float(np.nanmax(np.abs(np.asarray(o.coef, float) - ref) / scale))
        if d > best:
            best, far = d, o
    return far


def _with_structure_spread(model: Model, others: Sequence[Model]) -> Model:
    """``model`` with the spread of its coefficients to ``others`` (the neighbouring lags'
    fits) added to its covariance: half the difference between two neighbours, or the
    difference to one, per output as a rank-one term; standard errors follow."""
    if model.covariance is None or not others:
        return model
    ref = np.asarray(model.coef, float)
    diffs = [np.asarray(o.coef, float) - ref for o in others if np.shape(o.coef) == ref.shape]
    if not diffs:
        return model
    d = (diffs[1] - diffs[0]) / 2.0 if len(diffs) == 2 else diffs[0]
    d = np.where(model.coef != 0, np.nan_to_num(d), 0.0)
    cov = np.array(model.covariance, dtype=float, copy=True)
    for i in range(cov.shape[0]):
        cov[i] = cov[i] + np.outer(d[:, i], d[:, i])
    se = model.coef_stderr
    if se is not None:
        var = np.stack([np.diag(c) for c in cov], axis=1)
        se = np.where(np.isfinite(se), np.sqrt(np.clip(var, 0.0, None)), se)
    return replace(model, covariance=cov, coef_stderr=se)


def _one_step_noise(segments: Sequence[Segment], outputs: Sequence[str], best: float
                    ) -> float:
    """The best one-step residual's RMS (``best``: its mean square) over the outputs' RMS
    about their mean (1 − the one-step fit as a fraction)."""
    ys = np.concatenate([np.column_stack([s.states[:, s.state_names.index(o)]
                                          for o in outputs]) for s in segments
                         if all(o in s.state_names for o in outputs)])
    spread = float(np.nanmean(np.nanvar(ys, axis=0))) if ys.size else 0.0
    return math.sqrt(best / spread) if spread > 0 else 0.0


@one_blas_thread
def identify(
    x: Any,
    u: Any = None,
    dt: float = 1.0,
    *,
    kind: str = "discrete",
    features: Sequence[str] | None = None,
    estimator: str | Estimator = "ls",
    delay: float | str = 0,
    state_names: Sequence[str] | None = None,
    input_names: Sequence[str] | None = None,
    units: Mapping[str, str] | None = None,
    outputs: Sequence[str] | None = None,
    bias: bool = False,
    filters: Sequence[InputFilter] = (),
    max_delay: int = DEFAULT_MAX_DELAY_SAMPLES,
    lags_s: Iterable[float] | None = None,
    derivative: str = "savgol",
    window: int = 9,
    refine: str | None = None,
    oe_covariance: str = "cramer-rao",
    expect_positive: bool = True,
    **estimator_kwargs: object,
) -> Model:
    """Identify ``x[k+1] = Θᵀφ(x[k], u[k−d])`` or ``ẋ = Θᵀφ(x, u(t−d·dt))`` from arrays.

    Parameters
    ----------
    x : array_like (n,) or (n, nx), or a list of such records
        Measured states. Several records are fitted together; no row pairs the end of one
        record with the start of the next, and derivatives are taken within each record.
    u : array_like (n,) or (n, nu), or a list (one per record), optional
        Inputs (zero-order hold between samples).
    dt : float
        Sample time, s.
    kind : {"discrete", "continuous"}
        Next sample (``A_d``, ``B_d``, ``c_d``; the continuous-time equivalents are reported
        too) or time derivative (Savitzky–Golay by default, ``derivative="tv"`` for
        total-variation regularisation) as the target.
    features : sequence of str, optional
        Regressors, named as in :mod:`mavsid.estimators.library` (``"x"``, ``"u"``,
        ``"1"``, ``"x*u"``, ``"sin(theta)"``...). Default: the modelled states, the inputs
        and, with ``bias=True``, ``"1"``.
    estimator : str or Estimator
        ``"ls"``, ``"ridge"``, ``"l1"``, ``"elasticnet"``, ``"stlsq"`` or an instance.
    delay : float or "search"
        Input delay in samples (fractions allowed), or ``"search"``: chosen by the one-step
        residual among ``0 … max_delay`` samples (then fractions around the best).
    state_names, input_names : sequence of str, optional
        Column names (default ``x``/``x1…``, ``u``/``u1…``).
    units : Mapping[str, str], optional
        Units of states and inputs; parameter units are derived from them.
    outputs : sequence of str, optional
        The modelled states (default: all); features may use the others as measured.
    bias : bool
        Add the constant term ``"1"`` to the default features.
    filters : sequence of InputFilter
        Known linear filters applied to the inputs (e.g. a sensor's low-pass).
    max_delay : int
        Longest delay searched with ``delay="search"``, samples.
    lags_s : iterable of float, optional
        Candidate first-order input lags (s) searched with the delay.
    derivative, window : str, int
        Continuous time: derivative method and Savitzky–Golay window (samples).
    refine : {None, "oe", "auto"}
        ``"oe"``: output-error (free-run) estimation started from the equation-error fit
        (linear models in the states): every record simulated from its first sample with
        the measured inputs, the squared free-run error minimised. ``"auto"``: only when
        the states enter linearly.
    oe_covariance : {"cramer-rao", "newey-west"}
        Covariance of the output-error estimate: the Cramér–Rao bound for white output
        noise, ``(Σₜ Jₜᵀ R̂⁻¹ Jₜ)⁻¹``, or the Newey–West sandwich (coloured residuals).
    expect_positive : bool
        The states are rates of a physical plant sampled above their bandwidth, driven by
        the input with a positive effectiveness (u → rate): refuse an output whose lag-1
        autocorrelation is below 0 (aliased; :mod:`mavsid.estimators.plausibility`) and, for
        one output and one input, a fitted effectiveness ≤ 0 or a pole the sampling cannot
        hold. False for any other system (a discrete process that alternates, a plant that
        reverses its input).
    **estimator_kwargs
        Passed to the estimator (``alpha``, ``threshold``, ``n_bootstrap``, ``bounds``...).

    Returns
    -------
    Model

    Raises
    ------
    NoExcitationError
        A parameter cannot be identified (the message names it and the cause).
    ImplausibleModelError
        With ``expect_positive``: the output is aliased, or the fit is not a rate plant
        (the message says which and why).

    Examples
    --------
    A pendulum ``θ̈ = −c sin θ`` swung to 2.5 rad, library ``[1, θ, sin θ]`` for ``ω̇``;
    thresholding (STLSQ) removes the small terms the derivative errors leave:

    >>> import numpy as np
    >>> from scipy.integrate import solve_ivp
    >>> c, dt = 9.81, 0.01
    >>> t = np.arange(0, 10, dt)
    >>> sol = solve_ivp(lambda _, s: [s[1], -c * np.sin(s[0])], (0, 10), [2.5, 0.0],
    ...                 t_eval=t, rtol=1e-11, atol=1e-11)
    >>> m = identify(sol.y.T, dt=dt, kind="continuous", state_names=("theta", "omega"),
    ...              outputs=("omega",), features=("1", "theta", "sin(theta)"),
    ...              estimator="stlsq", threshold=0.05, n_bootstrap=0)
    >>> m.coef[:, 0].round(3).tolist()
    [0.0, 0.0, -9.81]
    """
    if kind not in ("discrete", "continuous"):
        raise ConfigError(f"kind must be 'discrete' or 'continuous', got {kind!r}")
    segs = records(x, u, dt, state_names=state_names, input_names=input_names)
    sn, inn = segs[0].state_names, segs[0].input_names
    outs = tuple(outputs) if outputs is not None else sn
    unknown = set(outs) - set(sn)
    if unknown:
        raise ConfigError(f"outputs {sorted(unknown)} are not states {sn}")
    feats = tuple(features) if features is not None else library.library(
        outs, inn, (library.BIAS,) if bias else ())
    missing = set(library.variables_of(feats)) - set(sn) - set(inn)
    if missing:
        raise ConfigError(f"features use unknown variables {sorted(missing)}; states {sn}, "
                          f"inputs {inn}")
    if expect_positive:
        check_sampled_rates(segs, outs)
    model = identify_segments(
        segs, outs, feats, tuple(v for v in inn if v in library.variables_of(feats)),
        continuous=kind == "continuous", estimator=estimator, filters=filters, delay=delay,
        max_delay_s=max_delay * float(dt), lags_s=lags_s, derivative=derivative,
        window=window, refine=refine, oe_covariance=oe_covariance, var_units=units,
        estimator_options=estimator_kwargs)
    if expect_positive:
        check_rate_plant(model)
    return model


# --------------------------------------------------------------------------- the log path


def log_params(segments: Iterable[Segment], params: Mapping[str, float] | None = None
               ) -> dict[str, float]:
    """The log parameters to use: ``params`` if given, else ``segment.meta['params']``."""
    if params is not None:
        return dict(params)
    for s in segments:
        got = s.meta.get("params") if isinstance(s.meta, Mapping) else None
        if isinstance(got, Mapping) and got:
            return {str(k): float(v) for k, v in got.items()
                    if isinstance(v, (int, float, np.floating))}
    return {}


@one_blas_thread
def fit_axis(
    segments: Sequence[Segment],
    axis: str,
    estimator: str = "ls",
    *,
    params: Mapping[str, float] | None = None,
    filters: Sequence[InputFilter] | None = None,
    delays: Iterable[float] | None = None,
    delay: float | None = None,
    delay_step: float = DEFAULT_DELAY_STEP,
    max_delay_s: float = DEFAULT_MAX_DELAY_S,
    lags_s: Iterable[float] | None = DEFAULT_LAGS_S,
    structure_tol: float = DEFAULT_STRUCTURE_TOL,
    inputs: Sequence[str] | None = None,
    bias: bool = True,
    continuous: bool = False,
    features: Sequence[str] = (),
    refine: str | None = "auto",
    choose_structure: StructureChooser | None = None,
    **estimator_kwargs: object,
) -> Model:
    """Choose the structure for one axis from the data and the log, fit it, return the model.

    The multicopter rate loop's structure: first-order rate dynamics per axis in discrete
    time, ``p[k+1] = a p[k] + b ũ[k-d] + c`` (reported also in continuous time: ``A[p,p]``
    in 1/s, ``B[p,u_roll]`` the control effectiveness in rad/s² per unit of controller
    output, ``c[p]`` the trim offset), with ``ũ`` the input through the log's known
    measurement filters (ArduPilot ``INS_GYRO_FILTER``, see
    :func:`~mavsid.estimators.regressors.filters_from_params`), a first-order input lag and
    the delay chosen together (:func:`~mavsid.estimators.select.search_structure`), then the
    coefficients refined by output error. It is :func:`identify_segments` with the axis's
    names and the log's filters.

    Parameters
    ----------
    segments : sequence of Segment
        Segments whose ``axis`` is another attitude axis are left out when at least one
        segment is for ``axis`` (or ``"all"``).
    axis : {"roll", "pitch", "yaw", "all"}
        ``"all"``: the coupled p/q/r model with all three inputs.
    estimator : str
        ``ls``, ``ridge``, ``l1``, ``elasticnet`` or ``stlsq``.
    params : Mapping, optional
        The log's parameters (default: ``segment.meta['params']``); used for known filters.
    filters : sequence of InputFilter, optional
        Override the filters derived from ``params`` (``()`` for none).
    delays : iterable of float, optional
        Candidate delays in samples; fractions allowed. Default: whole samples up to
        ``max_delay_s``, then steps of ``delay_step`` around the best.
    delay : float, optional
        Fix the delay (samples) instead of searching.
    delay_step, max_delay_s, lags_s, structure_tol
        The search (see :func:`~mavsid.estimators.select.search_structure`; defaults are the
        ``DEFAULT_*`` constants of :mod:`mavsid.estimators.select`).
    inputs : sequence of str, optional
        Inputs (default: the axis's own).
    bias : bool
        Include the constant term.
    continuous : bool
        Continuous-time regression (Savitzky–Golay derivatives) instead of discrete time.
    features : sequence of str
        Extra library terms (e.g. ``library.state_input(...)``).
    refine : {"auto", "oe", None}
        ``"oe"``: refine the estimator's coefficients by output error, i.e. so that the free
        run follows the training data (:mod:`~mavsid.estimators.output_error`); standard
        errors then come from its Newey–West sandwich covariance. ``"auto"`` (default): do
        so when the modelled states enter linearly, not for nonlinear libraries. None: the
        estimator's equation-error result as is.
    choose_structure : callable, optional
        Chooses the lag and delay among the search's candidates instead of the one-step
        score (see :func:`identify_segments`).
    **estimator_kwargs
        Passed to the estimator (``alpha``, ``n_bootstrap``, ...).

    Notes
    -----
    Bounded fits: ``estimator="l1"`` (or ``"elasticnet"``) takes ``bounds={name: (low, high)}`` and
    ``signs={name: ±1}`` on the fitted (discrete-time) parameters; ``alpha=0.0`` makes it
    bounded least squares. The output-error refinement keeps the same bounds. For a first-
    order discrete model, damping ``A[p,p] <= 0`` is ``A_d[p,p] <= 1`` and the control
    effectiveness ``B[p,u_roll]`` has the sign of ``B_d[p,u_roll]``::

        fit_axis(segs, "roll", "l1", alpha=0.0, bounds={"A_d[p,p]": (-np.inf, 1.0)},
                 signs={"B_d[p,u_roll]": +1})

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(3)
    >>> u = rng.standard_normal(2000) * 0.05
    >>> p = np.zeros(2000)
    >>> for k in range(1999):  # the input before the record is taken as its first value
    ...     p[k + 1] = 0.98 * p[k] + 0.4 * u[max(k - 3, 0)]
    >>> seg = Segment(np.arange(2000) * 0.0025, p[:, None], u[:, None], ("p",), ("u_roll",),
    ...               0.0025, "roll", "sysid")
    >>> m = fit_axis([seg], "roll", n_bootstrap=0)
    >>> m.delay, round(m.params["B_d[p,u_roll]"], 6)
    (3, 0.4)
    """
    if axis not in AXES:
        raise ConfigError(f"unknown axis {axis!r}; choose from {sorted(AXES)}")
    if refine not in ("auto", "oe", None):
        raise ConfigError(f"refine must be 'auto', 'oe' or None, got {refine!r}")
    if estimator not in ESTIMATORS:
        raise ConfigError(f"unknown estimator {estimator!r}; choose from {sorted(ESTIMATORS)}")
    segments = list(segments)
    if not segments:
        raise NoExcitationError(f"no segments to fit the {axis} axis")
    mine = [s for s in segments if s.axis in (axis, "all")]
    if mine and len(mine) < len(segments):
        segments = mine
    outputs, default_inputs = AXES[axis]
    linear = tuple(inputs) if inputs is not None else default_inputs
    ins = linear + tuple(v for v in library.variables_of(features)
                         if v.startswith("u_") and v not in linear)
    dt = float(segments[0].dt)
    flt = tuple(filters) if filters is not None else filters_from_params(
        log_params(segments, params), dt)
    feats = library.library(outputs, linear, (library.BIAS,) if bias else (), features)
    model = identify_segments(
        segments, outputs, feats, ins, continuous=continuous, estimator=estimator,
        filters=flt, delay="search" if delay is None else float(delay), delays=delays,
        delay_step=delay_step, max_delay_s=max_delay_s,
        lags_s=(0.0,) if lags_s is None else lags_s,
        structure_tol=structure_tol, refine=refine, estimator_options=estimator_kwargs,
        choose_structure=choose_structure)
    prov = dict(model.provenance)
    prov["axis"] = axis
    return replace(model, provenance=prov)


# --------------------------------------------------------------------------- regression


@dataclass(frozen=True)
class RegressionResult:
    """Equation-error regression ``y = Xθ + v`` and its statistics.

    Attributes
    ----------
    names : tuple of str
        Regressor names (all candidates, in the order given).
    coef : numpy.ndarray, shape (p,)
        Estimates (0 for a regressor left out by structure selection).
    selected : numpy.ndarray of bool, shape (p,)
        Regressors in the model.
    cov, cov_colored : numpy.ndarray, shape (p, p)
        Conventional ``s²(XᵀX)⁻¹`` and coloured-residual corrected covariance (NaN rows and
        columns for regressors left out).
    colored_method : str
        Which correction ``cov_colored`` is.
    s2 : float
        Fit-error variance ``vᵀv / (N − p)``.
    r2 : float
        Coefficient of determination ``1 − vᵀv / Σ(y − ȳ)²``.
    pse : float
        Predicted squared error ``vᵀv/N + σ²_max p/N``, ``σ²_max = Σ(y − ȳ)²/N``.
    residuals : numpy.ndarray, shape (N,)
        ``y − Xθ`` (records concatenated).
    n : int
        Rows.
    alpha : float
        Ridge weight λ of ``min ‖y − Xθ‖² + λ‖θ‖²`` (0: least squares).
    selection : str
        The structure-selection criterion used and what it did ("none" when all kept).
    """

    names: tuple[str, ...]
    coef: np.ndarray
    selected: np.ndarray
    cov: np.ndarray = field(repr=False)
    cov_colored: np.ndarray = field(repr=False)
    colored_method: str
    s2: float
    r2: float
    pse: float
    residuals: np.ndarray = field(repr=False)
    n: int
    alpha: float = 0.0
    selection: str = "none"

    @property
    def params(self) -> dict[str, float]:
        """Name -> estimate."""
        return {k: float(v) for k, v in zip(self.names, self.coef, strict=True)}

    def _diag(self, cov: np.ndarray) -> dict[str, float]:
        se = np.sqrt(np.clip(np.diag(cov), 0, None))
        return {k: float(v) for k, v in zip(self.names, se, strict=True)}

    @property
    def stderr(self) -> dict[str, float]:
        """Name -> conventional standard error ``sqrt(s² (XᵀX)⁻¹)ⱼⱼ``."""
        return self._diag(self.cov)

    @property
    def stderr_colored(self) -> dict[str, float]:
        """Name -> coloured-residual corrected standard error (see ``colored_method``)."""
        return self._diag(self.cov_colored)

    @property
    def tstat(self) -> dict[str, float]:
        """Name -> ``θⱼ / stderr_colored[j]`` (NaN for regressors left out)."""
        se = self.stderr_colored
        with np.errstate(divide="ignore", invalid="ignore"):
            return {k: float(np.float64(v) / se[k]) if s else float("nan")
                    for (k, v), s in zip(self.params.items(), self.selected, strict=True)}

    @property
    def tstat_conventional(self) -> dict[str, float]:
        """Name -> ``θⱼ / stderr[j]``."""
        se = self.stderr
        with np.errstate(divide="ignore", invalid="ignore"):
            return {k: float(np.float64(v) / se[k]) if s else float("nan")
                    for (k, v), s in zip(self.params.items(), self.selected, strict=True)}

    def predict(self, X: Any) -> np.ndarray:
        """``X θ`` for new regressor rows."""
        return np.asarray(np.asarray(X, dtype=float).reshape(-1, len(self.names)) @ self.coef)

    def summary(self) -> str:
        """A table: estimate, conventional and corrected standard error, t, per regressor."""
        lines = [f"{'':>12} {'estimate':>12} {'stderr':>11} {'stderr_col':>11} {'t':>8}"]
        se, sc, t = self.stderr, self.stderr_colored, self.tstat
        for k, v in self.params.items():
            lines.append(f"{k:>12} {v:12.6g} {se[k]:11.4g} {sc[k]:11.4g} {t[k]:8.2f}")
        lines.append(f"N={self.n} s2={self.s2:.4g} R2={self.r2:.4f} PSE={self.pse:.4g}; "
                     f"corrected: {self.colored_method}; selection: {self.selection}")
        return "\n".join(lines)


def _autocorrelation(v: Sequence[np.ndarray], n: int) -> np.ndarray:
    """``R̂(k) = (1/N) Σᵢ v(i) v(i+k)``, pooled over records (lags within a record only)."""
    longest = max(len(e) for e in v)
    r = np.zeros(longest)
    for e in v:
        m = len(e)
        nfft = 1 << int(np.ceil(np.log2(max(2 * m, 2))))
        f = np.fft.rfft(e, nfft)
        r[:m] += np.fft.irfft(f * np.conj(f), nfft)[:m]
    return r / n


def _toeplitz_times(r: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``T x`` with ``T[i, j] = r[|i − j|]`` (all lags of the record), by FFT."""
    m = len(x)
    two = np.concatenate([r[m - 1 : 0 : -1], r[:m]])  # lags −(m−1) … m−1
    nfft = 1 << int(np.ceil(np.log2(3 * m)))
    conv = np.fft.irfft(np.fft.rfft(two, nfft)[:, None] * np.fft.rfft(x, nfft, axis=0), nfft,
                        axis=0)
    return np.asarray(conv[m - 1 : 2 * m - 1])


@one_blas_thread
def regress(
    X: Any,
    y: Any,
    names: Sequence[str] | None = None,
    *,
    alpha: float = 0.0,
    select: str | None = None,
    threshold: float = 0.05,
    f_in: float = 4.0,
    f_out: float = 4.0,
    keep: Sequence[str] = (),
    colored: str = "all-lags",
    lags: int | None = None,
) -> RegressionResult:
    """Equation-error least squares ``y = Xθ + v`` with textbook statistics.

    Parameters
    ----------
    X : array_like (N, p), or a list of records
        Regressors (include a column of ones for a bias).
    y : array_like (N,), or a list of records
        Measured quantity.
    names : sequence of str, optional
        Regressor names (default ``x1 … xp``).
    alpha : float
        Ridge weight λ: ``θ = (XᵀX + λI)⁻¹Xᵀy`` (every regressor penalised).
    select : {None, "stepwise", "threshold"}
        ``"stepwise"``: Klein & Morelli's stepwise regression — the candidate with the
        largest partial F enters while it is ≥ ``f_in``, a regressor leaves when its partial F
        drops below ``f_out`` (the partial F tests use least squares, then the selected
        model is fitted with ``alpha``). ``"threshold"``: sequentially thresholded (ridge)
        least squares, a regressor leaves while its standardised coefficient
        ``|θⱼ| rms(xⱼ) / rms(y)`` is below ``threshold``. ``keep`` names stay in either way.
    threshold : float
        ``select="threshold"``: the relative threshold (dimensionless).
    f_in, f_out : float
        ``select="stepwise"``: partial F to enter, to stay.
    keep : sequence of str
        Regressors never left out by selection (e.g. the bias).
    colored : {"all-lags", "newey-west"}
        Correction of the covariance for coloured residuals: ``"all-lags"`` is Klein &
        Morelli's ``(XᵀX)⁻¹[Σᵢ Σⱼ x(i) R̂ᵥᵥ(i−j) x(j)ᵀ](XᵀX)⁻¹`` with the residual
        autocorrelation ``R̂ᵥᵥ(k) = (1/N) Σᵢ v(i) v(i+k)`` over every lag (pooled over records;
        biased low for a bias column, whose residuals sum to zero); ``"newey-west"`` is the
        Bartlett-weighted sandwich. Sums never cross a record's end.
    lags : int, optional
        ``"all-lags"``: truncate the sum at this lag. ``"newey-west"``: Bartlett lags
        (default ``⌈4 (N/100)^{2/9}⌉``).

    Returns
    -------
    RegressionResult

    Raises
    ------
    NoExcitationError
        A regressor is zero or regressors are collinear (named), or fewer rows than
        regressors.

    Examples
    --------
    The lecture's two rows, and a third row that is their sum (a linear combination, so
    Θ is unchanged):

    >>> r = regress([[1.0, 1.0], [2.0, 0.0]], [2.0, 1.8], names=["a", "b"])
    >>> {k: round(v, 12) for k, v in r.params.items()}
    {'a': 0.9, 'b': 1.1}
    >>> r3 = regress([[1.0, 1.0], [2.0, 0.0], [3.0, 1.0]], [2.0, 1.8, 3.8], names=["a", "b"])
    >>> {k: round(v, 12) for k, v in r3.params.items()}
    {'a': 0.9, 'b': 1.1}

    An input column of zeros:

    >>> regress([[1.0, 0.0], [2.0, 0.0], [1.5, 0.0]], [2.0, 1.8, 1.5], names=["a", "b"])
    Traceback (most recent call last):
    ...
    mavsid.errors.NoExcitationError: b unidentifiable: regressor b is zero

    Ridge is ``Θ = X₊Zᵀ(ZZᵀ + λI)⁻¹`` (rows of ``Z`` regressors, columns samples):

    >>> import numpy as np
    >>> Z = np.array([[1.0, 2.0, 1.8, 0.5], [1.0, 0.0, 0.0, 1.0]])
    >>> Xp = np.array([[2.0, 1.8, 1.6, 1.4]])
    >>> lam = 0.5
    >>> ridge = regress(Z.T, Xp[0], names=["a", "b"], alpha=lam).coef
    >>> textbook = Xp @ Z.T @ np.linalg.inv(Z @ Z.T + lam * np.eye(2))
    >>> ridge.round(10).tolist(), textbook.round(10).tolist()
    ([0.8825710754, 0.8304573548], [[0.8825710754, 0.8304573548]])
    """
    xs = _as_records(X, "X")
    ys = _as_records(y, "y")
    if len(xs) != len(ys):
        raise ConfigError(f"X has {len(xs)} records, y has {len(ys)}")
    p = xs[0].shape[1]
    for i, (a, b) in enumerate(zip(xs, ys, strict=True)):
        if a.shape[1] != p or b.shape[1] != 1 or len(a) != len(b):
            raise ConfigError(f"record {i}: X {a.shape} and y {b.shape} do not match "
                              f"(N, {p}) and (N,)")
    nm = _names(names, p, "x", "names")
    if select not in (None, "stepwise", "threshold"):
        raise ConfigError(f"select must be None, 'stepwise' or 'threshold', got {select!r}")
    if colored not in ("all-lags", "newey-west"):
        raise ConfigError(f"colored must be 'all-lags' or 'newey-west', got {colored!r}")
    if not 0 <= alpha < math.inf:
        raise ConfigError(f"alpha must be a finite number >= 0, got {alpha}")
    unknown = set(keep) - set(nm)
    if unknown:
        raise ConfigError(f"keep names unknown regressors {sorted(unknown)}")
    xa, ya = np.concatenate(xs), np.concatenate(ys)
    ok = np.isfinite(xa).all(axis=1) & np.isfinite(ya[:, 0])
    if not ok.all():
        raise ConfigError(f"{int((~ok).sum())} rows with non-finite values; remove them first")
    n = len(xa)
    g = Gram.of(xa, ya)
    _check_columns(g, nm)
    keep_mask = np.array([k in keep for k in nm])
    lam_rows = alpha / n
    if select == "threshold":
        act = thresholded(g, threshold, keep_mask, lam_rows, standardize=False)[:, 0] != 0
        how = f"threshold: |θⱼ| rms(xⱼ)/rms(y) >= {threshold:g}"
    elif select == "stepwise":
        act, how = _stepwise(g, f_in, f_out, keep_mask, nm)
    else:
        act, how = np.ones(p, bool), "none"
    dropped = [k for k, a in zip(nm, act, strict=True) if not a]
    if dropped:
        how += f"; left out {', '.join(dropped)}"
    coef = solve(g, lam_rows, None, act, standardize=False)[:, 0]
    v = ya[:, 0] - xa @ coef
    k = int(act.sum())
    dof = n - k
    sse = float(v @ v)
    s2 = sse / dof if dof > 0 else float("nan")
    xx = g.zz[np.ix_(act, act)]
    bread = np.linalg.inv(xx + alpha * np.eye(k))
    cov_a = s2 * bread @ xx @ bread
    xsel = [a[:, act] for a in xs]
    edges = np.cumsum([0] + [len(a) for a in xs])
    vs = [v[a:b] for a, b in itertools.pairwise(edges)]
    if colored == "all-lags":
        r = _autocorrelation(vs, n)
        if lags is not None:
            r[int(lags) + 1 :] = 0.0
        meat = sum(xr.T @ _toeplitz_times(r[: len(xr)], xr) for xr in xsel)
        method = ("Klein-Morelli: residual autocorrelation over all lags" if lags is None
                  else f"Klein-Morelli: residual autocorrelation up to lag {int(lags)}")
    else:
        nl = int(np.ceil(4 * (n / 100.0) ** (2.0 / 9.0))) if lags is None else int(lags)
        meat = sum(bartlett_meat(xr * e[:, None], nl) for xr, e in zip(xsel, vs, strict=True))
        method = f"Newey-West (Bartlett, {nl} lags)"
    cov_c = bread @ np.asarray(meat) @ bread
    cov = np.full((p, p), np.nan)
    cov_col = np.full((p, p), np.nan)
    cov[np.ix_(act, act)] = cov_a
    cov_col[np.ix_(act, act)] = cov_c
    sst = float(((ya[:, 0] - ya[:, 0].mean()) ** 2).sum())
    r2 = 1.0 - sse / sst if sst > 0 else float("nan")
    pse = sse / n + (sst / n) * k / n
    return RegressionResult(nm, coef, act, cov, cov_col, method, s2, r2, pse, v, n,
                            float(alpha), how)


def _check_columns(g: Gram, names: Sequence[str]) -> None:
    """Zero regressors, too few rows, collinear regressors -> NoExcitationError."""
    p = len(names)
    if g.n < p:
        raise NoExcitationError(f"{', '.join(names)} unidentifiable: only {g.n} rows for "
                                f"{p} regressors")
    d = np.diag(g.zz)
    for j in map(int, np.flatnonzero(d <= 0)):
        raise NoExcitationError(f"{names[j]} unidentifiable: regressor {names[j]} is zero")
    s = np.sqrt(d)
    lam, vec = np.linalg.eigh(g.zz / np.outer(s, s))
    if lam[0] <= lam[-1] * 1e-12:
        w = np.abs(vec[:, 0])
        js = [int(j) for j in np.flatnonzero(w > 0.2 * w.max())]
        raise NoExcitationError(f"{', '.join(names[j] for j in js)} unidentifiable: "
                                f"regressors {' and '.join(names[j] for j in js)} are collinear")


def _stepwise(g: Gram, f_in: float, f_out: float, keep: np.ndarray, names: Sequence[str]
              ) -> tuple[np.ndarray, str]:
    """Forward-backward stepwise regression by partial F (Klein & Morelli §5.4.1)."""
    p = g.zz.shape[0]

    def sse(act: np.ndarray) -> float:
        if not act.any():
            return float(g.yy[0, 0])
        return float(g.sse(solve(g, 0.0, None, act, standardize=False))[0])

    act = keep.copy()
    steps = []
    for _ in range(4 * p):
        changed = False
        base = sse(act)
        k = int(act.sum())
        out = [j for j in range(p) if not act[j]]
        if out and g.n - k - 1 > 0:
            trial = []
            for j in out:
                a2 = act.copy()
                a2[j] = True
                s_new = sse(a2)
                s2 = s_new / (g.n - k - 1)
                trial.append(((base - s_new) / s2 if s2 > 0 else np.inf, j))
            f, j = max(trial)
            if f >= f_in:
                act[j] = True
                steps.append(f"+{names[j]} (F={f:.3g})")
                changed = True
        base = sse(act)
        k = int(act.sum())
        s2 = base / (g.n - k) if g.n > k else np.inf
        removable = [j for j in range(p) if act[j] and not keep[j]]
        if removable and s2 > 0:
            trial = []
            for j in removable:
                a2 = act.copy()
                a2[j] = False
                trial.append(((sse(a2) - base) / s2, j))
            f, j = min(trial)
            if f < f_out:
                act[j] = False
                steps.append(f"-{names[j]} (F={f:.3g})")
                changed = True
        if not changed:
            break
    how = (f"stepwise: partial F to enter >= {f_in:g}, to stay >= {f_out:g}"
           + (f" ({', '.join(steps)})" if steps else ""))
    return act, how
