//! Thin bindings of `crack_measure`: crack size and closure from load–opening or potential-drop
//! records. Convert, release the GIL for the reduction, map errors. No numerics here.
use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::InputError;
use crate::crack_measure::{self as cm, Method};
use crate::specimen::{Geometry, Specimen};

type Array<'py> = Bound<'py, PyArray1<f64>>;

fn spec(geometry: &str, width_m: f64, thickness_m: f64) -> PyResult<Specimen> {
    Specimen::new(Geometry::parse(geometry)?, width_m, thickness_m).map_err(PyErr::from)
}

fn need(name: &str, v: Option<f64>, method: &str) -> PyResult<f64> {
    v.ok_or_else(|| InputError::new_err(format!("method `{method}` needs `{name}`")))
}

/// The measurement method from its name and constants (DATA_FORMAT's specimen entry).
#[allow(clippy::too_many_arguments)]
fn method_from(s: &Specimen, method: &str, modulus_pa: Option<f64>, cod_x_over_w: f64, cod_y_m: Option<f64>, poisson_ratio: f64,
               dcpd_probe_y_m: Option<f64>, dcpd_a_ref_m: Option<f64>, dcpd_v_ref: Option<f64>,
               calibration: Option<(Vec<f64>, Vec<f64>)>) -> PyResult<Method> {
    Ok(match (method, s.geometry) {
        ("compliance", Geometry::CT) => Method::ComplianceCt { x_over_w: cod_x_over_w, modulus_pa: need("modulus_pa", modulus_pa, method)? },
        ("compliance", Geometry::MT) => Method::ComplianceMt {
            y_m: need("cod_y_m", cod_y_m, method)?, modulus_pa: need("modulus_pa", modulus_pa, method)?, poisson_ratio,
        },
        ("potential_drop", g) => {
            // without a reference potential, the first interval's is taken at the reference crack
            let v_ref = dcpd_v_ref.unwrap_or(f64::NAN);
            match calibration {
                Some((v, a)) => Method::Calibration { v_over_vref: v, a_m: a, v_ref },
                None => Method::Johnson {
                    y_m: need("dcpd_probe_y_m", dcpd_probe_y_m, method)?,
                    a_ref_m: need("dcpd_a_ref_m", dcpd_a_ref_m, method)?,
                    v_ref,
                    width_m: if g == Geometry::CT { 2.0 * s.width_m } else { s.width_m },
                },
            }
        }
        (other, _) => return Err(InputError::new_err(format!("crack measurement `{other}` is unknown: use compliance or potential_drop"))),
    })
}

/// Reduce a load–opening (`signal` = cod [m], `f` required) or potential-drop (`signal` = V)
/// record to one row per burst or interval: returns (expression used, columns).
#[pyfunction]
#[pyo3(signature = (geometry, width_m, thickness_m, method, cycle, signal, f=None, *, modulus_pa=None, cod_x_over_w=-0.25,
                    cod_y_m=None, poisson_ratio=0.3, dcpd_probe_y_m=None, dcpd_a_ref_m=None, dcpd_v_ref=None,
                    calibration=None, cycles_per_interval=0))]
#[allow(clippy::too_many_arguments)]
fn crack_reduce<'py>(py: Python<'py>, geometry: &str, width_m: f64, thickness_m: f64, method: &str,
                     cycle: PyReadonlyArray1<'py, f64>, signal: PyReadonlyArray1<'py, f64>, f: Option<PyReadonlyArray1<'py, f64>>,
                     modulus_pa: Option<f64>, cod_x_over_w: f64, cod_y_m: Option<f64>, poisson_ratio: f64,
                     dcpd_probe_y_m: Option<f64>, dcpd_a_ref_m: Option<f64>, dcpd_v_ref: Option<f64>,
                     calibration: Option<(Vec<f64>, Vec<f64>)>, cycles_per_interval: usize) -> PyResult<(String, Bound<'py, PyDict>)> {
    let s = spec(geometry, width_m, thickness_m)?;
    let m = method_from(&s, method, modulus_pa, cod_x_over_w, cod_y_m, poisson_ratio, dcpd_probe_y_m, dcpd_a_ref_m, dcpd_v_ref, calibration)?;
    let (c, sig) = (cycle.as_slice()?, signal.as_slice()?);
    let fs = match &f {
        Some(a) => Some(a.as_slice()?),
        None => None,
    };
    let rows = py.detach(|| cm::reduce_record(&s, &m, c, fs, sig, cycles_per_interval))?;
    let d = PyDict::new(py);
    let col = |g: &dyn Fn(&cm::Interval) -> f64| rows.iter().map(g).collect::<Vec<f64>>();
    let cols: [(&str, Vec<f64>); 17] = [
        ("cycles", col(&|r| r.cycle)),
        ("n_cycles", col(&|r| r.n_cycles as f64)),
        ("a_m", col(&|r| r.a_m)),
        ("a_std_m", col(&|r| r.a_std_m)),
        ("fmin_n", col(&|r| r.fmin_n)),
        ("fmax_n", col(&|r| r.fmax_n)),
        ("value", col(&|r| r.value)),
        ("opening_force_1pct_n", col(&|r| r.opening_force_n[0])),
        ("opening_force_n", col(&|r| r.opening_force_n[1])),
        ("opening_force_4pct_n", col(&|r| r.opening_force_n[2])),
        ("opening_force_segments_n", col(&|r| r.opening_force_segments_n)),
        ("dk_pa_sqrt_m", col(&|r| r.dk)),
        ("dk_eff_pa_sqrt_m", col(&|r| r.dk_eff)),
        ("opening_resolved", col(&|r| if r.opening_resolved { 1.0 } else { 0.0 })),
        ("offset_noise", col(&|r| r.offset_noise)),
        ("closure_pooled", col(&|r| r.closure_pooled as f64)),
        ("resolution_m", col(&|_| cm::resolution_m(width_m))),
    ];
    for (k, v) in cols {
        d.set_item(k, PyArray1::from_vec(py, v))?;
    }
    Ok((m.describe(), d))
}

/// a/W of a C(T) from E·B·C at gauge location X/W (E647 compliance expression), per value.
#[pyfunction]
fn ct_alpha_from_compliance<'py>(py: Python<'py>, ebc: PyReadonlyArray1<'py, f64>, x_over_w: f64) -> PyResult<Array<'py>> {
    let v = ebc.as_slice()?.iter().map(|&e| cm::ct_alpha_from_compliance(e, x_over_w)).collect::<crate::Result<Vec<f64>>>()?;
    Ok(PyArray1::from_vec(py, v))
}

/// The E647 C(T) gauge location X/W a metadata name (`cod_at`) stands for.
#[pyfunction]
fn ct_gauge_x_over_w(name: &str) -> PyResult<f64> {
    Ok(cm::ct_gauge_x_over_w(name)?)
}

/// Crack sizes corrected linearly between the visual initial and final crack sizes (E647).
#[pyfunction]
fn correct_to_visual<'py>(py: Python<'py>, a_m: PyReadonlyArray1<'py, f64>, a0_visual_m: f64, af_visual_m: f64) -> PyResult<Array<'py>> {
    Ok(PyArray1::from_vec(py, cm::correct_to_visual(a_m.as_slice()?, a0_visual_m, af_visual_m)?))
}

/// E647's crack-size resolution for width W: max(0.1 mm, 0.002·W) [m].
#[pyfunction]
fn crack_resolution_m(width_m: f64) -> f64 {
    cm::resolution_m(width_m)
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(crack_reduce, m)?)?;
    m.add_function(wrap_pyfunction!(ct_alpha_from_compliance, m)?)?;
    m.add_function(wrap_pyfunction!(ct_gauge_x_over_w, m)?)?;
    m.add_function(wrap_pyfunction!(correct_to_visual, m)?)?;
    m.add_function(wrap_pyfunction!(crack_resolution_m, m)?)?;
    Ok(())
}
