"""Real-time scheduling of the calling thread, shared by the control loop and the virtual rig
served on its own (`htm rig serve`: its notifier thread answers each SYNC)."""
from __future__ import annotations

import os


def set_priority(priority: int) -> str | None:
    """Give the calling thread SCHED_FIFO `priority` (0: leave it as it is).

    Returns None when done (or not asked for), else why the OS refused, for the caller to log.
    """
    if priority <= 0:
        return None
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError) as e:
        return f"real-time priority {priority} refused: {e}"
    return None
