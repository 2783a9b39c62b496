//! Units of trace columns: what each measures, its SI unit, and how a file's number in it
//! becomes the SI value a trace holds.
//!
//! Units that are a power of ten of SI (mm, um, ms, mm/s) carry that power ([`Unit::pow10`]),
//! so the reader and the writer move the decimal point of the text instead of multiplying a
//! float: a value written and read back is the same `f64`, bit for bit.

use super::{QUOTE_CHARS, quote};
use crate::signal::{AxisSignal, Quantity};
use crate::units;

/// An accepted unit: what it measures and how its values become SI.
#[derive(Debug, Clone, Copy)]
pub struct Unit {
    /// As written in a header, e.g. `mm/min`.
    pub name: &'static str,
    /// What it measures.
    pub quantity: Quantity,
    /// k when one of this unit is exactly 10^k of the SI unit (mm: −3, m: 0); None when the
    /// factor is not a power of ten (mm/min). With k, reading and writing shift the decimal
    /// point of the text, which is exact; without, they convert numerically.
    pub pow10: Option<i32>,
    /// Value in this unit → SI value (a named helper from [`crate::units`], never a bare
    /// factor), for units without [`Unit::pow10`] and for plotting.
    pub to_si: fn(f64) -> f64,
    /// SI value → value in this unit, for showing a value in it (plots, tables).
    pub from_si: fn(f64) -> f64,
}

impl Unit {
    /// The SI unit a trace holds values of this unit in.
    pub fn si(&self) -> &'static str {
        self.quantity.si_unit()
    }
}

fn same(v: f64) -> f64 {
    v
}

/// Every unit TRACE_FORMAT accepts.
pub const UNITS: &[Unit] = &[
    Unit {
        name: "m",
        quantity: Quantity::Length,
        pow10: Some(0),
        to_si: same,
        from_si: same,
    },
    Unit {
        name: "mm",
        quantity: Quantity::Length,
        pow10: Some(-3),
        to_si: units::mm_to_m,
        from_si: units::m_to_mm,
    },
    Unit {
        name: "um",
        quantity: Quantity::Length,
        pow10: Some(-6),
        to_si: units::um_to_m,
        from_si: units::m_to_um,
    },
    Unit {
        name: "s",
        quantity: Quantity::Time,
        pow10: Some(0),
        to_si: same,
        from_si: same,
    },
    Unit {
        name: "ms",
        quantity: Quantity::Time,
        pow10: Some(-3),
        to_si: units::ms_to_s,
        from_si: units::s_to_ms,
    },
    Unit {
        name: "m/s",
        quantity: Quantity::Velocity,
        pow10: Some(0),
        to_si: same,
        from_si: same,
    },
    Unit {
        name: "mm/s",
        quantity: Quantity::Velocity,
        pow10: Some(-3),
        to_si: units::mm_per_s_to_m_per_s,
        from_si: units::m_per_s_to_mm_per_s,
    },
    Unit {
        name: "mm/min",
        quantity: Quantity::Velocity,
        pow10: None,
        to_si: units::mm_per_min_to_m_per_s,
        from_si: units::m_per_s_to_mm_per_min,
    },
    Unit {
        name: "N",
        quantity: Quantity::Force,
        pow10: Some(0),
        to_si: same,
        from_si: same,
    },
    Unit {
        name: "N*m",
        quantity: Quantity::Torque,
        pow10: Some(0),
        to_si: same,
        from_si: same,
    },
    Unit {
        name: "A",
        quantity: Quantity::Current,
        pow10: Some(0),
        to_si: same,
        from_si: same,
    },
    Unit {
        name: "degC",
        quantity: Quantity::Temperature,
        pow10: Some(0),
        to_si: same,
        from_si: same,
    },
    Unit {
        name: "",
        quantity: Quantity::Plain,
        pow10: Some(0),
        to_si: same,
        from_si: same,
    },
];

/// The accepted unit called `name`, if any.
pub fn unit(name: &str) -> Option<&'static Unit> {
    UNITS.iter().find(|u| u.name == name)
}

/// The unit a signal held in SI unit `si` is shown in (mm for m, mm/s for m/s, itself
/// otherwise), for plots and the file header; None for a unit the trace format does not know.
pub fn display_unit_of(si: &str) -> Option<&'static Unit> {
    unit(unit(si)?.quantity.display_unit())
}

/// The units of one quantity, for messages: "m, mm, um".
fn unit_names(q: Quantity) -> String {
    UNITS
        .iter()
        .filter(|u| u.quantity == q)
        .map(|u| if u.name.is_empty() { "none" } else { u.name })
        .collect::<Vec<_>>()
        .join(", ")
}

/// The accepted units, for messages.
fn all_unit_names() -> String {
    UNITS
        .iter()
        .filter(|u| !u.name.is_empty())
        .map(|u| u.name)
        .collect::<Vec<_>>()
        .join(", ")
}

/// What the unit of signal `name` must measure: `t` a time, `mode` (and `mode.<channel>`)
/// nothing, `temp.<name>` a temperature, `<axis>.<signal>` per [`AxisSignal`]. None
/// for a signal it does not know, which keeps any accepted unit.
pub fn expected_quantities(name: &str) -> Option<&'static [Quantity]> {
    if name == "t" {
        return Some(&[Quantity::Time]);
    }
    if name == "mode" || name.starts_with("mode.") {
        return Some(&[Quantity::Plain]);
    }
    if name.starts_with("temp.") {
        return Some(&[Quantity::Temperature]);
    }
    let (_, signal) = name.split_once('.')?;
    AxisSignal::from_name(signal).map(AxisSignal::quantities)
}

/// Checks that unit `unit_name` is accepted and fits signal `name`; the reason when not.
pub fn check_unit(name: &str, unit_name: &str) -> Result<&'static Unit, String> {
    let u = unit(unit_name).ok_or_else(|| {
        format!(
            "unit '{}' is not accepted ({})",
            quote(unit_name, QUOTE_CHARS),
            all_unit_names()
        )
    })?;
    match expected_quantities(name) {
        Some(qs) if !qs.contains(&u.quantity) => {
            let want: Vec<String> = qs
                .iter()
                .map(|q| format!("{} ({})", q.name(), unit_names(*q)))
                .collect();
            Err(format!(
                "{} is {}, not {} ('{}')",
                quote(name, QUOTE_CHARS),
                want.join(" or "),
                u.quantity.name(),
                u.name
            ))
        }
        _ => Ok(u),
    }
}
