"""Identify: the console's `htm rig identify` — on the connected rig (the console's configuration,
real or virtual), the identification experiment of `htm.control.identify` (holds, ramps, a sine
sweep in position control, every limit armed), its record and `htm diagnose`'s report and
model.json written into a folder, the findings shown. The experiment drives the loop itself: the
console hands the rig over (its session closed safely) and connects again afterwards. The
model.json it writes is what Setup's model field (and `htm run --model`, `htm tune`) runs on."""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from rich.markup import escape
from textual import on, work
from textual.app import ComposeResult
from textual.containers import Horizontal, Vertical
from textual.widgets import Button, Input, Label, Static


class IdentifyPane(Vertical):
    """Output folder and amplitude, the Identify button, the findings."""

    DEFAULT_CSS = """
    IdentifyPane { padding: 1; }
    IdentifyPane #identify-bar { height: 3; }
    IdentifyPane #identify-bar Input { width: 1fr; }
    IdentifyPane #identify-bar #identify-amplitude { width: 12; }
    IdentifyPane #identify-bar Label { padding: 1 1 0 1; }
    IdentifyPane #identify-result { height: auto; padding: 1 0; }
    """

    def __init__(self, **kw: Any) -> None:
        super().__init__(**kw)
        from htm.control.identify import Plan

        self.plan = Plan()  # the experiment (a shorter one can be set before pressing Identify)
        self.outcome: Any = None
        self.busy = False

    def compose(self) -> ComposeResult:
        with Horizontal(id="identify-bar"):
            yield Label("output folder")
            yield Input(f"out/identify-{time.strftime('%Y%m%d-%H%M%S')}", id="identify-out")
            yield Label("amplitude [mm]")
            yield Input(f"{self.plan.amplitude_m * 1e3:g}", id="identify-amplitude")
            yield Button("Identify", id="identify-run", variant="primary")
        yield Static("Runs the identification experiment on the connected rig with the piston free (no specimen "
                     "gripped): holds, ramps at three speeds and a sine sweep in position control around where it is, "
                     "every limit armed; then `htm diagnose` names what the nominal model lacks. The console hands the "
                     "rig over while it runs.", id="identify-help")
        yield Static("", id="identify-result")

    def show(self, text: str) -> None:
        self.query_one("#identify-result", Static).update(text)

    @on(Button.Pressed, "#identify-run")
    def action_identify(self) -> None:
        if self.busy:
            self.notify("an identification is running", severity="warning")
            return
        out = Path(self.query_one("#identify-out", Input).value.strip() or "out/identify")
        text = self.query_one("#identify-amplitude", Input).value
        try:
            amp = float(text) * 1e-3
            if not 0.0 < amp <= 0.05:
                raise ValueError
        except ValueError:
            self.notify(f"amplitude {text!r}: a number of millimetres in (0, 50]", severity="error")
            return
        from dataclasses import replace

        self.busy = True
        self.show(f"identifying the rig into {escape(str(out))} … (the console reconnects afterwards)")
        self._identify(out, replace(self.plan, amplitude_m=amp))

    @work(thread=True, exclusive=True, group="identify")
    def _identify(self, out: Path, plan: Any) -> None:
        from htm.control.identify import identify
        from htm.errors import HtmError

        app: Any = self.app
        app.call_from_thread(app.release_rig, "identification")
        try:
            res = identify(app.rig_config(), out, plan=plan, store=app.store_root)
            self.outcome = res
            text = self._describe(res, out)
        except (HtmError, OSError) as e:
            text = f"[red]identification refused: {escape(str(e))}[/]"
        self.busy = False
        app.call_from_thread(self.show, text)
        app.call_from_thread(app.reconnect_rig)

    @staticmethod
    def _describe(res: Any, out: Path) -> str:
        if res.tripped:
            return (f"[b red]stopped safely: {escape('; '.join(res.tripped))}[/] — valve null, amplifier off, supply "
                    f"unloaded; the {res.samples:,} samples recorded are kept in {escape(str(res.record_base))}.csv")
        findings = (res.report or {}).get("findings") or []
        lines = [f"[b green]identified[/] {res.samples:,} samples → {escape(str(out))}/report.md, model.json"
                 + (f" (store test {res.test_id})" if res.test_id else "")]
        if not findings:
            lines.append("no finding: the nominal model explains the rig")
        for f in findings:
            where = f"@{f['channel']}" if f.get("channel") else ""
            params = ", ".join(f"{k} = {v:.4g}" for k, v in f["params"].items())
            lines.append(f"  [b]{escape(f['effect'] + where)}[/]  {escape(params)}")
        lines.append(f"run tests on it: Setup's model field = {escape(str(out / 'model.json'))}")
        return "\n".join(lines)
