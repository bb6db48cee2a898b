"""Foreign-rig suite: records from servo-hydraulic rigs whose model form is not htm's, with known truth.

    python cases.py --seed S --out DIR [--only NAME ...] [--quick] [--list]

writes DIR/records/NAME.csv.gz + NAME.json (shared/DATA_FORMAT.md records), DIR/truth/NAME.json +
NAME.npz (the layout shared/benchmarks/diagnose_external/score.py reads) and DIR/suite.json.
Record names are opaque (frNN, order shuffled per seed); suite.json and the truth map them to case
ids. --only accepts record names or case ids. Same seed -> same files.
"""
from __future__ import annotations

import argparse
import gzip
import json
import math
import os
import sys
import time
import zlib

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import rig as R  # noqa: E402

LAW_POS = "u[k] = clip(kp*(y_ref[k]-y[k]) + kff*(y_ref[k+1]-y_ref[k])/Ts, -u_max, u_max)"
LAW_FORCE = "u[k] = clip(kp*(f_ref[k]-f[k]), -u_max, u_max)"
OFFSET_KEY = {"y": "offset_m", "v": "offset_m_s", "p_a": "offset_pa", "p_b": "offset_pa", "p_s": "offset_pa",
              "f": "offset_n"}
SENSOR_EFFECTS = ("sensor_offset", "sensor_gain", "sensor_delay")

# ------------------------------------------------------------------ the suite
# constraint keys: form, orient, fs (list), specimen, control, pab, ps, v (True/False/None=random),
# supply (lo, hi), switch (supply switched between two levels at holds), ref (special reference)


def _c(cid, cls, effects=(), oov=None, quick=False, **kw):
    return {"id": cid, "class": cls, "effects": list(effects), "oov": oov, "quick": quick, "con": kw}


SUITE = [
    # clean: several forms and rates
    _c("clean_double_h", "clean", quick=True, form="double_rod", orient="horizontal", fs=[500], pab=True),
    _c("clean_single_v", "clean", form="single_rod", orient="vertical", fs=[1000], pab=True, ps=True),
    _c("clean_double_v_nop", "clean", form="double_rod", orient="vertical", fs=[250], pab=False, v=True),
    _c("clean_single_spec", "clean", form="single_rod", fs=[2000], specimen=True, pab=True),
    _c("clean_any", "clean", pab=True),
    _c("clean_force", "force", quick=True, specimen=True, control="force", pab=True),
    # one single per EFFECTS.md id
    _c("s_offset_pb", "single", [("sensor_offset", "p_b")], quick=True, pab=True),
    _c("s_gain_pa", "single", [("sensor_gain", "p_a")], pab=True),
    _c("s_delay_y", "single", [("sensor_delay", "y")], pab=True, form="single_rod"),
    _c("s_null_bias", "single", [("valve_null_bias", None)], quick=True, pab=True),
    _c("s_valve_dyn", "single", [("valve_dynamics", None)], quick=True, pab=True),
    _c("s_deadband", "single", [("valve_deadband", None)], pab=True),
    _c("s_hysteresis", "single", [("valve_hysteresis", None)], pab=True),
    _c("s_sag", "single", [("supply_pressure_sag", None)], pab=True),
    _c("s_leakage", "single", [("internal_leakage", None)], pab=True, specimen=True),
    _c("s_fric_asym", "single", [("friction_asymmetry", None)], quick=True, pab=True),
    _c("s_fric_press", "single", [("pressure_dependent_friction", None)], pab=True, ps=True, switch=True),
    _c("s_air", "single", [("entrained_air", None)], pab=True, form="single_rod", specimen=True,
       supply=(70e5, 110e5)),
    _c("s_load_fb", "single", [("load_pressure_feedback", None)], pab=True, specimen=True),
    _c("s_spec_nonlin", "single", [("specimen_nonlinearity", "f")], specimen=True, pab=True, ref="closure"),
    # pairs
    _c("p_offset_pa_dyn", "pair", [("sensor_offset", "p_a"), ("valve_dynamics", None)], quick=True, pab=True),
    _c("p_bias_asym", "pair", [("valve_null_bias", None), ("friction_asymmetry", None)], pab=True),
    _c("p_gain_v_leak", "pair", [("sensor_gain", "v"), ("internal_leakage", None)], pab=True, v=True,
       specimen=True),
    _c("p_sag_delay_pb", "pair", [("supply_pressure_sag", None), ("sensor_delay", "p_b")], pab=True),
    _c("p_deadband_offset_ps", "pair", [("valve_deadband", None), ("sensor_offset", "p_s")], pab=True, ps=True),
    # force-controlled with effects
    _c("f_offset_f", "force", [("sensor_offset", "f")], quick=True, specimen=True, control="force", pab=True),
    _c("f_spec_nonlin", "force", [("specimen_nonlinearity", "f")], specimen=True, control="force", pab=True,
       ref="closure"),
    _c("f_leak", "force", [("internal_leakage", None)], specimen=True, control="force", pab=True),
    # outside the vocabulary
    _c("o_friction_bump", "oov", oov="friction_bump", quick=True, pab=True, ref="bump"),
    _c("o_supply_ripple", "oov", oov="supply_ripple", quick=True, pab=True, ps=True, fs=[1000, 2000]),
    _c("o_end_cushion", "oov", oov="end_cushion", pab=True, ref="cushion", fs=[500, 1000, 2000]),
    _c("o_fixture_resonance", "oov", oov="compliant_fixture", pab=True, fs=[1000, 2000]),
]
CASE_BY_ID = {c["id"]: c for c in SUITE}


# ------------------------------------------------------------------ draws
def _lu(rng, lo, hi):
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def _u(rng, lo, hi):
    return float(rng.uniform(lo, hi))


def _pick(rng, seq):
    return seq[int(rng.integers(len(seq)))]


def draw_rig(rng, con):
    """true rig parameters (SI) under the case's constraints"""
    form = con.get("form") or _pick(rng, ["double_rod", "single_rod"])
    orient = con.get("orient") or _pick(rng, ["vertical", "horizontal"])
    fs = float(_pick(rng, con.get("fs") or [250, 500, 1000, 2000]))
    lo_ps, hi_ps = con.get("supply", (70e5, 280e5))
    specimen = bool(con.get("specimen"))
    for _ in range(500):
        bore = _u(rng, 0.040, 0.125)
        if form == "double_rod":
            rod = bore * _u(rng, 0.45, 0.7)
            aa = ab = math.pi / 4 * (bore ** 2 - rod ** 2)
            ratio = 1.0
        else:
            ratio = _u(rng, 0.4, 0.9)
            aa = math.pi / 4 * bore ** 2
            ab = ratio * aa
            rod = bore * math.sqrt(1 - ratio)
        stroke = _u(rng, 0.05, 0.30)
        ps = _u(rng, lo_ps, hi_ps)
        pt = _u(rng, 0.5e5, 5e5)
        qr = _lu(rng, 10, 150) / 60000.0
        vmax = qr * math.sqrt(0.5 * (ps - pt) / R.RATED_EDGE_DP) / aa
        if not 0.05 <= vmax <= 1.0:
            continue
        m = _lu(rng, max(5.0, 3000 * aa), 300.0)
        if orient == "vertical" and m * R.G > 0.15 * min(aa, ab) * ps:
            continue
        beta0 = _u(rng, 1.3e9, 1.8e9)
        kb = _u(rng, 5.0, 9.0)
        v0a = aa * _u(rng, 0.004, 0.02) + _u(rng, 2e-6, 1e-5)
        v0b = ab * _u(rng, 0.004, 0.02) + _u(rng, 2e-6, 1e-5)
        # hoses sized for 3-6 m/s at rated flow
        dh = math.sqrt(4 * qr / (math.pi * _u(rng, 3.0, 6.0)))
        rho = _u(rng, 850.0, 890.0)
        nu = _u(rng, 25e-6, 50e-6)
        mu = rho * nu
        ah = math.pi / 4 * dh ** 2
        lines = {}
        for side in ("a", "b"):
            ln = _u(rng, 0.2, 1.5)
            lines[side] = dict(vol=ah * ln + _u(rng, 2e-6, 8e-6), rlam=128 * mu * ln / (math.pi * dh ** 4),
                               rturb=_u(rng, 2.0, 6.0) * rho / (2 * ah ** 2), len=ln)
        beta_mid = beta0 + kb * ps / 2
        vta = v0a + lines["a"]["vol"] + aa * stroke / 2
        vtb = v0b + lines["b"]["vol"] + ab * stroke / 2
        kh = beta_mid * (aa ** 2 / vta + ab ** 2 / vtb)
        wh = math.sqrt(kh / m)
        if wh < 2 * math.pi * 30:
            continue
        break
    else:
        raise RuntimeError("could not draw a rig under the constraints")
    fc = _u(rng, 0.003, 0.012) * aa * ps + _u(rng, 20, 60)
    sig0 = fc / _u(rng, 5e-6, 30e-6)
    rig = {
        "form": form, "orientation": orient, "sample_rate_hz": fs,
        "bore_m": bore, "rod_m": rod, "area_a_m2": aa, "area_b_m2": ab, "area_ratio": ratio, "stroke_m": stroke,
        "supply_pressure_pa": ps, "tank_pressure_pa": pt,
        "valve_rated_flow_m3_s": qr, "valve_rated_dp_pa": 7e6, "valve_max_command_v": R.U_RATED,
        "polarity": float(_pick(rng, [1.0, -1.0])),
        "wn": 2 * math.pi * _u(rng, 80, 200), "zeta": _u(rng, 0.5, 0.9), "spool_limit": 1.1,
        "underlap": _u(rng, 0.002, 0.008), "lap_smoothing": _u(rng, 0.002, 0.004),
        "spool_stroke_m": _u(rng, 0.25e-3, 0.5e-3), "re_crit": _u(rng, 20, 50), "nu_m2_s": nu,
        "oil_density_kg_m3": rho, "radial_clearance_m": _u(rng, 1e-6, 3e-6), "laminar_dp_min_pa": _u(rng, 2e4, 5e4),
        "dead_volume_a_m3": v0a, "dead_volume_b_m3": v0b,
        "line_volume_a_m3": lines["a"]["vol"], "line_volume_b_m3": lines["b"]["vol"],
        "line_length_a_m": lines["a"]["len"], "line_length_b_m": lines["b"]["len"], "line_bore_m": dh,
        "line_r_lam_a": lines["a"]["rlam"], "line_r_turb_a": lines["a"]["rturb"],
        "line_r_lam_b": lines["b"]["rlam"], "line_r_turb_b": lines["b"]["rturb"],
        "beta0_pa": beta0, "beta_dp": kb, "air_fraction_base": 2e-5, "vapour_pressure_pa": 2e3,
        "mass_kg": m,
        "coulomb_n": fc, "static_excess_n": fc * _u(rng, 0.2, 0.8), "stribeck_velocity_m_s": _u(rng, 2e-3, 1e-2),
        "viscous_n_s_m": fc * _u(rng, 0.3, 1.5) / 0.1, "bristle_stiffness_n_m": sig0,
        "bristle_damping_n_s_m": _u(rng, 0.3, 1.0) * 2 * math.sqrt(sig0 * m),
        "v_max_no_load_m_s": vmax, "hydraulic_wn_mid_rad_s": wh, "beta_at_half_supply_pa": beta_mid,
    }
    rig["underlap_v"] = rig["underlap"] * R.U_RATED
    if specimen:
        flim = 0.5 * min(aa, ab) * ps
        dy = _u(rng, 1.5e-3, min(10e-3, 0.25 * stroke))
        k = flim / dy
        rig["specimen_true"] = {"stiffness_n_m": k, "zero_force_position_m": stroke / 2 + _u(rng, -0.1, 0.1) * stroke,
                                "force_limit_n": flim}
        rig["hydraulic_wn_mid_rad_s"] = math.sqrt((kh + k) / m)
    return rig


def draw_sensors(rng, rig, con, control):
    """true sensor physics per measured channel + what the metadata declares"""
    fs = rig["sample_rate_hz"]
    true, decl = {}, {}

    def flt():
        return round(_u(rng, max(50.0, 0.08 * fs), min(500.0, 0.4 * fs)), 0)

    res = _pick(rng, [0.5e-6, 1e-6, 2e-6, 5e-6])
    ny = _u(rng, 0.0, 1.5) * res
    true["y"] = {"quant": res, "noise_std": ny}
    decl["y"] = {"resolution_m": res}
    if rng.random() < 0.5:
        decl["y"]["noise_std"] = ny
    mv = con.get("v")
    if mv is None:
        mv = rng.random() < 0.3
    if mv:
        q = _pick(rng, [1e-5, 5e-5, 1e-4])
        nv = _u(rng, 1e-4, 5e-4)
        true["v"] = {"quant": q, "noise_std": nv}
        decl["v"] = {"resolution_m_s": q}
        if rng.random() < 0.6:
            true["v"]["lowpass_hz"] = decl["v"]["lowpass_hz"] = flt()
        if rng.random() < 0.5:
            decl["v"]["noise_std"] = nv
    ps = rig["supply_pressure_pa"]
    chans = []
    pab = con.get("pab")
    if pab is None:
        pab = rng.random() < 0.85
    if pab:
        chans += ["p_a", "p_b"]
    mps = con.get("ps")
    if mps is None:
        mps = rng.random() < 0.4
    if mps:
        chans.append("p_s")
    rng_hi = min(r for r in (250e5, 400e5, 600e5, 1000e5) if r >= 1.25 * ps)
    for ch in chans:
        npa = _u(rng, 1e3, 8e3)
        t = {"noise_std": npa, "lo": 0.0, "hi": rng_hi, "lowpass_hz": flt()}
        d = {"range_pa": [0.0, rng_hi], "lowpass_hz": t["lowpass_hz"]}
        if rng.random() < 0.5:
            bits = int(_pick(rng, [12, 14, 16]))
            t["quant"] = rng_hi / 2 ** bits
            d["bits"] = bits
        else:
            t["quant"] = float(_pick(rng, [1e3, 2e3, 5e3, 1e4]))
            d["resolution_pa"] = t["quant"]
        if rng.random() < 0.5:
            d["noise_std"] = npa
        true[ch], decl[ch] = t, d
    if rig.get("specimen_true"):
        flim = rig["specimen_true"]["force_limit_n"]
        rn = float(10 ** math.ceil(math.log10(2.0 * flim)))
        if rn > 4 * flim:
            rn /= 2
        nf = _u(rng, 2e-4, 1e-3) * flim
        t = {"noise_std": nf, "lo": -rn, "hi": rn, "lowpass_hz": flt()}
        d = {"range_n": [-rn, rn], "lowpass_hz": t["lowpass_hz"]}
        if rng.random() < 0.5:
            bits = int(_pick(rng, [14, 16]))
            t["quant"] = 2 * rn / 2 ** bits
            d["bits"] = bits
        else:
            t["quant"] = float(10 ** round(math.log10(flim * 1e-4)))
            d["resolution_n"] = t["quant"]
        if rng.random() < 0.5:
            d["noise_std"] = nf
        true["f"], decl["f"] = t, d
    return true, decl


def draw_effect(rng, eid, ch, rig, sens):
    """(truth params, physics entries for rig.simulate). Sizes: clearly present, realistic."""
    ps, qr, fs = rig["supply_pressure_pa"], rig["valve_rated_flow_m3_s"], rig["sample_rate_hz"]
    sgn = float(_pick(rng, [1.0, -1.0]))
    fc = rig["coulomb_n"]
    if eid == "sensor_offset":
        if ch in ("p_a", "p_b", "p_s"):
            val = sgn * _u(rng, 2e5, 6e5)
        elif ch == "y":
            val = sgn * _u(rng, 0.1e-3, 0.5e-3)
        elif ch == "v":
            val = sgn * _u(rng, 2e-3, 8e-3)
        else:
            val = sgn * _u(rng, 0.01, 0.03) * rig["specimen_true"]["force_limit_n"]
        return {OFFSET_KEY[ch]: val}, {}
    if eid == "sensor_gain":
        return {"gain": 1.0 + sgn * _u(rng, 0.03, 0.06)}, {}
    if eid == "sensor_delay":
        d = max(2, int(round(_u(rng, 3e-3, 10e-3) * fs)))
        return {"delay_s": d / fs}, {}
    if eid == "valve_null_bias":
        p = {"bias_v": sgn * _u(rng, 0.05, 0.2)}
        return p, p
    if eid == "valve_dynamics":
        p = {"tau_s": _u(rng, 0.005, 0.025)}
        return p, p
    if eid == "valve_deadband":
        p = {"half_width_v": _u(rng, 0.08, 0.2)}
        return p, p
    if eid == "valve_hysteresis":
        p = {"half_width_v": _u(rng, 0.05, 0.15)}
        return p, p
    if eid == "supply_pressure_sag":
        qin = qr * math.sqrt(0.5 * ps / R.RATED_EDGE_DP)
        r = _u(rng, 0.08, 0.2) * ps / qin
        return {"resistance_pa_s_per_m3": r}, {"resistance_pa_s_per_m3": r, "time_constant_s": _u(rng, 0.005, 0.02)}
    if eid == "internal_leakage":
        p = {"coeff_m3_per_s_pa": _u(rng, 0.02, 0.05) * qr / ps}
        return p, p
    if eid == "friction_asymmetry":
        d = _u(rng, 0.25, 0.45)
        hi, lo = fc * (1 + d), fc * (1 - d)
        p = {"coulomb_pos_n": hi, "coulomb_neg_n": lo} if sgn > 0 else {"coulomb_pos_n": lo, "coulomb_neg_n": hi}
        return p, p
    if eid == "pressure_dependent_friction":
        p = {"coeff_n_per_pa": _u(rng, 0.5, 1.0) * fc / ps}
        return p, p
    if eid == "entrained_air":
        p = {"air_fraction": _u(rng, 0.005, 0.02)}
        return p, p
    if eid == "load_pressure_feedback":
        return {}, {}
    if eid == "specimen_nonlinearity":
        sp = rig["specimen_true"]
        k, flim = sp["stiffness_n_m"], sp["force_limit_n"]
        fcl = _u(rng, 0.1, 0.3) * flim
        ycl = sp["zero_force_position_m"] + fcl / k
        r = _u(rng, 1.3, 2.0)
        w = _u(rng, 0.05, 0.15) * fcl / k
        p = {"closure_position_m": ycl, "closure_force_n": fcl, "stiffness_ratio_closed": r,
             "transition_width_m": w,
             "model": "crack closure: f = k(y-y0) above the closure position, slope r*k below, "
                      "softplus blend of width w; f(y0) = 0"}
        return p, p
    raise KeyError(eid)


def draw_oov(rng, name, rig, sens):
    stroke, fs = rig["stroke_m"], rig["sample_rate_hz"]
    if name == "friction_bump":
        wdt = _u(rng, 0.1, 0.25) * stroke
        c = _u(rng, 0.3, 0.7) * stroke
        return {"extra_n": _u(rng, 0.6, 1.5) * rig["coulomb_n"], "y1": c - wdt / 2, "y2": c + wdt / 2,
                "edge_m": _u(rng, 1e-3, 3e-3)}
    if name == "supply_ripple":
        a = _u(rng, 0.015, 0.04)
        return {"rel_amplitude": a, "rel_amplitude_2nd": a * _u(rng, 0.3, 0.6),
                "pump_frequency_hz": _u(rng, 80.0, 0.4 * fs), "phase_2nd": _u(rng, 0, 2 * math.pi)}
    if name == "end_cushion":
        # needle sized for a cushion pressure dp_c at the piston speed v_c
        vc, dpc = _u(rng, 0.04, 0.12), _u(rng, 40e5, 100e5)
        qc = rig["area_b_m2"] * vc
        return {"length_m": min(_u(rng, 0.010, 0.025), 0.15 * stroke),
                "needle_resistance_pa_s2_per_m6": dpc / qc ** 2, "design_speed_m_s": vc, "design_dp_pa": dpc,
                "end": "full extension (chamber B outflow through the cushion needle, check valve for inflow)"}
    if name == "compliant_fixture":
        m2 = _u(rng, 0.3, 1.0) * rig["mass_kg"]
        fr = _u(rng, 20.0, min(60.0, 0.2 * fs))
        k2 = m2 * (2 * math.pi * fr) ** 2
        z = _u(rng, 0.03, 0.08)
        return {"mass_kg": m2, "stiffness_n_m": k2, "damping_n_s_m": 2 * z * math.sqrt(k2 * m2),
                "frequency_hz": fr, "damping_ratio": z}
    raise KeyError(name)


# ------------------------------------------------------------------ controller design
def valve_gains(rig):
    aa, ab = rig["area_a_m2"], rig["area_b_m2"]
    kq = rig["valve_rated_flow_m3_s"] * math.sqrt(0.5 * (rig["supply_pressure_pa"] - rig["tank_pressure_pa"])
                                                 / R.RATED_EDGE_DP) / R.U_RATED
    return kq, kq / (0.5 * (aa + ab))


def loop_response(rig, phys, sens_true, control, w, zeta_h=0.05):
    """open-loop frequency response per unit controller gain (|kp| = 1) of a linearised rig: spool
    (2nd order) [+ valve lag] -> flow gain -> cylinder with oil stiffness, mass, specimen (damping
    zeta_h assumed low) -> sensor filter, delay, sample-and-hold and one-sample computation delay."""
    kq, _ = valve_gains(rig)
    fs = rig["sample_rate_hz"]
    ts = 1.0 / fs
    m = rig["mass_kg"] + phys.get("compliant_fixture", {}).get("mass_kg", 0.0)
    aa, ab, stroke = rig["area_a_m2"], rig["area_b_m2"], rig["stroke_m"]
    beta = rig["beta_at_half_supply_pa"]
    kh = beta * (aa ** 2 / (rig["dead_volume_a_m3"] + rig["line_volume_a_m3"] + aa * stroke / 2)
                 + ab ** 2 / (rig["dead_volume_b_m3"] + rig["line_volume_b_m3"] + ab * stroke / 2))
    ks = rig["specimen_true"]["stiffness_n_m"] if rig.get("specimen_true") else 0.0
    a_eff = 0.5 * (aa + ab)
    s = 1j * w
    wn, z = rig["wn"], rig["zeta"]
    g = kq * wn ** 2 / (s ** 2 + 2 * z * wn * s + wn ** 2)
    tau = phys.get("valve_dynamics", {}).get("tau_s", 0.0)
    if tau:
        g = g / (1 + tau * s)
    b = 2 * zeta_h * math.sqrt((kh + ks) * m)
    fx = phys.get("compliant_fixture")
    if fx:
        # piston + a fixture mass on a spring-damper: dynamic mass seen by the piston
        m1, m2, k2, c2 = rig["mass_kg"], fx["mass_kg"], fx["stiffness_n_m"], fx["damping_n_s_m"]
        ms2 = m1 * s ** 2 + m2 * s ** 2 * (k2 + c2 * s) / (m2 * s ** 2 + c2 * s + k2)
    else:
        ms2 = m * s ** 2
    g = g * kh / (a_eff * s * (ms2 + b * s + ks + kh))
    ch = "y" if control == "position" else "f"
    if control != "position":
        g = g * ks
    sn = sens_true.get(ch, {})
    if sn.get("lowpass_hz"):
        g = g / (1 + s / (2 * math.pi * sn["lowpass_hz"]))
    x = w * ts / 2
    zoh = np.sinc(x / math.pi) * np.exp(-1j * x)
    return g * zoh * np.exp(-s * (sn.get("delay_s", 0.0) + ts)), kh, ks, m


def gain_limits(L1, w, gm=3.0, pm_deg=45.0):
    """largest |kp| with gain margin >= gm and phase margin >= pm for the response L1 (|kp| = 1)"""
    mag = np.abs(L1)
    ph = np.unwrap(np.angle(L1))
    kmax = np.inf
    for kk in range(1, 6):
        d = ph + (2 * kk - 1) * math.pi
        idx = np.where(np.sign(d[:-1]) != np.sign(d[1:]))[0]
        for i in idx:
            kmax = min(kmax, 1.0 / (gm * mag[i]))
    return kmax, ph


def crossover(kp, L1, w, ph):
    above = np.where(kp * np.abs(L1) >= 1.0)[0]
    if len(above) == 0:
        return w[0], math.pi
    i = above[-1]
    return w[i], math.pi + ph[i]


def design_controller(rng, rig, phys, sens_true, control):
    """gains a rig engineer would set on this (true) rig: a target bandwidth, lowered until the
    linearised loop keeps a gain margin >= 3 and a phase margin >= 45 deg"""
    kq, kvel = valve_gains(rig)
    pol = rig["polarity"]
    fs = rig["sample_rate_hz"]
    w = np.logspace(math.log10(0.5), math.log10(5 * math.pi * fs), 4000)
    L1, kh, ks, m = loop_response(rig, phys, sens_true, control, w)
    wr = math.sqrt((kh + ks) / m)
    fixture = phys.get("compliant_fixture")
    if control == "position":
        target = 2 * math.pi * _u(rng, 3.0, 15.0)
        if fixture:
            target = min(target, 0.25 * 2 * math.pi * fixture["frequency_hz"])
        k = target / (kvel * kh / (kh + ks))
    else:
        target = 2 * math.pi * _u(rng, 2.0, 8.0)
        k = target / (kvel / (1 / ks + 1 / kh))
    kmax, ph = gain_limits(L1, w)
    k = min(k, kmax)
    for _ in range(60):
        wc, pm = crossover(k, L1, w, ph)
        if pm >= math.radians(45.0):
            break
        k *= 0.9
    info = {"crossover_hz": wc / 2 / math.pi, "target_hz": target / 2 / math.pi,
            "phase_margin_deg": math.degrees(pm), "gain_margin": (kmax * 3.0 / k) if np.isfinite(kmax) else None,
            "resonance_hz": wr / 2 / math.pi, "design_zeta_h": 0.05}
    if control == "position":
        kff = pol * _u(rng, 0.85, 1.05) / kvel
        return {"type": "position_pff", "kp_v_per_m": pol * k, "kff_v_per_m_s": kff, "u_max_v": 10.0,
                "law": LAW_POS}, info
    return {"type": "force_p", "kp_v_per_n": pol * k, "u_max_v": 10.0, "law": LAW_FORCE}, info


# ------------------------------------------------------------------ references
class _Ref:
    def __init__(self, ts, start):
        self.ts, self.x, self.parts = ts, start, []

    def hold(self, sec):
        self.parts.append(np.full(max(1, int(round(sec / self.ts))), self.x))

    def move(self, to, speed):
        n = max(1, int(math.ceil(abs(to - self.x) / max(speed, 1e-12) / self.ts)))
        self.parts.append(self.x + (to - self.x) * np.arange(1, n + 1) / n)
        self.x = to

    def sine(self, amp, f, cycles):
        t = np.arange(int(round(cycles / f / self.ts))) * self.ts
        self.parts.append(self.x + amp * np.sin(2 * math.pi * f * t))

    def steps(self, amp, dwell, n, rng, rise):
        """steps with a short smooth rise (a function generator's edge, not a jump)"""
        c = self.x
        nr = max(3, int(round(rise / self.ts)))
        sm = np.arange(1, nr + 1) / nr
        sm = sm * sm * (3 - 2 * sm)
        lvls = [c + amp * (1 if i % 2 == 0 else -1) * _u(rng, 0.6, 1.0) for i in range(n)] + [c]
        prev = c
        for lvl in lvls:
            self.parts.append(prev + (lvl - prev) * sm)
            self.parts.append(np.full(max(1, int(round(dwell / self.ts)) - nr), lvl))
            prev = lvl
        self.x = c

    def n(self):
        return sum(len(p) for p in self.parts)

    def array(self):
        return np.concatenate(self.parts)


def position_reference(rng, ts, dur, lo, hi, vmax, f_bw, kp, start, special=None, extra=None):
    """holds, ramps at several speeds both ways, sines at several frequencies, steps; inside [lo, hi]"""
    rg = hi - lo
    r = _Ref(ts, start)
    r.hold(_u(rng, 1.0, 2.0))
    vmin, vtop = max(0.02 * vmax, 5e-4), min(0.5 * vmax, rg / 0.3)
    kinds = ["ramp", "ramp", "ramp", "sine", "sine", "steps", "ramp", "sine", "hold"]
    if special == "cushion":
        kinds += ["cushion", "cushion", "cushion"]
    if special == "bump":
        kinds += ["bump", "bump", "bump"]
    i = 0
    speeds = list(np.exp(np.linspace(math.log(vmin), math.log(max(vtop, vmin * 1.5)), 6)))
    rng.shuffle(speeds)
    while r.n() * ts < dur - 1.5:
        first = ["ramp", "sine", "ramp"] if special not in ("cushion", "bump") else \
            ["ramp", special, "sine", special, "steps", special, "ramp", special]
        kind = kinds[int(rng.integers(len(kinds)))] if i >= len(first) else first[i]
        i += 1
        if kind == "ramp":
            sp = speeds.pop() if speeds else _lu(rng, vmin, max(vtop, vmin * 1.5))
            a = _u(rng, lo, hi)
            b = _u(rng, lo, hi)
            r.move(a, sp)
            r.hold(_u(rng, 0.2, 1.0))
            r.move(b, sp * _u(rng, 0.7, 1.3))
            r.hold(_u(rng, 0.2, 1.0))
        elif kind == "sine":
            f = _lu(rng, 0.2, max(0.3, min(10.0, f_bw / 1.5)))
            c = _u(rng, lo + 0.3 * rg, hi - 0.3 * rg)
            amp = min(_u(rng, 0.1, 0.3) * rg, 0.4 * vmax / (2 * math.pi * f))
            r.move(c, 0.5 * (vmin + vtop))
            r.sine(amp, f, max(2, min(int(6 * f) + 2, 12)))
            r.hold(_u(rng, 0.2, 0.6))
        elif kind == "steps":
            amp = min(_u(rng, 0.03, 0.1) * rg, 4.0 / abs(kp))
            c = _u(rng, lo + amp, hi - amp)
            r.move(c, 0.5 * (vmin + vtop))
            r.hold(0.3)
            r.steps(amp, _u(rng, 0.4, 1.2), int(rng.integers(2, 5)), rng, _u(rng, 0.01, 0.03))
        elif kind == "hold":
            r.hold(_u(rng, 0.5, 2.0))
        elif kind == "cushion":
            end = extra["end"]
            r.move(hi - _u(rng, 0.05, 0.1) * rg, 0.5 * (vmin + vtop))
            r.move(end, _lu(rng, 0.5 * vtop, vtop))
            r.hold(_u(rng, 0.5, 1.0))
            r.move(_u(rng, lo, end - 0.3 * rg), _lu(rng, vmin, vtop))
            r.hold(0.3)
        elif kind == "bump":
            y1, y2 = extra["y1"], extra["y2"]
            a, b = max(lo, y1 - _u(rng, 0.02, 0.06)), min(hi, y2 + _u(rng, 0.02, 0.06))
            sp = _lu(rng, vmin, vtop)
            r.move(a, 0.5 * (vmin + vtop))
            r.hold(0.3)
            r.move(b, sp)
            r.hold(0.3)
            r.move(a, sp)
            r.hold(0.3)
    y = _end_with_hold(r.array(), int(round(dur / ts)), int(round(1.5 / ts)))
    return np.clip(y, lo, max(hi, (extra or {}).get("end", hi)))


def _end_with_hold(x, n, nhold):
    """cut the programme to n samples, the last nhold of which hold the level reached"""
    body = x[:n - nhold]
    return np.concatenate([body, np.full(n - len(body), body[-1])])


def force_reference(rng, ts, dur, flim, rate_max, f_bw, special=None, extra=None):
    """force sines, ramps and holds around a mean"""
    if special == "closure":
        mean = _u(rng, 0.1, 0.3) * flim
    else:
        mean = _u(rng, -0.2, 0.3) * flim
    lo, hi = -0.8 * flim, 0.8 * flim
    r = _Ref(ts, mean)
    r.hold(_u(rng, 1.0, 2.0))
    rmin, rtop = 0.05 * flim, min(3.0 * flim, rate_max)
    i = 0
    while r.n() * ts < dur - 1.5:
        kind = _pick(rng, ["sine", "sine", "ramp", "ramp", "hold", "steps"]) if i >= 2 else ["sine", "ramp"][i]
        i += 1
        if kind == "sine":
            f = _lu(rng, 0.2, max(0.3, min(10.0, f_bw / 3)))
            amp = min(_u(rng, 0.15, 0.6) * flim, hi - mean, mean - lo, 0.5 * rate_max / (2 * math.pi * f))
            if special == "closure":
                amp = max(amp, min(0.5 * flim, hi - mean, mean - lo))
            r.move(mean, rtop * 0.5)
            r.sine(amp, f, max(3, min(int(6 * f) + 3, 15)))
            r.hold(_u(rng, 0.3, 1.0))
        elif kind == "ramp":
            a, b = _u(rng, lo, hi), _u(rng, lo, hi)
            sp = _lu(rng, rmin, max(rtop, rmin * 1.5))
            r.move(a, sp)
            r.hold(_u(rng, 0.3, 1.0))
            r.move(b, sp)
            r.hold(_u(rng, 0.3, 1.0))
        elif kind == "steps":
            amp = _u(rng, 0.03, 0.1) * flim
            r.move(mean, rtop * 0.5)
            r.steps(amp, _u(rng, 0.4, 1.0), int(rng.integers(2, 4)), rng, _u(rng, 0.01, 0.03))
        else:
            r.move(_u(rng, lo, hi), _lu(rng, rmin, rtop))
            r.hold(_u(rng, 0.5, 2.0))
    f = _end_with_hold(r.array(), int(round(dur / ts)), int(round(1.5 / ts)))
    return np.clip(f, lo, hi)


# ------------------------------------------------------------------ one case
def _round_sig(x, n=3):
    if x == 0:
        return 0.0
    return float(round(x, -int(math.floor(math.log10(abs(x)))) + n - 1))


def case_rng(seed, cid):
    return np.random.default_rng(np.random.SeedSequence([int(seed), zlib.crc32(cid.encode())]))


def build_case(case, seed, effects_on=True):
    """draw everything for one case; returns a dict with rig, sensors, controller, references, truth"""
    rng = case_rng(seed, case["id"])
    con = case["con"]
    control = con.get("control", "position")
    rig = draw_rig(rng, con)
    fs = rig["sample_rate_hz"]
    ts = 1.0 / fs
    sens_true, sens_decl = draw_sensors(rng, rig, con, control)
    # effects (drawn always, so that effect-off runs share every other draw)
    truth_eff, phys = [], {}
    for eid, ch in case["effects"]:
        tp, ph = draw_effect(rng, eid, ch, rig, sens_true)
        truth_eff.append({"effect": eid, "channel": ch, "params": tp})
        if eid in SENSOR_EFFECTS:
            continue
        phys[eid] = ph
    oov = None
    if case["oov"]:
        oov = {"name": case["oov"], **draw_oov(rng, case["oov"], rig, sens_true)}
        phys[case["oov"]] = oov
    if "load_pressure_feedback" not in phys:
        rig["pressure_compensated_valve"] = False
    dur = _u(rng, 20.0, 60.0)
    sens_eff = _sensor_effects_true(truth_eff, {ch: dict(v) for ch, v in sens_true.items()})
    ctrl, design = design_controller(rng, rig, phys, sens_eff, control)
    kq, kvel = valve_gains(rig)
    stroke = rig["stroke_m"]
    sup_level = rig["supply_pressure_pa"]
    sp = rig.get("specimen_true")
    if control == "position":
        lo, hi = 0.1 * stroke, 0.9 * stroke
        start = 0.5 * stroke
        if sp:
            dyl = 0.8 * sp["force_limit_n"] / sp["stiffness_n_m"]
            if case["con"].get("ref") == "closure":
                lo = max(lo, sp["zero_force_position_m"] - 0.6 * dyl)
            else:
                lo = max(lo, sp["zero_force_position_m"] - dyl)
            hi = min(hi, sp["zero_force_position_m"] + dyl)
            start = sp["zero_force_position_m"]
        extra = None
        special = con.get("ref")
        if special == "cushion":
            L = oov["length_m"]
            extra = {"end": stroke - 0.25 * L}
            hi = stroke - 1.2 * L
            start = 0.5 * (lo + hi)
        if special == "bump":
            extra = oov
        vmax = kvel * R.U_RATED
        if sp:
            vmax = min(vmax, 4 * (hi - lo))
        ref = position_reference(rng, ts, dur, lo, hi, vmax, design["crossover_hz"], ctrl["kp_v_per_m"], start,
                                 special, extra)
        ctrl_sim = dict(ctrl)
    else:
        flim = sp["force_limit_n"]
        ref = force_reference(rng, ts, dur, flim, 0.4 * kvel * R.U_RATED * sp["stiffness_n_m"],
                              design["crossover_hz"], con.get("ref"))
        ctrl_sim = dict(ctrl)
        ctrl_sim["y_init"] = sp["zero_force_position_m"] + ref[0] / sp["stiffness_n_m"]
    n = len(ref)
    sup = np.full(n, sup_level)
    if con.get("switch"):
        # supply switched between two levels during holds of the reference
        lo_lvl = sup_level * _u(rng, 0.45, 0.6)
        sup, ref = _switch_supply(rng, ref, sup_level, lo_lvl, ts)
        rig["supply_low_pa"] = lo_lvl
        n = len(ref)
    # sensor effects
    sens_sim = {ch: dict(v) for ch, v in sens_true.items()}
    if effects_on:
        _sensor_effects_true(truth_eff, sens_sim)
        phys_sim = phys
    else:
        phys_sim = {}
    rig_sim = rig
    if "load_pressure_feedback" in phys and not effects_on:
        rig_sim = dict(rig, pressure_compensated_valve=True)
    if "compliant_fixture" in phys and not effects_on:
        # the same fixture, rigidly attached
        rig_sim = dict(rig, mass_kg=rig["mass_kg"] + phys["compliant_fixture"]["mass_kg"])
    noise_seed = int(np.random.SeedSequence([int(seed), zlib.crc32(case["id"].encode()), 7]).generate_state(1)[0])
    return dict(case=case, rig=rig, rig_sim=rig_sim, phys=phys, phys_sim=phys_sim, sens_true=sens_true,
                sens_sim=sens_sim, sens_decl=sens_decl, ctrl=ctrl, ctrl_sim=ctrl_sim, design=design, ref=ref,
                sup=sup, control=control, truth_eff=truth_eff, oov=oov, fs=fs, noise_seed=noise_seed,
                meta_rng=rng.integers(1 << 31), duration_s=n * ts)


def _sensor_effects_true(truth_eff, sens):
    """apply sensor-effect truth to a sensors dict (in place); returns it (used for loop design too)"""
    for e in truth_eff:
        ch, p = e["channel"], e["params"]
        if e["effect"] not in SENSOR_EFFECTS:
            continue
        s = sens.setdefault(ch, {})
        if e["effect"] == "sensor_offset":
            s["offset"] = p[OFFSET_KEY[ch]]
        elif e["effect"] == "sensor_gain":
            s["gain"] = p["gain"]
        elif e["effect"] == "sensor_delay":
            s["delay_s"] = p["delay_s"]
    return sens


def _switch_supply(rng, ref, hi_lvl, lo_lvl, ts):
    """insert 2.5 s holds at 1/3 and 2/3 of the record; the supply ramps (0.3 s) within them"""
    n = len(ref)
    cuts = [int(n / 3), int(2 * n / 3)]
    hold = int(round(2.5 / ts))
    parts, sparts = [], []
    prev = 0
    levels = [hi_lvl, lo_lvl, hi_lvl]
    for i, c in enumerate(cuts):
        parts.append(ref[prev:c])
        sparts.append(np.full(c - prev, levels[i]))
        parts.append(np.full(hold, ref[c - 1]))
        ramp = np.full(hold, levels[i + 1])
        n1 = int(round(1.0 / ts))
        n2 = int(round(0.3 / ts))
        ramp[:n1] = levels[i]
        ramp[n1:n1 + n2] = levels[i] + (levels[i + 1] - levels[i]) * np.arange(1, n2 + 1) / n2
        sparts.append(ramp)
        prev = c
    parts.append(ref[prev:])
    sparts.append(np.full(n - prev, levels[-1]))
    return np.concatenate(sparts), np.concatenate(parts)


def sane(b, sim):
    """the closed loop behaved: finished, pressures above vacuum, inside the stroke, little
    saturation, a quiet final hold"""
    if not sim["ok"]:
        return False
    st = sim["states"]
    stroke = b["rig"]["stroke_m"]
    pmin = min(float(st[k].min()) for k in ("p_a", "p_b", "p_va", "p_vb"))
    u = sim["u"]
    return bool(pmin > -1e4 and st["y"].min() > -1e-3 and st["y"].max() < stroke + 1e-3
                and np.mean(np.abs(u) >= 9.999) < 0.05 and np.std(u[-int(0.8 * b["fs"]):]) < 0.3)


H_STEP = 12.5e-6   # internal step target [s]; see README (convergence)


def simulate_case(b, h_target=None):
    """run the case; if the loop misbehaves, detune it as an engineer would (gain x 0.6, at most 4
    times) and record the factor in the design"""
    key = "kp_v_per_m" if b["control"] == "position" else "kp_v_per_n"
    fac = 1.0
    for _ in range(5):
        sim = run_case(b, h_target)
        if sane(b, sim):
            break
        fac *= 0.6
        for c in (b["ctrl"], b["ctrl_sim"]):
            c[key] *= 0.6
    b["design"]["detune_factor"] = fac
    sim["sane"] = sane(b, sim)
    return sim


def use_gains(b, ref_b):
    """give b the (possibly detuned) controller of ref_b (for effect-off comparisons)"""
    for k in ("kp_v_per_m", "kp_v_per_n", "kff_v_per_m_s"):
        if k in ref_b["ctrl"]:
            b["ctrl"][k] = b["ctrl_sim"][k] = ref_b["ctrl"][k]


def run_case(b, h_target=None):
    """simulate a built case (internal step ~h_target, an integer number per sample)"""
    h_target = h_target or H_STEP
    t0 = time.time()
    sim = R.simulate(b["rig_sim"], b["phys_sim"], b["sens_sim"], b["ctrl_sim"], b["ref"], b["sup"], b["fs"],
                     b["noise_seed"], h_target=h_target, jac_every=4)
    sim["secs"] = time.time() - t0
    return sim


def declared_meta(b):
    rig, rng = b["rig"], np.random.default_rng(int(b["meta_rng"]))

    def off(x, n=3):
        return _round_sig(x * _u(rng, 0.71, 1.29), n)

    r = {
        "area_a_m2": rig["area_a_m2"], "area_b_m2": rig["area_b_m2"], "stroke_m": rig["stroke_m"],
        "supply_pressure_pa": off(rig["supply_pressure_pa"]), "tank_pressure_pa": 0.0,
        "valve_rated_flow_m3_s": off(rig["valve_rated_flow_m3_s"]), "valve_rated_dp_pa": 7e6,
        "valve_max_command_v": R.U_RATED, "moving_mass_kg": off(rig["mass_kg"] + (b["oov"] or {}).get("mass_kg", 0.0), 2),
        "orientation": rig["orientation"], "bulk_modulus_pa": off(rig["beta_at_half_supply_pa"]),
        "dead_volume_a_m3": off(rig["dead_volume_a_m3"] + rig["line_volume_a_m3"]),
        "dead_volume_b_m3": off(rig["dead_volume_b_m3"] + rig["line_volume_b_m3"]),
        "oil_density_kg_m3": 870.0,
    }
    if "load_pressure_feedback" in b["phys"]:
        r["valve_flow_law"] = "linear"
    meta = {"format": "htm-record/1", "sample_rate_hz": b["fs"], "rig": r}
    sp = rig.get("specimen_true")
    meta["specimen"] = None if not sp else {"stiffness_n_m": off(sp["stiffness_n_m"]),
                                            "zero_force_position_m": sp["zero_force_position_m"]}
    meta["controller"] = {k: v for k, v in b["ctrl"].items()}
    meta["sensors"] = b["sens_decl"]
    return meta


def _json_clean(x):
    if isinstance(x, dict):
        return {k: _json_clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_clean(v) for v in x]
    if isinstance(x, (np.floating,)):
        return float(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.bool_,)):
        return bool(x)
    return x


def write_case(b, sim, name, out):
    rec_dir, tr_dir = os.path.join(out, "records"), os.path.join(out, "truth")
    os.makedirs(rec_dir, exist_ok=True)
    os.makedirs(tr_dir, exist_ok=True)
    meas_ch = [c for c in R.CHANNELS if c in b["sens_true"]]
    cols = {"t": sim["t"], "u": sim["u"]}
    for c in meas_ch:
        cols[c] = sim["meas"][c]
    if b["control"] == "position":
        cols["y_ref"] = b["ref"]
    else:
        cols["f_ref"] = b["ref"]
    with gzip.GzipFile(os.path.join(rec_dir, name + ".csv.gz"), "wb", mtime=0) as gz:
        gz.write((",".join(cols) + "\n").encode())
        arr = np.column_stack(list(cols.values()))
        lines = []
        fmts = {"t": "%.6f", "u": "%.6g"}
        fm = [fmts.get(k, "%.9g") for k in cols]
        for row in arr:
            lines.append(",".join(f % v for f, v in zip(fm, row)))
        gz.write(("\n".join(lines) + "\n").encode())
    meta = declared_meta(b)
    with open(os.path.join(rec_dir, name + ".json"), "w") as f:
        json.dump(_json_clean(meta), f, indent=1)
    npz = {"t": sim["t"], "measured_channels": np.array(meas_ch), "u": sim["u"]}
    for c in meas_ch:
        npz[c] = sim["true"][c]
    npz["y_ref" if b["control"] == "position" else "f_ref"] = b["ref"]
    for k, v in sim["states"].items():       # physical states, float32 to keep the files small
        if k != "t":
            npz["state_" + k] = v.astype(np.float32)
    npz["state_p_s_valve"] = sim["p_s_valve"].astype(np.float32)
    npz["state_f_specimen"] = sim["f_spec"].astype(np.float32)
    npz["u_at_valve"] = sim["u_valve"].astype(np.float32)
    _savez_det(os.path.join(tr_dir, name + ".npz"), npz)
    rig_true = dict(b["rig"])
    rig_true["controller_design"] = b["design"]
    rig_true["sensors_true"] = b["sens_true"]
    rig_true["integration"] = {"method": "ROS2 (linearly implicit, L-stable), numerical Jacobian",
                               "step_s": 1.0 / b["fs"] / sim["nsub"], "jacobian_every": 4}
    rig_true["duration_s"] = b["duration_s"]
    notes = _notes(b)
    truth = {"class": b["case"]["class"], "case_id": b["case"]["id"], "effects": b["truth_eff"],
             "oov": b["oov"], "rig_true": rig_true, "notes": notes}
    with open(os.path.join(tr_dir, name + ".json"), "w") as f:
        json.dump(_json_clean(truth), f, indent=1)


def _savez_det(path, arrays):
    """np.savez_compressed with fixed zip timestamps, so that a seed gives byte-identical files"""
    import io
    import zipfile
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for k, v in arrays.items():
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.asanyarray(v), allow_pickle=False)
            zi = zipfile.ZipInfo(k + ".npy", date_time=(1980, 1, 1, 0, 0, 0))
            zi.compress_type = zipfile.ZIP_DEFLATED
            zf.writestr(zi, buf.getvalue())


def _notes(b):
    rig = b["rig"]
    s = (f"{rig['form']} {rig['orientation']}, bore {rig['bore_m']*1e3:.0f} mm, stroke {rig['stroke_m']*1e3:.0f} mm, "
         f"supply {rig['supply_pressure_pa']/1e5:.0f} bar, valve {rig['valve_rated_flow_m3_s']*6e4:.0f} L/min, "
         f"mass {rig['mass_kg']:.0f} kg, {b['fs']:.0f} Hz, {b['control']} control "
         f"(crossover {b['design']['crossover_hz']:.1f} Hz)")
    if rig.get("specimen_true"):
        s += f", specimen {rig['specimen_true']['stiffness_n_m']:.3g} N/m"
    if rig.get("supply_low_pa"):
        s += f", supply switched {rig['supply_pressure_pa']/1e5:.0f} -> {rig['supply_low_pa']/1e5:.0f} -> " \
             f"{rig['supply_pressure_pa']/1e5:.0f} bar at holds"
    if "load_pressure_feedback" in b["phys"]:
        s += "; metadata declares valve_flow_law 'linear' but the valve is an ordinary orifice valve"
    if b["oov"]:
        s += f"; outside the vocabulary: {b['oov']['name']}"
    if any(e["effect"] == "specimen_nonlinearity" for e in b["truth_eff"]):
        s += "; specimen_nonlinearity params are model-specific (crack closure)"
    return s


def record_names(seed):
    perm = np.random.default_rng(np.random.SeedSequence([int(seed), 12345])).permutation(len(SUITE))
    return {SUITE[i]["id"]: f"fr{j + 1:02d}" for j, i in enumerate(perm)}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", required=False, default=None)
    ap.add_argument("--only", nargs="*", default=None)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--list", action="store_true", help="print the suite and exit")
    a = ap.parse_args(argv)
    names = record_names(a.seed)
    inv = {v: k for k, v in names.items()}
    cases = [c for c in SUITE if c["quick"]] if a.quick else list(SUITE)
    if a.only:
        want = {inv.get(x, x) for x in a.only}
        unknown = want - set(CASE_BY_ID)
        if unknown:
            ap.error(f"unknown case(s): {sorted(unknown)}")
        cases = [c for c in cases if c["id"] in want] if not a.quick else [c for c in SUITE if c["id"] in want]
    if a.list:
        for c in cases:
            print(names[c["id"]], c["id"], c["class"], c["effects"], c["oov"] or "")
        return
    if not a.out:
        ap.error("--out is required")
    os.makedirs(a.out, exist_ok=True)
    suite = []
    for c in cases:
        b = build_case(c, a.seed)
        sim = simulate_case(b)
        nm = names[c["id"]]
        if not sim["sane"]:
            print(f"{nm} {c['id']}: the closed loop misbehaves (sim ok={sim['ok']})", file=sys.stderr)
        write_case(b, sim, nm, a.out)
        suite.append({"name": nm, "case_id": c["id"], "class": c["class"],
                      "effects": [f"{e['effect']}/{e['channel']}" if e["channel"] else e["effect"]
                                  for e in b["truth_eff"]],
                      "oov": c["oov"], "sample_rate_hz": b["fs"], "duration_s": round(b["duration_s"], 2),
                      "form": b["rig"]["form"], "orientation": b["rig"]["orientation"],
                      "control": b["control"], "channels": [ch for ch in R.CHANNELS if ch in b["sens_true"]],
                      "sim_ok": sim["ok"], "sane": sim["sane"]})
        print(f"{nm} {c['id']:24s} {c['class']:6s} {b['fs']:5.0f} Hz {b['duration_s']:5.1f} s  "
              f"{sim['secs']:5.1f} s  ok={sim['ok']}", flush=True)
    suite_path = os.path.join(a.out, "suite.json")
    old = []
    if a.only and os.path.exists(suite_path):
        with open(suite_path) as f:
            old = [x for x in json.load(f).get("cases", []) if x["case_id"] not in {s["case_id"] for s in suite}]
    allc = sorted(old + suite, key=lambda x: x["name"])
    with open(suite_path, "w") as f:
        json.dump({"format": "foreign-rig-suite/1", "seed": a.seed, "quick": a.quick, "cases": allc}, f, indent=1)


if __name__ == "__main__":
    main()
