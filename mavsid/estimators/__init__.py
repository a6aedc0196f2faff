"""Estimators: segments -> fitted attitude-dynamics models.

One regression core (:mod:`._base`) on Gram matrices; rows from segments
(:mod:`.regressors`); SINDy-style libraries (:mod:`.library`); solvers
(:mod:`.least_squares`, :mod:`.l1`); output-error refinement (:mod:`.output_error`); the
fitted :class:`Model` (:mod:`.model`); structure selection and the per-axis entry point
:func:`fit_axis` (:mod:`.select`).

Examples
--------
>>> from mavsid.estimators import fit_axis, load_model, LeastSquares, Structure
>>> sorted(ESTIMATORS)
['elasticnet', 'l1', 'lasso', 'ls', 'ridge', 'stlsq']
"""

from mavsid.estimators import library
from mavsid.estimators._base import Estimator, Gram, check_identifiable, rollout_fit, solve
from mavsid.estimators.l1 import ElasticNet, Lasso
from mavsid.estimators.least_squares import STLSQ, LeastSquares, Ridge
from mavsid.estimators.model import Model, load_model
from mavsid.estimators.output_error import refine_output_error
from mavsid.estimators.regressors import (
    InputFilter,
    Regression,
    Structure,
    derivative,
    filters_from_params,
    rows,
    stack,
)
from mavsid.estimators.select import AXES, ESTIMATORS, fit_axis, make_estimator, select_delay

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
    "Ridge",
    "Structure",
    "check_identifiable",
    "derivative",
    "filters_from_params",
    "fit_axis",
    "library",
    "load_model",
    "make_estimator",
    "refine_output_error",
    "rollout_fit",
    "rows",
    "select_delay",
    "solve",
    "stack",
]
