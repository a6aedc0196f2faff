"""Whether a log's rate target already carries the SYSTEMID rate injection (``SID_AXIS`` 7-9).

The waveform is added to the rate target inside the rate controller; whether the logged
target (``RATE.RDes``...) holds the sum depends on the firmware. The log says it itself: over
a run, the logged target regressed on the waveform, both high-passed (the slow part is the
attitude controller's, and its answer to the injected rate is in quadrature with the
waveform), gives a coefficient near 1 when the target holds the waveform and near 0 when it
does not. Only between the two does the firmware version decide
(:func:`mavsid.autopilot.ardupilot.rate_target_logs_injection`).

Examples
--------
>>> import numpy as np
>>> dt = 0.0025
>>> t = np.arange(0.0, 20.0, dt)
>>> inj = 0.3 * np.sin(2 * np.pi * (0.5 + 0.4 * t) * t)   # a chirp, rad/s
>>> slow = 0.2 * np.sin(2 * np.pi * 0.2 * t)              # the attitude controller's part
>>> spans = [(0, t.size)]
>>> with_it = injection_in_target(slow + inj, inj, spans, dt, None)
>>> with_it.included, with_it.decided_by, round(with_it.coefficient, 2)
(True, 'data', 1.0)
>>> without = injection_in_target(slow, inj, spans, dt, None)
>>> without.included, without.decided_by, round(without.coefficient, 2)
(False, 'data', 0.0)
>>> half = injection_in_target(slow + 0.5 * inj, inj, spans, dt, "ArduCopter V4.6.2")
>>> half.included, half.decided_by
(True, 'firmware')
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["DECIDES", "HIGH_PASS_HZ", "InjectionInTarget", "injection_coefficient",
           "injection_in_target"]

#: a coefficient this close to 1 says included, this close to 0 says left out
DECIDES = 0.25
#: corner (Hz) of the high-pass both signals go through (lower when the chirp stops lower)
HIGH_PASS_HZ = 1.5


@dataclass(frozen=True)
class InjectionInTarget:
    """Whether one axis's logged rate target carries its rate injection.

    Attributes
    ----------
    included : bool
        The logged target holds the waveform (it is not added again).
    coefficient : float or None
        The high-passed logged target regressed on the high-passed waveform; None when the
        runs were too short or held no waveform.
    decided_by : str
        ``data`` (the coefficient), ``firmware`` (its version, the coefficient undecided) or
        ``assumed`` (neither said: taken as left out).
    """

    included: bool
    coefficient: float | None
    decided_by: str

    def to_dict(self) -> dict[str, object]:
        """JSON form."""
        return {"included": self.included, "coefficient": self.coefficient,
                "decided_by": self.decided_by}


def injection_coefficient(target: np.ndarray, injection: np.ndarray,
                          spans: Sequence[tuple[int, int]], dt: float,
                          f_stop_hz: float | None = None) -> float | None:
    """Least-squares coefficient of ``injection`` in ``target`` over ``spans`` (sample index
    ranges), both high-passed above :data:`HIGH_PASS_HZ` (half ``f_stop_hz`` when lower);
    None when no span is long and finite enough or the waveform is zero there."""
    from scipy.signal import butter, sosfiltfilt

    corner = HIGH_PASS_HZ if not f_stop_hz else min(HIGH_PASS_HZ, 0.5 * f_stop_hz)
    if not 0.0 < corner < 0.45 / dt:
        return None
    sos = butter(2, corner, "highpass", fs=1.0 / dt, output="sos")
    cross = power = 0.0
    for i0, i1 in spans:
        y, x = np.asarray(target[i0:i1], float), np.asarray(injection[i0:i1], float)
        if (i1 - i0) * dt < 4.0 / corner or not (np.isfinite(y).all() and np.isfinite(x).all()):
            continue
        yh, xh = sosfiltfilt(sos, y - y.mean()), sosfiltfilt(sos, x - x.mean())
        cross += float(yh @ xh)
        power += float(xh @ xh)
    return cross / power if power > 0.0 else None


def injection_in_target(target: np.ndarray, injection: np.ndarray,
                        spans: Sequence[tuple[int, int]], dt: float, firmware: str | None,
                        f_stop_hz: float | None = None) -> InjectionInTarget:
    """The decision for one axis: by :func:`injection_coefficient` when it is within
    :data:`DECIDES` of 1 or 0, else by the firmware version, else taken as left out."""
    from mavsid.autopilot.ardupilot import rate_target_logs_injection

    c = injection_coefficient(target, injection, spans, dt, f_stop_hz)
    if c is not None and abs(c - 1.0) <= DECIDES:
        return InjectionInTarget(True, c, "data")
    if c is not None and abs(c) <= DECIDES:
        return InjectionInTarget(False, c, "data")
    rule = rate_target_logs_injection(firmware)
    if rule is not None:
        return InjectionInTarget(rule, c, "firmware")
    return InjectionInTarget(False, c, "assumed")
