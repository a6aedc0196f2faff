"""The identification core: :func:`identify_segments`, the one path every fit takes, and
:func:`identify`, the state-space model from plain arrays.

:func:`identify` turns arrays (one record, or a list of records fitted together) into the
same :class:`~mavsid.estimators.model.Model` the log pipeline returns: named parameters with
units and standard errors, free-run and k-step rollouts, validation, JSON and python-control
export. The log path's :func:`~mavsid.estimators.axis_fit.fit_axis` names an axis's states
and inputs, takes the known filters from the log's parameters and calls the same core
(:func:`identify_segments`): the input structure searched (when asked,
:func:`~mavsid.estimators.select.search_structure`) or chosen by a
:data:`StructureChooser`, fitted, refined by output error, the structure's spread joined to
the covariance.

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
import math
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from mavsid.data import Segment
from mavsid.errors import ConfigError, DataQualityWarning, NoExcitationError, SolverError
from mavsid.estimators import library
from mavsid.estimators.arrays import records
from mavsid.estimators.base import Estimator
from mavsid.estimators.model import Model
from mavsid.estimators.output_error import output_error_coef, refine_output_error
from mavsid.estimators.plausibility import check_rate_plant, check_sampled_rates
from mavsid.estimators.regressors import InputFilter, Structure
from mavsid.estimators.select import (
    DEFAULT_DELAY_STEP,
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
from mavsid.threads import one_blas_thread

__all__ = [
    "DEFAULT_MAX_DELAY_SAMPLES",
    "StructureChooser",
    "identify",
    "identify_segments",
]

DEFAULT_MAX_DELAY_SAMPLES: int = 10

#: Settings of the ``ls`` estimator that leave its coefficients alone (a neighbouring lag's
#: fit then starts from the search's Gram).
_LS_SETTINGS_KEEPING_COEF = frozenset({"n_bootstrap", "hac", "random_state", "min_blocks"})



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
    :func:`~mavsid.estimators.axis_fit.fit_axis` calls this with an axis's names and the
    log's filters.
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
    return Model.of(st, coef, dt)


def _pick(choice: StructureChoice, base: Structure, dt: float, chooser: StructureChooser
          ) -> tuple[float, float] | None:
    """``chooser``'s (lag, delay) among the search's candidates, None when it gives none
    (the search's own then stands). A pick that agrees with the search's is the chooser's
    too: it decides, the output-error scoring of noisy data does not overrule it."""
    models = {lg: m for lg in choice.ls_coef
              if (m := _search_ls_model(choice, base, dt, lg)) is not None}
    got = chooser(models) if len(models) > 1 else None
    if got is None or got[0] not in choice.by_lag:
        return None
    return float(got[0]), max(float(got[1]), 0.0)


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
