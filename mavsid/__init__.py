"""mavsid: attitude-dynamics system identification from ArduPilot and PX4 flight logs.

The stages, each one module: :mod:`mavsid.readers` (log -> ``RawLog``),
:mod:`mavsid.align` (-> ``FlightData``), :mod:`mavsid.excitation` (-> segments),
:mod:`mavsid.estimators` (-> model), :mod:`mavsid.validation`, :mod:`mavsid.viz`.
The estimators also stand alone on arrays: :func:`identify` (state-space models) and
:func:`regress` (equation-error regression).
"""

from typing import Any

from mavsid.data import FlightData, MessageTable, ModeChange, RawLog, Segment, SourceInfo
from mavsid.errors import (
    ConfigError,
    DataQualityWarning,
    LogFormatError,
    MavsidError,
    MavsidWarning,
    MissingMessageError,
    NoExcitationError,
    SolverError,
)
from mavsid.readers import read_log

__version__ = "0.1.0"

#: Names served from :mod:`mavsid.estimators` on first use (it imports scipy: the command
#: line's start-up does not pay for it unless it fits).
_LAZY = {"Model": "model", "load_model": "model", "RegressionResult": "api",
         "identify": "api", "regress": "api"}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f"mavsid.estimators.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'mavsid' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


__all__ = [
    "ConfigError",
    "DataQualityWarning",
    "FlightData",
    "LogFormatError",
    "MavsidError",
    "MavsidWarning",
    "MessageTable",
    "MissingMessageError",
    "ModeChange",
    "Model",
    "NoExcitationError",
    "RawLog",
    "RegressionResult",
    "Segment",
    "SolverError",
    "SourceInfo",
    "__version__",
    "identify",
    "load_model",
    "read_log",
    "regress",
]
