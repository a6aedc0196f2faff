"""The commanded attitude on the grid: the autopilot's own desired attitude where it logs one,
else the pilot's sticks.

Examples
--------
>>> from mavsid.data import RawLog, SourceInfo
>>> commanded_attitude(RawLog(SourceInfo("x.bin", "dataflash", 0), {}), np.arange(3.0))
({}, {})
"""

from __future__ import annotations

import numpy as np

from mavsid.align.boots import boot_records
from mavsid.align.grid import resampled
from mavsid.autopilot.ardupilot import RC_MAP_AP
from mavsid.autopilot.presets import DESIRED_CHANNELS
from mavsid.autopilot.px4 import RC_MAP_PX4
from mavsid.channels import first_of, rows_of
from mavsid.data import RawLog

__all__ = ["STICK_SOURCE", "commanded_attitude", "pilot_sticks"]


def commanded_attitude(raw: RawLog, t: np.ndarray, boot: int = 0
               ) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """The commanded attitude per axis on the grid ``t`` (interpolated; NaN outside its
    span), from the first of :data:`mavsid.autopilot.presets.DESIRED_CHANNELS` the log has, its
    records of the boot the grid is laid on (``boot``, see :func:`boot_records`): roll and
    pitch angles (rad), and for yaw the commanded heading's rate (rad/s: the pilot commands
    a yaw rate, which the body rate follows; the heading unwrapped, central differences).
    Excitation judges a stick manoeuvre's response by its coherence with it, the fit checks
    the feedback's bias with it (:mod:`mavsid.estimators.instruments`). Where a log has
    none (a ``.tlog``), the pilot's sticks (:func:`pilot_sticks`), asked for only then. Second:
    each axis's source (``MESSAGE.field``, the sticks' followed by :data:`STICK_SOURCE`)."""
    out: dict[str, np.ndarray] = {}
    source: dict[str, str] = {}
    for axis, chans in DESIRED_CHANNELS.items():
        got = first_of(raw, chans, f"commanded {axis}")
        if got is None:
            continue
        ts, v = boot_records(got[1], got[2], boot)
        if ts.size < 2:
            continue
        if axis == "yaw":
            v = np.gradient(np.unwrap(v), ts)
        if np.ptp(v) > 0:
            # not published in a gap (PX4's rate-only modes such as ACRO): not a ramp across it
            out[axis] = resampled(ts, v, t, np.nan)
            source[axis] = f"{got[0].message}.{got[0].field}"
    sticks = pilot_sticks(raw) if len(out) < len(DESIRED_CHANNELS) else {}
    for axis, (name, ts, v) in sticks.items():
        if axis not in out:
            ts, v = boot_records(ts, v, boot)
            if ts.size >= 2 and np.ptp(v) > 0:
                out[axis] = resampled(ts, v, t, np.nan)
                source[axis] = f"{name}, {STICK_SOURCE}"
    return out, source


#: what ends a commanded attitude's source (``FlightData.commanded_from``) when the
#: pilot's sticks stand in for it
STICK_SOURCE = "the pilot's stick"


def pilot_sticks(raw: RawLog) -> dict[str, tuple[str, np.ndarray, np.ndarray]]:
    """The pilot's roll, pitch and yaw sticks in a MAVLink log (``RC_CHANNELS``, the RC input
    the autopilot reads, or MAVLink 1's ``RC_CHANNELS_RAW``; the vehicle's): per axis the
    field (``MESSAGE.field``), the times (s) and the stick's departure from its trim (µs,
    outside its dead zone), on the channel the autopilot maps to the axis (its ``RCMAP_*``,
    or PX4's ``RC_MAP_*``; ArduPilot's defaults 1, 2, 4; none for a PX4 log without them).

    The commanded attitude's stand-in where a log has none (a ``.tlog``): in the stabilised
    modes a stick sets an angle (roll, pitch) or a yaw rate in proportion, through the input
    shaping (a linear filter), which is all a coherence or an instrument needs (neither
    depends on scale, sign or offset). Samples outside 800–2200 µs (no signal) are left out.

    Examples
    --------
    >>> from mavsid.data import MessageTable, RawLog, SourceInfo
    >>> rc = MessageTable("RC_CHANNELS", {"chan1_raw": np.array([1500, 1600, 1400, 0]),
    ...                   "chan2_raw": np.full(4, 1500), "chan4_raw": np.full(4, 1490)},
    ...                   np.arange(4.0))
    >>> raw = RawLog(SourceInfo("x.tlog", "tlog", 0), {"RC_CHANNELS": rc},
    ...              params={"RC1_DZ": 20.0}, autopilot="ardupilot")
    >>> {k: v[2].tolist() for k, v in pilot_sticks(raw).items()}
    {'roll': [0.0, 80.0, -80.0], 'pitch': [0.0, 0.0, 0.0, 0.0], 'yaw': [-10.0, -10.0, -10.0, -10.0]}
    """
    table = raw.messages.get("RC_CHANNELS")
    if table is None or not len(table):
        table = raw.messages.get("RC_CHANNELS_RAW")
        if table is None or not len(table):
            return {}
    times = np.asarray(table.time_s, float)
    rows = np.isfinite(times)
    one = rows_of(table)  # (the vehicle's)
    if one is not None:
        rows &= one
    if "port" in table.columns:  # (RC_CHANNELS_RAW's channels 9-16 come on port 1)
        rows &= np.asarray(table.columns["port"]) == 0
    px4 = raw.autopilot == "px4"
    out: dict[str, tuple[str, np.ndarray, np.ndarray]] = {}
    for axis, (ardupilot, default) in RC_MAP_AP.items():
        got = raw.params.get(RC_MAP_PX4[axis] if px4 else ardupilot, None if px4 else default)
        if got is None or not 1 <= got <= 18 or got != int(got):
            continue
        n = int(got)
        column = table.columns.get(f"chan{n}_raw")
        if column is None:
            continue
        pwm = table.numbers(f"chan{n}_raw", raw.source.path)
        keep = (pwm >= 800) & (pwm <= 2200) & rows
        pwm = pwm[keep]
        trim = raw.params.get(f"RC{n}_TRIM", 1500.0)
        dead = raw.params.get(f"RC{n}_DZ", 0.0)  # (both autopilots name it so)
        x = pwm - trim
        out[axis] = (f"{table.name}.chan{n}_raw", times[keep],
                     np.sign(x) * np.maximum(np.abs(x) - max(dead, 0.0), 0.0))
    return out
