//! `crossvalidate`: held-out accuracy (issue #28). The rows are grouped
//! (workspace region, joint configuration, load, time: [`Grouping`]), the
//! groups dealt to `folds` folds whole, and each fold in turn is validated on
//! a calibration identified on the other folds. Beside it, the same number of
//! random folds: the figure a random split gives, so the report can show how
//! much of the validation accuracy survives away from the calibration rows.
//!
//! Each fold is exactly an `identify` stage on the other folds' rows followed
//! by a `validate` stage on the fold (the same row checks, registration,
//! robust fit, held parameters and statistics), run in parallel over the
//! folds; so a fold's figures equal those of the two stages run by hand on the
//! same selection.

use std::collections::BTreeMap;

use polars::prelude::{Column, DataFrame};
use rayon::prelude::*;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::held_out::fold_assignment;
use super::identify::{IdentifySettings, IdentifyStage, ids_with_role, measured_rows};
use super::validate::{ValidateSettings, ValidateStage};
use super::{
    InputTable, NoProgress, SettingsContext, SettingsProblem, Stage, StageContext, StageError,
    StageInfo, StageOutputs, TableSlot,
};
use crate::calibration::groups::Grouping;
use crate::ladder;
use crate::stats;
use crate::table::frame;
use crate::table::parameters::ModelName;
use crate::table::schema::{self, f64_values, i64_values, str_values};

pub struct CrossvalidateStage;

/// Settings of `crossvalidate`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct CrossvalidateSettings {
    /// How rows are grouped: configuration (clusters in joint space, default),
    /// region (of the workspace), load, time (`measured_at`) or random.
    pub grouping: Grouping,
    /// Folds: groups left out in turn.
    #[schemars(range(min = 2, max = 50))]
    pub folds: usize,
    /// Also run as many random folds, the optimistic figure, beside the grouped one.
    pub compare_random: bool,
    /// The identification of each fold, as an `identify` stage's settings.
    pub identify: IdentifySettings,
    /// The model ladder (`ladder` table, fact `chosen_model`), climbed from
    /// the elasto-geometric model when it is among the models (simpler ones
    /// are listed, never chosen): a richer model is chosen over a simpler
    /// one only when both paired tests on the grouped folds' held-out errors
    /// are below this.
    #[schemars(extend("exclusiveMinimum" = 0.0, "exclusiveMaximum" = 0.5))]
    pub ladder_alpha: f64,
    /// The model ladder: and only when its mean held-out error is lower by at
    /// least this share of the simpler model's (row-level tests overstate
    /// significance, as a fold's rows share one calibration).
    #[schemars(range(min = 0.0, max = 1.0))]
    pub ladder_min_gain: f64,
}

impl Default for CrossvalidateSettings {
    fn default() -> Self {
        CrossvalidateSettings {
            grouping: Grouping::Configuration,
            folds: 5,
            compare_random: true,
            ladder_alpha: 0.05,
            ladder_min_gain: 0.05,
            identify: IdentifySettings {
                models: ["registered", "kinematic", "elastogeometric"]
                    .map(String::from)
                    .to_vec(),
                ..IdentifySettings::default()
            },
        }
    }
}

static INFO: StageInfo = StageInfo {
    kind: "crossvalidate",
    uses_cable_robot: false,
    updates_input: None,
    summary: "Held-out accuracy: identify on all folds but one, validate on it, for grouped (region, configuration, load, time) and random folds",
    code_version: 10,
    inputs: &[
        TableSlot {
            name: "measurements",
            schema: schema::measurements,
            required: true,
            meaning: "measured rows (spec §6)",
        },
        TableSlot {
            name: "selection",
            schema: schema::selection,
            required: false,
            meaning: "only the rows with role = calibration are folded (a split's validation rows stay unseen); all rows when absent",
        },
    ],
    outputs: &[
        TableSlot {
            name: "folds",
            schema: schema::crossvalidation_folds,
            required: true,
            meaning: "per protocol, fold and model: rows, mean, rms, p99.7 and max error",
        },
        TableSlot {
            name: "stats",
            schema: schema::crossvalidation_stats,
            required: true,
            meaning: "per protocol and model, pooled over the folds: rows, mean, rms, p99.7, max",
        },
        TableSlot {
            name: "errors",
            schema: schema::crossvalidation_errors,
            required: true,
            meaning: "per protocol, row and model: the fold and the held-out error",
        },
        TableSlot {
            name: "tests",
            schema: schema::crossvalidation_tests,
            required: true,
            meaning: "per protocol and pair of models, on the same held-out rows: mean difference, paired t and Wilcoxon p-values",
        },
        TableSlot {
            name: "ladder",
            schema: schema::crossvalidation_ladder,
            required: true,
            meaning: "the models from the simplest up on the grouped folds, each compared with the one chosen so far, and the model chosen",
        },
    ],
};

/// One protocol's held-out errors: per model, (cw_id, fold, error) in row order.
type ProtocolErrors = BTreeMap<String, Vec<(i64, usize, f64)>>;

/// A selection table giving `rows` (cw_ids) the role `calibration` where
/// `calibrates` says so and `validation` otherwise.
fn selection_input(ids: &[i64], calibrates: impl Fn(usize) -> bool) -> InputTable {
    let roles: Vec<&str> = (0..ids.len())
        .map(|k| {
            if calibrates(k) {
                "calibration"
            } else {
                "validation"
            }
        })
        .collect();
    InputTable {
        path: "crossvalidate fold selection".into(),
        df: frame(vec![
            Column::new("cw_id".into(), ids.to_vec()),
            Column::new("role".into(), roles),
        ]),
    }
}

/// Identifies on every fold but `fold` and validates on it: the validate
/// stage's `errors` per model.
fn run_fold(
    ctx: &StageContext,
    settings: &IdentifySettings,
    ids: &[i64],
    fold_of_row: &[usize],
    fold: usize,
) -> Result<Vec<(String, i64, f64)>, StageError> {
    let measurements = ctx.input("measurements")?;
    let mut inputs = BTreeMap::new();
    inputs.insert(
        "measurements".to_string(),
        InputTable {
            path: measurements.path.clone(),
            df: measurements.df.clone(),
        },
    );
    inputs.insert(
        "selection".to_string(),
        selection_input(ids, |k| fold_of_row[k] != fold),
    );
    let quiet = NoProgress;
    let fold_ctx = StageContext {
        inputs: &inputs,
        progress: &quiet,
        ..*ctx
    };
    let identified = IdentifyStage
        .run(&fold_ctx, settings)
        .map_err(|e| fold_error(fold, e))?;
    let parameters = identified
        .tables
        .get("parameters")
        .cloned()
        .ok_or_else(|| StageError::Failed(format!("fold {fold}: identify wrote no parameters")))?;
    inputs.insert(
        "parameters".to_string(),
        InputTable {
            path: format!("crossvalidate fold {fold} parameters").into(),
            df: parameters,
        },
    );
    let residual_name = super::residual_rung::RESIDUAL_OUTPUT.name;
    if let Some(residual) = identified.tables.get(residual_name) {
        inputs.insert(
            residual_name.to_string(),
            InputTable {
                path: format!("crossvalidate fold {fold} residual_model").into(),
                df: residual.clone(),
            },
        );
    }
    let validate_ctx = StageContext {
        inputs: &inputs,
        progress: &quiet,
        ..*ctx
    };
    let validated = ValidateStage
        .run(&validate_ctx, &ValidateSettings::default())
        .map_err(|e| fold_error(fold, e))?;
    let errors = validated
        .tables
        .get("errors")
        .ok_or_else(|| StageError::Failed(format!("fold {fold}: validate wrote no errors")))?;
    let path = std::path::Path::new("crossvalidate fold errors");
    let models = str_values(errors, "model", path)?;
    let cw_ids = i64_values(errors, "cw_id", path)?;
    let norms = f64_values(errors, "error_mm", path)?;
    Ok(models
        .into_iter()
        .zip(cw_ids)
        .zip(norms)
        .map(|((m, id), e)| (m.unwrap_or_default(), id, e))
        .collect())
}

/// A fold's failure, named by its fold.
fn fold_error(fold: usize, error: StageError) -> StageError {
    match error {
        StageError::Invalid(m) => StageError::Invalid(format!("fold {fold}: {m}")),
        StageError::Failed(m) => StageError::Failed(format!("fold {fold}: {m}")),
        other => other,
    }
}

/// Every fold of one protocol, in parallel; errors per model in cw_id order
/// of the folds.
fn run_protocol(
    ctx: &StageContext,
    settings: &IdentifySettings,
    ids: &[i64],
    fold_of_row: &[usize],
    folds: usize,
) -> Result<ProtocolErrors, StageError> {
    let per_fold: Vec<Vec<(String, i64, f64)>> = (0..folds)
        .into_par_iter()
        .map(|fold| run_fold(ctx, settings, ids, fold_of_row, fold))
        .collect::<Result<_, _>>()?;
    let mut errors = ProtocolErrors::new();
    for (fold, rows) in per_fold.into_iter().enumerate() {
        // The fitted models asked for: `nominal` fits nothing, so leaving rows
        // out cannot change it (and with the tracker's frame unknown it is
        // metres off).
        for (model, id, error) in rows
            .into_iter()
            .filter(|(m, _, _)| m != "nominal" && settings.models.contains(m))
        {
            errors.entry(model).or_default().push((id, fold, error));
        }
    }
    for rows in errors.values_mut() {
        rows.sort_by_key(|(id, _, _)| *id);
    }
    Ok(errors)
}

/// Mean, RMS, 99.7th percentile and maximum of `errors`.
fn figures(errors: &[f64]) -> Result<[f64; 4], StageError> {
    let summary = stats::summary(errors).map_err(|e| StageError::Failed(e.to_string()))?;
    let p997 = stats::percentile(errors, 0.997).map_err(|e| StageError::Failed(e.to_string()))?;
    let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
    Ok([summary.mean, rms, p997, summary.max])
}

impl Stage for CrossvalidateStage {
    type Settings = CrossvalidateSettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn check_settings(
        &self,
        settings: &CrossvalidateSettings,
        ctx: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        // `reregistered` is refused below with crossvalidate's own reason,
        // not identify's (which would ask for an input crossvalidate lacks).
        let identify_ctx = SettingsContext {
            bound_inputs: &["measurements", "selection", "start"],
            ..*ctx
        };
        let mut problems: Vec<SettingsProblem> = IdentifyStage
            .check_settings(&settings.identify, &identify_ctx)
            .into_iter()
            .map(|p| SettingsProblem {
                key: format!("identify.{}", p.key),
                message: p.message,
            })
            .collect();
        if settings.identify.models.iter().any(|m| m == "reregistered") {
            problems.push(SettingsProblem::new(
                "identify.models",
                "model `reregistered` needs an earlier calibration; crossvalidate identifies from the rows alone",
            ));
        }
        problems
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &CrossvalidateSettings,
    ) -> Result<StageOutputs, StageError> {
        let keep = match ctx.inputs.get("selection") {
            Some(selection) => Some(ids_with_role(selection, "calibration")?),
            None => None,
        };
        let measurements = ctx.input("measurements")?;
        let data = measured_rows(measurements, ctx.robot.spec(), keep.as_ref())?;
        let mut protocols: Vec<(Grouping, Vec<usize>)> = Vec::new();
        let grouped =
            fold_assignment(&data, settings.grouping, settings.folds, ctx.seed).map_err(|e| {
                StageError::Invalid(format!(
                    "{}: setting `grouping` = {}: {e}",
                    measurements.path.display(),
                    settings.grouping
                ))
            })?;
        protocols.push((settings.grouping, grouped.fold_of_row));
        if settings.compare_random && settings.grouping != Grouping::Random {
            let random = fold_assignment(&data, Grouping::Random, settings.folds, ctx.seed)
                .map_err(|e| {
                    StageError::Invalid(format!(
                        "{}: random folds: {e}",
                        measurements.path.display()
                    ))
                })?;
            protocols.push((Grouping::Random, random.fold_of_row));
        }
        let mut outputs = StageOutputs::default();
        let mut folds_table = FoldColumns::default();
        let mut stats_table = FoldColumns::default();
        let mut error_rows = ErrorColumns::default();
        let mut tests = TestColumns::default();
        let mut ladder: Option<DataFrame> = None;
        for (grouping, fold_of_row) in &protocols {
            ctx.progress.note(&format!(
                "{grouping} folds: identifying and validating {} folds of {} rows",
                settings.folds,
                data.ids.len()
            ));
            let errors = run_protocol(
                ctx,
                &settings.identify,
                &data.ids,
                fold_of_row,
                settings.folds,
            )?;
            for (model, rows) in &errors {
                for fold in 0..settings.folds {
                    let values: Vec<f64> = rows
                        .iter()
                        .filter(|(_, f, _)| *f == fold)
                        .map(|(_, _, e)| *e)
                        .collect();
                    if values.is_empty() {
                        continue;
                    }
                    let calibration_rows = fold_of_row.iter().filter(|f| **f != fold).count();
                    folds_table.push(grouping, Some(fold), model, calibration_rows, &values)?;
                }
                let all: Vec<f64> = rows.iter().map(|(_, _, e)| *e).collect();
                let [mean, _, p997, max] =
                    stats_table.push(grouping, None, model, data.ids.len(), &all)?;
                let key = format!("{grouping}_{model}");
                outputs.facts.insert(
                    key.clone(),
                    format!("mean {mean:.4} mm, p99.7 {p997:.4} mm, max {max:.4} mm"),
                );
                ctx.progress.note(&format!(
                    "{grouping} folds: {model}: held-out mean {mean:.4} mm, p99.7 {p997:.4}, max {max:.4}"
                ));
                for (id, fold, error) in rows {
                    error_rows.push(grouping, *id, *fold, model, *error);
                }
            }
            let models: Vec<&String> = errors.keys().collect();
            for (i, a) in models.iter().enumerate() {
                for b in &models[i + 1..] {
                    tests.push(grouping, a, b, &errors[*a], &errors[*b])?;
                }
            }
            if ladder.is_none() {
                let rule = ladder::Rule {
                    alpha: settings.ladder_alpha,
                    min_gain: settings.ladder_min_gain,
                };
                let (table, chosen) = ladder_table(grouping, &errors, rule)?;
                ctx.progress.note(&format!(
                    "{grouping} folds: model chosen by the ladder: {chosen}"
                ));
                outputs.facts.insert("chosen_model".into(), chosen);
                ladder = Some(table);
            }
        }
        if let Some(ladder) = ladder {
            outputs.tables.insert("ladder".into(), ladder);
        }
        outputs
            .tables
            .insert("folds".into(), folds_table.into_frame(true));
        outputs
            .tables
            .insert("stats".into(), stats_table.into_frame(false));
        outputs
            .tables
            .insert("errors".into(), error_rows.into_frame());
        outputs.tables.insert("tests".into(), tests.into_frame());
        outputs
            .facts
            .insert("rows".into(), data.ids.len().to_string());
        Ok(outputs)
    }
}

/// The `ladder` table of one protocol's errors and the model chosen: the
/// models climbed from the simplest ([`ModelName::ladder_rank`]).
fn ladder_table(
    grouping: &Grouping,
    errors: &ProtocolErrors,
    rule: ladder::Rule,
) -> Result<(DataFrame, String), StageError> {
    let mut rungs: Vec<ladder::Rung> = errors
        .iter()
        .map(|(model, rows)| ladder::Rung {
            model: model.clone(),
            errors_mm: rows.iter().map(|(id, _, e)| (*id, *e)).collect(),
        })
        .collect();
    rungs.sort_by_key(|r| {
        r.model
            .parse::<ModelName>()
            .map_or(usize::MAX, ModelName::ladder_rank)
    });
    // From the paper's model when it was compared: a simpler one failing to
    // beat it by the minimum gain must not keep a worse model in service.
    let start = rungs
        .iter()
        .position(|r| r.model == ModelName::Elastogeometric.as_str())
        .unwrap_or(0);
    let climb = ladder::climb(&rungs, rule, start)
        .ok_or_else(|| StageError::Failed("no fitted model to choose from".into()))?;
    let mut figures_of = Vec::new();
    for rung in &rungs {
        let values: Vec<f64> = rung.errors_mm.iter().map(|(_, e)| *e).collect();
        figures_of.push(figures(&values)?);
    }
    let steps = &climb.steps;
    let column = |name: &str, values: Vec<Option<f64>>| Column::new(name.into(), values);
    let table = frame(vec![
        Column::new(
            "protocol".into(),
            vec![grouping.as_str().to_string(); steps.len()],
        ),
        Column::new(
            "model".into(),
            steps.iter().map(|s| s.model.clone()).collect::<Vec<_>>(),
        ),
        Column::new(
            "mean_mm".into(),
            steps.iter().map(|s| s.mean_mm).collect::<Vec<_>>(),
        ),
        Column::new(
            "p997_mm".into(),
            figures_of.iter().map(|f| f[2]).collect::<Vec<_>>(),
        ),
        Column::new(
            "max_mm".into(),
            figures_of.iter().map(|f| f[3]).collect::<Vec<_>>(),
        ),
        Column::new(
            "compared_with".into(),
            steps
                .iter()
                .map(|s| s.compared_with.clone())
                .collect::<Vec<_>>(),
        ),
        column(
            "mean_difference_mm",
            steps.iter().map(|s| s.mean_difference_mm).collect(),
        ),
        column("paired_t_p", steps.iter().map(|s| s.paired_t_p).collect()),
        column("wilcoxon_p", steps.iter().map(|s| s.wilcoxon_p).collect()),
        Column::new(
            "accepted".into(),
            steps.iter().map(|s| s.accepted).collect::<Vec<_>>(),
        ),
        Column::new(
            "chosen".into(),
            (0..steps.len())
                .map(|k| k == climb.chosen)
                .collect::<Vec<_>>(),
        ),
        Column::new(
            "reason".into(),
            steps.iter().map(|s| s.reason.clone()).collect::<Vec<_>>(),
        ),
    ]);
    Ok((table, steps[climb.chosen].model.clone()))
}

/// Rows of the `folds` and `stats` tables.
#[derive(Default)]
struct FoldColumns {
    protocol: Vec<String>,
    fold: Vec<i64>,
    model: Vec<String>,
    calibration_rows: Vec<i64>,
    validation_rows: Vec<i64>,
    mean: Vec<f64>,
    rms: Vec<f64>,
    p997: Vec<f64>,
    max: Vec<f64>,
}

impl FoldColumns {
    fn push(
        &mut self,
        grouping: &Grouping,
        fold: Option<usize>,
        model: &str,
        calibration_rows: usize,
        errors: &[f64],
    ) -> Result<[f64; 4], StageError> {
        let [mean, rms, p997, max] = figures(errors)?;
        self.protocol.push(grouping.as_str().to_string());
        self.fold.push(fold.map_or(-1, |f| f as i64));
        self.model.push(model.to_string());
        self.calibration_rows.push(calibration_rows as i64);
        self.validation_rows.push(errors.len() as i64);
        self.mean.push(mean);
        self.rms.push(rms);
        self.p997.push(p997);
        self.max.push(max);
        Ok([mean, rms, p997, max])
    }

    /// `per_fold`: the `folds` table (fold, calibration and validation rows);
    /// otherwise `stats` (rows).
    fn into_frame(self, per_fold: bool) -> DataFrame {
        let mut columns = vec![Column::new("protocol".into(), self.protocol)];
        if per_fold {
            columns.push(Column::new("fold".into(), self.fold));
        }
        columns.push(Column::new("model".into(), self.model));
        if per_fold {
            columns.push(Column::new(
                "calibration_rows".into(),
                self.calibration_rows,
            ));
            columns.push(Column::new("validation_rows".into(), self.validation_rows));
        } else {
            columns.push(Column::new("rows".into(), self.validation_rows));
        }
        columns.extend([
            Column::new("mean_mm".into(), self.mean),
            Column::new("rms_mm".into(), self.rms),
            Column::new("p997_mm".into(), self.p997),
            Column::new("max_mm".into(), self.max),
        ]);
        frame(columns)
    }
}

/// Rows of the `errors` table.
#[derive(Default)]
struct ErrorColumns {
    protocol: Vec<String>,
    cw_id: Vec<i64>,
    fold: Vec<i64>,
    model: Vec<String>,
    error: Vec<f64>,
}

impl ErrorColumns {
    fn push(&mut self, grouping: &Grouping, id: i64, fold: usize, model: &str, error: f64) {
        self.protocol.push(grouping.as_str().to_string());
        self.cw_id.push(id);
        self.fold.push(fold as i64);
        self.model.push(model.to_string());
        self.error.push(error);
    }

    fn into_frame(self) -> DataFrame {
        frame(vec![
            Column::new("protocol".into(), self.protocol),
            Column::new("cw_id".into(), self.cw_id),
            Column::new("fold".into(), self.fold),
            Column::new("model".into(), self.model),
            Column::new("error_mm".into(), self.error),
        ])
    }
}

/// Rows of the `tests` table: paired comparisons on the rows both models
/// predicted (the same held-out rows, fold for fold).
#[derive(Default)]
struct TestColumns {
    protocol: Vec<String>,
    model_a: Vec<String>,
    model_b: Vec<String>,
    rows: Vec<i64>,
    mean_difference: Vec<f64>,
    paired_t_p: Vec<f64>,
    wilcoxon_p: Vec<f64>,
}

impl TestColumns {
    fn push(
        &mut self,
        grouping: &Grouping,
        a: &str,
        b: &str,
        errors_a: &[(i64, usize, f64)],
        errors_b: &[(i64, usize, f64)],
    ) -> Result<(), StageError> {
        // Both sorted by cw_id: pair the rows present in both.
        let by_id: BTreeMap<i64, f64> = errors_b.iter().map(|(id, _, e)| (*id, *e)).collect();
        let (xs, ys): (Vec<f64>, Vec<f64>) = errors_a
            .iter()
            .filter_map(|(id, _, e)| by_id.get(id).map(|other| (*e, *other)))
            .unzip();
        if xs.len() < 2 {
            return Ok(());
        }
        let fail = |e: stats::StatsError| StageError::Failed(format!("{a} vs {b}: {e}"));
        let t = stats::paired_t(&xs, &ys).map_err(fail)?;
        let w = stats::wilcoxon_signed_rank(&xs, &ys).map_err(fail)?;
        self.protocol.push(grouping.as_str().to_string());
        self.model_a.push(a.to_string());
        self.model_b.push(b.to_string());
        self.rows.push(xs.len() as i64);
        self.mean_difference
            .push(xs.iter().zip(&ys).map(|(x, y)| x - y).sum::<f64>() / xs.len() as f64);
        self.paired_t_p.push(t.p_value);
        self.wilcoxon_p.push(w.p_value);
        Ok(())
    }

    fn into_frame(self) -> DataFrame {
        frame(vec![
            Column::new("protocol".into(), self.protocol),
            Column::new("model_a".into(), self.model_a),
            Column::new("model_b".into(), self.model_b),
            Column::new("rows".into(), self.rows),
            Column::new("mean_difference_mm".into(), self.mean_difference),
            Column::new("paired_t_p".into(), self.paired_t_p),
            Column::new("wilcoxon_p".into(), self.wilcoxon_p),
        ])
    }
}
