"""The Rust core's Python face: the one module that imports the extension `htm._core`.

Every other module of htm reaches the core through here (the layers contract in pyproject.toml
puts this module at the bottom and forbids the others `htm._core`). The core owns every default
and range of a test config and the vocabulary the record shares with it; Python reads them here
instead of restating them:

- `TEST_DEFAULTS`: the value of each config key a spec leaves out (``rtol``, ``control_rate_hz``,
  start-up cycles, end conditions, cycle-jump control); the amplitude ramp-in, which depends on the
  frequency, is `start_amplitude_cycles(frequency_hz)`;
- `TEST_R_RATIO_RANGE` ``[lo, hi)`` of a test phase, `LOAD_R_RATIO_RANGE` of a load (life
  prediction, E647 data), `MAX_TOLERANCE`, `TEST_TOLERANCE`, `PRECRACK_TOLERANCE`,
  `MIN_SAMPLES_PER_CYCLE`, `MAX_CONTROL_RATE_HZ` [Hz], `E647_MIN_K_GRADIENT_PER_M` [1/m], `RTOL_RANGE`;
- `YOUNGS_MODULUS_RANGE_PA` (open), `POISSON_RATIO_RANGE` ``[lo, hi)`` of a material;
- `NASGRO_DEFAULTS`: the NASGRO terms a law may omit (SI: ``dk_th``, ``k_crit`` in Pa·√m);
- `TestConfig`: a test's configuration, built once from its spec (`htm.spec`) and validated; runs,
  checks and controllers take it as it is. A bad value raises `ParameterError` with `.field` (the
  spec's own path, ``loading.delta_k_pa_sqrt_m``), `.value` and `.allowed`;
- `Outcome` (a run's result, typed), `Chunk` (a `TestRun` step) and `Table` (the per-cycle table and
  raw samples: an Arrow record batch through `__arrow_c_array__`; `columns` gives numpy views);
- `EVENTS` (event bits of the per-cycle table by name), `CHANNELS` (measured channels, DATA_FORMAT
  order), `RAW_COLUMNS` and `RAW_POLICY` (raw sample windows).
"""
import numpy as np

from htm._core import (
    CHANNELS,
    E647_MIN_K_GRADIENT_PER_M,
    EVENTS,
    LOAD_R_RATIO_RANGE,
    MARGINAL_FRACTION,
    MAX_CONTROL_RATE_HZ,
    MAX_TOLERANCE,
    MIN_SAMPLES_PER_CYCLE,
    NASGRO_DEFAULTS,
    POISSON_RATIO_RANGE,
    PRECRACK_TOLERANCE,
    RAW_COLUMNS,
    RAW_POLICY,
    RESONANCE_FRACTION,
    RTOL_RANGE,
    TEST_DEFAULTS,
    TEST_R_RATIO_RANGE,
    TEST_TOLERANCE,
    YOUNGS_MODULUS_RANGE_PA,
    Chunk,
    CyclicController,
    Detectors,
    HtmError,
    InputError,
    LoopParams,
    Machine,
    Outcome,
    ParameterError,
    Params,
    Progress,
    RigPlant,
    SolverError,
    Table,
    TestConfig,
    TestRun,
    __version__,
    a_range,
    compliance_ct,
    crack_after,
    crack_length_from_compliance_ct,
    feasibility,
    friction_force,
    g_ct,
    growth_rate,
    h_ct,
    life,
    life_curve,
    loop_simulate,
    newman_f,
    pmax_from_delta_p,
    rainflow,
    replay,
    run_batch,
    run_test,
    size_criterion,
    start_amplitude_cycles,
    stiffness_ct,
    stress_intensity,
)

__all__ = [
    "CHANNELS", "E647_MIN_K_GRADIENT_PER_M", "EVENTS", "LOAD_R_RATIO_RANGE", "MARGINAL_FRACTION", "MAX_CONTROL_RATE_HZ",
    "MAX_TOLERANCE", "MIN_SAMPLES_PER_CYCLE", "NASGRO_DEFAULTS", "POISSON_RATIO_RANGE", "PRECRACK_TOLERANCE", "RAW_COLUMNS", "RAW_POLICY",
    "RESONANCE_FRACTION", "RTOL_RANGE", "TEST_DEFAULTS", "TEST_R_RATIO_RANGE", "TEST_TOLERANCE", "YOUNGS_MODULUS_RANGE_PA",
    "CyclicController", "Detectors", "HtmError", "InputError", "LoopParams", "Machine", "ParameterError", "Params",
    "Progress", "RigPlant", "SolverError", "Chunk", "Outcome", "Table", "TestConfig", "TestRun", "__version__", "columns",
    "a_range", "compliance_ct", "crack_after", "crack_length_from_compliance_ct", "feasibility", "friction_force", "g_ct",
    "growth_rate", "h_ct", "life", "life_curve", "loop_simulate", "newman_f", "pmax_from_delta_p", "rainflow", "replay",
    "run_batch", "run_test", "size_criterion", "start_amplitude_cycles", "stiffness_ct", "stress_intensity",
]

# crack size and closure measured on the specimen (crack_measure.rs)
from htm._core import correct_to_visual, crack_reduce, crack_resolution_m, ct_alpha_from_compliance, ct_gauge_x_over_w  # noqa: E402

__all__ += ["correct_to_visual", "crack_reduce", "crack_resolution_m", "ct_alpha_from_compliance", "ct_gauge_x_over_w"]

def columns(table: Table) -> dict[str, np.ndarray]:
    """A table leaving the core (`Table`: an Arrow record batch) as named numpy columns, each a
    view of the core's own buffer (no copy, no per-row Python)."""
    import pyarrow as pa

    batch = pa.record_batch(table)
    return {name: col.to_numpy(zero_copy_only=True) for name, col in zip(batch.schema.names, batch.columns, strict=True)}

# the specimen and load-train force model of displacement_input records (specimen_force.rs)
from htm._core import SpecimenParams, closure_spring, specimen_force  # noqa: E402

__all__ += ["SpecimenParams", "closure_spring", "specimen_force"]

# life tests (force_life, strain_life) and the virtual cyclic specimen (engine/life.rs, cyclic_material.rs)
from htm._core import LifeController, LifeRig, cyclic_stress, run_life, run_life_batch, virtual_life  # noqa: E402

__all__ += ["LifeController", "LifeRig", "cyclic_stress", "run_life", "run_life_batch", "virtual_life"]
