//! What a fatigue test is: its configuration and validation, the force targets of a cycle, the
//! per-cycle table and the outcome, and the plant facts the controller design needs.
use crate::control::DemodGains;
use crate::crack::Law;
use crate::error::{Error, Result};
use crate::machine::Machine;
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

/// Stress ratios R a test phase may run: [lo, hi). Narrower than a load's
/// (`crack::LOAD_R_RATIO_RANGE`): the rig grips a C(T) for tension only, so a test's valley is at
/// most the peak's mirror.
pub const TEST_R_RATIO_RANGE: (f64, f64) = (-1.0, 1.0);
/// Largest force tolerance of a phase (a fraction; the tolerance must lie in (0, this]).
pub const MAX_TOLERANCE: f64 = 0.2;
/// Force tolerance of the test proper and of a precrack (ISO 12108) when a spec gives none.
pub const TEST_TOLERANCE: f64 = 0.02;
pub const PRECRACK_TOLERANCE: f64 = 0.05;
/// Fewest control samples per load cycle (control_rate_hz ≥ this × frequency_hz).
pub const MIN_SAMPLES_PER_CYCLE: f64 = 16.0;
/// Highest control rate a test may ask for [Hz].
pub const MAX_CONTROL_RATE_HZ: f64 = 1e5;
/// Integrator tolerance and control rate [Hz] of a test that gives none.
pub const DEFAULT_RTOL: f64 = 1e-4;
/// Integrator tolerances a test may ask for: [lo, hi] (the plant takes any in (0, 1); a test
/// tighter than lo never ends, looser than hi misses the force tolerance).
pub const RTOL_RANGE: (f64, f64) = (1e-8, 1e-2);
pub const DEFAULT_CONTROL_RATE_HZ: f64 = 1000.0;

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

/// A controller as named parameters (a spec's `[controller]` table, SI): `type` is
/// demodulation, force_p or position_pff; the gains its type does not use are ignored.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ControllerSpecArgs {
    pub kind: String,
    pub velocity_gain_m_s_per_v: Option<f64>,
    pub kp_v_per_n: Option<f64>,
    pub kp_v_per_m: Option<f64>,
    pub kff_v_per_m_s: Option<f64>,
    pub u_offset_v: Option<f64>,
}

impl ControllerSpecArgs {
    /// The controller spec; a gain its type needs and lacks is an input error naming it. The
    /// command offset defaults to 0 V.
    pub fn build(&self) -> Result<ControllerSpec> {
        let u_offset_v = self.u_offset_v.unwrap_or(0.0);
        match self.kind.as_str() {
            "demodulation" => Ok(ControllerSpec::Demod { velocity_gain_m_s_per_v: self.velocity_gain_m_s_per_v }),
            "force_p" => Ok(ControllerSpec::ForceP {
                kp_v_per_n: self.kp_v_per_n.ok_or_else(|| Error::Input("controller.kp_v_per_n is missing".into()))?,
                u_offset_v,
            }),
            "position_pff" => Ok(ControllerSpec::PositionPff {
                velocity_gain_m_s_per_v: self.velocity_gain_m_s_per_v, kp_v_per_m: self.kp_v_per_m, kff_v_per_m_s: self.kff_v_per_m_s, u_offset_v,
            }),
            other => Err(Error::Input(format!("controller.type = `{other}`: use demodulation, force_p or position_pff"))),
        }
    }
}

/// A phase as named parameters (a spec's `[precrack]` or `[loading]` table, SI, named as the
/// spec names them): `mode` is constant_force (needs `delta_f_n`), constant_delta_k
/// (`delta_k_pa_sqrt_m`) or k_gradient (`delta_k_pa_sqrt_m`, `k_gradient_per_m`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PhaseArgs {
    pub mode: String,
    pub r_ratio: Option<f64>,
    pub end_a_m: Option<f64>,
    pub tolerance: Option<f64>,
    pub delta_f_n: Option<f64>,
    pub delta_k_pa_sqrt_m: Option<f64>,
    pub k_gradient_per_m: Option<f64>,
}

impl PhaseArgs {
    /// The phase; `section` (`precrack` or `loading`) names a missing value in the error.
    pub fn build(&self, section: &str) -> Result<Phase> {
        let need = |k: &str, v: Option<f64>| v.ok_or_else(|| Error::Input(format!("{section}.{k} is missing")));
        let mode = match self.mode.as_str() {
            "constant_force" => Mode::ConstantForce { delta_f_n: need("delta_f_n", self.delta_f_n)? },
            "constant_delta_k" => Mode::ConstantDeltaK { delta_k: need("delta_k_pa_sqrt_m", self.delta_k_pa_sqrt_m)? },
            "k_gradient" => Mode::KGradient {
                delta_k0: need("delta_k_pa_sqrt_m", self.delta_k_pa_sqrt_m)?,
                c_per_m: need("k_gradient_per_m", self.k_gradient_per_m)?,
            },
            other => return Err(Error::Input(format!("{section}.mode = `{other}`: use constant_force, constant_delta_k or k_gradient"))),
        };
        Ok(Phase { mode, r_ratio: need("r_ratio", self.r_ratio)?, end_a_m: need("end_a_m", self.end_a_m)?, tolerance: need("tolerance", self.tolerance)? })
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Action {
    Flag,
    Stop,
}

impl Action {
    /// The action by its spec name, "flag" or "stop"; `field` names it in the error.
    pub fn parse(s: &str, field: &str) -> Result<Action> {
        match s {
            "flag" => Ok(Action::Flag),
            "stop" => Ok(Action::Stop),
            other => Err(Error::Input(format!("{field} = `{other}`: use \"flag\" or \"stop\""))),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Action::Flag => "flag",
            Action::Stop => "stop",
        }
    }
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

/// The end conditions of a test that states none.
impl Default for Limits {
    fn default() -> Self {
        Limits { max_cycles: 100_000_000, size_criterion: Action::Flag, tolerance_cycles: 10, tolerance_action: Action::Flag, stroke_margin_m: 1e-3 }
    }
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
    /// variable-amplitude loading (empty = constant amplitude from the phases): force levels
    /// applied in turn and repeated to the end; a level replaces the phase's force range
    pub sequence: Vec<Level>,
    /// the sequence came from a spectrum (`[variable_amplitude] spectrum`, one cycle a level),
    /// not from blocks: how an error names a level
    pub sequence_from_spectrum: bool,
    /// where the crack size the test runs on comes from (`[measurement]`; the law when none)
    pub measurement: super::measured::Measurement,
}

/// One level of a variable-amplitude sequence: peak and valley [N] for `cycles` cycles (a block;
/// a spectrum file gives one cycle per level).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Level {
    pub fmax_n: f64,
    pub fmin_n: f64,
    pub cycles: u64,
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
    /// the amplitude ramps back in after a hold (counted, not judged against the tolerance)
    pub const RAMP: u32 = 512;
    /// a crack reading was taken this cycle (measured crack)
    pub const READING: u32 = 1024;
    /// a crack reading failed (too few samples, gauge out of its range): the last ones stand
    pub const READING_FAILED: u32 = 2048;
    /// a crack reading taken this cycle leaves the opening force not resolved (the clip gauge's
    /// noise hides any closure): `opening_force_n` and ΔK_eff are NaN, not claimed, until a
    /// reading resolves it
    pub const CLOSURE_UNRESOLVED: u32 = 4096;

    /// Every bit by its name, the one list the bindings export.
    pub const NAMED: [(&str, u32); 13] = [
        ("start", START),
        ("out_of_tolerance", OUT_OF_TOLERANCE),
        ("tolerance_exceeded", TOLERANCE_EXCEEDED),
        ("size_criterion", SIZE_CRITERION),
        ("jump", JUMP),
        ("stiffness_step", STIFFNESS_STEP),
        ("phase_change", PHASE_CHANGE),
        ("stop", STOP),
        ("end", END),
        ("ramp", RAMP),
        ("reading", READING),
        ("reading_failed", READING_FAILED),
        ("closure_unresolved", CLOSURE_UNRESOLVED),
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
    /// the growth law's crack beside the measured one (= a_m when the test runs on the law) [m]
    pub a_law_m: Vec<f64>,
    /// opening force of the last reading (2 % compliance offset) [N] and ΔK_eff [Pa·√m] (NaN
    /// without a compliance measurement)
    pub opening_force_n: Vec<f64>,
    pub delta_k_eff: Vec<f64>,
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
    /// how fast |ΔF error| came into the band after the start, each resume and stiffness step
    pub convergence: Vec<super::convergence::Episode>,
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
    let (fmax, fmin) = force_range(df, ph.r_ratio);
    Ok((fmax, fmin, dk))
}

/// Peak and valley [N] of a force range ΔF [N] at stress ratio R (E647: for R < 0 the range is
/// the peak, ΔF = Fmax).
pub fn force_range(delta_f_n: f64, r_ratio: f64) -> (f64, f64) {
    let fmax = if r_ratio >= 0.0 { delta_f_n / (1.0 - r_ratio) } else { delta_f_n };
    (fmax, r_ratio * fmax)
}

/// (ΔK, Kmax, R) from a measured peak and valley [N] (E647: for R < 0, ΔK = Kmax). The one
/// rule for the controller's bookkeeping and for the virtual rig's specimen (which knows no
/// nominal R and passes the measured one).
#[inline]
pub fn measured_k(s: &Specimen, a: f64, fmax: f64, fmin: f64, r_nominal: f64) -> Result<(f64, f64, f64)> {
    let kmax = s.k(a, fmax)?;
    let dk = if r_nominal >= 0.0 { s.k(a, fmax - fmin)? } else { kmax };
    Ok((dk, kmax, if fmax != 0.0 { fmin / fmax } else { 0.0 }))
}

/// A sub-check's error with its field under the spec's `section` (`material` → `material.poisson_ratio`).
pub fn within<T>(section: &str, r: Result<T>) -> Result<T> {
    r.map_err(|e| match e {
        Error::Parameter { field, value, allowed } => Error::Parameter { field: format!("{section}.{field}"), value, allowed },
        other => other,
    })
}

impl TestConfig {
    /// The spec's table of phase `i`: the last phase is the test proper (`[loading]`), the one
    /// before it the precrack (`[precrack]`).
    pub fn phase_section(&self, i: usize) -> String {
        let n = self.phases.len();
        match n - 1 - i.min(n - 1) {
            0 => "loading".into(),
            1 => "precrack".into(),
            _ => format!("phases[{i}]"),
        }
    }

    /// Crack length `a_m` as the spec states an end crack length: a/W (C(T)) or 2a/W (M(T)).
    fn a_over_w(&self, a_m: f64) -> f64 {
        match self.specimen.geometry {
            crate::specimen::Geometry::CT => a_m / self.specimen.width_m,
            crate::specimen::Geometry::MT => 2.0 * a_m / self.specimen.width_m,
        }
    }

    /// Checks everything before anything runs; an error names the field by the spec's own path
    /// (`loading.delta_k_pa_sqrt_m`, `end.a_over_w`, `rig.overrides.supply_pressure_pa`), its
    /// value and the allowed range.
    pub fn validate(&self) -> Result<()> {
        within("rig.overrides", self.params.validate())?;
        let (rlo, rhi) = RTOL_RANGE;
        if !(self.rtol >= rlo && self.rtol <= rhi) {
            return Err(param("run.rtol", self.rtol, &format!("[{rlo:e}, {rhi:e}]")));
        }
        within("specimen", self.specimen.validate())?;
        within("material", self.material.validate())?;
        within("law", self.law.validate())?;
        self.measurement.validate(&self.specimen)?;
        within("loading", self.waveform.validate())?;
        let (alo, ahi) = self.specimen.a_range();
        let (wlo, whi) = self.specimen.geometry.alpha_range();
        let alpha = if self.specimen.geometry == crate::specimen::Geometry::CT { "a/W" } else { "2a/W" };
        if !(self.a0_m >= alo - 1e-12 && self.a0_m <= ahi) {
            return Err(param("specimen.a0_m", self.a0_m, &format!("[{alo}, {ahi}] m ({alpha} in [{wlo}, {whi}])")));
        }
        if !(self.frequency_hz.is_finite() && self.frequency_hz > 0.0 && self.frequency_hz * MIN_SAMPLES_PER_CYCLE <= MAX_CONTROL_RATE_HZ) {
            return Err(param("loading.frequency_hz", self.frequency_hz,
                &format!("(0, {}] Hz ({MIN_SAMPLES_PER_CYCLE} samples per cycle at a control rate ≤ {MAX_CONTROL_RATE_HZ} Hz)",
                    MAX_CONTROL_RATE_HZ / MIN_SAMPLES_PER_CYCLE)));
        }
        let min_rate = MIN_SAMPLES_PER_CYCLE * self.frequency_hz;
        if !(self.control_rate_hz.is_finite() && self.control_rate_hz >= min_rate && self.control_rate_hz <= MAX_CONTROL_RATE_HZ) {
            return Err(param("loading.control_rate_hz", self.control_rate_hz,
                &format!("[{min_rate}, {MAX_CONTROL_RATE_HZ}] Hz (≥ {MIN_SAMPLES_PER_CYCLE} samples per cycle)")));
        }
        if self.phases.is_empty() {
            return Err(Error::Input("a test needs at least one phase".into()));
        }
        let mut a_prev = self.a0_m;
        for (i, ph) in self.phases.iter().enumerate() {
            let sec = self.phase_section(i);
            let f = |n: &str| format!("{sec}.{n}");
            let (rlo, rhi) = TEST_R_RATIO_RANGE;
            if !(ph.r_ratio.is_finite() && ph.r_ratio >= rlo && ph.r_ratio < rhi) {
                return Err(param(&f("r_ratio"), ph.r_ratio, &format!("[{rlo}, {rhi})")));
            }
            if !(ph.end_a_m > a_prev && ph.end_a_m <= ahi) {
                return Err(if i + 1 == self.phases.len() {
                    // the test proper ends where the spec's [end] a_over_w says
                    param("end.a_over_w", self.a_over_w(ph.end_a_m), &format!("({}, {whi}] (beyond the crack at its start, {} m)",
                        self.a_over_w(a_prev), a_prev))
                } else {
                    param(&f("end_a_m"), ph.end_a_m, &format!("({a_prev}, {ahi}] m"))
                });
            }
            if !(ph.tolerance > 0.0 && ph.tolerance <= MAX_TOLERANCE) {
                return Err(param(&f("tolerance"), ph.tolerance, &format!("(0, {MAX_TOLERANCE}]")));
            }
            let (dk_name, dk_unit) = ("delta_k_pa_sqrt_m", "Pa·√m");
            match ph.mode {
                Mode::ConstantForce { delta_f_n } if !(delta_f_n.is_finite() && delta_f_n > 0.0) => return Err(param(&f("delta_f_n"), delta_f_n, "(0, inf) N")),
                Mode::ConstantDeltaK { delta_k } if !(delta_k.is_finite() && delta_k > 0.0) => return Err(param(&f(dk_name), delta_k, "(0, inf) Pa·√m")),
                Mode::KGradient { delta_k0, c_per_m } => {
                    if !(delta_k0.is_finite() && delta_k0 > 0.0) {
                        return Err(param(&f(dk_name), delta_k0, "(0, inf) Pa·√m"));
                    }
                    if !(c_per_m.is_finite() && c_per_m >= E647_MIN_K_GRADIENT_PER_M) {
                        return Err(param(&f("k_gradient_per_m"), c_per_m, "[-80, inf) 1/m (ASTM E647: C ≥ −0.08 mm⁻¹)"));
                    }
                }
                _ => {}
            }
            let (fmax, _, _) = targets(self, ph, a_prev, a_prev)?;
            let kmax = self.specimen.k(a_prev, fmax)?;
            let kic = self.material.fracture_toughness_pa_sqrt_m;
            if kmax >= kic && self.sequence.is_empty() {
                // the load the phase asks for, against the largest that keeps Kmax below K_IC
                let (name, value, unit) = match ph.mode {
                    Mode::ConstantForce { delta_f_n } => ("delta_f_n", delta_f_n, "N"),
                    Mode::ConstantDeltaK { delta_k } => (dk_name, delta_k, dk_unit),
                    Mode::KGradient { delta_k0, .. } => (dk_name, delta_k0, dk_unit),
                };
                return Err(param(&f(name), value, &format!(
                    "(0, {:.6e}) {unit}: Kmax at the start of the phase (a = {a_prev} m) must stay below K_IC = {kic} Pa·√m, it is {kmax:.6e} Pa·√m",
                    value * kic / kmax)));
            }
            a_prev = ph.end_a_m;
        }
        if self.limits.max_cycles == 0 {
            return Err(param("end.max_cycles", 0.0, "≥ 1"));
        }
        // what the rig can drive (resonance, valve flow, force, stroke, size criterion) is
        // `feasibility::assess`: a forced test runs past it
        for (i, l) in self.sequence.iter().enumerate() {
            // a level by the spec's path: a spectrum's peak, or a block's force range (E647: the
            // peak for R < 0)
            let (field, value) = if self.sequence_from_spectrum {
                (format!("variable_amplitude.spectrum[{i}].peak_n"), l.fmax_n)
            } else {
                (format!("variable_amplitude.blocks[{i}].delta_f_n"), if l.fmin_n >= 0.0 { l.fmax_n - l.fmin_n } else { l.fmax_n })
            };
            if !(l.fmax_n.is_finite() && l.fmin_n.is_finite() && l.fmax_n > l.fmin_n) {
                return Err(param(&field, value, &format!("finite, the peak above the valley {} N", l.fmin_n)));
            }
            if l.cycles == 0 {
                return Err(param(&format!("variable_amplitude.blocks[{i}].cycles"), 0.0, "≥ 1"));
            }
            let kmax = self.specimen.k(self.a0_m, l.fmax_n)?;
            let kic = self.material.fracture_toughness_pa_sqrt_m;
            if kmax >= kic {
                return Err(param(&field, value, &format!(
                    "(0, {:.6e}) N: Kmax at the start (a = {} m) must stay below K_IC = {kic} Pa·√m, it is {kmax:.6e} Pa·√m",
                    value * kic / kmax, self.a0_m)));
            }
        }
        if !self.sequence.is_empty() && self.sequence.iter().map(|l| l.cycles).sum::<u64>() == 0 {
            return Err(Error::Input("variable_amplitude: no cycles".into()));
        }
        for (i, &(c, fac)) in self.stiffness_steps.iter().enumerate() {
            if !(fac > 0.0 && fac <= 1.0) {
                return Err(param(&format!("stiffness_steps[{i}] (cycle {c}) factor"), fac, "(0, 1]"));
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

