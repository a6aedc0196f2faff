"""RawLog -> FlightData: every state and input on one uniform time grid, in SI units.

:func:`align` takes the channels a :class:`~mavsid.autopilot.presets.Preset` names (chosen from the
log's content unless given) and

- converts them to rad, rad/s and normalised inputs (motor PWMs through the frame's mixer);
- keeps one boot when the log's clock restarts (reboot, concatenated logs: the longest, with
  a :class:`~mavsid.errors.DataQualityWarning`) and sorts slightly unordered records;
- unwraps yaw;
- builds one grid with step ``1 / rate_hz`` (default: the mean sample interval of the
  body-rate channel, or of the attitude when the log has no rates), anchored at the first
  instant every channel has data;
- interpolates states linearly and holds inputs (zero-order hold: each grid point gets the
  latest input sample at or before it, never a value in between);
- splits the grid into blocks wherever any channel pauses for more than ``max_gap``
  of its own sample intervals: nothing is interpolated or held across a gap;
- excludes samples that were never measured: non-finite values (NaN, ±inf) and values no
  multicopter reports (a body rate beyond ``MAX_RATE_RAD_S``, roll or pitch beyond ±π, yaw
  outside −π..2π) and samples whose time stamp lies far off their neighbours' (a
  far-future ``TimeUS`` or ``time_boot_ms``): none is interpolated over (the grid has a gap
  there), each is counted in ``FlightData.channels`` (``excluded_samples``: channel -> count) and
  warned about once (:class:`~mavsid.errors.DataQualityWarning`);
- never builds a grid larger than the samples justify: points are laid only where every
  channel has data, and at most ``MAX_GRID_PER_SAMPLE`` points per sample of the densest
  channel (a larger ``rate_hz`` is a :class:`~mavsid.errors.ConfigError`);
- carries per-sample flags ``armed`` and ``airborne`` (bool) and ``mode`` (int, -1 before
  the first mode message), from the log's events (DataFlash EV/ARM, MAVLink HEARTBEAT and
  EXTENDED_SYS_STATE, PX4 actuator_armed / vehicle_land_detected);
- warns (:class:`~mavsid.errors.DataQualityWarning`) when an input is logged too slowly
  for attitude dynamics (below ``min_input_rate_hz``, e.g. 10 Hz RCOU).

``FlightData.channels`` holds each channel's source, native rate, unit read in and the
samples excluded (non-finite, impossible or mistimed), ``FlightData.mixer`` the mixer used,
``FlightData.sysid_injection`` SYSTEMID's logged waveform (held, NaN where not logged) and
``FlightData.inputs_at_state_times`` the inputs interpolated like the states (for a log that
has the waveform: the frequency response against it); ``FlightData.boot`` which boot
was used (:class:`~mavsid.data.Boot`), ``FlightData.sysid_runs`` the ArduPilot SYSTEMID
runs (from SIDS/SIDD or, in a .tlog, from the SYSTEMID mode and the SID_* parameter values
sent before it); the platform's names ``autopilot``, ``vehicle`` and ``firmware`` are
fields too.

Examples
--------
>>> import numpy as np
>>> from mavsid.data import MessageTable, RawLog, SourceInfo
>>> t = np.arange(0.0, 1.0, 0.01)
>>> att = MessageTable("ATTITUDE", {c: np.zeros_like(t) for c in
...     ("roll", "pitch", "yaw", "rollspeed", "pitchspeed", "yawspeed")}, time_s=t)
>>> log = RawLog(SourceInfo("x.tlog", "tlog", 0), {"ATTITUDE": att})
>>> fd = align(log)
>>> fd.preset, fd.state_names, round(fd.dt, 6), fd.blocks.tolist()
('mavlink-att', ('roll', 'pitch', 'yaw', 'p', 'q', 'r'), 0.01, [[0, 100]])
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterable, Mapping

import numpy as np

from mavsid.align.boots import one_boot
from mavsid.align.commanded import commanded_attitude
from mavsid.align.flags import flags_on_grid
from mavsid.align.grid import MAX_GAP_SAMPLES, between_held, hold, uniform_grid
from mavsid.align.series import first_fitting, message_scales, reference
from mavsid.align.sysid import sysid_injection, sysid_runs
from mavsid.autopilot.mixers import Mixer
from mavsid.autopilot.presets import Preset, get_preset, preset_messages
from mavsid.axes import STATE_UNITS
from mavsid.data import ChannelOrigin, FlightData, MessageTable, RawLog
from mavsid.errors import DataQualityWarning, MavsidError, NoExcitationError, naming_file
from mavsid.readers import read_log, sniff_format

__all__ = ["FLAG_MESSAGES", "MIN_INPUT_RATE_HZ", "align", "flight_table", "load_flight",
           "read_flight"]

#: inputs logged slower than this cannot show attitude dynamics (a 10 Hz input sees < 5 Hz)
MIN_INPUT_RATE_HZ = 20.0


#: messages alignment reads besides the presets' channels: flags, modes, params, SYSTEMID
FLAG_MESSAGES: dict[str, tuple[str, ...]] = {
    "dataflash": ("EV", "ARM", "MODE", "MSG", "PARM", "SIDS", "SIDD", "ATT"),
    "tlog": ("HEARTBEAT", "EXTENDED_SYS_STATE", "PARAM_VALUE", "STATUSTEXT", "RC_CHANNELS",
             "RC_CHANNELS_RAW"),
    "ulog": ("actuator_armed", "vehicle_land_detected", "vehicle_status",
             "vehicle_attitude_setpoint"),
}


FLAG_MESSAGES["dataflash-text"] = FLAG_MESSAGES["dataflash"]


def align(
    raw: RawLog,
    preset: Preset | str | None = None,
    rate_hz: float | None = None,
    *,
    presets: Mapping[str, Preset] | None = None,
    mixers: Mapping[str, Mixer] | None = None,
    max_gap: float = MAX_GAP_SAMPLES,
    min_input_rate_hz: float = MIN_INPUT_RATE_HZ,
) -> FlightData:
    """Put a log's states and inputs on one uniform grid (see the module docstring).

    Every error it raises names the log's file.

    Parameters
    ----------
    raw : RawLog
        A reader's output.
    preset : Preset or str, optional
        Channel preset or its name; default: chosen from the log's content.
    rate_hz : float, optional
        Grid rate, Hz; default the body-rate (else attitude) channel's own rate.
    presets, mixers : Mapping, optional
        User presets and mixers (:func:`mavsid.autopilot.config.load_presets`), tried first.
    max_gap : float
        A pause longer than this many of a channel's median sample intervals splits blocks.
    min_input_rate_hz : float
        Inputs logged slower than this raise a :class:`DataQualityWarning`.

    Raises
    ------
    MissingMessageError
        No preset fits, or a required message or field is absent.
    NoExcitationError
        The channels never overlap in time (nothing to align).
    """
    try:
        return _align(raw, preset, rate_hz, presets, mixers, max_gap, min_input_rate_hz)
    except MavsidError as exc:
        named = naming_file(exc, raw.source.path)
        if named is exc:
            raise
        raise named from exc


def _align(raw: RawLog, preset: Preset | str | None, rate_hz: float | None,
           presets: Mapping[str, Preset] | None, mixers: Mapping[str, Mixer] | None,
           max_gap: float, min_input_rate_hz: float) -> FlightData:
    preset, (states, inputs, mixer) = first_fitting(raw, preset, presets, mixers or {})
    if not states:
        raise NoExcitationError(f"{raw.source.path}: no state samples for preset {preset.name}")
    states, inputs, boot = one_boot(raw.source.path, states, inputs)
    states = [s for s in states if s.t.size >= 2]
    inputs = [s for s in inputs if s.t.size >= 2]
    if not states:
        raise NoExcitationError(
            f"{raw.source.path}: no state channel of preset {preset.name} has two samples "
            "with distinct time stamps: nothing to put on a time grid"
        )
    ref = reference(states)
    series = states + inputs
    excluded = {s.name: dict(s.excluded) for s in series if s.excluded}
    if excluded:
        groups: dict[tuple[str, tuple[tuple[str, int], ...]], list[str]] = {}
        for s in series:
            if s.excluded:
                groups.setdefault((s.source.split(".")[0], s.excluded), []).append(s.name)
        shown = "; ".join(f"{src} " + ", ".join(f"{n} {why}" for why, n in why_n)
                          + f" ({'/'.join(names)})" for (src, why_n), names in groups.items())
        warnings.warn(
            f"{raw.source.path}: samples excluded (never interpolated over): {shown}",
            DataQualityWarning,
            stacklevel=3,
        )
    t, blocks, dt = uniform_grid(series, ref, rate_hz, max_gap, raw.source.path)
    if not t.size:
        raise NoExcitationError(
            f"{raw.source.path}: the channels of preset {preset.name} "
            f"({', '.join(sorted({s.source for s in series}))}) never overlap for two samples"
            + (f" ({sum(sum(w.values()) for w in excluded.values())} sample(s) excluded as "
               "never measured or mistimed)" if excluded else "")
        )
    x = np.empty((t.size, len(states)))
    for j, s in enumerate(states):
        x[:, j] = np.interp(t, s.t, s.v)
    u = np.empty((t.size, len(inputs)))
    for j, s in enumerate(inputs):
        u[:, j] = hold(s, t, dt)
    rates = {s.name: (1.0 / s.median_dt if s.median_dt > 0 else 0.0) for s in series}
    warned = set()
    for s in inputs:
        msg = s.source.split(".")[0].split(" ")[0]
        if rates[s.name] < min_input_rate_hz and msg not in warned:
            warned.add(msg)
            warnings.warn(
                f"{raw.source.path}: inputs from {msg} are logged at {rates[s.name]:.1f} Hz "
                f"(below {min_input_rate_hz:g} Hz): dynamics above {rates[s.name] / 2:.1f} Hz "
                "cannot be identified from them",
                DataQualityWarning,
                stacklevel=3,
            )
    input_names = tuple(s.name for s in inputs)
    flags, flag_notes = flags_on_grid(raw, t, u, input_names)
    channels = {s.name: ChannelOrigin(s.source, round(rates[s.name], 3), s.unit_from,
                                      dict(s.excluded)) for s in series}
    commanded, commanded_from = commanded_attitude(raw, t, boot.used - 1)
    injection = sysid_injection(raw, t, dt, boot.used - 1)
    between: dict[str, np.ndarray] = {}
    if injection is not None:  # (its one use: the frequency response against the injection)
        for s in inputs:
            got = between_held(s, t, dt)
            if got is not None:
                between[s.name] = got
    return FlightData(
        time_s=t,
        states=x,
        inputs=u,
        state_names=tuple(s.name for s in states),
        input_names=input_names,
        state_units=tuple(STATE_UNITS[s.name] for s in states),
        input_units=tuple("1" for _ in inputs),
        dt=float(dt),
        blocks=blocks,
        flags=flags,
        source=raw.source,
        preset=preset.name,
        params=dict(raw.params),
        autopilot=raw.autopilot,
        vehicle=raw.vehicle,
        firmware=raw.firmware,
        sysid_runs=sysid_runs(raw),
        boot=boot,
        commanded=commanded,
        commanded_from=commanded_from,
        channels=channels,
        mixer=mixer,
        scales=message_scales(raw, series),
        mode_names={m.mode: m.name for m in raw.modes if m.name},
        flag_notes=flag_notes,
        sysid_injection=injection,
        inputs_at_state_times=between,
    )


def load_flight(
    path: str | os.PathLike[str],
    preset: Preset | str | None = None,
    rate_hz: float | None = None,
    *,
    presets: Mapping[str, Preset] | None = None,
    mixers: Mapping[str, Mixer] | None = None,
) -> FlightData:
    """Read only the messages alignment needs from a log file, then :func:`align` it.

    Examples
    --------
    >>> load_flight("/nonexistent.bin")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    mavsid.errors.LogFormatError: /nonexistent.bin: cannot open: ...
    """
    return read_flight(path, preset, rate_hz, presets=presets, mixers=mixers)[0]


def read_flight(
    path: str | os.PathLike[str],
    preset: Preset | str | None = None,
    rate_hz: float | None = None,
    *,
    presets: Mapping[str, Preset] | None = None,
    mixers: Mapping[str, Mixer] | None = None,
    also: Iterable[str] = (),
) -> tuple[FlightData, RawLog]:
    """:func:`load_flight`, and the log as read: the messages alignment needs and ``also``
    (read in the same pass, for a caller that needs a few more, e.g. the twin's targets)."""
    fmt = sniff_format(path)
    chosen = [preset] if isinstance(preset, Preset) else []
    if isinstance(preset, str):
        chosen = [get_preset(preset, presets)]
    extra = [*chosen, *(presets or {}).values()]
    wanted = preset_messages(fmt, extra) if not chosen else chosen[0].messages
    more = [m for m in also if m not in wanted]
    raw = read_log(path, messages=[*wanted, *FLAG_MESSAGES.get(fmt, ()), *more])
    return align(raw, preset, rate_hz, presets=presets, mixers=mixers), raw


def flight_table(flight: FlightData, start: float | None = None, stop: float | None = None
                 ) -> MessageTable:
    """FlightData as one table ``FlightData`` (for ``mavsid extract --aligned``).

    Columns: every state and input (SI units), the flags ``armed``, ``airborne``, ``mode``
    and ``block`` (index of the contiguous block); rows with ``start <= time_s <= stop``.

    Examples
    --------
    >>> import numpy as np
    >>> from mavsid.data import SourceInfo
    >>> fd = FlightData(np.array([0.0, 0.1]), np.zeros((2, 1)), np.ones((2, 1)), ("p",),
    ...                 ("u_roll",), ("rad/s",), ("1",), 0.1, np.array([[0, 2]]),
    ...                 {"armed": np.ones(2, bool)}, SourceInfo("x", "tlog", 0), "t")
    >>> tab = flight_table(fd)
    >>> tab.fields, tab.unit("p")
    (('p', 'u_roll', 'armed', 'block'), 'rad/s')
    """
    t = flight.time_s
    keep = np.ones(t.size, dtype=bool)
    if start is not None:
        keep &= t >= start
    if stop is not None:
        keep &= t <= stop
    cols: dict[str, np.ndarray] = {}
    units: dict[str, str] = {}
    for j, (name, unit) in enumerate(zip(flight.state_names, flight.state_units, strict=True)):
        cols[name], units[name] = flight.states[keep, j], unit
    for j, (name, unit) in enumerate(zip(flight.input_names, flight.input_units, strict=True)):
        cols[name], units[name] = flight.inputs[keep, j], unit
    for name, flag in flight.flags.items():
        cols[name] = np.asarray(flag)[keep]
    block = np.repeat(np.arange(len(flight.blocks)), flight.blocks[:, 1] - flight.blocks[:, 0])
    cols["block"] = block[keep]
    return MessageTable("FlightData", cols, time_s=t[keep], units=units)
