//! `gate`: the acceptance gate of a nightly re-calibration (see [`crate::gate`]).
//!
//! Compares the night's candidate parameters with the set in service on the
//! scanned window: each parameter's change in units of its standard error, the
//! predicted position change over reference poses, the hold-out error of both with
//! a paired t-test, and each day's error (where a rise of the in-service error
//! shows the day the robot changed). Then decides, and when it publishes, installs
//! the candidate's file as `<publish_dir>/current.parquet` ([`crate::publish`]).
//!
//! This is the one stage with an effect outside its output folder: publishing is
//! its purpose. A cached gate does not publish again, which is right: a cache hit
//! means the same candidate against the same in-service file, already decided.
//! The decision also sets the exit code of `egcal run` (the guide's exit codes, docs/reference/commands.md).

use std::collections::{BTreeMap, HashSet};
use std::path::{Path, PathBuf};

use polars::prelude::{Column, DataType};
use rayon::prelude::*;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::identify::{MeasuredRows, ids_with_role, measured_rows};
use super::{
    InputTable, SettingsContext, SettingsProblem, Stage, StageContext, StageError, StageInfo,
    StageOutputs, TableSlot, model_name_problem,
};
use crate::gate::{self, ChangePoint, Decision, Holdout, Rules};
use crate::robot::{ConfWrench, ParamId, batch_predict};
use crate::table::parameters::{self, ModelName, ParamStatus, ParameterSet};
use crate::table::time::date_string;
use crate::table::{frame, schema};

pub struct GateStage;

/// Settings of `gate`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct GateSettings {
    /// The model of both tables that is compared and put in service.
    pub model: String,
    /// Significance level of the paired t-test on hold-out errors.
    #[schemars(extend("exclusiveMinimum" = 0.0, "exclusiveMaximum" = 1.0))]
    pub alpha: f64,
    /// Smallest mean hold-out improvement worth publishing (mm).
    #[schemars(range(max = 1000.0))]
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub min_improvement_mm: f64,
    /// The in-service set has drifted when the candidate moves a reference pose's
    /// predicted position by more than this (mm).
    #[schemars(range(max = 1000.0))]
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub drift_threshold_mm: f64,
    /// Fewest hold-out rows the comparison needs.
    #[schemars(range(min = 1, max = 1_000_000_000))]
    pub min_holdout_rows: usize,
    /// Calibration folder, relative to the job file: a published candidate becomes
    /// `current.parquet` there. Empty: decide and report only.
    pub publish_dir: String,
}

impl Default for GateSettings {
    fn default() -> Self {
        GateSettings {
            model: ModelName::Elastogeometric.as_str().into(),
            alpha: 0.01,
            min_improvement_mm: 0.02,
            drift_threshold_mm: 0.15,
            min_holdout_rows: 20,
            publish_dir: String::new(),
        }
    }
}

static INFO: StageInfo = StageInfo {
    kind: "gate",
    uses_cable_robot: false,
    updates_input: Some("in_service"),
    summary: "Compare the night's calibration with the one in service; publish it only when it is better or the old one drifted",
    code_version: 5,
    inputs: &[
        TableSlot {
            name: "measurements",
            schema: schema::measurements,
            required: true,
            meaning: "the scanned window's rows (with measured_at for the daily errors)",
        },
        TableSlot {
            name: "selection",
            schema: schema::selection,
            required: true,
            meaning: "rows with role = validation are the hold-out",
        },
        TableSlot {
            name: "candidate",
            schema: schema::parameters,
            required: true,
            meaning: "the night's identified parameters",
        },
        TableSlot {
            name: "in_service",
            schema: schema::parameters,
            required: true,
            meaning: "the calibration in service (usually <publish_dir>/current.parquet)",
        },
        TableSlot {
            name: "reference",
            schema: schema::conf_wrenches,
            required: false,
            meaning: "poses and loads where position changes matter; the window's rows when absent",
        },
    ],
    outputs: &[
        TableSlot {
            name: "decision",
            schema: schema::gate_decision,
            required: true,
            meaning: "kept, published or refused, with the reasons and numbers",
        },
        TableSlot {
            name: "parameter_changes",
            schema: schema::parameter_changes,
            required: true,
            meaning: "each identified parameter's change in units of its standard error",
        },
        TableSlot {
            name: "daily_errors",
            schema: schema::daily_errors,
            required: true,
            meaning: "mean error of both sets per logged day",
        },
    ],
};

impl GateSettings {
    /// The decision rules; their ranges are the settings' (checked in phase 2).
    fn rules(&self) -> Rules {
        Rules {
            alpha: self.alpha,
            min_improvement_mm: self.min_improvement_mm,
            drift_threshold_mm: self.drift_threshold_mm,
        }
    }
}

/// The set an interrupted run of this night replaced, when that run published the
/// candidate and was killed before it finished: `current.parquet` holds the
/// candidate's bytes and `retired-<run date>[-N].parquet` (the newest) the set it
/// replaced. Deciding against that set again gives the interrupted run's decision
/// instead of comparing the candidate with itself.
fn interrupted_publication(
    dir: &Path,
    candidate: &Path,
    run_date: i64,
) -> Result<Option<InputTable>, StageError> {
    let read = |path: &Path| std::fs::read(path).ok();
    let current = dir.join(crate::publish::CURRENT);
    match (read(&current), read(candidate)) {
        (Some(a), Some(b)) if a == b => {}
        _ => return Ok(None),
    }
    let Some(retired) = crate::publish::newest_retired(dir, run_date) else {
        return Ok(None);
    };
    let df = crate::table::read_parquet(&retired)?;
    Ok(Some(InputTable { path: retired, df }))
}

fn model_set(
    table: &InputTable,
    model: ModelName,
    robot: &crate::robot::RobotSpec,
) -> Result<ParameterSet, StageError> {
    // The calibration in service is one parameters table; a residual model
    // beside it would not travel with it, and predictions without it are
    // another model's.
    if model.has_residual_model() {
        return Err(StageError::Invalid(format!(
            "{}: `{model}` cannot be gated into service: its residual model is a second table the published calibration does not carry; gate `{}` (its parameters) instead",
            table.path.display(),
            ModelName::EgHarmonic
        )));
    }
    let sets = parameters::from_frame(&table.df, &table.path, robot)?;
    let available: Vec<&str> = sets.iter().map(|s| s.model.as_str()).collect();
    sets.iter()
        .find(|s| s.model == model)
        .cloned()
        .ok_or_else(|| {
            StageError::Invalid(format!(
                "{}: no `{model}` parameters (the table has: {}); set `model`",
                table.path.display(),
                available.join(", ")
            ))
        })
}

/// Error norms of `set` on the rows (mm), each row with its own target's tool.
///
/// Row by row on the threads, without aimed copies of the rows or whole
/// predictions: on a million-row window those were 0.6 GB of fresh memory
/// per set, whose page faults cost more than the predictions (issue #31).
fn error_norms(
    ctx: &StageContext,
    set: &ParameterSet,
    rows: &MeasuredRows,
    file: &Path,
) -> Result<Vec<f64>, StageError> {
    let targets = set
        .target_indices(rows.target_ids.as_deref(), rows.rows.len())
        .map_err(|m| StageError::Invalid(format!("{}: {m}", file.display())))?;
    let prepared = ctx.robot.prepare(&set.values);
    Ok(rows
        .rows
        .par_iter()
        .zip(&targets)
        .zip(&rows.positions)
        .with_min_len(crate::calibration::stream::CHUNK_ROWS)
        .map(|((row, target), measured_mm)| {
            let aimed = ConfWrench {
                target: *target,
                ..*row
            };
            (prepared.predict_row(&aimed).position_mm - measured_mm).norm()
        })
        .collect())
}

/// `rows` with each one's target index in `set` (spec §8).
fn aimed_rows(
    set: &ParameterSet,
    rows: &[ConfWrench],
    target_ids: Option<&[Option<String>]>,
    file: &Path,
) -> Result<Vec<ConfWrench>, StageError> {
    let targets = set
        .target_indices(target_ids, rows.len())
        .map_err(|m| StageError::Invalid(format!("{}: {m}", file.display())))?;
    let mut aimed = rows.to_vec();
    for (row, target) in aimed.iter_mut().zip(targets) {
        row.target = target;
    }
    Ok(aimed)
}

/// UTC day of each row from `measured_at`, when the table has it.
fn row_days(table: &InputTable) -> Result<Option<Vec<i64>>, StageError> {
    let Ok(column) = table.df.column("measured_at") else {
        return Ok(None);
    };
    let micros = column
        .cast(&DataType::Int64)
        .and_then(|c| c.i64().cloned())
        .map_err(|e| StageError::Invalid(format!("{}: measured_at: {e}", table.path.display())))?;
    Ok(Some(
        micros
            .iter()
            .map(|us| us.map_or(i64::MIN, |us| us.div_euclid(86_400_000_000)))
            .collect(),
    ))
}

impl Stage for GateStage {
    type Settings = GateSettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn check_settings(&self, settings: &GateSettings, _: &SettingsContext) -> Vec<SettingsProblem> {
        model_name_problem("model", &settings.model)
            .into_iter()
            .collect()
    }

    fn run(&self, ctx: &StageContext, settings: &GateSettings) -> Result<StageOutputs, StageError> {
        let rules = settings.rules();
        let model: ModelName = settings
            .model
            .parse()
            .map_err(|e: String| StageError::Invalid(format!("setting `model`: {e}")))?;
        let candidate_table = ctx.input("candidate")?;
        let candidate = model_set(candidate_table, model, ctx.robot.spec())?;
        let publish_dir =
            (!settings.publish_dir.is_empty()).then(|| ctx.job_dir.join(&settings.publish_dir));
        let resumed = match &publish_dir {
            Some(dir) => interrupted_publication(dir, &candidate_table.path, ctx.run_date)?,
            None => None,
        };
        let in_service = match &resumed {
            Some(retired) => {
                ctx.progress.note(&format!(
                    "an earlier run of this night published the candidate and was interrupted; deciding again against the set it replaced, {}",
                    retired.path.display()
                ));
                model_set(retired, model, ctx.robot.spec())?
            }
            None => model_set(ctx.input("in_service")?, model, ctx.robot.spec())?,
        };

        let measurements = ctx.input("measurements")?;
        let mut window = measured_rows(measurements, ctx.robot.spec(), None)?;
        let holdout_ids = ids_with_role(ctx.input("selection")?, "validation")?;
        let left_out = window.leave_out_bad_rows(ctx.robot, &measurements.path);
        // The hold-out rows are window rows: taken from the converted and
        // checked window rather than converting the table again.
        let in_holdout: Vec<bool> = window
            .ids
            .iter()
            .map(|id| holdout_ids.contains(id))
            .collect();
        let holdout = window.subset(&in_holdout);
        if let Some(summary) = &left_out {
            ctx.progress.note(&format!("warning: {summary}"));
        }
        if holdout.ids.len() < settings.min_holdout_rows.max(2) {
            return Err(StageError::Invalid(format!(
                "the hold-out has {} rows, fewer than min_holdout_rows = {}: widen the window or hold out more days",
                holdout.ids.len(),
                settings.min_holdout_rows.max(2)
            )));
        }
        let file = measurements.path.as_path();
        let comparison = Holdout::compare(
            &error_norms(ctx, &in_service, &holdout, file)?,
            &error_norms(ctx, &candidate, &holdout, file)?,
        )
        .map_err(|e| StageError::Failed(format!("hold-out comparison: {e}")))?;

        // The reference rows aimed by each set with its own targets' tools.
        let (in_service_reference, candidate_reference) = match ctx.inputs.get("reference") {
            Some(table) => {
                let rows = super::commanded_rows(ctx, table)?.1;
                let mut a = rows.clone();
                super::aim_rows(table, &in_service, &mut a)?;
                let mut b = rows;
                super::aim_rows(table, &candidate, &mut b)?;
                (a, b)
            }
            None => (
                aimed_rows(
                    &in_service,
                    &window.rows,
                    window.target_ids.as_deref(),
                    file,
                )?,
                aimed_rows(&candidate, &window.rows, window.target_ids.as_deref(), file)?,
            ),
        };
        let changes: Vec<f64> = batch_predict(ctx.robot, &in_service.values, &in_service_reference)
            .iter()
            .zip(batch_predict(
                ctx.robot,
                &candidate.values,
                &candidate_reference,
            ))
            .map(|(a, b)| (a.position_mm - b.position_mm).norm())
            .collect();
        let max_change = changes.iter().copied().fold(0.0, f64::max);
        let mean_change = changes.iter().sum::<f64>() / changes.len().max(1) as f64;

        let (decision, mut reasons) = gate::decide(&comparison, max_change, &rules);
        let daily = Daily::new(
            row_days(measurements)?,
            &window,
            &holdout_ids,
            &error_norms(ctx, &in_service, &window, file)?,
            &error_norms(ctx, &candidate, &window, file)?,
        );
        let drift = daily.change_point(&rules);
        if let Some(point) = &drift {
            reasons.push(format!(
                "the in-service error rose from {:.3} mm to {:.3} mm on {} (Welch t = {:.1}, p = {:.1e})",
                point.mean_before_mm,
                point.mean_after_mm,
                date_string(point.day),
                point.welch_t.statistic,
                point.welch_t.p_value
            ));
            if daily.calibration_days_from(point.day) && daily.calibration_days_before(point.day) {
                reasons.push(format!(
                    "the candidate was identified on days before and after {}: a window starting then would fit the robot as it is now",
                    date_string(point.day)
                ));
            }
        }

        let mut published_as = None;
        let mut retired_as = None;
        let install = |dir: &Path, path: &Path| {
            let bytes = std::fs::read(path)
                .map_err(|e| StageError::Failed(format!("reading {}: {e}", path.display())))?;
            let installed = crate::publish::install(dir, &bytes, ctx.run_date).map_err(|e| {
                StageError::Failed(format!("publishing into {}: {e}", dir.display()))
            })?;
            if let Some(summary) = installed.swept.summary(dir) {
                ctx.progress.note(&format!("{}: {summary}", dir.display()));
            }
            Ok::<_, StageError>(installed)
        };
        match (&publish_dir, &resumed, decision) {
            (Some(dir), None, Decision::Published) => {
                let installed = install(dir, &candidate_table.path)?;
                reasons.push(format!("published as {}", installed.current.display()));
                published_as = Some(installed.current.display().to_string());
                retired_as = installed.retired.map(|p: PathBuf| p.display().to_string());
            }
            // Installed by the interrupted run: reported as that run would have.
            (Some(dir), Some(retired), Decision::Published) => {
                let current = dir.join(crate::publish::CURRENT);
                reasons.push(format!("published as {}", current.display()));
                published_as = Some(current.display().to_string());
                retired_as = Some(retired.path.display().to_string());
            }
            // The inputs changed since the interrupted run: the set it replaced
            // goes back in service, as this decision says.
            (Some(dir), Some(retired), _) => {
                install(dir, &retired.path)?;
                ctx.progress.note(&format!(
                    "put {} back in service: this run does not confirm the interrupted run's publication",
                    retired.path.display()
                ));
            }
            _ => {}
        }

        for reason in &reasons {
            ctx.progress.note(reason);
        }
        let mut outputs = StageOutputs::default();
        outputs
            .facts
            .insert("decision".into(), decision.as_str().into());
        if let Some(summary) = left_out {
            outputs.facts.insert("rows_left_out".into(), summary);
        }
        outputs.facts.insert(
            "holdout_mean_mm".into(),
            format!(
                "{:.3} -> {:.3}",
                comparison.in_service_mean_mm, comparison.candidate_mean_mm
            ),
        );
        outputs
            .facts
            .insert("max_position_change_mm".into(), format!("{max_change:.3}"));
        let t = comparison.paired_t;
        let decision_row = frame(vec![
            Column::new("decision".into(), [decision.as_str()]),
            Column::new("reasons".into(), [reasons.join("\n")]),
            Column::new("model".into(), [model.as_str()]),
            Column::new("holdout_rows".into(), [comparison.rows as i64]),
            Column::new("in_service_mean_mm".into(), [comparison.in_service_mean_mm]),
            Column::new("candidate_mean_mm".into(), [comparison.candidate_mean_mm]),
            Column::new("t_statistic".into(), [t.map(|t| t.statistic)]),
            Column::new("dof".into(), [t.and_then(|t| t.dof)]),
            Column::new("p_value".into(), [t.map(|t| t.p_value)]),
            Column::new("mean_position_change_mm".into(), [mean_change]),
            Column::new("max_position_change_mm".into(), [max_change]),
            Column::new(
                "drift_since".into(),
                [drift.as_ref().map(|p| date_string(p.day))],
            ),
            Column::new("published_as".into(), [published_as]),
            Column::new("retired_as".into(), [retired_as]),
        ]);
        outputs.files.insert(
            "decision.md".into(),
            summary(
                decision,
                model,
                &reasons,
                &candidate,
                &in_service,
                &ctx.robot.prismatic_joints(),
            )
            .into_bytes(),
        );
        outputs.tables.insert("decision".into(), decision_row);
        outputs.tables.insert(
            "parameter_changes".into(),
            parameter_changes(&candidate, &in_service, &ctx.robot.prismatic_joints()),
        );
        outputs
            .tables
            .insert("daily_errors".into(), daily.into_frame());
        Ok(outputs)
    }
}

/// One logged day's rows.
#[derive(Default)]
struct Day {
    rows: usize,
    /// Whether any of its rows is held out.
    holdout: bool,
    in_service_sum_mm: f64,
    candidate_sum_mm: f64,
}

/// Rows grouped by logged day.
struct Daily {
    days: BTreeMap<i64, Day>,
    /// Per row: day and in-service error, for the change point.
    row_days: Vec<i64>,
    in_service_mm: Vec<f64>,
}

impl Daily {
    fn new(
        days: Option<Vec<i64>>,
        window: &MeasuredRows,
        holdout: &HashSet<i64>,
        in_service_mm: &[f64],
        candidate_mm: &[f64],
    ) -> Daily {
        let mut grouped = BTreeMap::new();
        let Some(days) = days else {
            return Daily {
                days: grouped,
                row_days: Vec::new(),
                in_service_mm: Vec::new(),
            };
        };
        for (k, id) in window.ids.iter().enumerate() {
            let day: &mut Day = grouped.entry(days[k]).or_default();
            day.rows += 1;
            day.holdout |= holdout.contains(id);
            day.in_service_sum_mm += in_service_mm[k];
            day.candidate_sum_mm += candidate_mm[k];
        }
        Daily {
            days: grouped,
            row_days: days,
            in_service_mm: in_service_mm.to_vec(),
        }
    }

    fn change_point(&self, rules: &Rules) -> Option<ChangePoint> {
        gate::change_point(
            &self.row_days,
            &self.in_service_mm,
            rules.alpha,
            rules.min_improvement_mm,
        )
    }

    fn calibration_days_from(&self, day: i64) -> bool {
        self.days.range(day..).any(|(_, d)| !d.holdout)
    }

    fn calibration_days_before(&self, day: i64) -> bool {
        self.days.range(..day).any(|(_, d)| !d.holdout)
    }

    fn into_frame(self) -> polars::prelude::DataFrame {
        let mut date = Vec::new();
        let mut rows = Vec::new();
        let mut role = Vec::new();
        let mut in_service = Vec::new();
        let mut candidate = Vec::new();
        for (day, sums) in self.days {
            let n = sums.rows as f64;
            date.push(date_string(day));
            rows.push(sums.rows as i64);
            role.push(if sums.holdout {
                "validation"
            } else {
                "calibration"
            });
            in_service.push(sums.in_service_sum_mm / n);
            candidate.push(sums.candidate_sum_mm / n);
        }
        frame(vec![
            Column::new("date".into(), date),
            Column::new("rows".into(), rows),
            Column::new("role".into(), role),
            Column::new("in_service_mean_mm".into(), in_service),
            Column::new("candidate_mean_mm".into(), candidate),
        ])
    }
}

/// Parameters either set identifies, with the change in standard errors.
fn changed_parameters(
    candidate: &ParameterSet,
    in_service: &ParameterSet,
) -> Vec<(ParamId, f64, Option<f64>)> {
    ParamId::of_arm(crate::robot::MAX_JOINTS)
        .chain(ParamId::track_terms(crate::robot::track::MAX_TRACK_ORDER))
        .chain(ParamId::positioner_terms(
            crate::robot::positioner::MAX_POSITIONER_AXES,
        ))
        .filter(|id| {
            candidate.status[id.index()] == ParamStatus::Identified
                || in_service.status[id.index()] == ParamStatus::Identified
        })
        .map(|id| {
            let change = candidate.values.get(id) - in_service.values.get(id);
            let errors: Vec<f64> = [
                candidate.std_errors[id.index()],
                in_service.std_errors[id.index()],
            ]
            .into_iter()
            .flatten()
            .collect();
            let std_error = (!errors.is_empty())
                .then(|| errors.iter().map(|e| e * e).sum::<f64>().sqrt())
                .filter(|se| *se > 0.0);
            (id, change, std_error)
        })
        .collect()
}

fn parameter_changes(
    candidate: &ParameterSet,
    in_service: &ParameterSet,
    prismatic: &[bool; crate::robot::MAX_JOINTS],
) -> polars::prelude::DataFrame {
    let rows = changed_parameters(candidate, in_service);
    frame(vec![
        Column::new(
            "name".into(),
            rows.iter().map(|r| r.0.name()).collect::<Vec<_>>(),
        ),
        Column::new(
            "unit".into(),
            rows.iter()
                .map(|r| r.0.unit_on(prismatic))
                .collect::<Vec<_>>(),
        ),
        Column::new(
            "in_service".into(),
            rows.iter()
                .map(|r| in_service.values.get(r.0))
                .collect::<Vec<_>>(),
        ),
        Column::new(
            "candidate".into(),
            rows.iter()
                .map(|r| candidate.values.get(r.0))
                .collect::<Vec<_>>(),
        ),
        Column::new(
            "change".into(),
            rows.iter().map(|r| r.1).collect::<Vec<_>>(),
        ),
        Column::new(
            "std_error".into(),
            rows.iter().map(|r| r.2).collect::<Vec<_>>(),
        ),
        Column::new(
            "z".into(),
            rows.iter()
                .map(|r| r.2.map(|se| r.1 / se))
                .collect::<Vec<_>>(),
        ),
    ])
}

/// Parameters listed in the summary, largest |z| first.
const CHANGES_LISTED: usize = 5;

/// The human-readable decision (`decision.md`): what cron mails or CI shows.
fn summary(
    decision: Decision,
    model: ModelName,
    reasons: &[String],
    candidate: &ParameterSet,
    in_service: &ParameterSet,
    prismatic: &[bool; crate::robot::MAX_JOINTS],
) -> String {
    let mut text = format!(
        "# Calibration gate: {}\n\nModel compared: {model}.\n\n",
        decision.as_str()
    );
    for reason in reasons {
        text.push_str(&format!("- {reason}\n"));
    }
    let mut changes = changed_parameters(candidate, in_service);
    changes.retain(|c| c.2.is_some());
    changes.sort_by(|a, b| {
        let z = |c: &(ParamId, f64, Option<f64>)| (c.1 / c.2.unwrap_or(1.0)).abs();
        z(b).total_cmp(&z(a))
    });
    if !changes.is_empty() {
        text.push_str("\nLargest parameter changes (candidate − in service):\n\n| parameter | change | z |\n|---|---|---|\n");
        for (id, change, se) in changes.iter().take(CHANGES_LISTED) {
            let z = se.map_or(f64::NAN, |se| change / se);
            text.push_str(&format!(
                "| {} | {change:+.5} {} | {z:+.1} |\n",
                id.name(),
                id.unit_on(prismatic)
            ));
        }
    }
    text
}
