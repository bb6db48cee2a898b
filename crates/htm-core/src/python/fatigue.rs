//! Thin bindings of `specimen` and `crack`: convert, release the GIL for loops, map errors.
use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::convert::law_from;
use crate::crack::{self, Load};
use crate::specimen::{self, Geometry, Material, Specimen};
use crate::{Error, Result};

fn spec(geometry: &str, width_m: f64, thickness_m: f64) -> PyResult<Specimen> {
    Specimen::new(Geometry::parse(geometry)?, width_m, thickness_m).map_err(PyErr::from)
}

fn elastic(youngs_modulus_pa: f64, poisson_ratio: f64) -> Material {
    Material { youngs_modulus_pa, poisson_ratio, ..Material::default() }
}

fn map_each(a: &[f64], f: impl Fn(f64) -> Result<f64>) -> Result<Vec<f64>> {
    a.iter().map(|&x| f(x)).collect()
}

/// C(T) geometry function g(α) of E647 (thesis eq. 1.3) over an array of α = a/W.
#[pyfunction]
fn g_ct<'py>(py: Python<'py>, alpha: PyReadonlyArray1<'py, f64>) -> PyResult<Bound<'py, PyArray1<f64>>> {
    Ok(PyArray1::from_vec(py, alpha.as_slice()?.iter().map(|&x| specimen::g_ct(x)).collect()))
}

/// C(T) compliance polynomial h(α) (thesis eq. 4.6) over an array of α = a/W.
#[pyfunction]
fn h_ct<'py>(py: Python<'py>, alpha: PyReadonlyArray1<'py, f64>) -> PyResult<Bound<'py, PyArray1<f64>>> {
    Ok(PyArray1::from_vec(py, alpha.as_slice()?.iter().map(|&x| specimen::h_ct(x)).collect()))
}

/// Crack sizes (a_min, a_max) [m] over which the geometry's ΔK expression is valid.
#[pyfunction]
fn a_range(geometry: &str, width_m: f64, thickness_m: f64) -> PyResult<(f64, f64)> {
    Ok(spec(geometry, width_m, thickness_m)?.a_range())
}

/// Stress-intensity factor K [Pa·√m] for force `force_n` [N] at each crack size `a_m` [m]
/// (C(T) and M(T) per E647). Pass ΔP for ΔK, Pmax for Kmax.
#[pyfunction]
fn stress_intensity<'py>(py: Python<'py>, geometry: &str, width_m: f64, thickness_m: f64, a_m: PyReadonlyArray1<'py, f64>, force_n: f64) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let s = spec(geometry, width_m, thickness_m)?;
    let a = a_m.as_slice()?;
    let v = py.detach(|| map_each(a, |x| s.k(x, force_n)))?;
    Ok(PyArray1::from_vec(py, v))
}

type Array<'py> = Bound<'py, PyArray1<f64>>;

/// E647 size criterion at each crack size: (ligament [m], required ligament [m]).
#[pyfunction]
fn size_criterion<'py>(py: Python<'py>, geometry: &str, width_m: f64, thickness_m: f64, a_m: PyReadonlyArray1<'py, f64>, pmax_n: f64, yield_strength_pa: f64) -> PyResult<(Array<'py>, Array<'py>)> {
    let s = spec(geometry, width_m, thickness_m)?;
    let a = a_m.as_slice()?;
    let pairs: Vec<(f64, f64)> = py.detach(|| a.iter().map(|&x| s.size_criterion(x, pmax_n, yield_strength_pa)).collect::<Result<_>>())?;
    let (lig, req): (Vec<f64>, Vec<f64>) = pairs.into_iter().unzip();
    Ok((PyArray1::from_vec(py, lig), PyArray1::from_vec(py, req)))
}

/// C(T) load-line compliance [m/N] at each crack size (thesis eq. 4.5–4.6, E1820 A2).
#[pyfunction]
fn compliance_ct<'py>(py: Python<'py>, width_m: f64, thickness_m: f64, a_m: PyReadonlyArray1<'py, f64>, youngs_modulus_pa: f64, poisson_ratio: f64) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let s = spec("ct", width_m, thickness_m)?;
    let m = elastic(youngs_modulus_pa, poisson_ratio);
    let a = a_m.as_slice()?;
    let v = py.detach(|| map_each(a, |x| s.compliance(x, &m)))?;
    Ok(PyArray1::from_vec(py, v))
}

/// C(T) equivalent stiffness K_sp = 1/C [N/m] at each crack size.
#[pyfunction]
fn stiffness_ct<'py>(py: Python<'py>, width_m: f64, thickness_m: f64, a_m: PyReadonlyArray1<'py, f64>, youngs_modulus_pa: f64, poisson_ratio: f64) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let s = spec("ct", width_m, thickness_m)?;
    let m = elastic(youngs_modulus_pa, poisson_ratio);
    let a = a_m.as_slice()?;
    let v = py.detach(|| map_each(a, |x| s.stiffness(x, &m)))?;
    Ok(PyArray1::from_vec(py, v))
}

/// C(T) crack size [m] from load-line compliance [m/N] (inverse of `compliance_ct`).
#[pyfunction]
fn crack_length_from_compliance_ct<'py>(py: Python<'py>, width_m: f64, thickness_m: f64, compliance_m_per_n: PyReadonlyArray1<'py, f64>, youngs_modulus_pa: f64, poisson_ratio: f64) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let s = spec("ct", width_m, thickness_m)?;
    let m = elastic(youngs_modulus_pa, poisson_ratio);
    let c = compliance_m_per_n.as_slice()?;
    let v = py.detach(|| map_each(c, |x| s.crack_length_from_compliance(x, &m)))?;
    Ok(PyArray1::from_vec(py, v))
}

/// Growth rate da/dN [m/cycle] of `law` (dict: law = paris|forman|nasgro and its SI parameters)
/// at each ΔK and Kmax [Pa·√m] with stress ratio `r_ratio`.
#[pyfunction]
fn growth_rate<'py>(py: Python<'py>, law: &Bound<'py, PyAny>, delta_k: PyReadonlyArray1<'py, f64>, r_ratio: f64, kmax: PyReadonlyArray1<'py, f64>) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let law = law_from(law)?;
    let (dk, km) = (delta_k.as_slice()?, kmax.as_slice()?);
    if dk.len() != km.len() {
        return Err(Error::Input(format!("delta_k has {} values but kmax has {}", dk.len(), km.len())).into());
    }
    Ok(PyArray1::from_vec(py, dk.iter().zip(km).map(|(&d, &k)| law.rate(d, r_ratio, k)).collect()))
}

/// Newman's crack-opening function f(R, Smax/σ0, α) used by NASGRO.
#[pyfunction]
fn newman_f(r_ratio: f64, smax_over_flow_stress: f64, constraint_factor: f64) -> PyResult<f64> {
    crack::newman_f(r_ratio, smax_over_flow_stress, constraint_factor).map_err(PyErr::from)
}

fn life_dict<'py>(py: Python<'py>, l: crack::Life) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("cycles", l.cycles)?;
    d.set_item("a_end_m", l.a_end_m)?;
    d.set_item("fractured", l.fractured)?;
    Ok(d)
}

/// Cycles to grow from a0_m to af_m under constant amplitude (Pmax [N], R); dict with
/// `cycles`, `a_end_m`, `fractured`.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn life<'py>(py: Python<'py>, law: &Bound<'py, PyAny>, geometry: &str, width_m: f64, thickness_m: f64, pmax_n: f64, r_ratio: f64, a0_m: f64, af_m: f64) -> PyResult<Bound<'py, PyDict>> {
    let law = law_from(law)?;
    let s = spec(geometry, width_m, thickness_m)?;
    let load = Load::new(pmax_n, r_ratio)?;
    let l = py.detach(|| crack::life(&law, &s, &load, a0_m, af_m))?;
    life_dict(py, l)
}

/// Cycles N(a_i) − N(a_0) at each nondecreasing crack size (inf beyond fracture).
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn life_curve<'py>(py: Python<'py>, law: &Bound<'py, PyAny>, geometry: &str, width_m: f64, thickness_m: f64, pmax_n: f64, r_ratio: f64, a_m: PyReadonlyArray1<'py, f64>) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let law = law_from(law)?;
    let s = spec(geometry, width_m, thickness_m)?;
    let load = Load::new(pmax_n, r_ratio)?;
    let a = a_m.as_slice()?;
    let mut out = vec![0.0; a.len()];
    py.detach(|| crack::life_curve(&law, &s, &load, a, &mut out))?;
    Ok(PyArray1::from_vec(py, out))
}

/// Crack size after `cycles` from a0_m; dict with `cycles`, `a_end_m`, `fractured`.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn crack_after<'py>(py: Python<'py>, law: &Bound<'py, PyAny>, geometry: &str, width_m: f64, thickness_m: f64, pmax_n: f64, r_ratio: f64, a0_m: f64, cycles: f64) -> PyResult<Bound<'py, PyDict>> {
    let law = law_from(law)?;
    let s = spec(geometry, width_m, thickness_m)?;
    let load = Load::new(pmax_n, r_ratio)?;
    let l = py.detach(|| crack::crack_after(&law, &s, &load, a0_m, cycles))?;
    life_dict(py, l)
}

/// Pmax [N] from the force range ΔP [N] and R per E647.
#[pyfunction]
fn pmax_from_delta_p(delta_p_n: f64, r_ratio: f64) -> PyResult<f64> {
    Ok(Load::from_delta_p(delta_p_n, r_ratio)?.pmax_n)
}

/// Rainflow count (ASTM E1049) of a load history: a list of (range, mean, count), count 1 or 0.5.
#[pyfunction]
fn rainflow(series: Vec<f64>) -> Vec<(f64, f64, f64)> {
    crate::rainflow::rainflow(&series)
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(rainflow, m)?)?;
    m.add_function(wrap_pyfunction!(g_ct, m)?)?;
    m.add_function(wrap_pyfunction!(h_ct, m)?)?;
    m.add_function(wrap_pyfunction!(a_range, m)?)?;
    m.add_function(wrap_pyfunction!(stress_intensity, m)?)?;
    m.add_function(wrap_pyfunction!(size_criterion, m)?)?;
    m.add_function(wrap_pyfunction!(compliance_ct, m)?)?;
    m.add_function(wrap_pyfunction!(stiffness_ct, m)?)?;
    m.add_function(wrap_pyfunction!(crack_length_from_compliance_ct, m)?)?;
    m.add_function(wrap_pyfunction!(growth_rate, m)?)?;
    m.add_function(wrap_pyfunction!(newman_f, m)?)?;
    m.add_function(wrap_pyfunction!(life, m)?)?;
    m.add_function(wrap_pyfunction!(life_curve, m)?)?;
    m.add_function(wrap_pyfunction!(crack_after, m)?)?;
    m.add_function(wrap_pyfunction!(pmax_from_delta_p, m)?)?;
    let nasgro = PyDict::new(m.py());
    for (k, v) in crack::NASGRO_DEFAULTS {
        nasgro.set_item(k, v)?;
    }
    m.add("NASGRO_DEFAULTS", nasgro)?;
    m.add("LOAD_R_RATIO_RANGE", crack::LOAD_R_RATIO_RANGE)?;
    m.add("YOUNGS_MODULUS_RANGE_PA", specimen::YOUNGS_MODULUS_RANGE_PA)?;
    m.add("POISSON_RATIO_RANGE", specimen::POISSON_RATIO_RANGE)?;
    Ok(())
}
