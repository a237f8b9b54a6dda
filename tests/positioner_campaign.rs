//! A robot with a two-axis positioner, through the whole campaign (issue
//! #30): `jobs/positioner_sim.toml` adds the positioner's nests to the
//! arm's candidates (`nest_poses`), analyses and selects them with a
//! translation per SMR, measures them on the simulator turning the table,
//! calibrates arm, positioner and nests together, validates on the rows
//! not used, and compensates work given on the table into programs that
//! move the positioner. The nests are recovered, the positioner's base
//! lands where the truth's is in the tracker's frame, the positioner taken
//! as drawn is several times worse on the held-out nests, and the
//! compensated commands reach the table's targets where the true table
//! holds them.

mod common;

use std::collections::{BTreeMap, HashSet};
use std::path::{Path, PathBuf};

use egcal::robot::positioner::{PositionerModel, PositionerTerm};
use egcal::robot::{ConfWrench, ParamId, ParamValues, Robot, RobotSpec, Wrench};
use egcal::table::parameters::{ModelName, ParameterSet, from_frame};
use egcal::table::schema;
use polars::prelude::{Column, DataFrame};

use common::tables::{f64s, i64s, read, strings};

const NESTS: [&str; 3] = ["table_a", "table_b", "table_c"];

/// The elastogeometric set of a parameters table.
fn elastogeometric(path: &Path, spec: &RobotSpec) -> ParameterSet {
    from_frame(&read(path), path, spec)
        .unwrap()
        .into_iter()
        .find(|s| s.model == ModelName::Elastogeometric)
        .expect("an elastogeometric set")
}

/// Mean validation error (mm) of the elastogeometric model on the rows of
/// the nests and on the arm's.
fn nest_and_arm_errors(out: &Path, stage: &str, target_of: &BTreeMap<i64, String>) -> (f64, f64) {
    let errors = read(&out.join(stage).join("errors.parquet"));
    let (mut nests, mut arm) = (Vec::new(), Vec::new());
    for ((id, model), e) in i64s(&errors, "cw_id")
        .into_iter()
        .zip(strings(&errors, "model"))
        .zip(f64s(&errors, "error_mm"))
    {
        if model == "elastogeometric" {
            match target_of[&id].as_str() {
                "arm" => arm.push(e),
                _ => nests.push(e),
            }
        }
    }
    assert!(
        !nests.is_empty() && !arm.is_empty(),
        "{stage}: rows of both"
    );
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    (mean(&nests), mean(&arm))
}

/// How far (mm) the true arm puts the SMR under each command from where the
/// true table holds the command's target (a point given on the table at the
/// command's axes).
fn work_errors_mm(
    robot: &Robot,
    truth: &ParamValues,
    work: &DataFrame,
    commands: &DataFrame,
) -> Vec<f64> {
    let q: Vec<Vec<f64>> = schema::JOINT_COLUMNS
        .iter()
        .map(|c| f64s(commands, c))
        .collect();
    let axes = [f64s(work, "p1_deg"), f64s(work, "p2_deg")];
    let on_table = [f64s(work, "x_mm"), f64s(work, "y_mm"), f64s(work, "z_mm")];
    (0..commands.height())
        .map(|k| {
            let command = ConfWrench::new(
                std::array::from_fn(|i| q.get(i).map_or(0.0, |c| c[k])),
                Wrench::zero(),
            );
            let reached = common::measured::positions(robot, truth, &[command])[0];
            // The target as a nest of the truth.
            let mut held_by_table = *truth;
            for (axis, values) in on_table.iter().enumerate() {
                held_by_table.set(ParamId::target_translation(1, axis), values[k]);
            }
            let held_at = ConfWrench {
                target: 1,
                positioner_deg: Some([axes[0][k], axes[1][k]]),
                ..ConfWrench::new([0.0; 7], Wrench::zero())
            };
            let target = common::measured::positions(robot, &held_by_table, &[held_at])[0];
            (reached - target).norm()
        })
        .collect()
}

#[test]
fn the_positioner_campaign_designs_measures_calibrates_and_compensates_the_cell() {
    let dir = tempfile::tempdir().unwrap();
    // The work compensated with the drawn cell too, to compare.
    let job = common::shipped_job_in(dir.path(), "positioner_sim", |text| {
        let targets = common::root().join("jobs/targets/positioner_work.parquet");
        format!(
            "{text}\n[[stages]]\nid = \"nominal_work\"\nkind = \"compensate\"\ninputs = {{ targets = \"{}\" }}\nmodel = \"nominal\"\ntool = \"arm\"\n",
            targets.display()
        )
    });
    let (code, stdout, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 0, "{stdout}\n{stderr}");
    let out = dir.path().join("out/positioner_sim");
    let spec =
        RobotSpec::load(&common::root().join("jobs/robots/irb1600_145_positioner.toml")).unwrap();
    let robot = Robot::new(spec.clone());

    // The nests join the arm's candidates: 40 configurations each within the
    // axes' limits, the arm parked at zero without a wrench; the arm's rows
    // keep their ids.
    let arm_candidates = read(&out.join("wrenches/candidates.parquet"));
    let candidates = read(&out.join("nests/candidates.parquet"));
    let targets = strings(&candidates, "target_id");
    let arm_rows = arm_candidates.height();
    assert_eq!(
        i64s(&candidates, "cw_id")[..arm_rows],
        i64s(&arm_candidates, "cw_id")
    );
    assert!(targets[..arm_rows].iter().all(|t| t == "arm"));
    let p1 = schema::optional_f64_values(&candidates, "p1_deg", Path::new("p1"))
        .unwrap()
        .unwrap();
    for nest in NESTS {
        let rows: Vec<usize> = (0..targets.len()).filter(|k| targets[*k] == nest).collect();
        assert_eq!(rows.len(), 40, "{nest}");
        for k in rows {
            let tilt = p1[k].expect("a nest row has its tilt");
            assert!((-90.0..=90.0).contains(&tilt));
            assert_eq!(f64s(&candidates, "q2_deg")[k], 0.0);
            assert_eq!(f64s(&candidates, "fz_n")[k], 0.0);
        }
    }

    // The rank analysis names each SMR's translation and finds the
    // positioner's base and the turn axis's twist and offset identifiable.
    let identifiability = read(&out.join("identifiability/identifiability.parquet"));
    let identifiable: HashSet<String> = strings(&identifiability, "name")
        .into_iter()
        .zip(
            identifiability
                .column("identifiable")
                .unwrap()
                .bool()
                .unwrap()
                .iter(),
        )
        .filter_map(|(name, ok)| (ok == Some(true)).then_some(name))
        .collect();
    for name in [
        "x_t[arm]",
        "z_t[table_a]",
        "y_t[table_c]",
        "x_p",
        "gamma_p",
        "dalpha_p2",
        "da_p2",
    ] {
        assert!(identifiable.contains(name), "{name}: {identifiable:?}");
    }

    // DETMAX calibrates on rows of every nest and leaves some of each to
    // validate on.
    let measured = read(&out.join("measure/measurements.parquet"));
    let target_of: BTreeMap<i64, String> = i64s(&measured, "cw_id")
        .into_iter()
        .zip(strings(&measured, "target_id"))
        .collect();
    let selection = read(&out.join("select/selection.parquet"));
    for nest in NESTS {
        let roles: HashSet<String> = i64s(&selection, "cw_id")
            .iter()
            .zip(strings(&selection, "role"))
            .filter(|(id, _)| target_of[id] == nest)
            .map(|(_, role)| role)
            .collect();
        assert_eq!(roles.len(), 2, "{nest}: {roles:?}");
    }
    // The work's envelope is the arm's calibration rows: the nests' rows,
    // with the arm parked and its SMR unmeasured, are not in it.
    let arm_calibration_rows = i64s(&selection, "cw_id")
        .iter()
        .zip(strings(&selection, "role"))
        .filter(|(id, role)| role == "calibration" && target_of[id] == "arm")
        .count();
    assert!(
        stderr.contains(&format!("envelope_rows={arm_calibration_rows} ")),
        "{arm_calibration_rows} arm calibration rows: {stderr}"
    );
    // The job accepts the work beyond the default envelope, and says so.
    assert!(
        stderr.contains("warning: 27 ok command(s) lie more than 40 deg (the default envelope)"),
        "{stderr}"
    );

    // The nests are recovered within two standard errors; the positioner's
    // base lands where the truth's is in the tracker's frame (the robot's
    // base itself is only known up to the arm's dependent terms).
    let truth = elastogeometric(
        &common::root().join("jobs/truth/irb1600_positioner.parquet"),
        &spec,
    );
    let fit = elastogeometric(&out.join("identify/parameters.parquet"), &spec);
    for (slot, _) in NESTS.iter().enumerate() {
        for axis in 0..3 {
            let id = ParamId::target_translation(slot + 1, axis);
            let se = fit.std_errors[id.index()].expect("a nest translation's std error");
            let off = fit.values.get(id) - truth.values.get(id);
            assert!(
                off.abs() < 2.0 * se,
                "{}: off {off} mm, se {se}",
                fit.name_of(id)
            );
        }
    }
    for name in ["dalpha_p2", "da_p2"] {
        let id = ParamId::from_name(name).unwrap();
        let se = fit.std_errors[id.index()].expect("std error");
        let off = fit.values.get(id) - truth.values.get(id);
        assert!(off.abs() < 2.0 * se, "{name}: off {off}, se {se}");
    }
    let world_from_positioner = |values: &ParamValues| {
        let slots = std::array::from_fn(|slot| {
            values.get(ParamId::positioner(PositionerTerm::of_slot(slot)))
        });
        let positioner = PositionerModel::new(spec.positioner.as_ref().unwrap(), &slots);
        robot.world_from_base(values).compose(&positioner.base())
    };
    let (fitted, true_base) = (
        world_from_positioner(&fit.values),
        world_from_positioner(&truth.values),
    );
    let base_off_mm = (fitted.origin_mm - true_base.origin_mm).norm();
    let base_turn_deg = fitted.angle_to(&true_base).to_degrees();
    eprintln!(
        "positioner base in the world: {base_off_mm:.4} mm, {base_turn_deg:.4} deg from the truth's"
    );
    assert!(base_off_mm < 0.1 && base_turn_deg < 0.01);

    // Held-out nests: the joint fit within the tracker's noise, several
    // times better than the positioner as drawn; the arm's rows alike.
    let (joint_nests, joint_arm) = nest_and_arm_errors(&out, "validate", &target_of);
    let (drawn_nests, drawn_arm) =
        nest_and_arm_errors(&out, "validate_positioner_as_drawn", &target_of);
    eprintln!(
        "held-out nests: joint {joint_nests:.4} mm, as drawn {drawn_nests:.4} mm; arm: {joint_arm:.4}, {drawn_arm:.4} mm"
    );
    assert!(joint_nests < 0.05, "{joint_nests}");
    assert!(drawn_nests > 3.0 * joint_nests);
    assert!((joint_arm - drawn_arm).abs() < 0.02);

    // The work on the table: every command ok, with its target's axes, and
    // the true arm puts the SMR near where the true table holds the target,
    // several times nearer than the drawn cell's commands. (The work's
    // wrists lie outside the campaign's envelope, where the fitted arm is
    // about 0.4 mm off: the job's comment says so.)
    let work = read(&common::root().join("jobs/targets/positioner_work.parquet"));
    let commands = read(&out.join("compensate_work/commands.parquet"));
    assert!(strings(&commands, "status").iter().all(|s| s == "ok"));
    let axes = [f64s(&commands, "p1_deg"), f64s(&commands, "p2_deg")];
    assert_eq!(axes[0], f64s(&work, "p1_deg"));
    assert_eq!(axes[1], f64s(&work, "p2_deg"));
    let compensated = work_errors_mm(&robot, &truth.values, &work, &commands);
    let drawn = work_errors_mm(
        &robot,
        &truth.values,
        &work,
        &read(&out.join("nominal_work/commands.parquet")),
    );
    let worst = |e: &[f64]| e.iter().copied().fold(0.0, f64::max);
    let mean = |e: &[f64]| e.iter().sum::<f64>() / e.len() as f64;
    eprintln!(
        "work on the table, from the true table's targets: compensated mean {:.4} max {:.4} mm; drawn cell mean {:.4} max {:.4} mm",
        mean(&compensated),
        worst(&compensated),
        mean(&drawn),
        worst(&drawn)
    );
    assert!(worst(&compensated) < 0.6, "{compensated:?}");
    assert!(mean(&drawn) > 5.0 * mean(&compensated));

    // The programs move the positioner to each target's axes.
    let csv = std::fs::read_to_string(out.join("export_work/commands.csv")).unwrap();
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let column = |name: &str| header.iter().position(|h| *h == name).unwrap();
    for (k, line) in csv.lines().skip(1).enumerate() {
        let cells: Vec<&str> = line.split(',').collect();
        let p1: f64 = cells[column("p1_deg")].parse().unwrap();
        assert!((p1 - axes[0][k]).abs() < 1e-6, "row {k}: {line}");
    }
}

/// Runs `egcal stage nest_poses` with `settings` on `candidates` for the
/// robot file `robot`: exit code, log, output folder.
fn nest_poses(
    dir: &Path,
    robot: &Path,
    settings: &str,
    candidates: &Path,
) -> (i32, String, PathBuf) {
    common::stage(
        dir,
        robot,
        "nest_poses",
        settings,
        &[("candidates", candidates)],
    )
}

/// Two candidate rows of the arm as `wrenches` writes them.
fn arm_candidates(path: &Path, with_target_id: bool) {
    let mut columns = vec![
        Column::new("cw_id".into(), [4_i64, 9]),
        Column::new("config_id".into(), [1_i64, 2]),
    ];
    for (joint, name) in schema::JOINT_COLUMNS.iter().enumerate() {
        columns.push(Column::new((*name).into(), [10.0 * joint as f64, -5.0]));
    }
    for name in schema::WRENCH_COLUMNS {
        columns.push(Column::new(name.into(), [1.0, -2.0]));
    }
    for name in schema::TENSION_COLUMNS {
        columns.push(Column::new(name.into(), [50.0, 60.0]));
    }
    columns.push(Column::new("margin_n".into(), [12.0, 13.0]));
    if with_target_id {
        columns.push(Column::new("target_id".into(), ["arm", "arm"]));
    }
    let mut df = egcal::table::frame(columns);
    egcal::table::write_parquet(&mut df, path, None).unwrap();
}

/// `nest_poses` appends each nest's rows after the arm's with new ids, and
/// refuses, naming the setting or the file, what it cannot do.
#[test]
fn nest_poses_adds_the_nests_and_refuses_what_it_cannot_do() {
    let dir = tempfile::tempdir().unwrap();
    let robot = common::root().join("jobs/robots/irb1600_145_positioner.toml");
    let candidates = dir.path().join("candidates.parquet");
    arm_candidates(&candidates, false);

    let (code, log, out) = nest_poses(dir.path(), &robot, "per_nest = 3\n", &candidates);
    assert_eq!(code, 0, "{log}");
    let table = read(&out.join("candidates.parquet"));
    assert_eq!(
        i64s(&table, "cw_id"),
        [4, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18]
    );
    assert_eq!(i64s(&table, "config_id")[2], 3);
    let targets = strings(&table, "target_id");
    assert_eq!(&targets[..3], ["arm", "arm", "table_a"]);
    assert_eq!(targets.iter().filter(|t| *t == "table_c").count(), 3);
    let tension = table.column("tension1_n").unwrap();
    assert_eq!(tension.null_count(), 9, "a nest's row has no cable tension");
    let p2 = schema::optional_f64_values(&table, "p2_deg", Path::new("p2"))
        .unwrap()
        .unwrap();
    assert!(p2[..2].iter().all(Option::is_none) && p2[2..].iter().all(Option::is_some));
    // The arm's rows keep their joints and wrenches; the nests' are parked, unloaded.
    assert_eq!(f64s(&table, "q2_deg")[..3], [10.0, -5.0, 0.0]);
    assert_eq!(f64s(&table, "fx_n")[..3], [1.0, -2.0, 0.0]);

    // The simulated daily check measures the arm's SMR only: a pool with
    // the nests' rows is refused, naming the first.
    let (code, log, _) = common::stage(
        dir.path(),
        &robot,
        "simulate_logs",
        "robot_id = \"cell\"\nfirst_day = \"2026-11-02\"\ndays = 1\nrows_per_day = 2\n",
        &[("conf_wrenches", &out.join("candidates.parquet"))],
    );
    assert_ne!(code, 0, "{log}");
    assert!(log.contains("row 2 (cw_id 10) measures a nest"), "{log}");

    let refusals: [(&Path, &str, &str); 5] = [
        (&robot, "arm_target = \"table_b\"\n", "arm_target"),
        (
            &robot,
            "arm_park_deg = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]\n",
            "7 values for the 6 joints",
        ),
        (
            &robot,
            "arm_park_deg = [0.0, 150.0, 0.0, 0.0, 0.0, 0.0]\n",
            "joint 2",
        ),
        (
            &robot,
            "acceptance_half_angle_deg = 0.5\nmax_draws = 50\n",
            "nest `table_a`",
        ),
        (
            &common::root().join("jobs/robots/irb1600_145.toml"),
            "",
            "has no [positioner]",
        ),
    ];
    for (robot, settings, expected) in refusals {
        let (code, log, _) = nest_poses(dir.path(), robot, settings, &candidates);
        assert_ne!(code, 0, "{settings}: {log}");
        assert!(
            log.contains(expected),
            "{settings}: expected `{expected}` in {log}"
        );
    }
    arm_candidates(&candidates, true);
    let (code, log, _) = nest_poses(dir.path(), &robot, "", &candidates);
    assert_ne!(code, 0, "{log}");
    assert!(log.contains("already name their targets"), "{log}");
}
