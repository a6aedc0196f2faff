"""Channel presets, mixers and TOML presets (mavsid.autopilot.presets, .mixers, .config)."""

from __future__ import annotations

import math
import re
import warnings
from dataclasses import replace

import numpy as np
import pytest
from helpers import shared_path, table_log

from mavsid.autopilot.ardupilot import pwm_to_thrust, thrust_curve
from mavsid.autopilot.config import load_presets
from mavsid.autopilot.mixers import MIXERS
from mavsid.autopilot.presets import PRESETS, choose_preset, get_preset
from mavsid.channels import evaluate, motor_thrusts
from mavsid.data import MessageTable, RawLog, SourceInfo
from mavsid.errors import ConfigError, DataQualityWarning, MissingMessageError

# --------------------------------------------------------------------------- conversions


def test_pwm_to_thrust_inverts_ardupilot_thrust_curve():
    # ArduPilot's forward path (AP_Motors thrust linearisation, documented formula):
    # throttle ratio r = ((expo - 1) + sqrt((1 - expo)^2 + 4 expo thrust)) / (2 expo)
    # actuator = spin_min + (spin_max - spin_min) r ; pwm = pwm_min + (pwm_max - pwm_min) actuator
    params = {"MOT_PWM_MIN": 1100, "MOT_PWM_MAX": 1900, "MOT_SPIN_MIN": 0.12,
              "MOT_SPIN_MAX": 0.95, "MOT_THST_EXPO": 0.55}
    thrust = np.linspace(0.0, 1.0, 21)
    e = params["MOT_THST_EXPO"]
    r = ((e - 1) + np.sqrt((1 - e) ** 2 + 4 * e * thrust)) / (2 * e)
    act = params["MOT_SPIN_MIN"] + (params["MOT_SPIN_MAX"] - params["MOT_SPIN_MIN"]) * r
    pwm = params["MOT_PWM_MIN"] + (params["MOT_PWM_MAX"] - params["MOT_PWM_MIN"]) * act
    assert np.allclose(pwm_to_thrust(pwm, params), thrust, atol=1e-9)


@pytest.mark.parametrize(("name", "value", "said"), [
    ("MOT_THST_EXPO", 1e9, "MOT_THST_EXPO 1e+09 clipped to 1, as ArduPilot does"),
    ("MOT_THST_EXPO", float("nan"), "MOT_THST_EXPO nan: 0.65 assumed"),
    ("MOT_SPIN_MIN", float("nan"), "MOT_SPIN_MIN nan, MOT_SPIN_MAX 0.95: not a spin range"),
    ("MOT_SPIN_MAX", 0.0, "MOT_SPIN_MIN 0.15, MOT_SPIN_MAX 0: not a spin range"),
    ("MOT_PWM_MAX", 1e9, "PWM range 1000..1e+09 us is no output's: 1000..2000 assumed"),
])
def test_damaged_motor_parameters_take_ardupilots_values_and_say_so(name, value, said):
    """Motor PWMs through a thrust curve of damaged parameters: MOT_THST_EXPO 1e9 made
    inputs 10^7 times too large, a NaN spin range made every input NaN, MOT_PWM_MAX 1e9 made
    them all 0 — silently. Now ArduPilot's own rule (the exponent clipped to [-1, 1]) or
    default is used, and the warning names the file and the value."""
    ok = {"MOT_PWM_MIN": 1000.0, "MOT_PWM_MAX": 2000.0, "MOT_SPIN_MIN": 0.15,
          "MOT_SPIN_MAX": 0.95, "MOT_THST_EXPO": 0.65, "FRAME_CLASS": 1.0, "FRAME_TYPE": 1.0}
    pwm = np.linspace(1200.0, 1800.0, 50)
    raw = table_log("dataflash", {"RCOU": {f"C{i}": pwm for i in range(1, 5)}})
    fixed = {**ok, name: value}
    if name == "MOT_THST_EXPO" and value > 1:
        ok["MOT_THST_EXPO"] = 1.0  # (what ArduPilot flies with)
    preset = PRESETS["ardupilot-rcou"]
    told = f"x.dataflash: motor parameters that are no motor's (damaged?): {said}"
    with pytest.warns(DataQualityWarning, match=re.escape(told)):
        _, got = motor_thrusts(replace(raw, params=fixed), preset, MIXERS["quad-x"])
    assert np.allclose(got[:, 0], pwm_to_thrust(pwm, ok))
    assert thrust_curve(ok)[1] == []


# --------------------------------------------------------------------------- mixers


#: frames whose ArduPilot factors do not cancel at equal thrust: the V-tails' rear motors
#: tilt; octa V's pitch factors sum to 0.04 and the default Y6's (0.666/1.333) to 0.002
_UNBALANCED = {"quad-vtail", "quad-atail", "octa-v", "y6"}


@pytest.mark.parametrize("name", sorted(MIXERS))
def test_mixer_geometry_and_inverse(name):
    m = MIXERS[name]
    f = m.factors()
    if m.angle_deg:
        angles = np.radians(m.angle_deg)
        pitch_angles = np.radians(m.pitch_angle_deg or m.angle_deg)
        # a motor on the right (0 < angle < 180) must slow down for a right roll (roll factor
        # < 0); a motor in front must speed up for nose up
        right = (np.sin(angles) > 1e-6)
        front = (np.cos(pitch_angles) > 1e-6)
        assert np.all(f[right, 0] < 0) and np.all(f[~right & (np.sin(angles) < -1e-6), 0] > 0)
        assert np.all(f[front, 1] > 0)
    # balanced frame: no net roll, pitch or yaw at equal thrust
    if name not in _UNBALANCED:
        assert np.allclose(f.sum(axis=0), 0.0, atol=1e-12)
    # each axis scaled on its own to 0.5, as ArduPilot's normalise_rpy_factors
    top = np.abs(f).max(axis=0)
    assert np.allclose(top[:2], 0.5) and top[2] in (0.0, 0.5)
    rng = np.random.default_rng(0)
    u = np.column_stack([rng.uniform(-0.2, 0.2, (50, 3)), rng.uniform(0.2, 0.6, 50)])
    motors = u[:, 3:] + u[:, :3] @ f.T
    assert np.allclose(m.unmix(motors), u, atol=1e-12)


def test_mixer_factors_are_ardupilots_normalised_per_axis():
    """Factors computed by hand from ArduPilot's tables (AP_MotorsMatrix), roll, pitch and
    yaw each scaled to a largest magnitude of 0.5. A hexa-X's pitch factors are ±0.5, not
    ±0.433 (cos 30° of a scale shared with roll): unmixed with the shared scale, its pitch
    input came out 15 % large and its control effectiveness 13 % low."""
    h = 0.5
    expect = {
        # motor angles 90, -90, -30, 150, 30, -150; CW, CCW, CW, CCW, CCW, CW
        "hexa-x": [[-0.5, 0.0, -0.5], [0.5, 0.0, 0.5], [0.25, 0.5, -0.5],
                   [-0.25, -0.5, 0.5], [-0.25, 0.5, 0.5], [0.25, -0.5, -0.5]],
        # motor angles 0, 180, -120, 60, -60, 120
        "hexa-plus": [[0.0, 0.5, -0.5], [0.0, -0.5, 0.5], [0.5, -0.25, -0.5],
                      [-0.5, 0.25, 0.5], [0.5, 0.25, 0.5], [-0.5, -0.25, -0.5]],
        # raw roll -1, -1, 0, 0, 1, 1; pitch 0.5, 0.5, -1, -1, 0.5, 0.5; top CW, bottom CCW
        "y6b": [[-0.5, 0.25, -0.5], [-0.5, 0.25, 0.5], [0.0, -0.5, -0.5],
                [0.0, -0.5, 0.5], [0.5, 0.25, -0.5], [0.5, 0.25, 0.5]],
        # coaxial X8: 45 CCW, -45 CW, -135 CCW, 135 CW, -45 CCW, 45 CW, 135 CCW, -135 CW
        "octaquad-x": [[-h, h, h], [h, h, -h], [h, -h, h], [-h, -h, -h],
                       [h, h, h], [-h, h, -h], [-h, -h, h], [h, -h, -h]],
        # raw roll -1, 0, 0, 1; pitch 1, -1, -1, 1; CCW, CW, CCW, CW
        "quad-y4": [[-0.5, 0.5, 0.5], [0.0, -0.5, -0.5], [0.0, -0.5, 0.5], [0.5, 0.5, -0.5]],
        # V-tail: roll from the front motors (roll angles ±60), yaw from the rear only
        "quad-vtail": [[-0.5, 0.5 * 0.5 / np.cos(np.radians(20)), 0.0], [0.0, -0.5, -0.5],
                       [0.5, 0.5 * 0.5 / np.cos(np.radians(20)), 0.0], [0.0, -0.5, 0.5]],
    }
    for name, rows in expect.items():
        assert np.allclose(MIXERS[name].factors(), rows, atol=1e-9), name


def test_mixer_chosen_from_frame_params():
    from mavsid.autopilot.presets import mixer_for

    p = PRESETS["mavlink-servo"]
    assert mixer_for(p, {"FRAME_CLASS": 1, "FRAME_TYPE": 1}).name == "quad-x"
    assert mixer_for(p, {"FRAME_CLASS": 2, "FRAME_TYPE": 0}).name == "hexa-plus"
    assert mixer_for(p, {}).name == "quad-x"
    # ArduPilot's frame classes and types (AP_Motors_Class.h)
    for (cls, kind), name in {(1, 3): "quad-h", (1, 12): "quad-bf-x", (1, 13): "quad-dji-x",
                              (1, 19): "quad-y4", (2, 3): "hexa-h", (3, 15): "octa-i",
                              (4, 1): "octaquad-x", (4, 18): "octaquad-bf-x-rev",
                              (5, 10): "y6b", (5, 11): "y6f", (5, 1): "y6",
                              (12, 0): "dodecahexa-plus", (14, 14): "deca-x"}.items():
        assert mixer_for(p, {"FRAME_CLASS": cls, "FRAME_TYPE": kind}).name == name
    assert mixer_for(p, {"FRAME": 3}, n_motors=4).name == "quad-h"  # ArduCopter 3.4: FRAME
    # a frame without a mixer here (a heli's swash servos, a tricopter, a QuadPlane's frame
    # without yaw torque) is never unmixed as a quad: a typed error naming the frame
    for params, name in (({"FRAME_CLASS": 6, "FRAME_TYPE": 0}, "heli"),
                         ({"FRAME_CLASS": 7, "FRAME_TYPE": 0}, "tri"),
                         ({"FRAME_CLASS": 1, "FRAME_TYPE": 16}, "quad, type 16")):
        with pytest.raises(ConfigError, match=f"no mixer for FRAME_CLASS .*\\({name}\\)"):
            mixer_for(p, params)


def test_motor_outputs_follow_servo_functions():
    """Motors on other outputs (SERVOn_FUNCTION 33.. for motors 1-8, 82.. for 9-12) are read
    from them; a frame with more motors than outputs carry is a typed error."""
    from mavsid.autopilot.ardupilot import motor_channels

    params = {f"SERVO{n}_FUNCTION": 0.0 for n in range(1, 17)}
    params.update({"SERVO9_FUNCTION": 34, "SERVO10_FUNCTION": 33, "SERVO11_FUNCTION": 35,
                   "SERVO12_FUNCTION": 36, "SERVO3_FUNCTION": 37, "SERVO4_FUNCTION": 38,
                   "SERVO13_FUNCTION": 39, "SERVO14_FUNCTION": 40, "SERVO15_FUNCTION": 82,
                   "SERVO16_FUNCTION": 83})
    assert motor_channels(params, 10) == [10, 9, 11, 12, 3, 4, 13, 14, 15, 16]
    assert motor_channels({}, 6) == [1, 2, 3, 4, 5, 6]
    with pytest.raises(ConfigError, match=r"motor\(s\) 11, 12 of 12 \(SERVOn_FUNCTION 84, 85\)"):
        motor_channels(params, 12)


def test_a_heli_log_without_rate_gets_no_quad_mixed_inputs(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The motor-output preset on a frame with no mixer here: states, no inputs, a warning
    naming the frame (it was unmixed as quad-X without a word)."""
    import warnings

    from mavsid.align import align
    from mavsid.errors import DataQualityWarning

    t = np.arange(0.0, 20.0, 0.01)
    att = MessageTable("ATT", {"Roll": np.sin(t), "Pitch": np.cos(t), "Yaw": t * 0}, t)
    imu = MessageTable("IMU", {"GyrX": np.cos(t), "GyrY": -np.sin(t), "GyrZ": t * 0}, t)
    rcou = MessageTable("RCOU", {f"C{i}": 1500 + 100 * np.sin(t + i) for i in range(1, 9)}, t)
    raw = RawLog(SourceInfo("heli.bin", "dataflash", 0), {"ATT": att, "IMU": imu, "RCOU": rcou},
                 params={"FRAME_CLASS": 6.0, "FRAME_TYPE": 0.0}, autopilot="ardupilot",
                 vehicle="copter")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fd = align(raw, "ardupilot-rcou")
    assert fd.input_names == ()
    assert any(issubclass(w.category, DataQualityWarning) and "(heli)" in str(w.message)
               and "not unmixed" in str(w.message) for w in caught)


# --------------------------------------------------------------------------- choosing


@pytest.mark.parametrize(
    ("path", "expected"),
    [
        (("sitl", "flightA_mixer.BIN"), "ardupilot-rate"),
        (("sitl", "flightA_mixer.tlog"), "mavlink-servo"),
        (("public", "Auterion__px4-ulog-rs", "quadrotor_local.ulg"), "px4-torque"),
        (("public", "PX4__pyulog", "sample.ulg"), "px4-legacy"),
        (("public", "ArduPilot__ardupilot", "underpowered.log"), "ardupilot-att"),
    ],
)
def test_preset_chosen_from_log_content(path, expected):
    from mavsid.align import FLAG_MESSAGES
    from mavsid.autopilot.presets import preset_messages
    from mavsid.readers import read_log, sniff_format

    p = shared_path(*path)
    fmt = sniff_format(p)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        raw = read_log(p, messages=[*preset_messages(fmt), *FLAG_MESSAGES.get(fmt, ())])
    assert choose_preset(raw).name == expected


def test_no_preset_fits_names_what_is_missing():
    raw = table_log("dataflash", {"GPS": {"Lat": np.zeros(3)}})
    with pytest.raises(MissingMessageError, match="ATT"):
        choose_preset(raw)
    with pytest.raises(ConfigError, match="unknown channel preset"):
        get_preset("nope")


# --------------------------------------------------------------------------- TOML


def test_toml_presets_and_mixers(tmp_path):
    f = tmp_path / "p.toml"
    f.write_text(
        """
[preset.my-quad]
formats = ["dataflash"]
mixer = "my-tri"
[preset.my-quad.states]
roll = { message = "AHR2", field = "Roll", unit = "deg" }
p = { message = "GYR", field = "GyrX", unit = "rad/s" }
[preset.my-quad.inputs]
u_roll = { message = "CTRL", field = "R", scale = -1.0 }

[mixer.my-tri]
angle_deg = [60, -60, 180]
yaw = [0, 0, 0]
""",
        encoding="utf-8",
    )
    presets, mixers = load_presets(f)
    p = presets["my-quad"]
    assert p.requires == ("AHR2", "GYR", "CTRL") and p.mixer == "my-tri"
    assert mixers["my-tri"].n_motors == 3
    raw = table_log("dataflash", {"AHR2": {"Roll": np.array([90.0, 0.0])},
                             "GYR": {"GyrX": np.array([0.1, 0.2])},
                             "CTRL": {"R": np.array([0.3, 0.4])}})
    assert choose_preset(raw, presets).name == "my-quad"
    assert np.allclose(evaluate(raw, p.inputs["u_roll"])[1], [-0.3, -0.4])
    assert np.allclose(evaluate(raw, p.states["roll"])[1], [math.pi / 2, 0.0])


_ROLL = "roll = { message = 'ATT', field = 'Roll', unit = 'deg' }\n"


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("[preset.a\n", "not valid TOML"),
        ("[preset.a.states]\nroll = { message = 'ATT', field = 'Roll', unit = 'furlong' }\n",
         "unknown unit"),
        ("[preset.a.states]\nroll = { message = 'ATT', field = 'Roll', colour = 1 }\n",
         "unknown key"),
        ("[preset.a.states]\nalpha = { message = 'ATT', field = 'A' }\n", "unknown state"),
        ("[preset.a]\nstates = {}\n", "defines no states"),
        ("[mixer.m]\nangle_deg = [1, 2]\nyaw = [1]\n", "same number"),
        ("[mixer.m]\nangle_deg = [1, 2, 3]\nyaw = [1, 1, 1]\ntilt = [0, 0, 0]\n",
         "unknown key.*tilt"),
        ("[mixer.m]\nangle_deg = '45'\nyaw = [1, 1, 1, 1]\n", "angle_deg must be a list"),
        ("[mixer.m]\nroll = [1, -1, 0, 0]\npitch = [0, 0, 'a', 1]\nyaw = [1, 1, -1, -1]\n",
         "pitch must be a list of numbers"),
        ("[mixer.m]\nangle_deg = [45, -135, nan, 135]\nyaw = [1, 1, -1, -1]\n",
         "not a finite number"),
        ("[mixer.m]\nangle_deg = [60, -60, 180]\nyaw = [0, 0, 1]\n",
         "cannot set roll, pitch, yaw and thrust apart"),
        ("[mixer.m]\nangle_deg = [0, 0, 180, 180]\nyaw = [1, 1, -1, -1]\n",
         "cannot set pitch, yaw and thrust apart"),
        ("[mixer.m]\nroll = [1, -1]\nangle_deg = [0, 90]\nyaw = [1, 1]\n", "same number"),
        ("mixer = 3\n", "mixer must be a table"),
        # wrong types took a traceback, or were read as something else (a string's letters)
        ("[preset.a]\nstates = 3\n", "states must be a table"),
        ("[preset.a]\nformats = 'ulog'\n[preset.a.states]\n" + _ROLL, "formats must be a list"),
        ("[preset.a]\nformats = ['ulg']\n[preset.a.states]\n" + _ROLL, "unknown formats 'ulg'"),
        ("[preset.a]\nrequires = 5\n[preset.a.states]\n" + _ROLL, "requires must be a list"),
        ("[preset.a]\nvehicles = 'plane'\n[preset.a.states]\n" + _ROLL,
         "vehicles must be a list"),
        ("[preset.a]\nmixer = [3]\n[preset.a.states]\n" + _ROLL, "unknown mixer"),
        ("[preset.a]\nmotors = { message = 'RCOU', field = 'C{i}', unit = 'deg' }\n"
         "[preset.a.states]\n" + _ROLL, "motor and servo outputs are PWM"),
        ("[preset.a]\nmotors = { message = 'RCOU', field = 'C{i}' }\n"
         "servos = { message = 'RCOU', field = 'C{i}' }\n[preset.a.states]\n" + _ROLL,
         "motors .* or servos, not both"),
        ("[preset.a.states]\nroll = { message = 'ATT', field = 'Roll', unit = 'pwm' }\n",
         "only motors and servos take PWM"),
        ("[preset.a.states]\nroll = { message = 'ATT', field = 'Roll', scale = 'x' }\n",
         "scale must be a finite number"),
        ("[preset.a.states]\nroll = { message = 'ATT', field = 'Roll', scale = nan }\n",
         "scale must be a finite number"),
        ("[preset.a.states]\nroll = { message = 'ATT', field = 'Roll', instance = 'x' }\n",
         "instance must be a whole number"),
        ("[preset.a.states]\nroll = { message = 'ATT', field = 'Roll', transform = 'q' }\n",
         "unknown transform 'q'"),
        ("[preset.a.states]\nroll = { message = 'ATT', field = 'Roll', optional = 'y' }\n",
         "optional must be true or false"),
        ("[preset.a.states]\nroll = { message = 'ATT', field = '' }\n",
         "field must be a non-empty string"),
        ("preset = 'x'\n", "preset must be a table"),
        ("[mixer]\nm = 3\n", "mixer 'm': must be a table"),
        ("[other]\nx = 1\n", "unknown table"),
    ],
)
def test_bad_toml_is_a_config_error(tmp_path, text, match):
    f = tmp_path / "bad.toml"
    f.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError, match=match):
        load_presets(f)


@pytest.mark.parametrize("name", sorted(MIXERS))
def test_every_built_in_mixer_can_be_written_in_toml(tmp_path, name):
    """Each built-in motor matrix copied into a TOML file (raw factors where ArduPilot gives
    them, directions otherwise) is read back with the same factors: a user can start from
    any of them."""
    m = MIXERS[name]
    keys = ({"roll": m.roll, "pitch": m.pitch} if m.roll else
            {"angle_deg": m.angle_deg, **({"pitch_angle_deg": m.pitch_angle_deg}
                                          if m.pitch_angle_deg else {})})
    lines = [f"{k} = [{', '.join(str(float(v)) for v in vals)}]"
             for k, vals in {**keys, "yaw": m.yaw}.items()]
    f = tmp_path / "m.toml"
    f.write_text("[mixer.copy]\n" + "\n".join(lines) + "\n", encoding="utf-8")
    _, mixers = load_presets(f)
    assert np.allclose(mixers["copy"].factors(), m.factors())


def test_missing_toml_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="cannot open"):
        load_presets(tmp_path / "none.toml")


def test_px4s_commanded_attitude_is_its_own_roll_pitch_and_yaw_setpoint() -> None:
    """The commanded attitude (the instruments of mavsid.estimators.instruments) from PX4's
    setpoint quaternion ``q_d`` is the setpoint's own Euler angles ``roll_body`` /
    ``pitch_body`` / ``yaw_body`` where a log has both (PX4 computed those, not mavsid; yaw
    compared across its wrap at ±180 deg)."""
    from mavsid.autopilot.presets import DESIRED_CHANNELS
    from mavsid.readers import read_log

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        raw = read_log(shared_path("public", "Auterion__px4-ulog-rs", "esc_status_log.ulg"),
                       messages=["vehicle_attitude_setpoint"])
    table = raw["vehicle_attitude_setpoint"]
    for axis in ("roll", "pitch", "yaw"):
        channel = next(c for c in DESIRED_CHANNELS[axis] if c.message == table.name)
        _, got = evaluate(raw, channel)
        ref = np.asarray(table[f"{axis}_body"], float)
        assert np.std(ref) > 0.1  # (a flight that moves)
        np.testing.assert_allclose(np.angle(np.exp(1j * (got - ref))), 0.0, atol=1e-6)


def test_motors_on_remapped_outputs_are_unmixed_from_them() -> None:
    """A quad whose motors sit on outputs 5-8 (SERVO5..8_FUNCTION 33-36), outputs 1-4
    carrying something else: the unmixed inputs are the motors', as with motors on 1-4;
    a frame whose motors the outputs do not all carry gives no inputs and says why."""
    import warnings

    from mavsid.align import align
    from mavsid.errors import DataQualityWarning

    t = np.arange(0.0, 20.0, 0.01)
    u = np.column_stack([0.1 * np.sin(3 * t), 0.08 * np.cos(5 * t), 0.05 * np.sin(7 * t)])
    thrust = 0.45 + u @ MIXERS["quad-x"].factors().T  # motors 1-4
    params = {"FRAME_CLASS": 1.0, "FRAME_TYPE": 1.0, "MOT_THST_EXPO": 0.0,
              "MOT_SPIN_MIN": 0.0, "MOT_SPIN_MAX": 1.0, "MOT_PWM_MIN": 1000.0,
              "MOT_PWM_MAX": 2000.0}
    pwm = 1000.0 + 1000.0 * thrust
    att = MessageTable("ATT", {"Roll": np.sin(t), "Pitch": np.cos(t), "Yaw": t * 0}, t)
    imu = MessageTable("IMU", {"GyrX": np.cos(t), "GyrY": -np.sin(t), "GyrZ": t * 0}, t)

    def inputs(columns: dict[str, np.ndarray], extra: dict[str, float]) -> np.ndarray:
        rcou = MessageTable("RCOU", columns, t)
        raw = RawLog(SourceInfo("q.bin", "dataflash", 0), {"ATT": att, "IMU": imu, "RCOU": rcou},
                     params={**params, **extra}, autopilot="ardupilot", vehicle="copter")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fd = align(raw, "ardupilot-rcou")
        return np.asarray(fd.inputs)[:, :3]

    plain = inputs({f"C{i}": pwm[:, i - 1] for i in range(1, 5)}, {})
    gimbal = 1500 + 300 * np.sin(0.3 * t)
    moved = {**{f"C{i}": gimbal for i in range(1, 5)},
             **{f"C{i}": pwm[:, i - 5] for i in range(5, 9)}}
    functions = {"SERVO1_FUNCTION": 7.0, "SERVO2_FUNCTION": 8.0, "SERVO3_FUNCTION": 0.0,
                 "SERVO4_FUNCTION": 0.0, **{f"SERVO{i}_FUNCTION": 28.0 + i for i in range(5, 9)}}
    remapped = inputs(moved, functions)
    assert np.allclose(plain, u, atol=1e-6) and np.allclose(remapped, u, atol=1e-6)
    # a hexa frame on outputs that carry four motors: no inputs, a warning naming motors 5, 6
    rcou = MessageTable("RCOU", moved, t)
    raw = RawLog(SourceInfo("h.bin", "dataflash", 0), {"ATT": att, "IMU": imu, "RCOU": rcou},
                 params={**params, **functions, "FRAME_CLASS": 2.0}, autopilot="ardupilot",
                 vehicle="copter")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fd = align(raw, "ardupilot-rcou")
    assert fd.input_names == ()
    assert any(issubclass(w.category, DataQualityWarning) and "motor(s) 5, 6 of 6" in
               str(w.message) for w in caught)


@pytest.mark.parametrize(("params", "said"), [
    ({"FRAME_CLASS": float("nan")}, "not numbers (a damaged log): quad-X assumed"),
    ({"FRAME": float("inf")}, "not numbers (a damaged log): quad-X assumed"),
    ({"FRAME_CLASS": 2.0, "FRAME_TYPE": float("nan")}, "FRAME_TYPE not a number: X assumed"),
])
def test_damaged_frame_parameters_are_said_not_a_crash(params, said) -> None:  # type: ignore[no-untyped-def]
    """A NaN or infinite FRAME_CLASS/FRAME_TYPE/FRAME (a damaged PARM record) raised
    ValueError out of the motor-output preset; now the frame is assumed and said so, and
    non-number SERVOn_FUNCTIONs leave the motors on outputs 1..n."""
    import warnings

    from mavsid.align import align
    from mavsid.autopilot.ardupilot import motor_channels

    t = np.arange(0.0, 20.0, 0.01)
    att = MessageTable("ATT", {"Roll": np.sin(t), "Pitch": np.cos(t), "Yaw": t * 0}, t)
    motors = 6 if params.get("FRAME_CLASS") == 2.0 else 4  # (the other outputs unused)
    rcou = MessageTable("RCOU", {f"C{i}": (1500 + 100 * np.sin(t + i)) * (i <= motors)
                                 for i in range(1, 9)}, t)
    raw = RawLog(SourceInfo("x.bin", "dataflash", 0), {"ATT": att, "RCOU": rcou},
                 params=params, autopilot="ardupilot", vehicle="copter")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fd = align(raw, "ardupilot-rcou")
    assert fd.input_names[:3] == ("u_roll", "u_pitch", "u_yaw")
    assert any(said in str(w.message) for w in caught), [str(w.message) for w in caught]
    bad = {"SERVO1_FUNCTION": float("nan"), "SERVO2_FUNCTION": 1e300, "SERVO3_FUNCTION": 7.0}
    assert motor_channels(bad, 4) == [1, 2, 3, 4]
