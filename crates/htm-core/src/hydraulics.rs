//! Valve, orifice and chamber laws (thesis eq. 2.2, 2.8-2.17, 2.20-2.22).

/// Smooth max(x, 0) of width `w` (regularises the edge opening sg() of eq. 2.17):
/// exact to O(w^2/x) away from 0, w/2 at x = 0, never negative.
#[inline]
pub fn smooth_opening(x: f64, w: f64) -> f64 {
    0.5 * (x + (x * x + w * w).sqrt())
}

/// Derivative of [`smooth_opening`] with respect to x.
#[inline]
pub fn smooth_opening_dx(x: f64, w: f64) -> f64 {
    0.5 * (1.0 + x / (x * x + w * w).sqrt())
}

/// Turbulent orifice flow `k * a * sign(dp) * sqrt(|dp|)` (eq. 2.14), regularised as
/// `k * a * dp / (dp^2 + dp_t^2)^(1/4)`: laminar (linear) below the transition drop `dp_t`,
/// smooth and with the right sign in every quadrant.
#[inline]
pub fn orifice_flow(k: f64, a: f64, dp: f64, dp_t: f64) -> f64 {
    k * a * dp / (dp * dp + dp_t * dp_t).sqrt().sqrt()
}

/// d(orifice_flow)/d(dp).
#[inline]
pub fn orifice_flow_ddp(k: f64, a: f64, dp: f64, dp_t: f64) -> f64 {
    let s = dp * dp + dp_t * dp_t;
    let q = s.sqrt().sqrt();
    k * a * (1.0 / q - 0.5 * dp * dp / (q * s))
}

/// Effective bulk modulus [Pa] at gauge pressure `p`.
/// `beta` rising by `slope` per pascal of gauge pressure (the tangent modulus of real oil), or
/// Eggerth (eq. 2.2) when `k1 > 0`; lowered by entrained air (isothermal
/// free air fraction `air` at atmospheric pressure); collapsing to 0 at absolute zero so that a
/// chamber pressure never goes below it.
#[derive(serde::Serialize, serde::Deserialize)] // engine snapshots (resume)
#[derive(Debug, Clone, Copy)]
pub struct BulkModulus {
    pub beta: f64,
    pub slope: f64,
    pub k1: f64,
    pub k2: f64,
    pub lambda: f64,
    pub air: f64,
    pub p_atm: f64,
    pub p_cav: f64,
}

impl BulkModulus {
    #[inline]
    pub fn at(&self, p: f64) -> f64 {
        let p_abs = p + self.p_atm;
        if p_abs <= 0.0 {
            return 0.0;
        }
        let mut b = if self.k1 > 0.0 {
            1.0 / (self.k1 + self.k2 * (p_abs / 1.0e5).powf(-self.lambda))
        } else {
            // never below half its zero-pressure value (in vacuum the collapse below takes over)
            (self.beta + self.slope * p).max(0.5 * self.beta)
        };
        if self.air > 0.0 {
            b /= 1.0 + b * self.air * self.p_atm / (p_abs * p_abs);
        }
        let r = p_abs / self.p_cav;
        let r4 = (r * r) * (r * r);
        b * r4 / (1.0 + r4)
    }

    /// [`at`](Self::at) and its derivative d(beta)/dp [Pa/Pa] at gauge pressure `p` (the
    /// plant's analytic Jacobian), by the same formulas.
    #[inline]
    pub fn at_and_slope(&self, p: f64) -> (f64, f64) {
        let p_abs = p + self.p_atm;
        if p_abs <= 0.0 {
            return (0.0, 0.0);
        }
        let (mut b, mut db) = if self.k1 > 0.0 {
            let q = (p_abs / 1.0e5).powf(-self.lambda);
            let g = self.k1 + self.k2 * q;
            // d(q)/dp = -lambda q / p_abs
            (1.0 / g, self.k2 * self.lambda * q / (p_abs * g * g))
        } else if self.beta + self.slope * p > 0.5 * self.beta {
            (self.beta + self.slope * p, self.slope)
        } else {
            (0.5 * self.beta, 0.0)
        };
        if self.air > 0.0 {
            // b / (1 + b c / p_abs^2), c = air * p_atm
            let c = self.air * self.p_atm;
            let d = 1.0 + b * self.air * self.p_atm / (p_abs * p_abs);
            let dd = c * db / (p_abs * p_abs) - 2.0 * c * b / (p_abs * p_abs * p_abs);
            (b, db) = (b / d, (db * d - b * dd) / (d * d));
        }
        let r = p_abs / self.p_cav;
        let r4 = (r * r) * (r * r);
        let s = r4 / (1.0 + r4);
        let ds = 4.0 * r * r * r / (self.p_cav * (1.0 + r4) * (1.0 + r4));
        (b * r4 / (1.0 + r4), db * s + b * ds)
    }
}

/// A monotone, odd-symmetric command-to-spool characteristic through given knots
/// (Fritsch-Carlson monotone cubic Hermite, continuous slope).
#[derive(serde::Serialize, serde::Deserialize)] // engine snapshots (resume)
#[derive(Debug, Clone, Default)]
pub struct ValveMap {
    c: Vec<f64>,
    s: Vec<f64>,
    d: Vec<f64>,
}

impl ValveMap {
    /// Knots must start at (0, 0) and increase strictly (checked by `Params::validate`).
    pub fn new(c: &[f64], s: &[f64]) -> Self {
        let n = c.len();
        if n < 2 {
            return ValveMap::default();
        }
        let delta: Vec<f64> = (0..n - 1).map(|i| (s[i + 1] - s[i]) / (c[i + 1] - c[i])).collect();
        let mut d = vec![0.0; n];
        // The map is odd, so the slope at 0 is the first secant (keeps it smooth through 0).
        d[0] = delta[0];
        d[n - 1] = delta[n - 2];
        for i in 1..n - 1 {
            d[i] = if delta[i - 1] * delta[i] <= 0.0 {
                0.0
            } else {
                // weighted harmonic mean keeps the interpolant monotone
                let (h0, h1) = (c[i] - c[i - 1], c[i + 1] - c[i]);
                let (w1, w2) = (2.0 * h1 + h0, h1 + 2.0 * h0);
                (w1 + w2) / (w1 / delta[i - 1] + w2 / delta[i])
            };
        }
        ValveMap { c: c.to_vec(), s: s.to_vec(), d }
    }

    pub fn is_linear(&self) -> bool {
        self.c.is_empty()
    }

    /// Spool position [V equivalent] for command `u` [V] (after bias and dead band).
    pub fn eval(&self, u: f64) -> f64 {
        if self.c.is_empty() {
            return u;
        }
        let x = u.abs();
        let n = self.c.len();
        let y = if x >= self.c[n - 1] {
            self.s[n - 1] + self.d[n - 1] * (x - self.c[n - 1])
        } else {
            let i = self.c.partition_point(|&ci| ci <= x) - 1;
            let h = self.c[i + 1] - self.c[i];
            let t = (x - self.c[i]) / h;
            let (t2, t3) = (t * t, t * t * t);
            (2.0 * t3 - 3.0 * t2 + 1.0) * self.s[i]
                + (t3 - 2.0 * t2 + t) * h * self.d[i]
                + (-2.0 * t3 + 3.0 * t2) * self.s[i + 1]
                + (t3 - t2) * h * self.d[i + 1]
        };
        y.copysign(u)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn orifice_sign_and_continuity_in_every_quadrant() {
        let (k, dpt) = (1e-7, 1e5);
        for &a in &[0.0, 0.01, 1.0, 10.0] {
            for &dp in &[-1e7, -1e5, -1.0, 0.0, 1.0, 1e5, 1e7] {
                let q = orifice_flow(k, a, dp, dpt);
                assert!(q * dp >= 0.0, "flow follows the pressure drop");
                assert_eq!(q, -orifice_flow(k, a, -dp, dpt));
            }
            // continuity through dp = 0
            let (ql, qr) = (orifice_flow(k, a, -1e-3, dpt), orifice_flow(k, a, 1e-3, dpt));
            assert!((qr - ql).abs() <= k * a * 1e-3);
        }
        // turbulent limit: sqrt law far above the transition
        let q = orifice_flow(1.0, 1.0, 1e8, 1e5);
        assert!((q / 1e4 - 1.0).abs() < 1e-6);
        // derivative matches a central difference
        for &dp in &[-3e6, -2e4, 0.0, 5e4, 7e6] {
            let h = 1.0;
            let fd = (orifice_flow(1.0, 2.0, dp + h, dpt) - orifice_flow(1.0, 2.0, dp - h, dpt)) / (2.0 * h);
            assert!((fd - orifice_flow_ddp(1.0, 2.0, dp, dpt)).abs() < 1e-6 * fd.abs().max(1e-3));
        }
    }

    #[test]
    fn edge_opening_is_positive_smooth_max() {
        for &x in &[-1.0, -0.01, 0.0, 0.01, 1.0] {
            let o = smooth_opening(x, 0.005);
            assert!(o > 0.0 && o >= x && (o - x.max(0.0)).abs() <= 0.0025 + 1e-12);
        }
    }

    #[test]
    fn bulk_modulus_vanishes_at_absolute_zero_and_is_nominal_at_working_pressure() {
        let b = BulkModulus { beta: 1.2e9, slope: 0.0, k1: 0.0, k2: 0.0, lambda: 0.0, air: 0.0, p_atm: 101325.0, p_cav: 2e4 };
        assert_eq!(b.at(-101325.0), 0.0);
        assert!((b.at(1e7) / 1.2e9 - 1.0).abs() < 1e-9);
        assert!(b.at(-95000.0) < 0.1 * 1.2e9);
        let air = BulkModulus { air: 0.01, ..b };
        assert!(air.at(1e5) < 0.5 * b.at(1e5) && air.at(2e7) > 0.95 * b.at(2e7));
        let stiffening = BulkModulus { slope: 8.0, ..b };
        assert!((stiffening.at(2e7) / (1.2e9 + 8.0 * 2e7) - 1.0).abs() < 1e-9 && (stiffening.at(0.0) / b.at(0.0) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn the_bulk_modulus_slope_matches_differences_in_every_regime() {
        let b = BulkModulus { beta: 1.2e9, slope: 7.0, k1: 0.0, k2: 0.0, lambda: 0.0, air: 0.0, p_atm: 101325.0, p_cav: 2e4 };
        let eggerth = BulkModulus { k1: 1.0 / 1.6e9, k2: 1e-10, lambda: 1.0, ..b };
        for m in [b, BulkModulus { air: 0.01, ..b }, eggerth, BulkModulus { air: 0.02, ..eggerth }, BulkModulus { beta: 1e9, slope: 5e3, ..b }] {
            for p in [-9.9e4, -9e4, -5e4, 0.0, 3e5, 2e6, 1.5e7, 3e7] {
                let (v, d) = m.at_and_slope(p);
                assert_eq!(v, m.at(p));
                let h = 1e-5 * (p + m.p_atm);
                let fd = (m.at(p + h) - m.at(p - h)) / (2.0 * h);
                assert!((d - fd).abs() <= 1e-5 * fd.abs() + 1e-9 * m.beta / m.p_atm, "{m:?} at {p}: {d} vs {fd}");
            }
        }
    }

    #[test]
    fn valve_map_is_odd_monotone_and_hits_its_knots() {
        let m = ValveMap::new(&[0.0, 0.2, 0.5, 1.0, 10.0], &[0.0, 0.05, 0.3, 0.9, 8.0]);
        for (c, s) in [(0.2, 0.05), (0.5, 0.3), (1.0, 0.9), (10.0, 8.0)] {
            assert!((m.eval(c) - s).abs() < 1e-12);
            assert!((m.eval(-c) + s).abs() < 1e-12);
        }
        let mut last = m.eval(-10.0);
        for i in -1000..=1000 {
            let v = m.eval(i as f64 * 0.01);
            assert!(v >= last - 1e-15);
            last = v;
        }
    }
}
