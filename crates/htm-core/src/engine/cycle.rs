//! The cycle machine: what a force test does every control period and every cycle, the one copy
//! used by the simulator (`engine::run_test`), the real-time loop (`cyclic::Cyclic`) and so the
//! virtual rig. Per period: waveform phase, smooth start, hold/resume/stop ramps, peak-valley
//! compensation, the force loop's command, the cycle's peak and valley. Per cycle: ΔK and da/dN
//! from the measured peak and valley, crack and phase bookkeeping, tolerance, end conditions and
//! convergence. Plain data (serde): the simulator's snapshots save it whole.
use super::config::{events, hydraulic_stiffness, measure_velocity_gain, measured_k, series_stiffness, targets, Action, ControllerSpec, EndReason, Level, TestConfig};
use crate::control::{Demod, DemodGains, ForceLoop, PeakValley, PositionForce, Setpoint};
use crate::error::Result;
use crate::waveform::{Ramp, Waveform};

use super::convergence::{Cause, Episode};
use super::measured::{CrackReader, Reading};

/// Amplitude ramp of `hold` [cycles]: quick, but no step in the force rate.
pub const HOLD_CYCLES: f64 = 1.0;

/// What the test is doing.
#[derive(serde::Serialize, serde::Deserialize, Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// smooth start: mean, then amplitude (counted, not judged)
    Starting,
    /// cycling (a resume ramp included: counted, judged once at full amplitude)
    Running,
    /// amplitude ramped to zero at the mean; cycles not counted
    Holding,
    /// amplitude ramping to zero before the valve goes to its null
    Stopping,
    /// valve at its learned null
    Stopped,
}

/// The force loop: force control, or position control with the force turned into a position.
#[derive(serde::Serialize, serde::Deserialize, Debug, Clone)]
#[allow(clippy::large_enum_variant)] // one per test
pub enum Drive {
    Force(ForceLoop),
    Position(PositionForce),
}


/// One closed cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CycleResult {
    /// test cycles counted so far (this one included when `counted`)
    pub cycle: u64,
    pub phase: usize,
    pub fmax_n: f64,
    pub fmin_n: f64,
    pub fmax_target_n: f64,
    pub fmin_target_n: f64,
    pub peak_err_pct: f64,
    pub df_err_pct: f64,
    /// crack length before this cycle's growth [m]
    pub a_m: f64,
    pub delta_k: f64,
    pub delta_k_target: f64,
    pub kmax: f64,
    pub dadn_m: f64,
    /// specimen stiffness K_sp(a) [N/m]
    pub k_sp_n_m: f64,
    pub ymin_m: f64,
    pub ymax_m: f64,
    pub ctrl_u1_v: f64,
    pub ctrl_u2_v: f64,
    pub events: u32,
    /// counted test cycle (the crack grew); held and stopping cycles are not
    pub counted: bool,
    /// full amplitude, judged against the tolerance (start-up and ramps are not)
    pub judged: bool,
    /// the growth law's crack beside the measured one (= `a_m` on the law) [m]
    pub a_law_m: f64,
    /// opening force of the last crack reading (2 % compliance offset) [N], and ΔK_eff of
    /// this cycle from it [Pa·√m]; NaN without a compliance reading
    pub opening_force_n: f64,
    pub delta_k_eff: f64,
}

/// The controller side of a force test (see the module doc).
#[derive(serde::Serialize, serde::Deserialize, Debug, Clone)]
pub struct CycleMachine {
    pub drive: Drive,
    pub stage: Stage,
    /// samples per cycle and control period [s]
    pub n: usize,
    pub dt: f64,
    k: usize,
    /// sin/cos of the waveform phase (by rotation: exact to the last bit on every platform) and
    /// of one sample's step; the unit shape now
    rot: (f64, f64),
    step_rot: (f64, f64),
    s: f64,
    /// test cycles counted, crack length [m], phase, crack length at the phase start [m]
    pub cycle: u64,
    pub a: f64,
    pub phase_i: usize,
    pub a_phase0: f64,
    /// force at the start [N] (the smooth start ramps the mean from there)
    f0: f64,
    /// this cycle: targets (Fmax, Fmin, ΔK), mid and half-range [N], the next cycle's mid [N]
    t: (f64, f64, f64),
    mid_t: f64,
    amp_t: f64,
    next_mid: f64,
    starting: bool,
    counting: bool,
    /// the amplitude scale stayed 1 over the whole cycle
    full: bool,
    /// amplitude ramp of hold / resume / stop, per sample
    ramp: Ramp,
    ramping_in: bool,
    /// peak-valley compensation, and this cycle's rise into the peak relative to its range
    /// (≠ 1 when the previous cycle's valley was another level's)
    pub pv: PeakValley,
    k_rise: f64,
    /// phase where the shape falls through zero: the rise's half ends there
    x_fall: f64,
    compensate: bool,
    /// variable-amplitude cursor: level index and cycles left on it
    seq: (usize, u64),
    /// peak and valley of force, position and the nominal setpoint this cycle
    acc: [f64; 6],
    s_hi: f64,
    s_lo: f64,
    open: bool,
    /// the setpoint of the next sample [N] (raw capture)
    pub f_ref: f64,
    pub out_count: u64,
    pub max_df: f64,
    pub max_peak: f64,
    pub size_cycle: Option<u64>,
    pub convergence: Vec<Episode>,
    pub end: Option<EndReason>,
    /// the valve command that holds the piston still, learned by the force loop [V]
    pub u_null: f64,
    pub velocity_gain: f64,
    pub gains: Option<DemodGains>,
    /// the growth law's crack [m], integrated beside the measured one (the same when the test
    /// runs on the law); the crack reader when the spec names a measurement, and its last reading
    pub a_law: f64,
    pub reader: Option<CrackReader>,
    pub reading: Option<Reading>,
}

const EMPTY: [f64; 6] = [f64::MIN, f64::MAX, f64::MAX, f64::MIN, f64::MIN, f64::MAX];

impl CycleMachine {
    /// A test at rest with the force `f0` [N] measured, ready for its first cycle at `rate_hz`:
    /// the controller designed for the specimen at a0 (the valve's velocity gain measured on the
    /// plant model when the spec gives none). `cfg` must be validated.
    pub fn new(cfg: &TestConfig, rate_hz: f64, f0: f64) -> Result<Self> {
        let n = (rate_hz / cfg.frequency_hz).round().max(1.0) as usize;
        let dt = 1.0 / (n as f64 * cfg.frequency_hz);
        let f0 = if f0.is_finite() { f0 } else { 0.0 };
        let ksp0 = cfg.specimen.stiffness(cfg.a0_m, &cfg.material)?;
        let y0 = cfg.params.specimen_zero_force_position_m;
        let u_max = cfg.params.valve_max_command_v;
        let k_eff = series_stiffness(ksp0, hydraulic_stiffness(&cfg.params, y0));
        // the valve's gain depends on the opening (low near null): measure it at the command
        // amplitude the test will need (two fixed-point rounds from 0.1 V)
        let measured_kv = |given: Option<f64>| -> Result<f64> {
            if let Some(k) = given {
                return Ok(k);
            }
            let (fmax, fmin) = first_forces(cfg)?;
            let need = |kv: f64| (0.5 * (fmax - fmin) * 2.0 * std::f64::consts::PI * cfg.frequency_hz / (k_eff * kv)).abs().clamp(0.005, 1.0);
            let mut kv = measure_velocity_gain(&cfg.params, 0.1)?;
            for _ in 0..2 {
                kv = measure_velocity_gain(&cfg.params, need(kv))?;
            }
            Ok(kv)
        };
        let (drive, kv, gains) = match cfg.controller {
            ControllerSpec::ForceP { kp_v_per_n, u_offset_v } => (Drive::Force(ForceLoop::ForceP { kp_v_per_n, u_offset_v, u_max_v: u_max }), f64::NAN, None),
            ControllerSpec::Demod { velocity_gain_m_s_per_v } => {
                let kv = measured_kv(velocity_gain_m_s_per_v)?;
                let g = DemodGains::design(k_eff, kv, cfg.frequency_hz, n as f64 * cfg.frequency_hz)?;
                (Drive::Force(ForceLoop::Demod(Demod::new(g, cfg.waveform.stats(), u_max, f0))), kv, Some(g))
            }
            ControllerSpec::PositionPff { velocity_gain_m_s_per_v, kp_v_per_m, kff_v_per_m_s, u_offset_v } => {
                let kv = measured_kv(velocity_gain_m_s_per_v)?;
                // against the specimen part of the valve's flow compresses the oil column: the
                // piston moves at k_v·K_series/K_sp
                let mut pc = PositionForce::design(kv * k_eff / ksp0, ksp0, y0, u_max)?;
                if let crate::control::Controller::PositionPff { kp_v_per_m: kp, kff_v_per_m_s: kff, .. } = &mut pc.ctrl {
                    *kp = kp_v_per_m.unwrap_or(*kp);
                    *kff = kff_v_per_m_s.unwrap_or(*kff);
                }
                pc.u_offset_v = u_offset_v;
                (Drive::Position(pc), kv, None)
            }
        };
        let step = 2.0 * std::f64::consts::PI / n as f64;
        Ok(CycleMachine {
            drive, stage: Stage::Starting, n, dt, k: 0, rot: (0.0, 1.0), step_rot: (step.sin(), step.cos()), s: 0.0,
            cycle: 0, a: cfg.a0_m, phase_i: 0, a_phase0: cfg.a0_m, f0, t: (0.0, 0.0, 0.0), mid_t: 0.0, amp_t: 0.0, next_mid: 0.0,
            starting: true, counting: true, full: false, ramp: Ramp::FULL, ramping_in: false,
            pv: PeakValley::new(), k_rise: 1.0, x_fall: cfg.waveform.fall_crossing(),
            // peak-valley compensation corrects the force of both force and position control;
            // a fixed-gain force P is the thesis's uncompensated comparison case
            compensate: !matches!(cfg.controller, ControllerSpec::ForceP { .. }),
            seq: (0, cfg.sequence.first().map(|l| l.cycles).unwrap_or(0)),
            acc: EMPTY, s_hi: f64::MIN, s_lo: f64::MAX, open: false, f_ref: f0,
            out_count: 0, max_df: 0.0, max_peak: 0.0, size_cycle: None, convergence: vec![Episode::new(Cause::Start)], end: None,
            u_null: 0.0, velocity_gain: kv, gains,
            a_law: cfg.a0_m, reader: CrackReader::new(&cfg.measurement, &cfg.specimen, &cfg.material, cfg.a0_m), reading: None,
        })
    }

    /// Targets (Fmax, Fmin, ΔK) of the cycle in progress.
    pub fn targets(&self) -> (f64, f64, f64) {
        self.t
    }

    /// A cycle ends with the next sample.
    #[inline]
    pub fn at_boundary(&self) -> bool {
        self.k == 0
    }

    /// One control period: the measured force [N] and position [m] in, the valve command [V] out.
    /// Returns the cycle that closed with this sample, if one did.
    #[inline]
    pub fn step(&mut self, cfg: &TestConfig, f: f64, y: f64) -> Result<(f64, Option<CycleResult>)> {
        self.observe(f, y);
        let mut closed = None;
        if self.k == 0 {
            closed = self.close(cfg)?;
            self.begin(cfg)?;
        }
        Ok((self.command(cfg, f, y), closed))
    }

    /// One control period with the crack measurement's channel `m` (opening [m] or potential
    /// [V]; NaN when absent): `step` with the sample taken into the crack reading.
    #[inline]
    pub fn step_measured(&mut self, cfg: &TestConfig, f: f64, y: f64, m: f64) -> Result<(f64, Option<CycleResult>)> {
        self.observe_measure(f, m);
        self.step(cfg, f, y)
    }

    /// Take the measurement channel's sample with the force into the crack reading: only
    /// full-amplitude counted cycles are read (a ramp's or a hold's are not).
    #[inline]
    pub fn observe_measure(&mut self, f: f64, m: f64) {
        let Some(r) = &mut self.reader else { return };
        r.work(); // the last interval's reduction, a bounded share per control period
        if self.open && self.counting && self.full && !self.starting {
            r.sample(f, m, self.cycle);
        } else if self.starting && self.cycle == 0 {
            r.reference_sample(m); // the start's first cycle: the mean ramps in, the crack is a0
        }
    }

    /// Take a measurement into the cycle's peak and valley (the result of the last command).
    #[inline]
    pub fn observe(&mut self, f: f64, y: f64) {
        if self.open && f.is_finite() {
            let a = &mut self.acc;
            a[0] = a[0].max(f);
            a[1] = a[1].min(f);
            a[2] = a[2].min(y);
            a[3] = a[3].max(y);
        }
    }

    fn level(&self, cfg: &TestConfig, i: usize) -> Level {
        cfg.sequence[i % cfg.sequence.len()]
    }

    /// Start the next cycle: its targets, what it counts as.
    pub fn begin(&mut self, cfg: &TestConfig) -> Result<()> {
        if self.stage == Stage::Stopping && self.ramp.done() {
            self.stage = Stage::Stopped;
            self.u_null = self.summary().1.clamp(-1.0, 1.0);
        }
        if self.stage == Stage::Stopped {
            return Ok(());
        }
        let ph = cfg.phases[self.phase_i];
        let a = self.a.min(cfg.specimen.a_range().1);
        let prev_valley = self.t.1;
        if cfg.sequence.is_empty() {
            self.t = targets(cfg, &ph, self.a_phase0, a)?;
            self.next_mid = 0.5 * (self.t.0 + self.t.1);
        } else {
            let l = self.level(cfg, self.seq.0);
            let nl = if self.seq.1 > 1 { l } else { self.level(cfg, self.seq.0 + 1) };
            let dk = measured_k(&cfg.specimen, a, l.fmax_n, l.fmin_n, l.fmin_n / l.fmax_n)?.0;
            self.t = (l.fmax_n, l.fmin_n, dk);
            self.next_mid = 0.5 * (nl.fmax_n + nl.fmin_n);
        }
        self.mid_t = 0.5 * (self.t.0 + self.t.1);
        self.amp_t = 0.5 * (self.t.0 - self.t.1);
        self.k_rise = if self.cycle == 0 { 1.0 } else { (self.t.0 - prev_valley) / (self.t.0 - self.t.1) };
        self.starting = self.cycle < cfg.envelope.start_cycles();
        if self.stage == Stage::Starting && !self.starting {
            self.stage = Stage::Running;
        }
        self.counting = matches!(self.stage, Stage::Starting | Stage::Running);
        self.full = self.ramp.done() && self.ramp.target() >= 1.0;
        self.acc = EMPTY;
        self.s_hi = f64::MIN;
        self.s_lo = f64::MAX;
        self.rot = (0.0, 1.0);
        self.s = cfg.waveform.shape(0.0);
        self.open = true;
        Ok(())
    }

    /// The nominal (mid-point, half-range) [N] at cycle position x with amplitude scale `scale`,
    /// and the commanded half-range with the peak-valley compensation (`compensated`).
    /// Between two levels of a sequence the falling half moves the mid-point to the next level's,
    /// so the setpoint is continuous and still meets this cycle's peak and valley.
    #[inline]
    fn setpoint(&self, cfg: &TestConfig, x: f64, scale: f64, compensated: bool) -> (f64, f64) {
        let (mut mid, mut amp, mut sigma) = (self.mid_t, self.amp_t, scale);
        if self.starting {
            let (fm, fa) = cfg.envelope.start(self.cycle as f64 + x);
            mid = self.f0 + (self.mid_t - self.f0) * fm;
            amp *= fa;
            sigma *= fa;
        } else if self.next_mid != self.mid_t && x > self.x_fall {
            mid = self.mid_t + (self.next_mid - self.mid_t) * (x - self.x_fall) / (1.0 - self.x_fall);
            amp = mid - self.t.1;
        }
        amp *= scale;
        if compensated && self.compensate {
            // the correction of each reversal in proportion to the excursion into it
            let rising = x <= self.x_fall;
            let k = if rising { self.k_rise } else { 1.0 };
            amp += self.amp_t * sigma * (self.pv.apply(1.0, rising) - 1.0) * k;
        }
        (mid, amp)
    }

    /// The valve command for this period.
    #[inline]
    pub fn command(&mut self, cfg: &TestConfig, f: f64, y: f64) -> f64 {
        if self.stage == Stage::Stopped {
            return self.u_null;
        }
        let n = self.n as f64;
        let (x, x1) = (self.k as f64 / n, (self.k + 1) as f64 / n);
        let (sn, cn) = self.rot;
        let (ss, cs) = self.step_rot;
        let rot1 = (sn * cs + cn * ss, cn * cs - sn * ss);
        let s_next = if matches!(cfg.waveform, Waveform::Sine) { rot1.0 } else { cfg.waveform.shape(x1) };
        let (sc, sc1) = (self.ramp.scale(0), self.ramp.scale(1));
        let (nmid1, namp1) = self.setpoint(cfg, x1, sc1, false);
        // the nominal setpoint's true peak and valley (mid ± amp where the shape peaks): the
        // sampled shape can miss the corner between two samples (a triangle at 20 Hz, 1 kHz)
        if s_next > self.s_hi {
            self.s_hi = s_next;
            self.acc[4] = nmid1 + namp1;
        }
        if s_next < self.s_lo {
            self.s_lo = s_next;
            self.acc[5] = nmid1 - namp1;
        }
        let (mid, amp) = self.setpoint(cfg, x, sc, true);
        let (mid1, amp1) = self.setpoint(cfg, x1, sc1, true);
        // the next sample's setpoint exactly, in terms of this sample's half-range (the loops'
        // feed-forward is then the setpoint's rate, ramps included)
        // the amplitude loop learns the plant's gain from the amplitudes the compensation learns from
        let fa = if self.starting { cfg.envelope.start(self.cycle as f64 + x).1 } else { 1.0 };
        let learn = sc * fa >= PeakValley::MIN_AMPLITUDE_FRACTION;
        let sp = Setpoint { mid_n: mid, mid_next_n: mid1 + (amp1 - amp) * s_next, amp_n: amp, s: self.s, s_next, sin: sn, cos: cn, learn };
        self.f_ref = mid1 + amp1 * s_next;
        let u = if f.is_finite() {
            match &mut self.drive {
                Drive::Force(c) => c.command(&sp, f),
                Drive::Position(pc) => pc.command(&sp, y, self.dt),
            }
        } else {
            0.0
        };
        self.ramp.advance();
        self.rot = rot1;
        self.s = s_next;
        self.k = if self.k + 1 == self.n { 0 } else { self.k + 1 };
        u
    }

    /// (amplitude-loop, mean-loop) outputs of the force loop [V] for the table.
    fn summary(&self) -> (f64, f64) {
        match &self.drive {
            Drive::Force(c) => {
                let (u1, u2, _, _) = c.summary();
                (u1, u2)
            }
            Drive::Position(pc) => (0.0, pc.u_offset_v),
        }
    }

    /// Close the cycle in progress: growth from its measured peak and valley, bookkeeping and end
    /// conditions. None when no cycle was open.
    pub fn close(&mut self, cfg: &TestConfig) -> Result<Option<CycleResult>> {
        if !self.open || self.acc[0] == f64::MIN {
            return Ok(None);
        }
        self.open = false;
        let [fmax, fmin, ymin, ymax, rmax, rmin] = self.acc;
        let (tmax, tmin, dkt) = self.t;
        let spec = &cfg.specimen;
        let ph = cfg.phases[self.phase_i];
        let learn = matches!(self.stage, Stage::Starting | Stage::Running);
        if self.compensate && learn && rmax - rmin >= PeakValley::MIN_AMPLITUDE_FRACTION * 2.0 * self.amp_t {
            let gain = if self.starting || self.ramping_in { PeakValley::RAMP_GAIN } else { PeakValley::GAIN };
            self.pv.update(rmax, rmin, fmax, fmin, self.k_rise * (rmax - rmin), rmax - rmin, gain);
        }
        if let Drive::Position(pc) = &mut self.drive {
            pc.measured(fmax - fmin, ymax - ymin);
        }
        let pe = (fmax - tmax) / tmax;
        let de = ((fmax - fmin) - (tmax - tmin)) / (tmax - tmin);
        let (u1, u2) = self.summary();
        let ksp = spec.stiffness(self.a.min(spec.a_range().1), &cfg.material).unwrap_or(f64::NAN);
        let mut r = CycleResult {
            cycle: self.cycle, phase: self.phase_i, fmax_n: fmax, fmin_n: fmin, fmax_target_n: tmax, fmin_target_n: tmin,
            peak_err_pct: pe * 100.0, df_err_pct: de * 100.0, a_m: self.a, delta_k: f64::NAN, delta_k_target: dkt, kmax: f64::NAN,
            dadn_m: 0.0, k_sp_n_m: ksp, ymin_m: ymin, ymax_m: ymax, ctrl_u1_v: u1, ctrl_u2_v: u2, events: 0, counted: self.counting,
            judged: false, a_law_m: self.a_law, opening_force_n: self.reader.as_ref().map_or(f64::NAN, |r| r.opening_force_n()), delta_k_eff: f64::NAN,
        };
        if !self.counting {
            if matches!(self.stage, Stage::Stopping | Stage::Stopped) {
                r.events |= events::STOP;
            }
            return Ok(Some(r));
        }
        self.cycle += 1;
        r.cycle = self.cycle;
        // crack growth from the measured peak and valley (the nominal R picks the E647 rule)
        let r_nom = if cfg.sequence.is_empty() { ph.r_ratio } else { tmin / tmax };
        let (dk, kmax, r_meas) = if fmax > 0.0 { measured_k(spec, self.a, fmax, fmin, r_nom)? } else { (0.0, 0.0, 0.0) };
        let dadn = cfg.law.rate(dk, r_meas, kmax);
        (r.delta_k, r.kmax, r.dadn_m) = (dk, kmax, dadn);
        let mut ev = if self.starting { events::START } else { 0 };
        let mut stop: Option<EndReason> = None;
        r.judged = !self.starting && self.full;
        // the law's crack beside the measured one: its own ΔK from the measured forces
        let dadn_law = if self.reader.is_some() && fmax > 0.0 {
            let a_law = self.a_law.min(spec.a_range().1);
            let (dkl, kml, rl) = measured_k(spec, a_law, fmax, fmin, r_nom)?;
            cfg.law.rate(dkl, rl, kml)
        } else {
            dadn
        };
        if let Some(reader) = &mut self.reader {
            if r.judged {
                match reader.cycle_closed(spec, self.cycle) {
                    Some(rd) => {
                        self.reading = Some(rd);
                        ev |= events::READING;
                    }
                    None if reader.last_error.is_some() => {
                        reader.last_error = None;
                        ev |= events::READING_FAILED;
                    }
                    None => {}
                }
            } else {
                reader.discard();
            }
            if self.reading.is_some() {
                let f_op = reader.opening_force_n();
                r.opening_force_n = f_op;
                r.delta_k_eff = if f_op.is_finite() { crate::crack_measure::delta_k(spec, self.a, fmin, fmax, f_op).1 } else { dk };
                if reader.opening_unresolved() {
                    // the gauge's noise hides the closure: no opening force, ΔK_eff not claimed; the
                    // bit marks the readings that leave it so (not every cycle: a recording thins
                    // the cycles without events)
                    r.delta_k_eff = f64::NAN;
                    if ev & events::READING != 0 {
                        ev |= events::CLOSURE_UNRESOLVED;
                    }
                }
            }
        }
        if self.ramping_in && !r.judged {
            ev |= events::RAMP;
        }
        if r.judged {
            if self.ramping_in {
                self.ramping_in = false;
            }
            self.max_peak = self.max_peak.max(pe.abs() * 100.0);
            self.max_df = self.max_df.max(de.abs() * 100.0);
            if let Some(e) = self.convergence.last_mut() {
                e.observe(self.cycle, de);
            }
            if pe.abs() > ph.tolerance || de.abs() > ph.tolerance {
                ev |= events::OUT_OF_TOLERANCE;
                self.out_count += 1;
                if self.out_count > cfg.limits.tolerance_cycles {
                    ev |= events::TOLERANCE_EXCEEDED;
                    if cfg.limits.tolerance_action == Action::Stop {
                        stop = Some(EndReason::ForceTolerance);
                    }
                }
            } else {
                self.out_count = 0;
            }
        }
        if kmax >= cfg.material.fracture_toughness_pa_sqrt_m {
            stop = stop.or(Some(EndReason::Toughness));
        }
        if fmax > 0.0 {
            let (lig, req) = spec.size_criterion(self.a, fmax, cfg.material.yield_strength_pa)?;
            if lig < req {
                ev |= events::SIZE_CRITERION;
                self.size_cycle.get_or_insert(self.cycle);
                if cfg.limits.size_criterion == Action::Stop {
                    stop = stop.or(Some(EndReason::SizeCriterion));
                }
            }
        }
        let margin = cfg.limits.stroke_margin_m;
        if ymin < margin || ymax > cfg.params.stroke_m - margin {
            stop = stop.or(Some(EndReason::StrokeLimit));
        }
        let a_next = match &mut self.reader {
            Some(reader) => {
                // the law is the measured line's prior growth rate (the readings dominate once they can)
                reader.set_law_rate(dadn, self.cycle);
                reader.a_at(self.cycle)
            }
            None => self.a + dadn,
        };
        if dadn_law.is_finite() {
            self.a_law = (self.a_law + dadn_law).min(spec.a_range().1);
        }
        let end = if stop.is_some() {
            stop
        } else if !a_next.is_finite() || (self.reader.is_none() && !dadn.is_finite()) || a_next >= spec.a_range().1 {
            Some(EndReason::Fracture)
        } else {
            self.a = a_next;
            let mut end = None;
            if self.a >= ph.end_a_m {
                if self.phase_i + 1 == cfg.phases.len() {
                    end = Some(EndReason::TargetCrack);
                } else {
                    self.phase_i += 1;
                    self.a_phase0 = self.a;
                    ev |= events::PHASE_CHANGE;
                }
            }
            end.or((self.cycle >= cfg.limits.max_cycles).then_some(EndReason::CycleLimit))
        };
        r.events = ev;
        if !cfg.sequence.is_empty() {
            self.next_level(cfg);
        }
        if let Some(e) = end {
            self.finish(cfg, e);
            r.events |= events::END;
        }
        Ok(Some(r))
    }

    /// One cycle of the sequence's level done: on to the next level when this one's are. Each
    /// block's convergence is logged once, on the first pass (a spectrum's one-cycle levels are
    /// the start's episode).
    fn next_level(&mut self, cfg: &TestConfig) {
        self.seq.1 -= 1;
        if self.seq.1 > 0 {
            return;
        }
        self.seq.0 = (self.seq.0 + 1) % cfg.sequence.len();
        self.seq.1 = cfg.sequence[self.seq.0].cycles;
        if self.seq.1 > 1 {
            if let Some(e) = self.convergence.last_mut() {
                e.closed = true;
            }
            if self.seq.0 != 0 && self.cycle < cfg.sequence.iter().map(|l| l.cycles).sum::<u64>() {
                self.convergence.push(Episode::new(Cause::Level));
            }
        }
    }

    /// The test has ended (`reason`): a smooth stop, or at once to the valve null when the stroke
    /// ran out, the specimen broke or the run was cancelled.
    pub fn finish(&mut self, cfg: &TestConfig, reason: EndReason) {
        self.end = Some(reason);
        if matches!(reason, EndReason::StrokeLimit | EndReason::Fracture | EndReason::Cancelled) || cfg.envelope.stop_cycles <= 0.0 {
            self.stage = Stage::Stopped;
            self.u_null = self.summary().1.clamp(-1.0, 1.0);
        } else {
            self.stop(cfg);
        }
    }

    /// Freeze at the mean: the amplitude ramps to zero over `HOLD_CYCLES`; cycles stop counting.
    pub fn hold(&mut self) -> bool {
        match self.stage {
            Stage::Starting | Stage::Running => {
                self.ramp.retarget(0.0, HOLD_CYCLES, self.n);
                self.full = false;
                self.stage = Stage::Holding;
                true
            }
            Stage::Holding => true,
            _ => false,
        }
    }

    /// Ramp the amplitude back in (over the start's amplitude cycles) after `hold`; the ramp's
    /// cycles are counted but not judged, and convergence is logged again from its end.
    pub fn resume(&mut self, cfg: &TestConfig) -> bool {
        if self.stage != Stage::Holding {
            return false;
        }
        self.ramp.retarget(1.0, cfg.envelope.amplitude_cycles.max(1.0), self.n);
        self.full = false;
        self.stage = if self.cycle < cfg.envelope.start_cycles() { Stage::Starting } else { Stage::Running };
        self.ramping_in = true;
        self.convergence.push(Episode::new(Cause::Resume));
        true
    }

    /// Ramp the amplitude to zero at the mean over the spec's stop cycles, then valve null.
    pub fn stop(&mut self, cfg: &TestConfig) {
        if matches!(self.stage, Stage::Starting | Stage::Running | Stage::Holding) {
            self.ramp.retarget(0.0, cfg.envelope.stop_cycles.max(0.5), self.n);
            self.full = false;
            self.stage = Stage::Stopping;
        }
    }

    /// The plant's stiffness stepped (a simulated disturbance): log the convergence again.
    pub fn disturbed(&mut self, cause: Cause) {
        self.convergence.push(Episode::new(cause));
    }

    /// A cycle jump (simulation): the specimen's stiffness changed by `ratio` (new/old) with the
    /// force kept continuous, so the controller carries its converged state across.
    pub fn rescale_gain(&mut self, ratio: f64) {
        if let Drive::Force(c) = &mut self.drive {
            c.rescale_gain(ratio);
        }
    }

    /// Worst |ΔF error| of the first full-amplitude cycles after the start [%] (NaN before any).
    pub fn worst_first_cycles_df_pct(&self) -> f64 {
        self.convergence.iter().find(|e| e.cause == Cause::Start && e.cycles_seen > 0).map(|e| e.worst_first_df_pct).unwrap_or(f64::NAN)
    }
}

/// Peak and valley [N] of the first cycle at full amplitude (what the valve must deliver first).
fn first_forces(cfg: &TestConfig) -> Result<(f64, f64)> {
    Ok(match cfg.sequence.first() {
        Some(l) => (l.fmax_n, l.fmin_n),
        None => {
            let (fmax, fmin, _) = targets(cfg, &cfg.phases[0], cfg.a0_m, cfg.a0_m)?;
            (fmax, fmin)
        }
    })
}
