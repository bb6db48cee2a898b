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
    /// working (high) supply pressure [Pa]; 0 = no hydraulic start-up here (the supply is
    /// managed elsewhere and is at its working pressure whenever the amplifier is on)
    pub supply_pa: f64,
    /// tank (return) pressure [Pa]
    pub tank_pa: f64,
    /// the larger piston area [m²] and the moving mass's weight [N]: what the start-up
    /// pressure can push on the specimen
    pub area_m2: f64,
    pub weight_n: f64,
    /// start-up supply pressure [Pa]; 0 = chosen so that the actuator cannot push the specimen
    /// past the protect force (see `low_supply_pa`)
    pub low_supply_pa: f64,
    /// start-up: time at the low pressure while the null is learned, then the ramp to the
    /// working pressure [s]
    pub startup_low_s: f64,
    pub startup_ramp_s: f64,
}

/// Start-up pressure as a share of the working pressure above tank: the range `low_supply_pa`
/// picks from, and its value without specimen protect.
const LOW_SUPPLY_SHARE: (f64, f64, f64) = (0.02, 0.15, 0.10);
/// Start-up: how much faster the force target and the null integrator act than in motion.
const STARTUP_GAIN: f64 = 3.0;
/// Start-up: shortest and longest time at the working pressure while the piston's weight is
/// taken off the specimen [s], and the force it ends at, as a share of the protect force (or of
/// the weight without protect).
const UNLOAD_S: (f64, f64) = (0.2, 1.0);
const UNLOAD_TOLERANCE: f64 = 0.03;
/// The slowest the start-up lets the valve's flow gain fall (√ of the pressure share).
const MIN_FLOW_SCALE: f64 = 0.05;

impl Default for PositionGains {
    fn default() -> Self {
        PositionGains { bandwidth_per_s: 20.0, velocity_gain_m_s_per_v: -0.07, integral_time_s: 0.3, max_speed_m_s: 0.02, protect_force_n: 0.0, protect_stiffness_n_m: 1.0e8, y_min_m: 0.005, y_max_m: 0.195, u_max_v: 10.0,
            supply_pa: 0.0, tank_pa: 0.0, area_m2: 0.0, weight_n: 0.0, low_supply_pa: 0.0, startup_low_s: 1.0, startup_ramp_s: 1.0 }
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
        pos("startup_low_s", self.startup_low_s)?;
        pos("startup_ramp_s", self.startup_ramp_s)?;
        let nonneg = |field: &str, v: f64| if v.is_finite() && v >= 0.0 { Ok(()) } else { Err(Error::Parameter { field: format!("position.{field}"), value: v, allowed: "[0, inf)".into() }) };
        nonneg("supply_pa", self.supply_pa)?;
        nonneg("tank_pa", self.tank_pa)?;
        nonneg("area_m2", self.area_m2)?;
        nonneg("low_supply_pa", self.low_supply_pa)?;
        if !self.weight_n.is_finite() {
            return Err(Error::Parameter { field: "position.weight_n".into(), value: self.weight_n, allowed: "finite".into() });
        }
        if self.supply_pa > 0.0 && !(self.tank_pa < self.supply_pa) {
            return Err(Error::Parameter { field: "position.tank_pa".into(), value: self.tank_pa, allowed: format!("< supply_pa = {}", self.supply_pa) });
        }
        if self.supply_pa > 0.0 && self.low_supply_pa > self.supply_pa {
            return Err(Error::Parameter { field: "position.low_supply_pa".into(), value: self.low_supply_pa, allowed: format!("[0, supply_pa = {}] Pa (0 = from the protect force)", self.supply_pa) });
        }
        if !(self.y_min_m < self.y_max_m) {
            return Err(Error::Parameter { field: "position.y_min_m".into(), value: self.y_min_m, allowed: format!("< y_max_m = {}", self.y_max_m) });
        }
        Ok(())
    }

    /// The specimen force while the start-up learns the null [N]: the piston's weight, which
    /// the specimen carries with the chambers at equal pressure, whatever the supply — so the
    /// integrator learns the spool's true null (no pressure difference), not the offset that
    /// holds the weight at the low pressure and is wrong at the working one. Kept inside 80 %
    /// of the protect force.
    pub fn rest_force_n(&self) -> f64 {
        let w = -self.weight_n;
        if self.protect_force_n > 0.0 { w.clamp(-0.8 * self.protect_force_n, 0.8 * self.protect_force_n) } else { w }
    }

    /// The start-up supply pressure [Pa]: `low_supply_pa` when given, else the pressure at which
    /// the actuator's largest force (area × pressure above tank, plus the moving weight) stays
    /// at 80 % of the protect force, kept within 2–15 % of the working pressure above tank
    /// (10 % without protect or without the area).
    pub fn low_supply_pa(&self) -> f64 {
        let span = self.supply_pa - self.tank_pa;
        if self.low_supply_pa > 0.0 {
            return self.low_supply_pa.clamp(self.tank_pa, self.supply_pa);
        }
        let (lo, hi, dflt) = LOW_SUPPLY_SHARE;
        let share = if self.protect_force_n > 0.0 && self.area_m2 > 0.0 && span > 0.0 {
            (0.8 * (self.protect_force_n - self.weight_n.abs()) / (self.area_m2 * span)).clamp(lo, hi)
        } else {
            dflt
        };
        self.tank_pa + share * span
    }
}

/// Position control with velocity feed-through, a null integrator and specimen protect.
///
/// Specimen protect (force rises with y: the specimen hangs above the piston) limits the
/// commanded speed to the force headroom, `bw·(P − f)/k` upwards and `−bw·(P + f)/k` downwards
/// (P the protect force, k `protect_stiffness_n_m`): the force approaches ±P without passing it,
/// and beyond it the piston backs off in proportion to the excess. The reference is kept where
/// that speed puts it. The integrator always integrates the command actually applied, so under
/// protect it learns the null that holds the force at the limit: its state can never hold the
/// force past P (it was frozen before, and a wrong null then held the specimen far beyond P).
///
/// Hydraulic start-up (from the amplifier off, with `supply_pa` known): the supply comes up at
/// `low_supply_pa()` for `startup_low_s` while the loop learns the valve's null, the specimen
/// carrying only the piston's weight (`rest_force_n`: the reference follows the force to it), then
/// ramps geometrically to the working pressure over `startup_ramp_s`, and at the working pressure
/// the reference takes the weight off the specimen (its force to zero) before it holds where the
/// piston is. The loop's gain is scaled by √(pressure share), as the valve's flow is, and the
/// force target and the integrator act `STARTUP_GAIN` times faster. Motion commands wait.
#[derive(Debug, Clone)]
struct PositionLoop {
    g: PositionGains,
    r: f64,
    rate: f64,
    target: Option<f64>,
    integ: f64,
    protecting: bool,
    /// time into the hydraulic start-up [s], while it lasts
    startup: Option<f64>,
    /// the supply pressure this loop asks for now [Pa]
    supply_pa: f64,
}

impl PositionLoop {
    fn new(g: PositionGains) -> Self {
        PositionLoop { g, r: 0.0, rate: 0.0, target: None, integ: 0.0, protecting: false, startup: None, supply_pa: g.supply_pa }
    }

    /// Advance the start-up clock; returns the valve's flow scale (1 at the working pressure).
    fn startup_step(&mut self, f: f64, y: f64, dt: f64) -> f64 {
        let g = &self.g;
        let Some(t) = self.startup.as_mut() else { return 1.0 };
        *t += dt;
        let t = *t;
        let (lo, hi) = (g.low_supply_pa() - g.tank_pa, g.supply_pa - g.tank_pa);
        let gauge = if t < g.startup_low_s {
            lo
        } else if t < g.startup_low_s + g.startup_ramp_s && lo > 0.0 {
            lo * (hi / lo).powf((t - g.startup_low_s) / g.startup_ramp_s)
        } else {
            // unloading at the working pressure: done once the force is near zero (or after the
            // longest unload); the reference then holds the position read now
            let unloaded = f.is_finite() && f.abs() <= UNLOAD_TOLERANCE * g.protect_force_n.max(g.weight_n.abs()).max(1.0);
            let t_unload = t - g.startup_low_s - g.startup_ramp_s;
            if (t_unload >= UNLOAD_S.0 && unloaded) || t_unload >= UNLOAD_S.1 {
                if y.is_finite() {
                    self.r = y;
                }
                self.startup = None;
            }
            hi
        };
        self.supply_pa = g.tank_pa + gauge;
        if hi > 0.0 { (gauge / hi).sqrt().max(MIN_FLOW_SCALE) } else { 1.0 }
    }

    fn step(&mut self, f: f64, y: f64, dt: f64) -> f64 {
        let scale = self.startup_step(f, y, dt);
        let g = &self.g;
        let vmax = g.max_speed_m_s;
        let kf = g.bandwidth_per_s / g.protect_stiffness_n_m;
        if let Some(t) = self.startup {
            // the reference follows the force to its start-up target; motion commands wait
            let target = if t < g.startup_low_s + g.startup_ramp_s { g.rest_force_n() } else { 0.0 };
            if f.is_finite() {
                self.r += (STARTUP_GAIN * kf * (target - f)).clamp(-vmax, vmax) * dt;
            }
        } else {
            match self.target {
                Some(t) => self.r += (t - self.r).clamp(-vmax * dt, vmax * dt),
                None => self.r += self.rate * dt,
            }
        }
        self.r = self.r.clamp(g.y_min_m, g.y_max_m);
        if !y.is_finite() {
            return 0.0;
        }
        let bw = g.bandwidth_per_s;
        let mut v = (bw * (self.r - y)).clamp(-vmax, vmax);
        self.protecting = false;
        if g.protect_force_n > 0.0 && f.is_finite() {
            let (up, down) = (kf * (g.protect_force_n - f), -kf * (g.protect_force_n + f));
            if v > up {
                v = up;
                self.r = self.r.min(y + up / bw);
                self.protecting = true;
            } else if v < down {
                v = down;
                self.r = self.r.max(y + down / bw);
                self.protecting = true;
            }
        }
        let u_p = v / (g.velocity_gain_m_s_per_v * scale);
        let ti = if self.startup.is_some() { g.integral_time_s / STARTUP_GAIN } else { g.integral_time_s };
        self.integ = (self.integ + dt / ti * u_p).clamp(-1.0, 1.0);
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
            pos: PositionLoop::new(position),
            test: None, command_limit_v: f64::INFINITY, u_last: 0.0, u_null: 0.0, end_reason: None, results: 0, last: None,
        })
    }

    /// Switch to position control holding position `y` [m]. From a powered state it is bumpless
    /// from the command `u` [V]; from the amplifier off (idle or stopped) with a known supply
    /// (`PositionGains::supply_pa`) it starts the hydraulics at low pressure from the last
    /// learned null (see `PositionLoop`), and `u` is not used.
    pub fn position(&mut self, y: f64, u: f64) {
        let cold = matches!(self.state, State::Idle | State::Stopped);
        self.pos.r = if y.is_finite() { y } else { self.pos.r };
        self.pos.rate = 0.0;
        self.pos.target = None;
        if cold && self.pos.g.supply_pa > 0.0 {
            self.pos.integ = if self.u_null.is_finite() { self.u_null.clamp(-1.0, 1.0) } else { 0.0 };
            self.pos.startup = Some(0.0);
            self.pos.supply_pa = self.pos.g.low_supply_pa();
        } else {
            self.pos.integ = if u.is_finite() { u.clamp(-1.0, 1.0) } else { 0.0 };
            if self.state != State::Position {
                self.pos.startup = None;
                self.pos.supply_pa = self.pos.g.supply_pa;
            }
        }
        self.test = None;
        self.state = State::Position;
    }

    /// True while position control's hydraulic start-up runs (low pressure, then the ramp).
    pub fn starting_up(&self) -> bool {
        self.state == State::Position && self.pos.startup.is_some()
    }

    /// The supply pressure the controller asks for now [Pa]: the start-up's while it runs, else
    /// the working pressure (0 when `PositionGains::supply_pa` is not given).
    pub fn supply_demand_pa(&self) -> f64 {
        if self.starting_up() { self.pos.supply_pa } else { self.pos.g.supply_pa }
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
                self.pos.startup = None;
                self.state = State::Stopped;
            }
        }
    }

    /// No control: command 0 V (the loop disables the amplifier).
    pub fn idle(&mut self) {
        if self.state == State::Position {
            self.u_null = self.pos.integ; // the null learned: the next start-up starts from it
        }
        self.state = State::Idle;
    }

    /// One control period: measured force `f` [N] and position `y` [m] in, valve command [V] out.
    pub fn step(&mut self, f: f64, y: f64) -> Result<f64> {
        self.step_measured(f, y, f64::NAN)
    }

    /// `step` with the crack measurement's channel `m` (clip-gauge opening [m] or potential drop
    /// [V], NaN when absent): a force test with a `[measurement]` reads its crack from it.
    pub fn step_measured(&mut self, f: f64, y: f64, m: f64) -> Result<f64> {
        let u = match self.state {
            State::Idle => 0.0,
            State::Stopped => self.u_null,
            State::Position => self.pos.step(f, y, self.dt),
            _ => self.test_step(f, y, m)?,
        };
        let u = if u.is_finite() { u.clamp(-self.command_limit_v, self.command_limit_v) } else { 0.0 };
        self.u_last = u;
        Ok(u)
    }

    fn test_step(&mut self, f: f64, y: f64, m: f64) -> Result<f64> {
        let t = self.test.as_mut().expect("a force state has a test");
        let (u, closed) = t.cm.step_measured(&t.cfg, f, y, m)?;
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
    /// The growth law's crack beside the measured one [m].
    pub fn a_law_m(&self) -> f64 {
        self.test.as_ref().map(|t| t.cm.a_law).unwrap_or(f64::NAN)
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

    /// The plant data the start-up needs, from the rig's parameters.
    fn startup_gains(p: &crate::params::Params, protect_n: f64) -> PositionGains {
        PositionGains {
            protect_force_n: protect_n, supply_pa: p.supply_pressure_pa, tank_pa: p.tank_pressure_pa,
            area_m2: p.area_a_m2.max(p.area_b_m2), weight_n: p.moving_mass_kg * p.gravity_m_s2, ..PositionGains::default()
        }
    }

    /// Power-on to working pressure, then jogs and moves into and out of the gripped specimen:
    /// the specimen force of every period, and the supply the controller asked for.
    fn protect_run(geometry: crate::specimen::Geometry, w: f64, b: f64, a0: f64, material: crate::specimen::Material) -> (f64, Cyclic, f64) {
        use crate::rig::{CrackingSpecimen, RigPlant};
        let protect = 2000.0;
        let p = crate::params::Params::default();
        let sp = crate::specimen::Specimen::new(geometry, w, b).unwrap();
        let spec = CrackingSpecimen::new(sp, material, crate::crack::Law::Paris { c: 1e-30, m: 3.0 }, a0, 50.0).unwrap();
        let mut plant = RigPlant::new(p.clone(), Some(spec)).unwrap();
        let dt = 1.0 / 500.0;
        let q = |y: f64| (y / 5e-6).round() * 5e-6; // the transducer's 5 µm steps
        // power-on: supply unloaded, amplifier off (the spool centres), the weight settles
        plant.set_supply_setpoint_pa(0.0).unwrap();
        let mut worst: f64 = 0.0;
        let mut o = plant.machine.outputs();
        for _ in 0..250 {
            o = plant.step(-p.valve_null_bias_v, dt).unwrap();
            worst = worst.max(o.f.abs());
        }
        let mut c = Cyclic::new(500.0, startup_gains(&p, protect)).unwrap();
        c.position(q(o.y), 0.0);
        assert!(c.starting_up());
        let low = c.supply_demand_pa();
        let mut run = |c: &mut Cyclic, n: usize, o: &mut crate::machine::Outputs, worst: &mut f64| {
            for _ in 0..n {
                plant.set_supply_setpoint_pa(c.supply_demand_pa()).unwrap();
                let u = c.step(o.f, q(o.y)).unwrap();
                *o = plant.step(u, dt).unwrap();
                *worst = worst.max(o.f.abs());
            }
        };
        let g = c.position_gains();
        let n = ((g.startup_low_s + g.startup_ramp_s + UNLOAD_S.1) / dt) as usize + 2;
        for _ in 0..n {
            if !c.starting_up() {
                break;
            }
            run(&mut c, 1, &mut o, &mut worst); // the start-up: low pressure, ramp, unload
        }
        assert!(!c.starting_up() && (c.supply_demand_pa() - p.supply_pressure_pa).abs() < 1.0);
        assert!((o.p_s - p.supply_pressure_pa).abs() < 0.05 * p.supply_pressure_pa, "p_s {}", o.p_s);
        assert!(o.f.abs() < 0.1 * protect, "the specimen is unloaded at working pressure: f {}", o.f);
        assert!((c.pos.integ + p.valve_null_bias_v).abs() < 0.02, "the null is learned: {} V", c.pos.integ);
        run(&mut c, 250, &mut o, &mut worst);
        let y0 = o.y;
        c.jog(0.01).unwrap(); // into tension, far faster than the specimen allows
        run(&mut c, 1000, &mut o, &mut worst);
        assert!(c.protecting() && o.f > 0.8 * protect, "jog up ends at the protect level: f {}", o.f);
        c.jog(-0.01).unwrap();
        run(&mut c, 1500, &mut o, &mut worst);
        assert!(o.f < -0.8 * protect, "jog down ends at the protect level: f {}", o.f);
        c.jog(0.0).unwrap();
        c.move_to(y0 + 1e-3).unwrap();
        run(&mut c, 1500, &mut o, &mut worst);
        c.move_to(y0).unwrap();
        run(&mut c, 1500, &mut o, &mut worst);
        (worst, c, low)
    }

    #[test]
    fn start_up_and_motion_keep_a_gripped_ct_and_mt_inside_specimen_protect() {
        use crate::specimen::{Geometry, Material};
        // examples/ct_constant_force.toml and examples/virkler_mt.toml
        let ct = protect_run(Geometry::CT, 0.0508, 0.00635, 0.0152, Material::default());
        let al = Material { youngs_modulus_pa: 73e9, poisson_ratio: 0.33, yield_strength_pa: 345e6, fracture_toughness_pa_sqrt_m: 100e6 };
        let mt = protect_run(Geometry::MT, 0.1524, 0.00254, 0.009, al);
        for (name, (worst, c, low)) in [("C(T)", ct), ("M(T)", mt)] {
            eprintln!("{name}: peak |f| {worst:.0} N from power-on through start-up, jogs and moves (protect 2000 N)");
            assert!(worst <= 1.05 * 2000.0, "{name}: peak |f| {worst} N past protect + 5 %");
            assert!(low < 0.1 * c.position_gains().supply_pa, "{name}: start-up supply {low} Pa");
            assert_eq!(c.state, State::Position);
        }
    }

    #[test]
    fn low_supply_follows_the_protect_force() {
        let p = crate::params::Params::default();
        let g = startup_gains(&p, 2000.0);
        let low = g.low_supply_pa();
        let fmax = g.area_m2 * (low - g.tank_pa) + g.weight_n;
        assert!(fmax < 2000.0, "largest start-up force {fmax} N");
        let off = PositionGains { protect_force_n: 0.0, ..g };
        assert!((off.low_supply_pa() - 0.1 * p.supply_pressure_pa).abs() < 1.0);
        let set = PositionGains { low_supply_pa: 3e6, ..g };
        assert_eq!(set.low_supply_pa(), 3e6);
        assert!(PositionGains { low_supply_pa: 30e6, ..g }.validate().is_err());
    }
}
