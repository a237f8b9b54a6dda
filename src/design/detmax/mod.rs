//! DETMAX selection of conf-wrench combinations by observability (paper §III.C,
//! §IV.B; Mitchell 1974): from a random start of n, add the candidate that raises
//! the criterion most, remove the member whose removal lowers it least, until the
//! one removed is the one just added (paper steps (a)–(d)).
//!
//! Two engines run the same exchange and reach the same selection from the same
//! start (up to ties):
//!
//! * [`Method::Fast`] works on the information matrix M = JᵀJ and its inverse.
//!   Adding a candidate's 3×m block B multiplies det(M) by det(I + B·M⁻¹·Bᵀ),
//!   removing it by det(I − B·M⁻¹·Bᵀ) (matrix determinant lemma), and M⁻¹ follows
//!   each exchange by two rank-3 Woodbury updates. The 3×3 matrices B_c·M⁻¹·B_cᵀ of
//!   all candidates are cached and updated with the same rank-3 terms, so an
//!   exchange costs O(N·m) for N candidates, not O(N·m²) or N SVDs. M is
//!   refactorised (Cholesky) every [`REFACTOR_EVERY`] exchanges so that rounding
//!   cannot accumulate. For O2–O5 the lemma does not give the criterion: the fast
//!   engine ranks the outsiders by O1 gain, evaluates the criterion exactly
//!   (symmetric eigenvalues of the updated M) on the best `shortlist` of them and
//!   on every member for the removal.
//! * [`Method::Naive`] evaluates every trial by a fresh SVD of the trial Jacobian,
//!   as the paper describes; it is there to verify the fast engine and to measure
//!   what the fast one saves.
//!
//! Columns are scaled to unit norm over *all* candidates before selection; the
//! scaling changes the indices' values but not which subset wins (for O1), and it
//! is reported with them (spec §5).

mod fast;
mod naive;

use nalgebra::DMatrix;
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand::seq::index::sample;
use rayon::prelude::*;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

pub use crate::design::observability::Criterion;

/// Exchanges between two refactorisations of M in the fast engine: often enough
/// that Woodbury rounding stays far below 1e-9 in O1, rare enough to cost little.
pub const REFACTOR_EVERY: usize = 25;

/// How trials are evaluated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Determinant-lemma scores and Woodbury updates of M⁻¹.
    #[default]
    Fast,
    /// A fresh SVD of the trial Jacobian per trial, as in the paper.
    Naive,
}

/// What to select and how.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Options {
    /// Combinations to select.
    pub n: usize,
    pub criterion: Criterion,
    pub method: Method,
    /// Upper bound on exchanges.
    pub max_iterations: usize,
    /// Fast engine, O2–O5: outsiders evaluated exactly per addition, best by O1
    /// gain; 0 evaluates all of them.
    pub shortlist: usize,
    /// Seed of the random start.
    pub seed: u64,
}

/// One exchange of the DETMAX loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Exchange {
    pub iteration: usize,
    /// Index (into the candidates) added, then removed.
    pub added: usize,
    pub removed: usize,
    /// O1 of the selection after the exchange.
    pub o1: f64,
    /// The criterion's value after the exchange (equal to `o1` for O1).
    pub value: f64,
}

/// Result of a selection.
#[derive(Debug, Clone, PartialEq)]
pub struct Selection {
    /// Indexes into the candidates in the order they entered: the random start
    /// ascending, then the rows added by exchanges that stayed.
    pub chosen: Vec<usize>,
    /// O1 and the criterion of the final set, from a fresh factorisation.
    pub o1: f64,
    pub value: f64,
    /// O1 and the criterion of the random start.
    pub o1_start: f64,
    pub value_start: f64,
    pub trace: Vec<Exchange>,
    pub converged: bool,
    /// Cholesky refactorisations of M the fast engine made (0 for naive).
    pub refactorisations: usize,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DetmaxError {
    #[error("asked for {wanted} combinations out of {available} candidates")]
    NotEnoughCandidates { wanted: usize, available: usize },
    #[error(
        "{n} combinations give {rows} equations for {m} parameters; the paper's minimum is n ≥ m/3"
    )]
    TooFew { n: usize, rows: usize, m: usize },
    #[error(
        "the candidates cannot identify the parameters (JᵀJ is singular even with all of them)"
    )]
    Singular,
}

/// Candidate blocks, scaled: rows 3k..3k+3 of a row-major `3N × m` matrix are the
/// Jacobian of candidate k. One flat buffer, so a pass over 10⁵ candidates streams.
#[derive(Debug, Clone, PartialEq)]
pub struct Candidates {
    rows: Vec<f64>,
    count: usize,
    m: usize,
}

impl Candidates {
    /// From a row-major `3n × m` Jacobian; scales columns to unit norm over all rows.
    /// Returns the candidates and the column scale factors used.
    pub fn from_jacobian(jacobian: &[f64], n: usize, m: usize) -> (Candidates, Vec<f64>) {
        let scale: Vec<f64> = (0..m)
            .map(|j| {
                let norm = (0..3 * n)
                    .map(|r| jacobian[r * m + j].powi(2))
                    .sum::<f64>()
                    .sqrt();
                if norm > 0.0 { 1.0 / norm } else { 1.0 }
            })
            .collect();
        let rows = jacobian[..3 * n * m]
            .iter()
            .enumerate()
            .map(|(i, v)| v * scale[i % m])
            .collect();
        (Candidates { rows, count: n, m }, scale)
    }

    /// Number of candidates.
    pub fn len(&self) -> usize {
        self.count
    }

    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Number of parameters (columns).
    pub fn parameters(&self) -> usize {
        self.m
    }

    /// The 3×m block of candidate k, row-major.
    pub(crate) fn block(&self, k: usize) -> &[f64] {
        &self.rows[3 * k * self.m..3 * (k + 1) * self.m]
    }

    /// M = JᵀJ of a set.
    pub fn information(&self, set: &[usize]) -> DMatrix<f64> {
        let mut info = DMatrix::zeros(self.m, self.m);
        for &k in set {
            add_block(&mut info, self.block(k), 1.0);
        }
        info
    }

    /// The stacked Jacobian of a set (3·|set| × m).
    pub fn jacobian(&self, set: &[usize]) -> DMatrix<f64> {
        DMatrix::from_fn(3 * set.len(), self.m, |r, j| {
            self.block(set[r / 3])[(r % 3) * self.m + j]
        })
    }
}

/// info += sign·BᵀB for a 3×m row-major block.
pub(crate) fn add_block(info: &mut DMatrix<f64>, block: &[f64], sign: f64) {
    let m = info.nrows();
    for r in 0..3 {
        let row = &block[r * m..(r + 1) * m];
        for j in 0..m {
            for i in 0..m {
                info[(i, j)] += sign * row[i] * row[j];
            }
        }
    }
}

/// O1 of a set from a fresh Cholesky factorisation of its M; 0 when singular.
pub fn observability_index(c: &Candidates, set: &[usize]) -> f64 {
    let info = c.information(set);
    match info.cholesky() {
        Some(chol) => {
            let log_det: f64 = chol.l().diagonal().iter().map(|d| 2.0 * d.ln()).sum();
            crate::design::observability::o1_from_log_det(log_det, c.m, set.len())
        }
        None => 0.0,
    }
}

/// An exchange engine: the state of one selection and its trial evaluations.
trait Engine {
    /// The outsider whose addition raises the criterion most (lowest index on ties).
    fn best_addition(&self) -> Option<usize>;
    /// Adds `added`, removes the member whose removal keeps the criterion highest
    /// (`added` itself on a tie, so the loop stops), and returns the one removed.
    fn exchange(&mut self, added: usize) -> usize;
    fn members(&self) -> &[usize];
    /// O1 and the criterion of the current set as the engine tracks them.
    fn o1(&self) -> f64;
    fn value(&self) -> f64;
    fn refactorisations(&self) -> usize;
}

/// The candidate kept among scored trials: highest score, lowest index on ties.
pub(crate) fn best_of(scored: impl Iterator<Item = (usize, f64)>) -> Option<usize> {
    scored
        .max_by(|(ka, a), (kb, b)| a.total_cmp(b).then(kb.cmp(ka)))
        .map(|(k, _)| k)
}

/// The Cholesky factor of `exact` (an information matrix M), with a ridge of
/// 1e-9 of its mean diagonal, raised ×1000 until it factorises, where M is
/// singular (a degenerate start), so an exchange can climb out. Returns the
/// factor, the ridge (0 for a regular M) and the matrix factorised.
pub(crate) fn ridged_cholesky(
    exact: &DMatrix<f64>,
) -> (nalgebra::Cholesky<f64, nalgebra::Dyn>, f64, DMatrix<f64>) {
    let m = exact.nrows();
    let mut ridge = 0.0;
    let mut info = exact.clone();
    loop {
        if let Some(chol) = info.clone().cholesky() {
            return (chol, ridge, info);
        }
        ridge = if ridge == 0.0 {
            1e-9 * (exact.trace() / m as f64).max(1e-300)
        } else {
            ridge * 1e3
        };
        info = exact + DMatrix::identity(m, m) * ridge;
    }
}

/// The naive engines' addition: every outsider (not in `in_set`) tried with
/// `members`, the one whose set `score`s highest.
pub(crate) fn naive_best_addition(
    in_set: &[bool],
    members: &[usize],
    score: impl Fn(&[usize]) -> f64 + Sync,
) -> Option<usize> {
    let scores: Vec<(usize, f64)> = (0..in_set.len())
        .into_par_iter()
        .filter(|&k| !in_set[k])
        .map(|k| {
            let trial = [members, &[k]].concat();
            (k, score(&trial))
        })
        .collect();
    best_of(scores.into_iter())
}

/// The naive engines' exchange: adds `added`, removes the member whose
/// removal leaves the highest `score` ([`removal_choice`]); returns it.
pub(crate) fn naive_exchange(
    members: &mut Vec<usize>,
    in_set: &mut [bool],
    added: usize,
    score: impl Fn(&[usize]) -> f64 + Sync,
) -> usize {
    members.push(added);
    let scores: Vec<(usize, f64)> = (0..members.len())
        .into_par_iter()
        .map(|position| {
            let mut trial = members.clone();
            let k = trial.remove(position);
            (k, score(&trial))
        })
        .collect();
    let removed = removal_choice(&scores, added);
    members.retain(|&k| k != removed);
    in_set[added] = true;
    in_set[removed] = false;
    removed
}

/// The member to remove: the best removal score, but `added` when it is within
/// rounding of the best, so that a converged exchange is recognised.
pub(crate) fn removal_choice(scores: &[(usize, f64)], added: usize) -> usize {
    let best = best_of(scores.iter().copied()).expect("the set is not empty");
    let best_score = scores.iter().find(|(k, _)| *k == best).map_or(0.0, |s| s.1);
    match scores.iter().find(|(k, _)| *k == added) {
        Some(&(_, score)) if score >= best_score - 1e-12 * best_score.abs() => added,
        _ => best,
    }
}

/// A random start of `n` (ascending); redrawn a few times when its M is singular.
pub(crate) fn random_start(c: &Candidates, n: usize, seed: u64) -> Vec<usize> {
    let mut rng = StdRng::seed_from_u64(seed);
    let mut start: Vec<usize> = sample(&mut rng, c.count, n).into_vec();
    for _ in 0..20 {
        if c.information(&start).cholesky().is_some() {
            break;
        }
        start = sample(&mut rng, c.count, n).into_vec();
    }
    start.sort_unstable();
    start
}

/// DETMAX from one seeded random start (paper §IV.B steps (a)–(d)). Cost per
/// exchange, N candidates, m parameters: fast O(N·m) (+ O(N·m²) per refactorisation,
/// + shortlist eigendecompositions for O2–O5); naive N SVDs of a 3(n+1)×m matrix.
pub fn detmax(c: &Candidates, options: &Options) -> Result<Selection, DetmaxError> {
    let (n, m, total) = (options.n, c.m, c.count);
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
    let start = random_start(c, n, options.seed);
    let mut engine: Box<dyn Engine + '_> = match options.method {
        Method::Fast => Box::new(fast::Fast::new(c, start, options)),
        Method::Naive => Box::new(naive::Naive::new(c, start, options.criterion)),
    };
    let o1_start = engine.o1();
    let value_start = engine.value();
    let mut trace = Vec::new();
    let mut converged = false;
    for iteration in 1..=options.max_iterations {
        let Some(added) = engine.best_addition() else {
            // All candidates are chosen: nothing to exchange.
            converged = true;
            break;
        };
        let removed = engine.exchange(added);
        trace.push(Exchange {
            iteration,
            added,
            removed,
            o1: engine.o1(),
            value: engine.value(),
        });
        if added == removed {
            converged = true;
            break;
        }
    }
    let chosen = engine.members().to_vec();
    let o1 = observability_index(c, &chosen);
    let value = match options.criterion {
        Criterion::O1 => o1,
        other => other.evaluate_information(&c.information(&chosen), n),
    };
    Ok(Selection {
        chosen,
        o1,
        value,
        o1_start,
        value_start,
        trace,
        converged,
        refactorisations: engine.refactorisations(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::Rng;

    fn random_candidates(total: usize, m: usize, seed: u64) -> Candidates {
        let mut rng = StdRng::seed_from_u64(seed);
        let jacobian: Vec<f64> = (0..3 * total * m)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        Candidates::from_jacobian(&jacobian, total, m).0
    }

    fn options(n: usize, criterion: Criterion, method: Method, seed: u64) -> Options {
        Options {
            n,
            criterion,
            method,
            max_iterations: 1000,
            shortlist: 0,
            seed,
        }
    }

    fn svd_value(c: &Candidates, set: &[usize], criterion: Criterion) -> f64 {
        let sv = c.jacobian(set).singular_values();
        criterion.evaluate(sv.as_slice(), set.len())
    }

    #[test]
    fn observability_index_equals_the_svd_definition() {
        let c = random_candidates(30, 5, 1);
        let set: Vec<usize> = (0..30).collect();
        let sv = c.jacobian(&set).singular_values();
        let expected = sv.iter().product::<f64>().powf(1.0 / 5.0) / 30f64.sqrt();
        let got = observability_index(&c, &set);
        assert!((got - expected).abs() < 1e-12 * expected);
    }

    #[test]
    fn o1_tracked_by_the_fast_updates_equals_a_full_svd_of_the_chosen_set() {
        // Enough exchanges to pass several refactorisations and Woodbury stretches.
        let c = random_candidates(600, 12, 11);
        let result = detmax(&c, &options(40, Criterion::O1, Method::Fast, 3)).unwrap();
        assert!(
            result.trace.len() > REFACTOR_EVERY,
            "{}",
            result.trace.len()
        );
        // Walk back from the final set: every exchange's tracked O1, including those
        // deep in a stretch of Woodbury updates, against the SVD of its set.
        let mut set = result.chosen.clone();
        for exchange in result.trace.iter().rev() {
            let svd = svd_value(&c, &set, Criterion::O1);
            assert!(
                (exchange.o1 - svd).abs() < 1e-9 * svd,
                "exchange {}: {} vs {svd}",
                exchange.iteration,
                exchange.o1
            );
            if exchange.added != exchange.removed {
                set.retain(|&k| k != exchange.added);
                set.push(exchange.removed);
            }
        }
        let svd = svd_value(&c, &result.chosen, Criterion::O1);
        assert!((result.o1 - svd).abs() < 1e-12 * svd);
        assert!(result.refactorisations >= 1);
    }

    #[test]
    fn fast_and_naive_take_the_same_exchanges_from_the_same_start() {
        for seed in 0..4 {
            let c = random_candidates(60, 6, 20 + seed);
            let fast = detmax(&c, &options(5, Criterion::O1, Method::Fast, seed)).unwrap();
            let naive = detmax(&c, &options(5, Criterion::O1, Method::Naive, seed)).unwrap();
            assert!(fast.converged && naive.converged);
            assert_eq!(fast.chosen, naive.chosen);
            assert!((fast.o1 - naive.o1).abs() < 1e-12 * naive.o1);
            let moves = |s: &Selection| -> Vec<(usize, usize)> {
                s.trace.iter().map(|e| (e.added, e.removed)).collect()
            };
            assert_eq!(moves(&fast), moves(&naive));
            for (f, n) in fast.trace.iter().zip(&naive.trace) {
                assert!((f.o1 - n.o1).abs() < 1e-9 * n.o1);
            }
        }
    }

    #[test]
    fn fast_and_naive_agree_for_every_other_criterion() {
        for criterion in [Criterion::O2, Criterion::O3, Criterion::O4, Criterion::O5] {
            let c = random_candidates(50, 6, 31);
            let fast = detmax(&c, &options(5, criterion, Method::Fast, 2)).unwrap();
            let naive = detmax(&c, &options(5, criterion, Method::Naive, 2)).unwrap();
            assert_eq!(fast.chosen, naive.chosen, "{criterion:?}");
            assert!((fast.value - naive.value).abs() < 1e-9 * naive.value);
            assert!(fast.value >= fast.value_start, "{criterion:?}");
        }
    }

    #[test]
    fn each_criterion_tracked_matches_a_direct_svd() {
        let c = random_candidates(120, 8, 5);
        for criterion in [Criterion::O2, Criterion::O3, Criterion::O4, Criterion::O5] {
            let mut o = options(6, criterion, Method::Fast, 1);
            o.shortlist = 10;
            let result = detmax(&c, &o).unwrap();
            let svd = svd_value(&c, &result.chosen, criterion);
            let tracked = result.trace.last().unwrap().value;
            assert!((tracked - svd).abs() < 1e-9 * svd, "{criterion:?}");
            assert!((result.value - svd).abs() < 1e-9 * svd, "{criterion:?}");
            assert!((result.o1 - svd_value(&c, &result.chosen, Criterion::O1)).abs() < 1e-9);
        }
    }

    #[test]
    fn detmax_improves_on_the_start_and_matches_exhaustive_search_on_a_small_case() {
        let c = random_candidates(12, 4, 2);
        let result = detmax(&c, &options(3, Criterion::O1, Method::Fast, 7)).unwrap();
        assert!(result.converged);
        assert!(result.o1 >= result.o1_start);
        // Exhaustive: C(12, 3) = 220 subsets.
        let mut best = 0.0f64;
        for a in 0..12 {
            for b in a + 1..12 {
                for d in b + 1..12 {
                    best = best.max(observability_index(&c, &[a, b, d]));
                }
            }
        }
        // DETMAX is a local exchange: within a few percent of the optimum here.
        assert!(result.o1 >= 0.9 * best, "{} vs best {best}", result.o1);
    }

    #[test]
    fn detmax_beats_the_best_of_1000_random_subsets() {
        let c = random_candidates(200, 8, 4);
        let result = detmax(&c, &options(10, Criterion::O1, Method::Fast, 1)).unwrap();
        let mut rng = StdRng::seed_from_u64(9);
        let best_random = (0..1000)
            .map(|_| observability_index(&c, &sample(&mut rng, 200, 10).into_vec()))
            .fold(0.0, f64::max);
        assert!(result.o1 > best_random, "{} vs {best_random}", result.o1);
    }

    #[test]
    fn the_result_is_a_local_optimum_of_the_exchange() {
        let c = random_candidates(80, 6, 8);
        let result = detmax(&c, &options(6, Criterion::O1, Method::Fast, 4)).unwrap();
        assert!(result.converged);
        // Adding the best outsider, then removing any member, gives no higher O1.
        let with = |k: usize| -> Vec<usize> { [result.chosen.clone(), vec![k]].concat() };
        let best_outsider = (0..80)
            .filter(|k| !result.chosen.contains(k))
            .max_by(|&a, &b| {
                observability_index(&c, &with(a)).total_cmp(&observability_index(&c, &with(b)))
            })
            .unwrap();
        let grown = with(best_outsider);
        for position in 0..grown.len() {
            let mut shrunk = grown.clone();
            shrunk.remove(position);
            assert!(observability_index(&c, &shrunk) <= result.o1 * (1.0 + 1e-12));
        }
    }

    #[test]
    fn asking_for_too_few_rows_is_an_error() {
        let c = random_candidates(10, 9, 3);
        assert!(matches!(
            detmax(&c, &options(2, Criterion::O1, Method::Fast, 0)),
            Err(DetmaxError::TooFew { .. })
        ));
        assert!(matches!(
            detmax(&c, &options(11, Criterion::O1, Method::Fast, 0)),
            Err(DetmaxError::NotEnoughCandidates { .. })
        ));
    }
}
