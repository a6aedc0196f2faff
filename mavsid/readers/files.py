"""What every reader does with its file before decoding: open it, map it, refuse options.

Each reader module's ``read(path, messages=None, start=None, stop=None, **options)`` takes a
:data:`LogPath`; :func:`mapped` gives the file's bytes (memory-mapped, or read whole when
small) and turns any failure to open it into one :class:`~mavsid.errors.LogFormatError`
naming the file; :func:`refuse_options` is the one message for an option a format does not
take.

Examples
--------
>>> import os, tempfile
>>> with tempfile.NamedTemporaryFile(delete=False) as f:
...     _ = f.write(b"\\xa3\\x95\\x80")
>>> with mapped(f.name) as buf:
...     bytes(buf[:2])
b'\\xa3\\x95'
>>> os.unlink(f.name)
>>> refuse_options("x.bin", {"dialect": "common"}, "DataFlash .bin logs")
Traceback (most recent call last):
...
mavsid.errors.ConfigError: x.bin: option(s) dialect do not apply to DataFlash .bin logs
"""

from __future__ import annotations

import mmap
import os
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from typing import TypeAlias

from mavsid.errors import ConfigError, LogFormatError

__all__ = ["MAP_MIN", "LogPath", "mapped", "refuse_options"]

#: a log's path, as every reader takes it
LogPath: TypeAlias = str | os.PathLike[str]

#: files from this size on are memory-mapped; smaller ones are read whole (fewer system calls)
MAP_MIN = 1 << 16


@contextmanager
def mapped(path: LogPath, populate: bool = False) -> Iterator[mmap.mmap | bytes]:
    """The bytes of the file ``path``: memory-mapped (read-only; closed on leaving, unless a
    view of it is still referenced: then when collected), or read whole when smaller than
    :data:`MAP_MIN`.

    Parameters
    ----------
    path : path-like
    populate : bool
        Map every page at once where the system can (``MAP_POPULATE``), for a reader that
        walks the whole file: faulting the pages in one by one is slower.

    Raises
    ------
    LogFormatError
        The file is empty, cannot be opened, or changed size while it was being mapped.
    """
    try:
        with open(path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            if size == 0:
                raise LogFormatError("empty file", path=path)
            buf: mmap.mmap | bytes
            if size < MAP_MIN:
                buf = f.read()
            elif populate and hasattr(mmap, "MAP_POPULATE"):
                buf = mmap.mmap(f.fileno(), 0, flags=mmap.MAP_SHARED | mmap.MAP_POPULATE,
                                prot=mmap.PROT_READ)
            else:
                buf = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
    except OSError as exc:
        raise LogFormatError(f"cannot open: {exc.strerror or exc}", path=path) from None
    try:
        if len(buf) != size:
            raise LogFormatError("file changed while reading", path=path)
        yield buf
    finally:
        if isinstance(buf, mmap.mmap):
            try:
                buf.close()
            except BufferError:  # a view is still referenced somewhere: leave it to the GC
                pass


def refuse_options(path: LogPath, options: Mapping[str, object], what: str) -> None:
    """Raise :class:`~mavsid.errors.ConfigError` when ``options`` (a reader's ``**options``)
    holds any: none applies to ``what`` (e.g. ``"DataFlash text logs"``)."""
    if options:
        names = ", ".join(sorted(options))
        raise ConfigError(f"{os.fspath(path)}: option(s) {names} do not apply to {what}")
