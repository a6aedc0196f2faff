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
``FlightData.sysid_injection`` SYSTEMID's logged waveform; ``FlightData.boot`` which boot
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

import functools
import itertools
import math
import os
import re
import warnings
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from mavsid.autopilot.ardupilot import (
    IMU_GYRO_FIELDS,
    RC_MAP_AP,
    SID_PARAMS,
    SIDS_FIELDS,
    SYSTEM_ID_DELAY_S,
    SYSTEMID_MODE,
)
from mavsid.autopilot.mixers import MIXERS, Mixer, frame_name, frame_of, has_mixer
from mavsid.autopilot.presets import (
    DESIRED_CHANNELS,
    PRESETS,
    QUADPLANE,
    Channel,
    Preset,
    choose_preset,
    get_preset,
    mixer_for,
    preset_messages,
    vehicle_kind,
)
from mavsid.autopilot.px4 import RC_MAP_PX4
from mavsid.axes import INPUT_NAMES, STATE_NAMES, STATE_UNITS
from mavsid.channels import (
    evaluate,
    first_of,
    motor_thrusts,
    resolve,
    rows_of,
    servo_inputs,
    unit_origin,
)
from mavsid.data import Boot, ChannelOrigin, FlightData, MessageTable, RawLog, SysidRun
from mavsid.errors import (
    ConfigError,
    DataQualityWarning,
    MavsidError,
    MissingMessageError,
    NoExcitationError,
    naming_file,
)
from mavsid.readers import read_log, sniff_format

__all__ = ["FLAG_MESSAGES", "align", "channel_units", "flight_table", "load_flight", "read_flight",
           "sysid_runs"]

#: a channel pausing longer than this many of its own median sample intervals is a gap
MAX_GAP_SAMPLES = 4.0
#: inputs logged slower than this cannot show attitude dynamics (a 10 Hz input sees < 5 Hz)
MIN_INPUT_RATE_HZ = 20.0
#: no multicopter gyro reports more (4000 deg/s, twice the usual full scale)
MAX_RATE_RAD_S = float(np.deg2rad(4000.0))
#: grid points allowed per sample of the densest channel (a hard cap on the grid's size)
MAX_GRID_PER_SAMPLE = 50
#: a sample is mistimed when it lies further than this from the median time of the
#: ``2 * _OUTLIER_HALF + 1`` records around it (and further than many sample intervals)
TIME_OUTLIER_S = 10.0
_OUTLIER_HALF = 16


@dataclass(frozen=True)
class _Series:
    """One channel's native samples (sorted, finite) in SI units."""

    name: str
    source: str  # "MESSAGE.field" for messages and warnings
    t: np.ndarray
    v: np.ndarray
    #: times of excluded samples (never measured or mistimed): the grid leaves a gap there
    bad_t: np.ndarray = field(default_factory=lambda: np.empty(0))
    #: how many samples were excluded, and why
    excluded: tuple[tuple[str, int], ...] = ()
    #: the unit the field was read in and where it came from (declared, preset, inferred)
    unit_from: str = ""

    @functools.cached_property
    def median_dt(self) -> float:
        """The median of the positive sample intervals (s), measured once (the grid, the
        gaps and the rates ask for it: ~5 ms a long channel)."""
        d = np.diff(self.t)
        d = d[d > 0]
        return float(np.median(d)) if d.size else float("nan")


def _dedupe(t: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Keep the first of samples sharing a timestamp (interpolation needs increasing time)."""
    if t.size < 2:
        return t, v
    keep = np.concatenate([[True], np.diff(t) > 0])
    return t[keep], v[keep]


#: vehicle classes (RawLog.vehicle's first word) whose servo outputs are no multicopter motors
_NOT_MULTICOPTER = {"plane", "rover", "boat", "sub", "blimp", "heli", "helicopter", "tracker",
                    "vtol", "fixedwing", "fixed-wing", "airship", "antenna"}


def _resolve_preset(raw: RawLog, preset: Preset | str | None,
                    presets: Mapping[str, Preset] | None) -> Preset:
    if isinstance(preset, Preset):
        return preset
    if isinstance(preset, str):
        return get_preset(preset, presets)
    return choose_preset(raw, presets)


#: The fixed-wing presets of an ArduPlane log. A QuadPlane logs its VTOL rate controllers
#: (PIQR/PIQP/PIQY) while they fly the aircraft, its fixed-wing ones (PIDR...) with every
#: attitude record
_WING = ("ardupilot-plane-pid", "ardupilot-plane-servo")


def _vtol_or_wing(raw: RawLog, candidates: list[Preset]) -> list[Preset]:
    """``candidates`` (the applicable presets, in order) with a QuadPlane's VTOL preset
    after the fixed-wing ones when the VTOL controllers flew less than half the attitude
    records; when both apply, a warning says which flight is fitted and how to fit the
    other."""
    names = [p.name for p in candidates]
    wing = next((n for n in names if n in _WING), None)
    if QUADPLANE not in names or wing is None or names.index(QUADPLANE) > names.index(wing):
        return candidates
    att = len(raw.messages["PIDR"]) if "PIDR" in raw.messages else 0
    share = len(raw.messages["PIQR"]) / att if att else 1.0
    if share < 0.5:
        vtol = candidates.pop(names.index(QUADPLANE))
        candidates.insert(names.index(wing), vtol)
        fitted, other, what = wing, QUADPLANE, "VTOL"
    else:
        fitted, other, what = QUADPLANE, wing, "fixed-wing"
    warnings.warn(f"{raw.source.path}: a QuadPlane, its VTOL controllers flying "
                  f"{100 * min(share, 1.0):.0f} % of the attitude records: preset {fitted} "
                  f"fitted; --preset {other} fits the {what} flight", DataQualityWarning,
                  stacklevel=6)
    return candidates


def _first_fitting(raw: RawLog, preset: Preset | str | None,
                   presets: Mapping[str, Preset] | None, mixers: Mapping[str, Mixer]
                   ) -> tuple[Preset, tuple[list[_Series], list[_Series], str | None]]:
    """The preset to use and its channels: the one asked for, else the first applicable one
    whose channels the log really holds (a preset applies by its messages; a field renamed
    between firmware versions shows only when it is read, and then the next one is tried).

    Raises
    ------
    MissingMessageError
        No preset fits: every applicable preset's missing message or field, and what the
        log has.
    """
    if preset is not None:
        chosen = _resolve_preset(raw, preset, presets)
        return chosen, _collect(raw, chosen, mixers)
    candidates = _vtol_or_wing(raw, [p for p in (*(presets or {}).values(), *PRESETS.values())
                                     if p.applies_to(raw)])
    if not candidates:
        choose_preset(raw, presets)  # raises, naming what a preset needs
    tried: list[str] = []
    for cand in candidates:
        try:
            got = _collect(raw, cand, mixers)
        except MissingMessageError as exc:
            tried.append(f"{cand.name} needs {exc.what} {exc.name}")
            continue
        if tried:
            warnings.warn(f"{raw.source.path}: preset {cand.name} used: " + "; ".join(tried),
                          DataQualityWarning, stacklevel=5)
        return cand, got
    raise MissingMessageError("; ".join(tried), available=raw.messages, what="fitting preset",
                              path=raw.source.path)


def _collect(raw: RawLog, preset: Preset, mixers: Mapping[str, Mixer]
             ) -> tuple[list[_Series], list[_Series], str | None]:
    """States and inputs of the preset, as native series (record order) in canonical order."""
    states = _channel_series(raw, preset, STATE_NAMES, preset.states, need_samples=True)
    inputs: list[_Series] = []
    mixer_name = None
    kind = (raw.vehicle or "").split()[0].lower() if (raw.vehicle or "").strip() else ""
    if preset.motors is not None:
        inputs, mixer_name = _motor_inputs(raw, preset, mixers, kind)
    elif preset.servos is not None:
        for name, source, t, v in servo_inputs(raw, preset):
            late, bad_t = _mistimed(t)
            excluded = (("mistimed", int(late.sum())),) if late.any() else ()
            if late.any():
                t, v = t[~late], v[~late]
            if t.size >= 2:
                inputs.append(_Series(name, source, t, v, bad_t, excluded,
                                      "PWM us through SERVOn_MIN/TRIM/MAX"))
    else:
        inputs = _channel_series(raw, preset, INPUT_NAMES, preset.inputs, need_samples=False)
    states, inputs = _checked_scales(raw, states, inputs)
    states = [_possible(raw, s) for s in states]
    return states, inputs, mixer_name


#: ArduCopter 3.4-dev logged RATE in centidegrees/s and its outputs on a ±4500 scale
_CENTI = 0.01
_OUT_SCALE = 4500.0


def _checked_scales(raw: RawLog, states: list[_Series], inputs: list[_Series]
                    ) -> tuple[list[_Series], list[_Series]]:
    """ArduPilot RATE channels whose scale the evidence contradicts, rescaled and said so.

    Development builds of ArduCopter 3.4 logged ``RATE.R/P/Y`` in centidegrees per second and
    ``ROut/POut/YOut`` on a ±4500 scale, without unit records. The evidence, in order: the
    IMU gyro of the same log (a rate 100× the gyro is in centidegrees), else the range (a
    body rate beyond 35 rad/s — 2000 deg/s, every gyro's limit — cannot be deg/s); controller
    outputs beyond ±10 (normally ±1) are on the ±4500 scale. Each rescale is a warning and
    lands in the series' source (so ``fit`` shows it); nothing is rescaled silently.
    """
    notes: list[str] = []
    rates = [s for s in states if s.source.startswith("RATE.") and s.name in IMU_GYRO_FIELDS
             and s.v.size >= 10]
    centi, why = False, ""
    checked = []
    for s in rates:  # by the IMU gyro, on the axis the gyro sees moving most
        gyro = _col(raw, "IMU", IMU_GYRO_FIELDS[s.name])
        if gyro is None:
            continue
        ok = np.isfinite(gyro[0]) & np.isfinite(gyro[1])
        if ok.sum() < 10:
            continue
        gt, gv = gyro[0][ok], gyro[1][ok].astype(float)
        if (np.diff(gt) >= 0).all() and (np.diff(s.t) >= 0).all():
            ref = np.interp(s.t, gt, gv)  # the gyro at the rate's samples
        else:  # the clock restarts (a reboot): times mix boots; the whole of each, then
            ref = gv
        ref_rms = float(np.sqrt(np.mean(ref**2)))
        checked.append((ref_rms, float(np.sqrt(np.mean(s.v**2))) / max(ref_rms, 1e-12), s))
    if checked:
        _, ratio, s = max(checked, key=lambda c: c[0])
        if 30.0 < ratio < 300.0:
            centi = True
            why = (f"RATE body rates are {ratio:.0f}× the IMU gyro ({s.source} against "
                   f"IMU.{IMU_GYRO_FIELDS[s.name]}): logged in centidegrees/s (ArduCopter "
                   "3.4-dev), scaled by 0.01")
    elif rates:
        top = max(float(np.percentile(np.abs(s.v), 99)) for s in rates)
        dev34 = bool(re.search(r"V3\.4[.\d]*-dev", raw.firmware or ""))
        declared = bool(raw.messages["RATE"].units)
        if top > 35.0:
            centi = True
            why = (f"RATE body rates reach {top:.0f} rad/s read as deg/s, beyond any gyro: "
                   "taken as centidegrees/s (ArduCopter 3.4-dev), scaled by 0.01 (no IMU in "
                   "the log to confirm)")
        elif dev34 and not declared:
            centi = True
            why = (f"{raw.firmware} logged RATE in centidegrees/s (firmware table; no IMU in "
                   "the log to confirm), scaled by 0.01")
        elif not declared:
            notes.append("RATE body rates taken as deg/s: the log declares no units and has no "
                         "IMU gyro to check them by")
    out_states = states
    if centi:
        notes.append(why)
        out_states = [replace(s, v=s.v * _CENTI, source=f"{s.source} (centideg/s, inferred)",
                              unit_from="centideg/s, inferred")
                      if any(s is r for r in rates) else s for s in states]
    outs = [s for s in inputs if s.source in ("RATE.ROut", "RATE.POut", "RATE.YOut")
            and s.v.size >= 10]
    top_out = max((float(np.percentile(np.abs(s.v), 99)) for s in outs), default=0.0)
    out_inputs = inputs
    if top_out > 10.0 or (centi and outs and "firmware table" in why):
        notes.append(f"RATE.ROut/POut/YOut reach {top_out:.0f} (normally within ±1): on the "
                     "±4500 scale of ArduCopter 3.4-dev, divided by 4500")
        out_inputs = [replace(s, v=s.v / _OUT_SCALE, source=f"{s.source} (/4500, inferred)",
                              unit_from="/4500, inferred")
                      if any(s is o for o in outs) else s for s in inputs]
    if notes:
        warnings.warn(f"{raw.source.path}: " + "; ".join(notes), DataQualityWarning, stacklevel=5)
    return out_states, out_inputs


def _channel_series(raw: RawLog, preset: Preset, names: Sequence[str],
                    channels: Mapping[str, Channel], need_samples: bool) -> list[_Series]:
    """The preset's channels ``names`` (those it has) as native series, in that order.

    A channel that cannot be evaluated is left out when optional; one with fewer than two
    usable samples is left out, or (``need_samples``, not optional) is an error.
    """
    out: list[_Series] = []
    for name in names:
        ch = channels.get(name)
        if ch is None:
            continue
        try:
            t, v = evaluate(raw, ch, f"{preset.name}:{name}")
        except MavsidError:
            if ch.optional:
                continue
            raise
        t, v, bad_t, excluded = _screen(raw, ch, name, t, v)
        if t.size >= 2:
            out.append(_Series(name, f"{ch.message}.{ch.field}", t, v, bad_t, excluded,
                               unit_origin(raw, ch)))
        elif need_samples and not ch.optional:
            table = raw[ch.message]
            timed = int(np.count_nonzero(np.isfinite(np.asarray(table.time_s, dtype=float))))
            why = ""
            if timed == 0 and not any(
                    np.isfinite(np.asarray(m.time_s, dtype=float)).any()
                    for m in raw.messages.values() if len(m)):
                why = (" (the log has no clock: no boot-time field such as TimeUS/TimeMS and "
                       "no GPS fix to time its records by)")
            raise NoExcitationError(
                f"{raw.source.path}: {ch.message} has {len(table)} record(s), {timed} with a "
                f"time stamp and {t.size} usable: nothing to put on a time grid{why}"
            )
    return out


#: physically possible range of each state (SI units, after conversion)
_STATE_LIMITS: dict[str, tuple[float, float]] = {
    "p": (-MAX_RATE_RAD_S, MAX_RATE_RAD_S),
    "q": (-MAX_RATE_RAD_S, MAX_RATE_RAD_S),
    "r": (-MAX_RATE_RAD_S, MAX_RATE_RAD_S),
    "roll": (-np.pi - 1e-3, np.pi + 1e-3),
    "pitch": (-np.pi - 1e-3, np.pi + 1e-3),
    "yaw": (-np.pi - 1e-3, 2 * np.pi + 1e-3),  # ArduPilot logs 0..360 degrees
}


def time_outliers(t: np.ndarray, half: int = _OUTLIER_HALF,
                  limit_s: float = TIME_OUTLIER_S) -> np.ndarray:
    """Mask of samples (record order) whose time lies far from that of the records around
    them: more than ``limit_s`` and more than ``4 * half`` sample intervals from the median of
    the ``2 * half + 1`` records centred on it (the nearest ones, at either end).

    A run of time stamps that only increases is never flagged (each is its own window's
    median), nor is a reboot (time restarting, for more than ``half`` records); a run of up
    to ``half`` records far in the future (or past) is. Only records next to a large jump
    are examined, so the cost is linear.

    Examples
    --------
    >>> t = np.arange(100) * 0.01
    >>> t[40:45] = 2.0**32 / 1000  # time_boot_ms of 2^32 - 1 in five records
    >>> np.flatnonzero(time_outliers(t)).tolist()
    [40, 41, 42, 43, 44]
    >>> t = np.concatenate([np.arange(50) * 0.1, 1000 + np.arange(50) * 0.1])  # a pause
    >>> int(time_outliers(t).sum())
    0
    """
    out = np.zeros(t.size, dtype=bool)
    if t.size < 3:
        return out
    d = np.diff(t)
    if not (np.abs(d) > limit_s).any():  # no jump reaches even the smallest limit
        return out
    pos = d[d > 0]
    step = float(np.median(pos)) if pos.size else 0.0
    limit = max(limit_s, 4 * half * step)
    jumps = np.flatnonzero(np.abs(d) > limit)
    if not jumps.size:
        return out
    # the records within ``half`` of a jump, each against its window's median
    near = _sorted_unique((jumps[:, None] + np.arange(-half + 1, half + 1)).ravel())
    near = near[(near >= 0) & (near < t.size)]
    width = min(2 * half + 1, t.size)  # near either end, the window is shifted inwards
    first = np.clip(near - half, 0, t.size - width)
    med = np.median(np.lib.stride_tricks.sliding_window_view(t, width)[first], axis=1)
    out[near] = np.abs(t[near] - med) > limit
    return out


def _screen(raw: RawLog, ch: Channel, name: str, t: np.ndarray, v: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[tuple[str, int], ...]]:
    """A channel's samples without the mistimed ones; the times where samples are missing
    (the non-finite ones :func:`evaluate` dropped and, for mistimed ones, the neighbour's) and
    the counts of each kind. (Physically impossible values are screened once the units are
    settled: :func:`_possible`.)"""
    table = raw[ch.message]
    t_all = np.asarray(table.time_s, dtype=np.float64)
    rows = rows_of(table, ch.instance)
    if rows is not None:
        t_all = t_all[rows]
    t_all = t_all[np.isfinite(t_all)]
    excluded: list[tuple[str, int]] = []
    bad = [np.empty(0)]
    if t_all.size > t.size:  # non-finite values evaluate() left out
        excluded.append(("non-finite", int(t_all.size - t.size)))
        bad.append(t_all[~np.isin(t_all, t)])
    late, late_t = _mistimed(t)
    if late.any():
        excluded.append(("mistimed", int(late.sum())))
        bad.append(late_t)
        t, v = t[~late], v[~late]
    return t, v, np.concatenate(bad), tuple(excluded)


def _possible(raw: RawLog, s: _Series) -> _Series:
    """``s`` without the samples outside its state's physical range (:data:`_STATE_LIMITS`,
    SI units: judged after every unit decision, so a rate logged in centidegrees/s is
    checked once scaled), their times marked missing and counted.

    Raises
    ------
    NoExcitationError
        Fewer than two samples are possible.
    """
    lo, hi = _STATE_LIMITS.get(s.name, (-np.inf, np.inf))
    wrong = (s.v < lo) | (s.v > hi)
    if not wrong.any():
        return s
    if s.v.size - int(wrong.sum()) < 2:
        raise NoExcitationError(
            f"{raw.source.path}: {s.source}: {int(wrong.sum())} of {s.v.size} samples outside "
            f"the physically possible {lo:.4g}..{hi:.4g} ({s.name}, SI units): nothing to fit")
    return replace(s, t=s.t[~wrong], v=s.v[~wrong],
                   bad_t=np.sort(np.concatenate([s.bad_t, s.t[wrong]])),
                   excluded=(*s.excluded, (f"outside {lo:.4g}..{hi:.4g}", int(wrong.sum()))))


def _mistimed(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`time_outliers` of ``t`` and, for each, the time of the kept record before it
    (where the grid must leave a gap: a sample is missing there)."""
    late = time_outliers(t)
    if not late.any():
        return late, np.empty(0)
    kept = np.flatnonzero(~late)
    before = np.searchsorted(kept, np.flatnonzero(late)) - 1
    return late, t[kept[before[before >= 0]]]


#: a step back in time larger than this (s) is a reboot or the start of a concatenated log
BOOT_JUMP_S = 1.0


def _boots(t: np.ndarray) -> list[slice]:
    """Record ranges between backward time jumps (one per boot)."""
    cut = np.flatnonzero(np.diff(t) < -BOOT_JUMP_S) + 1
    edges = [0, *cut.tolist(), t.size]
    return [slice(a, b) for a, b in itertools.pairwise(edges)]


def _one_boot(path: str, states: list[_Series], inputs: list[_Series]
              ) -> tuple[list[_Series], list[_Series], Boot]:
    """Keep one boot of a log whose clock restarts, then sort by time and unwrap yaw.

    The boot is the longest one of the reference channel (body rate, else attitude); every
    channel keeps its records of that boot (its last boot when it has fewer).
    """
    ref = _reference(states)
    ref_boots = _boots(ref.t)
    k = 0
    boot = Boot(1, 1, float(np.min(ref.t)), float(np.max(ref.t)), "the log has one boot")
    if len(ref_boots) > 1:
        # the boot with the most time covered by samples (not its span: one mistimed
        # sample must not make a boot look long)
        covered = [_covered_s(np.sort(ref.t[b])) for b in ref_boots]
        k = int(np.argmax(covered))
        b = ref_boots[k]
        boot = Boot(k + 1, len(ref_boots), float(np.min(ref.t[b])), float(np.max(ref.t[b])),
                    f"the longest: {covered[k]:.1f} s of {ref.source} samples "
                    f"(next longest {sorted(covered)[-2]:.1f} s)")
        warnings.warn(
            f"{path}: the log's clock restarts {len(ref_boots) - 1} time(s) (reboot or "
            f"concatenated logs): only boot {k + 1} of {len(ref_boots)} is used "
            f"({boot.start_s:.1f}–{boot.stop_s:.1f} s, {boot.reason})",
            DataQualityWarning,
            stacklevel=4,
        )

    def fix(s: _Series) -> _Series:
        t, v = _boot_records(s.t, s.v, k)
        if s.name == "yaw":
            v = np.unwrap(v)
        bad_t = s.bad_t[(s.bad_t >= t[0]) & (s.bad_t <= t[-1])] if t.size else s.bad_t[:0]
        return replace(s, t=t, v=v, bad_t=np.sort(bad_t))

    return [fix(s) for s in states], [fix(s) for s in inputs], boot


def _boot_records(t: np.ndarray, v: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """A channel's records (``t``, ``v`` in record order) of boot ``k`` (its last when it has
    fewer boots, see :func:`_boots`), in time order, one per time stamp.

    Examples
    --------
    >>> t = np.array([30.0, 31.0, 31.0, 5.0, 6.0])
    >>> [a.tolist() for a in _boot_records(t, np.arange(5.0), 1)]
    [[5.0, 6.0], [3.0, 4.0]]
    """
    boots = _boots(t)
    sl = boots[min(k, len(boots) - 1)]
    t, v = t[sl], v[sl]
    if t.size < 2 or (t[1:] > t[:-1]).all():  # (most channels: already so)
        return t.copy(), v.copy()
    order = np.argsort(t, kind="stable")
    return _dedupe(t[order], v[order])


def _reference(states: Sequence[_Series]) -> _Series:
    """The channel that sets the grid: a body rate, else an attitude angle."""
    by_name = {s.name: s for s in states}
    for n in ("p", "q", "r", "roll", "pitch", "yaw"):
        if n in by_name:
            return by_name[n]
    raise ValueError("no state channel")  # callers check first


def _covered_s(t: np.ndarray, max_gap: float = MAX_GAP_SAMPLES) -> float:
    """Time (s) covered by sorted samples ``t``: the sum of their intervals that are no gap.

    Examples
    --------
    >>> round(_covered_s(np.array([0.0, 0.1, 0.2, 1e6, 1e6 + 0.1])), 6)
    0.3
    """
    d = np.diff(t)
    pos = d[d > 0]
    if not pos.size:
        return 0.0
    return float(d[(d > 0) & (d <= max_gap * float(np.median(pos)))].sum())


def _gaps(series: list[_Series], max_gap: float) -> np.ndarray:
    """Union of every channel's gaps as sorted, disjoint open intervals ``(k, 2)``."""
    spans = []
    for s in series:
        d = np.diff(s.t)
        i = np.flatnonzero(d > max_gap * s.median_dt)
        spans.append(np.column_stack([s.t[i], s.t[i + 1]]))
        if s.bad_t.size and s.t.size >= 2:  # between the kept samples around an excluded one
            j = np.clip(np.searchsorted(s.t, s.bad_t, side="right"), 1, s.t.size - 1)
            spans.append(np.column_stack([s.t[j - 1], s.t[j]]))
    if not spans:
        return np.empty((0, 2))
    g = np.concatenate(spans)
    if not g.size:
        return np.empty((0, 2))
    g = g[np.argsort(g[:, 0])]
    merged = [g[0].copy()]
    for a, b in g[1:]:
        if a <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], b)
        else:
            merged.append(np.array([a, b]))
    return np.asarray(merged)


def _sorted_unique(x: np.ndarray) -> np.ndarray:
    """``np.unique(x)`` for integers that are nearly sorted already (runs that overlap a
    little): a stable sort (a merge of the runs) and the repeats dropped. numpy 2's
    ``np.unique`` hashes first: 0.35 s for the 400 000 grid indices of a 27-min flight,
    against 0.3 ms.

    Examples
    --------
    >>> _sorted_unique(np.array([0, 1, 2, 1, 2, 3, 7, 7])).tolist()
    [0, 1, 2, 3, 7]
    """
    x = np.sort(x, kind="stable")
    keep = np.ones(x.size, bool)
    np.not_equal(x[1:], x[:-1], out=keep[1:])
    return x[keep]


def _grid(series: list[_Series], ref: _Series, rate_hz: float | None, max_gap: float,
          path: str = "") -> tuple[np.ndarray, np.ndarray, float]:
    """Uniform grid times, ``[start, stop)`` blocks and the step.

    The grid is laid only where no channel has a gap (points inside a gap are never
    made), so its size follows the samples, whatever their time stamps claim; more than
    ``MAX_GRID_PER_SAMPLE`` points per sample of the densest channel is a ConfigError.
    """
    gaps = _gaps(series, max_gap)
    if rate_hz is None:
        d = np.diff(ref.t)
        ok = d <= max_gap * ref.median_dt
        dt = float(d[ok].mean()) if ok.any() else float("nan")
    else:
        if not 0 < rate_hz < math.inf:
            raise ConfigError(f"rate_hz must be a positive finite number, got {rate_hz}")
        dt = 1.0 / float(rate_hz)
    start = max(float(s.t[0]) for s in series)
    stop = min(float(s.t[-1]) for s in series)
    if rate_hz is not None and 0 < stop - start < dt:
        raise ConfigError(f"{path}: a grid step of {dt:.3g} s (rate_hz {rate_hz:g}) is longer "
                          f"than the {stop - start:.3g} s the channels share: choose a higher "
                          "rate_hz")
    if not np.isfinite(dt) or dt <= 0 or stop - start < dt:
        return np.empty(0), np.empty((0, 2), dtype=np.int64), dt
    n = int(np.floor((stop - start) / dt + 1e-9)) + 1
    # grid indices of the stretches between gaps, counted before anything is allocated
    inner = gaps[(gaps[:, 1] > start) & (gaps[:, 0] < stop)]
    lo_t = np.concatenate([[start], inner[:, 1]])
    hi_t = np.concatenate([inner[:, 0], [stop]])
    k_lo = np.clip(np.floor((lo_t - start) / dt) - 1, 0, n)
    k_hi = np.clip(np.ceil((hi_t - start) / dt) + 1, -1, n - 1)
    counts = np.maximum(k_hi - k_lo + 1, 0).astype(np.int64)
    total = int(counts.sum())
    samples = max(s.t.size for s in series)
    if total > MAX_GRID_PER_SAMPLE * samples + 1000:
        raise ConfigError(
            f"{path}: a grid step of {dt:.3g} s gives {total} points for at most {samples} "
            f"samples per channel (more than {MAX_GRID_PER_SAMPLE} per sample): choose a "
            "lower rate_hz"
        )
    starts = np.repeat(k_lo.astype(np.int64) - np.cumsum(counts) + counts, counts)
    k = _sorted_unique(np.arange(total, dtype=np.int64) + starts)
    t = start + dt * k
    t = t[t <= stop]
    # index of the first gap starting at or after each time; inside a gap when that gap's
    # predecessor has not ended yet
    before = np.searchsorted(gaps[:, 0], t, side="left")  # gaps starting strictly before t
    inside = np.zeros(t.size, dtype=bool)
    has_prev = before > 0
    inside[has_prev] = t[has_prev] < gaps[before[has_prev] - 1, 1]
    # t exactly at a gap start is fine; t strictly between start and end is not
    keep = ~inside
    t, before = t[keep], before[keep]
    if not t.size:
        return t, np.empty((0, 2), dtype=np.int64), dt
    # a new block wherever a gap starts between two kept grid points
    idx = np.arange(t.size)
    cut = np.flatnonzero(np.diff(before) > 0) + 1
    edges = np.concatenate([[0], cut, [t.size]])
    blocks = np.column_stack([edges[:-1], edges[1:]])
    blocks = blocks[blocks[:, 1] - blocks[:, 0] >= 2]
    if not blocks.size:
        return np.empty(0), np.empty((0, 2), dtype=np.int64), dt
    sel = np.concatenate([idx[a:b] for a, b in blocks])
    lengths = blocks[:, 1] - blocks[:, 0]
    new_edges = np.concatenate([[0], np.cumsum(lengths)])
    return t[sel], np.column_stack([new_edges[:-1], new_edges[1:]]).astype(np.int64), dt


def _hold(s: _Series, t: np.ndarray, dt: float) -> np.ndarray:
    """Zero-order hold: the latest native sample at or before each time.

    "At" allows ``1e-6 * dt`` for the rounding of the grid times, so that a grid point meant
    to fall on a sample does not pick the one before it.
    """
    i = np.searchsorted(s.t, t + 1e-6 * dt, side="right") - 1
    return s.v[np.clip(i, 0, None)]


# --------------------------------------------------------------------------- flags


def _events_to_flag(events: list[tuple[float, bool]], t: np.ndarray, default: bool
                    ) -> np.ndarray:
    """Hold on/off events onto ``t``; before the first event, the opposite of it."""
    if not events:
        return np.full(t.shape, default)
    events.sort(key=lambda e: e[0])
    et = np.array([e[0] for e in events])
    ev = np.array([e[1] for e in events])
    i = np.searchsorted(et, t, side="right") - 1
    out = np.where(i >= 0, ev[np.clip(i, 0, None)], not ev[0])
    return out.astype(bool)


def _col(raw: RawLog, msg: str, fld: str) -> tuple[np.ndarray, np.ndarray] | None:
    """``(time_s, values)`` of one numeric field; None when the log lacks it."""
    if msg not in raw.messages or fld not in raw.messages[msg].columns:
        return None
    tab = raw.messages[msg]
    return np.asarray(tab.time_s, dtype=float), tab.numbers(fld, raw.source.path)


def _main_sysid(raw: RawLog) -> int | None:
    got = _col(raw, "ATTITUDE", "_sysid")
    if got is None or not got[1].size:
        return None
    ids, counts = np.unique(got[1], return_counts=True)
    return int(ids[np.argmax(counts)])


def _motor_inputs(raw: RawLog, preset: Preset, mixers: Mapping[str, Mixer], kind: str
                  ) -> tuple[list[_Series], str | None]:
    """The inputs a motor-output preset gives: the motors' PWM through the thrust curve,
    unmixed by the frame's mixer, and its name; none (and a warning saying why) for a
    vehicle that is not a multicopter, a frame without a mixer here, an assumed frame the
    outputs contradict (:func:`_more_motors`) or outputs that do not carry the motors."""
    ch = preset.motors
    assert ch is not None
    path = raw.source.path

    def none(why: str) -> tuple[list[_Series], str | None]:
        warnings.warn(f"{path}: {why}", DataQualityWarning, stacklevel=6)
        return [], None

    if kind in _NOT_MULTICOPTER:
        return none(f"a {raw.vehicle}'s {ch.message} outputs are not a multicopter's motors: "
                    "no inputs (the mixer presets are for multicopters)")
    n_motors = _motor_count(raw, preset)
    key, frame_source = frame_of(raw.params, n_motors)
    if preset.mixer == "auto" and not has_mixer(raw.params, n_motors):
        return none(f"FRAME_CLASS {key[0]} FRAME_TYPE {key[1]} ({frame_name(key)}): no motor "
                    f"mixer for it here, {ch.message} not unmixed: no inputs (choose a preset "
                    "with a mixer of your own for this frame)")
    mixer = mixer_for(preset, raw.params, {**MIXERS, **mixers}, n_motors)
    assumed = preset.mixer == "auto" and frame_source != "FRAME_CLASS/FRAME_TYPE"
    more = _more_motors(raw, preset, mixer.n_motors) if assumed and n_motors is None else []
    if more:
        return none(f"{frame_source.split(':')[0]}, and output(s) {', '.join(map(str, more))} "
                    f"move as motors or servos do: a frame with more than the "
                    f"{mixer.n_motors} motors assumed cannot be told from a quad with servos: "
                    f"{ch.message} not unmixed: no inputs (log the parameters, or choose a "
                    "preset with this frame's mixer)")
    try:
        t, thrust = motor_thrusts(raw, preset, mixer)
    except ConfigError as exc:  # (SERVOn_FUNCTION: the outputs do not carry every motor)
        return none(f"{mixer.name} mixer: {exc}: {ch.message} not unmixed: no inputs")
    if assumed:
        warnings.warn(f"{path}: {frame_source}: {ch.message} unmixed as {mixer.name} (choose a "
                      "preset with another mixer if the frame differs)", DataQualityWarning,
                      stacklevel=5)
    u = mixer.unmix(thrust)
    late, bad_t = _mistimed(t)
    excluded: tuple[tuple[str, int], ...] = ()
    if late.any():
        excluded = (("mistimed", int(late.sum())),)
        t, u = t[~late], u[~late]
    return [_Series(name, f"{ch.message} ({mixer.name} mixer)", t, u[:, j], bad_t, excluded,
                    "PWM us through the thrust curve, unmixed")
            for j, name in enumerate(INPUT_NAMES)], mixer.name


def _more_motors(raw: RawLog, preset: Preset, n: int) -> list[int]:
    """The outputs beyond an assumed frame's ``n`` motors that move in the PWM range
    (800-2200 µs): a hexa's 5 and 6 in a .tlog whose parameters were not fetched, unmixed
    as a quad-X's four, give a wrong model, and a quad's gimbal servos there look the same,
    so neither is guessed."""
    ch = preset.motors
    if ch is None or ch.message not in raw.messages:
        return []
    table = raw.messages[ch.message]
    rows = rows_of(table)
    more = []
    for i in range(n + 1, 17):
        got = resolve(table, ch.field.replace("{i}", str(i)))
        if got is None:
            break
        v = np.asarray(got[0], dtype=np.float64)
        v = v[(rows if rows is not None else np.ones(v.size, bool)) & np.isfinite(v)]
        if v.size > 2 and 800.0 <= float(np.median(v)) <= 2200.0 and np.std(v) > 2.0:
            more.append(i)
    return more


def _motor_count(raw: RawLog, preset: Preset) -> int | None:
    """How many motor outputs a per-motor message holds (``MOT`` Mot1..MotN); None when the
    message always has a fixed set (RCOU's 8 or more channels say nothing of the frame)."""
    ch = preset.motors
    if ch is None or ch.message != "MOT" or ch.message not in raw.messages:
        return None
    fields = raw.messages[ch.message].fields
    return sum(1 for i in range(1, 13) if f"Mot{i}" in fields) or None


def _armed_events(raw: RawLog) -> list[tuple[float, bool]]:
    ev: list[tuple[float, bool]] = []
    got = _col(raw, "EV", "Id")
    if got is not None:
        ev += [(float(t), i == 10) for t, i in zip(*got, strict=True) if i in (10, 11)]
    got = _col(raw, "ARM", "ArmState")
    if got is not None:
        ev += [(float(t), bool(a)) for t, a in zip(*got, strict=True)]
    got = _col(raw, "HEARTBEAT", "base_mode")
    if got is not None:
        sysid = _main_sysid(raw)
        ids = raw.messages["HEARTBEAT"].columns.get("_sysid")
        mask = np.ones(got[0].size, bool) if ids is None or sysid is None else ids == sysid
        pairs = zip(got[0][mask], got[1][mask], strict=True)
        ev += [(float(t), bool(int(b) & 128)) for t, b in pairs]
    got = _col(raw, "actuator_armed", "armed")
    if got is not None:
        ev += [(float(t), bool(a)) for t, a in zip(*got, strict=True)]
    got = _col(raw, "vehicle_status", "arming_state")
    if got is not None and not ev and np.any(got[1] > 0):  # all 0 (INIT): never set
        ev += [(float(t), int(a) == 2) for t, a in zip(*got, strict=True)]
    if not ev:
        for m in raw.texts:
            if m.text.startswith("Arming motors"):
                ev.append((m.time_s, True))
            elif m.text.startswith("Disarming motors"):
                ev.append((m.time_s, False))
    return ev


def _airborne_events(raw: RawLog) -> list[tuple[float, bool]]:
    ev: list[tuple[float, bool]] = []
    got = _col(raw, "EV", "Id")
    if got is not None:
        ev += [(float(t), i == 28) for t, i in zip(*got, strict=True) if i in (18, 28)]
    got = _col(raw, "EXTENDED_SYS_STATE", "landed_state")
    if got is not None:
        ev += [(float(t), int(s) in (2, 3, 4)) for t, s in zip(*got, strict=True) if int(s) != 0]
    got = _col(raw, "vehicle_land_detected", "landed")
    if got is not None:
        ev += [(float(t), not bool(s)) for t, s in zip(*got, strict=True)]
    return ev


def _flags(raw: RawLog, t: np.ndarray, inputs: np.ndarray, input_names: tuple[str, ...]
           ) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    notes: dict[str, str] = {}
    arm_ev = _armed_events(raw)
    armed = _events_to_flag(arm_ev, t, True)
    if not arm_ev:
        notes["armed"] = "no arming events in the log: assumed armed throughout"
    air_ev = _airborne_events(raw)
    if air_ev:
        airborne = _events_to_flag(air_ev, t, True) & armed
    elif "u_thrust" in input_names and np.ptp(inputs[:, input_names.index("u_thrust")]) > 0.05:
        thr = inputs[:, input_names.index("u_thrust")]
        on = thr[armed & (thr > 0.05)]
        level = 0.6 * float(np.median(on)) if on.size else np.inf
        airborne = armed & (thr > level)
        notes["airborne"] = (
            f"no landing events in the log: airborne where armed and u_thrust > {level:.3g} "
            "(60 % of its armed median)"
        )
    else:
        airborne = armed.copy()
        notes["airborne"] = "no landing events or thrust in the log: airborne assumed when armed"
    mode = np.full(t.shape, -1, dtype=np.int64)
    if raw.modes:
        mt = np.array([m.time_s for m in raw.modes])
        mv = np.array([m.mode for m in raw.modes], dtype=np.int64)
        order = np.argsort(mt, kind="stable")
        mt, mv = mt[order], mv[order]
        i = np.searchsorted(mt, t, side="right") - 1
        mode = np.where(i >= 0, mv[np.clip(i, 0, None)], -1)
    return {"armed": armed, "airborne": airborne, "mode": mode}, notes


# --------------------------------------------------------------------------- SYSTEMID

def _mode_spans(raw: RawLog, name: str) -> list[tuple[float, float]]:
    """[entry, exit) times of every stay in the mode called ``name``."""
    modes = sorted(raw.modes, key=lambda m: m.time_s)
    spans = []
    for i, m in enumerate(modes):
        if (m.name or "").upper() == name and (i == 0 or modes[i - 1].name != m.name):
            nxt = next((n.time_s for n in modes[i + 1:] if n.name != m.name), np.inf)
            spans.append((m.time_s, nxt))
    return spans


def _sid_axis_number(value: float) -> int:
    """A logged SID_AXIS as its whole number; 0 (no axis) when it is not a finite number.

    >>> _sid_axis_number(10.0), _sid_axis_number(float("nan"))
    (10, 0)
    """
    return int(value) if math.isfinite(value) else 0


def sysid_runs(raw: RawLog) -> tuple[SysidRun, ...]:
    """ArduPilot SYSTEMID runs: settings and the span of the injected waveform.

    From DataFlash: one per SIDS record, with SIDS's settings; the span is that of the SIDD
    samples after it whose waveform ``Targ`` is non-zero (the chirp itself, without the
    initial delay and the wait after it), else of all its SIDD samples, else the stay in
    SYSTEMID mode. From DataFlash with SIDD but no SIDS: one per stay in the mode
    (:func:`_runs_without_sids`; ``injected`` False when its waveform is zero throughout).
    From a .tlog: one
    per stay in SYSTEMID mode, the settings being the last SID_* PARAM_VALUE before it
    (``settings_from`` says which; a ground station may have sent the parameters only once,
    so segment selection checks that axis against the data); the span is then ArduCopter's
    injection: ``SYSTEM_ID_DELAY`` (1 s) after entering the mode, for ``SID_T_REC`` seconds.

    Examples
    --------
    >>> import numpy as np
    >>> from mavsid.data import MessageTable, ModeChange, RawLog, SourceInfo
    >>> sids = MessageTable("SIDS", {"Ax": np.array([10]), "Mag": np.array([0.05])},
    ...                     time_s=np.array([5.0]))
    >>> sidd = MessageTable("SIDD", {"Targ": np.array([0.0, 0.01, -0.02, 0.0])},
    ...                     time_s=np.array([5.1, 6.0, 8.0, 9.0]))
    >>> log = RawLog(SourceInfo("x.bin", "dataflash", 0), {"SIDS": sids, "SIDD": sidd},
    ...              modes=(ModeChange(5.0, 25, "SYSTEMID"), ModeChange(9.5, 0, "STABILIZE")))
    >>> sysid_runs(log)
    (SysidRun(start_s=6.0, stop_s=8.0, settings_from='SIDS', axis=10, magnitude=0.05, \
f_start_hz=None, f_stop_hz=None, t_fade_in_s=None, t_const_freq_s=None, t_record_s=None, \
t_fade_out_s=None, injected=True),)
    """
    runs: list[dict[str, Any]] = []
    path = raw.source.path
    spans = _mode_spans(raw, SYSTEMID_MODE)
    if "SIDS" in raw.messages and len(raw.messages["SIDS"]):
        sids = raw.messages["SIDS"]
        ts = np.asarray(sids.time_s, dtype=float)
        settings = {key: sids.numbers(f, path) for f, key in SIDS_FIELDS.items()
                    if f in sids.columns}
        sidd_t, active = np.empty(0), np.empty(0, dtype=bool)
        if "SIDD" in raw.messages:
            sidd = raw.messages["SIDD"]
            sidd_t = np.asarray(sidd.time_s, dtype=float)
            targ = (sidd.numbers("Targ", path) if "Targ" in sidd.columns
                    else np.ones(sidd_t.size))
            active = np.isfinite(targ) & (targ != 0)
        for k, t0 in enumerate(ts):
            t_next = ts[k + 1] if k + 1 < ts.size else np.inf
            mode_end = next((b for a, b in spans if a <= t0 + 0.5 < b), np.inf)
            end = min(t_next, mode_end)
            sel = (sidd_t >= t0) & (sidd_t < end)
            inside = sidd_t[sel & active] if np.count_nonzero(sel & active) >= 2 else sidd_t[sel]
            if inside.size >= 2:
                start, stop = float(np.min(inside)), float(np.max(inside))
            elif np.isfinite(mode_end):
                start, stop = float(t0), float(mode_end)
            else:
                continue
            run: dict[str, Any] = {"start_s": start, "stop_s": stop, "settings_from": "SIDS"}
            for key, values in settings.items():
                val = float(values[k])
                run[key] = _sid_axis_number(val) if key == "axis" else val
            if inside.size < 2:
                run["start_s"], run["stop_s"] = _chirp_span(start, stop, run)
            runs.append(run)
        return tuple(SysidRun(**r) for r in runs)
    if "SIDD" in raw.messages and len(raw.messages["SIDD"]):
        return tuple(SysidRun(**r) for r in _runs_without_sids(raw, spans))
    if not spans or "PARAM_VALUE" not in raw.messages:
        return ()
    pv = raw.messages["PARAM_VALUE"]
    names = np.asarray(pv.columns.get("param_id", []), dtype=object)
    values = (pv.numbers("param_value", path) if "param_value" in pv.columns
              else np.empty(0))
    times = np.asarray(pv.time_s, dtype=float)
    for a, b in spans:
        if not np.isfinite(b):
            continue
        run = {"start_s": float(a), "stop_s": float(b), "settings_from": "PARAM_VALUE"}
        for pname, key in SID_PARAMS.items():
            sel = np.flatnonzero((names == pname) & ~(times > a))
            if sel.size:
                val = float(values[sel[np.argmax(times[sel])]])
            elif pname in raw.params:
                val = float(raw.params[pname])
            else:
                continue
            run[key] = _sid_axis_number(val) if key == "axis" else val
        if "axis" in run:
            run["start_s"], run["stop_s"] = _chirp_span(a, b, run)
            runs.append(run)
    return tuple(SysidRun(**r) for r in runs)


#: How long before its MODE record a SYSTEMID stay's first SIDD record may come (the mode's
#: record is written after the mode has started: 0.09 s late on a real ArduCopter 4.6 log)
SIDD_BEFORE_MODE_S = 0.5


def _runs_without_sids(raw: RawLog, spans: Sequence[tuple[float, float]]
                       ) -> list[dict[str, Any]]:
    """SYSTEMID runs of a DataFlash log with SIDD but no SIDS record (its start not logged):
    one per stay in the mode holding SIDD records, the settings from the log's SID_*
    parameters (``settings_from`` ``"PARM"``), the span that of the records whose waveform
    ``Targ`` is non-zero; where none is, the stay itself and ``injected`` False (the mode
    was flown, nothing was injected).

    Examples
    --------
    >>> from mavsid.data import MessageTable, ModeChange, RawLog, SourceInfo
    >>> sidd = MessageTable("SIDD", {"Targ": np.zeros(4)}, time_s=np.array([5.0, 6, 8, 9]))
    >>> log = RawLog(SourceInfo("x.bin", "dataflash", 0), {"SIDD": sidd},
    ...              modes=(ModeChange(5.1, 25, "SYSTEMID"), ModeChange(9.5, 0, "STABILIZE")),
    ...              params={"SID_AXIS": 1.0})
    >>> [r.to_dict() for r in sysid_runs(log)]
    [{'start_s': 5.1, 'stop_s': 9.0, 'settings_from': 'PARM', 'axis': 1, 'injected': False}]
    """
    sidd = raw.messages["SIDD"]
    t = np.asarray(sidd.time_s, dtype=float)
    targ = (sidd.numbers("Targ", raw.source.path) if "Targ" in sidd.columns
            else np.ones(t.size))
    active = np.isfinite(targ) & (targ != 0)
    runs: list[dict[str, Any]] = []
    for a, b in spans:
        sel = (t >= a - SIDD_BEFORE_MODE_S) & (t < b)
        if np.count_nonzero(sel) < 2:
            continue
        injected = np.count_nonzero(sel & active) >= 2
        inside = t[sel & active] if injected else t[sel]
        run: dict[str, Any] = {
            "start_s": float(np.min(inside)) if injected else float(a),
            "stop_s": float(np.max(inside)) if injected else float(min(b, np.max(inside))),
            "settings_from": "PARM"}
        for pname, key in SID_PARAMS.items():
            if pname in raw.params:
                val = float(raw.params[pname])
                run[key] = _sid_axis_number(val) if key == "axis" else val
        if not injected:
            run["injected"] = False
        runs.append(run)
    return runs


def _commanded(raw: RawLog, t: np.ndarray, boot: int = 0
               ) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """The commanded attitude per axis on the grid ``t`` (interpolated; NaN outside its
    span), from the first of :data:`mavsid.autopilot.presets.DESIRED_CHANNELS` the log has, its
    records of the boot the grid is laid on (``boot``, see :func:`_boot_records`): roll and
    pitch angles (rad), and for yaw the commanded heading's rate (rad/s: the pilot commands
    a yaw rate, which the body rate follows; the heading unwrapped, central differences).
    Excitation judges a stick manoeuvre's response by its coherence with it, the fit checks
    the feedback's bias with it (:mod:`mavsid.estimators.instruments`). Where a log has
    none (a ``.tlog``), the pilot's sticks (:func:`_sticks`), asked for only then. Second:
    each axis's source (``MESSAGE.field``, the sticks' followed by :data:`STICK_SOURCE`)."""
    out: dict[str, np.ndarray] = {}
    source: dict[str, str] = {}
    for axis, chans in DESIRED_CHANNELS.items():
        got = first_of(raw, chans, f"commanded {axis}")
        if got is None:
            continue
        ts, v = _boot_records(got[1], got[2], boot)
        if ts.size < 2:
            continue
        if axis == "yaw":
            v = np.gradient(np.unwrap(v), ts)
        if np.ptp(v) > 0:
            # not published in a gap (PX4's rate-only modes such as ACRO): not a ramp across it
            out[axis] = _resampled(ts, v, t, np.nan)
            source[axis] = f"{got[0].message}.{got[0].field}"
    sticks = _sticks(raw) if len(out) < len(DESIRED_CHANNELS) else {}
    for axis, (name, ts, v) in sticks.items():
        if axis not in out:
            ts, v = _boot_records(ts, v, boot)
            if ts.size >= 2 and np.ptp(v) > 0:
                out[axis] = _resampled(ts, v, t, np.nan)
                source[axis] = f"{name}, {STICK_SOURCE}"
    return out, source


#: what ends a commanded attitude's source (``FlightData.commanded_from``) when the
#: pilot's sticks stand in for it
STICK_SOURCE = "the pilot's stick"


def _sticks(raw: RawLog) -> dict[str, tuple[str, np.ndarray, np.ndarray]]:
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
    >>> {k: v[2].tolist() for k, v in _sticks(raw).items()}
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


def _resampled(ts: np.ndarray, v: np.ndarray, t: np.ndarray, fill: float) -> np.ndarray:
    """Samples ``v`` at times ``ts`` interpolated on the grid ``t``, ``fill`` outside their
    span and inside a gap of more than three of their usual intervals (and 50 ms) between
    two samples, where the signal is not known.

    Examples
    --------
    >>> _resampled(np.array([0.0, 0.1, 0.2, 1.0, 1.1]), np.arange(5.0),
    ...            np.array([0.15, 0.6, 1.05, 2.0]), np.nan).tolist()
    [1.5, nan, 3.5, nan]
    """
    order = np.argsort(ts, kind="stable")
    ts = ts[order]
    out = np.interp(t, ts, v[order], left=fill, right=fill)
    if ts.size >= 2:
        gap = max(float(np.median(np.diff(ts))) * 3, 0.05)
        near = np.searchsorted(ts, t).clip(1, ts.size - 1)
        out[np.minimum(np.abs(t - ts[near]), np.abs(t - ts[near - 1])) > gap] = fill
    return out


def _sysid_injection(raw: RawLog, t: np.ndarray, boot: int = 0) -> np.ndarray | None:
    """SYSTEMID's logged waveform ``SIDD.Targ`` on the grid ``t`` (interpolated inside runs,
    0 elsewhere; its records of the grid's ``boot``), or None when the log has none.
    Excitation judges SYSTEMID runs by it."""
    sidd = raw.messages.get("SIDD")
    if sidd is None or "Targ" not in sidd.columns or len(sidd) < 2:
        return None
    ts, targ = _boot_records(np.asarray(sidd.time_s, dtype=float),
                             np.nan_to_num(sidd.numbers("Targ", raw.source.path)), boot)
    return _resampled(ts, targ, t, 0.0)  # between runs SIDD is not logged: no injection there


def _chirp_span(enter: float, leave: float, run: Mapping[str, Any]) -> tuple[float, float]:
    """The injection inside a SYSTEMID mode stay: from SYSTEM_ID_DELAY after entry for
    SID_T_REC seconds, cut at the mode exit (the whole stay when SID_T_REC is unknown)."""
    start = min(enter + SYSTEM_ID_DELAY_S, leave)
    rec = run.get("t_record_s")
    stop = min(start + float(rec), leave) if rec else leave
    return float(start), float(stop)


# --------------------------------------------------------------------------- align

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


def channel_units(
    raw: RawLog,
    preset: Preset | str | None = None,
    presets: Mapping[str, Preset] | None = None,
    mixers: Mapping[str, Mixer] | None = None,
) -> tuple[str, dict[str, dict[str, str]]]:
    """The preset :func:`align` would use and, per channel it reads, the SI unit it gives,
    the source and the unit the field is read in with where that came from (declared by the
    log, the preset's, inferred from evidence): what ``mavsid info`` shows. No time grid is
    built; the warnings alignment gives are left to it.

    Raises
    ------
    MavsidError
        No preset fits the log, or its channels hold no usable sample.

    Examples
    --------
    >>> from mavsid.data import MessageTable, SourceInfo
    >>> t = np.arange(0, 1, 0.01)
    >>> raw = RawLog(SourceInfo("x.bin", "dataflash", 0), {
    ...     "ATT": MessageTable("ATT", {"Roll": t, "Pitch": t, "Yaw": t}, t, {"Roll": "deg"}),
    ...     "RATE": MessageTable("RATE", {"R": t, "P": t, "Y": t, "ROut": t, "POut": t,
    ...                                   "YOut": t, "AOut": t}, t, {"R": "deg/s"})})
    >>> name, ch = channel_units(raw)
    >>> name, ch["p"]["unit"], ch["p"]["source"], ch["p"]["read_in"]
    ('ardupilot-rate', 'rad/s', 'RATE.R', 'deg/s, declared by the log')
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataQualityWarning)
        chosen, (states, inputs, _) = _first_fitting(raw, preset, presets, mixers or {})
    return chosen.name, {s.name: {"unit": STATE_UNITS.get(s.name, "1"), "source": s.source,
                                  "read_in": s.unit_from} for s in (*states, *inputs)}


def _align(raw: RawLog, preset: Preset | str | None, rate_hz: float | None,
           presets: Mapping[str, Preset] | None, mixers: Mapping[str, Mixer] | None,
           max_gap: float, min_input_rate_hz: float) -> FlightData:
    preset, (states, inputs, mixer) = _first_fitting(raw, preset, presets, mixers or {})
    if not states:
        raise NoExcitationError(f"{raw.source.path}: no state samples for preset {preset.name}")
    states, inputs, boot = _one_boot(raw.source.path, states, inputs)
    states = [s for s in states if s.t.size >= 2]
    inputs = [s for s in inputs if s.t.size >= 2]
    if not states:
        raise NoExcitationError(
            f"{raw.source.path}: no state channel of preset {preset.name} has two samples "
            "with distinct time stamps: nothing to put on a time grid"
        )
    ref = _reference(states)
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
    t, blocks, dt = _grid(series, ref, rate_hz, max_gap, raw.source.path)
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
        u[:, j] = _hold(s, t, dt)
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
    flags, flag_notes = _flags(raw, t, u, input_names)
    channels = {s.name: ChannelOrigin(s.source, round(rates[s.name], 3), s.unit_from,
                                      dict(s.excluded)) for s in series}
    # scales inferred for whole messages (ArduCopter 3.4-dev RATE): readers of the same
    # message's other fields (the twin's RATE.RDes targets) apply them too
    scales = ({"RATE": _CENTI} if any(s.source.endswith("(centideg/s, inferred)") for s in series)
              # ArduPlane's PIDR/PIDP/PIDY Tar and Act are deg/s (Copter's rad/s)
              else dict.fromkeys(("PIDR", "PIDP", "PIDY"), np.pi / 180.0)
              if vehicle_kind(raw) == "plane" else {})
    commanded, commanded_from = _commanded(raw, t, boot.used - 1)
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
        scales=scales,
        mode_names={m.mode: m.name for m in raw.modes if m.name},
        flag_notes=flag_notes,
        sysid_injection=_sysid_injection(raw, t, boot.used - 1),
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
