//! Bindings of the displacement-loop model (`outer_loop`): its parameter set and batched
//! simulation with the GIL released.
use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::exceptions::PyKeyError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use super::{field_table, values_dict, InputError};
use crate::outer_loop::{simulate_batch, validate_input, LoopOutput, LoopParams, LOOP_FIELDS, STALL_FORCE_KEY};

/// Parameters of a machine's closed displacement loop (SI); `LoopParams()` has every effect off.
#[pyclass(name = "LoopParams", module = "htm._core", from_py_object)]
#[derive(Clone)]
pub struct PyLoopParams {
    pub inner: LoopParams,
}

#[pymethods]
impl PyLoopParams {
    #[new]
    fn new() -> Self {
        PyLoopParams { inner: LoopParams::default() }
    }

    fn __getitem__(&self, name: &str) -> PyResult<f64> {
        self.inner.get(name).ok_or_else(|| PyKeyError::new_err(format!("unknown displacement-loop parameter `{name}`")))
    }

    fn __setitem__(&mut self, name: &str, value: f64) -> PyResult<()> {
        if self.inner.get(name).is_none() {
            return Err(PyKeyError::new_err(format!("unknown displacement-loop parameter `{name}`")));
        }
        self.inner.set(name, value).map_err(PyErr::from)
    }

    fn __contains__(&self, name: &str) -> bool {
        self.inner.get(name).is_some()
    }

    /// Names of the fields (the derived `load_stall_force_n` is readable too).
    fn keys(&self) -> Vec<&'static str> {
        LOOP_FIELDS.iter().map(|f| f.name).collect()
    }

    /// Raise ParameterError naming the first field out of range.
    fn validate(&self) -> PyResult<()> {
        self.inner.validate().map_err(PyErr::from)
    }

    fn copy(&self) -> Self {
        self.clone()
    }

    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        values_dict(py, LOOP_FIELDS, |name| self.inner.get(name))
    }

    /// Name, unit, documentation and allowed range of every field.
    #[staticmethod]
    fn fields<'py>(py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        field_table(py, LOOP_FIELDS)
    }

    #[classattr]
    fn stall_force_key() -> &'static str {
        STALL_FORCE_KEY
    }

    fn __repr__(&self) -> String {
        let p = &self.inner;
        format!("LoopParams(gain={}, bandwidth_hz={}, delay_s={}, feedforward={}, ...)", p.gain, p.bandwidth_hz, p.delay_s, p.feedforward)
    }
}

fn output_dict<'py>(py: Python<'py>, r: crate::Result<LoopOutput>, n: usize) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    match r {
        Ok(o) => {
            d.set_item("y", PyArray1::from_vec(py, o.y))?;
            d.set_item("v", PyArray1::from_vec(py, o.v))?;
            d.set_item("f", PyArray1::from_vec(py, o.f))?;
            d.set_item("error", py.None())?;
        }
        Err(e) => {
            for c in ["y", "v", "f"] {
                d.set_item(c, PyArray1::from_vec(py, vec![f64::NAN; n]))?;
            }
            d.set_item("error", e.to_string())?;
        }
    }
    Ok(d)
}

/// The displacement-loop model run with every parameter set in `params` (list of LoopParams)
/// on the command `y_ref` [m] sampled every `dt` [s] (NaN = dropped, previous value held);
/// `load`, the recorded load cell [N] if any, is the force that loads the loop.
/// Returns one dict per parameter set: `y` [m], `v` [m/s], `f` [N] per sample and `error`
/// (None, or the message with NaN arrays). The batch runs on `threads` threads (0 = all cores)
/// with the GIL released. Bad arguments raise.
#[pyfunction]
#[pyo3(signature = (params, dt, y_ref, load = None, threads = 0))]
fn loop_simulate<'py>(py: Python<'py>, params: Vec<PyLoopParams>, dt: f64, y_ref: PyReadonlyArray1<'py, f64>,
                      load: Option<PyReadonlyArray1<'py, f64>>, threads: usize) -> PyResult<Bound<'py, PyList>> {
    let r = y_ref.as_slice()?;
    validate_input(dt, r)?;
    let f = match &load {
        Some(a) => Some(a.as_slice()?),
        None => None,
    };
    if let Some(f) = f {
        if f.len() != r.len() {
            return Err(InputError::new_err(format!("load has {} samples but y_ref has {}", f.len(), r.len())));
        }
    }
    let ps: Vec<LoopParams> = params.into_iter().map(|p| p.inner).collect();
    if ps.is_empty() {
        return Err(InputError::new_err("loop_simulate needs at least one parameter set"));
    }
    let results = py.detach(|| simulate_batch(&ps, dt, r, f, threads));
    let out = PyList::empty(py);
    for res in results {
        out.append(output_dict(py, res, r.len())?)?;
    }
    Ok(out)
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyLoopParams>()?;
    m.add_function(wrap_pyfunction!(loop_simulate, m)?)?;
    Ok(())
}
