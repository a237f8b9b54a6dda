//! The calibration applied, end to end (`jobs/compensate_sim.toml`): calibrate
//! as the paper campaign does, compensate a grid and a loaded drilling pattern,
//! run the commands on the same simulated robot, and compare the achieved
//! positions with the targets. Issue #15's target: the compensated mean error
//! within 1.5× the elasto-geometric validation mean of the same calibration,
//! and far below the controller's nominal IK of the same targets.

mod common;

use std::path::Path;

use egcal::table::{self, schema};

/// `column` of the row whose `key_column` is `key`.
fn value_of(file: &Path, key_column: &str, key: &str, column: &str) -> f64 {
    let df = table::read_parquet(file).unwrap();
    let keys = schema::str_values(&df, key_column, file).unwrap();
    let values = schema::f64_values(&df, column, file).unwrap();
    let row = keys
        .iter()
        .position(|k| k.as_deref() == Some(key))
        .unwrap_or_else(|| panic!("{}: no {key_column} {key}", file.display()));
    values[row]
}

#[test]
fn compensated_targets_are_as_accurate_as_the_validation_and_the_programs_are_written() {
    let dir = tempfile::tempdir().unwrap();
    let job = common::shipped_job_in(dir.path(), "compensate_sim", |text| text);
    let (code, stdout, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 0, "{stdout}\n{stderr}");

    let out = dir.path().join("out/compensate_sim");
    let validation_mean = value_of(
        &out.join("validate/stats.parquet"),
        "model",
        "elastogeometric",
        "mean_mm",
    );
    for set in ["grid", "drilling"] {
        let stats = out.join(format!("accuracy_{set}/target_stats.parquet"));
        let compensated = value_of(&stats, "run", "achieved", "mean_mm");
        let nominal = value_of(&stats, "run", "baseline", "mean_mm");
        let compared =
            schema::i64_values(&table::read_parquet(&stats).unwrap(), "n", &stats).unwrap();
        assert!(
            compensated <= 1.5 * validation_mean,
            "{set}: compensated mean {compensated:.4} mm, validation mean {validation_mean:.4} mm"
        );
        assert!(
            compensated * 20.0 < nominal,
            "{set}: compensated {compensated:.4} mm, nominal IK {nominal:.4} mm"
        );
        assert!(compared[0] >= 15, "{set}: {compared:?} targets compared");
        let tests = out.join(format!("accuracy_{set}/tests.parquet"));
        let df = table::read_parquet(&tests).unwrap();
        let names = schema::str_values(&df, "test", &tests).unwrap();
        let p = schema::f64_values(&df, "p_value", &tests).unwrap();
        let wilcoxon = names
            .iter()
            .position(|n| n.as_deref() == Some("wilcoxon"))
            .unwrap();
        assert!(p[wilcoxon] < 1e-3, "{set}: Wilcoxon p = {}", p[wilcoxon]);
    }
    for file in [
        "DRILLING.mod",
        "DRILLING.src",
        "DRILLING.dat",
        "commands.csv",
        "robot.urdf",
    ] {
        let path = out.join("program_drilling").join(file);
        assert!(path.is_file(), "{} missing", path.display());
    }
}
