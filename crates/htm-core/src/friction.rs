//! Stribeck friction with the thesis's smoothed sign (eq. 3.2, 3.19) or a sign that saturates
//! sooner (tanh), plus the asymmetric and pressure-dependent variants named in EFFECTS.md.

/// Smoothed sign `sig(v) = v / (|v| + eps)` (thesis eq. 3.19): continuous through v = 0.
#[inline]
pub fn sig(v: f64, eps: f64) -> f64 {
    v / (v.abs() + eps)
}

/// The smoothed sign of form `shape`: 0 the thesis's `sig`, 1 `tanh(v/eps)`, between the blend.
#[inline]
pub fn smoothed_sign(v: f64, eps: f64, shape: f64) -> f64 {
    let s0 = sig(v, eps);
    if shape == 0.0 {
        return s0;
    }
    (1.0 - shape) * s0 + shape * (v / eps).tanh()
}

/// d/dv of [`smoothed_sign`].
#[inline]
pub fn smoothed_sign_slope(v: f64, eps: f64, shape: f64) -> f64 {
    let d = v.abs() + eps;
    let ds0 = eps / (d * d);
    if shape == 0.0 {
        return ds0;
    }
    let th = (v / eps).tanh();
    (1.0 - shape) * ds0 + shape * (1.0 - th * th) / eps
}

/// Friction parameters, SI.
#[derive(serde::Serialize, serde::Deserialize)] // engine snapshots (resume)
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Friction {
    /// viscous coefficient B_v [N s/m]
    pub viscous_n_s_m: f64,
    /// Coulomb force for positive velocity [N]
    pub coulomb_pos_n: f64,
    /// Coulomb force for negative velocity [N]
    pub coulomb_neg_n: f64,
    /// static (breakaway excess) force F_s [N]
    pub static_n: f64,
    /// Stribeck velocity C_s [m/s]
    pub stribeck_m_s: f64,
    /// smoothing velocity eps of sig() [m/s]
    pub smoothing_m_s: f64,
    /// form of the smoothed sign (0: thesis, 1: tanh; [`smoothed_sign`])
    pub sign_shape: f64,
    /// Coulomb growth with chamber pressure sum [N/Pa]
    pub pressure_coeff_n_per_pa: f64,
}

impl From<&crate::params::Params> for Friction {
    fn from(p: &crate::params::Params) -> Self {
        Friction {
            viscous_n_s_m: p.friction_viscous_n_s_m,
            coulomb_pos_n: p.friction_coulomb_pos_n,
            coulomb_neg_n: p.friction_coulomb_neg_n,
            static_n: p.friction_static_n,
            stribeck_m_s: p.friction_stribeck_m_s,
            smoothing_m_s: p.friction_smoothing_m_s,
            sign_shape: p.friction_sign_shape,
            pressure_coeff_n_per_pa: p.friction_pressure_coeff_n_per_pa,
        }
    }
}

impl Friction {
    /// The smoothed sign of `v` in this friction's form ([`smoothed_sign`]).
    #[inline]
    pub fn sign(&self, v: f64) -> f64 {
        smoothed_sign(v, self.smoothing_m_s, self.sign_shape)
    }

    /// Its slope d/dv ([`smoothed_sign_slope`]; the Jacobian's, not the right-hand side's).
    #[inline]
    pub fn sign_slope(&self, v: f64) -> f64 {
        smoothed_sign_slope(v, self.smoothing_m_s, self.sign_shape)
    }

    /// Friction force opposing motion [N] at velocity `v` [m/s] and chamber pressure sum
    /// `p_sum` = p_a + p_b [Pa].
    #[inline]
    pub fn force(&self, v: f64, p_sum: f64) -> f64 {
        let s = self.sign(v);
        // The Coulomb level of the direction of motion (a seal grips harder one way as soon as
        // it slides that way), through the smoothed sign: continuous, with a kink at v = 0 when
        // the two levels differ.
        let level = if v >= 0.0 { self.coulomb_pos_n } else { self.coulomb_neg_n };
        let coulomb = level + self.pressure_coeff_n_per_pa * p_sum;
        let stribeck = self.static_n * (-v.abs() / self.stribeck_m_s).exp();
        self.viscous_n_s_m * v + s * (coulomb + stribeck)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn thesis() -> Friction {
        Friction {
            viscous_n_s_m: 5017.35,
            coulomb_pos_n: 792.33,
            coulomb_neg_n: 792.33,
            static_n: 102.61,
            stribeck_m_s: 0.01,
            smoothing_m_s: 1e-3,
            sign_shape: 0.0,
            pressure_coeff_n_per_pa: 0.0,
        }
    }

    #[test]
    fn the_sign_forms_take_their_levels_and_slopes() {
        let eps = 2e-4;
        for v in [-3e-3, -2e-4, -1e-5, 0.0, 1e-5, 2e-4, 1e-3, 0.05] {
            // form 0 is the thesis's sig(); form 1 is tanh(v/eps); the blend is linear in the form
            assert_eq!(smoothed_sign(v, eps, 0.0), sig(v, eps));
            assert!((smoothed_sign(v, eps, 1.0) - (v / eps).tanh()).abs() < 1e-15);
            let mid = 0.5 * (smoothed_sign(v, eps, 0.0) + smoothed_sign(v, eps, 1.0));
            assert!((smoothed_sign(v, eps, 0.5) - mid).abs() < 1e-15);
            // the slope is the derivative (central difference)
            for k in [0.0, 0.3, 1.0] {
                let h = 1e-9;
                let fd = (smoothed_sign(v + h, eps, k) - smoothed_sign(v - h, eps, k)) / (2.0 * h);
                let ds = smoothed_sign_slope(v, eps, k);
                assert!((fd - ds).abs() <= 1e-5 * ds.abs().max(1.0), "v {v} form {k}: {fd} vs {ds}");
            }
        }
        // tanh takes 76 % of the level at eps where the thesis's form takes half, 99.9 % at 4 eps (80 %)
        assert!((smoothed_sign(eps, eps, 1.0) - 0.7616).abs() < 1e-4 && smoothed_sign(eps, eps, 0.0) == 0.5);
        assert!(smoothed_sign(4.0 * eps, eps, 1.0) > 0.999 && (smoothed_sign(4.0 * eps, eps, 0.0) - 0.8).abs() < 1e-12);
        let mut f = thesis();
        f.sign_shape = 1.0;
        assert!((f.force(1e-3, 0.0) - (5017.35e-3 + (1e-3f64 / 1e-3).tanh() * (792.33 + 102.61 * (-0.1f64).exp()))).abs() < 1e-9);
    }

    #[test]
    fn friction_is_odd_and_continuous_through_zero() {
        let f = thesis();
        for v in [1e-6, 1e-4, 1e-3, 0.01, 0.1, 0.5] {
            assert!((f.force(v, 0.0) + f.force(-v, 0.0)).abs() < 1e-9);
        }
        assert_eq!(f.force(0.0, 0.0), 0.0);
        // the smoothed sign makes friction a steep but finite damper through zero
        assert!((f.force(1e-9, 0.0) - f.force(-1e-9, 0.0)).abs() < 2e-9 * 1e6);
    }

    #[test]
    fn friction_matches_eq_3_20_at_speed() {
        let f = thesis();
        let v: f64 = 0.3;
        let expect = 5017.35 * v + (v / (v + 1e-3)) * (792.33 + 102.61 * (-v / 0.01).exp());
        assert!((f.force(v, 0.0) - expect).abs() < 1e-9);
    }

    #[test]
    fn asymmetric_coulomb_takes_each_level_by_direction() {
        let mut f = thesis();
        f.coulomb_pos_n = 900.0;
        f.coulomb_neg_n = 500.0;
        f.viscous_n_s_m = 0.0;
        f.static_n = 0.0;
        assert!((f.force(1.0, 0.0) - 900.0).abs() < 2.0);
        assert!((f.force(-1.0, 0.0) + 500.0).abs() < 2.0);
        // at creep speed too: half the level of each direction where sig() is one half
        let eps = f.smoothing_m_s;
        assert!((f.force(eps, 0.0) - 450.0).abs() < 1e-9);
        assert!((f.force(-eps, 0.0) + 250.0).abs() < 1e-9);
        assert_eq!(f.force(0.0, 0.0), 0.0);
    }
}
