//! `select`: picks the n conf-wrench rows that maximise an observability index (O1
//! by default, the paper's; O2–O5 selectable) of the identifiable parameters by
//! DETMAX (paper §IV.B). The other rows become the validation set. See
//! `design::detmax` for the algorithm, its fast and naive engines and the column
//! scaling, `design::observability` for the indices.

use polars::prelude::Column;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::{Stage, StageContext, StageError, StageInfo, StageOutputs, TableSlot, commanded_rows};
use crate::calibration::{rank, stream};
use crate::design::detmax::{Candidates, Criterion, DetmaxError, Method, Options, detmax};
use crate::robot::{ParamId, ParamValues, batch_jacobian};
use crate::table::frame;
use crate::table::schema::{self, str_values};

pub struct SelectStage;

/// Settings of `select`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct SelectSettings {
    /// Number of calibration rows to select.
    #[schemars(range(min = 1, max = 10_000_000))]
    pub n: usize,
    /// Upper bound on exchanges (the paper's loop stops earlier, when the row added is the row removed).
    #[schemars(range(min = 1, max = 100_000_000))]
    pub max_iterations: usize,
    /// Rank tolerance when no identifiability input is bound.
    #[schemars(extend("exclusiveMinimum" = 0.0, "exclusiveMaximum" = 1.0))]
    pub rank_tolerance: f64,
    /// Independent random starts; the selection with the highest criterion is kept.
    #[schemars(range(min = 1, max = 1000))]
    pub restarts: usize,
    /// Observability index to maximise: O1 (Borm & Menq, the paper's), O2 (σmin/σmax),
    /// O3 (σmin), O4 (σmin²/σmax) or O5 (1/Σ 1/σ).
    pub criterion: Criterion,
    /// `fast`: determinant-lemma trials and Woodbury updates; `naive`: a fresh SVD per
    /// trial, as in the paper (slow; for verification).
    pub method: Method,
    /// Fast method with O2–O5: per addition, the criterion is evaluated exactly on
    /// this many outsiders, those with the best O1 gain; 0 evaluates all.
    #[schemars(range(min = 0, max = 10_000_000))]
    pub shortlist: usize,
}

impl Default for SelectSettings {
    fn default() -> Self {
        SelectSettings {
            n: 50,
            max_iterations: 1000,
            rank_tolerance: 1e-6,
            restarts: 4,
            criterion: Criterion::O1,
            method: Method::Fast,
            shortlist: 64,
        }
    }
}

static INFO: StageInfo = StageInfo {
    kind: "select",
    uses_cable_robot: false,
    updates_input: None,
    summary: "DETMAX selection of calibration rows by an observability index (O1 by default)",
    code_version: 2,
    inputs: &[
        TableSlot {
            name: "candidates",
            schema: schema::conf_wrenches,
            required: true,
            meaning: "conf-wrench rows to choose from",
        },
        TableSlot {
            name: "identifiability",
            schema: schema::identifiability,
            required: false,
            meaning: "which parameters to make observable; rank analysis of the candidates when absent",
        },
    ],
    outputs: &[
        TableSlot {
            name: "selection",
            schema: schema::selection,
            required: true,
            meaning: "cw_id, role (calibration for the n selected, validation for the rest), order",
        },
        TableSlot {
            name: "observability",
            schema: schema::observability,
            required: true,
            meaning: "each exchange and O1 after it; with another criterion also `criterion` and `criterion_value`",
        },
    ],
};

impl Stage for SelectStage {
    type Settings = SelectSettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &SelectSettings,
    ) -> Result<StageOutputs, StageError> {
        let input = ctx.input("candidates")?;
        let (ids, rows) = commanded_rows(ctx, input)?;
        let nominal = ParamValues::nominal(ctx.robot.spec());
        let parameters: Vec<ParamId> = match ctx.inputs.get("identifiability") {
            Some(table) => {
                let names = str_values(&table.df, "name", &table.path)?;
                let flags = table
                    .df
                    .column("identifiable")
                    .and_then(|c| c.bool().map(|b| b.iter().collect::<Vec<_>>()))
                    .map_err(|e| StageError::Invalid(format!("{}: {e}", table.path.display())))?;
                let mut chosen = Vec::new();
                for (row, (name, flag)) in names.iter().zip(flags).enumerate() {
                    let name = name.as_deref().unwrap_or_default();
                    let id = ParamId::from_name(name).ok_or_else(|| {
                        StageError::Table(crate::table::TableError::BadValue {
                            file: table.path.clone(),
                            column: "name".into(),
                            row,
                            message: format!("unknown parameter `{name}`"),
                        })
                    })?;
                    if flag == Some(true) {
                        chosen.push(id);
                    }
                }
                chosen
            }
            None => {
                let all: Vec<ParamId> = ParamId::all().collect();
                rank::analyse(
                    ctx.robot,
                    &nominal,
                    &rows,
                    &all,
                    settings.rank_tolerance,
                    stream::CHUNK_ROWS,
                )
                .independent
            }
        };
        if parameters.is_empty() {
            return Err(StageError::Invalid(
                "no parameter to make observable: the identifiability input marks none identifiable"
                    .into(),
            ));
        }
        let jacobian = batch_jacobian(ctx.robot, &nominal, &rows, &parameters);
        let (candidates, _) =
            Candidates::from_jacobian(&jacobian.jacobian, rows.len(), parameters.len());
        let mut results = Vec::new();
        for restart in 0..settings.restarts as u64 {
            let options = Options {
                n: settings.n,
                criterion: settings.criterion,
                method: settings.method,
                max_iterations: settings.max_iterations,
                shortlist: settings.shortlist,
                seed: ctx
                    .seed
                    .wrapping_add(restart.wrapping_mul(0x9e37_79b9_7f4a_7c15)),
            };
            results.push(detmax(&candidates, &options).map_err(|e| match e {
                DetmaxError::Singular => StageError::Invalid(e.to_string()),
                _ => StageError::Invalid(format!("setting `n`: {e}")),
            })?);
        }
        let value_per_start: Vec<String> =
            results.iter().map(|r| format!("{:.6}", r.value)).collect();
        let result = results
            .into_iter()
            .max_by(|a, b| a.value.total_cmp(&b.value))
            .expect("at least one start");
        if !result.converged {
            ctx.progress.note(&format!(
                "DETMAX stopped at max_iterations = {} before converging",
                settings.max_iterations
            ));
        }

        let mut role = vec!["validation"; ids.len()];
        let mut order: Vec<Option<i64>> = vec![None; ids.len()];
        for (position, &k) in result.chosen.iter().enumerate() {
            role[k] = "calibration";
            order[k] = Some(position as i64 + 1);
        }
        let mut iteration = vec![0i64];
        let mut added = vec![None];
        let mut removed = vec![None];
        let mut o1 = vec![result.o1_start];
        let mut value = vec![result.value_start];
        for exchange in &result.trace {
            iteration.push(exchange.iteration as i64);
            added.push(Some(ids[exchange.added]));
            removed.push(Some(ids[exchange.removed]));
            o1.push(exchange.o1);
            value.push(exchange.value);
        }
        let mut trace = vec![
            Column::new("iteration".into(), iteration),
            Column::new("added_cw_id".into(), added),
            Column::new("removed_cw_id".into(), removed),
            Column::new("o1".into(), o1),
        ];
        if settings.criterion != Criterion::O1 {
            trace.push(Column::new(
                "criterion".into(),
                vec![settings.criterion.name(); value.len()],
            ));
            trace.push(Column::new("criterion_value".into(), value));
        }
        let mut outputs = StageOutputs::default();
        outputs.tables.insert(
            "selection".into(),
            frame(vec![
                Column::new("cw_id".into(), ids.clone()),
                Column::new("role".into(), role),
                Column::new("order".into(), order),
            ]),
        );
        outputs.tables.insert("observability".into(), frame(trace));
        outputs
            .facts
            .insert("parameters".into(), parameters.len().to_string());
        outputs
            .facts
            .insert("selected".into(), settings.n.to_string());
        outputs
            .facts
            .insert("o1".into(), format!("{:.6}", result.o1));
        outputs
            .facts
            .insert("o1_random_start".into(), format!("{:.6}", result.o1_start));
        outputs.facts.insert(
            "o1_scaling".into(),
            "columns scaled to unit norm over all candidates, at nominal".into(),
        );
        outputs
            .facts
            .insert("exchanges".into(), result.trace.len().to_string());
        outputs.facts.insert(
            "criterion".into(),
            format!(
                "{}, {} method",
                settings.criterion.name(),
                match settings.method {
                    Method::Fast => "fast",
                    Method::Naive => "naive",
                }
            ),
        );
        outputs.facts.insert(
            format!("{}_per_start", settings.criterion.name().to_lowercase()),
            value_per_start.join(" "),
        );
        if settings.criterion != Criterion::O1 {
            outputs.facts.insert(
                settings.criterion.name().to_lowercase(),
                format!("{:.6}", result.value),
            );
        }
        Ok(outputs)
    }
}
