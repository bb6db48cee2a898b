//! The measurement model: what each sensor reads of the true plant outputs — per channel an
//! offset, a gain and a transport delay (EFFECTS `sensor_offset`, `sensor_gain`, `sensor_delay`),
//! plus optional additive noise and quantization (a record generator's option, not a parameter).
//! In a closed loop the controller sees these readings, not the true signals.
use crate::machine::Outputs;
use crate::params::Params;

/// Measured channels, in this order everywhere (DATA_FORMAT column names).
pub const CHANNELS: [&str; 6] = ["y", "v", "p_a", "p_b", "p_s", "f"];
pub const NC: usize = 6;

/// One sensor: reads `offset + gain * true(t - delay_s)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sensor {
    pub offset: f64,
    pub gain: f64,
    pub delay_s: f64,
}

impl Sensor {
    pub const IDEAL: Sensor = Sensor { offset: 0.0, gain: 1.0, delay_s: 0.0 };

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
        let s = |offset, gain, delay_s| Sensor { offset, gain, delay_s };
        Sensors([
            s(p.sensor_offset_y, p.sensor_gain_y, p.sensor_delay_y_s),
            s(p.sensor_offset_v, p.sensor_gain_v, p.sensor_delay_v_s),
            s(p.sensor_offset_p_a, p.sensor_gain_p_a, p.sensor_delay_p_a_s),
            s(p.sensor_offset_p_b, p.sensor_gain_p_b, p.sensor_delay_p_b_s),
            s(p.sensor_offset_p_s, p.sensor_gain_p_s, p.sensor_delay_p_s_s),
            s(p.sensor_offset_f, p.sensor_gain_f, p.sensor_delay_f_s),
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

/// The history of true outputs at the sample instants, read back through the sensors.
#[derive(Debug, Clone)]
pub struct Probe {
    sensors: Sensors,
    dt: f64,
    history: [Vec<f64>; NC],
}

impl Probe {
    pub fn new(sensors: Sensors, dt: f64, capacity: usize) -> Self {
        Probe { sensors, dt, history: std::array::from_fn(|_| Vec::with_capacity(capacity)) }
    }

    /// Append the true outputs of the newest sample.
    pub fn push(&mut self, o: &Outputs) {
        for (h, x) in self.history.iter_mut().zip(channels(o)) {
            h.push(x);
        }
    }

    pub fn len(&self) -> usize {
        self.history[0].len()
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

/// Apply noise sample `k` and quantization to noise-free readings.
#[inline]
pub fn corrupt(r: &mut [f64; NC], c: &Corruption<'_>, k: usize) {
    for i in 0..NC {
        if let Some(n) = c.noise[i] {
            r[i] += n[k];
        }
        if c.quantum[i] > 0.0 {
            r[i] = (r[i] / c.quantum[i]).round() * c.quantum[i];
        }
    }
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
    fn quantization_rounds_to_the_step() {
        let noise = [0.5e-6; 3];
        let c = Corruption { noise: [Some(&noise), None, None, None, None, None], quantum: [1e-6, 0.0, 0.0, 0.0, 0.0, 0.0] };
        let mut r = [0.1234567, 1.0, 0.0, 0.0, 0.0, 0.0];
        corrupt(&mut r, &c, 1);
        assert!((r[0] - 0.123457).abs() < 1e-12);
        assert_eq!(r[1], 1.0);
    }
}
