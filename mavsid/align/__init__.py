"""RawLog -> FlightData: every state and input on one uniform time grid, in SI units.

The one place a log is turned into :class:`~mavsid.data.FlightData`
(:func:`~mavsid.align.flight.align`, :func:`~mavsid.align.flight.load_flight`). One concept
per module:

- :mod:`mavsid.align.series`: the preset chosen from the log's content and each channel's
  native samples in SI units (motor outputs unmixed, impossible and mistimed samples left
  out and counted);
- :mod:`mavsid.align.boots`: one boot of a log whose clock restarts;
- :mod:`mavsid.align.grid`: the uniform grid, its blocks between gaps, interpolation and hold;
- :mod:`mavsid.align.flags`: the ``armed``, ``airborne`` and ``mode`` flags;
- :mod:`mavsid.align.sysid`: ArduPilot SYSTEMID runs and their waveform;
- :mod:`mavsid.align.commanded`: the commanded attitude (or the pilot's sticks);
- :mod:`mavsid.align.flight`: :func:`align` composing them, reading a file, the aligned table.

Examples
--------
>>> fd = load_flight("fixtures/sysid_roll.bin")
>>> fd.preset, [r.sid_axis for r in fd.sysid_runs], fd.boot.of, fd.native_rate_hz["p"]
('ardupilot-rate', [10], 1, 200.0)
"""

from mavsid.align.commanded import STICK_SOURCE
from mavsid.align.flight import (
    FLAG_MESSAGES,
    MIN_INPUT_RATE_HZ,
    align,
    flight_table,
    load_flight,
    read_flight,
)
from mavsid.align.grid import MAX_GAP_SAMPLES, MAX_GRID_PER_SAMPLE
from mavsid.align.series import MAX_RATE_RAD_S, TIME_OUTLIER_S, channel_units, time_outliers
from mavsid.align.sysid import sysid_runs

__all__ = ["FLAG_MESSAGES", "MAX_GAP_SAMPLES", "MAX_GRID_PER_SAMPLE", "MAX_RATE_RAD_S",
           "MIN_INPUT_RATE_HZ", "STICK_SOURCE", "TIME_OUTLIER_S", "align", "channel_units",
           "flight_table", "load_flight", "read_flight", "sysid_runs", "time_outliers"]
