//! A robot on a linear track (issue #30): the IRB 1600 on a 3 m track whose
//! rail bows by 0.5 mm and whose carriage pitches and yaws by 0.02° along
//! the travel. The joint calibration recovers the track's errors within two
//! standard errors and validates on held-out rows like the arm alone; the
//! same rows fitted with the track taken as perfect are several times
//! worse. Through `egcal stage identify`: the `e1_mm` column is read, the
//! parameters table names the track's terms, and a table without positions
//! (or with positions for a robot without a track, or beyond the travel) is
//! refused naming the column.

mod common;

use std::path::{Path, PathBuf};

use egcal::calibration::fit::{FitOptions, Observations};
use egcal::calibration::{CalibrationOptions, calibrate};
use egcal::robot::{ConfWrench, ParamId, ParamValues, Robot, RobotSpec, Wrench};
use egcal::table::parameters::{ModelName, ParamStatus};
use nalgebra::Vector3;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use common::measured::{noisy, positions, write_measurements};

/// The IRB 1600 robot file with a 3 m track, polynomials to order `order`.
fn track_robot_file(dir: &Path, order: usize) -> PathBuf {
    let text =
        std::fs::read_to_string(common::root().join("jobs/robots/irb1600_145.toml")).unwrap();
    let path = dir.join("irb1600_on_track.toml");
    std::fs::write(
        &path,
        format!("{text}\n[track]\ntravel_mm = [0.0, 3000.0]\npolynomial_order = {order}\n"),
    )
    .unwrap();
    path
}

/// The spec's truth for the arm, and the track's errors: a scale error,
/// a misaligned rail bowing 0.5 mm sideways and 0.3 mm up at mid-travel, a
/// carriage pitching and yawing by 0.02° and rolling by 0.01°.
fn truth(spec: &RobotSpec) -> ParamValues {
    let mut truth =
        ParamValues::load_overrides(spec, &common::root().join("jobs/truth/irb1600_paper.toml"))
            .unwrap();
    for (name, value) in [
        ("track_scale", 0.4),
        ("track_y1", 0.3 + 2.0),
        ("track_y2", -2.0),
        ("track_z1", 1.2),
        ("track_z2", -1.2),
        ("track_roll1", 0.01),
        ("track_pitch1", 0.08),
        ("track_pitch2", -0.08),
        ("track_yaw1", 0.02),
        ("track_yaw2", -0.04),
    ] {
        truth.set(ParamId::from_name(name).unwrap(), value);
    }
    truth
}

/// Random rows within the joint limits and the travel, wrenches within the
/// paper's ±120 N, ±10 N·m.
fn rows_on_track(robot: &Robot, seed: u64, n: usize) -> Vec<ConfWrench> {
    let mut rng = StdRng::seed_from_u64(seed);
    (0..n)
        .map(|_| ConfWrench {
            track_mm: rng.random_range(0.0..3000.0),
            positioner_deg: None,
            ..ConfWrench::new(
                robot.joint_vector(|i| {
                    let [lo, hi] = robot.joint_limits(i);
                    rng.random_range(lo..hi)
                }),
                Wrench::from_array(std::array::from_fn(|i| {
                    let bound = if i < 3 { 120.0 } else { 10.0 };
                    rng.random_range(-bound..bound)
                })),
            )
        })
        .collect()
}

fn mean_error_mm(
    robot: &Robot,
    p: &ParamValues,
    rows: &[ConfWrench],
    measured: &[Vector3<f64>],
) -> f64 {
    positions(robot, p, rows)
        .iter()
        .zip(measured)
        .map(|(a, b)| (a - b).norm())
        .sum::<f64>()
        / rows.len() as f64
}

#[test]
fn the_track_s_errors_are_recovered_and_ignoring_them_is_several_times_worse() {
    let dir = tempfile::tempdir().unwrap();
    let spec = RobotSpec::load(&track_robot_file(dir.path(), 2)).unwrap();
    let robot = Robot::new(spec.clone());
    let truth = truth(&spec);
    // The bow at mid-travel: y(0.5) = 0.3·0.5 + 2·0.5 − 2·0.25 = 0.65 mm, of
    // which 0.5 mm off the straight line between the ends.
    let sigma_mm = 0.02;
    let rows = rows_on_track(&robot, 1, 300);
    let measured = noisy(&positions(&robot, &truth, &rows), sigma_mm, 2);
    let held_out = rows_on_track(&robot, 3, 200);
    let held_out_measured = noisy(&positions(&robot, &truth, &held_out), sigma_mm, 4);

    let options = |fixed: Vec<(ParamId, f64)>| CalibrationOptions {
        robust: None,
        fixed,
        ..CalibrationOptions::new(ParamId::all().collect(), FitOptions::default())
    };
    let fit = |fixed| {
        calibrate(
            &robot,
            ModelName::Elastogeometric,
            &Observations::new(&rows, &measured),
            &ParamValues::nominal(robot.spec()),
            &options(fixed),
        )
        .unwrap()
    };
    let joint = fit(Vec::new());
    assert!(joint.converged, "{:?}", joint.trace);
    let track_terms: Vec<ParamId> = ParamId::track_terms(2).collect();
    assert_eq!(track_terms.len(), 11);
    let mut z = Vec::new();
    // The rail's linear sideways misalignment is the only dependent term:
    // with joint 1's axis normal to the rail, turning the rail in the
    // horizontal plane is the world frame's yaw plus joint 1's offset, which
    // the fit takes instead (the predictions are the same).
    let y1 = ParamId::from_name("track_y1").unwrap();
    for id in &track_terms {
        let expected = if *id == y1 {
            ParamStatus::Dependent
        } else {
            ParamStatus::Identified
        };
        assert_eq!(joint.set.status[id.index()], expected, "{id}");
    }
    for id in track_terms.iter().filter(|id| **id != y1) {
        let se = joint.set.std_errors[id.index()].unwrap();
        z.push((*id, (joint.set.values.get(*id) - truth.get(*id)) / se));
        eprintln!(
            "{id}: {:.4} (truth {}, SE {se:.4})",
            joint.set.values.get(*id),
            truth.get(*id)
        );
    }
    // Within two standard errors, but for about one term in twenty.
    let beyond_two = z.iter().filter(|(_, z)| z.abs() > 2.0).count();
    assert!(z.iter().all(|(_, z)| z.abs() < 3.0), "{z:?}");
    assert!(beyond_two <= 1, "{z:?}");

    let arm_only = fit(track_terms.iter().map(|id| (*id, 0.0)).collect());
    let joint_mm = mean_error_mm(&robot, &joint.set.values, &held_out, &held_out_measured);
    let arm_only_mm = mean_error_mm(&robot, &arm_only.set.values, &held_out, &held_out_measured);
    // The same arm without a track, the same rows' joints and noise.
    let fixed_rows: Vec<ConfWrench> = rows
        .iter()
        .map(|r| ConfWrench {
            track_mm: 0.0,
            positioner_deg: None,
            ..*r
        })
        .collect();
    let plain =
        Robot::new(RobotSpec::load(&common::root().join("jobs/robots/irb1600_145.toml")).unwrap());
    let plain_truth = ParamValues::load_overrides(
        plain.spec(),
        &common::root().join("jobs/truth/irb1600_paper.toml"),
    )
    .unwrap();
    let plain_measured = noisy(&positions(&plain, &plain_truth, &fixed_rows), sigma_mm, 2);
    let plain_fit = calibrate(
        &plain,
        ModelName::Elastogeometric,
        &Observations::new(&fixed_rows, &plain_measured),
        &ParamValues::nominal(plain.spec()),
        &options(Vec::new()),
    )
    .unwrap();
    let plain_held_out: Vec<ConfWrench> = held_out
        .iter()
        .map(|r| ConfWrench {
            track_mm: 0.0,
            positioner_deg: None,
            ..*r
        })
        .collect();
    let plain_held_out_measured = noisy(
        &positions(&plain, &plain_truth, &plain_held_out),
        sigma_mm,
        4,
    );
    let plain_mm = mean_error_mm(
        &plain,
        &plain_fit.set.values,
        &plain_held_out,
        &plain_held_out_measured,
    );
    eprintln!(
        "held-out mean: jointly calibrated cell {joint_mm:.4} mm, arm alone {plain_mm:.4} mm, track taken as perfect {arm_only_mm:.4} mm"
    );
    assert!(
        joint_mm <= 1.5 * plain_mm,
        "{joint_mm} vs arm alone {plain_mm}"
    );
    assert!(arm_only_mm >= 3.0 * joint_mm, "{arm_only_mm} vs {joint_mm}");
}

/// Runs `egcal stage identify` on `rows` measured with `truth`.
fn identify_stage(
    dir: &Path,
    robot_file: &Path,
    rows: &[ConfWrench],
    measured: &[Vector3<f64>],
) -> (i32, String, PathBuf) {
    let input = dir.join("measurements.parquet");
    write_measurements(&input, rows, measured, 1);
    let settings = dir.join("settings.toml");
    std::fs::write(&settings, "models = [\"elastogeometric\"]\n").unwrap();
    let out = dir.join("out");
    let (code, stdout, stderr) = common::run(
        &[
            "stage",
            "identify",
            "--robot",
            robot_file.to_str().unwrap(),
            "--settings",
            settings.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--input",
            &format!("measurements={}", input.display()),
        ],
        dir,
    );
    (code, format!("{stdout}{stderr}"), out)
}

#[test]
fn the_stage_reads_track_positions_and_refuses_tables_without_them() {
    let dir = tempfile::tempdir().unwrap();
    let file = track_robot_file(dir.path(), 1);
    let spec = RobotSpec::load(&file).unwrap();
    let robot = Robot::new(spec.clone());
    let truth = truth(&spec);
    let rows = rows_on_track(&robot, 5, 120);
    let measured = noisy(&positions(&robot, &truth, &rows), 0.02, 6);
    let (code, log, out) = identify_stage(dir.path(), &file, &rows, &measured);
    assert_eq!(code, 0, "{log}");
    let parameters = egcal::table::read_parquet(&out.join("parameters.parquet")).unwrap();
    let names = egcal::table::schema::str_values(&parameters, "name", Path::new("p")).unwrap();
    for name in [
        "track_scale",
        "track_y1",
        "track_z1",
        "track_roll1",
        "track_pitch1",
        "track_yaw1",
    ] {
        assert!(
            names.iter().any(|n| n.as_deref() == Some(name)),
            "{name} in {names:?}"
        );
    }
    assert!(
        !names.iter().any(|n| n.as_deref() == Some("track_y2")),
        "order 1 only: {names:?}"
    );

    // The rows without their positions: refused, naming the column.
    let flat: Vec<ConfWrench> = rows
        .iter()
        .map(|r| ConfWrench {
            track_mm: 0.0,
            positioner_deg: None,
            ..*r
        })
        .collect();
    let (code, log, _) = identify_stage(dir.path(), &file, &flat, &measured);
    assert_eq!(code, 2, "{log}");
    assert!(log.contains("e1_mm") && log.contains("[track]"), "{log}");
    // Positions for a robot without a track.
    let plain = common::root().join("jobs/robots/irb1600_145.toml");
    let (code, log, _) = identify_stage(dir.path(), &plain, &rows, &measured);
    assert_eq!(code, 2, "{log}");
    assert!(
        log.contains("e1_mm") && log.contains("has no [track]"),
        "{log}"
    );
    // A position beyond the travel.
    let mut beyond = rows.clone();
    beyond[7].track_mm = 3200.0;
    let (code, log, _) = identify_stage(dir.path(), &file, &beyond, &measured);
    assert_eq!(code, 2, "{log}");
    assert!(log.contains("row 7") && log.contains("travel"), "{log}");
}

/// The nominal IRB 1600 with the track's errors of [`truth`] against the
/// independent chain of `fixtures/tools/track_fk.py` (its output pasted).
#[test]
fn forward_kinematics_on_the_track_matches_an_independent_numpy_chain() {
    let dir = tempfile::tempdir().unwrap();
    let spec = RobotSpec::load(&track_robot_file(dir.path(), 2)).unwrap();
    let robot = Robot::new(spec.clone());
    let truth = truth(&spec);
    let mut values = ParamValues::nominal(&spec);
    for id in ParamId::track_terms(2) {
        values.set(id, truth.get(id));
    }
    #[rustfmt::skip]
    let cases: [([f64; 6], f64, [f64; 3]); 4] = [
        ([0.0, 0.0, 0.0, 0.0, 0.0, 0.0], 0.0, [2291.000000000, -1412.000000000, 311.500000000]),
        ([10.0, 20.0, -30.0, 40.0, 50.0, 60.0], 1500.0, [3942.140931120, -1687.457325538, 279.993057545]),
        ([-35.0, -40.0, 25.0, -120.0, 70.0, 200.0], 2950.0, [4450.788844730, -1060.846900353, 135.530066988]),
        ([120.0, 60.0, -170.0, 10.0, -90.0, -45.0], 700.0, [1876.171593869, -1658.282099542, 101.171951067]),
    ];
    for (q, e, expected) in cases {
        let row = ConfWrench {
            track_mm: e,
            positioner_deg: None,
            ..ConfWrench::new(egcal::robot::joint_array(&q), Wrench::zero())
        };
        let got = robot.prepare(&values).predict_row(&row).position_mm;
        assert!(
            (got - Vector3::from(expected)).norm() < 1e-6,
            "q {q:?} e {e}: {got:?} vs {expected:?}"
        );
    }
}

/// A stage that would place the arm as if the carriage stood at 0 refuses a
/// robot on a track, naming the robot file and the kinds that handle one.
#[test]
fn stages_that_do_not_handle_a_track_refuse_it() {
    let dir = tempfile::tempdir().unwrap();
    let file = track_robot_file(dir.path(), 1);
    let settings = dir.path().join("settings.toml");
    std::fs::write(&settings, "").unwrap();
    let (code, stdout, stderr) = common::run(
        &[
            "stage",
            "nest_poses",
            "--robot",
            file.to_str().unwrap(),
            "--settings",
            settings.to_str().unwrap(),
            "--out",
            dir.path().join("out").to_str().unwrap(),
        ],
        dir.path(),
    );
    let log = format!("{stdout}{stderr}");
    assert_eq!(code, 2, "{log}");
    assert!(
        log.contains("[track]")
            && log.contains("`nest_poses` does not handle")
            && log.contains("identify"),
        "{log}"
    );
}

/// The ISO 9283 cube on a track runs at one carriage position: `iso_cube`
/// needs it (`track_mm`, within the travel) and writes it as every
/// target's `e1_mm`, which `compensate` solves at; a robot without a track
/// refuses the setting.
#[test]
fn the_iso_cube_on_a_track_runs_at_one_carriage_position() {
    let dir = tempfile::tempdir().unwrap();
    let on_track = track_robot_file(dir.path(), 1);
    let stage = |kind: &str, robot: &Path, settings: &str, inputs: &[String]| {
        let path = dir.path().join(format!("{kind}.toml"));
        std::fs::write(&path, settings).unwrap();
        let out = dir.path().join(format!("out_{kind}"));
        let mut args = vec![
            "stage".to_string(),
            kind.into(),
            "--robot".into(),
            robot.to_str().unwrap().into(),
            "--settings".into(),
            path.to_str().unwrap().into(),
            "--out".into(),
            out.to_str().unwrap().into(),
        ];
        for input in inputs {
            args.push("--input".into());
            args.push(input.clone());
        }
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let (code, stdout, stderr) = common::run(&args, dir.path());
        (code, format!("{stdout}{stderr}"), out)
    };
    let (code, log, _) = stage("iso_cube", &on_track, "", &[]);
    assert_eq!(code, 2, "{log}");
    assert!(log.contains("track_mm") && log.contains("e1_mm"), "{log}");
    let (code, log, _) = stage("iso_cube", &on_track, "track_mm = 3500.0\n", &[]);
    assert_eq!(code, 2, "{log}");
    assert!(log.contains("outside the track's travel"), "{log}");
    let arm_only = common::root().join("jobs/robots/irb1600_145.toml");
    let (code, log, _) = stage("iso_cube", &arm_only, "track_mm = 1500.0\n", &[]);
    assert_eq!(code, 2, "{log}");
    assert!(log.contains("has no [track]"), "{log}");

    let cube = "track_mm = 1500.0\ncentre_mm = [900.0, 0.0, 900.0]\nedge_mm = 300.0\ntool_orientation_deg = [180.0, 0.0, 0.0]\ncycles = 2\n";
    let (code, log, out) = stage("iso_cube", &on_track, cube, &[]);
    assert_eq!(code, 0, "{log}");
    let targets = out.join("targets.parquet");
    let df = egcal::table::read_parquet(&targets).unwrap();
    let e1 = egcal::table::schema::f64_values(&df, "e1_mm", &targets).unwrap();
    assert_eq!(e1, vec![1500.0; 10]);
    let (code, log, out) = stage(
        "compensate",
        &on_track,
        "model = \"nominal\"\n",
        &[format!("targets={}", targets.display())],
    );
    assert_eq!(code, 0, "{log}");
    let commands = out.join("commands.parquet");
    let df = egcal::table::read_parquet(&commands).unwrap();
    let e1 = egcal::table::schema::f64_values(&df, "e1_mm", &commands).unwrap();
    let status = egcal::table::schema::str_values(&df, "status", &commands).unwrap();
    assert_eq!(e1, vec![1500.0; 10]);
    assert!(
        status.iter().all(|s| s.as_deref() == Some("ok")),
        "{status:?}"
    );
}

/// A robot on a track through the nightly path: `simulate_logs` moves the
/// carriage to each pool row's `e1_mm` and logs the position read back,
/// `scan_logs` keeps the column (and refuses, with `bad_data = "fail"`, logs
/// without it), and `identify` calibrates the track from the scanned rows.
#[test]
fn the_logs_of_a_robot_on_a_track_carry_the_carriage() {
    let dir = tempfile::tempdir().unwrap();
    let file = track_robot_file(dir.path(), 2);
    let spec = RobotSpec::load(&file).unwrap();
    let robot = Robot::new(spec.clone());
    let pool_rows = rows_on_track(&robot, 61, 150);
    let pool = dir.path().join("pool.parquet");
    write_measurements(
        &pool,
        &pool_rows,
        &vec![Vector3::zeros(); pool_rows.len()],
        1,
    );
    let set =
        egcal::table::parameters::ParameterSet::fixed(ModelName::Elastogeometric, truth(&spec));
    let mut truth_table = egcal::table::parameters::to_frame(&spec, &[set]);
    let truth_path = dir.path().join("truth.parquet");
    egcal::table::write_parquet(&mut truth_table, &truth_path, None).unwrap();

    let (code, log, logs) = common::stage(
        dir.path(),
        &file,
        "simulate_logs",
        "robot_id = \"t1\"\nfirst_day = \"2026-11-02\"\ndays = 3\nrows_per_day = 120\n",
        &[("conf_wrenches", &pool), ("truth", &truth_path)],
    );
    assert_eq!(code, 0, "{log}");
    let commissioning_path = logs.join("commissioning.parquet");
    let commissioning = egcal::table::read_parquet(&commissioning_path).unwrap();
    let logged =
        egcal::table::schema::f64_values(&commissioning, "e1_mm", &commissioning_path).unwrap();
    for (row, e) in pool_rows.iter().zip(&logged) {
        assert!(
            (row.track_mm - e).abs() < 1e-9,
            "{} logged as {e}",
            row.track_mm
        );
    }

    let scan_settings = format!(
        "logs = \"{}\"\nrobot_id = \"t1\"\nfrom = \"2026-11-02\"\nto = \"2026-11-04\"\nholdout_days = 1\nbad_data = \"fail\"\n",
        logs.display()
    );
    let (code, log, scanned) = common::stage(dir.path(), &file, "scan_logs", &scan_settings, &[]);
    assert_eq!(code, 0, "{log}");
    let measurements = scanned.join("measurements.parquet");
    let table = egcal::table::read_parquet(&measurements).unwrap();
    assert_eq!(table.height(), 360);
    let positions = egcal::table::schema::f64_values(&table, "e1_mm", &measurements).unwrap();
    assert!(positions.iter().all(|e| (0.0..=3000.0).contains(e)));
    assert!(
        table.column("target_id").is_err(),
        "no empty optional column"
    );

    let (code, log, identified) = common::stage(
        dir.path(),
        &file,
        "identify",
        "models = [\"elastogeometric\"]\n",
        &[("measurements", &measurements)],
    );
    assert_eq!(code, 0, "{log}");
    let parameters = identified.join("parameters.parquet");
    let fit = egcal::table::parameters::from_frame(
        &egcal::table::read_parquet(&parameters).unwrap(),
        &parameters,
        &spec,
    )
    .unwrap()
    .remove(0);
    let id = ParamId::from_name("track_scale").unwrap();
    let se = fit.std_errors[id.index()].expect("track_scale identified");
    eprintln!(
        "track_scale from the scanned logs: {:.4} ± {se:.4} mm (truth 0.4)",
        fit.values.get(id)
    );
    assert!((fit.values.get(id) - 0.4).abs() < 3.0 * se);

    // The same logs for the arm without its track: the logged day files
    // hold e1_mm, which the scan keeps and identify refuses, naming it.
    let plain = common::root().join("jobs/robots/irb1600_145.toml");
    let (code, log, scanned) = common::stage(dir.path(), &plain, "scan_logs", &scan_settings, &[]);
    assert_eq!(code, 0, "{log}");
    let (code, log, _) = common::stage(
        dir.path(),
        &plain,
        "identify",
        "",
        &[("measurements", &scanned.join("measurements.parquet"))],
    );
    assert_ne!(code, 0, "{log}");
    assert!(log.contains("e1_mm") && log.contains("no [track]"), "{log}");

    // Logs without the carriage column, scanned for the robot on the track:
    // every row is bad, and the scan says why.
    let plain_dir = dir.path().join("plain");
    std::fs::create_dir(&plain_dir).unwrap();
    let (code, log, plain_logs) = common::stage(
        &plain_dir,
        &plain,
        "simulate_logs",
        "robot_id = \"t1\"\nfirst_day = \"2026-11-02\"\ndays = 1\nrows_per_day = 10\n",
        &[(
            "conf_wrenches",
            &common::root().join("fixtures/predict/nominal/conf_wrenches.parquet"),
        )],
    );
    assert_eq!(code, 0, "{log}");
    let settings = format!(
        "logs = \"{}\"\nrobot_id = \"t1\"\nfrom = \"2026-11-02\"\nto = \"2026-11-02\"\nholdout_days = 0\nbad_data = \"fail\"\n",
        plain_logs.display()
    );
    let (code, log, _) = common::stage(&plain_dir, &file, "scan_logs", &settings, &[]);
    assert_ne!(code, 0, "{log}");
    assert!(log.contains("null e1_mm"), "{log}");
}
