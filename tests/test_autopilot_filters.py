"""The configured filters' cut-offs, by each firmware's parameter names."""

from __future__ import annotations

import pytest

from mavsid.autopilot import ardupilot, filter_cutoffs, px4


def test_ardupilot_names_per_axis_and_the_notch_only_when_enabled() -> None:
    params = {"INS_GYRO_FILTER": 40.0, "ATC_RAT_PIT_FLTT": 20.0, "ATC_RAT_PIT_FLTD": 0.0,
              "ATC_RAT_PIT_FLTE": 2.5, "ATC_RAT_RLL_FLTT": 15.0, "INS_HNTCH_FREQ": 80.0}
    assert filter_cutoffs(params, "pitch") == {"INS_GYRO_FILTER": 40.0,
                                               "ATC_RAT_PIT_FLTT": 20.0,
                                               "ATC_RAT_PIT_FLTE": 2.5}
    assert filter_cutoffs({**params, "INS_HNTCH_ENABLE": 1.0}, "roll") == {
        "INS_GYRO_FILTER": 40.0, "ATC_RAT_RLL_FLTT": 15.0, "INS_HNTCH_FREQ": 80.0}
    assert ardupilot.filter_params({}, "yaw")[1:] == [
        ardupilot.rate_prefix("yaw") + s for s in ("FLTT", "FLTD", "FLTE")]


def test_px4_names_the_same_on_every_axis_and_off_left_out() -> None:
    params = {"IMU_GYRO_CUTOFF": 30.0, "IMU_DGYRO_CUTOFF": 0.0, "IMU_GYRO_NF0_FRQ": 95.0,
              "IMU_GYRO_NF_FREQ": float("nan"), "MC_ROLLRATE_P": 0.15}
    for axis in ("roll", "pitch", "yaw"):
        assert filter_cutoffs(params, axis) == {"IMU_GYRO_CUTOFF": 30.0,
                                                "IMU_GYRO_NF0_FRQ": 95.0}
    assert set(px4.filter_params()) >= set(px4.GYRO_FILTER_PARAMS)


@pytest.mark.parametrize("suffix", [".bin", ".ulg"])
def test_a_simulated_flight_marks_its_own_filters(tmp_path, suffix) -> None:
    from mavsid import response
    from mavsid.readers import read_log
    from mavsid.synthetic.run import scenario_from_options, simulate

    path = tmp_path / f"f{suffix}"
    simulate(scenario_from_options(manoeuvre="random", axis="roll", duration_s=20.0, seed=1),
             [path])
    params = read_log(path).params
    gyro = "INS_GYRO_FILTER" if suffix == ".bin" else "IMU_GYRO_CUTOFF"
    got = response.read_response(path, ("roll",)).spectra["roll"]
    assert got and got[0].cutoffs.get(gyro) == pytest.approx(params[gyro])
