//! Slurm executor: `egcal fleet submit` writes the night's manifest and one
//! `sbatch --array` per `MaxArraySize` tasks; each task runs `egcal fleet task`,
//! which finds its robots in the manifest by index.
//!
//! A task's index comes from `--index`, else Slurm's `SLURM_ARRAY_TASK_ID`, else
//! Kubernetes' `JOB_COMPLETION_INDEX` (an Indexed Job can run the same command),
//! plus `--index-offset` for arrays after the first. Slurm is driven through its
//! commands (`sbatch`, `squeue`, `scontrol`), as users script it; no accounting
//! database is needed.

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use super::gather::{self, Gathered};
use super::manifest::{ArraySubmission, Manifest};
use super::night::{self, Outcome, night_line};
use super::{Fleet, FleetError};
use crate::exit_code::{self, Finished};
use crate::table::time::date_string;

/// How `fleet submit` submits.
#[derive(Debug, Clone, Copy)]
pub struct SubmitOptions {
    pub run_date: i64,
    /// Tasks at once (`%M`); overrides `[slurm] max_parallel`; 0: no limit.
    pub max_parallel: Option<usize>,
    /// Wait for every task, then gather.
    pub wait: bool,
}

/// What `fleet submit` did.
#[derive(Debug, Clone)]
pub struct Submitted {
    pub manifest: Manifest,
    /// Set when the submission was waited for.
    pub gathered: Option<Gathered>,
}

impl Submitted {
    /// What was submitted, and how to gather it.
    pub fn summary(&self, fleet: &Fleet) -> String {
        let m = &self.manifest;
        let arrays: Vec<String> = m
            .arrays
            .iter()
            .map(|a| {
                format!(
                    "{} (tasks {}..{})",
                    a.job_id,
                    a.first_task,
                    a.first_task + a.tasks - 1
                )
            })
            .collect();
        format!(
            "fleet {}, night {}: {} robot-night(s) in {} task(s) submitted as Slurm job {}\nwhen they are done: egcal fleet gather {} --run-date {}",
            fleet.name,
            m.run_date,
            fleet.robots.len(),
            m.tasks.len(),
            arrays.join(", "),
            fleet.file.display(),
            m.run_date
        )
    }
}

/// Runs a Slurm command; its stdout, or an error naming it and its stderr.
fn slurm_command(program: &str, args: &[String]) -> Result<String, FleetError> {
    let output = Command::new(program).args(args).output().map_err(|e| {
        FleetError::Slurm(format!(
            "cannot run `{program}` ({e}); is Slurm's client installed and SLURM_CONF set?"
        ))
    })?;
    if !output.status.success() {
        return Err(FleetError::Slurm(format!(
            "`{program} {}` failed ({}): {}",
            args.join(" "),
            output.status,
            String::from_utf8_lossy(&output.stderr).trim()
        )));
    }
    Ok(String::from_utf8_lossy(&output.stdout).into_owned())
}

/// The cluster's `MaxArraySize`: array indices must stay below it.
pub fn max_array_size() -> Result<usize, FleetError> {
    let config = slurm_command("scontrol", &["show".into(), "config".into()])?;
    parse_max_array_size(&config)
        .ok_or_else(|| FleetError::Slurm("`scontrol show config` gives no MaxArraySize".into()))
}

fn parse_max_array_size(config: &str) -> Option<usize> {
    config.lines().find_map(|line| {
        let (key, value) = line.split_once('=')?;
        (key.trim() == "MaxArraySize")
            .then(|| value.trim().parse().ok())
            .flatten()
    })
}

/// `text` quoted for a POSIX shell.
fn shell_quote(text: &str) -> String {
    format!("'{}'", text.replace('\'', r"'\''"))
}

/// The batch script every task runs; its one argument is the array's offset.
fn task_script(fleet: &Fleet, run_date: i64, egcal: &Path) -> String {
    format!(
        "#!/bin/sh\n# egcal fleet `{name}`, night {date}: one array task = the robot-nights of\n# manifest.json's task (array index + offset). Written by `egcal fleet submit`.\n# The thread pools keep to the task's cores where no cgroup enforces them.\nexport RAYON_NUM_THREADS=\"${{SLURM_CPUS_PER_TASK:-1}}\" POLARS_MAX_THREADS=\"${{SLURM_CPUS_PER_TASK:-1}}\"\nexec {exe} fleet task {fleet} --run-date {date} --index-offset \"$1\"\n",
        name = fleet.name,
        date = date_string(run_date),
        exe = shell_quote(&egcal.display().to_string()),
        fleet = shell_quote(&fleet.file.display().to_string()),
    )
}

/// The `sbatch` arguments of one array of `tasks` tasks starting at `offset`.
fn sbatch_args(
    fleet: &Fleet,
    run_date: i64,
    script: &Path,
    offset: usize,
    tasks: usize,
    max_parallel: usize,
) -> Vec<String> {
    let night = fleet.night_dir(run_date);
    let settings = &fleet.slurm;
    let mut array = format!("--array=0-{}", tasks - 1);
    if max_parallel > 0 {
        array += &format!("%{max_parallel}");
    }
    let mut args = vec![
        "--parsable".to_string(),
        format!("--job-name=egcal-{}-{}", fleet.name, date_string(run_date)),
        array,
        format!(
            "--output={}",
            night.join("slurm").join("task-%A_%a.out").display()
        ),
        format!("--cpus-per-task={}", settings.cpus_per_task),
        format!(
            "--chdir={}",
            fleet.file.parent().unwrap_or(Path::new("/")).display()
        ),
    ];
    if let Some(partition) = &settings.partition {
        args.push(format!("--partition={partition}"));
    }
    if let Some(time) = &settings.time_limit {
        args.push(format!("--time={time}"));
    }
    if let Some(mem) = &settings.mem {
        args.push(format!("--mem={mem}"));
    }
    args.extend(settings.extra_options.iter().cloned());
    args.push(script.display().to_string());
    args.push(offset.to_string());
    args
}

/// Writes the manifest and submits the night as job arrays.
pub fn submit(fleet: &Fleet, options: &SubmitOptions) -> Result<Submitted, FleetError> {
    let run_date = options.run_date;
    night::check_template(fleet)?;
    let mut manifest = Manifest::new(fleet, run_date, "slurm", fleet.slurm.nights_per_task);
    let max_array = max_array_size()?;
    let slurm_dir = fleet.night_dir(run_date).join("slurm");
    std::fs::create_dir_all(&slurm_dir).map_err(|e| FleetError::io(&slurm_dir, e))?;
    let egcal = std::env::current_exe()
        .map_err(|e| FleetError::Usage(format!("cannot find the egcal binary: {e}")))?;
    let script = slurm_dir.join("task.sh");
    crate::fsio::write_bytes_atomic(&script, task_script(fleet, run_date, &egcal).as_bytes())
        .map_err(|e| FleetError::io(&script, e))?;
    manifest.write(fleet, run_date)?;
    let max_parallel = options.max_parallel.unwrap_or(fleet.slurm.max_parallel);
    let total = manifest.tasks.len();
    let mut first_task = 0;
    while first_task < total {
        let tasks = (total - first_task).min(max_array.max(1));
        let args = sbatch_args(fleet, run_date, &script, first_task, tasks, max_parallel);
        let out = slurm_command("sbatch", &args)?;
        let job_id = out.trim().split(';').next().unwrap_or_default().to_string();
        if job_id.is_empty() {
            return Err(FleetError::Slurm(format!(
                "sbatch printed no job id: `{}`",
                out.trim()
            )));
        }
        manifest.arrays.push(ArraySubmission {
            job_id,
            first_task,
            tasks,
        });
        manifest.write(fleet, run_date)?;
        first_task += tasks;
    }
    let gathered = if options.wait {
        let ids: Vec<&str> = manifest.arrays.iter().map(|a| a.job_id.as_str()).collect();
        wait_for(&ids)?;
        Some(gather::gather(fleet, run_date)?)
    } else {
        None
    };
    Ok(Submitted { manifest, gathered })
}

/// Polls `squeue` until none of the jobs (with all their array tasks) is queued
/// or running.
pub fn wait_for(job_ids: &[&str]) -> Result<(), FleetError> {
    if job_ids.is_empty() {
        return Ok(());
    }
    let args = vec![
        "-h".to_string(),
        "-r".to_string(),
        "-o".to_string(),
        "%i".to_string(),
        "-j".to_string(),
        job_ids.join(","),
    ];
    loop {
        match slurm_command("squeue", &args) {
            Ok(out) if out.trim().is_empty() => return Ok(()),
            Ok(_) => {}
            // Finished jobs drop out of the controller after MinJobAge.
            Err(FleetError::Slurm(message)) if message.contains("Invalid job id") => {
                return Ok(());
            }
            Err(e) => return Err(e),
        }
        std::thread::sleep(Duration::from_millis(500));
    }
}

/// The task index from the flag, Slurm's or Kubernetes' variable.
pub fn task_index(flag: Option<usize>) -> Result<usize, FleetError> {
    if let Some(index) = flag {
        return Ok(index);
    }
    for name in ["SLURM_ARRAY_TASK_ID", "JOB_COMPLETION_INDEX"] {
        if let Ok(text) = std::env::var(name) {
            return text
                .trim()
                .parse()
                .map_err(|_| FleetError::Usage(format!("{name} = `{text}` is not a task index")));
        }
    }
    Err(FleetError::Usage(
        "no task index: pass --index, or run under a Slurm array (SLURM_ARRAY_TASK_ID) or a Kubernetes Indexed Job (JOB_COMPLETION_INDEX)".into(),
    ))
}

/// `egcal fleet task`: the robot-nights of one manifest task, one after the
/// other. Exit 0 when each is recorded as kept, published or refused; 3 when one
/// failed (it is recorded too, and the others still ran).
pub fn task(fleet: &Fleet, run_date: i64, index: usize) -> Result<Finished, FleetError> {
    let manifest = Manifest::read(fleet, run_date)?;
    let robots = manifest.tasks.get(index).ok_or_else(|| {
        FleetError::Usage(format!(
            "task {index} is not in the manifest of night {} ({} task(s))",
            date_string(run_date),
            manifest.tasks.len()
        ))
    })?;
    let cores = std::env::var("SLURM_CPUS_PER_TASK")
        .ok()
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let mut lines = Vec::new();
    let mut failed = Vec::new();
    for robot in robots {
        let record = if night::already_decided(fleet, robot, run_date)? {
            None
        } else {
            Some(night::run_night(
                fleet,
                robot,
                run_date,
                Some(index),
                cores,
            )?)
        };
        if record
            .as_ref()
            .is_some_and(|r| r.outcome == Outcome::Failed)
        {
            failed.push(robot.clone());
        }
        lines.push(night_line(robot, record.as_ref()));
    }
    let mut message = format!(
        "task {index} of fleet `{}`, night {}:\n{}",
        fleet.name,
        date_string(run_date),
        lines.join("\n")
    );
    let code = if failed.is_empty() {
        exit_code::OK
    } else {
        message += &format!("\nfailed: {}", failed.join(", "));
        exit_code::STAGE_FAILED
    };
    Ok(Finished { message, code })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_max_array_size_from_the_config() {
        let config = "MaxArraySize            = 1001\nMaxJobCount = 10000\n";
        assert_eq!(parse_max_array_size(config), Some(1001));
        assert_eq!(parse_max_array_size("MaxJobCount = 3"), None);
    }

    #[test]
    fn quotes_paths_for_the_shell() {
        assert_eq!(shell_quote("/a b/it's"), r"'/a b/it'\''s'");
    }

    #[test]
    fn the_task_script_runs_the_task_with_the_arrays_offset() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("n.toml"), "").unwrap();
        let path = dir.path().join("it's fleet.toml");
        std::fs::write(
            &path,
            "[fleet]\nname = \"p\"\njob = \"n.toml\"\nrobots = [\"a\"]\n[slurm]\ntime_limit = \"00:10:00\"\n",
        )
        .unwrap();
        let fleet = Fleet::load(&path).unwrap();
        let script = task_script(&fleet, 20_000, Path::new("/opt/egcal"));
        let exec = script.lines().last().unwrap();
        assert!(exec.starts_with("exec '/opt/egcal' fleet task '"), "{exec}");
        assert!(exec.contains(r"it'\''s fleet.toml'"), "{exec}");
        assert!(
            exec.ends_with("--run-date 2024-10-04 --index-offset \"$1\""),
            "{exec}"
        );
        let args = sbatch_args(&fleet, 20_000, Path::new("/s/task.sh"), 3, 2, 4);
        assert!(args.contains(&"--array=0-1%4".to_string()), "{args:?}");
        assert!(args.contains(&"--time=00:10:00".to_string()), "{args:?}");
        assert_eq!(
            args[args.len() - 2..],
            ["/s/task.sh".to_string(), "3".to_string()]
        );
    }

    #[test]
    fn the_flag_wins_over_the_environment() {
        assert_eq!(task_index(Some(7)).unwrap(), 7);
    }
}
