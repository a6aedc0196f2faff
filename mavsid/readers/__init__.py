"""Readers: one module per log format, chosen by the file's content, never its suffix.

Each reader module exposes ``read(path, messages=None, start=None, stop=None, **options)
-> RawLog``. :func:`read_log` sniffs the format and dispatches.

The DataFlash binary reader, :mod:`~mavsid.readers.dataflash`, is built from
:mod:`~mavsid.readers.dataflash_scan` (the header scan, views of records),
:mod:`~mavsid.readers.dataflash_formats` (FMT definitions), :mod:`~mavsid.readers.dataflash_framing`
(which candidates are records, the damage between them), :mod:`~mavsid.readers.dataflash_decode`
(records to columns) and :mod:`~mavsid.readers.dataflash_assemble` (tables to a RawLog, shared
with the text reader :mod:`~mavsid.readers.dftext`); :mod:`~mavsid.readers.arrays` holds the
array operations over compact indices; :mod:`~mavsid.readers.dataflash_spec` is the format
shared with the simulator's writer. :mod:`~mavsid.readers.files` opens and maps a log for any
reader.

Examples
--------
>>> import tempfile, os
>>> with tempfile.NamedTemporaryFile(suffix=".bin", delete=False) as f:
...     _ = f.write(b"ULog\\x01\\x12\\x35\\x01" + bytes(8))
>>> sniff_format(f.name)
'ulog'
>>> os.unlink(f.name)
"""

from __future__ import annotations

import importlib
import os
import stat
from collections.abc import Sequence

from mavsid.data import RawLog
from mavsid.errors import ConfigError, LogFormatError, MavsidError, naming_file
from mavsid.readers.dataflash_spec import FMT_TYPE, HEAD
from mavsid.readers.files import LogPath
from mavsid.readers.ulog_spec import MAGIC as ULOG_MAGIC

__all__ = ["READERS", "read_log", "sniff_format"]

#: format name -> module implementing ``read``
READERS: dict[str, str] = {
    "dataflash": "mavsid.readers.dataflash",
    "dataflash-text": "mavsid.readers.dftext",
    "tlog": "mavsid.readers.tlog",
    "ulog": "mavsid.readers.ulog",
}

_SNIFF_BYTES = 64 * 1024


def _looks_like_tlog(head: bytes) -> bool:
    """True when the first records are 8-byte timestamps each followed by a MAVLink frame, or,
    after some garbage within the first 4 KiB, three such records whose timestamps agree in
    their first three bytes."""
    starts, end = _tlog_chain(head, 0)
    if len(starts) >= 3 or (starts and end >= len(head)):
        return True
    for pos in range(1, min(4096, len(head) - 11)):
        if head[pos + 8] in (0xFE, 0xFD):
            starts, _ = _tlog_chain(head, pos)
            if len(starts) == 3 and len({head[p : p + 3] for p in starts}) == 1:
                return True
    return False


def _tlog_chain(head: bytes, pos: int) -> tuple[list[int], int]:
    """Starts of up to three .tlog records chained from ``pos``, and where the chain ends."""
    starts: list[int] = []
    while len(starts) < 3 and pos + 11 <= len(head) and head[pos + 8] in (0xFE, 0xFD):
        starts.append(pos)
        if head[pos + 8] == 0xFE:
            pos += 8 + head[pos + 9] + 8  # timestamp + header(6) + payload + crc(2)
        else:
            pos += 8 + 10 + head[pos + 9] + 2 + (13 if head[pos + 10] & 0x01 else 0)
    return starts, pos


def sniff_format(path: LogPath) -> str:
    """Return the log format of ``path`` from its first bytes.

    Raises
    ------
    LogFormatError
        The file is empty, unreadable, a pipe or a device, or of no known format.
    """
    try:
        mode = os.stat(path).st_mode
    except OSError:
        mode = 0  # (open says why)
    if mode and not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        # a pipe has no size and cannot be mapped (or read twice: sniffed, then read), and
        # opening a FIFO nobody writes to waits for ever
        raise LogFormatError("a pipe or a device, not a file: save the log to a file first",
                             path=path)
    try:
        with open(path, "rb") as f:
            head = f.read(_SNIFF_BYTES)
    except OSError as exc:
        raise LogFormatError(f"cannot open: {exc.strerror or exc}", path=path) from None
    if not head:
        raise LogFormatError("empty file", path=path)
    if head.startswith(ULOG_MAGIC):
        return "ulog"
    if head.startswith(HEAD):
        return "dataflash"
    if _looks_like_tlog(head):
        return "tlog"
    text = head.lstrip(b"\xef\xbb\xbf \t\r\n")
    if text.startswith(b"FMT,") or b"\nFMT," in text[:4096]:
        return "dataflash-text"
    # a DataFlash log whose first bytes are damaged: look for an FMT record further on
    if HEAD + bytes((FMT_TYPE,)) in head:
        return "dataflash"
    raise LogFormatError(
        "not a DataFlash .bin/.log, MAVLink .tlog or ULog .ulg file", path=path
    )


def read_log(path: LogPath, messages: Sequence[str] | None = None, start: float | None = None,
             stop: float | None = None, **options: object) -> RawLog:
    """Read any supported log into a :class:`~mavsid.data.RawLog`.

    Parameters
    ----------
    path : path-like
        The log file; its format is found from its content.
    messages : sequence of str, optional
        Decode only these message types (topics for ULog); default all.
    start, stop : float, optional
        Keep only samples with ``start <= time_s <= stop`` (seconds, log clock).
    **options
        Passed to the format's reader (e.g. ``dialect`` for .tlog).

    Raises
    ------
    LogFormatError
        Unknown format, or nothing decodable in the file.
    ConfigError
        A ``dialect`` for a log that is not a .tlog, or an unknown dialect.
    """
    fmt = sniff_format(path)
    if "dialect" in options and fmt != "tlog":
        raise ConfigError(f"{path}: a MAVLink dialect applies to .tlog files only, not {fmt}")
    module = importlib.import_module(READERS[fmt])
    try:
        result: RawLog = module.read(path, messages=messages, start=start, stop=stop,
                                     **options)
    except MavsidError as exc:  # every error names the file
        named = naming_file(exc, os.fspath(path))
        if named is exc:
            raise
        raise named from exc
    return result
