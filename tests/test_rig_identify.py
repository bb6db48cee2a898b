"""`htm rig identify`'s safety path (issue 30, item 2): a limit that trips during the experiment
stops it safely (valve null, amplifier off, supply unloaded), says which detector, and keeps every
sample recorded up to the trip. The identification itself (two hidden effects found, none on a
clean rig) takes ~100 s per rig: `benchmarks/rig_identify.py`."""
import json

import numpy as np
import pytest

from htm.control.identify import Plan, identify
from htm.devices.config import virtual_config
from htm.errors import HtmError
from htm.ident.records import read_record
from htm.record.store import Store


def test_a_trip_stops_the_experiment_safely_and_keeps_the_record(tmp_path, monkeypatch):
    closed = {}
    from htm.devices import rig as rig_mod
    close = rig_mod.VirtualRig.close

    def spy(self):  # what the rig's outputs were when the session released it
        closed.update(valve=self.daq.output(self._valve), relay=self.daq.relay(self._relay),
                      supply=self.daq.output(self._supply))
        close(self)
    monkeypatch.setattr(rig_mod.VirtualRig, "close", spy)
    cfg = virtual_config("lockstep", virtual={"effects": {}})
    plan = Plan(ramp_speeds_m_s=(0.005,), sweep_s=2.0)
    res = identify(cfg, tmp_path / "id", plan=plan, inject=("supply_loss", 1.0, 0.8), store=tmp_path / "store")
    assert res.tripped and res.tripped[0].startswith("supply_pressure"), res.tripped
    assert res.report is None and not (tmp_path / "id" / "report.json").exists(), "no diagnosis of a cut record"
    assert closed == {"valve": 0.0, "relay": False, "supply": 0.0}, closed
    rec = read_record(tmp_path / "id" / "identify.csv")
    assert rec.columns["t"].size == res.samples > 0.8 * 500
    assert np.isfinite(rec.columns["y"]).all() and json.loads((tmp_path / "id" / "identify.json").read_text())["controller"] is None
    with Store(tmp_path / "store") as st:  # kept in the test store too, as stopped, with its trip
        t = st.get(res.test_id)
        assert t["kind"] == "identify" and t["status"] == "stopped" and "supply_pressure" in t["end_reason"]
        assert read_record(st.test_dir(res.test_id) / "identify.csv").columns["t"].size == res.samples
    with pytest.raises(HtmError, match="already holds an identification"):
        identify(cfg, tmp_path / "id", plan=plan)


def _spy_close(monkeypatch) -> dict:
    closed = {}
    from htm.devices import rig as rig_mod
    close = rig_mod.VirtualRig.close

    def spy(self):  # what the rig's outputs were when the session released it
        closed.update(valve=self.daq.output(self._valve), relay=self.daq.relay(self._relay),
                      supply=self.daq.output(self._supply))
        close(self)
    monkeypatch.setattr(rig_mod.VirtualRig, "close", spy)
    return closed


def test_a_lost_transducer_stops_the_experiment_safely_says_so_and_keeps_the_record(tmp_path, monkeypatch):
    closed = _spy_close(monkeypatch)
    cfg = virtual_config("lockstep", virtual={"effects": {}})
    plan = Plan(ramp_speeds_m_s=(0.005,), sweep_s=2.0)
    res = identify(cfg, tmp_path / "id", plan=plan, inject=("transducer_silent", 1.0, 0.8), store=tmp_path / "store")
    assert res.tripped and res.tripped[0].startswith("transducer_silent"), res.tripped
    assert closed == {"valve": 0.0, "relay": False, "supply": 0.0}, closed
    assert res.report is None and not (tmp_path / "id" / "model.json").exists()
    rec = read_record(tmp_path / "id" / "identify.csv")
    assert rec.columns["t"].size == res.samples and res.samples >= 0.8 * 500
    with Store(tmp_path / "store") as st:
        t = st.get(res.test_id)
        assert t["status"] == "stopped" and "transducer_silent" in t["end_reason"]


def test_a_record_the_diagnosis_refuses_is_said_with_the_rig_safe_and_the_record_kept(tmp_path, monkeypatch, capsys):
    """`htm rig identify` with an amplitude too small to excite anything: the diagnosis refuses the
    record; one line says why, that the rig ended safely and where the record is; exit 2."""
    from htm.cli import main

    closed = _spy_close(monkeypatch)
    tag = f"idrefuse-{tmp_path.name[-12:]}"
    (tmp_path / "rig.toml").write_text(f'[bus]\ninterface = "virtual"\nchannel = "{tag}"\n[analog]\ndevice = "{tag}"\n'
                                       '[loop]\nmode = "lockstep"\nrate_hz = 500.0\n[virtual.effects]\n')
    monkeypatch.setenv("HTM_STORE", str(tmp_path / "store"))
    code = main(["rig", "identify", str(tmp_path / "rig.toml"), "--amplitude", "0.0005", "--out", str(tmp_path / "id")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert "no excitation" in err and "ended safely" in err and "identify.csv" in err and "status failed" in err, err
    assert closed == {"valve": 0.0, "relay": False, "supply": 0.0}, closed
    rec = read_record(tmp_path / "id" / "identify.csv")
    assert rec.columns["t"].size > 1000 and not (tmp_path / "id" / "model.json").exists()
    with Store(tmp_path / "store") as st:
        (t,) = [r for r in st.list_tests() if r["kind"] == "identify"]
        assert t["status"] == "failed" and read_record(st.test_dir(t["id"]) / "identify.csv").columns["t"].size == rec.columns["t"].size
