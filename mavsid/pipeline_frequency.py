"""The plant's response measured against the SYSTEMID injection, and what a fit takes from
it: :func:`plant_fit` (the response and its transfer function, or why a run is refused),
:func:`model_response_check` (a model against it), :func:`disagrees`, the structure it
supports (:func:`tf_structure`, :func:`tf_chooser`, :func:`take_lag`) and
:func:`frequency_estimate` (a model's pole and effectiveness from it)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from mavsid.axes import RATE_OF
from mavsid.data import FlightData, Segment, SysidRun
from mavsid.errors import MavsidError
from mavsid.pipeline_config import PipelineConfig
from mavsid.reasons import injected_nothing
from mavsid.validation import Model

if TYPE_CHECKING:
    from mavsid.estimators.identification import StructureChooser
    from mavsid.estimators.model import Model as EstimatorModel
    from mavsid.frequency_fit import PlantTF

__all__ = [
    "ROLLOVER_AFTER_S",
    "ROLLOVER_DEG",
    "disagrees",
    "frequency_estimate",
    "model_response_check",
    "plant_fit",
    "take_lag",
    "tf_chooser",
    "tf_structure",
]


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
    return injected_nothing(run).message


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


def tf_chooser(axis: str, tf: PlantTF | None, cfg: PipelineConfig) -> StructureChooser | None:
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


def take_lag(lag_s: float, delay: float
             ) -> Callable[[Mapping[float, EstimatorModel]], tuple[float, float]]:
    """A ``choose_structure`` that takes the candidate lag nearest ``lag_s`` at ``delay``
    samples (the search always tries no lag too, and prefers it unless it scores worse)."""
    def choose(models: Mapping[float, EstimatorModel]) -> tuple[float, float]:
        return min(models, key=lambda lag: abs(lag - lag_s)), delay

    return choose


def tf_structure(tf: PlantTF | None, cfg: PipelineConfig, train: Sequence[Segment]
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
    from mavsid.estimators.select import is_lag_filter
    from mavsid.frequency import FrfStructure

    if not isinstance(model, Fitted) or tf.measured is None:
        return model
    rate, u_name = RATE_OF[axis], f"u_{axis}"
    i_a, i_b = model.features.index(rate), model.features.index(u_name)
    prov0: dict[str, Any] = dict(model.provenance or {})
    dt = float(model.dt)
    known = [f for f in prov0.get("filters") or () if not is_lag_filter(dict(f).get("source"))]
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
