"""`htm rig serve CONFIG`: run the virtual rig as its own process on the configured bus and
shared-memory DAQ, answering each SYNC with one plant period, until interrupted.
`htm rig identify CONFIG --out DIR`: the identification experiment (`htm.control.identify`)."""
from __future__ import annotations

import argparse
import signal
import threading
from typing import Any

from htm.devices.config import load_config
from htm.devices.rig import VirtualRig


def cmd_serve(args: argparse.Namespace) -> int:
    cfg = load_config(args.config)
    specimen: dict[str, Any] | None = None
    if args.spec:
        from htm.control.session import specimen_of
        from htm.spec import load

        specimen = specimen_of(load(args.spec))
    rig = VirtualRig(cfg, specimen, threaded=True)
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    signal.signal(signal.SIGINT, lambda *_: done.set())
    print(f"virtual rig ready: transducer node {cfg.transducer.node_id} on {cfg.bus.interface}:{cfg.bus.channel}, "
          f"DAQ {cfg.analog.device!r}, {cfg.loop.rate_hz:g} Hz per SYNC", flush=True)
    try:
        done.wait(args.seconds)
    finally:
        print(f"virtual rig stopping after {rig.periods} periods", flush=True)
        rig.close()
    return 0


def cmd_identify(args: argparse.Namespace) -> int:
    from htm.control.identify import identify, plan_of

    specimen = None
    if args.specimen:
        from htm.spec import load

        specimen = load(args.specimen)
    plan = plan_of(args)
    res = identify(args.config, args.out, specimen=specimen, plan=plan)
    print(f"record: {res.record_base}.csv + .json ({res.samples} samples)")
    if res.tripped:
        print(f"experiment stopped safely (valve null, amplifier off, supply unloaded): {'; '.join(res.tripped)}; "
              "the samples recorded up to the trip are kept; no diagnosis")
        return 1
    findings = (res.report or {}).get("findings") or []
    for f in findings:
        ch = f" on {f['channel']}" if f.get("channel") else ""
        params = ", ".join(f"{k} = {v:.4g}" for k, v in f["params"].items())
        print(f"finding: {f['effect']}{ch}: {params}")
    if not findings:
        print("no finding: the base model explains the rig")
    print(f"report and model.json: {args.out}")
    return 0


def register(sub: argparse._SubParsersAction, more: list | None = None) -> None:
    """`htm rig` and its commands; `more`: functions adding actions from higher layers."""
    from htm.control.identify import add_plan_args

    rig = sub.add_parser("rig", help="the virtual rig (serve it to another process)",
                         description="Virtual rig commands.")
    rs = rig.add_subparsers(dest="rig_command", required=True, metavar="RIG_COMMAND")
    s = rs.add_parser("serve", help="run the virtual rig on the configured bus and simulated DAQ",
                      description="Run the virtual rig (Rust plant + specimen) behind a CANopen transducer on the "
                                  "configured bus and the simulated DAQ, one plant period per SYNC, until interrupted.")
    s.add_argument("config", help="rig configuration TOML (bus, transducer, analog, loop, limits)")
    s.add_argument("--spec", help="test spec TOML whose specimen is gripped (default: none)")
    s.add_argument("--seconds", type=float, default=None, help="stop after this many seconds (default: run until interrupted)")
    s.set_defaults(func=cmd_serve)
    i = rs.add_parser("identify", help="run an identification experiment on the rig and diagnose it",
                      description="On the configured rig (a virtual rig's configuration starts that rig here): position "
                                  "control's start-up, holds, ramps at several speeds and a sine sweep around the installed "
                                  "position, every detector armed; the samples as a DATA_FORMAT.md record in OUT, then "
                                  "htm diagnose's report and model.json there. A trip stops the experiment safely.")
    i.add_argument("config", help="rig configuration TOML")
    i.add_argument("--specimen", help="test spec TOML whose specimen is gripped (default: none, a free piston)")
    add_plan_args(i)
    i.add_argument("--out", required=True, help="folder for the record, report.json and model.json")
    i.set_defaults(func=cmd_identify)
    for add in more or []:
        add(rs)
