//! Controllers that compute one valve command per sample from the measurements.
use crate::error::{Error, Result};
use crate::machine::Outputs;

/// A sampled control law.
#[derive(Debug, Clone, PartialEq)]
pub enum Controller {
    /// Position P with velocity feed-forward (thesis 4.1; DATA_FORMAT `position_pff`):
    /// u[k] = clip(kp*(r[k]-y[k]) + kff*(r[k+1]-r[k])/Ts, -u_max, u_max)
    PositionPff { kp_v_per_m: f64, kff_v_per_m_s: f64, u_max_v: f64 },
    /// Fixed-gain force P (the thesis's comparison case): u[k] = clip(kp*(r[k]-f[k]))
    ForceP { kp_v_per_n: f64, u_max_v: f64 },
}

impl Controller {
    pub fn validate(&self) -> Result<()> {
        let (gains, u_max): (&[f64], f64) = match self {
            Controller::PositionPff { kp_v_per_m, kff_v_per_m_s, u_max_v } => (&[*kp_v_per_m, *kff_v_per_m_s][..], *u_max_v),
            Controller::ForceP { kp_v_per_n, u_max_v } => (&[*kp_v_per_n][..], *u_max_v),
        };
        if gains.iter().any(|g| !g.is_finite()) {
            return Err(Error::Parameter { field: "controller gain".into(), value: f64::NAN, allowed: "finite".into() });
        }
        if !(u_max.is_finite() && u_max > 0.0) {
            return Err(Error::Parameter { field: "u_max_v".into(), value: u_max, allowed: "(0, inf) V".into() });
        }
        Ok(())
    }

    /// Command for sample k from the reference now (`r`), next (`r_next`) and the measurement.
    pub fn command(&self, r: f64, r_next: f64, ts: f64, m: &Outputs) -> f64 {
        match *self {
            Controller::PositionPff { kp_v_per_m, kff_v_per_m_s, u_max_v } => {
                (kp_v_per_m * (r - m.y) + kff_v_per_m_s * (r_next - r) / ts).clamp(-u_max_v, u_max_v)
            }
            Controller::ForceP { kp_v_per_n, u_max_v } => (kp_v_per_n * (r - m.f)).clamp(-u_max_v, u_max_v),
        }
    }
}

/// Force controllers of the fatigue engine: one command per sample from the cyclic setpoint
/// (mean, amplitude, waveform phase) and the measured force.
#[derive(serde::Serialize, serde::Deserialize)] // engine snapshots (resume)
#[derive(Debug, Clone)]
pub enum ForceLoop {
    /// Fixed-gain force P (thesis 4.1, Fig. 4.6–4.8): u = kp·(r − f) + u_offset, where r is the
    /// waveform setpoint and `u_offset_v` an optional fixed null compensation (the thesis's
    /// normalised plant has no null offset; the real valve's null is −0.115 V).
    ForceP { kp_v_per_n: f64, u_offset_v: f64, u_max_v: f64 },
    /// The demodulation amplitude/mean controller (thesis 4.2).
    Demod(Demod),
}

/// Per-sample inputs of a force loop.
#[derive(Debug, Clone, Copy)]
pub struct Setpoint {
    /// force mid-point (Fmax + Fmin)/2 now and at the next sample [N]
    pub mid_n: f64,
    pub mid_next_n: f64,
    /// force half-range (Fmax − Fmin)/2 [N]
    pub amp_n: f64,
    /// unit waveform value s(φ_k) and s(φ_{k+1})
    pub s: f64,
    pub s_next: f64,
    /// sin and cos of 2πφ_k (the demodulation references)
    pub sin: f64,
    pub cos: f64,
}

impl ForceLoop {
    #[inline]
    pub fn command(&mut self, sp: &Setpoint, f: f64) -> f64 {
        match self {
            ForceLoop::ForceP { kp_v_per_n, u_offset_v, u_max_v } => {
                let r = sp.mid_n + sp.amp_n * sp.s;
                (*kp_v_per_n * (r - f) + *u_offset_v).clamp(-*u_max_v, *u_max_v)
            }
            ForceLoop::Demod(d) => d.command(sp, f),
        }
    }
    /// (amplitude-loop state, mean-loop state) for the per-cycle table: u1 and u2 [V] for the
    /// demodulation controller; (0, u_offset) for force P.
    pub fn summary(&self) -> (f64, f64, f64, f64) {
        match self {
            ForceLoop::ForceP { u_offset_v, .. } => (0.0, *u_offset_v, f64::NAN, f64::NAN),
            ForceLoop::Demod(d) => (d.u1_total, d.u2, d.theta1_hat, d.theta2_hat),
        }
    }
    /// Tell the controller that the plant's force gain was scaled by `ratio` (new/old K_sp) by a
    /// cycle jump, so it carries its converged state across (u1 ∝ 1/gain).
    pub fn rescale_gain(&mut self, ratio: f64) {
        if let ForceLoop::Demod(d) = self {
            d.u1 = d.u1_total / ratio - d.u1_ff;
        }
    }
}

/// Gains of the demodulation controller, derived from the plant (see `DemodGains::design`).
#[derive(serde::Serialize, serde::Deserialize)] // engine snapshots (resume)
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DemodGains {
    /// plant force gain g = K_sp·k_v [N/s per V] (negative for the thesis valve's polarity)
    pub plant_gain_n_per_s_v: f64,
    /// integral gain of the amplitude loop [V/(N·s)]
    pub k1: f64,
    /// proportional and integral gains of the mean loop [V/N], [V/(N·s)]
    pub kp2: f64,
    pub ki2: f64,
    /// test frequency [Hz] and control period [s]
    pub frequency_hz: f64,
    pub ts_s: f64,
    /// samples per cycle of the one-cycle moving averages
    pub window: usize,
}

impl DemodGains {
    /// The gain rule. Averaged over a cycle, the plant from valve command to force is an
    /// integrator ḟ = g·(u − u_null) with g = K_sp·k_v (thesis 4.2: ẏ = −0.07·K_sp·u; k_v is the
    /// valve's small-signal velocity gain, signed by its polarity; the stiffness passed in is the
    /// specimen in series with the oil column, which the thesis's rigid model leaves out and
    /// which on the thesis rig is ~40 % of K_sp). With the carrier
    /// u1·ṡ(φ)/ω (u1·cos ωt for a sine, NOTES item 5) the force amplitude is θ1 = g·u1/ω, and the
    /// mean obeys θ̇2 = g·(u2 − u_null). Estimates are one-cycle moving averages (the thesis's
    /// high-pass, demodulation with sin and cos, low-pass — a boxcar over exactly one period has
    /// zeros at ω and 2ω, so no ripple reaches the loops; its lag is T/2 = 1/(2f)).
    ///
    /// * amplitude loop (integral, as the thesis): loop gain k1·g/ω/s, crossover
    ///   ω1 = `c1`·f rad/s → k1 = ω1·ω/g. With c1 = 0.5 (time constant 2 cycles) the T/2 lag costs
    ///   0.25 rad: phase margin ≈ 76°; a K_sp falling to 50 % halves ω1 and stays stable; a valve
    ///   gain twice the nominal one leaves ≈ 60°.
    /// * mean loop: PI (the thesis's P cannot absorb the valve's null offset: a P loop leaves a
    ///   steady error u_null/k2) on the type-1 plant, i.e. a symmetric-optimum type-2 loop:
    ///   crossover ω2 = `c2`·f, kp2 = ω2/g, integral time T_i = a²/ω2... here T_i = 3/ω2,
    ///   ki2 = kp2/T_i → phase margin atan(3) − ω2·T/2 ≈ 72° − 14° = 58° at c2 = 0.5.
    ///   A feed-forward of the mean setpoint's rate (ṁ/g) removes the ramp lag of the smooth start.
    /// Both gains carry the sign of g, so the rule needs no hand tuning for polarity either.
    pub fn design(specimen_stiffness_n_m: f64, velocity_gain_m_s_per_v: f64, frequency_hz: f64, control_rate_hz: f64) -> Result<Self> {
        let g = specimen_stiffness_n_m * velocity_gain_m_s_per_v;
        if !(g.is_finite() && g != 0.0) {
            return Err(Error::Parameter { field: "controller.velocity_gain_m_s_per_v".into(), value: velocity_gain_m_s_per_v, allowed: "non-zero, finite".into() });
        }
        let window = (control_rate_hz / frequency_hz).round();
        if !(window >= 16.0) {
            return Err(Error::Parameter { field: "control_rate_hz".into(), value: control_rate_hz, allowed: format!("≥ 16 samples per cycle: ≥ {} Hz at {frequency_hz} Hz", 16.0 * frequency_hz) });
        }
        let w = 2.0 * std::f64::consts::PI * frequency_hz;
        let (c1, c2) = (0.5, 0.5);
        let w1 = c1 * frequency_hz;
        let w2 = c2 * frequency_hz;
        let kp2 = w2 / g;
        Ok(DemodGains { plant_gain_n_per_s_v: g, k1: w1 * w / g, kp2, ki2: kp2 * w2 / 3.0, frequency_hz, ts_s: 1.0 / control_rate_hz, window: window as usize })
    }
}

/// Crossover of the static (preload) force PI [rad/s]: well below the oil-column resonance
/// (≈ 1700 rad/s with a 1.04e8 N/m specimen) and the 1 kHz sampling, fast enough to hold the
/// force against the valve's null drift while the mean ramps up.
pub const STATIC_CROSSOVER_RAD_S: f64 = 150.0;

/// The demodulation controller's state. Allocation happens once (the moving-average rings).
#[derive(serde::Serialize, serde::Deserialize)] // engine snapshots (resume)
#[derive(Debug, Clone)]
pub struct Demod {
    pub gains: DemodGains,
    pub u_max_v: f64,
    /// amplitude-loop integrator (carrier amplitude) and mean-loop output [V]
    pub u1: f64,
    pub u2: f64,
    i2: f64,
    /// carrier amplitude last applied (integrator + feed-forward) and its feed-forward part [V]
    pub u1_total: f64,
    u1_ff: f64,
    /// static hold (amplitude setpoint 0): PI on the instantaneous force error, whose integrator
    /// converges to the valve's null and seeds the mean loop when cycling starts
    static_mode: bool,
    /// estimates of the force amplitude (fundamental) and mean [N]
    pub theta1_hat: f64,
    pub theta2_hat: f64,
    /// fundamental magnitude and mean of the unit waveform (targets: amp·b1, mid + amp·s_mean)
    b1: f64,
    s_mean: f64,
    ring_f: Vec<f64>,
    ring_i: Vec<f64>,
    ring_q: Vec<f64>,
    sum_f: f64,
    sum_i: f64,
    sum_q: f64,
    pos: usize,
    filled: usize,
}

impl Demod {
    /// A controller with `gains` for a waveform with unit-shape (mean, fundamental) `stats`,
    /// starting from a measured force `f0` (the estimates start there, integrators at zero).
    pub fn new(gains: DemodGains, stats: (f64, f64), u_max_v: f64, f0: f64) -> Self {
        let n = gains.window;
        Demod {
            gains, u_max_v, u1: 0.0, u2: 0.0, i2: 0.0, u1_total: 0.0, u1_ff: 0.0, static_mode: true, theta1_hat: 0.0, theta2_hat: f0, s_mean: stats.0, b1: stats.1,
            ring_f: vec![f0; n], ring_i: vec![0.0; n], ring_q: vec![0.0; n],
            sum_f: f0 * n as f64, sum_i: 0.0, sum_q: 0.0, pos: 0, filled: 0,
        }
    }

    #[inline]
    fn command(&mut self, sp: &Setpoint, f: f64) -> f64 {
        let g = &self.gains;
        let n = g.window as f64;
        // mean estimate: one-cycle moving average (low-pass)
        self.sum_f += f - self.ring_f[self.pos];
        self.ring_f[self.pos] = f;
        self.theta2_hat = self.sum_f / n;
        // high-pass z = y − mean, demodulated with sin and cos, one-cycle averages
        let z = f - self.theta2_hat;
        let (zi, zq) = (2.0 * z * sp.sin, 2.0 * z * sp.cos);
        self.sum_i += zi - self.ring_i[self.pos];
        self.sum_q += zq - self.ring_q[self.pos];
        self.ring_i[self.pos] = zi;
        self.ring_q[self.pos] = zq;
        self.pos = if self.pos + 1 == g.window { 0 } else { self.pos + 1 };
        self.filled = (self.filled + 1).min(g.window);
        self.theta1_hat = ((self.sum_i / n).powi(2) + (self.sum_q / n).powi(2)).sqrt();
        let w = 2.0 * std::f64::consts::PI * g.frequency_hz;
        if sp.amp_n <= 0.0 {
            // static hold / preload: fast PI on the force error (crossover STATIC_CROSSOVER)
            let kp = STATIC_CROSSOVER_RAD_S / g.plant_gain_n_per_s_v;
            let e = sp.mid_n - f;
            self.i2 += g.ts_s * kp * STATIC_CROSSOVER_RAD_S / 4.0 * e;
            self.static_mode = true;
            self.u1 = 0.0;
            self.u1_total = 0.0;
            self.u2 = kp * e + self.i2;
            return self.u2.clamp(-self.u_max_v, self.u_max_v);
        }
        self.static_mode = false;
        // amplitude loop: integral; the feed-forward amp·ω/g seeds it (u1 is the integrator)
        let u1_ff = sp.amp_n * w / g.plant_gain_n_per_s_v;
        if self.filled == g.window {
            let e1 = sp.amp_n * self.b1 - self.theta1_hat;
            self.u1 += g.ts_s * g.k1 * e1;
        }
        let u1 = self.u1 + u1_ff;
        self.u1_total = u1;
        self.u1_ff = u1_ff;
        // mean loop: PI + setpoint-rate feed-forward
        let e2 = sp.mid_n + sp.amp_n * self.s_mean - self.theta2_hat;
        self.i2 += g.ts_s * g.ki2 * e2;
        let ff2 = (sp.mid_next_n - sp.mid_n) / (g.ts_s * g.plant_gain_n_per_s_v);
        self.u2 = g.kp2 * e2 + self.i2 + ff2;
        // carrier: u1·ṡ/ω over the sample (= u1·cos ωt for the sine) so that an integrator
        // plant moves the force by exactly (g·u1/ω)·Δs
        let carrier = (sp.s_next - sp.s) / (w * g.ts_s);
        (u1 * carrier + self.u2).clamp(-self.u_max_v, self.u_max_v)
    }
}
