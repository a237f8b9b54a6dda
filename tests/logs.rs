//! The `scan_logs` stage on a Hive-partitioned log folder written here: window and
//! robot filters, partition pruning, bad rows and files per `bad_data`, duplicate
//! rows, the day split, the clear errors of an empty or too small window, and the
//! cache key following the folder's content and the run date.

mod common;

use std::path::{Path, PathBuf};

use egcal::table::schema::{JOINT_COLUMNS, POSITION_COLUMNS, WRENCH_COLUMNS};
use egcal::table::time::parse_date;
use polars::prelude::*;

const ROWS_PER_DAY: i64 = 10;

/// One day of logged rows of `robot` (cw_id = day * 1000 + k), measured hourly.
fn day_rows(robot: &str, date: &str) -> DataFrame {
    let day = parse_date(date).unwrap();
    let ids: Vec<i64> = (0..ROWS_PER_DAY).map(|k| day * 1000 + k).collect();
    let mut columns = vec![Column::new("cw_id".into(), ids.clone())];
    for (i, name) in JOINT_COLUMNS
        .iter()
        .chain(&WRENCH_COLUMNS)
        .chain(&POSITION_COLUMNS)
        .enumerate()
    {
        columns.push(Column::new(
            (*name).into(),
            ids.iter()
                .map(|id| (id % 97) as f64 + i as f64)
                .collect::<Vec<_>>(),
        ));
    }
    columns.push(Column::new("robot_id".into(), vec![robot; ids.len()]));
    let stamps: Vec<i64> = (0..ROWS_PER_DAY)
        .map(|k| (day * 86_400 + 3600 * (k + 1)) * 1_000_000)
        .collect();
    columns.push(
        Column::new("measured_at".into(), stamps)
            .cast(&DataType::Datetime(
                TimeUnit::Microseconds,
                Some(TimeZone::UTC),
            ))
            .unwrap(),
    );
    DataFrame::new(ROWS_PER_DAY as usize, columns).unwrap()
}

fn write(df: &mut DataFrame, path: &Path) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    let file = std::fs::File::create(path).unwrap();
    ParquetWriter::new(file).finish(df).unwrap();
}

/// Logs of robots r1 and r2 for 2026-11-01 .. 2026-11-20.
fn log_folder(dir: &Path) -> PathBuf {
    let logs = dir.join("logs");
    for robot in ["r1", "r2"] {
        for day in 1..=20 {
            let date = format!("2026-11-{day:02}");
            write(
                &mut day_rows(robot, &date),
                &logs.join(format!("robot_id={robot}/date={date}/part-0.parquet")),
            );
        }
    }
    logs
}

fn scan(dir: &Path, settings: &str, run_date: &str) -> (i32, String, String, PathBuf) {
    let out = dir.join(format!("out-{run_date}"));
    let settings_file = dir.join("settings.toml");
    std::fs::write(&settings_file, settings).unwrap();
    let robot = common::root().join("jobs/robots/irb1600_145.toml");
    let (code, stdout, stderr) = common::run(
        &[
            "stage",
            "scan_logs",
            "--robot",
            robot.to_str().unwrap(),
            "--settings",
            settings_file.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--run-date",
            run_date,
        ],
        dir,
    );
    (code, stdout, stderr, out)
}

fn read(path: &Path) -> DataFrame {
    egcal::table::read_parquet(path).unwrap()
}

#[test]
fn window_robot_and_holdout_split() {
    let dir = tempfile::tempdir().unwrap();
    let logs = log_folder(dir.path());
    let settings = format!(
        "logs = \"{}\"\nrobot_id = \"r1\"\nlast = \"5d\"\n",
        logs.display()
    );
    let (code, stdout, stderr, out) = scan(dir.path(), &settings, "2026-11-18");
    assert_eq!(code, 0, "{stderr}");
    let measurements = read(&out.join("measurements.parquet"));
    // 2026-11-14 .. 2026-11-18: five days of r1 only.
    assert_eq!(measurements.height(), 5 * ROWS_PER_DAY as usize);
    let robots = measurements
        .column("robot_id")
        .unwrap()
        .str()
        .unwrap()
        .clone();
    assert!(robots.iter().all(|r| r == Some("r1")));
    let first = parse_date("2026-11-14").unwrap() * 1000;
    let last = parse_date("2026-11-18").unwrap() * 1000 + ROWS_PER_DAY - 1;
    let ids = measurements.column("cw_id").unwrap().i64().unwrap().clone();
    assert_eq!(ids.get(0), Some(first));
    assert_eq!(ids.get(ids.len() - 1), Some(last));
    let selection = read(&out.join("selection.parquet"));
    let roles = selection.column("role").unwrap().str().unwrap().clone();
    let validation = roles.iter().filter(|r| *r == Some("validation")).count();
    assert_eq!(
        validation, ROWS_PER_DAY as usize,
        "the newest day is held out"
    );
    // 40 files of 2 robots: all but r1's five days pruned without opening them.
    assert!(
        stdout.contains("35 pruned by partition, 5 read"),
        "{stdout}"
    );
}

#[test]
fn bad_rows_duplicates_and_corrupt_files_are_counted_or_fail() {
    let dir = tempfile::tempdir().unwrap();
    let logs = log_folder(dir.path());
    let day = logs.join("robot_id=r1/date=2026-11-17");
    // A re-delivered copy of a file, a NaN reading and a file that is not Parquet.
    std::fs::copy(day.join("part-0.parquet"), day.join("part-0-copy.parquet")).unwrap();
    let mut glitch = day_rows("r1", "2026-11-16");
    let x = glitch.column("x_mm").unwrap().f64().unwrap().clone();
    let broken: Vec<f64> = x
        .iter()
        .enumerate()
        .map(|(i, v)| if i == 3 { f64::NAN } else { v.unwrap() })
        .collect();
    glitch
        .replace("x_mm", Column::new("x_mm".into(), broken))
        .unwrap();
    write(
        &mut glitch,
        &logs.join("robot_id=r1/date=2026-11-16/part-0.parquet"),
    );
    std::fs::write(day.join("part-1.parquet"), b"half a file").unwrap();

    let settings = format!(
        "logs = \"{}\"\nrobot_id = \"r1\"\nlast = \"5d\"\n",
        logs.display()
    );
    let (code, stdout, stderr, out) = scan(dir.path(), &settings, "2026-11-18");
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("dropped: duplicate cw_id = 10"), "{stdout}");
    assert!(stdout.contains("dropped: non-finite x_mm = 1"), "{stdout}");
    assert!(
        stdout.contains("part-1.parquet"),
        "corrupt file named: {stdout}"
    );
    let measurements = read(&out.join("measurements.parquet"));
    assert_eq!(measurements.height(), 5 * ROWS_PER_DAY as usize - 1);

    let strict = format!("{settings}bad_data = \"fail\"\n");
    let (code, _, stderr, _) = scan(dir.path(), &strict, "2026-11-18");
    assert_ne!(code, 0);
    assert!(
        stderr.contains("part-1.parquet") && stderr.contains("not a readable Parquet file"),
        "{stderr}"
    );
    std::fs::remove_file(day.join("part-1.parquet")).unwrap();
    let (code, _, stderr, _) = scan(dir.path(), &strict, "2026-11-18");
    assert_ne!(code, 0);
    assert!(
        stderr.contains("11 logged rows fail the measurements contract")
            && stderr.contains("non-finite x_mm (cw_id"),
        "{stderr}"
    );
}

#[test]
fn empty_or_small_windows_fail_with_the_reason() {
    let dir = tempfile::tempdir().unwrap();
    let logs = log_folder(dir.path());
    let (code, _, stderr, _) = scan(
        dir.path(),
        &format!("logs = \"{}\"\nrobot_id = \"r3\"\n", logs.display()),
        "2026-11-18",
    );
    assert_ne!(code, 0);
    assert!(
        stderr.contains("no logged rows of robot `r3` in 2026-11-05 .. 2026-11-18"),
        "{stderr}"
    );
    // Files without partition folders are opened; the message names the robots they hold.
    let flat = dir.path().join("flat");
    write(&mut day_rows("r2", "2026-11-10"), &flat.join("a.parquet"));
    let (code, _, stderr, _) = scan(
        dir.path(),
        &format!("logs = \"{}\"\nrobot_id = \"r1\"\n", flat.display()),
        "2026-11-18",
    );
    assert_ne!(code, 0);
    assert!(stderr.contains("hold robot(s) r2"), "{stderr}");
    let (code, _, stderr, _) = scan(
        dir.path(),
        &format!(
            "logs = \"{}\"\nrobot_id = \"r1\"\nlast = \"3d\"\n",
            logs.display()
        ),
        "2026-11-18",
    );
    assert_ne!(code, 0);
    assert!(
        stderr.contains("20 identification rows") && stderr.contains("min_rows = 30"),
        "{stderr}"
    );
}

#[test]
fn cache_key_follows_new_files_and_the_run_date() {
    let dir = tempfile::tempdir().unwrap();
    let logs = log_folder(dir.path());
    let job = dir.path().join("nightly.toml");
    std::fs::write(
        &job,
        format!(
            "[job]\nname = \"n\"\nrobot = \"{}\"\n\n[[stages]]\nid = \"logs\"\nkind = \"scan_logs\"\nlogs = \"logs\"\nrobot_id = \"r1\"\nlast = \"5d\"\n",
            common::root().join("jobs/robots/irb1600_145.toml").display()
        ),
    )
    .unwrap();
    let run = |date: &str| {
        let (code, stdout, stderr) = common::run(
            &["run", job.to_str().unwrap(), "--run-date", date],
            dir.path(),
        );
        assert_eq!(code, 0, "{stderr}");
        stdout + &stderr
    };
    assert!(run("2026-11-18").contains("1 ran"));
    assert!(run("2026-11-18").contains("1 cached"));
    assert!(run("2026-11-19").contains("1 ran"), "a new night re-runs");
    write(
        &mut day_rows("r1", "2026-11-19"),
        &logs.join("robot_id=r1/date=2026-11-19/part-1.parquet"),
    );
    assert!(
        run("2026-11-19").contains("1 ran"),
        "a new log file re-runs"
    );
    // A file of another robot's partition is not part of this stage's input.
    write(
        &mut day_rows("r2", "2026-11-19"),
        &logs.join("robot_id=r2/date=2026-11-19/part-1.parquet"),
    );
    assert!(run("2026-11-19").contains("1 cached"));
}

#[test]
fn a_fifo_or_unreadable_log_file_is_a_bad_file_not_a_hang() {
    let dir = tempfile::tempdir().unwrap();
    let logs = log_folder(dir.path());
    let day = logs.join("robot_id=r1/date=2026-11-17");
    let fifo = day.join("part-1.parquet");
    let made = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap();
    assert!(made.success());
    let settings = format!(
        "logs = \"{}\"\nrobot_id = \"r1\"\nlast = \"5d\"\n",
        logs.display()
    );
    let (code, stdout, stderr, _) = scan(dir.path(), &settings, "2026-11-18");
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains("part-1.parquet") && stdout.contains("FIFO"),
        "{stdout}"
    );
    let strict = format!("{settings}bad_data = \"fail\"\n");
    let (code, _, stderr, _) = scan(dir.path(), &strict, "2026-11-18");
    assert_eq!(code, 3, "{stderr}");
    assert!(
        stderr.contains("part-1.parquet") && stderr.contains("FIFO"),
        "{stderr}"
    );
    std::fs::remove_file(&fifo).unwrap();

    // Permission denied (not testable as root, who reads anything).
    let locked = day.join("part-2.parquet");
    std::fs::copy(day.join("part-0.parquet"), &locked).unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&locked, std::fs::Permissions::from_mode(0o000)).unwrap();
    if std::fs::File::open(&locked).is_ok() {
        eprintln!("skipped the permission check: this user reads a mode-000 file");
        return;
    }
    let (code, _, stderr, _) = scan(dir.path(), &strict, "2026-11-18");
    assert_eq!(code, 3, "{stderr}");
    assert!(
        stderr.contains("part-2.parquet") && stderr.contains("ermission denied"),
        "{stderr}"
    );
}
