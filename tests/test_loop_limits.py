"""The limits a suggested loop must meet (:mod:`mavsid.loop.limits`), against independent
references: python-control's analysis of the same loop (``loop_reference.analyse_loop``), the
sensitivity evaluated point by point in numpy, and the closed-loop twin."""

from __future__ import annotations

import numpy as np
import pytest
from loop_plants import true_plant
from loop_reference import analyse_loop

from mavsid.loop.analysis import controller_polys
from mavsid.loop.controllers import controller_from_params, scaled
from mavsid.loop.limits import Limits, check_loop, limit_rows, twin_step
from mavsid.synthetic.plant import PlantParams


@pytest.fixture(scope="module")
def loop():  # type: ignore[no-untyped-def]
    ctrl = controller_from_params({}, "roll")
    return true_plant(PlantParams(), 0, 1.0 / ctrl.loop_hz), ctrl


@pytest.mark.parametrize("k", [0.5, 1.0, 2.0])
def test_figures_match_python_control_and_numpy(loop, k: float) -> None:  # type: ignore[no-untyped-def]
    import control

    plant, ctrl = loop
    c = scaled(ctrl, k)
    got = check_loop(plant, c)
    ss = control.ss(plant.a, plant.b.reshape(-1, 1), plant.c.reshape(1, -1), 0.0, plant.dt)
    ref = analyse_loop(ss, c)
    assert got.phase_margin_deg == pytest.approx(ref.phase_margin_deg, abs=0.05)
    assert got.crossover_hz == pytest.approx(ref.crossover_hz, rel=1e-3)
    assert got.gain_margin_db == pytest.approx(ref.gain_margin_db, abs=0.05)
    # Ms and the closed-loop peak on a dense grid, without python-control
    dt = plant.dt
    f = np.geomspace(0.01, 0.499 / dt, 20000)
    z = np.exp(2j * np.pi * f * dt)
    (bf, af), ct = controller_polys(c, dt)
    p = np.array([plant.c @ np.linalg.solve(zz * np.eye(plant.a.shape[0]) - plant.a, plant.b)
                  for zz in z])
    lz = p * np.polyval(bf, z) / np.polyval(af, z)
    assert got.sensitivity_peak == pytest.approx(np.max(np.abs(1 / (1 + lz))), rel=2e-3)
    peak = 20 * np.log10(np.max(np.abs(p * np.polyval(ct[0], z) / np.polyval(ct[1], z)
                                        / (1 + lz))))
    assert got.closed_peak_db == pytest.approx(peak, abs=0.1)  # (a 3000-point grid)
    assert got.crossovers == 1 and got.stable


def test_a_loop_past_its_limits_is_flagged(loop) -> None:  # type: ignore[no-untyped-def]
    plant, ctrl = loop
    hot = check_loop(plant, scaled(ctrl, 3.0))
    rows = {r["name"]: r for r in limit_rows(check_loop(plant, ctrl), hot, Limits(), 20.0)}
    assert hot.phase_margin_deg < 50 and not rows["phase margin"]["ok"]
    assert hot.sensitivity_peak > 2.0 and not rows["sensitivity peak Ms"]["ok"]
    # the crossover limit is half the trusted band's top
    assert rows["crossover"]["ok"] == (hot.crossover_hz <= 10.0)
    assert rows["phase margin"]["current"] > rows["phase margin"]["suggested"]


def test_the_twin_flies_the_predicted_step(loop) -> None:  # type: ignore[no-untyped-def]
    plant, ctrl = loop
    for lag, tau in ((0, 0.0), (1, 0.3)):
        c = check_loop(plant, ctrl, lag, tau)
        twin = twin_step(plant, ctrl, lag, tau)
        n = min(twin.size, c.step.size)
        assert n > 300
        assert np.max(np.abs(twin[:n] - c.step[:n])) < 0.01


def test_an_i_less_loop_around_an_integrator_is_stable_and_its_twin_step_agrees() -> None:
    """A real ArduCopter rate loop flies with ``I = 0`` (a Pixhawk 6C quad: P 0.04, D 0.0012)
    around a plant that is an integrator: the controller has no pole at z = 1 (else a mode on
    the unit circle that no gain moves makes every such loop "unstable"), and the twin's step
    (the controller stepped sample by sample) is the linear one even when the plant carries a
    trim bias (which an I-less loop never removes: it is not part of the step)."""
    import dataclasses

    from mavsid.loop.plant import LinearPlant

    params = {"ATC_RAT_RLL_P": 0.04, "ATC_RAT_RLL_I": 0.0, "ATC_RAT_RLL_D": 0.0012,
              "ATC_RAT_RLL_FLTD": 20.0, "ATC_RAT_RLL_FLTT": 20.0, "ATC_RAT_RLL_FLTE": 0.0}
    ctrl = controller_from_params(params, "roll")
    dt = 1.0 / ctrl.loop_hz
    (_, af), _ = controller_polys(ctrl, dt)
    assert not np.any(np.isclose(np.roots(af), 1.0, atol=1e-9))
    # an integrator with a 13-ms motor lag, B = 500 rad/s^2 per unit (x: lagged input, rate)
    alpha = dt / 0.013
    plant = LinearPlant(np.array([[1.0 - alpha, 0.0], [500.0 * dt, 1.0]]),
                        np.array([alpha, 0.0]), np.array([0.0, 1.0]), dt)
    got = check_loop(plant, ctrl, horizon_s=0.5)
    assert got.stable and 0.0 < got.phase_margin_deg < 180.0
    biased = dataclasses.replace(plant, u_offset=-0.005)
    step = twin_step(biased, ctrl, horizon_s=0.5)
    n = min(step.size, got.step.size)
    assert np.max(np.abs(step[:n] - got.step[:n])) < 0.02
