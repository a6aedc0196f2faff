"""Logs of older firmware: their clocks, names and parameters (every generation runs).

Facts are checked against pymavlink where it reads the log, and on hand-built logs with one
fact each where no shared log has it.
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from helpers import shared_path

from mavsid.align import align
from mavsid.align.flags import armed_events
from mavsid.autopilot.ardupilot import pwm_to_thrust
from mavsid.cli_format import format_result
from mavsid.data import MessageTable, RawLog, SourceInfo
from mavsid.errors import DataQualityWarning, MissingMessageError, NoExcitationError
from mavsid.info import format_summary, summarize
from mavsid.pipeline import fit
from mavsid.readers import read_log

_OLD_COPTER = ("tradheli_brownout.log", "mechanical_fail.log", "robert_lefebvre_octo_PM.log")


def _quiet_read(path, **kw):  # type: ignore[no-untyped-def]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_log(path, **kw)


def test_copter_31_text_log_is_timed_by_gps_like_pymavlink() -> None:
    """ArduCopter 3.1: no boot-time field on ATT; the GPS message's T (ms since boot) is the
    clock, pymavlink's and mavsid's. pymavlink holds the last GPS time (two ATT per 5 Hz fix
    share one stamp); mavsid interpolates by the record's place in the file: the two agree to
    within one GPS interval."""
    from pymavlink import DFReader

    path = shared_path("public", "ArduPilot__ardupilot", "mechanical_fail.log")
    ref = DFReader.DFReader_text(str(path))
    att, gps = [], []
    while (m := ref.recv_match(type=["ATT", "GPS"])) is not None:
        (att if m.get_type() == "ATT" else gps).append(m._timestamp)
    raw = _quiet_read(path, messages=["ATT", "GPS"])
    ours = raw["ATT"].time_s
    assert np.isfinite(ours).all() and len(ours) == len(att)
    # the clocks differ by a constant (pymavlink's epoch): compare after the median offset
    d = ours - np.asarray(att)
    d = np.abs(d - np.median(d))[10:]
    assert np.median(d) < 0.15 and np.percentile(d, 95) <= 0.25
    assert np.all(np.diff(ours) >= 0)
    assert any("GPS.T (ms since boot)" in n for n in raw.source.notes)


@pytest.mark.parametrize("name", _OLD_COPTER)
def test_old_copter_logs_reach_a_verdict(name: str) -> None:
    """3.0/3.1 logs (angles at 10 Hz, no body rates or outputs): a reason, not a time error."""
    path = shared_path("public", "ArduPilot__ardupilot", name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(NoExcitationError, match="nothing identifiable") as info:
            fit([str(path)])
    assert "time grid" not in str(info.value)


def test_a_log_without_the_controllers_output_says_which_and_what_to_log() -> None:
    """An ArduCopter log with attitude but no rate controller output (no RATE, no RCOU
    fast enough): each axis says the input it lacks, not "no window kept (1× missing
    channel)", and the advice is what to log (this firmware has no RATE record), not a
    manoeuvre to fly."""
    path = shared_path("public", "ArduPilot__ardupilot", "robert_lefebvre_octo_PM.log")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(NoExcitationError, match="the log has no u_roll input") as info:
            fit([str(path)])
    assert "missing channel" not in str(info.value)
    advice = " ".join(info.value.details)
    assert "LOG_BITMASK" in advice and "fly a SYSTEMID" not in advice, advice


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
    assert armed_events(raw) == [(1.0, True), (2.9, False)]


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
    assert fd.mixer == "quad-x"


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
    assert "inferred" in got.sources["p"]
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataQualityWarning)
        align(raw)  # the same log in its right units: nothing to say


def test_the_readme_preset_file_loads_and_fits(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The TOML preset example of the presets guide is valid, and its preset reads a fixture."""
    import re
    import textwrap
    from pathlib import Path

    from helpers import FIXTURES

    from mavsid.autopilot.config import load_presets

    guide = (Path(__file__).parent.parent / "docs" / "guide" / "presets.rst").read_text()
    block = re.search(r"\.\. code-block:: toml\n\n(.*?)\n\S", guide, re.S)
    assert block is not None
    path = tmp_path / "presets.toml"
    path.write_text(textwrap.dedent(block.group(1)))
    presets, mixers = load_presets(path)
    assert set(presets) == {"my-quad", "my-hexa-pwm"} and "my-hexa" in mixers
    raw = _quiet_read(FIXTURES / "sysid_roll.bin")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fd = align(raw, presets["my-quad"])
    assert fd.preset == "my-quad" and fd.input_names == ("u_roll",)


@pytest.mark.slow
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
    sources = result.flights[0].sources
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


@pytest.mark.slow
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


# --------------------------------------------------------------------------- the layouts
# without RATE outputs or without a motor mixer: ArduCopter 3.2, a traditional heli, ArduPlane


def _pymavlink(path, types):  # type: ignore[no-untyped-def]
    """The records of ``types`` as pymavlink decodes them: type -> field -> array."""
    from pymavlink import DFReader

    log = DFReader.DFReader_binary(str(path), zero_time_base=False)
    rows: dict[str, list[dict]] = {t: [] for t in types}
    while (m := log.recv_match(type=list(types))) is not None:
        d = m.to_dict()
        rows[d.pop("mavpackettype")].append(d)
    return {t: {k: np.array([r[k] for r in rs]) for k in rs[0]} for t, rs in rows.items() if rs}


def _loop_index(fl, t_s):  # type: ignore[no-untyped-def]
    """Loop sample of each logged time (s)."""
    return np.round((np.asarray(t_s, float) - fl.t_s[0]) / fl.dt).astype(int)


def _cli_verdicts(path) -> dict[str, int]:  # type: ignore[no-untyped-def]
    """Exit codes of ``mavsid info``, ``segments`` and ``fit`` on ``path``."""
    import contextlib
    import io

    from mavsid import cli

    codes = {}
    for cmd in ("info", "segments", "fit"):
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                codes[cmd] = cli.main([cmd, str(path)])
    return codes


def _fast(scenario):  # type: ignore[no-untyped-def]
    """The scenario with IMU and RCOU logged at the RATE rate (200 Hz)."""
    from dataclasses import replace

    from mavsid.synthetic.flight import LogRates

    return replace(scenario, rates=LogRates(rate=200, att=50, imu=200, rcou=200, rcin=10))


def _roll_fit(path, **cfg):  # type: ignore[no-untyped-def]
    from mavsid.pipeline_config import PipelineConfig

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = fit([str(path)], PipelineConfig(**cfg) if cfg else None)
    f = result.axes["roll"]
    assert f.verdict is not None and f.verdict.identified
    return result, f.model.params["B[p,u_roll]"], -f.model.params["A[p,p]"]


@pytest.mark.slow
def test_copter_32_layout_has_no_rate_and_fits_through_the_motor_mix(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """ArduCopter 3.2 (ArduCopter/Log.pde and DataFlash/LogStructure.h of the 3.2 release):
    TimeMS, ATT in centidegrees with ErrRP/ErrYaw, RCOU Chan1-Chan8, FRAME/RC3_*/THR_*/RATE_*
    parameters and no RATE: the inputs come from the motors through the quad-X mix. With
    RCOU at 3.2's 10 Hz, fit says why it cannot; with RCOU and IMU at 200 Hz it gives the
    plant back."""
    from mavsid.synthetic.run import scenario_from_options, simulate

    sc = scenario_from_options(sid_axes=[10], t_rec=15, rate_hz=200, seed=5)
    slow, fast = tmp_path / "c32.bin", tmp_path / "c32_fast.bin"
    simulate(sc, [slow], layout="copter-3.2")
    sim = simulate(_fast(sc), [fast], layout="copter-3.2")
    truth = json.loads(fast.with_suffix(".truth.json").read_text())
    assert truth["layout"] == "copter-3.2"
    ref = _pymavlink(fast, ("ATT", "RCOU", "PARM", "MSG", "RATE", "IMU"))
    assert "RATE" not in ref and "TimeMS" in ref["ATT"] and "ErrRP" in ref["ATT"]
    params = dict(zip(ref["PARM"]["Name"], ref["PARM"]["Value"], strict=True))
    assert params["FRAME"] == 1 and "FRAME_CLASS" not in params and "RATE_RLL_P" in params
    assert "MOT_THST_EXPO" not in params and "ATC_RAT_RLL_P" not in params
    assert any(m.startswith("ArduCopter V3.2") for m in ref["MSG"]["Message"])
    raw = _quiet_read(fast)
    for name in ("ATT", "RCOU", "IMU"):  # the reader against pymavlink, field by field
        for fld, want in ref[name].items():
            np.testing.assert_allclose(raw[name][fld], want, rtol=1e-6, err_msg=f"{name}.{fld}")
    # the motors: linear in thrust over THR_MIN..THR_MAX of RC3_MIN..RC3_MAX (no expo)
    fl = sim.flight
    k = _loop_index(fl, ref["RCOU"]["TimeMS"] / 1e3)
    lo, hi = params["RC3_MIN"], params["RC3_MAX"]
    spin = (params["THR_MIN"] + (params["THR_MAX"] - params["THR_MIN"]) * fl.motors[k]) / 1e3
    for c in range(4):
        np.testing.assert_allclose(ref["RCOU"][f"Chan{c + 1}"], np.round(lo + (hi - lo)
                                                                         * spin[:, c]))
    assert _cli_verdicts(slow) == {"info": 0, "segments": 0, "fit": 1}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(NoExcitationError, match="logged at 10 Hz") as info:
            fit([str(slow)])
    # the advice fits the firmware: no RATE before 3.3, no SYSTEMID chirp to fly
    advice = " ".join(info.value.details)
    assert "before 3.3 logs no RATE" in advice and "SID_AXIS" not in advice
    result, b, damping = _roll_fit(fast)
    assert result.flights[0].preset == "ardupilot-rcou"
    assert result.flights[0].sources["u_roll"] == "RCOU (quad-x mixer)"
    want = truth["axes"]["roll"]
    assert b == pytest.approx(want["effectiveness"], rel=0.12)
    assert damping == pytest.approx(want["damping"], rel=0.35)


@pytest.mark.slow
def test_heli_layout_takes_the_rate_outputs_not_the_swashplate(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A traditional helicopter (ArduCopter 4.x, FRAME_CLASS 6): swashplate servos 1-3 (H3-120
    mix of AP_MotorsHeli_Swash), tail on 4, rotor speed controller on 8; no mixer to invert,
    so the RCOU preset gives no inputs and says why, and fit takes RATE.ROut/POut/YOut and
    gives the heli plant back per normalised controller output."""
    from mavsid.synthetic.run import scenario_from_options, simulate

    path = tmp_path / "heli.bin"
    sim = simulate(scenario_from_options(sid_axes=[10], t_rec=15, rate_hz=200, seed=5,
                                         vehicle="heli"), [path], layout="heli")
    truth = json.loads(path.with_suffix(".truth.json").read_text())
    assert truth["layout"] == "heli" and "swashplate" in truth["axes"]["roll"][
        "input_unit_heli"]
    ref = _pymavlink(path, ("PARM", "MSG", "RCOU", "RATE"))
    params = dict(zip(ref["PARM"]["Name"], ref["PARM"]["Value"], strict=True))
    assert params["FRAME_CLASS"] == 6 and params["H_SW_TYPE"] == 3
    assert [params[f"SERVO{n}_FUNCTION"] for n in (1, 2, 3, 4, 8)] == [33, 34, 35, 36, 31]
    assert not any(k.startswith("MOT_") for k in params)
    assert "Frame: HELI" in list(ref["MSG"]["Message"])
    raw = _quiet_read(path)
    for name in ("RCOU", "RATE"):
        for fld, want in ref[name].items():
            np.testing.assert_allclose(raw[name][fld], want, rtol=1e-6, err_msg=f"{name}.{fld}")
    # H3-120 (AP_MotorsHeli_Swash): servo = (roll_f·roll + pitch_f·pitch)·0.45 + collective,
    # rescaled to -1..1 and through SERVOn_MIN/TRIM/MAX; the tail servo carries the yaw output
    fl = sim.flight
    k = _loop_index(fl, ref["RCOU"]["TimeUS"] / 1e6)
    u = fl.u_eff[k]
    for c, (rf, pf) in enumerate(((0.866025, 0.5), (-0.866025, 0.5), (0.0, -1.0))):
        x = 2.0 * ((rf * u[:, 0] + pf * u[:, 1]) * 0.45 + 0.5) - 1.0
        np.testing.assert_allclose(ref["RCOU"][f"C{c + 1}"], np.round(1500 + 400 * x))
    np.testing.assert_allclose(ref["RCOU"]["C4"], np.round(1500 + 400 * u[:, 2]))
    assert summarize(raw)["vehicle"] == "copter HELI"
    with pytest.warns(DataQualityWarning, match=r"FRAME_CLASS 6 .*\(heli\): no motor mixer"):
        assert align(raw, "ardupilot-rcou").input_names == ()
    assert _cli_verdicts(path) == {"info": 0, "segments": 0, "fit": 0}
    result, b, damping = _roll_fit(path)
    assert result.flights[0].preset == "ardupilot-rate"
    want = truth["axes"]["roll"]
    assert b == pytest.approx(want["effectiveness"], rel=0.12)
    assert damping == pytest.approx(want["damping"], rel=0.35)


@pytest.mark.slow
def test_plane_layout_fits_from_the_pid_sums_and_from_the_servos(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """ArduPlane 4.x: no RATE nor SYSTEMID; PIDR/PIDP/PIDY (Tar/Act in deg/s, P+I+D+FF the
    surface demand in degrees, ±45 full deflection) and the aileron/elevator/throttle/rudder
    servos (SERVOn_FUNCTION 4/19/70/21). The plane preset is chosen by the vehicle kind and
    gives the fixed-wing plant back from the PID sums; from the servo PWMs (normalised through
    SERVOn_MIN/TRIM/MAX) as well when RCOU is logged fast enough."""
    from mavsid.errors import ConfigError
    from mavsid.synthetic.run import scenario_from_options, simulate

    with pytest.raises(ConfigError, match="no SYSTEMID mode"):
        simulate(scenario_from_options(sid_axes=[10], vehicle="plane"),
                 [tmp_path / "sid.bin"], layout="plane")
    assert not list(tmp_path.iterdir())
    sc = scenario_from_options(manoeuvre="doublet", seed=4, rate_hz=200, vehicle="plane")
    path, fast = tmp_path / "plane.bin", tmp_path / "plane_fast.bin"
    simulate(sc, [path], layout="plane")
    sim = simulate(_fast(sc), [fast], layout="plane")
    truth = json.loads(fast.with_suffix(".truth.json").read_text())
    assert truth["layout"] == "plane"
    assert truth["axes"]["pitch"]["input_field_plane"].startswith("PIDP.P+I+D+FF / 45")
    ref = _pymavlink(fast, ("PARM", "MSG", "RCOU", "PIDR", "PIDP", "MODE", "RATE", "SIDD"))
    assert "RATE" not in ref and "SIDD" not in ref
    params = dict(zip(ref["PARM"]["Name"], ref["PARM"]["Value"], strict=True))
    assert [params[f"SERVO{n}_FUNCTION"] for n in (1, 2, 3, 4)] == [4, 19, 70, 21]
    assert set(ref["MODE"]["Mode"]) == {5}  # FBWA
    raw = _quiet_read(fast)
    assert raw.vehicle == "plane" and raw.firmware.startswith("ArduPlane V4")
    for name in ("RCOU", "PIDR", "PIDP"):
        for fld, want in ref[name].items():
            np.testing.assert_allclose(raw[name][fld], want, rtol=1e-6, err_msg=f"{name}.{fld}")
    fl = sim.flight
    k = _loop_index(fl, ref["PIDR"]["TimeUS"] / 1e6)
    np.testing.assert_allclose(ref["PIDR"]["Act"], np.degrees(fl.gyro[k, 0]), rtol=1e-5,
                               atol=1e-4)
    np.testing.assert_allclose(ref["PIDR"]["Tar"], np.degrees(fl.rate_target[k, 0]),
                               rtol=1e-5, atol=1e-4)
    pid_sum = sum(ref["PIDR"][t] for t in ("P", "I", "D", "FF"))
    np.testing.assert_allclose(pid_sum / 45.0, fl.u[k, 0], rtol=1e-5, atol=1e-6)
    k = _loop_index(fl, ref["RCOU"]["TimeUS"] / 1e6)  # SRV_Channel::pwm_from_angle
    for c, a in ((1, 0), (2, 1), (4, 2)):
        np.testing.assert_allclose(ref["RCOU"][f"C{c}"], np.round(1500 + 400 * fl.u_eff[k, a]))
    assert _cli_verdicts(path) == {"info": 0, "segments": 0, "fit": 0}
    want = truth["axes"]["roll"]
    for log, cfg, preset, source in (
            (path, {}, "ardupilot-plane-pid", "PIDR.P+I+D+FF"),
            (fast, {"preset": "ardupilot-plane-servo"}, "ardupilot-plane-servo",
             "RCOU.C1 (aileron, SERVO1)")):
        result, b, damping = _roll_fit(log, **cfg)
        assert result.flights[0].preset == preset
        assert result.flights[0].sources["u_roll"] == source
        assert b == pytest.approx(want["effectiveness"], rel=0.12), preset
        assert damping == pytest.approx(want["damping"], rel=0.35), preset
        assert "no closed-loop twin for ArduPlane" in (result.axes["roll"].closed_loop_note
                                                       or "")
        pitch = result.verdicts["pitch"]
        assert not pitch.identified  # only roll was flown
        assert "ArduPlane has no SYSTEMID mode" in " ".join(pitch.advice)


def test_servo_inputs_follow_the_servo_parameters() -> None:
    """A reversed servo flips its axis; an aileron on output 5 is found by its function; a
    log without servo functions names what is missing; a TRIM outside MIN..MAX is refused."""
    from mavsid.autopilot.presets import PRESETS
    from mavsid.channels import servo_inputs
    from mavsid.errors import ConfigError

    t = np.arange(4.0)
    pwm = {f"C{i}": np.full(4, 1500.0) for i in range(1, 9)}
    pwm["C5"] = np.array([1500.0, 1700, 1300, 0])
    base = {"SERVO5_FUNCTION": 4, "SERVO2_FUNCTION": 19, "SERVO4_FUNCTION": 21,
            "SERVO5_MIN": 1000, "SERVO5_TRIM": 1500, "SERVO5_MAX": 1900, "SERVO5_REVERSED": 1}
    preset = PRESETS["ardupilot-plane-servo"]

    def raw(params):  # type: ignore[no-untyped-def]
        return RawLog(SourceInfo("p.bin", "dataflash", 0),
                      {"RCOU": MessageTable("RCOU", pwm, t)}, params=params, vehicle="plane")

    name, source, tt, v = servo_inputs(raw(base), preset)[0]
    assert (name, source) == ("u_roll", "RCOU.C5 (aileron, SERVO5)")
    assert tt.tolist() == [0.0, 1.0, 2.0] and v.tolist() == [0.0, -0.5, 0.4]  # PWM 0 dropped
    with pytest.raises(MissingMessageError, match="SERVOn_FUNCTION 19"):
        servo_inputs(raw({"SERVO5_FUNCTION": 4}), preset)
    with pytest.raises(ConfigError, match="SERVO5_MIN/TRIM/MAX 1000/2000/1900"):
        servo_inputs(raw({**base, "SERVO5_TRIM": 2000}), preset)
    # a damaged end point (0, or 1e9) scaled one side of the deflections 3.75 or 2.5e6
    # times wrong, silently
    for end, value in (("MIN", 0.0), ("MAX", 1e9)):
        with pytest.raises(ConfigError, match=r"are not increasing PWMs within 1\.\.3000 us"):
            servo_inputs(raw({**base, f"SERVO5_{end}": value}), preset)
    # a throttle idles at its trim = MIN (ArduPlane's default): a range, normalised from MIN
    pwm["C3"] = np.array([1100.0, 1500, 1900, 1100])
    thr = {**base, "SERVO3_FUNCTION": 70, "SERVO3_MIN": 1100, "SERVO3_TRIM": 1100,
           "SERVO3_MAX": 1900}
    got = {n: v for n, _, _, v in servo_inputs(raw(thr), preset)}
    assert got["u_thrust"].tolist() == [0.0, 0.5, 1.0, 0.0]
    # one whose range is broken is left out: the attitude axes do not need it
    got = {n for n, _, _, _ in servo_inputs(raw({**thr, "SERVO3_MAX": 1100}), preset)}
    assert got == {"u_roll", "u_pitch", "u_yaw"}


def test_a_real_plane_log_reaches_a_verdict() -> None:
    """ArduPlane 3.8 (pymavlink's test.BIN, throttle trim at its minimum as on every plane):
    a verdict per axis, not a servo-normalisation error."""
    path = shared_path("public", "ArduPilot__pymavlink", "test.BIN")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(NoExcitationError, match="nothing identifiable") as info:
            fit([str(path)])
    assert set(info.value.verdicts) == {"roll", "pitch", "yaw"}  # type: ignore[attr-defined]


def test_a_toml_servo_preset_applies_to_its_vehicle_only(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """``servos`` and ``vehicles`` in a TOML preset: the plane preset reads the servos of a
    plane log and is never chosen for a copter."""
    from mavsid.autopilot.config import load_presets
    from mavsid.autopilot.presets import choose_preset
    from mavsid.channels import servo_inputs

    path = tmp_path / "p.toml"
    path.write_text('''[preset.my-plane]
vehicles = ["Plane"]
servos = { message = "RCOU", field = "C{i}", unit = "pwm" }
[preset.my-plane.states]
roll = { message = "ATT", field = "Roll", unit = "deg" }
''')
    presets, _ = load_presets(path)
    t = np.arange(3.0)
    msgs = {"ATT": MessageTable("ATT", {"Roll": np.zeros(3)}, t),
            "RCOU": MessageTable("RCOU", {f"C{i}": np.array([1500.0, 1900, 1100])
                                          for i in range(1, 5)}, t)}
    params = {"SERVO1_FUNCTION": 4, "SERVO2_FUNCTION": 19, "SERVO4_FUNCTION": 21}
    src = SourceInfo("p.bin", "dataflash", 0)
    plane = RawLog(src, msgs, params=params, vehicle="plane")
    assert choose_preset(plane, presets).name == "my-plane"
    roll = servo_inputs(plane, presets["my-plane"])[0]
    assert roll[0] == "u_roll" and roll[3].tolist() == [0, 1, -1]
    copter = RawLog(src, msgs, params=params, vehicle="copter QUAD/X")
    assert choose_preset(copter, presets).name != "my-plane"


@pytest.mark.slow
@pytest.mark.parametrize(("layout", "centi"), [("copter-4", False), ("copter-3.4-dev", True)])
def test_the_rate_scale_is_judged_right_across_a_reboot(tmp_path, layout: str,  # type: ignore[no-untyped-def]
                                                        centi: bool) -> None:
    """A log whose clock restarts (a reboot mid-flight: times mix two boots) compared its
    RATE channel with the IMU gyro interpolated on times that run backwards: a deg/s log
    came out "46x the gyro", was divided by 100 and fitted with B 1 % of the truth, and an
    ArduCopter 3.4-dev log in centideg/s was left unscaled (B 94x the truth), both called
    `usable` (bench_variety.py --faults, seeds 367 and 369). Across a reboot the two series
    are compared whole."""
    from mavsid.pipeline import PipelineConfig, fit
    from mavsid.synthetic.faults import Faults
    from mavsid.synthetic.run import scenario_from_options, simulate

    sc = scenario_from_options(manoeuvre="sysid", axis="roll", sid_axes=(10,), seed=615,
                               rate_hz=50.0)
    path = tmp_path / "rebooted.bin"
    simulate(sc, [path], Faults(reboot_at_s=9.0, truncate_bytes=3000), layout=layout)
    truth = json.loads(path.with_suffix(".truth.json").read_text())["axes"]["roll"]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = fit([str(path)], PipelineConfig(axes=("roll",)))
    said = " ".join(str(w.message) for w in caught)
    assert "clock restarts" in said
    assert ("centidegrees/s" in said) == centi
    f = result.axes["roll"]
    assert f.model is not None
    assert f.model.params["B[p,u_roll]"] == pytest.approx(truth["effectiveness"], rel=0.1)
