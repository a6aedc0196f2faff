"""RawLog -> FlightData (mavsid.align): properties on hand-built logs, references on real ones."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from helpers import FIXTURES, ids, require_shared, shared_logs, shared_path
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mavsid.align import MAX_GAP_SAMPLES, align, load_flight, sysid_runs
from mavsid.autopilot.presets import Channel, Preset
from mavsid.data import MessageTable, ModeChange, RawLog, SourceInfo
from mavsid.errors import DataQualityWarning, MavsidError
from mavsid.readers import read_log

# --------------------------------------------------------------------------- properties

_PRESET = Preset(
    "test", (), states={"p": Channel("S", "x", "rad/s"), "q": Channel("S", "y", "rad/s")},
    inputs={"u_roll": Channel("U", "v")},
)


@st.composite
def _times(draw, max_n: int = 150):
    """Sample times with jitter and a few long pauses (gaps)."""
    n = draw(st.integers(20, max_n))
    dt = draw(st.floats(0.002, 0.05))
    jitter = draw(st.floats(0.0, 0.3))
    rng = np.random.default_rng(draw(st.integers(0, 2**31)))
    steps = dt * (1 + jitter * rng.uniform(-1, 1, n - 1))
    for _ in range(draw(st.integers(0, 3))):
        steps[rng.integers(0, n - 1)] += dt * draw(st.floats(6.0, 60.0))
    t0 = draw(st.floats(0.0, 2.0))
    return t0 + np.concatenate([[0.0], np.cumsum(steps)]), rng


def _raw(ts, tu, rng) -> RawLog:
    s = MessageTable("S", {"x": rng.standard_normal(ts.size), "y": rng.standard_normal(ts.size)},
                     time_s=ts)
    u = MessageTable("U", {"v": np.round(rng.standard_normal(tu.size), 3)}, time_s=tu)
    return RawLog(SourceInfo("h.bin", "dataflash", 0), {"S": s, "U": u})


def _gaps(t: np.ndarray) -> np.ndarray:
    d = np.diff(t)
    i = np.flatnonzero(d > MAX_GAP_SAMPLES * np.median(d))
    return np.column_stack([t[i], t[i + 1]])


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_times(), _times(60))
def test_alignment_properties(states, inputs):
    (ts, rng), (tu, _) = states, inputs
    tu = tu - tu[0] + ts[0] - 0.01  # overlapping spans
    raw = _raw(ts, tu, rng)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataQualityWarning)
        try:
            fd = align(raw, _PRESET)
        except MavsidError:
            return  # nothing overlaps for two samples: a typed error is the right answer
    t, b = fd.time_s, fd.blocks
    # blocks partition the samples, in order
    assert b[0, 0] == 0 and b[-1, 1] == t.size and np.all(b[1:, 0] == b[:-1, 1])
    assert np.all(b[:, 1] - b[:, 0] >= 2)
    # strictly increasing everywhere, uniform within each block
    assert np.all(np.diff(t) > 0)
    for a, e in b:
        assert np.allclose(np.diff(t[a:e]), fd.dt, rtol=1e-9, atol=1e-9)
    # inputs are held, never interpolated: each value is the latest native sample at or before t
    v = raw["U"]["v"]
    for k in range(0, t.size, max(1, t.size // 40)):
        latest = np.flatnonzero(tu <= t[k] + 1e-6 * fd.dt).max()
        assert fd.inputs[k, 0] == v[latest]
    # states interpolate between their two bracketing samples
    x = raw["S"]["x"]
    i = np.searchsorted(ts, t, side="right") - 1
    j = np.minimum(i + 1, ts.size - 1)
    lo, hi = np.minimum(x[i], x[j]), np.maximum(x[i], x[j])
    assert np.all(fd.states[:, 0] >= lo - 1e-12) and np.all(fd.states[:, 0] <= hi + 1e-12)
    # no grid point inside a gap of any channel, and no block spans one
    for g in (_gaps(ts), _gaps(tu)):
        for g0, g1 in g:
            assert not np.any((t > g0) & (t < g1))
            for a, e in b:
                assert not np.any((t[a:e - 1] < g0) & (t[a + 1:e] > g0))


def test_yaw_unwrapped_units_converted_and_flags():
    t = np.arange(0, 10, 0.01)
    yaw = np.mod(350 + 5 * t, 360)  # crosses 360 -> 0 at t = 2 s
    att = MessageTable("ATT", {"Roll": np.full(t.size, 10.0), "Pitch": np.zeros(t.size),
                               "Yaw": yaw}, time_s=t, units={"Roll": "deg"})
    rate = MessageTable("RATE", {"R": np.full(t.size, 90.0), "P": np.zeros(t.size),
                                 "Y": np.zeros(t.size), "ROut": np.sin(t), "POut": t * 0,
                                 "YOut": t * 0}, time_s=t)
    ev = MessageTable("EV", {"Id": np.array([10, 28, 18, 11])},
                      time_s=np.array([1.0, 2.0, 8.0, 9.0]))
    raw = RawLog(SourceInfo("a.bin", "dataflash", 0), {"ATT": att, "RATE": rate, "EV": ev},
                 modes=(ModeChange(0.5, 0, "STABILIZE"), ModeChange(5.0, 25, "SYSTEMID")))
    fd = align(raw)
    col = {n: fd.states[:, i] for i, n in enumerate(fd.state_names)}
    assert fd.preset == "ardupilot-rate" and fd.input_names == ("u_roll", "u_pitch", "u_yaw")
    assert np.allclose(col["roll"], np.radians(10)) and np.allclose(col["p"], np.pi / 2)
    assert np.all(np.abs(np.diff(col["yaw"])) < np.radians(1))
    assert np.isclose(col["yaw"][-1] - col["yaw"][0], np.radians(5 * (t[-1] - t[0])))
    tt, f = fd.time_s, fd.flags
    assert np.array_equal(f["armed"], (tt >= 1.0) & (tt < 9.0))
    assert np.array_equal(f["airborne"], (tt >= 2.0) & (tt < 8.0))
    assert np.array_equal(f["mode"], np.where(tt < 0.5, -1, np.where(tt < 5.0, 0, 25)))


def test_slow_input_warns_with_message_and_rate():
    t = np.arange(0, 10, 0.0025)
    tr = np.arange(0, 10, 0.1)
    att = MessageTable("ATT", {k: np.zeros(t.size) for k in ("Roll", "Pitch", "Yaw")}, time_s=t)
    imu = MessageTable("IMU", {k: np.zeros(t.size) for k in ("GyrX", "GyrY", "GyrZ")}, time_s=t)
    rcou = MessageTable("RCOU", {f"C{i}": np.full(tr.size, 1500.0) for i in range(1, 9)},
                        time_s=tr)
    raw = RawLog(SourceInfo("b.bin", "dataflash", 0), {"ATT": att, "IMU": imu, "RCOU": rcou},
                 params={"FRAME_CLASS": 1.0, "FRAME_TYPE": 1.0})
    with pytest.warns(DataQualityWarning, match=r"RCOU .*10\.0 Hz"):
        fd = align(raw)
    assert fd.preset == "ardupilot-rcou" and fd.mixer == "quad-x"
    assert np.isclose(1 / fd.dt, 400.0)


def test_no_overlap_is_a_typed_error():
    s = MessageTable("S", {"x": np.zeros(5), "y": np.zeros(5)}, time_s=np.arange(5.0))
    u = MessageTable("U", {"v": np.zeros(5)}, time_s=np.arange(5.0) + 100)
    raw = RawLog(SourceInfo("c.bin", "dataflash", 0), {"S": s, "U": u})
    with pytest.raises(MavsidError, match="never overlap"):
        align(raw, _PRESET)


@pytest.mark.parametrize(("rate_hz", "match"), [
    (0.01, r"a grid step of 100 s \(rate_hz 0.01\) is longer than the 4 s the channels share"),
    (1e9, r"a grid step of 1e-09 s gives .* choose a lower rate_hz"),
])
def test_a_grid_rate_the_data_cannot_hold_is_named(rate_hz, match):
    """A grid step longer than the data said "the channels never overlap"; a very fine one
    is refused before it is allocated."""
    s = MessageTable("S", {"x": np.zeros(5), "y": np.zeros(5)}, time_s=np.arange(5.0))
    u = MessageTable("U", {"v": np.zeros(5)}, time_s=np.arange(5.0))
    raw = RawLog(SourceInfo("c.bin", "dataflash", 0), {"S": s, "U": u})
    with pytest.raises(MavsidError, match="c.bin: " + match):
        align(raw, _PRESET, rate_hz=rate_hz)


# --------------------------------------------------------------------------- references


@pytest.fixture(scope="module")
def doublets_rate():
    """pymavlink's RATE records of the simulated doublets log: (time_s, R deg/s, ROut)."""
    from pymavlink import mavutil

    path = FIXTURES / "doublets.bin"
    if not path.exists():
        pytest.skip("fixtures/doublets.bin not generated")
    m = mavutil.mavlink_connection(str(path))
    rows = []
    while (msg := m.recv_match(type="RATE")) is not None:
        rows.append((msg.TimeUS * 1e-6, msg.R, msg.ROut))
    m.close()
    return path, np.array(rows)


def test_dataflash_values_match_pymavlink(doublets_rate):
    path, ref = doublets_rate
    fd = load_flight(path)
    p = fd.states[:, fd.state_names.index("p")]
    assert np.allclose(p, np.interp(fd.time_s, ref[:, 0], np.radians(ref[:, 1])), atol=1e-6)
    # zero-order hold: the ROut of the latest RATE record at or before each grid time
    k = np.searchsorted(ref[:, 0], fd.time_s + 1e-6 * fd.dt, side="right") - 1
    assert np.allclose(fd.inputs[:, fd.input_names.index("u_roll")], ref[k, 2], atol=1e-7)


def test_sysid_injection_is_pymavlinks_sidd_held_and_nan_where_not_logged():
    """A direct alignment gives the waveform the fit uses: each grid point the Targ of
    pymavlink's latest SIDD record at or before it, NaN where none lies within two record
    steps (between the runs, where SIDD is not logged); and the inputs interpolated
    between the RATE records the grid holds."""
    from pymavlink import mavutil

    path = FIXTURES / "sysid_roll.bin"
    if not path.exists():
        pytest.skip("fixtures/sysid_roll.bin not generated")
    m = mavutil.mavlink_connection(str(path))
    sidd, rate = [], []
    while (msg := m.recv_match(type=["SIDD", "RATE"])) is not None:
        (sidd if msg.get_type() == "SIDD" else rate).append(
            (msg.TimeUS * 1e-6, msg.Targ if msg.get_type() == "SIDD" else msg.ROut))
    m.close()
    ts, targ = np.array(sidd).T
    fd = load_flight(path)
    t = fd.time_s
    k = np.searchsorted(ts, t + 1e-6 * fd.dt, side="right") - 1
    known = (k >= 0) & (t - ts[k.clip(0)] <= 2 * max(np.median(np.diff(ts)), fd.dt))
    assert 0 < known.sum() < t.size  # the runs, and the flight around them
    inj = fd.sysid_injection
    assert np.array_equal(np.isnan(inj), ~known)
    assert np.allclose(inj[known], targ[k[known]], atol=1e-7)
    tr, rout = np.array(rate).T
    held = np.unique(np.searchsorted(tr, t + 1e-6 * fd.dt, side="right") - 1)
    assert np.allclose(fd.inputs_at_state_times["u_roll"], np.interp(t, tr[held], rout[held]),
                       atol=1e-7)


def test_extract_aligned_writes_flightdata(doublets_rate, tmp_path, capsys):
    import pandas as pd

    from mavsid.cli import main

    path, ref = doublets_rate
    out = tmp_path / "fd.parquet"
    assert main(["extract", str(path), "--aligned", "--start", "35", "--stop", "40",
                 "-o", str(out)]) == 0
    assert "FlightData" in capsys.readouterr().out
    d = pd.read_parquet(out)
    assert {"time_s", "roll", "p", "u_roll", "armed", "airborne", "mode", "block"} <= set(d)
    assert d.time_s.min() >= 35 and d.time_s.max() <= 40 and len(d) > 1900
    assert np.allclose(d.p, np.interp(d.time_s, ref[:, 0], np.radians(ref[:, 1])), atol=1e-6)


def test_px4_attitude_and_rates_match_pyulog():
    from pyulog import ULog
    from scipy.spatial.transform import Rotation

    path = shared_path("public", "Auterion__px4-ulog-rs", "quadrotor_local.ulg")
    fd = load_flight(path)
    u = ULog(str(path), ["vehicle_attitude", "vehicle_angular_velocity"])
    att = u.get_dataset("vehicle_attitude").data
    av = u.get_dataset("vehicle_angular_velocity").data
    ta = att["timestamp_sample"] * 1e-6
    q = np.column_stack([att[f"q[{i}]"] for i in (1, 2, 3, 0)])  # scipy wants x y z w
    eul = Rotation.from_quat(q).as_euler("ZYX")  # yaw, pitch, roll
    col = {n: fd.states[:, i] for i, n in enumerate(fd.state_names)}
    assert np.allclose(col["roll"], np.interp(fd.time_s, ta, eul[:, 2]), atol=1e-6)
    assert np.allclose(col["pitch"], np.interp(fd.time_s, ta, eul[:, 1]), atol=1e-6)
    assert np.allclose(col["yaw"], np.interp(fd.time_s, ta, np.unwrap(eul[:, 0])), atol=1e-6)
    tv = av["timestamp_sample"] * 1e-6
    assert np.allclose(col["q"], np.interp(fd.time_s, tv, av["xyz[1]"]), atol=1e-6)
    assert fd.preset == "px4-torque"


@pytest.fixture(scope="module")
def sitl_pair():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataQualityWarning)
        return (load_flight(shared_path("sitl", "flightA_mixer.BIN")),
                load_flight(shared_path("sitl", "flightA_mixer.tlog")))


@pytest.mark.slow
@pytest.mark.parametrize(("name", "lo", "hi"),
                         [("u_roll", 88, 118), ("u_pitch", 174, 204), ("u_yaw", 260, 290)])
def test_tlog_mixer_inputs_match_dataflash_rate_outputs(sitl_pair, name, lo, hi):
    # the same flight: SERVO_OUTPUT_RAW PWMs through the quad-plus mixer (tlog) against the
    # rate controller's own RATE.ROut/POut/YOut (DataFlash), over the first 30 s of each chirp
    binf, tlog = sitl_pair
    assert tlog.mixer == "quad-plus"  # FRAME_CLASS 1, FRAME_TYPE 0 (README: + frame)
    sel = (tlog.time_s > lo) & (tlog.time_s < hi)
    ut = tlog.inputs[sel, tlog.input_names.index(name)]
    ub = np.interp(tlog.time_s[sel], binf.time_s, binf.inputs[:, binf.input_names.index(name)])
    assert np.corrcoef(ut, ub)[0, 1] > 0.95
    slope = np.polyfit(ub, ut, 1)[0]
    assert 0.9 < slope < 1.2


@pytest.mark.slow
def test_sitl_sysid_runs_from_sids(sitl_pair):
    # README: SID_AXIS 10, 11, 12, 13 entered at about 87, 173, 258 and 344 s; SID_T_REC 60 s,
    # injection 1 s (ArduCopter's SYSTEM_ID_DELAY) after entering the mode
    for fd in sitl_pair:
        runs = fd.sysid_runs
        assert [r.axis for r in runs] == [10, 11, 12, 13]
        for r, enter in zip(runs, (87, 173, 258, 344), strict=True):
            assert abs(r.start_s - (enter + 1)) < 1.0
            assert abs(r.stop_s - r.start_s - 60.0) < 0.2
            assert r.t_record_s == 60.0 and r.f_stop_hz == 20.0
        assert fd.params["INS_GYRO_FILTER"] == 20.0


def test_systemid_mode_with_sidd_but_no_sids_is_a_run_that_injected_nothing(tmp_path):
    """SYSTEMID flown, SIDD logged with its waveform zero, no SIDS: one run over the stay in
    the mode, its settings from the parameters, marked as having injected nothing."""
    from helpers import write_systemid_without_injection

    from mavsid import read_log

    raw = read_log(write_systemid_without_injection(tmp_path / "quiet.bin"))
    assert "SIDS" not in raw.messages and len(raw.messages["SIDD"]) > 1000
    enter = next(m.time_s for m in raw.modes if m.name == "SYSTEMID")
    runs = sysid_runs(raw)
    assert len(runs) == 1, runs
    run = runs[0]
    assert run.injected is False and run.settings_from == "PARM"
    assert run.axis == 1 and run.magnitude == pytest.approx(0.15)
    assert run.start_s == pytest.approx(enter) and run.stop_s - enter == pytest.approx(
        9.6, abs=0.01)


def test_sysid_runs_absent_without_systemid():
    raw = RawLog(SourceInfo("d.bin", "dataflash", 0), {}, modes=(ModeChange(1.0, 0, "STAB"),))
    assert sysid_runs(raw) == ()


_LOGS = shared_logs(".bin", ".log", ".tlog", ".ulg")


@pytest.mark.slow
@pytest.mark.parametrize("path", _LOGS, ids=ids(_LOGS))
def test_every_shared_log_aligns_or_gives_a_typed_error(path):
    require_shared()
    if path.stat().st_size > 50e6:
        pytest.skip("the big SITL log is covered by the sitl_pair tests")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            fd = load_flight(path)
        except MavsidError:
            return
    assert fd.time_s.size >= 2 and np.all(np.isfinite(fd.states))
    assert np.all(np.isfinite(fd.inputs))
    assert set(fd.flags) == {"armed", "airborne", "mode"}


def test_servo_outputs_of_a_plane_are_not_unmixed():
    t = np.arange(0, 5, 0.02)
    att = MessageTable("ATTITUDE", {k: np.zeros(t.size) for k in (
        "roll", "pitch", "yaw", "rollspeed", "pitchspeed", "yawspeed")}, time_s=t)
    servo = MessageTable("SERVO_OUTPUT_RAW", {f"servo{i}_raw": np.full(t.size, 1500.0)
                                              for i in range(1, 9)}, time_s=t)
    raw = RawLog(SourceInfo("p.tlog", "tlog", 0), {"ATTITUDE": att, "SERVO_OUTPUT_RAW": servo},
                 vehicle="plane")
    with pytest.warns(DataQualityWarning, match="plane"):
        fd = align(raw)
    assert fd.input_names == () and fd.inputs.shape == (t.size, 0)
    copter = RawLog(raw.source, raw.messages, vehicle="copter QUAD/X")
    with pytest.warns(DataQualityWarning, match="no frame parameters .* quad-x"):
        assert align(copter).input_names == ("u_roll", "u_pitch", "u_yaw", "u_thrust")


def test_reboot_keeps_the_longest_boot_only():
    # boot 1 runs 10..20 s with roll 5 deg, boot 2 restarts the clock at 5 s (5..12 s, roll
    # -5 deg); the time ranges overlap, so sorting alone would interleave two flights
    t1, t2 = np.arange(10, 20, 0.01), np.arange(5, 12, 0.01)
    t = np.concatenate([t1, t2])
    roll = np.concatenate([np.full(t1.size, 5.0), np.full(t2.size, -5.0)])
    att = MessageTable("ATT", {"Roll": roll, "Pitch": 0 * t, "Yaw": 0 * t}, time_s=t)
    rate = MessageTable("RATE", {k: 0 * t for k in ("R", "P", "Y", "ROut", "POut", "YOut")},
                        time_s=t)
    raw = RawLog(SourceInfo("r.bin", "dataflash", 0), {"ATT": att, "RATE": rate})
    with pytest.warns(DataQualityWarning, match=r"restarts 1 time.*boot 1 of 2"):
        fd = align(raw)
    assert np.all(np.diff(fd.time_s) > 0) and fd.time_s[0] >= 10 and fd.time_s[-1] < 20
    assert np.allclose(fd.states[:, fd.state_names.index("roll")], np.radians(5.0))


def test_the_command_and_the_injection_come_from_the_boot_used():
    """The commanded attitude (yaw: the commanded heading's rate) and SYSTEMID's injection
    are read from the records of the boot the grid is laid on, as the states are: sorted
    together, two boots whose clocks overlap (and whose stamps differ) interleave two
    flights, and a heading's rate taken across them is nonsense."""
    t1, t2 = np.arange(10, 20, 0.01), np.arange(5.005, 12, 0.01)
    t = np.concatenate([t1, t2])
    one, two = np.ones(t1.size), np.ones(t2.size)
    heading = np.concatenate([np.degrees(0.5 * t1), np.degrees(-1.0 * t2)]) % 360.0
    att = MessageTable("ATT", {"Roll": 0 * t, "Pitch": 0 * t, "Yaw": 0 * t,
                               "DesRoll": np.concatenate([5 * np.sin(t1), -5 * two]),
                               "DesYaw": heading}, time_s=t)
    rate = MessageTable("RATE", {k: 0 * t for k in ("R", "P", "Y", "ROut", "POut", "YOut")},
                        time_s=t)
    sidd = MessageTable("SIDD", {"Targ": np.concatenate([one, -two])}, time_s=t)
    raw = RawLog(SourceInfo("r.bin", "dataflash", 0), {"ATT": att, "RATE": rate, "SIDD": sidd})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fd = align(raw)
    assert any("boot 1 of 2" in str(w.message) for w in caught)
    cmd = fd.commanded
    np.testing.assert_allclose(cmd["roll"], np.radians(5 * np.sin(fd.time_s)), atol=1e-4)
    np.testing.assert_allclose(cmd["yaw"], 0.5, atol=1e-6)
    assert np.allclose(fd.sysid_injection, 1.0)


def test_sorted_unique_is_numpys_unique_on_overlapping_runs() -> None:
    """The grid's indices (ascending runs that overlap at their ends) made unique without
    numpy's hashing: the same as ``np.unique`` on 200 random sets of runs."""
    from mavsid.align.grid import sorted_unique

    rng = np.random.default_rng(5)
    for _ in range(200):
        runs = [np.arange(lo, lo + rng.integers(0, 40))
                for lo in np.cumsum(rng.integers(-3, 30, rng.integers(0, 12)))]
        x = np.concatenate([np.zeros(0, np.int64), *runs]).astype(np.int64)
        assert np.array_equal(sorted_unique(x), np.unique(x))


def _rc_log(autopilot: str, params: dict[str, float]) -> RawLog:
    """A MAVLink log of 20 s at 50 Hz: the roll stick (on channel 2) swings, the other
    channels hold at their centre, with ATTITUDE and SERVO_OUTPUT_RAW beside it."""
    t = np.arange(0, 20, 0.02)
    swing = np.round(1500 + 200 * np.sin(2 * np.pi * 0.7 * t))
    rc = MessageTable("RC_CHANNELS", {f"chan{i}_raw": swing if i == 2 else np.full(t.size, 1500.0)
                                      for i in range(1, 9)}, time_s=t)
    return RawLog(SourceInfo("x.tlog", "tlog", 0), {"RC_CHANNELS": rc}, params=params,
                  autopilot=autopilot)


def test_a_mavlink_logs_sticks_are_read_on_the_channels_the_autopilot_maps() -> None:
    """A .tlog has no commanded attitude: the pilot's sticks stand in (coherence and
    instruments need neither their scale nor their offset), on the RC channel the
    autopilot's parameters map to each axis, without the dead zone; a PX4 log that does not
    say its mapping gives none, as a channel out of range does."""
    from mavsid.align.commanded import pilot_sticks

    remapped = pilot_sticks(_rc_log("ardupilot", {"RCMAP_ROLL": 2.0, "RCMAP_PITCH": 1.0,
                                             "RC2_DZ": 20.0}))
    field, t, roll = remapped["roll"]
    assert field == "RC_CHANNELS.chan2_raw"
    want = np.round(200 * np.sin(2 * np.pi * 0.7 * t))
    np.testing.assert_allclose(roll, np.sign(want) * np.maximum(np.abs(want) - 20, 0))
    assert not np.ptp(remapped["pitch"][2]) and set(remapped) == {"roll", "pitch", "yaw"}
    assert not np.ptp(pilot_sticks(_rc_log("ardupilot", {}))["roll"][2])  # (default: channel 1)
    assert pilot_sticks(_rc_log("px4", {})) == {}
    px4 = pilot_sticks(_rc_log("px4", {"RC_MAP_ROLL": 2.0, "RC_MAP_YAW": 0.0}))
    assert set(px4) == {"roll"} and np.ptp(px4["roll"][2]) > 300
    assert "roll" not in pilot_sticks(_rc_log("ardupilot", {"RCMAP_ROLL": 19.0}))
    # MAVLink 1's RC_CHANNELS_RAW: channels 1-8 on port 0 (port 1 carries 9-16)
    old = _rc_log("ardupilot", {"RCMAP_ROLL": 2.0})
    table = old.messages.pop("RC_CHANNELS")
    port = np.arange(len(table)) % 2
    old.messages["RC_CHANNELS_RAW"] = MessageTable(
        "RC_CHANNELS_RAW", {**table.columns, "port": port}, time_s=table.time_s)
    field, t_old, _ = pilot_sticks(old)["roll"]
    assert field == "RC_CHANNELS_RAW.chan2_raw"
    np.testing.assert_array_equal(t_old, table.time_s[port == 0])
    # a second vehicle's sticks in the same telemetry are not the pilot's of the first
    two = _rc_log("ardupilot", {"RCMAP_ROLL": 2.0})
    table = two.messages["RC_CHANNELS"]
    ids = np.where(np.arange(len(table)) % 3 == 0, 2, 1)
    two.messages["RC_CHANNELS"] = MessageTable("RC_CHANNELS", {**table.columns, "_sysid": ids},
                                               time_s=table.time_s)
    np.testing.assert_array_equal(pilot_sticks(two)["roll"][1], table.time_s[ids == 1])


@pytest.mark.slow
def test_a_tlogs_commanded_attitude_follows_the_simulated_pilots_sticks(tmp_path: Path) -> None:
    """The same manual flight written as a .bin and as a .tlog: the .tlog's commanded roll
    (the stick, on the grid) follows the simulator's desired roll, in shape and timing."""
    from mavsid.synthetic.run import scenario_from_options, simulate

    sc = scenario_from_options(manoeuvre="3211", axis="roll", seed=4, duration_s=30.0)
    path = tmp_path / "stick.tlog"
    flight = simulate(sc, [path]).flight
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fd = load_flight(str(path))
    got = fd.commanded["roll"]
    assert fd.commanded_from["roll"] == "RC_CHANNELS.chan1_raw, the pilot's stick"
    want = np.interp(fd.time_s, flight.t_s, flight.desired[:, 0])
    ok = np.isfinite(got)
    assert ok.mean() > 0.9 and np.ptp(want) > 0.1
    assert np.corrcoef(got[ok], want[ok])[0, 1] > 0.99


def _text_sids_log(path: Path) -> Path:
    """A DataFlash log whose FMT declares SIDS.Mag as text (16 characters), with a SYSTEMID
    run's SIDD and the ATT and RATE records a fit reads (written with the project's own
    DataFlash writer)."""
    from mavsid.synthetic.dfwriter import DataFlashBuilder, MessageFormat

    b = DataFlashBuilder()
    b.define(b.formats["FMT"])
    sids = b.formats["SIDS"]
    for f in (b.formats["ATT"], b.formats["RATE"], b.formats["SIDD"], b.formats["MODE"],
              MessageFormat(sids.type_id, "SIDS", "QBNffffff", sids.columns)):
        b.define(f)
    t = np.arange(0, 20_000_000, 2_500)  # 20 s at 400 Hz
    chirp = 0.1 * np.sin(2 * np.pi * (0.5 + t / 4e6) * t / 1e6)
    b.add("ATT", t, Roll=np.zeros(t.size))
    b.add("RATE", t, R=chirp, ROut=chirp)
    b.add("MODE", [4_000_000], Mode=25, ModeNum=25)
    b.add("SIDS", [4_000_000], Ax=10, Mag=["0.1 oops"], FSt=0.5, FSp=10.0, TR=10.0)
    run = t[(t > 5_000_000) & (t < 15_000_000)]
    b.add("SIDD", run, Targ=0.1 * np.sin(run / 1e5))
    path.write_bytes(b.to_bytes())
    return path


def test_a_value_declared_as_text_is_refused_in_one_line(tmp_path, capsys) -> None:
    """A SIDS field that the log's format declares as text: one line naming the file, the
    message and the field, not a traceback."""
    from mavsid.cli import main

    path = _text_sids_log(tmp_path / "sids.bin")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataQualityWarning)
        with pytest.raises(MavsidError, match=r"sids\.bin: SIDS\.Mag holds text, not numbers"):
            sysid_runs(read_log(str(path)))
        assert main(["segments", str(path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len([line for line in err if "error" in line]) == 1, err
    assert str(path) in err[-1] and "SIDS.Mag" in err[-1] and "not numbers" in err[-1]
