//! Benchmarks of the model core (issue: predict + Jacobian for 875 rows and 32
//! parameters on one core; closed-form IK throughput). Run: `cargo bench --bench model`.

use std::path::Path;

use criterion::{Criterion, criterion_group, criterion_main};
use egcal::robot::ik::closed_form;
use egcal::robot::{ConfWrench, ParamValues, Robot, RobotSpec, Selection, Wrench};
use nalgebra::Vector3;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

fn robot() -> (Robot, ParamValues) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let spec = RobotSpec::load(&root.join("jobs/robots/irb1600_145.toml")).expect("robot file");
    let truth = ParamValues::load_overrides(&spec, &root.join("jobs/truth/irb1600_paper.toml"))
        .expect("truth");
    (Robot::new(spec), truth)
}

fn rows(robot: &Robot, n: usize) -> Vec<ConfWrench> {
    let mut rng = StdRng::seed_from_u64(1);
    (0..n)
        .map(|_| ConfWrench {
            q_deg: std::array::from_fn(|i| {
                let [lo, hi] = robot.limits_deg(i);
                rng.random_range(lo..hi)
            }),
            wrench: Wrench::from_array(std::array::from_fn(|i| {
                let bound = if i < 3 { 120.0 } else { 10.0 };
                rng.random_range(-bound..bound)
            })),
        })
        .collect()
}

fn model(c: &mut Criterion) {
    let (robot, truth) = robot();
    let rows = rows(&robot, 875);
    let selection = Selection::spec_identifiable();
    let mut columns = vec![Vector3::zeros(); selection.len()];
    c.bench_function("predict+jacobian 875 rows x 32 params, one core", |b| {
        b.iter(|| {
            let prepared = robot.prepare(&truth);
            let mut sum = 0.0;
            for row in &rows {
                let p =
                    prepared.jacobian_row(&row.q_deg, &row.wrench, selection.ids(), &mut columns);
                sum += p.position_mm.x + columns[0].x;
            }
            sum
        })
    });
    let poses: Vec<_> = rows
        .iter()
        .map(|r| robot.nominal_flange_in_base(&r.q_deg))
        .collect();
    c.bench_function("closed-form IK, 875 poses", |b| {
        b.iter(|| {
            poses
                .iter()
                .map(|p| closed_form(&robot, p).map_or(0, |s| s.len()))
                .sum::<usize>()
        })
    });
}

criterion_group!(benches, model);
criterion_main!(benches);
