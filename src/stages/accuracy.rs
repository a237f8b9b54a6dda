//! `accuracy`: how close the robot came to its targets. Compares the tool points
//! measured while the robot ran a set of commands (a `measure` stage whose rows'
//! `cw_id` is the `target_id`) with the targets, and, when the same targets were
//! also run without compensation (`baseline`), both, on the same targets. This is
//! the closed loop of a compensation: the number a user buys a calibration for.

use std::collections::HashMap;

use nalgebra::Vector3;
use polars::prelude::Column;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::identify::measured_rows;
use super::validate::TestColumns;
use super::{InputTable, Stage, StageContext, StageError, StageInfo, StageOutputs, TableSlot};
use crate::stats;
use crate::table::frame;
use crate::table::schema::{self, POSITION_COLUMNS, f64_values, i64_values};

pub struct AccuracyStage;

/// Farthest a target may lie from the origin of its frame (mm), as in a robot
/// file's lengths: a larger number is a unit or a typing error.
const MAX_POSITION_MM: f64 = crate::robot::file::MAX_LENGTH_MM;

/// Settings of `accuracy`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct AccuracySettings {
    /// A measured point farther than this from its target (mm) refuses the
    /// run: it was another target, another frame or another unit, not an error
    /// of the robot. The default, 50 mm, is ten times what an uncalibrated
    /// industrial arm misses by.
    #[schemars(range(max = 100_000.0))]
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub max_error_mm: f64,
}

impl Default for AccuracySettings {
    fn default() -> Self {
        Self { max_error_mm: 50.0 }
    }
}

type TwoSampleTest = fn(&[f64], &[f64]) -> Result<stats::TestResult, stats::StatsError>;

static INFO: StageInfo = StageInfo {
    kind: "accuracy",
    uses_cable_robot: false,
    updates_input: None,
    summary: "Position errors the robot achieved at its targets, with and without compensation",
    code_version: 2,
    inputs: &[
        TableSlot {
            name: "targets",
            schema: schema::targets,
            required: true,
            meaning: "where the tool had to be (world frame)",
        },
        TableSlot {
            name: "achieved",
            schema: schema::measurements,
            required: true,
            meaning: "tool points measured while running the commands; cw_id = target_id",
        },
        TableSlot {
            name: "baseline",
            schema: schema::measurements,
            required: false,
            meaning: "the same targets run without compensation (the controller's nominal IK)",
        },
    ],
    outputs: &[
        TableSlot {
            name: "target_errors",
            schema: schema::target_errors,
            required: true,
            meaning: "per target and run: error components and norm",
        },
        TableSlot {
            name: "target_stats",
            schema: schema::target_stats,
            required: true,
            meaning: "per run, over the targets every run reached: n, missing, mean, std, median, rms, p95, max",
        },
        TableSlot {
            name: "tests",
            schema: schema::tests,
            required: true,
            meaning: "with a baseline: paired t and Wilcoxon tests of achieved against baseline error norms (empty without)",
        },
    ],
};

impl Stage for AccuracyStage {
    type Settings = AccuracySettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &AccuracySettings,
    ) -> Result<StageOutputs, StageError> {
        let targets = ctx.input("targets")?;
        super::compensate::world_frame_rows_only(targets, "accuracy")?;
        let targets = target_points(targets)?;
        let mut runs = vec![("achieved", ctx.input("achieved")?)];
        if let Some(baseline) = ctx.inputs.get("baseline") {
            runs.push(("baseline", baseline));
        }
        let mut errors = ErrorColumns::default();
        let mut norms_by_run = Vec::with_capacity(runs.len());
        for (run, table) in &runs {
            norms_by_run.push(run_errors(
                run,
                table,
                ctx.robot.spec(),
                &targets.points,
                settings.max_error_mm,
                &mut errors,
            )?);
        }
        // Compared on the targets every run reached: a compensation that
        // leaves out its unreachable targets must not look better for it.
        let compared: Vec<i64> = targets
            .order
            .iter()
            .copied()
            .filter(|id| norms_by_run.iter().all(|norms| norms.contains_key(id)))
            .collect();
        let mut outputs = StageOutputs::default();
        let mut stats_columns = StatsColumns::default();
        let mut compared_norms = Vec::with_capacity(runs.len());
        for ((run, table), norms) in runs.iter().zip(&norms_by_run) {
            let values: Vec<f64> = compared.iter().map(|id| norms[id]).collect();
            let summary = stats::summary(&values).map_err(|e| {
                StageError::Invalid(format!(
                    "{}: {run}: {e} (targets measured in every run)",
                    table.path.display()
                ))
            })?;
            let missing = targets.order.len() - norms.len();
            stats_columns.push(run, &summary, missing);
            outputs.facts.insert(
                format!("{run}_mean_mm"),
                format!("{:.4} over {} targets", summary.mean, summary.n),
            );
            ctx.progress.note(&format!(
                "{run}: mean {:.4} mm, max {:.4} mm over {} targets ({missing} not measured)",
                summary.mean, summary.max, summary.n
            ));
            compared_norms.push(values);
        }
        let mut tests = TestColumns::default();
        if let [achieved, baseline] = compared_norms.as_slice() {
            for (name, test) in [
                ("paired_t", stats::paired_t as TwoSampleTest),
                ("wilcoxon", stats::wilcoxon_signed_rank),
            ] {
                match test(achieved, baseline) {
                    Ok(result) => tests.push("achieved", "baseline", name, &result),
                    Err(err) => ctx
                        .progress
                        .note(&format!("{name} achieved vs baseline: {err}")),
                }
            }
        }
        outputs
            .tables
            .insert("target_errors".into(), errors.into_frame());
        outputs
            .tables
            .insert("target_stats".into(), stats_columns.into_frame());
        outputs.tables.insert("tests".into(), tests.into_frame());
        Ok(outputs)
    }
}

/// The targets' points (world frame, mm) and their order in the table.
struct TargetPoints {
    points: HashMap<i64, Vector3<f64>>,
    order: Vec<i64>,
}

fn target_points(table: &InputTable) -> Result<TargetPoints, StageError> {
    let ids = i64_values(&table.df, "target_id", &table.path)?;
    let axes = POSITION_COLUMNS
        .iter()
        .map(|c| f64_values(&table.df, c, &table.path))
        .collect::<Result<Vec<_>, _>>()?;
    let mut points = HashMap::with_capacity(ids.len());
    for (k, id) in ids.iter().enumerate() {
        let point = Vector3::new(axes[0][k], axes[1][k], axes[2][k]);
        if let Some(axis) = (0..3).find(|a| point[*a].abs() > MAX_POSITION_MM) {
            return Err(StageError::Invalid(format!(
                "{}: row {k} (target_id {id}): {} = {} lies beyond ±{MAX_POSITION_MM} mm; expected a point of the robot's cell in mm",
                table.path.display(),
                POSITION_COLUMNS[axis],
                crate::calibration::row_checks::compact(point[axis])
            )));
        }
        if points.insert(*id, point).is_some() {
            return Err(StageError::Invalid(format!(
                "{}: row {k}: target_id {id} appears twice",
                table.path.display()
            )));
        }
    }
    Ok(TargetPoints { points, order: ids })
}

/// Appends one run's errors; returns each target's error norm. A measured row
/// whose cw_id is no target is bad input (the run was not of these targets),
/// and so is a target measured twice (which of the two was achieved?).
fn run_errors(
    run: &'static str,
    table: &InputTable,
    robot: &crate::robot::RobotSpec,
    targets: &HashMap<i64, Vector3<f64>>,
    max_error_mm: f64,
    errors: &mut ErrorColumns,
) -> Result<HashMap<i64, f64>, StageError> {
    let rows = measured_rows(table, robot, None)?;
    let mut norms = HashMap::with_capacity(rows.ids.len());
    for (k, id) in rows.ids.iter().enumerate() {
        let target = targets.get(id).ok_or_else(|| {
            StageError::Invalid(format!(
                "{}: row {} has cw_id {id}, which is no target_id of the targets table",
                table.path.display(),
                rows.file_rows[k]
            ))
        })?;
        if let Some(axis) = (0..3).find(|a| rows.positions[k][*a].abs() > MAX_POSITION_MM) {
            return Err(StageError::Invalid(format!(
                "{}: row {} (cw_id {id}): {} = {} lies beyond ±{MAX_POSITION_MM} mm; expected a tracker reading in mm",
                table.path.display(),
                rows.file_rows[k],
                POSITION_COLUMNS[axis],
                crate::calibration::row_checks::compact(rows.positions[k][axis])
            )));
        }
        let error = rows.positions[k] - target;
        if error.norm().is_nan() || error.norm() > max_error_mm {
            return Err(StageError::Invalid(format!(
                "{}: row {} (cw_id {id}): the measured point lies {} mm from its target, more than max_error_mm = {max_error_mm}: another target, frame or unit? (raise the setting if the robot really missed by that much)",
                table.path.display(),
                rows.file_rows[k],
                crate::calibration::row_checks::compact(error.norm())
            )));
        }
        if norms.insert(*id, error.norm()).is_some() {
            return Err(StageError::Invalid(format!(
                "{}: row {}: target {id} was measured twice; keep one row per target",
                table.path.display(),
                rows.file_rows[k]
            )));
        }
        errors.target_id.push(*id);
        errors.run.push(run);
        errors.ex.push(error.x);
        errors.ey.push(error.y);
        errors.ez.push(error.z);
        errors.norm.push(error.norm());
    }
    Ok(norms)
}

#[derive(Default)]
struct ErrorColumns {
    target_id: Vec<i64>,
    run: Vec<&'static str>,
    ex: Vec<f64>,
    ey: Vec<f64>,
    ez: Vec<f64>,
    norm: Vec<f64>,
}

impl ErrorColumns {
    fn into_frame(self) -> polars::prelude::DataFrame {
        frame(vec![
            Column::new("target_id".into(), self.target_id),
            Column::new("run".into(), self.run),
            Column::new("ex_mm".into(), self.ex),
            Column::new("ey_mm".into(), self.ey),
            Column::new("ez_mm".into(), self.ez),
            Column::new("error_mm".into(), self.norm),
        ])
    }
}

#[derive(Default)]
struct StatsColumns {
    run: Vec<&'static str>,
    n: Vec<i64>,
    missing: Vec<i64>,
    summaries: Vec<stats::Summary>,
}

impl StatsColumns {
    fn push(&mut self, run: &'static str, summary: &stats::Summary, missing: usize) {
        self.run.push(run);
        self.n.push(summary.n as i64);
        self.missing.push(missing as i64);
        self.summaries.push(*summary);
    }

    fn into_frame(self) -> polars::prelude::DataFrame {
        let column = |name: &str, value: fn(&stats::Summary) -> f64| {
            Column::new(
                name.into(),
                self.summaries.iter().map(value).collect::<Vec<_>>(),
            )
        };
        frame(vec![
            Column::new("run".into(), self.run),
            Column::new("n".into(), self.n),
            Column::new("missing".into(), self.missing),
            column("mean_mm", |s| s.mean),
            column("std_mm", |s| s.std),
            column("median_mm", |s| s.median),
            column("rms_mm", |s| s.rms),
            column("p95_mm", |s| s.p95),
            column("max_mm", |s| s.max),
        ])
    }
}
