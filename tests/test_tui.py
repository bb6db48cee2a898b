"""The operator console driven by Textual's pilot, one test per workflow, on the virtual rig."""
import asyncio
import re
from pathlib import Path

import numpy as np
import pytest
from textual.widgets import DataTable, Input, Static
from tui_pilot import text, until

from htm.record import Store
from htm.tui.app import HtmApp
from htm.tui.setup import SetupPane

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def run(coro):
    return asyncio.run(coro)




def cells(table: DataTable, row_key: str) -> dict[str, str]:
    """A table row as {column key: the text shown}."""
    return {str(k.value): str(v) for k, v in zip(table.columns, table.get_row(row_key))}


def test_setup_rejects_a_bad_field_and_simulates_a_valid_test(store):
    async def go():
        app = HtmApp(session_factory=lambda: None)
        async with app.run_test(size=(140, 50)) as pilot:
            pane = app.query_one(SetupPane)
            assert pane.spec is not None, text(app, "#setup-status")
            r = app.query_one("#loading-r_ratio", Input)
            r.value = "1.5"
            await pilot.pause()
            assert pane.spec is None
            assert "loading.r_ratio = 1.5 is out of range" in text(app, "#err-loading-r_ratio")
            r.value = "abc"
            await pilot.pause()
            assert "not a number" in text(app, "#err-loading-r_ratio")
            r.value = "0.1"
            await pilot.pause()
            assert pane.spec is not None and text(app, "#err-loading-r_ratio") == ""
            # a/W limit and hidden fields: switching mode hides ΔF and asks for ΔK
            app.query_one("#end-a_over_w", Input).value = "0.99"
            await pilot.pause()
            assert pane.spec is None and "end.a_over_w" in text(app, "#setup-status")
            app.query_one("#end-a_over_w", Input).value = "0.6"
            await pilot.press("ctrl+s")
            await app.workers.wait_for_complete()
            await pilot.pause()
            assert "predicted life" in text(app, "#sim-result") and "cycles" in text(app, "#sim-result")
            assert "inside the band ±2 %" in text(app, "#sim-result")
    run(go())


def test_spec_saves_and_loads_back(tmp_path, store):
    async def go():
        app = HtmApp(session_factory=lambda: None)
        async with app.run_test(size=(140, 50)) as pilot:
            app.query_one("#loading-delta_f_n", Input).value = "5"
            app.query_one("#spec-path", Input).value = str(tmp_path / "mine.toml")
            await pilot.pause()
            await pilot.click("#save")
            await pilot.pause()
            assert (tmp_path / "mine.toml").exists()
            app.query_one("#loading-delta_f_n", Input).value = "4"
            await pilot.click("#load")
            await pilot.pause()
            assert app.query_one("#loading-delta_f_n", Input).value == "5"
            assert app.query_one(SetupPane).spec.phases[-1].delta_f_n == pytest.approx(5000.0)
    run(go())


def test_setup_edits_the_crack_measurement_and_saves_it(tmp_path, store):
    """[measurement] from the Setup tab: the crack source chosen, its reading interval shown only
    for a measured crack, the spec built with it, saved and loaded back."""
    from textual.widgets import Select

    async def go():
        app = HtmApp(session_factory=lambda: None)
        async with app.run_test(size=(140, 60)) as pilot:
            pane = app.query_one(SetupPane)
            assert pane.spec.measurement["crack"] == "model"
            assert not app.query_one("#row-measurement-cycles_per_reading").display
            app.query_one("#measurement-crack", Select).value = "compliance"
            await pilot.pause()
            assert app.query_one("#row-measurement-cycles_per_reading").display
            app.query_one("#measurement-cycles_per_reading", Input).value = "20"
            await pilot.pause()
            assert pane.spec is not None, text(app, "#setup-status")
            assert pane.spec.measurement["crack"] == "compliance" and pane.spec.measurement["cycles_per_reading"] == 20
            app.query_one("#spec-path", Input).value = str(tmp_path / "measured.toml")
            await pilot.pause()
            await pilot.click("#save")
            await pilot.pause()
            assert 'crack = "compliance"' in (tmp_path / "measured.toml").read_text()
    run(go())


def test_install_jog_is_force_limited_by_specimen_protect(store):
    async def go():
        app = HtmApp()
        async with app.run_test(size=(140, 50)) as pilot:
            await until(pilot, lambda: app.session is not None)
            await pilot.press("f3")
            await pilot.press("o")
            await pilot.press("plus", "plus", "plus")  # 10 mm/s: into the specimen
            await pilot.press("up")
            await until(pilot, lambda: app.session.snapshot()["protecting"], timeout=30)
            await pilot.pause(1.0)
            snap = app.session.snapshot()
            assert abs(snap["f"]) < 1.15 * 2000.0, snap["f"]   # protect at 2 kN holds the force
            assert snap["interlock"] is None
            assert "ON (limiting force)" in text(app, "#install-numbers")
            await pilot.press("space")
            await pilot.press("t")
            await until(pilot, lambda: abs(app.session.snapshot()["f"]) < 200.0)
            # after a test's stop the supply is unloaded: position control waits for it, and says so
            await pilot.press("f4", "s")
            await until(pilot, lambda: app.session.snapshot()["state"] == "running", timeout=30)
            await pilot.press("x")
            await until(pilot, lambda: not app.session.snapshot()["amplifier"] and app.session.snapshot()["p_s"] < 50e5, timeout=30)
            await pilot.press("f3", "o")
            await pilot.pause(0.15)  # a poll after the key
            while app.session.snapshot()["state"] != "position":  # while the supply comes up: said so, never a bare "idle"
                shown = text(app, "#install-numbers")
                assert "switching to position control: loading the supply" in shown or "state[/] position" in shown, shown
                await pilot.pause(0.05)
            await until(pilot, lambda: "→" not in text(app, "#install-numbers") and "state[/] position" in text(app, "#install-numbers"))
    run(go())


def test_a_tab_entered_shows_the_state_of_now(store):
    """With the poller off, only entering the tab can bring its numbers up to date: the Run tab
    seen idle, position control switched on in Install, then F4 shows position at once."""
    async def go():
        app = HtmApp(poll=False)
        async with app.run_test(size=(160, 50)) as pilot:
            await until(pilot, lambda: app.session is not None)
            await pilot.press("f4")
            assert "state[/] idle" in text(app, "#run-numbers") and "amplifier[/] off" in text(app, "#run-numbers")
            await pilot.press("f3", "o")
            await until(pilot, lambda: app.session.snapshot()["state"] == "position" and not app.pending)
            await pilot.press("f4")
            shown = text(app, "#run-numbers")
            assert "state[/] position" in shown and "amplifier[/] ON" in shown, shown
    run(go())


def test_run_start_cycles_advance_trip_latches_reset_and_stop(store):
    async def go():
        app = HtmApp()
        async with app.run_test(size=(160, 60)) as pilot:
            await until(pilot, lambda: app.session is not None)
            await pilot.press("f4")
            await pilot.press("s")
            await until(pilot, lambda: app.session.snapshot()["cycles"] >= 30, timeout=60)
            assert "running" in text(app, "#run-numbers") or "starting" in text(app, "#run-numbers")
            # a fault: the supply pressure goes; its detector trips and latches power-off
            app.session.rig.inject("supply_loss")
            await until(pilot, lambda: app.session.snapshot()["interlock"] == "power_off", timeout=10)
            await pilot.pause(0.3)
            table = app.query_one("#detectors", DataTable)
            row = cells(table, "supply_pressure")
            assert row["state"] == "tripped" and row["latched"] == "LATCHED"
            # engineering units, each limit in its own aligned column, the unit beside
            assert (row["watches"], row["lo"], row["hi"], row["unit"]) == ("supply pressure", "120.0", "250.0", "bar"), row
            band = cells(table, "force_band")
            assert (band["lo"], band["hi"], band["unit"]) == ("none", "25.0", "% of ΔF"), band
            assert cells(table, "heartbeat")["hi"] == "150" and cells(table, "heartbeat")["unit"] == "ms"
            await pilot.press("s")  # refused while latched, in the console's words: its key, not an API call
            await until(pilot, lambda: any("start refused" in str(n.message) for n in app._notifications))
            said = [str(n.message) for n in app._notifications if "start refused" in str(n.message)][-1]
            assert "supply_pressure" in said and "ctrl+r" in said and "reset()" not in said, said
            assert app.session.snapshot()["state"] != "running"
            app.session.rig.clear_faults()
            await pilot.pause(0.5)
            await pilot.press("ctrl+r")
            await until(pilot, lambda: app.session.snapshot()["interlock"] is None, timeout=10)
            await pilot.pause(0.3)
            assert cells(table, "supply_pressure")["latched"] == ""
            await pilot.press("s")
            await until(pilot, lambda: app.session.snapshot()["state"] in ("starting", "running"), timeout=10)
            await pilot.press("x")
            await until(pilot, lambda: app.session.snapshot()["state"] in ("stopping", "stopped", "idle"), timeout=10)
            await pilot.press("f12")
            await until(pilot, lambda: app.session.snapshot()["estop"], timeout=5)
            assert not app.session.snapshot()["amplifier"]
    run(go())


def test_the_rerun_viewer_is_found_beside_python_off_path(monkeypatch):
    import sys

    from htm.tui.results import rerun_viewer

    monkeypatch.setenv("PATH", "/nonexistent")
    exe = rerun_viewer()
    assert exe == str(Path(sys.executable).with_name("rerun")) and Path(exe).is_file(), exe


def test_plot_axis_labels_differ_on_a_narrow_range():
    from htm.tui.plot import axis_labels

    assert axis_labels(15.2001, 15.2049) == ["15.2001", "15.2049"]  # was "15.2" twice
    assert axis_labels(15.2001, 15.2049, 3) == ["15.2001", "15.2025", "15.2049"]
    assert axis_labels(1, 95_399) == ["1", "95,399"]
    assert axis_labels(-4.45, 4.45, 3) == ["−4.5", "0.0", "4.5"]


def test_help_screen_lists_the_handset_keys(store):
    async def go():
        app = HtmApp(session_factory=lambda: None)
        async with app.run_test(size=(140, 50)) as pilot:
            await pilot.press("f1")
            await pilot.pause()
            from htm.tui.app import HelpScreen

            assert isinstance(app.screen, HelpScreen)
            await pilot.press("escape")
            await pilot.pause()
            assert not isinstance(app.screen, HelpScreen)
    run(go())


def test_results_lists_tests_opens_the_report_and_exports(store, tmp_path):
    """↑/↓ move in the list as soon as the tab is entered; the selection survives leaving and
    coming back; the summary is in engineering units."""
    from htm.cli import main as htm_main
    from htm.tui.results import ResultsPane

    for i in (1, 2):
        assert htm_main(["run", "examples/ct_constant_force.toml", "--out", str(tmp_path / f"run{i}"), "--quiet", "--no-recording"]) == 0

    async def go():
        app = HtmApp(session_factory=lambda: None, store=store)
        async with app.run_test(size=(140, 50)) as pilot:
            await pilot.press("f5")
            await pilot.pause()
            table = app.query_one("#results-table", DataTable)
            pane = app.query_one(ResultsPane)
            assert table.row_count == 2 and app.focused is table
            assert [str(c.label) for c in table.columns.values()][5] == "a end [mm]"
            older = str(table.get_row_at(1)[0])
            await pilot.press("down")  # no Tab first
            await until(pilot, lambda: pane.selected == older)
            await pilot.press("f2", "f5")
            await pilot.pause(0.3)
            assert table.cursor_row == 1 and pane.selected == older, "the selection stays where it was"
            await pilot.press("up", "down")
            await until(pilot, lambda: "target_crack_length" in text(app, "#results-summary"))
            summary = text(app, "#results-summary")
            assert re.search(r"final a +30\.\d{4} mm", summary) and "final_a_m" not in summary, summary
            assert re.search(r"velocity gain +-?\d+\.\d{4} mm/s per V", summary) and re.search(r"final a/W +0\.6000\n", summary), summary
            report = app.query_one("#results-report")
            assert "Simulated test" in report.source
            app.query_one("#export-dir", Input).value = str(tmp_path / "export")
            await pilot.click("#export")
            await until(pilot, lambda: (tmp_path / "export" / "cycles.parquet").exists())
            # the visual crack fronts: the measured sizes corrected, E647 redone, both kept
            app.query_one("#a0-visual", Input).value = "15.0"
            app.query_one("#af-visual", Input).value = "31.0"
            await pilot.click("#correct-visual")
            await until(pilot, lambda: "a0_visual" in text(app, "#results-summary") or "a0 visual" in text(app, "#results-summary"))
            with Store(store) as st:
                t = st.get(older)
            assert t["results"]["a0_visual_m"] == pytest.approx(15.0e-3) and t["results"]["af_visual_m"] == pytest.approx(31.0e-3)
            assert {"e647_measured", "e647_corrected"} <= set(t["files"])
            app.query_one("#af-visual", Input).value = "10"  # below a0: refused, nothing changed
            await pilot.click("#correct-visual")
            await pilot.pause(0.3)
            with Store(store) as st:
                assert st.get(older)["results"]["af_visual_m"] == pytest.approx(31.0e-3)
    run(go())


def rrd_entities(path: Path) -> tuple[set[str], dict[str, dict[str, list]]]:
    """(every entity path, static ones included; entity -> {column: values} of the rows over time)."""
    from rerun.chunk import RrdReader
    from test_record import _rrd

    return {ch.entity_path for ch in RrdReader(path).stream()}, _rrd(path)


def test_a_test_run_on_the_rig_is_recorded_and_shows_in_results(store, tmp_path):
    """A test run from the console and the same spec run by `htm run` record one layout: the
    same entity paths, ΔK over cycles, force with its setpoint; the ramp-in kept out of the
    force-error series and marked in the event log."""
    async def go():
        app = HtmApp(store=store)
        async with app.run_test(size=(160, 60)) as pilot:
            await until(pilot, lambda: app.session is not None)
            await pilot.press("f4", "s")
            await until(pilot, lambda: app.session.snapshot()["cycles"] >= 40, timeout=60)  # past the ramp-in (25 cycles)
            await pilot.press("x")
            await until(pilot, lambda: app.session.recorder is not None and app.session.recorder.status is not None, timeout=30)
            test_id = app.session.recorder.test_id
            await pilot.press("f5", "ctrl+l")
            await pilot.pause()
            table = app.query_one("#results-table", DataTable)
            row = table.get_row(test_id)
            assert str(row[2]) == "device" and str(row[3]) in ("finished", "stopped")
            from htm.record import Store

            with Store(store) as st:
                cyc = st.cycles(test_id)["cycle"]
            assert len(cyc) >= 20 and list(cyc) == list(range(int(cyc[0]), int(cyc[0]) + len(cyc)))  # no gap, no duplicate
            return test_id
    test_id = run(go())
    from htm.cli import main as htm_main
    from htm.record import Store

    assert htm_main(["run", str(EXAMPLES / "ct_constant_force.toml"), "--out", str(tmp_path / "run"), "--quiet", "--store", str(store)]) == 0
    with Store(store) as st:
        live = st.get(test_id)
        (sim,) = [t for t in st.list_tests() if t["id"] != test_id]
        sim = st.get(sim["id"])
    (live_paths, live_e), (sim_paths, sim_e) = (rrd_entities(Path(t["files"]["recording"]["path"])) for t in (live, sim))
    assert live_paths == sim_paths, live_paths ^ sim_paths
    # the rig records two signals the simulator does not model; otherwise both fill the same entities
    assert set(sim_e) <= set(live_e) and set(live_e) - set(sim_e) <= {"/signals/velocity_m_s", "/signals/supply_pressure_pa"}, \
        set(live_e) ^ set(sim_e)
    for name, e in (("console", live_e), ("htm run", sim_e)):
        dk = np.array(e["/cycle/stress_intensity_pa_sqrt_m"]["Scalars:scalars"], dtype=float)
        # ΔK (measured: it ramps in with the force) and its target, every cycle
        measured = dk[np.isfinite(dk[:, 0]), 0]  # (a cycle-jump row of `htm run` has none)
        assert len(measured) >= 40 and np.all(measured[-10:] > 15e6) and np.all(dk[:, 1] > 15e6), (name, dk[:3])
        force = np.array(e["/signals/force_n"]["Scalars:scalars"], dtype=float)
        assert force.shape[1] == 2 and len(force) >= 20, name  # force and setpoint, one entity
        moving = np.isfinite(force[:, 1])
        assert moving.sum() >= 20 and np.ptp(force[moving, 1]) > 3e3, (name, "the setpoint follows the cycles")
        # the force follows its setpoint (within the loop's lag of a few periods: ≈ 5 % of the range on the rig)
        assert np.median(np.abs(force[moving, 0] - force[moving, 1])) < 0.1 * np.ptp(force[moving, 1]), name
        err = e["/cycle/force_error_pct"]
        ramp = e["/cycle/ramp_force_error_pct"]
        ramp_in = [c for c in ramp["cycle"] if c < min(err["cycle"])]
        assert ramp_in == list(range(1, 26)) and 1 not in err["cycle"], (name, ramp["cycle"][:30])
        assert np.nanmin(np.array(err["Scalars:scalars"], dtype=float)) > -10.0, (name, "no ramp-in in the error plot")
        texts = [" ".join(x) if isinstance(x, list) else str(x) for x in e["/events"]["TextLog:text"]]
        marks = [x for x in texts if x.startswith("ramp-in")]
        assert marks and "cycles 1–25:" in marks[0], (name, marks)


def test_diagnose_runs_on_a_record_and_shows_findings(store, tmp_path):
    from htm.ident.proving import make_record
    from htm.ident.records import write_record

    rec, truth = make_record({"sensor_offset": {"channel": "p_a", "offset_pa": 4e5}}, seed=3, duration_s=10.0)
    table, _ = write_record(rec, tmp_path / "rec")

    async def go():
        app = HtmApp(session_factory=lambda: None, store=store)
        async with app.run_test(size=(160, 50)) as pilot:
            await pilot.press("f6")
            app.query_one("#diag-record", Input).value = str(table)
            app.query_one("#diag-out", Input).value = str(tmp_path / "diag")
            await pilot.click("#diag-run")
            await until(pilot, lambda: "report:" in text(app, "#diag-status") or "[red]" in text(app, "#diag-status"), timeout=300)
            status = text(app, "#diag-status")
            assert "finding" in status and "report:" in status, status
            rows = app.query_one("#findings", DataTable)
            assert rows.row_count >= 1
            first = rows.get_row_at(0)
            assert str(first[1]) == "sensor_offset" and str(first[2]) == "p_a"
            assert "bar" in str(first[3]), "the offset in bar, as the console shows pressures"
            assert (tmp_path / "diag" / "report.json").exists()
    run(go())


def test_results_refresh_on_entering_and_function_keys_leave_a_focused_button(store, tmp_path):
    from htm.cli import main as htm_main
    from htm.tui.results import ResultsPane

    async def go():
        app = HtmApp(session_factory=lambda: None, store=store)
        async with app.run_test(size=(140, 50)) as pilot:
            await pilot.press("f5")
            await pilot.pause()
            table = app.query_one("#results-table", DataTable)
            assert table.row_count == 0
            app.query_one("#refresh").focus()
            await pilot.press("f2")
            await pilot.pause()
            assert app.query_one("#tabs").active == "setup", "F2 from a Results button"
            assert htm_main(["run", "examples/ct_constant_force.toml", "--out", str(tmp_path / "run"), "--quiet",
                             "--no-recording", "--store", str(store)]) == 0
            await pilot.click("#tabs-tab-results" if app.query("#tabs-tab-results") else "Tab#--content-tab-results")
            await pilot.pause()
            assert app.query_one("#tabs").active == "results" and table.row_count == 1, "refreshed on entering"
            app.query_one(ResultsPane).query_one("#view").focus()
            await pilot.press("f6")
            await pilot.pause()
            assert app.query_one("#tabs").active == "diagnose"
    run(go())


def test_run_numbers_before_a_test_and_a_trip_shown_whole_and_once(store):
    async def go():
        app = HtmApp(store=store)
        async with app.run_test(size=(160, 60)) as pilot:
            await until(pilot, lambda: app.session is not None)
            await pilot.press("f4")
            await pilot.pause(0.5)
            assert "nan" not in text(app, "#run-numbers") and "state[/] idle" in text(app, "#run-numbers")
            await pilot.press("s")
            await until(pilot, lambda: app.session.snapshot()["cycles"] >= 12, timeout=60)
            app.session.rig.inject("transducer_silent")
            await until(pilot, lambda: app.session.snapshot()["interlock"] == "power_off", timeout=10)
            app.session.rig.clear_faults()
            await pilot.pause(1.0)
            await pilot.press("f12")
            await until(pilot, lambda: app.session.snapshot()["estop"], timeout=5)
            await pilot.pause(0.5)
            table = app.query_one("#detectors", DataTable)
            state = table.columns["state"]
            assert cells(table, "transducer_silent")["state"] == "tripped" and state.content_width >= len("tripped")
            lines = [ln.text for ln in app.query_one("#events").lines]
            assert sum(ln.split()[1:2] == ["trip"] for ln in lines) == 1, lines
            assert sum("E-STOP" in ln for ln in lines) == 1, lines
            # the log's columns are labelled, its times in seconds, the test by its name
            assert text(app, "#events-heading").split() == ["time", "[s]", "event", "detail"]
            assert any(ln.split()[1:] == ["command", "start", "test", "ct_constant_force"] for ln in lines), lines
    run(go())


def test_diagnose_evidence_fits_the_table_and_shows_whole_below(store):
    from htm.tui.diagnose_pane import EVIDENCE_CELL, DiagnosePane

    long = "the free run drifts by 4 bar on p_a while the other channels stay within their noise; " * 3
    finding = {"effect": "sensor_offset", "channel": "p_a", "params": {"offset_pa": 4e5}, "rmse_before": {"p_a": 4e5},
               "rmse_after": {"p_a": 1e4}, "evidence": long}
    report = {"record": "r", "findings": [finding], "unexplained": False, "baseline": {"rmse": {"p_a": 4e5}},
              "final": {"rmse": {"p_a": 1e4}}}

    async def go():
        app = HtmApp(session_factory=lambda: None, store=store)
        async with app.run_test(size=(140, 50)) as pilot:
            await pilot.press("f6")
            app.query_one(DiagnosePane).show(report, store)
            await pilot.pause()
            cell = str(app.query_one("#findings", DataTable).get_row_at(0)[6])
            assert len(cell) <= EVIDENCE_CELL and cell.endswith("…")
            assert long.strip() in str(app.query_one("#finding-detail", Static).content)
    run(go())


def test_setup_shows_what_the_rig_can_do_and_refuses_a_force_beyond_it(store):
    """The Setup tab runs the feasibility check of `htm run --check` as you type: the example
    asking 88.9 kN peak (ΔF 80 kN at R = 0.1) of the thesis rig's ~48 kN is refused, with the
    capacity and the largest feasible ΔF at the ΔF field, and cannot be simulated until ΔF is
    feasible."""
    async def go():
        app = HtmApp(session_factory=lambda: None)
        async with app.run_test(size=(140, 50)) as pilot:
            pane = app.query_one(SetupPane)
            assert pane.spec is not None and "force capacity (tension)" in text(app, "#setup-check")
            app.query_one("#spec-path", Input).value = str(EXAMPLES / "mt_beyond_capacity.toml")
            await pilot.click("#load")
            await pilot.pause()
            assert pane.spec is None
            check = text(app, "#setup-check")
            assert "REFUSED" in check and "48.2 kN" in check and "refused: force capacity (tension)" in check, check
            assert "cannot run this test" in text(app, "#setup-status")
            assert "largest feasible ΔF 43.4 kN" in text(app, "#err-loading-delta_f_n")
            await pilot.press("ctrl+s")
            await pilot.pause()
            assert "predicted life" not in text(app, "#sim-result")
            app.query_one("#loading-delta_f_n", Input).value = "40"
            await pilot.pause()
            assert pane.spec is not None and "REFUSED" not in text(app, "#setup-check")
            assert text(app, "#err-loading-delta_f_n") == ""
    run(go())
