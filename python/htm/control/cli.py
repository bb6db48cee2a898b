"""`htm rig serve CONFIG`: run the virtual rig as its own process on the configured bus and
shared-memory DAQ, answering each SYNC with one plant period, until interrupted."""
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


def register(sub: argparse._SubParsersAction) -> None:
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
