"""The console application: one tab per workflow, handset-like keys, a help screen."""
from __future__ import annotations

import argparse
import sys
from typing import Any

from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.containers import VerticalScroll
from textual.screen import ModalScreen
from textual.widgets import Footer, Header, Markdown, TabbedContent, TabPane

from htm.tui.setup import SetupPane

KEYS = """\
# htm-tui keys

| key | where | action |
|---|---|---|
| F1 or ? | anywhere | this help |
| F2 … F6 | anywhere | Setup, Install, Run, Results, Diagnose |
| ctrl+s | Setup | simulate the spec on the fast engine |
| q | anywhere | quit (refused while a test runs) |

Escape closes this screen.
"""


class HelpScreen(ModalScreen[None]):
    BINDINGS = [Binding("escape,f1,question_mark", "app.pop_screen", "close")]
    DEFAULT_CSS = "HelpScreen { align: center middle; } HelpScreen > VerticalScroll { width: 90; height: 80%; border: thick $accent; background: $surface; }"

    def compose(self) -> ComposeResult:
        with VerticalScroll():
            yield Markdown(KEYS)


class HtmApp(App[None]):
    TITLE = "htm"
    SUB_TITLE = "servo-hydraulic fatigue testing"
    BINDINGS = [
        Binding("f1,question_mark", "help", "help"),
        Binding("f2", "tab('setup')", "setup"),
        Binding("f3", "tab('install')", "install", show=False),
        Binding("f4", "tab('run')", "run", show=False),
        Binding("f5", "tab('results')", "results", show=False),
        Binding("f6", "tab('diagnose')", "diagnose", show=False),
        Binding("ctrl+s", "simulate", "simulate"),
        Binding("q", "quit_safely", "quit"),
    ]

    def __init__(self, *, config: Any = None, **kw: Any) -> None:
        super().__init__(**kw)
        self.config = config

    def compose(self) -> ComposeResult:
        yield Header()
        with TabbedContent(initial="setup", id="tabs"):
            with TabPane("Setup F2", id="setup"):
                yield SetupPane(id="setup-pane")
        yield Footer()

    def action_help(self) -> None:
        self.push_screen(HelpScreen())

    def action_tab(self, tab: str) -> None:
        tabs = self.query_one("#tabs", TabbedContent)
        if tabs.query(f"#{tab}"):
            tabs.active = tab

    def action_simulate(self) -> None:
        self.query_one(SetupPane).action_simulate()

    def action_quit_safely(self) -> None:
        self.exit()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="htm-tui", description="The htm operator console (virtual rig unless --config names hardware).")
    ap.add_argument("--config", help="rig configuration (TOML); default: the built-in virtual rig")
    args = ap.parse_args(argv)
    HtmApp(config=args.config).run()
    return 0


if __name__ == "__main__":
    sys.exit(main())
