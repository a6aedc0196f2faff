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


def test_missing_message_names_the_file() -> None:
    from mavsid.data import RawLog, SourceInfo

    log = RawLog(SourceInfo("flight.bin", "dataflash", 0), messages={})
    try:
        log["ATT"]
    except MissingMessageError as exc:
        assert str(exc).startswith("flight.bin: ") and "'ATT'" in str(exc)
    else:  # pragma: no cover
        raise AssertionError("no error")
