"""The fuzz suite's time budget: ``MAVSID_FUZZ_BUDGET`` seconds (default 90, for CI; a
nightly run sets it to thousands). Case lists are a pure function of the budget, so that
pytest-xdist workers collect the same tests."""

from __future__ import annotations

import os

BUDGET_S = float(os.environ.get("MAVSID_FUZZ_BUDGET", "90"))
#: share of the budget spent in-process (hypothesis) vs in measured subprocesses
IN_PROCESS_SHARE = 0.4
#: rough cost of one case, seconds (a loaded 2-core machine)
IN_PROCESS_CASE_S = 0.4
SUBPROCESS_CASE_S = 4.0


def in_process_examples() -> int:
    return max(20, int(BUDGET_S * IN_PROCESS_SHARE / IN_PROCESS_CASE_S))


def subprocess_cases() -> int:
    return max(8, int(BUDGET_S * (1 - IN_PROCESS_SHARE) / SUBPROCESS_CASE_S))
