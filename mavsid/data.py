"""Frozen data types that flow between the stages.

``RawLog`` (readers) -> ``FlightData`` (align) -> ``Segment`` (segment) -> estimators.
Arrays are samples-first; every table carries its time in seconds and its units.

Examples
--------
>>> import numpy as np
>>> t = MessageTable("ATT", {"Roll": np.array([1.0, 2.0])}, time_s=np.array([0.0, 0.1]),
...                  units={"Roll": "deg"})
>>> len(t), t["Roll"].tolist(), t.unit("Roll")
(2, [1.0, 2.0], 'deg')
"""

from __future__ import annotations

import functools
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from mavsid.errors import LogFormatError, MissingMessageError

__all__ = [
    "LOG_FORMATS",
    "Boot",
    "ChannelOrigin",
    "FlightData",
    "MessageTable",
    "ModeChange",
    "ParamChange",
    "RawLog",
    "Segment",
    "SourceInfo",
    "SysidRun",
    "TextMessage",
    "param_changes",
]


#: the formats a reader gives (:attr:`SourceInfo.format`)
LOG_FORMATS = ("dataflash", "dataflash-text", "tlog", "ulog")


@dataclass(frozen=True)
class MessageTable:
    """All samples of one message type, one array per field.

    Parameters
    ----------
    name : str
        Message (DataFlash, MAVLink) or topic (ULog) name.
    columns : Mapping[str, numpy.ndarray]
        Field name -> array with one row per sample (2-D for array fields). Strings are
        object arrays of ``str``.
    time_s : numpy.ndarray
        Sample time in seconds on the vehicle's own clock (float64), one per row.
    units : Mapping[str, str]
        Field name -> unit symbol as the log declares it (missing: unknown).
    multipliers : Mapping[str, float]
        Field name -> multiplier the log declares (DataFlash FMTU) but which is *not*
        applied to ``columns``; alignment applies it.
    declared : tuple of str
        Every field the log declares, for a table read for its times only (``times_only``
        of the DataFlash reader: ``columns`` then holds the time and instance columns).
    """

    name: str
    columns: Mapping[str, np.ndarray]
    time_s: np.ndarray
    units: Mapping[str, str] = field(default_factory=dict)
    multipliers: Mapping[str, float] = field(default_factory=dict)
    declared: tuple[str, ...] = ()

    def __len__(self) -> int:
        return int(self.time_s.shape[0])

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.columns[name]
        except KeyError:
            raise MissingMessageError(
                f"{self.name}.{name}", available=self.columns, what="field"
            ) from None

    def __contains__(self, name: object) -> bool:
        return name in self.columns

    @property
    def fields(self) -> tuple[str, ...]:
        """Field names in log order (``declared`` when the table was read for its times)."""
        return self.declared or tuple(self.columns)

    def unit(self, name: str) -> str | None:
        """The declared unit of field ``name``, or None when the log declares none."""
        return self.units.get(name)

    def numbers(self, name: str, path: object = None) -> np.ndarray:
        """Field ``name`` as float64 numbers: the one conversion every numeric value read
        from a log goes through (the field as logged, no multiplier applied).

        Raises
        ------
        LogFormatError
            The field holds text or anything else that is not a number (the log's format
            declares it so): one line naming the file (``path``), the message and the field.
        MissingMessageError
            The table has no such field.

        Examples
        --------
        >>> t = MessageTable("SIDS", {"Ax": np.array([10], np.uint8),
        ...                           "Mag": np.array(["abc"], object)}, np.zeros(1))
        >>> t.numbers("Ax").tolist()
        [10.0]
        >>> t.numbers("Mag", "a.bin")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        mavsid.errors.LogFormatError: a.bin: SIDS.Mag holds text, not numbers (its format ...
        """
        if name not in self.columns:
            raise MissingMessageError(f"{self.name}.{name}", available=self.columns,
                                      what="field", path=None if path is None else str(path))
        col = np.asarray(self.columns[name])
        if col.dtype.kind == "O" and not any(isinstance(v, (str, bytes)) for v in col.flat):
            try:
                col = col.astype(np.float64)
            except (TypeError, ValueError):
                pass
        if col.dtype.kind not in "biuf":
            what = "text" if col.dtype.kind in "OUS" else f"{col.dtype} values"
            raise LogFormatError(f"{self.name}.{name} holds {what}, not numbers (its format "
                                 "declares it so)", path=path)
        return col.astype(np.float64, copy=False)


@dataclass(frozen=True)
class TextMessage:
    """A text message from the log (DataFlash MSG, MAVLink STATUSTEXT, ULog logging)."""

    time_s: float
    text: str
    severity: int | None = None


@dataclass(frozen=True)
class ModeChange:
    """A flight-mode change: the mode number and, where known, its name."""

    time_s: float
    mode: int
    name: str | None = None


@dataclass(frozen=True)
class ParamChange:
    """A parameter set to a new value while the log ran (log clock, seconds)."""

    time_s: float
    name: str
    value: float


def param_changes(initial: Mapping[str, float],
                  records: Iterable[tuple[float, str, float]]) -> tuple[ParamChange, ...]:
    """The records ``(time_s, name, value)``, in the log's order, that change a parameter's
    value.

    ``initial`` holds the values the log starts with (a ULog's header; empty for a DataFlash
    log, which writes every parameter at its start, and a ground station's, which fetches
    them when it connects): a record of a name not seen before is its initial value, and
    one that repeats the value it had is no change (a reboot writing them all again). Values
    that are not finite numbers are left out.

    Examples
    --------
    >>> param_changes({"A": 1.0}, [(5.0, "A", 1.0), (6.0, "B", 3.0), (9.0, "A", 2.0),
    ...                            (12.0, "B", 4.0)])
    (ParamChange(time_s=9.0, name='A', value=2.0), ParamChange(time_s=12.0, name='B', \
value=4.0))
    """
    current = dict(initial)
    out = []
    for t, name, value in records:
        if not np.isfinite(value):
            continue
        before = current.get(name)
        current[name] = value
        if before is not None and before != value:
            out.append(ParamChange(float(t), str(name), float(value)))
    return tuple(out)


@dataclass(frozen=True)
class SourceInfo:
    """Where data came from and what the reader had to skip.

    Parameters
    ----------
    path : str
        The file as given.
    format : str
        ``"dataflash"``, ``"dataflash-text"``, ``"tlog"`` or ``"ulog"``.
    size_bytes : int
        File size.
    skipped_bytes : int
        Bytes that could not be decoded and were skipped.
    notes : tuple of str
        Data-quality notes (discontinuities, dropouts, corrections applied).
    """

    path: str
    format: str
    size_bytes: int
    skipped_bytes: int = 0
    notes: tuple[str, ...] = ()


@dataclass(frozen=True)
class RawLog:
    """Everything a reader decoded from one log file.

    Examples
    --------
    >>> log = RawLog(SourceInfo("x.bin", "dataflash", 0), messages={})
    >>> log["ATT"]
    Traceback (most recent call last):
    ...
    mavsid.errors.MissingMessageError: x.bin: log has no message 'ATT'
    """

    source: SourceInfo
    messages: Mapping[str, MessageTable]
    params: Mapping[str, float] = field(default_factory=dict)
    texts: tuple[TextMessage, ...] = ()
    modes: tuple[ModeChange, ...] = ()
    autopilot: str = "unknown"
    vehicle: str | None = None
    firmware: str | None = None
    #: the log's span (s) by its format's own clock where that differs from the records'
    #: times (a ULog: its header's start time to its last data timestamp, as pyulog has it)
    span_s: tuple[float, float] | None = None
    #: parameters set to a new value while the log ran, in time order (``params`` holds
    #: the values at its end; see :func:`param_changes`)
    param_changes: tuple[ParamChange, ...] = ()

    def __getitem__(self, name: str) -> MessageTable:
        try:
            return self.messages[name]
        except KeyError:
            raise MissingMessageError(
                name, available=self.messages, path=self.source.path or None
            ) from None

    def __contains__(self, name: object) -> bool:
        return name in self.messages

    @property
    def duration_s(self) -> float:
        """``span_s`` when the reader set it, else the span of the sample times over all
        messages (0 for an empty log)."""
        if self.span_s is not None:
            return max(0.0, float(self.span_s[1] - self.span_s[0]))
        lo, hi = np.inf, -np.inf
        for table in self.messages.values():
            t = table.time_s[np.isfinite(table.time_s)] if len(table) else table.time_s
            if t.size:
                lo, hi = min(lo, float(t.min())), max(hi, float(t.max()))
        return float(hi - lo) if hi >= lo else 0.0


@dataclass(frozen=True)
class Boot:
    """The boot of a log whose clock restarts that alignment kept (a log has one or more).

    Parameters
    ----------
    used, of : int
        Which boot (1-based) of how many.
    start_s, stop_s : float
        Its span by the reference channel's records (log clock).
    reason : str
        Why it was chosen.

    Examples
    --------
    >>> Boot(2, 3, 10.0, 70.0, "the longest").to_dict()["used"]
    2
    """

    used: int
    of: int
    start_s: float
    stop_s: float
    reason: str

    def to_dict(self) -> dict[str, int | float | str]:
        """The boot as JSON (``used of start_s stop_s reason``)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class SysidRun:
    """One ArduPilot SYSTEMID run: the span of its injected waveform and its settings.

    Parameters
    ----------
    start_s, stop_s : float
        The injection's first and last instants (log clock).
    settings_from : str
        ``"SIDS"`` (the run's own record), ``"PARM"`` (the log's SID_* parameters: no SIDS
        record) or ``"PARAM_VALUE"`` (parameters a ground station received before it).
    axis : int or None
        ``SID_AXIS`` (see :func:`mavsid.autopilot.ardupilot.sid_axis`).
    magnitude, f_start_hz, f_stop_hz : float or None
        The chirp's amplitude and frequency range.
    t_fade_in_s, t_const_freq_s, t_record_s, t_fade_out_s : float or None
        Its phases' durations.
    injected : bool
        False when the mode was flown but its waveform stayed zero throughout.

    Examples
    --------
    >>> run = SysidRun(6.0, 8.0, "SIDS", axis=10, magnitude=0.05)
    >>> run.to_dict()
    {'start_s': 6.0, 'stop_s': 8.0, 'settings_from': 'SIDS', 'axis': 10, 'magnitude': 0.05}
    >>> run.settings()
    {'settings_from': 'SIDS', 'axis': 10, 'magnitude': 0.05}
    """

    start_s: float
    stop_s: float
    settings_from: str
    axis: int | None = None
    magnitude: float | None = None
    f_start_hz: float | None = None
    f_stop_hz: float | None = None
    t_fade_in_s: float | None = None
    t_const_freq_s: float | None = None
    t_record_s: float | None = None
    t_fade_out_s: float | None = None
    injected: bool = True

    @property
    def sid_axis(self) -> int:
        """``SID_AXIS``, 0 (no axis) when unknown."""
        return self.axis or 0

    def to_dict(self) -> dict[str, float | int | str]:
        """The run as JSON: its span and the settings it has (unknown ones left out;
        ``injected`` only when False)."""
        return {f.name: v for f in fields(self)
                if (v := getattr(self, f.name)) is not None and not (f.name == "injected" and v)}

    def settings(self) -> dict[str, float | int | str]:
        """:meth:`to_dict` without the span."""
        return {k: v for k, v in self.to_dict().items() if k not in ("start_s", "stop_s")}


@dataclass(frozen=True)
class ChannelOrigin:
    """Where one aligned state or input came from: its source, native rate and unit.

    Parameters
    ----------
    source : str
        The field it was read from (``MESSAGE.field``), or how it was made (e.g.
        ``"RCOU (quad-x mixer)"``).
    native_rate_hz : float
        Its own sample rate in the log (Hz, rounded to 3 decimals; 0 when it has a single
        sample interval of 0).
    unit_from : str
        The unit the field was read in and where that came from (declared by the log, the
        preset's, inferred from evidence); empty when not known.
    excluded : Mapping[str, int]
        Samples excluded as never measured or mistimed: why -> how many.

    Examples
    --------
    >>> ch = ChannelOrigin("RATE.R", 400.0, "deg/s, declared by the log", {"non-finite": 2})
    >>> ch.excluded_count, ch.message
    (2, 'RATE')
    """

    source: str
    native_rate_hz: float
    unit_from: str = ""
    excluded: Mapping[str, int] = field(default_factory=dict)

    @property
    def excluded_count(self) -> int:
        """How many samples were excluded, for any reason."""
        return sum(self.excluded.values())

    @property
    def message(self) -> str:
        """The message (or topic) the channel was read from: ``source`` before its first dot
        or space."""
        return self.source.split(".")[0].split(" ")[0]


@dataclass(frozen=True)
class FlightData:
    """States and inputs of one flight on one uniform time grid, in SI units.

    Parameters
    ----------
    time_s : numpy.ndarray, shape (n,)
        Sample times (log clock, seconds); uniform with step ``dt`` inside each block.
    states : numpy.ndarray, shape (n, nx)
        Interpolated states (rad, rad/s).
    inputs : numpy.ndarray, shape (n, nu)
        Zero-order-held inputs (normalised controller outputs).
    state_names, input_names : tuple of str
    state_units, input_units : tuple of str
    dt : float
        Grid step in seconds.
    blocks : numpy.ndarray, shape (k, 2)
        ``[start, stop)`` index ranges of contiguous data; data is never interpolated across
        a gap, so a gap starts a new block.
    flags : Mapping[str, numpy.ndarray]
        Per-sample flags such as ``armed``, ``airborne`` (bool) and ``mode`` (int).
    source : SourceInfo
    preset : str
        Name of the channel preset used.
    params : Mapping[str, float]
        The log's parameters (needed for filters, SYSTEMID settings).
    autopilot, vehicle, firmware : str or None
        The platform as the log names it (:class:`RawLog`'s); None when not known.
    sysid_runs : tuple of SysidRun
        The ArduPilot SYSTEMID runs alignment found.
    boot : Boot or None
        The boot alignment kept (None: not from alignment).
    commanded : Mapping[str, numpy.ndarray]
        The commanded attitude per axis on the grid (roll and pitch angles, rad; the yaw
        heading's rate, rad/s; NaN outside its span).
    commanded_from : Mapping[str, str]
        Each commanded axis's source (``MESSAGE.field``).
    channels : Mapping[str, ChannelOrigin]
        Per state and input name, where it came from (source, native rate, unit read in,
        samples excluded); empty when not from alignment.
    mixer : str or None
        The mixer that turned motor outputs into the inputs (None: the inputs were logged).
    scales : Mapping[str, float]
        Factors inferred for whole messages (message -> factor to SI), which readers of the
        same message's other fields apply too (ArduCopter 3.4-dev ``RATE`` in centideg/s,
        ArduPlane's ``PIDR/PIDP/PIDY`` in deg/s).
    mode_names : Mapping[int, str]
        Flight-mode number -> name, for the modes the log names.
    flag_notes : Mapping[str, str]
        Per flag that had to be assumed (``armed``, ``airborne``), why.
    sysid_injection : numpy.ndarray or None
        SYSTEMID's logged waveform (``SIDD.Targ``) held on the grid, NaN where no record
        lies near (:func:`mavsid.align.sysid.sysid_injection`); None when not logged.
    inputs_at_state_times : Mapping[str, numpy.ndarray]
        Inputs interpolated between their native samples like the states (not held), for
        the frequency response against ``sysid_injection``; empty when the flight has no
        injection (:func:`mavsid.align.grid.between_held`).

    Examples
    --------
    >>> fd = FlightData(np.arange(2) * 0.1, np.zeros((2, 1)), np.ones((2, 1)), ("p",),
    ...                 ("u_roll",), ("rad/s",), ("1",), 0.1, np.array([[0, 2]]), {},
    ...                 SourceInfo("a.bin", "dataflash", 0), "t",
    ...                 channels={"p": ChannelOrigin("RATE.R", 400.0, excluded={"spike": 1}),
    ...                           "u_roll": ChannelOrigin("RATE.ROut", 400.0)})
    >>> fd.native_rate_hz, fd.excluded_samples, fd.sources["u_roll"]
    ({'p': 400.0, 'u_roll': 400.0}, {'p': 1}, 'RATE.ROut')
    """

    time_s: np.ndarray
    states: np.ndarray
    inputs: np.ndarray
    state_names: tuple[str, ...]
    input_names: tuple[str, ...]
    state_units: tuple[str, ...]
    input_units: tuple[str, ...]
    dt: float
    blocks: np.ndarray
    flags: Mapping[str, np.ndarray]
    source: SourceInfo
    preset: str
    params: Mapping[str, float] = field(default_factory=dict)
    autopilot: str | None = None
    vehicle: str | None = None
    firmware: str | None = None
    sysid_runs: tuple[SysidRun, ...] = ()
    boot: Boot | None = None
    commanded: Mapping[str, np.ndarray] = field(default_factory=dict)
    commanded_from: Mapping[str, str] = field(default_factory=dict)
    channels: Mapping[str, ChannelOrigin] = field(default_factory=dict)
    mixer: str | None = None
    scales: Mapping[str, float] = field(default_factory=dict)
    mode_names: Mapping[int, str] = field(default_factory=dict)
    flag_notes: Mapping[str, str] = field(default_factory=dict)
    sysid_injection: np.ndarray | None = field(default=None, repr=False)
    inputs_at_state_times: Mapping[str, np.ndarray] = field(default_factory=dict, repr=False)

    @property
    def native_rate_hz(self) -> dict[str, float]:
        """Each channel's own sample rate in the log, Hz (:attr:`channels`)."""
        return {n: c.native_rate_hz for n, c in self.channels.items()}

    @property
    def sources(self) -> dict[str, str]:
        """Each channel's source (:attr:`ChannelOrigin.source`)."""
        return {n: c.source for n, c in self.channels.items()}

    @property
    def units_from(self) -> dict[str, str]:
        """Each channel's unit read in and where that came from, where known."""
        return {n: c.unit_from for n, c in self.channels.items() if c.unit_from}

    @property
    def excluded_samples(self) -> dict[str, int]:
        """Channel -> how many of its samples were excluded (channels with any)."""
        return {n: c.excluded_count for n, c in self.channels.items() if c.excluded}

    def series(self, name: str) -> np.ndarray | None:
        """The state or input ``name`` on the grid; None when the flight has none.

        Examples
        --------
        >>> fd = FlightData(np.arange(2) * 0.1, np.zeros((2, 1)), np.ones((2, 1)), ("p",),
        ...                 ("u_roll",), ("rad/s",), ("1",), 0.1, np.array([[0, 2]]), {},
        ...                 SourceInfo("a.bin", "dataflash", 0), "t")
        >>> fd.series("u_roll").tolist(), fd.series("q")
        ([1.0, 1.0], None)
        """
        if name in self.state_names:
            return self.states[:, self.state_names.index(name)]
        if name in self.input_names:
            return self.inputs[:, self.input_names.index(name)]
        return None

    def index_of(self, segment: Segment) -> int | None:
        """Index of ``segment``'s first sample on this flight's grid; None when the segment
        was not cut from it (another log, other times).

        Examples
        --------
        >>> fd = FlightData(np.arange(5) * 0.1, np.zeros((5, 1)), np.zeros((5, 1)), ("p",),
        ...                 ("u_roll",), ("rad/s",), ("1",), 0.1, np.array([[0, 5]]), {},
        ...                 SourceInfo("a.bin", "dataflash", 0), "t")
        >>> seg = Segment(fd.time_s[2:4], fd.states[2:4], fd.inputs[2:4], ("p",), ("u_roll",),
        ...               0.1, "roll", "scan", log="a.bin")
        >>> fd.index_of(seg), fd.index_of(Segment(seg.time_s + 0.05, seg.states, seg.inputs,
        ...                                       ("p",), ("u_roll",), 0.1, "roll", "scan"))
        (2, None)
        """
        if segment.log and self.source.path and \
                os.fspath(segment.log) != os.fspath(self.source.path):
            return None
        t, n = self.time_s, len(segment)
        i = int(np.searchsorted(t, segment.time_s[0] - 1e-9)) if n else t.size
        if i >= t.size or i + n > t.size:
            return None
        if not np.allclose(t[i:i + n], segment.time_s, atol=1e-6 * max(self.dt, 1e-9)):
            return None
        return i


@dataclass(frozen=True)
class Segment:
    """A contiguous, uniformly sampled window chosen for identification.

    Parameters
    ----------
    time_s : numpy.ndarray, shape (n,)
    states : numpy.ndarray, shape (n, nx)
    inputs : numpy.ndarray, shape (n, nu)
    state_names, input_names : tuple of str
    dt : float
    axis : str
        ``"roll"``, ``"pitch"``, ``"yaw"`` (or ``"all"``).
    source : str
        ``"sysid"`` (an ArduPilot SYSTEMID run) or ``"scan"`` (found by scoring windows).
    score : float
        Excitation score (higher is better).
    log : str
        Path of the log the segment came from.
    reasons : tuple of str
        Why it was kept.
    meta : Mapping[str, object]
        Notes no stage reads, kept for the reader: the channel preset and the window's
        metrics (:func:`~mavsid.excitation.select_segments`), the block index
        (:func:`~mavsid.split.split_segments`), the record index (the array API).
    params : Mapping[str, float]
        The log's parameters (the estimators take known filters from them).
    sysid : SysidRun or None
        The ArduPilot SYSTEMID run the segment was cut from (its chirp's band and settings).
    inputs_before : numpy.ndarray, shape (k, nu), optional
        The inputs of the ``k`` samples just before the first (oldest first, columns as
        ``inputs``) when the segment was cut from a longer record (:meth:`cut`): the
        history that sets the input filters' and delay's state at the first sample, as
        the first measured state sets the model's. None: no history (filters start in
        steady state at the first input).
    """

    time_s: np.ndarray
    states: np.ndarray
    inputs: np.ndarray
    state_names: tuple[str, ...]
    input_names: tuple[str, ...]
    dt: float
    axis: str
    source: str
    score: float = float("nan")
    log: str = ""
    reasons: tuple[str, ...] = ()
    meta: Mapping[str, object] = field(default_factory=dict)
    params: Mapping[str, float] = field(default_factory=dict)
    sysid: SysidRun | None = None
    inputs_before: np.ndarray | None = None

    @property
    def start_s(self) -> float:
        """Time of the first sample."""
        return float(self.time_s[0])

    @property
    def stop_s(self) -> float:
        """Time of the last sample."""
        return float(self.time_s[-1])

    def __len__(self) -> int:
        return int(self.time_s.shape[0])

    def cut(self, a: int, b: int, **changes: Any) -> Segment:
        """Samples ``[a, b)`` as a segment, carrying the inputs before ``a`` (up to
        :data:`INPUT_HISTORY_S`, this segment's own history included) as its
        ``inputs_before``; ``changes`` replace other fields.

        A block cut from a longer record then starts its input filters and delay where
        the record had them: started cold at its first input instead, a free run over a
        chirp's fast part drifted as the slow plant integrated the filters' transient.

        Examples
        --------
        >>> u = np.arange(10.0)[:, None]
        >>> seg = Segment(u[:, 0] * 0.5, u, u, ("p",), ("u_roll",), 0.5, "roll", "scan")
        >>> late = seg.cut(6, 9)  # (2 s of history: 4 samples)
        >>> late.inputs[:, 0].tolist(), late.inputs_before[:, 0].tolist()
        ([6.0, 7.0, 8.0], [2.0, 3.0, 4.0, 5.0])
        >>> late.cut(1, 3).inputs_before[:, 0].tolist()  # (its own history carried on)
        [3.0, 4.0, 5.0, 6.0]
        >>> seg.cut(0, 3).inputs_before is None
        True
        """
        k = max(1, round(INPUT_HISTORY_S / self.dt)) if self.dt > 0 else 0
        own = self.inputs[max(0, a - k):a]
        before = self.inputs_before
        if a < k and before is not None and len(before):
            own = np.concatenate([before[max(0, len(before) - (k - a)):], own], axis=0)
        return replace(self, time_s=self.time_s[a:b], states=self.states[a:b],
                       inputs=self.inputs[a:b], inputs_before=own if len(own) else None,
                       **changes)


#: How far back :meth:`Segment.cut` keeps a block's input history, s: the slowest input
#: filter a model may hold (a heavy-lift frame's 170 ms motor lag, the longest searched)
#: forgets its start to 1e-5 in 2 s.
INPUT_HISTORY_S = 2.0


def demean(x: np.ndarray) -> np.ndarray:
    """``x`` less its mean along the last axis: ``scipy.signal.detrend(x, type="constant")``
    to the bit, without its per-call checks (Welch estimates call it once per window,
    thousands of times; pass it as ``detrend=demean``).

    Examples
    --------
    >>> from scipy.signal import detrend
    >>> x = np.random.default_rng(0).standard_normal(64)
    >>> bool(np.array_equal(demean(x), detrend(x, type="constant")))
    True
    """
    return x - np.mean(x, -1, keepdims=True)


@functools.lru_cache(maxsize=16)
def _line_basis(n: int) -> np.ndarray:
    """An orthonormal basis ``(n, 2)`` of the lines on ``n`` samples (QR of ``[k/n, 1]``)."""
    a = np.ones((n, 2))
    a[:, 0] = np.arange(1, n + 1, dtype=float) / n
    q = np.linalg.qr(a)[0]
    q.flags.writeable = False
    return q


def detrend_linear(x: np.ndarray) -> np.ndarray:
    """``x`` less its least-squares line along the last axis:
    ``scipy.signal.detrend(x, type="linear")`` to rounding (a projection on an orthonormal
    basis of the lines, kept between calls of one length, in place of a least-squares solve
    per call: a Welch estimate detrends all its windows in one call, ``detrend=detrend_linear``,
    and LAPACK's solver with many right-hand sides took a millisecond per window).

    Examples
    --------
    >>> from scipy.signal import detrend
    >>> x = np.random.default_rng(0).standard_normal((3, 64)) + np.arange(64)
    >>> bool(np.allclose(detrend_linear(x), detrend(x, type="linear"), rtol=0, atol=1e-12))
    True
    """
    x = np.asarray(x, dtype=float)
    q = _line_basis(x.shape[-1])
    return x - (x @ q) @ q.T


def decimate(v: np.ndarray, max_points: int, keep: np.ndarray | None = None) -> np.ndarray:
    """Indices of ``v`` that draw the same picture with at most about ``max_points`` samples:
    each bucket's minimum and maximum (the envelope, spikes included), every sample where
    ``keep`` is set, the first sample and the last; all of them when ``v`` is short enough.

    Examples
    --------
    >>> v = np.sin(np.arange(1000) / 5.0); v[500] = 9.0          # a spike
    >>> i = decimate(v, 100)
    >>> len(i) <= 102, 500 in i, bool(v[i].max() == v.max()), bool(v[i].min() == v.min())
    (True, True, True, True)
    >>> keep = np.zeros(1000, bool); keep[100:200] = True
    >>> bool(np.isin(np.arange(100, 200), decimate(v, 100, keep)).all())
    True
    """
    n = len(v)
    if n <= max_points:
        return np.arange(n)
    m = int(np.ceil(2 * n / max(max_points, 2)))
    nb = int(np.ceil(n / m))
    padded = np.full(nb * m, np.nan)
    padded[:n] = v
    grid = padded.reshape(nb, m)
    filled = np.isfinite(grid).any(axis=1)
    lo = np.where(np.isfinite(grid), grid, np.inf).argmin(axis=1)
    hi = np.where(np.isfinite(grid), grid, -np.inf).argmax(axis=1)
    base = np.arange(nb) * m
    picked = [base[filled] + lo[filled], base[filled] + hi[filled], base[~filled], [0, n - 1]]
    if keep is not None:
        picked.append(np.flatnonzero(keep))
    idx = np.concatenate([np.asarray(p, dtype=np.int64) for p in picked])
    mask = np.zeros(n, dtype=bool)  # sorted and unique (np.unique hashes: 10× slower here)
    mask[idx[idx < n]] = True
    return np.flatnonzero(mask)
