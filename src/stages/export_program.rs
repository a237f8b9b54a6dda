//! `export_program`: programs for the robot controller from a `commands` table
//! (spec §7): an ABB RAPID module, a KUKA KRL pair, a FANUC TP program, a
//! Yaskawa INFORM job, a CSV, and (with a parameters table) a URDF of the
//! calibrated geometry. Writes files only, no
//! table; the runner publishes and caches them beside other stages' tables.
//!
//! The conventions live in `crate::export`; this file reads the rows, checks
//! the settings (names must be identifiers the controllers accept), decides
//! what to do with rows whose status is not `ok` (`on_failed`), and which tool
//! the programs declare (`program_tools`): the calibrated tool of the
//! commands' target (SMR) in the `parameters` input, the row's own with a
//! `tool_id` column (spec §8: every stage that evaluates the model uses the
//! row's target), else the robot file's `[tool]`.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::{
    SettingsContext, SettingsProblem, Stage, StageContext, StageError, StageInfo, StageOutputs,
    TableSlot, model_name_problem, model_set,
};
use crate::calibration::row_checks::{MAX_POSITION_MM, compact, joints_problem};
use crate::compensation::Status;
use crate::export::cartesian::{self, Payload, ProgramTool};
use crate::export::{
    self, Command, MotionSettings, Motions, Program, Provenance, fanuc, krl, rapid, urdf, yaskawa,
};
use crate::robot::positioner::MAX_POSITIONER_AXES;
use crate::robot::{Frame, Robot};
use crate::table::parameters::{ModelName, ParameterSet};
use crate::table::schema::{
    self, COMMAND_POSITION_COLUMNS, COMMAND_QUATERNION_COLUMNS, approach_values, f64_values,
    i64_values, optional_f64_values, optional_str_values, str_values,
};
use crate::table::{self as tables, TableError};

pub struct ExportProgramStage;

/// A file format `export_program` writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum ProgramFormat {
    /// ABB RAPID module `<module_name>.mod`.
    Rapid,
    /// KUKA KRL pair `<module_name>.src` and `<module_name>.dat`.
    Krl,
    /// FANUC TP program `<module_name>.ls` (ASCII form).
    Fanuc,
    /// Yaskawa INFORM job `<module_name>.jbi` (joint moves need the robot
    /// file's `pulses_per_deg`).
    Yaskawa,
    /// `commands.csv`.
    Csv,
    /// `robot.urdf` of the calibrated geometry (needs the `parameters` input).
    Urdf,
}

impl ProgramFormat {
    /// The name a job file gives the format.
    fn key(self) -> &'static str {
        match self {
            ProgramFormat::Rapid => "rapid",
            ProgramFormat::Krl => "krl",
            ProgramFormat::Fanuc => "fanuc",
            ProgramFormat::Yaskawa => "yaskawa",
            ProgramFormat::Csv => "csv",
            ProgramFormat::Urdf => "urdf",
        }
    }
}

/// How the programs move to the targets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum MotionSetting {
    /// Joint moves to the joint commands (RAPID `MoveAbsJ`, KRL `PTP` E6AXIS):
    /// the controller's inverse kinematics is not involved.
    Joint,
    /// Cartesian moves to the corrected targets (RAPID `MoveJ` then `MoveL`, KRL
    /// `PTP` then `LIN` E6POS), with the configuration (confdata, Status/Turn).
    Linear,
    /// Both: the joint path, then the linear path.
    Both,
}

/// What to do with rows whose status is not `ok`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum OnFailedSetting {
    /// Leave them out of the motion and name them in each file's header.
    Skip,
    /// Fail (exit 2), naming the rows.
    Fail,
}

/// Zones RAPID predefines (`z0` … `z200`), in mm; KRL uses the same radius as
/// `$APO.CDIS`.
const ZONES_MM: [u32; 14] = [0, 1, 5, 10, 15, 20, 30, 40, 50, 60, 80, 100, 150, 200];

/// Settings of `export_program`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ExportProgramSettings {
    /// Files to write; by default RAPID, KRL and CSV, and the URDF with a
    /// `parameters` input (FANUC and Yaskawa when listed).
    pub formats: Option<Vec<ProgramFormat>>,
    /// Model of the `parameters` input whose calibrated tool the programs
    /// declare and the URDF shows: the one the commands were compensated with.
    pub model: String,
    /// RAPID module and KRL program name (and the files' base name): a letter,
    /// then letters, digits or `_`; at most 24 characters with KRL, 32 with RAPID.
    pub module_name: String,
    /// TCP speed, mm/s (RAPID speeddata `v_tcp`, KRL `$VEL.CP`).
    #[schemars(range(min = 1.0, max = 7000.0))]
    pub speed_mm_s: f64,
    /// Axis speed of KRL joint moves (`$VEL_AXIS`), percent.
    #[schemars(range(min = 1.0, max = 100.0))]
    pub joint_speed_percent: f64,
    /// `fine` (exact stop) or a RAPID predefined zone `z0` … `z200` (KRL:
    /// `$APO.CDIS` with `C_DIS` on linear moves).
    pub zone: String,
    /// Name of the RAPID `PERS tooldata` the module declares (with `_1` … when
    /// the rows use several tools): the tool whose poses the robtargets are.
    /// Not `tool0`, ABB's flange, which cannot be redefined.
    pub tool_name: String,
    /// Name of the RAPID `PERS wobjdata` the module declares: the robot base.
    pub wobj_name: String,
    /// The target (SMR) id, in a several-target `parameters` input, whose
    /// calibrated tool the commands were computed for; needed when the commands
    /// table has no `tool_id` column and the set has several targets.
    pub tool_target: Option<String>,
    /// Approach and retract moves (drilling), mm: the Cartesian path moves to
    /// the point this far back along the tool's z axis before and after each
    /// target, which it reaches with an exact stop. 0 = off.
    #[schemars(range(min = 0.0, max = 1000.0))]
    pub approach_mm: f64,
    /// Pre-positioning for a model with backlash, deg: before each target
    /// whose command carries approach directions (`dir1 … dir6`, written by
    /// `compensate` with such a model), a joint move to the command minus
    /// this times each direction, so that each joint reaches the command
    /// moving the way the backlash was compensated for. It must exceed the
    /// dead band (the identified `backlash` is half of it; 0.01°–0.1° on
    /// industrial reducers), and stay small, since the path from it to the
    /// target is where the directions hold. 0 = off: the program then
    /// carries a warning.
    #[schemars(range(min = 0.0, max = 10.0))]
    pub pre_position_deg: f64,
    /// FANUC: the tool frame (`UTOOL[n]`) the program writes its tool into
    /// and selects; it overwrites what the frame held.
    #[schemars(range(min = 1, max = 10))]
    pub fanuc_user_tool: u32,
    /// FANUC: the position register (`PR[n]`) the tool is built in; it
    /// overwrites what the register held.
    #[schemars(range(min = 1, max = 100))]
    pub fanuc_position_register: u32,
    /// Yaskawa: the tool file (`///TOOL n`) the job's positions are taught
    /// with; the job names the values it must hold.
    #[schemars(range(min = 0, max = 63))]
    pub yaskawa_tool_file: u32,
    /// `joint`, `linear` or `both`.
    pub motion: MotionSetting,
    /// Rows whose status is not `ok`: `skip` (named in the headers) or `fail`.
    pub on_failed: OnFailedSetting,
}

impl Default for ExportProgramSettings {
    fn default() -> Self {
        ExportProgramSettings {
            formats: None,
            model: ModelName::Elastogeometric.as_str().to_string(),
            module_name: "EGCAL_PROGRAM".into(),
            speed_mm_s: 100.0,
            joint_speed_percent: 20.0,
            zone: "fine".into(),
            tool_name: "egcal_tool".into(),
            wobj_name: "egcal_wobj".into(),
            tool_target: None,
            approach_mm: 0.0,
            pre_position_deg: 1.0,
            fanuc_user_tool: 10,
            fanuc_position_register: 100,
            yaskawa_tool_file: 1,
            motion: MotionSetting::Joint,
            on_failed: OnFailedSetting::Skip,
        }
    }
}

impl ExportProgramSettings {
    /// The formats to write, given whether a parameters table is bound and
    /// the arm (a seven-joint arm's or a gantry's default is the CSV, see
    /// [`arm_format_problem`]).
    fn formats(
        &self,
        parameters_bound: bool,
        robot: &crate::robot::RobotSpec,
    ) -> Vec<ProgramFormat> {
        match &self.formats {
            Some(formats) => formats.clone(),
            None => {
                let mut all = if !six_revolute_joints(robot) {
                    vec![ProgramFormat::Csv]
                } else {
                    vec![ProgramFormat::Rapid, ProgramFormat::Krl, ProgramFormat::Csv]
                };
                if parameters_bound {
                    all.push(ProgramFormat::Urdf);
                }
                all
            }
        }
    }

    /// The zone radius in mm, `None` for `fine`; an error for another name.
    fn zone_mm(&self) -> Result<Option<u32>, String> {
        if self.zone == "fine" {
            return Ok(None);
        }
        self.zone
            .strip_prefix('z')
            .and_then(|n| n.parse::<u32>().ok())
            .filter(|n| ZONES_MM.contains(n))
            .map(Some)
            .ok_or_else(|| {
                format!(
                    "unknown zone `{}`, expected fine or one of {}",
                    self.zone,
                    ZONES_MM.map(|z| format!("z{z}")).join(", ")
                )
            })
    }
}

/// Why `format` is not written for the arm of `robot`: a seven-joint arm's
/// programs are the CSV (`q1_deg … q7_deg`, what a cobot's own interface,
/// e.g. Franka's, takes as joint positions) and the URDF. Each controller
/// language carries a seventh joint its own way (ABB's YuMi in `eax_a`, the
/// KUKA LBR on a KR C as `E1` between A2 and A3, Yaskawa's SIA as its `E`
/// axis, FANUC has no seven-joint arm), and none is verified here, so they
/// are refused rather than written with a guessed axis order.
///
/// A gantry (an arm with a prismatic joint) likewise: the controller
/// languages' joint targets here are six angles of a six-axis arm, so its
/// programs are the CSV (`q{i}_mm` for the slides) and the URDF (prismatic
/// joints).
fn arm_format_problem(format: ProgramFormat, robot: &crate::robot::RobotSpec) -> Option<String> {
    if six_revolute_joints(robot) || matches!(format, ProgramFormat::Csv | ProgramFormat::Urdf) {
        return None;
    }
    let joints = robot.joints.len();
    Some(match robot.prismatic_joints().iter().position(|&p| p) {
        Some(joint) => format!(
            "`{}` is written for six-axis arms of revolute joints, and joint {} of the robot file {} is prismatic: a gantry's programs are `csv` (q{{i}}_mm for its slides) and `urdf`",
            format.key(),
            joint + 1,
            robot.path.display()
        ),
        None => format!(
            "`{}` is written for six-axis controllers, and the robot file {} has {joints} joints: a seven-joint arm's programs are `csv` (q1_deg … q7_deg) and `urdf`",
            format.key(),
            robot.path.display()
        ),
    })
}

/// Six revolute joints: the arms the controller languages here are written for.
fn six_revolute_joints(robot: &crate::robot::RobotSpec) -> bool {
    robot.joints.len() == 6 && !robot.prismatic_joints().contains(&true)
}

static INFO: StageInfo = StageInfo {
    kind: "export_program",
    uses_cable_robot: false,
    updates_input: None,
    summary: "Programs for the controller from joint commands: ABB RAPID (.mod), KUKA KRL (.src/.dat), CSV, and a URDF of the calibrated geometry",
    code_version: 8,
    inputs: &[
        TableSlot {
            name: "commands",
            schema: schema::commands,
            required: true,
            meaning: "joint commands and corrected Cartesian targets (compensate); an optional utf8 `tool_id` names each row's target (SMR)",
        },
        TableSlot {
            name: "parameters",
            schema: schema::parameters,
            required: false,
            meaning: "identified parameters: the programs' tool is the calibrated tool of `model` (of the rows' `tool_id` or `tool_target`); the URDF shows that model",
        },
    ],
    outputs: &[],
};

impl Stage for ExportProgramStage {
    type Settings = ExportProgramSettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn check_settings(
        &self,
        settings: &ExportProgramSettings,
        ctx: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        let mut problems: Vec<SettingsProblem> = model_name_problem("model", &settings.model)
            .into_iter()
            .collect();
        let parameters_bound = ctx.bound_inputs.contains(&"parameters");
        let formats = settings.formats(parameters_bound, ctx.robot);
        for (i, format) in formats.iter().enumerate() {
            if let Some(problem) = arm_format_problem(*format, ctx.robot) {
                problems.push(SettingsProblem::new(&format!("formats[{i}]"), problem));
            }
        }
        if formats.is_empty() {
            problems.push(SettingsProblem::new(
                "formats",
                "no format given: list at least one of rapid, krl, fanuc, yaskawa, csv, urdf",
            ));
        }
        if let Some(i) = formats.iter().position(|f| *f == ProgramFormat::Urdf)
            && !parameters_bound
        {
            problems.push(SettingsProblem::new(
                &format!("formats[{i}]"),
                "format `urdf` needs the input `parameters` (the calibrated geometry)",
            ));
        }
        let rapid = formats.contains(&ProgramFormat::Rapid);
        let krl = formats.contains(&ProgramFormat::Krl);
        let mut name_checks: Vec<(&str, &str, usize, &str)> = Vec::new();
        if rapid {
            name_checks.push((
                "module_name",
                &settings.module_name,
                rapid::MAX_IDENTIFIER_LEN,
                "RAPID",
            ));
            // Room for the suffix `_1` … `_8` of several tools.
            name_checks.push((
                "tool_name",
                &settings.tool_name,
                rapid::MAX_IDENTIFIER_LEN - 2,
                "RAPID",
            ));
            name_checks.push((
                "wobj_name",
                &settings.wobj_name,
                rapid::MAX_IDENTIFIER_LEN,
                "RAPID",
            ));
        }
        if krl {
            name_checks.push((
                "module_name",
                &settings.module_name,
                krl::MAX_IDENTIFIER_LEN,
                "KRL",
            ));
        }
        let fanuc = formats.contains(&ProgramFormat::Fanuc);
        let yaskawa = formats.contains(&ProgramFormat::Yaskawa);
        if fanuc {
            name_checks.push((
                "module_name",
                &settings.module_name,
                fanuc::MAX_NAME_LEN,
                "FANUC TP",
            ));
            if settings.module_name.chars().any(|c| c.is_ascii_lowercase()) {
                problems.push(SettingsProblem::new(
                    "module_name",
                    format!(
                        "`{}`: FANUC program names are upper case",
                        settings.module_name
                    ),
                ));
            }
        }
        if yaskawa {
            name_checks.push((
                "module_name",
                &settings.module_name,
                yaskawa::MAX_NAME_LEN,
                "Yaskawa INFORM",
            ));
        }
        if (fanuc || yaskawa) && settings.zone != "fine" {
            problems.push(SettingsProblem::new(
                "zone",
                format!(
                    "`{}` with format {}: FANUC's CNT and Yaskawa's PL are not radii, so these programs stop exactly at every point; use `fine`",
                    settings.zone,
                    if fanuc { "`fanuc`" } else { "`yaskawa`" }
                ),
            ));
        }
        for (key, name, max_len, language) in name_checks {
            if problems.iter().any(|p| p.key == key) {
                continue;
            }
            if let Some(message) = export::identifier_problem(name, max_len, language)
                .or_else(|| export::generated_name_clash(name))
            {
                problems.push(SettingsProblem::new(key, message));
            }
        }
        if rapid && !problems.iter().any(|p| p.key == "tool_name") {
            let several = format!("{}_1", settings.tool_name);
            if let Some(message) = export::generated_name_clash(&several) {
                problems.push(SettingsProblem::new(
                    "tool_name",
                    format!(
                        "with several tools it becomes `{several}`, `{}_2` …: {message}",
                        settings.tool_name
                    ),
                ));
            }
        }
        if rapid && settings.tool_name.eq_ignore_ascii_case(&settings.wobj_name) {
            problems.push(SettingsProblem::new(
                "wobj_name",
                format!(
                    "`{}` is also `tool_name`; the module declares both",
                    settings.wobj_name
                ),
            ));
        }
        if let Err(message) = settings.zone_mm() {
            problems.push(SettingsProblem::new("zone", message));
        }
        if settings.approach_mm > 0.0 && settings.motion == MotionSetting::Joint {
            problems.push(SettingsProblem::new(
                "approach_mm",
                "approach moves are linear (MoveL, LIN): set `motion` to `linear` or `both`",
            ));
        }
        match &settings.tool_target {
            Some(target) if target.is_empty() => problems.push(SettingsProblem::new(
                "tool_target",
                "empty: name a target (SMR) id of the parameters, or leave it out",
            )),
            Some(_) if !parameters_bound => problems.push(SettingsProblem::new(
                "tool_target",
                "`tool_target` picks a calibrated tool of the input `parameters`, which is not bound",
            )),
            _ => {}
        }
        problems
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &ExportProgramSettings,
    ) -> Result<StageOutputs, StageError> {
        let input = ctx.input("commands")?;
        let mut commands = read_commands(&input.df, &input.path, ctx.robot.spec())?;
        check_commands(ctx.robot, &commands, &input.path)?;
        // A robot on a track: each command's carriage position, required and
        // within the travel (and refused for a robot without one).
        let track_mm = super::track_positions(&input.df, &input.path, ctx.robot.spec())?;
        if ctx.robot.spec().track.is_some() {
            for (command, e_mm) in commands.iter_mut().zip(track_mm) {
                command.track_mm = Some(e_mm);
            }
        }
        // Commands at positioner axis values: the programs move the
        // positioner with the arm, since a target on the table is reached
        // only with the table where compensate put it.
        let positioner = super::positioner_rows::positioner_axes_of_targets(
            &input.df,
            &input.path,
            ctx.robot.spec(),
        )?;
        if let Some(held) = positioner_holds(&positioner) {
            for (command, p_deg) in commands.iter_mut().zip(held) {
                command.positioner_deg = Some(p_deg);
            }
        }
        if !commands.iter().any(Command::is_ok) {
            let mut statuses = std::collections::BTreeMap::<&str, usize>::new();
            for command in &commands {
                *statuses.entry(command.status.as_str()).or_default() += 1;
            }
            let statuses: Vec<String> = statuses
                .iter()
                .map(|(status, n)| format!("{n} {status}"))
                .collect();
            return Err(StageError::Invalid(format!(
                "{}: {} row(s), none with status ok ({}): the programs would move nowhere; compensate's table says why each row is not ok",
                input.path.display(),
                commands.len(),
                statuses.join(", ")
            )));
        }
        let failed: Vec<String> = commands
            .iter()
            .filter(|c| !c.is_ok())
            .map(|c| format!("{} ({})", c.target_id, c.status))
            .collect();
        if settings.on_failed == OnFailedSetting::Fail && !failed.is_empty() {
            return Err(StageError::Invalid(format!(
                "{}: {} row(s) have a status other than ok and `on_failed = \"fail\"`: target_id {}",
                input.path.display(),
                failed.len(),
                failed.join(", ")
            )));
        }
        let motion = MotionSettings {
            name: settings.module_name.clone(),
            speed_mm_s: settings.speed_mm_s,
            joint_speed_percent: settings.joint_speed_percent,
            zone_mm: settings
                .zone_mm()
                .map_err(|m| StageError::Invalid(format!("setting `zone`: {m}")))?,
            motions: Motions {
                joint: settings.motion != MotionSetting::Linear,
                linear: settings.motion != MotionSetting::Joint,
            },
            approach_mm: (settings.approach_mm > 0.0 && settings.motion != MotionSetting::Joint)
                .then_some(settings.approach_mm),
            pre_position_deg: (settings.pre_position_deg > 0.0)
                .then_some(settings.pre_position_deg),
        };
        let set = model_set(ctx, "parameters", "model", &settings.model)?;
        let parameters = match &set {
            Some(set) => Some((set, ctx.input("parameters")?.path.as_path())),
            None => None,
        };
        let (tools, row_tools) = program_tools(
            ctx.robot,
            parameters,
            settings.tool_target.as_deref(),
            &commands,
            &input.path,
        )?;
        let stops = cartesian::stops(
            ctx.robot,
            &commands,
            &tools,
            &row_tools,
            motion.approach_mm,
            motion.pre_position_deg,
        )
        .map_err(|e| StageError::Invalid(format!("{}: {e}", input.path.display())))?;
        let mut warnings = Vec::new();
        if motion.pre_position_deg.is_none()
            && let Some(c) = commands.iter().find(|c| c.is_ok() && c.has_approach())
        {
            warnings.push(format!(
                "the commands were compensated for each joint reaching them from a fixed direction (backlash; target_id {} from {:?}), and `pre_position_deg` = 0 writes no move that makes it so: a joint arriving from the other side is off by its dead band",
                c.target_id, c.approach
            ));
        }
        if let Some(d) = cartesian::table_deviation(&commands, &stops) {
            warnings.push(format!(
                "the commands table's Cartesian targets (x_cmd_mm ... qz_cmd) are up to {:.4} mm (target_id {}) and {:.2e} rad from the poses of the declared tool at the joint commands: they were computed for another tool. These files use the declared tool and its poses, which give the same joint commands.",
                d.position_mm, d.target_id, d.angle_rad
            ));
        }
        let payload = &ctx.robot.spec().payload;
        let program = Program {
            commands,
            tools,
            stops,
            payload: (payload.mass_kg > 0.0).then_some(Payload {
                mass_kg: payload.mass_kg,
                cog_in_tool_mm: payload.cog_mm,
            }),
            warnings,
            provenance: Provenance {
                version: env!("CARGO_PKG_VERSION").to_string(),
                source: describe(&input.path, &input.df),
                robot: ctx.robot.spec().name.clone(),
            },
        };
        // Every number a file prints, once more: the checks above bound them,
        // so this only fails on a bug, never with `inf`, `NaN` or 301 digits
        // in a program.
        if let Some(problem) = export::unprintable(&program, &motion) {
            return Err(StageError::Failed(format!(
                "{}: {problem}; no file written",
                input.path.display()
            )));
        }
        let mut outputs = StageOutputs::default();
        let name = &settings.module_name;
        for format in settings.formats(parameters.is_some(), ctx.robot.spec()) {
            match format {
                ProgramFormat::Rapid => {
                    let text = rapid::module(
                        ctx.robot,
                        &program,
                        &motion,
                        &settings.tool_name,
                        &settings.wobj_name,
                    );
                    outputs
                        .files
                        .insert(format!("{name}.mod"), text.into_bytes());
                }
                ProgramFormat::Krl => {
                    let src = krl::src(ctx.robot, &program, &motion);
                    let dat = krl::dat(ctx.robot, &program, &motion);
                    outputs
                        .files
                        .insert(format!("{name}.src"), src.into_bytes());
                    outputs
                        .files
                        .insert(format!("{name}.dat"), dat.into_bytes());
                }
                ProgramFormat::Fanuc => {
                    let frames = fanuc::FanucFrames {
                        user_tool: settings.fanuc_user_tool,
                        position_register: settings.fanuc_position_register,
                    };
                    let text = fanuc::program(ctx.robot, &program, &motion, &frames);
                    outputs
                        .files
                        .insert(format!("{name}.ls"), text.into_bytes());
                }
                ProgramFormat::Yaskawa => {
                    let text =
                        yaskawa::job(ctx.robot, &program, &motion, settings.yaskawa_tool_file)
                            .map_err(|e| {
                                StageError::Invalid(format!(
                                    "format `yaskawa` ({}): {e}",
                                    ctx.robot.spec().path.display()
                                ))
                            })?;
                    outputs
                        .files
                        .insert(format!("{name}.jbi"), text.into_bytes());
                }
                ProgramFormat::Csv => {
                    outputs.files.insert(
                        "commands.csv".into(),
                        export::csv::table(ctx.robot, &program).into_bytes(),
                    );
                    outputs.files.insert(
                        export::csv::NOTES_FILE.into(),
                        export::csv::notes(ctx.robot, &program).into_bytes(),
                    );
                }
                ProgramFormat::Urdf => {
                    let (set, path) = parameters.ok_or_else(|| {
                        StageError::Invalid(
                            "format `urdf` needs the input `parameters` (the calibrated geometry)"
                                .into(),
                        )
                    })?;
                    let source = urdf::UrdfSource {
                        version: env!("CARGO_PKG_VERSION").to_string(),
                        parameters: describe(path, &ctx.input("parameters")?.df),
                        model: set.model.to_string(),
                        targets: set.targets.clone(),
                    };
                    if let Some(problem) = urdf::unprintable(ctx.robot, &set.values) {
                        return Err(StageError::Failed(format!(
                            "{}: {problem}; no file written",
                            path.display()
                        )));
                    }
                    let text = urdf::robot_urdf(ctx.robot, &set.values, &source);
                    outputs.files.insert("robot.urdf".into(), text.into_bytes());
                }
            }
        }
        let exported = program.stops.len();
        outputs
            .facts
            .insert("exported".into(), exported.to_string());
        outputs
            .facts
            .insert("skipped".into(), failed.len().to_string());
        outputs
            .facts
            .insert("tools".into(), program.tools.len().to_string());
        // Printed by `egcal stage` and `egcal run`, cached or not.
        if !program.warnings.is_empty() {
            outputs
                .facts
                .insert("warning".into(), program.warnings.join(" | "));
        }
        outputs.facts.insert(
            "files".into(),
            outputs.files.keys().cloned().collect::<Vec<_>>().join(","),
        );
        Ok(outputs)
    }
}

/// The tools the programs declare (those of the `ok` rows, in target order)
/// and each row's tool as an index into them (0 for rows that are not `ok`).
///
/// Which tool a row's Cartesian target is a pose of, first match wins:
///
/// * a `tool_id` column: the row's target in the parameter set (an id the set
///   does not have is an error naming it and the set's ids; without a
///   `parameters` input, the robot file's `[tool]` for a single id);
/// * the setting `tool_target`: that target of a several-target set;
/// * the set's one target; a several-target set without either is an error
///   naming its targets;
/// * without a `parameters` input, the robot file's `[tool]`.
///
/// The calibrated tool, not the robot file's: it is the point the joint
/// commands put on the targets, so it is the frame linear and approach moves
/// must move. (Which tool `compensate` wrote `x_cmd_mm …` for does not change
/// the joint motion at the targets: the poses are recomputed for the declared
/// tool, [`cartesian`].)
fn program_tools(
    robot: &Robot,
    parameters: Option<(&ParameterSet, &std::path::Path)>,
    tool_target: Option<&str>,
    commands: &[Command],
    commands_path: &std::path::Path,
) -> Result<(Vec<ProgramTool>, Vec<usize>), StageError> {
    let has_column = commands.iter().any(|c| c.tool_id.is_some());
    let invalid = StageError::Invalid;
    if has_column {
        if let Some(row) = commands.iter().position(|c| c.tool_id.is_none()) {
            return Err(invalid(format!(
                "{}: row {row} (target_id {}): `tool_id` is null; every row needs its target (SMR) id",
                commands_path.display(),
                commands[row].target_id
            )));
        }
        if tool_target.is_some() {
            return Err(invalid(format!(
                "setting `tool_target` and the column `tool_id` of {} both name the tool; the column names each row's, so leave the setting out",
                commands_path.display()
            )));
        }
    }
    let row_ids: Vec<Option<String>> = commands.iter().map(|c| c.tool_id.clone()).collect();
    // Each row's target index in the set (0 for a one-target set), and the
    // name of each index for the headers.
    let (row_targets, target_names): (Vec<usize>, Vec<Option<String>>) = match parameters {
        Some((set, path)) => {
            let several = set.targets.len() > 1;
            let indices = if has_column {
                set.target_indices(Some(&row_ids), row_ids.len())
                    .map_err(|m| {
                        invalid(format!(
                            "{}: column `tool_id`: {m} ({})",
                            commands_path.display(),
                            path.display()
                        ))
                    })?
            } else {
                let index = match (tool_target, several) {
                    (Some(target), true) => {
                        set.targets.iter().position(|t| t == target).ok_or_else(|| {
                            invalid(format!(
                                "setting `tool_target`: target `{target}` has no tool translation in model `{}` of {} (it has {})",
                                set.model,
                                path.display(),
                                set.targets.join(", ")
                            ))
                        })?
                    }
                    (Some(target), false) => {
                        return Err(invalid(format!(
                            "setting `tool_target`: model `{}` of {} has one target (x_t, y_t, z_t), not named `{target}`; leave the setting out",
                            set.model,
                            path.display()
                        )));
                    }
                    (None, true) => {
                        return Err(invalid(format!(
                            "model `{}` of {} has several targets ({}), and {} does not say which one's tool the commands are for (no `tool_id` column): name it with the setting `tool_target`",
                            set.model,
                            path.display(),
                            set.targets.join(", "),
                            commands_path.display()
                        )));
                    }
                    (None, false) => 0,
                };
                vec![index; commands.len()]
            };
            let names = if several {
                set.targets.iter().cloned().map(Some).collect()
            } else {
                vec![None]
            };
            (indices, names)
        }
        None => {
            let mut ids: Vec<&String> = row_ids.iter().flatten().collect();
            ids.sort();
            ids.dedup();
            if ids.len() > 1 {
                return Err(invalid(format!(
                    "{}: column `tool_id` names several targets ({}), but without the input `parameters` egcal knows one tool, the robot file's [tool]: bind the parameters the commands were computed with",
                    commands_path.display(),
                    ids.iter()
                        .map(|s| s.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                )));
            }
            (
                vec![0; commands.len()],
                vec![ids.first().map(|s| (*s).clone())],
            )
        }
    };
    let mut used: Vec<usize> = commands
        .iter()
        .zip(&row_targets)
        .filter(|(c, _)| c.is_ok())
        .map(|(_, &t)| t)
        .collect();
    used.sort_unstable();
    used.dedup();
    let tools = used
        .iter()
        .map(|&target| {
            let (flange_from_tool, source) = match parameters {
                Some((set, path)) => (
                    robot.flange_from_tool(&set.values, target),
                    format!(
                        "the calibrated tool of model {} in {}",
                        set.model,
                        path.file_name().map_or_else(
                            || path.display().to_string(),
                            |f| f.to_string_lossy().into_owned()
                        )
                    ),
                ),
                None => (
                    robot_file_tool(robot),
                    "the robot file's [tool] (no parameters input)".to_string(),
                ),
            };
            ProgramTool {
                target_id: target_names[target].clone(),
                source,
                flange_from_tool,
            }
        })
        .collect();
    let row_tools = commands
        .iter()
        .zip(&row_targets)
        .map(|(c, t)| {
            if c.is_ok() {
                used.iter().position(|u| u == t).unwrap_or(0)
            } else {
                0
            }
        })
        .collect();
    Ok((tools, row_tools))
}

/// The robot file's nominal flange → tool.
fn robot_file_tool(robot: &Robot) -> Frame {
    robot.flange_from_tool(&crate::robot::ParamValues::nominal(robot.spec()), 0)
}

/// A table's file name and content hash, for the headers (not the full path,
/// which differs between machines and cache entries).
fn describe(path: &std::path::Path, df: &polars::prelude::DataFrame) -> String {
    let file = path.file_name().map_or_else(
        || path.display().to_string(),
        |f| f.to_string_lossy().into_owned(),
    );
    format!("{file} (content hash {})", &tables::content_hash(df))
}

/// How far a Cartesian target of the table may lie from the robot base, as a
/// multiple of [`reach_mm`]: compensate writes nominal poses of the arm, so a
/// target beyond it was written for another robot, in other units, or is
/// corrupt.
const REACH_FACTOR: f64 = 2.0;

/// The largest `envelope_distance` compensate writes: the largest per-joint
/// difference, wrapped to ±180° (deg).
const MAX_ENVELOPE_DISTANCE_DEG: f64 = 180.0;

/// An upper bound of the distance from the robot base to the robot file's
/// tool: the sum of the MDH lengths `|a| + |d|` (with a prismatic joint's
/// farthest travel) and the tool translation (mm).
pub fn reach_mm(robot: &Robot) -> f64 {
    let spec = robot.spec();
    let links: f64 = spec
        .joints
        .iter()
        .map(|j| {
            let travel = match j.kind {
                crate::robot::file::JointKind::Prismatic => {
                    j.limits().iter().fold(0.0_f64, |m, v| m.max(v.abs()))
                }
                crate::robot::file::JointKind::Revolute => 0.0,
            };
            j.a_mm.abs() + j.d_mm.abs() + travel
        })
        .sum();
    let tool = &spec.tool;
    links + nalgebra::Vector3::new(tool.x_mm, tool.y_mm, tool.z_mm).norm()
}

/// Refuses, naming the file, the row, its target_id, the column and what was
/// expected, a `commands` row whose values are not what `compensate` writes
/// for this robot:
///
/// * a status other than compensate's (`OK`, `ok ` would silently leave the
///   row out of the motion);
/// * a row with status `ok` whose joint command lies outside the robot file's
///   joint limits (the check `compensate` applies to its branch hints,
///   [`joints_problem`]): a program must never command it;
/// * a Cartesian target (`x_cmd_mm` …) farther from the base than
///   [`REACH_FACTOR`] × [`reach_mm`];
/// * a negative distance (`residual_mm`, `correction_mm`, `elastic_mm`), and
///   on an `ok` row one beyond that bound (the CSV prints them);
/// * an `envelope_distance` outside [0, 180]°, a `u95_mm` negative or beyond
///   [`MAX_POSITION_MM`];
/// * an empty `tool_id`.
///
/// NaN and infinities were refused by the table's schema check; the
/// quaternion's norm by [`read_commands`]. The joint values of rows that are
/// not `ok` (the solver's last iterate, maybe beyond a limit: that is what
/// `joint_limit` says) are not checked against the limits: no file prints them.
pub fn check_commands(
    robot: &Robot,
    commands: &[Command],
    path: &std::path::Path,
) -> Result<(), StageError> {
    let reach = reach_mm(robot);
    let limit_mm = REACH_FACTOR * reach;
    let statuses: Vec<&str> = Status::ALL.iter().map(|s| s.as_str()).collect();
    for (row, c) in commands.iter().enumerate() {
        let bad = |column: &str, message: String| {
            StageError::Invalid(format!(
                "{}: row {row} (target_id {}): column `{column}`: {message}",
                path.display(),
                c.target_id
            ))
        };
        if !statuses.contains(&c.status.as_str()) {
            return Err(bad(
                "status",
                format!(
                    "{:?} is no status compensate writes; expected one of {}",
                    c.status,
                    statuses.join(", ")
                ),
            ));
        }
        if c.is_ok()
            && let Some(problem) = joints_problem(robot, &c.q_deg)
        {
            let column = problem.split(' ').next().unwrap_or("q_deg").to_string();
            return Err(bad(
                &column,
                format!("{problem}; a command with status ok must be one the robot can take"),
            ));
        }
        // hypot: 1e300 stays 1e300 in the message, not inf.
        let distance = c.position_mm.iter().fold(0.0_f64, |n, v| n.hypot(*v));
        if !(0.0..=limit_mm).contains(&distance) {
            return Err(bad(
                "x_cmd_mm",
                format!(
                    "the Cartesian target (x_cmd_mm, y_cmd_mm, z_cmd_mm) is {} mm from the robot base, more than {limit_mm:.0} mm ({REACH_FACTOR} times the reach of the robot file's arm and tool, {reach:.0} mm)",
                    compact(distance)
                ),
            ));
        }
        for (column, value) in [
            ("residual_mm", c.residual_mm),
            ("correction_mm", c.correction_mm),
            ("elastic_mm", c.elastic_mm),
        ] {
            let max = if c.is_ok() { limit_mm } else { f64::MAX };
            if !(value >= 0.0 && value <= max) {
                return Err(bad(
                    column,
                    format!(
                        "{} mm, expected a distance from 0 to {max:.0} mm ({REACH_FACTOR} times the arm's reach)",
                        compact(value)
                    ),
                ));
            }
        }
        if let Some(value) = c.envelope_distance
            && !(0.0..=MAX_ENVELOPE_DISTANCE_DEG).contains(&value)
        {
            return Err(bad(
                "envelope_distance",
                format!(
                    "{}, expected a joint-space distance from 0 to {MAX_ENVELOPE_DISTANCE_DEG} deg",
                    compact(value)
                ),
            ));
        }
        if let Some(value) = c.u95_mm
            && !(0.0..=MAX_POSITION_MM).contains(&value)
        {
            return Err(bad(
                "u95_mm",
                format!(
                    "{} mm, expected an uncertainty radius from 0 to {MAX_POSITION_MM} mm",
                    compact(value)
                ),
            ));
        }
        if c.tool_id.as_deref().is_some_and(|t| t.trim().is_empty()) {
            return Err(bad(
                "tool_id",
                "empty; give the target (SMR) id of the parameters, or leave the column out".into(),
            ));
        }
    }
    Ok(())
}

/// The rows of a checked `commands` table; a quaternion far from unit length is
/// refused, naming its row.
pub fn read_commands(
    df: &polars::prelude::DataFrame,
    path: &std::path::Path,
    robot: &crate::robot::RobotSpec,
) -> Result<Vec<Command>, TableError> {
    let ids = i64_values(df, "target_id", path)?;
    let joints = schema::joint_vectors(df, path, robot)?;
    let status = str_values(df, "status", path)?;
    let [residual, correction, elastic] =
        ["residual_mm", "correction_mm", "elastic_mm"].map(|c| f64_values(df, c, path));
    let (residual, correction, elastic) = (residual?, correction?, elastic?);
    let position: Vec<Vec<f64>> = COMMAND_POSITION_COLUMNS
        .iter()
        .map(|c| f64_values(df, c, path))
        .collect::<Result<_, _>>()?;
    let quaternion: Vec<Vec<f64>> = COMMAND_QUATERNION_COLUMNS
        .iter()
        .map(|c| f64_values(df, c, path))
        .collect::<Result<_, _>>()?;
    // Optional: each row's target (SMR), and the envelope columns of spec §8.
    let tool_id = optional_str_values(df, "tool_id", path)?;
    let envelope_distance = optional_f64_values(df, "envelope_distance", path)?;
    let u95_mm = optional_f64_values(df, "u95_mm", path)?;
    let approach = approach_values(df, path)?;
    let at = |column: &Option<Vec<Option<f64>>>, row: usize| {
        column.as_ref().and_then(|c| c[row]).filter(|v| !v.is_nan())
    };
    let mut rows = Vec::with_capacity(ids.len());
    for (row, id) in ids.iter().enumerate() {
        let q: [f64; 4] = std::array::from_fn(|k| quaternion[k][row]);
        // hypot: a component of 1e300 gives a norm of 1e300, not inf.
        let norm = q.iter().fold(0.0_f64, |n, v| n.hypot(*v));
        // Written so that a NaN norm is refused too.
        if !(1.0 - QUATERNION_NORM_TOLERANCE..=1.0 + QUATERNION_NORM_TOLERANCE).contains(&norm) {
            return Err(TableError::BadValue {
                file: path.to_path_buf(),
                column: "qw_cmd".into(),
                row,
                message: format!(
                    "target_id {id}: quaternion (qw_cmd, qx_cmd, qy_cmd, qz_cmd) has norm {}, expected a unit quaternion",
                    compact(norm)
                ),
            });
        }
        rows.push(Command {
            target_id: *id,
            q_deg: joints[row],
            status: status[row].clone().unwrap_or_default(),
            residual_mm: residual[row],
            correction_mm: correction[row],
            elastic_mm: elastic[row],
            position_mm: std::array::from_fn(|k| position[k][row]),
            quaternion_wxyz: q,
            tool_id: tool_id.as_ref().and_then(|c| c[row].clone()),
            envelope_distance: at(&envelope_distance, row),
            u95_mm: at(&u95_mm, row),
            approach: approach[row],
            // Read and checked against the robot file by the stage.
            track_mm: None,
            positioner_deg: None,
        });
    }
    Ok(rows)
}

/// Each command's positioner axis values when some command moves the
/// positioner: a row off the table (no axis values) keeps the table where
/// the row before left it, and rows before the first on the table where
/// that one needs it, so the positioner never moves for a target it does
/// not carry. `None` when no row moves it.
fn positioner_holds(
    rows: &[Option<[f64; MAX_POSITIONER_AXES]>],
) -> Option<Vec<[f64; MAX_POSITIONER_AXES]>> {
    let first = rows.iter().flatten().next().copied()?;
    let mut held = first;
    Some(
        rows.iter()
            .map(|row| {
                if let Some(p_deg) = row {
                    held = *p_deg;
                }
                held
            })
            .collect(),
    )
}

/// How far from 1 a quaternion's norm may be: the table stores a unit
/// quaternion, so more than rounding means a wrong column.
const QUATERNION_NORM_TOLERANCE: f64 = 1e-6;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::test_support::irb1600;

    fn row(target_id: i64, status: &str, q_deg: [f64; crate::robot::MAX_JOINTS]) -> Command {
        Command {
            target_id,
            q_deg,
            status: status.into(),
            residual_mm: 0.0,
            correction_mm: 0.5,
            elastic_mm: 0.1,
            position_mm: [900.0, 0.0, 800.0],
            quaternion_wxyz: [1.0, 0.0, 0.0, 0.0],
            tool_id: None,
            envelope_distance: Some(3.0),
            u95_mm: Some(0.2),
            approach: [0; 7],
            track_mm: None,
            positioner_deg: None,
        }
    }

    #[test]
    fn rows_off_the_table_hold_the_positioner_where_it_stands() {
        assert_eq!(positioner_holds(&[None, None]), None);
        let (a, b) = ([10.0, 20.0], [-5.0, 90.0]);
        assert_eq!(
            positioner_holds(&[None, Some(a), None, Some(b), None]),
            Some(vec![a, a, a, b, b])
        );
    }

    fn problem(rows: &[Command]) -> String {
        let robot = irb1600();
        check_commands(&robot, rows, std::path::Path::new("c.parquet"))
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn commands_a_program_must_not_carry_are_named() {
        let robot = irb1600();
        let q = [10.0, 20.0, -30.0, 40.0, 50.0, 60.0];
        let good = vec![
            row(1, "ok", crate::robot::joint_array(&q)),
            row(2, "joint_limit", [0.0, 500.0, 0.0, 0.0, 0.0, 0.0, 0.0]),
        ];
        // A row that is not ok may keep a last iterate beyond the limits.
        assert!(check_commands(&robot, &good, std::path::Path::new("c.parquet")).is_ok());
        let mut beyond = good.clone();
        beyond[0].q_deg[1] = 500.0;
        let p = problem(&beyond);
        assert!(
            p.contains("c.parquet: row 0 (target_id 1): column `q2_deg`")
                && p.contains("q2_deg = 500")
                && p.contains("[-90, 120]"),
            "{p}"
        );
        let mut far = good.clone();
        far[1].position_mm[0] = 1e300;
        let p = problem(&far);
        assert!(
            p.contains("row 1 (target_id 2): column `x_cmd_mm`") && p.contains("1e300"),
            "{p}"
        );
        let mut status = good.clone();
        status[0].status = "OK".into();
        assert!(problem(&status).contains("column `status`: \"OK\""));
        let mut negative = good.clone();
        negative[1].correction_mm = -1.0;
        assert!(problem(&negative).contains("column `correction_mm`"));
        let mut huge = good.clone();
        huge[0].elastic_mm = 1e5;
        assert!(problem(&huge).contains("column `elastic_mm`"));
        let mut envelope = good.clone();
        envelope[1].envelope_distance = Some(181.0);
        assert!(problem(&envelope).contains("column `envelope_distance`"));
        let mut u95 = good.clone();
        u95[1].u95_mm = Some(1e300);
        assert!(problem(&u95).contains("column `u95_mm`: 1e300"));
        let mut tool = good;
        tool[0].tool_id = Some(" ".into());
        assert!(problem(&tool).contains("column `tool_id`"));
    }

    #[test]
    fn the_reach_bound_is_the_arm_and_its_tool() {
        // IRB 1600-1.45: a 150, 700, 115 (|a|) and d 486.5, 600, 65 (|d|) plus
        // its tool; about 2 m, and at least the arm's 1.45 m reach.
        let reach = reach_mm(&irb1600());
        assert!((1450.0..3000.0).contains(&reach), "{reach}");
    }
}
