"""Results: browse the test store, read a test's report and events, open its rerun recording,
export its tables, and predict a test's life as a band from a specimen set, updated from its own
first a–N points (`htm.campaign.lifeband`, as `htm life-band`)."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tomllib
from importlib.resources import files
from pathlib import Path
from typing import Any

from rich.markup import escape
from textual import on, work
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical, VerticalScroll
from textual.widgets import Button, DataTable, Input, Markdown, Static

from htm.errors import HtmError, SpecError
from htm.tui.units import plain, result_lines, right

# the specimen set shipped inside the package (40 Virkler 2024-T3 M(T) panels; a copy of the
# repository's data/virkler_2024t3, its source and licence in the README beside it)
VIRKLER = Path(str(files("htm").joinpath("data", "virkler_2024t3", "virkler_a_vs_n_specimens_1_40.csv")))
A_MM_COLUMN = "a_half_crack_mm"  # Virkler's a in mm; files with a_m or a_mm columns are read as usual
RESULTS_COLUMNS = (("id", "id"), ("name", "name"), ("kind", "kind"), ("status", "status"), ("cycles", "cycles"),
                   ("a_end", "a end [mm]"), ("end_reason", "end reason"))


def rerun_viewer() -> str | None:
    """The rerun viewer: the one installed beside this Python (the venv htm runs in, whether or
    not it is on PATH), else the one on PATH."""
    here = Path(sys.executable).with_name("rerun")
    if here.is_file():
        return str(here)
    return shutil.which("rerun")


def stored_specimen(t: dict[str, Any]) -> dict[str, Any] | None:
    """The specimen (geometry, W, B, a0 [m]) of a stored test, from the spec it keeps; None when
    the spec cannot be read."""
    try:
        if t["spec_format"] == "toml":
            d = tomllib.loads(t["spec"]).get("specimen", {})
        else:  # a live test keeps its engine config as JSON (htm.control.recorder)
            d = json.loads(t["spec"])
        return {k: d[k] for k in ("geometry", "width_m", "thickness_m", "a0_m")}
    except (KeyError, TypeError, ValueError, tomllib.TOMLDecodeError):
        return None


def spec_mismatch(test: dict[str, Any], spec: Any) -> tuple[list[str], list[str]]:
    """(refusals, warnings) of a spec typed in for a stored test's life band: another specimen
    type or width is another test (refused); another thickness or initial crack a warning."""
    def name(g: str, w: float) -> str:
        return f"{'C(T)' if g == 'ct' else 'M(T)' if g == 'mt' else g} W {w * 1e3:.1f} mm"

    ours = name(spec.geometry, spec.width_m)
    theirs = name(test["geometry"], test["width_m"])
    refuse, warn = [], []
    if spec.geometry != test["geometry"] or abs(spec.width_m - test["width_m"]) > 1e-3 * test["width_m"]:
        refuse.append(f"the spec is for a {ours} specimen, the test ran a {theirs}: enter this test's spec")
    for key, what in (("thickness_m", "thickness B"), ("a0_m", "initial crack a0")):
        if abs(getattr(spec, key) - test[key]) > 1e-3 * test[key]:
            warn.append(f"{what} {getattr(spec, key) * 1e3:.2f} mm in the spec, {test[key] * 1e3:.2f} mm in the test")
    return refuse, warn


class ResultsPane(Vertical):
    BINDINGS = [Binding("ctrl+l", "refresh", "refresh list"), Binding("v", "view", "open recording"),
                Binding("b", "life_band", "life band")]
    DEFAULT_CSS = """
    ResultsPane #results-table { height: 12; }
    ResultsPane #results-bar { height: 3; }
    ResultsPane #results-bar Input { width: 40; }
    ResultsPane #lifeband-bar { height: 3; }
    ResultsPane #lb-data { width: 1fr; }
    ResultsPane #lb-upto { width: 26; }
    ResultsPane #lb-spec { width: 30; }
    ResultsPane #visual-bar { height: 3; }
    ResultsPane #visual-bar Input { width: 24; }
    ResultsPane #results-detail { height: 1fr; border: round $accent; }
    """

    def __init__(self, store_root: Path | str | None = None, **kw: Any) -> None:
        super().__init__(**kw)
        self.store_root = store_root
        self.selected: str | None = None
        self.life_band_samples = 200  # Monte Carlo draws (simulated tests) of the band
        self.life_band: dict[str, Any] | None = None  # the band of the selected test, once computed
        self._bands: dict[str, tuple[dict[str, Any] | None, str]] = {}  # test id -> (band, text) shown with it
        self._lb_busy = False

    def compose(self) -> ComposeResult:
        yield DataTable(id="results-table", cursor_type="row", zebra_stripes=True)
        with Horizontal(id="results-bar"):
            yield Button("Refresh (ctrl+l)", id="refresh")
            yield Button("Open recording (v)", id="view")
            yield Input(placeholder="export folder", id="export-dir")
            yield Button("Export", id="export")
        with Horizontal(id="lifeband-bar"):
            yield Input(placeholder="specimen set a–N CSV" + (" (blank: Virkler 2024-T3 M(T))" if VIRKLER.exists() else ""),
                        id="lb-data")
            yield Input(placeholder="early: up to cycles", id="lb-upto")
            yield Input(placeholder="spec (blank: the test's)", id="lb-spec")
            yield Button("Life band (b)", id="lifeband")
        with Horizontal(id="visual-bar"):  # E647: the measured sizes corrected to the fracture surface's
            yield Input(placeholder="visual a0 [mm]", id="a0-visual")
            yield Input(placeholder="visual a_f [mm]", id="af-visual")
            yield Button("Correct to visual", id="correct-visual")
        with VerticalScroll(id="results-detail"):
            yield Static("", id="lifeband-result")
            yield Static("", id="results-summary")
            yield Markdown("", id="results-report")

    def on_mount(self) -> None:
        t = self.query_one("#results-table", DataTable)
        for key, label in RESULTS_COLUMNS:  # Text labels: "[mm]" as markup would vanish
            t.add_column(right(label) if key in ("cycles", "a_end") else plain(label), key=key)
        self.action_refresh()

    def _store(self):
        from htm.record.store import Store

        return Store(self.store_root)

    @on(Button.Pressed, "#refresh")
    def action_refresh(self) -> None:
        t = self.query_one("#results-table", DataTable)
        t.clear()
        try:
            with self._store() as st:
                rows = st.list_tests()
        except HtmError as e:
            self.query_one("#results-summary", Static).update(f"[red]{e}[/]")
            return
        for r in reversed(rows):  # newest first
            t.add_row(plain(r["id"]), plain(r["name"]), plain(r["kind"]), plain(r["status"]),
                      right(f"{r['cycles']:,}" if r["cycles"] is not None else ""),
                      right(f"{r['a_end_m'] * 1e3:.3f}" if r["a_end_m"] is not None else ""), plain(r["end_reason"] or ""), key=r["id"])
        if not rows:
            self.selected = None
            self.query_one("#results-summary", Static).update("the store holds no tests yet: run one (Run tab or `htm run`)")
            return
        ids = [r["id"] for r in reversed(rows)]
        if self.selected in ids:  # the selection stays where the operator left it
            t.move_cursor(row=ids.index(self.selected))

    @on(DataTable.RowHighlighted, "#results-table")
    def _row(self, ev: DataTable.RowHighlighted) -> None:
        if ev.row_key is not None and ev.row_key.value:
            self.show(str(ev.row_key.value))

    def show(self, test_id: str) -> None:
        """Show one test: summary, results, last events, its report when it has one, and its life
        band when one was computed (never another test's)."""
        self.selected = test_id
        self.life_band, band_text = self._bands.get(test_id, (None, ""))
        self.query_one("#lifeband-result", Static).update(band_text)
        try:
            with self._store() as st:
                t = st.get(test_id)
        except HtmError as e:
            self.query_one("#results-summary", Static).update(f"[red]{e}[/]")
            return
        lines = [f"[b]{escape(t['id'])}[/] {escape(t['name'])} ({t['kind']}, {t['mode'] or '-'}) — [b]{t['status']}[/]"
                 + (f", {escape(t['end_reason'])}" if t["end_reason"] else "")]
        if t["cycles"] is not None:
            lines.append(f"cycles {t['cycles']:,}" + (f", final a = {t['a_end_m'] * 1e3:.3f} mm" if t["a_end_m"] is not None else ""))
        lines += ["  " + escape(r) for r in result_lines(t["results"])]
        lines.append(f"events ({len(t['events'])}, the last 12):")
        lines.append(f"  {'cycle':>10}  {'event':<18} detail")
        lines += [f"  {'' if e['cycle'] is None else format(e['cycle'], ','):>10}  {escape(e['kind']):<18} {escape(e['detail'] or '')}"
                  for e in t["events"][-12:]]
        lines.append("files: " + ", ".join(f"{r} ({(f['bytes'] or 0) / 1e6:.2f} MB)" for r, f in sorted(t["files"].items())))
        self.query_one("#results-summary", Static).update("\n".join(lines))
        report = self._report(t)
        self.query_one("#results-report", Markdown).update(report.read_text() if report else "*no report for this test*")

    @staticmethod
    def _report(t: dict[str, Any]) -> Path | None:
        f = t["files"].get("report")
        if f and Path(f["path"]).exists():
            return Path(f["path"])
        for f in t["files"].values():  # the report sits beside the other outputs
            p = Path(f["path"]).with_name("report.md")
            if p.exists():
                return p
        return None

    def recording_path(self) -> Path | None:
        if self.selected is None:
            return None
        with self._store() as st:
            f = st.get(self.selected)["files"].get("recording")
        return Path(f["path"]) if f else None

    @on(Button.Pressed, "#view")
    def action_view(self) -> None:
        """Open the test's .rrd in the rerun viewer (a separate window/process)."""
        try:
            rrd = self.recording_path()
        except HtmError as e:
            self.notify(str(e), severity="error")
            return
        if rrd is None or not rrd.exists():
            self.notify("this test has no rerun recording", severity="warning")
            return
        exe = rerun_viewer()
        if exe is None:
            self.notify(f"no rerun viewer beside {sys.executable} nor on PATH (pip install rerun-sdk); "
                        f"the recording is {rrd}", severity="warning", timeout=10)
            return
        subprocess.Popen([exe, str(rrd)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        self.notify(f"opened {rrd.name} in the rerun viewer")

    @on(Button.Pressed, "#export")
    def _export(self) -> None:
        out = self.query_one("#export-dir", Input).value.strip()
        if self.selected is None or not out:
            self.notify("select a test and type an export folder", severity="warning")
            return
        try:
            with self._store() as st:
                st.export(self.selected, out)
        except (HtmError, OSError) as e:
            self.notify(f"export failed: {e}", severity="error")
            return
        self.notify(f"exported {self.selected} to {out}")

    # ---- the visual crack fronts -------------------------------------------------------------
    @on(Button.Pressed, "#correct-visual")
    def correct_visual(self) -> None:
        """Correct the selected test's measured crack sizes to the visually measured initial and
        final fronts (E647, `htm db correct`): the E647 reduction and report redone from the
        corrected sizes, both kept."""
        from htm.correct import correct_test

        if self.selected is None:
            self.notify("select a test first", severity="warning")
            return
        try:
            a0, af = (float(self.query_one(f"#{w}", Input).value.replace(",", ".")) for w in ("a0-visual", "af-visual"))
        except ValueError:
            self.notify("type the visual initial and final crack sizes in millimetres", severity="warning")
            return
        try:
            with self._store() as st:
                r = correct_test(st, self.selected, a0 * 1e-3, af * 1e-3)
        except (HtmError, OSError) as e:
            self.notify(f"correction refused: {e}", severity="error", timeout=10)
            return
        vc = r["visual_correction"]
        self.notify(f"{self.selected}: crack sizes corrected to the visual fronts (a0 {vc['offset_a0_m'] * 1e3:+.3f} mm, "
                    f"a_f {vc['offset_af_m'] * 1e3:+.3f} mm); E647 redone, measured and corrected both kept", timeout=10)
        self.show(self.selected)

    # ---- life band ---------------------------------------------------------------------------
    @on(Button.Pressed, "#lifeband")
    def action_life_band(self) -> None:
        """Predict the selected test's life from the specimen set, and update it from the test's points."""
        out = self.query_one("#lifeband-result", Static)
        if self._lb_busy:  # a thread cannot be cancelled: one band at a time
            self.notify("life band: still computing the last one", severity="warning")
            return
        if self.selected is None:
            out.update("[red]life band: select a test in the list first[/]")
            return
        data = self.query_one("#lb-data", Input).value.strip() or (str(VIRKLER) if VIRKLER.exists() else "")
        upto_text = self.query_one("#lb-upto", Input).value.strip().replace(",", "").replace("_", "")
        spec = self.query_one("#lb-spec", Input).value.strip() or None
        if not data:
            out.update("[red]life band: enter the specimen set's a–N CSV (cycles, a_m or a_mm, specimen)[/]")
            return
        try:
            upto = float(upto_text) if upto_text else None
        except ValueError:
            out.update(f"[red]life band: early points up to `{upto_text}` cycles is not a number[/]")
            return
        if upto is not None and upto <= 0:
            out.update("[red]life band: early points up to cycles must be > 0[/]")
            return
        self.life_band = None
        text = (f"[yellow]life band of {self.selected}: fitting the set's specimens and running "
                f"{self.life_band_samples} simulated tests…[/]")
        self._bands[self.selected] = (None, text)
        out.update(text)
        self._lb_busy = True
        self._life_band(self.selected, data, upto, spec, self.life_band_samples)

    @work(thread=True, exclusive=True, group="life-band")
    def _life_band(self, test_id: str, data: str, upto: float | None, spec: str | None, samples: int) -> None:
        try:
            res = self._compute_life_band(test_id, data, upto, spec, samples)
            text = self._life_band_text(res)
        except (HtmError, OSError, ValueError) as e:
            res, text = None, f"[red]life band: {escape(str(e))}[/]"
        except Exception as e:  # never a traceback in the console
            res, text = None, f"[red]life band failed: {type(e).__name__}: {escape(str(e))}[/]"
        self.app.call_from_thread(self._show_life_band, test_id, res, text)

    def _show_life_band(self, test_id: str, res: dict[str, Any] | None, text: str) -> None:
        self._lb_busy = False
        self._bands[test_id] = (res, text)
        if self.selected == test_id:  # another test selected meanwhile: shown when it is selected again
            self.life_band = res
            self.query_one("#lifeband-result", Static).update(text)

    def _compute_life_band(self, test_id: str, data: str, upto: float | None, spec: str | None,
                           samples: int) -> dict[str, Any]:
        from htm import spec as specmod
        from htm.campaign import engine, lifeband

        datas = lifeband.read_data(data, A_MM_COLUMN)
        warnings: list[str] = []
        with self._store() as st:
            t = st.get(test_id)
            out = st.root / "life-band" / test_id
            if spec is None:
                if t["spec_format"] != "toml":
                    raise SpecError(f"test {test_id} keeps its spec as the engine's {t['spec_format']} config, not a "
                                    "spec file: enter the test's spec (TOML) in the spec field")
                out.mkdir(parents=True, exist_ok=True)
                spec_path = out / "test_spec.toml"
                spec_path.write_text(t["spec"])
            else:
                spec_path = Path(spec)
                if not spec_path.is_file():
                    raise SpecError(f"{spec}: no such spec file")
                ours = stored_specimen(t)
                if ours is None:
                    warnings.append(f"test {test_id}'s specimen could not be read: the spec is not checked against it")
                else:
                    refuse, warn = spec_mismatch(ours, specmod.load(spec_path, check=False))
                    if refuse:
                        raise SpecError(f"{spec_path.name} does not match test {test_id}: " + "; ".join(refuse))
                    warnings += [f"{spec_path.name} differs from test {test_id}: {w}" for w in warn]
            table = st.cycles(test_id)
            if "a_m" not in table or len(table["a_m"]) == 0:
                raise SpecError(f"test {test_id} has no a–N points in the store yet")
            early = lifeband.early_from_table(test_id, table["cycle"], table["a_m"], upto)
            res = lifeband.build(spec_path, datas, set(), samples, 1, st, engine.local_runner(), out, progress=False)
        res["update"] = lifeband.update(res, early)
        res["early"] = early
        res["test"] = {"id": test_id, "status": t["status"], "cycles": int(table["cycle"][-1]),
                       "a_m": float(table["a_m"][-1])}
        res["spanning"] = sum(lifeband.life_between(d, res["a0_m"], res["af_m"]) is not None for d in datas)
        res["data"] = data
        res["warnings"] = warnings
        return res

    @staticmethod
    def _life_band_text(res: dict[str, Any]) -> str:
        lo, med, hi = res["band"]
        u, e, t = res["update"], res["early"], res["test"]
        lines = [f"[b]life band[/] of {t['id']}: a {res['a0_m'] * 1e3:.2f} → {res['af_m'] * 1e3:.2f} mm, "
                 f"{res['joint'].n_specimens} specimens of {Path(res['data']).name}, {len(res['life'])} simulated tests",
                 f"  before update  median {med:,.0f} cycles, 5–95 % {lo:,.0f} .. {hi:,.0f} (width {hi - lo:,.0f})",
                 f"  updated        median {u['median']:,.0f} cycles, 5–95 % {u['p5']:,.0f} .. {u['p95']:,.0f} "
                 f"(width {u['p95'] - u['p5']:,.0f}) from the test's {u['points']} points to a = {e.a_m[-1] * 1e3:.2f} mm "
                 f"at {e.cycles[-1]:,.0f} cycles ({u['effective_draws']:.0f} effective draws)",
                 f"  test so far    {t['cycles']:,} cycles, a = {t['a_m'] * 1e3:.2f} mm ({t['status']})"]
        if res["spanning"] == 0:
            lines.append("[yellow]  none of the set's specimens spans this test's a0 → af: is it the set of this test?[/]")
        lines += [f"[b yellow]  warning: {escape(w)}[/]" for w in res.get("warnings", [])]
        return "\n".join(lines)
