//! A seven-joint arm (issue #30): `jobs/panda_sim.toml` analyses, selects,
//! measures on the simulator, identifies and validates a Franka Emika Panda
//! whose seven joints all carry MDH errors and a compliance. The seventh
//! joint's parameters are named by the rule of the 42, and the calibration
//! validates in the accuracy class of the same campaign on the six-joint
//! IRB 1600. Stages built for six joints refuse the arm with a reason, and
//! tables of the wrong arm are refused.

mod common;

use std::collections::BTreeMap;
use std::path::Path;

use egcal::robot::{Frame, MAX_JOINTS, ParamId, ParamValues, Robot, RobotSpec, Wrench};
use egcal::table::parameters::{ModelName, ParamStatus, ParameterSet, from_frame};
use polars::prelude::{Column, CsvReadOptions, DataFrame, SerReader};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use common::tables::{f64s, read, strings};

fn set_of(path: &Path, spec: &RobotSpec, model: ModelName) -> ParameterSet {
    from_frame(&read(path), path, spec)
        .unwrap()
        .into_iter()
        .find(|s| s.model == model)
        .expect("the model's set")
}

/// Mean validation error (mm) of each model in a job's `validate` stage.
fn validation_means(out: &Path) -> BTreeMap<String, f64> {
    let errors = read(&out.join("validate/errors.parquet"));
    let mut sums: BTreeMap<String, (f64, usize)> = BTreeMap::new();
    for (model, e) in strings(&errors, "model")
        .into_iter()
        .zip(f64s(&errors, "error_mm"))
    {
        let entry = sums.entry(model).or_default();
        entry.0 += e;
        entry.1 += 1;
    }
    sums.into_iter()
        .map(|(model, (sum, n))| {
            assert_eq!(n, 450, "{model}: the 450 rows not selected");
            (model, sum / n as f64)
        })
        .collect()
}

#[test]
fn the_panda_campaign_identifies_all_seven_joints_as_well_as_a_six_joint_arm() {
    let dir = tempfile::tempdir().unwrap();
    let job = common::shipped_job_in(dir.path(), "panda_sim", |text| text);
    let (code, stdout, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 0, "{stdout}\n{stderr}");
    let out = dir.path().join("out/panda_sim");
    let spec = RobotSpec::load(&common::root().join("jobs/robots/panda.toml")).unwrap();

    // The measurements carry the seventh joint.
    let measurements = read(&out.join("measure/measurements.parquet"));
    assert_eq!(f64s(&measurements, "q7_deg").len(), 600);

    // The seventh joint's parameters are named by the rule of the 42; its
    // length error and compliance are identified, and the compliance (which
    // no geometric parameter stands in for) lands within two standard
    // errors of the truth.
    let seventh: Vec<&str> = ParamId::of_arm(7).skip(42).map(|id| id.name()).collect();
    assert_eq!(seventh, ["dtheta7", "dalpha7", "da7", "dd7", "k7"]);
    let truth = set_of(
        &common::root().join("jobs/truth/panda_sim.parquet"),
        &spec,
        ModelName::Elastogeometric,
    );
    let fitted = set_of(
        &out.join("identify/parameters.parquet"),
        &spec,
        ModelName::Elastogeometric,
    );
    for name in ["da7", "k7"] {
        let id = ParamId::from_name(name).unwrap();
        assert_eq!(fitted.status[id.index()], ParamStatus::Identified, "{name}");
    }
    let k7 = ParamId::from_name("k7").unwrap();
    let sigma = fitted.std_errors[k7.index()].unwrap();
    let error = fitted.values.get(k7) - truth.values.get(k7);
    assert!(error.abs() <= 2.0 * sigma, "k7 off by {error} ± {sigma}");

    // The same campaign for the six-joint IRB 1600 (joint vectors over the
    // whole joint space, the same wrenches and simulator), the paper's truth.
    let campaigns = common::root().join("jobs/campaigns");
    let six = dir.path().join("six");
    std::fs::create_dir_all(&six).unwrap();
    let six_job = common::shipped_job_in(&six, "panda_sim", |text| {
        text.replace("panda.toml", "irb1600_145.toml")
            .replace(
                &campaigns
                    .join("panda_conf_wrenches.parquet")
                    .display()
                    .to_string(),
                &campaigns
                    .join("irb1600_random_conf_wrenches.parquet")
                    .display()
                    .to_string(),
            )
            .replace("panda_sim.parquet", "irb1600_paper.parquet")
    });
    let (code, stdout, stderr) = common::run(&["run", six_job.to_str().unwrap()], &six);
    assert_eq!(code, 0, "{stdout}\n{stderr}");

    // Validated on the 450 rows not selected: the seven-joint arm's
    // calibration is within 1.5× the six-joint arm's (the same accuracy
    // class), ten times better than its nominal model, and its compliance
    // model beats the kinematic one.
    let seven = validation_means(&out);
    let six_out = six.join("out/panda_sim");
    let six = validation_means(&six_out);
    println!("validation means, seven joints {seven:?}, six joints {six:?}");
    let (eg7, eg6) = (seven["elastogeometric"], six["elastogeometric"]);
    assert!(
        eg7 <= 1.5 * eg6,
        "{eg7} mm against the six-joint arm's {eg6} mm"
    );
    assert!(seven["nominal"] > 10.0 * eg7, "{seven:?}");
    assert!(seven["kinematic"] > 2.0 * eg7, "{seven:?}");

    reaches_the_map_by_the_redundancy_rule(&out, &spec, &fitted.values, &measurements);
    let six_map = read(&six_out.join("accuracy_map/accuracy_map.parquet"));
    println!(
        "accuracy map reachable: six joints {} of {}",
        strings(&six_map, "status")
            .iter()
            .filter(|s| *s == "reachable")
            .count(),
        six_map.height()
    );

    compensates_by_the_redundancy_rule(dir.path(), &out, &spec, &truth.values);
}

/// The accuracy map's reachable points: the nominal arm's tool (calibrated
/// world and tool frames) at the point, joint 3 held at a measured row's value (the nearest row's, by the
/// redundancy rule).
fn reaches_the_map_by_the_redundancy_rule(
    out: &Path,
    spec: &RobotSpec,
    calibrated: &ParamValues,
    measurements: &DataFrame,
) {
    let robot = Robot::new(spec.clone());
    let map = read(&out.join("accuracy_map/accuracy_map.parquet"));
    let status = strings(&map, "status");
    let measured_q3 = f64s(measurements, "q3_deg");
    let q: Vec<Vec<Option<f64>>> = (1..=7)
        .map(|j| {
            map.column(&format!("q{j}_deg"))
                .unwrap()
                .f64()
                .unwrap()
                .iter()
                .collect()
        })
        .collect();
    let xyz: Vec<Vec<f64>> = ["x_mm", "y_mm", "z_mm"]
        .iter()
        .map(|c| f64s(&map, c))
        .collect();
    let mut reachable = 0;
    for k in (0..map.height()).filter(|k| status[*k] == "reachable") {
        reachable += 1;
        let q_deg: [f64; MAX_JOINTS] = std::array::from_fn(|j| q[j][k].unwrap());
        assert!(
            measured_q3.iter().any(|m| (m - q_deg[HELD]).abs() < 1e-9),
            "point {k}: q3 {} is no measured row's",
            q_deg[HELD]
        );
        // The map reaches its points by nominal IK, in the calibrated world
        // and tool frames.
        let tool = robot
            .world_from_base(calibrated)
            .compose(&robot.nominal_flange_in_base(&q_deg))
            .compose(&robot.flange_from_tool(calibrated, 0));
        let point = nalgebra::Vector3::new(xyz[0][k], xyz[1][k], xyz[2][k]);
        assert!((tool.origin_mm - point).norm() < 1e-6, "point {k}");
    }
    println!(
        "accuracy map reachable: seven joints {reachable} of {}",
        map.height()
    );
    assert!(reachable >= 30, "{reachable} reachable points");
}

/// The joint the redundancy rule holds (joint 3).
const HELD: usize = egcal::robot::ik::HELD_JOINT_OF_SEVEN;

/// `compensate` with the calibrated Panda: targets where the true arm puts
/// its SMR at random configurations, half with a branch hint (its `q3_deg`
/// holds joint 3, the redundancy rule's) and half without (joint 3 held at
/// `held_joint_deg`). Every command is `ok`, keeps joint 3 where the rule
/// says, and the true arm under it lands within the calibration's accuracy
/// of the target. `export_program` writes the commands as CSV, whose seven
/// joint columns a CSV reader reads back as the commands, and as URDF.
fn compensates_by_the_redundancy_rule(
    dir: &Path,
    out: &Path,
    spec: &RobotSpec,
    truth: &ParamValues,
) {
    let robot = Robot::new(spec.clone());
    let mut rng = StdRng::seed_from_u64(5);
    let held_deg = 20.0;
    let n = 12;
    let generators: Vec<[f64; MAX_JOINTS]> = (0..n)
        .map(|k| {
            let mut q = robot.joint_vector(|i| {
                let [lo, hi] = robot.joint_limits(i);
                // Away from the limits, where the true arm reaches the target.
                rng.random_range(lo + 0.2 * (hi - lo)..hi - 0.2 * (hi - lo))
            });
            if k % 2 == 1 {
                q[HELD] = held_deg;
            }
            q
        })
        .collect();
    let poses: Vec<Frame> = generators
        .iter()
        .map(|q| robot.tool_in_world(truth, q, &Wrench::zero(), &[0; MAX_JOINTS]))
        .collect();
    let hints: Vec<Column> = (0..7)
        .map(|joint| {
            Column::new(
                format!("q{}_deg", joint + 1).into(),
                generators
                    .iter()
                    .enumerate()
                    .map(|(k, q)| {
                        (k % 2 == 0).then_some(q[joint] + if joint == HELD { 0.0 } else { 1.0 })
                    })
                    .collect::<Vec<_>>(),
            )
        })
        .collect();
    let targets = dir.join("panda_targets.parquet");
    common::targets::write_targets(&targets, &poses, hints);
    let (code, output, stage_out) = common::stage(
        dir,
        &common::root().join("jobs/robots/panda.toml"),
        "compensate",
        &format!("held_joint_deg = {held_deg}\n"),
        &[
            ("parameters", &out.join("identify/parameters.parquet")),
            ("targets", &targets),
        ],
    );
    assert_eq!(code, 0, "{output}");
    let commands = read(&stage_out.join("commands.parquet"));
    assert_eq!(strings(&commands, "status"), vec!["ok".to_string(); n]);
    let q: Vec<Vec<f64>> = (1..=7)
        .map(|j| f64s(&commands, &format!("q{j}_deg")))
        .collect();
    let mut worst_mm: f64 = 0.0;
    for k in 0..n {
        let command: [f64; MAX_JOINTS] = std::array::from_fn(|j| q[j][k]);
        let held = if k % 2 == 0 {
            generators[k][HELD]
        } else {
            held_deg
        };
        assert!(
            (command[HELD] - held).abs() < 1e-9,
            "row {k}: q3 {} against {held}",
            command[HELD]
        );
        let reached = robot.tool_in_world(truth, &command, &Wrench::zero(), &[0; MAX_JOINTS]);
        worst_mm = worst_mm.max((reached.origin_mm - poses[k].origin_mm).norm());
    }
    println!("panda compensation: worst {worst_mm:.4} mm from the true targets");
    assert!(worst_mm < 1.0, "{worst_mm} mm");

    let (code, output, programs) = common::stage(
        dir,
        &common::root().join("jobs/robots/panda.toml"),
        "export_program",
        "",
        &[
            ("commands", &stage_out.join("commands.parquet")),
            ("parameters", &out.join("identify/parameters.parquet")),
        ],
    );
    assert_eq!(code, 0, "{output}");
    let csv = CsvReadOptions::default()
        .try_into_reader_with_file_path(Some(programs.join("commands.csv")))
        .unwrap()
        .finish()
        .unwrap();
    assert_eq!(csv.height(), n);
    for (j, column) in q.iter().enumerate() {
        let name = format!("q{}_deg", j + 1);
        for (printed, command) in f64s(&csv, &name).iter().zip(column) {
            // Six decimals printed.
            assert!(
                (printed - command).abs() <= 5e-7,
                "{name}: {printed} against {command}"
            );
        }
    }
    assert!(!programs.join("EGCAL_PROGRAM.mod").exists());
    let urdf = std::fs::read_to_string(programs.join("robot.urdf")).unwrap();
    assert!(
        urdf.contains("<joint name=\"joint7\" type=\"revolute\">")
            && urdf.contains("<parent link=\"link7\"/>"),
        "{urdf}"
    );
}

/// `poses` designs a Panda campaign: each attempt draws joint 3 (the held
/// joint) within its limits, so the configurations spread over elbow angles;
/// every row's nominal tool is at its target and within the joint limits.
#[test]
fn poses_of_the_panda_spread_the_held_joint_and_reach_their_targets() {
    let dir = tempfile::tempdir().unwrap();
    let panda = common::root().join("jobs/robots/panda.toml");
    let spec = RobotSpec::load(&panda).unwrap();
    let robot = Robot::new(spec.clone());
    let (code, output, out) = common::stage(
        dir.path(),
        &panda,
        "poses",
        "centre_mm = [450.0, 0.0, 350.0]\nedge_mm = 300.0\ntracker_mm = [2500.0, 0.0, 500.0]\nmin_shoulder_mm = 50.0\n",
        &[],
    );
    assert_eq!(code, 0, "{output}");
    let poses = read(&out.join("poses.parquet"));
    assert_eq!(poses.height(), 125, "{output}");
    let q: Vec<Vec<f64>> = (1..=7)
        .map(|j| f64s(&poses, &format!("q{j}_deg")))
        .collect();
    let target: Vec<Vec<f64>> = ["target_x_mm", "target_y_mm", "target_z_mm"]
        .iter()
        .map(|c| f64s(&poses, c))
        .collect();
    let nominal = ParamValues::nominal(&spec);
    for k in 0..poses.height() {
        let q_deg: [f64; MAX_JOINTS] = std::array::from_fn(|j| q[j][k]);
        assert!(robot.within_limits(&q_deg), "row {k}: {q_deg:?}");
        let (_, tool) = robot.frames_in_base(&nominal, &q_deg);
        let reached = nalgebra::Vector3::new(target[0][k], target[1][k], target[2][k]);
        assert!((tool.origin_mm - reached).norm() < 1e-6, "row {k}");
    }
    let held = &q[HELD];
    let mean = held.iter().sum::<f64>() / held.len() as f64;
    let sd = (held.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / held.len() as f64).sqrt();
    assert!(sd > 40.0, "joint 3 spread {sd}°");
}

/// `nest_poses` for a Panda with the IRB 1600 cell's positioner: the nests'
/// rows park all seven joints where `arm_park_deg` says; six values are
/// refused, naming the joint count.
#[test]
fn nest_poses_park_all_seven_joints() {
    let dir = tempfile::tempdir().unwrap();
    let panda_text =
        std::fs::read_to_string(common::root().join("jobs/robots/panda.toml")).unwrap();
    let positioner_text =
        std::fs::read_to_string(common::root().join("jobs/robots/irb1600_145_positioner.toml"))
            .unwrap();
    let positioner = &positioner_text[positioner_text.find("\n[positioner]").unwrap()..];
    let robot = dir.path().join("panda_positioner.toml");
    std::fs::write(&robot, format!("{panda_text}\n{positioner}")).unwrap();

    let mut columns = vec![
        Column::new("cw_id".into(), [1_i64, 2]),
        Column::new("config_id".into(), [1_i64, 2]),
    ];
    // Two configurations within the Panda's limits.
    let rows = [
        [0.0, 0.0, 0.0, -90.0, 0.0, 90.0, 0.0],
        [10.0, -10.0, 10.0, -100.0, 10.0, 100.0, 10.0],
    ];
    for (joint, name) in egcal::table::schema::ALL_JOINT_COLUMNS.iter().enumerate() {
        columns.push(Column::new(
            (*name).into(),
            [rows[0][joint], rows[1][joint]],
        ));
    }
    for name in egcal::table::schema::WRENCH_COLUMNS {
        columns.push(Column::new(name.into(), [1.0, -2.0]));
    }
    for name in egcal::table::schema::TENSION_COLUMNS {
        columns.push(Column::new(name.into(), [50.0, 60.0]));
    }
    columns.push(Column::new("margin_n".into(), [12.0, 13.0]));
    let mut df = egcal::table::frame(columns);
    let candidates = dir.path().join("candidates.parquet");
    egcal::table::write_parquet(&mut df, &candidates, None).unwrap();

    let park = [0.0, -30.0, 10.0, -120.0, 0.0, 100.0, 45.0];
    let (code, output, out) = common::stage(
        dir.path(),
        &robot,
        "nest_poses",
        &format!("arm_park_deg = {park:?}\nper_nest = 4\n"),
        &[("candidates", &candidates)],
    );
    assert_eq!(code, 0, "{output}");
    let table = read(&out.join("candidates.parquet"));
    let targets = strings(&table, "target_id");
    assert_eq!(table.height(), 2 + 3 * 4, "{output}");
    for (joint, value) in park.iter().enumerate() {
        let q = f64s(&table, &format!("q{}_deg", joint + 1));
        for (k, target) in targets.iter().enumerate().skip(2) {
            assert_ne!(target, "arm");
            assert_eq!(q[k], *value, "row {k}, joint {}", joint + 1);
        }
    }

    let (code, output, _) = common::stage(
        dir.path(),
        &robot,
        "nest_poses",
        "arm_park_deg = [0.0, 0.0, 0.0, -90.0, 0.0, 90.0]\n",
        &[("candidates", &candidates)],
    );
    assert_eq!(code, 2, "{output}");
    assert!(
        output.contains("arm_park_deg") && output.contains("6 values for the 7 joints"),
        "{output}"
    );
}

fn campaigns_file(name: &str) -> std::path::PathBuf {
    common::root().join("jobs/campaigns").join(name)
}

/// Stages that need a six-joint arm refuse the Panda, naming the robot file
/// and why; a six-joint arm's table with a seventh joint's column and a
/// seven-joint arm's table without it are refused.
#[test]
fn six_joint_stages_and_tables_of_the_wrong_arm_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let panda = common::root().join("jobs/robots/panda.toml");
    let campaign = common::root().join("jobs/campaigns/panda_conf_wrenches.parquet");
    // RAPID has no seven-joint arm's axis order here; a six-joint arm has no
    // joint to hold.
    let commands = dir.path().join("commands.parquet");
    let (code, output, _) = common::stage(
        dir.path(),
        &panda,
        "export_program",
        "formats = [\"csv\", \"rapid\"]\n",
        &[("commands", &commands)],
    );
    assert_eq!(code, 2, "{output}");
    assert!(
        output.contains("formats[1]") && output.contains("7 joints") && output.contains("`csv`"),
        "{output}"
    );
    let irb = common::root().join("jobs/robots/irb1600_145.toml");
    let (code, output, _) = common::stage(
        dir.path(),
        &irb,
        "compensate",
        "held_joint_deg = 10.0\n",
        &[("targets", &commands)],
    );
    assert_eq!(code, 2, "{output}");
    assert!(
        output.contains("held_joint_deg") && output.contains("6 joints"),
        "{output}"
    );

    // The driver protocol moves six joints: a seven-joint campaign is not
    // sent to a driver.
    let (code, output, _) = common::stage(
        dir.path(),
        &panda,
        "measure",
        "driver = \"external\"\ncommand = [\"true\"]\n",
        &[("conf_wrenches", &campaign)],
    );
    assert_eq!(code, 2, "{output}");
    assert!(
        output.contains("driver protocol moves six") && output.contains("simulator"),
        "{output}"
    );

    // The six-joint IRB 1600 given the Panda's rows: a column nothing reads.
    let (code, output, _) = common::stage(
        dir.path(),
        &irb,
        "identifiability",
        "",
        &[("candidates", &campaign)],
    );
    assert_eq!(code, 2, "{output}");
    assert!(
        output.contains("q7_deg") && output.contains("6 joints"),
        "{output}"
    );

    // The Panda's truth given to the six-joint arm: its seventh joint's
    // values would move nothing.
    let (code, output, _) = common::stage(
        dir.path(),
        &irb,
        "measure",
        "driver = \"simulator\"\n",
        &[
            (
                "conf_wrenches",
                &campaigns_file("irb1600_random_conf_wrenches.parquet"),
            ),
            (
                "truth",
                &common::root().join("jobs/truth/panda_sim.parquet"),
            ),
        ],
    );
    assert_eq!(code, 2, "{output}");
    assert!(
        output.contains("`dtheta7`") && output.contains("joint 7") && output.contains("6 joints"),
        "{output}"
    );

    // The Panda given six joints' rows: its seventh is missing.
    let six = dir.path().join("six.parquet");
    let mut df = read(&campaign);
    df = df.drop("q7_deg").unwrap();
    egcal::table::write_parquet(&mut df, &six, None).unwrap();
    let (code, output, _) = common::stage(
        dir.path(),
        &panda,
        "identifiability",
        "",
        &[("candidates", &six)],
    );
    assert_eq!(code, 2, "{output}");
    assert!(output.contains("q7_deg"), "{output}");
}
