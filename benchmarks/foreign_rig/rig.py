"""Foreign rig: a servo-hydraulic test rig simulator written without htm's model code.

Physics (all SI; see README.md for the ranges the suite draws from):

* valve: command u [V] -> (null bias) -> (play / backlash) -> (optional first-order lag) ->
  second-order spool (wn, zeta) with soft travel stops at +-spool_limit; the spool position is
  normalised (1 = rated opening = 10 V) and multiplied by the valve polarity. Four metering edges
  whose openings rise smoothly from a small underlap (or an overlap: dead band); each edge is an
  orifice whose flow is turbulent (sqrt) at large pressure drop and laminar below a transition
  pressure set by a critical Reynolds number of the edge's slot (so small openings stay laminar).
* supply: an ideal source p_s(t) (with optional switching schedule and pump ripple), or, for
  supply sag, a supply node of finite capacitance fed from the source through a resistance.
  Tank back-pressure pt.
* lines: between each valve port and its cylinder chamber a lumped line volume and a resistance
  (Hagen-Poiseuille laminar + fitting losses); an optional end-of-stroke cushion restricts the
  outflow of chamber B near full extension (check valve for the inflow).
* oil: tangent bulk modulus rising with pressure; free air (isothermal) that makes the mixture
  collapse smoothly towards vacuum; a vapour-pressure floor.
* cylinder: double or single rod, chamber A volume grows with y, B with (stroke - y). Soft end stops.
* friction: LuGre (bristle state z) with Stribeck (static excess), Coulomb (may differ per direction,
  may grow with p_a + p_b, may have a bump over part of the stroke) and viscous terms.
* specimen: linear spring to the frame (tension positive f = k (y - y0)), optionally with crack
  closure (a stiffer branch below a closure position); optional compliant fixture mass.
* sensors: first-order anti-alias filters, transport delay (whole samples), gain, offset, white
  noise, quantisation and range clipping; the controller reads the same measured values.
* integration: linearly-implicit two-stage Rosenbrock method (ROS2, L-stable, order 2) with a
  numerical Jacobian, fixed internal step, so the stiff line nodes and bristles stay stable.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

G = 9.81
P_ATM = 1.013e5
RATED_EDGE_DP = 3.5e6      # rated flow is given at 70 bar valve drop = 35 bar per metering edge
U_RATED = 10.0             # V at rated spool opening
CHANNELS = ("y", "v", "p_a", "p_b", "p_s", "f")

# ---------------------------------------------------------------- parameter vector layout
(P_AREA_A, P_AREA_B, P_STROKE, P_V0A, P_V0B, P_VLA, P_VLB, P_RLAM_A, P_RTURB_A, P_RLAM_B, P_RTURB_B,
 P_BETA0, P_BETA_K, P_AIR, P_PVAP, P_VSUP, P_RSAG,
 P_PS_A, P_PS_B, P_TK, P_TS, P_RIP_A, P_RIP_A2, P_RIP_F, P_RIP_PH2, P_PT,
 P_POL, P_WN, P_ZETA, P_XLIM, P_TAU_LAG,
 P_LAP, P_LAP_EPS, P_KV, P_DPT_MIN, P_C_RE, P_C_R, P_LIN_LAW, P_DP_LIN_REF, P_DP_LIN_C,
 P_MASS, P_VERT, P_FC_POS, P_FC_NEG, P_FS_EX, P_V_STR, P_SIG0, P_SIG1, P_SIG2, P_FRIC_P,
 P_BUMP_F, P_BUMP_Y1, P_BUMP_Y2, P_BUMP_W,
 P_K_SPEC, P_Y0_SPEC, P_R_CLOSED, P_Y_CL, P_W_CL, P_LEAK,
 P_CUSH_LEN, P_CUSH_R, P_M2, P_K2, P_C2, P_K_END, N_P) = range(67)

# ---------------------------------------------------------------- state layout
(S_PA, S_PB, S_PVA, S_PVB, S_PS, S_Y, S_V, S_Z, S_XS, S_VS, S_XL, S_T, S_Y2, S_V2, N_S) = range(15)

STATE_NAMES = ("p_a", "p_b", "p_va", "p_vb", "p_s_node", "y", "v", "z_bristle", "spool", "spool_vel",
               "valve_lag", "t", "y_fixture", "v_fixture")


@njit(cache=True)
def _sp(x):
    """softplus log(1 + e^x), overflow-safe"""
    if x > 30.0:
        return x
    if x < -30.0:
        return math.exp(x)
    return math.log1p(math.exp(x))


@njit(cache=True)
def _sig(x):
    if x > 30.0:
        return 1.0
    if x < -30.0:
        return 0.0
    return 1.0 / (1.0 + math.exp(-x))


@njit(cache=True)
def _ramp(x, eps):
    """smooth max(x, 0): a hyperbola, so the metering edge opens smoothly"""
    return 0.5 * (x + math.sqrt(x * x + eps * eps))


@njit(cache=True)
def _orifice(p, o, dp):
    """metering-edge flow: turbulent sqrt(dp) above, laminar (linear) below a transition pressure
    that grows as the opening shrinks (critical Reynolds number of the slot)."""
    if p[P_LIN_LAW] > 0.5:
        # pressure-compensated ('linear') valve: flow independent of the drop above a few bar
        return p[P_KV] * o * math.sqrt(p[P_DP_LIN_REF]) * dp / math.sqrt(dp * dp + p[P_DP_LIN_C] ** 2)
    w = o + p[P_C_R]
    dpt = p[P_DPT_MIN] + p[P_C_RE] / (w * w)
    return p[P_KV] * o * dp / math.sqrt(math.sqrt(dp * dp + dpt * dpt))


@njit(cache=True)
def _line_q(dp, rlam, rturb):
    """flow through a line with dp = rlam q + rturb q |q|"""
    a = abs(dp)
    q = 2.0 * a / (rlam + math.sqrt(rlam * rlam + 4.0 * rturb * a))
    return q if dp >= 0.0 else -q


@njit(cache=True)
def _beta(p, prm, qnet):
    """effective bulk modulus of oil with free air (isothermal), collapsing towards vacuum; below
    the vapour pressure a cavity forms: no stiffness while the node keeps losing oil (qnet < 0),
    the (air) stiffness again as soon as oil flows back in (the cavity's volume is neglected)"""
    pv = prm[P_PVAP]
    d = p - pv
    pp = pv + 0.5 * (d + math.sqrt(d * d + 4.0e6))       # smooth max(p, p_vap), 1 kPa rounding
    bo = prm[P_BETA0] + prm[P_BETA_K] * pp
    cav = _sig((p - pv) / 1.0e3)
    cav = cav + (1.0 - cav) * _sig(qnet / 1.0e-7)
    a0 = prm[P_AIR]
    if a0 <= 0.0:
        return bo * cav
    r = a0 * P_ATM / pp
    alpha = r / (1.0 - a0 + r)
    return cav / ((1.0 - alpha) / bo + alpha / pp)


@njit(cache=True)
def spec_force(y, p):
    """load-cell force of the specimen (tension positive), crack closure optional"""
    k = p[P_K_SPEC]
    if k <= 0.0:
        return 0.0
    y0 = p[P_Y0_SPEC]
    f = k * (y - y0)
    r = p[P_R_CLOSED]
    if r != 1.0:
        w = p[P_W_CL]
        yc = p[P_Y_CL]
        f += -(r - 1.0) * k * w * (_sp(-(y - yc) / w) - _sp(-(y0 - yc) / w))
    return f


@njit(cache=True)
def supply_source(t, p):
    s = (t - p[P_TK]) / p[P_TS]
    if s < 0.0:
        s = 0.0
    elif s > 1.0:
        s = 1.0
    ps = p[P_PS_A] + (p[P_PS_B] - p[P_PS_A]) * s
    if p[P_RIP_A] > 0.0:
        w = 2.0 * math.pi * p[P_RIP_F] * t
        ps *= 1.0 + p[P_RIP_A] * math.sin(w) + p[P_RIP_A2] * math.sin(2.0 * w + p[P_RIP_PH2])
    return ps


@njit(cache=True)
def _rhs(x, ucmd, p, out):
    pa = x[S_PA]
    pb = x[S_PB]
    pva = x[S_PVA]
    pvb = x[S_PVB]
    y = x[S_Y]
    v = x[S_V]
    z = x[S_Z]
    xs = x[S_XS]
    vs = x[S_VS]
    t = x[S_T]
    for i in range(N_S):
        out[i] = 0.0
    out[S_T] = 1.0
    pt = p[P_PT]
    ps_src = supply_source(t, p)
    # ---- valve electronics / torque motor / spool
    if p[P_TAU_LAG] > 0.0:
        out[S_XL] = (ucmd - x[S_XL]) / p[P_TAU_LAG]
        uin = x[S_XL]
    else:
        uin = ucmd
    wn = p[P_WN]
    target = p[P_POL] * uin / U_RATED
    xl = p[P_XLIM]
    ws = 0.01
    stop = ws * (_sp((xs - xl) / ws) - _sp((-xl - xs) / ws))
    out[S_XS] = vs
    out[S_VS] = wn * wn * (target - xs - 200.0 * stop) - 2.0 * p[P_ZETA] * wn * vs
    # ---- supply
    if p[P_RSAG] > 0.0:
        ps = x[S_PS]
    else:
        ps = ps_src
    # ---- metering edges
    lap = p[P_LAP]
    eps = p[P_LAP_EPS]
    o_pa = _ramp(lap + xs, eps)
    o_at = _ramp(lap - xs, eps)
    o_pb = _ramp(lap - xs, eps)
    o_bt = _ramp(lap + xs, eps)
    q_pa = _orifice(p, o_pa, ps - pva)
    q_pb = _orifice(p, o_pb, ps - pvb)
    qv_a = q_pa - _orifice(p, o_at, pva - pt)
    qv_b = q_pb - _orifice(p, o_bt, pvb - pt)
    # ---- lines (+ cushion on the B side near full extension)
    qla = _line_q(pva - pa, p[P_RLAM_A], p[P_RTURB_A])
    rlb = p[P_RLAM_B]
    rtb = p[P_RTURB_B]
    if p[P_CUSH_LEN] > 0.0:
        # cushion spear enters the bore over the first 15 % of the cushion length; from then on
        # the outflow of chamber B passes the cushion needle (turbulent, resistance P_CUSH_R)
        L = p[P_CUSH_LEN]
        s = (y - (p[P_STROKE] - L)) / (0.15 * L)
        if s < 0.0:
            s = 0.0
        elif s > 1.0:
            s = 1.0
        sm = s * s * (3.0 - 2.0 * s)
        kc = 1.0 / math.sqrt(p[P_CUSH_R]) + (1.0 - sm) / math.sqrt(0.1 * rtb)
        chk = _sig((pvb - pb) / 2.0e5)      # check valve: free inflow
        rtb = rtb + (1.0 - chk) / (kc * kc)
    qlb = _line_q(pvb - pb, rlb, rtb)
    # ---- cylinder chambers
    aa = p[P_AREA_A]
    ab = p[P_AREA_B]
    stroke = p[P_STROKE]
    va = p[P_V0A] + aa * y
    vb = p[P_V0B] + ab * (stroke - y)
    vmin_a = 0.3 * p[P_V0A]
    vmin_b = 0.3 * p[P_V0B]
    va = vmin_a + _ramp(va - vmin_a, 0.05 * vmin_a)
    vb = vmin_b + _ramp(vb - vmin_b, 0.05 * vmin_b)
    qleak = p[P_LEAK] * (pa - pb)
    qn = qla - aa * v - qleak
    out[S_PA] = _beta(pa, p, qn) / va * qn
    qn = qlb + ab * v + qleak
    out[S_PB] = _beta(pb, p, qn) / vb * qn
    qn = qv_a - qla
    out[S_PVA] = _beta(pva, p, qn) / p[P_VLA] * qn
    qn = qv_b - qlb
    out[S_PVB] = _beta(pvb, p, qn) / p[P_VLB] * qn
    if p[P_RSAG] > 0.0:
        qn = (ps_src - ps) / p[P_RSAG] - q_pa - q_pb
        out[S_PS] = _beta(ps, p, qn) / p[P_VSUP] * qn
    # ---- friction (LuGre)
    vabs = math.sqrt(v * v + 1e-10)
    th = 0.5 * (1.0 + math.tanh(v / 1e-4))
    fc = p[P_FC_NEG] + (p[P_FC_POS] - p[P_FC_NEG]) * th
    fc += p[P_FRIC_P] * (pa + pb)
    if p[P_BUMP_F] > 0.0:
        bw = p[P_BUMP_W]
        fc += p[P_BUMP_F] * 0.5 * (math.tanh((y - p[P_BUMP_Y1]) / bw) - math.tanh((y - p[P_BUMP_Y2]) / bw))
    vr = v / p[P_V_STR]
    gfun = fc + p[P_FS_EX] * math.exp(-vr * vr)
    dz = v - p[P_SIG0] * vabs * z / gfun
    out[S_Z] = dz
    ffric = p[P_SIG0] * z + p[P_SIG1] * math.exp(-vr * vr) * dz + p[P_SIG2] * v
    # ---- mechanics
    fspec = spec_force(y, p)
    we = 2e-4
    fend = p[P_K_END] * we * (_sp((y - stroke) / we) - _sp(-y / we))
    fend += 2.0 * math.sqrt(p[P_K_END] * p[P_MASS]) * v * (_sig((y - stroke) / we) + _sig(-y / we))
    grav = p[P_MASS] * G * p[P_VERT]
    fcpl = 0.0
    if p[P_M2] > 0.0:
        fcpl = p[P_K2] * (x[S_Y2] - y) + p[P_C2] * (x[S_V2] - v)
        out[S_Y2] = x[S_V2]
        out[S_V2] = (-fcpl - p[P_M2] * G * p[P_VERT]) / p[P_M2]
    out[S_Y] = v
    out[S_V] = (aa * pa - ab * pb - ffric - fspec - fend - grav + fcpl) / p[P_MASS]


@njit(cache=True)
def _f_scaled(X, ucmd, p, sc, act, out, tmp):
    for i in range(N_S):
        tmp[i] = X[i] * sc[i]
    _rhs(tmp, ucmd, p, out)
    for i in range(N_S):
        out[i] = out[i] / sc[i] if act[i] else 0.0


@njit(cache=True)
def _lu(a, piv, n):
    for k in range(n):
        m = k
        big = abs(a[k, k])
        for i in range(k + 1, n):
            if abs(a[i, k]) > big:
                big = abs(a[i, k])
                m = i
        piv[k] = m
        if m != k:
            for j in range(n):
                tmp = a[k, j]
                a[k, j] = a[m, j]
                a[m, j] = tmp
        d = a[k, k]
        for i in range(k + 1, n):
            a[i, k] /= d
            f = a[i, k]
            if f != 0.0:
                for j in range(k + 1, n):
                    a[i, j] -= f * a[k, j]


@njit(cache=True)
def _lu_solve(a, piv, b, n):
    for k in range(n):
        m = piv[k]
        if m != k:
            tmp = b[k]
            b[k] = b[m]
            b[m] = tmp
    for i in range(n):
        s = b[i]
        for j in range(i):
            s -= a[i, j] * b[j]
        b[i] = s
    for i in range(n - 1, -1, -1):
        s = b[i]
        for j in range(i + 1, n):
            s -= a[i, j] * b[j]
        b[i] = s / a[i, i]


GAMMA = 1.0 + 1.0 / math.sqrt(2.0)


@njit(cache=True)
def _ros2_step(X, h, ucmd, p, sc, act, W, piv, f0, f1, fp, k1, k2, Xt, tmp, new_jac):
    n = N_S
    _f_scaled(X, ucmd, p, sc, act, f0, tmp)
    for j in range(n):
        if not new_jac:
            break
        if not act[j]:
            for i in range(n):
                W[i, j] = 1.0 if i == j else 0.0
            continue
        d = 1e-7 * max(1.0, abs(X[j]))
        xj = X[j]
        X[j] = xj + d
        _f_scaled(X, ucmd, p, sc, act, fp, tmp)
        X[j] = xj
        for i in range(n):
            W[i, j] = -GAMMA * h * (fp[i] - f0[i]) / d
        W[j, j] += 1.0
    if new_jac:
        _lu(W, piv, n)
    for i in range(n):
        k1[i] = f0[i]
    _lu_solve(W, piv, k1, n)
    for i in range(n):
        Xt[i] = X[i] + h * k1[i]
    _f_scaled(Xt, ucmd, p, sc, act, f1, tmp)
    for i in range(n):
        k2[i] = f1[i] - 2.0 * k1[i]
    _lu_solve(W, piv, k2, n)
    for i in range(n):
        X[i] += 1.5 * h * k1[i] + 0.5 * h * k2[i]


@njit(cache=True)
def _step_ok(X):
    """pressures (scaled states, MPa) not below -0.1 bar and everything finite"""
    for i in range(N_S):
        if not math.isfinite(X[i]):
            return False
    for i in range(5):
        if X[i] < -0.01:
            return False
    return True


@njit(cache=True)
def _signals(x, p, sig):
    sig[0] = x[S_Y]
    sig[1] = x[S_V]
    sig[2] = x[S_PA]
    sig[3] = x[S_PB]
    sig[4] = x[S_PS] if p[P_RSAG] > 0.0 else supply_source(x[S_T], p)
    sig[5] = spec_force(x[S_Y], p)


@njit(cache=True)
def _simulate(p, x0, sc, act, nsub, jac_every, n_pre, ref, sup, ctrl_type, kp, kff, umax, bias_v, play_v,
              s_tau, s_delay, s_gain, s_off, s_quant, s_lo, s_hi, noise,
              rd_true, rd_meas, u_out, states, extra):
    """closed loop, sample by sample; returns the number of samples simulated (stops on NaN)."""
    n = ref.shape[0]
    ntot = n_pre + n
    ts = p[P_TS]
    h = ts / nsub
    X = np.empty(N_S)
    for i in range(N_S):
        X[i] = x0[i] / sc[i]
    W = np.zeros((N_S, N_S))
    piv = np.zeros(N_S, dtype=np.int64)
    f0 = np.zeros(N_S); f1 = np.zeros(N_S); fp = np.zeros(N_S)
    k1 = np.zeros(N_S); k2 = np.zeros(N_S); Xt = np.zeros(N_S); tmp = np.zeros(N_S)
    xs = np.zeros(N_S)
    sig = np.zeros(6)
    sig_prev = np.zeros(6)
    filt = np.zeros(6)
    hist = np.zeros((6, ntot))
    # filter coefficients (first-order hold on the internal steps)
    fa = np.zeros(6); fb0 = np.zeros(6); fb1 = np.zeros(6)
    for c in range(6):
        if s_tau[c] > 0.0:
            a = math.exp(-h / s_tau[c])
            fa[c] = a
            fb0[c] = 1.0 - s_tau[c] * (1.0 - a) / h
            fb1[c] = s_tau[c] * (1.0 - a) / h - a
    for i in range(N_S):
        xs[i] = X[i] * sc[i]
    _signals(xs, p, sig)
    for c in range(6):
        filt[c] = sig[c]
        sig_prev[c] = sig[c]
    hp = 0.0
    first_play = True
    Xsave = np.zeros(N_S)
    force_jac = True
    n_retry = 0
    for kk in range(ntot):
        k = kk - n_pre
        kr = k if k >= 0 else 0
        # ---- readings at t_k
        for c in range(6):
            hist[c, kk] = filt[c]
        for c in range(6):
            kd = kk - s_delay[c]
            if kd < 0:
                kd = 0
            r = s_gain[c] * hist[c, kd] + s_off[c]
            if r < s_lo[c]:
                r = s_lo[c]
            elif r > s_hi[c]:
                r = s_hi[c]
            m = r + noise[c, kk]
            if s_quant[c] > 0.0:
                m = math.floor(m / s_quant[c] + 0.5) * s_quant[c]
            if m < s_lo[c]:
                m = s_lo[c]
            elif m > s_hi[c]:
                m = s_hi[c]
            rd_true[c, kk] = r
            rd_meas[c, kk] = m
        # ---- controller
        if ctrl_type == 0:
            vref = 0.0
            if k >= 0 and k + 1 < n:
                vref = (ref[k + 1] - ref[k]) / ts
            u = kp * (ref[kr] - rd_meas[0, kk]) + kff * vref
        else:
            u = kp * (ref[kr] - rd_meas[5, kk])
        if u > umax:
            u = umax
        elif u < -umax:
            u = -umax
        u_out[kk] = u
        ue = u + bias_v
        if play_v > 0.0:
            if first_play:
                hp = ue
                first_play = False
            if ue > hp + play_v:
                hp = ue - play_v
            elif ue < hp - play_v:
                hp = ue + play_v
            ue = hp
        # ---- supply schedule over this sample
        p[P_TK] = (kk - n_pre) * ts
        p[P_PS_A] = sup[kr]
        p[P_PS_B] = sup[k + 1] if (k >= 0 and k + 1 < n) else sup[kr]
        for i in range(N_S):
            xs[i] = X[i] * sc[i]
        for i in range(N_S):
            states[kk, i] = xs[i]
        _signals(xs, p, sig)
        extra[kk, 0] = sig[4]
        extra[kk, 1] = sig[5]
        extra[kk, 2] = ue
        for j in range(nsub):
            for i in range(N_S):
                Xsave[i] = X[i]
            _ros2_step(X, h, ue, p, sc, act, W, piv, f0, f1, fp, k1, k2, Xt, tmp,
                       force_jac or (j % jac_every == 0))
            force_jac = False
            if not _step_ok(X):
                # a stale Jacobian or a hard transient: redo the step as 4 steps, fresh Jacobian each
                for i in range(N_S):
                    X[i] = Xsave[i]
                for _ in range(4):
                    _ros2_step(X, 0.25 * h, ue, p, sc, act, W, piv, f0, f1, fp, k1, k2, Xt, tmp, True)
                force_jac = True
                n_retry += 1
            for i in range(N_S):
                xs[i] = X[i] * sc[i]
            _signals(xs, p, sig)
            for c in range(6):
                if s_tau[c] > 0.0:
                    filt[c] = fa[c] * filt[c] + fb0[c] * sig[c] + fb1[c] * sig_prev[c]
                else:
                    filt[c] = sig[c]
                sig_prev[c] = sig[c]
        bad = False
        for i in range(N_S):
            if not math.isfinite(X[i]):
                bad = True
        if bad:
            return kk, n_retry
    return ntot, n_retry


# ---------------------------------------------------------------- python side

STATE_SCALE = np.array([1e6, 1e6, 1e6, 1e6, 1e6, 1e-3, 1e-2, 1e-5, 1e-2, 1.0, 1e-2, 1.0, 1e-3, 1e-2])


def build_params(rig: dict, eff: dict, ts: float) -> np.ndarray:
    """parameter vector from the true rig and the (non-sensor) effects / oov physics"""
    p = np.zeros(N_P)
    p[P_AREA_A] = rig["area_a_m2"]
    p[P_AREA_B] = rig["area_b_m2"]
    p[P_STROKE] = rig["stroke_m"]
    p[P_V0A] = rig["dead_volume_a_m3"]
    p[P_V0B] = rig["dead_volume_b_m3"]
    p[P_VLA] = rig["line_volume_a_m3"]
    p[P_VLB] = rig["line_volume_b_m3"]
    p[P_RLAM_A] = rig["line_r_lam_a"]
    p[P_RTURB_A] = rig["line_r_turb_a"]
    p[P_RLAM_B] = rig["line_r_lam_b"]
    p[P_RTURB_B] = rig["line_r_turb_b"]
    p[P_BETA0] = rig["beta0_pa"]
    p[P_BETA_K] = rig["beta_dp"]
    p[P_AIR] = rig["air_fraction_base"] + eff.get("entrained_air", {}).get("air_fraction", 0.0)
    p[P_PVAP] = rig["vapour_pressure_pa"]
    p[P_PT] = rig["tank_pressure_pa"]
    p[P_TS] = ts
    p[P_POL] = rig["polarity"]
    p[P_WN] = rig["wn"]
    p[P_ZETA] = rig["zeta"]
    p[P_XLIM] = rig["spool_limit"]
    p[P_TAU_LAG] = eff.get("valve_dynamics", {}).get("tau_s", 0.0)
    lap = rig["underlap"]
    if "valve_deadband" in eff:
        lap = -eff["valve_deadband"]["half_width_v"] / U_RATED
    p[P_LAP] = lap
    p[P_LAP_EPS] = rig["lap_smoothing"]
    p[P_KV] = rig["valve_rated_flow_m3_s"] / math.sqrt(RATED_EDGE_DP)
    p[P_DPT_MIN] = rig["laminar_dp_min_pa"]
    xm = rig["spool_stroke_m"]
    p[P_C_RE] = 0.5 * rig["oil_density_kg_m3"] * (rig["re_crit"] * rig["nu_m2_s"] / 2.0) ** 2 / xm ** 2
    p[P_C_R] = rig["radial_clearance_m"] / xm
    p[P_LIN_LAW] = 1.0 if rig.get("pressure_compensated_valve") else 0.0
    p[P_DP_LIN_REF] = 0.5 * (rig["supply_pressure_pa"] - rig["tank_pressure_pa"])
    p[P_DP_LIN_C] = 5e5
    p[P_MASS] = rig["mass_kg"]
    p[P_VERT] = 1.0 if rig["orientation"] == "vertical" else 0.0
    fc = rig["coulomb_n"]
    p[P_FC_POS] = eff.get("friction_asymmetry", {}).get("coulomb_pos_n", fc)
    p[P_FC_NEG] = eff.get("friction_asymmetry", {}).get("coulomb_neg_n", fc)
    p[P_FS_EX] = rig["static_excess_n"]
    p[P_V_STR] = rig["stribeck_velocity_m_s"]
    p[P_SIG0] = rig["bristle_stiffness_n_m"]
    p[P_SIG1] = rig["bristle_damping_n_s_m"]
    p[P_SIG2] = rig["viscous_n_s_m"]
    p[P_FRIC_P] = eff.get("pressure_dependent_friction", {}).get("coeff_n_per_pa", 0.0)
    if "friction_bump" in eff:
        b = eff["friction_bump"]
        p[P_BUMP_F] = b["extra_n"]
        p[P_BUMP_Y1] = b["y1"]
        p[P_BUMP_Y2] = b["y2"]
        p[P_BUMP_W] = b["edge_m"]
    sp = rig.get("specimen_true")
    p[P_R_CLOSED] = 1.0
    if sp:
        p[P_K_SPEC] = sp["stiffness_n_m"]
        p[P_Y0_SPEC] = sp["zero_force_position_m"]
        if "specimen_nonlinearity" in eff:
            e = eff["specimen_nonlinearity"]
            p[P_R_CLOSED] = e["stiffness_ratio_closed"]
            p[P_Y_CL] = e["closure_position_m"]
            p[P_W_CL] = e["transition_width_m"]
    p[P_LEAK] = eff.get("internal_leakage", {}).get("coeff_m3_per_s_pa", 0.0)
    if "supply_pressure_sag" in eff:
        r = eff["supply_pressure_sag"]["resistance_pa_s_per_m3"]
        p[P_RSAG] = r
        # supply node capacitance from the sag's time constant
        beta = rig["beta0_pa"] + rig["beta_dp"] * rig["supply_pressure_pa"]
        p[P_VSUP] = eff["supply_pressure_sag"]["time_constant_s"] * beta / r
    if "supply_ripple" in eff:
        rp = eff["supply_ripple"]
        p[P_RIP_A] = rp["rel_amplitude"]
        p[P_RIP_A2] = rp["rel_amplitude_2nd"]
        p[P_RIP_F] = rp["pump_frequency_hz"]
        p[P_RIP_PH2] = rp["phase_2nd"]
    if "end_cushion" in eff:
        c = eff["end_cushion"]
        p[P_CUSH_LEN] = c["length_m"]
        p[P_CUSH_R] = c["needle_resistance_pa_s2_per_m6"]
    if "compliant_fixture" in eff:
        c = eff["compliant_fixture"]
        p[P_M2] = c["mass_kg"]
        p[P_K2] = c["stiffness_n_m"]
        p[P_C2] = c["damping_n_s_m"]
    p[P_K_END] = 2e8
    return p


def active_states(p: np.ndarray) -> np.ndarray:
    act = np.ones(N_S, dtype=np.bool_)
    act[S_PS] = p[P_RSAG] > 0.0
    act[S_XL] = p[P_TAU_LAG] > 0.0
    act[S_Y2] = p[P_M2] > 0.0
    act[S_V2] = p[P_M2] > 0.0
    return act


def initial_state(rig: dict, p: np.ndarray, y_init: float, t0: float) -> np.ndarray:
    """a rough static equilibrium; the pre-run settles the rest"""
    x = np.zeros(N_S)
    aa, ab = rig["area_a_m2"], rig["area_b_m2"]
    ps, pt = rig["supply_pressure_pa"], rig["tank_pressure_pa"]
    load = p[P_MASS] * G * p[P_VERT] + spec_force(y_init, p)
    if p[P_M2] > 0:
        load += p[P_M2] * G * p[P_VERT]
    # symmetric valve near null: p_a + p_b*(ab/aa)... solve pa*aa - pb*ab = load with pa + pb = ps + pt
    pa = (load + ab * (ps + pt)) / (aa + ab)
    pb = ps + pt - pa
    pa = min(max(pa, pt + 1e5), ps)
    pb = min(max(pb, pt + 1e5), ps)
    x[S_PA] = x[S_PVA] = pa
    x[S_PB] = x[S_PVB] = pb
    x[S_PS] = ps
    x[S_Y] = y_init
    x[S_T] = t0
    if p[P_M2] > 0:
        x[S_Y2] = y_init - p[P_M2] * G * p[P_VERT] / p[P_K2]
    return x


def simulate(rig: dict, eff: dict, sensors: dict, ctrl: dict, ref: np.ndarray, sup: np.ndarray,
             fs_hz: float, noise_seed: int, h_target: float = 25e-6, pre_s: float = 1.5, jac_every: int = 1) -> dict:
    """Run the closed loop. `sensors[ch]` (ch in CHANNELS, only measured ones) has the true sensor
    physics: lowpass_hz, delay_s, gain, offset, noise_std, quant, lo, hi. `ctrl`: type
    ('position_pff' | 'force_p'), gains, u_max_v; `eff` may hold valve_null_bias / valve_hysteresis
    and the physics entries read by build_params. Returns readings (true and measured), u, states."""
    ts = 1.0 / fs_hz
    n = len(ref)
    n_pre = int(round(pre_s * fs_hz))
    ntot = n + n_pre
    p = build_params(rig, eff, ts)
    act = active_states(p)
    nsub = max(1, int(math.ceil(ts / h_target)))
    s_tau = np.zeros(6); s_delay = np.zeros(6, dtype=np.int64); s_gain = np.ones(6); s_off = np.zeros(6)
    s_quant = np.zeros(6); s_lo = np.full(6, -np.inf); s_hi = np.full(6, np.inf)
    noise = np.zeros((6, ntot))
    rng = np.random.default_rng(noise_seed)
    for c, ch in enumerate(CHANNELS):
        s = sensors.get(ch)
        if not s:
            continue
        if s.get("lowpass_hz"):
            s_tau[c] = 1.0 / (2 * math.pi * s["lowpass_hz"])
        s_delay[c] = int(round(s.get("delay_s", 0.0) * fs_hz))
        s_gain[c] = s.get("gain", 1.0)
        s_off[c] = s.get("offset", 0.0)
        s_quant[c] = s.get("quant", 0.0)
        s_lo[c] = s.get("lo", -np.inf)
        s_hi[c] = s.get("hi", np.inf)
        if s.get("noise_std", 0.0) > 0:
            noise[c] = rng.normal(0.0, s["noise_std"], ntot)
    if ctrl["type"] == "position_pff":
        ctype, kp, kff = 0, ctrl["kp_v_per_m"], ctrl["kff_v_per_m_s"]
    else:
        ctype, kp, kff = 1, ctrl["kp_v_per_n"], 0.0
    x0 = initial_state(rig, p, ctrl.get("y_init", float(ref[0]) if ctype == 0 else rig["stroke_m"] / 2), -n_pre * ts)
    rd_true = np.zeros((6, ntot)); rd_meas = np.zeros((6, ntot)); u = np.zeros(ntot)
    states = np.zeros((ntot, N_S)); extra = np.zeros((ntot, 3))
    bias = eff.get("valve_null_bias", {}).get("bias_v", 0.0)
    play = eff.get("valve_hysteresis", {}).get("half_width_v", 0.0)
    done, n_retry = _simulate(p, x0, STATE_SCALE, act, nsub, int(jac_every), n_pre, np.ascontiguousarray(ref, dtype=float),
                     np.ascontiguousarray(sup, dtype=float), ctype, float(kp), float(kff), float(ctrl["u_max_v"]),
                     float(bias), float(play), s_tau, s_delay, s_gain, s_off, s_quant, s_lo, s_hi, noise,
                     rd_true, rd_meas, u, states, extra)
    sl = slice(n_pre, ntot)
    out = {
        "ok": bool(done == ntot),
        "n_done": int(done) - n_pre,
        "t": np.arange(n) * ts,
        "u": u[sl],
        "true": {ch: rd_true[c, sl] for c, ch in enumerate(CHANNELS)},
        "meas": {ch: rd_meas[c, sl] for c, ch in enumerate(CHANNELS)},
        "states": {nm: states[sl, i] for i, nm in enumerate(STATE_NAMES)},
        "p_s_valve": extra[sl, 0],
        "f_spec": extra[sl, 1],
        "u_valve": extra[sl, 2],
        "nsub": nsub,
        "step_retries": int(n_retry),
    }
    return out
