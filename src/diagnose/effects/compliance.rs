//! An elastic drive train: a payload on a mount on the table (linear or stiffening), or the
//! screw's spring between motor and table. Its signature: the residual resonates, rings
//! after the command's acceleration steps, or peaks in the position loop's band.

use super::{Candidate, Effect, ParamDef, set_screw_spring};
use crate::diagnose::DiagnoseError;
use crate::diagnose::engine::Cand;
use crate::diagnose::evidence;
use crate::diagnose::fit::{Context, Evidence, Variant};
use crate::preset::Coupling;

/// Largest damping ratio a fitted spring may have. A screw's or a mount's spring rings
/// (feed drives measure 0.01–0.2): an overdamped one is a dashpot in series that stands in
/// for something else (a play's impacts, a lag), and resolving its damper explicitly takes
/// tens of plant sub-steps per period. A fit treats it as outside the model, as it treats a
/// replay that diverges.
const MAX_SPRING_DAMPING_RATIO: f64 = 1.0;

/// Whether the candidate's coupling is damped beyond critical or rings above the record's
/// Nyquist frequency (where it cannot ring in the record at all).
pub fn outside_spring(c: &Cand) -> bool {
    let a = &c.model.axis;
    let nyquist_rad_per_s = std::f64::consts::PI / c.model.t3_s;
    a.coupling_damping_ratio()
        .is_some_and(|z| z > MAX_SPRING_DAMPING_RATIO)
        || a.coupling_resonance_rad_per_s()
            .is_some_and(|w| w > nyquist_rad_per_s)
}

/// Window after a commanded acceleration step in which a compliant payload's dip and
/// overshoot show in the force residual (the loop's own settling time on these axes).
const RINGING_WINDOW_S: f64 = 0.08;
/// The position loop's own band, Hz, where a stiff payload's spring shows as a changed
/// closed-loop peak.
const LOOP_BAND_HZ: (f64, f64) = (8.0, 60.0);
/// How far a resonance's or the loop band's peak must stand above the spectrum's median.
const PEAK_RATIO: f64 = 8.0;

/// The signature: a resonance of the residual, ringing after acceleration steps, or a
/// peak in the position loop's band; with none of them it is clearly absent.
fn signature(ctx: &Context) -> Evidence {
    let dt = ctx.eng.split.main.t3_s;
    let y: &[f64] = ctx.sig.r_force.as_deref().unwrap_or(&ctx.sig.r_pos);
    let f_hi = (0.4 / dt).min(600.0);
    if let Some(r) = evidence::resonance(y, dt, 8.0, f_hi, Some(&ctx.sig.cmd_acc_mps2))
        && r.peak_ratio >= PEAK_RATIO
        && r.ref_ratio.is_none_or(|x| x >= 0.5 * PEAK_RATIO)
    {
        let m = ctx.base.model.axis.drive.total_mass_kg();
        let w = std::f64::consts::TAU * r.freq_hz;
        // A payload of about a third of the mass on the spring, to start from.
        let share = 0.3;
        let m_red = share * (1.0 - share) * m;
        let k_n_per_um = w * w * m_red * 1e-6;
        let c = 2.0 * r.damping_ratio.max(0.1) * w * m_red;
        return Evidence::found(
            true,
            format!(
                "the residual resonates at {:.1} Hz, {:.0}× its band's median",
                r.freq_hz, r.peak_ratio
            ),
        )
        .with("frequency_hz", r.freq_hz)
        .with("peak_ratio", r.peak_ratio)
        .with("damping_ratio", r.damping_ratio)
        .hint(vec![k_n_per_um, c, share]);
    }
    if let Some(f) = ctx.sig.r_force.as_deref()
        && let Some(r) = evidence::ringing(f, &ctx.sig.cmd_acc_mps2, dt, RINGING_WINDOW_S)
        && -r.dip_t >= evidence::RINGING_T.0
        && r.rise_t >= evidence::RINGING_T.1
    {
        return Evidence::found(
            true,
            format!(
                "the force residual rings after the command's {} acceleration steps: {:.2} N at {:.0} ms ({:.1} standard errors), then {:+.2} N ({:.1})",
                r.events,
                r.dip,
                crate::units::s_to_ms(r.dip_s),
                -r.dip_t,
                r.rise,
                r.rise_t
            ),
        )
        .with("ringing_dip_t", -r.dip_t)
        .with("ringing_rise_t", r.rise_t);
    }
    if let Some(r) = evidence::resonance(&ctx.sig.r_pos, dt, LOOP_BAND_HZ.0, f_hi, None)
        && (LOOP_BAND_HZ.0..=LOOP_BAND_HZ.1).contains(&r.freq_hz)
        && r.peak_ratio >= PEAK_RATIO
    {
        return Evidence::found(
            false,
            format!(
                "the position residual peaks at {:.1} Hz, in the position loop's band, {:.0}× its spectrum's median",
                r.freq_hz, r.peak_ratio
            ),
        )
        .with("loop_peak_hz", r.freq_hz)
        .with("loop_peak_ratio", r.peak_ratio);
    }
    Evidence::absent(
        "no resonance, no ringing after the acceleration steps and no peak in the position loop's band",
    )
}

fn set_payload(c: &mut Cand, th: &[f64]) {
    Effect::Compliance.apply(th, &mut c.model);
}

fn set_screw(c: &mut Cand, th: &[f64]) {
    set_screw_spring(&mut c.model, th);
}

/// The parameters of a payload on a mount that stiffens as it deflects.
const HARDENING_DEFS: [ParamDef; 4] = [
    ParamDef {
        key: "stiffness_n_per_um",
        lo: 0.01,
        hi: 2000.0,
        init: 10.0,
    },
    ParamDef {
        key: "damping_n_s_per_m",
        lo: 1.0,
        hi: 1.0e5,
        init: 500.0,
    },
    ParamDef {
        key: "far_mass_share",
        lo: 0.05,
        hi: 0.95,
        init: 0.3,
    },
    ParamDef {
        key: "hardening_deflection_um",
        lo: 0.01,
        hi: 1.0e5,
        init: 5.0,
    },
];

/// A payload on a hardening mount (`th`: stiffness N/µm, damping N·s/m, payload share,
/// then the deflection d₀ µm at which the force has doubled).
fn set_hardening(c: &mut Cand, th: &[f64]) {
    Effect::Compliance.apply(&th[..3], &mut c.model);
    if let (
        Coupling::Payload {
            hardening_deflection_um,
            ..
        },
        Some(d0),
    ) = (&mut c.model.axis.drive.coupling, th.get(3))
    {
        *hardening_deflection_um = *d0;
    }
}

/// The elastic drive train.
pub struct Compliance;

impl Candidate for Compliance {
    fn effect(&self) -> Effect {
        Effect::Compliance
    }

    fn signature(&self, ctx: &Context) -> Evidence {
        signature(ctx)
    }

    fn variants(&self, ctx: &Context, ev: &Evidence) -> Result<Vec<Variant>, DiagnoseError> {
        // Two starts: a resonance's own figures and a middling spring, or a soft and a stiff
        // one (each start is a whole solve of a spring's slower replays).
        let starts = if ev.hint.len() == 3 {
            vec![ev.hint.clone(), vec![10.0, 4000.0, 0.3]]
        } else {
            vec![vec![3.0, 2000.0, 0.3], vec![30.0, 8000.0, 0.3]]
        };
        let defs = Effect::Compliance.params();
        let screw = Variant::params(
            "screw",
            "the screw's spring between motor and table",
            defs,
            set_screw,
            starts.clone(),
        );
        if ctx.base.model.axis.lost_motion.enabled {
            return Ok(vec![screw]);
        }
        let m = ctx.base.model.axis.drive.total_mass_kg();
        let hard: Vec<Vec<f64>> = starts
            .iter()
            .take(1)
            .map(|s| {
                // Hardening from the deflection under 1 m/s².
                let d1 = s[2] * m / s[0].max(1e-9);
                vec![0.5 * s[0], s[1], s[2], d1]
            })
            .collect();
        Ok(vec![
            Variant::params(
                "payload",
                "a payload on a mount on the table",
                defs,
                set_payload,
                starts,
            ),
            screw,
            Variant::params(
                "hardening",
                "a payload on a mount that stiffens as it deflects",
                &HARDENING_DEFS,
                set_hardening,
                hard,
            ),
        ])
    }
}
