//! The measurement model: what each sensor reads of the true plant outputs — per channel an
//! offset, a gain and a transport delay (EFFECTS `sensor_offset`, `sensor_gain`, `sensor_delay`)
//! and a declared first-order anti-alias filter (DATA_FORMAT `sensors.<ch>.lowpass_hz`), plus
//! optional additive noise and quantization (a record generator's option, not a parameter).
//! In a closed loop the controller sees these readings, not the true signals.
use crate::machine::Outputs;
use crate::params::Params;

/// Measured channels, in this order everywhere (DATA_FORMAT column names).
pub const CHANNELS: [&str; 6] = ["y", "v", "p_a", "p_b", "p_s", "f"];
pub const NC: usize = 6;

/// One sensor: reads `offset + gain * F(true)(t - delay_s)`, F a first-order low-pass of cut-off
/// `lowpass_hz` (none when 0).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sensor {
    pub offset: f64,
    pub gain: f64,
    pub delay_s: f64,
    pub lowpass_hz: f64,
}

impl Sensor {
    pub const IDEAL: Sensor = Sensor { offset: 0.0, gain: 1.0, delay_s: 0.0, lowpass_hz: 0.0 };

    /// The reading of a true value (delay applied by the caller).
    #[inline]
    pub fn read(&self, x: f64) -> f64 {
        self.offset + self.gain * x
    }

    /// The true value behind a reading (to start a simulation from measurements).
    #[inline]
    pub fn unread(&self, r: f64) -> f64 {
        (r - self.offset) / self.gain
    }
}

/// The six sensors of a rig, from the `sensor_*` parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sensors(pub [Sensor; NC]);

impl Sensors {
    pub fn from_params(p: &Params) -> Self {
        let s = |offset, gain, delay_s, lowpass_hz| Sensor { offset, gain, delay_s, lowpass_hz };
        Sensors([
            s(p.sensor_offset_y, p.sensor_gain_y, p.sensor_delay_y_s, p.sensor_lowpass_y_hz),
            s(p.sensor_offset_v, p.sensor_gain_v, p.sensor_delay_v_s, p.sensor_lowpass_v_hz),
            s(p.sensor_offset_p_a, p.sensor_gain_p_a, p.sensor_delay_p_a_s, p.sensor_lowpass_p_a_hz),
            s(p.sensor_offset_p_b, p.sensor_gain_p_b, p.sensor_delay_p_b_s, p.sensor_lowpass_p_b_hz),
            s(p.sensor_offset_p_s, p.sensor_gain_p_s, p.sensor_delay_p_s_s, p.sensor_lowpass_p_s_hz),
            s(p.sensor_offset_f, p.sensor_gain_f, p.sensor_delay_f_s, p.sensor_lowpass_f_hz),
        ])
    }
}

/// The true outputs as an array in `CHANNELS` order.
#[inline]
pub fn channels(o: &Outputs) -> [f64; NC] {
    [o.y, o.v, o.p_a, o.p_b, o.p_s, o.f]
}

/// Measured readings as `Outputs` (what a controller takes); the spool is not measured.
#[inline]
pub fn as_outputs(r: &[f64; NC]) -> Outputs {
    Outputs { y: r[0], v: r[1], p_a: r[2], p_b: r[3], p_s: r[4], f: r[5], spool: f64::NAN }
}

/// Noise and quantization of the readings (the proving ground's realistic sensors).
#[derive(Debug, Clone, Default)]
pub struct Corruption<'a> {
    /// additive noise per channel, one value per sample from the first recorded sample on
    pub noise: [Option<&'a [f64]>; NC],
    /// quantization step per channel (0 = none) [channel unit]
    pub quantum: [f64; NC],
}

/// The history of (filtered) true outputs at the sample instants, read back through the sensors.
#[derive(Debug, Clone)]
pub struct Probe {
    sensors: Sensors,
    dt: f64,
    history: [Vec<f64>; NC],
    /// last true value per channel (the filters' input), None before the first sample or after
    /// a restart (the filter then starts settled on its input)
    last: Option<[f64; NC]>,
}

impl Probe {
    pub fn new(sensors: Sensors, dt: f64, capacity: usize) -> Self {
        Probe { sensors, dt, history: std::array::from_fn(|_| Vec::with_capacity(capacity)), last: None }
    }

    /// Append the true outputs of the newest sample (through each channel's filter).
    pub fn push(&mut self, o: &Outputs) {
        let x = channels(o);
        for c in 0..NC {
            let fc = self.sensors.0[c].lowpass_hz;
            let h = &mut self.history[c];
            let v = match (self.last, h.last()) {
                (Some(prev), Some(&y0)) if fc > 0.0 => lowpass_step(y0, prev[c], x[c], 2.0 * std::f64::consts::PI * fc * self.dt),
                _ => x[c],
            };
            h.push(v);
        }
        self.last = Some(x);
    }

    /// The plant state was re-set (an open-loop restart): the filters start again settled on
    /// the next sample instead of filtering the jump.
    pub fn restart(&mut self) {
        self.last = None;
    }

    pub fn len(&self) -> usize {
        self.history[0].len()
    }

    /// Drop all but the newest `keep` samples (a consumer that runs for hours: the virtual rig);
    /// readings need the samples back to the longest delay.
    pub fn keep_latest(&mut self, keep: usize) {
        for h in &mut self.history {
            if h.len() > keep {
                h.drain(..h.len() - keep);
            }
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Noise-free readings of the newest sample: each channel's true history at t - delay,
    /// interpolated linearly between samples (held at the first sample before the history).
    pub fn read_latest(&self) -> [f64; NC] {
        let k = self.len() - 1;
        std::array::from_fn(|c| {
            let s = &self.sensors.0[c];
            let h = &self.history[c];
            let x = if s.delay_s == 0.0 {
                h[k]
            } else {
                let pos = k as f64 - s.delay_s / self.dt;
                if pos <= 0.0 {
                    h[0]
                } else {
                    let i = pos.floor() as usize;
                    let w = pos - i as f64;
                    if w == 0.0 { h[i] } else { (1.0 - w) * h[i] + w * h[i + 1] }
                }
            };
            s.read(x)
        })
    }
}

/// One sample of a first-order low-pass `dy/dt = a (x - y)` whose input moves linearly from `x0`
/// to `x1` over the sample (exact for that input); `ah` = a * dt.
#[inline]
pub fn lowpass_step(y0: f64, x0: f64, x1: f64, ah: f64) -> f64 {
    let e = (-ah).exp();
    e * y0 + x1 - e * x0 - (x1 - x0) * (1.0 - e) / ah
}

/// Apply noise sample `k` and quantization to noise-free readings.
#[inline]
pub fn corrupt(r: &mut [f64; NC], c: &Corruption<'_>, k: usize) {
    for ((ri, noise), &q) in r.iter_mut().zip(&c.noise).zip(&c.quantum) {
        if let Some(n) = noise {
            *ri += n[k];
        }
        if q > 0.0 {
            *ri = (*ri / q).round() * q;
        }
    }
}

/// A recorded column with dropped samples (NaN) replaced by the previous value (the first
/// finite one at the start).
pub fn held(x: &[f64]) -> Vec<f64> {
    let mut last = x.iter().copied().find(|v| v.is_finite()).unwrap_or(0.0);
    x.iter()
        .map(|&v| {
            if v.is_finite() {
                last = v;
            }
            last
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn readings_apply_offset_gain_and_an_interpolated_delay() {
        let mut p = Params::base();
        p.sensor_offset_y = 0.01;
        p.sensor_gain_y = 2.0;
        p.sensor_delay_p_a_s = 2.5e-3; // 2.5 samples at 1 kHz
        let mut probe = Probe::new(Sensors::from_params(&p), 1e-3, 10);
        for k in 0..6 {
            probe.push(&Outputs { y: k as f64, p_a: 10.0 * k as f64, ..Default::default() });
        }
        let r = probe.read_latest();
        assert_eq!(r[0], 0.01 + 2.0 * 5.0);
        assert!((r[2] - 25.0).abs() < 1e-12, "{}", r[2]);
        assert_eq!(r[3], 0.0);
        let s = Sensors::from_params(&p).0[0];
        assert!((s.unread(s.read(0.123)) - 0.123).abs() < 1e-15);
    }

    #[test]
    fn a_declared_lowpass_lags_a_ramp_by_its_time_constant_and_settles_on_a_step() {
        let mut p = Params::base();
        p.sensor_lowpass_p_a_hz = 50.0;
        let dt = 1e-3;
        let mut probe = Probe::new(Sensors::from_params(&p), dt, 400);
        for k in 0..400 {
            probe.push(&Outputs { p_a: 1e6 * k as f64 * dt, y: 1.0, ..Default::default() });
        }
        // a ramp through a first-order filter lags by its time constant 1/(2 pi fc)
        let tau = 1.0 / (2.0 * std::f64::consts::PI * 50.0);
        let r = probe.read_latest();
        assert!((r[2] - 1e6 * (399.0 * dt - tau)).abs() < 1.0, "{}", r[2]);
        assert_eq!(r[0], 1.0);
        // a step settles to the input
        for _ in 0..400 {
            probe.push(&Outputs { p_a: 5.0, ..Default::default() });
        }
        assert!((probe.read_latest()[2] - 5.0).abs() < 1e-6);
        probe.restart();
        probe.push(&Outputs { p_a: 9.0, ..Default::default() });
        assert_eq!(probe.read_latest()[2], 9.0, "a restart starts the filter settled");
    }

    #[test]
    fn quantization_rounds_to_the_step() {
        let noise = [0.5e-6; 3];
        let c = Corruption { noise: [Some(&noise), None, None, None, None, None], quantum: [1e-6, 0.0, 0.0, 0.0, 0.0, 0.0] };
        let mut r = [0.1234567, 1.0, 0.0, 0.0, 0.0, 0.0];
        corrupt(&mut r, &c, 1);
        assert!((r[0] - 0.123457).abs() < 1e-12);
        assert_eq!(r[1], 1.0);
    }
}
