"""What a fitted (or unfitted) axis is worth: a verdict per axis with the numbers behind it.

Every axis a user asks for gets a :class:`Verdict`, whether a model was fitted or not:

- ``good``: the model can be trusted for what mavsid offers (simulation, tuning);
- ``usable``: it can serve some purposes (``usable_for`` says which), with the ``reasons``
  it is not better;
- ``not identified``: no model, or one that must not be used; ``reasons`` say why and
  ``advice`` what to change next flight (logging rate, excitation ...).

Examples
--------
>>> v = not_identified("pitch", "no window kept (input RMS below the noise floor)",
...                    advice=("fly a SYSTEMID run on pitch (SID_AXIS 11)",))
>>> v.line()
'pitch: not identified: no window kept (input RMS below the noise floor)'
>>> v.to_dict()["level"], v.identified
('not identified', False)
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

__all__ = ["LEVELS", "Verdict", "not_identified"]

#: The verdict levels, best first.
LEVELS = ("good", "usable", "not identified")


@dataclass(frozen=True)
class Verdict:
    """The verdict on one axis.

    Parameters
    ----------
    axis : str
        ``roll``, ``pitch`` or ``yaw``.
    level : str
        One of :data:`LEVELS`.
    reasons : tuple of str
        Why the level is not better (for ``good``: what supports it), one short clause each.
    usable_for : tuple of str
        For ``usable``: what the model can serve (e.g. ``"closed-loop simulation"``).
    numbers : Mapping[str, float or None]
        The evidence, by name (e.g. ``fit_free_run_pct``, ``log_rate_hz``), in the units its
        name says.
    advice : tuple of str
        What to change next flight to do better.
    """

    axis: str
    level: str
    reasons: tuple[str, ...] = ()
    usable_for: tuple[str, ...] = ()
    numbers: Mapping[str, float | None] = field(default_factory=dict)
    advice: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.level not in LEVELS:
            raise ValueError(f"verdict level {self.level!r} is not one of {', '.join(LEVELS)}")

    @property
    def identified(self) -> bool:
        """True for ``good`` and ``usable``."""
        return self.level != "not identified"

    def line(self) -> str:
        """One line for the terminal: ``axis: level[ (for ...)]: reasons``."""
        text = f"{self.axis}: {self.level}"
        if self.usable_for:
            text += f" (for {', '.join(self.usable_for)})"
        if self.reasons:
            text += ": " + "; ".join(self.reasons)
        return text

    def to_dict(self) -> dict[str, Any]:
        """The JSON form (non-finite numbers become ``None``)."""
        return {
            "axis": self.axis,
            "level": self.level,
            "reasons": list(self.reasons),
            "usable_for": list(self.usable_for),
            "numbers": {
                k: (None if v is None or not math.isfinite(float(v)) else float(v))
                for k, v in self.numbers.items()
            },
            "advice": list(self.advice),
        }


def not_identified(axis: str, reason: str, advice: tuple[str, ...] = (),
                   **numbers: float | None) -> Verdict:
    """A ``not identified`` verdict with one reason."""
    return Verdict(axis, "not identified", (reason,), (), numbers, advice)


def judge(axis: str, validation: Any, output: str) -> Verdict:
    """A first verdict from a model's validation on held-out data (stability, free run).

    Parameters
    ----------
    axis : str
    validation : mavsid.validation.Validation
    output : str
        The state that represents the axis (its body rate).
    """
    j = validation.state_names.index(output)
    free = float(validation.fit_free_run[j])
    one = float(validation.fit_one_step[j])
    numbers = {"fit_one_step_pct": one, "fit_free_run_pct": free}
    if validation.stable is False:
        worst = max(abs(complex(z)) for z in validation.eigenvalues)
        return Verdict(axis, "not identified",
                       (f"identified dynamics are unstable (|eigenvalue| {worst:.4g} > 1)",),
                       numbers=numbers)
    if not math.isfinite(free) or free < 0:
        return Verdict(axis, "not identified",
                       ("free run on held-out data diverges (fit below 0 %)",), numbers=numbers)
    if free >= 80:
        return Verdict(axis, "good", (f"free run {free:.1f} % on held-out data",),
                       numbers=numbers)
    return Verdict(axis, "usable", (f"free run only {free:.1f} % on held-out data",),
                   ("one-step prediction",), numbers)
