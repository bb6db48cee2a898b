"""Results: browse the test store, read a test's report and events, open its rerun recording,
export its tables."""
from __future__ import annotations

import shutil
import subprocess
from pathlib import Path
from typing import Any

from textual import on
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical, VerticalScroll
from textual.widgets import Button, DataTable, Input, Markdown, Static

from htm.errors import HtmError


class ResultsPane(Vertical):
    can_focus = True
    BINDINGS = [Binding("ctrl+l", "refresh", "refresh list"), Binding("v", "view", "open recording")]
    DEFAULT_CSS = """
    ResultsPane #results-table { height: 12; }
    ResultsPane #results-bar { height: 3; }
    ResultsPane #results-bar Input { width: 40; }
    ResultsPane #results-detail { height: 1fr; border: round $accent; }
    """

    def __init__(self, store_root: Path | str | None = None, **kw: Any) -> None:
        super().__init__(**kw)
        self.store_root = store_root
        self.selected: str | None = None

    def compose(self) -> ComposeResult:
        yield DataTable(id="results-table", cursor_type="row", zebra_stripes=True)
        with Horizontal(id="results-bar"):
            yield Button("Refresh (ctrl+l)", id="refresh")
            yield Button("Open recording (v)", id="view")
            yield Input(placeholder="export folder", id="export-dir")
            yield Button("Export", id="export")
        with VerticalScroll(id="results-detail"):
            yield Static("", id="results-summary")
            yield Markdown("", id="results-report")

    def on_mount(self) -> None:
        t = self.query_one("#results-table", DataTable)
        t.add_columns("id", "name", "kind", "status", "cycles", "a end [mm]", "end reason")
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
            t.add_row(r["id"], r["name"], r["kind"], r["status"], f"{r['cycles']:,}" if r["cycles"] is not None else "",
                      f"{r['a_end_m'] * 1e3:.3f}" if r["a_end_m"] is not None else "", r["end_reason"] or "", key=r["id"])
        if not rows:
            self.query_one("#results-summary", Static).update("the store holds no tests yet: run one (Run tab or `htm run`)")

    @on(DataTable.RowHighlighted, "#results-table")
    def _row(self, ev: DataTable.RowHighlighted) -> None:
        if ev.row_key is not None and ev.row_key.value:
            self.show(str(ev.row_key.value))

    def show(self, test_id: str) -> None:
        """Show one test: summary, results, last events, and its report when it has one."""
        self.selected = test_id
        try:
            with self._store() as st:
                t = st.get(test_id)
        except HtmError as e:
            self.query_one("#results-summary", Static).update(f"[red]{e}[/]")
            return
        lines = [f"[b]{t['id']}[/] {t['name']} ({t['kind']}, {t['mode'] or '-'}) — [b]{t['status']}[/]"
                 + (f", {t['end_reason']}" if t["end_reason"] else "")]
        if t["cycles"] is not None:
            lines.append(f"cycles {t['cycles']:,}" + (f", final a = {t['a_end_m'] * 1e3:.3f} mm" if t["a_end_m"] is not None else ""))
        for k, v in sorted(t["results"].items()):
            if isinstance(v, float):
                lines.append(f"  {k} = {v:.6g}")
        lines.append(f"events ({len(t['events'])}):")
        lines += [f"  {'' if e['cycle'] is None else e['cycle']:>10} {e['kind']:<18} {e['detail'] or ''}" for e in t["events"][-12:]]
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
        exe = shutil.which("rerun")
        if exe is None:
            self.notify(f"rerun viewer not found on PATH; open {rrd} with `rerun {rrd}`", severity="warning", timeout=10)
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
