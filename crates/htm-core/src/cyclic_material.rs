//! The virtual life specimen: a smooth round bar whose material follows the cyclic
//! Ramberg–Osgood curve with Masing loops (optional cyclic hardening or softening), accumulates
//! damage to crack initiation by Basquin / Coffin–Manson (Morrow mean stress) with a per-specimen
//! lognormal life factor, and then grows a semicircular surface crack by a crack-growth law
//! (`crack::Law`) that lowers its tensile stiffness until it separates.
//!
//! This is the rig's hidden truth: the controller sees only the load cell, the extensometer and
//! the piston position. `true_life` gives the life the same model predicts without a controller,
//! the reference the end criteria are judged against.
use crate::crack::Law;
use crate::error::{Error, Result};

/// Geometry factor of a semicircular surface crack in a round bar (deepest point), ΔK = Y·Δσ·√(πa).
pub const SURFACE_CRACK_Y: f64 = 0.73;
/// Tensile stiffness left after separation (fraction of the intact bar's): the halves touch
/// only in compression.
pub const SEPARATED_TENSION: f64 = 1e-3;

/// The cyclic and fatigue properties of a material (SI).
#[derive(serde::Serialize, serde::Deserialize, Debug, Clone, Copy, PartialEq)]
pub struct CyclicMaterial {
    pub e_pa: f64,
    /// cyclic strength coefficient K′ [Pa] and exponent n′: ε_a = σ_a/E + (σ_a/K′)^(1/n′)
    pub k_prime_pa: f64,
    pub n_prime: f64,
    /// Basquin: σ_f′ [Pa], b; Coffin–Manson: ε_f′, c (ε_a = σ_f′/E·(2N)^b + ε_f′·(2N)^c)
    pub sigma_f_pa: f64,
    pub b: f64,
    pub eps_f: f64,
    pub c: f64,
    /// cyclic transient: K′ starts at (1 + h)·K′ and tends to K′ over `transient_cycles`
    /// (h > 0 softens, h < 0 hardens, 0 = stable from the first cycle)
    pub transient: f64,
    pub transient_cycles: f64,
}

impl Default for CyclicMaterial {
    /// A normalised low-alloy steel (SAE 4340-like, Dowling's tables rounded).
    fn default() -> Self {
        CyclicMaterial {
            e_pa: 200e9, k_prime_pa: 1200e6, n_prime: 0.14, sigma_f_pa: 1600e6, b: -0.09, eps_f: 0.6, c: -0.6,
            transient: 0.0, transient_cycles: 100.0,
        }
    }
}

fn param(field: &str, value: f64, allowed: &str) -> Error {
    Error::Parameter { field: field.into(), value, allowed: allowed.into() }
}

impl CyclicMaterial {
    pub fn validate(&self) -> Result<()> {
        let pos = [("e_pa", self.e_pa), ("k_prime_pa", self.k_prime_pa), ("sigma_f_pa", self.sigma_f_pa), ("eps_f", self.eps_f),
            ("transient_cycles", self.transient_cycles)];
        for (k, v) in pos {
            if !(v.is_finite() && v > 0.0) {
                return Err(param(k, v, "(0, inf)"));
            }
        }
        if !(self.n_prime > 0.01 && self.n_prime < 1.0) {
            return Err(param("n_prime", self.n_prime, "(0.01, 1)"));
        }
        if !(self.b < 0.0 && self.b > -0.5) {
            return Err(param("b", self.b, "(-0.5, 0)"));
        }
        if !(self.c < 0.0 && self.c > -1.5) {
            return Err(param("c", self.c, "(-1.5, 0)"));
        }
        if !(self.transient > -0.9 && self.transient < 2.0) {
            return Err(param("transient", self.transient, "(-0.9, 2)"));
        }
        Ok(())
    }

    /// K′ at cycle `n` (the transient decays exponentially).
    #[inline]
    pub fn k_at(&self, n: f64) -> f64 {
        self.k_prime_pa * (1.0 + self.transient * (-n / self.transient_cycles).exp())
    }

    /// Strain amplitude of the cyclic curve at stress amplitude `sa` [Pa] (K′ = `k`).
    #[inline]
    pub fn strain_of(&self, sa: f64, k: f64) -> f64 {
        sa / self.e_pa + (sa / k).powf(1.0 / self.n_prime)
    }

    /// Stress amplitude [Pa] of the cyclic curve at strain amplitude `ea` ≥ 0, and dσ/dε there.
    #[inline]
    pub fn stress_of(&self, ea: f64, k: f64) -> (f64, f64) {
        if ea <= 0.0 {
            return (0.0, self.e_pa);
        }
        let (e, inv_n) = (self.e_pa, 1.0 / self.n_prime);
        // start below the root (elastic or plastic bound, whichever is smaller) and Newton up
        let mut s = (e * ea).min(k * ea.powf(self.n_prime));
        let mut d = 1.0 / e;
        for _ in 0..40 {
            let p = (s / k).powf(inv_n);
            let f = s / e + p - ea;
            d = 1.0 / e + inv_n * p / s.max(1e-30);
            let ds = f / d;
            s -= ds;
            if s <= 0.0 {
                s = 1e-9 * e * ea;
            }
            if ds.abs() <= 1e-13 * s {
                break;
            }
        }
        (s, 1.0 / d)
    }

    /// Cycles to crack initiation at strain amplitude `ea` and mean stress `sm` [Pa] (Morrow:
    /// σ_f′ − σ_m in the elastic term), solved in log(2N).
    pub fn initiation_cycles(&self, ea: f64, sm: f64) -> f64 {
        if !(ea > 0.0) {
            return f64::INFINITY;
        }
        let sf = (self.sigma_f_pa - sm).max(1e-3 * self.sigma_f_pa);
        let f = |x: f64| sf / self.e_pa * (x * self.b).exp() + self.eps_f * (x * self.c).exp() - ea;
        let (mut lo, mut hi) = (0.0f64, 80.0f64); // 2N in [1, e^80]
        if f(lo) <= 0.0 {
            return 0.5;
        }
        if f(hi) >= 0.0 {
            return f64::INFINITY;
        }
        for _ in 0..100 {
            let mid = 0.5 * (lo + hi);
            if f(mid) > 0.0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (0.5 * (lo + hi)).exp()
    }
}

/// Rate-independent Masing model with memory: a stack of reversal points; a branch from reversal
/// (ε_r, σ_r) follows Δε = Δσ/E + 2(Δσ/2K′)^(1/n′); closing a loop returns to the branch it
/// left (the skeleton curve after the first loading).
#[derive(serde::Serialize, serde::Deserialize, Debug, Clone, Default)]
pub struct Masing {
    rev: Vec<(f64, f64)>,
    dir: f64,
    pub eps: f64,
    pub sig: f64,
}

impl Masing {
    /// Stack depth left after moving to `eps` (loops closed popped) and the direction.
    fn top(&self, eps: f64) -> (usize, f64) {
        let d = eps - self.eps;
        let mut dir = self.dir;
        let mut n = self.rev.len();
        if d != 0.0 && d.signum() != dir {
            if dir != 0.0 {
                n += 1; // a new reversal at the current point
            }
            dir = d.signum();
        }
        // the stack with the virtual new reversal: entries 0..n, entry n-1 may be (self.eps, self.sig)
        let at = |i: usize| if i < self.rev.len() { self.rev[i].0 } else { self.eps };
        loop {
            if n >= 2 && (eps - at(n - 2)) * dir >= 0.0 {
                n -= 2;
            } else if n == 1 && dir * eps >= at(0).abs() && at(0) * dir < 0.0 {
                n = 0;
            } else {
                break;
            }
        }
        (n, dir)
    }

    /// Stress and tangent at strain `eps` without moving there.
    pub fn eval(&self, m: &CyclicMaterial, k: f64, eps: f64) -> (f64, f64) {
        let (n, dir) = self.top(eps);
        if n == 0 {
            let (s, t) = m.stress_of(eps.abs(), k);
            return (s * eps.signum(), t);
        }
        let (er, sr) = if n - 1 < self.rev.len() { self.rev[n - 1] } else { (self.eps, self.sig) };
        let (s, t) = m.stress_of(0.5 * (eps - er).abs(), k);
        let _ = dir;
        (sr + 2.0 * s * (eps - er).signum(), t)
    }

    /// The same strain history under another K′ (cyclic hardening or softening): the reversal
    /// points' stresses replayed along their branches, so the loop stays the Masing loop of the
    /// new curve (a plain change of K′ under stored stresses would make it drift off centre).
    pub fn replay(&mut self, m: &CyclicMaterial, k: f64) {
        let mut prev: Option<(f64, f64)> = None;
        for r in self.rev.iter_mut() {
            r.1 = match prev {
                None => m.stress_of(r.0.abs(), k).0 * r.0.signum(),
                Some((e0, s0)) => s0 + 2.0 * m.stress_of(0.5 * (r.0 - e0).abs(), k).0 * (r.0 - e0).signum(),
            };
            prev = Some(*r);
        }
        self.sig = match prev {
            None => m.stress_of(self.eps.abs(), k).0 * self.eps.signum(),
            Some((e0, s0)) => s0 + 2.0 * m.stress_of(0.5 * (self.eps - e0).abs(), k).0 * (self.eps - e0).signum(),
        };
    }

    /// Move to strain `eps`; returns the stress.
    pub fn update(&mut self, m: &CyclicMaterial, k: f64, eps: f64) -> f64 {
        let (n, dir) = self.top(eps);
        let (s, _) = self.eval(m, k, eps);
        if n > self.rev.len() {
            self.rev.push((self.eps, self.sig));
        } else {
            self.rev.truncate(n);
        }
        self.dir = dir;
        self.eps = eps;
        self.sig = s;
        s
    }
}

/// Geometry and hidden state of the virtual round bar.
#[derive(Debug, Clone)]
pub struct CyclicSpecimen {
    pub material: CyclicMaterial,
    pub diameter_m: f64,
    /// crack size at initiation [m]
    pub a_init_m: f64,
    pub law: Law,
    pub k_ic_pa_sqrt_m: f64,
    /// per-specimen factor on the initiation life (10^(σ·z))
    pub life_factor: f64,
    pub masing: Masing,
    /// cycles the material has seen (the transient's clock), damage, crack depth (0 = none)
    pub n: f64,
    pub damage: f64,
    pub a_m: f64,
    pub separated: bool,
    /// true-state milestones [cycles]: initiation, tensile stiffness at 90 % and 50 %, separation
    pub n_init: Option<f64>,
    pub n_phi10: Option<f64>,
    pub n_phi50: Option<f64>,
    pub n_sep: Option<f64>,
    /// this cycle's true extremes (ε_max, ε_min, σ_max, σ_min), and the last closed loop
    ext: [f64; 4],
    last: Option<(f64, f64, f64)>,
}

const EXT0: [f64; 4] = [f64::MIN, f64::MAX, f64::MIN, f64::MAX];

impl CyclicSpecimen {
    pub fn new(material: CyclicMaterial, diameter_m: f64, a_init_m: f64, law: Law, k_ic_pa_sqrt_m: f64, life_factor: f64) -> Result<Self> {
        material.validate().map_err(|e| within("material", e))?;
        if !(diameter_m > 0.0 && diameter_m < 1.0) {
            return Err(param("specimen.diameter_m", diameter_m, "(0, 1) m"));
        }
        if !(a_init_m > 0.0 && a_init_m < 0.2 * diameter_m) {
            return Err(param("specimen.a_init_m", a_init_m, &format!("(0, {}) m (a fifth of the diameter)", 0.2 * diameter_m)));
        }
        if !(life_factor.is_finite() && life_factor > 0.0) {
            return Err(param("specimen.life_factor", life_factor, "(0, inf)"));
        }
        if !(k_ic_pa_sqrt_m > 0.0) {
            return Err(param("material.fracture_toughness_pa_sqrt_m", k_ic_pa_sqrt_m, "(0, inf) Pa·√m"));
        }
        law.validate().map_err(|e| within("law", e))?;
        Ok(CyclicSpecimen {
            material, diameter_m, a_init_m, law, k_ic_pa_sqrt_m, life_factor, masing: Masing::default(), n: 0.0, damage: 0.0,
            a_m: 0.0, separated: false, n_init: None, n_phi10: None, n_phi50: None, n_sep: None, ext: EXT0, last: None,
        })
    }

    pub fn area_m2(&self) -> f64 {
        0.25 * std::f64::consts::PI * self.diameter_m * self.diameter_m
    }

    /// Cracked fraction of the section (semicircle of depth a): the tensile stiffness lost.
    pub fn phi(a_m: f64, area: f64) -> f64 {
        (0.5 * std::f64::consts::PI * a_m * a_m / area).min(1.0)
    }

    fn tension_factor(&self) -> f64 {
        if self.separated { SEPARATED_TENSION } else { 1.0 - Self::phi(self.a_m, self.area_m2()) }
    }

    /// Force [N] and dF/dε [N] at gauge strain `eps`, without moving there.
    pub fn force(&self, eps: f64) -> (f64, f64) {
        let k = self.material.k_at(self.n);
        let (s, t) = self.masing.eval(&self.material, k, eps);
        let a = self.area_m2();
        let f = if s > 0.0 { self.tension_factor() } else { 1.0 };
        (a * s * f, a * t * f)
    }

    /// Move to gauge strain `eps`; returns the force [N].
    pub fn strain_to(&mut self, eps: f64) -> f64 {
        let k = self.material.k_at(self.n);
        let s = self.masing.update(&self.material, k, eps);
        let e = &mut self.ext;
        e[0] = e[0].max(eps);
        e[1] = e[1].min(eps);
        e[2] = e[2].max(s);
        e[3] = e[3].min(s);
        let f = if s > 0.0 { self.tension_factor() } else { 1.0 };
        self.area_m2() * s * f
    }

    /// The true loop of the cycle just ended: (ε_a, σ_max, σ_min).
    pub fn last_loop(&self) -> Option<(f64, f64, f64)> {
        self.last
    }

    /// Damage or crack growth per cycle at loop (ε_a, σ_max, σ_min) and crack depth `a`: (dD/dN, da/dN).
    pub fn rates(&self, ea: f64, smax: f64, smin: f64, a: f64) -> (f64, f64) {
        if a <= 0.0 {
            let ni = self.material.initiation_cycles(ea, 0.5 * (smax + smin)) * self.life_factor;
            return (1.0 / ni, 0.0);
        }
        // the net section carries the tension: the crack sees the nominal stress over the ligament
        let lig = 1.0 - Self::phi(a, self.area_m2());
        let smax_net = smax / lig.max(1e-3);
        let smin_net = if smin > 0.0 { smin / lig.max(1e-3) } else { smin };
        let rootpa = (std::f64::consts::PI * a).sqrt();
        let kmax = SURFACE_CRACK_Y * smax_net.max(0.0) * rootpa;
        let r = if smax_net > 0.0 { smin_net / smax_net } else { 0.0 };
        // E647 for R < 0: ΔK = Kmax
        let dk = if r >= 0.0 { SURFACE_CRACK_Y * (smax_net - smin_net) * rootpa } else { kmax };
        if kmax >= self.k_ic_pa_sqrt_m {
            return (0.0, f64::INFINITY);
        }
        (0.0, self.law.rate(dk, r.clamp(-1.0, 0.99), kmax))
    }

    /// Advance the hidden state by `cycles` cycles of loop (ε_a, σ_max, σ_min): damage to
    /// initiation, then crack growth (midpoint rule), milestones and separation. Returns the
    /// cycles actually consumed (a jump stops at initiation).
    pub fn advance(&mut self, cycles: f64, ea: f64, smax: f64, smin: f64) -> f64 {
        let used = self.grow(cycles, ea, smax, smin);
        if self.material.transient != 0.0 {
            let k = self.material.k_at(self.n);
            self.masing.replay(&self.material, k);
        }
        used
    }

    fn grow(&mut self, cycles: f64, ea: f64, smax: f64, smin: f64) -> f64 {
        let area = self.area_m2();
        let n0 = self.n;
        let mut left = cycles;
        if self.a_m <= 0.0 {
            let (dd, _) = self.rates(ea, smax, smin, 0.0);
            let need = (1.0 - self.damage) / dd;
            if need > left {
                self.damage += left * dd;
                self.n += left;
                return cycles;
            }
            self.damage = 1.0;
            let used = need.max(0.0).ceil().min(left);
            self.n += used;
            self.a_m = self.a_init_m;
            self.n_init = Some(self.n);
            return used;
        }
        if self.separated {
            self.n += left;
            return cycles;
        }
        while left > 0.0 {
            let (_, r0) = self.rates(ea, smax, smin, self.a_m);
            // sub-steps of at most 2 % growth (midpoint rule)
            let h = if r0 > 0.0 && r0.is_finite() { left.min((0.02 * self.a_m / r0).max(1.0)) } else { left };
            let (_, r1) = self.rates(ea, smax, smin, self.a_m + 0.5 * h * r0);
            let a1 = self.a_m + h * r1;
            let a1 = if a1.is_finite() { a1 } else { f64::INFINITY };
            let p0 = Self::phi(self.a_m, area);
            let p1 = Self::phi(a1.min(self.diameter_m), area);
            let n_at = |p: f64| n0 + (cycles - left) + h * ((p - p0) / (p1 - p0)).clamp(0.0, 1.0);
            if p0 < 0.1 && p1 >= 0.1 {
                self.n_phi10 = Some(n_at(0.1));
            }
            if p0 < 0.5 && p1 >= 0.5 {
                self.n_phi50 = Some(n_at(0.5));
            }
            self.a_m = a1;
            left -= h;
            if !a1.is_finite() || p1 >= 0.9 || self.rates(ea, smax, smin, a1.min(self.diameter_m)).1.is_infinite() {
                self.separated = true;
                self.n_sep = Some(self.n + cycles - left);
                self.n_phi50.get_or_insert(self.n + cycles - left);
                self.n_phi10.get_or_insert(self.n + cycles - left);
                self.a_m = self.a_m.min(self.diameter_m);
                break;
            }
        }
        self.n += cycles;
        cycles
    }

    /// A cycle ended: the damage and growth of its true loop; clears the extremes.
    pub fn end_cycle(&mut self) {
        let e = self.ext;
        self.last = (e[0] > f64::MIN).then(|| (0.5 * (e[0] - e[1]), e[2], e[3]));
        if let Some((ea, smax, smin)) = self.last {
            self.advance(1.0, ea, smax, smin);
        } else {
            self.n += 1.0;
        }
        self.ext = EXT0;
    }
}

fn within(section: &str, e: Error) -> Error {
    match e {
        Error::Parameter { field, value, allowed } => Error::Parameter { field: format!("{section}.{field}"), value, allowed },
        other => other,
    }
}

/// The virtual truth without a controller: cycles to initiation, to half the tensile stiffness
/// (φ = 0.5) and to separation of a specimen with factor `life_factor` under a stable loop of
/// strain amplitude `ea` (R_ε = −1), integrating the crack in steps of at most 1 % of its depth.
/// Returns (N_init, N_50, N_sep).
pub fn true_life(s: &CyclicSpecimen, ea: f64, smax: f64, smin: f64) -> (f64, f64, f64) {
    let mut v = s.clone();
    v.n = 0.0;
    v.damage = 0.0;
    v.a_m = 0.0;
    v.separated = false;
    v.advance(1e15, ea, smax, smin);
    let ni = v.n_init.unwrap_or(f64::INFINITY);
    if !ni.is_finite() {
        return (ni, ni, ni);
    }
    let mut guard = 0;
    while !v.separated && guard < 100_000 {
        let (_, r) = v.rates(ea, smax, smin, v.a_m);
        let h = if r > 0.0 && r.is_finite() { (0.005 * v.a_m / r).max(1.0) } else { 1.0 };
        v.advance(h, ea, smax, smin);
        guard += 1;
    }
    (ni, v.n_phi50.unwrap_or(f64::INFINITY), v.n_sep.unwrap_or(f64::INFINITY))
}

/// Per-specimen life factor from a standard normal draw `z`: 10^(σ·z).
pub fn life_factor(sigma_log10: f64, z: f64) -> f64 {
    10f64.powf(sigma_log10 * z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn masing_loop_is_the_doubled_cyclic_curve_and_closes() {
        let m = CyclicMaterial::default();
        let k = m.k_prime_pa;
        let mut s = Masing::default();
        let ea = 0.006;
        for c in 0..3 {
            for i in 0..=400 {
                let x = i as f64 / 400.0 * 2.0 * std::f64::consts::PI;
                s.update(&m, k, ea * x.sin());
            }
            let (sa, _) = m.stress_of(ea, k);
            // at the peak the stress is the cyclic curve's
            let (sp, _) = s.eval(&m, k, ea);
            assert!((sp / sa - 1.0).abs() < 1e-6, "cycle {c}: {sp} vs {sa}");
            assert!(s.rev.len() <= 2, "memory closes loops: {:?}", s.rev);
        }
        assert!((m.strain_of(m.stress_of(0.01, k).0, k) - 0.01).abs() < 1e-12);
    }

    #[test]
    fn initiation_follows_the_strain_life_curve() {
        let m = CyclicMaterial::default();
        for n in [1e2f64, 1e4, 1e6] {
            let ea = m.sigma_f_pa / m.e_pa * (2.0 * n).powf(m.b) + m.eps_f * (2.0 * n).powf(m.c);
            assert!((m.initiation_cycles(ea, 0.0) / n - 1.0).abs() < 1e-9);
        }
    }
}
