//! Bounded Levenberg–Marquardt on replay residuals (the `levenberg-marquardt` crate), for the
//! calibration and for every candidate. Parameters are scaled to order 1 and clamped to
//! their bounds; the Jacobian is a forward difference of whole replays.

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
pub type Rows<'a> = dyn Fn(&[f64]) -> Result<Option<DVector<f64>>, DiagnoseError> + 'a;

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
    last_j: RefCell<Option<(DVector<f64>, DMatrix<f64>)>>,
    err: RefCell<Option<DiagnoseError>>,
}

impl Problem<'_, '_> {
    fn theta_of(&self, x: &DVector<f64>) -> Vec<f64> {
        x.iter()
            .zip(self.params)
            .map(|(x, p)| (x * p.scale).clamp(p.lo, p.hi))
            .collect()
    }

    fn rows_at(&self, x: &DVector<f64>) -> Option<DVector<f64>> {
        if self.err.borrow().is_some() {
            return None;
        }
        match (self.rows)(&self.theta_of(x)) {
            Ok(Some(r)) if r.iter().all(|v| v.is_finite()) => Some(r),
            Ok(_) => None,
            Err(e) => {
                *self.err.borrow_mut() = Some(e);
                None
            }
        }
    }

    fn jac_at(&self, x: &DVector<f64>) -> Option<DMatrix<f64>> {
        if let Some((xj, j)) = self.last_j.borrow().as_ref()
            && xj == x
        {
            return Some(j.clone());
        }
        let r0 = self.rows_at(x)?;
        let mut j = DMatrix::zeros(r0.len(), x.len());
        for i in 0..x.len() {
            let h = self.step * x[i].abs().max(0.3);
            let mut xp = x.clone();
            xp[i] += h;
            let r = self.rows_at(&xp)?;
            j.set_column(i, &((r - &r0) / h));
        }
        *self.last_j.borrow_mut() = Some((x.clone(), j.clone()));
        Some(j)
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
        self.rows_at(&self.x)
    }

    fn jacobian(&self) -> Option<DMatrix<f64>> {
        self.jac_at(&self.x)
    }
}

/// Minimises the squared rows over the parameters from `start`. `step` is the relative
/// finite-difference step (3 % suits replays with quantized sensors).
pub fn fit(
    start: &[f64],
    params: &[Param],
    rows: &Rows<'_>,
    step: f64,
    patience: usize,
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
        err: RefCell::new(None),
    };
    let (problem, _report) = LevenbergMarquardt::new()
        .with_patience(patience)
        .with_tol(1e-4)
        .minimize(problem);
    if let Some(e) = problem.err.borrow_mut().take() {
        return Err(e);
    }
    let theta = problem.theta_of(&problem.x);
    let x = problem.x.clone();
    let r = problem.rows_at(&x);
    let j = problem.jac_at(&x).map(|j| {
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
