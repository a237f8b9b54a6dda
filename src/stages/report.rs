//! `report`: one self-contained HTML page (`report.html`) of a calibration run —
//! first the verdict (the model in service's validation mean, p99.7 and max
//! against the job's tolerance, PASS or FAIL, and the warnings: held
//! parameters, accepted non-convergence, rows left out, targets not `ok`), then
//! the error statistics (beside the paper's Table III when the job reproduces
//! the paper), histograms, the poses, the parameters with standard errors (and
//! the truth of a simulated robot), the DETMAX and identification traces, the
//! hypothesis tests and the provenance of every input. Reads tables only;
//! writes no table.
//!
//! This file reads the inputs into plain data; `crate::report` renders it.

use std::collections::BTreeMap;
use std::path::Path;

use polars::prelude::DataFrame;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::{InputTable, Stage, StageContext, StageError, StageInfo, StageOutputs, TableSlot};
use crate::report::held_out::HeldOutRow;
use crate::report::ladder::LadderRow;
use crate::report::{
    self, AccuracyMap, CommandRow, Criterion, DetmaxStep, ExcludedRow, InputSource, IsoDistance,
    IsoPoint, IsoTest, MapPoint, ParamRow, Pose, ReportData, StatsRow, TestRow, TraceRow, Truth,
    VerdictSettings,
};
use crate::table::schema::{
    self, ColumnSpec, ColumnType, TableSchema, f64_values, i64_values, io_error, str_values,
};
use crate::table::{self as tables, TableError};

pub struct ReportStage;

/// Settings of `report`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ReportSettings {
    /// Page title.
    pub title: String,
    /// Bins of each error histogram.
    #[schemars(range(min = 1, max = 1000))]
    pub histogram_bins: usize,
    /// Model of the `truth` table whose values are the truth.
    pub truth_model: String,
    /// The model in service, which the verdict on the first screen judges;
    /// unset: the most complete calibration the errors table holds
    /// (elastogeometric, kinematic, reregistered, registered, nominal, in
    /// that order), not the one with the smallest error.
    #[schemars(length(min = 1, max = 200))]
    pub model: Option<String>,
    /// The accuracy the application needs (mm): the verdict is PASS when the
    /// `criterion` figure of the model's validation errors is at most this,
    /// FAIL otherwise. Unset: the figures without a verdict, since what is good
    /// enough depends on the application.
    #[schemars(range(max = 1.0e4))]
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub tolerance_mm: Option<f64>,
    /// Which figure is compared with `tolerance_mm`.
    pub criterion: CriterionSetting,
    /// The job reproduces the paper (a simulated IRB 1600 campaign): show the
    /// paper's Table III beside the statistics, the paper's figure numbers and
    /// the remarks on the truth's world frame. Off for real data: another
    /// robot is not the paper's.
    pub compare_with_paper: bool,
}

/// Which figure of the validation errors the verdict compares with the tolerance.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum CriterionSetting {
    /// The largest error: no validation row beyond the tolerance (the stricter).
    Max,
    /// The 99.7th percentile, the distribution-free "3σ" of a datasheet: about
    /// one row in 333 may lie beyond the tolerance.
    #[serde(rename = "p99_7")]
    P99_7,
}

impl From<CriterionSetting> for Criterion {
    fn from(c: CriterionSetting) -> Criterion {
        match c {
            CriterionSetting::Max => Criterion::Max,
            CriterionSetting::P99_7 => Criterion::P99_7,
        }
    }
}

impl Default for ReportSettings {
    fn default() -> Self {
        ReportSettings {
            title: "Elasto-geometric calibration report".into(),
            histogram_bins: 30,
            truth_model: "elastogeometric".into(),
            model: None,
            tolerance_mm: None,
            criterion: CriterionSetting::Max,
            compare_with_paper: false,
        }
    }
}

/// The columns of a `commands` table (compensate's output, spec §7–§8) that the
/// report reads: only `target_id` and `status` are required, so a table written
/// before spec §8 (without `envelope_distance` and `u95_mm`) or by another tool
/// still binds; those two are read where present. Not a table kind of its own:
/// a view of `commands`.
fn command_status() -> TableSchema {
    let column = |name, dtype, unit, required, meaning| ColumnSpec {
        name,
        dtype,
        unit,
        required,
        meaning,
        alternative: None,
    };
    TableSchema {
        kind: "commands",
        description: "Joint commands per target (compensate): the report reads each target's status.",
        columns: vec![
            column("target_id", ColumnType::Int64, "", true, "the target's id"),
            column(
                "status",
                ColumnType::Utf8,
                "",
                true,
                "ok, or why not (unreachable, joint_limit, singular, not_converged, outside_envelope, ...)",
            ),
        ],
        unique: Some("target_id"),
    }
}

/// The report's file name among the stage's outputs.
pub const REPORT_FILE: &str = "report.html";

static INFO: StageInfo = StageInfo {
    kind: "report",
    uses_cable_robot: false,
    updates_input: None,
    summary: "Self-contained HTML report (report.html): verdict (PASS/FAIL against tolerance_mm, warnings), error statistics (Table III with compare_with_paper), histograms, poses, accuracy map, ISO 9283, parameters, traces, tests, provenance",
    code_version: 11,
    inputs: &[
        TableSlot {
            name: "stats",
            schema: schema::stats,
            required: true,
            meaning: "error statistics per model (validate)",
        },
        TableSlot {
            name: "errors",
            schema: schema::errors,
            required: true,
            meaning: "error per validation row and model (validate), for the histograms",
        },
        TableSlot {
            name: "parameters",
            schema: schema::parameters,
            required: true,
            meaning: "identified parameter sets with standard errors (identify)",
        },
        TableSlot {
            name: "tests",
            schema: schema::tests,
            required: false,
            meaning: "hypothesis tests between models (validate)",
        },
        TableSlot {
            name: "poses",
            schema: schema::poses,
            required: false,
            meaning: "robot configurations, for the 3-D view of the poses",
        },
        TableSlot {
            name: "observability",
            schema: schema::observability,
            required: false,
            meaning: "O1 per DETMAX exchange (detmax)",
        },
        TableSlot {
            name: "identification_trace",
            schema: schema::identification_trace,
            required: false,
            meaning: "Gauss–Newton iterations per model (identify)",
        },
        TableSlot {
            name: "excluded_rows",
            schema: schema::excluded_rows,
            required: false,
            meaning: "rows the identification left out and why (identify)",
        },
        TableSlot {
            name: "crossvalidation",
            schema: schema::crossvalidation_stats,
            required: false,
            meaning: "held-out figures of grouped and random folds (crossvalidate's stats), shown beside the validation statistics",
        },
        TableSlot {
            name: "ladder",
            schema: schema::crossvalidation_ladder,
            required: false,
            meaning: "the model ladder and the model chosen (crossvalidate's ladder)",
        },
        TableSlot {
            name: "accuracy_map",
            schema: schema::accuracy_map,
            required: false,
            meaning: "predicted 95 % uncertainty over a grid around the calibration rows (accuracy_map), drawn as a heat map per slice",
        },
        TableSlot {
            name: "calibration_positions",
            schema: schema::calibration_positions,
            required: false,
            meaning: "the calibration rows' tool positions (accuracy_map), drawn over the map",
        },
        TableSlot {
            name: "iso9283",
            schema: schema::iso9283,
            required: false,
            meaning: "ISO 9283 AP and RP per point of the compensated commands (iso9283)",
        },
        TableSlot {
            name: "iso9283_distances",
            schema: schema::iso9283_distances,
            required: false,
            meaning: "AD and RD per pair of points of that test (iso9283)",
        },
        TableSlot {
            name: "iso9283_baseline",
            schema: schema::iso9283,
            required: false,
            meaning: "the same test with the nominal commands, shown beside it",
        },
        TableSlot {
            name: "iso9283_distances_baseline",
            schema: schema::iso9283_distances,
            required: false,
            meaning: "AD and RD of the baseline test",
        },
        TableSlot {
            name: "truth",
            schema: schema::parameters,
            required: false,
            meaning: "parameters of the simulated robot; the rows of model `truth_model` are the truth",
        },
        TableSlot {
            name: "commands",
            schema: command_status,
            required: false,
            meaning: "joint commands per target (compensate): targets whose status is not ok (outside_envelope, unreachable, ...) are warnings on the first screen, with envelope_distance and u95_mm where the table has them",
        },
    ],
    outputs: &[],
};

impl Stage for ReportStage {
    type Settings = ReportSettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &ReportSettings,
    ) -> Result<StageOutputs, StageError> {
        let truth = match ctx.inputs.get("truth") {
            Some(table) => Some(read_truth(table, &settings.truth_model)?),
            None => None,
        };
        let detmax_trace = ctx.inputs.get("observability");
        let o1_scaling = detmax_trace
            .and_then(|t| tables::read_provenance(&t.path).ok().flatten())
            .and_then(|p| p.extra.get("o1_scaling").cloned())
            .unwrap_or_else(|| report::DEFAULT_O1_SCALING.to_string());
        let errors = read_errors(ctx.input("errors")?)?;
        // A named model the errors lack is a mistake in the job, not a page
        // without a verdict.
        report::verdict::model_in_service(&errors, settings.model.as_deref())
            .map_err(StageError::Invalid)?;
        let data = ReportData {
            title: settings.title.clone(),
            verdict: VerdictSettings {
                model: settings.model.clone(),
                tolerance_mm: settings.tolerance_mm,
                criterion: settings.criterion.into(),
            },
            compare_with_paper: settings.compare_with_paper,
            commands: ctx.inputs.get("commands").map(read_commands).transpose()?,
            histogram_bins: settings.histogram_bins,
            truth_model: settings.truth_model.clone(),
            stats: read_stats(ctx.input("stats")?)?,
            errors,
            parameters: read_parameters(ctx.input("parameters")?)?,
            tests: ctx.inputs.get("tests").map(read_tests).transpose()?,
            poses: ctx.inputs.get("poses").map(read_poses).transpose()?,
            detmax_trace: detmax_trace.map(read_detmax).transpose()?,
            o1_scaling,
            identification_trace: ctx
                .inputs
                .get("identification_trace")
                .map(read_trace)
                .transpose()?,
            excluded_rows: ctx
                .inputs
                .get("excluded_rows")
                .map(read_excluded)
                .transpose()?,
            held_out: ctx
                .inputs
                .get("crossvalidation")
                .map(read_held_out)
                .transpose()?,
            ladder: ctx.inputs.get("ladder").map(read_ladder).transpose()?,
            accuracy_map: ctx
                .inputs
                .get("accuracy_map")
                .map(|map| read_accuracy_map(map, ctx.inputs.get("calibration_positions")))
                .transpose()?,
            iso9283: read_iso_test(ctx, "iso9283", "iso9283_distances")?,
            iso9283_baseline: read_iso_test(ctx, "iso9283_baseline", "iso9283_distances_baseline")?,
            truth,
            sources: ctx
                .inputs
                .iter()
                .map(|(name, table)| source(name, table, ctx.job_dir))
                .collect(),
        };
        let html = report::render(&data).map_err(|e| StageError::Failed(e.to_string()))?;
        let mut outputs = StageOutputs::default();
        outputs
            .facts
            .insert("report_bytes".into(), html.len().to_string());
        outputs
            .facts
            .insert("charts".into(), html.matches("<svg").count().to_string());
        outputs.files.insert(REPORT_FILE.into(), html.into_bytes());
        Ok(outputs)
    }
}

/// Provenance and identity of one input, read from its file.
fn source(name: &str, table: &InputTable, job_dir: &Path) -> InputSource {
    let shown = table.path.strip_prefix(job_dir).unwrap_or(&table.path);
    InputSource {
        input: name.to_string(),
        file: shown.display().to_string(),
        rows: table.df.height(),
        data_hash: tables::content_hash(&table.df),
        provenance: tables::read_provenance(&table.path).map_err(|e| e.to_string()),
    }
}

fn strings(table: &InputTable, column: &str) -> Result<Vec<String>, TableError> {
    Ok(str_values(&table.df, column, &table.path)?
        .into_iter()
        .map(Option::unwrap_or_default)
        .collect())
}

fn floats(table: &InputTable, column: &str) -> Result<Vec<f64>, TableError> {
    f64_values(&table.df, column, &table.path)
}

fn ints(table: &InputTable, column: &str) -> Result<Vec<i64>, TableError> {
    i64_values(&table.df, column, &table.path)
}

/// An optional f64 column: nulls (and a missing column) as `None`.
fn optional_floats(
    df: &DataFrame,
    column: &str,
    path: &Path,
) -> Result<Vec<Option<f64>>, TableError> {
    match df.column(column) {
        Ok(c) => Ok(c.f64().map_err(|e| io_error(path, e))?.iter().collect()),
        Err(_) => Ok(vec![None; df.height()]),
    }
}

/// An optional i64 column: nulls (and a missing column) as `None`.
fn optional_ints(
    df: &DataFrame,
    column: &str,
    path: &Path,
) -> Result<Vec<Option<i64>>, TableError> {
    match df.column(column) {
        Ok(c) => Ok(c.i64().map_err(|e| io_error(path, e))?.iter().collect()),
        Err(_) => Ok(vec![None; df.height()]),
    }
}

fn read_stats(table: &InputTable) -> Result<Vec<StatsRow>, TableError> {
    let model = strings(table, "model")?;
    let n = ints(table, "n")?;
    let [mean, std, median, rms, p95, max] = [
        "mean_mm",
        "std_mm",
        "median_mm",
        "rms_mm",
        "p95_mm",
        "max_mm",
    ]
    .map(|c| floats(table, c));
    let (mean, std, median, rms, p95, max) = (mean?, std?, median?, rms?, p95?, max?);
    Ok((0..model.len())
        .map(|k| StatsRow {
            model: model[k].clone(),
            n: n[k],
            mean: mean[k],
            std: std[k],
            median: median[k],
            rms: rms[k],
            p95: p95[k],
            max: max[k],
        })
        .collect())
}

fn read_errors(table: &InputTable) -> Result<BTreeMap<String, Vec<f64>>, TableError> {
    let model = strings(table, "model")?;
    let error = floats(table, "error_mm")?;
    let mut by_model: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    for (m, e) in model.into_iter().zip(error) {
        by_model.entry(m).or_default().push(e);
    }
    Ok(by_model)
}

fn read_parameters(table: &InputTable) -> Result<Vec<ParamRow>, TableError> {
    let model = strings(table, "model")?;
    let name = strings(table, "name")?;
    let unit = strings(table, "unit")?;
    let nominal = floats(table, "nominal")?;
    let value = floats(table, "value")?;
    let std_error = optional_floats(&table.df, "std_error", &table.path)?;
    let status = strings(table, "status")?;
    // Written before spec §8: no reasons.
    let reason = match table.df.column("reason") {
        Ok(_) => str_values(&table.df, "reason", &table.path)?,
        Err(_) => vec![None; table.df.height()],
    };
    Ok((0..model.len())
        .map(|k| ParamRow {
            model: model[k].clone(),
            name: name[k].clone(),
            unit: unit[k].clone(),
            nominal: nominal[k],
            value: value[k],
            std_error: std_error[k].filter(|v| v.is_finite()),
            status: status[k].clone(),
            reason: reason[k].clone().filter(|r| !r.is_empty()),
        })
        .collect())
}

/// The `commands` input: each target's status, and `envelope_distance` and
/// `u95_mm` where the table has them (spec §8; nulls and non-finite values read
/// as absent, since the report only shows them).
fn read_commands(table: &InputTable) -> Result<Vec<CommandRow>, TableError> {
    let target_id = ints(table, "target_id")?;
    let status = strings(table, "status")?;
    let lenient = |column: &str| -> Result<Vec<Option<f64>>, TableError> {
        match table.df.column(column) {
            Ok(c) if c.dtype().is_float() => Ok(c
                .cast(&polars::prelude::DataType::Float64)
                .map_err(|e| io_error(&table.path, e))?
                .f64()
                .map_err(|e| io_error(&table.path, e))?
                .iter()
                .map(|v| v.filter(|v| v.is_finite()))
                .collect()),
            Ok(c) if c.dtype() != &polars::prelude::DataType::Null => Err(TableError::WrongType {
                file: table.path.clone(),
                column: column.to_string(),
                found: c.dtype().to_string(),
                expected: polars::prelude::DataType::Float64.to_string(),
            }),
            _ => Ok(vec![None; table.df.height()]),
        }
    };
    let distance = lenient("envelope_distance")?;
    let u95 = lenient("u95_mm")?;
    Ok((0..target_id.len())
        .map(|k| CommandRow {
            target_id: target_id[k],
            status: status[k].clone(),
            envelope_distance: distance[k],
            u95_mm: u95[k],
        })
        .collect())
}

fn read_truth(table: &InputTable, truth_model: &str) -> Result<Truth, StageError> {
    let rows = read_parameters(table)?;
    let values: BTreeMap<String, f64> = rows
        .iter()
        .filter(|r| r.model == truth_model)
        .map(|r| (r.name.clone(), r.value))
        .collect();
    if values.is_empty() {
        let mut models: Vec<&str> = Vec::new();
        for row in &rows {
            if !models.contains(&row.model.as_str()) {
                models.push(&row.model);
            }
        }
        return Err(StageError::Invalid(format!(
            "setting `truth_model`: the truth table {} has no rows for model `{truth_model}` (it has: {})",
            table.path.display(),
            if models.is_empty() {
                "no rows".to_string()
            } else {
                models.join(", ")
            }
        )));
    }
    Ok(Truth {
        model: truth_model.to_string(),
        values,
    })
}

fn read_tests(table: &InputTable) -> Result<Vec<TestRow>, TableError> {
    let model_a = strings(table, "model_a")?;
    let model_b = strings(table, "model_b")?;
    let test = strings(table, "test")?;
    let statistic = floats(table, "statistic")?;
    let dof = optional_floats(&table.df, "dof", &table.path)?;
    let p_value = floats(table, "p_value")?;
    Ok((0..model_a.len())
        .map(|k| TestRow {
            model_a: model_a[k].clone(),
            model_b: model_b[k].clone(),
            test: test[k].clone(),
            statistic: statistic[k],
            dof: dof[k],
            p_value: p_value[k],
        })
        .collect())
}

fn read_poses(table: &InputTable) -> Result<Vec<Pose>, TableError> {
    let id = ints(table, "config_id")?;
    let [x, y, z, a, b, g] = [
        "target_x_mm",
        "target_y_mm",
        "target_z_mm",
        "tool_alpha_deg",
        "tool_beta_deg",
        "tool_gamma_deg",
    ]
    .map(|c| floats(table, c));
    let (x, y, z, a, b, g) = (x?, y?, z?, a?, b?, g?);
    Ok((0..id.len())
        .map(|k| Pose {
            config_id: id[k],
            target_mm: [x[k], y[k], z[k]],
            tool_deg: [a[k], b[k], g[k]],
        })
        .collect())
}

fn read_detmax(table: &InputTable) -> Result<Vec<DetmaxStep>, TableError> {
    let iteration = ints(table, "iteration")?;
    let added = optional_ints(&table.df, "added_cw_id", &table.path)?;
    let removed = optional_ints(&table.df, "removed_cw_id", &table.path)?;
    let o1 = floats(table, "o1")?;
    Ok((0..iteration.len())
        .map(|k| DetmaxStep {
            iteration: iteration[k],
            added: added[k],
            removed: removed[k],
            o1: o1[k],
        })
        .collect())
}

fn read_excluded(table: &InputTable) -> Result<Vec<ExcludedRow>, TableError> {
    let cw_id = ints(table, "cw_id")?;
    let model = str_values(&table.df, "model", &table.path)?;
    let check = strings(table, "check")?;
    let reason = strings(table, "reason")?;
    Ok((0..cw_id.len())
        .map(|k| ExcludedRow {
            cw_id: cw_id[k],
            model: model[k].clone(),
            check: check[k].clone(),
            reason: reason[k].clone(),
        })
        .collect())
}

fn read_held_out(table: &InputTable) -> Result<Vec<HeldOutRow>, TableError> {
    let protocol = strings(table, "protocol")?;
    let model = strings(table, "model")?;
    let rows = ints(table, "rows")?;
    let [mean, p997, max] = ["mean_mm", "p997_mm", "max_mm"].map(|c| floats(table, c));
    let (mean, p997, max) = (mean?, p997?, max?);
    Ok((0..rows.len())
        .map(|k| HeldOutRow {
            protocol: protocol[k].clone(),
            model: model[k].clone(),
            rows: rows[k],
            mean_mm: mean[k],
            p997_mm: p997[k],
            max_mm: max[k],
        })
        .collect())
}

fn read_ladder(table: &InputTable) -> Result<Vec<LadderRow>, TableError> {
    let protocol = strings(table, "protocol")?;
    let model = strings(table, "model")?;
    let [mean, p997, max] = ["mean_mm", "p997_mm", "max_mm"].map(|c| floats(table, c));
    let (mean, p997, max) = (mean?, p997?, max?);
    let compared_with = schema::str_values(&table.df, "compared_with", &table.path)?;
    let t = optional_floats(&table.df, "paired_t_p", &table.path)?;
    let w = optional_floats(&table.df, "wilcoxon_p", &table.path)?;
    let chosen: Vec<bool> = table
        .df
        .column("chosen")
        .and_then(|c| {
            c.bool()
                .map(|b| b.iter().map(|v| v == Some(true)).collect())
        })
        .map_err(|e| io_error(&table.path, e))?;
    let reason = strings(table, "reason")?;
    Ok((0..model.len())
        .map(|k| LadderRow {
            protocol: protocol[k].clone(),
            model: model[k].clone(),
            mean_mm: mean[k],
            p997_mm: p997[k],
            max_mm: max[k],
            compared_with: compared_with[k].clone(),
            paired_t_p: t[k],
            wilcoxon_p: w[k],
            chosen: chosen[k],
            reason: reason[k].clone(),
        })
        .collect())
}

fn read_accuracy_map(
    table: &InputTable,
    positions: Option<&InputTable>,
) -> Result<AccuracyMap, TableError> {
    let slice = ints(table, "slice")?;
    let [x, y, z] = ["x_mm", "y_mm", "z_mm"].map(|c| floats(table, c));
    let (x, y, z) = (x?, y?, z?);
    let inside: Vec<bool> = table
        .df
        .column("inside_box")
        .and_then(|c| c.bool().cloned())
        .map_err(|e| io_error(&table.path, e))?
        .iter()
        .map(Option::unwrap_or_default)
        .collect();
    let u95 = optional_floats(&table.df, "u95_mm", &table.path)?;
    let points = (0..slice.len())
        .map(|k| MapPoint {
            slice: slice[k],
            position_mm: [x[k], y[k], z[k]],
            inside_box: inside[k],
            u95_mm: u95[k].filter(|v| v.is_finite()),
        })
        .collect();
    let calibration_mm = match positions {
        Some(table) => {
            let [x, y, z] = ["x_mm", "y_mm", "z_mm"].map(|c| floats(table, c));
            let (x, y, z) = (x?, y?, z?);
            (0..x.len()).map(|k| [x[k], y[k], z[k]]).collect()
        }
        None => Vec::new(),
    };
    Ok(AccuracyMap {
        points,
        calibration_mm,
    })
}

/// An ISO 9283 test from its per-point input and optional distances input;
/// `None` when the per-point input is not bound.
fn read_iso_test(
    ctx: &StageContext,
    points: &str,
    distances: &str,
) -> Result<Option<IsoTest>, TableError> {
    let Some(table) = ctx.inputs.get(points) else {
        return Ok(None);
    };
    let point = strings(table, "point")?;
    let n = ints(table, "n")?;
    let (ap, rp) = (floats(table, "ap_mm")?, floats(table, "rp_mm")?);
    let points = (0..point.len())
        .map(|k| IsoPoint {
            point: point[k].clone(),
            n: n[k],
            ap_mm: ap[k],
            rp_mm: rp[k],
        })
        .collect();
    let distances = match ctx.inputs.get(distances) {
        Some(table) => {
            let (from, to) = (strings(table, "from")?, strings(table, "to")?);
            let n = ints(table, "n")?;
            let [d_cmd, ad, rd] = ["d_cmd_mm", "ad_mm", "rd_mm"].map(|c| floats(table, c));
            let (d_cmd, ad, rd) = (d_cmd?, ad?, rd?);
            (0..from.len())
                .map(|k| IsoDistance {
                    from: from[k].clone(),
                    to: to[k].clone(),
                    n: n[k],
                    d_cmd_mm: d_cmd[k],
                    ad_mm: ad[k],
                    rd_mm: rd[k],
                })
                .collect()
        }
        None => Vec::new(),
    };
    Ok(Some(IsoTest { points, distances }))
}

fn read_trace(table: &InputTable) -> Result<Vec<TraceRow>, TableError> {
    let model = strings(table, "model")?;
    let iteration = ints(table, "iteration")?;
    let [rms, max, step] = ["rms_mm", "max_mm", "step_mm"].map(|c| floats(table, c));
    let (rms, max, step) = (rms?, max?, step?);
    Ok((0..model.len())
        .map(|k| TraceRow {
            model: model[k].clone(),
            iteration: iteration[k],
            rms_mm: rms[k],
            max_mm: max[k],
            step_mm: step[k],
        })
        .collect())
}
