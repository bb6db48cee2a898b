"""`htm e647` and `htm crack fit|predict`: outputs and clear errors for bad input."""
import csv
import json

import numpy as np
import pytest

from htm.cli import main
from htm.fatigue.data import Setup
from htm.fatigue.laws import Model

G = ["--geometry", "mt", "--width-m", "0.1524", "--thickness-m", "0.00254", "--delta-p-n", "18680", "--r-ratio", "0.2"]
MT = Setup.from_loads("mt", 0.1524, 2.54e-3, delta_p_n=18680.0, r_ratio=0.2)


def _write(path, rows, header=("specimen", "cycles", "a_mm")):
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)
    return str(path)


@pytest.fixture
def an_csv(tmp_path):
    true = Model("paris", {"log10_c": -10.0, "m": 2.9})
    rows = []
    for s, dc in (("A", -0.03), ("B", 0.03)):
        m = Model("paris", {"log10_c": -10.0 + dc, "m": 2.9})
        a = np.linspace(9e-3, 40e-3, 100)
        rows += [(s, f"{n:.1f}", f"{x * 1e3:.5f}") for n, x in zip(m.life_curve(MT, a), a)]
    return _write(tmp_path / "an.csv", rows), true


def test_e647_writes_reduced_table_and_report(tmp_path, an_csv, capsys):
    assert main(["e647", an_csv[0], *G, "--out", str(tmp_path / "e")]) == 0
    rows = list(csv.DictReader(open(tmp_path / "e" / "reduced.csv")))
    assert list(rows[0].keys()) == ["specimen", "cycles", "a_m", "a_fit_m", "dadn_m_per_cycle", "delta_k_mpa_sqrt_m",
                                    "kmax_mpa_sqrt_m", "valid", "reasons"]
    r = next(r for r in rows if r["dadn_m_per_cycle"])
    assert float(r["kmax_mpa_sqrt_m"]) == pytest.approx(float(r["delta_k_mpa_sqrt_m"]) / 0.8)
    assert (tmp_path / "e" / "report.md").exists() and (tmp_path / "e" / "dadn_dk.png").exists()


def test_crack_fit_then_predict(tmp_path, an_csv, capsys):
    path, true = an_csv
    assert main(["crack", "fit", path, *G, "--law", "paris", "--out", str(tmp_path / "f")]) == 0
    model = json.loads((tmp_path / "f" / "model.json").read_text())
    assert model["law"] == "paris"
    assert model["parameters"]["m"]["value"] == pytest.approx(2.9, abs=0.03)
    assert model["parameters"]["m"]["stderr"] > 0
    # the two specimens differ by ±0.03 in log10 C: that scatter is what remains
    assert model["fit"]["rms_log10_rate"] < 0.04 and model["fit"]["life_rms_rel"] < 0.1
    capsys.readouterr()
    predict = ["crack", "predict", str(tmp_path / "f" / "model.json"), *G, "--a0-m", "0.009", "--af-m", "0.04"]
    assert main([*predict, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    want = true.life(MT, 0.009, 0.04)["cycles"]
    assert out["cycles"] == pytest.approx(want, rel=0.05)
    # a person reads the same life, labelled, in engineering units
    assert main(predict) == 0
    text = capsys.readouterr().out
    assert f"life   {out['cycles']:,.0f} cycles" in text and "9.000 → 40.000 mm" in text


def test_crack_fit_other_laws_and_auto(tmp_path, an_csv):
    for law in ("forman", "nasgro", "auto"):
        assert main(["crack", "fit", an_csv[0], *G, "--law", law, "--fit-by", "life", "--out", str(tmp_path / law)]) == 0
        m = json.loads((tmp_path / law / "model.json").read_text())
        assert m["fit"]["method"] == "life" and m["fit"]["life_rms_rel"] < 0.1


@pytest.mark.parametrize("rows,header,extra,message", [
    ([("1", "0", "9.0"), ("1", "500", "9.2"), ("1", "400", "9.4")], ("specimen", "cycles", "a_mm"), [], "non-monotonic"),
    ([("1", "0", "9.0"), ("1", "500", "90.2")], ("specimen", "cycles", "a_mm"), [], "outside the MT geometry"),
    ([("0", "9.0"), ("500", "9.2")], ("cycles", "crack"), [], "`a_m` (or `a_mm`) is missing"),
    ([("0", "9.0"), ("500", "9.2")], ("cycles", "a_m"), [], "looks like millimetres"),
])
def test_bad_input_is_a_one_line_error(tmp_path, capsys, rows, header, extra, message):
    path = _write(tmp_path / "bad.csv", rows, header)
    assert main(["e647", path, *G, "--out", str(tmp_path / "o"), *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and err.count("\n") == 1


def test_negative_load_and_mm_width_are_rejected(tmp_path, an_csv, capsys):
    g = [a if a != "18680" else "-18680" for a in G]
    assert main(["e647", an_csv[0], *g, "--out", str(tmp_path / "o")]) == 2
    assert "loads must be positive" in capsys.readouterr().err
    g = [a if a != "0.1524" else "152.4" for a in G]
    assert main(["crack", "fit", an_csv[0], *g, "--out", str(tmp_path / "o")]) == 2
    assert "looks like millimetres" in capsys.readouterr().err


def test_every_subcommand_has_help(capsys):
    for argv in (["e647", "--help"], ["crack", "--help"], ["crack", "fit", "--help"], ["crack", "predict", "--help"]):
        with pytest.raises(SystemExit) as e:
            main(argv)
        assert e.value.code == 0
        assert "usage: htm" in capsys.readouterr().out
