//! The case file, `case.toml`: what one fixture case runs and what it expects.
//! Parsed strictly (unknown keys are errors) and checked before anything runs,
//! so a typo in a lab's case is reported with its line and key instead of
//! running a different test than the one written.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::job::raw::LineIndex;
use crate::toml_error::StrictError;

/// `case.toml` as written. Paths are relative to the case folder, which is also
/// the stage's working folder (a setting `logs = "logs"` names the case's own
/// `logs/`).
#[derive(Debug, Clone, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CaseFile {
    /// Stage kind (`egcal list-stages`); default: the name of the case folder's
    /// parent, as in `fixtures/<kind>/<case>/case.toml`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kind: Option<String>,
    /// Robot file the stage runs with.
    pub robot: String,
    /// Cable-robot geometry; the built-in default when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cable_robot: Option<String>,
    /// The job seed the stage's randomness derives from.
    #[serde(default)]
    pub seed: u64,
    /// Day relative time windows end on, YYYY-MM-DD; default: today (UTC). A case
    /// whose stage reads a relative window (`last = "14d"`) must set it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub run_date: Option<String>,
    /// Present when `egcal test record` wrote the case: its expected tables are
    /// egcal's own output of that day (a regression case, not an independent check).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub recorded: Option<Recorded>,
    /// Input name → file.
    #[serde(default)]
    pub inputs: BTreeMap<String, String>,
    /// The stage's settings, as in a job's stage table.
    #[serde(default)]
    #[schemars(with = "BTreeMap<String, serde_json::Value>")]
    pub settings: toml::Table,
    pub expect: Expect,
}

/// Provenance of a recorded case.
#[derive(Debug, Clone, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Recorded {
    /// egcal version that wrote the expected tables.
    pub egcal_version: String,
    /// Day of the recording, YYYY-MM-DD.
    pub date: String,
}

/// What the stage must do: fail with an error (`error`), or succeed and write
/// tables equal to `expected/<table>.parquet` (`tolerance`), a file containing
/// strings (`file` + `contains`), or both.
#[derive(Debug, Clone, Default, Deserialize, Serialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Expect {
    /// Compare each `expected/<table>.parquet` with the output table of that name:
    /// floats within `tolerance × max(1, |expected|)`, everything else exactly,
    /// only the expected columns, row by row.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tolerance: Option<f64>,
    /// Text (or texts) the error message must contain; the stage must fail.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<Strings>,
    /// A file the stage writes besides its tables (`report.html`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file: Option<String>,
    /// Strings `file` must contain.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub contains: Vec<String>,
    /// Strings egcal's output must contain (the stage's facts).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub stdout: Vec<String>,
    /// Exit code: default 0 for a success (a publishing `gate` exits 10), any
    /// non-zero code for an `error` case unless given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exit: Option<u8>,
}

/// One string or a list of them.
#[derive(Debug, Clone, Deserialize, Serialize, JsonSchema)]
#[serde(untagged)]
pub enum Strings {
    One(String),
    Many(Vec<String>),
}

impl Strings {
    pub fn all(&self) -> &[String] {
        match self {
            Strings::One(one) => std::slice::from_ref(one),
            Strings::Many(many) => many,
        }
    }
}

/// A case file that cannot be run as written.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}: {}{message}", file.display(), where_(*line, key))]
pub struct Malformed {
    pub file: PathBuf,
    /// 1-based line of the key, when the file has one.
    pub line: Option<usize>,
    /// Key path (`expect.tolerance`); empty for the whole file.
    pub key: String,
    pub message: String,
}

fn where_(line: Option<usize>, key: &str) -> String {
    match (line, key.is_empty()) {
        (Some(line), false) => format!("line {line}, key `{key}`: "),
        (Some(line), true) => format!("line {line}: "),
        (None, false) => format!("key `{key}`: "),
        (None, true) => String::new(),
    }
}

/// A checked case, ready to run: paths resolved against its folder.
#[derive(Debug, Clone)]
pub struct Case {
    pub dir: PathBuf,
    pub kind: String,
    pub robot_file: PathBuf,
    pub cable_robot_file: Option<PathBuf>,
    pub seed: u64,
    pub run_date: Option<String>,
    pub recorded: bool,
    /// (input name, file).
    pub inputs: Vec<(String, PathBuf)>,
    pub settings: toml::Table,
    pub expect: Expect,
    /// (table name, `expected/<table>.parquet`), sorted, when `tolerance` is set.
    pub expected_tables: Vec<(String, polars::prelude::DataFrame)>,
}

/// Reads and checks `dir/case.toml`.
pub fn load(dir: &Path) -> Result<Case, Malformed> {
    let file = dir.join("case.toml");
    let bad = |line: Option<usize>, key: &str, message: String| Malformed {
        file: file.clone(),
        line,
        key: key.to_string(),
        message,
    };
    let text =
        std::fs::read_to_string(&file).map_err(|e| bad(None, "", format!("cannot read: {e}")))?;
    let lines = line_index(&text).unwrap_or_default();
    let raw: CaseFile = crate::toml_error::from_str_strict(&text).map_err(|e| match e {
        StrictError::Syntax(message) => bad(None, "", format!("invalid TOML: {message}")),
        StrictError::Invalid { key, message } => bad(lines.line_of(&key), &key, message),
    })?;
    let bad_key = |key: &str, message: String| bad(lines.line_of(key), key, message);
    check(dir, raw, &bad_key)
}

fn line_index(text: &str) -> Option<LineIndex> {
    let table = toml::de::DeTable::parse(text).ok()?;
    Some(LineIndex::build(text, table.get_ref()))
}

fn check(
    dir: &Path,
    raw: CaseFile,
    bad: &dyn Fn(&str, String) -> Malformed,
) -> Result<Case, Malformed> {
    let kind = match &raw.kind {
        Some(kind) => kind.clone(),
        // Absolute, so `egcal test .` inside a case finds its parent's name.
        None => std::path::absolute(dir)
            .ok()
            .as_deref()
            .and_then(Path::parent)
            .and_then(Path::file_name)
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default(),
    };
    let Some(stage) = crate::stages::lookup(&kind) else {
        let message = crate::stages::unknown_kind_message(&kind);
        return Err(bad(
            "kind",
            if raw.kind.is_some() {
                message
            } else {
                format!(
                    "no `kind`, and the case folder's parent: {message}; \
                     set `kind` or put the case under <folder>/<kind>/<case>/"
                )
            },
        ));
    };
    let info = stage.info();
    let existing = |key: &str, name: &str| -> Result<PathBuf, Malformed> {
        let path = dir.join(name);
        if path.is_file() {
            Ok(path)
        } else {
            Err(bad(
                key,
                format!(
                    "`{name}`: no such file in the case folder {}",
                    dir.display()
                ),
            ))
        }
    };
    // An input is a file of the case: inside its folder (the guide, docs/fixture-cases.md: "a folder
    // holding case.toml and the files it names"), so that the case, copied
    // elsewhere, still tests what it tested. The robot and cable-robot files
    // may be shared between cases (`../../robots/cell7.toml`) or absolute.
    let inside = |key: &str, name: &str| -> Result<PathBuf, Malformed> {
        inside_folder(Some(dir), name, "case folder").map_err(|message| bad(key, message))?;
        existing(key, name)
    };
    let robot_file = existing("robot", &raw.robot)?;
    let cable_robot_file = match &raw.cable_robot {
        Some(name) => Some(existing("cable_robot", name)?),
        None => None,
    };
    if let Some(day) = &raw.run_date
        && crate::table::time::parse_date(day).is_none()
    {
        return Err(bad("run_date", format!("`{day}` is not a date YYYY-MM-DD")));
    }
    let mut inputs = Vec::new();
    for (name, file) in &raw.inputs {
        let key = format!("inputs.{name}");
        if !info.inputs.iter().any(|slot| slot.name == name) {
            let names = info.inputs.iter().map(|slot| slot.name);
            return Err(bad(
                &key,
                format!(
                    "`{kind}` has no input `{name}`{}",
                    crate::suggest::did_you_mean(name, names)
                ),
            ));
        }
        inputs.push((name.clone(), inside(&key, file)?));
    }
    let expect = raw.expect;
    // A misspelt setting in a case that must succeed is the case's mistake; in
    // an error case it may be the error under test.
    if expect.error.is_none()
        && let Err(problems) = stage.canonical_settings(&raw.settings)
        && let Some(first) = problems.first()
    {
        let more = match problems.len() {
            1 => String::new(),
            n => format!(" (and {} more)", n - 1),
        };
        return Err(bad(
            &format!("settings.{}", first.key),
            format!("{}{more}", first.message),
        ));
    }
    let compares = expect.tolerance.is_some() || expect.file.is_some();
    if expect.error.is_some() && compares {
        return Err(bad(
            "expect.error",
            "an error case compares no outputs: remove `tolerance`, `file` and `contains`, \
             or split it into two cases"
                .into(),
        ));
    }
    if expect.error.is_none() && !compares {
        return Err(bad(
            "expect",
            "needs `error` (the stage must fail), `tolerance` (compare expected/ tables) \
             or `file` with `contains`"
                .into(),
        ));
    }
    if let Some(error) = &expect.error {
        if error.all().is_empty() || error.all().iter().any(String::is_empty) {
            return Err(bad(
                "expect.error",
                "needs non-empty text to look for".into(),
            ));
        }
        if expect.exit == Some(0) {
            return Err(bad(
                "expect.exit",
                "an error case exits non-zero; 0 contradicts `error`".into(),
            ));
        }
    }
    for (key, texts) in [
        ("expect.contains", &expect.contains),
        ("expect.stdout", &expect.stdout),
    ] {
        if texts.iter().any(String::is_empty) {
            return Err(bad(
                key,
                "holds an empty text, which every output contains: the check proves nothing".into(),
            ));
        }
    }
    if let Some(file) = &expect.file {
        // The stage's output folder is a fresh temporary folder; the file
        // must be one the stage wrote there, not one that was there anyway.
        inside_folder(None, file, "stage's output folder")
            .map_err(|message| bad("expect.file", message))?;
    }
    let (has_file, has_contains) = (expect.file.is_some(), !expect.contains.is_empty());
    if has_file != has_contains {
        let key = if has_file {
            "expect.file"
        } else {
            "expect.contains"
        };
        return Err(bad(key, "`file` and `contains` go together".into()));
    }
    let mut expected_tables = Vec::new();
    let expected_dir = dir.join("expected");
    if let Some(tolerance) = expect.tolerance {
        if !(tolerance.is_finite() && tolerance >= 0.0) {
            return Err(bad(
                "expect.tolerance",
                format!("{tolerance} is not a relative tolerance ≥ 0"),
            ));
        }
        if tolerance > MAX_TOLERANCE {
            return Err(bad(
                "expect.tolerance",
                format!(
                    "{tolerance:e} is a relative tolerance above {MAX_TOLERANCE} (100 %), which accepts almost any value: the comparison would prove nothing"
                ),
            ));
        }
        inside_folder(Some(dir), "expected", "case folder")
            .map_err(|message| bad("expect.tolerance", message))?;
        expected_tables = expected_tables_in(&expected_dir)
            .map_err(|message| bad("expect.tolerance", message))?;
    } else if expected_dir.exists() {
        return Err(bad(
            "expect",
            format!(
                "{} exists but nothing compares it: add `tolerance`",
                expected_dir.display()
            ),
        ));
    }
    Ok(Case {
        dir: dir.to_path_buf(),
        kind,
        robot_file,
        cable_robot_file,
        seed: raw.seed,
        run_date: raw.run_date,
        recorded: raw.recorded.is_some(),
        inputs,
        settings: raw.settings,
        expect,
        expected_tables,
    })
}

/// The largest relative tolerance of a comparison: beyond 100 %, any value of
/// the same sign passes.
const MAX_TOLERANCE: f64 = 1.0;

/// Why the path `name` of a case file does not stay inside `folder` (named
/// `what` in the message): empty, absolute, with a `..` component, or (for a
/// path that exists in a `folder` given) a symlink that resolves outside it.
/// `Ok` when it stays.
pub fn inside_folder(folder: Option<&Path>, name: &str, what: &str) -> Result<(), String> {
    use std::path::Component;
    let path = Path::new(name);
    if name.trim().is_empty() {
        return Err(format!("an empty path; name a file in the {what}"));
    }
    if path.is_absolute() || path.has_root() {
        return Err(format!(
            "`{name}` is an absolute path; a case may name only files in its {what}, relative to it"
        ));
    }
    if path.components().any(|c| c == Component::ParentDir) {
        return Err(format!(
            "`{name}` leaves the {what} (`..`); a case may name only files in it"
        ));
    }
    let Some(folder) = folder else {
        return Ok(());
    };
    let full = folder.join(path);
    if full.exists() {
        let (Ok(resolved), Ok(root)) = (full.canonicalize(), folder.canonicalize()) else {
            return Err(format!("`{name}` cannot be resolved in the {what}"));
        };
        if !resolved.starts_with(&root) {
            return Err(format!(
                "`{name}` resolves to {} outside the {what} (a symbolic link); a case may name only files in it",
                resolved.display()
            ));
        }
    }
    Ok(())
}

/// The `<table>.parquet` tables of `expected/`, read; anything else there is a
/// mistake (a table saved under another name is a comparison silently not made).
fn expected_tables_in(dir: &Path) -> Result<Vec<(String, polars::prelude::DataFrame)>, String> {
    let entries = std::fs::read_dir(dir)
        .map_err(|e| format!("needs the expected tables in {}: {e}", dir.display()))?;
    let mut tables = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| format!("{}: {e}", dir.display()))?;
        let path = entry.path();
        let name = entry.file_name().to_string_lossy().into_owned();
        if name.starts_with('.') {
            continue;
        }
        if std::fs::symlink_metadata(&path).is_ok_and(|m| m.file_type().is_symlink()) {
            inside_folder(Some(dir), &name, "expected folder")?;
        }
        if !(path.is_file() && name.ends_with(".parquet")) {
            return Err(format!(
                "{} holds `{name}`; it may hold only <table>.parquet files",
                dir.display()
            ));
        }
        let table = crate::table::read_parquet(&path).map_err(|e| e.to_string())?;
        tables.push((name.trim_end_matches(".parquet").to_string(), table));
    }
    if tables.is_empty() {
        return Err(format!("{} holds no <table>.parquet file", dir.display()));
    }
    tables.sort_by(|a, b| a.0.cmp(&b.0));
    Ok(tables)
}

/// The JSON Schema of `case.toml` (`schemas/fixture-case.schema.json`).
pub fn schema_json() -> String {
    serde_json::to_string_pretty(&schemars::schema_for!(CaseFile)).expect("schema serialises")
        + "\n"
}

#[cfg(test)]
mod tests {
    use super::*;

    fn case_dir(text: &str) -> (tempfile::TempDir, PathBuf) {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("identify").join("one");
        std::fs::create_dir_all(dir.join("expected")).unwrap();
        std::fs::write(dir.join("robot.toml"), "").unwrap();
        std::fs::write(dir.join("m.parquet"), "").unwrap();
        let mut table = polars::prelude::df!("value" => [1.0]).unwrap();
        crate::table::write_parquet(&mut table, &dir.join("expected/parameters.parquet"), None)
            .unwrap();
        std::fs::write(dir.join("case.toml"), text).unwrap();
        (root, dir)
    }

    const GOOD: &str = "robot = \"robot.toml\"\n[inputs]\nmeasurements = \"m.parquet\"\n\
                        [settings]\nmodels = [\"kinematic\"]\n[expect]\ntolerance = 1e-6\n";

    #[test]
    fn a_good_case_takes_its_kind_from_the_folder() {
        let (_root, dir) = case_dir(GOOD);
        let case = load(&dir).unwrap();
        assert_eq!(case.kind, "identify");
        assert_eq!(case.inputs[0].0, "measurements");
        assert_eq!(case.expected_tables.len(), 1);
        assert!(!case.recorded);
    }

    #[test]
    fn an_unknown_key_names_its_line() {
        let (_root, dir) = case_dir(&GOOD.replace("tolerance", "tolerence"));
        let e = load(&dir).unwrap_err();
        assert_eq!(e.line, Some(7), "{e}");
        assert!(e.to_string().contains("tolerence"), "{e}");
    }

    #[test]
    fn semantic_problems_name_key_and_line() {
        let cases = [
            (GOOD.replace("1e-6", "-1.0"), "expect.tolerance", 7),
            (
                GOOD.replace("m.parquet", "missing.parquet"),
                "inputs.measurements",
                3,
            ),
            (
                GOOD.replace("robot = ", "kind = \"identfy\"\nrobot = "),
                "kind",
                1,
            ),
            (
                GOOD.replace("tolerance = 1e-6", "tolerance = 1e-6\nerror = \"x\""),
                "expect.error",
                8,
            ),
            (
                GOOD.replace("tolerance = 1e-6", "tolerance = 1e-6\ncontains = [\"x\"]"),
                "expect.contains",
                8,
            ),
        ];
        for (text, key, line) in cases {
            let (_root, dir) = case_dir(&text);
            let e = load(&dir).unwrap_err();
            assert_eq!((e.key.as_str(), e.line), (key, Some(line)), "{e}");
        }
    }

    #[test]
    fn paths_that_leave_the_case_are_refused() {
        let outside = tempfile::tempdir().unwrap();
        std::fs::write(outside.path().join("x.parquet"), "").unwrap();
        // An input that is a symbolic link to a file outside the case.
        let (_root, dir) = case_dir(&GOOD.replace("m.parquet", "link.parquet"));
        std::os::unix::fs::symlink(outside.path().join("x.parquet"), dir.join("link.parquet"))
            .unwrap();
        let e = load(&dir).unwrap_err();
        assert_eq!(e.key, "inputs.measurements", "{e}");
        assert!(e.message.contains("outside the case folder"), "{e}");
        // An expected folder that is a link to another folder.
        let (_root, dir) = case_dir(GOOD);
        std::fs::remove_dir_all(dir.join("expected")).unwrap();
        std::os::unix::fs::symlink(outside.path(), dir.join("expected")).unwrap();
        let e = load(&dir).unwrap_err();
        assert_eq!(e.key, "expect.tolerance", "{e}");
        assert!(e.message.contains("outside the case folder"), "{e}");
        // An output file outside the output folder, however written.
        for file in ["/etc/passwd", "../x", "a/../../x", ""] {
            let text = GOOD.replace(
                "tolerance = 1e-6",
                &format!("tolerance = 1e-6\nfile = \"{file}\"\ncontains = [\"x\"]"),
            );
            let (_root, dir) = case_dir(&text);
            let e = load(&dir).unwrap_err();
            assert_eq!(e.key, "expect.file", "{file}: {e}");
        }
        // Inside is fine, through a link too.
        assert_eq!(inside_folder(None, "sub/report.html", "x"), Ok(()));
    }

    #[test]
    fn a_kind_typo_is_suggested() {
        let (_root, dir) = case_dir(&GOOD.replace("robot = ", "kind = \"identfy\"\nrobot = "));
        let e = load(&dir).unwrap_err();
        assert!(e.to_string().contains("did you mean `identify`"), "{e}");
    }

    #[test]
    fn stray_files_in_expected_are_refused() {
        let (_root, dir) = case_dir(GOOD);
        std::fs::write(dir.join("expected/notes.txt"), "").unwrap();
        let e = load(&dir).unwrap_err();
        assert!(e.message.contains("notes.txt"), "{e}");
    }

    #[test]
    fn unknown_inputs_settings_and_unreadable_tables_are_the_cases_mistakes() {
        let (_root, dir) = case_dir(&GOOD.replace("measurements =", "measurments ="));
        let e = load(&dir).unwrap_err();
        assert_eq!(e.key, "inputs.measurments", "{e}");
        assert!(e.message.contains("did you mean `measurements`"), "{e}");
        let (_root, dir) = case_dir(&GOOD.replace("models =", "modles ="));
        let e = load(&dir).unwrap_err();
        assert_eq!(
            (e.key.as_str(), e.line),
            ("settings.modles", Some(5)),
            "{e}"
        );
        let (_root, dir) = case_dir(GOOD);
        std::fs::write(dir.join("expected/parameters.parquet"), "not parquet").unwrap();
        let e = load(&dir).unwrap_err();
        assert!(e.message.contains("parameters.parquet"), "{e}");
        let (_root, dir) = case_dir(&GOOD.replace("tolerance = 1e-6", "error = \"x\""));
        let e = load(&dir).unwrap_err();
        assert_eq!(e.key, "expect", "{e}");
    }
}
