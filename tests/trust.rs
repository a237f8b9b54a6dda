//! Issue #26: no wrong answer with exit 0 on the user's path. Each case here
//! once gave a wrong result with exit 0: every row predicted with target 0's
//! tool (106 mm off on the other SMRs), a fit that stopped at `max_iterations`
//! taken as converged, a robot file 40 mm off calibrated without a word, and
//! `--force` replaying the old readings of a campaign a user wanted measured
//! again.

mod common;

use std::path::{Path, PathBuf};

use egcal::robot::ParamId;
use egcal::table::{self, schema};
use nalgebra::Vector3;
use polars::prelude::Column;

use common::measured::{noisy, positions, write_measurements};
use common::sample::{random_rows, robot_and_truth};

const TARGETS: [&str; 3] = ["A", "B", "C"];

/// 150 simulated rows measuring three SMRs (A, B, C, 60–90 mm apart) in turn,
/// with a `target_id` column; returns the table's path.
fn three_target_measurements(dir: &Path) -> PathBuf {
    let (robot, mut truth) = robot_and_truth();
    let offsets = [
        Vector3::zeros(),
        Vector3::new(60.0, -40.0, 25.0),
        Vector3::new(-45.0, 35.0, 80.0),
    ];
    for (target, offset) in offsets.iter().enumerate() {
        for axis in 0..3 {
            let base = truth.get(ParamId::target_translation(0, axis));
            truth.set(
                ParamId::target_translation(target, axis),
                base + offset[axis],
            );
        }
    }
    let mut rows = random_rows(&robot, 41, 150);
    for (k, row) in rows.iter_mut().enumerate() {
        row.target = k % 3;
    }
    let measured = noisy(&positions(&robot, &truth, &rows), 0.02, 42);
    let path = dir.join("measurements.parquet");
    write_measurements(&path, &rows, &measured, 0);
    let mut df = table::read_parquet(&path).unwrap();
    let ids: Vec<&str> = (0..rows.len()).map(|k| TARGETS[k % 3]).collect();
    df.with_column(Column::new("target_id".into(), ids))
        .unwrap();
    table::write_parquet(&mut df, &path, None).unwrap();
    path
}

fn job(dir: &Path, stages: &str) -> PathBuf {
    let robot = common::root().join("jobs/robots/irb1600_145.toml");
    let path = dir.join("job.toml");
    std::fs::write(
        &path,
        format!(
            "[job]\nname = \"trust\"\nseed = 5\nrobot = \"{}\"\noutput = \"out\"\n{stages}",
            robot.display()
        ),
    )
    .unwrap();
    path
}

fn run(dir: &Path, job: &Path) -> (i32, String, String) {
    common::run(&["run", job.to_str().unwrap()], dir)
}

fn f64_column(path: &Path, name: &str) -> Vec<f64> {
    let df = table::read_parquet(path).unwrap();
    schema::f64_values(&df, name, path).unwrap()
}

/// Spec §8: predict and gate use each row's own target's tool. Before, every
/// row took target 0's: B and C were predicted 60–90 mm off, exit 0.
#[test]
fn predict_and_gate_use_each_rows_own_target() {
    let dir = tempfile::tempdir().unwrap();
    let measurements = three_target_measurements(dir.path());
    let stages = format!(
        r#"
[[stages]]
id = "split"
kind = "split"
inputs = {{ measurements = "{m}" }}

[[stages]]
id = "identify"
kind = "identify"
inputs = {{ measurements = "{m}", selection = "split" }}
models = ["registered", "elastogeometric"]

[[stages]]
id = "predict"
kind = "predict"
inputs = {{ conf_wrenches = "{m}", parameters = "identify.parameters" }}

[[stages]]
id = "gate"
kind = "gate"
inputs = {{ measurements = "{m}", selection = "split", candidate = "identify.parameters", in_service = "identify.parameters" }}
"#,
        m = measurements.display()
    );
    let job = job(dir.path(), &stages);
    let (code, stdout, stderr) = run(dir.path(), &job);
    assert_eq!(code, 0, "{stdout}\n{stderr}");
    let out = dir.path().join("out");
    let predicted: Vec<Vec<f64>> = schema::POSITION_COLUMNS
        .iter()
        .map(|c| f64_column(&out.join("predict/predictions.parquet"), c))
        .collect();
    let measured: Vec<Vec<f64>> = schema::POSITION_COLUMNS
        .iter()
        .map(|c| f64_column(&measurements, c))
        .collect();
    for (target, name) in TARGETS.iter().enumerate() {
        let worst = (target..predicted[0].len())
            .step_by(3)
            .map(|k| {
                (0..3)
                    .map(|a| (predicted[a][k] - measured[a][k]).powi(2))
                    .sum::<f64>()
                    .sqrt()
            })
            .fold(0.0, f64::max);
        assert!(worst < 0.2, "target {name}: worst {worst} mm");
    }
    let decision = out.join("gate/decision.parquet");
    let candidate_mean = f64_column(&decision, "candidate_mean_mm")[0];
    assert!(
        candidate_mean < 0.1,
        "gate hold-out mean {candidate_mean} mm"
    );

    // The same rows without `target_id`: refused, naming the targets.
    let plain = dir.path().join("no_target_column.parquet");
    let mut df = table::read_parquet(&measurements).unwrap();
    let _ = df.drop_in_place("target_id").unwrap();
    table::write_parquet(&mut df, &plain, None).unwrap();
    let stages = format!(
        "{stages}\n[[stages]]\nid = \"predict_plain\"\nkind = \"predict\"\ninputs = {{ conf_wrenches = \"{}\", parameters = \"identify.parameters\" }}\n",
        plain.display()
    );
    let job = self::job(dir.path(), &stages);
    let (code, stdout, stderr) = run(dir.path(), &job);
    assert_eq!(code, 2, "{stdout}\n{stderr}");
    assert!(
        stderr.contains("no_target_column.parquet")
            && stderr.contains("A, B, C")
            && stderr.contains("target_id"),
        "{stderr}"
    );
}

/// Issue #26, 3: a fit stopped by `max_iterations` fails the stage (exit 3)
/// and says what to try, unless `accept_not_converged` lets it through with a
/// warning in the facts.
#[test]
fn a_fit_that_did_not_converge_fails_unless_accepted() {
    let dir = tempfile::tempdir().unwrap();
    let measurements = three_target_measurements(dir.path());
    let stages = |extra: &str| {
        format!(
            r#"
[[stages]]
id = "identify"
kind = "identify"
inputs = {{ measurements = "{m}" }}
models = ["elastogeometric"]
max_iterations = 2
{extra}
"#,
            m = measurements.display()
        )
    };
    let job = job(dir.path(), &stages(""));
    let (code, stdout, stderr) = run(dir.path(), &job);
    assert_eq!(code, 3, "{stdout}\n{stderr}");
    for expected in [
        "did not converge after",
        "max_iterations",
        "accept_not_converged",
    ] {
        assert!(stderr.contains(expected), "`{expected}` in {stderr}");
    }
    let job = self::job(dir.path(), &stages("accept_not_converged = true"));
    let (code, stdout, stderr) = run(dir.path(), &job);
    assert_eq!(code, 0, "{stdout}\n{stderr}");
    let provenance = table::read_provenance(&dir.path().join("out/identify/parameters.parquet"))
        .unwrap()
        .unwrap();
    let warning = provenance
        .extra
        .get("elastogeometric_not_converged_accepted")
        .unwrap_or_else(|| panic!("{:?}", provenance.extra));
    assert!(warning.contains("not converged"), "{warning}");
}

/// Issue #26, 1: a robot whose identified geometry is 15 mm off its file is a
/// wrong robot file, not a calibration: the stage fails naming the parameter,
/// its value and the bound to raise. At 40 mm the registration of the start
/// already leaves more than any robot's error and says so.
#[test]
fn an_implausible_parameter_or_registration_fails_the_stage() {
    let dir = tempfile::tempdir().unwrap();
    let (robot, truth) = robot_and_truth();
    let da3 = ParamId::from_name("da3").unwrap();
    let rows = random_rows(&robot, 51, 120);
    let measurements = |offset_mm: f64| {
        let mut off = truth;
        off.set(da3, truth.get(da3) + offset_mm);
        let measured = noisy(&positions(&robot, &off, &rows), 0.02, 52);
        let path = dir.path().join(format!("measurements_{offset_mm}.parquet"));
        write_measurements(&path, &rows, &measured, 0);
        path
    };
    let stages = |path: &Path, extra: &str| {
        format!(
            "\n[[stages]]\nid = \"identify\"\nkind = \"identify\"\ninputs = {{ measurements = \"{}\" }}\nmodels = [\"kinematic\"]\nmax_iterations = 100\n{extra}\n",
            path.display()
        )
    };
    let fifteen = measurements(15.0);
    let job = job(dir.path(), &stages(&fifteen, ""));
    let (code, stdout, stderr) = run(dir.path(), &job);
    assert_eq!(code, 3, "{stdout}\n{stderr}");
    assert!(
        stderr.contains("`da3`") && stderr.contains("plausible_length_mm"),
        "{stderr}"
    );
    // Raised on purpose, the same rows calibrate.
    let job = self::job(dir.path(), &stages(&fifteen, "plausible_length_mm = 20.0"));
    let (code, stdout, stderr) = run(dir.path(), &job);
    assert_eq!(code, 0, "{stdout}\n{stderr}");

    let forty = measurements(40.0);
    let job = self::job(dir.path(), &stages(&forty, ""));
    let (code, stdout, stderr) = run(dir.path(), &job);
    assert_eq!(code, 2, "{stdout}\n{stderr}");
    assert!(stderr.contains("max_registration_rms_mm"), "{stderr}");
}

/// Issue #26, 9: `--force` resumes a measuring stage from its journal (the old
/// readings come back); `--remeasure` sets the journal aside, keeps it, and
/// measures again.
#[test]
fn remeasure_sets_the_journal_aside_and_measures_afresh() {
    let dir = tempfile::tempdir().unwrap();
    let job = common::measure_job(dir.path(), "");
    let (code, stdout, stderr) = run(dir.path(), &job);
    assert_eq!(code, 0, "{stdout}\n{stderr}");
    let journal = dir.path().join("out/.egcal/work/measure");
    assert!(journal.is_dir());
    let (code, stdout, stderr) = common::run(
        &["run", job.to_str().unwrap(), "--remeasure", "measure"],
        dir.path(),
    );
    assert_eq!(code, 0, "{stdout}\n{stderr}");
    let all = format!("{stdout}{stderr}");
    assert!(all.contains("set aside"), "{all}");
    assert!(!all.contains("resuming"), "{all}");
    let set_aside = dir.path().join("out/.egcal/set_aside/measure");
    let kept: Vec<_> = std::fs::read_dir(&set_aside).unwrap().collect();
    assert_eq!(kept.len(), 1, "one journal kept in {}", set_aside.display());
    let (code, _, stderr) = common::run(
        &["run", job.to_str().unwrap(), "--remeasure", "mesure"],
        dir.path(),
    );
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("did you mean `measure`"), "{stderr}");
}
