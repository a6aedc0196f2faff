"""Plants for the loop tests: the simulator's own plant of one axis as the twin's linear system."""

from __future__ import annotations

import numpy as np

from mavsid.loop.plant import LinearPlant
from mavsid.synthetic.plant import PlantParams, discretise, lowpass2p_coefficients


def true_plant(p: PlantParams, axis: int, dt: float) -> LinearPlant:
    """The simulator's plant of one uncoupled axis as a LinearPlant: delay line, rate and
    motor lag (exact ZOH), then the gyro biquad, whose output the controller reads."""
    disc = discretise(p, dt)
    keep = [axis, 3 + axis] if disc.n_state == 6 else [axis]
    phi = disc.phi[np.ix_(keep, keep)]
    g_prev = disc.gamma_prev[keep, axis]
    g_now = disc.gamma_now[keep, axis]
    n_p, d = len(keep), disc.delay_steps
    # state: plant (n_p), biquad d1 d2, past inputs u[k-1] .. u[k-d-1]
    n = n_p + 2 + d + 1
    a = np.zeros((n, n))
    b = np.zeros(n)
    bq, aq = lowpass2p_coefficients(p.gyro_filter_hz, 1.0 / dt)
    hist = n_p + 2
    a[:n_p, :n_p] = phi
    a[:n_p, hist + d] += g_prev  # u[k-d-1]
    if d == 0:
        b[:n_p] += g_now
    else:
        a[:n_p, hist + d - 1] += g_now  # u[k-d]
    # biquad (direct form II): d0 = rate - a1 d1 - a2 d2; d2' = d1; d1' = d0
    a[n_p, 0], a[n_p, n_p], a[n_p, n_p + 1] = 1.0, -aq[1], -aq[2]
    a[n_p + 1, n_p] = 1.0
    b[hist] = 1.0  # u[k] becomes u[k-1]
    for i in range(1, d + 1):
        a[hist + i, hist + i - 1] = 1.0
    c = np.zeros(n)
    c[0] = bq[0]
    c[n_p] = bq[1] - bq[0] * aq[1]
    c[n_p + 1] = bq[2] - bq[0] * aq[2]
    return LinearPlant(a, b, c, dt)


AXES_INDEX = {"roll": 0, "pitch": 1, "yaw": 2}


def fly_rate_loop(truth: dict, axis: str, gains: dict[str, float], seed: int = 31
                  ) -> dict[str, float]:
    """Fly, in the simulator (its own controller, not the twin's), a fixture's vehicle
    (``*.truth.json``: plant, frame, loop rate and ``ATC_*`` parameters) with ``gains``
    (ArduPilot names) and its attitude loop on ``axis`` off, through a mixer chirp on
    ``axis``: the margins of the rate loop the flight measures (controller output per
    mixer input, against the injection)."""
    import dataclasses
    import re

    from mavsid.frequency import frf
    from mavsid.loop.analysis import frd_margins
    from mavsid.synthetic import ControllerParams, Scenario, SysIdSettings, fly

    axes = ("roll", "pitch", "yaw")
    short = {"RLL": "rll", "PIT": "pit", "YAW": "yaw"}
    fields = {f.name for f in dataclasses.fields(ControllerParams)}
    kw: dict[str, float] = {"loop_hz": float(truth["loop_hz"])}
    for name, value in {**truth["controller"], **gains}.items():
        m = re.fullmatch(r"ATC_(RAT|ANG)_(RLL|PIT|YAW)_(\w+)", name)
        if m is None:
            continue
        key = (f"ang_{short[m[2]]}_p" if m[1] == "ANG"
               else f"{short[m[2]]}_{m[3].lower()}")
        if key in fields:
            kw[key] = float(value)
    kw[f"ang_{('rll', 'pit', 'yaw')[axes.index(axis)]}_p"] = 0.0
    plant = {k: (tuple(tuple(r) for r in v) if k == "coupling" else
                 tuple(v) if isinstance(v, list) else v) for k, v in truth["plant"].items()}
    run = SysIdSettings(axis=10 + axes.index(axis), magnitude=0.05, f_start_hz=0.5,
                        f_stop_hz=30.0, t_rec=30.0)
    fl = fly(Scenario(sysid=(run,), seed=seed, controller=ControllerParams(**kw),
                      plant=PlantParams(**plant), frame=truth["frame"], axis=axis))
    rows = fl.run_index == 0
    j = axes.index(axis)
    u, c = fl.u[rows, j], fl.pid_out[rows, j]
    measured = frf([u], [-c], fl.dt, reference=[u - c], f_min_hz=0.5, f_max_hz=30.0)
    return frd_margins(measured)
