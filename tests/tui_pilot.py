"""Helpers the console's pilot tests share: wait for a condition while the app runs, read a Static."""
from __future__ import annotations

import time

from textual.widgets import Static


async def until(pilot, cond, timeout: float = 30.0, step: float = 0.1) -> None:
    """Let the app run until `cond()` holds (the loop and the poller run meanwhile)."""
    t0 = time.monotonic()
    while not cond():
        if time.monotonic() - t0 > timeout:
            raise AssertionError("condition not reached in time")
        await pilot.pause(step)


def text(app, sel: str) -> str:
    return str(app.query_one(sel, Static).content)
