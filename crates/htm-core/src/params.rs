//! Machine parameters: one documented struct, every field with its unit, source and allowed range.
//! The default is the thesis rig (Dias 2014, Appendix A, corrected per shared/reference/NOTES.md).
use crate::error::{Error, Result};

/// Metadata of one scalar parameter.
#[derive(Debug, Clone, Copy)]
pub struct Field {
    pub name: &'static str,
    pub unit: &'static str,
    pub doc: &'static str,
    pub min: f64,
    pub max: f64,
    /// true when `min` itself is excluded (strictly positive quantities)
    pub min_open: bool,
}

impl Field {
    pub fn allowed(&self) -> String {
        let lo = if self.min_open { "(" } else { "[" };
        format!("{lo}{}, {}] {}", self.min, self.max, self.unit)
    }
    pub fn check(&self, v: f64) -> Result<()> {
        let low_ok = if self.min_open { v > self.min } else { v >= self.min };
        if v.is_finite() && low_ok && v <= self.max {
            Ok(())
        } else {
            Err(Error::Parameter { field: self.name.into(), value: v, allowed: self.allowed() })
        }
    }
}

macro_rules! define_params {
    ($( $(#[doc = $doc:literal])+ $name:ident [$unit:literal] = $default:expr, $lo:tt $min:expr, $max:expr; )*) => {
        /// Plant parameters, SI. Field docs give the source of each default.
        #[derive(serde::Serialize, serde::Deserialize)] // engine snapshots (resume)
        #[derive(Debug, Clone, PartialEq)]
        pub struct Params {
            $( $(#[doc = $doc])+ pub $name: f64, )*
            /// Static command-to-spool characteristic (eq. 2.10 generalised): knots of command
            /// magnitude after the null bias [V], ascending from 0. Empty = linear (x_v = u).
            pub valve_map_command_v: Vec<f64>,
            /// Spool position at each knot [V equivalent]; odd-symmetric, monotone.
            pub valve_map_spool_v: Vec<f64>,
        }

        /// Every scalar parameter with unit, documentation and allowed range.
        pub const FIELDS: &[Field] = &[
            $( Field { name: stringify!($name), unit: $unit, doc: concat!($($doc, " "),+),
                       min: $min, max: $max, min_open: define_params!(@open $lo) }, )*
        ];

        impl Params {
            /// The thesis rig with the linear valve characteristic.
            pub fn base() -> Self {
                Params { $( $name: $default, )* valve_map_command_v: vec![], valve_map_spool_v: vec![] }
            }
            pub fn get(&self, name: &str) -> Option<f64> {
                match name { $( stringify!($name) => Some(self.$name), )* _ => None }
            }
            pub fn set(&mut self, name: &str, value: f64) -> Result<()> {
                match name {
                    $( stringify!($name) => { self.$name = value; Ok(()) } )*
                    _ => Err(Error::Input(format!("unknown parameter `{name}`"))),
                }
            }
        }
    };
    (@open open) => { true };
    (@open closed) => { false };
}

define_params! {
    /// Effective area of chamber A (annulus of the double-rod cylinder CGH2MF3/80/56/200,
    /// pi/4*(0.080^2-0.056^2); Table A.2 misprints it by 10x, NOTES item 1)
    area_a_m2 ["m^2"] = 2.5635e-3, open 0.0, 1.0;
    /// Effective area of chamber B (same annulus)
    area_b_m2 ["m^2"] = 2.5635e-3, open 0.0, 1.0;
    /// Cylinder stroke L (Table A.2); the piston lives in [0, L]
    stroke_m ["m"] = 0.2, open 0.0, 10.0;
    /// Moving mass M_t (identified 53.78 kg, NOTES item 8; datasheet 52 kg)
    moving_mass_kg ["kg"] = 53.78, open 0.0, 1.0e5;
    /// Gravity along -y on the moving mass; 0 for a horizontal rig
    gravity_m_s2 ["m/s^2"] = 9.80665, closed 0.0, 20.0;
    /// Supply pressure P_s at no flow, gauge (Table A.3)
    supply_pressure_pa ["Pa"] = 19.0e6, open 0.0, 1.0e8;
    /// Tank (return) pressure P_T, gauge
    tank_pressure_pa ["Pa"] = 0.0, closed 0.0, 1.0e7;
    /// Atmospheric pressure: absolute = gauge + this; no pressure falls below absolute zero
    atmospheric_pressure_pa ["Pa"] = 101_325.0, open 0.0, 2.0e5;
    /// Oil bulk modulus beta_e (section 2.1: 1200 MPa), at zero gauge pressure
    bulk_modulus_pa ["Pa"] = 1.2e9, open 1.0e6, 1.0e11;
    /// Rise of the bulk modulus with gauge pressure, d(beta)/dp (oil: about 5-12); 0 = constant
    bulk_modulus_slope ["-"] = 0.0, closed 0.0, 50.0;
    /// Eggerth bulk modulus (eq. 2.2) kappa_1; 0 keeps the constant bulk modulus
    eggerth_k1_per_pa ["1/Pa"] = 0.0, closed 0.0, 1.0e-3;
    /// Eggerth kappa_2
    eggerth_k2_per_pa ["1/Pa"] = 0.0, closed 0.0, 1.0e-3;
    /// Eggerth exponent lambda
    eggerth_lambda ["-"] = 0.0, closed 0.0, 5.0;
    /// Entrained free air, volume fraction at atmospheric pressure (EFFECTS entrained_air)
    air_fraction ["-"] = 0.0, closed 0.0, 0.5;
    /// Absolute pressure below which the oil cavitates and stiffness collapses
    cavitation_pressure_pa ["Pa"] = 2.0e4, open 0.0, 1.0e5;
    /// Dead volume of chamber A incl. lines, V_A0 (not in the thesis; typical manifold-mounted valve)
    dead_volume_a_m3 ["m^3"] = 5.0e-5, open 0.0, 1.0;
    /// Dead volume of chamber B incl. lines, V_B0
    dead_volume_b_m3 ["m^3"] = 5.0e-5, open 0.0, 1.0;
    /// Oil density (Table A.3); recorded with the rig, the flow law uses the rated flow instead
    oil_density_kg_m3 ["kg/m^3"] = 874.0, open 0.0, 2000.0;
    /// Valve rated flow Q_N at the rated valve drop (Table A.1: 75 L/min)
    valve_rated_flow_m3_s ["m^3/s"] = 1.25e-3, open 0.0, 1.0;
    /// Valve pressure drop for Q_N, both edges together (Table A.1: 70 bar)
    valve_rated_dp_pa ["Pa"] = 7.0e6, open 0.0, 1.0e8;
    /// Command for full spool opening (Table A.1: +-10 V); commands are clipped here
    valve_max_command_v ["V"] = 10.0, open 0.0, 100.0;
    /// Valve polarity: -1 means a positive command retracts the piston (NOTES item 2)
    valve_polarity ["-"] = -1.0, closed -1.0, 1.0;
    /// Underlap of each metering edge, in command volts (eq. 2.15); 0.1 V reproduces the
    /// null leakage of eq. 3.22 (1.5 L/min at 70 bar)
    valve_underlap_v ["V"] = 0.1, closed 0.0, 5.0;
    /// Width over which a metering edge opens (regularises sg() of eq. 2.17)
    valve_lap_smoothing_v ["V"] = 0.005, open 0.0, 1.0;
    /// Pressure drop below which orifice flow turns laminar (regularises sqrt near 0)
    valve_transition_dp_pa ["Pa"] = 1.0e5, open 0.0, 1.0e7;
    /// Valve null bias: the spool sees u + bias (Table 3.3 centres on -0.115 V, NOTES item 3)
    valve_null_bias_v ["V"] = 0.115, closed -10.0, 10.0;
    /// Spool time constant tau_v (eq. 2.8); 0 = static valve (eq. 2.10, the thesis's choice).
    /// With a second-order spool this lag acts in series before it (EFFECTS valve_dynamics)
    valve_tau_s ["s"] = 0.0, closed 0.0, 1.0;
    /// Natural frequency of a second-order spool (eq. 2.3-2.7); 0 = no second-order spool
    valve_natural_hz ["Hz"] = 0.0, closed 0.0, 1.0e4;
    /// Damping ratio of the second-order spool
    valve_damping ["-"] = 0.7, open 0.0, 10.0;
    /// Overlap dead band half width (EFFECTS valve_deadband); 0 = off
    valve_deadband_half_width_v ["V"] = 0.0, closed 0.0, 5.0;
    /// Backlash between command and spool (EFFECTS valve_hysteresis); 0 = off
    valve_hysteresis_half_width_v ["V"] = 0.0, closed 0.0, 5.0;
    /// 1 = flow proportional to spool only (no sqrt(dp) load feedback); 0 = orifice law.
    /// EFFECTS `load_pressure_feedback` is this switch going from 1 to 0: a rig whose metadata
    /// declares a linear (pressure-compensated) valve whose flow still falls with load pressure
    valve_linear_flow ["-"] = 0.0, closed 0.0, 1.0;
    /// Supply sag: p_s = p_s0 - R*Q_in (EFFECTS supply_pressure_sag); 0 = stiff supply
    supply_resistance_pa_s_per_m3 ["Pa s/m^3"] = 0.0, closed 0.0, 1.0e13;
    /// Supply ripple, sine part: p_s0 + s*sin(2 pi f t) + c*cos(2 pi f t) (a pump's ripple; not an
    /// EFFECTS.md id: a probe for structure outside the table), applied per sample in replays
    supply_ripple_sin_pa ["Pa"] = 0.0, closed -1.0e8, 1.0e8;
    /// Supply ripple, cosine part
    supply_ripple_cos_pa ["Pa"] = 0.0, closed -1.0e8, 1.0e8;
    /// Supply ripple frequency f
    supply_ripple_hz ["Hz"] = 0.0, closed 0.0, 1.0e5;
    /// Internal leakage across the piston, Q = c*(p_a - p_b) (EFFECTS internal_leakage)
    leakage_coeff_m3_per_s_pa ["m^3/(s Pa)"] = 0.0, closed 0.0, 1.0e-8;
    /// Viscous friction B_v (eq. 3.20)
    friction_viscous_n_s_m ["N s/m"] = 5017.35, closed 0.0, 1.0e7;
    /// Coulomb friction for upward motion (eq. 3.20: 792.33 both ways)
    friction_coulomb_pos_n ["N"] = 792.33, closed 0.0, 1.0e6;
    /// Coulomb friction for downward motion
    friction_coulomb_neg_n ["N"] = 792.33, closed 0.0, 1.0e6;
    /// Static friction excess F_s (eq. 3.20)
    friction_static_n ["N"] = 102.61, closed 0.0, 1.0e6;
    /// Stribeck velocity C_s (eq. 3.20)
    friction_stribeck_m_s ["m/s"] = 0.01, open 0.0, 10.0;
    /// Smoothing velocity eps of sig() (section 3.4.4: 1e-3 m/s)
    friction_smoothing_m_s ["m/s"] = 1.0e-3, open 0.0, 1.0;
    /// Form of that smoothed sign: 0 = the thesis's v/(|v| + eps) (eq. 3.19: half the level at
    /// eps, 91 % at 10 eps), 1 = tanh(v/eps) (the whole level within a few eps: a seal that grips
    /// at once); between, the blend (1 - k) v/(|v| + eps) + k tanh(v/eps)
    friction_sign_shape ["-"] = 0.0, closed 0.0, 1.0;
    /// Coulomb growth with p_a + p_b (EFFECTS pressure_dependent_friction)
    friction_pressure_coeff_n_per_pa ["N/Pa"] = 0.0, closed 0.0, 1.0e-2;
    /// Extra friction in a band of positions (a scored rod or bore). Not an EFFECTS.md id: the
    /// proving ground's effect outside the table; 0 = off
    friction_bump_n ["N"] = 0.0, closed 0.0, 1.0e6;
    /// Centre of the friction bump
    friction_bump_position_m ["m"] = 0.1, closed 0.0, 10.0;
    /// Half width (Gaussian sigma) of the friction bump
    friction_bump_width_m ["m"] = 5.0e-3, open 0.0, 10.0;
    /// A force along +y over the same band of positions (a spring, a cushion, a load over part of
    /// the stroke; not an EFFECTS.md id: a probe for structure outside the table); 0 = off
    force_bump_n ["N"] = 0.0, closed -1.0e6, 1.0e6;
    /// Extra viscous damping over the same band of positions (an end cushion's throttle); 0 = off
    damping_bump_n_s_m ["N s/m"] = 0.0, closed 0.0, 1.0e8;
    /// Specimen stiffness K_sp; 0 = free piston (C(T) of Table B.1: 1.04e8, NOTES item 10)
    specimen_stiffness_n_m ["N/m"] = 0.0, closed 0.0, 1.0e11;
    /// Piston position at which the specimen carries no force
    specimen_zero_force_position_m ["m"] = 0.1, closed 0.0, 10.0;
    /// Crack-closure stiffness added below the closure position (EFFECTS specimen_nonlinearity,
    /// a bilinear spring); 0 = linear specimen
    specimen_closure_stiffness_n_m ["N/m"] = 0.0, closed 0.0, 1.0e11;
    /// Closure position relative to the zero-force position: the closure stiffness acts for
    /// y < specimen_zero_force_position_m + this
    specimen_closure_offset_m ["m"] = 0.0, closed -1.0, 1.0;
    /// End-stop contact stiffness at y = 0 and y = L
    end_stop_stiffness_n_m ["N/m"] = 5.0e9, open 0.0, 1.0e12;
    /// End-stop contact damping
    end_stop_damping_n_s_m ["N s/m"] = 1.0e6, closed 0.0, 1.0e9;
    /// Sensor offset of `y` (position): the sensor reads offset + gain * true (EFFECTS sensor_offset)
    sensor_offset_y ["m"] = 0.0, closed -1.0, 1.0;
    /// Sensor gain of `y` (EFFECTS sensor_gain); 1 = ideal
    sensor_gain_y ["-"] = 1.0, open 0.0, 10.0;
    /// Transport delay of the `y` measurement (EFFECTS sensor_delay); 0 = none
    sensor_delay_y_s ["s"] = 0.0, closed 0.0, 1.0;
    /// Cut-off of a first-order anti-alias filter in the `y` signal path (a declared sensor
    /// property, DATA_FORMAT `sensors.y.lowpass_hz`); 0 = none
    sensor_lowpass_y_hz ["Hz"] = 0.0, closed 0.0, 1.0e6;
    /// Sensor offset of `v` (velocity): the sensor reads offset + gain * true (EFFECTS sensor_offset)
    sensor_offset_v ["m/s"] = 0.0, closed -10.0, 10.0;
    /// Sensor gain of `v` (EFFECTS sensor_gain); 1 = ideal
    sensor_gain_v ["-"] = 1.0, open 0.0, 10.0;
    /// Transport delay of the `v` measurement (EFFECTS sensor_delay); 0 = none
    sensor_delay_v_s ["s"] = 0.0, closed 0.0, 1.0;
    /// Cut-off of a first-order anti-alias filter in the `v` signal path (a declared sensor
    /// property, DATA_FORMAT `sensors.v.lowpass_hz`); 0 = none
    sensor_lowpass_v_hz ["Hz"] = 0.0, closed 0.0, 1.0e6;
    /// Sensor offset of `p_a` (chamber A pressure): the sensor reads offset + gain * true (EFFECTS sensor_offset)
    sensor_offset_p_a ["Pa"] = 0.0, closed -1.0e8, 1.0e8;
    /// Sensor gain of `p_a` (EFFECTS sensor_gain); 1 = ideal
    sensor_gain_p_a ["-"] = 1.0, open 0.0, 10.0;
    /// Transport delay of the `p_a` measurement (EFFECTS sensor_delay); 0 = none
    sensor_delay_p_a_s ["s"] = 0.0, closed 0.0, 1.0;
    /// Cut-off of a first-order anti-alias filter in the `p_a` signal path (a declared sensor
    /// property, DATA_FORMAT `sensors.p_a.lowpass_hz`); 0 = none
    sensor_lowpass_p_a_hz ["Hz"] = 0.0, closed 0.0, 1.0e6;
    /// Sensor offset of `p_b` (chamber B pressure): the sensor reads offset + gain * true (EFFECTS sensor_offset)
    sensor_offset_p_b ["Pa"] = 0.0, closed -1.0e8, 1.0e8;
    /// Sensor gain of `p_b` (EFFECTS sensor_gain); 1 = ideal
    sensor_gain_p_b ["-"] = 1.0, open 0.0, 10.0;
    /// Transport delay of the `p_b` measurement (EFFECTS sensor_delay); 0 = none
    sensor_delay_p_b_s ["s"] = 0.0, closed 0.0, 1.0;
    /// Cut-off of a first-order anti-alias filter in the `p_b` signal path (a declared sensor
    /// property, DATA_FORMAT `sensors.p_b.lowpass_hz`); 0 = none
    sensor_lowpass_p_b_hz ["Hz"] = 0.0, closed 0.0, 1.0e6;
    /// Sensor offset of `p_s` (supply pressure): the sensor reads offset + gain * true (EFFECTS sensor_offset)
    sensor_offset_p_s ["Pa"] = 0.0, closed -1.0e8, 1.0e8;
    /// Sensor gain of `p_s` (EFFECTS sensor_gain); 1 = ideal
    sensor_gain_p_s ["-"] = 1.0, open 0.0, 10.0;
    /// Transport delay of the `p_s` measurement (EFFECTS sensor_delay); 0 = none
    sensor_delay_p_s_s ["s"] = 0.0, closed 0.0, 1.0;
    /// Cut-off of a first-order anti-alias filter in the `p_s` signal path (a declared sensor
    /// property, DATA_FORMAT `sensors.p_s.lowpass_hz`); 0 = none
    sensor_lowpass_p_s_hz ["Hz"] = 0.0, closed 0.0, 1.0e6;
    /// Sensor offset of `f` (load cell force): the sensor reads offset + gain * true (EFFECTS sensor_offset)
    sensor_offset_f ["N"] = 0.0, closed -1.0e8, 1.0e8;
    /// Sensor gain of `f` (EFFECTS sensor_gain); 1 = ideal
    sensor_gain_f ["-"] = 1.0, open 0.0, 10.0;
    /// Transport delay of the `f` measurement (EFFECTS sensor_delay); 0 = none
    sensor_delay_f_s ["s"] = 0.0, closed 0.0, 1.0;
    /// Cut-off of a first-order anti-alias filter in the `f` signal path (a declared sensor
    /// property, DATA_FORMAT `sensors.f.lowpass_hz`); 0 = none
    sensor_lowpass_f_hz ["Hz"] = 0.0, closed 0.0, 1.0e6;
}

impl Default for Params {
    /// The thesis rig: base model plus the measured valve characteristic of Table 3.3.
    fn default() -> Self {
        let mut p = Params::base();
        let (c, s) = thesis_valve_map();
        p.valve_map_command_v = c;
        p.valve_map_spool_v = s;
        p
    }
}

/// Command-to-spool knots that reproduce the thesis's Table 3.3 (steady velocity vs command)
/// with the base model; generated by `tools/fit_valve_map.py`.
pub fn thesis_valve_map() -> (Vec<f64>, Vec<f64>) {
    (
        vec![0.0, 0.2, 0.5, 0.885, 1.115, 1.615, 2.0, 5.0, 10.0],
        vec![0.0, 0.038484, 0.295456, 0.656228, 0.795184, 1.390548, 1.517614, 4.623349, 7.678819],
    )
}

impl Params {
    /// Check every field and the relations between fields; the error names the first bad field.
    pub fn validate(&self) -> Result<()> {
        for f in FIELDS {
            f.check(self.get(f.name).expect("field table matches struct"))?;
        }
        let bad = |field: &str, value: f64, allowed: String| {
            Err(Error::Parameter { field: field.into(), value, allowed })
        };
        if self.valve_polarity != 1.0 && self.valve_polarity != -1.0 {
            return bad("valve_polarity", self.valve_polarity, "-1 or +1".into());
        }
        if self.tank_pressure_pa >= self.supply_pressure_pa {
            return bad("tank_pressure_pa", self.tank_pressure_pa, format!("below supply_pressure_pa = {}", self.supply_pressure_pa));
        }
        if self.specimen_zero_force_position_m > self.stroke_m {
            return bad("specimen_zero_force_position_m", self.specimen_zero_force_position_m, format!("[0, stroke_m = {}] m", self.stroke_m));
        }
        if self.eggerth_k1_per_pa > 0.0 && self.eggerth_lambda <= 0.0 {
            return bad("eggerth_lambda", self.eggerth_lambda, "> 0 when eggerth_k1_per_pa is set".into());
        }
        let (c, s) = (&self.valve_map_command_v, &self.valve_map_spool_v);
        if c.len() != s.len() || c.len() == 1 {
            return Err(Error::Input(format!(
                "valve map needs equal knot lists of length 0 or >= 2 (got {} commands, {} spools)", c.len(), s.len())));
        }
        if !c.is_empty() {
            if c[0] != 0.0 || s[0] != 0.0 {
                return Err(Error::Input("valve map must start at (0 V, 0 V)".into()));
            }
            for i in 1..c.len() {
                if !(c[i] > c[i - 1]) || !(s[i] > s[i - 1]) || !c[i].is_finite() || !s[i].is_finite() {
                    return Err(Error::Input(format!("valve map must be strictly increasing (knot {i})")));
                }
            }
        }
        Ok(())
    }

    /// Orifice coefficient per metering edge [m^3/s per V per sqrt(Pa)]: the rated flow at full
    /// command with half the rated valve drop across each of the two edges in series.
    pub fn valve_edge_coeff(&self) -> f64 {
        self.valve_rated_flow_m3_s / (self.valve_max_command_v * (0.5 * self.valve_rated_dp_pa).sqrt())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_every_field_is_reachable() {
        let p = Params::default();
        p.validate().unwrap();
        for f in FIELDS {
            assert!(p.get(f.name).is_some(), "{}", f.name);
        }
    }

    #[test]
    fn bad_values_name_the_field_and_range() {
        let mut p = Params::default();
        p.set("area_a_m2", -1.0).unwrap();
        let e = p.validate().unwrap_err().to_string();
        assert!(e.contains("area_a_m2") && e.contains("(0, 1]"), "{e}");
        let p = Params { moving_mass_kg: 0.0, ..Default::default() };
        assert!(p.validate().unwrap_err().to_string().contains("moving_mass_kg"));
        let p = Params { stroke_m: f64::NAN, ..Default::default() };
        assert!(p.validate().unwrap_err().to_string().contains("stroke_m"));
    }

    #[test]
    fn edge_coefficient_reproduces_the_theoretical_velocity_gain() {
        // Table 3.5: Q_N / (A_n * 10 V) = 4.876e-2 m/s per V at rated drop.
        let p = Params::default();
        let q = p.valve_edge_coeff() * 10.0 * (0.5 * p.valve_rated_dp_pa).sqrt();
        assert!((q / (p.area_a_m2 * 10.0) - 4.876e-2).abs() < 1e-4);
    }
}
