"""mavsid: attitude-dynamics system identification from ArduPilot and PX4 flight logs.

The stages, each one module: :mod:`mavsid.readers` (log -> ``RawLog``),
:mod:`mavsid.align` (-> ``FlightData``), :mod:`mavsid.excitation` (-> segments),
:mod:`mavsid.estimators` (-> model), :mod:`mavsid.validation`, :mod:`mavsid.viz`.
The estimators also stand alone on arrays: :func:`identify` (state-space models),
:func:`regress` (equation-error regression) and :func:`identify_frequency` (a rate plant's
transfer function fitted to its measured frequency response, :mod:`mavsid.frequency_fit`).
What mavsid knows about the firmware — message, topic and parameter names, SYSTEMID, flight
modes, mixers, logging advice — is in :mod:`mavsid.autopilot` (adding a firmware touches only
that package); the axis vocabulary (``roll``/``p``/``u_roll`` ...) in :mod:`mavsid.axes`.
"""

from typing import TYPE_CHECKING, Any

from mavsid.errors import (
    ConfigError,
    DataQualityWarning,
    ImplausibleModelError,
    LogFormatError,
    MavsidError,
    MavsidWarning,
    MissingMessageError,
    NoExcitationError,
    SolverError,
)

if TYPE_CHECKING:  # (served lazily below; the type checker sees them here)
    from mavsid.data import FlightData, MessageTable, ModeChange, RawLog, Segment, SourceInfo
    from mavsid.estimators.identification import identify
    from mavsid.estimators.model import Model, load_model
    from mavsid.estimators.regression import RegressionResult, regress
    from mavsid.frequency_fit import PlantTF, identify_frequency
    from mavsid.readers import read_log

__version__ = "0.1.0"

#: Names served from their modules on first use: the data types and the readers import numpy,
#: the estimators scipy; ``mavsid --help`` and ``--version`` pay for neither.
_LAZY = {"Model": "estimators.model", "load_model": "estimators.model",
         "RegressionResult": "estimators.regression", "regress": "estimators.regression",
         "identify": "estimators.identification", "read_log": "readers",
         "identify_frequency": "frequency_fit", "PlantTF": "frequency_fit",
         **dict.fromkeys(("FlightData", "MessageTable", "ModeChange", "RawLog", "Segment",
                          "SourceInfo"), "data")}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f"mavsid.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'mavsid' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


__all__ = [
    "ConfigError",
    "DataQualityWarning",
    "FlightData",
    "ImplausibleModelError",
    "LogFormatError",
    "MavsidError",
    "MavsidWarning",
    "MessageTable",
    "MissingMessageError",
    "ModeChange",
    "Model",
    "NoExcitationError",
    "PlantTF",
    "RawLog",
    "RegressionResult",
    "Segment",
    "SolverError",
    "SourceInfo",
    "__version__",
    "identify",
    "identify_frequency",
    "load_model",
    "read_log",
    "regress",
]
