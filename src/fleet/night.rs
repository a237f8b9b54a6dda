//! One robot-night: the job template loaded for the robot, run for the night's
//! date into the robot's output folder, and its record.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::{Fleet, FleetError};
use crate::exit_code::{self, Finished};
use crate::job::Plan;
use crate::job_run;
use crate::runner::RunOptions;
use crate::table::{self, time::date_string};

/// How a robot-night ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// The calibration in service stays (or the job has no gate and ran).
    Kept,
    /// A new calibration was published.
    Published,
    /// A candidate that should have replaced the calibration was refused.
    Refused,
    /// The job failed (bad input, a stage error); nothing was published.
    Failed,
    /// No record: the task never ran or was killed (gathering only).
    Missing,
}

impl Outcome {
    pub fn as_str(self) -> &'static str {
        match self {
            Outcome::Kept => "kept",
            Outcome::Published => "published",
            Outcome::Refused => "refused",
            Outcome::Failed => "failed",
            Outcome::Missing => "missing",
        }
    }
}

/// The gate's decision of a night, as its `decision.parquet` gives it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GateRecord {
    pub stage: String,
    pub decision: String,
    pub reasons: String,
    pub holdout_rows: Option<i64>,
    pub in_service_mean_mm: Option<f64>,
    pub candidate_mean_mm: Option<f64>,
    pub p_value: Option<f64>,
    pub max_position_change_mm: Option<f64>,
    pub published_as: Option<String>,
}

/// What `nights/<date>/results/<robot_id>.json` holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NightRecord {
    pub robot_id: String,
    pub run_date: String,
    pub outcome: Outcome,
    /// `egcal run`'s exit code for this night alone (0, 10, 11, or an error's).
    pub exit_code: u8,
    /// The array task that ran it (`fleet submit`), none for `fleet run`.
    pub task_index: Option<usize>,
    /// The job's own summary, or the error.
    pub message: String,
    /// One per gate stage of the job.
    pub gates: Vec<GateRecord>,
    pub host: String,
    pub started_at: String,
    pub seconds: f64,
}

/// Where a night's record is kept.
pub fn record_path(fleet: &Fleet, robot: &str, run_date: i64) -> PathBuf {
    fleet
        .night_dir(run_date)
        .join("results")
        .join(format!("{robot}.json"))
}

/// The night's record, if one was written.
pub fn read_record(path: &Path) -> Result<Option<NightRecord>, FleetError> {
    match std::fs::read_to_string(path) {
        Ok(text) => serde_json::from_str(&text)
            .map(Some)
            .map_err(|e| FleetError::io(path, format!("unreadable night record: {e}"))),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(FleetError::io(path, e)),
    }
}

fn write_record(path: &Path, record: &NightRecord) -> Result<(), FleetError> {
    let json = serde_json::to_string_pretty(record).expect("a night record serialises");
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| FleetError::io(dir, e))?;
    }
    crate::fsio::write_bytes_atomic(path, json.as_bytes()).map_err(|e| FleetError::io(path, e))
}

/// Whether an existing record ends the night: a failed night is run again, a
/// decided one never (a second run would compare against what it published).
pub fn already_decided(fleet: &Fleet, robot: &str, run_date: i64) -> Result<bool, FleetError> {
    let record = read_record(&record_path(fleet, robot, run_date))?;
    Ok(record.is_some_and(|r| r.outcome != Outcome::Failed))
}

/// Runs `robot`'s night and records it; a job that fails is a record with
/// [`Outcome::Failed`], not an error. `jobs`: stages run at once inside the night.
pub fn run_night(
    fleet: &Fleet,
    robot: &str,
    run_date: i64,
    task_index: Option<usize>,
    jobs: usize,
) -> Result<NightRecord, FleetError> {
    let started_at = table::now_rfc3339();
    let clock = Instant::now();
    let ran = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        run_job(fleet, robot, run_date, jobs)
    }))
    .unwrap_or_else(|panic| {
        let what = panic
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_default();
        Err((exit_code::INTERNAL, format!("internal error: {what}")))
    });
    let (code, message, gates) = match ran {
        Ok((finished, gates)) => (finished.code, finished.message, gates),
        Err((code, message)) => (code, message, Vec::new()),
    };
    let outcome = match code {
        exit_code::OK => Outcome::Kept,
        exit_code::GATE_PUBLISHED => Outcome::Published,
        exit_code::GATE_REFUSED => Outcome::Refused,
        _ => Outcome::Failed,
    };
    let record = NightRecord {
        robot_id: robot.to_string(),
        run_date: date_string(run_date),
        outcome,
        exit_code: code,
        task_index,
        message,
        gates,
        host: host_name(),
        started_at,
        seconds: clock.elapsed().as_secs_f64(),
    };
    write_record(&record_path(fleet, robot, run_date), &record)?;
    Ok(record)
}

/// Refuses a template that no robot can run (a broken job file, a variable
/// missing everywhere) before any night or array task starts: exit 2 with the
/// job's problems for the first robot. A robot's own settings that do not fit
/// the template (a misspelt setting or stage id, a wrong type, a variable the
/// template does not use) are refused the same way, naming the fleet file's line
/// and key. A problem of some robots only (a missing calibration in service) is
/// left to their nights, which record it.
pub fn check_template(fleet: &Fleet) -> Result<(), FleetError> {
    // A robot whose own settings load proves the template works for one robot:
    // the second loop would only load its plan again (the robot file, the
    // job's input tables), which each night then loaded three times.
    let mut one_loaded = false;
    for robot in fleet.robots_with_overrides() {
        if let Err(problems) = Plan::load_with(&fleet.job, &fleet.job_overrides(robot)) {
            let own: Vec<String> = problems
                .0
                .iter()
                .filter(|p| p.file == fleet.file)
                .map(|p| p.to_string())
                .collect();
            if !own.is_empty() {
                return Err(FleetError::Usage(format!(
                    "the settings of robot `{robot}` in the fleet file do not fit the job template {}:\n{}",
                    fleet.job.display(),
                    own.join("\n")
                )));
            }
        } else {
            one_loaded = true;
        }
    }
    if one_loaded {
        return Ok(());
    }
    let mut first = None;
    for robot in &fleet.robots {
        match Plan::load_with(&fleet.job, &fleet.job_overrides(robot)) {
            Ok(_) => return Ok(()),
            Err(problems) if first.is_none() => first = Some((robot, problems)),
            Err(_) => {}
        }
    }
    match first {
        None => Ok(()),
        Some((robot, problems)) => Err(FleetError::Usage(format!(
            "the job template fails for every robot of fleet `{}`; for `{robot}`:\n{problems}",
            fleet.name
        ))),
    }
}

type JobRun = Result<(Finished, Vec<GateRecord>), (u8, String)>;

fn run_job(fleet: &Fleet, robot: &str, run_date: i64, jobs: usize) -> JobRun {
    let mut plan = Plan::load_with(&fleet.job, &fleet.job_overrides(robot))
        .map_err(|e| (exit_code::BAD_INPUT, e.to_string()))?;
    plan.output_dir = fleet.robot_output(robot);
    let gate_dirs: Vec<(String, PathBuf)> = plan
        .stages
        .iter()
        .filter(|s| s.kind.info().kind == "gate")
        .map(|s| (s.id.clone(), plan.output_dir.join(&s.id)))
        .collect();
    let options = RunOptions {
        jobs: jobs.max(1),
        run_date: Some(run_date),
        ..RunOptions::default()
    };
    let finished = job_run::run_plan(plan, &options, true)
        .map_err(|e| (exit_code::of_run_error(&e), e.to_string()))?;
    let gates = gate_dirs
        .iter()
        .map(|(stage, dir)| gate_record(stage, dir))
        .collect::<Result<_, _>>()
        .map_err(|e| (exit_code::BAD_INPUT, e.to_string()))?;
    Ok((finished, gates))
}

fn gate_record(stage: &str, dir: &Path) -> Result<GateRecord, table::TableError> {
    let path = dir.join("decision.parquet");
    let df = table::read_checked(&path, &table::schema::gate_decision())?;
    let text = |name: &str| -> Result<Option<String>, table::TableError> {
        Ok(table::schema::str_values(&df, name, &path)?
            .into_iter()
            .next()
            .flatten())
    };
    let number = |name: &str| {
        df.column(name)
            .ok()
            .and_then(|c| c.cast(&polars::prelude::DataType::Float64).ok())
            .and_then(|c| c.f64().ok().and_then(|v| v.get(0)))
    };
    Ok(GateRecord {
        stage: stage.to_string(),
        decision: text("decision")?.unwrap_or_default(),
        reasons: text("reasons")?.unwrap_or_default(),
        holdout_rows: number("holdout_rows").map(|v| v as i64),
        in_service_mean_mm: number("in_service_mean_mm"),
        candidate_mean_mm: number("candidate_mean_mm"),
        p_value: number("p_value"),
        max_position_change_mm: number("max_position_change_mm"),
        published_as: text("published_as")?,
    })
}

/// This machine's name, for the record (Slurm spreads tasks over nodes).
fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_string())
        .unwrap_or_default()
}

/// One line per finished night: `robot_a: published (12.3 s)`.
pub fn night_line(robot: &str, record: Option<&NightRecord>) -> String {
    match record {
        None => format!("{robot}: decided earlier, not run again"),
        Some(r) => {
            let mut line = format!("{robot}: {} ({:.1} s)", r.outcome.as_str(), r.seconds);
            if r.outcome == Outcome::Failed {
                line += &format!(": {}", first_line(&r.message));
            }
            line
        }
    }
}

pub(crate) fn first_line(text: &str) -> &str {
    text.lines().next().unwrap_or_default()
}
