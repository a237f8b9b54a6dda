//! Writing a `targets` table in a test: poses as the table gives them.

use std::path::Path;

use egcal::robot::Frame;
use polars::prelude::{Column, DataFrame};

/// (rx, ry, rz) deg with rotation = Rot(x, rx)·Rot(y, ry)·Rot(z, rz), the
/// `targets` table's orientation.
pub fn xyz_euler_deg(frame: &Frame) -> [f64; 3] {
    let r = &frame.rotation;
    let ry = r[(0, 2)].clamp(-1.0, 1.0).asin();
    let rx = (-r[(1, 2)]).atan2(r[(2, 2)]);
    let rz = (-r[(0, 1)]).atan2(r[(0, 0)]);
    [rx.to_degrees(), ry.to_degrees(), rz.to_degrees()]
}

/// A `targets` table of `poses` (ids 1..), with extra columns.
pub fn write_targets(path: &Path, poses: &[Frame], extra: Vec<Column>) {
    let n = poses.len();
    let mut columns = vec![Column::new(
        "target_id".into(),
        (1..=n as i64).collect::<Vec<_>>(),
    )];
    for (axis, name) in ["x_mm", "y_mm", "z_mm"].iter().enumerate() {
        columns.push(Column::new(
            (*name).into(),
            poses.iter().map(|p| p.origin_mm[axis]).collect::<Vec<_>>(),
        ));
    }
    for (axis, name) in ["rx_deg", "ry_deg", "rz_deg"].iter().enumerate() {
        columns.push(Column::new(
            (*name).into(),
            poses
                .iter()
                .map(|p| xyz_euler_deg(p)[axis])
                .collect::<Vec<_>>(),
        ));
    }
    columns.extend(extra);
    let mut df = DataFrame::new(n, columns).unwrap();
    egcal::table::write_parquet(&mut df, path, None).unwrap();
}
