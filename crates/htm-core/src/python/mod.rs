//! Thin pyo3 bindings: convert, release the GIL, map errors. No numerics here.
use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::machine::{Machine, Outputs, NX};
use crate::params::Params;
use convert::controller_from;
use crate::run::{self, Trace};
use crate::solver::Stats;

mod arrow;
mod control;
mod convert;
mod engine;
mod fatigue;
mod feasibility;
mod ident;
mod life;
mod measure;
mod outer_loop;
mod replay;
mod specimen_force;

// Submodules add their own classes and functions here.
pub(crate) fn register_extensions(m: &Bound<'_, PyModule>) -> PyResult<()> {
    convert::register(m)?;
    fatigue::register(m)?;
    feasibility::register(m)?;
    control::register(m)?;
    engine::register(m)?;
    ident::register(m)?;
    life::register(m)?;
    measure::register(m)?;
    outer_loop::register(m)?;
    replay::register(m)?;
    specimen_force::register(m)?;
    Ok(())
}

create_exception!(htm._core, HtmError, PyException, "Base class of every htm error.");
create_exception!(htm._core, ParameterError, HtmError, "A parameter is outside its allowed range.");
create_exception!(htm._core, InputError, HtmError, "An input signal or argument is unusable.");
create_exception!(htm._core, SolverError, HtmError, "The integrator could not meet its tolerance.");

/// Machine parameters (SI); `Params()` is the thesis rig, `Params("base")` the same rig with
/// a linear valve characteristic.
#[pyclass(name = "Params", module = "htm._core", from_py_object)]
#[derive(Clone)]
pub struct PyParams {
    pub inner: Params,
}

convert::param_set_class!(PyParams, Params, {
    #[new]
    #[pyo3(signature = (preset = "thesis"))]
    fn new(preset: &str) -> PyResult<Self> {
        let inner = match preset {
            "thesis" => Params::default(),
            "base" => Params::base(),
            other => return Err(InputError::new_err(format!("unknown preset `{other}`: use \"thesis\" or \"base\""))),
        };
        Ok(PyParams { inner })
    }

    /// Command-to-spool knots (command after bias [V], spool [V]); empty lists = linear.
    #[getter]
    fn get_valve_map(&self) -> (Vec<f64>, Vec<f64>) {
        (self.inner.valve_map_command_v.clone(), self.inner.valve_map_spool_v.clone())
    }

    #[setter]
    fn set_valve_map(&mut self, knots: (Vec<f64>, Vec<f64>)) {
        self.inner.valve_map_command_v = knots.0;
        self.inner.valve_map_spool_v = knots.1;
    }

    fn __repr__(&self) -> String {
        format!("Params(supply_pressure_pa={}, moving_mass_kg={}, specimen_stiffness_n_m={}, ...)",
            self.inner.supply_pressure_pa, self.inner.moving_mass_kg, self.inner.specimen_stiffness_n_m)
    }
});

fn outputs_dict<'py>(py: Python<'py>, o: &Outputs) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("y", o.y)?;
    d.set_item("v", o.v)?;
    d.set_item("p_a", o.p_a)?;
    d.set_item("p_b", o.p_b)?;
    d.set_item("p_s", o.p_s)?;
    d.set_item("f", o.f)?;
    d.set_item("spool", o.spool)?;
    Ok(d)
}

fn stats_dict<'py>(py: Python<'py>, s: &Stats) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("accepted_steps", s.accepted)?;
    d.set_item("rejected_steps", s.rejected)?;
    d.set_item("rhs_evals", s.rhs_evals)?;
    Ok(d)
}

fn trace_dict<'py>(py: Python<'py>, tr: Trace) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("stats", stats_dict(py, &tr.stats)?)?;
    for (name, v) in [("t", tr.t), ("u", tr.u), ("y", tr.y), ("v", tr.v), ("p_a", tr.p_a), ("p_b", tr.p_b), ("p_s", tr.p_s), ("f", tr.f)] {
        d.set_item(name, PyArray1::from_vec(py, v))?;
    }
    Ok(d)
}


/// The plant with its state and integrator; step it one held command at a time.
#[pyclass(name = "Machine", module = "htm._core")]
pub struct PyMachine {
    inner: Machine,
}

#[pymethods]
impl PyMachine {
    #[new]
    #[pyo3(signature = (params = None, rtol = None))]
    fn new(params: Option<PyParams>, rtol: Option<f64>) -> PyResult<Self> {
        let p = params.map(|p| p.inner).unwrap_or_default();
        let mut m = Machine::new(p)?;
        if let Some(r) = rtol {
            m = m.with_rtol(r)?;
        }
        Ok(PyMachine { inner: m })
    }

    /// Hold command `u` [V] for `dt` [s]; returns the sensor readings at the end of the period.
    fn step<'py>(&mut self, py: Python<'py>, u: f64, dt: f64) -> PyResult<Bound<'py, PyDict>> {
        let m = &mut self.inner;
        let o = py.detach(|| m.step(u, dt))?;
        outputs_dict(py, &o)
    }

    fn outputs<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        outputs_dict(py, &self.inner.outputs())
    }

    /// State [p_a Pa, p_b Pa, y m, v m/s, spool V, spool velocity V/s, lagged command V].
    #[getter]
    fn get_state<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.inner.x)
    }

    #[setter]
    fn set_state(&mut self, x: PyReadonlyArray1<'_, f64>) -> PyResult<()> {
        let s = x.as_slice()?;
        let arr: [f64; NX] = s.try_into().map_err(|_| InputError::new_err(format!("state needs {NX} values, got {}", s.len())))?;
        self.inner.set_state(arr).map_err(PyErr::from)
    }

    #[getter]
    fn get_t(&self) -> f64 {
        self.inner.t
    }

    #[getter]
    fn get_stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        stats_dict(py, &self.inner.stats())
    }

    /// A state at rest at position `y` [m] (pressures carry gravity and the specimen).
    fn rest_state<'py>(&self, py: Python<'py>, y: f64) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.inner.plant.rest_state(y))
    }

    /// Time derivative of state `x` under held command `u` (for external integrators).
    fn rhs<'py>(&self, py: Python<'py>, x: PyReadonlyArray1<'_, f64>, u: f64) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let dx = run::derivatives(&self.inner, x.as_slice()?, u)?;
        Ok(PyArray1::from_slice(py, &dx))
    }

    /// Play command samples `u` [V] held `dt` [s] each from the current state (open loop).
    fn simulate<'py>(&mut self, py: Python<'py>, u: PyReadonlyArray1<'_, f64>, dt: f64) -> PyResult<Bound<'py, PyDict>> {
        let u = u.as_slice()?;
        let m = &mut self.inner;
        let tr = py.detach(|| run::simulate_open_loop(m, u, dt))?;
        trace_dict(py, tr)
    }

    /// Track `reference` with `controller` (dict as in DATA_FORMAT's `controller`).
    fn track<'py>(&mut self, py: Python<'py>, reference: PyReadonlyArray1<'_, f64>, dt: f64, controller: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyDict>> {
        let ctrl = controller_from(controller)?;
        let r = reference.as_slice()?;
        let m = &mut self.inner;
        let tr = py.detach(|| run::simulate_closed_loop(m, r, dt, &ctrl))?;
        trace_dict(py, tr)
    }
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add_class::<PyParams>()?;
    m.add_class::<PyMachine>()?;
    m.add("HtmError", py.get_type::<HtmError>())?;
    m.add("ParameterError", py.get_type::<ParameterError>())?;
    m.add("InputError", py.get_type::<InputError>())?;
    m.add("SolverError", py.get_type::<SolverError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("CHANNELS", pyo3::types::PyTuple::new(py, crate::measure::CHANNELS)?)?;
    register_extensions(m)?;
    Ok(())
}
