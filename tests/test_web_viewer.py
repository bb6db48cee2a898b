"""Watching a test from a browser: `htm run --serve-web PORT` serves the live rerun stream to rerun's
web viewer, and a real browser — Debian's headless Chromium, driven over its DevTools protocol —
opens the page: the title is the viewer's, the page throws nothing and logs no error of its own,
and it connects to the stream (its gRPC-web read on PORT+1 answers 200 and brings the test's bytes).
The server's side is read back by a second, late client (`rerun --save`): every entity of the
recording's layout is there, with the recording's blueprint. `.ci/run` installs Chromium when missing."""
from __future__ import annotations

import json
import os
import random
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

import pytest

from htm.record import streams
from htm.record.web import rerun_executable

ROOT = Path(__file__).resolve().parents[1]
HTM = [sys.executable, "-m", "htm.cli"]
VIEW_COUNT = len(streams.CYCLE_GROUPS) + len(streams.SIGNAL_GROUPS) + 2  # + da/dN–ΔK, events


def chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    raise AssertionError("no Chromium on PATH: `apt-get install chromium` (.ci/run installs it)")


def free_pair() -> int:
    """A port P with P and P+1 free on every interface."""
    for _ in range(200):
        p = random.randrange(20000, 60000)
        ok = True
        for q in (p, p + 1):
            with socket.socket() as s:
                try:
                    s.bind(("0.0.0.0", q))
                except OSError:
                    ok = False
        if ok:
            return p
    raise AssertionError("no two free consecutive ports")


def read_line(proc: subprocess.Popen, needle: str, timeout_s: float, seen: list[str]) -> str:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        line = proc.stdout.readline()
        if not line:
            break
        seen.append(line)
        if needle in line:
            return line
    raise AssertionError(f"`{needle}` not printed within {timeout_s} s; output:\n{''.join(seen)}")


WANT = {f"/{e}" for e in (*streams.CYCLE_GROUPS, *streams.SIGNAL_GROUPS, "crack/dadn_vs_delta_k", "events")}


def served_entities(grpc_port: int, saved: Path, want: set[str] = WANT, timeout_s: float = 30) -> tuple[set[str], int]:
    """What the stream proxy on `grpc_port` serves a client that connects now (`rerun --save`):
    its entity paths and the number of views of its blueprint."""
    exe = str(rerun_executable())
    late = subprocess.Popen([exe, "--save", str(saved), f"rerun+http://127.0.0.1:{grpc_port}/proxy", "--port", str(free_pair())],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    entities: set[str] = set()
    views = 0
    try:
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout_s:
            time.sleep(1)
            if not saved.exists():
                continue
            out = subprocess.run([exe, "rrd", "print", str(saved)], capture_output=True, text=True, timeout=60).stdout
            entities = {ln.split(" - ")[1] for ln in out.splitlines() if ln.startswith("Chunk(") and ln.count(" - ") >= 2}
            views = len({e.split("/")[2] for e in entities if e.startswith("/view/")})
            if want <= entities and views >= VIEW_COUNT:
                break
    finally:
        late.terminate()
        late.wait(10)
    return entities, views


class DevTools:
    """A minimal Chrome DevTools Protocol client over one page's websocket."""

    def __init__(self, ws_url: str):
        import websocket

        self.ws = websocket.create_connection(ws_url, timeout=30)
        self.n = 0
        self.events: list[dict] = []

    def send(self, method: str, **params) -> int:
        self.n += 1
        self.ws.send(json.dumps({"id": self.n, "method": method, "params": params}))
        return self.n

    def call(self, method: str, **params) -> dict:
        i = self.send(method, **params)
        while True:
            msg = json.loads(self.ws.recv())
            if msg.get("id") == i:
                assert "error" not in msg, msg
                return msg["result"]
            if "method" in msg:
                self.events.append(msg)

    def pump(self, seconds: float, until=None) -> None:
        import websocket

        self.ws.settimeout(0.5)
        t0 = time.monotonic()
        try:
            while time.monotonic() - t0 < seconds:
                try:
                    msg = json.loads(self.ws.recv())
                except websocket.WebSocketTimeoutException:
                    continue
                if "method" in msg:
                    self.events.append(msg)
                    if until is not None and until(self.events):
                        return
        finally:
            self.ws.settimeout(30)


@pytest.fixture
def served(tmp_path):
    """`htm run` of the README's main job with --serve-web, past its end (serving until stopped)."""
    port = free_pair()
    env = dict(os.environ, HTM_STORE=str(tmp_path / "store"), PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([*HTM, "run", str(ROOT / "examples/ct_constant_force.toml"), "--out", str(tmp_path / "out"),
                             "--quiet", "--serve-web", str(port)], cwd=tmp_path, env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            # as from a terminal: Ctrl-C delivered (a suite run as a background job inherits
                            # SIGINT ignored, and Python then keeps it ignored)
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    seen: list[str] = []
    try:
        first = read_line(proc, "watch the test in a browser:", 60, seen)
        read_line(proc, "keeps serving at", 120, seen)  # the test is over; its stream stays served
        # go on reading what it prints, so that a full pipe never blocks it
        threading.Thread(target=lambda: seen.extend(proc.stdout), daemon=True).start()
        proc.seen = seen  # type: ignore[attr-defined]  # what it printed, for a failure's message
        yield port, first.split(": ", 1)[1].split()[0], proc, tmp_path
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def test_the_web_viewer_loads_connects_and_serves_the_tests_stream(served):
    port, url, proc, tmp = served
    assert url == f"http://127.0.0.1:{port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{port + 1}%2Fproxy"

    # the browser: headless, software WebGL, every host but this one unreachable (the same offline or not)
    profile = tempfile.mkdtemp(dir=tmp)
    debug_port = free_pair()
    browser = subprocess.Popen([chromium(), "--headless=new", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
                                "--enable-unsafe-swiftshader", f"--remote-debugging-port={debug_port}", f"--user-data-dir={profile}",
                                "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1", "--no-first-run", "about:blank"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        for _ in range(300):
            try:
                tabs = json.load(urllib.request.urlopen(f"http://127.0.0.1:{debug_port}/json", timeout=2))
                break
            except OSError:
                time.sleep(0.1)
        else:
            raise AssertionError("Chromium's DevTools endpoint did not come up")
        page = next(t for t in tabs if t["type"] == "page")
        cdp = DevTools(page["webSocketDebuggerUrl"])
        for domain in ("Runtime", "Log", "Network", "Page"):
            cdp.call(f"{domain}.enable")
        cdp.call("Page.navigate", url=url)

        stream_path = "/rerun.sdk_comms.v1alpha1.MessageProxyService/ReadMessages"
        stream_url = f"http://127.0.0.1:{port + 1}{stream_path}"
        reads: set[str] = set()

        def received(events) -> int:
            for e in events:
                if e["method"] == "Network.requestWillBeSent" and e["params"]["request"]["url"] == stream_url:
                    reads.add(e["params"]["requestId"])
            return sum(e["params"]["dataLength"] for e in events if e["method"] == "Network.dataReceived" and e["params"]["requestId"] in reads)

        rrd = next((tmp / "store" / "tests").glob("*/recording.rrd"))
        # the stream carries the whole recording; the page has connected once it took most of its bytes
        cdp.pump(60, until=lambda ev: received(ev) > rrd.stat().st_size // 2)
        cdp.pump(3)  # errors that follow the connection
        # the page's title as the browser lists it (the page's own thread is busy drawing)
        tabs = json.load(urllib.request.urlopen(f"http://127.0.0.1:{debug_port}/json", timeout=10))
        title = next(t["title"] for t in tabs if t["id"] == page["id"])
        ev = cdp.events
    finally:
        browser.terminate()
        browser.wait(10)

    assert title == "Rerun Viewer"
    statuses = [e["params"]["response"]["status"] for e in ev
                if e["method"] == "Network.responseReceived" and e["params"]["response"]["url"] == stream_url]
    assert statuses and set(statuses) == {200}, f"the page's reads of the stream: {statuses}"
    got = received(ev)
    assert got > rrd.stat().st_size // 2, f"the page received {got} bytes of the stream; the recording is {rrd.stat().st_size}"

    # no exception; no error but the fetches of other hosts that the viewer tries (fonts, its version
    # check, examples, telemetry), each failed with the host unreachable
    assert not [e for e in ev if e["method"] == "Runtime.exceptionThrown"], "the page threw"
    failed_requests = {e["params"]["requestId"] for e in ev if e["method"] == "Network.loadingFailed"}
    urls = {e["params"]["requestId"]: e["params"]["request"]["url"] for e in ev if e["method"] == "Network.requestWillBeSent"}
    own = [urls.get(r, r) for r in failed_requests if urls.get(r, "").startswith("http://127.0.0.1")]
    assert not own, f"requests to this machine failed: {own}"
    offhost = len(failed_requests)
    log_errors = [e["params"]["entry"] for e in ev if e["method"] == "Log.entryAdded" and e["params"]["entry"]["level"] == "error"]
    assert all("ERR_NAME_NOT_RESOLVED" in x["text"] and not x.get("url", "").startswith("http://127.0.0.1") for x in log_errors), log_errors
    console_errors = [" ".join(str(a.get("value", a.get("description", ""))) for a in e["params"]["args"])
                      for e in ev if e["method"] == "Runtime.consoleAPICalled" and e["params"]["type"] == "error"]
    unexplained = [c for c in console_errors if not c.startswith("TypeError: Failed to fetch")]
    assert not unexplained, f"console errors of the page: {unexplained}"
    assert len(console_errors) <= offhost, (console_errors, offhost)

    # the server's side, read back by a late client: every entity of the layout and the blueprint's views
    entities, views = served_entities(port + 1, tmp / "late.rrd")
    assert WANT <= entities, f"the server lacks {sorted(WANT - entities)}"
    assert views == VIEW_COUNT, f"the blueprint served has {views} views, the recording's layout {VIEW_COUNT}"

    # stopping the server: Ctrl-C ends `htm run` cleanly, the test recorded as finished
    proc.send_signal(signal.SIGINT)
    t_int = time.monotonic()
    try:
        rc = proc.wait(60)  # the viewer's server gets 5 s to stop, then is killed
    except subprocess.TimeoutExpired:
        raise AssertionError("htm run did not end within 60 s of Ctrl-C; it printed:\n" + "".join(proc.seen[-20:])) from None
    assert rc == 0, f"exit {rc} after Ctrl-C ({time.monotonic() - t_int:.1f} s)"
    listed = subprocess.run([*HTM, "db", "list"], cwd=tmp, env=dict(os.environ, HTM_STORE=str(tmp / "store")),
                            capture_output=True, text=True, timeout=60)
    assert " finished " in listed.stdout, listed.stdout


def test_serve_web_on_a_port_in_use_is_one_line_and_exit_2(tmp_path):
    port = free_pair()
    with socket.socket() as s:
        s.bind(("0.0.0.0", port + 1))
        s.listen()
        p = subprocess.run([*HTM, "run", str(ROOT / "examples/ct_constant_force.toml"), "--out", str(tmp_path / "out"), "--quiet",
                            "--serve-web", str(port)], cwd=tmp_path, env=dict(os.environ, HTM_STORE=str(tmp_path / "store")),
                           capture_output=True, text=True, timeout=60)
    assert p.returncode == 2, p.stderr
    assert "Traceback" not in p.stderr
    err = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(err) == 1 and f"port {port + 1}" in err[0] and "in use" in err[0], p.stderr
    assert not (tmp_path / "store" / "tests").exists() or not any((tmp_path / "store" / "tests").iterdir()), "nothing was run"


def test_serve_web_needs_the_recording(tmp_path):
    p = subprocess.run([*HTM, "run", str(ROOT / "examples/ct_constant_force.toml"), "--out", str(tmp_path / "out"), "--quiet",
                        "--no-recording", "--serve-web", str(free_pair())], cwd=tmp_path,
                       env=dict(os.environ, HTM_STORE=str(tmp_path / "store")), capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and "--serve-web" in p.stderr and "Traceback" not in p.stderr, p.stderr


def test_the_consoles_key_serves_the_tests_it_records_to_the_web_viewer(store, monkeypatch):
    """ctrl+w in `htm-tui`: the tests recorded from then on stream to the web viewer (the live device
    loop's recording, through `htm.record.web.serve_live`)."""
    import asyncio

    from htm.record import web
    from htm.tui.app import HtmApp

    port = free_pair()
    monkeypatch.setenv("HTM_WEB_PORT", str(port))

    async def go():
        app = HtmApp(store=store)
        async with app.run_test(size=(160, 60)) as pilot:
            t0 = time.monotonic()
            while app.session is None and time.monotonic() - t0 < 30:
                await pilot.pause(0.1)
            await pilot.press("ctrl+w")
            await pilot.pause(0.5)
            assert web.live_url() == f"rerun+http://127.0.0.1:{port + 1}/proxy"
            assert any(f":{port}/" in str(n.message) for n in app._notifications), "the console names the page"
            await pilot.press("f4", "s")
            while app.session.snapshot()["cycles"] < 20 and time.monotonic() - t0 < 90:
                await pilot.pause(0.2)
            await pilot.press("x")
            while not (app.session.recorder is not None and app.session.recorder.status is not None) and time.monotonic() - t0 < 120:
                await pilot.pause(0.2)

    try:
        asyncio.run(go())
        entities, _ = served_entities(port + 1, store.parent / "late.rrd", want={"/cycle/force_n", "/events"})
        assert {"/cycle/force_n", "/events"} <= entities, f"the console's test is not on the web viewer: {sorted(entities)}"
    finally:
        web.stop_live()
    assert web.live_url() is None
