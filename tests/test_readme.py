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


def test_the_quick_start_flight_shows_three_good_axes() -> None:
    """A newcomer's first output: the bundled flight the first command fits has a good
    model on every axis, each near the simulated plant's truth (its ``.truth.json``)."""
    import json

    from mavsid.pipeline import fit

    quick = _blocks("sh")[0].strip().splitlines()
    example = ROOT / quick[0].split("mavsid ", 1)[1].split()[1]
    assert example.stat().st_size < 1_000_000  # (small: it ships with the code)
    result = fit([str(example)])
    assert {a: v.level for a, v in result.verdicts.items()} == {
        "roll": "good", "pitch": "good", "yaw": "good"}
    truth = json.loads(example.with_suffix(".truth.json").read_text())["axes"]
    for axis, fitted in result.axes.items():
        rate, want = truth[axis]["state"], truth[axis]
        b = fitted.model.params[f"B[{rate},u_{axis}]"]
        sb = fitted.model.stderr[f"B[{rate},u_{axis}]"]
        a = fitted.model.params[f"A[{rate},{rate}]"]
        sa = fitted.model.stderr[f"A[{rate},{rate}]"]
        assert abs(b - want["effectiveness"]) < 3 * sb, axis
        assert abs(a + want["damping"]) < 3 * sa, axis
