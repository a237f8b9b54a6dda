//! `import_measurements` end to end: the real UR10 export (Series C of
//! `../shared/realdata/ur10-ipa`, `;`-separated, decimal commas, joints in rad)
//! through `egcal stage`, checked against values read off the raw text by hand;
//! and a job whose export is edited between runs, which must re-run the stage.

mod common;

use std::path::{Path, PathBuf};

use polars::prelude::*;

/// The Series C settings as the guide shows them (docs/tracker-exports.md) (the path relative to the
/// folder egcal runs in: the repository root).
const SERIES_C: &str = r#"
path = "../shared/realdata/ur10-ipa/Series_C/measurements_random_poses.csv"
separator = ";"
decimal_comma = true
joint_unit = "rad"
constant = { robot_id = "ur10" }

[columns]
q1_deg = "shoulder_pan_joint"
q2_deg = "shoulder_lift_joint"
q3_deg = "elbow_joint"
q4_deg = "wrist_1_joint"
q5_deg = "wrist_2_joint"
q6_deg = "wrist_3_joint"
x_mm = "measurement_x"
y_mm = "measurement_y"
z_mm = "measurement_z"
sigma_x_mm = "measurement_std_x"
sigma_y_mm = "measurement_std_y"
sigma_z_mm = "measurement_std_z"
"#;

fn series_c() -> Option<PathBuf> {
    let file = common::root()
        .parent()
        .unwrap()
        .join("shared/realdata/ur10-ipa/Series_C/measurements_random_poses.csv");
    if file.exists() {
        Some(file)
    } else {
        eprintln!(
            "SKIPPED: {} is missing (the shared real-data folder is not beside the repository)",
            file.display()
        );
        None
    }
}

fn values(df: &DataFrame, name: &str) -> Vec<f64> {
    df.column(name)
        .unwrap()
        .f64()
        .unwrap()
        .into_no_null_iter()
        .collect()
}

#[test]
fn ur10_series_c_imports_every_row_with_joints_in_degrees() {
    let Some(file) = series_c() else {
        return;
    };
    // Data rows counted independently of polars: non-empty lines minus the header.
    let text = std::fs::read_to_string(&file).unwrap();
    let data_rows = text.lines().filter(|l| !l.trim().is_empty()).count() - 1;

    let dir = tempfile::tempdir().unwrap();
    let settings = dir.path().join("settings.toml");
    std::fs::write(&settings, SERIES_C).unwrap();
    let out = dir.path().join("out");
    let robot = common::root().join("jobs/robots/irb1600_145.toml");
    let (code, stdout, stderr) = common::run(
        &[
            "stage",
            "import_measurements",
            "--robot",
            robot.to_str().unwrap(),
            "--settings",
            settings.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ],
        &common::root(),
    );
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains(&format!("imported_rows = {data_rows}")),
        "{stdout}"
    );
    let df = egcal::table::read_parquet(&out.join("measurements.parquet")).unwrap();
    assert_eq!(df.height(), data_rows);
    assert_eq!(data_rows, 2773, "the guide's row count of Series C");

    // Row 0 of the file (line 2), as written:
    // shoulder_pan_joint … wrist_3_joint = -3,14159;-1,5708;0;-1,5708;0;0
    // measurement_x;_std_x;_y;_std_y;_z;_std_z =
    //   383,97123;0,041565;-3240,7562;0,022023;201,72621;0,0055848
    let first_line = text.lines().nth(1).unwrap();
    assert!(
        first_line.contains(";-3,14159;-1,5708;0;-1,5708;0;0;21,68000031;383,97123;0,041565;-3240,7562;0,022023;201,72621;0,0055848;"),
        "row 0 of the file is not the one this test was written for: {first_line}"
    );
    // By hand: -3.14159 rad · 180/π = -179.99984796050427°; -1.5708 rad = -90.00021045914971°.
    let q_deg = [
        -179.99984796050427,
        -90.00021045914971,
        0.0,
        -90.00021045914971,
        0.0,
        0.0,
    ];
    for (i, want) in q_deg.iter().enumerate() {
        let name = format!("q{}_deg", i + 1);
        let got = values(&df, &name)[0];
        assert!((got - want).abs() < 1e-9, "{name}: {got}, expected {want}");
    }
    // Positions and sigmas in mm, unchanged.
    for (name, want) in [
        ("x_mm", 383.97123),
        ("y_mm", -3240.7562),
        ("z_mm", 201.72621),
        ("sigma_x_mm", 0.041565),
        ("sigma_y_mm", 0.022023),
        ("sigma_z_mm", 0.0055848),
    ] {
        assert_eq!(values(&df, name)[0], want, "{name}");
    }
    // No load on the robot: the wrench is 0; cw_id is the data row number.
    assert!(values(&df, "fz_n").iter().all(|v| *v == 0.0));
    let ids: Vec<i64> = df
        .column("cw_id")
        .unwrap()
        .i64()
        .unwrap()
        .into_no_null_iter()
        .collect();
    assert_eq!(ids, (0..data_rows as i64).collect::<Vec<_>>());
    assert!(values(&df, "sigma_z_mm").iter().all(|s| *s > 0.0));
    egcal::table::schema::measurements()
        .check(&df, Path::new("measurements.parquet"))
        .unwrap();
}

fn ran_or_cached(stderr: &str) -> &'static str {
    if stderr.contains("tracker: running import_measurements") {
        "ran"
    } else if stderr.contains("tracker: cached") {
        "cached"
    } else {
        "neither"
    }
}

#[test]
fn an_edited_export_reruns_the_stage_and_an_unchanged_one_does_not() {
    let dir = tempfile::tempdir().unwrap();
    let job = dir.path().join("job.toml");
    std::fs::write(
        &job,
        format!(
            r#"[job]
name = "import"
robot = "{robot}"
output = "out"

[[stages]]
id = "tracker"
kind = "import_measurements"
path = "exports/points.csv"
separator = ";"
decimal_comma = true
length_unit = "m"

[stages.columns]
q1_deg = "j1"
q2_deg = "j2"
q3_deg = "j3"
q4_deg = "j4"
q5_deg = "j5"
q6_deg = "j6"
x_mm = "x"
y_mm = "y"
z_mm = "z"
"#,
            robot = common::root()
                .join("jobs/robots/irb1600_145.toml")
                .display()
        ),
    )
    .unwrap();
    std::fs::create_dir(dir.path().join("exports")).unwrap();
    let export = dir.path().join("exports/points.csv");
    let header = "j1;j2;j3;j4;j5;j6;x;y;z\n";
    std::fs::write(&export, format!("{header}1;2;3;4;5;6;1,5;0;0\n")).unwrap();
    let run = || common::run(&["run", job.to_str().unwrap()], dir.path());
    let table = dir.path().join("out/tracker/measurements.parquet");

    let (code, _, stderr) = run();
    assert_eq!(code, 0, "{stderr}");
    assert_eq!(ran_or_cached(&stderr), "ran", "{stderr}");
    let df = egcal::table::read_parquet(&table).unwrap();
    assert_eq!(values(&df, "x_mm"), [1500.0]);

    let (code, _, stderr) = run();
    assert_eq!(code, 0, "{stderr}");
    assert_eq!(ran_or_cached(&stderr), "cached", "{stderr}");

    // Same settings, new content: the file's hash is in the cache key.
    std::fs::write(
        &export,
        format!("{header}1;2;3;4;5;6;1,5;0;0\n1;2;3;4;5;6;2,5;0;0\n"),
    )
    .unwrap();
    let (code, _, stderr) = run();
    assert_eq!(code, 0, "{stderr}");
    assert_eq!(ran_or_cached(&stderr), "ran", "{stderr}");
    let df = egcal::table::read_parquet(&table).unwrap();
    assert_eq!(values(&df, "x_mm"), [1500.0, 2500.0]);

    // A bad cell is bad input (exit 2), named by file, line and column.
    std::fs::write(
        &export,
        format!("{header}1;2;3;4;5;6;1,5;0;0\n1;2;x3;4;5;6;2,5;0;0\n"),
    )
    .unwrap();
    let (code, _, stderr) = run();
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains(
            "points.csv: line 3, column `j3` (setting `columns.q3_deg`): `x3` is not a number"
        ),
        "{stderr}"
    );
}

/// The guide's import example (`docs/tracker-exports.md`), run as written (issue #26: followed
/// literally, it once gave a fit that had not converged, with exit 0): every
/// model converges, dtheta5 and dalpha6 are held with their reason, and the
/// validation error is the guide's.
#[test]
fn the_guide_s_import_example_calibrates_as_it_says() {
    if series_c().is_none() {
        return;
    }
    let root = common::root();
    let section = std::fs::read_to_string(root.join("docs/tracker-exports.md")).unwrap();
    let start = section.find("```toml\n").unwrap() + "```toml\n".len();
    let block = &section[start..start + section[start..].find("```").unwrap()];
    let jobs = root.join("jobs");
    let text = block
        .replace("\"robots/", &format!("\"{}/robots/", jobs.display()))
        .replace(
            "\"../../shared/",
            &format!("\"{}/../../shared/", jobs.display()),
        );
    let dir = tempfile::tempdir().unwrap();
    let job = dir.path().join("example.toml");
    std::fs::write(&job, text).unwrap();
    let (code, stdout, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 0, "{stdout}\n{stderr}");
    let out = dir.path().join("out/ur10_c_example");
    let parameters = out.join("identify/parameters.parquet");
    let df = egcal::table::read_parquet(&parameters).unwrap();
    let text = |c: &str| egcal::table::schema::str_values(&df, c, &parameters).unwrap();
    let held: Vec<String> = text("name")
        .into_iter()
        .zip(text("status"))
        .zip(text("model"))
        .filter(|((_, s), m)| {
            s.as_deref() == Some("held") && m.as_deref() == Some("elastogeometric")
        })
        .map(|((n, _), _)| n.unwrap_or_default())
        .collect();
    assert_eq!(held, vec!["dtheta5", "dalpha6"]);
    let stats = out.join("validate/stats.parquet");
    let df = egcal::table::read_parquet(&stats).unwrap();
    let models = egcal::table::schema::str_values(&df, "model", &stats).unwrap();
    let means = egcal::table::schema::f64_values(&df, "mean_mm", &stats).unwrap();
    let row = models
        .iter()
        .position(|m| m.as_deref() == Some("elastogeometric"))
        .unwrap();
    assert!((means[row] - 0.427).abs() < 0.0005, "{}", means[row]);
}

/// `clean` as tracker software writes it: a UTF-8 byte-order mark, CRLF line
/// ends, `units` as a row under the header, and blank lines and a row of bare
/// separators at the end.
fn as_tracker_writes(clean: &str, units: &str, separator: char) -> String {
    let mut lines = clean.lines();
    let mut out = String::from("\u{FEFF}");
    out.push_str(lines.next().unwrap());
    out.push_str("\r\n");
    out.push_str(units);
    out.push_str("\r\n");
    for line in lines {
        out.push_str(line);
        out.push_str("\r\n");
    }
    let width = clean.lines().next().unwrap().split(separator).count();
    out.push_str("\r\n");
    out.push_str(&separator.to_string().repeat(width - 1));
    out.push_str("\r\n\r\n");
    out
}

/// The six revolute joints the exports here carry.
fn irb1600() -> egcal::robot::RobotSpec {
    egcal::robot::RobotSpec::load(&common::root().join("jobs/robots/irb1600_145.toml")).unwrap()
}

/// Imports `text` written as `name` in `dir` with `settings` (TOML, without `path`).
fn import_text(dir: &Path, name: &str, text: &str, settings: &str) -> DataFrame {
    std::fs::write(dir.join(name), text).unwrap();
    let settings: egcal::stages::import_measurements::ImportMeasurementsSettings =
        toml::from_str(&format!("path = \"{name}\"\n{settings}")).unwrap();
    egcal::stages::import_measurements::import_for(&irb1600(), &settings, dir)
        .unwrap_or_else(|e| panic!("{name}: {e}"))
        .measurements
}

/// A byte-order mark, CRLF line ends, a units row and blank trailing lines are
/// what tracker software writes: the export imports to the very values of the
/// clean file, row for row.
#[test]
fn a_tracker_written_export_imports_as_the_clean_file() {
    let dir = tempfile::tempdir().unwrap();
    let clean = "id,A1,A2,A3,A4,A5,A6,X [mm],Y [mm],Z [mm],sigma\n\
                 1,0,10,20,0,30,0,1000.5,-20.25,1200,0.01\n\
                 2,5,15,25,-5,35,90,1010.5,-30.25,1190,0.02\n\
                 3,-5,5,15,5,25,-90,990.125,-10.5,1210.75,0.015\n";
    let units = ",[deg],[deg],[deg],[deg],[deg],[deg],mm,mm,mm,mm";
    let settings = r#"
[columns]
cw_id = "id"
q1_deg = "A1"
q2_deg = "A2"
q3_deg = "A3"
q4_deg = "A4"
q5_deg = "A5"
q6_deg = "A6"
x_mm = "X [mm]"
y_mm = "Y [mm]"
z_mm = "Z [mm]"
sigma_x_mm = "sigma"
sigma_y_mm = "sigma"
sigma_z_mm = "sigma"
"#;
    let want = import_text(dir.path(), "clean.csv", clean, settings);
    assert_eq!(want.height(), 3);
    let messy = as_tracker_writes(clean, units, ',');
    assert!(messy.ends_with(",,,,,,,,,,\r\n\r\n"), "{messy:?}");
    let got = import_text(dir.path(), "messy.csv", &messy, settings);
    assert!(got.equals(&want), "{got}\nvs the clean file's\n{want}");
    assert_eq!(values(&got, "x_mm"), [1000.5, 1010.5, 990.125]);

    // The same in the European layout of the UR10 export (`;`, decimal commas).
    let Some(file) = series_c() else {
        return;
    };
    let text = std::fs::read_to_string(&file).unwrap();
    let head: Vec<&str> = text.lines().take(41).collect();
    let clean = head.join("\n") + "\n";
    let header: Vec<&str> = head[0].split(';').collect();
    let units: Vec<&str> = header
        .iter()
        .map(|name| {
            if name.ends_with("_joint") {
                "[rad]"
            } else if name.starts_with("measurement_x")
                || name.starts_with("measurement_y")
                || name.starts_with("measurement_z")
                || name.starts_with("measurement_std_x")
                || name.starts_with("measurement_std_y")
                || name.starts_with("measurement_std_z")
            {
                "[mm]"
            } else {
                ""
            }
        })
        .collect();
    let series_c_settings = SERIES_C
        .lines()
        .filter(|l| !l.starts_with("path ="))
        .collect::<Vec<_>>()
        .join("\n");
    let want = import_text(dir.path(), "c_clean.csv", &clean, &series_c_settings);
    assert_eq!(want.height(), 40);
    let messy = as_tracker_writes(&clean, &units.join(";"), ';');
    let got = import_text(dir.path(), "c_messy.csv", &messy, &series_c_settings);
    assert!(got.equals(&want), "{got}\nvs the clean file's\n{want}");
}

/// A units row that contradicts the unit settings is refused, naming the line,
/// the column and the setting to change.
#[test]
fn a_units_row_that_contradicts_the_settings_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("e.csv"),
        "a1,a2,a3,a4,a5,a6,x,y,z\ndeg,deg,deg,deg,deg,deg,m,m,m\n0,0,0,0,30,0,1,0,1\n",
    )
    .unwrap();
    let settings: egcal::stages::import_measurements::ImportMeasurementsSettings =
        toml::from_str(
            r#"path = "e.csv"
columns = { q1_deg = "a1", q2_deg = "a2", q3_deg = "a3", q4_deg = "a4", q5_deg = "a5", q6_deg = "a6", x_mm = "x", y_mm = "y", z_mm = "z" }"#,
        )
        .unwrap();
    let message = egcal::stages::import_measurements::import_for(&irb1600(), &settings, dir.path())
        .unwrap_err()
        .to_string();
    for word in [
        "e.csv",
        "line 2",
        "units row",
        "`m`",
        "column `x`",
        "length_unit = \"m\"",
    ] {
        assert!(message.contains(word), "{word}: {message}");
    }
}
