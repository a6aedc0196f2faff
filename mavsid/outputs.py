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
import functools
import os
import pickle
import signal
import sys
import tempfile
from collections.abc import Callable, Iterable, Iterator
from typing import IO, Any, NoReturn, TypeVar

from mavsid import errors
from mavsid.errors import ConfigError, MavsidError

_T = TypeVar("_T")

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
    the block ends without an exception, removed otherwise. A symbolic link's file is
    replaced, not the link; a device or a pipe (``/dev/stdout``, a FIFO) is written in place
    (renaming over one replaced the device node: as root, ``-o /dev/full`` made it a file).

    Raises
    ------
    ConfigError
        The temporary file cannot be created or renamed, or the device not written (one
        line naming ``path``).
    """
    target = os.fspath(path)
    if os.path.exists(target) and not os.path.isfile(target):  # (directories: check_outputs)
        try:
            yield target
        except OSError as exc:
            raise ConfigError(f"{target}: cannot write: {exc.strerror or exc}") from None
        return
    shown, target = target, os.path.realpath(target)
    folder = os.path.dirname(target)
    stem, suffix = os.path.splitext(os.path.basename(target))
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{stem}.", suffix=f".tmp{suffix}", dir=folder)
    except OSError as exc:
        raise ConfigError(f"{shown}: cannot write: {exc.strerror or exc}") from None
    os.close(fd)
    try:
        yield tmp
        mode = 0o666 & ~_umask()
        os.chmod(tmp, mode)
        os.replace(tmp, target)
    except OSError as exc:
        raise ConfigError(f"{shown}: cannot write: {exc.strerror or exc}") from None
    finally:
        with contextlib.suppress(OSError):
            os.remove(tmp)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


# --------------------------------------------------------------------------- report worker
_SERVE = "from mavsid.outputs import _serve_report; _serve_report()"
#: Whether :class:`ReportWorker` forks this process (:class:`_Forked`) rather than start an
#: interpreter
FORK = sys.platform.startswith("linux") and hasattr(os, "fork")


class ReportWorker:
    """:func:`mavsid.report.write_report` in a process of its own, started when a command
    begins: it imports matplotlib, the report and python-control (the loop analysis's step
    responses) and builds the report's figures (:func:`mavsid.report.warm_up`; ~2 s of CPU)
    while this process reads and fits the logs; then works the loop analysis out
    (:func:`mavsid.loop.tune.tune_analysis`, ~0.4 s on a 100 MB flight), hands it back
    (:meth:`analysis`: the ``.rrd`` shows its gains) and draws the report (~1.3 s) while this
    one writes the other outputs (the ``.rrd``: ~0.8 s with rerun's import), the figures
    that need no analysis drawn meanwhile by a process forked from the worker
    (:func:`_drawn_aside`: this one waits once the ``.rrd`` is written). Worked out here,
    the analysis cost python-control's import too (1.3 s of CPU) after the fit.

    On Linux the worker is forked from this process once the modules of the result's
    classes are imported (:class:`_Forked`): a new interpreter imported them again, ~0.8 s
    of CPU (``fit --rrd --report`` of the SITL flight 7.8 -> 7.0 s of CPU, 11.8 -> 10.2 s
    wall median at load ~5 on two cores), and on a two-core machine its imports and
    figures were often not done when the fit was (the report began up to 0.25 s late).
    Elsewhere (``fork`` without ``exec`` is unsafe on macOS, absent on Windows) it is a
    new interpreter.

    The result goes over as a pickle in a temporary file (written at once, ~40 MB for the
    SITL flight), the pipe carrying only its name: fed through the pipe by a thread, its
    64 kB writes each waited for the interpreter lock while this process wrote the ``.rrd``,
    and the report began only when the ``.rrd`` was done (0.5 s later). The worker leaves
    without the interpreter's teardown once the report is written (freeing the result's
    objects took 0.4 s more).

    Use it as a context manager: leaving the block without :meth:`wait` ends the process
    (a fit that failed, Ctrl-C), and no file it was writing is left behind (the caller's
    :func:`atomic_path` removes it), nor the result's or the analysis's temporary file.

    Examples
    --------
    >>> with ReportWorker() as worker:  # a command that fails before its outputs
    ...     pass
    >>> worker.returncode is not None
    True
    """

    def __init__(self) -> None:
        import subprocess  # (not at import: 4 ms of every command's start)

        self._proc: subprocess.Popen[bytes] | _Forked
        if FORK:
            self._proc = _Forked()
        else:
            root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
            paths = [root, *filter(None, [os.environ.get("PYTHONPATH")])]  # this mavsid first
            env = {**os.environ, "PYTHONPATH": os.pathsep.join(paths)}
            self._proc = subprocess.Popen([sys.executable, "-c", _SERVE],
                                          stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env)
        self._handoff: str | None = None
        self._analysis: str | None = None  # (the file the worker puts the analysis in)
        self._answered = False  # (the worker's line about the analysis read)
        self._said = ""  # (that line when it was not about the analysis)
        self._ready = False  # (the analysis is in its file)
        self._target = ""

    @staticmethod
    def available() -> bool:
        """Whether a worker is worth starting: an interpreter to start (not a frozen app)
        and a core to spare — two usable cores or more, the last minute's load average
        leaving one idle (as ``make --load-average`` judges it), or, where it does not, the
        other processes using at most half a core less than that over the next 50 ms
        (:func:`_others_busy`): the load average also counts this user's own commands of
        the last minute (a loop of ``mavsid fit`` over logs kept it at 1-1.5 on an idle
        two-core machine and ran every report in-process: ``fit --rrd --report`` of the
        SITL flight 4.4 s median instead of 3.6). The worker costs CPU of its own (its
        imports, the figures built beforehand: ~1.7 s started afresh, ~1 s forked): on a
        machine whose cores are all busy it only adds that (6.4 s against 5.9 s at load ~2
        on two cores, started afresh)."""
        if not sys.executable or getattr(sys, "frozen", False):
            return False
        try:
            cores = len(os.sched_getaffinity(0))
        except AttributeError:  # (not on Linux)
            cores = os.cpu_count() or 1
        if cores < 2:
            return False
        try:
            load = os.getloadavg()[0]
        except (AttributeError, OSError):  # (Windows: no load average)
            load = 0.0
        if load <= cores - 1:
            return True
        others = _others_busy(0.05)
        return others is not None and others <= cores - 1.5

    @property
    def returncode(self) -> int | None:
        return self._proc.returncode

    def start(self, result: Any, path: str, target: str) -> bool:
        """Hand the worker ``result`` to write to ``path`` (a temporary file of ``target``,
        the output named in errors); returns once the result is on disk. False when it
        could not be put there (a full temporary folder): the caller draws the report
        itself (the worker, told nothing, ends). The worker works the loop analysis out
        first (:meth:`analysis`), then draws the report."""
        self._target = target
        self._analysis = _pickled(None)  # (the file the worker puts the analysis in)
        if self._analysis is not None:
            self._handoff = _pickled((result, path, self._analysis))
        if self._handoff is not None:
            self._line(self._handoff)
        self._close_stdin()
        return self._handoff is not None

    def analysis(self) -> Any:
        """The loop analysis of the result handed over (:func:`mavsid.loop.tune.
        tune_analysis`) as the worker worked it out for its report, once it has; None when
        it could not hand it back (it failed: :meth:`wait` says why)."""
        if self._read_answer() and self._analysis is not None:
            with contextlib.suppress(OSError, EOFError, pickle.UnpicklingError):
                return _unpickled(self._analysis)
        return None

    def _read_answer(self) -> bool:
        """Whether the worker's first line (read once) says the analysis is in its file
        (``analysis``); any other line is kept for :meth:`wait`."""
        if not self._answered:
            self._answered = True
            assert self._proc.stdout is not None
            line = self._proc.stdout.readline().decode("utf-8", "replace")
            self._ready = line == "analysis\n"
            self._said = "" if line in ("analysis\n", "no analysis\n") else line
        return self._ready

    def _line(self, text: str) -> None:
        stdin = self._proc.stdin
        with contextlib.suppress(OSError, ValueError):  # the worker died: wait() says so
            assert stdin is not None
            stdin.write(text.encode() + b"\n")
            stdin.flush()

    def _close_stdin(self) -> None:
        with contextlib.suppress(OSError):
            if self._proc.stdin is not None:
                self._proc.stdin.close()

    def wait(self) -> None:
        """Wait for the report.

        Raises
        ------
        MavsidError
            What stopped it, one line naming the output (of the class the worker raised:
            :class:`~mavsid.errors.ConfigError` when the file could not be written); a
            defect's traceback is printed by the worker itself.
        """
        assert self._proc.stdout is not None
        self._close_stdin()
        self._read_answer()
        said = (self._said + self._proc.stdout.read().decode("utf-8", "replace")).strip()
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
        for name in (self._handoff, self._analysis):  # (the worker removes the first)
            if name is not None:
                with contextlib.suppress(OSError):
                    os.unlink(name)


class _Forked:
    """The report worker forked from this process, once the modules of the result's
    classes are imported here (the fit needs them too): :func:`_serve_report` on two pipes,
    ended by ``os._exit`` whatever happens, never back in the command's code. What
    :class:`ReportWorker` asks of a :class:`subprocess.Popen`: ``stdin``, ``stdout``,
    ``returncode``, :meth:`poll`, :meth:`wait` and :meth:`kill`."""

    def __init__(self) -> None:
        from mavsid import estimators, excitation, frequency, pipeline  # noqa: F401
        from mavsid.loop import analysis, tune, twin  # noqa: F401

        down, to_child = os.pipe()
        from_child, up = os.pipe()
        for stream in (sys.stdout, sys.stderr):  # (else the child writes them out again)
            with contextlib.suppress(OSError, ValueError):
                stream.flush()
        pid = os.fork()
        if pid == 0:  # the worker
            os.close(to_child)
            os.close(from_child)
            _serve_forked(down, up)
        os.close(down)
        os.close(up)
        self.pid = pid
        self.stdin: IO[bytes] | None = open(to_child, "wb")  # (closed by ReportWorker)
        self.stdout: IO[bytes] | None = open(from_child, "rb")
        self.returncode: int | None = None

    def poll(self) -> int | None:
        if self.returncode is None:
            pid, status = os.waitpid(self.pid, os.WNOHANG)
            if pid:
                self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def wait(self) -> int:
        if self.returncode is None:
            _, status = os.waitpid(self.pid, 0)
            self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def kill(self) -> None:
        with contextlib.suppress(ProcessLookupError):
            os.kill(self.pid, signal.SIGKILL)


def _serve_forked(stdin: int, stdout: int) -> NoReturn:
    """The forked worker's life: :func:`_serve_report` reading the file descriptor ``stdin``
    and answering on ``stdout``; its exit code that of a worker started afresh (1 and a
    traceback on standard error for a defect)."""
    code = 1
    try:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)  # (the command's handler raises)
        sys.stdin = open(stdin, encoding="utf-8")
        sys.stdout = open(stdout, "w", encoding="utf-8")
        # a stream of its own: a thread of the command's (none in mavsid's) may have held
        # the lock of the one copied at the fork
        sys.stderr = open(2, "w", encoding="utf-8", errors="backslashreplace", closefd=False)
        _serve_report()
        code = 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    except BaseException:
        import traceback

        traceback.print_exc()
    finally:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        os._exit(code)


def _cpu_times() -> tuple[int, int, int] | None:
    """The machine's CPU time so far from ``/proc/stat`` (clock ticks): all, idle (with I/O
    wait) and the number of CPUs; None where there is no such file (not Linux).

    Niced processes' time counts as busy: with autogroup scheduling (Linux's default for
    desktop sessions) and in cgroups, niceness weighs only within a process's own group,
    and a nice-19 job of another session takes a core as much as one of nice 0 (two of
    them on two cores: ``fit --rrd --report`` of the SITL flight 7.2 s median with the
    worker, 5.7 s in-process).

    Examples
    --------
    >>> got = _cpu_times()
    >>> got is None or (got[0] >= got[1] >= 0 and got[2] >= 1)
    True
    """
    try:
        with open("/proc/stat", "rb") as f:
            lines = f.read().split(b"\n")
        ticks = [int(x) for x in lines[0].split()[1:9]]
    except (OSError, ValueError, IndexError):
        return None
    cpus = sum(1 for line in lines if line[:3] == b"cpu" and line[3:4].isdigit())
    return (sum(ticks), ticks[3] + ticks[4], cpus) if len(ticks) == 8 and cpus else None


def _others_busy(window_s: float) -> float | None:
    """How many CPUs the machine's other processes keep busy, measured over ``window_s``
    while this one sleeps; None where it cannot be measured."""
    import time

    first = _cpu_times()
    time.sleep(window_s)
    last = _cpu_times()
    if first is None or last is None or last[0] <= first[0]:
        return None
    total, idle = last[0] - first[0], last[1] - first[1]
    return last[2] * (total - idle) / total


def _pickled(obj: Any) -> str | None:
    """``obj`` pickled into a new temporary file: its name, None when it cannot be."""
    try:
        fd, name = tempfile.mkstemp(prefix="mavsid-report-", suffix=".pickle")
    except OSError:
        return None
    try:
        with os.fdopen(fd, "wb") as f:
            pickle.dump(obj, f, protocol=pickle.HIGHEST_PROTOCOL)
    except (OSError, pickle.PicklingError):
        with contextlib.suppress(OSError):
            os.unlink(name)
        return None
    return name


def _unpickled(name: str) -> Any:
    """The object pickled in the temporary file ``name``, which is then removed."""
    try:
        with open(name, "rb") as f:
            return pickle.load(f)
    finally:
        with contextlib.suppress(OSError):
            os.unlink(name)


def _drawn_aside(draw: Callable[[], _T]) -> Callable[[], _T]:
    """``draw()`` begun at once in a process forked from this one (the report worker: two
    cores, one of them this process's, the other's command writing its ``.rrd`` and then
    waiting): a function that returns what it drew (pickled through a pipe), or draws it
    then, here, when there was no fork or the process failed (a defect's traceback is then
    this process's).

    Examples
    --------
    >>> _drawn_aside(lambda: ["<p>drawn</p>"])()
    ['<p>drawn</p>']
    """
    if not FORK:
        return draw
    down, up = os.pipe()
    try:
        pid = os.fork()
    except OSError:
        os.close(down)
        os.close(up)
        return draw
    if pid == 0:  # (never back in the caller's code)
        code = 1
        try:
            os.close(down)
            for stream in (sys.stdin, sys.stdout):  # (the command reads to the worker's end)
                with contextlib.suppress(OSError, ValueError):
                    os.close(stream.fileno())
            with open(up, "wb") as f:
                pickle.dump(draw(), f, protocol=pickle.HIGHEST_PROTOCOL)
            code = 0
        finally:
            os._exit(code)
    os.close(up)

    def drawn() -> _T:
        with open(down, "rb") as f:
            data = f.read()
        _, status = os.waitpid(pid, 0)
        if os.waitstatus_to_exitcode(status) == 0 and data:
            with contextlib.suppress(pickle.UnpicklingError, EOFError):
                return pickle.loads(data)
        return draw()

    return drawn


def _serve_report() -> None:
    """The worker's side of :class:`ReportWorker`: import the report, read ``(result,
    path, file)`` from standard input, work the loop analysis out and hand it back (its
    pickle in ``file``, then a line ``analysis`` on standard output), write the report; a
    :class:`~mavsid.errors.MavsidError` or a file that cannot be written is one line
    ``class<TAB>message`` on standard output, exit 1."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the command's Ctrl-C ends it, not this
    # while the logs are fitted: the report's modules, those of the result's classes
    # (unpickling them here after the fit took 0.35 s) and python-control (the loop
    # analysis's step responses)
    import control  # noqa: F401

    from mavsid import estimators, excitation, frequency, pipeline, report  # noqa: F401
    from mavsid.loop.tune import tune_analysis  # (and the loop's other modules)

    report.warm_up()
    handoff = sys.stdin.readline().rstrip("\n")
    if not handoff:  # the command stopped before its outputs
        return
    result, path, put = _unpickled(handoff)
    # each axis's figures that need no loop analysis, drawn by a process of their own while
    # this one works the analysis out and draws the rest
    heads = _drawn_aside(functools.partial(report.axis_heads, result))
    analysis = tune_analysis(result)
    try:
        with open(put, "wb") as f:
            pickle.dump(analysis, f, protocol=pickle.HIGHEST_PROTOCOL)
    except (OSError, pickle.PicklingError):
        print("no analysis", flush=True)  # (the command works it out itself)
    else:
        print("analysis", flush=True)
    try:
        report.write_report(result, path, analysis=lambda: analysis, heads=heads)
    except MavsidError as exc:
        print(f"{type(exc).__name__}\t{exc}", flush=True)
        sys.exit(1)
    except OSError as exc:
        print(f"ConfigError\tcannot write: {exc.strerror or exc}", flush=True)
        sys.exit(1)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)  # (the report is closed; freeing the result's objects only costs time)
