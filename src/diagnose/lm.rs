//! Bounded Levenberg–Marquardt on replay residuals (the `levenberg-marquardt` crate), for the
//! calibration and for every candidate. Parameters are scaled to order 1 and clamped to
//! their bounds; the Jacobian is a forward difference of whole replays, or for the later
//! rounds' candidates a secant update of the last one between two of those
//! (`SECANT_UPDATES`).

use std::cell::RefCell;

use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{DMatrix, DVector, Dyn, Owned};

use super::DiagnoseError;

/// One fitted parameter: its bounds and a typical magnitude (the solver works in units of
/// it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Param {
    /// Smallest allowed value.
    pub lo: f64,
    /// Largest allowed value.
    pub hi: f64,
    /// Typical magnitude.
    pub scale: f64,
}

/// The residual rows at a parameter vector: None when the replay diverged there.
/// `Sync`: the Jacobian's columns are replayed on two threads.
pub type Rows<'a> = dyn Fn(&[f64]) -> Result<Option<DVector<f64>>, DiagnoseError> + Sync + 'a;

/// A fit's result.
#[derive(Debug, Clone)]
pub struct LmFit {
    /// The parameters.
    pub theta: Vec<f64>,
    /// Sum of squared rows at the optimum.
    pub cost: f64,
    /// Rows and Jacobian at the optimum (for parameter uncertainties).
    pub rows: Option<DVector<f64>>,
    /// The Jacobian in unscaled parameters.
    pub jacobian: Option<DMatrix<f64>>,
}

struct Problem<'r, 'a> {
    params: &'r [Param],
    rows: &'r Rows<'a>,
    x: DVector<f64>,
    /// Relative step of the forward differences: large enough not to see the encoder grid
    /// and the stick-slip switching instead of the trend.
    step: f64,
    last_j: RefCell<Option<Jac>>,
    /// Secant (Broyden) updates between two whole Jacobians.
    secant: usize,
    /// The rows at the last point the solver asked the residuals of: it asks the Jacobian
    /// there next, and the replay for its base column would be the same one again (a
    /// quarter of a three-parameter fit's replays).
    last_r: RefCell<Option<(DVector<f64>, DVector<f64>)>>,
    err: RefCell<Option<DiagnoseError>>,
}

/// The last Jacobian the solver was given.
struct Jac {
    /// Its point.
    x: DVector<f64>,
    /// The Jacobian.
    j: DMatrix<f64>,
    /// The rows at `x`.
    rows: DVector<f64>,
    /// Secant updates since it was last replayed column by column.
    updates: usize,
}

/// The parameters at solver point `x` (scaled, then clamped to their bounds).
fn theta_of(params: &[Param], x: &DVector<f64>) -> Vec<f64> {
    x.iter()
        .zip(params)
        .map(|(x, p)| (x * p.scale).clamp(p.lo, p.hi))
        .collect()
}

/// The rows at solver point `x` as the replay gave them: None when it diverged or gave a
/// non-finite row. Touches no solver state, so a Jacobian column can run on any thread.
fn replay(
    rows: &Rows<'_>,
    params: &[Param],
    x: &DVector<f64>,
) -> Result<Option<DVector<f64>>, DiagnoseError> {
    rows(&theta_of(params, x)).map(|r| r.filter(|r| r.iter().all(|v| v.is_finite())))
}

impl Problem<'_, '_> {
    fn theta_of(&self, x: &DVector<f64>) -> Vec<f64> {
        theta_of(self.params, x)
    }

    fn rows_at(&self, x: &DVector<f64>) -> Option<DVector<f64>> {
        if self.err.borrow().is_some() {
            return None;
        }
        self.keep(self.replay(x))
    }

    /// The rows at `x` as the replay gave them.
    fn replay(&self, x: &DVector<f64>) -> Result<Option<DVector<f64>>, DiagnoseError> {
        replay(self.rows, self.params, x)
    }

    /// A replay's rows, its error kept for [`fit`] to return.
    fn keep(&self, r: Result<Option<DVector<f64>>, DiagnoseError>) -> Option<DVector<f64>> {
        match r {
            Ok(r) => r,
            Err(e) => {
                *self.err.borrow_mut() = Some(e);
                None
            }
        }
    }

    /// The residuals the solver asked for last, when they were at `x`.
    fn last_rows_at(&self, x: &DVector<f64>) -> Option<DVector<f64>> {
        self.last_r
            .borrow()
            .as_ref()
            .filter(|(xr, _)| xr == x)
            .map(|(_, r)| r.clone())
    }

    /// [`Problem::rows_at`], from the residuals the solver asked last when they were at `x`.
    fn rows_cached(&self, x: &DVector<f64>) -> Option<DVector<f64>> {
        self.last_rows_at(x).or_else(|| self.rows_at(x))
    }

    fn jac_at(&self, x: &DVector<f64>) -> Option<DMatrix<f64>> {
        self.jac_within(x, self.secant)
    }

    /// The Jacobian at `x` (see [`Problem::jac_to`]).
    fn jac_within(&self, x: &DVector<f64>, secant: usize) -> Option<DMatrix<f64>> {
        self.jac_to(x, secant)?;
        self.last_j.borrow().as_ref().map(|last| last.j.clone())
    }

    /// Makes `last_j` the Jacobian at `x`: the last one when it is there, else the last one
    /// updated by the secant of the step to `x` (Broyden's rank-one update, from the rows
    /// the solver just asked for there) when it has had fewer than `secant` updates, else
    /// replayed whole. In place: a Jacobian is m × n, and its copies were a tenth of a fit.
    fn jac_to(&self, x: &DVector<f64>, secant: usize) -> Option<()> {
        if self
            .last_j
            .borrow()
            .as_ref()
            .is_some_and(|last| last.x == *x)
        {
            return Some(());
        }
        if let (Some(last), Some(r)) = (self.last_j.borrow_mut().as_mut(), self.last_rows_at(x))
            && last.updates < secant
        {
            let dx = x - &last.x;
            let dd = dx.norm_squared();
            if dd > 0.0 {
                let miss = (&r - &last.rows) - &last.j * &dx;
                for (k, d) in dx.iter().enumerate() {
                    for (jv, mv) in last.j.column_mut(k).iter_mut().zip(miss.iter()) {
                        *jv += mv * d / dd;
                    }
                }
                last.x = x.clone();
                last.rows = r;
                last.updates += 1;
                return Some(());
            }
        }
        let r0 = self.rows_cached(x)?;
        let (rows, params, step) = (self.rows, self.params, self.step);
        let shifted = |i: usize| {
            let h = step * x[i].abs().max(0.3);
            let mut xp = x.clone();
            xp[i] += h;
            (h, replay(rows, params, &xp))
        };
        let n = x.len();
        // The columns are independent whole replays, most of a fit's time: the odd ones
        // run on a second thread (a fit that outlasts the round's other fits, or the
        // calibration, then uses both cores). Each column is the same replay either way, so
        // the fit is bit for bit the same.
        let (odd, even) = std::thread::scope(|s| {
            let odd = s.spawn(|| (1..n).step_by(2).map(shifted).collect::<Vec<_>>());
            let even: Vec<_> = (0..n).step_by(2).map(shifted).collect();
            (odd.join(), even)
        });
        let mut odd = odd
            .unwrap_or_else(|e| std::panic::resume_unwind(e))
            .into_iter();
        let mut even = even.into_iter();
        let cols = (0..n).map_while(|i| if i % 2 == 0 { even.next() } else { odd.next() });
        let mut data = Vec::with_capacity(r0.len() * n);
        for (h, r) in cols {
            let r = self.keep(r)?;
            data.extend(r.iter().zip(r0.iter()).map(|(a, b)| (a - b) / h));
        }
        *self.last_j.borrow_mut() = Some(Jac {
            x: x.clone(),
            j: DMatrix::from_vec(r0.len(), n, data),
            rows: r0,
            updates: 0,
        });
        Some(())
    }
}

impl LeastSquaresProblem<f64, Dyn, Dyn> for Problem<'_, '_> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;

    fn set_params(&mut self, x: &DVector<f64>) {
        self.x.copy_from(x);
    }

    fn params(&self) -> DVector<f64> {
        self.x.clone()
    }

    fn residuals(&self) -> Option<DVector<f64>> {
        let r = self.rows_at(&self.x)?;
        *self.last_r.borrow_mut() = Some((self.x.clone(), r.clone()));
        Some(r)
    }

    fn jacobian(&self) -> Option<DMatrix<f64>> {
        self.jac_at(&self.x)
    }
}

/// Secant (Broyden) updates of a candidate's Jacobian between two whole ones. A whole
/// Jacobian replays the record once per parameter, and the solver asks for one at every
/// step it takes, so Jacobians were most of a diagnosis; the rank-one update from the step
/// just taken and its rows costs no replay. Every fourth step, and at the optimum (the
/// parameters' uncertainties), the Jacobian is replayed whole again: a secant estimate
/// drifts along a long valley. Only the joint fits use them (`fit::Context::polish`,
/// `select::joint_refit`): the calibration, which every candidate is measured against,
/// must sit at its optimum, not where an estimate of the Jacobian stopped.
const SECANT_UPDATES: usize = 3;

/// Minimises the squared rows over the parameters from `start`. `step` is the relative
/// finite-difference step (3 % suits replays with quantized sensors). Every Jacobian is
/// replayed whole: for the fits every candidate is measured against (the calibration).
pub fn fit(
    start: &[f64],
    params: &[Param],
    rows: &Rows<'_>,
    step: f64,
    patience: usize,
) -> Result<LmFit, DiagnoseError> {
    fit_with(start, params, rows, step, patience, 0)
}

/// [`fit`] with `SECANT_UPDATES` between two whole Jacobians: for the candidates.
pub fn fit_secant(
    start: &[f64],
    params: &[Param],
    rows: &Rows<'_>,
    step: f64,
    patience: usize,
) -> Result<LmFit, DiagnoseError> {
    fit_with(start, params, rows, step, patience, SECANT_UPDATES)
}

/// The patience of a stalled secant fit's restart with whole Jacobians (see [`fit_with`]):
/// as many replays as the secant solve had. The solver's patience counts its steps'
/// evaluations, (n + 1) per unit; a step costs one replay plus, with `secant` updates
/// between two whole Jacobians, n / (secant + 1) for the Jacobian, and n with whole ones
/// only. With the secant solve's patience, a ten-parameter restart that crawls along a
/// valley replays the record several times as often as the solve before it.
fn restart_patience(patience: usize, secant: usize, n: usize) -> usize {
    let per_secant_step = (secant + 1) + n;
    let per_whole_step = (secant + 1) * (n + 1);
    (patience * per_secant_step).div_ceil(per_whole_step).max(1)
}

/// [`fit`] with `secant` updates between two whole Jacobians.
fn fit_with(
    start: &[f64],
    params: &[Param],
    rows: &Rows<'_>,
    step: f64,
    patience: usize,
    secant: usize,
) -> Result<LmFit, DiagnoseError> {
    let problem = Problem {
        params,
        rows,
        x: DVector::from_iterator(
            start.len(),
            start.iter().zip(params).map(|(s, p)| s / p.scale),
        ),
        step,
        last_j: RefCell::new(None),
        secant,
        last_r: RefCell::new(None),
        err: RefCell::new(None),
    };
    let solve = |problem, patience| {
        LevenbergMarquardt::new()
            .with_patience(patience)
            .with_tol(1e-4)
            .minimize(problem)
            .0
    };
    let mut problem = solve(problem, patience);
    // The solver stops where a step along the Jacobian it was given fails; when that was a
    // secant estimate, the stop may be the estimate's, short of the optimum. It goes on from there with whole Jacobians;
    // where it had stopped at the optimum, that costs the whole Jacobian the uncertainties
    // need anyway and a step or two.
    let stalled = problem
        .last_j
        .borrow()
        .as_ref()
        .is_some_and(|last| last.updates > 0);
    if stalled && problem.err.borrow().is_none() {
        problem.secant = 0;
        *problem.last_j.borrow_mut() = None;
        problem = solve(problem, restart_patience(patience, secant, start.len()));
    }
    if let Some(e) = problem.err.borrow_mut().take() {
        return Err(e);
    }
    let theta = problem.theta_of(&problem.x);
    let x = problem.x.clone();
    let r = problem.rows_cached(&x);
    // The uncertainties need the Jacobian itself, not a secant estimate.
    let exact = problem
        .last_j
        .borrow()
        .as_ref()
        .is_some_and(|last| last.x == x && last.updates == 0);
    if !exact {
        *problem.last_j.borrow_mut() = None;
    }
    let j = problem.jac_within(&x, 0).map(|j| {
        // d rows / d theta = d rows / d x · 1/scale.
        let mut j = j;
        for (i, p) in params.iter().enumerate() {
            let c = j.column(i) / p.scale;
            j.set_column(i, &c);
        }
        j
    });
    Ok(LmFit {
        cost: r.as_ref().map_or(f64::INFINITY, |r| r.norm_squared()),
        theta,
        rows: r,
        jacobian: j,
    })
}

/// Standard deviations of the parameters from JᵀJ at the optimum. `n_eff_per_row` < 1 says
/// the rows are correlated (each is worth that many independent samples); rows were divided
/// by √n for the solver, which this undoes.
pub fn std_devs(f: &LmFit, n_eff_per_row: f64) -> Vec<f64> {
    let (Some(r), Some(j)) = (&f.rows, &f.jacobian) else {
        return vec![f64::NAN; f.theta.len()];
    };
    let n = (r.len() as f64).max(1.0);
    let jn = j * n.sqrt();
    let ssr = r.norm_squared() * n;
    let dof = (n - f.theta.len() as f64).max(1.0);
    let s2 = ssr / dof / n_eff_per_row.clamp(1e-6, 1.0);
    // A parameter pinned at a bound (a calibration ratio at its limit) has a zero column;
    // it is left out, so that it does not make the others' uncertainty look infinite.
    let norms: Vec<f64> = (0..jn.ncols()).map(|i| jn.column(i).norm()).collect();
    let max_norm = norms.iter().copied().fold(0.0, f64::max);
    let live: Vec<usize> = (0..jn.ncols())
        .filter(|&i| norms[i] > 1e-9 * max_norm && norms[i] > 0.0)
        .collect();
    let jl = jn.select_columns(&live);
    let jtj = jl.transpose() * &jl;
    let mut std = vec![f64::INFINITY; f.theta.len()];
    if let Some(inv) = jtj.try_inverse() {
        for (k, &i) in live.iter().enumerate() {
            std[i] = (inv[(k, k)].max(0.0) * s2).sqrt();
        }
    }
    std
}

#[cfg(test)]
mod tests {
    /// A stalled fit's restart with whole Jacobians gets about the replays of the secant
    /// solve before it, not the same patience (which cost up to five times as many).
    #[test]
    fn a_restart_replays_about_as_often_as_the_solve_before_it() {
        let (patience, secant) = (6, super::SECANT_UPDATES);
        for n in 1..=14 {
            let p2 = super::restart_patience(patience, secant, n);
            // Replays: evaluations × (one + the Jacobian's share per step).
            let solve = (patience * (n + 1)) as f64 * (1.0 + n as f64 / (secant + 1) as f64);
            let restart = (p2 * (n + 1) * (n + 1)) as f64;
            assert!(
                restart <= 1.5 * solve && restart >= 0.5 * solve,
                "n = {n}: restart {restart} replays against the solve's {solve}"
            );
        }
        assert_eq!(
            super::restart_patience(patience, 0, 3),
            patience,
            "no secant, no cut"
        );
    }

    use std::sync::Mutex;

    use nalgebra::DVector;

    use super::{Param, fit, fit_with};

    /// A straight line through noise-free points: the solver must find its slope and offset,
    /// and it must never replay the same parameters twice (the Jacobian's base column is the
    /// residual the solver has just asked for; its other columns run on two threads).
    #[test]
    fn a_fit_recovers_a_line_and_replays_no_point_twice() {
        let xs: Vec<f64> = (0..50).map(|i| f64::from(i) * 0.1).collect();
        let ys: Vec<f64> = xs.iter().map(|x| 2.5 * x - 1.25).collect();
        let calls: Mutex<Vec<Vec<f64>>> = Mutex::new(Vec::new());
        let rows = |th: &[f64]| {
            calls.lock().expect("lock").push(th.to_vec());
            Ok(Some(DVector::from_iterator(
                xs.len(),
                xs.iter().zip(&ys).map(|(x, y)| y - (th[0] * x + th[1])),
            )))
        };
        let params = [
            Param {
                lo: -10.0,
                hi: 10.0,
                scale: 1.0,
            },
            Param {
                lo: -10.0,
                hi: 10.0,
                scale: 1.0,
            },
        ];
        let f = fit(&[0.5, 0.5], &params, &rows, 0.03, 20).expect("fit");
        assert!((f.theta[0] - 2.5).abs() < 1e-6, "slope {}", f.theta[0]);
        assert!((f.theta[1] + 1.25).abs() < 1e-6, "offset {}", f.theta[1]);
        let mut calls = calls.into_inner().expect("lock");
        let n = calls.len();
        assert!(n > 3, "{n} replays");
        calls.sort_by(|a, b| a.partial_cmp(b).expect("finite"));
        calls.dedup();
        assert_eq!(calls.len(), n, "a point replayed twice");
    }

    /// A decay y = a·e^(−b·t) + c: with secant updates between whole Jacobians the solver
    /// lands where it lands with whole Jacobians only (on the truth within 1e-5), with fewer
    /// replays.
    #[test]
    fn secant_updates_find_the_same_decay_with_fewer_replays() {
        let ts: Vec<f64> = (0..200).map(|i| f64::from(i) * 0.02).collect();
        let model = |th: &[f64], t: f64| th[0] * (-th[1] * t).exp() + th[2];
        let truth = [2.0, 1.7, -0.4];
        let calls = Mutex::new(0usize);
        let rows = |th: &[f64]| {
            *calls.lock().expect("lock") += 1;
            Ok(Some(DVector::from_iterator(
                ts.len(),
                ts.iter().map(|&t| model(&truth, t) - model(th, t)),
            )))
        };
        let p = |lo: f64, hi: f64| Param { lo, hi, scale: 1.0 };
        let params = [p(0.0, 10.0), p(0.01, 10.0), p(-5.0, 5.0)];
        let mut replays = vec![];
        for secant in [0, 3] {
            *calls.lock().expect("lock") = 0;
            let f = fit_with(&[1.0, 0.5, 0.0], &params, &rows, 0.03, 50, secant).expect("fit");
            for (got, want) in f.theta.iter().zip(truth) {
                assert!((got - want).abs() < 1e-5, "secant {secant}: {:?}", f.theta);
            }
            replays.push(*calls.lock().expect("lock"));
        }
        assert!(
            replays[1] < replays[0],
            "replays with whole Jacobians {} and with secant updates {}",
            replays[0],
            replays[1]
        );
    }
}
