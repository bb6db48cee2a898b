"""rerun streams of a test (rerun-sdk 0.41): entity layout, timelines and the blueprint saved with it.

Timelines: `time` (duration, test time [s]; a per-cycle row sits at cycle/f, the end of its cycle)
and `cycle` (sequence, the per-cycle table's cycle number). Entities, all SI:

| entity | series |
|---|---|
| `signals/position_m` | piston position y |
| `signals/force_n` | load-cell force, force setpoint |
| `signals/pressure_pa` | chamber pressures A, B |
| `signals/valve_v` | valve command |
| `cycle/force_n` | measured peak, valley; target peak, valley |
| `cycle/force_error_pct` | peak error, ΔF error |
| `cycle/crack_length_m` | a |
| `cycle/stress_intensity_pa_sqrt_m` | ΔK, ΔK target, Kmax |
| `cycle/dadn_m_per_cycle` | da/dN |
| `cycle/specimen_stiffness_n_m` | K_sp |
| `cycle/controller_v` | amplitude-loop u1, mean-loop u2 |
| `crack/dadn_vs_delta_k` | points (log10 ΔK [MPa·√m], log10 da/dN [m/cycle]) |
| `events` | text log: limit trips, mode changes, operator actions |

The recording is for visual review: it holds every cycle of the first `full_cycles` and then one
in `stride` plus every cycle that carries an event (the store's Parquet table holds every cycle).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

APP_ID = "htm"
START_BIT = 1

SIGNAL_GROUPS = {  # entity -> (series names, signal column names)
    "signals/position_m": (["y"], ["y_m"]),
    "signals/force_n": (["force", "setpoint"], ["f_n", "f_ref_n"]),
    "signals/pressure_pa": (["p_A", "p_B"], ["p_a_pa", "p_b_pa"]),
    "signals/valve_v": (["u"], ["u_v"]),
}
CYCLE_GROUPS = {
    "cycle/force_n": (["peak", "valley", "target peak", "target valley"], ["fmax_n", "fmin_n", "fmax_target_n", "fmin_target_n"]),
    "cycle/force_error_pct": (["peak", "ΔF"], ["peak_err_pct", "df_err_pct"]),
    "cycle/crack_length_m": (["a"], ["a_m"]),
    "cycle/stress_intensity_pa_sqrt_m": (["ΔK", "ΔK target", "Kmax"], ["delta_k_pa_sqrt_m", "delta_k_target_pa_sqrt_m", "kmax_pa_sqrt_m"]),
    "cycle/dadn_m_per_cycle": (["da/dN"], ["dadn_m_per_cycle"]),
    "cycle/specimen_stiffness_n_m": (["K_sp"], ["k_sp_n_m"]),
    "cycle/controller_v": (["u1 amplitude", "u2 mean"], ["ctrl_u1_v", "ctrl_u2_v"]),
}


def blueprint() -> Any:
    """The layout a recording opens with: per-cycle plots, signals, da/dN–ΔK, events."""
    import rerun as rr
    import rerun.blueprint as rrb

    everything = rr.VisibleTimeRange("cycle", start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.infinite())
    per_cycle = [rrb.TimeSeriesView(origin=e, name=e.split("/", 1)[1]) for e in CYCLE_GROUPS]
    signals = [rrb.TimeSeriesView(origin=e, name=e.split("/", 1)[1]) for e in SIGNAL_GROUPS]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Tabs(rrb.Grid(*per_cycle, name="per cycle"), rrb.Grid(*signals, name="signals")),
            rrb.Vertical(
                rrb.Spatial2DView(origin="crack/dadn_vs_delta_k", name="log da/dN vs log ΔK", time_ranges=everything),
                rrb.TextLogView(origin="events", name="events"),
            ),
            column_shares=[3, 1],
        ),
        collapse_panels=True,
    )


class Recording:
    """A rerun recording of one test, saved to `path`; `spawn` starts a viewer, `connect` (a
    rerun+http URL) streams to a running one. `recording_id` is the test's, so the segments of
    a resumed test are one recording."""

    def __init__(self, path: Path, recording_id: str, name: str, frequency_hz: float, *, spawn: bool = False,
                 connect: str | None = None, full_cycles: int = 10_000, stride: int = 10):
        import rerun as rr

        self.rr = rr
        self.f = float(frequency_hz)
        self.full_cycles, self.stride = full_cycles, stride
        self.rec = rr.RecordingStream(APP_ID, recording_id=recording_id)
        sinks: list[Any] = [rr.FileSink(str(path))]
        if spawn:
            self.rec.spawn(connect=False)
            sinks.append(rr.GrpcSink())
        elif connect:
            sinks.append(rr.GrpcSink(connect))
        self.rec.set_sinks(*sinks, default_blueprint=blueprint())
        self.rec.send_recording_name(name)
        for e, (names, _) in {**CYCLE_GROUPS, **SIGNAL_GROUPS}.items():
            self.rec.log(e, rr.SeriesLines(names=names), static=True)
        self.rec.log("crack/dadn_vs_delta_k", rr.Points2D([[0.0, 0.0]], radii=[0.0]), static=True)

    def _index(self, cycle: np.ndarray, t_s: np.ndarray) -> list[Any]:
        rr = self.rr
        return [rr.TimeColumn("cycle", sequence=cycle.astype(np.int64)), rr.TimeColumn("time", duration=t_s)]

    def cycles(self, table: dict[str, np.ndarray]) -> None:
        """Per-cycle rows (the engine's table columns) in bulk, decimated as the module says."""
        rr = self.rr
        c = np.asarray(table["cycle"])
        if len(c) == 0:
            return
        ev = np.asarray(table.get("events", np.zeros(len(c), np.uint32)))
        keep = (c <= self.full_cycles) | (c % self.stride == 0) | ((ev & ~np.uint32(START_BIT)) != 0)
        c = c[keep]
        idx = self._index(c, c / self.f)
        for e, (_, cols) in CYCLE_GROUPS.items():
            if all(k in table for k in cols):
                v = np.column_stack([np.asarray(table[k], dtype=np.float64)[keep] for k in cols])
                self.rec.send_columns(e, indexes=idx, columns=rr.Scalars.columns(scalars=v))
        dk, dadn = (np.asarray(table.get(k, []), dtype=np.float64)[keep] for k in ("delta_k_pa_sqrt_m", "dadn_m_per_cycle"))
        ok = np.flatnonzero((dk > 0) & (dadn > 0))
        if len(ok):
            ok = ok[:: max(1, len(ok) // 20)]  # ≤ ~20 points per block keep the scatter light
            pts = np.column_stack([np.log10(dk[ok] / 1e6), np.log10(dadn[ok])])
            self.rec.send_columns("crack/dadn_vs_delta_k", indexes=self._index(c[ok], c[ok] / self.f),
                                  columns=rr.Points2D.columns(positions=pts).partition(np.ones(len(ok), dtype=np.int64)))

    def signals(self, cols: dict[str, np.ndarray]) -> None:
        """Samples with `t_s` [s] (and `cycle` when known) and any of the signal columns."""
        rr = self.rr
        t = np.asarray(cols["t_s"], dtype=np.float64)
        if len(t) == 0:
            return
        idx = [rr.TimeColumn("time", duration=t)]
        if "cycle" in cols:
            idx.append(rr.TimeColumn("cycle", sequence=np.asarray(cols["cycle"]).astype(np.int64)))
        known = set()
        for e, (_, names) in SIGNAL_GROUPS.items():
            if all(k in cols for k in names):
                known.update(names)
                v = np.column_stack([np.asarray(cols[k], dtype=np.float64) for k in names])
                self.rec.send_columns(e, indexes=idx, columns=rr.Scalars.columns(scalars=v))
        for k, v in cols.items():
            if k not in known and k not in ("t_s", "cycle"):
                self.rec.send_columns(f"signals/{k}", indexes=idx, columns=rr.Scalars.columns(scalars=np.asarray(v, dtype=np.float64)))

    def event(self, kind: str, detail: str, cycle: int | None, time_s: float | None, level: str = "INFO") -> None:
        if cycle is not None:
            self.rec.set_time("cycle", sequence=int(cycle))
        if time_s is not None:
            self.rec.set_time("time", duration=float(time_s))
        self.rec.log("events", self.rr.TextLog(f"{kind}: {detail}" if detail else kind, level=level))

    def flush(self) -> None:
        """Push what was logged to the sinks; a failed file writer (full disk) raises `RecordError`."""
        from htm.errors import RecordError

        try:
            self.rec.flush(timeout_sec=30.0)
        except RuntimeError as e:
            raise RecordError(f"cannot write the recording: {e}") from None

    def close(self) -> None:
        """Flush everything and write the file's footer."""
        self.flush()
        self.rec.disconnect()
