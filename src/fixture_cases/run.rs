//! Finding cases and running them: each case is one `egcal stage` process (the
//! same binary), run in the case folder with its output in a private work
//! folder, so a case sees exactly what a user's command line sees (exit code,
//! error text, facts) and a case that crashes or hangs fails alone.

use std::fs::File;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use super::case::{self, Case, Malformed};
use super::{FixtureError, compare};

/// What `egcal test` runs and how.
#[derive(Debug, Clone)]
pub struct TestOptions {
    /// Folders searched for `case.toml` (a folder may be one case).
    pub dirs: Vec<PathBuf>,
    /// Only cases whose name matches one of these (a glob, or a plain substring).
    pub only: Vec<String>,
    /// Cases run at once.
    pub jobs: usize,
    /// The egcal binary that runs each stage.
    pub egcal: PathBuf,
    /// A case still running after this long is killed and fails.
    pub timeout: Duration,
}

/// How a case ended.
#[derive(Debug, Clone, PartialEq)]
pub enum Outcome {
    Passed,
    /// What differed from the expectation.
    Failed(String),
    /// The case file cannot be run as written.
    Malformed(Malformed),
}

/// One case's result.
#[derive(Debug, Clone)]
pub struct CaseResult {
    /// The case folder as found under the searched folder (`fixtures/identify/x`).
    pub name: String,
    /// Stage kind; unknown for a malformed case that does not name one.
    pub kind: Option<String>,
    pub recorded: bool,
    pub outcome: Outcome,
    pub seconds: f64,
    /// The stage's output, kept for the JUnit report.
    pub stdout: String,
    pub stderr: String,
}

/// Every case's result, sorted by name.
#[derive(Debug, Clone)]
pub struct Summary {
    pub results: Vec<CaseResult>,
    pub seconds: f64,
}

impl Summary {
    fn count(&self, f: impl Fn(&Outcome) -> bool) -> usize {
        self.results.iter().filter(|r| f(&r.outcome)).count()
    }
    pub fn passed(&self) -> usize {
        self.count(|o| matches!(o, Outcome::Passed))
    }
    pub fn failed(&self) -> usize {
        self.count(|o| matches!(o, Outcome::Failed(_)))
    }
    pub fn malformed(&self) -> usize {
        self.count(|o| matches!(o, Outcome::Malformed(_)))
    }

    /// 2 when a case file is malformed, 1 when a case failed, else 0.
    pub fn exit_code(&self) -> u8 {
        if self.malformed() > 0 {
            2
        } else if self.failed() > 0 {
            1
        } else {
            0
        }
    }

    /// The failures in full, then `N passed, N failed[, N malformed]`.
    pub fn report(&self) -> String {
        let mut text = String::new();
        for result in &self.results {
            let detail = match &result.outcome {
                Outcome::Passed => continue,
                Outcome::Failed(why) => why.clone(),
                Outcome::Malformed(e) => e.to_string(),
            };
            text.push_str(&format!("\n---- {} ----\n{detail}\n", result.name));
        }
        let recorded = self
            .results
            .iter()
            .filter(|r| r.recorded && r.outcome == Outcome::Passed)
            .count();
        text.push_str(&format!(
            "\n{} passed{}, {} failed",
            self.passed(),
            if recorded > 0 {
                format!(" ({recorded} recorded from egcal)")
            } else {
                String::new()
            },
            self.failed()
        ));
        if self.malformed() > 0 {
            text.push_str(&format!(", {} malformed", self.malformed()));
        }
        text.push_str(&format!(" in {:.2} s", self.seconds));
        text
    }
}

/// A case folder found under a searched folder.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub struct Found {
    /// As found: the searched folder joined with the path below it.
    pub dir: PathBuf,
    /// The path below the searched folder (`identify/noiseless_truth`); the
    /// folder's own name when the searched folder is the case.
    pub relative: String,
}

/// The case folders under `dirs` (folders holding `case.toml`; not searched
/// below a case; symbolic links followed once), sorted.
pub fn discover(dirs: &[PathBuf]) -> Result<Vec<Found>, FixtureError> {
    let mut found = Vec::new();
    let mut visited = std::collections::HashSet::new();
    for dir in dirs {
        if !dir.is_dir() {
            return Err(FixtureError::Usage(format!(
                "{}: no such folder of fixture cases",
                dir.display()
            )));
        }
        walk(dir, dir, &mut visited, &mut found)?;
    }
    found.sort();
    found.dedup_by(|a, b| a.dir == b.dir);
    Ok(found)
}

fn walk(
    root: &Path,
    dir: &Path,
    visited: &mut std::collections::HashSet<PathBuf>,
    found: &mut Vec<Found>,
) -> Result<(), FixtureError> {
    let cannot =
        |e: std::io::Error| FixtureError::Usage(format!("{}: cannot list: {e}", dir.display()));
    // A link back up the tree is entered once.
    if !visited.insert(std::fs::canonicalize(dir).map_err(cannot)?) {
        return Ok(());
    }
    if dir.join("case.toml").is_file() {
        let relative = match dir.strip_prefix(root) {
            Ok(below) if !below.as_os_str().is_empty() => below.display().to_string(),
            _ => dir.file_name().map_or_else(
                || dir.display().to_string(),
                |n| n.to_string_lossy().into_owned(),
            ),
        };
        found.push(Found {
            dir: dir.to_path_buf(),
            relative,
        });
        return Ok(());
    }
    let mut subdirs = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(cannot)? {
        let path = entry.map_err(cannot)?.path();
        let hidden = path
            .file_name()
            .is_some_and(|n| n.to_string_lossy().starts_with('.'));
        if path.is_dir() && !hidden {
            subdirs.push(path);
        }
    }
    subdirs.sort();
    for sub in subdirs {
        walk(root, &sub, visited, found)?;
    }
    Ok(())
}

/// Whether a case matches `--only`: a glob when it has `*`, `?` or `[`, else a
/// substring, against the case folder as found or its path below the searched
/// folder.
fn selected(case: &Found, only: &[glob::Pattern], plain: &[&str]) -> bool {
    let names = [case.dir.display().to_string(), case.relative.clone()];
    (only.is_empty() && plain.is_empty())
        || names.iter().any(|name| {
            only.iter().any(|p| p.matches(name)) || plain.iter().any(|p| name.contains(p))
        })
}

/// Runs the cases; `on_result` sees each result as it ends (from worker threads).
pub fn run(
    options: &TestOptions,
    on_result: &(dyn Fn(&CaseResult) + Sync),
) -> Result<Summary, FixtureError> {
    let started = Instant::now();
    let mut globs = Vec::new();
    let mut plain = Vec::new();
    for pattern in &options.only {
        if pattern.contains(['*', '?', '[']) {
            globs.push(glob::Pattern::new(pattern).map_err(|e| {
                FixtureError::Usage(format!("--only `{pattern}`: not a glob pattern: {e}"))
            })?);
        } else {
            plain.push(pattern.as_str());
        }
    }
    let cases: Vec<PathBuf> = discover(&options.dirs)?
        .into_iter()
        .filter(|case| selected(case, &globs, &plain))
        .map(|case| case.dir)
        .collect();
    if cases.is_empty() {
        return Err(FixtureError::Usage(format!(
            "no fixture case (a folder with case.toml) under {}{}",
            options
                .dirs
                .iter()
                .map(|d| d.display().to_string())
                .collect::<Vec<_>>()
                .join(", "),
            if options.only.is_empty() {
                String::new()
            } else {
                format!(" matches --only {}", options.only.join(", "))
            }
        )));
    }
    let work = WorkFolder::create()?;
    let next = AtomicUsize::new(0);
    let results = Mutex::new(Vec::with_capacity(cases.len()));
    std::thread::scope(|scope| {
        for _ in 0..options.jobs.clamp(1, cases.len()) {
            scope.spawn(|| {
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some(dir) = cases.get(i) else { break };
                    let result = run_one(dir, options, &work.path.join(i.to_string()));
                    on_result(&result);
                    results.lock().expect("no worker panics").push(result);
                }
            });
        }
    });
    let mut results = results.into_inner().expect("no worker panics");
    results.sort_by(|a, b| a.name.cmp(&b.name));
    Ok(Summary {
        results,
        seconds: started.elapsed().as_secs_f64(),
    })
}

fn run_one(dir: &Path, options: &TestOptions, work: &Path) -> CaseResult {
    let started = Instant::now();
    let name = dir.display().to_string();
    let case = match case::load(dir) {
        Ok(case) => case,
        Err(e) => {
            return CaseResult {
                name,
                kind: None,
                recorded: false,
                outcome: Outcome::Malformed(e),
                seconds: started.elapsed().as_secs_f64(),
                stdout: String::new(),
                stderr: String::new(),
            };
        }
    };
    let ran = run_stage(&case, &options.egcal, options.timeout, work);
    let outcome = judge(&case, &ran, &work.join("out"));
    let _ = std::fs::remove_dir_all(work);
    CaseResult {
        name,
        kind: Some(case.kind.clone()),
        recorded: case.recorded,
        outcome,
        seconds: started.elapsed().as_secs_f64(),
        stdout: ran.stdout,
        stderr: ran.stderr,
    }
}

/// What the stage process did.
pub(super) struct Ran {
    /// Exit code; `Err` when the stage could not be started, was killed or
    /// timed out.
    pub code: Result<i32, String>,
    pub stdout: String,
    pub stderr: String,
}

/// Runs the case's stage into `work/out`.
pub(super) fn run_stage(case: &Case, egcal: &Path, timeout: Duration, work: &Path) -> Ran {
    let (mut stdout, mut stderr) = (String::new(), String::new());
    let code = start_and_wait(case, egcal, timeout, work, &mut stdout, &mut stderr);
    Ran {
        code,
        stdout,
        stderr,
    }
}

/// Starts the stage, waits for it, and reads its output (also that of a stage
/// killed at the timeout).
fn start_and_wait(
    case: &Case,
    egcal: &Path,
    timeout: Duration,
    work: &Path,
    stdout: &mut String,
    stderr: &mut String,
) -> Result<i32, String> {
    let out = work.join("out");
    std::fs::create_dir_all(&out).map_err(|e| format!("cannot create {}: {e}", out.display()))?;
    let settings = work.join("settings.toml");
    let text = toml::to_string(&case.settings).map_err(|e| format!("settings: {e}"))?;
    std::fs::write(&settings, text).map_err(|e| format!("{}: {e}", settings.display()))?;
    let mut command = Command::new(egcal);
    command
        .arg("stage")
        .arg(&case.kind)
        .arg("--robot")
        .arg(absolute(&case.robot_file))
        .arg("--settings")
        .arg(&settings)
        .arg("--out")
        .arg(&out)
        .arg("--seed")
        .arg(case.seed.to_string());
    if let Some(file) = &case.cable_robot_file {
        command.arg("--cable-robot").arg(absolute(file));
    }
    if let Some(day) = &case.run_date {
        command.arg("--run-date").arg(day);
    }
    for (name, file) in &case.inputs {
        command
            .arg("--input")
            .arg(format!("{name}={}", absolute(file).display()));
    }
    let stdout_file = work.join("stdout");
    let stderr_file = work.join("stderr");
    let open = |path: &Path| File::create(path).map_err(|e| format!("{}: {e}", path.display()));
    // Its own process group, so a timeout also stops what the stage started
    // (a lab driver).
    let child = command
        .current_dir(&case.dir)
        .env("NO_COLOR", "1")
        .stdin(Stdio::null())
        .stdout(open(&stdout_file)?)
        .stderr(open(&stderr_file)?)
        .process_group(0)
        .spawn()
        .map_err(|e| format!("cannot start {}: {e}", egcal.display()))?;
    let status = wait(child, timeout);
    let read = |path: &Path| {
        std::fs::read(path)
            .map(|b| String::from_utf8_lossy(&b).into_owned())
            .unwrap_or_default()
    };
    *stdout = read(&stdout_file);
    *stderr = read(&stderr_file);
    let status = status?;
    status
        .code()
        .ok_or_else(|| format!("the stage was killed ({status})"))
}

/// SIGKILL to the child's process group (std has no call for a group; `kill`
/// is part of every Linux base system), the child alone if that fails.
fn kill_group(child: &mut Child) {
    let group = format!("-{}", child.id());
    let killed = Command::new("kill")
        .args(["-s", "KILL", "--", &group])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !killed {
        let _ = child.kill();
    }
}

fn absolute(path: &Path) -> PathBuf {
    std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf())
}

/// Waits for the stage, killing its process group after `timeout`.
fn wait(mut child: Child, timeout: Duration) -> Result<ExitStatus, String> {
    let started = Instant::now();
    loop {
        match child.try_wait() {
            Ok(Some(status)) => return Ok(status),
            Ok(None) if started.elapsed() >= timeout => {
                kill_group(&mut child);
                return Err(format!(
                    "still running after {} s (--timeout-s): killed",
                    timeout.as_secs()
                ));
            }
            Ok(None) => std::thread::sleep(Duration::from_millis(10)),
            Err(e) => return Err(format!("cannot wait for the stage: {e}")),
        }
    }
}

/// The case's expectations against what the stage did.
pub(super) fn judge(case: &Case, ran: &Ran, out: &Path) -> Outcome {
    match check_expectations(case, ran, out) {
        Ok(()) => Outcome::Passed,
        Err(why) => Outcome::Failed(why),
    }
}

/// Rust's exit code of a panic: a bug, never the error a case expects.
const PANIC_EXIT: i32 = 101;

fn check_expectations(case: &Case, ran: &Ran, out: &Path) -> Result<(), String> {
    let expect = &case.expect;
    let stderr = ran.stderr.trim_end();
    let code = *ran
        .code
        .as_ref()
        .map_err(|why| format!("{why}\n{stderr}").trim_end().to_string())?;
    if code == PANIC_EXIT || ran.stderr.contains("panicked at") {
        return Err(format!("the stage panicked (exit {code}):\n{stderr}"));
    }
    if let Some(error) = &expect.error {
        let decided = [
            i32::from(crate::exit_code::GATE_PUBLISHED),
            i32::from(crate::exit_code::GATE_REFUSED),
        ];
        if code == 0 || (expect.exit.is_none() && decided.contains(&code)) {
            return Err(format!(
                "expected an error containing {:?}, but the stage succeeded (exit {code}):\n{}",
                error.all(),
                ran.stdout.trim_end()
            ));
        }
        if let Some(exit) = expect.exit
            && code != i32::from(exit)
        {
            return Err(format!("exit {code}, expected {exit}:\n{stderr}"));
        }
        let lacking = missing(&ran.stderr, error.all());
        if !lacking.is_empty() {
            return Err(format!("the error lacks {lacking:?}:\n{stderr}"));
        }
    } else {
        let exit = expect.exit.unwrap_or(0);
        if code != i32::from(exit) {
            return Err(format!("exit {code}, expected {exit}:\n{stderr}"));
        }
    }
    let mut problems = Vec::new();
    if let Some(tolerance) = expect.tolerance {
        for (name, want) in &case.expected_tables {
            let actual = out.join(format!("{name}.parquet"));
            if !actual.is_file() {
                problems.push(format!(
                    "table `{name}`: the stage wrote no {name}.parquet (it wrote: {})",
                    written_tables(out)
                ));
                continue;
            }
            match crate::table::read_parquet(&actual) {
                Ok(got) => problems.extend(compare::differences(name, want, &got, tolerance)),
                Err(e) => problems.push(format!("table `{name}`: {e}")),
            }
        }
    }
    if let Some(file) = &expect.file {
        match std::fs::read_to_string(out.join(file)) {
            Ok(text) => {
                let lacking = missing(&text, &expect.contains);
                if !lacking.is_empty() {
                    problems.push(format!("{file} lacks {lacking:?}"));
                }
            }
            Err(e) => problems.push(format!("the stage wrote no readable {file}: {e}")),
        }
    }
    let lacking = missing(&ran.stdout, &expect.stdout);
    if !lacking.is_empty() {
        problems.push(format!(
            "the output lacks {lacking:?}:\n{}",
            ran.stdout.trim_end()
        ));
    }
    if problems.is_empty() {
        Ok(())
    } else {
        Err(problems.join("\n"))
    }
}

fn written_tables(out: &Path) -> String {
    let mut names: Vec<String> = std::fs::read_dir(out)
        .map(|entries| {
            entries
                .flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.ends_with(".parquet"))
                .collect()
        })
        .unwrap_or_default();
    names.sort();
    if names.is_empty() {
        "none".into()
    } else {
        names.join(", ")
    }
}

/// The strings of `wanted` that `text` lacks.
fn missing<'a>(text: &str, wanted: &'a [String]) -> Vec<&'a str> {
    wanted
        .iter()
        .filter(|w| !text.contains(w.as_str()))
        .map(String::as_str)
        .collect()
}

/// This process's folder for the cases' outputs, in the system's temporary
/// folder (`egcal-test-<pid>`); work folders of killed runs are removed first.
pub(super) struct WorkFolder {
    pub path: PathBuf,
}

impl WorkFolder {
    pub fn create() -> Result<WorkFolder, FixtureError> {
        let tmp = std::env::temp_dir();
        let _ = crate::fsio::sweep::sweep_work_folders(&tmp);
        let path = tmp.join(crate::fsio::sweep::test_temp_name());
        std::fs::create_dir_all(&path)
            .map_err(|e| FixtureError::Usage(format!("cannot create {}: {e}", path.display())))?;
        Ok(WorkFolder { path })
    }
}

impl Drop for WorkFolder {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.path);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn found(dir: &str, relative: &str) -> Found {
        Found {
            dir: dir.into(),
            relative: relative.into(),
        }
    }

    #[test]
    fn only_takes_globs_and_substrings_of_either_name() {
        let globs = [glob::Pattern::new("identify/*").unwrap()];
        assert!(selected(
            &found("cases/cell7/identify/a", "identify/a"),
            &globs,
            &[]
        ));
        assert!(!selected(&found("cases/gate/a", "gate/a"), &globs, &[]));
        let full = [glob::Pattern::new("./fixtures/identify/*").unwrap()];
        assert!(selected(
            &found("./fixtures/identify/a", "identify/a"),
            &full,
            &[]
        ));
        assert!(selected(
            &found("f/gate/bad_alpha", "gate/bad_alpha"),
            &[],
            &["bad_"]
        ));
        assert!(selected(&found("anything", "anything"), &[], &[]));
    }

    #[test]
    fn discovery_stops_at_a_case_and_skips_hidden_folders() {
        let root = tempfile::tempdir().unwrap();
        for dir in ["a/one", "a/one/logs", "b/two", ".hidden/three"] {
            std::fs::create_dir_all(root.path().join(dir)).unwrap();
        }
        for case in ["a/one", "a/one/logs", "b/two", ".hidden/three"] {
            std::fs::write(root.path().join(case).join("case.toml"), "").unwrap();
        }
        let found = discover(&[root.path().to_path_buf()]).unwrap();
        let names: Vec<_> = found.iter().map(|f| f.relative.as_str()).collect();
        assert_eq!(names, ["a/one", "b/two"]);
        // A link to a folder is followed, a link back up the tree once.
        std::os::unix::fs::symlink(root.path().join("b"), root.path().join("c")).unwrap();
        std::os::unix::fs::symlink(root.path(), root.path().join("b/up")).unwrap();
        let found = discover(&[root.path().to_path_buf()]).unwrap();
        let names: Vec<_> = found.iter().map(|f| f.relative.as_str()).collect();
        assert_eq!(names, ["a/one", "b/two"]);
        let linked = discover(&[root.path().join("c")]).unwrap();
        assert_eq!(linked[0].relative, "two");
        assert!(discover(&[root.path().join("nope")]).is_err());
    }
}
