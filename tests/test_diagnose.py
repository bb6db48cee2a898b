"""`htm diagnose`: the CLI and its files per DATA_FORMAT.md, predictions.csv <-> rmse consistency,
and honest refusals of garbage (wrong rig, no excitation, a 3-sample file)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from htm.cli import main
from htm.ident import features as ft
from htm.ident import proving
from htm.ident.diagnose import IdentificationError, diagnose
from htm.ident.records import Record, write_record
from htm.ident.report import read_predictions

REPORT_KEYS = {"format", "record", "baseline", "findings", "final", "unexplained", "predictions", "settings", "trace"}
FINDING_KEYS = {"effect", "channel", "params", "rmse_before", "rmse_after", "evidence"}


def rmse(pred: np.ndarray, meas: np.ndarray) -> float:
    ok = np.isfinite(meas)
    return float(np.sqrt(np.mean((pred[ok] - meas[ok]) ** 2)))


@pytest.fixture(scope="module")
def offset_run(tmp_path_factory) -> tuple[Record, Path, int, str]:
    """The thesis's discovery on the proving ground: a 4 bar offset on p_a, diagnosed by the CLI,
    with the metadata kept apart from the table (--meta)."""
    tmp = tmp_path_factory.mktemp("diag")
    rec, _ = proving.make_record({"sensor_offset": {"channel": "p_a", "offset_pa": 4e5}}, seed=11, duration_s=8)
    table, meta = write_record(rec, tmp / "rec" / "offset_pa")
    moved = tmp / "meta.json"
    meta.rename(moved)
    out = tmp / "out"
    code = main(["diagnose", str(table), "--meta", str(moved), "--out", str(out)])
    return rec, out, code, table.name


def test_cli_writes_report_json_exactly_per_data_format(offset_run):
    rec, out, code, _ = offset_run
    assert code == 0
    report = json.loads((out / "report.json").read_text())
    assert set(report) == REPORT_KEYS  # closed loop: no horizon_s
    assert report["format"] == "htm-diagnosis/1"
    assert report["record"] == "offset_pa"
    assert report["predictions"] == "predictions.csv"
    channels = ["y", "v", "p_a", "p_b", "p_s"]
    assert set(report["baseline"]) == {"params", "rmse"} and set(report["final"]) == {"params", "rmse"}
    assert list(report["baseline"]["rmse"]) == channels and list(report["final"]["rmse"]) == channels
    assert "moving_mass_kg" in report["baseline"]["params"] and "bulk_modulus_pa" in report["baseline"]["params"]
    assert report["unexplained"] is False
    [f] = report["findings"]
    assert set(f) == FINDING_KEYS
    assert (f["effect"], f["channel"]) == ("sensor_offset", "p_a")
    assert f["params"]["offset_pa"] == pytest.approx(4e5, rel=0.05)
    assert "p_a" in f["evidence"]
    assert f["rmse_after"]["p_a"] < 0.2 * f["rmse_before"]["p_a"]


def test_every_rmse_comes_from_the_predictions_csv(offset_run):
    rec, out, _, _ = offset_run
    report = json.loads((out / "report.json").read_text())
    pred = read_predictions(out / "predictions.csv")
    assert list(pred) == ["t"] + [f"{c}_{w}" for c in ("y", "v", "p_a", "p_b", "p_s") for w in ("before", "after")]
    np.testing.assert_allclose(pred["t"], rec.columns["t"], rtol=0, atol=1e-9)
    for c in report["final"]["rmse"]:
        before = rmse(pred[f"{c}_before"], rec.columns[c])
        after = rmse(pred[f"{c}_after"], rec.columns[c])
        assert report["baseline"]["rmse"][c] == pytest.approx(before, rel=1e-6)
        assert report["findings"][0]["rmse_before"][c] == pytest.approx(before, rel=1e-6)
        assert report["findings"][-1]["rmse_after"][c] == pytest.approx(after, rel=1e-6)
        assert report["final"]["rmse"][c] == pytest.approx(after, rel=1e-6)


def test_report_md_shows_residuals_and_evidence_plots(offset_run):
    _, out, _, _ = offset_run
    md = (out / "report.md").read_text()
    assert "sensor_offset" in md and "Unexplained" in md
    images = [line.split("(")[1].rstrip(")") for line in md.splitlines() if line.startswith("![")]
    assert "residuals.png" in images and any(i.startswith("finding_1_sensor_offset") for i in images)
    for name in images:
        png = (out / name).read_bytes()
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 5000


def _cli_error(args: list[str], capsys) -> str:
    code = main(args)
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert "Traceback" not in err and len(err.splitlines()) == 1
    return err


def test_a_three_sample_file_cannot_be_identified(tmp_path, capsys):
    rec, _ = proving.make_record({}, seed=3, duration_s=2)
    tiny = Record({k: v[:3] for k, v in rec.columns.items()}, rec.meta, "tiny")
    table, _ = write_record(tiny, tmp_path / "tiny")
    err = _cli_error(["diagnose", str(table), "--out", str(tmp_path / "out")], capsys)
    assert "cannot identify" in err and "3 samples" in err
    assert not (tmp_path / "out" / "report.json").exists()


def test_a_constant_signal_cannot_be_identified(tmp_path, capsys):
    rec, _ = proving.make_record({}, seed=4, duration_s=4)
    n = len(rec.columns["t"])
    cols = {"t": rec.columns["t"], "u": np.zeros(n), "y": np.full(n, 0.1), "y_ref": np.full(n, 0.1),
            "p_a": np.full(n, 9.6e6), "p_b": np.full(n, 9.4e6), "p_s": np.full(n, 19e6)}
    table, _ = write_record(Record(cols, rec.meta, "flat"), tmp_path / "flat")
    err = _cli_error(["diagnose", str(table), "--out", str(tmp_path / "out")], capsys)
    assert "cannot identify" in err and "no excitation" in err


def test_a_record_of_another_rig_is_refused_not_diagnosed():
    """The table comes from the proving-ground rig; the metadata claims a cylinder with 2.5x the
    area (and so 2.5x the force per bar) and a valve of 3x the flow. No effect may be claimed."""
    rec, _ = proving.make_record({}, seed=5, duration_s=6)
    meta = json.loads(json.dumps(rec.meta))
    for k in ("area_a_m2", "area_b_m2"):
        meta["rig"][k] *= 2.5
    meta["rig"]["valve_rated_flow_m3_s"] *= 3.0
    with pytest.raises(IdentificationError, match="cannot identify.*does not match its metadata's rig"):
        diagnose(Record(rec.columns, meta, "other_rig"))


def test_an_open_loop_record_states_its_horizon_and_keeps_rmse_consistent(tmp_path):
    """Without a controller the predictions replay the recorded command open loop, restarted
    from the measurement every horizon_s, which report.json then states."""
    rec, _ = proving.make_record({}, seed=8, duration_s=4)
    meta = {**rec.meta, "controller": None}
    report = diagnose(Record(rec.columns, meta, "open"), out_dir=tmp_path)
    on_disk = json.loads((tmp_path / "report.json").read_text())
    assert on_disk == json.loads(json.dumps(report))
    assert set(report) == REPORT_KEYS | {"horizon_s"} and report["horizon_s"] == pytest.approx(0.5)
    pred = read_predictions(tmp_path / "predictions.csv")
    for c, value in report["final"]["rmse"].items():
        assert value == pytest.approx(rmse(pred[f"{c}_after"], rec.columns[c]), rel=1e-6)
        # open loop over 0.5 s horizons tracks to the noise; the position, re-anchored only at
        # each horizon's start, integrates the velocity's error in between
        assert value < (10 if c == "y" else 3) * proving.NOISE_STD[c]
    assert report["findings"] == [] and report["unexplained"] is False  # a clean record


def test_a_short_rig_without_a_specimen_is_taken_as_declared():
    """A stroke shorter than the thesis rig's default zero-force position (0.1 m) with no
    specimen: the metadata is valid (the unused zero-force position sits mid-stroke)."""
    from htm.ident import sim

    rec, _ = proving.make_record({}, seed=8, duration_s=1)
    meta = {**rec.meta, "rig": {**rec.meta["rig"], "stroke_m": 0.065}, "specimen": None}
    p = sim.params_from_meta(meta)
    assert p["stroke_m"] == 0.065 and p["specimen_zero_force_position_m"] == pytest.approx(0.0325)
    assert p["specimen_stiffness_n_m"] == 0.0


@pytest.mark.parametrize("drop", [(), ("p_a", "p_b"), ("p_s",), ("v",)])
def test_bad_samples_are_dropped_with_a_warning_and_missing_channels_are_not_needed(drop):
    """One sample of 1e400 (inf) and one far out of the declared range in a kept channel are
    dropped, with a warning in the report, and do not change the diagnosis of a valve null bias;
    a record without pressures, without p_s or without v is diagnosed, not crashed."""
    rec, truth = proving.make_record({"valve_null_bias": {}}, seed=21, duration_s=20)
    # without p_s the supply is the declared one: keep the record before the power unit switches
    n = int(proving.SUPPLY_SWITCH_AT * len(rec.columns["t"])) if "p_s" in drop else None
    cols = {k: np.array(v[:n], dtype=float) for k, v in rec.columns.items() if k not in drop}
    bad = "p_a" if "p_a" in cols else "y"
    cols[bad][100] = float("1e400")
    cols[bad][200] = 1e9 if bad == "p_a" else 50.0
    report = diagnose(Record(cols, rec.meta, "bad"))
    assert any(bad in w for w in report["warnings"]), report.get("warnings")
    assert not proving.judge(report, truth)
    assert all(np.isfinite(v) for v in report["final"]["rmse"].values())


def test_one_channel_the_model_cannot_follow_is_left_out_not_the_record(tmp_path):
    """A velocity channel carrying a tone the rig cannot make (as a velocity sampled below its
    motion's bandwidth aliases): the record is diagnosed without it — a warning names it, the record
    is unexplained, nothing is claimed — and the channel is still predicted and reported."""
    rec, _ = proving.make_record({}, seed=5, duration_s=6)
    cols = dict(rec.columns)
    v = np.asarray(cols["v"], dtype=float)
    cols["v"] = v + 3.0 * float(np.std(v)) * np.sin(2 * np.pi * 0.37 * 500.0 * np.asarray(cols["t"]))
    table, meta = write_record(Record(cols, rec.meta, "aliased_v"), tmp_path / "aliased_v")
    assert main(["diagnose", str(table), "--out", str(tmp_path / "out")]) == 0
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["findings"] == [] and report["unexplained"] is True
    assert any("cannot follow v" in w and "left out of the fit" in w for w in report["warnings"])
    pred = read_predictions(tmp_path / "out" / "predictions.csv")
    assert report["final"]["rmse"]["v"] == pytest.approx(rmse(pred["v_after"], cols["v"]), rel=1e-6)
    assert report["final"]["rmse"]["y"] < 0.1 * float(np.std(cols["y"]))  # the rest is fitted
    assert "left out of the fit" in (tmp_path / "out" / "report.md").read_text()


def test_under_force_control_a_missed_position_with_a_pinned_rig_parameter_is_unexplained_not_refused():
    """Under force control the specimen, not the rig, sets the motion: a position the fit misses
    grossly while a parameter of the rig sits at its bound is a specimen's form the model lacks
    (here a closure 0.5 mm above the zero-force position, 5x as stiff as the specimen, which the
    search may not add: max_findings 0), not another rig. The record is reported unexplained, the
    pins named, the rule in the trace (it was refused as "does not match its metadata's rig"). A
    position-controlled record so is refused (test_a_record_of_another_rig_is_refused_not_diagnosed)."""
    rec, _ = proving.make_record({"specimen_nonlinearity": {"closure_stiffness_n_m": 1e7, "closure_offset_m": 5e-4}},
                                 seed=7, duration_s=10, experiment="force")
    assert rec.meta["controller"]["type"] == "force_p"
    report = diagnose(rec, max_findings=0)
    assert report["unexplained"] and not report["findings"]
    said = " ".join(report["warnings"])
    assert "at its bound" in said and "under force control the specimen sets the motion" in said, said
    rules = [e for e in report["trace"] if e["stage"] == "verdict" and "where the rig sets the motion" in e["rule"]]
    assert rules and rules[0]["numbers"]["pinned"] and "y" in rules[0]["numbers"]["beyond_form"], report["trace"]


def test_a_reading_whose_quantum_dwarfs_its_declared_noise_is_weighed_by_both():
    """A declared `noise_std` is the sensor's white noise; the reading is that signal quantized, so
    its noise is both, added in quadrature (features.reading_noise). A position read at a 5 µm
    quantum with 0.05 µm of declared noise weighed by the 0.05 µm alone made the true model's
    position 57 times its noise (and a foreign force-controlled record's position outweigh its
    load-cell offset 10,000-fold); weighed by both, the true model sits at the floor."""
    meta = {"sensors": {"y": {"resolution_m": 5e-6, "noise_std": 5e-8}, "p_a": {"noise_std": 3e4}}}
    assert ft.reading_noise(meta, "y", np.zeros(10)) == pytest.approx(np.hypot(5e-8, 5e-6 / np.sqrt(12)))
    assert ft.reading_noise(meta, "p_a", np.zeros(10)) == 3e4  # no quantum declared: the noise as declared
    x = np.random.default_rng(0).normal(0.0, 1e-3, 5000)
    assert ft.reading_noise(meta, "v", x) == ft.noise_floor(x)  # nothing declared: estimated from the record

    rec, _ = proving.make_record({}, seed=7, duration_s=10, sensors={"y": {"resolution": 5e-6, "noise_std": 5e-8}})
    stats: dict = {}
    report = diagnose(rec, stats=stats)
    assert stats["noise_floor"]["y"] == pytest.approx(np.hypot(5e-8, 5e-6 / np.sqrt(12)))
    assert stats["systematic_ratio"]["y"] < 2.0, stats["systematic_ratio"]
    assert not report["findings"] and not report["unexplained"]
