"""FlightData -> well-excited windows, each kept or rejected with reasons that carry numbers.

Two sources of windows, per axis (``roll``, ``pitch``, ``yaw``; the plant input is
``u_<axis>``, the output the body rate ``p``/``q``/``r``, or the angle when a log has no
rates):

``sysid``
    ArduPilot SYSTEMID runs (``FlightData.sysid_runs``, found by alignment from
    SIDS/SIDD, or SYSTEMID mode + SID_* parameters in a .tlog). The window is the injected
    chirp; ``SID_AXIS`` 1–12 name the axis (angle, recovery, rate or mixer injection), 13 is
    mixer thrust, which excites no attitude axis and is reported, not kept.
``scan``
    Sliding windows (``window_s`` long, every ``step_s``) inside each contiguous block, for
    axes without a SYSTEMID run (or all axes with ``scan=True``).

Excitation is judged where the physics says, never from the controller output's own level
alone: a rate controller feeds the gyro's noise back into its output, so on a noisy vehicle
that output's "noise floor" can be as large as a SYSTEMID injection.

- **response**: RMS of the *output* (body rate) in the band (its moving average over one
  period of the band's lower edge removed) against the output's own *noise floor*, its 1-s
  RMS where the input has no power (the median over the airborne samples whose input 1-s
  RMS lies in its lowest 20 %: hover, sticks centred). Gate: ``power_ratio``× the floor,
  for windows without a logged injection (a SYSTEMID run with ``SIDD.Targ`` is judged by
  the injection, below: with 6 deg/s of gyro noise fed back a well-identifiable chirp's
  response can sit under 5× that floor while 92 % coherent with the injection).
- **command** (windows without an injection, where the log has the commanded attitude: a
  stick manoeuvre's ``ATT.DesRoll``/``DesPitch``, the rate of ``DesYaw``, PX4's attitude
  setpoint): the output's
  coherence with it (weighted by its PSD) and the share of the band where it reaches
  ``min_coherence``. A response under ``power_ratio``× its noise floor is kept when it is
  coherent with the pilot's command (``min_coherence`` on average, over ``min_coverage``
  of the band): with 6 deg/s of gyro noise fed back a 3-2-1-1 on a racer sat at 4.5× its
  floor while 0.93 coherent with the command. The fit then checks the feedback's bias with
  the same command (:mod:`mavsid.estimators.instruments`).
- **injection** (SYSTEMID runs whose log has ``SIDD.Targ``): the injected waveform's RMS, its
  band (``SID_F_START_HZ``–``SID_F_STOP_HZ``, upper edge at most 0.4× the sample rate) and
  the output's coherence with it (weighted by the injection's PSD). Gate: ``min_coherence``.
  Band coverage is then the share of that band where this coherence reaches
  ``min_coherence``.
- **input power** (reported, not gated): RMS of the input in the band against the input's
  noise floor, the 10th percentile of its 1-s RMS over the airborne flight (at least
  ``min_floor``).
- **band coverage** (without an injection): share of the ``band_hz`` band (log-frequency
  weighted; upper edge at most 0.4× the sample rate) where the input's Welch PSD is above
  10× the input floor's white level. Gate: ``min_coverage``, waived for a response coherent
  with the pilot's command over that share of the band (see *command*): a pilot who never
  lets go of the stick leaves no quiet stretch to measure the input's floor by, which is
  then the manoeuvre's own level (a random-stick flight without a hover: 0 % coverage).
- **conditioning**: condition number of the Gram matrix of the regressors of the model to be
  fitted, ``[rate, input]``, centred (which accounts for the constant term), the rate scaled
  by its own spread in the window and the input by the spread of all attitude inputs
  (``u_roll u_pitch u_yaw``) in the window. It is large when the axis's input carries a
  small share of the window's excitation (the other axes of a one-input manoeuvre) or only
  follows the response (closed-loop feedback without independent excitation). Gate:
  ``max_condition``.
- **coherence** (without an injection): input–output magnitude-squared coherence, averaged
  over the band weighted by the input's PSD. Gate: ``min_coherence``.
- **flight state**: airborne and armed over ``min_airborne`` of the window; no mode change
  inside a scan window; ``|roll|``, ``|pitch|`` within ``max_angle_deg``; the axis input and
  ``u_thrust`` saturated (``|u| >= saturation``, thrust also <= 0.02) on at most
  ``max_saturated`` of the samples.

``score`` (0..1) is the geometric mean of ``min(1, log10(response ratio)/2)``, the coverage,
the coherence and ``1 - log10(condition)/2`` (each clipped to 0..1). Adjacent kept scan
windows are merged, and a merged window's quiet head and tail (where the input stays within
the power gate of its level in a quiet first/last 0.5 s) are trimmed; when the merged window
fails a gate its parts are reported as they were. :func:`find_segments` returns every window's
:class:`WindowReport`; :func:`select_segments` turns the kept ones into
:class:`~mavsid.data.Segment` objects for the estimators.

Examples
--------
>>> import numpy as np
>>> from mavsid.data import FlightData, SourceInfo
>>> rng = np.random.default_rng(0)
>>> n, dt = 6000, 0.01
>>> t = np.arange(n) * dt
>>> u = 0.002 * rng.standard_normal(n)
>>> u[2000:4000] += 0.1 * np.sign(np.sin(2 * np.pi * 0.7 * t[2000:4000]))   # 20 s of doublets
>>> p = np.zeros(n)
>>> for k in range(1, n):
...     p[k] = 0.95 * p[k - 1] + 0.5 * u[k - 1]
>>> x = np.column_stack([np.zeros(n), np.zeros(n), np.zeros(n), p])
>>> fd = FlightData(t, x, u[:, None], ("roll", "pitch", "yaw", "p"), ("u_roll",),
...                 ("rad",) * 3 + ("rad/s",), ("1",), dt, np.array([[0, n]]),
...                 {"armed": np.ones(n, bool), "airborne": np.ones(n, bool)},
...                 SourceInfo("sim", "synthetic", 0), "test")
>>> kept = [w for w in find_segments(fd, axis="roll") if w.kept]
>>> [(round(w.start_s, 1), round(w.stop_s, 1), w.source) for w in kept]
[(20.0, 40.0, 'scan')]
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from mavsid.autopilot.ardupilot import SID_IDENTIFIES, sid_axis
from mavsid.axes import AXES, RATE_OF
from mavsid.data import FlightData, Segment, SysidRun, detrend_linear
from mavsid.errors import ConfigError, finite_number
from mavsid.numerics.spectra import density, segment_ffts
from mavsid.reasons import Reason, format_number, group

__all__ = [
    "AXES",
    "ScanOptions",
    "WindowReport",
    "find_segments",
    "select_segments",
]

def _interval(lo: float, hi: float) -> str:
    """``[lo, hi]`` as text (``(0, hi]`` where 0 is excluded).

    >>> _interval(0.0, 1.0), _interval(1.0, math.inf)
    ('[0, 1]', '[1, inf)')
    """
    right = "inf)" if hi == math.inf else f"{hi:g}]"
    return f"[{lo:g}, {right}"


#: the numeric scan options and the values each may take (inclusive)
_SCAN_RANGES = (
    ("window_s", 1e-3, math.inf), ("power_ratio", 0.0, math.inf), ("min_floor", 0.0, math.inf),
    ("min_coverage", 0.0, 1.0), ("min_coherence", 0.0, 1.0), ("max_condition", 1.0, math.inf),
    ("min_airborne", 0.0, 1.0), ("max_angle_deg", 1e-3, 180.0), ("saturation", 1e-3, math.inf),
    ("max_saturated", 0.0, 1.0),
)


@dataclass(frozen=True)
class ScanOptions:
    """Window lengths, gates and thresholds (defaults suit multirotor attitude dynamics).

    Parameters
    ----------
    window_s, step_s : float
        Scan window length and step, s (step default: half the window).
    band_hz : tuple of float
        Identification band for coverage and coherence, Hz.
    power_ratio : float
        The output's response must reach this many of its noise floors.
    min_floor : float
        Smallest noise floor (normalised input units): below it the log's own quantisation.
    min_coverage, min_coherence : float
        Gates on band coverage and input–output coherence (0..1).
    max_condition : float
        Gate on the regressor Gram's condition number.
    min_airborne : float
        Share of the window that must be airborne and armed.
    max_angle_deg : float
        Bound on ``|roll|`` and ``|pitch|``.
    saturation, max_saturated : float
        ``|u| >= saturation`` counts as saturated; at most ``max_saturated`` of the window.
    """

    window_s: float = 5.0
    step_s: float | None = None
    band_hz: tuple[float, float] = (0.5, 10.0)
    power_ratio: float = 5.0
    min_floor: float = 1e-3
    min_coverage: float = 0.3
    min_coherence: float = 0.5
    max_condition: float = 10.0
    min_airborne: float = 0.95
    max_angle_deg: float = 45.0
    saturation: float = 0.95
    max_saturated: float = 0.05

    def __post_init__(self) -> None:
        band = self.band_hz
        if not (isinstance(band, (tuple, list)) and len(band) == 2
                and all(map(finite_number, band))
                and 0 < band[0] < band[1]):
            raise ConfigError(f"band_hz must be [low, high] Hz, 0 < low < high, got {band!r}")
        if self.step_s is not None and not (finite_number(self.step_s) and self.step_s > 0):
            raise ConfigError(f"step_s must be a positive number of seconds, got {self.step_s!r}")
        for name, lo, hi in _SCAN_RANGES:
            x = getattr(self, name)
            if not (finite_number(x) and lo <= x <= hi):
                raise ConfigError(f"{name} must be a number in {_interval(lo, hi)}, got {x!r}")

    @classmethod
    def from_options(cls, options: Mapping[str, Any]) -> ScanOptions:
        """Options given by name (a pipeline config's ``[segments] options``), each checked.

        Examples
        --------
        >>> ScanOptions.from_options({"window_s": 4, "band_hz": [0.3, 8]}).band_hz
        (0.3, 8)
        >>> ScanOptions.from_options({"windows": 4})  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        mavsid.errors.ConfigError: segments.options: unknown option(s) windows (known: ...)
        """
        known = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(set(options) - set(known))
        if unknown:
            raise ConfigError(f"segments.options: unknown option(s) {', '.join(unknown)} "
                              f"(known: {', '.join(known)})")
        values = dict(options)
        if isinstance(values.get("band_hz"), list):
            values["band_hz"] = tuple(values["band_hz"])
        try:
            return cls(**values)
        except ConfigError as exc:
            raise ConfigError(f"segments.options: {exc}") from None

    @property
    def step(self) -> float:
        """Scan step, s."""
        return self.step_s if self.step_s is not None else self.window_s / 2


@dataclass(frozen=True)
class WindowReport:
    """One window on one axis: where, how good, kept or not and why.

    ``start_s``/``stop_s`` are the first and last sample times (log clock); ``i0``/``i1``
    the ``[start, stop)`` sample indices into the FlightData. ``checks`` are the gates a
    rejected window failed, as values; ``reasons`` the sentences made from them (or why it
    was kept), then notes (the SYSTEMID run's settings, a merge). ``sysid`` is the SYSTEMID
    run a ``"sysid"`` window lies in, ``axis_from_data`` the axis its input shows when that
    differs from the run's ``SID_AXIS``; ``merged_windows`` how many overlapping scan windows
    a kept window was merged from (0: not merged).
    """

    axis: str
    start_s: float
    stop_s: float
    score: float
    kept: bool
    source: str
    reasons: tuple[str, ...]
    i0: int
    i1: int
    metrics: Mapping[str, float] = field(default_factory=dict)
    checks: tuple[Reason, ...] = ()
    sysid: SysidRun | None = None
    axis_from_data: str | None = None
    merged_windows: int = 0

    @property
    def meta(self) -> dict[str, object]:
        """The window's SYSTEMID run (``sid_axis injection sysid``, its settings, and
        ``axis_from_data``) or merge (``merged_windows``) as JSON; empty for others."""
        out: dict[str, object] = {}
        if self.sysid is not None:
            sid = self.sysid.sid_axis
            out.update(sid_axis=sid, injection=sid_axis(sid)[1], sysid=self.sysid.settings())
            if self.axis_from_data is not None:
                out["axis_from_data"] = self.axis_from_data
        if self.merged_windows:
            out["merged_windows"] = self.merged_windows
        return out

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dict (``axis start_s stop_s score kept source reasons reason_kinds
        checks metrics meta``): ``reasons`` the sentences, ``checks`` the gates failed as
        :meth:`Reason.to_dict <mavsid.reasons.Reason.to_dict>`."""
        return {
            "axis": self.axis,
            "start_s": round(self.start_s, 6),
            "stop_s": round(self.stop_s, 6),
            "score": _json_float(self.score),
            "kept": bool(self.kept),
            "source": self.source,
            "reasons": list(self.reasons),
            "reason_kinds": [r.kind for r in self.checks],
            "checks": [r.to_dict() for r in self.checks],
            "metrics": {k: _json_float(v) for k, v in self.metrics.items()},
            "meta": self.meta,
        }


def _json_float(x: float) -> float | None:
    return round(float(x), 6) if math.isfinite(x) else None


# --------------------------------------------------------------------------- helpers


@dataclass(frozen=True)
class _Axis:
    """What one axis needs from the FlightData."""

    name: str
    u: np.ndarray | None  # input
    u_hp: np.ndarray | None  # input without content below the band (per block)
    y: np.ndarray | None  # output (rate, else angle)
    y_name: str
    u_name: str
    floor: float
    y_hp: np.ndarray | None = None  # output without content below the band (per block)
    y_floor: float = math.nan  # output's 1-s RMS where the input has no power
    injection: np.ndarray | None = None  # SYSTEMID's logged waveform (SIDD.Targ), 0 outside
    command: np.ndarray | None = None  # commanded attitude (rad; yaw: rate), NaN if not logged
    command_from: str = ""  # where the command came from (``ATT.DesRoll``, the sticks ...)
    # the collective thrust, where it was really logged (a constant column was not): judged
    # once per flight, not per window (a 27-min flight has ~600 windows an axis)
    thrust: np.ndarray | None = None


def _col(fd: FlightData, name: str) -> np.ndarray | None:
    if name in fd.state_names:
        return fd.states[:, fd.state_names.index(name)]
    if name in fd.input_names:
        return fd.inputs[:, fd.input_names.index(name)]
    return None


def _moving(x: np.ndarray, n: int) -> np.ndarray:
    """Centred moving average over ``n`` samples (same length; the first ``n // 2`` take the
    first ``n``, the last ones what is left after their window's start).

    >>> _moving(np.array([1.0, 2.0, 3.0, 4.0, 5.0]), 3).tolist()
    [2.0, 2.0, 3.0, 4.0, 4.5]
    """
    size = x.size
    n = max(1, min(int(n), size))
    h = n // 2
    c = np.concatenate([[0.0], np.cumsum(x)])
    out = np.empty(size)
    if not size:
        return out
    # sample i averages c[lo..hi) with lo = max(i - h, 0), hi = min(lo + n, size), by slices
    out[:h] = (c[n] - c[0]) / n
    out[h : size - n + h + 1] = c[n:] - c[: size - n + 1]
    out[h : size - n + h + 1] /= n
    lo = np.arange(size - n + 1, size - h)
    out[size - n + h + 1 :] = (c[size] - c[lo]) / (size - lo)
    return out


def _airborne(fd: FlightData) -> np.ndarray:
    n = fd.time_s.size
    air = np.asarray(fd.flags.get("airborne", np.ones(n, bool)), dtype=bool)
    armed = np.asarray(fd.flags.get("armed", np.ones(n, bool)), dtype=bool)
    return air & armed


def _axis(fd: FlightData, name: str, opts: ScanOptions, air: np.ndarray) -> _Axis:
    u_name = f"u_{name}"
    u = _col(fd, u_name)
    y_name = RATE_OF[name] if RATE_OF[name] in fd.state_names else name
    y = _col(fd, y_name)
    sel = air if air.any() else np.ones_like(air)
    floor = opts.min_floor
    u_hp = None
    u_env = y_hp = None
    y_floor = math.nan
    if u is not None:
        u_hp = _highpass(fd, u, opts)
        u_env = _envelope(fd, u_hp)
        if u_env[sel].size:
            floor = max(opts.min_floor, float(np.percentile(u_env[sel], 10)))
    if y is not None:
        y_hp = _highpass(fd, y, opts)
        y_env = _envelope(fd, y_hp)[sel]
        if y_env.size:
            quiet = np.ones(y_env.size, bool)
            if u_env is not None:  # where the input has no power
                quiet = u_env[sel] <= np.percentile(u_env[sel], 20)
            y_floor = max(float(np.median(y_env[quiet])), 1e-9)
    injection = None if fd.sysid_injection is None else np.asarray(fd.sysid_injection, float)
    cmd = fd.commanded.get(name)
    command = np.asarray(cmd, dtype=float) if isinstance(cmd, np.ndarray) else None
    source = fd.commanded_from.get(name, "")
    thrust = _col(fd, "u_thrust")
    if thrust is not None and not np.ptp(thrust) > 1e-6:
        thrust = None
    return _Axis(name, u, u_hp, y, y_name, u_name, floor, y_hp, y_floor, injection, command,
                 str(source), thrust)


def _highpass(fd: FlightData, x: np.ndarray, opts: ScanOptions) -> np.ndarray:
    """``x`` less its moving average over one period of the band's low edge (per block)."""
    n_lo = max(3, round(1.0 / (opts.band_hz[0] * fd.dt)))
    out = np.zeros_like(x)
    for a, b in fd.blocks:
        out[a:b] = x[a:b] - _moving(x[a:b], n_lo)
    return out


def _envelope(fd: FlightData, x_hp: np.ndarray) -> np.ndarray:
    """1-s moving RMS of ``x_hp`` (per block)."""
    n1 = max(3, round(1.0 / fd.dt))
    out = np.zeros_like(x_hp)
    for a, b in fd.blocks:
        out[a:b] = np.sqrt(np.clip(_moving(x_hp[a:b] ** 2, n1), 0, None))
    return out


def _metrics(ax: _Axis, fd: FlightData, i0: int, i1: int, opts: ScanOptions,
             band: tuple[float, float] | None, st: Mapping[str, Any]) -> dict[str, float]:
    """Excitation metrics of samples ``[i0, i1)`` for one axis (``band``: a SYSTEMID run's;
    ``st``: the window's :func:`_window_stats`)."""
    if i1 - i0 < 8:
        return {"noise_floor": ax.floor}
    with np.errstate(divide="ignore", invalid="ignore"):  # constant signals give NaN, handled
        out = _metrics_raw(ax, fd, i0, i1, opts, st)
        if ax.y_hp is not None:
            out["response_rms"] = math.sqrt(st["y_ms"])
            out["response_floor"] = ax.y_floor
            out["response_ratio"] = out["response_rms"] / ax.y_floor
        if ax.injection is not None and ax.y is not None:
            got = _referenced(st, "injection", i1 - i0, fd, opts, band)
            out.update({f"injection_{k}": v for k, v in got.items()})
        elif ax.command is not None and ax.y is not None and st["command_finite"]:
            got = _referenced(st, "command", i1 - i0, fd, opts, opts.band_hz)
            out.update({f"command_{k}": v for k, v in got.items() if k in ("coherence",
                                                                             "coverage")})
        return out


def _nper(n: int, fs: float) -> int:
    """The Welch segment length of a window of ``n`` samples: 2 s (16 samples at least),
    the whole window if shorter.

    >>> _nper(2000, 400.0), _nper(500, 400.0), _nper(100, 5.0)
    (800, 500, 16)
    """
    return int(min(n, max(16, round(2.0 * fs))))


#: the signals whose spectra a window's metrics use: input, output, command, injection
_SIGNALS = ("u", "y", "command", "injection")


def _window_stats(ax: _Axis, fd: FlightData, air: np.ndarray, opts: ScanOptions,
                  starts: Sequence[int], win: int) -> list[dict[str, Any]]:
    """What :func:`_metrics` and :func:`_gates` measure of windows of ``win`` samples at
    ``starts``, for all of them at once, one dict per window. For the gates: the airborne
    share, the first mode change (its index in the window, -1 none), the peak ``|roll|`` and
    ``|pitch|``, the input's saturated share and the thrust's share at its limits while
    airborne (NaN when never airborne). Of windows of 8 samples or more, for the metrics:
    the frequencies ``f`` of the Welch spectra (segments of :func:`_nper` samples, half
    overlapping, linear detrend, Hann: :mod:`mavsid.numerics.spectra`); per signal present
    (:data:`_SIGNALS`) its spectrum ``psd:<key>`` and, against the output, the
    cross-spectrum ``csd:<key>``; the mean squares of the high-passed input and output
    (``u_ms``, ``y_ms``) and of the command and injection (``<key>_ms``); whether the
    command is finite; the attitude inputs' mean variance ``att_var``; the centred sums
    ``syy``, ``suu``, ``syu`` of the output and input.

    A window measured alone is a batch of one: its numbers are those it gets in any batch
    (a long flight has thousands of windows; measured one by one they cost ~0.5 ms each).
    """
    first = np.asarray(starts, np.int64)
    rows = first[:, None] + np.arange(win)  # (windows, samples)
    got = _gate_stats(ax, fd, air, opts, rows)
    if win < 8:
        return [{k: v[i] for k, v in got.items()} for i in range(first.size)]
    fs = 1.0 / fd.dt
    nper = _nper(win, fs)
    hop = nper - nper // 2
    count = (win - nper) // hop + 1
    at = (first[:, None] + hop * np.arange(count)).ravel()
    seg: dict[str, np.ndarray] = {}
    signals = dict(zip(_SIGNALS, (ax.u, ax.y, ax.command, ax.injection), strict=True))
    for key, x in signals.items():
        if x is None:
            continue
        s = seg[key] = segment_ffts(x, nper, detrend=detrend_linear, starts=at).reshape(
            first.size, count, -1)
        got[f"psd:{key}"] = density(s, s, fs, nper, average=False).mean(axis=1).real
        if key in ("command", "injection"):
            got[f"{key}_ms"] = np.mean(x[rows] ** 2, axis=1)
    if "y" in seg:
        for key in ("u", "command", "injection"):
            if key in seg:
                got[f"csd:{key}"] = density(seg[key], seg["y"], fs, nper,
                                            average=False).mean(axis=1)
    if ax.command is not None:
        got["command_finite"] = np.isfinite(ax.command[rows]).all(axis=1)
    for key, x in (("u_ms", ax.u_hp), ("y_ms", ax.y_hp)):
        if x is not None:
            got[key] = np.mean(x[rows] ** 2, axis=1)
    att = [c for c in (_col(fd, f"u_{a}") for a in AXES) if c is not None]
    if att:
        got["att_var"] = np.mean([np.var(c[rows], axis=1) for c in att], axis=0)
    if ax.u is not None and ax.y is not None:
        y, u = ax.y[rows], ax.u[rows]
        y -= y.mean(axis=1, keepdims=True)
        u -= u.mean(axis=1, keepdims=True)
        got["syy"] = np.sum(y * y, axis=1) / win
        got["suu"] = np.sum(u * u, axis=1) / win
        got["syu"] = np.sum(y * u, axis=1) / win
    f = np.fft.rfftfreq(nper, 1.0 / fs)
    return [{"f": f, **{k: v[i] for k, v in got.items()}} for i in range(first.size)]


def _gate_stats(ax: _Axis, fd: FlightData, air: np.ndarray, opts: ScanOptions,
                rows: np.ndarray) -> dict[str, np.ndarray]:
    """:func:`_window_stats`' measures for the gates, of the windows of sample indices
    ``rows`` (windows, samples)."""
    on = air[rows]
    got: dict[str, np.ndarray] = {"airborne": on.mean(axis=1)}
    mode = fd.flags.get("mode")
    if mode is not None and rows.shape[1] > 1:
        change = np.diff(np.asarray(mode)[rows], axis=1) != 0
        got["mode_change"] = np.where(change.any(axis=1), change.argmax(axis=1), -1)
    for ang in ("roll", "pitch"):
        a = _col(fd, ang)
        if a is not None:
            got[f"peak_{ang}"] = np.max(np.abs(a[rows]), axis=1)
    if ax.u is not None:
        got["saturated"] = (np.abs(ax.u[rows]) >= opts.saturation).mean(axis=1)
    if ax.thrust is not None:
        tw = ax.thrust[rows]
        limits = ((tw >= opts.saturation) | (tw <= 0.02)) & on
        with np.errstate(divide="ignore", invalid="ignore"):
            got["thrust_limits"] = limits.sum(axis=1) / on.sum(axis=1)
    return got


def _coherence(st: Mapping[str, Any], key: str) -> np.ndarray:
    """``scipy.signal.coherence`` of signal ``key`` and the output (linear detrend) from
    the window's spectra (:func:`_window_stats`)."""
    return np.asarray(np.abs(st[f"csd:{key}"]) ** 2 / st[f"psd:{key}"] / st["psd:y"])


def _referenced(st: Mapping[str, Any], key: str, n: int, fd: FlightData, opts: ScanOptions,
                band: tuple[float, float] | None) -> dict[str, float]:
    """A reference's (``key``: the injection or the command, a window of ``n`` samples)
    RMS, band (``lo_hz``, ``hi_hz``), and the output's ``coherence`` with it (weighted by
    its PSD) and ``coverage`` (log-frequency share of the band where that coherence
    reaches ``min_coherence``); {} for a silent reference."""
    rms = math.sqrt(st[f"{key}_ms"])
    if not rms > 0:
        return {}
    fs = 1.0 / fd.dt
    f_lo, f_hi = band if band is not None else opts.band_hz
    f_lo, f_hi = max(f_lo, 2.0 / (n * fd.dt)), min(f_hi, 0.4 * fs)
    out = {"rms": rms, "lo_hz": f_lo, "hi_hz": f_hi}
    f, pvv = st["f"], st[f"psd:{key}"]
    coh = _coherence(st, key)
    sel = (f >= f_lo) & (f <= f_hi)
    if sel.sum() < 2 or not pvv[sel].sum() > 0:
        out["coherence"] = 0.0
        out["coverage"] = 0.0
        return out
    coh = np.nan_to_num(coh)
    out["coherence"] = float(np.sum(pvv[sel] * coh[sel]) / np.sum(pvv[sel]))
    w = 1.0 / f[sel]  # log-frequency weighting
    out["coverage"] = float(np.sum(w * (coh[sel] >= opts.min_coherence)) / np.sum(w))
    return out


def _metrics_raw(ax: _Axis, fd: FlightData, i0: int, i1: int, opts: ScanOptions,
                 st: Mapping[str, Any]) -> dict[str, float]:
    fs = 1.0 / fd.dt
    out: dict[str, float] = {"noise_floor": ax.floor}
    if ax.u is None or ax.u_hp is None or ax.y is None:
        return out
    rms = math.sqrt(st["u_ms"])
    out["input_rms"] = rms
    out["power_ratio"] = rms / ax.floor
    f_lo, f_hi = opts.band_hz[0], min(opts.band_hz[1], 0.4 * fs)
    out["band_lo_hz"], out["band_hi_hz"] = f_lo, f_hi
    if f_hi > f_lo:
        f, puu = st["f"], st["psd:u"]
        band = (f >= f_lo) & (f <= f_hi)
        if band.sum() >= 2:
            w = np.zeros_like(f)
            w[band] = 1.0 / f[band]  # log-frequency weighting
            white = ax.floor**2 / (fs / 2)
            out["coverage"] = float(np.sum(w * (puu > 10 * white)) / np.sum(w))
            coh = _coherence(st, "u")
            wp = puu * band
            out["coherence"] = float(np.sum(wp * np.nan_to_num(coh)) / np.sum(wp)) if wp.sum(
            ) > 0 else 0.0
    # Gram of the model's regressors [y, u], centred (the constant term); y scaled by its own
    # spread, u by the spread of all attitude inputs in the window (its share of the excitation)
    ref = math.sqrt(st["att_var"]) if "att_var" in st else math.nan
    syy, suu, syu = float(st["syy"]), float(st["suu"]), float(st["syu"])
    if syy > 0 and ref > 0:
        # the Gram [[1, b], [b, d]] of [y / its spread, u / ref], its eigenvalues in closed
        # form (a window's 2x2 eigvalsh and corrcoef cost ~0.4 ms; a long flight has
        # thousands of windows); the smaller one as det / the larger, not as the difference
        # of two nearly equal terms
        b, d = syu / math.sqrt(syy) / ref, suu / ref**2
        hi = (1 + d) / 2 + math.hypot((1 - d) / 2, b)
        lo = (d - b * b) / hi
        out["condition"] = hi / lo if lo > 0 else math.inf
        out["input_share"] = math.sqrt(suu) / ref
        out["correlation"] = syu / math.sqrt(syy * suu) if suu > 0 else math.nan
    else:
        out["condition"] = math.inf
    return out


def _score(m: Mapping[str, float]) -> float:
    if "power_ratio" not in m:
        return 0.0
    ratio = m.get("response_ratio", m["power_ratio"])
    inj = "injection_rms" in m
    # a response that follows the pilot's command: its coherence and coverage with the
    # command stand for its level and the input's coverage (measured against floors that
    # a flight without a quiet stretch does not show, see _gates)
    level = min(1.0, max(0.0, math.log10(max(ratio, 1e-12)) / 2)) if math.isfinite(ratio) else 0.0
    coverage = m.get("injection_coverage" if inj else "coverage", 0.0)
    if "command_coherence" in m and not inj:
        level = max(level, m["command_coherence"])
        coverage = max(coverage, m["command_coverage"])
    terms = [
        level,
        coverage,
        m.get("injection_coherence" if inj else "coherence", 0.0),
        min(1.0, max(0.0, 1 - math.log10(max(m.get("condition", math.inf), 1.0)) / 2))
        if math.isfinite(m.get("condition", math.inf)) else 0.0,
    ]
    return float(np.prod(terms) ** (1 / len(terms)))


def _gates(ax: _Axis, fd: FlightData, i0: int, i1: int, m: Mapping[str, float],
           opts: ScanOptions, st: Mapping[str, Any], check_mode: bool,
           check_excitation: bool = True) -> list[Reason]:
    """Rejection reasons (empty: passes); ``st``: the window's :func:`_window_stats`."""
    out: list[Reason] = []
    if ax.u is None:
        return [Reason("missing_channel", {}, {"channel": ax.u_name, "role": "input",
                                               "preset": fd.preset})]
    if ax.y is None:
        return [Reason("missing_channel", {}, {"channel": ax.y_name, "role": "output",
                                               "preset": fd.preset})]
    frac = float(st["airborne"])
    if frac < opts.min_airborne:
        out.append(Reason("not_airborne", {"grounded_pct": 100 * (1 - frac),
                                           "need_pct": 100 * opts.min_airborne}))
    mode = fd.flags.get("mode")
    k = int(st.get("mode_change", -1))
    if check_mode and mode is not None and k >= 0:
        names = fd.mode_names
        a, b = (names.get(int(v), str(int(v))) for v in (mode[i0 + k], mode[i0 + k + 1]))
        out.append(Reason("mode_change", {"at_s": float(fd.time_s[i0 + k + 1])},
                          {"from": str(a), "to": str(b)}))
    for ang in ("roll", "pitch"):
        if f"peak_{ang}" in st:
            peak = float(np.degrees(st[f"peak_{ang}"]))
            if peak > opts.max_angle_deg:
                out.append(Reason("attitude_bound", {"peak_deg": peak,
                                                     "bound_deg": opts.max_angle_deg},
                                  {"angle": ang}))
    sat = float(st["saturated"])
    if sat > opts.max_saturated:
        out.append(Reason("input_saturated", {"saturation": opts.saturation,
                                              "saturated_pct": 100 * sat,
                                              "limit_pct": 100 * opts.max_saturated},
                          {"input": ax.u_name}))
    ts = float(st.get("thrust_limits", math.nan))  # (NaN: no thrust, or never airborne)
    if ts > opts.max_saturated:
        out.append(Reason("thrust_limits", {"saturated_pct": 100 * ts,
                                            "limit_pct": 100 * opts.max_saturated}))
    if not check_excitation:
        return out
    if "power_ratio" not in m:
        out.append(Reason("too_short", {"samples": float(i1 - i0)}))
        return out
    names_uy = {"input": ax.u_name, "output": ax.y_name}
    ratio = m.get("response_ratio", math.nan)
    # (a SYSTEMID run with its injection logged is judged by the output's coherence with
    # the injection, below, not by these levels)
    by_level = "injection_rms" not in m
    if by_level and not math.isfinite(ratio):  # no output to judge by: the input's own level
        if m["power_ratio"] < opts.power_ratio:
            out.append(Reason("input_below_floor", {"rms": m["input_rms"],
                                                    "need_ratio": opts.power_ratio,
                                                    "floor": ax.floor}, names_uy))
    elif by_level and ratio < opts.power_ratio and not _commanded(m, opts):
        out.append(Reason("response_below_floor", {
            "rms": m["response_rms"], "need_ratio": opts.power_ratio,
            "floor": m["response_floor"], "input_ratio": m["power_ratio"]}, names_uy))
    cond = m.get("condition", math.inf)
    if not cond <= opts.max_condition:
        rho, share = m.get("correlation", math.nan), m.get("input_share", math.nan)
        cause = ("constant" if not math.isfinite(rho) else
                 "other_axis" if share < 0.5 else "feedback")
        out.append(Reason("ill_conditioned", {
            "condition": cond, "max_condition": opts.max_condition, "correlation": rho,
            "input_share_pct": 100 * share}, {**names_uy, "cause": cause}))
    if "injection_rms" in m:  # SYSTEMID: the output against the logged injection
        band = {"lo_hz": m["injection_lo_hz"], "hi_hz": m["injection_hi_hz"]}
        if m.get("injection_coverage", 0.0) < opts.min_coverage:
            out.append(Reason("injection_coverage", {
                "coverage_pct": 100 * m.get("injection_coverage", 0.0),
                "need_pct": 100 * opts.min_coverage, **band}, names_uy))
        if m.get("injection_coherence", 0.0) < opts.min_coherence:
            out.append(Reason("injection_coherence", {
                "coherence": m.get("injection_coherence", 0.0),
                "min_coherence": opts.min_coherence, **band}, names_uy))
        return out
    band = {"lo_hz": m.get("band_lo_hz", 0.0), "hi_hz": m.get("band_hi_hz", 0.0)}
    if m.get("coverage", 0.0) < opts.min_coverage and not _commanded(m, opts):
        out.append(Reason("coverage", {"coverage_pct": 100 * m.get("coverage", 0.0),
                                       "need_pct": 100 * opts.min_coverage, **band}))
    if m.get("coherence", 0.0) < opts.min_coherence:
        out.append(Reason("coherence", {"coherence": m.get("coherence", 0.0),
                                        "min_coherence": opts.min_coherence, **band},
                          names_uy))
    return out


def _rejected(reasons: Sequence[Reason]) -> tuple[str, ...]:
    """The reasons as the report's sentences (``rejected: ...``)."""
    return tuple(f"rejected: {r.message}" for r in reasons)


def _commanded(m: Mapping[str, float], opts: ScanOptions) -> bool:
    """Whether the window's response follows the pilot's command (see *command*)."""
    return (m.get("command_coherence", 0.0) >= opts.min_coherence
            and m.get("command_coverage", 0.0) >= opts.min_coverage)


def _kept_reason(ax: _Axis, m: Mapping[str, float]) -> str:
    if "response_ratio" in m and math.isfinite(m["response_ratio"]):
        level = (f"{ax.y_name} response RMS {format_number(m['response_rms'])} = "
                 f"{m['response_ratio']:.0f}× its noise floor")
    else:
        level = f"input RMS {format_number(m['input_rms'])} = {m['power_ratio']:.0f}× noise floor"
    if "injection_rms" in m:
        return (
            f"kept: {level}; injection (SIDD.Targ) RMS {format_number(m['injection_rms'])} over "
            f"{m['injection_lo_hz']:.3g}–{m['injection_hi_hz']:.3g} Hz, coherent with "
            f"{ax.y_name} over {100 * m.get('injection_coverage', 0):.0f} % of it (mean "
            f"{m.get('injection_coherence', 0):.2f}); Gram condition "
            f"{format_number(m.get('condition', math.inf))}"
        )
    if "command_coherence" in m:
        what = "yaw rate" if ax.name == "yaw" else "attitude"
        source = f" ({ax.command_from})" if ax.command_from else ""
        level += (f", coherent with the commanded {what}{source} over "
                  f"{100 * m['command_coverage']:.0f} % of the band (mean "
                  f"{m['command_coherence']:.2f})")
    return (
        f"kept: {level}; band coverage {100 * m.get('coverage', 0):.0f} %; "
        f"{ax.u_name}→{ax.y_name} coherence {m.get('coherence', 0):.2f}; Gram condition "
        f"{format_number(m.get('condition', math.inf))}"
    )


def _report(ax: _Axis, fd: FlightData, i0: int, i1: int, opts: ScanOptions, air: np.ndarray,
            source: str, run: SysidRun | None = None,
            stats: Mapping[str, Any] | None = None) -> WindowReport:
    band = None
    if run is not None and run.f_start_hz is not None and run.f_stop_hz is not None:
        band = (float(run.f_start_hz), float(run.f_stop_hz))
    st = _window_stats(ax, fd, air, opts, [i0], i1 - i0)[0] if stats is None else stats
    m = _metrics(ax, fd, i0, i1, opts, band, st)
    checks = tuple(_gates(ax, fd, i0, i1, m, opts, st, source == "scan"))
    kept = not checks
    return WindowReport(
        ax.name, float(fd.time_s[i0]), float(fd.time_s[i1 - 1]), _score(m), kept, source,
        (_kept_reason(ax, m),) if kept else _rejected(checks), i0, i1, m, checks, run,
    )


# --------------------------------------------------------------------------- sources


def _block_parts(fd: FlightData, t0: float, t1: float) -> list[tuple[int, int]]:
    """``[i0, i1)`` pieces of the time span ``[t0, t1]``, one per block it touches."""
    out = []
    for a, b in fd.blocks:
        i0 = int(np.searchsorted(fd.time_s[a:b], t0, side="left")) + a
        i1 = int(np.searchsorted(fd.time_s[a:b], t1, side="right")) + a
        if i1 - i0 >= 2:
            out.append((i0, i1))
    return out


def _sysid_windows(fd: FlightData, axes: Sequence[str], axes_cache: Mapping[str, _Axis],
                   opts: ScanOptions, air: np.ndarray) -> list[WindowReport]:
    out: list[WindowReport] = []
    for run in fd.sysid_runs:
        sid = run.sid_axis
        name, injection = sid_axis(sid)
        from_data: str | None = None
        notes: list[str] = []
        if run.settings_from == "PARAM_VALUE" and name in AXES:
            found = _excited_axis(fd, run, opts, air)
            if found is not None and found != name:
                notes.append(
                    f"SID_AXIS {sid} ({name}) comes from a parameter message sent before the "
                    f"run, but only the {found} input is excited: taken as a {found} run"
                )
                name = from_data = found
        if name not in AXES:
            if axes == AXES:  # only when every axis was asked for
                off = (Reason("not_attitude_axis", {"sid_axis": float(sid)},
                              {"axis": name, "injection": injection}),)
                for i0, i1 in _block_parts(fd, run.start_s, run.stop_s):
                    out.append(WindowReport(
                        name, float(fd.time_s[i0]), float(fd.time_s[i1 - 1]), float("nan"),
                        False, "sysid", _rejected(off), i0, i1, {}, off, run, from_data))
            continue
        if name not in axes:
            continue
        nan = float("nan")
        for i0, i1 in _block_parts(fd, run.start_s, run.stop_s):
            rep = replace(_report(axes_cache[name], fd, i0, i1, opts, air, "sysid", run),
                          axis_from_data=from_data)
            mag = nan if run.magnitude is None else run.magnitude
            note = (f"SYSTEMID {injection} {name} chirp, SID_AXIS {sid}, magnitude {mag:g}, "
                    f"{nan if run.f_start_hz is None else run.f_start_hz:g}–"
                    f"{nan if run.f_stop_hz is None else run.f_stop_hz:g} Hz")
            if injection in SID_IDENTIFIES:
                note += f": identifies {SID_IDENTIFIES[injection]}"
            out.append(replace(rep, reasons=(*rep.reasons, note, *notes)))
    return out


def _excited_axis(fd: FlightData, run: SysidRun, opts: ScanOptions,
                  air: np.ndarray) -> str | None:
    """The one attitude axis whose input passes the power gate during a run, if exactly one."""
    parts = _block_parts(fd, run.start_s, run.stop_s)
    excited = []
    for a in AXES:
        ax = _axis(fd, a, opts, air)
        if ax.u_hp is None or not parts:
            continue
        rms = math.sqrt(sum(float(np.sum(ax.u_hp[i0:i1] ** 2)) for i0, i1 in parts)
                        / sum(i1 - i0 for i0, i1 in parts))
        if rms >= opts.power_ratio * ax.floor:
            excited.append(a)
    return excited[0] if len(excited) == 1 else None


def _trim(ax: _Axis, fd: FlightData, i0: int, i1: int, opts: ScanOptions) -> tuple[int, int]:
    """Drop the quiet head and tail of a merged window.

    An end is trimmed only when its first (last) 0.5 s is quiet (input RMS below the power
    gate, ``power_ratio`` × noise floor); the trimmed end is where the input, smoothed over
    50 ms, first departs from its median over that quiet 0.5 s by more than the gate.
    """
    assert ax.u is not None and ax.u_hp is not None
    n = max(3, round(0.5 / fd.dt))
    if i1 - i0 < 3 * n:
        return i0, i1
    u, hp = ax.u[i0:i1], ax.u_hp[i0:i1]
    k = max(1, round(0.05 / fd.dt))
    thr = opts.power_ratio * ax.floor
    a, b = 0, u.size
    if np.sqrt(np.mean(hp[:n] ** 2)) < thr:
        head = _moving(np.abs(u - np.median(u[:n])), k) > thr
        a = int(np.argmax(head)) if head.any() else 0
    if np.sqrt(np.mean(hp[-n:] ** 2)) < thr:
        tail = _moving(np.abs(u - np.median(u[-n:])), k) > thr
        b = u.size - int(np.argmax(tail[::-1])) if tail.any() else u.size
    return (i0 + a, i0 + b) if b - a >= n else (i0, i1)


#: windows measured in one call of :func:`_window_stats` (bounds the transforms kept: ~4 MB)
_BATCH = 64


def _scan_windows(fd: FlightData, ax: _Axis, opts: ScanOptions, air: np.ndarray,
                  exclude: Sequence[tuple[int, int]]) -> list[WindowReport]:
    win = max(8, round(opts.window_s / fd.dt))
    step = max(1, round(opts.step / fd.dt))
    reports: list[WindowReport] = []
    for a, b in fd.blocks:
        a, b = int(a), int(b)
        if b - a < win:
            starts = [a] if b - a >= 8 else []
        else:
            starts = list(range(a, b - win + 1, step))
            if starts[-1] + win < b:
                starts.append(b - win)
        starts = [s for s in starts if not any(s < x1 and x0 < min(b, s + win)
                                               for x0, x1 in exclude)]
        if b - a < win:  # one window, shorter
            reports += [_report(ax, fd, s, b, opts, air, "scan") for s in starts]
            continue
        for k in range(0, len(starts), _BATCH):
            batch = starts[k : k + _BATCH]
            for s, st in zip(batch, _window_stats(ax, fd, air, opts, batch, win), strict=True):
                reports.append(_report(ax, fd, s, s + win, opts, air, "scan", None, st))
    return _merge(fd, ax, reports, opts, air)


def _merge(fd: FlightData, ax: _Axis, reports: list[WindowReport], opts: ScanOptions,
           air: np.ndarray) -> list[WindowReport]:
    """Merge runs of overlapping kept windows (within one block) and trim their quiet ends."""
    out: list[WindowReport] = []
    run: list[WindowReport] = []

    def flush() -> None:
        if not run:
            return
        i0, i1 = run[0].i0, max(r.i1 for r in run)
        j0, j1 = _trim(ax, fd, i0, i1, opts)
        merged = replace(_report(ax, fd, j0, j1, opts, air, "scan"), merged_windows=len(run))
        if merged.kept:
            out.append(replace(merged, reasons=(
                *merged.reasons,
                f"merged from {len(run)} overlapping {opts.window_s:g}-s windows"
                + (f", quiet ends trimmed ({fd.time_s[i0]:.2f}–{fd.time_s[i1 - 1]:.2f} s before)"
                   if (j0, j1) != (i0, i1) else ""),
            )))
        else:  # the whole fails where its parts passed: keep the parts as they were
            out.extend(run)
        run.clear()

    block_of = np.searchsorted(fd.blocks[:, 1], [r.i0 for r in reports], side="right")
    for r, blk in zip(reports, block_of, strict=True):
        if r.kept and run and r.i0 <= run[-1].i1 and blk == np.searchsorted(
                fd.blocks[:, 1], run[-1].i0, side="right"):
            run.append(r)
            continue
        flush()
        if r.kept:
            run.append(r)
        else:
            out.append(r)
    flush()
    return out


# --------------------------------------------------------------------------- public


def find_segments(
    flight: FlightData,
    axis: str | Sequence[str] | None = None,
    *,
    scan: bool | None = None,
    options: ScanOptions | None = None,
) -> list[WindowReport]:
    """Every window considered, kept or rejected, with reasons.

    Parameters
    ----------
    flight : FlightData
    axis : str or sequence of str, optional
        ``"roll"``, ``"pitch"``, ``"yaw"``; default all three.
    scan : bool, optional
        Scan sliding windows: default only for axes without a SYSTEMID run; True for all
        axes (outside their SYSTEMID runs), False never.
    options : ScanOptions, optional

    Returns
    -------
    list of WindowReport
        Sorted by axis (roll, pitch, yaw, then others), then start time.

    Raises
    ------
    ConfigError
        Unknown axis.
    """
    opts = options or ScanOptions()
    axes = AXES if axis is None else ((axis,) if isinstance(axis, str) else tuple(axis))
    for a in axes:
        if a not in AXES:
            raise ConfigError(f"unknown axis {a!r} (choose from {', '.join(AXES)})")
    air = _airborne(flight)
    cache = {a: _axis(flight, a, opts, air) for a in axes}
    reports = _sysid_windows(flight, axes, cache, opts, air)
    for a in axes:
        mine = [(r.i0, r.i1) for r in reports if r.axis == a and r.source == "sysid"]
        if scan is False or (scan is None and mine):
            continue
        if cache[a].u is None or cache[a].y is None:
            n = flight.time_s.size
            missing = tuple(_gates(cache[a], flight, 0, n, {}, opts, {}, False, False))
            reports.append(WindowReport(a, float(flight.time_s[0]), float(flight.time_s[-1]),
                                        0.0, False, "scan", _rejected(missing), 0, n, {},
                                        missing))
            continue
        found = _scan_windows(flight, cache[a], opts, air, mine)
        if not found and not mine:
            n = flight.time_s.size
            longest = int(np.max(flight.blocks[:, 1] - flight.blocks[:, 0]))
            little = (Reason("too_little_data", {"samples": float(longest),
                                                 "seconds": longest * flight.dt,
                                                 "need_samples": 8.0}),)
            found = [WindowReport(
                a, float(flight.time_s[0]), float(flight.time_s[-1]), 0.0, False, "scan",
                _rejected(little), 0, n, {}, little)]
        reports += found
    order = {a: i for i, a in enumerate(AXES)}
    reports.sort(key=lambda r: (order.get(r.axis, len(AXES)), r.start_s))
    return reports


def select_segments(
    flight: FlightData,
    axis: str | Sequence[str] | None = None,
    reports: Sequence[WindowReport] | None = None,
    **kwargs: Any,
) -> list[Segment]:
    """The kept windows as :class:`~mavsid.data.Segment` objects for the estimators.

    Each segment carries every state and input column of the flight, the log's parameters
    (``params``) and, for SYSTEMID runs, the run (``sysid``); ``meta`` the preset and the
    window's metrics.

    Parameters
    ----------
    reports : sequence of WindowReport, optional
        From :func:`find_segments` (computed when omitted, with ``axis`` and ``kwargs``).
    """
    reps = find_segments(flight, axis, **kwargs) if reports is None else reports
    out = []
    for r in reps:
        if not r.kept:
            continue
        meta = {"preset": flight.preset, "metrics": dict(r.metrics)}
        out.append(Segment(
            time_s=flight.time_s[r.i0:r.i1].copy(),
            states=flight.states[r.i0:r.i1].copy(),
            inputs=flight.inputs[r.i0:r.i1].copy(),
            state_names=flight.state_names,
            input_names=flight.input_names,
            dt=flight.dt,
            axis=r.axis,
            source=r.source,
            score=r.score,
            log=flight.source.path,
            reasons=r.reasons,
            meta=meta,
            params=dict(flight.params),
            sysid=r.sysid,
        ))
    return out


def format_reports(reports: Sequence[WindowReport], show_all: bool = False) -> str:
    """Human-readable table: SYSTEMID and kept windows in full, rejected scan windows
    grouped by the kind of their first failed gate (every window with ``show_all``).

    Examples
    --------
    >>> gate = Reason("input_below_floor", {"rms": 2e-4, "need_ratio": 5.0, "floor": 1e-3},
    ...               {"input": "u_roll"})
    >>> r = WindowReport("roll", 1.0, 6.0, 0.1, False, "scan", ("rejected: " + gate.message,),
    ...                  0, 9, checks=(gate,))
    >>> print(format_reports([r]))
    axis    start_s   stop_s  score  kept  source  reasons
    roll: 1 scan window(s) rejected: 1× input RMS below noise floor
    """
    lines = [f"{'axis':6s} {'start_s':>8s} {'stop_s':>8s} {'score':>6s}  kept  source  reasons"]
    hidden: dict[str, list[WindowReport]] = {}
    for r in reports:
        if r.kept or r.source == "sysid" or show_all or not r.checks:
            score = f"{r.score:6.2f}" if math.isfinite(r.score) else "     -"
            lines.append(
                f"{r.axis:6s} {r.start_s:8.2f} {r.stop_s:8.2f} {score}  "
                f"{'yes' if r.kept else 'no':4s}  {r.source:6s}  {r.reasons[0]}"
            )
            lines += [f"{'':47s}{x}" for x in r.reasons[1:]]
        else:
            hidden.setdefault(r.axis, []).append(r)
    for axis, rejected in hidden.items():
        detail = ", ".join(group([r.checks[0] for r in rejected]))
        lines.append(f"{axis}: {len(rejected)} scan window(s) rejected: {detail}")
    return "\n".join(lines)
