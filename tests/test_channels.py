"""Reading channels from a log: field expressions, units, quaternions, rows (mavsid.channels)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import table_log

from mavsid.autopilot.presets import Channel
from mavsid.channels import evaluate
from mavsid.data import MessageTable, RawLog, SourceInfo
from mavsid.errors import MissingMessageError


def test_declared_unit_and_multiplier_win_over_preset_unit():
    # the log declares centidegrees through its multiplier and deg through its unit
    raw = table_log("dataflash", {"ATT": {"Roll": np.array([1000.0, -4500.0])}},
               ATT={"units": {"Roll": "deg"}, "multipliers": {"Roll": 0.01}})
    _, v = evaluate(raw, Channel("ATT", "Roll", "rad"))
    assert np.allclose(v, np.radians([10.0, -45.0]))


def test_field_expressions_sum_alternatives_and_array_elements():
    raw = table_log("dataflash", {
        "PIDR": {"P": np.array([0.1, 0.2]), "I": np.array([0.01, 0.02]),
                 "D": np.array([0.001, 0.0])},
        "RCOU": {"Chan1": np.array([1100.0, 1200.0])},
        "vec": {"xyz": np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])},
    })
    assert np.allclose(evaluate(raw, Channel("PIDR", "P+I+D+FF|P+I+D"))[1], [0.111, 0.22])
    assert np.allclose(evaluate(raw, Channel("RCOU", "C1|Chan1"))[1], [1100, 1200])
    assert np.allclose(evaluate(raw, Channel("vec", "xyz[2]"))[1], [3.0, 6.0])
    with pytest.raises(MissingMessageError, match=r"PIDR\.Q"):
        evaluate(raw, Channel("PIDR", "Q"))


def test_multi_instance_and_multi_system_rows_are_separated():
    t = np.repeat(np.arange(3) * 0.01, 2)
    imu = MessageTable("IMU", {"I": np.tile([0, 1], 3), "GyrX": np.tile([0.1, 9.0], 3)},
                       time_s=t, units={"I": "instance"})
    att = MessageTable("ATTITUDE", {"_sysid": np.array([1, 1, 1, 7]),
                                    "roll": np.array([0.1, 0.2, 0.3, 5.0])},
                       time_s=np.arange(4) * 0.1)
    raw = RawLog(SourceInfo("x.bin", "dataflash", 0), {"IMU": imu, "ATTITUDE": att})
    tt, v = evaluate(raw, Channel("IMU", "GyrX", "rad/s"))
    assert np.allclose(v, 0.1) and np.allclose(tt, [0.0, 0.01, 0.02])
    assert np.allclose(evaluate(raw, Channel("IMU", "GyrX", "rad/s", instance=1))[1], 9.0)
    assert np.allclose(evaluate(raw, Channel("ATTITUDE", "roll", "rad"))[1], [0.1, 0.2, 0.3])
