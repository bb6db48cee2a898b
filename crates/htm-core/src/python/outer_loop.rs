//! Bindings of the displacement-loop model (`outer_loop`): its parameter set and batched
//! simulation with the GIL released.
use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use super::InputError;
use crate::outer_loop::{simulate_batch, validate_input, LoopOutput, LoopParams, STALL_FORCE_KEY};

/// Parameters of a machine's closed displacement loop (SI); `LoopParams()` has every effect off.
#[pyclass(name = "LoopParams", module = "htm._core", from_py_object)]
#[derive(Clone)]
pub struct PyLoopParams {
    pub inner: LoopParams,
}

super::convert::param_set_class!(PyLoopParams, LoopParams, {
    #[new]
    fn new() -> Self {
        PyLoopParams { inner: LoopParams::default() }
    }

    #[classattr]
    fn stall_force_key() -> &'static str {
        STALL_FORCE_KEY
    }

    fn __repr__(&self) -> String {
        let p = &self.inner;
        format!("LoopParams(gain={}, bandwidth_hz={}, delay_s={}, feedforward={}, ...)", p.gain, p.bandwidth_hz, p.delay_s, p.feedforward)
    }
});

/// One parameter set's result: `y`, `v`, `f`, or the `HtmError` of a set the solver could not
/// carry, as the item (the batch convention of every batch call).
fn output_item<'py>(py: Python<'py>, r: crate::Result<LoopOutput>) -> PyResult<Bound<'py, PyAny>> {
    match r {
        Ok(o) => {
            let d = PyDict::new(py);
            d.set_item("y", PyArray1::from_vec(py, o.y))?;
            d.set_item("v", PyArray1::from_vec(py, o.v))?;
            d.set_item("f", PyArray1::from_vec(py, o.f))?;
            Ok(d.into_any())
        }
        Err(e) => Ok(PyErr::from(e).into_value(py).into_bound(py).into_any()),
    }
}

/// The displacement-loop model run with every parameter set in `params` (list of LoopParams)
/// on the command `y_ref` [m] sampled every `dt` [s] (NaN = dropped, previous value held);
/// `load`, the recorded load cell [N] if any, is the force that loads the loop.
/// Returns one item per parameter set: a dict of `y` [m], `v` [m/s], `f` [N] per sample, or the
/// `HtmError` (`SolverError`) of a set the solver could not carry. The batch runs on `threads` threads (0 = all cores)
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
        out.append(output_item(py, res)?)?;
    }
    Ok(out)
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyLoopParams>()?;
    m.add_function(wrap_pyfunction!(loop_simulate, m)?)?;
    Ok(())
}
