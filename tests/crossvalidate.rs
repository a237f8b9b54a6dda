//! Issue #28, held-out validation: `crossvalidate` equals identify + validate
//! run by hand on the same folds, grouped splits keep groups whole and repeat
//! with the seed, and the parameter choice by held-out error holds a
//! parameter the simulated truth leaves at nominal.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use egcal::robot::ParamId;
use egcal::table::{self, schema};
use polars::prelude::Column;

use common::measured::{noisy, positions, write_measurements};
use common::sample::{random_rows, robot_and_truth};

/// 240 simulated rows of the spec's robot and truth (0.02 mm noise); with
/// `nominal`, those parameters of the truth set back to nominal.
fn measurements(dir: &Path, nominal: &[&str]) -> PathBuf {
    let (robot, mut truth) = robot_and_truth();
    for name in nominal {
        let id = ParamId::all().find(|p| p.name() == *name).unwrap();
        truth.set(id, 0.0);
    }
    let rows = random_rows(&robot, 7, 240);
    let measured = noisy(&positions(&robot, &truth, &rows), 0.02, 8);
    let path = dir.join("measurements.parquet");
    write_measurements(&path, &rows, &measured, 0);
    path
}

fn job(dir: &Path, name: &str, stages: &str) -> PathBuf {
    let robot = common::root().join("jobs/robots/irb1600_145.toml");
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(
        &path,
        format!(
            "[job]\nname = \"{name}\"\nseed = 3\nrobot = \"{}\"\noutput = \"out/{name}\"\n{stages}",
            robot.display()
        ),
    )
    .unwrap();
    path
}

fn run(dir: &Path, job: &Path) {
    let (code, stdout, stderr) = common::run(&["run", job.to_str().unwrap()], dir);
    assert_eq!(code, 0, "{stdout}\n{stderr}");
}

/// (protocol, model, cw_id) → (fold, error) of a crossvalidate `errors` table.
fn cv_errors(path: &Path) -> BTreeMap<(String, String, i64), (i64, f64)> {
    let df = table::read_parquet(path).unwrap();
    let protocol = schema::str_values(&df, "protocol", path).unwrap();
    let model = schema::str_values(&df, "model", path).unwrap();
    let id = schema::i64_values(&df, "cw_id", path).unwrap();
    let fold = schema::i64_values(&df, "fold", path).unwrap();
    let error = schema::f64_values(&df, "error_mm", path).unwrap();
    (0..id.len())
        .map(|k| {
            (
                (
                    protocol[k].clone().unwrap(),
                    model[k].clone().unwrap(),
                    id[k],
                ),
                (fold[k], error[k]),
            )
        })
        .collect()
}

#[test]
fn a_fold_equals_identify_and_validate_run_by_hand() {
    let dir = tempfile::tempdir().unwrap();
    let m = measurements(dir.path(), &[]);
    let cv = job(
        dir.path(),
        "cv",
        &format!(
            r#"
[[stages]]
id = "cv"
kind = "crossvalidate"
inputs = {{ measurements = "{m}" }}
grouping = "configuration"
folds = 3

[stages.identify]
models = ["kinematic", "elastogeometric"]
"#,
            m = m.display()
        ),
    );
    run(dir.path(), &cv);
    let errors = cv_errors(&dir.path().join("out/cv/cv/errors.parquet"));
    // Both protocols, both models, every row once each.
    for protocol in ["configuration", "random"] {
        for model in ["kinematic", "elastogeometric"] {
            let rows = errors
                .keys()
                .filter(|(p, mm, _)| p == protocol && mm == model)
                .count();
            assert_eq!(rows, 240, "{protocol} {model}");
        }
    }
    // Fold 1 of the configuration folds by hand: its rows validate, the
    // others calibrate.
    let ids: Vec<i64> = (0..240).collect();
    let roles: Vec<&str> = ids
        .iter()
        .map(|id| {
            let (fold, _) = errors[&("configuration".into(), "elastogeometric".into(), *id)];
            if fold == 1 {
                "validation"
            } else {
                "calibration"
            }
        })
        .collect();
    let selection = dir.path().join("fold1.parquet");
    let mut df = table::frame(vec![
        Column::new("cw_id".into(), ids.clone()),
        Column::new("role".into(), roles.clone()),
    ]);
    table::write_parquet(&mut df, &selection, None).unwrap();
    let by_hand = job(
        dir.path(),
        "by_hand",
        &format!(
            r#"
[[stages]]
id = "identify"
kind = "identify"
inputs = {{ measurements = "{m}", selection = "{s}" }}
models = ["kinematic", "elastogeometric"]

[[stages]]
id = "validate"
kind = "validate"
inputs = {{ measurements = "{m}", selection = "{s}", parameters = "identify" }}
"#,
            m = m.display(),
            s = selection.display()
        ),
    );
    run(dir.path(), &by_hand);
    let path = dir.path().join("out/by_hand/validate/errors.parquet");
    let df = table::read_parquet(&path).unwrap();
    let model = schema::str_values(&df, "model", &path).unwrap();
    let id = schema::i64_values(&df, "cw_id", &path).unwrap();
    let error = schema::f64_values(&df, "error_mm", &path).unwrap();
    let mut compared = 0;
    for k in 0..id.len() {
        let model = model[k].clone().unwrap();
        if model == "nominal" {
            continue;
        }
        let (fold, cv_error) = errors[&("configuration".into(), model.clone(), id[k])];
        assert_eq!(fold, 1);
        assert!(
            (cv_error - error[k]).abs() < 1e-12,
            "{model} row {}: crossvalidate {cv_error}, by hand {}",
            id[k],
            error[k]
        );
        compared += 1;
    }
    let fold_rows = roles.iter().filter(|r| **r == "validation").count();
    assert_eq!(compared, 2 * fold_rows);
    assert!(
        fold_rows > 20 && fold_rows < 160,
        "fold 1 has {fold_rows} rows"
    );

    // Pooled figures: held-out (configuration) worse than random folds for
    // the kinematic model, which misses the loads.
    let path = dir.path().join("out/cv/cv/stats.parquet");
    let df = table::read_parquet(&path).unwrap();
    assert_eq!(df.height(), 4);
    let p997 = schema::f64_values(&df, "p997_mm", &path).unwrap();
    let max = schema::f64_values(&df, "max_mm", &path).unwrap();
    let mean = schema::f64_values(&df, "mean_mm", &path).unwrap();
    for k in 0..4 {
        assert!(mean[k] < p997[k] && p997[k] <= max[k], "row {k}");
    }
    let tests = table::read_parquet(&dir.path().join("out/cv/cv/tests.parquet")).unwrap();
    assert_eq!(tests.height(), 2, "one pair of models per protocol");
}

#[test]
fn grouped_splits_keep_groups_whole_and_repeat() {
    let dir = tempfile::tempdir().unwrap();
    let m = measurements(dir.path(), &[]);
    let stages = |method: &str| {
        format!(
            r#"
[[stages]]
id = "split"
kind = "split"
inputs = {{ measurements = "{m}" }}
method = "{method}"
groups = 4
validation_groups = 1
"#,
            m = m.display()
        )
    };
    for method in ["region", "configuration", "load"] {
        let mut seen = Vec::new();
        for name in ["a", "b"] {
            let job = job(dir.path(), &format!("{method}_{name}"), &stages(method));
            run(dir.path(), &job);
            let path = dir
                .path()
                .join(format!("out/{method}_{name}/split/selection.parquet"));
            let df = table::read_parquet(&path).unwrap();
            let role = schema::str_values(&df, "role", &path).unwrap();
            let group = schema::i64_values(&df, "group", &path).unwrap();
            for k in 0..role.len() {
                assert_eq!(
                    role[k].as_deref() == Some("validation"),
                    group[k] == 0,
                    "{method}: row {k} of group {} has role {:?}",
                    group[k],
                    role[k]
                );
            }
            let validating = group.iter().filter(|g| **g == 0).count();
            assert!(validating > 0 && validating < 240, "{method}: {validating}");
            seen.push((role, group));
        }
        // The same seed and stage id: the same split.
        assert_eq!(seen[0], seen[1], "{method}");
    }
    // Time without measured_at is refused, naming the column.
    let job = job(dir.path(), "time", &stages("time"));
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("measured_at"), "{stderr}");
}

/// The simulated truth leaves `dd5` at nominal: the parameter choices by
/// held-out rows hold it, and only it (and say why); with the
/// standard-error choice it is fitted to noise. (Not every seed: on these
/// rows it also holds `da6`, `dtheta4` or `dalpha4` when they are the one at
/// nominal, and keeps `da5` or `dalpha3` free; the rule holds a parameter
/// only when holding it does not raise the held-out error.)
#[test]
fn held_out_choice_holds_a_parameter_the_truth_leaves_at_nominal() {
    let dir = tempfile::tempdir().unwrap();
    let m = measurements(dir.path(), &["dd5"]);
    let stages = |choice: &str| {
        format!(
            r#"
[[stages]]
id = "identify"
kind = "identify"
inputs = {{ measurements = "{m}" }}
models = ["elastogeometric"]
parameter_choice = "{choice}"
"#,
            m = m.display()
        )
    };
    let status_of = |name: &str, job_name: &str| {
        let path = dir
            .path()
            .join(format!("out/{job_name}/identify/parameters.parquet"));
        let df = table::read_parquet(&path).unwrap();
        let names = schema::str_values(&df, "name", &path).unwrap();
        let status = schema::str_values(&df, "status", &path).unwrap();
        let reason = schema::str_values(&df, "reason", &path).unwrap();
        let models = schema::str_values(&df, "model", &path).unwrap();
        let k = (0..names.len())
            .find(|k| {
                names[*k].as_deref() == Some(name)
                    && models[*k].as_deref() == Some("elastogeometric")
            })
            .unwrap();
        (status[k].clone().unwrap(), reason[k].clone())
    };
    let held_out = job(dir.path(), "held_out", &stages("held_out"));
    run(dir.path(), &held_out);
    let (status, reason) = status_of("dd5", "held_out");
    assert_eq!(status, "held", "{reason:?}");
    assert!(
        reason
            .as_deref()
            .unwrap_or_default()
            .contains("held-out rows"),
        "{reason:?}"
    );
    // Parameters the truth moves stay free: nothing else is held.
    for id in ParamId::all() {
        let (status, reason) = status_of(id.name(), "held_out");
        if id.name() != "dd5" {
            assert_ne!(status, "held", "{}: {reason:?}", id.name());
        }
    }
    let standard = job(dir.path(), "standard", &stages("standard_errors"));
    run(dir.path(), &standard);
    assert_eq!(status_of("dd5", "standard").0, "identified");
    // The grouped jackknife holds it too: its leave-group-out estimates
    // scatter around nominal; the parameters the truth moves stay free.
    let jackknife = job(dir.path(), "jackknife", &stages("grouped_jackknife"));
    run(dir.path(), &jackknife);
    let (status, reason) = status_of("dd5", "jackknife");
    assert_eq!(status, "held", "{reason:?}");
    assert!(
        reason
            .as_deref()
            .unwrap_or_default()
            .contains("grouped jackknife"),
        "{reason:?}"
    );
    for id in ParamId::all() {
        let (status, reason) = status_of(id.name(), "jackknife");
        if id.name() != "dd5" {
            assert_ne!(status, "held", "{}: {reason:?}", id.name());
        }
    }
}
