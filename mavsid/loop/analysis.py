"""What the rate loop does with given gains: margins, bandwidths, the closed loop's step,
on a modelled plant (:func:`analyse_plant`, :func:`analyse_model` with one-σ from the
model's covariance) and on measured responses (:func:`frd_margins`, :func:`margins_on_frf`,
:func:`compare_response`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.polynomial import Polynomial

from mavsid.errors import MavsidError
from mavsid.loop.controllers import (
    AXIS_RATE,
    AxisController,
    PX4RateGains,
    RateGains,
    lowpass_alpha,
    measurement_filter,
)
from mavsid.loop.plant import LinearPlant, Poly, plant_from_model, ss2tf
from mavsid.numerics.filters import lowpass2p_coefficients
from mavsid.numerics.lti import tf2ss

if TYPE_CHECKING:
    from mavsid.frequency import FRF

__all__ = [
    "LoopAnalysis",
    "analyse_model",
    "analyse_plant",
    "closed_figures",
    "compare_response",
    "controller_polys",
    "frd_margins",
    "frd_margins_at",
    "grid_margins",
    "loop_figures",
    "loop_statespace",
    "margin_db",
    "margin_grid",
    "margins_of",
    "margins_on_frf",
    "step_figures",
]

def controller_polys(ctrl: AxisController, dt: float | None = None) -> tuple[Poly, Poly]:
    """Discrete transfer functions of the rate controller at its loop step, ``(C_fb, C_t)``:
    output per measured rate (negated: ``u = C_t·target − C_fb·rate``) and per target, each
    ``(num, den)`` in descending powers of z.

    :class:`RatePID` without limits: error filter ``F_E``, target filter ``F_T``, derivative
    filter ``F_D`` (first order, ``α/(1 − (1−α)z⁻¹)``), integrator ``I·dt/(1 − z⁻¹)``,
    derivative ``(1 − z⁻¹)/dt``: ``C_fb = F_E·(P + I·dt/(1 − z⁻¹) + D·F_D·(1 − z⁻¹)/dt)``,
    ``C_t = F_T·(C_fb + FF)``. :class:`PX4RatePID`: ``C_fb = K·(P + I·dt/(1 − z⁻¹) +
    D·F_D·(1 − z⁻¹)/dt)`` (``F_D`` its biquad), ``C_t = K·(P + I·dt/(1 − z⁻¹)) + FF``.
    Written over one denominator with :class:`numpy.polynomial.Polynomial` in ``z⁻¹``
    (``tests/test_loop_analysis.py`` compares them with the controllers stepped and with
    python-control's sums and products of the parts).

    Examples
    --------
    >>> from mavsid.loop.controllers import controller_from_params
    >>> (bf, af), _ = controller_polys(controller_from_params({}, "roll"))
    >>> z = np.exp(2j * np.pi * 1.0 * 0.0025)
    >>> round(float(abs(np.polyval(bf, z) / np.polyval(af, z))), 3)   # |C_fb| at 1 Hz
    0.136
    """
    step = 1.0 / ctrl.loop_hz if dt is None else dt
    return _controller_polys(ctrl.gains, float(step))


def _in_z(num: Polynomial, den: Polynomial) -> Poly:
    """``num(z⁻¹) / den(z⁻¹)`` as ``(num, den)`` in descending powers of z (both times
    ``zᵐ``, ``m`` the higher degree: the ascending coefficients in z⁻¹, padded)."""
    if not np.any(num.coef):
        return np.zeros(1), np.ones(1)
    m = max(num.degree(), den.degree()) + 1
    return (np.pad(num.coef, (0, m - num.coef.size)), np.pad(den.coef, (0, m - den.coef.size)))


def _first_order(cutoff_hz: float, dt: float) -> tuple[Polynomial, Polynomial]:
    """The controllers' first-order low pass ``α / (1 − (1−α)z⁻¹)`` in z⁻¹ (1 when off)."""
    a = lowpass_alpha(cutoff_hz, dt)
    if a >= 1.0:
        return Polynomial([1.0]), Polynomial([1.0])
    return Polynomial([a]), Polynomial([1.0, a - 1.0])


@functools.lru_cache(maxsize=64)
def _controller_polys(g: RateGains | PX4RateGains, step: float) -> tuple[Poly, Poly]:
    """:func:`controller_polys` by gains and step, cached (callers never modify them)."""
    diff = Polynomial([1.0, -1.0])  # 1 − z⁻¹
    # over (1 − z⁻¹) with an integrator; without one (I = 0) the factor is not there at all,
    # rather than cancelled: a pole and zero at z = 1 would leave the closed loop a mode on
    # the unit circle that no gain moves (an I-less loop judged "unstable")
    back = diff if g.i != 0 else Polynomial([1.0])
    if isinstance(g, PX4RateGains):
        nd, dd = Polynomial([1.0]), Polynomial([1.0])
        if 0 < g.dgyro_hz < 0.5 / step:
            b, a = lowpass2p_coefficients(g.dgyro_hz, 1.0 / step)
            nd, dd = Polynomial(b), Polynomial(a)
        pi = g.k * g.p * back + g.k * g.i * step  # K·(P + I·dt/(1 − z⁻¹)), times `back`
        fb = _in_z(pi * dd + (g.k * g.d / step) * nd * diff * back, back * dd)
        return fb, _in_z(pi + g.ff * back, back)
    (nt, dt_), (ne, de), (nd, dd) = (_first_order(c, step) for c in (g.fltt, g.flte, g.fltd))
    inner = (g.p * back + g.i * step) * dd + (g.d / step) * nd * diff * back  # over back·F_D's
    num, den = ne * inner, de * back * dd
    return _in_z(num, den), _in_z(nt * (num + g.ff * den), dt_ * den)


@dataclass(frozen=True)
class LoopAnalysis:
    """The rate loop of one axis with given gains.

    Attributes
    ----------
    gain_margin_db, phase_margin_deg, crossover_hz : float
        Of the loop transfer ``L = C_fb·P`` (crossover: where ``|L| = 1``).
    bandwidth_hz : float
        −3 dB bandwidth of the closed loop from rate target to rate.
    peak_db : float
        Largest closed-loop gain.
    disturbance_bandwidth_hz : float
        Where the sensitivity ``1/(1+L)`` reaches −3 dB.
    phase_delay_s : float
        Phase delay of the closed loop at twice the −180° frequency (``-phase/ω``, at the
        bandwidth when that is not reached).
    rise_time_s, overshoot_percent : float
        Of the closed-loop step response.
    freq_hz, magnitude_db, phase_deg : numpy.ndarray
        The closed-loop response from rate target to rate.
    stderr : Mapping[str, float]
        One-σ of each figure from the plant's parameter covariance.
    loop_response, closed_response : numpy.ndarray
        Complex ``L`` and ``T`` at ``freq_hz``.
    mixer_loop_response : numpy.ndarray
        The broken loop a mixer injection measures: the rate loop and the attitude loop
        around it (``angle_p``), ``(C_fb + C_t·angle_p·dt/(1−z⁻¹))·P``.
    mixer_margins : Mapping[str, float]
        ``gain_db``, ``phase_deg``, ``crossover_hz`` of that loop.
    """

    gain_margin_db: float
    phase_margin_deg: float
    crossover_hz: float
    bandwidth_hz: float
    peak_db: float
    disturbance_bandwidth_hz: float
    phase_delay_s: float
    rise_time_s: float
    overshoot_percent: float
    freq_hz: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    magnitude_db: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    phase_deg: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    stderr: Mapping[str, float] = field(default_factory=dict)
    loop_response: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, complex))
    closed_response: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, complex))
    mixer_loop_response: np.ndarray = field(repr=False,
                                            default_factory=lambda: np.zeros(0, complex))
    mixer_margins: Mapping[str, float] = field(default_factory=dict)

    def figures(self) -> dict[str, float]:
        """The scalar figures by name."""
        return {k: float(getattr(self, k)) for k in _FIGURES}

    def to_dict(self) -> dict[str, Any]:
        """The JSON form ``mavsid tune --json`` gives per axis (margins, closed loop)."""
        return {
            "margins": {"gain_db": self.gain_margin_db, "phase_deg": self.phase_margin_deg,
                        "crossover_hz": self.crossover_hz},
            "closed_loop": {
                "bandwidth_hz": self.bandwidth_hz, "peak_db": self.peak_db,
                "disturbance_bandwidth_hz": self.disturbance_bandwidth_hz,
                "phase_delay_s": self.phase_delay_s, "rise_time_s": self.rise_time_s,
                "overshoot_percent": self.overshoot_percent,
                "frequency_hz": self.freq_hz.tolist(),
                "magnitude_db": self.magnitude_db.tolist(),
                "phase_deg": self.phase_deg.tolist(),
            },
            "mixer_margins": dict(self.mixer_margins),
            "loop": {
                "frequency_hz": self.freq_hz.tolist(),
                "magnitude_db": (20 * np.log10(np.abs(self.loop_response))).tolist(),
                "phase_deg": np.degrees(np.unwrap(np.angle(self.loop_response))).tolist(),
            },
            "stderr": dict(self.stderr),
        }


_FIGURES = ("gain_margin_db", "phase_margin_deg", "crossover_hz", "bandwidth_hz", "peak_db",
            "disturbance_bandwidth_hz", "phase_delay_s", "rise_time_s", "overshoot_percent")


def _crossing(f: np.ndarray, mag_db: np.ndarray, level: float, rising: bool) -> float:
    """First frequency where ``mag_db`` crosses ``level`` (log-interpolated), NaN if never."""
    above = mag_db >= level
    now, before = (above[1:], above[:-1]) if rising else (~above[1:], ~above[:-1])
    idx = np.flatnonzero(now & ~before)
    if not idx.size:
        return float("nan")
    i = int(idx[0])
    x0, x1 = np.log(f[i]), np.log(f[i + 1])
    y0, y1 = mag_db[i], mag_db[i + 1]
    return float(np.exp(x0 + (level - y0) * (x1 - x0) / (y1 - y0))) if y1 != y0 else float(f[i])


def loop_statespace(plant: LinearPlant, cfb: Poly
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The broken loop ``L = C_fb·P`` as a discrete state space ``(A, B, C)``: the plant,
    then the controller ``cfb`` (``(num, den)`` in z, :func:`controller_polys`), in
    python-control's ``C_fb * P`` order, without feedthrough (the plant has none). The
    closed loop with the gains scaled by ``k`` has the state matrix ``A − k·B·C``: its
    eigenvalues are the roots of ``1 + k·L``.

    Examples
    --------
    >>> p = LinearPlant(np.array([[1.0]]), np.array([0.25]), np.array([1.0]), 0.0025)
    >>> a, b, c = loop_statespace(p, (np.array([0.5]), np.array([1.0])))
    >>> float(np.linalg.eigvals(a - b @ c)[0])   # 1 - 0.5 * 0.25
    0.875
    """
    ac, bc, cc, dc = tf2ss(*cfb)
    ap, bp, cp = plant.a, plant.b.reshape(-1, 1), plant.c.reshape(1, -1)
    n_p, n_c = ap.shape[0], ac.shape[0]
    a = np.zeros((n_p + n_c,) * 2)
    a[:n_p, :n_p] = ap
    a[n_p:, :n_p] = bc @ cp
    a[n_p:, n_p:] = ac
    b = np.concatenate([bp, np.zeros((n_c, 1))])
    c = np.concatenate([dc @ cp, cc], axis=1)
    return a, b, c


def margin_grid(dt: float, n: int = 4000) -> np.ndarray:
    """The frequencies (Hz) :func:`margins_of` reads a discrete loop at step ``dt`` on: a
    dense log grid up to Nyquist."""
    return np.geomspace(1e-3 / dt, 0.4999 / dt, n)


def grid_margins(f: np.ndarray, resp: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                            np.ndarray]:
    """Every margin of an open loop read off its response ``resp`` at ``f`` (Hz, a dense
    log grid such as :func:`margin_grid`), in the order ``control.stability_margins(...,
    returnall=True)`` gives them: ``(gain margins (ratio), phase margins (deg), stability
    margins, phase crossovers, gain crossovers, stability-margin frequencies)`` (the last
    three in rad/s). The crossings are interpolated between the points (``log |L|`` and the
    phase linear in ``log f``); the gain margins are ``1/|L|`` where ``L`` crosses the
    negative real axis; the stability margins ``|1 + L|`` at its interior local minima on
    the grid (each at the vertex of the parabola through three points).
    ``tests/test_loop_analysis.py`` compares them with python-control's: they replace its
    ``stability_margins`` where a loop is checked many times (a gain search), whose fit of
    a spline to the loop and root finding on it took 50 ms a call.

    Examples
    --------
    >>> dt = 0.0025
    >>> f = margin_grid(dt)
    >>> z = np.exp(2j * np.pi * f * dt)
    >>> gms, pms, sms, wpc, wgc, wms = grid_margins(f, 0.02 / ((z - 1.0) * z * z))
    >>> [round(float(v[0]), 4) for v in (gms, pms, sms, wpc, wgc)]  # python-control: the same
    [30.9017, 87.1352, 0.9553, 251.3275, 8.0001]
    """
    mag = np.abs(resp)
    logf = np.log(f)
    up = mag >= 1.0
    i = np.flatnonzero(up[:-1] != up[1:])
    x = (0.0 - np.log(mag[i])) / (np.log(mag[i + 1]) - np.log(mag[i]))
    ang = np.angle(resp[i]) + x * np.angle(resp[i + 1] / resp[i])
    pms = np.degrees(ang) % 360.0 - 180.0  # in [-180, 180)
    wgc = np.exp(logf[i] + x * (logf[i + 1] - logf[i])) * 2 * np.pi
    keep = np.isfinite(pms)
    pms, wgc = pms[keep], wgc[keep]
    im = resp.imag
    j = np.flatnonzero(np.sign(im[:-1]) * np.sign(im[1:]) < 0)
    y = im[j] / (im[j] - im[j + 1])
    re = resp.real[j] + y * (resp.real[j + 1] - resp.real[j])
    neg = re < 0
    gms = 1.0 / np.abs(re[neg])
    wpc = np.exp(logf[j] + y * (logf[j + 1] - logf[j]))[neg] * 2 * np.pi
    dist = np.abs(1.0 + resp)
    k = np.flatnonzero((dist[1:-1] < dist[:-2]) & (dist[1:-1] <= dist[2:])) + 1
    # each minimum at the vertex of the parabola through it and its neighbours (in log f)
    d0, d1, d2 = dist[k - 1], dist[k], dist[k + 1]
    curv = d0 - 2.0 * d1 + d2
    v = np.where(curv > 0, 0.5 * (d0 - d2) / np.where(curv > 0, curv, 1.0), 0.0)
    step = logf[k + 1] - logf[k]
    return (gms, pms, d1 - 0.25 * (d0 - d2) * v, wpc, wgc,
            2 * np.pi * np.exp(logf[k] + v * step))


def margins_of(f: np.ndarray, resp: np.ndarray) -> tuple[float, float, float]:
    """``(gain margin (ratio), phase margin (deg), gain crossover (rad/s))`` of an open loop
    from its response ``resp`` at ``f`` (Hz, :func:`margin_grid`): :func:`grid_margins`'
    smallest (what ``control.stability_margins`` gives, ``tests/test_loop_analysis.py``
    compares, without its spline fit per call: the report analyses the loop dozens of times
    per axis)."""
    gms, pms, _, _, wgc, _ = grid_margins(f, resp)
    gm = float(np.min(gms)) if gms.size else float("inf")
    if not pms.size:
        return gm, float("inf"), float("nan")
    i = int(np.argmin(pms))
    return gm, float(pms[i]), float(wgc[i])


def margin_db(gain_margin: float) -> float:
    """A gain margin in dB (inf when the phase never crosses -180°)."""
    ok = np.isfinite(gain_margin) and gain_margin > 0
    return float(20 * np.log10(gain_margin)) if ok else float("inf")


def closed_figures(f: np.ndarray, t_resp: np.ndarray, s_resp: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, float, float, float]:
    """``(magnitude dB, phase deg, bandwidth, disturbance bandwidth, phase delay)`` of a
    closed loop from its responses ``T`` and ``S`` at ``f`` (see :class:`LoopAnalysis`)."""
    mag = 20 * np.log10(np.abs(t_resp))
    ph = np.degrees(np.unwrap(np.angle(t_resp)))
    bw = _crossing(f, mag - mag[0], -3.0, rising=False)
    dbw = _crossing(f, 20 * np.log10(np.abs(s_resp)), -3.0, rising=True)
    i180 = np.flatnonzero(ph <= -180.0)
    if i180.size:
        f2 = 2 * f[i180[0]] if 2 * f[i180[0]] <= f[-1] else f[i180[0]]
        phase_delay = float(-np.interp(f2, f, ph) / (360 * f2))
    elif np.isfinite(bw):
        phase_delay = float(-np.interp(bw, f, ph) / (360 * bw))
    else:
        phase_delay = float("nan")
    return mag, ph, bw, dbw, phase_delay


def loop_figures(plant: LinearPlant, ctrl: AxisController, lag: int = 0,
                 freq_hz: np.ndarray | None = None, meas_delay: float = 0.0
                 ) -> dict[str, float]:
    """:meth:`LoopAnalysis.figures` of :func:`analyse_plant` without the responses, for
    :func:`analyse_model`'s draws of the coefficients."""
    return analyse_plant(plant, ctrl, lag, freq_hz, meas_delay, responses=False).figures()


def analyse_plant(plant: LinearPlant, ctrl: AxisController, lag: int = 0,
                  freq_hz: np.ndarray | None = None, meas_delay: float = 0.0,
                  responses: bool = True) -> LoopAnalysis:
    """Margins, bandwidths and step figures of ``ctrl`` around ``plant`` (at the controller's
    step): each response the product of its parts' (the controller from
    :func:`controller_polys`), the step simulated in state space. ``lag`` loops of delay on
    the target path (see :func:`~mavsid.loop.twin.replay_controller`); ``meas_delay`` (0-1
    loop) on the measured rate the controller reads (``(1 − τ) + τz⁻¹``,
    :attr:`~mavsid.loop.twin.ClosedLoopFit.measurement_delay_loops`).
    ``tests/test_loop_analysis.py`` compares every figure and response with python-control's.
    ``responses=False`` leaves out the responses, the broken loop at the mixer and its
    margins."""
    dt = 1.0 / ctrl.loop_hz
    (bf, af), (bt, at) = controller_polys(ctrl, dt)
    if lag:
        at = np.polymul(at, [1.0] + [0.0] * lag)
    tau, num, den = measurement_filter(meas_delay)
    if tau:
        bf, af = np.polymul(bf, num), np.polymul(af, den)
    bp, ap = ss2tf(plant.a, plant.b, plant.c)
    f = np.geomspace(0.1, 0.45 / dt, 400) if freq_hz is None else np.asarray(freq_hz)
    fm = margin_grid(dt)

    def loop_at(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = np.polyval(bp, z) / np.polyval(ap, z)
        return p, p * np.polyval(bf, z) / np.polyval(af, z)

    mixer: dict[str, float] = {}
    m_resp = np.zeros(0, complex)
    with np.errstate(all="ignore"):
        zm = np.exp(2j * np.pi * fm * dt)
        gm, pm, wcp = margins_of(fm, loop_at(zm)[1])
        zs = np.exp(2j * np.pi * f * dt)
        p, lz = loop_at(zs)
        ctz = np.polyval(bt, zs) / np.polyval(at, zs)
        t_resp = p * ctz / (1.0 + lz)
        mag, ph, bw, dbw, phase_delay = closed_figures(f, t_resp, 1.0 / (1.0 + lz))
        t = np.arange(0.0, 2.0, dt)
        y = _closed_step(plant, (bf, af), (bt, at), t.size)
        if responses:
            # at the mixer the attitude loop closes too: target = angle_p · −∫rate
            def mixer_at(z: np.ndarray, p: np.ndarray, lz: np.ndarray,
                         ctz: np.ndarray) -> np.ndarray:
                return lz + ctz * ctrl.angle_p * (dt * z / (z - 1.0)) * p

            m_resp = mixer_at(zs, p, lz, ctz)
            pmz, lmz = loop_at(zm)
            mgm, mpm, mwc = margins_of(
                fm, mixer_at(zm, pmz, lmz, np.polyval(bt, zm) / np.polyval(at, zm)))
            mixer = {"gain_db": margin_db(mgm), "phase_deg": float(mpm),
                     "crossover_hz": float(mwc / (2 * np.pi))}
    rise, over = step_figures(t, y)
    return LoopAnalysis(
        gain_margin_db=margin_db(gm), phase_margin_deg=float(pm),
        crossover_hz=float(wcp / (2 * np.pi)), bandwidth_hz=bw, peak_db=float(np.max(mag)),
        disturbance_bandwidth_hz=dbw, phase_delay_s=phase_delay, rise_time_s=rise,
        overshoot_percent=over, freq_hz=f, magnitude_db=mag, phase_deg=ph,
        loop_response=lz if responses else np.zeros(0, complex),
        closed_response=t_resp if responses else np.zeros(0, complex),
        mixer_loop_response=m_resp, mixer_margins=mixer)


def _closed_step(plant: LinearPlant, fb: tuple[np.ndarray, np.ndarray],
                 tg: tuple[np.ndarray, np.ndarray], n: int) -> np.ndarray:
    """``n`` samples of the unit-step response of ``P·C_t / (1 + C_fb·P)`` (``fb``, ``tg``:
    ``C_fb``, ``C_t`` as ``(num, den)`` in z), simulated in state space: plant, feedback and
    target filter states side by side (a single polynomial of the closed loop would carry
    the integrators' cancelling pole-zero pair at z = 1 and drift)."""
    ap, bp, cp = plant.a, plant.b.reshape(-1, 1), plant.c.reshape(1, -1)
    af, bf, cf, df = tf2ss(*fb)
    at, bt, ct, dt_ = tf2ss(*tg)
    npl, nf, nt = ap.shape[0], af.shape[0], at.shape[0]
    a = np.zeros((npl + nf + nt,) * 2)
    a[:npl, :npl] = ap - bp @ (df @ cp)
    a[:npl, npl:npl + nf] = -bp @ cf
    a[:npl, npl + nf:] = bp @ ct
    a[npl:npl + nf, :npl] = bf @ cp
    a[npl:npl + nf, npl:npl + nf] = af
    a[npl + nf:, npl + nf:] = at
    b = np.concatenate([bp @ dt_, np.zeros((nf, 1)), bt]).ravel()
    c = np.concatenate([cp.ravel(), np.zeros(nf + nt)])
    # blocks of m steps: y[jm + i] = c·Aⁱ·x[jm] + c·(I + … + Aⁱ⁻¹)·b, x[(j+1)m] = Aᵐ·x[jm] + sₘ
    m = 32
    rows = np.empty((m, a.shape[0]))
    sums = np.empty(m)
    row, acc = c.copy(), 0.0
    for i in range(m):
        rows[i], sums[i] = row, acc
        acc += float(row @ b)
        row = row @ a
    power, s = np.eye(a.shape[0]), np.zeros(a.shape[0])
    for _ in range(m):
        s = a @ s + b
        power = a @ power
    x = np.zeros(a.shape[0])
    y = np.empty(-(-n // m) * m)
    for j in range(0, y.size, m):
        y[j:j + m] = rows @ x + sums
        x = power @ x + s
    return y[:n]


def step_figures(t: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """10-90 % rise time (s) and overshoot (%) of a step response ``y`` at times ``t``."""
    final = float(np.mean(y[-max(1, len(y) // 10):]))
    if not np.all(np.isfinite(y)) or abs(final) < 1e-9:
        return float("nan"), float("nan")
    r = y / final
    i10, i90 = np.flatnonzero(r >= 0.1), np.flatnonzero(r >= 0.9)
    rise = float(t[i90[0]] - t[i10[0]]) if i10.size and i90.size else float("nan")
    return rise, float(max(0.0, 100.0 * (np.max(r) - 1.0)))


def analyse_model(model: Any, axis: str, ctrl: AxisController, lag: int = 0,
                  samples: int = 40, seed: int = 0, meas_delay: float = 0.0) -> LoopAnalysis:
    """:func:`analyse_plant` of the identified plant, with one-σ uncertainties from
    ``samples`` draws of the model's coefficients from their covariance."""
    dt = 1.0 / ctrl.loop_hz
    base = analyse_plant(plant_from_model(model, axis, dt), ctrl, lag, meas_delay=meas_delay)
    cov = getattr(model, "covariance", None)
    rate = AXIS_RATE[axis]
    if cov is None or samples < 2 or rate not in model.state_names:
        return base
    j = model.state_names.index(rate)
    c = np.nan_to_num(np.asarray(cov[j], dtype=float))
    rng = np.random.default_rng(seed)
    draws = []
    for _ in range(samples):
        coef = model.coef.copy()
        coef[:, j] = rng.multivariate_normal(model.coef[:, j], c, check_valid="ignore")
        try:
            m = replace(model, coef=coef)
            draws.append(loop_figures(plant_from_model(m, axis, dt), ctrl, lag, base.freq_hz,
                                      meas_delay))
        except (MavsidError, ValueError, np.linalg.LinAlgError):
            continue
    if len(draws) < 2:
        return base
    finite = {k: [d[k] for d in draws if np.isfinite(d[k])] for k in _FIGURES}
    err = {k: float(np.std(v)) if v else math.nan for k, v in finite.items()}
    return replace(base, stderr=err)


def margins_on_frf(plant_frf: FRF, ctrl: AxisController) -> dict[str, float]:
    """Margins of ``ctrl`` around a measured plant FRF (controller output -> rate): the loop
    ``C_fb(e^{jωT})·P̂(f)`` over the FRF's coherent band, a check on a model's promise that
    does not go through the model (NaN where the band holds no crossover)."""
    m = plant_frf.coherent & np.isfinite(plant_frf.response)
    nan = {"gain_db": float("nan"), "phase_deg": float("nan"), "crossover_hz": float("nan")}
    if m.sum() < 8:
        return nan
    f, p = plant_frf.freq_hz[m], plant_frf.response[m]
    dt = 1.0 / ctrl.loop_hz
    cfb, _ = controller_polys(ctrl, dt)
    z = np.exp(2j * np.pi * f * dt)
    loop_resp = np.polyval(cfb[0], z) / np.polyval(cfb[1], z) * p
    band = replace(plant_frf, freq_hz=f, response=loop_resp, coherence=np.ones(f.size),
                   error=plant_frf.error[m])
    got = frd_margins(band)
    return got if f[0] < got["crossover_hz"] < f[-1] else nan


def compare_response(measured: FRF, freq_hz: np.ndarray, response: np.ndarray
                     ) -> dict[str, Any]:
    """Median and largest absolute error in dB and degrees of a predicted response against a
    measured FRF over the measured one's coherent band (NaN when none)."""
    m = measured.coherent & (measured.freq_hz >= freq_hz[0]) & (measured.freq_hz <= freq_hz[-1])
    if not m.any():
        return {"median_db": float("nan"), "max_db": float("nan"),
                "median_deg": float("nan"), "max_deg": float("nan"), "band_hz": None}
    f = measured.freq_hz[m]
    pred = np.interp(f, freq_hz, response.real) + 1j * np.interp(f, freq_hz, response.imag)
    ratio = measured.response[m] / pred
    db = np.abs(20 * np.log10(np.abs(ratio)))
    deg = np.abs(np.degrees(np.angle(ratio)))
    return {"median_db": float(np.median(db)), "max_db": float(np.max(db)),
            "median_deg": float(np.median(deg)), "max_deg": float(np.max(deg)),
            "band_hz": [float(f.min()), float(f.max())]}


def frd_margins(measured: FRF, freq_hz: np.ndarray | None = None,
                response: np.ndarray | None = None) -> dict[str, float]:
    """Gain and phase margin of a measured broken-loop FRF over its coherent band; with
    ``freq_hz`` and ``response``, those of that (predicted) response over the same band, for
    a like-for-like comparison. The margins are ``control.stability_margins`` of
    ``control.frd(h, ω)`` (:func:`frd_margins_at`: its interpolation and root finding, without
    importing python-control; ``tests/test_frequency.py`` compares)."""
    m = measured.coherent & np.isfinite(measured.response)
    nan = {"gain_db": float("nan"), "phase_deg": float("nan"), "crossover_hz": float("nan")}
    if m.sum() < 4:
        return nan
    f = measured.freq_hz[m]
    h = measured.response[m]
    if freq_hz is not None and response is not None:
        h = np.interp(f, freq_hz, response.real) + 1j * np.interp(f, freq_hz, response.imag)
    gm, pm, wc = frd_margins_at(h, 2 * np.pi * f)
    return {"gain_db": margin_db(gm), "phase_deg": float(pm),
            "crossover_hz": float(wc / (2 * np.pi))}


def frd_margins_at(h: np.ndarray, w: np.ndarray) -> tuple[float, float, float]:
    """``(gain margin, phase margin (deg), gain crossover (rad/s))`` of a frequency response
    ``h`` at ``w`` (rad/s) as python-control's ``stability_margins`` of a smoothed FRD gives
    them: a parametric interpolating spline through the real and imaginary parts
    (``scipy.interpolate.splprep``, ``s=0``), the −180° and unit-gain crossings between the
    points located on it by ``scipy.optimize.brentq``; the smallest ``|log GM|`` and
    ``|PM|``."""
    from scipy.interpolate import splev, splprep
    from scipy.optimize import brentq

    order = np.argsort(w, kind="stable")
    w, h = np.asarray(w, dtype=float)[order], np.asarray(h, dtype=complex)[order]
    tck, _ = splprep([h.real, h.imag], u=w, w=1.0 / (np.abs(h) + 0.001), s=0.0,
                     k=min(3, w.size - 1))

    def at(x: Any) -> np.ndarray:
        re, im = splev(x, tck)
        return np.asarray(re) + 1j * np.asarray(im)

    def arg(x: float) -> float:
        return float(np.angle(-at(x)))

    def mod(x: float) -> float:
        return float(np.abs(at(x))) - 1.0

    hw = at(w)
    idx = np.where(np.diff(np.sign(np.angle(-hw))))[0]
    idx = idx[np.real(hw[idx]) <= 0]
    w180 = np.array([brentq(arg, w[i], w[i + 1]) for i in idx])
    idx = np.where(np.diff(np.sign(np.abs(hw) - 1.0)))[0]
    wc = np.array([brentq(mod, w[i], w[i + 1]) for i in idx])
    with np.errstate(all="ignore"):
        gms = 1.0 / np.abs(at(w180)) if w180.size else np.zeros(0)
        pms = (np.remainder(np.angle(at(wc), deg=True), 360.0) - 180.0 if wc.size
               else np.zeros(0))
        gm = float("inf")
        if gms.size and not np.isinf(gms).all():
            lg = np.abs(np.log(gms))
            gm = float(gms[lg == np.min(lg)][0])
    if not pms.size:
        return gm, float("inf"), float("nan")
    i = int(np.flatnonzero(np.abs(pms) == np.min(np.abs(pms)))[0])
    return gm, float(pms[i]), float(wc[i])
