"""The `htm` command. Every subcommand has --help; bad input ends with a one-line error, exit 2."""
from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from htm import profiles
from htm.core import Machine, Params
from htm.errors import HtmError
from htm.ident.records import Record, write_record
from htm.params import parse_assignments, rig_metadata, with_overrides
from htm.terminal import add_json_flag, emit_json, path

LAWS = {
    "position_pff": "u[k] = clip(kp*(y_ref[k]-y[k]) + kff*(y_ref[k+1]-y_ref[k])/Ts, -u_max, u_max)",
    "force_p": "u[k] = clip(kp*(f_ref[k]-f[k]), -u_max, u_max)",
}


def _params(args: argparse.Namespace) -> Params:
    overrides = parse_assignments(args.param or [])
    if getattr(args, "specimen_stiffness_n_m", None) is not None:
        overrides["specimen_stiffness_n_m"] = args.specimen_stiffness_n_m
    return with_overrides(Params(args.preset), overrides)


def cmd_simulate(args: argparse.Namespace) -> int:
    params = _params(args)
    if not (np.isfinite(args.rate) and 0 < args.rate <= 1e5):
        raise HtmError(f"--rate {args.rate} Hz is out of range: allowed (0, 100000] Hz")
    dt = 1.0 / args.rate
    signal = profiles.build(args.profile, args.rate)
    m = Machine(params)
    if args.start_position_m is not None:
        if not 0.0 <= args.start_position_m <= params["stroke_m"]:
            raise HtmError(f"--start-position-m {args.start_position_m} is outside the stroke [0, {params['stroke_m']}] m")
        m.state = m.rest_state(args.start_position_m)
    controller = None
    t0 = time.perf_counter()
    if args.controller == "open":
        tr = m.simulate(signal, dt)
    else:
        if args.kp is None:
            raise HtmError(f"--controller {args.controller} needs --kp")
        if args.controller == "position_pff":
            controller = {"type": "position_pff", "kp_v_per_m": args.kp, "kff_v_per_m_s": args.kff or 0.0, "u_max_v": args.u_max}
        else:
            controller = {"type": "force_p", "kp_v_per_n": args.kp, "u_max_v": args.u_max}
        tr = m.track(signal, dt, controller)
        controller["law"] = LAWS[args.controller]
    wall = time.perf_counter() - t0

    columns = {k: tr[k] for k in ("t", "u", "y", "v", "p_a", "p_b", "p_s")}
    specimen = None
    if params["specimen_stiffness_n_m"] > 0:
        columns["f"] = tr["f"]
        specimen = {"stiffness_n_m": params["specimen_stiffness_n_m"]}
    if args.controller == "position_pff":
        columns["y_ref"] = signal
    elif args.controller == "force_p":
        columns["f_ref"] = signal
    meta = {
        "sample_rate_hz": args.rate,
        "rig": rig_metadata(params),
        "specimen": specimen,
        "controller": controller,
        "sensors": {},
        "source": "htm simulate (ideal sensors)",
    }
    table, meta_path = write_record(Record(columns, meta, Path(args.out).name), args.out, compress=args.gz)
    if args.json:
        emit_json({"samples": len(tr["t"]), "rate_hz": args.rate, "wall_s": wall,
                   "ranges": {k: [float(np.nanmin(v)), float(np.nanmax(v))] for k, v in columns.items() if k != "t"},
                   "solver": tr["stats"], "record": [str(table), str(meta_path)]})
        return 0
    _print_summary(tr, dt, wall, controller, signal)
    print(f"record: {path(table)} + {path(meta_path)}")
    return 0


def _print_summary(tr: dict, dt: float, wall: float, controller: dict | None, signal: np.ndarray) -> None:
    n = len(tr["t"])
    dur = n * dt
    st = tr["stats"]
    rows = [
        ("simulated", f"{dur:.3f} s, {n} samples at {1 / dt:.0f} Hz"),
        ("valve command", f"{tr['u'].min():+.3f} .. {tr['u'].max():+.3f} V"),
        ("position", f"{tr['y'].min() * 1e3:.3f} .. {tr['y'].max() * 1e3:.3f} mm"),
        ("velocity", f"{tr['v'].min() * 1e3:+.1f} .. {tr['v'].max() * 1e3:+.1f} mm/s"),
        ("pressure A", f"{tr['p_a'].min() / 1e5:.1f} .. {tr['p_a'].max() / 1e5:.1f} bar"),
        ("pressure B", f"{tr['p_b'].min() / 1e5:.1f} .. {tr['p_b'].max() / 1e5:.1f} bar"),
    ]
    if np.any(tr["f"] != 0):
        rows.append(("specimen force", f"{tr['f'].min() / 1e3:.3f} .. {tr['f'].max() / 1e3:.3f} kN"))
    if controller and controller["type"] == "position_pff":
        e = signal - tr["y"]
        rows.append(("tracking error", f"RMS {np.sqrt(np.mean(e**2)) * 1e3:.3f} mm, max {np.abs(e).max() * 1e3:.3f} mm"))
    if controller and controller["type"] == "force_p":
        e = signal - tr["f"]
        rows.append(("force error", f"RMS {np.sqrt(np.mean(e**2)):.1f} N, max {np.abs(e).max():.1f} N"))
    rows.append(("solver", f"{st['accepted_steps']} steps ({st['rejected_steps']} rejected), {wall * 1e3:.1f} ms wall, "
                           f"{dur / max(wall, 1e-9):.0f}x real time"))
    w = max(len(k) for k, _ in rows)
    for k, v in rows:
        print(f"{k:<{w}}  {v}")


def cmd_params(args: argparse.Namespace) -> int:
    p = Params(args.preset)
    if args.json:
        c, sv = p.valve_map
        emit_json({"preset": args.preset, "params": [dict(f, value=p[f["name"]]) for f in Params.fields()],
                   "valve_map": {"command_v": list(c), "spool_v": list(sv)}})
        return 0
    for f in Params.fields():
        print(f"{f['name']:<36} {p[f['name']]:>12.6g} {f['unit']:<11} {f['doc']}")
    c, s = p.valve_map
    if c:
        print("valve map (command V -> spool V): " + ", ".join(f"{a:g}->{b:.4g}" for a, b in zip(c, s)))
    return 0


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The `htm` parser (every subcommand); with `argv`, only the group of the subcommand it names
    where one does (the others' packages are not imported)."""
    ap = argparse.ArgumentParser(prog="htm", description="Simulate, run, identify and review servo-hydraulic fatigue testing machines.",
                                 epilog="Results print in engineering units (mm, kN, MPa·√m, bar); every command that prints "
                                        "results takes --json for scripts (SI values under their SI names). Long jobs draw "
                                        "one progress line on stderr (plain lines when it is not a terminal). Bad input: "
                                        "one line on stderr naming the file, row and field, exit 2.")
    sub = ap.add_subparsers(dest="command", required=True, metavar="COMMAND")

    s = sub.add_parser("simulate", help="play a command profile on the simulated rig and write a record",
                       description="Play a command profile (open loop) or track a reference (closed loop) on the "
                                   "simulated rig; write a DATA_FORMAT.md record (BASE.csv + BASE.json).",
                       epilog="profile segments: " + "; ".join(
                           ["hold:value=V,duration=S", "ramp:start=A,end=B,duration=S",
                            "sine:amplitude=A,frequency=HZ,duration=S[,offset=O,phase=RAD]", "csv:path=FILE[,column=u]"]))
    s.add_argument("--profile", action="append", required=True, help="profile segments joined by ';' (repeatable)")
    s.add_argument("--out", required=True, help="record base path (writes OUT.csv and OUT.json; never overwrites)")
    s.add_argument("--rate", type=float, default=500.0, help="sample / control rate in Hz (default 500)")
    s.add_argument("--controller", choices=["open", "position_pff", "force_p"], default="open",
                   help="open: the profile is the valve command [V]; position_pff: a position reference [m]; "
                        "force_p: a force reference [N]")
    s.add_argument("--kp", type=float, help="proportional gain (V/m or V/N); negative for the thesis rig's polarity")
    s.add_argument("--kff", type=float, help="velocity feed-forward gain for position_pff [V/(m/s)]")
    s.add_argument("--u-max", type=float, default=10.0, help="command clip [V] (default 10)")
    s.add_argument("--specimen-stiffness-n-m", type=float, help="fit a linear specimen spring [N/m]")
    s.add_argument("--start-position-m", type=float, help="start at rest at this position [m] (default mid-stroke)")
    s.add_argument("--param", action="append", metavar="NAME=VALUE", help="override a machine parameter (SI; see `htm params`)")
    s.add_argument("--preset", choices=["thesis", "base"], default="thesis", help="parameter preset (default thesis)")
    s.add_argument("--gz", action="store_true", help="write the table gzip-compressed (OUT.csv.gz)")
    add_json_flag(s)
    s.set_defaults(func=cmd_simulate)

    p = sub.add_parser("params", help="list machine parameters with units, defaults and sources",
                       description="List every machine parameter of a preset with its unit and source.")
    p.add_argument("--preset", choices=["thesis", "base"], default="thesis")
    add_json_flag(p)
    p.set_defaults(func=cmd_params)

    for register in _extensions(_command_of(argv)):
        register(sub)
    return ap


# Each group of subcommands that lives with its package: the module whose `register` adds its
# parsers, the subcommands it adds, and actions of other packages it takes (`more=`). `htm
# diagnose` imports the identification package only, not the campaign, fleet and fatigue packages
# with their scipy (about a second on every call). tests/test_cli_output.py checks the subcommands
# against what each group's `register` adds.
BUILT_IN = ("simulate", "params")  # defined in this module
GROUPS: dict[str, tuple[str, tuple[str, ...], tuple[str, ...]]] = {
    "run": ("htm.run", ("run", "resume"), ()),
    "fatigue": ("htm.fatigue.cli", ("e647", "crack"), ()),
    "ident": ("htm.ident.cli", ("identify", "diagnose", "predict"), ()),
    "rig": ("htm.control.cli", ("rig",), ("htm.rigcampaign:add_rig_action",)),
    "db": ("htm.record.cli", ("db",), ("htm.correct:add_db_action",)),  # `htm db correct`
    "campaign": ("htm.campaign.cli", ("campaign",), ()),
    "life-band": ("htm.campaign.lifeband_cli", ("life-band",), ()),
    "fleet": ("htm.fleet.cli", ("fleet",), ()),
    "sn": ("htm.fatigue.sn_cli", ("sn", "en"), ()),
    "tune": ("htm.tune", ("tune",), ()),
}


def _command_of(argv: Sequence[str] | None) -> str | None:
    """The subcommand `argv` names (its first word), or None (help, an option, nothing)."""
    words = list(argv or [])
    return words[0] if words and not words[0].startswith("-") else None


def _extensions(command: str | None = None) -> list[Callable[[argparse._SubParsersAction], None]]:
    """Subcommand groups that live with their packages (each adds its own parsers): only the group
    that registers `command` when one does, every group otherwise (help, a typo's suggestions)."""
    if command in BUILT_IN:
        return []
    wanted = [g for g, (_, names, _) in GROUPS.items() if command in names] or list(GROUPS)
    return [_group(g) for g in wanted]


def _group(name: str) -> Callable[[argparse._SubParsersAction], None]:
    """The `register` function of one group (importing its package and those of its actions)."""
    from importlib import import_module

    module, _, actions = GROUPS[name]
    register = import_module(module).register
    if not actions:
        return register
    more = [getattr(import_module(m), f) for m, f in (a.split(":") for a in actions)]
    return lambda sub: register(sub, more=more)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the `htm` command line with `argv` (default: sys.argv[1:]); returns the exit status:
    0 done, 1 a negative verdict (e.g. `run --check` of a test the rig cannot run), 2 bad input
    (one line on stderr naming the file, row and field; never a traceback)."""
    argv = sys.argv[1:] if argv is None else argv
    args = build_parser(argv).parse_args(argv)
    func: Callable[[argparse.Namespace], int] = args.func
    try:
        return func(args)
    except BrokenPipeError:  # `htm ... | head`: the reader has gone; nothing more to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except (HtmError, OSError) as e:
        print(f"htm {command_name(args)}: error: {one_line(e)}", file=sys.stderr)
        return 2


def command_name(args: argparse.Namespace) -> str:
    """The command as typed: `crack predict`, `db show`, `run`."""
    return " ".join(str(v) for k in ("command", "crack_command", "db_command", "fleet_command", "rig_command")
                    if (v := getattr(args, k, None)))


def one_line(e: BaseException) -> str:
    """An error's message on one line (a multi-line message joined with `; `)."""
    text = str(e) if not isinstance(e, OSError) or not e.filename else f"{e.filename}: {e.strerror or e}"
    return "; ".join(part.strip() for part in text.splitlines() if part.strip()) or type(e).__name__


if __name__ == "__main__":
    sys.exit(main())
