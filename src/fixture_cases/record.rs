//! `egcal test record`: freezes today's output of a stage on a lab's own files
//! as a fixture case. The case is built in a hidden temporary folder beside its
//! destination (inputs copied, the stage run from the copies, its tables stored
//! as `expected/`), then run once more as `egcal test` would run it, and only
//! then renamed into place: a killed recording leaves no half case, and a case
//! that would not pass (a setting naming a file that was not copied, a stage
//! whose output changes from run to run) is never written.

use std::path::{Component, Path, PathBuf};
use std::time::Duration;

use super::FixtureError;
use super::case::{self, CaseFile, Expect, Recorded, Strings};
use super::run::{self, Outcome};

/// What to record.
#[derive(Debug, Clone)]
pub struct RecordOptions {
    pub kind: String,
    pub robot_file: PathBuf,
    pub cable_robot_file: Option<PathBuf>,
    /// (input name, file).
    pub inputs: Vec<(String, PathBuf)>,
    pub settings_file: Option<PathBuf>,
    pub seed: u64,
    /// Day relative windows end on (days since 1970-01-01); pinned in the case.
    pub run_date: i64,
    /// Files or folders the settings name by relative path, copied into the
    /// case under the same relative path.
    pub copies: Vec<PathBuf>,
    /// Relative tolerance of the float comparisons.
    pub tolerance: f64,
    /// The case folder to create.
    pub out: PathBuf,
    /// Record the stage's error as the expectation (a known bad file) instead
    /// of its tables.
    pub expect_error: bool,
    /// The egcal binary that runs the stage.
    pub egcal: PathBuf,
    pub timeout: Duration,
}

/// Records the case; returns what was written.
pub fn record(options: &RecordOptions) -> Result<String, FixtureError> {
    let usage = FixtureError::Usage;
    if crate::stages::lookup(&options.kind).is_none() {
        return Err(usage(crate::stages::unknown_kind_message(&options.kind)));
    }
    if !(options.tolerance.is_finite() && options.tolerance >= 0.0) {
        return Err(usage(format!(
            "--tolerance {}: expected a relative tolerance ≥ 0",
            options.tolerance
        )));
    }
    let out = std::path::absolute(&options.out)
        .map_err(|e| usage(format!("{}: {e}", options.out.display())))?;
    if out.exists() {
        return Err(usage(format!(
            "{} already exists: a recorded case is never overwritten; remove it or choose another folder",
            out.display()
        )));
    }
    let name = out
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .ok_or_else(|| usage(format!("{}: not a folder name", out.display())))?;
    let parent = out.parent().unwrap_or(Path::new("/")).to_path_buf();
    std::fs::create_dir_all(&parent)
        .map_err(|e| usage(format!("cannot create {}: {e}", parent.display())))?;
    let _ = crate::fsio::sweep::sweep_folder(&parent);
    let staging = Staging::create(parent.join(crate::fsio::sweep::staging_folder_name(&name)))?;
    let case_file = stage_files(options, &staging.path)?;

    let work = run::WorkFolder::create()?;
    // First run: its tables become the expectation.
    let provisional = case::Case {
        dir: staging.path.clone(),
        kind: options.kind.clone(),
        robot_file: staging.path.join(&case_file.robot),
        cable_robot_file: case_file.cable_robot.as_ref().map(|f| staging.path.join(f)),
        seed: options.seed,
        run_date: case_file.run_date.clone(),
        recorded: true,
        inputs: case_file
            .inputs
            .iter()
            .map(|(n, f)| (n.clone(), staging.path.join(f)))
            .collect(),
        settings: case_file.settings.clone(),
        expect: Expect::default(),
        expected_tables: Vec::new(),
    };
    let first = work.path.join("first");
    let ran = run::run_stage(&provisional, &options.egcal, options.timeout, &first);
    let code = ran
        .code
        .clone()
        .map_err(|why| FixtureError::Record(format!("{why}\n{}", ran.stderr.trim_end())))?;
    let decided = [0, 10, 11].contains(&code);
    let (expect, recorded) = if options.expect_error {
        if decided {
            return Err(FixtureError::Record(format!(
                "the stage succeeded (exit {code}); --expect-error records a stage that fails"
            )));
        }
        if code == 101 || ran.stderr.contains("panicked at") {
            return Err(FixtureError::Record(format!(
                "the stage panicked, which is a bug to report rather than an error to expect:\n{}",
                ran.stderr.trim_end()
            )));
        }
        let texts = error_texts(&ran.stderr, &[&staging.path, &first]);
        if texts.is_empty() {
            return Err(FixtureError::Record(format!(
                "the stage failed (exit {code}) without an error message to expect"
            )));
        }
        let expect = Expect {
            error: Some(Strings::Many(texts)),
            exit: Some(code as u8),
            ..Expect::default()
        };
        (expect, format!("its error, exit {code}"))
    } else {
        if !decided {
            return Err(FixtureError::Record(format!(
                "the stage failed (exit {code}) on the case's copies of its files in {}; \
                 nothing was recorded{} (to keep this error as the expected one, add \
                 --expect-error):\n{}",
                staging.path.display(),
                if options.copies.is_empty() {
                    "; if a setting names a file or folder, add it with --copy"
                } else {
                    ""
                },
                ran.stderr.trim_end()
            )));
        }
        let tables = store_expected(&first.join("out"), &staging.path.join("expected"))?;
        let expect = Expect {
            tolerance: Some(options.tolerance),
            exit: (code != 0).then_some(code as u8),
            ..Expect::default()
        };
        let exit = if code != 0 {
            format!(", exit {code}")
        } else {
            String::new()
        };
        let described = format!(
            "{} expected table(s) ({}){exit}",
            tables.len(),
            tables.join(", ")
        );
        (expect, described)
    };
    let case_file = CaseFile {
        expect,
        ..case_file
    };
    let text = format!(
        "# Recorded by `egcal test record` (egcal {}, {}): the expectation is egcal's own\n\
         # output of that day, a regression case rather than an independent check.\n{}",
        env!("CARGO_PKG_VERSION"),
        crate::table::time::date_string(crate::table::time::today()),
        toml::to_string(&case_file).map_err(|e| FixtureError::Record(e.to_string()))?
    );
    crate::fsio::write_bytes_atomic(&staging.path.join("case.toml"), text.as_bytes())
        .map_err(|e| FixtureError::Record(format!("writing case.toml: {e}")))?;

    // Second run, exactly as `egcal test` runs the case.
    let checked = case::load(&staging.path).map_err(|e| FixtureError::Record(e.to_string()))?;
    let second = work.path.join("second");
    let again = run::run_stage(&checked, &options.egcal, options.timeout, &second);
    if let Outcome::Failed(why) = run::judge(&checked, &again, &second.join("out")) {
        return Err(FixtureError::Record(format!(
            "the recorded case does not pass on a second run, so it was not written \
             (does the stage's output change from run to run?):\n{why}"
        )));
    }
    staging.persist(&out)?;
    Ok(format!(
        "recorded a `{}` case in {}: {recorded}; run it with `egcal test {}`",
        options.kind,
        out.display(),
        options.out.display()
    ))
}

/// The path-free pieces of a stage's error: every line of its stderr cut at
/// the case's temporary folders, which the next run of the case will not share
/// (the inputs' copies are named again from the case's final folder).
fn error_texts(stderr: &str, temporary: &[&Path]) -> Vec<String> {
    let mut pieces = vec![stderr.trim().to_string()];
    for dir in temporary {
        let prefix = format!("{}/", dir.display());
        pieces = pieces
            .iter()
            .flat_map(|p| p.split(&prefix).map(str::to_string).collect::<Vec<_>>())
            .collect();
    }
    let mut texts: Vec<String> = Vec::new();
    for piece in pieces.iter().flat_map(|p| p.lines()).map(str::trim) {
        if !piece.is_empty() && !texts.iter().any(|t| t == piece) {
            texts.push(piece.to_string());
        }
    }
    texts
}

/// Copies the robot, cable robot, inputs and `--copy` paths into `dir`; returns
/// the case file without its expectation.
fn stage_files(options: &RecordOptions, dir: &Path) -> Result<CaseFile, FixtureError> {
    let usage = FixtureError::Usage;
    let robot = copy_named(&options.robot_file, dir, None, "--robot")?;
    let cable_robot = match &options.cable_robot_file {
        Some(file) => Some(copy_named(file, dir, Some("cable_robot"), "--cable-robot")?),
        None => None,
    };
    let mut inputs = std::collections::BTreeMap::new();
    for (name, file) in &options.inputs {
        let plain = !name.is_empty()
            && name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
        if !plain {
            return Err(usage(format!(
                "--input {name}=…: an input name is letters, digits, `_` and `-`"
            )));
        }
        if inputs.contains_key(name) {
            return Err(usage(format!("--input {name}=… is given twice")));
        }
        let copied = copy_named(file, dir, Some(name), &format!("--input {name}"))?;
        inputs.insert(name.clone(), copied);
    }
    let settings = match &options.settings_file {
        None => toml::Table::new(),
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .map_err(|e| usage(format!("cannot read settings {}: {e}", path.display())))?;
            toml::from_str(&text).map_err(|e| {
                usage(format!(
                    "{}: {}",
                    path.display(),
                    crate::toml_error::describe(&e, &text)
                ))
            })?
        }
    };
    for path in &options.copies {
        let relative = path.is_relative()
            && path
                .components()
                .all(|c| matches!(c, Component::Normal(_) | Component::CurDir));
        if !relative {
            return Err(usage(format!(
                "--copy {}: give a path relative to the current folder without `..`, \
                 as the settings name it",
                path.display()
            )));
        }
        let top = path
            .components()
            .find_map(|c| match c {
                Component::Normal(name) => Some(name.to_string_lossy().into_owned()),
                _ => None,
            })
            .unwrap_or_default();
        if top.is_empty() || dir.join(&top).exists() || RESERVED.contains(&top.as_str()) {
            return Err(usage(format!(
                "--copy {}: the case already uses the name `{top}` (robot, inputs, \
                 case.toml, expected/); copy another folder",
                path.display()
            )));
        }
        copy_tree(path, &dir.join(path))
            .map_err(|e| usage(format!("--copy {}: {e}", path.display())))?;
    }
    Ok(CaseFile {
        kind: Some(options.kind.clone()),
        robot,
        cable_robot,
        seed: options.seed,
        run_date: Some(crate::table::time::date_string(options.run_date)),
        recorded: Some(Recorded {
            egcal_version: env!("CARGO_PKG_VERSION").to_string(),
            date: crate::table::time::date_string(crate::table::time::today()),
        }),
        inputs,
        settings,
        expect: Expect::default(),
    })
}

/// Copies `file` into `dir` as `stem.<its extension>` (or its own name); returns
/// the new name.
fn copy_named(
    file: &Path,
    dir: &Path,
    stem: Option<&str>,
    option: &str,
) -> Result<String, FixtureError> {
    if !file.is_file() {
        return Err(FixtureError::Usage(format!(
            "{option} {}: no such file",
            file.display()
        )));
    }
    let name = match (stem, file.extension()) {
        (Some(stem), Some(ext)) => format!("{stem}.{}", ext.to_string_lossy()),
        (Some(stem), None) => stem.to_string(),
        (None, _) => file
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "robot.toml".into()),
    };
    if dir.join(&name).exists() || RESERVED.contains(&name.as_str()) {
        return Err(FixtureError::Usage(format!(
            "{option} {}: its copy would be named `{name}`, which the case already uses; \
             rename the file",
            file.display()
        )));
    }
    copy_durably(file, &dir.join(&name))
        .map_err(|e| FixtureError::Usage(format!("{option} {}: {e}", file.display())))?;
    Ok(name)
}

/// Names the case file and its expectation take in a case folder.
const RESERVED: [&str; 2] = ["case.toml", "expected"];

/// Copies a file and flushes it to disk, so the case renamed into place later
/// holds its data even after a power cut.
fn copy_durably(from: &Path, to: &Path) -> std::io::Result<()> {
    std::fs::copy(from, to)?;
    std::fs::File::open(to)?.sync_all()
}

fn copy_tree(from: &Path, to: &Path) -> std::io::Result<()> {
    if let Some(parent) = to.parent() {
        std::fs::create_dir_all(parent)?;
    }
    if from.is_dir() {
        std::fs::create_dir_all(to)?;
        for entry in std::fs::read_dir(from)? {
            let entry = entry?;
            copy_tree(&entry.path(), &to.join(entry.file_name()))?;
        }
        crate::fsio::sync_dir(to)
    } else {
        copy_durably(from, to)
    }
}

/// Copies the stage's output tables into `expected/`; their names and rows.
fn store_expected(out: &Path, expected: &Path) -> Result<Vec<String>, FixtureError> {
    let fail = |e: std::io::Error| FixtureError::Record(format!("{}: {e}", out.display()));
    let mut tables: Vec<PathBuf> = std::fs::read_dir(out)
        .map_err(fail)?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_file() && p.extension().is_some_and(|e| e == "parquet"))
        .collect();
    tables.sort();
    if tables.is_empty() {
        return Err(FixtureError::Record(
            "the stage wrote no table, so there is nothing to record; write `[expect] file` \
             and `contains` by hand for a stage whose output is a page or a program"
                .into(),
        ));
    }
    std::fs::create_dir_all(expected).map_err(fail)?;
    let mut described = Vec::new();
    for table in tables {
        let file_name = table.file_name().unwrap_or_default().to_owned();
        let rows = crate::table::read_parquet(&table)
            .map(|df| df.height())
            .map_err(|e| FixtureError::Record(e.to_string()))?;
        copy_durably(&table, &expected.join(&file_name)).map_err(fail)?;
        described.push(format!("{} {rows} rows", file_name.to_string_lossy()));
    }
    Ok(described)
}

/// The case being built; removed unless [`Staging::persist`] renamed it.
struct Staging {
    path: PathBuf,
    persisted: bool,
}

impl Staging {
    fn create(path: PathBuf) -> Result<Staging, FixtureError> {
        std::fs::create_dir(&path)
            .map_err(|e| FixtureError::Usage(format!("cannot create {}: {e}", path.display())))?;
        Ok(Staging {
            path,
            persisted: false,
        })
    }

    fn persist(mut self, to: &Path) -> Result<(), FixtureError> {
        // Checked again: the folder may have appeared while the stage ran (a
        // rename would replace an empty one).
        if to.exists() {
            return Err(FixtureError::Usage(format!(
                "{} appeared while the case was recorded; it is left as it is",
                to.display()
            )));
        }
        let sync = |dir: &Path| {
            crate::fsio::sync_dir(dir)
                .map_err(|e| FixtureError::Record(format!("{}: {e}", dir.display())))
        };
        let expected = self.path.join("expected");
        if expected.exists() {
            sync(&expected)?; // not in an error case
        }
        sync(&self.path)?;
        std::fs::rename(&self.path, to).map_err(|e| {
            FixtureError::Record(format!("cannot move the case to {}: {e}", to.display()))
        })?;
        self.persisted = true;
        if let Some(parent) = to.parent() {
            let _ = crate::fsio::sync_dir(parent);
        }
        Ok(())
    }
}

impl Drop for Staging {
    fn drop(&mut self) {
        if !self.persisted {
            let _ = std::fs::remove_dir_all(&self.path);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn error_texts_leave_out_the_temporary_folders() {
        let stderr = "error: stage `predict` failed: /t/.c.1.0.tmp/conf_wrenches.parquet: \
                      column `q3_deg` is NaN at row 4\nsee /w/egcal-test-1/first/settings.toml\n";
        let texts = error_texts(
            stderr,
            &[
                Path::new("/t/.c.1.0.tmp"),
                Path::new("/w/egcal-test-1/first"),
            ],
        );
        assert_eq!(
            texts,
            [
                "error: stage `predict` failed:",
                "conf_wrenches.parquet: column `q3_deg` is NaN at row 4",
                "see",
                "settings.toml"
            ]
        );
    }
}
