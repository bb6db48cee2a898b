//! Cyclic force waveforms (sine, triangle, trapezoid) as unit shapes s(φ) ∈ [−1, 1] over one
//! cycle φ ∈ [0, 1), their mean and fundamental, and the smooth start/stop envelope.
use crate::error::{Error, Result};
use std::f64::consts::PI;

/// Unit waveform; the force is mid + amp·s(φ) with mid = (Fmax + Fmin)/2, amp = (Fmax − Fmin)/2.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Waveform {
    /// s = sin(2πφ)
    Sine,
    /// symmetric triangle, in phase with the sine (rises through 0 at φ = 0, peak at φ = 1/4)
    Triangle,
    /// rise from valley to peak over `rise` of the cycle, hold the peak for `hold`, fall over
    /// `rise`, hold the valley for the rest (1 − 2·rise − hold); starts mid-rise at φ = 0.
    Trapezoid { rise: f64, hold: f64 },
}

impl Waveform {
    pub fn validate(&self) -> Result<()> {
        if let Waveform::Trapezoid { rise, hold } = *self {
            if !(rise.is_finite() && rise > 0.0 && rise <= 0.5) {
                return Err(Error::Parameter { field: "rise_fraction".into(), value: rise, allowed: "(0, 0.5]".into() });
            }
            if !(hold.is_finite() && hold >= 0.0 && 2.0 * rise + hold <= 1.0 + 1e-12) {
                return Err(Error::Parameter { field: "hold_fraction".into(), value: hold, allowed: format!("[0, {}] (1 − 2·rise)", 1.0 - 2.0 * rise) });
            }
        }
        Ok(())
    }

    pub fn name(&self) -> &'static str {
        match self {
            Waveform::Sine => "sine",
            Waveform::Triangle => "triangle",
            Waveform::Trapezoid { .. } => "trapezoid",
        }
    }

    /// Unit shape at cycle phase φ (any real; wrapped to [0, 1)).
    #[inline]
    pub fn shape(&self, phase: f64) -> f64 {
        let p = phase - phase.floor();
        match *self {
            Waveform::Sine => (2.0 * PI * p).sin(),
            Waveform::Triangle => {
                if p < 0.25 { 4.0 * p } else if p < 0.75 { 2.0 - 4.0 * p } else { 4.0 * p - 4.0 }
            }
            Waveform::Trapezoid { rise, hold } => {
                // shift so that the cycle starts half-way up the rise
                let q = (p + 0.5 * rise).fract();
                let fall0 = rise + hold;
                if q < rise {
                    -1.0 + 2.0 * q / rise
                } else if q < fall0 {
                    1.0
                } else if q < fall0 + rise {
                    1.0 - 2.0 * (q - fall0) / rise
                } else {
                    -1.0
                }
            }
        }
    }

    /// Phase where the shape falls through zero (the peak's half of the cycle ends there).
    pub fn fall_crossing(&self) -> f64 {
        match *self {
            Waveform::Sine | Waveform::Triangle => 0.5,
            Waveform::Trapezoid { rise, hold } => rise + hold,
        }
    }

    /// Largest |ds/dφ| over a cycle (per cycle): the peak force rate is amp·f·max_slope, so the
    /// piston speed a shape needs, and with it the valve flow, scales with this (sine 2π,
    /// triangle 4, trapezoid 2/rise).
    pub fn max_slope(&self) -> f64 {
        match *self {
            Waveform::Sine => 2.0 * PI,
            Waveform::Triangle => 4.0,
            Waveform::Trapezoid { rise, .. } => 2.0 / rise,
        }
    }

    /// (mean of s over a cycle, magnitude of its fundamental: |∫2·s·e^{−i2πφ}dφ|), by a fine
    /// midpoint sum (exact enough for the controller's targets; computed once per test).
    pub fn stats(&self) -> (f64, f64) {
        if let Waveform::Sine = self {
            return (0.0, 1.0);
        }
        let n = 20_000;
        let (mut m, mut c, mut s) = (0.0, 0.0, 0.0);
        for i in 0..n {
            let p = (i as f64 + 0.5) / n as f64;
            let v = self.shape(p);
            m += v;
            s += 2.0 * v * (2.0 * PI * p).sin();
            c += 2.0 * v * (2.0 * PI * p).cos();
        }
        let nf = n as f64;
        (m / nf, ((s / nf).powi(2) + (c / nf).powi(2)).sqrt())
    }
}

/// Smooth start and stop: the mean ramps from 0 over `mean_cycles`, then the amplitude over
/// `amplitude_cycles`; at the end the amplitude ramps down over `stop_cycles` (the mean is then
/// held; unloading is the operator's). Returns (mean factor, amplitude factor) at `cycle_pos`
/// (cycles since start, fractional).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Envelope {
    pub mean_cycles: f64,
    pub amplitude_cycles: f64,
    pub stop_cycles: f64,
}

/// The start-up and stop of a test that states none: mean over 5 cycles, amplitude over 20,
/// stop over 3.
impl Default for Envelope {
    fn default() -> Self {
        Envelope { mean_cycles: 5.0, amplitude_cycles: 20.0, stop_cycles: 3.0 }
    }
}

/// The shortest amplitude ramp-in of a test that states none [s].
pub const START_AMPLITUDE_MIN_S: f64 = 1.0;

impl Envelope {
    /// The default at test frequency `f_hz`: the amplitude ramps in over 20 cycles or
    /// `START_AMPLITUDE_MIN_S`, whichever is longer. The loops learn per cycle, and above 20 Hz
    /// the plant departs further from the reference each cycle (the oil column and the valve
    /// round a triangle's corners): the force's error at the ramp's end falls as 1/length², so
    /// 20 cycles leave a 40 Hz triangle at ≈ 2 %, 40 at ≈ 0.6 % (`benchmarks/million_cycles.py`).
    pub fn for_frequency(f_hz: f64) -> Self {
        let d = Envelope::default();
        Envelope { amplitude_cycles: d.amplitude_cycles.max((f_hz * START_AMPLITUDE_MIN_S).ceil()), ..d }
    }

    #[inline]
    pub fn start(&self, cycle_pos: f64) -> (f64, f64) {
        let ramp = |x: f64, n: f64| if n <= 0.0 { 1.0 } else { smoothstep((x / n).clamp(0.0, 1.0)) };
        (ramp(cycle_pos, self.mean_cycles), ramp(cycle_pos - self.mean_cycles, self.amplitude_cycles))
    }
    /// Start-up cycles before the test proper begins.
    pub fn start_cycles(&self) -> u64 {
        (self.mean_cycles + self.amplitude_cycles).ceil() as u64
    }
}

/// C¹ ramp 0 → 1 on [0, 1] (3x² − 2x³): no step in the force rate at either end.
#[inline]
pub fn smoothstep(x: f64) -> f64 {
    x * x * (3.0 - 2.0 * x)
}

/// A test's amplitude ramp at the mean (hold, resume, stop), counted in samples:
/// scale = from + (to − from)·smoothstep(pos/len). The cycle machine and the life machine share it.
/// Saved (a checkpoint) as the tuple (from, to, pos, len) it was before it had a name.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(from = "(f64, f64, u64, u64)", into = "(f64, f64, u64, u64)")]
pub struct Ramp {
    from: f64,
    to: f64,
    pos: u64,
    len: u64,
}

impl From<(f64, f64, u64, u64)> for Ramp {
    fn from((from, to, pos, len): (f64, f64, u64, u64)) -> Self {
        Ramp { from, to, pos, len }
    }
}

impl From<Ramp> for (f64, f64, u64, u64) {
    fn from(r: Ramp) -> Self {
        (r.from, r.to, r.pos, r.len)
    }
}

impl Ramp {
    /// Full amplitude, no ramp under way.
    pub const FULL: Ramp = Ramp { from: 1.0, to: 1.0, pos: 0, len: 0 };

    /// The scale `ahead` samples from now.
    #[inline]
    pub fn scale(&self, ahead: u64) -> f64 {
        let pos = self.pos + ahead;
        if pos >= self.len { self.to } else { self.from + (self.to - self.from) * smoothstep(pos as f64 / self.len as f64) }
    }

    /// Ramp from the scale now to `to` over `cycles` cycles of `n` samples (at least 0.05 cycle).
    pub fn retarget(&mut self, to: f64, cycles: f64, n: usize) {
        *self = Ramp { from: self.scale(0), to, pos: 0, len: (cycles.max(0.05) * n as f64).round() as u64 };
    }

    /// One sample on.
    #[inline]
    pub fn advance(&mut self) {
        if self.pos < self.len {
            self.pos += 1;
        }
    }

    /// The ramp has reached its target.
    pub fn done(&self) -> bool {
        self.pos >= self.len
    }

    /// The scale the ramp goes to.
    pub fn target(&self) -> f64 {
        self.to
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_ramp_retargeted_midway_starts_from_where_it_stood() {
        let mut r = Ramp::FULL;
        assert_eq!(r.scale(0), 1.0);
        r.retarget(0.0, 1.0, 10);
        for _ in 0..5 {
            r.advance();
        }
        let mid = r.scale(0);
        assert!((mid - 0.5).abs() < 1e-12 && !r.done());
        r.retarget(1.0, 2.0, 10);
        assert_eq!(r.scale(0), mid);
        for _ in 0..25 {
            r.advance();
        }
        assert!(r.done() && r.scale(0) == 1.0 && r.scale(3) == 1.0 && r.target() == 1.0);
    }

    #[test]
    fn shapes_span_unit_range_and_start_rising_through_zero() {
        for w in [Waveform::Sine, Waveform::Triangle, Waveform::Trapezoid { rise: 0.2, hold: 0.3 }] {
            let xs: Vec<f64> = (0..1000).map(|i| w.shape(i as f64 / 1000.0)).collect();
            let (lo, hi) = xs.iter().fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
            assert!((hi - 1.0).abs() < 1e-9 && (lo + 1.0).abs() < 1e-9, "{w:?} spans {lo}..{hi}");
            assert!(w.shape(0.0).abs() < 1e-12 && w.shape(0.01) > 0.0, "{w:?} must rise through 0 at φ = 0");
        }
    }

    #[test]
    fn stats_match_closed_forms() {
        let (m, b1) = Waveform::Triangle.stats();
        assert!(m.abs() < 1e-9 && (b1 - 8.0 / (PI * PI)).abs() < 1e-6, "triangle b1 {b1}");
        // asymmetric trapezoid: peak hold 0.4, valley hold 0.2 → mean > 0
        let (m, _) = Waveform::Trapezoid { rise: 0.2, hold: 0.4 }.stats();
        assert!((m - 0.2).abs() < 1e-6, "trapezoid mean {m}");
        assert!(Waveform::Trapezoid { rise: 0.4, hold: 0.5 }.validate().is_err());
    }

    #[test]
    fn max_slope_matches_the_sampled_shape() {
        for w in [Waveform::Sine, Waveform::Triangle, Waveform::Trapezoid { rise: 0.1, hold: 0.2 }] {
            let n = 100_000;
            let d = (0..n).map(|i| (w.shape((i + 1) as f64 / n as f64) - w.shape(i as f64 / n as f64)).abs() * n as f64).fold(0.0, f64::max);
            assert!((d / w.max_slope() - 1.0).abs() < 1e-3, "{w:?}: {d} vs {}", w.max_slope());
        }
    }

    #[test]
    fn envelope_ramps_mean_then_amplitude() {
        let e = Envelope { mean_cycles: 2.0, amplitude_cycles: 4.0, stop_cycles: 2.0 };
        assert_eq!(e.start(0.0), (0.0, 0.0));
        assert_eq!(e.start(2.0), (1.0, 0.0));
        assert!((e.start(4.0).1 - 0.5).abs() < 1e-12);
        assert_eq!(e.start(6.0), (1.0, 1.0));
        assert_eq!(e.start_cycles(), 6);
    }

    #[test]
    fn the_default_ramp_in_lasts_20_cycles_or_a_second() {
        assert_eq!(Envelope::for_frequency(10.0), Envelope::default());
        assert_eq!(Envelope::for_frequency(20.0).amplitude_cycles, 20.0);
        assert_eq!(Envelope::for_frequency(40.0).amplitude_cycles, 40.0);
        assert_eq!(Envelope::for_frequency(33.3).amplitude_cycles, 34.0);
    }
}
