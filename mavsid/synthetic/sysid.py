"""Excitation: ArduPilot SYSTEMID chirps and pilot manoeuvres.

The SYSTEMID waveform follows the semantics of ArduCopter's SYSTEMID mode (mode 25) as logged
in its SIDS/SIDD messages:

- the waveform clock ``Time`` (SIDD.Time) starts at 0 on entering the mode and advances one
  loop period per loop; the chirp itself is evaluated at ``tau = Time - 1 s`` (the mode waits
  one second before injecting);
- ``SID_T_REC`` is the length of the waveform; the first ``TC = 2 / SID_F_START_HZ`` seconds
  are two cycles at the start frequency (phase chosen so that the sine is continuous into the
  sweep), then the frequency rises exponentially from ``SID_F_START_HZ`` at ``tau = TC`` to
  ``SID_F_STOP_HZ`` at ``tau = SID_T_REC``:
  ``w(tau) = w0 * exp(B * (tau - TC) / (T_REC - TC))`` with ``B = ln(w1 / w0)``, and the phase
  is its integral ``w0 * (T_REC - TC) / B * (exp(B * (tau - TC) / (T_REC - TC)) - 1)``;
- the amplitude ``SID_MAGNITUDE`` is shaped by a raised-cosine fade-in over ``SID_T_FADE_IN``
  and fade-out over the last ``SID_T_FADE_OUT`` seconds of ``SID_T_REC``;
- the mode ends ("SystemID Finished") when ``Time > 1 + T_FADE_IN + TC + T_REC + T_FADE_OUT``;
  after ``SID_T_REC`` the output is zero and SIDD.F reads the stop frequency.

These facts were checked against the SIDD records of a real ArduCopter 4.7 SITL flight
(``tests/test_synthetic.py`` compares the waveform sample by sample).

Examples
--------
>>> s = SysIdSettings(axis=10, magnitude=0.05, f_start_hz=0.5, f_stop_hz=20.0,
...                   t_fade_in=5.0, t_rec=60.0, t_fade_out=2.0)
>>> s.t_const_freq, s.duration
(4.0, 72.0)
>>> targ, f = chirp(np.array([0.5, 4.5, 5.0, 33.0, 62.0]), s)
>>> np.abs(targ).round(4).tolist(), f.round(3).tolist()
([0.0, 0.0397, 0.0, 0.0253, 0.0], [0.5, 0.5, 0.5, 3.162, 20.0])
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mavsid.errors import ConfigError

__all__ = [
    "MANOEUVRES",
    "SID_AXES",
    "SYSTEM_ID_DELAY_S",
    "SysIdSettings",
    "chirp",
    "pilot_sticks",
]

#: seconds SYSTEMID waits after the mode change before the waveform starts
SYSTEM_ID_DELAY_S = 1.0

#: SID_AXIS value -> (injection point, axis)
SID_AXES: dict[int, tuple[str, str]] = {
    1: ("input_angle", "roll"),
    2: ("input_angle", "pitch"),
    3: ("input_angle", "yaw"),
    4: ("recovery_angle", "roll"),
    5: ("recovery_angle", "pitch"),
    6: ("recovery_angle", "yaw"),
    7: ("rate", "roll"),
    8: ("rate", "pitch"),
    9: ("rate", "yaw"),
    10: ("mixer", "roll"),
    11: ("mixer", "pitch"),
    12: ("mixer", "yaw"),
    13: ("mixer", "thrust"),
}

#: pilot manoeuvres understood by :func:`pilot_sticks` (besides ``"sysid"``)
MANOEUVRES = ("doublet", "3211", "random", "hover")


@dataclass(frozen=True)
class SysIdSettings:
    """The ``SID_*`` parameters of one SYSTEMID run.

    Parameters
    ----------
    axis : int
        ``SID_AXIS`` 1-13 (see :data:`SID_AXES`).
    magnitude : float
        ``SID_MAGNITUDE``: deg for angle axes, deg/s for rate axes, 0-1 for mixer axes.
    f_start_hz, f_stop_hz : float
        ``SID_F_START_HZ``, ``SID_F_STOP_HZ`` (Hz).
    t_fade_in, t_rec, t_fade_out : float
        ``SID_T_FADE_IN``, ``SID_T_REC``, ``SID_T_FADE_OUT`` (s).
    """

    axis: int = 10
    magnitude: float = 0.05
    f_start_hz: float = 0.5
    f_stop_hz: float = 15.0
    t_fade_in: float = 2.0
    t_rec: float = 20.0
    t_fade_out: float = 1.0

    def __post_init__(self) -> None:
        if self.axis not in SID_AXES:
            raise ConfigError(f"SID_AXIS must be 1-13, got {self.axis}")
        if not np.isfinite(self.magnitude):
            raise ConfigError(f"SID_MAGNITUDE must be finite, got {self.magnitude}")
        if not (self.f_start_hz > 0 and self.f_stop_hz > 0):
            raise ConfigError("SID_F_START_HZ and SID_F_STOP_HZ must be positive")
        if not (self.t_fade_in >= 0 and self.t_fade_out >= 0):
            raise ConfigError("SID_T_FADE_IN and SID_T_FADE_OUT must not be negative")
        if not self.t_rec > self.t_const_freq:
            raise ConfigError(
                f"SID_T_REC ({self.t_rec} s) must exceed two cycles at SID_F_START_HZ "
                f"({self.t_const_freq:g} s)"
            )

    @property
    def t_const_freq(self) -> float:
        """Time at the start frequency (s): two full cycles (SIDS.TC)."""
        return 2.0 / self.f_start_hz

    @property
    def duration(self) -> float:
        """Waveform clock value at which the mode reports "SystemID Finished" (s)."""
        return (
            SYSTEM_ID_DELAY_S + self.t_fade_in + self.t_const_freq + self.t_rec + self.t_fade_out
        )

    @property
    def injection(self) -> str:
        """``"input_angle"``, ``"recovery_angle"``, ``"rate"`` or ``"mixer"``."""
        return SID_AXES[self.axis][0]

    @property
    def target_axis(self) -> str:
        """``"roll"``, ``"pitch"``, ``"yaw"`` or ``"thrust"``."""
        return SID_AXES[self.axis][1]

    def params(self) -> dict[str, float]:
        """The settings as ArduPilot parameters."""
        return {
            "SID_AXIS": float(self.axis),
            "SID_MAGNITUDE": self.magnitude,
            "SID_F_START_HZ": self.f_start_hz,
            "SID_F_STOP_HZ": self.f_stop_hz,
            "SID_T_FADE_IN": self.t_fade_in,
            "SID_T_REC": self.t_rec,
            "SID_T_FADE_OUT": self.t_fade_out,
        }


def chirp(time_s: np.ndarray, s: SysIdSettings) -> tuple[np.ndarray, np.ndarray]:
    """SYSTEMID waveform and its frequency at waveform-clock times (SIDD.Time).

    Parameters
    ----------
    time_s : numpy.ndarray
        Waveform clock (s since entering SYSTEMID).
    s : SysIdSettings

    Returns
    -------
    targ : numpy.ndarray
        The injected signal (SIDD.Targ), in the units of ``s.magnitude``.
    freq_hz : numpy.ndarray
        Its instantaneous frequency (SIDD.F, Hz).
    """
    tau = np.asarray(time_s, dtype=float) - SYSTEM_ID_DELAY_S
    w0, w1 = 2 * np.pi * s.f_start_hz, 2 * np.pi * s.f_stop_hz
    tc, rec = s.t_const_freq, s.t_rec
    fade_out_start = rec - s.t_fade_out
    window = np.select(
        [tau <= 0, tau <= s.t_fade_in, tau <= fade_out_start, tau <= rec],
        [
            0.0,
            0.5 - 0.5 * np.cos(np.pi * tau / max(s.t_fade_in, 1e-12)),
            1.0,
            0.5 + 0.5 * np.cos(np.pi * (tau - fade_out_start) / max(s.t_fade_out, 1e-12)),
        ],
        0.0,
    )
    sweep = np.clip((tau - tc) / (rec - tc), 0.0, 1.0)
    if np.isclose(w0, w1):
        b, freq = 0.0, np.full_like(tau, w0)
        phase_sweep = w0 * (tau - tc)
    else:
        b = float(np.log(w1 / w0))
        freq = w0 * np.exp(b * sweep)
        phase_sweep = w0 * (rec - tc) / b * (np.exp(b * sweep) - 1.0)
    phase = np.where(tau <= tc, w0 * (tau - tc), phase_sweep)
    active = (tau > 0) & (tau <= rec)
    targ = np.where(active, window * s.magnitude * np.sin(phase), 0.0)
    freq = np.where(tau <= 0, w0, np.where(tau > rec, w1, freq))
    return targ, freq / (2 * np.pi)


def pilot_sticks(
    manoeuvre: str, n: int, dt: float, rng: np.random.Generator, amplitude: float = 0.3,
    start_s: float = 2.0, period_s: float = 0.5,
) -> np.ndarray:
    """Normalised stick deflection (-1..1) for one axis, one value per loop sample.

    Parameters
    ----------
    manoeuvre : str
        ``"doublet"`` (+A, -A, each ``period_s``, then rest, repeated every 4 s), ``"3211"``
        (+A 3T, -A 2T, +A T, -A T, repeated every 8 T + 2 s), ``"random"`` (band-limited noise,
        ~2 Hz, std A / 2) or ``"hover"`` (sticks centred).
    n : int
        Number of samples; ``dt`` the loop period (s).
    rng : numpy.random.Generator
        Used by ``"random"`` only.
    amplitude : float
        Stick deflection A (fraction of full stick).
    start_s : float
        Sticks stay centred until then.

    Examples
    --------
    >>> x = pilot_sticks("doublet", 2000, 0.0025, np.random.default_rng(0), start_s=0.0)
    >>> float(x[0]), float(x[300]), float(x[600])
    (0.3, -0.3, 0.0)
    """
    t = np.arange(n) * dt - start_s
    out = np.zeros(n)
    if manoeuvre == "hover":
        return out
    if manoeuvre == "doublet":
        cycle = 4.0
        tm = np.mod(t, cycle)
        out = np.where(tm < period_s, amplitude, np.where(tm < 2 * period_s, -amplitude, 0.0))
    elif manoeuvre == "3211":
        unit = period_s
        tm = np.mod(t, 7 * unit + 2.0) / unit
        levels = np.select(
            [tm < 3, tm < 5, tm < 6, tm < 7], [amplitude, -amplitude, amplitude, -amplitude], 0.0
        )
        out = levels
    elif manoeuvre == "random":
        # white noise through a 2nd-order low pass at ~2 Hz, scaled to std amplitude/2
        w = rng.standard_normal(n)
        wn, zeta = 2 * np.pi * 2.0, 0.7
        x = v = 0.0
        y = np.empty(n)
        for i in range(n):
            a = wn * wn * (w[i] - x) - 2 * zeta * wn * v
            v += a * dt
            x += v * dt
            y[i] = x
        std = float(np.std(y)) or 1.0
        out = np.clip(y / std * amplitude / 2, -1.0, 1.0)
    else:
        raise ConfigError(
            f"unknown manoeuvre {manoeuvre!r} (choose from sysid, {', '.join(MANOEUVRES)})"
        )
    return np.where(t < 0, 0.0, out)
