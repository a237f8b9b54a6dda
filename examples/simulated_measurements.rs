//! Writes a `measurements` table of simulated rows, for measuring `egcal stage
//! identify` on large inputs (README, performance):
//! `cargo run --release --example simulated_measurements -- 1000000 /tmp/m1m.parquet`.
//!
//! Rows as in `benches/identify.rs`: random joints within the limits and wrenches
//! within the paper's ±120 N, ±10 N·m, measured on the simulator (truth = spec
//! Table II, default noise).

use std::path::{Path, PathBuf};

use egcal::rig::Rig;
use egcal::rig::simulator::{Simulator, SimulatorSettings};
use egcal::robot::{ParamValues, Robot, RobotSpec};
use egcal::table::schema::{JOINT_COLUMNS, POSITION_COLUMNS, WRENCH_COLUMNS};
use egcal::table::{frame, write_parquet};
use polars::prelude::Column;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let usage = "usage: simulated_measurements ROWS OUT.parquet";
    let rows: usize = args.next().ok_or(usage)?.parse()?;
    let out = PathBuf::from(args.next().ok_or(usage)?);
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let spec = RobotSpec::load(&root.join("jobs/robots/irb1600_145.toml"))?;
    let truth = ParamValues::load_overrides(&spec, &root.join("jobs/truth/irb1600_paper.toml"))?;
    let robot = Robot::new(spec);
    let mut rig = Simulator::new(robot.clone(), truth, SimulatorSettings::default(), 5)?;
    let mut rng = StdRng::seed_from_u64(1);
    // Columns: cw_id, six joints, six wrench components, three positions.
    let mut values: Vec<Vec<f64>> = (0..15).map(|_| Vec::with_capacity(rows)).collect();
    for k in 0..rows {
        let q_deg: [f64; 6] = std::array::from_fn(|i| {
            let [lo, hi] = robot.joint_limits(i);
            rng.random_range(lo..hi)
        });
        let wrench: [f64; 6] = std::array::from_fn(|i| {
            let bound = if i < 3 { 120.0 } else { 10.0 };
            rng.random_range(-bound..bound)
        });
        rig.move_joints(k as i64, egcal::robot::joint_array(&q_deg))?;
        rig.apply_wrench(wrench)?;
        let read_wrench = rig.read_wrench()?;
        // Six joints: the rig reports MAX_JOINTS, zero beyond the arm's.
        let read_q = rig.read_joints()?;
        let position = rig.measure()?;
        rig.release_wrench()?;
        for (column, value) in values
            .iter_mut()
            .zip(read_q[..6].iter().chain(&read_wrench).chain(&position))
        {
            column.push(*value);
        }
    }
    let mut columns = vec![Column::new(
        "cw_id".into(),
        (1..=rows as i64).collect::<Vec<i64>>(),
    )];
    let names = JOINT_COLUMNS
        .iter()
        .chain(WRENCH_COLUMNS.iter())
        .chain(POSITION_COLUMNS.iter());
    for (name, column) in names.zip(values) {
        columns.push(Column::new((*name).into(), column));
    }
    write_parquet(&mut frame(columns), &out, None)?;
    println!("wrote {rows} rows to {}", out.display());
    Ok(())
}
