//! Identification against a known truth (the spec's Table II parameters on
//! simulated rows): exact recovery without noise, honest standard errors with
//! noise, the kinematic model's load-correlated residuals, the two algorithms'
//! agreement, the Huber loss's outlier handling, the streamed fit against a dense
//! least-squares solution and its independence of chunk size and thread count,
//! and the stage's outputs and metadata through `egcal run`.

mod common;

use std::path::Path;

use egcal::calibration::fit::{self, Algorithm, FitOptions, Loss, Observations};
use egcal::calibration::{CalibrationOptions, ModelResult, calibrate};
use egcal::robot::{ConfWrench, ParamId, ParamValues, Robot, Selection, batch_jacobian};
use egcal::table::parameters::{ModelName, ParamStatus};
use egcal::table::{self, schema};
use faer::Mat;
use faer::prelude::*;
use nalgebra::Vector3;

use common::measured::{noisy, positions, write_measurements};
use common::sample::{random_rows, robot_and_truth};

/// The loss as given: these tests are about least squares and Huber themselves
/// (`tests/real_cells.rs` covers the robust default).
fn options(fit: FitOptions) -> CalibrationOptions {
    CalibrationOptions {
        robust: None,
        ..CalibrationOptions::new(ParamId::all().collect(), fit)
    }
}

fn identify(
    robot: &Robot,
    model: ModelName,
    rows: &[ConfWrench],
    measured: &[Vector3<f64>],
    fit: FitOptions,
) -> ModelResult {
    calibrate(
        robot,
        model,
        &Observations::new(rows, measured),
        &ParamValues::nominal(robot.spec()),
        &options(fit),
    )
    .unwrap()
}

fn identified(result: &ModelResult) -> Vec<ParamId> {
    ParamId::all()
        .filter(|id| result.set.status[id.index()] == ParamStatus::Identified)
        .collect()
}

#[test]
fn noiseless_identification_recovers_the_truth_and_predicts_held_out_rows() {
    let (robot, truth) = robot_and_truth();
    let nominal = ParamValues::nominal(robot.spec());
    let rows = random_rows(&robot, 21, 60);
    let fit = FitOptions {
        stop_step_mm: 1e-9,
        ..FitOptions::default()
    };
    let result = identify(
        &robot,
        ModelName::Elastogeometric,
        &rows,
        &positions(&robot, &truth, &rows),
        fit,
    );
    assert!(result.converged, "{:?}", result.trace);
    assert_eq!(identified(&result), Selection::spec_identifiable().ids());
    for id in ParamId::all() {
        let (got, want) = (result.set.values.get(id), truth.get(id));
        match result.set.status[id.index()] {
            // To 1e-6 of the parameter's unit; compliances (~1e-4 deg/(N·m)) also
            // to 1e-6 relative.
            ParamStatus::Identified => {
                let tolerance = if id.is_compliance() {
                    1e-6 * want.abs()
                } else {
                    1e-6
                };
                assert!((got - want).abs() < tolerance, "{id}: {got} vs {want}");
                assert!(result.set.std_errors[id.index()].is_some());
            }
            // Held at nominal (the spec's truth leaves them there), no standard error.
            ParamStatus::Dependent => {
                assert_eq!(got, nominal.get(id), "{id}");
                assert_eq!(result.set.std_errors[id.index()], None);
            }
            ParamStatus::Fixed => panic!("{id}: fixed in the elasto-geometric model"),
            // Noise-free rows determine every identifiable parameter.
            ParamStatus::Held => panic!("{id}: held on exact data"),
        }
    }
    let held_out = random_rows(&robot, 22, 200);
    let predicted = positions(&robot, &result.set.values, &held_out);
    let actual = positions(&robot, &truth, &held_out);
    let worst = predicted
        .iter()
        .zip(&actual)
        .map(|(p, a)| (p - a).norm())
        .fold(0.0, f64::max);
    assert!(worst < 1e-6, "held-out error {worst} mm");
}

#[test]
fn noisy_estimates_lie_within_four_standard_errors_of_the_truth() {
    let (robot, truth) = robot_and_truth();
    for seed in 1..=5 {
        let rows = random_rows(&robot, 100 + seed, 50);
        let measured = noisy(&positions(&robot, &truth, &rows), 0.03, 200 + seed);
        let result = identify(
            &robot,
            ModelName::Elastogeometric,
            &rows,
            &measured,
            FitOptions::default(),
        );
        assert!(result.converged, "seed {seed}: {:?}", result.trace);
        for id in identified(&result) {
            let se = result.set.std_errors[id.index()].unwrap();
            let z = (result.set.values.get(id) - truth.get(id)) / se;
            assert!(z.abs() < 4.0, "seed {seed}, {id}: {z:.2} standard errors");
        }
    }
}

/// Pearson correlation and its t statistic (n − 2 degrees of freedom).
fn correlation_t(x: &[f64], y: &[f64]) -> (f64, f64) {
    let n = x.len() as f64;
    let (mx, my) = (x.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = x.iter().map(|a| (a - mx).powi(2)).sum();
    let syy: f64 = y.iter().map(|b| (b - my).powi(2)).sum();
    let rho = sxy / (sxx * syy).sqrt();
    (rho, rho * ((n - 2.0) / (1.0 - rho * rho)).sqrt())
}

#[test]
fn kinematic_residuals_grow_with_the_applied_load_and_elastogeometric_ones_do_not() {
    let (robot, truth) = robot_and_truth();
    let rows = random_rows(&robot, 31, 120);
    let measured = noisy(&positions(&robot, &truth, &rows), 0.02, 32);
    let force_n: Vec<f64> = rows.iter().map(|r| r.wrench.force_n.norm()).collect();
    let residual_norms = |model| -> Vec<f64> {
        identify(&robot, model, &rows, &measured, FitOptions::default())
            .residuals_mm
            .iter()
            .map(|r| r.norm())
            .collect()
    };
    // Regression of each row's residual norm on the applied force's magnitude:
    // the kinematic model cannot explain the joint deflections, so its residuals
    // scale with the load; the elasto-geometric model leaves only tracker noise.
    let (rho, t) = correlation_t(&force_n, &residual_norms(ModelName::Kinematic));
    assert!(t > 5.0, "kinematic: ρ = {rho:.3}, t = {t:.2}");
    let (rho, t) = correlation_t(&force_n, &residual_norms(ModelName::Elastogeometric));
    assert!(t.abs() < 3.0, "elasto-geometric: ρ = {rho:.3}, t = {t:.2}");
}

#[test]
fn levenberg_marquardt_and_the_paper_s_iteration_reach_the_same_optimum() {
    let (robot, truth) = robot_and_truth();
    let rows = random_rows(&robot, 41, 50);
    let measured = noisy(&positions(&robot, &truth, &rows), 0.03, 42);
    let run = |algorithm| {
        identify(
            &robot,
            ModelName::Elastogeometric,
            &rows,
            &measured,
            FitOptions {
                algorithm,
                stop_step_mm: 1e-8,
                ..FitOptions::default()
            },
        )
    };
    let (lm, paper) = (run(Algorithm::LevenbergMarquardt), run(Algorithm::Paper));
    assert!(lm.converged && paper.converged);
    for id in identified(&lm) {
        let se = lm.set.std_errors[id.index()].unwrap();
        let difference = lm.set.values.get(id) - paper.set.values.get(id);
        assert!(
            difference.abs() < 1e-4 * se,
            "{id}: differs by {difference} ({se} standard error)"
        );
    }
}

#[test]
fn huber_loss_downweights_an_injected_outlier() {
    let (robot, truth) = robot_and_truth();
    let rows = random_rows(&robot, 51, 60);
    let mut measured = noisy(&positions(&robot, &truth, &rows), 0.02, 52);
    let outlier = 17;
    measured[outlier] += Vector3::new(3.0, -2.0, 1.5);
    let threshold_mm = 0.5;
    let least_squares = identify(
        &robot,
        ModelName::Elastogeometric,
        &rows,
        &measured,
        FitOptions::default(),
    );
    let huber = identify(
        &robot,
        ModelName::Elastogeometric,
        &rows,
        &measured,
        FitOptions {
            loss: Loss::Huber { threshold_mm },
            ..FitOptions::default()
        },
    );
    assert!(huber.converged, "{:?}", huber.trace);
    // Least squares spreads the error over the fit but still leaves the row beyond
    // the threshold (so it is reported); Huber gives it a small weight, and only it.
    assert!(least_squares.residuals_mm[outlier].norm() > threshold_mm);
    assert!(least_squares.weights.iter().all(|w| *w == 1.0));
    assert!(
        huber.weights[outlier] < 0.2,
        "weight {}",
        huber.weights[outlier]
    );
    for (k, w) in huber.weights.iter().enumerate() {
        assert!(k == outlier || *w == 1.0, "row {k} has weight {w}");
    }
    // And the held-out predictions are closer to the truth.
    let held_out = random_rows(&robot, 53, 200);
    let actual = positions(&robot, &truth, &held_out);
    let rms_error = |result: &ModelResult| {
        let predicted = positions(&robot, &result.set.values, &held_out);
        (predicted
            .iter()
            .zip(&actual)
            .map(|(p, a)| (p - a).norm_squared())
            .sum::<f64>()
            / held_out.len() as f64)
            .sqrt()
    };
    let (ls_error, huber_error) = (rms_error(&least_squares), rms_error(&huber));
    assert!(
        huber_error < 0.5 * ls_error,
        "held-out RMS: huber {huber_error} mm, least squares {ls_error} mm"
    );
}

/// The streamed fit (chunks of 700 rows: four full ones and one of 200) converges
/// to the same parameters as an independent dense Gauss–Newton iteration on the
/// same 3000 noisy rows: the full Jacobian from `batch_jacobian`, each step solved
/// by faer's QR of all 9000 equations. Both start from nominal and iterate until a
/// step moves no position by more than 1e-10 mm, so both sit at the least-squares
/// optimum to rounding, and any difference between them would be an error of the
/// streaming. The standard errors and the condition number, from the streamed
/// triangular factor, are compared with the dense Jacobian's SVD the same way.
#[test]
fn a_streamed_fit_converges_to_the_dense_least_squares_solution() {
    let (robot, truth) = robot_and_truth();
    let nominal = ParamValues::nominal(robot.spec());
    let rows = random_rows(&robot, 71, 3000);
    let measured = noisy(&positions(&robot, &truth, &rows), 0.02, 72);
    let free = Selection::spec_identifiable();
    let m = free.len();
    let options = FitOptions {
        algorithm: Algorithm::Paper,
        stop_step_mm: 1e-10,
        chunk_rows: 700,
        ..FitOptions::default()
    };
    let streamed = fit::fit(
        &robot,
        &nominal,
        &Observations::new(&rows, &measured),
        free.ids(),
        &options,
    )
    .unwrap();
    assert!(streamed.converged, "{:?}", streamed.trace);

    let equations = 3 * rows.len();
    let mut dense = nominal;
    let mut converged = false;
    let mut jacobian = Mat::<f64>::zeros(0, 0);
    for _ in 0..20 {
        let batch = batch_jacobian(&robot, &dense, &rows, free.ids());
        jacobian = Mat::from_fn(equations, m, |i, j| batch.entry(i, j));
        let residuals = Mat::<f64>::from_fn(equations, 1, |i, _| {
            measured[i / 3][i % 3] - batch.predictions[i / 3].position_mm[i % 3]
        });
        let delta = jacobian.qr().solve_lstsq(&residuals);
        let change = &jacobian * &delta;
        for (j, id) in free.ids().iter().enumerate() {
            dense.set(*id, dense.get(*id) + delta[(j, 0)]);
        }
        let largest = (0..rows.len())
            .map(|k| {
                (0..3)
                    .map(|a| change[(3 * k + a, 0)].powi(2))
                    .sum::<f64>()
                    .sqrt()
            })
            .fold(0.0, f64::max);
        if largest < 1e-10 {
            converged = true;
            break;
        }
    }
    assert!(converged);
    for id in free.ids() {
        let (got, want) = (streamed.values.get(*id), dense.get(*id));
        assert!(
            (got - want).abs() <= 1e-9 * want.abs(),
            "{id}: streamed {got}, dense {want}"
        );
    }

    // Standard errors σ·sqrt(diag((JᵀJ)⁻¹)) and σ_max/σ_min of the column-scaled
    // Jacobian at the dense solution (the last step moved it by < 1e-10 mm).
    let residuals = positions(&robot, &dense, &rows);
    let rss: f64 = residuals
        .iter()
        .zip(&measured)
        .map(|(p, q)| (q - p).norm_squared())
        .sum();
    let sigma2 = rss / (equations - m) as f64;
    let norms: Vec<f64> = (0..m).map(|j| jacobian.col(j).norm_l2()).collect();
    let scaled = Mat::<f64>::from_fn(equations, m, |i, j| jacobian[(i, j)] / norms[j]);
    let svd = scaled.thin_svd().unwrap();
    let s = svd.S().column_vector();
    let condition = s[0] / s[m - 1];
    assert!(
        (streamed.condition_number - condition).abs() <= 1e-9 * condition,
        "condition number {} vs {condition}",
        streamed.condition_number
    );
    for (j, id) in free.ids().iter().enumerate() {
        let variance: f64 = (0..m).map(|k| (svd.V()[(j, k)] / s[k]).powi(2)).sum();
        let want = (variance * sigma2).sqrt() / norms[j];
        let got = streamed.std_errors[id.index()].unwrap();
        assert!(
            (got - want).abs() <= 1e-9 * want,
            "{id}: standard error {got} vs {want}"
        );
    }
}

/// The rows are split into fixed chunks reduced in a fixed tree, so the thread
/// count changes nothing (bit for bit) and the chunk size only the rounding: every
/// value and standard error within 1e-12 relative. A value near zero may differ by
/// up to 1e-10 of its standard error instead: at the optimum the step is computed
/// from residuals of about 1000 mm positions, each rounded to ~1e-13 mm, which
/// moves the solution by ~1e-11 standard errors however the rows are reduced (for
/// dd5 here, 6.6 standard errors from zero, that is 1.2e-12 of its value).
///
/// Both configurations converge to the optimum within rounding (a tight step
/// criterion that each reaches): Levenberg–Marquardt on least squares, and the
/// paper's iteration on the Huber loss with an outlier, whose reweighting converges
/// only linearly. (Levenberg–Marquardt on Huber ends on `stop_relative_cost` once
/// the cost changes by rounding only, so where it stops depends on rounding.)
#[test]
fn chunk_size_and_thread_count_change_results_only_by_rounding() {
    let (robot, truth) = robot_and_truth();
    let rows = random_rows(&robot, 81, 2000);
    let mut measured = noisy(&positions(&robot, &truth, &rows), 0.02, 82);
    measured[40] += Vector3::new(2.0, 0.0, -1.0);
    for (algorithm, loss, stop_step_mm) in [
        (Algorithm::LevenbergMarquardt, Loss::LeastSquares, 1e-9),
        (Algorithm::Paper, Loss::Huber { threshold_mm: 0.5 }, 1e-10),
    ] {
        let run = |chunk_rows: usize, threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let result = pool.install(|| {
                identify(
                    &robot,
                    ModelName::Elastogeometric,
                    &rows,
                    &measured,
                    FitOptions {
                        algorithm,
                        loss,
                        stop_step_mm,
                        chunk_rows,
                        ..FitOptions::default()
                    },
                )
            });
            assert!(result.converged, "{algorithm:?}: {:?}", result.trace);
            result
        };
        let reference = run(256, 2);
        for threads in [1, 3] {
            let other = run(256, threads);
            assert_eq!(other.set.values, reference.set.values, "{threads} threads");
            assert_eq!(other.set.std_errors, reference.set.std_errors);
            assert_eq!(other.residuals_mm, reference.residuals_mm);
            assert_eq!(other.weights, reference.weights);
            assert_eq!(other.trace, reference.trace);
        }
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * a.abs().max(b.abs());
        for chunk_rows in [1, 97, 1024, 5000] {
            let other = run(chunk_rows, 2);
            assert_eq!(identified(&other), identified(&reference));
            for id in identified(&reference) {
                let i = id.index();
                let (a, b) = (other.set.values.get(id), reference.set.values.get(id));
                let se = reference.set.std_errors[i].unwrap();
                assert!(
                    close(a, b) || (a - b).abs() <= 1e-10 * se,
                    "{algorithm:?}, chunks of {chunk_rows}, {id}: {a} vs {b} (standard error {se})"
                );
                let (a, b) = (
                    other.set.std_errors[i].unwrap(),
                    reference.set.std_errors[i].unwrap(),
                );
                assert!(
                    close(a, b),
                    "{algorithm:?}, chunks of {chunk_rows}, {id} standard error: {a} vs {b}"
                );
            }
            for (a, b) in other.weights.iter().zip(&reference.weights) {
                assert!(close(*a, *b), "weights {a} vs {b}");
            }
        }
    }
}

#[test]
fn the_stage_writes_residuals_and_logs_conditioning_correlations_and_outliers() {
    let dir = tempfile::tempdir().unwrap();
    let (robot, truth) = robot_and_truth();
    let rows = random_rows(&robot, 61, 40);
    let mut measured = noisy(&positions(&robot, &truth, &rows), 0.02, 62);
    measured[5] += Vector3::new(0.0, 0.0, 4.0);
    let input = dir.path().join("measurements.parquet");
    write_measurements(&input, &rows, &measured, 1);
    let job = dir.path().join("job.toml");
    std::fs::write(
        &job,
        format!(
            r#"[job]
name = "identify"
seed = 1
robot = "{robot}"
output = "out"

[[stages]]
id = "identify"
kind = "identify"
inputs = {{ measurements = "{input}" }}
loss = "huber"
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
    for expected in [
        "identify: elastogeometric: condition_number = ",
        "identify: elastogeometric: correlations = ",
        "identify: elastogeometric: outliers = 1 rows beyond 0.5 mm (cw_id:r_mm) 6:",
        "identify: elastogeometric: stop = ",
    ] {
        assert!(stderr.contains(expected), "`{expected}` not in\n{stderr}");
    }

    let out = dir.path().join("out/identify");
    let residuals =
        table::read_checked(&out.join("residuals.parquet"), &schema::residuals()).unwrap();
    assert_eq!(residuals.height(), 4 * 40);
    let models = schema::str_values(&residuals, "model", Path::new("r")).unwrap();
    let ids = schema::i64_values(&residuals, "cw_id", Path::new("r")).unwrap();
    let weights = schema::f64_values(&residuals, "weight", Path::new("r")).unwrap();
    let row = (0..residuals.height())
        .find(|&k| models[k].as_deref() == Some("elastogeometric") && ids[k] == 6)
        .unwrap();
    assert!(weights[row] < 0.2, "weight {}", weights[row]);

    // The same facts are in the output's metadata.
    let provenance = table::read_provenance(&out.join("parameters.parquet"))
        .unwrap()
        .unwrap();
    let correlations = &provenance.extra["elastogeometric_correlations"];
    assert_eq!(correlations.split(',').count(), 5, "{correlations}");
    let condition: f64 = provenance.extra["elastogeometric_condition_number"]
        .parse()
        .unwrap();
    assert!(condition > 1.0 && condition.is_finite());

    // Dependent parameters stay at nominal with status `dependent`.
    let parameters = table::read_parquet(&out.join("parameters.parquet")).unwrap();
    let sets =
        egcal::table::parameters::from_frame(&parameters, Path::new("p"), robot.spec()).unwrap();
    let eg = sets
        .iter()
        .find(|s| s.model == ModelName::Elastogeometric)
        .unwrap();
    let dd3 = ParamId::from_name("dd3").unwrap();
    assert_eq!(eg.status[dd3.index()], ParamStatus::Dependent);
    assert_eq!(
        eg.values.get(dd3),
        ParamValues::nominal(robot.spec()).get(dd3)
    );

    let trace = table::read_checked(
        &out.join("identification_trace.parquet"),
        &schema::identification_trace(),
    )
    .unwrap();
    assert!(trace.column("damping").is_ok() && trace.column("accepted").is_ok());
}
