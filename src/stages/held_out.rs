//! The folds of measured rows for held-out validation (issue #28), shared by
//! `split`, `identify` (choosing parameters) and `crossvalidate`: the rows'
//! groups ([`crate::calibration::groups`]) dealt to folds whole.

use super::identify::MeasuredRows;
use crate::calibration::groups::{self, GroupError, GroupInput, Grouping};
use crate::calibration::selection::FoldAssignment;

/// Why the rows cannot be folded as asked.
#[derive(Debug, thiserror::Error)]
pub enum FoldError {
    #[error(transparent)]
    Group(#[from] GroupError),
    #[error("grouping by time: `measured_at` is null at cw_id {cw_id}")]
    NullTime { cw_id: i64 },
}

/// `folds` folds of `data`'s rows grouped by `grouping` (one group per fold;
/// plain k-fold for `random`), reproducible from `seed`.
pub fn fold_assignment(
    data: &MeasuredRows,
    grouping: Grouping,
    folds: usize,
    seed: u64,
) -> Result<FoldAssignment, FoldError> {
    let times: Option<Vec<i64>> = match (&data.measured_at_us, grouping) {
        (Some(times), Grouping::Time) => Some(
            times
                .iter()
                .zip(&data.ids)
                .map(|(t, id)| t.ok_or(FoldError::NullTime { cw_id: *id }))
                .collect::<Result<_, _>>()?,
        ),
        _ => None,
    };
    let input = GroupInput {
        rows: &data.rows,
        positions_mm: &data.positions,
        measured_at_us: times.as_deref(),
    };
    let group_of_row = groups::group_rows(grouping, &input, folds, seed)?;
    let fold_of_row = groups::folds_of_groups(&group_of_row, folds, grouping, seed)?;
    Ok(FoldAssignment {
        fold_of_row,
        folds,
        description: format!("{grouping}, {folds} folds"),
    })
}
