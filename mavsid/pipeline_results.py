"""What :func:`mavsid.pipeline.fit` and :func:`~mavsid.pipeline.validate_logs` return, and
its JSON form: :class:`AxisFit` per axis, :class:`FitResult` for the run, :func:`json_safe`
(the one sanitiser of every ``--json`` document)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from mavsid.axes import RATE_OF
from mavsid.data import FlightData, Segment
from mavsid.pipeline_config import PipelineConfig
from mavsid.pipeline_frequency import model_response_check
from mavsid.validation import Model, Validation
from mavsid.verdict import Verdict

if TYPE_CHECKING:
    from mavsid.excitation import WindowReport
    from mavsid.frequency_fit import PlantTF
    from mavsid.loop.emulation import ControllerEmulation
    from mavsid.loop.twin import ClosedLoopFit, TwinSignals

__all__ = ["SUMMARY_HORIZON_S", "AxisFit", "FitResult", "frequency_dict", "json_safe"]


#: The horizon (s) reported between one step and free run (``fit_percent["0.5s"]``).
SUMMARY_HORIZON_S = 0.5


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
                "frequency_response": frequency_dict(self),
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


def frequency_dict(fitted: AxisFit) -> dict[str, Any] | None:
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


def _closed_loop_dict(fitted: AxisFit) -> dict[str, Any] | None:
    """``fit --json``'s ``closed_loop``: the twin's figures and the controller emulation (only
    the emulation when it failed and the twin was not run; None when neither ran)."""
    out = None if fitted.closed_loop is None else fitted.closed_loop.to_dict()
    if fitted.emulation is not None:
        out = {**(out or {}), "emulation": fitted.emulation.to_dict()}
    return out


@dataclass(frozen=True)
class FitResult:
    """The outcome of :func:`~mavsid.pipeline.fit` or :func:`~mavsid.pipeline.validate_logs`."""

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
        """The fitted models in the form :func:`~mavsid.pipeline.validate_logs` reads back."""
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
