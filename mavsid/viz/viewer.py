"""Where a recording goes: a rerun viewer process mavsid starts (native, or web viewer and
gRPC proxy) on ports free at the time, listening on one address, stopped with its whole
process group; a file, stdout or a viewer already running."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.parse
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import rerun as rr
import rerun.blueprint as rrb

from mavsid.errors import ConfigError

__all__ = [
    "Served",
    "free_port",
    "open_sink",
    "run_viewer",
    "serve_command",
    "stop_group",
    "viewer_command",
    "viewer_errors",
    "wait_listening",
]


@contextlib.contextmanager
def viewer_errors(viewer: str) -> Iterator[None]:
    """rerun's failure to reach a viewer, or the viewer's end (a ``RuntimeError`` when the
    recording is flushed), as one :class:`~mavsid.errors.ConfigError` line naming
    ``viewer`` (as :func:`mavsid.viz.series.write_errors` does for a file)."""
    try:
        yield
    except RuntimeError as exc:
        if "connect" not in str(exc):
            raise
        raise ConfigError(f"{viewer}: cannot reach the viewer ({exc})") from None



@dataclass(frozen=True)
class Served:
    """A rerun process started by :func:`open_sink` (web viewer and gRPC proxy, or a native
    viewer) and the ports it listens on."""

    url: str
    process: subprocess.Popen[bytes]
    ports: tuple[int, ...] = ()

    def close(self) -> None:
        """Stop the server and every process it started (``python -m rerun_cli`` runs the
        viewer binary as a child: the whole process group goes), freeing its ports."""
        stop_group(self.process)


def stop_group(process: subprocess.Popen[Any]) -> None:
    """Stop ``process`` and every process of its group (it was started with
    ``start_new_session=True``): SIGTERM, then SIGKILL to what is left after 10 s. The
    ``rerun`` command is a Python wrapper that runs the viewer binary as its child: killing
    the wrapper alone leaves the viewer running, listening on its port."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(process.pid, sig)
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:  # pragma: no cover
            continue
        if sig == signal.SIGTERM:  # (the wrapper is gone; its children may linger)
            time.sleep(0.2)
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(process.pid, signal.SIGKILL)
        break


def run_viewer(argv: Sequence[str], *, timeout_s: float, stdin: Any = None,
               env: Mapping[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """Run a rerun command to its end (``rerun --headless --screenshot-to PNG -``) in a
    process group of its own; on timeout (``subprocess.TimeoutExpired``), Ctrl-C or any
    error the whole group is stopped (:func:`stop_group`), the viewer with its wrapper.

    Examples
    --------
    >>> run_viewer([sys.executable, "-c", "print('ok')"], timeout_s=60).stdout
    'ok\\n'
    """
    process = subprocess.Popen(list(argv), stdin=stdin, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, env=env,
                               start_new_session=True)
    try:
        out, err = process.communicate(timeout=timeout_s)
    except BaseException:
        stop_group(process)
        process.communicate()
        raise
    stop_group(process)  # (whatever it left behind)
    return subprocess.CompletedProcess(list(argv), process.returncode, out, err)


def free_port(bind: str = "127.0.0.1") -> int:
    """A TCP port free on ``bind`` now (the OS's choice).

    Examples
    --------
    >>> 1024 <= free_port() <= 65535
    True
    """
    family = socket.AF_INET6 if ":" in bind else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as sock:
        sock.bind((bind, 0))
        return int(sock.getsockname()[1])


def serve_command(bind: str, grpc_port: int, web_port: int) -> list[str]:
    """The rerun CLI command that hosts the web viewer and the gRPC proxy on ``bind``.

    Examples
    --------
    >>> serve_command("127.0.0.1", 40001, 40002)[-7:]
    ['--serve-web', '--bind', '127.0.0.1', '--port', '40001', '--web-viewer-port', '40002']
    """
    return [sys.executable, "-m", "rerun_cli", "--serve-web", "--bind", bind,
            "--port", str(grpc_port), "--web-viewer-port", str(web_port)]


def viewer_command(bind: str, port: int) -> list[str]:
    """The rerun CLI command for a native viewer whose gRPC server listens on ``bind`` only
    (the SDK's ``spawn`` would listen on every interface).

    Examples
    --------
    >>> viewer_command("127.0.0.1", 40003)[-4:]
    ['--bind', '127.0.0.1', '--port', '40003']
    """
    return [sys.executable, "-m", "rerun_cli", "--bind", bind, "--port", str(port)]


def _client_host(bind: str) -> str:
    host = "127.0.0.1" if bind in ("0.0.0.0", "::", "") else bind
    return f"[{host}]" if ":" in host else host


def wait_listening(process: subprocess.Popen[bytes], host: str, port: int,
                   timeout_s: float = 20.0) -> None:
    """Return once ``host:port`` accepts connections; raise if the process exits first or
    the time runs out (never send data to a server that is not ours)."""
    deadline = time.monotonic() + timeout_s
    plain = host.strip("[]")
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise ConfigError(f"the rerun server exited (code {process.returncode}) before "
                              f"listening on {host}:{port}")
        try:
            with socket.create_connection((plain, port), timeout=0.5):
                return
        except OSError:
            time.sleep(0.1)
    stop_group(process)
    raise ConfigError(f"the rerun server did not listen on {host}:{port} within "
                      f"{timeout_s:.0f} s")


def open_sink(
    rec: rr.RecordingStream,
    bp: rrb.Blueprint,
    *,
    save: str | None = None,
    serve: bool = False,
    connect: bool = False,
    url: str | None = None,
    stdout: bool = False,
    headless: bool = False,
    bind: str = "127.0.0.1",
) -> Served | None:
    """Send ``rec`` where the ``view`` flags say.

    ``serve`` runs the rerun CLI's web viewer and gRPC proxy, ``spawn`` (the default) a
    native viewer; both listen on ``bind`` only (default 127.0.0.1: flight data is not
    published to the network unless asked) on ports free at the time, and data is sent only
    once the process mavsid started listens (a port held by another process is never sent
    to). Returns the process started (call :meth:`Served.close` when done; a spawned
    viewer is left running for the user).
    """
    if stdout:
        rec.stdout(default_blueprint=bp)
    elif serve:
        grpc_port, web_port = free_port(bind), free_port(bind)
        process = subprocess.Popen(serve_command(bind, grpc_port, web_port),
                                   start_new_session=True)
        host = _client_host(bind)
        wait_listening(process, host, grpc_port)
        grpc = f"rerun+http://{host}:{grpc_port}/proxy"
        rec.connect_grpc(grpc, default_blueprint=bp)
        web = f"http://{host}:{web_port}/?url={urllib.parse.quote(grpc, safe='')}"
        return Served(web, process, (grpc_port, web_port))
    elif connect:
        rec.connect_grpc(url, default_blueprint=bp)
    elif save is not None:
        rec.save(save, default_blueprint=bp)
    elif not headless:
        port = free_port(bind)
        process = subprocess.Popen(viewer_command(bind, port), start_new_session=True)
        host = _client_host(bind)
        wait_listening(process, host, port)
        rec.connect_grpc(f"rerun+http://{host}:{port}/proxy", default_blueprint=bp)
        return Served(f"rerun+http://{host}:{port}/proxy", process, (port,))
    return None
