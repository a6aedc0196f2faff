"""The whole path from logs to a validated model: read → align → segment → fit → validate.

:func:`fit` runs it with defaults taken from the log (channel preset, SYSTEMID runs or scored
windows, the estimator) unless a :class:`PipelineConfig` (usually a TOML file, see
``pipelines/``) says otherwise. :func:`validate_logs` applies saved models to other flights.

Training and validation data never share samples: every segment of an axis is cut into
blocks of about ``block_s`` seconds (one long SYSTEMID run becomes several), the blocks are
put in time order and alternate — even blocks train, odd blocks validate (a lone block is
cut in two halves).

The settings and their TOML form are :mod:`mavsid.pipeline_config`'s, the split
:func:`mavsid.split.split_segments` (both re-exported here).
"""

from __future__ import annotations

import dataclasses
import math
import os
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from mavsid.autopilot.presets import QUADPLANE
from mavsid.axes import AXES, INPUT_OF, RATE_OF, RATES
from mavsid.channels import source_text
from mavsid.data import FlightData, Segment, SysidRun
from mavsid.errors import (
    ConfigError,
    DataQualityWarning,
    MavsidError,
    NoExcitationError,
    escape,
)
from mavsid.pipeline_config import ESTIMATORS, PipelineConfig, config_from_dict, load_config
from mavsid.split import split_segments
from mavsid.threads import one_blas_thread
from mavsid.validation import Model, Validation, validate
from mavsid.verdict import Verdict, format_fit, judge, not_identified, unfitted

if TYPE_CHECKING:
    from mavsid.excitation import WindowReport
    from mavsid.frequency_fit import PlantTF
    from mavsid.loop.emulation import ControllerEmulation
    from mavsid.loop.twin import ClosedLoopFit, TwinSignals

__all__ = [
    "AXES",
    "ESTIMATORS",
    "AxisFit",
    "FitResult",
    "PipelineConfig",
    "config_from_dict",
    "find_windows",
    "fit",
    "format_result",
    "json_safe",
    "load_config",
    "load_models",
    "split_segments",
    "validate_line",
    "validate_logs",
    "validation_figures",
]

#: The horizon (s) reported between one step and free run (``fit_percent["0.5s"]``).
SUMMARY_HORIZON_S = 0.5


# --------------------------------------------------------------------------- results


@dataclass(frozen=True)
class AxisFit:
    """One axis: the fitted model, its validation and the segments used for each."""

    axis: str
    model: Model
    validation: Validation
    train: tuple[Segment, ...]
    held_out: tuple[Segment, ...]
    estimator: str = ""
    windows: tuple[WindowReport, ...] = ()
    verdict: Verdict | None = None
    #: the closed-loop twin on the held-out blocks (:mod:`mavsid.loop`); None when it could
    #: not run, ``closed_loop_note`` saying why
    closed_loop: ClosedLoopFit | None = None
    closed_loop_note: str = ""
    #: the rebuilt controller replayed on the logged rate and target against the logged
    #: output (:mod:`mavsid.loop.emulation`), run before the twin; the twin is not run when
    #: it fails
    emulation: ControllerEmulation | None = None
    #: the plant's transfer function fitted to its response measured against the SYSTEMID
    #: injection (:func:`mavsid.frequency.fit_plant`); None when there is none, ``frequency_note``
    #: saying why
    frequency: PlantTF | None = None
    frequency_note: str = ""

    @property
    def output(self) -> str:
        """The output that represents the axis (its body rate when the model predicts it)."""
        rate = RATE_OF.get(self.axis, "")
        return rate if rate in self.validation.state_names else self.validation.state_names[0]

    def to_dict(self) -> dict[str, Any]:
        """The JSON form of ``mavsid fit --json`` for this axis."""
        v = self.validation
        stderr = getattr(self.model, "stderr", {}) or {}
        units = getattr(self.model, "units", {}) or {}
        prov = dict(getattr(self.model, "provenance", {}) or {})
        return json_safe(
            {
                "output": self.output,
                "estimator": self.estimator,
                "dt_s": round(v.dt, 9),
                "delay_samples": int(getattr(self.model, "delay", 0)),
                "delay_s": round(float(getattr(self.model, "delay_s", 0.0)), 9),
                "input_lag_s": prov.get("lag_s"),
                "filters": prov.get("filters", []),
                "params": dict(self.model.params),
                "stderr": dict(stderr),
                "units": dict(units),
                "fit_percent": v.fit_summary(self.output, (SUMMARY_HORIZON_S,)),
                "fit_vs_horizon": {
                    state: {
                        "horizon_s": [*np.round(v.horizons_s, 9).tolist(), "free_run"],
                        "fit_percent": [*v.fit_vs_horizon[:, j].tolist(), v.fit_free_run[j]],
                    }
                    for j, state in enumerate(v.state_names)
                },
                "rmse": {
                    s: {"one_step": v.rmse_one_step[j], "free_run": v.rmse_free_run[j]}
                    for j, s in enumerate(v.state_names)
                },
                "verdict": None if self.verdict is None else self.verdict.to_dict(),
                "closed_loop": _closed_loop_dict(self),
                "closed_loop_note": self.closed_loop_note,
                "frequency_response": _frequency_dict(self),
                "frequency_response_note": self.frequency_note,
                "stable": v.stable,
                "eigenvalues": (
                    None
                    if v.eigenvalues is None
                    else [[float(z.real), float(z.imag)] for z in v.eigenvalues]
                ),
                "residual_whiteness": {
                    "band": v.residuals.band,
                    "autocorr_outside": dict(
                        zip(v.state_names, v.residuals.autocorr_outside.tolist(), strict=True)
                    ),
                    "crosscorr_outside": {
                        f"{u}->{y}": v.residuals.crosscorr_outside[i, j]
                        for i, u in enumerate(v.input_names)
                        for j, y in enumerate(v.state_names)
                    },
                },
                "train_segments": [[s.start_s, s.stop_s] for s in self.train],
                "validation_segments": [[s.start_s, s.stop_s] for s in self.held_out],
                "train_segment_logs": [s.log for s in self.train],
                "validation_segment_logs": [s.log for s in self.held_out],
            }
        )


def _frequency_dict(fitted: AxisFit) -> dict[str, Any] | None:
    """The ``frequency_response`` of ``fit --json``: the measured response, the fitted
    transfer function, and the axis model's response at the same frequencies."""
    tf = fitted.frequency
    if tf is None:
        return None
    out = dict(tf.to_dict())
    check = model_response_check(fitted.model, fitted.axis, tf)
    if check is not None:
        out.update({"tf_magnitude_db": out.pop("model_magnitude_db", None),
                    "tf_phase_deg": out.pop("model_phase_deg", None),
                    "model_magnitude_db": check.pop("magnitude_db"),
                    "model_phase_deg": check.pop("phase_deg")})
        out["model_check"] = check
    return out


def model_response_check(model: Model, axis: str, tf: PlantTF) -> dict[str, Any] | None:
    """The axis model's plant response (input to rate) against the measured one
    (``tf.measured``): at the measured frequencies its magnitude (dB) and phase (degrees),
    and over the trusted band the coherence-weighted RMS errors (dB, degrees); None when the
    model is not a rate plant the loop can rebuild."""
    from mavsid.frequency import MIN_COHERENCE
    from mavsid.frequency_fit import rms_errors
    from mavsid.loop.plant import plant_from_model, plant_response

    m = tf.measured
    if m is None:
        return None
    try:
        h = plant_response(plant_from_model(model, axis), m.freq_hz)
    except (MavsidError, ValueError, np.linalg.LinAlgError):
        return None
    band = (m.freq_hz >= tf.band_hz[0]) & (m.freq_hz <= tf.band_hz[1]) & (m.trust >= MIN_COHERENCE)
    db, deg = rms_errors(m.response[band], h[band], m.trust[band])
    with np.errstate(divide="ignore"):
        mag = 20 * np.log10(np.abs(h))
    return {"magnitude_db": mag.tolist(), "phase_deg": np.degrees(np.unwrap(np.angle(h))).tolist(),
            "rms_db": db, "rms_deg": deg, "band_hz": list(tf.band_hz)}


@dataclass(frozen=True)
class FitResult:
    """The outcome of :func:`fit` or :func:`validate_logs`."""

    axes: Mapping[str, AxisFit]
    flights: tuple[FlightData, ...]
    logs: tuple[str, ...]
    config: PipelineConfig = field(default_factory=PipelineConfig)
    #: A verdict for every axis asked for, fitted or not (fitted ones: ``axes[a].verdict``).
    verdicts: Mapping[str, Verdict] = field(default_factory=dict)
    #: The twin's signals of each flight (in ``flights`` order) when the fit had them, for
    #: later analyses (:func:`mavsid.loop.tune.tune`) not to read the logs again.
    twins: tuple[TwinSignals, ...] | None = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict[str, Any]:
        """``{"axes": {axis: {...}}, "verdicts": {axis: {...}}, "logs": [...], ...}``."""
        return {
            "axes": {a: f.to_dict() for a, f in self.axes.items()},
            "verdicts": {a: v.to_dict() for a, v in self.verdicts.items()},
            "logs": list(self.logs),
            "presets": sorted({fd.preset for fd in self.flights}),
            "pipeline": self.config.name,
            "data": [json_safe({"log": fd.source.path,
                                 "boot": fd.boot.to_dict() if fd.boot else None,
                                 "excluded_samples": fd.excluded_samples})
                     for fd in self.flights],
        }

    def models_dict(self) -> dict[str, Any]:
        """The fitted models in the form :func:`validate_logs` reads back."""
        return {
            "mavsid_models": 1,
            "axes": {a: f.model.to_dict() for a, f in self.axes.items()},  # type: ignore[attr-defined]
        }


def json_safe(x: Any) -> Any:
    """``x`` ready for JSON: NaN/inf -> None, numpy scalars and arrays -> Python, recursively.

    Examples
    --------
    >>> json_safe({"a": np.float64("nan"), "b": np.arange(2), "c": (1.5, np.int64(3))})
    {'a': None, 'b': [0, 1], 'c': [1.5, 3]}
    """
    if isinstance(x, Mapping):
        return {str(k): json_safe(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [json_safe(v) for v in x]
    if isinstance(x, np.ndarray):
        return json_safe(x.tolist())
    if isinstance(x, bool | np.bool_):
        return bool(x)
    if isinstance(x, int | np.integer):
        return int(x)
    if isinstance(x, float | np.floating):
        return float(x) if math.isfinite(float(x)) else None
    return x


# --------------------------------------------------------------------------- running


#: Per flight (by ``id``): its twin's signals, or why they could not be had.
_Twins = dict[int, "TwinSignals | MavsidError | ValueError | np.linalg.LinAlgError"]


def _read_flight(path: str | os.PathLike[str], cfg: PipelineConfig,
                 twins: _Twins | None = None) -> FlightData:
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
    injection = _injection(flight, raw)
    if injection is not None:  # (the reference of the plant's measured response)
        flight = dataclasses.replace(flight, sysid_injection=injection,
                                     inputs_at_state_times=_inputs_interpolated(flight, raw))
    if twins is not None:
        from mavsid.loop.twin import twin_signals

        try:
            twins[id(flight)] = twin_signals(flight, raw)
        except (MavsidError, ValueError, np.linalg.LinAlgError) as exc:
            twins[id(flight)] = exc  # (raised where the twin runs, as a second read would)
    return flight


def _inputs_interpolated(flight: FlightData, raw: Any) -> dict[str, np.ndarray]:
    """The inputs interpolated between their native samples like the states, not held: a
    held input lags an interpolated state by up to a sample (its share depending on where
    the grid falls between the records), a delay the frequency response would take for the
    plant's. Per input whose source is one message's field (``FlightData.sources``): the held
    grid values mapped back to the native sample each holds, then interpolated."""
    out: dict[str, np.ndarray] = {}
    sources = flight.sources
    t = flight.time_s
    for j, name in enumerate(flight.input_names):
        src = sources.get(name, "")
        msg = src.split(".")[0]
        if "." not in src or msg not in raw.messages or len(raw.messages[msg]) < 2:
            continue
        tn = np.sort(np.asarray(raw.messages[msg].time_s, dtype=float))
        i = np.searchsorted(tn, t + 1e-6 * flight.dt, side="right") - 1
        first = np.concatenate([[True], i[1:] != i[:-1]]) & (i >= 0)
        if first.sum() < 2:
            continue
        out[name] = np.interp(t, tn[i[first]], flight.inputs[first, j])
    return out


def _injection(flight: FlightData, raw: Any) -> np.ndarray | None:
    """SYSTEMID's injected waveform held on ``flight``'s grid (NaN where no record lies
    within two of its steps), whatever the injection point: the reference its plant response
    is measured against."""
    from mavsid.autopilot.presets import INJECTION_CHANNEL
    from mavsid.channels import evaluate

    if not flight.sysid_runs or INJECTION_CHANNEL.message not in raw.messages:
        return None
    try:
        t, v = evaluate(raw, INJECTION_CHANNEL, "SYSTEMID injection")
    except MavsidError:
        return None
    order = np.argsort(t, kind="stable")
    t, v = t[order], v[order]
    if t.size < 2:
        return None
    i = np.clip(np.searchsorted(t, flight.time_s + 1e-9, side="right") - 1, 0, None)
    out = v[i].astype(float)
    step = float(np.median(np.diff(t)))
    out[(flight.time_s < t[0]) | (flight.time_s - t[i] > 2 * max(step, flight.dt))] = np.nan
    return out


def _read_flights(logs: Sequence[str | os.PathLike[str]], cfg: PipelineConfig,
                  step: Callable[[str], None], twins: _Twins | None = None
                  ) -> tuple[FlightData, ...]:
    """Each log aligned; unless the config fixes the rate, later logs at the first one's
    (pooled segments and one model need one step)."""
    step(f"reading {os.fspath(logs[0])}")
    first = _read_flight(logs[0], cfg, twins)
    same_rate = cfg if cfg.rate_hz is not None else cfg.with_overrides(rate_hz=1.0 / first.dt)
    flights = [first]
    for p in logs[1:]:
        step(f"reading {os.fspath(p)}")
        flights.append(_read_flight(p, same_rate, twins))
    slow = [(fd, rate) for fd in flights[1:]
            if (rate := _slowest_rate(fd)) is not None and rate < POOL_RATE_RATIO / fd.dt]
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


def _slowest_rate(fd: FlightData,
                  names: Sequence[str] = (*RATES, *INPUT_OF.values())
                  ) -> float | None:
    """The slowest native rate (Hz) of a flight's channels ``names`` (default: the body
    rates and attitude inputs the rate models are fitted on), if known."""
    native = fd.native_rate_hz
    rates = [float(native[n]) for n in names if native.get(n)]
    return min(rates) if rates else None


def _windows(flight: FlightData, axis: str, cfg: PipelineConfig) -> list[WindowReport]:
    """Every window considered on ``axis``, kept or rejected, as the config asks."""
    from mavsid.excitation import ScanOptions, find_segments

    options = ScanOptions.from_options(cfg.segment_options)
    scan = {"auto": None, "sysid": False, "scan": True}[cfg.segment_source]
    reports = find_segments(flight, axis, scan=scan, options=options)
    if cfg.segment_source == "scan":
        reports = [r for r in reports if r.source == "scan"]
    return [r for r in reports if r.axis == axis]


def _axis_segments(
    flights: Sequence[FlightData], axis: str, cfg: PipelineConfig
) -> tuple[tuple[WindowReport, ...], tuple[Segment, ...]]:
    """Every window considered for ``axis`` over all flights, and the kept segments."""
    from mavsid.excitation import select_segments

    reports = [(fd, _windows(fd, axis, cfg)) for fd in flights]
    windows = tuple(r for _, rs in reports for r in rs)
    segs = tuple(s for fd, rs in reports for s in select_segments(fd, reports=rs))
    return windows, segs


def _validate(model: Model, segments: Sequence[Segment], cfg: PipelineConfig) -> Validation:
    """Validate ``model`` on ``segments`` with the config's horizons and residual settings."""
    return validate(
        model,
        segments,
        horizons_s=(*cfg.horizons_s, SUMMARY_HORIZON_S),
        max_lag=cfg.max_lag,
        fft_window_s=cfg.fft_window_s,
    )


def _closed_loop_dict(fitted: AxisFit) -> dict[str, Any] | None:
    """``fit --json``'s ``closed_loop``: the twin's figures and the controller emulation (only
    the emulation when it failed and the twin was not run; None when neither ran)."""
    out = None if fitted.closed_loop is None else fitted.closed_loop.to_dict()
    if fitted.emulation is not None:
        out = {**(out or {}), "emulation": fitted.emulation.to_dict()}
    return out


def _closed_loop(
    fitted: AxisFit, flights: Sequence[FlightData], signals: _Twins
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


def _missing_rate(axis: str, flights: Sequence[FlightData]) -> str:
    """Why ``axis`` cannot be modelled for want of its body rate (empty when it is logged)."""
    rate = RATE_OF.get(axis, "")
    lacking = [fd for fd in flights if rate and rate not in fd.state_names]
    if not lacking:
        return ""
    fd = lacking[0]
    return (f"no body rate {rate} in {os.path.basename(fd.source.path)} (preset {fd.preset}: "
            "attitude angles only): the rate dynamics need a gyro log (ArduPilot RATE or IMU, "
            "PX4 vehicle_angular_velocity)")


def _fit_model(train: Sequence[Segment], axis: str, cfg: PipelineConfig,
               choose: Any = None) -> Model:
    from mavsid import estimators

    options = dict(cfg.model_options)
    if choose is not None:
        options["choose_structure"] = choose
    model: Model = estimators.fit_axis(list(train), axis=axis, estimator=cfg.estimator,
                                       **options)
    return model


def _frf_chooser(axis: str, flights: Sequence[FlightData], signals: _Twins,
                 cfg: PipelineConfig) -> Any:
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


def _logged_around(fd: FlightData, ref: np.ndarray, i0: int, i1: int) -> tuple[int, int]:
    """``[i0, i1)`` widened to all the injection's records around it (its fades and the
    quiet records after the sweep, within the flight's block): the spectra then see the
    noise where the sweep is not, and a frequency the sweep passes in one window is not
    coherent by the window's count alone."""
    block = next(((int(a), int(b)) for a, b in fd.blocks if a <= i0 < b), (i0, i1))
    ok = np.isfinite(ref)
    a, b = i0, i1
    while a > block[0] and ok[a - 1]:
        a -= 1
    while b < block[1] and ok[b]:
        b += 1
    return a, b


#: A SYSTEMID run whose |roll| or |pitch| passes this within :data:`ROLLOVER_AFTER_S` of its
#: end ended in a roll-over: no multicopter controller leans that far on purpose (ArduCopter's
#: ANGLE_MAX is 30° by default and 80° at most; a SYSTEMID chirp adds tens of degrees), and a
#: quad past it has lost the lift that holds it: what follows is a crash, not a response.
ROLLOVER_DEG = 75.0
#: How long after a run's end its roll-over is still the run's (the vehicle falls over in
#: about a second, and the mode's end is logged first)
ROLLOVER_AFTER_S = 3.0


def _rollover(fd: FlightData, i0: int, i1: int, sid: int) -> str:
    """Why the SYSTEMID run ``[i0, i1)`` (``SID_AXIS`` ``sid``) is refused for ending in a
    roll-over (:data:`ROLLOVER_DEG`), or ``""``."""
    end = int(np.searchsorted(fd.time_s, fd.time_s[i1 - 1] + ROLLOVER_AFTER_S, side="right"))
    worst: tuple[float, str, float] | None = None
    for name in ("roll", "pitch"):
        if name not in fd.state_names:
            continue
        v = np.degrees(np.abs(fd.states[i0:end, fd.state_names.index(name)]))
        k = int(np.argmax(v > ROLLOVER_DEG)) if np.any(v > ROLLOVER_DEG) else -1
        if k >= 0 and (worst is None or fd.time_s[i0 + k] < worst[2]):
            worst = (float(np.nanmax(v)), name, float(fd.time_s[i0 + k]))
    if worst is None:
        return ""
    return (f"SYSTEMID run (SID_AXIS {sid}, {fd.time_s[i0]:.1f}–{fd.time_s[i1 - 1]:.1f} s) ends "
            f"in a roll-over: |{worst[1]}| passes {ROLLOVER_DEG:g}° at t={worst[2]:.1f} s "
            f"(reaching {worst[0]:.0f}°): the vehicle was lost")


def _injected_nothing(run: SysidRun) -> str:
    """Why a SYSTEMID run whose waveform is zero throughout (``injected`` False) is refused.

    Examples
    --------
    >>> print(_injected_nothing(SysidRun(3899.27, 3908.8, "PARM", axis=1, injected=False)))
    SYSTEMID mode (SID_AXIS 1) 3899.3–3908.8 s injected nothing (SIDD.Targ is 0 throughout, \
SIDS not logged)
    """
    sids = "" if run.settings_from == "SIDS" else ", SIDS not logged"
    return (f"SYSTEMID mode (SID_AXIS {run.sid_axis}) {run.start_s:.1f}–"
            f"{run.stop_s:.1f} s injected nothing (SIDD.Targ is 0 throughout{sids})")


def plant_fit(axis: str, flights: Sequence[FlightData]) -> tuple[PlantTF | None, str, bool]:
    """The plant's response on the axis's SYSTEMID runs measured against the injection
    (``H = S_ry / S_ru``, ``r`` the waveform ``SIDD.Targ``, ``u`` the mixer input, ``y`` the
    rate: the feedback does not bias it, whatever the injection point) and the transfer
    function fitted on its trusted band (:func:`mavsid.frequency.fit_plant`); or None and
    why not. The flag says the runs are refused (the reason then the one line to give): one
    injected nothing (its waveform zero throughout), one ends in a roll-over
    (:data:`ROLLOVER_DEG`), or the injection excites nothing above the noise (no frequency
    of the sweep where the input and the rate are coherent with it)."""
    from mavsid.frequency import MIN_COHERENCE, frf, sysid_spans
    from mavsid.frequency_fit import fit_plant

    rate, u_name = RATE_OF[axis], f"u_{axis}"
    us: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    rs: list[np.ndarray] = []
    bands: list[tuple[float, float]] = []
    settings: list[SysidRun] = []
    dt = 0.0
    for fd in flights:
        ref = fd.sysid_injection
        if (ref is None or rate not in fd.state_names
                or u_name not in fd.input_names):
            continue
        runs = {r.sid_axis: r for r in fd.sysid_runs}
        for i0, i1, sid in sysid_spans(fd, axis):
            if not runs[sid].injected:
                return None, _injected_nothing(runs[sid]), True
            lost = _rollover(fd, i0, i1, sid)
            if lost:
                return None, lost, True
            settings.append(runs[sid])
            lo, hi = runs[sid].f_start_hz, runs[sid].f_stop_hz
            if lo and hi:
                bands.append((float(lo), float(hi)))
            i0, i1 = _logged_around(fd, ref, i0, i1)
            u = fd.inputs_at_state_times.get(u_name, fd.inputs[:, fd.input_names.index(u_name)])
            us.append(u[i0:i1])
            ys.append(fd.states[i0:i1, fd.state_names.index(rate)])
            rs.append(ref[i0:i1])
            dt = fd.dt
    if not us:
        return None, "no SYSTEMID run on this axis with its injection logged", False
    # a channel logged slower than the grid holds nothing above its own Nyquist frequency
    native = [float(r) for fd in flights
              for n in (rate, u_name) if (r := fd.native_rate_hz.get(n))]
    top = 0.4 * min([1.0 / dt, *native])
    excited = (min(b[0] for b in bands), min(max(b[1] for b in bands), top)) if bands \
        else (0.0, top)
    if excited[1] <= excited[0]:
        return None, (f"{u_name} and {rate} logged at {min(native):.3g} Hz: nothing of the "
                      f"sweep above {excited[0]:.3g} Hz is resolved"), False
    try:
        measured = frf(us, ys, dt, reference=rs, names=(u_name, rate),
                       f_min_hz=excited[0] or None, f_max_hz=excited[1])
    except (MavsidError, ValueError, np.linalg.LinAlgError) as exc:
        return None, str(exc), False
    inside = (measured.freq_hz >= excited[0]) & (measured.freq_hz <= excited[1])
    # excitation judged by the response: the rate's coherence with the injection (a slowly
    # logged input is incoherent for want of samples, not of excitation)
    parts = measured.coherence_parts
    trust = np.where(inside, parts[1] if parts is not None else measured.coherence, 0.0)
    if not np.any(trust >= MIN_COHERENCE):
        k = int(np.argmax(trust))
        from mavsid.autopilot.ardupilot import sid_axis

        mags = sorted({r.magnitude for r in settings if r.magnitude})
        sids = sorted({r.sid_axis for r in settings})
        unit = {"input angle": "°", "recovery angle": "°", "rate": "°/s"}.get(
            sid_axis(sids[0])[1], "") if len(sids) == 1 else ""
        mag = f", magnitude {'/'.join(f'{m:g}{unit}' for m in mags)}" if mags else ""
        return None, (
            f"SYSTEMID run (SID_AXIS {'/'.join(map(str, sids))}{mag}, {excited[0]:g}–"
            f"{excited[1]:g} Hz) excites nothing above the noise: the rate is coherent with "
            f"the injection at no frequency of the sweep (at best γ² "
            f"{trust[k]:.2f} at {measured.freq_hz[k]:.2g} Hz, {MIN_COHERENCE:g} needed)"), True
    try:
        return fit_plant(measured, excited_hz=excited), "", False
    except (MavsidError, ValueError, np.linalg.LinAlgError) as exc:
        return None, str(exc), False


def _tf_chooser(axis: str, tf: PlantTF | None, cfg: PipelineConfig) -> Any:
    """The structure chooser from the injection-referenced response :func:`plant_fit`
    measured (:class:`mavsid.frequency.FrfStructure`: the lag and delay candidates scored
    against it; the coefficients stay the data's), None without one or where the
    configuration fixes the delay or lags."""
    if tf is None or tf.measured is None or {"delay", "delays", "lags_s"} & set(cfg.model_options):
        return None
    from mavsid.frequency import FrfStructure

    step = cfg.model_options.get("delay_step")
    chooser = FrfStructure(tf.measured, axis, **({"delay_step": float(step)} if step else {}))
    return chooser.__call__


def disagrees(model: Model, axis: str, tf: PlantTF) -> bool:
    """Whether a time-domain ``model`` disagrees with the accepted transfer function ``tf``
    fitted to the response measured against the injection: an unstable pole, an
    effectiveness more than :data:`mavsid.verdict.AGREE_SIGMAS` σ away, or a response off the
    measured one by more than :data:`mavsid.verdict.MAX_RESPONSE_RMS_DB` /
    :data:`~mavsid.verdict.MAX_RESPONSE_RMS_DEG` RMS over its trusted band."""
    from mavsid.verdict import AGREE_SIGMAS, MAX_RESPONSE_RMS_DB, MAX_RESPONSE_RMS_DEG

    if not tf.accepted:
        return False
    rate = RATE_OF[axis]
    params, stderr = dict(getattr(model, "params", {})), dict(getattr(model, "stderr", {}))
    name = f"B[{rate},u_{axis}]"
    b_td, s_td = params.get(name, math.nan), stderr.get(name, math.nan)
    if params.get(f"A_d[{rate},{rate}]", 0.0) > 1.0:
        return True
    if math.isfinite(b_td) and abs(b_td - tf.gain) > AGREE_SIGMAS * math.hypot(
            s_td if math.isfinite(s_td) else 0.0, tf.stderr["gain"]):
        return True
    check = model_response_check(model, axis, tf)
    return check is not None and not (check["rms_db"] <= MAX_RESPONSE_RMS_DB
                                      and check["rms_deg"] <= MAX_RESPONSE_RMS_DEG)


def _take_lag(lag_s: float, delay: float) -> Callable[[Mapping[float, Any]], tuple[float, float]]:
    """A ``choose_structure`` that takes the candidate lag nearest ``lag_s`` at ``delay``
    samples (the search always tries no lag too, and prefers it unless it scores worse)."""
    def choose(models: Mapping[float, Any]) -> tuple[float, float]:
        return min(models, key=lambda lag: abs(lag - lag_s)), delay

    return choose


def _tf_structure(tf: PlantTF | None, cfg: PipelineConfig, train: Sequence[Segment]
                  ) -> dict[str, Any] | None:
    """The time-domain structure of the transfer function :func:`plant_fit` fitted to the
    response measured against the injection: its lag and its delay, no further filter (the
    measured response holds the gyro filter's, which the lag and delay took); None without
    an accepted one or where the configuration fixes the delay, lags or filters."""
    if (tf is None or not tf.accepted or not train
            or {"delay", "delays", "lags_s", "filters"} & set(cfg.model_options)):
        return None
    # a held input adds half a step to a discrete model's delay (its response is the
    # continuous one times e^{-jω dt/2}): the model's delay is the rest
    dt = float(train[0].dt)
    return {"filters": (), "lags_s": (round(tf.lag_s, 6),),
            "delay": round(max(tf.delay_s / dt - 0.5, 0.0), 6)}


def frequency_estimate(model: Model, axis: str, tf: PlantTF) -> Model:
    """``model`` (its structure: filters, lag, delay, trim) with its pole and effectiveness
    estimated from the response measured against the injection instead
    (:meth:`mavsid.frequency.FrfStructure.estimate`): on closed-loop data a time-domain fit is
    biased by the noise the feedback puts into its input, the response against the injection
    is not. Their σ are the transfer function's (relative σ of B; the pole's of a first-order
    fit), the time-domain estimate is kept in ``provenance["time_domain_estimate"]``.
    ``model`` itself where the response cannot give one. (The pipeline takes it where the
    time-domain fit :func:`disagrees` with the response.)"""
    from mavsid.estimators.model import Model as Fitted
    from mavsid.frequency import FrfStructure

    if not isinstance(model, Fitted) or tf.measured is None:
        return model
    rate, u_name = RATE_OF[axis], f"u_{axis}"
    i_a, i_b = model.features.index(rate), model.features.index(u_name)
    prov0: dict[str, Any] = dict(model.provenance or {})
    dt = float(model.dt)
    known = [f for f in prov0.get("filters") or () if not str(
        dict(f).get("source", "")).startswith("input lag")]
    if (not known and abs(float(prov0.get("lag_s") or 0.0) - tf.lag_s) < 1e-5
            and abs((model.delay + model.delay_frac + 0.5) * dt - tf.delay_s) < 1e-5):
        # the model holds the transfer function's own lag and delay: its pole and gain are
        # the transfer function's, discretised for the held input
        coef = np.asarray(model.coef).astype(float)
        a_d = math.exp(-tf.pole * dt)
        coef[i_a, 0] = a_d
        coef[i_b, 0] = tf.gain * dt if tf.pole == 0 else tf.gain * (1 - a_d) / tf.pole
        est: Fitted | None = dataclasses.replace(model, coef=coef)
    else:
        est = FrfStructure(tf.measured, axis).estimate(model)
    if est is None:
        return model
    se = (np.asarray(model.coef_stderr).astype(float) if model.coef_stderr is not None
          else np.full(model.coef.shape, np.nan))
    b = float(est.coef[i_b, 0])
    se[i_b, 0] = abs(b) * tf.stderr.get("gain", math.nan) / tf.gain
    se[i_a, 0] = float(model.dt) * max(tf.stderr.get("pole", 0.0), 0.0)
    cov = None
    if model.covariance is not None:
        cov = np.asarray(model.covariance).astype(float)
        for i in (i_a, i_b):  # (uncorrelated with the trim: estimated apart)
            cov[0, i, :] = cov[0, :, i] = 0.0
            cov[0, i, i] = se[i, 0] ** 2
    prov = {**dict(model.provenance or {}),
            "estimated_from": "the frequency response against the SYSTEMID injection",
            "time_domain_estimate": {"params": dict(model.params),
                                     "stderr": dict(model.stderr)}}
    return dataclasses.replace(est, coef_stderr=se, covariance=cov, provenance=prov)


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

    def __call__(self, models: Any) -> None:
        return None

    def estimate(self, model: Any) -> Any:
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
    signals: _Twins = {}
    flights = _read_flights(logs, cfg, step, signals)
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
        windows, segs = _axis_segments(flights, axis, cfg)
        missing = _missing_rate(axis, flights)
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
                               or _tf_chooser(axis, tf, cfg)
                               or _instrument_check(axis, flights, train))
            structure = (_tf_structure(tf, cfg, train)
                         if tf is not None and disagrees(model, axis, tf) else None)
            if tf is not None and structure is not None:
                # refitted with the structure the measured response supports, then its pole
                # and effectiveness taken from the response (the time-domain fit is biased)
                fit_cfg = dataclasses.replace(cfg, model_options={**dict(cfg.model_options),
                                                                  **structure})
                model = frequency_estimate(
                    _fit_model(train, axis, fit_cfg, _take_lag(structure["lags_s"][0],
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
    got = _frequency_dict(fitted)
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
    native = _read_flights(logs, cfg, step)
    first = native[0]
    on_model_grid: dict[float, tuple[FlightData, ...]] = {}
    fits: dict[str, AxisFit] = {}
    verdicts: dict[str, Verdict] = {}
    signals: _Twins = {}
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
                    on_model_grid[model.dt] = tuple(_read_flight(p, grid) for p in logs)
                flights = on_model_grid[model.dt]
                note = "; ".join(filter(None, [str(exc), _resampling_note(model, flights)]))
        windows, segs = _axis_segments(flights, axis, cfg)
        missing = _missing_rate(axis, flights)
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
        slow = _slowest_rate(fd, (*model.state_names, *model.input_names))
        if slow is None:
            continue
        if abs(slow - model_hz) > 0.05 * model_hz:
            how = ("upsampled: states interpolated, inputs held, one-step fit optimistic"
                   if slow < model_hz else "downsampled to the model's step")
            notes.append(f"{os.path.basename(fd.source.path)} logged at {slow:.3g} Hz, "
                         f"resampled onto the model's {model_hz:.3g} Hz grid ({how})")
    return "; ".join(notes)


def find_windows(
    log: str | os.PathLike[str], config: PipelineConfig | None = None
) -> tuple[FlightData, dict[str, list[WindowReport]]]:
    """Read and align one log and find its windows per axis (for viewing without a model)."""
    cfg = config or PipelineConfig()
    flight = _read_flight(log, cfg)
    return flight, {axis: _windows(flight, axis, cfg) for axis in cfg.axes}


def _pm(value: float, sigma: float | None) -> str:
    text = f"{value:.6g}" if math.isfinite(value) else "nan"
    if sigma is not None and math.isfinite(sigma):
        text += f" ± {sigma:.2g}"
    return text


def _structure(d: Mapping[str, Any]) -> str:
    """The modelled filters (beside the input lag), as the text table's head shows them."""
    parts = []
    for flt in d.get("filters") or ():
        if not str(flt.get("source", "")).startswith("input lag"):
            parts.append(f"{flt.get('source') or 'filter'} {flt.get('cutoff_hz', 0):.3g} Hz")
    return "".join(f", {p}" for p in parts)


def _frequency_line(f: AxisFit) -> str:
    """The transfer function fitted to the response measured against the injection, and the
    model's error against that response."""
    tf = f.frequency
    assert tf is not None
    sd = tf.stderr
    pole = ("" if tf.structure == "integrator"
            else f", pole {tf.pole:.3g} ± {sd.get('pole', math.nan):.2g} 1/s")
    text = (f"frequency response (against the injection): {tf.structure.replace('_', ' ')} "
            f"B {tf.gain:.4g} ± {sd['gain']:.2g}{pole}, lag {tf.lag_s * 1e3:.3g} ± "
            f"{sd['lag_s'] * 1e3:.2g} ms, delay {tf.delay_s * 1e3:.3g} ± {sd['delay_s'] * 1e3:.2g}"
            f" ms, J {tf.cost:.3g}, band {tf.band_hz[0]:.2g}–{tf.band_hz[1]:.3g} Hz")
    check = model_response_check(f.model, f.axis, tf)
    if check is not None:
        text += f"; model {check['rms_db']:.2g} dB / {check['rms_deg']:.2g}° RMS"
    return text


def _emulation_line(e: ControllerEmulation) -> str:
    """The controller emulation's figures, one line.

    Examples
    --------
    >>> from mavsid.loop.emulation import ControllerEmulation, TermFit
    >>> e = ControllerEmulation(93.4, 0.0031, True, "", 0.047, 1, 0.0, "RATE.ROut",
    ...                         (TermFit("P", "PIDR.P", 97.0, 0.001, 0.03, 0.03),))
    >>> _emulation_line(e)
    'controller emulation: 93.4 % of RATE.ROut (RMS 0.0031 of 0.047; pass >= 80 %); P 97.0 %'
    """
    def pct(x: float) -> str:
        return "n/a" if not math.isfinite(x) else f"{x:.1f} %"

    text = (f"controller emulation: {pct(e.fit_percent)} of {e.output_source} (RMS "
            f"{e.rms:.2g} of {e.output_rms:.2g}; pass >= {e.threshold_percent:g} %)")
    if e.terms:
        text += "; " + ", ".join(f"{t.term} {pct(t.fit_percent)}" for t in e.terms)
    if not e.passed:
        text += f": FAILED, {e.reason}"
    return text


def _closed_loop_line(f: AxisFit) -> str:
    """The closed-loop twin's figures (or why there are none), one line."""
    cl = f.closed_loop
    if cl is None:
        return f"closed loop: not run ({f.closed_loop_note or 'no rate target'})"

    def pct(x: float) -> str:
        return "n/a" if not math.isfinite(x) else f"{x:.1f}"

    text = (f"closed loop %  rate {pct(cl.fit_percent)}  output {pct(cl.output_fit_percent)}  "
            f"(baseline {pct(cl.baseline_percent)} at {cl.baseline_delay_s * 1e3:.0f} ms)")
    if cl.measurement_delay_loops:
        text += (f"; the controller read the rate {cl.measurement_delay_loops:g} loop after "
                 "the logged sample (replay on the training blocks)")
    if cl.defaults_used:
        text += f"; defaults used: {', '.join(cl.defaults_used)}"
    return text


def _si_unit(fd: FlightData, name: str) -> str:
    """The SI unit a flight channel is held in."""
    if name in fd.state_names:
        return fd.state_units[fd.state_names.index(name)]
    if name in fd.input_names:
        return fd.input_units[fd.input_names.index(name)]
    return "?"


def _physical_lines(axis: str, output: str, d: Mapping[str, Any]) -> list[str]:
    """What a tuner reads first: the rate response's time constant (and its corner, the
    open-loop bandwidth), the control effectiveness B, the delay and the input lag.

    Examples
    --------
    >>> d = {"params": {"A[p,p]": -3.98, "B[p,u_roll]": 177.76},
    ...      "stderr": {"A[p,p]": 0.12, "B[p,u_roll]": 3.7},
    ...      "units": {"B[p,u_roll]": "rad/s^2"}, "delay_s": 0.0056, "input_lag_s": 0.015}
    >>> print("\\n".join(_physical_lines("roll", "p", d)))
      time constant  0.251 ± 0.0076 s (bandwidth 0.63 Hz)
      effectiveness  B[p,u_roll] 177.8 ± 3.7 rad/s^2
      delay          5.6 ms, input lag 15.0 ms
    """
    params, stderr = d["params"], d["stderr"]
    lines = []
    a = params.get(f"A[{output},{output}]")
    if a is not None and math.isfinite(a) and a < 0:
        sa = stderr.get(f"A[{output},{output}]")
        sigma = "" if sa is None or not math.isfinite(sa) else f" ± {sa / a**2:.2g}"
        lines.append(f"  time constant  {-1 / a:.3g}{sigma} s (bandwidth "
                     f"{-a / (2 * math.pi):.2g} Hz)")
    elif a is not None and math.isfinite(a):
        lines.append(f"  time constant  none: A[{output},{output}] {a:.3g} 1/s >= 0 (an "
                     "integrator or unstable)")
    name = f"B[{output},u_{axis}]"
    b = params.get(name)
    if b is not None and math.isfinite(b):
        sb = stderr.get(name)
        sigma = "" if sb is None or not math.isfinite(sb) else f" ± {sb:.2g}"
        lines.append(f"  effectiveness  {name} {b:.4g}{sigma} {d['units'].get(name, '')}"
                     .rstrip())
    lag = d.get("input_lag_s")
    lines.append(f"  delay          {d['delay_s'] * 1e3:.1f} ms"
                 + (f", input lag {lag * 1e3:.1f} ms" if lag else ""))
    return lines


def validation_figures(v: Verdict) -> str:
    """An axis's fit % on a validation flight, for people (empty when it had no segment).

    Examples
    --------
    >>> validation_figures(Verdict("roll", "good", numbers={
    ...     "fit_one_step_pct": 99.1, "fit_0.5s_pct": 93.0, "fit_free_run_pct": 92.8}))
    'one step 99.1 %, 0.5 s 93.0 %, free run 92.8 %'
    """
    n = v.numbers
    if "fit_free_run_pct" not in n:
        return ""
    text = ", ".join(f"{what} {_pct_text(n.get(key))}" for what, key in (
        ("one step", "fit_one_step_pct"), ("0.5 s", "fit_0.5s_pct"),
        ("free run", "fit_free_run_pct")))
    if n.get("fit_closed_loop_pct") is not None:
        text += (f", closed-loop twin {_pct_text(n['fit_closed_loop_pct'])} (baseline "
                 f"{_pct_text(n.get('baseline_closed_loop_pct'))})")
    return text


def validate_line(v: Verdict) -> str:
    """A verdict as ``mavsid validate`` says it: the model against this flight, with the
    numbers (no advice: that is for the flight a model is fitted from).

    Examples
    --------
    >>> v = Verdict("roll", "not identified", ("free run diverges",), (),
    ...             {"fit_one_step_pct": 84.9, "fit_0.5s_pct": -3e5, "fit_free_run_pct": -3e5},
    ...             ("fly a chirp",))
    >>> validate_line(v)
    'roll: does not predict this flight: one step 84.9 %, 0.5 s diverges (< -100 %), free \
run diverges (< -100 %); free run diverges'
    """
    figures = validation_figures(v)
    said = "; ".join(v.reasons)
    if not figures and ("windows_rejected" in v.numbers
                        or any(w in said for w in ("no window", "no segment", "no body rate"))):
        return f"{v.axis}: nothing to validate on: {said}"
    if not figures:  # (validation ran and failed: the model's prediction is no number)
        return f"{v.axis}: does not predict this flight: {said}"
    if v.identified:
        head = f"{v.axis}: {v.level}" + (f" (for {', '.join(v.usable_for)})"
                                         if v.usable_for else "")
    else:
        head = f"{v.axis}: does not predict this flight"
    return f"{head}: {figures}" + "".join(f"; {r}" for r in v.reasons)


def _pct_text(value: float | None) -> str:
    """``93.4 %``, ``diverges (< -100 %)`` or ``n/a``."""
    text = format_fit(value)
    return text.replace(")", " %)") if text.startswith("diverges") else (
        text if text == "n/a" else f"{text} %")


def format_result(result: FitResult, validating: bool = False) -> str:
    """The compact per-axis table ``mavsid fit`` prints: the physical parameters a tuner
    reads (time constant, bandwidth, effectiveness, delay, lag), then every parameter ± σ
    (continuous-time, then the discrete-time coefficients), fit % on held-out data at one
    step, 0.5 s and free run, and the verdicts. ``validating``: as ``mavsid validate`` says
    them (the model against another flight: :func:`_validation_line`).

    Examples
    --------
    >>> print(format_result(FitResult({}, (), ("x.bin",))))
    x.bin: no axis fitted
    """
    logs = ", ".join(result.logs)
    if not result.axes:
        return f"{logs}: no axis fitted"
    lines = [f"{logs}: {len(result.axes)} axis model(s), fit % on held-out segments"]
    for fd in result.flights:  # what of each log was used (align's boot and exclusions)
        boot = fd.boot
        excluded = fd.excluded_samples
        if boot and boot.of > 1:
            lines.append(f"{fd.source.path}: boot {boot.used} of {boot.of} used "
                         f"({boot.start_s:.1f}–{boot.stop_s:.1f} s, {boot.reason})")
        if excluded:
            lines.append(f"{fd.source.path}: samples excluded, never fitted: "
                         + ", ".join(f"{k} {v}" for k, v in excluded.items()))
        sources = fd.sources
        used = [n for ax in result.axes.values() for n in (ax.output, f"u_{ax.axis}")]
        units_from = fd.units_from
        if sources:  # where each channel came from, read in what unit (declared, preset's,
            # inferred), in which SI unit
            lines.append(f"{fd.source.path}: preset {fd.preset}; " + ", ".join(
                f"{n} [{_si_unit(fd, n)}] <- {escape(source_text(sources[n], units_from.get(n)))}"
                for n in dict.fromkeys(used) if n in sources))
    for axis, f in result.axes.items():
        d = f.to_dict()
        train_s = sum(s.stop_s - s.start_s for s in f.train)
        val_s = sum(s.stop_s - s.start_s for s in f.held_out)
        stable = {True: "stable", False: "UNSTABLE", None: "stability n/a"}[f.validation.stable]
        lines.append(
            f"{axis} ({f.output}; {f.estimator or 'model'}; {1 / f.validation.dt:.0f} Hz"
            f"{_structure(d)}; train {len(f.train)} seg "
            f"{train_s:.1f} s, validation {len(f.held_out)} seg {val_s:.1f} s; {stable})"
        )
        lines += _physical_lines(axis, f.output, d)
        width = max((len(k) for k in d["params"]), default=0)
        # continuous-time parameters first, the discrete-time coefficients after them
        for name, value in sorted(d["params"].items(), key=lambda kv: "_d[" in kv[0]):
            sigma = d["stderr"].get(name)
            unit = d["units"].get(name, "")
            lines.append(
                f"  {name:<{width}}  {_pm(np.nan if value is None else value, sigma)} {unit}"
                .rstrip()
            )
        fp = d["fit_percent"]
        cells = "  ".join(f"{k.replace('_', '-')} {format_fit(fp[k])}" for k in fp)
        lines.append(f"  fit %  {cells}")
        if f.emulation is not None:
            lines.append(f"  {_emulation_line(f.emulation)}")
        lines.append(f"  {_closed_loop_line(f)}")
        if f.frequency is not None:
            lines.append(f"  {_frequency_line(f)}")
    verdicts = [validate_line(v) if validating else v.line()
                for v in result.verdicts.values()]
    if verdicts:
        lines.append("verdict:")
        lines += [f"  {v}" for v in verdicts]
    return "\n".join(lines)
