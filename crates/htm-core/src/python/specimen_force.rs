//! Bindings of the specimen and load-train force model (`specimen_force`): its parameter set and
//! batched evaluation with the GIL released.
use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::prelude::*;
use pyo3::types::PyList;

use super::convert::ParamSet;
use super::InputError;
use crate::params::Field;
use crate::specimen_force::{force_batch, spring_from_samples, validate_input, SpecimenParams, SPECIMEN_FIELDS};

impl ParamSet for SpecimenParams {
    const WHAT: &'static str = "specimen parameter";
    fn fields() -> &'static [Field] {
        SPECIMEN_FIELDS
    }
    fn get(&self, name: &str) -> Option<f64> {
        SpecimenParams::get(self, name)
    }
    fn set(&mut self, name: &str, value: f64) -> crate::Result<()> {
        SpecimenParams::set(self, name, value)
    }
    fn validate(&self) -> crate::Result<()> {
        SpecimenParams::validate(self)
    }
}

/// Parameters of a specimen and its load train (SI); `SpecimenParams()` has every effect off.
#[pyclass(name = "SpecimenParams", module = "htm._core", from_py_object)]
#[derive(Clone)]
pub struct PySpecimenParams {
    pub inner: SpecimenParams,
}

super::convert::param_set_class!(PySpecimenParams, SpecimenParams, {
    #[new]
    fn new() -> Self {
        PySpecimenParams { inner: SpecimenParams::default() }
    }

    fn __repr__(&self) -> String {
        let p = &self.inner;
        format!("SpecimenParams(specimen_stiffness_n_m={}, specimen_friction_n={}, load_train_gap_m={}, ...)",
                p.specimen_stiffness_n_m, p.specimen_friction_n, p.load_train_gap_m)
    }
});

/// The load cell's force [N] the specimen model gives for each parameter set in `params` (list of
/// SpecimenParams), driven by the displacement `y` [m] sampled every `dt` [s] (NaN = dropped,
/// previous value held). Returns one item per parameter set: the force array, or the `HtmError`
/// of a set that cannot be evaluated (a parameter out of range). The batch runs on `threads`
/// threads (0 = all cores) with the GIL released. Bad arguments raise.
#[pyfunction]
#[pyo3(signature = (params, dt, y, threads = 0))]
fn specimen_force<'py>(py: Python<'py>, params: Vec<PySpecimenParams>, dt: f64, y: PyReadonlyArray1<'py, f64>,
                       threads: usize) -> PyResult<Bound<'py, PyList>> {
    let y = y.as_slice()?;
    validate_input(dt, y)?;
    let ps: Vec<SpecimenParams> = params.into_iter().map(|p| p.inner).collect();
    if ps.is_empty() {
        return Err(InputError::new_err("specimen_force needs at least one parameter set"));
    }
    let results = py.detach(|| force_batch(&ps, dt, y, threads));
    let out = PyList::empty(py);
    for res in results {
        match res {
            Ok(f) => out.append(PyArray1::from_vec(py, f))?,
            Err(e) => out.append(PyErr::from(e).into_value(py))?,
        }
    }
    Ok(out)
}

/// The bilinear spring a record's force `f` [N] shows against its displacement `y` [m]
/// (`spring_from_samples`): (stiffness [N/m], closure stiffness [N/m], closure position [m], in
/// the record's coordinates), or None where no corner makes it stiffer below. A start for a fit.
#[pyfunction]
fn closure_spring<'py>(py: Python<'py>, f: PyReadonlyArray1<'py, f64>, y: PyReadonlyArray1<'py, f64>) -> PyResult<Option<(f64, f64, f64)>> {
    let (f, y) = (f.as_slice()?, y.as_slice()?);
    if f.len() != y.len() {
        return Err(InputError::new_err(format!("f has {} values but y has {}", f.len(), y.len())));
    }
    Ok(py.detach(|| spring_from_samples(f, y)))
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(closure_spring, m)?)?;
    m.add_class::<PySpecimenParams>()?;
    m.add_function(wrap_pyfunction!(specimen_force, m)?)?;
    Ok(())
}
