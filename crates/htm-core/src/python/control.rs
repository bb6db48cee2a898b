//! Thin bindings of the real-time loop's Rust parts: the per-period controller (`Cyclic`), the
//! limit detectors and the virtual rig's plant. One call per control period, no GIL release (µs).
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use super::convert::PyTestConfig;
use super::convert::law_from;
use super::{InputError, PyParams};
use crate::control::limits::{Action, Detector, Detectors};
use crate::cyclic::{Cyclic, CycleResult, PositionGains};
use crate::rig::{CrackingSpecimen, RigPlant};
use crate::specimen::{Geometry, Material, Specimen};

fn opt_f(d: Option<&Bound<'_, PyDict>>, k: &str, default: f64) -> PyResult<f64> {
    match d {
        Some(d) => match d.get_item(k)? {
            Some(v) if !v.is_none() => v.extract(),
            _ => Ok(default),
        },
        None => Ok(default),
    }
}

fn cycle_dict<'py>(py: Python<'py>, r: &CycleResult) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("cycle", r.cycle)?;
    d.set_item("phase", r.phase)?;
    d.set_item("starting", r.events & crate::engine::events::START != 0)?;
    d.set_item("judged", r.judged)?;
    d.set_item("events", r.events)?;
    for (k, v) in [
        ("fmax_n", r.fmax_n), ("fmin_n", r.fmin_n), ("fmax_target_n", r.fmax_target_n), ("fmin_target_n", r.fmin_target_n),
        ("peak_err_pct", r.peak_err_pct), ("df_err_pct", r.df_err_pct), ("a_m", r.a_m), ("delta_k_pa_sqrt_m", r.delta_k),
        ("delta_k_target_pa_sqrt_m", r.delta_k_target), ("kmax_pa_sqrt_m", r.kmax), ("dadn_m_per_cycle", r.dadn_m),
        ("k_sp_n_m", r.k_sp_n_m), ("ymin_m", r.ymin_m), ("ymax_m", r.ymax_m), ("ctrl_u1_v", r.ctrl_u1_v), ("ctrl_u2_v", r.ctrl_u2_v),
        ("a_law_m", r.a_law_m), ("opening_force_n", r.opening_force_n), ("delta_k_eff_pa_sqrt_m", r.delta_k_eff),
    ] {
        d.set_item(k, v)?;
    }
    Ok(d)
}

/// The per-period controller: `u = ctrl.step(force_n, position_m)` once per control period.
/// `position` holds the position-mode settings (keys of `PositionGains`, SI).
#[pyclass(name = "CyclicController", module = "htm._core")]
pub struct PyCyclic {
    inner: Cyclic,
}

#[pymethods]
impl PyCyclic {
    #[new]
    #[pyo3(signature = (rate_hz, position = None))]
    fn new(rate_hz: f64, position: Option<&Bound<'_, PyDict>>) -> PyResult<Self> {
        let d = PositionGains::default();
        let g = PositionGains {
            bandwidth_per_s: opt_f(position, "bandwidth_per_s", d.bandwidth_per_s)?,
            velocity_gain_m_s_per_v: opt_f(position, "velocity_gain_m_s_per_v", d.velocity_gain_m_s_per_v)?,
            integral_time_s: opt_f(position, "integral_time_s", d.integral_time_s)?,
            max_speed_m_s: opt_f(position, "max_speed_m_s", d.max_speed_m_s)?,
            protect_force_n: opt_f(position, "protect_force_n", d.protect_force_n)?,
            protect_stiffness_n_m: opt_f(position, "protect_stiffness_n_m", d.protect_stiffness_n_m)?,
            y_min_m: opt_f(position, "y_min_m", d.y_min_m)?,
            y_max_m: opt_f(position, "y_max_m", d.y_max_m)?,
            u_max_v: opt_f(position, "u_max_v", d.u_max_v)?,
            supply_pa: opt_f(position, "supply_pa", d.supply_pa)?,
            tank_pa: opt_f(position, "tank_pa", d.tank_pa)?,
            area_m2: opt_f(position, "area_m2", d.area_m2)?,
            weight_n: opt_f(position, "weight_n", d.weight_n)?,
            low_supply_pa: opt_f(position, "low_supply_pa", d.low_supply_pa)?,
            startup_low_s: opt_f(position, "startup_low_s", d.startup_low_s)?,
            startup_ramp_s: opt_f(position, "startup_ramp_s", d.startup_ramp_s)?,
        };
        Ok(PyCyclic { inner: Cyclic::new(rate_hz, g)? })
    }

    /// One period: measured force [N] and position [m] in, valve command [V] out.
    #[pyo3(signature = (force_n, position_m, measurement=f64::NAN))]
    fn step(&mut self, force_n: f64, position_m: f64, measurement: f64) -> PyResult<f64> {
        self.inner.step_measured(force_n, position_m, measurement).map_err(PyErr::from)
    }

    /// Start the force test `config` (as `run_test`'s) from the measured force `f0_n`.
    fn start_test(&mut self, py: Python<'_>, config: PyRef<'_, PyTestConfig>, f0_n: f64) -> PyResult<()> {
        let cfg = std::sync::Arc::clone(&config.inner);
        let inner = &mut self.inner;
        py.detach(|| inner.start_test(&cfg, f0_n)).map_err(PyErr::from)
    }

    /// Position control holding `y_m`, bumpless from command `u_v`.
    fn position(&mut self, y_m: f64, u_v: f64) {
        self.inner.position(y_m, u_v)
    }
    fn jog(&mut self, rate_m_s: f64) -> PyResult<()> {
        self.inner.jog(rate_m_s).map_err(PyErr::from)
    }
    fn jog_step(&mut self, dm: f64) -> PyResult<()> {
        self.inner.jog_step(dm).map_err(PyErr::from)
    }
    fn move_to(&mut self, y_m: f64) -> PyResult<()> {
        self.inner.move_to(y_m).map_err(PyErr::from)
    }
    fn hold(&mut self) -> PyResult<()> {
        self.inner.hold().map_err(PyErr::from)
    }
    fn resume(&mut self) -> PyResult<()> {
        self.inner.resume().map_err(PyErr::from)
    }
    fn stop(&mut self) {
        self.inner.stop()
    }
    fn idle(&mut self) {
        self.inner.idle()
    }

    /// Largest |command| from now on [V] (a trip lowers it to the safe value).
    #[getter]
    fn get_command_limit_v(&self) -> f64 {
        self.inner.command_limit_v
    }
    #[setter]
    fn set_command_limit_v(&mut self, v: f64) -> PyResult<()> {
        Ok(self.inner.set_command_limit_v(v)?)
    }
    #[getter]
    fn state(&self) -> &'static str {
        self.inner.state.name()
    }
    #[getter]
    fn cycle(&self) -> u64 {
        self.inner.cycle()
    }
    #[getter]
    fn a_m(&self) -> f64 {
        self.inner.a_m()
    }
    /// The growth law's crack beside the measured one [m] (NaN without a test).
    #[getter]
    fn a_law_m(&self) -> f64 {
        self.inner.a_law_m()
    }
    #[getter]
    fn results(&self) -> u64 {
        self.inner.results
    }
    #[getter]
    fn u_null_v(&self) -> f64 {
        self.inner.u_null
    }
    #[getter]
    fn u_last_v(&self) -> f64 {
        self.inner.u_last
    }
    #[getter]
    fn end_reason(&self) -> Option<&'static str> {
        self.inner.end_reason.map(|e| e.name())
    }
    #[getter]
    fn protecting(&self) -> bool {
        self.inner.protecting()
    }
    /// True while position control's hydraulic start-up runs (low pressure, then the ramp).
    #[getter]
    fn starting_up(&self) -> bool {
        self.inner.starting_up()
    }
    /// The supply pressure the controller asks for now [Pa] (0 without a known supply).
    #[getter]
    fn supply_demand_pa(&self) -> f64 {
        self.inner.supply_demand_pa()
    }
    #[getter]
    fn reference_m(&self) -> f64 {
        self.inner.reference_m()
    }
    /// Force setpoint of the next period [N]; NaN outside a force test.
    #[getter]
    fn force_ref_n(&self) -> f64 {
        self.inner.force_ref_n()
    }
    /// (Fmax, Fmin, ΔK) targets of the current cycle [N, N, Pa·√m], or None.
    #[getter]
    fn targets(&self) -> Option<(f64, f64, f64)> {
        self.inner.targets()
    }
    /// Convergence of the loaded test so far (as `run_test`'s `convergence`); empty without one.
    fn convergence<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        match self.inner.machine() {
            Some(m) => super::convert::convergence_list(py, &m.convergence),
            None => Ok(PyList::empty(py)),
        }
    }
    /// The last closed test cycle as a dict, or None.
    fn last_cycle<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        self.inner.last.as_ref().map(|r| cycle_dict(py, r)).transpose()
    }
    /// Test frequency actually run (a whole number of periods per cycle), samples per cycle,
    /// the valve gain used and the demodulation gains.
    fn info<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        d.set_item("rate_hz", self.inner.rate_hz)?;
        d.set_item("frequency_hz", self.inner.frequency_hz())?;
        d.set_item("samples_per_cycle", self.inner.samples_per_cycle())?;
        d.set_item("velocity_gain_m_s_per_v", self.inner.velocity_gain())?;
        if let Some(g) = self.inner.demod_gains() {
            d.set_item("demod_k1", g.k1)?;
            d.set_item("demod_kp2", g.kp2)?;
            d.set_item("demod_ki2", g.ki2)?;
        }
        let p = self.inner.position_gains();
        d.set_item("protect_force_n", p.protect_force_n)?;
        d.set_item("max_speed_m_s", p.max_speed_m_s)?;
        Ok(d)
    }
}

/// Limit detectors: a list of dicts {name, channel, lo, hi, action, persist}.
#[pyclass(name = "Detectors", module = "htm._core")]
pub struct PyDetectors {
    inner: Detectors,
}

#[pymethods]
impl PyDetectors {
    #[new]
    fn new(items: &Bound<'_, PyList>) -> PyResult<Self> {
        let mut list = Vec::new();
        for it in items.iter() {
            let d = it.cast_into::<PyDict>()?;
            let get = |k: &str| -> PyResult<Bound<'_, PyAny>> { d.get_item(k)?.ok_or_else(|| InputError::new_err(format!("detector needs `{k}`"))) };
            let name: String = get("name")?.extract()?;
            let action = Action::parse(&get("action")?.extract::<String>()?).map_err(|e| InputError::new_err(format!("limits.{name}: {e}")))?;
            let persist: u32 = match d.get_item("persist")? { Some(v) => v.extract()?, None => 1 };
            list.push(Detector::new(&name, get("channel")?.extract()?, get("lo")?.extract()?, get("hi")?.extract()?, action, persist)?);
        }
        Ok(PyDetectors { inner: Detectors { list } })
    }

    /// Check all against `values` (indexed by channel); returns the indices that tripped now.
    fn check(&mut self, values: Vec<f64>) -> Vec<usize> {
        self.inner.check(&values)
    }
    /// Worst latched action ("indicate", "hold", "stop", "power_off") or None.
    fn worst(&self) -> Option<&'static str> {
        self.inner.worst().map(|a| a.name())
    }
    /// Clear the latches whose condition is gone; returns the names still out of band.
    fn reset(&mut self) -> Vec<String> {
        self.inner.reset()
    }
    fn set_enabled(&mut self, name: &str, enabled: bool) -> PyResult<()> {
        let d = self.inner.list.iter_mut().find(|d| d.name == name).ok_or_else(|| InputError::new_err(format!("no detector `{name}`")))?;
        d.enabled = enabled;
        Ok(())
    }
    fn __len__(&self) -> usize {
        self.inner.list.len()
    }
    /// Every detector: name, channel, lo, hi, action, persist, enabled, active, latched, trip_value.
    fn describe<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let out = PyList::empty(py);
        for d in &self.inner.list {
            let x = PyDict::new(py);
            x.set_item("name", &d.name)?;
            x.set_item("channel", d.channel)?;
            x.set_item("lo", d.lo)?;
            x.set_item("hi", d.hi)?;
            x.set_item("action", d.action.name())?;
            x.set_item("persist", d.persist)?;
            x.set_item("enabled", d.enabled)?;
            x.set_item("active", d.active)?;
            x.set_item("latched", d.latched)?;
            x.set_item("trip_value", d.trip_value)?;
            out.append(x)?;
        }
        Ok(out)
    }
}

/// The virtual rig's plant: machine + cracking specimen (dict with geometry, width_m,
/// thickness_m, a0_m, the material keys, law, optional hysteresis_n) + supply response.
#[pyclass(name = "RigPlant", module = "htm._core")]
pub struct PyRigPlant {
    inner: RigPlant,
}

#[pymethods]
impl PyRigPlant {
    #[new]
    #[pyo3(signature = (params = None, specimen = None, rtol = 1e-4))]
    fn new(params: Option<PyParams>, specimen: Option<&Bound<'_, PyDict>>, rtol: f64) -> PyResult<Self> {
        let p = params.map(|p| p.inner).unwrap_or_default();
        let spec = match specimen {
            None => None,
            Some(d) => {
                let need = |k: &str| -> PyResult<f64> { d.get_item(k)?.ok_or_else(|| InputError::new_err(format!("specimen needs `{k}`")))?.extract() };
                let geom: String = d.get_item("geometry")?.ok_or_else(|| InputError::new_err("specimen needs `geometry`"))?.extract()?;
                let s = Specimen::new(Geometry::parse(&geom)?, need("width_m")?, need("thickness_m")?)?;
                let m = Material {
                    youngs_modulus_pa: need("youngs_modulus_pa")?,
                    poisson_ratio: need("poisson_ratio")?,
                    yield_strength_pa: need("yield_strength_pa")?,
                    fracture_toughness_pa_sqrt_m: need("fracture_toughness_pa_sqrt_m")?,
                };
                let law = law_from(&d.get_item("law")?.ok_or_else(|| InputError::new_err("specimen needs `law`"))?)?;
                Some(CrackingSpecimen::new(s, m, law, need("a0_m")?, opt_f(Some(d), "hysteresis_n", CrackingSpecimen::DEFAULT_HYSTERESIS_N)?)?)
            }
        };
        let mut r = RigPlant::new(p, spec)?;
        r.machine = r.machine.clone().with_rtol(rtol)?;
        Ok(PyRigPlant { inner: r })
    }

    /// Hold valve command `u` [V] for `dt` [s]; returns (y, v, p_a, p_b, p_s, f) SI.
    fn step(&mut self, u: f64, dt: f64) -> PyResult<(f64, f64, f64, f64, f64, f64)> {
        let o = self.inner.step(u, dt)?;
        Ok((o.y, o.v, o.p_a, o.p_b, o.p_s, o.f))
    }
    /// Sensor readings now: (y, v, p_a, p_b, p_s, f).
    fn outputs(&self) -> (f64, f64, f64, f64, f64, f64) {
        let o = self.inner.machine.outputs();
        (o.y, o.v, o.p_a, o.p_b, o.p_s, o.f)
    }
    /// Relief-valve setpoint [Pa] (the supply follows with a 50 ms lag).
    #[getter]
    fn get_supply_setpoint_pa(&self) -> f64 {
        self.inner.supply_setpoint_pa
    }
    #[setter]
    fn set_supply_setpoint_pa(&mut self, v: f64) -> PyResult<()> {
        Ok(self.inner.set_supply_setpoint_pa(v)?)
    }
    fn fracture(&mut self) {
        self.inner.fracture()
    }
    #[getter]
    fn t(&self) -> f64 {
        self.inner.machine.t
    }
    #[getter]
    fn a_m(&self) -> f64 {
        self.inner.specimen.as_ref().map(|s| s.a_m).unwrap_or(f64::NAN)
    }
    /// Put a crack gauge on the specimen: `crack` "compliance" (a clip gauge's opening [m]) or
    /// "potential_drop" (the potential [V], 1 V at the initial crack), with its chain's noise,
    /// resolution, drift and the specimen's closure (opening force / Fmax); returns its index.
    #[pyo3(signature = (crack, noise=0.0, resolution=0.0, drift_per_cycle=0.0, closure_opening_fraction=0.0, gauge_x_over_w=-0.25, gauge_y_m=f64::NAN, seed=1))]
    #[allow(clippy::too_many_arguments)]
    fn add_gauge(&mut self, crack: &str, noise: f64, resolution: f64, drift_per_cycle: f64, closure_opening_fraction: f64, gauge_x_over_w: f64, gauge_y_m: f64, seed: u64) -> PyResult<usize> {
        let m = crate::engine::Measurement {
            crack: crate::engine::CrackSource::parse(crack)?, noise, resolution, drift_per_cycle, closure_opening_fraction, gauge_x_over_w, gauge_y_m, seed,
            ..crate::engine::Measurement::model()
        };
        Ok(self.inner.add_gauge(&m)?)
    }
    /// The gauges' readings after the last step (NaN before the first and once broken).
    #[getter]
    fn gauge_readings(&self) -> Vec<f64> {
        self.inner.gauge_readings.clone()
    }
    /// Gauge `i`'s offset from slips [m].
    fn gauge_offset(&self, i: usize) -> PyResult<f64> {
        self.inner.gauges.get(i).map(|g| g.offset).ok_or_else(|| InputError::new_err(format!("no gauge {i}")))
    }
    /// A gauge slip: a sudden offset of gauge `i`'s opening [m].
    fn slip_gauge(&mut self, i: usize, offset_m: f64) -> PyResult<()> {
        let g = self.inner.gauges.get_mut(i).ok_or_else(|| InputError::new_err(format!("no gauge {i}")))?;
        g.offset += offset_m;
        Ok(())
    }
    #[getter]
    fn cycles(&self) -> u64 {
        self.inner.specimen.as_ref().map(|s| s.cycles).unwrap_or(0)
    }
    #[getter]
    fn fractured(&self) -> bool {
        self.inner.specimen.as_ref().map(|s| s.fractured).unwrap_or(false)
    }
    #[getter]
    fn k_sp_n_m(&self) -> f64 {
        self.inner.machine.plant.p.specimen_stiffness_n_m
    }
    #[getter]
    fn valve_null_bias_v(&self) -> f64 {
        self.inner.machine.plant.p.valve_null_bias_v
    }
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyCyclic>()?;
    m.add_class::<PyDetectors>()?;
    m.add_class::<PyRigPlant>()?;
    Ok(())
}
