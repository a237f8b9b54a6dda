//! The paper's campaign in simulation, end to end (`jobs/paper_sim.toml`), with
//! the paper's qualitative result: elasto-geometric calibration beats kinematic
//! calibration by far, kinematic beats registration only, and the paired t-test
//! between kinematic and elasto-geometric errors is significant.

mod common;

use std::path::Path;

use egcal::table::{self, schema};

#[test]
fn paper_campaign_reproduces_the_qualitative_result() {
    let dir = tempfile::tempdir().unwrap();
    let jobs = common::root().join("jobs");
    let text = std::fs::read_to_string(jobs.join("paper_sim.toml")).unwrap();
    // Same job, run from a temporary folder: make its relative paths absolute.
    let text = text
        .replace("\"robots/", &format!("\"{}/robots/", jobs.display()))
        .replace("\"cdpr/", &format!("\"{}/cdpr/", jobs.display()))
        .replace("\"truth/", &format!("\"{}/truth/", jobs.display()));
    let job = dir.path().join("paper_sim.toml");
    std::fs::write(&job, text).unwrap();
    let (code, stdout, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 0, "{stdout}\n{stderr}");

    let out = dir.path().join("out/paper_sim");
    let candidates = table::read_parquet(&out.join("wrenches/candidates.parquet")).unwrap();
    // The default cable robot cannot apply every drawn wrench at every pose (see
    // docs/paper-campaign.md), but the campaign keeps enough rows for DETMAX and validation.
    assert!(
        candidates.height() >= 400,
        "{} candidates",
        candidates.height()
    );
    let selection = table::read_parquet(&out.join("select/selection.parquet")).unwrap();
    let roles = schema::str_values(&selection, "role", Path::new("s")).unwrap();
    assert_eq!(
        roles
            .iter()
            .filter(|r| r.as_deref() == Some("calibration"))
            .count(),
        50
    );

    let stats = table::read_parquet(&out.join("validate/stats.parquet")).unwrap();
    let models = schema::str_values(&stats, "model", Path::new("s")).unwrap();
    let max = schema::f64_values(&stats, "max_mm", Path::new("s")).unwrap();
    let max_of = |model: &str| {
        max[models
            .iter()
            .position(|m| m.as_deref() == Some(model))
            .unwrap()]
    };
    let (registered, kinematic, eg) = (
        max_of("registered"),
        max_of("kinematic"),
        max_of("elastogeometric"),
    );
    assert!(
        eg < 0.25 * kinematic,
        "elasto-geometric max {eg} vs kinematic {kinematic}"
    );
    assert!(
        kinematic < 0.8 * registered,
        "kinematic max {kinematic} vs registered {registered}"
    );

    let tests = table::read_parquet(&out.join("validate/tests.parquet")).unwrap();
    let a = schema::str_values(&tests, "model_a", Path::new("t")).unwrap();
    let b = schema::str_values(&tests, "model_b", Path::new("t")).unwrap();
    let kind = schema::str_values(&tests, "test", Path::new("t")).unwrap();
    let p = schema::f64_values(&tests, "p_value", Path::new("t")).unwrap();
    let paired = (0..p.len())
        .find(|&i| {
            a[i].as_deref() == Some("kinematic")
                && b[i].as_deref() == Some("elastogeometric")
                && kind[i].as_deref() == Some("paired_t")
        })
        .unwrap();
    assert!(p[paired] < 1e-6, "paired t-test p = {}", p[paired]);

    // The report: the verdict first (the elasto-geometric max within the job's
    // 1 mm), then Table III beside this run's statistics, since this job
    // reproduces the paper.
    let html = std::fs::read_to_string(out.join("report/report.html")).unwrap();
    assert!(
        html.find("<section id=\"verdict\">") < html.find("<nav>"),
        "the verdict comes first"
    );
    assert!(html.contains(
        "<span class=\"badge\">PASS</span> Model in service: <strong>elastogeometric</strong>"
    ));
    assert!(html.contains(&format!(
        "Its max validation error, {eg:.3} mm, is within the tolerance of 1.000 mm."
    )));
    assert!(html.contains("Position errors on the validation rows (Table III)"));
    assert!(html.contains(
        "<td class=\"paper\">Elasto-geometrical calibration</td><td class=\"num paper\">0.264</td>"
    ));
    assert!(html.contains("world-frame error of the truth"));

    // A second run does no work.
    let (code, stdout, _) = common::run(&["run", "--quiet", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 0);
    assert!(stdout.contains("0 ran"), "{stdout}");
}
