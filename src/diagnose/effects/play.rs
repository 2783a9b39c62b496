//! Play in the drive: the table stands while the motor crosses a gap. Its signature: the
//! residual gathers at the reversals, or the drive hunts across the gap (a steady tone in
//! the force that no model without play has).

use super::{Candidate, Effect};
use crate::diagnose::DiagnoseError;
use crate::diagnose::engine::Cand;
use crate::diagnose::evidence;
use crate::diagnose::fit::{Context, Evidence, Variant};
use crate::preset::Coupling;

/// Share of the force residual's power above [`HUNT_F_LO_HZ`] that one tone must hold for
/// the drive to count as hunting (white noise: a few per cent; limit cycles 0.95–1.0).
const HUNT_SHARE: f64 = 0.8;
/// Lowest frequency of the hunting band, Hz (below: the motion's own content).
const HUNT_F_LO_HZ: f64 = 50.0;
/// Half the window around a reversal where a play's residual gathers, s.
const REVERSAL_HALF_S: f64 = 0.03;

/// Below this commanded speed the command counts as standing, m/s.
const MOVING_MPS: f64 = 5e-4;

fn dir(v: f64) -> f64 {
    if v > MOVING_MPS {
        1.0
    } else if v < -MOVING_MPS {
        -1.0
    } else {
        0.0
    }
}

/// The signature of play: a hunting tone, or the residual's energy gathered at the
/// command's reversals (its share there over the share of time, which is 1 where it is
/// spread evenly: below that the signature is clearly absent).
fn reversal_evidence(ctx: &Context) -> Evidence {
    if matches!(ctx.base.model.axis.drive.coupling, Coupling::Payload { .. }) {
        return Evidence::absent(
            "the model has a payload on a mount, beside which the plant has no play",
        );
    }
    let s = ctx.sig;
    let dt = ctx.eng.split.main.t3_s;
    if let Some(y) = s.r_force.as_deref()
        && let Some(t) = evidence::tone(y, dt, HUNT_F_LO_HZ, 0.5 / dt)
        && t.share >= HUNT_SHARE
    {
        return Evidence::found(
            true,
            format!(
                "the drive hunts: a steady {:.0} Hz tone of {:.1} N rms holds {:.0} % of the force residual above {HUNT_F_LO_HZ:.0} Hz",
                t.freq_hz,
                t.rms,
                100.0 * t.share
            ),
        )
        .with("hunting_hz", t.freq_hz)
        .with("hunting_share", t.share);
    }
    let y: &[f64] = s.r_force.as_deref().unwrap_or(&s.r_pos);
    let n = y.len();
    let half = ((REVERSAL_HALF_S / dt).round() as usize).max(1);
    let mut near = vec![false; n];
    let mut reversals = 0usize;
    let mut last = 0.0;
    for (k, &v) in s.cmd_vel_mps.iter().enumerate() {
        let d = dir(v);
        if d != 0.0 && last != 0.0 && d != last {
            reversals += 1;
            for m in near
                .iter_mut()
                .take((k + half).min(n))
                .skip(k.saturating_sub(half))
            {
                *m = true;
            }
        }
        if d != 0.0 {
            last = d;
        }
    }
    if reversals < 3 {
        return Evidence::absent("fewer than 3 reversals in the fitting data");
    }
    let mean = y.iter().sum::<f64>() / n.max(1) as f64;
    let (mut e_near, mut e_all) = (0.0, 0.0);
    for (v, &m) in y.iter().zip(&near) {
        let e = (v - mean) * (v - mean);
        e_all += e;
        if m {
            e_near += e;
        }
    }
    let time_share = near.iter().filter(|m| **m).count() as f64 / n.max(1) as f64;
    let energy_share = if e_all > 0.0 { e_near / e_all } else { 0.0 };
    let ratio = energy_share / time_share.max(1e-9);
    let text = format!(
        "{:.0} % of the residual energy lies within ±30 ms of the {reversals} reversals, which take {:.0} % of the time ({ratio:.1}×)",
        100.0 * energy_share,
        100.0 * time_share
    );
    let ev = if ratio <= 1.0 {
        Evidence::absent(text)
    } else {
        Evidence::found(ratio >= 2.0, text)
    };
    ev.with("energy_share_at_reversals", energy_share)
        .with("concentration", ratio)
}

fn set_backlash(c: &mut Cand, th: &[f64]) {
    Effect::Backlash.apply(th, &mut c.model);
}

fn set_asymmetry(c: &mut Cand, th: &[f64]) {
    Effect::BacklashAsymmetry.apply(th, &mut c.model);
}

/// Lost motion in the drive train.
pub struct Backlash;

impl Candidate for Backlash {
    fn effect(&self) -> Effect {
        Effect::Backlash
    }

    fn signature(&self, ctx: &Context) -> Evidence {
        reversal_evidence(ctx)
    }

    fn variants(&self, _ctx: &Context, _ev: &Evidence) -> Result<Vec<Variant>, DiagnoseError> {
        Ok(vec![Variant::params(
            "lost_motion",
            "the table stands while the motor crosses the gap",
            Effect::Backlash.params(),
            set_backlash,
            vec![vec![3.0], vec![10.0], vec![30.0]],
        )])
    }
}

/// Play with one flank favoured by a preload force: a play and a constant force, fitted as
/// one effect when asked for by name.
pub struct Asymmetry;

impl Candidate for Asymmetry {
    fn effect(&self) -> Effect {
        Effect::BacklashAsymmetry
    }

    fn signature(&self, ctx: &Context) -> Evidence {
        reversal_evidence(ctx)
    }

    fn variants(&self, _ctx: &Context, _ev: &Evidence) -> Result<Vec<Variant>, DiagnoseError> {
        Ok(vec![Variant::params(
            "preloaded",
            "a play whose one flank a constant force favours",
            Effect::BacklashAsymmetry.params(),
            set_asymmetry,
            vec![vec![5.0, -30.0], vec![5.0, 30.0], vec![20.0, 30.0]],
        )])
    }
}
