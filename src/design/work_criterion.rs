//! Campaigns designed for the work (issue #28): choose the rows whose
//! identification leaves the smallest predicted position uncertainty at the
//! user's work targets, instead of the best-conditioned Jacobian overall (O1).
//! O1 spreads the rows over every direction of parameter space; what a target
//! needs is that the few combinations of parameters its position depends on are
//! well determined.
//!
//! With the candidates' scaled blocks B_k (3×m, scaled as [`super::detmax`]
//! does), M = Σ_set B_kᵀ·B_k and a tracker noise σ (mm per axis), a fit leaves
//! the scaled parameters with covariance σ²·M⁻¹, so the predicted position at
//! target t (its block G_t, scaled alike) has covariance C_t = σ²·G_t·M⁻¹·G_tᵀ
//! (mm²): the J·Σ·Jᵀ of [`crate::calibration::uncertainty`], in which the
//! scaling cancels. Both criteria are minimised:
//!
//! * [`WorkCriterion::Mean`], I-optimality (average prediction variance):
//!   mean_t trace C_t = σ²·trace(M⁻¹·W), W = mean_t G_tᵀ·G_t. It is linear in
//!   M⁻¹, so the fast engine scores every trial exactly from two cached 3×3
//!   matrices per candidate, Q_k = B_k·M⁻¹·B_kᵀ and P_k = B_k·M⁻¹·W·M⁻¹·B_kᵀ:
//!   adding k lowers trace(M⁻¹·W) by trace((I + Q_k)⁻¹·P_k), removing it raises
//!   it by trace((I − Q_k)⁻¹·P_k) (Woodbury). An exchange changes M⁻¹ by one
//!   rank-6 term V·E·Vᵀ, and every Q_k and P_k follows from B_k·[V, M⁻¹·W·V]: an
//!   O(N·m) pass over the N candidates. M is refactorised every
//!   [`REFACTOR_EVERY`] exchanges, as in DETMAX.
//! * [`WorkCriterion::Max`], minimax (V-optimality): the largest u95 over the
//!   targets, u95 = sqrt(χ²₃(0.95)·λmax C_t). Not linear: the outsiders are
//!   ranked by their I gain and the best `shortlist` evaluated exactly, and every
//!   member for the removal.
//!
//! [`Method::Naive`] refactorises M for every trial; it verifies the fast engine.

use nalgebra::{DMatrix, Dyn, Matrix3, OMatrix, SMatrix, U3};
use rayon::prelude::*;

use super::detmax::{
    Candidates, DetmaxError, Method, REFACTOR_EVERY, add_block, best_of, naive_best_addition,
    naive_exchange, observability_index, random_start, removal_choice, ridged_cholesky,
};
use crate::calibration::accuracy_map::u95_mm;

/// m×3: M⁻¹·Bᵀ of a 3×m block.
type Tall = OMatrix<f64, Dyn, U3>;
/// m×6: the two rank-3 directions of an exchange.
type Tall6 = OMatrix<f64, Dyn, nalgebra::U6>;

/// Candidates per rayon task (each costs ~100·m flops per exchange).
const MIN_CANDIDATES_PER_TASK: usize = 128;

/// The work targets' identification Jacobian, scaled like the candidates.
#[derive(Debug, Clone, PartialEq)]
pub struct WorkTargets {
    rows: Vec<f64>,
    count: usize,
    m: usize,
}

impl WorkTargets {
    /// From the row-major `3·count × m` Jacobian of the targets (unscaled, the
    /// candidates' parameters in the same order) and the candidates' column
    /// scale ([`Candidates::from_jacobian`]).
    pub fn from_jacobian(jacobian: &[f64], count: usize, scale: &[f64]) -> WorkTargets {
        let m = scale.len();
        let rows = jacobian[..3 * count * m]
            .iter()
            .enumerate()
            .map(|(i, v)| v * scale[i % m])
            .collect();
        WorkTargets { rows, count, m }
    }

    pub fn len(&self) -> usize {
        self.count
    }

    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    fn block(&self, t: usize) -> &[f64] {
        &self.rows[3 * t * self.m..3 * (t + 1) * self.m]
    }

    /// W = mean_t G_tᵀ·G_t.
    fn weight(&self) -> DMatrix<f64> {
        let mut w = DMatrix::zeros(self.m, self.m);
        for t in 0..self.count {
            add_block(&mut w, self.block(t), 1.0 / self.count as f64);
        }
        w
    }
}

/// What a work-driven selection minimises.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WorkCriterion {
    /// I-optimal: the mean over the targets of trace C_t (mm²).
    Mean,
    /// Minimax: the largest u95 over the targets (mm).
    Max,
}

/// What to select and how.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorkOptions {
    /// Rows to select.
    pub n: usize,
    pub criterion: WorkCriterion,
    pub method: Method,
    /// Upper bound on exchanges.
    pub max_iterations: usize,
    /// Fast engine, `Max`: outsiders evaluated exactly per addition, best by the
    /// I gain; 0 evaluates all.
    pub shortlist: usize,
    /// Seed of the random start.
    pub seed: u64,
    /// Measurement noise per axis (mm): C_t scales with its square.
    pub sigma_mm: f64,
}

/// The predicted position covariance at each target of a set.
#[derive(Debug, Clone, PartialEq)]
pub struct TargetPrediction {
    /// C_t = σ²·G_t·M⁻¹·G_tᵀ (mm²).
    pub covariances_mm2: Vec<Matrix3<f64>>,
    /// sqrt(χ²₃(0.95)·λmax C_t) (mm).
    pub u95_mm: Vec<f64>,
}

impl TargetPrediction {
    fn from_covariances(covariances_mm2: Vec<Matrix3<f64>>) -> TargetPrediction {
        let u95_mm = covariances_mm2.iter().map(u95_mm).collect();
        TargetPrediction {
            covariances_mm2,
            u95_mm,
        }
    }

    pub fn mean_u95_mm(&self) -> f64 {
        self.u95_mm.iter().sum::<f64>() / self.u95_mm.len().max(1) as f64
    }

    pub fn max_u95_mm(&self) -> f64 {
        self.u95_mm.iter().copied().fold(0.0, f64::max)
    }

    /// mean_t trace C_t (mm²).
    pub fn mean_variance_mm2(&self) -> f64 {
        self.covariances_mm2.iter().map(|c| c.trace()).sum::<f64>()
            / self.covariances_mm2.len().max(1) as f64
    }

    /// The criterion's value (lower is better).
    pub fn value(&self, criterion: WorkCriterion) -> f64 {
        match criterion {
            WorkCriterion::Mean => self.mean_variance_mm2(),
            WorkCriterion::Max => self.max_u95_mm(),
        }
    }
}

/// The prediction at the targets of a set, from a fresh Cholesky factorisation
/// of its M; `None` when M is singular.
pub fn predict(
    c: &Candidates,
    targets: &WorkTargets,
    set: &[usize],
    sigma_mm: f64,
) -> Option<TargetPrediction> {
    let inv = c.information(set).cholesky()?.inverse();
    Some(prediction_from_inverse(targets, &inv, sigma_mm))
}

fn prediction_from_inverse(
    targets: &WorkTargets,
    inv: &DMatrix<f64>,
    sigma_mm: f64,
) -> TargetPrediction {
    let s2 = sigma_mm * sigma_mm;
    TargetPrediction::from_covariances(
        (0..targets.len())
            .map(|t| quadratic(targets.block(t), inv) * s2)
            .collect(),
    )
}

/// One exchange of the loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorkExchange {
    pub iteration: usize,
    pub added: usize,
    pub removed: usize,
    /// The criterion after the exchange (mm² for `Mean`, mm for `Max`).
    pub value: f64,
}

/// Result of a work-driven selection.
#[derive(Debug, Clone, PartialEq)]
pub struct WorkSelection {
    /// Indexes into the candidates, in the order they entered.
    pub chosen: Vec<usize>,
    /// The criterion of the final set (fresh factorisation) and of the start.
    pub value: f64,
    pub value_start: f64,
    /// The prediction at the targets of the final set.
    pub prediction: TargetPrediction,
    /// O1 of the final set, for comparison with an O1 design.
    pub o1: f64,
    pub trace: Vec<WorkExchange>,
    pub converged: bool,
    pub refactorisations: usize,
}

/// The exchange (DETMAX's steps (a)–(d), with the work criterion) from a seeded
/// random start of `options.n`; for `Max`, from the `Mean` selection of that
/// start.
pub fn work_detmax(
    c: &Candidates,
    targets: &WorkTargets,
    options: &WorkOptions,
) -> Result<WorkSelection, DetmaxError> {
    check(c, options.n)?;
    let start = random_start(c, options.n, options.seed);
    if options.criterion == WorkCriterion::Max {
        // The minimax surface is flat almost everywhere (one target decides):
        // start it from the I-optimal set, so it can only improve on that.
        let mean = WorkOptions {
            criterion: WorkCriterion::Mean,
            ..*options
        };
        let warm = work_detmax_from(c, targets, &mean, start)?;
        return work_detmax_from(c, targets, options, warm.chosen);
    }
    work_detmax_from(c, targets, options, start)
}

/// The size checks of [`super::detmax::detmax`].
fn check(c: &Candidates, n: usize) -> Result<(), DetmaxError> {
    let (m, total) = (c.parameters(), c.len());
    if n > total {
        return Err(DetmaxError::NotEnoughCandidates {
            wanted: n,
            available: total,
        });
    }
    if 3 * n < m || n == 0 {
        return Err(DetmaxError::TooFew { n, rows: 3 * n, m });
    }
    let all: Vec<usize> = (0..total).collect();
    if c.information(&all).cholesky().is_none() {
        return Err(DetmaxError::Singular);
    }
    Ok(())
}

/// The exchange from a given start (its size is the n selected).
pub fn work_detmax_from(
    c: &Candidates,
    targets: &WorkTargets,
    options: &WorkOptions,
    start: Vec<usize>,
) -> Result<WorkSelection, DetmaxError> {
    check(c, start.len())?;
    let mut engine: Box<dyn WorkEngine + '_> = match options.method {
        Method::Fast => Box::new(Fast::new(c, targets, start, options)),
        Method::Naive => Box::new(Naive::new(c, targets, start, options)),
    };
    let value_start = engine.value();
    let mut trace = Vec::new();
    let mut converged = false;
    for iteration in 1..=options.max_iterations {
        let Some(added) = engine.best_addition() else {
            converged = true;
            break;
        };
        let removed = engine.exchange(added);
        trace.push(WorkExchange {
            iteration,
            added,
            removed,
            value: engine.value(),
        });
        if added == removed {
            converged = true;
            break;
        }
    }
    let chosen = engine.members().to_vec();
    let prediction = predict(c, targets, &chosen, options.sigma_mm).ok_or(DetmaxError::Singular)?;
    Ok(WorkSelection {
        value: prediction.value(options.criterion),
        o1: observability_index(c, &chosen),
        chosen,
        value_start,
        prediction,
        trace,
        converged,
        refactorisations: engine.refactorisations(),
    })
}

/// One point of the stopping rule's curve: the prediction at the targets of the
/// best set of `n` rows found.
#[derive(Debug, Clone, PartialEq)]
pub struct CurvePoint {
    pub n: usize,
    pub mean_u95_mm: f64,
    pub max_u95_mm: f64,
    pub chosen: Vec<usize>,
}

/// The predicted u95 at the targets against n, for n = `from`..=`to`: the
/// exchange at `from` from a random start, then at each next n from the previous
/// set plus its best addition, so that the sets are optimised at every n and
/// the criterion cannot rise with n (the previous set plus a row is a candidate
/// start no worse than it).
pub fn curve(
    c: &Candidates,
    targets: &WorkTargets,
    options: &WorkOptions,
    from: usize,
    to: usize,
) -> Result<Vec<CurvePoint>, DetmaxError> {
    let mut points = Vec::new();
    let mut set = work_detmax(
        c,
        targets,
        &WorkOptions {
            n: from,
            ..*options
        },
    )?
    .chosen;
    for n in from..=to.min(c.len()) {
        if n > from {
            let engine = Fast::new(c, targets, set.clone(), options);
            match engine.best_addition() {
                Some(k) => set.push(k),
                None => break,
            }
            set = work_detmax_from(c, targets, &WorkOptions { n, ..*options }, set)?.chosen;
        }
        let prediction =
            predict(c, targets, &set, options.sigma_mm).ok_or(DetmaxError::Singular)?;
        points.push(CurvePoint {
            n,
            mean_u95_mm: prediction.mean_u95_mm(),
            max_u95_mm: prediction.max_u95_mm(),
            chosen: set.clone(),
        });
    }
    Ok(points)
}

/// A work-criterion exchange engine. Scores are "higher is better" (the
/// negated criterion) so that [`best_of`] and [`removal_choice`] apply.
trait WorkEngine {
    fn best_addition(&self) -> Option<usize>;
    fn exchange(&mut self, added: usize) -> usize;
    fn members(&self) -> &[usize];
    fn value(&self) -> f64;
    fn refactorisations(&self) -> usize;
}

/// B·X·Bᵀ for a 3×m row-major block and a symmetric m×m X.
fn quadratic(b: &[f64], x: &DMatrix<f64>) -> Matrix3<f64> {
    let m = x.nrows();
    let mut q = Matrix3::zeros();
    for (l, column) in x.as_slice().chunks_exact(m).enumerate() {
        let t: [f64; 3] = std::array::from_fn(|r| dot(&b[r * m..(r + 1) * m], column));
        for r in 0..3 {
            for s in 0..3 {
                q[(r, s)] += t[r] * b[s * m + l];
            }
        }
    }
    0.5 * (q + q.transpose())
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// m×k matrix X as a k-wide product B·X (3×k) of a row-major 3×m block.
fn block_times<C: nalgebra::Dim>(b: &[f64], x: &OMatrix<f64, Dyn, C>) -> OMatrix<f64, U3, C>
where
    nalgebra::DefaultAllocator: nalgebra::allocator::Allocator<U3, C>,
{
    let m = x.nrows();
    OMatrix::<f64, U3, C>::from_fn_generic(U3, x.shape_generic().1, |r, j| {
        dot(&b[r * m..(r + 1) * m], x.column(j).as_slice())
    })
}

/// B_kᵀ as an m×3 matrix.
fn transposed(b: &[f64], m: usize) -> Tall {
    Tall::from_fn(m, |i, r| b[r * m + i])
}

/// The largest u95 at the targets for M⁻¹ = `inv` + U·S⁻¹·Uᵀ·`sign`.
fn max_u95_after(
    targets: &WorkTargets,
    z: &[Matrix3<f64>],
    u: &Tall,
    core: &Matrix3<f64>,
    sigma_mm: f64,
) -> f64 {
    let s2 = sigma_mm * sigma_mm;
    (0..targets.len())
        .map(|t| {
            let x = block_times(targets.block(t), u);
            u95_mm(&((z[t] + x * core * x.transpose()) * s2))
        })
        .fold(0.0, f64::max)
}

struct Fast<'a> {
    c: &'a Candidates,
    targets: &'a WorkTargets,
    criterion: WorkCriterion,
    shortlist: usize,
    sigma_mm: f64,
    members: Vec<usize>,
    in_set: Vec<bool>,
    info: DMatrix<f64>,
    /// M⁻¹ (of M plus `ridge`·I while M is singular).
    inv: DMatrix<f64>,
    /// W = mean_t G_tᵀ·G_t.
    w: DMatrix<f64>,
    /// trace(M⁻¹·W), by the exchange's updates between refactorisations.
    phi: f64,
    /// B_k·M⁻¹·B_kᵀ and B_k·M⁻¹·W·M⁻¹·B_kᵀ of every candidate.
    q: Vec<Matrix3<f64>>,
    p: Vec<Matrix3<f64>>,
    ridge: f64,
    since_refactor: usize,
    refactorisations: usize,
}

impl<'a> Fast<'a> {
    fn new(
        c: &'a Candidates,
        targets: &'a WorkTargets,
        start: Vec<usize>,
        options: &WorkOptions,
    ) -> Fast<'a> {
        let m = c.parameters();
        let mut in_set = vec![false; c.len()];
        start.iter().for_each(|&k| in_set[k] = true);
        let mut fast = Fast {
            c,
            targets,
            criterion: options.criterion,
            shortlist: options.shortlist,
            sigma_mm: options.sigma_mm,
            members: start,
            in_set,
            info: DMatrix::zeros(m, m),
            inv: DMatrix::zeros(m, m),
            w: targets.weight(),
            phi: 0.0,
            q: vec![Matrix3::zeros(); c.len()],
            p: vec![Matrix3::zeros(); c.len()],
            ridge: 0.0,
            since_refactor: 0,
            refactorisations: 0,
        };
        fast.refactor();
        fast
    }

    /// M, M⁻¹, trace(M⁻¹·W) and every Q_k, P_k afresh: O(N·m²). A singular M (a
    /// degenerate start) gets a ridge raised until it factorises, as in DETMAX.
    fn refactor(&mut self) {
        let (chol, ridge, info) = ridged_cholesky(&self.c.information(&self.members));
        self.ridge = ridge;
        self.inv = chol.inverse();
        self.info = info;
        self.phi = self.inv.component_mul(&self.w).sum();
        let h = &self.inv * &self.w * &self.inv;
        let (c, inv) = (self.c, &self.inv);
        self.q
            .par_iter_mut()
            .zip(self.p.par_iter_mut())
            .enumerate()
            .with_min_len(MIN_CANDIDATES_PER_TASK)
            .for_each(|(k, (q, p))| {
                *q = quadratic(c.block(k), inv);
                *p = quadratic(c.block(k), &h);
            });
        self.since_refactor = 0;
    }

    /// G_t·M⁻¹·G_tᵀ of every target (unscaled by σ²).
    fn target_quadratics(&self, inv: &DMatrix<f64>) -> Vec<Matrix3<f64>> {
        (0..self.targets.len())
            .map(|t| quadratic(self.targets.block(t), inv))
            .collect()
    }

    fn tall(&self, k: usize) -> Tall {
        &self.inv * transposed(self.c.block(k), self.c.parameters())
    }
}

/// trace(X⁻¹·P) for a positive-definite 3×3 X; −∞ when X is not invertible.
fn trace_solve(x: &Matrix3<f64>, p: &Matrix3<f64>) -> f64 {
    match x.try_inverse() {
        Some(inv) => (inv * p).trace(),
        None => f64::NEG_INFINITY,
    }
}

/// X⁻¹ of I − Q after a removal, or `None` when the removal leaves M singular
/// (det(I − Q) = det M_after / det M ≤ 0 to rounding).
fn regular_inverse(x: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    if x.determinant() <= 1e-12 {
        return None;
    }
    x.try_inverse()
}

impl WorkEngine for Fast<'_> {
    fn best_addition(&self) -> Option<usize> {
        let gains: Vec<(usize, f64)> = self
            .q
            .par_iter()
            .zip(self.p.par_iter())
            .enumerate()
            .with_min_len(MIN_CANDIDATES_PER_TASK)
            .filter(|(k, _)| !self.in_set[*k])
            .map(|(k, (q, p))| (k, trace_solve(&(Matrix3::identity() + q), p)))
            .collect();
        if self.criterion == WorkCriterion::Mean {
            return best_of(gains.into_iter());
        }
        let mut shortlist = gains;
        if self.shortlist > 0 && shortlist.len() > self.shortlist {
            shortlist.select_nth_unstable_by(self.shortlist - 1, |(ka, a), (kb, b)| {
                b.total_cmp(a).then(ka.cmp(kb))
            });
            shortlist.truncate(self.shortlist);
        }
        let z = self.target_quadratics(&self.inv);
        let scores: Vec<(usize, f64)> = shortlist
            .par_iter()
            .map(|&(k, _)| {
                let u = self.tall(k);
                let core = -(Matrix3::identity() + self.q[k])
                    .try_inverse()
                    .unwrap_or_else(Matrix3::zeros);
                (
                    k,
                    -max_u95_after(self.targets, &z, &u, &core, self.sigma_mm),
                )
            })
            .collect();
        best_of(scores.into_iter())
    }

    fn exchange(&mut self, added: usize) -> usize {
        let m = self.c.parameters();
        let a = added;
        let u_a = self.tall(a);
        let s = Matrix3::identity() + self.q[a];
        let s_inv = s.try_inverse().expect("I + B·M⁻¹·Bᵀ is positive definite");
        let aw = &self.inv * &self.w;
        let awu_a: Tall = &aw * &u_a;
        let wuu = u_a.transpose() * &self.w * &u_a;
        let grown: Vec<usize> = self.members.iter().copied().chain([a]).collect();
        // Q and P of the members after the addition (V = U_a, E = −S⁻¹).
        let after_addition: Vec<(Matrix3<f64>, Matrix3<f64>)> = grown
            .iter()
            .map(|&k| {
                let b = self.c.block(k);
                let x = block_times(b, &u_a);
                let y = block_times(b, &awu_a);
                let xs = x * s_inv;
                let q1 = self.q[k] - xs * x.transpose();
                let p1 = self.p[k] - y * s_inv * x.transpose() - xs * y.transpose()
                    + xs * wuu * xs.transpose();
                (q1, p1)
            })
            .collect();
        let phi1 = self.phi - (s_inv * self.p[a]).trace();
        let scores: Vec<(usize, f64)> = match self.criterion {
            WorkCriterion::Mean => grown
                .iter()
                .zip(&after_addition)
                .map(
                    |(&k, (q1, p1))| match regular_inverse(&(Matrix3::identity() - q1)) {
                        Some(t_inv) => (k, -(phi1 + (t_inv * p1).trace())),
                        None => (k, f64::NEG_INFINITY),
                    },
                )
                .collect(),
            WorkCriterion::Max => {
                let inv1 = &self.inv - &u_a * s_inv * u_a.transpose();
                let z1 = self.target_quadratics(&inv1);
                grown
                    .par_iter()
                    .zip(&after_addition)
                    .map(
                        |(&k, (q1, _))| match regular_inverse(&(Matrix3::identity() - q1)) {
                            Some(core) => {
                                let u = &inv1 * transposed(self.c.block(k), m);
                                (
                                    k,
                                    -max_u95_after(self.targets, &z1, &u, &core, self.sigma_mm),
                                )
                            }
                            None => (k, f64::NEG_INFINITY),
                        },
                    )
                    .collect()
            }
        };
        let removed = removal_choice(&scores, a);
        if removed == a {
            return a;
        }
        let r = removed;
        let position = grown.iter().position(|&k| k == r).expect("r is a member");
        let q1_r = after_addition[position].0;
        let t = Matrix3::identity() - q1_r;
        let t_inv = t
            .try_inverse()
            .expect("r's removal keeps M regular (det(I − Q1_r) > 0)");
        let x_ra = block_times(self.c.block(r), &u_a);
        let u_r1: Tall = self.tall(r) - &u_a * (s_inv * x_ra.transpose());
        // M⁻¹ changes by V·E·Vᵀ, V = [U_a, U_r1], E = diag(−S⁻¹, T⁻¹).
        let v = Tall6::from_fn(m, |i, j| if j < 3 { u_a[(i, j)] } else { u_r1[(i, j - 3)] });
        let mut e = SMatrix::<f64, 6, 6>::zeros();
        e.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-s_inv));
        e.fixed_view_mut::<3, 3>(3, 3).copy_from(&t_inv);
        let awv: Tall6 = &aw * &v;
        let vwv: SMatrix<f64, 6, 6> = {
            let x = v.transpose() * &self.w * &v;
            SMatrix::<f64, 6, 6>::from_fn(|i, j| x[(i, j)])
        };
        let f = e * vwv * e;
        self.phi += (e * vwv).trace();
        self.inv += &v * e * v.transpose();
        // Both halves of B_k·[V, M⁻¹·W·V] per candidate, one pass.
        let both = OMatrix::<f64, Dyn, nalgebra::U12>::from_fn(m, |i, j| {
            if j < 6 { v[(i, j)] } else { awv[(i, j - 6)] }
        });
        let c = self.c;
        self.q
            .par_iter_mut()
            .zip(self.p.par_iter_mut())
            .enumerate()
            .with_min_len(MIN_CANDIDATES_PER_TASK)
            .for_each(|(k, (q, p))| {
                let xy = block_times(c.block(k), &both);
                let x: SMatrix<f64, 3, 6> = xy.fixed_columns::<6>(0).into_owned();
                let y: SMatrix<f64, 3, 6> = xy.fixed_columns::<6>(6).into_owned();
                let xe = x * e;
                *q += xe * x.transpose();
                *p += y * xe.transpose() + xe * y.transpose() + x * f * x.transpose();
            });
        add_block(&mut self.info, self.c.block(a), 1.0);
        add_block(&mut self.info, self.c.block(r), -1.0);
        self.members.retain(|&k| k != r);
        self.members.push(a);
        self.in_set[a] = true;
        self.in_set[r] = false;
        self.since_refactor += 1;
        if self.ridge > 0.0 || self.since_refactor >= REFACTOR_EVERY {
            self.refactor();
            self.refactorisations += 1;
        }
        r
    }

    fn members(&self) -> &[usize] {
        &self.members
    }

    fn value(&self) -> f64 {
        match self.criterion {
            WorkCriterion::Mean => self.sigma_mm * self.sigma_mm * self.phi,
            WorkCriterion::Max => {
                prediction_from_inverse(self.targets, &self.inv, self.sigma_mm).max_u95_mm()
            }
        }
    }

    fn refactorisations(&self) -> usize {
        self.refactorisations
    }
}

/// Every trial by a fresh factorisation of its M.
struct Naive<'a> {
    c: &'a Candidates,
    targets: &'a WorkTargets,
    criterion: WorkCriterion,
    sigma_mm: f64,
    members: Vec<usize>,
    in_set: Vec<bool>,
}

impl<'a> Naive<'a> {
    fn new(
        c: &'a Candidates,
        targets: &'a WorkTargets,
        start: Vec<usize>,
        options: &WorkOptions,
    ) -> Naive<'a> {
        let mut in_set = vec![false; c.len()];
        start.iter().for_each(|&k| in_set[k] = true);
        Naive {
            c,
            targets,
            criterion: options.criterion,
            sigma_mm: options.sigma_mm,
            members: start,
            in_set,
        }
    }

    /// The criterion of a set; +∞ when singular.
    fn evaluate(&self, set: &[usize]) -> f64 {
        set_value(self.c, self.targets, set, self.sigma_mm, self.criterion)
    }
}

/// The criterion of `set` from a fresh factorisation (∞ where M is singular).
fn set_value(
    c: &Candidates,
    targets: &WorkTargets,
    set: &[usize],
    sigma_mm: f64,
    criterion: WorkCriterion,
) -> f64 {
    predict(c, targets, set, sigma_mm).map_or(f64::INFINITY, |p| p.value(criterion))
}

impl WorkEngine for Naive<'_> {
    fn best_addition(&self) -> Option<usize> {
        naive_best_addition(&self.in_set, &self.members, |set| -self.evaluate(set))
    }

    fn exchange(&mut self, added: usize) -> usize {
        let (c, targets, sigma_mm, criterion) =
            (self.c, self.targets, self.sigma_mm, self.criterion);
        naive_exchange(&mut self.members, &mut self.in_set, added, |set| {
            -set_value(c, targets, set, sigma_mm, criterion)
        })
    }

    fn members(&self) -> &[usize] {
        &self.members
    }

    fn value(&self) -> f64 {
        self.evaluate(&self.members)
    }

    fn refactorisations(&self) -> usize {
        0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::uncertainty::chi_squared_3_quantile;
    use crate::design::detmax::{Criterion, Options, detmax};
    use rand::rngs::StdRng;
    use rand::seq::index::sample;
    use rand::{Rng, SeedableRng};

    fn random_problem(
        total: usize,
        m: usize,
        count: usize,
        seed: u64,
    ) -> (Candidates, WorkTargets) {
        let mut rng = StdRng::seed_from_u64(seed);
        let mut draw = |rows: usize| -> Vec<f64> {
            (0..3 * rows * m)
                .map(|_| rng.random_range(-1.0..1.0))
                .collect()
        };
        // Candidates that inform one half of the parameters more than the
        // other: O1 balances them, the work design need not.
        let mut jacobian = draw(total);
        for (i, v) in jacobian.iter_mut().enumerate() {
            let (k, j) = (i / (3 * m), i % m);
            if (k % 2 == 0) == (j < m / 2) {
                *v *= 0.2;
            }
        }
        // Targets that depend mostly on the first half of the parameters: what
        // a work-driven design must concentrate on.
        let mut target_jacobian = draw(count);
        for (i, v) in target_jacobian.iter_mut().enumerate() {
            if i % m >= m / 2 {
                *v *= 0.05;
            }
        }
        let (c, scale) = Candidates::from_jacobian(&jacobian, total, m);
        (
            c,
            WorkTargets::from_jacobian(&target_jacobian, count, &scale),
        )
    }

    fn options(n: usize, criterion: WorkCriterion, method: Method, seed: u64) -> WorkOptions {
        WorkOptions {
            n,
            criterion,
            method,
            max_iterations: 1000,
            shortlist: 0,
            seed,
            sigma_mm: 0.02,
        }
    }

    /// Two parameters, three candidates of one row each (unscaled
    /// J_1 = [2 0], J_2 = [0 1], J_3 = [0 2]), one target J_t = I (first two
    /// rows). {1, 3}: M = diag(4, 4), C_t = σ²·diag(1/4, 1/4, 0); {1, 2}:
    /// M = diag(4, 1), C_t = σ²·diag(1/4, 1, 0); {2, 3} is singular. Both
    /// criteria choose {1, 3}: trace 0.5·σ², u95 = sqrt(χ²₃(0.95))·σ/2.
    #[test]
    fn a_hand_computed_case() {
        let row = |a: f64, b: f64| [a, b, 0.0, 0.0, 0.0, 0.0];
        let jacobian: Vec<f64> = [row(2.0, 0.0), row(0.0, 1.0), row(0.0, 2.0)].concat();
        let (c, scale) = Candidates::from_jacobian(&jacobian, 3, 2);
        let target = [1.0, 0.0, 0.0, 1.0, 0.0, 0.0];
        let targets = WorkTargets::from_jacobian(&target, 1, &scale);
        let sigma = 0.02;
        let best = predict(&c, &targets, &[0, 2], sigma).unwrap();
        let expected =
            Matrix3::from_diagonal(&nalgebra::Vector3::new(0.25, 0.25, 0.0)) * sigma * sigma;
        assert!((best.covariances_mm2[0] - expected).abs().max() < 1e-15);
        assert!((best.mean_variance_mm2() - 0.5 * sigma * sigma).abs() < 1e-15);
        let u95 = chi_squared_3_quantile(0.95).sqrt() * sigma / 2.0;
        assert!((best.max_u95_mm() - u95).abs() < 1e-12);
        let other = predict(&c, &targets, &[0, 1], sigma).unwrap();
        assert!((other.mean_variance_mm2() - 1.25 * sigma * sigma).abs() < 1e-15);
        assert!((other.max_u95_mm() - 2.0 * u95).abs() < 1e-12);
        assert!(predict(&c, &targets, &[1, 2], sigma).is_none());
        for method in [Method::Fast, Method::Naive] {
            for criterion in [WorkCriterion::Mean, WorkCriterion::Max] {
                for seed in 0..4 {
                    let result =
                        work_detmax(&c, &targets, &options(2, criterion, method, seed)).unwrap();
                    let mut chosen = result.chosen.clone();
                    chosen.sort_unstable();
                    assert_eq!(chosen, [0, 2], "{method:?} {criterion:?} seed {seed}");
                }
            }
        }
    }

    #[test]
    fn fast_and_naive_take_the_same_exchanges_from_the_same_start() {
        for criterion in [WorkCriterion::Mean, WorkCriterion::Max] {
            for seed in 0..3 {
                let (c, targets) = random_problem(60, 6, 5, 40 + seed);
                let fast =
                    work_detmax(&c, &targets, &options(4, criterion, Method::Fast, seed)).unwrap();
                let naive =
                    work_detmax(&c, &targets, &options(4, criterion, Method::Naive, seed)).unwrap();
                assert!(fast.converged && naive.converged);
                let moves = |s: &WorkSelection| -> Vec<(usize, usize)> {
                    s.trace.iter().map(|e| (e.added, e.removed)).collect()
                };
                assert_eq!(moves(&fast), moves(&naive), "{criterion:?} seed {seed}");
                assert_eq!(fast.chosen, naive.chosen);
                for (f, n) in fast.trace.iter().zip(&naive.trace) {
                    assert!((f.value - n.value).abs() < 1e-9 * n.value, "{f:?} {n:?}");
                }
                assert!(fast.value <= fast.value_start);
            }
        }
    }

    /// Past several refactorisations, every exchange's tracked I value (rank-6
    /// updates of M⁻¹, Q_k and P_k) equals a fresh factorisation of its set.
    #[test]
    fn the_tracked_mean_variance_equals_a_fresh_factorisation() {
        let (c, targets) = random_problem(800, 12, 8, 3);
        let o = options(40, WorkCriterion::Mean, Method::Fast, 2);
        let result = work_detmax(&c, &targets, &o).unwrap();
        assert!(
            result.trace.len() > REFACTOR_EVERY,
            "{}",
            result.trace.len()
        );
        assert!(result.refactorisations >= 1);
        let mut set = result.chosen.clone();
        for exchange in result.trace.iter().rev() {
            let fresh = predict(&c, &targets, &set, o.sigma_mm)
                .unwrap()
                .mean_variance_mm2();
            assert!(
                (exchange.value - fresh).abs() < 1e-9 * fresh,
                "exchange {}: {} vs {fresh}",
                exchange.iteration,
                exchange.value
            );
            if exchange.added != exchange.removed {
                set.retain(|&k| k != exchange.added);
                set.push(exchange.removed);
            }
        }
    }

    /// The work-driven set predicts less uncertainty at the targets than the
    /// O1 set of the same size and than the best of 500 random sets, while O1
    /// remains the O1 winner.
    #[test]
    fn the_work_design_beats_o1_and_random_sets_at_the_targets() {
        let (c, targets) = random_problem(300, 10, 6, 7);
        let n = 5;
        let work = work_detmax(
            &c,
            &targets,
            &options(n, WorkCriterion::Mean, Method::Fast, 1),
        )
        .unwrap();
        let o1 = detmax(
            &c,
            &Options {
                n,
                criterion: Criterion::O1,
                method: Method::Fast,
                max_iterations: 1000,
                shortlist: 0,
                seed: 1,
            },
        )
        .unwrap();
        let at = |set: &[usize]| predict(&c, &targets, set, 0.02).unwrap();
        let o1_value = at(&o1.chosen).mean_variance_mm2();
        assert!(
            work.value < 0.8 * o1_value,
            "{} vs O1 {o1_value}",
            work.value
        );
        assert!(work.o1 < o1.o1);
        let mut rng = StdRng::seed_from_u64(5);
        let best_random = (0..500)
            .filter_map(|_| predict(&c, &targets, &sample(&mut rng, 300, n).into_vec(), 0.02))
            .map(|p| p.mean_variance_mm2())
            .fold(f64::INFINITY, f64::min);
        assert!(work.value < best_random, "{} vs {best_random}", work.value);
        let minimax = work_detmax(
            &c,
            &targets,
            &options(n, WorkCriterion::Max, Method::Fast, 1),
        )
        .unwrap();
        assert!(minimax.prediction.max_u95_mm() <= work.prediction.max_u95_mm() * 1.0001);
    }

    #[test]
    fn the_curve_does_not_rise_with_n() {
        let (c, targets) = random_problem(200, 8, 5, 9);
        let points = curve(
            &c,
            &targets,
            &options(3, WorkCriterion::Mean, Method::Fast, 0),
            3,
            15,
        )
        .unwrap();
        assert_eq!(points.len(), 13);
        for pair in points.windows(2) {
            let at = |p: &CurvePoint| predict(&c, &targets, &p.chosen, 0.02).unwrap();
            assert!(
                at(&pair[1]).mean_variance_mm2()
                    <= at(&pair[0]).mean_variance_mm2() * (1.0 + 1e-12)
            );
            assert_eq!(pair[1].chosen.len(), pair[1].n);
        }
    }
}
