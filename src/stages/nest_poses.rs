//! `nest_poses`: adds a positioner's nests to a campaign (issue #30). The
//! arm's candidate rows (from `wrenches`) are kept and named as the arm's
//! SMR; each nest of the robot file's `[positioner]` gets `per_nest` rows
//! at positioner configurations where the tracker sees it
//! (`design::nest_views`), the arm parked and unloaded. The result is one
//! table of candidates with `target_id` and the axes, which
//! `identifiability` and `select` analyse with a translation per target and
//! `measure` runs as a nest campaign.

use polars::prelude::{Column, DataFrame};
use rand::SeedableRng;
use rand::rngs::StdRng;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::{
    SettingsContext, SettingsProblem, Stage, StageContext, StageError, StageInfo, StageOutputs,
    TableSlot,
};
use crate::design::nest_views::{NestView, draw_configurations};
use crate::robot::positioner::MAX_POSITIONER_AXES;
use crate::robot::{MAX_JOINTS, ParamValues};
use crate::table::parameters::target_id_problem;
use crate::table::schema::{
    self, ALL_JOINT_COLUMNS, ALL_PRISMATIC_JOINT_COLUMNS, POSITIONER_COLUMNS, WRENCH_COLUMNS,
    i64_values,
};

pub struct NestPosesStage;

/// Settings of `nest_poses`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct NestPosesSettings {
    /// Positioner configurations measured per nest.
    #[schemars(range(min = 1, max = 100_000))]
    pub per_nest: usize,
    /// The `target_id` the arm's rows get: the SMR on the arm's tool. It
    /// must not be one of the positioner's nests.
    pub arm_target: String,
    /// The arm's joints while the nests are measured (deg), one per joint of
    /// the robot file (six or seven): parked where it neither blocks the
    /// tracker's view of the table nor touches the positioner. Within the
    /// joint limits.
    #[schemars(length(min = 6, max = 7), inner(range(min = -100_000.0, max = 100_000.0)))]
    pub arm_park_deg: Vec<f64>,
    /// Tracker head in the robot base frame (mm); default: the robot file's
    /// nominal world origin.
    #[schemars(inner(range(min = -100_000.0, max = 100_000.0)))]
    pub tracker_mm: Option<[f64; 3]>,
    /// Largest angle between the table's normal (a nest's axis) and the
    /// direction to the tracker: the SMR's acceptance angle.
    #[schemars(range(min = 0.0, max = 90.0))]
    pub acceptance_half_angle_deg: f64,
    /// Configurations drawn per nest before the stage gives up.
    #[schemars(range(min = 1, max = 100_000_000))]
    pub max_draws: usize,
}

impl Default for NestPosesSettings {
    fn default() -> Self {
        NestPosesSettings {
            per_nest: 12,
            arm_target: "arm".into(),
            arm_park_deg: vec![0.0; 6],
            tracker_mm: None,
            acceptance_half_angle_deg: 40.0,
            max_draws: 100_000,
        }
    }
}

static INFO: StageInfo = StageInfo {
    kind: "nest_poses",
    uses_cable_robot: false,
    updates_input: None,
    summary: "The positioner's nests added to a campaign: per nest, configurations the tracker sees, the arm parked",
    code_version: 2,
    inputs: &[TableSlot {
        name: "candidates",
        schema: schema::candidates,
        required: true,
        meaning: "the arm's candidate rows (wrenches' output), without target_id",
    }],
    outputs: &[TableSlot {
        name: "candidates",
        schema: schema::candidates,
        required: true,
        meaning: "the arm's rows (target_id = arm_target) then each nest's rows (target_id, p1_deg, p2_deg; the arm at arm_park_deg, no wrench, tensions null)",
    }],
};

impl Stage for NestPosesStage {
    type Settings = NestPosesSettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn check_settings(
        &self,
        settings: &NestPosesSettings,
        ctx: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        let robot = ctx.robot;
        let Some(positioner) = &robot.positioner else {
            return vec![SettingsProblem::new(
                "",
                format!(
                    "the robot file {} has no [positioner]: `nest_poses` adds the positioner's nests to a campaign",
                    robot.path.display()
                ),
            )];
        };
        let mut problems = Vec::new();
        if let Some(why) = target_id_problem(&settings.arm_target) {
            problems.push(SettingsProblem::new("arm_target", why));
        } else if positioner.nests.contains(&settings.arm_target) {
            problems.push(SettingsProblem::new(
                "arm_target",
                format!(
                    "`{}` is one of the positioner's nests ({}) in the robot file {}: name the arm's SMR otherwise",
                    settings.arm_target,
                    positioner.nests.join(", "),
                    robot.path.display()
                ),
            ));
        }
        if settings.arm_park_deg.len() != robot.joints.len() {
            problems.push(SettingsProblem::new(
                "arm_park_deg",
                format!(
                    "{} values for the {} joints of the robot file {}: give one per joint",
                    settings.arm_park_deg.len(),
                    robot.joints.len(),
                    robot.path.display()
                ),
            ));
        }
        for (joint, (q, spec)) in settings.arm_park_deg.iter().zip(&robot.joints).enumerate() {
            let [lo, hi] = spec.limits();
            if !(q.is_finite() && (lo..=hi).contains(q)) {
                let unit = spec.kind.unit();
                problems.push(SettingsProblem::new(
                    "arm_park_deg",
                    format!(
                        "joint {}: {q} {unit} is outside its limits [{lo}, {hi}] {unit} (robot file {})",
                        joint + 1,
                        robot.path.display()
                    ),
                ));
            }
        }
        if settings.tracker_mm.is_none() && !robot.has_world {
            problems.push(SettingsProblem::new(
                "tracker_mm",
                format!(
                    "not set, and the robot file {} has no `[world]` to place the tracker from: give `tracker_mm = [x, y, z]` (the tracker head in the base frame, mm)",
                    robot.path.display()
                ),
            ));
        }
        problems
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &NestPosesSettings,
    ) -> Result<StageOutputs, StageError> {
        let input = ctx.input("candidates")?;
        if input.df.column("target_id").is_ok() {
            return Err(StageError::Invalid(format!(
                "{}: the candidates already name their targets (column `target_id`): `nest_poses` takes the arm's candidates, as `wrenches` writes them",
                input.path.display()
            )));
        }
        let spec = ctx.robot.spec();
        let positioner_spec = spec
            .positioner
            .as_ref()
            .ok_or_else(|| StageError::Invalid("the robot file has no [positioner]".into()))?;
        let nominal = ParamValues::nominal(spec);
        let prepared = ctx.robot.prepare(&nominal);
        let positioner = prepared
            .positioner
            .as_ref()
            .ok_or_else(|| StageError::Invalid("the robot file has no [positioner]".into()))?;
        let view = NestView {
            tracker_mm: match settings.tracker_mm {
                Some(t) => t.into(),
                None => ctx.robot.world_from_base(&nominal).inverse().origin_mm,
            },
            acceptance_half_angle_deg: settings.acceptance_half_angle_deg,
        };
        let limits: Vec<[f64; 2]> = positioner_spec.axes.iter().map(|a| a.limits_deg).collect();
        let mut nest_rows: Vec<(&str, [f64; MAX_POSITIONER_AXES])> = Vec::new();
        let mut outputs = StageOutputs::default();
        for (k, nest) in positioner_spec.nests.iter().enumerate() {
            let mut rng = StdRng::seed_from_u64(
                ctx.seed ^ (k as u64 + 1).wrapping_mul(0x9e37_79b9_7f4a_7c15),
            );
            let (kept, draws) = draw_configurations(
                positioner,
                &limits,
                &view,
                settings.per_nest,
                settings.max_draws,
                &mut rng,
            );
            if kept.len() < settings.per_nest {
                return Err(StageError::Failed(format!(
                    "nest `{nest}`: the tracker at {:?} mm (base frame) saw the table within acceptance_half_angle_deg = {} on {} of {draws} configurations drawn, fewer than per_nest = {}: widen the angle, move the tracker (tracker_mm), or raise max_draws",
                    view.tracker_mm.as_slice(),
                    settings.acceptance_half_angle_deg,
                    kept.len(),
                    settings.per_nest
                )));
            }
            outputs.facts.insert(
                format!("seen_fraction_{nest}"),
                format!("{:.3}", kept.len() as f64 / draws as f64),
            );
            nest_rows.extend(kept.into_iter().map(|p| (nest.as_str(), p)));
        }
        let table = with_nest_rows(
            input,
            &settings.arm_target,
            &crate::robot::joint_array(&settings.arm_park_deg),
            positioner_spec.axes.len(),
            &nest_rows,
        )?;
        outputs
            .facts
            .insert("arm_rows".into(), input.df.height().to_string());
        outputs
            .facts
            .insert("nest_rows".into(), nest_rows.len().to_string());
        outputs.tables.insert("candidates".into(), table);
        Ok(outputs)
    }
}

/// The arm's candidates named `arm_target`, then a row per nest
/// configuration: new `cw_id`s and `config_id`s after the arm's, the arm
/// at `park_deg` without a wrench, every other column null.
fn with_nest_rows(
    input: &super::InputTable,
    arm_target: &str,
    park_deg: &[f64; MAX_JOINTS],
    axes: usize,
    nest_rows: &[(&str, [f64; MAX_POSITIONER_AXES])],
) -> Result<DataFrame, StageError> {
    let after = |name: &str| -> Result<i64, StageError> {
        let values = i64_values(&input.df, name, &input.path)?;
        Ok(values.into_iter().max().map_or(1, |m| m + 1))
    };
    let (first_cw, first_config) = (after("cw_id")?, after("config_id")?);
    let n = nest_rows.len();
    let numbered = |first: i64| (0..n as i64).map(|k| first + k).collect::<Vec<_>>();
    let nest_columns: Vec<Column> = input
        .df
        .columns()
        .iter()
        .map(|c| {
            let name = c.name().as_str();
            if name == "cw_id" {
                Column::new(c.name().clone(), numbered(first_cw))
            } else if name == "config_id" {
                Column::new(c.name().clone(), numbered(first_config))
            } else if let Some(joint) = ALL_JOINT_COLUMNS
                .iter()
                .position(|j| *j == name)
                .or_else(|| ALL_PRISMATIC_JOINT_COLUMNS.iter().position(|j| *j == name))
            {
                Column::new(c.name().clone(), vec![park_deg[joint]; n])
            } else if WRENCH_COLUMNS.contains(&name) {
                Column::new(c.name().clone(), vec![0.0; n])
            } else {
                Column::full_null(c.name().clone(), n, c.dtype())
            }
        })
        .collect();
    let polars_error =
        |e: polars::prelude::PolarsError| StageError::Failed(format!("nest rows: {e}"));
    let nests = DataFrame::new(n, nest_columns).map_err(polars_error)?;
    let mut table = input.df.clone();
    table.vstack_mut(&nests).map_err(polars_error)?;
    let arm_rows = input.df.height();
    let target_ids: Vec<&str> = std::iter::repeat_n(arm_target, arm_rows)
        .chain(nest_rows.iter().map(|(nest, _)| *nest))
        .collect();
    table
        .with_column(Column::new("target_id".into(), target_ids))
        .map_err(polars_error)?;
    for (axis, name) in POSITIONER_COLUMNS[..axes].iter().enumerate() {
        let values: Vec<Option<f64>> = std::iter::repeat_n(None, arm_rows)
            .chain(nest_rows.iter().map(|(_, p)| Some(p[axis])))
            .collect();
        table
            .with_column(Column::new((*name).into(), values))
            .map_err(polars_error)?;
    }
    table.rechunk_mut();
    Ok(table)
}
