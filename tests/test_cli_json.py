"""``--json``: stdout is exactly one JSON document, whatever the exit code, for every
subcommand that takes the flag; the human text goes to stderr."""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import FIXTURES, REAL_LOGS

from mavsid import cli

#: real flights where fitting fails (no window kept: on the ground, or not excited)
KEITA = REAL_LOGS / "keita"
REAL_FAILING = [KEITA / "00000062.BIN", KEITA / "1_00000050.BIN"]


def _json_commands() -> list[str]:
    """Every subcommand that has a ``--json`` flag."""
    parser = cli.build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return sorted(name for name, p in sub.choices.items()
                  if any("--json" in a.option_strings for a in p._actions))


def test_the_json_commands_are_known() -> None:
    # a new --json command must be added to the runs below
    assert _json_commands() == ["fit", "info", "response", "segments", "tune", "validate"]


@pytest.fixture(scope="module")
def model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("json") / "roll.json"
    assert cli.main(["fit", str(FIXTURES / "sysid_roll.bin"), "--axis", "roll", "-q",
                     "-o", str(out)]) == 0
    return out


def _run(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = cli.main(argv)
        except SystemExit as exc:
            code = int(exc.code or 0)
    return code, out.getvalue(), err.getvalue()


def _logs(tmp_path: Path) -> dict[str, Path]:
    garbage = tmp_path / "garbage.bin"
    garbage.write_bytes(b"\x00not a log\n" * 50)
    return {"ok": FIXTURES / "sysid_roll.bin", "hover": FIXTURES / "hover.bin",
            "slow": FIXTURES / "slow_10hz.bin", "garbage": garbage}


@pytest.mark.slow
@pytest.mark.parametrize("command", ["fit", "info", "response", "segments", "tune",
                                     "validate"])
def test_json_is_one_document_on_success_and_on_failure(command: str, model: Path,
                                                        tmp_path: Path) -> None:
    codes = set()
    logs = {**_logs(tmp_path), **{p.name: p for p in REAL_FAILING if p.exists()}}
    for name, log in logs.items():
        argv = [command, *([str(model)] if command == "validate" else []), str(log), "--json"]
        code, out, err = _run(argv)
        doc = json.loads(out)  # exactly one document (json.loads refuses trailing text)
        codes.add(code)
        if code:
            assert "mavsid: error: " in err, (name, err)
            assert doc["error"]["message"] and doc["error"]["type"].endswith("Error")
            assert "verdict:" not in out and "mavsid: error" not in out
        else:
            assert "error" not in doc
    assert codes == {0, 1}, codes  # each command was seen to succeed and to fail


@pytest.mark.parametrize("log", ["hover", "slow", *[p.name for p in REAL_FAILING]])
def test_failed_fit_json_holds_the_verdicts_and_reasons(log: str, tmp_path: Path) -> None:
    logs = {**_logs(tmp_path), **{p.name: p for p in REAL_FAILING}}
    if not logs[log].exists():
        pytest.skip(f"{logs[log]} not present")
    code, out, err = _run(["fit", str(logs[log]), "--json"])
    assert code == 1
    doc = json.loads(out)
    assert doc["axes"] == {} and set(doc["verdicts"]) == {"roll", "pitch", "yaw"}
    for verdict in doc["verdicts"].values():
        assert verdict["level"] == "not identified" and verdict["reasons"]
    # the one error line on stderr is the document's error (nothing identifiable, or the
    # one-line refusal of the flight's SYSTEMID run)
    assert err.count("mavsid: error: ") == 1
    assert f"mavsid: error: {doc['error']['message']}" in err
    assert doc["error"]["type"] == "NoExcitationError"


def test_json_in_a_fresh_process_on_a_failing_log() -> None:
    """The installed command's own streams (not redirected ones): warnings on stderr."""
    proc = subprocess.run([sys.executable, "-m", "mavsid", "fit", str(FIXTURES / "hover.bin"),
                           "--json"], capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 1
    assert json.loads(proc.stdout)["verdicts"]["roll"]["level"] == "not identified"
    assert proc.stderr.startswith("mavsid: error: ")


def test_a_usage_error_with_json_is_a_json_document_too() -> None:
    code, out, err = _run(["fit", "--json"])
    assert code == 2
    assert json.loads(out)["error"]["type"] == "UsageError"
    assert "the following arguments are required: LOG" in err and err.startswith("usage:")


@pytest.mark.parametrize("where", ["before", "after"])
def test_debug_before_or_after_the_subcommand(where: str) -> None:
    argv = ["fit", str(FIXTURES / "hover.bin"), "--axis", "roll", "-q"]
    argv = ["--debug", *argv] if where == "before" else [*argv, "--debug"]
    code, _, err = _run(argv)
    assert code == 1
    assert "Traceback (most recent call last)" in err and "NoExcitationError" in err
    assert err.rstrip().splitlines()[-1].startswith("mavsid: error: ")
    code, _, err = _run(argv[:-1] if where == "after" else argv[1:])
    assert code == 1 and "Traceback" not in err



def test_a_reader_that_closes_the_pipe_early_gets_no_traceback() -> None:
    """``mavsid info LOG | head -0``: the output has nowhere to go; the command stops
    without a traceback (exit 141, as a shell reports SIGPIPE)."""
    cmd = [sys.executable, "-m", "mavsid", "info", str(FIXTURES / "sysid_roll.bin")]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout is not None
    proc.stdout.close()  # the reader is gone before the first line is written
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 141, err.decode()
    assert b"Traceback" not in err and b"BrokenPipe" not in err, err.decode()
