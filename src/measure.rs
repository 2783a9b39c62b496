//! Measuring cycles, run on the simulated machine the way an engineer runs them on a real
//! one, to fill the compensations' parameters: a reversal test for the backlash Q, a sag
//! table by moving X across the beam, thermal displacement at intervals, and the seed-002
//! Step 1 / Step 2 calibrations. Every cycle runs with all compensations off except where
//! the procedure needs one on (the thermal calibrations run with thermal correction on).

use crate::comp::thermal::{self, Step1, Thermal};
use crate::machine::{Machine, MachineError};
use crate::preset::Preset;
use crate::trace::AxisSignal;
use crate::units::{m_to_um, mm_to_m};

/// The preset with every compensation switched off and a plain scenario (no PLC events,
/// no fixed duration, every sample traced), as a measuring cycle needs it.
pub fn uncompensated(p: &Preset) -> Preset {
    let mut q = p.compensations_off();
    q.scenario.plc_events.clear();
    q.scenario.duration_s = None;
    q.scenario.trace_every = 1;
    q
}

/// Longest machine time a measuring cycle runs, s (two days of warm-up).
pub const MAX_MEASURE_S: f64 = 172_800.0;
/// Most measurements one cycle takes.
pub const MAX_MEASUREMENTS: usize = 100_000;

/// T3 periods per measuring interval `interval_s`, which must lie between one T2 period
/// (the position command's own period) and [`MAX_MEASURE_S`].
fn interval_steps(flag: &str, interval_s: f64, m: &Machine) -> Result<u64, MachineError> {
    let t2 = m.t3_s * f64::from(m.n23);
    if !(interval_s.is_finite() && interval_s >= t2 && interval_s <= MAX_MEASURE_S) {
        return Err(MachineError::Argument(format!(
            "{flag} {}: the measuring interval must lie in {t2} … {MAX_MEASURE_S} s",
            crate::preset::fields::short(interval_s)
        )));
    }
    Ok((interval_s / m.t3_s).round().max(1.0) as u64)
}

/// Runs the machine `per` periods at a time until it is done, calling `each` after every
/// interval; bounded by [`MAX_MEASURE_S`] of machine time and [`MAX_MEASUREMENTS`].
fn measure_every(
    m: &mut Machine,
    per: u64,
    mut each: impl FnMut(&mut Machine),
) -> Result<(), MachineError> {
    let mut count = 0usize;
    while !m.done() {
        if m.t_s() > MAX_MEASURE_S {
            return Err(MachineError::Argument(format!(
                "the program runs past {MAX_MEASURE_S} s of machine time; a measuring cycle stops there"
            )));
        }
        count += 1;
        if count > MAX_MEASUREMENTS {
            return Err(MachineError::Argument(format!(
                "more than {MAX_MEASUREMENTS} measurements; lengthen the interval"
            )));
        }
        m.run_steps(per)?;
        each(m);
    }
    Ok(())
}

fn axis_index(p: &Preset, name: &str) -> Result<usize, MachineError> {
    p.axes
        .iter()
        .position(|a| a.name == name)
        .ok_or_else(|| MachineError::Structure(format!("no axis named '{name}'")))
}

/// Runs `program` on the channel of `axis`; the other channels only end (their axes hold).
fn run_on_channel(p: &Preset, axis: usize, program: &str) -> Result<Machine, MachineError> {
    let ch = p.axes[axis].channel;
    let programs: Vec<(String, String)> = (0..p.scenario.programs.len())
        .map(|c| {
            let text = if c == ch {
                program.to_owned()
            } else {
                "M30\n".to_owned()
            };
            (format!("measure-ch{}.ngc", c + 1), text)
        })
        .collect();
    let mut m = Machine::new(p, &programs)?;
    m.run(3600.0)?;
    Ok(m)
}

/// Last sample index of each run of `cmd == x` (in order of the targets).
fn dwell_ends(cmd: &[f64], targets: &[f64]) -> Vec<Option<usize>> {
    let mut out = Vec::new();
    let mut from = 0;
    for &x in targets {
        let start = cmd[from..].iter().position(|&c| c == x).map(|i| i + from);
        let end = start.map(|s| s + cmd[s..].iter().take_while(|&&c| c == x).count() - 1);
        if let Some(e) = end {
            from = e + 1;
        }
        out.push(end);
    }
    out
}

/// Reversal test: approach a point from below, read the table; move past it, come back
/// from above, read again. The difference is the lost motion Q (µm).
pub fn backlash_um(p: &Preset, axis_name: &str) -> Result<f64, MachineError> {
    let q = uncompensated(p);
    let i = axis_index(&q, axis_name)?;
    let a = &q.axes[i];
    let l = a.letter;
    let x0 = a.initial_pos_mm + 20.0;
    let prog = format!(
        "G90 G01 F1000\n{l}{:.4}\n{l}{x0:.4}\nG04 P800\n{l}{:.4}\n{l}{x0:.4}\nG04 P800\nM30\n",
        x0 - 10.0,
        x0 + 10.0
    );
    let m = run_on_channel(&q, i, &prog)?;
    let tr = &m.trace;
    let cmd = tr
        .axis_values(axis_name, AxisSignal::Cmd)
        .ok_or_else(|| MachineError::Structure("trace has no cmd".into()))?;
    let pos = tr
        .axis_values(axis_name, AxisSignal::Pos)
        .ok_or_else(|| MachineError::Structure("trace has no pos".into()))?;
    // The program's X word converts to m as the NC converts it, so the dwell matches exactly.
    let x0_m = mm_to_m(x0);
    let ends = dwell_ends(cmd, &[x0_m, x0_m]);
    match (ends[0], ends[1]) {
        (Some(k1), Some(k2)) => Ok(m_to_um(pos[k2] - pos[k1])),
        _ => Err(MachineError::Structure(
            "the reversal test did not reach its point".into(),
        )),
    }
}

/// Sag table: moves `base_axis` across the beam to `n` evenly spaced points from `from_mm`
/// to `to_mm`, and reads the error of `comp_axis` at each. Returns (x mm, correction µm)
/// ready for a cross table. Every other axis stays parked where the preset starts it; the
/// base axis may be on another channel than the compensated one (the other tool post).
pub fn sag_table(
    p: &Preset,
    base_axis: &str,
    comp_axis: &str,
    n: usize,
    from_mm: f64,
    to_mm: f64,
) -> Result<Vec<(f64, f64)>, MachineError> {
    if n < 2 {
        return Err(MachineError::Structure(
            "a sag table needs at least 2 points".into(),
        ));
    }
    let q = uncompensated(p);
    let ib = axis_index(&q, base_axis)?;
    axis_index(&q, comp_axis)?;
    let l = q.axes[ib].letter;
    let xs: Vec<f64> = (0..n)
        .map(|k| {
            let x = from_mm + (to_mm - from_mm) * k as f64 / (n - 1) as f64;
            (x * 1e4).round() / 1e4
        })
        .collect();
    let mut prog = String::from("G90 G01 F8000\n");
    for x in &xs {
        prog += &format!("{l}{x:.4}\nG04 P300\n");
    }
    prog += "M30\n";
    let m = run_on_channel(&q, ib, &prog)?;
    let tr = &m.trace;
    let missing = || MachineError::Structure("trace lacks the measured signals".into());
    let cmd = tr
        .axis_values(base_axis, AxisSignal::Cmd)
        .ok_or_else(missing)?;
    let err = tr
        .axis_values(comp_axis, AxisSignal::Err)
        .ok_or_else(missing)?;
    let xs_m: Vec<f64> = xs.iter().map(|&x| mm_to_m(x)).collect();
    let ends = dwell_ends(cmd, &xs_m);
    xs.iter()
        .zip(ends)
        .map(|(&x, e)| {
            e.map(|k| (x, m_to_um(err[k]))).ok_or_else(|| {
                MachineError::Structure(format!("the sag run did not reach X = {x}"))
            })
        })
        .collect()
}

/// The real thermal displacement (µm) at the thermal measurement point of `axis_name`,
/// every `interval_s`, over the preset's own scenario with compensations off.
pub fn thermal_series(
    p: &Preset,
    programs: &[(String, String)],
    axis_name: &str,
    interval_s: f64,
) -> Result<Vec<(f64, f64)>, MachineError> {
    let q = uncompensated(p);
    let i = axis_index(&q, axis_name)?;
    let x = mm_to_m(q.axes[i].thermal.measure_pos_mm);
    let mut m = Machine::new(&q, programs)?;
    m.set_recording(false);
    let per = interval_steps("--interval", interval_s, &m)?;
    let at = |m: &Machine| {
        (
            m.t_s(),
            m_to_um(m.axes[i].axis_loop.plant().thermal().elongation_m(x)),
        )
    };
    let mut out = vec![at(&m)];
    measure_every(&mut m, per, |m| out.push(at(m)))?;
    Ok(out)
}

/// Runs `programs` (one run each, from cold) with thermal correction on at E = 1, measuring
/// at the measurement point every `interval_s`; returns each run's (F m, A m) series.
pub fn thermal_step1_runs(
    p: &Preset,
    axis_name: &str,
    runs: &[Vec<(String, String)>],
    interval_s: f64,
) -> Result<Vec<Vec<(f64, f64)>>, MachineError> {
    let mut q = uncompensated(p);
    let i = axis_index(&q, axis_name)?;
    let th = &mut q.axes[i].thermal;
    *th = p.axes[i].thermal.clone();
    th.enabled = true;
    th.a = 1.0;
    th.k_per_um = 0.0;
    th.judgement = crate::preset::comp::Judgement::None;
    let mut out = Vec::new();
    for programs in runs {
        let mut m = Machine::new(&q, programs)?;
        m.set_recording(false);
        let per = interval_steps("--interval", interval_s, &m)?;
        measure_every(&mut m, per, |m| {
            for t in m.find_comp_mut::<Thermal>() {
                t.request_measurement();
            }
        })?;
        m.run_steps(u64::from(m.n23))?;
        let log = m
            .find_comp::<Thermal>()
            .next()
            .map(|t| t.log.iter().map(|&(_, f, a)| (f, a)).collect())
            .unwrap_or_default();
        out.push(log);
    }
    Ok(out)
}

/// Step 1 on the simulated machine: k from several programs.
pub fn thermal_step1(
    p: &Preset,
    axis_name: &str,
    runs: &[Vec<(String, String)>],
    interval_s: f64,
) -> Result<Step1, MachineError> {
    let series = thermal_step1_runs(p, axis_name, runs, interval_s)?;
    thermal::step1(&series).map_err(|e| MachineError::Structure(e.to_string()))
}

/// Step 2 on the simulated machine: runs `programs` with the preset's k and a, takes one
/// measurement at `at_s`, and returns the new a.
pub fn thermal_step2(
    p: &Preset,
    axis_name: &str,
    programs: &[(String, String)],
    at_s: f64,
) -> Result<f64, MachineError> {
    let mut q = uncompensated(p);
    let i = axis_index(&q, axis_name)?;
    q.axes[i].thermal = p.axes[i].thermal.clone();
    q.axes[i].thermal.enabled = true;
    q.axes[i].thermal.judgement = crate::preset::comp::Judgement::None;
    let mut m = Machine::new(&q, programs)?;
    m.set_recording(false);
    if !(at_s.is_finite() && at_s > 0.0 && at_s <= MAX_MEASURE_S) {
        return Err(MachineError::Argument(format!(
            "--at {}: the measurement time must lie in (0, {MAX_MEASURE_S}] s",
            crate::preset::fields::short(at_s)
        )));
    }
    m.run_steps((at_s / m.t3_s).round() as u64)?;
    for t in m.find_comp_mut::<Thermal>() {
        t.request_measurement();
    }
    m.run_steps(u64::from(m.n23))?;
    m.find_comp::<Thermal>()
        .next()
        .map(|t| t.p.a)
        .ok_or_else(|| MachineError::Structure("no thermal correction installed".into()))
}

/// All cross tables for a crossbeam with one or two tool posts, `n` points each over the
/// span. Each post's Z gets a table over its own X (measured with the other post parked)
/// and, with two posts, one over the other post's X, zeroed at that post's parking position
/// so the two add without counting the parked load twice. The sum is exact while either
/// post stands at its parking position; elsewhere it leaves the small interaction term of
/// two loads on one beam.
pub fn sag_tables(
    p: &Preset,
    n: usize,
) -> Result<Vec<crate::preset::comp::CrossTable>, MachineError> {
    let cb = &p.crossbeam;
    if !cb.enabled {
        return Err(MachineError::Structure(
            "the preset has no crossbeam".into(),
        ));
    }
    let mut out = Vec::new();
    for post in &cb.posts {
        for other in &cb.posts {
            let mut points = sag_table(p, &other.x_axis, &post.z_axis, n, 0.0, cb.span_mm)?;
            if other.x_axis != post.x_axis {
                let park = p.axes[axis_index(p, &other.x_axis)?].initial_pos_mm;
                let at_park = crate::table::interp(&points, park);
                for pt in &mut points {
                    pt.1 -= at_park;
                }
            }
            out.push(crate::preset::comp::CrossTable {
                enabled: true,
                base_axis: other.x_axis.clone(),
                comp_axis: post.z_axis.clone(),
                points,
            });
        }
    }
    Ok(out)
}
