"""Fuzzing in process (hypothesis over the mutation corpus and over raw bytes): every
reader, ``info`` (on the whole log, and as ``mavsid info`` reads it) and alignment either
succeed or raise one typed, one-line
:class:`~mavsid.errors.MavsidError` naming the file; no numpy RuntimeWarning escapes.

Time and memory are measured in ``test_fuzz_limits.py`` (subprocesses); here the cases are
many and cheap. ``MAVSID_FUZZ_BUDGET`` (seconds) scales the number of examples.
"""

from __future__ import annotations

import os
import tempfile
import warnings

import pytest
from helpers import require_shared
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fuzz.budget import in_process_examples
from fuzz.mutate import MUTATORS, SEEDS, available_seeds, mutate, suffix
from mavsid.align import align
from mavsid.errors import MavsidError
from mavsid.info import format_summary, read_for_summary, summarize
from mavsid.readers import read_log

_SETTINGS = settings(max_examples=in_process_examples(), deadline=None, derandomize=True,
                     database=None, suppress_health_check=list(HealthCheck))
_MAGIC = {".bin": b"\xa3\x95\x80", ".tlog": b"\x00" * 8 + b"\xfd", ".ulg": b"ULog\x01\x12\x35",
          ".log": b"FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns\n"}


def check(data: bytes, suffix_: str) -> str:
    """Read, summarise and align ``data``; the outcome ('ok' or the error line)."""
    fd, name = tempfile.mkstemp(suffix=suffix_, prefix="fuzz")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            warnings.simplefilter("error", RuntimeWarning)  # numpy's must be handled
            try:
                raw = read_log(name)
                format_summary(summarize(raw))
                format_summary(summarize(read_for_summary(name)))  # as `mavsid info` reads
                align(raw)
            except MavsidError as exc:
                text = str(exc)
                assert "\n" not in text and "\r" not in text, text
                assert name in text, f"error does not name the file: {text}"
                return text
        return "ok"
    finally:
        os.unlink(name)


@pytest.mark.slow
@_SETTINGS
@given(seed=st.sampled_from(sorted(SEEDS)), mutator=st.sampled_from(sorted(MUTATORS)),
       n=st.integers(0, 2**16))
def test_mutated_logs(seed: str, mutator: str, n: int) -> None:
    if seed not in available_seeds():
        require_shared()
        pytest.skip(f"seed {seed} absent")
    check(mutate(seed, mutator, n), suffix(seed))


@_SETTINGS
@given(kind=st.sampled_from(sorted(_MAGIC)), body=st.binary(max_size=4096))
def test_random_bytes_behind_a_magic(kind: str, body: bytes) -> None:
    check(_MAGIC[kind] + body, kind)


@pytest.mark.slow
@pytest.mark.parametrize("mutator", sorted(MUTATORS))
def test_every_mutator_on_a_fixture(mutator: str) -> None:
    """Each mutation kind at least once on the simulated flight, whatever the budget."""
    for n in range(3):
        check(mutate("fix_roll.bin", mutator, n), ".bin")
        check(mutate("fix_roll.tlog", mutator, n), ".tlog")
