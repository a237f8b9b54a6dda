//! `measure`: the campaign, hardware in the loop. For each conf-wrench row it
//! moves the robot, applies the wrench, reads the force/torque sensor and the joint
//! encoders, measures the SMR, and records one `measurements` row (spec §6).
//!
//! Durability: every row is appended to a journal (flushed, fsynced) before the
//! next move, so an interrupted campaign — crash, Ctrl-C, driver death — resumes on
//! the next run without measuring a row twice or losing one. Rows that keep
//! failing after `retries` go to `measurement_failures` with the reason; they are
//! tried again when the campaign is resumed. Safety checks (joint limits, wrench
//! bounds) stop the campaign before the move, with the row and its file named.
//! Each row's readings are checked for plausibility ([`ReadingBounds`]: joint
//! limits and commands, sensor range, distance from the tracker); an implausible
//! reading is retried like a transient fault, then recorded as a failed row with
//! the reason — never as data.

use std::collections::HashMap;

use polars::prelude::{Column, DataFrame, DataType, TimeUnit, TimeZone};
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::{
    SettingsContext, SettingsProblem, Stage, StageContext, StageError, StageInfo, StageOutputs,
    TableSlot, conf_wrench_rows, model_name_problem, model_set,
};
use crate::calibration::row_checks::JOINT_LIMIT_TOLERANCE_DEG;
use crate::journal::Journal;
use crate::rig::approach::approach_directions;
use crate::rig::driver::ExternalDriver;
use crate::rig::reading_checks::{ReadingBounds, sigma_fault, track_fault};
use crate::rig::simulator::{Simulator, SimulatorSettings};
use crate::rig::{Disposition, Rig, RigError, timeout_from_seconds};
use crate::robot::{ConfWrench, MAX_JOINTS};
use crate::table::parameters::ModelName;
use crate::table::schema::{self, POSITION_COLUMNS, SIGMA_COLUMNS, WRENCH_COLUMNS};
use crate::table::{content_hash, frame};

pub struct MeasureStage;

/// Which rig the campaign runs on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum DriverKind {
    /// The in-process simulator (settings under `simulator`).
    Simulator,
    /// An external driver process started with `command`.
    External,
}

/// Settings of `measure`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct MeasureSettings {
    /// The rig: simulator (in process) or external (a driver process, see
    /// schemas/driver-protocol.md).
    pub driver: DriverKind,
    /// Program and arguments of the external driver, run in the job file's folder;
    /// a relative program path with a `/` (`./driver.sh`) is taken from there too.
    pub command: Vec<String>,
    /// Time limit of each driver request (s).
    #[schemars(range(max = 86_400.0))]
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub timeout_s: f64,
    /// Extra attempts of a row after a transient failure.
    #[schemars(range(min = 0, max = 100))]
    pub retries: u32,
    /// Stop the campaign at the first row that still fails after its retries.
    pub stop_on_failure: bool,
    /// Safety bound on each force component (N); a row beyond it stops the campaign.
    #[schemars(range(max = 100_000.0))]
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub max_force_n: f64,
    /// Safety bound on each moment component (N·m).
    #[schemars(range(max = 10_000.0))]
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub max_moment_nm: f64,
    /// Model of the `truth` input the simulator uses.
    pub truth_model: String,
    /// Written to the `robot_id` column when set.
    pub robot_id: Option<String>,
    /// Seed of the simulated noise; default: the stage's seed.
    pub seed: Option<u64>,
    /// Noise and unmodelled errors of the simulator.
    pub simulator: SimulatorSettings,
    // Plausibility of each row's readings (`rig::reading_checks`): a reading
    // beyond a bound is retried, then recorded as a failed row, never as data.
    /// How far beyond the robot file's joint limits a joint reading may lie (deg);
    /// the same slack the identification's row checks allow.
    #[schemars(range(min = 0.0, max = 360.0))]
    pub joint_tolerance_deg: f64,
    /// How far a joint reading may lie from its command (deg): a settled robot
    /// reads within hundredths of a degree, a reading degrees away is a fault.
    #[schemars(range(max = 360.0))]
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub max_joint_error_deg: f64,
    /// The force/torque sensor's range per force component (N); a reading beyond
    /// it is saturated or corrupt. Set it to your sensor's rated range.
    #[schemars(range(max = 1.0e6))]
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub sensor_range_n: f64,
    /// The force/torque sensor's range per moment component (N·m).
    #[schemars(range(max = 1.0e5))]
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub sensor_range_nm: f64,
    /// How far each force reading may lie from the commanded force (N), to catch a
    /// slack cable or a sensor read in the wrong frame; unchecked when unset,
    /// since the row records (and the model uses) the wrench the sensor read.
    #[schemars(range(min = 0.0, max = 1.0e6))]
    pub max_wrench_error_n: Option<f64>,
    /// How far each moment reading may lie from the commanded moment (N·m);
    /// unchecked when unset.
    #[schemars(range(min = 0.0, max = 1.0e5))]
    pub max_wrench_error_nm: Option<f64>,
    /// How far from the tracker (the origin of its frame) a measured position may
    /// lie (mm): a robot cell is a few metres across.
    #[schemars(range(max = 1.0e5))]
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub max_tracker_distance_mm: f64,
    /// Rows whose `conf_wrenches` carry approach directions (`dir1 … dir6`,
    /// as `compensate` writes them for a model with backlash) are reached
    /// from a pre-position: the command minus this (deg) times each
    /// direction, as an exported program moves (`export_program`'s
    /// `pre_position_deg`), so each joint arrives moving the way the
    /// compensation assumed.
    #[schemars(range(max = 10.0))]
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub pre_position_deg: f64,
    /// How far a linear track's position reading may lie from its command
    /// (mm), for a robot file with a `[track]`: a settled carriage reads
    /// within hundredths of a millimetre.
    #[schemars(range(max = 1000.0))]
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub max_track_error_mm: f64,
    /// How far a positioner axis's reading may lie from its command (deg),
    /// for rows measuring a nest on the positioner's table.
    #[schemars(range(max = 90.0))]
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub max_positioner_error_deg: f64,
}

impl Default for MeasureSettings {
    fn default() -> Self {
        MeasureSettings {
            driver: DriverKind::Simulator,
            command: Vec::new(),
            timeout_s: 30.0,
            retries: 2,
            stop_on_failure: false,
            max_force_n: 150.0,
            max_moment_nm: 15.0,
            truth_model: ModelName::Elastogeometric.as_str().into(),
            robot_id: None,
            seed: None,
            simulator: SimulatorSettings::default(),
            joint_tolerance_deg: JOINT_LIMIT_TOLERANCE_DEG,
            max_joint_error_deg: 1.0,
            sensor_range_n: 2500.0,
            sensor_range_nm: 400.0,
            max_wrench_error_n: None,
            max_wrench_error_nm: None,
            max_tracker_distance_mm: 40_000.0,
            pre_position_deg: 1.0,
            max_track_error_mm: 1.0,
            max_positioner_error_deg: 0.1,
        }
    }
}

static INFO: StageInfo = StageInfo {
    kind: "measure",
    uses_cable_robot: false,
    updates_input: None,
    summary: "Measurement campaign on a rig (simulator or external driver), resumable",
    code_version: 5,
    inputs: &[
        TableSlot {
            name: "conf_wrenches",
            schema: schema::conf_wrenches,
            required: true,
            meaning: "rows to measure: cw_id, q1_deg..q6_deg, commanded wrench",
        },
        TableSlot {
            name: "truth",
            schema: schema::parameters,
            required: false,
            meaning: "the simulated robot's true parameters (simulator only; nominal when absent)",
        },
    ],
    outputs: &[
        TableSlot {
            name: "measurements",
            schema: schema::measurements,
            required: true,
            meaning: "complete measured rows (spec §6)",
        },
        TableSlot {
            name: "measurement_failures",
            schema: schema::measurement_failures,
            required: true,
            meaning: "rows that could not be measured, with the reason",
        },
    ],
};

/// One journal entry.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "status", rename_all = "snake_case")]
enum Entry {
    Measured(Box<Reading>),
    Failed {
        cw_id: i64,
        attempts: u32,
        reason: String,
        failed_at_us: i64,
    },
}

/// What the rig read for one conf-wrench row.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct Reading {
    pub cw_id: i64,
    /// Encoder reading (deg).
    pub q_deg: [f64; 6],
    /// A seventh joint's encoder reading (deg), for a seven-joint arm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub q7_deg: Option<f64>,
    /// Force/torque sensor reading (N, N·m).
    pub wrench: [f64; 6],
    /// Tracker reading (mm).
    pub position_mm: [f64; 3],
    pub measured_at_us: i64,
    /// The tracker's own 1-σ uncertainty of the point (mm), when it gives one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma_mm: Option<[f64; 3]>,
    /// A linear track's position reading (mm), for a robot on a track.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub track_mm: Option<f64>,
    /// The SMR the tracker measured, in a campaign measuring a positioner's
    /// nests (every row names its target there).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target_id: Option<String>,
    /// The positioner's axis readings (deg, one per axis) of a row
    /// measuring a nest.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub positioner_deg: Option<Vec<f64>>,
}

impl Reading {
    /// The encoder reading as the model's joint vector.
    pub fn joint_vector(&self) -> [f64; MAX_JOINTS] {
        let mut q = crate::robot::joint_array(&self.q_deg);
        q[6] = self.q7_deg.unwrap_or(0.0);
        q
    }
}

impl Entry {
    fn cw_id(&self) -> i64 {
        match self {
            Entry::Measured(reading) => reading.cw_id,
            Entry::Failed { cw_id, .. } => *cw_id,
        }
    }
}

impl Stage for MeasureStage {
    type Settings = MeasureSettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn check_settings(
        &self,
        settings: &MeasureSettings,
        _ctx: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        let mut problems: Vec<SettingsProblem> =
            model_name_problem("truth_model", &settings.truth_model)
                .into_iter()
                .collect();
        if settings.driver == DriverKind::External && settings.command.is_empty() {
            problems.push(SettingsProblem::new(
                "command",
                "driver = \"external\" needs `command`: the driver program and its arguments, e.g. [\"python3\", \"driver.py\"]",
            ));
        }
        if let Err(m) = settings.simulator.clock_start_us() {
            problems.push(SettingsProblem::new("simulator.clock_start", m));
        }
        problems
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &MeasureSettings,
    ) -> Result<StageOutputs, StageError> {
        let input = ctx.input("conf_wrenches")?;
        let (ids, rows) = conf_wrench_rows(input, ctx.robot.spec())?;
        let config_ids = input
            .df
            .column("config_id")
            .ok()
            .and_then(|c| c.i64().ok().map(|v| v.iter().collect::<Vec<_>>()));
        let seed = settings.seed.unwrap_or(ctx.seed);

        let truth_set = model_set(ctx, "truth", "truth_model", &settings.truth_model)?;
        let truth = truth_set.as_ref().map_or_else(
            || crate::robot::ParamValues::nominal(ctx.robot.spec()),
            |set| set.values,
        );
        let truth_targets = truth_set.map(|set| set.targets).unwrap_or_default();
        // A campaign measuring a positioner's nests: every row says which
        // SMR the tracker measures, the arm's or a nest's.
        let row_targets = nest_campaign_targets(input, &rows)?;
        let positioner_axes = ctx
            .robot
            .spec()
            .positioner
            .as_ref()
            .map_or(0, |p| p.axes.len());
        // The direction each row must be reached from (spec §8), where given.
        let required = schema::approach_values(&input.df, &input.path)?;
        let pre_positioned = required.iter().flatten().any(|d| *d != 0);
        let on_track = ctx.robot.spec().track.is_some();

        // The journal belongs to the rows and the rig they are measured on, not to
        // retry, timeout or safety settings, nor to the external driver's command
        // line (a lab restarting its driver with other arguments continues the same
        // campaign). For the simulator, its settings, seed and truth define the rig.
        let fingerprint = {
            let mut hasher = blake3::Hasher::new();
            hasher.update(content_hash(&input.df).as_bytes());
            hasher.update(ctx.robot.spec().content_hash().as_bytes());
            let rig =
                serde_json::to_vec(&(settings.driver, &settings.robot_id)).expect("serialises");
            hasher.update(&rig);
            // Where the rows are reached from is part of what is measured.
            if pre_positioned {
                hasher.update(&settings.pre_position_deg.to_le_bytes());
            }
            if settings.driver == DriverKind::Simulator {
                hasher.update(&serde_json::to_vec(&settings.simulator).expect("serialises"));
                hasher.update(&seed.to_le_bytes());
                for v in truth.0 {
                    hasher.update(&v.to_le_bytes());
                }
                for target in &truth_targets {
                    hasher.update(target.as_bytes());
                    hasher.update(&[0]);
                }
            }
            hasher.finalize().to_hex().to_string()
        };
        let (mut journal, recorded) = Journal::open::<Entry>(ctx.work_dir, &fingerprint)
            .map_err(|e| StageError::Failed(e.to_string()))?;
        let mut latest: HashMap<i64, Entry> = HashMap::new();
        for entry in recorded {
            latest.insert(entry.cw_id(), entry);
        }
        let done = |latest: &HashMap<i64, Entry>, id: i64| {
            matches!(latest.get(&id), Some(Entry::Measured(_)))
        };
        let todo: Vec<usize> = (0..ids.len()).filter(|&k| !done(&latest, ids[k])).collect();
        if todo.len() < ids.len() {
            ctx.progress.note(&format!(
                "resuming: {} of {} rows already measured ({})",
                ids.len() - todo.len(),
                ids.len(),
                journal.path().display()
            ));
        }

        let bounds = ReadingBounds {
            limits_deg: ReadingBounds::limits_of(ctx.robot),
            prismatic: ctx.robot.prismatic_joints(),
            joint_tolerance_deg: settings.joint_tolerance_deg,
            max_joint_error_deg: settings.max_joint_error_deg,
            sensor_range_n: settings.sensor_range_n,
            sensor_range_nm: settings.sensor_range_nm,
            max_wrench_error_n: settings.max_wrench_error_n,
            max_wrench_error_nm: settings.max_wrench_error_nm,
            max_tracker_distance_mm: settings.max_tracker_distance_mm,
        };

        // The rows are measured in input order, each from its pre-position
        // where it has one: each row's approach direction follows from the
        // moves before it.
        let pre_positions: Vec<Option<[f64; MAX_JOINTS]>> = rows
            .iter()
            .zip(&required)
            .map(|(row, dir)| pre_position(&row.q_deg, dir, settings.pre_position_deg))
            .collect();
        let approach: HashMap<i64, [i8; MAX_JOINTS]> = ids
            .iter()
            .copied()
            .zip(row_directions(&rows, &pre_positions))
            .collect();
        let mut rig: Box<dyn Rig> = match settings.driver {
            DriverKind::Simulator => {
                // The in-process simulator meets the campaign's directions,
                // whatever a resume skips.
                Box::new(
                    Simulator::new(ctx.robot.clone(), truth, settings.simulator.clone(), seed)
                        .map_err(|m| {
                            StageError::Invalid(format!("setting `simulator.clock_start`: {m}"))
                        })?
                        .with_planned_approach(approach.clone())
                        .with_targets(truth_targets.clone()),
                )
            }
            DriverKind::External => {
                super::refuse_prismatic_joints(
                    ctx.robot.spec(),
                    "the driver protocol (`move_joints`, `read_joints`)",
                    "measure it on the simulator (`driver = \"simulator\"`)",
                )?;
                if ctx.robot.joint_count() > 6 {
                    return Err(StageError::Invalid(format!(
                        "the robot file {} has {} joints; the driver protocol moves six (`move_joints` and `read_joints` carry six values): a seven-joint arm is measured on the simulator (`driver = \"simulator\"`) or imported with `import_measurements`",
                        ctx.robot.spec().path.display(),
                        ctx.robot.joint_count()
                    )));
                }
                let driver = ExternalDriver::start(
                    &settings.command,
                    ctx.job_dir,
                    timeout_from_seconds(settings.timeout_s),
                )
                .map_err(|e| StageError::Failed(e.to_string()))?;
                if on_track && !driver.drives_a_track() {
                    return Err(StageError::Failed(format!(
                        "the robot file {} has a [track], and driver `{}` does not announce {} in its capabilities: it cannot place the carriage, so no row would be measured where it was designed",
                        ctx.robot.spec().path.display(),
                        driver.name,
                        crate::rig::protocol::TRACK_METHODS.join(" and ")
                    )));
                }
                if row_targets.is_some() && !driver.drives_a_positioner() {
                    return Err(StageError::Failed(format!(
                        "the rows of {} measure the positioner's nests, and driver `{}` does not announce {} in its capabilities: it cannot point the tracker at a nest or move the table, so no nest would be measured where it was designed",
                        input.path.display(),
                        driver.name,
                        crate::rig::protocol::POSITIONER_METHODS.join(", ")
                    )));
                }
                Box::new(driver.with_positioner_axes(positioner_axes))
            }
        };

        ctx.progress.start(todo.len() as u64, "rows");
        let mut failures = 0;
        for (done_count, &k) in todo.iter().enumerate() {
            check_safety(ctx, settings, &input.path, ids[k], k, &rows[k])?;
            if let Some(q_deg) = &pre_positions[k] {
                let pre = ConfWrench::new(*q_deg, rows[k].wrench);
                check_safety(ctx, settings, &input.path, ids[k], k, &pre).map_err(|e| {
                    StageError::Failed(format!(
                        "{e} (the pre-position {} deg before the row against its dir1 … dir6, the side its backlash was compensated for; lower `pre_position_deg` or compensate the target from the other side)",
                        settings.pre_position_deg
                    ))
                })?;
            }
            let mut attempts = 0;
            let entry = loop {
                attempts += 1;
                // The tracker is pointed at the row's SMR and the table moved
                // first; the carriage moves next, so the pre-position is where
                // the row is.
                let checked = row_targets
                    .as_ref()
                    .map_or(Ok(()), |targets| rig.select_target(&targets[k]))
                    .and_then(|()| {
                        rows[k]
                            .positioner_deg
                            .map_or(Ok(()), |p_deg| rig.move_positioner(ids[k], p_deg))
                    })
                    .and_then(|()| {
                        if on_track {
                            rig.move_track(ids[k], rows[k].track_mm)
                        } else {
                            Ok(())
                        }
                    })
                    .and_then(|()| {
                        pre_positions[k].map_or(Ok(()), |q_deg| rig.move_joints(ids[k], q_deg))
                    })
                    .and_then(|()| {
                        measure_row(
                            rig.as_mut(),
                            ids[k],
                            &rows[k],
                            on_track,
                            ctx.robot.joint_count(),
                        )
                    })
                    .map(|mut reading| {
                        reading.target_id = row_targets.as_ref().map(|t| t[k].clone());
                        reading
                    })
                    .and_then(|mut reading| {
                        if let Some(commanded) = rows[k].positioner_deg {
                            let read = rig.read_positioner()?;
                            if let Some(fault) = positioner_fault(
                                &commanded[..positioner_axes],
                                &read[..positioner_axes],
                                settings.max_positioner_error_deg,
                            ) {
                                return Err(fault);
                            }
                            reading.positioner_deg = Some(read[..positioner_axes].to_vec());
                        }
                        Ok(reading)
                    })
                    .and_then(|reading| {
                        bounds.check(
                            &rows[k].q_deg,
                            &rows[k].wrench.to_array(),
                            &reading.joint_vector(),
                            &reading.wrench,
                            &reading.position_mm,
                        )?;
                        if let Some(fault) = reading.sigma_mm.as_ref().and_then(sigma_fault) {
                            return Err(fault.into());
                        }
                        if let Some(fault) = reading.track_mm.and_then(|read| {
                            track_fault(rows[k].track_mm, read, settings.max_track_error_mm)
                        }) {
                            return Err(fault.into());
                        }
                        Ok(reading)
                    });
                match checked {
                    Ok(reading) => break Entry::Measured(Box::new(reading)),
                    Err(e) => match e.disposition() {
                        Disposition::Retry if attempts <= settings.retries => {
                            ctx.progress
                                .note(&format!("cw_id {}: {e}; retrying", ids[k]));
                            let _ = rig.release_wrench();
                        }
                        Disposition::Retry | Disposition::FailRow => {
                            let _ = rig.release_wrench();
                            break Entry::Failed {
                                cw_id: ids[k],
                                attempts,
                                reason: e.to_string(),
                                failed_at_us: rig.measured_at_us().max(now_us()),
                            };
                        }
                        Disposition::Stop => {
                            return Err(StageError::Failed(format!(
                                "cw_id {} (input row {k}): {e}; the {} rows measured so far are kept in {} and the next run resumes",
                                ids[k],
                                latest
                                    .values()
                                    .filter(|e| matches!(e, Entry::Measured(_)))
                                    .count(),
                                journal.path().display()
                            )));
                        }
                    },
                }
            };
            journal
                .append(&entry)
                .map_err(|e| StageError::Failed(e.to_string()))?;
            if let Entry::Failed { reason, .. } = &entry {
                failures += 1;
                if settings.stop_on_failure {
                    return Err(StageError::Failed(format!(
                        "cw_id {} (input row {k}) failed after {attempts} attempts: {reason} (stop_on_failure = true)",
                        ids[k]
                    )));
                }
            }
            latest.insert(ids[k], entry);
            ctx.progress.advance(done_count as u64 + 1);
        }
        drop(rig);
        journal
            .sync()
            .map_err(|e| StageError::Failed(e.to_string()))?;

        let mut outputs = tables(
            &schema::joint_column_names(ctx.robot.spec()),
            &ids,
            config_ids.as_deref(),
            &latest,
            settings.robot_id.as_deref(),
            &approach,
        );
        outputs.facts.insert("rows".into(), ids.len().to_string());
        outputs.facts.insert("failed".into(), failures.to_string());
        outputs.facts.insert(
            "measured_this_run".into(),
            (todo.len() - failures).to_string(),
        );
        Ok(outputs)
    }
}

/// Where a row with the approach directions `dir` is moved to first: its
/// command `distance_deg` back against them; `None` without a direction.
fn pre_position(
    q_deg: &[f64; MAX_JOINTS],
    dir: &[i8; MAX_JOINTS],
    distance_deg: f64,
) -> Option<[f64; MAX_JOINTS]> {
    dir.iter()
        .any(|d| *d != 0)
        .then(|| std::array::from_fn(|j| q_deg[j] - f64::from(dir[j]) * distance_deg))
}

/// The approach direction of every row measured in order, each from its
/// pre-position where it has one.
fn row_directions(
    rows: &[ConfWrench],
    pre_positions: &[Option<[f64; MAX_JOINTS]>],
) -> Vec<[i8; MAX_JOINTS]> {
    let mut moves = Vec::with_capacity(rows.len() * 2);
    let mut row_move = Vec::with_capacity(rows.len());
    for (row, pre) in rows.iter().zip(pre_positions) {
        moves.extend(*pre);
        row_move.push(moves.len());
        moves.push(row.q_deg);
    }
    let directions = approach_directions(&moves);
    row_move.into_iter().map(|k| directions[k]).collect()
}

/// Checks a commanded row before the move; a violation stops the campaign and
/// names the row and the file it came from (`path`, the conf_wrenches table), so
/// the lab knows which file to fix.
fn check_safety(
    ctx: &StageContext,
    settings: &MeasureSettings,
    path: &std::path::Path,
    cw_id: i64,
    k: usize,
    row: &ConfWrench,
) -> Result<(), StageError> {
    for (i, name) in schema::joint_column_names(ctx.robot.spec())
        .iter()
        .enumerate()
    {
        let [lo, hi] = ctx.robot.joint_limits(i);
        if !(row.q_deg[i] >= lo && row.q_deg[i] <= hi) {
            return Err(StageError::Failed(format!(
                "safety stop before cw_id {cw_id} (input row {k} of {}): {name} = {} is outside the joint limits [{lo}, {hi}]",
                path.display(),
                row.q_deg[i]
            )));
        }
    }
    let w = [
        row.wrench.force_n.as_slice(),
        row.wrench.moment_nm.as_slice(),
    ]
    .concat();
    for (i, name) in WRENCH_COLUMNS.iter().enumerate() {
        let (bound, setting) = if i < 3 {
            (settings.max_force_n, "max_force_n")
        } else {
            (settings.max_moment_nm, "max_moment_nm")
        };
        if w[i].abs() > bound {
            return Err(StageError::Failed(format!(
                "safety stop before cw_id {cw_id} (input row {k} of {}): {name} = {} exceeds the bound ±{bound} ({setting})",
                path.display(),
                w[i]
            )));
        }
    }
    Ok(())
}

/// One conf-wrench row on the rig, in the lab's order; with `on_track`, the
/// carriage (already moved to the row's position) is read with the joints.
pub(crate) fn measure_row(
    rig: &mut dyn Rig,
    cw_id: i64,
    row: &ConfWrench,
    on_track: bool,
    joints: usize,
) -> Result<Reading, RigError> {
    rig.move_joints(cw_id, row.q_deg)?;
    rig.apply_wrench(row.wrench.to_array())?;
    let wrench = rig.read_wrench()?;
    let q_deg = rig.read_joints()?;
    let track_mm = if on_track {
        Some(rig.read_track()?)
    } else {
        None
    };
    let position_mm = rig.measure()?;
    rig.release_wrench()?;
    let finite = wrench
        .iter()
        .chain(&q_deg)
        .chain(&position_mm)
        .chain(&track_mm)
        .all(|v| v.is_finite());
    if !finite {
        return Err(RigError::Transient(
            "rig returned a non-finite reading".into(),
        ));
    }
    Ok(Reading {
        cw_id,
        q_deg: std::array::from_fn(|i| q_deg[i]),
        q7_deg: (joints > 6).then_some(q_deg[6]),
        wrench,
        position_mm,
        measured_at_us: rig.measured_at_us(),
        sigma_mm: rig.measured_sigma_mm(),
        track_mm,
        target_id: None,
        positioner_deg: None,
    })
}

/// Each row's target id when the rows measure a positioner's nests (some
/// row is a nest row), so the tracker is pointed at each row's SMR; then
/// every row must name its target. `None` for any other campaign, whose
/// rows the tracker measures on the arm's one SMR.
fn nest_campaign_targets(
    input: &super::InputTable,
    rows: &[ConfWrench],
) -> Result<Option<Vec<String>>, StageError> {
    if rows.iter().all(|r| r.positioner_deg.is_none()) {
        return Ok(None);
    }
    let ids = schema::str_values(&input.df, "target_id", &input.path)?;
    ids.into_iter()
        .enumerate()
        .map(|(row, id)| {
            id.filter(|id| !id.trim().is_empty()).ok_or_else(|| {
                StageError::Invalid(format!(
                    "{}: column `target_id`, row {row} is empty: the rows measure the positioner's nests, so every row names the SMR the tracker measures (the arm's or a nest's)",
                    input.path.display()
                ))
            })
        })
        .collect::<Result<Vec<_>, _>>()
        .map(Some)
}

/// Why a positioner's axis reading cannot be the row's: farther than
/// `max_error_deg` from its command, or not finite.
fn positioner_fault(commanded: &[f64], read: &[f64], max_error_deg: f64) -> Option<RigError> {
    commanded
        .iter()
        .zip(read)
        .enumerate()
        .find(|(_, (c, r))| !r.is_finite() || (*r - *c).abs() > max_error_deg)
        .map(|(axis, (c, r))| {
            RigError::Row(format!(
                "the positioner's axis {} reads {r} deg for a command of {c} deg (max_positioner_error_deg = {max_error_deg}): it did not reach the row's position, or reports other units",
                axis + 1
            ))
        })
}

fn now_us() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as i64)
}

fn timestamps(name: &str, values: Vec<i64>) -> Column {
    Column::new(name.into(), values)
        .cast(&DataType::Datetime(
            TimeUnit::Microseconds,
            Some(TimeZone::UTC),
        ))
        .expect("i64 casts to datetime")
}

/// The two output tables, rows in input order; the measurements with the
/// campaign's approach directions (`approach`, by cw_id).
fn tables(
    joint_names: &[&'static str],
    ids: &[i64],
    config_ids: Option<&[Option<i64>]>,
    latest: &HashMap<i64, Entry>,
    robot_id: Option<&str>,
    approach: &HashMap<i64, [i8; MAX_JOINTS]>,
) -> StageOutputs {
    let mut measured: Vec<(&Reading, Option<i64>)> = Vec::new();
    let mut failed: Vec<&Entry> = Vec::new();
    for (k, id) in ids.iter().enumerate() {
        match latest.get(id) {
            Some(Entry::Measured(reading)) => {
                measured.push((reading.as_ref(), config_ids.and_then(|c| c[k])))
            }
            Some(e @ Entry::Failed { .. }) => failed.push(e),
            None => {}
        }
    }
    let mut measurements =
        measurements_frame(&measured, joint_names, config_ids.is_some(), robot_id);
    for (joint, name) in schema::APPROACH_COLUMNS.iter().enumerate() {
        let directions: Vec<i8> = measured
            .iter()
            .map(|(r, _)| approach.get(&r.cw_id).map_or(0, |d| d[joint]))
            .collect();
        measurements
            .with_column(Column::new((*name).into(), directions))
            .expect("one direction per measured row");
    }

    let mut f_id = Vec::new();
    let mut f_attempts = Vec::new();
    let mut f_reason = Vec::new();
    let mut f_at = Vec::new();
    for entry in failed {
        if let Entry::Failed {
            cw_id,
            attempts,
            reason,
            failed_at_us,
        } = entry
        {
            f_id.push(*cw_id);
            f_attempts.push(i64::from(*attempts));
            f_reason.push(reason.clone());
            f_at.push(*failed_at_us);
        }
    }
    let failures = frame(vec![
        Column::new("cw_id".into(), f_id),
        Column::new("attempts".into(), f_attempts),
        Column::new("reason".into(), f_reason),
        timestamps("failed_at", f_at),
    ]);
    let mut outputs = StageOutputs::default();
    outputs.tables.insert("measurements".into(), measurements);
    outputs
        .tables
        .insert("measurement_failures".into(), failures);
    outputs
}

/// The `measurements` table (spec §6) of readings in the given order, with their
/// configuration ids when `with_config_id`, and the robot id when known;
/// `joint_names` are the robot file's joint columns
/// ([`schema::joint_column_names`]).
pub(crate) fn measurements_frame(
    readings: &[(&Reading, Option<i64>)],
    joint_names: &[&'static str],
    with_config_id: bool,
    robot_id: Option<&str>,
) -> DataFrame {
    let mut cw = Vec::new();
    let mut q = vec![Vec::new(); 6];
    let mut w = vec![Vec::new(); 6];
    let mut p = vec![Vec::new(); 3];
    let mut at = Vec::new();
    let mut config = Vec::new();
    for (reading, config_id) in readings {
        cw.push(reading.cw_id);
        for i in 0..6 {
            q[i].push(reading.q_deg[i]);
            w[i].push(reading.wrench[i]);
        }
        for (column, value) in p.iter_mut().zip(reading.position_mm) {
            column.push(value);
        }
        at.push(reading.measured_at_us);
        config.push(*config_id);
    }
    let mut columns = vec![Column::new("cw_id".into(), cw)];
    for (name, values) in joint_names.iter().zip(q) {
        columns.push(Column::new((*name).into(), values));
    }
    // A seven-joint arm's readings carry the seventh joint.
    if let Some(name) = joint_names.get(6)
        && readings.iter().any(|(r, _)| r.q7_deg.is_some())
    {
        columns.push(Column::new(
            (*name).into(),
            readings.iter().map(|(r, _)| r.q7_deg).collect::<Vec<_>>(),
        ));
    }
    for (name, values) in WRENCH_COLUMNS.iter().zip(w) {
        columns.push(Column::new((*name).into(), values));
    }
    for (name, values) in POSITION_COLUMNS.iter().zip(p) {
        columns.push(Column::new((*name).into(), values));
    }
    if readings.iter().any(|(r, _)| r.sigma_mm.is_some()) {
        for (axis, name) in SIGMA_COLUMNS.iter().enumerate() {
            let values: Vec<Option<f64>> = readings
                .iter()
                .map(|(r, _)| r.sigma_mm.map(|s| s[axis]))
                .collect();
            columns.push(Column::new((*name).into(), values));
        }
    }
    if readings.iter().any(|(r, _)| r.track_mm.is_some()) {
        let values: Vec<Option<f64>> = readings.iter().map(|(r, _)| r.track_mm).collect();
        columns.push(Column::new(schema::TRACK_COLUMN.into(), values));
    }
    if readings.iter().any(|(r, _)| r.target_id.is_some()) {
        let values: Vec<Option<&str>> = readings
            .iter()
            .map(|(r, _)| r.target_id.as_deref())
            .collect();
        columns.push(Column::new("target_id".into(), values));
    }
    let axes = readings
        .iter()
        .filter_map(|(r, _)| r.positioner_deg.as_ref().map(Vec::len))
        .max()
        .unwrap_or(0);
    for (axis, name) in schema::POSITIONER_COLUMNS[..axes].iter().enumerate() {
        let values: Vec<Option<f64>> = readings
            .iter()
            .map(|(r, _)| r.positioner_deg.as_ref().and_then(|p| p.get(axis).copied()))
            .collect();
        columns.push(Column::new((*name).into(), values));
    }
    if with_config_id {
        columns.push(Column::new("config_id".into(), config));
    }
    if let Some(robot_id) = robot_id {
        columns.push(Column::new(
            "robot_id".into(),
            vec![robot_id; readings.len()],
        ));
    }
    columns.push(timestamps("measured_at", at));
    frame(columns)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_positioner_reading_far_from_its_command_fails_the_row() {
        assert!(positioner_fault(&[10.0, -45.0], &[10.02, -45.05], 0.1).is_none());
        // Radians for degrees, and NaN, name the axis.
        let fault = positioner_fault(&[10.0, -45.0], &[10.0, -0.785], 0.1)
            .unwrap()
            .to_string();
        assert!(fault.contains("axis 2 reads -0.785 deg"), "{fault}");
        let fault = positioner_fault(&[10.0], &[f64::NAN], 0.1)
            .unwrap()
            .to_string();
        assert!(fault.contains("axis 1 reads NaN"), "{fault}");
    }
}
