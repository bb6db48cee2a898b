//! Fatigue crack growth: Paris, Forman and NASGRO rate laws da/dN(ΔK, R, Kmax), the per-cycle
//! increment, and life integration N(a0 → af) for a specimen and constant-amplitude load
//! (adaptive Simpson on dN/da, with fracture detected where Kmax reaches the law's toughness).
//! SI: ΔK and K in Pa·√m, a in m, rates in m/cycle; C is in (m/cycle)/(Pa·√m)^m.
use crate::error::{Error, Result};
use crate::specimen::{root_illinois, Specimen};

/// A crack-growth rate law.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Law {
    /// da/dN = C·ΔK^m
    Paris { c: f64, m: f64 },
    /// da/dN = C·ΔK^m / ((1 − R)·K_c − ΔK)   (fracture when Kmax ≥ K_c)
    Forman { c: f64, m: f64, kc: f64 },
    /// da/dN = C·[((1 − f)/(1 − R))·ΔK]^n · (1 − ΔK_th/ΔK)^p / (1 − Kmax/K_crit)^q
    /// (NASGRO equation; `f_open` is the crack-opening function f, e.g. from `newman_f`).
    Nasgro { c: f64, n: f64, p: f64, q: f64, dk_th: f64, k_crit: f64, f_open: f64 },
}

/// Stress ratios R a load (life prediction, E647 data reduction) may have: [lo, hi). The test
/// engine runs a narrower range (`engine::TEST_R_RATIO_RANGE`).
pub const LOAD_R_RATIO_RANGE: (f64, f64) = (-5.0, 1.0);

/// NASGRO terms a law may leave out and their values then: no threshold (p = 0, ΔK_th = 0), no
/// toughness term (q = 0, K_crit far above any test), no closure (f = 0). The one source of
/// these defaults (the bindings and `htm.fatigue.laws` read them from here).
pub const NASGRO_DEFAULTS: [(&str, f64); 5] = [("p", 0.0), ("q", 0.0), ("dk_th", 0.0), ("k_crit", 1e12), ("f_open", 0.0)];

/// A law as named parameters (the shape of a spec's `[law]` table, SI): `law` is paris, forman or
/// nasgro; the parameters a law does not use are ignored.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LawSpec {
    pub law: String,
    pub c: Option<f64>,
    pub m: Option<f64>,
    pub kc: Option<f64>,
    pub n: Option<f64>,
    pub p: Option<f64>,
    pub q: Option<f64>,
    pub dk_th: Option<f64>,
    pub k_crit: Option<f64>,
    pub f_open: Option<f64>,
}

impl LawSpec {
    /// The validated law; a missing parameter the law needs is an input error naming it.
    pub fn build(&self) -> Result<Law> {
        let need = |k: &str, v: Option<f64>| v.ok_or_else(|| Error::Input(format!("growth law `{}` needs `{k}`", self.law)));
        let dflt = |k: &str, v: Option<f64>| v.unwrap_or_else(|| nasgro_default(k));
        let law = match self.law.as_str() {
            "paris" => Law::Paris { c: need("c", self.c)?, m: need("m", self.m)? },
            "forman" => Law::Forman { c: need("c", self.c)?, m: need("m", self.m)?, kc: need("kc", self.kc)? },
            "nasgro" => Law::Nasgro {
                c: need("c", self.c)?, n: need("n", self.n)?, p: dflt("p", self.p), q: dflt("q", self.q),
                dk_th: dflt("dk_th", self.dk_th), k_crit: dflt("k_crit", self.k_crit), f_open: dflt("f_open", self.f_open),
            },
            other => return Err(Error::Input(format!("unknown growth law `{other}`: use paris, forman or nasgro"))),
        };
        law.validate()?;
        Ok(law)
    }
}

fn nasgro_default(k: &str) -> f64 {
    NASGRO_DEFAULTS.iter().find(|(n, _)| *n == k).map(|(_, v)| *v).unwrap_or(0.0)
}

fn param(field: &str, value: f64, allowed: &str) -> Error {
    Error::Parameter { field: field.into(), value, allowed: allowed.into() }
}

fn positive(field: &str, v: f64) -> Result<()> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(param(field, v, "(0, inf)"))
    }
}

impl Law {
    pub fn name(&self) -> &'static str {
        match self {
            Law::Paris { .. } => "paris",
            Law::Forman { .. } => "forman",
            Law::Nasgro { .. } => "nasgro",
        }
    }

    pub fn validate(&self) -> Result<()> {
        let exponent = |field: &str, v: f64| {
            if v.is_finite() && v > 0.0 && v <= 20.0 { Ok(()) } else { Err(param(field, v, "(0, 20]")) }
        };
        match *self {
            Law::Paris { c, m } => {
                positive("c", c)?;
                exponent("m", m)
            }
            Law::Forman { c, m, kc } => {
                positive("c", c)?;
                exponent("m", m)?;
                positive("kc", kc)
            }
            Law::Nasgro { c, n, p, q, dk_th, k_crit, f_open } => {
                positive("c", c)?;
                exponent("n", n)?;
                if !(p.is_finite() && (0.0..=10.0).contains(&p)) {
                    return Err(param("p", p, "[0, 10]"));
                }
                if !(q.is_finite() && (0.0..=10.0).contains(&q)) {
                    return Err(param("q", q, "[0, 10]"));
                }
                if !(dk_th.is_finite() && dk_th >= 0.0) {
                    return Err(param("dk_th", dk_th, "[0, inf) Pa·√m"));
                }
                positive("k_crit", k_crit)?;
                if !(f_open.is_finite() && (-1.0..1.0).contains(&f_open)) {
                    return Err(param("f_open", f_open, "[-1, 1)"));
                }
                Ok(())
            }
        }
    }

    /// Fracture toughness the law carries (K_c or K_crit), if any [Pa·√m].
    pub fn toughness(&self) -> Option<f64> {
        match *self {
            Law::Paris { .. } => None,
            Law::Forman { kc, .. } => Some(kc),
            Law::Nasgro { k_crit, q, .. } => if q > 0.0 { Some(k_crit) } else { None },
        }
    }

    /// Growth rate da/dN [m/cycle] at range `dk` and maximum `kmax` [Pa·√m], stress ratio `r`.
    /// Zero at or below a threshold; +inf at or beyond fracture. No checks (per-cycle use):
    /// validate the law once with `validate`.
    #[inline]
    pub fn rate(&self, dk: f64, r: f64, kmax: f64) -> f64 {
        if !(dk > 0.0) {
            return 0.0;
        }
        match *self {
            Law::Paris { c, m } => c * dk.powf(m),
            Law::Forman { c, m, kc } => {
                let den = (1.0 - r) * kc - dk;
                if den <= 0.0 { f64::INFINITY } else { c * dk.powf(m) / den }
            }
            Law::Nasgro { c, n, p, q, dk_th, k_crit, f_open } => {
                if dk <= dk_th {
                    return 0.0;
                }
                let crit = 1.0 - kmax / k_crit;
                if q > 0.0 && crit <= 0.0 {
                    return f64::INFINITY;
                }
                let eff = (1.0 - f_open) / (1.0 - r) * dk;
                let th = if p > 0.0 { (1.0 - dk_th / dk).powf(p) } else { 1.0 };
                let fr = if q > 0.0 { crit.powf(q) } else { 1.0 };
                c * eff.powf(n) * th / fr
            }
        }
    }
}

/// Newman's crack-opening function f(R, Smax/σ0, α) as used by NASGRO (R ≥ 0 branch; for R < 0
/// the R = 0 value A0 + ... is used with A2 = A3 = 0 per NASGRO). `alpha_c` is the constraint factor.
pub fn newman_f(r: f64, smax_over_flow: f64, alpha_c: f64) -> Result<f64> {
    if !(-2.0..1.0).contains(&r) {
        return Err(param("r_ratio", r, "[-2, 1)"));
    }
    if !(smax_over_flow.is_finite() && smax_over_flow > 0.0 && smax_over_flow < 1.0) {
        return Err(param("smax_over_flow_stress", smax_over_flow, "(0, 1)"));
    }
    if !(alpha_c.is_finite() && (1.0..=3.0).contains(&alpha_c)) {
        return Err(param("constraint_factor", alpha_c, "[1, 3]"));
    }
    let s = smax_over_flow;
    let a0 = (0.825 - 0.34 * alpha_c + 0.05 * alpha_c * alpha_c)
        * (std::f64::consts::PI * s / 2.0).cos().powf(1.0 / alpha_c);
    let a1 = (0.415 - 0.071 * alpha_c) * s;
    if r >= 0.0 {
        let a3 = 2.0 * a0 + a1 - 1.0;
        let a2 = 1.0 - a0 - a1 - a3;
        Ok((a0 + a1 * r + a2 * r * r + a3 * r * r * r).max(r))
    } else {
        Ok(a0 + a1 * r)
    }
}

/// A constant-amplitude load: maximum force [N] and stress ratio R = Pmin/Pmax.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Load {
    pub pmax_n: f64,
    pub r_ratio: f64,
}

impl Load {
    pub fn new(pmax_n: f64, r_ratio: f64) -> Result<Self> {
        let l = Load { pmax_n, r_ratio };
        l.validate()?;
        Ok(l)
    }

    /// From the force range ΔP (E647: ΔP = Pmax − Pmin for R ≥ 0, ΔP = Pmax for R < 0).
    pub fn from_delta_p(delta_p_n: f64, r_ratio: f64) -> Result<Self> {
        if !(delta_p_n.is_finite() && delta_p_n > 0.0) {
            return Err(param("delta_p_n", delta_p_n, "(0, inf) N"));
        }
        check_r(r_ratio)?;
        let pmax = if r_ratio >= 0.0 { delta_p_n / (1.0 - r_ratio) } else { delta_p_n };
        Load::new(pmax, r_ratio)
    }

    pub fn validate(&self) -> Result<()> {
        if !(self.pmax_n.is_finite() && self.pmax_n > 0.0) {
            return Err(param("pmax_n", self.pmax_n, "(0, inf) N"));
        }
        check_r(self.r_ratio)
    }

    /// ΔP [N] per E647 (compressive part excluded for R < 0).
    pub fn delta_p_n(&self) -> f64 {
        if self.r_ratio >= 0.0 { self.pmax_n * (1.0 - self.r_ratio) } else { self.pmax_n }
    }
}

fn check_r(r: f64) -> Result<()> {
    let (lo, hi) = LOAD_R_RATIO_RANGE;
    if r.is_finite() && (lo..hi).contains(&r) {
        Ok(())
    } else {
        Err(param("r_ratio", r, &format!("[{lo}, {hi})")))
    }
}

/// (ΔK, Kmax) [Pa·√m] at crack size `a_m` under `load`.
pub fn delta_k_kmax(spec: &Specimen, load: &Load, a_m: f64) -> Result<(f64, f64)> {
    let kmax = spec.k(a_m, load.pmax_n)?;
    let dk = if load.r_ratio >= 0.0 { kmax * (1.0 - load.r_ratio) } else { kmax };
    Ok((dk, kmax))
}

/// Crack growth in one cycle [m] at crack size `a_m` (the per-cycle call of the engine).
pub fn growth_per_cycle(law: &Law, spec: &Specimen, load: &Load, a_m: f64) -> Result<f64> {
    let (dk, kmax) = delta_k_kmax(spec, load, a_m)?;
    Ok(law.rate(dk, load.r_ratio, kmax))
}

/// Outcome of a life integration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Life {
    /// Cycles to grow from a0 to `a_end_m`.
    pub cycles: f64,
    /// Final crack size [m]: af, or the critical size if the law's toughness was reached first.
    pub a_end_m: f64,
    /// true when Kmax reached the law's toughness before af.
    pub fractured: bool,
}

/// Relative tolerance of the life integral.
pub const LIFE_RTOL: f64 = 1e-9;

fn check_setup(law: &Law, spec: &Specimen, load: &Load) -> Result<()> {
    law.validate()?;
    spec.validate()?;
    load.validate()
}

/// Critical crack size in [a0, af] where Kmax reaches the law's toughness, if any.
fn critical_size(law: &Law, spec: &Specimen, load: &Load, a0: f64, af: f64) -> Result<Option<f64>> {
    let Some(kc) = law.toughness() else { return Ok(None) };
    // Forman's singularity is at ΔK = (1 − R)K_c, i.e. Kmax = K_c for R ≥ 0.
    let kc_eff = match *law {
        Law::Forman { kc, .. } if load.r_ratio < 0.0 => kc * (1.0 - load.r_ratio),
        _ => kc,
    };
    let kmax_at = |a: f64| spec.k(a, load.pmax_n).unwrap_or(f64::INFINITY);
    if kmax_at(a0) >= kc_eff {
        return Ok(Some(a0));
    }
    if kmax_at(af) < kc_eff {
        return Ok(None);
    }
    let _ = kc;
    let ac = root_illinois(|a| kmax_at(a) - kc_eff, a0, af, 1e-13 * spec.width_m)?;
    Ok(Some(ac))
}

/// dN/da [cycles/m] at a; +inf where the crack does not grow.
#[inline]
fn dn_da(law: &Law, spec: &Specimen, load: &Load, a: f64) -> f64 {
    match delta_k_kmax(spec, load, a) {
        Ok((dk, kmax)) => {
            let r = law.rate(dk, load.r_ratio, kmax);
            if r > 0.0 { 1.0 / r } else { f64::INFINITY }
        }
        Err(_) => f64::NAN,
    }
}

#[allow(clippy::too_many_arguments)]
fn simpson_rec<F: Fn(f64) -> f64>(f: &F, a: f64, b: f64, fa: f64, fm: f64, fb: f64, whole: f64, tol: f64, depth: u32) -> f64 {
    let m = 0.5 * (a + b);
    let (lm, rm) = (0.5 * (a + m), 0.5 * (m + b));
    let (flm, frm) = (f(lm), f(rm));
    let h = b - a;
    let left = h / 12.0 * (fa + 4.0 * flm + fm);
    let right = h / 12.0 * (fm + 4.0 * frm + fb);
    let delta = left + right - whole;
    if depth == 0 || delta.abs() <= 15.0 * tol || !delta.is_finite() {
        return left + right + delta / 15.0;
    }
    simpson_rec(f, a, m, fa, flm, fm, left, 0.5 * tol, depth - 1) + simpson_rec(f, m, b, fm, frm, fb, right, 0.5 * tol, depth - 1)
}

/// ∫ f over [a, b] by adaptive Simpson with relative tolerance `rtol` (on a 16-panel estimate).
fn integrate<F: Fn(f64) -> f64>(f: F, a: f64, b: f64, rtol: f64) -> f64 {
    if b <= a {
        return 0.0;
    }
    const PANELS: usize = 16;
    let h = (b - a) / PANELS as f64;
    // coarse estimate for the absolute tolerance
    let mut coarse = 0.0;
    for i in 0..PANELS {
        let (x0, x1) = (a + i as f64 * h, a + (i + 1) as f64 * h);
        coarse += h / 6.0 * (f(x0) + 4.0 * f(0.5 * (x0 + x1)) + f(x1));
    }
    if !coarse.is_finite() {
        return coarse;
    }
    let tol = rtol * coarse.abs() / PANELS as f64;
    let mut total = 0.0;
    for i in 0..PANELS {
        let (x0, x1) = (a + i as f64 * h, a + (i + 1) as f64 * h);
        let (f0, fm, f1) = (f(x0), f(0.5 * (x0 + x1)), f(x1));
        let whole = h / 6.0 * (f0 + 4.0 * fm + f1);
        total += simpson_rec(&f, x0, x1, f0, fm, f1, whole, tol, 40);
    }
    total
}

/// Cycles to grow the crack from `a0_m` to `af_m` [m] under constant-amplitude `load`.
/// Stops at the critical size if the law has a toughness and Kmax reaches it first.
/// Errors if a0/af are outside the specimen's range or the crack does not grow at a0.
pub fn life(law: &Law, spec: &Specimen, load: &Load, a0_m: f64, af_m: f64) -> Result<Life> {
    check_setup(law, spec, load)?;
    spec.alpha(a0_m)?;
    spec.alpha(af_m)?;
    if af_m < a0_m {
        return Err(param("af_m", af_m, &format!("[a0_m = {a0_m}, ...] m (final crack at least the initial one)")));
    }
    let (dk0, kmax0) = delta_k_kmax(spec, load, a0_m)?;
    if law.rate(dk0, load.r_ratio, kmax0) <= 0.0 {
        return Err(Error::Input(format!(
            "ΔK = {:.4} MPa·√m at a0 = {a0_m} m is at or below the law's threshold: the crack does not grow", dk0 / 1e6)));
    }
    let (a_end, fractured) = match critical_size(law, spec, load, a0_m, af_m)? {
        Some(ac) => (ac, true),
        None => (af_m, false),
    };
    let n = integrate(|a| dn_da(law, spec, load, a), a0_m, a_end, LIFE_RTOL);
    if !n.is_finite() {
        return Err(Error::Solver(format!("life integral from {a0_m} to {a_end} m is not finite")));
    }
    Ok(Life { cycles: n, a_end_m: a_end, fractured })
}

/// Cycles N(a_i) − N(a_0) at every crack size of the nondecreasing `a_m` into `out` (same
/// length). Sizes beyond fracture get +inf. Allocation-free.
pub fn life_curve(law: &Law, spec: &Specimen, load: &Load, a_m: &[f64], out: &mut [f64]) -> Result<()> {
    check_setup(law, spec, load)?;
    if a_m.len() != out.len() {
        return Err(Error::Input(format!("a has {} values but out has {}", a_m.len(), out.len())));
    }
    if a_m.is_empty() {
        return Ok(());
    }
    for (i, &a) in a_m.iter().enumerate() {
        spec.alpha(a)?;
        if i > 0 && a < a_m[i - 1] {
            return Err(Error::Input(format!("crack sizes must be nondecreasing: a[{i}] = {a} < a[{}] = {}", i - 1, a_m[i - 1])));
        }
    }
    let last = a_m[a_m.len() - 1];
    let a_crit = critical_size(law, spec, load, a_m[0], last)?.unwrap_or(f64::INFINITY);
    out[0] = if a_crit <= a_m[0] { f64::INFINITY } else { 0.0 };
    for i in 1..a_m.len() {
        let (lo, hi) = (a_m[i - 1], a_m[i]);
        if hi > a_crit || !out[i - 1].is_finite() {
            out[i] = f64::INFINITY;
            continue;
        }
        out[i] = out[i - 1] + integrate(|a| dn_da(law, spec, load, a), lo, hi, LIFE_RTOL);
        if out[i].is_nan() {
            out[i] = f64::INFINITY;
        }
    }
    Ok(())
}

/// Crack size [m] after `cycles` from `a0_m` (inverse of `life`); returns the critical size
/// (or the end of the specimen's range) with `fractured = true` if the crack gets there first.
pub fn crack_after(law: &Law, spec: &Specimen, load: &Load, a0_m: f64, cycles: f64) -> Result<Life> {
    if !(cycles.is_finite() && cycles >= 0.0) {
        return Err(param("cycles", cycles, "[0, inf)"));
    }
    let (_, a_max) = spec.a_range();
    let full = life(law, spec, load, a0_m, a_max)?;
    if cycles >= full.cycles {
        return Ok(Life { cycles: full.cycles, a_end_m: full.a_end_m, fractured: true });
    }
    let f = |a: f64| integrate(|x| dn_da(law, spec, load, x), a0_m, a, LIFE_RTOL) - cycles;
    let a = root_illinois(f, a0_m, full.a_end_m, 1e-12 * spec.width_m)?;
    Ok(Life { cycles, a_end_m: a, fractured: false })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::specimen::Geometry;
    use std::f64::consts::PI;

    #[test]
    fn a_law_spec_fills_the_nasgro_terms_it_omits_from_the_one_default_table() {
        let spec = LawSpec { law: "nasgro".into(), c: Some(1e-29), n: Some(3.0), q: Some(0.5), ..Default::default() };
        let Law::Nasgro { p, q, dk_th, k_crit, f_open, .. } = spec.build().unwrap() else { panic!("not nasgro") };
        assert_eq!((p, q, dk_th, k_crit, f_open), (0.0, 0.5, 0.0, 1e12, 0.0));
        let no_m = LawSpec { law: "paris".into(), c: Some(1e-11), ..Default::default() };
        assert!(no_m.build().unwrap_err().to_string().contains("`m`"));
        let bad = LawSpec { law: "walker".into(), ..Default::default() };
        assert!(bad.build().unwrap_err().to_string().contains("walker"));
        assert!(Load::new(1e3, LOAD_R_RATIO_RANGE.0 - 0.1).is_err() && Load::new(1e3, LOAD_R_RATIO_RANGE.0).is_ok());
    }

    fn mt() -> Specimen {
        Specimen::new(Geometry::MT, 0.1524, 2.54e-3).unwrap()
    }

    #[test]
    fn paris_life_matches_closed_form_for_griffith_crack() {
        // A wide M(T) panel: sec(πα/2) ≈ 1, so ΔK ≈ Δσ√(πa) and N has a closed form.
        let s = Specimen::new(Geometry::MT, 10.0, 0.01).unwrap();
        let load = Load::new(1e6, 0.0).unwrap();
        let sigma = 1e6 / (10.0 * 0.01);
        let (c, m) = (1e-11 * 1e-6f64.powf(3.0), 3.0);
        let law = Law::Paris { c, m };
        let (a0, af) = (0.01, 0.05);
        let n = life(&law, &s, &load, a0, af).unwrap().cycles;
        let k = c * (sigma * PI.sqrt()).powf(m);
        let exact = (a0.powf(1.0 - m / 2.0) - af.powf(1.0 - m / 2.0)) / (k * (m / 2.0 - 1.0));
        // secant correction at 2a/W ≤ 0.01 changes the rate by < 2e-4
        assert!((n / exact - 1.0).abs() < 5e-4 && n < exact, "{n} vs {exact}");
    }

    #[test]
    fn life_integral_is_accurate_against_a_fine_trapezoid() {
        let s = mt();
        let load = Load::from_delta_p(18680.0, 0.2).unwrap();
        let law = Law::Paris { c: 1e-11 * 1e-6f64.powf(3.2), m: 3.2 };
        let (a0, af) = (9e-3, 49.8e-3);
        let n = life(&law, &s, &load, a0, af).unwrap().cycles;
        let k = 200_000;
        let h = (af - a0) / k as f64;
        let mut trap = 0.0;
        for i in 0..k {
            let (x0, x1) = (a0 + i as f64 * h, a0 + (i + 1) as f64 * h);
            let f = |a| 1.0 / growth_per_cycle(&law, &s, &load, a).unwrap();
            trap += 0.5 * h * (f(x0) + f(x1));
        }
        assert!((n / trap - 1.0).abs() < 1e-8, "{n} vs {trap}");
        // and life_curve's last entry agrees with life()
        let a: Vec<f64> = (0..50).map(|i| a0 + (af - a0) * i as f64 / 49.0).collect();
        let mut out = vec![0.0; a.len()];
        life_curve(&law, &s, &load, &a, &mut out).unwrap();
        assert!((out[49] / n - 1.0).abs() < 1e-8);
        assert!(out.windows(2).all(|w| w[1] > w[0]));
    }

    #[test]
    fn forman_reaches_fracture_where_kmax_equals_kc() {
        let s = mt();
        let load = Load::from_delta_p(18680.0, 0.2).unwrap();
        let kc = 30e6;
        let law = Law::Forman { c: 1e-9 * 1e-6f64.powf(3.0) * 1e6, m: 3.0, kc };
        let l = life(&law, &s, &load, 9e-3, 60e-3).unwrap();
        assert!(l.fractured);
        let (_, kmax) = delta_k_kmax(&s, &load, l.a_end_m).unwrap();
        assert!((kmax / kc - 1.0).abs() < 1e-9);
        // the Forman rate exceeds Paris with the same C/((1-R)Kc) scaling as Kmax → Kc
        let r_lo = law.rate(5e6, 0.2, 6.25e6);
        let r_hi = law.rate(23.9e6, 0.2, 29.9e6);
        assert!(r_hi / r_lo > (23.9f64 / 5.0).powf(3.0) * 5.0);
    }

    #[test]
    fn nasgro_threshold_and_toughness_terms() {
        let law = Law::Nasgro { c: 1e-29, n: 3.0, p: 0.5, q: 0.5, dk_th: 3e6, k_crit: 60e6, f_open: 0.3 };
        law.validate().unwrap();
        assert_eq!(law.rate(2.9e6, 0.1, 3.2e6), 0.0);
        assert!(law.rate(50e6, 0.1, 61e6).is_infinite());
        // with p = q = 0 and f = R it is Paris on ΔK
        let plain = Law::Nasgro { c: 2e-29, n: 3.0, p: 0.0, q: 0.0, dk_th: 0.0, k_crit: 1e9, f_open: 0.1 };
        let paris = Law::Paris { c: 2e-29, m: 3.0 };
        assert!((plain.rate(10e6, 0.1, 11e6) / paris.rate(10e6, 0.1, 11e6) - 1.0).abs() < 1e-12);
        // below threshold at a0 is an error
        let s = mt();
        let load = Load::from_delta_p(1000.0, 0.1).unwrap();
        let e = life(&law, &s, &load, 9e-3, 20e-3).unwrap_err().to_string();
        assert!(e.contains("threshold"), "{e}");
    }

    #[test]
    fn newman_f_is_at_least_r_and_sensible() {
        let f0 = newman_f(0.0, 0.3, 2.0).unwrap();
        assert!(f0 > 0.2 && f0 < 0.5, "{f0}");
        assert!(newman_f(0.8, 0.3, 2.0).unwrap() >= 0.8);
        assert!(newman_f(1.0, 0.3, 2.0).is_err());
    }

    #[test]
    fn crack_after_inverts_life() {
        let s = mt();
        let load = Load::from_delta_p(18680.0, 0.2).unwrap();
        let law = Law::Paris { c: 1e-11 * 1e-6f64.powf(3.0), m: 3.0 };
        let n = life(&law, &s, &load, 10e-3, 30e-3).unwrap().cycles;
        let l = crack_after(&law, &s, &load, 10e-3, n).unwrap();
        assert!((l.a_end_m - 30e-3).abs() < 1e-9, "{}", l.a_end_m);
    }

    #[test]
    fn bad_inputs_name_the_field() {
        assert!(Law::Paris { c: -1.0, m: 3.0 }.validate().unwrap_err().to_string().contains("`c`"));
        assert!(Load::new(-5.0, 0.1).unwrap_err().to_string().contains("pmax_n"));
        assert!(Load::from_delta_p(100.0, 1.0).unwrap_err().to_string().contains("r_ratio"));
        let law = Law::Paris { c: 1e-29, m: 3.0 };
        let s = mt();
        let load = Load::new(1000.0, 0.1).unwrap();
        assert!(life(&law, &s, &load, 0.02, 0.01).unwrap_err().to_string().contains("af_m"));
        let mut out = [0.0; 2];
        assert!(life_curve(&law, &s, &load, &[0.02, 0.01], &mut out).is_err());
    }
}
