//! Convergence of the force into its band, logged with every test: an episode after a start, a
//! resume, a stiffness step or a new level, and how many cycles it took to enter each band.

/// The force bands convergence is logged for [fraction of ΔF].
pub const BANDS: [f64; 2] = [0.02, 0.005];
/// Full-amplitude cycles of an episode whose worst |ΔF error| is logged.
pub const FIRST_CYCLES: u64 = 20;

/// Why an episode of convergence began.
#[derive(serde::Serialize, serde::Deserialize, Debug, Clone, Copy, PartialEq, Eq)]
pub enum Cause {
    Start,
    Resume,
    StiffnessStep,
    /// a new block of a variable-amplitude sequence (its first pass)
    Level,
}

impl Cause {
    pub fn name(self) -> &'static str {
        match self {
            Cause::Start => "start",
            Cause::Resume => "resume",
            Cause::StiffnessStep => "stiffness_step",
            Cause::Level => "level",
        }
    }
}

/// Convergence after a start, a resume or a stiffness step, over the full-amplitude cycles that
/// follow: cycles until |ΔF error| enters each band of `BANDS` and stays there (0 = inside from
/// the first; `None` while the last cycle seen is still outside), and the worst |ΔF error| of the
/// first `FIRST_CYCLES`.
#[derive(serde::Serialize, serde::Deserialize, Debug, Clone, PartialEq)]
pub struct Episode {
    pub cause: Cause,
    /// test cycle (1-based) of the episode's first full-amplitude cycle; 0 until there is one
    pub first_cycle: u64,
    pub cycles_seen: u64,
    /// per band: full-amplitude cycles up to and including the last one outside it
    pub last_outside: [u64; 2],
    pub worst_first_df_pct: f64,
    /// over (a variable-amplitude level changed): no more cycles are its
    pub closed: bool,
}

impl Episode {
    pub(crate) fn new(cause: Cause) -> Self {
        Episode { cause, first_cycle: 0, cycles_seen: 0, last_outside: [0, 0], worst_first_df_pct: 0.0, closed: false }
    }

    pub(crate) fn observe(&mut self, cycle: u64, df_err: f64) {
        if self.closed {
            return;
        }
        if self.cycles_seen == 0 {
            self.first_cycle = cycle;
        }
        self.cycles_seen += 1;
        for (b, band) in BANDS.iter().enumerate() {
            if !(df_err.abs() <= *band) {
                self.last_outside[b] = self.cycles_seen;
            }
        }
        if self.cycles_seen <= FIRST_CYCLES {
            self.worst_first_df_pct = self.worst_first_df_pct.max(df_err.abs() * 100.0);
        }
    }

    /// Cycles to band `b` of `BANDS`, or None while not (yet) inside it.
    pub fn cycles_to(&self, b: usize) -> Option<u64> {
        (self.cycles_seen > self.last_outside[b]).then_some(self.last_outside[b])
    }
}
