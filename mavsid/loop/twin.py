"""The closed-loop twin: the rebuilt rate controller around the identified plant, driven by
the log's rate target, compared with the flight.

The twin (:func:`closed_loop_fit`) drives the controller with the logged rate target
(``RATE.RDes/PDes/YDes``, ``PIDR.Tar``, PX4 ``vehicle_rates_setpoint``, :func:`twin_signals`)
plus any SYSTEMID mixer injection (``SIDD.Targ`` during ``SID_AXIS`` 10–12), closes the loop
through the identified plant at the controller's loop rate (:func:`simulate_closed_loop`; the
plant re-discretised there when the log is slower), and compares the simulated rate and
controller output with the measured ones on the held-out blocks. Its baseline
(:func:`baseline_fit`) is "the rate follows its target after the best delay" (the delay
chosen on the training blocks). :func:`replay_controller` checks the controller alone.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from mavsid.autopilot.ardupilot import injects_into_mixer, sid_axis
from mavsid.errors import ConfigError, MavsidError
from mavsid.loop.controllers import (
    AXES,
    AXIS_RATE,
    PID,
    AxisController,
    RatePID,
    autopilot_of,
    controller_from_params,
    measurement_filter,
)
from mavsid.loop.injection import InjectionInTarget, injection_in_target
from mavsid.loop.plant import LinearPlant, plant_from_model

if TYPE_CHECKING:
    from mavsid.data import FlightData, RawLog, Segment
    from mavsid.validation import Model

__all__ = [
    "BASELINE_MAX_DELAY_S",
    "LAGS",
    "LOGGED_TERMS",
    "MEAS_DELAYS",
    "MEAS_DELAY_TOL",
    "PID_MESSAGES",
    "SETTLE_S",
    "TERMS",
    "WARMUP_S",
    "ClosedLoopFit",
    "LocatedBlock",
    "TwinBlock",
    "TwinSignals",
    "baseline_candidates",
    "baseline_fit",
    "closed_loop_fit",
    "controller_timing",
    "lagged",
    "locate_blocks",
    "replay_controller",
    "replay_terms",
    "simulate_closed_loop",
    "twin_messages",
    "twin_signals",
]

def simulate_closed_loop(
    plant: LinearPlant,
    pid: PID,
    target: np.ndarray,
    *,
    injection: np.ndarray | None = None,
    others: np.ndarray | None = None,
    substeps: int = 1,
    rate: np.ndarray | None = None,
    u: np.ndarray | None = None,
    warmup: int = 0,
    limit: float = 1.0,
    lag: int = 0,
    meas_delay: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Close the loop: the controller follows ``target`` through ``plant``.

    Each sample holds the target, injection and other inputs for ``substeps``
    plant/controller steps (the plant's ``dt`` times ``substeps`` is the data step).

    Parameters
    ----------
    plant : LinearPlant
    pid : RatePID or PX4RatePID
        A fresh controller at the plant's step.
    target : (n,) rate target (rad/s).
    injection : (n,), optional
        Added to the controller output before the ``±limit`` clip (SYSTEMID mixer axes).
    others : (n, len(plant.other_inputs)), optional
        The model's other inputs, as measured.
    rate, u : (n,), optional
        Measured rate and mixer input. They set the initial conditions: the first
        ``warmup`` samples drive the controller with the measured rate and the plant with the
        measured input (no feedback); the integrator is then corrected so that the
        controller's output matches the measured one, and the plant's state moved (least
        norm) to the measured rate. Without warm-up, the plant starts in equilibrium at the
        first sample and the integrator is preset from the first measured output.
    warmup : int
        Samples used for the initial conditions; the returned arrays start after them.
    limit : float
        The mixer input's clip.
    lag : int
        Controller steps between a target (and injection) sample and the step that first
        uses it (ArduCopter: 1, see :func:`replay_controller`).
    meas_delay : float
        Controller steps (0-1) by which the rate the controller reads lags the plant's output
        (linear interpolation with the step before; see :func:`replay_controller`).

    Returns
    -------
    rate, u : numpy.ndarray, shape (n - warmup,)
        Simulated rate and mixer input (controller output plus injection, clipped), sampled
        at the first sub-step of each sample.

    Notes
    -----
    An ArduPilot controller without slew limiter runs, after its first step, as one linear
    system in blocks of steps (:func:`_linear_run`, four times faster on the SITL flight)
    unless its integrator's or the output's clip would bind; then step by step. The same
    numbers to rounding (``tests/test_loop_twin.py``).

    Examples
    --------
    >>> from mavsid.loop.controllers import RateGains
    >>> plant = LinearPlant(np.array([[1.0]]), np.array([0.01]), np.array([1.0]), 0.01)
    >>> pid = RatePID(RateGains(2.0, 0.0, 0.0, 0.0, 0.5, 0.0, 0.0, 0.0), 0.01)
    >>> y, u = simulate_closed_loop(plant, pid, np.ones(2000))
    >>> round(float(y[-1]), 4)   # an integrator under P control reaches its target
    1.0
    """
    n = len(target)
    inj = np.zeros(n) if injection is None else np.asarray(injection, dtype=float)
    w = np.zeros((n, 0)) if others is None else np.asarray(others, dtype=float).reshape(n, -1)
    a, b, c, e = plant.a, plant.b, plant.c, plant.e
    off = plant.u_offset
    tg = lagged(np.repeat(np.asarray(target, dtype=float), substeps), lag)
    ij = lagged(np.repeat(inj, substeps), lag)
    ew = (np.repeat(w @ e.T, substeps, axis=0) if w.shape[1]
          else np.zeros((n * substeps, a.shape[0])))
    ym = np.zeros(n) if rate is None else np.asarray(rate, dtype=float)
    um = np.zeros(n) if u is None else np.asarray(u, dtype=float)
    warmup = min(max(0, warmup), n - 1) if rate is not None and u is not None else 0
    x = plant.initial_state(float(ym[0]), float(um[0]), w[0] if n and w.shape[1] else None)
    if u is not None and n:
        pid.preset(float(tg[0]), float(ym[0]), float(um[0] - ij[0]))
    j = 0
    tau = measurement_filter(meas_delay)[0]
    y_prev = float(ym[0]) if n else 0.0
    if warmup:
        outs = np.empty(warmup)
        for k in range(warmup):
            for s in range(substeps):
                y_now = float(ym[k])
                out = pid.update(float(tg[j]), (1.0 - tau) * y_now + tau * y_prev)
                y_prev = y_now
                if s == 0:
                    outs[k] = out
                x = a @ x + b * (float(um[k]) + off) + ew[j]
                j += 1
        last = max(1, min(10, warmup // 2))
        resid = (um[:warmup] - ij[: warmup * substeps: substeps]) - outs
        pid.adjust_integrator(float(np.mean(resid[-last:])))
        cc = c.reshape(1, -1)
        x = x + (np.linalg.pinv(cc) @ np.array([ym[warmup] - float((cc @ x)[0])])).ravel()
    steps = (n - warmup) * substeps
    y_all, u_all = np.empty(steps), np.empty(steps)
    tgl, ijl = tg.tolist(), ij.tolist()  # Python floats: no numpy scalar per step
    rows = list(ew) if w.shape[1] else None  # no other inputs: nothing to add

    def stepped(i0: int, i1: int, x: np.ndarray, y_prev: float, sat: int
                ) -> tuple[np.ndarray, float, int]:
        """Steps ``i0`` to ``i1`` (from the first after the warm-up), one at a time; ``sat``
        the sign of the clip in the step before (the clip stands for the motors' limit: the
        controller's integrator is held by it, :meth:`RatePID.update`)."""
        for jj in range(j + i0, j + i1):
            y = float(c @ x)
            seen = (1.0 - tau) * y + tau * y_prev
            y_prev = y
            raw = pid.update(tgl[jj], seen, sat) + ijl[jj]
            uk = min(max(raw, -limit), limit)
            sat = int(raw > limit) - int(raw < -limit)
            y_all[jj - j], u_all[jj - j] = y, uk
            x = a @ x + b * (uk + off)
            if rows is not None:
                x = x + rows[jj]
        return x, y_prev, sat

    if (isinstance(pid, RatePID) and pid.g.smax <= 0 and pid.g.pd_max <= 0
            and pid.g.d_ff == 0 and steps > 4 * _BLOCK):
        # the first step one at a time (a fresh controller starts from its inputs), the rest
        # as one linear system unless the integrator's or the output's clip binds
        x, y_prev, sat = stepped(0, 1, x, y_prev, 0)
        if sat or not _linear_steps(pid, plant, x, y_prev, tau, limit, tg[j + 1:j + steps],
                                    ij[j + 1:j + steps],
                                    ew[j + 1:j + steps] if rows is not None else None,
                                    y_all[1:], u_all[1:]):
            stepped(1, steps, x, y_prev, sat)
    else:
        stepped(0, steps, x, y_prev, 0)
    return y_all[::substeps].copy(), u_all[::substeps].copy()


#: steps per block of :func:`_linear_run`
_BLOCK = 32


def _linear_run(f: np.ndarray, g: np.ndarray, h: np.ndarray, k: np.ndarray, s0: np.ndarray,
                w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Outputs ``h·s[i] + k·w[i]`` of ``s[i+1] = f·s[i] + g·w[i]`` from ``s0`` over the rows of
    ``w``, and the last state, in blocks of :data:`_BLOCK` steps: one small product per block
    carries the state (``fᵐ``), the steps inside every block at once (``h·fⁱ`` and the
    inputs' ``h·fⁱ⁻¹⁻ˡ·g``). The same numbers as stepping, to rounding."""
    m = _BLOCK
    n, ns, nw = w.shape[0], f.shape[0], w.shape[1]
    nb = -(-n // m)
    wb = np.zeros((nb * m, nw))
    wb[:n] = w
    wb = wb.reshape(nb, m, nw)
    powers = [np.eye(ns)]
    for _ in range(m):
        powers.append(f @ powers[-1])
    hf = np.stack([h @ powers[i] for i in range(m)])  # (m, ny, ns)
    hfg = np.stack([h @ powers[i] @ g for i in range(m)])  # (m, ny, nw)
    kern = np.zeros((m, m, h.shape[0], nw))
    for i in range(1, m):
        kern[i, :i] = hfg[i - 1::-1]  # l < i: h·f^(i-1-l)·g
    gam = np.stack([powers[m - 1 - i] @ g for i in range(m)])  # (m, ns, nw)
    flat = wb.reshape(nb, m * nw)
    v = flat @ gam.transpose(1, 0, 2).reshape(ns, m * nw).T  # (nb, ns)
    fm = powers[m]
    states = np.empty((nb + 1, ns))
    states[0] = s0
    for i in range(nb):
        states[i + 1] = fm @ states[i] + v[i]
    ny = h.shape[0]
    y = (states[:nb] @ hf.reshape(m * ny, ns).T
         + flat @ kern.transpose(1, 3, 0, 2).reshape(m * nw, m * ny)).reshape(nb, m, ny)
    y = (y + wb @ k.T).reshape(nb * m, ny)[:n]
    last = states[n // m]
    for row in w[(n // m) * m:]:
        last = f @ last + g @ row
    return y, last


def _linear_steps(pid: RatePID, plant: LinearPlant, x: np.ndarray, y_prev: float, tau: float,
                  limit: float, tg: np.ndarray, ij: np.ndarray, ew: np.ndarray | None,
                  y_out: np.ndarray, u_out: np.ndarray) -> bool:
    """:func:`simulate_closed_loop`'s steps after the first (the controller past its reset,
    no slew limiter) as one linear system, :func:`_linear_run`: the rates and outputs into
    ``y_out`` and ``u_out`` and the controller's state updated, or False (nothing changed)
    when the integrator's ``±IMAX`` or the output's ``±limit`` would bind on some step."""
    gn, dt = pid.g, pid.dt
    a, b, c = plant.a, plant.b, plant.c
    n = a.shape[0]
    # state: x (n), y_prev, target filter T, error E, derivative D, integrator I
    ns = n + 5
    iy, it, ie, i_d, ii = n, n + 1, n + 2, n + 3, n + 4
    ext = ew is not None
    nw = 3 + (n if ext else 0)  # inputs: target, injection, 1 (offset), other inputs
    # each quantity of a step as a row over [state, inputs]
    z = np.zeros(ns + nw)
    y = z.copy()
    y[:n] = c
    seen = (1.0 - tau) * y
    seen[iy] += tau
    t_new = z.copy()
    t_new[it] = 1.0 - pid.a_t
    t_new[ns] = pid.a_t
    e_new = -pid.a_e * seen
    e_new[ie] += 1.0 - pid.a_e
    e_new += pid.a_e * t_new
    d_new = pid.a_d / dt * e_new
    d_new[ie] -= pid.a_d / dt
    d_new[i_d] += 1.0 - pid.a_d
    i_new = gn.i * dt * e_new
    i_new[ii] += 1.0
    out = gn.p * e_new + i_new + gn.d * d_new + gn.ff * t_new
    u = out.copy()
    u[ns + 1] += 1.0
    fg = np.zeros((ns, ns + nw))
    fg[:n] = np.outer(b, u)
    fg[:n, :n] += a
    fg[:n, ns + 2] += b * plant.u_offset
    if ext:
        fg[:n, ns + 3:] += np.eye(n)
    fg[iy], fg[it], fg[ie], fg[i_d], fg[ii] = y, t_new, e_new, d_new, i_new
    hk = np.stack([y, u, i_new])
    s0 = np.r_[x, y_prev, pid.target, pid.error, pid.deriv, pid.integ]
    steps = tg.size
    w = np.empty((steps, nw))
    w[:, 0], w[:, 1], w[:, 2] = tg, ij, 1.0
    if ext:
        w[:, 3:] = ew
    with np.errstate(all="ignore"):
        outs, last = _linear_run(fg[:, :ns], fg[:, ns:], hk[:, :ns], hk[:, ns:], s0, w)
    if not (np.all(np.isfinite(outs)) and np.all(np.abs(outs[:, 2]) <= gn.imax)
            and np.all(np.abs(outs[:, 1]) <= limit)):
        return False
    y_out[:steps], u_out[:steps] = outs[:, 0], outs[:, 1]
    pid.target, pid.error, pid.deriv, pid.integ = (float(v) for v in last[it:])
    return True


def lagged(x: np.ndarray, lag: int) -> np.ndarray:
    """``x`` delayed by ``lag`` samples, the first value held before it."""
    if lag <= 0 or not x.size:
        return x
    return np.concatenate([np.full(min(lag, x.size), x[0]), x[: max(0, x.size - lag)]])


def replay_controller(
    ctrl: AxisController, dt: float, target: np.ndarray, rate: np.ndarray, output: np.ndarray,
    injection: np.ndarray | None = None, lag: int = 0, substeps: int = 1,
    meas_delay: float = 0.0,
) -> np.ndarray:
    """The rebuilt controller fed the *measured* rate: its output (mixer input minus the
    injection) sample by sample, to compare with the logged one.

    This checks the controller alone (its parameters, and ``lag``: ArduCopter runs the rate
    controller at the start of each loop on the target and injection its attitude controller
    and SYSTEMID set in the loop before, and logs them when they are set: 1 loop).
    ``substeps`` controller steps per sample (``lag`` counts them) take the measured rate
    and the target interpolated between the samples.
    ``meas_delay`` (controller steps, 0-1): the rate the controller reads lags the logged one
    by that fraction of a step (linear interpolation with the step before): a log may stamp
    the gyro sample a little apart from the one the controller used (the SITL flight's
    replay: 96.2 % at 0, 97.7 % at 0.2 of its 400 Hz loop).

    Examples
    --------
    >>> c = controller_from_params({}, "roll")
    >>> t = np.sin(np.arange(200) * 0.05); y = 0.9 * t
    >>> u = replay_controller(c, 0.0025, t, y, np.zeros(200))
    >>> u.shape
    (200,)
    """
    terms = replay_terms(ctrl, dt, target, rate, output, injection, lag, substeps, meas_delay)
    return np.asarray(terms.sum(axis=1))


def _between(x: np.ndarray, substeps: int) -> np.ndarray:
    """``x`` at ``substeps`` controller steps per sample, interpolated linearly between the
    samples (the last held): a log slower than the loop holds no rate between its samples,
    and a held one would give the D term a derivative of steps (on the 100 Hz real chirp of a
    400 Hz loop the D term then matches the logged one to 55 % instead of 83 %).

    >>> _between(np.array([0.0, 1.0]), 4).tolist()
    [0.0, 0.25, 0.5, 0.75, 1.0, 1.0, 1.0, 1.0]
    """
    if substeps <= 1 or x.size < 2:
        return np.repeat(x, substeps)
    return np.interp(np.arange(x.size * substeps) / substeps, np.arange(x.size), x)


#: the columns of :func:`replay_terms`
TERMS = ("P", "I", "D", "FF", "DFF")


def replay_terms(
    ctrl: AxisController, dt: float, target: np.ndarray, rate: np.ndarray, output: np.ndarray,
    injection: np.ndarray | None = None, lag: int = 0, substeps: int = 1,
    meas_delay: float = 0.0,
) -> np.ndarray:
    """:func:`replay_controller`'s output as its terms, shape ``(n, 5)``: :data:`TERMS`
    (PX4: ``K·P·err``, the integrator, ``−K·D·ṁ``, ``FF·target`` and 0).

    Examples
    --------
    >>> c = controller_from_params({"ATC_RAT_RLL_I": 0.0}, "roll")
    >>> t = np.sin(np.arange(200) * 0.05)
    >>> terms = replay_terms(c, 0.0025, t, 0.9 * t, np.full(200, 0.3))
    >>> float(np.max(np.abs(terms[:, 1])))   # I = 0: no integrator, whatever the output
    0.0
    """
    n = len(target)
    inj = np.zeros(n) if injection is None else np.asarray(injection, dtype=float)
    tg = lagged(_between(np.asarray(target, dtype=float), substeps), lag)
    ij = lagged(np.repeat(inj, substeps), lag)[::substeps]
    ym = _between(np.asarray(rate, dtype=float), substeps)
    tau = measurement_filter(meas_delay)[0]
    if tau > 0 and ym.size:
        ym = (1.0 - tau) * ym + tau * np.concatenate([ym[:1], ym[:-1]])
    pid = ctrl.new_pid(dt / substeps)
    pid.preset(float(tg[0]), float(rate[0]), float(output[0] - ij[0]))
    whole = pid.run_terms(tg, ym) if isinstance(pid, RatePID) else None  # (no feedback here)
    if whole is None:
        rows = []
        for a, b in zip(tg, ym, strict=True):
            pid.update(float(a), float(b))
            rows.append(pid.terms)
        whole = np.array(rows, dtype=float).reshape(-1, len(TERMS))
    out = whole[::substeps].copy()
    if isinstance(pid, RatePID) and pid.g.i == 0:
        return out  # (no integrator to take an offset: AC_PID has none with I = 0)
    # the first output has no derivative term and an unfiltered error: the integrator takes
    # the offset that leaves, measured once the controller's filters have settled
    settle = min(round(SETTLE_S / dt), n // 2)
    early = slice(settle, min(settle + 20, n))
    out[:, 1] += float(np.mean((output - ij - out.sum(axis=1))[early]))
    return out


#: time (s) after which the controller's own filters (FLTE 2.5 Hz: 64 ms) have settled
SETTLE_S = 0.25


@dataclass(frozen=True)
class TwinSignals:
    """What the twin needs from a log besides states and inputs, on a flight's time grid.

    Attributes
    ----------
    target : Mapping[str, numpy.ndarray]
        Rate target (rad/s) per axis the log has one for.
    injection : Mapping[str, numpy.ndarray]
        SYSTEMID mixer injection (normalised) per axis; zeros outside the runs.
    sources : Mapping[str, str]
        Where each came from (``"RATE.RDes"``...).
    rate_injection : Mapping[str, numpy.ndarray]
        SYSTEMID rate-axis injection (rad/s, ``SID_AXIS`` 7-9), zeros outside the runs; part
        of ``target`` (added to the logged target when that did not carry it).
    terms : Mapping[str, Mapping[str, numpy.ndarray]]
        The rate controller's terms as logged, per axis and term (``P``, ``I``, ``D``,
        ``FF``, ``DFF``: ArduPilot's ``PIDR/PIDP/PIDY``), NaN where they are not logged;
        their sources in ``sources`` as ``term_<axis>_<term>``.
    injection_in_target : Mapping[str, InjectionInTarget]
        Per axis with a rate injection: whether the logged target carried it, and why.
    """

    target: Mapping[str, np.ndarray]
    injection: Mapping[str, np.ndarray]
    sources: Mapping[str, str] = field(default_factory=dict)
    rate_injection: Mapping[str, np.ndarray] = field(default_factory=dict)
    terms: Mapping[str, Mapping[str, np.ndarray]] = field(default_factory=dict)
    injection_in_target: Mapping[str, InjectionInTarget] = field(default_factory=dict)


def _on_grid(t: np.ndarray, v: np.ndarray, grid: np.ndarray, hold: bool) -> np.ndarray:
    """Samples put on ``grid``: interpolated or held; NaN outside their span."""
    order = np.argsort(t, kind="stable")
    t, v = t[order], v[order]
    keep = np.concatenate([[True], np.diff(t) > 0]) if t.size else np.zeros(0, bool)
    t, v = t[keep], v[keep]
    if t.size < 2:
        return np.full(grid.shape, np.nan)
    if hold:
        i = np.searchsorted(t, grid + 1e-9, side="right") - 1
        out = v[np.clip(i, 0, None)].astype(float)
    else:
        out = np.interp(grid, t, v)
    out[(grid < t[0] - 1e-9) | (grid > t[-1] + 1e-9)] = np.nan
    return out


#: ArduPilot's rate-controller records per axis, and the terms read from them
PID_MESSAGES = {"roll": "PIDR", "pitch": "PIDP", "yaw": "PIDY"}
LOGGED_TERMS = ("P", "I", "D", "FF", "DFF")


def twin_messages() -> set[str]:
    """The messages :func:`twin_signals` reads (rate targets, the controller's logged
    terms), of every format: a caller reading the log anyway reads them in the same pass."""
    from mavsid.autopilot.presets import TARGET_CHANNELS

    return {ch.message for chans in TARGET_CHANNELS.values() for ch in chans} | set(
        PID_MESSAGES.values())


def twin_signals(flight: FlightData, raw: RawLog | None = None) -> TwinSignals:
    """Rate targets and SYSTEMID mixer injections of ``flight``, from its log (re-read for
    the few messages needed unless ``raw`` is given).

    Targets come from the first of :data:`mavsid.autopilot.presets.TARGET_CHANNELS` the log has;
    mixer injections from the flight's ``sysid_injection`` (alignment's ``SIDD.Targ``, 0 where
    not logged) during the SYSTEMID runs on ``SID_AXIS`` 10-12, rate injections during those
    on 7-9: added to the target when the log's target did not carry them
    (:func:`mavsid.loop.injection.injection_in_target`, by the data, else the firmware).
    """
    from mavsid.autopilot.presets import INJECTION_CHANNEL, TARGET_CHANNELS
    from mavsid.channels import first_of

    if raw is None:
        from mavsid.readers import read_log

        path = flight.source.path
        if not path or not os.path.exists(path):
            return TwinSignals({}, {})
        wanted = twin_messages()
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            raw = read_log(path, messages=sorted(wanted))
    grid = flight.time_s
    targets: dict[str, np.ndarray] = {}
    sources: dict[str, str] = {}
    for axis in AXES:
        got = first_of(raw, TARGET_CHANNELS[AXIS_RATE[axis]], f"target {axis}")
        if got is not None:
            ch, t, v = got
            scale = flight.scales.get(ch.message, 1.0)
            targets[axis] = _on_grid(t, v * scale, grid, hold=True)
            sources[f"target_{axis}"] = f"{ch.message}.{ch.field}"
    injection: dict[str, np.ndarray] = {}
    runs = [r for r in flight.sysid_runs if sid_axis(r.sid_axis)[1] in ("rate", "mixer")
            and sid_axis(r.sid_axis)[0] in AXES]
    rate_injection: dict[str, np.ndarray] = {}
    rate_spans: dict[str, list[tuple[int, int]]] = {}
    if runs and flight.sysid_injection is not None:  # (alignment's: held, NaN unlogged)
        held = np.nan_to_num(np.asarray(flight.sysid_injection, dtype=float))
        src = f"{INJECTION_CHANNEL.message}.{INJECTION_CHANNEL.field}"
        for r in runs:
            axis = sid_axis(r.sid_axis)[0]
            inside = (grid >= r.start_s - 1e-9) & (grid <= r.stop_s + 1e-9)
            if injects_into_mixer(r.sid_axis):
                inj = injection.setdefault(axis, np.zeros(grid.shape))
                inj[inside] = held[inside]
                sources[f"injection_{axis}"] = src
            elif inside.any():  # rate axes: the waveform (deg/s) is added to the target
                inj = rate_injection.setdefault(axis, np.zeros(grid.shape))
                inj[inside] = np.radians(held[inside])
                sources[f"rate_injection_{axis}"] = src
                idx = np.flatnonzero(inside)
                rate_spans.setdefault(axis, []).append((int(idx[0]), int(idx[-1]) + 1))
    in_target: dict[str, InjectionInTarget] = {}
    for axis, inj in rate_injection.items():
        if axis not in targets:
            continue
        f_stop = min((float(r.f_stop_hz) for r in runs if r.f_stop_hz
                      and sid_axis(r.sid_axis) == (axis, "rate")), default=None)
        said = injection_in_target(targets[axis], inj, rate_spans[axis], flight.dt,
                                   flight.firmware, f_stop)
        in_target[axis] = said
        if not said.included:
            targets[axis] = targets[axis] + inj
    return TwinSignals(targets, injection, sources, rate_injection, _logged_terms(
        raw, grid, sources), in_target)


def _logged_terms(raw: RawLog, grid: np.ndarray, sources: dict[str, str]
                  ) -> dict[str, dict[str, np.ndarray]]:
    """The rate controller's logged terms per axis on ``grid`` (held; ``sources`` gains
    their names)."""
    from mavsid.autopilot.presets import Channel
    from mavsid.channels import evaluate

    out: dict[str, dict[str, np.ndarray]] = {}
    for axis, msg in PID_MESSAGES.items():
        if msg not in raw.messages or not len(raw.messages[msg]):
            continue
        for term in LOGGED_TERMS:
            try:
                t, v = evaluate(raw, Channel(msg, term, "1"), f"{axis} {term} term")
            except MavsidError:
                continue
            if t.size >= 2:
                out.setdefault(axis, {})[term] = _on_grid(t, v, grid, hold=True)
                sources[f"term_{axis}_{term}"] = f"{msg}.{term}"
    return out


@dataclass(frozen=True)
class TwinBlock:
    """One held-out block: measured and simulated rate and controller output."""

    time_s: np.ndarray
    target: np.ndarray
    rate: np.ndarray
    rate_twin: np.ndarray
    output: np.ndarray
    output_twin: np.ndarray
    baseline: np.ndarray


@dataclass(frozen=True)
class ClosedLoopFit:
    """How well the closed-loop twin reproduces the held-out blocks of one axis.

    Attributes
    ----------
    fit_percent : float
        Fit % of the simulated rate against the measured one (NRMSE, as elsewhere).
    output_fit_percent : float
        Fit % of the simulated controller output (mixer input minus any SYSTEMID
        injection, which both share) against the measured one.
    baseline_percent : float
        Fit % of "the rate follows its target after ``baseline_delay_s``".
    baseline_delay_s : float
        The baseline's delay, chosen on the training blocks.
    open_loop_percent : float
        The open-loop free-run fit % of the same blocks, for comparison.
    defaults_used : tuple of str
        Controller parameters the log lacks, taken at documented defaults.
    controller : Mapping
        :meth:`AxisController.to_dict`.
    substeps : int
        Controller steps per data sample (the plant re-discretised when > 1).
    lag_loops : int
        Controller loops between a logged target (and injection) and its use.
    measurement_delay_loops : float
        Part of a loop by which the rate the controller reads lags the logged rate (chosen,
        as ``lag_loops``, by the controller replay on the training blocks).
    target_source, injection_source : str
    rate_injection : InjectionInTarget or None
        With a SYSTEMID rate injection: whether the logged target carried it (else the twin's
        target has it added), with the coefficient that said so.
    blocks : tuple of TwinBlock
    """

    fit_percent: float
    output_fit_percent: float
    baseline_percent: float
    baseline_delay_s: float
    defaults_used: tuple[str, ...] = ()
    open_loop_percent: float = float("nan")
    controller: Mapping[str, Any] = field(default_factory=dict)
    substeps: int = 1
    lag_loops: int = 0
    measurement_delay_loops: float = 0.0
    target_source: str = ""
    injection_source: str = ""
    rate_injection: InjectionInTarget | None = None
    blocks: tuple[TwinBlock, ...] = field(default=(), repr=False)

    def to_dict(self) -> dict[str, Any]:
        """JSON form (without the per-block arrays)."""
        return {
            "fit_percent": self.fit_percent,
            "output_fit_percent": self.output_fit_percent,
            "baseline_percent": self.baseline_percent,
            "baseline_delay_s": self.baseline_delay_s,
            "open_loop_percent": self.open_loop_percent,
            "defaults_used": list(self.defaults_used),
            "controller": dict(self.controller),
            "substeps": self.substeps,
            "lag_loops": self.lag_loops,
            "measurement_delay_loops": self.measurement_delay_loops,
            "target_source": self.target_source,
            "injection_source": self.injection_source,
            "rate_injection": self.rate_injection.to_dict() if self.rate_injection else None,
            "blocks": [[float(b.time_s[0]), float(b.time_s[-1])] for b in self.blocks],
        }


def _pooled_fit(y: Sequence[np.ndarray], yhat: Sequence[np.ndarray]) -> float:
    from mavsid.validation import fit_percent

    if not y:
        return float("nan")
    return float(fit_percent(np.concatenate(y), np.concatenate(yhat)))


#: longest delay (s) the baseline tries
BASELINE_MAX_DELAY_S = 0.5


def baseline_fit(
    train: Sequence[tuple[np.ndarray, np.ndarray]],
    held_out: Sequence[tuple[np.ndarray, np.ndarray]],
    dt: float,
    max_delay_s: float = BASELINE_MAX_DELAY_S,
) -> tuple[float, float, list[np.ndarray]]:
    """"The rate follows its target after the best delay": the delay (whole samples up to
    ``max_delay_s``) that fits the training blocks best, and the fit % it gives on the
    held-out ones.

    Parameters
    ----------
    train, held_out : sequence of (target, rate) pairs, each (n_i,)
    dt : float

    Returns
    -------
    fit_percent, delay_s, predictions (one per held-out block, NaN before the delay)

    Examples
    --------
    >>> t = np.sin(np.arange(400) * 0.05)
    >>> y = np.concatenate([[0.0] * 3, t[:-3]])       # the target, 3 samples late
    >>> fit, delay, _ = baseline_fit([(t, y)], [(t, y)], dt=0.01)
    >>> round(fit, 6), delay
    (100.0, 0.03)
    """
    from mavsid.validation import fit_sums

    def shifted(x: np.ndarray, d: int) -> np.ndarray:
        out = np.full(x.shape, np.nan)  # (a block shorter than the delay: all unknown)
        if d < len(x):
            out[d:] = x[: len(x) - d]
        return out

    longest = max((len(t) for t, _ in (*train, *held_out)), default=0)
    max_d = max(0, min(round(max_delay_s / dt), longest - 2))
    pool = train or held_out

    def score(d: int) -> float:
        err = norm = 0.0
        for t, y in pool:
            e, n = fit_sums(y, shifted(t, d))
            err, norm = err + float(e[0]), norm + float(n[0])
        return -err / norm if norm > 0 else -np.inf

    best, best_d = -np.inf, 0
    for d in baseline_candidates(pool, max_d):
        sc = score(d)
        if sc > best:
            best, best_d = sc, d
    preds = [shifted(t, best_d) for t, _ in held_out]
    fit = _pooled_fit([y for _, y in held_out], preds)
    return fit, best_d * dt, preds


def baseline_candidates(pool: Sequence[tuple[np.ndarray, np.ndarray]], max_d: int
                         ) -> range | list[int]:
    """The delays :func:`baseline_fit` scores exactly, in increasing order: every one up to
    ``max_d`` when a block holds a non-finite sample, else those whose score, from running
    sums and one dot product per delay and block (rounding differs from the exact sums),
    is within a rounding margin of the best: the exact scores of these choose the same
    delay as those of all (the rest are far below)."""
    blocks = [(np.asarray(t, dtype=float), np.asarray(y, dtype=float)) for t, y in pool]
    if not all(np.all(np.isfinite(t)) and np.all(np.isfinite(y)) for t, y in blocks):
        return range(max_d + 1)
    err = np.zeros(max_d + 1)
    norm = np.zeros(max_d + 1)
    scale = 0.0
    for t, y in blocks:
        n = y.size
        k = min(max_d, n - 1) + 1  # delays with samples left
        if n == 0 or k <= 0:
            continue
        s1 = np.cumsum(y[::-1])[::-1][:k]  # sum over i >= d of y[i]
        s2 = np.cumsum((y * y)[::-1])[::-1][:k]
        t2 = np.cumsum(t * t)[::-1][:k]  # sum over i < n - d of t[i]
        cross = np.array([y[d:] @ t[:n - d] for d in range(k)])
        err[:k] += s2 - 2.0 * cross + t2
        norm[:k] += s2 - s1 * s1 / (n - np.arange(k))
        scale += float(y @ y + t @ t)
    with np.errstate(divide="ignore", invalid="ignore"):
        approx = np.where(norm > 0, -err / norm, -np.inf)
    if not np.any(np.isfinite(approx)):
        return range(max_d + 1)
    best = float(np.max(approx[np.isfinite(approx)]))
    margin = 1e-7 * scale / float(np.min(norm[norm > 0])) + 1e-9 * abs(best)
    return [int(d) for d in np.flatnonzero(~(approx < best - margin))]


@dataclass(frozen=True)
class LocatedBlock:
    """A segment located on its flight, with up to ``warm`` samples before it."""

    seg: Segment
    ctrl: AxisController
    warm: int
    target: np.ndarray
    injection: np.ndarray
    rate: np.ndarray
    u: np.ndarray
    inputs: np.ndarray
    input_names: tuple[str, ...]
    terms: Mapping[str, np.ndarray] = field(default_factory=dict)


#: measured samples before a block (s) used for the twin's initial conditions
WARMUP_S = 0.5


#: target/injection lags (controller loops) tried
LAGS = (0, 1, 2)
#: measurement delays (controller loops) tried when the log is at the loop rate: the rate
#: the controller read may lag the logged one by part of a loop (the gyro sample stamped
#: apart from the one used); the shortest within MEAS_DELAY_TOL (fit %) of the best replay
MEAS_DELAYS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5)
MEAS_DELAY_TOL = 0.1
#: ArduCopter uses a target one loop after logging it (see :func:`replay_controller`)
_DEFAULT_LAG = {"ardupilot": 1, "px4": 0}


def closed_loop_fit(
    model: Model,
    axis: str,
    train: Sequence[Segment],
    held_out: Sequence[Segment],
    flights: Sequence[FlightData],
    signals: Sequence[TwinSignals] | None = None,
    open_loop_percent: float = float("nan"),
    timing: tuple[int, float] | None = None,
) -> ClosedLoopFit:
    """Run the closed-loop twin of ``axis`` on the held-out blocks.

    The controller is rebuilt from the parameters of the flight each block comes from; it
    follows the logged rate target (plus the SYSTEMID mixer injection) through the plant
    model at the controller's loop rate, from the measured rate and controller output at
    the block's start. The lag between a logged target and its use (0-2 loops) is the one
    whose controller replay (:func:`replay_controller`) matches the training blocks best
    (without training blocks: ArduPilot's 1 loop, PX4's 0); then, for a log at the loop
    rate, the measurement delay (:data:`MEAS_DELAYS`) the same way (:func:`controller_timing`;
    ``timing`` gives both instead).

    Raises
    ------
    ConfigError
        No rate target in the logs, a model the twin cannot run, or no block on a flight's
        grid.
    """
    from mavsid.validation import fit_percent

    sigs = list(signals) if signals is not None else [twin_signals(fd) for fd in flights]
    tr = locate_blocks(train, axis, flights, sigs)
    val = locate_blocks(held_out, axis, flights, sigs)
    if not val:
        from mavsid.autopilot.presets import TARGET_CHANNELS

        names = [f"{c.message}.{c.field}" for c in TARGET_CHANNELS[AXIS_RATE[axis]]]
        raise ConfigError(f"{axis}: no rate target logged for the held-out blocks "
                          f"({', '.join(names[:-1])} or {names[-1]})")
    ctrl = val[0].ctrl
    dt = val[0].seg.dt
    substeps = max(1, round(ctrl.loop_hz * dt))
    lag, meas_delay = timing if timing is not None else controller_timing(tr, val)
    try:
        plant = plant_from_model(model, axis, dt / substeps)
    except ConfigError:
        if substeps == 1:
            raise
        substeps = 1
        plant = plant_from_model(model, axis, dt)
    ys, yts, us, uts, blocks = [], [], [], [], []
    for b in val:
        y_sim, u_sim = simulate_closed_loop(
            plant, b.ctrl.new_pid(dt / substeps), b.target, injection=b.injection,
            others=_others(b, plant), substeps=substeps, rate=b.rate, u=b.u, warmup=b.warm,
            lag=lag, meas_delay=meas_delay,
        )
        w = b.warm
        inj = lagged(np.repeat(b.injection, substeps), lag)[::substeps][w:]
        ys.append(b.rate[w:])
        yts.append(y_sim)
        us.append(b.u[w:] - inj)
        uts.append(u_sim - inj)
        blocks.append((b.seg.time_s, b.target[w:], b.rate[w:], y_sim, b.u[w:], u_sim))
    b_fit, b_delay, b_pred = baseline_fit([(b.target[b.warm:], b.rate[b.warm:]) for b in tr],
                                          [(b.target[b.warm:], b.rate[b.warm:]) for b in val],
                                          dt)
    twin_blocks = tuple(
        TwinBlock(t, tg, y, ysim, u, usim, bp)
        for (t, tg, y, ysim, u, usim), bp in zip(blocks, b_pred, strict=True)
    )
    k = flights.index(next(fd for fd in flights if fd.index_of(val[0].seg) is not None))
    return ClosedLoopFit(
        fit_percent=_pooled_fit(ys, yts),
        output_fit_percent=float(fit_percent(np.concatenate(us), np.concatenate(uts))),
        baseline_percent=b_fit,
        baseline_delay_s=b_delay,
        defaults_used=ctrl.defaults_used,
        open_loop_percent=open_loop_percent,
        controller=ctrl.to_dict(),
        substeps=substeps,
        lag_loops=lag,
        measurement_delay_loops=meas_delay,
        target_source=sigs[k].sources.get(f"target_{axis}", ""),
        injection_source=sigs[k].sources.get(f"injection_{axis}", ""),
        rate_injection=sigs[k].injection_in_target.get(axis),
        blocks=twin_blocks,
    )


def controller_timing(train: Sequence[LocatedBlock], held_out: Sequence[LocatedBlock]
                      ) -> tuple[int, float]:
    """The lag (controller loops, :data:`LAGS`) between a logged target and its use, and the
    measurement delay (:data:`MEAS_DELAYS`, for a log at the loop rate), whose controller
    replay (:func:`replay_controller`) fits the training blocks best; without training
    blocks ArduPilot's 1 loop, PX4's 0, and no delay."""
    first = (train or held_out)[0]
    dt = first.seg.dt
    substeps = max(1, round(first.ctrl.loop_hz * dt))
    lag = _DEFAULT_LAG[first.ctrl.autopilot]
    meas_delay = 0.0

    def replayed(cand: int, tau: float) -> float:
        """The controller replay's fit % on the training blocks."""
        out = [(b.u - lagged(np.repeat(b.injection, substeps), cand)[::substeps],
                replay_controller(b.ctrl, dt, b.target, b.rate, b.u, b.injection, cand,
                                  substeps, tau))
               for b in train]
        out = [(m[b.warm:], r[b.warm:]) for b, (m, r) in zip(train, out, strict=True)]
        return _pooled_fit([o[0] for o in out], [o[1] for o in out])

    if train:
        scores = [replayed(cand, 0.0) for cand in LAGS]
        if np.any(np.isfinite(scores)):
            lag = LAGS[int(np.nanargmax(scores))]
            if substeps == 1:  # (a sample held over several steps has no sub-step timing)
                by_tau = [(scores[LAGS.index(lag)], 0.0)]
                by_tau += [(replayed(lag, tau), tau) for tau in MEAS_DELAYS[1:]]
                best = max(sc for sc, _ in by_tau if np.isfinite(sc))
                meas_delay = min(tau for sc, tau in by_tau
                                 if np.isfinite(sc) and sc >= best - MEAS_DELAY_TOL)
    return lag, meas_delay


def _others(b: LocatedBlock, plant: LinearPlant) -> np.ndarray | None:
    """The model's other inputs, as measured over the block and its warm-up."""
    if not plant.other_inputs:
        return None
    return np.column_stack([b.inputs[:, b.input_names.index(n)] for n in plant.other_inputs])


def locate_blocks(segments: Sequence[Segment], axis: str, flights: Sequence[FlightData],
            sigs: Sequence[TwinSignals]) -> list[LocatedBlock]:
    """The segments found on a flight with a rate target, with their twin signals and the
    measured samples before them (within the flight's contiguous block)."""
    rate, u_name = AXIS_RATE[axis], f"u_{axis}"
    out = []
    for seg in segments:
        for k, fd in enumerate(flights):
            i = fd.index_of(seg)
            if i is None or axis not in sigs[k].target or u_name not in fd.input_names:
                continue
            first = max((int(a) for a, _ in fd.blocks if a <= i), default=0)
            warm = min(i - first, round(WARMUP_S / fd.dt))
            sl = slice(i - warm, i + len(seg))
            tgt = sigs[k].target[axis][sl]
            ok = np.isfinite(tgt)
            if not ok[warm:].all():
                break
            if not ok[:warm].all():  # no target before the block: no warm-up
                warm = 0
                sl = slice(i, i + len(seg))
                tgt = tgt[-len(seg):]
            inj_full = sigs[k].injection.get(axis)
            inj = inj_full[sl] if inj_full is not None else np.zeros(len(tgt))
            ctrl = controller_from_params(fd.params, axis, autopilot_of(fd))
            out.append(LocatedBlock(
                seg, ctrl, warm, tgt, inj, fd.states[sl, fd.state_names.index(rate)],
                fd.inputs[sl, fd.input_names.index(u_name)], fd.inputs[sl], fd.input_names,
                {name: v[sl] for name, v in sigs[k].terms.get(axis, {}).items()},
            ))
            break
    return out
