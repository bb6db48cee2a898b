//! The closed displacement loop of a machine that closes its own loop (DATA_FORMAT
//! `machine_position` records: position command, position, load force; no valve command, no
//! pressures): its command-to-position dynamics, the specimen's force acting back on it, that
//! loop's own imperfections, and the specimen's force as a predicted output.
//!
//! A position loop around a flow-controlled actuator behaves, below the oil column's resonance,
//! like an integrator fed by the valve's opening. In units of position error (the valve command
//! divided by the controller's gain), with `r` the command as the machine sees it:
//!
//! ```text
//!   r   = Q(hold(y_ref))(t − τ + (T_u − Δt)/2)      quantised (step q), updated every T_u, whole mean delay τ
//!   z   = k·(r + (β/ω)·ṙ) + y_0 − y                 valve command: position error + feed-forward β
//!   z_b = play(z; b)                                 backlash of half width b (a valve's play)
//!   τ_v·ż_v = z_b − z_v        (z_v = z_b if τ_v = 0) valve lag
//!   ẏ   = dz(ω·[(z_v + α|z_v|)·√(1 − sgn(z_v)·L/F_s) − C·L], v_c)
//!   F   = k_s·(y − y_s) + c_s·ẏ + F_c·tanh(ẏ/v_f) − k_cl·⌊y_s + y_cl − y⌋₊    specimen force (tension +)
//!   f   = F + f_0                                    load cell reading (predicted)
//!   L   = f_recorded − f_0, or F without a recorded load cell     the force loading the loop
//! ```
//!
//! Where the load cell is recorded, its force loads the loop (an input) while the specimen model
//! predicts it (an output): the loop's fit does not lean on the specimen model, and the
//! specimen's residual is its own.
//!
//! ω = 2π·bandwidth is the loop gain, k the command-to-position gain, y_0 the command-to-transducer
//! offset, C the loop's static compliance under load (the valve's and seals' flow–pressure
//! coefficient over the controller gain: the specimen's force pushes the position off the
//! command by C·F at rest), α the direction asymmetry (unequal extension/retraction speed for the
//! same opening), F_s the stall force of the orifice law (1/F_s = `load_per_stall_n`; the
//! velocity falls with the load pressure), v_c the velocity the actuator loses to its own
//! friction (the flow through the leakage paths while the pressure holds the friction: a dead
//! zone of the velocity, dz(x, v_c) = sgn(x)·max(0, |x| − v_c)). The velocity is implicit when the
//! specimen force depends on it and acts back; it is solved exactly (the right side falls as ẏ
//! rises, so the root is unique). Inputs are linear between samples, except the hold. Classic
//! RK4 on the position with enough sub-steps per sample for the loop's rate; the valve lag is
//! solved exactly over each step (any time constant, down to the static valve).
use crate::error::{Error, Result};
use crate::measure::held;
use crate::params::Field;
use crate::specimen_force::{damping_friction_force, spring_force};

macro_rules! define_loop_params {
    ($( $(#[doc = $doc:literal])+ $name:ident [$unit:literal] = $default:expr, $lo:tt $min:expr, $max:expr; )*) => {
        /// Parameters of the displacement-loop model, SI. Each effect is off at its default.
        #[derive(Debug, Clone, PartialEq)]
        pub struct LoopParams {
            $( $(#[doc = $doc])+ pub $name: f64, )*
        }

        /// Every parameter of the loop model with unit, documentation and allowed range.
        pub const LOOP_FIELDS: &[Field] = &[
            $( Field { name: stringify!($name), unit: $unit, doc: concat!($($doc, " "),+),
                       min: $min, max: $max, min_open: define_loop_params!(@open $lo) }, )*
        ];

        impl Default for LoopParams {
            fn default() -> Self {
                LoopParams { $( $name: $default, )* }
            }
        }

        impl LoopParams {
            fn field(&self, name: &str) -> Option<f64> {
                match name { $( stringify!($name) => Some(self.$name), )* _ => None }
            }
            fn set_field(&mut self, name: &str, value: f64) -> bool {
                match name {
                    $( stringify!($name) => { self.$name = value; true } )*
                    _ => false,
                }
            }
        }
    };
    (@open open) => { true };
    (@open closed) => { false };
}

define_loop_params! {
    /// Static gain k from command to position (a command and a transducer scaled differently)
    gain ["-"] = 1.0, open 0.0, 10.0;
    /// Offset y_0 between command and measured position: at rest without load y = k·y_ref + y_0
    offset_m ["m"] = 0.0, closed -10.0, 10.0;
    /// Loop bandwidth ω/2π: the loop gain (controller gain × valve velocity gain) over 2π
    bandwidth_hz ["Hz"] = 5.0, open 0.0, 1.0e4;
    /// Transport delay τ of the command (controller cycle, filters, communication); with a
    /// held command (`command_period_s`) it includes the hold's mean lag of half an update
    delay_s ["s"] = 0.0, closed 0.0, 1.0;
    /// Velocity feed-forward β: share of the command's velocity the controller passes to the
    /// valve directly (β = kff·velocity gain for a P + feed-forward controller)
    feedforward ["-"] = 0.0, closed -10.0, 10.0;
    /// Static compliance C of the loop under load: the position gives way C·F to a force F
    compliance_m_per_n ["m/N"] = 0.0, closed 0.0, 1.0;
    /// First-order lag τ_v of the valve inside the loop (EFFECTS valve_dynamics `tau_s`)
    valve_tau_s ["s"] = 0.0, closed 0.0, 1.0;
    /// Direction asymmetry α: extension moves (1 + α)/(1 − α) times faster than retraction for
    /// the same valve command (a single-rod cylinder, unequal valve edges)
    asymmetry ["-"] = 0.0, closed -0.95, 0.95;
    /// Velocity v_c lost to the actuator's own friction (a dead zone of the loop's velocity)
    velocity_loss_m_s ["m/s"] = 0.0, closed 0.0, 10.0;
    /// Backlash (play) half width b between the loop's valve command and the valve, in metres
    /// of position error (a valve's play in volts over the controller's gain in V/m)
    backlash_m ["m"] = 0.0, closed 0.0, 1.0;
    /// Load sensitivity of the velocity 1/F_s: the orifice law's √(1 − F/F_s), F_s the stall
    /// force (piston area × supply-to-tank pressure); 0 = a velocity that ignores the load
    load_per_stall_n ["1/N"] = 0.0, closed 0.0, 1.0;
    /// Quantum q of the command the machine sees; 0 = continuous
    command_step_m ["m"] = 0.0, closed 0.0, 1.0;
    /// Update period T_u of the command the machine sees (held in between, rounded to whole
    /// samples); 0 = every sample
    command_period_s ["s"] = 0.0, closed 0.0, 10.0;
    /// Specimen stiffness k_s (linear spring)
    specimen_stiffness_n_m ["N/m"] = 0.0, closed 0.0, 1.0e12;
    /// Position y_s at which the specimen carries no force (position-sensor coordinates)
    specimen_zero_force_position_m ["m"] = 0.0, closed -10.0, 10.0;
    /// Specimen viscous damping c_s
    specimen_damping_n_s_m ["N s/m"] = 0.0, closed 0.0, 1.0e9;
    /// Specimen friction level F_c (a friction-like damper such as an MR damper): F_c·tanh(ẏ/v_f)
    specimen_friction_n ["N"] = 0.0, closed 0.0, 1.0e8;
    /// Velocity v_f over which the specimen's friction builds up (its pre-yield slope F_c/v_f)
    specimen_friction_velocity_m_s ["m/s"] = 1.0e-3, open 0.0, 10.0;
    /// Crack-closure stiffness k_cl added below the closure position (EFFECTS specimen_nonlinearity)
    specimen_closure_stiffness_n_m ["N/m"] = 0.0, closed 0.0, 1.0e12;
    /// Closure position relative to the zero-force position: k_cl acts for y < y_s + this
    specimen_closure_offset_m ["m"] = 0.0, closed -1.0, 1.0;
    /// Load cell offset f_0 (EFFECTS sensor_offset on f)
    sensor_offset_f ["N"] = 0.0, closed -1.0e8, 1.0e8;
}

/// A derived key: the stall force F_s = 1/`load_per_stall_n` [N] (infinite when off).
pub const STALL_FORCE_KEY: &str = "load_stall_force_n";

impl LoopParams {
    /// A parameter by name (the fields, and the derived `load_stall_force_n`).
    pub fn get(&self, name: &str) -> Option<f64> {
        if name == STALL_FORCE_KEY {
            return Some(if self.load_per_stall_n > 0.0 { 1.0 / self.load_per_stall_n } else { f64::INFINITY });
        }
        self.field(name)
    }

    /// Set a parameter by name (no range check: `validate` does that).
    pub fn set(&mut self, name: &str, value: f64) -> Result<()> {
        if name == STALL_FORCE_KEY {
            if !(value > 0.0) {
                return Err(Error::Parameter { field: name.into(), value, allowed: "(0, inf] N".into() });
            }
            self.load_per_stall_n = 1.0 / value;
            return Ok(());
        }
        if self.set_field(name, value) {
            Ok(())
        } else {
            Err(Error::Input(format!("unknown displacement-loop parameter `{name}`")))
        }
    }

    /// Check every field; the error names the first bad one and its allowed range.
    pub fn validate(&self) -> Result<()> {
        for f in LOOP_FIELDS {
            f.check(self.field(f.name).expect("field table matches struct"))?;
        }
        Ok(())
    }
}

/// What the model predicts at every sample: position [m] and velocity [m/s] as the transducer
/// sees them, and the load cell's force [N].
#[derive(Debug, Clone, PartialEq)]
pub struct LoopOutput {
    pub y: Vec<f64>,
    pub v: Vec<f64>,
    pub f: Vec<f64>,
}

/// Largest RK4 step times the loop's fastest rate (accuracy far below any sensor's noise).
const STEP_RATE: f64 = 0.5;
const MAX_SUBSTEPS: usize = 400;

/// Sample `x` at fractional index `i` (linear interpolation, held at the ends).
#[inline]
fn at(x: &[f64], i: f64) -> f64 {
    if i <= 0.0 {
        return x[0];
    }
    let k = i.floor() as usize;
    if k + 1 >= x.len() {
        return x[x.len() - 1];
    }
    let w = i - k as f64;
    x[k] * (1.0 - w) + x[k + 1] * w
}

/// Slope per sample of the linear interpolation of `x` at fractional index `i` (0 outside).
#[inline]
fn slope(x: &[f64], i: f64) -> f64 {
    if i < 0.0 {
        return 0.0;
    }
    let k = i.floor() as usize;
    if k + 1 >= x.len() {
        return 0.0;
    }
    x[k + 1] - x[k]
}

#[inline]
fn dead_zone(x: f64, half: f64) -> f64 {
    if half <= 0.0 {
        x
    } else {
        x.signum() * (x.abs() - half).max(0.0)
    }
}

/// Samples per update of the command the machine sees (at least 1).
fn update_every(p: &LoopParams, dt: f64) -> usize {
    if p.command_period_s > 0.0 {
        ((p.command_period_s / dt).round() as usize).max(1)
    } else {
        1
    }
}

/// The command as the machine sees it: dropped samples held, updated every `command_period_s`
/// (whole samples, from the first) and quantised to `command_step_m`.
pub fn machine_command(p: &LoopParams, dt: f64, y_ref: &[f64]) -> Vec<f64> {
    let r = held(y_ref);
    let every = update_every(p, dt);
    let q = p.command_step_m;
    (0..r.len())
        .map(|k| {
            let x = r[(k / every) * every];
            if q > 0.0 {
                q * (x / q).round()
            } else {
                x
            }
        })
        .collect()
}

/// The loop's right-hand side for one parameter set.
struct Law<'a> {
    p: &'a LoopParams,
    w: f64,
    cmd: &'a [f64],
    /// the recorded load cell, pre-rolled like the command: the force acting on the loop
    load: Option<&'a [f64]>,
    lag: f64,
    ff: f64,
    dt: f64,
}

impl Law<'_> {
    /// Valve command z [m] at fractional sample index `i` with the position at `y`.
    #[inline]
    fn command(&self, i: f64, y: f64) -> f64 {
        let j = i - self.lag;
        let r = at(self.cmd, j) + self.ff * slope(self.cmd, j) / self.dt;
        self.p.gain * r + self.p.offset_m - y
    }

    /// Specimen force [N] (tension positive) at position `y`, velocity `v`.
    #[inline]
    fn specimen(&self, y: f64, v: f64) -> f64 {
        let p = self.p;
        spring_force(p.specimen_stiffness_n_m, p.specimen_zero_force_position_m, p.specimen_closure_stiffness_n_m,
                     p.specimen_closure_offset_m, y)
            + damping_friction_force(p.specimen_damping_n_s_m, p.specimen_friction_n, p.specimen_friction_velocity_m_s, v)
    }

    /// Velocity the valve opening `zv` gives against the load `force`, and its derivative with
    /// respect to the force.
    #[inline]
    fn valve_velocity(&self, zv: f64, force: f64) -> (f64, f64) {
        let p = self.p;
        let a = zv + p.asymmetry * zv.abs();
        let (mut g, mut dg) = (a, 0.0);
        if p.load_per_stall_n > 0.0 {
            let s = zv.signum() * p.load_per_stall_n;
            let l2 = 1.0 - s * force;
            if l2 > 0.0 {
                let l = l2.sqrt();
                g = a * l;
                dg = -a * s / (2.0 * l);
            } else {
                g = 0.0;
            }
        }
        let x = self.w * (g - p.compliance_m_per_n * force);
        let v = dead_zone(x, p.velocity_loss_m_s);
        let inside = p.velocity_loss_m_s > 0.0 && x.abs() <= p.velocity_loss_m_s;
        (v, if inside { 0.0 } else { self.w * (dg - p.compliance_m_per_n) })
    }

    /// (velocity, specimen force) at position `y` with valve opening `zv` at fractional sample
    /// `i` (the force only `want_force` when it does not act back on the loop). The force that
    /// loads the loop is the recorded one where the load cell is recorded; otherwise the
    /// specimen's own, and the velocity is the root of
    /// h(v) = v − valve_velocity(zv, F(y, v)). h rises with slope h' ≥ 1 (the specimen's force
    /// grows with the velocity, the valve's velocity falls with the force), so the root is unique
    /// and lies within |h(v)| of any v: Newton from `hint` (a velocity nearby), each step kept
    /// inside the bracket that every evaluation narrows.
    fn motion(&self, zv: f64, y: f64, i: f64, hint: f64, want_force: bool) -> (f64, f64) {
        let p = self.p;
        let rate_dependent = p.specimen_damping_n_s_m > 0.0 || p.specimen_friction_n > 0.0;
        let acts_back = p.compliance_m_per_n > 0.0 || p.load_per_stall_n > 0.0;
        if let Some(load) = self.load {
            // a recorded load cell: its force (less the cell's offset) loads the loop; the
            // specimen's modelled force is the prediction of that reading
            let f = if acts_back { at(load, i) - p.sensor_offset_f } else { 0.0 };
            let v = self.valve_velocity(zv, f).0;
            return (v, if want_force { self.specimen(y, v) } else { f64::NAN });
        }
        if !acts_back {
            // the force is an output only
            let v = self.valve_velocity(zv, 0.0).0;
            return (v, if want_force { self.specimen(y, v) } else { f64::NAN });
        }
        if !rate_dependent {
            let f = self.specimen(y, 0.0);
            return (self.valve_velocity(zv, f).0, f);
        }
        // the force's part that does not depend on the velocity, then per iterate one tanh
        let f_static = self.specimen(y, 0.0);
        let (cs, fc, vf) = (p.specimen_damping_n_s_m, p.specimen_friction_n, p.specimen_friction_velocity_m_s);
        let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
        let mut v = hint;
        let mut f = f_static;
        for _ in 0..60 {
            let t = if fc > 0.0 { (v / vf).tanh() } else { 0.0 };
            f = f_static + cs * v + fc * t;
            let (g, dg_df) = self.valve_velocity(zv, f);
            let hv = v - g;
            let dh = 1.0 - dg_df * (cs + if fc > 0.0 { fc / vf * (1.0 - t * t) } else { 0.0 });
            if hv > 0.0 {
                hi = hi.min(v);
                lo = lo.max(v - hv);
            } else {
                lo = lo.max(v);
                hi = hi.min(v - hv);
            }
            let mut next = v - hv / dh;
            if !(next >= lo && next <= hi) {
                next = 0.5 * (lo + hi);
            }
            if (next - v).abs() <= 1e-14 + 1e-11 * v.abs() {
                break; // (v, f) is the root to far below any sensor's resolution
            }
            v = next;
        }
        (v, f)
    }

    /// Valve opening the velocity law sees: the lagged state, or the play's output at once.
    #[inline]
    fn opening(&self, zb: f64, zv: f64) -> f64 {
        if self.p.valve_tau_s > 0.0 {
            zv
        } else {
            zb
        }
    }
}

#[inline]
fn play(z: f64, memory: f64, half: f64) -> f64 {
    if half > 0.0 {
        memory.clamp(z - half, z + half)
    } else {
        z
    }
}

/// Check the record's arguments; the message names what is wrong.
pub fn validate_input(dt: f64, y_ref: &[f64]) -> Result<()> {
    if y_ref.is_empty() {
        return Err(Error::Input("the command y_ref has no samples".into()));
    }
    if !(dt.is_finite() && dt > 0.0) {
        return Err(Error::Input(format!("sample period dt = {dt} s must be > 0")));
    }
    if !y_ref.iter().any(|x| x.is_finite()) {
        return Err(Error::Input("the command y_ref holds no finite value".into()));
    }
    Ok(())
}

/// Position, velocity and force the model predicts at every sample of the command `y_ref` [m]
/// sampled every `dt` [s] (NaN = a dropped sample, the previous value held). `load`: the
/// recorded load cell [N], when there is one, is the force that loads the loop (the predicted
/// force is the modelled specimen's all the same); without it the specimen's own force does.
/// The loop starts settled on the first command: it is held before the record for a few loop
/// time constants.
pub fn simulate(p: &LoopParams, dt: f64, y_ref: &[f64], load: Option<&[f64]>) -> Result<LoopOutput> {
    p.validate()?;
    validate_input(dt, y_ref)?;
    if let Some(f) = load {
        if f.len() != y_ref.len() {
            return Err(Error::Input(format!("the load cell `f` has {} samples but y_ref has {}", f.len(), y_ref.len())));
        }
        if !f.iter().any(|x| x.is_finite()) {
            return Err(Error::Input("the load cell `f` holds no finite value".into()));
        }
    }
    let n = y_ref.len();
    let w = 2.0 * std::f64::consts::PI * p.bandwidth_hz;
    let preroll_s = (6.0 / w + 6.0 * p.valve_tau_s + p.delay_s).clamp(0.2, 5.0);
    let pre = (preroll_s / dt).round() as usize;
    let seen = machine_command(p, dt, y_ref);
    let mut cmd = vec![seen[0]; pre];
    cmd.extend_from_slice(&seen);
    // `delay_s` is the command's whole mean delay: the hold's own (N − 1)/2 samples are part of it
    let lag = (p.delay_s / dt - 0.5 * (update_every(p, dt) as f64 - 1.0)).max(0.0);
    let loaded: Option<Vec<f64>> = load.map(|f| {
        let f = held(f);
        let mut x = vec![f[0]; pre];
        x.extend_from_slice(&f);
        x
    });
    let law = Law { p, w, cmd: &cmd, load: loaded.as_deref(), lag, ff: p.feedforward / w, dt };
    // fastest rate of the loop: the integrator, stiffened by the specimen through C (the valve
    // lag is integrated exactly, whatever its time constant)
    let stiff = p.compliance_m_per_n * (p.specimen_stiffness_n_m + p.specimen_closure_stiffness_n_m);
    let rate = w * (1.0 + p.asymmetry.abs()) * (1.0 + stiff);
    let substeps = ((dt * rate / STEP_RATE).ceil() as usize).clamp(1, MAX_SUBSTEPS);
    let h = dt / substeps as f64;
    let di = 1.0 / substeps as f64;
    let half = p.backlash_m;
    let lagged = Lag::new(p.valve_tau_s, h);

    let mut y = p.gain * cmd[0] + p.offset_m;
    let mut zv = 0.0;
    let mut memory = 0.0;
    let mut v_last = 0.0;
    let mut out = LoopOutput { y: Vec::with_capacity(n), v: Vec::with_capacity(n), f: Vec::with_capacity(n) };
    for k in 0..pre + n {
        for j in 0..substeps {
            let i = k as f64 + j as f64 * di;
            // RK4 on the position; the valve's opening at each stage from the exact response of
            // the lag to a command varying linearly from the step's start to that stage
            let zb0 = play(law.command(i, y), memory, half);
            let (k1, f0) = law.motion(law.opening(zb0, zv), y, i, v_last, j == 0);
            v_last = k1;
            if j == 0 && k >= pre {
                out.y.push(y);
                out.v.push(k1);
                out.f.push(f0 + p.sensor_offset_f);
            }
            if k + 1 == pre + n {
                break; // the last sample is recorded; nothing after it is needed
            }
            let stage = |c: f64, yc: f64| -> f64 {
                let zb = play(law.command(i + c * di, yc), memory, half);
                law.motion(law.opening(zb, lagged.at(zv, zb0, zb, c)), yc, i + c * di, k1, false).0
            };
            let k2 = stage(0.5, y + 0.5 * h * k1);
            let k3 = stage(0.5, y + 0.5 * h * k2);
            let k4 = stage(1.0, y + h * k3);
            y += h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
            let zb1 = play(law.command(i + di, y), memory, half);
            zv = lagged.at(zv, zb0, zb1, 1.0);
            memory = zb1;
        }
        if !(y.is_finite() && zv.is_finite() && y.abs() < 1e3) {
            let at = k.saturating_sub(pre);
            return Err(Error::Solver(format!("displacement-loop model diverged at sample {at}")));
        }
    }
    Ok(out)
}

/// The valve lag τ·ż_v = z_b − z_v over one step of length h, solved exactly for an input
/// varying linearly over the step (stable and exact in the static limit τ → 0).
struct Lag {
    tau: f64,
    /// per stage fraction c ∈ {½, 1}: (c·h, τ·(x + e^{−x} − 1), e^{−x}) with x = c·h/τ
    half: (f64, f64, f64),
    full: (f64, f64, f64),
}

impl Lag {
    fn new(tau: f64, h: f64) -> Self {
        let k = |t: f64| {
            let x = if tau > 0.0 { t / tau } else { 0.0 };
            (t, tau * (x + (-x).exp_m1()), (-x).exp())
        };
        Lag { tau, half: k(0.5 * h), full: k(h) }
    }

    /// z_v at the fraction `c` (½ or 1) of the step from z_v = `zv0`, the input going from `zb0`
    /// to `zbc`: z_v(t) = z_b(t) − s·τ·(1 − e^{−x}) + (z_v0 − z_b0)·e^{−x}, s the input's slope,
    /// written without cancellation.
    #[inline]
    fn at(&self, zv0: f64, zb0: f64, zbc: f64, c: f64) -> f64 {
        if self.tau <= 0.0 {
            return zbc;
        }
        let (t, a, e) = if c < 1.0 { self.half } else { self.full };
        zb0 + (zbc - zb0) / t * a + (zv0 - zb0) * e
    }
}

/// `simulate` for every parameter set, spread over `threads` threads (0 = all cores).
pub fn simulate_batch(ps: &[LoopParams], dt: f64, y_ref: &[f64], load: Option<&[f64]>, threads: usize) -> Vec<Result<LoopOutput>> {
    crate::batch::par_map(ps, threads, |p| simulate(p, dt, y_ref, load))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn sine(n: usize, dt: f64, f_hz: f64, amp: f64) -> Vec<f64> {
        (0..n).map(|k| amp * (2.0 * PI * f_hz * k as f64 * dt).sin()).collect()
    }

    fn ramp_up_down(n: usize, dt: f64, speed: f64) -> Vec<f64> {
        (0..n).map(|k| speed * (k as f64 * dt).min((n - k) as f64 * dt)).collect()
    }

    #[test]
    fn first_order_loop_has_its_bandwidth_amplitude() {
        // at f = bandwidth a first-order loop passes 1/√2 of the amplitude
        let dt = 1e-3;
        let p = LoopParams { bandwidth_hz: 5.0, ..Default::default() };
        let r = sine(4000, dt, 5.0, 1e-3);
        let y = simulate(&p, dt, &r, None).unwrap().y;
        let peak = y[2000..].iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!((peak / 1e-3 - 0.5f64.sqrt()).abs() < 0.01, "peak ratio {}", peak / 1e-3);
    }

    #[test]
    fn delay_shifts_the_response_and_feed_forward_removes_the_lag() {
        let dt = 1e-3;
        let mut r = vec![0.0; 400];
        for x in r.iter_mut().skip(100) {
            *x = 1e-3;
        }
        let p = LoopParams { bandwidth_hz: 20.0, delay_s: 0.01, ..Default::default() };
        let y = simulate(&p, dt, &r, None).unwrap().y;
        assert!(y[109].abs() < 1e-9, "moved before the delay: {}", y[109]);
        assert!(y[115] > 1e-5);
        // a ramp: a plain loop lags by v/ω, full feed-forward tracks it exactly
        let r = ramp_up_down(2000, dt, 0.01);
        let plain = simulate(&LoopParams { bandwidth_hz: 2.0, ..Default::default() }, dt, &r, None).unwrap().y;
        let ff = simulate(&LoopParams { bandwidth_hz: 2.0, feedforward: 1.0, ..Default::default() }, dt, &r, None).unwrap().y;
        let lag = 0.01 / (2.0 * PI * 2.0);
        assert!((r[900] - plain[900] - lag).abs() < 1e-3 * lag, "{} vs {lag}", r[900] - plain[900]);
        assert!((r[900] - ff[900]).abs() < 1e-9, "{}", r[900] - ff[900]);
    }

    #[test]
    fn specimen_force_is_predicted_and_pushes_the_position_off_by_the_compliance() {
        let dt = 1e-3;
        let n = 3000;
        let (ks, c) = (2e6, 1e-9);
        let p = LoopParams { bandwidth_hz: 5.0, specimen_stiffness_n_m: ks, specimen_zero_force_position_m: -1e-3,
                             compliance_m_per_n: c, sensor_offset_f: 50.0, ..Default::default() };
        let out = simulate(&p, dt, &vec![0.0; n], None).unwrap();
        // at rest: y = -C·k_s·(y + 1 mm)
        let y_rest = -c * ks * 1e-3 / (1.0 + c * ks);
        assert!((out.y[n - 1] - y_rest).abs() < 1e-12, "{} vs {y_rest}", out.y[n - 1]);
        assert!((out.f[n - 1] - (ks * (y_rest + 1e-3) + 50.0)).abs() < 1e-6);
        // a damper: force follows the velocity, and slows the loop that pushes it
        let r = sine(4000, dt, 2.0, 1e-3);
        let d = LoopParams { bandwidth_hz: 5.0, specimen_damping_n_s_m: 2e4, specimen_friction_n: 500.0,
                             specimen_friction_velocity_m_s: 1e-3, ..Default::default() };
        let free = simulate(&d, dt, &r, None).unwrap();
        for k in (100..4000).step_by(97) {
            let v = free.v[k];
            let want = 2e4 * v + 500.0 * (v / 1e-3).tanh();
            assert!((free.f[k] - want).abs() < 1e-9 * want.abs().max(1.0));
        }
        let loaded = simulate(&LoopParams { compliance_m_per_n: 2e-7, ..d.clone() }, dt, &r, None).unwrap();
        let amp = |y: &[f64]| y[2000..].iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(amp(&loaded.y) < 0.9 * amp(&free.y), "{} vs {}", amp(&loaded.y), amp(&free.y));
        // a recorded load cell loads the loop instead of the modelled specimen (less its offset):
        // the droop is C·(f − f_0), while the predicted force stays the specimen's
        let rec_f = vec![1050.0; n];
        let with_cell = simulate(&p, dt, &vec![0.0; n], Some(&rec_f)).unwrap();
        assert!((with_cell.y[n - 1] + c * 1000.0).abs() < 1e-12, "{}", with_cell.y[n - 1]);
        assert!((with_cell.f[n - 1] - (ks * (with_cell.y[n - 1] + 1e-3) + 50.0)).abs() < 1e-6);
        assert!(matches!(simulate(&p, dt, &vec![0.0; n], Some(&rec_f[1..])), Err(Error::Input(_))));
        // the implicit velocity solves v = valve_velocity(z, F(v)) from any hint, also where the
        // friction's slope F_c/v_f times the loop's compliance is far above 1
        let stiff = LoopParams { bandwidth_hz: 7.0, specimen_friction_n: 2000.0, specimen_friction_velocity_m_s: 2e-3,
                                 specimen_damping_n_s_m: 5e3, compliance_m_per_n: 1e-6, load_per_stall_n: 1e-4,
                                 velocity_loss_m_s: 1e-4, ..Default::default() };
        let cmd = [0.0, 0.0];
        let law = Law { p: &stiff, w: 2.0 * PI * 7.0, cmd: &cmd, load: None, lag: 0.0, ff: 0.0, dt };
        for &zv in &[-2e-3, -1e-4, 1e-5, 3e-4, 5e-3] {
            for &hint in &[-1.0, 0.0, 0.02, 1.0] {
                let (v, f) = law.motion(zv, 1e-3, 0.0, hint, true);
                let (g, _) = law.valve_velocity(zv, f);
                assert!((v - g).abs() < 1e-10 * g.abs().max(1e-6), "zv {zv} hint {hint}: v {v} vs {g}");
            }
        }
    }

    #[test]
    fn asymmetry_shifts_the_mean_and_the_stall_force_slows_the_loaded_direction() {
        let dt = 1e-3;
        let r = sine(6000, dt, 3.0, 2e-3);
        let pa = LoopParams { bandwidth_hz: 5.0, asymmetry: 0.1, ..Default::default() };
        let ya = simulate(&pa, dt, &r, None).unwrap().y;
        let mean: f64 = ya[2000..].iter().sum::<f64>() / 4000.0;
        assert!(mean.abs() > 1e-5, "asymmetry should shift the mean, got {mean}");
        // a spring pulling back: extension (against it) is slower than with a load-blind valve
        let spring = LoopParams { bandwidth_hz: 5.0, specimen_stiffness_n_m: 1e7, ..Default::default() };
        let blind = simulate(&spring, dt, &r, None).unwrap();
        let stall = simulate(&LoopParams { load_per_stall_n: 1.0 / 4e4, ..spring }, dt, &r, None).unwrap();
        let top = |y: &[f64]| y[2000..].iter().fold(f64::MIN, |m, v| m.max(*v));
        assert!(top(&stall.y) < top(&blind.y) - 1e-5, "{} vs {}", top(&stall.y), top(&blind.y));
        assert_eq!(LoopParams { load_per_stall_n: 2.5e-5, ..Default::default() }.get(STALL_FORCE_KEY), Some(4e4));
    }

    #[test]
    fn actuator_friction_adds_its_velocity_loss_to_the_ramp_error() {
        let dt = 1e-3;
        let (w_hz, speed, vc) = (2.0, 0.01, 2e-3);
        let r = ramp_up_down(3000, dt, speed);
        let y = simulate(&LoopParams { bandwidth_hz: w_hz, velocity_loss_m_s: vc, ..Default::default() }, dt, &r, None).unwrap().y;
        let e = (speed + vc) / (2.0 * PI * w_hz);
        assert!((r[1400] - y[1400] - e).abs() < 1e-3 * e, "{} vs {e}", r[1400] - y[1400]);
    }

    #[test]
    fn backlash_holds_the_valve_until_the_command_reverses_by_twice_its_half_width() {
        let dt = 1e-3;
        let b = 2e-4;
        let r = ramp_up_down(3000, dt, 0.01);
        let p = LoopParams { bandwidth_hz: 2.0, ..Default::default() };
        let plain = simulate(&p, dt, &r, None).unwrap().y;
        let play = simulate(&LoopParams { backlash_m: b, ..p }, dt, &r, None).unwrap().y;
        // on the way up the valve lags the command by b: the position trails by b more
        assert!((plain[1400] - play[1400] - b).abs() < 1e-3 * b, "{}", plain[1400] - play[1400]);
        // after the reversal the valve keeps pushing up until the command has come back by 2b:
        // the error then falls at twice the speed, so the top comes b/v later
        let k_top = |y: &[f64]| (0..y.len()).max_by(|&a, &b| y[a].total_cmp(&y[b])).unwrap() as i64;
        let late = k_top(&play) - k_top(&plain);
        assert!((late - 20).abs() <= 1, "top {late} samples later, expected b/v = 20");
    }

    #[test]
    fn the_machine_sees_a_held_quantised_command() {
        let p = LoopParams { command_step_m: 1e-3, command_period_s: 4e-3, ..Default::default() };
        let r: Vec<f64> = (0..10).map(|k| k as f64 * 0.4e-3).collect();
        let c = machine_command(&p, 1e-3, &r);
        assert_eq!(c, vec![0.0, 0.0, 0.0, 0.0, 2e-3, 2e-3, 2e-3, 2e-3, 3e-3, 3e-3]);
        let nan = machine_command(&LoopParams::default(), 1e-3, &[f64::NAN, 1.0, f64::NAN, 2.0]);
        assert_eq!(nan, vec![1.0, 1.0, 1.0, 2.0]);
        // the hold's mean lag is part of `delay_s`: on a ramp the held command only adds a ripple
        let dt = 1e-3;
        let r = ramp_up_down(4000, dt, 0.01);
        let base = LoopParams { bandwidth_hz: 5.0, delay_s: 0.006, ..Default::default() };
        let plain = simulate(&base, dt, &r, None).unwrap().y;
        let held = simulate(&LoopParams { command_period_s: 0.011, ..base }, dt, &r, None).unwrap().y;
        let diff: Vec<f64> = (1000..1900).map(|k| held[k] - plain[k]).collect();
        let mean = diff.iter().sum::<f64>() / diff.len() as f64;
        let ripple = diff.iter().fold(0.0f64, |m, d| m.max(d.abs()));
        assert!(mean.abs() < 0.02 * ripple && ripple > 1e-6, "mean {mean}, ripple {ripple}");
    }

    #[test]
    fn valve_lag_makes_the_loop_overshoot_and_batches_agree_with_single_runs() {
        let dt = 1e-3;
        let mut r = vec![0.0; 1500];
        for x in r.iter_mut().skip(100) {
            *x = 1e-3;
        }
        let fast = LoopParams { bandwidth_hz: 8.0, ..Default::default() };
        let lag = LoopParams { valve_tau_s: 0.03, ..fast.clone() };
        let out = simulate_batch(&[fast.clone(), lag.clone(), fast.clone()], dt, &r, None, 2);
        let (a, b) = (out[0].as_ref().unwrap(), out[1].as_ref().unwrap());
        assert_eq!(a, out[2].as_ref().unwrap());
        assert_eq!(b, &simulate(&lag, dt, &r, None).unwrap());
        let peak = |y: &[f64]| y.iter().cloned().fold(f64::MIN, f64::max);
        assert!(peak(&a.y) <= 1e-3 + 1e-9 && peak(&b.y) > 1.05e-3, "{} {}", peak(&a.y), peak(&b.y));
        // the lag is integrated exactly: a vanishing one is the static valve, a slow one agrees
        // with the same lag sampled ten times finer
        let tiny = simulate(&LoopParams { valve_tau_s: 1e-9, ..fast.clone() }, dt, &r, None).unwrap();
        assert!(tiny.y.iter().zip(&a.y).all(|(x, y)| (x - y).abs() < 1e-9));
        let fine_r: Vec<f64> = (0..r.len() * 10).map(|k| at(&r, k as f64 / 10.0)).collect();
        let fine = simulate(&lag, dt / 10.0, &fine_r, None).unwrap();
        let worst = (200..1500).map(|k| (fine.y[10 * k] - b.y[k]).abs()).fold(0.0, f64::max);
        assert!(worst < 2e-6, "{worst}");
    }

    #[test]
    fn bad_input_is_refused() {
        let p = LoopParams { asymmetry: 1.5, ..Default::default() };
        assert!(matches!(simulate(&p, 1e-3, &[0.0], None), Err(Error::Parameter { .. })));
        let p = LoopParams::default();
        assert!(matches!(simulate(&p, 1e-3, &[], None), Err(Error::Input(_))));
        assert!(matches!(simulate(&p, 0.0, &[0.0], None), Err(Error::Input(_))));
        assert!(matches!(simulate(&p, 1e-3, &[f64::NAN, f64::NAN], None), Err(Error::Input(_))));
        let mut q = LoopParams::default();
        assert!(q.set("no_such", 1.0).is_err() && q.set(STALL_FORCE_KEY, -1.0).is_err());
        q.set(STALL_FORCE_KEY, 5e4).unwrap();
        assert_eq!(q.load_per_stall_n, 2e-5);
    }
}
