"""`htm rig identify` on virtual rigs with hidden physics (issue 30, items 2 and 3): each rig's
`[virtual.effects]` is its truth, known to nothing but its plant; the experiment runs through
the device layer and `htm.diagnose` names what it finds. Prints JSON: per rig the hidden effects,
the findings with their parameters and the relative error against the truth, whether exactly the
hidden effects were found (every parameter within 30 %), and the wall time.

    .venv/bin/python benchmarks/rig_identify.py [--rigs two none untuned]
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

from htm.control.identify import identify
from htm.devices.config import virtual_config

RIGS = {
    # the pair of the acceptance: one valve effect, one sensor effect
    "two": {"valve_null_bias": {"bias_v": 0.12}, "sensor_offset": {"channel": "p_a", "offset_pa": 3e5}},
    "none": {},
    # a pair nobody tuned the experiment for
    "untuned": {"internal_leakage": {"coeff_m3_per_s_pa": 3e-12}, "sensor_offset": {"channel": "p_b", "offset_pa": -2e5}},
}


def judge(hidden: dict, findings: list[dict]) -> dict:
    found = {(f["effect"], f.get("channel")): f["params"] for f in findings}
    truth = {(eid, e.get("channel")): {k: v for k, v in e.items() if k != "channel"} for eid, e in hidden.items()}
    errors = {f"{eid}{'@' + ch if ch else ''}": {k: (found[(eid, ch)][k] - v) / v for k, v in params.items()}
              for (eid, ch), params in truth.items() if (eid, ch) in found}
    exact = set(found) == set(truth) and all(abs(e) <= 0.30 for errs in errors.values() for e in errs.values())
    return {"rel_errors": errors, "missed": [f"{e}@{c}" if c else e for e, c in truth if (e, c) not in found],
            "extra": [f"{e}@{c}" if c else e for e, c in found if (e, c) not in truth], "exact": exact}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rigs", nargs="+", choices=sorted(RIGS), default=["two", "none"])
    args = ap.parse_args(argv)
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.rigs:
            t0 = time.perf_counter()
            res = identify(virtual_config("lockstep", virtual={"effects": RIGS[name]}), Path(tmp) / name)
            findings = (res.report or {}).get("findings") or []
            out.append({"rig": name, "hidden": RIGS[name], "tripped": res.tripped, "samples": res.samples,
                        "findings": [{"effect": f["effect"], "channel": f.get("channel"), "params": f["params"]} for f in findings],
                        **judge(RIGS[name], findings), "wall_s": round(time.perf_counter() - t0, 1)})
            print(json.dumps(out[-1]), file=sys.stderr, flush=True)
    print(json.dumps({"benchmark": "rig_identify", "rigs": out, "all_exact": all(r["exact"] for r in out)}, indent=1))
    return 0 if all(r["exact"] for r in out) else 1


if __name__ == "__main__":
    sys.exit(main())
