"""Sanity checks of the foreign-rig suite (no htm involved).

    python check.py --seed S [--only ID ...] [--quick] [--md FILE] [--json FILE]

Per case: the simulation finished (no NaN), closed loop stable (no saturation chatter, a quiet final
hold), pressures above vacuum, position inside the stroke, reference tracking RMS, and for a case
with effects the visibility of the effect: the same case re-run with every effect (and oov physics)
off, same rig / reference / noise; per measured channel RMS(noise-free reading on - off) divided by
that channel's noise level (sqrt(noise_std^2 + quantum^2/12)); the largest ratio is reported.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import cases as C  # noqa: E402
import rig as R  # noqa: E402

UNIT = {"y": (1e3, "mm"), "v": (1e3, "mm/s"), "p_a": (1e-5, "bar"), "p_b": (1e-5, "bar"), "p_s": (1e-5, "bar"),
        "f": (1.0, "N")}


def noise_level(s):
    return math.sqrt(s.get("noise_std", 0.0) ** 2 + s.get("quant", 0.0) ** 2 / 12.0) or 1e-12


def diagnose_sim(b, sim):
    st = sim["states"]
    d = {"ok": sim["ok"], "secs": round(sim["secs"], 1)}
    if not sim["ok"]:
        return d
    y = st["y"]
    stroke = b["rig"]["stroke_m"]
    d["y_min_frac"] = float(y.min() / stroke)
    d["y_max_frac"] = float(y.max() / stroke)
    pmin = min(st["p_a"].min(), st["p_b"].min(), st["p_va"].min(), st["p_vb"].min())
    d["p_min_bar"] = float(pmin / 1e5)
    d["p_max_bar"] = float(max(st["p_a"].max(), st["p_b"].max(), st["p_va"].max(), st["p_vb"].max()) / 1e5)
    u = sim["u"]
    d["u_sat_frac"] = float(np.mean(np.abs(u) >= 9.999))
    k = int(b["fs"] * 0.8)
    d["u_std_end"] = float(np.std(u[-k:]))   # final hold: a stable loop is quiet there
    if b["control"] == "position":
        e = b["ref"] - y
        d["track_rms"] = float(np.sqrt(np.mean(e ** 2)))
        d["track_unit"] = "mm"
        d["track_rms_disp"] = d["track_rms"] * 1e3
        d["track_rel"] = float(d["track_rms"] / max(np.std(b["ref"]), 1e-12))
        d["y_end_err"] = float(np.mean(np.abs(e[-k:])))
    else:
        e = b["ref"] - sim["f_spec"]
        d["track_rms"] = float(np.sqrt(np.mean(e ** 2)))
        d["track_unit"] = "N"
        d["track_rms_disp"] = d["track_rms"]
        d["track_rel"] = float(d["track_rms"] / max(np.std(b["ref"]), 1e-12))
    # stable: no NaN, little saturation, final hold quiet, position inside the stroke
    d["stable"] = bool(d["u_sat_frac"] < 0.05 and d["u_std_end"] < 0.3 and np.all(np.isfinite(u)))
    d["inside"] = bool(0.0 <= d["y_min_frac"] and d["y_max_frac"] <= 1.0)
    return d


def visibility(b, sim_on, sim_off):
    out = {}
    for ch in R.CHANNELS:
        if ch not in b["sens_true"]:
            continue
        diff = sim_on["true"][ch] - sim_off["true"][ch]
        nl = noise_level(b["sens_true"][ch])
        w = max(1, int(0.5 * b["fs"]))
        m = len(diff) // w
        win = np.sqrt(np.mean(diff[:m * w].reshape(m, w) ** 2, axis=1)) if m else np.array([0.0])
        out[ch] = (float(np.sqrt(np.mean(diff ** 2)) / nl), float(win.max() / nl))
    return out


def check_case(case, seed, converge=False):
    b = C.build_case(case, seed)
    sim = C.simulate_case(b)
    d = diagnose_sim(b, sim)
    d["detune"] = b["design"]["detune_factor"]
    d["step_retries"] = sim["step_retries"]
    if converge and sim["ok"]:
        # integration error: the same case at half the internal step
        fine = C.run_case(b, h_target=C.H_STEP / 2)
        d["step_err_rms"] = {ch: round(float(np.sqrt(np.mean((sim["true"][ch] - fine["true"][ch]) ** 2))
                                             / noise_level(b["sens_true"][ch])), 3)
                             for ch in R.CHANNELS if ch in b["sens_true"]}
        d["step_err_max"] = {ch: round(float(np.max(np.abs(sim["true"][ch] - fine["true"][ch]))
                                             / noise_level(b["sens_true"][ch])), 3)
                             for ch in R.CHANNELS if ch in b["sens_true"]}
    d.update(id=case["id"], cls=case["class"], fs=b["fs"], dur=round(b["duration_s"], 1), form=b["rig"]["form"],
             orient=b["rig"]["orientation"], control=b["control"], xover_hz=round(b["design"]["crossover_hz"], 1),
             effects=[f"{e['effect']}/{e['channel']}" if e["channel"] else e["effect"] for e in b["truth_eff"]]
             + ([f"oov:{case['oov']}"] if case["oov"] else []))
    if (case["effects"] or case["oov"]) and sim["ok"]:
        boff = C.build_case(case, seed, effects_on=False)
        C.use_gains(boff, b)
        soff = C.run_case(boff)
        if soff["ok"]:
            vis = visibility(b, sim, soff)
            d["vis"] = {k: round(v[0], 1) for k, v in vis.items()}
            d["vis_peak"] = {k: round(v[1], 1) for k, v in vis.items()}
            ch = max(vis, key=lambda k: vis[k][0])
            d["vis_max"] = round(vis[ch][0], 1)
            d["vis_ch"] = ch
            chp = max(vis, key=lambda k: vis[k][1])
            d["vis_peak_max"] = round(vis[chp][1], 1)
            d["vis_peak_ch"] = chp
            d["secs_off"] = round(soff["secs"], 1)
    return d


def md_table(rows):
    h = ("| case | class | effects | form | Hz | s | ctrl (xover Hz) | ok/stable | track RMS (rel) | p min..max bar |"
         " y in stroke | effect visible: RMS/noise whole record (ch) / worst 0.5 s (ch) | sim s |")
    lines = [h, "|" + "---|" * 13]
    for d in rows:
        if not d.get("ok"):
            lines.append(f"| {d['id']} | {d['cls']} | {' + '.join(d['effects']) or '-'} | | | | | FAILED | | | | | |")
            continue
        vis = (f"{d['vis_max']:.0f} ({d['vis_ch']}) / {d['vis_peak_max']:.0f} ({d['vis_peak_ch']})"
               if "vis_max" in d else "-")
        lines.append(
            f"| {d['id']} | {d['cls']} | {' + '.join(d['effects']) or '-'} | "
            f"{d['form'].replace('_rod', '')} {d['orient'][0]} | {d['fs']:.0f} | {d['dur']:.0f} | "
            f"{'pos' if d['control'] == 'position' else 'force'} ({d['xover_hz']}) | "
            f"{'yes' if d['stable'] else 'NO'} | {d['track_rms_disp']:.3g} {d['track_unit']} ({d['track_rel']:.3f}) | "
            f"{d['p_min_bar']:.1f}..{d['p_max_bar']:.0f} | "
            f"{d['y_min_frac']:.2f}..{d['y_max_frac']:.2f} | {vis} | {d['secs']:.1f} |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only", nargs="*")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--md")
    ap.add_argument("--json")
    ap.add_argument("--converge", action="store_true", help="also re-run at half the step (max |diff| / noise)")
    a = ap.parse_args(argv)
    cases = [c for c in C.SUITE if c["quick"]] if a.quick else list(C.SUITE)
    if a.only:
        cases = [c for c in C.SUITE if c["id"] in set(a.only)]
    rows = []
    for c in cases:
        d = check_case(c, a.seed, a.converge)
        rows.append(d)
        print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in d.items()}), flush=True)
    tab = md_table(rows)
    print(tab)
    if a.md:
        with open(a.md, "w") as f:
            f.write(tab + "\n")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
