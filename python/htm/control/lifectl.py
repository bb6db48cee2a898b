"""A life test (force_life E466, strain_life E606) in the control loop: the core's `LifeController`
(`engine::life::LifeMachine`, the code the simulator's `run_life` runs) behind the face the loop,
the session and the recorder know of the force test's `CyclicController` (state, step, hold,
resume, stop, the last cycle's row).

The loop feeds it the load cell, the piston position and the extensometer's strain each period;
it returns the valve command. A counted cycle's row carries the life table's columns (peak and
valley stress and strain, plastic strain range, moduli, the stabilised trend of the judged
quantity) and, when the core keeps the loop (logarithmic intervals), its samples. The end
criteria are judged by the core on those measured rows; the test then ramps down and stops."""
from __future__ import annotations

import math
from typing import Any

from htm import core
from htm.errors import HtmError

START = 1  # the life table's event bits (engine::life::life_events)
DROP10, DROP50, END = 1024, 2048, 256


class LifeTest:
    """`core.LifeController` with the force test controller's face (see the module doc).

    ``config``: the life test's core dict on the loop's rate (`htm.devices.config.life_on_loop`);
    ``f0_n``, ``strain0``: the measured force and strain at the start (smooth start from there)."""

    is_life = True

    def __init__(self, config: dict[str, Any], params: core.Params, f0_n: float, strain0: float, rate_hz: float):
        self.config = config
        self.mode = str(config["mode"])
        self.core = core.LifeController(config, f0_n, 0.0 if not math.isfinite(strain0) else strain0, params)
        self.rate_hz = rate_hz
        self.command_limit_v = math.inf
        self.u_last_v = 0.0
        self._idle = False
        # nominal area (the controller's: the spec's diameter) for stresses
        self.area_m2 = math.pi / 4 * float(config.get("diameter_m", 6.35e-3)) ** 2
        self.drop = float(config.get("drop", 0.5))
        hi, lo = self.core.targets
        self.amplitude = 0.5 * (hi - lo)
        # what other threads read (the console, the recorder), written only by the loop's thread:
        # the core object is called from that thread alone (a call from another thread while the
        # loop steps it would find it borrowed)
        self._state, self._cycle, self._results, self._end = self.core.state, 0, 0, None
        self._info = {"rate_hz": rate_hz, "frequency_hz": self.core.frequency_hz, "samples_per_cycle": self.core.samples_per_cycle,
                      "velocity_gain_m_s_per_v": self.core.velocity_gain_m_s_per_v}
        self._loop: tuple[Any, Any] = ((), ())
        self._drops: tuple[int | None, int | None] = (None, None)

    # -- the loop's calls ----------------------------------------------------------------------
    def step(self, f: float, y: float, strain: float = math.nan) -> float:
        if self._idle:
            return 0.0
        c = self.core
        u = c.step(f, strain, y)
        u = max(-self.command_limit_v, min(self.command_limit_v, u))
        self.u_last_v = u
        self._sync()
        return u

    def _sync(self) -> None:
        c = self.core
        self._state, self._cycle, self._results, self._end = c.state, c.cycle, c.results, c.end_reason

    @property
    def state(self) -> str:
        return "idle" if self._idle else self._state

    def hold(self) -> None:
        if not self.core.hold():
            raise HtmError(f"hold needs a running test (state is {self.state})")
        self._sync()

    def resume(self) -> None:
        if not self.core.resume():
            raise HtmError(f"resume needs a held test (state is {self.state})")
        self._sync()

    def stop(self) -> None:
        self.core.stop()
        self._sync()

    def idle(self) -> None:
        self._idle = True

    def position(self, y_m: float, u_v: float) -> None:
        raise HtmError("position control needs the position controller (Session.position)")

    @property
    def cycle(self) -> int:
        return self._cycle

    @property
    def results(self) -> int:
        return self._results

    @property
    def end_reason(self) -> str | None:
        return self._end

    @property
    def u_null_v(self) -> float:
        return self.core.u_null_v

    # a life test has no crack of its own to show, no force targets for the force band and the
    # fracture watch (under strain control the force is the specimen's answer; a separation is
    # the life test's own end criterion), no position reference
    targets = None
    a_m = math.nan
    a_law_m = math.nan
    force_ref_n = math.nan
    reference_m = math.nan
    protecting = False
    starting_up = False
    supply_demand_pa = 0.0

    def info(self) -> dict[str, Any]:
        return dict(self._info)

    def convergence(self) -> list:
        return []

    def last_cycle(self) -> dict[str, Any] | None:
        """The last counted cycle's row: the life table's columns, the amplitude error of the
        controlled signal, whether it was judged, the end-criterion threshold and, for a kept
        loop, its samples (`loop_strain`, `loop_stress_pa`)."""
        r = self.core.last_cycle()  # (the loop's thread)
        if r is None:
            return None
        self._loop = self.core.last_loop()
        self._drops = (self.core.n_drop10, self.core.n_drop50)
        lo_hi = (r["strain_min"], r["strain_max"]) if self.mode == "strain_life" else (r["fmin_n"], r["fmax_n"])
        r["df_err_pct"] = 100.0 * (0.5 * (lo_hi[1] - lo_hi[0]) / self.amplitude - 1.0)
        r["peak_err_pct"] = math.nan
        r["judged"] = math.isfinite(r["trend"])
        r["starting"] = bool(r["events"] & START)
        r["threshold"] = (1.0 - self.drop) * r["trend"] if self.drop > 0 else math.nan
        if r["keep_loop"]:
            r["loop_strain"], r["loop_stress_pa"] = self._loop
        return r

    def live_loop(self) -> tuple[Any, Any]:
        """The last counted cycle's (strain, stress [Pa]) samples: the console's live loop."""
        return self._loop

    @property
    def n_drop10(self) -> int | None:
        return self._drops[0]

    @property
    def n_drop50(self) -> int | None:
        return self._drops[1]
