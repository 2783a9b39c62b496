//! Cross (sag) compensation tables (cross-table patent, SPEC §6).
//!
//! Each table maps the position x_s of a base axis to a correction ΔZ of a compensated
//! axis: between points (x_i, ΔZ_i) and (x_{i+1}, ΔZ_{i+1}),
//! ΔZ = ΔZ_i + (x_s − x_i)/(x_{i+1} − x_i)·(ΔZ_{i+1} − ΔZ_i), and Z_u = Z_s + ΔZ is
//! commanded. Outside the table the end value is held (the seed is silent; holding is what
//! pitch and cross tables do on FANUC and Siemens controls, and it never extrapolates a
//! deflection past the last measured point). Several tables may act at once: a left and a
//! right tool post, several channels, or two tables adding onto one axis.
//!
//! The base position is the base axis's uncompensated command, as the NC knows it when it
//! generates the command, so the correction does not feed back on itself.

use super::{CompSignal, PosCompCtx, PositionComp};
use crate::preset::comp::CrossTable;
use crate::signal::AxisSignal;
use crate::units::{mm_to_m, um_to_m};

/// One installed table, in SI.
struct Installed {
    base: usize,
    comp: usize,
    points_m: Vec<(f64, f64)>,
    value_m: f64,
    name: String,
}

/// All cross tables of a machine.
pub struct Cross {
    tables: Vec<Installed>,
}

impl Cross {
    /// `index` resolves an axis name; tables naming unknown axes are skipped (the preset
    /// validator reports them).
    pub fn new(tables: &[CrossTable], index: impl Fn(&str) -> Option<usize>) -> Cross {
        Cross {
            tables: tables
                .iter()
                .filter(|t| t.enabled)
                .filter_map(|t| {
                    Some(Installed {
                        base: index(&t.base_axis)?,
                        comp: index(&t.comp_axis)?,
                        points_m: t
                            .points
                            .iter()
                            .map(|&(x, z)| (mm_to_m(x), um_to_m(z)))
                            .collect(),
                        value_m: 0.0,
                        name: t.comp_axis.clone(),
                    })
                })
                .collect(),
        }
    }

    /// True when no enabled table resolved to known axes: nothing to install.
    pub fn is_empty(&self) -> bool {
        self.tables.is_empty()
    }
}

/// The table value at `x_m` (m), end values held.
pub fn delta_m(points_m: &[(f64, f64)], x_m: f64) -> f64 {
    crate::table::interp(points_m, x_m)
}

impl PositionComp for Cross {
    fn reads_machine(&self) -> bool {
        false
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }

    fn name(&self) -> &str {
        "cross"
    }

    fn step(&mut self, ctx: &PosCompCtx<'_>, out_m: &mut [f64]) {
        for t in &mut self.tables {
            t.value_m = delta_m(&t.points_m, ctx.cmd_m[t.base]);
            out_m[t.comp] += t.value_m;
        }
    }

    fn signals(&self) -> Vec<CompSignal> {
        self.tables
            .iter()
            .enumerate()
            .map(|(i, t)| CompSignal {
                axis: t.name.clone(),
                signal: if self.tables[..i].iter().any(|u| u.name == t.name) {
                    format!("{}{}", AxisSignal::CrossComp.name(), i + 1)
                } else {
                    AxisSignal::CrossComp.name().into()
                },
                quantity: AxisSignal::CrossComp.quantity(),
            })
            .collect()
    }

    fn values(&self, out: &mut [f64]) {
        for (o, t) in out.iter_mut().zip(&self.tables) {
            *o = t.value_m;
        }
    }
}
