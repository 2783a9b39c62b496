//! Point tables (x_i, y_i): linear interpolation between points and the end value held outside the
//! range, as the cross-table patent (SPEC §6) specifies for cross tables and as pitch-error tables
//! behave on real controls. Shared by the plant (measured lead error) and the compensations.

use std::cell::Cell;

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
    ends(points, x).unwrap_or_else(|| on_segment(points, points.partition_point(|p| p.0 <= x), x))
}

/// [`interp_slope`], searching first around `hint`, the segment found last (updated): a
/// position moves by a fraction of a segment per control period, so the segment is nearly
/// always that one or a neighbour, and a replay looks its lead table up every period. The
/// segment is the same one either way, so the value is exactly [`interp_slope`]'s.
#[inline]
pub fn interp_slope_near(points: &[(f64, f64)], x: f64, hint: &Cell<usize>) -> (f64, f64) {
    if let Some(v) = ends(points, x) {
        return v;
    }
    // The segment i with x_{i-1} <= x < x_i.
    let holds = |i: usize| i >= 1 && i < points.len() && points[i - 1].0 <= x && x < points[i].0;
    let h = hint.get();
    let i = [h, h + 1, h.wrapping_sub(1)]
        .into_iter()
        .find(|&i| holds(i))
        .unwrap_or_else(|| points.partition_point(|p| p.0 <= x));
    hint.set(i);
    on_segment(points, i, x)
}

/// The value and slope at `x` when it lies outside the points (or is NaN, or the table is
/// empty); None when it lies strictly inside.
#[inline]
fn ends(points: &[(f64, f64)], x: f64) -> Option<(f64, f64)> {
    let (Some(first), Some(last)) = (points.first(), points.last()) else {
        return Some((0.0, 0.0));
    };
    if x.is_nan() {
        // A diverged state (a replay the fit drove unstable): no point to hold, and the
        // NaN must reach the caller's finiteness check rather than index before the table.
        return Some((f64::NAN, f64::NAN));
    }
    if x <= first.0 {
        return Some((first.1, 0.0));
    }
    if x >= last.0 {
        return Some((last.1, 0.0));
    }
    None
}

/// The value and slope on segment `i` (from point i − 1 to point i, 1 <= i < len).
#[inline]
fn on_segment(points: &[(f64, f64)], i: usize, x: f64) -> (f64, f64) {
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

    #[test]
    fn the_search_from_the_last_segment_finds_what_the_full_search_finds() {
        // Uneven knots, positions that creep forward, jump back, cross a knot exactly, and
        // leave the table on both sides: every lookup equals the full search bit for bit.
        let t: Vec<(f64, f64)> = (0..40)
            .map(|i| {
                let x = f64::from(i) * 0.7 + 0.05 * f64::from(i * i % 7);
                (x, (x * 1.3).sin())
            })
            .collect();
        let hint = std::cell::Cell::new(0);
        let xs = (0..2000)
            .map(|k| f64::from(k) * 0.015 - 1.0)
            .chain([10.5, 3.2, 3.2, t[7].0, t[8].0, -5.0, 99.0, 20.0, 19.99, 0.0]);
        let mut jumps = 0;
        for x in xs {
            let before = hint.get();
            assert_eq!(
                super::interp_slope_near(&t, x, &hint).0.to_bits(),
                super::interp_slope(&t, x).0.to_bits(),
                "x = {x}"
            );
            assert_eq!(
                super::interp_slope_near(&t, x, &hint),
                super::interp_slope(&t, x)
            );
            jumps += usize::from(hint.get().abs_diff(before) > 1);
        }
        // The hint followed the creeping positions (only the jumps searched afresh).
        assert!(jumps <= 6, "{jumps} full searches");
    }
}
