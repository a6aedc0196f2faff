"""The simulator writes what real ArduCopter 4.5-4.7 SYSTEMID logs hold, and mavsid reads it.

Each phenomenon was seen in real ArduCopter 4.6.2 SYSTEMID flights of a Pixhawk 6C quad
(public logs, kept outside the repository; where they are present — ``MAVSID_REAL_LOGS``,
``keita/`` below ``helpers.REAL_LOGS`` — the simulated log is compared with them, else those checks
skip): RATE/PID/ANG at 100 Hz only while SYSTEMID runs with the loop at 400 Hz and 10 Hz
outside, ATT 10 Hz, two IMUs at 25 Hz each; an angle injection (``SID_AXIS`` 1) shaped by
the attitude controller (``ATC_INPUT_TC``, acceleration limits) before the rate loop; rate
PIDs without I; the motors on outputs 9-12 (DShot) with 1-8 unused; the 4.5+ message
layouts (AUXF with pos/source/result, PID records with DFF and Flags, ANG, ...); logging
gaps of minutes; a run that ends in a roll-over.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from helpers import REAL_LOGS
from pymavlink import mavutil

from mavsid import read_log
from mavsid.autopilot.ardupilot import motor_channels
from mavsid.autopilot.mixers import MIXERS
from mavsid.autopilot.presets import PRESETS
from mavsid.channels import motor_thrusts
from mavsid.info import summarize
from mavsid.loop import controller_from_params
from mavsid.pipeline import PipelineConfig, fit
from mavsid.synthetic import (
    ControllerParams,
    Faults,
    PlantParams,
    Scenario,
    SysIdSettings,
    simulate,
)
from mavsid.synthetic.flight import MODE_SYSTEMID, LogRates

REAL = REAL_LOGS / "keita"
#: what ArduCopter 4.6.2 logs with LOG_BITMASK 180222 and the loop at 400 Hz (IMU: each of
#: the two IMUs at 25 Hz, 50 records a second)
RATES_46 = LogRates(rate=100.0, rate_idle=10.0, att=10.0, imu=25.0, rcou=10.0, rcin=10.0)
TC = 0.15  # ATC_INPUT_TC
ACCEL = 1100.0  # ATC_ACCEL_R_MAX / 100 (deg/s²), ArduCopter's default


def real(name: str) -> Path:
    """A real log, or skip."""
    path = REAL / name
    if not path.exists():
        pytest.skip(f"{path} not present (real ArduCopter 4.6.2 logs: MAVSID_REAL_LOGS)")
    return path


def quiet_read(path: Path):  # type: ignore[no-untyped-def]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_log(path)


def quiet_fit(path: Path, axis: str):  # type: ignore[no-untyped-def]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fit([str(path)], PipelineConfig(axes=(axis,))).axes[axis]


def like_71(seed: int = 71) -> Scenario:
    """A flight like 00000071.BIN: STABILIZE at 10-Hz logging, then a 20° roll-angle chirp
    1 -> 40 Hz (SID_AXIS 1, 3-s fade-in, SID_T_REC 15 s) through the attitude controller
    (ATC_INPUT_TC 0.15, ATC_ACCEL_R_MAX 110000, feed-forward on), rate PIDs without I (pitch
    with FF), motors on outputs 9-12 by DShot; a plant of the same authority (B ≈ 500)."""
    ctl = ControllerParams(rll_p=0.04, rll_i=0.0, rll_d=0.0012, pit_p=0.05, pit_i=0.0,
                           pit_d=0.0012, pit_ff=0.02, yaw_p=0.2, yaw_i=0.0, yaw_fltd=20.0,
                           accel_r_max=ACCEL, accel_p_max=ACCEL, accel_y_max=270.0,
                           input_tc=TC, spin_min=0.02, thst_expo=0.0)
    plant = PlantParams(damping=(3.0, 3.0, 1.0), effectiveness=(500.0, 450.0, 40.0),
                        motor_tau_s=0.013, delay_s=0.006, hover_throttle=0.223)
    run = SysIdSettings(axis=1, magnitude=20.0, f_start_hz=1.0, f_stop_hz=40.0,
                        t_fade_in=3.0, t_rec=15.0, t_fade_out=1.0)
    return Scenario(sysid=(run,), controller=ctl, plant=plant, rates=RATES_46, motor_output=9,
                    esc="dshot150", hover_before_s=10.0, hover_after_s=5.0, seed=seed)


@pytest.fixture(scope="module")
def sim71(tmp_path_factory):  # type: ignore[no-untyped-def]
    path = tmp_path_factory.mktemp("real") / "like71.bin"
    result = simulate(like_71(), [path], layout="copter-4.6")
    return path, result.flight


def records(path: Path, types: tuple[str, ...]) -> dict[str, dict[str, np.ndarray]]:
    """Columns of ``types`` as pymavlink decodes them (the reference reader)."""
    m = mavutil.mavlink_connection(str(path))
    rows: dict[str, list[dict]] = {t: [] for t in types}
    while (msg := m.recv_match(type=list(types))) is not None:
        rows[msg.get_type()].append(msg.to_dict())
    return {t: {k: np.array([r[k] for r in rs]) for k in (rs[0] if rs else {})
                if k != "mavpackettype"} for t, rs in rows.items()}


def formats(path: Path) -> dict[str, tuple[int, str, str, str, str]]:
    """Per message name: FMT type, format, columns and FMTU units, multipliers."""
    m = mavutil.mavlink_connection(str(path))
    fmt, fmtu = {}, {}
    while (msg := m.recv_match(type=["FMT", "FMTU"])) is not None:
        if msg.get_type() == "FMT":
            fmt[msg.Type] = (msg.Name, msg.Format, msg.Columns)
        else:
            fmtu[msg.FmtType] = (msg.UnitIds, msg.MultIds)
    return {name: (ty, f, c, *fmtu.get(ty, ("", ""))) for ty, (name, f, c) in fmt.items()}


def sysid_spans(modes: dict[str, np.ndarray], end_s: float) -> list[tuple[float, float]]:
    t, mode = modes["TimeUS"] / 1e6, modes["Mode"]
    out = []
    for k in np.flatnonzero(mode == MODE_SYSTEMID):
        later = t[(t > t[k]) & (mode != MODE_SYSTEMID)]
        out.append((float(t[k]), float(later[0]) if later.size else end_s))
    return out


def logging_steps(path: Path) -> dict[str, float]:
    """Median record interval (s) of RATE in and out of SYSTEMID, of SIDD, ATT, the first
    IMU."""
    r = records(path, ("RATE", "SIDD", "ATT", "IMU", "MODE"))
    imu = r["IMU"]["TimeUS"][r["IMU"]["I"] == 0] / 1e6  # (the first IMU)
    t = r["RATE"]["TimeUS"] / 1e6
    spans = sysid_spans(r["MODE"], float(t[-1]) + 1.0)
    inside = np.zeros(t.size, dtype=bool)
    for a, b in spans:
        inside |= (t >= a) & (t < b)
    ts = r["SIDD"]["TimeUS"] / 1e6
    assert all(any(a <= x < b + 0.011 for a, b in spans) for x in ts)  # SIDD only in a run
    return {"rate_in": float(np.median(np.diff(t[inside]))),
            "rate_out": float(np.median(np.diff(t[~inside]))),
            "sidd": float(np.median(np.diff(ts))),
            "att": float(np.median(np.diff(r["ATT"]["TimeUS"] / 1e6))),
            "imu": float(np.median(np.diff(imu)))}


# --------------------------------------------------------------------------- (a) logging


def test_systemid_logs_at_100_hz_and_10_hz_outside(sim71):
    path, _flight = sim71
    steps = logging_steps(path)
    assert steps == pytest.approx({"rate_in": 0.01, "rate_out": 0.1, "sidd": 0.01,
                                   "att": 0.1, "imu": 0.04}, rel=0.02)
    raw = quiet_read(path)
    assert raw.params["LOG_BITMASK"] == 180222 and raw.params["SCHED_LOOP_RATE"] == 400
    for name in ("PIDR", "PIDP", "PIDY", "ANG"):  # written with RATE
        np.testing.assert_array_equal(raw[name].time_s, raw["RATE"].time_s)
    info = summarize(raw)
    assert info["messages"]["RATE"]["rate_hz"] == pytest.approx(100.0)


def test_systemid_logging_rates_are_the_real_ones(sim71):
    ours, theirs = logging_steps(sim71[0]), logging_steps(real("00000071.BIN"))
    assert ours == pytest.approx(theirs, rel=0.05)


def test_a_log_at_10_hz_outside_systemid_recovers_the_plant(sim71):
    """fit uses the 100-Hz run and recovers the plant's authority within its σ."""
    path, _flight = sim71
    f = quiet_fit(path, "roll")
    b, se = f.model.params["B[p,u_roll]"], f.model.stderr["B[p,u_roll]"]
    assert abs(b - 500.0) < 3 * se + 0.02 * 500.0, (b, se)
    assert f.verdict is not None and f.verdict.level in ("good", "usable")


# --------------------------------------------------------------------------- (b) angle axis


def band_levels(path: Path) -> dict[str, float]:
    """From SIDD (the injected angle, its frequency), ANG.DesRoll (the shaped attitude
    target) and RATE.RDes (the rate target): while the chirp is at 1-2 Hz (from its start),
    the regression slope and correlation of the attitude target on the injected angle passed
    through a first-order lag of ``ATC_INPUT_TC``; while it sweeps, the rate target's RMS
    (deg/s) at 1-1.6 Hz, 2-3 Hz and 25-40 Hz."""
    from scipy.signal import lfilter

    r = records(path, ("SIDD", "ANG", "RATE", "SIDS"))
    s, sids = r["SIDD"], r["SIDS"]
    t = s["TimeUS"] / 1e6
    end = s["Time"] < 1 + sids["TC"][0] + sids["TR"][0]
    sweep = (s["Time"] > 1 + sids["TFin"][0]) & end

    def at(table: dict[str, np.ndarray], name: str, sel: np.ndarray) -> np.ndarray:
        return np.interp(t[sel], table["TimeUS"] / 1e6, table[name])

    a = np.exp(-np.median(np.diff(t)) / TC)
    lagged = lfilter([1 - a], [1, -a], s["Targ"])
    sel = (s["Time"] > 1) & end & (s["F"] >= 1.0) & (s["F"] < 2.0)
    x, y = lagged[sel] - lagged[sel].mean(), at(r["ANG"], "DesRoll", sel)
    y = y - y.mean()
    out = {"shaped_slope": float(x @ y / (x @ x)), "shaped_corr": float(np.corrcoef(x, y)[0, 1])}
    for lo, hi in ((1.0, 1.6), (2.0, 3.0), (25.0, 40.0)):
        sel = sweep & (s["F"] >= lo) & (s["F"] < hi)
        out[f"rdes_{lo:g}_{hi:g}"] = float(np.std(at(r["RATE"], "RDes", sel)))
    return out


def test_angle_injection_reaches_the_rate_loop_through_input_shaping(sim71):
    """At 1-2 Hz the acceleration limit hardly bites: the attitude target is the injected
    angle through ArduPilot's first-order input shaping of time constant ATC_INPUT_TC. At
    25-40 Hz it does: the target rate's swing is bounded by the acceleration (a rate
    slewing at ``a`` reaches ±a/(4f)), far below what the shaping alone would pass
    (20°·ω·|1/(1+jωτ)| ≈ 20°/τ = 133 deg/s, RMS 94)."""
    got = band_levels(sim71[0])
    assert got["shaped_slope"] == pytest.approx(1.0, abs=0.05)
    assert got["shaped_corr"] > 0.99
    bound = ACCEL / (4 * 25.0)  # the largest swing at the band's lowest frequency
    assert got["rdes_25_40"] < bound < 0.25 * 20.0 / TC / np.sqrt(2)


def test_angle_injection_levels_are_the_real_flights(sim71):
    """The same measures on the real 00000071: the shaping within 15 % (the real target
    also carries the pilot's corrections), the rate target's level where the vehicle
    follows (1-3 Hz) within 10 %; at 25-40 Hz both far below what an unlimited shaping
    passes (the real one 3x the simulated: its attitude estimate moves at those
    frequencies, the simulated one hardly)."""
    ours, theirs = band_levels(sim71[0]), band_levels(real("00000071.BIN"))
    assert theirs["shaped_slope"] == pytest.approx(ours["shaped_slope"], rel=0.15)
    assert theirs["shaped_corr"] > 0.9
    for key in ("rdes_1_1.6", "rdes_2_3"):
        assert ours[key] == pytest.approx(theirs[key], rel=0.10), key
    unlimited_rms = 20.0 / TC / np.sqrt(2)
    assert max(ours["rdes_25_40"], theirs["rdes_25_40"]) < 0.25 * unlimited_rms


def test_an_angle_run_is_found_as_the_injection_axis(sim71):
    path, _ = sim71
    f = quiet_fit(path, "roll")
    assert any(s.source == "sysid" for s in f.train)


# --------------------------------------------------------------------------- (c) no I term


def pid_identity(path: Path) -> tuple[float, float]:
    """Largest |I| of PIDR/PIDP, and largest |RATE.xOut - (P + I + D + FF + DFF)| where
    RATE and the PID record were written in the same loop."""
    r = records(path, ("RATE", "PIDR", "PIDP"))
    i_max, worst = 0.0, 0.0
    for pid, out in (("PIDR", "ROut"), ("PIDP", "POut")):
        p = r[pid]
        i_max = max(i_max, float(np.max(np.abs(p["I"]))))
        t_rate, t_pid = r["RATE"]["TimeUS"], p["TimeUS"]
        k = np.searchsorted(t_rate, t_pid, side="right") - 1  # the RATE at or before it
        ok = (k >= 0) & (t_pid - t_rate[np.maximum(k, 0)] < 2000)
        total = p["P"] + p["I"] + p["D"] + p["FF"] + p["DFF"]
        worst = max(worst, float(np.max(np.abs(r["RATE"][out][k[ok]] - total[ok]))))
    return i_max, worst


def test_an_i_less_rate_loop_logs_its_terms(sim71):
    path, _flight = sim71
    i_max, worst = pid_identity(path)
    assert i_max == 0.0
    assert worst < 1e-6  # (float32 records)
    p = records(path, ("PIDP",))["PIDP"]
    np.testing.assert_allclose(p["FF"], 0.02 * p["Tar"], rtol=1e-5, atol=1e-9)
    raw = quiet_read(path)
    for axis in ("roll", "pitch"):  # the twin's rebuild reads I = 0 and the FF
        gains = controller_from_params(raw.params, axis).gains
        assert gains.i == 0.0
        assert gains.ff == pytest.approx(0.02 if axis == "pitch" else 0.0, abs=1e-8)


def test_the_real_i_less_loop_logs_the_same_identity():
    i_max, worst = pid_identity(real("00000071.BIN"))
    assert i_max == 0.0 and worst < 1e-5


def test_the_twin_follows_the_i_less_controller(sim71):
    """The twin's rebuild from the log's parameters, driven by the simulated loop's rate
    target and filtered gyro at 400 Hz, gives the simulated controller's output."""
    path, flight = sim71
    raw = quiet_read(path)
    for j, axis in enumerate(("roll", "pitch")):
        pid = controller_from_params(raw.params, axis).new_pid()
        out = np.array([pid.update(float(a), float(b)) for a, b in
                        zip(flight.rate_target[:, j], flight.gyro[:, j], strict=True)])
        # (the log's gains are float32: 0.04 is read as 0.0399999991)
        scale = np.max(np.abs(flight.pid_out[:, j]))
        assert np.max(np.abs(out - flight.pid_out[:, j])) < 1e-6 * scale, axis


# --------------------------------------------------------------------------- (d) motors


def test_motors_on_outputs_9_to_12(sim71):
    path, flight = sim71
    r = records(path, ("RCOU", "MSG"))
    rc = r["RCOU"]
    for c in range(1, 9):
        assert not rc[f"C{c}"].any(), c
    k = np.round((rc["TimeUS"] / 1e6 - flight.t_s[0]) / flight.dt).astype(int)
    for m in range(4):
        np.testing.assert_array_equal(rc[f"C{9 + m}"], flight.pwm[k, m])
    assert "RCOut: PWM:1-8 DS150:9-12 PWM:13-16" in r["MSG"]["Message"].tolist()
    raw = quiet_read(path)
    assert raw.params["MOT_PWM_TYPE"] == 4
    assert motor_channels(raw.params, 4) == [9, 10, 11, 12]
    t, thrust = motor_thrusts(raw, PRESETS["ardupilot-rcou"], MIXERS["quad-x"])
    k = np.round((t - flight.t_s[0]) / flight.dt).astype(int)
    np.testing.assert_allclose(thrust, flight.motors[k], atol=2e-3)  # (whole µs)


def test_real_motors_are_on_outputs_9_to_12():
    raw = quiet_read(real("00000071.BIN"))
    assert motor_channels(raw.params, 4) == [9, 10, 11, 12]
    assert raw.params["MOT_PWM_TYPE"] == 4
    rc = raw["RCOU"]
    assert not any(rc[f"C{c}"].any() for c in range(1, 9))


# --------------------------------------------------------------------------- (e) layouts


def test_message_layouts_are_the_real_4_6_ones(sim71):
    """Every message type the simulator writes in the 4.6 layout has the real log's type
    id, format, columns, units and multipliers."""
    ours, theirs = formats(sim71[0]), formats(real("00000071.BIN"))
    assert set(ours) <= set(theirs)
    for name, spec in ours.items():
        assert spec == theirs[name], name
    assert {"AUXF", "ANG", "PIDR", "ARM", "VER"} <= set(ours)


def test_4_6_logs_are_read_by_every_field_name(sim71):
    """info, on the simulated and (where present) the real log: AUXF's 16-bit
    instance column (function) is not a reason to fail."""
    paths = [sim71[0]] + ([REAL / "00000071.BIN"] if (REAL / "00000071.BIN").exists() else [])
    for path in paths:
        info = summarize(quiet_read(path))
        assert info["messages"]["AUXF"]["count"] == 2
        assert "function" in info["messages"]["AUXF"]["fields"]


# --------------------------------------------------------------------------- (f) gaps


@pytest.fixture(scope="module")
def gap_log(tmp_path_factory):  # type: ignore[no-untyped-def]
    path = tmp_path_factory.mktemp("gap") / "gap.bin"
    sc = Scenario(sysid=(SysIdSettings(axis=10), SysIdSettings(axis=10)), rates=RATES_46,
                  seed=5, gap_s=6.0)
    simulate(sc, [path], faults=Faults(gap=(32.0, 240.0)), layout="copter-4.6")
    return path


def test_a_minutes_long_logging_gap(gap_log):
    r = records(gap_log, ("RATE", "EV"))
    t = r["RATE"]["TimeUS"] / 1e6
    jumps = np.diff(t)
    assert jumps.max() == pytest.approx(240.0, abs=0.2)
    assert int(np.sum(jumps > 1.0)) == 1
    assert r["EV"]["Id"].tolist() == [10, 11, 10, 11]  # disarmed before it, armed after


def test_a_logging_gap_splits_the_flight_and_both_runs_fit(gap_log):
    f = quiet_fit(gap_log, "roll")
    spans = [(float(s.time_s[0]), float(s.time_s[-1])) for s in (*f.train, *f.held_out)]
    t = records(gap_log, ("RATE",))["RATE"]["TimeUS"] / 1e6
    k = int(np.argmax(np.diff(t)))
    gap = (float(t[k]), float(t[k + 1]))
    assert not any(a < gap[0] and b > gap[1] for a, b in spans)
    assert any(b <= gap[0] for a, b in spans) and any(a >= gap[1] for a, b in spans)
    b, se = f.model.params["B[p,u_roll]"], f.model.stderr["B[p,u_roll]"]
    assert abs(b - 180.0) < 3 * se, (b, se)


# --------------------------------------------------------------------------- (g) roll-over


@pytest.fixture(scope="module")
def rollover_log(tmp_path_factory):  # type: ignore[no-untyped-def]
    """Like 00000060: a slow mixer-roll chirp (0.15, 0.05-5 Hz) during which a motor
    fails; the run stops at the lean limit, the vehicle rolls over and disarms."""
    path = tmp_path_factory.mktemp("rollover") / "rollover.bin"
    run = SysIdSettings(axis=10, magnitude=0.15, f_start_hz=0.05, f_stop_hz=5.0, t_rec=130.0,
                        t_fade_in=5.0, t_fade_out=5.0)
    sc = Scenario(sysid=(run,), duration_s=30.0, hover_before_s=5.0, rates=RATES_46,
                  motor_output=9, esc="dshot150", motor_failure_s=12.0, seed=3)
    return path, simulate(sc, [path], layout="copter-4.6").flight


def test_a_motor_failure_rolls_the_vehicle_over(rollover_log):
    path, _flight = rollover_log
    r = records(path, ("MSG", "ATT", "ARM"))
    texts = r["MSG"]["Message"].tolist()
    stop = [x for x in texts if x.startswith("SystemID Stopped: lean=")]
    assert len(stop) == 1 and "SystemID Finished" not in texts
    assert float(stop[0].split("lean=")[1].split()[0]) > 30.0  # (ANGLE_MAX 3000 cdeg)
    assert np.max(np.abs(r["ATT"]["Roll"])) > 90.0
    assert r["ARM"]["ArmState"].tolist() == [1, 0]


def test_a_run_that_ends_in_a_roll_over_is_refused_in_one_line(rollover_log):
    from mavsid.errors import NoExcitationError

    with warnings.catch_warnings(), pytest.raises(NoExcitationError) as err:
        warnings.simplefilter("ignore")
        fit([str(rollover_log[0])], PipelineConfig(axes=("roll",)))
    message = str(err.value)
    assert "\n" not in message
    assert "ends in a roll-over: |roll| passes 75° at t=" in message
