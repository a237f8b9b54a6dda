//! Identification in a real cell (spec §7): several targets, per-point σ, frames
//! that are unknown or far off, re-registration, fixed parameters, and bad rows
//! that must not spoil a calibration.

mod common;

use egcal::calibration::fit::{self, FitOptions, Observations};
use egcal::calibration::{CalibrationOptions, ModelResult, calibrate, registered_start};
use egcal::robot::{ConfWrench, ParamId, ParamValues, Robot, RobotSpec, batch_jacobian};
use egcal::table::parameters::{ModelName, ParamStatus};
use faer::Mat;
use faer::prelude::*;
use nalgebra::Vector3;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};

use common::measured::{noisy, positions, write_measurements};
use common::sample::{random_rows, robot_and_truth};

fn id(name: &str) -> ParamId {
    ParamId::from_name(name).unwrap()
}

/// The identify stage's way: frames registered from the robot file's values, then the fit.
fn identify_registered(
    robot: &Robot,
    model: ModelName,
    data: &Observations<'_>,
    options: &CalibrationOptions,
) -> ModelResult {
    let nominal = ParamValues::nominal(robot.spec());
    let (start, _) = registered_start(robot, &nominal, data).unwrap();
    calibrate(robot, model, data, &start, options).unwrap()
}

fn all_candidates() -> CalibrationOptions {
    CalibrationOptions::new(ParamId::all().collect(), FitOptions::default())
}

fn identified(result: &ModelResult) -> Vec<ParamId> {
    ParamId::all_with_targets(6, egcal::robot::MAX_TARGETS)
        .filter(|id| result.set.status[id.index()] == ParamStatus::Identified)
        .collect()
}

#[test]
fn three_targets_on_the_simulator_recover_each_tool_translation() {
    let (robot, mut truth) = robot_and_truth();
    let offsets = [
        Vector3::zeros(),
        Vector3::new(60.0, -40.0, 25.0),
        Vector3::new(-45.0, 35.0, 80.0),
    ];
    for (target, offset) in offsets.iter().enumerate() {
        for axis in 0..3 {
            let slot = ParamId::target_translation(target, axis);
            truth.set(
                slot,
                truth.get(ParamId::target_translation(0, axis)) + offset[axis],
            );
        }
    }
    let mut rows = random_rows(&robot, 31, 300);
    for (k, row) in rows.iter_mut().enumerate() {
        row.target = k % 3;
    }
    let measured = noisy(&positions(&robot, &truth, &rows), 0.02, 32);
    let options = CalibrationOptions {
        targets: 3,
        ..all_candidates()
    };
    let data = Observations::new(&rows, &measured);
    let result = identify_registered(&robot, ModelName::Elastogeometric, &data, &options);
    assert!(result.converged);
    let free = identified(&result);
    for target in 0..3 {
        for axis in 0..3 {
            let slot = ParamId::target_translation(target, axis);
            assert!(
                free.contains(&slot),
                "target {target} axis {axis} not identified"
            );
            let se = result.set.std_errors[slot.index()].unwrap();
            let error = result.set.values.get(slot) - truth.get(slot);
            assert!(
                error.abs() < 4.0 * se && error.abs() < 0.05,
                "target {target} axis {axis}: error {error} mm, se {se}"
            );
        }
    }
    // With every target's translation free, a rotation of the flange frame is
    // absorbed by the translations: the tool angles and joint 6's offsets stay
    // dependent, as with one target.
    for name in ["alpha_t", "beta_t", "gamma_t", "dtheta6", "dd6"] {
        assert_eq!(
            result.set.status[id(name).index()],
            ParamStatus::Dependent,
            "{name}"
        );
    }
    // Every other identified parameter is as good as with one target.
    for slot in free.iter().filter(|p| !p.is_tool_translation()) {
        let se = result.set.std_errors[slot.index()].unwrap();
        let error = result.set.values.get(*slot) - truth.get(*slot);
        assert!(error.abs() < 4.5 * se, "{slot}: error {error}, se {se}");
    }
}

#[test]
fn a_weighted_fit_equals_a_hand_weighted_least_squares_solution() {
    let (robot, truth) = robot_and_truth();
    let nominal = ParamValues::nominal(robot.spec());
    let rows = random_rows(&robot, 41, 400);
    let mut rng = StdRng::seed_from_u64(42);
    let sigma_mm: Vec<Vector3<f64>> = (0..rows.len())
        .map(|_| Vector3::from_fn(|_, _| rng.random_range(0.005..0.08)))
        .collect();
    let exact = positions(&robot, &truth, &rows);
    let normal = Normal::new(0.0, 1.0).unwrap();
    let measured: Vec<Vector3<f64>> = exact
        .iter()
        .zip(&sigma_mm)
        .map(|(p, s)| p + Vector3::from_fn(|a, _| s[a] * normal.sample(&mut rng)))
        .collect();
    let scales: Vec<Vector3<f64>> = sigma_mm.iter().map(|s| s.map(|v| 1.0 / v)).collect();
    let free = egcal::robot::Selection::spec_identifiable();
    let m = free.len();
    let options = FitOptions {
        algorithm: fit::Algorithm::Paper,
        stop_step_mm: 1e-10,
        ..FitOptions::default()
    };
    let data = Observations {
        row_scale: Some(&scales),
        ..Observations::new(&rows, &measured)
    };
    let streamed = fit::fit(&robot, &nominal, &data, free.ids(), &options).unwrap();
    assert!(streamed.converged, "{:?}", streamed.trace);

    // By hand: Gauss–Newton on the rows multiplied by 1/σ, dense QR.
    let equations = 3 * rows.len();
    let weight = |i: usize| 1.0 / sigma_mm[i / 3][i % 3];
    let mut dense = nominal;
    let mut jacobian = Mat::<f64>::zeros(0, 0);
    let mut residual = Mat::<f64>::zeros(0, 0);
    for _ in 0..30 {
        let batch = batch_jacobian(&robot, &dense, &rows, free.ids());
        jacobian = Mat::from_fn(equations, m, |i, j| weight(i) * batch.entry(i, j));
        residual = Mat::<f64>::from_fn(equations, 1, |i, _| {
            weight(i) * (measured[i / 3][i % 3] - batch.predictions[i / 3].position_mm[i % 3])
        });
        let delta = jacobian.qr().solve_lstsq(&residual);
        for (j, p) in free.ids().iter().enumerate() {
            dense.set(*p, dense.get(*p) + delta[(j, 0)]);
        }
        if (0..m).all(|j| delta[(j, 0)].abs() < 1e-12) {
            break;
        }
    }
    let rss: f64 = (0..equations).map(|i| residual[(i, 0)].powi(2)).sum();
    let variance_factor = rss / (equations - m) as f64;
    let svd = jacobian.thin_svd().unwrap();
    let s = svd.S().column_vector();
    for (j, p) in free.ids().iter().enumerate() {
        let (got, want) = (streamed.values.get(*p), dense.get(*p));
        assert!(
            (got - want).abs() <= 1e-8 * want.abs().max(1e-3),
            "{p}: weighted fit {got}, by hand {want}"
        );
        let variance: f64 = (0..m).map(|k| (svd.V()[(j, k)] / s[k]).powi(2)).sum();
        let want_se = (variance * variance_factor).sqrt();
        let got_se = streamed.std_errors[p.index()].unwrap();
        assert!(
            (got_se - want_se).abs() <= 1e-6 * want_se,
            "{p}: standard error {got_se} vs {want_se}"
        );
    }
    // The weights matter: the unweighted fit is another solution.
    let plain = fit::fit(
        &robot,
        &nominal,
        &Observations::new(&rows, &measured),
        free.ids(),
        &options,
    )
    .unwrap();
    let dd2 = id("dd2");
    assert!((plain.values.get(dd2) - streamed.values.get(dd2)).abs() > 1e-6);
}

/// The IRB 1600 robot file with its `[world]` replaced.
fn robot_with_world(world: &str) -> Robot {
    let root = common::root();
    let text = std::fs::read_to_string(root.join("jobs/robots/irb1600_145.toml")).unwrap();
    let start = text.find("[world]").unwrap();
    let end = start + text[start..].find("[tool]").unwrap();
    let text = format!("{}{world}\n{}", &text[..start], &text[end..]);
    Robot::new(RobotSpec::parse(&text, std::path::Path::new("r.toml")).unwrap())
}

#[test]
fn a_world_frame_3_m_and_30_degrees_off_or_absent_calibrates_the_same() {
    let (robot, truth) = robot_and_truth();
    let rows = random_rows(&robot, 51, 200);
    let measured = noisy(&positions(&robot, &truth, &rows), 0.02, 52);
    let data = Observations::new(&rows, &measured);
    let options = all_candidates();
    let reference = identify_registered(&robot, ModelName::Elastogeometric, &data, &options);
    let far_off = robot_with_world(
        "[world]\nx_mm = -1674.0\ny_mm = 1362.0\nz_mm = -1476.0\nalpha_deg = -150.0\nbeta_deg = 20.0\ngamma_deg = 10.0\n",
    );
    let absent = robot_with_world("");
    for (what, robot) in [("3 m and 30 deg off", &far_off), ("absent", &absent)] {
        for model in [ModelName::Registered, ModelName::Elastogeometric] {
            let result = identify_registered(robot, model, &data, &options);
            let same = if model == ModelName::Elastogeometric {
                reference.clone()
            } else {
                identify_registered(&robot_and_truth().0, model, &data, &options)
            };
            assert!(result.converged, "{what} {model}");
            let residual_rms = |r: &ModelResult| {
                (r.residuals_mm.iter().map(|v| v.norm_squared()).sum::<f64>()
                    / r.residuals_mm.len() as f64)
                    .sqrt()
            };
            assert!(
                (residual_rms(&result) - residual_rms(&same)).abs() < 1e-9,
                "{what} {model}: rms {} vs {}",
                residual_rms(&result),
                residual_rms(&same)
            );
            for p in identified(&same) {
                let (got, want) = (result.set.values.get(p), same.set.values.get(p));
                // Angles may come out on another 360° turn; positions are what count.
                let difference = if p.unit() == "deg" {
                    (got - want + 180.0).rem_euclid(360.0) - 180.0
                } else {
                    got - want
                };
                let se = same.set.std_errors[p.index()].unwrap();
                assert!(
                    difference.abs() < 1e-4 * se,
                    "{what} {model} {p}: {got} vs {want} (se {se})"
                );
            }
        }
    }
}

#[test]
fn re_registration_recovers_a_moved_tracker_and_leaves_the_robot_untouched() {
    let (robot, truth) = robot_and_truth();
    // The calibration in service: the truth itself.
    let mut moved = truth;
    for (name, change) in [
        ("x_w", 420.0),
        ("y_w", -260.0),
        ("z_w", 95.0),
        ("gamma_w", 17.0),
        ("beta_w", -2.0),
        ("z_t", 40.0),
        ("x_t", -12.0),
    ] {
        moved.set(id(name), moved.get(id(name)) + change);
    }
    let rows = random_rows(&robot, 61, 120);
    let measured = noisy(&positions(&robot, &moved, &rows), 0.02, 62);
    let data = Observations::new(&rows, &measured);
    let options = all_candidates();
    let (start, _) = registered_start(&robot, &truth, &data).unwrap();
    let result = calibrate(&robot, ModelName::Reregistered, &data, &start, &options).unwrap();
    assert!(result.converged);
    for p in ParamId::all() {
        let value = result.set.values.get(p);
        if p.is_world() || p.is_tool_translation() {
            if result.set.status[p.index()] == ParamStatus::Identified {
                let se = result.set.std_errors[p.index()].unwrap();
                let error = value - moved.get(p);
                assert!(error.abs() < 4.0 * se, "{p}: error {error}, se {se}");
            }
        } else {
            assert_eq!(value, truth.get(p), "{p} changed");
            assert_eq!(result.set.status[p.index()], ParamStatus::Fixed, "{p}");
        }
    }
    let rms = (result
        .residuals_mm
        .iter()
        .map(|r| r.norm_squared())
        .sum::<f64>()
        / (3 * rows.len()) as f64)
        .sqrt();
    assert!(rms < 0.03, "residual rms {rms} mm");
}

#[test]
fn fixed_parameters_hold_their_value_and_say_so() {
    let (robot, truth) = robot_and_truth();
    let rows = random_rows(&robot, 71, 80);
    let measured = noisy(&positions(&robot, &truth, &rows), 0.02, 72);
    let data = Observations::new(&rows, &measured);
    let options = CalibrationOptions {
        fixed: vec![(id("k6"), 0.0), (id("dd5"), 0.1)],
        ..all_candidates()
    };
    let result = identify_registered(&robot, ModelName::Elastogeometric, &data, &options);
    for (name, value) in [("k6", 0.0), ("dd5", 0.1)] {
        let p = id(name);
        assert_eq!(result.set.status[p.index()], ParamStatus::Fixed, "{name}");
        assert_eq!(result.set.values.get(p), value, "{name}");
        assert_eq!(result.set.std_errors[p.index()], None, "{name}");
    }
    assert_eq!(identified(&result).len(), 30);
}

/// Mean validation error (mm) of `values` on `rows` against `measured`.
fn mean_error(
    robot: &Robot,
    values: &ParamValues,
    rows: &[ConfWrench],
    measured: &[Vector3<f64>],
) -> f64 {
    positions(robot, values, rows)
        .iter()
        .zip(measured)
        .map(|(p, m)| (p - m).norm())
        .sum::<f64>()
        / rows.len() as f64
}

/// Gross errors among 847 rows (the paper campaign's size) with default settings:
/// every identified parameter stays within one standard error of the clean fit,
/// and the validation error within 10 %.
#[test]
fn gross_errors_in_a_few_rows_cannot_spoil_the_calibration() {
    let (robot, truth) = robot_and_truth();
    let rows = random_rows(&robot, 81, 847);
    let clean = noisy(&positions(&robot, &truth, &rows), 0.02, 82);
    let held_out = random_rows(&robot, 83, 500);
    let held_out_measured = noisy(&positions(&robot, &truth, &held_out), 0.02, 84);
    let options = all_candidates();
    let fit_of = |measured: &[Vector3<f64>]| {
        identify_registered(
            &robot,
            ModelName::Elastogeometric,
            &Observations::new(&rows, measured),
            &options,
        )
    };
    let reference = fit_of(&clean);
    assert!(reference.robust.as_ref().unwrap().excluded.is_empty());
    let reference_error = mean_error(&robot, &reference.set.values, &held_out, &held_out_measured);

    let mut one_row = clean.clone();
    one_row[123] += Vector3::new(30.0, -40.0, 0.0);
    let mut rng = StdRng::seed_from_u64(85);
    let mut many = clean.clone();
    let mut spoiled = Vec::new();
    while spoiled.len() < 847 / 20 {
        let k = rng.random_range(0..847);
        if !spoiled.contains(&k) {
            let direction = Vector3::from_fn(|_, _| rng.random_range(-1.0..1.0)).normalize();
            many[k] += direction * rng.random_range(1.0..20.0);
            spoiled.push(k);
        }
    }
    for (case, measured, bad) in [
        ("one row by 50 mm", one_row, vec![123]),
        ("5 % by 1-20 mm", many, spoiled),
    ] {
        let result = fit_of(&measured);
        let summary = result.robust.as_ref().unwrap();
        let mut excluded = summary.excluded.clone();
        excluded.sort();
        let mut bad = bad;
        bad.sort();
        assert_eq!(excluded, bad, "{case}: excluded rows");
        for p in identified(&reference) {
            let se = reference.set.std_errors[p.index()].unwrap();
            let shift = result.set.values.get(p) - reference.set.values.get(p);
            assert!(shift.abs() < se, "{case} {p}: moved {shift}, se {se}");
        }
        let error = mean_error(&robot, &result.set.values, &held_out, &held_out_measured);
        assert!(
            (error - reference_error).abs() < 0.1 * reference_error,
            "{case}: validation error {error} vs {reference_error}"
        );
    }
}

#[test]
fn a_kinematic_model_s_load_errors_are_not_taken_for_outliers() {
    let (robot, truth) = robot_and_truth();
    let rows = random_rows(&robot, 91, 847);
    let measured = noisy(&positions(&robot, &truth, &rows), 0.02, 92);
    let result = identify_registered(
        &robot,
        ModelName::Kinematic,
        &Observations::new(&rows, &measured),
        &all_candidates(),
    );
    let summary = result.robust.as_ref().unwrap();
    assert!(
        summary.excluded.is_empty(),
        "{} rows excluded beyond {}",
        summary.excluded.len(),
        summary.threshold
    );
    assert!(
        summary.sigma > 0.1,
        "the scale follows the load errors: {}",
        summary.sigma
    );
}

/// Runs one identify stage of a job in `dir` with `settings` on `input`.
fn run_identify(
    dir: &std::path::Path,
    input: &std::path::Path,
    settings: &str,
) -> (i32, String, String) {
    let job = dir.join("job.toml");
    std::fs::write(
        &job,
        format!(
            "[job]\nname = \"bad_rows\"\nseed = 1\nrobot = \"{robot}\"\noutput = \"out\"\n\n\
             [[stages]]\nid = \"identify\"\nkind = \"identify\"\ninputs = {{ measurements = \"{input}\" }}\n{settings}\n",
            robot = common::root().join("jobs/robots/irb1600_145.toml").display(),
            input = input.display(),
        ),
    )
    .unwrap();
    common::run(&["run", "--force", job.to_str().unwrap()], dir)
}

/// The case: one row with q2 = 130° (outside the limits) and one with
/// q1 = 1e300 among the rows. By default both are dropped, named on stderr and in
/// `excluded_rows`, and the fit equals the one without them; with
/// `bad_rows = "fail"` the run fails naming the file and the row.
#[test]
fn rows_outside_the_joint_limits_or_absurd_are_dropped_and_named_or_fail() {
    use egcal::table::{self, parameters, schema};
    let dir = tempfile::tempdir().unwrap();
    let (robot, truth) = robot_and_truth();
    let rows = random_rows(&robot, 101, 200);
    let measured = noisy(&positions(&robot, &truth, &rows), 0.02, 102);
    let clean_input = dir.path().join("clean.parquet");
    write_measurements(&clean_input, &rows, &measured, 0);
    let (mut bad_rows, bad_measured) = (rows.clone(), measured.clone());
    bad_rows[10].q_deg[1] = 130.0;
    bad_rows[20].q_deg[0] = 1e300;
    let bad_input = dir.path().join("bad.parquet");
    write_measurements(&bad_input, &bad_rows, &bad_measured, 0);

    let (code, _, stderr) = run_identify(dir.path(), &clean_input, "");
    assert_eq!(code, 0, "{stderr}");
    let out = dir.path().join("out/identify");
    let read_eg = || {
        let df = table::read_parquet(&out.join("parameters.parquet")).unwrap();
        parameters::from_frame(&df, std::path::Path::new("p"), robot.spec())
            .unwrap()
            .remove(0)
    };
    let clean = read_eg();

    let (code, _, stderr) = run_identify(dir.path(), &bad_input, "");
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stderr.contains("2 of 200 rows of")
            && stderr.contains("dropped by the row checks")
            && stderr.contains("cw_id 10: q2_deg = 130 is outside the joint limits [-90, 120]")
            && stderr.contains("cw_id 20: q1_deg = 1e300"),
        "{stderr}"
    );
    let excluded =
        table::read_checked(&out.join("excluded_rows.parquet"), &schema::excluded_rows()).unwrap();
    assert_eq!(
        schema::i64_values(&excluded, "cw_id", std::path::Path::new("e")).unwrap(),
        vec![10, 20]
    );
    let dropped = read_eg();
    for p in ParamId::all().filter(|p| clean.status[p.index()] == ParamStatus::Identified) {
        let se = clean.std_errors[p.index()].unwrap();
        let shift = dropped.values.get(p) - clean.values.get(p);
        assert!(shift.abs() < 0.2 * se, "{p}: moved {shift}, se {se}");
    }

    let (code, _, stderr) = run_identify(dir.path(), &bad_input, "bad_rows = \"fail\"");
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains("bad.parquet: row 10 (cw_id 10): q2_deg = 130")
            && stderr.contains("2 bad rows"),
        "{stderr}"
    );

    let (code, _, stderr) = run_identify(dir.path(), &clean_input, "models = [\"reregistered\"]");
    assert_ne!(code, 0);
    assert!(
        stderr.contains("duplicate key") || stderr.contains("needs the input `start`"),
        "{stderr}"
    );
}
