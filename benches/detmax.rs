//! Benchmarks of DETMAX (issue #4 item 5): 875 candidates, n = 50, fast against
//! naive in the same run (target ratio ≥ 100); 100 000 candidates, n = 100, fast
//! (target < 10 s on 2 cores). One random start each, criterion O1.
//!
//! Candidates are what the select stage sees: random joint configurations within
//! the limits and random wrenches (±120 N, ±10 N·m) of the nominal IRB 1600, the
//! spec's 32 identifiable parameters, `batch_jacobian`, columns scaled to unit norm.
//! The naive engine (a fresh SVD per trial) takes seconds per run, so it and the
//! ratio are timed once, outside criterion's sampling, and printed as `summary:`.
//! Run: `cargo bench --bench detmax`.

use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use egcal::design::detmax::{self, Method, Options};

#[path = "common/random_candidates.rs"]
mod random_candidates;
use random_candidates::candidates;

fn options(n: usize, method: Method) -> Options {
    Options {
        n,
        criterion: detmax::Criterion::O1,
        method,
        max_iterations: 10_000,
        shortlist: 0,
        seed: 2026,
    }
}

/// Seconds of one call, and its result.
fn timed<T>(f: impl FnOnce() -> T) -> (f64, T) {
    let start = Instant::now();
    let out = f();
    (start.elapsed().as_secs_f64(), out)
}

fn paper_size(c: &mut Criterion) {
    let cands = candidates(875, 1);
    let fast = options(50, Method::Fast);
    c.bench_function("detmax fast, 875 candidates, n = 50", |b| {
        b.iter(|| detmax::detmax(&cands, &fast).expect("selection"))
    });
    // The ratio, from the same start: median of 5 fast runs against one naive run.
    let mut fast_s: Vec<f64> = (0..5)
        .map(|_| timed(|| detmax::detmax(&cands, &fast)).0)
        .collect();
    fast_s.sort_by(f64::total_cmp);
    let (_, fast_result) = timed(|| detmax::detmax(&cands, &fast).expect("selection"));
    let (naive_s, naive_result) =
        timed(|| detmax::detmax(&cands, &options(50, Method::Naive)).expect("selection"));
    println!(
        "summary: 875 candidates, n = 50: fast {:.2} ms (median of 5), naive {:.2} s, ratio {:.0}; \
         exchanges {} / {}; O1 start {:.6}, fast {:.9}, naive {:.9}; same selection: {}",
        fast_s[2] * 1e3,
        naive_s,
        naive_s / fast_s[2],
        fast_result.trace.len(),
        naive_result.trace.len(),
        fast_result.o1_start,
        fast_result.o1,
        naive_result.o1,
        fast_result.chosen == naive_result.chosen
    );
}

fn large(c: &mut Criterion) {
    let (build_s, cands) = timed(|| candidates(100_000, 2));
    let fast = options(100, Method::Fast);
    let (run_s, result) = timed(|| detmax::detmax(&cands, &fast).expect("selection"));
    println!(
        "summary: 100000 candidates, n = 100: fast {run_s:.2} s ({} exchanges, {} refactorisations, \
         converged: {}); O1 start {:.6}, final {:.12}; building the candidates (batch_jacobian) {build_s:.2} s",
        result.trace.len(),
        result.refactorisations,
        result.converged,
        result.o1_start,
        result.o1
    );
    let mut group = c.benchmark_group("large");
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(1));
    group.bench_function("detmax fast, 100000 candidates, n = 100", |b| {
        b.iter(|| detmax::detmax(&cands, &fast).expect("selection"))
    });
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20).warm_up_time(Duration::from_secs(1));
    targets = paper_size, large
}
criterion_main!(benches);
