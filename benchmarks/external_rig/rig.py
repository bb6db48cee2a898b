"""Held-out bench rig: an independent valve-cylinder simulator with hidden effects.

A verbatim copy of `shared/benchmarks/diagnose_external/generator/rig.py` (the project's shared
external benchmark, written outside this project), carried here so that the tests and
`benchmarks/diagnose_external.py` can regenerate its records with fresh seeds from a clone of the
repository alone. Do not edit; `cases.py` beside it holds the case list.

Written for the steering repo only. It generates measurement records in the
format of shared/DATA_FORMAT.md, with an effect that the record's metadata does
not declare, plus the noise-free truth for scoring.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, asdict

import numpy as np
from numba import njit

G = 9.81


@dataclass
class Rig:
    area: float = 2.5635e-3          # m^2, both sides (double rod)
    stroke: float = 0.2              # m
    v0a: float = 6.0e-5              # m^3 dead volume A
    v0b: float = 6.0e-5              # m^3 dead volume B
    beta: float = 1.4e9              # Pa
    ps: float = 18.6e6               # Pa supply (true)
    pt: float = 0.3e5                # Pa tank
    kv: float = 0.93 * 1.25e-3 / (10.0 * math.sqrt(3.5e6))  # m^3/s per V per sqrt(Pa)
    underlap: float = 0.03           # V equivalent
    dp_lam: float = 0.5e5            # Pa, laminar transition of the orifice law
    polarity: float = -1.0           # spool = polarity * u
    mass: float = 55.0               # kg
    bv: float = 4800.0               # N s/m
    fc: float = 780.0                # N
    fs: float = 120.0                # N
    cs: float = 0.012                # m/s
    veps: float = 2.0e-4             # m/s smoothing of sign
    vertical: bool = True            # gravity acts against +y
    k_spec: float = 0.0              # N/m specimen stiffness (0: free piston)
    y_spec0: float = 0.1             # m, unloaded specimen position


# effect flags / parameter slots (indices into the eff array)
E_NULL_BIAS, E_TAU, E_DEADBAND, E_HYST, E_LEAK, E_FC_POS, E_FC_NEG, E_FC_P, E_SAG_R, E_BUMP_F, E_BUMP_Y0, E_BUMP_Y1, E_AIR = range(13)
N_EFF = 13


@njit(cache=True)
def _sqrt_reg(dp, dp_lam):
    # signed square root, linear below the laminar transition pressure
    a = abs(dp)
    if a >= dp_lam:
        r = math.sqrt(a)
    else:
        r = a / math.sqrt(dp_lam) * (1.5 - 0.5 * a / dp_lam)
        # smooth blend: value and slope continuous enough for RK4
    return r if dp >= 0.0 else -r


@njit(cache=True)
def _rhs(x, u_cmd, p, eff, out):
    pa, pb, y, v, xv = x[0], x[1], x[2], x[3], x[4]
    area, stroke, v0a, v0b, beta, ps0, pt, kv, xu, dp_lam, pol, m, bv, fc, fs, cs, veps, vert, kspec, yspec0 = (
        p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8], p[9], p[10], p[11], p[12], p[13], p[14], p[15], p[16], p[17], p[18], p[19])
    # spool: first-order lag toward the (biased, dead-banded) command
    target = u_cmd + eff[E_NULL_BIAS]
    db = eff[E_DEADBAND]
    if db > 0.0:
        if target > db:
            target = target - db
        elif target < -db:
            target = target + db
        else:
            target = 0.0
    tau = eff[E_TAU]
    if tau > 0.0:
        out[4] = (target - xv) / tau
        s = pol * xv
    else:
        out[4] = 0.0
        s = pol * target
    # supply pressure sag with total valve inflow (accumulator / pump limit)
    ps = ps0
    # land openings of an underlapped 4-way valve
    o1 = max(xu + s, 0.0)   # P->A
    o2 = max(xu - s, 0.0)   # A->T
    o3 = max(xu - s, 0.0)   # P->B
    o4 = max(xu + s, 0.0)   # B->T
    for _ in range(2):
        qpa = kv * o1 * _sqrt_reg(ps - pa, dp_lam)
        qpb = kv * o3 * _sqrt_reg(ps - pb, dp_lam)
        if eff[E_SAG_R] > 0.0:
            ps = ps0 - eff[E_SAG_R] * max(qpa + qpb, 0.0)
        else:
            break
    qa = kv * o1 * _sqrt_reg(ps - pa, dp_lam) - kv * o2 * _sqrt_reg(pa - pt, dp_lam)
    qb = kv * o3 * _sqrt_reg(ps - pb, dp_lam) - kv * o4 * _sqrt_reg(pb - pt, dp_lam)
    qleak = eff[E_LEAK] * (pa - pb)
    va = v0a + area * y
    vb = v0b + area * (stroke - y)
    ba = beta
    bb = beta
    if eff[E_AIR] > 0.0:
        # entrained air: effective bulk modulus drops at low pressure
        ba = beta / (1.0 + eff[E_AIR] * beta / max(pa, 2e5))
        bb = beta / (1.0 + eff[E_AIR] * beta / max(pb, 2e5))
    out[0] = ba / va * (qa - area * v - qleak)
    out[1] = bb / vb * (qb + area * v + qleak)
    out[2] = v
    # friction
    sg = math.tanh(v / veps)
    fcoul = fc
    if eff[E_FC_POS] > 0.0 or eff[E_FC_NEG] > 0.0:
        fcoul = eff[E_FC_POS] if v >= 0.0 else eff[E_FC_NEG]
    fcoul += eff[E_FC_P] * (pa + pb)
    if eff[E_BUMP_F] > 0.0 and y > eff[E_BUMP_Y0] and y < eff[E_BUMP_Y1]:
        fcoul += eff[E_BUMP_F]
    ff = bv * v + sg * (fcoul + fs * math.exp(-abs(v) / cs))
    fext = 0.0
    if kspec > 0.0:
        fext = kspec * (y - yspec0)
    # end stops
    if y < 0.0:
        fext += 1e9 * y + 2e5 * v
    elif y > stroke:
        fext += 1e9 * (y - stroke) + 2e5 * v
    fg = m * G if vert > 0.5 else 0.0
    out[3] = (area * (pa - pb) - ff - fext - fg) / m


@njit(cache=True)
def _step(x, u, p, eff, dt, k1, k2, k3, k4, tmp):
    _rhs(x, u, p, eff, k1)
    for i in range(5):
        tmp[i] = x[i] + 0.5 * dt * k1[i]
    _rhs(tmp, u, p, eff, k2)
    for i in range(5):
        tmp[i] = x[i] + 0.5 * dt * k2[i]
    _rhs(tmp, u, p, eff, k3)
    for i in range(5):
        tmp[i] = x[i] + dt * k3[i]
    _rhs(tmp, u, p, eff, k4)
    for i in range(5):
        x[i] += dt / 6.0 * (k1[i] + 2 * k2[i] + 2 * k3[i] + k4[i])
    if x[0] < 1e3:
        x[0] = 1e3
    if x[1] < 1e3:
        x[1] = 1e3


@njit(cache=True)
def _run(p, eff, x0, yref, ts, nsub, kp, kff, umax, delay_y, hyst_w, quant_y, pa_true, pb_true, y_true, v_true, u_out, ps_true):
    n = yref.shape[0]
    x = x0.copy()
    k1 = np.zeros(5); k2 = np.zeros(5); k3 = np.zeros(5); k4 = np.zeros(5); tmp = np.zeros(5)
    dt = ts / nsub
    hist = np.zeros(n)
    hyst_pos = 0.0
    for k in range(n):
        pa_true[k] = x[0]; pb_true[k] = x[1]; y_true[k] = x[2]; v_true[k] = x[3]
        hist[k] = x[2]
        kd = k - delay_y
        ym = hist[kd] if kd >= 0 else hist[0]
        ym = math.floor(ym / quant_y + 0.5) * quant_y
        vref = (yref[k + 1] - yref[k]) / ts if k + 1 < n else 0.0
        u = kp * (yref[k] - ym) + kff * vref
        if u > umax:
            u = umax
        elif u < -umax:
            u = -umax
        u_out[k] = u
        ue = u
        if hyst_w > 0.0:
            # backlash (play) between command and spool
            if ue > hyst_pos + hyst_w:
                hyst_pos = ue - hyst_w
            elif ue < hyst_pos - hyst_w:
                hyst_pos = ue + hyst_w
            ue = hyst_pos
        # supply pressure actually seen this sample (for p_s channel)
        ps_true[k] = p[5]
        for _ in range(nsub):
            _step(x, ue, p, eff, dt, k1, k2, k3, k4, tmp)
    return x


def reference(ts: float, seed: int = 0) -> np.ndarray:
    """A rich closed-loop position reference: holds, constant-velocity ramps, sines, steps."""
    rng = np.random.default_rng(seed)
    segs = []
    mid = 0.1

    def hold(sec, level=mid):
        segs.append(np.full(int(sec / ts), level))

    def tri(vel, amp, periods):
        n_quarter = int(amp / vel / ts)
        up = mid + np.arange(n_quarter) * vel * ts
        top = up[-1] if len(up) else mid
        down = top - np.arange(2 * n_quarter) * vel * ts
        back = down[-1] + np.arange(n_quarter) * vel * ts
        cyc = np.concatenate([up, down, back])
        segs.append(np.tile(cyc, periods))

    def sine(freq, amp, sec):
        t = np.arange(int(sec / ts)) * ts
        segs.append(mid + amp * np.sin(2 * np.pi * freq * t))

    def steps(amp, period, n):
        half = int(period / 2 / ts)
        cyc = np.concatenate([np.full(half, mid + amp), np.full(half, mid - amp)])
        segs.append(np.tile(cyc, n))

    hold(1.0)
    order = [0.005, 0.01, 0.02, 0.04, 0.08, 0.15, 0.3]
    rng.shuffle(order)
    for vel in order:
        amp = 0.012 if vel < 0.015 else (0.03 if vel < 0.1 else 0.06)
        tri(vel, amp, 1 if vel < 0.03 else 2)
        hold(0.3)
    for f in (0.5, 1.0, 2.0, 4.0):
        sine(f, 0.01 if f < 3 else 0.005, 4.0)
    hold(0.3)
    steps(0.015, 2.0, 4)
    hold(1.0)
    return np.concatenate(segs)


@dataclass
class Case:
    name: str
    effect: str | None                    # canonical id from shared/EFFECTS.md, None for a clean record
    channel: str | None = None
    true_params: dict = field(default_factory=dict)
    fs_hz: float = 500.0
    seed: int = 0
    rig_overrides: dict = field(default_factory=dict)
    measure_ps: bool = True
    notes: str = ""


def simulate(case: Case):
    rig = Rig(**case.rig_overrides)
    ts = 1.0 / case.fs_hz
    yref = reference(ts, case.seed)
    n = len(yref)
    p = np.array([rig.area, rig.stroke, rig.v0a, rig.v0b, rig.beta, rig.ps, rig.pt, rig.kv, rig.underlap,
                  rig.dp_lam, rig.polarity, rig.mass, rig.bv, rig.fc, rig.fs, rig.cs, rig.veps,
                  1.0 if rig.vertical else 0.0, rig.k_spec, rig.y_spec0])
    eff = np.zeros(N_EFF)
    tp = case.true_params
    delay = 0
    hyst = 0.0
    e = case.effect
    if e == "valve_null_bias":
        eff[E_NULL_BIAS] = tp["bias_v"]
    elif e == "valve_dynamics":
        eff[E_TAU] = tp["tau_s"]
    elif e == "valve_deadband":
        eff[E_DEADBAND] = tp["half_width_v"]
    elif e == "valve_hysteresis":
        hyst = tp["half_width_v"]
    elif e == "internal_leakage":
        eff[E_LEAK] = tp["coeff_m3_per_s_pa"]
    elif e == "friction_asymmetry":
        eff[E_FC_POS] = tp["coulomb_pos_n"]
        eff[E_FC_NEG] = tp["coulomb_neg_n"]
    elif e == "pressure_dependent_friction":
        eff[E_FC_P] = tp["coeff_n_per_pa"]
    elif e == "supply_pressure_sag":
        eff[E_SAG_R] = tp["resistance_pa_s_per_m3"]
    elif e == "sensor_delay":
        delay = int(round(tp["delay_s"] / ts))
    elif e == "entrained_air":
        eff[E_AIR] = tp["air_fraction"]
    elif e == "oov_position_friction":
        eff[E_BUMP_F] = tp["extra_n"]; eff[E_BUMP_Y0] = tp["y0"]; eff[E_BUMP_Y1] = tp["y1"]
    kp, kff, umax = -150.0, -1.0 / 0.07, 10.0
    nsub = max(1, int(math.ceil(ts / 2e-5)))
    x0 = np.array([rig.ps * 0.5, rig.ps * 0.5 + rig.mass * G / rig.area * (1 if rig.vertical else 0) * -1.0, 0.1, 0.0, 0.0])
    arrs = [np.zeros(n) for _ in range(6)]
    _run(p, eff, x0, yref, ts, nsub, kp, kff, umax, delay, hyst, 5e-6, *arrs)
    pa, pb, y, v, u, ps_t = arrs
    t = np.arange(n) * ts
    truth = dict(t=t, u=u, y=y, v=v, p_a=pa, p_b=pb, p_s=ps_t, y_ref=yref)
    # measurement model
    rng = np.random.default_rng(1000 + case.seed)
    ym = np.floor(y / 5e-6 + 0.5) * 5e-6
    if e == "sensor_delay":
        ym = np.concatenate([np.full(delay, ym[0]), ym[:-delay]]) if delay else ym
    vm = np.round((v + rng.normal(0, 2e-4, n)) / 1e-4) * 1e-4
    lsb = 400e5 / 10.0 * (20.0 / 65536)
    def pmeas(x):
        return np.round((x + rng.normal(0, 3e3, n)) / lsb) * lsb
    pam, pbm, psm = pmeas(pa), pmeas(pb), pmeas(ps_t + 0.0)
    if e == "sensor_offset":
        tgt = {"p_a": "pam", "p_b": "pbm"}[case.channel]
        if case.channel == "p_a":
            pam = pam + tp["offset_pa"]
        else:
            pbm = pbm + tp["offset_pa"]
    if e == "sensor_gain":
        if case.channel == "p_a":
            pam = pam * tp["gain"]
        else:
            pbm = pbm * tp["gain"]
    meas = dict(t=t, u=u, y=ym, v=vm, p_a=pam, p_b=pbm, y_ref=yref)
    if case.measure_ps:
        meas["p_s"] = psm
    meta = {
        "format": "htm-record/1",
        "sample_rate_hz": case.fs_hz,
        "rig": {
            "area_a_m2": rig.area, "area_b_m2": rig.area, "stroke_m": rig.stroke,
            "supply_pressure_pa": 19.0e6, "tank_pressure_pa": 0.0,
            "valve_rated_flow_m3_s": 1.25e-3, "valve_rated_dp_pa": 7.0e6, "valve_max_command_v": 10.0,
            "moving_mass_kg": 52.0, "orientation": "vertical" if rig.vertical else "horizontal",
            "bulk_modulus_pa": 1.2e9, "dead_volume_a_m3": 5.0e-5, "dead_volume_b_m3": 5.0e-5,
            "oil_density_kg_m3": 874.0,
        },
        "specimen": None if rig.k_spec == 0 else {"stiffness_n_m": rig.k_spec},
        "controller": {
            "type": "position_pff",
            "law": "u[k] = clip(kp*(y_ref[k]-y[k]) + kff*(y_ref[k+1]-y_ref[k])/Ts, -u_max, u_max)",
            "kp_v_per_m": kp, "kff_v_per_m_s": kff, "u_max_v": umax,
        },
        "sensors": {
            "y": {"resolution_m": 5e-6}, "v": {"resolution_m_s": 1e-4},
            "p_a": {"range_pa": [0, 400e5]}, "p_b": {"range_pa": [0, 400e5]},
        },
    }
    return meas, truth, meta


def write(case: Case, outdir: str, truthdir: str):
    import gzip, os
    meas, truth, meta = simulate(case)
    cols = list(meas.keys())
    arr = np.column_stack([meas[c] for c in cols])
    with gzip.open(os.path.join(outdir, case.name + ".csv.gz"), "wt") as f:
        f.write(",".join(cols) + "\n")
        np.savetxt(f, arr, fmt="%.9g", delimiter=",")
    with open(os.path.join(outdir, case.name + ".json"), "w") as f:
        json.dump(meta, f, indent=1)
    tcols = list(truth.keys())
    np.savez_compressed(os.path.join(truthdir, case.name + ".npz"), **truth)
    with open(os.path.join(truthdir, case.name + ".json"), "w") as f:
        json.dump({"effect": case.effect, "channel": case.channel, "params": case.true_params,
                   "rig": asdict(Rig(**case.rig_overrides)), "notes": case.notes}, f, indent=1)
    return meas, truth
