use super::*;
use rand_distr::{Distribution, Normal};

/// Options small enough for debug-build tests: 64 inducing points, 800
/// optimisation rows, 2 starts.
fn small_options(seed: u64) -> ResidualOptions {
    ResidualOptions {
        inducing_points: 64,
        optimisation_rows: 800,
        restarts: 2,
        max_iterations: 100,
        seed,
    }
}

/// A smooth function of `x` per axis (mm).
fn smooth(x: &[f64]) -> [f64; 3] {
    let s: f64 = x.iter().sum();
    [
        (x[0]).sin(),
        0.5 * (x[0] + 1.0).cos() + 0.2 * x.get(1).copied().unwrap_or(0.0),
        0.3 * (2.0 * s).sin(),
    ]
}

/// `n` rows of `d` features uniform in `[lo, hi)` and `smooth` plus noise.
fn simulated(
    n: usize,
    d: usize,
    (lo, hi): (f64, f64),
    noise_sd_mm: f64,
    seed: u64,
) -> (Vec<f64>, Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let mut rng = StdRng::seed_from_u64(seed);
    let noise = Normal::new(0.0, noise_sd_mm).expect("positive sd");
    let x: Vec<f64> = (0..n * d).map(|_| rng.random_range(lo..hi)).collect();
    let truth: Vec<[f64; 3]> = x.chunks(d).map(smooth).collect();
    let y = truth
        .iter()
        .map(|t| std::array::from_fn(|a| t[a] + noise.sample(&mut rng)))
        .collect();
    (x, y, truth)
}

fn one_group(d: usize) -> FeatureLayout {
    FeatureLayout::new(vec![0; d]).expect("layout")
}

#[test]
fn gradient_matches_finite_differences() {
    let layout = FeatureLayout::new(vec![0, 1, 1]).expect("layout");
    let (x, y, _) = simulated(60, 3, (-2.0, 2.0), 0.1, 1);
    let rows = Rows {
        values: &x,
        columns: 3,
    };
    let z_values: Vec<f64> = x[..15 * 3].to_vec();
    let z = Rows {
        values: &z_values,
        columns: 3,
    };
    let theta = [0.4_f64.ln(), 0.02_f64.ln(), 0.9_f64.ln(), 1.7_f64.ln()];
    let evaluate = |theta: &[f64], sparse: bool| {
        let h = Hyperparameters::from_log(theta);
        let hyper = h.hyper(&layout);
        let evaluation = if sparse {
            Sparse::evaluate(&hyper, rows, z, &y, BASE_JITTER, true).map(|(_, e)| e)
        } else {
            Exact::evaluate(&hyper, rows, &y, BASE_JITTER, true).map(|(_, e)| e)
        };
        evaluation
            .expect("positive definite")
            .expect("gradient asked for")
    };
    for sparse in [false, true] {
        let analytic = evaluate(&theta, sparse).gradient;
        for i in 0..theta.len() {
            let h = 1e-5;
            let mut plus = theta;
            let mut minus = theta;
            plus[i] += h;
            minus[i] -= h;
            let numeric =
                (evaluate(&plus, sparse).value - evaluate(&minus, sparse).value) / (2.0 * h);
            assert!(
                (analytic[i] - numeric).abs() <= 1e-6 * (1.0 + numeric.abs()),
                "sparse {sparse}, coordinate {i}: analytic {} numeric {numeric}",
                analytic[i]
            );
        }
    }
}

#[test]
fn matches_numpy_exact_and_sparse() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/fixtures/residual/gp_check.json"
    );
    let text = std::fs::read_to_string(path).expect("fixture (fixtures/tools/gp_check.py)");
    let f: serde_json::Value = serde_json::from_str(&text).expect("JSON");
    let numbers = |v: &serde_json::Value| -> Vec<f64> {
        v.as_array()
            .expect("array")
            .iter()
            .map(|t| t.as_f64().expect("number"))
            .collect()
    };
    let triples = |v: &serde_json::Value| -> Vec<[f64; 3]> {
        v.as_array()
            .expect("array")
            .iter()
            .map(|r| {
                let r = numbers(r);
                [r[0], r[1], r[2]]
            })
            .collect()
    };
    let groups: Vec<usize> = numbers(&f["groups"]).iter().map(|g| *g as usize).collect();
    let layout = FeatureLayout::new(groups).expect("layout");
    let hyperparameters = Hyperparameters {
        signal_variance_mm2: f["signal_variance_mm2"].as_f64().expect("s2"),
        noise_variance_mm2: f["noise_variance_mm2"].as_f64().expect("noise"),
        length_scales: numbers(&f["length_scales"]),
    };
    let x = numbers(&f["x"]);
    let y = triples(&f["y"]);
    let z = numbers(&f["z"]);
    let at = numbers(&f["x_star"]);
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-8 * b.abs().max(1e-12);
    for (name, inducing) in [("exact", None), ("sparse", Some(z.as_slice()))] {
        let model =
            ResidualModel::with_hyperparameters(&layout, &x, &y, &hyperparameters, inducing)
                .expect("fit");
        let expected = &f[name];
        let ll = expected["log_likelihood"].as_f64().expect("ll");
        assert!(
            close(model.log_marginal_likelihood(), ll),
            "{name}: log likelihood {} against numpy's {ll}",
            model.log_marginal_likelihood()
        );
        let predicted = model.predict(&at).expect("predict");
        let means = triples(&expected["mean_mm"]);
        let variances = numbers(&expected["latent_variance_mm2"]);
        for (k, p) in predicted.iter().enumerate() {
            for (a, expected) in means[k].iter().enumerate() {
                assert!(
                    close(p.mean_mm[a], *expected),
                    "{name} row {k} axis {a}: mean {} against {expected}",
                    p.mean_mm[a]
                );
            }
            assert!(
                close(p.latent_variance_mm2, variances[k]),
                "{name} row {k}: variance {} against {}",
                p.latent_variance_mm2,
                variances[k]
            );
        }
    }
}

/// RMS over held-out points of (mean − truth), per axis pooled.
fn mean_error_rms(model: &ResidualModel, x: &[f64], truth: &[[f64; 3]]) -> f64 {
    let predicted = model.predict(x).expect("predict");
    let sum: f64 = predicted
        .iter()
        .zip(truth)
        .flat_map(|(p, t)| (0..3).map(move |a| (p.mean_mm[a] - t[a]).powi(2)))
        .sum();
    (sum / (3 * truth.len()) as f64).sqrt()
}

#[test]
fn recovers_a_smooth_function_within_the_noise() {
    let sd = 0.1;
    let layout = one_group(1);
    let (test_x, _, test_truth) = simulated(500, 1, (0.3, 6.0), sd, 99);
    for (n, sparse) in [(50, false), (2000, true)] {
        let (x, y, _) = simulated(n, 1, (0.0, 6.3), sd, 7);
        let model = ResidualModel::fit(&layout, &x, &y, &small_options(3)).expect("fit");
        assert_eq!(model.inducing_points() > 0, sparse);
        let rms = mean_error_rms(&model, &test_x, &test_truth);
        // The posterior mean averages about n·ℓ/range rows: its error is a
        // fraction of the noise, falling with n.
        let tolerance = if sparse { 0.1 * sd } else { 0.5 * sd };
        assert!(rms < tolerance, "n = {n}: RMS error {rms} ≥ {tolerance}");
        let noise = model.hyperparameters().noise_variance_mm2;
        assert!(
            (noise / (sd * sd) - 1.0).abs() < 0.3,
            "n = {n}: noise variance {noise} against {}",
            sd * sd
        );
    }
}

#[test]
fn variance_returns_to_the_prior_far_away_and_is_small_near_dense_rows() {
    let sd = 0.05;
    let layout = one_group(2);
    for n in [150, 1500] {
        let (x, y, _) = simulated(n, 2, (-1.0, 1.0), sd, 11);
        let model = ResidualModel::fit(&layout, &x, &y, &small_options(5)).expect("fit");
        let s2 = model.hyperparameters().signal_variance_mm2;
        let far = model.predict(&[40.0, -35.0, 1e3, 1e3]).expect("predict");
        for p in &far {
            assert!(
                (p.latent_variance_mm2 - s2).abs() <= 1e-6 * s2,
                "n = {n}: variance {} far away, prior {s2}",
                p.latent_variance_mm2
            );
            assert!(
                p.mean_mm.iter().all(|m| m.abs() < 1e-9),
                "n = {n}: mean {:?}",
                p.mean_mm
            );
        }
        let near = model.predict(&[0.0, 0.0, 0.5, -0.5]).expect("predict");
        for p in &near {
            assert!(
                p.latent_variance_mm2 < 0.01 * s2 && p.latent_variance_mm2 < sd * sd,
                "n = {n}: variance {} among dense rows (s² {s2}, σ² {})",
                p.latent_variance_mm2,
                sd * sd
            );
        }
    }
}

#[test]
fn held_out_coverage_of_95_percent_intervals() {
    // Interval per axis: mean ± 1.96·√(latent variance + noise variance),
    // against the noisy held-out value; 2000 rows × 3 axes.
    let sd = 0.05;
    let layout = one_group(2);
    let (x, y, _) = simulated(1500, 2, (-2.0, 2.0), sd, 21);
    let (test_x, test_y, _) = simulated(2000, 2, (-2.0, 2.0), sd, 22);
    let model = ResidualModel::fit(&layout, &x, &y, &small_options(9)).expect("fit");
    assert!(model.inducing_points() > 0);
    let noise = model.hyperparameters().noise_variance_mm2;
    let predicted = model.predict(&test_x).expect("predict");
    let inside = predicted
        .iter()
        .zip(&test_y)
        .flat_map(|(p, t)| {
            let half = 1.96 * (p.latent_variance_mm2 + noise).sqrt();
            (0..3).map(move |a| (t[a] - p.mean_mm[a]).abs() <= half)
        })
        .filter(|inside| *inside)
        .count();
    let coverage = inside as f64 / (3 * test_y.len()) as f64;
    assert!((coverage - 0.95).abs() <= 0.03, "coverage {coverage}");
}

#[test]
fn pure_noise_gives_a_small_signal_and_a_flat_mean() {
    let sd = 0.05;
    let layout = one_group(2);
    let mut rng = StdRng::seed_from_u64(31);
    let normal = Normal::new(0.0, sd).expect("sd");
    for n in [200, 1500] {
        let x: Vec<f64> = (0..2 * n).map(|_| rng.random_range(-2.0..2.0)).collect();
        let y: Vec<[f64; 3]> = (0..n)
            .map(|_| std::array::from_fn(|_| normal.sample(&mut rng)))
            .collect();
        let model = ResidualModel::fit(&layout, &x, &y, &small_options(13)).expect("fit");
        let h = model.hyperparameters();
        assert!(
            h.signal_variance_mm2 < 0.05 * sd * sd,
            "n = {n}: signal variance {} against noise {}",
            h.signal_variance_mm2,
            sd * sd
        );
        let grid: Vec<f64> = (0..400)
            .flat_map(|k| [-2.0 + 0.01 * k as f64, 1.0])
            .collect();
        let largest = model
            .predict(&grid)
            .expect("predict")
            .iter()
            .flat_map(|p| p.mean_mm)
            .fold(0.0_f64, |m, v| m.max(v.abs()));
        assert!(largest < 0.2 * sd, "n = {n}: largest |mean| {largest}");
    }
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    let layout = one_group(2);
    let (x, y, _) = simulated(700, 2, (-2.0, 2.0), 0.05, 41);
    let options = ResidualOptions {
        inducing_points: 40,
        optimisation_rows: 300,
        restarts: 1,
        max_iterations: 20,
        seed: 1,
    };
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool")
            .install(|| {
                let model = ResidualModel::fit(&layout, &x, &y, &options).expect("fit");
                (
                    model.hyperparameters().clone(),
                    model.predict(&x[..200]).expect("predict"),
                )
            })
    };
    assert_eq!(run(1), run(3));
}

#[test]
fn joint_load_features_are_periodic_and_scaled() {
    let q = [10.0, -20.0, 30.0, 45.0, 90.0, -170.0];
    let wrench = [50.0, -100.0, 20.0, 1.0, -5.0, 10.0];
    let f = joint_load_features(&q, &wrench);
    let turned = joint_load_features(&q.map(|v| v + 360.0), &wrench);
    for (a, b) in f.iter().zip(&turned) {
        assert!((a - b).abs() < 1e-12);
    }
    assert!((f[0] - 10f64.to_radians().sin()).abs() < 1e-15);
    assert!((f[9] - 90f64.to_radians().cos()).abs() < 1e-15);
    assert_eq!(&f[12..], &[0.5, -1.0, 0.2, 0.1, -0.5, 1.0]);
    let layout = FeatureLayout::joint_load();
    assert_eq!(
        (layout.columns(), layout.group_count()),
        (JOINT_LOAD_FEATURES, 12)
    );
}

#[test]
fn bad_input_is_a_typed_error() {
    let layout = one_group(2);
    let (x, y, _) = simulated(30, 2, (-1.0, 1.0), 0.1, 51);
    let options = small_options(0);
    let fit = |x: &[f64], y: &[[f64; 3]]| ResidualModel::fit(&layout, x, y, &options).map(|_| ());
    assert_eq!(
        fit(&x[..2 * 10], &y[..10]),
        Err(ResidualError::TooFewRows {
            rows: 10,
            min: MIN_ROWS
        })
    );
    assert_eq!(
        fit(&x[..59], &y),
        Err(ResidualError::RaggedFeatures {
            what: "features",
            values: 59,
            columns: 2
        })
    );
    assert_eq!(
        fit(&x, &y[..29]),
        Err(ResidualError::LengthMismatch {
            features: 30,
            residuals: 29
        })
    );
    let mut bad_x = x.clone();
    bad_x[2 * 7 + 1] = f64::NAN;
    assert_eq!(
        fit(&bad_x, &y),
        Err(ResidualError::NonFinite {
            what: "features",
            row: 7
        })
    );
    let mut bad_y = y.clone();
    bad_y[12][2] = f64::INFINITY;
    assert_eq!(
        fit(&x, &bad_y),
        Err(ResidualError::NonFinite {
            what: "residuals",
            row: 12
        })
    );
    assert!(matches!(
        FeatureLayout::new(vec![0, 2]),
        Err(ResidualError::Layout(_))
    ));
    let hyperparameters = Hyperparameters {
        signal_variance_mm2: 1.0,
        noise_variance_mm2: 0.0,
        length_scales: vec![1.0],
    };
    assert!(matches!(
        ResidualModel::with_hyperparameters(&layout, &x, &y, &hyperparameters, None),
        Err(ResidualError::Hyperparameter { .. })
    ));
    let model = ResidualModel::fit(&layout, &x, &y, &options).expect("fit");
    assert_eq!(
        model.predict(&[0.0, f64::NAN]),
        Err(ResidualError::NonFinite {
            what: "prediction features",
            row: 0
        })
    );
}

#[test]
fn duplicate_rows_without_noise_are_factored_with_jitter() {
    // Every row the same point: K is all s², and K + σ²I with σ² = 1e-30 s² is
    // singular in floating point. The jitter ladder makes it factorable.
    let layout = one_group(1);
    let x = vec![0.5; 25];
    let y = vec![[0.1, 0.2, 0.3]; 25];
    let hyperparameters = Hyperparameters {
        signal_variance_mm2: 1.0,
        noise_variance_mm2: 1e-30,
        length_scales: vec![1.0],
    };
    let model = ResidualModel::with_hyperparameters(&layout, &x, &y, &hyperparameters, None)
        .expect("jitter makes it positive definite");
    assert!(model.jitter() > 0.0);
}
