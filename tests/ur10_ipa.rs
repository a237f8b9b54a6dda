//! The real-data job (`jobs/ur10_ipa.toml`) end to end on the UR10 tracker data
//! in `../shared/realdata/ur10-ipa`: the figures the README gives, within a
//! margin, beside the independent fit of the data's README. Skipped, with a
//! message, where the data are not beside the checkout.

mod common;

use std::path::Path;

use egcal::table::{self, schema};

/// Mean validation error (mm) of `model` in a validate stage's `stats`.
fn mean_mm(out: &Path, stage: &str, model: &str) -> f64 {
    let path = out.join(stage).join("stats.parquet");
    let stats = table::read_parquet(&path).unwrap();
    let models = schema::str_values(&stats, "model", &path).unwrap();
    let means = schema::f64_values(&stats, "mean_mm", &path).unwrap();
    let row = models
        .iter()
        .position(|m| m.as_deref() == Some(model))
        .unwrap_or_else(|| panic!("{stage}: no model {model}"));
    means[row]
}

#[test]
fn the_ur10_job_calibrates_series_c_and_carries_it_to_b_and_d() {
    let root = common::root();
    let data = root.join("../shared/realdata/ur10-ipa");
    if !data.join("Series_C").is_dir() {
        eprintln!(
            "SKIPPED: the UR10 data are not at {}; the job needs ../shared beside the checkout",
            data.display()
        );
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let jobs = root.join("jobs");
    let text = std::fs::read_to_string(jobs.join("ur10_ipa.toml")).unwrap();
    // Same job, run from a temporary folder: make its relative paths absolute.
    let text = text
        .replace("\"robots/", &format!("\"{}/robots/", jobs.display()))
        .replace(
            "\"../../shared/",
            &format!("\"{}/../../shared/", jobs.display()),
        );
    let job = dir.path().join("ur10_ipa.toml");
    std::fs::write(&job, text).unwrap();
    let (code, stdout, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 0, "{stdout}\n{stderr}");
    let out = dir.path().join("out/ur10_ipa");

    // Series C, half fitted and half validated (independent fit: 0.90, 0.44, 0.44).
    let registered = mean_mm(&out, "validate_c", "registered");
    let kinematic = mean_mm(&out, "validate_c", "kinematic");
    let elastogeometric = mean_mm(&out, "validate_c", "elastogeometric");
    assert!((registered - 0.90).abs() < 0.05, "registered {registered}");
    assert!(kinematic < 0.46, "kinematic {kinematic}");
    assert!(elastogeometric < 0.46, "elasto-geometric {elastogeometric}");
    // Only the frames refitted on B and D: better than the nominal robot there,
    // and the elasto-geometric robot better than the kinematic one.
    for series in ["b", "d"] {
        let nominal = mean_mm(&out, &format!("validate_{series}_kin"), "registered");
        let kinematic = mean_mm(&out, &format!("validate_{series}_kin"), "reregistered");
        let elastogeometric = mean_mm(&out, &format!("validate_{series}_eg"), "reregistered");
        assert!(
            elastogeometric < kinematic && kinematic < nominal,
            "series {series}: nominal {nominal}, kinematic {kinematic}, elasto-geometric {elastogeometric}"
        );
    }
    assert!(out.join("report_c/report.html").is_file());
}
