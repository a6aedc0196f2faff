"""The rate controllers rebuilt from log parameters (the simulator's own are compared with
them in test_synthetic_controller.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mavsid.errors import ConfigError
from mavsid.loop.controllers import (
    PX4RateGains,
    PX4RatePID,
    RateGains,
    RatePID,
    controller_from_params,
)


def test_controller_from_params_lists_the_defaults_it_used() -> None:
    full = {f"ATC_RAT_PIT_{k}": v for k, v in zip(
        ("P", "I", "D", "FF", "IMAX", "FLTT", "FLTE", "FLTD", "SMAX"),
        (0.2, 0.15, 0.004, 0.01, 0.4, 15.0, 5.0, 25.0, 10.0), strict=True)}
    full.update(SCHED_LOOP_RATE=800.0, INS_GYRO_FILTER=40.0)
    c = controller_from_params(full, "pitch")
    assert c.defaults_used == ()
    assert (c.gains.p, c.gains.flte, c.gains.fltd, c.gains.smax, c.loop_hz) == (
        0.2, 5.0, 25.0, 10.0, 800.0)
    c = controller_from_params({"ATC_RAT_YAW_P": 0.3}, "yaw")
    assert "ATC_RAT_YAW_I" in c.defaults_used and "SCHED_LOOP_RATE" in c.defaults_used
    assert "ATC_RAT_YAW_P" not in c.defaults_used
    # 3.5-4.0: one FILT on the error
    c = controller_from_params({"ATC_RAT_RLL_P": 0.1, "ATC_RAT_RLL_FILT": 30.0}, "roll")
    assert (c.naming, c.gains.flte, c.gains.fltt, c.gains.fltd) == ("ATC_RAT_FILT", 30.0, 0, 0)
    # 3.x: centidegree gains and a ±4500 output
    c = controller_from_params({"RATE_PIT_P": 0.15, "RATE_PIT_IMAX": 4500.0}, "pitch")
    assert c.naming == "RATE" and c.gains.imax == pytest.approx(1.0)
    assert c.gains.p == pytest.approx(0.15 * 18000 / np.pi / 4500, rel=1e-6)
    # PX4
    c = controller_from_params({"MC_PITCHRATE_P": 0.1, "MC_PITCHRATE_K": 2.0,
                                     "MC_PR_INT_LIM": 0.2, "IMU_GYRO_RATEMAX": 1000.0}, "pitch")
    assert c.autopilot == "px4" and c.loop_hz == 1000.0
    assert isinstance(c.gains, PX4RateGains) and c.gains.int_lim == 0.2
    assert "MC_PITCHRATE_I" in c.defaults_used and "MC_PITCHRATE_K" not in c.defaults_used
    with pytest.raises(ConfigError, match="ATC_RAT_RLL_P"):
        controller_from_params({"ATC_RAT_RLL_P": -1.0}, "roll")


def test_rate_pid_run_equals_stepping_and_steps_when_imax_binds() -> None:
    """The replay's vectorised controller (filters as recursions, the integrator a running
    sum): update() step by step to rounding; None (step instead) when IMAX would bind or the
    slew limiter is on."""
    rng = np.random.default_rng(4)
    n = 3000
    tg = np.cumsum(rng.standard_normal(n)) * 0.01
    ym = 0.9 * tg + 0.01 * rng.standard_normal(n)
    gains = RateGains(0.135, 0.135, 0.0036, 0.05, 0.5, 20.0, 20.0, 2.5)
    for g, whole in ((gains, True), (replace(gains, imax=0.01), False),
                     (replace(gains, smax=50.0), False)):
        run, step = RatePID(g, 0.0025), RatePID(g, 0.0025)
        run.preset(tg[0], ym[0], 0.02)
        step.preset(tg[0], ym[0], 0.02)
        got = run.run(tg, ym)
        want = np.array([step.update(a, b) for a, b in zip(tg, ym, strict=True)])
        if whole:
            assert got is not None
            np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-14)
        else:
            assert got is None


def test_px4_pid_terms() -> None:
    # K multiplies P, I and D; the derivative acts on the measurement, not the target; the
    # integration shrinks as (1 - (err / 400 deg/s)^2) and stops at MC_*R_INT_LIM
    k, p, i, d, ff, dt = 0.5, 0.2, 1.0, 0.01, 0.1, 0.01
    pid = PX4RatePID(PX4RateGains(p, i, d, ff, k=k, int_lim=0.05, dgyro_hz=0.0), dt)

    def factor(err: float) -> float:
        return 1 - (err / np.radians(400)) ** 2

    assert pid.update(1.0, 0.0) == pytest.approx(k * p + ff)
    i1 = factor(1.0) * k * i * 1.0 * dt
    assert pid.update(2.0, 0.0) == pytest.approx(k * p * 2 + i1 + ff * 2)  # no derivative kick
    i2 = i1 + factor(2.0) * k * i * 2.0 * dt
    assert pid.update(2.0, 0.1) == pytest.approx(k * p * 1.9 + i2 - k * d * 10.0 + ff * 2)
    for _ in range(100):
        pid.update(2.0, 0.0)
    assert pid.integ == pytest.approx(0.05)


def test_smax_limits_the_pd_slew() -> None:
    g = RateGains(p=0.2, i=0.0, d=0.01, ff=0.0, imax=0.5, fltt=0.0, fltd=0.0, flte=0.0)
    t = np.sign(np.sin(np.arange(800) * 2 * np.pi * 8 / 400))  # an 8 Hz square wave target
    pid = RatePID(g, 0.0025)
    free = np.array([pid.update(x, 0.0) for x in t])
    pid = RatePID(replace(g, smax=5.0), 0.0025)
    limited = np.array([pid.update(x, 0.0) for x in t])
    assert np.std(limited) < 0.8 * np.std(free)
    pid = RatePID(replace(g, smax=1e6), 0.0025)  # a limit never reached changes nothing
    assert np.allclose([pid.update(x, 0.0) for x in t], free)


@pytest.mark.parametrize("value", [1e9, float("inf"), 0.0, 5.0])
def test_a_damaged_loop_rate_is_not_simulated(value: float) -> None:
    """A loop rate no flight controller runs (a damaged SCHED_LOOP_RATE or IMU_GYRO_RATEMAX)
    set how many controller steps the twin simulates per sample: 1e9 Hz asked numpy for
    78 GiB. The default is used instead, and said among the defaults."""
    ap = controller_from_params({"ATC_RAT_RLL_P": 0.1, "SCHED_LOOP_RATE": value}, "roll")
    assert ap.loop_hz == 400.0 and "SCHED_LOOP_RATE" in ap.defaults_used
    px4 = controller_from_params({"MC_ROLLRATE_P": 0.1, "IMU_GYRO_RATEMAX": value}, "roll")
    assert 100.0 <= px4.loop_hz <= 8000.0 and "IMU_GYRO_RATEMAX" in px4.defaults_used
    assert controller_from_params({"SCHED_LOOP_RATE": 1000.0}, "roll").loop_hz == 1000.0
