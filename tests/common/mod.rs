//! Shared helpers for the integration tests: the built binary, the repository's
//! files, and a temporary folder per test.

#![allow(dead_code)] // each test binary uses a different subset

pub mod measured;
pub mod sample;
pub mod tables;
pub mod targets;
pub mod ur10;
pub mod urdf;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The repository root.
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The `egcal` binary built for this test run.
pub fn egcal() -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_egcal"));
    command.env("NO_COLOR", "1");
    command
}

/// A fresh folder for data a test binary prepares once and shares between its
/// tests: `target/tmp/<name>`, emptied on first use. A static `TempDir` would
/// never be dropped and would leave its folder in the system's /tmp after each
/// run; this one is replaced by the next run instead.
pub fn shared_dir(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    if dir.exists() {
        std::fs::remove_dir_all(&dir).expect("remove the previous run's shared folder");
    }
    std::fs::create_dir_all(&dir).expect("create the shared folder");
    dir
}

/// Runs egcal with arguments; returns (exit code, stdout, stderr).
pub fn run(args: &[&str], dir: &Path) -> (i32, String, String) {
    let Output {
        status,
        stdout,
        stderr,
    } = egcal()
        .args(args)
        .current_dir(dir)
        .output()
        .expect("egcal runs");
    (
        status.code().unwrap_or(-1),
        String::from_utf8_lossy(&stdout).into_owned(),
        String::from_utf8_lossy(&stderr).into_owned(),
    )
}

/// Runs `egcal stage <kind>` for the robot file `robot` with `settings` (written
/// to `dir/<kind>.toml`) and `inputs` (name, path) into `dir/out_<kind>`,
/// which a second run finds as the first left it (a campaign resumes
/// there); returns (exit code, stdout and stderr, output folder).
pub fn stage(
    dir: &Path,
    robot: &Path,
    kind: &str,
    settings: &str,
    inputs: &[(&str, &Path)],
) -> (i32, String, PathBuf) {
    let settings_path = dir.join(format!("{kind}.toml"));
    std::fs::write(&settings_path, settings).expect("write the settings");
    let out = dir.join(format!("out_{kind}"));
    let mut args: Vec<String> = ["stage", kind, "--robot"].map(String::from).to_vec();
    args.push(robot.display().to_string());
    args.extend(["--settings".into(), settings_path.display().to_string()]);
    args.extend(["--out".into(), out.display().to_string()]);
    for (name, path) in inputs {
        args.extend(["--input".into(), format!("{name}={}", path.display())]);
    }
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let (code, stdout, stderr) = run(&args, dir);
    (code, format!("{stdout}{stderr}"), out)
}

/// A small but complete campaign: 8 poses, 3 wrenches each, measured in the
/// simulator, identified and validated; plus an independent `predict` stage.
/// `extra` is appended to the file (more stages, or overrides).
pub fn small_job(dir: &Path, wrenches_per_config: usize, extra: &str) -> PathBuf {
    let root = root();
    let text = format!(
        r#"[job]
name = "small"
seed = 7
robot = "{robot}"
cable_robot = "{cable}"
output = "out"

[[stages]]
id = "poses"
kind = "poses"
points_per_axis = 2
edge_mm = 300.0

[[stages]]
id = "wrenches"
kind = "wrenches"
inputs = {{ poses = "poses" }}
per_config = {wrenches_per_config}

[[stages]]
id = "measure"
kind = "measure"
inputs = {{ conf_wrenches = "wrenches", truth = "{truth}" }}

[[stages]]
id = "identify"
kind = "identify"
inputs = {{ measurements = "measure.measurements" }}
models = ["nominal", "registered"]

[[stages]]
id = "predict_nominal"
kind = "predict"
inputs = {{ conf_wrenches = "{fixture}" }}
{extra}"#,
        robot = root.join("jobs/robots/irb1600_145.toml").display(),
        cable = root.join("jobs/cdpr/default.toml").display(),
        truth = root.join("jobs/truth/irb1600_paper.parquet").display(),
        fixture = root
            .join("fixtures/predict/nominal/conf_wrenches.parquet")
            .display(),
    );
    let path = dir.join("job.toml");
    std::fs::write(&path, text).expect("write job");
    path
}

/// A job measuring the fixture's conf-wrench rows with the given measure settings.
/// The shipped job `jobs/<name>.toml`, its text changed by `edit`, written
/// into `dir` with its relative paths (robot, cable robot, truth, targets)
/// made absolute, so it runs from there; the job file's path.
pub fn shipped_job_in(dir: &Path, name: &str, edit: impl Fn(String) -> String) -> PathBuf {
    let jobs = root().join("jobs");
    let text = std::fs::read_to_string(jobs.join(format!("{name}.toml"))).expect("shipped job");
    let text = ["robots/", "cdpr/", "truth/", "targets/", "campaigns/"]
        .iter()
        .fold(text, |text, folder| {
            text.replace(
                &format!("\"{folder}"),
                &format!("\"{}/{folder}", jobs.display()),
            )
        });
    let job = dir.join(format!("{name}.toml"));
    std::fs::write(&job, edit(text)).expect("write job");
    job
}

pub fn measure_job(dir: &Path, settings: &str) -> std::path::PathBuf {
    let root = root();
    let text = format!(
        r#"[job]
name = "campaign"
seed = 3
robot = "{robot}"
output = "out"

[[stages]]
id = "measure"
kind = "measure"
inputs = {{ conf_wrenches = "{rows}", truth = "{truth}" }}
{settings}
"#,
        robot = root.join("jobs/robots/irb1600_145.toml").display(),
        rows = root
            .join("fixtures/measure/noiseless_simulator/conf_wrenches.parquet")
            .display(),
        truth = root.join("jobs/truth/irb1600_paper.parquet").display(),
    );
    let path = dir.join("job.toml");
    std::fs::write(&path, text).expect("write job");
    path
}

/// Says why a test that needs an external server skips; under CI
/// (`EGCAL_TEST_REQUIRE_SERVICES`, set by `.ci/run`) the test fails instead, so a
/// broken service start cannot pass as a skip.
pub fn skip_without_service(why: &str) {
    assert!(
        std::env::var_os("EGCAL_TEST_REQUIRE_SERVICES").is_none(),
        "{why}, but EGCAL_TEST_REQUIRE_SERVICES is set (CI must start it: .ci/services.sh)"
    );
    eprintln!(
        "SKIPPED: {why}; `bash .ci/services.sh start DIR` and source DIR/env.sh to run this test"
    );
}

/// Copies a folder recursively, leaving out the top-level entries named in `skip`
/// (a job folder without its `out` and `calibration`).
pub fn copy_dir(from: &Path, to: &Path, skip: &[&str]) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap().flatten() {
        let name = entry.file_name();
        if skip.iter().any(|s| name == *s) {
            continue;
        }
        if entry.path().is_dir() {
            copy_dir(&entry.path(), &to.join(&name), &[]);
        } else {
            std::fs::copy(entry.path(), to.join(&name)).unwrap();
        }
    }
}
