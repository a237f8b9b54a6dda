//! A gantry (issue #30): three prismatic joints and a spherical wrist,
//! `jobs/gantry_sim.toml` end to end. A prismatic joint's value is mm in
//! every table (`q1_mm`), its compliance mm/N in the parameters table; the
//! calibration is identified and validated on the simulator, the work
//! targets are compensated and run on the simulated gantry, and its
//! programs are read back as a consumer would: the CSV by polars' reader,
//! the URDF by forward kinematics written from its joints. Paths built for
//! six revolute joints refuse a gantry by name.

mod common;

use std::collections::BTreeMap;
use std::path::Path;

use egcal::robot::{MAX_JOINTS, ParamId, Robot, RobotSpec};
use egcal::table::parameters::{ModelName, ParamStatus, ParameterSet, from_frame};
use nalgebra::{Matrix4, Vector3};
use polars::prelude::{CsvReadOptions, SerReader};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use common::tables::{f64s, read, strings};
use common::urdf::{chain, urdf_joints, urdf_transform};

fn set_of(path: &Path, spec: &RobotSpec, model: ModelName) -> ParameterSet {
    from_frame(&read(path), path, spec)
        .unwrap()
        .into_iter()
        .find(|s| s.model == model)
        .expect("the model's set")
}

fn gantry_spec() -> RobotSpec {
    RobotSpec::load(&common::root().join("jobs/robots/gantry.toml")).unwrap()
}

#[test]
fn the_gantry_is_calibrated_compensated_and_programmed_in_millimetres_of_its_slides() {
    let dir = tempfile::tempdir().unwrap();
    let job = common::shipped_job_in(dir.path(), "gantry_sim", |text| text);
    let (code, stdout, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 0, "{stdout}\n{stderr}");
    let out = dir.path().join("out/gantry_sim");
    let spec = gantry_spec();

    // The slides' columns are millimetres; no angle column stands for them.
    let measurements = read(&out.join("measure/measurements.parquet"));
    for name in ["q1_mm", "q2_mm", "q3_mm", "q4_deg", "q5_deg", "q6_deg"] {
        assert_eq!(f64s(&measurements, name).len(), 600, "{name}");
    }
    assert!(measurements.column("q1_deg").is_err());

    // Validated on the 450 rows not selected: the compliance model is ten
    // times better than the nominal one and beats the kinematic one.
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
    let means: BTreeMap<String, f64> = sums
        .into_iter()
        .map(|(model, (sum, n))| {
            assert_eq!(n, 450, "{model}");
            (model, sum / n as f64)
        })
        .collect();
    println!("gantry validation means {means:?}");
    let eg = means["elastogeometric"];
    assert!(eg < 0.15, "{means:?}");
    assert!(means["nominal"] > 10.0 * eg, "{means:?}");
    assert!(means["kinematic"] > 2.0 * eg, "{means:?}");

    // The slides' compliances are mm/N in the table and land within two
    // standard errors of the truth.
    let parameters = read(&out.join("identify/parameters.parquet"));
    let units: BTreeMap<String, String> = strings(&parameters, "name")
        .into_iter()
        .zip(strings(&parameters, "unit"))
        .collect();
    assert_eq!(units["k3"], "mm/N");
    assert_eq!(units["k4"], "deg/(N·m)");
    let truth = set_of(
        &common::root().join("jobs/truth/gantry_sim.parquet"),
        &spec,
        ModelName::Elastogeometric,
    );
    let fitted = set_of(
        &out.join("identify/parameters.parquet"),
        &spec,
        ModelName::Elastogeometric,
    );
    for name in ["k1", "k2", "k3"] {
        let id = ParamId::from_name(name).unwrap();
        assert_eq!(fitted.status[id.index()], ParamStatus::Identified, "{name}");
        let sigma = fitted.std_errors[id.index()].unwrap();
        let error = fitted.values.get(id) - truth.values.get(id);
        assert!(
            error.abs() <= 2.0 * sigma,
            "{name} off by {error} ± {sigma}"
        );
    }

    // The work targets, compensated and run on the simulated gantry: every
    // one `ok`, and the tool lands within a tenth of the nominal model's
    // error.
    let commands = read(&out.join("compensate/commands.parquet"));
    assert!(strings(&commands, "status").iter().all(|s| s == "ok"));
    let stats = read(&out.join("accuracy/target_stats.parquet"));
    let runs = strings(&stats, "run");
    let mean = f64s(&stats, "mean_mm");
    let of = |run: &str| mean[runs.iter().position(|r| r == run).unwrap()];
    println!(
        "gantry work targets: compensated {} mm, nominal {} mm",
        of("achieved"),
        of("baseline")
    );
    assert!(of("achieved") < 0.15 && of("achieved") < of("baseline") / 10.0);

    // The CSV read back by polars' reader: the commands, slides in mm.
    let csv = CsvReadOptions::default()
        .try_into_reader_with_file_path(Some(out.join("program/commands.csv")))
        .unwrap()
        .finish()
        .unwrap();
    assert_eq!(csv.height(), commands.height());
    for name in ["q1_mm", "q2_mm", "q3_mm", "q4_deg", "q5_deg", "q6_deg"] {
        for (printed, command) in f64s(&csv, name).iter().zip(f64s(&commands, name)) {
            assert!((printed - command).abs() <= 5e-7, "{name}");
        }
    }

    urdf_is_the_calibrated_gantry(
        &std::fs::read_to_string(out.join("program/robot.urdf")).unwrap(),
        &Robot::new(spec),
        &fitted,
    );
}

/// The URDF's forward kinematics (each joint's origin, then a translation
/// along z by q/1000 m for a prismatic joint or a turn about z for a
/// revolute one) equals egcal's rigid model of the fitted set at random
/// configurations.
fn urdf_is_the_calibrated_gantry(text: &str, robot: &Robot, fitted: &ParameterSet) {
    let chain = chain(&urdf_joints(text), "world", "tool");
    let kinds: Vec<&str> = chain
        .iter()
        .filter(|j| j.kind != "fixed")
        .map(|j| j.kind.as_str())
        .collect();
    assert_eq!(
        kinds,
        [
            "prismatic",
            "prismatic",
            "prismatic",
            "revolute",
            "revolute",
            "revolute"
        ]
    );
    // The slides' limits in metres.
    assert!(text.contains("lower=\"0\" upper=\"3\""), "{text}");
    let mut rng = StdRng::seed_from_u64(5);
    for _ in 0..200 {
        let q: [f64; MAX_JOINTS] = robot.joint_vector(|i| {
            let [lo, hi] = robot.joint_limits(i);
            rng.random_range(lo..hi)
        });
        let mut t = Matrix4::identity();
        let mut joint = 0;
        for j in &chain {
            t *= j.origin;
            match j.kind.as_str() {
                "prismatic" => t *= urdf_transform([0.0, 0.0, q[joint] / 1000.0], [0.0; 3]),
                "revolute" => t *= urdf_transform([0.0; 3], [0.0, 0.0, q[joint].to_radians()]),
                _ => continue,
            }
            joint += 1;
        }
        let urdf_mm = Vector3::new(t[(0, 3)], t[(1, 3)], t[(2, 3)]) * 1000.0;
        let (_, tool) = robot.frames_in_base(&fitted.values, &q);
        let world = robot.world_from_base(&fitted.values);
        let egcal_mm = world.transform_point(&tool.origin_mm);
        assert!((urdf_mm - egcal_mm).norm() < 1e-9, "{q:?}");
        let rotation = world.rotation * tool.rotation;
        assert!((t.fixed_view::<3, 3>(0, 0) - rotation).abs().max() < 1e-12);
    }
}

#[test]
fn paths_for_six_revolute_joints_refuse_a_gantry_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let gantry = common::root().join("jobs/robots/gantry.toml");
    let irb = common::root().join("jobs/robots/irb1600_145.toml");
    let campaign = common::root().join("jobs/campaigns/gantry_conf_wrenches.parquet");
    let irb_campaign = common::root().join("jobs/campaigns/irb1600_random_conf_wrenches.parquet");

    // A controller language's joint targets are six angles.
    let commands = dir.path().join("commands.parquet");
    let (code, output, _) = common::stage(
        dir.path(),
        &gantry,
        "export_program",
        "formats = [\"csv\", \"rapid\"]\n",
        &[("commands", &commands)],
    );
    assert_eq!(code, 2, "{output}");
    assert!(
        output.contains("formats[1]") && output.contains("joint 1") && output.contains("prismatic"),
        "{output}"
    );

    // The driver protocol carries angles.
    let (code, output, _) = common::stage(
        dir.path(),
        &gantry,
        "measure",
        "driver = \"external\"\ncommand = [\"true\"]\n",
        &[("conf_wrenches", &campaign)],
    );
    assert_ne!(code, 0, "{output}");
    assert!(
        output.contains("prismatic joint (joint 1)") && output.contains("simulator"),
        "{output}"
    );

    // A revolute arm's table for the gantry, and the gantry's for a
    // revolute arm: the column names the joint and the unit it should be.
    let (code, output, _) = common::stage(
        dir.path(),
        &gantry,
        "identifiability",
        "",
        &[("candidates", &irb_campaign)],
    );
    assert_ne!(code, 0, "{output}");
    assert!(
        output.contains("q1_deg") && output.contains("joint 1") && output.contains("`q1_mm`"),
        "{output}"
    );
    let (code, output, _) = common::stage(
        dir.path(),
        &irb,
        "identifiability",
        "",
        &[("candidates", &campaign)],
    );
    assert_ne!(code, 0, "{output}");
    assert!(
        output.contains("q1_mm") && output.contains("revolute") && output.contains("`q1_deg`"),
        "{output}"
    );

    // A prismatic joint's limits are millimetres.
    let text = std::fs::read_to_string(&gantry).unwrap().replacen(
        "limits_mm = [0.0, 3000.0]",
        "limits_deg = [0.0, 3000.0]",
        1,
    );
    let err = RobotSpec::parse(&text, Path::new("g.toml"))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("joints[0].limits_deg") && err.contains("limits_mm"),
        "{err}"
    );
}

/// The campaign's poses for a gantry: the numeric IK places every point of
/// the box the tracker sees, its slides' values in mm within their travel;
/// only the wrist's singularity applies.
#[test]
fn poses_of_a_gantry_are_in_its_slides_millimetres() {
    let dir = tempfile::tempdir().unwrap();
    let gantry = common::root().join("jobs/robots/gantry.toml");
    let (code, output, out) = common::stage(
        dir.path(),
        &gantry,
        "poses",
        "sampling = \"grid\"\npoints_per_axis = 3\ncentre_mm = [900.0, 1500.0, -1500.0]\nedge_mm = 600.0\nacceptance_half_angle_deg = 40.0\n",
        &[],
    );
    assert_eq!(code, 0, "{output}");
    let poses = read(&out.join("poses.parquet"));
    assert_eq!(poses.height(), 27);
    let robot = Robot::new(gantry_spec());
    for (joint, name) in ["q1_mm", "q2_mm", "q3_mm", "q4_deg", "q5_deg", "q6_deg"]
        .iter()
        .enumerate()
    {
        let [lo, hi] = robot.joint_limits(joint);
        assert!(
            f64s(&poses, name).iter().all(|q| (lo..=hi).contains(q)),
            "{name}"
        );
    }
    // The wrist keeps the stage's default margin (`min_wrist_deg` = 5)
    // from the singular q5 = 0.
    assert!(f64s(&poses, "q5_deg").iter().all(|q| q.abs() >= 5.0));
}

/// `predict` names a slide's load and deflection in its units: the force
/// along its axis (`force3_n`, N) and `dq3_mm`, which is `k3·force3_n`.
#[test]
fn predictions_name_a_slide_s_force_and_deflection_in_its_units() {
    let dir = tempfile::tempdir().unwrap();
    let gantry = common::root().join("jobs/robots/gantry.toml");
    let campaign = common::root().join("jobs/campaigns/gantry_conf_wrenches.parquet");
    let truth = common::root().join("jobs/truth/gantry_sim.parquet");
    let (code, output, out) = common::stage(
        dir.path(),
        &gantry,
        "predict",
        "model = \"elastogeometric\"\n",
        &[("conf_wrenches", &campaign), ("parameters", &truth)],
    );
    assert_eq!(code, 0, "{output}");
    let predictions = read(&out.join("predictions.parquet"));
    assert!(predictions.column("tau3_nm").is_err());
    assert!(predictions.column("dq3_deg").is_err());
    let k3 = set_of(&truth, &gantry_spec(), ModelName::Elastogeometric)
        .values
        .get(ParamId::from_name("k3").unwrap());
    for (force, deflection) in f64s(&predictions, "force3_n")
        .iter()
        .zip(f64s(&predictions, "dq3_mm"))
    {
        assert!((deflection - k3 * force).abs() < 1e-12);
    }
    // The ram carries its 80 kg, the wrist's 19.5 kg and the payload's 10 kg
    // (plus the rows' wrenches): about 1074 N on average.
    let forces = f64s(&predictions, "force3_n");
    let mean = forces.iter().sum::<f64>() / forces.len() as f64;
    assert!((mean - 109.5 * 9.81).abs() < 30.0, "{mean}");
    assert_eq!(f64s(&predictions, "tau4_nm").len(), forces.len());
}
