"""`htm rig identify RIG.toml --out DIR`: the rig identifies itself. On the configured rig (a
virtual rig's configuration — `[analog] backend = "simulated"` — starts that virtual rig here, as
`htm rig serve` would) run an identification experiment through the device layer: position
control's start-up, holds, ramps at several speeds and a sine sweep around the installed position,
every limit detector armed. Every loop sample becomes a DATA_FORMAT.md record (`u` as sent, the
readings, `y_ref`; `controller` null: the diagnosis replays `u`), written into DIR, and
`htm.diagnose` writes its report and model.json there.

A trip (any detector whose action is not `indicate`) or an e-stop ends the experiment at once: the
loop has already acted (valve to its safe value, amplifier off for power-off trips); the
experiment then stops the loop safely (valve null, amplifier off, supply unloaded), writes what
it recorded and says which detector tripped. The diagnosis is not run on an interrupted record."""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from htm.control.session import Session, specimen_of
from htm.devices.config import RigConfig, load_config
from htm.errors import HtmError
from htm.params import rig_metadata


@dataclass
class Plan:
    """The experiment (SI): amplitude around the installed position, ramp speeds, sweep range."""
    amplitude_m: float = 4e-3
    hold_s: float = 0.6
    ramp_speeds_m_s: tuple[float, ...] = (0.002, 0.005, 0.012)
    sweep_hz: tuple[float, float] = (0.3, 12.0)
    sweep_s: float = 10.0
    # position loop for the experiment: faster than installation's, so the sweep accelerates the
    # moving mass enough to tell it from a static pressure offset (within the velocity limit)
    max_speed_m_s: float = 0.08
    bandwidth_per_s: float = 60.0


def add_plan_args(p: Any) -> None:
    """The experiment's command-line options (`htm rig identify`, `htm fleet identify`)."""
    d = Plan()
    p.add_argument("--amplitude", type=float, help=f"motion amplitude around the installed position [mm] (default {d.amplitude_m * 1e3:g})")
    p.add_argument("--ramp-speeds", type=float, nargs="+", metavar="MM_S",
                   help=f"ramp speeds [mm/s] (default {' '.join(f'{v * 1e3:g}' for v in d.ramp_speeds_m_s)})")
    p.add_argument("--sweep-s", type=float, help=f"duration of the sine sweep [s] (default {d.sweep_s:g}; shorter: a quicker, "
                                                 "less certain identification)")


def plan_of(args: Any) -> Plan:
    """The experiment the options of `add_plan_args` ask for; HtmError names a bad value."""
    plan = Plan()
    if args.amplitude is not None:
        if not (math.isfinite(args.amplitude) and 0.0 < args.amplitude <= 50.0):
            raise HtmError(f"--amplitude {args.amplitude!r}: give millimetres in (0, 50]")
        plan = replace(plan, amplitude_m=args.amplitude * 1e-3)
    if args.ramp_speeds:
        if not all(math.isfinite(v) and 0.0 < v <= 1000.0 for v in args.ramp_speeds):
            raise HtmError(f"--ramp-speeds {args.ramp_speeds!r}: give speeds in mm/s in (0, 1000]")
        plan = replace(plan, ramp_speeds_m_s=tuple(v * 1e-3 for v in args.ramp_speeds))
    if args.sweep_s is not None:
        if not (math.isfinite(args.sweep_s) and 0.5 <= args.sweep_s <= 600.0):
            raise HtmError(f"--sweep-s {args.sweep_s!r}: give seconds in [0.5, 600]")
        plan = replace(plan, sweep_s=args.sweep_s)
    return plan


@dataclass
class Outcome:
    record_base: Path
    samples: int
    tripped: list[str] = field(default_factory=list)
    report: dict[str, Any] | None = None
    test_id: str | None = None  # the test store's id of this identification

    @property
    def complete(self) -> bool:
        return not self.tripped


class Experiment:
    """The experiment on an open `Session` (thread=False: the experiment drives the loop)."""

    def __init__(self, session: Session, plan: Plan):
        self.s, self.plan = session, plan
        self.rows: list[tuple[float, ...]] = []
        lp = session.loop
        self.dt = lp.dt
        g = lp.ctrl.info()
        self.vmax = g["max_speed_m_s"]
        self._events0 = session.log.count

    def _period(self) -> None:
        lp = self.s.loop
        lp.period()
        m = lp.meas
        self.rows.append((lp.k * lp.dt, m["u"], m["y"], m["v"], m["p_a"], m["p_b"], m["p_s"], m["f"], lp.ctrl.reference_m))
        trips = self.trips()
        if trips or not lp.powered:
            raise _Stopped(trips or ["amplifier off"])

    def trips(self) -> list[str]:
        return [f"{e['detector']} ({e['message']})" for e in self.s.log.since(self._events0)
                if e["kind"] == "trip" and e.get("action") != "indicate"] + (["estop"] if self.s.loop.safety.estop else [])

    def _hold(self, seconds: float) -> None:
        c = self.s.loop.ctrl
        c.jog(0.0)
        for _ in range(round(seconds / self.dt)):
            self._period()

    def _ramp(self, dy: float, speed: float) -> None:
        c = self.s.loop.ctrl
        c.jog(math.copysign(min(speed, self.vmax), dy))
        for _ in range(round(abs(dy) / min(speed, self.vmax) / self.dt)):
            self._period()
        c.jog(0.0)

    def run(self) -> None:
        p, s = self.plan, self.s
        s.position()  # the start-up (low pressure, null, ramp) is not part of the record
        self._events0 = s.log.count
        A = p.amplitude_m
        self._hold(p.hold_s)
        for v in p.ramp_speeds_m_s:
            self._ramp(A, v)
            self._hold(p.hold_s)
            self._ramp(-2 * A, v)
            self._hold(p.hold_s)
            self._ramp(A, v)
            self._hold(p.hold_s)
        # logarithmic sine sweep of the reference: y_ref = y0 + A_f sin(phase), speed-limited amplitude
        c = s.loop.ctrl
        f0, f1 = p.sweep_hz
        n = round(p.sweep_s / self.dt)
        k = math.log(f1 / f0) / p.sweep_s
        for i in range(n):
            t = i * self.dt
            f = f0 * math.exp(k * t)
            amp = min(A, 0.8 * self.vmax / (2 * math.pi * f))
            phase = 2 * math.pi * f0 * (math.exp(k * t) - 1.0) / k
            c.jog(max(-self.vmax, min(self.vmax, amp * 2 * math.pi * f * math.cos(phase))))
            self._period()
        self._hold(p.hold_s)

    def record(self, cfg: RigConfig, params: Any):
        from htm.ident.records import Record

        cols = np.array(self.rows, dtype=float).reshape(-1, 9)
        names = ("t", "u", "y", "v", "p_a", "p_b", "p_s", "f", "y_ref")
        columns = {n: cols[:, i] for i, n in enumerate(names)}
        columns["t"] = columns["t"] - columns["t"][0] if len(cols) else columns["t"]
        gripped = self.s.rig is not None and self.s.rig.plant.k_sp_n_m > 0.0
        if not gripped:
            del columns["f"]
        meta = {
            "format": "htm-record/1",
            "sample_rate_hz": cfg.loop.rate_hz,
            "rig": {**rig_metadata(params), "valve_polarity": params["valve_polarity"]},
            "specimen": {"stiffness_n_m": self.s.rig.plant.k_sp_n_m} if gripped else None,
            "controller": None,
            "sensors": {"y": {"resolution_m": cfg.transducer.resolution_m},
                        "v": {"resolution_m_s": cfg.transducer.speed_resolution_m_s}},
            "source": "htm rig identify (position control: holds, ramps, sine sweep)",
        }
        return Record(columns, meta, "identify")


class _Stopped(Exception):
    def __init__(self, why: list[str]):
        super().__init__("; ".join(why))
        self.why = why


def identify(config: RigConfig | str | Path, out: str | Path, *, specimen: Any = None, plan: Plan | None = None,
             diagnose: bool = True, inject: tuple[str, float, float] | None = None, store: Any = None) -> Outcome:
    """Run the experiment on the configured rig, record it into `out`, diagnose it there, and
    keep the record (and the report and model) as a test of kind `identify` in the test store
    (`store`: its root, default $HTM_STORE; False = not stored). `inject` = (fault, value, at_s):
    a virtual rig's fault injected that far into the experiment (the safety path's test)."""
    from htm.ident.records import write_record

    cfg = load_config(config) if isinstance(config, (str, Path)) else config
    plan = plan or Plan()
    pos = {**cfg.position, "max_speed_m_s": plan.max_speed_m_s, "bandwidth_per_s": plan.bandwidth_per_s}
    if specimen is None and pos.get("protect_force_n", 0.0) > 0.0:
        # a free piston: protect still brings the speed to zero as |force| nears its level, but its
        # gain is set so that at zero force it allows the experiment's speed (the installation's
        # stiff-specimen gain would hold a free piston to ~1 mm/s and leave the mass unexcited)
        pos["protect_stiffness_n_m"] = min(pos.get("protect_stiffness_n_m", 1e8),
                                           plan.bandwidth_per_s * pos["protect_force_n"] / plan.max_speed_m_s)
    cfg = replace(cfg, position=pos)
    out = Path(out)
    base = out / "identify"
    if any(base.with_suffix(x).exists() for x in (".csv", ".json")) or (out / "report.json").exists():
        raise HtmError(f"{out} already holds an identification (identify.csv or report.json): choose another --out; "
                       "nothing was run")
    out.mkdir(parents=True, exist_ok=True)
    if specimen is not None and not isinstance(specimen, dict):
        specimen = specimen_of(specimen)
    virtual = cfg.analog.backend == "simulated"
    s = Session().open(cfg, virtual=virtual, specimen=specimen, thread=False)
    tripped: list[str] = []
    try:
        exp = Experiment(s, plan)
        if inject is not None:
            fault, value, at_s = inject
            period = exp._period
            start = [None]

            def faulty() -> None:
                if start[0] is None:
                    start[0] = s.loop.k
                if (s.loop.k - start[0]) * exp.dt >= at_s and fault not in s.rig.faults:
                    s.rig.inject(fault, value)
                period()
            exp._period = faulty
        try:
            exp.run()
        except _Stopped as e:
            tripped = e.why
        except HtmError as e:
            tripped = [str(e)]
        rec = exp.record(cfg, _session_params(s))
    finally:
        s.close()  # valve null, amplifier off, supply unloaded
    write_record(rec, base)
    res = Outcome(base, len(rec.columns["t"]), tripped)
    test_id = _store_open(store, plan, res) if store is not False else None
    try:
        if diagnose and not tripped:
            from htm.ident.diagnose import diagnose as run_diagnosis

            try:
                res.report = run_diagnosis(rec, out_dir=out)
            except HtmError as e:  # the diagnosis refuses the record: the rig is already safe, the record kept
                kept = f"{base}.csv" + (f" and store test {test_id} (status failed)" if test_id else "")
                raise HtmError(f"{e} — the experiment ended safely (valve null, amplifier off, supply unloaded); "
                               f"its {res.samples:,} samples are kept: {kept}") from None
    finally:
        if test_id is not None:
            _store_close(store, test_id, out, res)
    res.test_id = test_id
    return res


def _store_open(root: Any, plan: Plan, res: Outcome) -> str:
    import dataclasses
    import json

    from htm.record.store import Store

    with Store(root) as st:
        test_id = st.create_test("identify", "identify", None, "json", json.dumps(dataclasses.asdict(plan)))
        import shutil

        for ext, role in ((".csv", "record"), (".json", "record_meta")):
            dst = st.test_dir(test_id) / f"identify{ext}"
            shutil.copy2(res.record_base.with_suffix(ext), dst)
            st.add_file(test_id, role, dst)
        for why in res.tripped:
            st.add_event(test_id, "trip", why, source="identify")
        return test_id


def _store_close(root: Any, test_id: str, out: Path, res: Outcome) -> None:
    import shutil

    from htm.record.store import Store

    with Store(root) as st:
        for name, role in (("report.json", "report"), ("model.json", "model")):
            if (out / name).exists():
                dst = st.test_dir(test_id) / name
                shutil.copy2(out / name, dst)
                st.add_file(test_id, role, dst)
        findings = (res.report or {}).get("findings") or []
        st.set_results(test_id, {"samples": res.samples, "findings": [f["effect"] for f in findings]})
        st.set_status(test_id, "stopped" if res.tripped else ("finished" if res.report is not None else "failed"),
                      end_reason=("; ".join(res.tripped) or None))


def _session_params(s: Session):
    from htm import core
    from htm.params import with_overrides

    return with_overrides(core.Params(s.cfg.rig_preset), s.cfg.rig_overrides)
