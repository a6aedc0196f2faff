"""Shared test helpers (import as ``helpers``): the ``../shared`` logs, skipped when absent
unless CI requires them."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest

if TYPE_CHECKING:
    from mavsid.data import RawLog

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
LOGS = SHARED / "logs"
FIXTURES = ROOT / "fixtures"
REQUIRE_SHARED = os.environ.get("MAVSID_REQUIRE_SHARED") == "1"
#: real flight logs from public repositories that carry no licence to redistribute, kept
#: outside the project: ``$MAVSID_REAL_LOGS``, else a ``cache`` folder beside the checkout
#: (or beside the folder holding it); ``keita/`` holds ArduCopter 4.6.2 SYSTEMID flights
REAL_LOGS = (Path(os.environ["MAVSID_REAL_LOGS"]) if os.environ.get("MAVSID_REAL_LOGS")
             else next((d for d in (ROOT.parent / "cache", ROOT.parent.parent / "cache")
                        if d.is_dir()), ROOT.parent / "cache"))


def real_path(*parts: str) -> Path:
    """Path below :data:`REAL_LOGS`; skips the test when absent (never bundled, so never
    required)."""
    path = REAL_LOGS.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"{path} not present (a real log, not bundled: set MAVSID_REAL_LOGS)")
    return path


def shared_path(*parts: str) -> Path:
    """Path below ``../shared/logs``; skips the test when absent (fails under CI)."""
    path = LOGS.joinpath(*parts)
    if not path.exists():
        if REQUIRE_SHARED:
            pytest.fail(f"{path} missing and MAVSID_REQUIRE_SHARED=1")
        pytest.skip(f"{path} not present (the shared logs belong in ../shared/logs)")
    return path


def shared_logs(*suffixes: str) -> list[Path]:
    """Every shared log whose (lower-case) suffix is in ``suffixes``; [] when absent.

    Use with :func:`require_shared` in a parametrised test so that an absent folder skips
    (or fails under CI) instead of silently collecting nothing.
    """
    if not LOGS.exists():
        return []
    return sorted(p for p in LOGS.rglob("*") if p.is_file() and p.suffix.lower() in suffixes)


def require_shared() -> None:
    """Skip (or fail under CI) when ``../shared/logs`` is missing."""
    if not LOGS.exists():
        if REQUIRE_SHARED:
            pytest.fail(f"{LOGS} missing and MAVSID_REQUIRE_SHARED=1")
        pytest.skip(f"{LOGS} not present")


def ids(paths: list[Path]) -> list[str]:
    """Readable test ids for shared logs."""
    return [str(p.relative_to(LOGS)) if LOGS in p.parents else p.name for p in paths]


GOLDEN = Path(__file__).parent / "golden"


def assert_info_matches_golden(raw: object, path: Path) -> None:
    """``mavsid info`` text of ``raw`` (read from ``path``) equals ``golden/info_NAME.txt``.

    The golden file is rewritten only with ``MAVSID_UPDATE_GOLDEN=1`` (the test then skips,
    so an update never passes silently).
    """
    from mavsid.info import format_summary, summarize

    summary = summarize(raw)  # type: ignore[arg-type]
    summary["path"] = path.name  # independent of where shared/ lives
    text = format_summary(summary) + "\n"
    golden = GOLDEN / f"info_{path.name}.txt"
    if os.environ.get("MAVSID_UPDATE_GOLDEN") == "1":
        golden.parent.mkdir(exist_ok=True)
        golden.write_text(text)
        pytest.skip(f"rewrote {golden}")
    assert text == golden.read_text()


def table_log(fmt: str, tables: dict[str, dict[str, np.ndarray]], **kw: dict) -> RawLog:
    """A RawLog of format ``fmt`` from column tables, each sampled at 100 Hz (``kw``: a
    table's extra MessageTable arguments, by name)."""
    from mavsid.data import MessageTable, RawLog, SourceInfo

    msgs = {}
    for name, cols in tables.items():
        n = len(next(iter(cols.values())))
        msgs[name] = MessageTable(name, cols, time_s=np.arange(n) * 0.01, **kw.pop(name, {}))
    return RawLog(SourceInfo(f"x.{fmt}", fmt, 0), msgs)


def write_systemid_without_injection(path: Path) -> Path:
    """A simulated hover (the project's simulator and DataFlash writer) that spends 9.6 s in
    SYSTEMID mode 8 s after its first sample with SIDD logged at the loop rate but its
    waveform zero throughout (``F`` the stop frequency) and no SIDS record; SID_* parameters
    those of a real such run (SID_AXIS 1, 0.15°, 0.05–5 Hz, SID_T_REC 130 s)."""
    import dataclasses

    from mavsid.synthetic import Scenario, SysIdSettings, fly
    from mavsid.synthetic.dfwriter import write_dataflash
    from mavsid.synthetic.flight import MODE_SYSTEMID

    hover = fly(Scenario(manoeuvre="hover", duration_s=20.0, seed=3))
    t = hover.t_s - hover.t_s[0]
    inside = (t >= 8.0) & (t < 17.6)
    settings = SysIdSettings(axis=1, magnitude=0.15, f_start_hz=0.05, f_stop_hz=5.0,
                             t_fade_in=5.0, t_rec=130.0, t_fade_out=5.0)
    flight = dataclasses.replace(
        hover,
        scenario=dataclasses.replace(hover.scenario, manoeuvre="sysid", sysid=(settings,),
                                     duration_s=None),  # (its SID_* parameters)
        mode=np.where(inside, MODE_SYSTEMID, hover.mode),
        sid_time=np.where(inside, t - 8.0, np.nan), sid_targ=np.where(inside, 0.0, np.nan),
        sid_freq=np.where(inside, settings.f_stop_hz, np.nan))
    write_dataflash(flight, path)
    return path
