//! Shipped presets, strict loading and every validation class.

use axisbench::Machine;
use axisbench::preset::{self, Preset, PresetError, SHIPPED_PRESETS};

#[test]
fn every_shipped_preset_validates_and_simulates() {
    for name in SHIPPED_PRESETS {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("presets");
        let on_disk = std::fs::read_to_string(dir.join(name)).expect("preset file");
        assert_eq!(
            Some(on_disk.as_str()),
            preset::embedded(name),
            "{name}: embedded copy differs"
        );
        let lp =
            preset::load(&dir.join(name).display().to_string()).unwrap_or_else(|e| panic!("{e}"));
        let mut m = Machine::from_loaded(&lp).unwrap_or_else(|e| panic!("{name}: {e}"));
        m.run(60.0).unwrap();
        let tr = &m.trace;
        assert!(tr.len() > 100, "{name}: only {} samples", tr.len());
        // `meas` is sparse by definition (TRACE_FORMAT): empty except at a measurement.
        for s in tr.signals.iter().filter(|s| !s.name.ends_with(".meas")) {
            assert!(
                s.data.iter().all(|v| v.is_finite()),
                "{name}: {} has non-finite samples",
                s.name
            );
        }
        for a in &m.axes {
            let e = (a.cmd_raw_m() - a.pos_m).abs();
            assert!(
                e < 5e-4,
                "{name}: axis {} ended {e} m off its command",
                a.name
            );
        }
    }
}

#[test]
fn presets_round_trip_through_ron() {
    for name in SHIPPED_PRESETS {
        let p = preset::load_embedded(name).expect("loads").preset;
        let text = p.to_ron().expect("serializes");
        let back = Preset::from_ron(&text, name).expect("reads back");
        assert_eq!(p, back, "{name}");
    }
}

fn default_text() -> String {
    preset::embedded("default.ron")
        .expect("embedded")
        .to_owned()
}

fn invalid(text: &str) -> Vec<String> {
    match Preset::from_ron(text, "bad.ron") {
        Err(PresetError::Invalid { errors, .. }) => errors.iter().map(|e| e.to_string()).collect(),
        Err(e) => vec![e.to_string()],
        Ok(_) => panic!("accepted an invalid preset"),
    }
}

#[test]
fn nan_and_negative_physical_values_are_rejected() {
    let e = invalid(&default_text().replace("table_mass_kg: 300.0", "table_mass_kg: NaN"));
    assert!(
        e.iter()
            .any(|m| m.contains("axes.x.drive.table_mass_kg") && m.contains("finite")),
        "{e:?}"
    );
    let e = invalid(&default_text().replace("coulomb_n: 250.0", "coulomb_n: -5.0"));
    assert!(
        e.iter().any(|m| m.contains("axes.x.friction.coulomb_n")
            && m.contains("-5 is outside the allowed range 0 … 1000000 N")),
        "{e:?}"
    );
}

#[test]
fn a_viscous_split_beyond_the_coefficient_is_refused_by_name() {
    // 800 ± 900 N·s/m would be −100 N·s/m moving −: a friction that pushes.
    let text = default_text().replace(
        "viscous_n_s_per_m: 800.0,",
        "viscous_n_s_per_m: 800.0,\n                viscous_split_n_s_per_m: -900.0,",
    );
    let e = invalid(&text);
    assert!(
        e.iter().any(
            |m| m.contains("axes.x.friction.viscous_split_n_s_per_m") && m.contains("negative")
        ),
        "{e:?}"
    );
    // Within the coefficient it loads, and the default (absent) is no split.
    let ok = text.replace("-900.0", "-300.0");
    let p = Preset::from_ron(&ok, "split.ron").expect("a split within the coefficient loads");
    assert_eq!(p.axes[0].friction.viscous_split_n_s_per_m, -300.0);
    let d = Preset::from_ron(&default_text(), "default.ron").expect("default loads");
    assert_eq!(d.axes[0].friction.viscous_split_n_s_per_m, 0.0);
}

#[test]
fn a_power_law_speed_term_loads_and_its_exponent_is_checked_by_name() {
    let text = default_text().replace(
        "viscous_n_s_per_m: 800.0,",
        "viscous_n_s_per_m: 800.0,\n                viscous_power: (enabled: true, force_at_100mm_per_s_n: 15.0, exponent: 0.6, core_mm_per_s: 2.0),",
    );
    let p = Preset::from_ron(&text, "power.ron").expect("a power-law term loads");
    let v = &p.axes[0].friction.viscous_power;
    assert!(v.enabled && v.force_at_100mm_per_s_n == 15.0 && v.exponent == 0.6);
    let e = invalid(&text.replace("exponent: 0.6", "exponent: 0.0"));
    assert!(
        e.iter()
            .any(|m| m.contains("axes.x.friction.viscous_power.exponent")
                && m.contains("outside the allowed range")),
        "{e:?}"
    );
    let d = Preset::from_ron(&default_text(), "default.ron").expect("default loads");
    assert!(
        !d.axes[0].friction.viscous_power.enabled,
        "off unless asked for"
    );
}

#[test]
fn a_coulomb_smoothing_loads_and_is_checked_by_name() {
    let text = default_text().replace(
        "viscous_n_s_per_m: 800.0,",
        "viscous_n_s_per_m: 800.0,\n                coulomb_smoothing_mm_per_s: 0.4,",
    );
    let p = Preset::from_ron(&text, "smooth.ron").expect("a smoothing loads");
    assert_eq!(p.axes[0].friction.coulomb_smoothing_mm_per_s, 0.4);
    let e = invalid(&text.replace(
        "coulomb_smoothing_mm_per_s: 0.4",
        "coulomb_smoothing_mm_per_s: -1.0",
    ));
    assert!(
        e.iter()
            .any(|m| m.contains("axes.x.friction.coulomb_smoothing_mm_per_s")
                && m.contains("outside the allowed range")),
        "{e:?}"
    );
    let d = Preset::from_ron(&default_text(), "default.ron").expect("default loads");
    assert_eq!(
        d.axes[0].friction.coulomb_smoothing_mm_per_s, 0.0,
        "the exact law unless asked for"
    );
}

#[test]
fn periods_must_be_integer_multiples() {
    let e = invalid(&default_text().replace("t2_s: 0.001", "t2_s: 0.0007"));
    assert!(e.iter().any(|m| m.starts_with("timing.t1_s")), "{e:?}");
    assert!(e.iter().any(|m| m.starts_with("timing.t2_s")), "{e:?}");
}

#[test]
fn unstable_gains_are_rejected_by_their_poles() {
    // The field rules accept the numbers; the stability check (machine::check, which needs
    // the model) rejects them by their closed-loop poles.
    let text = default_text().replace("kv_n_s_per_m: 560000.0", "kv_n_s_per_m: 500000000.0");
    let p = Preset::from_ron(&text, "bad.ron").expect("valid fields");
    let e: Vec<String> = axisbench::machine::check(&p)
        .iter()
        .map(|e| e.to_string())
        .collect();
    assert!(
        e.iter()
            .any(|m| m.contains("axes.x.servo") && m.contains("pole")),
        "{e:?}"
    );
    let stable = Preset::from_ron(&default_text(), "default.ron").expect("default");
    assert!(axisbench::machine::check(&stable).is_empty());
}

#[test]
fn tables_must_increase_strictly() {
    let text = default_text().replace(
        "cumulative_um_per_m: 0.0)",
        "cumulative_um_per_m: 0.0, table: [(0.0, 1.0), (50.0, 2.0), (50.0, 3.0)])",
    );
    let e = invalid(&text);
    assert!(
        e.iter()
            .any(|m| m.contains("axes.x.lead_error.table.2") && m.contains("strictly increasing")),
        "{e:?}"
    );
}

#[test]
fn unknown_fields_syntax_and_version_are_errors() {
    let e = invalid(&default_text().replace("lead_mm: 10.0", "lead_mm: 10.0, pitch_mm: 3.0"));
    assert!(
        e.iter()
            .any(|m| m.contains("bad.ron:") && m.contains("pitch_mm")),
        "{e:?}"
    );
    let e = invalid(&default_text().replace("version: 1", "version: 7"));
    assert!(e.iter().any(|m| m.contains("version 7")), "{e:?}");
    let e = invalid(&default_text().replace("name: \"x\",", "name: \"x\""));
    assert!(e.iter().any(|m| m.starts_with("bad.ron:")), "{e:?}");
}

#[test]
fn overrides_set_nested_fields_by_axis_name() {
    let p = preset::load_embedded("default.ron").expect("loads").preset;
    let q = p
        .set("axes.x.lost_motion.width_um", "12.5")
        .expect("override");
    assert_eq!(q.axes[0].lost_motion.width_um, 12.5);
    let q = p.set("nc.accdec.kind", "bell").expect("enum override");
    assert_eq!(q.nc.accdec.kind, axisbench::preset::AccDecKind::Bell);
    let e = p.set("axes.x.lost_motion.widht_um", "1").expect_err("typo");
    assert!(
        e.to_string().contains(
            "no field 'axes.x.lost_motion.widht_um'; axes.x.lost_motion has: enabled, width_um"
        ),
        "{e}"
    );
    let e = p
        .set("axes.x.drive.table_mass_kg", "-1")
        .expect_err("invalid");
    assert!(
        e.to_string().contains(
            "axes.x.drive.table_mass_kg: -1 is outside the allowed range 0.01 … 1000000 kg"
        ),
        "{e}"
    );
    // An absurd number is refused with a short message, not printed in full.
    let e = p
        .set("axes.x.servo.ki_per_s", "1e300")
        .expect_err("out of range");
    let msg = e.to_string();
    assert!(
        msg.contains("1.000000e300 is outside the allowed range 0 … 100000 1/s"),
        "{msg}"
    );
    assert!(msg.len() < 200, "{msg}");
    let e = p.set("axes.x.servo.kp_per_s", "fast").expect_err("text");
    assert!(e.to_string().contains("'fast' is not a number"), "{e}");
    let e = p.set("nc.accdec.kind", "smooth").expect_err("bad choice");
    assert!(
        e.to_string()
            .contains("'smooth' is not one of: none, linear, bell"),
        "{e}"
    );
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(1000))]

    /// Every numeric field of every shipped preset, set to anything from 1e-300 to 1e300
    /// with either sign (or 0, NaN, inf): the value is either accepted inside its stated
    /// range, or refused with the field's path and that range. An accepted preset still
    /// runs: a machine builds or is refused by the stability check, and a short run stays
    /// finite.
    #[test]
    fn every_numeric_field_is_range_checked(
        preset_i in 0usize..axisbench::preset::SHIPPED_PRESETS.len(),
        field_i in 0usize..10_000,
        mag in -300i32..=300,
        mant in 1.0f64..10.0,
        sign in proptest::bool::ANY,
        special in 0u8..12,
    ) {
        let name = axisbench::preset::SHIPPED_PRESETS[preset_i];
        let lp = preset::load_embedded(name).expect("loads");
        let p = &lp.preset;
        let nums: Vec<(String, axisbench::preset::fields::Num)> = p
            .field_paths()
            .into_iter()
            .filter_map(|(path, r)| r.map(|r| (path, r)))
            .collect();
        let (path, range) = &nums[field_i % nums.len()];
        let x = match special {
            0 => 0.0,
            1 => f64::NAN,
            2 => f64::INFINITY,
            3 => range.lo,
            4 => range.hi,
            _ => {
                let v = mant * 10f64.powi(mag);
                if sign { -v } else { v }
            }
        };
        match p.set(path, &format!("{x}")) {
            Ok(q) => {
                proptest::prop_assert!(range.accepts(x), "{path} = {x} accepted outside {}", range.describe());
                let programs: Vec<(String, String)> = q
                    .scenario
                    .programs
                    .iter()
                    .map(|f| (f.clone(), lp.program_text(f).unwrap_or_default()))
                    .collect();
                if let Ok(mut m) = axisbench::Machine::new(&q, &programs) {
                    m.set_recording(false);
                    m.run_steps(400).map_err(|e| proptest::test_runner::TestCaseError::fail(format!("{path} = {x}: {e}")))?;
                    for a in &m.axes {
                        proptest::prop_assert!(a.pos_m.is_finite(), "{path} = {x}: position not finite");
                    }
                }
            }
            Err(e) => {
                let msg = e.to_string();
                proptest::prop_assert!(!range.accepts(x) || msg.contains(path.as_str()), "{path} = {x}: {msg}");
                proptest::prop_assert!(msg.len() < 4000, "{msg}");
                if !range.accepts(x) {
                    proptest::prop_assert!(msg.contains(path.as_str()) && msg.contains(&range.describe()), "{path} = {x}: {msg}");
                }
            }
        }
    }
}

/// A payload on a spring is modelled on a drive without play: the pair is refused at the
/// coupling's path, and each alone is accepted.
#[test]
fn a_payload_beside_lost_motion_is_refused_at_the_coupling() {
    let mut p = preset::load_embedded("default.ron").expect("loads").preset;
    p.axes[0].drive.coupling = axisbench::preset::Coupling::Payload {
        mass_kg: 20.0,
        stiffness_n_per_um: 10.0,
        damping_n_s_per_m: 1000.0,
        hardening_deflection_um: 2.0,
    };
    p.axes[0].lost_motion.enabled = false;
    assert!(p.validate().is_empty(), "{:?}", p.validate());
    p.axes[0].lost_motion.enabled = true;
    let errs = p.validate();
    assert!(
        errs.iter()
            .any(|e| e.path == "axes.x.drive.coupling" && e.reason.contains("without backlash")),
        "{errs:?}"
    );
}
