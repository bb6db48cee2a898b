//! Re-simulation of a measured record (DATA_FORMAT.md): the whole closed loop from the reference,
//! the declared controller fed by the simulated *measurements*; or, without a controller, the
//! recorded command played open loop, its position put back on the measurement every horizon.
//! Batches over parameter sets run on all cores (what a model fit by simulation error needs).

use crate::control::Controller;
use crate::error::{Error, Result};
use crate::machine::{Machine, Outputs, PA, PB, V, Y};
use crate::measure::{as_outputs, corrupt, held, Corruption, Probe, Sensors, NC};
use crate::params::Params;
use crate::solver::Stats;
use std::sync::{Condvar, Mutex};

/// What to re-simulate: the record's signals and how to drive the model with them.
#[derive(Debug, Clone)]
pub struct Replay<'a> {
    /// sample period [s]
    pub dt: f64,
    /// recorded valve command [V] (open loop input; NaN = dropped sample, previous value held)
    pub u: &'a [f64],
    /// the declared controller and its reference (m for position, N for force) when closed loop
    pub closed_loop: Option<(Controller, &'a [f64])>,
    /// measured channels in `measure::CHANNELS` order (start state, open-loop restarts)
    pub measured: [Option<&'a [f64]>; NC],
    /// open loop: put the position back on the measurement every this many seconds
    pub horizon_s: f64,
    /// closed loop: hold the first reference this long before the record starts, so the model
    /// begins at its own equilibrium (a real record starts from a settled rig)
    pub preroll_s: f64,
    /// relative tolerance of the plant integrator
    pub rtol: f64,
    /// noise and quantization of the readings (record generation only; default none)
    pub corruption: Corruption<'a>,
    /// supply pressure read at rest, per sample, as a factor of `supply_pressure_pa` (a power
    /// unit switched between pressure levels; with sag the set-point is higher by the standing
    /// leakage's drop); None = the constant set-point `supply_pressure_pa`
    pub supply: Option<&'a [f64]>,
    /// open loop: simulate only these samples (None = all); the others read NaN and cost no
    /// integration — the plant is re-started from the measurement where a simulated run begins,
    /// and the valve (its play and spool, which the hydraulics do not act on) follows the
    /// recorded command throughout, so a simulated sample reads the same as in a whole run
    pub active: Option<&'a [bool]>,
    /// the integrator solves its stages as one dense system (`Rodas4::dense_stages`: the
    /// coupled form, a benchmark's peer) instead of the spool's block apart
    pub dense_stages: bool,
}

/// A re-simulated record: per channel what the sensors read, and the command applied.
#[derive(Debug, Clone, Default)]
pub struct Replayed {
    pub readings: [Vec<f64>; NC],
    pub u: Vec<f64>,
    pub stats: Stats,
}

/// Default open-loop restart horizon [s].
pub const DEFAULT_HORIZON_S: f64 = 0.5;
/// Open loop on some samples only: each run of active samples is simulated from this long
/// before it [s], so that velocity and pressures there are the model's own (as in a whole run).
pub const WARMUP_S: f64 = 0.1;
/// Default closed-loop pre-roll [s].
pub const DEFAULT_PREROLL_S: f64 = 1.0;
/// Default integrator tolerance for re-simulation: the fit needs readings accurate far below the
/// sensor noise (1e-4 keeps pressures within ~1 kPa and positions within ~1 um of rtol 1e-6).
pub const DEFAULT_RTOL: f64 = 1e-4;

impl<'a> Replay<'a> {
    pub fn new(dt: f64, u: &'a [f64]) -> Self {
        Replay {
            dt,
            u,
            closed_loop: None,
            measured: [None; NC],
            horizon_s: DEFAULT_HORIZON_S,
            preroll_s: DEFAULT_PREROLL_S,
            rtol: DEFAULT_RTOL,
            corruption: Corruption::default(),
            supply: None,
            active: None,
            dense_stages: false,
        }
    }

    fn n(&self) -> usize {
        self.u.len()
    }

    /// Check lengths and settings; the message names the bad argument.
    pub fn validate(&self) -> Result<()> {
        let n = self.n();
        if n == 0 {
            return Err(Error::Input("the record has no samples".into()));
        }
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return Err(Error::Input(format!("sample period dt = {} s must be > 0", self.dt)));
        }
        if let Some(a) = self.active {
            if a.len() != n {
                return Err(Error::Input(format!("active mask has {} samples but `u` has {n}", a.len())));
            }
        }
        if let Some(s) = self.supply {
            if s.len() != n {
                return Err(Error::Input(format!("supply schedule has {} samples but `u` has {n}", s.len())));
            }
            if let Some(x) = s.iter().find(|x| !(x.is_finite() && **x > 0.0 && **x <= 10.0)) {
                return Err(Error::Parameter { field: "supply schedule".into(), value: *x, allowed: "(0, 10] x supply_pressure_pa".into() });
            }
        }
        let names = crate::measure::CHANNELS;
        for (i, m) in self.measured.iter().enumerate() {
            if let Some(m) = m {
                if m.len() != n {
                    return Err(Error::Input(format!("column `{}` has {} samples but `u` has {n}", names[i], m.len())));
                }
            }
            if let Some(z) = self.corruption.noise[i] {
                if z.len() < n {
                    return Err(Error::Input(format!("noise of `{}` has {} samples, need {n}", names[i], z.len())));
                }
            }
        }
        match &self.closed_loop {
            Some((ctrl, r)) => {
                ctrl.validate()?;
                if r.len() != n {
                    return Err(Error::Input(format!("reference has {} samples but `u` has {n}", r.len())));
                }
                if !r.iter().any(|x| x.is_finite()) {
                    return Err(Error::Input("the reference holds no finite value".into()));
                }
                if !(self.preroll_s.is_finite() && (0.0..=60.0).contains(&self.preroll_s)) {
                    return Err(Error::Parameter { field: "preroll_s".into(), value: self.preroll_s, allowed: "[0, 60] s".into() });
                }
            }
            None => {
                if !(self.horizon_s.is_finite() && self.horizon_s > 0.0) {
                    return Err(Error::Parameter { field: "horizon_s".into(), value: self.horizon_s, allowed: "(0, inf) s".into() });
                }
                if !self.u.iter().any(|x| x.is_finite()) {
                    return Err(Error::Input("the command `u` holds no finite value".into()));
                }
            }
        }
        Ok(())
    }

    /// A run's start: the machine at rest where the record starts, its sensors and readings.
    fn start(&self, p: &Params) -> Result<Run> {
        let sensors = Sensors::from_params(p);
        let mut m = Machine::new(p.clone())?.with_rtol(self.rtol)?;
        m.solver.dense_stages = self.dense_stages;
        // The supply set-point per sample: the schedule is the supply read at rest (above tank,
        // so that the valve keeps a drop), as a factor of `supply_pressure_pa`.
        let setpoints: Option<Vec<f64>> = self.supply.map(|s| {
            s.iter().map(|f| m.plant.setpoint_for_rest((p.supply_pressure_pa * f).max(p.tank_pressure_pa + 1e5))).collect()
        });
        let ripple = if p.supply_ripple_hz > 0.0 && (p.supply_ripple_sin_pa != 0.0 || p.supply_ripple_cos_pa != 0.0) {
            Some((p.supply_ripple_hz, p.supply_ripple_sin_pa, p.supply_ripple_cos_pa))
        } else {
            None
        };
        let mut run = Run { supply_pa: p.supply_pressure_pa, setpoints, ripple, m, sensors, probe: Probe::new(sensors, self.dt, 0), out: Replayed::default(), followed: Vec::new() };
        run.m.plant.p.supply_pressure_pa = run.supply_at(0, self.dt);
        let y0 = self.start_position(&run.m, &sensors);
        run.m.x = run.m.plant.rest_state(y0);
        let n = self.n();
        let pre = match self.closed_loop {
            Some(_) => (self.preroll_s / self.dt).round() as usize,
            None => 0,
        };
        run.probe = Probe::new(sensors, self.dt, pre + n);
        run.out = Replayed { readings: std::array::from_fn(|_| Vec::with_capacity(n)), u: Vec::with_capacity(n), stats: Stats::default() };
        Ok(run)
    }

    /// Re-simulate the record with parameters `p`.
    pub fn run(&self, p: &Params) -> Result<Replayed> {
        self.validate()?;
        let n = self.n();
        let mut run = self.start(p)?;
        match &self.closed_loop {
            Some((ctrl, reference)) => {
                let pre = (self.preroll_s / self.dt).round() as usize;
                let r = held(reference);
                for _ in 0..pre {
                    run.probe.push(&run.m.outputs());
                    let uk = ctrl.command(r[0], r[0], self.dt, &as_outputs(&run.probe.read_latest()));
                    run.m.step(uk, self.dt)?;
                }
                for k in 0..n {
                    run.m.plant.p.supply_pressure_pa = run.supply_at(k, self.dt); // read at k and held to k + 1
                    run.probe.push(&run.m.outputs());
                    let mut rd = run.probe.read_latest();
                    corrupt(&mut rd, &self.corruption, k);
                    let uk = ctrl.command(r[k], r[(k + 1).min(n - 1)], self.dt, &as_outputs(&rd));
                    push(&mut run.out, &rd, uk);
                    run.m.step(uk, self.dt)?;
                }
            }
            None => {
                let plan = self.open_plan();
                run.followed = self.followed(&plan.simulated, &run.sensors);
                self.open_steps(&mut run, &plan, 0..n)?;
            }
        }
        run.out.stats = run.m.stats();
        Ok(run.out)
    }

    /// Open loop: what every parameter set's run shares (the held command, the samples
    /// simulated, the restart period).
    fn open_plan(&self) -> OpenPlan {
        OpenPlan { u: held(self.u), simulated: self.simulated(), every: self.every() }
    }

    /// Open loop: samples `ks` of a run, in order (a whole run is one call over every sample,
    /// or consecutive calls over consecutive ranges: the same operations either way).
    fn open_steps(&self, run: &mut Run, plan: &OpenPlan, ks: std::ops::Range<usize>) -> Result<()> {
        for k in ks {
            let uk = plan.u[k];
            if self.open_sample(run, k, uk, &plan.simulated, plan.every) {
                run.m.step(uk, self.dt)?;
            } else {
                run.m.step_valve(uk, self.dt);
            }
        }
        Ok(())
    }

    /// Open loop, every set of `ps` on `threads` threads (>= 2), each run carried forward a
    /// slice of the record at a time (`BATCH_SLICES` per record) by whichever thread is free:
    /// one run per thread while more sets wait to begin than there are threads, then the set with
    /// the most of the record left first: the last sets finish together, and a batch of
    /// a few sets (three on two threads: a fit's point and two neighbours) takes the time of
    /// its work spread over the threads, not that of whole runs handed out one at a time (two
    /// runs' time for three). A run is one thread's at a time and takes its samples in order,
    /// so each set's readings are those of [`run`](Self::run), bit for bit.
    fn open_batch(&self, ps: &[Params], threads: usize) -> Vec<Result<Replayed>> {
        let (n, plan) = (self.n(), self.open_plan());
        let slice = n.div_ceil(BATCH_SLICES).max(1);
        // per set: the samples done (n: finished or failed) and whether a thread holds its run
        let sched = Mutex::new((vec![0usize; ps.len()], vec![false; ps.len()]));
        let freed = Condvar::new();
        let runs: Vec<Mutex<Option<Result<Run>>>> = ps.iter().map(|_| Mutex::new(None)).collect();
        let work = || {
            // the set this thread ran last (its state is in this core's cache)
            let mut mine: Option<usize> = None;
            loop {
                let (i, k0) = {
                    let mut sc = sched.lock().expect("no thread panics holding the schedule");
                    loop {
                        let (done, busy) = &*sc;
                        let free = |i: &usize| !busy[*i] && done[*i] < n;
                        // while as many sets wait to begin as there are threads, a thread carries on
                        // with a run begun (its own): one run per thread, as in a plain batch; then
                        // the most left first, so that the last runs end together
                        let waiting = (0..ps.len()).filter(|&i| done[i] == 0 && !busy[i]).count();
                        let carry_on = if waiting >= threads { mine.filter(free).or_else(|| (0..ps.len()).filter(free).find(|&i| done[i] > 0)) } else { None };
                        if let Some(i) = carry_on.or_else(|| (0..ps.len()).filter(free).min_by_key(|&i| (done[i], i))) {
                            sc.1[i] = true;
                            break (i, sc.0[i]);
                        }
                        if done.iter().all(|&k| k >= n) {
                            return;
                        }
                        sc = freed.wait(sc).expect("no thread panics holding the schedule");
                    }
                };
                let k1 = (k0 + slice).min(n);
                let mut slot = runs[i].lock().expect("one thread holds a run at a time");
                let start = slot.take().unwrap_or_else(|| {
                    self.start(&ps[i]).map(|mut r| {
                        r.followed = self.followed(&plan.simulated, &r.sensors);
                        r
                    })
                });
                let (run, end) = match start {
                    Ok(mut r) => match self.open_steps(&mut r, &plan, k0..k1) {
                        Ok(()) => (Ok(r), k1),
                        Err(e) => (Err(e), n),
                    },
                    Err(e) => (Err(e), n),
                };
                *slot = Some(run);
                drop(slot);
                let mut sc = sched.lock().expect("no thread panics holding the schedule");
                (sc.0[i], sc.1[i]) = (end, false);
                drop(sc);
                freed.notify_all();
                mine = Some(i);
            }
        };
        std::thread::scope(|s| {
            for _ in 0..threads {
                s.spawn(work);
            }
        });
        runs.into_iter().map(|r| {
            r.into_inner().expect("the threads are done").expect("every set was run").map(|mut r| {
                r.out.stats = r.m.stats();
                r.out
            })
        }).collect()
    }

    /// Re-simulate with `ps[0]` and, in lockstep with it, every other set of `ps` (sets that
    /// differ slightly from the first: a fit's finite-difference neighbours): the others take
    /// the first one's step sizes (`Machine::step_lockstep`), so that their differences to the
    /// first — a Jacobian's columns — are free of step-size noise, and they spend no rejected
    /// steps. Open loop only (a closed loop runs each set alone), one thread; a first set that
    /// fails has every set run alone.
    pub fn run_lockstep(&self, ps: &[Params]) -> Vec<Result<Replayed>> {
        let alone = || ps.iter().map(|p| self.run(p)).collect();
        if ps.len() < 2 || self.closed_loop.is_some() {
            return alone();
        }
        if let Err(e) = self.validate() {
            return ps.iter().map(|_| Err(e.clone())).collect();
        }
        let mut runs: Vec<Result<Run>> = ps.iter().map(|p| self.start(p)).collect();
        if runs[0].is_err() {
            return alone();
        }
        let u = held(self.u);
        let simulated = self.simulated();
        for r in runs.iter_mut().flatten() {
            r.followed = self.followed(&simulated, &r.sensors);
        }
        let every = self.every();
        for (k, &uk) in u.iter().enumerate() {
            let mut step = false;
            for r in runs.iter_mut().flatten() {
                step = self.open_sample(r, k, uk, &simulated, every);
            }
            if !step {
                for r in runs.iter_mut().flatten() {
                    r.m.step_valve(uk, self.dt);
                }
                continue;
            }
            let (lead, rest) = runs.split_first_mut().expect("two sets or more");
            let lead = lead.as_mut().expect("the first set started");
            let mut followers: Vec<&mut Machine> = rest.iter_mut().flatten().map(|r| &mut r.m).collect();
            if lead.m.step_lockstep(&mut followers, uk, self.dt).is_err() {
                return alone();
            }
            for r in rest.iter_mut() {
                if r.as_ref().is_ok_and(|r| !r.m.x.iter().all(|v| v.is_finite())) {
                    *r = Err(Error::Solver(format!("non-finite state at sample {k} in a step taken in lockstep (t = {:.4} s)", k as f64 * self.dt)));
                }
            }
        }
        runs.into_iter().map(|r| r.map(|mut r| {
            r.out.stats = r.m.stats();
            r.out
        })).collect()
    }

    /// Open loop: every `every` samples the position is put back on the measurement.
    fn every(&self) -> usize {
        ((self.horizon_s / self.dt).round() as usize).max(1)
    }

    /// Open loop: the samples simulated, the active ones and a warm-up before each active run,
    /// so that the pressures there are the model's own (see `anchor`), not the measurement's.
    fn simulated(&self) -> Vec<bool> {
        let n = self.n();
        let warm = ((WARMUP_S / self.dt).round() as usize).max(1);
        match self.active {
            None => vec![true; n],
            Some(a) => {
                let mut sim = a.to_vec();
                let mut next_active = usize::MAX;
                for k in (0..n).rev() {
                    if a[k] {
                        next_active = k;
                    } else if next_active != usize::MAX && next_active - k <= warm {
                        sim[k] = true;
                    }
                }
                sim
            }
        }
    }

    /// Open loop on some samples only: the samples not simulated whose state must still follow
    /// the measurement (restarted from it, read by the sensors): those a delayed reading of a
    /// simulated sample can reach back to. The others push a placeholder that nothing reads:
    /// a simulated run starts its filters afresh (`Probe::restart`), and a sensor delayed by d
    /// reads back d. Empty (every sample followed) when all samples are simulated, or when a
    /// channel is both delayed and filtered (its filter would carry the placeholder into what a
    /// delayed reading sees).
    fn followed(&self, simulated: &[bool], s: &Sensors) -> Vec<bool> {
        if self.active.is_none() || s.0.iter().any(|c| c.delay_s > 0.0 && c.lowpass_hz > 0.0) {
            return Vec::new();
        }
        let reach = (s.0.iter().map(|c| c.delay_s.max(0.0)).fold(0.0, f64::max) / self.dt).ceil() as usize + 2;
        let mut out = vec![false; simulated.len()];
        let mut next_sim = usize::MAX;
        for k in (0..simulated.len()).rev() {
            if simulated[k] {
                next_sim = k;
            }
            out[k] = simulated[k] || (next_sim != usize::MAX && next_sim - k <= reach);
        }
        out
    }

    /// Open loop, sample `k` up to its step: the supply, re-starts and anchors, the readings.
    /// Returns whether the sample is integrated (else only the valve follows the command).
    fn open_sample(&self, run: &mut Run, k: usize, uk: f64, simulated: &[bool], every: usize) -> bool {
        run.m.plant.p.supply_pressure_pa = run.supply_at(k, self.dt);
        let Run { m, sensors, probe, out, followed, .. } = run;
        if !simulated[k] {
            // not simulated: the state follows the measurement, the valve the command — where
            // a delayed reading can reach back to it; elsewhere its history is never read
            if followed.get(k).is_none_or(|f| *f) {
                self.restart(m, sensors, k);
                probe.push(&m.outputs());
            } else {
                probe.push(&Outputs::default());
            }
            push(out, &[f64::NAN; NC], uk);
            return false;
        }
        if k == 0 || !simulated[k - 1] {
            self.restart(m, sensors, k);
            probe.restart();
        } else if k.is_multiple_of(every) {
            self.anchor(m, sensors, k);
        }
        probe.push(&m.outputs());
        let mut rd = probe.read_latest();
        corrupt(&mut rd, &self.corruption, k);
        if self.active.is_some_and(|a| !a[k]) {
            rd = [f64::NAN; NC]; // warm-up: simulated, not reported
        }
        push(out, &rd, uk);
        true
    }

    /// Re-simulate with every parameter set, spread over `threads` threads (0 = all cores).
    /// Open loop, the runs advance a slice of the record at a time on whichever thread is free
    /// (`open_batch`): the same readings as [`run`](Self::run) for each set.
    pub fn run_batch(&self, ps: &[Params], threads: usize) -> Vec<Result<Replayed>> {
        let threads = if threads == 0 { std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1) } else { threads };
        if self.closed_loop.is_some() || ps.len() < 2 || threads < 2 {
            return crate::batch::par_map(ps, threads, |p| self.run(p));
        }
        if let Err(e) = self.validate() {
            return ps.iter().map(|_| Err(e.clone())).collect();
        }
        self.open_batch(ps, threads.min(ps.len()))
    }

    /// [`run_lockstep`](Self::run_lockstep) spread over `threads` threads (0 = all cores): the
    /// sets after the first in as many contiguous groups, each run in lockstep with its own copy
    /// of the first (one more simulation of it per extra thread). Results in the order of `ps`.
    pub fn run_lockstep_batch(&self, ps: &[Params], threads: usize) -> Vec<Result<Replayed>> {
        let threads = if threads == 0 { std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1) } else { threads };
        let rest = ps.len().saturating_sub(1);
        let groups = threads.clamp(1, rest.max(1));
        if groups <= 1 {
            return self.run_lockstep(ps);
        }
        let bounds: Vec<(usize, usize)> = (0..groups).map(|g| (1 + g * rest / groups, 1 + (g + 1) * rest / groups)).collect();
        let sets: Vec<Vec<Params>> = bounds.iter().map(|&(a, b)| std::iter::once(ps[0].clone()).chain(ps[a..b].iter().cloned()).collect()).collect();
        let mut out = Vec::with_capacity(ps.len());
        for (g, res) in crate::batch::par_map(&sets, groups, |set| self.run_lockstep(set)).into_iter().enumerate() {
            let mut res = res.into_iter();
            let first = res.next().expect("each group runs its first set");
            if g == 0 {
                out.push(first);
            }
            out.extend(res);
        }
        out
    }

    /// True start position. Position control: where the sensor reads the first reference (the
    /// pre-roll then settles the loop as the rig was settled; starting from the measured position
    /// instead would add a second settling, which with a dead band or stiction ends elsewhere).
    /// Otherwise the first measured position through the inverse sensor, else mid-stroke or the
    /// specimen's zero-force position.
    fn start_position(&self, m: &Machine, s: &Sensors) -> f64 {
        let p = &m.plant.p;
        let first = |x: &[f64]| x.iter().take(20).copied().find(|v| v.is_finite());
        let y = match &self.closed_loop {
            Some((Controller::PositionPff { .. }, r)) => first(r),
            _ => self.measured[0].and_then(first),
        };
        let fallback = if p.specimen_stiffness_n_m > 0.0 { p.specimen_zero_force_position_m } else { 0.5 * p.stroke_m };
        y.map(|r| s.0[0].unread(r)).unwrap_or(fallback).clamp(0.0, p.stroke_m)
    }

    /// Open loop, every horizon: put the position back on the measurement at sample `k`. Only
    /// the position: an integrator, it drifts away from any model; velocity and pressures settle
    /// by themselves (the valve and the oil's stiffness hold them) and stay the model's own, so a
    /// sensor offset or gain on a pressure or velocity channel shows in that reading only, as it
    /// does in the closed loop, instead of entering the dynamics at every re-start.
    fn anchor(&self, m: &mut Machine, s: &Sensors, k: usize) {
        if let Some(y) = self.reading_of(s, 0, k) {
            m.x[Y] = s.0[0].unread(y).clamp(0.0, m.plant.p.stroke_m);
        }
    }

    /// Channel `c`'s reading of the state at sample `k`: a sensor delayed by d shows it d later
    /// (linear between samples; the last sample where the record ends). None where not finite.
    fn reading_of(&self, s: &Sensors, c: usize, k: usize) -> Option<f64> {
        let x = self.measured[c]?;
        let at = k as f64 + (s.0[c].delay_s / self.dt).max(0.0);
        let i = (at.floor() as usize).min(x.len() - 1);
        let j = (i + 1).min(x.len() - 1);
        let w = (at - i as f64).clamp(0.0, 1.0);
        let v = if w == 0.0 { x[i] } else { (1.0 - w) * x[i] + w * x[j] };
        v.is_finite().then_some(v)
    }

    /// Open loop, where a simulated run begins: set position, velocity and chamber pressures
    /// from the measurements at sample `k` (through the inverse sensors); what is not measured
    /// keeps its simulated value.
    fn restart(&self, m: &mut Machine, s: &Sensors, k: usize) {
        let at = |c: usize| self.reading_of(s, c, k);
        if let Some(y) = at(0) {
            m.x[Y] = s.0[0].unread(y).clamp(0.0, m.plant.p.stroke_m);
        }
        let v = at(1).map(|v| s.0[1].unread(v)).or_else(|| {
            // central difference of the measured position over +-2 samples (where it reads k)
            let y = self.measured[0]?;
            let ky = (k + (s.0[0].delay_s / self.dt).round().max(0.0) as usize).min(y.len() - 1);
            let (lo, hi) = (ky.saturating_sub(2), (ky + 2).min(y.len() - 1));
            let d = (y[hi] - y[lo]) / ((hi - lo).max(1) as f64 * self.dt);
            d.is_finite().then(|| d / s.0[0].gain)
        });
        if let Some(v) = v {
            m.x[V] = v;
        }
        let floor = -m.plant.p.atmospheric_pressure_pa + 1e3;
        for (c, i) in [(2, PA), (3, PB)] {
            if let Some(pr) = at(c) {
                m.x[i] = s.0[c].unread(pr).max(floor);
            }
        }
    }
}

/// Open loop: a record's slices per run in a batch (`Replay::open_batch`): fine enough that the
/// runs' ends meet within a slice, coarse enough that handing a run between threads (a lock and
/// its state's cache lines) costs nothing next to the slice's integration.
pub const BATCH_SLICES: usize = 32;

/// Open loop: what every parameter set's run shares.
struct OpenPlan {
    /// the recorded command, dropped samples held
    u: Vec<f64>,
    /// the samples integrated (`Replay::simulated`)
    simulated: Vec<bool>,
    /// the position put back on the measurement every this many samples
    every: usize,
}

/// One parameter set's run over the record: its machine, sensors, readings so far and supply.
struct Run {
    /// the parameters' supply set-point [Pa]
    supply_pa: f64,
    /// per sample, the set-point that reads the schedule's supply at rest
    setpoints: Option<Vec<f64>>,
    /// a pump's ripple (frequency [Hz], sine and cosine amplitudes [Pa])
    ripple: Option<(f64, f64, f64)>,
    m: Machine,
    sensors: Sensors,
    probe: Probe,
    out: Replayed,
    /// open loop on some samples: the samples not simulated that follow the measurement
    /// (`Replay::followed`; empty = all)
    followed: Vec<bool>,
}

impl Run {
    /// The supply set-point at sample `k`, with the ripple at the sample instant (held over it).
    fn supply_at(&self, k: usize, dt: f64) -> f64 {
        let base = self.setpoints.as_ref().map(|s| s[k]).unwrap_or(self.supply_pa);
        match self.ripple {
            Some((hz, sin, cos)) => {
                let w = 2.0 * std::f64::consts::PI * hz * k as f64 * dt;
                base + (sin * w.sin() + cos * w.cos())
            }
            None => base,
        }
    }
}

fn push(out: &mut Replayed, rd: &[f64; NC], u: f64) {
    for (v, r) in out.readings.iter_mut().zip(rd) {
        v.push(*r);
    }
    out.u.push(u);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::run::simulate_closed_loop;

    fn ramp(n: usize) -> Vec<f64> {
        (0..n).map(|k| 0.1 + 0.02 * ((k as f64 * 2e-3) * 3.0).sin()).collect()
    }

    const PFF: Controller = Controller::PositionPff { kp_v_per_m: -150.0, kff_v_per_m_s: -14.3, u_max_v: 10.0 };

    #[test]
    fn ideal_closed_loop_replay_matches_the_plain_closed_loop() {
        let p = Params::base();
        let r = ramp(1500);
        let u = vec![0.0; r.len()];
        let mut rp = Replay::new(2e-3, &u);
        rp.closed_loop = Some((PFF, &r));
        rp.preroll_s = 0.0;
        rp.rtol = 1e-6;
        let a = rp.run(&p).unwrap();
        let mut m = Machine::new(p.clone()).unwrap();
        m.x = m.plant.rest_state(r[0]);
        let tr = simulate_closed_loop(&mut m, &r, 2e-3, &PFF).unwrap();
        for k in 0..r.len() {
            assert!((a.readings[0][k] - tr.y[k]).abs() < 1e-12 && (a.u[k] - tr.u[k]).abs() < 1e-9, "sample {k}");
        }
    }

    #[test]
    fn open_loop_on_active_samples_only_reads_as_the_whole_run_there() {
        let mut p = Params::base();
        p.valve_natural_hz = 120.0;
        p.valve_tau_s = 0.01;
        p.valve_hysteresis_half_width_v = 0.05;
        let r = ramp(1500);
        let u0 = vec![0.0; r.len()];
        let mut rp = Replay::new(2e-3, &u0);
        rp.closed_loop = Some((PFF, &r));
        let truth = rp.run(&p).unwrap();
        let mut ol = Replay::new(2e-3, &truth.u);
        for c in 0..4 {
            ol.measured[c] = Some(&truth.readings[c]);
        }
        ol.horizon_s = 0.1;
        let whole = ol.run(&p).unwrap();
        // every fourth 0.1 s block reported (each simulated from a warm-up before it)
        let mask: Vec<bool> = (0..r.len()).map(|k| (k / 50) % 4 == 1).collect();
        ol.active = Some(&mask);
        let part = ol.run(&p).unwrap();
        for (k, &reported) in mask.iter().enumerate() {
            if reported {
                for c in 0..4 {
                    let (a, b) = (part.readings[c][k], whole.readings[c][k]);
                    assert!((a - b).abs() <= 1e-3 * b.abs().max(1e-3), "channel {c} sample {k}: {a} vs {b}");
                }
            } else {
                assert!(part.readings[0][k].is_nan());
            }
        }
        assert!(part.stats.accepted < whole.stats.accepted);
    }

    #[test]
    fn a_reading_delayed_past_the_warm_up_reads_the_measured_state_before_it() {
        let p = Params::base();
        let r = ramp(1500);
        let u0 = vec![0.0; r.len()];
        let mut rp = Replay::new(2e-3, &u0);
        rp.closed_loop = Some((PFF, &r));
        let truth = rp.run(&p).unwrap();
        let mut ol = Replay::new(2e-3, &truth.u);
        for c in 0..4 {
            ol.measured[c] = Some(&truth.readings[c]);
        }
        let mask: Vec<bool> = (0..r.len()).map(|k| (k / 200) % 3 == 2).collect();
        ol.active = Some(&mask);
        let mut late = p.clone();
        late.sensor_delay_y_s = 0.13; // 65 samples, past the 50-sample warm-up
        let out = ol.run(&late).unwrap();
        let mut checked = 0;
        for k in (0..r.len()).filter(|&k| mask[k] && !mask[k - 15]) {
            // the sample 65 back is not simulated: the state there followed the measurement
            // (restarted from the reading 65 later), so the reading is the measured one
            assert!((out.readings[0][k] - truth.readings[0][k]).abs() < 1e-12, "sample {k}: {} vs {}", out.readings[0][k], truth.readings[0][k]);
            checked += 1;
        }
        assert_eq!(checked, 2 * 15);
        // a sample past the reach of any reading: never read, never restarted
        let run_far = ol.followed(&ol.simulated(), &Sensors::from_params(&late));
        assert!(!run_far[0] && !run_far[200] && run_far[400 - 50 - 67] && run_far[350] && run_far[700 - 1] == mask[699]);
    }

    #[test]
    fn a_supply_schedule_sets_the_supply_and_chamber_pressures_per_sample() {
        let r = ramp(2000);
        let u = vec![0.0; r.len()];
        let sched: Vec<f64> = (0..r.len()).map(|k| if k < 1000 { 1.0 } else { 0.6 }).collect();
        let mut rp = Replay::new(2e-3, &u);
        rp.closed_loop = Some((PFF, &r));
        rp.supply = Some(&sched);
        let p = Params::base();
        let a = rp.run(&p).unwrap();
        let ps = &a.readings[4];
        assert!((ps[500] - p.supply_pressure_pa).abs() < 1.0 && (ps[1500] - 0.6 * p.supply_pressure_pa).abs() < 1.0);
        // a symmetric actuator holds p_a + p_b near the supply: it follows the new level
        let sum = |k: usize| a.readings[2][k] + a.readings[3][k];
        assert!((sum(1900) / (0.6 * p.supply_pressure_pa) - 1.0).abs() < 0.05, "{}", sum(1900));
        assert!((sum(900) / p.supply_pressure_pa - 1.0).abs() < 0.05, "{}", sum(900));
        let bad = vec![1.0; 10];
        rp.supply = Some(&bad);
        assert!(rp.run(&p).unwrap_err().to_string().contains("supply schedule"));
    }

    #[test]
    fn a_delayed_position_sensor_inside_the_loop_changes_the_motion() {
        let r = ramp(1500);
        let u = vec![0.0; r.len()];
        let mut rp = Replay::new(2e-3, &u);
        rp.closed_loop = Some((PFF, &r));
        let ideal = rp.run(&Params::base()).unwrap();
        let mut p = Params::base();
        p.sensor_delay_y_s = 0.01;
        let late = rp.run(&p).unwrap();
        // the reading is the position 10 ms ago, and the controller acting on it moves the
        // piston differently: the late reading is not just the ideal one shifted by 10 ms
        let diff = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
        let shifted: Vec<f64> = (0..r.len()).map(|k| ideal.readings[0][k.saturating_sub(5)]).collect();
        assert!(diff(&late.readings[0], &ideal.readings[0]) > 5e-4);
        assert!(diff(&late.readings[0], &shifted) > 2e-4, "{}", diff(&late.readings[0], &shifted));
    }

    #[test]
    fn neighbours_in_lockstep_follow_the_first_set_and_differ_from_it_as_when_run_alone() {
        let mut p = Params::base();
        p.valve_natural_hz = 200.0;
        let r = ramp(1500);
        let u0 = vec![0.0; r.len()];
        let mut rp = Replay::new(2e-3, &u0);
        rp.closed_loop = Some((PFF, &r));
        let truth = rp.run(&p).unwrap();
        let mut ol = Replay::new(2e-3, &truth.u);
        for c in 0..4 {
            ol.measured[c] = Some(&truth.readings[c]);
        }
        ol.horizon_s = 0.2;
        let mask: Vec<bool> = (0..r.len()).map(|k| (k / 100) % 3 == 1).collect();
        ol.active = Some(&mask);
        let mut heavier = p.clone();
        heavier.moving_mass_kg *= 1.02;
        let mut softer = p.clone();
        softer.bulk_modulus_pa *= 0.98;
        let mut lagged = p.clone();
        lagged.valve_tau_s = 0.002; // a spool form of its own: stepped alone
        let ps = [p.clone(), heavier, softer, lagged];
        let alone: Vec<Replayed> = ps.iter().map(|q| ol.run(q).unwrap()).collect();
        let mut tight = ol.clone();
        tight.rtol = 1e-7;
        let exact: Vec<Replayed> = ps.iter().map(|q| tight.run(q).unwrap()).collect();
        for threads in [1, 2] {
            let lock: Vec<Replayed> = ol.run_lockstep_batch(&ps, threads).into_iter().map(|x| x.unwrap()).collect();
            let bits = |r: &Replayed| r.readings.iter().flatten().map(|v| v.to_bits()).collect::<Vec<u64>>();
            assert!(bits(&lock[0]) == bits(&alone[0]), "the first set takes its own steps");
            // the neighbours take the first set's steps (a step that misses their tolerance is
            // crossed with their own control: a rejection or two, not the leader's own ten)
            for l in &lock[1..3] {
                assert!(l.stats.rejected <= 2 && l.stats.accepted.abs_diff(lock[0].stats.accepted) <= 5, "{:?} vs {:?}", l.stats, lock[0].stats);
            }
            assert!(lock[0].stats.rejected >= 5, "the leader's own step control rejects: {:?}", lock[0].stats);
            for i in 1..ps.len() {
                for c in 0..4 {
                    let col = |a: &Replayed, b: &Replayed| -> Vec<f64> {
                        (0..r.len()).filter(|&k| mask[k]).map(|k| a.readings[c][k] - b.readings[c][k]).collect()
                    };
                    let (got, want) = (col(&lock[i], &lock[0]), col(&exact[i], &exact[0]));
                    let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
                    let err: Vec<f64> = got.iter().zip(&want).map(|(a, b)| a - b).collect();
                    assert!(norm(&err) <= 0.05 * norm(&want), "set {i} channel {c}: {} of {}", norm(&err), norm(&want));
                }
            }
        }
    }

    #[test]
    fn the_spool_solved_apart_reads_as_the_coupled_form_with_every_valve_effect() {
        // an open-loop record of a rig with a second-order spool, then each valve effect on it
        let mut base = Params::base();
        base.valve_natural_hz = 150.0;
        base.valve_damping = 0.7;
        let r: Vec<f64> = (0..2500).map(|k| {
            let t = k as f64 * 2e-3;
            0.1 + 0.02 * (3.0 * t).sin() + 0.004 * (23.0 * t).sin()
        }).collect();
        let u0 = vec![0.0; r.len()];
        let mut rp = Replay::new(2e-3, &u0);
        rp.closed_loop = Some((PFF, &r));
        let truth = rp.run(&base).unwrap();
        let mut ol = Replay::new(2e-3, &truth.u);
        for c in 0..4 {
            ol.measured[c] = Some(&truth.readings[c]);
        }
        type Effect = (&'static str, fn(&mut Params));
        let effects: [Effect; 6] = [
            ("spool only", |_| {}),
            ("play (hysteresis)", |p| p.valve_hysteresis_half_width_v = 0.2),
            ("dead band", |p| p.valve_deadband_half_width_v = 0.15),
            ("lag", |p| p.valve_tau_s = 0.01),
            ("fast spool", |p| p.valve_natural_hz = 2000.0),
            ("slow spool", |p| { p.valve_natural_hz = 60.0; p.valve_damping = 1.3 }),
        ];
        for (name, set) in effects {
            let mut p = base.clone();
            set(&mut p);
            ol.dense_stages = true;
            let coupled = ol.run(&p).unwrap();
            ol.dense_stages = false;
            let apart = ol.run(&p).unwrap();
            let worst = |c: usize| coupled.readings[c].iter().zip(&apart.readings[c]).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
            // far below the sensor noise (~1 um, ~10 kPa): the same steps, rounding apart
            assert!(worst(0) < 1e-9 && worst(2) < 1.0 && worst(3) < 1.0, "{name}: y {:.2e} m, p_a {:.2e} Pa, p_b {:.2e} Pa", worst(0), worst(2), worst(3));
            assert_eq!(coupled.stats.accepted, apart.stats.accepted, "{name}");
            // and the effect is there to be carried: it moves the readings by far more
            let plain = ol.run(&base).unwrap();
            if name != "spool only" {
                let moved = plain.readings[2].iter().zip(&apart.readings[2]).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
                assert!(moved > 1e4, "{name}: {moved}");
            }
        }
    }

    #[test]
    fn a_batch_carried_in_slices_across_threads_reads_as_each_set_run_alone() {
        // a fit's point and its neighbours on part of an open-loop record, a delayed sensor and
        // a spool form among them, and one set the plant rejects
        let mut p = Params::base();
        p.valve_natural_hz = 300.0;
        let r = ramp(2000);
        let u0 = vec![0.0; r.len()];
        let mut rp = Replay::new(2e-3, &u0);
        rp.closed_loop = Some((PFF, &r));
        let truth = rp.run(&p).unwrap();
        let mut ol = Replay::new(2e-3, &truth.u);
        for c in 0..4 {
            ol.measured[c] = Some(&truth.readings[c]);
        }
        let mask: Vec<bool> = (0..r.len()).map(|k| (k / 150) % 3 == 1).collect();
        let mut sets = vec![p.clone()];
        for f in ["moving_mass_kg", "bulk_modulus_pa", "valve_rated_flow_m3_s", "sensor_delay_p_a_s", "valve_tau_s"] {
            let mut q = p.clone();
            let v = q.get(f).unwrap();
            q.set(f, if v > 0.0 { v * 1.05 } else { 3e-3 }).unwrap();
            sets.push(q);
        }
        let mut bad = p.clone();
        bad.moving_mass_kg = -1.0;
        sets.push(bad);
        for active in [None, Some(&mask[..])] {
            ol.active = active;
            let alone: Vec<Result<Replayed>> = sets.iter().map(|q| ol.run(q)).collect();
            let bits = |r: &Replayed| (r.readings.iter().flatten().chain(&r.u).map(|v| v.to_bits()).collect::<Vec<u64>>(), r.stats);
            for threads in [2, 3, 8] {
                for n in [2, 3, sets.len()] {
                    let batch = ol.run_batch(&sets[..n], threads);
                    assert_eq!(batch.len(), n);
                    for (i, (a, b)) in alone.iter().zip(&batch).enumerate() {
                        match (a, b) {
                            (Ok(a), Ok(b)) => assert!(bits(a) == bits(b), "set {i}, {threads} threads, {n} sets"),
                            (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string()),
                            _ => panic!("set {i}: {:?} vs {:?}", a.as_ref().err(), b.as_ref().err()),
                        }
                    }
                }
            }
        }
        // a record the replay rejects: every set gets its error
        ol.horizon_s = -1.0;
        assert!(ol.run_batch(&sets[..3], 2).iter().all(|r| r.as_ref().unwrap_err().to_string().contains("horizon_s")));
    }

    #[test]
    fn open_loop_restarts_from_the_measurement_and_batches_agree_with_single_runs() {
        let p = Params::base();
        let r = ramp(1000);
        let u0 = vec![0.0; r.len()];
        let mut rp = Replay::new(2e-3, &u0);
        rp.closed_loop = Some((PFF, &r));
        let truth = rp.run(&p).unwrap();
        let mut ol = Replay::new(2e-3, &truth.u);
        for c in 0..4 {
            ol.measured[c] = Some(&truth.readings[c]);
        }
        ol.horizon_s = 0.2;
        let mut q = p.clone();
        q.moving_mass_kg *= 1.5;
        let out = ol.run_batch(&[p.clone(), q, p.clone()], 2);
        let a = out[0].as_ref().unwrap();
        let worst = a.readings[0].iter().zip(&truth.readings[0]).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
        assert!(worst < 2e-4, "open loop with restarts stays on the record: {worst}");
        assert_eq!(a.readings[0], out[2].as_ref().unwrap().readings[0]);
        assert_ne!(a.readings[0], out[1].as_ref().unwrap().readings[0]);
        let mut bad = p.clone();
        bad.moving_mass_kg = -1.0;
        assert!(ol.run_batch(&[bad], 1)[0].is_err());
    }
}
