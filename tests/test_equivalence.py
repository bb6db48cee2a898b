"""One test engine: the same spec run by the simulator (`htm run --mode full`) and by the device
loop in lock-step on the virtual rig (real CANopen/python-can stacks, the simulated DAQ with its
16-bit quantisation) gives the same per-cycle table — peaks, valleys, crack length and ΔK —
within the sensors' noise. Both run the core's one cycle machine (engine::cycle)."""
import tomllib
from pathlib import Path

import numpy as np
import pytest

from htm.control import Session
from htm.control.session import specimen_of
from htm.core import EVENTS
from htm.devices.config import virtual_config
from htm.run import run_test
from htm.spec import parse

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "ct_constant_force.toml"
RATE_HZ = 500.0
CYCLES = 240


def _spec(waveform: str, frequency_hz: float):
    d = tomllib.loads(EXAMPLE.read_text())
    d["loading"].update(waveform=waveform, frequency_hz=frequency_hz, control_rate_hz=RATE_HZ)
    if waveform == "trapezoid":
        d["loading"].update(rise_fraction=0.25, hold_fraction=0.25)
    d["law"]["c"] *= 25.0  # the crack grows ≈ 0.5 mm in the compared cycles
    d["end"]["max_cycles"] = CYCLES
    return parse(d, "ct")


def _rig_table(spec) -> dict[str, np.ndarray]:
    s = Session().open(virtual_config("lockstep", RATE_HZ), virtual=True, specimen=specimen_of(spec), thread=False)
    try:
        s.start(spec, f0_n=0.0, record=False)
        n = round(RATE_HZ / spec.frequency_hz)
        s.step(n * (CYCLES + 10))
        rows = s.cycles_since(0)
        assert not [e for e in s.events_since(0) if e["kind"] == "trip"]
        assert s.snapshot()["end_reason"] == "cycle_limit"
        keys = ("cycle", "fmax_n", "fmin_n", "a_m", "delta_k_pa_sqrt_m")
        out = {k: np.array([r[k] for r in rows]) for k in keys}
        out["rig_a_m"] = s.rig.plant.a_m
        return out
    finally:
        s.close()


@pytest.mark.parametrize("waveform,frequency_hz", [("sine", 10.0), ("trapezoid", 20.0)])
def test_simulator_and_virtual_rig_give_the_same_cycle_table(waveform, frequency_hz):
    spec = _spec(waveform, frequency_hz)
    sim = run_test(spec, "full")
    t = sim.table
    counted = (t["events"] & EVENTS["stop"]) == 0  # not the smooth-stop rows
    sim_t = {k: np.asarray(t[k])[counted] for k in ("cycle", "fmax_n", "fmin_n", "a_m", "delta_k_pa_sqrt_m")}
    rig = _rig_table(spec)
    assert len(rig["cycle"]) == len(sim_t["cycle"]) == CYCLES
    assert np.array_equal(rig["cycle"], sim_t["cycle"])
    # sensor noise: the load cell's 16-bit DAQ (25 kN at 10 V: LSB ≈ 7.6 N) and the transducer's
    # 1 µm steps; the rig's supply comes up through its relief valve, the simulator's is ideal
    amp = 0.5 * (sim_t["fmax_n"] - sim_t["fmin_n"]).mean()
    for k in ("fmax_n", "fmin_n"):
        diff = np.abs(rig[k] - sim_t[k])
        assert diff[:30].max() < 0.005 * amp, (k, diff[:30].max())  # ramp-in: ≤ 0.5 % of the amplitude
        assert diff[30:].max() < 0.002 * amp, (k, diff[30:].max())  # test cycles: ≤ 0.2 %
    dk = np.abs(rig["delta_k_pa_sqrt_m"] - sim_t["delta_k_pa_sqrt_m"])[30:] / sim_t["delta_k_pa_sqrt_m"][30:]
    assert dk.max() < 0.002, dk.max()
    grown = sim_t["a_m"][-1] - sim_t["a_m"][0]
    assert grown > 2e-4, "the crack must grow for the comparison to mean anything"
    assert np.abs(rig["a_m"] - sim_t["a_m"]).max() < 0.001 * grown
    # the rig's specimen grows its own crack from the force it sees, by the controller's rule
    assert abs(rig["rig_a_m"] - sim.a_end_m) < 0.01 * grown
