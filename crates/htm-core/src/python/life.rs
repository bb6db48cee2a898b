//! Bindings of the life tests (`engine::life`) and the virtual cyclic specimen: a test as a flat
//! dict of SI values (the spec's `[loading]`, `[specimen]`, `[material]`, `[end]` tables, see
//! `htm.fatigue.lifetest`), the outcome as a dict of numpy columns. No numerics here.
use numpy::PyArray1;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::{InputError, PyParams};
use crate::crack::Law;
use crate::cyclic_material::{CyclicMaterial, CyclicSpecimen};
use crate::engine::cycle::Stage;
use crate::engine::life::{run_life as run, virtual_life as vlife, Criteria, LifeConfig, LifeMachine, LifeMode, LifeOutcome, LifeRow, VirtualBar};
use crate::waveform::Envelope;

const KEYS: &[&str] = &[
    "mode", "amplitude", "r_ratio", "frequency_hz", "control_rate_hz", "rtol", "mean_cycles", "amplitude_cycles", "e_pa", "k_prime_pa",
    "n_prime", "sigma_f_pa", "b", "eps_f", "c", "transient", "transient_cycles", "fracture_toughness_pa_sqrt_m", "paris_c", "paris_m",
    "diameter_m", "a_init_m", "life_factor", "gauge_length_m", "load_train_n_m", "drop", "modulus_ratio_drop", "separation",
    "runout_cycles", "loops_per_decade", "jump", "velocity_gain_m_s_per_v",
];

fn config(d: &Bound<'_, PyDict>, params: Option<&PyParams>) -> PyResult<LifeConfig> {
    for k in d.keys() {
        let k: String = k.extract()?;
        if !KEYS.contains(&k.as_str()) {
            return Err(InputError::new_err(format!("life test: unknown key `{k}`")));
        }
    }
    let f = |k: &str, dflt: f64| -> PyResult<f64> {
        match d.get_item(k)? {
            Some(v) if !v.is_none() => v.extract::<f64>().map_err(|_| InputError::new_err(format!("life test: `{k}` must be a number"))),
            _ => Ok(dflt),
        }
    };
    let mode = match d.get_item("mode")? {
        Some(v) => match v.extract::<String>()?.as_str() {
            "force_life" => LifeMode::Force,
            "strain_life" => LifeMode::Strain,
            o => return Err(InputError::new_err(format!("loading.mode = `{o}`: use force_life or strain_life"))),
        },
        None => return Err(InputError::new_err("loading.mode is missing")),
    };
    let amplitude = match d.get_item("amplitude")? {
        Some(v) => v.extract::<f64>()?,
        None => return Err(InputError::new_err("loading amplitude is missing")),
    };
    let dm = CyclicMaterial::default();
    let material = CyclicMaterial {
        e_pa: f("e_pa", dm.e_pa)?, k_prime_pa: f("k_prime_pa", dm.k_prime_pa)?, n_prime: f("n_prime", dm.n_prime)?,
        sigma_f_pa: f("sigma_f_pa", dm.sigma_f_pa)?, b: f("b", dm.b)?, eps_f: f("eps_f", dm.eps_f)?, c: f("c", dm.c)?,
        transient: f("transient", dm.transient)?, transient_cycles: f("transient_cycles", dm.transient_cycles)?,
    };
    // a steel's Paris law in SI (1e-11 m/cycle at 1 MPa·√m, m = 3)
    let m = f("paris_m", 3.0)?;
    let law = Law::Paris { c: f("paris_c", 1e-11 / 1e6f64.powf(3.0))?, m };
    let specimen = CyclicSpecimen::new(material, f("diameter_m", 6.35e-3)?, f("a_init_m", 0.1e-3)?, law,
        f("fracture_toughness_pa_sqrt_m", 60e6)?, f("life_factor", 1.0)?)?;
    let freq = f("frequency_hz", 5.0)?;
    let runout = f("runout_cycles", 1e7)?;
    if !(1.0..=1e12).contains(&runout) {
        return Err(crate::error::Error::Parameter { field: "end.runout_cycles".into(), value: runout, allowed: "[1, 1e12]".into() }.into());
    }
    let jump = match d.get_item("jump")? {
        Some(v) => v.extract::<bool>()?,
        None => true,
    };
    let vg = match d.get_item("velocity_gain_m_s_per_v")? {
        Some(v) if !v.is_none() => Some(v.extract::<f64>()?),
        _ => None,
    };
    Ok(LifeConfig {
        params: params.map(|p| p.inner.clone()).unwrap_or_default(), rtol: f("rtol", 1e-4)?, mode, amplitude,
        r_ratio: f("r_ratio", -1.0)?, frequency_hz: freq, control_rate_hz: f("control_rate_hz", 80.0 * freq)?,
        envelope: Envelope { mean_cycles: f("mean_cycles", 1.0)?, amplitude_cycles: f("amplitude_cycles", 5.0)?, stop_cycles: 1.0 },
        specimen, gauge_length_m: f("gauge_length_m", 25e-3)?, load_train_n_m: f("load_train_n_m", 5e8)?,
        criteria: Criteria { drop: f("drop", 0.5)?, modulus_ratio_drop: f("modulus_ratio_drop", 0.0)?, separation: f("separation", 0.1)?,
            runout_cycles: runout as u64 },
        loops_per_decade: f("loops_per_decade", 5.0)?.clamp(1.0, 100.0) as u32, jump, velocity_gain_m_s_per_v: vg,
    })
}

fn outcome<'py>(py: Python<'py>, o: LifeOutcome) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let r = o.records;
    let t = PyDict::new(py);
    t.set_item("cycle", PyArray1::from_vec(py, r.cycle))?;
    for (k, v) in [("fmax_n", r.fmax_n), ("fmin_n", r.fmin_n), ("stress_max_pa", r.stress_max_pa), ("stress_min_pa", r.stress_min_pa),
        ("strain_max", r.strain_max), ("strain_min", r.strain_min), ("plastic_strain_range", r.plastic_strain_range),
        ("modulus_t_pa", r.modulus_t_pa), ("modulus_c_pa", r.modulus_c_pa), ("stiffness_n_m", r.stiffness_n_m), ("trend", r.trend)] {
        t.set_item(k, PyArray1::from_vec(py, v))?;
    }
    t.set_item("events", PyArray1::from_vec(py, r.events))?;
    d.set_item("table", t)?;
    let l = PyDict::new(py);
    l.set_item("cycle", PyArray1::from_vec(py, o.loops.cycle))?;
    l.set_item("strain", PyArray1::from_vec(py, o.loops.strain))?;
    l.set_item("stress_pa", PyArray1::from_vec(py, o.loops.stress_pa))?;
    d.set_item("loops", l)?;
    d.set_item("end_reason", o.end.name())?;
    d.set_item("failed", o.end.failed())?;
    d.set_item("cycles", o.cycles)?;
    d.set_item("n_drop10", o.n_drop10)?;
    d.set_item("n_drop50", o.n_drop50)?;
    d.set_item("n_modulus", o.n_modulus)?;
    d.set_item("cycles_simulated", o.cycles_simulated)?;
    d.set_item("velocity_gain_m_s_per_v", o.velocity_gain_m_s_per_v)?;
    let tr = PyDict::new(py);
    tr.set_item("life_factor", o.truth.life_factor)?;
    tr.set_item("n_init", o.truth.n_init)?;
    tr.set_item("n_phi10", o.truth.n_phi10)?;
    tr.set_item("n_phi50", o.truth.n_phi50)?;
    tr.set_item("n_sep", o.truth.n_sep)?;
    d.set_item("truth", tr)?;
    Ok(d)
}

/// Run a life test (force_life or strain_life) on the simulated rig with the virtual round bar;
/// the GIL is released. Returns a dict: `table` (per-cycle columns), `loops` (kept hysteresis
/// loops), `end_reason`, `failed`, `cycles`, `n_drop10`, `n_drop50`, `n_modulus`,
/// `cycles_simulated`, `truth` (the virtual specimen's hidden milestones).
#[pyfunction]
#[pyo3(signature = (spec, params = None))]
fn run_life<'py>(py: Python<'py>, spec: &Bound<'py, PyDict>, params: Option<PyRef<'py, PyParams>>) -> PyResult<Bound<'py, PyDict>> {
    let cfg = config(spec, params.as_deref())?;
    let o = py.detach(|| run(&cfg, None, None))?;
    outcome(py, o)
}

/// Run many life tests on `threads` cores (0 = all); results in input order, each a dict or,
/// for a test that failed, its `HtmError`.
#[pyfunction]
#[pyo3(signature = (specs, params = None, threads = 0))]
fn run_life_batch<'py>(py: Python<'py>, specs: Vec<Bound<'py, PyDict>>, params: Option<PyRef<'py, PyParams>>, threads: usize) -> PyResult<Vec<Py<PyAny>>> {
    let cfgs = specs.iter().map(|s| config(s, params.as_deref())).collect::<PyResult<Vec<_>>>()?;
    let outs = py.detach(|| crate::batch::par_map(&cfgs, threads, |c| run(c, None, None)));
    outs.into_iter().map(|o| match o {
        Ok(o) => Ok(outcome(py, o)?.into_any().unbind()),
        Err(e) => Ok(PyErr::from(e).into_value(py).into_any()),
    }).collect()
}

/// The virtual specimen's life at the test's amplitude without a controller (its true loop from
/// the cyclic curve): (N_init, N_50, N_sep) [cycles].
#[pyfunction]
fn virtual_life(spec: &Bound<'_, PyDict>) -> PyResult<(f64, f64, f64)> {
    let cfg = config(spec, None)?;
    cfg.validate()?; // every value judged (the spec's checker calls this)
    Ok(vlife(&cfg))
}

/// Stress amplitude [Pa] of the cyclic curve ε_a = σ_a/E + (σ_a/K′)^(1/n′) at strain amplitude `ea`.
#[pyfunction]
fn cyclic_stress(ea: f64, e_pa: f64, k_prime_pa: f64, n_prime: f64) -> f64 {
    let m = CyclicMaterial { e_pa, k_prime_pa, n_prime, ..CyclicMaterial::default() };
    m.stress_of(ea, k_prime_pa).0
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(run_life, m)?)?;
    m.add_function(wrap_pyfunction!(run_life_batch, m)?)?;
    m.add_function(wrap_pyfunction!(virtual_life, m)?)?;
    m.add_function(wrap_pyfunction!(cyclic_stress, m)?)?;
    m.add_class::<PyLifeController>()?;
    m.add_class::<PyLifeRig>()?;
    Ok(())
}

/// The controller side of a life test for a rig loop (`engine::life::LifeMachine`, the same code
/// `run_life` runs): `command(f, strain, y)` once per control period with the measured force [N],
/// extensometer strain and piston position [m], the valve command [V] back; `at_end` when the
/// cycle's last period was commanded, then `close()` (the cycle's row as a dict) and `next_cycle()`.
#[pyclass(name = "LifeController", module = "htm._core")]
pub struct PyLifeController {
    cfg: LifeConfig,
    lm: LifeMachine,
    last: Option<LifeRow>,
    results: u64,
}

#[pymethods]
impl PyLifeController {
    #[new]
    #[pyo3(signature = (spec, f0, strain0, params = None))]
    fn new(spec: &Bound<'_, PyDict>, f0: f64, strain0: f64, params: Option<PyRef<'_, PyParams>>) -> PyResult<Self> {
        let cfg = config(spec, params.as_deref())?;
        cfg.validate()?;
        let s0 = if cfg.mode == LifeMode::Strain { strain0 * cfg.ea() } else { f0 };
        let lm = LifeMachine::new(&cfg, s0)?;
        Ok(PyLifeController { cfg, lm, last: None, results: 0 })
    }
    /// control period [s] and samples per cycle
    #[getter]
    fn dt(&self) -> f64 {
        self.lm.dt
    }
    #[getter]
    fn samples_per_cycle(&self) -> usize {
        self.lm.n
    }
    #[getter]
    fn cycle(&self) -> u64 {
        self.lm.cycle
    }
    /// why the test ended (None while it runs)
    #[getter]
    fn end_reason(&self) -> Option<&'static str> {
        self.lm.end.map(|e| e.name())
    }
    fn command(&mut self, f: f64, strain: f64, y: f64) -> f64 {
        self.lm.command(&self.cfg, f, strain, y)
    }
    fn at_end(&self) -> bool {
        self.lm.at_end()
    }
    fn close<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let r = self.lm.close(&self.cfg);
        let d = PyDict::new(py);
        d.set_item("cycle", r.cycle)?;
        for (k, v) in [("fmax_n", r.fmax_n), ("fmin_n", r.fmin_n), ("strain_max", r.strain_max), ("strain_min", r.strain_min),
            ("plastic_strain_range", r.plastic_strain_range), ("modulus_t_pa", r.modulus_t_pa), ("modulus_c_pa", r.modulus_c_pa),
            ("stiffness_n_m", r.stiffness_n_m), ("trend", r.trend)] {
            d.set_item(k, v)?;
        }
        d.set_item("events", r.events)?;
        d.set_item("keep_loop", r.keep_loop)?;
        Ok(d)
    }
    fn next_cycle(&mut self) {
        self.lm.next_cycle()
    }

    /// One control period of a rig's loop (`LifeMachine::step`): measured force [N], strain and
    /// piston position [m] in, the valve command [V] out; a counted cycle that closed with this
    /// period is `last_cycle()` (and `results` counts up).
    fn step(&mut self, f: f64, strain: f64, y: f64) -> f64 {
        let (u, row) = self.lm.step(&self.cfg, f, strain, y);
        if let Some(r) = row {
            self.last = Some(r);
            self.results += 1;
        }
        if u.is_finite() { u } else { 0.0 }
    }
    /// The stage: starting, running, holding, stopping, stopped.
    #[getter]
    fn state(&self) -> &'static str {
        match self.lm.stage {
            Stage::Starting => "starting",
            Stage::Running => "running",
            Stage::Holding => "holding",
            Stage::Stopping => "stopping",
            Stage::Stopped => "stopped",
        }
    }
    /// Counted cycles closed so far (a new one is `last_cycle()`).
    #[getter]
    fn results(&self) -> u64 {
        self.results
    }
    /// The valve null once stopped [V].
    #[getter]
    fn u_null_v(&self) -> f64 {
        self.lm.u_null
    }
    /// The controlled signal's (max, min) at full amplitude: force [N] (force_life) or strain.
    #[getter]
    fn targets(&self) -> (f64, f64) {
        let (hi, lo) = self.cfg.targets();
        let s = if self.cfg.mode == LifeMode::Strain { 1.0 / self.cfg.ea() } else { 1.0 };
        (hi * s, lo * s)
    }
    /// Samples per cycle and the test frequency run [Hz].
    #[getter]
    fn frequency_hz(&self) -> f64 {
        self.cfg.frequency_hz
    }
    #[getter]
    fn n_drop10(&self) -> Option<u64> {
        self.lm.n_drop10
    }
    #[getter]
    fn n_drop50(&self) -> Option<u64> {
        self.lm.n_drop50
    }
    #[getter]
    fn velocity_gain_m_s_per_v(&self) -> f64 {
        self.lm.velocity_gain
    }
    /// Hold: the amplitude ramps to zero at the mean over one cycle (False when no test runs).
    fn hold(&mut self) -> bool {
        self.lm.hold()
    }
    /// Resume after a hold (False when not held).
    fn resume(&mut self) -> bool {
        self.lm.resume(&self.cfg)
    }
    /// Ramp down over the stop cycles, then the valve null.
    fn stop(&mut self) {
        self.lm.stop(&self.cfg)
    }
    /// The last counted cycle's row (as `close()`'s), or None.
    fn last_cycle<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        self.last.as_ref().map(|r| row_dict(py, r, self.cfg.specimen.area_m2())).transpose()
    }
    /// The last counted cycle's samples: (strain, stress [Pa]) arrays.
    fn last_loop<'py>(&self, py: Python<'py>) -> (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>) {
        let e: Vec<f64> = self.lm.last_loop.iter().map(|p| p.1).collect();
        let s: Vec<f64> = self.lm.last_loop.iter().map(|p| p.0).collect();
        (PyArray1::from_vec(py, e), PyArray1::from_vec(py, s))
    }
}

fn row_dict<'py>(py: Python<'py>, r: &LifeRow, area: f64) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("cycle", r.cycle)?;
    for (k, v) in [("fmax_n", r.fmax_n), ("fmin_n", r.fmin_n), ("stress_max_pa", r.fmax_n / area), ("stress_min_pa", r.fmin_n / area),
        ("strain_max", r.strain_max), ("strain_min", r.strain_min), ("plastic_strain_range", r.plastic_strain_range),
        ("modulus_t_pa", r.modulus_t_pa), ("modulus_c_pa", r.modulus_c_pa), ("stiffness_n_m", r.stiffness_n_m), ("trend", r.trend)] {
        d.set_item(k, v)?;
    }
    d.set_item("events", r.events)?;
    d.set_item("keep_loop", r.keep_loop)?;
    Ok(d)
}

/// The virtual rig of a life test: the plant with the virtual bar (hidden truth) behind sensors.
/// `measure()` and `step(u, dt)` give (force [N], extensometer strain, piston position [m]); the
/// bar closes its own true loop every load cycle.
#[pyclass(name = "LifeRig", module = "htm._core")]
pub struct PyLifeRig {
    vb: VirtualBar,
}

#[pymethods]
impl PyLifeRig {
    #[new]
    #[pyo3(signature = (spec, params = None))]
    fn new(spec: &Bound<'_, PyDict>, params: Option<PyRef<'_, PyParams>>) -> PyResult<Self> {
        Ok(PyLifeRig { vb: VirtualBar::new(&config(spec, params.as_deref())?)? })
    }
    fn measure(&self) -> (f64, f64, f64) {
        self.vb.measure()
    }
    fn step(&mut self, u: f64, dt: f64) -> PyResult<(f64, f64, f64)> {
        Ok(self.vb.step(u, dt)?)
    }
    /// Every sensor now: (y [m], v [m/s], p_a, p_b, p_s [Pa], force [N], strain).
    fn outputs(&self) -> (f64, f64, f64, f64, f64, f64, f64) {
        self.vb.outputs()
    }
    /// `step`, returning every sensor as `outputs()` does.
    fn step_all(&mut self, u: f64, dt: f64) -> PyResult<(f64, f64, f64, f64, f64, f64, f64)> {
        self.vb.step(u, dt)?;
        Ok(self.vb.outputs())
    }
    /// Relief-valve setpoint [Pa] (the supply follows with its lag, as `RigPlant`'s).
    #[getter]
    fn get_supply_setpoint_pa(&self) -> f64 {
        self.vb.rp.supply_setpoint_pa
    }
    #[setter]
    fn set_supply_setpoint_pa(&mut self, v: f64) -> PyResult<()> {
        Ok(self.vb.rp.set_supply_setpoint_pa(v)?)
    }
    #[getter]
    fn valve_null_bias_v(&self) -> f64 {
        self.vb.rp.machine.plant.p.valve_null_bias_v
    }
    /// The bar's hidden truth now: cycles it has seen, damage, crack depth [m], separated, life
    /// factor and the milestones (initiation, tensile stiffness −10 % / −50 %, separation;
    /// NaN until reached) [cycles].
    fn truth<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = &self.vb.spec;
        let nan = |o: Option<f64>| o.unwrap_or(f64::NAN);
        let d = PyDict::new(py);
        d.set_item("cycles", s.n)?;
        d.set_item("damage", s.damage)?;
        d.set_item("a_m", s.a_m)?;
        d.set_item("separated", s.separated)?;
        d.set_item("life_factor", s.life_factor)?;
        d.set_item("n_init", nan(s.n_init))?;
        d.set_item("n_phi10", nan(s.n_phi10))?;
        d.set_item("n_phi50", nan(s.n_phi50))?;
        d.set_item("n_sep", nan(s.n_sep))?;
        Ok(d)
    }
}
