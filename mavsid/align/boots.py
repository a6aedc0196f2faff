"""One boot of a log whose clock restarts (a reboot, concatenated logs): the longest one of
the reference channel, every channel's records of it, in time order.

Examples
--------
>>> t = np.array([30.0, 31.0, 31.0, 5.0, 6.0])
>>> [a.tolist() for a in boot_records(t, np.arange(5.0), 0)]
[[30.0, 31.0], [0.0, 1.0]]
"""

from __future__ import annotations

import itertools
import warnings
from dataclasses import replace

import numpy as np

from mavsid.align.grid import MAX_GAP_SAMPLES
from mavsid.align.series import Series, dedupe, reference
from mavsid.data import Boot
from mavsid.errors import DataQualityWarning

__all__ = ["BOOT_JUMP_S", "boot_records", "one_boot"]


#: a step back in time larger than this (s) is a reboot or the start of a concatenated log
BOOT_JUMP_S = 1.0


def _boots(t: np.ndarray) -> list[slice]:
    """Record ranges between backward time jumps (one per boot)."""
    cut = np.flatnonzero(np.diff(t) < -BOOT_JUMP_S) + 1
    edges = [0, *cut.tolist(), t.size]
    return [slice(a, b) for a, b in itertools.pairwise(edges)]


def one_boot(path: str, states: list[Series], inputs: list[Series]
              ) -> tuple[list[Series], list[Series], Boot]:
    """Keep one boot of a log whose clock restarts, then sort by time and unwrap yaw.

    The boot is the longest one of the reference channel (body rate, else attitude); every
    channel keeps its records of that boot (its last boot when it has fewer).
    """
    ref = reference(states)
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

    def fix(s: Series) -> Series:
        t, v = boot_records(s.t, s.v, k)
        if s.name == "yaw":
            v = np.unwrap(v)
        bad_t = s.bad_t[(s.bad_t >= t[0]) & (s.bad_t <= t[-1])] if t.size else s.bad_t[:0]
        return replace(s, t=t, v=v, bad_t=np.sort(bad_t))

    return [fix(s) for s in states], [fix(s) for s in inputs], boot


def boot_records(t: np.ndarray, v: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """A channel's records (``t``, ``v`` in record order) of boot ``k`` (its last when it has
    fewer boots, see :func:`_boots`), in time order, one per time stamp.

    Examples
    --------
    >>> t = np.array([30.0, 31.0, 31.0, 5.0, 6.0])
    >>> [a.tolist() for a in boot_records(t, np.arange(5.0), 1)]
    [[5.0, 6.0], [3.0, 4.0]]
    """
    boots = _boots(t)
    sl = boots[min(k, len(boots) - 1)]
    t, v = t[sl], v[sl]
    if t.size < 2 or (t[1:] > t[:-1]).all():  # (most channels: already so)
        return t.copy(), v.copy()
    order = np.argsort(t, kind="stable")
    return dedupe(t[order], v[order])


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
