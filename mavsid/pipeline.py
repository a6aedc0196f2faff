"""The whole path from logs to a validated model: read → align → segment → fit → validate.

:func:`fit` runs it with defaults taken from the log (channel preset, SYSTEMID runs or scored
windows, the estimator) unless a :class:`PipelineConfig` (usually a TOML file, see
``pipelines/``) says otherwise. :func:`validate_logs` applies saved models to other flights.

Training and validation data never share samples: every segment of an axis is cut into
blocks of about ``block_s`` seconds (one long SYSTEMID run becomes several), the blocks are
put in time order and alternate — even blocks train, odd blocks validate (a lone block is
cut in two halves).

The settings and their TOML form are :mod:`mavsid.pipeline_config`'s, the split
:func:`mavsid.split.split_segments`; the flights a run reads and their windows are
:mod:`mavsid.pipeline_read`'s, the plant's response against the SYSTEMID injection and what
the fit takes from it :mod:`mavsid.pipeline_frequency`'s, the result types and their JSON
form :mod:`mavsid.pipeline_results`' (those the caller needs re-exported here); the text
``mavsid fit`` prints is :func:`mavsid.cli_format.format_result`.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from mavsid.autopilot.presets import QUADPLANE
from mavsid.axes import AXES, RATE_OF
from mavsid.data import FlightData, Segment
from mavsid.errors import ConfigError, MavsidError, NoExcitationError
from mavsid.pipeline_config import ESTIMATORS, PipelineConfig, config_from_dict, load_config
from mavsid.pipeline_frequency import (
    disagrees,
    frequency_estimate,
    plant_fit,
    take_lag,
    tf_chooser,
    tf_structure,
)
from mavsid.pipeline_read import (
    Twins,
    axis_segments,
    find_windows,
    flight_of,
    flights_of,
    missing_rate,
    slowest_rate,
)
from mavsid.pipeline_results import SUMMARY_HORIZON_S, AxisFit, FitResult, frequency_dict, json_safe
from mavsid.split import split_segments
from mavsid.threads import one_blas_thread
from mavsid.validation import Model, Validation, validate
from mavsid.verdict import Verdict, judge, not_identified, unfitted

if TYPE_CHECKING:
    from mavsid.estimators.identification import StructureChooser
    from mavsid.estimators.model import Model as EstimatorModel
    from mavsid.frequency import FrfStructure

__all__ = [
    "AXES",
    "ESTIMATORS",
    "AxisFit",
    "FitResult",
    "PipelineConfig",
    "config_from_dict",
    "find_windows",
    "fit",
    "json_safe",
    "load_config",
    "load_models",
    "split_segments",
    "validate_logs",
]


def _validate(model: Model, segments: Sequence[Segment], cfg: PipelineConfig) -> Validation:
    """Validate ``model`` on ``segments`` with the config's horizons and residual settings."""
    return validate(
        model,
        segments,
        horizons_s=(*cfg.horizons_s, SUMMARY_HORIZON_S),
        max_lag=cfg.max_lag,
        fft_window_s=cfg.fft_window_s,
    )


def _closed_loop(
    fitted: AxisFit, flights: Sequence[FlightData], signals: Twins
) -> AxisFit:
    """``fitted`` with its controller emulation and, when that passes, its closed-loop twin
    run on the held-out blocks (or the reason not)."""
    from mavsid.loop.emulation import emulation_check
    from mavsid.loop.twin import closed_loop_fit, twin_signals

    planes = [fd for fd in flights
              if (fd.vehicle or "").lower().split()[:1] == ["plane"]
              and fd.preset != QUADPLANE]  # (a QuadPlane's VTOL: a multicopter's)
    if planes:  # (the twin would run a multicopter's controller on a plane's targets)
        return dataclasses.replace(
            fitted, closed_loop_note="no closed-loop twin for ArduPlane: the twin rebuilds "
            "ArduCopter's or PX4's multicopter rate controller, not Plane's roll/pitch/yaw "
            "controllers")
    try:
        sigs = []
        for fd in flights:
            if id(fd) not in signals:
                signals[id(fd)] = twin_signals(fd)
            sig = signals[id(fd)]
            if isinstance(sig, Exception):
                raise sig
            sigs.append(sig)
        emu = emulation_check(fitted.axis, fitted.train, fitted.held_out, flights, sigs)
    except (MavsidError, ValueError, np.linalg.LinAlgError) as exc:
        return dataclasses.replace(fitted, closed_loop_note=str(exc))
    fitted = dataclasses.replace(fitted, emulation=emu)
    if not emu.passed:
        return dataclasses.replace(fitted, closed_loop_note="twin not used: " + emu.reason)
    try:
        j = fitted.validation.state_names.index(fitted.output)
        cl = closed_loop_fit(fitted.model, fitted.axis, fitted.train, fitted.held_out, flights,
                             sigs, open_loop_percent=float(fitted.validation.fit_free_run[j]),
                             timing=(emu.lag_loops, emu.measurement_delay_loops))
    except (MavsidError, ValueError, np.linalg.LinAlgError) as exc:
        return dataclasses.replace(fitted, closed_loop_note=str(exc))
    return dataclasses.replace(fitted, closed_loop=cl)


def _nothing(logs: Sequence[str | os.PathLike[str]], verdicts: Mapping[str, Verdict],
             what: str, refused: Sequence[str] = ()) -> NoExcitationError:
    """The error for a run with no model: one line naming the logs and each axis's first
    reason (the ``refused`` axes' alone when there are: a SYSTEMID run that ended in a
    roll-over or excited nothing); each axis's verdict and the advice (once, not per axis) as
    ``details`` lines (the command line prints them on stdout, as it prints a fit's verdicts).

    Examples
    --------
    >>> from mavsid.verdict import not_identified
    >>> v = {a: not_identified(a, "no window kept", advice=("fly a chirp",))
    ...      for a in ("roll", "pitch")}
    >>> e = _nothing(["a.bin"], v, "nothing identifiable")
    >>> str(e).split("; see ")
    ['a.bin: nothing identifiable (roll: no window kept; pitch: no window kept)', \
'`mavsid segments a.bin --all`']
    >>> e.details[-1]
    'next time: fly a chirp'
    """
    names = ", ".join(os.fspath(p) for p in logs)
    short = "; ".join(f"{a}: {v.reasons[0] if v.reasons else v.level}"
                      for a, v in verdicts.items())
    first = os.fspath(logs[0]) if logs else "LOG"
    exc = NoExcitationError(f"{names}: {what} ({short}); see `mavsid segments {first} --all`")
    if refused:  # (a refused SYSTEMID run is the one line: the rest only repeats it)
        exc = NoExcitationError(f"{names}: " + "; ".join(
            f"{a}: {verdicts[a].reasons[0]}" for a in refused))
    lines = [f"{a}: {v.level}: " + "; ".join(v.reasons) for a, v in verdicts.items()]
    advice = list(dict.fromkeys(x for v in verdicts.values() for x in v.advice))
    if advice:
        lines.append("next time: " + "; ".join(advice))
    exc.details = tuple(lines)
    exc.verdicts = dict(verdicts)  # type: ignore[attr-defined]
    return exc


def _fit_model(train: Sequence[Segment], axis: str, cfg: PipelineConfig,
               choose: StructureChooser | None = None) -> Model:
    from mavsid import estimators

    options = dict(cfg.model_options)
    if choose is not None:
        options["choose_structure"] = choose
    model: Model = estimators.fit_axis(list(train), axis=axis, estimator=cfg.estimator,
                                       **options)
    return model


def _frf_chooser(axis: str, flights: Sequence[FlightData], signals: Twins,
                 cfg: PipelineConfig) -> FrfStructure | None:
    """The structure chooser from the axis's SYSTEMID injection (its FRF against the
    injection, :class:`mavsid.frequency.FrfStructure`), None where there is none or the
    configuration fixes the delay or lags."""
    if {"delay", "delays", "lags_s"} & set(cfg.model_options):
        return None
    from mavsid.frequency import FrfStructure, measured_responses
    from mavsid.loop.twin import TwinSignals

    sigs = [sg for fd in flights if isinstance(sg := signals.get(id(fd)), TwinSignals)]
    if len(sigs) < len(flights):
        return None
    try:
        plant = measured_responses(axis, flights, sigs, which=("plant",)).get("plant")
    except (MavsidError, ValueError, np.linalg.LinAlgError):
        return None
    if plant is None or not plant.referenced:
        return None
    step = cfg.model_options.get("delay_step")
    return FrfStructure(plant, axis, **({"delay_step": float(step)} if step else {}))


class _InstrumentCheck:
    """``choose_structure`` for :func:`mavsid.estimators.fit_axis` where there is no
    injection: keeps the search's structure, and estimates the chosen model again with the
    commanded attitude as instrument (:func:`mavsid.estimators.instruments.
    instrument_estimate`), whose difference joins the covariance: a fit the fed-back gyro
    noise biased says so in its σ."""

    estimate_source = "the estimate with the commanded attitude as instrument"

    def __init__(self, segments: Sequence[Segment],
                 references: Sequence[np.ndarray | None], sticks: bool = False) -> None:
        self.segments, self.references = list(segments), list(references)
        if sticks:  # (a .tlog's: the pilot's sticks stand for the commanded attitude)
            self.estimate_source = ("the estimate with the commanded attitude (the pilot's "
                                    "sticks) as instrument")

    def __call__(self, models: Mapping[float, EstimatorModel]) -> None:
        return None

    def estimate(self, model: EstimatorModel) -> EstimatorModel | None:
        from mavsid.estimators.instruments import instrument_estimate

        return instrument_estimate(model, self.segments, self.references)


def _instrument_check(axis: str, flights: Sequence[FlightData],
                      segments: Sequence[Segment]) -> _InstrumentCheck | None:
    """An :class:`_InstrumentCheck` of ``segments`` (cut from ``flights``), with the flights'
    commanded attitude (``FlightData.commanded``, from alignment) on their samples; None where
    the logs have none for the axis."""
    from mavsid.align import STICK_SOURCE

    refs: list[np.ndarray | None] = []
    sticks = False
    for seg in segments:
        ref = None
        for fd in flights:
            desired = fd.commanded.get(axis)
            i = fd.index_of(seg) if desired is not None else None
            if desired is not None and i is not None:
                ref = desired[i:i + len(seg)]
                source = fd.commanded_from.get(axis, "")
                sticks |= str(source).endswith(STICK_SOURCE)
                break
        refs.append(ref)
    if all(r is None for r in refs):
        return None
    return _InstrumentCheck(segments, refs, sticks)


#: Stages :func:`fit` reports per axis (reading is one more per log).
FIT_STAGES = ("segments", "fit", "validation", "closed-loop twin")


def _noop(stage: str) -> None:
    pass


@one_blas_thread
def fit(
    logs: Sequence[str | os.PathLike[str]],
    config: PipelineConfig | None = None,
    progress: Callable[[str], None] | None = None,
) -> FitResult:
    """Fit and validate a model per axis from one or more logs.

    Parameters
    ----------
    logs : sequence of path-like
        Flight logs (any supported format); their segments are pooled per axis.
    config : PipelineConfig, optional
        Settings; defaults chosen from the log.
    progress : callable, optional
        Called with a stage's name as it starts: ``"reading LOG"`` per log, then per axis
        ``"AXIS: STAGE"`` for each of :data:`FIT_STAGES` (a skipped stage is reported too,
        so that the count is ``len(logs) + len(FIT_STAGES) * len(axes)``).

    Returns
    -------
    FitResult

    Raises
    ------
    MavsidError
        Unreadable logs, no excitation on any requested axis, or estimator failure.
    """
    cfg = config or PipelineConfig()
    if not logs:
        raise ConfigError("no log given")
    step = progress or _noop
    signals: Twins = {}
    flights = flights_of(logs, cfg, step, signals)
    from mavsid.estimators.model import hash_soon

    hash_soon(f.source.path for f in flights)  # (for the model's provenance, meanwhile)
    fits: dict[str, AxisFit] = {}
    verdicts: dict[str, Verdict] = {}
    refused_runs: list[str] = []
    for axis in cfg.axes:
        stages = iter(FIT_STAGES)

        def next_stage(axis: str = axis, stages: Any = stages, rest: bool = False) -> None:
            """Report the next stage (``rest``: all those left, skipped: the count stays
            whole)."""
            for name in stages:
                step(f"{axis}: {name}")
                if not rest:
                    return

        next_stage()
        windows, segs = axis_segments(flights, axis, cfg)
        missing = missing_rate(axis, flights)
        if missing:
            next_stage(rest=True)
            verdicts[axis] = unfitted(axis, missing, windows, flights,
                                      [os.fspath(p) for p in logs])
            continue
        tf, tf_note, refused = plant_fit(axis, flights)
        if refused:  # (one line: every other gate would only repeat it)
            next_stage(rest=True)
            verdicts[axis] = not_identified(axis, tf_note)
            refused_runs.append(axis)
            continue
        try:
            train, held_out = split_segments(segs, cfg.block_s)
            next_stage()
            fit_cfg = cfg
            model = _fit_model(train, axis, cfg, _frf_chooser(axis, flights, signals, cfg)
                               or tf_chooser(axis, tf, cfg)
                               or _instrument_check(axis, flights, train))
            structure = (tf_structure(tf, cfg, train)
                         if tf is not None and disagrees(model, axis, tf) else None)
            if tf is not None and structure is not None:
                # refitted with the structure the measured response supports, then its pole
                # and effectiveness taken from the response (the time-domain fit is biased)
                fit_cfg = dataclasses.replace(cfg, model_options={**dict(cfg.model_options),
                                                                  **structure})
                model = frequency_estimate(
                    _fit_model(train, axis, fit_cfg, take_lag(structure["lags_s"][0],
                                                               structure["delay"])), axis, tf)
            next_stage()
            val = _validate(model, held_out, cfg)
        except NoExcitationError as exc:
            next_stage(rest=True)
            verdicts[axis] = unfitted(axis, str(exc), windows, flights,
                                      [os.fspath(p) for p in logs])
            continue
        fitted = AxisFit(axis, model, val, train, held_out, cfg.estimator, windows,
                         frequency=tf, frequency_note=tf_note)
        next_stage()
        fitted = _closed_loop(fitted, flights, signals)
        verdict = _judge(fitted, flights)
        if val.stable is False and not cfg.allow_unstable:
            bounded = _bounded_fit(fitted, fit_cfg)
            if bounded is None or bounded.validation.stable is False:
                verdicts[axis] = dataclasses.replace(
                    verdict, reasons=(*verdict.reasons, "refused (--allow-unstable keeps it); "
                                      "the bounded fit (damping >= 0, effectiveness > 0) "
                                      + ("is unstable too" if bounded else "failed")))
                continue
            bounded = dataclasses.replace(bounded, closed_loop=None, closed_loop_note="",
                                          emulation=None)
            fitted = _closed_loop(bounded, flights, signals)
            verdict = _judge(fitted, flights)
            note = (f"the unconstrained fit was unstable ({_worst_eig(val)}): refused, "
                    "replaced by the bounded fit")
            lead = () if verdict.identified else verdict.reasons[:1]  # (why it is not, first)
            verdict = dataclasses.replace(verdict, reasons=(
                *lead, note, *verdict.reasons[len(lead):]))
        verdicts[axis] = verdict
        if verdict.identified or cfg.allow_unstable:  # a model judged useless is no result
            fits[axis] = dataclasses.replace(fitted, verdict=verdict)
    if not fits:
        raise _nothing(logs, verdicts, "nothing identifiable", refused_runs)
    from mavsid.loop.twin import TwinSignals

    twins = [signals.get(id(fd)) for fd in flights]
    return FitResult(fits, flights, tuple(os.fspath(p) for p in logs), cfg, verdicts,
                     tuple(t for t in twins if isinstance(t, TwinSignals))
                     if all(isinstance(t, TwinSignals) for t in twins) else None)


def _judge(fitted: AxisFit, flights: Sequence[FlightData]) -> Verdict:
    """The verdict on one fitted axis (the closed-loop twin's fit when it ran)."""
    return judge(fitted.axis, fitted.validation, fitted.output, model=fitted.model,
                 train=fitted.train, windows=fitted.windows, flights=flights,
                 closed_loop=getattr(fitted, "closed_loop", None),
                 emulation=getattr(fitted, "emulation", None),
                 frequency=_frequency_evidence(fitted))


def _frequency_evidence(fitted: AxisFit) -> dict[str, Any] | None:
    """What the verdict's frequency-domain checks need (:func:`mavsid.verdict.
    frequency_checks`): the transfer function, the model against the measured response, and
    the time-domain estimate of the effectiveness when the model's comes from the response."""
    got = frequency_dict(fitted)
    if got is None or "model_check" not in got:
        return None
    prov = dict(getattr(fitted.model, "provenance", {}) or {})
    td = prov.get("time_domain_estimate")
    name = f"B[{RATE_OF[fitted.axis]},u_{fitted.axis}]"
    if isinstance(td, Mapping) and name in dict(td.get("params") or {}):
        got["time_domain"] = {"B": td["params"][name],
                              "sigma": dict(td.get("stderr") or {}).get(name)}
    return got


def _worst_eig(val: Validation) -> str:
    if val.eigenvalues is None or not len(val.eigenvalues):
        return "no eigenvalue"
    z = max((complex(e) for e in val.eigenvalues), key=abs)
    return f"eigenvalue {abs(z):.4g}, pole {math.log(abs(z)) / val.dt:+.3g} 1/s"


def _bounded_fit(fitted: AxisFit, cfg: PipelineConfig) -> AxisFit | None:
    """The fit the physics allows: damping >= 0 (``A_d[y,y] <= 1``) and control effectiveness
    >= 0 on the axis's own input, by bounded least squares (cvxpy, no penalty, no output-error
    refinement, which would leave the bounds). ``provenance["bounds_active"]`` lists the
    parameters that sit on their bound. None when the estimator fails."""
    from mavsid import estimators
    from mavsid.errors import SolverError

    y = fitted.output
    names = set(fitted.model.params)
    bounds = {f"A_d[{y},{y}]": (-math.inf, 1.0)} if f"A_d[{y},{y}]" in names else {}
    signs = {k: 1 for k in names if k.startswith(f"B_d[{y},u_{fitted.axis}")}
    if not bounds and not signs:
        return None
    options = {**dict(cfg.model_options), "alpha": 0.0, "bounds": bounds, "signs": signs,
               "refine": None}
    try:
        model: Model = estimators.fit_axis(list(fitted.train), axis=fitted.axis,
                                           estimator="l1", **options)
        val = _validate(model, fitted.held_out, cfg)
    except (SolverError, NoExcitationError, ConfigError):
        return None
    active = [k for k, (_, hi) in bounds.items() if model.params[k] >= hi - 1e-6]
    active += [k for k in signs if abs(model.params[k]) <= 1e-9]
    prov = {**dict(getattr(model, "provenance", {}) or {}), "bounds": {
        **{k: list(v) for k, v in bounds.items()}, **{k: [0.0, math.inf] for k in signs}},
        "bounds_active": active}
    model = dataclasses.replace(model, provenance=prov)  # type: ignore[type-var]
    return dataclasses.replace(fitted, model=model, validation=val, estimator="bounded ls")


def load_models(path: str | os.PathLike[str]) -> dict[str, Model]:
    """Read the models ``mavsid fit -o`` wrote: ``{axis: model}``."""
    import json

    from mavsid import estimators

    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not a mavsid model file: {exc}") from None
    if not isinstance(data, dict) or not isinstance(data.get("axes"), dict):
        raise ConfigError(f"{path}: not a mavsid model file (no 'axes' table)")
    out: dict[str, Model] = {}
    for axis, d in data["axes"].items():
        if axis not in AXES:
            raise ConfigError(f"{path}: axis {axis!r} is not one of {', '.join(AXES)}")
        try:
            out[axis] = estimators.Model.from_dict(d)
        except MavsidError as exc:
            raise ConfigError(f"{path}: axis {axis}: {exc}") from None
    return out


#: Stages :func:`validate_logs` reports per model (reading is one more per log).
VALIDATE_STAGES = ("segments", "validation", "closed-loop twin")


@one_blas_thread
def validate_logs(
    models: Mapping[str, Model],
    logs: Sequence[str | os.PathLike[str]],
    config: PipelineConfig | None = None,
    progress: Callable[[str], None] | None = None,
) -> FitResult:
    """Validate saved models on other flights: every segment found is held out.

    ``progress`` is called as in :func:`fit`, with :data:`VALIDATE_STAGES` per model.

    Unless the config fixes ``rate_hz``, the flights are aligned at the first log's own rate
    (later logs at the same rate) and a model fitted at another rate is re-discretised to it
    (:meth:`~mavsid.estimators.model.Model.resampled`; the verdict says so), so that the
    one-step and multi-step fits compare the model with samples the log really holds. A
    model that cannot be re-discretised is run on the model's grid instead, the flight's
    samples interpolated (also said).
    """
    cfg = config or PipelineConfig()
    if not logs:
        raise ConfigError("no log given")
    step = progress or _noop
    native = flights_of(logs, cfg, step)
    first = native[0]
    on_model_grid: dict[float, tuple[FlightData, ...]] = {}
    fits: dict[str, AxisFit] = {}
    verdicts: dict[str, Verdict] = {}
    signals: Twins = {}
    for axis, model in models.items():
        if axis not in cfg.axes:
            continue
        step(f"{axis}: {VALIDATE_STAGES[0]}")
        flights, note = native, ""
        if not np.isclose(model.dt, first.dt, rtol=1e-3):
            fitted_hz = 1.0 / model.dt
            try:
                resampled = getattr(model, "resampled", None)
                if resampled is None:
                    raise ConfigError("the model cannot be re-discretised")
                model = resampled(first.dt)
                note = (f"model re-discretised from {fitted_hz:.3g} Hz to the log's "
                        f"{1 / first.dt:.3g} Hz (delay kept in seconds)")
            except ConfigError as exc:
                if model.dt not in on_model_grid:
                    grid = cfg.with_overrides(rate_hz=fitted_hz)
                    on_model_grid[model.dt] = tuple(flight_of(p, grid) for p in logs)
                flights = on_model_grid[model.dt]
                note = "; ".join(filter(None, [str(exc), _resampling_note(model, flights)]))
        windows, segs = axis_segments(flights, axis, cfg)
        missing = missing_rate(axis, flights)
        try:
            if missing:
                raise NoExcitationError(missing)
            if not segs:
                raise NoExcitationError("no segments")
            step(f"{axis}: {VALIDATE_STAGES[1]}")
            val = _validate(model, segs, cfg)
        except NoExcitationError as exc:
            verdicts[axis] = unfitted(axis, str(exc), windows, flights,
                                      [os.fspath(p) for p in logs])
            continue
        estimator = str(dict(getattr(model, "provenance", {}) or {}).get("estimator", ""))
        # a chirp of the other flight validates the model in the frequency domain: the
        # model's response against the one measured there against its injection
        tf, tf_note, _ = plant_fit(axis, flights)
        fitted = AxisFit(axis, model, val, (), segs, estimator, windows, frequency=tf,
                         frequency_note=tf_note)
        step(f"{axis}: {VALIDATE_STAGES[2]}")
        fitted = _closed_loop(fitted, flights, signals)
        verdict = _judge(fitted, flights)
        if note:
            verdict = dataclasses.replace(verdict, reasons=(*verdict.reasons, note))
        verdicts[axis] = verdict
        fits[axis] = dataclasses.replace(fitted, verdict=verdict)
    if not fits:
        raise _nothing(logs, verdicts, "no segment to validate on")
    return FitResult(fits, native, tuple(os.fspath(p) for p in logs), cfg, verdicts)


def _resampling_note(model: Model, flights: Sequence[FlightData]) -> str:
    """What was done to apply ``model`` to flights logged at another rate (empty if none).

    A discrete-time model predicts at its own step only: each flight is aligned on the
    model's grid, its states interpolated linearly and its inputs held (zero-order hold)
    between their logged samples. When the log's rate channels are slower than the grid the
    one-step fit compares the model with interpolated samples and is optimistic.
    """
    model_hz = 1.0 / model.dt
    notes = []
    for fd in flights:
        slow = slowest_rate(fd, (*model.state_names, *model.input_names))
        if slow is None:
            continue
        if abs(slow - model_hz) > 0.05 * model_hz:
            how = ("upsampled: states interpolated, inputs held, one-step fit optimistic"
                   if slow < model_hz else "downsampled to the model's step")
            notes.append(f"{os.path.basename(fd.source.path)} logged at {slow:.3g} Hz, "
                         f"resampled onto the model's {model_hz:.3g} Hz grid ({how})")
    return "; ".join(notes)


