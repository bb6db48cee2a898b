//! htm-core: the numerics of htm. Pure Rust over plain structs and slices; the `python`
//! feature adds thin pyo3 bindings that own no logic.
pub mod batch;
pub mod control;
pub mod crack;
pub mod crack_measure;
pub mod cyclic;
pub mod cyclic_material;
pub mod engine;
pub mod error;
pub mod feasibility;
pub mod friction;
pub mod hydraulics;
pub mod machine;
pub mod measure;
pub mod outer_loop;
pub mod params;
pub mod rainflow;
pub mod replay;
pub mod rig;
pub mod run;
pub mod solver;
pub mod specimen;
pub mod specimen_force;
pub mod waveform;

#[cfg(feature = "python")]
mod python;

pub use error::{Error, Result};
pub use machine::{Machine, Outputs};
pub use params::Params;
