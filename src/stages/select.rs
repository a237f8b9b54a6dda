//! `select`: picks the n conf-wrench rows that maximise an observability index (O1
//! by default, the paper's; O2–O5 selectable) of the identifiable parameters by
//! DETMAX (paper §IV.B). The other rows become the validation set. See
//! `design::detmax` for the algorithm, its fast and naive engines and the column
//! scaling, `design::observability` for the indices.
//!
//! With the optional input `targets` (the work, spec §7), each target's
//! configuration is found by nominal loaded IK (as `compensate` with `model =
//! "nominal"`), and the predicted 95 % position uncertainty there after
//! identification on the selected rows (σ = `tracker_sigma_mm` per axis) is
//! written per target (`work_targets`) and against n (`u95_curve`, the stopping
//! rule: the smallest n whose largest u95 reaches `required_u95_mm`). With
//! `criterion = "I"` or `"V"` the rows are chosen for those targets
//! (`design::work_criterion`): the least mean variance, or the least largest
//! u95. Without `targets` nothing of this runs and the stage is as before.

use std::collections::BTreeMap;

use polars::prelude::Column;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::compensate::{WORLD_FRAME, nominal_target_commands, target_frame_problems};
use super::target_slots::{aim_candidates, cell_parameters};
use super::{
    SettingsContext, SettingsProblem, Stage, StageContext, StageError, StageInfo, StageOutputs,
    TableSlot, commanded_rows,
};
use crate::calibration::{rank, stream};
use crate::compensation::Status;
use crate::design::branch_coverage::{branch_coverage, describe};
use crate::design::detmax::{
    Candidates, Criterion, DetmaxError, Method, Options, detmax, observability_index,
};
use crate::design::work_criterion::{
    self, WorkCriterion, WorkOptions, WorkSelection, WorkTargets, work_detmax,
};
use crate::robot::{ConfWrench, MAX_JOINTS, ParamId, ParamValues, batch_jacobian, ik};
use crate::table::frame;
use crate::table::parameters::param_of_name;
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
    /// O3 (σmin), O4 (σmin²/σmax) or O5 (1/Σ 1/σ); or, with the `targets` input, a
    /// design for the work: I (least mean predicted variance at the targets,
    /// I-optimal) or V (least largest u95 at the targets, minimax).
    pub criterion: SelectCriterion,
    /// `fast`: determinant-lemma trials and Woodbury updates; `naive`: a fresh SVD per
    /// trial, as in the paper (slow; for verification).
    pub method: Method,
    /// Fast method with O2–O5: per addition, the criterion is evaluated exactly on
    /// this many outsiders, those with the best O1 gain; 0 evaluates all.
    #[schemars(range(min = 0, max = 10_000_000))]
    pub shortlist: usize,
    /// With `targets`: the measurement noise per axis (mm) the predicted
    /// uncertainty assumes, the tracker's (0.02 mm: a FARO-class tracker at
    /// ~3 m, as the simulated campaigns use); u95 scales with it.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    #[schemars(range(max = 100.0))]
    pub tracker_sigma_mm: f64,
    /// With `targets`: the largest u95 (mm) the work needs at its targets. The
    /// stage reports the smallest n that reaches it on the curve, and warns
    /// when the selected n does not.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schemars(range(min = 0.0, max = 1000.0))]
    pub required_u95_mm: Option<f64>,
    /// With `targets`: the curve of u95 against n runs from the fewest rows that
    /// can identify the parameters (m/3) to this many (0: twice `n`).
    #[schemars(range(min = 0, max = 100_000))]
    pub curve_max_n: usize,
    /// With `targets`: the frame of targets whose `frame` column is null or
    /// absent, as `compensate` reads it (`world`, `base` or a name of `frames`).
    pub frame: String,
    /// With `targets`: user frames, as `compensate`'s setting `frames`.
    pub frames: BTreeMap<String, [f64; 6]>,
}

/// What `select` optimises.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, JsonSchema)]
pub enum SelectCriterion {
    /// Borm & Menq: (σ1·…·σm)^(1/m)/√n, the paper's eq. (26).
    #[default]
    O1,
    /// Driels & Pathre: σmin/σmax.
    O2,
    /// Nahvi, Hollerbach & Hayward: σmin.
    O3,
    /// Nahvi & Hollerbach: σmin²/σmax.
    O4,
    /// Sun & Hollerbach: 1/Σ(1/σi).
    O5,
    /// With `targets`: the mean over the targets of the predicted position
    /// variance (I-optimal), minimised.
    I,
    /// With `targets`: the largest predicted u95 over the targets (minimax), minimised.
    V,
}

impl SelectCriterion {
    fn observability(self) -> Option<Criterion> {
        match self {
            SelectCriterion::O1 => Some(Criterion::O1),
            SelectCriterion::O2 => Some(Criterion::O2),
            SelectCriterion::O3 => Some(Criterion::O3),
            SelectCriterion::O4 => Some(Criterion::O4),
            SelectCriterion::O5 => Some(Criterion::O5),
            SelectCriterion::I | SelectCriterion::V => None,
        }
    }

    fn work(self) -> Option<WorkCriterion> {
        match self {
            SelectCriterion::I => Some(WorkCriterion::Mean),
            SelectCriterion::V => Some(WorkCriterion::Max),
            _ => None,
        }
    }

    fn name(self) -> &'static str {
        match (self.observability(), self) {
            (Some(c), _) => c.name(),
            (None, SelectCriterion::I) => "I",
            _ => "V",
        }
    }
}

impl Default for SelectSettings {
    fn default() -> Self {
        SelectSettings {
            n: 50,
            max_iterations: 1000,
            rank_tolerance: 1e-6,
            restarts: 4,
            criterion: SelectCriterion::O1,
            method: Method::Fast,
            shortlist: 64,
            tracker_sigma_mm: 0.02,
            required_u95_mm: None,
            curve_max_n: 0,
            frame: WORLD_FRAME.to_string(),
            frames: BTreeMap::new(),
        }
    }
}

static INFO: StageInfo = StageInfo {
    kind: "select",
    uses_cable_robot: false,
    updates_input: None,
    summary: "DETMAX selection of calibration rows by an observability index (O1 by default)",
    code_version: 7,
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
        TableSlot {
            name: "targets",
            schema: schema::targets,
            required: false,
            meaning: "the work (spec §7 targets, with their wrenches and branch hints): the predicted u95 there is reported, and criterion I or V designs for it",
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
        TableSlot {
            name: "work_targets",
            schema: schema::work_targets,
            required: false,
            meaning: "with `targets`: each target's status, configuration (nominal loaded IK) and predicted covariance and u95 after identification on the selected rows",
        },
        TableSlot {
            name: "u95_curve",
            schema: schema::u95_curve,
            required: false,
            meaning: "with `targets`: predicted mean and largest u95 at the targets against n (the stopping rule)",
        },
    ],
};

impl Stage for SelectStage {
    type Settings = SelectSettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn check_settings(
        &self,
        settings: &SelectSettings,
        ctx: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        let with_targets = ctx.bound_inputs.contains(&"targets");
        let mut problems = Vec::new();
        if settings.criterion.work().is_some() && !with_targets {
            problems.push(SettingsProblem::new(
                "criterion",
                format!(
                    "criterion {} designs for the work targets: bind the input `targets`",
                    settings.criterion.name()
                ),
            ));
        }
        if with_targets {
            problems.extend(target_frame_problems(&settings.frame, &settings.frames));
        }
        problems
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &SelectSettings,
    ) -> Result<StageOutputs, StageError> {
        let input = ctx.input("candidates")?;
        let (ids, mut rows) = commanded_rows(ctx, input)?;
        let targets = aim_candidates(input, &mut rows)?;
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
                // A name of another arm (`k7` for a six-joint one) is as
                // unknown here as a typo.
                let known = cell_parameters(ctx.robot.spec(), targets.ids.len().max(1));
                for (row, (name, flag)) in names.iter().zip(flags).enumerate() {
                    let name = name.as_deref().unwrap_or_default();
                    let of_cell = param_of_name(name, &targets.ids).filter(|id| known.contains(id));
                    let id = of_cell.ok_or_else(|| {
                        StageError::Table(crate::table::TableError::BadValue {
                            file: table.path.clone(),
                            column: "name".into(),
                            row,
                            message: format!(
                                "unknown parameter `{name}` for candidates of {}",
                                match targets.ids.len() {
                                    0 | 1 => "one target".to_string(),
                                    _ => format!("the targets {}", targets.ids.join(", ")),
                                }
                            ),
                        })
                    })?;
                    if flag == Some(true) {
                        chosen.push(id);
                    }
                }
                chosen
            }
            None => {
                let all = cell_parameters(ctx.robot.spec(), targets.count());
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
        let (candidates, scale) =
            Candidates::from_jacobian(&jacobian.jacobian, rows.len(), parameters.len());
        let work = match ctx.inputs.get("targets") {
            Some(input) => Some(work_targets(
                ctx,
                settings,
                input,
                &parameters,
                &scale,
                targets.arm_slot(ctx.robot.spec()),
            )?),
            None => None,
        };
        let seed_of = |restart: u64| {
            ctx.seed
                .wrapping_add(restart.wrapping_mul(0x9e37_79b9_7f4a_7c15))
        };
        let n_error = |e: DetmaxError| match e {
            DetmaxError::Singular => StageError::Invalid(e.to_string()),
            _ => StageError::Invalid(format!("setting `n`: {e}")),
        };
        let work_options = |criterion: WorkCriterion, seed: u64| WorkOptions {
            n: settings.n,
            criterion,
            method: settings.method,
            max_iterations: settings.max_iterations,
            shortlist: settings.shortlist,
            seed,
            sigma_mm: settings.tracker_sigma_mm,
        };
        let mut results = Vec::new();
        for restart in 0..settings.restarts as u64 {
            let seed = seed_of(restart);
            let result = match (settings.criterion.observability(), &work) {
                (Some(criterion), _) => detmax(
                    &candidates,
                    &Options {
                        n: settings.n,
                        criterion,
                        method: settings.method,
                        max_iterations: settings.max_iterations,
                        shortlist: settings.shortlist,
                        seed,
                    },
                ),
                (None, Some(work)) => {
                    let criterion = settings.criterion.work().expect("I or V");
                    work_detmax(&candidates, &work.targets, &work_options(criterion, seed))
                        .map(|w| as_selection(&candidates, w))
                }
                (None, None) => {
                    return Err(StageError::Invalid(format!(
                        "criterion {} needs the input `targets`",
                        settings.criterion.name()
                    )));
                }
            };
            results.push(result.map_err(n_error)?);
        }
        let value_per_start: Vec<String> = results
            .iter()
            .map(|r| match settings.criterion.work() {
                Some(_) => format!("{:.6e}", -r.value),
                None => format!("{:.6}", r.value),
            })
            .collect();
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
        if settings.criterion != SelectCriterion::O1 {
            // I and V are minimised: their value is the negated criterion
            // internally (see `as_selection`); the table says the criterion.
            let value: Vec<f64> = match settings.criterion.work() {
                Some(_) => value.iter().map(|v| -v).collect(),
                None => value,
            };
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
        if let Some(work) = settings.criterion.work() {
            outputs.facts.insert(
                settings.criterion.name().to_lowercase(),
                format!(
                    "{:.6e} {}",
                    -result.value,
                    match work {
                        WorkCriterion::Mean => "mm² (mean predicted variance at the targets)",
                        WorkCriterion::Max => "mm (largest u95 at the targets)",
                    }
                ),
            );
        } else if settings.criterion != SelectCriterion::O1 {
            outputs.facts.insert(
                settings.criterion.name().to_lowercase(),
                format!("{:.6}", result.value),
            );
        }
        if let Some(work) = &work {
            let curve_criterion = settings.criterion.work().unwrap_or(WorkCriterion::Mean);
            let mut warnings =
                branch_warnings(ctx, work, &rows, &result.chosen, &mut outputs.facts);
            warnings.extend(report_work(
                ctx,
                settings,
                work,
                &candidates,
                &result.chosen,
                &work_options(curve_criterion, seed_of(0)),
                &mut outputs,
            )?);
            for warning in &warnings {
                ctx.progress.note(&format!("warning: {warning}"));
            }
            if !warnings.is_empty() {
                outputs.facts.insert("warning".into(), warnings.join("; "));
            }
        }
        Ok(outputs)
    }
}

/// A work-driven selection in the shape of a DETMAX one, its criterion negated
/// so that "higher is better" holds for the restarts and the trace, and O1 of
/// every set on the way (walking back from the final set) for the trace.
fn as_selection(c: &Candidates, w: WorkSelection) -> crate::design::detmax::Selection {
    let mut set = w.chosen.clone();
    let mut o1_after = vec![0.0; w.trace.len()];
    for (i, exchange) in w.trace.iter().enumerate().rev() {
        o1_after[i] = observability_index(c, &set);
        if exchange.added != exchange.removed {
            set.retain(|&k| k != exchange.added);
            set.push(exchange.removed);
        }
    }
    crate::design::detmax::Selection {
        o1: w.o1,
        value: -w.value,
        o1_start: observability_index(c, &set),
        value_start: -w.value_start,
        trace: w
            .trace
            .iter()
            .zip(o1_after)
            .map(|(e, o1)| crate::design::detmax::Exchange {
                iteration: e.iteration,
                added: e.added,
                removed: e.removed,
                o1,
                value: -e.value,
            })
            .collect(),
        chosen: w.chosen,
        converged: w.converged,
        refactorisations: w.refactorisations,
    }
}

/// The work targets as `select` uses them: each one's id, status and
/// configuration, and the scaled Jacobian of the `ok` ones.
struct Work {
    ids: Vec<i64>,
    status: Vec<Status>,
    q_deg: Vec<[f64; MAX_JOINTS]>,
    /// Positions in `ids` of the `ok` targets, the rows of `targets`.
    ok: Vec<usize>,
    targets: WorkTargets,
}

fn work_targets(
    ctx: &StageContext,
    settings: &SelectSettings,
    input: &super::InputTable,
    parameters: &[ParamId],
    scale: &[f64],
    arm_slot: usize,
) -> Result<Work, StageError> {
    let (ids, targets, commands) =
        nominal_target_commands(ctx.robot, &settings.frame, &settings.frames, input)?;
    let ok: Vec<usize> = (0..ids.len())
        .filter(|&k| commands[k].status == Status::Ok)
        .collect();
    if ok.is_empty() {
        return Err(StageError::Invalid(format!(
            "{}: none of the {} targets has a configuration on the nominal robot (statuses: {}); nothing to design for",
            input.path.display(),
            ids.len(),
            statuses(&commands.iter().map(|c| c.status).collect::<Vec<_>>())
        )));
    }
    if ok.len() < ids.len() {
        ctx.progress.note(&format!(
            "{} of {} targets are not ok on the nominal robot ({}); designing for the other {}",
            ids.len() - ok.len(),
            ids.len(),
            statuses(&commands.iter().map(|c| c.status).collect::<Vec<_>>()),
            ok.len()
        ));
    }
    let rows: Vec<ConfWrench> = ok
        .iter()
        .map(|&k| ConfWrench {
            // The work is the arm's: its SMR's tool, among several targets.
            target: arm_slot,
            ..ConfWrench::new(commands[k].q_deg, targets[k].wrench)
        })
        .collect();
    let nominal = ParamValues::nominal(ctx.robot.spec());
    let jacobian = batch_jacobian(ctx.robot, &nominal, &rows, parameters);
    Ok(Work {
        ids,
        status: commands.iter().map(|c| c.status).collect(),
        q_deg: commands.iter().map(|c| c.q_deg).collect(),
        targets: WorkTargets::from_jacobian(&jacobian.jacobian, ok.len(), scale),
        ok,
    })
}

/// "ok 18, joint_limit 2": the statuses present and their counts.
fn statuses(status: &[Status]) -> String {
    Status::ALL
        .iter()
        .filter_map(|s| {
            let count = status.iter().filter(|t| *t == s).count();
            (count > 0).then(|| format!("{} {count}", s.as_str()))
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// `work_targets`, `u95_curve` and the stopping rule's facts; its warning.
fn report_work(
    ctx: &StageContext,
    settings: &SelectSettings,
    work: &Work,
    candidates: &Candidates,
    chosen: &[usize],
    options: &WorkOptions,
    outputs: &mut StageOutputs,
) -> Result<Vec<String>, StageError> {
    let prediction = work_criterion::predict(candidates, &work.targets, chosen, options.sigma_mm)
        .ok_or_else(|| {
        StageError::Invalid("the selected rows cannot identify the parameters".into())
    })?;
    let mut covariances = vec![None; work.ids.len()];
    for (row, &k) in work.ok.iter().enumerate() {
        covariances[k] = Some(prediction.covariances_mm2[row]);
    }
    let ok = |k: usize| work.status[k] == Status::Ok;
    let mut columns = vec![
        Column::new("target_id".into(), work.ids.clone()),
        Column::new(
            "status".into(),
            work.status.iter().map(|s| s.as_str()).collect::<Vec<_>>(),
        ),
    ];
    for (joint, name) in schema::joint_column_names(ctx.robot.spec())
        .iter()
        .enumerate()
    {
        columns.push(Column::new(
            (*name).into(),
            (0..work.ids.len())
                .map(|k| ok(k).then_some(work.q_deg[k][joint]))
                .collect::<Vec<_>>(),
        ));
    }
    columns.push(Column::new(
        "branch".into(),
        (0..work.ids.len())
            .map(|k| ok(k).then(|| i64::from(ik::branch_of(ctx.robot, &work.q_deg[k]))))
            .collect::<Vec<_>>(),
    ));
    columns.extend(super::covariance_columns(&covariances));
    columns.push(Column::new(
        "u95_mm".into(),
        covariances
            .iter()
            .map(|c| c.as_ref().map(crate::calibration::accuracy_map::u95_mm))
            .collect::<Vec<_>>(),
    ));
    outputs.tables.insert("work_targets".into(), frame(columns));

    let m = candidates.parameters();
    let from = m.div_ceil(3).max(1);
    let to = match settings.curve_max_n {
        0 => 2 * settings.n,
        n => n,
    }
    .max(from)
    .min(candidates.len());
    let curve = work_criterion::curve(candidates, &work.targets, options, from, to)
        .map_err(|e| StageError::Invalid(format!("the u95 curve: {e}")))?;
    outputs.tables.insert(
        "u95_curve".into(),
        frame(vec![
            Column::new(
                "n".into(),
                curve.iter().map(|p| p.n as i64).collect::<Vec<_>>(),
            ),
            Column::new(
                "mean_u95_mm".into(),
                curve.iter().map(|p| p.mean_u95_mm).collect::<Vec<_>>(),
            ),
            Column::new(
                "max_u95_mm".into(),
                curve.iter().map(|p| p.max_u95_mm).collect::<Vec<_>>(),
            ),
        ]),
    );
    let facts = &mut outputs.facts;
    facts.insert(
        "work_targets".into(),
        format!("{} of {} ok", work.ok.len(), work.ids.len()),
    );
    facts.insert(
        "mean_u95_mm".into(),
        format!("{:.4}", prediction.mean_u95_mm()),
    );
    facts.insert(
        "max_u95_mm".into(),
        format!("{:.4}", prediction.max_u95_mm()),
    );
    facts.insert(
        "tracker_sigma_mm".into(),
        format!("{}", settings.tracker_sigma_mm),
    );
    let mut warnings = Vec::new();
    if let Some(required) = settings.required_u95_mm {
        let reached = curve.iter().find(|p| p.max_u95_mm <= required);
        let (key, value) = match reached {
            Some(p) => ("n_required", p.n.to_string()),
            None => (
                "n_required",
                format!(
                    "not reached by n = {to} (largest u95 there {:.4} mm)",
                    curve.last().map_or(f64::NAN, |p| p.max_u95_mm)
                ),
            ),
        };
        facts.insert(key.into(), value);
        if prediction.max_u95_mm() > required {
            let warning = format!(
                "the {} selected rows predict a largest u95 of {:.4} mm at the targets, above required_u95_mm = {required} mm{}",
                settings.n,
                prediction.max_u95_mm(),
                match reached {
                    Some(p) => format!(
                        "; a design for the targets (u95_curve, criterion {}) reaches it at n = {}",
                        if options.criterion == WorkCriterion::Max {
                            "V"
                        } else {
                            "I"
                        },
                        p.n
                    ),
                    None => format!("; no n up to {to} reaches it"),
                }
            );
            warnings.push(warning);
        }
    }
    Ok(warnings)
}

/// The `work_branches` fact (per IK branch of the `ok` targets: targets,
/// candidates, selected rows) and a warning for each branch no candidate, or
/// no selected row, shares ([`branch_coverage`]).
fn branch_warnings(
    ctx: &StageContext,
    work: &Work,
    rows: &[ConfWrench],
    chosen: &[usize],
    facts: &mut BTreeMap<String, String>,
) -> Vec<String> {
    let targets_q: Vec<[f64; MAX_JOINTS]> = work.ok.iter().map(|&k| work.q_deg[k]).collect();
    let candidates_q: Vec<[f64; MAX_JOINTS]> = rows.iter().map(|r| r.q_deg).collect();
    let coverage = branch_coverage(ctx.robot, &targets_q, &candidates_q, chosen);
    facts.insert(
        "work_branches".into(),
        coverage
            .iter()
            .map(|c| {
                format!(
                    "branch {}: {} targets, {} candidates, {} selected",
                    c.branch, c.targets, c.candidates, c.selected
                )
            })
            .collect::<Vec<_>>()
            .join("; "),
    );
    coverage
        .iter()
        .filter(|c| c.selected == 0)
        .map(|c| {
            let whose = if c.candidates == 0 {
                "no candidate is in it (poses: another box, tool orientation or acceptance angle)"
            } else {
                "no selected row is in it (raise n, or design for the targets: criterion I or V)"
            };
            format!(
                "{} work targets are reached in IK branch {} ({}), and {whose}: the calibration is extrapolated there, whatever u95 predicts",
                c.targets,
                c.branch,
                describe(c.branch),
            )
        })
        .collect()
}
