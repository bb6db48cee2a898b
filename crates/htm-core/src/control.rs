//! Controllers that compute one valve command per sample from the measurements.
use crate::error::{Error, Result};
use crate::machine::Outputs;

pub mod limits;

/// A sampled control law.
#[derive(serde::Serialize, serde::Deserialize)] // engine snapshots (resume)
#[derive(Debug, Clone, PartialEq)]
pub enum Controller {
    /// Position P with velocity feed-forward (thesis 4.1; DATA_FORMAT `position_pff`):
    /// u[k] = clip(kp*(r[k]-y[k]) + kff*(r[k+1]-r[k])/Ts, -u_max, u_max)
    PositionPff { kp_v_per_m: f64, kff_v_per_m_s: f64, u_max_v: f64 },
    /// Fixed-gain force P (the thesis's comparison case): u[k] = clip(kp*(r[k]-f[k]))
    ForceP { kp_v_per_n: f64, u_max_v: f64 },
}

/// Command limit [V] of a controller that states none (the valve's full command).
pub const DEFAULT_U_MAX_V: f64 = 10.0;

/// A controller as named parameters (DATA_FORMAT's `controller` table, SI): `type` is
/// position_pff or force_p; the gains the type does not use are ignored.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ControllerArgs {
    pub kind: String,
    pub kp_v_per_m: Option<f64>,
    pub kff_v_per_m_s: Option<f64>,
    pub kp_v_per_n: Option<f64>,
    pub u_max_v: Option<f64>,
}

impl ControllerArgs {
    /// The controller; a gain its type needs and lacks is an input error naming it.
    pub fn build(&self) -> Result<Controller> {
        let need = |k: &str, v: Option<f64>| v.ok_or_else(|| Error::Input(format!("controller needs `{k}`")));
        let u_max_v = self.u_max_v.unwrap_or(DEFAULT_U_MAX_V);
        match self.kind.as_str() {
            "position_pff" => Ok(Controller::PositionPff { kp_v_per_m: need("kp_v_per_m", self.kp_v_per_m)?, kff_v_per_m_s: need("kff_v_per_m_s", self.kff_v_per_m_s)?, u_max_v }),
            "force_p" => Ok(Controller::ForceP { kp_v_per_n: need("kp_v_per_n", self.kp_v_per_n)?, u_max_v }),
            other => Err(Error::Input(format!("unknown controller type `{other}`: use position_pff or force_p"))),
        }
    }
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
#[allow(clippy::large_enum_variant)] // one per test, never in a collection: boxing Demod would only add an indirection per sample
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
    /// the amplitude is large enough to judge the plant's gain by (at least
    /// `PeakValley::MIN_AMPLITUDE_FRACTION` of the cycle's nominal half-range): early in a ramp
    /// the force's fundamental is mostly the ramp's and the valve null's transients, and a
    /// relative gain learned from it over a tiny feed-forward swings to its limits
    pub learn: bool,
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
            if d.u1_ff != 0.0 {
                d.u1 = d.u1_total / ratio / d.u1_ff - 1.0;
            }
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
    /// inner proportional gain on the force error r − f (the mean loop's P term) [V/N] and the
    /// mean loop's integral gain [V/(N·s)]
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
    /// u1·ṡ(φ)/ω (u1·cos ωt for a sine, NOTES item 5) the open-loop force amplitude is
    /// θ1 = g·u1/ω, and the mean obeys θ̇2 = g·(u2 − u_null). Estimates are one-cycle moving averages (the thesis's
    /// high-pass, demodulation with sin and cos, low-pass — a boxcar over exactly one period has
    /// zeros at ω and 2ω, so no ripple reaches the loops; its lag is T/2 = 1/(2f)).
    ///
    /// * inner force P (not in the thesis): u += kp2·(r − f) on the instantaneous error, crossover
    ///   ω_c = `STATIC_CROSSOVER_RAD_S` (kp2 = ω_c/g). With the carrier as velocity feed-forward it
    ///   leaves the loops only the residuals, and it rejects what one-cycle averages cannot see
    ///   in time: the valve's load-pressure asymmetry (extension and retraction flows differ under
    ///   the mean load, a net drift per cycle that grows with the amplitude during the ramp-in)
    ///   and its low-gain null region. It is also the mean loop's proportional term.
    /// * amplitude loop (integral, as the thesis): with the inner loop the carrier moves the force
    ///   amplitude by g·u1/|jω + ω_c| per volt; crossover ω1 = `c1`·f rad/s →
    ///   k1 = ω1·|jω + ω_c|/g. With c1 = 0.5 (time constant 2 cycles) the T/2 lag costs 0.25 rad:
    ///   phase margin ≈ 76°; a K_sp falling to 50 % halves ω1 and stays stable.
    /// * mean loop: integral on the one-cycle mean (the thesis's P alone cannot absorb the valve's
    ///   null offset, it leaves u_null/k2). Below ω_c the inner loop makes the plant from u2 to
    ///   the mean a gain g/ω_c, so ki2 = ω2·ω_c/g puts the crossover at ω2 = `c2`·f (c2 = 0.5).
    ///   A feed-forward of the mean setpoint's rate (ṁ/g) removes the ramp lag of the smooth start.
    ///
    /// Both loops compare the force's estimates with the reference's through the same filters, and
    /// `PeakValley` corrects the setpoint once per cycle so that peaks and valleys, not only the
    /// fundamental and mean, meet ISO 12108's ±2 %.
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
        let wc = STATIC_CROSSOVER_RAD_S;
        let kp2 = wc / g;
        let k1 = w1 * (w * w + wc * wc).sqrt() / g;
        Ok(DemodGains { plant_gain_n_per_s_v: g, k1, kp2, ki2: w2 * wc / g, frequency_hz, ts_s: 1.0 / control_rate_hz, window: window as usize })
    }
}

/// Crossover of the static (preload) force PI [rad/s]: well below the oil-column resonance
/// (≈ 1700 rad/s with a 1.04e8 N/m specimen) and the 1 kHz sampling, fast enough to hold the
/// force against the valve's null drift while the mean ramps up.
pub const STATIC_CROSSOVER_RAD_S: f64 = 150.0;

/// Largest relative correction of the amplitude loop's feed-forward: a plant whose gain is off by
/// more than half is not the one the controller was designed for.
const REL_GAIN_LIMIT: f64 = 0.5;

/// The demodulation controller's state. Allocation happens once (the moving-average rings).
#[derive(serde::Serialize, serde::Deserialize)] // engine snapshots (resume)
#[derive(Debug, Clone)]
pub struct Demod {
    pub gains: DemodGains,
    pub u_max_v: f64,
    /// amplitude-loop integrator, as a relative correction of the carrier's feed-forward (the
    /// plant gain the design missed: valve gain at this opening, the oil column's and the valve's
    /// roll-off at the test frequency). Relative, it scales with the amplitude: a ramp-in, a
    /// resume after a hold or a new level of a sequence starts with the gain already learned
    /// instead of integrating up to each new amplitude (which lags every ramp by the loop's
    /// time constant). Mean-loop output [V].
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
    /// the same estimates of the reference r = mid + amp·s: the loops' targets
    pub theta1_ref: f64,
    pub theta2_ref: f64,
    /// fundamental magnitude and mean of the unit waveform (a steady cycle's targets are
    /// amp·b1 and mid + amp·s_mean)
    pub b1: f64,
    pub s_mean: f64,
    /// one-cycle moving averages of the measurement (f) and of the reference (r)
    f_avg: Boxcar3,
    r_avg: Boxcar3,
    pos: usize,
    filled: usize,
}

/// One-cycle moving sums of a signal x and of its sin/cos demodulation 2·(x − mean)·(sin, cos).
#[derive(serde::Serialize, serde::Deserialize)] // engine snapshots (resume)
#[derive(Debug, Clone)]
struct Boxcar3 {
    ring_x: Vec<f64>,
    ring_i: Vec<f64>,
    ring_q: Vec<f64>,
    sum_x: f64,
    sum_i: f64,
    sum_q: f64,
}

impl Boxcar3 {
    fn new(n: usize, x0: f64) -> Self {
        Boxcar3 { ring_x: vec![x0; n], ring_i: vec![0.0; n], ring_q: vec![0.0; n], sum_x: x0 * n as f64, sum_i: 0.0, sum_q: 0.0 }
    }

    /// Push sample x at ring position `pos`; returns (fundamental magnitude, mean) over the
    /// last n samples: the thesis's high-pass, demodulation and low-pass.
    #[inline]
    fn push(&mut self, pos: usize, x: f64, sin: f64, cos: f64) -> (f64, f64) {
        let n = self.ring_x.len() as f64;
        self.sum_x += x - self.ring_x[pos];
        self.ring_x[pos] = x;
        let mean = self.sum_x / n;
        let z = x - mean;
        let (zi, zq) = (2.0 * z * sin, 2.0 * z * cos);
        self.sum_i += zi - self.ring_i[pos];
        self.sum_q += zq - self.ring_q[pos];
        self.ring_i[pos] = zi;
        self.ring_q[pos] = zq;
        (((self.sum_i / n).powi(2) + (self.sum_q / n).powi(2)).sqrt(), mean)
    }
}

impl Demod {
    /// A controller with `gains` for a waveform with unit-shape (mean, fundamental) `stats`,
    /// starting from a measured force `f0` (the estimates start there, integrators at zero).
    pub fn new(gains: DemodGains, stats: (f64, f64), u_max_v: f64, f0: f64) -> Self {
        let n = gains.window;
        Demod {
            gains, u_max_v, u1: 0.0, u2: 0.0, i2: 0.0, u1_total: 0.0, u1_ff: 0.0, static_mode: true,
            theta1_hat: 0.0, theta2_hat: f0, theta1_ref: 0.0, theta2_ref: f0, s_mean: stats.0, b1: stats.1,
            f_avg: Boxcar3::new(n, f0), r_avg: Boxcar3::new(n, f0), pos: 0, filled: 0,
        }
    }

    #[inline]
    fn command(&mut self, sp: &Setpoint, f: f64) -> f64 {
        let g = &self.gains;
        // amplitude and mean of the force and, through the same filters, of the reference: the
        // loops compare like with like, so a ramping setpoint (smooth start, ΔK schedules) is
        // not mistaken for a tracking error by the filters' half-cycle lag
        (self.theta1_hat, self.theta2_hat) = self.f_avg.push(self.pos, f, sp.sin, sp.cos);
        let r = sp.mid_n + sp.amp_n * sp.s;
        (self.theta1_ref, self.theta2_ref) = self.r_avg.push(self.pos, r, sp.sin, sp.cos);
        self.pos = if self.pos + 1 == g.window { 0 } else { self.pos + 1 };
        self.filled = (self.filled + 1).min(g.window);
        let w = 2.0 * std::f64::consts::PI * g.frequency_hz;
        if sp.amp_n <= 0.0 {
            // static hold / preload: fast PI on the force error (crossover STATIC_CROSSOVER)
            let kp = STATIC_CROSSOVER_RAD_S / g.plant_gain_n_per_s_v;
            let e = sp.mid_n - f;
            self.i2 += g.ts_s * kp * STATIC_CROSSOVER_RAD_S / 4.0 * e;
            self.static_mode = true;
            self.u1_total = 0.0;
            self.u2 = kp * e + self.i2;
            return self.u2.clamp(-self.u_max_v, self.u_max_v);
        }
        self.static_mode = false;
        // amplitude loop: integral on the relative gain of the feed-forward amp·ω/g; at a
        // constant amplitude d(u1·ff)/dt = ts·k1·e1, the absolute integrator's law
        let u1_ff = sp.amp_n * w / g.plant_gain_n_per_s_v;
        if self.filled == g.window && sp.learn {
            let e1 = self.theta1_ref - self.theta1_hat;
            self.u1 = (self.u1 + g.ts_s * g.k1 * e1 / u1_ff).clamp(-REL_GAIN_LIMIT, REL_GAIN_LIMIT);
        }
        let u1 = u1_ff * (1.0 + self.u1);
        self.u1_total = u1;
        self.u1_ff = u1_ff;
        // mean loop: integral on the one-cycle mean, inner P on r − f, setpoint-rate feed-forward
        let e2 = self.theta2_ref - self.theta2_hat;
        self.i2 += g.ts_s * g.ki2 * e2;
        let ff2 = (sp.mid_next_n - sp.mid_n) / (g.ts_s * g.plant_gain_n_per_s_v);
        self.u2 = g.kp2 * (r - f) + self.i2 + ff2;
        // carrier: u1·ṡ/ω over the sample (= u1·cos ωt for the sine) so that an integrator
        // plant moves the force by exactly (g·u1/ω)·Δs
        let carrier = (sp.s_next - sp.s) / (w * g.ts_s);
        (u1 * carrier + self.u2).clamp(-self.u_max_v, self.u_max_v)
    }
}

/// Peak-valley compensation (vendors' "PVC" / amplitude control), per reversal: the
/// demodulation loops hold the force's fundamental and mean, while ISO 12108 judges its peaks and
/// valleys; corners rounded by the finite bandwidth (triangle, trapezoid), the valve's
/// nonlinearity and load-pressure asymmetry and the loops' lag during a ramp put the two apart.
/// Once per cycle the measured peak and valley are compared with the nominal setpoint's, and the
/// excursion into each (rise into the peak, fall into the valley) is corrected by an integral law
/// on its own error, relative to that excursion: a variable-amplitude sequence, whose excursions
/// differ from cycle to cycle, gets each reversal's correction in proportion to its own size.
/// Plain data: it can be snapshotted with the rest of a run.
#[derive(serde::Serialize, serde::Deserialize)] // engine snapshots (resume)
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PeakValley {
    /// relative correction of the rise into the peak and of the fall into the valley (0 = none)
    pub peak: f64,
    pub valley: f64,
}

impl PeakValley {
    /// Integral gain per cycle at full amplitude. The amplitude loop learns the plant's gain
    /// relative to its feed-forward, so what is left for the compensation is the waveform's
    /// distortion (rounded corners, the valve's load-pressure asymmetry), which changes little
    /// from one cycle to the next: 0.7 settles in ≈ 4 cycles without overshoot (benchmarks/
    /// million_cycles.py: 1–40 Hz, sine, triangle, trapezoid).
    pub const GAIN: f64 = 0.7;
    /// Gain during a ramp (start, resume): the distortion grows with the amplitude, so the
    /// correction must keep up with a moving target rather than average it.
    pub const RAMP_GAIN: f64 = 0.85;
    /// Largest correction (±30 % of the half-range): a rig that needs more is beyond its
    /// bandwidth or valve flow for that waveform, which `engine::TestConfig::validate` refuses.
    pub const LIMIT: f64 = 0.3;
    /// Smallest nominal half-range, relative to the test's, at which a cycle teaches the
    /// compensation (early in the ramp-in the force is too small to judge).
    pub const MIN_AMPLITUDE_FRACTION: f64 = 0.3;

    pub fn new() -> Self {
        PeakValley { peak: 0.0, valley: 0.0 }
    }

    /// The commanded half-excursion [N] of a nominal one `amp_n` [N] on the rising half of the
    /// cycle (into the peak, `rising`) or the falling half (into the valley).
    #[inline]
    pub fn apply(&self, amp_n: f64, rising: bool) -> f64 {
        amp_n * (1.0 + if rising { self.peak } else { self.valley })
    }

    /// Learn from one cycle: the nominal setpoint's peak and valley `r_max`, `r_min`, the measured
    /// force peak and valley `f_max`, `f_min`, and the nominal excursions into the peak
    /// (`rise`: from the previous valley) and into the valley (`fall`: from this peak) [N].
    #[allow(clippy::too_many_arguments)]
    pub fn update(&mut self, r_max: f64, r_min: f64, f_max: f64, f_min: f64, rise: f64, fall: f64, gain: f64) {
        if !(rise > 0.0 && fall > 0.0 && f_max.is_finite() && f_min.is_finite()) {
            return;
        }
        // the half-excursion moves the reversal: an error e [N] needs 2e/excursion of it
        self.peak = (self.peak + gain * 2.0 * (r_max - f_max) / rise).clamp(-Self::LIMIT, Self::LIMIT);
        self.valley = (self.valley + gain * 2.0 * (f_min - r_min) / fall).clamp(-Self::LIMIT, Self::LIMIT);
    }
}

impl Default for PeakValley {
    fn default() -> Self {
        Self::new()
    }
}

/// A force test run in position control (thesis 4.1: position P with velocity feed-forward):
/// the force setpoint r becomes the piston reference y0 + r/K, with K the specimen stiffness
/// measured over the last cycle (force range / position range: the compliance a real rig
/// measures for crack length). Nothing corrects the force itself, so it is as good as the
/// stiffness estimate and the position tracking. Plain data.
#[derive(serde::Serialize, serde::Deserialize)] // engine snapshots (resume)
#[derive(Debug, Clone, PartialEq)]
pub struct PositionForce {
    /// `Controller::PositionPff`
    pub ctrl: Controller,
    /// stiffness used to turn force into position [N/m]
    pub k_ref_n_m: f64,
    /// piston position at zero specimen force [m]
    pub y0_m: f64,
    /// fixed null compensation added to the command [V] (as for force P: with a stiff specimen a
    /// P loop's steady position error u_null/kp is a large force error)
    pub u_offset_v: f64,
}

impl PositionForce {
    /// Gains from the plant: velocity feed-forward kff = 1/k_v (the piston follows ṙ exactly on
    /// the integrator plant) and kp = ω_p/k_v, with ω_p = `STATIC_CROSSOVER_RAD_S`; both carry the
    /// sign of the valve's velocity gain k_v [m/s per V].
    pub fn design(velocity_gain_m_s_per_v: f64, k_ref_n_m: f64, y0_m: f64, u_max_v: f64) -> Result<Self> {
        let kv = velocity_gain_m_s_per_v;
        if !(kv.is_finite() && kv != 0.0) {
            return Err(Error::Parameter { field: "controller.velocity_gain_m_s_per_v".into(), value: kv, allowed: "non-zero, finite".into() });
        }
        let ctrl = Controller::PositionPff { kp_v_per_m: STATIC_CROSSOVER_RAD_S / kv, kff_v_per_m_s: 1.0 / kv, u_max_v };
        Ok(PositionForce { ctrl, k_ref_n_m, y0_m, u_offset_v: 0.0 })
    }

    /// Command for one sample from the (compensated) force setpoint and the measured position `y` [m].
    #[inline]
    pub fn command(&self, sp: &Setpoint, y: f64, ts: f64) -> f64 {
        let r = self.y0_m + (sp.mid_n + sp.amp_n * sp.s) / self.k_ref_n_m;
        let r_next = self.y0_m + (sp.mid_next_n + sp.amp_n * sp.s_next) / self.k_ref_n_m;
        match self.ctrl {
            Controller::PositionPff { kp_v_per_m, kff_v_per_m_s, u_max_v } => {
                (kp_v_per_m * (r - y) + kff_v_per_m_s * (r_next - r) / ts + self.u_offset_v).clamp(-u_max_v, u_max_v)
            }
            Controller::ForceP { .. } => 0.0,
        }
    }

    /// Update the stiffness from one cycle's force and position ranges [N], [m].
    pub fn measured(&mut self, force_range_n: f64, position_range_m: f64) {
        let k = force_range_n / position_range_m;
        if position_range_m > 1e-9 && k.is_finite() && k > 0.0 {
            self.k_ref_n_m = k;
        }
    }
}
