//! Thermal growth of the screw heated by motion: a slow drift of the position, or an error
//! that grows with the screw's heat and the distance from its fixed bearing.

use super::{Candidate, Effect};
use crate::diagnose::DiagnoseError;
use crate::diagnose::engine::Cand;
use crate::diagnose::evidence;
use crate::diagnose::fit::{Context, Evidence, Variant};
use crate::preset::PosSource;
use crate::units::{m_to_mm, m_to_um};

/// Time constants the growth regression tries besides the drift's own, s.
const GROWTH_TAUS_S: [f64; 4] = [30.0, 100.0, 300.0, 1000.0];

/// The growth as a regression sees it: with the candidate's heat model (heat `q` per metre
/// travelled, the preset's heat loss, time constant τ) the screw's temperature rise is
/// q·h(t), h' = |v|/C − h/τ (C = loss·τ), and the growth at position x is α·q·h(t)·(x − x₀):
/// linear in q·α and q·α·x₀ for a given τ. Regressing the position residual on h·x and h
/// (and a constant) for a few τ gives q, τ and x₀ to start from, and the share explained.
fn growth_regression(ctx: &Context, tau_drift_s: f64) -> Option<(f64, Vec<f64>)> {
    let th = &ctx.base.model.axis.screw_thermal;
    let (alpha, loss) = (th.alpha_per_k, th.loss_w_per_k);
    if !(alpha > 0.0 && loss > 0.0) {
        return None;
    }
    let s = ctx.sig;
    let dt = ctx.eng.split.main.t3_s;
    let ones = vec![1.0; s.r_pos.len()];
    let mut best: Option<(f64, Vec<f64>)> = None;
    for tau in std::iter::once(tau_drift_s.clamp(10.0, 36_000.0)).chain(GROWTH_TAUS_S) {
        let c = loss * tau;
        let mut h = 0.0;
        let hs: Vec<f64> = s
            .vel_mps
            .iter()
            .map(|v| {
                let now = h;
                h += dt * (v.abs() / c - h / tau);
                now
            })
            .collect();
        let hx: Vec<f64> = hs.iter().zip(&s.pos_m).map(|(h, x)| h * x).collect();
        let Some(r) = evidence::regress(&[&hx, &hs, &ones], &s.r_pos, s.corr_len) else {
            continue;
        };
        let (a, b) = (r.coef[0], r.coef[1]);
        let heat = a / alpha;
        if !(heat > 0.0 && heat.is_finite()) {
            continue;
        }
        let x0_mm = m_to_mm(-b / a);
        if best.as_ref().is_none_or(|(e, _)| r.explained > *e) {
            best = Some((
                r.explained,
                vec![heat.min(1e5), tau, x0_mm.clamp(-2000.0, 2000.0)],
            ));
        }
    }
    best
}

fn set_growth(c: &mut Cand, th: &[f64]) {
    Effect::ThermalGrowth.apply(th, &mut c.model);
}

/// The screw's thermal growth.
pub struct Growth;

impl Candidate for Growth {
    fn effect(&self) -> Effect {
        Effect::ThermalGrowth
    }

    fn signature(&self, ctx: &Context) -> Evidence {
        if ctx.base.model.pos_source == PosSource::MotorEncoder {
            return Evidence::absent(
                "the record's position is the motor encoder, which the screw's growth does not move",
            );
        }
        let drift = evidence::drift(&ctx.sig.t_s, &ctx.sig.r_pos, None);
        let tau = drift.as_ref().and_then(|d| d.tau_s).unwrap_or(600.0);
        let regression = growth_regression(ctx, tau);
        let (explained, hint) = match &regression {
            Some((e, h)) => (*e, h.clone()),
            None => (0.0, vec![100.0, tau.clamp(10.0, 36_000.0), 0.0]),
        };
        let drift_text = drift
            .as_ref()
            .map_or("no slow drift in time".to_owned(), |d| {
                format!(
                    "a drift of {:.1} µm{}, {:.0} % of the slow part",
                    m_to_um(d.magnitude),
                    d.tau_s
                        .map(|t| format!(" with a time constant of {t:.0} s"))
                        .unwrap_or_default(),
                    100.0 * d.explained
                )
            });
        let text = format!(
            "the position residual shows {drift_text}; the screw's heat and the distance from a bearing at {:.0} mm explain {:.0} % of it",
            hint[2],
            100.0 * explained
        );
        if drift.is_none() && regression.is_none() {
            return Evidence::absent(text);
        }
        let pass = drift.as_ref().is_some_and(|d| d.explained >= 0.5) || explained >= 0.5;
        Evidence::found(pass, text)
            .with("time_constant_s", hint[1])
            .with("explained_share", explained)
            .hint(hint)
    }

    fn variants(&self, _ctx: &Context, ev: &Evidence) -> Result<Vec<Variant>, DiagnoseError> {
        let h = if ev.hint.len() == 3 {
            ev.hint.clone()
        } else {
            vec![100.0, 600.0, 0.0]
        };
        let mut v = Variant::params(
            "motion_heat",
            "heat per metre travelled, lost to the surroundings with a time constant",
            Effect::ThermalGrowth.params(),
            set_growth,
            vec![
                h.clone(),
                vec![h[0], if h[1] > 200.0 { 60.0 } else { 600.0 }, h[2]],
            ],
        );
        v.slow = true;
        Ok(vec![v])
    }
}
