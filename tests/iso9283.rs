//! The ISO 9283 pose test end to end (`jobs/iso9283_sim.toml`): calibrate as
//! the paper campaign does, place the test cube, run its 30 cycles on the
//! simulated robot compensated and with the controller's nominal IK, and
//! compute AP, RP, AD and RD for both. Sanity, not canned values: compensation
//! brings AP far below the nominal IK's, and RP, which only the tracker noise
//! makes (the simulator repeats a command exactly), is about 3.6 σ of that
//! noise (the mean plus three standard deviations of a Maxwell distribution).
//! The job's report shows both tests in one table.

mod common;

use std::path::Path;

use egcal::table::{self, schema};

/// The simulator's tracker noise in the job (1 σ per axis, mm).
const TRACKER_NOISE_MM: f64 = 0.02;

fn column(file: &Path, name: &str) -> Vec<f64> {
    let df = table::read_parquet(file).unwrap();
    schema::f64_values(&df, name, file).unwrap()
}

#[test]
fn compensation_brings_iso_pose_accuracy_down_and_repeatability_is_the_tracker_noise() {
    let dir = tempfile::tempdir().unwrap();
    let jobs = common::root().join("jobs");
    let text = std::fs::read_to_string(jobs.join("iso9283_sim.toml")).unwrap();
    // Same job, run from a temporary folder: make its relative paths absolute.
    let text = ["robots/", "cdpr/", "truth/"]
        .iter()
        .fold(text, |text, folder| {
            text.replace(
                &format!("\"{folder}"),
                &format!("\"{}/{folder}", jobs.display()),
            )
        });
    let job = dir.path().join("iso9283_sim.toml");
    std::fs::write(&job, text).unwrap();
    let (code, stdout, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 0, "{stdout}\n{stderr}");

    let out = dir.path().join("out/iso9283_sim");
    let mut mean_ap = Vec::new();
    for run in ["iso_compensated", "iso_nominal"] {
        let file = out.join(run).join("iso9283.parquet");
        let df = table::read_parquet(&file).unwrap();
        let points = schema::str_values(&df, "point", &file).unwrap();
        let n = schema::i64_values(&df, "n", &file).unwrap();
        assert_eq!(points.len(), 5, "{run}: {points:?}");
        assert!(n.iter().all(|&n| n == 30), "{run}: cycles {n:?}");
        for rp in column(&file, "rp_mm") {
            let ratio = rp / TRACKER_NOISE_MM;
            assert!(
                (2.5..5.0).contains(&ratio),
                "{run}: RP {rp:.4} mm is {ratio:.2} σ of the tracker noise"
            );
        }
        let ap = column(&file, "ap_mm");
        mean_ap.push(ap.iter().sum::<f64>() / ap.len() as f64);
        let distances = out.join(run).join("iso9283_distances.parquet");
        let commanded = column(&distances, "d_cmd_mm");
        assert!((commanded[0] - 692.820).abs() < 5e-4, "{commanded:?}");
    }
    let (compensated, nominal) = (mean_ap[0], mean_ap[1]);
    assert!(
        compensated * 20.0 < nominal,
        "mean AP compensated {compensated:.4} mm, nominal IK {nominal:.4} mm"
    );
    let ad = |run: &str| column(&out.join(run).join("iso9283_distances.parquet"), "ad_mm")[0];
    assert!(
        ad("iso_compensated") < ad("iso_nominal"),
        "AD compensated {}, nominal {}",
        ad("iso_compensated"),
        ad("iso_nominal")
    );

    // The job's report shows both tests side by side, per point and per pair.
    let html = std::fs::read_to_string(out.join("report/report.html")).unwrap();
    assert!(html.contains("<table class=\"iso9283\">"), "ISO 9283 table");
    assert!(html.contains(
        "<th class=\"num\">AP compensated (mm)</th><th class=\"num\">AP nominal (mm)</th>"
    ));
    for point in ["P1", "P2", "P3", "P4", "P5"] {
        assert!(
            html.contains(&format!("<tr><td>{point}</td><td class=\"num\">30</td>")),
            "{point}"
        );
    }
    assert!(
        html.contains("<table class=\"iso9283_distances\">")
            && html.contains("<tr><td>P2</td><td>P4</td>")
    );
}
