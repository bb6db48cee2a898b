"""A staircase on the rig, one specimen at a time (issue 33 item 3, ISO 12107).

`htm rig staircase CAMPAIGN.toml --config RIG.toml --out DIR`: the campaign's `[life_campaign]`
(kind = "staircase", its force_life test, start_pa, step_pa, specimens) run on the rig through
`htm.Session`: specimen i at the level the outcome of specimen i − 1 set (the sequence is
`htm.campaign.life.staircase_steps`, the same code the simulated and the Dask staircases run), each
test into the store as any rig test, its end (failure by the test's criterion, or run-out) judged
by the controller on the measured rows. Between specimens a real rig waits for the operator to
mount the next one; the virtual rig grips a new bar of its own (its `[virtual.specimen]` seed
advanced by one per specimen: a new life the controller does not know). The sequence is written
as it grows (`DIR/staircase.csv`, the form `htm sn staircase` reads), then the estimate.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from htm.campaign import life as life_campaign
from htm.campaign.engine import LIFE_ENDS
from htm.control.session import Session
from htm.devices.config import RigConfig, load_config
from htm.errors import HtmError, SpecError
from htm.fatigue import lifetest


def _specimen_rig(cfg: RigConfig, i: int) -> RigConfig:
    """The virtual rig with specimen i's own bar: its seed advanced by i (the bar's life factor
    and nothing else of the rig's truth changes)."""
    vs = dict(cfg.virtual_specimen)
    vs["seed"] = int(vs.get("seed", 1)) + i
    return dataclasses.replace(cfg, virtual_specimen=vs)


def run_specimen(spec: lifetest.LifeSpec, cfg: RigConfig, *, virtual: bool, store: Any = None,
                 max_seconds: float = 3600.0) -> dict[str, Any]:
    """One life test of `spec` on the rig, to its end: the campaign's result row (life, end
    reason, valid) as the simulated campaigns give it. A trip or a lost rig ends the row with
    its reason (not valid: the staircase stops there, the rig safe)."""
    lockstep = cfg.loop.mode == "lockstep"
    t0 = time.perf_counter()
    s = Session().open(cfg, virtual=virtual, specimen=spec, thread=not lockstep)
    try:
        if lockstep:
            s.step(5)
        s.start(spec, store=store, recording=store is not None, record=store is not None)
        lp = s.loop
        per = max(1, int(lp.ctrl.info()["samples_per_cycle"]))
        # to the test's end, or a hold (a trip: the operator's matter, the staircase stops there)
        while lp.ctrl.state not in ("stopped", "idle", "holding") and lp.powered and time.perf_counter() - t0 < max_seconds:
            if lockstep:
                s.step(50 * per)
            else:
                time.sleep(0.2)
        ctrl = lp.ctrl
        end = ctrl.end_reason  # set when the controller ended the test (the loop then unloads and idles)
        trips = [e["message"] for e in s.events_since(0) if e["kind"] == "trip"]
        life = int(ctrl.cycle)
    finally:
        s.close()
    valid = end in LIFE_ENDS  # the ends a campaign counts as an outcome, as on the simulator
    why = None if valid else (trips[-1] if trips else "the test did not end by its criterion")
    return {"life_cycles": life, "end_reason": end or "stopped", "valid": valid, "error": why,
            "wall_s": time.perf_counter() - t0}


def staircase_on_rig(lc: life_campaign.LifeCampaign, cfg: RigConfig, *, virtual: bool, store: Any = None,
                     mount: Callable[[int, float], None] | None = None,
                     on_row: Callable[[int, float, dict[str, Any]], None] | None = None) -> list[dict[str, Any]]:
    """The staircase `lc` run specimen by specimen on the rig. `mount(i, level_pa)` is called
    before specimen i (the operator mounts it; the virtual rig grips its own new bar);
    `on_row(i, level_pa, row)` after each outcome."""
    levels: list[float] = []

    def run_one(i: int) -> dict[str, Any]:
        level = float(lc.campaign.inputs[i][life_campaign.AMPLITUDE[lc.spec.mode]])
        levels.append(level)
        if mount is not None:
            mount(i, level)
        spec = lc.spec.with_(amplitude=level * lc.spec.area_m2)
        row = run_specimen(spec, _specimen_rig(cfg, i) if virtual else cfg, virtual=virtual, store=store)
        if on_row is not None:
            on_row(i, level, row)
        return row

    return life_campaign.staircase_steps(lc, run_one)


def cmd_staircase(args: argparse.Namespace) -> int:
    from htm.fatigue.sn_cli import staircase_files
    from htm.terminal import path

    if not life_campaign.is_life_campaign(args.campaign):
        raise SpecError(f"{args.campaign}: a [life_campaign] with kind = \"staircase\" is needed for `htm rig staircase`")
    lc = life_campaign.load(args.campaign)
    if lc.kind != "staircase":
        raise SpecError(f"{args.campaign}: [life_campaign] kind is {lc.kind!r}; `htm rig staircase` runs kind = \"staircase\"")
    cfg = load_config(args.config)
    virtual = bool(args.virtual)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    csv = out / "staircase.csv"
    csv.write_text("stress_amplitude_pa,runout,cycles,end_reason\n")

    def mount(i: int, level: float) -> None:
        msg = f"specimen {i + 1} of {lc.n}: {level / 1e6:.1f} MPa"
        if virtual:
            print(f"{msg} (the virtual rig grips a new bar)")
        else:
            input(f"{msg}: mount the specimen, then press Enter ")

    def on_row(i: int, level: float, row: dict[str, Any]) -> None:
        print(f"  {row['end_reason']:<10} after {row['life_cycles']:>12,} cycles")
        if not row["valid"]:
            return  # a stop that is no outcome stays out of the staircase's data
        with csv.open("a") as f:
            f.write(f"{level:.6g},{int(row['end_reason'] == 'runout')},{row['life_cycles']},{row['end_reason']}\n")

    try:
        staircase_on_rig(lc, cfg, virtual=virtual, store=args.store, mount=mount, on_row=on_row)
    except HtmError as e:
        print(f"htm rig staircase: stopped, the rig is safe: {e}; the outcomes so far are in {path(csv)}", file=sys.stderr)
        return 2
    staircase_files(csv, out, lc.step)
    print(f"wrote {path(csv)}, {path(out / 'fit.json')}")
    return 0


def add_rig_action(rs: argparse._SubParsersAction) -> None:
    """`htm rig staircase` (added to the `htm rig` group)."""
    p = rs.add_parser("staircase", help="an ISO 12107 staircase on the rig, one specimen at a time",
                      description="Run a [life_campaign] kind = \"staircase\" on the rig: each specimen a force_life test "
                                  "through the control loop at the level the last outcome set (one step up after a run-out, "
                                  "one down after a failure), into the store; a real rig waits for the operator to mount "
                                  "each specimen, the virtual rig grips a new bar of its own. Writes DIR/staircase.csv as it "
                                  "grows and the estimate (htm sn staircase) at the end.")
    p.add_argument("campaign", help="campaign TOML with [life_campaign] kind = \"staircase\"")
    p.add_argument("--config", required=True, help="rig configuration TOML (with an extensometer for strain control)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--store", default=None, help="test store (default: $HTM_STORE)")
    p.add_argument("--virtual", action="store_true",
                   help="start the configuration's virtual rig here and run on it (each specimen a new bar of its own)")
    p.set_defaults(func=cmd_staircase)
