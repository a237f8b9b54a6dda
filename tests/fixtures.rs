//! Data-driven stage tests: every `fixtures/<kind>/<case>/case.toml` runs its stage
//! kind through `egcal stage` on the case's input tables and settings, then either
//! checks the expected error text and a non-zero exit, or checks the outputs:
//!
//! * `[expect] tolerance = …`: each `expected/<table>.parquet` is compared with the
//!   output table of that name (floats within the tolerance, relative to
//!   max(1, |expected|); everything else exactly; only the expected columns);
//! * `[expect] file = "report.html"` and `contains = ["…", …]`: a file the stage
//!   writes besides its tables must contain each string (for stages whose output
//!   is not a table);
//! * `[expect] stdout = ["…", …]`: strings egcal's output must contain (the
//!   stage's facts, e.g. how many files a scan pruned).
//!
//! `[expect] error` is one string or a list of strings that stderr must contain.
//! A successful stage exits 0 unless `[expect] exit` says otherwise (a `gate`
//! that publishes exits 10).
//!
//! The stage runs with the case folder as its working directory, which
//! `egcal stage` resolves relative settings paths against (as a job resolves them
//! against the job file's folder), so a case's `logs = "logs"` names its own folder.
//!
//! Expected tables and strings come from independent sources (see `fixtures/tools/`).

mod common;

use std::path::{Path, PathBuf};

use polars::prelude::*;

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Case {
    inputs: toml::Table,
    #[serde(default)]
    settings: toml::Table,
    expect: Expect,
    #[serde(default)]
    seed: u64,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Expect {
    tolerance: Option<f64>,
    error: Option<Strings>,
    file: Option<String>,
    #[serde(default)]
    contains: Vec<String>,
    #[serde(default)]
    stdout: Vec<String>,
    #[serde(default)]
    exit: i32,
}

/// One string or a list of them.
#[derive(serde::Deserialize)]
#[serde(untagged)]
enum Strings {
    One(String),
    Many(Vec<String>),
}

impl Strings {
    fn all(&self) -> &[String] {
        match self {
            Strings::One(one) => std::slice::from_ref(one),
            Strings::Many(many) => many,
        }
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

fn cases() -> Vec<PathBuf> {
    let mut found = Vec::new();
    for kind in std::fs::read_dir(common::root().join("fixtures"))
        .unwrap()
        .flatten()
    {
        if !kind.path().is_dir() {
            continue;
        }
        for case in std::fs::read_dir(kind.path()).unwrap().flatten() {
            if case.path().join("case.toml").exists() {
                found.push(case.path());
            }
        }
    }
    found.sort();
    found
}

fn run_case(dir: &Path) -> Result<(), String> {
    let kind = dir
        .parent()
        .unwrap()
        .file_name()
        .unwrap()
        .to_string_lossy()
        .into_owned();
    let case: Case = toml::from_str(&std::fs::read_to_string(dir.join("case.toml")).unwrap())
        .map_err(|e| format!("case.toml: {e}"))?;
    let out = tempfile::tempdir().unwrap();
    let settings = out.path().join("settings.toml");
    std::fs::write(&settings, toml::to_string(&case.settings).unwrap()).unwrap();
    let robot = common::root().join("jobs/robots/irb1600_145.toml");
    let mut args: Vec<String> = vec![
        "stage".into(),
        kind.clone(),
        "--robot".into(),
        robot.display().to_string(),
        "--settings".into(),
        settings.display().to_string(),
        "--out".into(),
        out.path().display().to_string(),
        "--seed".into(),
        case.seed.to_string(),
    ];
    for (name, file) in &case.inputs {
        let file = file.as_str().ok_or("inputs must be file names")?;
        args.push("--input".into());
        args.push(format!("{name}={}", dir.join(file).display()));
    }
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let (code, stdout, stderr) = common::run(&args, dir);
    let expect = &case.expect;
    if let Some(error) = &expect.error {
        let error = error.all();
        if code == 0 {
            return Err(format!(
                "expected an error containing {error:?}, but it succeeded: {stdout}"
            ));
        }
        let lacking = missing(&stderr, error);
        if !lacking.is_empty() {
            return Err(format!("expected {lacking:?} in:\n{stderr}"));
        }
        return Ok(());
    }
    if code != expect.exit {
        return Err(format!("exit {code}, expected {}:\n{stderr}", expect.exit));
    }
    if expect.tolerance.is_none() && expect.file.is_none() {
        return Err("[expect] needs error, tolerance or file".into());
    }
    if expect.file.is_none() && !expect.contains.is_empty() {
        return Err("[expect] contains needs `file`".into());
    }
    if let Some(tolerance) = expect.tolerance {
        let expected =
            std::fs::read_dir(dir.join("expected")).map_err(|e| format!("expected/: {e}"))?;
        for expected in expected.flatten() {
            let name = expected.file_name().to_string_lossy().into_owned();
            let want = egcal::table::read_parquet(&expected.path()).map_err(|e| e.to_string())?;
            let got =
                egcal::table::read_parquet(&out.path().join(&name)).map_err(|e| e.to_string())?;
            compare(&want, &got, tolerance).map_err(|e| format!("{name}: {e}"))?;
        }
    }
    if let Some(file) = &expect.file {
        if expect.contains.is_empty() {
            return Err("[expect] file needs `contains`".into());
        }
        let text =
            std::fs::read_to_string(out.path().join(file)).map_err(|e| format!("{file}: {e}"))?;
        let lacking = missing(&text, &expect.contains);
        if !lacking.is_empty() {
            return Err(format!("{file} lacks {lacking:?}"));
        }
    }
    let lacking = missing(&stdout, &expect.stdout);
    if !lacking.is_empty() {
        return Err(format!("expected {lacking:?} in the output:\n{stdout}"));
    }
    Ok(())
}

fn compare(want: &DataFrame, got: &DataFrame, tolerance: f64) -> Result<(), String> {
    if want.height() != got.height() {
        return Err(format!("{} rows, expected {}", got.height(), want.height()));
    }
    for column in want.columns() {
        let name = column.name().as_str();
        let other = got
            .column(name)
            .map_err(|_| format!("missing column `{name}`"))?;
        if column.dtype().is_float() {
            let a = column.f64().unwrap();
            let b = other.f64().map_err(|e| format!("`{name}`: {e}"))?;
            for (row, (x, y)) in a.iter().zip(b.iter()).enumerate() {
                match (x, y) {
                    (Some(x), Some(y)) if (x - y).abs() <= tolerance * x.abs().max(1.0) => {}
                    (None, None) => {}
                    _ => {
                        return Err(format!(
                            "`{name}` row {row}: {y:?}, expected {x:?} (tolerance {tolerance})"
                        ));
                    }
                }
            }
        } else {
            // Physical values, so timestamps compare as µs whatever their time-zone tag.
            let a = column.to_physical_repr().cast(&DataType::String).unwrap();
            let b = other.to_physical_repr().cast(&DataType::String).unwrap();
            for (row, (x, y)) in a
                .str()
                .unwrap()
                .iter()
                .zip(b.str().unwrap().iter())
                .enumerate()
            {
                if x != y {
                    return Err(format!("`{name}` row {row}: {y:?}, expected {x:?}"));
                }
            }
        }
    }
    Ok(())
}

#[test]
fn every_fixture_case_passes() {
    let cases = cases();
    assert!(
        cases.len() >= 10,
        "found only {} fixture cases",
        cases.len()
    );
    let failures: Vec<String> = cases
        .iter()
        .filter_map(|dir| {
            run_case(dir)
                .err()
                .map(|e| format!("{}: {e}", dir.display()))
        })
        .collect();
    assert!(
        failures.is_empty(),
        "{} of {} cases failed:\n{}",
        failures.len(),
        cases.len(),
        failures.join("\n\n")
    );
}
