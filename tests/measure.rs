//! The measurement campaign through the runner: the external-driver path gives
//! the same rows as the in-process simulator, an interrupted campaign resumes
//! without measuring a row twice or losing one, and failing rows are recorded.

mod common;

use std::path::Path;

use egcal::table;

fn measurements(dir: &Path) -> polars::prelude::DataFrame {
    table::read_parquet(&dir.join("out/measure/measurements.parquet")).unwrap()
}

/// The largest difference of `x_mm` between two measurements of the same rows.
fn largest_x_difference_mm(a: &polars::prelude::DataFrame, b: &polars::prelude::DataFrame) -> f64 {
    let x = |df: &polars::prelude::DataFrame| {
        table::schema::f64_values(df, "x_mm", Path::new("m")).unwrap()
    };
    x(a).iter()
        .zip(x(b))
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max)
}

/// The measure stage's settings for `egcal sim-driver` over the paper's
/// robot and truth, seed 42, with `extra` arguments.
fn sim_driver(extra: &[&str]) -> String {
    let root = common::root();
    let robot = root.join("jobs/robots/irb1600_145.toml");
    let truth = root.join("jobs/truth/irb1600_paper.parquet");
    let mut command = vec![
        env!("CARGO_BIN_EXE_egcal"),
        "sim-driver",
        "--robot",
        robot.to_str().unwrap(),
        "--truth",
        truth.to_str().unwrap(),
        "--seed",
        "42",
    ];
    command.extend(extra);
    let quoted: Vec<String> = command.iter().map(|a| format!("{a:?}")).collect();
    format!("driver = \"external\"\ncommand = [{}]", quoted.join(", "))
}

#[test]
fn external_driver_gives_the_same_rows_as_the_in_process_simulator() {
    let inproc = tempfile::tempdir().unwrap();
    let job = common::measure_job(inproc.path(), "seed = 42");
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], inproc.path());
    assert_eq!(code, 0, "{stderr}");

    let external = tempfile::tempdir().unwrap();
    let job = common::measure_job(external.path(), &sim_driver(&[]));
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], external.path());
    assert_eq!(code, 0, "{stderr}");
    let (a, b) = (measurements(inproc.path()), measurements(external.path()));
    assert_eq!(a.height(), 15);
    assert_eq!(table::content_hash(&a), table::content_hash(&b));
}

/// With backlash, transmission errors and a smooth residual, the external
/// simulator (which takes each row's approach from its own previous move)
/// measures what the in-process one (given the campaign's planned approach)
/// does, and the effects move the rows.
#[test]
fn the_unmodelled_effects_are_the_same_robot_in_process_and_behind_a_driver() {
    let effects = "backlash_deg = 0.01\ntransmission_error_1_deg = 0.01\nresidual_mm = 0.05\n";
    let inproc = tempfile::tempdir().unwrap();
    let job = common::measure_job(
        inproc.path(),
        &format!("seed = 42\n[stages.simulator]\n{effects}"),
    );
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], inproc.path());
    assert_eq!(code, 0, "{stderr}");
    let plain = tempfile::tempdir().unwrap();
    let job = common::measure_job(plain.path(), "seed = 42");
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], plain.path());
    assert_eq!(code, 0, "{stderr}");

    let external = tempfile::tempdir().unwrap();
    let settings = external.path().join("simulator.toml");
    std::fs::write(&settings, effects).unwrap();
    let job = common::measure_job(
        external.path(),
        &sim_driver(&["--settings", settings.to_str().unwrap()]),
    );
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], external.path());
    assert_eq!(code, 0, "{stderr}");
    let (a, b) = (measurements(inproc.path()), measurements(external.path()));
    assert_eq!(table::content_hash(&a), table::content_hash(&b));
    let moved = largest_x_difference_mm(&a, &measurements(plain.path()));
    assert!(moved > 0.01, "the effects move x by at most {moved} mm");

    // Each row carries its approach direction (spec §8), from the commands in
    // input order.
    let commands_file =
        common::root().join("fixtures/measure/noiseless_simulator/conf_wrenches.parquet");
    let commands = table::read_parquet(&commands_file).unwrap();
    let joint = |df: &polars::prelude::DataFrame, name: &str| {
        table::schema::f64_values(df, name, Path::new("c")).unwrap()
    };
    let columns: Vec<Vec<f64>> = table::schema::JOINT_COLUMNS
        .iter()
        .map(|name| joint(&commands, name))
        .collect();
    let q: Vec<[f64; egcal::robot::MAX_JOINTS]> = (0..commands.height())
        .map(|k| std::array::from_fn(|j| columns.get(j).map_or(0.0, |c| c[k])))
        .collect();
    let expected = egcal::rig::approach::approach_directions(&q);
    for (j, name) in table::schema::APPROACH_COLUMNS.iter().enumerate() {
        let written: Vec<i64> = a
            .column(name)
            .unwrap()
            .cast(&polars::prelude::DataType::Int64)
            .unwrap()
            .i64()
            .unwrap()
            .iter()
            .map(|v| v.unwrap())
            .collect();
        let wanted: Vec<i64> = expected.iter().map(|d| i64::from(d[j])).collect();
        assert_eq!(written, wanted, "{name}");
    }
}

/// A driver that answers like a rig and dies after a number of `measure` calls,
/// standing in for a crashed lab driver.
const DYING_DRIVER: &str = r#"
import json, sys
limit = int(sys.argv[1])
measured = 0
for line in sys.stdin:
    request = json.loads(line)
    method, rid = request["method"], request["id"]
    result = {}
    if method == "hello":
        result = {"protocol": 1, "name": "dying test driver"}
    elif method == "move_joints":
        q = request["params"]["q_deg"]
    elif method == "read_joints":
        result = {"q_deg": q}
    elif method == "read_wrench":
        result = {"wrench": [0.0] * 6}
    elif method == "measure":
        if measured == limit:
            sys.exit(3)
        measured += 1
        result = {"position_mm": [sum(q), 1.0, 2.0], "measured_at_us": 0}
    elif method == "shutdown":
        print(json.dumps({"id": rid, "result": {}}), flush=True)
        break
    print(json.dumps({"id": rid, "result": result}), flush=True)
"#;

#[test]
fn a_campaign_interrupted_by_driver_death_resumes_without_duplicates_or_losses() {
    let dir = tempfile::tempdir().unwrap();
    let script = dir.path().join("driver.py");
    std::fs::write(&script, DYING_DRIVER).unwrap();
    let job_with_limit = |limit: usize| {
        common::measure_job(
            dir.path(),
            &format!(
                "driver = \"external\"\ncommand = [\"python3\", \"{}\", \"{limit}\"]",
                script.display()
            ),
        )
    };
    let job = job_with_limit(6);
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 3, "{stderr}");
    assert!(stderr.contains("driver exited"), "{stderr}");
    assert!(
        stderr.contains("the 6 rows measured so far are kept"),
        "{stderr}"
    );
    assert!(!dir.path().join("out/measure/measurements.parquet").exists());

    // A restarted driver (here with another argument: the command line is not part
    // of the campaign's identity) continues the journal: 6 rows come from it.
    let job = job_with_limit(100);
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stderr.contains("resuming: 6 of 15 rows already measured"),
        "{stderr}"
    );
    let df = measurements(dir.path());
    let ids = table::schema::i64_values(&df, "cw_id", Path::new("m")).unwrap();
    assert_eq!(ids, (1..=15).collect::<Vec<i64>>());
}

#[test]
fn transient_failures_are_retried_then_recorded_without_stopping() {
    let dir = tempfile::tempdir().unwrap();
    let job = common::measure_job(
        dir.path(),
        "retries = 1\n[stages.simulator]\nbeam_loss_probability = 0.5",
    );
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 0, "{stderr}");
    let measured = measurements(dir.path()).height();
    let failures =
        table::read_parquet(&dir.path().join("out/measure/measurement_failures.parquet")).unwrap();
    assert!(
        failures.height() > 0 && measured > 0,
        "{measured} measured, {} failed",
        failures.height()
    );
    assert_eq!(measured + failures.height(), 15);
    let reasons = table::schema::str_values(&failures, "reason", Path::new("f")).unwrap();
    assert!(
        reasons
            .iter()
            .all(|r| r.as_deref() == Some("tracker lost the beam"))
    );
    let attempts = table::schema::i64_values(&failures, "attempts", Path::new("f")).unwrap();
    assert!(attempts.iter().all(|a| *a == 2));
}

/// A driver whose tracker hangs on row 2: it answers after the timeout.
const SLOW_DRIVER: &str = r#"
import json, sys, time
for line in sys.stdin:
    request = json.loads(line)
    method, rid = request["method"], request["id"]
    result = {}
    if method == "hello":
        result = {"protocol": 1, "name": "slow test driver"}
    elif method == "move_joints":
        row, q = request["params"]["cw_id"], request["params"]["q_deg"]
    elif method == "read_joints":
        result = {"q_deg": q}
    elif method == "read_wrench":
        result = {"wrench": [0.0] * 6}
    elif method == "measure":
        if row == 2:
            time.sleep(4.0)
        result = {"position_mm": [sum(q), 1.0, 2.0]}
    elif method == "shutdown":
        print(json.dumps({"id": rid, "result": {}}), flush=True)
        break
    print(json.dumps({"id": rid, "result": result}), flush=True)
"#;

#[test]
fn a_driver_timeout_fails_that_row_only_and_late_replies_are_ignored() {
    let dir = tempfile::tempdir().unwrap();
    let script = dir.path().join("driver.py");
    std::fs::write(&script, SLOW_DRIVER).unwrap();
    let job = common::measure_job(
        dir.path(),
        &format!(
            "driver = \"external\"\ncommand = [\"python3\", \"{}\"]\ntimeout_s = 1.5\nretries = 0",
            script.display()
        ),
    );
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 0, "{stderr}");
    let failures =
        table::read_parquet(&dir.path().join("out/measure/measurement_failures.parquet")).unwrap();
    assert_eq!(
        table::schema::i64_values(&failures, "cw_id", Path::new("f")).unwrap(),
        [2]
    );
    let reasons = table::schema::str_values(&failures, "reason", Path::new("f")).unwrap();
    assert_eq!(
        reasons[0].as_deref(),
        Some("driver did not answer `measure` within 1.5 s")
    );
    assert_eq!(measurements(dir.path()).height(), 14);
}

/// A driver that answers like a rig, logs every `move_joints` to a file, and
/// answers `measure` for one row with garbage: `text` (not JSON), `shape` (a
/// position with two coordinates), `binary` (not even UTF-8) or nothing wrong (`none`).
const GARBAGE_DRIVER: &str = r#"
import json, sys
mode, bad_row, log = sys.argv[1], int(sys.argv[2]), open(sys.argv[3], "a")
for line in sys.stdin:
    request = json.loads(line)
    method, rid = request["method"], request["id"]
    result = {}
    if method == "hello":
        result = {"protocol": 1, "name": "garbage test driver"}
    elif method == "move_joints":
        row, q = request["params"]["cw_id"], request["params"]["q_deg"]
        log.write(f"{row}\n")
        log.flush()
    elif method == "read_joints":
        result = {"q_deg": q}
    elif method == "read_wrench":
        result = {"wrench": [0.0] * 6}
    elif method == "measure":
        if row == bad_row and mode == "text":
            print("tracker: warming up, please wait", flush=True)
            continue
        if row == bad_row and mode == "shape":
            print(json.dumps({"id": rid, "result": {"position_mm": [1.0, 2.0]}}), flush=True)
            continue
        if row == bad_row and mode == "binary":
            sys.stdout.buffer.write(b"\xff\xfe\x00\x01 garbage\n")
            sys.stdout.flush()
            continue
        result = {"position_mm": [sum(q), 1.0, 2.0]}
    elif method == "shutdown":
        print(json.dumps({"id": rid, "result": {}}), flush=True)
        break
    print(json.dumps({"id": rid, "result": result}), flush=True)
"#;

/// The measure stage's settings for [`GARBAGE_DRIVER`] in `dir`.
fn garbage_driver_settings(dir: &Path, mode: &str, bad_row: i64) -> String {
    let script = dir.join("driver.py");
    std::fs::write(&script, GARBAGE_DRIVER).unwrap();
    format!(
        "driver = \"external\"\ncommand = [\"python3\", \"{}\", \"{mode}\", \"{bad_row}\", \"{}\"]\ntimeout_s = 10.0",
        script.display(),
        dir.join("moves.log").display()
    )
}

fn moves(dir: &Path) -> Vec<i64> {
    std::fs::read_to_string(dir.join("moves.log"))
        .unwrap_or_default()
        .lines()
        .map(|l| l.parse().unwrap())
        .collect()
}

#[test]
fn a_garbage_reply_stops_the_campaign_with_a_clear_error_and_keeps_every_measured_row() {
    for (mode, says) in [
        ("text", ": \"tracker: warming up, please wait\"; the 3 rows"),
        ("shape", "invalid length 2, expected an array of length 3"),
        // Not UTF-8: shown replaced and escaped, not taken for the driver's death.
        ("binary", "\"\u{fffd}\u{fffd}\\0\\u{1} garbage\""),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let job = common::measure_job(dir.path(), &garbage_driver_settings(dir.path(), mode, 4));
        let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
        assert_eq!(code, 3, "{mode}: {stderr}");
        for expected in [
            "cw_id 4 (input row 3): driver sent a malformed reply to `measure`",
            says,
            "the 3 rows measured so far are kept",
        ] {
            assert!(
                stderr.contains(expected),
                "{mode}: `{expected}` not in {stderr}"
            );
        }
        assert!(!dir.path().join("out/measure/measurements.parquet").exists());

        // A fixed driver resumes after the 3 rows; none is measured twice or lost.
        let job = common::measure_job(dir.path(), &garbage_driver_settings(dir.path(), "none", 0));
        let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
        assert_eq!(code, 0, "{mode}: {stderr}");
        assert!(
            stderr.contains("resuming: 3 of 15 rows already measured"),
            "{mode}: {stderr}"
        );
        let df = measurements(dir.path());
        let ids = table::schema::i64_values(&df, "cw_id", Path::new("m")).unwrap();
        assert_eq!(ids, (1..=15).collect::<Vec<i64>>(), "{mode}");
        // Row 4 is moved to again (its garbage reading was not recorded), no other.
        assert_eq!(
            moves(dir.path()),
            [1, 2, 3, 4, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15],
            "{mode}"
        );
    }
}

#[test]
fn an_unsafe_wrench_is_refused_before_the_move_and_the_rows_before_it_are_kept() {
    let dir = tempfile::tempdir().unwrap();
    let driver = garbage_driver_settings(dir.path(), "none", 0);
    // cw_id 9 asks for fx = −118.8 N, beyond a 114 N bound; rows 1–8 are within it.
    let job = common::measure_job(dir.path(), &format!("{driver}\nmax_force_n = 114.0"));
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 3, "{stderr}");
    assert!(
        stderr.contains("safety stop before cw_id 9 (input row 8 of ")
            && stderr.contains("noiseless_simulator/conf_wrenches.parquet): fx_n = -118.7")
            && stderr.contains("exceeds the bound ±114 (max_force_n)"),
        "{stderr}"
    );
    // The driver never saw the unsafe row.
    assert_eq!(moves(dir.path()), (1..=8).collect::<Vec<i64>>());

    let job = common::measure_job(dir.path(), &driver);
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stderr.contains("resuming: 8 of 15 rows already measured"),
        "{stderr}"
    );
    assert_eq!(measurements(dir.path()).height(), 15);
}

/// Rows carrying approach directions (as `compensate` writes them for a
/// model with backlash) are reached from a pre-position: the measured rows
/// carry those directions, the external simulator (which takes directions
/// from its own moves, the pre-positioning move among them) measures what the
/// in-process one does, and the backlash puts the rows where it should.
#[test]
fn rows_with_approach_directions_are_reached_from_their_pre_positions() {
    use polars::prelude::{Column, DataFrame};
    let source = common::root().join("fixtures/measure/noiseless_simulator/conf_wrenches.parquet");
    let plain_rows = table::read_parquet(&source).unwrap();
    let n = plain_rows.height();
    // Row k from +1 on every joint when k is even, −1 when odd.
    let wanted: Vec<i8> = (0..n).map(|k| if k % 2 == 0 { 1 } else { -1 }).collect();
    let with_directions = |dir: &Path| {
        let mut df: DataFrame = plain_rows.clone();
        for name in table::schema::APPROACH_COLUMNS {
            df.with_column(Column::new(name.into(), wanted.clone()))
                .unwrap();
        }
        let path = dir.join("conf_wrenches.parquet");
        table::write_parquet(&mut df, &path, None).unwrap();
        let job = dir.join("job.toml");
        let text = std::fs::read_to_string(&job).unwrap();
        std::fs::write(
            &job,
            text.replace(source.to_str().unwrap(), path.to_str().unwrap()),
        )
        .unwrap();
        job
    };
    let effects = "backlash_deg = 0.05\n";
    let inproc = tempfile::tempdir().unwrap();
    // Row 7 is 0.2° from joint 2's limit: a 1° pre-position would be refused.
    common::measure_job(
        inproc.path(),
        &format!("seed = 42\npre_position_deg = 0.1\n[stages.simulator]\n{effects}"),
    );
    let job = with_directions(inproc.path());
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], inproc.path());
    assert_eq!(code, 0, "{stderr}");

    let external = tempfile::tempdir().unwrap();
    let settings = external.path().join("simulator.toml");
    std::fs::write(&settings, effects).unwrap();
    common::measure_job(
        external.path(),
        &format!(
            "{}\npre_position_deg = 0.1",
            sim_driver(&["--settings", settings.to_str().unwrap()])
        ),
    );
    let job = with_directions(external.path());
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], external.path());
    assert_eq!(code, 0, "{stderr}");
    let (a, b) = (measurements(inproc.path()), measurements(external.path()));
    assert_eq!(a.height(), n);
    assert_eq!(table::content_hash(&a), table::content_hash(&b));
    let written = table::schema::approach_values(&a, Path::new("measurements")).unwrap();
    let expected: Vec<[i8; egcal::robot::MAX_JOINTS]> = wanted
        .iter()
        .map(|d| egcal::robot::joint_array(&[*d; 6]))
        .collect();
    assert_eq!(written, expected);

    // The same rows measured in order without directions sit elsewhere: the
    // pre-positions changed the side of the dead band of some joints.
    let plain = tempfile::tempdir().unwrap();
    let job = common::measure_job(
        plain.path(),
        &format!("seed = 42\n[stages.simulator]\n{effects}"),
    );
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], plain.path());
    assert_eq!(code, 0, "{stderr}");
    let moved = largest_x_difference_mm(&a, &measurements(plain.path()));
    assert!(moved > 0.1, "pre-positioning moves x by at most {moved} mm");
}
