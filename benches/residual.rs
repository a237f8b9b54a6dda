//! Benchmarks of the Gaussian-process residual model (issue 29, `eg_residual`):
//! fit on 10 000 rows (target < 10 s on 2 cores) and predict 10 000 points
//! (target < 1 s), default options (256 inducing points, hyperparameters on
//! 2000 rows, 3 starts).
//!
//! Rows are what the identify stage will pass: random joint configurations
//! within ±170° and random wrenches (±120 N, ±10 N·m) as
//! `joint_load_features`, and a residual of 0.05 mm amplitude that is smooth
//! in the joints and linear in the load, plus 0.02 mm tracker noise per axis.
//! The fit takes seconds, so it is timed by criterion with 10 samples and also
//! once outside it with the fitted hyperparameters printed as `summary:`.
//! Run: `cargo bench --bench residual`.

use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use egcal::calibration::residual::{
    FeatureLayout, ResidualModel, ResidualOptions, joint_load_features,
};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};

/// `n` feature rows and residuals (mm).
fn rows(n: usize, seed: u64) -> (Vec<f64>, Vec<[f64; 3]>) {
    let mut rng = StdRng::seed_from_u64(seed);
    let noise = Normal::new(0.0, 0.02).expect("positive sd");
    let mut features = Vec::with_capacity(n * 18);
    let mut residuals = Vec::with_capacity(n);
    for _ in 0..n {
        let q: [f64; 6] = std::array::from_fn(|_| rng.random_range(-170.0..170.0));
        let wrench: [f64; 6] = std::array::from_fn(|i| {
            let bound = if i < 3 { 120.0 } else { 10.0 };
            rng.random_range(-bound..bound)
        });
        features.extend(joint_load_features(&q, &wrench));
        let r = |k: usize| (2.0 * q[k].to_radians()).sin();
        let truth = [
            0.05 * r(1) + 0.0002 * wrench[2] * r(2),
            0.05 * r(2) * r(0) + 0.0001 * wrench[0],
            0.05 * (q[3] + q[4]).to_radians().cos(),
        ];
        residuals.push(truth.map(|t| t + noise.sample(&mut rng)));
    }
    (features, residuals)
}

fn residual(c: &mut Criterion) {
    let layout = FeatureLayout::joint_load();
    let options = ResidualOptions::default();
    let (features, residuals) = rows(10_000, 1);
    let (targets, _) = rows(10_000, 2);
    let start = Instant::now();
    let model = ResidualModel::fit(&layout, &features, &residuals, &options).expect("fit");
    let fit_s = start.elapsed().as_secs_f64();
    let start = Instant::now();
    let predicted = model.predict(&targets).expect("predict");
    let predict_s = start.elapsed().as_secs_f64();
    let h = model.hyperparameters();
    let mean_sd = (predicted.iter().map(|p| p.latent_variance_mm2).sum::<f64>()
        / predicted.len() as f64)
        .sqrt();
    println!(
        "summary: 10000 rows: fit {fit_s:.2} s, predict 10000 points {predict_s:.3} s; \
         s² {:.3e} mm², σ² {:.3e} mm² (simulated 4.0e-4), {} inducing points, \
         RMS latent sd at the targets {mean_sd:.4} mm",
        h.signal_variance_mm2,
        h.noise_variance_mm2,
        model.inducing_points()
    );
    let mut group = c.benchmark_group("residual");
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(1));
    group.bench_function("predict 10000 points", |b| {
        b.iter(|| model.predict(&targets).expect("predict"))
    });
    group.bench_function("fit 10000 rows", |b| {
        b.iter(|| ResidualModel::fit(&layout, &features, &residuals, &options).expect("fit"))
    });
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().warm_up_time(Duration::from_secs(1));
    targets = residual
}
criterion_main!(benches);
