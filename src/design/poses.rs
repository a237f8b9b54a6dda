//! Pose generation (paper §IV.A steps (a)–(b)): target SMR positions in the
//! cable robot's workspace, tool orientations that keep the SMR facing the laser
//! tracker, every inverse-kinematics solution filtered by joint limits, distance
//! from singularities, collisions and line of sight, and one survivor drawn at random.
//!
//! Each target point draws from its own seeded stream, so results do not depend on
//! thread scheduling, and points run in parallel.

use std::collections::BTreeMap;

use nalgebra::{Matrix3, Vector3};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rayon::prelude::*;

use super::collision::{Cell, Rejection};
use crate::robot::ik::{IkError, closed_form, flange_target_in_base, frame_with_z_along};
use crate::robot::{Frame, JOINTS, ParamValues, Robot};

/// How target points fill the workspace box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Sampling {
    /// `n × n × n` evenly spaced points including the faces.
    Grid { per_axis: usize },
    /// Uniform random points.
    Random { count: usize },
    /// Latin hypercube: one point per stratum of each axis.
    LatinHypercube { count: usize },
}

/// Limits that keep a configuration away from singularities.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SingularityLimits {
    /// Smallest |q5| (wrist singularity at q5 = 0).
    pub min_wrist_deg: f64,
    /// Smallest distance of the wrist centre from axis 1 (shoulder singularity).
    pub min_shoulder_mm: f64,
    /// Smallest bend of the elbow away from straight (elbow singularity).
    pub min_elbow_deg: f64,
}

/// Everything pose generation needs.
#[derive(Debug, Clone)]
pub struct PoseProblem {
    pub centre_mm: Vector3<f64>,
    pub edge_mm: f64,
    pub sampling: Sampling,
    pub acceptance_half_angle_deg: f64,
    /// Tool roll about its z axis is drawn uniformly within ± this of the upright
    /// roll (see [`upright_tool_frame`]); 180 draws any roll.
    pub roll_half_range_deg: f64,
    pub orientation_attempts: usize,
    pub singularity: SingularityLimits,
    pub cell: Cell,
}

/// One generated configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct GeneratedPose {
    pub config_id: i64,
    /// Target SMR (tool origin) in the base frame.
    pub target_mm: Vector3<f64>,
    /// Tool orientation in the base frame.
    pub tool_rotation: Matrix3<f64>,
    pub q_deg: [f64; JOINTS],
    pub branch: u8,
    pub clearance_mm: f64,
    /// Angle between the SMR's axis (tool z) and the direction to the tracker.
    pub incidence_deg: f64,
}

/// Generated poses and how many candidates each filter rejected.
#[derive(Debug, Clone, Default)]
pub struct PoseOutcome {
    pub poses: Vec<GeneratedPose>,
    pub rejections: BTreeMap<&'static str, usize>,
    /// Target points with no surviving configuration after every orientation attempt.
    pub dropped_points: usize,
    pub targets: usize,
}

/// Target points of the box, in sampling order.
pub fn targets(problem: &PoseProblem, rng: &mut impl Rng) -> Vec<Vector3<f64>> {
    let half = problem.edge_mm / 2.0;
    let corner = problem.centre_mm - Vector3::repeat(half);
    match problem.sampling {
        Sampling::Grid { per_axis } => {
            let step = if per_axis > 1 {
                problem.edge_mm / (per_axis - 1) as f64
            } else {
                0.0
            };
            let offset = if per_axis > 1 { 0.0 } else { half };
            let mut points = Vec::with_capacity(per_axis.pow(3));
            for i in 0..per_axis {
                for j in 0..per_axis {
                    for k in 0..per_axis {
                        let ijk = Vector3::new(i as f64, j as f64, k as f64);
                        points.push(corner + ijk * step + Vector3::repeat(offset));
                    }
                }
            }
            points
        }
        Sampling::Random { count } => (0..count)
            .map(|_| corner + Vector3::from_fn(|_, _| rng.random::<f64>() * problem.edge_mm))
            .collect(),
        Sampling::LatinHypercube { count } => {
            let mut strata: Vec<Vec<usize>> = (0..3).map(|_| (0..count).collect()).collect();
            for axis in &mut strata {
                for i in (1..axis.len()).rev() {
                    axis.swap(i, rng.random_range(0..=i));
                }
            }
            (0..count)
                .map(|p| {
                    corner
                        + Vector3::from_fn(|axis, _| {
                            (strata[axis][p] as f64 + rng.random::<f64>()) / count as f64
                                * problem.edge_mm
                        })
                })
                .collect()
        }
    }
}

/// A direction uniformly distributed on the spherical cap of `half_angle_deg` around `axis`.
fn direction_in_cone(axis: &Vector3<f64>, half_angle_deg: f64, rng: &mut impl Rng) -> Vector3<f64> {
    let cos_max = half_angle_deg.to_radians().cos();
    let cos_theta = rng.random_range(cos_max..=1.0);
    let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
    let phi = rng.random_range(0.0..std::f64::consts::TAU);
    let frame = frame_with_z_along(axis, 0.0, Vector3::zeros());
    frame.rotation * Vector3::new(sin_theta * phi.cos(), sin_theta * phi.sin(), cos_theta)
}

/// The tool frame with z along `facing` (unit, base frame), turned by `roll_rad`
/// about z from the upright roll: tool y as close to base +z as the facing allows,
/// so tool x is horizontal.
///
/// Why a reference roll: the platform (a cube on the tool) turns with the roll, and
/// the cable robot's wrench-feasible set depends strongly on the platform's
/// orientation relative to its frame, so a real cell holds the platform roughly at
/// the orientation its frame was designed for and varies the roll only a little
/// (`jobs/cdpr/default.toml` is designed for this reference).
pub fn upright_tool_frame(facing: &Vector3<f64>, roll_rad: f64, origin_mm: Vector3<f64>) -> Frame {
    let z = facing.normalize();
    let up = Vector3::z();
    let y = up - z * up.dot(&z);
    if y.norm() < 1e-6 {
        // Facing straight up or down: no upright roll, any reference will do.
        return frame_with_z_along(&z, roll_rad, origin_mm);
    }
    let y = y.normalize();
    let x = y.cross(&z);
    Frame {
        rotation: Matrix3::from_columns(&[x, y, z]) * crate::robot::frame::rot_z(roll_rad),
        origin_mm,
    }
}

/// How far a configuration is from the arm's three singularities:
/// (|q5| in deg, wrist centre distance from axis 1 in mm, elbow bend in deg).
pub fn singularity_margins(joints: &[Frame; JOINTS + 1], q_deg: &[f64; JOINTS]) -> (f64, f64, f64) {
    let wrist = joints[4].origin_mm;
    let shoulder = wrist.x.hypot(wrist.y);
    let upper = joints[3].origin_mm - joints[2].origin_mm;
    let fore = wrist - joints[3].origin_mm;
    let cos = upper.dot(&fore) / (upper.norm() * fore.norm()).max(1e-12);
    let bend = cos.clamp(-1.0, 1.0).acos().to_degrees();
    let elbow = bend.min(180.0 - bend);
    (q_deg[4].abs(), shoulder, elbow)
}

/// Generates one configuration per target point (or drops the point).
pub fn generate(
    robot: &Robot,
    nominal: &ParamValues,
    problem: &PoseProblem,
    seed: u64,
) -> PoseOutcome {
    let mut rng = StdRng::seed_from_u64(seed);
    let points = targets(problem, &mut rng);
    let per_point: Vec<(Option<GeneratedPose>, BTreeMap<&'static str, usize>)> = points
        .par_iter()
        .enumerate()
        .map(|(index, target)| {
            let mut rng =
                StdRng::seed_from_u64(seed ^ (index as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15));
            generate_one(robot, nominal, problem, index as i64 + 1, target, &mut rng)
        })
        .collect();
    let mut outcome = PoseOutcome {
        targets: points.len(),
        ..PoseOutcome::default()
    };
    for (pose, rejections) in per_point {
        for (key, count) in rejections {
            *outcome.rejections.entry(key).or_default() += count;
        }
        match pose {
            Some(p) => outcome.poses.push(p),
            None => outcome.dropped_points += 1,
        }
    }
    outcome
}

fn generate_one(
    robot: &Robot,
    nominal: &ParamValues,
    problem: &PoseProblem,
    config_id: i64,
    target: &Vector3<f64>,
    rng: &mut StdRng,
) -> (Option<GeneratedPose>, BTreeMap<&'static str, usize>) {
    let mut rejections: BTreeMap<&'static str, usize> = BTreeMap::new();
    let mut reject = |why: Rejection| *rejections.entry(why.key()).or_default() += 1;
    let to_tracker = (problem.cell.tracker - target).normalize();
    let world = robot.world_from_base(nominal);
    for _ in 0..problem.orientation_attempts {
        let facing = direction_in_cone(&to_tracker, problem.acceptance_half_angle_deg, rng);
        let half_range = problem.roll_half_range_deg.to_radians();
        let roll = rng.random_range(-half_range..=half_range);
        let tool_in_base = upright_tool_frame(&facing, roll, *target);
        let flange = flange_target_in_base(robot, nominal, &world.compose(&tool_in_base));
        let solutions = match closed_form(robot, &flange) {
            Ok(s) => s,
            Err(IkError::Singular(_)) => {
                reject(Rejection::Singular);
                continue;
            }
            Err(_) => {
                reject(Rejection::Unreachable);
                continue;
            }
        };
        let mut survivors = Vec::new();
        for solution in solutions {
            if !robot.within_limits(&solution.q_deg) {
                reject(Rejection::JointLimits);
                continue;
            }
            let (joints, tool) = robot.frames_in_base(nominal, &solution.q_deg);
            let (wrist, shoulder, elbow) = singularity_margins(&joints, &solution.q_deg);
            let limits = &problem.singularity;
            if wrist < limits.min_wrist_deg
                || shoulder < limits.min_shoulder_mm
                || elbow < limits.min_elbow_deg
            {
                reject(Rejection::Singular);
                continue;
            }
            match problem.cell.check(&joints, &tool) {
                Ok(clearance) => survivors.push((solution, tool, clearance)),
                Err(why) => reject(why),
            }
        }
        if survivors.is_empty() {
            continue;
        }
        let (solution, tool, clearance_mm) =
            survivors.swap_remove(rng.random_range(0..survivors.len()));
        let incidence_deg = tool
            .axis(2)
            .dot(&to_tracker)
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees();
        return (
            Some(GeneratedPose {
                config_id,
                target_mm: *target,
                tool_rotation: tool.rotation,
                q_deg: solution.q_deg,
                branch: solution.branch,
                clearance_mm,
                incidence_deg,
            }),
            rejections,
        );
    }
    (None, rejections)
}

/// `Rot(x,α)·Rot(y,β)·Rot(z,γ)` angles (deg) of a rotation, the convention of eq. (4).
pub fn xyz_euler_deg(r: &Matrix3<f64>) -> [f64; 3] {
    let beta = r[(0, 2)].clamp(-1.0, 1.0).asin();
    let alpha = (-r[(1, 2)]).atan2(r[(2, 2)]);
    let gamma = (-r[(0, 1)]).atan2(r[(0, 0)]);
    [alpha.to_degrees(), beta.to_degrees(), gamma.to_degrees()]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::frame::{rot_x, rot_y, rot_z};

    #[test]
    fn euler_angles_round_trip() {
        let r = rot_x(0.3) * rot_y(-0.4) * rot_z(1.2);
        let [a, b, c] = xyz_euler_deg(&r);
        let back = rot_x(a.to_radians()) * rot_y(b.to_radians()) * rot_z(c.to_radians());
        assert!((back - r).norm() < 1e-12);
    }

    #[test]
    fn upright_frame_is_a_rotation_with_horizontal_x_and_the_asked_roll() {
        let facing = Vector3::new(-2226.0, -1362.0, 576.0).normalize();
        let origin = Vector3::new(900.0, 0.0, 900.0);
        let upright = upright_tool_frame(&facing, 0.0, origin);
        let r = upright.rotation;
        assert!((r.transpose() * r - Matrix3::identity()).norm() < 1e-12);
        assert!((r.determinant() - 1.0).abs() < 1e-12);
        assert!((r.column(2) - facing).norm() < 1e-12);
        assert!(r[(2, 0)].abs() < 1e-12, "tool x is horizontal");
        assert!(r[(2, 1)] > 0.0, "tool y points up");
        let rolled = upright_tool_frame(&facing, 0.3, origin);
        let angle = upright.axis(0).dot(&rolled.axis(0)).acos();
        assert!((angle - 0.3).abs() < 1e-12);
        assert_eq!(rolled.origin_mm, origin);
        // Straight up: falls back to a valid frame.
        let vertical = upright_tool_frame(&Vector3::z(), 0.0, origin).rotation;
        assert!((vertical.column(2) - Vector3::z()).norm() < 1e-12);
    }

    #[test]
    fn cone_directions_stay_within_the_half_angle() {
        let mut rng = StdRng::seed_from_u64(1);
        let axis = Vector3::new(-1.0, -1.0, 0.5).normalize();
        for _ in 0..1000 {
            let d = direction_in_cone(&axis, 40.0, &mut rng);
            assert!((d.norm() - 1.0).abs() < 1e-12);
            assert!(d.dot(&axis).acos().to_degrees() <= 40.0 + 1e-9);
        }
    }
}
