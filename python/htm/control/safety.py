"""Safety of the loop: the limit detectors (Rust `Detectors`), what each action does to the
controller and the outputs, latched interlocks and the e-stop. Trips go to the event log."""
from __future__ import annotations

import math
import time
from collections import deque
from typing import Any

from htm import _core
from htm.devices.config import CHANNELS, RigConfig

SEVERITY = {"indicate": 0, "hold": 1, "stop": 2, "power_off": 3}
CH = {name: i for i, name in enumerate(CHANNELS)}


class EventLog:
    """Append-only event log (bounded in memory; the consumer copies what it keeps)."""

    def __init__(self, maxlen: int = 10_000):
        self._q: deque[dict[str, Any]] = deque(maxlen=maxlen)
        self.count = 0

    def add(self, period: int, kind: str, message: str, **detail: Any) -> None:
        self._q.append({"period": period, "time": time.time(), "kind": kind, "message": message, **detail})
        self.count += 1

    def since(self, n: int = 0) -> list[dict[str, Any]]:
        """Events with index ≥ n (n = an earlier `count`)."""
        items = list(self._q)
        first = self.count - len(items)
        return items[max(0, n - first):]


class Safety:
    """Detectors + latches. `check` returns the worst new action this period (or None)."""

    def __init__(self, cfg: RigConfig, log: EventLog):
        self.cfg = cfg
        self.log = log
        self.det = _core.Detectors(cfg.detector_specs())
        self._specs = cfg.detector_specs()
        self.estop = False
        self.values = [0.0] * len(CHANNELS)

    def check(self, period: int) -> str | None:
        tripped = self.det.check(self.values)
        if not tripped:
            return None
        worst = None
        for i in tripped:
            s = self._specs[i]
            v = self.values[s["channel"]]
            self.log.add(period, "trip", f"{s['name']}: {CHANNELS[s['channel']]} = {v:.6g} outside "
                         f"[{s['lo']:.6g}, {s['hi']:.6g}] → {s['action']}", detector=s["name"], action=s["action"], value=v)
            if worst is None or SEVERITY[s["action"]] > SEVERITY[worst]:
                worst = s["action"]
        return worst

    def latched(self) -> str | None:
        """Worst latched action, with the e-stop as power_off."""
        return "power_off" if self.estop else self.det.worst()

    def interlocked(self) -> bool:
        """Motion commands are refused while a stop or power-off latch holds."""
        w = self.latched()
        return w is not None and SEVERITY[w] >= SEVERITY["stop"]

    def reset(self, period: int) -> list[str]:
        still = self.det.reset()
        self.estop = False
        self.log.add(period, "reset", "interlocks reset" + (f"; still active: {', '.join(still)}" if still else ""), still=still)
        return still

    def describe(self) -> list[dict[str, Any]]:
        """Every detector: name, channel, limit, state, action, latched."""
        out = []
        for d in self.det.describe():
            out.append({"name": d["name"], "channel": CHANNELS[d["channel"]], "lo": d["lo"], "hi": d["hi"],
                        "action": d["action"], "state": "tripped" if d["latched"] else ("active" if d["active"] else "ok"),
                        "latched": d["latched"], "enabled": d["enabled"],
                        "value": self.values[d["channel"]], "trip_value": None if math.isnan(d["trip_value"]) else d["trip_value"]})
        return out
