"""Write a simulated flight as a ground station's MAVLink ``.tlog``.

Each record is the 8-byte big-endian receive time (µs since the UNIX epoch, the ground
station's wall clock) followed by one MAVLink 2 frame, encoded by pymavlink's own
``ardupilotmega`` encoder. The vehicle (system 1, component 1) streams ATTITUDE, SCALED_IMU,
SERVO_OUTPUT_RAW and RC_CHANNELS at the telemetry rate (``LogRates.tlog``, 50 Hz by default,
sampled from the loop), HEARTBEAT at 1 Hz, all parameters as PARAM_VALUE at the start (and
those a retune changes when it does, as the vehicle answers a PARAM_SET), and STATUSTEXT for
the firmware banner and SYSTEMID start/finish; the ground station's own HEARTBEAT (system
255) appears once a second. Receive times carry link latency with random jitter (never
running backwards); the messages' ``time_boot_ms``/``time_usec`` carry the
vehicle's clock.

Examples
--------
>>> import tempfile, os
>>> from mavsid.synthetic.flight import Scenario, fly
>>> fl = fly(Scenario(manoeuvre="hover", duration_s=1.0))
>>> path = os.path.join(tempfile.mkdtemp(), "h.tlog")
>>> write_tlog(fl, path) > 1000
True
"""

from __future__ import annotations

import os
import struct

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mavsid.errors import ConfigError
from mavsid.synthetic.faults import Faults
from mavsid.synthetic.flight import GRAVITY, Flight

__all__ = ["EPOCH_US", "write_tlog"]

#: ground-station wall clock at the flight's first sample: 2026-01-01T00:00:00Z
EPOCH_US = 1_767_225_600_000_000

_ARMED_BASE_MODE = (
    mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    | mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
    | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
    | mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
)


def _wrap_pi(x: np.ndarray) -> np.ndarray:
    return (x + np.pi) % (2 * np.pi) - np.pi


def write_tlog(
    flight: Flight, path: str | os.PathLike[str], faults: Faults | None = None
) -> int:
    """Write ``flight`` as a MAVLink 2 ``.tlog``; returns its size in bytes.

    Parameters
    ----------
    flight : Flight
    path : path-like
    faults : Faults
        Dropped frames (their sequence numbers are lost, as on a lossy link), a reboot
        (``time_boot_ms`` restarts from 5 s, the link is silent for 2 s) and a truncated tail.
    """
    faults = faults or Faults()
    sc = flight.scenario
    n = len(flight)
    loop_hz = sc.controller.loop_hz
    step = sc.rates.step("tlog", loop_hz)
    rng = np.random.default_rng([sc.seed, 0x7106])
    vehicle = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)

    # vehicle clock per loop sample, with the reboot fault applied
    boot = flight.t_s.copy()
    wall = flight.t_s - flight.t_s[0]
    if faults.reboot_at_s is not None:
        k = round(faults.reboot_at_s / flight.dt)
        if not 0 < k < n:
            raise ConfigError(f"reboot at {faults.reboot_at_s} s is outside the flight")
        boot[k:] = 5.0 + (flight.t_s[k:] - flight.t_s[k])
        wall[k:] += 2.0

    # (send time on the wall clock, order, frame)
    frames: list[tuple[float, int, bytes]] = []

    def emit(k: int, msg: mavlink.MAVLink_message, link: mavlink.MAVLink = vehicle) -> None:
        frames.append((float(wall[k]), len(frames), msg.pack(link)))

    ms = np.round(boot * 1e3).astype(np.int64)
    us = np.round(boot * 1e6).astype(np.int64)
    att = flight.attitude
    # banner and parameters at the start
    emit(0, vehicle.heartbeat_encode(
        mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, _ARMED_BASE_MODE,
        int(flight.mode[0]), mavlink.MAV_STATE_ACTIVE))
    emit(0, vehicle.statustext_encode(mavlink.MAV_SEVERITY_INFO, b"ArduCopter V4.5.7 (mavsid00)"))
    params = flight.params()
    for i, (name, value) in enumerate(params.items()):
        emit(0, vehicle.param_value_encode(name.encode(), float(value),
                                           mavlink.MAV_PARAM_TYPE_REAL32, len(params), i))
    retune = flight.retuned(Flight.params)  # (a PARAM_SET in flight, answered)
    hb_step = round(loop_hz)
    run = flight.run_index
    rc_in = flight.rc_in()
    for k in range(n):
        if k % hb_step == 0:
            if k:
                emit(k, vehicle.heartbeat_encode(
                    mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                    _ARMED_BASE_MODE, int(flight.mode[k]), mavlink.MAV_STATE_ACTIVE))
            emit(k, gcs.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID,
                                         0, 0, 0), gcs)
        if run[k] >= 0 and (k == 0 or run[k - 1] != run[k]):
            text = f"SystemID Starting: axis={sc.runs[run[k]].axis}".encode()
            emit(k, vehicle.statustext_encode(mavlink.MAV_SEVERITY_INFO, text))
        if run[k] >= 0 and (k == n - 1 or run[k + 1] != run[k]):
            emit(k, vehicle.statustext_encode(mavlink.MAV_SEVERITY_INFO, b"SystemID Finished"))
        if retune is not None and k == retune[0]:
            for name, value in retune[1].items():
                emit(k, vehicle.param_value_encode(name.encode(), float(value),
                                                   mavlink.MAV_PARAM_TYPE_REAL32, len(params),
                                                   list(params).index(name)))
        if k % step:
            continue
        g = flight.gyro[k]
        emit(k, vehicle.attitude_encode(int(ms[k]), float(att[k, 0]), float(att[k, 1]),
                                        float(_wrap_pi(att[k, 2])), float(g[0]), float(g[1]),
                                        float(g[2])))
        acc_mg = np.round(flight.accel[k] / GRAVITY * 1000.0).astype(int)
        gyr = np.round(flight.gyro[k] * 1000.0).astype(int)
        emit(k, vehicle.scaled_imu_encode(int(ms[k]), *map(int, acc_mg), *map(int, gyr),
                                          0, 0, 0, 4500))
        pwm = [int(v) for v in flight.pwm[k]] + [0] * (8 - flight.pwm.shape[1])
        emit(k, vehicle.servo_output_raw_encode(int(us[k]) & 0xFFFFFFFF, 0, *pwm))
        emit(k, vehicle.rc_channels_encode(int(ms[k]), 16, *map(int, rc_in[k]), *[0] * 10, 255))

    send = np.array([f[0] for f in frames])
    keep = faults.keep_mask(len(frames), salt="tlog")
    # latency: 12 ms + exponential jitter (mean 6 ms), never reordering the link
    recv = send + 0.012 + rng.exponential(0.006, len(frames))
    recv = np.maximum.accumulate(recv)
    recv_us = EPOCH_US + np.round(recv * 1e6).astype(np.int64)
    out = bytearray()
    for (_, _, frame), t, ok in zip(frames, recv_us, keep, strict=True):
        if ok:
            out += struct.pack(">Q", int(t)) + frame
    data = bytes(out)
    if faults.truncate_bytes:
        data = data[: max(0, len(data) - faults.truncate_bytes)]
    with open(path, "wb") as f:
        f.write(data)
    return len(data)
