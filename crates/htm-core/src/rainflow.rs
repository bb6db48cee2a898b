//! Rainflow counting of a load history (ASTM E1049-85, 5.4.4): the variable-amplitude report's
//! cycle count.

/// The turning points of `series` (plateaus and non-reversing points dropped; ends kept).
pub fn reversals(series: &[f64]) -> Vec<f64> {
    let mut out: Vec<f64> = Vec::with_capacity(series.len());
    for &x in series.iter().filter(|x| x.is_finite()) {
        match out.len() {
            0 => out.push(x),
            1 => {
                if x != out[0] {
                    out.push(x)
                }
            }
            n => {
                let (a, b) = (out[n - 2], out[n - 1]);
                if (b - a) * (x - b) > 0.0 {
                    out[n - 1] = x; // still rising (or falling): b was no turning point
                } else if x != b {
                    out.push(x);
                }
            }
        }
    }
    out
}

/// Cycles of `series` as (range, mean, count) with count 1 (full cycle) or 0.5 (half cycle).
pub fn rainflow(series: &[f64]) -> Vec<(f64, f64, f64)> {
    let mut out = Vec::new();
    let mut stack: Vec<f64> = Vec::new();
    for r in reversals(series) {
        stack.push(r);
        while stack.len() >= 3 {
            let n = stack.len();
            let x = (stack[n - 1] - stack[n - 2]).abs();
            let y = (stack[n - 2] - stack[n - 3]).abs();
            if x < y {
                break;
            }
            let mean = 0.5 * (stack[n - 2] + stack[n - 3]);
            if n == 3 {
                // y holds the start point: a half cycle, and the start moves on
                out.push((y, mean, 0.5));
                stack.remove(0);
            } else {
                out.push((y, mean, 1.0));
                stack.drain(n - 3..n - 1);
            }
        }
    }
    for w in stack.windows(2) {
        out.push(((w[1] - w[0]).abs(), 0.5 * (w[0] + w[1]), 0.5));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn astm_e1049_example_is_counted_as_the_standard_counts_it() {
        // E1049-85 Fig. 6: -2 1 -3 5 -1 3 -4 4 -2 → ranges 3 (½), 4 (½ + 1), 6 (½), 8 (1 + ½), 9 (½)
        let c = rainflow(&[-2.0, 1.0, -3.0, 5.0, -1.0, 3.0, -4.0, 4.0, -2.0]);
        let count = |r: f64| c.iter().filter(|x| x.0 == r).map(|x| x.2).sum::<f64>();
        assert_eq!((count(3.0), count(4.0), count(6.0), count(8.0), count(9.0)), (0.5, 1.5, 0.5, 1.0, 0.5));
        assert_eq!(c.iter().map(|x| x.2).sum::<f64>(), 4.0);
        assert_eq!(reversals(&[0.0, 1.0, 2.0, 2.0, 1.0, 3.0]), vec![0.0, 2.0, 1.0, 3.0]);
    }
}
