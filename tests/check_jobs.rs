//! Every shipped job file passes `egcal check` (job file, robot, cable robot,
//! external inputs' schemas), so examples cannot rot. Jobs that read another
//! job's outputs are checked by their own tests, after that job has run.

mod common;

/// Jobs whose inputs another job writes (checked in `tests/nightly.rs`), and the
/// fleet file, which is not a job (checked in `tests/fleet.rs`).
const RUN_AFTER_OTHER_JOBS: [&str; 2] = ["nightly.toml", "fleet.toml"];

#[test]
fn shipped_jobs_check_clean() {
    let jobs = common::root().join("jobs");
    let mut checked = 0;
    for entry in std::fs::read_dir(&jobs).unwrap().flatten() {
        let path = entry.path();
        let after_other_jobs = RUN_AFTER_OTHER_JOBS
            .iter()
            .any(|name| path.file_name().is_some_and(|n| n == *name));
        if path.extension().is_some_and(|e| e == "toml") && !after_other_jobs {
            let (code, stdout, stderr) = common::run(&["check", path.to_str().unwrap()], &jobs);
            assert_eq!(code, 0, "{}: {stdout}{stderr}", path.display());
            checked += 1;
        }
    }
    assert!(checked >= 1);
}
