//! Thin bindings of the fatigue test engine: a `TestConfig` (built once from the spec, see
//! `convert.rs`) in, a typed `Outcome` with its per-cycle table (an Arrow record batch) out; the
//! run releases the GIL and reports progress atomically.
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::convert::{mode_from, raw_from, PyChunk, PyOutcome, PyTestConfig};
use super::InputError;
use crate::engine::{self, JumpConfig, Limits};
use crate::waveform::Envelope;

/// Progress of a running test (cycles so far) and a cancel switch; share it with `run_test`.
#[pyclass(name = "Progress", module = "htm._core", from_py_object)]
#[derive(Clone, Default)]
pub struct PyProgress {
    cycles: Arc<AtomicU64>,
    cancel: Arc<AtomicBool>,
}

#[pymethods]
impl PyProgress {
    #[new]
    fn new() -> Self {
        Self::default()
    }
    #[getter]
    fn cycles(&self) -> u64 {
        self.cycles.load(Ordering::Relaxed)
    }
    fn cancel(&self) {
        self.cancel.store(true, Ordering::Relaxed);
    }
}

/// Run one fatigue test in `mode` "full" or "jump"; the GIL is released.
#[pyfunction]
#[pyo3(signature = (config, mode = "full", progress = None))]
fn run_test(py: Python<'_>, config: PyRef<'_, PyTestConfig>, mode: &str, progress: Option<PyProgress>) -> PyResult<PyOutcome> {
    let cfg = Arc::clone(&config.inner);
    let mode = mode_from(mode)?;
    let prog = progress.unwrap_or_default();
    let o = py.detach(|| engine::run_test(&cfg, mode, Some(&prog.cycles), Some(&prog.cancel)))?;
    PyOutcome::new(py, o)
}

/// The amplitude ramp-in [cycles] of a test at `frequency_hz` that states none
/// (`Envelope::for_frequency`: 20 cycles or 1 s, whichever is longer).
#[pyfunction]
fn start_amplitude_cycles(frequency_hz: f64) -> f64 {
    Envelope::for_frequency(frequency_hz).amplitude_cycles
}

/// Run many tests on `threads` cores (0 = all) with the GIL released; results in input order,
/// each an `Outcome` or, for a test that failed, its `HtmError` (the one convention of batches).
#[pyfunction]
#[pyo3(signature = (configs, mode = "full", threads = 0))]
fn run_batch(py: Python<'_>, configs: Vec<PyRef<'_, PyTestConfig>>, mode: &str, threads: usize) -> PyResult<Vec<Py<PyAny>>> {
    let cfgs: Vec<engine::TestConfig> = configs.iter().map(|c| (*c.inner).clone()).collect();
    let mode = mode_from(mode)?;
    let outs = py.detach(|| engine::run_batch(&cfgs, mode, threads));
    outs.into_iter().map(|o| match o {
        Ok(o) => Ok(Py::new(py, PyOutcome::new(py, o)?)?.into_any()),
        Err(e) => Ok(PyErr::from(e).into_value(py).into_any()),
    }).collect()
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let events = PyDict::new(m.py());
    for (name, bit) in engine::events::NAMED {
        events.set_item(name, bit)?;
    }
    m.add("EVENTS", events)?;
    let (first, decade, pre, post) = engine::RawCapture::DEFAULT_POLICY;
    let raw = PyDict::new(m.py());
    raw.set_item("first_cycles", first)?;
    raw.set_item("decade_cycles", decade)?;
    raw.set_item("pre_cycles", pre)?;
    raw.set_item("post_cycles", post)?;
    m.add("RAW_POLICY", raw)?;
    m.add("RAW_COLUMNS", pyo3::types::PyTuple::new(m.py(), engine::RAW_COLUMNS)?)?;
    m.add("TEST_DEFAULTS", test_defaults(m.py())?)?;
    m.add("TEST_R_RATIO_RANGE", engine::TEST_R_RATIO_RANGE)?;
    m.add("MAX_TOLERANCE", engine::MAX_TOLERANCE)?;
    m.add("RTOL_RANGE", engine::RTOL_RANGE)?;
    m.add("TEST_TOLERANCE", engine::TEST_TOLERANCE)?;
    m.add("PRECRACK_TOLERANCE", engine::PRECRACK_TOLERANCE)?;
    m.add("MIN_SAMPLES_PER_CYCLE", engine::MIN_SAMPLES_PER_CYCLE)?;
    m.add("MAX_CONTROL_RATE_HZ", engine::MAX_CONTROL_RATE_HZ)?;
    m.add("E647_MIN_K_GRADIENT_PER_M", engine::E647_MIN_K_GRADIENT_PER_M)?;
    m.add_class::<PyProgress>()?;
    m.add_function(wrap_pyfunction!(run_test, m)?)?;
    m.add_function(wrap_pyfunction!(start_amplitude_cycles, m)?)?;
    m.add_function(wrap_pyfunction!(run_batch, m)?)?;
    register_session(m)?;
    Ok(())
}

/// The value a config key takes when the config leaves it out (keys as in `run_test`'s config;
/// `start_amplitude_cycles` depends on the frequency: `Envelope::for_frequency`).
fn test_defaults(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let (dj, dl, de) = (JumpConfig::default(), Limits::default(), Envelope::default());
    let d = PyDict::new(py);
    d.set_item("rtol", engine::DEFAULT_RTOL)?;
    d.set_item("control_rate_hz", engine::DEFAULT_CONTROL_RATE_HZ)?;
    d.set_item("start_mean_cycles", de.mean_cycles)?;
    d.set_item("stop_cycles", de.stop_cycles)?;
    d.set_item("max_cycles", dl.max_cycles)?;
    d.set_item("size_criterion_action", dl.size_criterion.name())?;
    d.set_item("tolerance_cycles", dl.tolerance_cycles)?;
    d.set_item("tolerance_action", dl.tolerance_action.name())?;
    d.set_item("stroke_margin_m", dl.stroke_margin_m)?;
    d.set_item("jump_max_da_m", dj.max_da_m)?;
    d.set_item("jump_max_rel_change", dj.max_rel_change)?;
    d.set_item("jump_settle_cycles", dj.settle_cycles)?;
    d.set_item("jump_min_cycles", dj.min_jump_cycles)?;
    Ok(d)
}

/// A fatigue test run in bounded chunks whose complete state can be saved as bytes between two
/// chunks and restored (resume after a crash); the rows equal `run_test`'s bit for bit.
#[pyclass(name = "TestRun", module = "htm._core")]
pub struct PyTestRun {
    inner: engine::Session,
}

#[pymethods]
impl PyTestRun {
    /// Validate `config` and bring the test to rest. `raw` (dict: first_cycles, decade_cycles,
    /// pre_cycles, post_cycles) keeps raw sample windows; None keeps none.
    #[new]
    #[pyo3(signature = (config, mode = "full", raw = None))]
    fn new(py: Python<'_>, config: PyRef<'_, PyTestConfig>, mode: &str, raw: Option<&Bound<'_, PyDict>>) -> PyResult<Self> {
        let cfg = (*config.inner).clone();
        let mode = mode_from(mode)?;
        let raw = raw_from(raw)?;
        let inner = py.detach(|| engine::Session::new(cfg, mode, raw))?;
        Ok(PyTestRun { inner })
    }

    /// Continue a test from `snapshot` (bytes from `snapshot()`) of the same config and mode.
    #[staticmethod]
    #[pyo3(signature = (config, mode, snapshot))]
    fn restore(config: PyRef<'_, PyTestConfig>, mode: &str, snapshot: &[u8]) -> PyResult<Self> {
        let inner = engine::Session::restore((*config.inner).clone(), mode_from(mode)?, snapshot)?;
        Ok(PyTestRun { inner })
    }

    /// Run at most `max_cycles` more cycles for at most `max_seconds` of wall time (GIL released);
    /// returns the chunk: its new per-cycle rows and raw samples (tables) and the end, if reached.
    #[pyo3(signature = (max_cycles = u64::MAX, max_seconds = 0.25))]
    fn advance(&mut self, py: Python<'_>, max_cycles: u64, max_seconds: f64) -> PyResult<PyChunk> {
        if !(max_seconds.is_finite() && max_seconds > 0.0) {
            return Err(InputError::new_err(format!("max_seconds = {max_seconds}: allowed (0, inf) s")));
        }
        let inner = &mut self.inner;
        let chunk = py.detach(|| inner.advance(max_cycles, std::time::Duration::from_secs_f64(max_seconds)))?;
        PyChunk::new(py, chunk)
    }

    /// The complete engine state as bytes (plant, solver step, controller and its filter rings,
    /// waveform phase, crack length, cycle count, compensation terms, counters, raw-window memory).
    fn snapshot<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyBytes>> {
        let b = self.inner.snapshot()?;
        Ok(pyo3::types::PyBytes::new(py, &b))
    }

    /// Cycles applied so far.
    #[getter]
    fn cycle(&self) -> u64 {
        self.inner.cycle()
    }

    /// Crack length now [m].
    #[getter]
    fn a_m(&self) -> f64 {
        self.inner.a_m()
    }

    #[getter]
    fn finished(&self) -> bool {
        self.inner.outcome().is_some()
    }

    /// The run's summary (as `run_test`'s, with an empty table) once finished, else None.
    fn outcome(&self, py: Python<'_>) -> PyResult<Option<PyOutcome>> {
        self.inner.outcome().map(|o| PyOutcome::new(py, o.clone())).transpose()
    }

    /// Names of the raw sample columns (SI).
    #[staticmethod]
    fn raw_columns() -> Vec<&'static str> {
        engine::RAW_COLUMNS.to_vec()
    }
}

pub(crate) fn register_session(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyTestRun>()
}
