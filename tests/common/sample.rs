//! The spec's robot with its truth, and random conf-wrench rows: the setup the
//! identification tests and the benchmarks share (benches include this file by
//! path, as they cannot see `tests/common`'s module).

use std::path::Path;

use egcal::robot::{ConfWrench, ParamValues, Robot, RobotSpec, Wrench};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// The IRB 1600 of `jobs/robots/` and the spec's truth (`jobs/truth/`).
pub fn robot_and_truth() -> (Robot, ParamValues) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let spec = RobotSpec::load(&root.join("jobs/robots/irb1600_145.toml")).expect("robot file");
    let truth = ParamValues::load_overrides(&spec, &root.join("jobs/truth/irb1600_paper.toml"))
        .expect("truth");
    (Robot::new(spec), truth)
}

/// Random rows within the joint limits, wrenches within the paper's ±120 N, ±10 N·m.
pub fn random_rows(robot: &Robot, seed: u64, n: usize) -> Vec<ConfWrench> {
    let mut rng = StdRng::seed_from_u64(seed);
    (0..n)
        .map(|_| ConfWrench {
            q_deg: robot.joint_vector(|i| {
                let [lo, hi] = robot.joint_limits(i);
                rng.random_range(lo..hi)
            }),
            wrench: Wrench::from_array(std::array::from_fn(|i| {
                let bound = if i < 3 { 120.0 } else { 10.0 };
                rng.random_range(-bound..bound)
            })),
            target: 0,
            approach: [0; 7],
            track_mm: 0.0,
            positioner_deg: None,
        })
        .collect()
}
