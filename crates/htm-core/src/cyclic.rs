//! The per-period controller of the real-time loop: one call per control period turns the
//! measured force and position into a valve command. A force test runs the engine's cyclic
//! setpoint (waveform phase, smooth start, per-cycle peak/valley, peak-valley compensation) around
//! a `ForceLoop`; a position mode (install, jog, move) limits the specimen force (specimen protect).
//! Hold, resume and stop ramp the amplitude; the state machine is here so that the loop in Python
//! only moves numbers.
use crate::control::{Demod, DemodGains, ForceLoop, Setpoint};
use crate::engine::{hydraulic_stiffness, measure_velocity_gain, series_stiffness, targets, ControllerSpec, EndReason, TestConfig};
use crate::error::{Error, Result};
use crate::waveform::Waveform;

/// Per-cycle integral gain of the peak-valley compensation (as the engine: the inner loops settle
/// in ≈ 2 cycles).
const PV_GAIN: f64 = 0.3;
/// Amplitude ramp of `hold` [cycles]: quick, but no step in the force rate.
const HOLD_CYCLES: f64 = 1.0;

/// What the controller is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum State {
    /// no control: the command is 0 V (amplifier off)
    Idle,
    /// position control (install, jog, move) with specimen protect
    Position,
    /// force test: smooth start (mean, then amplitude)
    Starting,
    /// force test: cycling (cycles counted, crack grows)
    Running,
    /// force test: amplitude ramped to zero, mean held; `resume` ramps it back
    Holding,
    /// force test: amplitude ramping to zero before the valve goes to null
    Stopping,
    /// valve at its learned null
    Stopped,
}

impl State {
    pub fn name(self) -> &'static str {
        match self {
            State::Idle => "idle",
            State::Position => "position",
            State::Starting => "starting",
            State::Running => "running",
            State::Holding => "holding",
            State::Stopping => "stopping",
            State::Stopped => "stopped",
        }
    }
}

/// Position loop settings (SI).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PositionGains {
    /// position loop crossover [1/s]: commanded velocity per metre of error
    pub bandwidth_per_s: f64,
    /// valve velocity gain [m/s per V], signed by polarity (thesis rig ≈ −0.07)
    pub velocity_gain_m_s_per_v: f64,
    /// integral time of the null-offset integrator [s]
    pub integral_time_s: f64,
    /// fastest commanded speed [m/s]
    pub max_speed_m_s: f64,
    /// specimen protect: largest |force| the motion may cause [N]; 0 = off
    pub protect_force_n: f64,
    /// stiffness assumed for the protect loop gain [N/m]
    pub protect_stiffness_n_m: f64,
    /// soft stroke limits of the reference [m]
    pub y_min_m: f64,
    pub y_max_m: f64,
    pub u_max_v: f64,
}

impl Default for PositionGains {
    fn default() -> Self {
        PositionGains { bandwidth_per_s: 20.0, velocity_gain_m_s_per_v: -0.07, integral_time_s: 0.3, max_speed_m_s: 0.02, protect_force_n: 0.0, protect_stiffness_n_m: 1.0e8, y_min_m: 0.005, y_max_m: 0.195, u_max_v: 10.0 }
    }
}

impl PositionGains {
    pub fn validate(&self) -> Result<()> {
        let pos = |field: &str, v: f64| if v.is_finite() && v > 0.0 { Ok(()) } else { Err(Error::Parameter { field: format!("position.{field}"), value: v, allowed: "(0, inf)".into() }) };
        pos("bandwidth_per_s", self.bandwidth_per_s)?;
        pos("integral_time_s", self.integral_time_s)?;
        pos("max_speed_m_s", self.max_speed_m_s)?;
        pos("protect_stiffness_n_m", self.protect_stiffness_n_m)?;
        pos("u_max_v", self.u_max_v)?;
        if !(self.velocity_gain_m_s_per_v.is_finite() && self.velocity_gain_m_s_per_v != 0.0) {
            return Err(Error::Parameter { field: "position.velocity_gain_m_s_per_v".into(), value: self.velocity_gain_m_s_per_v, allowed: "non-zero, finite (negative on the thesis rig)".into() });
        }
        if !(self.protect_force_n.is_finite() && self.protect_force_n >= 0.0) {
            return Err(Error::Parameter { field: "position.protect_force_n".into(), value: self.protect_force_n, allowed: "[0, inf) N (0 = off)".into() });
        }
        if !(self.y_min_m < self.y_max_m) {
            return Err(Error::Parameter { field: "position.y_min_m".into(), value: self.y_min_m, allowed: format!("< y_max_m = {}", self.y_max_m) });
        }
        Ok(())
    }
}

/// Position control with velocity feed-through, a slow null integrator and specimen protect:
/// when |force| passes the protect level the reference stops where the piston is and the command
/// backs off in proportion to the excess (force rises with y: the specimen hangs above the piston).
#[derive(Debug, Clone)]
struct PositionLoop {
    g: PositionGains,
    r: f64,
    rate: f64,
    target: Option<f64>,
    integ: f64,
    protecting: bool,
}

impl PositionLoop {
    fn step(&mut self, f: f64, y: f64, dt: f64) -> f64 {
        let g = &self.g;
        let vmax = g.max_speed_m_s;
        match self.target {
            Some(t) => self.r += (t - self.r).clamp(-vmax * dt, vmax * dt),
            None => self.r += self.rate * dt,
        }
        self.r = self.r.clamp(g.y_min_m, g.y_max_m);
        if !y.is_finite() {
            return 0.0;
        }
        let mut v = (g.bandwidth_per_s * (self.r - y)).clamp(-vmax, vmax);
        self.protecting = false;
        if g.protect_force_n > 0.0 && f.is_finite() {
            let kf = g.bandwidth_per_s / g.protect_stiffness_n_m;
            let (over, under) = (f - g.protect_force_n, -g.protect_force_n - f);
            if over > 0.0 {
                v = v.min(-kf * over);
                self.r = self.r.min(y);
                self.protecting = true;
            } else if under > 0.0 {
                v = v.max(kf * under);
                self.r = self.r.max(y);
                self.protecting = true;
            }
        }
        let u_p = v / g.velocity_gain_m_s_per_v;
        if !self.protecting {
            self.integ = (self.integ + dt / g.integral_time_s * u_p).clamp(-1.0, 1.0);
        }
        (u_p + self.integ).clamp(-g.u_max_v, g.u_max_v)
    }
}

/// One closed cycle of a force test (what the per-cycle table and the console show).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CycleResult {
    /// test cycles counted so far (this one included)
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
    pub kmax: f64,
    pub dadn_m: f64,
    pub k_sp_n_m: f64,
    pub ymin_m: f64,
    pub ymax_m: f64,
    pub ctrl_u1_v: f64,
    pub ctrl_u2_v: f64,
    /// start-up cycle (not judged against the tolerance)
    pub starting: bool,
}

#[derive(Debug, Clone)]
struct ForceTest {
    cfg: TestConfig,
    ctrl: ForceLoop,
    n: usize,
    k: usize,
    cycle: u64,
    n_start: u64,
    a: f64,
    phase_i: usize,
    a_phase0: f64,
    comp_amp: f64,
    comp_mid: f64,
    compensate: bool,
    /// amplitude scale (hold/resume/stop ramps) and where it is going, per sample
    scale: f64,
    scale_target: f64,
    scale_rate: f64,
    f0: f64,
    mid_t: f64,
    amp_t: f64,
    t: (f64, f64, f64),
    counting: bool,
    starting: bool,
    acc: (f64, f64, f64, f64),
    have_prev: bool,
    sample_pos: (f64, f64),
    gains: Option<DemodGains>,
    velocity_gain: f64,
}

/// The per-period controller (see the module doc).
#[derive(Debug, Clone)]
pub struct Cyclic {
    pub rate_hz: f64,
    dt: f64,
    pub state: State,
    pos: PositionLoop,
    test: Option<ForceTest>,
    /// largest |command| written (a trip lowers it to the safe value) [V]
    pub command_limit_v: f64,
    pub u_last: f64,
    /// the valve command that holds the piston still, learned by the force loop [V]
    pub u_null: f64,
    pub end_reason: Option<EndReason>,
    pub results: u64,
    pub last: Option<CycleResult>,
}

impl Cyclic {
    pub fn new(rate_hz: f64, position: PositionGains) -> Result<Self> {
        if !(rate_hz.is_finite() && (50.0..=20_000.0).contains(&rate_hz)) {
            return Err(Error::Parameter { field: "loop.rate_hz".into(), value: rate_hz, allowed: "[50, 20000] Hz".into() });
        }
        position.validate()?;
        Ok(Cyclic {
            rate_hz, dt: 1.0 / rate_hz, state: State::Idle,
            pos: PositionLoop { g: position, r: 0.0, rate: 0.0, target: None, integ: 0.0, protecting: false },
            test: None, command_limit_v: f64::INFINITY, u_last: 0.0, u_null: 0.0, end_reason: None, results: 0, last: None,
        })
    }

    /// Switch to position control holding position `y` [m], bumpless from the command `u` [V].
    pub fn position(&mut self, y: f64, u: f64) {
        self.pos.r = if y.is_finite() { y } else { self.pos.r };
        self.pos.rate = 0.0;
        self.pos.target = None;
        self.pos.integ = if u.is_finite() { u.clamp(-1.0, 1.0) } else { 0.0 };
        self.test = None;
        self.state = State::Position;
    }

    fn need_position(&self, what: &str) -> Result<()> {
        if self.state != State::Position {
            return Err(Error::Input(format!("{what} needs position control (state is {})", self.state.name())));
        }
        Ok(())
    }

    /// Move the reference at `rate` [m/s] (0 stops), within the speed and stroke limits.
    pub fn jog(&mut self, rate: f64) -> Result<()> {
        self.need_position("jog")?;
        let v = self.pos.g.max_speed_m_s;
        if !(rate.is_finite() && rate.abs() <= v) {
            return Err(Error::Parameter { field: "jog rate_m_s".into(), value: rate, allowed: format!("[-{v}, {v}] m/s") });
        }
        self.pos.target = None;
        self.pos.rate = rate;
        Ok(())
    }

    /// Move the reference by `dm` [m] at the largest speed.
    pub fn jog_step(&mut self, dm: f64) -> Result<()> {
        self.need_position("jog_step")?;
        let base = self.pos.target.unwrap_or(self.pos.r);
        self.move_to(base + dm)
    }

    /// Move the reference to `y` [m] at the largest speed.
    pub fn move_to(&mut self, y: f64) -> Result<()> {
        self.need_position("move_to")?;
        let g = &self.pos.g;
        if !(y.is_finite() && y >= g.y_min_m && y <= g.y_max_m) {
            return Err(Error::Parameter { field: "move_to y_m".into(), value: y, allowed: format!("[{}, {}] m", g.y_min_m, g.y_max_m) });
        }
        self.pos.rate = 0.0;
        self.pos.target = Some(y);
        Ok(())
    }

    /// Load a force test and start it from the measured force `f0` [N] (smooth start from there).
    pub fn start_test(&mut self, cfg: &TestConfig, f0: f64) -> Result<()> {
        let mut cfg = cfg.clone();
        if !(cfg.frequency_hz.is_finite() && cfg.frequency_hz > 0.0) {
            return Err(Error::Parameter { field: "frequency_hz".into(), value: cfg.frequency_hz, allowed: "(0, inf) Hz".into() });
        }
        // the loop period is fixed: the cycle is a whole number of periods
        let n = (self.rate_hz / cfg.frequency_hz).round().max(1.0) as usize;
        cfg.frequency_hz = self.rate_hz / n as f64;
        cfg.control_rate_hz = self.rate_hz;
        cfg.validate()?;
        let f0 = if f0.is_finite() { f0 } else { 0.0 };
        let mut p = cfg.params.clone();
        let ksp0 = cfg.specimen.stiffness(cfg.a0_m, &cfg.material)?;
        p.specimen_stiffness_n_m = ksp0;
        let y0 = p.specimen_zero_force_position_m;
        let u_max = cfg.params.valve_max_command_v;
        let (ctrl, kv, gains) = match cfg.controller {
            ControllerSpec::ForceP { kp_v_per_n, u_offset_v } => (ForceLoop::ForceP { kp_v_per_n, u_offset_v, u_max_v: u_max }, f64::NAN, None),
            ControllerSpec::Demod { velocity_gain_m_s_per_v } => {
                let k_eff = series_stiffness(ksp0, hydraulic_stiffness(&cfg.params, y0));
                let kv = match velocity_gain_m_s_per_v {
                    Some(k) => k,
                    None => {
                        // as the engine: the model's gain at the opening the test needs
                        let (fmax, fmin, _) = targets(&cfg, &cfg.phases[0], cfg.a0_m, cfg.a0_m)?;
                        let need = |kv: f64| (0.5 * (fmax - fmin) * 2.0 * std::f64::consts::PI * cfg.frequency_hz / (k_eff * kv)).abs().clamp(0.005, 1.0);
                        let mut kv = measure_velocity_gain(&cfg.params, 0.1)?;
                        for _ in 0..2 {
                            kv = measure_velocity_gain(&cfg.params, need(kv))?;
                        }
                        kv
                    }
                };
                let g = DemodGains::design(k_eff, kv, cfg.frequency_hz, self.rate_hz)?;
                (ForceLoop::Demod(Demod::new(g, cfg.waveform.stats(), u_max, f0)), kv, Some(g))
            }
            ControllerSpec::PositionPff { .. } => {
                return Err(Error::Parameter { field: "controller.type".into(), value: f64::NAN, allowed: "demodulation or force_p on the real-time loop (position_pff runs in the simulation engine only)".into() });
            }
        };
        let compensate = matches!(cfg.controller, ControllerSpec::Demod { .. });
        let n_start = cfg.envelope.start_cycles();
        let a0 = cfg.a0_m;
        self.test = Some(ForceTest {
            cfg, ctrl, n, k: 0, cycle: 0, n_start, a: a0, phase_i: 0, a_phase0: a0, comp_amp: 0.0, comp_mid: 0.0, compensate,
            scale: 1.0, scale_target: 1.0, scale_rate: 0.0, f0, mid_t: 0.0, amp_t: 0.0, t: (0.0, 0.0, 0.0), counting: true, starting: true,
            acc: (f64::MIN, f64::MAX, f64::MAX, f64::MIN), have_prev: false, sample_pos: (0.0, 0.0), gains, velocity_gain: kv,
        });
        self.end_reason = None;
        self.results = 0;
        self.last = None;
        self.state = State::Starting;
        Ok(())
    }

    fn ramp_amplitude(&mut self, target: f64, cycles: f64) {
        if let Some(t) = &mut self.test {
            t.scale_target = target;
            t.scale_rate = 1.0 / (cycles.max(0.05) * t.n as f64);
        }
    }

    /// Freeze at the mean: the amplitude ramps to zero over one cycle; cycles stop counting.
    pub fn hold(&mut self) -> Result<()> {
        match self.state {
            State::Starting | State::Running => {
                self.ramp_amplitude(0.0, HOLD_CYCLES);
                self.state = State::Holding;
                Ok(())
            }
            State::Holding => Ok(()),
            s => Err(Error::Input(format!("hold needs a running test (state is {})", s.name()))),
        }
    }

    /// Ramp the amplitude back in (over the start's amplitude cycles) after `hold`.
    pub fn resume(&mut self) -> Result<()> {
        if self.state != State::Holding {
            return Err(Error::Input(format!("resume needs a held test (state is {})", self.state.name())));
        }
        let cycles = self.test.as_ref().map(|t| t.cfg.envelope.amplitude_cycles.max(1.0)).unwrap_or(1.0);
        self.ramp_amplitude(1.0, cycles);
        let starting = self.test.as_ref().map(|t| t.cycle < t.n_start).unwrap_or(false);
        self.state = if starting { State::Starting } else { State::Running };
        Ok(())
    }

    /// Ramp the amplitude to zero at the mean (over the spec's stop cycles), then valve null.
    pub fn stop(&mut self) {
        match self.state {
            State::Starting | State::Running | State::Holding => {
                let cycles = self.test.as_ref().map(|t| t.cfg.envelope.stop_cycles.max(0.5)).unwrap_or(1.0);
                self.ramp_amplitude(0.0, cycles);
                self.state = State::Stopping;
            }
            State::Stopping | State::Stopped | State::Idle => {}
            State::Position => {
                self.u_null = self.pos.integ;
                self.state = State::Stopped;
            }
        }
    }

    /// No control: command 0 V (the loop disables the amplifier).
    pub fn idle(&mut self) {
        self.state = State::Idle;
    }

    /// One control period: measured force `f` [N] and position `y` [m] in, valve command [V] out.
    pub fn step(&mut self, f: f64, y: f64) -> Result<f64> {
        let u = match self.state {
            State::Idle => 0.0,
            State::Stopped => self.u_null,
            State::Position => self.pos.step(f, y, self.dt),
            _ => self.test_step(f, y)?,
        };
        let u = if u.is_finite() { u.clamp(-self.command_limit_v, self.command_limit_v) } else { 0.0 };
        self.u_last = u;
        Ok(u)
    }

    fn test_step(&mut self, f: f64, y: f64) -> Result<f64> {
        let t = self.test.as_mut().expect("a force state has a test");
        if t.have_prev && f.is_finite() {
            t.acc.0 = t.acc.0.max(f);
            t.acc.1 = t.acc.1.min(f);
            t.acc.2 = t.acc.2.min(y);
            t.acc.3 = t.acc.3.max(y);
        }
        if t.k == 0 {
            if t.have_prev {
                self.close_cycle()?;
            }
            self.begin_cycle()?;
        }
        let state = self.state;
        let t = self.test.as_mut().unwrap();
        if state == State::Stopped {
            return Ok(self.u_null);
        }
        let n = t.n as f64;
        let (x, x1) = (t.k as f64 / n, (t.k + 1) as f64 / n);
        let next_scale = if t.scale < t.scale_target { (t.scale + t.scale_rate).min(t.scale_target) } else { (t.scale - t.scale_rate).max(t.scale_target) };
        let set = |x: f64, scale: f64| -> (f64, f64) {
            if t.starting {
                let (fm, fa) = t.cfg.envelope.start(t.sample_pos.0 + x);
                (t.f0 + (t.mid_t - t.f0) * fm, t.amp_t * fa * scale)
            } else {
                (t.mid_t + t.comp_mid * t.amp_t, t.amp_t * (1.0 + t.comp_amp) * scale)
            }
        };
        let (mid, amp) = set(x, t.scale);
        let (mid1, _) = set(x1, next_scale);
        let w = 2.0 * std::f64::consts::PI;
        let wave = &t.cfg.waveform;
        let (s, s_next) = match wave {
            Waveform::Sine => ((w * x).sin(), (w * x1).sin()),
            _ => (wave.shape(x), wave.shape(x1)),
        };
        let sp = Setpoint { mid_n: mid, mid_next_n: mid1, amp_n: amp, s, s_next, sin: (w * x).sin(), cos: (w * x).cos() };
        let u = if f.is_finite() { t.ctrl.command(&sp, f) } else { 0.0 };
        t.scale = next_scale;
        t.k = if t.k + 1 == t.n { 0 } else { t.k + 1 };
        t.have_prev = true;
        // the amplitude has reached zero: a stop ends at the learned null
        if state == State::Stopping && t.scale <= 0.0 && t.k == 0 {
            self.u_null = t.ctrl.summary().1.clamp(-1.0, 1.0);
            self.state = State::Stopped;
        }
        Ok(u)
    }

    fn begin_cycle(&mut self) -> Result<()> {
        let counting = matches!(self.state, State::Starting | State::Running);
        let t = self.test.as_mut().unwrap();
        let ph = t.cfg.phases[t.phase_i];
        let a = t.a.min(t.cfg.specimen.a_range().1);
        t.t = targets(&t.cfg, &ph, t.a_phase0, a)?;
        t.mid_t = 0.5 * (t.t.0 + t.t.1);
        t.amp_t = 0.5 * (t.t.0 - t.t.1);
        t.starting = t.cycle < t.n_start;
        t.sample_pos.0 = t.cycle as f64;
        t.counting = counting;
        t.acc = (f64::MIN, f64::MAX, f64::MAX, f64::MIN);
        if self.state == State::Starting && !t.starting {
            self.state = State::Running;
        }
        Ok(())
    }

    fn close_cycle(&mut self) -> Result<()> {
        let t = self.test.as_mut().unwrap();
        if !t.counting || t.acc.0 == f64::MIN {
            return Ok(());
        }
        let (fmax, fmin) = (t.acc.0, t.acc.1);
        let ph = t.cfg.phases[t.phase_i];
        let spec = &t.cfg.specimen;
        let (dk, kmax, r) = if fmax > 0.0 {
            let kmax = spec.k(t.a, fmax)?;
            let dk = if ph.r_ratio >= 0.0 { spec.k(t.a, fmax - fmin)? } else { kmax };
            (dk, kmax, fmin / fmax)
        } else {
            (0.0, 0.0, 0.0)
        };
        let dadn = t.cfg.law.rate(dk, r, kmax);
        let (tmax, tmin, _) = t.t;
        let pe = (fmax - tmax) / tmax;
        let de = ((fmax - fmin) - (tmax - tmin)) / (tmax - tmin);
        if t.compensate && !t.starting && t.scale >= 1.0 {
            let (amp_m, mid_m) = (0.5 * (fmax - fmin), 0.5 * (fmax + fmin));
            t.comp_amp = (t.comp_amp + PV_GAIN * (t.amp_t - amp_m) / t.amp_t).clamp(-0.2, 0.2);
            t.comp_mid = (t.comp_mid + PV_GAIN * (t.mid_t - mid_m) / t.amp_t).clamp(-0.2, 0.2);
        }
        t.cycle += 1;
        let (u1, u2, _, _) = t.ctrl.summary();
        let ksp = spec.stiffness(t.a, &t.cfg.material).unwrap_or(f64::NAN);
        self.last = Some(CycleResult {
            cycle: t.cycle, phase: t.phase_i, fmax_n: fmax, fmin_n: fmin, fmax_target_n: tmax, fmin_target_n: tmin,
            peak_err_pct: pe * 100.0, df_err_pct: de * 100.0, a_m: t.a, delta_k: dk, kmax, dadn_m: dadn, k_sp_n_m: ksp,
            ymin_m: t.acc.2, ymax_m: t.acc.3, ctrl_u1_v: u1, ctrl_u2_v: u2, starting: t.starting,
        });
        self.results += 1;
        // end conditions, as the engine's (they stop smoothly)
        let kic = t.cfg.material.fracture_toughness_pa_sqrt_m;
        let a_max = spec.a_range().1;
        let mut end = None;
        if kmax >= kic {
            end = Some(EndReason::Toughness);
        } else if !dadn.is_finite() || t.a + dadn >= a_max {
            end = Some(EndReason::Fracture);
        } else {
            t.a += dadn;
            if t.a >= ph.end_a_m {
                if t.phase_i + 1 == t.cfg.phases.len() {
                    end = Some(EndReason::TargetCrack);
                } else {
                    t.phase_i += 1;
                    t.a_phase0 = t.a;
                }
            }
        }
        if end.is_none() && t.cycle >= t.cfg.limits.max_cycles {
            end = Some(EndReason::CycleLimit);
        }
        if let Some(e) = end {
            self.end_reason = Some(e);
            self.stop();
        }
        Ok(())
    }

    pub fn cycle(&self) -> u64 {
        self.test.as_ref().map(|t| t.cycle).unwrap_or(0)
    }
    pub fn a_m(&self) -> f64 {
        self.test.as_ref().map(|t| t.a).unwrap_or(f64::NAN)
    }
    /// Test targets (Fmax, Fmin, ΔK) of the current cycle.
    pub fn targets(&self) -> Option<(f64, f64, f64)> {
        self.test.as_ref().map(|t| t.t)
    }
    pub fn samples_per_cycle(&self) -> usize {
        self.test.as_ref().map(|t| t.n).unwrap_or(0)
    }
    pub fn frequency_hz(&self) -> f64 {
        self.test.as_ref().map(|t| t.cfg.frequency_hz).unwrap_or(f64::NAN)
    }
    pub fn demod_gains(&self) -> Option<DemodGains> {
        self.test.as_ref().and_then(|t| t.gains)
    }
    pub fn velocity_gain(&self) -> f64 {
        self.test.as_ref().map(|t| t.velocity_gain).unwrap_or(f64::NAN)
    }
    pub fn reference_m(&self) -> f64 {
        self.pos.r
    }
    pub fn protecting(&self) -> bool {
        self.state == State::Position && self.pos.protecting
    }
    pub fn position_gains(&self) -> PositionGains {
        self.pos.g
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::tests::table_b1;
    use crate::machine::Machine;

    fn plant_for(cfg: &TestConfig) -> Machine {
        let mut p = cfg.params.clone();
        p.specimen_stiffness_n_m = cfg.specimen.stiffness(cfg.a0_m, &cfg.material).unwrap();
        Machine::new(p).unwrap().with_rtol(cfg.rtol).unwrap()
    }

    #[test]
    fn per_period_demod_holds_two_percent_like_the_engine() {
        let cfg = table_b1(10.0, 500.0, 0.35, 30.0);
        let mut c = Cyclic::new(500.0, PositionGains::default()).unwrap();
        let mut m = plant_for(&cfg);
        let mut o = m.outputs();
        c.start_test(&cfg, o.f).unwrap();
        let mut worst: f64 = 0.0;
        for _ in 0..(300 * 50) {
            let u = c.step(o.f, o.y).unwrap();
            o = m.step(u, 1.0 / 500.0).unwrap();
            if let Some(r) = c.last {
                if !r.starting && r.cycle > 40 {
                    worst = worst.max(r.peak_err_pct.abs()).max(r.df_err_pct.abs());
                }
            }
        }
        assert_eq!(c.state, State::Running);
        assert!(c.cycle() >= 299, "cycles {}", c.cycle());
        assert!(worst < 2.0, "worst error {worst} %");
        assert!(c.a_m() > cfg.a0_m, "the crack grows from the measured peaks");
    }

    #[test]
    fn hold_freezes_at_mean_and_stop_ends_at_null() {
        let cfg = table_b1(10.0, 500.0, 0.35, 1.0);
        let mut c = Cyclic::new(500.0, PositionGains::default()).unwrap();
        let mut m = plant_for(&cfg);
        let mut o = m.outputs();
        c.start_test(&cfg, o.f).unwrap();
        let mut run = |c: &mut Cyclic, n: usize, o: &mut crate::machine::Outputs| {
            let (mut lo, mut hi) = (f64::MAX, f64::MIN);
            for _ in 0..n {
                let u = c.step(o.f, o.y).unwrap();
                *o = m.step(u, 1.0 / 500.0).unwrap();
                lo = lo.min(o.f);
                hi = hi.max(o.f);
            }
            (lo, hi)
        };
        run(&mut c, 50 * 40, &mut o);
        let n0 = c.cycle();
        c.hold().unwrap();
        run(&mut c, 50 * 3, &mut o);
        let (lo, hi) = run(&mut c, 50 * 3, &mut o);
        let (fmax, fmin, _) = c.targets().unwrap();
        assert!(hi - lo < 0.05 * (fmax - fmin), "held range {}", hi - lo);
        assert!((0.5 * (hi + lo) - 0.5 * (fmax + fmin)).abs() < 0.05 * (fmax - fmin));
        assert_eq!(c.cycle(), n0 + 1, "held cycles are not counted");
        c.resume().unwrap();
        run(&mut c, 50 * 30, &mut o);
        assert!(c.cycle() > n0 + 25);
        c.stop();
        run(&mut c, 50 * 6, &mut o);
        assert_eq!(c.state, State::Stopped);
        assert!(c.u_null.abs() < 0.5);
    }

    #[test]
    fn position_mode_moves_and_protects_the_specimen() {
        let p = crate::params::Params { specimen_stiffness_n_m: 1.0e8, ..Default::default() };
        let mut m = Machine::new(p).unwrap();
        let g = PositionGains { protect_force_n: 2000.0, ..PositionGains::default() };
        let mut c = Cyclic::new(500.0, g).unwrap();
        let mut o = m.outputs();
        c.position(o.y, 0.0);
        assert!(c.jog(1.0).is_err(), "jog beyond the speed limit is refused");
        c.move_to(o.y + 1e-3).unwrap();
        let mut fmax: f64 = 0.0;
        for _ in 0..1500 {
            let u = c.step(o.f, o.y).unwrap();
            o = m.step(u, 1.0 / 500.0).unwrap();
            fmax = fmax.max(o.f);
        }
        // 1 mm into a 1e8 N/m specimen would be 100 kN: protect holds it near 2 kN
        assert!(c.protecting());
        assert!(fmax < 4000.0 && o.f > 1000.0, "fmax {fmax}, f {}", o.f);
        c.move_to(0.1).unwrap();
        for _ in 0..1500 {
            let u = c.step(o.f, o.y).unwrap();
            o = m.step(u, 1.0 / 500.0).unwrap();
        }
        assert!((o.y - 0.1).abs() < 2e-5 && o.f.abs() < 2000.0, "y {} f {}", o.y, o.f);
    }
}
