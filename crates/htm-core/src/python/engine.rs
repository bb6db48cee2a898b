//! Thin bindings of the fatigue test engine: a config dict in (SI, keys as in `htm.spec`), the
//! per-cycle table and summary out; the run releases the GIL and reports progress atomically.
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

use numpy::{PyArray1, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use super::fatigue::law_from;
use super::{InputError, PyParams};
use crate::engine::{self, Action, ControllerSpecArgs, Episode, ExecMode, JumpConfig, Level, Limits, Outcome, PhaseArgs, TestConfig};
use crate::params::Params;
use crate::specimen::{Geometry, Material, Specimen};
use crate::waveform::{Envelope, Waveform};

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

fn need<'py, T: FromPyObjectOwned<'py>>(d: &Bound<'py, PyDict>, k: &str) -> PyResult<T> {
    d.get_item(k)?.ok_or_else(|| InputError::new_err(format!("test config needs `{k}`")))?.extract().map_err(Into::into)
}

fn opt<'py, T: FromPyObjectOwned<'py>>(d: &Bound<'py, PyDict>, k: &str, default: T) -> PyResult<T> {
    match d.get_item(k)? {
        Some(v) if !v.is_none() => v.extract().map_err(Into::into),
        _ => Ok(default),
    }
}

pub(super) fn config_from(d: &Bound<'_, PyDict>) -> PyResult<TestConfig> {
    let params = match d.get_item("params")? {
        Some(p) if !p.is_none() => p.extract::<PyParams>()?.inner,
        _ => Params::default(),
    };
    let specimen = Specimen::new(Geometry::parse(&need::<String>(d, "geometry")?)?, need(d, "width_m")?, need(d, "thickness_m")?)?;
    let material = Material {
        youngs_modulus_pa: need(d, "youngs_modulus_pa")?,
        poisson_ratio: need(d, "poisson_ratio")?,
        yield_strength_pa: need(d, "yield_strength_pa")?,
        fracture_toughness_pa_sqrt_m: need(d, "fracture_toughness_pa_sqrt_m")?,
    };
    let law = law_from(&need::<Bound<'_, PyAny>>(d, "law")?)?;
    let waveform = match need::<String>(d, "waveform")?.as_str() {
        "sine" => Waveform::Sine,
        "triangle" => Waveform::Triangle,
        "trapezoid" => Waveform::Trapezoid { rise: need(d, "rise_fraction")?, hold: need(d, "hold_fraction")? },
        other => return Err(InputError::new_err(format!("waveform `{other}`: use sine, triangle or trapezoid"))),
    };
    let phases = need::<Bound<'_, PyList>>(d, "phases")?.iter()
        .map(|ph| ph.extract::<PhaseArgs>().map_err(|e| InputError::new_err(format!("test config phase: {e}")))?.build().map_err(PyErr::from))
        .collect::<PyResult<Vec<_>>>()?;
    let controller = need::<Bound<'_, PyAny>>(d, "controller")?.extract::<ControllerSpecArgs>()
        .map_err(|e| InputError::new_err(format!("test config controller: {e}")))?.build()?;
    // every default is the core's (`Limits`, `Envelope`, `JumpConfig` defaults, `DEFAULT_*`)
    let frequency_hz: f64 = need(d, "frequency_hz")?;
    let (dj, dl, de) = (JumpConfig::default(), Limits::default(), Envelope::for_frequency(frequency_hz));
    Ok(TestConfig {
        params,
        rtol: opt(d, "rtol", engine::DEFAULT_RTOL)?,
        specimen,
        material,
        law,
        a0_m: need(d, "a0_m")?,
        waveform,
        frequency_hz,
        control_rate_hz: opt(d, "control_rate_hz", engine::DEFAULT_CONTROL_RATE_HZ)?,
        phases,
        controller,
        envelope: Envelope {
            mean_cycles: opt(d, "start_mean_cycles", de.mean_cycles)?,
            amplitude_cycles: opt(d, "start_amplitude_cycles", de.amplitude_cycles)?,
            stop_cycles: opt(d, "stop_cycles", de.stop_cycles)?,
        },
        limits: Limits {
            max_cycles: opt(d, "max_cycles", dl.max_cycles)?,
            size_criterion: Action::parse(&opt(d, "size_criterion_action", dl.size_criterion.name().to_string())?, "size_criterion_action")?,
            tolerance_cycles: opt(d, "tolerance_cycles", dl.tolerance_cycles)?,
            tolerance_action: Action::parse(&opt(d, "tolerance_action", dl.tolerance_action.name().to_string())?, "tolerance_action")?,
            stroke_margin_m: opt(d, "stroke_margin_m", dl.stroke_margin_m)?,
        },
        stiffness_steps: opt(d, "stiffness_steps", Vec::<(u64, f64)>::new())?,
        jump: JumpConfig {
            max_da_m: opt(d, "jump_max_da_m", dj.max_da_m)?,
            max_rel_change: opt(d, "jump_max_rel_change", dj.max_rel_change)?,
            settle_cycles: opt(d, "jump_settle_cycles", dj.settle_cycles)?,
            min_jump_cycles: opt(d, "jump_min_cycles", dj.min_jump_cycles)?,
        },
        sequence: sequence_from(d)?,
    })
}

/// Variable-amplitude loading: `blocks` [(cycles, delta_f_n, r_ratio)] or `spectrum`
/// [(fmax_n, fmin_n)], one cycle per pair.
fn sequence_from(d: &Bound<'_, PyDict>) -> PyResult<Vec<Level>> {
    let blocks: Vec<(u64, f64, f64)> = opt(d, "blocks", Vec::new())?;
    let spectrum: Vec<(f64, f64)> = opt(d, "spectrum", Vec::new())?;
    if !blocks.is_empty() && !spectrum.is_empty() {
        return Err(InputError::new_err("variable amplitude: give blocks or a spectrum, not both"));
    }
    let mut seq: Vec<Level> = blocks.into_iter().map(|(cycles, df, r)| {
        let (fmax_n, fmin_n) = engine::force_range(df, r);
        Level { fmax_n, fmin_n, cycles }
    }).collect();
    seq.extend(spectrum.into_iter().map(|(fmax_n, fmin_n)| Level { fmax_n, fmin_n, cycles: 1 }));
    Ok(seq)
}

fn mode_from(s: &str) -> PyResult<ExecMode> {
    match s {
        "full" => Ok(ExecMode::Full),
        "jump" => Ok(ExecMode::Jump),
        other => Err(InputError::new_err(format!("mode `{other}`: use full or jump"))),
    }
}

fn outcome_dict<'py>(py: Python<'py>, o: Outcome) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("end_reason", o.end_reason.name())?;
    d.set_item("cycles", o.cycles)?;
    d.set_item("a_end_m", o.a_end_m)?;
    d.set_item("max_abs_df_err_pct", o.max_abs_df_err_pct)?;
    d.set_item("max_abs_peak_err_pct", o.max_abs_peak_err_pct)?;
    d.set_item("cycles_simulated", o.cycles_simulated)?;
    d.set_item("size_criterion_cycle", o.size_criterion_cycle)?;
    d.set_item("velocity_gain_m_s_per_v", o.velocity_gain_m_s_per_v)?;
    if let Some(g) = o.demod_gains {
        let gd = PyDict::new(py);
        gd.set_item("plant_gain_n_per_s_v", g.plant_gain_n_per_s_v)?;
        gd.set_item("k1", g.k1)?;
        gd.set_item("kp2", g.kp2)?;
        gd.set_item("ki2", g.ki2)?;
        gd.set_item("window", g.window)?;
        d.set_item("demod_gains", gd)?;
    }
    d.set_item("convergence", convergence_list(py, &o.convergence)?)?;
    d.set_item("worst_first_cycles_df_pct", o.convergence.iter().find(|e| e.cycles_seen > 0).map(|e| e.worst_first_df_pct))?;
    d.set_item("table", records_dict(py, o.records)?)?;
    Ok(d)
}

/// Convergence episodes as dicts: cause, first_cycle, cycles_seen, cycles_to_2pct,
/// cycles_to_0p5pct (None while not inside), worst_first_df_pct.
pub(super) fn convergence_list<'py>(py: Python<'py>, eps: &[Episode]) -> PyResult<Bound<'py, PyList>> {
    let l = PyList::empty(py);
    for e in eps {
        let d = PyDict::new(py);
        d.set_item("cause", e.cause.name())?;
        d.set_item("first_cycle", e.first_cycle)?;
        d.set_item("cycles_seen", e.cycles_seen)?;
        d.set_item("cycles_to_2pct", e.cycles_to(0))?;
        d.set_item("cycles_to_0p5pct", e.cycles_to(1))?;
        d.set_item("worst_first_df_pct", e.worst_first_df_pct)?;
        l.append(d)?;
    }
    Ok(l)
}

/// Run one fatigue test (config dict, SI) in `mode` "full" or "jump"; the GIL is released.
#[pyfunction]
#[pyo3(signature = (config, mode = "full", progress = None))]
fn run_test<'py>(py: Python<'py>, config: &Bound<'py, PyDict>, mode: &str, progress: Option<PyProgress>) -> PyResult<Bound<'py, PyDict>> {
    let cfg = config_from(config)?;
    let mode = mode_from(mode)?;
    let prog = progress.unwrap_or_default();
    let o = py.detach(|| engine::run_test(&cfg, mode, Some(&prog.cycles), Some(&prog.cancel)))?;
    outcome_dict(py, o)
}

/// The amplitude ramp-in [cycles] of a test at `frequency_hz` that states none
/// (`Envelope::for_frequency`: 20 cycles or 1 s, whichever is longer).
#[pyfunction]
fn start_amplitude_cycles(frequency_hz: f64) -> f64 {
    Envelope::for_frequency(frequency_hz).amplitude_cycles
}

/// Check a config without running it (raises ParameterError/InputError naming the field).
#[pyfunction]
fn validate_test(config: &Bound<'_, PyDict>) -> PyResult<()> {
    config_from(config)?.validate().map_err(PyErr::from)
}

/// Run many tests on `threads` cores (0 = all) with the GIL released; results in input order.
#[pyfunction]
#[pyo3(signature = (configs, mode = "full", threads = 0))]
fn run_batch<'py>(py: Python<'py>, configs: &Bound<'py, PyList>, mode: &str, threads: usize) -> PyResult<Bound<'py, PyList>> {
    let cfgs = configs.iter().map(|c| config_from(&c.cast_into::<PyDict>()?)).collect::<PyResult<Vec<_>>>()?;
    let mode = mode_from(mode)?;
    let outs = py.detach(|| engine::run_batch(&cfgs, mode, threads));
    let l = PyList::empty(py);
    for o in outs {
        l.append(outcome_dict(py, o?)?)?;
    }
    Ok(l)
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
    m.add_function(wrap_pyfunction!(validate_test, m)?)?;
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

fn records_dict<'py>(py: Python<'py>, r: crate::engine::Records) -> PyResult<Bound<'py, PyDict>> {
    let t = PyDict::new(py);
    t.set_item("cycle", PyArray1::from_vec(py, r.cycle))?;
    t.set_item("phase", PyArray1::from_vec(py, r.phase))?;
    t.set_item("events", PyArray1::from_vec(py, r.events))?;
    for (k, v) in [
        ("fmax_n", r.fmax_n), ("fmin_n", r.fmin_n), ("fmax_target_n", r.fmax_target_n), ("fmin_target_n", r.fmin_target_n),
        ("peak_err_pct", r.peak_err_pct), ("df_err_pct", r.df_err_pct), ("a_m", r.a_m), ("delta_k_pa_sqrt_m", r.delta_k),
        ("delta_k_target_pa_sqrt_m", r.delta_k_target), ("kmax_pa_sqrt_m", r.kmax), ("dadn_m_per_cycle", r.dadn_m),
        ("k_sp_n_m", r.k_sp_n_m), ("ctrl_u1_v", r.ctrl_u1_v), ("ctrl_u2_v", r.ctrl_u2_v),
    ] {
        t.set_item(k, PyArray1::from_vec(py, v))?;
    }
    Ok(t)
}

/// A fatigue test run in bounded chunks whose complete state can be saved as bytes between two
/// chunks and restored (resume after a crash); the rows equal `run_test`'s bit for bit.
#[pyclass(name = "TestRun", module = "htm._core")]
pub struct PyTestRun {
    inner: engine::Session,
}

fn raw_from(raw: Option<&Bound<'_, PyDict>>) -> PyResult<engine::RawCapture> {
    Ok(match raw {
        None => engine::RawCapture::default(),
        Some(d) => {
            let (first, decade, pre, post) = engine::RawCapture::DEFAULT_POLICY;
            engine::RawCapture::new(opt(d, "first_cycles", first)?, opt(d, "decade_cycles", decade)?, opt(d, "pre_cycles", pre)?, opt(d, "post_cycles", post)?)
        }
    })
}

#[pymethods]
impl PyTestRun {
    /// Validate `config` and bring the test to rest. `raw` (dict: first_cycles, decade_cycles,
    /// pre_cycles, post_cycles) keeps raw sample windows; None keeps none.
    #[new]
    #[pyo3(signature = (config, mode = "full", raw = None))]
    fn new(py: Python<'_>, config: &Bound<'_, PyDict>, mode: &str, raw: Option<&Bound<'_, PyDict>>) -> PyResult<Self> {
        let cfg = config_from(config)?;
        let mode = mode_from(mode)?;
        let raw = raw_from(raw)?;
        let inner = py.detach(|| engine::Session::new(cfg, mode, raw))?;
        Ok(PyTestRun { inner })
    }

    /// Continue a test from `snapshot` (bytes from `snapshot()`) of the same config and mode.
    #[staticmethod]
    #[pyo3(signature = (config, mode, snapshot))]
    fn restore(config: &Bound<'_, PyDict>, mode: &str, snapshot: &[u8]) -> PyResult<Self> {
        let inner = engine::Session::restore(config_from(config)?, mode_from(mode)?, snapshot)?;
        Ok(PyTestRun { inner })
    }

    /// Run at most `max_cycles` more cycles for at most `max_seconds` of wall time (GIL released);
    /// returns {"table": new per-cycle rows, "raw": (n, 8) samples (RAW_COLUMNS), "end_reason": str or None}.
    #[pyo3(signature = (max_cycles = u64::MAX, max_seconds = 0.25))]
    fn advance<'py>(&mut self, py: Python<'py>, max_cycles: u64, max_seconds: f64) -> PyResult<Bound<'py, PyDict>> {
        if !(max_seconds.is_finite() && max_seconds > 0.0) {
            return Err(InputError::new_err(format!("max_seconds = {max_seconds}: allowed (0, inf) s")));
        }
        let inner = &mut self.inner;
        let chunk = py.detach(|| inner.advance(max_cycles, std::time::Duration::from_secs_f64(max_seconds)))?;
        let d = PyDict::new(py);
        d.set_item("table", records_dict(py, chunk.records)?)?;
        let n = chunk.raw.len();
        let flat: Vec<f64> = chunk.raw.into_iter().flatten().collect();
        d.set_item("raw", PyArray1::from_vec(py, flat).reshape([n, 8])?)?;
        d.set_item("end_reason", chunk.end.map(|e| e.name()))?;
        Ok(d)
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
    fn outcome<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        self.inner.outcome().map(|o| outcome_dict(py, o.clone())).transpose()
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
