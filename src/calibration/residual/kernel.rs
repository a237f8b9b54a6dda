//! The squared-exponential kernel with one length scale per group of feature
//! columns (ARD by group), its matrices, and the contraction that turns a
//! likelihood's gradient with respect to a kernel matrix into gradients with
//! respect to the log length scales.
//!
//! Squared-exponential rather than Matérn-5/2: the residual it models is smooth
//! (transmission errors, unmodelled compliance), and its derivative with respect
//! to a length scale is the kernel times a squared distance, which the
//! contraction below needs per group without a square root.
//!
//! Matrices are built in fixed chunks of columns in parallel and reduced in
//! chunk order, so results do not depend on the number of threads.

use faer::Mat;
use rayon::prelude::*;

/// Columns of a kernel matrix built or contracted per parallel task.
pub(super) const CHUNK: usize = 256;

/// Feature rows, row-major, `columns` values per row.
#[derive(Debug, Clone, Copy)]
pub(super) struct Rows<'a> {
    pub values: &'a [f64],
    pub columns: usize,
}

impl<'a> Rows<'a> {
    pub fn len(&self) -> usize {
        self.values.len() / self.columns
    }

    pub fn row(&self, i: usize) -> &'a [f64] {
        &self.values[i * self.columns..(i + 1) * self.columns]
    }

    /// Rows `start..end`.
    pub fn slice(&self, start: usize, end: usize) -> Rows<'a> {
        Rows {
            values: &self.values[start * self.columns..end * self.columns],
            columns: self.columns,
        }
    }
}

/// `k(a, b) = s²·exp(−½ Σ_c ((a_c − b_c)/ℓ_{group(c)})²)`.
#[derive(Debug, Clone)]
pub(super) struct Kernel<'a> {
    pub signal_variance: f64,
    /// One per group.
    pub length_scales: &'a [f64],
    /// The group of each feature column.
    pub groups: &'a [usize],
}

impl Kernel<'_> {
    fn inverse_scales(&self) -> Vec<f64> {
        self.groups
            .iter()
            .map(|g| 1.0 / self.length_scales[*g])
            .collect()
    }

    /// `K(a, b)`, `a.len() × b.len()`: one exponential per entry.
    pub fn matrix(&self, a: Rows<'_>, b: Rows<'_>) -> Mat<f64> {
        let w = self.inverse_scales();
        let (na, nb) = (a.len(), b.len());
        let mut values = vec![0.0; na * nb];
        if na > 0 {
            values
                .par_chunks_mut(na * CHUNK)
                .enumerate()
                .for_each(|(chunk, out)| {
                    for (jj, column) in out.chunks_mut(na).enumerate() {
                        let bj = b.row(chunk * CHUNK + jj);
                        for (i, entry) in column.iter_mut().enumerate() {
                            let ai = a.row(i);
                            let mut r2 = 0.0;
                            for c in 0..w.len() {
                                let t = (ai[c] - bj[c]) * w[c];
                                r2 += t * t;
                            }
                            *entry = self.signal_variance * (-0.5 * r2).exp();
                        }
                    }
                });
        }
        Mat::from_fn(na, nb, |i, j| values[j * na + i])
    }

    /// `Σ_ij weights_ij · ∂K_ij/∂log ℓ_g` for each group `g`, where
    /// `∂k/∂log ℓ_g = k · Σ_{c∈g} (a_c − b_c)²/ℓ_g²`; `weights` and `k` are
    /// `a.len() × b.len()` (`weights` is a likelihood's gradient with respect to
    /// `K(a, b)`, `k` the matrix itself).
    pub fn log_length_scale_gradient(
        &self,
        a: Rows<'_>,
        b: Rows<'_>,
        weights: &Mat<f64>,
        k: &Mat<f64>,
    ) -> Vec<f64> {
        let w = self.inverse_scales();
        let groups = self.length_scales.len();
        let nb = b.len();
        let partials: Vec<Vec<f64>> = (0..nb.div_ceil(CHUNK))
            .into_par_iter()
            .map(|chunk| {
                let mut sums = vec![0.0; groups];
                for j in chunk * CHUNK..((chunk + 1) * CHUNK).min(nb) {
                    let bj = b.row(j);
                    for i in 0..a.len() {
                        let factor = weights[(i, j)] * k[(i, j)];
                        if factor == 0.0 {
                            continue;
                        }
                        let ai = a.row(i);
                        for c in 0..w.len() {
                            let t = (ai[c] - bj[c]) * w[c];
                            sums[self.groups[c]] += factor * t * t;
                        }
                    }
                }
                sums
            })
            .collect();
        partials.iter().fold(vec![0.0; groups], |mut total, part| {
            for (t, p) in total.iter_mut().zip(part) {
                *t += p;
            }
            total
        })
    }
}
