"""`import htm` is the scripting API: each public name is the real object of the module that
defines it, documented with numpydoc sections and units, and importing htm stays cheap."""
import subprocess
import sys
from importlib import import_module
from pathlib import Path

import pytest

import htm
from htm import control, errors, params, run, spec
from htm.core import Machine, Params
from htm.devices import config
from htm.fatigue import data, e647, sn, staircase, strainlife
from htm.ident import diagnose, proving, records
from htm.record import store

simulate = import_module("htm.simulate")  # the module; htm.simulate is its function
SPEC = Path(__file__).resolve().parents[1] / "examples" / "ct_constant_force.toml"

REAL = {
    "Machine": Machine, "Params": Params, "thesis_rig": params.thesis_rig,
    "simulate": simulate.simulate, "track": simulate.track,
    "TestSpec": spec.TestSpec, "load_spec": spec.load, "run_test": run.run_test,
    "Store": store.Store, "Session": control.session.Session, "virtual_config": config.virtual_config,
    "read_a_n": data.read_a_n, "CrackData": data.CrackData, "Setup": data.Setup, "e647": e647.reduce,
    "read_record": records.read_record, "Record": records.Record, "diagnose": diagnose.diagnose,
    "write_record": records.write_record, "proving_record": proving.make_record,
    "HtmError": errors.HtmError, "ParameterError": errors.ParameterError, "InputError": errors.InputError,
    "SolverError": errors.SolverError, "SpecError": errors.SpecError, "InfeasibleTest": errors.InfeasibleTest, "RecordError": errors.RecordError,
    "DeviceError": errors.DeviceError, "InterlockTripped": errors.InterlockTripped,
    "read_sn": sn.read_sn, "sn_fit": sn.sn_fit, "miner_damage": sn.miner_damage, "staircase": staircase.dixon_mood,
    "read_en": strainlife.read_en, "en_fit": strainlife.en_fit,
}
# the names this branch documented (htm.ident's docstrings are its own work's to convert)
NUMPYDOC = ["thesis_rig", "TestSpec", "load_spec", "run_test", "Store", "Session", "virtual_config",
            "read_a_n", "CrackData", "Setup", "e647"]
UNITS = ("[m]", "[N]", "[Pa", "[Hz]", "SI", "[m/s]")


def test_every_public_name_is_the_real_thing():
    assert set(htm.__all__) == set(REAL) | {"__version__"}
    for name, obj in REAL.items():
        assert getattr(htm, name) is obj, name
        assert name in dir(htm)
    with pytest.raises(AttributeError):
        htm.no_such_name  # noqa: B018 (the attribute access is the test)


@pytest.mark.parametrize("name", NUMPYDOC)
def test_public_docstrings_are_numpydoc_with_units(name):
    doc = getattr(htm, name).__doc__ or ""
    assert any(f"\n    {h}\n    {'-' * len(h)}\n" in doc for h in ("Parameters", "Attributes", "Returns", "Notes")), doc
    assert any(u in doc for u in UNITS), f"{name}: no unit stated"


def test_import_htm_loads_nothing_heavy():
    code = ("import sys, htm; heavy = ('scipy', 'pyarrow', 'canopen', 'can', 'textual', 'rerun', 'htm.control', "
            "'htm.record', 'htm.ident', 'htm.fatigue'); print([m for m in heavy if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_run_test_takes_a_spec_path_and_returns_the_table():
    out = htm.run_test(SPEC)
    assert out.end_reason and out.cycles > 0
    assert out.a_end_m > htm.load_spec(SPEC).a0_m
    assert len(out.table["a_m"]) > 0


def test_dir_shows_the_public_names_only():
    """`dir(htm)` is what a script may use: `__all__`, not the helpers the package imports."""
    assert dir(htm) == sorted(htm.__all__)
    for private in ("Any", "import_module", "TYPE_CHECKING", "annotations", "core", "errors", "params"):
        assert private not in dir(htm), private


# the methods a console or a script calls on the two handles, each documented with its units
METHODS = {
    "Session": ("hold", "resume", "stop", "detectors", "feed_since", "start", "open"),
    "Store": ("get", "list_tests", "set_results", "test_dir", "cycles", "raw", "export"),
}
METHOD_UNITS = {"detectors": "[m]", "feed_since": "[m/s]", "get": "[m]", "list_tests": "[m]", "set_results": "[m]",
                "resume": "cycles", "stop": "cycles", "hold": "cycle"}


@pytest.mark.parametrize("cls,method", [(c, m) for c, ms in METHODS.items() for m in ms])
def test_session_and_store_methods_have_docstrings(cls, method):
    doc = getattr(getattr(htm, cls), method).__doc__ or ""
    assert len(doc.split()) >= 8, f"{cls}.{method}: {doc!r}"
    if method in METHOD_UNITS:
        assert METHOD_UNITS[method] in doc, f"{cls}.{method}: no unit {METHOD_UNITS[method]}"
