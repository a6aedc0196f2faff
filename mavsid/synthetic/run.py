"""Fly a scenario and write its logs plus the ground-truth sidecar: what ``mavsid simulate`` does.

The format of each output is chosen by its suffix (``.bin`` DataFlash, ``.tlog`` MAVLink
telemetry, ``.ulg`` PX4 ULog) — the one place in mavsid where the suffix decides. Next to
each log goes ``<stem>.truth.json`` (:meth:`~mavsid.synthetic.flight.Flight.truth`, plus
the file names and the command line that reproduces them); logs written by one call describe
the same flight and share one truth file.

Examples
--------
>>> import tempfile, os, json
>>> d = tempfile.mkdtemp()
>>> res = simulate(Scenario(manoeuvre="hover", duration_s=1.0),
...                [os.path.join(d, "h.bin"), os.path.join(d, "h.tlog")])
>>> sorted(os.listdir(d))
['h.bin', 'h.tlog', 'h.truth.json']
>>> json.load(open(os.path.join(d, "h.truth.json")))["logs"]
['h.bin', 'h.tlog']
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np  # noqa: F401  (doctest namespace)

from mavsid.errors import ConfigError
from mavsid.synthetic.dfwriter import LAYOUTS, write_dataflash
from mavsid.synthetic.faults import Faults
from mavsid.synthetic.flight import Flight, Scenario, fly
from mavsid.synthetic.tlogwriter import write_tlog
from mavsid.synthetic.ulogwriter import ULOG_LAYOUTS, write_ulog

__all__ = ["SimulationResult", "scenario_from_options", "simulate", "truth_path"]

WRITERS = {".bin": write_dataflash, ".tlog": write_tlog, ".ulg": write_ulog}  # by suffix
#: the layout each format is written in unless one is asked for
DEFAULT_LAYOUTS = {".bin": "copter-4", ".ulg": "px4-1.14"}
#: for a truth file: each layout's rate and controller-output fields per axis
_FIELDS = {
    "px4-1.14": (("vehicle_angular_velocity.xyz[{i}]", "vehicle_torque_setpoint.xyz[{i}]")),
    "px4-1.11": (("vehicle_angular_velocity.xyz[{i}]", "actuator_controls_0.control[{i}]")),
    "px4-1.8": (("vehicle_attitude.{speed}", "actuator_controls_0.control[{i}]")),
    "copter-3.2": (("IMU.Gyr{xyz}", "RCOU.Chan1-Chan4 (quad-X motor mix of u)")),
    "plane": (("IMU.Gyr{xyz}", "PID{rpy}.P+I+D+FF / 45 = RCOU servo {servo} through "
               "SERVO{servo}_MIN/TRIM/MAX")),
    "quadplane": (("PIQ{rpy}.Act", "PIQ{rpy}.P+I+D+FF")),
}
#: what the effectiveness is per unit of, for layouts whose input is not RATE.ROut/POut/YOut
_INPUT_UNIT = {
    "heli": "the rate controller's normalised output (RATE.ROut/POut/YOut) driving the "
            "swashplate cyclic (roll, pitch) and the tail rotor (yaw)",
    "plane": "normalised surface deflection: aileron (roll), elevator (pitch), rudder (yaw), "
             "-1..1 over the servo's SERVOn_MIN/TRIM/MAX travel",
}
#: layouts whose firmware has no SYSTEMID mode (ArduPlane 4.x)
_NO_SYSTEMID = ("plane", "quadplane")


@dataclass(frozen=True)
class SimulationResult:
    """What :func:`simulate` wrote."""

    flight: Flight
    logs: tuple[str, ...]
    truths: tuple[str, ...]
    sizes: tuple[int, ...]


def truth_path(log: str | os.PathLike[str]) -> Path:
    """``dir/stem.truth.json`` for ``dir/stem.bin``, ``dir/stem.tlog`` or ``dir/stem.ulg``.

    >>> truth_path("fixtures/sysid_roll.bin").as_posix()
    'fixtures/sysid_roll.truth.json'
    """
    p = Path(log)
    return p.with_name(p.stem + ".truth.json")


def simulate(
    scenario: Scenario,
    outputs: Sequence[str | os.PathLike[str]],
    faults: Faults | None = None,
    command: str | None = None,
    layout: str | None = None,
) -> SimulationResult:
    """Fly ``scenario`` once and write it to every path in ``outputs`` with its truth file.

    ``layout`` is the log layout of the ``.bin`` (an ArduCopter generation, a heli or
    ArduPlane, see :data:`~mavsid.synthetic.dfwriter.LAYOUTS`; default ``copter-4``) or of
    the ``.ulg`` (a PX4 topic set, :data:`~mavsid.synthetic.ulogwriter.ULOG_LAYOUTS`; default
    ``px4-1.14``). The layout sets the records, not the plant: fly
    ``VEHICLES["heli"]``/``["plane"]`` for those (``mavsid simulate`` does by default).

    Raises
    ------
    ConfigError
        No output, or an output whose suffix is neither ``.bin`` nor ``.tlog``; SYSTEMID runs
        written as ArduPlane (which has no SYSTEMID mode).
    """
    faults = faults or Faults()
    if not outputs:
        raise ConfigError("no output file given (-o OUT.bin or OUT.tlog)")
    paths = [Path(o) for o in outputs]
    for p in paths:
        if p.suffix.lower() not in WRITERS:
            raise ConfigError(f"{p}: output must end in .bin (DataFlash), .tlog (MAVLink) or "
                              ".ulg (PX4 ULog)")
        if not p.parent.exists():
            raise ConfigError(f"{p}: directory {p.parent} does not exist")
    layouts: dict[Path, str | None] = {}
    for p in paths:
        suffix = p.suffix.lower()
        fits = {".bin": LAYOUTS, ".ulg": ULOG_LAYOUTS}.get(suffix, ())
        if layout is not None and layout not in (*LAYOUTS, *ULOG_LAYOUTS):
            raise ConfigError(f"unknown layout {layout!r}; choose from "
                              f"{', '.join((*LAYOUTS, *ULOG_LAYOUTS))}")
        if layout is not None and fits and layout not in fits:
            raise ConfigError(f"{p}: layout {layout} is not a {suffix} layout; choose from "
                              f"{', '.join(fits)}")
        layouts[p] = (layout if layout in fits else DEFAULT_LAYOUTS[suffix]) if fits else None
    for p in paths:
        if layouts[p] in _NO_SYSTEMID and scenario.runs:
            raise ConfigError(f"{p}: layout {layouts[p]}: ArduPlane has no SYSTEMID mode; fly "
                              "a pilot manoeuvre (--manoeuvre doublet, 3211 or random)")
    flight = fly(scenario)
    sizes = [write_dataflash(flight, p, faults, str(layouts[p])) if p.suffix.lower() == ".bin"
             else write_ulog(flight, p, faults, str(layouts[p])) if p.suffix.lower() == ".ulg"
             else write_tlog(flight, p, faults) for p in paths]
    truths: dict[Path, list[Path]] = {}
    for p in paths:
        truths.setdefault(truth_path(p), []).append(p)
    for tp, logs in truths.items():
        doc: dict[str, Any] = {"logs": [p.name for p in logs], "command": command,
                               **flight.truth()}
        written = {layouts[p] for p in logs} - {None, "copter-4"}
        if written:  # (the fixtures' truth files predate layouts: 4.x)
            doc["layout"] = ", ".join(sorted(str(w) for w in written))
        for name in sorted(str(w) for w in written if w in _FIELDS):
            rate, out = _FIELDS[name]
            for i, (ax, speed) in enumerate(zip(("roll", "pitch", "yaw"),
                                                ("rollspeed", "pitchspeed", "yawspeed"),
                                                strict=True)):
                keys = {"i": i, "speed": speed, "xyz": "XYZ"[i], "rpy": "RPY"[i],
                        "servo": (1, 2, 4)[i]}
                doc["axes"][ax][f"output_field_{name}"] = rate.format(**keys)
                doc["axes"][ax][f"input_field_{name}"] = out.format(**keys)
        for name in sorted(str(w) for w in written if w in _INPUT_UNIT):
            for ax in ("roll", "pitch", "yaw"):
                doc["axes"][ax][f"input_unit_{name}"] = _INPUT_UNIT[name]
        doc["faults"] = {"drop_fraction": faults.drop_fraction,
                         "reboot_at_s": faults.reboot_at_s,
                         "truncate_bytes": faults.truncate_bytes,
                         **({"gap": list(faults.gap)} if faults.gap is not None else {})}
        tp.write_text(json.dumps(doc, indent=1) + "\n")
    return SimulationResult(flight, tuple(map(str, paths)), tuple(map(str, truths)),
                            tuple(sizes))


def scenario_from_options(
    manoeuvre: str = "sysid",
    axis: str = "roll",
    sid_axes: Sequence[int] = (),
    duration_s: float | None = None,
    seed: int = 0,
    noise: float = 1.0,
    magnitude: float | None = None,
    f_start_hz: float = 0.5,
    f_stop_hz: float = 15.0,
    t_rec: float = 20.0,
    t_fade_in: float = 2.0,
    t_fade_out: float = 1.0,
    rate_hz: float = 400.0,
    stick_amplitude: float = 0.3,
    vehicle: str = "quad",
    gyro_noise_dps: float | None = None,
    vibration_dps: float = 0.0,
    frame: str = "quad-x",
) -> Scenario:
    """The :class:`Scenario` the command line's options describe.

    ``sid_axes`` lists SYSTEMID runs (``SID_AXIS`` values) flown in turn; empty with
    ``manoeuvre="sysid"`` means one mixer run on ``axis``. ``magnitude`` defaults per
    injection point (0.05 mixer roll/pitch, 0.1 mixer yaw, 0.05 thrust, 5 deg angle, 20 deg/s
    rate). ``noise`` scales the default sensor noise, gyro bias and disturbance (0: none).
    ``vehicle`` names a plant of :data:`~mavsid.synthetic.plant.VEHICLES`; ``gyro_noise_dps``
    sets the gyro's white noise (deg/s RMS per loop sample, fed back through the rate
    controller), after ``noise`` scaling; ``vibration_dps`` adds a frame vibration of that
    amplitude (deg/s). ``frame`` names the multirotor frame whose motors are mixed and logged
    (:data:`~mavsid.synthetic.controller.FRAMES`). ``rate_hz`` is the RATE/SIDD logging
    rate; below 25 Hz every other message is logged at it too (a slow log throughout).

    >>> sc = scenario_from_options(vehicle="heavy-x", gyro_noise_dps=3.0)
    >>> sc.plant.effectiveness[0], round(float(np.degrees(sc.plant.gyro_noise)), 6)
    (95.0, 3.0)
    >>> round(scenario_from_options(vehicle="racer").controller.rll_p, 6)  # its own tuning
    0.045

    >>> sc = scenario_from_options(sid_axes=[10, 12], seed=3)
    >>> [r.axis for r in sc.runs], sc.runs[1].magnitude
    ([10, 12], 0.1)
    >>> scenario_from_options(manoeuvre="doublet", sid_axes=[10])
    Traceback (most recent call last):
    ...
    mavsid.errors.ConfigError: --sid-axis needs --manoeuvre sysid (got 'doublet')
    """
    from mavsid.synthetic.flight import LogRates
    from mavsid.synthetic.plant import AXES, VEHICLES
    from mavsid.synthetic.sysid import SID_AXES, SysIdSettings

    if sid_axes and manoeuvre != "sysid":
        raise ConfigError(f"--sid-axis needs --manoeuvre sysid (got {manoeuvre!r})")
    default_mag = {"mixer": 0.05, "input_angle": 5.0, "recovery_angle": 5.0, "rate": 20.0}
    runs = []
    for ax in sid_axes:
        if ax not in SID_AXES:
            raise ConfigError(f"--sid-axis must be 1-13, got {ax}")
        kind, target = SID_AXES[ax]
        mag = magnitude
        if mag is None:
            mag = 0.1 if (kind, target) == ("mixer", "yaw") else default_mag[kind]
        runs.append(SysIdSettings(axis=ax, magnitude=mag, f_start_hz=f_start_hz,
                                  f_stop_hz=f_stop_hz, t_fade_in=t_fade_in, t_rec=t_rec,
                                  t_fade_out=t_fade_out))
    if manoeuvre == "sysid" and not runs:
        if axis not in AXES:
            raise ConfigError(f"--axis must be one of {', '.join(AXES)}, got {axis!r}")
        sid = {"roll": 10, "pitch": 11, "yaw": 12}[axis]
        mag = magnitude if magnitude is not None else (0.1 if axis == "yaw" else 0.05)
        runs.append(SysIdSettings(axis=sid, magnitude=mag, f_start_hz=f_start_hz,
                                  f_stop_hz=f_stop_hz, t_fade_in=t_fade_in, t_rec=t_rec,
                                  t_fade_out=t_fade_out))
    if vehicle not in VEHICLES:
        raise ConfigError(f"--vehicle must be one of {', '.join(VEHICLES)}, got {vehicle!r}")
    plant = VEHICLES[vehicle].scaled_noise(noise)
    if gyro_noise_dps is not None:
        if not 0 <= gyro_noise_dps < math.inf:
            raise ConfigError(f"--gyro-noise must be a finite number >= 0 deg/s, got "
                              f"{gyro_noise_dps}")
        plant = replace(plant, gyro_noise=math.radians(gyro_noise_dps))
    if not 0 <= vibration_dps < math.inf:
        raise ConfigError(f"--vibration must be a finite number >= 0 deg/s, got {vibration_dps}")
    plant = replace(plant, vibration=math.radians(vibration_dps))
    slow = min(rate_hz, 10.0) if rate_hz < 25 else None
    rates = LogRates(rate=rate_hz) if slow is None else LogRates(
        rate=rate_hz, att=slow, imu=rate_hz, rcou=slow, rcin=slow, tlog=rate_hz)
    from mavsid.synthetic.controller import ControllerParams
    from mavsid.synthetic.plant import RATE_GAIN_SCALE

    controller = ControllerParams()
    k = RATE_GAIN_SCALE.get(vehicle)
    if k is not None:  # (a vehicle tuned by its owner: the default loop gain)
        controller = replace(controller, **{f"{ax}_{g}": getattr(controller, f"{ax}_{g}") * k
                                            for ax in ("rll", "pit", "yaw")
                                            for g in ("p", "i", "d")})
    return Scenario(
        manoeuvre=manoeuvre, axis=axis, sysid=tuple(runs), duration_s=duration_s, seed=seed,
        plant=plant, rates=rates, stick_amplitude=stick_amplitude, controller=controller,
        frame=frame,
    )
