//! Passes over the rows in fixed chunks, in parallel, reduced to a small
//! triangular factor instead of the full `3n × m` Jacobian (issue #7: a million
//! rows must fit in memory and time).
//!
//! Each chunk stacks its rows' equations into a `3·chunk × k` block and reduces it
//! to the `k × k` factor `R` of a Householder QR (`RᵀR = AᵀA`, `R = QᵀA`); two
//! neighbouring factors combine by the QR of the two stacked (TSQR). The final `R`
//! is the R factor of the whole matrix, so everything downstream (least-squares
//! steps, singular values, rank analysis) sees exactly what a dense QR of all
//! rows would give, with the accuracy of QR: errors grow with the condition
//! number κ of the scaled Jacobian, not κ² as with the normal equations `JᵀJ`,
//! which lose the 1e-9 agreement with a dense QR once κ passes ~1e4 (measured:
//! DESIGN.md). The price: on one core faer factorises a million rows'
//! blocks (3·10⁶ × 33) in 0.67 s where it forms `AᵀA` in 0.15 s, a third of a
//! pass whose Jacobian rows take 1.25 s.
//!
//! The chunks are fixed (`chunk_rows` each, the last one shorter) and combined in a
//! fixed binary tree over their order, so a pass gives the same bits whatever the
//! number of threads or the scheduling; another chunk size changes results only by
//! rounding.

use std::ops::Range;

use faer::Mat;
use nalgebra::Vector3;

use super::dense;
use crate::robot::{ConfWrench, ParamId, ParamValues, Robot};

/// Rows per chunk: 1024 rows make a `3072 × (m + 1)` block (0.8 MB at m = 32).
/// Measured per million rows of Jacobian blocks on one core, the QR takes 0.80 s
/// in chunks of 128 rows, 0.69 s of 512, 0.67 s of 1024 and 0.65 s of 2048;
/// a thousand chunks still balance well over the threads.
pub const CHUNK_ROWS: usize = 1024;

/// Reduces the rows in chunks of `chunk_rows` (at least 1) in parallel: `leaf`
/// gets a chunk's row range and its slice of `outputs` (one element per row) and
/// returns the chunk's summary; `combine` joins the summaries of neighbouring
/// row ranges, left first. `None` when there are no rows.
///
/// The binary tree over the chunks depends only on their number, so the result
/// does not depend on the thread count.
pub(crate) fn reduce_chunks<O, T, L, C>(
    outputs: &mut [O],
    chunk_rows: usize,
    leaf: &L,
    combine: &C,
) -> Option<T>
where
    O: Send,
    T: Send,
    L: Fn(Range<usize>, &mut [O]) -> T + Sync,
    C: Fn(T, T) -> T + Sync,
{
    let chunk_rows = chunk_rows.max(1);
    let rows = outputs.len();
    let chunks = rows.div_ceil(chunk_rows);
    (chunks > 0).then(|| tree(0..chunks, 0, outputs, chunk_rows, leaf, combine))
}

/// One node of [`reduce_chunks`]'s tree: chunks `chunks`, whose rows start at `first_row`.
fn tree<O, T, L, C>(
    chunks: Range<usize>,
    first_row: usize,
    outputs: &mut [O],
    chunk_rows: usize,
    leaf: &L,
    combine: &C,
) -> T
where
    O: Send,
    T: Send,
    L: Fn(Range<usize>, &mut [O]) -> T + Sync,
    C: Fn(T, T) -> T + Sync,
{
    if chunks.len() == 1 {
        return leaf(first_row..first_row + outputs.len(), outputs);
    }
    let middle = chunks.start + chunks.len() / 2;
    // Every chunk but the last is full, so the left half has exactly this many rows.
    let left_rows = (middle - chunks.start) * chunk_rows;
    let (left, right) = outputs.split_at_mut(left_rows);
    let (a, b) = rayon::join(
        || {
            tree(
                chunks.start..middle,
                first_row,
                left,
                chunk_rows,
                leaf,
                combine,
            )
        },
        || {
            tree(
                middle..chunks.end,
                first_row + left_rows,
                right,
                chunk_rows,
                leaf,
                combine,
            )
        },
    );
    combine(a, b)
}

/// Equations staged before they are copied into the block: 24 rows of at most
/// 43 values stay in L1 and each flush writes 192 contiguous bytes per column.
const STAGED_EQUATIONS: usize = 24;

/// A chunk's column-major block of equations, filled one equation (row) at a
/// time through a small row-major stage and copied in a column at a time.
///
/// Written straight into the block, one row's values land a column stride
/// apart (24 KiB for 1024 rows, a multiple of 4 KiB, so every value of a row
/// competes for the same cache sets): those stores took a fifth of a pass
/// (issue #31). The values and so the factor are the same bits either way.
pub(crate) struct EquationBlock {
    block: Mat<f64>,
    staged: Vec<f64>,
    staged_rows: usize,
    /// Rows of `block` already copied.
    filled: usize,
}

impl EquationBlock {
    pub(crate) fn new(equations: usize, columns: usize) -> Self {
        EquationBlock {
            block: Mat::zeros(equations, columns),
            staged: vec![0.0; STAGED_EQUATIONS * columns],
            staged_rows: 0,
            filled: 0,
        }
    }

    /// The next equation's values, one per column, to be written in full.
    pub(crate) fn next_equation(&mut self) -> &mut [f64] {
        if self.staged_rows == STAGED_EQUATIONS {
            self.flush();
        }
        let width = self.block.ncols();
        let start = self.staged_rows * width;
        self.staged_rows += 1;
        &mut self.staged[start..start + width]
    }

    fn flush(&mut self) {
        let (width, rows, first) = (self.block.ncols(), self.staged_rows, self.filled);
        for j in 0..width {
            let column = &mut self.block.col_as_slice_mut(j)[first..first + rows];
            for (i, value) in column.iter_mut().enumerate() {
                *value = self.staged[i * width + j];
            }
        }
        self.filled += rows;
        self.staged_rows = 0;
    }

    /// The block, every equation copied in (rows never asked for stay zero).
    pub(crate) fn finish(mut self) -> Mat<f64> {
        self.flush();
        self.block
    }
}

/// The factor of two stacked factors: `R` with `RᵀR = aᵀa + bᵀb`.
pub(crate) fn stack(a: &Mat<f64>, b: &Mat<f64>) -> Mat<f64> {
    let (k, rows_a) = (a.ncols(), a.nrows());
    let stacked = Mat::<f64>::from_fn(rows_a + b.nrows(), k, |i, j| {
        if i < rows_a {
            a[(i, j)]
        } else {
            b[(i - rows_a, j)]
        }
    });
    dense::triangular_factor(stacked)
}

/// The `m × m` factor `R` of the identification Jacobian of `columns` at `at`
/// over all rows (`RᵀR = JᵀJ`), one parallel pass: what the rank analysis needs.
///
/// Memory: one `3·chunk_rows × m` block per thread, whatever the number of rows.
pub fn jacobian_factor(
    robot: &Robot,
    at: &ParamValues,
    rows: &[ConfWrench],
    columns: &[ParamId],
    chunk_rows: usize,
) -> Mat<f64> {
    let m = columns.len();
    let prepared = robot.prepare(at);
    let leaf = |range: Range<usize>, _: &mut [()]| {
        let chunk = &rows[range];
        let mut block = EquationBlock::new(3 * chunk.len(), m);
        let mut row_columns = vec![Vector3::zeros(); m];
        for row in chunk {
            prepared.jacobian_row(row, columns, &mut row_columns);
            for axis in 0..3 {
                let equation = block.next_equation();
                for (value, column) in equation.iter_mut().zip(&row_columns) {
                    *value = column[axis];
                }
            }
        }
        dense::triangular_factor(block.finish())
    };
    let combine = |a: Mat<f64>, b: Mat<f64>| stack(&a, &b);
    reduce_chunks(&mut vec![(); rows.len()], chunk_rows, &leaf, &combine)
        .unwrap_or_else(|| Mat::zeros(m, m))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::test_support::{irb1600, random_q, random_wrench, truth_params};
    use crate::robot::{Selection, batch_jacobian};
    use rand::SeedableRng;
    use rand::rngs::StdRng;

    fn random_rows(robot: &Robot, n: usize) -> Vec<ConfWrench> {
        let mut rng = StdRng::seed_from_u64(3);
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
    fn equation_block_places_every_equation_in_its_row() {
        for equations in [0, 1, STAGED_EQUATIONS, STAGED_EQUATIONS + 1, 100] {
            let mut block = EquationBlock::new(equations, 5);
            for i in 0..equations {
                for (j, value) in block.next_equation().iter_mut().enumerate() {
                    *value = (100 * i + j) as f64;
                }
            }
            let block = block.finish();
            assert_eq!(block.shape(), (equations, 5));
            for i in 0..equations {
                for j in 0..5 {
                    assert_eq!(block[(i, j)], (100 * i + j) as f64);
                }
            }
        }
    }

    #[test]
    fn chunks_cover_every_row_once_in_order() {
        for (rows, chunk_rows) in [(10, 3), (9, 3), (1, 5), (7, 1), (1000, 64)] {
            let mut outputs = vec![0usize; rows];
            let leaf = |range: Range<usize>, out: &mut [usize]| {
                assert!(range.len() <= chunk_rows && range.len() == out.len());
                for (o, row) in out.iter_mut().zip(range.clone()) {
                    *o = row + 1;
                }
                vec![range]
            };
            let combine = |mut a: Vec<Range<usize>>, b: Vec<Range<usize>>| {
                assert_eq!(a.last().map(|r| r.end), b.first().map(|r| r.start));
                a.extend(b);
                a
            };
            let ranges = reduce_chunks(&mut outputs, chunk_rows, &leaf, &combine).unwrap();
            assert_eq!(ranges.len(), rows.div_ceil(chunk_rows));
            assert_eq!(outputs, (1..=rows).collect::<Vec<_>>());
        }
        let none = reduce_chunks(&mut Vec::<()>::new(), 4, &|_, _| 1, &|a, b| a + b);
        assert_eq!(none, None);
    }

    /// The streamed factor has the Gram matrix of the full Jacobian (`RᵀR = JᵀJ`)
    /// for any chunk size, including chunks with fewer equations than columns.
    #[test]
    fn streamed_factor_has_the_full_jacobian_s_gram_matrix() {
        let robot = irb1600();
        let p = truth_params(&robot);
        let rows = random_rows(&robot, 301);
        let columns = Selection::spec_identifiable().ids().to_vec();
        let m = columns.len();
        let full = batch_jacobian(&robot, &p, &rows, &columns);
        let j = Mat::<f64>::from_fn(full.rows(), m, |r, c| full.entry(r, c));
        let gram = j.transpose() * &j;
        for chunk_rows in [1, 7, 64, 300, 301, 5000] {
            let r = jacobian_factor(&robot, &p, &rows, &columns, chunk_rows);
            let streamed = r.transpose() * &r;
            for a in 0..m {
                for b in 0..m {
                    let scale = (gram[(a, a)] * gram[(b, b)]).sqrt();
                    assert!(
                        (streamed[(a, b)] - gram[(a, b)]).abs() < 1e-12 * scale,
                        "chunk {chunk_rows}, ({a}, {b})"
                    );
                }
            }
        }
    }
}
