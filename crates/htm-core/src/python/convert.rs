//! The one conversion layer between Python and the core (the `Wrap<T>` pattern of polars): every
//! value that crosses the boundary is converted here, and no core type carries a pyo3 attribute.
//!
//! In: a test spec (`htm.spec.TestSpec`, named as the spec's TOML names it) → the core's
//! `TestConfig`, once, validated (`PyTestConfig`). Out: the core's errors as `HtmError`
//! subclasses (a `ParameterError` carries `.field`, `.value`, `.allowed`), the outcome of a run
//! as a typed object (`PyOutcome`), the per-cycle table and raw samples as Arrow record batches
//! (`PyTable`, exported through `arrow.rs`).
use std::collections::HashMap;
use std::sync::Arc;

use numpy::PyArray1;
use pyo3::exceptions::PyKeyError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use super::arrow::{self, Column, Columns};
use super::{InputError, ParameterError, PyParams, SolverError};
use crate::crack::{Law, LawSpec};
use crate::engine::config::within;
use crate::params::Field;
use crate::engine::{self, Action, ControllerSpecArgs, Episode, ExecMode, JumpConfig, Level, Limits, Outcome, PhaseArgs, Records, TestConfig};
use crate::specimen::{Geometry, Material, Specimen};
use crate::waveform::{Envelope, Waveform};
use crate::Error;

// ---- errors -----------------------------------------------------------------------------------

/// Each core error as its `HtmError` subclass, so `?` carries it to Python; a parameter error
/// keeps its parts as attributes (`field` is the spec's own path) and its message is built from them.
impl From<Error> for PyErr {
    fn from(e: Error) -> PyErr {
        let msg = e.to_string();
        match e {
            Error::Parameter { field, value, allowed } => {
                let err = ParameterError::new_err(msg);
                Python::attach(|py| {
                    let v = err.value(py);
                    // attributes on a fresh exception instance cannot fail
                    let _ = v.setattr("field", field);
                    let _ = v.setattr("value", value);
                    let _ = v.setattr("allowed", allowed);
                });
                err
            }
            Error::Input(_) => InputError::new_err(msg),
            Error::Solver(_) => SolverError::new_err(msg),
        }
    }
}

// ---- parameter sets ----------------------------------------------------------------------------

/// A model family's parameter set as the bindings see it: scalar fields by name with their table
/// (`Field`), a validation naming the first field out of range.
pub(crate) trait ParamSet: Clone {
    /// What the family is called in an unknown-name error ("parameter", "displacement-loop parameter").
    const WHAT: &'static str;
    fn fields() -> &'static [Field];
    fn get(&self, name: &str) -> Option<f64>;
    fn set(&mut self, name: &str, value: f64) -> crate::Result<()>;
    fn validate(&self) -> crate::Result<()>;
}

impl ParamSet for crate::params::Params {
    const WHAT: &'static str = "parameter";
    fn fields() -> &'static [Field] {
        crate::params::FIELDS
    }
    fn get(&self, name: &str) -> Option<f64> {
        crate::params::Params::get(self, name)
    }
    fn set(&mut self, name: &str, value: f64) -> crate::Result<()> {
        crate::params::Params::set(self, name, value)
    }
    fn validate(&self) -> crate::Result<()> {
        crate::params::Params::validate(self)
    }
}

impl ParamSet for crate::outer_loop::LoopParams {
    const WHAT: &'static str = "displacement-loop parameter";
    fn fields() -> &'static [Field] {
        crate::outer_loop::LOOP_FIELDS
    }
    fn get(&self, name: &str) -> Option<f64> {
        crate::outer_loop::LoopParams::get(self, name)
    }
    fn set(&mut self, name: &str, value: f64) -> crate::Result<()> {
        crate::outer_loop::LoopParams::set(self, name, value)
    }
    fn validate(&self) -> crate::Result<()> {
        crate::outer_loop::LoopParams::validate(self)
    }
}

pub(crate) fn param_get<P: ParamSet>(p: &P, name: &str) -> PyResult<f64> {
    p.get(name).ok_or_else(|| PyKeyError::new_err(format!("unknown {} `{name}`", P::WHAT)))
}

pub(crate) fn param_set<P: ParamSet>(p: &mut P, name: &str, value: f64) -> PyResult<()> {
    if p.get(name).is_none() {
        return Err(PyKeyError::new_err(format!("unknown {} `{name}`", P::WHAT)));
    }
    Ok(p.set(name, value)?)
}

/// `{name: value}` of a parameter set's fields.
pub(crate) fn param_dict<'py, P: ParamSet>(py: Python<'py>, p: &P) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    for f in P::fields() {
        d.set_item(f.name, p.get(f.name))?;
    }
    Ok(d)
}

/// Name, unit, documentation and allowed range of each field of a parameter set.
pub(crate) fn field_table<'py>(py: Python<'py>, fields: &[Field]) -> PyResult<Bound<'py, PyList>> {
    let out = PyList::empty(py);
    for f in fields {
        let d = PyDict::new(py);
        d.set_item("name", f.name)?;
        d.set_item("unit", f.unit)?;
        d.set_item("doc", f.doc.trim())?;
        d.set_item("min", f.min)?;
        d.set_item("max", f.max)?;
        d.set_item("min_open", f.min_open)?;
        d.set_item("allowed", f.allowed())?;
        out.append(d)?;
    }
    Ok(out)
}

/// The one parameter-set wrapper: the mapping methods every model family's `Params` class has
/// (`p[name]`, `p[name] = v`, `name in p`, `keys`, `validate`, `copy`, `to_dict`, `fields`), for a
/// `#[pyclass]` struct with an `inner` field of a `ParamSet` type; `$extra` adds the family's own.
macro_rules! param_set_class {
    ($py:ty, $core:ty, { $($extra:tt)* }) => {
        #[pymethods]
        impl $py {
            fn __getitem__(&self, name: &str) -> PyResult<f64> {
                $crate::python::convert::param_get(&self.inner, name)
            }
            fn __setitem__(&mut self, name: &str, value: f64) -> PyResult<()> {
                $crate::python::convert::param_set(&mut self.inner, name, value)
            }
            fn __contains__(&self, name: &str) -> bool {
                <$core as $crate::python::convert::ParamSet>::get(&self.inner, name).is_some()
            }
            /// Names of the scalar fields.
            fn keys(&self) -> Vec<&'static str> {
                <$core as $crate::python::convert::ParamSet>::fields().iter().map(|f| f.name).collect()
            }
            /// Raise ParameterError naming the first field out of range.
            fn validate(&self) -> PyResult<()> {
                Ok(<$core as $crate::python::convert::ParamSet>::validate(&self.inner)?)
            }
            fn copy(&self) -> Self {
                self.clone()
            }
            fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
                $crate::python::convert::param_dict(py, &self.inner)
            }
            /// Name, unit, documentation and allowed range of every scalar field.
            #[staticmethod]
            fn fields<'py>(py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyList>> {
                $crate::python::convert::field_table(py, <$core as $crate::python::convert::ParamSet>::fields())
            }
            $($extra)*
        }
    };
}
pub(crate) use param_set_class;

// ---- in: growth laws ---------------------------------------------------------------------------

/// A `[law]` table (`law` paris, forman or nasgro, SI; the parameters a law does not use are ignored).
#[derive(FromPyObject)]
#[pyo3(from_item_all)]
struct LawIn {
    law: String,
    #[pyo3(default)]
    c: Option<f64>,
    #[pyo3(default)]
    m: Option<f64>,
    #[pyo3(default)]
    kc: Option<f64>,
    #[pyo3(default)]
    n: Option<f64>,
    #[pyo3(default)]
    p: Option<f64>,
    #[pyo3(default)]
    q: Option<f64>,
    #[pyo3(default)]
    dk_th: Option<f64>,
    #[pyo3(default)]
    k_crit: Option<f64>,
    #[pyo3(default)]
    f_open: Option<f64>,
}

fn law_spec(d: &Bound<'_, PyAny>) -> PyResult<LawSpec> {
    let l: LawIn = d.extract().map_err(|e| InputError::new_err(format!("growth law: {e}")))?;
    Ok(LawSpec { law: l.law, c: l.c, m: l.m, kc: l.kc, n: l.n, p: l.p, q: l.q, dk_th: l.dk_th, k_crit: l.k_crit, f_open: l.f_open })
}

/// A growth law from its dict (as a spec's `[law]` table), validated.
pub(crate) fn law_from(d: &Bound<'_, PyAny>) -> PyResult<Law> {
    Ok(law_spec(d)?.build()?)
}

// ---- in: a closed-loop controller --------------------------------------------------------------

/// A controller table (DATA_FORMAT's `controller`, SI): `type` position_pff or force_p.
#[derive(FromPyObject)]
#[pyo3(from_item_all)]
struct ControllerArgsIn {
    #[pyo3(item("type"))]
    kind: String,
    #[pyo3(default)]
    kp_v_per_m: Option<f64>,
    #[pyo3(default)]
    kff_v_per_m_s: Option<f64>,
    #[pyo3(default)]
    kp_v_per_n: Option<f64>,
    #[pyo3(default)]
    u_max_v: Option<f64>,
}

/// A controller from its dict; a malformed dict is an `InputError`.
pub(crate) fn controller_from(d: &Bound<'_, PyAny>) -> PyResult<crate::control::Controller> {
    let a: ControllerArgsIn = d.extract().map_err(|e| InputError::new_err(format!("controller: {e}")))?;
    Ok(crate::control::ControllerArgs { kind: a.kind, kp_v_per_m: a.kp_v_per_m, kff_v_per_m_s: a.kff_v_per_m_s, kp_v_per_n: a.kp_v_per_n, u_max_v: a.u_max_v }
        .build()?)
}

// ---- in: the test spec ------------------------------------------------------------------------

/// A `htm.spec.TestSpec` as the core reads it: attributes and table keys are the spec's own names.
#[derive(FromPyObject)]
struct SpecIn<'py> {
    geometry: String,
    width_m: f64,
    thickness_m: f64,
    a0_m: f64,
    material: MaterialIn,
    law: Bound<'py, PyAny>,
    waveform: String,
    /// `rise_fraction`, `hold_fraction` of a trapezoid (empty otherwise)
    waveform_shape: HashMap<String, f64>,
    frequency_hz: f64,
    control_rate_hz: f64,
    phases: Vec<LoadingIn>,
    controller: ControllerIn,
    end: EndIn,
    start: StartIn,
    rtol: f64,
    stiffness_steps: Vec<(u64, f64)>,
    blocks: Vec<(u64, f64, f64)>,
    spectrum: Vec<(f64, f64)>,
    measurement: MeasurementIn,
}

/// `[measurement]` (`htm.spec.TestSpec.measurement`): what it leaves out is the core's default.
#[derive(FromPyObject)]
#[pyo3(from_item_all)]
struct MeasurementIn {
    crack: String,
    #[pyo3(default)]
    gauge_x_over_w: Option<f64>,
    #[pyo3(default)]
    gauge_y_m: Option<f64>,
    #[pyo3(default)]
    cycles_per_reading: Option<u64>,
    #[pyo3(default)]
    readings_fitted: Option<usize>,
    #[pyo3(default)]
    noise: Option<f64>,
    #[pyo3(default)]
    resolution: Option<f64>,
    #[pyo3(default)]
    drift_per_cycle: Option<f64>,
    #[pyo3(default)]
    closure_opening_fraction: Option<f64>,
    #[pyo3(default)]
    seed: Option<u64>,
}

fn measurement_of(m: &MeasurementIn) -> PyResult<engine::Measurement> {
    let crack = engine::CrackSource::parse(&m.crack)?;
    let d = engine::Measurement::model();
    // the simulated chain's defaults: a clip gauge of 0.1 µm noise and 0.05 µm steps; a
    // potential of 0.01 % noise and 0.001 % steps
    let (noise, res) = if crack == engine::CrackSource::PotentialDrop { (1e-4, 1e-5) } else { (0.1e-6, 0.05e-6) };
    Ok(engine::Measurement {
        crack,
        gauge_x_over_w: m.gauge_x_over_w.unwrap_or(d.gauge_x_over_w),
        gauge_y_m: m.gauge_y_m.unwrap_or(d.gauge_y_m),
        cycles_per_reading: m.cycles_per_reading.unwrap_or(d.cycles_per_reading),
        readings_fitted: m.readings_fitted.unwrap_or(d.readings_fitted),
        noise: m.noise.unwrap_or(noise),
        resolution: m.resolution.unwrap_or(res),
        drift_per_cycle: m.drift_per_cycle.unwrap_or(0.0),
        closure_opening_fraction: m.closure_opening_fraction.unwrap_or(0.0),
        seed: m.seed.unwrap_or(d.seed),
    })
}

#[derive(FromPyObject)]
#[pyo3(from_item_all)]
struct MaterialIn {
    youngs_modulus_pa: f64,
    poisson_ratio: f64,
    yield_strength_pa: f64,
    fracture_toughness_pa_sqrt_m: f64,
}

/// One `[precrack]` / `[loading]` phase (`htm.spec.Loading`).
#[derive(FromPyObject)]
struct LoadingIn {
    mode: String,
    r_ratio: f64,
    end_a_m: f64,
    tolerance: f64,
    delta_f_n: Option<f64>,
    delta_k_pa_sqrt_m: Option<f64>,
    k_gradient_per_m: Option<f64>,
}

#[derive(FromPyObject)]
#[pyo3(from_item_all)]
struct ControllerIn {
    #[pyo3(item("type"))]
    kind: String,
    #[pyo3(default)]
    velocity_gain_m_s_per_v: Option<f64>,
    #[pyo3(default)]
    kp_v_per_n: Option<f64>,
    #[pyo3(default)]
    kp_v_per_m: Option<f64>,
    #[pyo3(default)]
    kff_v_per_m_s: Option<f64>,
    #[pyo3(default)]
    u_offset_v: Option<f64>,
}

#[derive(FromPyObject)]
#[pyo3(from_item_all)]
struct EndIn {
    max_cycles: Option<u64>,
    size_criterion: Option<String>,
    tolerance_cycles: Option<u64>,
    tolerance_action: Option<String>,
}

#[derive(FromPyObject)]
#[pyo3(from_item_all)]
struct StartIn {
    mean_cycles: Option<f64>,
    amplitude_cycles: Option<f64>,
    stop_cycles: Option<f64>,
}

fn waveform(s: &SpecIn<'_>) -> PyResult<Waveform> {
    let need = |k: &str, v: Option<f64>| v.ok_or_else(|| InputError::new_err(format!("loading.{k} is missing")));
    match s.waveform.as_str() {
        "sine" => Ok(Waveform::Sine),
        "triangle" => Ok(Waveform::Triangle),
        "trapezoid" => Ok(Waveform::Trapezoid {
            rise: need("rise_fraction", s.waveform_shape.get("rise_fraction").copied())?,
            hold: need("hold_fraction", s.waveform_shape.get("hold_fraction").copied())?,
        }),
        other => Err(InputError::new_err(format!("loading.waveform = `{other}`: use sine, triangle or trapezoid"))),
    }
}

/// The core's config of a spec (every default the spec leaves out is the core's), unvalidated.
fn config_of(s: SpecIn<'_>, params: crate::params::Params) -> PyResult<TestConfig> {
    let n = s.phases.len();
    let phases = s.phases.iter().enumerate().map(|(i, ph)| {
        let section = if i + 1 == n { "loading" } else { "precrack" };
        PhaseArgs {
            mode: ph.mode.clone(), r_ratio: Some(ph.r_ratio), end_a_m: Some(ph.end_a_m), tolerance: Some(ph.tolerance),
            delta_f_n: ph.delta_f_n, delta_k_pa_sqrt_m: ph.delta_k_pa_sqrt_m, k_gradient_per_m: ph.k_gradient_per_m,
        }.build(section).map_err(PyErr::from)
    }).collect::<PyResult<Vec<_>>>()?;
    let c = &s.controller;
    let controller = ControllerSpecArgs {
        kind: c.kind.clone(), velocity_gain_m_s_per_v: c.velocity_gain_m_s_per_v, kp_v_per_n: c.kp_v_per_n,
        kp_v_per_m: c.kp_v_per_m, kff_v_per_m_s: c.kff_v_per_m_s, u_offset_v: c.u_offset_v,
    }.build()?;
    let (dl, de) = (Limits::default(), Envelope::for_frequency(s.frequency_hz));
    let action = |v: &Option<String>, field: &str, default: Action| v.as_deref().map_or(Ok(default), |a| Action::parse(a, field));
    if !s.blocks.is_empty() && !s.spectrum.is_empty() {
        return Err(InputError::new_err("variable_amplitude: give blocks or a spectrum, not both"));
    }
    let mut sequence: Vec<Level> = s.blocks.iter().map(|&(cycles, df, r)| {
        let (fmax_n, fmin_n) = engine::force_range(df, r);
        Level { fmax_n, fmin_n, cycles }
    }).collect();
    sequence.extend(s.spectrum.iter().map(|&(fmax_n, fmin_n)| Level { fmax_n, fmin_n, cycles: 1 }));
    Ok(TestConfig {
        params,
        rtol: s.rtol,
        specimen: Specimen { geometry: Geometry::parse(&s.geometry)?, width_m: s.width_m, thickness_m: s.thickness_m },
        material: Material {
            youngs_modulus_pa: s.material.youngs_modulus_pa,
            poisson_ratio: s.material.poisson_ratio,
            yield_strength_pa: s.material.yield_strength_pa,
            fracture_toughness_pa_sqrt_m: s.material.fracture_toughness_pa_sqrt_m,
        },
        law: within("law", law_spec(&s.law)?.build())?,
        a0_m: s.a0_m,
        waveform: waveform(&s)?,
        frequency_hz: s.frequency_hz,
        control_rate_hz: s.control_rate_hz,
        phases,
        controller,
        envelope: Envelope {
            mean_cycles: s.start.mean_cycles.unwrap_or(de.mean_cycles),
            amplitude_cycles: s.start.amplitude_cycles.unwrap_or(de.amplitude_cycles),
            stop_cycles: s.start.stop_cycles.unwrap_or(de.stop_cycles),
        },
        limits: Limits {
            max_cycles: s.end.max_cycles.unwrap_or(dl.max_cycles),
            size_criterion: action(&s.end.size_criterion, "end.size_criterion", dl.size_criterion)?,
            tolerance_cycles: s.end.tolerance_cycles.unwrap_or(dl.tolerance_cycles),
            tolerance_action: action(&s.end.tolerance_action, "end.tolerance_action", dl.tolerance_action)?,
            stroke_margin_m: dl.stroke_margin_m,
        },
        stiffness_steps: s.stiffness_steps,
        jump: JumpConfig::default(),
        sequence_from_spectrum: !s.spectrum.is_empty(),
        sequence,
        measurement: measurement_of(&s.measurement)?,
    })
}

/// A test's configuration, built once from its spec and validated; every run, check and
/// controller takes it as it is (nothing is converted again).
#[pyclass(name = "TestConfig", module = "htm._core", frozen)]
pub struct PyTestConfig {
    pub(crate) inner: Arc<TestConfig>,
}

#[pymethods]
impl PyTestConfig {
    /// The configuration of `spec` (an `htm.spec.TestSpec`) on the rig `params`; raises
    /// ParameterError naming the spec's field (`loading.r_ratio`), its value and allowed range.
    #[new]
    fn new(spec: &Bound<'_, PyAny>, params: PyRef<'_, PyParams>) -> PyResult<Self> {
        let s: SpecIn = spec.extract().map_err(|e| InputError::new_err(format!("test spec: {e}")))?;
        let cfg = config_of(s, params.inner.clone())?;
        cfg.validate()?;
        Ok(PyTestConfig { inner: Arc::new(cfg) })
    }

    /// The same test on other rig parameters (a real rig's own), validated.
    fn with_params(&self, params: PyRef<'_, PyParams>) -> PyResult<Self> {
        let mut cfg = (*self.inner).clone();
        cfg.params = params.inner.clone();
        cfg.validate()?;
        Ok(PyTestConfig { inner: Arc::new(cfg) })
    }

    /// The rig parameters the test runs on (a copy).
    #[getter]
    fn params(&self) -> PyParams {
        PyParams { inner: self.inner.params.clone() }
    }
    #[getter]
    fn frequency_hz(&self) -> f64 {
        self.inner.frequency_hz
    }
    #[getter]
    fn waveform(&self) -> &'static str {
        match self.inner.waveform {
            Waveform::Sine => "sine",
            Waveform::Triangle => "triangle",
            Waveform::Trapezoid { .. } => "trapezoid",
        }
    }
    /// Stress ratio R of each phase (precrack first).
    #[getter]
    fn r_ratios(&self) -> Vec<f64> {
        self.inner.phases.iter().map(|p| p.r_ratio).collect()
    }
    /// The spec's table of each phase (`precrack`, `loading`).
    #[getter]
    fn sections(&self) -> Vec<String> {
        (0..self.inner.phases.len()).map(|i| self.inner.phase_section(i)).collect()
    }
    /// Whether the load follows a block sequence or spectrum (`[variable_amplitude]`).
    #[getter]
    fn variable_amplitude(&self) -> bool {
        !self.inner.sequence.is_empty()
    }
    #[getter]
    fn max_cycles(&self) -> u64 {
        self.inner.limits.max_cycles
    }
    /// The amplitude ramp-in [cycles] the test runs (given or the core's default).
    #[getter]
    fn start_amplitude_cycles(&self) -> f64 {
        self.inner.envelope.amplitude_cycles
    }

    fn __repr__(&self) -> String {
        format!("TestConfig({} W = {} m, {} phase(s), {} Hz)", self.inner.specimen.geometry.name(), self.inner.specimen.width_m,
            self.inner.phases.len(), self.inner.frequency_hz)
    }
}

pub(crate) fn mode_from(s: &str) -> PyResult<ExecMode> {
    match s {
        "full" => Ok(ExecMode::Full),
        "jump" => Ok(ExecMode::Jump),
        other => Err(InputError::new_err(format!("mode `{other}`: use full or jump"))),
    }
}

/// The raw-window policy of a `TestRun` (dict: first_cycles, decade_cycles, pre_cycles,
/// post_cycles; a key left out takes the core's `RAW_POLICY`); None keeps no raw samples.
pub(crate) fn raw_from(raw: Option<&Bound<'_, PyDict>>) -> PyResult<engine::RawCapture> {
    Ok(match raw {
        None => engine::RawCapture::default(),
        Some(d) => {
            let r: HashMap<String, u64> = d.extract().map_err(|e| InputError::new_err(format!("raw policy: {e}")))?;
            let (first, decade, pre, post) = engine::RawCapture::DEFAULT_POLICY;
            let get = |k: &str, default: u64| r.get(k).copied().unwrap_or(default);
            engine::RawCapture::new(get("first_cycles", first), get("decade_cycles", decade), get("pre_cycles", pre as u64) as usize,
                get("post_cycles", post))
        }
    })
}

// ---- out: tables ------------------------------------------------------------------------------

/// The per-cycle table's columns as the record names them (SI, units in the names): the one list.
impl Columns for Records {
    fn columns(&self) -> Vec<(&'static str, Column<'_>)> {
        vec![
            ("cycle", Column::U64(&self.cycle)), ("phase", Column::U8(&self.phase)), ("events", Column::U32(&self.events)),
            ("fmax_n", Column::F64(&self.fmax_n)), ("fmin_n", Column::F64(&self.fmin_n)),
            ("fmax_target_n", Column::F64(&self.fmax_target_n)), ("fmin_target_n", Column::F64(&self.fmin_target_n)),
            ("peak_err_pct", Column::F64(&self.peak_err_pct)), ("df_err_pct", Column::F64(&self.df_err_pct)),
            ("a_m", Column::F64(&self.a_m)), ("delta_k_pa_sqrt_m", Column::F64(&self.delta_k)),
            ("delta_k_target_pa_sqrt_m", Column::F64(&self.delta_k_target)), ("kmax_pa_sqrt_m", Column::F64(&self.kmax)),
            ("dadn_m_per_cycle", Column::F64(&self.dadn_m)), ("k_sp_n_m", Column::F64(&self.k_sp_n_m)),
            ("ctrl_u1_v", Column::F64(&self.ctrl_u1_v)), ("ctrl_u2_v", Column::F64(&self.ctrl_u2_v)),
            ("a_law_m", Column::F64(&self.a_law_m)), ("opening_force_n", Column::F64(&self.opening_force_n)),
            ("delta_k_eff_pa_sqrt_m", Column::F64(&self.delta_k_eff)),
        ]
    }
}

/// Raw sample windows, one column per `RAW_COLUMNS` name.
pub(crate) struct RawSamples(Vec<Vec<f64>>);

impl RawSamples {
    pub(crate) fn from_rows(rows: Vec<[f64; engine::RAW_COLUMNS.len()]>) -> Self {
        let mut cols: Vec<Vec<f64>> = (0..engine::RAW_COLUMNS.len()).map(|_| Vec::with_capacity(rows.len())).collect();
        for r in &rows {
            for (c, v) in cols.iter_mut().zip(r) {
                c.push(*v);
            }
        }
        RawSamples(cols)
    }
}

impl Columns for RawSamples {
    fn columns(&self) -> Vec<(&'static str, Column<'_>)> {
        engine::RAW_COLUMNS.iter().zip(&self.0).map(|(n, c)| (*n, Column::F64(c))).collect()
    }
}

/// A table leaving the core: named, typed columns as an Arrow record batch
/// (`pyarrow.record_batch(table)`, no copy); `table["a_m"]` is one column as a numpy array.
#[pyclass(name = "Table", module = "htm._core", frozen)]
pub struct PyTable {
    inner: Arc<dyn Columns>,
}

impl PyTable {
    pub(crate) fn new(t: impl Columns) -> Self {
        PyTable { inner: Arc::new(t) }
    }
}

#[pymethods]
impl PyTable {
    /// `(schema, array)` PyCapsules of the Arrow C Data Interface (a struct array).
    #[pyo3(signature = (requested_schema = None))]
    fn __arrow_c_array__<'py>(&self, py: Python<'py>, requested_schema: Option<Bound<'py, PyAny>>) -> PyResult<Bound<'py, pyo3::types::PyTuple>> {
        let _ = requested_schema; // the columns have one type each: no cast offered
        let (s, a) = arrow::export(py, self.inner.clone())?;
        pyo3::types::PyTuple::new(py, [s.into_any(), a.into_any()])
    }

    fn __arrow_c_schema__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyCapsule>> {
        arrow::export_schema(py, &*self.inner)
    }

    fn __len__(&self) -> usize {
        self.inner.columns().first().map_or(0, |(_, c)| match c {
            Column::U8(v) => v.len(),
            Column::U32(v) => v.len(),
            Column::U64(v) => v.len(),
            Column::F64(v) => v.len(),
        })
    }

    /// Column names in order.
    fn keys(&self) -> Vec<&'static str> {
        self.inner.columns().iter().map(|(n, _)| *n).collect()
    }

    fn __contains__(&self, name: &str) -> bool {
        self.inner.columns().iter().any(|(n, _)| *n == name)
    }

    /// One column as a numpy array (a copy).
    fn __getitem__<'py>(&self, py: Python<'py>, name: &str) -> PyResult<Bound<'py, PyAny>> {
        let cols = self.inner.columns();
        let (_, c) = cols.iter().find(|(n, _)| *n == name).ok_or_else(|| PyKeyError::new_err(format!("no column `{name}`")))?;
        Ok(match c {
            Column::U8(v) => PyArray1::from_slice(py, v).into_any(),
            Column::U32(v) => PyArray1::from_slice(py, v).into_any(),
            Column::U64(v) => PyArray1::from_slice(py, v).into_any(),
            Column::F64(v) => PyArray1::from_slice(py, v).into_any(),
        })
    }
}

// ---- out: the outcome -------------------------------------------------------------------------

/// Convergence episodes: cause, first_cycle, cycles_seen, cycles_to_2pct, cycles_to_0p5pct
/// (None while not inside), worst_first_df_pct.
pub(crate) fn convergence_list<'py>(py: Python<'py>, eps: &[Episode]) -> PyResult<Bound<'py, PyList>> {
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

/// How a test ended, its worst force errors and its per-cycle table.
#[pyclass(name = "Outcome", module = "htm._core", frozen)]
pub struct PyOutcome {
    inner: Outcome,
    table: Py<PyTable>,
}

impl PyOutcome {
    pub(crate) fn new(py: Python<'_>, mut o: Outcome) -> PyResult<Self> {
        let records = std::mem::take(&mut o.records);
        Ok(PyOutcome { inner: o, table: Py::new(py, PyTable::new(records))? })
    }
}

#[pymethods]
impl PyOutcome {
    /// Why the test ended (`target_crack_length`, `cycle_limit`, ...).
    #[getter]
    fn end_reason(&self) -> &'static str {
        self.inner.end_reason.name()
    }
    /// Cycles applied to the end (start-up included, smooth stop excluded).
    #[getter]
    fn cycles(&self) -> u64 {
        self.inner.cycles
    }
    #[getter]
    fn a_end_m(&self) -> f64 {
        self.inner.a_end_m
    }
    #[getter]
    fn max_abs_df_err_pct(&self) -> f64 {
        self.inner.max_abs_df_err_pct
    }
    #[getter]
    fn max_abs_peak_err_pct(&self) -> f64 {
        self.inner.max_abs_peak_err_pct
    }
    #[getter]
    fn cycles_simulated(&self) -> u64 {
        self.inner.cycles_simulated
    }
    #[getter]
    fn size_criterion_cycle(&self) -> Option<u64> {
        self.inner.size_criterion_cycle
    }
    #[getter]
    fn velocity_gain_m_s_per_v(&self) -> f64 {
        self.inner.velocity_gain_m_s_per_v
    }
    /// The demodulation controller's gains (plant_gain_n_per_s_v, k1, kp2, ki2, window), or None.
    #[getter]
    fn demod_gains<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        self.inner.demod_gains.as_ref().map(|g| {
            let d = PyDict::new(py);
            d.set_item("plant_gain_n_per_s_v", g.plant_gain_n_per_s_v)?;
            d.set_item("k1", g.k1)?;
            d.set_item("kp2", g.kp2)?;
            d.set_item("ki2", g.ki2)?;
            d.set_item("window", g.window)?;
            Ok(d)
        }).transpose()
    }
    #[getter]
    fn convergence<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        convergence_list(py, &self.inner.convergence)
    }
    /// Worst |ΔF error| [%] over the first cycles after the start, or None.
    #[getter]
    fn worst_first_cycles_df_pct(&self) -> Option<f64> {
        self.inner.convergence.iter().find(|e| e.cycles_seen > 0).map(|e| e.worst_first_df_pct)
    }
    /// The per-cycle table (empty from `TestRun.outcome()`: its rows left chunk by chunk).
    #[getter]
    fn table(&self, py: Python<'_>) -> Py<PyTable> {
        self.table.clone_ref(py)
    }
    fn __repr__(&self) -> String {
        format!("Outcome(end_reason={:?}, cycles={}, a_end_m={})", self.inner.end_reason.name(), self.inner.cycles, self.inner.a_end_m)
    }
}

/// One chunk of a `TestRun`: new per-cycle rows, raw samples and the end (None while running).
#[pyclass(name = "Chunk", module = "htm._core", frozen, get_all)]
pub struct PyChunk {
    pub table: Py<PyTable>,
    pub raw: Py<PyTable>,
    pub end_reason: Option<&'static str>,
}

impl PyChunk {
    pub(crate) fn new(py: Python<'_>, c: engine::Chunk) -> PyResult<Self> {
        Ok(PyChunk {
            table: Py::new(py, PyTable::new(c.records))?,
            raw: Py::new(py, PyTable::new(RawSamples::from_rows(c.raw)))?,
            end_reason: c.end.map(|e| e.name()),
        })
    }
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyTestConfig>()?;
    m.add_class::<PyTable>()?;
    m.add_class::<PyOutcome>()?;
    m.add_class::<PyChunk>()?;
    Ok(())
}
