//! Whole simulations: a command array played open loop, or a reference tracked in closed loop.
use crate::control::Controller;
use crate::error::{Error, Result};
use crate::machine::{Machine, Outputs, NX, SPOOL};
use crate::solver::Stats;

/// Sampled signals of a run; sample k is read at t[k] = k*dt, before u[k] is applied.
#[derive(Debug, Clone, Default)]
pub struct Trace {
    pub t: Vec<f64>,
    pub u: Vec<f64>,
    pub y: Vec<f64>,
    pub v: Vec<f64>,
    pub p_a: Vec<f64>,
    pub p_b: Vec<f64>,
    pub p_s: Vec<f64>,
    pub f: Vec<f64>,
    pub stats: Stats,
}

impl Trace {
    fn with_capacity(n: usize) -> Self {
        let v = || Vec::with_capacity(n);
        Trace { t: v(), u: v(), y: v(), v: v(), p_a: v(), p_b: v(), p_s: v(), f: v(), stats: Stats::default() }
    }
    fn push(&mut self, t: f64, u: f64, o: &Outputs) {
        self.t.push(t);
        self.u.push(u);
        self.y.push(o.y);
        self.v.push(o.v);
        self.p_a.push(o.p_a);
        self.p_b.push(o.p_b);
        self.p_s.push(o.p_s);
        self.f.push(o.f);
    }
}

fn check_dt(dt: f64) -> Result<()> {
    if dt.is_finite() && dt > 0.0 {
        Ok(())
    } else {
        Err(Error::Input(format!("sample period dt = {dt} s must be > 0")))
    }
}

/// Play the command samples `u` [V], each held for `dt` [s].
/// Time derivative of state `x` (NX values) of machine `m`'s plant under held command `u` [V],
/// for external integrators: the spool is the command's target when the valve has no spool
/// dynamics (as the integrator holds it).
pub fn derivatives(m: &Machine, x: &[f64], u: f64) -> Result<[f64; NX]> {
    let mut arr: [f64; NX] = x.try_into().map_err(|_| Error::Input(format!("state needs {NX} values, got {}", x.len())))?;
    let plant = &m.plant;
    let target = plant.spool_target(u, &mut 0.0);
    if !plant.spool_has_dynamics() {
        arr[SPOOL] = target;
    }
    let mut dx = [0.0; NX];
    plant.derivatives(&arr, target, &mut dx);
    Ok(dx)
}

pub fn simulate_open_loop(m: &mut Machine, u: &[f64], dt: f64) -> Result<Trace> {
    check_dt(dt)?;
    if let Some(k) = u.iter().position(|x| !x.is_finite()) {
        return Err(Error::Input(format!("command sample {k} is {}", u[k])));
    }
    let mut tr = Trace::with_capacity(u.len());
    let t0 = m.t;
    for (k, &uk) in u.iter().enumerate() {
        tr.push(t0 + k as f64 * dt, uk, &m.outputs());
        m.step(uk, dt)?;
    }
    tr.stats = m.stats();
    Ok(tr)
}

/// Track `reference` (metres or newtons, per the controller) sampled at `dt`.
pub fn simulate_closed_loop(m: &mut Machine, reference: &[f64], dt: f64, ctrl: &Controller) -> Result<Trace> {
    check_dt(dt)?;
    ctrl.validate()?;
    if let Some(k) = reference.iter().position(|x| !x.is_finite()) {
        return Err(Error::Input(format!("reference sample {k} is {}", reference[k])));
    }
    let n = reference.len();
    let mut tr = Trace::with_capacity(n);
    let t0 = m.t;
    for k in 0..n {
        let o = m.outputs();
        let r_next = reference[(k + 1).min(n - 1)];
        let uk = ctrl.command(reference[k], r_next, dt, &o);
        tr.push(t0 + k as f64 * dt, uk, &o);
        m.step(uk, dt)?;
    }
    tr.stats = m.stats();
    Ok(tr)
}
