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

use egcal::robot::{ParamId, ParamValues, RobotSpec};
use egcal::table::parameters::{ModelName, ParamStatus, ParameterSet, from_frame};

use common::tables::{f64s, read, strings};

fn set_of(path: &Path, spec: &RobotSpec, model: ModelName) -> ParameterSet {
    from_frame(&read(path), path, &ParamValues::nominal(spec))
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
    let six = validation_means(&six.join("out/panda_sim"));
    println!("validation means, seven joints {seven:?}, six joints {six:?}");
    let (eg7, eg6) = (seven["elastogeometric"], six["elastogeometric"]);
    assert!(
        eg7 <= 1.5 * eg6,
        "{eg7} mm against the six-joint arm's {eg6} mm"
    );
    assert!(seven["nominal"] > 10.0 * eg7, "{seven:?}");
    assert!(seven["kinematic"] > 2.0 * eg7, "{seven:?}");
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
    let (code, output, _) = common::stage(dir.path(), &panda, "poses", "", &[]);
    assert_eq!(code, 2, "{output}");
    assert!(
        output.contains("panda.toml")
            && output.contains("7 joints")
            && output.contains("inverse kinematics"),
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
    let irb = common::root().join("jobs/robots/irb1600_145.toml");
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
