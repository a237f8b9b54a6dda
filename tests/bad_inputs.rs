//! The bad-input corpus: every case under `tests/bad_inputs/` is one TOML file
//! holding the input (job file, robot file, tables as CSV, a scripted driver),
//! the commands to run, and for each the expected exit code and the words its
//! stderr (or stdout) must contain. Whatever a case feeds egcal, it must end in
//! that clear error or that accepted result: never a panic, an abort, a signal or
//! a hang.
//!
//! Case format:
//!
//! ```toml
//! about = "what the case checks"
//! [files]                 # written into the case folder
//! "job.toml" = '''...'''
//! [derived."arm.toml"]    # a repository file with text replaced (each `old` must occur)
//! from = "jobs/robots/irb1600_145.toml"
//! replace = [["d_mm = 486.5", "d_mm = nan"]]
//! [tables]                # CSV text, written as Parquet (unit-suffixed columns as f64,
//!                         # `measured_at` as a UTC µs timestamp from `2026-11-01T08:00:00`)
//! "rows.parquet" = '''cw_id,q1_deg,...'''
//! [links]                 # symbolic links, made last: name = target (as written)
//! "logs/loop" = "."
//! [[step]]
//! args = ["check", "job.toml"]
//! exit = 2
//! stderr = ["job.toml:7", "edge_mm"]   # words that must appear
//! stdout = []                          # optional
//! unchanged = ["out/table.parquet"]    # optional: files or folders an earlier
//!                                      # step wrote, byte-identical after this one
//! ```
//!
//! Each case runs in its own temporary folder, which also holds `robots/`,
//! `cdpr/` and `truth/` (the shipped files under `jobs/`) and
//! `scripted_driver.py`, a lab driver that misbehaves on request.

mod common;

use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::{Duration, Instant};

use polars::prelude::{CsvReadOptions, DataType, SerReader, TimeUnit, TimeZone};
use serde::Deserialize;

/// Longer than any case needs; a step still running then counts as a hang.
const STEP_TIMEOUT: Duration = Duration::from_secs(120);

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Case {
    about: String,
    #[serde(default)]
    files: BTreeMap<String, String>,
    #[serde(default)]
    derived: BTreeMap<String, Derived>,
    #[serde(default)]
    tables: BTreeMap<String, String>,
    #[serde(default)]
    links: BTreeMap<String, String>,
    step: Vec<Step>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Derived {
    from: String,
    replace: Vec<(String, String)>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Step {
    args: Vec<String>,
    exit: i32,
    #[serde(default)]
    stderr: Vec<String>,
    #[serde(default)]
    stdout: Vec<String>,
    /// Files or folders (relative to the case folder) that this step must leave
    /// byte for byte as it found them: a bad input damages nothing already written.
    #[serde(default)]
    unchanged: Vec<String>,
}

/// Every file under `path` (or `path` itself) with its bytes, sorted by path.
fn snapshot(path: &Path) -> Result<Vec<(PathBuf, Vec<u8>)>, String> {
    let meta = std::fs::symlink_metadata(path).map_err(|e| format!("{}: {e}", path.display()))?;
    if meta.is_file() {
        let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
        return Ok(vec![(path.to_path_buf(), bytes)]);
    }
    if !meta.is_dir() {
        return Ok(Vec::new());
    }
    let mut entries: Vec<PathBuf> = std::fs::read_dir(path)
        .map_err(|e| format!("{}: {e}", path.display()))?
        .flatten()
        .map(|e| e.path())
        .collect();
    entries.sort();
    let mut all = Vec::new();
    for entry in entries {
        all.extend(snapshot(&entry)?);
    }
    Ok(all)
}

fn cases() -> Vec<PathBuf> {
    let dir = common::root().join("tests/bad_inputs");
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&dir)
        .expect("tests/bad_inputs exists")
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    // `BAD_INPUT_CASE=word cargo test --test bad_inputs` runs the cases whose
    // file name contains `word` (the full corpus still runs without it).
    if let Ok(word) = std::env::var("BAD_INPUT_CASE") {
        paths.retain(|p| p.to_string_lossy().contains(word.as_str()));
    }
    paths.sort();
    paths
}

/// Writes a CSV text as Parquet; columns named with a unit suffix become f64 so
/// that a case can write `nan`, `inf` or `1e300` where a number belongs.
fn write_table(csv: &str, path: &Path) {
    let mut df = CsvReadOptions::default()
        .with_infer_schema_length(None)
        .into_reader_with_file_handle(std::io::Cursor::new(csv.as_bytes().to_vec()))
        .finish()
        .unwrap_or_else(|e| panic!("{}: table is not CSV: {e}", path.display()));
    let float_columns: Vec<String> = df
        .get_column_names()
        .iter()
        .map(|n| n.to_string())
        .filter(|n| ["_deg", "_n", "_nm", "_mm"].iter().any(|s| n.ends_with(s)))
        .collect();
    for name in float_columns {
        let cast = df
            .column(&name)
            .expect("column listed")
            .cast(&DataType::Float64)
            .expect("casts to f64");
        df.with_column(cast).expect("same length");
    }
    if let Ok(stamps) = df.column("measured_at") {
        let utc = DataType::Datetime(TimeUnit::Microseconds, Some(TimeZone::UTC));
        let cast = stamps
            .cast(&DataType::Datetime(TimeUnit::Microseconds, None))
            .and_then(|c| c.cast(&utc))
            .unwrap_or_else(|e| panic!("{}: measured_at is not a timestamp: {e}", path.display()));
        df.with_column(cast).expect("same length");
    }
    std::fs::create_dir_all(path.parent().expect("in the case folder")).expect("mkdir");
    egcal::table::write_parquet(&mut df, path, None).expect("write table");
}

fn prepare(case: &Case, dir: &Path) {
    let jobs = common::root().join("jobs");
    for shared in ["robots", "cdpr", "truth"] {
        std::os::unix::fs::symlink(jobs.join(shared), dir.join(shared)).expect("link");
    }
    std::fs::copy(
        common::root().join("tests/bad_inputs/scripted_driver.py"),
        dir.join("scripted_driver.py"),
    )
    .expect("copy the scripted driver");
    for (name, text) in &case.files {
        let path = dir.join(name);
        std::fs::create_dir_all(path.parent().expect("in the case folder")).expect("mkdir");
        std::fs::write(&path, text).expect("write case file");
        if name.ends_with(".sh") || name.ends_with(".py") {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755)).expect("chmod");
        }
    }
    for (name, derived) in &case.derived {
        let mut text = std::fs::read_to_string(common::root().join(&derived.from))
            .unwrap_or_else(|e| panic!("{}: {e}", derived.from));
        for (old, new) in &derived.replace {
            assert!(
                text.contains(old.as_str()),
                "{}: no `{old}` to replace",
                derived.from
            );
            text = text.replacen(old.as_str(), new, 1);
        }
        std::fs::write(dir.join(name), text).expect("write derived file");
    }
    for (name, csv) in &case.tables {
        write_table(csv, &dir.join(name));
    }
    for (name, target) in &case.links {
        let path = dir.join(name);
        std::fs::create_dir_all(path.parent().expect("in the case folder")).expect("mkdir");
        std::os::unix::fs::symlink(target, &path).expect("make the link");
    }
}

/// Runs one step with a time limit: (exit code or a description of how it
/// ended, stdout, stderr).
fn run_step(args: &[String], dir: &Path) -> (Result<i32, String>, String, String) {
    let mut child = common::egcal()
        .args(args)
        .current_dir(dir)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("egcal starts");
    let mut stdout_pipe = child.stdout.take().expect("piped");
    let mut stderr_pipe = child.stderr.take().expect("piped");
    let out = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = stdout_pipe.read_to_string(&mut s);
        s
    });
    let err = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = stderr_pipe.read_to_string(&mut s);
        s
    });
    let started = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait") {
            break Ok(status);
        }
        if started.elapsed() > STEP_TIMEOUT {
            let _ = child.kill();
            let _ = child.wait();
            break Err(format!("hung for more than {STEP_TIMEOUT:?}"));
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let stdout = out.join().unwrap_or_default();
    let stderr = err.join().unwrap_or_default();
    let code = status.and_then(|s| {
        use std::os::unix::process::ExitStatusExt;
        match (s.code(), s.signal()) {
            (Some(code), _) => Ok(code),
            (None, Some(signal)) => Err(format!("killed by signal {signal}")),
            (None, None) => Err("ended without a status".into()),
        }
    });
    (code, stdout, stderr)
}

/// Problems with one case, empty when it passes.
fn check_case(path: &Path) -> Vec<String> {
    let name = path.file_name().unwrap_or_default().to_string_lossy();
    let text = std::fs::read_to_string(path).expect("read case");
    let case: Case = match toml::from_str(&text) {
        Ok(c) => c,
        Err(e) => return vec![format!("{name}: malformed case file: {e}")],
    };
    let dir = tempfile::tempdir().expect("tempdir");
    prepare(&case, dir.path());
    let mut problems = Vec::new();
    for (i, step) in case.step.iter().enumerate() {
        let label = format!("{name} ({}) step {i} `{}`", case.about, step.args.join(" "));
        let mut before = Vec::new();
        for kept in &step.unchanged {
            match snapshot(&dir.path().join(kept)) {
                Ok(files) if !files.is_empty() => before.push((kept, files)),
                Ok(_) => problems.push(format!(
                    "{label}: `unchanged` names {kept}, which holds no file before the step"
                )),
                Err(e) => problems.push(format!(
                    "{label}: `unchanged` names {kept}, which is not there before the step: {e}"
                )),
            }
        }
        let (code, stdout, stderr) = run_step(&step.args, dir.path());
        for (kept, files) in &before {
            match snapshot(&dir.path().join(kept)) {
                Ok(after) if &after == files => {}
                Ok(_) => problems.push(format!(
                    "{label}: {kept} was changed by a step that had to leave it alone"
                )),
                Err(e) => problems.push(format!("{label}: {kept} is gone after the step: {e}")),
            }
        }
        match code {
            Ok(code) if code == step.exit => {}
            Ok(code) => problems.push(format!(
                "{label}: exit {code}, expected {}\n--- stderr:\n{stderr}--- stdout:\n{stdout}",
                step.exit
            )),
            Err(how) => problems.push(format!("{label}: {how}\n--- stderr:\n{stderr}")),
        }
        if stderr.contains("panicked") || stderr.contains("RUST_BACKTRACE") {
            problems.push(format!("{label}: panicked\n{stderr}"));
        }
        for word in &step.stderr {
            if !stderr.contains(word.as_str()) {
                problems.push(format!(
                    "{label}: stderr lacks {word:?}\n--- stderr:\n{stderr}"
                ));
            }
        }
        for word in &step.stdout {
            if !stdout.contains(word.as_str()) {
                problems.push(format!(
                    "{label}: stdout lacks {word:?}\n--- stdout:\n{stdout}"
                ));
            }
        }
    }
    problems
}

#[test]
fn every_bad_input_ends_in_a_clear_error() {
    let cases = cases();
    assert!(
        cases.len() >= 20 || std::env::var("BAD_INPUT_CASE").is_ok(),
        "the corpus shrank: {} cases",
        cases.len()
    );
    // Two workers: cases are mostly short processes.
    let (first, second) = cases.split_at(cases.len() / 2);
    let worker = |paths: Vec<PathBuf>| {
        std::thread::spawn(move || -> Vec<String> {
            paths.iter().flat_map(|p| check_case(p)).collect()
        })
    };
    let a = worker(first.to_vec());
    let b = worker(second.to_vec());
    let mut problems = a.join().expect("worker");
    problems.extend(b.join().expect("worker"));
    assert!(
        problems.is_empty(),
        "{} of {} cases fall short:\n\n{}",
        problems.len(),
        cases.len(),
        problems.join("\n\n")
    );
}

/// `egcal list-stages | head` closes the pipe before egcal writes: the result
/// stands and nothing panics.
#[test]
fn a_reader_that_stops_early_is_not_an_error() {
    let mut child = common::egcal()
        .arg("list-stages")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("egcal starts");
    drop(child.stdout.take());
    let output = child.wait_with_output().expect("egcal ends");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(0), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}
