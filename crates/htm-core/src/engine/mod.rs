//! The fatigue test engine: plant + force controller + specimen + crack growth, cycle by cycle.
//! Each cycle's measured force peak and valley give ΔK and Kmax, the growth law advances a, and
//! K_sp(a) goes back into the plant.
//!
//! * `config`: what a test is (spec, validation, targets, the per-cycle table, the outcome);
//! * `cycle`: the cycle machine, the one per-period/per-cycle logic the simulator and the
//!   real-time loop (`crate::cyclic`) both run;
//! * `sim`: the simulator around it (plant, K_sp(a) feedback, cycle jump);
//! * `batch`: many tests on all cores; `session`: a test in resumable chunks; `raw`: raw windows.
use std::sync::atomic::{AtomicBool, AtomicU64};

use crate::error::Result;

mod batch;
pub mod config;
pub mod convergence;
pub mod cycle;
pub mod life;
pub mod measured;
mod raw;
mod session;
mod sim;

pub use batch::run_batch;
pub use config::*;
pub use convergence::{Cause, Episode};
pub use cycle::{CycleMachine, CycleResult, Stage};
pub use measured::{CrackReader, CrackSource, GaugeChain, Measurement, Reading};
pub use raw::{RawCapture, RAW_COLUMNS};
pub use session::{Chunk, Session};

/// Run one test. `progress` receives the cycle count as it goes; `cancel` stops it.
pub fn run_test(cfg: &TestConfig, mode: ExecMode, progress: Option<&AtomicU64>, cancel: Option<&AtomicBool>) -> Result<Outcome> {
    let mut sim = sim::Sim::start(cfg, mode, RawCapture::default())?;
    sim.advance(cfg, mode, u64::MAX, None, progress, cancel)?.expect("an unbounded advance runs to the end");
    Ok(sim.outcome())
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::crack::Law;
    use crate::params::Params;
    use crate::specimen::{Geometry, Material, Specimen};
    use crate::waveform::{Envelope, Waveform};

    /// Table B.1's C(T) (B = 6.35 mm, W = 50.8 mm, ΔP = 4.45 kN, R = 0.1) on the thesis rig, with
    /// a Paris law through Table B.1's row 4 (8.21e-5 mm/cycle at 19.3 MPa·√m, m = 3) scaled by `c_scale`.
    pub fn table_b1(freq: f64, rate: f64, a_end_over_w: f64, c_scale: f64) -> TestConfig {
        let w = 50.8e-3;
        TestConfig {
            params: Params::default(),
            rtol: 1e-4,
            specimen: Specimen::new(Geometry::CT, w, 6.35e-3).unwrap(),
            material: Material::default(),
            law: Law::Paris { c: c_scale * 8.21e-8 / 19.3e6f64.powi(3), m: 3.0 },
            a0_m: 15.2e-3,
            waveform: Waveform::Sine,
            frequency_hz: freq,
            control_rate_hz: rate,
            phases: vec![Phase { mode: Mode::ConstantForce { delta_f_n: 4.45e3 }, r_ratio: 0.1, end_a_m: a_end_over_w * w, tolerance: 0.02 }],
            controller: ControllerSpec::Demod { velocity_gain_m_s_per_v: None },
            envelope: Envelope { mean_cycles: 5.0, amplitude_cycles: 20.0, stop_cycles: 3.0 },
            limits: Limits { max_cycles: 10_000_000, size_criterion: Action::Flag, tolerance_cycles: 10, tolerance_action: Action::Flag, stroke_margin_m: 1e-3 },
            stiffness_steps: vec![],
            jump: JumpConfig::default(),
            sequence: vec![],
            sequence_from_spectrum: false,
            measurement: Measurement::model(),
        }
    }

    #[test]
    fn demod_holds_two_percent_as_the_crack_grows_and_jump_agrees() {
        let cfg = table_b1(10.0, 1000.0, 0.35, 30.0);
        let o = run_test(&cfg, ExecMode::Full, None, None).unwrap();
        assert_eq!(o.end_reason, EndReason::TargetCrack);
        assert!(o.max_abs_df_err_pct < 2.0 && o.max_abs_peak_err_pct < 2.0, "{} {}", o.max_abs_df_err_pct, o.max_abs_peak_err_pct);
        let r = &o.records;
        let n = r.cycle.len();
        assert!(r.k_sp_n_m[n - 1] < 0.8 * r.k_sp_n_m[0], "K_sp must fall as the crack grows");
        assert!(r.events[..20].iter().all(|e| e & events::START != 0));
        let j = run_test(&cfg, ExecMode::Jump, None, None).unwrap();
        assert!(j.cycles_simulated * 3 < o.cycles_simulated, "jump resolved {} of {}", j.cycles_simulated, o.cycles);
        let err = (j.cycles as f64 / o.cycles as f64 - 1.0).abs();
        assert!(err < 0.01, "jump {} vs full {}", j.cycles, o.cycles);
    }

    /// The amplitude loop's relative gain learns only from amplitudes large enough to judge: from
    /// the first small cycles of the ramp-in it swung to its limits and spent the ramp coming
    /// back, and the first full-amplitude cycles of a fast triangle missed ±2 % (2.08 % here).
    /// A case outside the benchmark's table: 35 Hz, 6 kN.
    #[test]
    fn a_fast_triangle_is_inside_two_percent_from_its_first_full_cycle() {
        let mut cfg = table_b1(35.0, 1000.0, 0.35, 1.0);
        cfg.waveform = Waveform::Triangle;
        cfg.phases[0].mode = Mode::ConstantForce { delta_f_n: 6e3 };
        cfg.limits.max_cycles = 45;
        assert!(crate::feasibility::refusals(&cfg).unwrap().is_empty(), "the rig can run it");
        let o = run_test(&cfg, ExecMode::Full, None, None).unwrap();
        let e = &o.convergence[0];
        assert!(e.cycles_seen >= 20 && e.worst_first_df_pct < 2.0, "{e:?}");
    }

    /// `htm run` with a measurement: the specimen's truth grows by the law, the test runs on the
    /// crack read through the simulated chain (noise, resolution, closure at 30 % of Fmax); both
    /// are in the table, within E647's resolution of each other, and the opening force is found.
    #[test]
    fn a_measured_crack_follows_the_truth_within_e647_resolution() {
        for (crack, y, closure) in [(CrackSource::Compliance, f64::NAN, 0.3), (CrackSource::PotentialDrop, 0.004, 0.0)] {
            let mut cfg = table_b1(10.0, 500.0, 0.45, 60.0);
            cfg.measurement = Measurement { crack, gauge_y_m: y, closure_opening_fraction: closure, noise: if y.is_nan() { 0.2e-6 } else { 1e-4 }, ..Measurement::model() };
            let o = run_test(&cfg, ExecMode::Full, None, None).unwrap();
            assert_eq!(o.end_reason, EndReason::TargetCrack, "{crack:?}");
            let r = &o.records;
            let res = crate::crack_measure::resolution_m(cfg.specimen.width_m);
            let first = r.events.iter().position(|e| e & events::READING != 0).expect("readings");
            let worst = (first..r.cycle.len()).map(|i| (r.a_m[i] - r.a_law_m[i]).abs()).fold(0.0, f64::max);
            let grown = r.a_law_m[r.cycle.len() - 1] - r.a_law_m[first];
            eprintln!("{crack:?}: worst |a − a_true| {:.3} mm over {:.2} mm of growth (E647 resolution {:.3} mm)", worst * 1e3, grown * 1e3, res * 1e3);
            assert!(grown > 5e-3 && worst < res, "{crack:?}: worst {worst}");
            if closure > 0.0 {
                let i = r.cycle.len() - 5;
                let err = (r.opening_force_n[i] - closure * r.fmax_n[i]).abs() / r.fmax_n[i];
                assert!(err < 0.05, "opening force {} vs {}", r.opening_force_n[i], closure * r.fmax_n[i]);
                assert!(r.delta_k_eff[i] < 0.8 * r.delta_k[i]);
            }
        }
        // a cycle jump carries the truth and the measured crack together
        let mut cfg = table_b1(10.0, 500.0, 0.45, 30.0);
        cfg.measurement = Measurement { crack: CrackSource::Compliance, ..Measurement::model() };
        let o = run_test(&cfg, ExecMode::Jump, None, None).unwrap();
        assert_eq!(o.end_reason, EndReason::TargetCrack);
        let r = &o.records;
        let worst = (0..r.cycle.len()).map(|i| (r.a_m[i] - r.a_law_m[i]).abs()).fold(0.0, f64::max);
        assert!(worst < 1e-4, "jump: {worst}");
    }

    #[test]
    fn bad_configs_fail_before_running() {
        let mut c = table_b1(10.0, 1000.0, 0.35, 1.0);
        c.phases[0].mode = Mode::KGradient { delta_k0: 10e6, c_per_m: -100.0 };
        assert!(run_test(&c, ExecMode::Full, None, None).unwrap_err().to_string().contains("k_gradient_per_m"));
        let mut c = table_b1(10.0, 1000.0, 0.35, 1.0);
        c.phases[0].r_ratio = 1.0;
        assert!(c.validate().unwrap_err().to_string().contains("r_ratio"));
        let mut c = table_b1(10.0, 1000.0, 0.35, 1.0);
        c.material.fracture_toughness_pa_sqrt_m = 15e6;
        assert!(c.validate().unwrap_err().to_string().contains("K_IC"));
    }
}

