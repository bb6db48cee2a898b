//! Solver work per control sample on the million-cycle benchmark's scenario (a profiling aid):
//! `cargo run --release --example solver_work -- 5000` (cycles).
use htm_core::crack::Law;
use htm_core::engine::*;
use htm_core::machine::Machine;
use htm_core::params::Params;
use htm_core::specimen::{Geometry, Material, Specimen};
use htm_core::waveform::{Envelope, Waveform};

fn main() {
    let cycles: u64 = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(2000);
    let w = 50.8e-3;
    let cfg = TestConfig {
        params: Params::default(),
        rtol: 1e-4,
        specimen: Specimen::new(Geometry::CT, w, 6.35e-3).unwrap(),
        material: Material::default(),
        law: Law::Paris { c: 1.1413e-30, m: 3.0 },
        a0_m: 15.2e-3,
        waveform: Waveform::Sine,
        frequency_hz: 10.0,
        control_rate_hz: 1000.0,
        phases: vec![Phase { mode: Mode::ConstantForce { delta_f_n: 4.45e3 }, r_ratio: 0.1, end_a_m: 0.6 * w, tolerance: 0.02 }],
        controller: ControllerSpec::Demod { velocity_gain_m_s_per_v: None },
        envelope: Envelope { mean_cycles: 5.0, amplitude_cycles: 20.0, stop_cycles: 3.0 },
        limits: Limits { max_cycles: cycles, size_criterion: Action::Flag, tolerance_cycles: 10, tolerance_action: Action::Flag, stroke_margin_m: 1e-3 },
        stiffness_steps: vec![],
        jump: JumpConfig::default(),
        sequence: vec![],
        sequence_from_spectrum: false,
        measurement: htm_core::engine::Measurement::model(),
    };
    let mut p = cfg.params.clone();
    p.specimen_stiffness_n_m = cfg.specimen.stiffness(cfg.a0_m, &cfg.material).unwrap();
    let mut m = Machine::new(p).unwrap().with_rtol(cfg.rtol).unwrap();
    let mut cm = CycleMachine::new(&cfg, cfg.control_rate_hz, m.outputs().f).unwrap();
    let t0 = std::time::Instant::now();
    let mut samples = 0u64;
    let mut last = None;
    for _ in 0..cycles {
        cm.begin(&cfg).unwrap();
        let mut meas = m.outputs();
        for _ in 0..cm.n {
            let u = cm.command(&cfg, meas.f, meas.y);
            meas = m.step(u, cm.dt).unwrap();
            cm.observe(meas.f, meas.y);
            samples += 1;
        }
        last = cm.close(&cfg).unwrap();
    }
    let el = t0.elapsed().as_secs_f64();
    let s = m.stats();
    println!("{cycles} cycles in {el:.3} s ({:.0}/s); per sample: accepted {:.3} rejected {:.3} rhs {:.3}; last {:?}",
        cycles as f64 / el, s.accepted as f64 / samples as f64, s.rejected as f64 / samples as f64, s.rhs_evals as f64 / samples as f64,
        last.map(|r| (r.fmax_n, r.fmin_n)));
}
