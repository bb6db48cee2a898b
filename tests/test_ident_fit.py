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
