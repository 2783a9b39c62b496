//! Point tables (x_i, y_i): linear interpolation between points and the end value held
//! outside the range, as seed 004 specifies for cross tables and as pitch-error tables
//! behave on real controls. Shared by the plant (measured lead error) and the compensations.

/// Interpolates `points` (x strictly increasing) at `x`; holds the end values outside.
/// An empty table is 0; a NaN `x` gives NaN.
#[inline]
pub fn interp(points: &[(f64, f64)], x: f64) -> f64 {
    interp_slope(points, x).0
}

/// [`interp`] at `x` and the slope dy/dx of the segment `x` falls in (0 outside the range,
/// where the end value is held). The value is exactly [`interp`]'s.
#[inline]
pub fn interp_slope(points: &[(f64, f64)], x: f64) -> (f64, f64) {
    let (Some(first), Some(last)) = (points.first(), points.last()) else {
        return (0.0, 0.0);
    };
    if x.is_nan() {
        // A diverged state (a replay the fit drove unstable): no point to hold, and the
        // NaN must reach the caller's finiteness check rather than index before the table.
        return (f64::NAN, f64::NAN);
    }
    if x <= first.0 {
        return (first.1, 0.0);
    }
    if x >= last.0 {
        return (last.1, 0.0);
    }
    // First point with x_i > x; it exists because x < last.0.
    let i = points.partition_point(|p| p.0 <= x);
    let (x0, y0) = points[i - 1];
    let (x1, y1) = points[i];
    (y0 + (x - x0) / (x1 - x0) * (y1 - y0), (y1 - y0) / (x1 - x0))
}

/// Problems with a table, each as (path, reason): non-finite values, x not strictly
/// increasing, fewer than `min_points` points.
pub fn check(path: &str, points: &[(f64, f64)], min_points: usize) -> Vec<(String, String)> {
    let mut out = Vec::new();
    if points.len() < min_points {
        out.push((
            path.to_owned(),
            format!("needs at least {min_points} points, has {}", points.len()),
        ));
    }
    for (i, &(x, y)) in points.iter().enumerate() {
        if !x.is_finite() || !y.is_finite() {
            out.push((format!("{path}[{i}]"), format!("({x}, {y}) is not finite")));
        }
        if i > 0 && x.is_finite() && points[i - 1].0.is_finite() && x <= points[i - 1].0 {
            out.push((
                format!("{path}[{i}]"),
                format!(
                    "x = {x} is not greater than the previous x = {}; x must be strictly increasing",
                    points[i - 1].0
                ),
            ));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_nan_position_gives_nan_not_a_panic() {
        let t = [(0.0, 1.0), (1.0, 3.0)];
        assert!(super::interp(&t, f64::NAN).is_nan());
        assert_eq!(super::interp(&t, 0.5), 2.0);
        assert_eq!(super::interp(&t, -1.0), 1.0);
        assert_eq!(super::interp(&t, 2.0), 3.0);
        assert_eq!(super::interp_slope(&t, 0.5), (2.0, 2.0));
        assert_eq!(super::interp_slope(&t, 2.0), (3.0, 0.0));
    }
}
