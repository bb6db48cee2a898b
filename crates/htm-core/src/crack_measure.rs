//! Crack size and closure measured on the specimen (ASTM E647): elastic compliance from the
//! loading curve of a clip gauge, crack size from compliance (C(T) and M(T)) or from the direct-
//! current potential drop (Johnson's expression, or a calibration table), and the opening force by
//! the compliance offset (E647 Appendix X2, criteria 1, 2 and 4 %). One copy, used by the record
//! reduction (`htm crack measure`) and meant for the rig loop and the simulator alike.
//!
//! Expressions and their sources:
//! - C(T) compliance → a/W: E647's compact-specimen expression (Saxena & Hudak 1978),
//!   a/W = C0 + C1·u + … + C5·u⁵, u = 1/(√(E·B·C) + 1), C = v/P at the gauge location X/W
//!   (coefficients `CT_COMPLIANCE`), valid 0.2 ≤ a/W ≤ 0.975. E is the modulus the expression is
//!   written with (E647: Young's modulus, plane stress); a measured effective modulus may replace it.
//! - M(T) compliance: the closed-form opening across a gauge at ±Y on the centre line of a
//!   centre-cracked strip (Irwin's periodic-crack Westergaard function, plane stress, with the
//!   uniaxial correction; Tada–Paris–Irwin), inverted numerically; E647's M(T) polynomial is a fit
//!   of such an expression and its coefficients are not used here.
//! - Potential drop, M(T): Johnson's expression (E647 potential-difference annex),
//!   a = (W/π)·acos[cosh(πY/W) / cosh((V/Vr)·acosh(cosh(πY/W)/cos(π·ar/W)))].
//!   C(T): a calibration table (V/Vr → a) when one is given, otherwise Johnson's form with the
//!   C(T) taken as half of a centre-cracked strip of width 2W (an approximation, said so).
//! - Closure: compliance offset = (C_open − C_local)/C_open (E647 X2). The local compliance is
//!   taken from a smooth closure curve fitted to the pooled loading branches of an interval
//!   (E647 allows averaging over a few cycles); E647's segment offsets (segments of 10 % of the
//!   force range) are computed beside it by `segment_offsets`.
use crate::error::{Error, Result};
use crate::specimen::{root_illinois, Geometry, Specimen};
use std::f64::consts::PI;

fn param(field: &str, value: f64, allowed: &str) -> Error {
    Error::Parameter { field: field.into(), value, allowed: allowed.into() }
}

/// E647 C(T) compliance coefficients C0..C5 per gauge location X/W (X measured from the load line,
/// negative towards the front face): front face of the specimen with integral knife edges
/// (−0.345), crack mouth = front face of the standard specimen (−0.25), knife edges at −0.1576,
/// load line (0).
pub const CT_COMPLIANCE: [(f64, [f64; 6]); 4] = [
    (-0.345, [1.0012, -4.9165, 23.057, -323.91, 1798.3, -3513.2]),
    (-0.25, [1.0010, -4.6695, 18.460, -236.82, 1214.9, -2143.6]),
    (-0.1576, [1.0008, -4.4473, 15.400, -180.55, 870.92, -1411.3]),
    (0.0, [1.0002, -4.0632, 11.242, -106.04, 464.33, -650.68]),
];

/// The gauge location X/W a metadata name stands for.
pub fn ct_gauge_x_over_w(name: &str) -> Result<f64> {
    match name {
        "crack_mouth" | "front_face" => Ok(-0.25),
        "front_face_knife_edges" => Ok(-0.345),
        "knife_edges_0.1576" => Ok(-0.1576),
        "load_line" => Ok(0.0),
        other => Err(Error::Input(format!(
            "cod_at `{other}` is unknown for a C(T): use crack_mouth (X/W = −0.25), front_face_knife_edges (−0.345), knife_edges_0.1576 or load_line"
        ))),
    }
}

fn ct_coefficients(x_over_w: f64) -> Result<&'static [f64; 6]> {
    CT_COMPLIANCE
        .iter()
        .find(|(x, _)| (x - x_over_w).abs() < 1e-6)
        .map(|(_, c)| c)
        .ok_or_else(|| param("cod_x_over_w", x_over_w, "one of −0.345, −0.25, −0.1576, 0 (E647 C(T) gauge locations)"))
}

/// a/W of a C(T) from the dimensionless compliance E·B·C at gauge location `x_over_w` (E647).
pub fn ct_alpha_from_compliance(ebc: f64, x_over_w: f64) -> Result<f64> {
    let c = ct_coefficients(x_over_w)?;
    if !(ebc.is_finite() && ebc > 0.0) {
        return Err(param("E·B·C", ebc, "(0, inf)"));
    }
    let u = 1.0 / (ebc.sqrt() + 1.0);
    Ok(c.iter().rev().fold(0.0, |acc, &ci| acc * u + ci))
}

/// The forward form: E·B·C of a C(T) at a/W `alpha` (the E647 polynomial inverted numerically).
pub fn ct_compliance_from_alpha(alpha: f64, x_over_w: f64) -> Result<f64> {
    let c = ct_coefficients(x_over_w)?;
    if !(alpha.is_finite() && (0.2..=0.975).contains(&alpha)) {
        return Err(param("a/W", alpha, "[0.2, 0.975] (E647 C(T) compliance)"));
    }
    let poly = |u: f64| c.iter().rev().fold(0.0, |acc, &ci| acc * u + ci);
    // a/W falls monotonically with u over the valid range; u in (0.01, 0.5) covers it
    let u = root_illinois(|u| poly(u) - alpha, 0.005, 0.5, 1e-15)?;
    let s = 1.0 / u - 1.0;
    Ok(s * s)
}

/// E·B·V/P of an M(T) strip of width W with half crack `a` (2a/W = `alpha`), V the opening across
/// a gauge at ±Y (`y_over_w` = Y/W) on the centre line, Poisson's ratio `nu` (plane stress).
pub fn mt_compliance_dimensionless(alpha: f64, y_over_w: f64, nu: f64) -> f64 {
    let q = PI * alpha / 2.0; // πa/W
    let p = PI * y_over_w; // πY/W
    let (sh, sq) = (p.sinh(), q.sin());
    let acosh_arg = p.cosh() / q.cos();
    let term = 2.0 / PI * acosh_arg.acosh() - (1.0 + nu) * y_over_w * sh / (sh * sh + sq * sq).sqrt() + nu * y_over_w;
    2.0 * term
}

/// 2a/W of an M(T) from E·B·V/P (inverse of `mt_compliance_dimensionless`).
pub fn mt_alpha_from_compliance(ebc: f64, y_over_w: f64, nu: f64) -> Result<f64> {
    if !(y_over_w.is_finite() && y_over_w > 0.0 && y_over_w <= 1.0) {
        return Err(param("cod_y_m / W", y_over_w, "(0, 1]"));
    }
    if !(nu.is_finite() && (0.0..0.5).contains(&nu)) {
        return Err(param("poisson_ratio", nu, "[0, 0.5)"));
    }
    let (lo, hi) = (0.0, 0.95);
    let (flo, fhi) = (mt_compliance_dimensionless(lo, y_over_w, nu), mt_compliance_dimensionless(hi, y_over_w, nu));
    if !(ebc.is_finite() && ebc >= flo && ebc <= fhi) {
        return Err(param("E·B·V/P", ebc, &format!("[{flo:.4}, {fhi:.4}] (2a/W 0–0.95 for this gauge)")));
    }
    root_illinois(|x| mt_compliance_dimensionless(x, y_over_w, nu) - ebc, lo, hi, 1e-14)
}

/// Johnson's potential-drop expression: crack size [m] from V/Vr for a strip of width `w` with the
/// potential probes at ±`y` from the crack plane, reference crack `a_ref` (half crack for M(T)).
pub fn johnson_a(v_ratio: f64, w: f64, y: f64, a_ref: f64) -> Result<f64> {
    if !(v_ratio.is_finite() && v_ratio > 0.0) {
        return Err(param("V/Vr", v_ratio, "(0, inf)"));
    }
    if !(a_ref > 0.0 && a_ref < w / 2.0 && y > 0.0) {
        return Err(param("dcpd_a_ref_m", a_ref, "(0, W/2) with dcpd_probe_y_m > 0"));
    }
    let ch = (PI * y / w).cosh();
    let k = (ch / (PI * a_ref / w).cos()).acosh();
    let c = ch / (v_ratio * k).cosh();
    if !(c > 0.0 && c <= 1.0) {
        return Err(param("V/Vr", v_ratio, "a ratio giving a crack inside the specimen"));
    }
    Ok(w / PI * c.acos())
}

/// The forward form of Johnson's expression: V/Vr at crack size `a`.
pub fn johnson_v_ratio(a: f64, w: f64, y: f64, a_ref: f64) -> f64 {
    let ch = (PI * y / w).cosh();
    (ch / (PI * a / w).cos()).acosh() / (ch / (PI * a_ref / w).cos()).acosh()
}

/// Crack size from a calibration table (V/Vr ascending → a [m]), linear between its points;
/// outside the table is an error (no extrapolation).
pub fn calibration_a(v_ratio: f64, table_v: &[f64], table_a: &[f64]) -> Result<f64> {
    if table_v.len() != table_a.len() || table_v.len() < 2 {
        return Err(Error::Input("dcpd_calibration needs at least two [v_over_vref, a_m] pairs".into()));
    }
    if table_v.windows(2).any(|w| !(w[1] > w[0])) || table_a.windows(2).any(|w| !(w[1] > w[0])) {
        return Err(Error::Input("dcpd_calibration must rise in both V/Vr and a".into()));
    }
    let n = table_v.len();
    if !(v_ratio >= table_v[0] && v_ratio <= table_v[n - 1]) {
        return Err(param("V/Vr", v_ratio, &format!("[{}, {}] (the calibration table)", table_v[0], table_v[n - 1])));
    }
    let i = table_v.partition_point(|&v| v <= v_ratio).clamp(1, n - 1);
    let t = (v_ratio - table_v[i - 1]) / (table_v[i] - table_v[i - 1]);
    Ok(table_a[i - 1] + t * (table_a[i] - table_a[i - 1]))
}

/// E647's crack-size resolution: 0.1 mm or 0.002·W, whichever is larger [m].
pub fn resolution_m(width_m: f64) -> f64 {
    (1e-4f64).max(0.002 * width_m)
}

/// Least-squares line y = c0 + c1·x: (c1, c0, standard error of c1). None below 3 points.
pub fn ls_line(x: &[f64], y: &[f64]) -> Option<(f64, f64, f64)> {
    let n = x.len();
    if n < 3 || y.len() != n {
        return None;
    }
    let nf = n as f64;
    let mx = x.iter().sum::<f64>() / nf;
    let my = y.iter().sum::<f64>() / nf;
    let (mut sxx, mut sxy) = (0.0, 0.0);
    for (&xi, &yi) in x.iter().zip(y) {
        sxx += (xi - mx) * (xi - mx);
        sxy += (xi - mx) * (yi - my);
    }
    if !(sxx > 0.0) {
        return None;
    }
    let c1 = sxy / sxx;
    let c0 = my - c1 * mx;
    let sse: f64 = x.iter().zip(y).map(|(&xi, &yi)| (yi - c0 - c1 * xi).powi(2)).sum();
    Some((c1, c0, (sse / (nf - 2.0) / sxx).sqrt()))
}

/// How the crack size follows from the measurement.
#[derive(serde::Serialize, serde::Deserialize, Debug, Clone, PartialEq)]
pub enum Method {
    /// C(T) compliance at gauge location X/W, with the modulus the expression uses [Pa].
    ComplianceCt { x_over_w: f64, modulus_pa: f64 },
    /// M(T) compliance across a gauge at ±`y_m`, modulus [Pa] and Poisson's ratio.
    ComplianceMt { y_m: f64, modulus_pa: f64, poisson_ratio: f64 },
    /// Johnson's expression with probes at ±`y_m`, reference crack and potential; `width_m` the
    /// strip width it is written for (W for M(T), 2W for a C(T)).
    Johnson { y_m: f64, a_ref_m: f64, v_ref: f64, width_m: f64 },
    /// A calibration table V/Vr → a [m] with its reference potential.
    Calibration { v_over_vref: Vec<f64>, a_m: Vec<f64>, v_ref: f64 },
}

impl Method {
    /// The expression's name, as a reduction states it.
    pub fn describe(&self) -> String {
        match self {
            Method::ComplianceCt { x_over_w, .. } => format!(
                "ASTM E647 C(T) compliance expression (Saxena & Hudak), a/W = Σ Ci·u^i, u = 1/(√(E·B·C)+1), gauge at X/W = {x_over_w}"
            ),
            Method::ComplianceMt { .. } => {
                "M(T) compliance: closed-form centre-line opening of a centre-cracked strip (Tada–Paris–Irwin, plane stress), inverted numerically".into()
            }
            Method::Johnson { width_m, .. } => format!("Johnson's potential-drop expression (strip width {width_m} m)"),
            Method::Calibration { .. } => "potential-drop calibration table (V/Vr → a, linear between points)".into(),
        }
    }

    fn is_compliance(&self) -> bool {
        matches!(self, Method::ComplianceCt { .. } | Method::ComplianceMt { .. })
    }
}

/// Crack size [m] from a compliance C = v/P [m/N] (compliance methods) or a potential [V].
pub fn crack_size(spec: &Specimen, method: &Method, value: f64) -> Result<f64> {
    let (w, b) = (spec.width_m, spec.thickness_m);
    match (method, spec.geometry) {
        (Method::ComplianceCt { x_over_w, modulus_pa }, Geometry::CT) => {
            let alpha = ct_alpha_from_compliance(modulus_pa * b * value, *x_over_w)?;
            Ok(alpha * w)
        }
        (Method::ComplianceMt { y_m, modulus_pa, poisson_ratio }, Geometry::MT) => {
            let alpha = mt_alpha_from_compliance(modulus_pa * b * value, y_m / w, *poisson_ratio)?;
            Ok(alpha * w / 2.0)
        }
        (Method::Johnson { y_m, a_ref_m, v_ref, width_m }, _) => johnson_a(value / v_ref, *width_m, *y_m, *a_ref_m),
        (Method::Calibration { v_over_vref, a_m, v_ref }, _) => calibration_a(value / v_ref, v_over_vref, a_m),
        (m, g) => Err(Error::Input(format!("{} does not apply to a {} specimen", m.describe(), g.name()))),
    }
}

/// The compliance offset criteria of E647 X2 [-].
pub const OFFSET_CRITERIA: [f64; 3] = [0.01, 0.02, 0.04];

/// Closure fitted to the pooled loading branches of one interval: the local compliance is
/// C_open·(1 − d·σ((F_t − F)/w)), σ the logistic function (a smooth step from the closed to the
/// open crack; a sharp kink as w → 0, no closure as d → 0).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClosureFit {
    pub c_open: f64,
    /// closure depth d [-]: the compliance offset far below the transition
    pub depth: f64,
    /// transition force F_t [N] and width w [N]
    pub f_t: f64,
    pub w: f64,
}

impl ClosureFit {
    /// The compliance offset (C_open − C_local)/C_open at force `f`.
    pub fn offset(&self, f: f64) -> f64 {
        self.depth * sigmoid((self.f_t - f) / self.w)
    }

    /// The opening force at offset criterion `k`: the highest force where the offset reaches `k`;
    /// `fmin` when the crack is open over the whole loading branch.
    pub fn opening_force(&self, k: f64, fmin: f64, fmax: f64) -> f64 {
        if !(self.depth > k) {
            return fmin;
        }
        let p = k / self.depth;
        let f = self.f_t - self.w * (p / (1.0 - p)).ln();
        f.clamp(fmin, fmax)
    }
}

#[inline]
fn sigmoid(z: f64) -> f64 {
    if z >= 0.0 { 1.0 / (1.0 + (-z).exp()) } else { let e = z.exp(); e / (1.0 + e) }
}

#[inline]
fn softplus(z: f64) -> f64 {
    z.max(0.0) + (-z.abs()).exp().ln_1p()
}

/// The F statistic a fitted closure needs over the straight loading line to be kept.
pub const CLOSURE_F_MIN: f64 = 25.0;

/// Fit the closure curve to loading-branch samples (force, opening) over [fmin, fmax]: for each
/// transition force and width on a grid (then a finer one around the best), the opening is linear
/// in (offset, C_open, C_open·d): least squares with d ≥ 0.
pub fn fit_closure(f: &[f64], v: &[f64], fmin: f64, fmax: f64) -> Result<ClosureFit> {
    let span = fmax - fmin;
    if !(span > 0.0) || f.len() < 10 || f.len() != v.len() {
        return Err(Error::Input("too few loading samples to fit the loading curve".into()));
    }
    let x: Vec<f64> = f.iter().map(|&fi| (fi - fmin) / span).collect();
    let vs = v.iter().map(|&a| a.abs()).fold(0.0, f64::max).max(1e-300);
    let y: Vec<f64> = v.iter().map(|&a| a / vs).collect();
    // the straight line (no closure), and Σy² for the residual of each least-squares solution
    let yy: f64 = y.iter().map(|v| v * v).sum();
    let line = {
        let (c1, c0, _) = ls_line(&x, &y).unwrap_or((0.0, 0.0, 0.0));
        let sse: f64 = x.iter().zip(&y).map(|(&xi, &yi)| (yi - c0 - c1 * xi).powi(2)).sum();
        (sse, [c0, c1, 0.0])
    };
    let fit = |t: f64, w: f64| -> (f64, [f64; 3]) {
        // normal equations for columns [1, x, g]; SSE = Σy² − solᵀ·(Xᵀy) at the solution
        let mut m = [[0.0; 3]; 3];
        let mut r = [0.0; 3];
        for (&xi, &yi) in x.iter().zip(&y) {
            let g = w * softplus((t - xi) / w);
            let c = [1.0, xi, g];
            for a in 0..3 {
                r[a] += c[a] * yi;
                for b in a..3 {
                    m[a][b] += c[a] * c[b];
                }
            }
        }
        (m[1][0], m[2][0], m[2][1]) = (m[0][1], m[0][2], m[1][2]);
        match solve3(m, r).filter(|s| s[2] >= 0.0) {
            Some(s) => ((yy - s[0] * r[0] - s[1] * r[1] - s[2] * r[2]).max(0.0), s),
            None => line,
        }
    };
    let mut best = (f64::INFINITY, 0.0, 0.02, [0.0; 3]);
    let widths: Vec<f64> = (0..12).map(|i| 0.003 * (0.15f64 / 0.003).powf(i as f64 / 11.0)).collect();
    for i in 0..=65 {
        let t = -0.05 + 0.01 * i as f64;
        for &w in &widths {
            let (sse, s) = fit(t, w);
            if sse < best.0 {
                best = (sse, t, w, s);
            }
        }
    }
    // refine around the best: transition in steps of 0.001, width in steps of 5 %
    let (t0, w0) = (best.1, best.2);
    for i in -12..=12 {
        let t = (t0 + 0.001 * i as f64).min(0.6);
        for j in -6..=6 {
            let w = (w0 * 1.05f64.powi(j)).min(0.15);
            let (sse, s) = fit(t, w);
            if sse < best.0 {
                best = (sse, t, w, s);
            }
        }
    }
    let (sse, t, w, mut s) = best;
    // a closure must explain the curve beyond what the noise allows a searched step to: an F test
    // of its three terms against the straight line (searching t and w inflates F under no closure,
    // hence a high bar); below it the crack is taken as open over the whole range
    let n = x.len() as f64;
    let f_stat = (line.0 - sse) / 3.0 / (sse / (n - 5.0)).max(1e-300);
    if s[2] > 0.0 && f_stat < CLOSURE_F_MIN {
        s = line.1;
    }
    let c_open = s[1] * vs / span;
    if !(c_open.is_finite() && c_open > 0.0) {
        return Err(Error::Input("the opening does not rise with the force on the loading branches (gauge or force channel wrong?)".into()));
    }
    Ok(ClosureFit { c_open, depth: s[2] / s[1], f_t: fmin + t * span, w: w * span })
}

fn solve3(m: [[f64; 3]; 3], r: [f64; 3]) -> Option<[f64; 3]> {
    let det = |a: &[[f64; 3]; 3]| {
        a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1]) - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
            + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
    };
    let d = det(&m);
    let scale = m[0][0] * m[1][1] * m[2][2];
    if !(d.abs() > 1e-12 * scale.abs()) || !d.is_finite() {
        return None;
    }
    let mut out = [0.0; 3];
    for (k, o) in out.iter_mut().enumerate() {
        let mut a = m;
        for row in 0..3 {
            a[row][k] = r[row];
        }
        *o = det(&a) / d;
    }
    Some(out)
}

/// E647 X2 segment offsets: the loading branch cut into segments spanning `span_frac` of the
/// force range, stepped by `step_frac`; per segment (its mean force [N], its compliance offset
/// (C_open − C_seg)/C_open). Segments with fewer than 5 samples are skipped.
pub fn segment_offsets(f: &[f64], v: &[f64], fmin: f64, fmax: f64, c_open: f64, span_frac: f64, step_frac: f64) -> Vec<(f64, f64)> {
    let range = fmax - fmin;
    let mut out = Vec::new();
    if !(range > 0.0 && span_frac > 0.0 && step_frac > 0.0) {
        return out;
    }
    let mut lo = 0.0;
    while lo + span_frac <= 1.0 + 1e-9 {
        let (a, b) = (fmin + lo * range, fmin + (lo + span_frac) * range);
        let (xs, ys): (Vec<f64>, Vec<f64>) = f.iter().zip(v).filter(|(&fi, _)| fi >= a && fi <= b).map(|(&fi, &vi)| (fi, vi)).unzip();
        if xs.len() >= 5 {
            if let Some((c, _, _)) = ls_line(&xs, &ys) {
                out.push((xs.iter().sum::<f64>() / xs.len() as f64, (c_open - c) / c_open));
            }
        }
        lo += step_frac;
    }
    out
}

/// E647 X2 opening force from segment offsets: going up from the lowest segment, the force where
/// the offset first falls below criterion `k`, interpolated between the two segments' mean
/// forces; `fmin` when the lowest segment is already below it (no closure seen).
pub fn segment_opening_force(segments: &[(f64, f64)], k: f64, fmin: f64) -> f64 {
    for i in 0..segments.len() {
        let (fi, oi) = segments[i];
        if oi < k {
            if i == 0 {
                return fmin;
            }
            let (fp, op) = segments[i - 1];
            let t = (op - k) / (op - oi).max(1e-12);
            return fp + t * (fi - fp);
        }
    }
    segments.last().map(|s| s.0).unwrap_or(fmin)
}

/// Contiguous bursts of a record: index ranges where the cycle count steps by at most one.
pub fn bursts(cycle: &[f64]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut start = 0;
    for i in 1..=cycle.len() {
        let cut = i == cycle.len() || !(cycle[i] - cycle[i - 1] >= 0.0 && cycle[i] - cycle[i - 1] <= 1.0);
        if cut {
            if i > start {
                out.push((start, i));
            }
            start = i;
        }
    }
    out
}

/// Intervals for reduction: each burst, cut further into groups of `cycles_per_interval` cycles
/// (0: the whole burst; a continuous record is one long burst).
pub fn intervals(cycle: &[f64], cycles_per_interval: usize) -> Vec<(usize, usize)> {
    if cycles_per_interval == 0 {
        return bursts(cycle);
    }
    let n = cycles_per_interval as f64;
    let mut out = Vec::new();
    for (s, e) in bursts(cycle) {
        let c0 = cycle[s];
        let mut start = s;
        for i in s + 1..=e {
            if i == e || ((cycle[i] - c0) / n).floor() != ((cycle[i - 1] - c0) / n).floor() {
                out.push((start, i));
                start = i;
            }
        }
    }
    out
}

/// One measurement interval reduced.
#[derive(Debug, Clone, PartialEq)]
pub struct Interval {
    /// first cycle of the interval, and the number of cycles in it
    pub cycle: f64,
    pub n_cycles: usize,
    /// crack size [m] and its standard uncertainty from the fit [m] (NaN when not estimated)
    pub a_m: f64,
    pub a_std_m: f64,
    /// mean minimum and maximum force of the interval's cycles [N] (NaN without force)
    pub fmin_n: f64,
    pub fmax_n: f64,
    /// fully open compliance [m/N] (compliance methods) or mean potential [V]
    pub value: f64,
    /// opening forces at the 1, 2, 4 % offsets from the fitted curve, and at 2 % from E647's
    /// segments [N] (NaN for potential drop)
    pub opening_force_n: [f64; 3],
    pub opening_force_segments_n: f64,
    /// ΔK and ΔK_eff = K(Fmax) − K(max(F_op(2 %), Fmin)) [Pa·√m] (NaN without force)
    pub dk: f64,
    pub dk_eff: f64,
}

/// Per-cycle mean minimum and maximum of the force over an interval.
fn force_extremes(f: &[f64], cycle: &[f64]) -> (f64, f64) {
    let (mut mins, mut maxs) = (Vec::new(), Vec::new());
    let mut s = 0;
    for i in 1..=f.len() {
        if i == f.len() || cycle[i] != cycle[s] {
            let seg = f[s..i].iter().copied().filter(|x| x.is_finite());
            let (lo, hi) = seg.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| (lo.min(x), hi.max(x)));
            if lo.is_finite() && hi > lo {
                mins.push(lo);
                maxs.push(hi);
            }
            s = i;
        }
    }
    let mean = |v: &[f64]| if v.is_empty() { f64::NAN } else { v.iter().sum::<f64>() / v.len() as f64 };
    (mean(&mins), mean(&maxs))
}

/// Indices of the loading samples (force rising) of an interval: the sign of a centred difference
/// over ±k samples, k ~ 1/50 of a cycle's samples.
fn loading_samples(f: &[f64], cycle: &[f64]) -> Vec<usize> {
    let n = f.len();
    let ncyc = {
        let mut c = 1usize;
        for i in 1..n {
            if cycle[i] != cycle[i - 1] {
                c += 1;
            }
        }
        c
    };
    let k = (n / ncyc / 50).max(1);
    (0..n)
        .filter(|&i| {
            let (a, b) = (i.saturating_sub(k), (i + k).min(n - 1));
            b > a && f[b] > f[a] && f[i].is_finite()
        })
        .collect()
}

/// Reduce one interval of a load–opening record: fully open compliance (least squares over the
/// samples above the opening, at least the upper quarter of the range), crack size, the
/// opening forces and ΔK, ΔK_eff.
pub fn reduce_compliance_interval(spec: &Specimen, method: &Method, f: &[f64], cod: &[f64], cycle: &[f64]) -> Result<Interval> {
    if !method.is_compliance() {
        return Err(Error::Input(format!("{} is not a compliance method", method.describe())));
    }
    let (fmin, fmax) = force_extremes(f, cycle);
    if !(fmax > fmin) {
        return Err(Error::Input(format!("cycle {}: the force does not vary", cycle[0])));
    }
    let idx: Vec<usize> = loading_samples(f, cycle).into_iter().filter(|&i| cod[i].is_finite() && f[i] >= fmin && f[i] <= fmax).collect();
    let lf: Vec<f64> = idx.iter().map(|&i| f[i]).collect();
    let lv: Vec<f64> = idx.iter().map(|&i| cod[i]).collect();
    let closure = fit_closure(&lf, &lv, fmin, fmax)?;
    let range = fmax - fmin;
    // fully open: above where the fitted offset falls under 0.25 % (plus 5 % of the range), and
    // never less than the upper quarter
    let f_open = closure.opening_force(0.0025, fmin, fmax) + 0.05 * range;
    let lower = f_open.clamp(fmin + 0.1 * range, fmin + 0.75 * range);
    // both branches above the opening: the crack is open on loading and unloading alike there
    let (xs, ys): (Vec<f64>, Vec<f64>) = f.iter().zip(cod).filter(|(&x, &y)| x >= lower && x <= fmax && y.is_finite()).map(|(&x, &y)| (x, y)).unzip();
    let (c_open, _, c_se) = ls_line(&xs, &ys).ok_or_else(|| Error::Input(format!("cycle {}: too few samples above the opening force", cycle[0])))?;
    if !(c_open > 0.0) {
        return Err(Error::Input(format!("cycle {}: the opening falls as the force rises (gauge sign or channel wrong?)", cycle[0])));
    }
    let a = crack_size(spec, method, c_open)?;
    let a_hi = crack_size(spec, method, c_open + c_se).unwrap_or(f64::NAN);
    let fit = ClosureFit { c_open, ..closure };
    let ops = OFFSET_CRITERIA.map(|k| fit.opening_force(k, fmin, fmax));
    let segs = segment_offsets(&lf, &lv, fmin, fmax, c_open, 0.1, 0.05);
    let op_seg = segment_opening_force(&segs, 0.02, fmin);
    let (dk, dk_eff) = delta_k(spec, a, fmin, fmax, ops[1]);
    Ok(Interval {
        cycle: cycle[0],
        n_cycles: count_cycles(cycle),
        a_m: a,
        a_std_m: (a_hi - a).abs(),
        fmin_n: fmin,
        fmax_n: fmax,
        value: c_open,
        opening_force_n: ops,
        opening_force_segments_n: op_seg,
        dk,
        dk_eff,
    })
}

fn count_cycles(cycle: &[f64]) -> usize {
    1 + cycle.windows(2).filter(|w| w[1] != w[0]).count()
}

/// ΔK (E647: Pmax − Pmin for R ≥ 0, Pmax for R < 0) and ΔK_eff = K(Fmax) − K(max(F_op, Fmin, 0)).
pub fn delta_k(spec: &Specimen, a: f64, fmin: f64, fmax: f64, f_op: f64) -> (f64, f64) {
    let k = |p: f64| spec.k(a, p).unwrap_or(f64::NAN);
    let dk = k(fmax - fmin.max(0.0));
    let lo = if f_op.is_finite() { f_op.max(fmin).max(0.0) } else { fmin.max(0.0) };
    (dk, k(fmax - lo))
}

/// Reduce one interval of a potential-drop record: the mean potential over the interval (E647
/// allows averaging a few readings), crack size, and ΔK when the force is recorded.
pub fn reduce_potential_interval(spec: &Specimen, method: &Method, v: &[f64], f: Option<&[f64]>, cycle: &[f64]) -> Result<Interval> {
    let vals: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if vals.is_empty() {
        return Err(Error::Input(format!("cycle {}: no potential readings", cycle[0])));
    }
    let n = vals.len() as f64;
    let mean = vals.iter().sum::<f64>() / n;
    let sd = (vals.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0)).sqrt();
    let a = crack_size(spec, method, mean)?;
    let a_hi = crack_size(spec, method, mean + sd / n.sqrt()).unwrap_or(f64::NAN);
    let (fmin, fmax) = f.map(|f| force_extremes(f, cycle)).unwrap_or((f64::NAN, f64::NAN));
    let (dk, _) = if fmax > fmin { delta_k(spec, a, fmin, fmax, f64::NAN) } else { (f64::NAN, f64::NAN) };
    Ok(Interval {
        cycle: cycle[0],
        n_cycles: count_cycles(cycle),
        a_m: a,
        a_std_m: (a_hi - a).abs(),
        fmin_n: fmin,
        fmax_n: fmax,
        value: mean,
        opening_force_n: [f64::NAN; 3],
        opening_force_segments_n: f64::NAN,
        dk,
        dk_eff: dk,
    })
}

/// Reduce a whole record: one `Interval` per burst (cut into `cycles_per_interval` groups).
/// `cod` for compliance methods, `dcpd_v` for potential drop.
pub fn reduce_record(spec: &Specimen, method: &Method, cycle: &[f64], f: Option<&[f64]>, signal: &[f64], cycles_per_interval: usize) -> Result<Vec<Interval>> {
    if cycle.len() != signal.len() || f.is_some_and(|f| f.len() != signal.len()) {
        return Err(Error::Input("columns differ in length".into()));
    }
    let mut out = Vec::new();
    let mut method = method.clone();
    for (s, e) in intervals(cycle, cycles_per_interval) {
        // a potential-drop reference not given: the first interval's mean potential at the reference crack
        if let Method::Johnson { v_ref, .. } | Method::Calibration { v_ref, .. } = &mut method {
            if !v_ref.is_finite() {
                let vals: Vec<f64> = signal[s..e].iter().copied().filter(|x| x.is_finite()).collect();
                *v_ref = vals.iter().sum::<f64>() / vals.len().max(1) as f64;
            }
        }
        let method = &method;
        let r = if method.is_compliance() {
            let f = f.ok_or_else(|| Error::Input("compliance needs the force column `f`".into()))?;
            reduce_compliance_interval(spec, method, &f[s..e], &signal[s..e], &cycle[s..e])
        } else {
            reduce_potential_interval(spec, method, &signal[s..e], f.map(|f| &f[s..e]), &cycle[s..e])
        };
        out.push(r.map_err(|err| match err {
            Error::Parameter { field, value, allowed } => Error::Input(format!("interval at cycle {}: `{field}` = {value} is out of range {allowed}", cycle[s])),
            other => other,
        })?);
    }
    Ok(out)
}

/// E647's linear correction of measured crack sizes to the visual initial and final cracks:
/// the difference between visual and measured size at the first and last point, distributed
/// linearly in the measured crack size between them. Returns the corrected sizes.
pub fn correct_to_visual(a_measured: &[f64], a0_visual: f64, af_visual: f64) -> Result<Vec<f64>> {
    let n = a_measured.len();
    if n < 2 {
        return Err(Error::Input("the correction needs at least two measured crack sizes".into()));
    }
    if !(a0_visual.is_finite() && af_visual.is_finite() && af_visual > a0_visual && a0_visual > 0.0) {
        return Err(Error::Input(format!("visual crack sizes a0 = {a0_visual} m, af = {af_visual} m: need 0 < a0 < af")));
    }
    let (m0, mf) = (a_measured[0], a_measured[n - 1]);
    if !(mf > m0) {
        return Err(Error::Input("the measured crack does not grow from the first to the last point".into()));
    }
    let (e0, ef) = (a0_visual - m0, af_visual - mf);
    Ok(a_measured.iter().map(|&a| a + e0 + (ef - e0) * (a - m0) / (mf - m0)).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::specimen::{compliance_ct_dimensionless, Material};

    #[test]
    fn ct_load_line_expression_matches_e1820_forward_form() {
        // E647's load-line polynomial against ASTM E1820's forward compliance (plane stress E):
        // two independent fits of the same solution agree to better than 0.3 % in a/W
        for i in 0..=70 {
            let alpha = 0.25 + 0.01 * i as f64;
            let ebc = compliance_ct_dimensionless(alpha);
            let back = ct_alpha_from_compliance(ebc, 0.0).unwrap();
            assert!((back - alpha).abs() < 0.003, "α {alpha}: E647 gives {back}");
        }
    }

    #[test]
    fn ct_round_trip_every_location() {
        for (x, _) in CT_COMPLIANCE {
            for i in 0..=15 {
                let alpha = 0.2 + 0.05 * i as f64;
                let ebc = ct_compliance_from_alpha(alpha, x).unwrap();
                assert!((ct_alpha_from_compliance(ebc, x).unwrap() - alpha).abs() < 1e-9);
            }
        }
        // the crack mouth opens more than the load line at the same crack
        assert!(ct_compliance_from_alpha(0.5, -0.25).unwrap() > ct_compliance_from_alpha(0.5, 0.0).unwrap());
    }

    #[test]
    fn mt_uncracked_strip_is_the_gauge_strain_and_inverse_holds() {
        let ebc0 = mt_compliance_dimensionless(0.0, 0.2, 0.3);
        assert!((ebc0 - 0.4).abs() < 1e-12, "{ebc0}");
        for i in 1..=18 {
            let alpha = 0.05 * i as f64;
            let e = mt_compliance_dimensionless(alpha, 0.2, 0.3);
            assert!((mt_alpha_from_compliance(e, 0.2, 0.3).unwrap() - alpha).abs() < 1e-9);
        }
    }

    #[test]
    fn mt_far_field_opening_matches_the_energy_release_of_the_same_stress_function() {
        // Castigliano: far from the crack (Y/W = 2) the crack's share of E·B·V/P is
        // 2·∫ tan(πt/2) dt over 2a/W, the energy release of Irwin's periodic-crack K
        // (K² = σ²·W·tan(πa/W)); the closed form must give the same
        for &alpha in &[0.2, 0.4, 0.6, 0.8] {
            let d = mt_compliance_dimensionless(alpha, 2.0, 0.3) - mt_compliance_dimensionless(0.0, 2.0, 0.3);
            let e = -4.0 / PI * (PI * alpha / 2.0).cos().ln();
            assert!((d - e).abs() < 2e-4 * e.max(0.1), "2a/W {alpha}: {d} vs {e}");
        }
    }

    #[test]
    fn johnson_round_trip_and_reference_point() {
        let (w, y, ar) = (0.1, 0.005, 0.01);
        assert!((johnson_a(1.0, w, y, ar).unwrap() - ar).abs() < 1e-12);
        for i in 1..9 {
            let a = 0.005 * i as f64;
            let r = johnson_v_ratio(a, w, y, ar);
            assert!((johnson_a(r, w, y, ar).unwrap() - a).abs() < 1e-10);
        }
    }

    #[test]
    fn closure_fit_finds_a_kink_and_no_closure() {
        let (c, fmin, fmax, fk) = (1e-8, 500.0, 10000.0, 3000.0);
        let f: Vec<f64> = (0..400).map(|i| fmin + (fmax - fmin) * i as f64 / 399.0).collect();
        let v: Vec<f64> = f.iter().map(|&x| if x > fk { c * x } else { c * fk - 0.6 * c * (fk - x) }).collect();
        let fit = fit_closure(&f, &v, fmin, fmax).unwrap();
        assert!((fit.c_open - c).abs() / c < 1e-3);
        assert!((fit.opening_force(0.02, fmin, fmax) - fk).abs() < 0.01 * fmax, "{fit:?}");
        let v: Vec<f64> = f.iter().map(|&x| c * x + 1e-6).collect();
        let fit = fit_closure(&f, &v, fmin, fmax).unwrap();
        assert_eq!(fit.opening_force(0.02, fmin, fmax), fmin);
    }

    #[test]
    fn correction_meets_both_visual_sizes() {
        let a = [0.010, 0.012, 0.015, 0.020];
        let c = correct_to_visual(&a, 0.0105, 0.0212).unwrap();
        assert!((c[0] - 0.0105).abs() < 1e-15 && (c[3] - 0.0212).abs() < 1e-15);
        assert!(c.windows(2).all(|w| w[1] > w[0]));
        let _ = Material::default();
    }
}
