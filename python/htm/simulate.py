"""Whole-run simulation helpers over the Rust plant: numpy in, numpy out, GIL released inside."""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from htm.core import Machine, Params


def _machine(params: Params | None, rtol: float | None, state: np.ndarray | None) -> Machine:
    m = Machine(params, rtol)
    if state is not None:
        m.state = np.asarray(state, dtype=float)
    return m


def simulate(u: np.ndarray, dt: float, params: Params | None = None, *, rtol: float | None = None,
             state: np.ndarray | None = None) -> dict[str, Any]:
    """Play valve commands `u` [V], each held for `dt` [s], open loop.

    Returns arrays `t, u, y, v, p_a, p_b, p_s, f` (sample k read at t[k] before u[k] is applied)
    and solver `stats`. Starts at rest at mid-stroke unless `state` is given.
    """
    return _machine(params, rtol, state).simulate(np.ascontiguousarray(u, dtype=float), float(dt))


def track(reference: np.ndarray, dt: float, controller: Mapping[str, Any], params: Params | None = None, *,
          rtol: float | None = None, state: np.ndarray | None = None) -> dict[str, Any]:
    """Track `reference` (m for `position_pff`, N for `force_p`) in closed loop at period `dt` [s].

    `controller` is the DATA_FORMAT `controller` mapping, e.g.
    ``{"type": "position_pff", "kp_v_per_m": -150, "kff_v_per_m_s": -14.3, "u_max_v": 10}``.
    """
    return _machine(params, rtol, state).track(np.ascontiguousarray(reference, dtype=float), float(dt), dict(controller))


def steady_velocity(u: float, params: Params | None = None, *, settle_s: float = 0.06, window_s: float = 0.02,
                    dt: float = 1e-3) -> float:
    """Steady piston velocity [m/s] under constant command `u` [V], open loop (thesis Table 3.3).

    The piston starts at rest near the end it moves away from, so the whole stroke is available;
    the velocity is averaged over the last `window_s` of `settle_s`.
    """
    p = params or Params()
    stroke = p["stroke_m"]
    # Probe the direction with a short run from mid-stroke, then restart from the far end.
    probe = Machine(p)
    probe.state = probe.rest_state(0.5 * stroke)
    v0 = probe.simulate(np.full(20, float(u)), dt)["v"][-1]
    m = Machine(p)
    m.state = m.rest_state(0.02 * stroke if v0 >= 0 else 0.98 * stroke)
    n = int(round(settle_s / dt))
    tr = m.simulate(np.full(n, float(u)), dt)
    k = int(round(window_s / dt))
    return float(np.mean(tr["v"][-k:]))
