//! A Gaussian-process model of what a parametric model leaves: the residual
//! `measured − predicted` (mm, three axes) as a function of the joint angles and
//! the load, with a predictive variance that says how far to trust it (issue
//! 29, the `eg_residual` rung). Knows nothing of tables, robots or stages: rows
//! come in as feature vectors ([`joint_load_features`] builds them from a
//! configuration and a wrench).
//!
//! Shaped so because:
//! * one squared-exponential kernel with one length scale per joint and per
//!   wrench component (ARD by group, [`FeatureLayout`]) serves the three axes,
//!   with one noise variance: a joint that does not matter gets a long length
//!   scale, and the three axes' residuals come from the same physical causes;
//! * the mean is zero, so far from the calibration rows the model adds nothing
//!   to the parametric prediction and its latent variance returns to the prior
//!   signal variance `s²`: the uncertainty columns can then say "not measured
//!   here" instead of extrapolating a correction;
//! * up to [`ResidualOptions::inducing_points`] rows the posterior is exact; above,
//!   it is Titsias' variational (VFE) approximation on inducing points chosen by
//!   k-means++ seeding among the rows: `O(n·m²)` and the prior variance far
//!   from them (a DTC/SoR variance would fall to zero there);
//! * the hyperparameters `s²`, `σ²` and the length scales maximise the log
//!   marginal likelihood (the VFE bound above the exact size) by a small
//!   box-constrained L-BFGS from several seeded starts, on at most
//!   [`ResidualOptions::optimisation_rows`] rows drawn with the seed; the
//!   posterior then uses every row. Hand-written on faer rather than taken from
//!   a GP crate: see DESIGN.md.
//!
//! Everything random (the optimisation rows, the inducing points, the starts)
//! comes from [`ResidualOptions::seed`], and parallel work runs in fixed chunks
//! reduced in order, so results do not depend on the number of threads.

mod kernel;
mod optimise;
mod posterior;

use rand::rngs::StdRng;
use rand::seq::index;
use rand::{Rng, SeedableRng};
use rayon::prelude::*;

use kernel::Rows;
use optimise::Bounds;
use posterior::{AXES, Exact, Hyper, Sparse};

/// Features [`joint_load_features`] makes per row.
pub const JOINT_LOAD_FEATURES: usize = 18;
/// Forces are divided by this (N) in the features: campaign loads reach about
/// ±120 N, so scaled forces lie within about ±1.2 like the sines and cosines.
/// The length scales are fitted per component, so the scale matters only for
/// where k-means++ places inducing points.
pub const FORCE_SCALE_N: f64 = 100.0;
/// Moments are divided by this (N·m), for the same reason (loads of ±10 N·m).
pub const MOMENT_SCALE_NM: f64 = 10.0;
/// Rows a fit needs at least: fewer cannot say much about 14 hyperparameters.
pub const MIN_ROWS: usize = 20;
/// Jitter on `K_uu`'s diagonal (times `s²`) of the sparse posterior, and the
/// first one tried on the exact `K + σ²I` after a failed Cholesky.
pub const BASE_JITTER: f64 = 1e-8;
/// Jitters (times `s²`) tried in turn before a Cholesky failure is an error.
const JITTERS: [f64; 3] = [BASE_JITTER, 1e-6, 1e-4];

/// The features of one row: `sin q_i`, `cos q_i` of each joint angle (a joint
/// turned by 360° is the same joint, and the kernel distance between two
/// angles becomes `2 − 2cos Δq`), then the wrench `fx, fy, fz` (N) divided by
/// [`FORCE_SCALE_N`] and `mx, my, mz` (N·m) by [`MOMENT_SCALE_NM`].
pub fn joint_load_features(q_deg: &[f64; 6], wrench: &[f64; 6]) -> [f64; JOINT_LOAD_FEATURES] {
    let mut out = [0.0; JOINT_LOAD_FEATURES];
    for (i, q) in q_deg.iter().enumerate() {
        let (sin, cos) = q.to_radians().sin_cos();
        out[2 * i] = sin;
        out[2 * i + 1] = cos;
    }
    for (i, w) in wrench.iter().enumerate() {
        let scale = if i < 3 {
            FORCE_SCALE_N
        } else {
            MOMENT_SCALE_NM
        };
        out[12 + i] = w / scale;
    }
    out
}

/// Errors of fitting or evaluating a residual model.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ResidualError {
    #[error("a residual model needs at least {min} rows; got {rows}")]
    TooFewRows { rows: usize, min: usize },
    #[error("{what}: {values} values are not whole rows of {columns} features")]
    RaggedFeatures {
        what: &'static str,
        values: usize,
        columns: usize,
    },
    #[error("{features} feature rows but {residuals} residuals")]
    LengthMismatch { features: usize, residuals: usize },
    #[error("{what}: non-finite value in row {row}")]
    NonFinite { what: &'static str, row: usize },
    #[error(
        "feature layout: {0} (expected each column's length-scale group, the groups numbered 0, 1, … without gaps)"
    )]
    Layout(String),
    #[error("hyperparameter {name} = {value}: expected a positive finite number")]
    Hyperparameter { name: String, value: f64 },
    #[error("{expected} length scales expected (one per group); got {got}")]
    LengthScales { expected: usize, got: usize },
    #[error(
        "the covariance matrix is not positive definite even with {jitter:e}·s² on its diagonal (duplicate or near-duplicate rows with a tiny noise variance?)"
    )]
    Cholesky { jitter: f64 },
}

/// Which length scale each feature column uses.
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureLayout {
    groups: Vec<usize>,
    group_count: usize,
}

impl FeatureLayout {
    /// `groups[c]` is column `c`'s length-scale group; groups are numbered
    /// `0..g` and each is used.
    pub fn new(groups: Vec<usize>) -> Result<Self, ResidualError> {
        let group_count = groups.iter().max().map_or(0, |g| g + 1);
        if groups.is_empty() {
            return Err(ResidualError::Layout("no columns".into()));
        }
        if let Some(missing) = (0..group_count).find(|g| !groups.contains(g)) {
            return Err(ResidualError::Layout(format!(
                "group {missing} has no column"
            )));
        }
        Ok(FeatureLayout {
            groups,
            group_count,
        })
    }

    /// The layout of [`joint_load_features`]: a joint's sine and cosine share
    /// a length scale (so the kernel is periodic in that joint), and each
    /// wrench component has its own: 12 groups.
    pub fn joint_load() -> Self {
        let groups = (0..6).flat_map(|j| [j, j]).chain(6..12).collect();
        FeatureLayout {
            groups,
            group_count: 12,
        }
    }

    pub fn columns(&self) -> usize {
        self.groups.len()
    }

    pub fn group_count(&self) -> usize {
        self.group_count
    }
}

/// The kernel's and the noise's parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct Hyperparameters {
    /// Prior variance of the latent residual per axis (mm²): the predictive
    /// variance far from the data.
    pub signal_variance_mm2: f64,
    /// Variance of the measurement noise per axis (mm²).
    pub noise_variance_mm2: f64,
    /// One per group of the [`FeatureLayout`], in feature units.
    pub length_scales: Vec<f64>,
}

impl Hyperparameters {
    fn check(&self, layout: &FeatureLayout) -> Result<(), ResidualError> {
        if self.length_scales.len() != layout.group_count {
            return Err(ResidualError::LengthScales {
                expected: layout.group_count,
                got: self.length_scales.len(),
            });
        }
        let named = [
            ("signal_variance_mm2".to_string(), self.signal_variance_mm2),
            ("noise_variance_mm2".to_string(), self.noise_variance_mm2),
        ];
        let scales = self
            .length_scales
            .iter()
            .enumerate()
            .map(|(g, v)| (format!("length_scales[{g}]"), *v));
        for (name, value) in named.into_iter().chain(scales) {
            if !(value.is_finite() && value > 0.0) {
                return Err(ResidualError::Hyperparameter { name, value });
            }
        }
        Ok(())
    }

    /// From `[log s², log σ², log ℓ_0, …]`, the optimiser's coordinates.
    fn from_log(theta: &[f64]) -> Self {
        Hyperparameters {
            signal_variance_mm2: theta[0].exp(),
            noise_variance_mm2: theta[1].exp(),
            length_scales: theta[2..].iter().map(|v| v.exp()).collect(),
        }
    }

    fn hyper<'a>(&'a self, layout: &'a FeatureLayout) -> Hyper<'a> {
        Hyper {
            signal_variance: self.signal_variance_mm2,
            noise_variance: self.noise_variance_mm2,
            length_scales: &self.length_scales,
            groups: &layout.groups,
        }
    }
}

/// How a fit runs.
#[derive(Debug, Clone, PartialEq)]
pub struct ResidualOptions {
    /// Inducing points `m` of the sparse posterior; with at most this many rows
    /// the posterior is exact. Fit cost grows as `n·m²`.
    pub inducing_points: usize,
    /// Rows (drawn with the seed) the hyperparameters are optimised on; the
    /// posterior uses all rows.
    pub optimisation_rows: usize,
    /// Optimiser starts: the first from data-based guesses, the others
    /// perturbed from them with the seed; the best likelihood wins.
    pub restarts: usize,
    /// L-BFGS iterations per start.
    pub max_iterations: usize,
    pub seed: u64,
}

impl Default for ResidualOptions {
    /// 256 inducing points, 2000 optimisation rows, 3 starts of at most 100
    /// iterations, seed 0: 10 000 rows fit in a few seconds (docs/model-ladder.md).
    fn default() -> Self {
        ResidualOptions {
            inducing_points: 256,
            optimisation_rows: 2000,
            restarts: 3,
            max_iterations: 100,
            seed: 0,
        }
    }
}

/// One predicted residual.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ResidualPrediction {
    /// Posterior mean of the residual (mm), to add to the parametric prediction.
    pub mean_mm: [f64; 3],
    /// Posterior variance of the latent residual per axis (mm², the same for
    /// the three axes): near `0` among dense rows, `s²` far from them. A new
    /// measurement's variance adds the noise variance.
    pub latent_variance_mm2: f64,
}

#[derive(Debug, Clone)]
enum Posterior {
    /// The training features (row-major) and the exact posterior.
    Exact(Vec<f64>, Exact),
    /// The inducing points (row-major) and the VFE posterior.
    Sparse(Vec<f64>, Sparse),
}

/// A fitted residual model.
#[derive(Debug, Clone)]
pub struct ResidualModel {
    /// The training rows [`ResidualModel::fit`] chose as inducing points
    /// (empty for an exact posterior or explicit points): what a table keeps
    /// to rebuild the same posterior.
    inducing_rows: Vec<usize>,
    layout: FeatureLayout,
    hyperparameters: Hyperparameters,
    jitter: f64,
    posterior: Posterior,
}

fn check_rows(what: &'static str, values: &[f64], columns: usize) -> Result<usize, ResidualError> {
    if !values.len().is_multiple_of(columns) {
        return Err(ResidualError::RaggedFeatures {
            what,
            values: values.len(),
            columns,
        });
    }
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        return Err(ResidualError::NonFinite {
            what,
            row: i / columns,
        });
    }
    Ok(values.len() / columns)
}

fn check_training(
    layout: &FeatureLayout,
    features: &[f64],
    residuals_mm: &[[f64; 3]],
) -> Result<(), ResidualError> {
    let rows = check_rows("features", features, layout.columns())?;
    if rows != residuals_mm.len() {
        return Err(ResidualError::LengthMismatch {
            features: rows,
            residuals: residuals_mm.len(),
        });
    }
    if let Some(row) = residuals_mm
        .iter()
        .position(|r| r.iter().any(|v| !v.is_finite()))
    {
        return Err(ResidualError::NonFinite {
            what: "residuals",
            row,
        });
    }
    if rows < MIN_ROWS {
        return Err(ResidualError::TooFewRows {
            rows,
            min: MIN_ROWS,
        });
    }
    Ok(())
}

/// The indices of `count` rows chosen by k-means++ seeding (each next row
/// drawn with probability proportional to its squared distance to the nearest
/// chosen one). Fewer when the rows have fewer distinct values. `O(n·m·d)`.
fn kmeans_plus_plus(x: Rows<'_>, count: usize, rng: &mut StdRng) -> Vec<usize> {
    let n = x.len();
    let distance = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(p, q)| (p - q) * (p - q)).sum();
    let first = rng.random_range(0..n);
    let mut chosen = vec![first];
    let mut nearest: Vec<f64> = (0..n).map(|i| distance(x.row(i), x.row(first))).collect();
    for _ in 1..count.min(n) {
        let total: f64 = nearest.iter().sum();
        if total <= 0.0 {
            break;
        }
        let mut target = rng.random::<f64>() * total;
        let pick = nearest
            .iter()
            .position(|d| {
                target -= d;
                target < 0.0
            })
            .unwrap_or_else(|| nearest.iter().rposition(|d| *d > 0.0).unwrap_or(n - 1));
        let new = x.row(pick);
        chosen.push(pick);
        nearest.par_iter_mut().enumerate().for_each(|(i, d)| {
            *d = d.min(distance(x.row(i), new));
        });
    }
    chosen
}

/// Data-based starting hyperparameters and the box they are searched in: `s²`
/// and `σ²` from the residuals' mean square `v`, each length scale from the
/// median squared distance of its group's columns between random pairs of rows.
fn start_and_bounds(
    layout: &FeatureLayout,
    x: Rows<'_>,
    y: &[[f64; 3]],
    rng: &mut StdRng,
) -> (Vec<f64>, Bounds) {
    let v = (y.iter().flatten().map(|t| t * t).sum::<f64>() / (AXES * y.len()) as f64).max(1e-12);
    let n = x.len();
    let pairs = 500;
    let mut distances = vec![Vec::with_capacity(pairs); layout.group_count];
    for _ in 0..pairs {
        let (a, b) = (x.row(rng.random_range(0..n)), x.row(rng.random_range(0..n)));
        let mut per_group = vec![0.0; layout.group_count];
        for (c, g) in layout.groups.iter().enumerate() {
            per_group[*g] += (a[c] - b[c]) * (a[c] - b[c]);
        }
        for (g, d) in per_group.into_iter().enumerate() {
            distances[g].push(d);
        }
    }
    let medians: Vec<f64> = distances
        .into_iter()
        .map(|mut d| {
            d.sort_by(f64::total_cmp);
            d[d.len() / 2].sqrt()
        })
        .collect();
    let active = medians.iter().filter(|m| **m > 0.0).count().max(1) as f64;
    let scales: Vec<f64> = medians
        .iter()
        .map(|m| if *m > 0.0 { m * active.sqrt() } else { 1.0 })
        .collect();
    let mut start = vec![(0.5 * v).ln(), (0.1 * v).ln()];
    start.extend(scales.iter().map(|s| s.ln()));
    let mut lower = vec![(1e-6 * v).ln(), (1e-6 * v).ln()];
    let mut upper = vec![(1e2 * v).ln(), (1e1 * v).ln()];
    lower.extend(scales.iter().map(|s| (s / 20.0).ln()));
    upper.extend(scales.iter().map(|s| (s * 1e3).ln()));
    (start, Bounds { lower, upper })
}

impl ResidualModel {
    /// Fits the hyperparameters by maximum (marginal) likelihood and builds the
    /// posterior on every row. `features` is row-major, `layout.columns()` per
    /// row; `residuals_mm[k]` is row `k`'s `measured − predicted`.
    ///
    /// Cost: each likelihood evaluation is `O(r·m²)` on the `r` optimisation
    /// rows (`O(r³)` when exact), some 50–300 of them over the starts; the
    /// posterior is `O(n·m²)`.
    pub fn fit(
        layout: &FeatureLayout,
        features: &[f64],
        residuals_mm: &[[f64; 3]],
        options: &ResidualOptions,
    ) -> Result<Self, ResidualError> {
        check_training(layout, features, residuals_mm)?;
        let columns = layout.columns();
        let all = Rows {
            values: features,
            columns,
        };
        let n = all.len();
        let mut rng = StdRng::seed_from_u64(options.seed);
        let sparse = n > options.inducing_points;
        let inducing_rows = if sparse {
            kmeans_plus_plus(all, options.inducing_points.max(1), &mut rng)
        } else {
            Vec::new()
        };
        let inducing: Vec<f64> = inducing_rows
            .iter()
            .flat_map(|i| all.row(*i).iter().copied())
            .collect();
        let (subset_x, subset_y) = if n > options.optimisation_rows.max(MIN_ROWS) {
            let mut picked =
                index::sample(&mut rng, n, options.optimisation_rows.max(MIN_ROWS)).into_vec();
            picked.sort_unstable();
            let x: Vec<f64> = picked
                .iter()
                .flat_map(|i| all.row(*i).iter().copied())
                .collect();
            let y: Vec<[f64; 3]> = picked.iter().map(|i| residuals_mm[*i]).collect();
            (x, y)
        } else {
            (features.to_vec(), residuals_mm.to_vec())
        };
        let x = Rows {
            values: &subset_x,
            columns,
        };
        let z = Rows {
            values: &inducing,
            columns,
        };
        let subset_sparse = sparse && x.len() > z.len();
        let scale = 1.0 / (x.len() * AXES) as f64;
        let objective = |theta: &[f64]| {
            let h = Hyperparameters::from_log(theta);
            let hyper = h.hyper(layout);
            let evaluation = if subset_sparse {
                Sparse::evaluate(&hyper, x, z, &subset_y, BASE_JITTER, true)?.1
            } else {
                Exact::evaluate(&hyper, x, &subset_y, 0.0, true)?.1
            }?;
            let gradient = evaluation.gradient.iter().map(|g| -g * scale).collect();
            Some((-evaluation.value * scale, gradient))
        };
        let (first, bounds) = start_and_bounds(layout, x, &subset_y, &mut rng);
        let mut best: Option<(Vec<f64>, f64)> = None;
        for restart in 0..options.restarts.max(1) {
            let start: Vec<f64> = if restart == 0 {
                first.clone()
            } else {
                first
                    .iter()
                    .enumerate()
                    .map(|(i, v)| match i {
                        0 => v + rng.random_range(-2.0..1.0),
                        1 => v + rng.random_range(-3.0..1.0),
                        _ => v + rng.random_range(-1.0..1.5),
                    })
                    .collect()
            };
            if let Some((theta, value)) =
                optimise::minimise(objective, &start, &bounds, options.max_iterations, 1e-6)
                && best.as_ref().is_none_or(|(_, b)| value < *b)
            {
                best = Some((theta, value));
            }
        }
        let (theta, _) = best.ok_or(ResidualError::Cholesky {
            jitter: BASE_JITTER,
        })?;
        let hyperparameters = Hyperparameters::from_log(&theta);
        let mut model = Self::build(
            layout,
            features,
            residuals_mm,
            hyperparameters,
            sparse.then_some(inducing),
        )?;
        model.inducing_rows = inducing_rows;
        Ok(model)
    }

    /// The posterior for given hyperparameters: exact without `inducing`,
    /// VFE on the `inducing` points (row-major) with them. For tests against
    /// other implementations, and for refitting folds with one set of
    /// hyperparameters.
    pub fn with_hyperparameters(
        layout: &FeatureLayout,
        features: &[f64],
        residuals_mm: &[[f64; 3]],
        hyperparameters: &Hyperparameters,
        inducing: Option<&[f64]>,
    ) -> Result<Self, ResidualError> {
        check_training(layout, features, residuals_mm)?;
        hyperparameters.check(layout)?;
        if let Some(z) = inducing
            && check_rows("inducing points", z, layout.columns())? == 0
        {
            return Err(ResidualError::TooFewRows { rows: 0, min: 1 });
        }
        Self::build(
            layout,
            features,
            residuals_mm,
            hyperparameters.clone(),
            inducing.map(<[f64]>::to_vec),
        )
    }

    fn build(
        layout: &FeatureLayout,
        features: &[f64],
        residuals_mm: &[[f64; 3]],
        hyperparameters: Hyperparameters,
        inducing: Option<Vec<f64>>,
    ) -> Result<Self, ResidualError> {
        let columns = layout.columns();
        let x = Rows {
            values: features,
            columns,
        };
        let hyper = hyperparameters.hyper(layout);
        for (k, jitter) in JITTERS.iter().enumerate() {
            let posterior = match &inducing {
                Some(z) => {
                    let zr = Rows { values: z, columns };
                    Sparse::new(&hyper, x, zr, residuals_mm, *jitter)
                        .map(|s| Posterior::Sparse(z.clone(), s))
                }
                None => {
                    // The exact posterior needs no jitter unless it fails without.
                    let jitter = if k == 0 { 0.0 } else { *jitter };
                    Exact::new(&hyper, x, residuals_mm, jitter)
                        .map(|e| Posterior::Exact(features.to_vec(), e))
                }
            };
            if let Some(posterior) = posterior {
                return Ok(ResidualModel {
                    inducing_rows: Vec::new(),
                    layout: layout.clone(),
                    hyperparameters,
                    jitter: *jitter,
                    posterior,
                });
            }
        }
        Err(ResidualError::Cholesky {
            jitter: JITTERS[JITTERS.len() - 1],
        })
    }

    /// Mean residual and latent variance at each row of `features`
    /// (row-major). `O(N·m²)` (`O(N·n²)` exact), parallel in chunks.
    pub fn predict(&self, features: &[f64]) -> Result<Vec<ResidualPrediction>, ResidualError> {
        let columns = self.layout.columns();
        check_rows("prediction features", features, columns)?;
        let at = Rows {
            values: features,
            columns,
        };
        let hyper = self.hyperparameters.hyper(&self.layout);
        let predicted = match &self.posterior {
            Posterior::Exact(x, exact) => exact.predict(&hyper, Rows { values: x, columns }, at),
            Posterior::Sparse(z, sparse) => sparse.predict(&hyper, Rows { values: z, columns }, at),
        };
        Ok(predicted
            .into_iter()
            .map(|(mean_mm, variance)| ResidualPrediction {
                mean_mm,
                latent_variance_mm2: variance.max(0.0),
            })
            .collect())
    }

    pub fn hyperparameters(&self) -> &Hyperparameters {
        &self.hyperparameters
    }

    /// The training rows chosen as inducing points by [`ResidualModel::fit`]
    /// (in the order chosen); empty when the posterior is exact or was
    /// built on explicit points.
    pub fn inducing_rows(&self) -> &[usize] {
        &self.inducing_rows
    }

    /// Inducing points of the sparse posterior; 0 when it is exact.
    pub fn inducing_points(&self) -> usize {
        match &self.posterior {
            Posterior::Exact(..) => 0,
            Posterior::Sparse(z, _) => z.len() / self.layout.columns(),
        }
    }

    /// The log marginal likelihood of all rows (exact), or its VFE lower bound.
    pub fn log_marginal_likelihood(&self) -> f64 {
        match &self.posterior {
            Posterior::Exact(_, exact) => exact.log_likelihood,
            Posterior::Sparse(_, sparse) => sparse.log_likelihood,
        }
    }

    /// The jitter (times `s²`) the posterior's factorisation needed.
    pub fn jitter(&self) -> f64 {
        self.jitter
    }
}

#[cfg(test)]
mod tests;
