//! The nominal machine the diagnosis receives (presets/emps.ron) and the true machine built
//! from it: the same structure with every nominal parameter off by 1–5 %.

use std::collections::BTreeMap;

use super::control::{Gains, Grid, GridMode, SetPoint};
use super::dice::Dice;
use super::rig::RigParams;
use super::run::TrueMachine;
use super::{IndepError, PosSensor};
use crate::preset::{AxisParams, Coupling, Feedback, PosSource, Preset};
use crate::units::{force_per_torque, mm_to_m, um_to_m};

/// The preset the diagnosis gets: emps.ron, read as TRACE_FORMAT (no mapping), with its
/// position source set to the sensor the record's `pos` comes from.
pub fn nominal_preset(sensor: PosSensor) -> Result<Preset, IndepError> {
    let mut p = crate::preset::load_embedded("emps.ron")?.preset;
    p.diagnose.mapping = None;
    p.diagnose.pos_source = match sensor {
        PosSensor::MotorEncoder => PosSource::MotorEncoder,
        PosSensor::LinearScale => PosSource::Scale,
    };
    Ok(p)
}

/// Refuses a nominal axis with a feature the generator does not model.
fn check_supported(a: &AxisParams) -> Result<(), IndepError> {
    let s = &a.servo;
    let mut missing = Vec::new();
    if s.vff != 0.0 || s.aff != 0.0 {
        missing.push("velocity/acceleration feed-forward");
    }
    if s.feedback != Feedback::Motor {
        missing.push("scale feedback");
    }
    if !matches!(a.drive.coupling, Coupling::Rigid) {
        missing.push("a two-mass nominal coupling");
    }
    let f = &a.friction;
    if f.enabled && (f.stribeck.enabled || f.stroke.enabled) {
        missing.push("nominal Stribeck or stroke friction");
    }
    if a.lost_motion.enabled || a.gravity.enabled || a.screw_thermal.enabled || a.lead_error.enabled
    {
        missing.push("nominal lost motion, gravity, thermal growth or lead error");
    }
    if missing.is_empty() {
        Ok(())
    } else {
        Err(IndepError::Unsupported(format!(
            "axis '{}' of the nominal preset has {}",
            a.name,
            missing.join(", ")
        )))
    }
}

/// The machine exactly as the nominal preset describes it, with `sensor` logged.
pub fn exact_machine(p: &Preset, sensor: PosSensor) -> Result<TrueMachine, IndepError> {
    let a = p
        .axes
        .first()
        .ok_or_else(|| IndepError::Unsupported("the nominal preset has no axis".into()))?;
    check_supported(a)?;
    let lead_m = mm_to_m(a.drive.lead_mm);
    let k = force_per_torque(lead_m);
    let (visc, coul) = if a.friction.enabled {
        (a.friction.viscous_n_s_per_m, a.friction.coulomb_n)
    } else {
        (0.0, 0.0)
    };
    let mut rig = RigParams::rigid(
        a.drive.motor_inertia_kgm2 * k * k,
        a.drive.table_mass_kg,
        visc,
    );
    rig.friction.coulomb_pos_n = coul;
    rig.friction.coulomb_neg_n = coul;
    rig.force_lag_s = a.servo.current_lag_s;
    let encoder = Grid {
        step_m: if a.encoder.quantize_motor {
            lead_m / f64::from(a.encoder.motor_counts_per_rev.max(1))
        } else {
            0.0
        },
        mode: GridMode::Round,
    };
    Ok(TrueMachine {
        rig,
        gains: Gains {
            kp_per_s: a.servo.kp_per_s,
            kv_n_s_per_m: a.servo.kv_n_s_per_m,
            ki_per_s: a.servo.ki_per_s,
            force_limit_n: a.servo.torque_limit_nm * k,
            avg2: a.servo.vel_filter_avg2,
            t3_s: p.timing.t3_s,
        },
        setpoint: SetPoint::Direct,
        encoder,
        scale: Grid {
            step_m: um_to_m(a.encoder.scale_resolution_um),
            mode: GridMode::Round,
        },
        sensor,
        thermal: None,
        substeps: 10,
        start_gap_frac: 0.0,
    })
}

/// Moves every nominal parameter by 1–5 % with a random sign; returns true/nominal ratios.
pub fn offset_nominal(m: &mut TrueMachine, dice: &mut Dice) -> BTreeMap<String, f64> {
    let mut scales = BTreeMap::new();
    let mut f = |key: &str, x: &mut f64| {
        let r = 1.0 + dice.sign() * dice.between(0.01, 0.05);
        *x *= r;
        scales.insert(key.to_owned(), r);
    };
    f("motor_mass_kg", &mut m.rig.motor_mass_kg);
    f("table_mass_kg", &mut m.rig.carriage_mass_kg);
    f("viscous_n_s_per_m", &mut m.rig.friction.viscous_n_s_per_m);
    f("kp_per_s", &mut m.gains.kp_per_s);
    f("kv_n_s_per_m", &mut m.gains.kv_n_s_per_m);
    f("force_gain", &mut m.rig.force_gain);
    if m.rig.friction.coulomb_pos_n > 0.0 {
        let mut c = m.rig.friction.coulomb_pos_n;
        f("coulomb_n", &mut c);
        m.rig.friction.coulomb_pos_n = c;
        m.rig.friction.coulomb_neg_n = c;
    }
    scales
}
