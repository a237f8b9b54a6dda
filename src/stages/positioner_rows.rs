//! Which rows of a table measured a positioner's nest, and at which axis
//! values (issue #30): a row whose `target_id` is one of the robot file's
//! `[positioner] nests` is a positioner row, and needs `p1_deg` (and
//! `p2_deg` on a two-axis positioner). Every stage that reads rows reads
//! them here, so none evaluates a nest's row as the arm's; `compensate`
//! reads its targets' axis values here too.

use std::path::Path;

use polars::prelude::DataFrame;

use super::StageError;
use crate::robot::RobotSpec;
use crate::robot::positioner::MAX_POSITIONER_AXES;
use crate::table::schema::{POSITIONER_COLUMNS, optional_f64_values, str_values};

/// Axis values of one row, `None` where the table has no value.
type AxisCells = [Option<f64>; MAX_POSITIONER_AXES];

/// The axis columns of a table, checked: refused for a robot file without a
/// positioner (or the second axis's for a one-axis positioner), since
/// nothing would read them and the table is meant for another cell; every
/// value given finite and within its axis's limits. `None` without any.
fn axis_cells(
    df: &DataFrame,
    path: &Path,
    robot: &RobotSpec,
) -> Result<Option<Vec<AxisCells>>, StageError> {
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
    let Some(positioner) = &robot.positioner else {
        return Ok(None);
    };
    let mut cells = vec![[None; MAX_POSITIONER_AXES]; df.height()];
    let mut any = false;
    for (axis, name) in POSITIONER_COLUMNS[..axes].iter().enumerate() {
        let Some(column) = optional_f64_values(df, name, path)? else {
            continue;
        };
        any = true;
        let [lo, hi] = positioner.axes[axis].limits_deg;
        for (row, value) in column.into_iter().enumerate() {
            if let Some(v) = value
                && !(v.is_finite() && (lo..=hi).contains(&v))
            {
                return Err(StageError::Invalid(format!(
                    "{}: column `{name}`, row {row}: {v} deg is outside the positioner axis's limits [{lo}, {hi}] deg (robot file {})",
                    path.display(),
                    robot.path.display()
                )));
            }
            cells[row][axis] = value;
        }
    }
    Ok(any.then_some(cells))
}

/// The values of a row's axes when all of the positioner's are given.
fn complete(cells: &AxisCells, axes: usize) -> Option<[f64; MAX_POSITIONER_AXES]> {
    let mut values = [0.0; MAX_POSITIONER_AXES];
    for (value, cell) in values.iter_mut().zip(cells).take(axes) {
        *value = (*cell)?;
    }
    Some(values)
}

/// Each row's positioner axis values (deg) when it measured a nest on the
/// positioner's table, `None` for a row on the arm. A nest row without its
/// axis values is refused, naming the column and row.
pub(crate) fn positioner_axes_of_rows(
    df: &DataFrame,
    path: &Path,
    robot: &RobotSpec,
) -> Result<Vec<Option<[f64; MAX_POSITIONER_AXES]>>, StageError> {
    let cells = axis_cells(df, path, robot)?;
    let (Some(positioner), Ok(_)) = (&robot.positioner, df.column("target_id")) else {
        return Ok(vec![None; df.height()]);
    };
    let target_ids = str_values(df, "target_id", path)?;
    let nest_of = |row: usize| {
        target_ids[row]
            .as_deref()
            .filter(|id| positioner.nests.iter().any(|n| n == id))
    };
    let axes = positioner.axes.len();
    (0..df.height())
        .map(|row| {
            let Some(nest) = nest_of(row) else {
                return Ok(None);
            };
            let row_cells = cells.as_ref().map(|c| c[row]).unwrap_or_default();
            match complete(&row_cells, axes) {
                Some(values) => Ok(Some(values)),
                None => {
                    let missing = (0..axes)
                        .find(|axis| row_cells[*axis].is_none())
                        .map_or(POSITIONER_COLUMNS[0], |axis| POSITIONER_COLUMNS[axis]);
                    Err(StageError::Invalid(format!(
                        "{}: row {row} measured the positioner's nest `{nest}`, so it needs the positioner's axis value in column `{missing}` (deg)",
                        path.display()
                    )))
                }
            }
        })
        .collect()
}

/// Each target row's positioner axis values (deg) where the row gives all
/// of them (`None` where it gives none); a row giving some but not all is
/// refused, naming it.
pub(crate) fn positioner_axes_of_targets(
    df: &DataFrame,
    path: &Path,
    robot: &RobotSpec,
) -> Result<Vec<Option<[f64; MAX_POSITIONER_AXES]>>, StageError> {
    let Some(cells) = axis_cells(df, path, robot)? else {
        return Ok(vec![None; df.height()]);
    };
    let axes = robot.positioner.as_ref().map_or(0, |p| p.axes.len());
    cells
        .iter()
        .enumerate()
        .map(|(row, row_cells)| {
            let given = row_cells[..axes].iter().filter(|c| c.is_some()).count();
            match given {
                0 => Ok(None),
                n if n == axes => Ok(complete(row_cells, axes)),
                _ => Err(StageError::Invalid(format!(
                    "{}: row {row}: gives {} of the positioner's axes; give all of {} or none",
                    path.display(),
                    given,
                    POSITIONER_COLUMNS[..axes].join(", ")
                ))),
            }
        })
        .collect()
}
