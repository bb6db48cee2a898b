//! Know before you start: whether the rig (its parameters) can run a test on this specimen.
//! Each check compares what the test needs with what the rig or the specimen gives, over the
//! whole crack range of every phase, and says how far the test could go: the largest ΔF (all
//! forces scaled together, R kept) and, where the limit is a rate, the largest frequency.
//! One formula per limit, here; callers format the numbers.
use std::f64::consts::PI;

use crate::engine::{hydraulic_stiffness, series_stiffness, targets, Level, TestConfig};
use crate::error::Result;

/// A need above this fraction of its limit is marginal: it runs, but with little headroom.
pub const MARGINAL_FRACTION: f64 = 0.8;
/// The test frequency may be at most this fraction of the oil-column/specimen resonance.
pub const RESONANCE_FRACTION: f64 = 0.2;
/// Crack lengths sampled per phase (ΔK modes change the force as the crack grows).
const SAMPLES: usize = 64;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Status {
    Ok,
    Marginal,
    Refused,
}

impl Status {
    pub fn name(self) -> &'static str {
        match self {
            Status::Ok => "ok",
            Status::Marginal => "marginal",
            Status::Refused => "refused",
        }
    }
}

/// One limit: what the test needs against what the rig or specimen gives (same unit, SI).
#[derive(Debug, Clone, PartialEq)]
pub struct Check {
    /// `force_tension`, `force_compression`, `valve_flow`, `frequency`, `stroke`, `size_criterion`
    pub name: &'static str,
    pub status: Status,
    pub need: f64,
    pub limit: f64,
    /// unit of `need` and `limit`
    pub unit: &'static str,
    /// phase index and crack length [m] where the need is largest (or the size criterion first fails)
    pub phase: usize,
    pub a_m: f64,
    /// ΔF [N] the test asks at that point, and the largest ΔF this limit allows there
    pub delta_f_n: f64,
    pub largest_delta_f_n: f64,
    /// largest test frequency this limit allows [Hz] (NaN when the limit does not depend on it)
    pub largest_frequency_hz: f64,
}

fn status(need: f64, limit: f64) -> Status {
    if !(need <= limit) {
        Status::Refused
    } else if need > MARGINAL_FRACTION * limit {
        Status::Marginal
    } else {
        Status::Ok
    }
}

/// (phase index, crack length a [m], target Fmax [N], target Fmin [N])
type LoadPoint = (usize, f64, f64, f64);

/// The targets at crack lengths spread over every phase, `SAMPLES` points from each phase's
/// start; a variable-amplitude sequence replaces the phase's forces by its limiting levels.
fn load_points(cfg: &TestConfig) -> Result<Vec<LoadPoint>> {
    let levels = limiting_levels(&cfg.sequence);
    let mut out = Vec::with_capacity(cfg.phases.len() * SAMPLES * levels.len().max(1));
    let mut a0 = cfg.a0_m;
    for (i, ph) in cfg.phases.iter().enumerate() {
        let a_at = |k: usize| a0 + (ph.end_a_m - a0) * k as f64 / (SAMPLES - 1) as f64;
        if levels.is_empty() {
            for k in 0..SAMPLES {
                let (fmax, fmin, _) = targets(cfg, ph, a0, a_at(k))?;
                out.push((i, a_at(k), fmax, fmin));
            }
        }
        for &(fmax, fmin) in &levels {
            out.extend((0..SAMPLES).map(|k| (i, a_at(k), fmax, fmin)));
        }
        a0 = ph.end_a_m;
    }
    Ok(out)
}

/// The levels of a variable-amplitude sequence that set its limits: the highest peak, the
/// deepest valley and the widest range (each once).
fn limiting_levels(seq: &[Level]) -> Vec<(f64, f64)> {
    let mut out: Vec<(f64, f64)> = Vec::new();
    for key in [|l: &Level| l.fmax_n, |l: &Level| -l.fmin_n, |l: &Level| l.fmax_n - l.fmin_n] {
        if let Some(l) = seq.iter().max_by(|x, y| key(x).total_cmp(&key(y))) {
            if !out.contains(&(l.fmax_n, l.fmin_n)) {
                out.push((l.fmax_n, l.fmin_n));
            }
        }
    }
    out
}

/// Largest static force of the cylinder on the specimen [N] in tension (+) and compression:
/// supply on one side, tank on the other, less (tension) or plus (compression) the moving weight.
pub fn force_capacity(cfg: &TestConfig) -> (f64, f64) {
    let p = &cfg.params;
    let weight = p.moving_mass_kg * p.gravity_m_s2;
    let tension = p.area_a_m2 * p.supply_pressure_pa - p.area_b_m2 * p.tank_pressure_pa - weight;
    let compression = p.area_b_m2 * p.supply_pressure_pa - p.area_a_m2 * p.tank_pressure_pa + weight;
    (tension, compression)
}

/// Oil-column + specimen resonance [Hz] at the stiffest specimen (the initial crack), piston
/// mid-stroke.
pub fn resonance_hz(cfg: &TestConfig) -> Result<f64> {
    let p = &cfg.params;
    let ksp0 = cfg.specimen.stiffness(cfg.a0_m, &cfg.material)?;
    let a_n = 0.5 * (p.area_a_m2 + p.area_b_m2);
    let v_half = p.dead_volume_a_m3 + a_n * 0.5 * p.stroke_m;
    let k_oil = p.bulk_modulus_pa * a_n * a_n * 2.0 / v_half;
    Ok(((k_oil + ksp0) / p.moving_mass_kg).sqrt() / (2.0 * PI))
}

/// (piston speed the test needs, speed the valve gives) [m/s]. The need is the waveform's peak
/// force rate amp·f·max_slope over the stiffness the flow works against (specimen at the final
/// crack length in series with the oil column), doubled for the peak/valley compensation and the
/// loops' transients; the valve gives half its rated flow over the piston area.
pub fn piston_speed(cfg: &TestConfig) -> Result<(f64, f64)> {
    let p = &cfg.params;
    let a_end = cfg.phases.last().map_or(cfg.a0_m, |ph| ph.end_a_m);
    let ksp_end = cfg.specimen.stiffness(a_end, &cfg.material).unwrap_or(0.0);
    let amp_max = load_points(cfg)?.iter().map(|&(_, _, fmax, fmin)| 0.5 * (fmax - fmin)).fold(0.0, f64::max);
    let a_n = 0.5 * (p.area_a_m2 + p.area_b_m2);
    let k_flow = series_stiffness(ksp_end.max(1.0), hydraulic_stiffness(p, p.specimen_zero_force_position_m));
    let need = amp_max * cfg.waveform.max_slope() * cfg.frequency_hz / k_flow * 2.0;
    Ok((need, 0.5 * p.valve_rated_flow_m3_s / a_n))
}

/// Every check of `cfg` (validated first). Refused checks name the largest feasible ΔF and,
/// for rate limits, the largest feasible frequency.
pub fn assess(cfg: &TestConfig) -> Result<Vec<Check>> {
    cfg.validate()?;
    let p = &cfg.params;
    let pts = load_points(cfg)?;
    let df = |fmax: f64, fmin: f64| fmax - fmin;
    let mut out = Vec::new();
    let check = |name, need: f64, limit: f64, unit, (phase, a, fmax, fmin): LoadPoint, f_max: f64| {
        let d = df(fmax, fmin);
        Check { name, status: status(need, limit), need, limit, unit, phase, a_m: a, delta_f_n: d,
                largest_delta_f_n: if need > 0.0 { d * limit / need } else { f64::INFINITY }, largest_frequency_hz: f_max }
    };
    let worst = |key: &dyn Fn(&LoadPoint) -> f64| {
        *pts.iter().max_by(|x, y| key(x).total_cmp(&key(y))).expect("a test has phases")
    };

    // force: the largest peak against the tension capacity, the deepest valley against compression
    let (cap_t, cap_c) = force_capacity(cfg);
    let w = worst(&|x| x.2);
    out.push(check("force_tension", w.2.max(0.0), cap_t, "N", w, f64::NAN));
    let w = worst(&|x| -x.3);
    if w.3 < 0.0 {
        out.push(check("force_compression", -w.3, cap_c, "N", w, f64::NAN));
    }

    // valve flow for the waveform's peak piston speed: scales with ΔF and with frequency
    let (v_need, v_max) = piston_speed(cfg)?;
    let w = worst(&|x| x.2 - x.3);
    out.push(check("valve_flow", v_need, v_max, "m/s", w, cfg.frequency_hz * v_max / v_need));

    // frequency against the oil-column/specimen resonance (independent of ΔF)
    let f_lim = RESONANCE_FRACTION * resonance_hz(cfg)?;
    let mut c = check("frequency", cfg.frequency_hz, f_lim, "Hz", w, f_lim);
    c.largest_delta_f_n = f64::INFINITY;
    out.push(c);

    // stroke: the piston moves F/K_sp from the specimen's zero-force position, most at the
    // longest (most compliant) crack; a margin stays at either end
    let margin = cfg.limits.stroke_margin_m;
    let y0 = p.specimen_zero_force_position_m;
    let mut worst_stroke: (f64, f64, _) = (0.0, 1.0, w);
    for &pt in &pts {
        let ksp = cfg.specimen.stiffness(pt.1, &cfg.material)?;
        for (travel, room) in [(pt.2 / ksp, p.stroke_m - margin - y0), (-pt.3 / ksp, y0 - margin)] {
            if travel > 0.0 && travel / room.max(1e-12) > worst_stroke.0 / worst_stroke.1.max(1e-12) {
                worst_stroke = (travel, room, pt);
            }
        }
    }
    out.push(check("stroke", worst_stroke.0, worst_stroke.1, "m", worst_stroke.2, f64::NAN));

    // E647 size criterion over the crack range: refused when it fails at the start of a phase
    // (no valid point at all), marginal when it fails before the phase ends (the points beyond
    // are invalid); the largest ΔF keeps it over the whole range
    let sy = cfg.material.yield_strength_pa;
    let ratio = |a: f64, fmax: f64| -> Result<f64> {
        let (lig, req) = cfg.specimen.size_criterion(a, fmax, sy)?;
        Ok(req / lig)
    };
    let (mut first_fail, mut start_fail, mut scale) = (None, false, f64::INFINITY);
    let mut worst_size = (0.0, pts[0]);
    for (k, &pt) in pts.iter().enumerate() {
        let r = ratio(pt.1, pt.2)?;
        if r > worst_size.0 {
            worst_size = (r, pt);
        }
        if r > 1.0 && first_fail.is_none() {
            first_fail = Some(pt);
            start_fail = k % SAMPLES == 0;
        }
        scale = scale.min(force_scale_for(|s| ratio(pt.1, s * pt.2))?);
    }
    let at = first_fail.unwrap_or(worst_size.1);
    let (lig, req) = cfg.specimen.size_criterion(at.1, at.2, sy)?;
    let st = match (first_fail, start_fail) {
        (Some(_), true) => Status::Refused,
        (Some(_), false) => Status::Marginal,
        (None, _) => Status::Ok,
    };
    out.push(Check { name: "size_criterion", status: st, need: req, limit: lig, unit: "m", phase: at.0, a_m: at.1,
                     delta_f_n: df(at.2, at.3), largest_delta_f_n: scale * df(at.2, at.3), largest_frequency_hz: f64::NAN });
    Ok(out)
}

/// Largest factor s on the forces with `ratio(s)` ≤ 1 (`ratio` rises with s), by bisection.
fn force_scale_for(ratio: impl Fn(f64) -> Result<f64>) -> Result<f64> {
    let (mut lo, mut hi) = (0.0, 1.0);
    while ratio(hi)? <= 1.0 {
        lo = hi;
        hi *= 2.0;
        if hi > 1e6 {
            return Ok(f64::INFINITY);
        }
    }
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if ratio(mid)? <= 1.0 { lo = mid } else { hi = mid }
    }
    Ok(lo)
}

/// The refused checks of `cfg`, empty when the rig can run it.
pub fn refusals(cfg: &TestConfig) -> Result<Vec<Check>> {
    Ok(assess(cfg)?.into_iter().filter(|c| c.status == Status::Refused).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::tests::table_b1;
    use crate::engine::Mode;

    fn by_name(cfg: &TestConfig, name: &str) -> Check {
        assess(cfg).unwrap().into_iter().find(|c| c.name == name).unwrap()
    }

    #[test]
    fn the_thesis_test_is_feasible_on_the_thesis_rig() {
        let cfg = table_b1(10.0, 1000.0, 0.5, 1.0);
        for c in assess(&cfg).unwrap() {
            assert_eq!(c.status, Status::Ok, "{c:?}");
        }
        // to a/W = 0.6 the steel's ligament runs out near a = 30 mm (the engine flags it there)
        let c = by_name(&table_b1(10.0, 1000.0, 0.6, 1.0), "size_criterion");
        assert!(c.status == Status::Marginal && (c.a_m - 30e-3).abs() < 0.5e-3, "{c:?}");
    }

    #[test]
    fn a_peak_beyond_areas_times_supply_is_refused_with_the_largest_delta_f() {
        let mut cfg = table_b1(10.0, 1000.0, 0.3, 1.0);
        cfg.phases[0].mode = Mode::ConstantForce { delta_f_n: 80.01e3 };
        cfg.material.fracture_toughness_pa_sqrt_m = 1e9; // K stays below K_IC: only the rig limits
        let c = by_name(&cfg, "force_tension");
        assert_eq!(c.status, Status::Refused);
        let cap = 2.5635e-3 * 19e6 - 53.78 * 9.80665;
        assert!((c.limit - cap).abs() < 1.0 && (c.need - 88.9e3).abs() < 1.0, "{c:?}");
        assert!((c.largest_delta_f_n - 0.9 * cap).abs() < 1.0, "ΔF = (1 − R)·capacity: {c:?}");
    }

    #[test]
    fn rate_limits_name_the_largest_frequency() {
        let mut cfg = table_b1(80.0, 8000.0, 0.6, 1.0);
        let c = by_name(&cfg, "frequency");
        assert_eq!(c.status, Status::Refused);
        assert!((c.largest_frequency_hz - 0.2 * resonance_hz(&cfg).unwrap()).abs() < 1e-9);
        cfg.frequency_hz = 10.0;
        cfg.control_rate_hz = 1000.0;
        cfg.params.valve_rated_flow_m3_s = 5e-6;
        let c = by_name(&cfg, "valve_flow");
        assert_eq!(c.status, Status::Refused);
        assert!(c.largest_frequency_hz < 10.0 && c.largest_delta_f_n < c.delta_f_n);
        assert!((c.largest_frequency_hz / 10.0 - c.limit / c.need).abs() < 1e-12);
    }

    #[test]
    fn the_size_criterion_refuses_at_the_start_and_warns_part_way() {
        let mut cfg = table_b1(10.0, 1000.0, 0.6, 1.0);
        cfg.material.yield_strength_pa = 60e6; // fails from the first crack length
        let c = by_name(&cfg, "size_criterion");
        assert_eq!(c.status, Status::Refused);
        assert!((c.a_m - cfg.a0_m).abs() < 1e-12 && c.largest_delta_f_n < c.delta_f_n);
        cfg.material.yield_strength_pa = 150e6; // holds at a0, fails before a/W = 0.6
        let c = by_name(&cfg, "size_criterion");
        assert_eq!(c.status, Status::Marginal);
        assert!(c.a_m > cfg.a0_m && c.a_m < 0.6 * 50.8e-3 && c.need > c.limit, "{c:?}");
        // the largest ΔF meets the criterion over the whole range
        let mut ok = cfg.clone();
        ok.phases[0].mode = Mode::ConstantForce { delta_f_n: 0.999 * c.largest_delta_f_n };
        assert_eq!(by_name(&ok, "size_criterion").status, Status::Ok);
    }

    #[test]
    fn a_long_crack_in_a_compliant_specimen_runs_out_of_stroke() {
        let mut cfg = table_b1(1.0, 1000.0, 0.6, 1.0);
        cfg.params.specimen_zero_force_position_m = 0.19895; // 0.05 mm left above it
        let c = by_name(&cfg, "stroke");
        assert_eq!(c.status, Status::Refused, "{c:?}");
        assert!((c.limit - 0.05e-3).abs() < 1e-9 && c.largest_delta_f_n < c.delta_f_n, "{c:?}");
        assert!((c.a_m - 0.6 * 50.8e-3).abs() < 1e-9, "most travel at the longest crack: {c:?}");
    }
}
