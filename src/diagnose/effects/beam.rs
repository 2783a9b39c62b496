//! Sag of the crossbeam a tool post hangs from, seen at the post's Z as the posts move.

use super::{Candidate, Effect};
use crate::diagnose::DiagnoseError;
use crate::diagnose::engine::Cand;
use crate::diagnose::fit::{Context, Evidence, Variant};

fn set_sag(c: &mut Cand, th: &[f64]) {
    Effect::BeamSag.apply(th, &mut c.model);
}

/// The crossbeam's sag under a post weight the nominal has wrong.
pub struct Sag;

impl Candidate for Sag {
    fn effect(&self) -> Effect {
        Effect::BeamSag
    }

    fn signature(&self, ctx: &Context) -> Evidence {
        if ctx.base.model.beam.is_some() && !ctx.eng.split.main.beam_x_m.is_empty() {
            Evidence::found(
                true,
                "the axis hangs from a crossbeam whose posts' positions are recorded",
            )
        } else {
            Evidence::absent("no crossbeam posts recorded for this axis")
        }
    }

    fn variants(&self, _ctx: &Context, _ev: &Evidence) -> Result<Vec<Variant>, DiagnoseError> {
        Ok(vec![Variant::params(
            "post_weight",
            "a post weight other than the nominal's",
            Effect::BeamSag.params(),
            set_sag,
            vec![vec![1000.0], vec![-1000.0]],
        )])
    }
}
