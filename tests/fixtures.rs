//! Data-driven stage tests: every case under `fixtures/` (`<kind>/<case>/case.toml`:
//! a stage kind run on the case's files and checked against its `[expect]`),
//! run by the same library function as `egcal test`, so the project's fixtures
//! and a lab's own cannot drift apart. The format is documented in
//! `src/fixture_cases/case.rs`, `schemas/fixture-case.schema.json` and docs/fixture-cases.md.
//!
//! Expected tables and strings come from independent sources (see `fixtures/tools/`).

mod common;

use egcal::fixture_cases::{self, TestOptions};

#[test]
fn every_fixture_case_passes() {
    let options = TestOptions {
        dirs: vec![common::root().join("fixtures")],
        only: Vec::new(),
        jobs: std::thread::available_parallelism().map_or(1, |n| n.get()),
        egcal: env!("CARGO_BIN_EXE_egcal").into(),
        timeout: std::time::Duration::from_secs(600),
    };
    let summary = fixture_cases::run(&options, &|_| {}).expect("the fixtures folder is readable");
    assert!(
        summary.results.len() >= 60,
        "found only {} fixture cases",
        summary.results.len()
    );
    assert_eq!(summary.exit_code(), 0, "{}", summary.report());
}
