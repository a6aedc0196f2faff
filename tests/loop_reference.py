"""The loop analysis written with python-control's systems, the reference the runtime numpy
analysis (:mod:`mavsid.loop.analysis`) is compared against: the controller as sums and
products of python-control transfer functions, the loops as state-space products and
feedback, the step by ``control.step_response``."""

from __future__ import annotations

import functools
import warnings
from typing import Any

import control
import numpy as np

from mavsid.loop.analysis import (
    LoopAnalysis,
    closed_figures,
    margin_db,
    margin_grid,
    margins_of,
    step_figures,
)
from mavsid.loop.controllers import (
    AxisController,
    PX4RateGains,
    RateGains,
    lowpass_alpha,
    measurement_filter,
)
from mavsid.numerics.filters import lowpass2p_coefficients


def first_order_z(cutoff_hz: float, dt: float) -> tuple[list[float], list[float]]:
    """The ``lowpass_alpha`` low pass as ``(num, den)`` in z⁻¹ (unity when off)."""
    a = lowpass_alpha(cutoff_hz, dt)
    return ([a, 0.0], [1.0, -(1.0 - a)]) if a < 1.0 else ([1.0], [1.0])


def controller_tf(ctrl: AxisController, dt: float | None = None) -> tuple[Any, Any]:
    """Discrete transfer functions of the rate controller at its loop step: ``(C_fb, C_t)``,
    output per measured rate (negated: ``u = C_t·target − C_fb·rate``) and per target.

    Sums and products of the parts as :class:`RatePID` / :class:`PX4RatePID` combine them
    (integrator ``I·dt/(1 − z⁻¹)``, derivative ``(1 − z⁻¹)/dt``, first-order filters
    ``α/(1 − (1−α)z⁻¹)``, PX4's biquad on the derivative).

    Examples
    --------
    >>> from mavsid.loop.controllers import controller_from_params
    >>> cfb, ct = controller_tf(controller_from_params({}, "roll"))
    >>> round(float(abs(cfb(np.exp(1j * 2 * np.pi * 1.0 * 0.0025)))), 3)   # |C| at 1 Hz
    0.136
    """
    step = 1.0 / ctrl.loop_hz if dt is None else dt
    return controller_tf_of(ctrl.gains, float(step))


@functools.lru_cache(maxsize=64)
def controller_tf_of(g: RateGains | PX4RateGains, step: float) -> tuple[Any, Any]:
    """:func:`controller_tf` by gains and step, cached (python-control's polynomial
    arithmetic, ~5 ms a call; the systems are never modified in place)."""
    one = control.tf([1.0], [1.0], step)
    integ = control.tf([step, 0.0], [1.0, -1.0], step)  # dt / (1 - z^-1)
    deriv = control.tf([1.0, -1.0], [step, 0.0], step)  # (1 - z^-1) / dt
    if isinstance(g, PX4RateGains):
        fd = one
        if 0 < g.dgyro_hz < 0.5 / step:
            b, a = lowpass2p_coefficients(g.dgyro_hz, 1.0 / step)
            fd = control.tf(list(b), list(a), step)
        pi = g.k * g.p * one + g.k * g.i * integ
        return pi + g.k * g.d * fd * deriv, pi + g.ff * one
    ft = control.tf(*first_order_z(g.fltt, step), step)
    fe = control.tf(*first_order_z(g.flte, step), step)
    fd = control.tf(*first_order_z(g.fltd, step), step)
    pid = fe * (g.p * one + g.i * integ + g.d * fd * deriv)
    return pid, pid * ft + g.ff * ft


def frequency_response(system: Any, z: np.ndarray) -> np.ndarray:
    """A single-input single-output python-control system's response at the points ``z``,
    through its transfer-function polynomials (python-control evaluates a state space with
    one linear solve per point, far slower for thousands of points).

    Examples
    --------
    >>> import control
    >>> sys = control.ss(control.tf([0.5], [1.0, -0.9], 0.01))
    >>> z = np.exp(2j * np.pi * np.array([0.1, 10.0]) * 0.01)
    >>> bool(np.allclose(frequency_response(sys, z), np.ravel(sys(z))))
    True
    """
    if hasattr(system, "A"):
        a, b, c, d = (np.asarray(x, dtype=float) for x in
                      (system.A, system.B, system.C, system.D))
        if a.size == 0:
            return np.full(z.shape, float(d.ravel()[0]), dtype=complex)
        from scipy import signal

        num, den = (np.atleast_1d(np.ravel(x)) for x in signal.ss2tf(a, b, c, d))
    else:
        num = np.asarray(system.num[0][0], dtype=float)
        den = np.asarray(system.den[0][0], dtype=float)
    return np.polyval(num, z) / np.polyval(den, z)


def loop_margins(loop: Any, dt: float, n: int = 4000) -> tuple[float, float, float]:
    """``(gain margin (ratio), phase margin (deg), gain-crossover (rad/s))`` of a discrete
    open loop, read off its frequency response on a dense log grid up to Nyquist (crossings
    interpolated between grid points; the smallest margins when there are several), as
    ``control.stability_margins`` gives them but without its per-call spline fits (about
    100× faster: the report samples the loop dozens of times per axis).

    Examples
    --------
    >>> import control
    >>> dt = 0.0025
    >>> loop = control.tf([0.0, 0.02], [1.0, -1.0], dt) * control.tf([1.0], [1.0, 0.0, 0.0], dt)
    >>> gm, pm, wc = loop_margins(loop, dt)
    >>> ref = control.stability_margins(loop)
    >>> bool(abs(pm - ref[1]) < 0.05 and abs(wc - ref[4]) / ref[4] < 1e-3
    ...      and abs(gm - ref[0]) / ref[0] < 1e-3)
    True
    """
    f = margin_grid(dt, n)
    return margins_of(f, frequency_response(loop, np.exp(2j * np.pi * f * dt)))


def analyse_loop(plant_ss: Any, ctrl: AxisController, lag: int = 0,
                 freq_hz: np.ndarray | None = None, meas_delay: float = 0.0) -> LoopAnalysis:
    """Margins, bandwidths and step metrics of ``ctrl`` around ``plant_ss`` (a discrete
    python-control system at the controller's loop step, rate per controller output).

    ``lag`` loops of delay on the target path (see :func:`replay_controller`);
    ``meas_delay`` (0-1 loop) on the measured rate the controller reads (``(1 − τ) + τz⁻¹``,
    :attr:`ClosedLoopFit.measurement_delay_loops`).
    """
    dt = float(plant_ss.dt)
    cfb, ct = controller_tf(ctrl, dt)
    if lag:
        ct = ct * control.tf([1.0], [1.0] + [0.0] * lag, dt)
    tau, num, den = measurement_filter(meas_delay)
    if tau:
        cfb = cfb * control.tf(num, den, dt)
    p = control.ss(plant_ss)
    cfb_ss, ct_ss = control.ss(cfb), control.ss(ct)
    loop_tf = cfb_ss * p
    # at the mixer the attitude loop closes too: rate target = angle_p * -(integral of rate)
    integ = control.tf([dt, 0.0], [1.0, -1.0], dt)
    mixer_loop = (cfb + ct * ctrl.angle_p * integ) * control.tf(plant_ss)
    closed = control.feedback(p, cfb_ss) * ct_ss
    sens = control.feedback(control.ss([], [], [], [[1.0]], dt), loop_tf)
    f = np.geomspace(0.1, 0.45 / dt, 400) if freq_hz is None else np.asarray(freq_hz)
    w = 2 * np.pi * f
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # python-control's method fall-backs
        gm, pm, wcp = loop_margins(loop_tf, dt)
        zs = np.exp(1j * w * dt)
        t_resp = frequency_response(closed, zs)
        s_resp = frequency_response(sens, zs)
        l_resp = frequency_response(loop_tf, zs)
        m_resp = frequency_response(mixer_loop, zs)
        mgm, mpm, mwc = loop_margins(mixer_loop, dt)
    mag, ph, bw, dbw, phase_delay = closed_figures(f, t_resp, s_resp)
    rise, over = step_metrics(closed, dt)
    return LoopAnalysis(
        gain_margin_db=margin_db(gm),
        phase_margin_deg=float(pm), crossover_hz=float(wcp / (2 * np.pi)),
        bandwidth_hz=bw, peak_db=float(np.max(mag)), disturbance_bandwidth_hz=dbw,
        phase_delay_s=phase_delay, rise_time_s=rise, overshoot_percent=over,
        freq_hz=f, magnitude_db=mag, phase_deg=ph,
        loop_response=np.asarray(l_resp).ravel(), closed_response=np.asarray(t_resp).ravel(),
        mixer_loop_response=np.asarray(m_resp).ravel(),
        mixer_margins={"gain_db": margin_db(mgm), "phase_deg": float(mpm),
                       "crossover_hz": float(mwc / (2 * np.pi))},
    )


def step_metrics(closed: Any, dt: float, horizon_s: float = 2.0) -> tuple[float, float]:
    """10-90 % rise time (s) and overshoot (%) of the closed loop's unit step."""
    t = np.arange(0.0, horizon_s, dt)
    y = np.asarray(control.step_response(closed, T=t).outputs, dtype=float).ravel()
    return step_figures(t, y)
