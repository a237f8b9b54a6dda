//! Every shipped job file passes `egcal check` (job file, robot, cable robot,
//! external inputs' schemas), so examples cannot rot.

mod common;

#[test]
fn shipped_jobs_check_clean() {
    let jobs = common::root().join("jobs");
    let mut checked = 0;
    for entry in std::fs::read_dir(&jobs).unwrap().flatten() {
        let path = entry.path();
        if path.extension().is_some_and(|e| e == "toml") {
            let (code, stdout, stderr) = common::run(&["check", path.to_str().unwrap()], &jobs);
            assert_eq!(code, 0, "{}: {stdout}{stderr}", path.display());
            checked += 1;
        }
    }
    assert!(checked >= 1);
}
