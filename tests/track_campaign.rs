//! A robot on a linear track, through the whole campaign (issue #30):
//! `jobs/track_sim.toml` designs poses at carriage stations, measures them
//! on the simulator moving the carriage, and calibrates arm and track
//! together. The jointly calibrated cell validates like the arm alone
//! (`jobs/paper_sim.toml`), the same rows with the track taken as perfect
//! are several times worse, and the track's errors are recovered. An
//! external driver moves and reads the carriage as the in-process
//! simulator does; one that cannot is refused before a row is measured.

mod common;

use std::collections::{BTreeSet, HashMap};
use std::path::Path;

use egcal::table::{self, schema};
use polars::prelude::DataFrame;

use common::tables::{f64s, i64s, read, strings};

/// A model's value of a `stats` column in a validate stage's output.
fn stat(out: &Path, stage: &str, model: &str, column: &str) -> f64 {
    let stats = read(&out.join(stage).join("stats.parquet"));
    let k = strings(&stats, "model")
        .iter()
        .position(|m| m == model)
        .unwrap_or_else(|| panic!("{stage}: no {model}"));
    f64s(&stats, column)[k]
}

#[test]
fn the_track_campaign_designs_measures_and_calibrates_the_cell() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["paper_sim", "track_sim"] {
        let job = common::shipped_job_in(dir.path(), name, |text| text);
        let (code, stdout, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
        assert_eq!(code, 0, "{name}: {stdout}\n{stderr}");
    }
    let out = dir.path().join("out/track_sim");

    // Poses: the box at 5 stations spread evenly over the 3 m travel.
    let poses = read(&out.join("poses/poses.parquet"));
    let stations: BTreeSet<i64> = f64s(&poses, "e1_mm").iter().map(|e| *e as i64).collect();
    assert_eq!(
        stations,
        BTreeSet::from([0, 750, 1500, 2250, 3000]),
        "stations"
    );
    let station_of: HashMap<i64, f64> = i64s(&poses, "config_id")
        .into_iter()
        .zip(f64s(&poses, "e1_mm"))
        .collect();
    assert_eq!(station_of.len(), poses.height(), "config ids are unique");

    // Each wrench keeps its configuration's station, and the rig measured
    // each row with the carriage where the row asked.
    let candidates = read(&out.join("wrenches/candidates.parquet"));
    let commanded: HashMap<i64, f64> = i64s(&candidates, "cw_id")
        .into_iter()
        .zip(f64s(&candidates, "e1_mm"))
        .collect();
    for (config, e) in i64s(&candidates, "config_id")
        .iter()
        .zip(f64s(&candidates, "e1_mm"))
    {
        assert_eq!(station_of[config], e, "config_id {config}");
    }
    let measurements = read(&out.join("measure/measurements.parquet"));
    assert_eq!(measurements.height(), candidates.height());
    for (cw, e) in i64s(&measurements, "cw_id")
        .iter()
        .zip(f64s(&measurements, "e1_mm"))
    {
        assert_eq!(commanded[cw], e, "cw_id {cw}");
    }
    // DETMAX spreads the calibration rows along the travel.
    let selection = read(&out.join("select/selection.parquet"));
    let chosen_stations: BTreeSet<i64> = i64s(&selection, "cw_id")
        .iter()
        .zip(strings(&selection, "role"))
        .filter(|(_, role)| role == "calibration")
        .map(|(cw, _)| commanded[cw] as i64)
        .collect();
    assert_eq!(chosen_stations.len(), 5, "{chosen_stations:?}");

    // The jointly calibrated cell validates within 1.5x the arm alone; the
    // track taken as perfect is several times worse.
    let eg = "elastogeometric";
    let arm_alone = stat(&dir.path().join("out/paper_sim"), "validate", eg, "mean_mm");
    let joint = stat(&out, "validate", eg, "mean_mm");
    let track_ignored = stat(&out, "validate_track_ignored", eg, "mean_mm");
    assert!(
        joint <= 1.5 * arm_alone,
        "joint {joint:.4} mm against the arm alone {arm_alone:.4} mm"
    );
    assert!(
        track_ignored >= 3.0 * joint,
        "track ignored {track_ignored:.4} mm against the joint fit {joint:.4} mm"
    );

    // Every identified track term within two standard errors of the truth
    // (the job is seeded: this is its outcome, not a chance).
    let truth = read(&common::root().join("jobs/truth/irb1600_track.parquet"));
    let true_value: HashMap<String, f64> = strings(&truth, "name")
        .into_iter()
        .zip(f64s(&truth, "value"))
        .collect();
    let parameters = read(&out.join("identify/parameters.parquet"));
    let (models, names, statuses) = (
        strings(&parameters, "model"),
        strings(&parameters, "name"),
        strings(&parameters, "status"),
    );
    let (values, errors) = (f64s(&parameters, "value"), f64s(&parameters, "std_error"));
    let mut identified = 0;
    for k in 0..parameters.height() {
        if models[k] != eg || !names[k].starts_with("track_") || statuses[k] != "identified" {
            continue;
        }
        identified += 1;
        let truth = true_value.get(&names[k]).copied().unwrap_or(0.0);
        let z = (values[k] - truth) / errors[k];
        assert!(
            z.abs() <= 2.0,
            "{}: {} ± {} against the truth {truth}",
            names[k],
            values[k],
            errors[k]
        );
    }
    // All 11 terms of order 2 but the rail's linear sideways misalignment,
    // which the world frame's yaw and joint 1's offset take.
    assert_eq!(identified, 10);

    the_programs_move_the_carriage_to_each_target(&out);
    the_accuracy_map_reaches_each_point_from_its_nearest_row_s_carriage(&out);
    a_carriage_beyond_the_calibrated_stations_is_outside_the_envelope(&out);
}

/// The accuracy map along the travel: each reachable grid point's
/// configuration, at the carriage position of its nearest calibration row
/// (one of the stations), puts the calibrated tool within the calibration's
/// correction of the point (nominal inverse kinematics: a few mm), where the
/// carriage left at 0 would miss by metres.
fn the_accuracy_map_reaches_each_point_from_its_nearest_row_s_carriage(out: &Path) {
    use egcal::robot::{ConfWrench, Robot, RobotSpec, Wrench};
    use egcal::table::parameters::{ModelName, from_frame};
    let spec = RobotSpec::load(&common::root().join("jobs/robots/irb1600_145_track.toml")).unwrap();
    let robot = Robot::new(spec.clone());
    let parameters_path = out.join("identify/parameters.parquet");
    let fit = from_frame(&read(&parameters_path), &parameters_path, &spec)
        .unwrap()
        .into_iter()
        .find(|s| s.model == ModelName::Elastogeometric)
        .unwrap();
    let map = read(&out.join("accuracy_map/accuracy_map.parquet"));
    let reachable: Vec<usize> = strings(&map, "status")
        .iter()
        .enumerate()
        .filter(|(_, s)| *s == "reachable")
        .map(|(k, _)| k)
        .collect();
    assert!(
        reachable.len() > map.height() / 2,
        "{} of {}",
        reachable.len(),
        map.height()
    );
    let cell = |name: &str| -> Vec<Option<f64>> {
        schema::optional_f64_values(&map, name, Path::new(name))
            .unwrap()
            .unwrap()
    };
    let (e1, position) = (
        cell("e1_mm"),
        ["x_mm", "y_mm", "z_mm"].map(|c| f64s(&map, c)),
    );
    let joints: Vec<Vec<Option<f64>>> = schema::JOINT_COLUMNS.iter().map(|c| cell(c)).collect();
    let stations: BTreeSet<i64> = reachable.iter().map(|k| e1[*k].unwrap() as i64).collect();
    assert_eq!(stations, BTreeSet::from([0, 750, 1500, 2250, 3000]));
    let mut worst_mm: f64 = 0.0;
    for &k in &reachable {
        let row = ConfWrench {
            track_mm: e1[k].unwrap(),
            ..ConfWrench::new(
                std::array::from_fn(|i| joints.get(i).map_or(0.0, |c| c[k].unwrap())),
                Wrench::zero(),
            )
        };
        let reached = robot.prepare(&fit.values).predict_row(&row).position_mm;
        let point = nalgebra::Vector3::new(position[0][k], position[1][k], position[2][k]);
        worst_mm = worst_mm.max((reached - point).norm());
    }
    eprintln!(
        "accuracy map on the track: {} of {} points reachable, the calibrated tool within {worst_mm:.3} mm of each",
        reachable.len(),
        map.height()
    );
    assert!(worst_mm < 10.0, "{worst_mm}");
    let u95 = cell("u95_mm");
    assert!(
        reachable
            .iter()
            .all(|k| u95[*k].is_some_and(|u| u > 0.0 && u < 1.0))
    );
}

/// Compensation trusts the track's polynomials between the positions the
/// calibration rows were measured at, not beyond: with the envelope of the
/// rows at 0 … 1500 mm only, the targets at 1875 and 2625 mm are
/// `outside_envelope`, with how far beyond in `track_beyond_mm`; within the
/// job's own envelope (all five stations) nothing is beyond.
fn a_carriage_beyond_the_calibrated_stations_is_outside_the_envelope(out: &Path) {
    let job_commands = read(&out.join("compensate_grid/commands.parquet"));
    assert!(
        f64s(&job_commands, "track_beyond_mm")
            .iter()
            .all(|b| *b == 0.0)
    );

    let dir = tempfile::tempdir().unwrap();
    let measurements = read(&out.join("measure/measurements.parquet"));
    let near: Vec<usize> = f64s(&measurements, "e1_mm")
        .iter()
        .enumerate()
        .filter(|(_, e)| **e <= 1500.0)
        .map(|(k, _)| k)
        .collect();
    let pick = |values: Vec<f64>| -> Vec<f64> { near.iter().map(|&k| values[k]).collect() };
    let ids = i64s(&measurements, "cw_id");
    let mut columns = vec![polars::prelude::Column::new(
        "cw_id".into(),
        near.iter().map(|&k| ids[k]).collect::<Vec<i64>>(),
    )];
    for name in [
        "q1_deg", "q2_deg", "q3_deg", "q4_deg", "q5_deg", "q6_deg", "e1_mm",
    ] {
        columns.push(polars::prelude::Column::new(
            name.into(),
            pick(f64s(&measurements, name)),
        ));
    }
    let envelope = dir.path().join("envelope.parquet");
    table::write_parquet(&mut table::frame(columns), &envelope, None).unwrap();
    let (code, log) = run_stage(
        dir.path(),
        "compensate",
        &common::root().join("jobs/robots/irb1600_145_track.toml"),
        "",
        &[
            (
                "targets",
                common::root().join("jobs/targets/track_grid.parquet"),
            ),
            ("parameters", out.join("identify/parameters.parquet")),
            ("envelope", envelope),
        ],
    );
    assert_eq!(code, 0, "{log}");
    let commands = read(&dir.path().join("out/commands.parquet"));
    let statuses = strings(&commands, "status");
    let job_statuses = strings(&job_commands, "status");
    let mut flagged = 0;
    for (k, (e, beyond)) in f64s(&commands, "e1_mm")
        .iter()
        .zip(f64s(&commands, "track_beyond_mm"))
        .enumerate()
    {
        assert_eq!(beyond, (e - 1500.0).max(0.0), "row {k}");
        if job_statuses[k] == "ok" && beyond > 0.0 {
            assert_eq!(statuses[k], "outside_envelope", "row {k} at {e} mm");
            flagged += 1;
        }
    }
    assert!(flagged >= 10, "{flagged} commands flagged");
}

/// The grid's programs, read back as the controllers would: every position
/// carries its command's carriage position as the first external axis, and
/// the FANUC program's joint positions with their E1, run on the job's
/// simulated cell without noise, put the tool on the targets to the
/// calibration's accuracy.
fn the_programs_move_the_carriage_to_each_target(out: &Path) {
    let commands = read(&out.join("compensate_grid/commands.parquet"));
    let statuses = strings(&commands, "status");
    let carriage: HashMap<i64, f64> = i64s(&commands, "target_id")
        .into_iter()
        .zip(f64s(&commands, "e1_mm"))
        .zip(&statuses)
        .filter(|(_, status)| *status == "ok")
        .map(|(pair, _)| pair)
        .collect();
    assert!(carriage.len() >= 40, "{} ok commands", carriage.len());
    let files = out.join("export_grid");
    let text = |name: &str| std::fs::read_to_string(files.join(name)).unwrap();

    // RAPID: jointtarget jt_<id> and robtarget pt_<id>, eax_a first in
    // their extjoint (the last bracket).
    let rapid = text("TRACKGRID.mod");
    for prefix in ["jt_", "pt_"] {
        for (id, e) in &carriage {
            let key = format!(" {prefix}{id} := ");
            let line = rapid
                .lines()
                .find(|l| l.contains(&key))
                .unwrap_or_else(|| panic!("RAPID: no {prefix}{id}"));
            let extjoint = line.rsplit('[').next().unwrap();
            let eax_a: f64 = extjoint.split(',').next().unwrap().trim().parse().unwrap();
            assert!(
                (eax_a - e).abs() < 1e-4,
                "{prefix}{id}: eax_a {eax_a}, e1 {e}"
            );
        }
    }
    // KRL: E6AXIS XJ_<id> and E6POS XP_<id> with E1.
    let krl = text("TRACKGRID.dat");
    for prefix in ["XJ_", "XP_"] {
        for (id, e) in &carriage {
            let key = format!(" {prefix}{id}={{");
            let line = krl
                .lines()
                .find(|l| l.contains(&key))
                .unwrap_or_else(|| panic!("KRL: no {prefix}{id}"));
            let e1: f64 = line
                .split(',')
                .find_map(|field| field.trim().strip_prefix("E1 "))
                .unwrap()
                .parse()
                .unwrap();
            assert!((e1 - e).abs() < 1e-4, "{prefix}{id}: E1 {e1}, e1 {e}");
        }
    }
    // CSV: the e1_mm column.
    let csv = text("commands.csv");
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let column = header.iter().position(|c| *c == "e1_mm").expect("e1_mm");
    for line in lines {
        let fields: Vec<&str> = line.split(',').collect();
        let id: i64 = fields[0].parse().unwrap();
        let e1: f64 = fields[column].parse().unwrap();
        assert_eq!(e1, carriage[&id], "target_id {id}");
    }

    yaskawa_moves_the_carriage_as_its_base_axis(out, &commands);

    // FANUC: each joint-form position of a target, J1 … J6 and E1.
    let spec =
        egcal::robot::RobotSpec::load(&common::root().join("jobs/robots/irb1600_145_track.toml"))
            .unwrap();
    let robot = egcal::robot::Robot::new(spec.clone());
    let truth = egcal::table::parameters::load_model(
        &common::root().join("jobs/truth/irb1600_track.parquet"),
        egcal::table::parameters::ModelName::Elastogeometric,
        &spec,
    )
    .unwrap()
    .values;
    // The job's simulated cell, its gearboxes' transmission error included,
    // without tracker noise.
    let settings = egcal::rig::simulator::SimulatorSettings {
        tracker_noise_mm: 0.0,
        encoder_noise_deg: 0.0,
        transmission_error_deg: 0.02,
        ..Default::default()
    };
    let mut cell = egcal::rig::simulator::Simulator::new(robot, truth, settings, 1).unwrap();
    let targets = read(&common::root().join("jobs/targets/track_grid.parquet"));
    let target_at: HashMap<i64, [f64; 3]> = i64s(&targets, "target_id")
        .into_iter()
        .zip(
            f64s(&targets, "x_mm")
                .into_iter()
                .zip(f64s(&targets, "y_mm"))
                .zip(f64s(&targets, "z_mm"))
                .map(|((x, y), z)| [x, y, z]),
        )
        .collect();
    let fanuc = text("TRACKGRID.ls");
    let mut errors = Vec::new();
    for block in fanuc.split("P[").skip(1) {
        let Some(id) = block
            .split('"')
            .nth(1)
            .and_then(|label| label.strip_prefix("target "))
        else {
            continue;
        };
        if !block.contains("J1=") {
            continue; // the Cartesian position of the same target
        }
        let id: i64 = id.parse().unwrap();
        let value = |name: &str| -> f64 {
            let after = block.split(&format!("{name}=")).nth(1).unwrap();
            after.split_whitespace().next().unwrap().parse().unwrap()
        };
        let q: [f64; 6] = std::array::from_fn(|j| value(&format!("J{}", j + 1)));
        let e1 = value("E1");
        assert!((e1 - carriage[&id]).abs() < 1e-3, "target {id}: E1 {e1}");
        use egcal::rig::Rig;
        cell.move_track(id, e1).unwrap();
        cell.move_joints(id, egcal::robot::joint_array(&q)).unwrap();
        let p = cell.measure().unwrap();
        let target = target_at[&id];
        errors.push(
            (0..3)
                .map(|k| (p[k] - target[k]).powi(2))
                .sum::<f64>()
                .sqrt(),
        );
    }
    assert_eq!(
        errors.len(),
        carriage.len(),
        "one joint position per ok command"
    );
    let mean = errors.iter().sum::<f64>() / errors.len() as f64;
    let max = errors.iter().copied().fold(0.0, f64::max);
    assert!(
        mean < 0.15 && max < 0.3,
        "mean {mean:.4} mm, max {max:.4} mm"
    );
}

/// The grid's commands as a Yaskawa job (Cartesian moves): the carriage is
/// the base axis, one `BC` position in pulses beside each robot position
/// and named in its move; without the robot file's base-axis pulse ratio the
/// format is refused, naming the key.
fn yaskawa_moves_the_carriage_as_its_base_axis(out: &Path, commands: &DataFrame) {
    let dir = tempfile::tempdir().unwrap();
    let shipped = common::root().join("jobs/robots/irb1600_145_track.toml");
    let text = std::fs::read_to_string(&shipped).unwrap();
    assert!(
        text.trim_end().ends_with("polynomial_order = 2"),
        "[track] is last"
    );
    let robot = dir.path().join("track_with_pulses.toml");
    std::fs::write(&robot, format!("{text}pulses_per_mm = -800.0\n")).unwrap();
    let run = |robot: &Path| {
        run_stage(
            dir.path(),
            "export_program",
            robot,
            "formats = [\"yaskawa\"]\nmodule_name = \"TRACKGRID\"\nmotion = \"linear\"\npre_position_deg = 0.0\n",
            &[
                ("commands", out.join("compensate_grid/commands.parquet")),
                ("parameters", out.join("identify/parameters.parquet")),
            ],
        )
    };
    let (code, log) = run(&shipped);
    assert_ne!(code, 0, "{log}");
    assert!(
        log.contains("pulses_per_mm") && log.contains("base axis"),
        "{log}"
    );

    let (code, log) = run(&robot);
    assert_eq!(code, 0, "{log}");
    let job = std::fs::read_to_string(dir.path().join("out/TRACKGRID.jbi")).unwrap();
    let ok: Vec<f64> = f64s(commands, "e1_mm")
        .into_iter()
        .zip(strings(commands, "status"))
        .filter(|(_, status)| status == "ok")
        .map(|(e, _)| e)
        .collect();
    let n = ok.len();
    assert!(job.contains(&format!("///NPOS {n},{n},0,0,0,0\n")), "{job}");
    assert!(job.contains("///GROUP1 RB1,BS1\n"));
    for (k, e) in ok.iter().enumerate() {
        let pulses: f64 = job
            .lines()
            .find_map(|l| l.strip_prefix(&format!("BC{k:05}=")))
            .unwrap_or_else(|| panic!("no BC{k:05}"))
            .parse()
            .unwrap();
        assert!(
            (pulses / -800.0 - e).abs() <= 0.5 / 800.0,
            "BC{k:05}: {pulses} for {e} mm"
        );
        // The first move is joint-interpolated (where the robot starts is
        // unknown), the others linear.
        let step = if k == 0 {
            format!("MOVJ C{k:05} BC{k:05} VJ=")
        } else {
            format!("MOVL C{k:05} BC{k:05} V=")
        };
        assert!(job.lines().any(|l| l.starts_with(&step)), "no `{step}`");
    }
}

/// `egcal stage <kind>` in `dir` for `robot` with the settings `settings`
/// and the bound inputs, writing to `dir/out`: its exit code and output.
fn run_stage(
    dir: &Path,
    kind: &str,
    robot: &Path,
    settings: &str,
    inputs: &[(&str, std::path::PathBuf)],
) -> (i32, String) {
    let settings_file = dir.join("settings.toml");
    std::fs::write(&settings_file, settings).unwrap();
    let mut args = vec![
        "stage".to_string(),
        kind.into(),
        "--robot".into(),
        robot.display().to_string(),
        "--settings".into(),
        settings_file.display().to_string(),
        "--out".into(),
        dir.join("out").display().to_string(),
    ];
    for (name, path) in inputs {
        args.push("--input".into());
        args.push(format!("{name}={}", path.display()));
    }
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let (code, stdout, stderr) = common::run(&args, dir);
    (code, format!("{stdout}{stderr}"))
}

/// A small track campaign's rows, designed by the shipped job's stages.
fn small_campaign(dir: &Path, measure: &str) -> std::path::PathBuf {
    common::shipped_job_in(dir, "track_sim", |text| {
        let design = text
            .split("[[stages]]\nid = \"identifiability\"")
            .next()
            .unwrap()
            .replace("points_per_axis = 5", "points_per_axis = 2")
            .replace("track_stations = 5", "track_stations = 3")
            .replace("per_config = 7", "per_config = 1");
        format!(
            "{design}[[stages]]\nid = \"measure\"\nkind = \"measure\"\ninputs = {{ conf_wrenches = \"wrenches\", truth = \"{}\" }}\nseed = 42\n{measure}\n",
            common::root()
                .join("jobs/truth/irb1600_track.parquet")
                .display()
        )
    })
}

/// `egcal sim-driver` for `robot` with the track truth, as a measure
/// stage's `driver` and `command`.
fn sim_driver(robot: &str) -> String {
    let root = common::root();
    let command = [
        env!("CARGO_BIN_EXE_egcal").to_string(),
        "sim-driver".into(),
        "--robot".into(),
        root.join("jobs/robots").join(robot).display().to_string(),
        "--truth".into(),
        root.join("jobs/truth/irb1600_track.parquet")
            .display()
            .to_string(),
        "--seed".into(),
        "42".into(),
    ];
    let quoted: Vec<String> = command.iter().map(|a| format!("{a:?}")).collect();
    format!("driver = \"external\"\ncommand = [{}]", quoted.join(", "))
}

#[test]
fn a_driver_moves_and_reads_the_carriage_as_the_in_process_simulator_does() {
    let inproc = tempfile::tempdir().unwrap();
    let job = small_campaign(inproc.path(), "");
    let (code, stdout, stderr) = common::run(&["run", job.to_str().unwrap()], inproc.path());
    assert_eq!(code, 0, "{stdout}\n{stderr}");

    let external = tempfile::tempdir().unwrap();
    let job = small_campaign(external.path(), &sim_driver("irb1600_145_track.toml"));
    let (code, stdout, stderr) = common::run(&["run", job.to_str().unwrap()], external.path());
    assert_eq!(code, 0, "{stdout}\n{stderr}");

    let rows = |dir: &Path| read(&dir.join("out/track_sim/measure/measurements.parquet"));
    let (a, b) = (rows(inproc.path()), rows(external.path()));
    assert_eq!(
        a.height(),
        24,
        "2 x 2 x 2 points at 3 stations, one wrench each"
    );
    assert_eq!(f64s(&a, "e1_mm"), f64s(&b, "e1_mm"));
    assert_eq!(table::content_hash(&a), table::content_hash(&b));
}

#[test]
fn a_driver_without_the_track_s_methods_is_refused_before_any_row() {
    let dir = tempfile::tempdir().unwrap();
    // The driver simulates the arm alone: its `hello` announces no track.
    let job = small_campaign(dir.path(), &sim_driver("irb1600_145.toml"));
    let (code, stdout, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    let log = format!("{stdout}{stderr}");
    assert_ne!(code, 0, "{log}");
    assert!(
        log.contains("does not announce move_track and read_track")
            && log.contains("irb1600_145_track.toml"),
        "{log}"
    );
    assert!(
        !dir.path()
            .join("out/track_sim/measure/measurements.parquet")
            .exists()
    );
}

#[test]
fn track_stations_are_checked_against_the_robot_file() {
    let dir = tempfile::tempdir().unwrap();
    let check = |edit: &dyn Fn(String) -> String| {
        let job = common::shipped_job_in(dir.path(), "track_sim", edit);
        let (code, stdout, stderr) = common::run(&["check", job.to_str().unwrap()], dir.path());
        (code, format!("{stdout}{stderr}"))
    };
    let (code, log) = check(&|t| t.replace("track_stations = 5", "track_stations = 2"));
    assert_eq!(code, 2, "{log}");
    assert!(
        log.contains("track_stations") && log.contains("order 2") && log.contains("at least 3"),
        "{log}"
    );
    let (code, log) =
        check(&|t| t.replace("robots/irb1600_145_track.toml", "robots/irb1600_145.toml"));
    assert_eq!(code, 2, "{log}");
    assert!(
        log.contains("track_stations") && log.contains("has no [track]"),
        "{log}"
    );
}

/// A driver of a robot on a track that answers like a rig, reads its
/// carriage in the unit `argv[2]` (1 for mm, 0.001 for metres) and dies
/// after `argv[1]` `measure` calls, standing in for a crashed lab driver.
const TRACK_DRIVER: &str = r#"
import json, sys
limit, unit = int(sys.argv[1]), float(sys.argv[2])
measured = 0
for line in sys.stdin:
    request = json.loads(line)
    method, rid = request["method"], request["id"]
    result = {}
    if method == "hello":
        result = {"protocol": 1, "name": "track test driver",
                  "capabilities": ["move_joints", "read_joints", "read_wrench", "apply_wrench",
                                   "release_wrench", "measure", "move_track", "read_track"]}
    elif method == "move_track":
        e = request["params"]["e_mm"]
    elif method == "read_track":
        result = {"e_mm": e * unit}
    elif method == "move_joints":
        q = request["params"]["q_deg"]
    elif method == "read_joints":
        result = {"q_deg": q}
    elif method == "read_wrench":
        result = {"wrench": [0.0] * 6}
    elif method == "measure":
        if measured == limit:
            sys.exit(3)
        measured += 1
        result = {"position_mm": [1000.0 + e, sum(q), 2.0], "measured_at_us": 0}
    elif method == "shutdown":
        print(json.dumps({"id": rid, "result": {}}), flush=True)
        break
    print(json.dumps({"id": rid, "result": result}), flush=True)
"#;

fn track_driver_job(dir: &Path, limit: usize, unit: f64) -> std::path::PathBuf {
    let script = dir.join("driver.py");
    std::fs::write(&script, TRACK_DRIVER).unwrap();
    small_campaign(
        dir,
        &format!(
            "driver = \"external\"\nretries = 0\ncommand = [\"python3\", \"{}\", \"{limit}\", \"{unit}\"]",
            script.display()
        ),
    )
}

#[test]
fn a_track_campaign_resumes_with_each_row_s_carriage_position() {
    let dir = tempfile::tempdir().unwrap();
    let job = track_driver_job(dir.path(), 5, 1.0);
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 3, "{stderr}");
    assert!(
        stderr.contains("the 5 rows measured so far are kept"),
        "{stderr}"
    );
    let job = track_driver_job(dir.path(), 100, 1.0);
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stderr.contains("resuming: 5 of 24 rows already measured"),
        "{stderr}"
    );
    let out = dir.path().join("out/track_sim");
    let candidates = read(&out.join("wrenches/candidates.parquet"));
    let commanded: HashMap<i64, f64> = i64s(&candidates, "cw_id")
        .into_iter()
        .zip(f64s(&candidates, "e1_mm"))
        .collect();
    let measurements = read(&out.join("measure/measurements.parquet"));
    assert_eq!(measurements.height(), 24);
    let positions = f64s(&measurements, "x_mm");
    for ((cw, e), x) in i64s(&measurements, "cw_id")
        .iter()
        .zip(f64s(&measurements, "e1_mm"))
        .zip(positions)
    {
        assert_eq!(e, commanded[cw], "cw_id {cw}: the journal's e1_mm");
        assert_eq!(
            x,
            1000.0 + e,
            "cw_id {cw}: measured with the carriage there"
        );
    }
}

#[test]
fn a_carriage_read_in_metres_fails_its_rows_with_the_reason() {
    let dir = tempfile::tempdir().unwrap();
    let job = track_driver_job(dir.path(), 100, 0.001);
    let (code, stdout, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    let out = dir.path().join("out/track_sim/measure");
    let failures = read(&out.join("measurement_failures.parquet"));
    let reasons = strings(&failures, "reason");
    // The 8 rows at the travel's start read 0 m = 0 mm, right by chance; the
    // 16 at 1500 and 3000 mm fail.
    assert_eq!(failures.height(), 16, "{code}: {stdout}\n{stderr}");
    assert!(
        reasons
            .iter()
            .all(|r| r.contains("e1_mm") && r.contains("max_track_error_mm = 1 mm")),
        "{reasons:?}"
    );
}

/// Designed for the work on a track: the points near each target are placed
/// with the carriage where the target is reached from, in the target's IK
/// branch, beside the box at each station.
#[test]
fn points_near_the_work_stand_at_each_target_s_carriage_position() {
    let dir = tempfile::tempdir().unwrap();
    let job = common::shipped_job_in(dir.path(), "track_sim", |text| {
        let design = text
            .split("[[stages]]\nid = \"wrenches\"")
            .next()
            .unwrap()
            .replace("points_per_axis = 5", "points_per_axis = 2")
            .replace("track_stations = 5", "track_stations = 3");
        let targets = common::root().join("jobs/targets/track_grid.parquet");
        design.replace(
            "kind = \"poses\"\n",
            &format!(
                "kind = \"poses\"\ninputs = {{ targets = \"{}\" }}\nnear_work_points = 2\n",
                targets.display()
            ),
        )
    });
    let (code, stdout, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 0, "{stdout}\n{stderr}");
    let poses = read(&dir.path().join("out/track_sim/poses/poses.parquet"));
    let ids = i64s(&poses, "config_id");
    assert_eq!(
        ids.iter().collect::<BTreeSet<_>>().len(),
        ids.len(),
        "unique ids"
    );
    let positions: BTreeSet<i64> = f64s(&poses, "e1_mm").iter().map(|e| *e as i64).collect();
    // The box at the 3 stations, and points near the targets at theirs.
    for e in [0, 1500, 3000, 375, 1125, 1875, 2625] {
        assert!(positions.contains(&e), "no pose at {e} mm: {positions:?}");
    }
    assert_eq!(positions.len(), 7, "{positions:?}");
}
