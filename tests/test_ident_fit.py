"""The fit's Jacobian schedule (issue 31, speed): a Jacobian differenced afresh only every
`jacobian_every` iterations, Broyden's rank-one update carrying it between, reaches the same
parameters as one differenced every other iteration for fewer simulations; a step that fails on
a carried Jacobian has it differenced afresh rather than ending the fit."""
from __future__ import annotations

import dataclasses

import numpy as np

from htm.ident.fit import Problem, blocks, fit
from htm.ident.model import Model, lin, logf
from htm.ident.records import Record
from htm.ident.settings import DEFAULT

TRUE = {"amp": 0.03, "tau": 0.4, "ripple": 0.004}


def _simulate(plist, rec, **_opts):
    """A smooth nonlinear 'plant' of three parameters: a first-order rise and a ripple."""
    t = np.asarray(rec.columns["t"])
    return [{"y": p["amp"] * (1.0 - np.exp(-t / p["tau"])) + p["ripple"] * np.sin(7.0 * t) * np.exp(-t / p["tau"])}
            for p in plist]


def _problem(settings):
    rng = np.random.default_rng(3)
    t = np.arange(2000) * 1e-3
    clean = _simulate([TRUE], Record({"t": t, "u": np.zeros_like(t), "y": t}))[0]["y"]
    y = clean + 2e-5 * rng.standard_normal(len(t))
    rec = Record({"t": t, "u": np.zeros_like(t), "y": y, "v": np.zeros_like(t), "p_a": np.zeros_like(t),
                  "p_b": np.zeros_like(t)}, {}, "fit-schedule")
    fit_mask, val_mask = blocks(len(t), len(t), 1000.0, 0.1)
    return Problem(rec, _simulate, ["y"], {"y": 2e-5}, len(t), fit_mask, val_mask, settings=settings)


def _fitted(every: int) -> tuple[dict, int]:
    prob = _problem(dataclasses.replace(DEFAULT, jacobian_every=every))
    nominal = {"amp": 0.02, "tau": 0.25, "ripple": 0.0}
    model = Model(nominal, [lin("amp", 0.01, -10, 10, step=0.01), logf("tau", 0.1, 10.0), lin("ripple", 0.001, -20, 20, step=0.01)],
                  np.zeros(3))
    model = model.at(model.start())
    fitted, _, jac = fit(prob, model, iters=30, ftol=1e-9)
    p = fitted.params()
    assert jac.shape == (int(prob.fit_mask.sum()), 3)
    return {k: p[k] for k in TRUE}, prob.simulations


def test_a_jacobian_carried_by_broyden_between_differencings_reaches_the_same_fit_for_fewer_simulations():
    every2, sims2 = _fitted(2)
    every4, sims4 = _fitted(4)
    for k, v in TRUE.items():
        assert abs(every2[k] - v) <= 0.01 * abs(v), (k, every2[k])
        assert abs(every4[k] - v) <= 0.01 * abs(v), (k, every4[k])
    assert sims4 < sims2, (sims4, sims2)


def test_jacobian_neighbours_run_in_lockstep_give_the_finite_difference_columns():
    """A Jacobian's neighbours simulated in lockstep with the point (on its integrator step
    sizes) give the columns that separate simulations at a tight tolerance give, within a few
    percent (a neighbour that used the point's Jacobian instead of its own was 15 % off on a
    valve play's column); the point itself reads exactly as when simulated alone."""
    from htm.ident import proving, sim
    from htm.ident.fit import spread_blocks

    rec, _ = proving.make_record({"valve_hysteresis": {"half_width_v": 0.2}}, seed=3, duration_s=6.0, rate_hz=500)
    n = len(rec.columns["t"])
    fit_mask, _ = spread_blocks(n, 500.0, 0.5, 2.0)
    p = sim.params_from_meta(rec.meta)
    p["valve_natural_hz"] = 300.0
    p["valve_damping"] = 0.7
    steps = {"moving_mass_kg": 1.02, "bulk_modulus_pa": 1.02, "dead_volume_a_m3": 1.05, "friction_coulomb_pos_n": 1.05,
             "valve_rated_flow_m3_s": 1.02, "valve_hysteresis_half_width_v": 0.02, "sensor_offset_p_a": 2e4}
    plist = []
    for k, s in steps.items():
        q = p.copy()
        q[k] = q[k] * s if k not in ("valve_hysteresis_half_width_v", "sensor_offset_p_a") else q[k] + s
        plist.append(q)
    kw = {"command": True, "active": fit_mask}
    lock = sim.predict([p, *plist], rec, lockstep=True, threads=2, **kw)
    alone = sim.predict([p, *plist], rec, threads=2, **kw)
    tight = sim.predict([p, *plist], rec, threads=2, rtol=1e-7, **kw)
    for c in ("y", "p_a", "p_b"):
        assert np.array_equal(lock[0][c], alone[0][c], equal_nan=True), c  # the point: the same steps, bit for bit
        for i, k in enumerate(steps, 1):
            ref = (tight[i][c] - tight[0][c])[fit_mask]
            col = (lock[i][c] - lock[0][c])[fit_mask]
            size = np.linalg.norm(ref)
            if size < 1e-9 * np.linalg.norm(tight[0][c][fit_mask]):
                assert np.linalg.norm(col) <= 1e-6 * np.linalg.norm(tight[0][c][fit_mask]), (c, k)
                continue
            assert np.linalg.norm(col - ref) <= 0.05 * size, (c, k, np.linalg.norm(col - ref) / size)


def test_a_simulator_without_lockstep_has_its_jacobian_simulated_alone():
    """A problem asked for lockstep columns whose simulator takes no such option (a model of
    its own, the displacement loop) fits as one that simulates them alone, the option turned off
    after the first refusal."""

    def strict(plist, rec, **opts):
        if opts:
            raise TypeError(f"unexpected options {sorted(opts)}")
        return _simulate(plist, rec)

    nominal = {"amp": 0.02, "tau": 0.25, "ripple": 0.0}
    model = Model(nominal, [lin("amp", 0.01, -10, 10, step=0.01), logf("tau", 0.1, 10.0), lin("ripple", 0.001, -20, 20, step=0.01)],
                  np.zeros(3))
    fits = []
    for lockstep in (True, False):
        prob = dataclasses.replace(_problem(DEFAULT), simulate=strict, lockstep=lockstep)
        fitted, _, _ = fit(prob, model.at(model.start()), iters=30, ftol=1e-9)
        assert not prob.lockstep
        fits.append((fitted.params(), prob.simulations))
    assert fits[0] == fits[1]
    assert abs(fits[0][0]["tau"] - TRUE["tau"]) <= 0.01 * TRUE["tau"]


def _counting(calls: list[int]):
    def simulate(plist, rec, **opts):
        calls.append(len(plist))
        return _simulate(plist, rec, **opts)
    return simulate


def _start_model() -> Model:
    nominal = {"amp": 0.02, "tau": 0.25, "ripple": 0.0}
    model = Model(nominal, [lin("amp", 0.01, -10, 10, step=0.01), logf("tau", 0.1, 10.0), lin("ripple", 0.001, -20, 20, step=0.01)],
                  np.zeros(3))
    return model.at(model.start())


def test_a_parameter_set_predicted_again_is_not_simulated_again():
    """The same model re-predicted by a later stage comes from the problem's cache: the same
    readings, no simulation; another set, or the whole record instead of the working window, is
    simulated."""
    calls: list[int] = []
    prob = dataclasses.replace(_problem(DEFAULT), simulate=_counting(calls))
    a, b = dict(TRUE), {**TRUE, "tau": 0.5}
    first = prob.predict([a])[0]
    assert sum(calls) == 1 and prob.simulations == 1
    again, other = prob.predict([dict(a), b])
    assert sum(calls) == 2 and prob.simulations == 2, "only the new set is simulated"
    assert np.array_equal(again["y"], first["y"]) and not np.array_equal(other["y"], first["y"])
    prob.predict([a], whole=True)
    assert sum(calls) == 3, "the whole record is another prediction"
    prob.predict([a], noise={"y": np.zeros(2000)})
    assert sum(calls) == 4, "a prediction with other options is not taken from the cache"


def test_a_fit_stops_when_the_next_step_promises_less_than_ftol():
    """After one iteration that gains less than ftol, a fit whose Gauss-Newton model promises
    less than ftol for the next step stops (predicted_stop) instead of spending another
    iteration (a Jacobian and three trials) to see it: the same fit within the noise, fewer
    simulations; predicted_stop 0 restores two small iterations. (noise_cost below 1: the fit
    does not stop at the noise first.)"""
    out = {}
    for stop in (0.0, 1.0):
        prob = _problem(dataclasses.replace(DEFAULT, predicted_stop=stop, noise_cost=0.5))
        fitted, _, _ = fit(prob, _start_model(), iters=30, ftol=1e-3)
        out[stop] = (fitted.params(), prob.simulations)
    (p0, sims0), (p1, sims1) = out[0.0], out[1.0]
    for k, v in TRUE.items():
        assert abs(p1[k] - v) <= 0.01 * abs(v), (k, p1[k])
        assert abs(p1[k] - p0[k]) <= 0.005 * abs(v), (k, p1[k], p0[k])
    assert sims1 < sims0, (sims1, sims0)


def test_a_fit_started_with_the_jacobian_at_its_point_saves_one_differencing():
    """A refit from where a fit ended, given that fit's Jacobian (`jac0`), takes it for the first
    differencing of its schedule: over the same iterations one simulation per parameter fewer,
    the same fit."""
    prob = _problem(DEFAULT)
    model, pred, jac = fit(prob, _start_model(), iters=3, ftol=1e-9)
    model = model.at(model.x + np.array([0.2, 0.0, 0.0]))  # pushed off: the refit has work to do
    pred = prob.predict([model.params()])[0]
    jac = fit(prob, model, iters=1, pred0=pred, ftol=1e-9)[2]  # the Jacobian near there
    model = model.at(model.x)
    out = {}
    for warm in (None, jac):
        p = _problem(DEFAULT)
        fitted, _, _ = fit(p, model, iters=4, pred0=pred, ftol=1e-9, jac0=warm)
        out[warm is None] = (fitted.params(), p.simulations)
    (p_cold, sims_cold), (p_warm, sims_warm) = out[True], out[False]
    assert sims_warm <= sims_cold - 3, (sims_warm, sims_cold)
    assert abs(p_warm["amp"] - p_cold["amp"]) <= 0.02 * TRUE["amp"]


def test_a_fit_reports_why_it_ended_and_stops_where_its_caller_says():
    """`info` says how a fit ended (converged on its ftol, or its budget spent); `stop`, asked
    after every iteration with the costs so far and the iterations left, ends it there (fewer
    simulations, the costs it saw falling)."""
    prob = _problem(DEFAULT)
    info: dict = {}
    fit(prob, _start_model(), iters=2, ftol=1e-9, info=info)
    assert info == {"iterations": 2, "ended": "budget"}
    info = {}
    fit(prob, _start_model(), iters=60, ftol=1e-2, info=info)
    assert info["ended"] == "converged" and info["iterations"] < 60
    full = _problem(DEFAULT)
    fit(full, _start_model(), iters=8, ftol=1e-9)
    seen: list = []
    stopped = _problem(DEFAULT)
    info = {}
    fit(stopped, _start_model(), iters=8, ftol=1e-9, info=info,
        stop=lambda costs, left: seen.append((list(costs), left)) or len(costs) > 2)
    assert info == {"iterations": 2, "ended": "stopped"}
    assert [left for _, left in seen] == [7, 6] and seen[-1][0][0] > seen[-1][0][-1]
    assert stopped.simulations < full.simulations
