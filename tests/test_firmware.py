"""Logs of older firmware: their clocks, names and parameters (issue: every generation runs).

Facts are checked against pymavlink where it reads the log, and on hand-built logs with one
fact each where no shared log has it.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from helpers import shared_path

from mavsid.align import _armed_events, align
from mavsid.channels import pwm_to_thrust
from mavsid.data import MessageTable, RawLog, SourceInfo
from mavsid.errors import DataQualityWarning, MissingMessageError, NoExcitationError
from mavsid.info import format_summary, summarize
from mavsid.pipeline import fit, format_result
from mavsid.readers import read_log

_OLD_COPTER = ("tradheli_brownout.log", "mechanical_fail.log", "robert_lefebvre_octo_PM.log")


def _quiet_read(path, **kw):  # type: ignore[no-untyped-def]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_log(path, **kw)


def test_copter_31_text_log_is_timed_by_gps_like_pymavlink() -> None:
    """ArduCopter 3.1: no boot-time field on ATT; GPS.TimeMS is the only clock. pymavlink
    holds the last GPS time (two ATT per 5 Hz fix share one stamp); mavsid interpolates by
    the record's place in the file: the two agree to within one GPS interval."""
    from pymavlink import DFReader

    path = shared_path("public", "ArduPilot__ardupilot", "mechanical_fail.log")
    ref = DFReader.DFReader_text(str(path))
    att, gps = [], []
    while (m := ref.recv_match(type=["ATT", "GPS"])) is not None:
        (att if m.get_type() == "ATT" else gps).append(m._timestamp)
    raw = _quiet_read(path, messages=["ATT", "GPS"])
    ours = raw["ATT"].time_s
    assert np.isfinite(ours).all() and len(ours) == len(att)
    # the clocks differ by a constant (pymavlink's epoch; it also skips the 7.4 s jump of
    # GPS.TimeMS at the second fix, mavsid keeps it): compare after the median offset
    d = ours - np.asarray(att)
    d = np.abs(d - np.median(d))[10:]
    assert np.median(d) < 0.15 and np.percentile(d, 95) <= 0.25
    assert np.all(np.diff(ours) >= 0)
    assert any("GPS time of week" in n for n in raw.source.notes)


@pytest.mark.parametrize("name", _OLD_COPTER)
def test_old_copter_logs_reach_a_verdict(name: str) -> None:
    """3.0/3.1 logs (angles at 10 Hz, no body rates or outputs): a reason, not a time error."""
    path = shared_path("public", "ArduPilot__ardupilot", name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(NoExcitationError, match="nothing identifiable") as info:
            fit([str(path)])
    assert "time grid" not in str(info.value)


def test_a_log_without_any_clock_says_so() -> None:
    path = shared_path("public", "ArduPilot__ardupilot", "underpowered.log")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(NoExcitationError, match="the log has no clock"):
            fit([str(path)])


def test_arm_event_before_the_first_timed_record_is_kept(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """EV 10 (armed) written before any TimeMS record: placed at the first one, noted."""
    lines = ["FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns",
             "FMT, 13, 4, EV, B, Id",
             "FMT, 1, 11, ATT, Ih, TimeMS,Roll",
             "EV, 10"]
    lines += [f"ATT, {1000 + 100 * k}, {k}" for k in range(20)]
    lines += ["EV, 11", "ATT, 3000, 0"]
    path = tmp_path / "arm_first.log"
    path.write_text("\n".join(lines) + "\n")
    with pytest.warns(DataQualityWarning, match="before the first timed record"):
        raw = read_log(path)
    assert raw["EV"].time_s.tolist() == [1.0, 2.9]
    assert _armed_events(raw) == [(1.0, True), (2.9, False)]


def _rcou_raw(channel: str) -> RawLog:
    t = np.arange(0, 4, 0.01)
    att = MessageTable("ATT", {"Roll": np.zeros(t.size), "Pitch": np.zeros(t.size),
                               "Yaw": np.zeros(t.size)}, t)
    imu = MessageTable("IMU", {k: np.zeros(t.size) for k in ("GyrX", "GyrY", "GyrZ")}, t)
    pwm = {f"{channel}{i}": np.full(t.size, 1500.0) for i in range(1, 9)}
    return RawLog(SourceInfo("old.bin", "dataflash", 0),
                  {"ATT": att, "IMU": imu, "RCOU": MessageTable("RCOU", pwm, t)},
                  params={"FRAME": 1.0, "RC3_MIN": 1100.0, "RC3_MAX": 1900.0})


@pytest.mark.parametrize("channel", ["C", "Chan", "Ch"])
def test_rcou_channels_of_every_generation(channel: str) -> None:
    """RCOU.C1 (4.x), Chan1 (3.4-3.6), Ch1 (3.3): all unmixed as motor outputs."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fd = align(_rcou_raw(channel))
    assert fd.input_names == ("u_roll", "u_pitch", "u_yaw", "u_thrust")
    assert fd.meta["mixer"] == "quad-x"


def test_old_throttle_range_and_minimum() -> None:
    """ArduCopter < 3.5 has no MOT_PWM_MIN/MAX (RC3_MIN/MAX) nor MOT_SPIN_MIN (THR_MIN)."""
    old = {"RC3_MIN": 1100.0, "RC3_MAX": 1900.0, "THR_MIN": 100.0, "MOT_THST_EXPO": 0.0}
    assert pwm_to_thrust(np.array([1100.0, 1180.0, 1900.0]), old).tolist() == pytest.approx(
        [0.0, 0.0, 1.0])
    mid = 1100.0 + 800.0 * (0.1 + 0.85 * 0.5)  # half way up the spin range 0.1..0.95
    assert pwm_to_thrust(np.array([mid]), old)[0] == pytest.approx(0.5)


def test_a_renamed_field_falls_back_to_the_next_preset() -> None:
    """RATE present but without ROut/POut/YOut (another layout): the RCOU preset is used;
    when nothing fits, the error names what each preset needed."""
    raw = _rcou_raw("C")
    t = raw["ATT"].time_s
    rate = MessageTable("RATE", {k: np.zeros(t.size) for k in ("R", "P", "Y", "RollOut")}, t)
    both = RawLog(raw.source, {**raw.messages, "RATE": rate}, params=raw.params)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert align(both).preset == "ardupilot-rcou"
    rcou = MessageTable("RCOU", {"Out1": np.zeros(t.size)}, t)
    neither = RawLog(raw.source, {**both.messages, "RCOU": rcou}, params=raw.params)
    with pytest.warns(DataQualityWarning, match="preset ardupilot-att used") as caught:
        fd = align(neither)
    assert fd.preset == "ardupilot-att" and fd.input_names == ()
    text = " ".join(str(w.message) for w in caught)
    assert "ardupilot-rate needs field RATE.ROut" in text and "ardupilot-rcou needs" in text
    # no preset at all fits: the error lists every one's need and what the log has
    bare = RawLog(raw.source, {"RATE": rate}, params=raw.params)
    with pytest.raises(MissingMessageError, match="it has: RATE"):
        align(bare)


def test_info_gives_rates_for_sampled_types_only() -> None:
    """Definitions, units, parameters, texts written in a burst at boot: counted, no rate
    (they showed 10 000-100 000 Hz); sampled types keep theirs."""
    path = shared_path("public", "ArduPilot__MethodicConfigurator", "backend_log_80k.bin")
    s = summarize(_quiet_read(path))["messages"]
    for name in ("FMT", "FMTU", "PARM", "MSG", "FNCE"):
        assert s[name]["rate_hz"] is None and s[name]["count"] > 0, name
    assert s["IMU"]["rate_hz"] == pytest.approx(25.0, rel=0.05)
    assert s["ATT"]["rate_hz"] == pytest.approx(10.0, rel=0.05)


def _scaled_like_34dev(raw: RawLog, keep_imu: bool = True,
                       firmware: str | None = None) -> RawLog:
    rate = raw["RATE"]
    cols = dict(rate.columns)
    for k in ("R", "P", "Y", "RDes", "PDes", "YDes"):
        cols[k] = cols[k] * 100.0  # centidegrees/s
    for k in ("ROut", "POut", "YOut"):
        cols[k] = cols[k] * 4500.0
    msgs = {**raw.messages, "RATE": MessageTable("RATE", cols, rate.time_s)}
    if not keep_imu:
        msgs.pop("IMU", None)
    return RawLog(raw.source, msgs, params=raw.params, texts=raw.texts, modes=raw.modes,
                  autopilot=raw.autopilot, vehicle=raw.vehicle,
                  firmware=firmware or raw.firmware)


@pytest.mark.parametrize("keep_imu", [True, False], ids=["by-imu", "by-firmware"])
def test_centidegree_rates_of_copter_34_dev_are_found_and_said(keep_imu: bool) -> None:
    """RATE in centideg/s and outputs on ±4500 (ArduCopter 3.4-dev, no unit records): the
    scale is decided from the IMU gyro (or the firmware string) and stated; the flight
    equals the one aligned from the same log in deg/s and ±1."""
    from helpers import FIXTURES

    raw = _quiet_read(FIXTURES / "sysid_roll.bin")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = align(raw)
    with pytest.warns(DataQualityWarning, match="centidegrees/s") as caught:
        got = align(_scaled_like_34dev(raw, keep_imu, None if keep_imu else
                                       "ArduCopter V3.4-dev (e707341b)"))
    text = " ".join(str(w.message) for w in caught)
    assert ("against IMU" in text) == keep_imu and "divided by 4500" in text
    assert ("firmware table" in text) == (not keep_imu)
    assert got.state_names == ref.state_names and got.input_names == ref.input_names
    # float32 storage: equal to its precision
    np.testing.assert_allclose(got.states, ref.states, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(got.inputs, ref.inputs, rtol=1e-6, atol=1e-9)
    assert "inferred" in got.meta["sources"]["p"]
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataQualityWarning)
        align(raw)  # the same log in its right units: nothing to say


def test_the_readme_preset_file_loads_and_fits(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The TOML preset example of the README is valid, and its preset reads a fixture."""
    import re
    from pathlib import Path

    from helpers import FIXTURES

    from mavsid.channels import load_presets

    readme = (Path(__file__).parent.parent / "README.md").read_text()
    block = re.search(r"```toml\n(.*?)```", readme, re.S)
    assert block is not None
    path = tmp_path / "presets.toml"
    path.write_text(block.group(1))
    presets, mixers = load_presets(path)
    assert set(presets) == {"my-quad", "my-hexa-pwm"} and "my-hexa" in mixers
    raw = _quiet_read(FIXTURES / "sysid_roll.bin")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fd = align(raw, presets["my-quad"])
    assert fd.preset == "my-quad" and fd.input_names == ("u_roll",)


@pytest.mark.parametrize("layout", ["copter-4", "copter-3.6", "copter-3.3", "copter-3.4-dev"])
def test_firmware_matrix_gives_the_truth_back(layout: str, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The same simulated plant logged as each ArduCopter generation did (TimeMS, RCOU.Ch*,
    no unit records, untimed PARM/MODE and an ARM event first for 3.3; centidegree RATE and
    ±4500 outputs for 3.4-dev; no unit records, no SYSTEMID messages and PARM without its
    Default for 3.6): info reads it, fit finds the roll chirp (by its SYSTEMID run, or by
    scanning where the log has none) and gives the plant's effectiveness and damping back in
    SI units."""
    import contextlib
    import io
    import json

    from mavsid import cli

    path = tmp_path / f"{layout}.bin"
    with contextlib.redirect_stdout(io.StringIO()):
        assert cli.main(["simulate", "-o", str(path), "--layout", layout, "--sid-axis", "10",
                         "--t-rec", "15", "--rate-hz", "200", "--seed", "5"]) == 0
    truth = json.loads(path.with_suffix(".truth.json").read_text())
    assert truth.get("layout", "copter-4") == layout
    raw = _quiet_read(path)
    assert ("TimeMS" in raw["ATT"].fields) == (layout == "copter-3.3")
    assert ("FMTU" in raw.messages) == (layout == "copter-4")
    assert summarize(raw)["firmware"].startswith(
        {"copter-4": "ArduCopter V4", "copter-3.3": "ArduCopter V3.3",
         "copter-3.4-dev": "ArduCopter V3.4-dev", "copter-3.6": "ArduCopter V3.6"}[layout])
    assert ("SIDD" in raw.messages) == (layout in ("copter-4", "copter-3.4-dev"))
    assert ("Default" in raw["PARM"].fields) == (layout in ("copter-4", "copter-3.4-dev"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = fit([str(path)])
    f = result.axes["roll"]
    assert f.verdict is not None and f.verdict.identified
    b, damping = f.model.params["B[p,u_roll]"], -f.model.params["A[p,p]"]
    want = truth["axes"]["roll"]
    assert b == pytest.approx(want["effectiveness"], rel=0.12)
    assert damping == pytest.approx(want["damping"], rel=0.35)
    sources = result.flights[0].meta["sources"]
    assert ("inferred" in sources["p"]) == (layout == "copter-3.4-dev")
    # the unit each channel was read in, and where it came from, is in info and in fit
    info = format_summary(summarize(raw))
    assert {"copter-4": "p        [rad/s] <- RATE.R (deg/s, declared by the log)",
            "copter-3.3": "p        [rad/s] <- RATE.R (deg/s, the preset's unit: the log "
                          "declares none)",
            "copter-3.6": "p        [rad/s] <- RATE.R (deg/s, the preset's unit: the log "
                          "declares none)",
            "copter-3.4-dev": "p        [rad/s] <- RATE.R (centideg/s, inferred)"}[layout] in info
    line = format_result(result).splitlines()[1]
    assert {"copter-4": "p [rad/s] <- RATE.R (deg/s, declared by the log)",
            "copter-3.3": "p [rad/s] <- RATE.R (deg/s, the preset's unit: the log declares none)",
            "copter-3.6": "p [rad/s] <- RATE.R (deg/s, the preset's unit: the log declares none)",
            "copter-3.4-dev": "p [rad/s] <- RATE.R (centideg/s, inferred)"}[layout] in line
    assert ("u_roll [1] <- RATE.ROut (/4500, inferred)" in line) == (layout == "copter-3.4-dev")


@pytest.mark.parametrize("layout, preset, rate_field, release", [
    ("px4-1.14", "px4-torque", "vehicle_angular_velocity", "v1.14.0"),
    ("px4-1.11", "px4-actuator-controls", "vehicle_angular_velocity", "v1.11.3"),
    ("px4-1.8", "px4-legacy", "vehicle_attitude", "v1.8.2"),
])
def test_px4_layouts_give_the_truth_back(layout: str, preset: str, rate_field: str,
                                         release: str, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The simulated plant logged as a PX4 ULog in each generation's topic set (torque
    setpoint; actuator_controls_0; rates inside vehicle_attitude): pyulog reads the file and
    mavsid's tables equal its values, and a stick doublet gives the plant back by default."""
    import json

    from pyulog import ULog

    from mavsid.synthetic.run import scenario_from_options, simulate

    path = tmp_path / f"{layout}.ulg"
    sim = simulate(scenario_from_options(manoeuvre="doublet", seed=4), [path], layout=layout)
    truth = json.loads(path.with_suffix(".truth.json").read_text())
    assert truth["layout"] == layout
    assert truth["axes"]["roll"][f"output_field_{layout}"].startswith(rate_field)
    ref = ULog(str(path))
    raw = read_log(path)
    assert raw.firmware is not None and release in raw.firmware
    for d in ref.data_list:  # the reader against pyulog, field by field
        for name, want in d.data.items():
            assert np.array_equal(raw[d.name][name], want, equal_nan=True), (d.name, name)
    # what was written is the flight: the roll rate is the simulator's filtered gyro
    fl = sim.flight
    table = raw[rate_field]
    got = table["rollspeed"] if layout == "px4-1.8" else table["xyz[0]"]
    k = np.searchsorted(fl.t_s, np.asarray(table["timestamp"], float) / 1e6 - 1e-7)
    np.testing.assert_array_equal(got, fl.gyro[k, 0].astype(np.float32))
    result = fit([str(path)])
    assert result.flights[0].preset == preset
    f = result.axes["roll"]
    assert f.verdict is not None and f.verdict.identified
    want = truth["axes"]["roll"]
    assert f.model.params["B[p,u_roll]"] == pytest.approx(want["effectiveness"], rel=0.05)
    assert -f.model.params["A[p,p]"] == pytest.approx(want["damping"], rel=0.10)
    delay = f.model.delay_s + float(dict(f.model.provenance).get("lag_s", 0.0))
    assert delay == pytest.approx(want["effective_delay_s"], abs=1.0 / 400 + 1e-9)


def test_a_layout_for_another_format_is_refused(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from mavsid.errors import ConfigError
    from mavsid.synthetic import Scenario, simulate

    for name, layout in (("x.bin", "px4-1.14"), ("x.ulg", "copter-3.3")):
        with pytest.raises(ConfigError, match="is not a"):
            simulate(Scenario(manoeuvre="hover", duration_s=1.0), [tmp_path / name],
                     layout=layout)
    assert not list(tmp_path.iterdir())
