//! Replay of a measured record through the model: the measured command drives the
//! amplifier and plant of one axis from the measured initial state, on the model's T3 grid.
//!
//! The NC is bypassed on purpose: the record's `cmd` is already the interpolated position
//! command, so running the program again would only add the NC's own differences.

use super::DiagnoseError;
use crate::plant::AxisPlant;
use crate::preset::{AxisParams, Feedback, PosSource};
use crate::servo::{Servo, ServoInput};
use crate::trace::Trace;

/// One axis of a measured record on the model's uniform T3 grid, in SI units.
#[derive(Debug, Clone)]
pub struct Record {
    pub axis: String,
    pub t3_s: f64,
    /// Time of the first sample (the record's own clock).
    pub t0_s: f64,
    pub cmd_m: Vec<f64>,
    /// Total compensation the controller added to the command, when recorded.
    pub comp_m: Option<Vec<f64>>,
    pub pos_m: Vec<f64>,
    pub force_n: Option<Vec<f64>>,
    /// Position of the base axis (cross tables, beam sag), when the record has one.
    pub base_pos_m: Option<Vec<f64>>,
    /// True when the record's sampling differed from T3 and it was interpolated.
    pub resampled: bool,
}

impl Record {
    pub fn len(&self) -> usize {
        self.cmd_m.len()
    }

    pub fn is_empty(&self) -> bool {
        self.cmd_m.is_empty()
    }

    pub fn t_s(&self, i: usize) -> f64 {
        self.t0_s + i as f64 * self.t3_s
    }

    /// Reads axis `axis` (and `base`, if given) of `trace` onto the T3 grid. `file` names the
    /// record in errors.
    pub fn from_trace(
        trace: &Trace,
        file: &str,
        axis: &str,
        base: Option<&str>,
        t3_s: f64,
    ) -> Result<Record, DiagnoseError> {
        let bad = |reason: String| DiagnoseError::Record {
            file: file.to_owned(),
            reason,
        };
        let t = trace.t();
        if t.len() < 10 {
            return Err(bad(format!(
                "{} samples; the diagnosis needs at least 10",
                t.len()
            )));
        }
        for (i, w) in t.windows(2).enumerate() {
            if w[1].partial_cmp(&w[0]) != Some(std::cmp::Ordering::Greater) {
                return Err(bad(format!(
                    "t[s] does not increase at data row {} ({} after {})",
                    i + 2,
                    w[1],
                    w[0]
                )));
            }
        }
        let col = |sig: &str, required: bool| -> Result<Option<Vec<f64>>, DiagnoseError> {
            let name = format!("{axis}.{sig}");
            let Some(s) = trace.signal(&name) else {
                if required {
                    let have: Vec<String> = trace
                        .signals
                        .iter()
                        .map(|s| format!("{}[{}]", s.name, s.unit))
                        .collect();
                    return Err(bad(format!(
                        "no column '{name}'; the record has: {}",
                        have.join(", ")
                    )));
                }
                return Ok(None);
            };
            // Traces hold mm; the model works in m.
            let k = if s.unit == "mm" { 1e-3 } else { 1.0 };
            let mut v = Vec::with_capacity(s.data.len());
            for (i, &x) in s.data.iter().enumerate() {
                if !x.is_finite() {
                    return Err(bad(format!(
                        "column '{name}' has no finite value at data row {} ({x}); the diagnosis needs it at every sample",
                        i + 1
                    )));
                }
                v.push(x * k);
            }
            Ok(Some(v))
        };
        let cmd = col("cmd", true)?.unwrap_or_default();
        let pos = col("pos", true)?.unwrap_or_default();
        let comp = col("comp", false)?;
        let force = match col("force", false)? {
            Some(f) => Some(f),
            None => col("torque", false)?.map(|_| Vec::new()),
        };
        if force.as_ref().is_some_and(Vec::is_empty) {
            return Err(bad(format!(
                "'{axis}.torque' is recorded but the diagnosis compares load-side force; map it as '{axis}.force[N]' (torque × 2π/lead)"
            )));
        }
        let base_pos = match base {
            Some(b) => Some(
                trace
                    .values(&format!("{b}.pos"))
                    .ok_or_else(|| bad(format!("no column '{b}.pos' for the base axis '{b}'")))?
                    .iter()
                    .map(|x| x * 1e-3)
                    .collect::<Vec<f64>>(),
            ),
            None => None,
        };
        let n = t.len();
        let dt_mean = (t[n - 1] - t[0]) / (n - 1) as f64;
        let uniform = ((dt_mean - t3_s) / t3_s).abs() < 1e-3
            && t.windows(2)
                .all(|w| ((w[1] - w[0]) - t3_s).abs() < 0.05 * t3_s);
        if uniform {
            return Ok(Record {
                axis: axis.to_owned(),
                t3_s,
                t0_s: t[0],
                cmd_m: cmd,
                comp_m: comp,
                pos_m: pos,
                force_n: force,
                base_pos_m: base_pos,
                resampled: false,
            });
        }
        let m = ((t[n - 1] - t[0]) / t3_s).floor() as usize + 1;
        if m > 50_000_000 {
            return Err(bad(format!(
                "spans {:.1} s, which is {m} model periods of {t3_s} s; too long to replay",
                t[n - 1] - t[0]
            )));
        }
        let grid: Vec<f64> = (0..m).map(|i| t[0] + i as f64 * t3_s).collect();
        let rs = |v: &Vec<f64>| resample(t, v, &grid);
        Ok(Record {
            axis: axis.to_owned(),
            t3_s,
            t0_s: t[0],
            cmd_m: rs(&cmd),
            comp_m: comp.as_ref().map(rs),
            pos_m: rs(&pos),
            force_n: force.as_ref().map(rs),
            base_pos_m: base_pos.as_ref().map(rs),
            resampled: true,
        })
    }

    /// A contiguous piece of the record (for splitting into fit and held-out parts).
    pub fn slice(&self, r: std::ops::Range<usize>) -> Record {
        let s = |v: &Vec<f64>| v[r.clone()].to_vec();
        Record {
            axis: self.axis.clone(),
            t3_s: self.t3_s,
            t0_s: self.t_s(r.start),
            cmd_m: s(&self.cmd_m),
            comp_m: self.comp_m.as_ref().map(s),
            pos_m: s(&self.pos_m),
            force_n: self.force_n.as_ref().map(s),
            base_pos_m: self.base_pos_m.as_ref().map(s),
            resampled: self.resampled,
        }
    }
}

/// Linear interpolation of (t, v) at the sorted `grid` times.
fn resample(t: &[f64], v: &[f64], grid: &[f64]) -> Vec<f64> {
    let mut j = 0;
    grid.iter()
        .map(|&g| {
            while j + 2 < t.len() && t[j + 1] < g {
                j += 1;
            }
            let (t0, t1) = (t[j], t[j + 1]);
            let f = ((g - t0) / (t1 - t0)).clamp(0.0, 1.0);
            v[j] + (v[j + 1] - v[j]) * f
        })
        .collect()
}

/// A window of constant external force on the table (the disturbance candidate).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForceEvent {
    pub i0: usize,
    pub i1: usize,
    pub force_n: f64,
}

/// Everything a candidate can change: the axis parameters plus what lies outside the
/// plant (command delay, external forces).
#[derive(Debug, Clone)]
pub struct Model {
    pub axis: AxisParams,
    pub t3_s: f64,
    pub pos_source: PosSource,
    pub delay_s: f64,
    pub events: Vec<ForceEvent>,
}

/// Simulated signals, sample for sample with the record.
#[derive(Debug, Clone, Default)]
pub struct SimOut {
    pub pos_m: Vec<f64>,
    pub force_n: Vec<f64>,
}

/// Replays `rec[..n]` through `model`. Row k holds the position at the start of period k
/// and the force the amplifier put out during it, as the machine's own trace does.
pub fn simulate(model: &Model, rec: &Record, n: usize) -> SimOut {
    let n = n.min(rec.len());
    let mut out = SimOut {
        pos_m: Vec::with_capacity(n),
        force_n: Vec::with_capacity(n),
    };
    if n == 0 {
        return out;
    }
    let t3 = model.t3_s;
    let a = &model.axis;
    let x0 = rec.pos_m[0];
    let mut plant = AxisPlant::new(a, t3, x0);
    let mut servo = Servo::new(a, t3, rec.cmd_m[0]);
    // Start moving when the record does, so a record cut from a run does not begin with a
    // start-up transient the machine never had.
    if n > 2 {
        let v0 = (rec.cmd_m[1] - rec.cmd_m[0]) / t3;
        plant.v_m = v0;
        plant.v_t = v0;
    }
    let d = model.delay_s / t3;
    let cmd_at = |k: usize| -> f64 {
        if d == 0.0 {
            return rec.cmd_m[k];
        }
        let u = (k as f64 - d).clamp(0.0, (rec.len() - 1) as f64);
        let i = u.floor() as usize;
        let f = u - i as f64;
        if i + 1 < rec.len() {
            rec.cmd_m[i] + (rec.cmd_m[i + 1] - rec.cmd_m[i]) * f
        } else {
            rec.cmd_m[i]
        }
    };
    let inv_t3_sq = 1.0 / (t3 * t3);
    let mut ev = model.events.iter().peekable();
    let mut f_ext = 0.0;
    let mut cur_end = usize::MAX;
    let (mut c1, mut c2) = (cmd_at(0), cmd_at(0));
    for k in 0..n {
        let c = cmd_at(k);
        let acc = if k >= 2 {
            (c - 2.0 * c1 + c2) * inv_t3_sq
        } else {
            0.0
        };
        c2 = c1;
        c1 = c;
        let comp = rec.comp_m.as_ref().map_or(0.0, |v| v[k]);
        let o = &plant.out;
        out.pos_m.push(match model.pos_source {
            PosSource::Load => o.pos_m,
            PosSource::MotorEncoder => o.motor_enc_m,
            PosSource::Scale => o.scale_m,
        });
        let fb = match servo.feedback {
            Feedback::Motor => o.motor_enc_m,
            Feedback::Scale => o.scale_m,
        };
        let input = ServoInput {
            cmd_m: c + comp,
            ff_cmd_m: c,
            fb_pos_m: fb,
            motor_pos_m: o.motor_enc_m,
            vel_add_mps: 0.0,
            force_ff_n: 0.0,
            acc_cmd_mps2: acc,
        };
        let force = servo.step(&input);
        out.force_n.push(force);
        if k >= cur_end {
            f_ext = 0.0;
            cur_end = usize::MAX;
        }
        while let Some(e) = ev.peek() {
            if e.i0 > k {
                break;
            }
            if e.i1 > k {
                f_ext = e.force_n;
                cur_end = e.i1;
            }
            ev.next();
        }
        plant.step(force + f_ext);
    }
    out
}
