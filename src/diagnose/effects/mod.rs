//! The candidate effects: the plant effects of SPEC §7 a nominal preset may leave out, each
//! with named parameters (units in the key), bounds, and how it changes the model; and,
//! one file per family, each effect's [`Candidate`]: its signature test and the variants
//! (shapes) it is fitted in. Nothing here decides whether an effect is there: that is the
//! criterion's (`super::criterion`).

pub mod beam;
pub mod compliance;
pub mod delay;
pub mod disturbance;
pub mod friction;
pub mod lead;
pub mod play;
pub mod quantization;
pub mod thermal;

use super::DiagnoseError;
use super::fit::{Context, Evidence, Variant};
use super::replay::Model;
use crate::preset::Coupling;
use serde::Serialize;

/// What is specific to one effect: the test of its signature in the base's residual, and
/// the shapes it may take. The diagnosis drives every effect through this alone.
pub trait Candidate: Sync {
    /// The effect.
    fn effect(&self) -> Effect;
    /// The signature test on the base's fitting residual: its figures, the fit's starting
    /// values, and whether the signature is clearly absent (then the fit is skipped).
    fn signature(&self, ctx: &Context) -> Evidence;
    /// The variants to fit, the plain one first. Detector-shaped variants arrive fitted.
    fn variants(&self, ctx: &Context, ev: &Evidence) -> Result<Vec<Variant>, DiagnoseError>;
}

/// The candidate of `e`.
pub fn candidate(e: Effect) -> &'static dyn Candidate {
    match e {
        Effect::CoulombFriction => &friction::Coulomb,
        Effect::StribeckFriction => &friction::Stribeck,
        Effect::ViscousFriction => &friction::Viscous,
        Effect::StrokeFriction => &friction::Stroke,
        Effect::ConstantForce => &friction::ConstantForce,
        Effect::Backlash => &play::Backlash,
        Effect::BacklashAsymmetry => &play::Asymmetry,
        Effect::Compliance => &compliance::Compliance,
        Effect::ThermalGrowth => &thermal::Growth,
        Effect::BeamSag => &beam::Sag,
        Effect::LeadError => &lead::Lead,
        Effect::Quantization => &quantization::Quantization,
        Effect::CommandDelay => &delay::Delay,
        Effect::ExternalDisturbance => &disturbance::External,
    }
}

/// An unmodelled plant effect the diagnosis can fit to a record and write back into the
/// preset: the hypotheses the residual is tested against.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Effect {
    /// Direction-dependent sliding friction (N) added to the nominal Coulomb force: shows
    /// as force steps and following-error spikes at reversals.
    CoulombFriction,
    /// Breakaway friction above the Coulomb level at low speed (excess N, decay speed mm/s).
    StribeckFriction,
    /// Correction to the speed-proportional friction coefficient, N·s/m (may be negative).
    ViscousFriction,
    /// Friction that rises over repeated short reversal strokes (rise N, groove/lead pitch mm).
    StrokeFriction,
    /// Lost motion in the drive train (width µm): the table stands while the motor crosses it.
    Backlash,
    /// Backlash plus a constant preload force (N) that makes the lost motion one-sided.
    BacklashAsymmetry,
    /// Constant force on the table (N): unbalanced weight, cable drag or a load.
    ConstantForce,
    /// Elastic drive train: a two-mass coupling (stiffness, damping, share of mass beyond the
    /// spring) that rings after accelerations.
    Compliance,
    /// Thermal growth of the screw heated by motion (heat per metre, time constant, fixed-end
    /// position): a slow position drift.
    ThermalGrowth,
    /// Sag of the crossbeam a tool post hangs from, seen at the post's Z as the posts move
    /// along X (fitted: post weight, N).
    BeamSag,
    /// Screw pitch error: a once-per-lead sinusoid (sin/cos µm) plus a cumulative slope (µm/m).
    LeadError,
    /// Rounding of the measured position to a sensor resolution (µm).
    Quantization,
    /// Constant lag (ms, may be negative) between the recorded command and the machine
    /// acting on it; sits outside the plant.
    CommandDelay,
    /// Force not explained by any state of the axis (a periodic wave, level steps or
    /// bursts), shaped by a detector rather than by fixed parameters.
    ExternalDisturbance,
}

/// One fitted parameter: report key (with unit), bounds, and a typical magnitude that
/// seeds the fit.
#[derive(Debug, Clone, Copy)]
pub struct ParamDef {
    /// Report and command-line key, unit in the name (`width_um`).
    pub key: &'static str,
    /// Lower bound the fit keeps the parameter above, in the key's unit.
    pub lo: f64,
    /// Upper bound, in the key's unit.
    pub hi: f64,
    /// Typical magnitude: seeds the fit and scales its step.
    pub init: f64,
}

/// A struct literal, so that the tables below are promoted to statics.
macro_rules! p {
    ($key:expr, $lo:expr, $hi:expr, $init:expr) => {
        ParamDef {
            key: $key,
            lo: $lo,
            hi: $hi,
            init: $init,
        }
    };
}

impl Effect {
    /// Every candidate: the set a diagnosis tries when `--only` names none.
    pub const ALL: [Effect; 14] = [
        Effect::CoulombFriction,
        Effect::StribeckFriction,
        Effect::ViscousFriction,
        Effect::StrokeFriction,
        Effect::Backlash,
        Effect::BacklashAsymmetry,
        Effect::ConstantForce,
        Effect::Compliance,
        Effect::ThermalGrowth,
        Effect::BeamSag,
        Effect::LeadError,
        Effect::Quantization,
        Effect::CommandDelay,
        Effect::ExternalDisturbance,
    ];

    /// The name used in reports and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Effect::CoulombFriction => "coulomb_friction",
            Effect::StribeckFriction => "stribeck_friction",
            Effect::ViscousFriction => "viscous_friction",
            Effect::StrokeFriction => "stroke_friction",
            Effect::Backlash => "backlash",
            Effect::BacklashAsymmetry => "backlash_asymmetry",
            Effect::ConstantForce => "constant_force",
            Effect::Compliance => "compliance",
            Effect::ThermalGrowth => "thermal_growth",
            Effect::BeamSag => "beam_sag",
            Effect::LeadError => "lead_error",
            Effect::Quantization => "quantization",
            Effect::CommandDelay => "command_delay",
            Effect::ExternalDisturbance => "external_disturbance",
        }
    }

    /// The candidates a diagnosis tries when `--effects` names none: all but
    /// [`Effect::BacklashAsymmetry`], which is a play and a constant force (two candidates
    /// of this set, named as two effects); asked for by name it is fitted as one.
    pub const DEFAULT: [Effect; 13] = [
        Effect::CoulombFriction,
        Effect::StribeckFriction,
        Effect::ViscousFriction,
        Effect::StrokeFriction,
        Effect::Backlash,
        Effect::ConstantForce,
        Effect::Compliance,
        Effect::ThermalGrowth,
        Effect::BeamSag,
        Effect::LeadError,
        Effect::Quantization,
        Effect::CommandDelay,
        Effect::ExternalDisturbance,
    ];

    /// The effect with report/command-line name `s` (inverse of [`Effect::name`]).
    pub fn from_name(s: &str) -> Option<Effect> {
        Effect::ALL.into_iter().find(|e| e.name() == s)
    }

    /// The fitted parameters. Signed parameters (offset force, viscous correction, lead
    /// error terms) have symmetric bounds.
    pub fn params(self) -> &'static [ParamDef] {
        match self {
            Effect::CoulombFriction => &[p!("force_n", 0.0, 5000.0, 10.0)],
            Effect::StribeckFriction => &[
                p!("breakaway_excess_n", 0.0, 5000.0, 20.0),
                p!("velocity_mm_per_s", 0.05, 50.0, 2.0),
            ],
            Effect::ViscousFriction => &[p!("viscous_n_s_per_m", -1.0e5, 1.0e5, 100.0)],
            Effect::StrokeFriction => &[
                p!("rise_n", 0.0, 5000.0, 20.0),
                p!("pitch_mm", 0.5, 200.0, 10.0),
            ],
            Effect::Backlash => &[p!("width_um", 0.0, 500.0, 5.0)],
            Effect::BacklashAsymmetry => &[
                p!("width_um", 0.0, 500.0, 5.0),
                p!("preload_force_n", -5000.0, 5000.0, 50.0),
            ],
            Effect::ConstantForce => &[p!("force_n", -1.0e4, 1.0e4, 10.0)],
            Effect::Compliance => &[
                p!("stiffness_n_per_um", 0.01, 2000.0, 10.0),
                p!("damping_n_s_per_m", 1.0, 1.0e5, 500.0),
                p!("far_mass_share", 0.05, 0.95, 0.3),
            ],
            Effect::ThermalGrowth => &[
                p!("heat_w_s_per_m", 0.0, 1.0e5, 100.0),
                p!("time_constant_s", 10.0, 36000.0, 1200.0),
                p!("fixed_end_mm", -2000.0, 2000.0, 100.0),
            ],
            Effect::BeamSag => &[p!("post_weight_n", -1.0e5, 1.0e5, 1000.0)],
            Effect::LeadError => &[
                p!("sin_um", -200.0, 200.0, 1.0),
                p!("cos_um", -200.0, 200.0, 1.0),
                p!("cumulative_um_per_m", -500.0, 500.0, 1.0),
            ],
            Effect::Quantization => &[p!("resolution_um", 1e-4, 100.0, 1.0)],
            Effect::CommandDelay => &[p!("delay_ms", -50.0, 50.0, 1.0)],
            Effect::ExternalDisturbance => &[],
        }
    }

    /// Adds the effect with parameters `th` to `m`. Effects the nominal already has are
    /// corrected rather than replaced (Coulomb adds to the nominal Coulomb force, viscous to
    /// the nominal coefficient), so a mis-set parameter shows as that effect.
    pub fn apply(self, th: &[f64], m: &mut Model) {
        let a = &mut m.axis;
        match self {
            Effect::CoulombFriction => {
                a.friction.enabled = true;
                a.friction.coulomb_n += th[0];
                if a.friction.stribeck.enabled {
                    a.friction.stribeck.static_n += th[0];
                }
            }
            Effect::StribeckFriction => {
                a.friction.enabled = true;
                let s = &mut a.friction.stribeck;
                s.enabled = true;
                s.static_n = a.friction.coulomb_n + th[0];
                s.velocity_mm_per_s = th[1];
            }
            Effect::ViscousFriction => {
                a.friction.enabled = true;
                a.friction.viscous_n_s_per_m = (a.friction.viscous_n_s_per_m + th[0]).max(0.0);
            }
            Effect::StrokeFriction => {
                a.friction.enabled = true;
                let s = &mut a.friction.stroke;
                s.enabled = true;
                s.rise_ratio = 0.0;
                s.rise_n = th[0];
                s.pitch_mm = th[1];
            }
            Effect::Backlash => {
                a.lost_motion.enabled = true;
                a.lost_motion.width_um = th[0].max(1e-6);
            }
            Effect::BacklashAsymmetry => {
                a.lost_motion.enabled = true;
                a.lost_motion.width_um = th[0].max(1e-6);
                a.gravity.enabled = true;
                a.gravity.offset_n += th[1];
            }
            Effect::ConstantForce => {
                a.gravity.enabled = true;
                a.gravity.offset_n += th[0];
            }
            Effect::Compliance if !a.lost_motion.enabled => {
                // A share of the table's mass (with any payload it already carries) sits on
                // a spring on it: a fixture or a head on a flexible mount, neither rubbed by
                // the slide nor seen by the scale.
                let table = a.drive.table_mass_kg + a.drive.payload_mass_kg();
                let far = (th[2] * table).max(1e-3);
                a.drive.table_mass_kg = (table - far).max(1e-3);
                a.drive.coupling = Coupling::Payload {
                    mass_kg: far,
                    stiffness_n_per_um: th[0],
                    damping_n_s_per_m: th[1],
                    hardening_deflection_um: 0.0,
                };
            }
            // With play in the drive, the spring is the screw's.
            Effect::Compliance => set_screw_spring(m, th),
            Effect::ThermalGrowth => {
                let t = &mut a.screw_thermal;
                t.enabled = true;
                t.friction_heat_share = 0.0;
                t.motion_heat_w_s_per_m = th[0];
                // The heat loss stays as the preset has it; the time constant sets the
                // heat capacity, so heat and time constant are independent parameters.
                t.heat_capacity_j_per_k = t.loss_w_per_k * th[1].max(1.0);
                t.initial_c = t.ambient_c;
                t.reference_c = t.ambient_c;
                t.fixed_end_mm = th[2];
            }
            Effect::BeamSag => {
                if let Some(b) = &mut m.beam
                    && let Some(p) = b.crossbeam.posts.get_mut(b.post)
                {
                    p.weight_n += th[0];
                }
            }
            Effect::LeadError => {
                let l = &mut a.lead_error;
                l.enabled = true;
                l.period_mm = a.drive.lead_mm;
                l.amplitude_um = th[0].hypot(th[1]);
                l.phase_deg = th[1].atan2(th[0]).to_degrees();
                l.cumulative_um_per_m = th[2];
                l.table.clear();
            }
            Effect::Quantization => {
                // The sensor behind `pos` (and the feedback, if it is the same device).
                let e = &mut a.encoder;
                match m.pos_source {
                    crate::preset::PosSource::MotorEncoder => {
                        e.quantize_motor = true;
                        let counts = (crate::units::mm_to_um(a.drive.lead_mm) / th[0])
                            .round()
                            .max(1.0);
                        e.motor_counts_per_rev = counts as u32;
                    }
                    _ => {
                        e.quantize_scale = true;
                        e.scale_resolution_um = th[0];
                    }
                }
            }
            Effect::CommandDelay => m.delay_s += crate::units::ms_to_s(th[0]),
            Effect::ExternalDisturbance => {}
        }
    }
}

/// Gives `m` a compliance as the screw's spring (`th`: stiffness N/µm, damping N·s/m, share
/// of the moving mass beyond the spring): the table beyond it, the rest moving with the
/// motor. The table is then rubbed by the slide and read by the scale, unlike a payload on
/// a mount ([`Effect::apply`] without play).
pub fn set_screw_spring(m: &mut Model, th: &[f64]) {
    let a = &mut m.axis;
    let total = a.drive.total_mass_kg();
    let far = (th[2] * total).max(1e-3);
    let k = a.drive.force_per_torque();
    a.drive.table_mass_kg = far;
    a.drive.motor_inertia_kgm2 = (total - far).max(1e-6) / (k * k);
    a.drive.coupling = Coupling::TwoMass {
        stiffness_n_per_um: th[0],
        damping_n_s_per_m: th[1],
    };
}
