//! A constant lag between the recorded command and the machine acting on it, as a pure
//! shift or through a first-order lag (a drive's command filter). Its signature is the lag
//! both responses share in the calibration's channel shifts.

use super::{Candidate, Effect, ParamDef};
use crate::diagnose::DiagnoseError;
use crate::diagnose::engine::Cand;
use crate::diagnose::fit::{Context, Evidence, Variant};
use crate::units::{ms_to_s, s_to_ms};

/// A command delay and a first-order lag behind it.
const LAG_DEFS: [ParamDef; 2] = [
    ParamDef {
        key: "delay_ms",
        lo: -50.0,
        hi: 50.0,
        init: 1.0,
    },
    ParamDef {
        key: "lag_ms",
        lo: 0.0,
        hi: 50.0,
        init: 1.0,
    },
];

fn set_delay(c: &mut Cand, th: &[f64]) {
    Effect::CommandDelay.apply(th, &mut c.model);
}

fn set_delay_lag(c: &mut Cand, th: &[f64]) {
    Effect::CommandDelay.apply(&th[..1], &mut c.model);
    c.model.lag_s = ms_to_s(th[1].max(0.0));
}

/// The command delay.
pub struct Delay;

impl Candidate for Delay {
    fn effect(&self) -> Effect {
        Effect::CommandDelay
    }

    fn signature(&self, ctx: &Context) -> Evidence {
        let lag = -ctx.cal.common_lag_samples;
        let t3 = ctx.eng.split.main.t3_s;
        let text = format!(
            "position and force both follow the model {lag:.2} samples ({:.2} ms) late",
            s_to_ms(lag * t3)
        );
        // Within half a sample the lag is the calibration's (a hold's half period).
        if lag <= crate::diagnose::calibrate::MAX_CAL_DELAY_SAMPLES {
            return Evidence::absent(format!(
                "{text}: within the half sample the calibration takes"
            ));
        }
        Evidence::found(true, text)
            .with("lag_samples", lag)
            .hint(vec![s_to_ms(lag * t3)])
    }

    fn variants(&self, _ctx: &Context, ev: &Evidence) -> Result<Vec<Variant>, DiagnoseError> {
        let d = ev.hint.first().copied().unwrap_or(1.0).max(0.0);
        Ok(vec![
            Variant::params(
                "pure",
                "a pure shift of the command",
                Effect::CommandDelay.params(),
                set_delay,
                vec![vec![d]],
            ),
            Variant::params(
                "first_order_lag",
                "a first-order lag behind a shift of the command",
                &LAG_DEFS,
                set_delay_lag,
                vec![vec![0.5 * d, 0.5 * d], vec![0.0, d]],
            ),
        ])
    }
}
