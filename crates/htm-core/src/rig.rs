//! The virtual rig's plant: the machine with a specimen whose crack grows cycle by cycle from
//! the force it actually sees (peaks and valleys found with a hysteresis), K_sp(a) fed back
//! into the machine, and the plant-side faults (supply pressure, fracture). Its readings go
//! through the measurement model of its parameters (`measure`: the EFFECTS sensor effects the
//! identification simulates, one copy), so a virtual rig can carry hidden sensor effects.
use crate::crack::Law;
use crate::engine::measured_k;
use crate::error::{Error, Result};
use crate::machine::{Machine, Outputs};
use crate::measure::{as_outputs, Probe, Sensor, Sensors};
use crate::params::Params;
use crate::specimen::{Material, Specimen};

/// A cracked specimen between the grips.
#[derive(Debug, Clone)]
pub struct CrackingSpecimen {
    pub specimen: Specimen,
    pub material: Material,
    pub law: Law,
    /// crack length [m]
    pub a_m: f64,
    /// force reversal needed to confirm a peak or a valley [N]
    pub hysteresis_n: f64,
    pub cycles: u64,
    pub fractured: bool,
    rising: bool,
    peak: f64,
    valley: f64,
}

impl CrackingSpecimen {
    /// Force hysteresis [N] of the peak/valley finder when a specimen gives none.
    pub const DEFAULT_HYSTERESIS_N: f64 = 50.0;

    pub fn new(specimen: Specimen, material: Material, law: Law, a0_m: f64, hysteresis_n: f64) -> Result<Self> {
        specimen.validate()?;
        material.validate()?;
        law.validate()?;
        let (lo, hi) = specimen.a_range();
        if !(a0_m >= lo - 1e-12 && a0_m < hi) {
            return Err(Error::Parameter { field: "specimen.a0_m".into(), value: a0_m, allowed: format!("[{lo}, {hi}) m") });
        }
        if !(hysteresis_n.is_finite() && hysteresis_n > 0.0) {
            return Err(Error::Parameter { field: "specimen.hysteresis_n".into(), value: hysteresis_n, allowed: "(0, inf) N".into() });
        }
        Ok(CrackingSpecimen { specimen, material, law, a_m: a0_m, hysteresis_n, cycles: 0, fractured: false, rising: true, peak: f64::MIN, valley: f64::MAX })
    }

    pub fn stiffness(&self) -> f64 {
        if self.fractured { 0.0 } else { self.specimen.stiffness(self.a_m, &self.material).unwrap_or(0.0) }
    }

    /// Feed one force sample [N]; true when a cycle closed (the crack may have grown).
    pub fn observe(&mut self, f: f64) -> bool {
        if self.fractured || !f.is_finite() {
            return false;
        }
        if self.rising {
            if f > self.peak {
                self.peak = f;
            } else if f < self.peak - self.hysteresis_n {
                self.rising = false;
                self.valley = f;
            }
            false
        } else if f < self.valley {
            self.valley = f;
            false
        } else if f > self.valley + self.hysteresis_n {
            self.rising = true;
            let (p, v) = (self.peak, self.valley);
            self.peak = f;
            self.cycles += 1;
            self.grow(p, v);
            true
        } else {
            false
        }
    }

    fn grow(&mut self, fmax: f64, fmin: f64) {
        if fmax <= 0.0 {
            return;
        }
        let s = &self.specimen;
        // the controller's rule (engine::measured_k) with the R the specimen sees
        let Ok((krange, kmax, r)) = measured_k(s, self.a_m, fmax, fmin, fmin / fmax) else {
            self.fractured = true;
            return;
        };
        let dadn = self.law.rate(krange, r, kmax);
        if kmax >= self.material.fracture_toughness_pa_sqrt_m || !dadn.is_finite() || self.a_m + dadn >= s.a_range().1 {
            self.fractured = true;
        } else {
            self.a_m += dadn;
        }
    }
}

/// Machine + specimen + the supply's response to its setpoint.
#[derive(Debug, Clone)]
pub struct RigPlant {
    pub machine: Machine,
    pub specimen: Option<CrackingSpecimen>,
    /// supply pressure the relief valve is set to [Pa] and its time constant [s]
    pub supply_setpoint_pa: f64,
    pub supply_tau_s: f64,
    /// the sensors when they are not ideal (offset, gain, delay or filter)
    sensors: Option<Sensors>,
    /// their history: the probe, the period it samples and how many samples it keeps
    probe: Option<(Probe, f64, usize)>,
    /// the crack gauges on the specimen (clip gauge, potential drop): what they read of its
    /// true crack (`engine::measured::GaugeChain`, the simulator's one copy), and the last readings
    pub gauges: Vec<crate::engine::GaugeChain>,
    pub gauge_readings: Vec<f64>,
    /// the last confirmed peak force the specimen saw [N] (closure scales with it)
    last_peak_n: f64,
}

impl RigPlant {
    /// Set the relief-valve setpoint [Pa], finite and ≥ 0 (the supply follows with its lag).
    pub fn set_supply_setpoint_pa(&mut self, v: f64) -> Result<()> {
        if !(v.is_finite() && v >= 0.0) {
            return Err(Error::Parameter { field: "supply_setpoint_pa".into(), value: v, allowed: "[0, inf) Pa".into() });
        }
        self.supply_setpoint_pa = v;
        Ok(())
    }

    pub fn new(params: Params, specimen: Option<CrackingSpecimen>) -> Result<Self> {
        let mut p = params;
        if let Some(s) = &specimen {
            p.specimen_stiffness_n_m = s.stiffness();
        }
        let ps = p.supply_pressure_pa;
        let sensors = Sensors::from_params(&p);
        let sensors = sensors.0.iter().any(|s| *s != Sensor::IDEAL).then_some(sensors);
        Ok(RigPlant { machine: Machine::new(p)?, specimen, supply_setpoint_pa: ps, supply_tau_s: 0.05, sensors, probe: None, gauges: Vec::new(), gauge_readings: Vec::new(), last_peak_n: f64::NAN })
    }

    /// Put a crack gauge on the specimen (its chain: kind, noise, resolution, drift, closure);
    /// returns its index in `gauge_readings`.
    pub fn add_gauge(&mut self, m: &crate::engine::Measurement) -> Result<usize> {
        let s = self.specimen.as_ref().ok_or_else(|| Error::Input("a crack gauge needs a specimen in the rig".into()))?;
        m.validate(&s.specimen)?;
        let g = crate::engine::GaugeChain::new(m, &s.specimen, &s.material, s.a_m).ok_or_else(|| Error::Input("measurement.crack = \"model\" is no gauge".into()))?;
        self.gauges.push(g);
        self.gauge_readings.push(f64::NAN);
        Ok(self.gauges.len() - 1)
    }

    /// Hold valve command `u` [V] for `dt` [s]; returns the sensor readings (the true outputs
    /// through the sensors of the parameters; the specimen sees the true force).
    pub fn step(&mut self, u: f64, dt: f64) -> Result<Outputs> {
        let o = self.step_true(u, dt)?;
        let Some(sensors) = self.sensors else { return Ok(o) };
        if self.probe.as_ref().is_none_or(|(_, pdt, _)| *pdt != dt) {
            let delay = sensors.0.iter().map(|s| s.delay_s).fold(0.0, f64::max);
            self.probe = Some((Probe::new(sensors, dt, 64), dt, (delay / dt).ceil() as usize + 4));
        }
        let (probe, _, keep) = self.probe.as_mut().expect("set above");
        probe.push(&o);
        probe.keep_latest(*keep);
        Ok(Outputs { spool: o.spool, ..as_outputs(&probe.read_latest()) })
    }

    fn step_true(&mut self, u: f64, dt: f64) -> Result<Outputs> {
        let p = &mut self.machine.plant.p;
        // the relief valve follows its setpoint with a first-order lag (never below tank + 1 bar)
        let target = self.supply_setpoint_pa.max(p.tank_pressure_pa + 1e5);
        p.supply_pressure_pa += (target - p.supply_pressure_pa) * (1.0 - (-dt / self.supply_tau_s).exp());
        let o = self.machine.step(u, dt)?;
        if let Some(s) = &mut self.specimen {
            let peak = s.peak;
            if s.observe(o.f) {
                self.machine.plant.p.specimen_stiffness_n_m = s.stiffness();
                self.last_peak_n = peak;
                for g in &mut self.gauges {
                    g.cycle();
                }
            }
            let fmax = if self.last_peak_n.is_finite() { self.last_peak_n } else { s.peak.max(0.0) };
            for (g, r) in self.gauges.iter_mut().zip(&mut self.gauge_readings) {
                *r = if s.fractured { f64::NAN } else { g.read(&s.specimen, s.a_m, o.f, fmax) };
            }
        }
        Ok(o)
    }

    /// The specimen breaks: it carries no more force.
    pub fn fracture(&mut self) {
        if let Some(s) = &mut self.specimen {
            s.fractured = true;
        }
        self.machine.plant.p.specimen_stiffness_n_m = 0.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::specimen::Geometry;

    #[test]
    fn crack_grows_once_per_force_cycle_and_lowers_the_stiffness() {
        let sp = Specimen::new(Geometry::CT, 50.8e-3, 6.35e-3).unwrap();
        let law = Law::Paris { c: 1e-27, m: 3.0 };
        let mut s = CrackingSpecimen::new(sp, Material::default(), law, 15.2e-3, 50.0).unwrap();
        let k0 = s.stiffness();
        for i in 0..1000 {
            let f = 2722.0 + 2225.0 * (2.0 * std::f64::consts::PI * i as f64 / 50.0).sin();
            s.observe(f);
        }
        assert_eq!(s.cycles, 20, "a cycle closes when the rise after each valley is confirmed");
        assert!(s.a_m > 15.2e-3 && s.stiffness() < k0);
        s.fractured = true;
        assert_eq!(s.stiffness(), 0.0);
    }
}
