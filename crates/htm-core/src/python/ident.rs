//! Bindings for identification: the plant's own formulas evaluated over arrays.
use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::prelude::*;

use super::{InputError, PyParams};
use crate::friction::Friction;

/// Friction force [N] of the parameters' Stribeck model at velocities `v` [m/s] and chamber
/// pressure sums `p_sum` [Pa] (eq. 3.2 with the smoothed sign; asymmetric and pressure terms).
#[pyfunction]
fn friction_force<'py>(py: Python<'py>, params: &PyParams, v: PyReadonlyArray1<'py, f64>, p_sum: PyReadonlyArray1<'py, f64>) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let (v, ps) = (v.as_slice()?, p_sum.as_slice()?);
    if v.len() != ps.len() {
        return Err(InputError::new_err(format!("v has {} values but p_sum has {}", v.len(), ps.len())));
    }
    let f = Friction::from(&params.inner);
    let out: Vec<f64> = v.iter().zip(ps).map(|(&vi, &pi)| f.force(vi, pi)).collect();
    Ok(PyArray1::from_vec(py, out))
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(friction_force, m)?)?;
    Ok(())
}
