//! Benchmark of the numeric inverse kinematics on an arm without a closed form:
//! every configuration of the UR10 (`jobs/robots/ur10.toml`) for random reachable
//! flange poses (forward kinematics of random joint vectors within the limits),
//! with the default 64 starts. Run:
//! `CARGO_TARGET_DIR=/tmp/egcal-release cargo bench --bench ik`.

use std::path::Path;

use criterion::{Criterion, criterion_group, criterion_main};
use egcal::robot::ik::{NumericIkOptions, numeric};
use egcal::robot::{Robot, RobotSpec};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

const POSES: usize = 100;

fn ik(c: &mut Criterion) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let robot = Robot::new(RobotSpec::load(&root.join("jobs/robots/ur10.toml")).expect("UR10"));
    let mut rng = StdRng::seed_from_u64(1);
    let poses: Vec<_> = (0..POSES)
        .map(|_| {
            let q = robot.joint_vector(|i| {
                let [lo, hi] = robot.joint_limits(i);
                rng.random_range(lo..hi)
            });
            robot.nominal_flange_in_base(&q)
        })
        .collect();
    let options = NumericIkOptions::default();
    let configurations: usize = poses
        .iter()
        .map(|p| numeric(&robot, p, &options).len() / 64)
        .sum();
    println!(
        "summary: {POSES} UR10 poses, {:.2} configurations per pose (each in 64 turns within ±360°)",
        configurations as f64 / POSES as f64
    );
    c.bench_function(
        "numeric IK, UR10, 100 random reachable poses, 64 starts",
        |b| {
            b.iter(|| {
                poses
                    .iter()
                    .map(|p| numeric(&robot, p, &options).len())
                    .sum::<usize>()
            })
        },
    );
}

criterion_group!(benches, ik);
criterion_main!(benches);
