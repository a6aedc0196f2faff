"""The README's promises: its quick-start commands are what CI runs, its Python example runs."""

from __future__ import annotations

import re

from helpers import FIXTURES, ROOT

README = (ROOT / "README.md").read_text(encoding="utf-8")


def _blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", README, flags=re.S)


def test_ci_runs_the_quick_start_commands_verbatim() -> None:
    quick = _blocks("sh")[0].strip().splitlines()
    assert len(quick) == 2
    venv = "python3 -m venv .venv && . .venv/bin/activate && "
    assert quick[0].startswith(venv + "pip install . && mavsid ")
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()
    for line in quick:
        assert line in ci, line
    assert "export MAVSID_REQUIRE_SHARED=1" in ci
    # the bundled example the first command runs is in the repository
    example = quick[0].split("mavsid ", 1)[1].split()[1]
    assert (ROOT / example).is_file() and (ROOT / example).parent == FIXTURES


def test_python_example_runs_on_a_fixture() -> None:
    (code,) = _blocks("python")
    namespace: dict[str, object] = {}
    exec(code.replace('"flight.bin"', repr(str(FIXTURES / "sysid_roll.bin"))), namespace)
    model = namespace["model"]
    assert "B[p,u_roll]" in model.params  # type: ignore[attr-defined]
