"""The search's rules that decide what is refitted and from where (unit level; the effect
matrix and the external benchmark show them at work on whole records)."""
import numpy as np

from htm.ident.model import Model, logf
from htm.ident.valve import MIN_GAIN_ERROR, _calibrated_off


def test_a_gain_within_calibration_tolerance_is_not_claimed():
    assert not _calibrated_off({"gain": 1.0 + 0.5 * MIN_GAIN_ERROR})
    assert _calibrated_off({"gain": 0.965})
    assert _calibrated_off({"gain": 1.15})


def test_a_parameter_pinned_where_it_started_stays_one_pinned_elsewhere_goes_to_nominal():
    # a spool started static (at its upper bound): still static is fine; pinned at its lower
    # bound it stood in for something else and restarts at its typical value
    nominal = {"valve_natural_hz": 150.0, "moving_mass_kg": 50.0}
    frees = [logf("valve_natural_hz", 0.4, 60.0), logf("moving_mass_kg", 0.4, 2.5)]
    start = np.array([np.log(60.0), 0.0])
    typical = np.zeros(2)
    static = Model(nominal, frees, np.array([np.log(60.0), 0.3]))
    assert np.allclose(static.unpinned(start, typical).x, [np.log(60.0), 0.3])
    slow = Model(nominal, frees, np.array([np.log(0.4), np.log(2.5)]))
    assert np.allclose(slow.unpinned(start, typical).x, [0.0, 0.0])


def _sensor_problem():
    """A toy record: channel `a` reads 0.95 x (a gain error) and channel `b` reads 2 z, the base
    parameter `k` being the 2; the simulator is the obvious one."""
    from htm.ident.fit import Problem, blocks
    from htm.ident.model import Candidate, lin
    from htm.ident.records import Record

    rng = np.random.default_rng(3)
    n = 4000
    t = np.arange(n) * 1e-3
    x = 100.0 + 10.0 * np.sin(2 * np.pi * 3 * t)
    z = np.cos(2 * np.pi * 5 * t)
    rec = Record({"t": t, "y": z, "a": 0.95 * x + rng.normal(0, 0.05, n), "b": 2.0 * z + rng.normal(0, 0.05, n)}, {}, "toy")

    def simulate(plist, rec, **opts):
        m = len(rec.columns["t"])
        return [{"a": p["gain_a"] * x[:m] + p["off_a"], "b": p["k"] * z[:m]} for p in plist]

    fit_mask, val_mask = blocks(n, n, 1e3)
    prob = Problem(rec, simulate, ["a", "b"], {"a": 0.05, "b": 0.05}, n, fit_mask, val_mask)
    nominal = {"k": 1.0, "off_a": 0.0, "gain_a": 1.0}
    base = Model(nominal, [lin("k", 0.1, -100.0, 100.0)], np.zeros(1))
    offset = Candidate("sensor_offset", "a", (lin("off_a", 0.01, -1e5, 1e5),), "constant", fields=(("offset", "off_a"),))
    gain = Candidate("sensor_gain", "a", (lin("gain_a", 0.01, -50.0, 50.0, origin=1.0),), "predicted a",
                     fields=(("gain", "gain_a"),))
    return prob, base, offset, gain


def test_two_contenders_are_judged_on_one_base():
    # The offset was polished where the base fits `b` (k = 2), the true gain where it does not
    # (k = 1): judged as they stand the better base picks the offset; on a common base the gain
    # explains channel `a` and wins.
    from htm.ident.search import _on_common_base, pays_off

    prob, base, offset, gain = _sensor_problem()
    pred0 = prob.predict([base.params()], whole=True)[0]
    polished = []
    for cand, k, own in ((offset, 2.0, -5.0 / 0.01), (gain, 1.0, -0.05 / 0.01)):
        trial = base.with_candidate(cand, own).at(np.array([k / 0.1, own]))
        tpred = prob.predict([trial.params()], whole=True)[0]
        polished.append((cand, pays_off(prob, pred0, trial, tpred, base, cand), trial, tpred, None, tpred))
    as_polished = min(polished, key=lambda g: g[1]["dbic"])[0]
    assert as_polished.effect == "sensor_offset"
    judged = _on_common_base(prob, pred0, base, polished, lambda *a: None)
    best = min(judged, key=lambda g: g[1]["dbic"])
    assert best[0].effect == "sensor_gain"
    assert abs(best[2].params()["gain_a"] - 0.95) < 0.002 and abs(best[2].params()["k"] - 2.0) < 0.01


def test_an_offset_a_tolerated_gain_would_read_is_not_claimed():
    # A supply gauge reads nearly constant: an offset under 1 % of its reading is a gain inside
    # calibration tolerance; a chamber pressure that swings tells an offset from a gain.
    from htm.ident.records import Record
    from htm.ident.valve import _not_a_tolerated_gain

    rng = np.random.default_rng(1)
    n = 5000
    t = np.arange(n) * 2e-3
    supply = 186e5 + rng.normal(0, 3e3, n)
    chamber = 93e5 + 40e5 * np.sin(2 * np.pi * t) + rng.normal(0, 3e3, n)
    rec = Record({"t": t, "y": t, "p_s": supply, "p_a": chamber}, {}, "toy")
    on_supply = _not_a_tolerated_gain(rec, "p_s")
    assert not on_supply({"offset_pa": 0.31e5}) and not on_supply({"offset_pa": -1.55e5})
    assert on_supply({"offset_pa": 2.6e5})
    assert _not_a_tolerated_gain(rec, "p_a")({"offset_pa": 0.31e5})
