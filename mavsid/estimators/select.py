"""Structure from data: which inputs, which known filters, which delay; then fit one axis.

:func:`fit_axis` is what the ``mavsid fit`` pipeline calls per axis. The structure it fits is
physically meaningful for a multicopter's rate loop:

* first-order rate dynamics per axis in discrete time, ``p[k+1] = a p[k] + b ũ[k-d] + c``,
  reported also in continuous time (``A[p,p]`` in 1/s, ``B[p,u_roll]`` the control
  effectiveness in rad/s² per unit of controller output, ``c[p]`` the trim offset);
* ``ũ`` is the input passed through the known measurement filters of the log's parameters
  (ArduPilot ``INS_GYRO_FILTER``, see :func:`~mavsid.estimators.regressors.filters_from_params`)
  so that the filter's lag is not absorbed into a smaller gain;
* the coefficients refined by output error (free-run error minimised) unless
  ``refine=None``;
* a first-order input lag (the motors' response, not in any log parameter) and the delay
  ``d`` (whole samples, then fractions) chosen together by the one-step residual.

Examples
--------
>>> import numpy as np
>>> from mavsid.data import Segment
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

from __future__ import annotations

import warnings
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import replace

import numpy as np

from mavsid.data import Segment
from mavsid.errors import ConfigError, DataQualityWarning, NoExcitationError, SolverError
from mavsid.estimators import library
from mavsid.estimators._base import Estimator, block_grams, check_identifiable, solve
from mavsid.estimators.l1 import ElasticNet, Lasso
from mavsid.estimators.least_squares import STLSQ, LeastSquares, Ridge
from mavsid.estimators.model import Model
from mavsid.estimators.output_error import refine_output_error
from mavsid.estimators.regressors import InputFilter, Structure, filters_from_params, stack

__all__ = [
    "AXES",
    "DEFAULT_LAGS_S",
    "ESTIMATORS",
    "fit_axis",
    "log_params",
    "make_estimator",
    "select_delay",
]

#: Axis -> (modelled states, inputs).
AXES: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "roll": (("p",), ("u_roll",)),
    "pitch": (("q",), ("u_pitch",)),
    "yaw": (("r",), ("u_yaw",)),
    "all": (("p", "q", "r"), ("u_roll", "u_pitch", "u_yaw")),
}

#: Default candidates for a first-order input (motor) lag, s.
DEFAULT_LAGS_S: tuple[float, ...] = (0.0, 0.005, 0.01, 0.015, 0.02, 0.03, 0.04, 0.06)

#: Estimator name -> class.
ESTIMATORS: dict[str, type[Estimator]] = {
    "ls": LeastSquares,
    "ridge": Ridge,
    "l1": Lasso,
    "lasso": Lasso,
    "elasticnet": ElasticNet,
    "stlsq": STLSQ,
}


def make_estimator(name: str, structure: Structure | None = None, **kwargs: object
                   ) -> Estimator:
    """An estimator by name (``ls``, ``ridge``, ``l1``, ``elasticnet``, ``stlsq``)."""
    try:
        cls = ESTIMATORS[name]
    except KeyError:
        raise ConfigError(f"unknown estimator {name!r}; choose from {sorted(ESTIMATORS)}") \
            from None
    try:
        return cls(structure, **kwargs)  # type: ignore[arg-type]
    except TypeError as exc:
        raise ConfigError(f"estimator {name!r}: {exc}") from None


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


def select_delay(segments: Sequence[Segment], structure: Structure, delays: Iterable[float]
                 ) -> tuple[float, dict[float, float]]:
    """The delay (samples, possibly fractional) with the smallest one-step mean squared
    residual of a least-squares fit.

    Returns the best delay and the mean squared residual for every candidate.
    """
    scan: dict[float, float] = {}
    for dly in delays:
        d = int(np.floor(dly + 1e-9))
        st = replace(structure, delay=d, delay_frac=round(float(dly) - d, 9) % 1.0)
        try:
            reg = stack(segments, st)
        except NoExcitationError:
            continue
        grams = block_grams(reg)
        g = sum(grams[1:], grams[0])
        check_identifiable(reg, g)
        coef = solve(g)
        resid = reg.y - reg.z @ coef
        scan[float(dly)] = float(np.mean(resid**2))
    if not scan:
        raise NoExcitationError("segments too short for every candidate delay")
    return min(scan, key=scan.__getitem__), scan


def fit_axis(
    segments: Sequence[Segment],
    axis: str,
    estimator: str = "ls",
    *,
    params: Mapping[str, float] | None = None,
    filters: Sequence[InputFilter] | None = None,
    delays: Iterable[int] | None = None,
    delay: float | None = None,
    delay_step: float = 0.125,
    max_delay_s: float = 0.025,
    lags_s: Iterable[float] | None = DEFAULT_LAGS_S,
    structure_tol: float = 0.005,
    inputs: Sequence[str] | None = None,
    bias: bool = True,
    continuous: bool = False,
    features: Sequence[str] = (),
    refine: str | None = "auto",
    **estimator_kwargs: object,
) -> Model:
    """Choose the structure for one axis from the data and the log, fit it, return the model.

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
    delay_step : float
        Resolution of the default delay search, in samples (1: whole samples only).
    max_delay_s : float
        Longest delay searched by default (s).
    lags_s : iterable of float, optional
        Candidate time constants (s) of a first-order input lag (motor and ESC response),
        searched jointly with the delay; 0 is always a candidate; None: no lag. Lags too
        short for the sampling rate (corner above Nyquist) are left out.
    structure_tol : float
        Parsimony: the simplest (lag, delay) whose mean squared one-step residual is within
        this fraction of the best is chosen (a longer delay or a lag must earn its keep).
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
        errors then come from its sandwich covariance. ``"auto"`` (default): do so when the
        modelled states enter linearly (fast free run), not for nonlinear libraries. None:
        the estimator's equation-error result as is.
    **estimator_kwargs
        Passed to the estimator (``alpha``, ``n_bootstrap``, ...).
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
    structure = Structure(outputs=outputs, features=feats, inputs=ins, filters=flt,
                          continuous=continuous)
    # a lag whose corner lies above the grid's Nyquist frequency cannot be told from a
    # fraction of a sample of delay: such candidates are left out of the search
    nyquist_hz = 0.5 / dt
    lag_grid = [0.0] if lags_s is None else sorted(
        {0.0, *(lag for lag in map(float, lags_s) if lag * 2 * np.pi * nyquist_hz > 1.0)})
    cands: list[tuple[float, float, float]] = []  # (mse, lag, delay)
    scan: dict[str, float] = {}
    for lag in lag_grid:
        st = replace(structure, filters=flt + _lag_filter(lag))
        if delay is not None:
            d_scan = select_delay(segments, st, [float(delay)])[1]
        elif delays is not None:
            d_scan = select_delay(segments, st, delays)[1]
        else:  # whole samples first, then fractions around the best
            top = round(max_delay_s / dt)
            d0, d_scan = select_delay(segments, st, range(top + 1))
            if delay_step < 1:
                fine = np.arange(max(d0 - 1, 0), min(d0 + 1, top) + 1e-9, delay_step)
                d_scan.update(select_delay(segments, st, fine)[1])
        scan.update({f"lag={lag:g}s,delay={k:g}": v for k, v in d_scan.items()})
        cands.extend((v, lag, k) for k, v in d_scan.items())
    # parsimony: the simplest structure (no or short lag, then short delay) whose one-step
    # residual is within structure_tol of the best
    floor = min(c[0] for c in cands)
    _, lag, dly = min((c for c in cands if c[0] <= floor * (1 + structure_tol)),
                      key=lambda c: (c[1], c[2]))
    whole = int(np.floor(dly + 1e-9))
    structure = replace(structure, filters=flt + _lag_filter(lag), delay=whole,
                        delay_frac=round(float(dly) - whole, 9) % 1.0)
    est = make_estimator(estimator, structure, **estimator_kwargs).fit(segments)
    model = est.model_
    if refine == "oe":
        model = refine_output_error(model, segments)
    elif refine == "auto" and model.is_affine:
        try:
            model = refine_output_error(model, segments)
        except SolverError as exc:
            warnings.warn(f"{axis}: {exc}; keeping the {estimator} estimate",
                          DataQualityWarning, stacklevel=2)
    prov = dict(model.provenance)
    prov["structure_scan"] = scan
    prov["axis"] = axis
    prov["filters"] = [f.to_dict() for f in structure.filters]
    prov["lag_s"] = lag
    prov["delay_s"] = dly * dt
    return replace(model, provenance=prov)


def _lag_filter(lag_s: float) -> tuple[InputFilter, ...]:
    """A first-order input lag (motor/ESC response) as a filter; none for 0."""
    if lag_s <= 0:
        return ()
    return (InputFilter(1.0 / (2 * np.pi * lag_s), 1, f"input lag {lag_s * 1e3:g} ms"),)
