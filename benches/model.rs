//! Benchmarks of the model core (issue: predict + Jacobian for 875 rows and 32
//! parameters on one core; closed-form IK throughput). Run: `cargo bench --bench model`.

use criterion::{Criterion, criterion_group, criterion_main};
use egcal::robot::Selection;
use egcal::robot::ik::closed_form;
use nalgebra::Vector3;

#[path = "../tests/common/sample.rs"]
mod sample;
use sample::{random_rows, robot_and_truth};

fn model(c: &mut Criterion) {
    let (robot, truth) = robot_and_truth();
    let rows = random_rows(&robot, 1, 875);
    let selection = Selection::spec_identifiable();
    let mut columns = vec![Vector3::zeros(); selection.len()];
    c.bench_function("predict+jacobian 875 rows x 32 params, one core", |b| {
        b.iter(|| {
            let prepared = robot.prepare(&truth);
            let mut sum = 0.0;
            for row in &rows {
                let p = prepared.jacobian_row(row, selection.ids(), &mut columns);
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
