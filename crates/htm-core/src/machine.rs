//! The plant: valve + chambers + double-rod cylinder + friction + gravity + specimen spring +
//! end stops (thesis eq. 2.15-2.27 with the errata of NOTES.md), stepped one zero-order-hold
//! command sample at a time.
use crate::error::{Error, Result};
use crate::friction::Friction;
use crate::hydraulics::{orifice_flow, orifice_flow_ddp, smooth_opening, smooth_opening_dx, BulkModulus, ValveMap};
use crate::params::Params;
use crate::solver::{fd_jacobian, OdeSystem, Rodas4, Stats};

/// State vector layout.
pub const PA: usize = 0;
pub const PB: usize = 1;
pub const Y: usize = 2;
pub const V: usize = 3;
pub const SPOOL: usize = 4;
/// spool velocity [V/s] (second-order spool only)
pub const SPOOL_V: usize = 5;
/// command after the first-order lag that precedes a second-order spool [V]
pub const LAG: usize = 6;
pub const NX: usize = 7;

/// Width over which the specimen's closure corner is rounded [m] (keeps the force smooth for
/// the integrator; far from the corner the error is k_c*w^2/(4|dy|)).
pub const CLOSURE_SMOOTHING_M: f64 = 2.0e-5;

/// Default relative tolerance of the plant integrator.
pub const DEFAULT_RTOL: f64 = 1e-6;

/// What the sensors of the rig would read (ideal sensors), SI.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Outputs {
    /// piston position [m]
    pub y: f64,
    /// piston velocity [m/s]
    pub v: f64,
    /// chamber pressures, gauge [Pa]
    pub p_a: f64,
    pub p_b: f64,
    /// supply pressure at the valve, gauge [Pa]
    pub p_s: f64,
    /// specimen (load cell) force, tension positive [N]
    pub f: f64,
    /// spool position [V equivalent]
    pub spool: f64,
}

/// Plant equations with one held spool target.
#[derive(serde::Serialize, serde::Deserialize)] // engine snapshots (resume)
#[derive(Debug, Clone)]
pub struct Plant {
    pub p: Params,
    k_edge: f64,
    bulk: BulkModulus,
    friction: Friction,
    map: ValveMap,
    /// spool target for the current sample [V equivalent]
    pub target: f64,
}

impl Plant {
    pub fn new(p: Params) -> Result<Self> {
        p.validate()?;
        let bulk = BulkModulus {
            beta: p.bulk_modulus_pa,
            slope: p.bulk_modulus_slope,
            k1: p.eggerth_k1_per_pa,
            k2: p.eggerth_k2_per_pa,
            lambda: p.eggerth_lambda,
            air: p.air_fraction,
            p_atm: p.atmospheric_pressure_pa,
            p_cav: p.cavitation_pressure_pa,
        };
        let friction = Friction::from(&p);
        let map = ValveMap::new(&p.valve_map_command_v, &p.valve_map_spool_v);
        Ok(Plant { k_edge: p.valve_edge_coeff(), bulk, friction, map, target: 0.0, p })
    }

    /// Static part of the valve (amplifier clip, null bias, dead band, map, polarity):
    /// the spool position the command asks for. `backlash` is the play operator's memory.
    pub fn spool_target(&self, u: f64, backlash: &mut f64) -> f64 {
        let p = &self.p;
        let umax = p.valve_max_command_v;
        let mut c = u.clamp(-umax, umax) + p.valve_null_bias_v;
        let h = p.valve_hysteresis_half_width_v;
        if h > 0.0 {
            *backlash = backlash.clamp(c - h, c + h);
            c = *backlash;
        }
        let w = p.valve_deadband_half_width_v;
        if w > 0.0 {
            c = c.signum() * (c.abs() - w).max(0.0);
        }
        (p.valve_polarity * self.map.eval(c)).clamp(-umax, umax)
    }

    /// Metering-edge flows for spool `xs`: (P->A, A->T, P->B, B->T) openings.
    #[inline]
    fn openings(&self, xs: f64) -> (f64, f64) {
        let (xu, w) = (self.p.valve_underlap_v, self.p.valve_lap_smoothing_v);
        (smooth_opening(xu + xs, w), smooth_opening(xu - xs, w))
    }

    #[inline]
    fn edge(&self, a: f64, dp: f64) -> f64 {
        if self.p.valve_linear_flow > 0.5 {
            // flow proportional to opening at the nominal drop, no load-pressure feedback
            let dp0 = 0.5 * (self.p.supply_pressure_pa - self.p.tank_pressure_pa);
            self.k_edge * a * dp0.sqrt()
        } else {
            orifice_flow(self.k_edge, a, dp, self.p.valve_transition_dp_pa)
        }
    }

    /// Supply pressure at the valve: p_s0, or with sag the root of p_s = p_s0 - R*Q_in(p_s).
    fn supply(&self, open_pa: f64, open_pb: f64, pa: f64, pb: f64) -> f64 {
        let p = &self.p;
        let r = p.supply_resistance_pa_s_per_m3;
        if r <= 0.0 {
            return p.supply_pressure_pa;
        }
        let dpt = p.valve_transition_dp_pa;
        let mut ps = p.supply_pressure_pa;
        for _ in 0..4 {
            let q = self.edge(open_pa, ps - pa) + self.edge(open_pb, ps - pb);
            let dq = if p.valve_linear_flow > 0.5 {
                0.0
            } else {
                orifice_flow_ddp(self.k_edge, open_pa, ps - pa, dpt) + orifice_flow_ddp(self.k_edge, open_pb, ps - pb, dpt)
            };
            ps -= (ps - p.supply_pressure_pa + r * q) / (1.0 + r * dq);
        }
        ps
    }

    /// Specimen force, tension positive [N]: the specimen is stretched as y rises above its
    /// zero-force position and pulls the piston back down. Below the closure position the
    /// closure stiffness adds (bilinear spring, corner smoothed over `CLOSURE_SMOOTHING_M`).
    #[inline]
    pub fn specimen_force(&self, y: f64) -> f64 {
        let p = &self.p;
        crate::specimen_force::spring_force(p.specimen_stiffness_n_m, p.specimen_zero_force_position_m,
                                            p.specimen_closure_stiffness_n_m, p.specimen_closure_offset_m, y)
    }

    /// The band of positions of the bumps: Gaussian weight at `y` and its derivative in y.
    #[inline]
    fn band(&self, y: f64) -> (f64, f64) {
        let p = &self.p;
        if p.friction_bump_n == 0.0 && p.force_bump_n == 0.0 && p.damping_bump_n_s_m == 0.0 {
            return (0.0, 0.0);
        }
        let w = p.friction_bump_width_m;
        let z = (y - p.friction_bump_position_m) / w;
        let g = (-0.5 * z * z).exp();
        (g, -g * z / w)
    }

    /// Force of the bumps on the piston along +y [N] at position `y`, velocity `v`: the force
    /// bump, less the friction bump (Coulomb-like) and the damping bump (viscous).
    #[inline]
    fn bumps(&self, y: f64, v: f64) -> f64 {
        let (g, _) = self.band(y);
        if g == 0.0 {
            return 0.0;
        }
        let p = &self.p;
        g * (p.force_bump_n - p.friction_bump_n * self.friction.sign(v) - p.damping_bump_n_s_m * v)
    }

    /// d(specimen_force)/dy [N/m].
    #[inline]
    pub fn specimen_stiffness(&self, y: f64) -> f64 {
        let p = &self.p;
        let mut k = p.specimen_stiffness_n_m;
        if p.specimen_closure_stiffness_n_m > 0.0 {
            let x = p.specimen_zero_force_position_m + p.specimen_closure_offset_m - y;
            k += p.specimen_closure_stiffness_n_m * smooth_opening_dx(x, CLOSURE_SMOOTHING_M);
        }
        k
    }

    pub fn outputs(&self, x: &[f64; NX]) -> Outputs {
        let (o1, o2) = self.openings(x[SPOOL]);
        Outputs {
            y: x[Y],
            v: x[V],
            p_a: x[PA],
            p_b: x[PB],
            p_s: self.supply(o1, o2, x[PA], x[PB]),
            f: self.specimen_force(x[Y]),
            spool: x[SPOOL],
        }
    }

    /// The supply set-point p_s0 at which the supply reads `p_rest` with the spool at null and
    /// the chambers centred: with sag, the underlap's standing leakage already pulls the supply
    /// below its set-point (a record's supply level is what its gauge reads at rest).
    pub fn setpoint_for_rest(&self, p_rest: f64) -> f64 {
        let p = &self.p;
        if p.supply_resistance_pa_s_per_m3 <= 0.0 {
            return p_rest;
        }
        let (open_a, open_b) = self.openings(0.0);
        let dp = 0.5 * (p_rest - p.tank_pressure_pa);
        p_rest + p.supply_resistance_pa_s_per_m3 * (self.edge(open_a, dp) + self.edge(open_b, dp))
    }

    /// A state at rest at position `y`: chamber pressures centred between supply and tank and
    /// split so that the hydraulic force carries gravity and the specimen.
    pub fn rest_state(&self, y: f64) -> [f64; NX] {
        let p = &self.p;
        let load = p.moving_mass_kg * p.gravity_m_s2 + self.specimen_force(y);
        let mid = 0.5 * (p.supply_pressure_pa + p.tank_pressure_pa);
        let a = 0.5 * (p.area_a_m2 + p.area_b_m2);
        let half = 0.5 * load / a;
        let lo = p.tank_pressure_pa;
        let hi = p.supply_pressure_pa;
        [(mid + half).clamp(lo, hi), (mid - half).clamp(lo, hi), y, 0.0, 0.0, 0.0, 0.0]
    }

    /// Rates of the spool states (SPOOL, SPOOL_V, LAG) under spool target `target`: a first-order
    /// lag (`valve_tau_s`) and/or a second-order spool (`valve_natural_hz`, `valve_damping`) in
    /// series; with neither the spool follows the target at once (set by `Machine::step`).
    #[inline]
    fn spool_rates(&self, x: &[f64; NX], target: f64) -> (f64, f64, f64) {
        let p = &self.p;
        let tau = p.valve_tau_s;
        let wn = 2.0 * std::f64::consts::PI * p.valve_natural_hz;
        if wn > 0.0 {
            let (drive, dlag) = if tau > 0.0 { (x[LAG], (target - x[LAG]) / tau) } else { (target, 0.0) };
            (x[SPOOL_V], wn * wn * (drive - x[SPOOL]) - 2.0 * p.valve_damping * wn * x[SPOOL_V], dlag)
        } else if tau > 0.0 {
            ((target - x[SPOOL]) / tau, 0.0, 0.0)
        } else {
            (0.0, 0.0, 0.0)
        }
    }

    /// The spool states' exact transition over `dt` under a held target: x(t + dt) = phi x(t) +
    /// gamma target, states (SPOOL, SPOOL_V, LAG) — the exponential of the linear system,
    /// augmented with the held input, by scaling and squaring a Taylor series.
    pub fn spool_transition(&self, dt: f64) -> ([[f64; 3]; 3], [f64; 3]) {
        // columns of the augmented generator: d/dt of (spool, spool_v, lag, target)
        let mut a = [[0.0f64; 4]; 4];
        let unit = |i: usize| {
            let mut x = [0.0; NX];
            match i {
                0 => x[SPOOL] = 1.0,
                1 => x[SPOOL_V] = 1.0,
                2 => x[LAG] = 1.0,
                _ => {}
            }
            x
        };
        // column c of the spool block: its response to unit state c (c = 3: unit command)
        #[allow(clippy::needless_range_loop)] // writes column c of three rows: an index reads as the maths
        for c in 0..4 {
            let (d0, d1, d2) = self.spool_rates(&unit(c), if c == 3 { 1.0 } else { 0.0 });
            a[0][c] = d0 * dt;
            a[1][c] = d1 * dt;
            a[2][c] = d2 * dt;
        }
        let norm = a.iter().map(|r| r.iter().map(|v| v.abs()).sum::<f64>()).fold(0.0, f64::max);
        let squarings = if norm > 0.5 { (norm / 0.5).log2().ceil() as u32 } else { 0 };
        let scale = 0.5f64.powi(squarings as i32);
        let mul = |x: &[[f64; 4]; 4], y: &[[f64; 4]; 4]| {
            let mut z = [[0.0; 4]; 4];
            for i in 0..4 {
                for j in 0..4 {
                    z[i][j] = (0..4).map(|k| x[i][k] * y[k][j]).sum();
                }
            }
            z
        };
        let mut m = [[0.0; 4]; 4];
        for (i, row) in a.iter().enumerate() {
            for (j, v) in row.iter().enumerate() {
                m[i][j] = v * scale;
            }
        }
        // exp(m) = sum m^k / k!, k <= 12 (|m| <= 0.5: error below 1e-13)
        let mut e = [[0.0; 4]; 4];
        let mut term = [[0.0; 4]; 4];
        for i in 0..4 {
            e[i][i] = 1.0;
            term[i][i] = 1.0;
        }
        for k in 1..=12 {
            term = mul(&term, &m);
            for i in 0..4 {
                for j in 0..4 {
                    term[i][j] /= k as f64;
                    e[i][j] += term[i][j];
                }
            }
        }
        for _ in 0..squarings {
            e = mul(&e, &e);
        }
        ([[e[0][0], e[0][1], e[0][2]], [e[1][0], e[1][1], e[1][2]], [e[2][0], e[2][1], e[2][2]]], [e[0][3], e[1][3], e[2][3]])
    }

    /// True when the spool is a state (a lag or a second-order spool), not the target itself.
    #[inline]
    pub fn spool_has_dynamics(&self) -> bool {
        self.p.valve_tau_s > 0.0 || self.p.valve_natural_hz > 0.0
    }
}

impl Plant {
    /// State derivative under spool target `target` [V equivalent] (the held sample's input).
    #[inline(always)] // into the integrator's stage loop: its rates go straight to the stage (no store and reload)
    pub fn derivatives(&self, x: &[f64; NX], target: f64, dx: &mut [f64; NX]) {
        let p = &self.p;
        let (pa, pb, y, v, xs) = (x[PA], x[PB], x[Y], x[V], x[SPOOL]);
        // Valve (eq. 2.15-2.16, general underlapped form, NOTES item 4)
        let (open_pa, open_at) = self.openings(xs);
        let (open_pb, open_bt) = (open_at, open_pa);
        let ps = self.supply(open_pa, open_pb, pa, pb);
        let pt = p.tank_pressure_pa;
        let qa = self.edge(open_pa, ps - pa) - self.edge(open_at, pa - pt);
        let qb = self.edge(open_pb, ps - pb) - self.edge(open_bt, pb - pt);
        let q_leak = p.leakage_coeff_m3_per_s_pa * (pa - pb);
        // Chambers (eq. 2.20-2.22)
        let va = p.dead_volume_a_m3 + p.area_a_m2 * y.clamp(0.0, p.stroke_m);
        let vb = p.dead_volume_b_m3 + p.area_b_m2 * (p.stroke_m - y).clamp(0.0, p.stroke_m);
        dx[PA] = self.bulk.at(pa) / va * (qa - p.area_a_m2 * v - q_leak);
        dx[PB] = self.bulk.at(pb) / vb * (qb + p.area_b_m2 * v + q_leak);
        // Piston (eq. 2.23, 2.27)
        let f_h = p.area_a_m2 * pa - p.area_b_m2 * pb;
        let f_f = self.friction.force(v, pa + pb) - self.bumps(y, v);
        let f_g = p.moving_mass_kg * p.gravity_m_s2;
        let mut f_stop = 0.0;
        if y < 0.0 {
            f_stop = (-y * p.end_stop_stiffness_n_m - v * p.end_stop_damping_n_s_m).max(0.0);
        } else if y > p.stroke_m {
            f_stop = ((p.stroke_m - y) * p.end_stop_stiffness_n_m - v * p.end_stop_damping_n_s_m).min(0.0);
        }
        dx[Y] = v;
        dx[V] = (f_h - f_f - f_g - self.specimen_force(y) + f_stop) / p.moving_mass_kg;
        (dx[SPOOL], dx[SPOOL_V], dx[LAG]) = self.spool_rates(x, target);
    }
}

impl OdeSystem<NX> for Plant {
    /// The spool states (SPOOL, SPOOL_V, LAG): their rates depend on the held target and on
    /// themselves, never on the hydraulics.
    const DECOUPLED_TAIL: usize = NX - SPOOL;

    #[inline]
    fn rhs(&self, x: &[f64; NX], dx: &mut [f64; NX]) {
        self.derivatives(x, self.target, dx)
    }

    /// Analytic Jacobian (finite differences only with supply sag, whose p_s is implicit).
    fn jacobian(&self, x: &[f64; NX], f0: &[f64; NX], jac: &mut [[f64; NX]; NX]) -> u64 {
        let p = &self.p;
        if p.supply_resistance_pa_s_per_m3 > 0.0 {
            return fd_jacobian(self, x, f0, jac);
        }
        let (pa, pb, y, v, xs) = (x[PA], x[PB], x[Y], x[V], x[SPOOL]);
        let (xu, w) = (p.valve_underlap_v, p.valve_lap_smoothing_v);
        let (o1, o2) = (smooth_opening(xu + xs, w), smooth_opening(xu - xs, w));
        let (do1, do2) = (smooth_opening_dx(xu + xs, w), -smooth_opening_dx(xu - xs, w));
        let (ps, pt, k, dpt) = (p.supply_pressure_pa, p.tank_pressure_pa, self.k_edge, p.valve_transition_dp_pa);
        let linear = p.valve_linear_flow > 0.5;
        // flow per unit opening and its pressure derivative for one edge
        let per_open = |dp: f64| if linear { k * (0.5 * (ps - pt)).sqrt() } else { orifice_flow(k, 1.0, dp, dpt) };
        let ddp = |a: f64, dp: f64| if linear { 0.0 } else { orifice_flow_ddp(k, a, dp, dpt) };
        let (q_pa, q_at, q_pb, q_bt) = (per_open(ps - pa), per_open(pa - pt), per_open(ps - pb), per_open(pb - pt));
        let qa = o1 * q_pa - o2 * q_at;
        let qb = o2 * q_pb - o1 * q_bt;
        let dqa_dpa = -ddp(o1, ps - pa) - ddp(o2, pa - pt);
        let dqb_dpb = -ddp(o2, ps - pb) - ddp(o1, pb - pt);
        let dqa_dxs = q_pa * do1 - q_at * do2;
        let dqb_dxs = q_pb * do2 - q_bt * do1;
        let c = p.leakage_coeff_m3_per_s_pa;
        let ql = c * (pa - pb);
        let inside = y > 0.0 && y < p.stroke_m;
        let va = p.dead_volume_a_m3 + p.area_a_m2 * y.clamp(0.0, p.stroke_m);
        let vb = p.dead_volume_b_m3 + p.area_b_m2 * (p.stroke_m - y).clamp(0.0, p.stroke_m);
        let (dva, dvb) = if inside { (p.area_a_m2, -p.area_b_m2) } else { (0.0, 0.0) };
        let ((ba, dba), (bb, dbb)) = (self.bulk.at_and_slope(pa), self.bulk.at_and_slope(pb));
        let na = qa - p.area_a_m2 * v - ql;
        let nb = qb + p.area_b_m2 * v + ql;
        jac[PA] = [dba / va * na + ba / va * (dqa_dpa - c), ba / va * c, -ba * na / (va * va) * dva, -ba * p.area_a_m2 / va, ba / va * dqa_dxs, 0.0, 0.0];
        jac[PB] = [bb / vb * c, dbb / vb * nb + bb / vb * (dqb_dpb - c), -bb * nb / (vb * vb) * dvb, bb * p.area_b_m2 / vb, bb / vb * dqb_dxs, 0.0, 0.0];
        jac[Y] = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
        // friction derivatives
        let fr = &self.friction;
        let (s, ds) = (fr.sign(v), fr.sign_slope(v));
        let coulomb = if v >= 0.0 { fr.coulomb_pos_n } else { fr.coulomb_neg_n };
        let e = fr.static_n * (-v.abs() / fr.stribeck_m_s).exp();
        let level = coulomb + fr.pressure_coeff_n_per_pa * (pa + pb) + e;
        let dff_dv = fr.viscous_n_s_m + ds * level - s * e * v.signum() / fr.stribeck_m_s;
        let dff_dpsum = fr.pressure_coeff_n_per_pa * s;
        // the bumps enter as a negative friction: -g(y) (F_f - F_c s - c v)
        let (g, dg) = self.band(y);
        let dff_dv = dff_dv + g * (p.friction_bump_n * ds + p.damping_bump_n_s_m);
        let dff_dy = -dg * (p.force_bump_n - p.friction_bump_n * s - p.damping_bump_n_s_m * v);
        let (mut dstop_dy, mut dstop_dv) = (0.0, 0.0);
        if (y < 0.0 && -y * p.end_stop_stiffness_n_m - v * p.end_stop_damping_n_s_m > 0.0)
            || (y > p.stroke_m && (p.stroke_m - y) * p.end_stop_stiffness_n_m - v * p.end_stop_damping_n_s_m < 0.0)
        {
            dstop_dy = -p.end_stop_stiffness_n_m;
            dstop_dv = -p.end_stop_damping_n_s_m;
        }
        let m = p.moving_mass_kg;
        jac[V] = [
            (p.area_a_m2 - dff_dpsum) / m,
            (-p.area_b_m2 - dff_dpsum) / m,
            (-self.specimen_stiffness(y) - dff_dy + dstop_dy) / m,
            (-dff_dv + dstop_dv) / m,
            0.0,
            0.0,
            0.0,
        ];
        jac[SPOOL] = [0.0; NX];
        jac[SPOOL_V] = [0.0; NX];
        jac[LAG] = [0.0; NX];
        let (tau, wn) = (p.valve_tau_s, 2.0 * std::f64::consts::PI * p.valve_natural_hz);
        if wn > 0.0 {
            jac[SPOOL][SPOOL_V] = 1.0;
            jac[SPOOL_V][SPOOL] = -wn * wn;
            jac[SPOOL_V][SPOOL_V] = -2.0 * p.valve_damping * wn;
            if tau > 0.0 {
                jac[SPOOL_V][LAG] = wn * wn;
                jac[LAG][LAG] = -1.0 / tau;
            }
        } else if tau > 0.0 {
            jac[SPOOL][SPOOL] = -1.0 / tau;
        }
        let _ = f0;
        0
    }

    fn error_weights(&self) -> ([f64; NX], [f64; NX]) {
        // Positions are judged absolutely (the offset of y says nothing about force accuracy).
        ([1.0, 1.0, 0.0, 1.0, 1.0, 1.0, 1.0], [1.0e5, 1.0e5, 1.0e-3, 1.0e-2, 1.0, 1.0e3, 1.0])
    }

    /// The spool drives the flows and is linear: its own transient (up to kHz for a fast valve,
    /// restarted by every command sample) is judged through the pressures it drives.
    fn error_checked(&self) -> [bool; NX] {
        let spool = !self.spool_has_dynamics();
        [true, true, true, true, spool, false, false]
    }
}

/// Number of hydraulic and mechanical states (p_a, p_b, y, v: the first of the layout).
const NH: usize = 4;

/// The plant with a static valve (no lag, no spool dynamics): the spool is the held target, an
/// input rather than a state, so the stiff integrator works on (p_a, p_b, y, v) alone — a 4×4
/// factorisation and solves instead of 7×7 ones whose spool rows are empty. Steps, error norm
/// and result are those of the 7-state form: its spool rows stay zero through every stage
/// (their rate is zero and their Jacobian rows are empty), so they add nothing but work.
struct HeldSpool<'a> {
    plant: &'a Plant,
    /// the full state: the spool entries held, the first `NH` replaced by the integrator's
    x: [f64; NX],
}

impl HeldSpool<'_> {
    #[inline]
    fn full(&self, x: &[f64; NH]) -> [f64; NX] {
        let mut full = self.x;
        full[..NH].copy_from_slice(x);
        full
    }
}

impl OdeSystem<NH> for HeldSpool<'_> {
    #[inline]
    fn rhs(&self, x: &[f64; NH], dx: &mut [f64; NH]) {
        let mut d = [0.0; NX];
        self.plant.derivatives(&self.full(x), self.plant.target, &mut d);
        dx.copy_from_slice(&d[..NH]);
    }

    fn jacobian(&self, x: &[f64; NH], f0: &[f64; NH], jac: &mut [[f64; NH]; NH]) -> u64 {
        if self.plant.p.supply_resistance_pa_s_per_m3 > 0.0 {
            return fd_jacobian(self, x, f0, jac);
        }
        let mut j = [[0.0; NX]; NX];
        self.plant.jacobian(&self.full(x), &[0.0; NX], &mut j);
        for (row, full) in jac.iter_mut().zip(&j) {
            row.copy_from_slice(&full[..NH]);
        }
        0
    }

    fn error_weights(&self) -> ([f64; NH], [f64; NH]) {
        let (rel, scale) = self.plant.error_weights();
        let mut out = ([0.0; NH], [0.0; NH]);
        out.0.copy_from_slice(&rel[..NH]);
        out.1.copy_from_slice(&scale[..NH]);
        out
    }

    /// The held spool counts in the norm as the 7-state form's checked spool (error zero).
    fn error_count(&self) -> usize {
        self.plant.error_count()
    }
}

/// A plant with its state, integrator and valve memory: the object a control loop steps.
#[derive(serde::Serialize, serde::Deserialize)] // engine snapshots (resume)
#[derive(Debug, Clone)]
pub struct Machine {
    pub plant: Plant,
    pub x: [f64; NX],
    pub t: f64,
    pub solver: Rodas4,
    backlash: f64,
    /// the spool's exact transition for the last `step_valve` period (dt, phi, gamma)
    #[serde(skip)]
    valve_step: Option<(f64, [[f64; 3]; 3], [f64; 3])>,
}

impl Machine {
    /// A machine at rest at mid-stroke (or the specimen's zero-force position when one is fitted).
    pub fn new(p: Params) -> Result<Self> {
        let plant = Plant::new(p)?;
        let y0 = if plant.p.specimen_stiffness_n_m > 0.0 { plant.p.specimen_zero_force_position_m } else { 0.5 * plant.p.stroke_m };
        let x = plant.rest_state(y0);
        Ok(Machine { plant, x, t: 0.0, solver: Rodas4::new(DEFAULT_RTOL), backlash: 0.0, valve_step: None })
    }

    pub fn with_rtol(mut self, rtol: f64) -> Result<Self> {
        if !(rtol.is_finite() && rtol > 0.0 && rtol < 1.0) {
            return Err(Error::Parameter { field: "rtol".into(), value: rtol, allowed: "(0, 1)".into() });
        }
        self.solver.rtol = rtol;
        Ok(self)
    }

    /// Replace the state; rejects non-finite values and negative absolute pressures.
    pub fn set_state(&mut self, x: [f64; NX]) -> Result<()> {
        let names = ["p_a", "p_b", "y", "v", "spool", "spool velocity", "lagged command"];
        for (i, v) in x.iter().enumerate() {
            if !v.is_finite() {
                return Err(Error::Input(format!("state `{}` is {v}", names[i])));
            }
        }
        for i in [PA, PB] {
            if x[i] + self.plant.p.atmospheric_pressure_pa < 0.0 {
                return Err(Error::Input(format!("state `{}` = {} Pa is below absolute zero", names[i], x[i])));
            }
        }
        self.x = x;
        Ok(())
    }

    /// Apply command `u` [V] held for `dt` [s]; returns the sensor readings at the end.
    pub fn step(&mut self, u: f64, dt: f64) -> Result<Outputs> {
        if !u.is_finite() {
            return Err(Error::Input(format!("valve command is {u} at t = {:.6} s", self.t)));
        }
        if !(dt.is_finite() && dt > 0.0) {
            return Err(Error::Input(format!("time step dt = {dt} s must be > 0")));
        }
        self.plant.target = self.plant.spool_target(u, &mut self.backlash);
        if !self.plant.spool_has_dynamics() {
            self.x[SPOOL] = self.plant.target;
        }
        if self.plant.spool_has_dynamics() {
            self.solver.advance(&self.plant, &mut self.x, dt)?;
        } else {
            let mut x = [0.0; NH];
            x.copy_from_slice(&self.x[..NH]);
            self.solver.advance(&HeldSpool { plant: &self.plant, x: self.x }, &mut x, dt)?;
            self.x[..NH].copy_from_slice(&x);
        }
        self.t += dt;
        Ok(self.outputs())
    }

    pub fn outputs(&self) -> Outputs {
        self.plant.outputs(&self.x)
    }

    /// [`step`](Self::step) for this machine and, in lockstep, for `followers`: machines whose
    /// parameters differ slightly from its own (the finite-difference neighbours of a fit's
    /// Jacobian). A follower takes this machine's accepted step sizes with its own rates and
    /// Jacobian (`Rodas4::follow`): no step size that differs from its neighbour's for
    /// reasons of step-size control alone (a step that misses the tolerance for the follower is
    /// crossed with its own control). One whose spool form differs (a lag switched on from zero)
    /// steps alone.
    /// A follower that cannot be carried is left with a non-finite state (the caller checks).
    pub fn step_lockstep(&mut self, followers: &mut [&mut Machine], u: f64, dt: f64) -> Result<Outputs> {
        if !u.is_finite() {
            return Err(Error::Input(format!("valve command is {u} at t = {:.6} s", self.t)));
        }
        if !(dt.is_finite() && dt > 0.0) {
            return Err(Error::Input(format!("time step dt = {dt} s must be > 0")));
        }
        let dynamic = self.plant.spool_has_dynamics();
        let mut lock = Vec::with_capacity(followers.len());
        for (i, f) in followers.iter_mut().enumerate() {
            if f.plant.spool_has_dynamics() != dynamic {
                if f.step(u, dt).is_err() {
                    f.x = [f64::NAN; NX];
                }
                continue;
            }
            f.plant.target = f.plant.spool_target(u, &mut f.backlash);
            if !dynamic {
                f.x[SPOOL] = f.plant.target;
            }
            f.t += dt;
            lock.push(i);
        }
        self.plant.target = self.plant.spool_target(u, &mut self.backlash);
        let Machine { plant, solver, x, .. } = self;
        if dynamic {
            solver.advance_with(&*plant, x, dt, |h| {
                for &i in &lock {
                    let f = &mut *followers[i];
                    f.solver.follow(&f.plant, &mut f.x, h);
                }
            })?;
        } else {
            x[SPOOL] = plant.target;
            let mut xh = [0.0; NH];
            xh.copy_from_slice(&x[..NH]);
            solver.advance_with(&HeldSpool { plant, x: *x }, &mut xh, dt, |h| {
                for &i in &lock {
                    let f = &mut *followers[i];
                    let mut fx = [0.0; NH];
                    fx.copy_from_slice(&f.x[..NH]);
                    f.solver.follow(&HeldSpool { plant: &f.plant, x: f.x }, &mut fx, h);
                    f.x[..NH].copy_from_slice(&fx);
                }
            })?;
            x[..NH].copy_from_slice(&xh);
        }
        self.t += dt;
        Ok(self.outputs())
    }


    /// Advance only the valve (its play memory and spool states) under command `u` [V] held for
    /// `dt` [s]; the hydraulic and mechanical states stay (the caller sets them). The spool is
    /// linear and not acted on by the hydraulics, so this is the spool of a whole simulation,
    /// stepped exactly (zero-order hold).
    pub fn step_valve(&mut self, u: f64, dt: f64) {
        let target = self.plant.spool_target(if u.is_finite() { u } else { 0.0 }, &mut self.backlash);
        self.plant.target = target;
        if !self.plant.spool_has_dynamics() {
            self.x[SPOOL] = target;
        } else {
            let (phi, gamma) = match self.valve_step {
                Some((h, phi, gamma)) if h == dt => (phi, gamma),
                _ => {
                    let (phi, gamma) = self.plant.spool_transition(dt);
                    self.valve_step = Some((dt, phi, gamma));
                    (phi, gamma)
                }
            };
            let x0 = [self.x[SPOOL], self.x[SPOOL_V], self.x[LAG]];
            for (i, j) in [SPOOL, SPOOL_V, LAG].into_iter().enumerate() {
                self.x[j] = (0..3).map(|c| phi[i][c] * x0[c]).sum::<f64>() + gamma[i] * target;
            }
        }
        self.t += dt;
    }

    pub fn stats(&self) -> Stats {
        self.solver.stats
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rest_setpoint_makes_a_sagging_supply_read_its_level_at_rest() {
        let mut p = Params::base();
        p.supply_resistance_pa_s_per_m3 = 1e10;
        p.gravity_m_s2 = 0.0;
        let mut plant = Plant::new(p.clone()).unwrap();
        let x = plant.rest_state(0.1);
        let sagged = plant.outputs(&x).p_s;
        assert!(sagged < p.supply_pressure_pa - 1e4, "the underlap's leakage sags the supply: {sagged}");
        plant.p.supply_pressure_pa = plant.setpoint_for_rest(p.supply_pressure_pa);
        assert!((plant.outputs(&x).p_s - p.supply_pressure_pa).abs() < 1e3, "{}", plant.outputs(&x).p_s);
        p.supply_resistance_pa_s_per_m3 = 0.0;
        assert_eq!(Plant::new(p.clone()).unwrap().setpoint_for_rest(1.5e7), 1.5e7);
    }

    #[test]
    fn the_spool_transition_is_the_exact_step_of_a_lag_and_a_second_order_spool() {
        let mut p = Params::base();
        p.valve_tau_s = 0.004;
        p.valve_natural_hz = 150.0;
        p.valve_damping = 0.6;
        let plant = Plant::new(p).unwrap();
        let dt = 2e-3;
        let (phi, gamma) = plant.spool_transition(dt);
        // reference: many tiny RK4 steps of the same linear rates
        let mut x = [0.0; NX];
        (x[SPOOL], x[SPOOL_V], x[LAG]) = (0.2, -30.0, 0.5);
        let x0 = [x[SPOOL], x[SPOOL_V], x[LAG]];
        let n = 20000;
        let h = dt / n as f64;
        for _ in 0..n {
            let f = |x: &[f64; NX]| plant.spool_rates(x, 1.3);
            let k1 = f(&x);
            let mut y = x;
            (y[SPOOL], y[SPOOL_V], y[LAG]) = (x[SPOOL] + 0.5 * h * k1.0, x[SPOOL_V] + 0.5 * h * k1.1, x[LAG] + 0.5 * h * k1.2);
            let k2 = f(&y);
            (y[SPOOL], y[SPOOL_V], y[LAG]) = (x[SPOOL] + 0.5 * h * k2.0, x[SPOOL_V] + 0.5 * h * k2.1, x[LAG] + 0.5 * h * k2.2);
            let k3 = f(&y);
            (y[SPOOL], y[SPOOL_V], y[LAG]) = (x[SPOOL] + h * k3.0, x[SPOOL_V] + h * k3.1, x[LAG] + h * k3.2);
            let k4 = f(&y);
            x[SPOOL] += h / 6.0 * (k1.0 + 2.0 * k2.0 + 2.0 * k3.0 + k4.0);
            x[SPOOL_V] += h / 6.0 * (k1.1 + 2.0 * k2.1 + 2.0 * k3.1 + k4.1);
            x[LAG] += h / 6.0 * (k1.2 + 2.0 * k2.2 + 2.0 * k3.2 + k4.2);
        }
        for (i, j) in [SPOOL, SPOOL_V, LAG].into_iter().enumerate() {
            let exact = (0..3).map(|c| phi[i][c] * x0[c]).sum::<f64>() + gamma[i] * 1.3;
            assert!((exact - x[j]).abs() < 1e-9 * x[j].abs().max(1.0), "state {j}: {exact} vs {}", x[j]);
        }
    }

    fn check(p: Params, states: &[[f64; NX]], target: f64) {
        let mut plant = Plant::new(p).unwrap();
        plant.target = target;
        for x in states {
            let mut f0 = [0.0; NX];
            plant.rhs(x, &mut f0);
            let (mut ja, mut jf) = ([[0.0; NX]; NX], [[0.0; NX]; NX]);
            plant.jacobian(x, &f0, &mut ja);
            // central differences as the yardstick
            for j in 0..NX {
                let h = 1e-6 * x[j].abs().max([1e3, 1e3, 1e-6, 1e-6, 1e-6, 1e-3, 1e-6][j]);
                let (mut xp, mut xm) = (*x, *x);
                xp[j] += h;
                xm[j] -= h;
                let (mut fp, mut fm) = ([0.0; NX], [0.0; NX]);
                plant.rhs(&xp, &mut fp);
                plant.rhs(&xm, &mut fm);
                for i in 0..NX {
                    jf[i][j] = (fp[i] - fm[i]) / (2.0 * h);
                }
            }
            for i in 0..NX {
                let row_scale = jf[i].iter().map(|v| v.abs()).fold(0.0, f64::max).max(1e-9);
                for j in 0..NX {
                    assert!((ja[i][j] - jf[i][j]).abs() <= 1e-4 * jf[i][j].abs() + 1e-8 * row_scale,
                        "d f{i}/d x{j}: analytic {} vs numeric {} at {x:?}", ja[i][j], jf[i][j]);
                }
            }
        }
    }

    #[test]
    fn analytic_jacobian_matches_differences_with_every_effect() {
        let states = [
            [1.35e7, 5.5e6, 0.1002, 3e-3, 0.02, 30.0, 0.05],
            [9.5e6, 9.4e6, 0.05, -0.2, -1.3, -200.0, -1.1],
            [1.8e7, 2e5, 0.19, 0.45, 4.0, 0.0, 3.0],
            [5e4, 1.85e7, 0.01, -2e-4, -0.01, 5.0, 0.0],
        ];
        let mut p = Params { specimen_stiffness_n_m: 1.04e8, ..Default::default() };
        check(p.clone(), &states, 0.3);
        p.valve_tau_s = 0.005;
        p.leakage_coeff_m3_per_s_pa = 1e-11;
        p.friction_coulomb_pos_n = 900.0;
        p.friction_coulomb_neg_n = 600.0;
        p.friction_pressure_coeff_n_per_pa = 1e-5;
        p.air_fraction = 0.01;
        p.specimen_closure_stiffness_n_m = 5e7;
        p.specimen_closure_offset_m = 2e-4;
        p.friction_bump_n = 300.0;
        p.friction_bump_position_m = 0.052;
        p.force_bump_n = -200.0;
        p.damping_bump_n_s_m = 3e4;
        check(p.clone(), &states, -0.7);
        p.valve_natural_hz = 120.0;
        p.valve_damping = 0.6;
        p.bulk_modulus_slope = 7.0;
        check(p.clone(), &states, 0.4);
        p.valve_tau_s = 0.0;
        check(p.clone(), &states, -0.2);
        p.valve_linear_flow = 1.0;
        p.eggerth_k1_per_pa = 1.0 / 1.6e9;
        p.eggerth_k2_per_pa = 1e-10;
        p.eggerth_lambda = 1.0;
        check(p, &states, 1.1);
    }
}
