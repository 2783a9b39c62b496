//! Rounding of the measured position to a sensor resolution coarser than the preset's.
//! Its signature is the grid the logged positions lie on; the quantum q is read off it. A
//! rounded reading says the position lies within ±q/2 of it: the model with the effect
//! reads its position residual as that interval (only what lies beyond is misfit), which
//! the criterion weighs like any other change of the residual.

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

/// The candidate's own reading of a quantum: the interval, and the preset's sensor set to it
/// for "apply to model" (the replay reads it unrounded, see `diagnose`).
fn set_interval(c: &mut Cand, th: &[f64]) {
    set_quantum(c, th);
    c.model.axis.encoder.quantize_motor = false;
    c.model.axis.encoder.quantize_scale = false;
    c.model.pos_interval_m = 0.5 * crate::units::um_to_m(th[0]);
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
                    set: set_interval,
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
