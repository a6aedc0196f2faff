"""The closed-loop response: simulated flights whose loop is known, two flights of one
vehicle, real and public logs, the command line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import REAL_LOGS, shared_logs

from mavsid import response
from mavsid.axes import AXES
from mavsid.synthetic.controller import ArduPilotPID, motor_outputs
from mavsid.synthetic.plant import Lowpass2p, discretise
from mavsid.synthetic.run import scenario_from_options, simulate

CACHE = REAL_LOGS


def true_rate_step(scenario, axis: str, length_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The simulator's own loop, noise-free, stepped: a unit rate-target step on ``axis``
    through its rate PID (P + I + D + feed-forward), the mixer, the delayed plant and the
    gyro filter; the filtered
    gyro (what RATE.R logs) against time."""
    ctl, pl = scenario.controller, scenario.plant
    dt = 1.0 / ctl.loop_hz
    j = ("roll", "pitch", "yaw").index(axis)
    disc = discretise(pl, dt)
    pid = ArduPilotPID(ctl.rate_gains(axis), dt)
    pid.update(0.0, 0.0)  # (past its first call, which starts its filters at their input)
    gyro = Lowpass2p(pl.gyro_filter_hz, ctl.loop_hz, 1)
    n = round(length_s / dt) + 1
    x = np.zeros(disc.n_state)
    n_hist = disc.delay_steps + 2
    u_hist = np.zeros((n_hist, 3))
    out = np.zeros(n)
    size = 0.2  # rad/s: small enough that nothing saturates
    for k in range(n):
        g = float(gyro(np.array([x[j]]))[0])
        u = np.zeros(3)
        u[j] = pid.update(size, g, now_s=(k + 1) * dt) + pid.feedforward
        _, ue = motor_outputs(np.array([pl.hover_throttle]), u[None, :])
        u_hist[k % n_hist] = ue[0]
        x = (disc.phi @ x + disc.gamma_prev @ u_hist[(k + 1) % n_hist]
             + disc.gamma_now @ u_hist[(k + 2) % n_hist])
        out[k] = g / size
    return np.arange(n) * dt, out


@pytest.fixture(scope="module")
def flights(tmp_path_factory) -> dict[int, tuple[Path, object]]:
    """Two simulated flights of one vehicle (random roll sticks), different seeds."""
    out = {}
    folder = tmp_path_factory.mktemp("response")
    for seed in (1, 2):
        sc = scenario_from_options(manoeuvre="random", axis="roll", duration_s=60.0, seed=seed)
        path = folder / f"roll{seed}.bin"
        simulate(sc, [path])
        out[seed] = (path, sc)
    return out


def test_simulated_step_lies_within_its_band(flights) -> None:
    path, sc = flights[1]
    got = response.read_response(path).loop("roll", "rate")
    assert got is not None and got.step is not None, got
    step = got.step
    t, truth = true_rate_step(sc, "roll", float(step.time_s[-1]))
    assert np.allclose(t, step.time_s)
    inside = (truth >= step.lower) & (truth <= step.upper)
    assert inside.mean() >= 0.9, (inside.mean(), np.abs(step.response - truth).max())
    # the metrics of the truth, by python-control's step_info on the true samples
    import control

    info = control.step_info(truth, T=t, SettlingTimeThreshold=0.05, RiseTimeLimits=(0.1, 0.9))
    assert got.rise_s == pytest.approx(info["RiseTime"], rel=0.2, abs=0.005)
    assert got.overshoot_pct == pytest.approx(info["Overshoot"], abs=5.0)
    assert step.windows >= 20 and got.bandwidth_hz is not None
    assert got.band_hz is not None and got.band_hz[1] == 200.0  # (400 Hz RATE)
    assert got.band_hz[0] == pytest.approx(1 / step.window_s, rel=0.01)
    # the pitch and yaw sticks were not moved: said, no curve
    for axis in ("pitch", "yaw"):
        other = response.read_response(path).loop(axis, "rate")
        assert other is not None and other.step is None and "no step response" in other.verdict


def test_true_bandwidth_matches_the_measured_one(flights) -> None:
    import control

    path, sc = flights[1]
    got = response.read_response(path).loop("roll", "rate")
    assert got is not None and got.bandwidth_hz is not None
    # the truth's -3 dB point: its impulse response (from the stepped loop) as an FIR
    t, truth = true_rate_step(sc, "roll", 2.0)
    dt = t[1]
    fir = control.tf(np.diff(truth, prepend=0.0), [1.0] + [0.0] * (truth.size - 1), dt)
    f = np.geomspace(1, 60, 2000)
    mag = np.abs(fir(np.exp(2j * np.pi * f * dt)))
    f3 = f[np.flatnonzero(mag < mag[0] * 10 ** (-3 / 20))[0]]
    assert got.bandwidth_hz == pytest.approx(f3, rel=0.15)


def test_two_flights_of_one_vehicle_agree_within_their_bands(flights) -> None:
    a = response.read_response(flights[1][0]).loop("roll", "rate")
    b = response.read_response(flights[2][0]).loop("roll", "rate")
    assert a is not None and b is not None and a.step is not None and b.step is not None
    half_a = (a.step.upper - a.step.lower) / 2
    half_b = (b.step.upper - b.step.lower) / 2
    agree = np.abs(a.step.response - b.step.response) <= np.hypot(half_a, half_b) * 1.0
    assert agree.mean() >= 0.9


def test_the_attitude_loop_from_the_records_logged_with_the_rate(tmp_path) -> None:
    # ArduCopter 4.5+ logs ANG (attitude target and attitude) with RATE; ATT stays slow
    sc = scenario_from_options(manoeuvre="random", axis="roll", duration_s=60.0, seed=5)
    new, old = tmp_path / "new.bin", tmp_path / "old.bin"
    simulate(sc, [new], layout="copter-4.6")
    simulate(sc, [old], layout="copter-4")
    fast = response.read_response(new, ("roll",)).loop("roll", "attitude")
    slow = response.read_response(old, ("roll",)).loop("roll", "attitude")
    assert fast is not None and slow is not None
    assert (fast.target, fast.actual) == ("ANG.DesRoll", "ANG.Roll")
    assert slow.target == "ATT.DesRoll" and fast.rate_hz > 1.5 * slow.rate_hz
    assert fast.step is not None and fast.band_hz is not None
    assert fast.band_hz[1] == pytest.approx(fast.rate_hz / 2, rel=0.01)


def test_two_real_flights_of_one_vehicle_agree_within_their_bands() -> None:
    """KeitaTK's Pixhawk 6C quad (ArduCopter 4.6.2), flights 64 and 65: the same frame and
    rate-controller parameters, flown in SYSTEMID mode with nothing injected (RATE at
    100 Hz). The two flights' rate-loop steps agree within their bands on every axis; both
    are flagged as not the loop's own step (the targets answer the actual: hover, no
    commands to speak of), and neither reaches its bandwidth in the coherent band."""
    from helpers import real_path

    from mavsid.autopilot import ardupilot
    from mavsid.readers import read_log

    paths = [real_path("keita", f"000000{n}.BIN") for n in (64, 65)]
    raws = [read_log(p, messages=["RATE"]) for p in paths]
    settings = [{k: v for k, v in r.params.items() if ardupilot.is_rate_setting(k)}
                for r in raws]
    assert settings[0] == settings[1] and settings[0]
    assert raws[0].params["FRAME_CLASS"] == raws[1].params["FRAME_CLASS"]
    assert not any(ardupilot.is_rate_setting(c.name) for r in raws for c in r.param_changes)
    found = [response.read_response(p) for p in paths]
    for axis in AXES:
        a, b = (f.loop(axis, "rate") for f in found)
        assert a is not None and b is not None and a.step is not None and b.step is not None
        band = np.hypot((a.step.upper - a.step.lower) / 2, (b.step.upper - b.step.lower) / 2)
        agree = np.abs(a.step.response - b.step.response) <= band
        assert agree.mean() >= 0.9, (axis, agree.mean())
        for r in (a, b):
            assert "not the loop's step response" in r.verdict and r.rise_s is None
            assert r.bandwidth_hz is None


def test_a_slow_log_says_what_it_resolves(tmp_path) -> None:
    sc = scenario_from_options(manoeuvre="random", axis="roll", duration_s=60.0, seed=3,
                               rate_hz=10.0)
    path = tmp_path / "slow.bin"
    simulate(sc, [path])
    got = response.read_response(path).loop("roll", "rate")
    assert got is not None and got.band_hz is not None and got.band_hz[1] == 5.0
    assert "only the slow part" in got.verdict


def test_a_target_driven_by_the_actual_gives_no_step_metrics() -> None:
    # hovering without commands: the target is the outer loop's answer to the actual (here
    # -0.8 times it, at once), and a deconvolution target -> actual starts far below zero
    rng = np.random.default_rng(2)
    t = np.arange(0, 120, 0.01)
    actual = np.convolve(rng.standard_normal(t.size), np.ones(5) / 5, mode="same")
    target = -0.8 * actual + 0.05 * rng.standard_normal(t.size)
    got = response.loop_response("roll", "rate", t, target, actual, rate_hz=100.0)
    assert got.step is not None and got.step.upper[0] < -response.MAX_DIP
    assert got.rise_s is None and got.overshoot_pct is None
    assert "not the loop's step response" in got.verdict
    doc = got.to_dict()
    assert doc["feedback_dominated"] is True
    assert [r["kind"] for r in doc["reasons"]] == ["feedback_dominated"]
    assert doc["reasons"][0]["numbers"]["dip"] < -response.MAX_DIP


def test_a_mixer_injection_is_left_out_of_target_to_rate(tmp_path) -> None:
    """SYSTEMID on the roll mixer (SID_AXIS 10): the rate controller is bypassed and its
    target answers the disturbed rate. Left in, that span gives a step flagged as the target
    answering the actual; left out (as the response does), too little remains, said in one
    line, with no curve."""
    from dataclasses import replace

    from mavsid.align import read_flight
    from mavsid.loop import twin_messages

    sc = scenario_from_options(sid_axes=[10], seed=1)
    path = tmp_path / "mixer.bin"
    simulate(sc, [path])
    flight, raw = read_flight(path, also=sorted(twin_messages()))
    (run,) = flight.sysid_runs
    assert run.sid_axis == 10 and run.injected
    got = response.flight_response(flight, raw, ("roll",)).loop("roll", "rate")
    assert got is not None and got.step is None and got.rise_s is None
    expected = run.stop_s - run.start_s + response.RESPONSE_S["rate"]
    assert got.left_out_s == pytest.approx(expected, abs=2 * flight.dt)
    doc = got.to_dict()
    assert [r["kind"] for r in doc["reasons"]] == ["target_not_exogenous"]
    assert doc["left_out_s"] == got.left_out_s and doc["feedback_dominated"] is False
    assert "no step response" in got.verdict and "SID_AXIS 10" in got.verdict
    assert f"{expected:.0f} s left out" in got.verdict
    # the same flight with its run not typed: the mixer span is the step's, and it is the
    # feedback's (starts far below zero), flagged in the JSON
    untyped = response.flight_response(replace(flight, sysid_runs=()), raw, ("roll",))
    fed = untyped.loop("roll", "rate")
    assert fed is not None and fed.step is not None and fed.left_out_s == 0.0
    assert fed.to_dict()["feedback_dominated"] is True and fed.rise_s is None
    assert fed.step.upper[: fed.step.response.size // 10].min() < -response.MAX_DIP


def test_an_attitude_injection_gives_the_true_rate_step(tmp_path) -> None:
    """SYSTEMID on the roll angle target (SID_AXIS 1): the target is exogenous, nothing is
    left out, and the rate loop's step lies within its band of the simulator's own loop."""
    sc = scenario_from_options(sid_axes=[1], seed=1, t_rec=40.0)
    path = tmp_path / "angle.bin"
    simulate(sc, [path])
    got = response.read_response(path, ("roll",)).loop("roll", "rate")
    assert got is not None and got.step is not None, got
    assert got.left_out_s == 0.0 and got.reasons == () and not got.feedback_dominated
    t, truth = true_rate_step(sc, "roll", float(got.step.time_s[-1]))
    assert np.allclose(t, got.step.time_s)
    inside = (truth >= got.step.lower) & (truth <= got.step.upper)
    assert inside.mean() >= 0.9, (inside.mean(), np.abs(got.step.response - truth).max())
    assert got.delay_s is not None and got.delay_note == ""


@pytest.mark.parametrize(("layout", "included"), [("copter-4", True), ("copter-4.4", False)])
def test_a_rate_injection_gives_the_true_rate_step(tmp_path, layout, included) -> None:
    """SYSTEMID on the roll rate target (SID_AXIS 7), one flight logged as 4.5+ logs it (RATE
    target with the waveform) and as 4.0-4.4 do (without): the log itself says which
    (coefficient near 1 or 0), the waveform is counted once, and the rate loop's step lies
    within its band of the simulator's own loop on both."""
    sc = scenario_from_options(sid_axes=[7], seed=1, t_rec=40.0)
    path = tmp_path / f"rate_{layout}.bin"
    simulate(sc, [path], layout=layout)
    got = response.read_response(path, ("roll",)).loop("roll", "rate")
    assert got is not None and got.step is not None, got
    inj = got.rate_injection
    assert inj is not None and inj.included is included and inj.decided_by == "data", inj
    assert inj.coefficient is not None and abs(inj.coefficient - float(included)) < 0.15
    assert got.to_dict()["rate_injection"] == inj.to_dict()
    t, truth = true_rate_step(sc, "roll", float(got.step.time_s[-1]))
    assert np.allclose(t, got.step.time_s)
    inside = (truth >= got.step.lower) & (truth <= got.step.upper)
    # (measured 0.96 on both; counting the waveform twice gave 0.07)
    assert inside.mean() >= 0.9, (inside.mean(), np.abs(got.step.response - truth).max())


def test_a_delay_at_the_edge_of_the_search_is_not_found() -> None:
    rng = np.random.default_rng(4)
    dt = 0.01
    x = np.convolve(rng.standard_normal(6000), np.ones(40) / 40, mode="same")
    t = np.arange(x.size) * dt

    def delayed(n: int) -> np.ndarray:
        return np.r_[np.zeros(n), x[:-n]]

    near = response.loop_response("roll", "rate", t, x, delayed(4), rate_hz=100.0)
    assert near.delay_s == pytest.approx(0.04, abs=0.002) and near.delay_note == ""
    far = response.loop_response("roll", "rate", t, x, delayed(60), rate_hz=100.0)
    assert far.delay_s is None and "edge" in far.delay_note
    assert far.to_dict()["delay_s"] is None and far.to_dict()["delay_note"] == far.delay_note
    leads = response.loop_response("roll", "rate", t, delayed(8), x, rate_hz=100.0)
    assert leads.delay_s is None and "leads" in leads.delay_note
    from mavsid.cli_format import format_loop

    assert far.step is not None  # (the deconvolution is longer than the delay search)
    assert "delay not found (the correlation peaks at the edge" in format_loop(far)
    assert response.best_delay([x], [delayed(25)], dt)[0] is None  # (the edge itself)
    assert response.best_delay([x], [delayed(24)], dt)[0] == pytest.approx(0.24, abs=0.002)


def test_nothing_is_said_below_the_least_rate() -> None:
    t = np.arange(0, 60, 0.2)
    got = response.loop_response("roll", "rate", t, np.sin(t), np.sin(t), rate_hz=5.0)
    assert got.step is None and got.bandwidth_hz is None and "nothing can be said" in got.verdict


def test_a_parameter_change_in_flight_splits_the_response(tmp_path) -> None:
    from dataclasses import replace

    from mavsid.align import read_flight
    from mavsid.data import ParamChange
    from mavsid.loop import twin_messages

    sc = scenario_from_options(manoeuvre="random", axis="roll", duration_s=60.0, seed=4)
    path = tmp_path / "f.bin"
    simulate(sc, [path])
    flight, raw = read_flight(path, also=sorted(twin_messages()))
    t0 = float(flight.time_s[0])
    changed = replace(raw, param_changes=(
        ParamChange(t0 + 30.0, "ATC_RAT_RLL_P", 0.2),
        ParamChange(t0 + 30.5, "ATC_RAT_RLL_D", 0.005),  # (within a second: one change)
        ParamChange(t0 + 40.0, "LOG_BITMASK", 1.0)))  # (not the rate loop's: no split)
    got = response.flight_response(flight, changed)
    assert len(got.settings) == 2
    assert got.settings[1].changed == {"ATC_RAT_RLL_P": 0.2, "ATC_RAT_RLL_D": 0.005}
    assert got.settings[0].stop_s == got.settings[1].start_s == t0 + 30.0
    assert all(s.loops[0].axis == "roll" for s in got.settings)
    # PX4's names split a PX4 log, not an ArduPilot one
    px4 = replace(changed, param_changes=(ParamChange(t0 + 30.0, "MC_ROLLRATE_P", 0.2),))
    assert response.flight_response(flight, px4).settings == ()
    assert len(response.flight_response(replace(flight, autopilot="px4"), px4).settings) == 2


@pytest.mark.parametrize("suffix", [".bin", ".ulg"])
def test_a_retune_in_flight_gives_each_setting_its_own_response(tmp_path, suffix) -> None:
    from dataclasses import replace

    sc = scenario_from_options(manoeuvre="random", axis="roll", duration_s=90.0, seed=6)
    after = replace(sc.controller, rll_p=0.27, rll_d=0.0072)  # (twice the roll P and D)
    sc = replace(sc, retune=(45.0, after))
    path = tmp_path / f"retuned{suffix}"
    simulate(sc, [path])
    got = response.read_response(path, ("roll",))
    assert len(got.settings) == 2
    changed = got.settings[1].changed
    names = (("ATC_RAT_RLL_P", "ATC_RAT_RLL_D") if suffix == ".bin"
             else ("MC_ROLLRATE_P", "MC_ROLLRATE_D"))
    assert set(changed) == set(names)
    assert [changed[n] for n in names] == pytest.approx([0.27, 0.0072])
    assert got.settings[1].start_s == pytest.approx(sc.boot_s + 45.0, abs=0.01)
    rises = []
    for setting, controller in zip(got.settings, (sc.controller, after), strict=True):
        loop = setting.loops[0]
        assert loop.axis == "roll" and loop.loop == "rate" and loop.step is not None
        t, truth = true_rate_step(replace(sc, controller=controller, retune=None), "roll",
                                  float(loop.step.time_s[-1]))
        assert np.allclose(t, loop.step.time_s)
        inside = (truth >= loop.step.lower) & (truth <= loop.step.upper)
        assert inside.mean() >= 0.9, (inside.mean(), loop.verdict)
        rises.append(loop.rise_s)
    assert rises[0] is not None and rises[1] is not None and rises[1] < rises[0]


def _mavsid(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    return subprocess.run([sys.executable, "-m", "mavsid", *args], capture_output=True,
                          text=True, env=env, timeout=600, check=False)


def test_cli_json(flights) -> None:
    path = str(flights[1][0])
    run = _mavsid("response", path, "--json", "-q", "--axis", "roll")
    assert run.returncode == 0, run.stderr
    doc = json.loads(run.stdout)
    rate = doc["axes"]["roll"]["rate"]
    for key in ("rise_s", "overshoot_pct", "bandwidth_hz", "tracking_rms", "delay_s",
                "windows", "band_hz", "verdict"):
        assert key in rate
    assert set(rate["step"]) >= {"time_s", "response", "lower", "upper"}
    assert list(doc["axes"]) == ["roll"]


def test_cli_text_and_error(flights, tmp_path) -> None:
    run = _mavsid("response", str(flights[1][0]))
    assert run.returncode == 0, run.stderr
    assert "roll rate" in run.stdout and "pitch rate" in run.stdout
    bad = tmp_path / "x.bin"
    bad.write_bytes(b"nothing")
    run = _mavsid("response", str(bad), "--json")
    assert run.returncode == 1 and "Traceback" not in run.stderr
    assert "error" in json.loads(run.stdout)


def _real_logs() -> list[Path]:
    found = sorted(shared_logs(".bin", ".log", ".tlog", ".ulg"))
    for pattern in ("keita/*.BIN", "px4_ulog_tools/*.ulg", "impulse-response/**/*.ulg",
                    "px4tools/**/*.px4log"):
        found += sorted(CACHE.glob(pattern))
    return [p for p in found if "00000068" not in p.name]


def test_every_log_runs_without_a_traceback(capsys) -> None:
    from mavsid.cli import main

    logs = _real_logs()
    if not logs:
        pytest.skip("no shared or cached logs")
    for log in logs:
        code = main(["response", str(log), "--json", "-q"])
        doc = json.loads(capsys.readouterr().out)
        assert code in (0, 1), (log, code)
        if code == 0:
            for axis in doc["axes"].values():
                assert all(loop["verdict"] for loop in axis.values())
        else:
            assert doc["error"], log


def test_fit_writes_its_outputs_when_nothing_is_identified(flights, tmp_path) -> None:
    html, rrd = tmp_path / "r.html", tmp_path / "r.rrd"
    run = _mavsid("fit", str(flights[1][0]), "--axis", "pitch", "--report", str(html),
                  "--rrd", str(rrd), "-q")
    assert run.returncode == 1 and "Traceback" not in run.stderr
    text = html.read_text(encoding="utf-8")
    assert "no plant identified" in text and "not identified" in text
    assert "step response" in text.lower() and rrd.stat().st_size > 1000
    assert "wrote" in run.stderr and "no plant identified" in run.stderr


def test_two_logs_overlaid_in_the_report_and_recording(flights, tmp_path) -> None:
    from mavsid.report import write_response_report
    from mavsid.viz.response import response_blueprint, save_response_rrd

    found = [response.read_response(flights[s][0], ("roll",)) for s in (1, 2)]
    page = tmp_path / "two.html"
    write_response_report(found, page)
    text = page.read_text(encoding="utf-8")
    assert text.count("roll1.bin") >= 2 and text.count("roll2.bin") >= 2
    assert text.count("<img") >= 3  # time, step, spectrum
    bp = save_response_rrd(found, tmp_path / "two.rrd")
    assert bp is not None and (tmp_path / "two.rrd").stat().st_size > 1000
    assert response_blueprint(found) is not None
