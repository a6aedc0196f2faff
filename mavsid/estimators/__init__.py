"""Estimators: segments -> fitted attitude-dynamics models.

One regression core (:mod:`._base`) on Gram matrices; rows from segments
(:mod:`.regressors`); SINDy-style libraries (:mod:`.library`); solvers
(:mod:`.least_squares`, :mod:`.l1`); output-error refinement (:mod:`.output_error`); the
fitted :class:`Model` (:mod:`.model`); structure search (:mod:`.select`); arrays in
(:func:`records`, :mod:`.arrays`); the identification core :func:`identify_segments` and the
array API :func:`identify` on it (:mod:`.identification`); the log path's per-axis
:func:`fit_axis` on the same core (:mod:`.axis_fit`); equation-error :func:`regress`
(:mod:`.regression`).

Examples
--------
>>> from mavsid.estimators import fit_axis, load_model, LeastSquares, Structure
>>> sorted(ESTIMATORS)
['elasticnet', 'l1', 'lasso', 'ls', 'ridge', 'stlsq']
"""

from mavsid.estimators import library
from mavsid.estimators.arrays import records
from mavsid.estimators.axis_fit import fit_axis
from mavsid.estimators.base import Estimator, Gram, check_identifiable, rollout_fit, solve
from mavsid.estimators.identification import identify, identify_segments
from mavsid.estimators.l1 import ElasticNet, Lasso
from mavsid.estimators.least_squares import STLSQ, LeastSquares, Ridge
from mavsid.estimators.model import Model, load_model
from mavsid.estimators.output_error import refine_output_error
from mavsid.estimators.regression import RegressionResult, regress
from mavsid.estimators.regressors import (
    InputFilter,
    Regression,
    Structure,
    derivative,
    filters_from_params,
    rows,
    stack,
)
from mavsid.estimators.select import (
    AXES,
    ESTIMATORS,
    make_estimator,
    search_structure,
    select_delay,
)

__all__ = [
    "AXES",
    "ESTIMATORS",
    "STLSQ",
    "ElasticNet",
    "Estimator",
    "Gram",
    "InputFilter",
    "Lasso",
    "LeastSquares",
    "Model",
    "Regression",
    "RegressionResult",
    "Ridge",
    "Structure",
    "check_identifiable",
    "derivative",
    "filters_from_params",
    "fit_axis",
    "identify",
    "identify_segments",
    "library",
    "load_model",
    "make_estimator",
    "records",
    "refine_output_error",
    "regress",
    "rollout_fit",
    "rows",
    "search_structure",
    "select_delay",
    "solve",
    "stack",
]
