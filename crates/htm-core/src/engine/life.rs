//! Life tests: constant-amplitude force to failure (`force_life`, ASTM E466 / ISO 1099) and
//! strain control with an extensometer (`strain_life`, ASTM E606 / ISO 12106).
//!
//! * `LifeMachine`: the controller side, measured signals only (load cell, extensometer, piston
//!   position). Per control period the setpoint (smooth start, sine) and the force loop's
//!   command — the strain loop is the same `ForceLoop` fed the extensometer's strain times the
//!   specimen's nominal axial stiffness E·A, so the same gains serve both. Per cycle the table
//!   row (peak/valley stress and strain, plastic strain range, unloading moduli in tension and
//!   compression), the stabilised trends and the end criteria (separation, a drop of the tensile
//!   peak — or, under force control, of the secant stiffness — by a set fraction from its
//!   stabilised trend, a change of the unloading-modulus ratio, run-out), and the hysteresis
//!   loops kept at logarithmic intervals.
//! * `run_life`: the simulator around it: the plant with the virtual round bar
//!   (`cyclic_material::CyclicSpecimen`, hidden truth) linearised each control period, and the
//!   cycle jump across cycles whose loop the physics keeps the same (transient decayed, damage
//!   or crack growth bounded).
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use crate::control::{Demod, DemodGains, ForceLoop, PeakValley, Setpoint};
use crate::cyclic_material::{true_life, CyclicSpecimen};
use crate::error::{Error, Result};
use crate::machine::Y;
use crate::params::Params;
use crate::rig::RigPlant;
use crate::waveform::{Envelope, Ramp, Waveform};

use super::config::{hydraulic_stiffness, measure_velocity_gain, series_stiffness};
use super::cycle::{Stage, HOLD_CYCLES};

/// What the loop controls.
#[derive(serde::Serialize, serde::Deserialize, Debug, Clone, Copy, PartialEq, Eq)]
pub enum LifeMode {
    /// force amplitude [N] (E466)
    Force,
    /// strain amplitude (E606)
    Strain,
}

impl LifeMode {
    pub fn name(self) -> &'static str {
        match self {
            LifeMode::Force => "force_life",
            LifeMode::Strain => "strain_life",
        }
    }
}

/// End criteria (fractions; 0 = off).
#[derive(serde::Serialize, serde::Deserialize, Debug, Clone, Copy, PartialEq)]
pub struct Criteria {
    /// drop of the tensile peak force (strain control) or of the secant stiffness (force
    /// control) from its stabilised trend that ends the test (E606: 0.1 or 0.5)
    pub drop: f64,
    /// drop of the unloading-modulus ratio E_T/E_C from its stabilised value that ends the test
    pub modulus_ratio_drop: f64,
    /// separation: the tensile peak force below this fraction of its trend (strain control) or
    /// of the target (force control)
    pub separation: f64,
    /// run-out: the test ends unbroken at this cycle count
    pub runout_cycles: u64,
}

impl Default for Criteria {
    fn default() -> Self {
        Criteria { drop: 0.5, modulus_ratio_drop: 0.0, separation: 0.1, runout_cycles: 10_000_000 }
    }
}

/// A life test.
#[derive(Debug, Clone)]
pub struct LifeConfig {
    pub params: Params,
    pub rtol: f64,
    pub mode: LifeMode,
    /// force [N] or strain amplitude, and the ratio min/max of the controlled quantity
    pub amplitude: f64,
    pub r_ratio: f64,
    pub frequency_hz: f64,
    pub control_rate_hz: f64,
    pub envelope: Envelope,
    /// the virtual specimen (its geometry is also the controller's nominal area)
    pub specimen: CyclicSpecimen,
    /// extensometer gauge length ≈ the bar's effective length [m], and the load train's
    /// stiffness in series with the bar [N/m]
    pub gauge_length_m: f64,
    pub load_train_n_m: f64,
    pub criteria: Criteria,
    /// hysteresis loops kept per decade of cycles
    pub loops_per_decade: u32,
    pub jump: bool,
    pub velocity_gain_m_s_per_v: Option<f64>,
}

fn param(field: &str, value: f64, allowed: &str) -> Error {
    Error::Parameter { field: field.into(), value, allowed: allowed.into() }
}

impl LifeConfig {
    pub fn validate(&self) -> Result<()> {
        self.params.validate().map_err(|e| match e {
            Error::Parameter { field, value, allowed } => param(&format!("rig.overrides.{field}"), value, &allowed),
            o => o,
        })?;
        let amp_ok = match self.mode {
            LifeMode::Force => self.amplitude > 0.0 && self.amplitude.is_finite(),
            LifeMode::Strain => self.amplitude > 0.0 && self.amplitude < 0.1,
        };
        if !amp_ok {
            let (k, r) = match self.mode {
                LifeMode::Force => ("loading.force_amplitude_n", "(0, inf) N"),
                LifeMode::Strain => ("loading.strain_amplitude", "(0, 0.1)"),
            };
            return Err(param(k, self.amplitude, r));
        }
        if !(self.r_ratio >= -1.0 && self.r_ratio < 1.0) {
            return Err(param("loading.r_ratio", self.r_ratio, "[-1, 1)"));
        }
        if !(self.frequency_hz > 0.0 && self.frequency_hz <= 200.0) {
            return Err(param("loading.frequency_hz", self.frequency_hz, "(0, 200] Hz"));
        }
        let n = self.control_rate_hz / self.frequency_hz;
        if !(n >= 16.0 && self.control_rate_hz <= 1e5) {
            return Err(param("loading.control_rate_hz", self.control_rate_hz, &format!("[{}, 1e5] Hz (≥ 16 samples per cycle)", 16.0 * self.frequency_hz)));
        }
        if !(self.gauge_length_m > 0.0 && self.gauge_length_m < 1.0) {
            return Err(param("specimen.gauge_length_m", self.gauge_length_m, "(0, 1) m"));
        }
        if !(self.load_train_n_m > 0.0) {
            return Err(param("specimen.load_train_n_m", self.load_train_n_m, "(0, inf) N/m"));
        }
        let c = &self.criteria;
        for (k, v) in [("end.drop", c.drop), ("end.modulus_ratio_drop", c.modulus_ratio_drop)] {
            if !(0.0..0.95).contains(&v) {
                return Err(param(k, v, "[0, 0.95) (0 = off)"));
            }
        }
        if !(c.separation > 0.0 && c.separation < 0.9) {
            return Err(param("end.separation", c.separation, "(0, 0.9)"));
        }
        if c.runout_cycles == 0 {
            return Err(param("end.runout_cycles", 0.0, "≥ 1"));
        }
        if !(self.rtol > 0.0 && self.rtol <= 1e-2) {
            return Err(param("run.rtol", self.rtol, "(0, 1e-2]"));
        }
        Ok(())
    }

    /// Nominal axial stiffness of the bar E·A [N] (force per unit strain).
    pub fn ea(&self) -> f64 {
        self.specimen.material.e_pa * self.specimen.area_m2()
    }

    /// (max, min) of the controlled signal [N or N-equivalent] at full amplitude.
    pub fn targets(&self) -> (f64, f64) {
        let scale = if self.mode == LifeMode::Strain { self.ea() } else { 1.0 };
        let amp = self.amplitude * scale;
        let mean = amp * (1.0 + self.r_ratio) / (1.0 - self.r_ratio);
        (mean + amp, mean - amp)
    }

    /// Elastic stiffness piston → specimen [N/m]: the bar in series with the load train.
    pub fn elastic_stiffness(&self) -> f64 {
        series_stiffness(self.ea() / self.gauge_length_m, self.load_train_n_m)
    }
}

/// Event bits of a life table row.
pub mod life_events {
    pub const START: u32 = 1;
    pub const JUMP: u32 = 16;
    pub const DROP10: u32 = 1024;
    pub const DROP50: u32 = 2048;
    pub const END: u32 = 256;
}

/// Why a life test ended.
#[derive(serde::Serialize, serde::Deserialize, Debug, Clone, Copy, PartialEq, Eq)]
pub enum LifeEnd {
    Separation,
    Drop,
    ModulusRatio,
    Runout,
    StrokeLimit,
    Cancelled,
}

impl LifeEnd {
    pub fn name(self) -> &'static str {
        match self {
            LifeEnd::Separation => "separation",
            LifeEnd::Drop => "load_drop",
            LifeEnd::ModulusRatio => "modulus_ratio",
            LifeEnd::Runout => "runout",
            LifeEnd::StrokeLimit => "stroke_limit",
            LifeEnd::Cancelled => "cancelled",
        }
    }
    /// The specimen failed (a run-out or a stop did not).
    pub fn failed(self) -> bool {
        matches!(self, LifeEnd::Separation | LifeEnd::Drop | LifeEnd::ModulusRatio)
    }
}

/// The per-cycle table of a life test (struct of columns, SI; stresses nominal F/A).
#[derive(Debug, Clone, Default)]
pub struct LifeRecords {
    pub cycle: Vec<u64>,
    pub fmax_n: Vec<f64>,
    pub fmin_n: Vec<f64>,
    pub stress_max_pa: Vec<f64>,
    pub stress_min_pa: Vec<f64>,
    pub strain_max: Vec<f64>,
    pub strain_min: Vec<f64>,
    pub plastic_strain_range: Vec<f64>,
    /// unloading moduli from the tensile and the compressive peak [Pa], secant stiffness ΔF/Δy [N/m]
    pub modulus_t_pa: Vec<f64>,
    pub modulus_c_pa: Vec<f64>,
    pub stiffness_n_m: Vec<f64>,
    /// the stabilised trend of the judged quantity at this cycle (NaN before it is set)
    pub trend: Vec<f64>,
    pub events: Vec<u32>,
}

/// Hysteresis loops kept at logarithmic intervals: every sample of the kept cycles.
#[derive(Debug, Clone, Default)]
pub struct Loops {
    pub cycle: Vec<u64>,
    pub strain: Vec<f64>,
    pub stress_pa: Vec<f64>,
}

/// The truth of the virtual specimen (simulation only; the rig has none).
#[derive(Debug, Clone, Copy, Default)]
pub struct LifeTruth {
    pub life_factor: f64,
    pub n_init: f64,
    pub n_phi10: f64,
    pub n_phi50: f64,
    pub n_sep: f64,
}

#[derive(Debug, Clone)]
pub struct LifeOutcome {
    pub records: LifeRecords,
    pub loops: Loops,
    pub end: LifeEnd,
    /// the cycle the end criterion tripped (the life for a failure)
    pub cycles: u64,
    /// first cycles where the judged quantity fell 10 % / 50 % below its stabilised trend
    pub n_drop10: Option<u64>,
    pub n_drop50: Option<u64>,
    pub n_modulus: Option<u64>,
    pub cycles_simulated: u64,
    pub truth: LifeTruth,
    pub velocity_gain_m_s_per_v: f64,
}

/// The stabilised level of a per-cycle value: at cycle N, the median of the values of the five
/// resolved cycles nearest N/2 (half the life so far: past a cyclic transient, before a crack's
/// fall, which takes the last part of a life).
#[derive(serde::Serialize, serde::Deserialize, Debug, Clone, Default)]
struct Trend {
    pts: Vec<(f64, f64)>,
}

impl Trend {
    fn predict(&self, n: f64) -> f64 {
        if self.pts.is_empty() {
            return f64::NAN;
        }
        let i = self.pts.partition_point(|p| p.0 <= 0.5 * n).max(1);
        let mut v: Vec<f64> = self.pts[i.saturating_sub(5)..i].iter().map(|p| p.1).collect();
        v.sort_by(|a, b| a.total_cmp(b));
        v[v.len() / 2]
    }

    /// Judge value `v` at cycle `n`: its drop from the stabilised level (NaN before any).
    fn observe(&mut self, n: f64, v: f64) -> f64 {
        let t = self.predict(n);
        if v.is_finite() {
            self.pts.push((n, v));
        }
        if t.is_finite() && t > 0.0 { 1.0 - v / t } else { f64::NAN }
    }
}

/// The controller side of a life test (see the module doc): measured signals in, valve command out.
#[derive(serde::Serialize, serde::Deserialize, Debug, Clone)]
pub struct LifeMachine {
    drive: ForceLoop,
    /// peak-valley compensation of the controlled signal (as the cycle machine's)
    pub pv: PeakValley,
    pub n: usize,
    pub dt: f64,
    k: usize,
    pub cycle: u64,
    f0: f64,
    start_cycles: u64,
    ea: f64,
    area: f64,
    /// this cycle's samples: (stress, strain, force, position)
    buf: Vec<(f64, f64, f64, f64)>,
    e_ref: f64,
    trend: Trend,
    ratio_trend: Trend,
    pub n_drop10: Option<u64>,
    pub n_drop50: Option<u64>,
    pub n_modulus: Option<u64>,
    pub end: Option<LifeEnd>,
    kept_bucket: i64,
    /// largest tensile peak of the judged cycles [N]
    peak_max: f64,
    pub velocity_gain: f64,
    /// what the test is doing (the cycle machine's stages: hold, resume and stop on a rig)
    pub stage: Stage,
    /// amplitude ramp of hold / resume / stop, per sample
    ramp: Ramp,
    /// the smallest and largest amplitude scale of this cycle's periods
    cycle_scale: (f64, f64),
    /// cycles up to this one are not judged (a resume's ramp and the cycles after it)
    judge_after: u64,
    /// the valve command that holds the piston still once stopped [V]
    pub u_null: f64,
    /// the samples (stress [Pa], strain) of the last closed cycle, for a rig's live loop and
    /// kept loops
    pub last_loop: Vec<(f64, f64)>,
}

/// Peak-valley gain of a life test relative to the cycle machine's: a yielding bar changes its
/// loop with each correction (the reversal moves along a Masing branch), so the correction is
/// learnt more slowly than on a linear specimen.
const LIFE_PV_GAIN: f64 = 0.3;

/// One closed cycle's row.
#[derive(Debug, Clone, Copy, Default)]
pub struct LifeRow {
    pub cycle: u64,
    pub fmax_n: f64,
    pub fmin_n: f64,
    pub strain_max: f64,
    pub strain_min: f64,
    pub plastic_strain_range: f64,
    pub modulus_t_pa: f64,
    pub modulus_c_pa: f64,
    pub stiffness_n_m: f64,
    pub trend: f64,
    pub events: u32,
    /// keep this cycle's loop (logarithmic interval)
    pub keep_loop: bool,
}

/// Slope of stress on strain over the samples from index `i0` while the stress has moved less
/// than `frac` of the range `range` from its value there: the unloading modulus [Pa].
fn unloading_modulus(buf: &[(f64, f64, f64, f64)], i0: usize, range: f64, frac: f64) -> f64 {
    let s0 = buf[i0].0;
    let mut pts = vec![];
    for p in &buf[i0..] {
        if (p.0 - s0).abs() > frac * range {
            break;
        }
        pts.push((p.1, p.0));
    }
    if pts.len() < 3 {
        return f64::NAN;
    }
    let m = pts.len() as f64;
    let (mx, my) = pts.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0, a.1 + p.1));
    let (mx, my) = (mx / m, my / m);
    let (sxy, sxx) = pts.iter().fold((0.0, 0.0), |a, p| (a.0 + (p.0 - mx) * (p.1 - my), a.1 + (p.0 - mx).powi(2)));
    sxy / sxx
}

impl LifeMachine {
    /// A test at rest with the controlled signal at `s0` [N or N-equivalent]; `k_series` is
    /// the piston-to-signal stiffness the controller is designed for [N/m].
    pub fn new(cfg: &LifeConfig, s0: f64) -> Result<Self> {
        let n = (cfg.control_rate_hz / cfg.frequency_hz).round() as usize;
        let dt = 1.0 / (n as f64 * cfg.frequency_hz);
        let p = &cfg.params;
        let y0 = p.specimen_zero_force_position_m;
        // the loop's gain from piston to signal: the elastic bar and load train for force; for
        // strain the yielding bar's (dε/dy → 1/L), the largest, so the loop stays damped when
        // the specimen yields
        let k_sig = if cfg.mode == LifeMode::Strain { cfg.ea() / cfg.gauge_length_m } else { cfg.elastic_stiffness() };
        let k_eff = series_stiffness(k_sig, hydraulic_stiffness(p, y0));
        let kv = match cfg.velocity_gain_m_s_per_v {
            Some(k) => k,
            None => {
                let (hi, lo) = cfg.targets();
                let need = |kv: f64| (0.5 * (hi - lo) * 2.0 * std::f64::consts::PI * cfg.frequency_hz / (k_eff * kv)).abs().clamp(0.005, 1.0);
                let mut kv = measure_velocity_gain(p, 0.1)?;
                kv = measure_velocity_gain(p, need(kv))?;
                kv
            }
        };
        let g = DemodGains::design(k_eff, kv, cfg.frequency_hz, n as f64 * cfg.frequency_hz)?;
        let drive = ForceLoop::Demod(Demod::new(g, Waveform::Sine.stats(), p.valve_max_command_v, s0));
        Ok(LifeMachine {
            drive, pv: PeakValley::new(), n, dt, k: 0, cycle: 0, f0: s0, start_cycles: cfg.envelope.start_cycles(), ea: cfg.ea(), area: cfg.specimen.area_m2(),
            buf: Vec::with_capacity(n), e_ref: f64::NAN, trend: Trend::default(), ratio_trend: Trend::default(), n_drop10: None,
            n_drop50: None, n_modulus: None, end: None, kept_bucket: -1, peak_max: 0.0, velocity_gain: kv, stage: Stage::Starting,
            ramp: Ramp::FULL, cycle_scale: (f64::MAX, f64::MIN), judge_after: 0, u_null: 0.0, last_loop: Vec::new(),
        })
    }

    /// The controlled signal from the measurements [N or N-equivalent].
    #[inline]
    pub fn signal(&self, cfg: &LifeConfig, f: f64, strain: f64) -> f64 {
        if cfg.mode == LifeMode::Strain { strain * self.ea } else { f }
    }

    fn setpoint_at(&self, cfg: &LifeConfig, pos: f64) -> (f64, f64) {
        let (hi, lo) = cfg.targets();
        let (mid, amp) = (0.5 * (hi + lo), 0.5 * (hi - lo));
        let (fm, fa) = cfg.envelope.start(pos);
        (self.f0 + (mid - self.f0) * fm, amp * fa)
    }

    /// One control period: measured force [N], extensometer strain and piston position [m] in
    /// (the values at the start of the period), the valve command [V] out.
    #[inline]
    pub fn command(&mut self, cfg: &LifeConfig, f: f64, strain: f64, y: f64) -> f64 {
        let nf = self.n as f64;
        let c = self.cycle as f64;
        let (x, x1) = (self.k as f64 / nf, (self.k + 1) as f64 / nf);
        let tau = 2.0 * std::f64::consts::PI;
        let (sn, cn) = (tau * x).sin_cos();
        let s_next = (tau * x1).sin();
        let (mid, amp) = self.setpoint_at(cfg, c + x);
        let (mid1, amp1) = self.setpoint_at(cfg, c + x1);
        // hold / resume / stop: the amplitude ramps at the mean
        let (g, g1) = (self.ramp.scale(0), self.ramp.scale(1));
        self.ramp.advance();
        self.cycle_scale = (self.cycle_scale.0.min(g), self.cycle_scale.1.max(g));
        // the correction of each reversal (the peak in the first half, the valley in the second)
        let (amp, amp1) = (self.pv.apply(amp * g, x <= 0.5), self.pv.apply(amp1 * g1, x1 <= 0.5));
        let learn = cfg.envelope.start(c + x).1 * g >= 0.3;
        let sp = Setpoint { mid_n: mid, mid_next_n: mid1 + (amp1 - amp) * s_next, amp_n: amp, s: sn, s_next, sin: sn, cos: cn, learn };
        let meas = self.signal(cfg, f, strain);
        let u = if meas.is_finite() { self.drive.command(&sp, meas) } else { 0.0 };
        self.buf.push((f / self.area, strain, f, y));
        self.k += 1;
        u
    }

    /// The cycle ends with this period.
    pub fn at_end(&self) -> bool {
        self.k == self.n
    }

    /// This cycle's samples (stress [Pa], strain) for a kept loop.
    pub fn loop_samples(&self) -> impl Iterator<Item = (f64, f64)> + '_ {
        self.buf.iter().map(|p| (p.1, p.0))
    }

    /// Close the cycle: the row, trends and end criteria. The caller clears with `next_cycle`.
    pub fn close(&mut self, cfg: &LifeConfig) -> LifeRow {
        let b = &self.buf;
        let (mut imax, mut imin) = (0, 0);
        for (i, p) in b.iter().enumerate() {
            if p.2 > b[imax].2 {
                imax = i;
            }
            if p.2 < b[imin].2 {
                imin = i;
            }
        }
        let (fmax, fmin) = (b[imax].2, b[imin].2);
        let sig = |p: &(f64, f64, f64, f64)| if cfg.mode == LifeMode::Strain { p.1 * self.ea } else { p.2 };
        let smax = b.iter().map(sig).fold(f64::MIN, f64::max);
        let smin = b.iter().map(sig).fold(f64::MAX, f64::min);
        let emax = b.iter().map(|p| p.1).fold(f64::MIN, f64::max);
        let emin = b.iter().map(|p| p.1).fold(f64::MAX, f64::min);
        let ymax = b.iter().map(|p| p.3).fold(f64::MIN, f64::max);
        let ymin = b.iter().map(|p| p.3).fold(f64::MAX, f64::min);
        let srange = (fmax - fmin) / self.area;
        let et = unloading_modulus(b, imax, srange, 0.25);
        let ec = unloading_modulus(b, imin, srange, 0.25);
        self.cycle += 1;
        let c = self.cycle;
        let mut ev = if c <= self.start_cycles { life_events::START } else { 0 };
        let (thi, tlo) = cfg.targets();
        let fa = cfg.envelope.start(c as f64 - 0.5).1;
        let full = self.cycle_scale.0 >= 1.0;
        if fa >= PeakValley::MIN_AMPLITUDE_FRACTION && self.end.is_none() && full {
            let (mid, amp) = self.setpoint_at(cfg, c as f64 - 0.25);
            let gain = LIFE_PV_GAIN * if fa < 1.0 { PeakValley::RAMP_GAIN } else { PeakValley::GAIN };
            self.pv.update(mid + amp, mid - amp, smax, smin, 2.0 * amp, 2.0 * amp, gain);
        }
        // judged: past the start, at full amplitude, not in or just after a resume's ramp
        let judged = c > self.start_cycles + 2 && full && c > self.judge_after;
        if judged && !self.e_ref.is_finite() && ec.is_finite() {
            self.e_ref = ec;
        }
        let e_ref = if self.e_ref.is_finite() { self.e_ref } else { cfg.specimen.material.e_pa };
        let dep = ((emax - emin) - srange / e_ref).max(0.0);
        let stiff = if emax > emin { (fmax - fmin) / (emax - emin) } else { f64::NAN };
        let mut row = LifeRow {
            cycle: c, fmax_n: fmax, fmin_n: fmin, strain_max: emax, strain_min: emin, plastic_strain_range: dep, modulus_t_pa: et,
            modulus_c_pa: ec, stiffness_n_m: (fmax - fmin) / (ymax - ymin), trend: f64::NAN, events: 0, keep_loop: false,
        };
        let mut end = None;
        if judged {
            // the judged quantity: the tensile peak under strain control, the secant stiffness
            // under force control
            let v = if cfg.mode == LifeMode::Strain { fmax } else { stiff / self.area };
            let drop = self.trend.observe(c as f64, v);
            row.trend = self.trend.predict(c as f64);
            if drop >= 0.1 && self.n_drop10.is_none() {
                self.n_drop10 = Some(c);
                ev |= life_events::DROP10;
            }
            if drop >= 0.5 && self.n_drop50.is_none() {
                self.n_drop50 = Some(c);
                ev |= life_events::DROP50;
            }
            if cfg.criteria.drop > 0.0 && drop >= cfg.criteria.drop {
                end = Some(LifeEnd::Drop);
            }
            let ratio = et / ec;
            if ratio.is_finite() {
                let rd = self.ratio_trend.observe(c as f64, ratio);
                if cfg.criteria.modulus_ratio_drop > 0.0 && rd >= cfg.criteria.modulus_ratio_drop {
                    self.n_modulus.get_or_insert(c);
                    end = end.or(Some(LifeEnd::ModulusRatio));
                }
            }
            // separation: the tension the bar carries is gone
            let _ = tlo;
            self.peak_max = self.peak_max.max(fmax);
            let ref_t = if cfg.mode == LifeMode::Strain { self.peak_max } else { thi };
            if fmax < cfg.criteria.separation * ref_t || (cfg.mode == LifeMode::Force && drop >= 1.0 - cfg.criteria.separation) {
                end = Some(LifeEnd::Separation);
            }
        }
        let margin = 1e-3;
        if ymin < margin || ymax > cfg.params.stroke_m - margin {
            end = end.or(Some(LifeEnd::StrokeLimit));
        }
        if end.is_none() && c >= cfg.criteria.runout_cycles {
            end = Some(LifeEnd::Runout);
        }
        let bucket = ((c as f64).log10() * cfg.loops_per_decade as f64).floor() as i64;
        if bucket > self.kept_bucket || end.is_some() {
            self.kept_bucket = bucket;
            row.keep_loop = true;
        }
        if let Some(e) = end {
            self.end = Some(e);
            ev |= life_events::END;
        }
        row.events = ev;
        row
    }

    pub fn next_cycle(&mut self) {
        self.buf.clear();
        self.k = 0;
        self.cycle_scale = (f64::MAX, f64::MIN);
    }

    #[inline]
    /// Freeze at the mean (a rig's hold): the amplitude ramps to zero over `HOLD_CYCLES`; the
    /// cycles held at zero amplitude are not counted. False when no test runs.
    pub fn hold(&mut self) -> bool {
        match self.stage {
            Stage::Starting | Stage::Running => {
                self.ramp.retarget(0.0, HOLD_CYCLES, self.n);
                self.stage = Stage::Holding;
                true
            }
            Stage::Holding => true,
            _ => false,
        }
    }

    /// Ramp the amplitude back in over the start's amplitude cycles after `hold`; the ramp's
    /// cycles and the two after it are counted but not judged (the compensation settles again).
    pub fn resume(&mut self, cfg: &LifeConfig) -> bool {
        if self.stage != Stage::Holding {
            return false;
        }
        let len = cfg.envelope.amplitude_cycles.max(1.0);
        self.ramp.retarget(1.0, len, self.n);
        self.judge_after = self.cycle + len.ceil() as u64 + 2;
        self.stage = if self.cycle < self.start_cycles { Stage::Starting } else { Stage::Running };
        true
    }

    /// Ramp the amplitude to zero at the mean over the spec's stop cycles, then the valve null.
    pub fn stop(&mut self, cfg: &LifeConfig) {
        if matches!(self.stage, Stage::Starting | Stage::Running | Stage::Holding) {
            self.ramp.retarget(0.0, cfg.envelope.stop_cycles.max(0.5), self.n);
            self.stage = Stage::Stopping;
        }
    }

    /// One control period of a rig's loop (the same `command` and `close` as `run_life`'s):
    /// measured force [N], extensometer strain and piston position [m] in; the valve command [V]
    /// and, when a counted cycle closed with this period, its row out (its samples then in
    /// `last_loop`). Cycles held at zero amplitude, and those after the end, are not counted;
    /// an end criterion ramps the amplitude down (`stop`), then the valve goes to its null.
    pub fn step(&mut self, cfg: &LifeConfig, f: f64, strain: f64, y: f64) -> (f64, Option<LifeRow>) {
        if self.stage == Stage::Stopped {
            return (self.u_null, None);
        }
        let u = self.command(cfg, f, strain, y);
        if !self.at_end() {
            return (u, None);
        }
        let mut row = None;
        let counted = self.cycle_scale.1 > 0.0 && self.end.is_none() && self.stage != Stage::Stopping;
        if counted {
            let r = self.close(cfg);
            self.last_loop.clear();
            self.last_loop.extend(self.buf.iter().map(|p| (p.0, p.1)));
            row = Some(r);
            if self.end.is_some() {
                self.stop(cfg);
            } else if self.stage == Stage::Starting && self.cycle >= self.start_cycles {
                self.stage = Stage::Running;
            }
        }
        self.next_cycle();
        if self.stage == Stage::Stopping && self.ramp.done() {
            self.stage = Stage::Stopped;
            self.u_null = self.drive.summary().1.clamp(-1.0, 1.0);
        }
        (u, row)
    }


    /// A jump of `j` cycles (simulation): the counter moves on, the next cycle's loop is kept
    /// again when it opens a new logarithmic bucket.
    pub fn jumped(&mut self, j: u64) {
        self.cycle += j;
    }
}

/// The virtual bar on the plant: the piston position gives the gauge strain through the load
/// train in series (Newton), the specimen gives the force, and the plant's spring is set to the
/// tangent through that point for the next period.
#[derive(Debug, Clone)]
struct Bar {
    y_zero: f64,
    l: f64,
    k_lt: f64,
    eps: f64,
}

impl Bar {
    /// Move the specimen to the piston position `y`: (force, strain, tangent dF/dy).
    fn settle(&mut self, s: &mut CyclicSpecimen, y: f64) -> (f64, f64, f64) {
        let u = y - self.y_zero;
        let mut e = self.eps;
        for _ in 0..20 {
            let (f, t) = s.force(e);
            let g = self.l * e + f / self.k_lt - u;
            let dg = self.l + t / self.k_lt;
            let de = g / dg;
            e -= de;
            if de.abs() < 1e-14 {
                break;
            }
        }
        self.eps = e;
        let f = s.strain_to(e);
        let (_, t) = s.force(e);
        let k = 1.0 / (self.l / t.max(1e-6) + 1.0 / self.k_lt);
        (f, e, k)
    }
}

/// The virtual rig of a life test: the plant (with its supply, `rig::RigPlant`) with the virtual
/// bar on it (the hidden truth). Its sensors are what a rig's would read; `step` applies a valve
/// command for one control period.
#[derive(Debug, Clone)]
pub struct VirtualBar {
    pub rp: RigPlant,
    bar: Bar,
    pub spec: CyclicSpecimen,
    /// measured force [N], extensometer strain
    pub f: f64,
    pub eps: f64,
    /// control periods per load cycle and the count in this one: the bar closes its true loop
    /// every cycle by itself (a rig's specimen needs no telling); a window in which the bar did
    /// not move (a rig at rest or a held test) is no cycle of the material's
    n: usize,
    k: usize,
    win: (f64, f64),
}

/// Strain range below which a window of a load cycle's periods is no cycle of the bar's.
const REST_STRAIN_RANGE: f64 = 2e-5;

impl VirtualBar {
    pub fn new(cfg: &LifeConfig) -> Result<Self> {
        cfg.validate()?;
        let mut spec = cfg.specimen.clone();
        let mut p = cfg.params.clone();
        p.specimen_stiffness_n_m = cfg.elastic_stiffness();
        p.specimen_closure_stiffness_n_m = 0.0;
        let y_zero = p.specimen_zero_force_position_m;
        let mut rp = RigPlant::new(p, None)?;
        rp.machine = rp.machine.clone().with_rtol(cfg.rtol)?;
        let mut bar = Bar { y_zero, l: cfg.gauge_length_m, k_lt: cfg.load_train_n_m, eps: 0.0 };
        let (f, eps, _) = bar.settle(&mut spec, rp.machine.x[Y]);
        let n = (cfg.control_rate_hz / cfg.frequency_hz).round() as usize;
        Ok(VirtualBar { rp, bar, spec, f, eps, n, k: 0, win: (f64::MAX, f64::MIN) })
    }

    /// (force [N], strain, piston position [m]) as the sensors read them now.
    pub fn measure(&self) -> (f64, f64, f64) {
        (self.f, self.eps, self.rp.machine.x[Y])
    }

    /// Every sensor now: (position [m], velocity [m/s], p_a, p_b, p_s [Pa], force [N], strain).
    pub fn outputs(&self) -> (f64, f64, f64, f64, f64, f64, f64) {
        let o = self.rp.machine.outputs();
        (o.y, o.v, o.p_a, o.p_b, o.p_s, self.f, self.eps)
    }

    /// One control period under valve command `u` [V] for `dt` [s]: the plant moves, the bar
    /// follows, its tangent becomes the plant's spring for the next period.
    pub fn step(&mut self, u: f64, dt: f64) -> Result<(f64, f64, f64)> {
        self.rp.step(u, dt)?;
        let y = self.rp.machine.x[Y];
        let (f1, e1, k) = self.bar.settle(&mut self.spec, y);
        let p = &mut self.rp.machine.plant.p;
        p.specimen_stiffness_n_m = k;
        p.specimen_zero_force_position_m = y - f1 / k;
        (self.f, self.eps) = (f1, e1);
        self.win = (self.win.0.min(e1), self.win.1.max(e1));
        self.k += 1;
        if self.k == self.n {
            // a load cycle is over: the bar's damage and crack advance by its true loop
            self.k = 0;
            if self.win.1 - self.win.0 >= REST_STRAIN_RANGE {
                self.spec.end_cycle();
            }
            self.win = (f64::MAX, f64::MIN);
        }
        Ok(self.measure())
    }
}

/// Run a life test on the simulated rig to its end. `progress` receives the cycle count.
pub fn run_life(cfg: &LifeConfig, progress: Option<&AtomicU64>, cancel: Option<&AtomicBool>) -> Result<LifeOutcome> {
    let mut vb = VirtualBar::new(cfg)?;
    let (f, eps, _) = vb.measure();
    let mut lm = LifeMachine::new(cfg, lm_signal(cfg, f, eps))?;
    let mut rec = LifeRecords::default();
    let mut loops = Loops::default();
    let mut simulated = 0u64;
    let mut since_jump = 0u64;
    let mut prev = (f64::NAN, f64::NAN);
    let area = vb.spec.area_m2();
    loop {
        if cancel.is_some_and(|c| c.load(Ordering::Relaxed)) {
            lm.end = Some(LifeEnd::Cancelled);
            break;
        }
        // the rig's per-period step (`LifeMachine::step`), period by period until a cycle closes
        let row = loop {
            let (f, eps, y) = vb.measure();
            let (u, closed) = lm.step(cfg, f, eps, y);
            vb.step(u, lm.dt)?;
            if let Some(r) = closed {
                break r;
            }
        };
        simulated += 1;
        let spec = &mut vb.spec;
        if row.keep_loop {
            for &(s, e) in &lm.last_loop {
                loops.cycle.push(row.cycle);
                loops.strain.push(e);
                loops.stress_pa.push(s);
            }
        }
        push(&mut rec, &row, area);
        if let Some(pg) = progress {
            pg.store(lm.cycle, Ordering::Relaxed);
        }
        if lm.end.is_some() {
            break;
        }
        since_jump += 1;
        let settled = (row.fmax_n / prev.0 - 1.0).abs() < 2e-4 && (row.strain_max / prev.1 - 1.0).abs() < 2e-4;
        prev = (row.fmax_n, row.strain_max);
        if cfg.jump && row.events & life_events::START == 0 && since_jump >= 3 && (settled || since_jump >= 30) && !spec.separated {
            if let Some(j) = jump_length(cfg, spec, lm.cycle) {
                let (ea, smax, smin) = spec.last_loop_or(&row, area);
                let used = spec.advance(j as f64, ea, smax, smin).round() as u64;
                let used = used.max(1);
                lm.jumped(used);
                let mut jr = row;
                jr.cycle = lm.cycle;
                jr.events = life_events::JUMP;
                jr.trend = f64::NAN;
                push(&mut rec, &jr, area);
                since_jump = 0;
                if lm.cycle >= cfg.criteria.runout_cycles {
                    lm.end = Some(LifeEnd::Runout);
                    if let Some(e) = rec.events.last_mut() {
                        *e |= life_events::END;
                    }
                    break;
                }
            }
        }
    }
    let nan = |o: Option<f64>| o.unwrap_or(f64::NAN);
    let spec = &vb.spec;
    Ok(LifeOutcome {
        records: rec, loops, end: lm.end.unwrap_or(LifeEnd::Cancelled), cycles: lm.cycle, n_drop10: lm.n_drop10, n_drop50: lm.n_drop50,
        n_modulus: lm.n_modulus, cycles_simulated: simulated,
        truth: LifeTruth { life_factor: spec.life_factor, n_init: nan(spec.n_init), n_phi10: nan(spec.n_phi10), n_phi50: nan(spec.n_phi50), n_sep: nan(spec.n_sep) },
        velocity_gain_m_s_per_v: lm.velocity_gain,
    })
}

fn lm_signal(cfg: &LifeConfig, f: f64, eps: f64) -> f64 {
    if cfg.mode == LifeMode::Strain { eps * cfg.ea() } else { f }
}

fn push(rec: &mut LifeRecords, r: &LifeRow, area: f64) {
    rec.cycle.push(r.cycle);
    rec.fmax_n.push(r.fmax_n);
    rec.fmin_n.push(r.fmin_n);
    rec.stress_max_pa.push(r.fmax_n / area);
    rec.stress_min_pa.push(r.fmin_n / area);
    rec.strain_max.push(r.strain_max);
    rec.strain_min.push(r.strain_min);
    rec.plastic_strain_range.push(r.plastic_strain_range);
    rec.modulus_t_pa.push(r.modulus_t_pa);
    rec.modulus_c_pa.push(r.modulus_c_pa);
    rec.stiffness_n_m.push(r.stiffness_n_m);
    rec.trend.push(r.trend);
    rec.events.push(r.events);
}

/// Largest jump [cycles] the physics allows from cycle `cycle`: the cyclic transient moves K′ by
/// at most 0.1 %, the damage stops at initiation, the crack takes at most 0.5 % of the section,
/// the run-out is not passed. None when shorter than 20 cycles.
fn jump_length(cfg: &LifeConfig, s: &CyclicSpecimen, cycle: u64) -> Option<u64> {
    let m = &s.material;
    let mut j = (cfg.criteria.runout_cycles.saturating_sub(cycle)) as f64;
    if m.transient != 0.0 {
        let k0 = m.k_at(s.n);
        // |dK/dN| = |h|K′/N_h·e^(−N/N_h): the jump that moves K′ by 0.1 %
        let rate = (m.transient * m.k_prime_pa / m.transient_cycles * (-s.n / m.transient_cycles).exp()).abs();
        if rate > 0.0 {
            j = j.min(1e-3 * k0 / rate);
        }
    }
    let (ea, smax, smin) = s.last_loop()?;
    let (dd, da) = s.rates(ea, smax, smin, s.a_m);
    if s.a_m <= 0.0 {
        if dd > 0.0 {
            // stop a few cycles short of initiation: the crack starts in resolved cycles
            j = j.min(((1.0 - s.damage) / dd - 2.0).max(0.0));
        }
    } else {
        let area = s.area_m2();
        // dφ/da = π a / A
        let dphi = std::f64::consts::PI * s.a_m / area * da;
        if dphi > 0.0 {
            // and the crack grows by at most 5 % of its depth
            j = j.min(0.005 / dphi).min(0.05 * s.a_m / da);
        } else if da.is_infinite() {
            return None;
        }
    }
    let j = j.floor();
    (j >= 20.0).then_some(j as u64)
}

impl CyclicSpecimen {
    /// The last true loop, or the measured one as a fallback.
    fn last_loop_or(&self, row: &LifeRow, area: f64) -> (f64, f64, f64) {
        self.last_loop().unwrap_or((0.5 * (row.strain_max - row.strain_min), row.fmax_n / area, row.fmin_n / area))
    }
}

/// The virtual specimen's life without a controller at the test's amplitude (its true loop
/// taken from the material's cyclic curve at R = −1): (N_init, N_50, N_sep).
pub fn virtual_life(cfg: &LifeConfig) -> (f64, f64, f64) {
    let s = &cfg.specimen;
    let m = &s.material;
    let k = m.k_prime_pa;
    let (ea, sa) = match cfg.mode {
        LifeMode::Strain => (cfg.amplitude, m.stress_of(cfg.amplitude, k).0),
        LifeMode::Force => {
            let sa = cfg.amplitude / s.area_m2();
            (m.strain_of(sa, k), sa)
        }
    };
    let (hi, lo) = cfg.targets();
    let sm = if cfg.mode == LifeMode::Force { 0.5 * (hi + lo) / s.area_m2() } else { 0.0 };
    true_life(s, ea, sm + sa, sm - sa)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::crack::Law;
    use crate::cyclic_material::CyclicMaterial;

    pub fn bar(mode: LifeMode, amplitude: f64) -> LifeConfig {
        let law = Law::Paris { c: 1e-11 / 1e6f64.powi(3), m: 3.0 };
        LifeConfig {
            params: Params::default(), rtol: 1e-4, mode, amplitude, r_ratio: -1.0, frequency_hz: 5.0, control_rate_hz: 400.0,
            envelope: Envelope { mean_cycles: 1.0, amplitude_cycles: 5.0, stop_cycles: 1.0 },
            specimen: CyclicSpecimen::new(CyclicMaterial::default(), 6.35e-3, 0.1e-3, law, 60e6, 1.0).unwrap(),
            gauge_length_m: 25e-3, load_train_n_m: 5e8, criteria: Criteria::default(), loops_per_decade: 5, jump: true,
            velocity_gain_m_s_per_v: None,
        }
    }

    /// A rig's hold: the amplitude ramps to zero within a cycle, held cycles are not counted (nor
    /// cycled on the bar), a resume ramps back in, and its cycles are counted but not judged.
    #[test]
    fn a_hold_stops_counting_and_a_resume_is_not_judged() {
        let cfg = bar(LifeMode::Strain, 0.006);
        let mut vb = VirtualBar::new(&cfg).unwrap();
        let (f, eps, _) = vb.measure();
        let mut lm = LifeMachine::new(&cfg, lm_signal(&cfg, f, eps)).unwrap();
        let n = lm.n;
        let mut rows = vec![];
        let run = |lm: &mut LifeMachine, vb: &mut VirtualBar, periods: usize, rows: &mut Vec<LifeRow>| {
            for _ in 0..periods {
                let (f, e, y) = vb.measure();
                let (u, r) = lm.step(&cfg, f, e, y);
                vb.step(u, lm.dt).unwrap();
                rows.extend(r);
            }
        };
        run(&mut lm, &mut vb, 20 * n, &mut rows);
        assert_eq!(lm.cycle, 20);
        assert!(lm.hold());
        assert_eq!(lm.stage, Stage::Holding);
        let n0 = vb.spec.n;
        run(&mut lm, &mut vb, 10 * n, &mut rows);
        assert!(lm.cycle <= 21, "held cycles counted: {}", lm.cycle);
        assert!(vb.spec.n - n0 <= 2.0, "a held bar cycled: {}", vb.spec.n - n0);
        let held = lm.cycle;
        assert!(lm.resume(&cfg));
        run(&mut lm, &mut vb, 15 * n, &mut rows);
        assert_eq!(lm.cycle, held + 15);
        let cycles: Vec<u64> = rows.iter().map(|r| r.cycle).collect();
        assert_eq!(cycles, (1..=lm.cycle).collect::<Vec<_>>(), "every cycle once");
        // the resume's ramp (5 cycles) and the two after it are not judged, the ones after are
        for r in &rows[held as usize..held as usize + 7] {
            assert!(r.trend.is_nan(), "cycle {} judged during the resume", r.cycle);
        }
        assert!(rows.last().unwrap().trend.is_finite());
        let last = rows.last().unwrap();
        assert!((0.5 * (last.strain_max - last.strain_min) / 0.006 - 1.0).abs() < 0.02);
        lm.stop(&cfg);
        run(&mut lm, &mut vb, 3 * n, &mut rows);
        assert_eq!(lm.stage, Stage::Stopped);
    }

    #[test]
    fn strain_life_holds_the_amplitude_and_detects_the_load_drop() {
        let cfg = bar(LifeMode::Strain, 0.008);
        let t0 = std::time::Instant::now();
        let o = run_life(&cfg, None, None).unwrap();
        eprintln!("wall {:?} resolved {} cycles {} end {:?} truth {:?}", t0.elapsed(), o.cycles_simulated, o.cycles, o.end, o.truth);
        assert_eq!(o.end, LifeEnd::Drop, "{:?}", o.end);
        let n50 = o.truth.n_phi50;
        assert!((o.cycles as f64 / n50 - 1.0).abs() < 0.02, "detected {} vs true {}", o.cycles, n50);
        let r = &o.records;
        let i = r.cycle.len() / 2;
        let ea = 0.5 * (r.strain_max[i] - r.strain_min[i]);
        assert!((ea / 0.008 - 1.0).abs() < 0.02, "strain amplitude {ea}");
    }
}
