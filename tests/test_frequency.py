"""Frequency responses and the loop analysis on simulated flights with a known plant."""

from __future__ import annotations

import json
from pathlib import Path

import control
import numpy as np
import pytest
from test_loop import true_plant

from mavsid import loop, pipeline
from mavsid.cli import main
from mavsid.frequency import fit_tf, frf
from mavsid.synthetic.plant import PlantParams

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "sysid_roll.bin"


@pytest.fixture(scope="module")
def roll_fit():
    return pipeline.fit([str(FIXTURE)], pipeline.PipelineConfig(axes=("roll",)))


def test_frf_matches_the_true_plant_within_its_error(roll_fit) -> None:
    f = roll_fit.axes["roll"]
    segs = [*f.train, *f.held_out]
    r = frf([s.inputs[:, 0] for s in segs], [s.states[:, s.state_names.index("p")]
                                              for s in segs], segs[0].dt)
    p = PlantParams()
    s = 2j * np.pi * r.freq_hz
    truth = (p.effectiveness[0] / (s + p.damping[0]) / (1 + p.motor_tau_s * s)
             * np.exp(-p.delay_s * s))
    band = r.coherent & (r.freq_hz > 1.0) & (r.freq_hz < 8.0)
    assert band.sum() > 20
    rel = np.abs(np.abs(r.response[band]) / np.abs(truth[band]) - 1)
    # the gyro filter (20 Hz) is in the measured response, not in this truth: below 8 Hz
    # it changes |H| by < 3 %; allow that beside 3 σ of the random error
    assert np.all(rel < 3 * r.error[band] + 0.03)
    # a first-order + delay fit absorbs the motor lag and gyro filter into its pole and
    # delay (its gain comes out near 145, not the plant's 180); only its bounds are checked
    tf = fit_tf(r)
    assert 0 <= tf.delay_s <= 0.1 and tf.gain > 0


def test_margins_and_bandwidth_match_the_true_plant(roll_fit) -> None:
    ctrl = loop.controller_from_params(roll_fit.flights[0].params, "roll")
    model = loop.analyse_model(roll_fit.axes["roll"].model, "roll", ctrl, samples=10)
    tp = true_plant(PlantParams(), 0, 1.0 / ctrl.loop_hz)
    ss = control.ss(tp.a, tp.b.reshape(-1, 1), tp.c.reshape(1, -1), 0.0, tp.dt)
    truth = loop.analyse_loop(ss, ctrl)
    # measured: phase margin 75.1 against 72.0 deg, bandwidth 12.21 against 12.37 Hz
    assert model.phase_margin_deg == pytest.approx(truth.phase_margin_deg, abs=4.0)
    assert model.bandwidth_hz == pytest.approx(truth.bandwidth_hz, rel=0.05)
    assert model.crossover_hz == pytest.approx(truth.crossover_hz, rel=0.05)


def test_suggested_gains_give_the_promised_margin_on_the_true_plant(roll_fit) -> None:
    ctrl = loop.controller_from_params(roll_fit.flights[0].params, "roll")
    plant = loop.plant_statespace(roll_fit.axes["roll"].model, "roll", 1.0 / ctrl.loop_hz)
    got = loop.suggest_gains(plant, ctrl, 55.0)
    assert got is not None
    gains, predicted = got
    assert predicted.phase_margin_deg == pytest.approx(55.0, abs=0.5)
    k = gains["ATC_RAT_RLL_P"] / ctrl.gains.p
    new = loop._scaled(ctrl, k)
    tp = true_plant(PlantParams(), 0, 1.0 / ctrl.loop_hz)
    ss = control.ss(tp.a, tp.b.reshape(-1, 1), tp.c.reshape(1, -1), 0.0, tp.dt)
    assert loop.analyse_loop(ss, new).phase_margin_deg == pytest.approx(55.0, abs=5.0)


def test_tune_json(capsys) -> None:
    assert main(["tune", str(FIXTURE), "--axis", "roll", "--json", "--target-pm", "50"]) == 0
    d = json.loads(capsys.readouterr().out)["axes"]["roll"]
    assert set(d["margins"]) == {"gain_db", "phase_deg", "crossover_hz"}
    assert {"bandwidth_hz", "peak_db", "frequency_hz", "magnitude_db", "phase_deg"} <= set(
        d["closed_loop"])
    assert isinstance(d["suggested"], dict) and isinstance(d["advice"], list)
    assert main(["tune", str(FIXTURE), "--target-pm", "95"]) == 1
