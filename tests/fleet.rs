//! A fleet's nights (issue #17): four robots' synthetic logs, the shipped
//! `jobs/nightly.toml` as the template, two nights. `fleet run` must give each
//! robot what `egcal run nightly.toml --var robot_id=…` gives it alone; a Slurm
//! array (`fleet submit` + `gather`) must give what `fleet run` gives; failures and
//! missing records must reach `gather`'s exit code by name.
//!
//! The Slurm test needs a running single-node cluster (`SLURM_CONF`, started by
//! `.ci/services.sh`); where there is none it says so and skips.

mod common;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use egcal::table;
use polars::prelude::*;

const NIGHTS: [&str; 2] = ["2026-11-12", "2026-11-13"];
const ROBOTS: [&str; 4] = ["robot_a", "robot_b", "robot_c", "robot_d"];

/// Logs of four robots for 16 days (2026-10-29 .. 2026-11-13), 30 rows a day;
/// robot_a's joint 2 zero shifts on 2026-11-12, robot_c's second link grows.
const MAKE_LOGS: &str = r#"
[job]
name = "make_logs"
seed = 5
robot = "robots/irb1600_145.toml"
cable_robot = "cdpr/default.toml"

[[stages]]
id = "poses"
kind = "poses"
sampling = "grid"
points_per_axis = 4
centre_mm = [900.0, 0.0, 900.0]
edge_mm = 500.0
acceptance_half_angle_deg = 40.0

[[stages]]
id = "wrenches"
kind = "wrenches"
inputs = { poses = "poses" }
per_config = 5
"#;

fn robot_logs(robot: &str, extra: &str) -> String {
    let short = robot.trim_start_matches("robot_");
    format!(
        r#"
[[stages]]
id = "logs_{short}"
kind = "simulate_logs"
inputs = {{ conf_wrenches = "wrenches", truth = "truth/irb1600_paper.parquet" }}
robot_id = "{robot}"
first_day = "2026-10-29"
days = 16
rows_per_day = 30
{extra}

[[stages]]
id = "commission_{short}"
kind = "identify"
inputs = {{ measurements = "logs_{short}.commissioning" }}
models = ["kinematic", "elastogeometric"]
"#
    )
}

/// `jobs/` with the four robots' logs made once, shared read-only.
fn prepared() -> &'static Path {
    static PREPARED: OnceLock<PathBuf> = OnceLock::new();
    PREPARED
        .get_or_init(|| {
            let dir = common::shared_dir("fleet_prepared");
            common::copy_dir(&common::root().join("jobs"), &dir, &["out", "calibration"]);
            let mut text = MAKE_LOGS.to_string();
            text += &robot_logs(
                "robot_a",
                r#"steps = [{ parameter = "dtheta2", date = "2026-11-12", change = 0.02 }]"#,
            );
            text += &robot_logs("robot_b", "offsets = { dtheta3 = 0.015, da3 = 0.12 }");
            text += &robot_logs(
                "robot_c",
                r#"drifts = [{ parameter = "da2", per_day = 0.004 }]"#,
            );
            text += &robot_logs("robot_d", "");
            std::fs::write(dir.join("make_logs.toml"), text).unwrap();
            let (code, stdout, stderr) = common::run(&["-q", "run", "make_logs.toml"], &dir);
            assert_eq!(code, 0, "make_logs: {stdout}{stderr}");
            dir
        })
        .as_path()
}

/// A fresh cell: the prepared logs, each robot's commissioning calibration in
/// service, and a fleet file over the four robots.
fn cell() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    common::copy_dir(prepared(), dir.path(), &[]);
    for robot in ROBOTS {
        let short = robot.trim_start_matches("robot_");
        let (code, stdout, stderr) = common::run(
            &[
                "publish",
                &format!("out/make_logs/commission_{short}/parameters.parquet"),
                "--to",
                &format!("calibration/{robot}"),
                "--date",
                "2026-10-28",
            ],
            dir.path(),
        );
        assert_eq!(code, 0, "{stdout}{stderr}");
    }
    std::fs::write(
        dir.path().join("cell.toml"),
        r#"
[fleet]
name = "cell"
job = "nightly.toml"
robots_from_logs = "out/make_logs"

[slurm]
nights_per_task = 3
"#,
    )
    .unwrap();
    dir
}

/// The night's decisions without what depends on where and how it ran.
fn decisions(dir: &Path, night: &str) -> DataFrame {
    let path = dir.join(format!("out/cell/nights/{night}/decisions.parquet"));
    let df = table::read_checked(&path, &table::schema::fleet_decisions()).unwrap();
    let root = dir.display().to_string();
    let reasons: Vec<Option<String>> = df
        .column("reasons")
        .unwrap()
        .str()
        .unwrap()
        .iter()
        .map(|r| r.map(|r| r.replace(&root, "<cell>")))
        .collect();
    df.select([
        "robot_id",
        "outcome",
        "exit_code",
        "gate_decision",
        "holdout_rows",
        "in_service_mean_mm",
        "candidate_mean_mm",
        "p_value",
        "max_position_change_mm",
    ])
    .unwrap()
    .hstack(&[Column::new("reasons".into(), reasons)])
    .unwrap()
}

/// The two cells' decisions of `night` agree, column by column.
fn assert_same_decisions(dir: &Path, expected_dir: &Path, night: &str) {
    let (got, expected) = (decisions(dir, night), decisions(expected_dir, night));
    for column in expected.get_column_names() {
        let values = |df: &DataFrame| {
            let series = df.column(column).unwrap().as_materialized_series().clone();
            (0..series.len())
                .map(|i| series.get(i).unwrap().to_string())
                .collect::<Vec<_>>()
        };
        assert_eq!(values(&got), values(&expected), "{night}: column {column}");
    }
}

/// Content hash of each robot's calibration in service.
fn in_service(dir: &Path) -> Vec<String> {
    ROBOTS
        .iter()
        .map(|robot| {
            let path = dir.join(format!("calibration/{robot}/current.parquet"));
            table::content_hash(&table::read_parquet(&path).unwrap())
        })
        .collect()
}

/// The array task of each robot's night, from the gathered table.
fn task_indexes(dir: &Path, night: &str) -> Vec<Option<i64>> {
    let path = dir.join(format!("out/cell/nights/{night}/decisions.parquet"));
    table::read_parquet(&path)
        .unwrap()
        .column("task_index")
        .unwrap()
        .i64()
        .unwrap()
        .iter()
        .collect()
}

fn outcomes(df: &DataFrame) -> Vec<String> {
    df.column("outcome")
        .unwrap()
        .str()
        .unwrap()
        .iter()
        .map(|o| o.unwrap().to_string())
        .collect()
}

#[test]
fn fleet_run_gives_each_robot_what_its_own_run_gives() {
    let fleet = cell();
    let alone = cell();
    for night in NIGHTS {
        let (code, stdout, stderr) = common::run(
            &[
                "fleet",
                "run",
                "cell.toml",
                "--run-date",
                night,
                "--jobs",
                "2",
            ],
            fleet.path(),
        );
        let gathered = decisions(fleet.path(), night);
        let mut expected_code = 0;
        for (i, robot) in ROBOTS.iter().enumerate() {
            let (own, out, err) = common::run(
                &[
                    "-q",
                    "run",
                    "nightly.toml",
                    "--run-date",
                    night,
                    "--var",
                    &format!("robot_id={robot}"),
                ],
                alone.path(),
            );
            assert!([0, 10, 11].contains(&own), "{robot} {night}: {out}{err}");
            expected_code = expected_code.max(own);
            let row = gathered.slice(i as i64, 1);
            assert_eq!(
                row.column("robot_id").unwrap().str().unwrap().get(0),
                Some(*robot)
            );
            assert_eq!(
                row.column("exit_code").unwrap().i64().unwrap().get(0),
                Some(own as i64),
                "{robot} {night}"
            );
            let gate_dir = alone.path().join(format!("out/nightly_{robot}/gate"));
            let own_decision = table::read_parquet(&gate_dir.join("decision.parquet")).unwrap();
            for column in ["in_service_mean_mm", "candidate_mean_mm", "p_value"] {
                assert_eq!(
                    row.column(column).unwrap().f64().unwrap().get(0),
                    own_decision.column(column).unwrap().f64().unwrap().get(0),
                    "{robot} {night} {column}"
                );
            }
        }
        assert_eq!(code, expected_code, "{night}: {stdout}{stderr}");
    }
    assert_eq!(in_service(fleet.path()), in_service(alone.path()));
    // The collision on 2026-11-12 is caught on the 13th, when the held-out day
    // follows it.
    let last = decisions(fleet.path(), NIGHTS[1]);
    assert_eq!(outcomes(&last)[0], "published", "{last}");
    assert_eq!(outcomes(&last)[3], "kept", "{last}");
}

#[test]
fn a_decided_night_is_not_run_again() {
    let fleet = cell();
    let night = NIGHTS[1];
    let (code, _, stderr) = common::run(
        &["fleet", "run", "cell.toml", "--run-date", night],
        fleet.path(),
    );
    assert_eq!(code, 10, "{stderr}");
    let before = in_service(fleet.path());
    let (code, _, stderr) = common::run(
        &["fleet", "run", "cell.toml", "--run-date", night],
        fleet.path(),
    );
    assert_eq!(code, 10, "the same decisions: {stderr}");
    assert_eq!(stderr.matches("decided earlier").count(), 4, "{stderr}");
    assert_eq!(in_service(fleet.path()), before);
}

#[test]
fn a_fleet_run_killed_mid_night_finishes_on_the_next_run_with_the_same_decisions() {
    let clean = cell();
    let killed = cell();
    let night = NIGHTS[1];
    let (clean_code, _, stderr) = common::run(
        &["fleet", "run", "cell.toml", "--run-date", night],
        clean.path(),
    );
    assert_eq!(clean_code, 10, "{stderr}");
    let results = killed
        .path()
        .join(format!("out/cell/nights/{night}/results"));
    let mut child = common::egcal()
        .args(["-q", "fleet", "run", "cell.toml", "--run-date", night])
        .current_dir(killed.path())
        .spawn()
        .unwrap();
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
    while std::fs::read_dir(&results).map_or(0, |d| d.count()) == 0
        && std::time::Instant::now() < deadline
    {
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    let recorded = std::fs::read_dir(&results).unwrap().count();
    eprintln!("killed after {recorded} of 4 nights were recorded");
    let (code, stdout, stderr) = common::run(
        &["fleet", "run", "cell.toml", "--run-date", night],
        killed.path(),
    );
    assert_eq!(code, clean_code, "{stdout}{stderr}");
    assert_same_decisions(killed.path(), clean.path(), night);
    assert_eq!(in_service(killed.path()), in_service(clean.path()));
}

#[test]
fn a_failed_or_missing_night_makes_gather_exit_3_and_names_it() {
    let fleet = cell();
    let night = NIGHTS[0];
    // robot_d's calibration in service disappears: its night fails, the others run.
    std::fs::remove_file(fleet.path().join("calibration/robot_d/current.parquet")).unwrap();
    let (code, stdout, stderr) = common::run(
        &["fleet", "run", "cell.toml", "--run-date", night],
        fleet.path(),
    );
    assert_eq!(code, 3, "{stdout}{stderr}");
    assert!(stdout.contains("robot_d: failed"), "{stdout}");
    assert!(
        stdout.contains("3 kept") || stdout.contains("published"),
        "{stdout}"
    );
    let df = decisions(fleet.path(), night);
    assert_eq!(outcomes(&df)[3], "failed");

    // A record lost (a task killed before writing it): missing, named, exit 3.
    let results = fleet
        .path()
        .join(format!("out/cell/nights/{night}/results"));
    std::fs::remove_file(results.join("robot_b.json")).unwrap();
    let (code, stdout, _) = common::run(
        &["fleet", "gather", "cell.toml", "--run-date", night],
        fleet.path(),
    );
    assert_eq!(code, 3);
    assert!(stdout.contains("robot_b: missing"), "{stdout}");

    // Fixed and run again: only the failed and missing nights run.
    std::fs::copy(
        fleet.path().join("calibration/robot_c/current.parquet"),
        fleet.path().join("calibration/robot_d/current.parquet"),
    )
    .unwrap();
    let (code, stdout, stderr) = common::run(
        &["fleet", "run", "cell.toml", "--run-date", night],
        fleet.path(),
    );
    assert!([0, 10, 11].contains(&code), "{stdout}{stderr}");
    assert_eq!(stderr.matches("decided earlier").count(), 2, "{stderr}");
}

#[test]
fn tasks_find_their_robots_by_index_from_the_flag_or_the_schedulers_variable() {
    let fleet = cell();
    let night = NIGHTS[0];
    let dir = fleet.path();
    // A manifest as `fleet submit` writes it, without a scheduler.
    let loaded = egcal::fleet::Fleet::load(&dir.join("cell.toml")).unwrap();
    let day = egcal::table::time::parse_date(night).unwrap();
    egcal::fleet::manifest::Manifest::new(&loaded, day, "slurm", 3)
        .write(&loaded, day)
        .unwrap();
    let task = |env: &[(&str, &str)], extra: &[&str]| {
        let mut command = common::egcal();
        command
            .args(["fleet", "task", "cell.toml", "--run-date", night])
            .args(extra)
            .current_dir(dir)
            .env_remove("SLURM_ARRAY_TASK_ID")
            .env_remove("JOB_COMPLETION_INDEX");
        for (k, v) in env {
            command.env(k, v);
        }
        let out = command.output().unwrap();
        (
            out.status.code().unwrap_or(-1),
            String::from_utf8_lossy(&out.stdout).into_owned(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let (code, stdout, stderr) = task(&[("SLURM_ARRAY_TASK_ID", "1")], &[]);
    assert_eq!(code, 0, "{stdout}{stderr}");
    assert!(
        stdout.contains("robot_d") && !stdout.contains("robot_a"),
        "{stdout}"
    );
    let (code, stdout, stderr) = task(&[("JOB_COMPLETION_INDEX", "0")], &[]);
    assert_eq!(
        code, 0,
        "published and refused are results: {stdout}{stderr}"
    );
    assert!(
        stdout.contains("robot_a") && stdout.contains("robot_c"),
        "{stdout}"
    );
    let (code, _, stderr) = task(&[], &["--index", "1", "--index-offset", "1"]);
    assert_eq!(code, 2);
    assert!(stderr.contains("task 2 is not in the manifest"), "{stderr}");
    let (code, _, stderr) = task(&[], &[]);
    assert_eq!(code, 2);
    assert!(stderr.contains("no task index"), "{stderr}");
    let (code, _, stderr) = task(&[("SLURM_ARRAY_TASK_ID", "x")], &[]);
    assert_eq!(code, 2);
    assert!(stderr.contains("SLURM_ARRAY_TASK_ID"), "{stderr}");
    let (code, stdout, _) =
        common::run(&["fleet", "gather", "cell.toml", "--run-date", night], dir);
    assert!([0, 10, 11].contains(&code), "{stdout}");
    let df = decisions(dir, night);
    assert_eq!(
        task_indexes(dir, night),
        [Some(0), Some(0), Some(0), Some(1)],
        "{df}"
    );
}

#[test]
fn bad_fleet_files_name_the_file_and_key() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("nightly.toml"), "").unwrap();
    let cases = [
        (
            "[fleet]\nname = \"c\"\njob = \"nightly.toml\"\nrobots = [\"a b\"]\n",
            "fleet.robots[0]",
        ),
        (
            "[fleet]\nname = \"c\"\njob = \"missing.toml\"\nrobots = [\"a\"]\n",
            "fleet.job",
        ),
        (
            "[fleet]\nname = \"c\"\njob = \"nightly.toml\"\nrobots = [\"a\"]\n[slurm]\ncpus = 2\n",
            "unknown field `cpus`",
        ),
        (
            "[fleet]\nname = \"c\"\njob = \"nightly.toml\"\nrobots_from_logs = \"nowhere\"\n",
            "robots_from_logs",
        ),
        ("[fleet\n", "invalid TOML"),
    ];
    for (text, expected) in cases {
        std::fs::write(dir.path().join("f.toml"), text).unwrap();
        let (code, _, stderr) = common::run(&["fleet", "run", "f.toml"], dir.path());
        assert_eq!(code, 2, "{text}: {stderr}");
        assert!(
            stderr.contains("f.toml") && stderr.contains(expected),
            "{text}: {stderr}"
        );
    }
    // A template without {robot_id} would run the same night for every robot.
    std::fs::write(
        dir.path().join("f.toml"),
        "[fleet]\nname = \"c\"\njob = \"plain.toml\"\nrobots = [\"a\"]\n",
    )
    .unwrap();
    std::fs::copy(
        common::root().join("jobs/paper_sim.toml"),
        dir.path().join("plain.toml"),
    )
    .unwrap();
    let (code, _, stderr) = common::run(&["fleet", "run", "f.toml"], dir.path());
    assert_eq!(code, 2, "refused before any night runs: {stderr}");
    assert!(
        stderr.contains("fails for every robot") && stderr.contains("uses no `{robot_id}`"),
        "{stderr}"
    );
}

/// The guide's fleet commands (docs/fleet.md) on the shipped files: jobs/fleet.toml over the logs
/// of jobs/make_logs.toml.
#[test]
fn the_shipped_fleet_runs_on_the_shipped_logs() {
    let dir = tempfile::tempdir().unwrap();
    common::copy_dir(
        &common::root().join("jobs"),
        dir.path(),
        &["out", "calibration"],
    );
    let run = |args: &[&str]| {
        let (code, stdout, stderr) = common::run(args, dir.path());
        (code, format!("{stdout}{stderr}"))
    };
    assert_eq!(run(&["-q", "run", "make_logs.toml"]).0, 0);
    for robot in ["a", "b"] {
        let (code, out) = run(&[
            "publish",
            &format!("out/make_logs/commission_{robot}/parameters.parquet"),
            "--to",
            &format!("calibration/robot_{robot}"),
            "--date",
            "2026-10-21",
        ]);
        assert_eq!(code, 0, "{out}");
    }
    let (code, out) = run(&["fleet", "run", "fleet.toml", "--run-date", "2026-11-12"]);
    assert_eq!(code, 0, "{out}");
    assert!(out.contains("2 robot(s): 0 published, 2 kept"), "{out}");
    // A task of a night as a Slurm array task runs it (here without Slurm).
    let loaded = egcal::fleet::Fleet::load(&dir.path().join("fleet.toml")).unwrap();
    let day = egcal::table::time::parse_date("2026-11-13").unwrap();
    egcal::fleet::manifest::Manifest::new(&loaded, day, "slurm", loaded.slurm.nights_per_task)
        .write(&loaded, day)
        .unwrap();
    let (code, out) = run(&[
        "fleet",
        "task",
        "fleet.toml",
        "--run-date",
        "2026-11-13",
        "--index",
        "0",
    ]);
    assert_eq!(code, 0, "{out}");
    let (code, out) = run(&["fleet", "gather", "fleet.toml", "--run-date", "2026-11-13"]);
    assert_eq!(code, 10, "robot_a's collision is caught: {out}");
    assert!(out.contains("1 published, 1 kept"), "{out}");
    let page = std::fs::read_to_string(
        dir.path()
            .join("out/fleet/nights/2026-11-13/fleet_report.html"),
    )
    .unwrap();
    assert!(
        page.contains("<tr class=\"published\"><td>robot_a"),
        "{page}"
    );
}

/// The Slurm cluster of `.ci/services.sh`, if one is running.
fn slurm_available() -> bool {
    if std::env::var_os("SLURM_CONF").is_none() {
        common::skip_without_service("no Slurm cluster (SLURM_CONF unset)");
        return false;
    }
    let up = std::process::Command::new("sinfo")
        .args(["-h", "-o", "%T"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !up {
        common::skip_without_service("SLURM_CONF is set but `sinfo` does not answer");
    }
    up
}

#[test]
fn a_slurm_array_gives_what_fleet_run_gives() {
    if !slurm_available() {
        return;
    }
    let local = cell();
    let slurm = cell();
    for night in NIGHTS {
        let (local_code, stdout, stderr) = common::run(
            &["fleet", "run", "cell.toml", "--run-date", night],
            local.path(),
        );
        assert!([0, 10, 11].contains(&local_code), "{stdout}{stderr}");
        let (code, stdout, stderr) = common::run(
            &[
                "fleet",
                "submit",
                "cell.toml",
                "--run-date",
                night,
                "--max-parallel",
                "2",
            ],
            slurm.path(),
        );
        assert_eq!(code, 0, "{stdout}{stderr}");
        assert!(
            stdout.contains("in 2 task(s) submitted as Slurm job"),
            "{stdout}"
        );
        let manifest: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(
                slurm
                    .path()
                    .join(format!("out/cell/nights/{night}/manifest.json")),
            )
            .unwrap(),
        )
        .unwrap();
        let job_id = manifest["arrays"][0]["job_id"]
            .as_str()
            .unwrap()
            .to_string();
        egcal::fleet::slurm::wait_for(&[&job_id]).unwrap();
        let (code, stdout, stderr) = common::run(
            &["fleet", "gather", "cell.toml", "--run-date", night],
            slurm.path(),
        );
        assert_eq!(code, local_code, "{night}: {stdout}{stderr}");
        assert_same_decisions(slurm.path(), local.path(), night);
        let logs = slurm.path().join(format!("out/cell/nights/{night}/slurm"));
        let task_logs = std::fs::read_dir(&logs)
            .unwrap()
            .filter(|e| {
                e.as_ref()
                    .is_ok_and(|e| e.file_name().to_string_lossy().starts_with("task-"))
            })
            .count();
        assert_eq!(task_logs, 2, "one log per array task");
    }
    assert_eq!(in_service(slurm.path()), in_service(local.path()));
}

#[test]
fn a_night_beyond_max_array_size_is_split_into_arrays_with_offsets() {
    if !slurm_available() {
        return;
    }
    let max = egcal::fleet::slurm::max_array_size().unwrap();
    let dir = cell();
    // One night per task: four tasks (CI's cluster has MaxArraySize = 3).
    let text = std::fs::read_to_string(dir.path().join("cell.toml"))
        .unwrap()
        .replace("nights_per_task = 3", "nights_per_task = 1");
    std::fs::write(dir.path().join("cell.toml"), text).unwrap();
    let night = NIGHTS[1];
    let (code, stdout, stderr) = common::run(
        &[
            "fleet",
            "submit",
            "cell.toml",
            "--run-date",
            night,
            "--wait",
        ],
        dir.path(),
    );
    assert_eq!(code, 10, "gathered after waiting: {stdout}{stderr}");
    let manifest: egcal::fleet::manifest::Manifest = serde_json::from_str(
        &std::fs::read_to_string(
            dir.path()
                .join(format!("out/cell/nights/{night}/manifest.json")),
        )
        .unwrap(),
    )
    .unwrap();
    assert_eq!(manifest.arrays.len(), 4usize.div_ceil(max), "{manifest:?}");
    let offsets: Vec<usize> = manifest.arrays.iter().map(|a| a.first_task).collect();
    assert_eq!(offsets, (0..4).step_by(max).collect::<Vec<_>>());
    assert_eq!(
        task_indexes(dir.path(), night),
        [Some(0), Some(1), Some(2), Some(3)]
    );
}
