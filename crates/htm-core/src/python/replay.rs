//! Binding of record re-simulation: one record's arrays in, one dict of readings per parameter
//! set out; the batch runs with the GIL released on all cores.
use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use super::{controller_from, InputError, PyParams};
use crate::measure::{Corruption, CHANNELS};
use crate::replay::{Replay, Replayed, DEFAULT_HORIZON_S, DEFAULT_PREROLL_S, DEFAULT_RTOL};

fn channel_index(name: &str) -> PyResult<usize> {
    CHANNELS.iter().position(|c| *c == name).ok_or_else(|| InputError::new_err(format!("unknown channel `{name}`: use one of {}", CHANNELS.join(", "))))
}

/// Borrow the arrays of a `{channel: array}` dict in `CHANNELS` order.
fn channel_arrays<'py>(d: Option<&Bound<'py, PyDict>>) -> PyResult<Vec<(usize, PyReadonlyArray1<'py, f64>)>> {
    let mut out = Vec::new();
    if let Some(d) = d {
        for (k, v) in d.iter() {
            let name: String = k.extract()?;
            out.push((channel_index(&name)?, v.extract::<PyReadonlyArray1<'py, f64>>()?));
        }
    }
    Ok(out)
}

/// One parameter set's result: its readings by channel, or — the batch convention of every batch
/// call (`run_batch` alike) — the `HtmError` of a set the solver could not carry, as the item.
fn result_item<'py>(py: Python<'py>, r: Result<Replayed, crate::Error>) -> PyResult<Bound<'py, PyAny>> {
    match r {
        Ok(o) => {
            let d = PyDict::new(py);
            for (c, v) in CHANNELS.iter().zip(o.readings) {
                d.set_item(*c, PyArray1::from_vec(py, v))?;
            }
            d.set_item("u", PyArray1::from_vec(py, o.u))?;
            d.set_item("steps", o.stats.accepted)?;
            d.set_item("rejected", o.stats.rejected)?;
            d.set_item("rhs_evals", o.stats.rhs_evals)?;
            Ok(d.into_any())
        }
        Err(e) => Ok(PyErr::from(e).into_value(py).into_bound(py).into_any()),
    }
}

/// Re-simulate one record with every parameter set in `params` (list of Params).
///
/// `u` [V] is the recorded command; `measured` maps channel names (y, v, p_a, p_b, p_s, f) to the
/// recorded columns (start state and open-loop restarts); `controller` (DATA_FORMAT dict) with
/// `reference` (m or N) selects the closed loop, else the open loop re-started every `horizon_s`.
/// `noise` (per-channel arrays added to the readings) and `quantum` (per-channel steps) make a
/// record's realistic sensors. `supply` (one factor per sample) scales the supply set-point
/// `supply_pressure_pa` over time (a power unit switched between pressure levels). Returns one item per parameter set: a dict of the readings per channel,
/// `u`, `steps`, `rejected` and `rhs_evals` — or, for a set the solver could not carry, its `HtmError` as the item (every batch call's
/// convention). `lockstep` (open loop): the sets after the first differ from it slightly (a fit's finite-difference neighbours)
/// and take its integrator step sizes (`Replay::run_lockstep`). `dense_stages`: the integrator solves each stage as one dense
/// system (the coupled form before the spool's block was solved apart; the same readings to rounding, a benchmark's peer).
/// Bad arguments raise.
#[pyfunction]
#[pyo3(signature = (params, dt, u, measured = None, controller = None, reference = None, horizon_s = DEFAULT_HORIZON_S,
                    preroll_s = DEFAULT_PREROLL_S, rtol = DEFAULT_RTOL, noise = None, quantum = None, supply = None, active = None,
                    threads = 0, lockstep = false, dense_stages = false))]
#[allow(clippy::too_many_arguments)]
fn replay<'py>(
    py: Python<'py>,
    params: Vec<PyParams>,
    dt: f64,
    u: PyReadonlyArray1<'py, f64>,
    measured: Option<&Bound<'py, PyDict>>,
    controller: Option<&Bound<'py, PyAny>>,
    reference: Option<PyReadonlyArray1<'py, f64>>,
    horizon_s: f64,
    preroll_s: f64,
    rtol: f64,
    noise: Option<&Bound<'py, PyDict>>,
    quantum: Option<&Bound<'py, PyDict>>,
    supply: Option<PyReadonlyArray1<'py, f64>>,
    active: Option<PyReadonlyArray1<'py, bool>>,
    threads: usize,
    lockstep: bool,
    dense_stages: bool,
) -> PyResult<Bound<'py, PyList>> {
    let meas = channel_arrays(measured)?;
    let noise = channel_arrays(noise)?;
    let ctrl = controller.map(controller_from).transpose()?;
    let u_s = u.as_slice()?;
    let mut rp = Replay::new(dt, u_s);
    rp.horizon_s = horizon_s;
    rp.preroll_s = preroll_s;
    rp.rtol = rtol;
    rp.dense_stages = dense_stages;
    for (i, a) in &meas {
        rp.measured[*i] = Some(a.as_slice()?);
    }
    let mut corr = Corruption::default();
    for (i, a) in &noise {
        corr.noise[*i] = Some(a.as_slice()?);
    }
    if let Some(q) = quantum {
        for (k, v) in q.iter() {
            corr.quantum[channel_index(&k.extract::<String>()?)?] = v.extract()?;
        }
    }
    if corr.quantum.iter().any(|q| !(q.is_finite() && *q >= 0.0)) {
        return Err(InputError::new_err("quantum steps must be finite and >= 0"));
    }
    rp.corruption = corr;
    if let Some(s) = &supply {
        rp.supply = Some(s.as_slice()?);
    }
    if let Some(a) = &active {
        rp.active = Some(a.as_slice()?);
    }
    let r_s;
    match (ctrl, &reference) {
        (Some(c), Some(r)) => {
            r_s = r.as_slice()?;
            rp.closed_loop = Some((c, r_s));
        }
        (Some(_), None) => return Err(InputError::new_err("a controller needs its `reference` (y_ref or f_ref)")),
        (None, _) => {}
    }
    rp.validate()?;
    let ps: Vec<_> = params.into_iter().map(|p| p.inner).collect();
    let rp_ref = &rp;
    let results = py.detach(move || if lockstep { rp_ref.run_lockstep_batch(&ps, threads) } else { rp_ref.run_batch(&ps, threads) });
    let out = PyList::empty(py);
    for r in results {
        out.append(result_item(py, r)?)?;
    }
    Ok(out)
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(replay, m)?)?;
    Ok(())
}
