"""Run: live plots and numbers of the running test, start/hold/resume/stop/e-stop, and the
limits/interlock panel with every detector, its state and action, and a reset."""
from __future__ import annotations

import math
from collections import deque
from typing import Any

from rich.text import Text
from textual import on
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Grid, Horizontal, Vertical
from textual.widgets import Button, DataTable, Static

from htm.tui.plot import LinePlot
from htm.tui.units import plain, right, shown, unit_of

FEED_KEEP = 200     # decimated samples shown (≈ 10 s at 20 Hz)
CYCLES_KEEP = 2000  # per-cycle points shown


# the limits panel: (column key, heading); limits and value in the channel's engineering unit
DETECTOR_COLUMNS = (("name", "detector"), ("watches", "watches"), ("lo", "low limit"), ("hi", "high limit"),
                    ("value", "value"), ("unit", "unit"), ("state", "state"), ("action", "action"), ("latched", "latched"))
NUMERIC = {"lo", "hi", "value"}
# The numeric columns' width [cells]: fixed, so that a wider value shown earlier in a run does not
# widen the panel for good (a cell's update only grows its column) and the columns stay where the
# operator reads them.
NUMERIC_WIDTH = 10


def detector_row(d: dict[str, Any]) -> tuple[Text, ...]:
    """One detector as the limits panel shows it (cells in the order of DETECTOR_COLUMNS)."""
    ch = d["channel"]
    return (plain(d["name"]), plain(unit_of(ch).label), right(shown(ch, d["lo"], limit=True)), right(shown(ch, d["hi"], limit=True)),
            right(shown(ch, d["value"])), plain(unit_of(ch).unit), plain(d["state"]), plain(d["action"]),
            plain("LATCHED" if d["latched"] else ""))


def num(v: float, fmt: str) -> str:
    """A live number, or a dash while there is none yet (before the first cycle)."""
    return "–" if v is None or not math.isfinite(v) else format(v, fmt)


# the plots' titles: a crack-growth test's and a life test's (the live stress–strain loop and the
# judged quantity with its stabilised trend and failure threshold)
CRACK_TITLES = {"plot-force": "force [kN] vs time [s]", "plot-peaks": "peak/valley [kN] vs cycle, ±2 % band",
                "plot-a": "crack length a [mm] vs cycle", "plot-dk": "ΔK [MPa·√m] vs cycle"}
LIFE_TITLES = {"plot-force": "force [kN] vs time [s]", "plot-peaks": "peak/valley force [kN] vs cycle",
               "plot-a": "stress–strain loop, last cycle: σ [MPa] vs ε [%]",
               "plot-dk": "tensile peak [kN] vs cycle, stabilised trend, failure threshold"}


class RunPane(Vertical):
    can_focus = True
    BINDINGS = [
        Binding("s", "start", "start"),
        Binding("h", "hold", "hold"),
        Binding("r", "resume", "resume"),
        Binding("x", "stop", "stop"),
        Binding("ctrl+r", "reset", "reset interlocks"),
    ]
    DEFAULT_CSS = """
    RunPane #run-bar { height: 3; }
    RunPane #run-numbers { height: auto; border: round $accent; padding: 0 1; }
    RunPane #plots { grid-size: 2 2; height: 1fr; min-height: 16; }
    RunPane #detectors { height: 12; }
    RunPane #estop { background: $error; }
    """

    def __init__(self, **kw: Any) -> None:
        super().__init__(**kw)
        self.t: deque[float] = deque(maxlen=FEED_KEEP)
        self.force: deque[float] = deque(maxlen=FEED_KEEP)
        self.cyc: dict[str, deque[float]] = {k: deque(maxlen=CYCLES_KEEP) for k in ("n", "fmax", "fmin", "tmax", "tmin", "a", "a_law", "dk",
                                                                                    "trend", "threshold", "stiff")}
        self.life: dict[str, Any] | None = None  # a life test's live numbers and loop (the snapshot's `life`)

    def compose(self) -> ComposeResult:
        with Horizontal(id="run-bar"):
            yield Button("Start (s)", id="start", variant="success")
            yield Button("Hold (h)", id="hold")
            yield Button("Resume (r)", id="resume")
            yield Button("Stop (x)", id="stop", variant="warning")
            yield Button("E-STOP (F12)", id="estop", variant="error")
            yield Button("Reset (ctrl+r)", id="reset")
        yield Static("", id="run-numbers")
        with Grid(id="plots"):
            for pid, title in CRACK_TITLES.items():
                yield LinePlot(title, id=pid)
        yield DataTable(id="detectors", cursor_type="row", zebra_stripes=True)

    def on_mount(self) -> None:
        t = self.query_one("#detectors", DataTable)
        for key, label in DETECTOR_COLUMNS:
            t.add_column(right(label) if key in NUMERIC else plain(label), key=key,
                         width=NUMERIC_WIDTH if key in NUMERIC else None)

    # ---- data from the app's poller (≤ 10 Hz, coalesced) ---------------------------------------
    def add_feed(self, samples: list[dict[str, Any]]) -> None:
        for s in samples:
            self.t.append(s["t_s"])
            self.force.append(s.get("f", math.nan) / 1e3)

    def add_cycles(self, rows: list[dict[str, Any]]) -> None:
        c = self.cyc
        for r in rows:
            c["n"].append(r["cycle"])
            c["fmax"].append(r["fmax_n"] / 1e3)
            c["fmin"].append(r["fmin_n"] / 1e3)
            c["tmax"].append(r.get("fmax_target_n", math.nan) / 1e3)
            c["tmin"].append(r.get("fmin_target_n", math.nan) / 1e3)
            c["a"].append(r.get("a_m", math.nan) * 1e3)
            c["a_law"].append(r.get("a_law_m", math.nan) * 1e3)
            c["dk"].append(r.get("delta_k_pa_sqrt_m", math.nan) / 1e6)
            # a life test: the judged quantity's stabilised trend and the failure threshold
            # (the tensile peak [kN] under strain control, the secant modulus [GPa] under force)
            scale = 1e3 if r.get("stress_max_pa") is not None and self._strain_control() else 1e9
            c["trend"].append(r.get("trend", math.nan) / scale)
            c["threshold"].append(r.get("threshold", math.nan) / scale)
            if "strain_max" in r:
                de = r["strain_max"] - r["strain_min"]
                c["stiff"].append(r["fmax_n"] / 1e3 if scale == 1e3 else
                                  ((r["fmax_n"] - r["fmin_n"]) / de / self._area() / 1e9 if de > 0 else math.nan))
            else:
                c["stiff"].append(math.nan)

    def _strain_control(self) -> bool:
        return self.life is None or self.life.get("mode") == "strain_life"

    def _area(self) -> float:
        life = self.life or {}
        return life.get("area_m2", math.nan)

    def update_live(self, snap: dict[str, Any], detectors: list[dict[str, Any]]) -> None:
        self.update_numbers(snap)
        self._plots()
        self._detectors(detectors)

    def set_life(self, life: dict[str, Any] | None) -> None:
        """A life test runs (its snapshot's `life`), or none: the plots' titles follow."""
        was = self.life is not None
        self.life = life
        if (life is not None) == was:
            return
        titles = (LIFE_TITLES if life is not None else CRACK_TITLES)
        if life is not None and life.get("mode") == "force_life":
            titles = {**titles, "plot-dk": "secant modulus [GPa] vs cycle, stabilised trend, failure threshold"}
        for pid, title in titles.items():
            p = self.query_one(f"#{pid}", LinePlot)
            p.title = title
            p.path = pid == "plot-a" and life is not None
            p.refresh()

    def update_numbers(self, snap: dict[str, Any]) -> None:
        """The live numbers (kept current behind other tabs too: a tab entered never shows an old state)."""
        self.set_life(snap.get("life"))
        if snap.get("life") is not None:
            self._life_numbers(snap)
            return
        tm = snap.get("timing") or {}
        self.query_one("#run-numbers", Static).update(
            f"[b]state[/] {snap['state']}   [b]cycles[/] {snap['cycles']:,}   [b]f[/] {num(snap['frequency_hz'], '.2f')} Hz   "
            f"[b]a[/] {num(snap['a_m'] * 1e3, '.3f')} mm   [b]ΔK[/] {num(snap['delta_k_pa_sqrt_m'] / 1e6, '.2f')} MPa·√m   "
            f"[b]K_sp[/] {num(snap['k_sp_n_m'] / 1e6, '.1f')} kN/mm\n"
            f"[b]crack[/] {snap.get('crack', 'model')}   [b]a law[/] {num(snap.get('a_law_m', math.nan) * 1e3, '.3f')} mm   "
            f"[b]F_op[/] {num(snap.get('opening_force_n', math.nan) / 1e3, '.3f')} kN   "
            f"[b]ΔK_eff[/] {num(snap.get('delta_k_eff_pa_sqrt_m', math.nan) / 1e6, '.2f')} MPa·√m\n"
            f"[b]peak err[/] {num(snap['peak_err_pct'], '+.2f')} %   [b]ΔF err[/] {num(snap['df_err_pct'], '+.2f')} %   "
            f"[b]amplifier[/] {'ON' if snap['amplifier'] else 'off'}   [b]interlock[/] {snap['interlock'] or 'none'}"
            f"{'   [b red]E-STOP[/]' if snap.get('estop') else ''}   "
            f"[b]loop[/] p99 {num(tm.get('p99_ms', math.nan), '.3f')} ms, overruns {tm.get('overruns', 0)}"
            + (f"   [b]end[/] {snap['end_reason']}" if snap.get("end_reason") else "")
            + (f"\n[b yellow]→ {snap['pending']}[/]" if snap.get("pending") else ""))

    def _life_numbers(self, snap: dict[str, Any]) -> None:
        """A life test's live numbers: mode, cycles, the last cycle's strain and stress
        amplitudes, the judged quantity's trend, its failure threshold and how far it has fallen."""
        lf = snap["life"]
        tm = snap.get("timing") or {}
        strain = lf["mode"] == "strain_life"
        ea = 0.5 * (lf["strain_max"] - lf["strain_min"]) * 100
        sa = 0.5 * (lf["stress_max_pa"] - lf["stress_min_pa"]) / 1e6
        unit, scale = ("kN", 1e3) if strain else ("GPa", 1e9)
        judged = "tensile peak" if strain else "secant modulus"
        c = self.cyc
        last = c["stiff"][-1] if c["stiff"] else math.nan
        fallen = 100 * (1 - last / c["trend"][-1]) if c["trend"] and c["trend"][-1] > 0 else math.nan
        self.query_one("#run-numbers", Static).update(
            f"[b]state[/] {snap['state']}   [b]mode[/] {lf['mode']}   [b]cycles[/] {snap['cycles']:,}   "
            f"[b]f[/] {num(snap['frequency_hz'], '.2f')} Hz   [b]ε_a[/] {num(ea, '.4f')} %   [b]σ_a[/] {num(sa, '.1f')} MPa   "
            f"[b]amplitude err[/] {num(snap['df_err_pct'], '+.2f')} %\n"
            f"[b]{judged}[/] {num(last, '.3f')} {unit}   [b]trend[/] {num(lf['trend'] / scale, '.3f')} {unit}   "
            f"[b]failure at[/] {num(lf['threshold'] / scale, '.3f')} {unit} ({lf['drop'] * 100:g} % drop)   "
            f"[b]fallen[/] {num(fallen, '.1f')} %   [b]10 % drop[/] {lf['n_drop10'] or '–'}   [b]50 % drop[/] {lf['n_drop50'] or '–'}\n"
            f"[b]amplifier[/] {'ON' if snap['amplifier'] else 'off'}   [b]interlock[/] {snap['interlock'] or 'none'}"
            f"{'   [b red]E-STOP[/]' if snap.get('estop') else ''}   "
            f"[b]loop[/] p99 {num(tm.get('p99_ms', math.nan), '.3f')} ms, overruns {tm.get('overruns', 0)}"
            + (f"   [b]end[/] {snap['end_reason']}" if snap.get("end_reason") else "")
            + (f"\n[b yellow]→ {snap['pending']}[/]" if snap.get("pending") else ""))

    def _plots(self) -> None:
        def draw(pid: str, series: list[tuple[list[float], list[float], str]]) -> None:
            self.query_one(f"#{pid}", LinePlot).set_series(series)

        c = {k: list(v) for k, v in self.cyc.items()}
        if self.life is not None:  # a life test: force, peaks, the live loop, the judged quantity
            lf = self.life
            draw("plot-force", [(list(self.t), list(self.force), "F")])
            draw("plot-peaks", [(c["n"], c["fmax"], "peak"), (c["n"], c["fmin"], "valley")])
            draw("plot-a", [([e * 100 for e in lf["loop_strain"]], [s / 1e6 for s in lf["loop_stress_pa"]], "σ(ε)")])
            draw("plot-dk", [(c["n"], c["stiff"], "measured"), (c["n"], c["trend"], "trend"), (c["n"], c["threshold"], "failure")])
            return
        draw("plot-force", [(list(self.t), list(self.force), "F")])
        band = [(c["n"], [v * 1.02 for v in c["tmax"]], "+2 %"), (c["n"], [v * 0.98 for v in c["tmax"]], "−2 %")] if c["n"] else []
        draw("plot-peaks", [(c["n"], c["fmax"], "peak"), (c["n"], c["fmin"], "valley"), *band])
        draw("plot-a", [(c["n"], c["a"], "a"), (c["n"], c["a_law"], "a law")])
        draw("plot-dk", [(c["n"], c["dk"], "ΔK")])

    def _detectors(self, dets: list[dict[str, Any]]) -> None:
        t = self.query_one("#detectors", DataTable)
        rows = [detector_row(d) for d in dets]
        if t.row_count != len(rows):
            t.clear()
            for d, r in zip(dets, rows):
                t.add_row(*r, key=d["name"])
            return
        for d, r in zip(dets, rows):
            for (col, _), val in zip(DETECTOR_COLUMNS, r):
                t.update_cell(d["name"], col, val, update_width=True)  # "ok" → "tripped" must fit

    # ---- commands ---------------------------------------------------------------------------
    def _cmd(self, name: str, *args) -> None:
        self.app.command(name, *args)  # type: ignore[attr-defined]

    @on(Button.Pressed, "#start")
    def action_start(self) -> None:
        spec = self.app.current_spec()  # type: ignore[attr-defined]
        if spec is None:
            self.notify("the spec in Setup is not valid", severity="error")
            return
        for d in self.cyc.values():
            d.clear()
        self._cmd("start", spec)

    @on(Button.Pressed, "#hold")
    def action_hold(self) -> None:
        self._cmd("hold")

    @on(Button.Pressed, "#resume")
    def action_resume(self) -> None:
        self._cmd("resume")

    @on(Button.Pressed, "#stop")
    def action_stop(self) -> None:
        self._cmd("stop")

    @on(Button.Pressed, "#estop")
    def _estop(self) -> None:
        self.app.action_estop()  # type: ignore[attr-defined]

    @on(Button.Pressed, "#reset")
    def action_reset(self) -> None:
        self._cmd("reset")
