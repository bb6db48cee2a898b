"""Watch a live test from a browser: rerun's web viewer (shipped with rerun-sdk 0.41) on a local port.

`WebViewer(port)` starts rerun's own server — the `rerun` executable that rerun-sdk installs with
`rerun_cli` — in a child process: the viewer's page over HTTP on `port`, and the gRPC message proxy
the page reads the stream from on `port + 1`. The proxy buffers the stream (up to
`server_memory_limit`, the oldest data dropped past it), so a browser that opens the page late, or
reloads it, still gets the test from its start. A test's `Recording` streams into it through
`connect=viewer.grpc_url`, with the recording's blueprint (`htm.record.streams.blueprint`), so the
page opens laid out like `recording.rrd` does.

A child process rather than `rerun.serve_grpc` in this one: a gRPC server the SDK hosts lives and
dies with one recording stream (a test's ends when the test closes), and a second stream to host it
would show in the viewer as a second, empty recording. The child is ended with this process
(`close`, and on Linux by the kernel if this process dies).

`serving(cmd)` wraps `htm run` and `htm resume`: with `--serve-web [PORT]` the viewer starts before
the test, the test streams to it, and after the test it keeps serving until Ctrl-C.

`serve_live(port)` serves every test this process records from then on (the console's key, a
`Session` script): a `Recording` opened without `connect` or `spawn` streams to the live viewer.
"""
from __future__ import annotations

import atexit
import contextlib
import functools
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any
from urllib.parse import quote

from htm.errors import HtmError

DEFAULT_PORT = 9090
START_TIMEOUT_S = 20.0


def rerun_executable() -> Path:
    """The `rerun` executable that rerun-sdk installs (`rerun_cli/rerun`), whether or not its
    folder is on PATH."""
    try:
        import rerun_cli
    except ImportError:
        raise HtmError("the web viewer needs rerun-sdk's rerun_cli (pip install rerun-sdk)") from None
    exe = Path(rerun_cli.__file__).parent / "rerun"
    if not exe.is_file():
        raise HtmError(f"the web viewer needs the rerun executable, not found at {exe} (reinstall rerun-sdk)")
    return exe


def _port_free(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def _listening(port: int) -> bool:
    with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), timeout=0.5):
        return True
    return False


def _die_with_parent() -> None:  # pragma: no cover - runs in the child between fork and exec
    """The child gets SIGTERM when this process dies, however it dies (Linux prctl PR_SET_PDEATHSIG)."""
    with contextlib.suppress(Exception):
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)


class WebViewer:
    """rerun's web viewer and its stream proxy, served from this machine.

    Parameters
    ----------
    port : int
        The page's HTTP port; the stream's gRPC proxy takes ``port + 1``. Both must be free.
    bind : str
        The address both listen on: ``"0.0.0.0"`` (every interface, so the page can be opened from
        another machine) or ``"127.0.0.1"`` (this machine only).
    server_memory_limit : str
        How much of the stream the proxy keeps for late browsers (rerun's syntax: ``"1GiB"``, ``"25%"``).
    """

    def __init__(self, port: int = DEFAULT_PORT, *, bind: str = "0.0.0.0", server_memory_limit: str = "1GiB"):
        if not 0 < port < 65535:
            raise HtmError(f"web viewer port {port}: a port is 1 to 65534 (the stream takes the next one)")
        self.port, self.grpc_port, self.bind = port, port + 1, bind
        for p in (self.port, self.grpc_port):
            if not _port_free(bind, p):
                raise HtmError(f"web viewer: port {p} on {bind} is in use; give another port "
                               f"(the page takes PORT, the stream PORT+1); nothing was run")
        cmd = [str(rerun_executable()), "--serve-web", "--bind", bind, "--port", str(self.grpc_port),
               "--web-viewer-port", str(self.port), "--server-memory-limit", server_memory_limit,
               # a page opened by this host's name or address (from the office) reads the stream from the
               # same host: allow its origin, on the page's port only
               "--cors-allow-origin", f"http://*:{self.port}"]
        self.log = tempfile.TemporaryFile()  # the server's log (a pipe nobody reads would fill and block it)
        self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=self.log, stderr=self.log, preexec_fn=_die_with_parent)
        t0 = time.monotonic()
        while not (_listening(self.port) and _listening(self.grpc_port)):
            if self.proc.poll() is not None or time.monotonic() - t0 > START_TIMEOUT_S:
                err = self._stop()
                raise HtmError(f"web viewer on port {port}: rerun's web viewer did not start ({err or 'no message'})")
            time.sleep(0.05)

    @property
    def grpc_url(self) -> str:
        """Where this machine's recording streams to (`Recording(connect=...)`)."""
        return f"rerun+http://127.0.0.1:{self.grpc_port}/proxy"

    def page_url(self, host: str = "127.0.0.1") -> str:
        """The page to open in a browser, as seen from a machine that reaches this one as `host`:
        the viewer with the stream's address in its ``url`` query."""
        return f"http://{host}:{self.port}/?url=" + quote(f"rerun+http://{host}:{self.grpc_port}/proxy", safe="")

    def page_urls(self) -> list[str]:
        """The page's address on this machine and, when bound to every interface, by this host's name."""
        urls = [self.page_url()]
        if self.bind in ("0.0.0.0", "::"):
            urls.append(self.page_url(socket.gethostname()))
        return urls

    def linger(self) -> None:
        """Keep serving (the test is over, its stream stays on the page) until Ctrl-C or SIGTERM."""
        print(f"the web viewer keeps serving at {self.page_urls()[-1]} — Ctrl-C to stop", file=sys.stderr, flush=True)
        sys.stderr.flush()
        old = signal.signal(signal.SIGTERM, signal.default_int_handler)
        try:
            while self.proc.poll() is None:
                time.sleep(0.2)
            print(f"the web viewer stopped (exit {self.proc.returncode})", file=sys.stderr)
        except KeyboardInterrupt:
            pass
        finally:
            signal.signal(signal.SIGTERM, old)

    def _stop(self) -> str:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.log.closed:
            return ""
        self.log.seek(0)
        err = self.log.read().decode(errors="replace")
        self.log.close()
        lines = [ln.strip() for ln in err.splitlines() if "rror" in ln]
        return lines[-1][-300:] if lines else ""

    def close(self) -> None:
        """Stop the viewer and its stream proxy."""
        self._stop()

    def __enter__(self) -> WebViewer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_live: WebViewer | None = None


def serve_live(port: int | None = None, **kw: Any) -> WebViewer:
    """Serve every test recorded by this process from now on to rerun's web viewer (the same
    viewer again if one is already serving); it stops when the process exits or `stop_live()`.
    The page's port: `port`, else `$HTM_WEB_PORT`, else 9090 (the stream on the next one)."""
    global _live
    if _live is None or _live.proc.poll() is not None:
        if port is None:
            env = os.environ.get("HTM_WEB_PORT", "")
            if env and not env.isdigit():
                raise HtmError(f"HTM_WEB_PORT={env!r} is not a port number")
            port = int(env) if env else DEFAULT_PORT
        _live = WebViewer(port, **kw)
        atexit.register(stop_live)
    return _live


def live_url() -> str | None:
    """The stream address of the live viewer `serve_live` started, or None."""
    return _live.grpc_url if _live is not None and _live.proc.poll() is None else None


def stop_live() -> None:
    """Stop the live viewer, if any."""
    global _live
    if _live is not None:
        _live.close()
        _live = None


def serving(cmd: Callable[[Any], int]) -> Callable[[Any], int]:
    """Wrap a command that records a test (`htm run`, `htm resume`) for ``--serve-web [PORT]``:
    start the web viewer, stream the test to it (``args.connect``), and after the test keep
    serving until Ctrl-C. Without the option the command runs as it is."""

    @functools.wraps(cmd)
    def run(args: Any) -> int:
        port = getattr(args, "serve_web", None)
        if port is None or getattr(args, "check", False):
            return cmd(args)
        if getattr(args, "no_recording", False) or getattr(args, "no_store", False):
            raise HtmError("--serve-web streams the test's recording: drop --no-recording / --no-store")
        with WebViewer(port) as viewer:
            print("watch the test in a browser: " + "  or  ".join(viewer.page_urls()), file=sys.stderr, flush=True)
            args.connect = viewer.grpc_url
            rc = cmd(args)
            sys.stdout.flush()
            viewer.linger()
        return rc

    return run
