"""The flights a run reads: each log read once and aligned (:func:`flight_of`; the twin's
signals taken in the same pass), several logs on one grid
(:func:`flights_of`), and per axis the windows considered and the segments kept
(:func:`axis_windows`, :func:`axis_segments`, :func:`find_windows`)."""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np

from mavsid.axes import INPUT_OF, RATE_OF, RATES
from mavsid.data import FlightData, Segment
from mavsid.errors import DataQualityWarning, MavsidError
from mavsid.pipeline_config import PipelineConfig

if TYPE_CHECKING:
    from mavsid.excitation import WindowReport
    from mavsid.loop.twin import TwinSignals

__all__ = [
    "POOL_RATE_RATIO",
    "Twins",
    "axis_segments",
    "axis_windows",
    "find_windows",
    "flight_of",
    "flights_of",
    "missing_rate",
    "slowest_rate",
]


#: Per flight (by ``id``): its twin's signals, or why they could not be had.
Twins = dict[int, "TwinSignals | MavsidError | ValueError | np.linalg.LinAlgError"]


def flight_of(path: str | os.PathLike[str], cfg: PipelineConfig,
              twins: Twins | None = None) -> FlightData:
    """Read only the messages alignment needs, then align. With ``twins``: the twin's few
    messages are read in the same pass and its signals put there (no second read)."""
    from mavsid.align import read_flight

    also: Sequence[str] = ()
    if twins is not None:
        from mavsid.loop.twin import twin_messages

        also = sorted(twin_messages())
    flight, raw = read_flight(
        path,
        cfg.preset,
        cfg.rate_hz,
        presets=cfg.presets or None,
        mixers=cfg.mixers or None,
        also=also,
    )
    if twins is not None:
        from mavsid.loop.twin import twin_signals

        try:
            twins[id(flight)] = twin_signals(flight, raw)
        except (MavsidError, ValueError, np.linalg.LinAlgError) as exc:
            twins[id(flight)] = exc  # (raised where the twin runs, as a second read would)
    return flight


def flights_of(logs: Sequence[str | os.PathLike[str]], cfg: PipelineConfig,
               step: Callable[[str], None], twins: Twins | None = None
               ) -> tuple[FlightData, ...]:
    """Each log aligned; unless the config fixes the rate, later logs at the first one's
    (pooled segments and one model need one step)."""
    step(f"reading {os.fspath(logs[0])}")
    first = flight_of(logs[0], cfg, twins)
    same_rate = cfg if cfg.rate_hz is not None else cfg.with_overrides(rate_hz=1.0 / first.dt)
    flights = [first]
    for p in logs[1:]:
        step(f"reading {os.fspath(p)}")
        flights.append(flight_of(p, same_rate, twins))
    slow = [(fd, rate) for fd in flights[1:]
            if (rate := slowest_rate(fd)) is not None and rate < POOL_RATE_RATIO / fd.dt]
    if slow:
        shown = ", ".join(f"{fd.source.path} at {rate:.3g} Hz" for fd, rate in slow)
        warnings.warn(f"pooled on {first.source.path}'s {1 / first.dt:.3g} Hz grid: {shown} "
                      "(interpolated samples between its own weigh on the model as measured "
                      "ones would; fit the slower logs apart, or give them first)",
                      DataQualityWarning, stacklevel=3)
    return tuple(flights)


#: a pooled log whose rate channels are slower than this share of the grid's rate is said
#: (most of its grid points interpolated)
POOL_RATE_RATIO = 0.5


def slowest_rate(fd: FlightData,
                 names: Sequence[str] = (*RATES, *INPUT_OF.values())
                 ) -> float | None:
    """The slowest native rate (Hz) of a flight's channels ``names`` (default: the body
    rates and attitude inputs the rate models are fitted on), if known."""
    native = fd.native_rate_hz
    rates = [float(native[n]) for n in names if native.get(n)]
    return min(rates) if rates else None


def axis_windows(flight: FlightData, axis: str, cfg: PipelineConfig) -> list[WindowReport]:
    """Every window considered on ``axis``, kept or rejected, as the config asks."""
    from mavsid.excitation import ScanOptions, find_segments

    options = ScanOptions.from_options(cfg.segment_options)
    scan = {"auto": None, "sysid": False, "scan": True}[cfg.segment_source]
    reports = find_segments(flight, axis, scan=scan, options=options)
    if cfg.segment_source == "scan":
        reports = [r for r in reports if r.source == "scan"]
    return [r for r in reports if r.axis == axis]


def axis_segments(
    flights: Sequence[FlightData], axis: str, cfg: PipelineConfig
) -> tuple[tuple[WindowReport, ...], tuple[Segment, ...]]:
    """Every window considered for ``axis`` over all flights, and the kept segments."""
    from mavsid.excitation import select_segments

    reports = [(fd, axis_windows(fd, axis, cfg)) for fd in flights]
    windows = tuple(r for _, rs in reports for r in rs)
    segs = tuple(s for fd, rs in reports for s in select_segments(fd, reports=rs))
    return windows, segs


def missing_rate(axis: str, flights: Sequence[FlightData]) -> str:
    """Why ``axis`` cannot be modelled for want of its body rate (empty when it is logged)."""
    rate = RATE_OF.get(axis, "")
    lacking = [fd for fd in flights if rate and rate not in fd.state_names]
    if not lacking:
        return ""
    fd = lacking[0]
    return (f"no body rate {rate} in {os.path.basename(fd.source.path)} (preset {fd.preset}: "
            "attitude angles only): the rate dynamics need a gyro log (ArduPilot RATE or IMU, "
            "PX4 vehicle_angular_velocity)")


def find_windows(
    log: str | os.PathLike[str], config: PipelineConfig | None = None
) -> tuple[FlightData, dict[str, list[WindowReport]]]:
    """Read and align one log and find its windows per axis (for viewing without a model)."""
    cfg = config or PipelineConfig()
    flight = flight_of(log, cfg)
    return flight, {axis: axis_windows(flight, axis, cfg) for axis in cfg.axes}
