//! `split`: divides measured rows into calibration and validation rows (a
//! `selection` table), for data that were not designed by `select`: an imported
//! tracker export is identified on one part and validated on the other.
//!
//! Deterministic by construction: `alternate` and `halves` depend only on the
//! row order, so the same export always splits the same way.
//!
//! The grouped methods (issue #28) validate on whole groups of rows instead:
//! a block of the workspace (`region`), a cluster of joint configurations
//! (`configuration`), a bin of loads (`load`) or a stretch of time (`time`),
//! the calibration never having seen anything like them
//! ([`crate::calibration::groups`]); reproducible from the job's seed.

use polars::prelude::Column;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::held_out::fold_assignment;
use super::identify::measured_rows;
use super::{
    SettingsContext, SettingsProblem, Stage, StageContext, StageError, StageInfo, StageOutputs,
    TableSlot,
};
use crate::calibration::groups::Grouping;
use crate::table::frame;
use crate::table::schema::{self, i64_values};

pub struct SplitStage;

/// How rows are divided.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum SplitMethod {
    /// Rows in turn: every other row (in file order) is a calibration row; both
    /// parts span the whole session, so slow drift affects them alike.
    Alternate,
    /// The first rows calibrate, the rest validate: a harder test when the robot
    /// or the cell drifts during the session.
    Halves,
    /// Whole blocks of the workspace validate (k-means on the measured positions).
    Region,
    /// Whole clusters of joint configurations validate (k-means in joint space).
    Configuration,
    /// Whole bins of the wrench validate.
    Load,
    /// Whole stretches of `measured_at` validate.
    Time,
}

impl SplitMethod {
    /// The grouping of a grouped method.
    fn grouping(self) -> Option<Grouping> {
        match self {
            SplitMethod::Alternate | SplitMethod::Halves => None,
            SplitMethod::Region => Some(Grouping::Region),
            SplitMethod::Configuration => Some(Grouping::Configuration),
            SplitMethod::Load => Some(Grouping::Load),
            SplitMethod::Time => Some(Grouping::Time),
        }
    }
}

/// Settings of `split`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct SplitSettings {
    /// alternate (default) or halves; or, validating on whole groups of rows:
    /// region, configuration, load or time.
    pub method: SplitMethod,
    /// alternate, halves: fraction of the rows that calibrate, in (0, 1).
    #[schemars(extend("exclusiveMinimum" = 0.0, "exclusiveMaximum" = 1.0))]
    pub calibration_fraction: f64,
    /// Grouped methods: groups the rows fall into.
    #[schemars(range(min = 2, max = 50))]
    pub groups: usize,
    /// Grouped methods: how many of the groups validate (the rest calibrate).
    #[schemars(range(min = 1, max = 49))]
    pub validation_groups: usize,
}

impl Default for SplitSettings {
    fn default() -> Self {
        SplitSettings {
            method: SplitMethod::Alternate,
            calibration_fraction: 0.5,
            groups: 5,
            validation_groups: 1,
        }
    }
}

static INFO: StageInfo = StageInfo {
    kind: "split",
    uses_cable_robot: false,
    updates_input: None,
    summary: "Calibration and validation rows of measured data (alternate rows, halves, or whole groups by region, configuration, load or time)",
    code_version: 3,
    inputs: &[TableSlot {
        name: "measurements",
        schema: schema::measurements,
        required: true,
        meaning: "measured rows (spec §6)",
    }],
    outputs: &[TableSlot {
        name: "selection",
        schema: schema::selection,
        required: true,
        meaning: "role of each row: calibration or validation",
    }],
};

/// Whether row `k` of `n` calibrates.
fn calibrates(method: SplitMethod, fraction: f64, k: usize, n: usize) -> bool {
    match method {
        // Row k calibrates when it carries the running count of calibration rows
        // past an integer: exactly round(fraction·n) rows, spread evenly.
        SplitMethod::Alternate => {
            ((k + 1) as f64 * fraction).floor() > (k as f64 * fraction).floor()
        }
        SplitMethod::Halves => (k as f64) < (fraction * n as f64).round(),
        // Grouped methods split by group, not by row position.
        SplitMethod::Region
        | SplitMethod::Configuration
        | SplitMethod::Load
        | SplitMethod::Time => false,
    }
}

impl Stage for SplitStage {
    type Settings = SplitSettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn check_settings(
        &self,
        settings: &SplitSettings,
        _: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        if settings.method.grouping().is_some() && settings.validation_groups >= settings.groups {
            return vec![SettingsProblem::new(
                "validation_groups",
                format!(
                    "`validation_groups` ({}) must be fewer than `groups` ({}): some groups must calibrate",
                    settings.validation_groups, settings.groups
                ),
            )];
        }
        Vec::new()
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &SplitSettings,
    ) -> Result<StageOutputs, StageError> {
        let fraction = settings.calibration_fraction;
        let input = ctx.input("measurements")?;
        let (ids, roles, groups) = match settings.method.grouping() {
            None => {
                let ids = i64_values(&input.df, "cw_id", &input.path)?;
                let n = ids.len();
                let roles: Vec<&str> = (0..n)
                    .map(|k| {
                        if calibrates(settings.method, fraction, k, n) {
                            "calibration"
                        } else {
                            "validation"
                        }
                    })
                    .collect();
                (ids, roles, None)
            }
            Some(grouping) => {
                let data = measured_rows(input, ctx.robot.spec(), None)?;
                // One group per fold: fold g is group g, dealt by size.
                let folds =
                    fold_assignment(&data, grouping, settings.groups, ctx.seed).map_err(|e| {
                        StageError::Invalid(format!(
                            "{}: setting `method` = {}: {e}",
                            input.path.display(),
                            grouping
                        ))
                    })?;
                let roles = folds
                    .fold_of_row
                    .iter()
                    .map(|g| {
                        if *g < settings.validation_groups {
                            "validation"
                        } else {
                            "calibration"
                        }
                    })
                    .collect();
                let groups: Vec<i64> = folds.fold_of_row.iter().map(|g| *g as i64).collect();
                (data.ids, roles, Some(groups))
            }
        };
        let n = ids.len();
        let calibration = roles.iter().filter(|r| **r == "calibration").count();
        if calibration == 0 || calibration == n {
            return Err(StageError::Invalid(format!(
                "{}: {n} rows split at {fraction} leave one part empty",
                input.path.display()
            )));
        }
        let mut outputs = StageOutputs::default();
        outputs
            .facts
            .insert("calibration_rows".into(), calibration.to_string());
        outputs
            .facts
            .insert("validation_rows".into(), (n - calibration).to_string());
        let mut columns = vec![
            Column::new("cw_id".into(), ids),
            Column::new("role".into(), roles),
        ];
        if let Some(groups) = groups {
            columns.push(Column::new("group".into(), groups));
        }
        outputs.tables.insert("selection".into(), frame(columns));
        Ok(outputs)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pattern(method: SplitMethod, fraction: f64, n: usize) -> String {
        (0..n)
            .map(|k| {
                if calibrates(method, fraction, k, n) {
                    'c'
                } else {
                    'v'
                }
            })
            .collect()
    }

    #[test]
    fn alternate_spreads_the_calibration_rows_evenly() {
        assert_eq!(pattern(SplitMethod::Alternate, 0.5, 7), "vcvcvcv");
        assert_eq!(pattern(SplitMethod::Alternate, 1.0 / 3.0, 6), "vvcvvc");
        let count = pattern(SplitMethod::Alternate, 0.3, 1000)
            .matches('c')
            .count();
        assert_eq!(count, 300);
    }

    #[test]
    fn halves_take_the_first_rows() {
        assert_eq!(pattern(SplitMethod::Halves, 0.5, 7), "ccccvvv");
        assert_eq!(pattern(SplitMethod::Halves, 0.25, 8), "ccvvvvvv");
    }
}
