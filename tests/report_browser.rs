//! The `report` stage through the binary on a small simulated campaign, then the
//! page opened in headless Chromium: the DOM it builds has the tables and the
//! SVG charts, and a screenshot is drawn.
//!
//! Needs Debian's `chromium`. Without it the test fails when `CI` is set (CI
//! installs it, see `.ci/run`) and otherwise prints that it skipped.

mod common;

use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{root, run};

/// A small campaign ending in a report: 27 poses × 3 wrenches measured in the
/// simulator, 30 rows selected by DETMAX for identification, the rest for validation.
fn report_job(dir: &Path) -> PathBuf {
    let root = root();
    let text = format!(
        r#"[job]
name = "small_report"
seed = 11
robot = "{robot}"
cable_robot = "{cable}"
output = "out"

[[stages]]
id = "poses"
kind = "poses"
points_per_axis = 3
edge_mm = 400.0

[[stages]]
id = "wrenches"
kind = "wrenches"
inputs = {{ poses = "poses" }}
per_config = 3

[[stages]]
id = "select"
kind = "select"
inputs = {{ candidates = "wrenches" }}
n = 30

[[stages]]
id = "measure"
kind = "measure"
inputs = {{ conf_wrenches = "wrenches", truth = "{truth}" }}

[[stages]]
id = "identify"
kind = "identify"
inputs = {{ measurements = "measure.measurements", selection = "select.selection" }}

[[stages]]
id = "validate"
kind = "validate"
inputs = {{ measurements = "measure.measurements", parameters = "identify", selection = "select.selection" }}

[[stages]]
id = "accuracy_map"
kind = "accuracy_map"
inputs = {{ parameters = "identify.parameters", covariance = "identify.covariance", measurements = "measure.measurements", selection = "select.selection" }}
points_per_axis = 8
slices = 2

[[stages]]
id = "report"
kind = "report"
title = "Small <campaign> report"
histogram_bins = 12
tolerance_mm = 1.0
compare_with_paper = true

[stages.inputs]
stats = "validate.stats"
errors = "validate.errors"
parameters = "identify.parameters"
tests = "validate.tests"
poses = "poses"
observability = "select.observability"
identification_trace = "identify.identification_trace"
accuracy_map = "accuracy_map.accuracy_map"
calibration_positions = "accuracy_map.calibration_positions"
truth = "{truth}"
"#,
        robot = root.join("jobs/robots/irb1600_145.toml").display(),
        cable = root.join("jobs/cdpr/default.toml").display(),
        truth = root.join("jobs/truth/irb1600_paper.parquet").display(),
    );
    let path = dir.join("job.toml");
    std::fs::write(&path, text).expect("write job");
    path
}

/// The Chromium binary, if installed.
fn chromium() -> Option<PathBuf> {
    let candidates = ["/usr/bin/chromium", "/usr/bin/chromium-browser"];
    candidates
        .iter()
        .map(PathBuf::from)
        .find(|p| p.exists())
        .or_else(|| {
            let path = std::env::var_os("PATH")?;
            std::env::split_paths(&path)
                .map(|d| d.join("chromium"))
                .find(|p| p.exists())
        })
}

/// Runs headless Chromium on `page` with `extra` arguments; stdout goes to
/// `stdout_file`. Killed after two minutes.
fn headless(chromium: &Path, profile: &Path, extra: &[String], page: &Path, stdout_file: &Path) {
    let mut args: Vec<String> = [
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--hide-scrollbars",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    args.push(format!("--user-data-dir={}", profile.display()));
    args.extend(extra.iter().cloned());
    args.push(format!("file://{}", page.display()));
    let stdout = File::create(stdout_file).unwrap();
    let stderr = File::create(stdout_file.with_extension("stderr")).unwrap();
    let mut child = Command::new(chromium)
        .args(&args)
        .stdin(Stdio::null())
        .stdout(stdout)
        .stderr(stderr)
        .spawn()
        .expect("chromium starts");
    let started = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            let log =
                std::fs::read_to_string(stdout_file.with_extension("stderr")).unwrap_or_default();
            assert!(
                status.success(),
                "chromium {args:?} failed: {status}\n{log}"
            );
            return;
        }
        if started.elapsed() > Duration::from_secs(120) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("chromium {args:?} did not finish within 120 s");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

#[test]
fn report_renders_in_a_headless_browser() {
    let dir = tempfile::tempdir().unwrap();
    let job = report_job(dir.path());
    let job = job.to_str().unwrap();
    let (code, stdout, stderr) = run(&["run", job], dir.path());
    assert_eq!(code, 0, "{stdout}\n{stderr}");
    let page = dir.path().join("out/report/report.html");
    let html = std::fs::read_to_string(&page).expect("report.html is published");

    // The page itself: escaped title, the verdict first, Table III beside this
    // run, every section, the charts.
    assert!(html.contains("<title>Small &#60;campaign&#62; report</title>"));
    assert!(
        html.find("<section id=\"verdict\">") < html.find("<nav>"),
        "the verdict comes before the table of contents"
    );
    assert!(
        html.contains(
            "<span class=\"badge\">PASS</span> Model in service: <strong>elastogeometric</strong>"
        ),
        "the elasto-geometric model within 1 mm"
    );
    assert!(html.contains("<h3 id=\"warnings\">Warnings ("));
    assert!(
        html.contains("Elasto-geometrical calibration")
            && html.contains("no counterpart in the paper")
    );
    for id in [
        "verdict",
        "errors",
        "histograms",
        "poses",
        "accuracy",
        "parameters",
        "observability",
        "convergence",
        "tests",
        "provenance",
    ] {
        assert!(
            html.contains(&format!("<section id=\"{id}\">")),
            "section {id}"
        );
    }
    // Overlay + 4 per-model histograms + poses + 2 map slices + O1 + convergence.
    assert_eq!(html.matches("<svg").count(), 10, "charts");
    // The accuracy map: one heat map per slice, its caption and the medians.
    assert!(html.contains("u95 at z = "), "accuracy map slices");
    assert!(
        html.contains("Median u95 inside the box:")
            && html.contains("calibration positions within"),
        "accuracy map text"
    );
    assert!(
        html.contains("small_report") && html.contains("created at"),
        "provenance"
    );

    // Rendering again from the same inputs gives the same bytes.
    let (code, _, stderr) = run(&["run", job, "--only", "report", "--force"], dir.path());
    assert_eq!(code, 0, "{stderr}");
    assert!(stderr.contains("report: running report"), "{stderr}");
    assert_eq!(
        std::fs::read_to_string(&page).unwrap(),
        html,
        "report is not deterministic"
    );

    let Some(chromium) = chromium() else {
        if std::env::var_os("CI").is_some() {
            panic!(
                "chromium is not installed, and CI is set: CI must install it (apt-get install chromium)"
            );
        }
        eprintln!(
            "SKIPPED the browser part of report_renders_in_a_headless_browser: chromium is not installed (apt-get install chromium)"
        );
        return;
    };

    let browser = tempfile::tempdir().unwrap();
    let dom_file = browser.path().join("dom.html");
    headless(
        &chromium,
        &browser.path().join("profile-dom"),
        &["--dump-dom".to_string()],
        &page,
        &dom_file,
    );
    let dom = std::fs::read_to_string(&dom_file).unwrap();
    assert!(
        dom.contains("<div class=\"verdict pass\">") && dom.contains("<table class=\"figures\">"),
        "the verdict in the DOM"
    );
    assert!(
        dom.contains("<table class=\"stats\">"),
        "stats table in the DOM"
    );
    assert!(
        dom.contains("<table class=\"parameters\">"),
        "parameters table in the DOM"
    );
    assert!(
        dom.contains("<table class=\"tests\">"),
        "tests table in the DOM"
    );
    assert!(dom.contains("<td>elastogeometric</td>") && dom.contains("<td>kinematic</td>"));
    assert!(
        dom.contains("x_w") && dom.contains("k6"),
        "parameter rows in the DOM"
    );
    assert_eq!(dom.matches("<svg").count(), 10, "svg elements in the DOM");
    assert!(
        dom.matches("<rect").count() > 20 && dom.contains("<circle"),
        "chart content in the DOM"
    );
    assert!(!dom.contains("<parsererror"), "the page parses");

    let shot = browser.path().join("shot.png");
    headless(
        &chromium,
        &browser.path().join("profile-shot"),
        &[
            format!("--screenshot={}", shot.display()),
            "--window-size=1280,2000".to_string(),
        ],
        &page,
        &browser.path().join("shot.stdout"),
    );
    let png = std::fs::read(&shot).expect("the screenshot exists");
    assert!(png.starts_with(b"\x89PNG\r\n\x1a\n"), "a PNG file");
    // A blank 1280×2000 page compresses to a few kB; text, tables and charts do not.
    assert!(
        png.len() > 40_000,
        "screenshot of {} bytes looks empty",
        png.len()
    );
}
