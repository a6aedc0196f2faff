"""Alignment of hostile logs: each test builds the file."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from fuzz import hostile

from mavsid.align import MAX_RATE_RAD_S, align, load_flight, time_outliers
from mavsid.data import MessageTable, RawLog, SourceInfo
from mavsid.errors import ConfigError, DataQualityWarning, NoExcitationError
from mavsid.pipeline import fit

FIX = Path(__file__).resolve().parents[1] / "fixtures"


def _att_log(t: np.ndarray, **cols: np.ndarray) -> RawLog:
    base = {c: np.zeros_like(t) for c in ("roll", "pitch", "yaw", "rollspeed", "pitchspeed",
                                           "yawspeed")}
    base.update(cols)
    return RawLog(SourceInfo("x.tlog", "tlog", 0), {"ATTITUDE": MessageTable("ATTITUDE", base,
                                                                            time_s=t)})


def test_one_timestamp_is_a_typed_error_naming_the_file(tmp_path: Path) -> None:
    data = hostile.set_tlog_field((FIX / "sysid_roll.tlog").read_bytes(), "ATTITUDE",
                                  "time_boot_ms", {k: 1000 for k in range(100_000)})
    path = tmp_path / "one_time.tlog"
    path.write_bytes(data)
    with pytest.raises(NoExcitationError, match=r"one_time\.tlog: .*two samples with distinct"):
        load_flight(path)


def test_time_outliers_spike_run_and_tail() -> None:
    t = np.arange(1000) * 0.01
    t[500:510] = (2**32 - 1) / 1000  # ten frames of time_boot_ms 2^32 - 1
    t[-5:] = 2.0**40 * 1e-6  # TimeUS of 2^40 in the last records
    assert np.flatnonzero(time_outliers(t)).tolist() == [*range(500, 510), *range(995, 1000)]


def test_time_outliers_leave_reboots_and_pauses() -> None:
    boot = np.arange(300) * 0.01
    assert not time_outliers(np.concatenate([boot + 100, boot])).any()  # reboot
    assert not time_outliers(np.concatenate([boot, boot + 5000])).any()  # pause


def test_far_future_samples_are_dropped_counted_and_bound_the_grid() -> None:
    t = np.arange(2000) * 0.01
    t[[300, 301, 1999]] = 2.0**40 * 1e-6
    with pytest.warns(DataQualityWarning, match="3 mistimed"):
        fd = align(_att_log(t))
    assert fd.time_s.size < 2000 and fd.time_s[-1] < 20.0
    assert fd.excluded_samples["p"] == 3
    # the mistimed frames leave a gap: nothing interpolated across them
    assert len(fd.blocks) == 2


def test_far_future_tail_in_a_dataflash_log_is_cheap(tmp_path: Path) -> None:
    data = hostile.dataflash_time_outlier((FIX / "sysid_roll.bin").read_bytes(), None,
                                          2**40, last=3)
    path = tmp_path / "t40.bin"
    path.write_bytes(data)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataQualityWarning)
        fd = load_flight(path)
    assert fd.time_s[-1] < 100.0  # the clean flight lasts ~33 s
    assert fd.time_s.size < 20_000


def test_grid_never_larger_than_samples_justify() -> None:
    t = np.arange(100) * 0.01
    with pytest.raises(ConfigError, match=r"x\.tlog: .*points"):
        align(_att_log(t), rate_hz=1e7)


def test_non_finite_and_impossible_samples_excluded_and_counted() -> None:
    t = np.arange(1000) * 0.01
    p = np.sin(t)
    p[[100, 600]] = -np.inf
    p[[300]] = np.nan
    p[[800]] = 2 * MAX_RATE_RAD_S
    roll = np.zeros_like(t)
    roll[400] = 7.0  # beyond ±π after conversion
    with pytest.warns(DataQualityWarning, match="non-finite"):
        fd = align(_att_log(t, rollspeed=p, roll=roll))
    assert fd.excluded_samples == {"p": 4, "roll": 1}
    assert np.all(np.isfinite(fd.states)) and np.abs(fd.states).max() <= math.pi + 1e-3
    # every excluded sample splits the grid: 5 gaps -> 6 blocks
    assert len(fd.blocks) == 6
    for a, b in fd.blocks:
        for bad in (1.0, 3.0, 4.0, 6.0, 8.0):
            assert not fd.time_s[a] < bad < fd.time_s[b - 1]


def test_minus_inf_in_a_crc_valid_tlog_is_never_fitted(tmp_path: Path) -> None:
    data = hostile.set_tlog_field((FIX / "sysid_roll.tlog").read_bytes(), "ATTITUDE",
                                  "rollspeed", {k: -math.inf for k in range(0, 100_000, 7)})
    path = tmp_path / "ninf.tlog"
    path.write_bytes(data)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataQualityWarning)
        assert load_flight(path).excluded_samples["p"] == 236
        with pytest.raises(NoExcitationError, match=r"ninf\.tlog: nothing identifiable"):
            fit([path])


def test_boot_choice_is_reported() -> None:
    a, b = np.arange(500) * 0.01, np.arange(2000) * 0.01
    with pytest.warns(DataQualityWarning, match=r"only boot 2 of 2 .*the longest"):
        fd = align(_att_log(np.concatenate([a + 50, b])))
    assert fd.boot is not None and (fd.boot.used, fd.boot.of) == (2, 2)
    assert "longest" in fd.boot.reason


@pytest.mark.slow
@pytest.mark.parametrize("value", [float("nan"), float("inf"), -float("inf"), 1e300, -1e300,
                                   -1.0, 0.0, 1e9])
def test_every_parameter_damaged_at_once_fits_or_says_why(monkeypatch, value: float) -> None:  # type: ignore[no-untyped-def]
    """Every parameter of the bundled SYSTEMID flight set to one hostile value (a damaged
    PARM block): the fit ends in a model or a MavsidError, never another exception. Found
    so: 1e9 for SCHED_LOOP_RATE asked numpy for 78 GiB (the twin's controller steps),
    1e300 overflowed an integer, a NaN FRAME_CLASS raised ValueError. (Each parameter alone,
    inf, 1e9 and -5, on this flight, a simulated QuadPlane and a PX4 1.14 ULog: no crash.)"""
    import dataclasses

    import mavsid.align.flight as al
    from mavsid.errors import MavsidError
    from mavsid.pipeline_config import PipelineConfig

    read = al.read_log

    def damaged(*args, **kwargs):  # type: ignore[no-untyped-def]
        raw = read(*args, **kwargs)
        return dataclasses.replace(raw, params=dict.fromkeys(raw.params, value))

    monkeypatch.setattr(al, "read_log", damaged)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            result = fit([str(FIX / "sysid_roll.bin")], PipelineConfig(axes=("roll",)))
        except MavsidError:
            return
    assert result.axes["roll"].verdict is not None
