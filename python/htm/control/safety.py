"""Safety of the loop: the limit detectors (Rust `Detectors`), what each action does to the
controller and the outputs, latched interlocks and the e-stop. Trips go to the event log."""
from __future__ import annotations

import math
import time
from collections import deque
from typing import Any

from htm import core
from htm.devices.config import CHANNELS, RigConfig

SEVERITY = {"indicate": 0, "hold": 1, "stop": 2, "power_off": 3}
CH = {name: i for i, name in enumerate(CHANNELS)}
FRACTURE_WINDOW = 4  # periods over which the force is checked against the specimen's stiffness
FRACTURE_ZERO = 0.1  # a broken specimen carries no force: |force| within this share of the force range
FRACTURE_STATES = ("starting", "running", "holding", "stopping")  # a force test holds the specimen


class FractureWatch:
    """Has the specimen broken? A gripped specimen is a spring: each period's force change is
    its stiffness times the piston's displacement (the transducer's speed, trapezoid-integrated:
    its 5 µm position steps are worth ~500 N on a C(T) specimen, its 0.1 mm/s speed steps ~20 N).
    A specimen that breaks carries no force from one period to the next: the force falls to
    zero while the piston, relieved, moves on, so the force is less than the stretch says by
    about the force the specimen carried — at a valley too, where the force barely moves and
    stays inside the force band (R = 0.1: 0.11 of the range).

    The stiffness is measured, not assumed (grips and frame are in series with the specimen):
    a least-squares fit of force change on displacement over each whole cycle (`n` periods)
    that moved the force, used from the next cycle on, so a break cannot pull the estimate
    down before it is judged. Each period's residual (force change − stiffness × displacement)
    is taken towards zero force (negative in tension, positive in compression: the side the
    specimen was last loaded on). It has a periodic part (the speed is sampled once a period
    while a stiff specimen's force wave has kinks the sample does not see; a DAQ read later
    than the SYNC) that repeats every cycle, so it is summed over FRACTURE_WINDOW periods both
    as is and less the same periods one cycle earlier, and the smaller sum counts: a break shows
    in both, a repeating pattern or a slow change of amplitude in at most one. What the speed's
    quantisation can account for is taken off.

    Only while the force looks like a broken specimen's does it count: within FRACTURE_ZERO of
    the force range of zero, and no larger in magnitude than the largest in the window (by more
    than 2 % of the range). A valve fault that rings the piston faster than the speed is sampled
    also leaves a large residual, but with the specimen loading or loaded (the force band's
    business). The value is a fraction of the test's force range (its targets Fmax − Fmin);
    zero until the first cycle has given a stiffness, outside a force test, and for a stale or
    invalid sample (those have their own detectors; a gap restarts the window)."""

    def __init__(self, dt: float, speed_resolution_m_s: float):
        self.dt = dt
        self.speed_res = speed_resolution_m_s
        self.test: object = None
        self.n = 0
        self.k_n_m: float | None = None

    def new_test(self, test: object, samples_per_cycle: int) -> None:
        self.test, self.n, self.k_n_m = test, max(1, samples_per_cycle), None
        self._hist: list[tuple[int, float]] = [(-1, 0.0)] * self.n
        self._block = [0.0, 0.0, 0.0, 0]  # Σ dF·ds, Σ ds², Σ |dF|, periods
        self._side = 1.0  # +1 tension, −1 compression
        self._restart()

    def _restart(self) -> None:
        self._last: tuple[int, float, float] | None = None
        self._win: deque[tuple[float, float, float]] = deque(maxlen=FRACTURE_WINDOW)

    def update(self, k: int, f: float, v: float, span_n: float) -> float:
        """Period `k`'s force `f` [N] and fresh speed `v` [m/s]; `span_n` = Fmax − Fmin of the
        test's targets. Returns how far the force falls short of the stretch over the window, as
        a fraction of `span_n` (0 unless the force has fallen to near zero)."""
        if not (math.isfinite(f) and math.isfinite(v) and span_n > 0.0):
            self._restart()
            return 0.0
        last = self._last
        self._last = (k, f, v)
        if last is None or last[0] != k - 1:
            self._win.clear()
            return 0.0
        df = f - last[1]
        ds = 0.5 * (v + last[2]) * self.dt
        b = self._block
        b[0] += df * ds
        b[1] += ds * ds
        b[2] += abs(df)
        b[3] += 1
        if b[3] >= self.n:  # a cycle's worth: refit when the force moved (not while held)
            if b[2] >= 0.2 * span_n and b[1] > 0.0 and b[0] > 0.0:
                self.k_n_m = b[0] / b[1]
            self._block = [0.0, 0.0, 0.0, 0]
        if self.k_n_m is None:
            return 0.0
        r = df - self.k_n_m * ds
        i = k % self.n
        pk, pr = self._hist[i]
        self._hist[i] = (k, r)
        if abs(last[1]) > 0.02 * span_n:  # the side the specimen is loaded on (kept through zero)
            self._side = 1.0 if last[1] > 0.0 else -1.0
        side = self._side
        win = self._win
        # per period, how far the force fell short of the stretch towards zero: as is and less
        # the same period's residual one cycle earlier
        win.append((-side * r, -side * (r - pr) if pk == k - self.n else -side * r, last[1]))
        if abs(f) > FRACTURE_ZERO * span_n or abs(f) > max(abs(w[2]) for w in win) + 0.02 * span_n:
            return 0.0  # loaded, or loading (beyond the noise): not a break
        short = min(sum(w[0] for w in win), sum(w[1] for w in win))
        quantum = self.k_n_m * self.speed_res * self.dt * len(win)
        return max(short - quantum, 0.0) / span_n


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
        self.det = core.Detectors(cfg.detector_specs())
        self._specs = cfg.detector_specs()
        # a crack gauge not wired has nothing to watch
        wired = cfg.crack_channels + (("extensometer",) if cfg.has_extensometer else ())
        for name, needs in (("gauge_range", "cod"), ("gauge_slip", "cod"), ("dcpd_current", "dcpd_current"),
                            ("extensometer_range", "extensometer"), ("extensometer_slip", "extensometer")):
            if needs not in wired and any(s["name"] == name for s in self._specs):
                self.det.set_enabled(name, False)
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
