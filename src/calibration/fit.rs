//! Parameter identification on the linearised model (paper §III.B, eqs. (18)–(25)),
//! with standard errors, the condition number and parameter correlations at the
//! solution.
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
//! Every parameter vector the iteration visits costs one parallel pass over the
//! rows in chunks ([`stream`]): each chunk computes its rows' predictions,
//! residuals, loss weights and Jacobian rows and reduces the weighted equations
//! `[√W·J | √W·r]` to their `(m+1) × (m+1)` triangular factor, combined across
//! chunks. Only the per-row residuals and weights are kept, never the `3n × m`
//! Jacobian. Steps, predicted cost reductions, standard errors, the condition
//! number and correlations all come from that factor, exactly as from a QR of the
//! whole matrix: each step solves the column-scaled problem `min ‖R·D·y − c‖`
//! (`δ = D·y`, `D` scaling the columns of `√W·J` to unit norm) rather than the
//! normal equations of eq. (25), the same solution without squaring the condition
//! number. With unit-norm columns Marquardt's damping `λ·diag(JᵀJ)` becomes `λ·I`,
//! appended as rows to the `m × m` system.
//!
//! Stop criteria ([`Stop`]): both algorithms stop when an *undamped* step of
//! eq. (25) moved no predicted position by more than `stop_step_mm` — the largest
//! change over the rows between the predictions at the trial point and at the
//! current one, which the trial's pass computes anyway. (Before the passes were
//! streamed this was the change the linearisation predicts, `J_k·δ` per row,
//! which needs the whole Jacobian; for steps that small the two agree to second
//! order.) The undamped step vanishes exactly at a stationary point whatever the
//! damping, so a large λ cannot fake convergence. Levenberg–Marquardt tries it
//! instead of its damped step when its root-mean-square predicted change over the
//! rows, `‖R·δ‖/√n` from the factor, is below `stop_step_mm`: a necessary
//! condition, since with loss weights ≤ 1 that RMS cannot exceed the largest
//! change. Levenberg–Marquardt also stops when an accepted step lowers the cost by
//! less than the fraction `stop_relative_cost`; both give up, not converged, after
//! `max_iterations` steps tried.
//!
//! On large tables ([`WarmStart`], from 5 000 rows) [`fit_identifiable`]
//! first fits an evenly strided subsample and starts the full iteration at its
//! optimum, with Gauss–Newton steps until one is rejected (then Marquardt's
//! damping as from a cold start): two steps and three passes instead of four to
//! six steps, each a pass over every row (issue #31). The robust refits
//! ([`refit`]) start undamped there too. The optimum is the same; only the
//! path to it changes.
//!
//! The rank analysis stays at the start even then, but runs on the
//! subsample ([`Subsample`], which holds every kind of row the table does):
//! at a fitted point the exact dependencies of the nominal model (parallel
//! axes) become near ones, and a 3 000-row table's 32 identifiable parameters
//! became 37 there, five of them fitted to noise. So a large table's fit
//! makes no pass over every row at the start at all.
//!
//! An optional Huber loss on each row's residual norm is minimised by iteratively
//! reweighted least squares (the weights are recomputed from the residuals at
//! every point).
//!
//! Rows may carry fixed scales per axis ([`Observations::row_scale`]): `1/σ` of
//! the tracker's per-point uncertainty (spec §7), or 0 for a row excluded by the
//! robust fit ([`super::robust`]). Each equation is multiplied by its scale, the
//! loss acts on the scaled residual's norm, and the statistics count only rows
//! with a non-zero scale.
//!
//! A 6-D row (spec §8: the tool's orientation measured as well,
//! [`Observations::orientations`]) adds three equations: the rotation from the
//! model's tool orientation to the measured one as a world-frame rotation
//! vector in degrees ([`orientation_residual_deg`]), times the row's
//! orientation scale. It stays one row: one loss weight from the norm of its
//! six scaled residuals, excluded whole, and its predicted change in
//! `step_mm` counts the rotation as the position change it is worth (degrees
//! times the orientation scale over the position scale). Position-only rows
//! give exactly the equations, factors and bits they always did.

use std::ops::Range;

use faer::Mat;
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use super::rank::{self, RankAnalysis};
use super::subsample::Subsample;
use super::{dense, stream};
use crate::robot::frame::rotation_vector;
use crate::robot::{ConfWrench, PARAM_COUNT, ParamId, ParamValues, Robot};

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
    /// The IRLS weight of a row with residual norm `r_mm` (1 inside the threshold,
    /// below 1 beyond it).
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
    /// Stop when an undamped step changes no predicted position by more than this (mm).
    pub stop_step_mm: f64,
    /// Levenberg–Marquardt only: stop when an accepted step lowers the cost by
    /// less than this fraction.
    pub stop_relative_cost: f64,
    /// Rows per chunk of a pass (also of [`calibrate`](super::calibrate)'s rank
    /// analysis): [`stream::CHUNK_ROWS`] by default. Results depend on it only
    /// through rounding.
    pub chunk_rows: usize,
    /// [`fit_identifiable`] on large tables: start the iteration from a fit to
    /// a subsample (`None`: always from the start).
    pub warm_start: Option<WarmStart>,
}

/// When and from how many rows [`fit_identifiable`] starts from a subsample's
/// optimum ([`warm_start_sample`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WarmStart {
    /// Tables of at least this many rows.
    pub min_rows: usize,
    /// Rows of the subsample, evenly strided over the table: a fifth of the
    /// table, at most this many.
    pub sample_rows: usize,
}

impl WarmStart {
    /// The subsample's rows for a table of `rows`: a fifth of them keeps the
    /// subsample's fit (about as many steps as the whole's) near one pass
    /// over the table; `sample_rows` caps it where a larger one would not
    /// start the whole table any closer.
    fn sample_rows_for(&self, rows: usize) -> usize {
        self.sample_rows.min(rows / 5)
    }
}

impl Default for WarmStart {
    /// From 5 000 rows, whose fifth (1 000 rows, 3 000 equations for at
    /// most about 40 parameters) still starts the whole table a step or two
    /// from its optimum (a 10 000-row night: two Gauss–Newton steps for the
    /// kinematic model, one for the elasto-geometric); up to 20 000 rows,
    /// whose fit costs 2 % of a pass over 10⁶ rows and lands within a few µm
    /// of the whole's.
    fn default() -> Self {
        WarmStart {
            min_rows: 5_000,
            sample_rows: 20_000,
        }
    }
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            algorithm: Algorithm::LevenbergMarquardt,
            loss: Loss::LeastSquares,
            max_iterations: 30,
            stop_step_mm: 1e-4,
            stop_relative_cost: 1e-10,
            chunk_rows: stream::CHUNK_ROWS,
            warm_start: Some(WarmStart::default()),
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
    /// Largest change of a predicted position the step made: predictions at the
    /// trial point against those before the step.
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
    /// An undamped step moved no predicted position by more than `stop_step_mm`
    /// (on a large table: would move none by more, to first order; see
    /// [`WarmStart`]).
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

/// A 6-D row's measured tool orientation (spec §8) and the weight of its three
/// rotation equations.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeasuredOrientation {
    /// World ← tool rotation as measured (the tool's axes in the tracker frame).
    pub world_from_tool: Matrix3<f64>,
    /// The factor each rotation-residual component (deg) is multiplied by: `1/σ`
    /// (1/deg) with a per-point σ, else what the lever arm makes of a degree
    /// against the row's position scale (`identify`'s `orientation_lever_mm`).
    pub scale_per_deg: f64,
}

/// The rotation (deg, world frame, as a rotation vector) that takes the model's
/// tool orientation to the measured one: `log(R_measured·R_modelᵀ)`. It is
/// "measured − predicted" for orientations: `R_measured = exp([r]×)·R_model`.
pub fn orientation_residual_deg(
    measured_world_from_tool: &Matrix3<f64>,
    model_world_from_tool: &Matrix3<f64>,
) -> Vector3<f64> {
    rotation_vector(&(measured_world_from_tool * model_world_from_tool.transpose()))
        .map(f64::to_degrees)
}

/// What is fitted to: the rows, their measured positions and fixed per-row scales.
#[derive(Debug, Clone, Copy)]
pub struct Observations<'a> {
    pub rows: &'a [ConfWrench],
    pub measured_mm: &'a [Vector3<f64>],
    /// Per row and axis, the factor each equation is multiplied by: `1/σ` (1/mm)
    /// for weighted rows, 0 for an excluded row; `None`: 1 everywhere.
    pub row_scale: Option<&'a [Vector3<f64>]>,
    /// Per row, the measured tool orientation of a 6-D row (`None` for a
    /// position-only row); `None` overall: no row has one.
    pub orientations: Option<&'a [Option<MeasuredOrientation>]>,
}

impl<'a> Observations<'a> {
    /// Unweighted rows.
    pub fn new(rows: &'a [ConfWrench], measured_mm: &'a [Vector3<f64>]) -> Self {
        Observations {
            rows,
            measured_mm,
            row_scale: None,
            orientations: None,
        }
    }

    /// The measured orientation of row `k` where it is a 6-D row that takes
    /// part (an excluded row is excluded whole).
    pub fn orientation_of(&self, k: usize) -> Option<&MeasuredOrientation> {
        let orientation = self.orientations?[k].as_ref()?;
        match self.row_scale {
            Some(scales) if scales[k].iter().all(|s| *s == 0.0) => None,
            _ => Some(orientation),
        }
    }

    /// Whether some row carries an orientation.
    pub fn has_orientations(&self) -> bool {
        self.orientations
            .is_some_and(|o| o.iter().any(Option::is_some))
    }

    /// Row `k`'s scaled residual norm (positions and, for a 6-D row, the
    /// rotation), the quantity the loss and the robust fit judge a row by.
    pub fn scaled_norm(
        &self,
        k: usize,
        residual_mm: &Vector3<f64>,
        residual_deg: Option<&Vector3<f64>>,
    ) -> f64 {
        let scaled = residual_mm.component_mul(&self.scale_of(k));
        match (self.orientation_of(k), residual_deg) {
            (Some(o), Some(r)) => {
                (scaled.norm_squared() + (r * o.scale_per_deg).norm_squared()).sqrt()
            }
            _ => scaled.norm(),
        }
    }

    /// 6-D rows that take part.
    pub fn included_orientation_rows(&self) -> usize {
        match self.orientations {
            None => 0,
            Some(o) => (0..o.len())
                .filter(|k| self.orientation_of(*k).is_some())
                .count(),
        }
    }

    /// The scale of row `k` (1 on every axis without scales).
    pub fn scale_of(&self, k: usize) -> Vector3<f64> {
        self.row_scale
            .map_or_else(|| Vector3::repeat(1.0), |scales| scales[k])
    }

    /// Rows that take part (some axis with a non-zero scale).
    pub fn included_rows(&self) -> usize {
        match self.row_scale {
            None => self.rows.len(),
            Some(scales) => scales
                .iter()
                .filter(|s| s.iter().any(|v| *v != 0.0))
                .count(),
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
    /// Per row, a 6-D row's rotation residual ([`orientation_residual_deg`]) at
    /// the solution; `None` for position-only rows.
    pub residuals_deg: Vec<Option<Vector3<f64>>>,
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
    /// Covariance of the estimates in the parameters' units, row-major `m × m`.
    pub covariance: Vec<f64>,
    /// σ² of the covariance: the residual variance of a unit-weight equation,
    /// `Σ w_k‖s_k∘r_k‖² / (3n + 3n₆ − m)` (n₆ the 6-D rows; mm² without per-point σ; dimensionless with,
    /// a row's noise then being σ²·σ_row²). Kept so that a prediction's error can
    /// be judged against measurement noise as well as parameter uncertainty.
    pub variance_factor: f64,
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
    #[error("{rows} rows but {measured} measured positions or scales")]
    LengthMismatch { rows: usize, measured: usize },
    #[error("the fit diverged (residual became non-finite at iteration {0})")]
    Diverged(usize),
    #[error(
        "the Jacobian is rank deficient at the solution: the free parameters are not all identifiable from these rows"
    )]
    Singular,
    #[error("{0}")]
    Untrustworthy(String),
}

/// Residuals `measured − predicted` per row, in parallel.
pub fn residuals(
    robot: &Robot,
    p: &ParamValues,
    rows: &[ConfWrench],
    measured: &[Vector3<f64>],
) -> Vec<Vector3<f64>> {
    let prepared = robot.prepare(p);
    rows.par_iter()
        .zip(measured)
        .with_min_len(stream::CHUNK_ROWS)
        .map(|(row, meas)| meas - prepared.predict_row(row).position_mm)
        .collect()
}

/// Rotation residuals (deg) of each row with its orientation, `None` for the
/// rows without one: what [`residuals`] is for positions.
pub fn orientation_residuals(
    robot: &Robot,
    p: &ParamValues,
    data: &Observations<'_>,
) -> Vec<Option<Vector3<f64>>> {
    let Some(orientations) = data.orientations else {
        return vec![None; data.rows.len()];
    };
    let prepared = robot.prepare(p);
    data.rows
        .par_iter()
        .zip(orientations)
        .with_min_len(stream::CHUNK_ROWS)
        .map(|(row, orientation)| {
            let orientation = orientation.as_ref()?;
            let chains = prepared.loaded_chains(row);
            let model =
                prepared.world_from_base_at(row.track_mm).rotation * chains.deflected.tool.rotation;
            Some(orientation_residual_deg(
                &orientation.world_from_tool,
                &model,
            ))
        })
        .collect()
}

/// One row's residual `measured − predicted` (mm; deg for a 6-D row's rotation)
/// and loss weight at a point.
#[derive(Debug, Clone, Copy, Default)]
struct RowFit {
    residual_mm: Vector3<f64>,
    residual_deg: Option<Vector3<f64>>,
    weight: f64,
}

/// The larger of two values, NaN if either is (so a non-finite row cannot hide).
fn max_or_nan(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else {
        a.max(b)
    }
}

/// What some rows contribute at a point: one chunk's, or neighbouring chunks' combined.
struct Sums {
    /// Triangular factor of the rows' `[√W·J | √W·r]`, `(m+1) × (m+1)`.
    factor: Mat<f64>,
    /// When asked for, the factor of the unweighted `[J | r]` where it differs
    /// (`None`: every row has weight 1, so it is `factor`).
    unweighted: Option<Mat<f64>>,
    /// The loss (mm²).
    cost: f64,
    /// Σ w·‖r‖² (mm²).
    weighted_rss: f64,
    /// Σ ‖r‖² over the included rows (mm²).
    rss: f64,
    /// Rows with a non-zero scale.
    included: usize,
    /// Of those, 6-D rows (three more equations each).
    included_orientations: usize,
    /// Largest ‖r‖ (mm).
    max_mm: f64,
    /// Largest change of a predicted position from the previous point (mm; 0
    /// without one).
    step_mm: f64,
    /// On a large table, per free parameter, the square of the largest change
    /// of an included row's predicted position per unit of it (mm, a 6-D row's
    /// turn counted as in `step_mm`): `Σ_j |δ_j|·reach_j` bounds the largest
    /// change a step `δ` makes, to first order.
    reach_sq: Option<Vec<f64>>,
}

impl Sums {
    fn join(self, other: Sums) -> Sums {
        let unweighted = match (&self.unweighted, &other.unweighted) {
            (None, None) => None,
            (a, b) => Some(stream::stack(
                a.as_ref().unwrap_or(&self.factor),
                b.as_ref().unwrap_or(&other.factor),
            )),
        };
        Sums {
            factor: stream::stack(&self.factor, &other.factor),
            unweighted,
            cost: self.cost + other.cost,
            weighted_rss: self.weighted_rss + other.weighted_rss,
            rss: self.rss + other.rss,
            included: self.included + other.included,
            included_orientations: self.included_orientations + other.included_orientations,
            max_mm: max_or_nan(self.max_mm, other.max_mm),
            step_mm: max_or_nan(self.step_mm, other.step_mm),
            reach_sq: match (self.reach_sq, other.reach_sq) {
                (Some(a), Some(b)) => Some(a.iter().zip(&b).map(|(a, b)| a.max(*b)).collect()),
                (a, b) => a.or(b),
            },
        }
    }
}

/// The model at one parameter vector: each row's residual and weight, and the
/// factor and sums of all rows.
struct Point {
    values: ParamValues,
    rows: Vec<RowFit>,
    sums: Sums,
}

impl Point {
    /// One pass over the rows at `values`. With `previous` (the rows of the point
    /// this one is a step from), also the largest change of predicted position;
    /// with `unweighted`, also the factor without the loss's weights.
    fn at(
        problem: &Problem<'_>,
        values: ParamValues,
        previous: Option<&[RowFit]>,
        unweighted: bool,
    ) -> Point {
        let Problem {
            robot,
            data,
            free,
            options,
        } = *problem;
        let (rows, measured) = (data.rows, data.measured_mm);
        let m = free.len();
        let prepared = robot.prepare(&values);
        let leaf = |range: Range<usize>, out: &mut [RowFit]| {
            // Three equations a row, three more for a 6-D row's rotation (zero
            // for an excluded row, whose residuals are still reported).
            let raw_orientation = |k: usize| data.orientations.and_then(|o| o[k].as_ref());
            let six_d = range
                .clone()
                .filter(|k| raw_orientation(*k).is_some())
                .count();
            let six_d_taking_part = range
                .clone()
                .filter(|k| data.orientation_of(*k).is_some())
                .count();
            let equations = 3 * (range.len() + six_d);
            let mut block = stream::EquationBlock::new(equations, m + 1);
            let mut plain = unweighted.then(|| stream::EquationBlock::new(equations, m + 1));
            let mut columns = vec![Vector3::zeros(); m];
            let mut angular = vec![Vector3::zeros(); if six_d > 0 { m } else { 0 }];
            let (mut cost, mut weighted_rss, mut rss, mut max_mm, mut step_mm) =
                (0.0, 0.0, 0.0, 0.0, 0.0);
            let (mut included, mut all_weights_one) = (0, true);
            let mut reach_sq = problem.is_large().then(|| vec![0.0_f64; m]);
            for (k, (row, meas)) in rows[range.clone()]
                .iter()
                .zip(&measured[range.clone()])
                .enumerate()
            {
                let (prediction, residual_deg) = match raw_orientation(range.start + k) {
                    None => (prepared.jacobian_row(row, free, &mut columns), None),
                    Some(o) => {
                        let (prediction, model) = prepared.jacobian_row_with_orientation(
                            row,
                            free,
                            &mut columns,
                            &mut angular,
                        );
                        let residual = orientation_residual_deg(&o.world_from_tool, &model);
                        let scale = match data.orientation_of(range.start + k) {
                            Some(_) => o.scale_per_deg,
                            None => 0.0,
                        };
                        (prediction, Some((residual, scale)))
                    }
                };
                let residual_mm = meas - prediction.position_mm;
                let scale = data.scale_of(range.start + k);
                let scaled = residual_mm.component_mul(&scale);
                let norm = match residual_deg {
                    None => scaled.norm(),
                    Some((r, s)) => (scaled.norm_squared() + (r * s).norm_squared()).sqrt(),
                };
                let weight = options.loss.weight(norm);
                let root_weight = weight.sqrt();
                for axis in 0..3 {
                    let equation = block.next_equation();
                    for (value, column) in equation.iter_mut().zip(&columns) {
                        *value = root_weight * scale[axis] * column[axis];
                    }
                    equation[m] = root_weight * scaled[axis];
                    if let Some(plain) = plain.as_mut() {
                        let equation = plain.next_equation();
                        for (value, column) in equation.iter_mut().zip(&columns) {
                            *value = scale[axis] * column[axis];
                        }
                        equation[m] = scaled[axis];
                    }
                }
                if let Some((r, s)) = residual_deg {
                    for axis in 0..3 {
                        let equation = block.next_equation();
                        for (value, column) in equation.iter_mut().zip(&angular) {
                            *value = root_weight * s * column[axis];
                        }
                        equation[m] = root_weight * s * r[axis];
                        if let Some(plain) = plain.as_mut() {
                            let equation = plain.next_equation();
                            for (value, column) in equation.iter_mut().zip(&angular) {
                                *value = s * column[axis];
                            }
                            equation[m] = s * r[axis];
                        }
                    }
                }
                let taking_part = scale.iter().any(|v| *v != 0.0);
                if taking_part {
                    let norm_mm = residual_mm.norm();
                    included += 1;
                    all_weights_one &= weight == 1.0;
                    cost += options.loss.cost(norm);
                    weighted_rss += weight * norm * norm;
                    rss += norm_mm * norm_mm;
                    max_mm = max_or_nan(max_mm, norm_mm);
                    if let Some(reach_sq) = reach_sq.as_mut() {
                        let turn_scale = match residual_deg {
                            Some((_, s)) if s != 0.0 => Some(s * 3f64.sqrt() / scale.norm()),
                            _ => None,
                        };
                        for (j, reach) in reach_sq.iter_mut().enumerate() {
                            let moved_sq = match turn_scale {
                                None => columns[j].norm_squared(),
                                Some(t) => (columns[j].norm() + angular[j].norm() * t).powi(2),
                            };
                            *reach = reach.max(moved_sq);
                        }
                    }
                    if let Some(previous) = previous {
                        // r = measured − predicted: the prediction moved by r_before − r_now.
                        let before = &previous[range.start + k];
                        let moved_mm = (before.residual_mm - residual_mm).norm();
                        let moved = match (residual_deg, before.residual_deg) {
                            // The turn as the position change it is worth at this row's scales.
                            (Some((r, s)), Some(r_before)) => {
                                let position_scale = scale.norm() / 3f64.sqrt();
                                let turned_mm = (r_before - r).norm() * s / position_scale;
                                moved_mm.hypot(turned_mm)
                            }
                            _ => moved_mm,
                        };
                        step_mm = max_or_nan(step_mm, moved);
                    }
                }
                out[k] = RowFit {
                    residual_mm,
                    residual_deg: residual_deg.map(|(r, _)| r),
                    weight: if taking_part { weight } else { 0.0 },
                };
            }
            Sums {
                factor: dense::triangular_factor(block.finish()),
                unweighted: plain
                    .filter(|_| !all_weights_one)
                    .map(|plain| dense::triangular_factor(plain.finish())),
                cost,
                weighted_rss,
                rss,
                included,
                included_orientations: six_d_taking_part,
                max_mm,
                step_mm,
                reach_sq,
            }
        };
        let mut out = vec![RowFit::default(); rows.len()];
        let sums = stream::reduce_chunks(&mut out, options.chunk_rows, &leaf, &Sums::join)
            .unwrap_or_else(|| Sums {
                factor: Mat::zeros(m + 1, m + 1),
                unweighted: None,
                cost: 0.0,
                weighted_rss: 0.0,
                rss: 0.0,
                included: 0,
                included_orientations: 0,
                max_mm: 0.0,
                step_mm: 0.0,
                reach_sq: None,
            });
        Point {
            values,
            rows: out,
            sums,
        }
    }

    /// The same point with the Jacobian restricted to the columns `to` (a subset
    /// of `from`, the columns it was evaluated with). Those columns of the factor,
    /// with the residual column, are `Qᵀ` times the original columns, so their own
    /// factor is the restricted matrix's: no pass over the rows.
    fn restricted(mut self, from: &[ParamId], to: &[ParamId]) -> Point {
        let index: Vec<usize> = to
            .iter()
            .map(|id| {
                from.iter()
                    .position(|c| c == id)
                    .expect("restricted to a subset of the columns")
            })
            .collect();
        let (factor, k) = (&self.sums.factor, from.len());
        let selected = Mat::<f64>::from_fn(k + 1, to.len() + 1, |i, j| {
            factor[(i, index.get(j).copied().unwrap_or(k))]
        });
        self.sums.factor = dense::triangular_factor(selected);
        self.sums.unweighted = None;
        self
    }

    /// Residual RMS per coordinate and largest residual norm over the included rows (mm).
    /// An upper bound, to first order, on how far the step `delta` would move
    /// any included row's predicted position (mm); `None` off a large table.
    fn step_bound_mm(&self, delta: &[f64]) -> Option<f64> {
        let reach_sq = self.sums.reach_sq.as_ref()?;
        Some(
            delta
                .iter()
                .zip(reach_sq)
                .map(|(d, r)| d.abs() * r.sqrt())
                .sum(),
        )
    }

    fn norms(&self) -> (f64, f64) {
        let equations = (3 * self.sums.included).max(1) as f64;
        ((self.sums.rss / equations).sqrt(), self.sums.max_mm)
    }
}

/// What a fit works on.
#[derive(Clone, Copy)]
struct Problem<'a> {
    robot: &'a Robot,
    data: &'a Observations<'a>,
    free: &'a [ParamId],
    options: &'a FitOptions,
}

impl Problem<'_> {
    /// A table of at least the warm start's `min_rows`, where a pass over the
    /// rows costs enough to save one where possible.
    fn is_large(&self) -> bool {
        self.options
            .warm_start
            .is_some_and(|settings| self.data.rows.len() >= settings.min_rows)
    }
}

/// A point's column-scaled least-squares problem `min ‖R·D·y − c‖`, `δ = D·y`.
struct System {
    /// `R·D`: the factor of `√W·J` with columns scaled to unit norm, `m × m`.
    scaled: Mat<f64>,
    /// `c = Q₁ᵀ·√W·r`, `m × 1`.
    rhs: Mat<f64>,
    /// `D`: the scale of each column's parameter (1 for a column of zeros).
    scale: Vec<f64>,
    /// Rows of the data, for the RMS change.
    rows: usize,
}

/// A step from a [`Point`] and what the linear model predicts of it.
struct Step {
    delta: Vec<f64>,
    /// Root-mean-square predicted position change over the rows, weighted (mm):
    /// `‖R·δ‖/√n`, never above the largest change.
    rms_change_mm: f64,
    /// Cost reduction the weighted linear model predicts (mm²).
    predicted_reduction: f64,
}

impl System {
    fn new(point: &Point, m: usize) -> System {
        let factor = &point.sums.factor;
        // The factor's columns have the norms of √W·J's.
        let scale: Vec<f64> = (0..m)
            .map(|j| {
                let norm = factor.col(j).norm_l2();
                if norm > 0.0 { 1.0 / norm } else { 1.0 }
            })
            .collect();
        System {
            scaled: Mat::from_fn(m, m, |i, j| factor[(i, j)] * scale[j]),
            rhs: Mat::from_fn(m, 1, |i, _| factor[(i, m)]),
            scale,
            rows: point.sums.included,
        }
    }

    /// Solves `min ‖R·D·y − c‖² + λ‖y‖²` by QR with `√λ·I` appended (λ = 0: the
    /// Gauss–Newton step of eq. (25)).
    fn step(&self, damping: f64) -> Step {
        let m = self.scale.len();
        let y = if damping > 0.0 {
            let root_damping = damping.sqrt();
            let a = Mat::<f64>::from_fn(2 * m, m, |i, j| {
                if i < m {
                    self.scaled[(i, j)]
                } else if i - m == j {
                    root_damping
                } else {
                    0.0
                }
            });
            let b =
                Mat::<f64>::from_fn(2 * m, 1, |i, _| if i < m { self.rhs[(i, 0)] } else { 0.0 });
            dense::lstsq(a.as_ref(), b.as_ref())
        } else {
            dense::lstsq(self.scaled.as_ref(), self.rhs.as_ref())
        };
        // u = R·D·y = Q₁ᵀ·√W·J·δ; ‖c‖² − ‖c − u‖² = uᵀ(2c − u) without cancellation.
        let (mut predicted_reduction, mut change_squared) = (0.0, 0.0);
        for i in 0..m {
            let u: f64 = (i..m).map(|j| self.scaled[(i, j)] * y[(j, 0)]).sum();
            predicted_reduction += 0.5 * u * (2.0 * self.rhs[(i, 0)] - u);
            change_squared += u * u;
        }
        Step {
            delta: (0..m).map(|j| y[(j, 0)] * self.scale[j]).collect(),
            rms_change_mm: (change_squared / self.rows.max(1) as f64).sqrt(),
            predicted_reduction,
        }
    }
}

/// Fits the `free` parameters, starting from `start`, to the measured positions.
///
/// Cost: one parallel pass over the rows (predictions and Jacobian rows, reduced
/// chunk by chunk) per step tried plus one at the start, and `m × m` work per
/// step. Memory: O(n) for the per-row residuals and weights of two points, O(m²)
/// per chunk in flight; never the `3n × m` Jacobian.
pub fn fit(
    robot: &Robot,
    start: &ParamValues,
    data: &Observations<'_>,
    free: &[ParamId],
    options: &FitOptions,
) -> Result<Fit, FitError> {
    fit_from(robot, start, data, free, options, false)
}

/// [`fit`] from the optimum of a nearby problem (the robust refits: the same
/// rows under other weights). On a table large enough for a warm start the
/// iteration begins with Gauss–Newton steps, as after one: Marquardt's damping
/// there only shortens steps that each cost a pass over every row (10⁷ rows
/// with two gross outliers took 128 s through two damped refits, issue #31).
pub fn refit(
    robot: &Robot,
    nearby_optimum: &ParamValues,
    data: &Observations<'_>,
    free: &[ParamId],
    options: &FitOptions,
) -> Result<Fit, FitError> {
    fit_from(robot, nearby_optimum, data, free, options, true)
}

/// [`fit`], or with `near_optimum` [`refit`].
fn fit_from(
    robot: &Robot,
    start: &ParamValues,
    data: &Observations<'_>,
    free: &[ParamId],
    options: &FitOptions,
    near_optimum: bool,
) -> Result<Fit, FitError> {
    check_sizes(data, free.len())?;
    let problem = Problem {
        robot,
        data,
        free,
        options,
    };
    let point = Point::at(&problem, *start, None, false);
    let damping = if near_optimum && problem.is_large() {
        0.0
    } else {
        INITIAL_DAMPING
    };
    iterate(&problem, point, damping)
}

/// Rank analysis of `candidates` at `start` ([`rank`]) and the fit of the
/// identifiable ones from there, as [`fit`] does.
///
/// On a small table the first pass serves both: it factors the Jacobian of
/// every candidate with the residuals, unweighted for the rank analysis (and
/// weighted, where the loss down-weights rows, for the fit), and the start
/// point of the fit takes the identifiable columns of that factor
/// (`Point::restricted`). So the rank analysis costs no pass of its own.
///
/// On a large one ([`WarmStart`]) both the rank analysis and a first fit run
/// on a subsample that holds every kind of row the table does
/// ([`Subsample`]), and the full iteration starts at the subsample's optimum:
/// no pass over every row at the start at all (issue #31).
pub fn fit_identifiable(
    robot: &Robot,
    start: &ParamValues,
    data: &Observations<'_>,
    candidates: &[ParamId],
    rank_tolerance: f64,
    options: &FitOptions,
) -> Result<(RankAnalysis, Fit), FitError> {
    check_sizes(data, 0)?;
    let ordered = rank::priority_order(candidates, data.has_orientations());
    let all = Problem {
        robot,
        data,
        free: &ordered,
        options,
    };
    let subsample = warm_start_sample(&all);
    let sample = subsample.as_ref().map(Subsample::observations);
    let analysed = Problem {
        data: sample.as_ref().unwrap_or(data),
        ..all
    };
    let (analysis, first) = analyse_at_start(&analysed, &ordered, start, rank_tolerance);
    let free = analysis.independent.clone();
    check_sizes(data, free.len())?;
    let problem = Problem { free: &free, ..all };
    let first = first.restricted(&ordered, &free);
    let (point, damping) = match &sample {
        // A small table: the first pass is the fit's start.
        None => (first, INITIAL_DAMPING),
        // A large one: fit the subsample from its first pass, then start the
        // whole table's iteration at its optimum with the Gauss–Newton step
        // (Marquardt's damping there only shortens it, and each shortened
        // step costs a pass: the kinematic model of a loaded arm took four).
        // A fit that fails on the subsample leaves the whole table to start
        // from `start`, damped, as a small table does.
        Some(_) => {
            let sample_problem = Problem {
                free: &free,
                ..analysed
            };
            match iterate(&sample_problem, first, INITIAL_DAMPING) {
                Ok(fitted) if fitted.converged => {
                    (Point::at(&problem, fitted.values, None, false), 0.0)
                }
                _ => (Point::at(&problem, *start, None, false), INITIAL_DAMPING),
            }
        }
    };
    Ok((analysis, iterate(&problem, point, damping)?))
}

/// The pass at `start` over `all`'s rows with every column of `ordered`,
/// and the rank analysis of its unweighted factor.
fn analyse_at_start(
    all: &Problem<'_>,
    ordered: &[ParamId],
    start: &ParamValues,
    rank_tolerance: f64,
) -> (RankAnalysis, Point) {
    let first = Point::at(all, *start, None, true);
    let unweighted = first.sums.unweighted.as_ref().unwrap_or(&first.sums.factor);
    let analysis = rank::analyse_factor(
        unweighted.as_ref().subcols(0, ordered.len()),
        ordered,
        rank_tolerance,
    );
    (analysis, first)
}

/// Marquardt's λ at a cold start, relative to the unit diagonal of the scaled
/// JᵀJ; also where a warm start's undamped iteration turns after its first
/// rejected step.
const INITIAL_DAMPING: f64 = 1e-3;

/// The subsample of [`WarmStart::sample_rows`] rows that `problem`'s rank
/// analysis and first fit run on; `None` without a warm start, below its
/// `min_rows`, or for the paper's algorithm, whose iteration stays the
/// paper's from the start.
///
/// Every step from `start` costs a pass over all rows; from the subsample's
/// optimum the full problem needs one step and the pass that confirms it
/// (plus one where that step still moved a prediction by more than
/// `stop_step_mm`), where the start took three to five (issue #31). The
/// optimum is the full problem's either way: only the path to it changes.
fn warm_start_sample(problem: &Problem<'_>) -> Option<Subsample> {
    let settings = problem.options.warm_start?;
    if problem.data.rows.len() < settings.min_rows || problem.options.algorithm == Algorithm::Paper
    {
        return None;
    }
    let rows = problem.data.rows.len();
    Some(Subsample::of(problem.data, settings.sample_rows_for(rows)))
}

/// One measured position (and scale) per row, and more equations than free
/// parameters among the included rows.
fn check_sizes(data: &Observations<'_>, parameters: usize) -> Result<(), FitError> {
    let rows = data.rows.len();
    for other in [Some(data.measured_mm.len()), data.row_scale.map(<[_]>::len)]
        .into_iter()
        .flatten()
    {
        if other != rows {
            return Err(FitError::LengthMismatch {
                rows,
                measured: other,
            });
        }
    }
    if let Some(orientations) = data.orientations
        && orientations.len() != rows
    {
        return Err(FitError::LengthMismatch {
            rows,
            measured: orientations.len(),
        });
    }
    let included = data.included_rows();
    let equations = 3 * (included + data.included_orientation_rows());
    if equations <= parameters {
        return Err(FitError::TooFewRows {
            rows: included,
            equations,
            parameters,
        });
    }
    Ok(())
}

/// The iteration from its first point (see the module docs), Marquardt's λ
/// starting at `damping` (0: Gauss–Newton steps until one is rejected).
fn iterate(problem: &Problem<'_>, mut point: Point, damping: f64) -> Result<Fit, FitError> {
    let (free, options) = (problem.free, problem.options);
    let m = free.len();
    let mut trace = Vec::new();
    let mut stop = Stop::MaxIterations;
    // Marquardt's λ relative to the unit diagonal of the scaled JᵀJ; ν is Nielsen's
    // growth factor after rejections (Madsen, Nielsen & Tingleff 2004, §3.2).
    let (mut damping, mut growth) = (damping, 2.0);
    // Levenberg–Marquardt: the undamped step from this point raised the cost, so
    // damped steps follow until one is taken.
    let mut undamped_rejected = false;
    for iteration in 1..=options.max_iterations {
        if !point.sums.cost.is_finite() {
            return Err(FitError::Diverged(iteration));
        }
        let (rms_mm, max_mm) = point.norms();
        let system = System::new(&point, m);
        // The Gauss–Newton step of eq. (25) decides convergence for both algorithms:
        // it vanishes exactly at a stationary point, whatever the damping.
        let gauss_newton = system.step(0.0);
        if !gauss_newton.delta.iter().all(|d| d.is_finite()) {
            return Err(FitError::Diverged(iteration));
        }
        // On a large table, a step that provably moves nothing by more than
        // `stop_step_mm` need not be taken: the pass that would confirm it
        // costs as much as a step (issue #31). Its predicted positions are
        // within that of this point's, so the optimum is the same.
        if options.algorithm == Algorithm::LevenbergMarquardt
            && !trace.is_empty()
            && point
                .step_bound_mm(&gauss_newton.delta)
                .is_some_and(|bound_mm| bound_mm < options.stop_step_mm)
        {
            stop = Stop::Step;
            break;
        }
        let (step, damping_used) = match options.algorithm {
            Algorithm::Paper => (gauss_newton, None),
            Algorithm::LevenbergMarquardt
                if gauss_newton.rms_change_mm < options.stop_step_mm && !undamped_rejected =>
            {
                (gauss_newton, Some(0.0))
            }
            Algorithm::LevenbergMarquardt => (system.step(damping), Some(damping)),
        };
        let undamped = damping_used.is_none_or(|d| d == 0.0);
        let mut candidate = point.values;
        for (id, dv) in free.iter().zip(&step.delta) {
            candidate.0[id.index()] += dv;
        }
        let next = Point::at(problem, candidate, Some(&point.rows), false);
        let mut record = Iteration {
            iteration,
            rms_mm,
            max_mm,
            step_mm: next.sums.step_mm,
            damping: damping_used,
            accepted: true,
        };
        let converged = undamped && next.sums.step_mm < options.stop_step_mm;
        if converged || options.algorithm == Algorithm::Paper {
            // Paper steps (f)–(g): take the step, stop once it no longer moves the
            // model. Levenberg–Marquardt takes its last (tiny) undamped step too.
            point = next;
            trace.push(record);
            if converged {
                stop = Stop::Step;
                break;
            }
            continue;
        }
        let gain = (point.sums.cost - next.sums.cost) / step.predicted_reduction;
        if next.sums.cost.is_finite() && gain > 0.0 {
            let relative =
                (point.sums.cost - next.sums.cost) / point.sums.cost.max(f64::MIN_POSITIVE);
            damping *= (1.0 - (2.0 * gain - 1.0).powi(3)).max(1.0 / 3.0);
            growth = 2.0;
            undamped_rejected = false;
            point = next;
            trace.push(record);
            if relative < options.stop_relative_cost {
                stop = Stop::CostChange;
                break;
            }
        } else {
            damping = if damping > 0.0 {
                damping * growth
            } else {
                INITIAL_DAMPING
            };
            growth *= 2.0;
            undamped_rejected |= undamped;
            record.accepted = false;
            trace.push(record);
        }
    }
    if !point.sums.cost.is_finite() {
        return Err(FitError::Diverged(trace.len()));
    }
    let system = System::new(&point, m);
    let statistics = statistics(&point, &system, free)?;
    let residual_rms_mm = point.norms().0;
    let (residuals_mm, weights) = point
        .rows
        .iter()
        .map(|row| (row.residual_mm, row.weight))
        .unzip();
    let residuals_deg = point.rows.iter().map(|row| row.residual_deg).collect();
    Ok(Fit {
        values: point.values,
        std_errors: statistics.std_errors,
        trace,
        residual_rms_mm,
        residuals_mm,
        residuals_deg,
        weights,
        stop,
        converged: stop != Stop::MaxIterations,
        condition_number: statistics.condition_number,
        free: free.to_vec(),
        correlation: statistics.correlation,
        covariance: statistics.covariance,
        variance_factor: statistics.variance_factor,
    })
}

struct Statistics {
    std_errors: [Option<f64>; PARAM_COUNT],
    condition_number: f64,
    correlation: Vec<f64>,
    covariance: Vec<f64>,
    variance_factor: f64,
}

/// Covariance `σ²·(JᵀWJ)⁻¹` at the solution with `σ² = Σ w_k‖r_k‖² / (3n + 3n₆ − m)`
/// (scaled residuals, included rows; with per-point σ, σ² is the variance factor),
/// from the SVD of the scaled factor `R·D = U·S·Vᵀ` (the same singular values and
/// `V` as the scaled, weighted Jacobian's): `Cov ∝ V·S⁻²·Vᵀ`, which stays accurate
/// where forming JᵀJ would square the condition number. For the Huber loss this is
/// the usual IRLS approximation.
fn statistics(point: &Point, system: &System, free: &[ParamId]) -> Result<Statistics, FitError> {
    let m = free.len();
    let equations = 3 * (point.sums.included + point.sums.included_orientations);
    let sigma2 = point.sums.weighted_rss / (equations - m) as f64;
    let scale = &system.scale;
    let (s, v) = dense::svd(system.scaled.as_ref(), true).map_err(|_| FitError::Singular)?;
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
    let covariance = (0..m * m)
        .map(|ij| {
            let (i, j) = (ij / m, ij % m);
            covariance[ij] * sigma2 * scale[i] * scale[j]
        })
        .collect();
    Ok(Statistics {
        std_errors,
        condition_number: s_max / s_min,
        correlation,
        covariance,
        variance_factor: sigma2,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::test_support::{irb1600, random_q, random_wrench, truth_params};
    use crate::robot::{Selection, batch_jacobian, batch_predict};
    use rand::SeedableRng;
    use rand::rngs::StdRng;

    /// The rows' positions under `truth` with Gaussian noise of `sigma_mm` per axis.
    fn noisy_positions(
        robot: &Robot,
        truth: &ParamValues,
        rows: &[ConfWrench],
        sigma_mm: f64,
        seed: u64,
    ) -> Vec<Vector3<f64>> {
        let mut rng = StdRng::seed_from_u64(seed);
        let normal = rand_distr::Normal::new(0.0, sigma_mm).unwrap();
        batch_predict(robot, truth, rows)
            .iter()
            .map(|p| {
                p.position_mm
                    + Vector3::from_fn(|_, _| rand_distr::Distribution::sample(&normal, &mut rng))
            })
            .collect()
    }

    fn random_rows(robot: &Robot, seed: u64, n: usize) -> Vec<ConfWrench> {
        let mut rng = StdRng::seed_from_u64(seed);
        (0..n)
            .map(|_| ConfWrench {
                q_deg: random_q(robot, &mut rng),
                wrench: random_wrench(&mut rng),
                target: 0,
                approach: [0; 7],
                track_mm: 0.0,
                positioner_deg: None,
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
            let fit = fit(
                &robot,
                &nominal,
                &Observations::new(&rows, &measured),
                free.ids(),
                &options,
            )
            .unwrap();
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
        let data = Observations::new(&rows, &measured);
        let problem = Problem {
            robot: &robot,
            data: &data,
            free: free.ids(),
            options: &options,
        };
        // Damped from the start, and undamped until the first rejection (a
        // warm start's iteration).
        for damping in [INITIAL_DAMPING, 0.0] {
            let point = Point::at(&problem, start, None, false);
            let fit = iterate(&problem, point, damping).unwrap();
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
            let fit = fit(
                &robot,
                &truth,
                &Observations::new(&rows, &noisy),
                free.ids(),
                &options,
            )
            .unwrap();
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
            &Observations::new(&rows, &measured),
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

    /// The streamed Gauss–Newton step of eq. (25) and a damped step equal an
    /// independent dense solution at the same linearisation point: the full
    /// weighted Jacobian from `batch_jacobian`, solved by faer's own QR
    /// (`Mat::qr().solve_lstsq`). Same point and rows, so only rounding may differ:
    /// 2500 noisy rows in chunks of 300 (nine chunks, the last of 100 rows), with
    /// Huber weights that differ from row to row.
    #[test]
    fn streamed_steps_equal_the_dense_least_squares_solution() {
        use faer::prelude::*;
        let robot = irb1600();
        let truth = truth_params(&robot);
        let rows = random_rows(&robot, 14, 2500);
        let mut rng = StdRng::seed_from_u64(15);
        let normal = rand_distr::Normal::new(0.0, 0.02).unwrap();
        let measured: Vec<Vector3<f64>> = batch_predict(&robot, &truth, &rows)
            .iter()
            .map(|p| {
                p.position_mm
                    + Vector3::from_fn(|_, _| rand_distr::Distribution::sample(&normal, &mut rng))
            })
            .collect();
        let free = Selection::spec_identifiable();
        let m = free.len();
        // Linearise near the truth, with the Huber threshold at the median residual
        // so that about half the rows are down-weighted.
        let mut start = truth;
        for (name, change) in [("x_w", 0.3), ("dtheta2", 0.02), ("da3", -0.2), ("k2", 2e-5)] {
            let id = ParamId::from_name(name).unwrap();
            start.set(id, start.get(id) + change);
        }
        let mut norms: Vec<f64> = residuals(&robot, &start, &rows, &measured)
            .iter()
            .map(|r| r.norm())
            .collect();
        norms.sort_by(f64::total_cmp);
        let options = FitOptions {
            loss: Loss::Huber {
                threshold_mm: norms[norms.len() / 2],
            },
            chunk_rows: 300,
            ..FitOptions::default()
        };
        let data = Observations::new(&rows, &measured);
        let problem = Problem {
            robot: &robot,
            data: &data,
            free: free.ids(),
            options: &options,
        };
        let point = Point::at(&problem, start, None, false);
        let system = System::new(&point, m);

        // The dense problem, built independently.
        let batch = batch_jacobian(&robot, &start, &rows, free.ids());
        let equations = 3 * rows.len();
        let residual = |k: usize| measured[k] - batch.predictions[k].position_mm;
        let weights: Vec<f64> = (0..rows.len())
            .map(|k| options.loss.weight(residual(k).norm()))
            .collect();
        assert!(weights.iter().any(|w| *w < 0.9) && weights.contains(&1.0));
        let a = Mat::<f64>::from_fn(equations, m, |i, j| {
            weights[i / 3].sqrt() * batch.entry(i, j)
        });
        let b = Mat::<f64>::from_fn(equations, 1, |i, _| {
            weights[i / 3].sqrt() * residual(i / 3)[i % 3]
        });
        let column_norms: Vec<f64> = (0..m).map(|j| a.col(j).norm_l2()).collect();
        for damping in [0.0_f64, 1e-3] {
            // min ‖A·δ − b‖² + λ‖D⁻¹δ‖² with D⁻¹ the column norms of A.
            let dense: Vec<f64> = if damping == 0.0 {
                let x = a.qr().solve_lstsq(&b);
                (0..m).map(|j| x[(j, 0)]).collect()
            } else {
                let stacked = Mat::<f64>::from_fn(equations + m, m, |i, j| {
                    if i < equations {
                        a[(i, j)] / column_norms[j]
                    } else if i - equations == j {
                        damping.sqrt()
                    } else {
                        0.0
                    }
                });
                let rhs = Mat::<f64>::from_fn(equations + m, 1, |i, _| {
                    if i < equations { b[(i, 0)] } else { 0.0 }
                });
                let y = stacked.qr().solve_lstsq(&rhs);
                (0..m).map(|j| y[(j, 0)] / column_norms[j]).collect()
            };
            let streamed = system.step(damping).delta;
            // Compared in scaled units (parameter change times its column norm:
            // mm of position change), relative to the whole step.
            let scaled = |d: &[f64]| -> Vec<f64> {
                d.iter().zip(&column_norms).map(|(x, n)| x * n).collect()
            };
            let (s, d) = (scaled(&streamed), scaled(&dense));
            let size = d.iter().map(|x| x * x).sum::<f64>().sqrt();
            let worst = s
                .iter()
                .zip(&d)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f64::max);
            assert!(worst <= 1e-9 * size, "λ = {damping}: {worst} of {size}");
            for (j, (x, y)) in streamed.iter().zip(&dense).enumerate() {
                assert!(
                    (x - y).abs() <= 1e-9 * y.abs(),
                    "λ = {damping}, {}: {x} vs {y}",
                    free.ids()[j]
                );
            }
        }
    }

    /// A warm start changes the path, not the optimum: the fit from a
    /// subsample's optimum agrees with the fit from the start to well within
    /// the standard errors, in fewer steps, the first of them undamped, and
    /// without the pass that would confirm a last negligible step.
    #[test]
    fn a_warm_start_reaches_the_same_optimum_in_fewer_steps() {
        let robot = irb1600();
        let truth = truth_params(&robot);
        let nominal = ParamValues::nominal(robot.spec());
        let rows = random_rows(&robot, 23, 3000);
        let measured = noisy_positions(&robot, &truth, &rows, 0.03, 29);
        let data = Observations::new(&rows, &measured);
        let candidates: Vec<ParamId> = ParamId::all().collect();
        let fit_with = |warm_start| {
            let options = FitOptions {
                warm_start,
                ..FitOptions::default()
            };
            fit_identifiable(&robot, &nominal, &data, &candidates, 1e-6, &options).unwrap()
        };
        let (cold_rank, cold) = fit_with(None);
        let (warm_rank, warm) = fit_with(Some(WarmStart {
            min_rows: 1000,
            sample_rows: 500,
        }));
        assert_eq!(cold_rank.independent, warm_rank.independent);
        assert!(cold.converged && warm.converged);
        assert!(
            warm.trace.len() < cold.trace.len(),
            "{} steps warm, {} cold",
            warm.trace.len(),
            cold.trace.len()
        );
        assert_eq!(warm.trace[0].damping, Some(0.0));
        // The first-order bound ended it without a confirming pass: its last
        // step still moved a prediction by more than the tolerance.
        assert_eq!(warm.stop, Stop::Step);
        let last = warm.trace.last().unwrap();
        assert!(
            last.step_mm > FitOptions::default().stop_step_mm,
            "{last:?}"
        );
        for (k, id) in cold.free.iter().enumerate() {
            let error = cold.std_errors[id.index()].unwrap();
            let gap = (warm.values.get(*id) - cold.values.get(*id)).abs();
            assert!(
                gap < 1e-3 * error,
                "{id}: {gap} against σ {error} (column {k})"
            );
        }
        assert!((warm.residual_rms_mm - cold.residual_rms_mm).abs() < 1e-9);
    }

    /// On a large table the rank analysis runs on the subsample: a second
    /// target measured on five rows only, all between the stride's rows, is
    /// still found identifiable, as the whole table's analysis finds it.
    #[test]
    fn the_subsample_s_rank_analysis_keeps_a_target_measured_on_few_rows() {
        let robot = irb1600();
        let truth = truth_params(&robot);
        let nominal = ParamValues::nominal(robot.spec());
        let mut rows = random_rows(&robot, 31, 3000);
        for k in [1, 2, 3, 4, 5] {
            rows[k].target = 1;
        }
        let measured = noisy_positions(&robot, &truth, &rows, 0.03, 37);
        let data = Observations::new(&rows, &measured);
        let candidates: Vec<ParamId> = ParamId::all_with_targets(6, 2).collect();
        let fit_with = |warm_start| {
            let options = FitOptions {
                warm_start,
                ..FitOptions::default()
            };
            fit_identifiable(&robot, &nominal, &data, &candidates, 1e-6, &options).unwrap()
        };
        let (whole_rank, whole) = fit_with(None);
        let (sample_rank, sampled) = fit_with(Some(WarmStart {
            min_rows: 1000,
            sample_rows: 500,
        }));
        let second_target = ParamId::all_with_targets(6, 2).last().unwrap();
        assert!(whole_rank.independent.contains(&second_target));
        assert_eq!(whole_rank.independent, sample_rank.independent);
        assert!(whole.converged && sampled.converged);
        assert!((sampled.residual_rms_mm - whole.residual_rms_mm).abs() < 1e-9);
    }

    /// A Huber refit from the least-squares optimum (a few gross rows among
    /// many) reaches [`fit`]'s optimum; on a large table it begins with a
    /// Gauss–Newton step and needs fewer steps, on a small one it starts
    /// damped as [`fit`] does.
    #[test]
    fn a_refit_from_a_nearby_optimum_starts_undamped_on_large_tables() {
        let robot = irb1600();
        let truth = truth_params(&robot);
        let nominal = ParamValues::nominal(robot.spec());
        let rows = random_rows(&robot, 31, 2000);
        let mut measured = noisy_positions(&robot, &truth, &rows, 0.03, 37);
        for k in [17, 900, 1500] {
            measured[k].x += 3.0;
        }
        let data = Observations::new(&rows, &measured);
        let free = Selection::spec_identifiable();
        let least_squares =
            fit(&robot, &nominal, &data, free.ids(), &FitOptions::default()).unwrap();
        let huber = |min_rows| FitOptions {
            loss: Loss::Huber { threshold_mm: 0.1 },
            warm_start: Some(WarmStart {
                min_rows,
                sample_rows: 500,
            }),
            ..FitOptions::default()
        };
        let damped = fit(
            &robot,
            &least_squares.values,
            &data,
            free.ids(),
            &huber(1000),
        )
        .unwrap();
        let large = refit(
            &robot,
            &least_squares.values,
            &data,
            free.ids(),
            &huber(1000),
        )
        .unwrap();
        let small = refit(
            &robot,
            &least_squares.values,
            &data,
            free.ids(),
            &huber(10_000),
        )
        .unwrap();
        let damped_small = fit(
            &robot,
            &least_squares.values,
            &data,
            free.ids(),
            &huber(10_000),
        )
        .unwrap();
        assert!(damped.converged && large.converged && small.converged);
        assert_eq!(large.trace[0].damping, Some(0.0));
        assert_eq!(small.trace, damped_small.trace);
        assert_eq!(small.values.0, damped_small.values.0);
        assert!(
            large.trace.len() <= damped.trace.len(),
            "{} steps undamped, {} damped",
            large.trace.len(),
            damped.trace.len()
        );
        for id in free.ids() {
            let error = damped.std_errors[id.index()].unwrap();
            // The Huber iteration creeps: each path stops within its step
            // tolerance, a hundredth of a standard error apart.
            let gap = (large.values.get(*id) - damped.values.get(*id)).abs();
            assert!(gap < 1e-2 * error, "{id}: {gap} against σ {error}");
        }
    }

    /// The rank analysis taken from the fit's first pass (weighted rows, since the
    /// Huber loss down-weights every row at nominal) and the fit started from that
    /// pass's restricted factor equal a separate rank pass and a separate fit.
    #[test]
    fn the_rank_analysis_shares_the_fit_s_first_pass() {
        let robot = irb1600();
        let truth = truth_params(&robot);
        let nominal = ParamValues::nominal(robot.spec());
        let rows = random_rows(&robot, 16, 300);
        let measured = noisy_positions(&robot, &truth, &rows, 0.02, 17);
        let options = FitOptions {
            algorithm: Algorithm::Paper,
            loss: Loss::Huber { threshold_mm: 0.5 },
            stop_step_mm: 1e-10,
            chunk_rows: 64,
            ..FitOptions::default()
        };
        let all: Vec<ParamId> = ParamId::all().collect();
        let (analysis, shared) = fit_identifiable(
            &robot,
            &nominal,
            &Observations::new(&rows, &measured),
            &all,
            1e-6,
            &options,
        )
        .unwrap();
        let separate_analysis = rank::analyse(&robot, &nominal, &rows, &all, 1e-6, 64);
        assert_eq!(analysis.independent, Selection::spec_identifiable().ids());
        assert_eq!(analysis.independent, separate_analysis.independent);
        assert_eq!(analysis.dependent, separate_analysis.dependent);
        for (a, b) in analysis
            .singular_values
            .iter()
            .zip(&separate_analysis.singular_values)
        {
            assert!((a - b).abs() < 1e-12 * separate_analysis.singular_values[0]);
        }
        let separate = fit(
            &robot,
            &nominal,
            &Observations::new(&rows, &measured),
            &analysis.independent,
            &options,
        )
        .unwrap();
        assert!(shared.converged && separate.converged);
        assert_eq!(shared.trace.len(), separate.trace.len());
        for id in &analysis.independent {
            let (a, b) = (shared.values.get(*id), separate.values.get(*id));
            let se = separate.std_errors[id.index()].unwrap();
            assert!(
                (a - b).abs() <= 1e-12 * b.abs() + 1e-10 * se,
                "{id}: {a} vs {b}"
            );
        }
    }
}
