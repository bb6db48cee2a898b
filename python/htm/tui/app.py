"""The console application: one tab per workflow, handset-like keys, a help screen.

The control loop runs on its own thread inside `htm.control.session.Session`; the console only
polls it (snapshot, decimated feed, new cycles, new events) at `POLL_HZ` and sends commands from
worker threads, so the loop never waits for the UI and a slow screen never piles up messages.
"""
from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import Any

from rich.markup import escape
from textual import work
from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.containers import VerticalScroll
from textual.css.query import NoMatches
from textual.screen import ModalScreen
from textual.widgets import Footer, Header, Markdown, RichLog, Static, TabbedContent, TabPane

from htm.errors import HtmError, InterlockTripped
from htm.tui.diagnose_pane import DiagnosePane
from htm.tui.identify import IdentifyPane
from htm.tui.install import InstallPane
from htm.tui.results import ResultsPane
from htm.tui.runpane import RunPane
from htm.tui.setup import SetupPane

POLL_HZ = 10.0  # ≤ 20 Hz: the console's view of the loop
PROTECT_FORCE_N = 2000.0  # specimen protect of the built-in virtual rig
# what a command does while the loop has not yet done it (motions and starts load the supply first)
PENDING = {"position": "switching to position control: loading the supply", "start": "starting the test: loading the supply",
           "jog": "jogging: loading the supply", "jog_step": "stepping: loading the supply",
           "move_to": "moving to the start position: loading the supply", "reset": "resetting the interlocks"}
EVENTS_HEADING = f"{'time [s]':>10}  {'event':<10} detail"


def virtual_rig_config(rate_hz: float = 500.0):
    """The built-in virtual rig: in-process, lock-step device path, specimen protect at 2 kN, an
    extensometer on ai7 (a life test's round bar carries it)."""
    from htm.devices.config import virtual_config

    return virtual_config("lockstep", rate_hz, position={"protect_force_n": PROTECT_FORCE_N},
                          analog={"channels": {"extensometer": "ai7"}})

KEYS = """\
# htm-tui keys

Like a controller handset: the keys act on the tab you are in; E-stop works everywhere.

| key | where | action |
|---|---|---|
| **F12** or **ctrl+e** | anywhere | **E-STOP**: valve null, amplifier off, supply unloaded; latched until reset |
| F1 or ? | anywhere | this help |
| F2 … F7 | anywhere | Setup, Install, Run, Results, Diagnose, Identify (the keys then act on that tab at once) |
| Tab / shift+Tab | anywhere | next / previous field or button; enter presses a button |
| ctrl+s | anywhere | simulate the Setup spec on the fast engine (predicted life, force errors), on the twin when Setup names a model.json |
| ↑ / ↓ | Install | jog up / down at the jog rate (position control, specimen protect on) |
| space | Install | stop jogging |
| [ / ] | Install | step down / up by the step size |
| + / − | Install | faster / slower jog rate and larger / smaller step |
| t | Install | tare the load cell |
| m | Install | move to the start position |
| o | Install | position control on (holds where the piston is) |
| s | Run | start the test (smooth ramp-in) |
| h / r | Run | hold (freeze at mean) / resume |
| x | Run | stop (ramp to mean, then null) |
| ctrl+r | Run | reset interlocks whose condition has gone |
| ↑ / ↓ | Results | select a test in the list (its summary, report and life band below) |
| ctrl+l | Results | refresh the list of tests |
| v | Results | open the selected test's rerun recording |
| b | Results | the selected test's life band, updated from its own first points (blank set: Virkler 2024-T3) |
| (fields) | Diagnose | record table and output folder, then Diagnose (enter) |
| (fields) | Identify | output folder and amplitude, then Identify: the rig identifies itself (report, model.json) |
| q | anywhere | quit (the loop stops safely: valve null, amplifier off) |

Escape closes this screen.
"""


class HelpScreen(ModalScreen[None]):
    BINDINGS = [Binding("escape,f1,question_mark", "app.pop_screen", "close")]
    DEFAULT_CSS = "HelpScreen { align: center middle; } HelpScreen > VerticalScroll { width: 100; height: 90%; border: thick $accent; background: $surface; }"

    def compose(self) -> ComposeResult:
        with VerticalScroll():
            yield Markdown(KEYS)


class HtmApp(App[None]):
    TITLE = "htm"
    SUB_TITLE = "servo-hydraulic fatigue testing"
    BINDINGS = [
        Binding("f12,ctrl+e", "estop", "E-STOP", priority=True),
        Binding("f1,question_mark", "help", "help"),
        Binding("f2", "tab('setup')", "setup", show=False),
        Binding("f3", "tab('install')", "install", show=False),
        Binding("f4", "tab('run')", "run", show=False),
        Binding("f5", "tab('results')", "results", show=False),
        Binding("f6", "tab('diagnose')", "diagnose", show=False),
        Binding("f7", "tab('identify')", "identify", show=False),
        Binding("ctrl+s", "simulate", "simulate"),
        Binding("ctrl+w", "web", "web viewer", show=False),  # htm.record.web: tests from now on to a browser
        Binding("q", "quit", "quit"),
    ]
    CSS = """
    #tabs { height: 1fr; }
    TabPane { height: 1fr; padding: 0; }
    #events-heading { height: 2; border-top: solid $accent; color: $text-muted; }
    #events { height: 5; }
    """

    def __init__(self, *, config: Any = None, session: Any = None, session_factory: Callable[[], Any] | None = None,
                 poll: bool = True, store: Any = None, spec: Any = None, **kw: Any) -> None:
        super().__init__(**kw)
        # the simulated DAQ lives in shared memory, whose tracker process must be forked while
        # the standard streams are still real files (Textual replaces them once it runs)
        from multiprocessing import resource_tracker

        resource_tracker.ensure_running()
        self.config = config
        self.store_root = store
        self.session = session
        self._factory = session_factory
        self._poll_on = poll
        self._last_period = 0
        self._last_cycle = 0
        self._last_event = 0
        self.key_latency_ms: list[float] = []
        self.spec_path = spec  # a spec file (TOML) the Setup tab starts with (--spec)
        self.pending: dict[int, str] = {}  # commands sent and not yet done (worker id -> command)

    def compose(self) -> ComposeResult:
        yield Header()
        with TabbedContent(initial="setup", id="tabs"):
            with TabPane("Setup F2", id="setup"):
                yield SetupPane(*self._spec_doc(), id="setup-pane")
            with TabPane("Install F3", id="install"):
                yield InstallPane(id="install-pane")
            with TabPane("Run F4", id="run"):
                yield RunPane(id="run-pane")
            with TabPane("Results F5", id="results"):
                yield ResultsPane(self.store_root, id="results-pane")
            with TabPane("Diagnose F6", id="diagnose"):
                yield DiagnosePane(id="diagnose-pane")
            with TabPane("Identify F7", id="identify"):
                yield IdentifyPane(id="identify-pane")
        yield Static(EVENTS_HEADING, id="events-heading", markup=False)
        yield RichLog(id="events", markup=True, max_lines=500)
        yield Footer()

    def _spec_doc(self) -> tuple[Any, ...]:
        """(document, name) of --spec, or nothing (the example C(T) test)."""
        if self.spec_path is None:
            return ()
        import tomllib
        from pathlib import Path

        p = Path(self.spec_path)
        return (tomllib.loads(p.read_text(encoding="utf-8")), p.stem)

    def on_mount(self) -> None:
        if self.session is None:
            self._open_session()
        if self._poll_on:
            self.set_interval(1.0 / POLL_HZ, self.poll)

    # ---- the session (rig + loop) ------------------------------------------------------------
    def _open_session(self, spec: Any = None) -> None:
        from htm.control.session import Session, specimen_of

        try:
            if self._factory is not None:
                self.session = self._factory()
            else:
                spec = spec or self.current_spec()
                specimen = specimen_of(spec) if spec else None
                if self.config:
                    self.session = Session().open(self.config, specimen=specimen)
                else:  # the built-in virtual rig: in-process, paced to the wall clock, protect on
                    self.session = Session().open(virtual_rig_config(), virtual=True, specimen=specimen, paced=True)
            where = "hardware config " + str(self.config) if self.config else "the virtual rig"
            self.log_event(f"[green]connected to {where}[/]")
        except Exception as e:  # the console stays up without a rig and says why
            self.session = None
            self.log_event(f"[red]rig not available: {e}[/]")
            self.notify(f"rig not available: {e}", severity="error", timeout=10)

    def rig_config(self) -> Any:
        """The connected rig's configuration (the built-in virtual rig's when none was given)."""
        from htm.devices.config import RigConfig, load_config

        if self.config is None:
            return virtual_rig_config()
        return self.config if isinstance(self.config, RigConfig) else load_config(self.config)

    def release_rig(self, why: str) -> None:
        """Hand the rig over (the identification drives its own loop): the session closes safely."""
        if self.session is not None:
            self.session.close()
            self.session = None
        self._last_period = self._last_cycle = self._last_event = 0
        self.log_event(f"[yellow]rig handed over to the {escape(why)}[/]")

    def reconnect_rig(self) -> None:
        if self.session is None:
            self._open_session()

    def current_spec(self):
        return self.query_one(SetupPane).spec

    def log_event(self, text: str) -> None:
        self.query_one("#events", RichLog).write(text)

    def poll(self) -> None:
        """Read what the loop published since the last poll and hand it to the panes."""
        s = self.session
        if s is None or getattr(s, "loop", None) is None or not self.is_running:
            return
        try:
            self._poll(s)
        except NoMatches:  # the screen is being torn down
            pass

    def _poll(self, s: Any) -> None:
        snap = s.snapshot()
        feed = s.feed_since(self._last_period)
        rows = s.cycles_since(self._last_cycle)
        events = s.events_since(self._last_event)
        if feed:
            self._last_period = feed[-1]["period"]
        if rows:
            self._last_cycle = rows[-1]["cycle"]
        self._last_event += len(events)
        dt = s.loop.dt
        for e in events:
            color = {"trip": "red", "estop": "b red", "reset": "green"}.get(e.get("kind", ""), "white")
            self.log_event(f"[{color}]{e.get('period', 0) * dt:>10.2f}  {escape(e.get('kind', '')):<10} {escape(e.get('message', ''))}[/]")
        run = self.query_one(RunPane)
        run.set_life(snap.get("life"))
        run.add_feed(feed)
        run.add_cycles(rows)
        snap["pending"] = self.pending_text(snap)
        # numbers on both handset tabs every poll (a few lines of text); plots and the limits panel
        # only where they are seen
        if self.query_one("#tabs", TabbedContent).active == "run":
            run.update_live(snap, s.detectors())
        else:
            run.update_numbers(snap)
        self.query_one(InstallPane).update_live(snap)

    def grip(self, spec: Any) -> None:
        """The built-in virtual rig grips the specimen of `spec` before it starts: a life test's
        round bar (or a crack test's specimen after a bar) means a specimen change, done with the
        rig at rest: the session is opened again with it."""
        from htm.control.session import is_life, specimen_of

        s = self.session
        if self.config is not None or self._factory is not None or s is None or getattr(s, "rig", None) is None:
            return
        want = specimen_of(spec)
        gripped = getattr(s.rig, "gripped", None)
        if (gripped == want) or (not is_life(spec) and s.rig.bar is None):
            return
        if s.loop is not None and s.loop.powered:
            return  # never while energised: the start is refused by the session then
        s.close()
        self.session = None
        self._last_period = self._last_cycle = self._last_event = 0
        self._open_session(spec)
        self.log_event(f"[yellow]virtual rig: {'a round bar' if is_life(spec) else 'the crack specimen'} gripped for {escape(spec.name)}[/]")

    def command(self, name: str, *args: Any) -> None:
        """Send session command `name` (a `Session` method) from a worker thread."""
        if name == "start" and args:
            self.grip(args[0])
        if self.session is None or getattr(self.session, "loop", None) is None:
            self.notify(f"{name}: no rig connected", severity="error")
            return
        worker = self._command(getattr(self.session, name), name, *args)
        if name in PENDING:
            self.pending[id(worker)] = name

    def pending_text(self, snap: dict[str, Any]) -> str:
        """What the operator waits for: the command sent last and not yet done (the supply comes
        up before anything moves), with the supply pressure meanwhile."""
        if not self.pending:
            return ""
        name = list(self.pending.values())[-1]
        p_s = snap.get("p_s", float("nan"))
        return PENDING[name] + (f" ({p_s / 1e5:.0f} bar)…" if "supply" in PENDING[name] and p_s == p_s else "…")

    @work(thread=True, group="commands")
    def _command(self, fn: Callable[..., Any], name: str, *args: Any) -> None:
        """Run a session command off the UI thread; refusals become notifications."""
        from textual.worker import get_current_worker

        me = id(get_current_worker())
        try:
            fn(*args)
        except InterlockTripped:
            self.call_from_thread(self.notify, self.interlock_message(name), severity="error", timeout=8)
        except HtmError as e:
            self.call_from_thread(self.notify, f"{name} refused: {e}", severity="error")
        except TimeoutError:
            self.call_from_thread(self.notify, f"{name}: the loop did not answer", severity="error")
        finally:
            self.call_from_thread(self._done, me)

    def _done(self, worker_id: int) -> None:
        self.pending.pop(worker_id, None)

    def interlock_message(self, name: str) -> str:
        """A command refused while an interlock holds, in the console's words (its key, not the API)."""
        s = self.session
        try:
            latched = [d["name"] for d in s.detectors() if d["latched"]] + (["E-STOP"] if s.snapshot()["estop"] else [])
        except Exception:  # the session went meanwhile
            latched = []
        return (f"{name} refused: interlock latched ({', '.join(latched) or 'see the limits panel'}). "
                "Clear the cause, then press ctrl+r on the Run tab (F4) to reset.")

    # ---- actions ----------------------------------------------------------------------------
    def action_estop(self) -> None:
        # straight from the UI thread: Session.estop only sets the latch the loop checks
        if self.session is not None and getattr(self.session, "loop", None) is not None:
            self.session.estop()  # the session logs it; the next poll shows it once

    def action_help(self) -> None:
        self.push_screen(HelpScreen())

    def action_tab(self, tab: str) -> None:
        tabs = self.query_one("#tabs", TabbedContent)
        if tabs.query(f"#{tab}"):
            # a widget left focused in the old tab would pull it back to the front
            self.set_focus(None)
            tabs.active = tab
            self.focus_tab(tab)
            self.poll()  # the tab's first picture is of now, not of when it was last seen

    def focus_tab(self, tab: str) -> None:
        """Keys act at once on the tab just entered: the handset panes take them, Results its list
        (↑/↓), Diagnose its record field."""
        target = {"install": lambda: self.query_one(InstallPane), "run": lambda: self.query_one(RunPane),
                  "results": lambda: self.query_one("#results-table"), "diagnose": lambda: self.query_one("#diag-record"),
                  "identify": lambda: self.query_one("#identify-out")}.get(tab)
        if target is not None:
            target().focus()

    def on_tabbed_content_tab_activated(self, ev: TabbedContent.TabActivated) -> None:
        if ev.pane.id == "results":  # tests may have ended since: show the store as it is now
            self.query_one(ResultsPane).action_refresh()
        if self.focused is None:  # nothing has the keys: give them to the tab entered
            self.focus_tab(ev.pane.id or "")

    def action_web(self) -> None:
        """Serve the tests recorded from now on to rerun's web viewer ($HTM_WEB_PORT or 9090, the stream on the next port)."""
        from htm.record import web

        try:
            viewer = web.serve_live()
        except HtmError as e:
            self.notify(str(e), severity="error", timeout=10)
            return
        self.notify(f"tests recorded from now on: {viewer.page_urls()[-1]}", timeout=30)

    def action_simulate(self) -> None:
        self.query_one(SetupPane).action_simulate()

    async def action_quit(self) -> None:
        if self.session is not None:
            self.session.close()
            self.session = None
        self.exit()

    def on_unmount(self) -> None:
        if self.session is not None:
            self.session.close()
            self.session = None


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="htm-tui", description="The htm operator console: the built-in virtual rig, "
                                 "or the hardware a rig configuration (TOML) names.")
    ap.add_argument("--config", help="rig configuration (TOML); default: the built-in virtual rig")
    ap.add_argument("--store", help="test store folder (default: $HTM_STORE or ~/.local/share/htm/store)")
    ap.add_argument("--spec", help="a spec file (TOML) the Setup tab starts with: a crack-growth test or a life test "
                                   "(force_life / strain_life)")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.spec:
        import tomllib

        try:
            tomllib.loads(open(args.spec, encoding="utf-8").read())
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
            print(f"htm-tui: --spec {args.spec}: {e}", file=sys.stderr)
            return 2
    HtmApp(config=args.config, store=args.store, spec=args.spec).run()
    return 0


if __name__ == "__main__":
    sys.exit(main())
