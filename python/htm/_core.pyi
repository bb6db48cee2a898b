"""Type stubs for the Rust extension `htm._core` (crates/htm-core/src/python)."""
from typing import Any, TypedDict, final

import numpy as np
import numpy.typing as npt

__all__ = [
    "HtmError", "InputError", "ParameterError", "SolverError", "__version__",
    "Params", "Machine", "g_ct", "h_ct", "a_range", "stress_intensity", "size_criterion", "compliance_ct", "stiffness_ct",
    "crack_length_from_compliance_ct", "growth_rate", "rainflow", "newman_f", "life", "life_curve", "crack_after", "pmax_from_delta_p",
    "CyclicController", "Detectors", "RigPlant", "Progress", "EVENTS", "run_test", "start_amplitude_cycles", "run_batch", "TestRun",
    "TestConfig", "Outcome", "Chunk", "Table",
    "feasibility", "MARGINAL_FRACTION", "RESONANCE_FRACTION",
    "friction_force", "LoopParams", "loop_simulate", "replay", "SpecimenParams", "specimen_force", "closure_spring",
    "CHANNELS", "RAW_COLUMNS", "RAW_POLICY", "TEST_DEFAULTS", "TEST_R_RATIO_RANGE", "LOAD_R_RATIO_RANGE", "MAX_TOLERANCE",
    "TEST_TOLERANCE", "PRECRACK_TOLERANCE", "MIN_SAMPLES_PER_CYCLE", "MAX_CONTROL_RATE_HZ", "E647_MIN_K_GRADIENT_PER_M",
    "RTOL_RANGE", "NASGRO_DEFAULTS", "YOUNGS_MODULUS_RANGE_PA", "POISSON_RATIO_RANGE",
    "run_life", "run_life_batch", "virtual_life", "cyclic_stress", "LifeController", "LifeRig",
]

__version__: str

# measured channels in DATA_FORMAT order (measure.rs CHANNELS)
CHANNELS: tuple[str, ...]

class HtmError(Exception): ...
class ParameterError(HtmError):
    # set on every ParameterError the core raises: the field by the spec's own path
    # (``loading.r_ratio``), the value given and the allowed range with its unit
    field: str
    value: float
    allowed: str
class InputError(HtmError): ...
class SolverError(HtmError): ...

# one row of Params.fields(); a dict at run time, so private to the stub
class _FieldInfo(TypedDict):
    name: str
    unit: str
    doc: str
    min: float
    max: float
    min_open: bool
    allowed: str

# a closed-loop controller table (DATA_FORMAT's `controller`, SI): type position_pff or force_p
class _ControllerArgs(TypedDict, total=False):
    type: str
    kp_v_per_m: float
    kff_v_per_m_s: float
    kp_v_per_n: float
    u_max_v: float

class _Stats(TypedDict):
    accepted_steps: int
    rejected_steps: int
    rhs_evals: int

# a trace of Machine.simulate / track: arrays per sample (t, u, y, v, p_a, p_b, p_s, f) and stats
class _Trace(TypedDict):
    stats: _Stats
    t: npt.NDArray[np.float64]
    u: npt.NDArray[np.float64]
    y: npt.NDArray[np.float64]
    v: npt.NDArray[np.float64]
    p_a: npt.NDArray[np.float64]
    p_b: npt.NDArray[np.float64]
    p_s: npt.NDArray[np.float64]
    f: npt.NDArray[np.float64]

# a growth law (a spec's `[law]` table, SI): law paris, forman or nasgro and its constants
class _Law(TypedDict, total=False):
    law: str
    c: float
    m: float
    kc: float
    n: float
    p: float
    q: float
    dk_th: float
    k_crit: float
    f_open: float

class _Life(TypedDict):
    cycles: float
    a_end_m: float
    fractured: bool

# every extension class is @final: pyo3 classes cannot be subclassed at run time
@final
class Params:
    """Machine parameters (SI). `Params()` is the thesis rig; `Params("base")` has a linear valve."""
    def __new__(cls, preset: str = "thesis") -> Params: ...
    def __getitem__(self, name: str, /) -> float: ...
    def __setitem__(self, name: str, value: float, /) -> None: ...
    def __contains__(self, name: str, /) -> bool: ...
    def keys(self) -> list[str]: ...
    def validate(self) -> None: ...
    def copy(self) -> Params: ...
    def to_dict(self) -> dict[str, float]: ...
    @staticmethod
    def fields() -> list[_FieldInfo]: ...
    valve_map: tuple[list[float], list[float]]

@final
class Machine:
    """The plant with its state [p_a Pa, p_b Pa, y m, v m/s, spool V, spool velocity V/s, lagged command V] and integrator."""
    def __new__(cls, params: Params | None = None, rtol: float | None = None) -> Machine: ...
    def step(self, u: float, dt: float) -> dict[str, float]: ...
    def outputs(self) -> dict[str, float]: ...
    state: npt.NDArray[np.float64]
    @property
    def t(self) -> float: ...
    @property
    def stats(self) -> _Stats: ...
    def rest_state(self, y: float) -> npt.NDArray[np.float64]: ...
    def rhs(self, x: npt.NDArray[np.float64], u: float) -> npt.NDArray[np.float64]: ...
    def simulate(self, u: npt.NDArray[np.float64], dt: float) -> _Trace: ...
    def track(self, reference: npt.NDArray[np.float64], dt: float, controller: _ControllerArgs) -> _Trace: ...
# --- fatigue: specimen and crack growth (crates/htm-core/src/{specimen,crack}.rs), SI units ---

def g_ct(alpha: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]: ...
def h_ct(alpha: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]: ...
def a_range(geometry: str, width_m: float, thickness_m: float) -> tuple[float, float]: ...
def stress_intensity(geometry: str, width_m: float, thickness_m: float, a_m: npt.NDArray[np.float64], force_n: float) -> npt.NDArray[np.float64]: ...
def size_criterion(geometry: str, width_m: float, thickness_m: float, a_m: npt.NDArray[np.float64], pmax_n: float, yield_strength_pa: float) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]: ...
def compliance_ct(width_m: float, thickness_m: float, a_m: npt.NDArray[np.float64], youngs_modulus_pa: float, poisson_ratio: float) -> npt.NDArray[np.float64]: ...
def stiffness_ct(width_m: float, thickness_m: float, a_m: npt.NDArray[np.float64], youngs_modulus_pa: float, poisson_ratio: float) -> npt.NDArray[np.float64]: ...
def crack_length_from_compliance_ct(width_m: float, thickness_m: float, compliance_m_per_n: npt.NDArray[np.float64], youngs_modulus_pa: float, poisson_ratio: float) -> npt.NDArray[np.float64]: ...
def rainflow(series: list[float]) -> list[tuple[float, float, float]]: ...
def growth_rate(law: _Law, delta_k: npt.NDArray[np.float64], r_ratio: float, kmax: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]: ...
def newman_f(r_ratio: float, smax_over_flow_stress: float, constraint_factor: float) -> float: ...
def life(law: _Law, geometry: str, width_m: float, thickness_m: float, pmax_n: float, r_ratio: float, a0_m: float, af_m: float) -> _Life: ...
def life_curve(law: _Law, geometry: str, width_m: float, thickness_m: float, pmax_n: float, r_ratio: float, a_m: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]: ...
def crack_after(law: _Law, geometry: str, width_m: float, thickness_m: float, pmax_n: float, r_ratio: float, a0_m: float, cycles: float) -> _Life: ...
def pmax_from_delta_p(delta_p_n: float, r_ratio: float) -> float: ...

# NASGRO terms a law may omit and their values then, SI (crack.rs NASGRO_DEFAULTS)
NASGRO_DEFAULTS: dict[str, float]
# stress ratios [lo, hi) of a load: life prediction, E647 data (crack.rs LOAD_R_RATIO_RANGE)
LOAD_R_RATIO_RANGE: tuple[float, float]
# a material's Young's modulus (lo, hi) [Pa] and Poisson's ratio [lo, hi) (specimen.rs)
YOUNGS_MODULUS_RANGE_PA: tuple[float, float]
POISSON_RATIO_RANGE: tuple[float, float]
# --- fatigue test engine (crates/htm-core/src/engine/, bindings python/convert.rs, engine.rs) ---

# event bits of the engine's per-cycle `events` column, by name (engine.rs `events`)
EVENTS: dict[str, int]
# the value a spec's key takes when the spec leaves it out (engine/config.rs defaults)
class _TestDefaults(TypedDict):
    rtol: float
    control_rate_hz: float
    start_mean_cycles: float
    stop_cycles: float
    max_cycles: int
    size_criterion_action: str
    tolerance_cycles: int
    tolerance_action: str
    stroke_margin_m: float
    jump_max_da_m: float
    jump_max_rel_change: float
    jump_settle_cycles: int
    jump_min_cycles: int

TEST_DEFAULTS: _TestDefaults
# ranges and constants of a test config (engine/config.rs): R of a phase [lo, hi), the largest force
# tolerance, the default tolerances of the test and of a precrack, samples per cycle, the highest
# control rate [Hz], the E647 K-gradient limit [1/m], the integrator tolerances [lo, hi]
TEST_R_RATIO_RANGE: tuple[float, float]
MAX_TOLERANCE: float
TEST_TOLERANCE: float
PRECRACK_TOLERANCE: float
MIN_SAMPLES_PER_CYCLE: float
MAX_CONTROL_RATE_HZ: float
E647_MIN_K_GRADIENT_PER_M: float
RTOL_RANGE: tuple[float, float]
# raw sample columns (SI) and the capture policy `htm run` records with (engine/raw.rs)
RAW_COLUMNS: tuple[str, ...]
RAW_POLICY: dict[str, int]

@final
class Progress:
    """Cycles done so far by a running test, and a cancel switch."""
    def __init__(self) -> None: ...
    @property
    def cycles(self) -> int: ...
    def cancel(self) -> None: ...

@final
class TestConfig:
    """A test's configuration: built once from its spec (an `htm.spec.TestSpec`) on rig `params`
    and validated (ParameterError names the spec's field); runs, checks and controllers take it."""
    def __new__(cls, spec: Any, params: Params) -> TestConfig: ...
    def with_params(self, params: Params) -> TestConfig: ...
    @property
    def params(self) -> Params: ...
    @property
    def frequency_hz(self) -> float: ...
    @property
    def waveform(self) -> str: ...
    @property
    def r_ratios(self) -> list[float]: ...
    @property
    def sections(self) -> list[str]: ...
    @property
    def variable_amplitude(self) -> bool: ...
    @property
    def max_cycles(self) -> int: ...
    @property
    def start_amplitude_cycles(self) -> float: ...

@final
class Table:
    """A table leaving the core: an Arrow record batch (`pyarrow.record_batch(table)`, no copy);
    `table["a_m"]` one column as a numpy array."""
    def __arrow_c_array__(self, requested_schema: object | None = None) -> tuple[object, object]: ...
    def __arrow_c_schema__(self) -> object: ...
    def __len__(self) -> int: ...
    def keys(self) -> list[str]: ...
    def __contains__(self, name: str, /) -> bool: ...
    def __getitem__(self, name: str, /) -> npt.NDArray[Any]: ...

# one convergence episode; a dict at run time, so private to the stub
class _Episode(TypedDict):
    cause: str
    first_cycle: int
    cycles_seen: int
    cycles_to_2pct: int | None
    cycles_to_0p5pct: int | None
    worst_first_df_pct: float

class _DemodGains(TypedDict):
    plant_gain_n_per_s_v: float
    k1: float
    kp2: float
    ki2: float
    window: int

@final
class Outcome:
    """How a test ended, its worst force errors and its per-cycle table."""
    @property
    def end_reason(self) -> str: ...
    @property
    def cycles(self) -> int: ...
    @property
    def a_end_m(self) -> float: ...
    @property
    def max_abs_df_err_pct(self) -> float: ...
    @property
    def max_abs_peak_err_pct(self) -> float: ...
    @property
    def cycles_simulated(self) -> int: ...
    @property
    def size_criterion_cycle(self) -> int | None: ...
    @property
    def velocity_gain_m_s_per_v(self) -> float: ...
    @property
    def demod_gains(self) -> _DemodGains | None: ...
    @property
    def convergence(self) -> list[_Episode]: ...
    @property
    def worst_first_cycles_df_pct(self) -> float | None: ...
    @property
    def table(self) -> Table: ...

@final
class Chunk:
    """One step of a TestRun: its new per-cycle rows, raw samples (RAW_COLUMNS) and the end."""
    @property
    def table(self) -> Table: ...
    @property
    def raw(self) -> Table: ...
    @property
    def end_reason(self) -> str | None: ...

def run_test(config: TestConfig, mode: str = "full", progress: Progress | None = None) -> Outcome: ...
def start_amplitude_cycles(frequency_hz: float) -> float: ...
# each item an Outcome, or the HtmError of a test that failed (its neighbours still run)
def run_batch(configs: list[TestConfig], mode: str = "full", threads: int = 0) -> list[Outcome | HtmError]: ...

# --- know before you start (crates/htm-core/src/feasibility.rs) ---
# a need above this fraction of its limit is marginal; the frequency limit is this fraction of
# the oil-column/specimen resonance
MARGINAL_FRACTION: float
RESONANCE_FRACTION: float

# one check of feasibility(); a dict at run time, so private to the stub
class _FeasibilityCheck(TypedDict):
    name: str
    status: str
    need: float
    limit: float
    unit: str
    phase: int
    a_m: float
    delta_f_n: float
    largest_delta_f_n: float | None
    largest_frequency_hz: float | None

def feasibility(config: TestConfig) -> list[_FeasibilityCheck]: ...

# --- a machine's closed displacement loop (crates/htm-core/src/outer_loop.rs) ---
@final
class LoopParams:
    """Parameters of a machine's closed displacement loop (SI); `LoopParams()` has every effect off."""
    stall_force_key: str
    def __new__(cls) -> LoopParams: ...
    def __getitem__(self, name: str, /) -> float: ...
    def __setitem__(self, name: str, value: float, /) -> None: ...
    def __contains__(self, name: str, /) -> bool: ...
    def keys(self) -> list[str]: ...
    def validate(self) -> None: ...
    def copy(self) -> LoopParams: ...
    def to_dict(self) -> dict[str, float]: ...
    @staticmethod
    def fields() -> list[_FieldInfo]: ...

# one parameter set's run: y [m], v [m/s], f [N] per sample; a failed set is its HtmError, as
# the item (every batch call's convention, run_batch's too)
class _LoopOutput(TypedDict):
    y: npt.NDArray[np.float64]
    v: npt.NDArray[np.float64]
    f: npt.NDArray[np.float64]

def loop_simulate(params: list[LoopParams], dt: float, y_ref: npt.NDArray[np.float64], load: npt.NDArray[np.float64] | None = None, threads: int = 0) -> list[_LoopOutput | HtmError]: ...

# --- specimen and load-train force model (crates/htm-core/src/specimen_force.rs) ---
@final
class SpecimenParams:
    """Parameters of a specimen and its load train (SI); `SpecimenParams()` has every effect off."""
    def __new__(cls) -> SpecimenParams: ...
    def __getitem__(self, name: str, /) -> float: ...
    def __setitem__(self, name: str, value: float, /) -> None: ...
    def __contains__(self, name: str, /) -> bool: ...
    def keys(self) -> list[str]: ...
    def validate(self) -> None: ...
    def copy(self) -> SpecimenParams: ...
    def to_dict(self) -> dict[str, float]: ...
    @staticmethod
    def fields() -> list[_FieldInfo]: ...

# the load cell's force [N] per sample for each set; a set that cannot be evaluated is its HtmError
def specimen_force(params: list[SpecimenParams], dt: float, y: npt.NDArray[np.float64], threads: int = 0) -> list[npt.NDArray[np.float64] | HtmError]: ...
# the bilinear spring a record's force shows against its displacement: (stiffness [N/m], closure
# stiffness [N/m], closure position [m], the record's coordinates), None where none is stiffer below
def closure_spring(f: npt.NDArray[np.float64], y: npt.NDArray[np.float64]) -> tuple[float, float, float] | None: ...

# --- real-time loop (crates/htm-core/src/cyclic.rs, control/limits.rs, rig.rs) ---
# the last closed cycle of the real-time loop (the per-cycle table's row, with the stroke range)
class _CycleResult(TypedDict):
    cycle: int
    phase: int
    starting: bool
    judged: bool
    events: int
    fmax_n: float
    fmin_n: float
    fmax_target_n: float
    fmin_target_n: float
    peak_err_pct: float
    df_err_pct: float
    a_m: float
    delta_k_pa_sqrt_m: float
    kmax_pa_sqrt_m: float
    dadn_m_per_cycle: float
    k_sp_n_m: float
    ymin_m: float
    ymax_m: float
    ctrl_u1_v: float
    ctrl_u2_v: float
    a_law_m: float
    opening_force_n: float
    delta_k_eff_pa_sqrt_m: float

class _ControllerInfo(TypedDict, total=False):
    rate_hz: float
    frequency_hz: float
    samples_per_cycle: int
    velocity_gain_m_s_per_v: float
    demod_k1: float
    demod_kp2: float
    demod_ki2: float
    protect_force_n: float
    max_speed_m_s: float

class _DetectorItem(TypedDict, total=False):
    name: str
    channel: int
    lo: float
    hi: float
    action: str
    persist: int

class _DetectorState(TypedDict):
    name: str
    channel: int
    lo: float
    hi: float
    action: str
    persist: int
    enabled: bool
    active: bool
    latched: bool
    trip_value: float

# the virtual rig's cracking specimen (SI): geometry, width_m, thickness_m, the material, law, a0_m
class _RigSpecimen(TypedDict, total=False):
    geometry: str
    width_m: float
    thickness_m: float
    youngs_modulus_pa: float
    poisson_ratio: float
    yield_strength_pa: float
    fracture_toughness_pa_sqrt_m: float
    law: _Law
    a0_m: float
    hysteresis_n: float
@final
class CyclicController:
    """Per-period controller of the real-time loop: `u = step(force_n, position_m)` [V]."""
    def __new__(cls, rate_hz: float, position: dict[str, float] | None = None) -> CyclicController: ...
    def step(self, force_n: float, position_m: float, measurement: float = ...) -> float: ...
    def start_test(self, config: TestConfig, f0_n: float) -> None: ...
    def position(self, y_m: float, u_v: float) -> None: ...
    def jog(self, rate_m_s: float) -> None: ...
    def jog_step(self, dm: float) -> None: ...
    def move_to(self, y_m: float) -> None: ...
    def hold(self) -> None: ...
    def resume(self) -> None: ...
    def stop(self) -> None: ...
    def idle(self) -> None: ...
    def convergence(self) -> list[_Episode]: ...
    def last_cycle(self) -> _CycleResult | None: ...
    def info(self) -> _ControllerInfo: ...
    command_limit_v: float
    @property
    def state(self) -> str: ...
    @property
    def cycle(self) -> int: ...
    @property
    def a_m(self) -> float: ...
    @property
    def a_law_m(self) -> float: ...
    @property
    def results(self) -> int: ...
    @property
    def u_null_v(self) -> float: ...
    @property
    def u_last_v(self) -> float: ...
    @property
    def end_reason(self) -> str | None: ...
    @property
    def protecting(self) -> bool: ...
    @property
    def starting_up(self) -> bool: ...
    @property
    def supply_demand_pa(self) -> float: ...
    @property
    def reference_m(self) -> float: ...
    @property
    def force_ref_n(self) -> float: ...
    @property
    def targets(self) -> tuple[float, float, float] | None: ...

@final
class TestRun:
    """A fatigue test run in bounded chunks; its complete state saves to bytes and restores (resume)."""
    def __new__(cls, config: TestConfig, mode: str = "full", raw: dict[str, int] | None = None) -> TestRun: ...
    @staticmethod
    def restore(config: TestConfig, mode: str, snapshot: bytes) -> TestRun: ...
    def advance(self, max_cycles: int = ..., max_seconds: float = 0.25) -> Chunk: ...
    def snapshot(self) -> bytes: ...
    @property
    def cycle(self) -> int: ...
    @property
    def a_m(self) -> float: ...
    @property
    def finished(self) -> bool: ...
    def outcome(self) -> Outcome | None: ...
    @staticmethod
    def raw_columns() -> list[str]: ...

@final
class Detectors:
    """Limit detectors: items {name, channel, lo, hi, action, persist}."""
    def __new__(cls, items: list[_DetectorItem]) -> Detectors: ...
    def check(self, values: list[float]) -> list[int]: ...
    def worst(self) -> str | None: ...
    def reset(self) -> list[str]: ...
    def set_enabled(self, name: str, enabled: bool) -> None: ...
    def describe(self) -> list[_DetectorState]: ...
    def __len__(self) -> int: ...

@final
class RigPlant:
    """The virtual rig's plant: machine + cracking specimen + supply response."""
    def __new__(cls, params: Params | None = None, specimen: _RigSpecimen | None = None, rtol: float = 1e-4) -> RigPlant: ...
    def step(self, u: float, dt: float) -> tuple[float, float, float, float, float, float]: ...
    def outputs(self) -> tuple[float, float, float, float, float, float]: ...
    def fracture(self) -> None: ...
    def add_gauge(self, crack: str, noise: float = 0.0, resolution: float = 0.0, drift_per_cycle: float = 0.0,
                  closure_opening_fraction: float = 0.0, gauge_x_over_w: float = ..., gauge_y_m: float = ..., seed: int = 1) -> int: ...
    def slip_gauge(self, i: int, offset_m: float) -> None: ...
    def gauge_offset(self, i: int) -> float: ...
    @property
    def gauge_readings(self) -> list[float]: ...
    supply_setpoint_pa: float
    @property
    def t(self) -> float: ...
    @property
    def a_m(self) -> float: ...
    @property
    def cycles(self) -> int: ...
    @property
    def fractured(self) -> bool: ...
    @property
    def k_sp_n_m(self) -> float: ...
    @property
    def valve_null_bias_v(self) -> float: ...

# --- record re-simulation (crates/htm-core/src/replay.rs, measure.rs); see htm.ident.sim ---
# one parameter set's replay: the readings of each measured channel and the command u per sample,
# the solver's accepted and rejected steps and right-hand-side evaluations; a failed set is its HtmError, as the item (every batch call's convention)
class _Replayed(TypedDict, total=False):
    y: npt.NDArray[np.float64]
    v: npt.NDArray[np.float64]
    p_a: npt.NDArray[np.float64]
    p_b: npt.NDArray[np.float64]
    p_s: npt.NDArray[np.float64]
    f: npt.NDArray[np.float64]
    u: npt.NDArray[np.float64]
    steps: int
    rejected: int
    rhs_evals: int

def replay(params: list[Params], dt: float, u: npt.NDArray[np.float64], measured: dict[str, npt.NDArray[np.float64]] | None = None,
           controller: _ControllerArgs | None = None, reference: npt.NDArray[np.float64] | None = None,
           horizon_s: float = ..., preroll_s: float = ..., rtol: float = ...,  # 0.5 s, 1.0 s, 1e-4 (replay.rs DEFAULT_*)
           noise: dict[str, npt.NDArray[np.float64]] | None = None, quantum: dict[str, float] | None = None,
           supply: npt.NDArray[np.float64] | None = None, active: npt.NDArray[np.bool_] | None = None,
           threads: int = 0, lockstep: bool = False, dense_stages: bool = False) -> list[_Replayed | HtmError]: ...

# --- identification (crates/htm-core/src/python/ident.rs) ---

def friction_force(params: Params, v: npt.NDArray[np.float64], p_sum: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Friction force [N] of the Stribeck model at velocities `v` [m/s] and chamber pressure sums `p_sum` [Pa]."""


# crack size and closure measured on the specimen (python/measure.rs, crack_measure.rs)
__all__ += ["crack_reduce", "ct_alpha_from_compliance", "ct_gauge_x_over_w", "correct_to_visual", "crack_resolution_m"]

# columns of crack_reduce: one value per burst or interval (SI; NaN where not measured)
class _CrackReduction(TypedDict):
    cycles: npt.NDArray[np.float64]
    n_cycles: npt.NDArray[np.float64]
    a_m: npt.NDArray[np.float64]
    a_std_m: npt.NDArray[np.float64]
    fmin_n: npt.NDArray[np.float64]
    fmax_n: npt.NDArray[np.float64]
    value: npt.NDArray[np.float64]
    opening_force_1pct_n: npt.NDArray[np.float64]
    opening_force_n: npt.NDArray[np.float64]
    opening_force_4pct_n: npt.NDArray[np.float64]
    opening_force_segments_n: npt.NDArray[np.float64]
    dk_pa_sqrt_m: npt.NDArray[np.float64]
    dk_eff_pa_sqrt_m: npt.NDArray[np.float64]
    resolution_m: npt.NDArray[np.float64]

def crack_reduce(geometry: str, width_m: float, thickness_m: float, method: str, cycle: npt.NDArray[np.float64],
                 signal: npt.NDArray[np.float64], f: npt.NDArray[np.float64] | None = None, *, modulus_pa: float | None = None,
                 cod_x_over_w: float = ..., cod_y_m: float | None = None, poisson_ratio: float = 0.3,
                 dcpd_probe_y_m: float | None = None, dcpd_a_ref_m: float | None = None, dcpd_v_ref: float | None = None,
                 calibration: tuple[list[float], list[float]] | None = None,
                 cycles_per_interval: int = 0) -> tuple[str, _CrackReduction]: ...
def ct_alpha_from_compliance(ebc: npt.NDArray[np.float64], x_over_w: float) -> npt.NDArray[np.float64]: ...
def ct_gauge_x_over_w(name: str) -> float: ...
def correct_to_visual(a_m: npt.NDArray[np.float64], a0_visual_m: float, af_visual_m: float) -> npt.NDArray[np.float64]: ...
def crack_resolution_m(width_m: float) -> float: ...

# --- life tests: force_life (E466), strain_life (E606) on the virtual round bar (engine/life.rs) ---
# a test as a flat dict of SI values (htm.fatigue.lifetest builds it); the result a dict of
# `table` and `loops` (numpy columns), end_reason, failed, cycles, n_drop10, n_drop50, n_modulus,
# cycles_simulated, velocity_gain_m_s_per_v and `truth` (the virtual specimen's milestones)
def run_life(spec: dict[str, Any], params: Params | None = None) -> dict[str, Any]: ...
# each item a result dict, or the HtmError of a test that failed
def run_life_batch(specs: list[dict[str, Any]], params: Params | None = None, threads: int = 0) -> list[dict[str, Any] | HtmError]: ...
# (N_init, N_50, N_sep) of the virtual specimen at the test's amplitude, without a controller
def virtual_life(spec: dict[str, Any]) -> tuple[float, float, float]: ...
def cyclic_stress(ea: float, e_pa: float, k_prime_pa: float, n_prime: float) -> float: ...

# the controller side of a life test, one control period at a time (the code run_life runs)
@final
class LifeController:
    def __new__(cls, spec: dict[str, Any], f0: float, strain0: float, params: Params | None = None) -> LifeController: ...
    @property
    def dt(self) -> float: ...
    @property
    def samples_per_cycle(self) -> int: ...
    @property
    def cycle(self) -> int: ...
    @property
    def end_reason(self) -> str | None: ...
    def command(self, f: float, strain: float, y: float) -> float: ...
    def at_end(self) -> bool: ...
    def close(self) -> dict[str, Any]: ...
    def next_cycle(self) -> None: ...
    # a rig's loop: one period (command, and the cycle's close when it ends); hold/resume/stop ramps
    def step(self, f: float, strain: float, y: float) -> float: ...
    @property
    def state(self) -> str: ...
    @property
    def results(self) -> int: ...
    @property
    def u_null_v(self) -> float: ...
    @property
    def targets(self) -> tuple[float, float]: ...
    @property
    def frequency_hz(self) -> float: ...
    @property
    def n_drop10(self) -> int | None: ...
    @property
    def n_drop50(self) -> int | None: ...
    @property
    def velocity_gain_m_s_per_v(self) -> float: ...
    def hold(self) -> bool: ...
    def resume(self) -> bool: ...
    def stop(self) -> None: ...
    def last_cycle(self) -> dict[str, Any] | None: ...
    def last_loop(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]: ...

# the virtual rig of a life test: plant and virtual bar behind (force, strain, position) sensors
@final
class LifeRig:
    def __new__(cls, spec: dict[str, Any], params: Params | None = None) -> LifeRig: ...
    def measure(self) -> tuple[float, float, float]: ...
    def step(self, u: float, dt: float) -> tuple[float, float, float]: ...
    # (y, v, p_a, p_b, p_s, force, strain) SI
    def outputs(self) -> tuple[float, float, float, float, float, float, float]: ...
    def step_all(self, u: float, dt: float) -> tuple[float, float, float, float, float, float, float]: ...
    supply_setpoint_pa: float
    @property
    def valve_null_bias_v(self) -> float: ...
    # the bar's hidden state (for tests; never the controller's)
    def truth(self) -> dict[str, Any]: ...
