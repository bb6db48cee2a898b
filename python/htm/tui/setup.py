"""Setup: every spec field with validation as you type, what the rig can do with the test (the
feasibility check of `htm run --check`), presets, TOML load/save, and "simulate this test" on the
fast engine (predicted life and force-error statistics)."""
from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from rich.markup import escape
from textual import on, work
from textual.app import ComposeResult
from textual.containers import Horizontal, Vertical, VerticalScroll
from textual.message import Message
from textual.widgets import Button, Input, Label, Select, Static

from htm import spec as specmod
from htm.errors import HtmError
from htm.feasibility import TITLES
from htm.tui import fields as F

DEFAULT_SPEC = Path(__file__).resolve().parents[3] / "examples" / "ct_constant_force.toml"


def default_doc() -> dict[str, Any]:
    """The example C(T) test (Table B.1-like) as the starting document."""
    try:
        return tomllib.loads(DEFAULT_SPEC.read_text())
    except OSError:
        return {
            "specimen": dict(F.SPECIMENS["C(T) W 50.8 B 6.35 (Table B.1)"]),
            "material": dict(F.MATERIALS["structural steel"]),
            "law": {"law": "paris", "c": 1.1413e-29, "m": 3.0},
            "loading": {"waveform": "sine", "frequency_hz": 10.0, "control_rate_hz": 1000.0, "mode": "constant_force",
                        "delta_f_n": 4450.0, "r_ratio": 0.1},
            "controller": {"type": "demodulation"},
            "end": {"a_over_w": 0.6, "size_criterion": "flag"},
        }


class SetupPane(Vertical):
    """The spec form. Posts `SpecChanged` whenever the document becomes valid or invalid."""

    DEFAULT_CSS = """
    SetupPane { height: 1fr; }
    SetupPane #form { height: 1fr; }
    SetupPane .row { height: 3; }
    SetupPane .row Label { width: 22; padding: 1 1 0 0; }
    SetupPane .row Input, SetupPane .row Select { width: 24; }
    SetupPane .unit { width: 22; padding: 1 0 0 1; color: $text-muted; }
    SetupPane .err { width: 1fr; padding: 1 0 0 1; color: $error; }
    SetupPane #setup-status { height: auto; padding: 0 1; }
    SetupPane #setup-check { height: auto; padding: 0 1; }
    SetupPane #setup-bar { height: 3; }
    SetupPane #setup-bar Select { width: 34; }
    SetupPane #setup-bar Input { width: 1fr; }
    SetupPane #setup-bar Button { width: auto; min-width: 8; }
    SetupPane #sim-result { height: auto; padding: 0 1; }
    SetupPane #setup-model-bar { height: 3; }
    SetupPane #setup-model-bar Label { padding: 1 1 0 1; }
    SetupPane #setup-model-bar Input { width: 1fr; }
    """

    class SpecChanged(Message):
        def __init__(self, spec: specmod.TestSpec | None) -> None:
            self.spec = spec
            super().__init__()

    def __init__(self, doc: dict[str, Any] | None = None, name: str | None = None, **kw: Any) -> None:
        super().__init__(**kw)
        self.doc = doc or default_doc()
        # the test's name in the store and the event log
        self.name_ = name or (DEFAULT_SPEC.stem if doc is None else "spec")
        self.spec: specmod.TestSpec | None = None
        self.bad: dict[str, str] = {}  # field id -> reason (unparsable text)

    def compose(self) -> ComposeResult:
        with Horizontal(id="setup-bar"):
            yield Select([(k, k) for k in F.SPECIMENS], prompt="specimen preset", id="preset-specimen")
            yield Select([(k, k) for k in F.MATERIALS], prompt="material preset", id="preset-material")
            yield Input(placeholder="spec file (.toml)", id="spec-path")
            yield Button("Load", id="load")
            yield Button("Save", id="save")
            yield Button("Simulate", id="simulate", variant="primary")
        with Horizontal(id="setup-model-bar"):
            yield Label("rig model")
            yield Input(placeholder="model.json of `htm rig identify` (Identify F7): simulate on the rig's twin; "
                                    "blank: the nominal rig", id="model-path")
        yield Static("", id="setup-status")
        yield Static("", id="setup-check")
        yield Static("", id="sim-result")
        with VerticalScroll(id="form"):
            for f in F.FIELDS:
                with Horizontal(classes="row", id=f"row-{f.id}"):
                    yield Label(f.label)
                    if f.choices:
                        yield Select([(c, c) for c in f.choices], allow_blank=False, value=F.choice(f, self.doc), id=f.id)
                    else:
                        yield Input(F.show(f, self.doc), id=f.id)
                    yield Static(f.unit, classes="unit")
                    yield Static("", classes="err", id=f"err-{f.id}")

    def on_mount(self) -> None:
        self._refresh()

    # ---- editing ------------------------------------------------------------------------
    def _field(self, wid: str | None) -> F.Field | None:
        return next((f for f in F.FIELDS if f.id == wid), None)

    @on(Input.Changed)
    def _input(self, ev: Input.Changed) -> None:
        f = self._field(ev.input.id)
        if f is not None:
            self._set(f, ev.value)

    @on(Select.Changed)
    def _select(self, ev: Select.Changed) -> None:
        sid = ev.select.id or ""
        if sid == "preset-specimen" and ev.value in F.SPECIMENS:
            self.load_doc({**self.doc, "specimen": dict(F.SPECIMENS[ev.value])})
            return
        if sid == "preset-material" and ev.value in F.MATERIALS:
            self.load_doc({**self.doc, "material": dict(F.MATERIALS[ev.value])})
            return
        f = self._field(sid)
        if f is not None and ev.value is not Select.BLANK:
            self._set(f, str(ev.value))

    def _set(self, f: F.Field, text: str) -> None:
        try:
            value = F.parse_value(f, text)
        except ValueError as e:
            self.bad[f.id] = str(e)
        else:
            self.bad.pop(f.id, None)
            self.doc = F.with_value(self.doc, f, value)
            if f.path == ("loading", "mode"):
                # into a life mode (or back to a crack test's): its values where the document has
                # none yet, shown in the form
                doc = {k: dict(v) if isinstance(v, dict) else v for k, v in self.doc.items()}
                missing = False
                fill = F.LIFE_DEFAULTS if F.is_life(self.doc) else {k: v for k, v in default_doc().items() if isinstance(v, dict)}
                for sec, vals in fill.items():
                    for k, v in vals.items():
                        if k not in doc.setdefault(sec, {}):
                            doc[sec][k], missing = v, True
                if missing:
                    self.load_doc(doc)
                    return
        self._refresh()

    def load_doc(self, doc: dict[str, Any], name: str | None = None) -> None:
        """Replace the whole document (preset, file) and show its values."""
        self.doc = doc
        self.bad.clear()
        if name:
            self.name_ = name
        for f in F.FIELDS:
            w = self.query_one(f"#{f.id}")
            with self.prevent(Input.Changed, Select.Changed):
                if isinstance(w, Select):
                    w.value = F.choice(f, doc)
                else:
                    w.value = F.show(f, doc)
        self._refresh()

    def _refresh(self) -> None:
        for f in F.FIELDS:
            self.query_one(f"#row-{f.id}").display = F.visible(f, self.doc)
            self.query_one(f"#err-{f.id}", Static).update(self.bad.get(f.id, ""))
        status = self.query_one("#setup-status", Static)
        self.query_one("#setup-check", Static).update("")  # shown again for a valid spec
        if self.bad:
            self.spec = None
            status.update(f"[b red]✗[/] {len(self.bad)} field(s) unreadable")
        else:
            self.spec, fid, msg = F.validate(self.doc, self.name_)
            if self.spec is not None and F.is_life(self.doc):
                c = self.spec.config
                amp = (f"ε_a {c['amplitude'] * 100:.3g} %" if self.spec.mode == "strain_life"
                       else f"F_a {c['amplitude'] / 1e3:.3g} kN (σ_a {c['amplitude'] / self.spec.area_m2 / 1e6:.0f} MPa)")
                ends = [f"{c.get('drop', 0.5) * 100:g} % drop" if c.get("drop", 0.5) > 0 else "",
                        f"{c['modulus_ratio_drop'] * 100:g} % modulus ratio" if c.get("modulus_ratio_drop", 0) > 0 else "",
                        f"run-out {c.get('runout_cycles', 1e7):,.0f}"]
                status.update(f"[b green]✓[/] valid: round bar D {c.get('diameter_m', 6.35e-3) * 1e3:.2f} mm, {self.spec.mode}, {amp}, "
                              f"sine {c.get('frequency_hz', 5.0):g} Hz; ends at {', '.join(e for e in ends if e)}")
            elif self.spec is not None:
                status.update(f"[b green]✓[/] valid: {self.spec.geometry.upper()} W {self.spec.width_m * 1e3:.1f} mm, "
                              f"{self.spec.phases[-1].mode}, {self.spec.waveform} {self.spec.frequency_hz:g} Hz")
                self._check(self.spec)
            else:
                status.update(f"[b red]✗[/] {msg}")
                if fid:
                    self.query_one(f"#err-{fid}", Static).update(msg or "")
        self.post_message(self.SpecChanged(self.spec))

    def _check(self, spec: specmod.TestSpec) -> None:
        """Show every limit; a refused test cannot be run or simulated unless its spec overrides."""
        feas = spec.feasibility()
        colour = {"ok": "green", "marginal": "yellow", "refused": "red"}
        lines = [f"[b {colour[c.status]}]{c.status.upper():<8}[/] {TITLES[c.name]}: {escape(c.text)}" for c in feas.checks]
        self.query_one("#setup-check", Static).update("[b]can the rig run it?[/] " + escape(feas.verdict()) + "\n" + "\n".join(lines))
        if not feas.feasible and not spec.override_limits:
            self.spec = None
            self.query_one("#setup-status", Static).update(f"[b red]✗[/] {escape(feas.refusal())}")
            for c in feas.refused:
                self.query_one(f"#err-{F.field_of_check(c.name, self.doc)}", Static).update(escape(c.text))

    # ---- files and simulation -------------------------------------------------------------
    @on(Button.Pressed, "#load")
    def _load(self) -> None:
        path = Path(self.query_one("#spec-path", Input).value.strip() or DEFAULT_SPEC)
        try:
            doc = tomllib.loads(path.read_text())
        except (OSError, tomllib.TOMLDecodeError) as e:
            self.notify(f"cannot load {path}: {e}", severity="error")
            return
        self.load_doc(doc, path.stem)
        self.notify(f"loaded {path}")

    @on(Button.Pressed, "#save")
    def _save(self) -> None:
        text = self.query_one("#spec-path", Input).value.strip()
        if not text:
            self.notify("type a file name to save to", severity="warning")
            return
        try:
            doc = F.effective(self.doc)
            if F.is_life(doc):  # a life test: its own rules (htm.fatigue.lifetest), the same TOML
                from htm.fatigue import lifetest

                lifetest.parse(doc, Path(text).stem)
                if Path(text).exists():
                    raise HtmError(f"{text} exists; refusing to overwrite a spec")
                Path(text).write_text(specmod.dumps(doc))
            else:
                specmod.save(doc, text, Path(text).stem)
        except (HtmError, OSError) as e:
            self.notify(f"not saved: {e}", severity="error")
            return
        self.notify(f"saved {text}")

    @on(Button.Pressed, "#simulate")
    def action_simulate(self) -> None:
        if self.spec is None:
            self.notify("fix the spec first", severity="error")
            return
        model = self.query_one("#model-path", Input).value.strip() or None
        where = f"the twin {model}" if model else "the nominal rig"
        self.query_one("#sim-result", Static).update(f"simulating on the fast engine (cycle-jump), on {escape(where)}…")
        self._simulate(self.spec, model)

    @work(thread=True, exclusive=True, group="simulate")
    def _simulate(self, spec: Any, model: str | None = None) -> None:
        from htm.run import run_spec, summary
        from htm.twin import label, on_model

        if F.is_life(self.doc):  # the life engine with the cycle jump (htm run of a life spec)
            from htm.fatigue import lifetest

            try:
                out, wall = lifetest.run(spec)
                s = lifetest.summary(spec, out, wall)
                st = s["stabilised"]
                text = (f"[b]predicted life[/] {s['cycles']:,} cycles → {s['end_reason']}"
                        + (f"   [b]stabilised[/] σ_a {st['stress_amplitude_pa'] / 1e6:.1f} MPa at ε_a {st['strain_amplitude'] * 100:.3f} %" if st else "")
                        + f"   [dim]{wall:.2f} s wall[/]")
            except HtmError as e:
                text = f"[red]simulation refused: {escape(str(e))}[/]"
            self.app.call_from_thread(self.query_one("#sim-result", Static).update, text)
            return
        try:
            if model:  # the identified plant (base parameters and every finding) instead of the nominal rig
                spec = on_model(spec, model)
            out, wall = run_spec(spec, "jump")
            s = summary(spec, out, wall, "jump")
            text = (f"[b]predicted life[/] {s['cycles']:,} cycles → {s['end_reason']}, a = {s['final_a_m'] * 1e3:.2f} mm "
                    f"(a/W {s['final_a_over_w']:.3f})\n[b]force error[/] max |ΔF| {s['max_abs_df_err_pct']:.2f} %, "
                    f"max |peak| {s['max_abs_peak_err_pct']:.2f} %: {'inside' if s['force_in_band'] else '[b red]OUTSIDE[/]'} the band "
                    f"±{s['force_tolerance_pct']:g} %   [dim]{wall:.2f} s wall[/]\n[b]plant[/] {escape(label(spec.twin))}")
        except HtmError as e:
            text = f"[red]simulation refused: {escape(str(e))}[/]"
        self.app.call_from_thread(self.query_one("#sim-result", Static).update, text)
