//! `scan_logs`: the logged measurements of one robot over a time window, as the
//! `measurements` table of a nightly re-calibration, with a time-split `selection`
//! (identify on the older days, validate on the newest) — see [`crate::logs`].
//!
//! The window is relative to the run date (`last = "14d"`: the run date and the 13
//! days before it) or absolute (`from`/`to`). The files found and their content
//! hashes (or, on S3, their ETags), and the run date, are part of the cache key: a
//! new log file or a new night re-runs the stage, an unchanged folder does not.
//!
//! Logs may live in a folder or in S3-compatible object storage
//! (`logs = "s3://bucket/prefix"`); outputs and published calibrations stay on
//! POSIX storage, since publishing relies on an atomic rename.

use std::path::Path;

use polars::prelude::*;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::{
    SettingsContext, SettingsProblem, Stage, StageContext, StageError, StageInfo, StageOutputs,
    TableSlot, settings_error,
};
use crate::logs::s3::{S3Location, S3Settings};
use crate::logs::{self, ContentKey, LogQuery, LogSource, ScanReport};
use crate::table::schema;
use crate::table::time::date_string;

pub struct ScanLogsStage;

/// What to do with unreadable files and rows that break the measurements contract.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum BadData {
    /// Count them by reason, leave them out, carry on.
    #[default]
    Skip,
    /// Stop the run at the first bad file or with the count of bad rows.
    Fail,
}

/// Settings of `scan_logs`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ScanLogsSettings {
    /// Log folder (searched recursively for `*.parquet`; `robot_id=…` and
    /// `date=YYYY-MM-DD` folders prune) or a glob, relative to the job file; or an
    /// S3 prefix `s3://bucket/prefix` (credentials from the `AWS_*` variables).
    pub logs: String,
    /// Endpoint, region and plain-HTTP permission of an S3-compatible store (each
    /// defaults to its `AWS_*` variable).
    pub s3: S3Settings,
    /// What identifies a log file in the cache key: `etag` (S3's ETag, the BLAKE3
    /// hash of a local file) or `content` (the BLAKE3 hash of every file's bytes,
    /// wherever it is stored: the same key for a folder and a bucket of the same
    /// logs, at the price of reading every object once more).
    pub content_key: ContentKey,
    /// The robot whose rows to keep.
    pub robot_id: String,
    /// Window of whole days ending on the run date (or `to`), e.g. `"14d"`:
    /// `1d` to `36600d`. Ignored when `from` is set.
    pub last: String,
    /// First day of an absolute window, `YYYY-MM-DD`.
    pub from: Option<String>,
    /// Last day of an absolute window (included), `YYYY-MM-DD`; default the run date.
    pub to: Option<String>,
    /// Newest logged days held out of identification (role `validation`).
    #[schemars(range(min = 0, max = 36_600))]
    pub holdout_days: u32,
    /// Fewest identification (older-day) rows the window must hold.
    #[schemars(range(min = 1, max = 1_000_000_000))]
    pub min_rows: usize,
    pub bad_data: BadData,
}

impl Default for ScanLogsSettings {
    fn default() -> Self {
        ScanLogsSettings {
            logs: String::new(),
            s3: S3Settings::default(),
            content_key: ContentKey::default(),
            robot_id: String::new(),
            last: "14d".into(),
            from: None,
            to: None,
            holdout_days: 1,
            min_rows: 30,
            bad_data: BadData::Skip,
        }
    }
}

static INFO: StageInfo = StageInfo {
    kind: "scan_logs",
    uses_cable_robot: false,
    updates_input: None,
    summary: "Logged measurements of one robot over a time window, split by day for validation",
    code_version: 3,
    inputs: &[],
    outputs: &[
        TableSlot {
            name: "measurements",
            schema: schema::measurements,
            required: true,
            meaning: "the robot's good logged rows in the window, oldest first",
        },
        TableSlot {
            name: "selection",
            schema: schema::selection,
            required: true,
            meaning: "calibration = older days, validation = the newest holdout_days",
        },
    ],
};

/// Where the window starts, as the settings give it (before the run date is known).
enum WindowStart {
    /// `from`: a day.
    Day(i64),
    /// `last`: this many whole days ending on the last day.
    Last(i64),
}

impl ScanLogsSettings {
    /// The settings' window and logs, checked without the run date: every problem
    /// by key, or the window's start and its last day when `to` is set.
    fn window(&self) -> Result<(WindowStart, Option<i64>), Vec<SettingsProblem>> {
        let mut problems = Vec::new();
        if self.logs.is_empty() {
            problems.push(SettingsProblem::new(
                "logs",
                "required: a log folder, glob or s3:// prefix",
            ));
        }
        if let Some(Err(message)) = S3Location::parse(&self.logs) {
            problems.push(SettingsProblem::new("logs", message));
        }
        if self.robot_id.is_empty() {
            problems.push(SettingsProblem::new("robot_id", "required"));
        }
        for (key, message) in self.s3.problems("s3") {
            problems.push(SettingsProblem::new(&key, message));
        }
        let mut date = |key: &str, text: &str| {
            let day = crate::table::time::parse_date(text);
            if day.is_none() {
                problems.push(SettingsProblem::new(
                    key,
                    format!("`{text}` is not a date YYYY-MM-DD (a four-digit year, a real day)"),
                ));
            }
            day
        };
        let to = self.to.as_deref().map(|to| date("to", to));
        let start = match &self.from {
            Some(from) => date("from", from).map(WindowStart::Day),
            None => match last_days(&self.last) {
                Ok(days) => Some(WindowStart::Last(days)),
                Err(message) => {
                    problems.push(SettingsProblem::new("last", message));
                    None
                }
            },
        };
        if let (Some(WindowStart::Day(from)), Some(Some(to))) = (&start, &to)
            && from > to
        {
            problems.push(SettingsProblem::new(
                "from",
                format!(
                    "`{}` is after `to` = `{}`: the window would be empty",
                    date_string(*from),
                    date_string(*to)
                ),
            ));
        }
        match (start, to) {
            (Some(start), None) if problems.is_empty() => Ok((start, None)),
            (Some(start), Some(Some(to))) if problems.is_empty() => Ok((start, Some(to))),
            _ => Err(problems),
        }
    }

    fn query(&self, job_dir: &Path, run_date: i64) -> Result<LogQuery, StageError> {
        let (start, to) = self.window().map_err(|p| settings_error(&p))?;
        let last_day = to.unwrap_or(run_date);
        let first_day = match start {
            WindowStart::Day(day) => day,
            WindowStart::Last(days) => last_day - days + 1,
        };
        if first_day > last_day {
            return Err(StageError::Invalid(format!(
                "setting `from`: the window {} .. {} is empty (`from` is after the run date {})",
                date_string(first_day),
                date_string(last_day),
                date_string(last_day)
            )));
        }
        Ok(LogQuery {
            source: LogSource::parse(&self.logs, job_dir, &self.s3)
                .map_err(|m| StageError::Invalid(format!("setting `logs`: {m}")))?,
            robot_id: self.robot_id.clone(),
            first_day,
            last_day,
            skip_bad_data: self.bad_data == BadData::Skip,
            on_track: false,
        })
    }
}

/// Longest window `last` allows, in days (100 years).
const MAX_LAST_DAYS: i64 = 36_600;

/// The days of a `last` window (`"14d"`), or why it is not one.
fn last_days(text: &str) -> Result<i64, String> {
    let allowed = format!("allowed: 1d to {MAX_LAST_DAYS}d");
    let digits = text.strip_prefix('+').unwrap_or(text).strip_suffix('d');
    match digits {
        Some(n) if !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()) => {
            match n.parse::<i64>() {
                Ok(0) => Err(format!("`{text}` is an empty window ({allowed})")),
                Ok(days) if days <= MAX_LAST_DAYS => Ok(days),
                _ => Err(format!("`{text}` is out of range ({allowed})")),
            }
        }
        _ if text.starts_with('-') => Err(format!(
            "`{text}` is negative; a window counts days back from the run date ({allowed})"
        )),
        _ => Err(format!(
            "`{text}` is not a number of days like \"14d\" ({allowed})"
        )),
    }
}

/// A scan's error as a stage error: a setting or the environment is bad input.
fn stage_error(e: logs::LogError) -> StageError {
    if e.is_bad_input() {
        StageError::Invalid(e.to_string())
    } else {
        StageError::Failed(e.to_string())
    }
}

impl Stage for ScanLogsStage {
    type Settings = ScanLogsSettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn check_settings(
        &self,
        settings: &ScanLogsSettings,
        _: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        settings.window().err().unwrap_or_default()
    }

    fn external_key(
        &self,
        settings: &ScanLogsSettings,
        job_dir: &Path,
        run_date: i64,
    ) -> Result<serde_json::Value, StageError> {
        let query = settings.query(job_dir, run_date)?;
        let found = logs::discover(&query).map_err(stage_error)?;
        let hashes = logs::content_keys(&found, settings.content_key).map_err(stage_error)?;
        Ok(serde_json::json!({
            "window": [date_string(query.first_day), date_string(query.last_day)],
            "files": hashes,
        }))
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &ScanLogsSettings,
    ) -> Result<StageOutputs, StageError> {
        super::refuse_prismatic_joints(
            ctx.robot.spec(),
            "scan_logs (the logged measurements' `q1_deg … q6_deg`)",
            "calibrate a gantry from a measure stage's table",
        )?;
        let query = LogQuery {
            on_track: ctx.robot.spec().track.is_some(),
            ..settings.query(ctx.job_dir, ctx.run_date)?
        };
        let found = logs::discover(&query).map_err(stage_error)?;
        let scan = logs::scan(&query, &found).map_err(stage_error)?;
        let window = format!(
            "{} .. {}",
            date_string(query.first_day),
            date_string(query.last_day)
        );
        for (file, reason) in &scan.report.bad_files {
            ctx.progress
                .note(&format!("skipped {}: {reason}", file.address));
        }
        let measurements = scan.measurements;
        if measurements.height() == 0 {
            return Err(StageError::Failed(no_rows_message(
                &query,
                &window,
                &scan.report,
            )));
        }
        let days = &scan.days;
        let mut distinct = days.to_vec();
        distinct.dedup();
        let holdout = settings.holdout_days as usize;
        if distinct.len() <= holdout {
            return Err(StageError::Failed(format!(
                "robot `{}` has logs on {} day(s) in {window}; holding out {holdout} needs at least {}",
                query.robot_id,
                distinct.len(),
                holdout + 1
            )));
        }
        let first_holdout_day = distinct[distinct.len() - holdout];
        let calibration_rows = days.iter().filter(|d| **d < first_holdout_day).count();
        if calibration_rows < settings.min_rows {
            return Err(StageError::Failed(format!(
                "robot `{}` has {calibration_rows} identification rows in {window} before the hold-out day {}, fewer than min_rows = {}",
                query.robot_id,
                date_string(first_holdout_day),
                settings.min_rows
            )));
        }
        let roles: Vec<&str> = days
            .iter()
            .map(|d| {
                if *d < first_holdout_day {
                    "calibration"
                } else {
                    "validation"
                }
            })
            .collect();
        let ids = measurements
            .column("cw_id")
            .map_err(|e| StageError::Failed(e.to_string()))?
            .clone();
        let selection = crate::table::frame(vec![
            ids,
            Column::new("role".into(), roles),
            Column::new("order".into(), (0..days.len() as i64).collect::<Vec<_>>()),
        ]);
        let mut outputs = StageOutputs::default();
        let report = &scan.report;
        let facts = [
            ("window", window),
            (
                "files",
                format!(
                    "{} found, {} pruned by partition, {} read{}",
                    report.files_found,
                    report.files_pruned,
                    report.files_read,
                    folders_not_listed(report)
                ),
            ),
            ("bad_files", report.bad_files.len().to_string()),
            ("rows_in_window", report.rows_in_window.to_string()),
            ("calibration_rows", calibration_rows.to_string()),
            (
                "validation_rows",
                (days.len() - calibration_rows).to_string(),
            ),
            ("holdout_from", date_string(first_holdout_day)),
        ];
        for (name, value) in facts {
            outputs.facts.insert(name.into(), value);
        }
        for (reason, count) in &report.dropped_rows {
            outputs
                .facts
                .insert(format!("dropped: {reason}"), count.to_string());
        }
        for (file, reason) in &report.bad_files {
            outputs
                .facts
                .insert(format!("bad file: {}", file.relative), reason.clone());
        }
        outputs.tables.insert("measurements".into(), measurements);
        outputs.tables.insert("selection".into(), selection);
        Ok(outputs)
    }
}

/// Explains an empty scan: nothing there, or rows of other robots only.
fn no_rows_message(query: &LogQuery, window: &str, report: &ScanReport) -> String {
    if report.files_found == 0 {
        return format!(
            "no log files under {}: no `*.parquet` file found{} (expected robot_id=…/date=YYYY-MM-DD/*.parquet)",
            query.source,
            folders_not_listed(report)
        );
    }
    let mut message = format!(
        "no logged rows of robot `{}` in {window} under {} ({} file(s) found, {} pruned by partition, {} read{}",
        query.robot_id,
        query.source,
        report.files_found,
        report.files_pruned,
        report.files_read,
        folders_not_listed(report)
    );
    if !report.bad_files.is_empty() {
        message += &format!(", {} unreadable", report.bad_files.len());
    }
    message += ")";
    let others: Vec<&str> = report
        .robots_seen
        .iter()
        .map(String::as_str)
        .filter(|r| *r != query.robot_id)
        .collect();
    if !others.is_empty() {
        message += &format!("; the logs hold robot(s) {}", others.join(", "));
    }
    message
}

/// `; N partition folders not listed` for an S3 scan that skipped some.
fn folders_not_listed(report: &ScanReport) -> String {
    match report.folders_pruned {
        0 => String::new(),
        n => format!("; {n} partition folder(s) outside the window not listed"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn last_windows_are_checked_with_their_range() {
        assert_eq!(last_days("14d"), Ok(14));
        assert_eq!(last_days("36600d"), Ok(36_600));
        for (text, word) in [
            ("1000000000000d", "out of range"),
            ("99999999999999999999999d", "out of range"),
            ("36601d", "out of range"),
            ("0d", "empty window"),
            ("-3d", "negative"),
            ("14", "not a number of days"),
            ("d", "not a number of days"),
            ("1.5d", "not a number of days"),
        ] {
            let message = last_days(text).unwrap_err();
            assert!(
                message.contains(word) && message.contains("1d to 36600d"),
                "{text}: {message}"
            );
        }
    }

    #[test]
    fn dates_and_their_order_are_checked() {
        let settings = |from: &str, to: &str| ScanLogsSettings {
            logs: "logs".into(),
            robot_id: "r".into(),
            from: Some(from.into()),
            to: Some(to.into()),
            ..ScanLogsSettings::default()
        };
        let keys = |s: ScanLogsSettings| -> Vec<String> {
            s.window()
                .err()
                .unwrap_or_default()
                .into_iter()
                .map(|p| p.key)
                .collect()
        };
        assert!(keys(settings("2026-11-01", "2026-11-14")).is_empty());
        assert_eq!(keys(settings("2026-11-20", "2026-11-14")), ["from"]);
        assert_eq!(keys(settings("2026-02-30", "2026-11-14")), ["from"]);
        assert_eq!(keys(settings("99999999999-01-01", "2026-11-14")), ["from"]);
        assert_eq!(keys(settings("2026-11-01", "26-11-14")), ["to"]);
    }
}
