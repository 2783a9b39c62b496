//! Rounding of the measured position to a sensor resolution coarser than the model's.
//! Its signature is the grid the logged positions lie on; the quantum is read off it and
//! the model rounds its reading (and, with the same sensor in the loop, its feedback) to
//! it. Where the model follows the axis within a count, the rounded reading lands on the
//! record's counts and the criterion sees it.

use super::{Candidate, Effect};
use crate::diagnose::DiagnoseError;
use crate::diagnose::criterion::Part;
use crate::diagnose::engine::Cand;
use crate::diagnose::evidence;
use crate::diagnose::fit::{Context, Evidence, Fixed, Shape, Variant};
use crate::units::m_to_um;

fn set_quantum(c: &mut Cand, th: &[f64]) {
    Effect::Quantization.apply(th, &mut c.model);
}

/// The position sensor's rounding.
pub struct Quantization;

impl Candidate for Quantization {
    fn effect(&self) -> Effect {
        Effect::Quantization
    }

    fn signature(&self, ctx: &Context) -> Evidence {
        // Coarser than the model's own sensor, and than numbers written to a few decimals.
        let min_q = (3.0 * ctx.sensor_quantum_m).max(1e-7);
        match evidence::grid(&ctx.sig.logged_pos_m, min_q, 0.02) {
            Some(g) if g.on_grid >= 0.99 && g.by_chance <= 0.2 => Evidence::found(
                true,
                format!(
                    "{:.1} % of the measured positions lie on a {:.3} µm grid ({:.0} % would by chance)",
                    100.0 * g.on_grid,
                    m_to_um(g.quantum),
                    100.0 * g.by_chance
                ),
            )
            .with("quantum_um", m_to_um(g.quantum))
            .with("on_grid_share", g.on_grid)
            .hint(vec![m_to_um(g.quantum)]),
            _ => Evidence::absent(format!(
                "the measured positions lie on no grid coarser than {:.3} µm",
                m_to_um(min_q)
            )),
        }
    }

    fn variants(&self, _ctx: &Context, ev: &Evidence) -> Result<Vec<Variant>, DiagnoseError> {
        let q_um = ev.hint.first().copied().unwrap_or(1.0);
        Ok(vec![Variant::fixed(
            "grid",
            "the sensor rounds to the grid the positions lie on",
            Fixed {
                shape: Shape::Params {
                    set: set_quantum,
                    theta: vec![q_um],
                },
                keys: vec!["resolution_um".into()],
                theta: vec![q_um],
                n_params: 1,
            },
            Part::Held,
        )])
    }
}
