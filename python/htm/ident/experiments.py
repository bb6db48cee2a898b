"""Closed-loop position experiments rich enough to identify from, run on the simulated rig and
returned as DATA_FORMAT records (holds, constant-velocity ramps at several speeds)."""
from __future__ import annotations

import numpy as np

from htm.core import Machine, Params
from htm.ident.records import Record
from htm.params import rig_metadata

POSITION_LAW = "u[k] = clip(kp*(y_ref[k]-y[k]) + kff*(y_ref[k+1]-y_ref[k])/Ts, -u_max, u_max)"


def ramp_reference(speeds_m_s: list[float], rate_hz: float, *, low_m: float = 0.03, high_m: float = 0.17,
                   hold_s: float = 0.3, min_ramp_s: float = 0.6) -> np.ndarray:
    """Up-and-down ramps at each speed (travel shortened for slow speeds), holds in between."""
    dt = 1.0 / rate_hz
    parts = [np.full(int(hold_s / dt), low_m)]
    for s in speeds_m_s:
        travel = float(np.clip(s * min_ramp_s * 2, 0.02, high_m - low_m))
        n = max(2, int(round(travel / s / dt)))
        up = low_m + travel * np.arange(1, n + 1) / n
        parts += [up, np.full(int(hold_s / dt), low_m + travel), up[::-1] - travel / n, np.full(int(hold_s / dt), low_m)]
    return np.concatenate(parts)


def position_record(params: Params, reference: np.ndarray, rate_hz: float, *, kp_v_per_m: float = -150.0,
                    kff_v_per_m_s: float = -14.3, name: str = "experiment") -> Record:
    """Track `reference` [m] with the position P+feed-forward loop and return the record (ideal sensors)."""
    m = Machine(params)
    m.state = m.rest_state(float(reference[0]))
    ctrl = {"type": "position_pff", "kp_v_per_m": kp_v_per_m, "kff_v_per_m_s": kff_v_per_m_s, "u_max_v": 10.0}
    tr = m.track(np.asarray(reference, dtype=float), 1.0 / rate_hz, ctrl)
    cols = {k: tr[k] for k in ("t", "u", "y", "v", "p_a", "p_b", "p_s")}
    cols["y_ref"] = np.asarray(reference, dtype=float)
    meta = {"sample_rate_hz": rate_hz, "rig": rig_metadata(params), "specimen": None,
            "controller": {**ctrl, "law": POSITION_LAW}, "sensors": {}}
    return Record(cols, meta, name)
