"""What a fitted (or unfitted) axis is worth: a verdict per axis with the numbers behind it.

Every axis a user asks for gets a :class:`Verdict`, whether a model was fitted or not:

- ``good``: the model can be trusted for what mavsid offers (simulation, tuning);
- ``usable``: it can serve some purposes (``usable_for`` says which), with the ``reasons``
  it is not better;
- ``not identified``: no model, or one that must not be used; ``reasons`` say why and
  ``advice`` what to change next flight (logging rate, excitation ...).

Examples
--------
>>> v = not_identified("pitch", "no window kept", advice=("fly a SYSTEMID chirp",))
>>> v.line()
'pitch: not identified: no window kept — next time: fly a SYSTEMID chirp'
>>> v.to_dict()["level"], v.identified
('not identified', False)
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from mavsid.autopilot import excitation_advice, logging_advice, longer_advice
from mavsid.axes import INPUT_OF, RATE_OF

if TYPE_CHECKING:
    from mavsid.data import FlightData, Segment
    from mavsid.excitation import WindowReport
    from mavsid.loop.emulation import ControllerEmulation
    from mavsid.loop.twin import ClosedLoopFit
    from mavsid.validation import Model, Validation

__all__ = ["FIT_FLOOR_PCT", "LEVELS", "Verdict", "format_fit", "frequency_checks", "judge",
           "not_identified", "unfitted"]

#: The verdict levels, best first.
LEVELS = ("good", "usable", "not identified")

#: Fit % below this is shown as "diverges", never as a number.
FIT_FLOOR_PCT = -100.0
#: Free-run fit % on held-out data for ``good``.
GOOD_FREE_RUN_PCT = 80.0
#: Fit % at 0.5 s for a model whose free run drifts to still be ``usable``.
USABLE_SHORT_PCT = 50.0
#: Points of free-run fit % a window's own trim adds beyond which the verdict says so.
TRIM_NOTE_PCT = 10.0
#: A rate loop's bandwidth lies between 5 and 15 Hz: channels logged slower than 4x its
#: lower end (under 4 samples per period of the slowest loop; a 10 Hz log) cannot resolve
#: it; slower than 4x the upper end only its low-frequency part (measured on simulated noisy
#: SYSTEMID chirps and doublets at 25 Hz: effectiveness -3.6 / -5.8 %, free run 72 / 84 %).
RATE_LOOP_BANDWIDTH_HZ = (5.0, 15.0)
#: Training samples per fitted parameter below which the estimate is called thin (at best
#: ``usable``), and below which it is not an estimate at all (``not identified``). Samples
#: are not information: 5 s of a 25 Hz log hold as much of a 5-15 Hz loop as of a 400 Hz
#: one, so whether the parameters are determined is judged by their σ
#: (:data:`MAX_EFFECTIVENESS_REL_SE`), the count only where it is too small for any σ.
MIN_SAMPLES_PER_PARAM = 200
REFUSE_SAMPLES_PER_PARAM = 10
#: A control effectiveness whose standard error exceeds this fraction of its value is not
#: identified: the data do not say how strongly the axis responds.
MAX_EFFECTIVENESS_REL_SE = 0.25
#: The model's response against the one measured from a chirp's injection, RMS over the
#: trusted band: CIFER's J ≤ 100 guideline (:data:`mavsid.frequency_fit.MAX_COST`) split into
#: magnitude and phase, 20 (1.5² + 0.01745 · 10²) = 80 (a model off by both everywhere
#: still passes J; one off by more in either does not).
MAX_RESPONSE_RMS_DB = 1.5
MAX_RESPONSE_RMS_DEG = 10.0
#: σ apart beyond which the time-domain and the frequency-domain effectiveness disagree
AGREE_SIGMAS = 2.0
#: A second estimate of the effectiveness (the frequency response against an injection, the
#: commanded attitude as instrument) differing by this share or more is said in the notes
OTHER_ESTIMATE_NOTE = 0.05


@dataclass(frozen=True)
class Verdict:
    """The verdict on one axis.

    Parameters
    ----------
    axis : str
        ``roll``, ``pitch`` or ``yaw``.
    level : str
        One of :data:`LEVELS`.
    reasons : tuple of str
        Why the level is not better (for ``good``: what supports it), one short clause each.
    usable_for : tuple of str
        For ``usable``: what the model can serve (e.g. ``"closed-loop simulation"``).
    numbers : Mapping[str, float or None]
        The evidence, by name (e.g. ``fit_free_run_pct``, ``log_rate_hz``), in the units its
        name says.
    advice : tuple of str
        What to change next flight to do better.
    """

    axis: str
    level: str
    reasons: tuple[str, ...] = ()
    usable_for: tuple[str, ...] = ()
    numbers: Mapping[str, float | None] = field(default_factory=dict)
    advice: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.level not in LEVELS:
            raise ValueError(f"verdict level {self.level!r} is not one of {', '.join(LEVELS)}")

    @property
    def identified(self) -> bool:
        """True for ``good`` and ``usable``."""
        return self.level != "not identified"

    def line(self) -> str:
        """One line for the terminal: ``axis: level[ (for ...)]: reasons[ — next time: ...]``
        (the advice shown for ``not identified``)."""
        text = f"{self.axis}: {self.level}"
        if self.usable_for:
            text += f" (for {', '.join(self.usable_for)})"
        if self.reasons:
            text += ": " + "; ".join(self.reasons)
        if self.advice and not self.identified:
            text += " — next time: " + "; ".join(self.advice)
        return text

    def to_dict(self) -> dict[str, Any]:
        """The JSON form (non-finite numbers become ``None``)."""
        return {
            "axis": self.axis,
            "level": self.level,
            "reasons": list(self.reasons),
            "usable_for": list(self.usable_for),
            "numbers": {
                k: (None if v is None or not math.isfinite(float(v)) else float(v))
                for k, v in self.numbers.items()
            },
            "advice": list(self.advice),
        }


def not_identified(axis: str, reason: str, advice: tuple[str, ...] = (),
                   **numbers: float | None) -> Verdict:
    """A ``not identified`` verdict with one reason."""
    return Verdict(axis, "not identified", (reason,), (), numbers, advice)


def format_fit(value: float | None) -> str:
    """A fit % for people: one decimal, ``diverges`` below :data:`FIT_FLOOR_PCT` or non-finite.

    Examples
    --------
    >>> format_fit(93.44), format_fit(-2245833.0), format_fit(None)
    ('93.4', 'diverges (< -100)', 'n/a')
    """
    if value is None:
        return "n/a"
    v = float(value)
    if not math.isfinite(v) or v < FIT_FLOOR_PCT:
        return f"diverges (< {FIT_FLOOR_PCT:.0f})"
    return f"{v:.1f}"


def _pct(value: float | None) -> str:
    """``93.4 %`` or ``diverges (< -100 %)``."""
    text = format_fit(value)
    return text.replace(")", " %)") if text.startswith("diverges") else f"{text} %"


def _pole(z: complex, dt: float) -> float:
    """Continuous-time real part (1/s) of a discrete eigenvalue."""
    return math.log(max(abs(z), 1e-300)) / dt


def _rates(flights: Sequence[FlightData], names: Sequence[str]) -> float | None:
    """The slowest native logging rate (Hz) of the named channels over the flights."""
    found = []
    for fd in flights:
        native = fd.native_rate_hz
        found += [float(native[n]) for n in names if native.get(n)]
    return min(found) if found else None


def _excitation(windows: Sequence[WindowReport]) -> dict[str, float | None]:
    """Band (Hz) and coherence of the kept windows (injection's when there is one)."""
    kept = [w for w in windows if getattr(w, "kept", False)]
    if not kept:
        return {}
    inj = [w for w in kept if "injection_rms" in w.metrics]
    use = inj or kept
    lo_key, hi_key, c_key = (("injection_lo_hz", "injection_hi_hz", "injection_coherence")
                             if inj else ("band_lo_hz", "band_hi_hz", "coherence"))
    span = [w.i1 - w.i0 for w in use]
    coh = [float(w.metrics.get(c_key, math.nan)) for w in use]
    return {
        "band_lo_hz": min(float(w.metrics.get(lo_key, math.nan)) for w in use),
        "band_hi_hz": max(float(w.metrics.get(hi_key, math.nan)) for w in use),
        "coherence": float(np.average(coh, weights=span)) if all(map(math.isfinite, coh))
        else None,
    }


def frequency_checks(frequency: Mapping[str, Any]) -> dict[str, Any]:
    """The frequency-domain checks of a chirp, as structured values: ``numbers`` (J, band,
    the model's RMS error against the measured response, both effectiveness estimates),
    ``passed`` (J within the cost bound and the model within :data:`MAX_RESPONSE_RMS_DB` and
    :data:`MAX_RESPONSE_RMS_DEG`), and the clauses ``good``, ``caps`` and ``notes``.

    ``frequency`` holds ``J``, ``J_max``, ``band_hz``, ``B``, ``sigma`` (of the transfer
    function, :meth:`mavsid.frequency_fit.PlantTF.to_dict`), ``model_check`` (``rms_db``,
    ``rms_deg``) and optionally ``time_domain`` (``B``, ``sigma``).

    Examples
    --------
    >>> c = frequency_checks({"J": 6.7, "J_max": 100, "band_hz": [1, 19], "B": 540,
    ...                       "sigma": {"B": 5}, "model_check": {"rms_db": 1.0, "rms_deg": 2.5},
    ...                       "time_domain": {"B": 325, "sigma": 60}})
    >>> c["passed"], c["notes"][0][:40]
    (True, 'time-domain B 325 ± 60 against the frequ')
    """
    nums: dict[str, float | None] = {}
    good: list[str] = []
    caps: list[str] = []
    notes: list[str] = []
    cost = float(frequency.get("J", math.nan))
    j_max = float(frequency.get("J_max", 100.0))
    lo, hi = (frequency.get("band_hz") or (math.nan, math.nan))[:2]
    check = dict(frequency.get("model_check") or {})
    db, deg = float(check.get("rms_db", math.nan)), float(check.get("rms_deg", math.nan))
    nums.update({"frequency_J": cost, "frequency_band_lo_hz": float(lo),
                 "frequency_band_hi_hz": float(hi), "frequency_rms_db": db,
                 "frequency_rms_deg": deg})
    passed = True
    if not cost <= j_max:
        passed = False
        caps.append(f"transfer function fits the measured response with J {cost:.3g} "
                    f"(CIFER's guideline J <= {j_max:g})")
    if not (db <= MAX_RESPONSE_RMS_DB and deg <= MAX_RESPONSE_RMS_DEG):
        passed = False
        caps.append(f"model's response off the measured one by {db:.2g} dB / {deg:.2g}° RMS "
                    f"over {lo:.2g}–{hi:.3g} Hz (at most {MAX_RESPONSE_RMS_DB:g} dB / "
                    f"{MAX_RESPONSE_RMS_DEG:g}°)")
    if passed:
        good.append(f"model's response within {db:.2g} dB / {deg:.2g}° RMS of the one measured "
                    f"against the injection over {lo:.2g}–{hi:.3g} Hz (transfer function J "
                    f"{cost:.3g})")
    td = frequency.get("time_domain")
    b_fd = float(frequency.get("B", math.nan))
    s_fd = float(dict(frequency.get("sigma") or {}).get("B") or math.nan)
    if isinstance(td, Mapping):
        b_td, s_td = float(td.get("B", math.nan)), float(td.get("sigma", math.nan))
        z = abs(b_td - b_fd) / math.hypot(s_td, s_fd) if math.isfinite(s_td + s_fd) else math.nan
        nums.update({"time_domain_B": b_td, "frequency_B": b_fd, "B_disagreement_sigmas": z})
        if math.isfinite(z) and z > AGREE_SIGMAS:
            notes.append(f"time-domain B {b_td:.4g} ± {s_td:.2g} against the frequency "
                         f"response's {b_fd:.4g} ± {s_fd:.2g} ({100 * (b_td / b_fd - 1):+.0f} %, "
                         f"{z:.1f} σ): the frequency response is trusted (measured against the "
                         "injection; a time-domain fit on closed-loop data is biased by the "
                         "fed-back noise)")
    return {"numbers": nums, "passed": passed, "good": good, "caps": caps, "notes": notes}


def judge(axis: str, validation: Validation, output: str, *, model: Model | None = None,
          train: Sequence[Segment] = (), windows: Sequence[WindowReport] = (),
          flights: Sequence[FlightData] = (), closed_loop: ClosedLoopFit | None = None,
          frequency: Mapping[str, Any] | None = None,
          emulation: ControllerEmulation | None = None) -> Verdict:
    """The verdict on one fitted axis from everything known about it.

    Checks, each adding its numbers (``Verdict.numbers``) and, when it fails, a reason:

    - **stability** of the identified dynamics (an unstable rate plant: ``not identified``);
    - **log rate** of the output and input channels against a 5–15 Hz rate loop: below 20 Hz
      (under 4 samples per period of its slowest bandwidth) ``not identified``, below 60 Hz
      at best ``usable``;
      the advice names the logging parameter to change (:func:`logging_advice`);
    - **excitation**: band and coherence of the kept windows (the injection's for SYSTEMID);
    - **training length** against the number of parameters (under 200 samples each: at best
      ``usable``; under 10: ``not identified``), and whether the control effectiveness is
      determined (its σ at most 25 % of it, else ``not identified``);
    - **residual whiteness**: Ljung–Box p-value of the one-step residual over 20 lags, and
      its lag-1 autocorrelation. Reported, not gated: the logged gyro is low-passed
      (``INS_GYRO_FILTER``), so even the true plant leaves a coloured one-step residual; a
      small p-value says the σ cover the statistical error and the lag's grid resolution
      but not other model-structure error;
    - **bounds**: a parameter held at a physical bound (``model.provenance["bounds_active"]``)
      caps the level at ``usable``;
    - **open-loop fit** on held-out data (each window with its own trim, as
      :func:`mavsid.validation.validate` runs it; the free run with the model's own trim is
      in the numbers and said when 10 points or more lower): free run ≥ 80 % ``good``; a
      free run that drifts (rate plants are nearly integrators: wind and prop wash make it
      wander) with a 0.5-s fit ≥ 50 % is ``usable`` for short-horizon prediction; below that
      ``not identified``;
    - **closed-loop fit**, when the closed-loop twin ran: ``closed_loop.fit_percent`` (the
      twin's fit % of the measured rate) against ``closed_loop.baseline_percent`` (the rate
      following its target after the best delay). Beating the baseline makes a drifting
      model ``usable`` for closed-loop simulation; not beating it is a reason;
    - **frequency response**, for a chirp (``frequency``, :func:`frequency_checks`): the
      model's response against the one measured from the injection (within
      :data:`MAX_RESPONSE_RMS_DB` and :data:`MAX_RESPONSE_RMS_DEG`) and the transfer
      function's J. When they pass, the open-loop free run is reported but decides nothing
      (an integrating plant with unmeasured disturbances drifts whatever the model); when
      they fail, at best ``usable``. A time-domain effectiveness that disagrees is said.

    Parameters
    ----------
    axis : str
    validation : mavsid.validation.Validation
    output : str
        The state that represents the axis (its body rate).
    model : Model, optional
    train : sequence of Segment, optional
    windows : sequence of WindowReport, optional
        Every window considered for the axis (kept ones give band and coherence).
    flights : sequence of FlightData, optional
        Their ``native_rate_hz`` and ``autopilot``.
    closed_loop : ClosedLoopFit, optional
        The twin's ``fit_percent`` and ``baseline_percent`` (``AxisFit.closed_loop``).
    frequency : Mapping, optional
        The chirp's frequency-domain results (see :func:`frequency_checks`).
    emulation : ControllerEmulation, optional
        The rebuilt controller against the logged output (``AxisFit.emulation``): its fit is
        in ``numbers`` and, when it failed, a note says which part did not match and that the
        twin was not used.

    Examples
    --------
    >>> from types import SimpleNamespace as NS
    >>> val = NS(state_names=("p",), fit_free_run=np.array([-5e6]), fit_vs_horizon=None,
    ...          fit_one_step=np.array([40.0]), fit_at=lambda s: np.array([-20.0]),
    ...          stable=False, eigenvalues=np.array([1.02]), dt=0.1, residuals=None)
    >>> v = judge("roll", val, "p")
    >>> v.level, v.reasons[0]
    ('not identified', 'identified dynamics are unstable: eigenvalue 1.02 (pole +0.198 1/s)')
    """
    j = validation.state_names.index(output)
    free = float(validation.fit_free_run[j])
    one = float(validation.fit_one_step[j])
    short = float(validation.fit_at(0.5)[j])
    numbers: dict[str, float | None] = {
        "fit_one_step_pct": one, "fit_0.5s_pct": short, "fit_free_run_pct": free}
    bad: list[str] = []      # -> not identified
    caps: list[str] = []     # -> at best usable
    good: list[str] = []
    advice: list[str] = []
    dt = float(validation.dt)

    # stability
    eig = getattr(validation, "eigenvalues", None)
    if eig is not None and len(eig):
        worst = max((complex(z) for z in eig), key=abs)
        numbers["max_abs_eigenvalue"] = abs(worst)
        numbers["slowest_pole_per_s"] = _pole(worst, dt)
        if validation.stable is False:
            bad.append(f"identified dynamics are unstable: eigenvalue {abs(worst):.4g} "
                       f"(pole {_pole(worst, dt):+.3g} 1/s)")
            advice.append("refit with the physical bounds (damping >= 0; the default) or "
                          + excitation_advice(axis, _autopilot(flights)))

    # log rate against the rate loop's bandwidth
    u_names = tuple(getattr(model, "input_names", ()) or ()) if model is not None else ()
    rate = _rates(flights, (output, *u_names))
    if rate is not None:
        numbers["log_rate_hz"] = rate
        lo, hi = RATE_LOOP_BANDWIDTH_HZ
        slow = _too_slow(rate, flights)
        if slow:
            bad.append(slow[0])
            advice.append(slow[1])
        elif rate < 4 * hi:
            caps.append(f"logged at {rate:.3g} Hz: only the slow part of a {lo:g}–{hi:g} Hz rate "
                        "loop is resolved")
            advice.append(logging_advice(_autopilot(flights), _telemetry(flights)))

    # excitation
    exc = _excitation(windows)
    numbers.update({f"excitation_{k}": v for k, v in exc.items()})
    if exc.get("band_lo_hz") is not None and exc.get("coherence") is not None:
        good.append(f"excited {exc['band_lo_hz']:.2g}–{exc['band_hi_hz']:.3g} Hz, coherence "
                    f"{exc['coherence']:.2f}")

    # training length against the parameter count
    n_train = int(sum(len(getattr(s, "time_s", ())) for s in train))
    params = dict(getattr(model, "params", {}) or {})
    n_par = len([k for k in params if "_d[" in k]) or len(params)
    if n_train and n_par:
        numbers["train_samples"] = float(n_train)
        numbers["params"] = float(n_par)
        if n_train < REFUSE_SAMPLES_PER_PARAM * n_par:
            bad.append(f"only {n_train} training samples for {n_par} parameters")
            advice.append(longer_advice(_autopilot(flights)))
        elif n_train < MIN_SAMPLES_PER_PARAM * n_par:
            caps.append(f"only {n_train} training samples for {n_par} parameters (want "
                        f"{MIN_SAMPLES_PER_PARAM} per parameter)")
            advice.append(longer_advice(_autopilot(flights)))

    # is the response's strength determined?
    rel = _effectiveness(model, output, axis)
    if rel is not None:
        name, value, se = rel
        numbers["effectiveness_rel_se"] = se / abs(value)
        if se > MAX_EFFECTIVENESS_REL_SE * abs(value):
            bad.append(f"control effectiveness not determined: {name} {value:.4g} ± {se:.2g} "
                       f"(σ {100 * se / abs(value):.0f} % of it, at most "
                       f"{100 * MAX_EFFECTIVENESS_REL_SE:.0f} %)")
            advice.append(excitation_advice(axis, _autopilot(flights)))

    # residual whiteness
    res = getattr(validation, "residuals", None)
    if res is not None and hasattr(res, "ljung_box"):
        _, pval = res.ljung_box(min(20, int(res.lags[-1])))
        r1 = float(res.autocorr[1, j]) if res.autocorr.shape[0] > 1 else math.nan
        numbers["ljung_box_p"] = float(pval[j])
        numbers["residual_lag1_autocorr"] = r1
        if math.isfinite(float(pval[j])) and float(pval[j]) < 0.01:
            good.append(f"residual not white (Ljung–Box p {float(pval[j]):.2g}): σ hold "
                        "the statistical error and the lag's grid resolution, not other "
                        "model-structure error")

    # parameters held at bounds
    prov = dict(getattr(model, "provenance", {}) or {})
    notes: list[str] = []  # said whatever the level
    if prov.get("bounds"):
        active = list(prov.get("bounds_active", []) or [])
        if active:
            caps.append("bounded fit, bound active on " + ", ".join(map(str, active))
                        + " (the data alone would take it past the physical limit)")
        else:
            notes.append("bounded fit, no bound active")

    other = prov.get("other_estimate")
    if isinstance(other, Mapping) and rel is not None:
        name, value, _ = rel
        alt = float(dict(other.get("params") or {}).get(name, math.nan))
        if math.isfinite(alt) and abs(alt / value - 1) >= OTHER_ESTIMATE_NOTE:
            notes.append(f"{name} {alt:.4g} by {other.get('by')} against {value:.4g} "
                         f"({100 * (alt / value - 1):+.0f} %): its σ include the difference")

    # open loop (each held-out window with its own trim; see mavsid.validation)
    own = getattr(validation, "fit_free_run_own_trim", None)
    own_free = float(own[j]) if own is not None else math.nan
    if math.isfinite(own_free) and math.isfinite(free):
        numbers["fit_free_run_own_trim_pct"] = own_free
        if free - own_free >= TRIM_NOTE_PCT:
            notes.append(f"free run {_pct(own_free)} with the training windows' trim: the "
                         "held-out windows hold another (the constant term moves between "
                         "windows; each is re-estimated, as its initial state is taken)")
    fchk = frequency_checks(frequency) if frequency is not None else None
    if fchk is not None:
        numbers.update(fchk["numbers"])
        good += fchk["good"]
        caps += fchk["caps"]
        notes += fchk["notes"]
    by_frequency = fchk is not None and fchk["passed"]
    drift = False
    if by_frequency:  # (the chirp is validated in the frequency domain)
        notes.append(f"free run on held-out data {_pct(free)}, 0.5 s ahead {_pct(short)} "
                     "(reported only: an integrating plant with unmeasured disturbances "
                     "drifts whatever the model)")
        drift = not math.isfinite(free) or free < GOOD_FREE_RUN_PCT
    elif not math.isfinite(free) or free < 0:
        drift = True
        if math.isfinite(short) and short >= USABLE_SHORT_PCT and validation.stable is not False:
            caps.append(f"free run drifts on held-out data ({_pct(free)}) while 0.5 s "
                        f"ahead reaches {short:.1f} %: unmeasured disturbances (wind, prop wash) "
                        "make an open-loop rate simulation wander")
        else:
            bad.append(f"free run on held-out data {_pct(free)}, 0.5 s ahead "
                       f"{_pct(short)}: the model does not predict this axis")
    elif free < GOOD_FREE_RUN_PCT:
        caps.append(f"free run only {free:.1f} % on held-out data")
    else:
        good.append(f"free run {free:.1f} % on held-out data")

    if emulation is not None:
        numbers["controller_emulation_pct"] = float(emulation.fit_percent)
        if not emulation.passed:
            notes.append(f"closed-loop twin not used: {emulation.reason}")
    # closed loop (the twin), when it ran
    cl_fit = getattr(closed_loop, "fit_percent", None) if closed_loop is not None else None
    cl_base = getattr(closed_loop, "baseline_percent", None) if closed_loop is not None else None
    closed_ok = False
    if cl_fit is not None:
        numbers["fit_closed_loop_pct"] = float(cl_fit)
        numbers["baseline_closed_loop_pct"] = None if cl_base is None else float(cl_base)
        if float(cl_fit) <= FIT_FLOOR_PCT:
            base = "" if cl_base is None else f" {_pct(cl_base)}"
            caps.append(f"closed-loop twin {_pct(cl_fit)}: does not beat the baseline{base}")
        elif cl_base is not None and float(cl_fit) > float(cl_base):
            closed_ok = True
            good.append(f"closed-loop twin {_pct(cl_fit)} beats the baseline "
                        f"{_pct(cl_base)}")
        else:
            caps.append(f"closed-loop twin {_pct(cl_fit)} does not beat the baseline "
                        f"{_pct(cl_base)}")

    usable: list[str] = []
    if math.isfinite(one) and one >= USABLE_SHORT_PCT:
        usable.append("one-step prediction")
    if not drift and free >= GOOD_FREE_RUN_PCT:
        usable.append("open-loop simulation")
    elif math.isfinite(short) and short >= USABLE_SHORT_PCT:
        usable.append("short-horizon prediction")
    if closed_ok:
        usable.append("closed-loop simulation")
    if by_frequency:
        usable.append("frequency-domain analysis (margins, tuning)")
    if caps and not usable and not bad:  # nothing it could be used for: no model
        bad.append(f"on held-out data one step {_pct(one)}, 0.5 s ahead {_pct(short)}, free "
                   f"run {_pct(free)}: too poor for any use")
    if bad:
        said = [c for c in caps if c.startswith(("bounded fit", "closed-loop twin"))]
        return Verdict(axis, "not identified", tuple(bad + said + notes), (), numbers,
                       tuple(dict.fromkeys(advice)))
    if caps:
        return Verdict(axis, "usable", tuple(caps + good + notes), tuple(usable), numbers,
                       tuple(dict.fromkeys(advice)))
    return Verdict(axis, "good", tuple(good + notes), (), numbers, tuple(dict.fromkeys(advice)))


def _effectiveness(model: Model | None, output: str, axis: str) -> tuple[str, float, float] | None:
    """The model's control effectiveness of ``output`` by the axis's own input (continuous
    ``B[output,u_axis]``): its name, value and standard error; None when it has none.

    Examples
    --------
    >>> from types import SimpleNamespace as NS
    >>> m = NS(params={"B[p,u_roll]": 180.0}, stderr={"B[p,u_roll]": 3.0})
    >>> _effectiveness(m, "p", "roll")
    ('B[p,u_roll]', 180.0, 3.0)
    """
    name = f"B[{output},u_{axis}]"
    value = float((getattr(model, "params", None) or {}).get(name, math.nan))
    se = float((getattr(model, "stderr", None) or {}).get(name, math.nan))
    if value == 0 or not (math.isfinite(value) and math.isfinite(se)):
        return None
    return name, value, se


def _too_slow(rate: float, flights: Sequence[FlightData]) -> tuple[str, str] | None:
    """(reason, advice) when ``rate`` (Hz) cannot resolve a rate loop, else None."""
    lo, hi = RATE_LOOP_BANDWIDTH_HZ
    if rate >= 4 * lo:
        return None
    reason = (f"rates/outputs logged at {rate:.3g} Hz (Nyquist {rate / 2:.3g} Hz) cannot "
              f"resolve a rate loop of {lo:g}–{hi:g} Hz bandwidth")
    return reason, logging_advice(_autopilot(flights), _telemetry(flights))


def _telemetry(flights: Sequence[FlightData]) -> bool:
    """Whether every flight was read from a ground station's telemetry (``.tlog``)."""
    formats = [getattr(getattr(fd, "source", None), "format", None) for fd in flights]
    return bool(formats) and all(f == "tlog" for f in formats)


def _autopilot(flights: Sequence[FlightData]) -> str | None:
    """The platform the flights name, if any: ``autopilot``, then the vehicle and the
    firmware banner when known (``ardupilot plane ArduPlane V4.3.8 (...)``), ``quadplane``
    after them for a QuadPlane's VTOL flight (its preset)."""
    for fd in flights:
        if getattr(fd, "autopilot", None):
            from mavsid.autopilot.presets import QUADPLANE

            vtol = "quadplane" if getattr(fd, "preset", "") == QUADPLANE else ""
            words = (fd.autopilot, getattr(fd, "vehicle", None), getattr(fd, "firmware", None),
                     vtol)
            return " ".join(str(w) for w in words if w)
    return None




def unfitted(axis: str, why: str, windows: Sequence[WindowReport] = (),
             flights: Sequence[FlightData] = (),
             logs: Sequence[str] = ()) -> Verdict:
    """The ``not identified`` verdict of an axis that got no model, in one honest line.

    The reason names the cause the user can act on: a log rate too slow for a rate loop
    (with the logging setting to change), else the windows' rejections counted by kind
    (with the command that lists them), else ``why`` (the fitting error).

    Examples
    --------
    >>> from types import SimpleNamespace as NS
    >>> fd = NS(native_rate_hz={"p": 10.0, "u_roll": 10.0}, autopilot="ArduPilot")
    >>> v = unfitted("roll", "no segments to fit", flights=[fd], logs=["a.bin"])
    >>> v.reasons[0]
    'rates/outputs logged at 10 Hz (Nyquist 5 Hz) cannot resolve a rate loop of 5–15 Hz bandwidth'
    >>> v.advice[0].startswith("ArduPilot: set LOG_BITMASK")
    True
    """
    from mavsid.reasons import group

    reasons: list[str] = []
    advice: list[str] = []
    numbers: dict[str, float | None] = {}
    rate = _rates(flights, (RATE_OF.get(axis, axis), INPUT_OF.get(axis, f"u_{axis}")))
    if rate is not None:
        numbers["log_rate_hz"] = rate
        slow = _too_slow(rate, flights)
        if slow:
            reasons.append(slow[0])
            advice.append(slow[1])
    mine = [w for w in windows if getattr(w, "axis", axis) == axis]
    where = " ".join(logs) if logs else "LOG"
    if mine and not any(w.kept for w in mine):
        first = [w.checks[0] for w in mine if w.checks]  # (each window's first failed gate)
        top = ", ".join(group(first))
        numbers["windows_rejected"] = float(len(mine))
        if first and {r.kind for r in first} == {"missing_channel"}:
            # (no data to judge: say which, and what to log)
            reasons.append(first[0].message)
            advice.append(logging_advice(_autopilot(flights), _telemetry(flights)))
        else:
            reasons.append(f"no window kept ({len(mine)} rejected: {top}; see `mavsid "
                           f"segments {where} --axis {axis} --all`)")
            advice.append(excitation_advice(axis, _autopilot(flights)))
    elif not mine and not reasons:
        reasons.append(f"no window on {axis} ({why})")
    if not reasons:
        reasons.append(why)
    return Verdict(axis, "not identified", tuple(reasons), (), numbers,
                   tuple(dict.fromkeys(advice)))
