//! Limit detectors of the control loop: each watches one measured value against a band, trips
//! after `persist` consecutive out-of-band periods (a non-finite value is always out of band),
//! latches, and names the action the loop must take. The loop owns the actions; this owns the
//! bookkeeping, so the same rules serve the real rig and the virtual one.
use crate::error::{Error, Result};

/// What a tripped detector asks for, in rising severity (the loop applies the worst).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Action {
    /// log and show only
    Indicate = 0,
    /// freeze at the mean (amplitude to zero, mean held)
    Hold = 1,
    /// ramp to the mean, then valve null
    Stop = 2,
    /// valve null and amplifier disabled at once
    PowerOff = 3,
}

impl Action {
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "indicate" => Ok(Action::Indicate),
            "hold" => Ok(Action::Hold),
            "stop" => Ok(Action::Stop),
            "power_off" => Ok(Action::PowerOff),
            other => Err(Error::Input(format!("limit action `{other}`: use indicate, hold, stop or power_off"))),
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            Action::Indicate => "indicate",
            Action::Hold => "hold",
            Action::Stop => "stop",
            Action::PowerOff => "power_off",
        }
    }
}

/// One detector: trips while `value` is outside [lo, hi] for `persist` consecutive checks.
#[derive(Debug, Clone, PartialEq)]
pub struct Detector {
    pub name: String,
    /// index of the watched value in the vector passed to `Detectors::check`
    pub channel: usize,
    pub lo: f64,
    pub hi: f64,
    pub action: Action,
    pub persist: u32,
    pub enabled: bool,
    /// out of band now (last check)
    pub active: bool,
    /// tripped and not yet reset
    pub latched: bool,
    /// value that tripped it
    pub trip_value: f64,
    count: u32,
}

impl Detector {
    pub fn new(name: &str, channel: usize, lo: f64, hi: f64, action: Action, persist: u32) -> Result<Self> {
        if lo.is_nan() || hi.is_nan() || lo > hi {
            return Err(Error::Parameter { field: format!("limits.{name}"), value: lo, allowed: format!("lo ≤ hi (got [{lo}, {hi}])") });
        }
        Ok(Detector { name: name.into(), channel, lo, hi, action, persist: persist.max(1), enabled: true, active: false, latched: false, trip_value: f64::NAN, count: 0 })
    }
}

/// A set of detectors checked together once per control period.
#[derive(Debug, Clone, Default)]
pub struct Detectors {
    pub list: Vec<Detector>,
}

impl Detectors {
    /// Check every enabled detector against `values`; returns the indices that tripped now.
    pub fn check(&mut self, values: &[f64]) -> Vec<usize> {
        let mut tripped = Vec::new();
        for (i, d) in self.list.iter_mut().enumerate() {
            let v = values.get(d.channel).copied().unwrap_or(f64::NAN);
            let out = d.enabled && !(v >= d.lo && v <= d.hi);
            d.active = out;
            d.count = if out { d.count + 1 } else { 0 };
            if out && !d.latched && d.count >= d.persist {
                d.latched = true;
                d.trip_value = v;
                tripped.push(i);
            }
        }
        tripped
    }

    /// Worst action among latched detectors, if any.
    pub fn worst(&self) -> Option<Action> {
        self.list.iter().filter(|d| d.latched).map(|d| d.action).max()
    }

    /// Clear latches whose condition has gone; returns the names still out of band (kept latched).
    pub fn reset(&mut self) -> Vec<String> {
        let mut still = Vec::new();
        for d in &mut self.list {
            if d.latched && d.active {
                still.push(d.name.clone());
            } else {
                d.latched = false;
                d.count = 0;
            }
        }
        still
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trips_after_persist_latches_and_resets_only_when_clear() {
        let mut d = Detectors { list: vec![Detector::new("force", 0, -1.0, 1.0, Action::Stop, 2).unwrap()] };
        assert!(d.check(&[2.0]).is_empty());
        assert_eq!(d.check(&[2.0]), vec![0]);
        assert_eq!(d.worst(), Some(Action::Stop));
        assert!(d.check(&[0.0]).is_empty());
        assert!(d.list[0].latched, "latched until reset");
        d.check(&[5.0]);
        assert_eq!(d.reset(), vec!["force".to_string()], "cannot reset while out of band");
        d.check(&[0.0]);
        assert!(d.reset().is_empty());
        assert_eq!(d.worst(), None);
    }

    #[test]
    fn nan_is_out_of_band() {
        let mut d = Detectors { list: vec![Detector::new("position", 0, 0.0, 0.2, Action::PowerOff, 1).unwrap()] };
        assert_eq!(d.check(&[f64::NAN]), vec![0]);
        assert!(Detector::new("x", 0, 1.0, 0.0, Action::Stop, 1).is_err());
    }
}
