//! Benchmarks of identification and the simulated campaign (issue #5):
//! identification of 50 measured rows with 32 identifiable parameters (target
//! < 5 ms) and the in-process simulator over 875 conf-wrench rows (target < 0.2 s),
//! both without Parquet I/O; and identification at scale (issue #7): 1 000 000
//! simulated rows, 32 of 42 parameters (target < 10 s on a 2-core machine). Run:
//! `CARGO_TARGET_DIR=/tmp/egcal-release-identify cargo bench --bench identify`
//! (the large case alone: add `-- 1000000`).

use std::cell::OnceCell;
use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use criterion::{BatchSize, Criterion, criterion_group, criterion_main};
use egcal::calibration::fit::{Algorithm, FitOptions, Observations};
use egcal::calibration::{CalibrationOptions, calibrate};
use egcal::cdpr::CableRobotSpec;
use egcal::rig::Rig;
use egcal::rig::simulator::{Simulator, SimulatorSettings};
use egcal::robot::{ConfWrench, ParamId, ParamValues, Robot, Wrench};
use egcal::stages::measure::{MeasureSettings, MeasureStage};
use egcal::stages::{InputTable, NoProgress, Stage, StageContext};
use egcal::table::frame;
use egcal::table::parameters::ModelName;
use egcal::table::schema::{JOINT_COLUMNS, WRENCH_COLUMNS};
use nalgebra::Vector3;
use polars::prelude::Column;

#[path = "../tests/common/sample.rs"]
mod sample;
use sample::{random_rows, robot_and_truth};

fn wrench_array(w: &Wrench) -> [f64; 6] {
    [
        w.force_n.x,
        w.force_n.y,
        w.force_n.z,
        w.moment_nm.x,
        w.moment_nm.y,
        w.moment_nm.z,
    ]
}

/// Measures every row on the simulator (the rig's own sequence of calls) and
/// returns the rows as read back (encoders, sensor) with the tracker positions.
fn campaign(
    robot: &Robot,
    truth: &ParamValues,
    rows: &[ConfWrench],
) -> (Vec<ConfWrench>, Vec<Vector3<f64>>) {
    let mut rig = Simulator::new(robot.clone(), *truth, SimulatorSettings::default(), 5)
        .expect("default simulator settings");
    let mut read = Vec::with_capacity(rows.len());
    let mut measured = Vec::with_capacity(rows.len());
    for (k, row) in rows.iter().enumerate() {
        rig.move_joints(k as i64, row.q_deg).expect("move");
        rig.apply_wrench(wrench_array(&row.wrench)).expect("wrench");
        let wrench = rig.read_wrench().expect("sensor");
        let q_deg = rig.read_joints().expect("encoders");
        let p = rig.measure().expect("tracker");
        rig.release_wrench().expect("release");
        read.push(ConfWrench {
            q_deg,
            wrench: Wrench::from_array(wrench),
            target: 0,
            approach: [0; egcal::robot::MAX_JOINTS],
            track_mm: 0.0,
            positioner_deg: None,
        });
        measured.push(Vector3::from(p));
    }
    (read, measured)
}

fn identify(c: &mut Criterion) {
    let (robot, truth) = robot_and_truth();
    let (rows, measured) = campaign(&robot, &truth, &random_rows(&robot, 1, 50));
    for (name, algorithm) in [
        ("levenberg-marquardt", Algorithm::LevenbergMarquardt),
        ("paper", Algorithm::Paper),
    ] {
        let options = CalibrationOptions::new(
            ParamId::all().collect(),
            FitOptions {
                algorithm,
                ..FitOptions::default()
            },
        );
        let check = calibrate(
            &robot,
            ModelName::Elastogeometric,
            &Observations::new(&rows, &measured),
            &ParamValues::nominal(robot.spec()),
            &options,
        )
        .expect("identifiable");
        assert_eq!(check.rank.as_ref().map(|r| r.independent.len()), Some(32));
        assert!(check.converged);
        c.bench_function(
            &format!("identify elastogeometric, 50 rows, 32 of 42 parameters, {name}"),
            |b| {
                b.iter(|| {
                    calibrate(
                        &robot,
                        ModelName::Elastogeometric,
                        &Observations::new(&rows, &measured),
                        &ParamValues::nominal(robot.spec()),
                        &options,
                    )
                })
            },
        );
    }
    let options = CalibrationOptions::new(ParamId::all().collect(), FitOptions::default());
    c.bench_function("identify all four models, 50 rows", |b| {
        b.iter(|| {
            ModelName::ALL.map(|model| {
                calibrate(
                    &robot,
                    model,
                    &Observations::new(&rows, &measured),
                    &ParamValues::nominal(robot.spec()),
                    &options,
                )
            })
        })
    });
}

/// Rows of the large case.
const LARGE_ROWS: usize = 1_000_000;

/// The elasto-geometric identification of a million simulated rows, as `identify`
/// runs it (rank analysis of the 42 candidates at nominal, Levenberg–Marquardt on
/// the 32 identifiable, standard errors): every pass over the rows streamed in
/// chunks, never the 3·10⁶ × 42 Jacobian. The rows are simulated (about 2 s) and
/// checked once, and only when this benchmark is selected.
fn identify_large(c: &mut Criterion) {
    let (robot, truth) = robot_and_truth();
    let options = CalibrationOptions::new(ParamId::all().collect(), FitOptions::default());
    let data = OnceCell::new();
    let prepare = || {
        let started = Instant::now();
        let (rows, measured) = campaign(&robot, &truth, &random_rows(&robot, 1, LARGE_ROWS));
        let simulated_s = started.elapsed().as_secs_f64();
        let started = Instant::now();
        let check = calibrate(
            &robot,
            ModelName::Elastogeometric,
            &Observations::new(&rows, &measured),
            &ParamValues::nominal(robot.spec()),
            &options,
        )
        .expect("identifiable");
        let once_s = started.elapsed().as_secs_f64();
        assert_eq!(check.rank.as_ref().map(|r| r.independent.len()), Some(32));
        assert!(check.converged);
        let diagnostics = check.diagnostics.as_ref().expect("fitted");
        let rms_mm = (check
            .residuals_mm
            .iter()
            .map(|r| r.norm_squared())
            .sum::<f64>()
            / (3 * LARGE_ROWS) as f64)
            .sqrt();
        println!(
            "summary: {LARGE_ROWS} rows simulated in {simulated_s:.1} s; one identification \
             {once_s:.2} s, {} steps ({}), condition number {:.1}, residual rms {rms_mm:.4} mm",
            check.trace.len(),
            diagnostics.stop.as_str(),
            diagnostics.condition_number,
        );
        (rows, measured)
    };
    c.bench_function(
        "identify elastogeometric, 1000000 rows, 32 of 42 parameters",
        |b| {
            let (rows, measured) = data.get_or_init(prepare);
            b.iter(|| {
                calibrate(
                    &robot,
                    ModelName::Elastogeometric,
                    &Observations::new(rows, measured),
                    &ParamValues::nominal(robot.spec()),
                    &options,
                )
            })
        },
    );
}

fn simulate(c: &mut Criterion) {
    let (robot, truth) = robot_and_truth();
    let rows = random_rows(&robot, 1, 875);
    c.bench_function("simulator rig, 875 rows", |b| {
        b.iter(|| campaign(&robot, &truth, &rows))
    });
}

/// The whole measure stage on an in-memory table: rig plus journal (one fsync per
/// row, which dominates: about 3.5 ms each on this machine's disk), no Parquet.
fn measure_stage(c: &mut Criterion) {
    let (robot, _) = robot_and_truth();
    let rows = random_rows(&robot, 1, 875);
    let mut columns = vec![Column::new("cw_id".into(), (1..=875).collect::<Vec<i64>>())];
    for (i, name) in JOINT_COLUMNS.iter().enumerate() {
        columns.push(Column::new(
            (*name).into(),
            rows.iter().map(|r| r.q_deg[i]).collect::<Vec<f64>>(),
        ));
    }
    for (i, name) in WRENCH_COLUMNS.iter().enumerate() {
        columns.push(Column::new(
            (*name).into(),
            rows.iter()
                .map(|r| wrench_array(&r.wrench)[i])
                .collect::<Vec<f64>>(),
        ));
    }
    let mut inputs = BTreeMap::new();
    inputs.insert(
        "conf_wrenches".to_string(),
        InputTable {
            path: "conf_wrenches.parquet".into(),
            df: frame(columns),
        },
    );
    let cable_robot = CableRobotSpec::default();
    let settings = MeasureSettings::default();
    c.bench_function(
        "measure stage on the simulator, 875 rows, with journal",
        |b| {
            b.iter_batched(
                || tempfile::tempdir().expect("temporary folder"),
                |work| {
                    let ctx = StageContext {
                        robot: &robot,
                        cable_robot: &cable_robot,
                        seed: 5,
                        inputs: &inputs,
                        work_dir: work.path(),
                        job_dir: work.path(),
                        run_date: 0,
                        progress: &NoProgress,
                    };
                    let outputs = MeasureStage.run(&ctx, &settings).expect("campaign");
                    (outputs, work)
                },
                BatchSize::PerIteration,
            )
        },
    );
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = identify, simulate
}
criterion_group! {
    name = slow;
    config = Criterion::default().sample_size(10);
    targets = measure_stage
}
criterion_group! {
    name = large;
    config = Criterion::default()
        .sample_size(10)
        .measurement_time(Duration::from_secs(70));
    targets = identify_large
}
criterion_main!(benches, slow, large);
