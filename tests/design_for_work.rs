//! Campaigns designed for the work (issue #28), end to end on the simulator
//! (`jobs/design_for_work_sim.toml`): the design chosen for the drilling
//! targets (criterion I) predicts less uncertainty there than DETMAX-O1 over
//! the same candidates and, calibrated and compensated on the same simulated
//! robot, puts the tool closer to the targets: within 1.5× the tracker-noise
//! floor, the mean norm of a 3-D normal with σ = 0.02 mm per axis. The
//! stopping rule's n is the first point of its curve at the required u95.

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

/// The largest non-null `u95_mm` of a `work_targets` table.
fn max_u95(file: &Path) -> f64 {
    let df = table::read_parquet(file).unwrap();
    df.column("u95_mm")
        .unwrap()
        .f64()
        .unwrap()
        .iter()
        .flatten()
        .fold(0.0, f64::max)
}

fn fact(file: &Path, key: &str) -> String {
    table::read_provenance(file)
        .unwrap()
        .unwrap()
        .extra
        .get(key)
        .unwrap_or_else(|| panic!("{}: no fact {key}", file.display()))
        .clone()
}

#[test]
fn the_design_for_the_work_beats_o1_at_the_work_targets() {
    let dir = tempfile::tempdir().unwrap();
    let job = common::shipped_job_in(dir.path(), "design_for_work_sim", |text| text);
    let (code, stdout, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 0, "{stdout}\n{stderr}");
    let out = dir.path().join("out/design_for_work_sim");

    // Predicted: the work design's largest u95 at the targets is well below O1's.
    let predicted_work = max_u95(&out.join("select_work/work_targets.parquet"));
    let predicted_o1 = max_u95(&out.join("select_o1/work_targets.parquet"));
    assert!(
        predicted_work < 0.8 * predicted_o1,
        "predicted max u95: work {predicted_work:.4} mm, O1 {predicted_o1:.4} mm"
    );

    // Achieved on the simulated robot.
    let achieved = |design: &str| {
        let stats = out.join(format!("accuracy_{design}/target_stats.parquet"));
        value_of(&stats, "run", "achieved", "mean_mm")
    };
    let (work, o1) = (achieved("work"), achieved("o1"));
    let noise_floor = 0.02 * (8.0 / std::f64::consts::PI).sqrt();
    assert!(
        work < 0.6 * o1,
        "achieved mean: work {work:.4} mm, O1 {o1:.4} mm"
    );
    assert!(
        work <= 1.5 * noise_floor,
        "work {work:.4} mm against the tracker-noise floor {noise_floor:.4} mm"
    );

    // The stopping rule: n_required is the first n of the curve whose largest
    // u95 reaches required_u95_mm, and the curve does not rise with n.
    let curve_file = out.join("select_work/u95_curve.parquet");
    let curve = table::read_parquet(&curve_file).unwrap();
    let n = schema::i64_values(&curve, "n", &curve_file).unwrap();
    let largest = schema::f64_values(&curve, "max_u95_mm", &curve_file).unwrap();
    let mean = schema::f64_values(&curve, "mean_u95_mm", &curve_file).unwrap();
    assert!(n.windows(2).all(|w| w[1] == w[0] + 1), "{n:?}");
    for w in mean.windows(2) {
        assert!(w[1] <= w[0] * (1.0 + 1e-9), "{mean:?}");
    }
    let required = 0.02;
    let first = n[largest.iter().position(|&u| u <= required).unwrap()];
    let selection = out.join("select_work/selection.parquet");
    assert_eq!(fact(&selection, "n_required"), first.to_string());
    // The curve's n = 50 is the selected n: the same u95 to a few percent
    // (the selection keeps the best of its restarts, the curve one path).
    let at_50 = largest[n.iter().position(|&k| k == 50).unwrap()];
    assert!(
        (at_50 - predicted_work).abs() < 0.1 * predicted_work,
        "{at_50} vs {predicted_work}"
    );
    // Every target is worked in a branch the candidates cover; the design for
    // the work puts more of its rows there than O1 (38 and 13 of 50 when
    // measured).
    let in_branch = |selection: &Path| -> usize {
        let branches = fact(selection, "work_branches");
        branches
            .split("; ")
            .map(|b| {
                let selected = b.rsplit(", ").next().unwrap();
                let candidates = b.split(", ").nth(1).unwrap();
                assert!(!candidates.starts_with("0 "), "{branches}");
                selected
                    .trim_end_matches(" selected")
                    .parse::<usize>()
                    .unwrap()
            })
            .sum()
    };
    // The points `poses` added near the holes (after the cube's 125) are in
    // the holes' branches.
    let poses_file = out.join("poses/poses.parquet");
    let poses = table::read_parquet(&poses_file).unwrap();
    let ids = schema::i64_values(&poses, "config_id", &poses_file).unwrap();
    let pose_branches = schema::i64_values(&poses, "branch", &poses_file).unwrap();
    let targets_file = out.join("select_work/work_targets.parquet");
    let targets = table::read_parquet(&targets_file).unwrap();
    let target_branches: Vec<i64> = targets
        .column("branch")
        .unwrap()
        .i64()
        .unwrap()
        .iter()
        .flatten()
        .collect();
    let near: Vec<i64> = (0..ids.len())
        .filter(|k| ids[*k] > 125)
        .map(|k| pose_branches[k])
        .collect();
    assert!(near.len() >= 60, "{} points near the holes", near.len());
    assert!(
        near.iter().all(|b| target_branches.contains(b)),
        "{near:?} against the targets' {target_branches:?}"
    );
    let o1_selection = out.join("select_o1/selection.parquet");
    let (work_rows, o1_rows) = (in_branch(&selection), in_branch(&o1_selection));
    assert!(work_rows > o1_rows, "work {work_rows}, O1 {o1_rows}");
    // O1's 50 rows do not reach the required u95: a warning says so.
    assert!(predicted_o1 > required);
    assert!(fact(&o1_selection, "warning").contains("required_u95_mm"));
}
