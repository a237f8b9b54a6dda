//! DETMAX's candidates as the select stage sees them, for the benchmarks
//! (`benches/detmax.rs`, `examples/detmax_scaling.rs`): random joint
//! configurations within the limits and random wrenches (±120 N, ±10 N·m) of
//! the nominal IRB 1600, the spec's 32 identifiable parameters,
//! `batch_jacobian`, columns scaled to unit norm.

use std::path::Path;

use egcal::design::detmax::Candidates;
use egcal::robot::{ConfWrench, ParamValues, Robot, RobotSpec, Selection, Wrench, batch_jacobian};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

pub fn candidates(count: usize, seed: u64) -> Candidates {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let spec = RobotSpec::load(&root.join("jobs/robots/irb1600_145.toml")).expect("robot file");
    let nominal = ParamValues::nominal(&spec);
    let robot = Robot::new(spec);
    let mut rng = StdRng::seed_from_u64(seed);
    let rows: Vec<ConfWrench> = (0..count)
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
            approach: [0; egcal::robot::MAX_JOINTS],
            track_mm: 0.0,
            positioner_deg: None,
        })
        .collect();
    let parameters = Selection::spec_identifiable();
    let jacobian = batch_jacobian(&robot, &nominal, &rows, parameters.ids());
    Candidates::from_jacobian(&jacobian.jacobian, count, parameters.len()).0
}
