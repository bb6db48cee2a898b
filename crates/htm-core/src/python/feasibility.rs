//! Thin binding of `feasibility::assess`: a `TestConfig` in, one dict per check out.
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use super::convert::PyTestConfig;
use crate::feasibility;

/// Every feasibility check of a test config (SI): name, status ("ok", "marginal", "refused"),
/// need and limit with their unit, where it binds (phase, a_m), the ΔF asked there and the
/// largest ΔF and frequency the limit allows (None when it does not bound them).
#[pyfunction]
#[pyo3(name = "feasibility")]
fn assess<'py>(py: Python<'py>, config: PyRef<'py, PyTestConfig>) -> PyResult<Bound<'py, PyList>> {
    let cfg = std::sync::Arc::clone(&config.inner);
    let checks = py.detach(|| feasibility::assess(&cfg))?;
    let finite = |v: f64| v.is_finite().then_some(v);
    let out = PyList::empty(py);
    for c in checks {
        let d = PyDict::new(py);
        d.set_item("name", c.name)?;
        d.set_item("status", c.status.name())?;
        d.set_item("need", c.need)?;
        d.set_item("limit", c.limit)?;
        d.set_item("unit", c.unit)?;
        d.set_item("phase", c.phase)?;
        d.set_item("a_m", c.a_m)?;
        d.set_item("delta_f_n", c.delta_f_n)?;
        d.set_item("largest_delta_f_n", finite(c.largest_delta_f_n))?;
        d.set_item("largest_frequency_hz", finite(c.largest_frequency_hz))?;
        out.append(d)?;
    }
    Ok(out)
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("MARGINAL_FRACTION", feasibility::MARGINAL_FRACTION)?;
    m.add("RESONANCE_FRACTION", feasibility::RESONANCE_FRACTION)?;
    m.add_function(wrap_pyfunction!(assess, m)?)?;
    Ok(())
}
