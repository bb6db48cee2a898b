//! The per-period controller of the real-time loop: one call per control period turns the
//! measured force and position into a valve command. A force test is the engine's cycle machine
//! (`engine::cycle`: waveform phase, smooth start, compensation, per-cycle peak/valley, crack
//! bookkeeping, hold/resume/stop ramps), the same code the simulator runs; a position mode
//! (install, jog, move) limits the specimen force (specimen protect). The state machine is here
//! so that the loop in Python only moves numbers.
pub use crate::engine::CycleResult;
use crate::control::DemodGains;
use crate::engine::{CycleMachine, EndReason, Stage, TestConfig};
use crate::error::{Error, Result};

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

/// A loaded force test: its config and the cycle machine.
#[derive(Debug, Clone)]
struct ForceTest {
    cfg: TestConfig,
    cm: CycleMachine,
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
    /// Set the largest |command| from now on [V], ≥ 0 (a trip lowers it to the safe value).
    pub fn set_command_limit_v(&mut self, v: f64) -> Result<()> {
        if !(v >= 0.0) {
            return Err(Error::Parameter { field: "command_limit_v".into(), value: v, allowed: "[0, inf] V".into() });
        }
        self.command_limit_v = v;
        Ok(())
    }

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
        let n = (self.rate_hz / cfg.frequency_hz).round().max(1.0);
        cfg.frequency_hz = self.rate_hz / n;
        cfg.control_rate_hz = self.rate_hz;
        cfg.validate()?;
        let cm = CycleMachine::new(&cfg, self.rate_hz, f0)?;
        self.test = Some(ForceTest { cfg, cm });
        self.end_reason = None;
        self.results = 0;
        self.last = None;
        self.state = State::Starting;
        Ok(())
    }

    /// Freeze at the mean: the amplitude ramps to zero over one cycle; cycles stop counting.
    pub fn hold(&mut self) -> Result<()> {
        let held = matches!(self.state, State::Starting | State::Running | State::Holding) && self.test.as_mut().is_some_and(|t| t.cm.hold());
        if !held {
            return Err(Error::Input(format!("hold needs a running test (state is {})", self.state.name())));
        }
        self.sync_state();
        Ok(())
    }

    /// Ramp the amplitude back in (over the start's amplitude cycles) after `hold`.
    pub fn resume(&mut self) -> Result<()> {
        let resumed = self.state == State::Holding && self.test.as_mut().is_some_and(|t| t.cm.resume(&t.cfg));
        if !resumed {
            return Err(Error::Input(format!("resume needs a held test (state is {})", self.state.name())));
        }
        self.sync_state();
        Ok(())
    }

    /// Ramp the amplitude to zero at the mean (over the spec's stop cycles), then valve null.
    pub fn stop(&mut self) {
        match self.state {
            State::Starting | State::Running | State::Holding => {
                if let Some(t) = &mut self.test {
                    t.cm.stop(&t.cfg);
                }
                self.sync_state();
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
        let (u, closed) = t.cm.step(&t.cfg, f, y)?;
        if let Some(r) = closed.filter(|r| r.counted) {
            self.last = Some(r);
            self.results += 1;
        }
        self.sync_state();
        Ok(u)
    }

    /// The controller's state from the cycle machine's stage (and its end, once there is one).
    fn sync_state(&mut self) {
        let Some(t) = &self.test else { return };
        self.end_reason = t.cm.end;
        self.state = match t.cm.stage {
            Stage::Starting => State::Starting,
            Stage::Running => State::Running,
            Stage::Holding => State::Holding,
            Stage::Stopping => State::Stopping,
            Stage::Stopped => {
                self.u_null = t.cm.u_null;
                State::Stopped
            }
        };
    }

    pub fn cycle(&self) -> u64 {
        self.test.as_ref().map(|t| t.cm.cycle).unwrap_or(0)
    }
    pub fn a_m(&self) -> f64 {
        self.test.as_ref().map(|t| t.cm.a).unwrap_or(f64::NAN)
    }
    /// Test targets (Fmax, Fmin, ΔK) of the current cycle.
    pub fn targets(&self) -> Option<(f64, f64, f64)> {
        self.test.as_ref().map(|t| t.cm.targets())
    }
    pub fn samples_per_cycle(&self) -> usize {
        self.test.as_ref().map(|t| t.cm.n).unwrap_or(0)
    }
    pub fn frequency_hz(&self) -> f64 {
        self.test.as_ref().map(|t| t.cfg.frequency_hz).unwrap_or(f64::NAN)
    }
    pub fn demod_gains(&self) -> Option<DemodGains> {
        self.test.as_ref().and_then(|t| t.cm.gains)
    }
    pub fn velocity_gain(&self) -> f64 {
        self.test.as_ref().map(|t| t.cm.velocity_gain).unwrap_or(f64::NAN)
    }
    /// The force test's cycle machine (convergence, compensation), if one is loaded.
    pub fn machine(&self) -> Option<&CycleMachine> {
        self.test.as_ref().map(|t| &t.cm)
    }
    pub fn reference_m(&self) -> f64 {
        self.pos.r
    }
    /// The force setpoint of the next control period [N] (NaN outside a force test): read
    /// before `step`, the setpoint at the time of the force that `step` is given.
    pub fn force_ref_n(&self) -> f64 {
        match (self.state, &self.test) {
            (State::Starting | State::Running | State::Holding | State::Stopping, Some(t)) => t.cm.f_ref,
            _ => f64::NAN,
        }
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
                if r.judged && r.cycle > 40 {
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
