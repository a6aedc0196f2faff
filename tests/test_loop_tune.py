"""Gain suggestion and ``mavsid tune``'s report."""

from __future__ import annotations

from dataclasses import replace

import pytest
from loop_plants import true_plant
from loop_reference import analyse_loop

from mavsid.cli_format import format_tune
from mavsid.loop.controllers import controller_from_params, scale_of, scaled
from mavsid.loop.tune import LOOP_MISMATCH_DB, suggest_gains, tune
from mavsid.synthetic.plant import PlantParams


def test_suggest_gains_takes_a_linear_plant_or_a_python_control_system() -> None:
    import control

    ctrl = controller_from_params({}, "roll")
    dt = 1.0 / ctrl.loop_hz
    tp = true_plant(PlantParams(), 0, dt)
    ss = control.ss(tp.a, tp.b.reshape(-1, 1), tp.c.reshape(1, -1), 0.0, dt)
    got = suggest_gains(tp, ctrl, 45.0, 1, 0.3)
    assert got is not None
    assert got[0] == suggest_gains(ss, ctrl, 45.0, 1, 0.3)[0]  # type: ignore[index]
    # the promised margin, by python-control, of the scaled controller around the plant
    truth = analyse_loop(ss, scaled(ctrl, scale_of(got[0], ctrl)), 1,
                              meas_delay=0.3)
    assert truth.phase_margin_deg == pytest.approx(45.0, abs=0.05)
    # (the scale read back from the suggested P: the parameters keep fewer digits)
    assert got[1].phase_margin_deg == pytest.approx(truth.phase_margin_deg, abs=1e-3)


def test_a_damaged_gain_stops_only_its_axis_in_tune() -> None:
    """A log whose ATC_RAT_RLL_P is negative (damaged): ``mavsid tune`` stopped with "parameter
    ATC_RAT_RLL_P = -1 must be >= 0", naming no file and analysing no axis. Now that axis
    says why it was not analysed, naming the log (the others are analysed as before)."""
    from pathlib import Path

    from mavsid import pipeline

    path = Path(__file__).resolve().parents[1] / "fixtures" / "sysid_roll.bin"
    res = pipeline.fit([str(path)], pipeline.PipelineConfig(axes=("roll",)))
    fd = res.flights[0]
    bad = replace(res, flights=(replace(fd, params={**fd.params, "ATC_RAT_RLL_P": -1.0}),
                                *res.flights[1:]))
    out = tune(bad)
    assert out["roll"] == {"error": f"{path}: parameter ATC_RAT_RLL_P = -1 must be >= 0"}
    assert "error" not in tune(res)["roll"]


@pytest.mark.slow
@pytest.mark.parametrize("p_gain", [1e30, 0.135 * 8])
def test_logged_gains_that_are_not_the_flights_are_said_and_not_scaled(p_gain: float) -> None:
    """The SYSTEMID fixture (flown on P 0.135) analysed with a logged ATC_RAT_RLL_P that is
    not the one flown (damaged: 1e30; changed: 8x): ``tune`` printed "phase margin inf deg",
    "crossover nan Hz" and "prediction within 614.6 dB" as figures, and would have scaled
    the wrong gains. Now the loop measured at the mixer against the one predicted from the
    logged gains says so, no gains are suggested, and figures that do not exist print as
    ``none``. With the gains flown: no warning, gains suggested."""
    from pathlib import Path

    from mavsid import pipeline

    path = Path(__file__).resolve().parents[1] / "fixtures" / "sysid_roll.bin"
    res = pipeline.fit([str(path)], pipeline.PipelineConfig(axes=("roll",)))
    fd = res.flights[0]
    bad = replace(res, flights=(replace(fd, params={**fd.params, "ATC_RAT_RLL_P": p_gain}),
                                *res.flights[1:]))
    entry = tune(bad, samples=5)["roll"]
    assert entry["loop_frf_vs_predicted"]["median_db"] > LOOP_MISMATCH_DB
    assert "do not describe this flight" in entry["gains_mismatch"]
    assert "ATC_RAT_RLL_P" in entry["gains_mismatch"]
    assert entry["suggested"] == {}
    text = format_tune({"roll": entry})
    assert "warning: the loop predicted from the logged gains" in text
    assert "nan" not in text and "inf" not in text.replace("info", "")
    good = tune(res, samples=5)["roll"]
    assert "gains_mismatch" not in good
    assert good["loop_frf_vs_predicted"]["median_db"] < 1.0
    assert good["suggested"] and "warning" not in format_tune({"roll": good})
