//! LinuxCNC 2.9 joint compensation, modelled operation for operation so that axisbench can
//! predict what a LinuxCNC machine does with an exported preset (and the conformance test
//! can check it against the real LinuxCNC to 2e-6 mm).
//!
//! Sources (LinuxCNC 2.9, `src/emc/motion/`):
//! - `command.c`, case `EMCMOT_SET_JOINT_COMP`: rows are appended one by one; a row whose
//!   nominal is not above the previous accepted row is rejected ("compensation values must
//!   increase"), more than `EMCMOT_COMP_SIZE` = 256 rows are rejected ("too many
//!   compensation entries"). Each accepted row sets the slopes of the row before it; the
//!   first row also sets the trims of the −DBL_MAX sentinel in front of it (slope 0), and
//!   the last row keeps slope 0 up to the +DBL_MAX sentinel. So the end trims are held
//!   outside the table and nothing is extrapolated.
//! - `motion.c` (joint init): `comp.array[0].nominal = -DBL_MAX`, every other entry
//!   `+DBL_MAX`, trims and slopes 0, `comp.entry = &array[0]`.
//! - `control.c`, `compute_screw_comp()`: with table rows, `backlash_corr` is the forward
//!   trim + forward slope·(pos − nominal) while `vel_cmd > 0`, the reverse one while
//!   `vel_cmd < 0`, and unchanged while `vel_cmd == 0`; without rows it is ±BACKLASH/2 by the
//!   same sign rule (so BACKLASH is ignored once a table is loaded). `backlash_filt` then
//!   follows `backlash_corr` with a trapezoidal velocity profile limited to
//!   0.5·vel_limit·net_feed_scale and 0.5·acc_limit (Bas Laarhoven's 2005 S-curve code).
//! - `control.c`, `output_to_hal()`: `motor_pos_cmd = pos_cmd + backlash_filt + motor_offset`.
//! - `usrmotintf.cc`, `usrmotLoadComp()`: the comp file is read line by line with
//!   `sscanf("%lf %lf %lf")` and reading stops at the first line that is not three numbers;
//!   type 0 rows hold positions (trim = nominal − value), type 1 rows hold trims.
//!
//! Everything is in LinuxCNC machine units (mm here) and f64, in the same order of
//! operations as the C code, because the conformance test compares to 1e-6 mm.

use super::{CompSignal, PosCompCtx, PositionComp};
use crate::signal::Quantity;
use crate::units::{m_to_mm, mm_to_m};

/// `EMCMOT_COMP_SIZE`: rows a joint's comp table can hold.
pub const COMP_SIZE: usize = 256;

/// One comp-file row as LinuxCNC stores it: nominal position and the two trims.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CompRow {
    /// Nominal (commanded) joint position of the row, mm; rows must strictly increase.
    pub nominal: f64,
    /// Trim added while moving in + (`vel_cmd > 0`).
    pub fwd: f64,
    /// Trim added while moving in − (`vel_cmd < 0`).
    pub rev: f64,
}

impl CompRow {
    /// A `COMP_FILE_TYPE = 0` row (nominal, position reached moving +, moving −), converted
    /// as `usrmotLoadComp` does: trim = nominal − value.
    pub fn from_type0(nominal: f64, fwd_pos: f64, rev_pos: f64) -> CompRow {
        CompRow {
            nominal,
            fwd: nominal - fwd_pos,
            rev: nominal - rev_pos,
        }
    }
}

/// A row LinuxCNC would reject while loading (it reports it and carries on).
#[derive(Debug, Clone, PartialEq)]
pub enum LoadIssue {
    /// "joint N: compensation values must increase"
    NotIncreasing {
        /// Index of the rejected row in the input (0-based).
        row: usize,
        /// Its nominal position, mm.
        nominal: f64,
        /// Nominal of the last accepted row it fails to exceed, mm.
        prev: f64,
    },
    /// "joint N: too many compensation entries"
    TooMany {
        /// Index of the dropped row in the input (0-based); every row past [`COMP_SIZE`].
        row: usize,
    },
}

impl std::fmt::Display for LoadIssue {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LoadIssue::NotIncreasing { row, nominal, prev } => write!(
                f,
                "row {}: nominal {nominal} is not above the previous row's {prev}; LinuxCNC rejects it (\"compensation values must increase\")",
                row + 1
            ),
            LoadIssue::TooMany { row } => write!(
                f,
                "row {}: beyond the {COMP_SIZE} rows a joint holds; LinuxCNC drops it (\"too many compensation entries\")",
                row + 1
            ),
        }
    }
}

#[derive(Debug, Clone, Copy)]
struct Entry {
    nominal: f64,
    fwd_trim: f64,
    rev_trim: f64,
    fwd_slope: f64,
    rev_slope: f64,
}

const SENTINEL_HI: Entry = Entry {
    nominal: f64::MAX,
    fwd_trim: 0.0,
    rev_trim: 0.0,
    fwd_slope: 0.0,
    rev_slope: 0.0,
};

/// A joint's loaded comp table, with LinuxCNC's −DBL_MAX/+DBL_MAX sentinels.
#[derive(Debug, Clone)]
pub struct CompTable {
    /// `[−DBL_MAX sentinel, accepted rows…, +DBL_MAX sentinel]`.
    entries: Vec<Entry>,
}

impl Default for CompTable {
    fn default() -> Self {
        CompTable::load(&[]).0
    }
}

impl CompTable {
    /// Loads rows as `EMCMOT_SET_JOINT_COMP` does, one command per row; returns the table
    /// and every row LinuxCNC would reject.
    pub fn load(rows: &[CompRow]) -> (CompTable, Vec<LoadIssue>) {
        let mut entries = vec![Entry {
            nominal: -f64::MAX,
            ..SENTINEL_HI
        }];
        let mut issues = Vec::new();
        for (i, r) in rows.iter().enumerate() {
            let n = entries.len() - 1; // comp.entries
            if n >= COMP_SIZE {
                issues.push(LoadIssue::TooMany { row: i });
                continue;
            }
            let prev = entries[n];
            // `if (comp_nominal <= comp_entry[0].nominal)`: a NaN nominal passes this test.
            if r.nominal <= prev.nominal {
                issues.push(LoadIssue::NotIncreasing {
                    row: i,
                    nominal: r.nominal,
                    prev: prev.nominal,
                });
                continue;
            }
            let new = Entry {
                nominal: r.nominal,
                fwd_trim: r.fwd,
                rev_trim: r.rev,
                fwd_slope: 0.0,
                rev_slope: 0.0,
            };
            if prev.nominal != -f64::MAX {
                let tmp1 = new.nominal - prev.nominal;
                entries[n].fwd_slope = (new.fwd_trim - prev.fwd_trim) / tmp1;
                entries[n].rev_slope = (new.rev_trim - prev.rev_trim) / tmp1;
            } else {
                entries[n].fwd_trim = new.fwd_trim;
                entries[n].rev_trim = new.rev_trim;
            }
            entries.push(new);
        }
        entries.push(SENTINEL_HI);
        (CompTable { entries }, issues)
    }

    /// Accepted rows (`comp.entries`).
    pub fn len(&self) -> usize {
        self.entries.len() - 2
    }

    /// No rows accepted: the joint falls back to ±BACKLASH/2.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The (fwd, rev) trims at `pos`, for reports and plots (no pointer state).
    pub fn trims_at(&self, pos: f64) -> (f64, f64) {
        let i = self.entries.partition_point(|e| e.nominal <= pos).max(1) - 1;
        let e = &self.entries[i];
        let dpos = pos - e.nominal;
        (
            e.fwd_trim + e.fwd_slope * dpos,
            e.rev_trim + e.rev_slope * dpos,
        )
    }
}

/// The joint settings the compensation uses, in machine units.
#[derive(Debug, Clone, PartialEq)]
pub struct JointParams {
    /// `[JOINT_n]BACKLASH`; used only while the table is empty.
    pub backlash: f64,
    /// `[JOINT_n]MAX_VELOCITY` (`joint->vel_limit`).
    pub max_velocity: f64,
    /// `[JOINT_n]MAX_ACCELERATION` (`joint->acc_limit`).
    pub max_acceleration: f64,
    /// Servo period in s (`[EMCMOT]SERVO_PERIOD`·1e−9).
    pub servo_period_s: f64,
    /// `emcmotStatus->net_feed_scale` (feed override and friends), 1 at 100 %.
    pub feed_scale: f64,
}

/// The compensation state of one LinuxCNC joint: one [`LinuxCncComp::step`] per servo period.
#[derive(Debug, Clone)]
pub struct LinuxCncComp {
    /// The joint's loaded comp table; when non-empty it replaces BACKLASH.
    pub table: CompTable,
    /// Joint limits and servo period the ramp uses.
    pub p: JointParams,
    /// `comp.entry`: index of the table entry at or below the last position.
    entry: usize,
    /// `joint->backlash_corr`: the raw correction for the current direction and position, mm.
    pub backlash_corr: f64,
    /// `joint->backlash_filt`: the ramped correction added to `motor_pos_cmd`, mm.
    pub backlash_filt: f64,
    /// `joint->backlash_vel`: rate of `backlash_filt` in the ramp, mm/s (signed).
    pub backlash_vel: f64,
}

impl LinuxCncComp {
    /// A joint as after LinuxCNC start-up: corrections 0, table pointer at the low sentinel.
    pub fn new(table: CompTable, p: JointParams) -> LinuxCncComp {
        LinuxCncComp {
            table,
            p,
            entry: 0,
            backlash_corr: 0.0,
            backlash_filt: 0.0,
            backlash_vel: 0.0,
        }
    }

    /// One servo period with the joint's `pos_cmd` and `vel_cmd` of that period; returns
    /// `motor_pos_cmd` (motor offset 0).
    pub fn step(&mut self, pos_cmd: f64, vel_cmd: f64) -> f64 {
        self.correction(pos_cmd, vel_cmd);
        self.ramp();
        pos_cmd + self.backlash_filt
    }

    /// `compute_screw_comp`, first half: the raw correction.
    fn correction(&mut self, pos_cmd: f64, vel_cmd: f64) {
        if !self.table.is_empty() {
            let e = &self.table.entries;
            while pos_cmd < e[self.entry].nominal {
                self.entry -= 1;
            }
            while pos_cmd >= e[self.entry + 1].nominal {
                self.entry += 1;
            }
            let c = &e[self.entry];
            let dpos = pos_cmd - c.nominal;
            if vel_cmd > 0.0 {
                self.backlash_corr = c.fwd_trim + c.fwd_slope * dpos;
            } else if vel_cmd < 0.0 {
                self.backlash_corr = c.rev_trim + c.rev_slope * dpos;
            }
        } else if vel_cmd > 0.0 {
            self.backlash_corr = 0.5 * self.p.backlash;
        } else if vel_cmd < 0.0 {
            self.backlash_corr = -0.5 * self.p.backlash;
        }
    }

    /// `compute_screw_comp`, second half: the trapezoidal ramp of `backlash_filt`.
    fn ramp(&mut self) {
        let servo_period = self.p.servo_period_s;
        let v_max = 0.5 * self.p.max_velocity * self.p.feed_scale;
        let a_max = 0.5 * self.p.max_acceleration;
        let v = self.backlash_vel;
        if self.backlash_corr >= self.backlash_filt {
            let s_to_go = self.backlash_corr - self.backlash_filt;
            if s_to_go > 0.0 {
                let ds_vel = v * servo_period;
                let mut dv_acc = a_max * servo_period;
                let ds_stop = 0.5 * (v + dv_acc) * (v + dv_acc) / a_max;
                if s_to_go <= ds_stop + ds_vel {
                    if v > dv_acc {
                        let ds_acc = 0.5 * dv_acc * servo_period;
                        self.backlash_vel -= dv_acc;
                        self.backlash_filt += ds_vel - ds_acc;
                    } else {
                        self.backlash_vel = 0.0;
                        self.backlash_filt = self.backlash_corr;
                    }
                } else {
                    if v + dv_acc > v_max {
                        dv_acc = v_max - v;
                    }
                    let ds_acc = 0.5 * dv_acc * servo_period;
                    let ds_stop = 0.5 * (v + dv_acc) * (v + dv_acc) / a_max;
                    if s_to_go > ds_stop + ds_vel + ds_acc {
                        self.backlash_vel += dv_acc;
                        self.backlash_filt += ds_vel + ds_acc;
                    } else {
                        self.backlash_filt += ds_vel;
                    }
                }
            } else if s_to_go < 0.0 {
                self.backlash_vel = 0.0;
                self.backlash_filt = self.backlash_corr;
            }
        } else {
            let s_to_go = self.backlash_filt - self.backlash_corr;
            if s_to_go > 0.0 {
                let ds_vel = -v * servo_period;
                let mut dv_acc = a_max * servo_period;
                let ds_stop = 0.5 * (v - dv_acc) * (v - dv_acc) / a_max;
                if s_to_go <= ds_stop + ds_vel {
                    if -v > dv_acc {
                        let ds_acc = 0.5 * dv_acc * servo_period;
                        self.backlash_vel += dv_acc;
                        self.backlash_filt -= ds_vel - ds_acc;
                    } else {
                        self.backlash_vel = 0.0;
                        self.backlash_filt = self.backlash_corr;
                    }
                } else {
                    if -v + dv_acc > v_max {
                        dv_acc = v_max + v;
                    }
                    let ds_acc = 0.5 * dv_acc * servo_period;
                    let ds_stop = 0.5 * (v - dv_acc) * (v - dv_acc) / a_max;
                    if s_to_go > ds_stop + ds_vel + ds_acc {
                        self.backlash_vel -= dv_acc;
                        self.backlash_filt -= ds_vel + ds_acc;
                    } else {
                        self.backlash_filt -= ds_vel;
                    }
                }
            } else if s_to_go < 0.0 {
                self.backlash_vel = 0.0;
                self.backlash_filt = self.backlash_corr;
            }
        }
    }
}

/// The LinuxCNC compensation installed in an axisbench machine (position stage, mm inside),
/// so a report can simulate what the exported settings do on the modelled axis. The NC's
/// generation period stands in for the servo period.
pub struct LinuxCncPosComp {
    axis: usize,
    axis_name: String,
    /// The modelled LinuxCNC joint (mm); its servo period is set from each generation period.
    pub joint: LinuxCncComp,
}

impl LinuxCncPosComp {
    /// Installs `joint` on axis index `axis`, named `axis_name` in the trace.
    pub fn new(axis: usize, axis_name: &str, joint: LinuxCncComp) -> LinuxCncPosComp {
        LinuxCncPosComp {
            axis,
            axis_name: axis_name.to_owned(),
            joint,
        }
    }
}

impl PositionComp for LinuxCncPosComp {
    fn reads_machine(&self) -> bool {
        false
    }

    fn name(&self) -> &str {
        "linuxcnc"
    }

    fn step(&mut self, ctx: &PosCompCtx<'_>, out_m: &mut [f64]) {
        let pos_mm = m_to_mm(ctx.cmd_m[self.axis]);
        let d_m = ctx.cmd_m[self.axis] - ctx.prev_cmd_m[self.axis];
        // Standstill is exactly zero velocity in LinuxCNC; the NC's filters can leave
        // sub-picometre noise, which axisbench's own backlash also treats as standstill.
        let vel = if d_m.abs() <= super::backlash::MOVE_EPS_M {
            0.0
        } else {
            m_to_mm(d_m) / ctx.period_s
        };
        self.joint.p.servo_period_s = ctx.period_s;
        self.joint.step(pos_mm, vel);
        out_m[self.axis] += mm_to_m(self.joint.backlash_filt);
    }

    fn signals(&self) -> Vec<CompSignal> {
        vec![CompSignal {
            axis: self.axis_name.clone(),
            signal: "linuxcnc_comp".into(),
            quantity: Quantity::Length,
        }]
    }

    fn values(&self, out: &mut [f64]) {
        out[0] = mm_to_m(self.joint.backlash_filt);
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn joint(backlash: f64, vmax: f64, amax: f64) -> JointParams {
        JointParams {
            backlash,
            max_velocity: vmax,
            max_acceleration: amax,
            servo_period_s: 0.001,
            feed_scale: 1.0,
        }
    }

    fn rows(r: &[(f64, f64, f64)]) -> Vec<CompRow> {
        r.iter()
            .map(|&(nominal, fwd, rev)| CompRow { nominal, fwd, rev })
            .collect()
    }

    #[test]
    fn trims_interpolate_and_hold_the_ends() {
        let (t, issues) = CompTable::load(&rows(&[
            (0.0, 0.010, -0.010),
            (10.0, 0.020, -0.005),
            (20.0, 0.000, -0.020),
        ]));
        assert!(issues.is_empty());
        assert_eq!(t.len(), 3);
        assert_eq!(t.trims_at(-5.0), (0.010, -0.010), "held below");
        assert_eq!(t.trims_at(25.0), (0.0, -0.020), "held above");
        let (f, r) = t.trims_at(5.0);
        assert!((f - 0.015).abs() < 1e-15 && (r + 0.0075).abs() < 1e-15);
    }

    #[test]
    fn rejected_rows_are_reported_like_linuxcnc() {
        let mut r = rows(&[(0.0, 0.0, 0.0), (10.0, 0.0, 0.0), (5.0, 1.0, 1.0)]);
        for i in 0..300 {
            r.push(CompRow {
                nominal: 20.0 + i as f64,
                fwd: 0.0,
                rev: 0.0,
            });
        }
        let (t, issues) = CompTable::load(&r);
        assert_eq!(t.len(), COMP_SIZE);
        assert!(matches!(issues[0], LoadIssue::NotIncreasing { row: 2, .. }));
        assert_eq!(issues.len(), 1 + (302 - COMP_SIZE));
    }

    #[test]
    fn backlash_only_is_plus_minus_half_and_held_at_standstill() {
        let mut c = LinuxCncComp::new(CompTable::default(), joint(0.05, 50.0, 500.0));
        c.step(0.0, 0.0);
        assert_eq!(c.backlash_corr, 0.0, "starts at 0 and holds at rest");
        c.step(0.001, 1.0);
        assert_eq!(c.backlash_corr, 0.025);
        c.step(0.001, 0.0);
        assert_eq!(c.backlash_corr, 0.025, "held while vel_cmd == 0");
        c.step(0.0, -1.0);
        assert_eq!(c.backlash_corr, -0.025);
    }

    #[test]
    fn the_ramp_is_trapezoidal_at_half_the_joint_limits() {
        // README of the shared tool: B = 0.05, MAX_ACC = 500: backlash_vel steps by
        // 0.25 mm/s per 1 ms, the reversal ramp is triangular and takes about 28–30 ms.
        let mut c = LinuxCncComp::new(CompTable::default(), joint(0.05, 50.0, 500.0));
        for _ in 0..100 {
            c.step(0.0, 1.0);
        }
        assert_eq!(c.backlash_filt, 0.025);
        let mut peak: f64 = 0.0;
        let mut n = 0;
        while c.backlash_filt != -0.025 {
            let before = c.backlash_vel;
            c.step(0.0, -1.0);
            assert!(
                (c.backlash_vel - before).abs() <= 0.25 + 1e-12,
                "a ≤ 250 mm/s²"
            );
            peak = peak.max(c.backlash_vel.abs());
            n += 1;
            assert!(n < 100, "the ramp ends");
        }
        assert!((25..=32).contains(&n), "{n} periods");
        assert!(
            (peak - 3.5).abs() < 0.26,
            "triangular peak ≈ √(B·a) = 3.5: {peak}"
        );
        // With MAX_VELOCITY = 4 the peak is capped at 2 mm/s.
        let mut c = LinuxCncComp::new(CompTable::default(), joint(0.05, 4.0, 500.0));
        let mut peak: f64 = 0.0;
        for _ in 0..60 {
            c.step(0.0, 1.0);
            peak = peak.max(c.backlash_vel);
        }
        assert_eq!(peak, 2.0);
    }

    #[test]
    fn backlash_is_ignored_once_a_table_is_loaded() {
        let (t, _) = CompTable::load(&rows(&[(0.0, 0.001, -0.001)]));
        let mut c = LinuxCncComp::new(t, joint(0.5, 50.0, 500.0));
        for _ in 0..50 {
            c.step(1.0, 1.0);
        }
        assert_eq!(c.backlash_filt, 0.001);
    }
}
