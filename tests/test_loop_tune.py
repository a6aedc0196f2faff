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


_SITL: dict[str, dict] = {}


def _sitl_report() -> dict:
    import warnings

    from helpers import shared_path

    from mavsid import pipeline

    if not _SITL:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = pipeline.fit([str(shared_path("sitl", "flightA_mixer.BIN"))])
        _SITL.update(tune(res, 50.0, samples=10))
    return _SITL


@pytest.mark.slow
def test_the_sitl_flights_yaw_is_capped_and_says_so() -> None:
    """The SITL flight's yaw loop (logged P 0.3, I 0.02, phase margin 102 deg) wants ×4
    for 50 deg: ``tune`` printed ``ATC_RAT_YAW_P 1.214`` with no current value, ratio nor
    warning. Now the step is capped at ×2 and says so, with the current values, the ratio
    and the next flight; the capped loop meets every limit printed beside it."""
    yaw = _sitl_report()["yaw"]
    rows = {g["name"]: g for g in yaw["gains"]}
    assert set(rows) == {"ATC_RAT_YAW_P", "ATC_RAT_YAW_I"}  # D is 0: nothing to change
    assert rows["ATC_RAT_YAW_P"]["current"] == pytest.approx(0.3)
    assert rows["ATC_RAT_YAW_I"]["current"] == pytest.approx(0.02)
    for g in rows.values():
        assert g["capped"] and g["ratio"] == pytest.approx(2.0, rel=1e-3)
        assert g["suggested"] == pytest.approx(2.0 * g["current"], rel=1e-3)
    assert yaw["wanted_ratio"] > 2.0 and "tune again" in yaw["next_flight"]
    assert all(r["ok"] for r in yaw["limits"])
    assert yaw["suggested_loop_check"]["phase_margin_deg"] >= 50.0
    assert yaw["twin_step"]["agree"] and yaw["twin_step"]["max_difference"] < 0.05
    text = format_tune({"yaw": yaw})
    assert text.startswith("yaw: verdict good; suggested gains (capped")
    assert "ATC_RAT_YAW_P  0.3      0.6        ×2.00 (capped)" in text


@pytest.mark.slow
def test_the_sitl_flights_roll_is_refused_in_one_line_naming_the_limits() -> None:
    # roll crosses over at 15 Hz, the chirp stopped at 20 Hz: above half the trusted band
    rep = _sitl_report()
    for axis in ("roll", "pitch"):
        e = rep[axis]
        assert e["gains"] == [] and e["suggested"] == {}
        assert "crossover" in e["no_gains_reason"] and "\n" not in e["no_gains_reason"]
        crossover = next(r for r in e["limits"] if r["name"] == "crossover")
        assert not crossover["ok"] and crossover["suggested"] > 10.0
        assert "SID_F_STOP_HZ" in e["next_flight"]


def _stop_hz(texts: list[str]) -> set[int]:
    """Every ``SID_F_STOP_HZ N`` the texts name."""
    import re

    return {int(m) for t in texts for m in re.findall(r"SID_F_STOP_HZ (\d+)", t)}


@pytest.mark.slow
def test_the_sitl_flights_next_flight_and_advice_name_one_chirp_top() -> None:
    """The SITL flight's roll and pitch: the next flight said "with SID_F_STOP_HZ 31, so the
    band covers twice the crossover" and the advice beside it "the loop needs up to 70 Hz: set
    SID_F_STOP_HZ 70" (three times the closed-loop bandwidth). Now both name the top the
    crossover limit needs for the current and the refused gains' crossovers, one number."""
    from mavsid.loop.limits import Limits

    rep = _sitl_report()
    for axis in ("roll", "pitch"):
        e = rep[axis]
        named = _stop_hz([e["next_flight"]]) | _stop_hz(e["advice"])
        assert named == {int(e["chirp_top_hz"])}, (e["next_flight"], e["advice"])
        crossovers = (e["current_loop"]["crossover_hz"],
                      e["suggested_loop_check"]["crossover_hz"])
        assert max(crossovers) <= Limits().band_fraction * e["chirp_top_hz"]
        assert e["chirp_top_hz"] == 31.0  # (15.4 Hz crossover, twice it rounded up)


def test_the_advices_chirp_top_is_the_one_computed_for_the_next_flight() -> None:
    """The SYSTEMID fixture's roll (crossover 5 Hz, chirp to 15 Hz): the advice names the
    chirp top :func:`mavsid.loop.tune.chirp_top_hz` gives for its crossovers, the number a
    next flight to measure the loop would name (the limits' rule, at least 20 Hz)."""
    from pathlib import Path

    from mavsid import pipeline
    from mavsid.loop.limits import Limits
    from mavsid.loop.tune import chirp_top_hz

    path = Path(__file__).resolve().parents[1] / "fixtures" / "sysid_roll.bin"
    res = pipeline.fit([str(path)], pipeline.PipelineConfig(axes=("roll",)))
    e = tune(res, samples=5)["roll"]
    crossovers = [e["current_loop"]["crossover_hz"]]
    if "suggested_loop_check" in e:
        crossovers.append(e["suggested_loop_check"]["crossover_hz"])
    rate = 1.0 / res.axes["roll"].validation.dt
    assert e["chirp_top_hz"] == chirp_top_hz(crossovers, rate, Limits())
    assert _stop_hz(e["advice"]) == {int(e["chirp_top_hz"])}
    assert _stop_hz([e.get("next_flight", "")]) <= {int(e["chirp_top_hz"])}


@pytest.mark.slow
def test_params_out_loads_with_pymavlink_and_holds_only_the_changes(tmp_path, capsys) -> None:
    from helpers import shared_path
    from pymavlink import mavparm

    from mavsid.cli import main

    log = shared_path("sitl", "flightA_mixer.BIN")
    out = tmp_path / "yaw.parm"
    assert main(["tune", str(log), "--axis", "yaw", "--params-out", str(out), "-q"]) == 0
    loaded = mavparm.MAVParmDict()
    assert loaded.load(str(out))
    assert dict(loaded) == pytest.approx({"ATC_RAT_YAW_P": 0.6, "ATC_RAT_YAW_I": 0.04})
    text = out.read_text()
    assert text.startswith(f"# mavsid tune of {log}") and "yaw: phase margin 102" in text
    capsys.readouterr()
    # nothing suggested (roll): refused in one line, no file
    refused = tmp_path / "roll.parm"
    assert main(["tune", str(log), "--axis", "roll", "--params-out", str(refused), "-q"]) == 1
    errors = [ln for ln in capsys.readouterr().err.splitlines() if "error" in ln]
    assert len(errors) == 1 and "no gains suggested" in errors[0] and not refused.exists()


def test_a_px4_parameter_file_is_qgroundcontrols() -> None:
    from mavsid.loop.tune import param_file

    check = {"phase_margin_deg": 40.0, "gain_margin_db": 8.0, "crossover_hz": 12.0}
    entry = {"controller": {"autopilot": "px4"}, "current_loop": check,
             "suggested_loop_check": check, "capped": False,
             "gains": [{"name": "MC_ROLLRATE_P", "current": 0.15, "suggested": 0.135,
                        "ratio": 0.9, "capped": False}]}
    text = param_file({"roll": entry, "yaw": {"gains": [], "no_gains_reason": "x"}},
                      "f.ulg", when="2026-01-01T00:00:00+00:00")
    lines = text.splitlines()
    assert lines[0] == "# Onboard parameters for Vehicle 1"
    assert "# Vehicle-Id Component-Id Name Value Type" in lines
    rows = [ln.split("\t") for ln in lines if not ln.startswith("#")]
    assert rows == [["1", "1", "MC_ROLLRATE_P", "0.135", "9"]]
