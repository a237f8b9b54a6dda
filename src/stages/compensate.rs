//! `compensate`: the joint command per target that puts the calibrated, loaded
//! robot's tool on it, and the corrected Cartesian target for a controller that
//! keeps its nominal model (`../shared/spec/model.md` §7, §8; the maths is
//! [`crate::compensation`]). This file reads and checks the `targets` rows,
//! brings them into the world frame, chooses each row's tool, judges each
//! command against the calibration's envelope, and writes `commands` and
//! `conf_wrenches`.
//!
//! `conf_wrenches` holds the `ok` commands as conf-wrench rows (cw_id =
//! target_id, q = the command, the target's wrench), so a `measure` stage can run
//! them on a rig or the simulator and the achieved positions can be compared
//! with the targets.
//!
//! **Frames** (spec §8). A row's pose is in the frame its `frame` column names,
//! else in the setting `frame` (default `world`): `world` is the tracker frame
//! the calibration's world parameters place the robot in; `base` the robot's
//! base frame; any other name a user frame (work object) of the setting
//! `frames`, given as `[x_mm, y_mm, z_mm, rx_deg, ry_deg, rz_deg]` in the base
//! frame, read like a target's pose (origin, then base←user =
//! Rot(x, rx)·Rot(y, ry)·Rot(z, rz)). Base and user-frame poses reach the world
//! through the chosen set's world frame (the robot file's for nominal), the
//! frame the commands are solved in. A table most of whose targets come back
//! `unreachable` (more than `max_unreachable_fraction`) was almost surely
//! written in another frame (or unit): the stage refuses it, naming the frame
//! it assumed, instead of writing a table of failures with exit 0.
//!
//! **A robot on a linear track** (robot file `[track]`). Each target gives
//! the carriage position to reach it from (`e1_mm`, required); the command
//! is the arm's joints with the carriage there, solved through the
//! calibrated carriage (its straightness, angles and scale), and `commands`
//! and `conf_wrenches` carry the same `e1_mm`. `base` is the base with the
//! carriage at 0 (the frame fixed to the floor that the world frame
//! places), and user frames are given in it.
//!
//! **Targets on a positioner** (robot file `[positioner]`). A row in the
//! frame `positioner` is a pose on the positioner's table at the axis values
//! its `p1_deg`, `p2_deg` give (required on such rows, within the limits):
//! it reaches the world through the chosen set's positioner (its base and
//! axes, calibrated with the nests), so the part's targets follow where the
//! table really is. `commands` carries each row's axis values, the
//! positioner's commands beside the arm's.
//!
//! **A seven-joint arm.** Its redundancy is resolved by holding joint 3
//! ([`crate::robot::ik::HELD_JOINT_OF_SEVEN`]) at the row's branch hint
//! `q3_deg` (a hint is then `q1_deg … q7_deg`), else at `held_joint_deg`;
//! the other six place the tool, and `commands` carries `q7_deg`.
//!
//! **Tools** (spec §8). A row aims the parameters' target named by its
//! `tool_id` column, else by the setting `tool`. A several-target set needs one
//! of them on every row; a name the set does not know is refused, naming the
//! ones it has. A one-target set (and the nominal model) has one tool, which
//! every row aims whatever it names. The chosen name is written to `commands`
//! (`tool_id`), so an exported program can declare the same tool.
//!
//! **Envelope** (spec §8). With the optional input `envelope` (the
//! configurations the calibration was identified on, e.g. identify's
//! `measurements`, restricted to a `selection`'s calibration rows when one is
//! bound), each command's `envelope_distance` is its joint-space distance to
//! the nearest of them ([`crate::compensation::envelope`]: largest per-joint
//! difference, wrapped, over the arm's joints). With the optional `covariance`,
//! `u95_mm` is the radius of the predicted position's 95 % uncertainty at the
//! command, `sqrt(χ²₃(0.95)·λmax(J·Σ·Jᵀ))` (the longest semi-axis of the 95 %
//! ellipsoid, as `accuracy_map` reports it), and `commands` also carries
//! `cov_xx_mm2 … cov_zz_mm2` (spec §7). An `ok` command beyond
//! `max_envelope_distance_deg` or `max_u95_mm` (or, on a track, whose carriage
//! position lies more than `max_track_beyond_mm` beyond the rows' positions,
//! `track_beyond_mm`) becomes `outside_envelope`,
//! which an exported program treats like every other status but `ok`
//! (`on_failed`). A calibrated model compensated without `envelope` (or
//! without `covariance`) is not checked: the column is null and the stage says
//! so in a warning (its log and the `warning` fact kept with the table).

use std::collections::BTreeMap;

use nalgebra::Vector3;
use polars::prelude::{Column, DataFrame, DataType};
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::identify::ids_with_role;
use super::{
    InputTable, SettingsContext, SettingsProblem, Stage, StageContext, StageError, StageInfo,
    StageOutputs, TableSlot, bound_covariance, covariance_binding_problem, covariance_columns,
    model_name_problem, model_set, row_covariances,
};
use crate::calibration::accuracy_map::u95_mm;
use crate::calibration::row_checks::{MAX_POSITION_MM, compact, joints_problem, wrench_problem};
use crate::compensation::envelope::{self, EnvelopeLimits, EnvelopeMeasures, JointEnvelope};
use crate::compensation::{self, Command, Options, Status, Target, pose_frame};
use crate::robot::ik::NumericOptions;
use crate::robot::positioner::MAX_POSITIONER_AXES;
use crate::robot::{ConfWrench, Frame, MAX_JOINTS, ParamId, ParamValues, Robot, Wrench};
use crate::table::frame;
use crate::table::parameters::{ModelName, ParameterSet};
use crate::table::schema::{
    self, COMMAND_POSITION_COLUMNS, COMMAND_QUATERNION_COLUMNS, ORIENTATION_COLUMNS,
    POSITION_COLUMNS, WRENCH_COLUMNS, f64_values, i64_values, io_error, str_values,
};

pub struct CompensateStage;

/// The tracker frame: what `frame` means by default.
pub const WORLD_FRAME: &str = "world";
/// The robot's base frame.
pub const BASE_FRAME: &str = "base";
/// The table of the robot file's positioner at the row's `p1_deg`, `p2_deg`.
pub const POSITIONER_FRAME: &str = "positioner";

/// Settings of `compensate`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct CompensateSettings {
    /// Which model of the `parameters` input to compensate with: nominal,
    /// registered, kinematic or elastogeometric. Ignored when no parameters table
    /// is bound (nominal).
    pub model: String,
    /// A command is converged when the tool position is within this of the target (mm).
    #[schemars(range(min = 1e-12, max = 1.0))]
    pub position_tolerance_mm: f64,
    /// ... and the tool orientation within this (rad).
    #[schemars(range(min = 1e-14, max = 0.01))]
    pub orientation_tolerance_rad: f64,
    /// Levenberg–Marquardt iterations per target before `not_converged`.
    #[schemars(range(min = 1, max = 10_000))]
    pub max_iterations: usize,
    /// A converged command is `singular` when the smallest singular value of the
    /// geometric Jacobian at the tool (1 rad of rotation counted as 1000 mm) is
    /// below this (mm/rad); about 7 mm/rad per degree of q5 from the IRB 1600's
    /// straight wrist, so the default flags |q5| below about 0.5°. 0 reports no singularity of a converged command.
    #[schemars(range(min = 0.0, max = 10_000.0))]
    pub singular_sigma_min_mm_per_rad: f64,
    /// Frame of the targets whose `frame` column is null or absent: `world`
    /// (the tracker frame), `base` (the robot's base frame) or a name of `frames`.
    pub frame: String,
    /// User frames (work objects): name → `[x_mm, y_mm, z_mm, rx_deg, ry_deg,
    /// rz_deg]`, the frame's origin and orientation in the robot's base frame
    /// (base←user = Rot(x, rx)·Rot(y, ry)·Rot(z, rz)), as a target's pose is written.
    pub frames: BTreeMap<String, [f64; 6]>,
    /// The parameters' target (SMR nest, tool) of the rows whose `tool_id` is
    /// null or absent; needed with a several-target set unless every row names one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tool: Option<String>,
    /// An `ok` command farther than this from the nearest calibration row
    /// (`envelope_distance`: the largest per-joint difference, deg) is
    /// `outside_envelope`. The default, 40°, passes every held-out row of the
    /// sparse simulated campaign (50 calibration rows; at most 31.4° from
    /// them) and its compensated targets (at most 30.4°), and flags the
    /// configurations where compensation was found wanting: the simulated
    /// loop's first targets (90° and more away, 4× the validation error) and
    /// the UR10 targets at q2 ≈ −43° calibrated on q2 ≤ −90° (47° and more).
    #[schemars(range(min = 0.0, max = 360.0))]
    pub max_envelope_distance_deg: f64,
    /// An `ok` command whose predicted 95 % position uncertainty (`u95_mm`,
    /// with a `covariance`) is larger than this (mm) is `outside_envelope`:
    /// set it to what the work needs. The default, 0.5 mm, is twice the largest
    /// u95 on the UR10's own calibration rows (0.24 mm; the simulated cell's
    /// are below 0.1 mm); the UR10's series B configurations, 30°–120° from
    /// them, reach 0.68 mm.
    #[schemars(range(min = 0.0, max = 1000.0))]
    pub max_u95_mm: f64,
    /// A robot on a track: an `ok` command whose carriage position lies
    /// farther than this (mm) beyond the calibration rows' positions
    /// (`track_beyond_mm`) is `outside_envelope`, since the track's
    /// polynomials extrapolate badly; between the rows' positions they
    /// interpolate. The default, 50 mm, is a margin, not an extrapolation.
    #[schemars(range(min = 0.0, max = 100_000.0))]
    pub max_track_beyond_mm: f64,
    /// When more than this share of the targets is `unreachable`, the stage
    /// refuses the table, naming the frame it assumed (a table written in
    /// another frame or unit); 1 never refuses.
    #[schemars(range(min = 0.0, max = 1.0))]
    pub max_unreachable_fraction: f64,
    /// The direction each joint reaches every command from (spec §8), −1, 0
    /// or +1 per joint: a model with backlash (`eg_backlash`, `eg_harmonic`)
    /// puts the tool where it is when each joint arrives moving this way, and
    /// an exported program moves so (a pre-positioning joint move before each
    /// target, `export_program`'s `pre_position_deg`). Absent: +1 on every
    /// joint with a model whose backlash is not zero, else 0 (no direction).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub approach: Option<[i8; 6]>,
    /// A seven-joint arm's joint 3 (deg) at targets without a branch hint:
    /// the redundancy rule (`ik::HELD_JOINT_OF_SEVEN`) holds it there and the
    /// other six place the tool (a hint holds it at the hint's `q3_deg`).
    /// Absent: 0°. Within joint 3's limits; refused for a six-joint arm,
    /// which has no redundancy to resolve.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schemars(range(min = -100_000.0, max = 100_000.0))]
    pub held_joint_deg: Option<f64>,
}

impl Default for CompensateSettings {
    fn default() -> Self {
        CompensateSettings {
            model: ModelName::Elastogeometric.as_str().to_string(),
            position_tolerance_mm: 1e-6,
            orientation_tolerance_rad: 1e-6,
            max_iterations: 100,
            singular_sigma_min_mm_per_rad: 3.5,
            frame: WORLD_FRAME.to_string(),
            frames: BTreeMap::new(),
            tool: None,
            max_envelope_distance_deg: envelope::DEFAULT_MAX_DISTANCE_DEG,
            max_u95_mm: 0.5,
            max_track_beyond_mm: 50.0,
            max_unreachable_fraction: 0.5,
            approach: None,
            held_joint_deg: None,
        }
    }
}

static INFO: StageInfo = StageInfo {
    kind: "compensate",
    uses_cable_robot: false,
    updates_input: None,
    summary: "Load-aware compensation: joint commands that put the calibrated, loaded tool on each target, and corrected Cartesian targets for the nominal controller",
    code_version: 10,
    inputs: &[
        TableSlot {
            name: "targets",
            schema: schema::targets,
            required: true,
            meaning: "target_id, tool pose (world, base or a user frame), optional wrench, branch hint, frame and tool_id",
        },
        TableSlot {
            name: "parameters",
            schema: schema::parameters,
            required: false,
            meaning: "parameter sets; nominal when absent",
        },
        super::COVARIANCE_INPUT,
        super::residual_rung::RESIDUAL_INPUT,
        TableSlot {
            name: "envelope",
            schema: schema::envelope,
            required: false,
            meaning: "the configurations the calibration was identified on (e.g. identify's measurements): envelope_distance, and outside_envelope beyond max_envelope_distance_deg",
        },
        TableSlot {
            name: "selection",
            schema: schema::selection,
            required: false,
            meaning: "rows of `envelope` with role = calibration are the calibration rows; all rows when absent",
        },
    ],
    outputs: &[
        TableSlot {
            name: "commands",
            schema: schema::commands,
            required: true,
            meaning: "one row per target, in target order: command, status, residual, correction, corrected Cartesian target, tool_id, envelope_distance, u95_mm",
        },
        TableSlot {
            name: "conf_wrenches",
            schema: schema::conf_wrenches,
            required: true,
            meaning: "the ok commands as conf-wrench rows (cw_id = target_id) for a measure stage",
        },
    ],
};

/// `held_joint_deg` given for an arm without redundancy, or outside the held
/// joint's limits.
fn held_joint_problem(
    held_joint_deg: Option<f64>,
    ctx: &SettingsContext,
) -> Option<SettingsProblem> {
    let held = crate::robot::ik::HELD_JOINT_OF_SEVEN;
    let value = held_joint_deg?;
    let joints = ctx.robot.joints.len();
    if joints <= 6 {
        return Some(SettingsProblem::new(
            "held_joint_deg",
            format!(
                "the robot file {} has {joints} joints: only a seven-joint arm has a joint to hold (remove the key)",
                ctx.robot.path.display()
            ),
        ));
    }
    let [lo, hi] = ctx.robot.joints[held].limits();
    (!(lo..=hi).contains(&value)).then(|| {
        SettingsProblem::new(
            "held_joint_deg",
            format!(
                "{value} is outside joint {}'s limits [{lo}, {hi}] of the robot file",
                held + 1
            ),
        )
    })
}

impl CompensateSettings {
    /// Problems of `frame` and `frames` (names, values).
    fn frame_problems(&self) -> Vec<SettingsProblem> {
        let mut problems = Vec::new();
        for (name, pose) in &self.frames {
            if [WORLD_FRAME, BASE_FRAME, POSITIONER_FRAME].contains(&name.as_str())
                || name.trim().is_empty()
            {
                problems.push(SettingsProblem::new(
                    &format!("frames.{name}"),
                    format!(
                        "`{name}` cannot name a user frame (`world`, `base` and `positioner` are built in; a name must not be empty)"
                    ),
                ));
            }
            let distance = Vector3::new(pose[0], pose[1], pose[2]).norm();
            let angles_ok = pose[3..].iter().all(|a| a.abs() <= 360.0);
            if !pose.iter().all(|v| v.is_finite()) || distance > MAX_POSITION_MM || !angles_ok {
                problems.push(SettingsProblem::new(
                    &format!("frames.{name}"),
                    format!(
                        "expected [x_mm, y_mm, z_mm, rx_deg, ry_deg, rz_deg] with the origin within {MAX_POSITION_MM} mm of the base and the angles within ±360°, found {pose:?}"
                    ),
                ));
            }
        }
        if let Some(problem) = self.unknown_frame(&self.frame) {
            problems.push(SettingsProblem::new("frame", problem));
        }
        problems
    }

    /// Why `name` is no frame of these settings, or `None` when it is one.
    fn unknown_frame(&self, name: &str) -> Option<String> {
        if [WORLD_FRAME, BASE_FRAME, POSITIONER_FRAME].contains(&name)
            || self.frames.contains_key(name)
        {
            return None;
        }
        let known: Vec<&str> = [WORLD_FRAME, BASE_FRAME, POSITIONER_FRAME]
            .into_iter()
            .chain(
                self.frames
                    .keys()
                    .map(String::as_str)
                    .filter(|k| ![WORLD_FRAME, BASE_FRAME, POSITIONER_FRAME].contains(k)),
            )
            .collect();
        Some(format!(
            "unknown frame `{name}`{}; the frames are {} (user frames are declared in the setting `frames`)",
            crate::suggest::did_you_mean(name, known.iter().copied()),
            known.join(", ")
        ))
    }
}

impl Stage for CompensateStage {
    type Settings = CompensateSettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn check_settings(
        &self,
        settings: &CompensateSettings,
        ctx: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        let mut problems: Vec<SettingsProblem> = model_name_problem("model", &settings.model)
            .into_iter()
            .chain(covariance_binding_problem(ctx))
            .chain(settings.frame_problems())
            .collect();
        problems.extend(held_joint_problem(settings.held_joint_deg, ctx));
        if ctx.bound_inputs.contains(&"selection") && !ctx.bound_inputs.contains(&"envelope") {
            problems.push(SettingsProblem::new(
                "inputs.selection",
                "input `selection` chooses rows of the input `envelope`, which is not bound",
            ));
        }
        if let Some(approach) = settings.approach
            && approach.iter().any(|d| !(-1..=1).contains(d))
        {
            problems.push(SettingsProblem::new(
                "approach",
                format!(
                    "expected −1, 0 or +1 per joint (the direction each joint reaches the command from), found {approach:?}"
                ),
            ));
        }
        if settings
            .tool
            .as_deref()
            .is_some_and(|t| t.trim().is_empty())
        {
            problems.push(SettingsProblem::new("tool", "must not be empty"));
        }
        problems
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &CompensateSettings,
    ) -> Result<StageOutputs, StageError> {
        let set = model_set(ctx, "parameters", "model", &settings.model)?;
        let values = set
            .as_ref()
            .map_or_else(|| ParamValues::nominal(ctx.robot.spec()), |set| set.values);
        let input = ctx.input("targets")?;
        let rows = target_rows(ctx.robot, settings, &input.df, &input.path)?;
        let tools = tool_indices(set.as_ref(), settings, &rows, &input.path)?;
        let world_from_base = ctx.robot.world_from_base(&values);
        let targets = world_targets(settings, ctx.robot, &values, &rows, &tools);
        let approach = settings.approach_for(&values);
        let residual = match &set {
            Some(set) => super::residual_rung::bound_residual(ctx, set)?,
            None => None,
        };
        let (commands, residual_predictions) = match &residual {
            Some(residual) => {
                let (commands, predictions) = super::residual_rung::compensate_with_residual(
                    ctx.robot,
                    &values,
                    &targets,
                    &settings.solver_options(approach),
                    residual,
                    approach,
                )?;
                (commands, Some(predictions))
            }
            None => (
                compensation::compensate(
                    ctx.robot,
                    &values,
                    &targets,
                    &settings.solver_options(approach),
                ),
                None,
            ),
        };
        refuse_mostly_unreachable(
            settings,
            &input.path,
            &rows,
            &targets,
            &commands,
            &world_from_base,
        )?;

        let mut warnings = Vec::new();
        let calibrated = set.as_ref().filter(|s| s.model != ModelName::Nominal);
        // The predicted uncertainty at each command, for the row's tool.
        let mut covariances = None;
        if let Some(set) = &set
            && let Some(covariance) = bound_covariance(ctx, set)?
        {
            let conf_wrenches = compensation::command_rows(&targets, &commands, approach);
            let mut rows = row_covariances(ctx, set, covariance.as_ref(), &conf_wrenches);
            // The residual's variance: back to its prior far from the rows.
            if let Some(extra) = &residual_predictions {
                super::residual_rung::add_variance(&mut rows, extra);
            }
            covariances = Some(rows);
        } else if calibrated.is_some() {
            warnings.push(
                "u95_mm not checked: no `covariance` input (bind identify's covariance so that commands whose predicted 95 % uncertainty exceeds max_u95_mm are outside_envelope)".to_string(),
            );
        }
        let u95: Vec<Option<f64>> = match &covariances {
            Some(c) => c.iter().map(|c| c.as_ref().map(u95_mm)).collect(),
            None => vec![None; commands.len()],
        };
        let envelope = envelope_rows(ctx)?;
        let distances: Vec<Option<f64>> = match &envelope {
            Some(envelope) => {
                use rayon::prelude::*;
                commands
                    .par_iter()
                    .map(|c| Some(envelope.distance_deg(&c.q_deg)))
                    .collect()
            }
            None => {
                if calibrated.is_some() {
                    warnings.push(
                        "envelope not checked: no `envelope` input (bind the measurements identify was given, and its selection, so that commands far from the calibration rows are outside_envelope)".to_string(),
                    );
                }
                vec![None; commands.len()]
            }
        };
        // On a track, how far each carriage position lies beyond the rows'.
        let track_beyond: Option<Vec<Option<f64>>> = envelope
            .as_ref()
            .filter(|_| ctx.robot.spec().track.is_some())
            .map(|envelope| {
                targets
                    .iter()
                    .map(|t| envelope.track_beyond_mm(t.track_mm))
                    .collect()
            });
        let limits = EnvelopeLimits {
            max_distance_deg: settings.max_envelope_distance_deg,
            max_u95_mm: settings.max_u95_mm,
            max_track_beyond_mm: settings.max_track_beyond_mm,
        };
        let commands: Vec<Command> = commands
            .into_iter()
            .enumerate()
            .map(|(k, command)| {
                let measures = EnvelopeMeasures {
                    distance_deg: distances[k],
                    u95_mm: u95[k],
                    track_beyond_mm: track_beyond.as_ref().and_then(|b| b[k]),
                };
                Command {
                    status: envelope::judged(command.status, &measures, &limits),
                    ..command
                }
            })
            .collect();

        warnings.extend(beyond_default_envelope(&commands, &distances));
        let tool_names = tool_names(set.as_ref(), settings, &rows, &tools);
        let on_track = ctx.robot.spec().track.is_some();
        let positioner_axes = ctx.robot.spec().positioner.as_ref().map(|p| p.axes.len());
        let mut commands_table = commands_frame(
            ctx.robot.spec(),
            &rows.ids,
            &commands,
            on_track.then_some(&targets),
            positioner_axes.map(|axes| (axes, rows.positioner_deg.as_slice())),
        );
        let extra = [
            Column::new("tool_id".into(), tool_names),
            Column::new("envelope_distance".into(), distances),
            Column::new("u95_mm".into(), u95),
        ];
        let covariance_columns = covariances
            .as_deref()
            .map(covariance_columns)
            .unwrap_or_default();
        // The direction each joint must reach its command from, for the
        // program (spec §8's dir columns); absent when none was used.
        let approach_columns: Vec<Column> = if approach.iter().any(|d| *d != 0) {
            (0..schema::APPROACH_COLUMNS.len())
                .map(|j| {
                    Column::new(
                        schema::APPROACH_COLUMNS[j].into(),
                        vec![approach[j]; commands.len()],
                    )
                })
                .collect()
        } else {
            Vec::new()
        };
        let track_beyond_column =
            track_beyond.map(|values| Column::new(schema::TRACK_BEYOND_COLUMN.into(), values));
        for column in extra
            .into_iter()
            .chain(track_beyond_column)
            .chain(covariance_columns)
            .chain(approach_columns)
        {
            commands_table
                .with_column(column)
                .map_err(|e| StageError::Failed(format!("commands: {e}")))?;
        }
        let mut outputs = StageOutputs::default();
        if let Some(extra) = &residual_predictions {
            let largest = extra
                .iter()
                .map(|r| super::residual_rung::mean_mm(r).norm())
                .fold(0.0, f64::max);
            outputs.facts.insert(
                "residual_mean_max_mm".into(),
                format!("{largest:.4} (the residual's mean added at the commands; their correction_mm is measured from the targets shifted by it)"),
            );
        }
        outputs.tables.insert("commands".into(), commands_table);
        outputs.tables.insert(
            "conf_wrenches".into(),
            conf_wrenches_frame(
                ctx.robot.spec(),
                &rows.ids,
                &targets,
                &commands,
                &approach,
                on_track,
            ),
        );
        outputs
            .facts
            .insert("targets".into(), rows.ids.len().to_string());
        for status in Status::ALL {
            let count = commands.iter().filter(|c| c.status == status).count();
            outputs
                .facts
                .insert(status.as_str().into(), count.to_string());
        }
        if let Some(envelope) = &envelope {
            outputs
                .facts
                .insert("envelope_rows".into(), envelope.len().to_string());
        }
        for warning in &warnings {
            ctx.progress.note(&format!("warning: {warning}"));
        }
        if !warnings.is_empty() {
            outputs.facts.insert("warning".into(), warnings.join("; "));
        }
        Ok(outputs)
    }
}

/// A warning when `ok` commands lie beyond the default envelope
/// ([`envelope::DEFAULT_MAX_DISTANCE_DEG`]): a job that raised
/// `max_envelope_distance_deg` accepts them, but no calibration row was
/// measured there.
fn beyond_default_envelope(commands: &[Command], distances_deg: &[Option<f64>]) -> Option<String> {
    let beyond: Vec<f64> = commands
        .iter()
        .zip(distances_deg)
        .filter(|(c, _)| c.status == Status::Ok)
        .filter_map(|(_, d)| *d)
        .filter(|d| *d > envelope::DEFAULT_MAX_DISTANCE_DEG)
        .collect();
    let farthest = beyond.iter().copied().fold(f64::NAN, f64::max);
    (!beyond.is_empty()).then(|| {
        format!(
            "{} ok command(s) lie more than {} deg (the default envelope) from the nearest calibration row, up to {farthest:.1} deg: accepted by max_envelope_distance_deg, but no row was measured there, so the validation does not vouch for them",
            beyond.len(),
            envelope::DEFAULT_MAX_DISTANCE_DEG
        )
    })
}

/// Target ids, the targets in the world frame, and their nominal commands.
pub(super) type NominalTargets = (Vec<i64>, Vec<Target>, Vec<Command>);

/// The joint configuration of every target on the nominal model, as
/// `compensate` with `model = "nominal"` finds it (loaded IK seeded by the
/// branch hint, else the nominal solution nearest the previous target's), in
/// the frames `frame` and `frames` name: where a design for the work predicts
/// its uncertainty. The targets' `tool_id` plays no part (one nominal tool).
pub(super) fn nominal_target_commands(
    robot: &Robot,
    frame: &str,
    frames: &BTreeMap<String, [f64; 6]>,
    input: &InputTable,
) -> Result<NominalTargets, StageError> {
    let settings = CompensateSettings {
        model: ModelName::Nominal.as_str().to_string(),
        frame: frame.to_string(),
        frames: frames.clone(),
        ..CompensateSettings::default()
    };
    let rows = target_rows(robot, &settings, &input.df, &input.path)?;
    let values = ParamValues::nominal(robot.spec());
    let targets = world_targets(&settings, robot, &values, &rows, &vec![0; rows.ids.len()]);
    let commands = compensation::compensate(
        robot,
        &values,
        &targets,
        &settings.solver_options([0; MAX_JOINTS]),
    );
    Ok((rows.ids, targets, commands))
}

/// The targets of `rows` in the world frame, each with its row's load,
/// branch hint and tool (`tools`, one per row).
///
/// `values` place the frames: the world frame, and on a positioner its base
/// and axes at each row's axis values.
fn world_targets(
    settings: &CompensateSettings,
    robot: &Robot,
    values: &ParamValues,
    rows: &TargetRows,
    tools: &[usize],
) -> Vec<Target> {
    let prepared = robot.prepare(values);
    let world_from_base = prepared.world_from_base;
    let base_from_table = |k: usize| {
        let positioner = prepared.positioner.as_ref()?;
        Some(positioner.chain(&rows.positioner_deg[k]?).table())
    };
    (0..rows.ids.len())
        .map(|k| Target {
            tool_in_world: match rows.frames[k].as_str() {
                POSITIONER_FRAME => {
                    world_from_base.compose(&base_from_table(k).unwrap_or_else(Frame::identity))
                }
                name => world_from(settings, &world_from_base, name),
            }
            .compose(&rows.poses[k]),
            wrench: rows.wrenches[k],
            hint_deg: rows.hints[k],
            tool: tools[k],
            track_mm: rows.track_mm[k],
        })
        .collect()
}

impl CompensateSettings {
    /// The approach direction of every joint for the parameter `values`: the
    /// setting, else +1 on every joint when the values hold a backlash (a
    /// model with backlash needs a direction to place the tool), else none.
    fn approach_for(&self, values: &ParamValues) -> [i8; MAX_JOINTS] {
        match self.approach {
            Some(approach) => crate::robot::joint_array(&approach),
            None if ParamId::backlashes(MAX_JOINTS).any(|id| values.get(id) != 0.0) => {
                crate::robot::joint_array(&[1; 6])
            }
            None => [0; MAX_JOINTS],
        }
    }

    /// The loaded IK's options these settings describe, each joint reaching
    /// its command from `approach`.
    fn solver_options(&self, approach: [i8; MAX_JOINTS]) -> Options {
        Options {
            solver: NumericOptions {
                max_iterations: self.max_iterations,
                position_tolerance_mm: self.position_tolerance_mm,
                orientation_tolerance_rad: self.orientation_tolerance_rad,
                ..NumericOptions::default()
            },
            singular_sigma_min_mm_per_rad: self.singular_sigma_min_mm_per_rad,
            approach,
            held_joint_deg: self.held_joint_deg.unwrap_or(0.0),
        }
    }
}

/// Problems of a `frame` setting and its user `frames`, as `compensate` judges
/// them, for a stage that reads `targets` the same way.
pub(super) fn target_frame_problems(
    frame: &str,
    frames: &BTreeMap<String, [f64; 6]>,
) -> Vec<SettingsProblem> {
    CompensateSettings {
        frame: frame.to_string(),
        frames: frames.clone(),
        ..CompensateSettings::default()
    }
    .frame_problems()
}

/// world ← frame of a row's frame name (already checked to be known).
fn world_from(settings: &CompensateSettings, world_from_base: &Frame, name: &str) -> Frame {
    match name {
        WORLD_FRAME => Frame::identity(),
        BASE_FRAME => *world_from_base,
        user => settings.frames.get(user).map_or(Frame::identity(), |p| {
            world_from_base.compose(&pose_frame([p[0], p[1], p[2]], [p[3], p[4], p[5]]))
        }),
    }
}

/// The calibration rows of the `envelope` input (a `selection`'s calibration
/// rows when one is bound), without the rows measuring a positioner's nest
/// (the arm stood parked there, its SMR unmeasured); `None` when it is not
/// bound. No rows is refused:
/// an envelope of nothing would make every command `outside_envelope` for a
/// reason the user cannot see.
fn envelope_rows(ctx: &StageContext) -> Result<Option<JointEnvelope>, StageError> {
    let Some(table) = ctx.inputs.get("envelope") else {
        return Ok(None);
    };
    let keep = ctx
        .inputs
        .get("selection")
        .map(|s| ids_with_role(s, "calibration"))
        .transpose()?;
    let (ids, rows) = conf_wrench_rows_of(table, ctx.robot.spec())?;
    // The carriage positions of the rows, on a track (zeros without one).
    let track_mm = super::track_positions(&table.df, &table.path, ctx.robot.spec())?;
    let nest_axes =
        super::positioner_rows::positioner_axes_of_rows(&table.df, &table.path, ctx.robot.spec())?;
    let kept: Vec<usize> = (0..ids.len())
        .filter(|&k| keep.as_ref().is_none_or(|kept| kept.contains(&ids[k])))
        .filter(|&k| nest_axes[k].is_none())
        .collect();
    let configurations: Vec<[f64; MAX_JOINTS]> = kept.iter().map(|&k| rows[k]).collect();
    let positions: Vec<f64> = match ctx.robot.spec().track {
        Some(_) => kept.iter().map(|&k| track_mm[k]).collect(),
        None => Vec::new(),
    };
    let envelope = JointEnvelope::new(configurations).map(|e| {
        e.with_track(&positions)
            .with_slides(ctx.robot.prismatic_joints())
    });
    envelope.map(Some).ok_or_else(|| {
        StageError::Invalid(format!(
            "{}: no calibration rows for the envelope (the table is empty, or the selection marks none of its cw_id as calibration)",
            table.path.display()
        ))
    })
}

/// cw_id and joint columns of an `envelope` table (any other columns play no part).
fn conf_wrench_rows_of(
    table: &InputTable,
    robot: &crate::robot::RobotSpec,
) -> Result<(Vec<i64>, Vec<[f64; MAX_JOINTS]>), StageError> {
    let ids = i64_values(&table.df, "cw_id", &table.path)?;
    let rows = schema::joint_vectors(&table.df, &table.path, robot)?;
    Ok((ids, rows))
}

/// Values of an optional f64 column: `None` where absent or null (a column
/// pandas wrote all-null has type null).
fn optional_f64(
    df: &DataFrame,
    name: &str,
    file: &std::path::Path,
) -> Result<Vec<Option<f64>>, StageError> {
    match df.column(name) {
        Err(_) => Ok(vec![None; df.height()]),
        Ok(column) if column.dtype() == &DataType::Null => Ok(vec![None; df.height()]),
        Ok(column) => Ok(column
            .f64()
            .map_err(|e| io_error(file, e))?
            .iter()
            .collect()),
    }
}

/// The checked `targets` rows, each pose still in its own frame.
struct TargetRows {
    ids: Vec<i64>,
    /// frame ← tool of each row, in the frame `frames` names.
    poses: Vec<Frame>,
    /// Each row's frame name (its `frame` value, else the setting), known.
    frames: Vec<String>,
    /// Each row's `tool_id` value (null or absent: `None`).
    tool_ids: Vec<Option<String>>,
    wrenches: Vec<Wrench>,
    hints: Vec<Option<[f64; MAX_JOINTS]>>,
    /// Each row's carriage position (`e1_mm`; zeros without a track).
    track_mm: Vec<f64>,
    /// Each row's positioner axis values (`p1_deg`, `p2_deg`; `None` where
    /// not given), checked against the limits; given on every row in the
    /// frame `positioner`.
    positioner_deg: Vec<Option<[f64; MAX_POSITIONER_AXES]>>,
}

/// Values of an optional utf8 column: `None` where absent or null (a column
/// pandas wrote all-null has type null).
fn optional_str(
    df: &DataFrame,
    name: &str,
    file: &std::path::Path,
) -> Result<Vec<Option<String>>, StageError> {
    match df.column(name) {
        Err(_) => Ok(vec![None; df.height()]),
        Ok(column) if column.dtype() == &DataType::Null => Ok(vec![None; df.height()]),
        Ok(_) => Ok(str_values(df, name, file)?),
    }
}

/// The checked `targets` rows. A missing wrench value is 0; a branch hint is used
/// only when all six q columns are given on the row. Refused, naming the row: a
/// frame the settings do not know, a position farther than [`MAX_POSITION_MM`]
/// from its frame's origin, a wrench beyond `row_checks`' bounds, a partial
/// hint, a hint outside the robot file's joint limits (a seed there asks for a
/// branch the robot cannot take, and says the row was typed for another robot
/// or in radians), an empty `tool_id`.
fn target_rows(
    robot: &Robot,
    settings: &CompensateSettings,
    df: &DataFrame,
    file: &std::path::Path,
) -> Result<TargetRows, StageError> {
    let ids = i64_values(df, "target_id", file)?;
    let required = |names: &[&str]| {
        names
            .iter()
            .map(|c| f64_values(df, c, file))
            .collect::<Result<Vec<_>, _>>()
    };
    let position = required(&POSITION_COLUMNS)?;
    let orientation = required(&ORIENTATION_COLUMNS)?;
    let optional = |names: &[&str]| {
        names
            .iter()
            .map(|c| optional_f64(df, c, file))
            .collect::<Result<Vec<_>, _>>()
    };
    let wrench = optional(&WRENCH_COLUMNS)?;
    schema::refuse_foreign_joint_columns(df, file, robot.spec())?;
    let joint_names = schema::joint_column_names(robot.spec());
    let hint = optional(&joint_names)?;
    let frame_column = optional_str(df, "frame", file)?;
    let tool_ids = optional_str(df, "tool_id", file)?;
    let track_mm = super::track_positions(df, file, robot.spec())?;
    let positioner_deg =
        super::positioner_rows::positioner_axes_of_targets(df, file, robot.spec())?;
    let bad = |row: usize, message: String| {
        StageError::Invalid(format!(
            "{}: row {row} (target_id {}): {message}",
            file.display(),
            ids[row]
        ))
    };
    let mut rows = TargetRows {
        ids: ids.clone(),
        poses: Vec::with_capacity(ids.len()),
        frames: Vec::with_capacity(ids.len()),
        tool_ids: Vec::with_capacity(ids.len()),
        wrenches: Vec::with_capacity(ids.len()),
        hints: Vec::with_capacity(ids.len()),
        track_mm,
        positioner_deg,
    };
    for row in 0..ids.len() {
        let frame_name = frame_column[row]
            .as_deref()
            .map(str::trim)
            .unwrap_or(&settings.frame);
        if let Some(problem) = settings.unknown_frame(frame_name) {
            return Err(bad(row, format!("column `frame`: {problem}")));
        }
        if frame_name == POSITIONER_FRAME {
            if robot.spec().positioner.is_none() {
                return Err(bad(
                    row,
                    format!(
                        "frame `{POSITIONER_FRAME}`, but the robot file {} has no [positioner]",
                        robot.spec().path.display()
                    ),
                ));
            }
            if rows.positioner_deg[row].is_none() {
                return Err(bad(
                    row,
                    format!(
                        "a target in the frame `{POSITIONER_FRAME}` needs the positioner's axis values ({})",
                        schema::POSITIONER_COLUMNS
                            [..robot.spec().positioner.as_ref().map_or(1, |p| p.axes.len())]
                            .join(", ")
                    ),
                ));
            }
        }
        let position_mm: [f64; 3] = std::array::from_fn(|i| position[i][row]);
        let distance = nalgebra::Vector3::from(position_mm).norm();
        // A NaN too, should one get past the schema check.
        if distance.is_nan() || distance > MAX_POSITION_MM {
            return Err(bad(
                row,
                format!(
                    "the target is {} mm from the origin of its frame `{frame_name}` (more than {MAX_POSITION_MM} mm)",
                    compact(distance)
                ),
            ));
        }
        let wrench = Wrench::from_array(std::array::from_fn(|i| wrench[i][row].unwrap_or(0.0)));
        if let Some(problem) = wrench_problem(&ConfWrench::new([0.0; MAX_JOINTS], wrench)) {
            return Err(bad(row, problem));
        }
        let given: Vec<f64> = hint.iter().filter_map(|c| c[row]).collect();
        let hint_deg = match given.len() {
            0 => None,
            n if n == joint_names.len() => {
                let hint_deg = crate::robot::joint_array(&given);
                if let Some(problem) = joints_problem(robot, &hint_deg) {
                    return Err(bad(row, format!("branch hint: {problem}")));
                }
                Some(hint_deg)
            }
            n => {
                return Err(bad(
                    row,
                    format!(
                        "a branch hint needs all of {}, found {n} of them",
                        joint_names.join(", ")
                    ),
                ));
            }
        };
        let tool_id = tool_ids[row].as_deref().map(str::trim);
        if tool_id == Some("") {
            return Err(bad(
                row,
                "column `tool_id` is empty; give a target id of the parameters, or null for the setting `tool`".into(),
            ));
        }
        rows.poses.push(pose_frame(
            position_mm,
            std::array::from_fn(|i| orientation[i][row]),
        ));
        rows.frames.push(frame_name.to_string());
        rows.tool_ids.push(tool_id.map(str::to_string));
        rows.wrenches.push(wrench);
        rows.hints.push(hint_deg);
    }
    Ok(rows)
}

/// The parameters' target index each row aims (see the module doc): the
/// row's `tool_id`, else the setting `tool`. Every row aims tool 0 of a
/// one-target set or the nominal model.
fn tool_indices(
    set: Option<&ParameterSet>,
    settings: &CompensateSettings,
    rows: &TargetRows,
    file: &std::path::Path,
) -> Result<Vec<usize>, StageError> {
    let Some(set) = set.filter(|s| s.targets.len() > 1) else {
        return Ok(vec![0; rows.ids.len()]);
    };
    let known = || set.targets.join(", ");
    rows.tool_ids
        .iter()
        .enumerate()
        .map(|(row, id)| {
            let (name, source) = match (id, &settings.tool) {
                (Some(id), _) => (id.as_str(), "column `tool_id`"),
                (None, Some(tool)) => (tool.as_str(), "setting `tool`"),
                (None, None) => {
                    return Err(StageError::Invalid(format!(
                        "{}: row {row} (target_id {}): the {} set has several targets ({}): say which one this row aims, in a `tool_id` column or the setting `tool`",
                        file.display(),
                        rows.ids[row],
                        set.model,
                        known()
                    )));
                }
            };
            set.targets.iter().position(|t| t == name).ok_or_else(|| {
                StageError::Invalid(format!(
                    "{}: row {row} (target_id {}): {source}: target `{name}` is not one of the {} set's targets ({}){}",
                    file.display(),
                    rows.ids[row],
                    set.model,
                    known(),
                    crate::suggest::did_you_mean(name, set.targets.iter().map(String::as_str))
                ))
            })
        })
        .collect()
}

/// The `tool_id` written to `commands`: the set's target id of a several-target
/// set, else what the row (or the setting `tool`) named, else null.
fn tool_names(
    set: Option<&ParameterSet>,
    settings: &CompensateSettings,
    rows: &TargetRows,
    tools: &[usize],
) -> Vec<Option<String>> {
    match set.filter(|s| s.targets.len() > 1) {
        Some(set) => tools
            .iter()
            .map(|k| Some(set.targets[*k].clone()))
            .collect(),
        None => rows
            .tool_ids
            .iter()
            .map(|id| id.clone().or_else(|| settings.tool.clone()))
            .collect(),
    }
}

/// Refuses a table most of whose targets came back `unreachable` (more than
/// `max_unreachable_fraction`): a table written in another frame (or unit)
/// than the one assumed, which would otherwise end as a table of failures with
/// exit 0. Names the frame(s) assumed, how far from the robot base the
/// targets lie read so, and the other frame to try.
fn refuse_mostly_unreachable(
    settings: &CompensateSettings,
    file: &std::path::Path,
    rows: &TargetRows,
    targets: &[Target],
    commands: &[Command],
    world_from_base: &Frame,
) -> Result<(), StageError> {
    let unreachable: Vec<usize> = (0..commands.len())
        .filter(|&k| commands[k].status == Status::Unreachable)
        .collect();
    let n = commands.len();
    if n == 0 || unreachable.len() as f64 <= settings.max_unreachable_fraction * n as f64 {
        return Ok(());
    }
    let mut assumed: Vec<&str> = unreachable
        .iter()
        .map(|&k| rows.frames[k].as_str())
        .collect();
    assumed.sort_unstable();
    assumed.dedup();
    let base_from_world = world_from_base.inverse();
    let mut from_base_mm: Vec<f64> = unreachable
        .iter()
        .map(|&k| {
            base_from_world
                .transform_point(&targets[k].tool_in_world.origin_mm)
                .norm()
        })
        .collect();
    from_base_mm.sort_by(f64::total_cmp);
    let median_mm = from_base_mm[from_base_mm.len() / 2];
    let other = if assumed.contains(&WORLD_FRAME) {
        "the robot's base frame (`frame = \"base\"`, or a `frame` column)"
    } else {
        "the tracker frame (`frame = \"world\"`, or a `frame` column)"
    };
    Err(StageError::Invalid(format!(
        "{}: {} of {n} targets are unreachable, assuming frame {} (more than max_unreachable_fraction = {}); read so, they lie a median {median_mm:.0} mm from the robot base. Were they written in another frame? Try {other}, or check the units (mm, deg)",
        file.display(),
        unreachable.len(),
        assumed
            .iter()
            .map(|f| format!("`{f}`"))
            .collect::<Vec<_>>()
            .join(", "),
        settings.max_unreachable_fraction,
    )))
}

/// The `commands` table; with `track_targets` (a robot on a track), each
/// command's carriage position in `e1_mm`, its target's.
fn commands_frame(
    robot: &crate::robot::RobotSpec,
    ids: &[i64],
    commands: &[Command],
    track_targets: Option<&[Target]>,
    positioner: Option<(usize, &[Option<[f64; MAX_POSITIONER_AXES]>])>,
) -> DataFrame {
    let mut columns = vec![Column::new("target_id".into(), ids.to_vec())];
    let float = |name: &str, f: &dyn Fn(&Command) -> f64| {
        Column::new(name.into(), commands.iter().map(f).collect::<Vec<f64>>())
    };
    for (joint, name) in schema::joint_column_names(robot).iter().enumerate() {
        columns.push(float(name, &|c| c.q_deg[joint]));
    }
    columns.push(Column::new(
        "status".into(),
        commands
            .iter()
            .map(|c| c.status.as_str())
            .collect::<Vec<_>>(),
    ));
    columns.push(float("residual_mm", &|c| c.residual_mm));
    columns.push(float("correction_mm", &|c| c.correction_mm));
    columns.push(float("elastic_mm", &|c| c.elastic_mm));
    for (axis, name) in COMMAND_POSITION_COLUMNS.iter().enumerate() {
        columns.push(float(name, &|c| c.tool_in_base_cmd.origin_mm[axis]));
    }
    for (k, name) in COMMAND_QUATERNION_COLUMNS.iter().enumerate() {
        columns.push(float(name, &|c| c.quaternion_wxyz_cmd[k]));
    }
    if let Some(targets) = track_targets {
        columns.push(Column::new(
            schema::TRACK_COLUMN.into(),
            targets.iter().map(|t| t.track_mm).collect::<Vec<_>>(),
        ));
    }
    // The positioner's commands beside the arm's, where the targets gave them.
    if let Some((axes, values)) = positioner.filter(|(_, v)| v.iter().any(Option::is_some)) {
        for (axis, name) in schema::POSITIONER_COLUMNS[..axes].iter().enumerate() {
            columns.push(Column::new(
                (*name).into(),
                values
                    .iter()
                    .map(|v| v.map(|v| v[axis]))
                    .collect::<Vec<Option<f64>>>(),
            ));
        }
    }
    frame(columns)
}

/// The `ok` commands as conf-wrench rows, with the direction each joint must
/// reach them from (`dir1 … dir6`, when one was used; a `measure` stage
/// pre-positions for it).
fn conf_wrenches_frame(
    robot: &crate::robot::RobotSpec,
    ids: &[i64],
    targets: &[Target],
    commands: &[Command],
    approach: &[i8; MAX_JOINTS],
    on_track: bool,
) -> DataFrame {
    let ok: Vec<usize> = (0..ids.len())
        .filter(|&k| commands[k].status == Status::Ok)
        .collect();
    let mut columns = vec![Column::new(
        "cw_id".into(),
        ok.iter().map(|&k| ids[k]).collect::<Vec<_>>(),
    )];
    for (joint, name) in schema::joint_column_names(robot).iter().enumerate() {
        columns.push(Column::new(
            (*name).into(),
            ok.iter()
                .map(|&k| commands[k].q_deg[joint])
                .collect::<Vec<_>>(),
        ));
    }
    for (i, name) in WRENCH_COLUMNS.iter().enumerate() {
        columns.push(Column::new(
            (*name).into(),
            ok.iter()
                .map(|&k| targets[k].wrench.to_array()[i])
                .collect::<Vec<_>>(),
        ));
    }
    if approach.iter().any(|d| *d != 0) {
        for (joint, name) in schema::APPROACH_COLUMNS.iter().enumerate() {
            columns.push(Column::new((*name).into(), vec![approach[joint]; ok.len()]));
        }
    }
    if on_track {
        columns.push(Column::new(
            schema::TRACK_COLUMN.into(),
            ok.iter().map(|&k| targets[k].track_mm).collect::<Vec<_>>(),
        ));
    }
    frame(columns)
}

/// Refuses a `targets` table with a row whose `frame` is not `world`: stages
/// that compare targets with tracker measurements (`accuracy`, `iso9283`) read
/// the pose columns as tracker coordinates, and a base-frame row compared so
/// would give a wrong error with exit 0.
pub fn world_frame_rows_only(table: &InputTable, stage: &str) -> Result<(), StageError> {
    let frames = optional_str(&table.df, "frame", &table.path)?;
    match frames
        .iter()
        .enumerate()
        .find(|(_, f)| f.as_deref().is_some_and(|f| f.trim() != WORLD_FRAME))
    {
        None => Ok(()),
        Some((row, frame)) => Err(StageError::Invalid(format!(
            "{}: row {row}: column `frame` is `{}`; {stage} compares targets with tracker measurements and takes world-frame (tracker) targets only (the `commands` of a compensate stage hold where each target went)",
            table.path.display(),
            frame.as_deref().unwrap_or_default()
        ))),
    }
}
