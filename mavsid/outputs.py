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
import pickle
import signal
import sys
import tempfile
import threading
from collections.abc import Iterable, Iterator
from typing import Any

from mavsid import errors
from mavsid.errors import ConfigError, MavsidError

__all__ = ["ReportWorker", "atomic_path", "check_outputs"]

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


# --------------------------------------------------------------------------- report worker
_SERVE = "from mavsid.outputs import _serve_report; _serve_report()"


class ReportWorker:
    """:func:`mavsid.report.write_report` in a process of its own, started when a command
    begins: it imports matplotlib and the report (~0.5 s) while this process reads and fits
    the logs, then draws the report (~1.5 s on a 100 MB flight) while this one writes the
    other outputs (the ``.rrd``: ~1 s with rerun's import). On two cores ``fit --rrd
    --report`` of the SITL flight then ends when the report does.

    Use it as a context manager: leaving the block without :meth:`wait` ends the process
    (a fit that failed, Ctrl-C), and no file it was writing is left behind (the caller's
    :func:`atomic_path` removes it).

    Examples
    --------
    >>> with ReportWorker() as worker:  # a command that fails before its outputs
    ...     pass
    >>> worker.returncode is not None
    True
    """

    def __init__(self) -> None:
        import subprocess  # (not at import: 4 ms of every command's start)

        root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        paths = [root, *filter(None, [os.environ.get("PYTHONPATH")])]  # this mavsid first
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(paths)}
        self._proc: subprocess.Popen[bytes] = subprocess.Popen(
            [sys.executable, "-c", _SERVE], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
            env=env)
        self._feeder: threading.Thread | None = None
        self._target = ""

    @staticmethod
    def available() -> bool:
        """Whether a worker is worth starting: an interpreter to start (not a frozen app)
        and a core to spare — two usable cores or more, the last minute's load average
        leaving one idle (as ``make --load-average`` judges it). The worker costs ~1 s of
        CPU of its own (its imports): on a machine whose cores are all busy it only adds
        that (``fit --rrd --report`` of the SITL flight 6.4 s against 5.9 s at load ~2 on
        two cores)."""
        if not sys.executable or getattr(sys, "frozen", False):
            return False
        try:
            cores = len(os.sched_getaffinity(0))
        except AttributeError:  # (not on Linux)
            cores = os.cpu_count() or 1
        try:
            load = os.getloadavg()[0]
        except (AttributeError, OSError):  # (Windows: no load average)
            load = 0.0
        return cores >= 2 and load <= cores - 1

    @property
    def returncode(self) -> int | None:
        return self._proc.returncode

    def start(self, result: Any, path: str, target: str) -> None:
        """Hand the worker ``result`` to write to ``path`` (a temporary file of ``target``,
        the output named in errors); returns at once (a thread feeds the pipe)."""
        self._target = target
        stdin = self._proc.stdin
        assert stdin is not None

        def feed() -> None:
            with contextlib.suppress(OSError):  # the worker died: wait() says so
                with stdin:
                    pickle.dump((result, path), stdin, protocol=pickle.HIGHEST_PROTOCOL)

        self._feeder = threading.Thread(target=feed, daemon=True)
        self._feeder.start()

    def wait(self) -> None:
        """Wait for the report.

        Raises
        ------
        MavsidError
            What stopped it, one line naming the output (of the class the worker raised:
            :class:`~mavsid.errors.ConfigError` when the file could not be written); a
            defect's traceback is printed by the worker itself.
        """
        if self._feeder is not None:
            self._feeder.join()
        assert self._proc.stdout is not None
        said = self._proc.stdout.read().decode("utf-8", "replace").strip()
        if self._proc.wait() == 0:
            return
        kind, _, message = said.partition("\t")
        cls = getattr(errors, kind, None)
        if not (isinstance(cls, type) and issubclass(cls, MavsidError) and message):
            cls, message = MavsidError, "the report could not be drawn (the error above)"
        raise cls(f"{self._target}: {message}")

    def __enter__(self) -> ReportWorker:
        return self

    def __exit__(self, *exc: object) -> None:
        if self._proc.poll() is None:
            self._proc.kill()
        for stream in (self._proc.stdin, self._proc.stdout):
            with contextlib.suppress(OSError):
                if stream is not None:
                    stream.close()
        self._proc.wait()


def _serve_report() -> None:
    """The worker's side of :class:`ReportWorker`: import the report, read ``(result,
    path)`` from standard input, write it; a :class:`~mavsid.errors.MavsidError` or a file
    that cannot be written is one line ``class<TAB>message`` on standard output, exit 1."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the command's Ctrl-C ends it, not this
    from mavsid import loop, pipeline, report  # noqa: F401  (while the logs are fitted)

    report.warm_up()
    try:
        result, path = pickle.load(sys.stdin.buffer)
    except EOFError:  # the command stopped before its outputs
        return
    try:
        report.write_report(result, path)
    except MavsidError as exc:
        print(f"{type(exc).__name__}\t{exc}", flush=True)
        sys.exit(1)
    except OSError as exc:
        print(f"ConfigError\tcannot write: {exc.strerror or exc}", flush=True)
        sys.exit(1)
