//! One DETMAX selection (fast engine, O1, n = 100, one start) over a given
//! number of random candidates, for the README's scaling table
//! (`benches/scaling.sh`; peak memory is the process's):
//! `cargo run --release --example detmax_scaling -- 100000`.
//!
//! Prints `candidates,build_s,select_s,exchanges`: building the candidates'
//! Jacobian and the selection, timed apart.

use std::time::Instant;

use egcal::design::detmax::{self, Method, Options};

#[path = "../benches/common/random_candidates.rs"]
mod random_candidates;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let count: usize = std::env::args()
        .nth(1)
        .ok_or("usage: detmax_scaling CANDIDATES")?
        .parse()?;
    let started = Instant::now();
    let candidates = random_candidates::candidates(count, 2);
    let build_s = started.elapsed().as_secs_f64();
    let options = Options {
        n: 100,
        criterion: detmax::Criterion::O1,
        method: Method::Fast,
        max_iterations: 10_000,
        shortlist: 0,
        seed: 2026,
    };
    let started = Instant::now();
    let result = detmax::detmax(&candidates, &options)?;
    let select_s = started.elapsed().as_secs_f64();
    println!("{count},{build_s:.3},{select_s:.3},{}", result.trace.len());
    Ok(())
}
