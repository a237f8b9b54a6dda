//! The UR10 tracker data's jobs (`jobs/ur10_ipa*.toml`) run from a temporary
//! folder, and the figures their validate stages write.

use std::path::{Path, PathBuf};

use egcal::table::{self, schema};

/// Runs `jobs/<job>.toml` in a temporary folder (its relative paths made
/// absolute) and returns the folder with the job's output folder; `None`,
/// with a message, where the data are not beside the checkout.
pub fn run_job(job: &str) -> Option<(tempfile::TempDir, PathBuf)> {
    let root = super::root();
    let data = root.join("../shared/realdata/ur10-ipa");
    if !data.join("Series_C").is_dir() {
        eprintln!(
            "SKIPPED: the UR10 data are not at {}; the job needs ../shared beside the checkout",
            data.display()
        );
        return None;
    }
    let dir = tempfile::tempdir().unwrap();
    let jobs = root.join("jobs");
    let text = std::fs::read_to_string(jobs.join(format!("{job}.toml"))).unwrap();
    let text = text
        .replace("\"robots/", &format!("\"{}/robots/", jobs.display()))
        .replace(
            "\"../../shared/",
            &format!("\"{}/../../shared/", jobs.display()),
        );
    let path = dir.path().join(format!("{job}.toml"));
    std::fs::write(&path, text).unwrap();
    let (code, stdout, stderr) = super::run(&["run", path.to_str().unwrap()], dir.path());
    assert_eq!(code, 0, "{stdout}\n{stderr}");
    let out = dir.path().join("out").join(job);
    Some((dir, out))
}

/// `column` of `model` in a validate stage's `stats`.
pub fn stat(out: &Path, stage: &str, model: &str, column: &str) -> f64 {
    let path = out.join(stage).join("stats.parquet");
    let stats = table::read_parquet(&path).unwrap();
    let models = schema::str_values(&stats, "model", &path).unwrap();
    let values = schema::f64_values(&stats, column, &path).unwrap();
    let row = models
        .iter()
        .position(|m| m.as_deref() == Some(model))
        .unwrap_or_else(|| panic!("{stage}: no model {model}"));
    values[row]
}
