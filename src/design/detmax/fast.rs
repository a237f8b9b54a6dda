//! The exchange by rank-3 updates: M⁻¹ by Woodbury, ln det M by the determinant
//! lemma, and the cached 3×3 matrices Q_k = B_k·M⁻¹·B_kᵀ of every candidate by the
//! same rank-3 terms, so that scoring all candidates is a 3×3 determinant each.
//!
//! An exchange (add a, remove r) touches every candidate once: with U = M⁻¹·[B_aᵀ B_rᵀ]
//! (after the addition for r), X = B_k·U gives both corrections of Q_k. The removal
//! only needs the n+1 members' Q after the addition, so the full pass waits until
//! r is known, and is skipped when r = a (convergence).

use nalgebra::{DMatrix, Dyn, Matrix3, OMatrix, U3};
use rayon::prelude::*;

use super::{
    Candidates, Criterion, Engine, Options, REFACTOR_EVERY, add_block, best_of, removal_choice,
    ridged_cholesky,
};
use crate::design::observability::o1_from_log_det;

/// m×3: M⁻¹·Bᵀ for a candidate block B.
type Tall = OMatrix<f64, Dyn, U3>;

/// Candidates per rayon task: each costs ~20·m flops, so a task is ~10⁵ flops.
const MIN_CANDIDATES_PER_TASK: usize = 256;

/// Runs `work` on each task of `MIN_CANDIDATES_PER_TASK` candidates' `q`
/// (with the task's first candidate index) in parallel, inside one `pulp`
/// dispatch per task: the loops are compiled for the machine's widest vector
/// unit (AVX2, AVX-512) and chosen at run time, where the portable build
/// would use SSE2 only. They are vectorised across independent sums, and
/// Rust never fuses a multiply and an add by itself, so every value is the
/// same bits as the baseline code's (issue #31: 100 000 candidates).
fn for_each_task(q: &mut [Matrix3<f64>], work: impl Fn(usize, &mut [Matrix3<f64>]) + Sync) {
    let arch = pulp::Arch::new();
    q.par_chunks_mut(MIN_CANDIDATES_PER_TASK)
        .enumerate()
        .for_each(|(task, chunk)| {
            arch.dispatch(|| work(task * MIN_CANDIDATES_PER_TASK, chunk));
        });
}

pub(super) struct Fast<'a> {
    c: &'a Candidates,
    criterion: Criterion,
    shortlist: usize,
    /// In order of entry.
    members: Vec<usize>,
    in_set: Vec<bool>,
    /// M = JᵀJ of the members, plus `ridge`·I while that is singular.
    info: DMatrix<f64>,
    /// M⁻¹, by Woodbury updates between refactorisations.
    inv: DMatrix<f64>,
    /// ln det M, by the determinant lemma between refactorisations.
    log_det: f64,
    /// B_k·M⁻¹·B_kᵀ for every candidate k.
    q: Vec<Matrix3<f64>>,
    ridge: f64,
    since_refactor: usize,
    refactorisations: usize,
}

impl<'a> Fast<'a> {
    pub(super) fn new(c: &'a Candidates, start: Vec<usize>, options: &Options) -> Fast<'a> {
        let mut in_set = vec![false; c.len()];
        start.iter().for_each(|&k| in_set[k] = true);
        let m = c.parameters();
        let mut fast = Fast {
            c,
            criterion: options.criterion,
            shortlist: options.shortlist,
            members: start,
            in_set,
            info: DMatrix::zeros(m, m),
            inv: DMatrix::zeros(m, m),
            log_det: 0.0,
            q: vec![Matrix3::zeros(); c.len()],
            ridge: 0.0,
            since_refactor: 0,
            refactorisations: 0,
        };
        fast.refactor();
        fast
    }

    /// M from the members, its Cholesky factorisation, M⁻¹, ln det M and every Q_k
    /// afresh. Cost O(N·m²). A singular M (a degenerate random start) gets a ridge
    /// of 1e-9 of its mean diagonal, raised until it factorises, so the exchange can
    /// climb out; it is dropped at the next refactorisation where M is regular.
    fn refactor(&mut self) {
        let (chol, ridge, info) = ridged_cholesky(&self.c.information(&self.members));
        self.ridge = ridge;
        self.log_det = chol.l().diagonal().iter().map(|d| 2.0 * d.ln()).sum();
        self.inv = chol.inverse();
        self.info = info;
        // Row l of M⁻¹ as a contiguous column, for the vectorised products.
        let (c, inv_rows) = (self.c, self.inv.transpose());
        for_each_task(&mut self.q, |first, chunk| {
            for (i, q) in chunk.iter_mut().enumerate() {
                *q = quadratic(c.block(first + i), &inv_rows);
            }
        });
        self.since_refactor = 0;
    }

    /// M⁻¹·Bᵀ for candidate k.
    fn tall(&self, k: usize) -> Tall {
        let (b, m) = (self.c.block(k), self.c.parameters());
        &self.inv * Tall::from_fn(m, |i, r| b[r * m + i])
    }

    /// The criterion of M + sign·B_kᵀB_k (a set of `n` rows), O2–O5 only.
    fn evaluate_with(&self, info: &DMatrix<f64>, k: usize, sign: f64, n: usize) -> f64 {
        let mut trial = info.clone();
        add_block(&mut trial, self.c.block(k), sign);
        self.criterion.evaluate_information(&trial, n)
    }
}

/// Longest parameter vector [`quadratic`] keeps on the stack (the model has 42
/// parameters at most; longer ones take the heap).
const STACK_PARAMETERS: usize = 64;

/// B·M⁻¹·Bᵀ for a 3×m row-major block, from `inv_rows`, the transpose of
/// M⁻¹ (its column l is row l of M⁻¹).
///
/// T = B·M⁻¹ is accumulated a row of M⁻¹ at a time, so each T[r][l] sums
/// B[r][l']·M⁻¹[l'][l] over l' in order (the dot products of before, the
/// same bits) while the loop over l vectorises; then Q = T·Bᵀ.
fn quadratic(b: &[f64], inv_rows: &DMatrix<f64>) -> Matrix3<f64> {
    let m = inv_rows.nrows();
    let mut stack = [[0.0; STACK_PARAMETERS]; 3];
    let mut heap;
    let mut t: [&mut [f64]; 3] = if m <= STACK_PARAMETERS {
        stack.each_mut().map(|row| &mut row[..m])
    } else {
        heap = [vec![0.0; m], vec![0.0; m], vec![0.0; m]];
        heap.each_mut().map(|row| row.as_mut_slice())
    };
    for (l_prime, inv_row) in inv_rows.as_slice().chunks_exact(m).enumerate() {
        for (r, t_r) in t.iter_mut().enumerate() {
            let b_rl = b[r * m + l_prime];
            for (acc, inv) in t_r.iter_mut().zip(inv_row) {
                *acc += b_rl * inv;
            }
        }
    }
    let mut q = Matrix3::zeros();
    for l in 0..m {
        for r in 0..3 {
            for s in 0..3 {
                q[(r, s)] += t[r][l] * b[s * m + l];
            }
        }
    }
    q
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// B·U for a 3×m row-major block and an m×3 U.
fn cross(b: &[f64], u: &Tall) -> Matrix3<f64> {
    let m = u.nrows();
    Matrix3::from_fn(|r, j| dot(&b[r * m..(r + 1) * m], u.column(j).as_slice()))
}

impl Engine for Fast<'_> {
    fn best_addition(&self) -> Option<usize> {
        // O1 gain of each outsider: det(I + Q_k) (determinant lemma).
        let outsiders = || {
            self.q
                .par_iter()
                .enumerate()
                .with_min_len(MIN_CANDIDATES_PER_TASK)
                .filter(|(k, _)| !self.in_set[*k])
                .map(|(k, q)| (k, (Matrix3::identity() + q).determinant()))
        };
        if self.criterion == Criterion::O1 {
            // The best straight from the threads, without collecting every
            // gain: the order is `best_of`'s (higher gain, then lower index),
            // total, so the reduction's grouping cannot change the winner.
            return outsiders()
                .max_by(|(ka, a), (kb, b)| a.total_cmp(b).then(kb.cmp(ka)))
                .map(|(k, _)| k);
        }
        let gains: Vec<(usize, f64)> = outsiders().collect();
        let mut shortlist = gains;
        if self.shortlist > 0 && shortlist.len() > self.shortlist {
            shortlist.select_nth_unstable_by(self.shortlist - 1, |(ka, a), (kb, b)| {
                b.total_cmp(a).then(ka.cmp(kb))
            });
            shortlist.truncate(self.shortlist);
        }
        let n = self.members.len() + 1;
        let scores: Vec<(usize, f64)> = shortlist
            .par_iter()
            .map(|&(k, _)| (k, self.evaluate_with(&self.info, k, 1.0, n)))
            .collect();
        best_of(scores.into_iter())
    }

    fn exchange(&mut self, added: usize) -> usize {
        let m = self.c.parameters();
        let a = added;
        // After adding a: M1⁻¹ = M⁻¹ − U_a·S⁻¹·U_aᵀ, det M1 = det M · det S (Woodbury,
        // determinant lemma), S = I + Q_a.
        let u_a = self.tall(a);
        let s = Matrix3::identity() + self.q[a];
        let s_inv = s.try_inverse().expect("I + B·M⁻¹·Bᵀ is positive definite");
        let grown: Vec<usize> = self.members.iter().copied().chain([a]).collect();
        // Q of the n+1 members after the addition.
        let q_grown: Vec<Matrix3<f64>> = grown
            .iter()
            .map(|&k| {
                let x = cross(self.c.block(k), &u_a);
                self.q[k] - x * s_inv * x.transpose()
            })
            .collect();
        let n = self.members.len();
        let scores: Vec<(usize, f64)> = if self.criterion == Criterion::O1 {
            // Removing k multiplies det M1 by det(I − Q1_k).
            grown
                .iter()
                .zip(&q_grown)
                .map(|(&k, q)| (k, (Matrix3::identity() - q).determinant()))
                .collect()
        } else {
            let mut info = self.info.clone();
            add_block(&mut info, self.c.block(a), 1.0);
            grown
                .par_iter()
                .map(|&k| (k, self.evaluate_with(&info, k, -1.0, n)))
                .collect()
        };
        let removed = removal_choice(&scores, a);
        if removed == a {
            // Back to the same set: nothing changes.
            return a;
        }
        let r = removed;
        let position = grown.iter().position(|&k| k == r).expect("r is a member");
        let q1_r = q_grown[position];
        // Removing r from M1: M2⁻¹ = M1⁻¹ + U_r1·T⁻¹·U_r1ᵀ, T = I − Q1_r, with
        // U_r1 = M1⁻¹·B_rᵀ = U_r − U_a·S⁻¹·(B_r·U_a)ᵀ.
        let t = Matrix3::identity() - q1_r;
        let t_inv = t
            .try_inverse()
            .expect("r's removal keeps M regular (det(I − Q1_r) > 0)");
        let x_ra = cross(self.c.block(r), &u_a);
        let u_r1 = self.tall(r) - &u_a * (s_inv * x_ra.transpose());
        self.inv -= &u_a * s_inv * u_a.transpose();
        self.inv += &u_r1 * t_inv * u_r1.transpose();
        self.log_det += s.determinant().ln() + t.determinant().ln();
        add_block(&mut self.info, self.c.block(a), 1.0);
        add_block(&mut self.info, self.c.block(r), -1.0);
        // Every Q_k: Q2_k = Q_k − X_a·S⁻¹·X_aᵀ + X_r·T⁻¹·X_rᵀ, X = B_k·U.
        let u6: Vec<[f64; 6]> = (0..m)
            .map(|l| {
                [
                    u_a[(l, 0)],
                    u_a[(l, 1)],
                    u_a[(l, 2)],
                    u_r1[(l, 0)],
                    u_r1[(l, 1)],
                    u_r1[(l, 2)],
                ]
            })
            .collect();
        let c = self.c;
        for_each_task(&mut self.q, |first, chunk| {
            for (i, q) in chunk.iter_mut().enumerate() {
                let b = c.block(first + i);
                let mut y = [[0.0; 6]; 3];
                for (l, u) in u6.iter().enumerate() {
                    for (r, row) in y.iter_mut().enumerate() {
                        let b_rl = b[r * m + l];
                        for (acc, u_j) in row.iter_mut().zip(u) {
                            *acc += b_rl * u_j;
                        }
                    }
                }
                let x_a = Matrix3::from_fn(|r, j| y[r][j]);
                let x_r = Matrix3::from_fn(|r, j| y[r][j + 3]);
                *q += x_r * t_inv * x_r.transpose() - x_a * s_inv * x_a.transpose();
            }
        });
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

    fn o1(&self) -> f64 {
        o1_from_log_det(self.log_det, self.c.parameters(), self.members.len())
    }

    fn value(&self) -> f64 {
        match self.criterion {
            Criterion::O1 => self.o1(),
            other => other.evaluate_information(&self.info, self.members.len()),
        }
    }

    fn refactorisations(&self) -> usize {
        self.refactorisations
    }
}
