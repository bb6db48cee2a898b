"""Score `htm diagnose` on records with undeclared effects whose truth is known.

A verbatim copy of `shared/benchmarks/diagnose_external/score.py` (the project's shared external
benchmark's scorer); `benchmarks/diagnose_external.py` and the tests use its `judge`.

Usage: python score.py HTM_EXECUTABLE [--data DIR] [--truth DIR] [--reuse] [--timeout S] [case ...]
(defaults: records/ and truth/ beside this file). Runs `htm diagnose RECORD --meta META --out DIR`
on each record, prints one JSON line per case, then a summary line and two verdict lines:
  STRICT : findings == the truth set (effect, and channel for sensor effects), every truth parameter
           within 30 %, `unexplained` false, and the final model's free-run error against the
           noise-free readings not worse than the baseline's; a clean record needs no finding and
           `unexplained` false; an effect outside EFFECTS.md needs `unexplained` true and no finding
           with an EFFECTS.md id.
  LENIENT: the truth effects are the first findings (extra findings after them and `unexplained`
           allowed), parameters within 30 %; a clean record needs no EFFECTS.md finding; an effect
           outside the table needs `unexplained` true.
A finding that names real physics of the rig is neither required nor a false claim: a
`valve_dynamics` lag within 0.3-3x the spool's own 2*zeta/wn (when the truth gives the spool), or a
`sensor_delay` no longer than 3x the lag of the channel's declared anti-alias filter.
Exit 0 only when STRICT passes on every case. `--reuse` re-scores reports already under SCORE_OUT
(default /tmp/htm-score-<data dir name>) without running diagnose again.
"""
import json
import os
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "records")
TRUTH = os.path.join(HERE, "truth")
SCALE = {"y": 1e-3, "v": 1e-2, "p_a": 1e5, "p_b": 1e5, "p_s": 1e5, "f": 100.0}
PARAM_TOL = 0.3
ABS_OK = 0.1  # normalised error (1 mm, 10 mm/s, 1 bar units) a well-identified model reaches


def load_pred(path):
    import csv
    with open(path) as f:
        r = csv.reader(f)
        head = next(r)
        arr = np.array([[float(x) for x in row] for row in r])
    return {h: arr[:, i] for i, h in enumerate(head)}


VOCAB = ("sensor_offset", "sensor_gain", "sensor_delay", "valve_null_bias", "valve_dynamics", "valve_deadband",
         "valve_hysteresis", "supply_pressure_sag", "internal_leakage", "friction_asymmetry",
         "pressure_dependent_friction", "entrained_air", "load_pressure_feedback", "specimen_nonlinearity")
SENSOR = ("sensor_offset", "sensor_gain", "sensor_delay")
MODEL_SPECIFIC = ("specimen_nonlinearity",)   # EFFECTS.md: params are model-specific, not compared
CHANNELS = ("y", "v", "p_a", "p_b", "p_s", "f")
OFFSET_KEY = {"y": "offset_m", "v": "offset_m_s", "p_a": "offset_pa", "p_b": "offset_pa", "p_s": "offset_pa",
              "f": "offset_n"}


def _key(effect, channel):
    """Findings are matched by effect, and by channel for the sensor effects and specimen_nonlinearity."""
    if effect in SENSOR:
        return (effect, channel)
    if effect == "specimen_nonlinearity":
        return (effect, "f")
    return (effect, None)


def truth_spec(tj):
    """(class, [(effect, channel, params)], oov) of a truth file (either layout)."""
    if "effects" in tj:
        effs = [(e["effect"], e.get("channel"), e.get("params") or {}) for e in tj["effects"]]
        return tj.get("class") or ("clean" if not effs else "single"), effs, tj.get("oov")
    eff = tj.get("effect")
    if eff is None:
        return "clean", [], None
    if eff.startswith("oov_"):
        return "oov", [], {"name": eff[4:], **(tj.get("params") or {})}
    return "single", [(eff, tj.get("channel"), tj.get("params") or {})], None


def reference_readings(truth, tj, chans):
    """Noise-free sensor readings of the channels: stored in the truth, or rebuilt from its states."""
    if "measured_channels" in truth:
        return {c: np.asarray(truth[c], dtype=float) for c in chans}
    ref = {c: np.asarray(truth[c], dtype=float).copy() for c in chans if c in truth}
    ts = float(truth["t"][1] - truth["t"][0])
    for e, ch, p in truth_spec(tj)[1]:
        if ch not in ref:
            continue
        if e == "sensor_offset":
            ref[ch] = ref[ch] + float(p.get(OFFSET_KEY[ch], next(iter(p.values()))))
        elif e == "sensor_gain":
            ref[ch] = ref[ch] * float(p["gain"])
        elif e == "sensor_delay":
            n = int(round(float(p["delay_s"]) / ts))
            if n:
                ref[ch] = np.concatenate([np.full(n, ref[ch][0]), ref[ch][:-n]])
    return ref


def norm_err_nan(pred, ref, chans):
    tot = []
    for c in chans:
        d = (np.asarray(pred[c], dtype=float) - ref[c]) / SCALE[c]
        tot.append(float(np.sqrt(np.nanmean(d ** 2))) if np.isfinite(d).any() else float("nan"))
    return float(np.mean(tot)) if tot else float("nan")


def params_within(truth_p, found_p, effect):
    if effect in MODEL_SPECIFIC:
        return True
    for k, v in truth_p.items():
        if k in ("y0", "y1"):
            continue
        if k not in found_p:
            return False
        try:
            f = float(found_p[k])
        except (TypeError, ValueError):
            return False
        if not np.isfinite(f) or abs(f - float(v)) > PARAM_TOL * abs(float(v)):
            return False
    return True


def record_channels(path):
    """Measured channels of a record table (the header of its CSV)."""
    import gzip
    opener = gzip.open if path.endswith(".gz") else open
    with opener(path, "rt") as fh:
        head = [h.strip() for h in fh.readline().split(",")]
    return [c for c in CHANNELS if c in head]


def physically_true(finding, effs, rig_true, sensors):
    """An extra finding that names real physics of the rig rather than a wrong effect: a spool lag
    close to the spool's own first-order equivalent 2*zeta/wn, or a delay on a channel equal to its
    declared anti-alias filter's lag 1/(2*pi*fc). Neither required nor counted as a false claim."""
    e, ch, p = finding.get("effect"), finding.get("channel"), finding.get("params") or {}
    if any(_key(e, ch) == _key(te, tch) for te, tch, _ in effs):
        return False
    try:
        if e == "valve_dynamics" and rig_true and rig_true.get("wn") and rig_true.get("zeta"):
            lag = 2.0 * float(rig_true["zeta"]) / float(rig_true["wn"])
            return 0.3 * lag <= float(p.get("tau_s", -1)) <= 3.0 * lag
        if e == "sensor_delay" and ch in (sensors or {}) and (sensors[ch] or {}).get("lowpass_hz"):
            lag = 1.0 / (2.0 * np.pi * float(sensors[ch]["lowpass_hz"]))
            return 0.0 < float(p.get("delay_s", -1)) <= 3.0 * lag
    except (TypeError, ValueError):
        return False
    return False


def judge(cls, effs, findings, unexplained, eb, ea, rig_true=None, sensors=None):
    """STRICT and LENIENT verdicts (and the pieces they are made of) for one case."""
    findings = [x for x in findings if not physically_true(x, effs, rig_true, sensors)]
    fkeys = [_key(x.get("effect"), x.get("channel")) for x in findings]
    tkeys = [_key(e, ch) for e, ch, _ in effs]
    vocab_found = [k for k in fkeys if k[0] in VOCAB]
    out = {}
    if cls == "oov":
        out["strict"] = unexplained and not vocab_found
        out["lenient"] = unexplained
        out["named"] = None
        out["params_ok"] = None
        out["false_claim"] = bool(vocab_found)
        return out
    if not effs:  # clean (free piston or force-controlled)
        out["strict"] = not findings and not unexplained
        out["lenient"] = not vocab_found
        out["named"] = None
        out["params_ok"] = None
        out["false_claim"] = bool(vocab_found)
        return out
    pok = []
    for (e, ch, p), k in zip(effs, tkeys):
        hit = [x for x in findings if _key(x.get("effect"), x.get("channel")) == k]
        pok.append(bool(hit) and params_within(p, hit[0].get("params") or {}, e))
    params_ok = all(pok)
    exact = sorted(map(str, fkeys)) == sorted(map(str, tkeys))
    first = sorted(map(str, fkeys[:len(tkeys)])) == sorted(map(str, tkeys))
    no_worse = np.isfinite(ea) and np.isfinite(eb) and ea <= eb * 1.02
    out["named"] = exact
    out["named_first"] = first
    out["params_ok"] = params_ok
    out["no_worse"] = bool(no_worse)
    out["strict"] = exact and params_ok and not unexplained and bool(no_worse)
    out["lenient"] = first and params_ok
    out["false_claim"] = any(k not in tkeys for k in fkeys)
    return out


def run_case(htm, name, data, truthdir, outroot, reuse=False, timeout=600):
    out = os.path.join(outroot, name)
    os.makedirs(out, exist_ok=True)
    table = os.path.join(data, name + ".csv.gz")
    if not os.path.exists(table):
        table = os.path.join(data, name + ".csv")
    with open(os.path.join(truthdir, name + ".json")) as f:
        tj = json.load(f)
    cls, effs, oov = truth_spec(tj)
    t0 = time.time()
    if not (reuse and os.path.exists(os.path.join(out, "report.json"))):
        if os.path.exists(os.path.join(out, "report.json")):
            os.remove(os.path.join(out, "report.json"))
        cmd = [htm, "diagnose", table, "--meta", os.path.join(data, name + ".json"), "--out", out]
        try:
            p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return {"name": name, "class": cls, "strict": False, "lenient": False,
                    "why": f"timeout after {timeout:.0f} s", "secs": round(time.time() - t0, 1)}
        if p.returncode != 0:
            return {"name": name, "class": cls, "strict": False, "lenient": False,
                    "why": f"exit {p.returncode}: {p.stderr.strip()[-300:]}", "secs": round(time.time() - t0, 1)}
    dt = time.time() - t0
    with open(os.path.join(out, "report.json")) as f:
        rep = json.load(f)
    truth = dict(np.load(os.path.join(truthdir, name + ".npz")))
    chans = record_channels(table)
    ref = reference_readings(truth, tj, chans)
    pred = load_pred(os.path.join(out, rep.get("predictions", "predictions.csv")))
    missing = [c + s for c in chans for s in ("_before", "_after") if c + s not in pred]
    findings = rep.get("findings", []) or []
    unexplained = bool(rep.get("unexplained", False))
    res = {"name": name, "class": cls, "secs": round(dt, 1),
           "truth": [f"{e}/{ch}" for e, ch, _ in effs] or ([f"oov:{oov.get('name')}"] if oov else []),
           "found": [f"{x.get('effect')}/{x.get('channel')}" for x in findings], "unexplained": unexplained,
           "found_params": [x.get("params") for x in findings]}
    if missing:
        res.update(strict=False, lenient=False, why=f"predictions.csv lacks {missing}")
        return res
    n = min(len(pred["t"]), len(truth["t"]))
    pred = {k: v[:n] for k, v in pred.items()}
    ref = {k: v[:n] for k, v in ref.items()}
    eb = norm_err_nan({c: pred[c + "_before"] for c in chans}, ref, chans)
    ea = norm_err_nan({c: pred[c + "_after"] for c in chans}, ref, chans)
    res.update(err_before=round(eb, 4), err_after=round(ea, 4),
               ratio=round(ea / eb, 3) if eb > 0 and np.isfinite(ea) else None)
    with open(os.path.join(data, name + ".json")) as f:
        sensors = json.load(f).get("sensors") or {}
    allowed = [f"{x.get('effect')}/{x.get('channel')}" for x in findings
               if physically_true(x, effs, tj.get("rig_true"), sensors)]
    if allowed:
        res["allowed_extra"] = allowed
    res.update(judge(cls, effs, findings, unexplained, eb, ea, tj.get("rig_true"), sensors))
    return res


def main():
    import argparse
    ap = argparse.ArgumentParser(description="score htm diagnose against known truth")
    ap.add_argument("htm")
    ap.add_argument("cases", nargs="*")
    ap.add_argument("--data", default=DATA)
    ap.add_argument("--truth", default=TRUTH)
    ap.add_argument("--reuse", action="store_true", help="score existing reports under SCORE_OUT, run only missing ones")
    ap.add_argument("--timeout", type=float, default=600.0)
    a = ap.parse_intermixed_args()
    data, truthdir = os.path.abspath(a.data), os.path.abspath(a.truth)
    names = a.cases or sorted(f[:-5] for f in os.listdir(data) if f.endswith(".json"))
    outroot = os.environ.get("SCORE_OUT", "/tmp/htm-score-" + os.path.basename(data.rstrip("/")))
    results = []
    for nm in names:
        try:
            r = run_case(a.htm, nm, data, truthdir, outroot, a.reuse, a.timeout)
        except Exception as ex:  # noqa: BLE001
            r = {"name": nm, "strict": False, "lenient": False, "why": repr(ex)[:300]}
        results.append(r)
        print(json.dumps(r))
        sys.stdout.flush()
    classes = ("clean", "single", "pair", "force", "oov")

    def line(kind):
        ok = sum(1 for r in results if r.get(kind))
        parts = []
        for c in classes:
            rs = [r for r in results if r.get("class") == c]
            if rs:
                parts.append(f"{c} {sum(1 for r in rs if r.get(kind))}/{len(rs)}")
        return f"{kind.upper()}: {ok}/{len(results)} pass ({', '.join(parts)})"

    ratios = [r["ratio"] for r in results if r.get("ratio") is not None and r.get("class") not in ("clean", "oov")]
    pq = [r for r in results if r.get("params_ok") is not None]
    fc = sum(1 for r in results if r.get("false_claim"))
    med = float(np.median(ratios)) if ratios else float("nan")
    afters = [r["err_after"] for r in results if "err_after" in r]
    print(f"diagnose: error-ratio median {med:.3f} (effect records), error-after median "
          f"{float(np.median(afters)) if afters else float('nan'):.3f}, params-ok {sum(1 for r in pq if r['params_ok'])}/{len(pq)}, "
          f"false-claims {fc}, failed-to-run {sum(1 for r in results if 'why' in r)}")
    print(line("strict"))
    print(line("lenient"))
    sys.exit(0 if results and all(r.get("strict") for r in results) else 1)

if __name__ == "__main__":
    main()
