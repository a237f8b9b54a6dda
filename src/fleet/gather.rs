//! Gathering a night (`egcal fleet gather`): every robot's record into one table
//! (`nights/<date>/decisions.parquet`, schema `fleet_decisions`) and one page
//! (`nights/<date>/fleet_report.html`), and the exit code a scheduler or a person
//! acts on: 3 when a night failed or left no record, else 11 when a gate refused
//! a candidate, else 10 when one published, else 0.

use std::fmt::Write as _;
use std::path::PathBuf;

use polars::prelude::*;

use super::manifest::Manifest;
use super::night::{self, NightRecord, Outcome, first_line};
use super::{Fleet, FleetError};
use crate::exit_code;
use crate::report::escape;
use crate::table::time::date_string;

/// A gathered night.
#[derive(Debug, Clone)]
pub struct Gathered {
    pub decisions: PathBuf,
    pub report: PathBuf,
    /// Per robot: its task and its record (none when missing).
    pub rows: Vec<(String, Option<usize>, Option<NightRecord>)>,
    pub code: u8,
    pub summary: String,
}

/// Collects the night's records; writes the table and the page.
pub fn gather(fleet: &Fleet, run_date: i64) -> Result<Gathered, FleetError> {
    let manifest = Manifest::read(fleet, run_date)?;
    let slurm = manifest.executor == "slurm";
    let mut rows = Vec::new();
    for (index, robots) in manifest.tasks.iter().enumerate() {
        for robot in robots {
            let record = night::read_record(&night::record_path(fleet, robot, run_date))?;
            rows.push((robot.clone(), slurm.then_some(index), record));
        }
    }
    rows.sort_by(|a, b| a.0.cmp(&b.0));
    let dir = fleet.night_dir(run_date);
    let decisions = dir.join("decisions.parquet");
    let mut table = decisions_table(&rows, &date_string(run_date));
    crate::table::write_parquet(&mut table, &decisions, None)?;
    let report = dir.join("fleet_report.html");
    let page = report_page(fleet, &date_string(run_date), &rows);
    crate::fsio::write_bytes_atomic(&report, page.as_bytes())
        .map_err(|e| FleetError::io(&report, e))?;

    let outcome = |row: &(String, Option<usize>, Option<NightRecord>)| {
        row.2.as_ref().map_or(Outcome::Missing, |r| r.outcome)
    };
    let count = |o: Outcome| rows.iter().filter(|r| outcome(r) == o).count();
    let code = if count(Outcome::Failed) + count(Outcome::Missing) > 0 {
        exit_code::STAGE_FAILED
    } else if count(Outcome::Refused) > 0 {
        exit_code::GATE_REFUSED
    } else if count(Outcome::Published) > 0 {
        exit_code::GATE_PUBLISHED
    } else {
        exit_code::OK
    };
    let mut summary = format!(
        "fleet {}, night {}: {} robot(s): {} published, {} kept, {} refused, {} failed, {} missing",
        fleet.name,
        date_string(run_date),
        rows.len(),
        count(Outcome::Published),
        count(Outcome::Kept),
        count(Outcome::Refused),
        count(Outcome::Failed),
        count(Outcome::Missing),
    );
    for (robot, task, record) in &rows {
        let task = task.map(|t| format!(" (task {t})")).unwrap_or_default();
        match record {
            None => write!(
                summary,
                "\n  {robot}{task}: missing: no record (the task was killed, timed out or has not run; see {})",
                dir.join("slurm").display()
            ),
            Some(r) if r.outcome == Outcome::Failed => write!(
                summary,
                "\n  {robot}{task}: failed: {}",
                r.message.trim_end().replace('\n', "\n    ")
            ),
            Some(r) if r.outcome == Outcome::Refused => {
                write!(summary, "\n  {robot}{task}: refused: a person should look")
            }
            Some(_) => Ok(()),
        }
        .expect("write to a string");
    }
    write!(
        summary,
        "\ndecisions: {}\nreport: {}",
        decisions.display(),
        report.display()
    )
    .expect("write to a string");
    Ok(Gathered {
        decisions,
        report,
        rows,
        code,
        summary,
    })
}

fn decisions_table(
    rows: &[(String, Option<usize>, Option<NightRecord>)],
    run_date: &str,
) -> DataFrame {
    let records: Vec<Option<&NightRecord>> = rows.iter().map(|r| r.2.as_ref()).collect();
    let gate = |i: usize| records[i].and_then(|r| r.gates.first());
    let n = rows.len();
    let strings = |f: &dyn Fn(usize) -> Option<String>| (0..n).map(f).collect::<Vec<_>>();
    let floats = |f: &dyn Fn(usize) -> Option<f64>| (0..n).map(f).collect::<Vec<_>>();
    crate::table::frame(vec![
        Column::new("run_date".into(), vec![run_date.to_string(); n]),
        Column::new(
            "robot_id".into(),
            rows.iter().map(|r| r.0.clone()).collect::<Vec<_>>(),
        ),
        Column::new(
            "outcome".into(),
            strings(&|i| {
                Some(
                    records[i]
                        .map_or(Outcome::Missing, |r| r.outcome)
                        .as_str()
                        .to_string(),
                )
            }),
        ),
        Column::new(
            "exit_code".into(),
            (0..n)
                .map(|i| records[i].map(|r| r.exit_code as i64))
                .collect::<Vec<_>>(),
        ),
        Column::new(
            "task_index".into(),
            rows.iter()
                .map(|r| r.1.map(|t| t as i64))
                .collect::<Vec<_>>(),
        ),
        Column::new(
            "gate_stage".into(),
            strings(&|i| gate(i).map(|g| g.stage.clone())),
        ),
        Column::new(
            "gate_decision".into(),
            strings(&|i| gate(i).map(|g| g.decision.clone())),
        ),
        Column::new(
            "reasons".into(),
            strings(&|i| gate(i).map(|g| g.reasons.clone())),
        ),
        Column::new(
            "holdout_rows".into(),
            (0..n)
                .map(|i| gate(i).and_then(|g| g.holdout_rows))
                .collect::<Vec<_>>(),
        ),
        Column::new(
            "in_service_mean_mm".into(),
            floats(&|i| gate(i).and_then(|g| g.in_service_mean_mm)),
        ),
        Column::new(
            "candidate_mean_mm".into(),
            floats(&|i| gate(i).and_then(|g| g.candidate_mean_mm)),
        ),
        Column::new(
            "p_value".into(),
            floats(&|i| gate(i).and_then(|g| g.p_value)),
        ),
        Column::new(
            "max_position_change_mm".into(),
            floats(&|i| gate(i).and_then(|g| g.max_position_change_mm)),
        ),
        Column::new(
            "published_as".into(),
            strings(&|i| gate(i).and_then(|g| g.published_as.clone())),
        ),
        Column::new(
            "message".into(),
            strings(&|i| Some(records[i].map_or("no record".to_string(), |r| r.message.clone()))),
        ),
        Column::new(
            "host".into(),
            strings(&|i| records[i].map(|r| r.host.clone())),
        ),
        Column::new("seconds".into(), floats(&|i| records[i].map(|r| r.seconds))),
    ])
}

/// The night's page: a line per robot, the urgent ones first.
fn report_page(
    fleet: &Fleet,
    run_date: &str,
    rows: &[(String, Option<usize>, Option<NightRecord>)],
) -> String {
    let rank = |o: Outcome| match o {
        Outcome::Failed | Outcome::Missing => 0,
        Outcome::Refused => 1,
        Outcome::Published => 2,
        Outcome::Kept => 3,
    };
    let mut ordered: Vec<&(String, Option<usize>, Option<NightRecord>)> = rows.iter().collect();
    ordered.sort_by_key(|r| {
        (
            rank(r.2.as_ref().map_or(Outcome::Missing, |x| x.outcome)),
            r.0.clone(),
        )
    });
    let number =
        |v: Option<f64>, digits: usize| v.map_or("–".to_string(), |v| format!("{v:.digits$}"));
    let mut body = String::new();
    for (robot, task, record) in ordered {
        let outcome = record.as_ref().map_or(Outcome::Missing, |r| r.outcome);
        let gate = record.as_ref().and_then(|r| r.gates.first());
        let detail = match (record, gate) {
            (None, _) => "no record".to_string(),
            (Some(r), _) if outcome == Outcome::Failed => first_line(&r.message).to_string(),
            (_, Some(g)) => g.reasons.replace('\n', " "),
            (Some(_), None) => String::new(),
        };
        let report_link = fleet.robot_output(robot).join("report").join("report.html");
        let link = if report_link.is_file() {
            format!(
                " <a href=\"file://{}\">report</a>",
                escape(&report_link.display().to_string())
            )
        } else {
            String::new()
        };
        writeln!(
            body,
            "<tr class=\"{o}\"><td>{robot}{link}</td><td>{o}</td><td>{task}</td><td>{before}</td><td>{after}</td><td>{p}</td><td>{change}</td><td>{detail}</td></tr>",
            o = outcome.as_str(),
            robot = escape(robot),
            task = task.map_or("–".to_string(), |t| t.to_string()),
            before = number(gate.and_then(|g| g.in_service_mean_mm), 3),
            after = number(gate.and_then(|g| g.candidate_mean_mm), 3),
            p = gate.and_then(|g| g.p_value).map_or("–".to_string(), |p| format!("{p:.2e}")),
            change = number(gate.and_then(|g| g.max_position_change_mm), 3),
            detail = escape(&detail),
        )
        .expect("write to a string");
    }
    format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{name}: night {run_date}</title>\n<style>\nbody {{ font-family: sans-serif; margin: 2em; }}\ntable {{ border-collapse: collapse; }}\ntd, th {{ border: 1px solid #ccc; padding: 0.3em 0.6em; text-align: left; vertical-align: top; }}\ntr.failed, tr.missing {{ background: #f8d0d0; }}\ntr.refused {{ background: #fbe6b8; }}\ntr.published {{ background: #d6ecd2; }}\n</style></head><body>\n<h1>Fleet {name}: night {run_date}</h1>\n<p>{n} robot(s). Failed and missing nights first, then refused candidates (a person should look), then published calibrations. Hold-out errors are the gate's means over the held-out day.</p>\n<table>\n<tr><th>robot</th><th>outcome</th><th>task</th><th>in service, mm</th><th>candidate, mm</th><th>p</th><th>largest change, mm</th><th>why</th></tr>\n{body}</table>\n</body></html>\n",
        name = escape(&fleet.name),
        n = rows.len(),
    )
}
