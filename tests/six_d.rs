//! 6-D rows (spec §8): the tool's orientation measured with its position.
//! Simulated rows of a robot whose tool is turned on its flange (non-zero
//! `alpha_t`, `beta_t`, `gamma_t`) recover that rotation within two standard
//! errors, which positions alone cannot determine; and through `egcal run` the
//! orientation columns reach the fit and the validation's orientation errors.

mod common;

use std::path::Path;

use egcal::calibration::fit::{FitOptions, MeasuredOrientation, Observations};
use egcal::calibration::registration::xyz_euler_nearest;
use egcal::calibration::{CalibrationOptions, calibrate, registered_start};
use egcal::robot::{ConfWrench, ParamId, ParamValues, Robot};
use egcal::table::parameters::{ModelName, ParamStatus};
use egcal::table::{self, schema};
use nalgebra::{Matrix3, Rotation3, Vector3};
use polars::prelude::Column;
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, Normal};

use common::measured::{noisy, positions};
use common::sample::{random_rows, robot_and_truth};

/// The probe's mounting on the flange (deg).
const TOOL_ROTATION_DEG: [(&str, f64); 3] = [("alpha_t", 1.5), ("beta_t", -2.0), ("gamma_t", 30.0)];
/// Tracker noise per position axis (mm); the orientation noise is the same
/// error seen at [`LEVER_MM`] (rad per axis of the rotation vector).
const SIGMA_MM: f64 = 0.02;
const LEVER_MM: f64 = 100.0;

fn id(name: &str) -> ParamId {
    ParamId::from_name(name).unwrap()
}

/// The spec's truth with the probe turned on its flange.
fn truth_with_tool_rotation() -> (Robot, ParamValues) {
    let (robot, mut truth) = robot_and_truth();
    for (name, value) in TOOL_ROTATION_DEG {
        truth.set(id(name), value);
    }
    (robot, truth)
}

/// Each row's tool orientation (world ← tool) under `p`, turned by Gaussian
/// noise of `sigma_rad` per axis of a rotation vector.
fn orientations(
    robot: &Robot,
    p: &ParamValues,
    rows: &[ConfWrench],
    sigma_rad: f64,
    seed: u64,
) -> Vec<Matrix3<f64>> {
    let mut rng = StdRng::seed_from_u64(seed);
    let normal = Normal::new(0.0, sigma_rad).unwrap();
    rows.iter()
        .map(|row| {
            let exact = robot
                .tool_in_world(p, &row.q_deg, &row.wrench, &row.approach)
                .rotation;
            let noise = Vector3::from_fn(|_, _| normal.sample(&mut rng));
            Rotation3::new(noise).matrix() * exact
        })
        .collect()
}

#[test]
fn six_d_rows_recover_a_known_tool_rotation_within_two_standard_errors() {
    let (robot, truth) = truth_with_tool_rotation();
    let rows = random_rows(&robot, 71, 150);
    let measured = noisy(&positions(&robot, &truth, &rows), SIGMA_MM, 72);
    let rotations = orientations(&robot, &truth, &rows, SIGMA_MM / LEVER_MM, 73);
    let oriented: Vec<Option<MeasuredOrientation>> = rotations
        .iter()
        .map(|r| {
            Some(MeasuredOrientation {
                world_from_tool: *r,
                scale_per_deg: LEVER_MM.to_radians(),
            })
        })
        .collect();
    let six_d = Observations {
        orientations: Some(&oriented),
        ..Observations::new(&rows, &measured)
    };
    let options = CalibrationOptions::new(
        ParamId::all().collect(),
        FitOptions {
            max_iterations: 60,
            ..FitOptions::default()
        },
    );
    let nominal = ParamValues::nominal(robot.spec());

    // The closed-form start already has the mounting, to within the arm's
    // own errors (a few tenths of a degree).
    let (start, registration) = registered_start(&robot, &nominal, &six_d).unwrap();
    let rms_deg = registration.orientation_rms_deg.unwrap();
    assert!(rms_deg < 0.5, "{rms_deg}");
    for (name, value) in TOOL_ROTATION_DEG {
        assert!(
            (start.get(id(name)) - value).abs() < 0.5,
            "{name}: {}",
            start.get(id(name))
        );
    }

    let result = calibrate(&robot, ModelName::Elastogeometric, &six_d, &start, &options).unwrap();
    assert!(result.converged);
    for (name, value) in TOOL_ROTATION_DEG {
        let p = id(name);
        assert_eq!(
            result.set.status[p.index()],
            ParamStatus::Identified,
            "{name}"
        );
        let se = result.set.std_errors[p.index()].unwrap();
        let got = result.set.values.get(p);
        assert!(se > 0.0 && se < 0.02, "{name}: se {se}");
        assert!(
            (got - value).abs() < 2.0 * se,
            "{name}: {got} vs {value} ± {se}"
        );
    }
    // dtheta6 turns the tool about the flange axis as the mounting does: the
    // frame is kept, the joint offset held (rank analysis, tool angles first).
    assert_eq!(
        result.set.status[id("dtheta6").index()],
        ParamStatus::Dependent
    );
    // The noise is what was simulated: one σ for both kinds of equation.
    let sigma = result.diagnostics.as_ref().unwrap().variance_factor.sqrt();
    assert!((sigma / SIGMA_MM - 1.0).abs() < 0.15, "{sigma}");
    // Every row has its rotation residual, at the noise level.
    let angles: Vec<f64> = result
        .residuals_deg
        .iter()
        .map(|r| r.unwrap().norm())
        .collect();
    let rms = (angles.iter().map(|a| a * a).sum::<f64>() / angles.len() as f64).sqrt();
    assert!(rms < 3.0 * (SIGMA_MM / LEVER_MM).to_degrees(), "{rms}");

    // Positions alone cannot tell the mounting from the tool translation.
    let positions_only = Observations::new(&rows, &measured);
    let (start, _) = registered_start(&robot, &nominal, &positions_only).unwrap();
    let result = calibrate(
        &robot,
        ModelName::Elastogeometric,
        &positions_only,
        &start,
        &options,
    )
    .unwrap();
    for (name, _) in TOOL_ROTATION_DEG {
        assert_eq!(
            result.set.status[id(name).index()],
            ParamStatus::Dependent,
            "{name}"
        );
    }
    assert!(result.residuals_deg.iter().all(Option::is_none));
}

/// `rows`, positions and orientations (Euler XYZ, deg) as a measurements table.
fn write_six_d(
    path: &Path,
    rows: &[ConfWrench],
    measured: &[Vector3<f64>],
    rotations: &[Matrix3<f64>],
) {
    let mut columns = vec![Column::new(
        "cw_id".into(),
        (0..rows.len() as i64).collect::<Vec<_>>(),
    )];
    for (i, name) in schema::JOINT_COLUMNS.iter().enumerate() {
        columns.push(Column::new(
            (*name).into(),
            rows.iter().map(|r| r.q_deg[i]).collect::<Vec<_>>(),
        ));
    }
    for (i, name) in schema::WRENCH_COLUMNS.iter().enumerate() {
        let values: Vec<f64> = rows.iter().map(|r| r.wrench.to_array()[i]).collect();
        columns.push(Column::new((*name).into(), values));
    }
    for (axis, name) in schema::POSITION_COLUMNS.iter().enumerate() {
        columns.push(Column::new(
            (*name).into(),
            measured.iter().map(|p| p[axis]).collect::<Vec<_>>(),
        ));
    }
    let angles: Vec<[f64; 3]> = rotations
        .iter()
        .map(|r| xyz_euler_nearest(r, [0.0; 3]))
        .collect();
    for (axis, name) in schema::ORIENTATION_COLUMNS.iter().enumerate() {
        columns.push(Column::new(
            (*name).into(),
            angles.iter().map(|a| a[axis]).collect::<Vec<_>>(),
        ));
    }
    table::write_parquet(&mut table::frame(columns), path, None).unwrap();
}

#[test]
fn orientation_columns_reach_the_fit_and_the_validation() {
    let dir = tempfile::tempdir().unwrap();
    let (robot, truth) = truth_with_tool_rotation();
    let rows = random_rows(&robot, 81, 120);
    let measured = noisy(&positions(&robot, &truth, &rows), SIGMA_MM, 82);
    let rotations = orientations(&robot, &truth, &rows, SIGMA_MM / LEVER_MM, 83);
    let input = dir.path().join("measurements.parquet");
    write_six_d(&input, &rows, &measured, &rotations);
    let job = dir.path().join("job.toml");
    std::fs::write(
        &job,
        format!(
            r#"[job]
name = "six_d"
seed = 1
robot = "{robot}"
output = "out"

[[stages]]
id = "split"
kind = "split"
inputs = {{ measurements = "{input}" }}

[[stages]]
id = "identify"
kind = "identify"
inputs = {{ measurements = "{input}", selection = "split" }}
models = ["nominal", "registered", "elastogeometric"]
max_iterations = 60

[[stages]]
id = "validate"
kind = "validate"
inputs = {{ measurements = "{input}", selection = "split", parameters = "identify.parameters" }}
"#,
            robot = common::root()
                .join("jobs/robots/irb1600_145.toml")
                .display(),
            input = input.display(),
        ),
    )
    .unwrap();
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stderr.contains("tool rotation from the orientations: rms"),
        "{stderr}"
    );

    let out = dir.path().join("out");
    let parameters = table::read_parquet(&out.join("identify/parameters.parquet")).unwrap();
    let sets =
        egcal::table::parameters::from_frame(&parameters, Path::new("p"), robot.spec()).unwrap();
    // The registered model (the nominal arm in fitted frames) has the mounting
    // too: fitted, or held at its closed-form registration where the arm's
    // own errors leave its standard error beyond `max_std_error_deg`.
    for model in [ModelName::Registered, ModelName::Elastogeometric] {
        let set = sets.iter().find(|s| s.model == model).unwrap();
        for (name, value) in TOOL_ROTATION_DEG {
            let (status, reason) = (set.status[id(name).index()], &set.reasons[id(name).index()]);
            let expected: &[ParamStatus] = match model {
                ModelName::Registered => &[ParamStatus::Identified, ParamStatus::Held],
                _ => &[ParamStatus::Identified],
            };
            assert!(
                expected.contains(&status),
                "{model} {name}: {status:?} {reason:?}"
            );
            let got = set.values.get(id(name));
            assert!((got - value).abs() < 0.5, "{model} {name}: {got}");
        }
    }

    let stats = table::read_checked(&out.join("validate/stats.parquet"), &schema::stats()).unwrap();
    let models = schema::str_values(&stats, "model", Path::new("s")).unwrap();
    let mean_deg = schema::f64_values(&stats, "mean_deg", Path::new("s")).unwrap();
    let max_deg = schema::f64_values(&stats, "max_deg", Path::new("s")).unwrap();
    let of = |model: &str| {
        models
            .iter()
            .position(|m| m.as_deref() == Some(model))
            .unwrap()
    };
    let noise_deg = (SIGMA_MM / LEVER_MM).to_degrees();
    // Calibrated: the orientation error is the noise's (mean of a χ₃ ≈ 1.6 σ).
    let calibrated = mean_deg[of("elastogeometric")];
    assert!(
        calibrated < 2.5 * noise_deg,
        "{calibrated} vs noise {noise_deg}"
    );
    assert!(max_deg[of("elastogeometric")] >= calibrated);
    // The nominal robot file does not know the mounting: tens of degrees off.
    assert!(
        mean_deg[of("nominal")] > 20.0,
        "{}",
        mean_deg[of("nominal")]
    );
    assert!(mean_deg[of("registered")] > calibrated);
    let errors =
        table::read_checked(&out.join("validate/errors.parquet"), &schema::errors()).unwrap();
    let error_deg = schema::f64_values(&errors, "error_deg", Path::new("e")).unwrap();
    assert_eq!(error_deg.len(), errors.height());
    assert!(error_deg.iter().all(|a| a.is_finite() && *a >= 0.0));
}
