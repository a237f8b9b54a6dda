//! The nightly re-calibration end to end, on the synthetic logs of
//! `jobs/make_logs.toml`: robot_a's joint 2 zero shifts by 0.02 deg on 2026-11-12
//! (and its second link grows 3 µm a day); robot_b is stable.
//!
//! The shipped jobs run unchanged from a copy of `jobs/` (their paths are
//! relative), once per test, after `make_logs` and the installation of each
//! robot's commissioning calibration.

mod common;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use egcal::table::{self, schema};

const PUBLISHED: i32 = 10;
const REFUSED: i32 = 11;

/// A copy of `jobs/` with make_logs run once, shared read-only by the tests.
fn prepared() -> &'static Path {
    static PREPARED: OnceLock<PathBuf> = OnceLock::new();
    PREPARED
        .get_or_init(|| {
            let dir = common::shared_dir("nightly_prepared");
            common::copy_dir(&common::root().join("jobs"), &dir, &["out", "calibration"]);
            let (code, stdout, stderr) = common::run(&["-q", "run", "make_logs.toml"], &dir);
            assert_eq!(code, 0, "make_logs: {stdout}{stderr}");
            dir
        })
        .as_path()
}

/// A fresh cell folder: the prepared jobs and logs, and `robot`'s commissioning
/// calibration in service; plus the nightly job for `robot`.
fn cell(robot: &str) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    common::copy_dir(prepared(), dir.path(), &[]);
    let suffix = robot.trim_start_matches("robot_");
    let commissioning = format!("out/make_logs/commission_{suffix}/parameters.parquet");
    let (code, stdout, stderr) = common::run(
        &[
            "publish",
            &commissioning,
            "--to",
            &format!("calibration/{robot}"),
            "--date",
            "2026-10-21",
        ],
        dir.path(),
    );
    assert_eq!(code, 0, "{stdout}{stderr}");
    let text = std::fs::read_to_string(dir.path().join("nightly.toml"))
        .unwrap()
        .replace("robot_a", robot);
    let job = dir.path().join(format!("nightly_{robot}.toml"));
    std::fs::write(&job, text).unwrap();
    (dir, job)
}

fn nightly(dir: &Path, job: &Path, run_date: &str) -> (i32, String, String) {
    common::run(
        &["-q", "run", job.to_str().unwrap(), "--run-date", run_date],
        dir,
    )
}

/// The gate's decision row: decision, drift_since, reasons.
fn decision(dir: &Path, robot: &str) -> (String, Option<String>, String) {
    let path = dir.join(format!("out/nightly_{robot}/gate/decision.parquet"));
    let df = table::read_parquet(&path).unwrap();
    let text = |c: &str| schema::str_values(&df, c, &path).unwrap()[0].clone();
    (
        text("decision").unwrap(),
        text("drift_since"),
        text("reasons").unwrap(),
    )
}

#[test]
fn the_collision_day_is_detected_and_the_next_night_publishes() {
    let (dir, job) = cell("robot_a");
    let (code, stdout, stderr) = common::run(&["check", job.to_str().unwrap()], dir.path());
    assert_eq!(
        code, 0,
        "the shipped nightly job checks clean: {stdout}{stderr}"
    );
    let current = dir.path().join("calibration/robot_a/current.parquet");
    let commissioning = std::fs::read(&current).unwrap();

    // On the day of the collision the hold-out day shows it, but the candidate
    // was identified on the days before: no better, so the old set stays.
    let (code, stdout, stderr) = nightly(dir.path(), &job, "2026-11-12");
    assert_eq!(code, 0, "{stdout}{stderr}");
    let (kept, drift_since, reasons) = decision(dir.path(), "robot_a");
    assert_eq!(kept, "kept", "{reasons}");
    assert_eq!(drift_since.as_deref(), Some("2026-11-12"), "{reasons}");
    assert_eq!(std::fs::read(&current).unwrap(), commissioning);

    // The next night has a day of post-collision rows to learn from.
    let (code, stdout, stderr) = nightly(dir.path(), &job, "2026-11-13");
    assert_eq!(code, PUBLISHED, "{stdout}{stderr}");
    assert!(stdout.contains("gate: published"), "{stdout}");
    let (published, drift_since, reasons) = decision(dir.path(), "robot_a");
    assert_eq!(published, "published", "{reasons}");
    assert_eq!(drift_since.as_deref(), Some("2026-11-12"), "{reasons}");
    assert!(reasons.contains("significantly better"), "{reasons}");
    let candidate = std::fs::read(
        dir.path()
            .join("out/nightly_robot_a/identify/parameters.parquet"),
    )
    .unwrap();
    assert_eq!(std::fs::read(&current).unwrap(), candidate);
    let retired = dir
        .path()
        .join("calibration/robot_a/retired-2026-11-13.parquet");
    assert_eq!(std::fs::read(retired).unwrap(), commissioning);

    // Re-running the same night (a replay, or a run killed after it published)
    // decides again against the set the night replaced: the same decision, and
    // nothing installed twice.
    let (code, stdout, _) = nightly(dir.path(), &job, "2026-11-13");
    assert_eq!(code, PUBLISHED, "{stdout}");
    assert_eq!(decision(dir.path(), "robot_a").2, reasons);
    assert_eq!(std::fs::read(&current).unwrap(), candidate);
    assert!(
        !dir.path()
            .join("calibration/robot_a/retired-2026-11-13-2.parquet")
            .exists()
    );

    // A week later most of the window is after the collision: the night's set
    // differs from the one in service most in joint 2's zero, far beyond its
    // standard error.
    let (code, stdout, stderr) = nightly(dir.path(), &job, "2026-11-20");
    assert_eq!(code, PUBLISHED, "{stdout}{stderr}");
    let path = dir
        .path()
        .join("out/nightly_robot_a/gate/parameter_changes.parquet");
    let changes = table::read_parquet(&path).unwrap();
    let names = schema::str_values(&changes, "name", &path).unwrap();
    let z = schema::f64_values(&changes, "z", &path).unwrap();
    let largest = (0..z.len())
        .max_by(|&a, &b| z[a].abs().total_cmp(&z[b].abs()))
        .unwrap();
    assert_eq!(names[largest].as_deref(), Some("dtheta2"), "z = {z:?}");
    assert!(z[largest].abs() > 3.0, "z = {}", z[largest]);
    assert!(
        dir.path()
            .join("calibration/robot_a/retired-2026-11-20.parquet")
            .exists()
    );
}

#[test]
fn a_stable_robot_keeps_its_calibration() {
    let (dir, job) = cell("robot_b");
    let current = dir.path().join("calibration/robot_b/current.parquet");
    let before = std::fs::read(&current).unwrap();
    let (code, stdout, stderr) = nightly(dir.path(), &job, "2026-11-20");
    assert_eq!(code, 0, "{stdout}{stderr}");
    let (kept, drift_since, reasons) = decision(dir.path(), "robot_b");
    assert_eq!(kept, "kept", "{reasons}");
    assert_eq!(drift_since, None, "{reasons}");
    assert_eq!(std::fs::read(&current).unwrap(), before);
    let retired = std::fs::read_dir(dir.path().join("calibration/robot_b"))
        .unwrap()
        .count();
    assert_eq!(retired, 1, "only current.parquet");
}

#[test]
fn a_calibration_for_another_robot_is_refused() {
    // robot_b's calibration offered as robot_a's candidate: much worse on
    // robot_a's hold-out, so the gate refuses it whatever the drift.
    let (dir, job) = cell("robot_a");
    let (code, stdout, stderr) = nightly(dir.path(), &job, "2026-11-08");
    assert_eq!(code, 0, "{stdout}{stderr}");
    let out = dir.path().join("out/nightly_robot_a");
    let inputs = [
        format!(
            "measurements={}",
            out.join("logs/measurements.parquet").display()
        ),
        format!("selection={}", out.join("logs/selection.parquet").display()),
        format!(
            "candidate={}",
            dir.path()
                .join("out/make_logs/commission_b/parameters.parquet")
                .display()
        ),
        format!(
            "in_service={}",
            dir.path()
                .join("calibration/robot_a/current.parquet")
                .display()
        ),
    ];
    let settings = dir.path().join("gate.toml");
    std::fs::write(&settings, "publish_dir = \"calibration/robot_a\"\n").unwrap();
    let gate_out = dir.path().join("gate");
    let mut args = vec![
        "stage",
        "gate",
        "--robot",
        "robots/irb1600_145.toml",
        "--settings",
        settings.to_str().unwrap(),
        "--out",
        gate_out.to_str().unwrap(),
    ];
    for input in &inputs {
        args.extend(["--input", input.as_str()]);
    }
    let before = std::fs::read(dir.path().join("calibration/robot_a/current.parquet")).unwrap();
    let (code, stdout, stderr) = common::run(&args, dir.path());
    assert_eq!(code, REFUSED, "{stdout}{stderr}");
    let summary = std::fs::read_to_string(gate_out.join("decision.md")).unwrap();
    assert!(
        summary.starts_with("# Calibration gate: refused"),
        "{summary}"
    );
    assert!(summary.contains("significantly worse"), "{summary}");
    assert_eq!(
        std::fs::read(dir.path().join("calibration/robot_a/current.parquet")).unwrap(),
        before
    );
}

#[test]
fn thin_windows_other_robots_and_corrupt_logs_fail_clearly() {
    let (dir, job) = cell("robot_a");

    // Two logged days: 50 identification rows, fewer than the job's min_rows.
    let (code, _, stderr) = nightly(dir.path(), &job, "2026-10-23");
    assert_eq!(code, 3, "{stderr}");
    assert!(
        stderr.contains("stage `logs`") && stderr.contains("fewer than min_rows = 200"),
        "{stderr}"
    );

    // A robot the logs do not hold: the message names the ones they do.
    let text = std::fs::read_to_string(&job)
        .unwrap()
        .replace("robot_id = \"{robot_id}\"", "robot_id = \"robot_c\"");
    let other = dir.path().join("nightly_robot_c.toml");
    std::fs::write(&other, text).unwrap();
    let (code, _, stderr) = nightly(dir.path(), &other, "2026-11-20");
    assert_eq!(code, 3, "{stderr}");
    assert!(
        stderr.contains("robot_c") && stderr.contains("robot_a") && stderr.contains("robot_b"),
        "{stderr}"
    );

    // A truncated log file in the window: named and skipped by default ...
    let corrupt = dir
        .path()
        .join("out/make_logs/logs_a/robot_id=robot_a/date=2026-11-05/part-1.parquet");
    std::fs::write(&corrupt, b"PAR1 truncated").unwrap();
    let (code, stdout, stderr) = nightly(dir.path(), &job, "2026-11-08");
    assert_eq!(code, 0, "{stdout}{stderr}");
    let provenance = table::read_provenance(
        &dir.path()
            .join("out/nightly_robot_a/logs/measurements.parquet"),
    )
    .unwrap()
    .unwrap();
    let facts = serde_json::to_string(&provenance.extra).unwrap();
    assert!(facts.contains("part-1.parquet"), "{facts}");

    // ... and fatal with bad_data = "fail".
    let strict = std::fs::read_to_string(&job)
        .unwrap()
        .replace("min_rows = 200", "min_rows = 200\nbad_data = \"fail\"");
    std::fs::write(&job, strict).unwrap();
    let (code, _, stderr) = nightly(dir.path(), &job, "2026-11-08");
    assert_eq!(code, 3, "{stderr}");
    assert!(
        stderr.contains("part-1.parquet") && stderr.contains("not a readable Parquet file"),
        "{stderr}"
    );
}
