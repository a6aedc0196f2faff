"""A rate plant's transfer function fitted to its measured frequency response.

:func:`fit_plant` fits ``B e^{−τ s} / ((s + a)(T s + 1))`` — an integrator (``a`` = 0) or a
first-order pole, a first-order lag ``T`` (motor, gyro filter) and an equivalent delay ``τ`` —
to the trusted band of a :class:`mavsid.frequency.FRF` (:func:`trusted_band`) by CIFER's cost
(:func:`cifer_cost`), with σ of each parameter (random error and the composite's bias);
:func:`identify_frequency` does the whole from arrays. The pipeline runs it on every
SYSTEMID run, against the injection.

Examples
--------
>>> f = np.geomspace(1, 15, 40)
>>> s = 2j * np.pi * f
>>> h = 500 * np.exp(-0.019 * s) / (s * (0.013 * s + 1))
>>> fit = fit_plant(FRF(f, h, np.full(40, 0.9), np.full(40, 0.05), (4.0,), referenced=True))
>>> fit.structure, round(fit.gain), round(fit.lag_s, 4), round(fit.delay_s, 4), fit.cost < 1e-6
('integrator', 500, 0.013, 0.019, True)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from mavsid.errors import NoExcitationError
from mavsid.frequency import CYCLES, FRF, FRF_STRUCTURE_FLOOR, MIN_COHERENCE, WINDOWS_S, frf

__all__ = ["BIAS_OCTAVES", "MAX_COST", "PlantTF", "cifer_cost", "coherence_weight", "error_cost",
           "fit_plant", "identify_frequency", "rms_errors", "trusted_band"]

#: CIFER's cost (Tischler & Remple, *Aircraft and Rotorcraft System Identification*, 2nd ed.,
#: ch. 11): ``J = (20/n) Σ W_γ [(|Ĥ|dB − |T|dB)² + W_p (∠Ĥ − ∠T)²]`` (degrees), with the
#: coherence weight ``W_γ = [1.58 (1 − e^{−γ²})]²`` and ``W_p`` = 0.01745 (1 dB of
#: magnitude error costs as much as 7.57° of phase).
PHASE_WEIGHT = 0.01745
#: Cost a fit is accepted below (CIFER's guideline for a good fit, J ≤ 100; ArduPilot
#: WebTools' SysID uses the same bound).
MAX_COST = 100.0
#: Coherent frequencies a transfer-function fit needs (4 parameters at most; fewer points
#: than twice that leave no residual to judge them by).
MIN_TF_POINTS = 8
#: A gap between coherent frequencies wider than this ratio (half an octave) ends the
#: trusted band: a coherent point beyond it is a spurious peak of a noisy estimate (on a
#: real quad's chirp, isolated points above the 15-Hz cut-off), not a band.
BAND_GAP_RATIO = 2.0**0.5
#: A first-order pole is chosen over the integrator only when it is this many σ from zero
#: (CIFER's guideline for an identified parameter: Cramér–Rao bound at most 20 % of its
#: value; the random error of the response is in its σ) and lowers J by more than the
#: composite's bias explains (:func:`error_cost` of :data:`FRF_STRUCTURE_FLOOR`): a pole the data
#: cannot tell from zero is an integrator.
POLE_SIGMAS = 5.0
#: How far (octaves) the composite's bias (:data:`FRF_STRUCTURE_FLOOR`) stays alike across
#: frequency: leakage where the sweep passes fast moves a window's neighbouring bins
#: together (the correlation ``exp(−|log₂ f/f'|)`` of :func:`_bias_covariance`).
BIAS_OCTAVES = 1.0
#: Plant structures :func:`fit_plant` chooses between.
STRUCTURES = ("integrator", "first_order")


def coherence_weight(coherence: np.ndarray) -> np.ndarray:
    """CIFER's coherence weight ``W_γ = [1.58 (1 − e^{−γ²})]²`` (≈ 1 at γ² = 1, 0.51 at 0.6).

    Examples
    --------
    >>> [round(float(w), 3) for w in coherence_weight(np.array([0.0, 0.6, 1.0]))]
    [0.0, 0.508, 0.998]
    """
    return (1.58 * (1.0 - np.exp(-np.asarray(coherence, dtype=float)))) ** 2


def _errors_db_deg(measured: np.ndarray, model: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Magnitude (dB) and phase (degrees, wrapped to ±180) of ``measured / model``."""
    ratio = measured / model
    return 20.0 * np.log10(np.abs(ratio)), np.degrees(np.angle(ratio))


def cifer_cost(measured: np.ndarray, model: np.ndarray, coherence: np.ndarray) -> float:
    """CIFER's cost ``J`` of ``model`` against ``measured`` at the same frequencies
    (:data:`PHASE_WEIGHT`, :func:`coherence_weight`).

    Examples
    --------
    >>> h = np.array([1.0, 1j, -1.0])
    >>> cifer_cost(h, h, np.ones(3))
    0.0
    >>> round(cifer_cost(h * 10 ** (1 / 20), h, np.ones(3)), 2)   # 1 dB everywhere
    19.95
    """
    db, deg = _errors_db_deg(np.asarray(measured), np.asarray(model))
    w = coherence_weight(coherence)
    return float(20.0 / db.size * np.sum(w * (db**2 + PHASE_WEIGHT * deg**2)))


def error_cost(error: np.ndarray, coherence: np.ndarray) -> float:
    """The J that a response's own error accounts for: :func:`cifer_cost` of a model off by
    the random error ``ε`` (with :data:`FRF_STRUCTURE_FLOOR`) in magnitude and in phase at every
    point. Two models whose J differ by less fit the measurement equally well.

    Examples
    --------
    >>> round(error_cost(np.full(10, 0.05), np.ones(10)), 2)
    8.72
    """
    e = np.sqrt(np.asarray(error, dtype=float) ** 2 + FRF_STRUCTURE_FLOOR**2)
    db, deg = 20.0 * np.log10(1.0 + e), np.degrees(e)
    w = coherence_weight(coherence)
    return float(20.0 / e.size * np.sum(w * (db**2 + PHASE_WEIGHT * deg**2)))


def rms_errors(measured: np.ndarray, model: np.ndarray, coherence: np.ndarray
               ) -> tuple[float, float]:
    """Coherence-weighted (:func:`coherence_weight`) RMS of the magnitude (dB) and phase
    (degrees) errors of ``model`` against ``measured``.

    Examples
    --------
    >>> h = np.exp(1j * np.linspace(0, 1, 5))
    >>> [round(v, 3) for v in rms_errors(2 * h, h * np.exp(0.1j), np.ones(5))]
    [6.021, 5.73]
    """
    db, deg = _errors_db_deg(np.asarray(measured), np.asarray(model))
    w = coherence_weight(coherence)
    return (float(np.sqrt(np.sum(w * db**2) / np.sum(w))),
            float(np.sqrt(np.sum(w * deg**2) / np.sum(w))))


def trusted_band(r: FRF, excited_hz: tuple[float, float] | None = None
                 ) -> tuple[float, float] | None:
    """The band (Hz) where ``r`` is trusted: its frequencies whose coherence (``r.trust``:
    of the input and of the output with the reference, for a referenced FRF) reaches
    :data:`MIN_COHERENCE`, inside
    the excited band ``excited_hz``, from the widest stretch whose gaps stay under
    :data:`BAND_GAP_RATIO`. None when no frequency is coherent.

    Examples
    --------
    >>> f = np.geomspace(1, 40, 60)
    >>> coh = np.where(f < 15, 0.9, 0.1)
    >>> coh[np.argmin(abs(f - 30))] = 0.7          # an isolated spurious point
    >>> r = FRF(f, np.ones(60, complex), coh, np.full(60, 0.1), (4.0,))
    >>> [round(v, 1) for v in trusted_band(r)]
    [1.0, 14.7]
    """
    ok = (r.trust >= MIN_COHERENCE) & np.isfinite(r.response)
    if excited_hz is not None:
        ok &= (r.freq_hz >= excited_hz[0]) & (r.freq_hz <= excited_hz[1])
    f = r.freq_hz[ok]
    if not f.size:
        return None
    cuts = np.flatnonzero(f[1:] / f[:-1] > BAND_GAP_RATIO) + 1
    runs = np.split(f, cuts)
    widest = max(runs, key=lambda x: x[-1] / x[0])
    return float(widest[0]), float(widest[-1])


@dataclass(frozen=True)
class PlantTF:
    """A rate plant ``B e^{−τ s} / ((s + a)(T s + 1))`` fitted to a measured response.

    Attributes
    ----------
    structure : ``"integrator"`` (``a`` = 0) or ``"first_order"``.
    gain : B (rate unit per s per input unit: rad/s² per unit for a rate plant).
    pole : a (1/s; 0 for the integrator).
    lag_s : T, the first-order lag (motor, gyro filter).
    delay_s : τ, the equivalent delay.
    cost : CIFER's J (:func:`cifer_cost`) over the points fitted.
    band_hz : (low, high) band fitted.
    stderr : σ of each parameter (``gain``, ``pole``, ``lag_s``, ``delay_s``; for the
        integrator, ``pole`` is the σ of the first-order fit's pole: how closely the data
        place a pole at zero): the random error and the composite's bias
        (:data:`~mavsid.frequency.FRF_STRUCTURE_FLOOR` correlated over
        :data:`BIAS_OCTAVES`); ``<name>_random`` the random error alone (what the
        structure choice weighs, :data:`POLE_SIGMAS`).
    rms_db, rms_deg : coherence-weighted RMS error in magnitude and phase over the band.
    n_points : frequencies fitted.
    measured : the response it was fitted to (None when not kept).
    reason : why this structure was chosen.
    """

    structure: str
    gain: float
    pole: float
    lag_s: float
    delay_s: float
    cost: float
    band_hz: tuple[float, float]
    stderr: dict[str, float]
    rms_db: float
    rms_deg: float
    n_points: int
    measured: FRF | None = None
    reason: str = ""

    def response(self, freq_hz: np.ndarray) -> np.ndarray:
        """``H(j 2π f)`` of the transfer function."""
        s = 2j * np.pi * np.asarray(freq_hz, dtype=float)
        return np.asarray(self.gain * np.exp(-self.delay_s * s)
                          / ((s + self.pole) * (self.lag_s * s + 1.0)))

    @property
    def accepted(self) -> bool:
        """Whether the cost is within :data:`MAX_COST`."""
        return bool(self.cost <= MAX_COST)

    def to_dict(self) -> dict[str, object]:
        """JSON form: the fit, and (with ``measured``) the measured and modelled response at
        the measured frequencies."""
        out: dict[str, object] = {
            "structure": self.structure, "B": self.gain, "pole_per_s": self.pole,
            "lag_s": self.lag_s, "delay_s": self.delay_s, "J": self.cost,
            "J_max": MAX_COST, "band_hz": list(self.band_hz),
            "sigma": {"B": self.stderr.get("gain"), "pole_per_s": self.stderr.get("pole"),
                      "lag_s": self.stderr.get("lag_s"), "delay_s": self.stderr.get("delay_s")},
            "rms_db": self.rms_db, "rms_deg": self.rms_deg, "n_points": self.n_points,
            "reason": self.reason,
        }
        if self.measured is not None:
            m = self.measured
            model = self.response(m.freq_hz)
            with np.errstate(divide="ignore"):
                out.update({
                    "freq_hz": m.freq_hz.tolist(),
                    "magnitude_db": [float(v) if np.isfinite(v) else None
                                     for v in m.magnitude_db],
                    "phase_deg": _phase_near(m.response, model).tolist(),
                    "coherence": m.coherence.tolist(),
                    "error": m.error.tolist(),
                    "model_magnitude_db": (20 * np.log10(np.abs(model))).tolist(),
                    "model_phase_deg": np.degrees(np.unwrap(np.angle(model))).tolist(),
                    "input": m.input, "output": m.output, "referenced": m.referenced,
                })
        return out


def _phase_near(h: np.ndarray, model: np.ndarray) -> np.ndarray:
    """Phase of ``h`` (degrees) on the model's branch (the model's unwrapped phase plus the
    wrapped difference): a noisy point never jumps by 360°."""
    ref = np.degrees(np.unwrap(np.angle(model)))
    with np.errstate(invalid="ignore"):
        return np.asarray(ref + np.degrees(np.angle(h / model)))


def _independent(f: np.ndarray, windows_s: Sequence[float]) -> float:
    """How many independent frequencies the log-spaced points ``f`` hold: each point is
    worth its share of the resolution ``1/w`` of the longest window resolving it
    (:data:`CYCLES` periods), a composite's grid being finer than its bins at low frequency."""
    if f.size < 2:
        return float(f.size)
    edges = np.sqrt(f[1:] * f[:-1])
    width = np.diff(np.concatenate([[f[0] ** 2 / edges[0]], edges, [f[-1] ** 2 / edges[-1]]]))
    res = np.array([1.0 / max((w for w in windows_s if CYCLES / w <= x), default=min(windows_s))
                    for x in f])
    return float(np.clip(np.sum(np.minimum(width / res, 1.0)), 1.0, f.size))


def _fit_structure(f: np.ndarray, h: np.ndarray, coh: np.ndarray, structure: str,
                   max_delay_s: float, max_lag_s: float, n_ind: float
                   ) -> tuple[np.ndarray, float, dict[str, float]]:
    """Least-squares fit of one structure: parameters ``(B, a, T, τ)``, J and σ."""
    from scipy.optimize import least_squares

    s = 2j * np.pi * f
    sw = np.sqrt(20.0 / f.size * coherence_weight(coh))
    first = structure == "first_order"

    def full(p: np.ndarray) -> np.ndarray:
        return np.array([p[0], p[1], p[2], p[3]]) if first else np.array([p[0], 0.0, p[1], p[2]])

    def resid(p: np.ndarray) -> np.ndarray:
        b, a, lag, tau = full(p)
        db, deg = _errors_db_deg(h, b * np.exp(-tau * s) / ((s + a) * (lag * s + 1.0)))
        return np.concatenate([sw * db, sw * np.sqrt(PHASE_WEIGHT) * deg])

    w = 2 * np.pi * f
    low = f <= np.quantile(f, 0.3)
    b0 = float(np.median(np.abs(h[low]) * w[low]))
    lo = [b0 * 1e-3, 0.0, 0.0]
    hi = [b0 * 1e3, max_lag_s, max_delay_s]
    if first:
        lo.insert(1, -0.5 * float(w.min()))
        hi.insert(1, 2.0 * float(w.max()))
    best = None
    for lag0 in (0.005, 0.02):
        for tau0 in (0.005, 0.02, 0.05):
            x0 = [b0, lag0, min(tau0, max_delay_s)] if not first else [b0, 1.0, lag0,
                                                                       min(tau0, max_delay_s)]
            sol = least_squares(resid, np.array(x0, float), bounds=(lo, hi), x_scale="jac")
            if best is None or sol.cost < best.cost:
                best = sol
    assert best is not None
    cost = float(2.0 * best.cost)
    n_par = best.x.size
    # σ from the Jacobian of the weighted residuals, the residual variance counted over the
    # independent frequencies (the log grid oversamples the Welch bins at low frequency)
    dof = max(2.0 * n_ind - n_par, 1.0)
    jac = best.jac
    names = ("gain", "pole", "lag_s", "delay_s") if first else ("gain", "lag_s", "delay_s")
    try:
        bread = np.linalg.pinv(jac.T @ jac)
        cov = bread * cost / dof * (f.size / n_ind)
        bias = _bias_covariance(bread, jac, f, sw)
    except np.linalg.LinAlgError:
        cov = bias = np.full((n_par, n_par), np.nan)
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    sd_all = np.sqrt(np.clip(np.diag(cov) + np.diag(bias), 0.0, None))
    stderr = dict(zip(names, (float(v) for v in sd_all), strict=True))
    stderr.update({f"{k}_random": float(v) for k, v in zip(names, sd, strict=True)})
    if not first:
        stderr["pole"] = stderr["pole_random"] = 0.0
    return full(best.x), cost, stderr


def _bias_covariance(bread: np.ndarray, jac: np.ndarray, f: np.ndarray, sw: np.ndarray
                     ) -> np.ndarray:
    """The parameters' covariance from the composite's bias: an error of
    :data:`FRF_STRUCTURE_FLOOR` of the response in magnitude and as much (radians) in phase
    at each frequency, correlated across :data:`BIAS_OCTAVES` (``exp(−|log₂ f/f'| / o)``),
    through the fit's linearisation ``(JᵀJ)⁻¹ Jᵀ Σ J (JᵀJ)⁻¹``. The residuals do not show
    such an error where the model's parameters absorb it (a gain error spread over the band
    is all B's), so the random σ alone left the truth 3-4.5 σ from the gain and pole of
    noise-free simulated chirps (1.3 % and 4.5 % off)."""
    octaves = np.abs(np.log2(f[:, None] / f[None, :]))
    corr = np.exp(-octaves / BIAS_OCTAVES) * np.outer(sw, sw)
    e_db = 20.0 * np.log10(1.0 + FRF_STRUCTURE_FLOOR)
    e_deg = np.degrees(FRF_STRUCTURE_FLOOR) * np.sqrt(PHASE_WEIGHT)
    n = f.size
    # (magnitude and phase errors independent; the residuals are [dB rows, degree rows])
    jm, jp = jac[:n], jac[n:]
    meat = e_db**2 * jm.T @ corr @ jm + e_deg**2 * jp.T @ corr @ jp
    return np.asarray(bread @ meat @ bread)


def fit_plant(r: FRF, band_hz: tuple[float, float] | None = None, *,
              excited_hz: tuple[float, float] | None = None,
              structures: Sequence[str] = STRUCTURES, max_delay_s: float = 0.1,
              max_lag_s: float = 0.1) -> PlantTF:
    """Fit ``B e^{−τ s} / ((s + a)(T s + 1))`` to the trusted band of ``r`` by CIFER's cost.

    Both structures of :data:`STRUCTURES` are fitted (``scipy.optimize.least_squares`` on the
    weighted dB and degree errors, whose sum of squares is J); the first-order pole is kept
    only when it is :data:`POLE_SIGMAS` σ from zero and lowers J by more than the composite's
    bias accounts for (:func:`error_cost`).

    Parameters
    ----------
    r : FRF
        The measured response (rate per input unit), referenced to an injection on
        closed-loop data.
    band_hz : (float, float), optional
        Band to fit; default :func:`trusted_band` of ``r`` within ``excited_hz``.
    excited_hz : (float, float), optional
        The band the excitation swept (SYSTEMID's ``SID_F_START_HZ``..``SID_F_STOP_HZ``).
    structures : sequence of str
        The structures to choose between.
    max_delay_s, max_lag_s : float
        Upper bounds of τ and T.

    Raises
    ------
    NoExcitationError
        Fewer than :data:`MIN_TF_POINTS` coherent frequencies in the band, or a gain that is
        not positive.

    Examples
    --------
    >>> f = np.geomspace(1, 15, 40)
    >>> s = 2j * np.pi * f
    >>> h = 500 * np.exp(-0.019 * s) / (s * (0.013 * s + 1))
    >>> fit = fit_plant(FRF(f, h, np.full(40, 0.9), np.full(40, 0.05), (4.0,), referenced=True))
    >>> fit.structure, round(fit.gain), round(fit.lag_s, 4), round(fit.delay_s, 4)
    ('integrator', 500, 0.013, 0.019)
    """
    unknown = set(structures) - set(STRUCTURES)
    if unknown or not structures:
        raise ValueError(f"structures must be among {STRUCTURES}, got {list(structures)}")
    band = band_hz or trusted_band(r, excited_hz)
    name = f"{r.input} -> {r.output}"
    if band is None:
        raise NoExcitationError(f"{name}: no frequency with coherence >= {MIN_COHERENCE:g}")
    m = ((r.trust >= MIN_COHERENCE) & np.isfinite(r.response) & (np.abs(r.response) > 0)
         & (r.freq_hz >= band[0]) & (r.freq_hz <= band[1]))
    if m.sum() < MIN_TF_POINTS:
        raise NoExcitationError(
            f"{name}: {int(m.sum())} coherent frequencies in {band[0]:.3g}-{band[1]:.3g} Hz "
            f"(a transfer function needs {MIN_TF_POINTS})")
    f, h, coh = r.freq_hz[m], r.response[m], r.trust[m]
    n_ind = _independent(f, r.windows_s)
    fits = {st: _fit_structure(f, h, coh, st, max_delay_s, max_lag_s, n_ind)
            for st in structures}
    chosen = "integrator" if "integrator" in fits else "first_order"
    reason = "integrator: " + ("the only structure asked for" if len(fits) == 1 else "")
    if "first_order" in fits and "integrator" in fits:
        p, cost, sd = fits["first_order"]
        cost_i = fits["integrator"][1]
        z = abs(p[1]) / sd["pole_random"] if sd["pole_random"] > 0 else math.inf
        floor = error_cost(np.zeros(coh.size), coh)  # (the random error is in the σ)
        if z >= POLE_SIGMAS and cost_i - cost > floor:
            chosen = "first_order"
            reason = (f"first order: pole {p[1]:.3g} ± {sd['pole_random']:.2g} 1/s ({z:.1f} σ) "
                      f"lowers "
                      f"J from {cost_i:.3g} to {cost:.3g}, more than the response's bias "
                      f"({floor:.2g})")
        else:
            reason = (f"integrator: the first-order pole {p[1]:.3g} ± {sd['pole_random']:.2g} 1/s "
                      f"({z:.1f} σ from 0) lowers J only from {cost_i:.3g} to {cost:.3g} "
                      f"(the response's bias accounts for {floor:.2g})")
    elif chosen == "first_order":
        reason = "first order: the only structure asked for"
    p, cost, sd = fits[chosen]
    if chosen == "integrator" and "first_order" in fits:  # (how well the data place a pole)
        sd = {**sd, "pole": fits["first_order"][2]["pole"],
              "pole_random": fits["first_order"][2]["pole_random"]}
    if not p[0] > 0:
        raise NoExcitationError(f"{name}: the fitted gain {p[0]:.3g} is not positive")
    tf = PlantTF(chosen, float(p[0]), float(p[1]), float(p[2]), float(p[3]), cost,
                 (float(f.min()), float(f.max())), sd, 0.0, 0.0, int(m.sum()), r, reason)
    db, deg = rms_errors(h, tf.response(f), coh)
    return replace(tf, rms_db=db, rms_deg=deg)


def identify_frequency(u: np.ndarray | Sequence[np.ndarray], y: np.ndarray | Sequence[np.ndarray],
                       dt: float, *, reference: np.ndarray | Sequence[np.ndarray] | None = None,
                       excited_hz: tuple[float, float] | None = None,
                       structures: Sequence[str] = STRUCTURES,
                       windows_s: Sequence[float] = WINDOWS_S) -> PlantTF:
    """A rate plant identified from arrays in the frequency domain: the composite response of
    ``y`` to ``u`` (:func:`frf`; against ``reference`` on closed-loop data), fitted on the
    band where its coherence holds (:func:`fit_plant`).

    A gyro full of aliased vibration is incoherent with the input above some frequency: the
    fit keeps to the band below it, or refuses when too little is coherent (a time-domain
    regression on such a signal can return a negative effectiveness without a word).

    Parameters
    ----------
    u, y : numpy.ndarray or sequence of numpy.ndarray
        Plant input (the mixer input, normalised) and rate (rad/s), one array per record.
    dt : float
        Sample step (s).
    reference : numpy.ndarray or sequence of numpy.ndarray, optional
        The injected signal (SYSTEMID's ``SIDD.Targ``) per record.
    excited_hz : (float, float), optional
        The band the excitation swept.
    structures, windows_s :
        As :func:`fit_plant` and :func:`frf` take them.

    Raises
    ------
    NoExcitationError
        Too little of the response is coherent, or the fitted gain is not positive.

    Examples
    --------
    >>> from scipy import signal
    >>> t = np.arange(0, 30, 0.01)
    >>> u = signal.chirp(t, 0.5, 30, 15, method="logarithmic")
    >>> plant = signal.cont2discrete(([400.0], [0.02, 1.0, 0.0]), 0.01, method="zoh")
    >>> y = signal.dlsim((plant[0].ravel(), plant[1], 0.01), u)[1].ravel()
    >>> fit = identify_frequency(u, y, 0.01, excited_hz=(0.5, 15))
    >>> fit.structure, bool(abs(fit.gain / 400 - 1) < 0.05)
    ('integrator', True)
    """
    def records(x: np.ndarray | Sequence[np.ndarray]) -> list[np.ndarray]:
        arr = x if isinstance(x, Sequence) else [x]
        return [np.asarray(v, dtype=float).ravel() for v in arr]

    us, ys = records(u), records(y)
    refs = None if reference is None else records(reference)
    grid = {} if excited_hz is None else {"f_min_hz": excited_hz[0],
                                          "f_max_hz": min(excited_hz[1], 0.4 / dt)}
    measured = frf(us, ys, dt, reference=refs, windows_s=windows_s, **grid)  # type: ignore[arg-type]
    return fit_plant(measured, excited_hz=excited_hz, structures=structures)
