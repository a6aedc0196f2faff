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


def test_log_text_reaching_the_terminal_is_escaped(tmp_path, capsys) -> None:
    """Column names, units, texts and the firmware from a log never reach the terminal raw:
    no escape sequence, carriage return or extra line."""
    from mavsid.cli import main
    from mavsid.readers.dataflash_spec import build_fmt, build_record

    evil = "\x1b[2J\x1b]0;pwned\x07\r\x9b31m\u202e"
    data = (build_fmt(0x81, "MSG", "QZ", "TimeUS,Message")
            + build_fmt(0x82, "TST", "Qf", f"TimeUS,V{evil}")
            + build_fmt(0x83, "UNIT", "QbZ", "TimeUS,Id,Label")
            + build_fmt(0x84, "FMTU", "QBNN", "TimeUS,FmtType,UnitIds,MultIds")
            + build_record(0x81, "QZ", 1, f"ArduCopter V4.5 {evil}\nsecond line")
            + build_record(0x83, "QbZ", 1, ord("x"), f"deg{evil}")
            + build_record(0x84, "QBNN", 1, 0x82, "-x", "--"))
    for k in range(5):
        data += build_record(0x82, "Qf", 1000 * k, 1.0)
    path = tmp_path / "evil\x1b[31m.bin"
    path.write_bytes(data)
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr()
    for text in (out.out, out.err):
        assert not any(c in text for c in "\x1b\x07\r\x9b\u202e"), repr(text)
    assert "V\\x1b[2J" in out.out and "deg\\x1b" in out.out
    assert "\\nsecond line" in out.out  # the text's newline shown, not obeyed
    assert main(["info", "--json", str(path)]) == 0  # JSON: ASCII, controls escaped
    out = capsys.readouterr()
    assert out.out.isascii() and "\\u001b[2J" in out.out and "\\u009b" in out.out


def test_errors_are_one_escaped_line() -> None:
    err = MissingMessageError("RATE", available=["A\nB", "C\x1b[2J"], path="x\r.bin")
    assert str(err) == "x\\r.bin: log has no message 'RATE' (it has: A\\nB, C\\x1b[2J)"
    from mavsid.errors import LogFormatError, NoExcitationError

    assert "\n" not in str(NoExcitationError("a.bin: line\nbreak"))
    assert str(LogFormatError("bad\r", path="p")) == "p: bad\\r"
