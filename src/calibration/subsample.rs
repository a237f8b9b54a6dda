//! The subsample a large table's fit starts from (issue #31): its rank
//! analysis and a fit to it cost about a pass over every row on 5 000 rows,
//! a fiftieth of one on 10⁶.
//!
//! Rows are taken evenly strided over the table, then topped up so that every
//! kind of row the whole table holds is there: each target (SMR or nest), on
//! the arm or on the positioner, with and without a measured orientation, and
//! each joint's approach direction. A parameter whose Jacobian column lives on
//! a few rows only (a target's translation, a joint's backlash) then has rows
//! in the subsample whenever it has rows in the table, so the subsample's rank
//! analysis (columns scaled to unit norm, a relative tolerance: the row count
//! cancels) finds the dependencies the whole table has. Exact dependencies
//! (parallel axes, a second target's rotation) hold on any rows.

use nalgebra::Vector3;

use super::fit::{MeasuredOrientation, Observations};
use crate::robot::{ConfWrench, MAX_JOINTS};

/// Rows of a kind the subsample holds, at least (or all of them, if fewer):
/// a handful beyond the three equations a target's translation needs.
const ROWS_PER_KIND: usize = 10;

/// What a row contributes to: the parameters of its target, of its mounting,
/// of a measured orientation, and of the backlash of the joints it approached
/// in a known direction.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum RowKind {
    Target {
        target: usize,
        on_positioner: bool,
        with_orientation: bool,
    },
    Approach {
        joint: usize,
        direction: i8,
    },
}

impl RowKind {
    /// A dense index for counting without hashing (a pass over 10⁶ rows):
    /// each joint's two directions first, then four kinds per target.
    fn slot(self) -> usize {
        match self {
            RowKind::Approach { joint, direction } => 2 * joint + usize::from(direction > 0),
            RowKind::Target {
                target,
                on_positioner,
                with_orientation,
            } => {
                2 * MAX_JOINTS
                    + 4 * target
                    + 2 * usize::from(on_positioner)
                    + usize::from(with_orientation)
            }
        }
    }
}

/// Rows of each kind, by [`RowKind::slot`].
#[derive(Default)]
struct KindCounts(Vec<usize>);

impl KindCounts {
    fn get(&self, kind: RowKind) -> usize {
        self.0.get(kind.slot()).copied().unwrap_or(0)
    }

    fn add(&mut self, kind: RowKind) {
        let slot = kind.slot();
        if slot >= self.0.len() {
            self.0.resize(slot + 1, 0);
        }
        self.0[slot] += 1;
    }
}

/// The kinds of row `k` of `data`: none for a row the fit excludes.
fn kinds_of(data: &Observations<'_>, k: usize) -> impl Iterator<Item = RowKind> {
    let row = &data.rows[k];
    let included = data.scale_of(k).iter().any(|s| *s != 0.0);
    let target = RowKind::Target {
        target: row.target,
        on_positioner: row.positioner_deg.is_some(),
        with_orientation: data.orientation_of(k).is_some(),
    };
    let approaches = (0..MAX_JOINTS)
        .filter(|j| row.approach[*j] != 0)
        .map(|joint| RowKind::Approach {
            joint,
            direction: row.approach[joint],
        });
    std::iter::once(target)
        .chain(approaches)
        .filter(move |_| included)
}

/// Indices of `sample_rows` rows evenly strided over `data`, topped up to
/// [`ROWS_PER_KIND`] rows of every kind of row (module docs), ascending.
fn sample_indices(data: &Observations<'_>, sample_rows: usize) -> Vec<usize> {
    let rows = data.rows.len();
    let stride = rows.div_ceil(sample_rows.max(1)).max(1);
    let mut taken = vec![false; rows];
    let mut in_sample = KindCounts::default();
    for k in (0..rows).step_by(stride) {
        taken[k] = true;
        for kind in kinds_of(data, k) {
            in_sample.add(kind);
        }
    }
    for (k, taken) in taken.iter_mut().enumerate() {
        if *taken {
            continue;
        }
        let short = kinds_of(data, k).any(|kind| in_sample.get(kind) < ROWS_PER_KIND);
        if short {
            *taken = true;
            for kind in kinds_of(data, k) {
                in_sample.add(kind);
            }
        }
    }
    (0..rows).filter(|k| taken[*k]).collect()
}

/// A subsample's rows, owned; [`Subsample::observations`] lends them as a fit's input.
pub(crate) struct Subsample {
    rows: Vec<ConfWrench>,
    measured_mm: Vec<Vector3<f64>>,
    row_scale: Option<Vec<Vector3<f64>>>,
    orientations: Option<Vec<Option<MeasuredOrientation>>>,
}

impl Subsample {
    /// About `sample_rows` rows of `data` (module docs).
    pub(crate) fn of(data: &Observations<'_>, sample_rows: usize) -> Subsample {
        let indices = sample_indices(data, sample_rows);
        let pick = |values: &[_]| -> Vec<_> { indices.iter().map(|k| values[*k]).collect() };
        Subsample {
            rows: indices.iter().map(|k| data.rows[*k]).collect(),
            measured_mm: pick(data.measured_mm),
            row_scale: data.row_scale.map(pick),
            orientations: data
                .orientations
                .map(|o| indices.iter().map(|k| o[*k]).collect()),
        }
    }

    pub(crate) fn observations(&self) -> Observations<'_> {
        Observations {
            rows: &self.rows,
            measured_mm: &self.measured_mm,
            row_scale: self.row_scale.as_deref(),
            orientations: self.orientations.as_deref(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::Wrench;

    fn row(target: usize, approach_joint_2: i8) -> ConfWrench {
        let mut row = ConfWrench::new([0.0; MAX_JOINTS], Wrench::zero());
        row.target = target;
        row.approach[1] = approach_joint_2;
        row
    }

    #[test]
    fn a_rare_target_and_a_rare_approach_are_topped_up_and_the_stride_kept() {
        // 10 000 rows of target 0 approached from below, 4 of target 1 and
        // 12 approached from above, scattered where the stride misses them.
        let mut rows: Vec<ConfWrench> = (0..10_000).map(|_| row(0, 1)).collect();
        for k in [1, 3, 5, 7] {
            rows[k] = row(1, 1);
        }
        for k in 0..12 {
            rows[101 + 100 * k] = row(0, -1);
        }
        let measured = vec![Vector3::zeros(); rows.len()];
        let data = Observations::new(&rows, &measured);
        let indices = sample_indices(&data, 100);
        let strided = (0..rows.len()).step_by(100).count();
        let count =
            |wanted: fn(&ConfWrench) -> bool| indices.iter().filter(|k| wanted(&rows[**k])).count();
        assert_eq!(count(|r| r.target == 1), 4);
        assert_eq!(count(|r| r.approach[1] == -1), ROWS_PER_KIND);
        assert!(indices.windows(2).all(|w| w[0] < w[1]));
        assert_eq!(indices.len(), strided + 4 + ROWS_PER_KIND);
    }

    #[test]
    fn excluded_rows_count_for_nothing() {
        let rows: Vec<ConfWrench> = (0..1000).map(|k| row(usize::from(k < 20), 0)).collect();
        let measured = vec![Vector3::zeros(); rows.len()];
        // Target 1's rows are all excluded: nothing to top up.
        let scale: Vec<Vector3<f64>> = (0..rows.len())
            .map(|k| Vector3::repeat(if k < 20 { 0.0 } else { 1.0 }))
            .collect();
        let data = Observations {
            row_scale: Some(&scale),
            ..Observations::new(&rows, &measured)
        };
        let indices = sample_indices(&data, 100);
        assert_eq!(indices.len(), 100);
    }
}
