"""mavsid's own flight-mode tables against pymavlink's (the reference)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from mavsid.autopilot.modes import ARDUPILOT_MODES, MAV_TYPE_MODES, ardupilot_modes, px4_mode_name
from mavsid.readers import dataflash_assemble, tlog

mavutil = pytest.importorskip("pymavlink.mavutil")


def test_mav_type_tables_equal_pymavlink():
    assert set(MAV_TYPE_MODES) == set(mavutil.AP_MAV_TYPE_MODE_MAP)
    for mav_type in range(64):
        assert ardupilot_modes(mav_type) == mavutil.mode_mapping_bynumber(mav_type), mav_type


@pytest.mark.parametrize(("vehicle", "mav_type"), [
    ("copter", 2), ("heli", 4), ("plane", 1), ("rover", 10), ("sub", 12), ("tracker", 5),
    ("blimp", 7),
])
def test_vehicle_classes_name_pymavlink_tables(vehicle, mav_type):
    """The DataFlash reader's vehicle words pick the table pymavlink gives that MAV_TYPE."""
    assert dict(ARDUPILOT_MODES[vehicle]) == mavutil.mode_mapping_bynumber(mav_type)
    names = dataflash_assemble.mode_names
    assert names(f"{vehicle} QUAD/X") == mavutil.mode_mapping_bynumber(mav_type)
    assert names(None) == {} and names("boat") == {}


def test_px4_names_equal_pymavlink():
    for main in range(256):
        for sub in range(256) if main == 4 else (0, 1, 4, 255):
            mode = main << 16 | sub << 24 | 0x1234
            assert px4_mode_name(mode) == mavutil.interpret_px4_mode(0, mode), hex(mode)


def test_tlog_mode_names():
    assert tlog._mode_names(12, 2)(4 << 16 | 5 << 24) == "RTL"
    assert tlog._mode_names(3, 1)(19) == "QLOITER"
    assert tlog._mode_names(3, 6)(0) is None and tlog._mode_names(0, 2)(0) is None


def test_no_pymavlink_import():
    """Reading a DataFlash log (modes named) does not import pymavlink."""
    code = ("import sys, tempfile, os\n"
            "from mavsid.readers.dataflash import read\n"
            "from mavsid.readers.dataflash_spec import build_fmt, build_record\n"
            "data = (build_fmt(0x81, 'MODE', 'QMB', 'TimeUS,Mode,ModeNum')"
            " + build_fmt(0x82, 'MSG', 'QZ', 'TimeUS,Message')"
            " + build_record(0x82, 'QZ', 1, 'ArduCopter V4.6.2 (1ebd4d99)')"
            " + build_record(0x81, 'QMB', 2, 5, 5))\n"
            "f = tempfile.NamedTemporaryFile(suffix='.bin', delete=False)\n"
            "f.write(data); f.close()\n"
            "log = read(f.name); os.unlink(f.name)\n"
            "print([m.name for m in log.modes], 'pymavlink' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == ["['LOITER']", "False"]
