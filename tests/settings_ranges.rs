//! Settings out of their range, non-finite or missing a companion setting are job
//! errors: `egcal check` and `egcal run` both refuse them with exit code 2, naming
//! the job file, the line, the key and what was expected (issue #14).

mod common;

use std::path::{Path, PathBuf};

/// A small job whose stage `stage` (0 poses, 1 wrenches, 2 select, 3 measure) gets
/// the line `setting`; returns the job file and the line number of `setting`.
fn job_with(dir: &Path, stage: usize, setting: &str) -> (PathBuf, usize) {
    let root = common::root();
    let mut extra = ["", "", "", ""];
    extra[stage] = setting;
    let text = format!(
        r#"[job]
name = "ranges"
seed = 7
robot = "{robot}"
cable_robot = "{cable}"
output = "out"

[[stages]]
id = "poses"
kind = "poses"
{poses}

[[stages]]
id = "wrenches"
kind = "wrenches"
inputs = {{ poses = "poses" }}
{wrenches}

[[stages]]
id = "select"
kind = "select"
inputs = {{ candidates = "wrenches" }}
n = 12
{select}

[[stages]]
id = "measure"
kind = "measure"
inputs = {{ conf_wrenches = "wrenches", truth = "{truth}" }}
{measure}
"#,
        robot = root.join("jobs/robots/irb1600_145.toml").display(),
        cable = root.join("jobs/cdpr/default.toml").display(),
        truth = root.join("jobs/truth/irb1600_paper.parquet").display(),
        poses = extra[0],
        wrenches = extra[1],
        select = extra[2],
        measure = extra[3],
    );
    let line = text
        .lines()
        .position(|l| l == setting)
        .expect("the setting is in the job")
        + 1;
    let path = dir.join("job.toml");
    std::fs::write(&path, text).expect("write job");
    (path, line)
}

/// (stage, setting line, key, text the message must hold)
const CASES: [(usize, &str, &str, &str); 14] = [
    (
        0,
        "edge_mm = -300.0",
        "stages[0].edge_mm",
        "is -300; expected > 0 (range (0, 100000])",
    ),
    (
        3,
        "simulator = { tracker_noise_mm = -0.02 }",
        "stages[3].simulator.tracker_noise_mm",
        "is -0.02; expected ≥ 0 (range [0, 100])",
    ),
    (
        2,
        "restarts = 0",
        "stages[2].restarts",
        "is 0; expected ≥ 1 (range [1, 1000])",
    ),
    (
        0,
        "centre_mm = [900.0, 0.0, -1e9]",
        "stages[0].centre_mm[2]",
        "is -1000000000; expected ≥ -100000 (range [-100000, 100000])",
    ),
    (
        0,
        "acceptance_half_angle_deg = 400.0",
        "stages[0].acceptance_half_angle_deg",
        "is 400; expected ≤ 90 (range [0, 90])",
    ),
    (
        3,
        "timeout_s = -1.0",
        "stages[3].timeout_s",
        "is -1; expected > 0 (range (0, 86400])",
    ),
    (
        0,
        "points_per_axis = 0",
        "stages[0].points_per_axis",
        "is 0; expected ≥ 1 (range [1, 1000])",
    ),
    (
        0,
        "points_per_axis = 100000",
        "stages[0].points_per_axis",
        "is 100000; expected ≤ 1000 (range [1, 1000])",
    ),
    (
        0,
        "points_per_axis = 800",
        "stages[0].points_per_axis",
        "points_per_axis = 800 (cubed): 512000000 target points need about",
    ),
    (
        1,
        "per_config = 1000000000",
        "stages[1].per_config",
        "is 1000000000; expected ≤ 10000 (range [1, 10000])",
    ),
    (
        1,
        "max_draws = 1e9",
        "stages[1].max_draws",
        "expected usize (range [1, 1000000])",
    ),
    (
        0,
        "edge_mm = nan",
        "stages[0].edge_mm",
        "`edge_mm` is nan; expected a finite number",
    ),
    (
        3,
        "simulator = { tracker_noise_mm = inf }",
        "stages[3].simulator.tracker_noise_mm",
        "`simulator.tracker_noise_mm` is inf; expected a finite number",
    ),
    (
        3,
        "driver = \"external\"",
        "stages[3].command",
        "driver = \"external\" needs `command`",
    ),
];

#[test]
fn check_and_run_refuse_bad_settings_naming_file_line_and_key() {
    for (stage, setting, key, expected) in CASES {
        let dir = tempfile::tempdir().unwrap();
        let (job, mut line) = job_with(dir.path(), stage, setting);
        if key.ends_with(".command") {
            // A missing setting is located at its stage's table.
            let text = std::fs::read_to_string(&job).unwrap();
            line = text
                .lines()
                .enumerate()
                .filter(|(_, l)| *l == "[[stages]]")
                .nth(stage)
                .unwrap()
                .0
                + 1;
        }
        let at = format!("job.toml:{line}: {key}: ");
        for command in ["check", "run"] {
            let (code, stdout, stderr) = common::run(&[command, "job.toml"], dir.path());
            assert_eq!(code, 2, "{command} `{setting}`: {stdout}{stderr}");
            assert!(
                stderr.contains(&at) && stderr.contains(expected),
                "{command} `{setting}`: expected `{at}…{expected}` in\n{stderr}"
            );
        }
        assert!(
            !dir.path().join("out").exists(),
            "`{setting}`: nothing runs"
        );
    }
}

#[test]
fn the_unmodified_job_checks_clean() {
    let dir = tempfile::tempdir().unwrap();
    let (job, _) = job_with(dir.path(), 0, "floor_z_mm = 0.0");
    let (code, stdout, stderr) = common::run(&["check", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 0, "{stdout}{stderr}");
}

#[test]
fn stage_on_files_names_the_settings_file_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let settings = dir.path().join("poses.toml");
    let robot = common::root().join("jobs/robots/irb1600_145.toml");
    let out = dir.path().join("out");
    let poses_with = |text: &str| {
        std::fs::write(&settings, text).unwrap();
        let args = ["stage", "poses", "--robot", robot.to_str().unwrap()];
        let files = [
            "--settings",
            settings.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ];
        let (code, _, stderr) = common::run(&[&args[..], &files[..]].concat(), dir.path());
        assert_eq!(code, 2, "{stderr}");
        stderr
    };
    let stderr = poses_with("edge_mm = -300.0\nroll_half_range_deg = nan\n");
    assert!(
        stderr.contains(&format!(
            "{}: roll_half_range_deg: `roll_half_range_deg` is nan; expected a finite number",
            settings.display()
        )),
        "{stderr}"
    );
    let stderr = poses_with("edge_mm = -300.0\n");
    assert!(
        stderr.contains(&format!(
            "{}: edge_mm: `edge_mm` is -300; expected > 0 (range (0, 100000])",
            settings.display()
        )),
        "{stderr}"
    );
}
