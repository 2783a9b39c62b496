use axisbench::preset::{self, AccDecKind, Mode, Preset};
use axisbench::units::m_to_mm;
use axisbench::{Machine, Trace};

/// The default preset with every plant effect off and an ideal (unquantized) encoder: the
/// base for analytic checks.
pub fn plain() -> Preset {
    let mut p = preset::load_embedded("default.ron")
        .expect("default preset")
        .preset;
    let a = &mut p.axes[0];
    a.friction.enabled = false;
    a.lost_motion.enabled = false;
    a.screw_thermal.enabled = false;
    a.lead_error.enabled = false;
    a.gravity.enabled = false;
    a.encoder.quantize_motor = false;
    a.encoder.quantize_scale = false;
    a.servo.vff = 0.0;
    a.servo.aff = 0.0;
    a.backlash.enabled = false;
    a.quadrant.enabled = false;
    a.thermal.enabled = false;
    a.initial_pos_mm = 0.0;
    p.nc.accdec.kind = AccDecKind::None;
    p.nc.initial_mode = Mode::Normal;
    p.scenario.duration_s = None;
    p.scenario.settle_s = 0.3;
    p
}

/// Runs `program` (single channel) on `p` to its end plus settle time.
pub fn run(p: &Preset, program: &str) -> Machine {
    let mut m =
        Machine::new(p, &[("test.ngc".into(), program.to_owned())]).expect("machine builds");
    m.run(600.0).unwrap();
    assert!(m.done(), "run did not finish");
    m
}

/// The samples of signal `name`, in SI as the trace holds them.
pub fn col<'a>(t: &'a Trace, name: &str) -> &'a [f64] {
    t.values(name)
        .unwrap_or_else(|| panic!("trace has no {name}"))
}

/// The samples of a length (m) or velocity (m/s) signal in mm or mm/s, for checks that reason
/// in the units of the program.
pub fn col_mm(t: &Trace, name: &str) -> Vec<f64> {
    col(t, name).iter().map(|&x| m_to_mm(x)).collect()
}

/// Index of the first sample at or after `t_s`.
pub fn at(t: &Trace, t_s: f64) -> usize {
    t.t().partition_point(|&x| x < t_s)
}
