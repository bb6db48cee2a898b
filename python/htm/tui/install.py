"""Install: position control with specimen protect — jog by rate or step, tare the load cell,
move to the start position."""
from __future__ import annotations

import math
from typing import Any

from textual import on
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.widgets import Button, Input, Label, Static

from htm.tui.runpane import num

JOG_RATES_MM_S = (0.1, 0.5, 1.0, 2.0, 5.0, 10.0)
STEPS_MM = (0.001, 0.01, 0.1, 1.0)


class InstallPane(Vertical):
    """Handset-like jogging. Every command goes through the session (the loop runs it)."""

    can_focus = True
    BINDINGS = [
        Binding("up", "jog(1)", "jog up"),
        Binding("down", "jog(-1)", "jog down"),
        Binding("space", "jog(0)", "stop jog"),
        Binding("right_square_bracket", "step(1)", "step up"),
        Binding("left_square_bracket", "step(-1)", "step down"),
        Binding("plus,equals_sign", "rate(1)", "faster", show=False),
        Binding("minus", "rate(-1)", "slower", show=False),
        Binding("t", "tare", "tare"),
        Binding("m", "move_start", "move to start"),
        Binding("o", "position_on", "position ctrl"),
    ]
    DEFAULT_CSS = """
    InstallPane { padding: 1; }
    InstallPane #install-numbers { height: auto; border: round $accent; padding: 0 1; }
    InstallPane #install-bar { height: 3; }
    InstallPane #install-bar Input { width: 16; }
    InstallPane #install-bar Label { padding: 1 1 0 1; }
    """

    def __init__(self, **kw: Any) -> None:
        super().__init__(**kw)
        self.rate_i = 2
        self.step_i = 2

    def compose(self) -> ComposeResult:
        yield Static("", id="install-numbers")
        with Horizontal(id="install-bar"):
            yield Button("Position ctrl (o)", id="position-on")
            yield Button("Tare (t)", id="tare")
            yield Label("start position [mm]")
            yield Input("100", id="start-position")
            yield Button("Move to start (m)", id="move-start")
        yield Static("↑/↓ jog at the rate · space stops · [ / ] step · +/− change rate and step · "
                     "specimen protect limits the force while in position control", id="install-help")

    @property
    def rate_mm_s(self) -> float:
        return JOG_RATES_MM_S[self.rate_i]

    @property
    def step_mm(self) -> float:
        return STEPS_MM[self.step_i]

    def update_live(self, snap: dict[str, Any]) -> None:
        y = snap.get("y", math.nan)
        f = snap.get("f", math.nan)
        protect = "ON (limiting force)" if snap.get("protecting") else "on"
        self.query_one("#install-numbers", Static).update(
            f"[b]state[/] {snap.get('state')}   [b]amplifier[/] {'ON' if snap.get('amplifier') else 'off'}   "
            f"[b]specimen protect[/] {protect}   [b]interlock[/] {snap.get('interlock') or 'none'}\n"
            f"[b]position[/] {num(y * 1e3, '9.4f')} mm   [b]reference[/] {num(snap.get('reference_m', math.nan) * 1e3, '9.4f')} mm   "
            f"[b]force[/] {num(f / 1e3, '8.3f')} kN\n"
            f"[b]jog rate[/] {self.rate_mm_s:g} mm/s   [b]step[/] {self.step_mm:g} mm"
            + (f"\n[b yellow]→ {snap['pending']}[/]" if snap.get("pending") else ""))

    def _cmd(self, name: str, *args) -> None:
        self.app.command(name, *args)  # type: ignore[attr-defined]

    def action_jog(self, direction: int) -> None:
        self._cmd("jog", direction * self.rate_mm_s * 1e-3)

    def action_step(self, direction: int) -> None:
        self._cmd("jog_step", direction * self.step_mm * 1e-3)

    def action_rate(self, d: int) -> None:
        self.rate_i = min(max(self.rate_i + d, 0), len(JOG_RATES_MM_S) - 1)
        self.step_i = min(max(self.step_i + d, 0), len(STEPS_MM) - 1)

    @on(Button.Pressed, "#tare")
    def action_tare(self) -> None:
        self._cmd("tare")

    @on(Button.Pressed, "#position-on")
    def action_position_on(self) -> None:
        self._cmd("position")

    @on(Button.Pressed, "#move-start")
    def action_move_start(self) -> None:
        text = self.query_one("#start-position", Input).value
        try:
            y = float(text) * 1e-3
        except ValueError:
            self.notify(f"start position {text!r} is not a number (mm)", severity="error")
            return
        self._cmd("move_to", y)
