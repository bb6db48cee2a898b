"""Identified models that travel: `htm diagnose` writes model.json for both model families and
`htm predict` re-simulates another record of the same rig with it (to the noise), tares a new
session's zero, and refuses what it cannot do without writing anything."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from htm.cli import main
from htm.ident import proving
from htm.ident.loop_proving import NOISE_STD, make_loop_record
from htm.ident.records import Record, write_record
from htm.ident.report import read_predictions


def _rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2)))


@pytest.fixture(scope="module")
def loop_model(tmp_path_factory) -> tuple[Path, dict]:
    """A machine loop with a slow valve and a specimen, diagnosed through the CLI."""
    tmp = tmp_path_factory.mktemp("loop")
    rec, truth = make_loop_record({"valve_dynamics": {"tau_s": 0.01}}, seed=6, specimen=True)
    table, _ = write_record(rec, tmp / "first")
    assert main(["diagnose", str(table), "--out", str(tmp / "diag")]) == 0
    return tmp, truth


def test_model_json_holds_the_family_its_parameters_and_findings(loop_model):
    tmp, truth = loop_model
    model = json.loads((tmp / "diag" / "model.json").read_text())
    assert model["format"] == "htm-model/1" and model["family"] == "machine_position"
    assert model["channels"] == ["y", "f"]
    assert [e["effect"] for e in model["effects"]] == ["valve_dynamics"]
    assert model["params"]["valve_tau_s"] == pytest.approx(0.01, rel=0.3)
    report = json.loads((tmp / "diag" / "report.json").read_text())
    assert model["params"]["valve_tau_s"] == report["findings"][0]["params"]["tau_s"]
    md = (tmp / "diag" / "report.md").read_text()
    assert "displacement loop" in md and (tmp / "diag" / "loop_response.png").stat().st_size > 10_000


def test_predict_reproduces_another_run_of_the_same_rig_to_the_noise(loop_model):
    tmp, _ = loop_model
    other, _ = make_loop_record({"valve_dynamics": {"tau_s": 0.01}}, seed=6, specimen=True, variant=1, half_range_m=0.004)
    table, _ = write_record(other, tmp / "second")
    assert main(["predict", str(tmp / "diag" / "model.json"), str(table), "--out", str(tmp / "pred")]) == 0
    report = json.loads((tmp / "pred" / "report.json").read_text())
    pred = read_predictions(tmp / "pred" / "predictions.csv")
    assert list(pred) == ["t", "y_pred", "f_pred"]
    for c in ("y", "f"):
        assert report["rmse"][c] == pytest.approx(_rmse(pred[f"{c}_pred"], other.columns[c]), rel=1e-6)
        assert report["rmse"][c] < 1.3 * NOISE_STD[c], c
    # the run is not the fitted one: its command differs
    first = json.loads((tmp / "diag" / "report.json").read_text())
    assert first["record"] != report["record"]


def test_tare_takes_a_new_sessions_zero_from_its_rest_and_refuses_a_moving_start(loop_model, capsys):
    tmp, _ = loop_model
    other, _ = make_loop_record({"valve_dynamics": {"tau_s": 0.01}}, seed=6, specimen=True, variant=2)
    # a new session: the position transducer zeroed 0.3 mm away (command, position and the
    # specimen's declared zero-force position move with it) and the load cell 150 N away
    shifted = dict(other.columns, y=other.columns["y"] + 3e-4, y_ref=other.columns["y_ref"] + 3e-4, f=other.columns["f"] + 150.0)
    meta = dict(other.meta, specimen=dict(other.meta["specimen"], zero_force_position_m=other.meta["specimen"]["zero_force_position_m"] + 3e-4))
    table, _ = write_record(Record(shifted, meta, "rezeroed"), tmp / "rezeroed")
    model = str(tmp / "diag" / "model.json")
    assert main(["predict", model, str(table), "--out", str(tmp / "raw")]) == 0
    assert main(["predict", model, str(table), "--tare", "0.5", "--out", str(tmp / "tared")]) == 0
    raw = json.loads((tmp / "raw" / "report.json").read_text())
    tared = json.loads((tmp / "tared" / "report.json").read_text())
    assert raw["rmse"]["f"] > 5 * NOISE_STD["f"]
    assert tared["rmse"]["f"] < 1.5 * NOISE_STD["f"] and tared["rmse"]["y"] < 1.5 * NOISE_STD["y"]
    assert tared["tare"]["f"] == pytest.approx(150.0, abs=15.0)
    # the record is moving 1.5 s in: that is no rest to tare on
    capsys.readouterr()
    assert main(["predict", model, str(table), "--tare", "5", "--out", str(tmp / "moving")]) == 2
    err = capsys.readouterr().err
    assert "does not rest" in err and not (tmp / "moving").exists()


def test_a_broken_or_mismatched_model_is_refused_by_name(loop_model, tmp_path, capsys):
    tmp, _ = loop_model
    model = json.loads((tmp / "diag" / "model.json").read_text())
    table = next((tmp).glob("second.csv"))
    cases = {"unknown machine_position parameter `bogus`": dict(model, params={**model["params"], "bogus": 1.0}),
             "format": dict(model, format="htm-model/0"),
             "valve-level model": dict(model, family="valve", params={"moving_mass_kg": 50.0})}
    for needle, content in cases.items():
        path = tmp_path / "m.json"
        path.write_text(json.dumps(content))
        assert main(["predict", str(path), str(table), "--out", str(tmp_path / "out")]) == 2
        assert needle in capsys.readouterr().err
        assert not (tmp_path / "out").exists()


def test_a_valve_level_model_travels_too(tmp_path):
    """The valve family's model.json (here the proving-ground rig's true parameters) re-simulates
    another record of that rig through the core's closed loop, to the noise."""
    from htm.core import Params
    from htm.ident.predict import model_dict

    first, truth = proving.make_record({}, seed=21, duration_s=4)
    params = Params("base")
    for k, v in truth["params"].items():
        params[k] = v
    path = tmp_path / "model.json"
    path.write_text(json.dumps(model_dict("valve", params, first)))
    assert json.loads(path.read_text())["family"] == "valve"
    longer, _ = proving.make_record({}, seed=21, duration_s=8)  # same rig (seed), another run
    table, _ = write_record(longer, tmp_path / "longer")
    assert main(["predict", str(path), str(table), "--out", str(tmp_path / "pred")]) == 0
    report = json.loads((tmp_path / "pred" / "report.json").read_text())
    assert set(report["rmse"]) == {"y", "v", "p_a", "p_b", "p_s"}
    # as close as on the record the model came from (the proving ground switches its supply
    # part-way, which the re-simulation follows from the measured p_s only approximately)
    table0, _ = write_record(first, tmp_path / "first")
    assert main(["predict", str(path), str(table0), "--out", str(tmp_path / "same")]) == 0
    same = json.loads((tmp_path / "same" / "report.json").read_text())
    for c, v in report["rmse"].items():
        assert v < 1.5 * max(same["rmse"][c], proving.NOISE_STD[c]), (c, v, same["rmse"][c])
    assert report["rmse"]["y"] < 0.05 * float(np.std(longer.columns["y"]))
