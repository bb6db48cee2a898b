//! The fatigue test engine: plant + force controller + specimen + crack growth, cycle by cycle.
//! Each cycle's measured force peak and valley give ΔK and Kmax, the growth law advances a, and
//! K_sp(a) goes back into the plant. Full fidelity runs every cycle through the plant; cycle-jump
//! resolves short blocks to steady state and integrates growth across the cycles in between.
//! Batches of tests run on all cores.
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::time::Instant;

use crate::control::{Demod, DemodGains, ForceLoop, PeakValley, PositionForce, Setpoint};
use crate::crack::Law;
use crate::error::{Error, Result};
use crate::machine::{Machine, Y};
use crate::params::Params;
use crate::specimen::{Material, Specimen};
use crate::waveform::{Envelope, Waveform};

/// How the force range is set each cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Mode {
    /// constant force range ΔF [N]
    ConstantForce { delta_f_n: f64 },
    /// constant ΔK [Pa·√m]: ΔF follows a
    ConstantDeltaK { delta_k: f64 },
    /// ΔK = ΔK0·exp(C·(a − a_phase_start)), C [1/m] ≥ −80 (E647: −0.08 mm⁻¹)
    KGradient { delta_k0: f64, c_per_m: f64 },
}

/// The E647 limit on the normalised K-gradient for decreasing-ΔK tests [1/m] (−0.08 mm⁻¹).
pub const E647_MIN_K_GRADIENT_PER_M: f64 = -80.0;

/// One phase of a test (a precrack, then the test proper), ending at crack length `end_a_m`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Phase {
    pub mode: Mode,
    pub r_ratio: f64,
    pub end_a_m: f64,
    /// force tolerance as a fraction (ISO 12108: 0.02 test, 0.05 precrack)
    pub tolerance: f64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ControllerSpec {
    /// demodulation amplitude/mean controller; velocity gain of the valve [m/s per V], signed by
    /// polarity; `None` = measured on the plant (see `measure_velocity_gain`)
    Demod { velocity_gain_m_s_per_v: Option<f64> },
    ForceP { kp_v_per_n: f64, u_offset_v: f64 },
    /// position P + velocity feed-forward (thesis 4.1), the force setpoint turned into a position
    /// through the measured specimen stiffness (`PositionForce`); gains from the valve's velocity
    /// gain unless given
    PositionPff { velocity_gain_m_s_per_v: Option<f64>, kp_v_per_m: Option<f64>, kff_v_per_m_s: Option<f64>, u_offset_v: f64 },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Action {
    Flag,
    Stop,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    pub max_cycles: u64,
    pub size_criterion: Action,
    /// consecutive out-of-tolerance cycles allowed before `tolerance_action`
    pub tolerance_cycles: u64,
    pub tolerance_action: Action,
    /// margin kept from either end of the stroke [m]
    pub stroke_margin_m: f64,
}

/// Cycle-jump step control.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JumpConfig {
    /// largest crack growth per jump [m]
    pub max_da_m: f64,
    /// largest relative change of ΔK and of K_sp per jump
    pub max_rel_change: f64,
    /// cycles resolved after a jump before the next (the controller settles)
    pub settle_cycles: u64,
    /// smallest jump worth taking [cycles]
    pub min_jump_cycles: u64,
}

impl Default for JumpConfig {
    fn default() -> Self {
        JumpConfig { max_da_m: 0.5e-3, max_rel_change: 0.01, settle_cycles: 3, min_jump_cycles: 20 }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExecMode {
    Full,
    Jump,
}

#[derive(Debug, Clone, PartialEq)]
pub struct TestConfig {
    pub params: Params,
    pub rtol: f64,
    pub specimen: Specimen,
    pub material: Material,
    pub law: Law,
    pub a0_m: f64,
    pub waveform: Waveform,
    pub frequency_hz: f64,
    pub control_rate_hz: f64,
    pub phases: Vec<Phase>,
    pub controller: ControllerSpec,
    pub envelope: Envelope,
    pub limits: Limits,
    /// (cycle, factor): from that cycle on K_sp = factor·K_sp(a) (step drops, thesis Fig. 4.6)
    pub stiffness_steps: Vec<(u64, f64)>,
    pub jump: JumpConfig,
}

/// Why a test ended.
#[derive(serde::Serialize, serde::Deserialize)] // engine snapshots (resume)
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EndReason {
    TargetCrack,
    Toughness,
    SizeCriterion,
    StrokeLimit,
    CycleLimit,
    ForceTolerance,
    Fracture,
    Cancelled,
}

impl EndReason {
    pub fn name(self) -> &'static str {
        match self {
            EndReason::TargetCrack => "target_crack_length",
            EndReason::Toughness => "kmax_reached_toughness",
            EndReason::SizeCriterion => "size_criterion",
            EndReason::StrokeLimit => "stroke_limit",
            EndReason::CycleLimit => "cycle_limit",
            EndReason::ForceTolerance => "force_out_of_tolerance",
            EndReason::Fracture => "fracture",
            EndReason::Cancelled => "cancelled",
        }
    }
}

/// Event bits of the per-cycle table (exported to Python by name as `htm._core.EVENTS`).
pub mod events {
    pub const START: u32 = 1;
    pub const OUT_OF_TOLERANCE: u32 = 2;
    pub const TOLERANCE_EXCEEDED: u32 = 4;
    pub const SIZE_CRITERION: u32 = 8;
    pub const JUMP: u32 = 16;
    pub const STIFFNESS_STEP: u32 = 32;
    pub const PHASE_CHANGE: u32 = 64;
    pub const STOP: u32 = 128;
    pub const END: u32 = 256;

    /// Every bit by its name, the one list the bindings export.
    pub const NAMED: [(&str, u32); 9] = [
        ("start", START),
        ("out_of_tolerance", OUT_OF_TOLERANCE),
        ("tolerance_exceeded", TOLERANCE_EXCEEDED),
        ("size_criterion", SIZE_CRITERION),
        ("jump", JUMP),
        ("stiffness_step", STIFFNESS_STEP),
        ("phase_change", PHASE_CHANGE),
        ("stop", STOP),
        ("end", END),
    ];
}

/// The per-cycle table (struct of columns). Rows with `JUMP` summarise a jump (forces predicted
/// from the last resolved cycle); `STOP` rows are the smooth stop after the end.
#[derive(Debug, Clone, Default)]
pub struct Records {
    pub cycle: Vec<u64>,
    pub phase: Vec<u8>,
    pub fmax_n: Vec<f64>,
    pub fmin_n: Vec<f64>,
    pub fmax_target_n: Vec<f64>,
    pub fmin_target_n: Vec<f64>,
    pub peak_err_pct: Vec<f64>,
    pub df_err_pct: Vec<f64>,
    pub a_m: Vec<f64>,
    pub delta_k: Vec<f64>,
    pub delta_k_target: Vec<f64>,
    pub kmax: Vec<f64>,
    pub dadn_m: Vec<f64>,
    pub k_sp_n_m: Vec<f64>,
    pub ctrl_u1_v: Vec<f64>,
    pub ctrl_u2_v: Vec<f64>,
    pub events: Vec<u32>,
}

#[derive(Debug, Clone)]
pub struct Outcome {
    pub records: Records,
    pub end_reason: EndReason,
    /// cycles applied to the end (start-up included, smooth stop excluded)
    pub cycles: u64,
    pub a_end_m: f64,
    /// worst |ΔF| and |peak| errors over resolved test cycles (start-up excluded) [%]
    pub max_abs_df_err_pct: f64,
    pub max_abs_peak_err_pct: f64,
    pub cycles_simulated: u64,
    pub size_criterion_cycle: Option<u64>,
    pub velocity_gain_m_s_per_v: f64,
    pub demod_gains: Option<DemodGains>,
}

fn param(field: &str, value: f64, allowed: &str) -> Error {
    Error::Parameter { field: field.into(), value, allowed: allowed.into() }
}

/// Force targets (Fmax, Fmin) [N] and the scheduled ΔK for phase `ph` at crack length `a`.
pub fn targets(cfg: &TestConfig, ph: &Phase, a_phase0: f64, a: f64) -> Result<(f64, f64, f64)> {
    let s = &cfg.specimen;
    let y = s.k(a, 1.0)?; // K per newton
    let (df, dk) = match ph.mode {
        Mode::ConstantForce { delta_f_n } => (delta_f_n, delta_f_n * y),
        Mode::ConstantDeltaK { delta_k } => (delta_k / y, delta_k),
        Mode::KGradient { delta_k0, c_per_m } => {
            let dk = delta_k0 * (c_per_m * (a - a_phase0)).exp();
            (dk / y, dk)
        }
    };
    let fmax = if ph.r_ratio >= 0.0 { df / (1.0 - ph.r_ratio) } else { df };
    Ok((fmax, ph.r_ratio * fmax, dk))
}

/// (ΔK, Kmax, R) from a measured peak and valley [N] (E647: for R < 0, ΔK = Kmax).
#[inline]
fn measured_k(s: &Specimen, a: f64, fmax: f64, fmin: f64, r_nominal: f64) -> Result<(f64, f64, f64)> {
    let kmax = s.k(a, fmax)?;
    let dk = if r_nominal >= 0.0 { s.k(a, fmax - fmin)? } else { kmax };
    Ok((dk, kmax, if fmax != 0.0 { fmin / fmax } else { 0.0 }))
}

impl TestConfig {
    /// Checks everything before anything runs; errors name the field, value and allowed range.
    pub fn validate(&self) -> Result<()> {
        self.params.validate()?;
        self.specimen.validate()?;
        self.material.validate()?;
        self.law.validate()?;
        self.waveform.validate()?;
        let (alo, ahi) = self.specimen.a_range();
        if !(self.a0_m >= alo - 1e-12 && self.a0_m <= ahi) {
            return Err(param("a0_m", self.a0_m, &format!("[{alo}, {ahi}] m (a/W in 0.2–0.975 for C(T))")));
        }
        if !(self.frequency_hz.is_finite() && self.frequency_hz > 0.0) {
            return Err(param("frequency_hz", self.frequency_hz, "(0, inf) Hz"));
        }
        if !(self.control_rate_hz.is_finite() && self.control_rate_hz >= 16.0 * self.frequency_hz) {
            return Err(param("control_rate_hz", self.control_rate_hz, &format!("≥ 16 samples per cycle: ≥ {} Hz", 16.0 * self.frequency_hz)));
        }
        if self.phases.is_empty() {
            return Err(Error::Input("a test needs at least one phase".into()));
        }
        let mut a_prev = self.a0_m;
        for (i, ph) in self.phases.iter().enumerate() {
            let f = |n: &str| format!("phases[{i}].{n}");
            if !(ph.r_ratio.is_finite() && ph.r_ratio >= -1.0 && ph.r_ratio < 1.0) {
                return Err(param(&f("r_ratio"), ph.r_ratio, "[-1, 1)"));
            }
            if !(ph.end_a_m > a_prev && ph.end_a_m <= ahi) {
                return Err(param(&f("end_a_m"), ph.end_a_m, &format!("({a_prev}, {ahi}] m")));
            }
            if !(ph.tolerance > 0.0 && ph.tolerance <= 0.2) {
                return Err(param(&f("tolerance"), ph.tolerance, "(0, 0.2]"));
            }
            match ph.mode {
                Mode::ConstantForce { delta_f_n } if !(delta_f_n.is_finite() && delta_f_n > 0.0) => return Err(param(&f("delta_f_n"), delta_f_n, "(0, inf) N")),
                Mode::ConstantDeltaK { delta_k } if !(delta_k.is_finite() && delta_k > 0.0) => return Err(param(&f("delta_k"), delta_k, "(0, inf) Pa·√m")),
                Mode::KGradient { delta_k0, c_per_m } => {
                    if !(delta_k0.is_finite() && delta_k0 > 0.0) {
                        return Err(param(&f("delta_k0"), delta_k0, "(0, inf) Pa·√m"));
                    }
                    if !(c_per_m.is_finite() && c_per_m >= E647_MIN_K_GRADIENT_PER_M) {
                        return Err(param(&f("k_gradient_per_m"), c_per_m, "≥ −80 1/m (ASTM E647: C ≥ −0.08 mm⁻¹)"));
                    }
                }
                _ => {}
            }
            let (fmax, _, dk) = targets(self, ph, a_prev, a_prev)?;
            let kmax = self.specimen.k(a_prev, fmax)?;
            let kic = self.material.fracture_toughness_pa_sqrt_m;
            if kmax >= kic {
                return Err(param(&f("start Kmax"), kmax, &format!("< K_IC = {kic} Pa·√m (ΔK at start {dk} Pa·√m)")));
            }
            a_prev = ph.end_a_m;
        }
        if self.limits.max_cycles == 0 {
            return Err(param("limits.max_cycles", 0.0, "≥ 1"));
        }
        // what the rig can drive (resonance, valve flow, force, stroke, size criterion) is
        // `feasibility::assess`: a forced test runs past it
        for &(c, fac) in &self.stiffness_steps {
            if !(fac > 0.0 && fac <= 1.0) {
                return Err(param(&format!("stiffness_steps[cycle {c}]"), fac, "(0, 1]"));
            }
        }
        if let ControllerSpec::PositionPff { velocity_gain_m_s_per_v, kp_v_per_m, kff_v_per_m_s, u_offset_v } = self.controller {
            if !u_offset_v.is_finite() {
                return Err(param("controller.u_offset_v", u_offset_v, "finite"));
            }
            for (name, v) in [("velocity_gain_m_s_per_v", velocity_gain_m_s_per_v), ("kp_v_per_m", kp_v_per_m)] {
                if let Some(v) = v {
                    if !(v.is_finite() && v != 0.0) {
                        return Err(param(&format!("controller.{name}"), v, "non-zero, finite (negative on the thesis rig)"));
                    }
                }
            }
            if let Some(v) = kff_v_per_m_s.filter(|v| !v.is_finite()) {
                return Err(param("controller.kff_v_per_m_s", v, "finite (0 = no feed-forward)"));
            }
        }
        if let ControllerSpec::ForceP { kp_v_per_n, u_offset_v } = self.controller {
            if !(kp_v_per_n.is_finite() && kp_v_per_n != 0.0) {
                return Err(param("controller.kp_v_per_n", kp_v_per_n, "non-zero, finite (negative on the thesis rig)"));
            }
            if !u_offset_v.is_finite() {
                return Err(param("controller.u_offset_v", u_offset_v, "finite"));
            }
        }
        Ok(())
    }
}

/// Small-signal velocity gain [m/s per V] of the free piston (no specimen), measured on the plant
/// model itself around the command that holds it still: the gain rule's k_v. It bisects the
/// command for zero velocity (the hydraulic null), then takes the speed at null ± `delta_v`.
pub fn measure_velocity_gain(params: &Params, delta_v: f64) -> Result<f64> {
    let mut p = params.clone();
    p.specimen_stiffness_n_m = 0.0;
    let speed = |u: f64| -> Result<f64> {
        let mut m = Machine::new(p.clone())?.with_rtol(1e-5)?;
        for _ in 0..100 {
            m.step(u, 1e-3)?;
        }
        Ok(m.outputs().v)
    };
    let umax = p.valve_max_command_v;
    let (mut lo, mut hi) = (-0.5 * umax, 0.5 * umax);
    let (mut vlo, _) = (speed(lo)?, 0);
    for _ in 0..30 {
        let mid = 0.5 * (lo + hi);
        let vm = speed(mid)?;
        if vm.signum() == vlo.signum() {
            lo = mid;
            vlo = vm;
        } else {
            hi = mid;
        }
    }
    let null = 0.5 * (lo + hi);
    let k = (speed(null + delta_v)? - speed(null - delta_v)?) / (2.0 * delta_v);
    if !(k.is_finite() && k != 0.0) {
        return Err(Error::Solver("could not measure the valve velocity gain".into()));
    }
    Ok(k)
}

/// Oil-column stiffness of the cylinder at piston position `y` [N/m]: β·(A_A²/V_A + A_B²/V_B).
pub fn hydraulic_stiffness(p: &Params, y: f64) -> f64 {
    let y = y.clamp(0.0, p.stroke_m);
    let va = p.dead_volume_a_m3 + p.area_a_m2 * y;
    let vb = p.dead_volume_b_m3 + p.area_b_m2 * (p.stroke_m - y);
    p.bulk_modulus_pa * (p.area_a_m2 * p.area_a_m2 / va + p.area_b_m2 * p.area_b_m2 / vb)
}

/// Two springs in series [N/m]: the valve's flow compresses the oil column and stretches the
/// specimen, so the force rate per unit flow sees 1/(1/K_sp + 1/K_oil), not K_sp alone.
pub fn series_stiffness(k1: f64, k2: f64) -> f64 {
    1.0 / (1.0 / k1 + 1.0 / k2)
}

struct Run<'a> {
    cfg: &'a TestConfig,
    m: Machine,
    ctrl: ForceLoop,
    n: usize,
    dt: f64,
    a: f64,
    ksp_factor: f64,
    y0: f64,
    cycle: u64,
    rec: Records,
    max_df: f64,
    max_peak: f64,
    out_count: u64,
    size_cycle: Option<u64>,
    simulated: u64,
    progress: Option<&'a AtomicU64>,
    cancel: Option<&'a AtomicBool>,
    /// peak-valley compensation of the demodulation controller's setpoint (control.rs), applied
    /// to every cycle and learning from every cycle with enough amplitude, ramp-in included
    pv: PeakValley,
    compensate: bool,
    /// set when the test runs in position control (then `ctrl` is unused)
    position: Option<PositionForce>,
    /// raw high-rate windows (see `RawCapture`)
    raw: RawCapture,
}

struct CycleResult {
    fmax: f64,
    fmin: f64,
    /// peak and valley of the nominal (uncompensated) setpoint in the cycle [N]
    rmax: f64,
    rmin: f64,
    ymin: f64,
    ymax: f64,
}

impl<'a> Run<'a> {
    /// One cycle through the plant; `mid(x)`, `amp(x)` give the setpoint at cycle position x ∈ [0, 1].
    fn cycle_through<F: Fn(f64) -> (f64, f64)>(&mut self, set: F) -> Result<CycleResult> {
        let n = self.n;
        let w = &self.cfg.waveform;
        let sine = matches!(w, Waveform::Sine);
        let (mut fmax, mut fmin, mut ymin, mut ymax) = (f64::MIN, f64::MAX, f64::MAX, f64::MIN);
        let step = 2.0 * std::f64::consts::PI / n as f64;
        let (cs, ss) = (step.cos(), step.sin());
        let (mut sn, mut cn) = (0.0f64, 1.0f64);
        let mut s = 0.0;
        let pv = if self.compensate { self.pv } else { PeakValley::new() };
        // the nominal setpoint's true peak and valley (mid ± amp where the shape peaks): the
        // sampled shape can miss the corner between two samples (a triangle at 20 Hz, 1 kHz)
        let (mut rmax, mut rmin, mut s_hi, mut s_lo) = (f64::MIN, f64::MAX, f64::MIN, f64::MAX);
        let (mid0, amp0) = set(0.0);
        let (mut mid, mut amp) = pv.apply(mid0, amp0);
        let mut meas = self.m.outputs();
        for k in 0..n {
            let x1 = (k + 1) as f64 / n as f64;
            let (sn1, cn1) = (sn * cs + cn * ss, cn * cs - sn * ss);
            let s_next = if sine { sn1 } else { w.shape(x1) };
            let (nmid1, namp1) = set(x1);
            if s_next > s_hi {
                (s_hi, rmax) = (s_next, nmid1 + namp1);
            }
            if s_next < s_lo {
                (s_lo, rmin) = (s_next, nmid1 - namp1);
            }
            let (mid1, amp1) = pv.apply(nmid1, namp1);
            let sp = Setpoint { mid_n: mid, mid_next_n: mid1, amp_n: amp, s, s_next, sin: sn, cos: cn };
            let u = match &self.position {
                Some(pc) => pc.command(&sp, &meas, self.dt),
                None => self.ctrl.command(&sp, meas.f),
            };
            let o = self.m.step(u, self.dt)?;
            self.raw.sample((self.cycle as f64 + x1) / self.cfg.frequency_hz, u, &o, mid1 + amp1 * s_next);
            let f = o.f;
            meas = o;
            fmax = fmax.max(f);
            fmin = fmin.min(f);
            ymin = ymin.min(o.y);
            ymax = ymax.max(o.y);
            sn = sn1;
            cn = cn1;
            s = s_next;
            mid = mid1;
            amp = amp1;
        }
        self.simulated += 1;
        if let Some(pc) = &mut self.position {
            pc.measured(fmax - fmin, ymax - ymin);
        }
        Ok(CycleResult { fmax, fmin, rmax, rmin, ymin, ymax })
    }

    fn set_stiffness(&mut self, keep_force: bool) -> Result<()> {
        let k_new = self.cfg.specimen.stiffness(self.a, &self.cfg.material)? * self.ksp_factor;
        let k_old = self.m.plant.p.specimen_stiffness_n_m;
        if keep_force && k_old > 0.0 {
            // a jump: keep the force continuous and tell the controller about the new gain
            self.m.x[Y] = self.y0 + (self.m.x[Y] - self.y0) * k_old / k_new;
            self.ctrl.rescale_gain(k_new / k_old);
        }
        self.m.plant.p.specimen_stiffness_n_m = k_new;
        Ok(())
    }

    #[allow(clippy::too_many_arguments)]
    fn push(&mut self, phase: u8, fmax: f64, fmin: f64, t: (f64, f64, f64), dk: f64, kmax: f64, dadn: f64, ev: u32) {
        let (tmax, tmin, dkt) = t;
        let r = &mut self.rec;
        let pe = (fmax - tmax) / tmax * 100.0;
        let de = ((fmax - fmin) - (tmax - tmin)) / (tmax - tmin) * 100.0;
        let (u1, u2, _, _) = self.ctrl.summary();
        r.cycle.push(self.cycle);
        r.phase.push(phase);
        r.fmax_n.push(fmax);
        r.fmin_n.push(fmin);
        r.fmax_target_n.push(tmax);
        r.fmin_target_n.push(tmin);
        r.peak_err_pct.push(pe);
        r.df_err_pct.push(de);
        r.a_m.push(self.a);
        r.delta_k.push(dk);
        r.delta_k_target.push(dkt);
        r.kmax.push(kmax);
        r.dadn_m.push(dadn);
        r.k_sp_n_m.push(self.m.plant.p.specimen_stiffness_n_m);
        r.ctrl_u1_v.push(u1);
        r.ctrl_u2_v.push(u2);
        r.events.push(ev);
        self.raw.end_cycle(self.cycle, ev);
    }
}

/// Run one test. `progress` receives the cycle count as it goes; `cancel` stops it.
pub fn run_test(cfg: &TestConfig, mode: ExecMode, progress: Option<&AtomicU64>, cancel: Option<&AtomicBool>) -> Result<Outcome> {
    let (mut run, kv, gains) = start(cfg, progress, cancel, RawCapture::default())?;
    let mut cur = Cursor::new(cfg);
    let end = advance(&mut run, mode, &mut cur, u64::MAX, None)?.expect("an unbounded advance runs to the end");
    finish(&mut run, end, &cur, kv, gains)
}

/// A test at rest, ready for its first cycle: the plant at the specimen's zero-force position and
/// the controller designed for it (the valve's velocity gain is measured here when not given).
#[allow(clippy::type_complexity)]
fn start<'a>(cfg: &'a TestConfig, progress: Option<&'a AtomicU64>, cancel: Option<&'a AtomicBool>, raw: RawCapture) -> Result<(Run<'a>, f64, Option<DemodGains>)> {
    cfg.validate()?;
    let mut p = cfg.params.clone();
    let ksp0 = cfg.specimen.stiffness(cfg.a0_m, &cfg.material)?;
    p.specimen_stiffness_n_m = ksp0;
    let m = Machine::new(p)?.with_rtol(cfg.rtol)?;
    let y0 = m.plant.p.specimen_zero_force_position_m;
    let n = (cfg.control_rate_hz / cfg.frequency_hz).round() as usize;
    let dt = 1.0 / (n as f64 * cfg.frequency_hz);
    let u_max = cfg.params.valve_max_command_v;
    // the valve's gain depends on the opening (low near null): measure it at the command
    // amplitude the test will need (two fixed-point rounds from 0.1 V)
    let measured_kv = || -> Result<f64> {
        let (fmax, fmin, _) = targets(cfg, &cfg.phases[0], cfg.a0_m, cfg.a0_m)?;
        let k_eff = series_stiffness(ksp0, hydraulic_stiffness(&cfg.params, y0));
        let need = |kv: f64| (0.5 * (fmax - fmin) * 2.0 * std::f64::consts::PI * cfg.frequency_hz / (k_eff * kv)).abs().clamp(0.005, 1.0);
        let mut kv = measure_velocity_gain(&cfg.params, 0.1)?;
        for _ in 0..2 {
            kv = measure_velocity_gain(&cfg.params, need(kv))?;
        }
        Ok(kv)
    };
    let mut position = None;
    let (ctrl, kv, gains) = match cfg.controller {
        ControllerSpec::ForceP { kp_v_per_n, u_offset_v } => (ForceLoop::ForceP { kp_v_per_n, u_offset_v, u_max_v: u_max }, f64::NAN, None),
        ControllerSpec::Demod { velocity_gain_m_s_per_v } => {
            let kv = match velocity_gain_m_s_per_v {
                Some(k) => k,
                None => measured_kv()?,
            };
            let k_eff = series_stiffness(ksp0, hydraulic_stiffness(&cfg.params, y0));
            let g = DemodGains::design(k_eff, kv, cfg.frequency_hz, n as f64 * cfg.frequency_hz)?;
            (ForceLoop::Demod(Demod::new(g, cfg.waveform.stats(), u_max, 0.0)), kv, Some(g))
        }
        ControllerSpec::PositionPff { velocity_gain_m_s_per_v, kp_v_per_m, kff_v_per_m_s, u_offset_v } => {
            let kv = match velocity_gain_m_s_per_v {
                Some(k) => k,
                None => measured_kv()?,
            };
            // against the specimen part of the valve's flow compresses the oil column: the piston
            // moves at k_v·K_series/K_sp
            let k_eff = series_stiffness(ksp0, hydraulic_stiffness(&cfg.params, y0));
            let mut pc = PositionForce::design(kv * k_eff / ksp0, ksp0, y0, u_max)?;
            if let crate::control::Controller::PositionPff { kp_v_per_m: kp, kff_v_per_m_s: kff, .. } = &mut pc.ctrl {
                *kp = kp_v_per_m.unwrap_or(*kp);
                *kff = kff_v_per_m_s.unwrap_or(*kff);
            }
            pc.u_offset_v = u_offset_v;
            position = Some(pc);
            // the force loop is unused in position control
            (ForceLoop::ForceP { kp_v_per_n: 0.0, u_offset_v: 0.0, u_max_v: u_max }, kv, None)
        }
    };
    let run = Run {
        raw,
        cfg, m, ctrl, n, dt, a: cfg.a0_m, ksp_factor: 1.0, y0, cycle: 0, rec: Records::default(),
        max_df: 0.0, max_peak: 0.0, out_count: 0, size_cycle: None, simulated: 0, progress, cancel,
        pv: PeakValley::new(), compensate: matches!(cfg.controller, ControllerSpec::Demod { .. }), position,
    };
    Ok((run, kv, gains))
}

/// The cycle loop's own variables, kept between two calls of `advance`.
#[derive(Debug, Clone, Copy, serde::Serialize, serde::Deserialize)]
struct Cursor {
    phase_i: usize,
    a_phase0: f64,
    next_step: usize,
    since_jump: u64,
    prev_err: (f64, f64),
}

impl Cursor {
    fn new(cfg: &TestConfig) -> Self {
        Cursor { phase_i: 0, a_phase0: cfg.a0_m, next_step: 0, since_jump: 0, prev_err: (f64::NAN, f64::NAN) }
    }
}

/// Run cycles until the test ends (`Some(reason)`), or pause between two cycles (`None`) once the
/// cycle count reaches `until_cycle` or the wall clock passes `deadline`. A paused test continues
/// exactly as if it had never stopped.
fn advance(run: &mut Run, mode: ExecMode, cur: &mut Cursor, until_cycle: u64, deadline: Option<Instant>) -> Result<Option<EndReason>> {
    let cfg = run.cfg;
    let law = &cfg.law;
    let spec = &cfg.specimen;
    let kic = cfg.material.fracture_toughness_pa_sqrt_m;
    let (stroke_lo, stroke_hi) = (cfg.limits.stroke_margin_m, cfg.params.stroke_m - cfg.limits.stroke_margin_m);
    let a_max_valid = spec.a_range().1;
    let Cursor { mut phase_i, mut a_phase0, mut next_step, mut since_jump, mut prev_err } = *cur;
    let n_start = cfg.envelope.start_cycles();
    let mut steps = cfg.stiffness_steps.clone();
    steps.sort_by_key(|s| s.0);
    let end: EndReason;

    loop {
        if let Some(c) = run.cancel {
            if c.load(Ordering::Relaxed) {
                end = EndReason::Cancelled;
                break;
            }
        }
        if run.cycle >= until_cycle || deadline.is_some_and(|d| Instant::now() >= d) {
            *cur = Cursor { phase_i, a_phase0, next_step, since_jump, prev_err };
            return Ok(None);
        }
        // scheduled stiffness steps (before this cycle)
        let mut ev = 0u32;
        while next_step < steps.len() && steps[next_step].0 <= run.cycle + 1 {
            run.ksp_factor = steps[next_step].1;
            run.set_stiffness(false)?;
            next_step += 1;
            ev |= events::STIFFNESS_STEP;
        }
        let ph = cfg.phases[phase_i];
        let t = targets(cfg, &ph, a_phase0, run.a)?;
        let (mid_t, amp_t) = (0.5 * (t.0 + t.1), 0.5 * (t.0 - t.1));
        let starting = run.cycle < n_start;
        let c0 = run.cycle as f64;
        let env = cfg.envelope;
        let res = if starting {
            ev |= events::START;
            run.cycle_through(|x| {
                let (fm, fa) = env.start(c0 + x);
                (mid_t * fm, amp_t * fa)
            })?
        } else {
            run.cycle_through(|_| (mid_t, amp_t))?
        };
        if run.compensate && res.rmax - res.rmin >= PeakValley::MIN_AMPLITUDE_FRACTION * 2.0 * amp_t {
            run.pv.update(res.rmax, res.rmin, res.fmax, res.fmin);
        }
        run.cycle += 1;
        since_jump += 1;
        if let Some(p) = run.progress {
            p.store(run.cycle, Ordering::Relaxed);
        }
        // crack growth from the measured peak and valley
        let (dk, kmax, r_meas) = if res.fmax > 0.0 { measured_k(spec, run.a, res.fmax, res.fmin, ph.r_ratio)? } else { (0.0, 0.0, 0.0) };
        let dadn = law.rate(dk, r_meas, kmax);
        // tolerance (test cycles only)
        let pe = (res.fmax - t.0) / t.0;
        let de = ((res.fmax - res.fmin) - (t.0 - t.1)) / (t.0 - t.1);
        let mut stop: Option<EndReason> = None;
        if !starting {
            run.max_peak = run.max_peak.max(pe.abs() * 100.0);
            run.max_df = run.max_df.max(de.abs() * 100.0);
            if pe.abs() > ph.tolerance || de.abs() > ph.tolerance {
                ev |= events::OUT_OF_TOLERANCE;
                run.out_count += 1;
                if run.out_count > cfg.limits.tolerance_cycles {
                    ev |= events::TOLERANCE_EXCEEDED;
                    if cfg.limits.tolerance_action == Action::Stop {
                        stop = Some(EndReason::ForceTolerance);
                    }
                }
            } else {
                run.out_count = 0;
            }
        }
        if kmax >= kic {
            stop = stop.or(Some(EndReason::Toughness));
        }
        if res.fmax > 0.0 {
            let (lig, req) = spec.size_criterion(run.a, res.fmax, cfg.material.yield_strength_pa)?;
            if lig < req {
                ev |= events::SIZE_CRITERION;
                run.size_cycle.get_or_insert(run.cycle);
                if cfg.limits.size_criterion == Action::Stop {
                    stop = stop.or(Some(EndReason::SizeCriterion));
                }
            }
        }
        if res.ymin < stroke_lo || res.ymax > stroke_hi {
            stop = stop.or(Some(EndReason::StrokeLimit));
        }
        run.push(phase_i as u8, res.fmax, res.fmin, t, dk, kmax, dadn, ev);
        let (last_fmax, last_fmin, last_ev) = (res.fmax, res.fmin, ev);
        // settled: peak and range errors changed by < 0.01 % of target over the last cycle
        let settled = (pe - prev_err.0).abs() < 1e-4 && (de - prev_err.1).abs() < 1e-4;
        prev_err = (pe, de);
        if let Some(r) = stop {
            end = r;
            break;
        }
        if !dadn.is_finite() || run.a + dadn >= a_max_valid {
            end = EndReason::Fracture;
            break;
        }
        run.a += dadn;
        if run.a >= ph.end_a_m {
            if phase_i + 1 == cfg.phases.len() {
                end = EndReason::TargetCrack;
                break;
            }
            phase_i += 1;
            a_phase0 = run.a;
            *run.rec.events.last_mut().unwrap() |= events::PHASE_CHANGE;
            since_jump = 0;
        }
        if run.cycle >= cfg.limits.max_cycles {
            end = EndReason::CycleLimit;
            break;
        }
        run.set_stiffness(false)?;

        // cycle jump
        let ready = since_jump >= cfg.jump.settle_cycles && (settled || since_jump >= 10 * cfg.jump.settle_cycles);
        if mode == ExecMode::Jump && !starting && ready && res.fmax > 0.0 {
            let ph = cfg.phases[phase_i];
            let t_now = targets(cfg, &ph, a_phase0, run.a)?;
            let (rmax, rmin) = (last_fmax / t_now.0, if t_now.1 != 0.0 { last_fmin / t_now.1 } else { f64::NAN });
            let forces = |a: f64| -> Result<(f64, f64)> {
                let t = targets(cfg, &ph, a_phase0, a)?;
                Ok((t.0 * rmax, if t.1 != 0.0 { t.1 * rmin } else { last_fmin }))
            };
            let rate = |a: f64| -> Result<f64> {
                let (fx, fn_) = forces(a)?;
                let (dk, kmax, r) = measured_k(spec, a, fx, fn_, ph.r_ratio)?;
                Ok(law.rate(dk, r, kmax))
            };
            // largest Δa within the bounds on Δa, ΔK and K_sp change, and the phase end
            let y_now = spec.k(run.a, 1.0)?;
            let dk_now = measured_k(spec, run.a, forces(run.a)?.0, forces(run.a)?.1, ph.r_ratio)?.0;
            let k_now = spec.stiffness(run.a, &cfg.material)?;
            let rel = cfg.jump.max_rel_change;
            let mut da = cfg.jump.max_da_m.min(ph.end_a_m - run.a);
            for _ in 0..30 {
                let a1 = run.a + da;
                let ok = a1 < a_max_valid && {
                    let (fx, fn_) = forces(a1)?;
                    let dk1 = measured_k(spec, a1, fx, fn_, ph.r_ratio)?.0;
                    let k1 = spec.stiffness(a1, &cfg.material)?;
                    let y1 = spec.k(a1, 1.0)?;
                    (dk1 / dk_now - 1.0).abs() <= rel && (k1 / k_now - 1.0).abs() <= rel && (y1 / y_now - 1.0).abs() <= 4.0 * rel
                };
                if ok {
                    break;
                }
                da *= 0.5;
            }
            let r_mid = rate(run.a + 0.5 * da)?;
            let mut jn = if r_mid > 0.0 && r_mid.is_finite() { (da / r_mid).floor() as u64 } else { 0 };
            jn = jn.min(cfg.limits.max_cycles - run.cycle);
            if next_step < steps.len() {
                jn = jn.min(steps[next_step].0.saturating_sub(run.cycle + 1));
            }
            // RK4 in N across the jump, shortened while it would cross an end condition
            loop {
                if jn < cfg.jump.min_jump_cycles {
                    jn = 0;
                    break;
                }
                let h = jn as f64;
                let k1 = rate(run.a)?;
                let k2 = rate(run.a + 0.5 * h * k1)?;
                let k3 = rate(run.a + 0.5 * h * k2)?;
                let k4 = rate(run.a + h * k3)?;
                let a1 = run.a + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
                let (fx, _) = forces(a1)?;
                let kmax1 = spec.k(a1, fx).unwrap_or(f64::INFINITY);
                let (lig, req) = spec.size_criterion(a1, fx, cfg.material.yield_strength_pa).unwrap_or((0.0, 1.0));
                let size_stop = cfg.limits.size_criterion == Action::Stop && lig < req;
                if a1 >= ph.end_a_m || kmax1 >= kic || size_stop || !a1.is_finite() {
                    jn /= 2;
                    continue;
                }
                // apply the jump
                let (fx, fn_) = forces(a1)?;
                let (dk1, km1, r1) = measured_k(spec, a1, fx, fn_, ph.r_ratio)?;
                if last_ev & events::OUT_OF_TOLERANCE != 0 {
                    run.out_count += jn;
                }
                if lig < req {
                    run.size_cycle.get_or_insert(run.cycle + 1);
                }
                run.cycle += jn;
                run.a = a1;
                run.set_stiffness(true)?;
                let t1 = targets(cfg, &ph, a_phase0, a1)?;
                let ev = events::JUMP | if lig < req { events::SIZE_CRITERION } else { 0 };
                run.push(phase_i as u8, fx, fn_, t1, dk1, km1, law.rate(dk1, r1, km1), ev);
                since_jump = 0;
                break;
            }
            if jn > 0 && run.cycle >= cfg.limits.max_cycles {
                end = EndReason::CycleLimit;
                break;
            }
        }
    }
    *cur = Cursor { phase_i, a_phase0, next_step, since_jump, prev_err };
    Ok(Some(end))
}

/// After the end: mark the last row, ramp the amplitude down (smooth stop) and sum up.
fn finish(run: &mut Run, end: EndReason, cur: &Cursor, kv: f64, gains: Option<DemodGains>) -> Result<Outcome> {
    let cfg = run.cfg;
    let a_max_valid = cfg.specimen.a_range().1;
    let Cursor { phase_i, a_phase0, .. } = *cur;
    if let Some(r) = run.rec.events.last_mut() {
        *r |= events::END;
    }
    let cycles = run.cycle;
    let a_end = run.a;
    // smooth stop: amplitude ramps to zero at the last setpoint (not counted, no growth)
    if !matches!(end, EndReason::StrokeLimit | EndReason::Fracture | EndReason::Cancelled) && cfg.envelope.stop_cycles > 0.0 {
        let ph = cfg.phases[phase_i];
        let t = targets(cfg, &ph, a_phase0, run.a.min(a_max_valid))?;
        let (mid_t, amp_t) = (0.5 * (t.0 + t.1), 0.5 * (t.0 - t.1));
        let ns = cfg.envelope.stop_cycles.ceil() as u64;
        for i in 0..ns {
            let ci = i as f64;
            let env = cfg.envelope;
            let res = run.cycle_through(|x| (mid_t, amp_t * (1.0 - crate::waveform::smoothstep(((ci + x) / env.stop_cycles).min(1.0)))))?;
            run.cycle = cycles + i + 1;
            run.push(phase_i as u8, res.fmax, res.fmin, t, f64::NAN, f64::NAN, 0.0, events::STOP);
        }
        run.cycle = cycles;
    }
    Ok(Outcome {
        records: std::mem::take(&mut run.rec),
        end_reason: end,
        cycles,
        a_end_m: a_end,
        max_abs_df_err_pct: run.max_df,
        max_abs_peak_err_pct: run.max_peak,
        cycles_simulated: run.simulated,
        size_criterion_cycle: run.size_cycle,
        velocity_gain_m_s_per_v: kv,
        demod_gains: gains,
    })
}

/// Run many tests on `threads` worker threads (0 = all cores); results in input order.
pub fn run_batch(cfgs: &[TestConfig], mode: ExecMode, threads: usize) -> Vec<Result<Outcome>> {
    let threads = if threads == 0 { std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1) } else { threads }.max(1).min(cfgs.len().max(1));
    let next = AtomicUsize::new(0);
    let mut slots: Vec<Option<Result<Outcome>>> = (0..cfgs.len()).map(|_| None).collect();
    let results = std::sync::Mutex::new(&mut slots);
    std::thread::scope(|s| {
        for _ in 0..threads {
            s.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                if i >= cfgs.len() {
                    break;
                }
                let r = run_test(&cfgs[i], mode, None, None);
                results.lock().unwrap()[i] = Some(r);
            });
        }
    });
    slots.into_iter().map(|r| r.unwrap()).collect()
}

mod raw;
mod session;
pub use raw::{RawCapture, RAW_COLUMNS};
pub use session::{Chunk, Session};

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::specimen::Geometry;

    /// Table B.1's C(T) (B = 6.35 mm, W = 50.8 mm, ΔP = 4.45 kN, R = 0.1) on the thesis rig, with
    /// a Paris law through Table B.1's row 4 (8.21e-5 mm/cycle at 19.3 MPa·√m, m = 3) scaled by `c_scale`.
    pub fn table_b1(freq: f64, rate: f64, a_end_over_w: f64, c_scale: f64) -> TestConfig {
        let w = 50.8e-3;
        TestConfig {
            params: Params::default(),
            rtol: 1e-4,
            specimen: Specimen::new(Geometry::CT, w, 6.35e-3).unwrap(),
            material: Material::default(),
            law: Law::Paris { c: c_scale * 8.21e-8 / 19.3e6f64.powi(3), m: 3.0 },
            a0_m: 15.2e-3,
            waveform: Waveform::Sine,
            frequency_hz: freq,
            control_rate_hz: rate,
            phases: vec![Phase { mode: Mode::ConstantForce { delta_f_n: 4.45e3 }, r_ratio: 0.1, end_a_m: a_end_over_w * w, tolerance: 0.02 }],
            controller: ControllerSpec::Demod { velocity_gain_m_s_per_v: None },
            envelope: Envelope { mean_cycles: 5.0, amplitude_cycles: 20.0, stop_cycles: 3.0 },
            limits: Limits { max_cycles: 10_000_000, size_criterion: Action::Flag, tolerance_cycles: 10, tolerance_action: Action::Flag, stroke_margin_m: 1e-3 },
            stiffness_steps: vec![],
            jump: JumpConfig::default(),
        }
    }

    #[test]
    fn demod_holds_two_percent_as_the_crack_grows_and_jump_agrees() {
        let cfg = table_b1(10.0, 1000.0, 0.35, 30.0);
        let o = run_test(&cfg, ExecMode::Full, None, None).unwrap();
        assert_eq!(o.end_reason, EndReason::TargetCrack);
        assert!(o.max_abs_df_err_pct < 2.0 && o.max_abs_peak_err_pct < 2.0, "{} {}", o.max_abs_df_err_pct, o.max_abs_peak_err_pct);
        let r = &o.records;
        let n = r.cycle.len();
        assert!(r.k_sp_n_m[n - 1] < 0.8 * r.k_sp_n_m[0], "K_sp must fall as the crack grows");
        assert!(r.events[..20].iter().all(|e| e & events::START != 0));
        let j = run_test(&cfg, ExecMode::Jump, None, None).unwrap();
        assert!(j.cycles_simulated * 3 < o.cycles_simulated, "jump resolved {} of {}", j.cycles_simulated, o.cycles);
        let err = (j.cycles as f64 / o.cycles as f64 - 1.0).abs();
        assert!(err < 0.01, "jump {} vs full {}", j.cycles, o.cycles);
    }

    #[test]
    fn bad_configs_fail_before_running() {
        let mut c = table_b1(10.0, 1000.0, 0.35, 1.0);
        c.phases[0].mode = Mode::KGradient { delta_k0: 10e6, c_per_m: -100.0 };
        assert!(run_test(&c, ExecMode::Full, None, None).unwrap_err().to_string().contains("k_gradient_per_m"));
        let mut c = table_b1(10.0, 1000.0, 0.35, 1.0);
        c.phases[0].r_ratio = 1.0;
        assert!(c.validate().unwrap_err().to_string().contains("r_ratio"));
        let mut c = table_b1(10.0, 1000.0, 0.35, 1.0);
        c.material.fracture_toughness_pa_sqrt_m = 15e6;
        assert!(c.validate().unwrap_err().to_string().contains("K_IC"));
    }
}
