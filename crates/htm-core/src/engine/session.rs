//! A test run in bounded chunks, with its complete state saved as bytes between any two chunks
//! and restored later (resume after a crash): the same cycle loop as `run_test`, which is one
//! unbounded chunk, so a resumed test gives the same per-cycle rows as an uninterrupted one.
//!
//! Snapshot bytes: `MAGIC`, format version (u32 LE), a fingerprint of the test config (u64 LE),
//! the exec mode (u8), then the state in postcard (serde; f64 as their exact 8 bytes). Serde
//! derive rather than a hand-written layout: a field added to the plant or the controller is
//! saved without anyone remembering to, and one that cannot be saved fails to compile.
use std::time::{Duration, Instant};

use super::sim::Sim;
use super::{EndReason, ExecMode, Outcome, RawCapture, Records, TestConfig};
use crate::error::{Error, Result};

const MAGIC: &[u8; 8] = b"HTMSNAP\0";
const VERSION: u32 = 3; // 3: the cycle machine (one state for the simulator and the real-time loop)

/// What one `Session::advance` produced: the new per-cycle rows, the raw samples kept (see
/// `RAW_COLUMNS`), and the end reason once the test is over (its smooth-stop rows included).
#[derive(Debug, Default)]
pub struct Chunk {
    pub records: Records,
    pub raw: Vec<[f64; 8]>,
    pub end: Option<EndReason>,
}

/// A resumable test.
pub struct Session {
    cfg: TestConfig,
    mode: ExecMode,
    /// the simulator itself (its state is the snapshot); `None` once the test is over or after
    /// an error inside a chunk
    state: Option<Sim>,
    outcome: Option<Outcome>,
}

/// FNV-1a over the config's exact text (f64 Debug output round-trips), so a snapshot is never
/// restored into another test.
fn fingerprint(cfg: &TestConfig) -> u64 {
    let text = format!("{cfg:?}");
    text.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ b as u64).wrapping_mul(0x100_0000_01b3))
}

fn mode_byte(mode: ExecMode) -> u8 {
    match mode {
        ExecMode::Full => 0,
        ExecMode::Jump => 1,
    }
}

impl Session {
    /// Validate `cfg` and bring the test to rest, ready for cycle 1.
    pub fn new(cfg: TestConfig, mode: ExecMode, raw: RawCapture) -> Result<Self> {
        let state = Sim::start(&cfg, mode, raw)?;
        Ok(Session { cfg, mode, state: Some(state), outcome: None })
    }

    pub fn config(&self) -> &TestConfig {
        &self.cfg
    }

    /// Cycles applied so far.
    pub fn cycle(&self) -> u64 {
        match (&self.state, &self.outcome) {
            (Some(s), _) => s.cm.cycle,
            (None, Some(o)) => o.cycles,
            _ => 0,
        }
    }

    /// Crack length now [m].
    pub fn a_m(&self) -> f64 {
        match (&self.state, &self.outcome) {
            (Some(s), _) => s.cm.a,
            (None, Some(o)) => o.a_end_m,
            _ => f64::NAN,
        }
    }

    /// The summary (records empty) once the test is over.
    pub fn outcome(&self) -> Option<&Outcome> {
        self.outcome.as_ref()
    }

    /// Run at most `max_cycles` more cycles (a cycle jump may overshoot) and for at most
    /// `max_wall` of wall time, then pause between two cycles.
    pub fn advance(&mut self, max_cycles: u64, max_wall: Duration) -> Result<Chunk> {
        if let Some(o) = &self.outcome {
            return Ok(Chunk { end: Some(o.end_reason), ..Default::default() });
        }
        let mut sim = self.state.take().ok_or_else(|| Error::Input("the test stopped on an earlier error; restore it from a snapshot".into()))?;
        let until = sim.cm.cycle.saturating_add(max_cycles);
        let deadline = Instant::now().checked_add(max_wall);
        let end = sim.advance(&self.cfg, self.mode, until, deadline, None, None)?;
        let raw = sim.raw.take();
        match end {
            None => {
                let records = std::mem::take(&mut sim.rec);
                self.state = Some(sim);
                Ok(Chunk { records, raw, end: None })
            }
            Some(end) => {
                let mut o = sim.outcome();
                let records = std::mem::take(&mut o.records);
                self.outcome = Some(o);
                Ok(Chunk { records, raw, end: Some(end) })
            }
        }
    }

    /// The complete state between two chunks as bytes (see the module docs).
    pub fn snapshot(&self) -> Result<Vec<u8>> {
        let st = self.state.as_ref().ok_or_else(|| Error::Input("a finished or failed test has no state to save".into()))?;
        let mut out = Vec::with_capacity(16 * 1024);
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&VERSION.to_le_bytes());
        out.extend_from_slice(&fingerprint(&self.cfg).to_le_bytes());
        out.push(mode_byte(self.mode));
        postcard::to_io(st, &mut out).map_err(|e| Error::Input(format!("snapshot: {e}")))?;
        Ok(out)
    }

    /// A session continuing from `snapshot` of the same `cfg` and `mode`.
    pub fn restore(cfg: TestConfig, mode: ExecMode, snapshot: &[u8]) -> Result<Self> {
        cfg.validate()?;
        let bad = |why: &str| Error::Input(format!("engine snapshot unusable: {why}"));
        if snapshot.len() < 21 || &snapshot[..8] != MAGIC {
            return Err(bad("not an htm engine snapshot"));
        }
        let version = u32::from_le_bytes(snapshot[8..12].try_into().unwrap());
        if version != VERSION {
            return Err(bad(&format!("format version {version}, this htm reads {VERSION}")));
        }
        if u64::from_le_bytes(snapshot[12..20].try_into().unwrap()) != fingerprint(&cfg) {
            return Err(bad("it was taken from a different test config (or htm version)"));
        }
        if snapshot[20] != mode_byte(mode) {
            return Err(bad("it was taken in the other exec mode (full/jump)"));
        }
        let state: Sim = postcard::from_bytes(&snapshot[21..]).map_err(|e| bad(&format!("state does not decode ({e})")))?;
        Ok(Session { cfg, mode, state: Some(state), outcome: None })
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::table_b1;
    use super::super::{run_test, Records};
    use super::*;

    fn append(all: &mut Records, r: Records) {
        all.cycle.extend(r.cycle);
        all.fmax_n.extend(r.fmax_n);
        all.fmin_n.extend(r.fmin_n);
        all.a_m.extend(r.a_m);
        all.ctrl_u1_v.extend(r.ctrl_u1_v);
        all.events.extend(r.events);
    }

    /// Chunked with a save/restore round trip after every chunk = one uninterrupted run, bit for bit.
    fn chunked_matches_run_test(mode: ExecMode, chunk: u64) {
        let cfg = table_b1(10.0, 1000.0, 0.32, 30.0);
        let whole = run_test(&cfg, mode, None, None).unwrap();
        let mut s = Session::new(cfg.clone(), mode, RawCapture::new(30, 2, 2, 2)).unwrap();
        let mut all = Records::default();
        let mut raw_rows = 0;
        loop {
            let c = s.advance(chunk, Duration::from_secs(3600)).unwrap();
            append(&mut all, c.records);
            raw_rows += c.raw.len();
            if c.end.is_some() {
                break;
            }
            let bytes = s.snapshot().unwrap();
            s = Session::restore(cfg.clone(), mode, &bytes).unwrap();
        }
        let w = &whole.records;
        assert_eq!(all.cycle, w.cycle);
        assert_eq!(all.events, w.events);
        assert_eq!(all.a_m.iter().map(|x| x.to_bits()).collect::<Vec<_>>(), w.a_m.iter().map(|x| x.to_bits()).collect::<Vec<_>>());
        assert_eq!(all.fmax_n.iter().map(|x| x.to_bits()).collect::<Vec<_>>(), w.fmax_n.iter().map(|x| x.to_bits()).collect::<Vec<_>>());
        assert_eq!(all.ctrl_u1_v.iter().map(|x| x.to_bits()).collect::<Vec<_>>(), w.ctrl_u1_v.iter().map(|x| x.to_bits()).collect::<Vec<_>>());
        let o = s.outcome().unwrap();
        assert_eq!((o.end_reason, o.cycles, o.a_end_m.to_bits()), (whole.end_reason, whole.cycles, whole.a_end_m.to_bits()));
        assert!(raw_rows >= 30 * 100, "the first 30 cycles are kept whole: {raw_rows} samples");
    }

    #[test]
    fn full_mode_resumes_bit_for_bit() {
        chunked_matches_run_test(ExecMode::Full, 737);
    }

    #[test]
    fn jump_mode_resumes_bit_for_bit() {
        chunked_matches_run_test(ExecMode::Jump, 7);
    }

    #[test]
    fn snapshot_refuses_another_config_or_garbage() {
        let cfg = table_b1(10.0, 1000.0, 0.32, 30.0);
        let mut s = Session::new(cfg.clone(), ExecMode::Full, RawCapture::default()).unwrap();
        s.advance(50, Duration::from_secs(60)).unwrap();
        let bytes = s.snapshot().unwrap();
        let mut other = cfg.clone();
        other.frequency_hz = 9.0;
        assert!(Session::restore(other, ExecMode::Full, &bytes).err().unwrap().to_string().contains("different test config"));
        assert!(Session::restore(cfg.clone(), ExecMode::Jump, &bytes).err().unwrap().to_string().contains("exec mode"));
        assert!(Session::restore(cfg.clone(), ExecMode::Full, &bytes[..40]).err().unwrap().to_string().contains("does not decode"));
        assert!(Session::restore(cfg, ExecMode::Full, b"garbage garbage garbage").err().unwrap().to_string().contains("not an htm"));
    }
}
