//! Controllers that compute one valve command per sample from the measurements.
use crate::error::{Error, Result};
use crate::machine::Outputs;

/// A sampled control law.
#[derive(Debug, Clone, PartialEq)]
pub enum Controller {
    /// Position P with velocity feed-forward (thesis 4.1; DATA_FORMAT `position_pff`):
    /// u[k] = clip(kp*(r[k]-y[k]) + kff*(r[k+1]-r[k])/Ts, -u_max, u_max)
    PositionPff { kp_v_per_m: f64, kff_v_per_m_s: f64, u_max_v: f64 },
    /// Fixed-gain force P (the thesis's comparison case): u[k] = clip(kp*(r[k]-f[k]))
    ForceP { kp_v_per_n: f64, u_max_v: f64 },
}

impl Controller {
    pub fn validate(&self) -> Result<()> {
        let (gains, u_max): (&[f64], f64) = match self {
            Controller::PositionPff { kp_v_per_m, kff_v_per_m_s, u_max_v } => (&[*kp_v_per_m, *kff_v_per_m_s][..], *u_max_v),
            Controller::ForceP { kp_v_per_n, u_max_v } => (&[*kp_v_per_n][..], *u_max_v),
        };
        if gains.iter().any(|g| !g.is_finite()) {
            return Err(Error::Parameter { field: "controller gain".into(), value: f64::NAN, allowed: "finite".into() });
        }
        if !(u_max.is_finite() && u_max > 0.0) {
            return Err(Error::Parameter { field: "u_max_v".into(), value: u_max, allowed: "(0, inf) V".into() });
        }
        Ok(())
    }

    /// Command for sample k from the reference now (`r`), next (`r_next`) and the measurement.
    pub fn command(&self, r: f64, r_next: f64, ts: f64, m: &Outputs) -> f64 {
        match *self {
            Controller::PositionPff { kp_v_per_m, kff_v_per_m_s, u_max_v } => {
                (kp_v_per_m * (r - m.y) + kff_v_per_m_s * (r_next - r) / ts).clamp(-u_max_v, u_max_v)
            }
            Controller::ForceP { kp_v_per_n, u_max_v } => (kp_v_per_n * (r - m.f)).clamp(-u_max_v, u_max_v),
        }
    }
}
