"""Whether a log's rate target carries the SYSTEMID rate injection (mavsid.loop.injection):
the decision from the data against signals built with and without it, the firmware version
only where the data cannot say, and the version rule itself."""

from __future__ import annotations

import numpy as np
import pytest

from mavsid.autopilot.ardupilot import rate_target_logs_injection
from mavsid.loop.injection import DECIDES, injection_in_target

DT = 0.0025


def _chirp(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 1-20 Hz chirp (rad/s), the attitude controller's slow part with its answer in
    quadrature (the integrated chirp through an angle P), and gyro-like noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 30.0, DT)
    phase = 2 * np.pi * (1.0 * t + 0.5 * (19.0 / 30.0) * t**2)
    inj = 0.4 * np.sin(phase)
    slow = 0.3 * np.sin(2 * np.pi * 0.15 * t) - 4.5 * np.cumsum(inj) * DT
    return inj, slow, 0.02 * rng.standard_normal(t.size)


@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("included", [True, False])
def test_the_data_decide_with_or_without_the_waveform(seed: int, included: bool) -> None:
    inj, slow, noise = _chirp(seed)
    target = slow + noise + (inj if included else 0.0)
    # (a firmware saying the opposite does not override the data)
    firmware = "ArduCopter V4.4.4" if included else "ArduCopter V4.6.2"
    got = injection_in_target(target, inj, [(0, inj.size)], DT, firmware, 20.0)
    assert got.decided_by == "data" and got.included is included, got
    assert got.coefficient is not None
    assert abs(got.coefficient - float(included)) < DECIDES / 2


@pytest.mark.parametrize(("firmware", "included", "by"), [
    ("ArduCopter V4.6.2 (abc)", True, "firmware"), ("ArduCopter V4.3.8", False, "firmware"),
    (None, False, "assumed"), ("PX4 v1.14.0", False, "assumed")])
def test_the_firmware_decides_when_the_data_cannot(firmware, included, by) -> None:
    inj, slow, noise = _chirp(3)
    got = injection_in_target(slow + noise + 0.5 * inj, inj, [(0, inj.size)], DT, firmware)
    assert got.coefficient is not None and abs(got.coefficient - 0.5) < 0.05
    assert (got.included, got.decided_by) == (included, by)


def test_no_waveform_or_too_short_a_run_gives_no_coefficient() -> None:
    inj, slow, _ = _chirp(4)
    assert injection_in_target(slow, np.zeros_like(inj), [(0, inj.size)], DT,
                               None).coefficient is None
    short = injection_in_target(slow + inj, inj, [(0, 200)], DT, "ArduCopter V4.5.7")
    assert short.coefficient is None and short.decided_by == "firmware" and short.included


def test_the_version_rule() -> None:
    got = [rate_target_logs_injection(f) for f in (
        "ArduCopter V4.0.0", "ArduCopter V4.4.4", "ArduCopter V4.5.0", "ArduCopter V4.7.0-dev",
        "ArduCopter V3.6.12", "PX4 v1.14.0", None)]
    assert got == [False, False, True, True, None, None, None]
