"""What crosses the Rust–Python boundary is typed: one `TestConfig` per test, errors that name the
spec's own field with its value and allowed range, outcomes and tables as typed objects (Arrow)."""
from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

import htm.core as core
import htm.feasibility
from htm.cli import main
from htm.errors import ParameterError, SpecError, SpecParameterError
from htm.spec import parse

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "ct_constant_force.toml"


def doc() -> dict:
    return tomllib.loads(EXAMPLE.read_text())


def test_one_htm_run_builds_one_config_and_every_stage_takes_that_object(tmp_path, monkeypatch, capsys):
    """`htm run` reads the spec into one TestConfig; the feasibility check, the engine and the
    summary take that object (nothing rebuilds or re-parses the config)."""
    built: list[core.TestConfig] = []
    seen: list[tuple[str, int]] = []
    real_config, real_run, real_checks = core.TestConfig, core.TestRun, htm.feasibility.core_checks

    def counting_config(*a, **k):
        c = real_config(*a, **k)
        built.append(c)
        return c

    def watching_run(config, *a, **k):
        seen.append(("TestRun", id(config)))
        return real_run(config, *a, **k)

    def watching_checks(config):
        seen.append(("feasibility", id(config)))
        return real_checks(config)

    monkeypatch.setattr(core, "TestConfig", counting_config)
    monkeypatch.setattr(core, "TestRun", watching_run)
    monkeypatch.setattr(htm.feasibility, "core_checks", watching_checks)
    out = tmp_path / "o"
    assert main(["run", str(EXAMPLE), "--out", str(out), "--quiet", "--store", str(tmp_path / "s"), "--no-recording"]) == 0
    assert len(built) == 1, f"{len(built)} TestConfig constructions in one `htm run`"
    assert {name for name, _ in seen} == {"TestRun", "feasibility"}
    assert {i for _, i in seen} == {id(built[0])}, "every stage got the one config object"
    assert [n for n, _ in seen].count("feasibility") == 1, "the rig's limits are assessed once"
    assert (out / "cycles.parquet").exists()


# ten (and more) representative fields: the spec's own path, the value given, the allowed range
BAD = [
    ("specimen.a0_m", lambda d: d["specimen"].update(a0_m=0.005), 0.005, "a/W in [0.2, 0.975]"),
    ("material.poisson_ratio", lambda d: d["material"].update(poisson_ratio=0.7), 0.7, "[0, 0.5)"),
    ("material.youngs_modulus_pa", lambda d: d["material"].update(youngs_modulus_pa=-2e11), -2e11, "Pa"),
    ("law.m", lambda d: d["law"].update(m=25.0), 25.0, "(0, 20]"),
    ("loading.r_ratio", lambda d: d["loading"].update(r_ratio=1.0), 1.0, "[-1, 1)"),
    ("loading.delta_f_n", lambda d: d["loading"].update(delta_f_n=-10.0), -10.0, "(0, inf) N"),
    ("loading.delta_f_n", lambda d: d["loading"].update(delta_f_n=80e3), 80e3, "K_IC"),
    ("loading.delta_k_pa_sqrt_m", lambda d: d["loading"].update(mode="constant_delta_k", delta_k_pa_sqrt_m=-1e6) or d["loading"].pop("delta_f_n"),
     -1e6, "(0, inf) Pa·√m"),
    ("loading.k_gradient_per_m", lambda d: d["loading"].update(mode="k_gradient", delta_k_pa_sqrt_m=15e6, k_gradient_per_m=-100.0)
     or d["loading"].pop("delta_f_n"), -100.0, "0.08 mm⁻¹"),
    ("loading.tolerance", lambda d: d["loading"].update(tolerance=0.5), 0.5, "(0, 0.2]"),
    ("loading.frequency_hz", lambda d: d["loading"].update(frequency_hz=0.0), 0.0, "(0, 6250]"),
    ("loading.control_rate_hz", lambda d: d["loading"].update(control_rate_hz=100.0), 100.0, "[160, 100000] Hz"),
    ("loading.hold_fraction", lambda d: d["loading"].update(waveform="trapezoid", rise_fraction=0.4, hold_fraction=0.5), 0.5, "(1 − 2·rise)"),
    ("end.a_over_w", lambda d: d["end"].update(a_over_w=0.99), 0.99, "0.975]"),
    ("run.rtol", lambda d: d["run"].update(rtol=0.5), 0.5, "[1e-8, 1e-2]"),
    ("rig.overrides.supply_pressure_pa", lambda d: d.update(rig={"overrides": {"supply_pressure_pa": -1.0}}), -1.0, "Pa"),
    ("precrack.r_ratio", lambda d: d.update(precrack={"mode": "constant_force", "delta_f_n": 5e3, "r_ratio": -3.0, "end_a_m": 0.017}),
     -3.0, "[-1, 1)"),
    ("controller.kp_v_per_n", lambda d: d.update(controller={"type": "force_p", "kp_v_per_n": 0.0}), 0.0, "non-zero"),
]


@pytest.mark.parametrize("field, edit, value, allowed", BAD, ids=[f"{b[0]}-{i}" for i, b in enumerate(BAD)])
def test_a_spec_error_names_the_specs_field_its_value_and_allowed_range(field, edit, value, allowed):
    d = doc()
    edit(d)
    with pytest.raises(SpecParameterError) as e:
        parse(d, "bad", check=False)
    err = e.value
    assert isinstance(err, SpecError) and isinstance(err, ParameterError)
    assert err.field == field
    assert err.value == pytest.approx(value) or (math.isnan(value) and math.isnan(err.value))
    assert allowed in err.allowed, err.allowed
    # the message is built from the parts
    msg = str(err)
    assert msg.startswith(f"{field} = ") and err.allowed in msg


def test_a_cli_spec_error_is_one_line_with_the_field_path(tmp_path, capsys):
    d = doc()
    text = EXAMPLE.read_text().replace("r_ratio = 0.1", "r_ratio = 1.5")
    p = tmp_path / "bad.toml"
    p.write_text(text)
    assert d["loading"]["r_ratio"] == 0.1
    assert main(["run", str(p), "--out", str(tmp_path / "o"), "--quiet", "--no-store"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "loading.r_ratio = 1.5" in err[0] and "[-1, 1)" in err[0], err


def test_core_parameter_errors_carry_their_parts():
    p = core.Params()
    p["supply_pressure_pa"] = -5.0
    with pytest.raises(core.ParameterError) as e:
        p.validate()
    assert (e.value.field, e.value.value) == ("supply_pressure_pa", -5.0)
    assert e.value.allowed and e.value.allowed in str(e.value)


def test_outcome_and_tables_are_typed_and_arrow():
    spec = parse(doc(), "ct")
    o = core.run_test(spec.config, "jump")
    assert isinstance(o, core.Outcome) and o.end_reason == "target_crack_length" and o.cycles > 0
    batch = pa.record_batch(o.table)  # the Arrow C Data Interface, no copy
    types = dict(zip(batch.schema.names, batch.schema.types, strict=True))
    assert types["cycle"] == pa.uint64() and types["phase"] == pa.uint8() and types["events"] == pa.uint32()
    assert types["a_m"] == pa.float64() and types["delta_k_pa_sqrt_m"] == pa.float64()
    assert batch.num_rows == len(o.table) > 100
    # the same schema as a table built from numpy columns (what cycles.parquet held before)
    assert batch.schema == pa.table({k: o.table[k] for k in o.table.keys()}).schema
    np.testing.assert_array_equal(batch.column("a_m").to_numpy(), o.table["a_m"])
    assert batch.column("a_m").to_numpy()[-1] == pytest.approx(o.a_end_m, rel=1e-3)
    # the columns survive the batch that exported them (the core's buffers stay alive)
    cols = core.columns(o.table)
    del o, batch
    assert cols["cycle"].dtype == np.uint64 and np.all(np.diff(cols["cycle"].astype(np.int64)) > 0)
    # a chunk of a TestRun: rows and raw samples as tables with named columns
    s = core.TestRun(spec.config, "full", core.RAW_POLICY)
    ch = s.advance(max_cycles=50)
    raw = pa.record_batch(ch.raw)
    assert raw.schema.names == list(core.RAW_COLUMNS) and raw.num_rows > 0
    assert ch.end_reason is None and len(ch.table) > 0


def test_batch_failures_are_per_item_exceptions():
    good = parse(doc(), "good").config
    d = doc()
    d["law"]["c"] = 1e-20  # grows through the specimen in a few cycles: the run ends, the others still run
    outs = core.run_batch([good, parse(d, "fast", check=False).config, good], "jump", 2)
    assert all(isinstance(o, (core.Outcome, core.HtmError)) for o in outs)
    assert isinstance(outs[0], core.Outcome) and isinstance(outs[2], core.Outcome)
    assert outs[0].cycles == outs[2].cycles


def test_replay_and_loop_batches_follow_the_same_convention():
    """Every batch call returns one item per input: its result, or the HtmError of the input the
    core could not carry (no NaN arrays with an error string beside them)."""
    good, bad = core.Params(), core.Params()
    bad["tank_pressure_pa"] = bad["supply_pressure_pa"] + 1e5
    n = 200
    out = core.replay([good, bad, good], 1e-3, np.zeros(n), threads=2)
    assert isinstance(out[0], dict) and "error" not in out[0] and len(out[0]["y"]) == n and np.all(np.isfinite(out[0]["y"]))
    assert isinstance(out[1], core.ParameterError) and out[1].field == "tank_pressure_pa"
    assert np.array_equal(out[0]["y"], out[2]["y"])
    lp = core.LoopParams()
    lbad = core.LoopParams()
    lbad["asymmetry"] = 1.5
    lout = core.loop_simulate([lbad, lp], 1e-3, np.zeros(n))
    assert isinstance(lout[0], core.ParameterError) and isinstance(lout[1], dict) and "error" not in lout[1]


def test_a_config_is_not_a_dict_and_is_built_from_the_spec_once():
    spec = parse(doc(), "ct")
    cfg = spec.config
    assert isinstance(cfg, core.TestConfig)
    assert cfg.frequency_hz == 10.0 and cfg.r_ratios == [0.1] and cfg.sections == ["loading"] and not cfg.variable_amplitude
    # a rig's own parameters give a new config, checked again, the spec's untouched
    p = core.Params()
    p["supply_pressure_pa"] = 15e6
    other = cfg.with_params(p)
    assert other.params["supply_pressure_pa"] == 15e6 and cfg.params["supply_pressure_pa"] != 15e6
    bad = p.copy()
    bad["supply_pressure_pa"] = -1.0
    with pytest.raises(core.ParameterError) as e:
        cfg.with_params(bad)
    assert e.value.field == "rig.overrides.supply_pressure_pa"
