//! Thermal displacement correction with automatic re-measurement (thermal patent, SPEC §4).
//!
//! A predictor gives F, the thermal displacement it expects at the measurement point
//! (`measure_pos_mm`). It is the control's own model, deliberately not the plant: either an
//! operation model (a first-order screw temperature heated by commanded speed, with its own
//! capacity, loss and gain) or the plant's screw temperature seen through a lagging sensor.
//! The adjustment value E = a + k·|F|, kept within 0.01…10, scales it: F' = E·F. The screw
//! grows from its fixed bearing, so the correction at position x is F'·(x − x₀)/(x_m − x₀),
//! subtracted from the command (it cancels the predicted growth).
//!
//! Measurement (step 2 of the seed): with correction in force the residual A at the
//! measurement point is measured; the real displacement is D = A + F' (the seed writes
//! D = A + F with F the correction in force, which with E applied is F'); r = D/F (r = E if
//! F = 0); a := r − k·|F|. The judgement that asks for a measurement is one of:
//! - `since_last`: |E − E at the start or at the last measurement| ≥ Em;
//! - `window`: within the current window of ΔT, max(E) − min(E) ≥ Em (the window restarts
//!   after ΔT and after each measurement);
//! - `reference`: at the set times, |E − E_ref(t)| ≥ Em, with E_ref a stored curve.
//!
//! Step 1 (machine maker, once): from a cold machine, with correction on and E = 1, measure
//! A_i at intervals, D_i = A_i + F_i, r_i = D_i/F_i (skip F_i = 0, drop r_i < 0), and fit
//! r = a + k·|F| by least squares; over several programs k is the mean of their slopes.

use super::{CompSignal, PosCompCtx, PositionComp};
use crate::preset::comp::{Judgement, Source, ThermalParams};
use crate::signal::{AxisSignal, Quantity};
use crate::units::{m_to_um, mm_to_m};
use nalgebra::{DMatrix, DVector};

/// Decides when to measure again. Fed E once per period; returns true at the period in which
/// the condition is first met.
#[derive(Debug, Clone)]
pub struct Judge {
    kind: Judgement,
    em: f64,
    window_s: f64,
    checks: Vec<f64>,
    e_ref: Vec<(f64, f64)>,
    next_check: usize,
    e_base: Option<f64>,
    win_start_s: f64,
    win_min: f64,
    win_max: f64,
}

impl Judge {
    /// A judge with the preset's rule, threshold Em, window ΔT and check times; nothing seen yet.
    pub fn new(p: &ThermalParams) -> Judge {
        Judge {
            kind: p.judgement,
            em: p.em,
            window_s: p.window_s,
            checks: p.check_times_s.clone(),
            e_ref: p.e_ref.clone(),
            next_check: 0,
            e_base: None,
            win_start_s: 0.0,
            win_min: f64::INFINITY,
            win_max: f64::NEG_INFINITY,
        }
    }

    /// Feeds E at time `t_s` (s); true while the selected rule says re-measure (E dimensionless).
    pub fn update(&mut self, t_s: f64, e: f64) -> bool {
        match self.kind {
            Judgement::None => false,
            Judgement::SinceLast => {
                let base = *self.e_base.get_or_insert(e);
                (e - base).abs() >= self.em
            }
            Judgement::Window => {
                if t_s - self.win_start_s >= self.window_s {
                    self.restart_window(t_s);
                }
                self.win_min = self.win_min.min(e);
                self.win_max = self.win_max.max(e);
                self.win_max - self.win_min >= self.em
            }
            Judgement::Reference => {
                let mut fire = false;
                while let Some(&tc) = self.checks.get(self.next_check) {
                    if tc > t_s {
                        break;
                    }
                    self.next_check += 1;
                    let e_ref = crate::table::interp(&self.e_ref, tc);
                    fire |= (e - e_ref).abs() >= self.em;
                }
                fire
            }
        }
    }

    fn restart_window(&mut self, t_s: f64) {
        self.win_start_s = t_s;
        self.win_min = f64::INFINITY;
        self.win_max = f64::NEG_INFINITY;
    }

    /// A measurement was taken with E now `e`: restart the comparison.
    pub fn measured(&mut self, t_s: f64, e: f64) {
        self.e_base = Some(e);
        self.restart_window(t_s);
        self.win_min = e;
        self.win_max = e;
    }
}

/// Thermal correction of one axis.
pub struct Thermal {
    axis: usize,
    axis_name: String,
    /// The preset's parameters; `a` is rewritten by each measurement (step 2).
    pub p: ThermalParams,
    judge: Judge,
    /// Predictor state: modelled screw temperature (operation) or sensor reading.
    pub pred_temp_c: f64,
    /// Predicted displacement F at the measurement point, m.
    pub f_m: f64,
    /// Adjustment value E = a + k·|F|, within 0.01…10 (dimensionless).
    pub e: f64,
    /// Applied correction at the measurement point F' = E·F, m.
    pub f_applied_m: f64,
    /// Requested a measurement and waits for it.
    pending: bool,
    /// Measurements taken since start (automatic and requested).
    pub measurements: u32,
    /// Last measured residual A (m), shown as a sparse trace signal.
    pub last_meas_m: Option<f64>,
    /// A measurement not yet shown in the trace: the trace may keep only every n-th sample,
    /// so the value waits for the next recorded row instead of being lost.
    meas_unrecorded: std::cell::Cell<bool>,
    /// Correction at the axis position this cycle, m.
    pub out_m: f64,
    /// (t s, F m, A m) of every measurement, for calibration.
    pub log: Vec<(f64, f64, f64)>,
    t_now_s: f64,
}

impl Thermal {
    /// Correction for axis index `axis` as at power-on: predictor at ambient, F = 0, E = a.
    pub fn new(axis: usize, axis_name: &str, p: ThermalParams) -> Thermal {
        Thermal {
            axis,
            axis_name: axis_name.to_owned(),
            judge: Judge::new(&p),
            pred_temp_c: p.ambient_c,
            f_m: 0.0,
            e: p.e_of(0.0),
            f_applied_m: 0.0,
            pending: false,
            measurements: 0,
            last_meas_m: None,
            meas_unrecorded: std::cell::Cell::new(false),
            out_m: 0.0,
            log: vec![],
            t_now_s: 0.0,
            p,
        }
    }

    /// Index of the corrected axis, in preset order.
    pub fn axis(&self) -> usize {
        self.axis
    }

    /// Adopts edited parameters, keeping the predictor state and the measurement history.
    pub fn retune(&mut self, p: ThermalParams) {
        self.judge = Judge::new(&p);
        self.p = p;
    }

    fn lever_m(&self) -> f64 {
        mm_to_m(self.p.measure_pos_mm - self.p.fixed_end_mm)
    }

    /// Asks for a measurement now (the GUI's "measure now").
    pub fn request_measurement(&mut self) {
        self.pending = true;
    }

    /// The measurement point's position (m) if a measurement is wanted.
    pub fn wants_measurement(&self) -> Option<f64> {
        self.pending.then_some(mm_to_m(self.p.measure_pos_mm))
    }

    /// Takes a measurement: `real_m` is the real thermal displacement at the measurement
    /// point; the instrument reads the residual A = D − F'. Updates a (step 2).
    pub fn measured(&mut self, t_s: f64, real_m: f64) {
        let a_resid = real_m - self.f_applied_m;
        self.log.push((t_s, self.f_m, a_resid));
        let d = a_resid + self.f_applied_m;
        let r = if self.f_m == 0.0 {
            self.e
        } else {
            d / self.f_m
        };
        self.p.a = r - self.p.k_per_um * m_to_um(self.f_m).abs();
        self.e = self.p.e_of(self.f_m);
        self.f_applied_m = self.e * self.f_m;
        self.measurements += 1;
        self.last_meas_m = Some(a_resid);
        self.meas_unrecorded.set(true);
        self.pending = false;
        self.judge.measured(t_s, self.e);
    }

    /// Advances the predictor by `dt_s` with commanded speed and the plant sensor reading.
    pub fn predict(&mut self, t_s: f64, dt_s: f64, speed_mps: f64, screw_temp_c: f64) {
        let p = &self.p;
        match p.source {
            Source::Operation => {
                self.pred_temp_c += dt_s / p.capacity_j_per_k
                    * (p.heat_w_s_per_m * speed_mps
                        - p.loss_w_per_k * (self.pred_temp_c - p.ambient_c));
            }
            Source::Temperature => {
                self.pred_temp_c += dt_s / p.sensor_lag_s * (screw_temp_c - self.pred_temp_c);
            }
        }
        self.f_m = p.alpha_per_k * (self.pred_temp_c - p.reference_c) * self.lever_m();
        self.e = p.e_of(self.f_m);
        self.f_applied_m = self.e * self.f_m;
        if self.judge.update(t_s, self.e) {
            self.pending = true;
        }
    }
}

impl PositionComp for Thermal {
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }

    fn name(&self) -> &str {
        "thermal"
    }

    fn step(&mut self, ctx: &PosCompCtx<'_>, out_m: &mut [f64]) {
        let i = self.axis;
        let speed = (ctx.cmd_m[i] - ctx.prev_cmd_m[i]).abs() / ctx.period_s;
        self.t_now_s = ctx.t_s;
        self.predict(ctx.t_s, ctx.period_s, speed, ctx.temps_c[i]);
        let x0 = mm_to_m(self.p.fixed_end_mm);
        self.out_m = -self.f_applied_m * (ctx.cmd_m[i] - x0) / self.lever_m();
        out_m[i] += self.out_m;
    }

    fn signals(&self) -> Vec<CompSignal> {
        let s = |name: &str, quantity: Quantity| CompSignal {
            axis: self.axis_name.clone(),
            signal: name.into(),
            quantity,
        };
        let mut v = vec![
            s(AxisSignal::ThermalComp.name(), Quantity::Length),
            s("thermal_f", Quantity::Length),
            s("thermal_f_applied", Quantity::Length),
            s("thermal_e", Quantity::Plain),
            s("thermal_a", Quantity::Plain),
            s(AxisSignal::Meas.name(), Quantity::Length),
            s("thermal_measurements", Quantity::Plain),
        ];
        if !self.p.e_ref.is_empty() {
            v.push(s("thermal_e_ref", Quantity::Plain));
            v.push(s("thermal_band_hi", Quantity::Plain));
            v.push(s("thermal_band_lo", Quantity::Plain));
        }
        v
    }

    fn values(&self, out: &mut [f64]) {
        out[0] = self.out_m;
        out[1] = self.f_m;
        out[2] = self.f_applied_m;
        out[3] = self.e;
        out[4] = self.p.a;
        // Sparse: a value only on the row of a measurement (TRACE_FORMAT `meas`).
        out[5] = match (self.meas_unrecorded.replace(false), self.last_meas_m) {
            (true, Some(a)) => a,
            _ => f64::NAN,
        };
        out[6] = self.measurements as f64;
        if out.len() >= 10 {
            let e_ref = crate::table::interp(&self.p.e_ref, self.t_now_s);
            out[7] = e_ref;
            out[8] = e_ref + self.p.em;
            out[9] = e_ref - self.p.em;
        }
    }

    fn measurement_request(&self) -> Option<(usize, f64)> {
        self.wants_measurement().map(|x| (self.axis, x))
    }

    fn measured(&mut self, t_s: f64, real_m: f64) {
        Thermal::measured(self, t_s, real_m);
    }
}

/// Why step 1 could not fit r = a + k·|F|.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CalibError {
    /// A program's series has fewer than 2 usable points, or all at the same |F|.
    #[error(
        "program {program}: {used} usable points (F ≠ 0, r ≥ 0), at least 2 with different |F| are needed"
    )]
    TooFew {
        /// Index of the offending program in the input.
        program: usize,
        /// Points left after dropping F = 0 and r < 0.
        used: usize,
    },
}

/// Step 1 result: the mean slope and each program's own fit.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Step1 {
    /// k: mean of the programs' slopes, per µm of |F|.
    pub k_per_um: f64,
    /// Per program: (a, k per µm, points used).
    pub fits: Vec<(f64, f64, usize)>,
}

/// Step 1 of the seed on measurement series, one per program: points (F m, A m) taken with
/// correction on at E = 1.
pub fn step1(programs: &[Vec<(f64, f64)>]) -> Result<Step1, CalibError> {
    let mut fits = Vec::new();
    for (j, pts) in programs.iter().enumerate() {
        let rows: Vec<(f64, f64)> = pts
            .iter()
            .filter(|(f, _)| *f != 0.0)
            .map(|&(f, a)| (m_to_um(f).abs(), (a + f) / f))
            .filter(|&(_, r)| r >= 0.0 && r.is_finite())
            .collect();
        let distinct = rows.iter().any(|r| r.0 != rows[0].0);
        if rows.len() < 2 || !distinct {
            return Err(CalibError::TooFew {
                program: j,
                used: rows.len(),
            });
        }
        let x = DMatrix::from_fn(rows.len(), 2, |i, c| if c == 0 { 1.0 } else { rows[i].0 });
        let y = DVector::from_iterator(rows.len(), rows.iter().map(|r| r.1));
        let sol = x
            .svd(true, true)
            .solve(&y, 1e-12)
            .map_err(|_| CalibError::TooFew {
                program: j,
                used: rows.len(),
            })?;
        fits.push((sol[0], sol[1], rows.len()));
    }
    let k = fits.iter().map(|f| f.1).sum::<f64>() / fits.len().max(1) as f64;
    Ok(Step1 { k_per_um: k, fits })
}

/// Step 2 of the seed: a from one measurement A (m) taken with F (m) predicted and E in
/// force: D = A + E·F, r = D/F (r = E when F = 0), a = r − k·|F|.
pub fn step2(k_per_um: f64, f_m: f64, a_meas_m: f64, e: f64) -> f64 {
    let d = a_meas_m + e * f_m;
    let r = if f_m == 0.0 { e } else { d / f_m };
    r - k_per_um * m_to_um(f_m).abs()
}
