//! Pose generation (paper §IV.A steps (a)–(b)): target SMR positions in the
//! cable robot's workspace, tool orientations that keep the SMR facing the laser
//! tracker, every inverse-kinematics solution filtered by joint limits, distance
//! from singularities, collisions and line of sight, and one survivor drawn at random.
//!
//! Works for any six-axis arm: the solutions come from [`ik::solve`] (closed form
//! for spherical-wrist arms, the numeric search otherwise, e.g. a UR), and the
//! singularity margins are measured on the joint frames, not on joint angles.
//! A seven-joint arm's attempts each draw the value of the joint the
//! redundancy rule holds ([`ik::HELD_JOINT_OF_SEVEN`]) within its limits, so
//! the campaign spreads over elbow angles as over orientations, and the
//! margins are its six free joints' ([`ik::role_frames`]).
//!
//! Each target point draws from its own seeded stream, so results do not depend on
//! thread scheduling, and points run in parallel.

use std::collections::BTreeMap;

use nalgebra::{Matrix3, Vector3};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rayon::prelude::*;

use super::collision::{Cell, Rejection};
use crate::robot::ik::{self, IkError, flange_target_in_base, frame_with_z_along};
use crate::robot::{Frame, MAX_JOINTS, ParamValues, Robot};

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
    /// Smallest angle between axes 4 and 6 (wrist singularity; |q5| on the usual
    /// arms). See [`singularity_margins`] for all three measures.
    pub min_wrist_deg: f64,
    /// Smallest distance of the wrist point from the plane of axes 1 and 2
    /// (shoulder singularity; the distance from axis 1 without a lateral offset).
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
    pub q_deg: [f64; MAX_JOINTS],
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

/// How far a configuration is from the arm's three singularities, from its joint
/// frames (base frame) alone, so the same measures serve any MDH table:
///
/// * wrist (deg): the angle between axes 4 and 6 (or its supplement, whichever is
///   smaller); they align at the wrist singularity. On the spherical-wrist and UR
///   arms this is |q5| for |q5| <= 90.
/// * shoulder (mm): the distance of the wrist point (frame 5's origin: the wrist
///   centre, or where axes 5 and 6 meet on a UR) from the plane through axis 1
///   that contains axis 2's direction. Without a lateral offset (the IRB family)
///   this is its distance from axis 1; with UR's offset it is where the shoulder
///   singularity lies.
/// * elbow (deg): the bend of the forearm (frame 3 to frame 4 origins) away from
///   straight along the upper arm (frame 2 to frame 3 origins), both seen along
///   axis 3 so that a lateral offset (UR's d4) does not count as bend.
pub fn singularity_margins(joints: &[Frame; 7]) -> (f64, f64, f64) {
    let (z4, z6) = (joints[4].axis(2), joints[6].axis(2));
    let wrist = z4.cross(&z6).norm().atan2(z4.dot(&z6).abs()).to_degrees();

    let (o1, z1) = (joints[1].origin_mm, joints[1].axis(2));
    let point = joints[5].origin_mm - o1;
    let normal = z1.cross(&joints[2].axis(2));
    let shoulder = if normal.norm() > 1e-9 {
        point.dot(&normal.normalize()).abs()
    } else {
        // Axes 1 and 2 parallel: the distance from axis 1.
        (point - z1 * z1.dot(&point)).norm()
    };

    let z3 = joints[3].axis(2);
    let across = |v: Vector3<f64>| v - z3 * z3.dot(&v);
    let upper = across(joints[3].origin_mm - joints[2].origin_mm);
    let fore = across(joints[4].origin_mm - joints[3].origin_mm);
    let cos = upper.dot(&fore) / (upper.norm() * fore.norm()).max(1e-12);
    let bend = cos.clamp(-1.0, 1.0).acos().to_degrees();
    let elbow = bend.min(180.0 - bend);
    (wrist, shoulder, elbow)
}

/// A point near a work target (base frame, mm) and the IK branch the work
/// uses there: its configurations are accepted in that branch only.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BranchPoint {
    pub position_mm: Vector3<f64>,
    pub branch: u8,
}

/// Generates one configuration per target point of the box, then per point
/// of `near_work` (or drops the point), calling `on_point` after each point
/// (from any thread) so a caller can show progress.
pub fn generate(
    robot: &Robot,
    nominal: &ParamValues,
    problem: &PoseProblem,
    near_work: &[BranchPoint],
    seed: u64,
    on_point: &(dyn Fn() + Sync),
) -> PoseOutcome {
    let mut rng = StdRng::seed_from_u64(seed);
    let points: Vec<(Vector3<f64>, Option<u8>)> = targets(problem, &mut rng)
        .into_iter()
        .map(|p| (p, None))
        .chain(near_work.iter().map(|p| (p.position_mm, Some(p.branch))))
        .collect();
    let per_point: Vec<(Option<GeneratedPose>, BTreeMap<&'static str, usize>)> = points
        .par_iter()
        .enumerate()
        .map(|(index, (target, branch))| {
            let mut rng =
                StdRng::seed_from_u64(seed ^ (index as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15));
            let id = index as i64 + 1;
            let result = generate_one(robot, nominal, problem, id, target, *branch, &mut rng);
            on_point();
            result
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
    branch: Option<u8>,
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
        let solved = if robot.joint_count() > 6 {
            let [lo, hi] = robot.joint_limits(ik::HELD_JOINT_OF_SEVEN);
            ik::solve_holding(robot, &flange, rng.random_range(lo..=hi))
        } else {
            ik::solve(robot, &flange)
        };
        let solutions = match solved {
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
        // Extra turns of a joint give the same geometry: the singularity and
        // collision checks run once per configuration (joint angles modulo 360),
        // and every turn within the limits shares the outcome.
        let mut checked: Vec<([f64; MAX_JOINTS], Result<f64, Rejection>)> = Vec::new();
        let mut survivors = Vec::new();
        for solution in solutions {
            if branch.is_some_and(|b| b != solution.branch) {
                reject(Rejection::OtherBranch);
                continue;
            }
            if !robot.within_limits(&solution.q_deg) {
                reject(Rejection::JointLimits);
                continue;
            }
            let wrapped = solution
                .q_deg
                .map(|q| (q + 180.0).rem_euclid(360.0) - 180.0);
            let same = |c: &[f64; MAX_JOINTS]| {
                c.iter().zip(&wrapped).all(|(a, b)| {
                    let d = (a - b).abs();
                    d.min(360.0 - d) < 1e-6
                })
            };
            let outcome = match checked.iter().find(|(c, _)| same(c)) {
                Some((_, outcome)) => *outcome,
                None => {
                    let (joints, tool) = robot.frames_in_base(nominal, &solution.q_deg);
                    let outcome = check_configuration(robot, problem, &joints, &tool);
                    checked.push((wrapped, outcome));
                    outcome
                }
            };
            match outcome {
                Ok(_) => survivors.push(solution),
                Err(why) => reject(why),
            }
        }
        while !survivors.is_empty() {
            let solution = survivors.swap_remove(rng.random_range(0..survivors.len()));
            // The shared check ran on the frames of another turn, equal to these
            // to rounding; parry3d's distances move by ~1e-7 with that, so the
            // tool frame and clearance reported are the chosen joint vector's own.
            let (joints, tool) = robot.frames_in_base(nominal, &solution.q_deg);
            let clearance_mm = match problem.cell.check(&joints, &tool) {
                Ok(clearance) => clearance,
                Err(why) => {
                    reject(why);
                    continue;
                }
            };
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
    }
    (None, rejections)
}

/// The singularity limits, then the cell's collision and sight checks, of one
/// configuration: its clearance (mm) or the first rejection. A gantry (an arm
/// with a prismatic joint) has its wrist's singularity only: its slides have
/// no shoulder or elbow to stretch.
fn check_configuration(
    robot: &Robot,
    problem: &PoseProblem,
    joints: &[Frame; MAX_JOINTS + 1],
    tool: &Frame,
) -> Result<f64, Rejection> {
    let (wrist, shoulder, elbow) = singularity_margins(&ik::role_frames(robot, joints));
    let limits = &problem.singularity;
    let arm_singular = !robot.has_prismatic_joint()
        && (shoulder < limits.min_shoulder_mm || elbow < limits.min_elbow_deg);
    if wrist < limits.min_wrist_deg || arm_singular {
        return Err(Rejection::Singular);
    }
    problem.cell.check(joints, tool)
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

    /// A UR10 (no spherical wrist, so no closed form) gets a pose at every point
    /// of a small grid in front of it, facing a tracker 2.5 m away at shoulder
    /// height; every pose reaches its target on the nominal model, faces the
    /// tracker within the acceptance angle, keeps the singularity margins, and the
    /// outcome does not depend on scheduling.
    #[test]
    fn a_ur10_gets_poses_from_the_numeric_inverse_kinematics() {
        let robot = crate::robot::test_support::ur10();
        assert!(crate::robot::ik::closed_form_applies(&robot).is_err());
        let nominal = ParamValues::nominal(robot.spec());
        let tracker = Vector3::new(2500.0, 0.0, 500.0);
        let problem = PoseProblem {
            centre_mm: Vector3::new(700.0, 0.0, 400.0),
            edge_mm: 300.0,
            sampling: Sampling::Grid { per_axis: 3 },
            acceptance_half_angle_deg: 40.0,
            roll_half_range_deg: 30.0,
            orientation_attempts: 20,
            singularity: SingularityLimits {
                min_wrist_deg: 5.0,
                min_shoulder_mm: 100.0,
                min_elbow_deg: 5.0,
            },
            cell: Cell {
                link_capsules: [None; MAX_JOINTS],
                anchors: Vec::new(),
                pulley_radius_mm: 40.0,
                attachments: Vec::new(),
                cable_radius_mm: 3.0,
                platform_centre: Vector3::zeros(),
                platform_half_extents_mm: Vector3::repeat(1.0),
                smr_radius_mm: 19.05,
                floor_z_mm: 0.0,
                tracker,
                safety_margin_mm: 5.0,
            },
        };
        let outcome = generate(&robot, &nominal, &problem, &[], 7, &|| {});
        assert_eq!(outcome.targets, 27);
        assert_eq!(outcome.poses.len(), 27, "{:?}", outcome.rejections);
        for pose in &outcome.poses {
            assert!(robot.within_limits(&pose.q_deg), "{pose:?}");
            let tool = robot.tool_in_world(
                &nominal,
                &pose.q_deg,
                &crate::robot::Wrench::zero(),
                &[0; MAX_JOINTS],
            );
            assert!((tool.origin_mm - pose.target_mm).norm() < 1e-9, "{pose:?}");
            assert!(
                (tool.rotation - pose.tool_rotation).norm() < 1e-9,
                "{pose:?}"
            );
            let to_tracker = (tracker - pose.target_mm).normalize();
            let incidence = tool.axis(2).dot(&to_tracker).acos().to_degrees();
            assert!(incidence <= 40.0 + 1e-9, "{pose:?}");
            assert!((incidence - pose.incidence_deg).abs() < 1e-9);
            let (joints, _) = robot.frames_in_base(&nominal, &pose.q_deg);
            let (wrist, shoulder, elbow) = singularity_margins(&ik::role_frames(&robot, &joints));
            assert!(
                wrist >= 5.0 && shoulder >= 100.0 && elbow >= 5.0,
                "{pose:?}"
            );
            assert_eq!(
                pose.branch,
                crate::robot::ik::branch_of(&robot, &pose.q_deg)
            );
        }
        let again = generate(&robot, &nominal, &problem, &[], 7, &|| {});
        assert_eq!(again.poses, outcome.poses);
        assert_eq!(again.rejections, outcome.rejections);
    }

    /// On the closed form's arm the frame-based margins are the joint-angle ones:
    /// |q5| for the wrist and the wrist centre's distance from axis 1.
    #[test]
    fn singularity_margins_of_the_irb1600_are_q5_and_the_radial_distance() {
        let robot = crate::robot::test_support::irb1600();
        let nominal = ParamValues::nominal(robot.spec());
        for q in [
            [10.0, 20.0, -30.0, 40.0, 50.0, 60.0],
            [-120.0, 80.0, -200.0, -150.0, -100.0, 300.0],
            [0.0, 0.0, -90.0, 0.0, 3.0, 0.0],
        ] {
            let (joints, _) = robot.frames_in_base(&nominal, &crate::robot::joint_array(&q));
            let (wrist, shoulder, elbow) = singularity_margins(&ik::role_frames(&robot, &joints));
            assert!(
                (wrist - q[4].abs().min(180.0 - q[4].abs())).abs() < 1e-9,
                "{q:?}"
            );
            let centre = joints[4].origin_mm;
            assert!((shoulder - centre.x.hypot(centre.y)).abs() < 1e-9, "{q:?}");
            // The forearm (a4 = 0, d4 = 600) is straight along the upper arm at
            // q3 = -90, bent by |q3 + 90| otherwise.
            let bend = (q[2] + 90.0).abs();
            assert!((elbow - bend.min(180.0 - bend)).abs() < 1e-9, "{q:?}");
        }
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
