"""The console's twin (issue 30): Setup simulates on a model.json's twin instead of the nominal rig,
and the Identify tab runs `htm rig identify` on the connected rig — Textual's pilot, a virtual
rig with a hidden valve effect."""
import asyncio
import json

from test_twin import write_model
from textual.widgets import Input
from tui_pilot import text, until

from htm.control.identify import Plan
from htm.control.session import Session
from htm.devices.config import virtual_config
from htm.record.store import Store
from htm.tui.app import HtmApp
from htm.tui.identify import IdentifyPane


def test_setup_simulates_on_the_twin_a_model_file_names(tmp_path, store):
    model = write_model(tmp_path / "model.json")
    weak = write_model(tmp_path / "weak.json", supply_pressure_pa=1.5e6)
    loop = tmp_path / "loop.json"
    loop.write_text(json.dumps({"format": "htm-model/1", "family": "machine_position", "params": {"kp_per_s": 30.0},
                                "channels": ["y"]}))

    async def go():
        app = HtmApp(session_factory=lambda: None)
        async with app.run_test(size=(150, 50)) as pilot:
            async def simulate(path: str) -> str:
                app.query_one("#model-path", Input).value = path
                await pilot.pause()
                await pilot.press("ctrl+s")
                await app.workers.wait_for_complete()
                await pilot.pause()
                return text(app, "#sim-result")

            nominal = await simulate("")
            assert "predicted life" in nominal and "nominal rig" in nominal, nominal
            twin = await simulate(str(model))
            assert "predicted life" in twin and f"twin {model}" in twin and "valve_null_bias" in twin, twin
            # the twin is what runs: a machine whose supply is weaker refuses the test the nominal rig runs
            refused = await simulate(str(weak))
            assert "simulation refused" in refused and "the actuator gives 3.31 kN in tension" in refused and "weak.json" in refused, refused
            bad = await simulate(str(loop))
            assert "simulation refused" in bad and "machine_position" in bad, bad
    asyncio.run(go())


def test_identify_runs_the_experiment_on_the_connected_rig_shows_the_findings_and_reconnects(tmp_path, store):
    cfg = virtual_config("lockstep", virtual={"effects": {"valve_null_bias": {"bias_v": 0.12}}})
    opened = []

    def connect():
        s = Session().open(cfg, virtual=True, paced=True)
        opened.append(s)
        return s

    async def go():
        app = HtmApp(config=cfg, session_factory=connect, store=tmp_path / "store")
        async with app.run_test(size=(150, 50)) as pilot:
            assert len(opened) == 1 and app.session is opened[0]
            pane = app.query_one(IdentifyPane)
            pane.plan = Plan(ramp_speeds_m_s=(0.005,), sweep_s=3.0, hold_s=0.3)  # a short experiment
            await pilot.press("f7")
            app.query_one("#identify-out", Input).value = str(tmp_path / "id")
            app.query_one("#identify-amplitude", Input).value = "abc"
            await pilot.click("#identify-run")
            await pilot.pause()
            assert pane.outcome is None and not pane.busy, "a bad amplitude runs nothing"
            app.query_one("#identify-amplitude", Input).value = "4"
            await pilot.click("#identify-run")
            await pilot.pause()
            assert app.session is None, "the rig is handed over to the experiment"
            await until(pilot, lambda: pane.outcome is not None and not pane.busy and app.session is not None, timeout=240)
            shown = text(app, "#identify-result")
            assert "identified" in shown and "valve_null_bias" in shown and "bias_v = 0.12" in shown, shown
            assert (tmp_path / "id" / "model.json").exists() and (tmp_path / "id" / "report.md").exists()
            assert len(opened) == 2 and app.session is opened[1] and opened[1].loop is not None, "connected again"
            with Store(tmp_path / "store") as st:
                t = st.get(pane.outcome.test_id)
                assert t["kind"] == "identify" and t["status"] == "finished"
    asyncio.run(go())
