//! The accuracy map (issue #16): the predicted 95 % position uncertainty over a
//! grid of the workspace the calibration rows covered, and a margin beyond it,
//! so a user sees where the calibration holds and where it extrapolates.
//!
//! The grid spans the bounding box of the calibration rows' tool positions
//! (unloaded, under the calibrated parameters) enlarged by a margin on every
//! side: `points_per_axis` × `points_per_axis` points in each of `slices`
//! horizontal planes (world z) from the bottom to the top of the enlarged box.
//! Each grid point gets the configuration a user would command there: the
//! tool keeps the orientation of the nearest calibration pose (nearest tool
//! position), and of the nominal inverse-kinematics solutions for that tool pose
//! (placed by the set's world and tool frames) the one closest in joint space to
//! that pose's configuration, so the map follows the calibration's branch. The
//! tool carries no external wrench (gravity still loads the arm): the map is of
//! the robot as it moves, not of one load case. On a linear track the grid
//! spans the world positions the rows reached along the travel, and each
//! point is reached with the carriage where its nearest calibration row had
//! it.
//!
//! The uncertainty is [`super::uncertainty::position_covariances`] there, and
//! its summary `u95 = sqrt(χ²₃(0.95)·λ_max)`: the longest semi-axis of the 95 %
//! ellipsoid, the radius of the smallest sphere that holds it. Inverse
//! kinematics is on the nominal arm, so the calibrated tool lies within the
//! calibration's correction (a few mm) of its grid point; the uncertainty varies
//! far more slowly than that.
//!
//! Knows nothing of tables.

use nalgebra::{Matrix3, Vector3};

use super::uncertainty::{chi_squared_3_quantile, position_covariances};
use crate::robot::frame::Frame;
use crate::robot::ik::{self, IkError};
use crate::robot::model::PreparedRobot;
use crate::robot::{ConfWrench, MAX_JOINTS, ParamId, ParamValues, Robot, Wrench};

/// The grid's shape.
#[derive(Debug, Clone, Copy)]
pub struct GridSpec {
    /// Points along world x and along world y in each slice.
    pub points_per_axis: usize,
    /// Horizontal slices (world z levels).
    pub slices: usize,
    /// How far (mm) the grid extends beyond the calibration rows' bounding box
    /// on every side.
    pub margin_mm: f64,
}

/// Why a grid point has no uncertainty.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PointStatus {
    Reachable,
    /// No configuration within the joint limits puts the tool there.
    Unreachable,
    /// The pose is singular for the inverse kinematics.
    Singular,
}

impl PointStatus {
    pub fn as_str(self) -> &'static str {
        match self {
            PointStatus::Reachable => "reachable",
            PointStatus::Unreachable => "unreachable",
            PointStatus::Singular => "singular",
        }
    }
}

/// One grid point of the map.
#[derive(Debug, Clone, PartialEq)]
pub struct MapPoint {
    /// 0-based slice (bottom first).
    pub slice: usize,
    /// The grid point, world frame (mm).
    pub position_mm: Vector3<f64>,
    /// Whether the point lies in the calibration rows' bounding box (not in the margin).
    pub inside_box: bool,
    pub status: PointStatus,
    /// The configuration used, when reachable.
    pub q_deg: Option<[f64; MAX_JOINTS]>,
    /// The carriage position the point is reached from (mm; 0 without a
    /// track): its nearest calibration row's.
    pub track_mm: f64,
    /// `J·Σ·Jᵀ` (mm², world frame), when reachable.
    pub covariance_mm2: Option<Matrix3<f64>>,
}

impl MapPoint {
    /// The point's configuration as an unloaded row, when reachable.
    pub fn row(&self) -> Option<ConfWrench> {
        self.q_deg.map(|q| ConfWrench {
            track_mm: self.track_mm,
            ..ConfWrench::new(q, Wrench::zero())
        })
    }

    /// `sqrt(χ²₃(0.95)·λ_max)` (mm), when reachable.
    pub fn u95_mm(&self) -> Option<f64> {
        self.covariance_mm2.map(|c| u95_mm(&c))
    }
}

/// The radius of the 95 % uncertainty of a position with covariance `c` (mm²):
/// `sqrt(χ²₃(0.95)·λ_max)`, the longest semi-axis of its 95 % ellipsoid.
pub fn u95_mm(c: &Matrix3<f64>) -> f64 {
    let largest = c.symmetric_eigenvalues().max().max(0.0);
    (chi_squared_3_quantile(0.95) * largest).sqrt()
}

/// A calibration row's unloaded tool pose under the calibrated parameters, with
/// the configuration that reached it.
#[derive(Debug, Clone, Copy)]
pub struct CalibrationPose {
    pub q_deg: [f64; MAX_JOINTS],
    /// The carriage's position on a track (mm; 0 without one).
    pub track_mm: f64,
    pub tool_in_world: Frame,
}

/// The unloaded tool poses of the calibration rows' configurations (and
/// carriage positions) under `values`.
pub fn calibration_poses(
    robot: &Robot,
    values: &ParamValues,
    rows: &[ConfWrench],
) -> Vec<CalibrationPose> {
    let prepared = robot.prepare(values);
    rows.iter()
        .map(|row| CalibrationPose {
            q_deg: row.q_deg,
            track_mm: row.track_mm,
            tool_in_world: prepared
                .world_from_base_at(row.track_mm)
                .compose(&prepared.loaded_chain(&row.q_deg, &Wrench::zero(), &[0; MAX_JOINTS])),
        })
        .collect()
}

/// Lower and upper corners of the poses' tool positions (mm); `None` without poses.
pub fn bounding_box(poses: &[CalibrationPose]) -> Option<(Vector3<f64>, Vector3<f64>)> {
    let first = poses.first()?.tool_in_world.origin_mm;
    Some(poses.iter().fold((first, first), |(lo, hi), p| {
        let o = p.tool_in_world.origin_mm;
        (lo.inf(&o), hi.sup(&o))
    }))
}

/// `count` evenly spaced values from `lo` to `hi`; the midpoint for one.
fn levels(lo: f64, hi: f64, count: usize) -> Vec<f64> {
    if count <= 1 {
        return vec![(lo + hi) / 2.0];
    }
    (0..count)
        .map(|k| lo + (hi - lo) * k as f64 / (count - 1) as f64)
        .collect()
}

/// The grid points (slice, position) over the box `lo`–`hi` enlarged by the
/// margin, slice by slice, y then x within a slice.
pub fn grid(lo: &Vector3<f64>, hi: &Vector3<f64>, spec: &GridSpec) -> Vec<(usize, Vector3<f64>)> {
    let margin = Vector3::repeat(spec.margin_mm);
    let (lo, hi) = (lo - margin, hi + margin);
    let xs = levels(lo.x, hi.x, spec.points_per_axis);
    let ys = levels(lo.y, hi.y, spec.points_per_axis);
    let zs = levels(lo.z, hi.z, spec.slices);
    let mut points = Vec::with_capacity(xs.len() * ys.len() * zs.len());
    for (slice, z) in zs.iter().enumerate() {
        for y in &ys {
            for x in &xs {
                points.push((slice, Vector3::new(*x, *y, *z)));
            }
        }
    }
    points
}

fn joint_distance_deg(a: &[f64; MAX_JOINTS], b: &[f64; MAX_JOINTS]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// The configuration for a grid point (module doc): orientation and carriage
/// position (and a seven-joint arm's held joint 3) of the nearest calibration
/// pose, IK branch closest to its configuration.
fn configuration(
    robot: &Robot,
    values: &ParamValues,
    prepared: &PreparedRobot,
    poses: &[CalibrationPose],
    position_mm: &Vector3<f64>,
) -> Result<([f64; MAX_JOINTS], f64), PointStatus> {
    let nearest = poses
        .iter()
        .min_by(|a, b| {
            (a.tool_in_world.origin_mm - position_mm)
                .norm()
                .total_cmp(&(b.tool_in_world.origin_mm - position_mm).norm())
        })
        .ok_or(PointStatus::Unreachable)?;
    let tool = Frame {
        rotation: nearest.tool_in_world.rotation,
        origin_mm: *position_mm,
    };
    // On a track the solver places the arm by the world frame: the target
    // with the carriage's transform taken out, `W·C(e)⁻¹·W⁻¹·T`.
    let tool = match prepared.carriage(nearest.track_mm) {
        None => tool,
        Some(_) => prepared
            .world_from_base
            .compose(&prepared.world_from_base_at(nearest.track_mm).inverse())
            .compose(&tool),
    };
    let flange = ik::flange_target_in_base(robot, values, &tool);
    // A seven-joint arm holds its joint 3 where the nearest pose had it.
    let held_deg = nearest.q_deg[ik::HELD_JOINT_OF_SEVEN];
    let solutions = match ik::solve_holding(robot, &flange, held_deg) {
        Ok(s) => s,
        Err(IkError::Singular(_)) => return Err(PointStatus::Singular),
        Err(_) => return Err(PointStatus::Unreachable),
    };
    solutions
        .iter()
        .map(|s| s.q_deg)
        .filter(|q| robot.within_limits(q))
        .min_by(|a, b| {
            joint_distance_deg(a, &nearest.q_deg).total_cmp(&joint_distance_deg(b, &nearest.q_deg))
        })
        .map(|q| (q, nearest.track_mm))
        .ok_or(PointStatus::Unreachable)
}

/// The accuracy map of the set `values` with covariance `covariance` (row-major
/// over `free`) around the calibration rows' configurations and carriage
/// positions (their wrenches are not used). Empty without calibration rows.
///
/// Cost: one inverse kinematics per grid point (µs for the closed form, ~1 ms
/// for the numeric search) and one Jacobian row with `O(m²)` for the reachable.
pub fn accuracy_map(
    robot: &Robot,
    values: &ParamValues,
    free: &[ParamId],
    covariance: &[f64],
    calibration: &[ConfWrench],
    spec: &GridSpec,
) -> Vec<MapPoint> {
    let poses = calibration_poses(robot, values, calibration);
    let prepared = robot.prepare(values);
    let Some((lo, hi)) = bounding_box(&poses) else {
        return Vec::new();
    };
    let mut points: Vec<MapPoint> = grid(&lo, &hi, spec)
        .into_iter()
        .map(|(slice, position_mm)| {
            let inside_box =
                (0..3).all(|i| position_mm[i] >= lo[i] - 1e-9 && position_mm[i] <= hi[i] + 1e-9);
            let (status, q_deg, track_mm) =
                match configuration(robot, values, &prepared, &poses, &position_mm) {
                    Ok((q, track_mm)) => (PointStatus::Reachable, Some(q), track_mm),
                    Err(status) => (status, None, 0.0),
                };
            MapPoint {
                slice,
                position_mm,
                inside_box,
                status,
                q_deg,
                track_mm,
                covariance_mm2: None,
            }
        })
        .collect();
    let rows: Vec<ConfWrench> = points.iter().filter_map(MapPoint::row).collect();
    let mut covariances = position_covariances(robot, values, free, covariance, &rows).into_iter();
    for point in points.iter_mut().filter(|p| p.q_deg.is_some()) {
        point.covariance_mm2 = covariances.next();
    }
    points
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::test_support::{irb1600, truth_params};

    /// Calibration configurations around one working pose: small joint offsets,
    /// so their tool positions span a box a few hundred mm wide.
    fn rows(q_deg: Vec<[f64; MAX_JOINTS]>) -> Vec<ConfWrench> {
        q_deg
            .into_iter()
            .map(|q| ConfWrench::new(q, Wrench::zero()))
            .collect()
    }

    fn calibration_q() -> Vec<[f64; MAX_JOINTS]> {
        let mut q = Vec::new();
        for d1 in [-10.0, 0.0, 10.0] {
            for d2 in [-8.0, 0.0, 8.0] {
                for d3 in [-8.0, 0.0, 8.0] {
                    q.push([d1, 10.0 + d2, 10.0 + d3, 5.0, 40.0, 0.0, 0.0]);
                }
            }
        }
        q
    }

    /// Σ of a least-squares fit on the calibration rows, closed form:
    /// σ²·(AᵀA)⁻¹ with A the rows' stacked Jacobians (σ = 0.02 mm), row-major.
    fn fitted_covariance(robot: &Robot, values: &ParamValues, free: &[ParamId]) -> Vec<f64> {
        let m = free.len();
        let prepared = robot.prepare(values);
        let mut normal = nalgebra::DMatrix::<f64>::zeros(m, m);
        let mut columns = vec![Vector3::zeros(); m];
        for q in calibration_q() {
            prepared.jacobian_row(&ConfWrench::new(q, Wrench::zero()), free, &mut columns);
            for i in 0..m {
                for j in 0..m {
                    normal[(i, j)] += columns[i].dot(&columns[j]);
                }
            }
        }
        let inverse = normal
            .try_inverse()
            .expect("the parameters are identifiable");
        (0..m * m)
            .map(|k| 0.02_f64.powi(2) * inverse[(k / m, k % m)])
            .collect()
    }

    fn free() -> Vec<ParamId> {
        [
            "x_w", "y_w", "z_w", "da2", "da3", "dd4", "dtheta2", "dtheta3",
        ]
        .iter()
        .map(|n| ParamId::from_name(n).expect("parameter name"))
        .collect()
    }

    #[test]
    fn grid_spans_the_box_and_its_margin() {
        let spec = GridSpec {
            points_per_axis: 3,
            slices: 2,
            margin_mm: 10.0,
        };
        let points = grid(&Vector3::zeros(), &Vector3::new(100.0, 50.0, 20.0), &spec);
        assert_eq!(points.len(), 18);
        assert_eq!(points[0], (0, Vector3::new(-10.0, -10.0, -10.0)));
        assert_eq!(points[17], (1, Vector3::new(110.0, 60.0, 30.0)));
        assert_eq!(points[4].1, Vector3::new(50.0, 25.0, -10.0));
    }

    /// A grid point's covariance is the uncertainty function at its configuration,
    /// and the tool of that configuration is at the grid point with the nearest
    /// calibration pose's orientation (nominal IK, so up to the calibration's
    /// correction).
    #[test]
    fn a_grid_point_is_the_uncertainty_at_its_configuration() {
        let robot = irb1600();
        let values = truth_params(&robot);
        let free = free();
        let sigma = fitted_covariance(&robot, &values, &free);
        let spec = GridSpec {
            points_per_axis: 5,
            slices: 3,
            margin_mm: 200.0,
        };
        let map = accuracy_map(
            &robot,
            &values,
            &free,
            &sigma,
            &rows(calibration_q()),
            &spec,
        );
        let poses = calibration_poses(&robot, &values, &rows(calibration_q()));
        let point = map
            .iter()
            .find(|p| p.inside_box && p.status == PointStatus::Reachable)
            .expect("a reachable point inside the box");
        let q = point.q_deg.expect("reachable");
        let direct = position_covariances(
            &robot,
            &values,
            &free,
            &sigma,
            &[ConfWrench::new(q, Wrench::zero())],
        )[0];
        let c = point.covariance_mm2.expect("covariance");
        assert!((c - direct).abs().max() < 1e-15, "{c} vs {direct}");
        let tool = robot.tool_in_world(&values, &q, &Wrench::zero(), &[0; MAX_JOINTS]);
        assert!(
            (tool.origin_mm - point.position_mm).norm() < 20.0,
            "tool {} vs grid point {}",
            tool.origin_mm,
            point.position_mm
        );
        let nearest = poses
            .iter()
            .min_by(|a, b| {
                (a.tool_in_world.origin_mm - point.position_mm)
                    .norm()
                    .total_cmp(&(b.tool_in_world.origin_mm - point.position_mm).norm())
            })
            .expect("poses");
        let angle = tool.angle_to(&nearest.tool_in_world);
        assert!(angle < 0.02, "orientation off by {angle} rad");
        // u95 is the longest semi-axis of the 95 % ellipsoid.
        let largest = c.symmetric_eigenvalues().max();
        assert!((point.u95_mm().expect("u95").powi(2) - 7.814_727_9 * largest).abs() < 1e-9);
    }

    /// The uncertainty of a geometric model grows with the distance from the
    /// rows it was fitted on: the map's far corners (outside the box) are more
    /// uncertain than its inside.
    #[test]
    fn u95_grows_away_from_the_calibration_rows() {
        let robot = irb1600();
        let values = truth_params(&robot);
        let free = free();
        let sigma = fitted_covariance(&robot, &values, &free);
        let spec = GridSpec {
            points_per_axis: 11,
            slices: 3,
            margin_mm: 150.0,
        };
        let map = accuracy_map(
            &robot,
            &values,
            &free,
            &sigma,
            &rows(calibration_q()),
            &spec,
        );
        let median = |inside: bool| {
            let mut u: Vec<f64> = map
                .iter()
                .filter(|p| p.inside_box == inside)
                .filter_map(MapPoint::u95_mm)
                .collect();
            assert!(
                u.len() > 3,
                "{} reachable points inside = {inside}",
                u.len()
            );
            u.sort_by(f64::total_cmp);
            u[u.len() / 2]
        };
        let (inside, outside) = (median(true), median(false));
        assert!(
            outside > 1.5 * inside,
            "median u95 inside {inside} mm, outside {outside} mm"
        );
    }
}
