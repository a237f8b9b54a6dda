//! Sequential dense linear algebra for the calibration's small problems: one
//! chunk's block of equations (a few thousand rows, at most 43 columns) and the
//! `m × m` factors the passes reduce to.
//!
//! faer's high-level solvers (`Mat::qr`, `thin_svd`, ...) run with its global
//! parallelism, rayon on every core by default. At this size the thread hand-offs
//! cost more than the arithmetic: they took over half the time of identifying 50
//! rows (`benches/identify.rs`), and the chunks already run in parallel. These
//! wrappers call faer's low-level routines with `Par::Seq` instead, leaving the
//! global setting alone for other modules.

use faer::diag::Diag;
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::svd::{ComputeSvdVectors, SvdError};
use faer::linalg::{qr, svd};
use faer::{Conj, Mat, MatRef, Par};

/// Householder block size for a chunk's factor: on 3072 × 32 Jacobian blocks
/// faer's recommended 32 took 0.79 s per million rows on one core, 8 took 0.67 s
/// (4 and 16 in between); the tall, narrow panels favour short blocks.
const FACTOR_BLOCK: usize = 8;

/// Householder QR of `a` in place, sequentially: `R` in the upper part, the
/// reflectors below it; returns the block reflectors' coefficients.
fn householder_in_place(a: &mut Mat<f64>, block_size: usize) -> Mat<f64> {
    let (m, n) = a.shape();
    let par = Par::Seq;
    let mut coefficients = Mat::<f64>::zeros(block_size, n.min(m));
    qr::no_pivoting::factor::qr_in_place(
        a.as_mut(),
        coefficients.as_mut(),
        par,
        MemStack::new(&mut MemBuffer::new(
            qr::no_pivoting::factor::qr_in_place_scratch::<f64>(
                m,
                n,
                block_size,
                par,
                Default::default(),
            ),
        )),
        Default::default(),
    );
    clear_upper_vector_state();
    coefficients
}

/// Ends the dirty upper state of the vector registers that faer's kernels
/// leave behind.
///
/// faer's block updates run the `gemm` crate's AVX-512 kernels, which return
/// without a `vzeroupper`; until one runs, the scalar (SSE) code that follows
/// on that thread carries a false dependency on the registers' upper halves.
/// After each chunk's QR, the next chunk's Jacobian rows took 1.97 µs a row
/// instead of 0.87 (kinematic model, 1 024-row chunks, 26 columns; 1.40
/// instead of 1.31 for the elasto-geometric one): issue #31.
pub(crate) fn clear_upper_vector_state() {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: `zero_upper` needs AVX, which the CPU has (checked above).
        unsafe { zero_upper() }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
fn zero_upper() {
    std::arch::x86_64::_mm256_zeroupper();
}

/// The upper-triangular factor `R` of `a`'s QR (Householder, no pivoting):
/// `ncols × ncols` with `RᵀR = aᵀa`, zero rows below `nrows` when `a` is wider
/// than tall. Factorises `a` in place.
///
/// faer skips a column whose remaining part is below rounding (≈ 16·ε·nrows of
/// its norm) and eliminates the next one in its row; the upper part is then still
/// a valid factor, with that column's rounding-level remainder on its row.
pub fn triangular_factor(mut a: Mat<f64>) -> Mat<f64> {
    let (m, n) = a.shape();
    if m.min(n) == 0 {
        return Mat::zeros(n, n);
    }
    let block_size = qr::no_pivoting::factor::recommended_block_size::<f64>(m, n).min(FACTOR_BLOCK);
    householder_in_place(&mut a, block_size);
    Mat::<f64>::from_fn(n, n, |i, j| if i <= j && i < m { a[(i, j)] } else { 0.0 })
}

/// Least-squares solution `x` of `a·x ≈ b` (`a` with at least as many rows as
/// columns) by Householder QR, one column of `x` per column of `b`.
pub fn lstsq(a: MatRef<'_, f64>, b: MatRef<'_, f64>) -> Mat<f64> {
    let (m, n) = a.shape();
    let par = Par::Seq;
    let block_size = qr::no_pivoting::factor::recommended_block_size::<f64>(m, n);
    let mut factors = a.to_owned();
    let coefficients = householder_in_place(&mut factors, block_size);
    // Householder basis: strictly lower part with a unit diagonal; R: upper part.
    let basis = Mat::<f64>::from_fn(m, n, |i, j| match i.cmp(&j) {
        std::cmp::Ordering::Greater => factors[(i, j)],
        std::cmp::Ordering::Equal => 1.0,
        std::cmp::Ordering::Less => 0.0,
    });
    let r = Mat::<f64>::from_fn(n, n, |i, j| if i <= j { factors[(i, j)] } else { 0.0 });
    let mut rhs = b.to_owned();
    qr::no_pivoting::solve::solve_lstsq_in_place_with_conj(
        basis.as_ref(),
        coefficients.as_ref(),
        r.as_ref(),
        Conj::No,
        rhs.as_mut(),
        par,
        MemStack::new(&mut MemBuffer::new(
            qr::no_pivoting::solve::solve_lstsq_in_place_scratch::<f64>(
                m,
                n,
                block_size,
                b.ncols(),
                par,
            ),
        )),
    );
    rhs.subrows(0, n).to_owned()
}

/// Singular values (in faer's order, descending) and, when asked, the right
/// singular vectors `V` (`n × min(m, n)`, column k belongs to value k).
pub fn svd(a: MatRef<'_, f64>, with_v: bool) -> Result<(Vec<f64>, Option<Mat<f64>>), SvdError> {
    let (m, n) = a.shape();
    let size = m.min(n);
    let par = Par::Seq;
    let mut s = Diag::<f64>::zeros(size);
    let mut v = with_v.then(|| Mat::<f64>::zeros(n, size));
    let compute_v = if with_v {
        ComputeSvdVectors::Thin
    } else {
        ComputeSvdVectors::No
    };
    svd::svd(
        a,
        s.as_mut(),
        None,
        v.as_mut().map(|v| v.as_mut()),
        par,
        MemStack::new(&mut MemBuffer::new(svd::svd_scratch::<f64>(
            m,
            n,
            ComputeSvdVectors::No,
            compute_v,
            par,
            Default::default(),
        ))),
        Default::default(),
    )?;
    clear_upper_vector_state();
    let values = (0..size).map(|k| s.column_vector()[k]).collect();
    Ok((values, v))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn example() -> Mat<f64> {
        Mat::<f64>::from_fn(7, 3, |i, j| {
            ((i * 3 + j) as f64).sin() + if i == j { 2.0 } else { 0.0 }
        })
    }

    #[test]
    fn lstsq_matches_faer_s_solver() {
        use faer::prelude::*;
        let a = example();
        let b = Mat::<f64>::from_fn(7, 2, |i, j| (i as f64 + 0.5 * j as f64).cos());
        let ours = lstsq(a.as_ref(), b.as_ref());
        let theirs = a.qr().solve_lstsq(&b);
        assert!((&ours - &theirs).norm_l2() < 1e-12 * theirs.norm_l2());
    }

    #[test]
    fn svd_matches_faer_s_solver() {
        let a = example();
        let (values, v) = svd(a.as_ref(), true).unwrap();
        let reference = a.thin_svd().unwrap();
        for (k, value) in values.iter().enumerate() {
            let want = reference.S().column_vector()[k];
            assert!((value - want).abs() < 1e-12 * want);
        }
        // Columns of V agree up to sign.
        let v = v.unwrap();
        for k in 0..3 {
            let dot: f64 = (0..3).map(|i| v[(i, k)] * reference.V()[(i, k)]).sum();
            assert!((dot.abs() - 1.0).abs() < 1e-10);
        }
        let (only_values, none) = svd(a.as_ref(), false).unwrap();
        for (x, y) in only_values.iter().zip(&values) {
            assert!((x - y).abs() < 1e-12 * y);
        }
        assert!(none.is_none());
    }

    /// `RᵀR = AᵀA`, also when faer skips dependent columns (a repeated and a zero
    /// column) and when `A` has fewer rows than columns.
    #[test]
    fn triangular_factor_keeps_the_gram_matrix() {
        let base = example();
        let dependent = Mat::<f64>::from_fn(7, 5, |i, j| match j {
            0 | 1 => base[(i, j)],
            2 => base[(i, 0)],
            3 => 0.0,
            _ => base[(i, 2)],
        });
        for a in [
            example(),
            dependent.clone(),
            dependent.subrows(0, 3).to_owned(),
        ] {
            let r = triangular_factor(a.clone());
            assert_eq!(r.shape(), (a.ncols(), a.ncols()));
            let (rtr, ata) = (r.transpose() * &r, a.transpose() * &a);
            assert!((&rtr - &ata).norm_l2() < 1e-13 * ata.norm_l2());
            for i in 0..r.nrows() {
                for j in 0..i {
                    assert_eq!(r[(i, j)], 0.0);
                }
            }
        }
    }
}
