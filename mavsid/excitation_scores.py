"""How well a window of a flight excites one axis: its signals, measures and score.

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
the coherence and ``1 - log10(condition)/2`` (each clipped to 0..1).

The gates on these measures, and the reasons a window is rejected for, are
:mod:`mavsid.excitation_gates`; cutting the flight into windows, :mod:`mavsid.excitation`.

Examples
--------
>>> score({"power_ratio": 100.0, "coverage": 1.0, "coherence": 1.0, "condition": 1.0})
1.0
>>> ScanOptions(window_s=4.0).step
2.0
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from mavsid.axes import AXES, RATE_OF
from mavsid.data import FlightData, detrend_linear
from mavsid.errors import ConfigError, finite_number
from mavsid.numerics.spectra import density, segment_ffts

__all__ = ["AxisSignals", "ScanOptions", "airborne", "axis_signals", "metrics", "moving_mean",
           "score", "window_stats"]


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
class AxisSignals:
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
    injection: np.ndarray | None = None  # SYSTEMID's logged waveform (SIDD.Targ), NaN unlogged
    command: np.ndarray | None = None  # commanded attitude (rad; yaw: rate), NaN if not logged
    command_from: str = ""  # where the command came from (``ATT.DesRoll``, the sticks ...)
    # the collective thrust, where it was really logged (a constant column was not): judged
    # once per flight, not per window (a 27-min flight has ~600 windows an axis)
    thrust: np.ndarray | None = None


def moving_mean(x: np.ndarray, n: int) -> np.ndarray:
    """Centred moving average over ``n`` samples (same length; the first ``n // 2`` take the
    first ``n``, the last ones what is left after their window's start).

    >>> moving_mean(np.array([1.0, 2.0, 3.0, 4.0, 5.0]), 3).tolist()
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


def airborne(fd: FlightData) -> np.ndarray:
    n = fd.time_s.size
    air = np.asarray(fd.flags.get("airborne", np.ones(n, bool)), dtype=bool)
    armed = np.asarray(fd.flags.get("armed", np.ones(n, bool)), dtype=bool)
    return air & armed


def axis_signals(fd: FlightData, name: str, opts: ScanOptions, air: np.ndarray) -> AxisSignals:
    u_name = f"u_{name}"
    u = fd.series(u_name)
    y_name = RATE_OF[name] if RATE_OF[name] in fd.state_names else name
    y = fd.series(y_name)
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
    thrust = fd.series("u_thrust")
    if thrust is not None and not np.ptp(thrust) > 1e-6:
        thrust = None
    return AxisSignals(name, u, u_hp, y, y_name, u_name, floor, y_hp, y_floor, injection, command,
                 str(source), thrust)


def _highpass(fd: FlightData, x: np.ndarray, opts: ScanOptions) -> np.ndarray:
    """``x`` less its moving average over one period of the band's low edge (per block)."""
    n_lo = max(3, round(1.0 / (opts.band_hz[0] * fd.dt)))
    out = np.zeros_like(x)
    for a, b in fd.blocks:
        out[a:b] = x[a:b] - moving_mean(x[a:b], n_lo)
    return out


def _envelope(fd: FlightData, x_hp: np.ndarray) -> np.ndarray:
    """1-s moving RMS of ``x_hp`` (per block)."""
    n1 = max(3, round(1.0 / fd.dt))
    out = np.zeros_like(x_hp)
    for a, b in fd.blocks:
        out[a:b] = np.sqrt(np.clip(moving_mean(x_hp[a:b] ** 2, n1), 0, None))
    return out


def metrics(ax: AxisSignals, fd: FlightData, i0: int, i1: int, opts: ScanOptions,
             band: tuple[float, float] | None, st: Mapping[str, Any]) -> dict[str, float]:
    """Excitation metrics of samples ``[i0, i1)`` for one axis (``band``: a SYSTEMID run's;
    ``st``: the window's :func:`window_stats`)."""
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


def window_stats(ax: AxisSignals, fd: FlightData, air: np.ndarray, opts: ScanOptions,
                  starts: Sequence[int], win: int) -> list[dict[str, Any]]:
    """What :func:`metrics` and :func:`gates` measure of windows of ``win`` samples at
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
    att = [c for c in (fd.series(f"u_{a}") for a in AXES) if c is not None]
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


def _gate_stats(ax: AxisSignals, fd: FlightData, air: np.ndarray, opts: ScanOptions,
                rows: np.ndarray) -> dict[str, np.ndarray]:
    """:func:`window_stats`' measures for the gates, of the windows of sample indices
    ``rows`` (windows, samples)."""
    on = air[rows]
    got: dict[str, np.ndarray] = {"airborne": on.mean(axis=1)}
    mode = fd.flags.get("mode")
    if mode is not None and rows.shape[1] > 1:
        change = np.diff(np.asarray(mode)[rows], axis=1) != 0
        got["mode_change"] = np.where(change.any(axis=1), change.argmax(axis=1), -1)
    for ang in ("roll", "pitch"):
        a = fd.series(ang)
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
    the window's spectra (:func:`window_stats`)."""
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


def _metrics_raw(ax: AxisSignals, fd: FlightData, i0: int, i1: int, opts: ScanOptions,
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


def score(m: Mapping[str, float]) -> float:
    if "power_ratio" not in m:
        return 0.0
    ratio = m.get("response_ratio", m["power_ratio"])
    inj = "injection_rms" in m
    # a response that follows the pilot's command: its coherence and coverage with the
    # command stand for its level and the input's coverage (measured against floors that
    # a flight without a quiet stretch does not show, see mavsid.excitation_gates)
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
