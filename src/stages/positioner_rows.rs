//! Which rows of a table measured a positioner's nest, and at which axis
//! values (issue #30): a row whose `target_id` is one of the robot file's
//! `[positioner] nests` is a positioner row, and needs `p1_deg` (and
//! `p2_deg` on a two-axis positioner) within the axes' limits. Every stage
//! that reads rows reads them here, so none evaluates a nest's row as the
//! arm's.

use std::path::Path;

use polars::prelude::DataFrame;

use super::StageError;
use crate::robot::RobotSpec;
use crate::robot::positioner::MAX_POSITIONER_AXES;
use crate::table::schema::{POSITIONER_COLUMNS, optional_f64_values, str_values};

/// Each row's positioner axis values (deg) when it measured a nest on the
/// positioner's table, `None` for a row on the arm. A table with axis
/// columns for a robot file without a positioner (or the second axis's for
/// a one-axis positioner) is refused: nothing would read them, so the table
/// is meant for another cell.
pub(crate) fn positioner_axes_of_rows(
    df: &DataFrame,
    path: &Path,
    robot: &RobotSpec,
) -> Result<Vec<Option<[f64; MAX_POSITIONER_AXES]>>, StageError> {
    let axes = robot.positioner.as_ref().map_or(0, |p| p.axes.len());
    if let Some(extra) = POSITIONER_COLUMNS[axes..]
        .iter()
        .find(|c| df.column(c).is_ok())
    {
        return Err(StageError::Invalid(format!(
            "{}: column `{extra}` gives a positioner axis, but the robot file {} has {}: add the axis to its [positioner], or use the table of this cell",
            path.display(),
            robot.path.display(),
            match axes {
                0 => "no [positioner]".to_string(),
                n => format!("a positioner of {n} axis"),
            }
        )));
    }
    let (Some(positioner), Ok(_)) = (&robot.positioner, df.column("target_id")) else {
        return Ok(vec![None; df.height()]);
    };
    let target_ids = str_values(df, "target_id", path)?;
    let on_nest: Vec<bool> = target_ids
        .iter()
        .map(|id| {
            id.as_deref()
                .is_some_and(|id| positioner.nests.iter().any(|n| n == id))
        })
        .collect();
    let Some(first_nest_row) = on_nest.iter().position(|n| *n) else {
        return Ok(vec![None; df.height()]);
    };
    let mut values = vec![[0.0; MAX_POSITIONER_AXES]; df.height()];
    for (axis, name) in POSITIONER_COLUMNS[..axes].iter().enumerate() {
        let Some(column) = optional_f64_values(df, name, path)? else {
            return Err(StageError::Invalid(format!(
                "{}: row {first_nest_row} measured the positioner's nest `{}`, so the table needs the positioner's axis values in column `{name}` (deg)",
                path.display(),
                target_ids[first_nest_row].as_deref().unwrap_or_default()
            )));
        };
        let [lo, hi] = positioner.axes[axis].limits_deg;
        for (row, value) in column.iter().enumerate() {
            if !on_nest[row] {
                continue;
            }
            match value {
                Some(v) if v.is_finite() && (lo..=hi).contains(v) => values[row][axis] = *v,
                Some(v) => {
                    return Err(StageError::Invalid(format!(
                        "{}: column `{name}`, row {row}: {v} deg is outside the positioner axis's limits [{lo}, {hi}] deg (robot file {})",
                        path.display(),
                        robot.path.display()
                    )));
                }
                None => {
                    return Err(StageError::Invalid(format!(
                        "{}: column `{name}`, row {row}: empty, but the row measured the positioner's nest `{}` and needs the axis's value (deg)",
                        path.display(),
                        target_ids[row].as_deref().unwrap_or_default()
                    )));
                }
            }
        }
    }
    Ok(on_nest
        .iter()
        .zip(values)
        .map(|(on, v)| on.then_some(v))
        .collect())
}
