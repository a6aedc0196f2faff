"""The channels alignment reads: the preset chosen from the log's content, each channel's
native samples in SI units, with the samples never measured (non-finite, physically
impossible, mistimed) left out and counted.

A motor-output preset's inputs are the motors' PWM through the thrust curve, unmixed by the
frame's mixer; ArduCopter 3.4-dev's centidegree RATE records are found by evidence and
rescaled, with a warning.

Examples
--------
>>> t = np.array([0.0, 0.1, 0.1, 0.2])
>>> [a.tolist() for a in dedupe(t, np.arange(4.0))]
[[0.0, 0.1, 0.2], [0.0, 1.0, 3.0]]
"""

from __future__ import annotations

import functools
import re
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from mavsid.align.grid import sorted_unique
from mavsid.autopilot.ardupilot import IMU_GYRO_FIELDS
from mavsid.autopilot.mixers import MIXERS, Mixer, frame_name, frame_of, has_mixer
from mavsid.autopilot.presets import (
    PRESETS,
    QUADPLANE,
    Channel,
    Preset,
    choose_preset,
    get_preset,
    mixer_for,
    vehicle_kind,
)
from mavsid.axes import INPUT_NAMES, STATE_NAMES, STATE_UNITS
from mavsid.channels import (
    evaluate,
    motor_thrusts,
    resolve,
    rows_of,
    servo_inputs,
    unit_origin,
)
from mavsid.data import RawLog
from mavsid.errors import (
    ConfigError,
    DataQualityWarning,
    MavsidError,
    MissingMessageError,
    NoExcitationError,
)

__all__ = ["CENTI", "MAX_RATE_RAD_S", "TIME_OUTLIER_S", "Series", "channel_units", "dedupe",
           "first_fitting", "message_scales", "numeric_field", "reference", "time_outliers"]


#: no multicopter gyro reports more (4000 deg/s, twice the usual full scale)
MAX_RATE_RAD_S = float(np.deg2rad(4000.0))


#: a sample is mistimed when it lies further than this from the median time of the
#: ``2 * _OUTLIER_HALF + 1`` records around it (and further than many sample intervals)
TIME_OUTLIER_S = 10.0


_OUTLIER_HALF = 16


@dataclass(frozen=True)
class Series:
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


def dedupe(t: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


def first_fitting(raw: RawLog, preset: Preset | str | None,
                   presets: Mapping[str, Preset] | None, mixers: Mapping[str, Mixer]
                   ) -> tuple[Preset, tuple[list[Series], list[Series], str | None]]:
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
             ) -> tuple[list[Series], list[Series], str | None]:
    """States and inputs of the preset, as native series (record order) in canonical order."""
    states = _channel_series(raw, preset, STATE_NAMES, preset.states, need_samples=True)
    inputs: list[Series] = []
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
                inputs.append(Series(name, source, t, v, bad_t, excluded,
                                      "PWM us through SERVOn_MIN/TRIM/MAX"))
    else:
        inputs = _channel_series(raw, preset, INPUT_NAMES, preset.inputs, need_samples=False)
    states, inputs = _checked_scales(raw, states, inputs)
    states = [_possible(raw, s) for s in states]
    return states, inputs, mixer_name


#: ArduCopter 3.4-dev logged RATE in centidegrees/s and its outputs on a ±4500 scale
CENTI = 0.01


_OUT_SCALE = 4500.0


def _checked_scales(raw: RawLog, states: list[Series], inputs: list[Series]
                    ) -> tuple[list[Series], list[Series]]:
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
        gyro = numeric_field(raw, "IMU", IMU_GYRO_FIELDS[s.name])
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
        out_states = [replace(s, v=s.v * CENTI, source=f"{s.source} (centideg/s, inferred)",
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
                    channels: Mapping[str, Channel], need_samples: bool) -> list[Series]:
    """The preset's channels ``names`` (those it has) as native series, in that order.

    A channel that cannot be evaluated is left out when optional; one with fewer than two
    usable samples is left out, or (``need_samples``, not optional) is an error.
    """
    out: list[Series] = []
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
            out.append(Series(name, f"{ch.message}.{ch.field}", t, v, bad_t, excluded,
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
    near = sorted_unique((jumps[:, None] + np.arange(-half + 1, half + 1)).ravel())
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


def _possible(raw: RawLog, s: Series) -> Series:
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


def reference(states: Sequence[Series]) -> Series:
    """The channel that sets the grid: a body rate, else an attitude angle."""
    by_name = {s.name: s for s in states}
    for n in ("p", "q", "r", "roll", "pitch", "yaw"):
        if n in by_name:
            return by_name[n]
    raise ValueError("no state channel")  # callers check first


def numeric_field(raw: RawLog, msg: str, fld: str) -> tuple[np.ndarray, np.ndarray] | None:
    """``(time_s, values)`` of one numeric field; None when the log lacks it."""
    if msg not in raw.messages or fld not in raw.messages[msg].columns:
        return None
    tab = raw.messages[msg]
    return np.asarray(tab.time_s, dtype=float), tab.numbers(fld, raw.source.path)


def _motor_inputs(raw: RawLog, preset: Preset, mixers: Mapping[str, Mixer], kind: str
                  ) -> tuple[list[Series], str | None]:
    """The inputs a motor-output preset gives: the motors' PWM through the thrust curve,
    unmixed by the frame's mixer, and its name; none (and a warning saying why) for a
    vehicle that is not a multicopter, a frame without a mixer here, an assumed frame the
    outputs contradict (:func:`_more_motors`) or outputs that do not carry the motors."""
    ch = preset.motors
    assert ch is not None
    path = raw.source.path

    def none(why: str) -> tuple[list[Series], str | None]:
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
    return [Series(name, f"{ch.message} ({mixer.name} mixer)", t, u[:, j], bad_t, excluded,
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
        chosen, (states, inputs, _) = first_fitting(raw, preset, presets, mixers or {})
    return chosen.name, {s.name: {"unit": STATE_UNITS.get(s.name, "1"), "source": s.source,
                                  "read_in": s.unit_from} for s in (*states, *inputs)}


def message_scales(raw: RawLog, series: Sequence[Series]) -> dict[str, float]:
    """Factors to SI inferred for whole messages (message -> factor): readers of the same
    message's other fields (the twin's ``RATE.RDes`` targets) apply them too. ArduCopter
    3.4-dev's ``RATE`` when its body rates were found in centidegrees/s
    (:func:`first_fitting` says so in their source); ArduPlane's ``PIDR/PIDP/PIDY`` ``Tar``
    and ``Act`` are deg/s (Copter's rad/s).

    Examples
    --------
    >>> from mavsid.data import SourceInfo
    >>> raw = RawLog(SourceInfo("x.bin", "dataflash", 0), {})
    >>> s = Series("p", "RATE.R (centideg/s, inferred)", np.zeros(2), np.zeros(2))
    >>> message_scales(raw, [s]), message_scales(raw, [])
    ({'RATE': 0.01}, {})
    """
    if any(s.source.endswith("(centideg/s, inferred)") for s in series):
        return {"RATE": CENTI}
    if vehicle_kind(raw) == "plane":
        return dict.fromkeys(("PIDR", "PIDP", "PIDY"), np.pi / 180.0)
    return {}
