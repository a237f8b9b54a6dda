//! Design stages re-checked independently of how they were produced: every pose
//! reaches its target with the SMR facing the tracker within the limits, and
//! every candidate wrench is produced by its cable tensions within bounds.

mod common;

use std::path::Path;

use egcal::cdpr::{CableRobotSpec, structure_matrix};
use egcal::robot::{Frame, ParamValues, Robot, RobotSpec};
use egcal::table::{self, schema};
use nalgebra::{SVector, Vector3};

fn robot() -> Robot {
    Robot::new(RobotSpec::load(&common::root().join("jobs/robots/irb1600_145.toml")).unwrap())
}

fn stage(kind: &str, settings: &str, inputs: &[(&str, &Path)], out: &Path) -> (i32, String) {
    let settings_file = out.join(format!("{kind}.toml"));
    std::fs::write(&settings_file, settings).unwrap();
    let robot = common::root().join("jobs/robots/irb1600_145.toml");
    let mut args = vec![
        "stage".to_string(),
        kind.to_string(),
        "--robot".into(),
        robot.display().to_string(),
        "--settings".into(),
        settings_file.display().to_string(),
        "--out".into(),
        out.display().to_string(),
        "--seed".into(),
        "5".into(),
    ];
    for (name, path) in inputs {
        args.push("--input".into());
        args.push(format!("{name}={}", path.display()));
    }
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let (code, _, stderr) = common::run(&args, out);
    (code, stderr)
}

#[test]
fn poses_reach_their_targets_facing_the_tracker_and_wrenches_are_feasible() {
    let out = tempfile::tempdir().unwrap();
    let (code, stderr) = stage("poses", "points_per_axis = 3\n", &[], out.path());
    assert_eq!(code, 0, "{stderr}");
    let poses_path = out.path().join("poses.parquet");
    let poses = table::read_parquet(&poses_path).unwrap();
    assert!(poses.height() >= 20, "{} poses of 27", poses.height());
    let robot = robot();
    let nominal = ParamValues::nominal(robot.spec());
    let tracker = robot.world_from_base(&nominal).inverse().origin_mm;
    let col = |name: &str| schema::f64_values(&poses, name, Path::new("p")).unwrap();
    let q: Vec<Vec<f64>> = schema::JOINT_COLUMNS.iter().map(|c| col(c)).collect();
    let (tx, ty, tz) = (col("target_x_mm"), col("target_y_mm"), col("target_z_mm"));
    let incidence = col("incidence_deg");
    for k in 0..poses.height() {
        let q_deg: [f64; 6] = std::array::from_fn(|i| q[i][k]);
        assert!(robot.within_limits(&q_deg), "row {k}: {q_deg:?}");
        let (_, tool) = robot.frames_in_base(&nominal, &q_deg);
        let target = Vector3::new(tx[k], ty[k], tz[k]);
        assert!(
            (tool.origin_mm - target).norm() < 1e-6,
            "row {k}: FK misses the target"
        );
        let facing = tool
            .axis(2)
            .dot(&(tracker - target).normalize())
            .acos()
            .to_degrees();
        assert!(
            facing <= 40.0 + 1e-9,
            "row {k}: SMR {facing}° off the tracker"
        );
        assert!((facing - incidence[k]).abs() < 1e-6);
    }

    let (code, stderr) = stage(
        "wrenches",
        "per_config = 4\n",
        &[("poses", &poses_path)],
        out.path(),
    );
    assert_eq!(code, 0, "{stderr}");
    let candidates = table::read_parquet(&out.path().join("candidates.parquet")).unwrap();
    assert!(
        candidates.height() >= poses.height(),
        "{} candidates",
        candidates.height()
    );
    let spec = CableRobotSpec::default();
    let col = |name: &str| schema::f64_values(&candidates, name, Path::new("c")).unwrap();
    let q: Vec<Vec<f64>> = schema::JOINT_COLUMNS.iter().map(|c| col(c)).collect();
    let w: Vec<Vec<f64>> = schema::WRENCH_COLUMNS.iter().map(|c| col(c)).collect();
    let t: Vec<Vec<f64>> = schema::TENSION_COLUMNS.iter().map(|c| col(c)).collect();
    for k in 0..candidates.height() {
        let q_deg: [f64; 6] = std::array::from_fn(|i| q[i][k]);
        let (_, tool): (_, Frame) = robot.frames_in_base(&nominal, &q_deg);
        let tensions = SVector::<f64, 8>::from_fn(|i, _| t[i][k]);
        for tension in tensions.iter() {
            assert!(*tension >= spec.min_tension_n - 1e-6 && *tension <= spec.max_tension_n + 1e-6);
        }
        let produced = structure_matrix(&spec, &tool) * tensions;
        for i in 0..6 {
            assert!(
                (produced[i] - w[i][k]).abs() < 1e-6,
                "row {k} component {i}: {} vs {}",
                produced[i],
                w[i][k]
            );
        }
        assert!(w[0][k].abs() <= 120.0 && w[3][k].abs() <= 10.0);
    }
}

#[test]
fn an_unreachable_box_is_dropped_with_its_reason() {
    let out = tempfile::tempdir().unwrap();
    let (code, stderr) = stage(
        "poses",
        "points_per_axis = 2\ncentre_mm = [3000.0, 0.0, 900.0]\norientation_attempts = 3\n",
        &[],
        out.path(),
    );
    assert_eq!(code, 3, "{stderr}");
    assert!(
        stderr.contains("no reachable collision-free pose at any of the 8 target points"),
        "{stderr}"
    );
    assert!(stderr.contains("\"unreachable\": 24"), "{stderr}");
}

/// The design claim of the default cable robot and the `poses` roll range: the
/// paper's 5 × 5 × 5 grid keeps at least 120 of its 125 points, every kept point
/// gets its 7 wrenches, and at least 80 % of the wrench draws are feasible
/// (measured: 122 points, 92–95 % of draws, over seeds).
#[test]
fn default_campaign_grid_keeps_its_points_and_most_wrench_draws() {
    let out = tempfile::tempdir().unwrap();
    let (code, stderr) = stage("poses", "points_per_axis = 5\n", &[], out.path());
    assert_eq!(code, 0, "{stderr}");
    let poses_path = out.path().join("poses.parquet");
    let points = table::read_parquet(&poses_path).unwrap().height();
    assert!(points >= 120, "{points} of 125 points kept");

    let (code, stderr) = stage(
        "wrenches",
        "per_config = 7\n",
        &[("poses", &poses_path)],
        out.path(),
    );
    assert_eq!(code, 0, "{stderr}");
    let candidates_path = out.path().join("candidates.parquet");
    let candidates = table::read_parquet(&candidates_path).unwrap().height();
    assert_eq!(candidates, 7 * points);
    let facts = table::read_provenance(&candidates_path)
        .unwrap()
        .expect("egcal writes provenance")
        .extra;
    let draws: f64 = facts["draws"].parse().unwrap();
    let acceptance = candidates as f64 / draws;
    assert!(acceptance > 0.8, "{acceptance} of {draws} draws feasible");
}
