"""Diagnose: pick a measurement record, run `htm diagnose` on it (in a worker), and show the
findings with the error before and after each one."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from rich.markup import escape
from textual import on, work
from textual.app import ComposeResult
from textual.containers import Horizontal, Vertical
from textual.widgets import Button, DataTable, Input, Static

from htm.errors import HtmError
from htm.tui.units import eng, plain, right

TABLE_SUFFIXES = (".csv", ".csv.gz", ".parquet")
EVIDENCE_CELL = 48  # characters of evidence in the table; the whole text shows below it


def fmt_rmse(d: dict[str, float]) -> str:
    units = {"y": ("mm", 1e3), "v": ("mm/s", 1e3), "p_a": ("bar", 1e-5), "p_b": ("bar", 1e-5), "p_s": ("bar", 1e-5), "f": ("N", 1.0)}
    return ", ".join(f"{c} {v * units.get(c, ('', 1.0))[1]:.4g} {units.get(c, ('', 1.0))[0]}" for c, v in d.items())


class DiagnosePane(Vertical):
    DEFAULT_CSS = """
    DiagnosePane #diag-bar { height: 3; }
    DiagnosePane #diag-bar #diag-record { width: 2fr; }
    DiagnosePane #diag-bar #diag-out { width: 1fr; }
    DiagnosePane #diag-bar Button { width: auto; min-width: 16; }
    DiagnosePane #diag-status { height: auto; padding: 0 1; }
    DiagnosePane #findings { height: 1fr; }
    DiagnosePane #finding-detail { height: auto; max-height: 8; padding: 0 1; border-top: solid $accent; }
    """

    def __init__(self, **kw: Any) -> None:
        super().__init__(**kw)
        self.findings: list[dict[str, Any]] = []

    def compose(self) -> ComposeResult:
        with Horizontal(id="diag-bar"):
            yield Input(placeholder="record table (.csv, .csv.gz, .parquet) with its .json beside it", id="diag-record")
            yield Input(placeholder="output folder", id="diag-out")
            yield Button("Diagnose", id="diag-run", variant="primary")
        yield Static("", id="diag-status")
        yield DataTable(id="findings", zebra_stripes=True, cursor_type="row")
        yield Static("", id="finding-detail")

    def on_mount(self) -> None:
        self.query_one("#findings", DataTable).add_columns("#", "effect", "channel", "params", "RMSE before", "RMSE after", "evidence")

    @on(Button.Pressed, "#diag-run")
    def start(self) -> None:
        rec = self.query_one("#diag-record", Input).value.strip()
        out = self.query_one("#diag-out", Input).value.strip()
        if not rec:
            self.notify("type the path of a record", severity="warning")
            return
        out_dir = Path(out) if out else Path(rec).with_name(Path(rec).name.split(".")[0] + "-diagnosis")
        self.query_one("#diag-status", Static).update(f"diagnosing {escape(rec)} → {escape(str(out_dir))} …")
        self.query_one("#findings", DataTable).clear()
        self._run(rec, out_dir)

    @work(thread=True, exclusive=True, group="diagnose")
    def _run(self, path: str, out_dir: Path) -> None:
        from htm.ident.diagnose import diagnose
        from htm.ident.records import read_record

        try:
            if out_dir.exists() and any(out_dir.iterdir()):
                raise HtmError(f"{out_dir} is not empty; choose another output folder")
            report = diagnose(read_record(path), out_dir=out_dir)
        except (HtmError, OSError) as e:
            self.app.call_from_thread(self.query_one("#diag-status", Static).update, f"[red]{escape(str(e))}[/]")
            return
        except Exception as e:  # a record it cannot read: a message, never a traceback in the console
            self.app.call_from_thread(self.query_one("#diag-status", Static).update,
                                      f"[red]{escape(path)}: cannot diagnose: {type(e).__name__}: {escape(str(e))}[/]")
            return
        self.app.call_from_thread(self.show, report, out_dir)

    def show(self, report: dict[str, Any], out_dir: Path) -> None:
        t = self.query_one("#findings", DataTable)
        t.clear()
        self.findings = list(report["findings"])
        for i, f in enumerate(self.findings, 1):
            params = ", ".join(" ".join(eng(k, v, pressures_in_bar=True)).strip() for k, v in f["params"].items())
            ev = f["evidence"]  # long prose: cut in the table (it would run off the screen), whole below
            cell = ev if len(ev) <= EVIDENCE_CELL else ev[: EVIDENCE_CELL - 1] + "…"
            t.add_row(right(str(i)), plain(f["effect"]), plain(f["channel"] or ""), plain(params), plain(fmt_rmse(f["rmse_before"])),
                      plain(fmt_rmse(f["rmse_after"])), plain(cell))
        self._detail(0)
        n = len(report["findings"])
        verdict = ("[b yellow]unexplained structure remains[/]" if report["unexplained"]
                   else "[green]nothing systematic left unexplained[/]")
        self.query_one("#diag-status", Static).update(
            f"[b]{escape(str(report['record']))}[/]: {n} finding{'s' if n != 1 else ''}; {verdict}\n"
            f"baseline RMSE {fmt_rmse(report['baseline']['rmse'])}\nfinal RMSE    {fmt_rmse(report['final']['rmse'])}\n"
            f"report: {escape(str(out_dir / 'report.md'))}")

    @on(DataTable.RowHighlighted, "#findings")
    def _highlighted(self, ev: DataTable.RowHighlighted) -> None:
        self._detail(ev.cursor_row)

    def _detail(self, i: int) -> None:
        """The highlighted finding's whole evidence, wrapped to the screen."""
        f = self.findings[i] if 0 <= i < len(self.findings) else None
        self.query_one("#finding-detail", Static).update(
            "" if f is None else f"[b]{i + 1}. {f['effect']}[/] {f['channel'] or ''}: {escape(f['evidence'])}")
