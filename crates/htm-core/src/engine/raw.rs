//! Raw high-rate windows of a test ("limit raw data"): every control sample of the first cycles,
//! of a few cycles from each decade (10, 100, 1000, …) and of the cycles around events; the rest
//! of the test keeps only its per-cycle row.
use std::collections::VecDeque;

use super::events;
use crate::machine::Outputs;

/// Columns of one raw sample: test time [s] (cycle/f at each cycle's end), cycle number (1-based,
/// the per-cycle table's), valve command [V], position [m], force [N], force setpoint [N],
/// chamber pressures A and B [Pa].
pub const RAW_COLUMNS: [&str; 8] = ["t_s", "cycle", "u_v", "y_m", "f_n", "f_ref_n", "p_a_pa", "p_b_pa"];

/// Event bits whose appearance keeps a window around the cycle (the others are states that
/// would keep whole stretches: start-up is covered by `first`, jumps have no samples).
const NOTABLE: u32 = events::OUT_OF_TOLERANCE | events::TOLERANCE_EXCEEDED | events::SIZE_CRITERION
    | events::STIFFNESS_STEP | events::PHASE_CHANGE | events::STOP | events::END;

/// The capture policy and its memory (part of an engine snapshot, so a resumed test keeps the
/// same windows). Disabled by default: `run_test` keeps no samples.
#[derive(Debug, Clone, Default, serde::Serialize, serde::Deserialize)]
pub struct RawCapture {
    pub enabled: bool,
    /// cycles 1..=first are kept whole
    pub first_cycles: u64,
    /// cycles 10^k .. 10^k + decade_cycles − 1 are kept (k ≥ 1)
    pub decade_cycles: u64,
    /// cycles kept before and after a cycle whose events newly include a notable bit
    pub pre_cycles: usize,
    pub post_cycles: u64,
    cur: Vec<[f64; 8]>,
    ring: VecDeque<Vec<[f64; 8]>>,
    post_left: u64,
    prev_ev: u32,
    /// kept samples not yet handed out (`take`)
    out: Vec<[f64; 8]>,
}

impl RawCapture {
    /// The capture `htm run` records with: the first 30 cycles, 2 from each decade, 2 before and
    /// 2 after each notable event.
    pub const DEFAULT_POLICY: (u64, u64, usize, u64) = (30, 2, 2, 2);

    pub fn new(first_cycles: u64, decade_cycles: u64, pre_cycles: usize, post_cycles: u64) -> Self {
        RawCapture { enabled: true, first_cycles, decade_cycles, pre_cycles, post_cycles, ..Default::default() }
    }

    /// One control sample at test time `t_s` [s] with command `u` [V] and force setpoint `f_ref` [N].
    #[inline]
    pub fn sample(&mut self, t_s: f64, u: f64, o: &Outputs, f_ref: f64) {
        if self.enabled {
            self.cur.push([t_s, 0.0, u, o.y, o.f, f_ref, o.p_a, o.p_b]);
        }
    }

    fn in_decade(&self, cycle: u64) -> bool {
        let mut d = 10u64;
        while d <= cycle {
            if cycle < d + self.decade_cycles {
                return true;
            }
            d = match d.checked_mul(10) {
                Some(x) => x,
                None => break,
            };
        }
        false
    }

    /// The per-cycle row of `cycle` was written with event bits `ev`: keep or set aside the
    /// samples of that cycle.
    pub fn end_cycle(&mut self, cycle: u64, ev: u32) {
        if !self.enabled {
            return;
        }
        let fresh = ev & !self.prev_ev & NOTABLE != 0;
        self.prev_ev = ev;
        if self.cur.is_empty() {
            return; // a jump row: nothing was sampled
        }
        let mut samples = std::mem::take(&mut self.cur);
        for s in samples.iter_mut() {
            s[1] = cycle as f64;
        }
        if fresh {
            for c in self.ring.drain(..) {
                self.out.extend_from_slice(&c);
            }
            self.post_left = self.post_cycles;
            self.out.extend_from_slice(&samples);
        } else if cycle <= self.first_cycles || self.in_decade(cycle) || self.post_left > 0 {
            self.post_left = self.post_left.saturating_sub(1);
            self.out.extend_from_slice(&samples);
        } else if self.pre_cycles > 0 {
            if self.ring.len() == self.pre_cycles {
                let mut old = self.ring.pop_front().unwrap();
                old.clear();
                self.cur = old; // reuse the allocation
            }
            self.ring.push_back(samples);
            return;
        }
        self.ring.clear();
    }

    /// The kept samples so far (and forget them).
    pub fn take(&mut self) -> Vec<[f64; 8]> {
        std::mem::take(&mut self.out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cycle(r: &mut RawCapture, c: u64, ev: u32) {
        for k in 0..4 {
            r.sample(c as f64 + k as f64 / 4.0, 0.0, &Outputs::default(), 0.0);
        }
        r.end_cycle(c, ev);
    }

    #[test]
    fn keeps_first_cycles_decades_and_windows_around_events() {
        let mut r = RawCapture::new(3, 2, 2, 1);
        for c in 1..=200 {
            cycle(&mut r, c, if c == 50 { events::STIFFNESS_STEP } else { 0 });
        }
        let mut kept: Vec<u64> = r.take().iter().map(|s| s[1] as u64).collect();
        kept.dedup();
        assert_eq!(kept, vec![1, 2, 3, 10, 11, 48, 49, 50, 51, 100, 101]);
    }
}
