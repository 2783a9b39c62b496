//! The physically meaningful ranges of the numbers that cross the boundary to a controller.
//!
//! The importer rejects a number outside them before it reaches the model (a
//! `MAX_ACCELERATION` of 1e-300 would make an acc/dec filter of 1e301 s, which no machine
//! has and no simulation can allocate), and every export checks the same ranges on what it
//! is about to write, so an export our own import would reject is refused before anything
//! is written. The bounds are generous — far outside any real machine tool — so they only
//! catch nonsense, never an unusual machine.

use super::entry::{show, with_unit};
use super::{Ctx, Violation};
use crate::preset::AccDecKind;

/// A closed range of one kind of quantity, with its unit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Range {
    /// What the quantity is, for messages.
    pub what: &'static str,
    /// Smallest allowed value.
    pub min: f64,
    /// Largest allowed value.
    pub max: f64,
    /// Unit of `min`, `max` and the checked value.
    pub unit: &'static str,
}

impl Range {
    /// `Ok(x)` when `x` is finite and inside the range, else why not (value and range).
    pub fn check(&self, x: f64) -> Result<f64, String> {
        if !x.is_finite() {
            return Err(format!("{} is not a finite number", show(x)));
        }
        if x < self.min || x > self.max {
            return Err(format!(
                "{} is outside the allowed range {} ({})",
                with_unit(x, self.unit),
                self.text(),
                self.what
            ));
        }
        Ok(x)
    }

    /// "0…10 mm".
    pub fn text(&self) -> String {
        format!("{}…{} {}", show(self.min), show(self.max), self.unit)
    }
}

/// Axis velocity limit (LinuxCNC MAX_VELOCITY): 0.06 mm/min … 600 m/min.
pub const VELOCITY_MM_S: Range = Range {
    what: "axis velocity limit",
    min: 0.001,
    max: 10_000.0,
    unit: "mm/s",
};

/// Axis acceleration limit (LinuxCNC MAX_ACCELERATION): up to about 100 g.
pub const ACCELERATION_MM_S2: Range = Range {
    what: "axis acceleration limit",
    min: 0.01,
    max: 1_000_000.0,
    unit: "mm/s²",
};

/// Acc/dec time constant: the rapid velocity over the acceleration limit. Ten seconds is
/// already far beyond any feed axis; the filter's length grows with it.
pub const ACCDEC_TIME_S: Range = Range {
    what: "acc/dec time constant = velocity / acceleration limit",
    min: 0.0,
    max: 10.0,
    unit: "s",
};

/// Backlash (lost motion) of an axis.
pub const BACKLASH_MM: Range = Range {
    what: "backlash",
    min: 0.0,
    max: 10.0,
    unit: "mm",
};

/// A compensation value (pitch-error trim, sag correction).
pub const TRIM_MM: Range = Range {
    what: "compensation value",
    min: -10.0,
    max: 10.0,
    unit: "mm",
};

/// A machine position (table point, travel end): ±100 m.
pub const POSITION_MM: Range = Range {
    what: "machine position",
    min: -100_000.0,
    max: 100_000.0,
    unit: "mm",
};

/// The same ranges on what an export is about to write, named by preset field and value.
pub(crate) fn check_export(ctx: &Ctx) -> Vec<Violation> {
    let mut bad = Vec::new();
    let mut tables = Vec::new();
    let p = ctx.preset;
    let mut push = |field: String, r: Result<f64, String>| {
        if let Err(reason) = r {
            bad.push(Violation::new(field, reason));
        }
    };
    let tau = match p.nc.accdec.kind {
        AccDecKind::None => 0.0,
        AccDecKind::Linear => p.nc.accdec.tc1_s,
        AccDecKind::Bell => p.nc.accdec.tc1_s.max(p.nc.accdec.tc2_s),
    };
    let gives = |what: &str, r: Result<f64, String>| {
        r.map_err(|reason| format!("the {what} it gives: {reason}"))
    };
    if let Some(ax) = ctx.axes.first() {
        push(
            "nc.rapid_mm_per_min".into(),
            gives(
                "velocity limit",
                VELOCITY_MM_S.check(ax.limits.max_vel_mm_s),
            ),
        );
        push("nc.accdec".into(), ACCDEC_TIME_S.check(tau));
    }
    for (i, a) in p.axes.iter().enumerate() {
        let d = &ctx.axes[i];
        let acc_field = if tau > 0.0 {
            "nc.accdec".to_owned()
        } else {
            format!("axes.{}.servo.torque_limit_nm", a.name)
        };
        push(
            acc_field,
            gives(
                "acceleration limit",
                ACCELERATION_MM_S2.check(d.limits.max_acc_mm_s2),
            ),
        );
        if a.backlash.enabled {
            push(
                format!("axes.{}.backlash.q_um", a.name),
                BACKLASH_MM.check(crate::units::um_to_mm(a.backlash.q_um)),
            );
        }
        for x in [d.travel_mm.0, d.travel_mm.1] {
            push(
                "scenario.programs".into(),
                gives("travel", POSITION_MM.check(x)),
            );
        }
        if a.lead_error.enabled {
            tables.extend(lead_error(ctx, i));
        }
    }
    for (ci, t) in p.cross.iter().enumerate().filter(|(_, t)| t.enabled) {
        tables.extend(points(&format!("cross.{ci}.points"), &t.points));
    }
    bad.extend(tables);
    bad.dedup();
    bad
}

/// Table points (mm, µm) against the position and compensation ranges.
fn points(field: &str, pts: &[(f64, f64)]) -> Vec<Violation> {
    let mut bad = Vec::new();
    for (k, &(x, v_um)) in pts.iter().enumerate() {
        if let Err(r) = POSITION_MM.check(x) {
            bad.push(Violation::new(format!("{field}.{k}"), r));
        }
        if let Err(r) = TRIM_MM.check(crate::units::um_to_mm(v_um)) {
            bad.push(Violation::new(format!("{field}.{k}"), r));
        }
    }
    bad
}

/// The lead error a pitch table must cancel, over the travel: each part on its own, and
/// the sum, within the compensation range. Naming the part that breaks it points at the
/// field to fix (`cumulative_um_per_m = 1e300` rather than "the table").
fn lead_error(ctx: &Ctx, i: usize) -> Vec<Violation> {
    let a = &ctx.preset.axes[i];
    let l = &a.lead_error;
    let (lo, hi) = ctx.axes[i].travel_mm;
    let reach_mm = lo.abs().max(hi.abs());
    let um = crate::units::um_to_mm;
    let parts = [
        (
            "amplitude_um",
            l.amplitude_um.abs(),
            with_unit(l.amplitude_um, "µm"),
        ),
        (
            "cumulative_um_per_m",
            (l.cumulative_um_per_m * crate::units::mm_to_m(reach_mm)).abs(),
            with_unit(l.cumulative_um_per_m, "µm/m"),
        ),
    ];
    let mut bad = Vec::new();
    for (name, peak_um, value) in parts {
        if let Err(r) = TRIM_MM.check(um(peak_um)) {
            bad.push(Violation::new(
                format!("axes.{}.lead_error.{name}", a.name),
                format!(
                    "{value} gives a lead error of up to {} µm over the travel {lo}…{hi} mm: {r}",
                    show(peak_um)
                ),
            ));
        }
    }
    bad.extend(points(
        &format!("axes.{}.lead_error.table", a.name),
        &l.table,
    ));
    if bad.is_empty() {
        let n = 2000;
        let peak_um = (0..=n)
            .map(|k| lo + (hi - lo) * k as f64 / n as f64)
            .map(|x| super::lead_error_um(l, x).abs())
            .fold(0.0, f64::max);
        if let Err(r) = TRIM_MM.check(um(peak_um)) {
            bad.push(Violation::new(
                format!("axes.{}.lead_error", a.name),
                format!(
                    "the lead error reaches {} µm over the travel {lo}…{hi} mm: {r}",
                    show(peak_um)
                ),
            ));
        }
    }
    bad
}
