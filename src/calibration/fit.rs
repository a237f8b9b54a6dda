//! Parameter identification on the linearised model (paper §III.B, eqs. (18)–(25)),
//! with standard errors, the condition number and parameter correlations from the
//! final Jacobian.
//!
//! Two algorithms share one step solver:
//!
//! * [`Algorithm::Paper`] is the paper's iteration: the full Gauss–Newton step of
//!   eq. (25), added unconditionally (step (f)), until the step stops changing
//!   the predicted positions (step (g)).
//! * [`Algorithm::LevenbergMarquardt`] (the default) damps the same step with a
//!   trust region and accepts it only when the cost actually drops, so a poor start
//!   or a badly conditioned model cannot make it diverge. On well-posed data it
//!   takes the Gauss–Newton steps and reaches the same optimum.
//!
//! Stop criteria ([`Stop`]): both algorithms stop when the *undamped* step of
//! eq. (25) would move no predicted position by more than `stop_step_mm` (that
//! step vanishes exactly at a stationary point, whatever the damping, so a large
//! λ cannot fake convergence); Levenberg–Marquardt also stops when an accepted
//! step lowers the cost by less than the fraction `stop_relative_cost`; both give
//! up, not converged, after `max_iterations` steps tried.
//!
//! Each step solves the column-scaled least-squares problem with a QR
//! factorisation (faer, sequential: see [`dense`]) rather than the normal equations of eq. (25): the same
//! solution, without squaring the condition number. Columns are scaled to unit
//! norm, so Marquardt's damping `λ·diag(JᵀJ)` becomes `λ·I`, appended as rows.
//!
//! An optional Huber loss on each row's residual norm is minimised by iteratively
//! reweighted least squares (the weights are recomputed from the residuals before
//! every step).

use faer::Mat;
use nalgebra::Vector3;

use super::dense;
use crate::robot::{
    BatchJacobian, ConfWrench, PARAM_COUNT, ParamId, ParamValues, Robot, batch_jacobian,
    batch_predict,
};

/// How each step is taken and accepted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Algorithm {
    /// Paper §III.B: undamped Gauss–Newton (eq. (25)), every step taken.
    Paper,
    /// Levenberg–Marquardt: damped steps, rejected when the cost does not drop.
    LevenbergMarquardt,
}

/// The cost each row's residual contributes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Loss {
    /// Sum of squared residuals: the paper's estimator, and the one the standard
    /// errors assume.
    LeastSquares,
    /// Huber on the row's residual norm: quadratic up to `threshold_mm`, linear
    /// beyond, so one gross error (a tracker glitch) cannot pull the fit.
    Huber { threshold_mm: f64 },
}

impl Loss {
    /// The IRLS weight of a row with residual norm `r_mm` (1 inside the threshold).
    pub fn weight(self, r_mm: f64) -> f64 {
        match self {
            Loss::Huber { threshold_mm } if r_mm > threshold_mm => threshold_mm / r_mm,
            _ => 1.0,
        }
    }

    /// The row's cost (mm²).
    fn cost(self, r_mm: f64) -> f64 {
        match self {
            Loss::Huber { threshold_mm } if r_mm > threshold_mm => {
                threshold_mm * (r_mm - 0.5 * threshold_mm)
            }
            _ => 0.5 * r_mm * r_mm,
        }
    }
}

/// When to stop iterating, and how.
#[derive(Debug, Clone, Copy)]
pub struct FitOptions {
    pub algorithm: Algorithm,
    pub loss: Loss,
    /// Upper bound on steps tried (rejected Levenberg–Marquardt steps count).
    pub max_iterations: usize,
    /// Stop when the largest predicted position change of a step is below this (mm).
    pub stop_step_mm: f64,
    /// Levenberg–Marquardt only: stop when an accepted step lowers the cost by
    /// less than this fraction.
    pub stop_relative_cost: f64,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            algorithm: Algorithm::LevenbergMarquardt,
            loss: Loss::LeastSquares,
            max_iterations: 30,
            stop_step_mm: 1e-4,
            stop_relative_cost: 1e-10,
        }
    }
}

/// One step tried, for the convergence trace.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Iteration {
    pub iteration: usize,
    /// Residual norms before the step.
    pub rms_mm: f64,
    pub max_mm: f64,
    /// Largest position change the step predicts.
    pub step_mm: f64,
    /// Levenberg–Marquardt damping λ relative to the unit-norm columns; `None` for
    /// the paper's undamped step.
    pub damping: Option<f64>,
    /// Whether the step was taken (a Levenberg–Marquardt step that raises the cost
    /// is not).
    pub accepted: bool,
}

/// Why the iteration ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stop {
    /// A step moved no predicted position by more than `stop_step_mm`.
    Step,
    /// An accepted step lowered the cost by less than `stop_relative_cost`.
    CostChange,
    /// `max_iterations` steps were tried: not converged.
    MaxIterations,
}

impl Stop {
    pub fn as_str(self) -> &'static str {
        match self {
            Stop::Step => "step",
            Stop::CostChange => "cost_change",
            Stop::MaxIterations => "max_iterations",
        }
    }
}

/// Result of a fit.
#[derive(Debug, Clone)]
pub struct Fit {
    pub values: ParamValues,
    pub std_errors: [Option<f64>; PARAM_COUNT],
    pub trace: Vec<Iteration>,
    /// Residual RMS per coordinate at the solution (mm).
    pub residual_rms_mm: f64,
    /// `measured − predicted` per row at the solution (mm).
    pub residuals_mm: Vec<Vector3<f64>>,
    /// The loss's weight of each row at the solution (all 1 for least squares).
    pub weights: Vec<f64>,
    pub stop: Stop,
    pub converged: bool,
    /// σ_max / σ_min of the column-scaled, weighted Jacobian at the solution.
    pub condition_number: f64,
    /// The free parameters, in the order of `correlation`.
    pub free: Vec<ParamId>,
    /// Correlation matrix of the estimates, row-major `m × m`.
    pub correlation: Vec<f64>,
}

impl Fit {
    /// The `count` parameter pairs with the largest |correlation|, strongest first.
    pub fn strongest_correlations(&self, count: usize) -> Vec<(ParamId, ParamId, f64)> {
        let m = self.free.len();
        let mut pairs: Vec<(ParamId, ParamId, f64)> = (0..m)
            .flat_map(|i| (i + 1..m).map(move |j| (i, j)))
            .map(|(i, j)| (self.free[i], self.free[j], self.correlation[i * m + j]))
            .collect();
        pairs.sort_by(|a, b| b.2.abs().total_cmp(&a.2.abs()));
        pairs.truncate(count);
        pairs
    }
}

#[derive(Debug, thiserror::Error)]
pub enum FitError {
    #[error(
        "{rows} measurements give {equations} equations for {parameters} free parameters; need more rows"
    )]
    TooFewRows {
        rows: usize,
        equations: usize,
        parameters: usize,
    },
    #[error("{rows} rows but {measured} measured positions")]
    LengthMismatch { rows: usize, measured: usize },
    #[error("the fit diverged (residual became non-finite at iteration {0})")]
    Diverged(usize),
    #[error(
        "the Jacobian is rank deficient at the solution: the free parameters are not all identifiable from these rows"
    )]
    Singular,
}

/// Residuals `measured − predicted` per row.
pub fn residuals(
    robot: &Robot,
    p: &ParamValues,
    rows: &[ConfWrench],
    measured: &[Vector3<f64>],
) -> Vec<Vector3<f64>> {
    batch_predict(robot, p, rows)
        .iter()
        .zip(measured)
        .map(|(pred, meas)| meas - pred.position_mm)
        .collect()
}

/// RMS per coordinate and largest norm of residuals (mm).
pub fn norms(residuals: &[Vector3<f64>]) -> (f64, f64) {
    let n = residuals.len().max(1) as f64;
    let rms = (residuals.iter().map(|r| r.norm_squared()).sum::<f64>() / (3.0 * n)).sqrt();
    let max = residuals.iter().map(|r| r.norm()).fold(0.0, f64::max);
    (rms, max)
}

/// Model, residuals, weights and cost at one parameter vector.
struct Point {
    values: ParamValues,
    batch: BatchJacobian,
    residuals: Vec<Vector3<f64>>,
    weights: Vec<f64>,
    cost: f64,
}

impl Point {
    fn at(
        robot: &Robot,
        values: ParamValues,
        rows: &[ConfWrench],
        measured: &[Vector3<f64>],
        free: &[ParamId],
        loss: Loss,
    ) -> Point {
        let batch = batch_jacobian(robot, &values, rows, free);
        let residuals: Vec<Vector3<f64>> = batch
            .predictions
            .iter()
            .zip(measured)
            .map(|(p, meas)| meas - p.position_mm)
            .collect();
        let weights = residuals.iter().map(|r| loss.weight(r.norm())).collect();
        let cost = residuals.iter().map(|r| loss.cost(r.norm())).sum();
        Point {
            values,
            batch,
            residuals,
            weights,
            cost,
        }
    }
}

/// A step from a [`Point`] and what the linear model predicts of it.
struct Step {
    delta: Vec<f64>,
    /// Largest predicted position change over the rows (mm).
    step_mm: f64,
    /// Cost reduction the weighted linear model predicts (mm²).
    predicted_reduction: f64,
}

/// Solves `min Σ w_k‖r_k − J_k δ‖² + λ‖D⁻¹δ‖²` by QR of the column-scaled, weighted
/// Jacobian with `√λ·I` appended (λ = 0: the Gauss–Newton step of eq. (25)).
fn solve_step(point: &Point, m: usize, damping: f64) -> Step {
    let n = point.residuals.len();
    let equations = 3 * n;
    let jacobian = &point.batch.jacobian;
    let (scaled, scale) = scaled_jacobian(jacobian, &point.weights, equations, m);
    let extra = if damping > 0.0 { m } else { 0 };
    let root_damping = damping.sqrt();
    let a = Mat::<f64>::from_fn(equations + extra, m, |row, j| {
        if row < equations {
            scaled[(row, j)]
        } else if row - equations == j {
            root_damping
        } else {
            0.0
        }
    });
    let rhs = Mat::<f64>::from_fn(equations + extra, 1, |row, _| {
        if row < equations {
            point.weights[row / 3].sqrt() * point.residuals[row / 3][row % 3]
        } else {
            0.0
        }
    });
    let y = dense::lstsq(a.as_ref(), rhs.as_ref());
    let delta: Vec<f64> = (0..m).map(|j| y[(j, 0)] * scale[j]).collect();
    let mut step_mm: f64 = 0.0;
    let mut predicted_reduction = 0.0;
    for k in 0..n {
        let mut change = Vector3::<f64>::zeros();
        for axis in 0..3 {
            let row = &jacobian[(3 * k + axis) * m..(3 * k + axis + 1) * m];
            change[axis] = row.iter().zip(&delta).map(|(j, d)| j * d).sum();
        }
        step_mm = step_mm.max(change.norm());
        let r = &point.residuals[k];
        predicted_reduction +=
            0.5 * point.weights[k] * (r.norm_squared() - (r - change).norm_squared());
    }
    Step {
        delta,
        step_mm,
        predicted_reduction,
    }
}

/// Fits the `free` parameters, starting from `start`, to the measured positions.
///
/// Cost: one Jacobian of all rows per step tried, one QR of a `3n × m` matrix per
/// step (two for a damped step), and one SVD at the end.
pub fn fit(
    robot: &Robot,
    start: &ParamValues,
    rows: &[ConfWrench],
    measured: &[Vector3<f64>],
    free: &[ParamId],
    options: &FitOptions,
) -> Result<Fit, FitError> {
    let m = free.len();
    let equations = 3 * rows.len();
    if rows.len() != measured.len() {
        return Err(FitError::LengthMismatch {
            rows: rows.len(),
            measured: measured.len(),
        });
    }
    if equations <= m {
        return Err(FitError::TooFewRows {
            rows: rows.len(),
            equations,
            parameters: m,
        });
    }
    let evaluate = |values| Point::at(robot, values, rows, measured, free, options.loss);
    let mut point = evaluate(*start);
    let mut trace = Vec::new();
    let mut stop = Stop::MaxIterations;
    // Marquardt's λ relative to the unit diagonal of the scaled JᵀJ; ν is Nielsen's
    // growth factor after rejections (Madsen, Nielsen & Tingleff 2004, §3.2).
    let (mut damping, mut growth) = (1e-3, 2.0);
    for iteration in 1..=options.max_iterations {
        let (rms_mm, max_mm) = norms(&point.residuals);
        if !point.cost.is_finite() {
            return Err(FitError::Diverged(iteration));
        }
        // The Gauss–Newton step of eq. (25) decides convergence for both algorithms:
        // it vanishes exactly at a stationary point, whatever the damping.
        let gauss_newton = solve_step(&point, m, 0.0);
        if !gauss_newton.step_mm.is_finite() {
            return Err(FitError::Diverged(iteration));
        }
        let converged = gauss_newton.step_mm < options.stop_step_mm;
        let (step, damping_used) = match options.algorithm {
            Algorithm::LevenbergMarquardt if !converged => {
                (solve_step(&point, m, damping), Some(damping))
            }
            Algorithm::LevenbergMarquardt => (gauss_newton, Some(0.0)),
            Algorithm::Paper => (gauss_newton, None),
        };
        let mut record = Iteration {
            iteration,
            rms_mm,
            max_mm,
            step_mm: step.step_mm,
            damping: damping_used,
            accepted: true,
        };
        let mut candidate = point.values;
        for (id, dv) in free.iter().zip(&step.delta) {
            candidate.0[id.index()] += dv;
        }
        if converged || options.algorithm == Algorithm::Paper {
            // Paper steps (f)–(g): take the step, stop once it no longer moves the
            // model. Levenberg–Marquardt takes the last (tiny) Gauss–Newton step too.
            point = evaluate(candidate);
            trace.push(record);
            if converged {
                stop = Stop::Step;
                break;
            }
            continue;
        }
        let next = evaluate(candidate);
        let gain = (point.cost - next.cost) / step.predicted_reduction;
        if next.cost.is_finite() && gain > 0.0 {
            let relative = (point.cost - next.cost) / point.cost.max(f64::MIN_POSITIVE);
            damping *= (1.0 - (2.0 * gain - 1.0).powi(3)).max(1.0 / 3.0);
            growth = 2.0;
            point = next;
            trace.push(record);
            if relative < options.stop_relative_cost {
                stop = Stop::CostChange;
                break;
            }
        } else {
            damping *= growth;
            growth *= 2.0;
            record.accepted = false;
            trace.push(record);
        }
    }
    if !point.cost.is_finite() {
        return Err(FitError::Diverged(trace.len()));
    }
    let statistics = statistics(&point, free)?;
    Ok(Fit {
        values: point.values,
        std_errors: statistics.std_errors,
        trace,
        residual_rms_mm: norms(&point.residuals).0,
        residuals_mm: point.residuals,
        weights: point.weights,
        stop,
        converged: stop != Stop::MaxIterations,
        condition_number: statistics.condition_number,
        free: free.to_vec(),
        correlation: statistics.correlation,
    })
}

struct Statistics {
    std_errors: [Option<f64>; PARAM_COUNT],
    condition_number: f64,
    correlation: Vec<f64>,
}

/// Covariance `σ²·(JᵀWJ)⁻¹` at the solution with `σ² = Σ w_k‖r_k‖² / (3n − m)`,
/// from the SVD of the scaled, weighted Jacobian `U·S·Vᵀ`: `Cov ∝ V·S⁻²·Vᵀ`, which
/// stays accurate where forming JᵀJ would square the condition number. For the
/// Huber loss this is the usual IRLS approximation.
fn statistics(point: &Point, free: &[ParamId]) -> Result<Statistics, FitError> {
    let m = free.len();
    let equations = 3 * point.residuals.len();
    let weighted_rss: f64 = point
        .residuals
        .iter()
        .zip(&point.weights)
        .map(|(r, w)| w * r.norm_squared())
        .sum();
    let sigma2 = weighted_rss / (equations - m) as f64;
    let (scaled, scale) = scaled_jacobian(&point.batch.jacobian, &point.weights, equations, m);
    let (s, v) = dense::svd(scaled.as_ref(), true).map_err(|_| FitError::Singular)?;
    let v = v.ok_or(FitError::Singular)?;
    let s_max = (0..m).map(|k| s[k]).fold(0.0, f64::max);
    let s_min = (0..m).map(|k| s[k]).fold(f64::INFINITY, f64::min);
    if !s_min.is_finite() || s_min <= 1e-12 * s_max {
        return Err(FitError::Singular);
    }
    // Scaled covariance without σ²: C = V·S⁻²·Vᵀ.
    let mut covariance = vec![0.0; m * m];
    for i in 0..m {
        for j in i..m {
            let c: f64 = (0..m).map(|k| v[(i, k)] * v[(j, k)] / (s[k] * s[k])).sum();
            covariance[i * m + j] = c;
            covariance[j * m + i] = c;
        }
    }
    let mut std_errors = [None; PARAM_COUNT];
    for (j, id) in free.iter().enumerate() {
        std_errors[id.index()] = Some((covariance[j * m + j] * sigma2).sqrt() * scale[j]);
    }
    let correlation = (0..m * m)
        .map(|ij| {
            let (i, j) = (ij / m, ij % m);
            covariance[ij] / (covariance[i * m + i] * covariance[j * m + j]).sqrt()
        })
        .collect();
    Ok(Statistics {
        std_errors,
        condition_number: s_max / s_min,
        correlation,
    })
}

/// The Jacobian with rows weighted by `√w` and columns scaled to unit norm, and the
/// scale of each column's parameter.
fn scaled_jacobian(
    jacobian: &[f64],
    weights: &[f64],
    rows: usize,
    m: usize,
) -> (Mat<f64>, Vec<f64>) {
    let weighted = Mat::<f64>::from_fn(rows, m, |r, j| jacobian[r * m + j] * weights[r / 3].sqrt());
    let scale: Vec<f64> = (0..m)
        .map(|j| {
            let norm = weighted.col(j).norm_l2();
            if norm > 0.0 { 1.0 / norm } else { 1.0 }
        })
        .collect();
    let scaled = Mat::<f64>::from_fn(rows, m, |r, j| weighted[(r, j)] * scale[j]);
    (scaled, scale)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::Selection;
    use crate::robot::test_support::{irb1600, random_q, random_wrench, truth_params};
    use rand::SeedableRng;
    use rand::rngs::StdRng;

    fn random_rows(robot: &Robot, seed: u64, n: usize) -> Vec<ConfWrench> {
        let mut rng = StdRng::seed_from_u64(seed);
        (0..n)
            .map(|_| ConfWrench {
                q_deg: random_q(robot, &mut rng),
                wrench: random_wrench(&mut rng),
            })
            .collect()
    }

    #[test]
    fn recovers_the_truth_from_noiseless_data_with_both_algorithms() {
        let robot = irb1600();
        let truth = truth_params(&robot);
        let nominal = ParamValues::nominal(robot.spec());
        let rows = random_rows(&robot, 8, 60);
        let measured: Vec<Vector3<f64>> = batch_predict(&robot, &truth, &rows)
            .iter()
            .map(|p| p.position_mm)
            .collect();
        let free = Selection::spec_identifiable();
        for algorithm in [Algorithm::Paper, Algorithm::LevenbergMarquardt] {
            let options = FitOptions {
                algorithm,
                stop_step_mm: 1e-9,
                ..FitOptions::default()
            };
            let fit = fit(&robot, &nominal, &rows, &measured, free.ids(), &options).unwrap();
            assert!(fit.converged, "{algorithm:?}: {:?}", fit.trace);
            // The truth's dependent parameters are nominal, so the identifiable ones
            // are recovered exactly (the spec's truth leaves the dependent ones at nominal).
            for id in free.ids() {
                let (got, want) = (fit.values.get(*id), truth.get(*id));
                assert!(
                    (got - want).abs() < 1e-7 * want.abs().max(1.0),
                    "{algorithm:?} {id}: {got} vs {want}"
                );
            }
            assert!(fit.residual_rms_mm < 1e-9);
            // Gauss–Newton converges quadratically: a handful of iterations, and
            // Levenberg–Marquardt with little damping follows it.
            assert!(fit.trace.len() <= 8, "{algorithm:?}: {:?}", fit.trace);
            assert!(fit.trace.iter().all(|it| it.accepted));
        }
    }

    #[test]
    fn levenberg_marquardt_rejects_steps_that_raise_the_cost_and_still_converges() {
        let robot = irb1600();
        let truth = truth_params(&robot);
        let rows = random_rows(&robot, 9, 40);
        let measured: Vec<Vector3<f64>> = batch_predict(&robot, &truth, &rows)
            .iter()
            .map(|p| p.position_mm)
            .collect();
        let free = Selection::spec_identifiable();
        // A start far outside the linear regime: joint offsets off by 40°, where
        // full Gauss–Newton steps overshoot.
        let mut start = ParamValues::nominal(robot.spec());
        for id in free.ids() {
            if id.name().starts_with("dtheta") {
                start.set(*id, 40.0);
            }
        }
        let options = FitOptions {
            max_iterations: 200,
            stop_step_mm: 1e-9,
            ..FitOptions::default()
        };
        let fit = fit(&robot, &start, &rows, &measured, free.ids(), &options).unwrap();
        assert!(fit.converged, "{:?}", fit.trace);
        assert!(fit.residual_rms_mm < 1e-6, "{}", fit.residual_rms_mm);
        assert!(fit.trace.iter().any(|it| !it.accepted), "{:#?}", fit.trace);
        // Accepted steps never raise the residual.
        let accepted: Vec<f64> = fit
            .trace
            .iter()
            .filter(|it| it.accepted)
            .map(|it| it.rms_mm)
            .collect();
        assert!(accepted.windows(2).all(|w| w[1] <= w[0] * (1.0 + 1e-12)));
    }

    #[test]
    fn huber_weights_fall_beyond_the_threshold() {
        let huber = Loss::Huber { threshold_mm: 0.5 };
        assert_eq!(huber.weight(0.4), 1.0);
        assert!((huber.weight(2.0) - 0.25).abs() < 1e-15);
        // The cost is continuous with a continuous slope at the threshold.
        assert!((huber.cost(0.5) - Loss::LeastSquares.cost(0.5)).abs() < 1e-15);
        assert_eq!(Loss::LeastSquares.weight(100.0), 1.0);
    }

    #[test]
    fn standard_errors_match_the_scatter_of_repeated_noisy_fits() {
        let robot = irb1600();
        let truth = truth_params(&robot);
        let mut rng = StdRng::seed_from_u64(12);
        let rows = random_rows(&robot, 12, 40);
        let exact: Vec<Vector3<f64>> = batch_predict(&robot, &truth, &rows)
            .iter()
            .map(|p| p.position_mm)
            .collect();
        let free = Selection::spec_identifiable();
        let options = FitOptions {
            max_iterations: 20,
            stop_step_mm: 1e-7,
            ..FitOptions::default()
        };
        let k6 = ParamId::from_name("k6").unwrap();
        let normal = rand_distr::Normal::new(0.0, 0.05).unwrap();
        let mut estimates = Vec::new();
        let mut reported = Vec::new();
        for _ in 0..40 {
            let noisy: Vec<Vector3<f64>> = exact
                .iter()
                .map(|p| {
                    p + Vector3::from_fn(|_, _| rand_distr::Distribution::sample(&normal, &mut rng))
                })
                .collect();
            let fit = fit(&robot, &truth, &rows, &noisy, free.ids(), &options).unwrap();
            estimates.push(fit.values.get(k6));
            reported.push(fit.std_errors[k6.index()].unwrap());
        }
        let mean = estimates.iter().sum::<f64>() / estimates.len() as f64;
        let scatter = (estimates.iter().map(|e| (e - mean).powi(2)).sum::<f64>()
            / (estimates.len() - 1) as f64)
            .sqrt();
        let typical = reported.iter().sum::<f64>() / reported.len() as f64;
        // 40 samples: the sample standard deviation is within ±35 % of the truth with high probability.
        assert!(
            (scatter / typical - 1.0).abs() < 0.35,
            "scatter {scatter} vs reported {typical}"
        );
    }

    #[test]
    fn correlations_are_a_valid_correlation_matrix() {
        let robot = irb1600();
        let truth = truth_params(&robot);
        let rows = random_rows(&robot, 13, 50);
        let measured: Vec<Vector3<f64>> = batch_predict(&robot, &truth, &rows)
            .iter()
            .map(|p| p.position_mm + Vector3::new(0.01, -0.02, 0.015))
            .collect();
        let free = Selection::spec_identifiable();
        let fit = fit(
            &robot,
            &truth,
            &rows,
            &measured,
            free.ids(),
            &FitOptions::default(),
        )
        .unwrap();
        let m = free.len();
        for i in 0..m {
            assert!((fit.correlation[i * m + i] - 1.0).abs() < 1e-12);
            for j in 0..m {
                let c = fit.correlation[i * m + j];
                assert!(c.abs() <= 1.0 + 1e-12 && c == fit.correlation[j * m + i]);
            }
        }
        let top = fit.strongest_correlations(5);
        assert_eq!(top.len(), 5);
        assert!(top.windows(2).all(|w| w[0].2.abs() >= w[1].2.abs()));
        assert!(fit.condition_number >= 1.0 && fit.condition_number.is_finite());
    }
}
