//! Parse and compile arbitrary text as a program for a 3-axis channel (X, Y, Z), then check
//! what the compiler promises: bounded, finite operations and a short error text.
#![no_main]

use axisbench::nc::program::{self, MAX_BLOCK_TIME_S, MAX_COORD_MM, Op, Path};
use axisbench::units::mm_to_m;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let result = program::parse(text, "fuzz.ngc").and_then(|blocks| {
        program::compile(
            &blocks,
            &['X', 'Y', 'Z'],
            &[0.0; 3],
            1000.0,
            10000.0,
            "fuzz.ngc",
        )
    });
    let ops = match result {
        Ok(ops) => ops,
        Err(e) => {
            let shown = e.to_string();
            assert!(shown.chars().count() < 4000, "{} chars", shown.len());
            assert!(e.line >= 1 && e.col >= 1, "{shown}");
            return;
        }
    };
    let bound_m = mm_to_m(MAX_COORD_MM);
    let mut start = vec![0.0; 3];
    let mut out = vec![0.0; 3];
    for op in &ops {
        match op {
            Op::Move {
                end_m,
                feed_mps,
                path,
                length_m,
                ..
            } => {
                assert!(
                    end_m.iter().all(|x| x.is_finite() && x.abs() <= bound_m),
                    "{op:?}"
                );
                assert!(feed_mps.is_finite() && *feed_mps > 0.0, "{op:?}");
                assert!(length_m.is_finite() && *length_m >= 0.0, "{op:?}");
                assert!(length_m / feed_mps <= MAX_BLOCK_TIME_S, "{op:?}");
                if let Path::Arc {
                    radius_m,
                    sweep_rad,
                    ..
                } = path
                {
                    assert!(radius_m.is_finite() && sweep_rad.is_finite(), "{op:?}");
                }
                for s in [0.0, 0.25, 0.5, 1.0] {
                    program::point_on(path, &start, end_m, s, &mut out);
                    assert!(out.iter().all(|x| x.is_finite()), "{op:?} at {s}");
                }
                start.clone_from(end_m);
            }
            Op::Dwell { t_s, .. } => {
                assert!(
                    t_s.is_finite() && (0.0..=MAX_BLOCK_TIME_S).contains(t_s),
                    "{op:?}"
                );
            }
            Op::Switch { .. } | Op::End => {}
        }
    }
});
