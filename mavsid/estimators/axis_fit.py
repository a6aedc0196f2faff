"""The log path: :func:`fit_axis`, what ``mavsid fit`` runs per attitude axis.

It names the axis's states and inputs (:data:`~mavsid.estimators.select.AXES`), takes the
known measurement filters from the log's parameters (:func:`log_params`,
:func:`~mavsid.estimators.regressors.filters_from_params`) and calls the identification core
(:func:`~mavsid.estimators.identification.identify_segments`) that the array API's
:func:`~mavsid.estimators.identification.identify` calls too.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import replace

import numpy as np

from mavsid.data import Segment
from mavsid.errors import ConfigError, NoExcitationError
from mavsid.estimators import library
from mavsid.estimators.identification import StructureChooser, identify_segments
from mavsid.estimators.model import Model
from mavsid.estimators.regressors import InputFilter, filters_from_params
from mavsid.estimators.select import (
    AXES,
    DEFAULT_DELAY_STEP,
    DEFAULT_LAGS_S,
    DEFAULT_MAX_DELAY_S,
    DEFAULT_STRUCTURE_TOL,
    ESTIMATORS,
)
from mavsid.threads import one_blas_thread

__all__ = ["fit_axis", "log_params"]


def log_params(segments: Iterable[Segment], params: Mapping[str, float] | None = None
               ) -> dict[str, float]:
    """The log parameters to use: ``params`` if given, else the first segment's that has
    any (:attr:`Segment.params <mavsid.data.Segment.params>`)."""
    if params is not None:
        return dict(params)
    for s in segments:
        if s.params:
            return {str(k): float(v) for k, v in s.params.items()
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
    coefficients refined by output error. It is
    :func:`~mavsid.estimators.identification.identify_segments` with the axis's
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
        The log's parameters (default: the segments' ``params``); used for known filters.
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
        score (see :func:`~mavsid.estimators.identification.identify_segments`).
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
    A pitch rate ``q[k+1] = 0.97 q[k] + 0.3 u[k-2]`` simulated by scipy (the record starts at
    rest: the input is zero before it and for its first samples):

    >>> import numpy as np
    >>> from scipy.signal import lfilter
    >>> from mavsid.estimators import records
    >>> rng = np.random.default_rng(5)
    >>> u = np.r_[np.zeros(4), rng.standard_normal(1996) * 0.05]
    >>> q = lfilter([0, 0, 0, 0.3], [1, -0.97], u)
    >>> segs = records(q, u, 0.0025, state_names=("q",), input_names=("u_pitch",))
    >>> m = fit_axis(segs, "pitch", n_bootstrap=0)
    >>> m.delay, round(m.params["A_d[q,q]"], 6), round(m.params["B_d[q,u_pitch]"], 6)
    (2, 0.97, 0.3)
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


