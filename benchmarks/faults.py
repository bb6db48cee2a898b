"""Fault campaign on the virtual rig: every fault the rig can inject, at random moments of running
tests (lock-step, over the real canopen/python-can stack and the simulated DAQ), each test recorded
into a store. Measures, per fault, the periods from the fault reaching the loop to the first trip
and its action; misses (no trip), wrong actions (another action or detector than the one that
guards against it), false trips in clean cycling, and rows recorded before the fault that the
store lost or changed. Prints JSON beside the acceptance figures.

    .venv/bin/python benchmarks/faults.py [--repeats 3] [--clean-cycles 10000] [--seed 1] [--quick]

"The fault reaching the loop": the injection period for a sensor or bus fault (the next SYNC sees
it); for a fault that shows as a growing value (supply loss, heartbeat timeout, valve saturation,
over-force, over-travel, load-cell drift) the first period its detector's watched value is out
of range — the detector cannot act before the value says so; for a stuck transducer the first
repeated position reading.
"""
from __future__ import annotations

import argparse
import json
import random
import tempfile
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from htm.control import Session
from htm.control.safety import CH
from htm.control.session import specimen_of
from htm.devices.config import virtual_config
from htm.record import Store
from htm.spec import parse

SPEC = Path(__file__).resolve().parents[1] / "examples" / "ct_constant_force.toml"
RAMP_PERIODS = 50 * 40  # 40 cycles at 10 Hz, 500 Hz: past the smooth start
WINDOW = 3000  # periods watched after the injection


@dataclass(frozen=True)
class Fault:
    name: str
    inject: str  # VirtualRig.inject name
    value: float
    detectors: tuple[str, ...]  # the detectors that guard against it (the first trip must be one)
    action: str
    gradual: bool = False  # latency counted from the watched value leaving its range
    repeat: bool = False  # latency counted from the first repeated (frozen) position reading
    position_mode: bool = False  # injected while moving in position control, no specimen gripped
    limits: tuple = ()  # (detector, lo, hi) overrides of the rig configuration
    jog_m_s: float = 0.01  # position mode: the move the fault meets


FAULTS = [
    Fault("transducer_silent", "transducer_silent", 1, ("transducer_silent",), "power_off"),
    Fault("transducer_nan", "transducer_nan", 1, ("transducer_fault",), "power_off"),
    Fault("heartbeat_lost", "heartbeat_lost", 1, ("heartbeat",), "power_off", gradual=True),
    Fault("can_error_frames", "can_error_frames", 5, ("can_errors",), "stop"),
    Fault("bus_off", "bus_off", 1, ("bus_off",), "power_off"),
    Fault("supply_loss", "supply_loss", 1, ("supply_pressure",), "power_off", gradual=True),
    Fault("valve_saturation", "valve_stuck", -10.0, ("force_band",), "power_off", gradual=True),
    Fault("over_force", "valve_stuck", 1.0, ("force_band",), "power_off", gradual=True),
    Fault("load_cell_drift", "load_drift", 2000.0, ("load_plausibility",), "hold", gradual=True),
    # a break at any phase: the force stops following the displacement (at a valley it stays in the band);
    # the piston's jump at a loaded break may trip position plausibility in the same period
    Fault("specimen_break", "fracture", 1, ("fracture",), "power_off"),
    # a frozen position while the force loop cycles a stiff specimen moves < 3 µm a period: the
    # position matters, and so is checked, while the piston moves in position control
    Fault("transducer_stuck", "transducer_stuck", 1, ("position_plausibility",), "power_off", position_mode=True,
          repeat=True),
    # over-travel: a jog that runs past the permitted travel (here set to ±10 mm around the start)
    Fault("over_travel", "jog", 0.02, ("position",), "stop", gradual=True, position_mode=True,
          limits=(("position", 0.09, 0.11),), jog_m_s=0.002),
]


def spec_at(frequency_hz: float):
    doc = tomllib.loads(SPEC.read_text())
    doc["loading"]["frequency_hz"] = frequency_hz
    doc["loading"]["control_rate_hz"] = 500.0
    return parse(doc, "ct")


def limits_of(s: Session) -> dict[str, dict]:
    return {d["name"]: d for d in s.detectors()}


def one(fault: Fault, rng: random.Random, store: Path) -> dict:
    """One injection at a random moment; returns what happened."""
    spec = spec_at(10.0)
    limits = {name: {"lo": lo, "hi": hi} for name, lo, hi in fault.limits}
    s = Session().open(virtual_config("lockstep", limits=limits), virtual=True,
                       specimen=None if fault.position_mode else specimen_of(spec), thread=False)
    try:
        if fault.position_mode:
            s.jog(fault.jog_m_s)
            s.step(rng.randrange(150, 400))  # past the jog's acceleration
        else:
            s.start(spec, store=store, recording=False)
            s.step(RAMP_PERIODS + rng.randrange(0, 2000))
        assert s.snapshot()["interlock"] is None, "a trip before the fault"
        test_no, k0, n0, f0 = s.loop.test_no, s.loop.k, s.log.count, s.loop.meas["f"]
        before = [dict(r) for r in s.loop.cycles if r["test"] == test_no]
        lim = limits_of(s)
        watched = [(lim[d]["channel"], lim[d]["lo"], lim[d]["hi"]) for d in fault.detectors]
        if fault.inject == "jog":  # the operator's command is the fault
            s.jog(fault.value)
        else:
            s.rig.inject(fault.inject, fault.value)
        crossed, trips, y_last = None, [], s.loop.meas["y"]
        for _ in range(WINDOW):
            s.step(1)
            v = s.loop.safety.values
            if fault.repeat:
                if crossed is None and s.loop.meas["y"] == y_last:
                    crossed = s.loop.k
                y_last = s.loop.meas["y"]
            elif crossed is None and any(not lo <= v[CH[ch]] <= hi for ch, lo, hi in watched):
                crossed = s.loop.k
            # an indicate-only trip informs; the action is the first trip that does something
            trips = [e for e in s.events_since(n0) if e["kind"] == "trip" and e["action"] != "indicate"]
            if trips:
                break
        rec = s.recorder
    finally:
        s.close()  # the recorder flushes and closes the test
    out = {"fault": fault.name, "injected_period": k0 + 1, "force_at_fault_n": round(f0), "tripped": bool(trips)}
    if not trips:
        return out
    first = min(e["period"] for e in trips)
    early = [e for e in trips if e["period"] == first]
    ref = crossed if (fault.gradual or fault.repeat) and crossed is not None else k0 + 1
    worst = max(early, key=lambda e: ("indicate", "hold", "stop", "power_off").index(e["action"]))
    out.update(latency_periods=first - ref, detectors=[e["detector"] for e in early], action=worst["action"],
               right=worst["action"] == fault.action and any(e["detector"] in fault.detectors for e in early))
    if rec is not None:
        out["rows_before"], out["rows_lost"] = len(before), rows_lost(store, rec.test_id, before)
    return out


def rows_lost(store: Path, test_id: str, before: list[dict]) -> int:
    """Rows the loop produced before the fault that the store lacks or holds changed."""
    with Store(store) as st:
        t = st.cycles(test_id)
    have = {int(c): i for i, c in enumerate(t.get("cycle", []))}
    lost = 0
    for r in before:
        i = have.get(r["cycle"])
        if i is None or any(not np.isclose(t[k][i], r[k], equal_nan=True) for k in ("fmax_n", "fmin_n", "a_m")):
            lost += 1
    return lost


def clean(cycles: int) -> dict:
    """`cycles` nominal cycles at 25 Hz (20 periods each): every trip is a false trip."""
    spec = spec_at(25.0)
    s = Session().open(virtual_config("lockstep"), virtual=True, specimen=specimen_of(spec), thread=False)
    try:
        s.start(spec, record=False)
        t0 = time.perf_counter()
        while s.snapshot()["cycles"] < cycles + 30:  # + the ramp-in
            s.step(2000)
        trips = [e["message"] for e in s.events_since(0) if e["kind"] == "trip"]
        return {"cycles": s.snapshot()["cycles"], "periods": s.loop.k, "false_trips": len(trips),
                "trips": trips[:5], "wall_s": round(time.perf_counter() - t0, 1)}
    finally:
        s.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3, help="injections of each fault (default 3)")
    ap.add_argument("--clean-cycles", type=int, default=10_000, help="clean cycles watched for false trips")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--quick", action="store_true", help="one injection each, 300 clean cycles (a smoke run)")
    ap.add_argument("--only", help="inject only this fault (a name from FAULTS)")
    a = ap.parse_args()
    if a.quick:
        a.repeats, a.clean_cycles = 1, 300
    rng = random.Random(a.seed)
    t0 = time.perf_counter()
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(a.repeats):
            for f in FAULTS:
                if a.only and f.name != a.only:
                    continue
                runs.append(one(f, rng, Path(tmp) / "store"))
    cl = clean(a.clean_cycles)
    lat = [r["latency_periods"] for r in runs if r["tripped"]]
    by_fault = {}
    for r in runs:
        d = by_fault.setdefault(r["fault"], {"latency_periods": [], "detectors": set(), "actions": set(), "force_at_fault_n": []})
        d["force_at_fault_n"].append(r["force_at_fault_n"])  # where in the cycle (0.5 kN valley, 4.9 kN peak)
        if r["tripped"]:
            d["latency_periods"].append(r["latency_periods"])
            d["detectors"].update(r["detectors"])
            d["actions"].add(r["action"])
    print(json.dumps({
        "faults_injected": len(runs),
        "misses": sum(not r["tripped"] for r in runs),
        "wrong_actions": sum(r["tripped"] and not r["right"] for r in runs),
        "false_trips": cl["false_trips"],
        "clean_cycles": cl["cycles"],
        "max_latency_periods": max(lat) if lat else None,
        "rows_lost": sum(r.get("rows_lost", 0) for r in runs),
        "rows_checked": sum(r.get("rows_before", 0) for r in runs),
        "acceptance": {"misses": 0, "wrong_actions": 0, "max_latency_periods": 2, "false_trips_in_1e4_cycles": 0, "rows_lost": 0},
        "by_fault": {k: {"latency_periods": v["latency_periods"], "detectors": sorted(v["detectors"]),
                         "actions": sorted(v["actions"]), "force_at_fault_n": v["force_at_fault_n"]}
                     for k, v in by_fault.items()},
        "wrong": [r for r in runs if not r["tripped"] or not r["right"]],
        "clean": cl,
        "wall_s": round(time.perf_counter() - t0, 1),
    }, indent=1))


if __name__ == "__main__":
    main()
