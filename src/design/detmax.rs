//! DETMAX selection of conf-wrench combinations by observability (paper §III.C,
//! §IV.B; Mitchell 1974).
//!
//! The observability index O1 = (σ1·…·σm)^(1/m)/√n of the scaled identification
//! Jacobian grows with det(JᵀJ), so the exchange works on log det(M), M = JᵀJ:
//! adding a row block B (3×m) multiplies det(M) by det(I + B·M⁻¹·Bᵀ), removing it by
//! det(I − B·M⁻¹·Bᵀ) — a 3×3 determinant per candidate instead of an SVD.
//!
//! Columns are scaled to unit norm over *all* candidates before selection; the
//! scaling changes O1's value but not which subset wins, and it is reported with it.

use nalgebra::{DMatrix, Matrix3};
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand::seq::index::sample;

/// One exchange of the DETMAX loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Exchange {
    pub iteration: usize,
    /// Index (into the candidates) added, then removed.
    pub added: usize,
    pub removed: usize,
    /// O1 of the selection after the exchange.
    pub o1: f64,
}

/// Result of a selection.
#[derive(Debug, Clone, PartialEq)]
pub struct Selection {
    /// Indexes into the candidates, ascending.
    pub chosen: Vec<usize>,
    pub o1: f64,
    /// O1 of the random start.
    pub o1_start: f64,
    pub trace: Vec<Exchange>,
    pub converged: bool,
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

/// Candidate blocks: `blocks[k]` is the 3×m Jacobian of candidate k (already scaled).
pub struct Candidates {
    pub blocks: Vec<nalgebra::OMatrix<f64, nalgebra::U3, nalgebra::Dyn>>,
    pub m: usize,
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
        let blocks = (0..n)
            .map(|k| {
                nalgebra::OMatrix::<f64, nalgebra::U3, nalgebra::Dyn>::from_fn(m, |r, j| {
                    jacobian[(3 * k + r) * m + j] * scale[j]
                })
            })
            .collect();
        (Candidates { blocks, m }, scale)
    }

    fn information(&self, set: &[usize]) -> DMatrix<f64> {
        let mut info = DMatrix::zeros(self.m, self.m);
        for &k in set {
            let b = &self.blocks[k];
            info += b.transpose() * b;
        }
        info
    }
}

/// O1 of a set from its information matrix M = JᵀJ: (Π σ)^(1/m)/√n with σ² the
/// eigenvalues of M, i.e. det(M)^(1/2m)/√n.
pub fn observability_index(info: &DMatrix<f64>, n: usize) -> f64 {
    match info.clone().cholesky() {
        Some(chol) => {
            let log_det: f64 = chol.l().diagonal().iter().map(|d| 2.0 * d.ln()).sum();
            (log_det / (2.0 * info.nrows() as f64)).exp() / (n as f64).sqrt()
        }
        None => 0.0,
    }
}

fn inverse(info: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    info.clone().cholesky().map(|c| c.inverse())
}

/// ln det(I ± B·M⁻¹·Bᵀ) for every candidate, or −∞ where not positive.
fn log_det_change(c: &Candidates, inv: &DMatrix<f64>, k: usize, sign: f64) -> f64 {
    let b = &c.blocks[k];
    let s: Matrix3<f64> = Matrix3::identity() + (b * inv * b.transpose()) * sign;
    let det = s.determinant();
    if det > 0.0 {
        det.ln()
    } else {
        f64::NEG_INFINITY
    }
}

/// DETMAX: from a random start of `n`, repeatedly add the candidate that raises
/// det(JᵀJ) most, then remove the member whose removal lowers it least, until the
/// removed one is the one just added (paper §IV.B steps (a)–(d)).
pub fn detmax(
    c: &Candidates,
    n: usize,
    seed: u64,
    max_iterations: usize,
) -> Result<Selection, DetmaxError> {
    let total = c.blocks.len();
    if n > total {
        return Err(DetmaxError::NotEnoughCandidates {
            wanted: n,
            available: total,
        });
    }
    if 3 * n < c.m {
        return Err(DetmaxError::TooFew {
            n,
            rows: 3 * n,
            m: c.m,
        });
    }
    let all: Vec<usize> = (0..total).collect();
    if inverse(&c.information(&all)).is_none() {
        return Err(DetmaxError::Singular);
    }
    let mut rng = StdRng::seed_from_u64(seed);
    // A random start can be rank deficient; redraw a few times, then fall back to
    // a small ridge so the exchange can still climb out of it.
    let mut chosen: Vec<usize> = sample(&mut rng, total, n).into_vec();
    for _ in 0..20 {
        if inverse(&c.information(&chosen)).is_some() {
            break;
        }
        chosen = sample(&mut rng, total, n).into_vec();
    }
    let ridge = |info: DMatrix<f64>| -> DMatrix<f64> {
        if info.clone().cholesky().is_some() {
            info
        } else {
            let m = info.nrows();
            info + DMatrix::identity(m, m) * 1e-9
        }
    };
    let o1_start = observability_index(&c.information(&chosen), n);
    let mut trace = Vec::new();
    let mut converged = false;
    for iteration in 1..=max_iterations {
        let mut in_set = vec![false; total];
        chosen.iter().for_each(|&k| in_set[k] = true);
        let info = ridge(c.information(&chosen));
        let inv = inverse(&info).ok_or(DetmaxError::Singular)?;
        let added = (0..total)
            .filter(|&k| !in_set[k])
            .max_by(|&a, &b| {
                log_det_change(c, &inv, a, 1.0).total_cmp(&log_det_change(c, &inv, b, 1.0))
            })
            .ok_or(DetmaxError::NotEnoughCandidates {
                wanted: n + 1,
                available: total,
            })?;
        chosen.push(added);
        let info = ridge(c.information(&chosen));
        let inv = inverse(&info).ok_or(DetmaxError::Singular)?;
        let (position, &removed) = chosen
            .iter()
            .enumerate()
            .max_by(|(_, a), (_, b)| {
                log_det_change(c, &inv, **a, -1.0).total_cmp(&log_det_change(c, &inv, **b, -1.0))
            })
            .expect("the set is not empty");
        chosen.swap_remove(position);
        let o1 = observability_index(&c.information(&chosen), n);
        trace.push(Exchange {
            iteration,
            added,
            removed,
            o1,
        });
        if added == removed {
            converged = true;
            break;
        }
    }
    chosen.sort_unstable();
    let o1 = observability_index(&c.information(&chosen), n);
    Ok(Selection {
        chosen,
        o1,
        o1_start,
        trace,
        converged,
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

    #[test]
    fn observability_index_equals_the_svd_definition() {
        let c = random_candidates(30, 5, 1);
        let set: Vec<usize> = (0..30).collect();
        let mut j = DMatrix::zeros(90, 5);
        for (k, b) in c.blocks.iter().enumerate() {
            j.rows_mut(3 * k, 3).copy_from(b);
        }
        let sv = j.singular_values();
        let expected = sv.iter().product::<f64>().powf(1.0 / 5.0) / 30f64.sqrt();
        let got = observability_index(&c.information(&set), 30);
        assert!((got - expected).abs() < 1e-12 * expected);
    }

    #[test]
    fn detmax_improves_on_the_start_and_matches_exhaustive_search_on_a_small_case() {
        let c = random_candidates(12, 4, 2);
        let result = detmax(&c, 3, 7, 100).unwrap();
        assert!(result.converged);
        assert!(result.o1 >= result.o1_start);
        // Exhaustive: C(12, 3) = 220 subsets.
        let mut best = 0.0f64;
        for a in 0..12 {
            for b in a + 1..12 {
                for d in b + 1..12 {
                    best = best.max(observability_index(&c.information(&[a, b, d]), 3));
                }
            }
        }
        // DETMAX is a local exchange: within a few percent of the optimum here.
        assert!(result.o1 >= 0.9 * best, "{} vs best {best}", result.o1);
    }

    #[test]
    fn detmax_beats_the_best_of_1000_random_subsets() {
        let c = random_candidates(200, 8, 4);
        let result = detmax(&c, 10, 1, 1000).unwrap();
        let mut rng = StdRng::seed_from_u64(9);
        let best_random = (0..1000)
            .map(|_| observability_index(&c.information(&sample(&mut rng, 200, 10).into_vec()), 10))
            .fold(0.0, f64::max);
        assert!(result.o1 > best_random, "{} vs {best_random}", result.o1);
    }

    #[test]
    fn asking_for_too_few_rows_is_an_error() {
        let c = random_candidates(10, 9, 3);
        assert!(matches!(
            detmax(&c, 2, 0, 10),
            Err(DetmaxError::TooFew { .. })
        ));
        assert!(matches!(
            detmax(&c, 11, 0, 10),
            Err(DetmaxError::NotEnoughCandidates { .. })
        ));
    }
}
