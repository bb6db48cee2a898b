//! The simulator: the cycle machine driving the plant model, with the specimen's stiffness K_sp(a)
//! fed back each cycle. Full fidelity runs every cycle through the plant; cycle-jump resolves
//! short blocks to steady state and integrates the growth across the cycles in between.
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Instant;

use super::config::{events, measured_k, targets, Action, EndReason, ExecMode, Outcome, Records, TestConfig};
use super::convergence::Cause;
use super::cycle::{CycleMachine, CycleResult, Stage};
use super::raw::RawCapture;
use crate::error::{Error, Result};
use crate::machine::{Machine, Y};

/// A simulated test between two cycles: plant, cycle machine and the simulator's own counters.
/// All of it is the state a snapshot saves (the rows are handed out as they are made).
#[derive(Clone, serde::Serialize, serde::Deserialize)]
pub(crate) struct Sim {
    m: Machine,
    pub cm: CycleMachine,
    /// piston position at zero specimen force [m]
    y0: f64,
    /// stiffness step factor in force (K_sp = factor·K_sp(a))
    ksp_factor: f64,
    next_step: usize,
    since_jump: u64,
    /// (peak, ΔF) error of the last cycle: a jump waits until they settle
    prev_err: (f64, f64),
    simulated: u64,
    stop_rows: u64,
    pending_ev: u32,
    pub raw: RawCapture,
    /// the measurement chain the specimen is read through (a spec's `[measurement]`): the
    /// truth is the law's crack (`cm.a_law`), the cycle machine runs on what the chain shows
    chain: Option<super::measured::GaugeChain>,
    #[serde(skip)]
    pub rec: Records,
}

impl Sim {
    /// A validated test at rest at the specimen's zero-force position, ready for cycle 1.
    pub fn start(cfg: &TestConfig, mode: ExecMode, raw: RawCapture) -> Result<Self> {
        cfg.validate()?;
        if mode == ExecMode::Jump && !cfg.sequence.is_empty() {
            return Err(Error::Input("cycle-jump needs constant-amplitude loading: run a variable-amplitude sequence in full mode (--mode full)".into()));
        }
        let mut p = cfg.params.clone();
        p.specimen_stiffness_n_m = cfg.specimen.stiffness(cfg.a0_m, &cfg.material)?;
        let m = Machine::new(p)?.with_rtol(cfg.rtol)?;
        let y0 = m.plant.p.specimen_zero_force_position_m;
        let cm = CycleMachine::new(cfg, cfg.control_rate_hz, m.outputs().f)?;
        let chain = super::measured::GaugeChain::new(&cfg.measurement, &cfg.specimen, &cfg.material, cfg.a0_m);
        Ok(Sim { m, cm, y0, ksp_factor: 1.0, next_step: 0, since_jump: 0, prev_err: (f64::NAN, f64::NAN), simulated: 0, stop_rows: 0, pending_ev: 0, raw, chain, rec: Records::default() })
    }

    fn set_stiffness(&mut self, cfg: &TestConfig, keep_force: bool) -> Result<()> {
        // the specimen's true crack: the law's (the same as the test's without a measurement)
        let k_new = cfg.specimen.stiffness(self.cm.a_law, &cfg.material)? * self.ksp_factor;
        let k_old = self.m.plant.p.specimen_stiffness_n_m;
        if keep_force && k_old > 0.0 {
            // a jump: keep the force continuous and tell the controller about the new gain
            self.m.x[Y] = self.y0 + (self.m.x[Y] - self.y0) * k_old / k_new;
            self.cm.rescale_gain(k_new / k_old);
        }
        self.m.plant.p.specimen_stiffness_n_m = k_new;
        Ok(())
    }

    fn push(&mut self, r: &CycleResult, cycle: u64, ev: u32) {
        let rec = &mut self.rec;
        rec.cycle.push(cycle);
        rec.phase.push(r.phase as u8);
        rec.fmax_n.push(r.fmax_n);
        rec.fmin_n.push(r.fmin_n);
        rec.fmax_target_n.push(r.fmax_target_n);
        rec.fmin_target_n.push(r.fmin_target_n);
        rec.peak_err_pct.push(r.peak_err_pct);
        rec.df_err_pct.push(r.df_err_pct);
        rec.a_m.push(r.a_m);
        rec.delta_k.push(r.delta_k);
        rec.delta_k_target.push(r.delta_k_target);
        rec.kmax.push(r.kmax);
        rec.dadn_m.push(r.dadn_m);
        rec.k_sp_n_m.push(self.m.plant.p.specimen_stiffness_n_m);
        rec.ctrl_u1_v.push(r.ctrl_u1_v);
        rec.ctrl_u2_v.push(r.ctrl_u2_v);
        rec.events.push(ev);
        rec.a_law_m.push(r.a_law_m);
        rec.opening_force_n.push(r.opening_force_n);
        rec.delta_k_eff.push(r.delta_k_eff);
        self.raw.end_cycle(cycle, ev);
    }

    /// One cycle through the plant.
    fn cycle_through(&mut self, cfg: &TestConfig) -> Result<CycleResult> {
        let (n, dt) = (self.cm.n, self.cm.dt);
        let c0 = self.cm.cycle as f64;
        let mut meas = self.m.outputs();
        for k in 0..n {
            let u = self.cm.command(cfg, meas.f, meas.y);
            meas = self.m.step(u, dt)?;
            self.raw.sample((c0 + (k + 1) as f64 / n as f64) / cfg.frequency_hz, u, &meas, self.cm.f_ref);
            self.cm.observe(meas.f, meas.y);
            if let Some(ch) = &mut self.chain {
                let m = ch.read(&cfg.specimen, self.cm.a_law, meas.f, self.cm.targets().0);
                self.cm.observe_measure(meas.f, m);
            }
        }
        if let Some(ch) = &mut self.chain {
            ch.cycle();
        }
        self.simulated += 1;
        Ok(self.cm.close(cfg)?.expect("a cycle was begun"))
    }

    /// Run cycles until the test is over (`Some(reason)`, its smooth stop included), or pause
    /// between two cycles (`None`) once `until_cycle` cycles are counted or the wall clock passes
    /// `deadline`. A paused test continues exactly as if it had never stopped.
    pub fn advance(&mut self, cfg: &TestConfig, mode: ExecMode, until_cycle: u64, deadline: Option<Instant>, progress: Option<&AtomicU64>, cancel: Option<&AtomicBool>) -> Result<Option<EndReason>> {
        let mut steps = cfg.stiffness_steps.clone();
        steps.sort_by_key(|s| s.0);
        loop {
            if self.cm.end.is_none() {
                if cancel.is_some_and(|c| c.load(Ordering::Relaxed)) {
                    self.cm.finish(cfg, EndReason::Cancelled);
                    if let Some(e) = self.rec.events.last_mut() {
                        *e |= events::END;
                    }
                } else if self.cm.cycle >= until_cycle || deadline.is_some_and(|d| Instant::now() >= d) {
                    return Ok(None);
                }
                // scheduled stiffness steps (before this cycle)
                while self.next_step < steps.len() && steps[self.next_step].0 <= self.cm.cycle + 1 {
                    self.ksp_factor = steps[self.next_step].1;
                    self.set_stiffness(cfg, false)?;
                    self.next_step += 1;
                    self.pending_ev |= events::STIFFNESS_STEP;
                    self.cm.disturbed(Cause::StiffnessStep);
                }
            }
            self.cm.begin(cfg)?;
            if self.cm.stage == Stage::Stopped {
                return Ok(self.cm.end);
            }
            let r = self.cycle_through(cfg)?;
            if !r.counted {
                // the smooth stop after the end: not counted, no growth
                self.stop_rows += 1;
                self.push(&r, self.cm.cycle + self.stop_rows, r.events);
                continue;
            }
            let ev = r.events | std::mem::take(&mut self.pending_ev);
            self.push(&r, r.cycle, ev);
            if let Some(p) = progress {
                p.store(self.cm.cycle, Ordering::Relaxed);
            }
            self.since_jump = if ev & events::PHASE_CHANGE != 0 { 0 } else { self.since_jump + 1 };
            let (pe, de) = (r.peak_err_pct / 100.0, r.df_err_pct / 100.0);
            // settled: peak and range errors changed by < 0.01 % of target over the last cycle
            let settled = (pe - self.prev_err.0).abs() < 1e-4 && (de - self.prev_err.1).abs() < 1e-4;
            self.prev_err = (pe, de);
            if self.cm.end.is_some() {
                continue;
            }
            self.set_stiffness(cfg, false)?;
            let ready = self.since_jump >= cfg.jump.settle_cycles && (settled || self.since_jump >= 10 * cfg.jump.settle_cycles);
            // a measured crack: a reading since the last jump first (the table keeps the chain's data)
            let read = self.cm.reader.as_ref().is_none_or(|rd| !rd.readings.is_empty());
            if mode == ExecMode::Jump && ev & events::START == 0 && ready && read && r.fmax_n > 0.0 {
                self.jump(cfg, &r, ev, steps.get(self.next_step).map(|s| s.0))?;
            }
        }
    }

    /// Integrate the growth across as many cycles as the bounds on Δa, ΔK and K_sp allow, with
    /// the forces predicted from the last resolved cycle (`last`).
    fn jump(&mut self, cfg: &TestConfig, last: &CycleResult, last_ev: u32, next_step_cycle: Option<u64>) -> Result<()> {
        let spec = &cfg.specimen;
        let law = &cfg.law;
        let kic = cfg.material.fracture_toughness_pa_sqrt_m;
        let a_max_valid = spec.a_range().1;
        let cm = &self.cm;
        let (a0, a_phase0, phase_i) = (cm.a, cm.a_phase0, cm.phase_i);
        let ph = cfg.phases[phase_i];
        let t_now = targets(cfg, &ph, a_phase0, a0)?;
        let (rmax, rmin) = (last.fmax_n / t_now.0, if t_now.1 != 0.0 { last.fmin_n / t_now.1 } else { f64::NAN });
        let forces = |a: f64| -> Result<(f64, f64)> {
            let t = targets(cfg, &ph, a_phase0, a)?;
            Ok((t.0 * rmax, if t.1 != 0.0 { t.1 * rmin } else { last.fmin_n }))
        };
        let rate = |a: f64| -> Result<f64> {
            let (fx, fn_) = forces(a)?;
            let (dk, kmax, r) = measured_k(spec, a, fx, fn_, ph.r_ratio)?;
            Ok(law.rate(dk, r, kmax))
        };
        // largest Δa within the bounds on Δa, ΔK and K_sp change, and the phase end
        let y_now = spec.k(a0, 1.0)?;
        let (f0x, f0n) = forces(a0)?;
        let dk_now = measured_k(spec, a0, f0x, f0n, ph.r_ratio)?.0;
        let k_now = spec.stiffness(a0, &cfg.material)?;
        let rel = cfg.jump.max_rel_change;
        let mut da = cfg.jump.max_da_m.min(ph.end_a_m - a0);
        for _ in 0..30 {
            let a1 = a0 + da;
            let ok = a1 < a_max_valid && {
                let (fx, fn_) = forces(a1)?;
                let dk1 = measured_k(spec, a1, fx, fn_, ph.r_ratio)?.0;
                let k1 = spec.stiffness(a1, &cfg.material)?;
                let y1 = spec.k(a1, 1.0)?;
                (dk1 / dk_now - 1.0).abs() <= rel && (k1 / k_now - 1.0).abs() <= rel && (y1 / y_now - 1.0).abs() <= 4.0 * rel
            };
            if ok {
                break;
            }
            da *= 0.5;
        }
        let r_mid = rate(a0 + 0.5 * da)?;
        let mut jn = if r_mid > 0.0 && r_mid.is_finite() { (da / r_mid).floor() as u64 } else { 0 };
        jn = jn.min(cfg.limits.max_cycles - cm.cycle);
        if let Some(c) = next_step_cycle {
            jn = jn.min(c.saturating_sub(cm.cycle + 1));
        }
        // RK4 in N across the jump, shortened while it would cross an end condition
        while jn >= cfg.jump.min_jump_cycles {
            let h = jn as f64;
            let k1 = rate(a0)?;
            let k2 = rate(a0 + 0.5 * h * k1)?;
            let k3 = rate(a0 + 0.5 * h * k2)?;
            let k4 = rate(a0 + h * k3)?;
            let a1 = a0 + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
            let (fx, fn_) = forces(a1)?;
            let kmax1 = spec.k(a1, fx).unwrap_or(f64::INFINITY);
            let (lig, req) = spec.size_criterion(a1, fx, cfg.material.yield_strength_pa).unwrap_or((0.0, 1.0));
            let size_stop = cfg.limits.size_criterion == Action::Stop && lig < req;
            if a1 >= ph.end_a_m || kmax1 >= kic || size_stop || !a1.is_finite() {
                jn /= 2;
                continue;
            }
            let (dk1, km1, r1) = measured_k(spec, a1, fx, fn_, ph.r_ratio)?;
            let cm = &mut self.cm;
            if last_ev & events::OUT_OF_TOLERANCE != 0 {
                cm.out_count += jn;
            }
            if lig < req {
                cm.size_cycle.get_or_insert(cm.cycle + 1);
            }
            cm.cycle += jn;
            // the truth moves by the growth integrated; a measured crack starts again from it (the
            // chain's errors are simulated over resolved cycles, not across a jump)
            cm.a_law += a1 - cm.a;
            cm.a = a1;
            if let Some(rd) = &mut cm.reader {
                cm.a = cm.a_law;
                rd.restart(cm.a_law);
            }
            self.set_stiffness(cfg, true)?;
            let t1 = targets(cfg, &ph, a_phase0, a1)?;
            let row = CycleResult {
                fmax_n: fx, fmin_n: fn_, fmax_target_n: t1.0, fmin_target_n: t1.1, delta_k_target: t1.2,
                peak_err_pct: (fx - t1.0) / t1.0 * 100.0, df_err_pct: ((fx - fn_) - (t1.0 - t1.1)) / (t1.0 - t1.1) * 100.0,
                a_m: self.cm.a, delta_k: dk1, kmax: km1, dadn_m: law.rate(dk1, r1, km1), a_law_m: self.cm.a_law, ..*last
            };
            let ev = events::JUMP | if lig < req { events::SIZE_CRITERION } else { 0 };
            self.push(&row, self.cm.cycle, ev);
            self.since_jump = 0;
            if self.cm.cycle >= cfg.limits.max_cycles {
                self.cm.finish(cfg, EndReason::CycleLimit);
                if let Some(e) = self.rec.events.last_mut() {
                    *e |= events::END;
                }
            }
            break;
        }
        Ok(())
    }

    /// The summary once the test is over (the rows made so far included).
    pub fn outcome(&mut self) -> Outcome {
        let cm = &self.cm;
        Outcome {
            records: std::mem::take(&mut self.rec),
            end_reason: cm.end.unwrap_or(EndReason::Cancelled),
            cycles: cm.cycle,
            a_end_m: cm.a,
            max_abs_df_err_pct: cm.max_df,
            max_abs_peak_err_pct: cm.max_peak,
            cycles_simulated: self.simulated,
            size_criterion_cycle: cm.size_cycle,
            velocity_gain_m_s_per_v: cm.velocity_gain,
            demod_gains: cm.gains,
            convergence: cm.convergence.clone(),
        }
    }
}
