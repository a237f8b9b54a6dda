//! Simulated measurements for the identification tests: exact positions of a
//! parameter set, tracker noise, and the rows written as a `measurements` table.

use std::path::Path;

use egcal::robot::{ConfWrench, ParamValues, Robot};
use egcal::table::{self, schema};
use nalgebra::Vector3;
use polars::prelude::Column;
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, Normal};

/// The SMR positions of `p` for `rows` (mm, world frame).
pub fn positions(robot: &Robot, p: &ParamValues, rows: &[ConfWrench]) -> Vec<Vector3<f64>> {
    egcal::robot::batch_predict(robot, p, rows)
        .iter()
        .map(|p| p.position_mm)
        .collect()
}

/// Exact positions plus Gaussian tracker noise (mm per axis).
pub fn noisy(exact: &[Vector3<f64>], sigma_mm: f64, seed: u64) -> Vec<Vector3<f64>> {
    let mut rng = StdRng::seed_from_u64(seed);
    let normal = Normal::new(0.0, sigma_mm).unwrap();
    exact
        .iter()
        .map(|p| p + Vector3::from_fn(|_, _| normal.sample(&mut rng)))
        .collect()
}

/// `rows` and `measured` as a `measurements` table at `path`, cw_id `first_id`, `first_id + 1`, ….
pub fn write_measurements(
    path: &Path,
    rows: &[ConfWrench],
    measured: &[Vector3<f64>],
    first_id: i64,
) {
    let ids: Vec<i64> = (first_id..first_id + rows.len() as i64).collect();
    let mut columns = vec![Column::new("cw_id".into(), ids)];
    for (i, name) in schema::JOINT_COLUMNS.iter().enumerate() {
        let values: Vec<f64> = rows.iter().map(|r| r.q_deg[i]).collect();
        columns.push(Column::new((*name).into(), values));
    }
    for (i, name) in schema::WRENCH_COLUMNS.iter().enumerate() {
        let values: Vec<f64> = rows
            .iter()
            .map(|r| {
                if i < 3 {
                    r.wrench.force_n[i]
                } else {
                    r.wrench.moment_nm[i - 3]
                }
            })
            .collect();
        columns.push(Column::new((*name).into(), values));
    }
    for (axis, name) in schema::POSITION_COLUMNS.iter().enumerate() {
        let values: Vec<f64> = measured.iter().map(|p| p[axis]).collect();
        columns.push(Column::new((*name).into(), values));
    }
    // Rows of a robot on a track carry their carriage positions.
    if rows.iter().any(|r| r.track_mm != 0.0) {
        let values: Vec<f64> = rows.iter().map(|r| r.track_mm).collect();
        columns.push(Column::new(schema::TRACK_COLUMN.into(), values));
    }
    table::write_parquet(&mut table::frame(columns), path, None).unwrap();
}
