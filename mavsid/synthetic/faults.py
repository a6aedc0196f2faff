"""Faults the writers can inject, for robustness tests of the readers.

Examples
--------
>>> f = Faults.parse("drop=0.01,reboot=12.5,truncate=100")
>>> f.drop_fraction, f.reboot_at_s, f.truncate_bytes
(0.01, 12.5, 100)
>>> Faults.parse("gap=20:300").gap
(20.0, 300.0)
>>> Faults.parse("").any
False
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from mavsid.errors import ConfigError

__all__ = ["Faults"]


@dataclass(frozen=True)
class Faults:
    """Damage to apply when writing a log.

    Parameters
    ----------
    drop_fraction : float
        Fraction of data records (not format/parameter records) removed at random.
    reboot_at_s : float, optional
        Seconds after the log's first sample at which the vehicle clock restarts (a reboot:
        the log continues with time since the new boot, headers written again).
    truncate_bytes : int
        Bytes cut from the end of the file (the last record is left incomplete).
    seed : int
        Seeds the choice of dropped records.
    gap : (float, float), optional
        ``(at_s, length_s)``: logging stops ``at_s`` seconds after the log's first sample and
        resumes ``length_s`` seconds later on the same clock, the flight going on where it
        was (a log kept across a disarmed spell: ``LOG_DISARMED`` 0; DataFlash only). The
        4.6 layout records the disarm before the gap and the arm after it.
    """

    drop_fraction: float = 0.0
    reboot_at_s: float | None = None
    truncate_bytes: int = 0
    seed: int = 0
    gap: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if not 0.0 <= self.drop_fraction < 1.0:
            raise ConfigError(f"drop fraction must lie in [0, 1), got {self.drop_fraction}")
        if self.reboot_at_s is not None and not self.reboot_at_s > 0:
            raise ConfigError(f"reboot time must be positive, got {self.reboot_at_s}")
        if self.gap is not None and not (self.gap[0] > 0 and self.gap[1] > 0):
            raise ConfigError(f"a logging gap needs a positive start and length, got {self.gap}")
        if self.truncate_bytes < 0:
            raise ConfigError(f"truncate must be >= 0 bytes, got {self.truncate_bytes}")

    @property
    def any(self) -> bool:
        """True when some damage is asked for."""
        return bool(self.drop_fraction or self.reboot_at_s is not None or self.truncate_bytes
                    or self.gap is not None)

    @classmethod
    def parse(cls, text: str, seed: int = 0) -> Faults:
        """From ``"drop=F,reboot=S,truncate=N,gap=AT:LENGTH"`` (any subset, comma
        separated)."""
        kw: dict[str, float | int | tuple[float, float]] = {}
        for item in filter(None, (s.strip() for s in text.split(","))):
            key, _, value = item.partition("=")
            try:
                if key == "drop":
                    kw["drop_fraction"] = float(value)
                elif key == "reboot":
                    kw["reboot_at_s"] = float(value)
                elif key == "truncate":
                    kw["truncate_bytes"] = int(value)
                elif key == "gap":
                    at, _, length = value.partition(":")
                    kw["gap"] = (float(at), float(length))
                else:
                    raise ConfigError(
                        f"unknown fault {key!r} (use drop=F, reboot=S, truncate=N, gap=AT:S)"
                    )
            except ValueError:
                raise ConfigError(f"bad fault value {item!r}") from None
        return cls(seed=seed, **kw)  # type: ignore[arg-type]

    def keep_mask(self, n: int, salt: str = "") -> np.ndarray:
        """Boolean mask of ``n`` data records that survive ``drop_fraction``; ``salt`` (e.g.
        the message name) varies the draw between message types."""
        if not self.drop_fraction:
            return np.ones(n, dtype=bool)
        rng = np.random.default_rng([self.seed, zlib.crc32(salt.encode())])
        return rng.random(n) >= self.drop_fraction
