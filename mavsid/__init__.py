"""mavsid: attitude-dynamics system identification from ArduPilot and PX4 flight logs.

The stages, each one module: :mod:`mavsid.readers` (log -> ``RawLog``),
:mod:`mavsid.align` (-> ``FlightData``), :mod:`mavsid.excitation` (-> segments),
:mod:`mavsid.estimators` (-> model), :mod:`mavsid.validation`, :mod:`mavsid.viz`.
"""

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
    "NoExcitationError",
    "RawLog",
    "Segment",
    "SolverError",
    "SourceInfo",
    "__version__",
    "read_log",
]
