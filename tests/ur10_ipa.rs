//! The real-data job (`jobs/ur10_ipa.toml`) end to end on the UR10 tracker data
//! in `../shared/realdata/ur10-ipa`: the figures the README gives, within a
//! margin, beside the independent fit of the data's README. Skipped, with a
//! message, where the data are not beside the checkout.

mod common;

use std::path::Path;

use egcal::table::{self, schema};

/// Mean validation error (mm) of `model` in a validate stage's `stats`.
fn mean_mm(out: &Path, stage: &str, model: &str) -> f64 {
    common::ur10::stat(out, stage, model, "mean_mm")
}

#[test]
fn the_ur10_job_calibrates_series_c_and_carries_it_to_b_and_d() {
    let Some((_dir, out)) = common::ur10::run_job("ur10_ipa") else {
        return;
    };

    // Series C, half fitted and half validated (independent fit: 0.90, 0.44, 0.44).
    let registered = mean_mm(&out, "validate_c", "registered");
    let kinematic = mean_mm(&out, "validate_c", "kinematic");
    let elastogeometric = mean_mm(&out, "validate_c", "elastogeometric");
    assert!((registered - 0.90).abs() < 0.05, "registered {registered}");
    assert!(kinematic < 0.46, "kinematic {kinematic}");
    assert!(elastogeometric < 0.46, "elasto-geometric {elastogeometric}");
    // Only the frames refitted on B and D: better than the nominal robot there,
    // and the elasto-geometric robot better than the kinematic one.
    for series in ["b", "d"] {
        let nominal = mean_mm(&out, &format!("validate_{series}_kin"), "registered");
        let kinematic = mean_mm(&out, &format!("validate_{series}_kin"), "reregistered");
        let elastogeometric = mean_mm(&out, &format!("validate_{series}_eg"), "reregistered");
        assert!(
            elastogeometric < kinematic && kinematic < nominal,
            "series {series}: nominal {nominal}, kinematic {kinematic}, elasto-geometric {elastogeometric}"
        );
    }

    // Issue #28: series C carried to the other halves of B and D (only the
    // frames refitted on their first halves): measured 0.556 and 0.551 mm
    // mean with the job's settings (the issue's targets, 0.48 and 0.40, are
    // not met: docs/real-cells.md, held-out validation).
    let carried_b = mean_mm(&out, "validate_b_eg", "reregistered");
    let carried_d = mean_mm(&out, "validate_d_eg", "reregistered");
    assert!(
        (carried_b - 0.556).abs() < 0.03,
        "C carried to B: {carried_b}"
    );
    assert!(
        (carried_d - 0.551).abs() < 0.03,
        "C carried to D: {carried_d}"
    );

    // Issue #28: held-out accuracy by configuration beside random folds
    // (measured: elasto-geometric 0.468 and 0.432 mm mean, p99.7 1.25 and
    // 1.20 mm). Away from the calibration rows the error grows.
    let path = out.join("crossvalidate_c/stats.parquet");
    let stats = table::read_parquet(&path).unwrap();
    let protocols = schema::str_values(&stats, "protocol", &path).unwrap();
    let models = schema::str_values(&stats, "model", &path).unwrap();
    let means = schema::f64_values(&stats, "mean_mm", &path).unwrap();
    let held_out = |protocol: &str| {
        (0..means.len())
            .find(|k| {
                protocols[*k].as_deref() == Some(protocol)
                    && models[*k].as_deref() == Some("elastogeometric")
            })
            .map(|k| means[k])
            .unwrap_or_else(|| panic!("no {protocol} row"))
    };
    let (grouped, random) = (held_out("configuration"), held_out("random"));
    assert!(
        (grouped - 0.468).abs() < 0.03,
        "configuration folds {grouped}"
    );
    assert!((random - 0.432).abs() < 0.03, "random folds {random}");
    assert!(grouped > random, "configuration {grouped}, random {random}");
    let report = std::fs::read_to_string(out.join("report_c/report.html")).unwrap();
    assert!(
        report.contains("Held-out accuracy"),
        "the report shows them"
    );

    // Issue #29: the ladder, climbed from the elasto-geometric model, does not
    // take eg_harmonic (measured 0.499 mm on configuration folds against
    // 0.468), and lists the simpler models without choosing one (kinematic is
    // 2 % worse, below the minimum gain a richer model must show).
    let path = out.join("crossvalidate_c/ladder.parquet");
    let ladder = table::read_parquet(&path).unwrap();
    let models = schema::str_values(&ladder, "model", &path).unwrap();
    let means = schema::f64_values(&ladder, "mean_mm", &path).unwrap();
    let chosen: Vec<bool> = ladder
        .column("chosen")
        .unwrap()
        .bool()
        .unwrap()
        .iter()
        .map(Option::unwrap)
        .collect();
    let position = |model: &str| {
        models
            .iter()
            .position(|m| m.as_deref() == Some(model))
            .unwrap_or_else(|| panic!("no {model} rung: {models:?}"))
    };
    let (eg, harmonic, residual) = (
        position("elastogeometric"),
        position("eg_harmonic"),
        position("eg_residual"),
    );
    assert!((means[eg] - grouped).abs() < 1e-12);
    assert!(
        means[harmonic] > means[eg],
        "eg_harmonic {}",
        means[harmonic]
    );
    // eg_residual over the paper's model is chosen, its tail lower too
    // (measured 0.350 mm, p99.7 1.07 against 1.25 mm).
    let k = chosen.iter().position(|c| *c).unwrap();
    assert_eq!(k, residual, "{models:?}");
    assert!(
        means[residual] < 0.8 * means[eg],
        "eg_residual {}",
        means[residual]
    );
    let tails = schema::f64_values(&ladder, "p997_mm", &path).unwrap();
    assert!(tails[residual] < tails[eg], "{tails:?}");

    // Issue #29: series C's own halves with the learned rung: 0.333 mm mean
    // measured (target 0.35; elasto-geometric 0.427).
    let learned = mean_mm(&out, "validate_c", "eg_residual");
    assert!(learned < 0.35, "eg_residual on C's halves {learned}");

    // Issue #29: series A (11,911 rows on a grid) by workspace region beside
    // random folds (measured: elasto-geometric 0.413 and 0.382 mm; eg_harmonic
    // 0.447 mm with a 99.7th percentile of 4.33 mm by region: harmonics fitted
    // without a region extrapolate into it). The ladder keeps the paper's model.
    let path = out.join("crossvalidate_a/stats.parquet");
    let stats = table::read_parquet(&path).unwrap();
    let protocols = schema::str_values(&stats, "protocol", &path).unwrap();
    let models = schema::str_values(&stats, "model", &path).unwrap();
    let means = schema::f64_values(&stats, "mean_mm", &path).unwrap();
    let held_out = |protocol: &str, model: &str| {
        (0..means.len())
            .find(|k| {
                protocols[*k].as_deref() == Some(protocol) && models[*k].as_deref() == Some(model)
            })
            .map(|k| means[k])
            .unwrap_or_else(|| panic!("no {protocol} {model} row"))
    };
    let (region, random) = (
        held_out("region", "elastogeometric"),
        held_out("random", "elastogeometric"),
    );
    assert!((region - 0.413).abs() < 0.03, "series A by region {region}");
    assert!((random - 0.382).abs() < 0.03, "series A random {random}");
    assert!(region > random, "region {region}, random {random}");
    assert!(held_out("region", "eg_harmonic") > region);
    let path = out.join("crossvalidate_a/ladder.parquet");
    let ladder = table::read_parquet(&path).unwrap();
    let models = schema::str_values(&ladder, "model", &path).unwrap();
    let chosen = ladder.column("chosen").unwrap().bool().unwrap().clone();
    let k = (0..ladder.height())
        .find(|k| chosen.get(*k) == Some(true))
        .unwrap();
    assert_eq!(models[k].as_deref(), Some("elastogeometric"), "{models:?}");

    // Issue #26, 2: before, dtheta5 = -13.5° ± 10.6, dalpha6 = 17.2° ± 12.7 and
    // dd5 = -55.6 ± 43.6 mm were put in service as `identified`. Now the
    // near-dependent ones are held at nominal with their reason, no identified
    // value is absurd, and validation is within 2 % of before (0.433, 0.427).
    let path = out.join("identify_c/parameters.parquet");
    let df = table::read_parquet(&path).unwrap();
    let text = |c: &str| schema::str_values(&df, c, &path).unwrap();
    let number = |c: &str| schema::f64_values(&df, c, &path).unwrap();
    let (models, names, statuses, reasons) =
        (text("model"), text("name"), text("status"), text("reason"));
    let (values, nominals) = (number("value"), number("nominal"));
    let std_errors = df.column("std_error").unwrap().f64().unwrap().clone();
    for row in 0..df.height() {
        let name = names[row].as_deref().unwrap();
        let status = statuses[row].as_deref().unwrap();
        let model = models[row].as_deref().unwrap();
        if ["dtheta5", "dalpha6"].contains(&name) && model != "registered" {
            assert_eq!(status, "held", "{model} {name}");
            let reason = reasons[row].as_deref().unwrap_or_default();
            assert!(
                reason.starts_with("near-dependent on "),
                "{model} {name}: {reason}"
            );
            assert_eq!(values[row], nominals[row], "{model} {name}");
        }
        if status != "identified" {
            continue;
        }
        let id = egcal::robot::ParamId::from_name(name).unwrap();
        let (value_bound, std_bound) = match id.unit() {
            _ if id.is_world() || id.is_tool_translation() => continue,
            "mm" => (10.0, 0.5),
            "deg" => (2.0, 0.05),
            _ => (f64::INFINITY, 0.01),
        };
        let deviation = values[row] - nominals[row];
        let std_error = std_errors.get(row).unwrap();
        assert!(deviation.abs() < value_bound, "{model} {name}: {deviation}");
        assert!(std_error < std_bound, "{model} {name}: ± {std_error}");
    }
    assert!(kinematic < 0.433 * 1.02, "kinematic {kinematic}");
    assert!(
        elastogeometric < 0.427 * 1.02,
        "elasto-geometric {elastogeometric}"
    );

    // The report answers "is my calibration good?" first, and does not compare
    // a UR10 with the IRB 1600 of the paper.
    let html = std::fs::read_to_string(out.join("report_c/report.html")).unwrap();
    let verdict = html
        .find("<section id=\"verdict\">")
        .expect("a verdict section");
    assert!(
        verdict < html.find("<nav>").unwrap(),
        "the verdict comes first"
    );
    assert!(html.contains("Model in service: <strong>elastogeometric</strong>"));
    // 1 mm on the largest of 1,387 validation errors (docs/real-cells.md: max 1.49 mm).
    assert!(
        html.contains("<span class=\"badge\">FAIL</span>"),
        "the verdict against 1 mm"
    );
    assert!(
        html.contains("<td class=\"num\">1387</td>"),
        "validation rows"
    );
    assert!(
        html.contains("held at nominal"),
        "held parameters are warnings"
    );
    // The page after its style sheet, without the setting's name in the provenance.
    let body = html[html.find("</style>").unwrap()..].replace("compare_with_paper = false", "");
    for paper in ["paper", "Table III", "IRB", "Fig. 7", "world-frame"] {
        assert!(
            !body.to_lowercase().contains(&paper.to_lowercase()),
            "the UR10 report mentions `{paper}`"
        );
    }
    assert!(html.contains("<li><strong>registered</strong>: the nominal robot with the world frame and the tool translation fitted"));
}

/// The UR10 series C folder, or `None` (with a SKIPPED line) without `../shared`.
fn series_c() -> Option<std::path::PathBuf> {
    let file =
        common::root().join("../shared/realdata/ur10-ipa/Series_C/measurements_random_poses.csv");
    if file.is_file() {
        Some(file)
    } else {
        eprintln!(
            "SKIPPED: the UR10 data are not at {}; the test needs ../shared beside the checkout",
            file.display()
        );
        None
    }
}

/// The first `rows` data rows of series C with the position columns (x, y, z:
/// fields 14, 16, 18) divided by `divisor`, as a tracker set to another unit
/// would export them; decimal commas kept.
fn series_c_scaled(source: &Path, rows: usize, divisor: f64) -> String {
    let text = std::fs::read_to_string(source).unwrap();
    let mut lines = text.lines();
    let mut out = format!("{}\n", lines.next().unwrap());
    for line in lines.take(rows) {
        let mut fields: Vec<String> = line.split(';').map(str::to_string).collect();
        for field in [14, 16, 18] {
            let value: f64 = fields[field].replace(',', ".").parse().unwrap();
            fields[field] = format!("{}", value / divisor).replace('.', ",");
        }
        out.push_str(&fields.join(";"));
        out.push('\n');
    }
    out
}

/// An import and an identification of `file`, with `joint_unit` as given.
fn import_job(dir: &Path, file: &Path, joint_unit: &str) -> std::path::PathBuf {
    let robot = common::root().join("jobs/robots/ur10.toml");
    let job = dir.join("job.toml");
    std::fs::write(
        &job,
        format!(
            r#"[job]
name = "units"
robot = "{robot}"

[[stages]]
id = "series_c"
kind = "import_measurements"
path = "{file}"
separator = ";"
decimal_comma = true
joint_unit = "{joint_unit}"

[stages.columns]
q1_deg = "shoulder_pan_joint"
q2_deg = "shoulder_lift_joint"
q3_deg = "elbow_joint"
q4_deg = "wrist_1_joint"
q5_deg = "wrist_2_joint"
q6_deg = "wrist_3_joint"
x_mm = "measurement_x"
y_mm = "measurement_y"
z_mm = "measurement_z"

[[stages]]
id = "identify"
kind = "identify"
inputs = {{ measurements = "series_c" }}
models = ["registered", "kinematic"]
max_iterations = 200
"#,
            robot = robot.display(),
            file = file.display(),
        ),
    )
    .unwrap();
    job
}

/// Issue #26, 1: an export in metres read as millimetres calibrated "perfectly"
/// by shrinking the arm 1000× (exit 0), and joints in radians read as degrees
/// gave 125 mm errors (exit 0). Both are refused at the import, naming the
/// file, the source columns, the setting and the likely unit.
#[test]
fn an_export_in_metres_or_joints_in_radians_read_as_mm_or_degrees_is_refused() {
    let Some(source) = series_c() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let metres = dir.path().join("series_c_metres.csv");
    std::fs::write(&metres, series_c_scaled(&source, 300, 1000.0)).unwrap();
    let job = import_job(dir.path(), &metres, "rad");
    let (code, stdout, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 2, "{stdout}\n{stderr}");
    for expected in [
        "series_c_metres.csv",
        "measurement_x",
        "metres read as millimetres",
        "length_unit = \"m\"",
    ] {
        assert!(stderr.contains(expected), "`{expected}` in:\n{stderr}");
    }

    let millimetres = dir.path().join("series_c.csv");
    std::fs::write(&millimetres, series_c_scaled(&source, 300, 1.0)).unwrap();
    let job = import_job(dir.path(), &millimetres, "deg");
    let (code, stdout, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 2, "{stdout}\n{stderr}");
    for expected in [
        "shoulder_pan_joint",
        "radians read as degrees",
        "joint_unit = \"rad\"",
    ] {
        assert!(stderr.contains(expected), "`{expected}` in:\n{stderr}");
    }

    // The same rows in their own units import and identify.
    let job = import_job(dir.path(), &millimetres, "rad");
    let (code, stdout, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 0, "{stdout}\n{stderr}");
}
