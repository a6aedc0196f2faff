"""mavsid.synthetic: the known plant, its logs and their truth.

References outside the code under test: pymavlink (decodes every written .bin and .tlog),
scipy.signal (an independent re-simulation of the plant and the gyro filter), the SIDD records
of a real ArduCopter SITL flight (the SYSTEMID waveform), and the chirp's specification
written out here.
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from helpers import FIXTURES, shared_path
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from pymavlink import DFReader, mavutil
from scipy import signal

from mavsid import read_log
from mavsid.cli import main
from mavsid.errors import ConfigError
from mavsid.synthetic import (
    Faults,
    LogRates,
    PlantParams,
    Scenario,
    SysIdSettings,
    chirp,
    fly,
    simulate,
)
from mavsid.synthetic.flight import MODE_SYSTEMID
from mavsid.synthetic.tlogwriter import EPOCH_US

LOOP_HZ = 400.0
DT = 1.0 / LOOP_HZ
FIXTURE_LOGS = ["sysid_roll.bin", "sysid_pitch.bin", "sysid_yaw.bin", "doublets.bin",
                "hover.bin", "sysid_roll.tlog"]


# --------------------------------------------------------------------------- references


def pymavlink_bin(path: Path) -> dict[str, dict[str, np.ndarray]]:
    """Every message of a .bin as pymavlink decodes it: type -> field -> array."""
    log = DFReader.DFReader_binary(str(path), zero_time_base=False)
    rows: dict[str, list[dict]] = defaultdict(list)
    while (m := log.recv_msg()) is not None:
        d = m.to_dict()
        rows[d.pop("mavpackettype")].append(d)
    return {name: {k: np.array([r[k] for r in rs]) for k in rs[0]} for name, rs in rows.items()}


def pymavlink_tlog(path: Path) -> dict[str, dict[str, np.ndarray]]:
    """Every message of a .tlog as pymavlink's log reader (mavutil) decodes it; ``_recv_us``
    is the record's receive time, ``_sysid`` its sender."""
    conn = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
    rows: dict[str, list[dict]] = defaultdict(list)
    try:
        while (msg := conn.recv_match()) is not None:
            d = msg.to_dict()
            d["_recv_us"] = round(msg._timestamp * 1e6)
            d["_sysid"] = msg.get_srcSystem()
            rows[d.pop("mavpackettype")].append(d)
    finally:
        conn.close()
    return {name: {k: np.array([r[k] for r in rs]) for k in rs[0]} for name, rs in rows.items()}


def every(n: int, hz: float) -> np.ndarray:
    """Loop indices of a message logged at ``hz``."""
    return np.arange(0, n, round(LOOP_HZ / hz))


def f32(x: np.ndarray) -> np.ndarray:
    return np.asarray(x, dtype=np.float32).astype(float)


def spec_frequency(tau: np.ndarray, f0: float, f1: float, tc: float, tr: float) -> np.ndarray:
    """SYSTEMID chirp frequency (Hz) at chirp time ``tau`` (= SIDD.Time - 1 s): f0 for two
    cycles (tc), then exponential to f1 at tr; f1 after."""
    f = f0 * np.exp(np.log(f1 / f0) * np.clip(tau - tc, 0, None) / (tr - tc))
    return np.where(tau > tr, f1, f)


# --------------------------------------------------------------------------- fixtures

SHORT_SID = SysIdSettings(axis=10, magnitude=0.06, f_start_hz=1.0, f_stop_hz=12.0,
                          t_fade_in=1.0, t_rec=6.0, t_fade_out=0.5)


@pytest.fixture(scope="module")
def short(tmp_path_factory: pytest.TempPathFactory):
    """A short SYSTEMID flight logged at loop rate, written as .bin and .tlog."""
    d = tmp_path_factory.mktemp("short")
    sc = Scenario(sysid=(SHORT_SID,), hover_before_s=1.0, hover_after_s=1.0, seed=11)
    res = simulate(sc, [d / "s.bin", d / "s.tlog"])
    return res.flight, d / "s.bin", d / "s.tlog"


@pytest.fixture(scope="module")
def short_bin(short):
    return pymavlink_bin(short[1])


@pytest.fixture(scope="module")
def short_tlog(short):
    return pymavlink_tlog(short[2])


# --------------------------------------------------------------------------- the waveform


@pytest.fixture(scope="module")
def sitl_sid():
    """SIDS and SIDD of the real SITL flight (pymavlink, those two types only)."""
    log = DFReader.DFReader_binary(str(shared_path("sitl", "flightA_mixer.BIN")),
                                   zero_time_base=False)
    out = {}
    for name in ("SIDS", "SIDD"):
        log.rewind()
        rows = []
        while (m := log.recv_match(type=name)) is not None:
            rows.append(m.to_dict())
        out[name] = {k: np.array([r[k] for r in rows]) for k in rows[0] if k != "mavpackettype"}
    return out


@pytest.mark.slow
def test_chirp_reproduces_real_sitl_sidd(sitl_sid):
    """Our waveform, given the SIDS settings and SIDD.Time, equals ArduCopter's SIDD.Targ and
    SIDD.F in all four real runs (within ArduPilot's float32 arithmetic)."""
    sids, sidd = sitl_sid["SIDS"], sitl_sid["SIDD"]
    assert len(sids["Ax"]) == 4
    for k in range(4):
        s = SysIdSettings(axis=int(sids["Ax"][k]), magnitude=float(sids["Mag"][k]),
                          f_start_hz=float(sids["FSt"][k]), f_stop_hz=float(sids["FSp"][k]),
                          t_fade_in=float(sids["TFin"][k]), t_rec=float(sids["TR"][k]),
                          t_fade_out=float(sids["TFout"][k]))
        assert s.t_const_freq == pytest.approx(float(sids["TC"][k]))
        stop = sids["TimeUS"][k + 1] if k < 3 else np.inf
        m = (sidd["TimeUS"] >= sids["TimeUS"][k]) & (sidd["TimeUS"] < stop)
        assert m.sum() > 20_000
        targ, freq = chirp(sidd["Time"][m].astype(float), s)
        np.testing.assert_allclose(targ, sidd["Targ"][m], rtol=0, atol=2e-3 * s.magnitude)
        np.testing.assert_allclose(freq, sidd["F"][m], rtol=2e-5)
        assert np.abs(sidd["Targ"][m]).max() == pytest.approx(s.magnitude, rel=1e-3)


@pytest.mark.slow
def test_sidd_frequency_matches_specification(short, short_bin):
    """SIDD.F follows the chirp specification, and the waveform's own zero crossings have
    that instantaneous frequency."""
    flight, _, _ = short
    sidd, sids = short_bin["SIDD"], short_bin["SIDS"]
    s = SHORT_SID
    assert (sids["Ax"][0], sids["FSt"][0], sids["FSp"][0], sids["TR"][0]) == (10, 1.0, 12.0, 6.0)
    tau = sidd["Time"].astype(float) - 1.0
    want = spec_frequency(tau, s.f_start_hz, s.f_stop_hz, 2.0 / s.f_start_hz, s.t_rec)
    np.testing.assert_allclose(sidd["F"], want, rtol=1e-5)
    # zero crossings of Targ during the sweep: half a period apart
    t, y = sidd["Time"].astype(float), sidd["Targ"].astype(float)
    live = (tau > 0.2) & (tau < s.t_rec - 0.2)
    idx = np.flatnonzero(live[:-1] & live[1:] & (np.sign(y[:-1]) != np.sign(y[1:]))
                         & (y[:-1] != 0))
    tz = t[idx] - y[idx] * (t[idx + 1] - t[idx]) / (y[idx + 1] - y[idx])
    f_meas = 0.5 / np.diff(tz)
    f_spec = spec_frequency(0.5 * (tz[1:] + tz[:-1]) - 1.0, s.f_start_hz, s.f_stop_hz,
                            2.0 / s.f_start_hz, s.t_rec)
    assert len(f_meas) > 25
    np.testing.assert_allclose(f_meas, f_spec, rtol=0.03)
    # SIDD exists exactly while SYSTEMID is the mode, Time advancing one loop per sample
    assert np.allclose(np.diff(sidd["Time"]), DT, atol=1e-6)
    assert len(sidd["Time"]) == int(np.sum(flight.mode == MODE_SYSTEMID))


# --------------------------------------------------------------------------- .bin content


def test_bin_values_match_simulation(short, short_bin):
    """pymavlink decodes the .bin to exactly the simulated signals (float32 / µs rounding)."""
    fl, _, _ = short
    n, log = len(fl), short_bin
    tus = np.round(fl.t_s * 1e6).astype(np.int64)
    i = every(n, 400)
    rate = log["RATE"]
    np.testing.assert_array_equal(rate["TimeUS"], tus[i])
    for j, ax in enumerate("RPY"):
        np.testing.assert_array_equal(rate[ax], f32(np.degrees(fl.gyro[i, j])))
        np.testing.assert_array_equal(rate[f"{ax}Des"], f32(np.degrees(fl.rate_target[i, j])))
        np.testing.assert_array_equal(rate[f"{ax}Out"], f32(fl.u[i, j]))
    np.testing.assert_array_equal(rate["AOut"], f32(fl.throttle[i]))
    sid = np.flatnonzero(fl.mode == MODE_SYSTEMID)
    sidd = log["SIDD"]
    np.testing.assert_array_equal(sidd["TimeUS"], tus[sid])
    np.testing.assert_array_equal(sidd["Targ"], f32(fl.sid_targ[sid]))
    for j, ax in enumerate("xyz"):
        np.testing.assert_array_equal(sidd[f"G{ax}"], f32(np.degrees(fl.gyro_raw[sid, j])))
        np.testing.assert_array_equal(sidd[f"A{ax}"], f32(fl.accel[sid, j]))
    i = every(n, 10)
    att = log["ATT"]
    np.testing.assert_array_equal(att["TimeUS"], tus[i])
    np.testing.assert_array_equal(att["Roll"], f32(np.degrees(fl.attitude[i, 0])))
    np.testing.assert_array_equal(att["Pitch"], f32(np.degrees(fl.attitude[i, 1])))
    np.testing.assert_array_equal(att["Yaw"], f32(np.degrees(fl.attitude[i, 2]) % 360))
    np.testing.assert_array_equal(att["DesRoll"], f32(np.degrees(fl.attitude_target[i, 0])))
    i = every(n, 25)
    imu = log["IMU"]
    np.testing.assert_array_equal(imu["TimeUS"], tus[i])
    np.testing.assert_array_equal(imu["GyrX"], f32(fl.gyro[i, 0]))
    np.testing.assert_array_equal(imu["AccZ"], f32(fl.accel[i, 2]))
    i = every(n, 10)
    for c in range(4):
        np.testing.assert_array_equal(log["RCOU"][f"C{c + 1}"], fl.pwm[i, c])
    rc = fl.rc_in()
    for c in range(8):
        np.testing.assert_array_equal(log["RCIN"][f"C{c + 1}"], rc[i, c])
    # the mode goes STABILIZE -> SYSTEMID -> STABILIZE; one SIDS
    assert log["MODE"]["Mode"].tolist() == [0, 25, 0]
    assert len(log["SIDS"]["TimeUS"]) == 1
    params = dict(zip(log["PARM"]["Name"], log["PARM"]["Value"], strict=True))
    for name, value in fl.params().items():
        assert params[name] == pytest.approx(value, rel=1e-6), name
    assert params["INS_GYRO_FILTER"] == fl.scenario.plant.gyro_filter_hz
    assert any(m.startswith("ArduCopter V4") for m in log["MSG"]["Message"])


def test_bin_layouts_are_arducopter_4(short, short_bin):
    """FMT/FMTU of our logs equal those of the real ArduCopter 4.7 SITL log."""
    real = DFReader.DFReader_binary(str(shared_path("sitl", "flightA_mixer.BIN")),
                                    zero_time_base=False)
    ours = DFReader.DFReader_binary(str(short[1]), zero_time_base=False)
    names = ["PARM", "MSG", "MODE", "ATT", "RATE", "IMU", "RCOU", "RCIN", "SIDS", "SIDD"]
    for name in names:
        a, b = real.formats[real.name_to_id[name]], ours.formats[ours.name_to_id[name]]
        assert (a.type, a.len, a.format, a.columns) == (b.type, b.len, b.format, b.columns)
    # units / multipliers as declared by FMTU, as in the real log
    real_fmtu = {}
    while (m := real.recv_match(type="FMTU")) is not None:
        real_fmtu[m.FmtType] = (m.UnitIds, m.MultIds)
    fmtu = short_bin["FMTU"]
    declared = {int(t): (u, m) for t, u, m in zip(fmtu["FmtType"], fmtu["UnitIds"],
                                                 fmtu["MultIds"], strict=True)}
    for name in names:
        assert declared[ours.name_to_id[name]] == real_fmtu[real.name_to_id[name]], name
    units = dict(zip(short_bin["UNIT"]["Id"], short_bin["UNIT"]["Label"], strict=True))
    assert units[ord("k")] == "deg/s" and units[ord("E")] == "rad/s"


def test_builder_scales_every_format_character(tmp_path):
    """Format characters with implied scaling (c C e E L), integers, strings, doubles and
    int16[32] arrays come back from pymavlink as written."""
    from mavsid.synthetic.dfwriter import DataFlashBuilder, MessageFormat

    fmts = [MessageFormat(201, "TST", "QcCeELbBhHiIfd", ("TimeUS", "Ac", "BC", "Ce", "DE",
                                                        "EL", "Fb", "GB", "Hh", "IH", "Ji",
                                                        "KI", "Lf", "Md")),
            MessageFormat(202, "TS2", "QnNZqa", ("TimeUS", "Nn", "ON", "PZ", "Qq", "Ra"))]
    with pytest.raises(ConfigError):
        MessageFormat(203, "LONG", "Q" * 17, tuple(f"c{i}" for i in range(17)))
    rng = np.random.default_rng(0)
    n = 50
    vals = {
        "Ac": np.round(rng.uniform(-300, 300, n), 2), "BC": np.round(rng.uniform(0, 600, n), 2),
        "Ce": np.round(rng.uniform(-2e7, 2e7, n), 2), "DE": np.round(rng.uniform(0, 4e7, n), 2),
        "EL": np.round(rng.uniform(-180, 180, n), 7), "Fb": rng.integers(-128, 128, n),
        "GB": rng.integers(0, 256, n), "Hh": rng.integers(-2**15, 2**15, n),
        "IH": rng.integers(0, 2**16, n), "Ji": rng.integers(-2**31, 2**31, n),
        "KI": rng.integers(0, 2**32, n), "Lf": rng.normal(size=n), "Md": rng.normal(size=n),
        "Nn": ["ab"] * n, "ON": ["sixteen_chars_ok"] * n, "PZ": ["x" * 64] * n,
        "Qq": rng.integers(-2**62, 2**62, n), "Ra": rng.integers(-999, 999, (n, 32)),
    }
    b = DataFlashBuilder()
    b.define(b.formats["FMT"])
    t = np.arange(n) * 1000 + 5
    for f in fmts:
        b.define(f)
        b.add(f.name, t, **{k: v for k, v in vals.items() if k in f.columns})
    (tmp_path / "f.bin").write_bytes(b.to_bytes())
    log = pymavlink_bin(tmp_path / "f.bin")
    got = {**log["TST"], **log["TS2"]}
    np.testing.assert_array_equal(got["TimeUS"], t)
    for key, want in vals.items():
        if key == "Ra":
            np.testing.assert_array_equal(np.array(got[key].tolist()), want)
        elif key in ("Nn", "ON", "PZ"):
            assert got[key].tolist() == want
        elif key == "Lf":
            np.testing.assert_array_equal(got[key], f32(want))
        else:
            np.testing.assert_allclose(got[key], want, rtol=1e-12, atol=1e-9, err_msg=key)
    ours = read_log(tmp_path / "f.bin")
    assert _compare_tables(ours, {"TST": log["TST"]}) == 14
    assert _compare_tables(ours, {"TS2": {k: v for k, v in log["TS2"].items() if k != "Ra"}}) == 5
    np.testing.assert_array_equal(ours["TS2"]["Ra"], vals["Ra"])


# --------------------------------------------------------------------------- .tlog content


def test_tlog_values_match_simulation(short, short_tlog):
    fl, _, _ = short
    n, log = len(fl), short_tlog
    i = every(n, 50)
    att = log["ATTITUDE"]
    ms = np.round(fl.t_s * 1e3).astype(np.int64)
    np.testing.assert_array_equal(att["time_boot_ms"], ms[i])
    np.testing.assert_array_equal(att["roll"], f32(fl.attitude[i, 0]))
    np.testing.assert_array_equal(att["rollspeed"], f32(fl.gyro[i, 0]))
    yaw = (fl.attitude[i, 2] + np.pi) % (2 * np.pi) - np.pi
    np.testing.assert_array_equal(att["yaw"], f32(yaw))
    servo = log["SERVO_OUTPUT_RAW"]
    np.testing.assert_array_equal(servo["time_usec"], np.round(fl.t_s[i] * 1e6))
    for c in range(4):
        np.testing.assert_array_equal(servo[f"servo{c + 1}_raw"], fl.pwm[i, c])
    rc = fl.rc_in()
    for c in range(8):
        np.testing.assert_array_equal(log["RC_CHANNELS"][f"chan{c + 1}_raw"], rc[i, c])
    imu = log["SCALED_IMU"]
    np.testing.assert_array_equal(imu["xgyro"], np.round(fl.gyro[i, 0] * 1000))
    np.testing.assert_array_equal(imu["zacc"], np.round(fl.accel[i, 2] / 9.80665 * 1000))
    params = dict(zip(log["PARAM_VALUE"]["param_id"], log["PARAM_VALUE"]["param_value"],
                      strict=True))
    for name, value in fl.params().items():
        assert params[name] == pytest.approx(value, rel=1e-6), name
    hb = log["HEARTBEAT"]
    vehicle = hb["_sysid"] == 1
    assert set(hb["custom_mode"][vehicle]) == {0, 25}
    assert (hb["_sysid"] == 255).sum() >= 1
    # receive times: after the send time, with jitter, never backwards
    recv = np.concatenate([t["_recv_us"] for t in log.values()])
    assert np.all(np.diff(np.sort(recv)) >= 0)
    lat = att["_recv_us"] - EPOCH_US - (fl.t_s[i] - fl.t_s[0]) * 1e6
    assert lat.min() > 10_000 and np.std(lat) > 1_000


# --------------------------------------------------------------------------- mavsid readers


def _compare_tables(ours, ref: dict[str, dict[str, np.ndarray]], skip=()) -> int:
    """Field-by-field equality of mavsid's RawLog against pymavlink; returns fields compared."""
    compared = 0
    for name, fields in ref.items():
        if name in skip:
            continue
        table = ours[name]
        for field, want in fields.items():
            if field.startswith("_"):
                continue
            got = table[field]
            assert len(got) == len(want), f"{name}.{field}"
            if want.dtype.kind in "fiub":
                np.testing.assert_array_equal(np.asarray(got, dtype=float),
                                              want.astype(float), err_msg=f"{name}.{field}")
            else:
                assert [str(x) for x in got] == [str(x) for x in want], f"{name}.{field}"
            compared += 1
    return compared


@pytest.mark.slow
@pytest.mark.parametrize("name", FIXTURE_LOGS)
def test_fixtures_read_alike_by_pymavlink_and_mavsid(name):
    """Every committed fixture: pymavlink decodes it, mavsid's reader agrees on every value,
    and it is small enough to ship."""
    path = FIXTURES / name
    assert path.stat().st_size <= 1_000_000
    ref = pymavlink_bin(path) if path.suffix == ".bin" else pymavlink_tlog(path)
    ours = read_log(path)
    assert ours.source.skipped_bytes == 0
    assert _compare_tables(ours, ref) > 50
    if path.suffix == ".bin":
        np.testing.assert_array_equal(ours["RATE"].time_s, ref["RATE"]["TimeUS"] * 1e-6)
        assert ours.firmware and ours.firmware.startswith("ArduCopter V4")
    truth = json.loads((FIXTURES / (path.stem + ".truth.json")).read_text())
    assert name in truth["logs"]


def test_short_logs_read_alike(short, short_bin, short_tlog):
    _, bin_path, tlog_path = short
    assert _compare_tables(read_log(bin_path), short_bin) > 100
    ours = read_log(tlog_path)
    assert _compare_tables(ours, short_tlog) > 50
    np.testing.assert_allclose(ours["ATTITUDE"]["_recv_time_s"],
                               short_tlog["ATTITUDE"]["_recv_us"] * 1e-6, rtol=0, atol=2e-6)


# --------------------------------------------------------------------------- the plant


def resimulate(u: np.ndarray, p: PlantParams, axis: int, dt: float, sub: int = 1) -> np.ndarray:
    """Independent re-simulation with scipy: u (loop rate) -> delay -> motor lag ->
    b/(s + d) -> 2nd-order Butterworth at the gyro filter cutoff. ``sub`` substeps per loop
    step let the delay be a multiple of dt/sub."""
    b, d, tau = p.effectiveness[axis], p.damping[axis], p.motor_tau_s
    num, den = [b], (np.polymul([tau, 1.0], [1.0, d]) if tau > 0 else [1.0, d])
    h = dt / sub
    bz, az, _ = signal.cont2discrete((num, den), h, method="zoh")
    delay = round(p.delay_s / h)
    assert abs(delay * h - p.delay_s) < 1e-12
    us = np.repeat(u, sub)
    us = np.concatenate([np.zeros(delay), us[: len(us) - delay]])
    rate = signal.lfilter(np.ravel(bz), az, us)[::sub]
    fb, fa = signal.butter(2, p.gyro_filter_hz, fs=1.0 / dt)
    return signal.lfilter(fb, fa, rate)


@pytest.mark.slow
@pytest.mark.parametrize("delay_s", [0.005, 0.00375])
def test_logged_rates_obey_the_plant(tmp_path, delay_s):
    """Noiseless: re-simulating the plant from the logged RATE.*Out reproduces RATE.R/P/Y
    (also with a delay that is not a whole number of loop steps)."""
    plant = replace(PlantParams().scaled_noise(0.0), delay_s=delay_s)
    sc = Scenario(sysid=(replace(SHORT_SID, axis=10),), plant=plant, seed=5,
                  hover_before_s=0.5, hover_after_s=0.5)
    simulate(sc, [tmp_path / "a.bin"])
    rate = pymavlink_bin(tmp_path / "a.bin")["RATE"]
    for j, ax in enumerate("RPY"):
        u = rate[f"{ax}Out"].astype(float)
        want = np.degrees(resimulate(u, plant, j, DT, sub=4))
        got = rate[ax].astype(float)
        scale = max(np.abs(got).max(), 1e-3)
        assert np.abs(got - want).max() < 1e-4 * scale + 1e-5, ax
    assert np.abs(rate["R"]).max() > 5.0  # the roll chirp moved the vehicle


@pytest.mark.slow
@settings(max_examples=6, deadline=None, derandomize=True)
@given(
    damping=st.tuples(*[st.floats(0.5, 10.0)] * 3),
    effectiveness=st.tuples(st.floats(60.0, 250.0), st.floats(60.0, 250.0),
                            st.floats(8.0, 40.0)),
    motor_tau_s=st.sampled_from([0.0, 0.01, 0.025]),
    delay_steps=st.integers(0, 12),  # quarter loop steps
    gyro_filter_hz=st.floats(10.0, 80.0),
)
def test_any_plant_is_what_the_log_obeys(damping, effectiveness, motor_tau_s, delay_steps,
                                         gyro_filter_hz, tmp_path_factory):
    """Property: for any plant, the noiseless logged rates are the plant's response to the
    logged controller outputs (pilot random sticks on roll)."""
    plant = PlantParams(damping=damping, effectiveness=effectiveness, motor_tau_s=motor_tau_s,
                        delay_s=delay_steps * DT / 4, gyro_filter_hz=gyro_filter_hz,
                        gyro_noise=0.0, gyro_bias=(0.0, 0.0, 0.0), disturbance=0.0)
    sc = Scenario(manoeuvre="random", duration_s=3.0, hover_before_s=0.5, seed=2, plant=plant)
    path = tmp_path_factory.mktemp("prop") / "p.bin"
    res = simulate(sc, [path])
    assume(res.flight.truth()["saturated_fraction"] == 0.0)
    rate = pymavlink_bin(path)["RATE"]
    for j, ax in enumerate("RPY"):
        want = np.degrees(resimulate(rate[f"{ax}Out"].astype(float), plant, j, DT, sub=4))
        got = rate[ax].astype(float)
        assert np.abs(got - want).max() < 1e-4 * max(np.abs(got).max(), 1e-3) + 1e-5, ax


@pytest.mark.slow
def test_noisy_rates_obey_the_plant_within_noise(short, short_bin):
    """With sensor noise: the residual to the noiseless re-simulation is the filtered noise
    plus the gyro bias, of the size the truth declares."""
    fl, _, _ = short
    p = fl.scenario.plant
    rate = short_bin["RATE"]
    sc = replace(fl.scenario, plant=replace(p, disturbance=0.0))
    fl2 = fly(sc)  # same seed, no disturbance: the only difference from the model is noise
    u = fl2.u[:, 0]
    want = resimulate(u, p, 0, DT) + p.gyro_bias[0]
    resid = fl2.gyro[:, 0] - want
    fb, fa = signal.butter(2, p.gyro_filter_hz, fs=LOOP_HZ)
    _, h = signal.freqz(fb, fa, worN=4096)
    noise_gain = np.sqrt(np.mean(np.abs(h) ** 2))
    expected = p.gyro_noise * noise_gain
    assert 0.7 * expected < np.std(resid[200:]) < 1.3 * expected
    assert abs(np.mean(resid[200:])) < 3 * expected
    assert len(rate["R"]) == len(fl)


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.corrcoef(a, b)[0, 1])


@pytest.mark.slow
@pytest.mark.parametrize("sid_axis", [1, 2, 3, 4, 7, 8, 9, 10, 11, 12, 13])
def test_injection_points(sid_axis):
    """SID_AXIS puts the waveform where ArduPilot does: angle target (deg), rate target
    (deg/s), mixer input (0-1) or throttle; nowhere else."""
    s = SysIdSettings(axis=sid_axis, magnitude=0.05 if sid_axis >= 10 else 5.0,
                      f_start_hz=1.0, f_stop_hz=5.0, t_fade_in=0.5, t_rec=4.0, t_fade_out=0.5)
    fl = fly(Scenario(sysid=(s,), hover_before_s=0.2, hover_after_s=0.2, seed=1,
                      plant=PlantParams().scaled_noise(0.0)))
    on = fl.mode == MODE_SYSTEMID
    targ = fl.sid_targ[on]
    ax = (sid_axis - 1) % 3
    if sid_axis == 13:
        np.testing.assert_allclose(fl.throttle[on], fl.scenario.plant.hover_throttle + targ)
        return
    if sid_axis in (1, 2, 3, 4):  # desired angle (deg), for yaw the desired rate (deg/s)
        np.testing.assert_allclose(np.degrees(fl.desired[on, ax]), targ, atol=1e-12)
    elif sid_axis in (7, 8, 9):  # added to the rate target (deg/s)
        assert _corr(np.degrees(fl.rate_target[on, ax]), targ) > 0.8
    else:  # added to the rate controller's output
        np.testing.assert_allclose(fl.u[on, ax] - fl.pid_out[on, ax], targ, atol=1e-12)
    if sid_axis in (1, 2, 4):  # the shaped angle target follows it (ATC_INPUT_TC)
        assert _corr(np.degrees(fl.attitude_target[on, ax]), targ) > 0.5
    others = [j for j in range(3) if j != ax]
    for j in others:  # no cross coupling in the default plant: other axes stay quiet
        assert np.abs(np.degrees(fl.rate_true[on, j])).max() < 0.05
    assert np.abs(np.degrees(fl.rate_true[on, ax])).max() > 1.0


def test_cross_coupling_moves_the_other_axis():
    coupling = ((0.0, 0.0, 0.0), (20.0, 0.0, 0.0), (0.0, 0.0, 0.0))  # roll input -> pitch
    plant = replace(PlantParams().scaled_noise(0.0), coupling=coupling)
    s = replace(SHORT_SID, t_rec=3.0, f_start_hz=2.0)
    fl = fly(Scenario(sysid=(s,), plant=plant, hover_before_s=0.2, hover_after_s=0.2))
    q = fl.rate_true[:, 1]
    assert np.abs(q).max() > 0.002
    # pitch rate obeys q' = -d q + b m_pitch + c m_roll: re-simulate from the realised inputs
    assert _corr(q, signal.lfilter(*_first_order(plant, 0), fl.u_eff[:, 0])) > 0.5
    truth = fl.truth()
    assert truth["axes"]["pitch"]["coupling"] == {"roll": 20.0}


def _first_order(p: PlantParams, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """ZOH-discretised lag + first-order rate response at the loop rate (no delay)."""
    num, den = [1.0], np.polymul([p.motor_tau_s, 1.0], [1.0, p.damping[axis]])
    bz, az, _ = signal.cont2discrete((num, den), DT, method="zoh")
    return np.ravel(bz), az


def test_gyro_filter_is_butterworth():
    from mavsid.synthetic.plant import lowpass2p_coefficients

    b, a = lowpass2p_coefficients(20.0, 400.0)
    sb, sa = signal.butter(2, 20.0, fs=400.0)
    np.testing.assert_allclose(b, sb, rtol=1e-12)
    np.testing.assert_allclose(a, sa, rtol=1e-12)


def test_truth_sidecar(short):
    fl, bin_path, _ = short
    truth = json.loads(bin_path.with_name("s.truth.json").read_text())
    p = fl.scenario.plant
    assert truth["logs"] == ["s.bin", "s.tlog"]
    for j, ax in enumerate(("roll", "pitch", "yaw")):
        t = truth["axes"][ax]
        assert (t["damping"], t["effectiveness"], t["delay_s"]) == (
            p.damping[j], p.effectiveness[j], p.delay_s)
        assert t["motor_tau_s"] == p.motor_tau_s and t["gyro_filter_hz"] == p.gyro_filter_hz
        assert set(t["units"]) >= {"damping", "effectiveness", "delay_s"}
    assert "FILTERED" in truth["logged_rate"]
    assert truth["gyro_filter"]["cutoff_hz"] == 20.0
    run = truth["sysid_runs"][0]
    assert run["sid_axis"] == 10 and run["sweep_start_s"] - run["waveform_start_s"] == 2.0


# --------------------------------------------------------------------------- determinism, CLI


def test_same_seed_same_bytes(tmp_path):
    sc = Scenario(manoeuvre="random", duration_s=3.0, seed=7)
    a = simulate(sc, [tmp_path / "a.bin", tmp_path / "a.tlog"])
    b = simulate(sc, [tmp_path / "b.bin", tmp_path / "b.tlog"])
    assert (tmp_path / "a.bin").read_bytes() == (tmp_path / "b.bin").read_bytes()
    assert (tmp_path / "a.tlog").read_bytes() == (tmp_path / "b.tlog").read_bytes()
    c = simulate(replace(sc, seed=8), [tmp_path / "c.bin"])
    assert not np.array_equal(a.flight.gyro, c.flight.gyro)
    assert a.sizes == b.sizes


@pytest.mark.slow
@pytest.mark.parametrize("truth_file", sorted(p.name for p in FIXTURES.glob("*.truth.json")))
def test_fixture_regenerates_from_its_truth_command(tmp_path, monkeypatch, truth_file):
    """The command recorded in each truth file rewrites its logs byte for byte."""
    truth = json.loads((FIXTURES / truth_file).read_text())
    argv = truth["command"].split()[1:]
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 0
    for name in truth["logs"]:
        assert (tmp_path / name).read_bytes() == (FIXTURES / name).read_bytes(), name
    assert json.loads((tmp_path / truth_file).read_text()) == truth


def test_cli_errors(tmp_path, capsys):
    assert main(["simulate", "-o", str(tmp_path / "x.txt")]) == 1
    assert "x.txt" in capsys.readouterr().err
    assert main(["simulate", "-o", str(tmp_path / "x.bin"), "--sid-axis", "14"]) == 1
    assert main(["simulate", "-o", str(tmp_path / "x.bin"), "--manoeuvre", "doublet",
                 "--sid-axis", "10"]) == 1
    assert main(["simulate", "-o", str(tmp_path / "x.bin"), "--rate-hz", "300"]) == 1
    assert main(["simulate", "-o", str(tmp_path / "no" / "x.bin")]) == 1
    assert main(["simulate", "-o", str(tmp_path / "x.bin"), "--faults", "melt=1"]) == 1
    for bad in (["--seed", "-1"], ["--duration", "1e9"], ["--duration", "nan"],
                ["--noise", "-1"], ["--magnitude", "nan"], ["--t-rec", "nan"],
                ["--f-start", "0"], ["--rate-hz", "0"]):
        assert main(["simulate", "-o", str(tmp_path / "x.bin"), *bad]) == 1, bad
    with pytest.raises(SystemExit) as exc:
        main(["simulate", "-o", str(tmp_path / "x.bin"), "--manoeuvre", "loop"])
    assert exc.value.code == 2
    with pytest.raises(ConfigError):
        SysIdSettings(f_start_hz=0.1, t_rec=15.0)  # two cycles at 0.1 Hz take 20 s
    assert not list(tmp_path.iterdir())


def test_cli_writes_tlog_and_bin(tmp_path, capsys):
    out = tmp_path / "d.tlog"
    assert main(["simulate", "-o", str(out), "--manoeuvre", "3211", "--axis", "pitch",
                 "--duration", "4", "--seed", "2"]) == 0
    log = pymavlink_tlog(out)
    truth = json.loads((tmp_path / "d.truth.json").read_text())
    assert truth["manoeuvre"] == "3211" and truth["axis"] == "pitch" and truth["seed"] == 2
    assert truth["command"].startswith("mavsid simulate -o ")
    assert np.ptp(log["RC_CHANNELS"]["chan2_raw"]) > 100  # the pitch stick moved
    assert np.ptp(log["RC_CHANNELS"]["chan1_raw"]) == 0


@pytest.mark.slow
def test_multi_run_log(tmp_path):
    """Three SYSTEMID runs in one log: one SIDS and one STABILIZE -> SYSTEMID -> STABILIZE
    cycle each, every SIDD record inside its run's mode window."""
    from mavsid.synthetic.run import scenario_from_options

    sc = scenario_from_options(sid_axes=[10, 11, 12], f_start_hz=1.0, t_rec=4.0, seed=4,
                               rate_hz=100)
    res = simulate(sc, [tmp_path / "m.bin"])
    log = pymavlink_bin(tmp_path / "m.bin")
    assert log["SIDS"]["Ax"].tolist() == [10, 11, 12]
    assert log["SIDS"]["Mag"].tolist() == pytest.approx([0.05, 0.05, 0.1])
    assert log["MODE"]["Mode"].tolist() == [0, 25, 0, 25, 0, 25, 0]
    runs = json.loads((tmp_path / "m.truth.json").read_text())["sysid_runs"]
    t = log["SIDD"]["TimeUS"] * 1e-6
    inside = np.zeros(len(t), dtype=bool)
    for run, t_sids in zip(runs, log["SIDS"]["TimeUS"] * 1e-6, strict=True):
        assert run["mode_enter_s"] == pytest.approx(t_sids, abs=1e-6)
        inside |= (t >= run["mode_enter_s"] - 1e-9) & (t <= run["mode_exit_s"] + 1e-9)
    assert inside.all()
    assert [r["axis"] for r in runs] == ["roll", "pitch", "yaw"]
    assert res.flight.scenario.runs[2].magnitude == 0.1
    with pytest.raises(ConfigError, match="duration"):
        scenario_from_options(sid_axes=[10], duration_s=10.0)


@pytest.mark.parametrize(("option", "value"), [("gyro_noise_dps", math.inf),
                                             ("gyro_noise_dps", -1.0),
                                             ("vibration_dps", math.nan),
                                             ("vibration_dps", math.inf)])
def test_noise_that_is_not_a_finite_amount_is_refused(option, value):
    """``--gyro-noise inf`` wrote a log of infinite gyro readings and its truth."""
    from mavsid.synthetic.run import scenario_from_options

    with pytest.raises(ConfigError, match="must be a finite number >= 0 deg/s"):
        scenario_from_options(**{option: value})


# --------------------------------------------------------------------------- faults


@pytest.mark.slow
def test_faults(tmp_path):
    sc = Scenario(manoeuvre="doublet", duration_s=4.0, seed=3, rates=LogRates(rate=100))
    clean = simulate(sc, [tmp_path / "c.bin", tmp_path / "c.tlog"])
    ref = pymavlink_bin(tmp_path / "c.bin")
    n_rate = len(ref["RATE"]["TimeUS"])
    simulate(sc, [tmp_path / "d.bin", tmp_path / "d.tlog"], Faults(drop_fraction=0.1, seed=1))
    dropped = pymavlink_bin(tmp_path / "d.bin")
    assert 0.8 * n_rate < len(dropped["RATE"]["TimeUS"]) < 0.97 * n_rate
    assert set(dropped["RATE"]["TimeUS"]) <= set(ref["RATE"]["TimeUS"])
    tl = pymavlink_tlog(tmp_path / "d.tlog")
    assert len(tl["ATTITUDE"]["time_boot_ms"]) < len(pymavlink_tlog(tmp_path / "c.tlog")[
        "ATTITUDE"]["time_boot_ms"])
    # reboot: time restarts at 5 s, headers repeated
    simulate(sc, [tmp_path / "r.bin", tmp_path / "r.tlog"], Faults(reboot_at_s=2.0))
    rb = pymavlink_bin(tmp_path / "r.bin")
    t = rb["RATE"]["TimeUS"]
    assert np.sum(np.diff(t) < 0) == 1 and t.min() == 5_000_000
    assert len(rb["PARM"]["Name"]) == 2 * len(clean.flight.params())
    ms = pymavlink_tlog(tmp_path / "r.tlog")["ATTITUDE"]["time_boot_ms"]
    assert np.sum(np.diff(ms) < 0) == 1
    # truncated: all but the cut record decode; mavsid reads the rest and counts the bytes
    simulate(sc, [tmp_path / "t.bin", tmp_path / "t.tlog"], Faults(truncate_bytes=20))
    ref_t = pymavlink_tlog(tmp_path / "c.tlog")
    cut = pymavlink_tlog(tmp_path / "t.tlog")
    assert sum(len(v["_sysid"]) for v in cut.values()) == sum(
        len(v["_sysid"]) for v in ref_t.values()) - 1
    with pytest.warns(Warning):
        ours_t = read_log(tmp_path / "t.tlog")
    assert _compare_tables(ours_t, cut) > 50
    assert (tmp_path / "t.bin").stat().st_size == (tmp_path / "c.bin").stat().st_size - 20
    with pytest.warns(Warning):
        ours = read_log(tmp_path / "t.bin")
    assert ours.source.skipped_bytes > 0
    assert len(ours["RATE"]) >= n_rate - 1


def test_discretisation_is_scipys_zero_order_hold():
    """The simulator's plants held over a step (mavsid.numerics.lti.c2d) against scipy's
    cont2discrete and the textbook exp([[A, B], [0, 0]] t), within 1e-12."""
    from scipy.linalg import expm
    from scipy.signal import cont2discrete

    from mavsid.numerics.lti import c2d
    from mavsid.synthetic.plant import VEHICLES

    for p in VEHICLES.values():
        a, b, _ = p.continuous()
        n, m = b.shape
        for t in (DT, 0.3 * DT, 0.01):
            big = np.zeros((n + m, n + m))
            big[:n, :n], big[:n, n:] = a, b
            ref = expm(big * t)
            phi, gamma = c2d(a, b, t)
            np.testing.assert_allclose(phi, ref[:n, :n], rtol=0, atol=1e-12)
            np.testing.assert_allclose(gamma, ref[:n, n:], rtol=0, atol=1e-12)
            sp_phi, sp_gamma, *_ = cont2discrete((a, b, np.eye(n), np.zeros((n, m))), t)
            np.testing.assert_allclose(phi, sp_phi, rtol=0, atol=1e-12)
            np.testing.assert_allclose(gamma, sp_gamma, rtol=0, atol=1e-12)


@pytest.mark.parametrize(("cutoff", "fs"), [(20.0, 400.0), (15.0, 400.0), (80.0, 1000.0)])
def test_gyro_filter_matches_the_prewarped_bilinear_formula(cutoff, fs):
    """ArduPilot's LowPassFilter2p coefficients written out (bilinear, pre-warped)."""
    from mavsid.synthetic.plant import lowpass2p_coefficients

    ohm = np.tan(np.pi * cutoff / fs)
    c = 1.0 + 2.0 * np.cos(np.pi / 4) * ohm + ohm * ohm
    b0 = ohm * ohm / c
    ref_a = [1.0, 2.0 * (ohm * ohm - 1.0) / c, (1.0 - 2.0 * np.cos(np.pi / 4) * ohm + ohm**2) / c]
    b, a = lowpass2p_coefficients(cutoff, fs)
    np.testing.assert_allclose(b, [b0, 2 * b0, b0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(a, ref_a, rtol=0, atol=1e-12)


@pytest.mark.parametrize("vehicle", ["quad", "heavy-x", "hexa"])
def test_vehicles_with_a_noisy_vibrating_gyro(vehicle):
    from mavsid.synthetic.plant import VEHICLES
    from mavsid.synthetic.run import scenario_from_options

    sc = scenario_from_options(manoeuvre="hover", duration_s=4.0, vehicle=vehicle,
                               gyro_noise_dps=3.0, vibration_dps=2.0, seed=2)
    assert sc.plant.effectiveness == VEHICLES[vehicle].effectiveness
    fl = fly(sc)
    err = fl.gyro_raw - fl.rate_true - np.array(sc.plant.gyro_bias)
    f, pxx = signal.welch(err[:, 0], fs=LOOP_HZ, nperseg=400)
    # white part: 3 deg/s; vibration: a sine of 2 deg/s amplitude at 170 Hz
    assert f[np.argmax(pxx)] == pytest.approx(170.0, abs=1.0)
    total = np.degrees(np.std(err, axis=0))
    np.testing.assert_allclose(total, np.sqrt(3.0**2 + 2.0**2 / 2), rtol=0.05)
    # the controller sees it: its output moves with the noise (fed back), hover or not
    assert np.std(fl.pid_out[:, 0]) > 0.002


def test_slow_logs_log_everything_slowly(tmp_path):
    from mavsid.synthetic.run import scenario_from_options

    sc = scenario_from_options(rate_hz=10.0)
    assert (sc.rates.rate, sc.rates.att, sc.rates.rcou) == (10.0, 10.0, 10.0)
    with pytest.raises(ConfigError, match="--vehicle"):
        scenario_from_options(vehicle="octo")


def test_an_unknown_frame_is_a_config_error():
    from mavsid.errors import ConfigError

    with pytest.raises(ConfigError, match="frame must be one of quad-x, hexa-x"):
        Scenario(frame="tri")
