//! Lab drivers that misbehave, played by a scripted Python driver: implausible
//! readings become failed rows with their reason (never data), a driver that dies
//! says how, a driver that fails at start is named, and a relative driver command
//! runs in the job file's folder wherever egcal is started.

mod common;

use std::path::{Path, PathBuf};

use egcal::table;

/// A driver that answers like a noiseless rig (it reads back what it was
/// commanded) except for one row, where `mode` says what goes wrong:
/// `joints500`, `joints1e300`, `position1e300`, `wrench1e9`, `slack` (the sensor
/// reads no force) on every attempt, `once` (a joint of 500° on the first attempt
/// only), `exit3` or `sigkill` at its `measure`; coded errors at that row:
/// `beam_lost` (transient, at `measure`), `out_of_range` (at `apply_wrench`),
/// `estop` (at `move_joints`); `sigma` gives every point the tracker's σ; or at
/// start: `silent` (never answers), `garbage`, `wrong_id`, `exit_at_start`. It
/// writes its working directory to `cwd.txt` there.
const FAULTY_DRIVER: &str = r#"
import json, os, signal, sys
mode, bad_row = sys.argv[1], int(sys.argv[2])
with open("cwd.txt", "w") as f:
    f.write(os.getcwd())
if mode == "exit_at_start":
    sys.exit(1)
attempts = 0
def reply(rid, result):
    print(json.dumps({"id": rid, "result": result}), flush=True)
def fail(rid, code, transient, message):
    print(json.dumps({"id": rid, "error": {"message": message, "transient": transient, "code": code}}), flush=True)
bad = False
for line in sys.stdin:
    request = json.loads(line)
    method, rid = request["method"], request["id"]
    result = {}
    if method == "hello":
        if mode == "silent":
            continue
        if mode == "garbage":
            print("READY", flush=True)
            continue
        if mode == "wrong_id":
            rid = 7
        result = {"protocol": 1, "name": "faulty test driver"}
    elif method == "move_joints":
        row, q = request["params"]["cw_id"], list(request["params"]["q_deg"])
        bad = row == bad_row
        if bad:
            attempts += 1
        if bad and mode == "estop":
            fail(rid, "estop", False, "emergency stop pressed")
            continue
    elif method == "apply_wrench":
        wrench = list(request["params"]["wrench"])
        if bad and mode == "out_of_range":
            fail(rid, "out_of_range", False, "wrench outside the feasible set")
            continue
    elif method == "read_joints":
        if bad and (mode == "joints500" or (mode == "once" and attempts == 1)):
            q[0] = 500.0
        if bad and mode == "joints1e300":
            q[3] = 1e300
        result = {"q_deg": q}
    elif method == "read_wrench":
        if bad and mode == "wrench1e9":
            wrench[2] = 1e9
        if bad and mode == "slack":
            wrench[0:3] = [0.0, 0.0, 0.0]
        result = {"wrench": wrench}
    elif method == "measure":
        if bad and mode == "exit3":
            sys.exit(3)
        if bad and mode == "sigkill":
            os.kill(os.getpid(), signal.SIGKILL)
        if bad and mode == "beam_lost":
            fail(rid, "beam_lost", True, "no reflector in the beam")
            continue
        result = {"position_mm": [1e300 if bad and mode == "position1e300" else sum(q), 1.0, 2.0]}
        if mode == "sigma":
            result["sigma_mm"] = [0.01, 0.02, 0.5 if bad else 0.03]
    elif method == "shutdown":
        reply(rid, {})
        break
    reply(rid, result)
"#;

/// Writes the driver and a job measuring the fixture's 15 conf-wrench rows
/// (cw_id 1..=15) into `dir`, with `command` and further settings.
fn job(dir: &Path, command: &str, settings: &str) -> PathBuf {
    std::fs::write(dir.join("driver.py"), FAULTY_DRIVER).unwrap();
    common::measure_job(
        dir,
        &format!("driver = \"external\"\ncommand = {command}\n{settings}"),
    )
}

/// A job whose driver misbehaves in `mode` on row `bad_row`.
fn faulty_job(dir: &Path, mode: &str, bad_row: i64, settings: &str) -> PathBuf {
    job(
        dir,
        &format!(r#"["python3", "driver.py", "{mode}", "{bad_row}"]"#),
        settings,
    )
}

fn run(job: &Path, dir: &Path) -> (i32, String) {
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], dir);
    (code, stderr)
}

fn i64_column(path: &Path, column: &str) -> Vec<i64> {
    let df = table::read_parquet(path).unwrap();
    table::schema::i64_values(&df, column, path).unwrap()
}

#[test]
fn implausible_readings_are_retried_then_recorded_as_failed_rows_with_their_reason() {
    for (mode, extra, reason) in [
        (
            "joints500",
            "",
            "implausible reading: q1_deg = 500 is outside the joint limits [-180, 180] by more than joint_tolerance_deg = 0.5°",
        ),
        (
            "joints1e300",
            "",
            "implausible reading: q4_deg = 1e300 is outside the joint limits",
        ),
        (
            "position1e300",
            "",
            "implausible reading: position (1e300, 1, 2) mm is 1e300 mm from the tracker, more than max_tracker_distance_mm = 40000 mm",
        ),
        (
            "wrench1e9",
            "",
            "implausible reading: fz_n = 1e9 is beyond the force/torque sensor's range ±2500 (sensor_range_n)",
        ),
        // Off by default: a slack cable is only a fault when the lab says so.
        ("slack", "max_wrench_error_n = 20.0", "from the commanded"),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let job = faulty_job(dir.path(), mode, 5, &format!("retries = 1\n{extra}"));
        let (code, stderr) = run(&job, dir.path());
        assert_eq!(code, 0, "{mode}: {stderr}");
        assert!(
            stderr.contains("cw_id 5: implausible reading: ")
                && stderr.contains(reason)
                && stderr.contains("retrying"),
            "{mode}: {stderr}"
        );
        let out = dir.path().join("out/measure");
        let measured = i64_column(&out.join("measurements.parquet"), "cw_id");
        assert_eq!(
            measured,
            (1..=15).filter(|&id| id != 5).collect::<Vec<_>>(),
            "{mode}"
        );
        let failures = out.join("measurement_failures.parquet");
        assert_eq!(i64_column(&failures, "cw_id"), [5], "{mode}");
        assert_eq!(i64_column(&failures, "attempts"), [2], "{mode}");
        let df = table::read_parquet(&failures).unwrap();
        let reasons = table::schema::str_values(&df, "reason", &failures).unwrap();
        let recorded = reasons[0].as_deref().unwrap_or_default();
        assert!(recorded.contains(reason), "{mode}: {recorded}");
    }
}

#[test]
fn a_slack_cable_is_data_by_default_and_a_fault_that_clears_on_retry_is_a_good_row() {
    let dir = tempfile::tempdir().unwrap();
    let job = faulty_job(dir.path(), "slack", 5, "");
    let (code, stderr) = run(&job, dir.path());
    assert_eq!(code, 0, "{stderr}");
    let out = dir.path().join("out/measure");
    assert_eq!(
        i64_column(&out.join("measurements.parquet"), "cw_id").len(),
        15
    );

    let dir = tempfile::tempdir().unwrap();
    let job = faulty_job(dir.path(), "once", 5, "retries = 1");
    let (code, stderr) = run(&job, dir.path());
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stderr.contains("cw_id 5: implausible reading: q1_deg = 500"),
        "{stderr}"
    );
    let out = dir.path().join("out/measure");
    assert_eq!(
        i64_column(&out.join("measurements.parquet"), "cw_id").len(),
        15
    );
    let failures = out.join("measurement_failures.parquet");
    assert!(i64_column(&failures, "cw_id").is_empty());
}

#[test]
fn a_driver_that_dies_mid_campaign_says_how_and_the_rows_before_are_kept() {
    for (mode, says) in [
        ("exit3", "driver exited with status 3 during `measure`"),
        (
            "sigkill",
            "driver was killed by signal 9 (SIGKILL) during `measure`",
        ),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let job = faulty_job(dir.path(), mode, 6, "");
        let (code, stderr) = run(&job, dir.path());
        assert_eq!(code, 3, "{mode}: {stderr}");
        for expected in [
            &format!("cw_id 6 (input row 5): {says}"),
            "the 5 rows measured so far are kept",
        ] {
            assert!(
                stderr.contains(expected),
                "{mode}: `{expected}` not in {stderr}"
            );
        }
    }
}

#[test]
fn a_driver_that_fails_at_start_is_named_with_what_went_wrong() {
    for (mode, says) in [
        (
            "silent",
            "driver did not answer `hello` within 1.0 s; does it read requests from stdin and flush each reply line?",
        ),
        (
            "garbage",
            "driver sent a malformed reply to `hello`: expected value at line 1 column 1: \"READY\"",
        ),
        (
            "wrong_id",
            "driver answered request 7 while egcal waited for 1",
        ),
        (
            "exit_at_start",
            "driver exited with status 1 during `hello`",
        ),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let job = faulty_job(dir.path(), mode, 0, "timeout_s = 1.0");
        let (code, stderr) = run(&job, dir.path());
        assert_eq!(code, 3, "{mode}: {stderr}");
        let named = format!("starting driver `python3 driver.py {mode} 0`: ");
        assert!(
            stderr.contains(&format!("{named}{says}")),
            "{mode}: {stderr}"
        );
    }

    let dir = tempfile::tempdir().unwrap();
    let job = job(dir.path(), r#"["./no_such_driver.sh"]"#, "");
    let (code, stderr) = run(&job, dir.path());
    assert_eq!(code, 3, "{stderr}");
    assert!(
        stderr.contains("cannot start driver `./no_such_driver.sh` in ")
            && stderr.contains("no_such_driver.sh: No such file"),
        "{stderr}"
    );
}

#[test]
fn relative_driver_commands_run_in_the_job_files_folder_wherever_egcal_starts() {
    let elsewhere = tempfile::tempdir().unwrap();
    let jobs = elsewhere.path().join("jobs");
    std::fs::create_dir(&jobs).unwrap();
    // A wrapper script that itself relies on the working directory.
    let script = jobs.join("driver.sh");
    std::fs::write(&script, "#!/bin/sh\nexec python3 driver.py \"$@\"\n").unwrap();
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o755)).unwrap();
    }
    for command in [
        r#"["python3", "driver.py", "none", "0"]"#,
        r#"["./driver.sh", "none", "0"]"#,
    ] {
        job(&jobs, command, "");
        // Started from the folder above, with a relative job path.
        let (code, _, stderr) = common::run(&["run", "jobs/job.toml"], elsewhere.path());
        assert_eq!(code, 0, "{command}: {stderr}");
        let cwd = std::fs::read_to_string(jobs.join("cwd.txt")).unwrap();
        assert_eq!(
            Path::new(&cwd).canonicalize().unwrap(),
            jobs.canonicalize().unwrap(),
            "{command}"
        );
        let measured = i64_column(&jobs.join("out/measure/measurements.parquet"), "cw_id");
        assert_eq!(measured.len(), 15, "{command}");
        std::fs::remove_dir_all(jobs.join("out")).unwrap();
        std::fs::remove_file(jobs.join("cwd.txt")).unwrap();
    }
}

#[test]
fn a_negative_reading_bound_is_refused_before_anything_moves() {
    let dir = tempfile::tempdir().unwrap();
    let job = faulty_job(dir.path(), "none", 0, "max_joint_error_deg = -1.0");
    let (code, stderr) = run(&job, dir.path());
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains("job.toml:")
            && stderr.contains("max_joint_error_deg")
            && stderr.contains("expected > 0"),
        "{stderr}"
    );
}

#[test]
fn coded_errors_are_retried_recorded_or_stop_as_their_code_says() {
    let failures = |dir: &Path| dir.join("out/measure/measurement_failures.parquet");
    // beam_lost, transient: retried, then recorded with its code.
    let dir = tempfile::tempdir().unwrap();
    let job = faulty_job(dir.path(), "beam_lost", 4, "retries = 2");
    let (code, stderr) = run(&job, dir.path());
    assert_eq!(code, 0, "{stderr}");
    assert_eq!(i64_column(&failures(dir.path()), "attempts"), [3]);
    let df = table::read_parquet(&failures(dir.path())).unwrap();
    let reason = table::schema::str_values(&df, "reason", &failures(dir.path())).unwrap();
    assert!(
        reason[0]
            .as_deref()
            .unwrap()
            .starts_with("beam_lost: no reflector"),
        "{reason:?}"
    );
    // out_of_range, not transient: recorded at once.
    let dir = tempfile::tempdir().unwrap();
    let job = faulty_job(dir.path(), "out_of_range", 4, "retries = 2");
    let (code, stderr) = run(&job, dir.path());
    assert_eq!(code, 0, "{stderr}");
    assert_eq!(i64_column(&failures(dir.path()), "attempts"), [1]);
    // estop: the campaign stops with the rows before kept, and resumes.
    let dir = tempfile::tempdir().unwrap();
    let job = faulty_job(dir.path(), "estop", 4, "");
    let (code, stderr) = run(&job, dir.path());
    assert_eq!(code, 3, "{stderr}");
    assert!(
        stderr.contains("estop: emergency stop pressed")
            && stderr.contains("the 3 rows measured so far are kept"),
        "{stderr}"
    );
    let job = faulty_job(dir.path(), "none", 0, "");
    let (code, stderr) = run(&job, dir.path());
    assert_eq!(code, 0, "resumed: {stderr}");
    assert_eq!(
        i64_column(
            &dir.path().join("out/measure/measurements.parquet"),
            "cw_id"
        )
        .len(),
        15
    );
}

#[test]
fn the_trackers_own_sigmas_are_stored_with_each_point() {
    let dir = tempfile::tempdir().unwrap();
    let job = faulty_job(dir.path(), "sigma", 4, "");
    let (code, stderr) = run(&job, dir.path());
    assert_eq!(code, 0, "{stderr}");
    let path = dir.path().join("out/measure/measurements.parquet");
    let df = table::read_parquet(&path).unwrap();
    let z = table::schema::f64_values(&df, "sigma_z_mm", &path).unwrap();
    let ids = i64_column(&path, "cw_id");
    for (id, sigma) in ids.iter().zip(&z) {
        assert_eq!(*sigma, if *id == 4 { 0.5 } else { 0.03 });
    }
    assert!(
        table::schema::f64_values(&df, "sigma_x_mm", &path)
            .unwrap()
            .iter()
            .all(|s| *s == 0.01)
    );
}
