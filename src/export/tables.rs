//! Position tables every target derives: the lead error a pitch table cancels, the table
//! itself and its residual, and equidistant resampling for controls with one spacing.

use crate::preset::LeadError;
use crate::units::mm_to_m;

/// The preset's lead (pitch) error at screw position `x_mm`, µm: the cyclic part, the
/// cumulative lead deviation and the measured table, as the plant applies them.
pub fn lead_error_um(l: &LeadError, x_mm: f64) -> f64 {
    if !l.enabled {
        return 0.0;
    }
    let turns = x_mm / l.period_mm + l.phase_deg / 360.0;
    l.amplitude_um * (std::f64::consts::TAU * turns).sin()
        + l.cumulative_um_per_m * mm_to_m(x_mm)
        + crate::table::interp(&l.table, x_mm)
}

/// A pitch-error compensation table: (position mm, correction µm = −lead error).
#[derive(Debug, Clone, PartialEq)]
pub struct PitchTable {
    /// (position mm, correction µm).
    pub points: Vec<(f64, f64)>,
    /// Largest |lead error + table correction| over the travel, µm (0 = exact).
    pub residual_um: f64,
    /// Whether the points have one spacing.
    pub equidistant: bool,
}

/// The table that cancels the preset's lead error over `travel`, with at most `max_points`
/// points; `equidistant` for controls whose tables have one spacing (SINUMERIK, FANUC).
/// The measured table's own points are used when they fit and the error is piecewise
/// linear (then the table is exact); otherwise a uniform grid as fine as the limit allows
/// (32 points per cyclic period are enough for a 0.5 % residual).
pub fn pitch_table(
    l: &LeadError,
    travel: (f64, f64),
    max_points: usize,
    equidistant: bool,
) -> PitchTable {
    let (lo, hi) = travel;
    let piecewise_linear = l.amplitude_um == 0.0;
    let mut xs: Vec<f64> = Vec::new();
    if piecewise_linear && !equidistant {
        xs.push(lo);
        xs.extend(l.table.iter().map(|p| p.0));
        xs.push(hi);
        xs.sort_by(f64::total_cmp);
        xs.dedup();
    }
    if xs.is_empty() || xs.len() > max_points {
        let width = hi - lo;
        let wanted = if !piecewise_linear {
            (width / (l.period_mm / 32.0)).ceil() as usize + 1
        } else if l.table.len() >= 2 {
            let min_gap = l
                .table
                .windows(2)
                .map(|w| w[1].0 - w[0].0)
                .fold(f64::INFINITY, f64::min);
            (width / min_gap).ceil() as usize + 1
        } else {
            2
        };
        let n = wanted.clamp(2, max_points.max(2));
        let step = width / (n - 1) as f64;
        xs = (0..n).map(|i| lo + step * i as f64).collect();
        if let Some(last) = xs.last_mut() {
            *last = hi;
        }
    }
    let points: Vec<(f64, f64)> = xs.iter().map(|&x| (x, -lead_error_um(l, x))).collect();
    let residual = residual_um(l, &points, travel);
    PitchTable {
        points,
        residual_um: residual,
        equidistant,
    }
}

/// Largest |lead error + correction| over the travel, evaluated on 20 000 points plus every
/// table point (the correction interpolated with its ends held, as every target does).
pub fn residual_um(l: &LeadError, points: &[(f64, f64)], travel: (f64, f64)) -> f64 {
    let (lo, hi) = travel;
    let n = 20_000;
    (0..=n)
        .map(|i| lo + (hi - lo) * i as f64 / n as f64)
        .chain(points.iter().map(|p| p.0))
        .map(|x| (lead_error_um(l, x) + crate::table::interp(points, x)).abs())
        .fold(0.0, f64::max)
}

/// A point table on an equidistant grid, for controls whose tables have one spacing: the
/// table itself when its points are equidistant, else resampled at its smallest spacing
/// (at most `max_points`). Returns (points, spacing, largest interpolation change µm or
/// table unit).
pub fn equidistant(points: &[(f64, f64)], max_points: usize) -> (Vec<(f64, f64)>, f64, f64) {
    let (Some(first), Some(last)) = (points.first(), points.last()) else {
        return (vec![], 0.0, 0.0);
    };
    if points.len() < 2 {
        return (points.to_vec(), 1.0, 0.0);
    }
    let width = last.0 - first.0;
    let step0 = points[1].0 - points[0].0;
    let regular = points
        .windows(2)
        .all(|w| ((w[1].0 - w[0].0) - step0).abs() <= 1e-9 * width.max(1.0));
    if regular {
        return (points.to_vec(), step0, 0.0);
    }
    let min_gap = points
        .windows(2)
        .map(|w| w[1].0 - w[0].0)
        .fold(f64::INFINITY, f64::min);
    let n = ((width / min_gap).ceil() as usize + 1).clamp(2, max_points.max(2));
    let step = width / (n - 1) as f64;
    let out: Vec<(f64, f64)> = (0..n)
        .map(|i| {
            let x = if i + 1 == n {
                last.0
            } else {
                first.0 + step * i as f64
            };
            (x, crate::table::interp(points, x))
        })
        .collect();
    let m = 20_000;
    let err = (0..=m)
        .map(|i| first.0 + width * i as f64 / m as f64)
        .chain(points.iter().map(|p| p.0))
        .map(|x| (crate::table::interp(points, x) - crate::table::interp(&out, x)).abs())
        .fold(0.0, f64::max);
    (out, step, err)
}
