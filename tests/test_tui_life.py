"""The console's life tests (issue 33 item 6), by Textual's pilot: Setup switches to the life
modes (their fields shown, the crack test's hidden), edits the amplitude, the end criterion and
its fraction and the run-out, saves the spec and reads it back; Run starts a strain_life test on
the built-in virtual rig (which grips a round bar for it) and shows the live stress–strain loop
and the tensile peak's trend with the failure threshold."""
from __future__ import annotations

import asyncio

import pytest
from textual.widgets import Input, Select, Static
from tui_pilot import text, until

from htm.fatigue import lifetest
from htm.tui.app import HtmApp
from htm.tui.plot import LinePlot
from htm.tui.setup import SetupPane


def run(coro):
    return asyncio.run(coro)




def test_setup_edits_a_strain_life_test_saves_and_loads_it_back(tmp_path, store):
    async def go():
        app = HtmApp(session_factory=lambda: None)
        async with app.run_test(size=(150, 70)) as pilot:
            pane = app.query_one(SetupPane)
            assert not app.query_one("#row-loading-strain_amplitude").display
            app.query_one("#loading-mode", Select).value = "strain_life"
            await pilot.pause()
            # the life test's fields, its defaults filled in; the crack test's hidden
            for fid in ("loading-strain_amplitude", "specimen-diameter_m", "specimen-gauge_length_m", "end-drop",
                        "end-modulus_ratio_drop", "end-runout_cycles", "material-cyclic_k_prime_pa"):
                assert app.query_one(f"#row-{fid}").display, fid
            for fid in ("specimen-width_m", "loading-delta_f_n", "loading-force_amplitude_n", "end-a_over_w", "measurement-crack",
                        "controller-type", "loading-waveform"):
                assert not app.query_one(f"#row-{fid}").display, fid
            assert isinstance(pane.spec, lifetest.LifeSpec), text(app, "#setup-status")
            app.query_one("#loading-strain_amplitude", Input).value = "0.8"  # %
            app.query_one("#end-drop", Input).value = "0.1"
            app.query_one("#end-runout_cycles", Input).value = "200000"
            app.query_one("#loading-frequency_hz", Input).value = "2"
            await pilot.pause()
            c = pane.spec.config
            assert (pane.spec.mode, c["amplitude"], c["drop"], c["runout_cycles"], c["frequency_hz"]) == \
                ("strain_life", pytest.approx(0.008), 0.1, 200000, 2.0)
            assert "strain_life" in text(app, "#setup-status") and "10 % drop" in text(app, "#setup-status")
            # a bad fraction is refused on its field
            app.query_one("#end-drop", Input).value = "1.5"
            await pilot.pause()
            assert pane.spec is None and "end.drop" in str(app.query_one("#err-end-drop", Static).content)
            app.query_one("#end-drop", Input).value = "0.1"
            # saved, changed, loaded back
            path = tmp_path / "en.toml"
            app.query_one("#spec-path", Input).value = str(path)
            await pilot.pause()
            await pilot.click("#save")
            await pilot.pause()
            saved = lifetest.load(path)
            assert saved.mode == "strain_life" and saved.config["amplitude"] == pytest.approx(0.008) and saved.config["drop"] == 0.1
            assert "[controller]" not in path.read_text() and "a_over_w" not in path.read_text()
            app.query_one("#loading-strain_amplitude", Input).value = "0.5"
            await pilot.click("#load")
            await pilot.pause()
            assert app.query_one("#loading-strain_amplitude", Input).value == "0.8"
            assert pane.spec.config["amplitude"] == pytest.approx(0.008)
            # force_life: its force amplitude instead, the strain amplitude hidden
            app.query_one("#loading-mode", Select).value = "force_life"
            await pilot.pause()
            assert app.query_one("#row-loading-force_amplitude_n").display
            assert not app.query_one("#row-loading-strain_amplitude").display
            app.query_one("#loading-force_amplitude_n", Input).value = "12"
            await pilot.pause()
            assert pane.spec.mode == "force_life" and pane.spec.config["amplitude"] == pytest.approx(12e3)
            # and back to a crack-growth test: the C(T) form as it was
            app.query_one("#loading-mode", Select).value = "constant_force"
            await pilot.pause()
            assert app.query_one("#row-loading-delta_f_n").display and not app.query_one("#row-end-drop").display
            assert pane.spec is not None and pane.spec.phases[-1].mode == "constant_force", text(app, "#setup-status")
    run(go())


SHORT_LIFE = {  # the short-life bar of tests/test_life_rig.py: a few hundred cycles
    "specimen": {"geometry": "round_bar", "diameter_m": 6.35e-3, "gauge_length_m": 0.025, "a_init_m": 0.3e-3, "load_train_n_m": 5e8},
    "material": {"youngs_modulus_pa": 200e9, "cyclic_k_prime_pa": 1200e6, "cyclic_n_prime": 0.14,
                 "fatigue_strength_coefficient_pa": 1000e6, "fatigue_strength_exponent": -0.09,
                 "fatigue_ductility_coefficient": 0.1, "fatigue_ductility_exponent": -0.6, "cyclic_transient": 0.0,
                 "fracture_toughness_pa_sqrt_m": 150e6},
    "law": {"law": "paris", "c": 1e-20, "m": 2.0},
    "loading": {"mode": "strain_life", "strain_amplitude": 0.006, "r_ratio": -1.0, "frequency_hz": 5.0, "control_rate_hz": 500.0},
    "end": {"drop": 0.5, "separation": 0.1, "runout_cycles": 100_000},
}


def test_run_shows_the_live_loop_and_the_peak_trend_with_its_threshold(store):
    async def go():
        app = HtmApp()
        async with app.run_test(size=(160, 60)) as pilot:
            await until(pilot, lambda: app.session is not None)
            app.query_one(SetupPane).load_doc(SHORT_LIFE, "en_short")
            await pilot.pause()
            assert isinstance(app.current_spec(), lifetest.LifeSpec)
            await pilot.press("f4")
            await pilot.press("s")
            # the virtual rig grips a round bar (the session is opened again with it), the test runs
            await until(pilot, lambda: app.session is not None and app.session.rig.bar is not None, timeout=20)
            await until(pilot, lambda: app.session.snapshot()["cycles"] >= 14, timeout=60)
            await pilot.pause(0.3)
            shown = text(app, "#run-numbers")
            assert "mode[/] strain_life" in shown and "tensile peak" in shown and "failure at" in shown and "(50 % drop)" in shown, shown
            loop = app.query_one("#plot-a", LinePlot)
            assert loop.path and "stress–strain loop" in loop.title
            (x, y, _), = loop.series
            assert 0.55 < x.max() < 0.65 and -0.65 < x.min() < -0.55, (x.min(), x.max())  # ε [%] at ε_a = 0.6 %
            assert 450 < y.max() < 700 and -700 < y.min() < -450, (y.min(), y.max())  # σ [MPa] of the yielding bar
            trend = app.query_one("#plot-dk", LinePlot)
            assert "failure threshold" in trend.title
            series = {label: (xs, ys) for xs, ys, label in trend.series}
            assert set(series) == {"measured", "trend", "failure"}
            peak = series["measured"][1][-1]
            assert 15 < peak < 22, peak  # kN: the tensile peak at σ_a ≈ 590 MPa on 31.7 mm²
            assert series["failure"][1][-1] == pytest.approx(0.5 * series["trend"][1][-1])
            await pilot.press("x")
            await until(pilot, lambda: app.session.snapshot()["state"] in ("stopped", "idle"), timeout=20)
    run(go())
