"""Output files the commands write: checked before the work starts, written atomically.

A fit can take minutes; an output path that cannot be written should stop it before, not
after. An output that is one of the inputs (the same file, through a symlink or a hard link
too) is refused: ``mavsid fit LOG -o LOG`` must never replace a flight log with JSON. Every
output is written to a temporary file beside it and renamed over the target only when
complete, so an interrupted run leaves either the old file or the new one, never half of one.

Examples
--------
>>> import os, tempfile
>>> d = tempfile.mkdtemp()
>>> log = os.path.join(d, "a.bin")
>>> _ = open(log, "wb").write(b"x")
>>> check_outputs([os.path.join(d, "model.json")], [log])
>>> check_outputs([log], [log])
Traceback (most recent call last):
...
mavsid.errors.ConfigError: ...a.bin: is an input of this command; refusing to overwrite it
>>> with atomic_path(os.path.join(d, "m.json")) as tmp:
...     _ = open(tmp, "w").write("{}")
>>> open(os.path.join(d, "m.json")).read(), [f for f in os.listdir(d) if ".tmp" in f]
('{}', [])
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterable, Iterator

from mavsid.errors import ConfigError

__all__ = ["atomic_path", "check_outputs"]

PathLike = str | os.PathLike[str]


def _same(a: str, b: str) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def check_outputs(outputs: Iterable[PathLike | None], inputs: Iterable[PathLike] = ()) -> None:
    """Refuse outputs that are inputs, directories, or in a folder that cannot be written.

    Raises
    ------
    ConfigError
        One line naming the path and why.
    """
    ins = [os.fspath(p) for p in inputs]
    seen: list[str] = []
    for out in outputs:
        if out is None or out == "":
            continue
        path = os.fspath(out)
        if any(_same(path, p) for p in ins if os.path.exists(p)):
            raise ConfigError(f"{path}: is an input of this command; refusing to overwrite it")
        if any(_same(path, s) for s in seen):
            raise ConfigError(f"{path}: given as two outputs of one command")
        seen.append(path)
        if os.path.isdir(path):
            raise ConfigError(f"{path}: is a directory, not an output file")
        folder = os.path.dirname(os.path.abspath(path))
        if not os.path.isdir(folder):
            raise ConfigError(f"{path}: folder {folder} does not exist")
        if not os.access(folder, os.W_OK | os.X_OK):
            raise ConfigError(f"{path}: folder {folder} is not writable")
        if os.path.exists(path) and not os.access(path, os.W_OK):
            raise ConfigError(f"{path}: exists and is not writable")


@contextlib.contextmanager
def atomic_path(path: PathLike) -> Iterator[str]:
    """A temporary path beside ``path`` (same suffix) to write to; renamed over ``path`` when
    the block ends without an exception, removed otherwise.

    Raises
    ------
    ConfigError
        The temporary file cannot be created or renamed (one line naming ``path``).
    """
    target = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(target))
    stem, suffix = os.path.splitext(os.path.basename(target))
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{stem}.", suffix=f".tmp{suffix}", dir=folder)
    except OSError as exc:
        raise ConfigError(f"{target}: cannot write: {exc.strerror or exc}") from None
    os.close(fd)
    try:
        yield tmp
        mode = 0o666 & ~_umask()
        os.chmod(tmp, mode)
        os.replace(tmp, target)
    except OSError as exc:
        raise ConfigError(f"{target}: cannot write: {exc.strerror or exc}") from None
    finally:
        with contextlib.suppress(OSError):
            os.remove(tmp)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
