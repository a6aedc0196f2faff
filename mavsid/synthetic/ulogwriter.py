"""Write a simulated flight as a PX4 ULog ``.ulg`` file, in the topic set of a PX4 generation.

The file follows the ULog format as PX4 documents it: the 16-byte header (magic, version 1,
start time in µs), a flag-bits message, then the definitions (``F`` formats, ``I`` info such
as ``sys_name`` and ``ver_sw_release``, ``P`` parameters) and the data section (``A``
subscriptions, ``D`` records in time order, ``L`` logged strings). Every data record starts
with its topic's ``uint64_t timestamp`` (µs since boot). Records are built column-wise in
numpy structured arrays and merged into one buffer by a stable sort on time.

Layouts (:data:`ULOG_LAYOUTS`) are the topic sets mavsid's presets meet in the field:

``px4-1.14``
    ``vehicle_angular_velocity``, ``vehicle_torque_setpoint``,
    ``vehicle_thrust_setpoint``, ``actuator_motors`` (PX4 ≥ 1.14)
``px4-1.11``
    ``vehicle_angular_velocity``, ``actuator_controls_0``, ``actuator_outputs``
``px4-1.8``
    body rates in ``vehicle_attitude`` (``rollspeed``...), ``actuator_controls_0``

plus, in each, ``vehicle_attitude.q``, ``vehicle_rates_setpoint``,
``vehicle_attitude_setpoint`` (``q_d``; also ``roll_body``... before 1.14; published only
outside ACRO, where the attitude controller runs), ``sensor_combined``,
``vehicle_status`` (``nav_state``, ``arming_state``), ``vehicle_land_detected`` and the
rate-controller parameters under PX4's names (``MC_ROLLRATE_P``...). The plant and
controller are the simulator's own (ArduPilot-style PID gains written as PX4's P, I, D, FF
with K = 1): a simulated ULog tests reading, units and identification on PX4's layouts, not
PX4's rate controller.

Examples
--------
>>> import tempfile, os
>>> from mavsid.synthetic.flight import Scenario, fly
>>> fl = fly(Scenario(manoeuvre="hover", duration_s=1.0))
>>> path = os.path.join(tempfile.mkdtemp(), "h.ulg")
>>> write_ulog(fl, path) > 10_000
True
>>> open(path, "rb").read(7) == b"ULog\\x01\\x12\\x35"
True
"""

from __future__ import annotations

import os
import struct
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from mavsid.errors import ConfigError
from mavsid.numerics.rotations import euler_to_quat
from mavsid.readers.ulog_spec import BASIC_TYPES, MAGIC
from mavsid.synthetic.faults import Faults
from mavsid.synthetic.flight import MODE_SYSTEMID, Flight

__all__ = ["ULOG_LAYOUTS", "ULOG_RELEASES", "write_ulog"]

#: PX4 generations whose topic sets :func:`write_ulog` writes
ULOG_LAYOUTS = ("px4-1.14", "px4-1.11", "px4-1.8")
#: ``ver_sw_release`` (0xMMmmpptt, tt = 255 for a release) written for each layout
ULOG_RELEASES = {"px4-1.14": 0x010E00FF, "px4-1.11": 0x010B03FF, "px4-1.8": 0x010802FF}

#: PX4 vehicle_status.nav_state for the simulator's modes: its SYSTEMID chirps fly in ACRO
#: (10, not self-levelling), everything else in STAB (15)
_NAV_STATE = {MODE_SYSTEMID: 10}
_NAV_STAB = 15


def _topics(layout: str) -> dict[str, tuple[tuple[str, str], ...]]:
    """Each topic's fields ``(type, name)`` in the order they are packed."""
    ts = (("uint64_t", "timestamp"),)
    sample = (*ts, ("uint64_t", "timestamp_sample"))
    att_rates = (("float", "rollspeed"), ("float", "pitchspeed"), ("float", "yawspeed"))
    topics: dict[str, tuple[tuple[str, str], ...]] = {
        "vehicle_attitude": (*(sample if layout != "px4-1.8" else ts),
                             *(att_rates if layout == "px4-1.8" else ()),
                             ("float[4]", "q"), ("float[4]", "delta_q_reset"),
                             ("uint8_t", "quat_reset_counter")),
        "vehicle_rates_setpoint": (*ts, ("float", "roll"), ("float", "pitch"),
                                   ("float", "yaw"), ("float[3]", "thrust_body"),
                                   ("bool", "reset_integral")),
        "sensor_combined": (*ts, ("float[3]", "gyro_rad"), ("uint32_t", "gyro_integral_dt"),
                            ("int32_t", "accelerometer_timestamp_relative"),
                            ("float[3]", "accelerometer_m_s2")),
        "vehicle_status": (*ts, ("uint8_t", "nav_state"), ("uint8_t", "arming_state"),
                           ("uint8_t", "vehicle_type")),
        "vehicle_land_detected": (*ts, ("bool", "landed"), ("bool", "maybe_landed")),
    }
    # the attitude controller's output (published in the attitude-stabilised modes only)
    if layout == "px4-1.14":  # (roll_body... gone since 1.14: the quaternion q_d alone)
        topics["vehicle_attitude_setpoint"] = (*ts, ("float", "yaw_sp_move_rate"),
                                               ("float[4]", "q_d"), ("float[3]", "thrust_body"),
                                               ("bool", "reset_integral"),
                                               ("bool", "fw_control_yaw_wheel"))
    else:
        topics["vehicle_attitude_setpoint"] = (*ts, ("float", "roll_body"),
                                               ("float", "pitch_body"), ("float", "yaw_body"),
                                               ("float", "yaw_sp_move_rate"), ("float[4]", "q_d"),
                                               ("float[3]", "thrust_body"))
    if layout != "px4-1.8":
        topics["vehicle_angular_velocity"] = (*sample, ("float[3]", "xyz"),
                                              ("float[3]", "xyz_derivative"))
    if layout == "px4-1.14":
        topics["vehicle_torque_setpoint"] = (*sample, ("float[3]", "xyz"))
        topics["vehicle_thrust_setpoint"] = (*sample, ("float[3]", "xyz"))
        topics["actuator_motors"] = (*sample, ("uint16_t", "reversible_flags"),
                                     ("float[12]", "control"))
    else:
        topics["actuator_controls_0"] = (*sample, ("float[8]", "control"))
        topics["actuator_outputs"] = (*ts, ("uint32_t", "noutputs"), ("float[16]", "output"))
    return topics


def _dtype(fields: Sequence[tuple[str, str]]) -> np.dtype:
    """Packed numpy dtype of a topic's payload (ULog has no implicit padding)."""
    out: list[tuple[Any, ...]] = []
    for typ, name in fields:
        base, _, count = typ.partition("[")
        dt = BASIC_TYPES[base].dtype
        out.append((name, dt, (int(count[:-1]),)) if count else (name, dt))
    return np.dtype(out)


def _message(kind: bytes, payload: bytes) -> bytes:
    if len(payload) > 0xFFFF:
        raise ConfigError(f"ULog message {kind!r} of {len(payload)} bytes is too long")
    return struct.pack("<HB", len(payload), kind[0]) + payload


def _keyed(kind: bytes, typ: str, name: str, value: bytes) -> bytes:
    key = f"{typ} {name}".encode()
    return _message(kind, bytes([len(key)]) + key + value)


def _params(flight: Flight, layout: str) -> dict[str, float | int]:
    """The simulated controller's gains and filters under PX4's parameter names."""
    sc = flight.scenario
    c = sc.controller
    out: dict[str, float | int] = {}
    for axis, ax, lim in (("roll", "ROLL", "RR"), ("pitch", "PITCH", "PR"), ("yaw", "YAW", "YR")):
        g = c.rate_gains(axis)
        out.update({f"MC_{ax}RATE_P": g.p, f"MC_{ax}RATE_I": g.i, f"MC_{ax}RATE_D": g.d,
                    f"MC_{ax}RATE_FF": g.ff, f"MC_{ax}RATE_K": 1.0, f"MC_{lim}_INT_LIM": g.imax,
                    f"MC_{ax}_P": c.angle_p(axis)})
    out["IMU_GYRO_CUTOFF"] = sc.plant.gyro_filter_hz
    out["IMU_DGYRO_CUTOFF"] = 30.0
    if layout != "px4-1.8":
        out["IMU_GYRO_RATEMAX"] = int(c.loop_hz)
    out["SYS_AUTOSTART"] = 4001  # generic quadcopter X
    out["MAV_TYPE"] = 2
    if layout == "px4-1.14":
        out["CA_AIRFRAME"] = 0
    out["SDLOG_PROFILE"] = 3  # default + high rate (rate controller topics at full rate)
    return dict(sorted(out.items()))


def _every(flight: Flight, hz: float) -> np.ndarray:
    """Loop indices at ``hz`` (the nearest divisor of the loop rate)."""
    step = max(1, round(flight.scenario.controller.loop_hz / hz))
    return np.arange(0, len(flight), step)


def write_ulog(
    flight: Flight, path: str | os.PathLike[str], faults: Faults | None = None,
    layout: str = "px4-1.14",
) -> int:
    """Write ``flight`` as a PX4 ULog file; returns its size in bytes.

    Parameters
    ----------
    flight : Flight
    path : path-like
    faults : Faults
        Dropped data records and a truncated tail (a ULog holds one boot: a reboot fault is
        refused).
    layout : str
        One of :data:`ULOG_LAYOUTS`.

    Raises
    ------
    ConfigError
        Unknown layout, or a reboot fault.
    """
    if layout not in ULOG_LAYOUTS:
        raise ConfigError(f"unknown layout {layout!r} for a .ulg; choose from "
                          f"{', '.join(ULOG_LAYOUTS)}")
    faults = faults or Faults()
    if faults.reboot_at_s is not None:
        raise ConfigError(f"{path}: a ULog file holds one boot: no reboot fault")
    sc = flight.scenario
    tus = np.round(flight.t_s * 1e6).astype(np.uint64)
    topics = _topics(layout)
    ids = {name: k for k, name in enumerate(topics)}
    dtypes = {name: _dtype(fields) for name, fields in topics.items()}

    head = bytearray(MAGIC + b"\x01" + struct.pack("<Q", int(tus[0])))
    head += _message(b"B", bytes(16) + bytes(24))  # no compat/incompat flags, no appended data
    for name, fields in topics.items():
        text = f"{name}:" + "".join(f"{t} {f};" for t, f in fields)
        head += _message(b"F", text.encode())
    info = {"sys_name": b"PX4", "ver_hw": b"SITL", "sys_toolchain": b"mavsid",
            "ver_sw": b"0123456789abcdef0123456789abcdef01234567"}
    for key, value in info.items():
        head += _keyed(b"I", f"char[{len(value)}]", key, value)
    head += _keyed(b"I", "uint32_t", "ver_sw_release", struct.pack("<I", ULOG_RELEASES[layout]))
    for key, val in _params(flight, layout).items():
        head += (_keyed(b"P", "int32_t", key, struct.pack("<i", val)) if isinstance(val, int)
                 else _keyed(b"P", "float", key, struct.pack("<f", val)))
    for name, k in ids.items():
        head += _message(b"A", struct.pack("<BH", 0, k) + name.encode())

    parts: list[tuple[np.ndarray, np.ndarray]] = []  # (time, records as bytes rows)

    def add(name: str, idx: np.ndarray, cols: Mapping[str, Any]) -> None:
        idx = np.asarray(idx)
        if faults.drop_fraction:
            idx = idx[faults.keep_mask(len(idx), salt=name)]
        if not len(idx):
            return
        dt = dtypes[name]
        rec = np.zeros(len(idx), np.dtype([("size", "<u2"), ("kind", "u1"), ("id", "<u2"),
                                           ("payload", dt)]))
        rec["size"], rec["kind"], rec["id"] = 2 + dt.itemsize, ord("D"), ids[name]
        pay = rec["payload"]
        pay["timestamp"] = tus[idx]
        if "timestamp_sample" in (dt.names or ()):
            pay["timestamp_sample"] = tus[idx]
        for key, value in cols.items():
            v = np.asarray(value)
            pay[key] = v[idx] if v.ndim and len(v) == len(flight) else v
        parts.append((tus[idx], rec.view(np.uint8).reshape(len(idx), rec.dtype.itemsize)))

    step = sc.rates.step("rate", sc.controller.loop_hz)
    rate_hz = sc.controller.loop_hz / step
    fast = np.arange(0, len(flight), step)  # the rate controller's (SDLOG_PROFILE high rate)
    slow = _every(flight, min(rate_hz, 50.0))
    q = euler_to_quat(flight.attitude)
    att: dict[str, Any] = {"q": q}
    if layout == "px4-1.8":
        att.update(rollspeed=flight.gyro[:, 0], pitchspeed=flight.gyro[:, 1],
                   yawspeed=flight.gyro[:, 2])
        add("vehicle_attitude", fast, att)
    else:
        add("vehicle_attitude", slow, att)
        add("vehicle_angular_velocity", fast, {"xyz": flight.gyro})
    thrust = flight.throttle
    thrust_body = np.column_stack([np.zeros_like(thrust), np.zeros_like(thrust), -thrust])
    add("vehicle_rates_setpoint", fast, {
        "roll": flight.rate_target[:, 0], "pitch": flight.rate_target[:, 1],
        "yaw": flight.rate_target[:, 2], "thrust_body": thrust_body})
    # the attitude setpoint where the attitude controller runs: not in ACRO (rates from the
    # sticks), so not during the SYSTEMID chirps
    nav = np.array([_NAV_STATE.get(int(m), _NAV_STAB) for m in flight.mode], dtype=np.uint8)
    stabilised = slow[nav[slow] == _NAV_STAB]
    target = flight.attitude_target
    setpoint: dict[str, Any] = {"q_d": euler_to_quat(target), "thrust_body": thrust_body}
    if layout != "px4-1.14":
        setpoint.update(roll_body=target[:, 0], pitch_body=target[:, 1], yaw_body=target[:, 2])
    add("vehicle_attitude_setpoint", stabilised, setpoint)
    if layout == "px4-1.14":
        add("vehicle_torque_setpoint", fast, {"xyz": flight.u})
        add("vehicle_thrust_setpoint", fast, {"xyz": thrust_body})
        motors = np.zeros((len(flight), 12))
        motors[:, :flight.motors.shape[1]] = flight.motors
        add("actuator_motors", slow, {"control": motors})
    else:
        controls = np.zeros((len(flight), 8))
        controls[:, :3], controls[:, 3] = flight.u, thrust
        add("actuator_controls_0", fast, {"control": controls})
        pwm = np.zeros((len(flight), 16))
        pwm[:, :flight.pwm.shape[1]] = flight.pwm
        add("actuator_outputs", slow, {"noutputs": flight.pwm.shape[1], "output": pwm})
    add("sensor_combined", slow, {"gyro_rad": flight.gyro_raw,
                                  "accelerometer_m_s2": flight.accel,
                                  "gyro_integral_dt": int(1e6 / min(rate_hz, 50.0))})
    # status at 1 Hz and at every mode change; landed never (the flight is airborne)
    one_hz = _every(flight, 1.0)
    change = np.flatnonzero(np.r_[True, nav[1:] != nav[:-1]])
    status = np.union1d(one_hz, change)
    add("vehicle_status", status, {"nav_state": nav, "arming_state": 2, "vehicle_type": 1})
    add("vehicle_land_detected", one_hz, {"landed": 0, "maybe_landed": 0})

    k_retune, changed = flight.retuned(lambda f: _params(f, layout)) or (0, {})
    for name, val in changed.items():  # (set in flight)
        msg = (_keyed(b"P", "int32_t", name, struct.pack("<i", val)) if isinstance(val, int)
               else _keyed(b"P", "float", name, struct.pack("<f", val)))
        parts.append((tus[[k_retune]], np.frombuffer(msg, np.uint8)[None, :]))
    times = np.concatenate([t for t, _ in parts])
    sizes = np.concatenate([np.full(len(t), r.shape[1]) for t, r in parts])
    flat = np.concatenate([r.ravel() for _, r in parts])
    starts = np.r_[0, np.cumsum(sizes)[:-1]]
    order = np.argsort(times, kind="stable")
    lengths = sizes[order]
    new_starts = np.r_[0, np.cumsum(lengths)[:-1]]
    gather = np.repeat(starts[order] - new_starts, lengths) + np.arange(int(lengths.sum()))
    texts = [(int(tus[0]), f"mavsid synthetic flight: manoeuvre={sc.manoeuvre} "
                           f"axis={sc.axis} seed={sc.seed}")]
    logged = b"".join(_message(b"L", struct.pack("<BQ", ord("6"), t) + m.encode())
                      for t, m in texts)
    data = bytes(head) + logged + flat[gather].tobytes()
    if faults.truncate_bytes:
        data = data[: max(0, len(data) - faults.truncate_bytes)]
    with open(path, "wb") as f:
        f.write(data)
    return len(data)
