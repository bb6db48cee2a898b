//! Bindings for the reduced displacement-loop model (`outer_loop`).
use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::{py_err, InputError};
use crate::outer_loop::{simulate, LoopParams};

const NAMES: [&str; 8] = ["gain", "bandwidth_hz", "delay_s", "offset_m", "load_m_s_per_n", "asymmetry", "valve_bandwidth_hz", "friction_m_s"];

fn params_from(d: &Bound<'_, PyDict>) -> PyResult<LoopParams> {
    let mut p = LoopParams::default();
    for (k, v) in d.iter() {
        let key: String = k.extract()?;
        let v: f64 = v.extract()?;
        match key.as_str() {
            "gain" => p.gain = v,
            "bandwidth_hz" => p.bandwidth_hz = v,
            "delay_s" => p.delay_s = v,
            "offset_m" => p.offset_m = v,
            "load_m_s_per_n" => p.load_m_s_per_n = v,
            "asymmetry" => p.asymmetry = v,
            "valve_bandwidth_hz" => p.valve_bandwidth_hz = v,
            "friction_m_s" => p.friction_m_s = v,
            _ => return Err(InputError::new_err(format!("unknown displacement-loop parameter `{key}` (known: {})", NAMES.join(", ")))),
        }
    }
    Ok(p)
}

/// Position [m] predicted by the displacement-loop model with parameters `params` (dict of SI
/// values; missing keys take their defaults) from the command `y_ref` [m] and load `f` [N].
#[pyfunction]
fn outer_loop_simulate<'py>(py: Python<'py>, params: &Bound<'py, PyDict>, y_ref: PyReadonlyArray1<'py, f64>, f: PyReadonlyArray1<'py, f64>, dt: f64) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let p = params_from(params)?;
    let (r, f) = (y_ref.as_slice()?, f.as_slice()?);
    let y = py.detach(|| simulate(&p, r, f, dt)).map_err(py_err)?;
    Ok(PyArray1::from_vec(py, y))
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(outer_loop_simulate, m)?)?;
    Ok(())
}
