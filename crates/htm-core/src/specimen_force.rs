//! The specimen and load-train force model of a `displacement_input` record (DATA_FORMAT.md):
//! the measured displacement (`y`, or a clip gauge's `cod`) is the input, the load cell's force
//! the output. One copy of the law, used by the diagnosis's simulation (`htm diagnose`, `htm
//! predict`) and by the generator of simulated records, and written in the terms of the per-cycle
//! compliance and closure of `crack_measure` (`closure_fit`, `from_closure_fit`):
//!
//! ```text
//!   x   = play(y; g/2)                               load-train play of gap g (EFFECTS load_train_backlash)
//!   ẋ   = (x[k+m] − x[k−m]) / (2m·Δt)                the specimen's velocity (central difference, window 2m·Δt)
//!   F   = k·(x − y_s) − k_cl·(⌊y_s + y_cl − x⌋₊ − ⌊y_cl⌋₊)
//!                                                    spring, stiffer by k_cl below the closure position,
//!                                                    no force at y_s on either branch
//!         + c·ẋ + F_c·tanh(ẋ/v_f)                     viscous damping, friction in the load path
//!         + F_p·z(u),  u = clip(u + Δy, ±(g/2 + δ_e))  friction built up over a displacement (pre-sliding),
//!           z(u) = sign(u)·min(⌊|u| − g/2⌋₊/δ_e, 1)     behind the play in series (below), δ_e = δ_p − g/2
//!   f   = F + f_0                                    the load cell's reading (EFFECTS sensor_offset on f)
//! ```
//!
//! `play` is the backlash operator: after each reversal the displacement travels the gap g with
//! the specimen at rest (no force change) before it is loaded again; it starts centred. The
//! pre-sliding friction (an elastic stage δ_p in series with a slider) sits behind that play in
//! series: a force goes through the play only while it is closed, so after a reversal the element
//! first unloads over δ_p, the play then opens and the displacement travels g at no friction force,
//! and the element loads again over δ_p before it slides (a dry friction damper with play: the
//! force falls to zero, stays there over the gap, and builds up the other way). δ_p is the travel
//! from a reversal to where that friction force crosses zero, half the travel from sliding one way
//! to sliding the other (with no play, the elastic stage itself): its elastic stage is δ_e =
//! δ_p − g/2 (at least `PRESLIDING_MIN_SHARE`·δ_p: a slider behind the play with no elastic
//! stage to speak of when g/2 ≥ δ_p). A play added to a pre-sliding friction so keeps the width
//! of its reversal and reshapes it (flat in the middle), which is how a fit finds one. The velocity
//! friction F_c·tanh(ẋ/v_f) behind the play does the same with no elastic stage: x rests in the
//! gap, and so does its friction. Without a play z(u) is the elasto-plastic z = clip(z + Δx/δ_p, ±1). ⌊·⌋₊ is
//! max(·, 0) with its corner smoothed over `CLOSURE_SMOOTHING_M` (the same bilinear spring as the
//! plant's specimen, `machine.rs`, and the displacement loop's, `outer_loop.rs`: all three call
//! `spring_force`; the loop's damping and friction are `damping_friction_force`, as here).
//!
//! **The same physics as `crack_measure`.** Its closure fit describes the loading branch as the
//! opening against the force, compliance C_open above the opening force and C_open·(1 − d)
//! below it (the compliance offset d of E647 X2). The spring above is the same bilinear law read
//! the other way: C_open = 1/k, d = k_cl/(k + k_cl), and the opening force F_t = k·y_cl +
//! k_cl·⌊y_cl⌋₊ + f_0 (the force at the closure position, `closure_force`). `closure_fit` and
//! `from_closure_fit` convert between the two, and a loading branch simulated here and reduced by
//! `crack_measure::fit_closure` returns them (test `crack_measure_reads_this_closure_back`).
use crate::crack_measure::ClosureFit;
use crate::error::{Error, Result};
use crate::hydraulics::{smooth_opening, smooth_opening_dx};
use crate::machine::CLOSURE_SMOOTHING_M;
use crate::measure::held;
use crate::params::Field;

macro_rules! define_specimen_params {
    ($( $(#[doc = $doc:literal])+ $name:ident [$unit:literal] = $default:expr, $lo:tt $min:expr, $max:expr; )*) => {
        /// Parameters of the specimen and load-train force model, SI. Each effect is off at its default.
        #[derive(Debug, Clone, PartialEq)]
        pub struct SpecimenParams {
            $( $(#[doc = $doc])+ pub $name: f64, )*
        }

        /// Every parameter of the specimen force model with unit, documentation and allowed range.
        pub const SPECIMEN_FIELDS: &[Field] = &[
            $( Field { name: stringify!($name), unit: $unit, doc: concat!($($doc, " "),+),
                       min: $min, max: $max, min_open: define_specimen_params!(@open $lo) }, )*
        ];

        impl Default for SpecimenParams {
            fn default() -> Self {
                SpecimenParams { $( $name: $default, )* }
            }
        }

        impl SpecimenParams {
            /// A parameter by name.
            pub fn get(&self, name: &str) -> Option<f64> {
                match name { $( stringify!($name) => Some(self.$name), )* _ => None }
            }
            /// Set a parameter by name (no range check: `validate` does that).
            pub fn set(&mut self, name: &str, value: f64) -> Result<()> {
                match name {
                    $( stringify!($name) => { self.$name = value; Ok(()) } )*
                    _ => Err(Error::Input(format!("unknown specimen parameter `{name}`"))),
                }
            }
        }
    };
    (@open open) => { true };
    (@open closed) => { false };
}

define_specimen_params! {
    /// Specimen (and load-train) stiffness k: the inverse of its compliance above the opening
    specimen_stiffness_n_m ["N/m"] = 0.0, closed 0.0, 1.0e12;
    /// Displacement y_s at which the specimen carries no force
    specimen_zero_force_position_m ["m"] = 0.0, closed -10.0, 10.0;
    /// Viscous damping c of the specimen and load train
    specimen_damping_n_s_m ["N s/m"] = 0.0, closed 0.0, 1.0e9;
    /// Friction F_c in the load path (guides, anti-buckling plates, a damper): F_c·tanh(ẋ/v_f)
    specimen_friction_n ["N"] = 0.0, closed 0.0, 1.0e8;
    /// Velocity v_f over which the friction builds up
    specimen_friction_velocity_m_s ["m/s"] = 1.0e-3, open 0.0, 10.0;
    /// Friction F_p that builds up over a displacement (pre-sliding: an elasto-plastic element,
    /// slope F_p/δ_p from each reversal until it slides at F_p; the project's
    /// `presliding_friction`, beside EFFECTS specimen_friction's build-up over a velocity)
    specimen_presliding_friction_n ["N"] = 0.0, closed 0.0, 1.0e8;
    /// Displacement δ_p over which the pre-sliding friction builds up: from a reversal to where
    /// its force crosses zero (behind a play g, its elastic stage is δ_p − g/2)
    specimen_presliding_m ["m"] = 1.0e-3, open 0.0, 1.0;
    /// Closure stiffness k_cl added below the closure position (EFFECTS specimen_nonlinearity)
    specimen_closure_stiffness_n_m ["N/m"] = 0.0, closed 0.0, 1.0e12;
    /// Closure position relative to the zero-force position: k_cl acts for x < y_s + this
    specimen_closure_offset_m ["m"] = 0.0, closed -1.0, 1.0;
    /// Play g of the load train (EFFECTS load_train_backlash `gap_m`)
    load_train_gap_m ["m"] = 0.0, closed 0.0, 1.0;
    /// Load cell offset f_0 (EFFECTS sensor_offset on f)
    sensor_offset_f ["N"] = 0.0, closed -1.0e8, 1.0e8;
    /// Time window 2m·Δt of the central difference that gives the specimen's velocity (at least
    /// one sample each side): a wider window keeps a noisy displacement's noise out of the
    /// friction and damping forces
    velocity_window_s ["s"] = 0.0, closed 0.0, 10.0;
}

impl SpecimenParams {
    /// Check every field; the error names the first bad one and its allowed range.
    pub fn validate(&self) -> Result<()> {
        for f in SPECIMEN_FIELDS {
            f.check(self.get(f.name).expect("field table matches struct"))?;
        }
        Ok(())
    }

    /// The closure of this spring as `crack_measure` reads it from a loading branch (compliance
    /// C_open above the opening force, offset d below it, transition force F_t as the load cell
    /// reads it); the transition width is the corner smoothing in force units.
    pub fn closure_fit(&self) -> ClosureFit {
        let k = self.specimen_stiffness_n_m;
        let kc = self.specimen_closure_stiffness_n_m;
        ClosureFit {
            c_open: 1.0 / k,
            depth: if k + kc > 0.0 { kc / (k + kc) } else { 0.0 },
            f_t: closure_force(k, kc, self.specimen_closure_offset_m) + self.sensor_offset_f,
            w: k * CLOSURE_SMOOTHING_M,
        }
    }

    /// The spring (stiffness, closure stiffness and closure position) that `crack_measure`'s
    /// closure `fit` describes, for a specimen at zero-force position `zero_force_position_m`
    /// (the load cell offset and the other terms kept).
    pub fn from_closure_fit(&self, fit: &ClosureFit) -> Result<SpecimenParams> {
        if !(fit.c_open.is_finite() && fit.c_open > 0.0 && (0.0..1.0).contains(&fit.depth)) {
            return Err(Error::Input(format!(
                "a closure fit needs C_open > 0 and a depth in [0, 1) (got C_open = {}, depth = {})",
                fit.c_open, fit.depth
            )));
        }
        let k = 1.0 / fit.c_open;
        let mut p = self.clone();
        p.specimen_stiffness_n_m = k;
        p.specimen_closure_stiffness_n_m = k * fit.depth / (1.0 - fit.depth);
        p.specimen_closure_offset_m = closure_offset_at(k, p.specimen_closure_stiffness_n_m, fit.f_t - self.sensor_offset_f);
        p.validate()?;
        Ok(p)
    }
}

/// The bilinear spring a record's force shows against its displacement (samples `f` [N], `x`
/// [m], any order, NaN pairs skipped): f = a + k·x − k_cl·⌊x_c − x⌋₊ by least squares, the
/// corner x_c tried at each percentile (2 % to 98 %) of the displacement and the best kept.
/// Returns (k, k_cl, x_c) — the stiffness, the closure stiffness and the closure's position, in
/// the record's coordinates — or `None` where no corner makes the spring stiffer below it (or
/// fewer than 20 samples). A start for a fit of [`spring_force`], not a result of its own: the
/// damping, friction and play of a load train, a sensor's lag and the corner's smoothing are
/// not in it. (`crack_measure::fit_closure` reads the same law from a loading branch as
/// compliance, its transition in the lower part of the force range where a crack closes; a
/// record's closure may sit anywhere along its travel.)
pub fn spring_from_samples(f: &[f64], x: &[f64]) -> Option<(f64, f64, f64)> {
    let (f, x): (Vec<f64>, Vec<f64>) = f.iter().zip(x).filter(|(a, b)| a.is_finite() && b.is_finite()).map(|(a, b)| (*a, *b)).unzip();
    if f.len() < 20 {
        return None;
    }
    let mut sorted = x.clone();
    sorted.sort_by(f64::total_cmp);
    let (x0, span) = (sorted[sorted.len() / 2], (sorted[sorted.len() - 1] - sorted[0]).max(1e-300));
    let fs = f.iter().map(|v| v.abs()).fold(0.0, f64::max).max(1e-300);
    let yy: f64 = f.iter().map(|v| (v / fs) * (v / fs)).sum();
    // normal equations in scaled units (x about its median over its span, f over its largest):
    // the line's columns (1, x) once, the corner's column per corner
    let u: Vec<f64> = x.iter().map(|xi| (xi - x0) / span).collect();
    let (mut line, mut rl) = ([[0.0; 2]; 2], [0.0; 2]);
    for (&ui, &fi) in u.iter().zip(&f) {
        let c = [1.0, ui];
        for a in 0..2 {
            rl[a] += c[a] * fi / fs;
            for b in 0..2 {
                line[a][b] += c[a] * c[b];
            }
        }
    }
    let mut best: Option<(f64, [f64; 3], f64)> = None;
    for q in 2..=98 {
        let xc = sorted[(q * (sorted.len() - 1)) / 100];
        let (mut mh, mut rh) = ([0.0; 3], 0.0); // Σ h·1, Σ h·x, Σ h², Σ h·f of the corner's column h
        for ((&xi, &ui), &fi) in x.iter().zip(&u).zip(&f) {
            let h = ((xc - xi) / span).max(0.0);
            mh[0] += h;
            mh[1] += ui * h;
            mh[2] += h * h;
            rh += h * fi / fs;
        }
        let m = [[line[0][0], line[0][1], mh[0]], [line[1][0], line[1][1], mh[1]], [mh[0], mh[1], mh[2]]];
        let r = [rl[0], rl[1], rh];
        if let Some(s) = crate::crack_measure::solve3(m, r) {
            let sse = yy - s[0] * r[0] - s[1] * r[1] - s[2] * r[2];
            if best.is_none_or(|b| sse < b.0) {
                best = Some((sse, s, xc));
            }
        }
    }
    let (_, s, xc) = best?;
    let (k, k_cl) = (s[1] * fs / span, -s[2] * fs / span);
    (k > 0.0 && k_cl > 0.0).then_some((k, k_cl, xc))
}

/// The bilinear spring of a specimen [N] at displacement `x`: stiffness `k`, and `k_cl` more
/// below `y0 + closure_offset` (corner smoothed over `CLOSURE_SMOOTHING_M`), carrying no force
/// at the zero-force position `y0` whichever branch it lies on (DATA_FORMAT.md: the position at
/// which the gripped specimen carried no force). A closure above `y0` (at a positive force, the
/// usual crack closure) puts `y0` on the closed, stiffer branch: that branch passes through
/// (`y0`, 0) and the open branch lies `k_cl·⌊closure_offset⌋₊` above `k·(x − y0)`; a closure below
/// `y0` leaves the open branch through (`y0`, 0). The one copy of the closure law (plant,
/// displacement loop, this model).
#[inline]
pub fn spring_force(k: f64, y0: f64, k_cl: f64, closure_offset: f64, x: f64) -> f64 {
    let mut f = k * (x - y0);
    if k_cl > 0.0 {
        f -= k_cl * (smooth_opening(y0 + closure_offset - x, CLOSURE_SMOOTHING_M)
            - smooth_opening(closure_offset, CLOSURE_SMOOTHING_M));
    }
    f
}

/// The force at the closure position (where the two branches of [`spring_force`] meet),
/// without a load cell's offset: k·y_cl + k_cl·⌊y_cl⌋₊ (the corner's smoothing as in the spring).
pub fn closure_force(k: f64, k_cl: f64, closure_offset: f64) -> f64 {
    k * closure_offset + k_cl * smooth_opening(closure_offset, CLOSURE_SMOOTHING_M)
}

/// The closure offset whose [`closure_force`] is `f` (the inverse: monotone in the offset).
pub fn closure_offset_at(k: f64, k_cl: f64, f: f64) -> f64 {
    let mut y = if f > 0.0 { f / (k + k_cl) } else { f / k };
    for _ in 0..50 {
        let r = closure_force(k, k_cl, y) - f;
        let d = k + k_cl * smooth_opening_dx(y, CLOSURE_SMOOTHING_M);
        let step = r / d;
        y -= step;
        if step.abs() <= 1e-15 * y.abs().max(CLOSURE_SMOOTHING_M) {
            break;
        }
    }
    y
}

/// The velocity-dependent force of a specimen [N] at velocity `v`: viscous damping `c` and a
/// friction `fc` that builds up over the velocity `vf` (`fc`·tanh(v/`vf`); off at `fc` = 0). The
/// one copy of that law (the displacement loop's specimen, this model).
#[inline]
pub fn damping_friction_force(c: f64, fc: f64, vf: f64, v: f64) -> f64 {
    let mut f = c * v;
    if fc > 0.0 {
        f += fc * (v / vf).tanh();
    }
    f
}

/// The backlash (play) operator: the output follows the input at `half` behind it, and rests
/// while the input travels back across the gap 2·`half`; it starts at `start`.
pub fn play(y: &[f64], half: f64, start: f64) -> Vec<f64> {
    let mut x = start;
    y.iter()
        .map(|&v| {
            if v > x + half {
                x = v - half;
            } else if v < x - half {
                x = v + half;
            }
            x
        })
        .collect()
}

/// The least elastic stage of the pre-sliding friction behind a play, as a share of δ_p.
pub const PRESLIDING_MIN_SHARE: f64 = 1e-3;

/// The share z ∈ [−1, 1] of the pre-sliding friction carried at the element's state `u` (the
/// displacement ahead of the play, kept within ±(`half` + `d`)): none while the play of half-width
/// `half` is open, then built up linearly over `d`. With no play it is z = clip(z + Δx/δ_p, −1, 1).
#[inline]
pub fn presliding_share(u: f64, half: f64, d: f64) -> f64 {
    ((u.abs() - half).max(0.0) / d).min(1.0).copysign(u)
}

/// Check a displacement input: samples, a finite value, a positive sample period.
pub fn validate_input(dt: f64, y: &[f64]) -> Result<()> {
    if y.len() < 2 {
        return Err(Error::Input(format!("the displacement has {} samples; at least 2 are needed", y.len())));
    }
    if !(dt.is_finite() && dt > 0.0) {
        return Err(Error::Input(format!("sample period dt = {dt} s must be > 0")));
    }
    if !y.iter().any(|x| x.is_finite()) {
        return Err(Error::Input("the displacement holds no finite value".into()));
    }
    Ok(())
}

/// The load cell's force [N] at every sample of the displacement `y` [m] sampled every `dt` [s]
/// (NaN = a dropped sample, the previous value held).
pub fn force(p: &SpecimenParams, dt: f64, y: &[f64]) -> Result<Vec<f64>> {
    p.validate()?;
    validate_input(dt, y)?;
    let y = held(y);
    let n = y.len();
    let played = (p.load_train_gap_m > 0.0).then(|| play(&y, 0.5 * p.load_train_gap_m, y[0]));
    let x: &[f64] = played.as_deref().unwrap_or(&y);
    let m = ((p.velocity_window_s / (2.0 * dt)).round() as usize).clamp(1, (n - 1).max(1));
    let mut u = 0.0;
    let out = (0..n)
        .map(|k| {
            let (a, b) = (k.saturating_sub(m), (k + m).min(n - 1));
            let v = (x[b] - x[a]) / ((b - a) as f64 * dt);
            let mut f = spring_force(p.specimen_stiffness_n_m, p.specimen_zero_force_position_m, p.specimen_closure_stiffness_n_m,
                                     p.specimen_closure_offset_m, x[k])
                + damping_friction_force(p.specimen_damping_n_s_m, p.specimen_friction_n, p.specimen_friction_velocity_m_s, v);
            if p.specimen_presliding_friction_n > 0.0 {
                // the element sits behind the play, in series: its state u follows the displacement
                // ahead of the play within ±(g/2 + δ_p), and the play is a dead zone of width g in it
                let dy = if k > 0 { y[k] - y[k - 1] } else { 0.0 };
                let half = 0.5 * p.load_train_gap_m;
                let d = (p.specimen_presliding_m - half).max(PRESLIDING_MIN_SHARE * p.specimen_presliding_m);
                u = (u + dy).clamp(-(half + d), half + d);
                f += p.specimen_presliding_friction_n * presliding_share(u, half, d);
            }
            f + p.sensor_offset_f
        })
        .collect();
    Ok(out)
}

/// `force` for every parameter set, on `threads` threads (0 = all cores).
pub fn force_batch(ps: &[SpecimenParams], dt: f64, y: &[f64], threads: usize) -> Vec<Result<Vec<f64>>> {
    crate::batch::par_map(ps, threads, |p| force(p, dt, y))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::crack_measure::fit_closure;
    use std::f64::consts::PI;

    fn sine(n: usize, dt: f64, f_hz: f64, amp: f64) -> Vec<f64> {
        (0..n).map(|k| amp * (2.0 * PI * f_hz * k as f64 * dt).sin()).collect()
    }

    #[test]
    fn a_linear_spring_is_hookes_law_with_its_offset() {
        let p = SpecimenParams { specimen_stiffness_n_m: 2e6, specimen_zero_force_position_m: 1e-3, sensor_offset_f: 50.0,
                                 ..Default::default() };
        let y = sine(500, 1e-3, 2.0, 1e-3);
        let f = force(&p, 1e-3, &y).unwrap();
        for (fi, yi) in f.iter().zip(&y) {
            assert!((fi - (2e6 * (yi - 1e-3) + 50.0)).abs() < 1e-9);
        }
    }

    #[test]
    fn friction_opposes_the_motion_at_its_level() {
        let p = SpecimenParams { specimen_friction_n: 300.0, specimen_friction_velocity_m_s: 1e-4, ..Default::default() };
        let dt = 1e-3;
        let y = sine(1000, dt, 1.0, 1e-3);
        let f = force(&p, dt, &y).unwrap();
        // rising at k = 0 (v = 2π mm/s), falling at k = 500
        assert!((f[1] - 300.0).abs() < 1.0 && (f[500] + 300.0).abs() < 1.0, "{} {}", f[1], f[500]);
    }

    #[test]
    fn presliding_friction_builds_up_over_its_displacement_after_each_reversal() {
        let p = SpecimenParams { specimen_presliding_friction_n: 200.0, specimen_presliding_m: 1e-4, ..Default::default() };
        // up 1 mm in 1 µm steps, then back
        let y: Vec<f64> = (0..2001).map(|i| 1e-6 * (1000.0 - (i as f64 - 1000.0).abs())).collect();
        let f = force(&p, 1e-3, &y).unwrap();
        assert!((f[50] - 100.0).abs() < 1e-6 && (f[1000] - 200.0).abs() < 1e-9, "{} {}", f[50], f[1000]);
        // back by its displacement: no friction; by twice it: sliding the other way
        assert!(f[1100].abs() < 1e-6 && (f[1200] + 200.0).abs() < 1e-9, "{} {}", f[1100], f[1200]);
    }

    #[test]
    fn after_a_reversal_the_force_does_not_change_over_the_gap() {
        let (k, gap) = (1e6, 2e-4);
        let p = SpecimenParams { specimen_stiffness_n_m: k, load_train_gap_m: gap, ..Default::default() };
        let dt = 1e-4;
        // up 1 mm, then back down 1 mm at constant speed
        let n = 2000;
        let y: Vec<f64> = (0..n).map(|i| 1e-3 * (1.0 - (2.0 * i as f64 / n as f64 - 1.0).abs())).collect();
        let f = force(&p, dt, &y).unwrap();
        let top = n / 2;
        let peak = f[top];
        // the displacement travels back by less than the gap: no change; beyond it, the spring unloads
        let back = |d: f64| top + (d / (1e-3 / (n as f64 / 2.0))).round() as usize;
        assert!((f[back(0.9 * gap)] - peak).abs() < 1e-9);
        assert!((f[back(gap + 1e-4)] - (peak - k * 1e-4)).abs() < 0.5, "{}", f[back(gap + 1e-4)] - peak);
    }

    #[test]
    fn presliding_friction_behind_a_play_unloads_then_crosses_the_gap_at_no_force() {
        // elastic stage d = δ_p − g/2
        let (fp, d, gap) = (1000.0, 1e-4, 4e-4);
        let p = SpecimenParams { specimen_presliding_friction_n: fp, specimen_presliding_m: d + 0.5 * gap, load_train_gap_m: gap,
                                 ..Default::default() };
        // up 2 mm in 1 µm steps (sliding at +F_p), then back 2 mm
        let y: Vec<f64> = (0..4001).map(|i| 1e-6 * (2000.0 - (i as f64 - 2000.0).abs())).collect();
        let f = force(&p, 1e-3, &y).unwrap();
        assert!((f[2000] - fp).abs() < 1e-9, "{}", f[2000]);
        // back by half of δ_p: half unloaded; by δ_p: none; across the gap: none; then loading the other way
        assert!((f[2050] - 0.5 * fp).abs() < 1e-6 && f[2100].abs() < 1e-6 && f[2100 + 390].abs() < 1e-6, "{} {}", f[2050], f[2100]);
        assert!((f[2100 + 400 + 50] + 0.5 * fp).abs() < 1e-6 && (f[2100 + 400 + 100] + fp).abs() < 1e-6);
        // the same reversal without the play: from +F_p to −F_p over 2δ_p, crossing zero at δ_p as with it
        let q = SpecimenParams { load_train_gap_m: 0.0, ..p };
        let g = force(&q, 1e-3, &y).unwrap();
        assert!(g[2300].abs() < 1e-6 && (g[2600] + fp).abs() < 1e-9 && (g[2150] - 0.5 * fp).abs() < 1e-6);
    }

    #[test]
    fn the_spring_carries_no_force_at_its_zero_force_position_on_either_branch() {
        let (k, kc, y0) = (2e6, 1.5e6, 0.01);
        for yc in [0.5e-3, 0.0, -0.5e-3] {
            assert!(spring_force(k, y0, kc, yc, y0).abs() < 1e-9, "closure offset {yc}: {}", spring_force(k, y0, kc, yc, y0));
            // the branches' slopes: k + k_cl well below the closure position, k well above it
            let slope = |x: f64| (spring_force(k, y0, kc, yc, x + 1e-7) - spring_force(k, y0, kc, yc, x - 1e-7)) / 2e-7;
            assert!((slope(y0 + yc - 0.5e-3) / (k + kc) - 1.0).abs() < 1e-3 && (slope(y0 + yc + 0.5e-3) / k - 1.0).abs() < 1e-3);
        }
        // a closure at a positive force (above y0): y0 on the closed branch, the open branch
        // lies k_cl·y_cl above k·(x − y0); the force at the closure position is (k + k_cl)·y_cl
        let yc = 0.5e-3;
        assert!((spring_force(k, y0, kc, yc, y0 + 2e-3) - (k * 2e-3 + kc * yc)).abs() < 1.0);
        assert!((closure_force(k, kc, yc) - (k + kc) * yc).abs() < 1.0);
        assert!((closure_force(k, kc, -yc) + k * yc).abs() < 1.0);
        // below y0: unchanged, the open branch through (y0, 0)
        assert!((spring_force(k, y0, kc, -yc, y0 + 1e-3) - k * 1e-3).abs() < 0.5); // the corner's smoothing only
        for f in [-2000.0, -1.0, 0.0, 3.0, 1750.0] {
            let y = closure_offset_at(k, kc, f);
            assert!((closure_force(k, kc, y) - f).abs() < 1e-6, "{f}: {}", closure_force(k, kc, y));
        }
    }

    #[test]
    fn crack_measure_reads_this_closure_back() {
        // a loading branch of the bilinear spring, force against displacement, reduced by the
        // E647 closure fit: the same compliance, depth and opening force
        let p = SpecimenParams {
            specimen_stiffness_n_m: 4e6,
            specimen_closure_stiffness_n_m: 4e6,
            specimen_closure_offset_m: 0.4e-3,
            sensor_offset_f: 120.0,
            ..Default::default()
        };
        let y: Vec<f64> = (0..2001).map(|i| -0.5e-3 + 2.5e-3 * i as f64 / 2000.0).collect();
        let f = force(&p, 1e-3, &y).unwrap();
        let (fmin, fmax) = (f[0], f[f.len() - 1]);
        let got = fit_closure(&f, &y, fmin, fmax).unwrap();
        let want = p.closure_fit();
        assert!((got.c_open / want.c_open - 1.0).abs() < 0.01, "C_open {} vs {}", got.c_open, want.c_open);
        assert!((got.depth - want.depth).abs() < 0.02, "depth {} vs {}", got.depth, want.depth);
        assert!((got.f_t - want.f_t).abs() < 0.02 * (fmax - fmin), "F_t {} vs {}", got.f_t, want.f_t);
        // and back: the spring the fit describes
        let back = p.from_closure_fit(&got).unwrap();
        assert!((back.specimen_stiffness_n_m / 4e6 - 1.0).abs() < 0.01);
        assert!((back.specimen_closure_stiffness_n_m / 4e6 - 1.0).abs() < 0.05, "{}", back.specimen_closure_stiffness_n_m);
        assert!((back.specimen_closure_offset_m / 0.4e-3 - 1.0).abs() < 0.05, "{}", back.specimen_closure_offset_m);
    }

    #[test]
    fn a_records_force_against_its_displacement_gives_its_spring_back() {
        // a record's samples: cycles of a closure spring with noise, up and down, in time order;
        // the closure 1 mm above the zero-force position at 0.5 mm, high in the force range
        let p = SpecimenParams {
            specimen_stiffness_n_m: 2e6,
            specimen_zero_force_position_m: 0.5e-3,
            specimen_closure_stiffness_n_m: 2e6,
            specimen_closure_offset_m: 1e-3,
            ..Default::default()
        };
        let n = 20_000;
        let mut seed = 7_u64;
        let mut noise = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 40.0 // +-20 N
        };
        let y: Vec<f64> = (0..n).map(|i| 1e-3 + 2.5e-3 * (i as f64 * 0.01).sin()).collect();
        let e: Vec<f64> = (0..n).map(|_| noise()).collect();
        let f: Vec<f64> = force(&p, 1e-3, &y).unwrap().iter().zip(&e).map(|(v, ei)| v + ei).collect();
        let (k, k_cl, xc) = spring_from_samples(&f, &y).expect("a closure");
        assert!((k / 2e6 - 1.0).abs() < 0.02, "{k}");
        assert!((k_cl / 2e6 - 1.0).abs() < 0.05, "{k_cl}");
        assert!((xc - 1.5e-3).abs() < 0.05e-3, "{xc}");
        // a straight spring shows no stiffer branch worth a start; a softer one below none at all
        let line: Vec<f64> = y.iter().zip(&e).map(|(v, ei)| 2e6 * v + ei).collect();
        assert!(spring_from_samples(&line, &y).is_none_or(|(_, k_cl, _)| k_cl < 0.02 * 2e6));
        let softer: Vec<f64> = f.iter().map(|v| -v).collect();
        assert!(spring_from_samples(&softer, &y.iter().map(|v| -v).collect::<Vec<_>>()).is_none());
        assert!(spring_from_samples(&[1.0, f64::NAN], &[0.0, 1.0]).is_none());
    }

    #[test]
    fn bad_input_is_refused_by_name() {
        let p = SpecimenParams { specimen_friction_velocity_m_s: 0.0, ..Default::default() };
        let e = force(&p, 1e-3, &[0.0, 1.0]).unwrap_err().to_string();
        assert!(e.contains("specimen_friction_velocity_m_s"), "{e}");
        let e = force(&SpecimenParams::default(), 1e-3, &[f64::NAN, f64::NAN]).unwrap_err().to_string();
        assert!(e.contains("no finite value"), "{e}");
        assert!(SpecimenParams::default().set("nope", 1.0).is_err());
    }
}
