//! A reduced model of a machine's closed displacement loop, for records that hold only the
//! outer loop (position command, measured position, load force) and no valve command or
//! pressures — a vendor controller whose inner loop is unknown.
//!
//! A position loop around an integrating actuator (valve flow → piston velocity) behaves, below
//! the oil-column resonance, like
//!
//! ```text
//!   e  = k·y_ref(t − τ) + y_0 − y                  command error after transport delay τ
//!   ẏ  = ω·(1 + α·sgn(e))·s − c·f − v_c·sig(s)     velocity: loop gain ω, direction asymmetry α,
//!                                                    load sensitivity c (flow falls with load),
//!                                                    Coulomb velocity loss v_c
//!   ṡ  = ω_v·(e − s)        (s = e when ω_v = 0)    valve lag (first order)
//! ```
//!
//! ω = k_p·k_v is the loop bandwidth [rad/s]; α ≠ 0 when extension and retraction move at different
//! speeds for the same error (unequal valve gains or areas); c·f is the velocity lost to the load
//! pressure f/A through the valve's flow–pressure coefficient (`load_pressure_feedback` in
//! EFFECTS.md), so a loaded actuator lags more; y_0 is the offset between command and transducer.
use crate::error::{Error, Result};

/// Parameters of the displacement-loop model (SI).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopParams {
    /// static gain from command to position k [-]
    pub gain: f64,
    /// loop bandwidth ω/(2π) [Hz]
    pub bandwidth_hz: f64,
    /// transport delay τ of the command [s]
    pub delay_s: f64,
    /// offset y_0 between command and measured position [m]
    pub offset_m: f64,
    /// load sensitivity c: velocity lost per newton of load [m/(s·N)]
    pub load_m_s_per_n: f64,
    /// direction asymmetry α of the velocity gain [-], |α| < 1
    pub asymmetry: f64,
    /// valve bandwidth ω_v/(2π) [Hz]; 0 = no valve lag
    pub valve_bandwidth_hz: f64,
    /// Coulomb velocity loss v_c [m/s]
    pub friction_m_s: f64,
}

/// Smoothing of the sign in the Coulomb term [m of error]: below the position noise of any
/// practical transducer, and wide enough that RK4 at half the sample period stays stable.
pub const SIG_EPS_M: f64 = 1e-5;

impl Default for LoopParams {
    fn default() -> Self {
        LoopParams { gain: 1.0, bandwidth_hz: 5.0, delay_s: 0.0, offset_m: 0.0, load_m_s_per_n: 0.0, asymmetry: 0.0, valve_bandwidth_hz: 0.0, friction_m_s: 0.0 }
    }
}

impl LoopParams {
    pub fn validate(&self) -> Result<()> {
        let check = |field: &str, value: f64, ok: bool, allowed: &str| {
            if ok && value.is_finite() {
                Ok(())
            } else {
                Err(Error::Parameter { field: field.into(), value, allowed: allowed.into() })
            }
        };
        check("gain", self.gain, self.gain > 0.0, "> 0")?;
        check("bandwidth_hz", self.bandwidth_hz, self.bandwidth_hz > 0.0, "> 0")?;
        check("delay_s", self.delay_s, self.delay_s >= 0.0, "≥ 0")?;
        check("offset_m", self.offset_m, true, "finite")?;
        check("load_m_s_per_n", self.load_m_s_per_n, true, "finite")?;
        check("asymmetry", self.asymmetry, self.asymmetry.abs() < 1.0, "|α| < 1")?;
        check("valve_bandwidth_hz", self.valve_bandwidth_hz, self.valve_bandwidth_hz >= 0.0, "≥ 0 (0 = no valve lag)")?;
        check("friction_m_s", self.friction_m_s, self.friction_m_s >= 0.0, "≥ 0")
    }
}

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

/// Position [m] the model predicts at every sample, from the command `y_ref` [m] and the load
/// force `f` [N] sampled every `dt` [s], starting at rest on the command (y = k·y_ref[0] + y_0,
/// minus the static droop under the first load sample). Inputs vary linearly within a sample;
/// classic RK4 with `substeps` steps per sample (the loop poles sit far below 1/dt).
pub fn simulate(p: &LoopParams, y_ref: &[f64], f: &[f64], dt: f64) -> Result<Vec<f64>> {
    p.validate()?;
    if y_ref.len() != f.len() {
        return Err(Error::Input(format!("y_ref has {} samples but f has {}", y_ref.len(), f.len())));
    }
    if !(dt.is_finite() && dt > 0.0) {
        return Err(Error::Input(format!("sample period dt = {dt} s must be > 0")));
    }
    if let Some(k) = y_ref.iter().chain(f).position(|x| !x.is_finite()) {
        return Err(Error::Input(format!("input sample {} is not finite (fill dropped samples first)", k % y_ref.len().max(1))));
    }
    let n = y_ref.len();
    if n == 0 {
        return Ok(Vec::new());
    }
    let w = 2.0 * std::f64::consts::PI * p.bandwidth_hz;
    let wv = 2.0 * std::f64::consts::PI * p.valve_bandwidth_hz;
    let lag = p.delay_s / dt;
    let substeps = 2usize;
    let h = dt / substeps as f64;
    // state (y, s); s is the valve's view of the error (= e without valve lag)
    let rhs = |y: f64, s: f64, i: f64| -> (f64, f64) {
        let e = p.gain * at(y_ref, i - lag) + p.offset_m - y;
        let s_eff = if wv > 0.0 { s } else { e };
        let dy = w * (1.0 + p.asymmetry * s_eff.signum()) * s_eff - p.load_m_s_per_n * at(f, i) - p.friction_m_s * s_eff / (s_eff.abs() + SIG_EPS_M);
        let ds = if wv > 0.0 { wv * (e - s) } else { 0.0 };
        (dy, ds)
    };
    // start at the static equilibrium of the first sample: w·(1 ± α)·e0 = c·f0 (friction aside)
    let e0 = {
        let c = p.load_m_s_per_n * f[0];
        let g = w * (1.0 + p.asymmetry * c.signum());
        c / g
    };
    let mut y = p.gain * y_ref[0] + p.offset_m - e0;
    let mut s = e0;
    let mut out = Vec::with_capacity(n);
    for k in 0..n {
        out.push(y);
        for j in 0..substeps {
            let i = k as f64 + j as f64 / substeps as f64;
            let d = 0.5 / substeps as f64;
            let (k1y, k1s) = rhs(y, s, i);
            let (k2y, k2s) = rhs(y + 0.5 * h * k1y, s + 0.5 * h * k1s, i + d);
            let (k3y, k3s) = rhs(y + 0.5 * h * k2y, s + 0.5 * h * k2s, i + d);
            let (k4y, k4s) = rhs(y + h * k3y, s + h * k3s, i + 2.0 * d);
            y += h / 6.0 * (k1y + 2.0 * k2y + 2.0 * k3y + k4y);
            s += h / 6.0 * (k1s + 2.0 * k2s + 2.0 * k3s + k4s);
        }
        if !y.is_finite() {
            return Err(Error::Solver(format!("displacement-loop model diverged at sample {k}")));
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sine(n: usize, dt: f64, f_hz: f64, amp: f64) -> Vec<f64> {
        (0..n).map(|k| amp * (2.0 * std::f64::consts::PI * f_hz * k as f64 * dt).sin()).collect()
    }

    #[test]
    fn first_order_loop_has_its_bandwidth_amplitude() {
        // at f = bandwidth a first-order loop passes 1/√2 of the amplitude
        let dt = 1e-3;
        let p = LoopParams { bandwidth_hz: 5.0, ..Default::default() };
        let r = sine(4000, dt, 5.0, 1e-3);
        let y = simulate(&p, &r, &vec![0.0; r.len()], dt).unwrap();
        let peak = y[2000..].iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!((peak / 1e-3 - 0.5f64.sqrt()).abs() < 0.01, "peak ratio {}", peak / 1e-3);
    }

    #[test]
    fn delay_shifts_the_response() {
        let dt = 1e-3;
        let mut r = vec![0.0; 400];
        for x in r.iter_mut().skip(100) {
            *x = 1e-3;
        }
        let p = LoopParams { bandwidth_hz: 20.0, delay_s: 0.01, ..Default::default() };
        let y = simulate(&p, &r, &vec![0.0; r.len()], dt).unwrap();
        assert!(y[109].abs() < 1e-9, "moved before the delay: {}", y[109]);
        assert!(y[115] > 1e-5);
    }

    #[test]
    fn load_causes_static_droop_and_asymmetry_a_mean_shift() {
        let dt = 1e-3;
        let n = 3000;
        let p = LoopParams { bandwidth_hz: 5.0, load_m_s_per_n: 1e-6, ..Default::default() };
        let y = simulate(&p, &vec![0.0; n], &vec![1000.0; n], dt).unwrap();
        let droop = 1e-6 * 1000.0 / (2.0 * std::f64::consts::PI * 5.0);
        assert!((y[n - 1] + droop).abs() < 1e-9, "{} vs {}", y[n - 1], -droop);
        let r = sine(6000, dt, 8.0, 2e-3);
        let pa = LoopParams { bandwidth_hz: 5.0, asymmetry: 0.1, ..Default::default() };
        let ya = simulate(&pa, &r, &vec![0.0; r.len()], dt).unwrap();
        let mean: f64 = ya[2000..].iter().sum::<f64>() / 4000.0;
        assert!(mean.abs() > 1e-5, "asymmetry should shift the mean, got {mean}");
    }

    #[test]
    fn bad_input_is_refused() {
        let p = LoopParams { asymmetry: 1.5, ..Default::default() };
        assert!(matches!(simulate(&p, &[0.0], &[0.0], 1e-3), Err(Error::Parameter { .. })));
        let p = LoopParams::default();
        assert!(matches!(simulate(&p, &[0.0, f64::NAN], &[0.0, 0.0], 1e-3), Err(Error::Input(_))));
        assert!(matches!(simulate(&p, &[0.0], &[0.0, 0.0], 1e-3), Err(Error::Input(_))));
    }
}
