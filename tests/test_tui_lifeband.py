"""The console's life band (Results tab, key b): a stored test's life predicted from a specimen set and
updated from the test's own first points, computed off the UI thread; bad input is a message."""
import asyncio
from pathlib import Path

import pytest
from test_tui import text, until
from textual.widgets import DataTable, Input

from htm.tui.app import HtmApp
from htm.tui.results import VIRKLER, ResultsPane

ROOT = Path(__file__).resolve().parents[1]
LONG = 120.0  # s: a Monte Carlo campaign runs before the band shows


@pytest.fixture()
def virkler_test(store, tmp_path):
    """A simulated Virkler M(T) test in the store, its law inside the set's scatter."""
    from htm.cli import main as htm_main

    spec = tmp_path / "virkler_run.toml"
    spec.write_text((ROOT / "examples" / "virkler_mt.toml").read_text()
                    .replace("c = 1.0e-30", "c = 1.585e-29").replace("m = 3.0\n", "m = 3.08\n"))
    assert htm_main(["run", str(spec), "--out", str(tmp_path / "run"), "--quiet", "--no-recording",
                     "--store", str(store)]) == 0
    return store


def open_results(app, pilot):
    async def go():
        await pilot.press("f5")
        await pilot.pause()
        assert app.query_one("#results-table", DataTable).row_count == 1
        await pilot.press("down", "up")
        await until(pilot, lambda: app.query_one(ResultsPane).selected is not None, timeout=LONG)
    return go()


def test_life_band_of_a_stored_test_narrows_with_its_early_points(virkler_test):
    assert VIRKLER.exists()

    async def go():
        app = HtmApp(session_factory=lambda: None, store=virkler_test)
        async with app.run_test(size=(160, 50)) as pilot:
            await open_results(app, pilot)
            pane = app.query_one(ResultsPane)
            pane.life_band_samples = 40
            assert app.query_one("#lb-data", Input).value == ""  # blank: the repo's Virkler set
            app.query_one("#lb-upto", Input).value = "80000"
            await pilot.click("#lifeband")
            await pilot.pause()
            assert "running 40 simulated tests" in text(app, "#lifeband-result")
            await until(pilot, lambda: pane.life_band is not None or "[red]" in text(app, "#lifeband-result"), timeout=LONG)
            shown = text(app, "#lifeband-result")
            res = pane.life_band
            assert res is not None, shown
            lo, med, hi = res["band"]
            u = res["update"]
            assert len(res["life"]) == 40 and res["joint"].n_specimens == 40 and res["data"] == str(VIRKLER)
            assert not res["warnings"]  # the test's own spec: nothing to warn of
            assert lo < med < hi and u["p5"] <= u["median"] <= u["p95"]
            assert u["p95"] - u["p5"] < hi - lo  # the test's own points narrow the band
            assert res["early"].cycles[-1] <= 80_000 and u["points"] >= 2
            # what the pane shows is that band, before and after, and the test's cycles so far
            assert f"median {med:,.0f} cycles, 5–95 % {lo:,.0f} .. {hi:,.0f}" in shown
            assert f"median {u['median']:,.0f} cycles, 5–95 % {u['p5']:,.0f} .. {u['p95']:,.0f}" in shown
            assert f"test so far    {res['test']['cycles']:,} cycles" in shown and "(finished)" in shown
            # the test ran to af: its life sits near the updated median, closer than the prior one
            life = res["test"]["cycles"]
            assert abs(u["median"] - life) < abs(med - life)
    asyncio.run(go())


def test_the_virkler_set_ships_inside_the_package_unchanged():
    """A blank specimen-set field means the Virkler set in an installed htm too: it is package
    data (maturin puts every file under python/htm into the wheel), a copy of data/'s."""
    import htm

    assert VIRKLER.is_relative_to(Path(htm.__file__).parent), VIRKLER
    assert VIRKLER.read_bytes() == (ROOT / "data" / "virkler_2024t3" / VIRKLER.name).read_bytes()
    assert "GPL" in (VIRKLER.parent / "README.md").read_text(), "its source and licence go with it"


def test_a_spec_of_another_specimen_is_refused_and_a_band_stays_with_its_test(virkler_test, tmp_path):
    """A C(T) test and the Virkler M(T) spec typed in: refused, naming both specimens. The message
    belongs to that test: selecting the other test clears the pane, coming back shows it again."""
    from htm.cli import main as htm_main

    assert htm_main(["run", str(ROOT / "examples" / "ct_constant_force.toml"), "--out", str(tmp_path / "ct"), "--quiet",
                     "--no-recording", "--store", str(virkler_test)]) == 0

    async def go():
        app = HtmApp(session_factory=lambda: None, store=virkler_test)
        async with app.run_test(size=(160, 50)) as pilot:
            await pilot.press("f5")
            await pilot.pause()
            table = app.query_one("#results-table", DataTable)
            pane = app.query_one(ResultsPane)
            assert table.row_count == 2 and str(table.get_row_at(0)[1]) == "ct_constant_force"  # newest first
            await until(pilot, lambda: pane.selected == str(table.get_row_at(0)[0]))
            ct = pane.selected
            app.query_one("#lb-spec", Input).value = str(ROOT / "examples" / "virkler_mt.toml")
            await pilot.click("#lifeband")
            await until(pilot, lambda: "[red]" in text(app, "#lifeband-result"), timeout=LONG)
            said = text(app, "#lifeband-result")
            assert "does not match test" in said and "M(T) W 152.4 mm" in said and "C(T) W 50.8 mm" in said, said
            assert pane.life_band is None
            table.focus()
            await pilot.press("down")
            await until(pilot, lambda: pane.selected != ct)
            assert text(app, "#lifeband-result") == "", "no other test's band above this test"
            await pilot.press("up")
            await until(pilot, lambda: pane.selected == ct)
            assert text(app, "#lifeband-result") == said
    asyncio.run(go())


def test_life_band_bad_input_is_a_message(virkler_test, tmp_path):
    async def go():
        app = HtmApp(session_factory=lambda: None, store=virkler_test)
        async with app.run_test(size=(160, 50)) as pilot:
            await open_results(app, pilot)
            pane = app.query_one(ResultsPane)
            pane.life_band_samples = 8
            app.query_one("#lb-data", Input).value = str(tmp_path / "missing.csv")
            await pilot.click("#lifeband")
            await until(pilot, lambda: "[red]" in text(app, "#lifeband-result"), timeout=LONG)
            assert "missing.csv: no such file" in text(app, "#lifeband-result") and pane.life_band is None
            # too few early points: the table starts at cycle 1, one point
            app.query_one("#lb-data", Input).value = str(VIRKLER)
            app.query_one("#lb-upto", Input).value = "1"
            await pilot.click("#lifeband")
            await until(pilot, lambda: "needs at least 2" in text(app, "#lifeband-result")
                        or "updated" in text(app, "#lifeband-result"), timeout=LONG)
            assert "the update needs at least 2" in text(app, "#lifeband-result") and pane.life_band is None
            app.query_one("#lb-upto", Input).value = "soon"
            await pilot.click("#lifeband")
            await pilot.pause()
            assert "is not a number" in text(app, "#lifeband-result")
    asyncio.run(go())


def test_a_spec_of_the_same_specimen_with_another_crack_is_a_warning():
    from htm import spec as specmod
    from htm.tui.results import spec_mismatch

    spec = specmod.load(ROOT / "examples" / "ct_constant_force.toml", check=False)
    same = {"geometry": "ct", "width_m": spec.width_m, "thickness_m": spec.thickness_m, "a0_m": spec.a0_m}
    assert spec_mismatch(same, spec) == ([], [])
    refuse, warn = spec_mismatch({**same, "a0_m": 0.012}, spec)
    assert refuse == [] and warn == ["initial crack a0 15.20 mm in the spec, 12.00 mm in the test"]
    refuse, _ = spec_mismatch({**same, "width_m": 0.1016}, spec)
    assert refuse == ["the spec is for a C(T) W 50.8 mm specimen, the test ran a C(T) W 101.6 mm: enter this test's spec"]
