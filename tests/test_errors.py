from helpers import LOGS

import mavsid
from mavsid.errors import LogFormatError, MavsidError, MissingMessageError


def test_errors_are_typed_and_one_line() -> None:
    err = MissingMessageError("RATE", available=["ATT", "IMU"])
    assert isinstance(err, KeyError) and isinstance(err, MavsidError)
    assert "\n" not in str(err) and "RATE" in str(err)
    assert isinstance(LogFormatError("x", path="a.bin"), ValueError)


def test_public_api_exports_exist() -> None:
    for name in mavsid.__all__:
        assert hasattr(mavsid, name), name
    assert LOGS.name == "logs"
