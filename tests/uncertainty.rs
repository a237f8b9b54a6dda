//! Predicted-position uncertainty (issue #16) against what it claims, on the
//! simulator with tracker noise only (no transmission error, no unmodelled
//! compliance, exact joints and wrenches), so the model is right and the noise
//! is all there is:
//!
//! * 200 re-identifications from fresh noise scatter the predicted positions as
//!   J·Σ·Jᵀ says (±20 %);
//! * validation errors fall inside the 95 % ellipsoid of J·Σ·Jᵀ + σ²·I for
//!   0.95 ± 0.03 of the rows;
//! * reparametrising (a parameter's unit, a dependent parameter carrying the
//!   degree of freedom instead of its partner) leaves J·Σ·Jᵀ unchanged;
//! * through `egcal run`: identify's covariance matches its standard errors,
//!   and predict, validate and compensate write the §7 columns.

mod common;

use std::path::Path;

use egcal::calibration::fit::{FitOptions, Observations};
use egcal::calibration::uncertainty::{
    chi_squared_3_quantile, position_covariances, propagate, within_ellipsoid,
};
use egcal::calibration::{CalibrationOptions, ModelResult, calibrate};
use egcal::rig::Rig;
use egcal::rig::simulator::{Simulator, SimulatorSettings};
use egcal::robot::{ConfWrench, ParamId, ParamValues, Robot};
use egcal::table::parameters::{ModelName, ParamStatus};
use egcal::table::{self, schema};
use nalgebra::{Matrix3, Vector3};

use common::sample::{random_rows, robot_and_truth};

/// Tracker noise per axis (mm), the only error the simulator adds.
const NOISE_MM: f64 = 0.05;
const CALIBRATION_ROWS: usize = 60;

/// The simulator with tracker noise only.
fn noise_only(robot: &Robot, truth: &ParamValues, seed: u64) -> Simulator {
    let settings = SimulatorSettings {
        tracker_noise_mm: NOISE_MM,
        tracker_noise_mm_per_m: 0.0,
        encoder_noise_deg: 0.0,
        wrench_tracking_relative: 0.0,
        force_tracking_n: 0.0,
        moment_tracking_nm: 0.0,
        sensor_noise_n: 0.0,
        sensor_noise_nm: 0.0,
        transmission_error_deg: 0.0,
        quadratic_compliance: 0.0,
        ..SimulatorSettings::default()
    };
    Simulator::new(robot.clone(), *truth, settings, seed).unwrap()
}

/// The rows measured on `rig` as a measure stage does (cw_id = first_id + k).
fn measure(rig: &mut Simulator, rows: &[ConfWrench], first_id: i64) -> Vec<Vector3<f64>> {
    rows.iter()
        .enumerate()
        .map(|(k, row)| {
            rig.move_joints(first_id + k as i64, row.q_deg).unwrap();
            rig.apply_wrench(row.wrench.to_array()).unwrap();
            let p = rig.measure().unwrap();
            rig.release_wrench().unwrap();
            Vector3::from(p)
        })
        .collect()
}

/// The elasto-geometric model by least squares from the truth (the linearisation
/// point the covariance describes), candidates `candidates`.
fn identify(
    robot: &Robot,
    truth: &ParamValues,
    rows: &[ConfWrench],
    measured: &[Vector3<f64>],
    candidates: Vec<ParamId>,
    stop_step_mm: f64,
) -> ModelResult {
    let options = CalibrationOptions {
        robust: None,
        ..CalibrationOptions::new(
            candidates,
            FitOptions {
                stop_step_mm,
                // Only the step criterion: the cost flattens long before the
                // estimate stops moving along the weakest directions.
                stop_relative_cost: 0.0,
                max_iterations: 500,
                ..FitOptions::default()
            },
        )
    };
    let result = calibrate(
        robot,
        ModelName::Elastogeometric,
        &Observations::new(rows, measured),
        truth,
        &options,
    )
    .unwrap();
    assert!(result.converged, "{:?}", result.trace);
    result
}

/// J·Σ·Jᵀ of `rows` under a fitted model.
fn predicted(robot: &Robot, result: &ModelResult, rows: &[ConfWrench]) -> Vec<Matrix3<f64>> {
    let d = result.diagnostics.as_ref().unwrap();
    position_covariances(robot, &result.set.values, &d.free, &d.covariance, rows)
}

fn positions(robot: &Robot, p: &ParamValues, rows: &[ConfWrench]) -> Vec<Vector3<f64>> {
    egcal::robot::batch_predict(robot, p, rows)
        .iter()
        .map(|p| p.position_mm)
        .collect()
}

/// One campaign: 200 re-identifications from fresh noise on the same rows,
/// with the predictions at test rows and fresh validation errors.
#[test]
fn re_identifications_scatter_as_predicted_and_errors_cover_95_percent() {
    const FITS: usize = 200;
    const VALIDATION_ROWS: usize = 5;
    let (robot, truth) = robot_and_truth();
    let rows = random_rows(&robot, 31, CALIBRATION_ROWS);
    let test_rows = random_rows(&robot, 32, 4);
    let radius_squared = chi_squared_3_quantile(0.95);
    let mut predictions: Vec<Vec<Vector3<f64>>> = vec![Vec::new(); test_rows.len()];
    let mut claimed = vec![Matrix3::zeros(); test_rows.len()];
    let (mut covered, mut checked) = (0usize, 0usize);
    for fit in 0..FITS {
        let mut rig = noise_only(&robot, &truth, 1000 + fit as u64);
        let measured = measure(&mut rig, &rows, 0);
        let result = identify(
            &robot,
            &truth,
            &rows,
            &measured,
            ParamId::all().collect(),
            1e-6,
        );
        for (k, p) in positions(&robot, &result.set.values, &test_rows)
            .into_iter()
            .enumerate()
        {
            predictions[k].push(p);
        }
        for (sum, c) in claimed
            .iter_mut()
            .zip(predicted(&robot, &result, &test_rows))
        {
            *sum += c / FITS as f64;
        }
        // Fresh rows, measured by the same rig (other cw_ids: independent noise).
        let validation = random_rows(&robot, 5000 + fit as u64, VALIDATION_ROWS);
        let measured = measure(&mut rig, &validation, 10_000);
        let sigma2 = result.diagnostics.as_ref().unwrap().variance_factor;
        let covariances = predicted(&robot, &result, &validation);
        for ((p, m), c) in positions(&robot, &result.set.values, &validation)
            .iter()
            .zip(&measured)
            .zip(&covariances)
        {
            let total = c + Matrix3::identity() * sigma2;
            checked += 1;
            covered += usize::from(within_ellipsoid(&(p - m), &total, radius_squared).unwrap());
        }
    }
    for (k, (samples, claimed)) in predictions.iter().zip(&claimed).enumerate() {
        let mean = samples.iter().sum::<Vector3<f64>>() / samples.len() as f64;
        let scatter = samples
            .iter()
            .map(|p| (p - mean) * (p - mean).transpose())
            .sum::<Matrix3<f64>>()
            / (samples.len() - 1) as f64;
        let ratio = scatter.trace() / claimed.trace();
        println!(
            "test row {k}: trace of the scatter {:.3e} mm², of J·Σ·Jᵀ {:.3e} mm², ratio {ratio:.3}",
            scatter.trace(),
            claimed.trace()
        );
        assert!((ratio - 1.0).abs() < 0.2, "test row {k}: ratio {ratio}");
    }
    let coverage = covered as f64 / checked as f64;
    println!("coverage of the 95 % ellipsoid: {coverage:.4} over {checked} validation rows");
    assert!((coverage - 0.95).abs() < 0.03, "coverage {coverage}");
}

/// A unit change scales a Jacobian column by 1/c and Σ's row and column by c;
/// a dependent parameter that carries its partner's degree of freedom (dtheta1
/// for gamma_w, dd3 for dd2: rank analysis keeps the partner when both are
/// candidates) changes J and Σ but not what they say about positions.
#[test]
fn reparametrising_leaves_the_predicted_covariance_unchanged() {
    let (robot, truth) = robot_and_truth();
    let rows = random_rows(&robot, 41, CALIBRATION_ROWS);
    let test_rows = random_rows(&robot, 42, 6);
    let mut rig = noise_only(&robot, &truth, 43);
    let measured = measure(&mut rig, &rows, 0);
    // Converged tightly: J·Σ·Jᵀ depends on the point it is evaluated at, and
    // the two parametrisations should reach the same predictions.
    let usual = identify(
        &robot,
        &truth,
        &rows,
        &measured,
        ParamId::all().collect(),
        1e-7,
    );
    let reference = predicted(&robot, &usual, &test_rows);
    let close = |a: &Matrix3<f64>, b: &Matrix3<f64>, tolerance: f64| {
        (a - b).abs().max() <= tolerance * b.abs().max()
    };

    // Units: degrees to radians, millimetres to metres, deg/(N·m) to rad/(N·m).
    let d = usual.diagnostics.as_ref().unwrap();
    let m = d.free.len();
    let per_new_unit: Vec<f64> = d
        .free
        .iter()
        .map(|id| match id.unit() {
            "mm" => 1e-3,
            _ => std::f64::consts::PI / 180.0,
        })
        .collect();
    let scaled_sigma: Vec<f64> = (0..m * m)
        .map(|ij| d.covariance[ij] * per_new_unit[ij / m] * per_new_unit[ij % m])
        .collect();
    let prepared = robot.prepare(&usual.set.values);
    let mut columns = vec![Vector3::zeros(); m];
    for (row, want) in test_rows.iter().zip(&reference) {
        prepared.jacobian_row(row, &d.free, &mut columns);
        let scaled: Vec<Vector3<f64>> = columns
            .iter()
            .zip(&per_new_unit)
            .map(|(c, s)| c / *s)
            .collect();
        let got = propagate(&scaled, &scaled_sigma);
        let relative = (got - want).abs().max() / want.abs().max();
        // Only rounding differs, but J·Σ·Jᵀ of strongly correlated parameters
        // cancels large terms (its entries are ~1e-3 of ‖J‖²‖Σ‖), so 1e-8, not 1e-12.
        assert!(close(&got, want, 1e-8), "relative difference {relative:e}");
    }

    // The dependent partners instead.
    let swapped_out = ["gamma_w", "dd2"].map(|n| ParamId::from_name(n).unwrap());
    let merged = identify(
        &robot,
        &truth,
        &rows,
        &measured,
        ParamId::all()
            .filter(|p| !swapped_out.contains(p))
            .collect(),
        1e-7,
    );
    for (name, was) in [
        ("dtheta1", ParamStatus::Dependent),
        ("dd3", ParamStatus::Dependent),
    ] {
        let id = ParamId::from_name(name).unwrap();
        assert_eq!(usual.set.status[id.index()], was, "{name}");
        assert_eq!(
            merged.set.status[id.index()],
            ParamStatus::Identified,
            "{name}"
        );
    }
    // Not to rounding: the two fits end at residual sums 1e-6 (relative) apart,
    // so the two families are not exactly one model here; J·Σ·Jᵀ agrees to 5e-6.
    for (got, want) in predicted(&robot, &merged, &test_rows)
        .iter()
        .zip(&reference)
    {
        let relative = (got - want).abs().max() / want.abs().max();
        assert!(close(got, want, 1e-4), "relative difference {relative:e}");
    }
}

/// Identify, validate, predict and compensate through `egcal run` on
/// noise-only simulated rows, with the covariance bound.
#[test]
fn the_stages_write_the_uncertainty_and_its_coverage() {
    let dir = tempfile::tempdir().unwrap();
    let root = common::root();
    let simulator = format!(
        "simulator = {{ tracker_noise_mm = {NOISE_MM}, encoder_noise_deg = 0.0, wrench_tracking_relative = 0.0, force_tracking_n = 0.0, moment_tracking_nm = 0.0, sensor_noise_n = 0.0, sensor_noise_nm = 0.0, transmission_error_deg = 0.0 }}"
    );
    let simulator_later = simulator.replace(" }", ", clock_start = \"2026-02-01T00:00:00Z\" }");
    let job = format!(
        r#"[job]
name = "uncertainty"
seed = 11
robot = "{robot}"
cable_robot = "{cable}"
output = "out"

[[stages]]
id = "poses"
kind = "poses"
points_per_axis = 4
edge_mm = 400.0

[[stages]]
id = "wrenches"
kind = "wrenches"
inputs = {{ poses = "poses" }}
per_config = 3

[[stages]]
id = "calibration"
kind = "measure"
inputs = {{ conf_wrenches = "wrenches", truth = "{truth}" }}
{simulator}

# Measured again, later: independent noise on the same rows.
[[stages]]
id = "check"
kind = "measure"
inputs = {{ conf_wrenches = "wrenches", truth = "{truth}" }}
{simulator_later}

[[stages]]
id = "identify"
kind = "identify"
inputs = {{ measurements = "calibration.measurements" }}
models = ["nominal", "elastogeometric"]
loss = "least_squares"

[[stages]]
id = "validate"
kind = "validate"
inputs = {{ measurements = "check.measurements", parameters = "identify.parameters", covariance = "identify.covariance" }}

[[stages]]
id = "predict"
kind = "predict"
inputs = {{ conf_wrenches = "wrenches", parameters = "identify.parameters", covariance = "identify.covariance" }}

[[stages]]
id = "compensate"
kind = "compensate"
inputs = {{ targets = "{targets}", parameters = "identify.parameters", covariance = "identify.covariance" }}
"#,
        robot = root.join("jobs/robots/irb1600_145.toml").display(),
        cable = root.join("jobs/cdpr/default.toml").display(),
        truth = root.join("jobs/truth/irb1600_paper.parquet").display(),
        targets = root.join("jobs/targets/grid.parquet").display(),
    );
    let path = dir.path().join("job.toml");
    std::fs::write(&path, job).unwrap();
    let (code, out, err) = common::run(&["run", path.to_str().unwrap()], dir.path());
    assert_eq!(code, 0, "{out}\n{err}");
    let out_dir = dir.path().join("out");
    let read = |stage: &str, name: &str| {
        table::read_parquet(&out_dir.join(stage).join(format!("{name}.parquet"))).unwrap()
    };
    let file = Path::new("t");

    // Item 1: the covariance's diagonal is the squared standard errors.
    let parameters = read("identify", "parameters");
    let covariance = read("identify", "covariance");
    let spec = egcal::robot::RobotSpec::load(&root.join("jobs/robots/irb1600_145.toml")).unwrap();
    let sets = egcal::table::parameters::from_frame(&parameters, file, &spec).unwrap();
    let eg = sets
        .iter()
        .find(|s| s.model == ModelName::Elastogeometric)
        .unwrap();
    let model_covariance = egcal::table::parameters::covariance_of(&covariance, file, eg)
        .unwrap()
        .unwrap();
    let m = model_covariance.free.len();
    assert_eq!(m, 32);
    for (i, id) in model_covariance.free.iter().enumerate() {
        let se = eg.std_errors[id.index()].unwrap();
        let variance = model_covariance.matrix[i * m + i];
        assert!((variance - se * se).abs() <= 1e-12 * se * se, "{id}");
    }
    let factor = model_covariance.variance_factor.unwrap();
    assert!(
        (factor.sqrt() / NOISE_MM - 1.0).abs() < 0.15,
        "σ̂ {} mm for noise {NOISE_MM} mm",
        factor.sqrt()
    );

    // validate: coverage for the fitted model, null for nominal.
    let stats = read("validate", "stats");
    let models = schema::str_values(&stats, "model", file).unwrap();
    let coverage: Vec<Option<f64>> = stats
        .column("coverage_95")
        .unwrap()
        .f64()
        .unwrap()
        .iter()
        .collect();
    for (model, coverage) in models.iter().zip(&coverage) {
        match model.as_deref() {
            Some("nominal") => assert_eq!(*coverage, None),
            _ => {
                let coverage = coverage.unwrap();
                println!("validate coverage_95 {coverage:.3}");
                assert!((coverage - 0.95).abs() < 0.06, "{coverage}");
            }
        }
    }
    let errors = read("validate", "errors");
    assert!(errors.column("covered_95").is_ok());

    // predict and compensate: the six columns, positive variances.
    for (stage, name) in [("predict", "predictions"), ("compensate", "commands")] {
        let df = read(stage, name);
        for (column, i, j) in schema::POSITION_COVARIANCE_COLUMNS {
            let values = schema::f64_values(&df, column, file).unwrap();
            assert!(
                values.iter().all(|v| v.is_finite() && (i != j || *v > 0.0)),
                "{stage} {column}"
            );
        }
    }
    // compensate's u95_mm is the 95 % radius of those columns' largest
    // eigenvalue, sqrt(χ²₃(0.95)·λmax), computed here from the columns.
    let df = read("compensate", "commands");
    let cov: Vec<Vec<f64>> = schema::POSITION_COVARIANCE_COLUMNS
        .iter()
        .map(|(column, _, _)| schema::f64_values(&df, column, file).unwrap())
        .collect();
    let u95 = schema::f64_values(&df, "u95_mm", file).unwrap();
    for (k, u) in u95.iter().enumerate() {
        let mut m = Matrix3::zeros();
        for (c, (_, i, j)) in schema::POSITION_COVARIANCE_COLUMNS.iter().enumerate() {
            m[(*i, *j)] = cov[c][k];
            m[(*j, *i)] = cov[c][k];
        }
        let largest = m.symmetric_eigenvalues().max();
        assert!(
            (u * u - 7.814_727_903 * largest).abs() < 1e-9 * (1.0 + u * u),
            "{k}"
        );
    }
}
