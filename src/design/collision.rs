//! The measurement cell as geometry in the robot base frame (mm): robot links as
//! capsules, the cable robot's pulleys as balls, its 8 cables as thin capsules, the
//! platform as a box on the tool, a floor plane, and the tracker's line of sight.
//!
//! Distance queries go through parry3d (the only place its glam types appear:
//! [`to_parry`] is the boundary). A configuration is rejected with the first
//! reason found, and otherwise reports its minimum clearance.

use nalgebra::Vector3;
use parry3d_f64::math::{Pose, Vector};
use parry3d_f64::query;
use parry3d_f64::shape::{Capsule, Cuboid, Shape};

use crate::robot::frame::rotation_vector;
use crate::robot::{Frame, MAX_JOINTS};

/// Why a configuration was rejected (also the rejection-count keys).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Rejection {
    Unreachable,
    Singular,
    JointLimits,
    Floor,
    SelfCollision,
    FrameCollision,
    CableCollision,
    LineOfSight,
    /// A point near a work target whose configurations all lie in other IK
    /// branches than the target's.
    OtherBranch,
}

impl Rejection {
    pub fn key(self) -> &'static str {
        match self {
            Rejection::Unreachable => "unreachable",
            Rejection::Singular => "singular",
            Rejection::JointLimits => "joint_limits",
            Rejection::Floor => "floor",
            Rejection::SelfCollision => "self_collision",
            Rejection::FrameCollision => "frame_collision",
            Rejection::CableCollision => "cable_collision",
            Rejection::LineOfSight => "line_of_sight",
            Rejection::OtherBranch => "other_branch",
        }
    }
}

/// A capsule in some frame (mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CapsuleMm {
    pub from: Vector3<f64>,
    pub to: Vector3<f64>,
    pub radius: f64,
}

/// Everything the checks need, fixed for a campaign.
#[derive(Debug, Clone)]
pub struct Cell {
    /// Capsule of link i (1-based joint i, in frame i), if any.
    pub link_capsules: [Option<CapsuleMm>; MAX_JOINTS],
    /// Cable-robot anchor (pulley) centres in the base frame.
    pub anchors: Vec<Vector3<f64>>,
    pub pulley_radius_mm: f64,
    /// Cable attachment points on the platform, in the tool frame.
    pub attachments: Vec<Vector3<f64>>,
    pub cable_radius_mm: f64,
    /// Platform as a box aligned with the tool frame: centre (tool frame) and half extents.
    pub platform_centre: Vector3<f64>,
    pub platform_half_extents_mm: Vector3<f64>,
    /// The beam ends this far before the SMR centre (the SMR's radius).
    pub smr_radius_mm: f64,
    /// Lowest z any link point may reach (base frame).
    pub floor_z_mm: f64,
    /// Tracker head in the base frame.
    pub tracker: Vector3<f64>,
    /// Clearance every distance must exceed (mm).
    pub safety_margin_mm: f64,
}

fn to_parry(v: &Vector3<f64>) -> Vector {
    Vector::new(v.x, v.y, v.z)
}

fn capsule(a: &Vector3<f64>, b: &Vector3<f64>, radius: f64) -> Capsule {
    Capsule::new(to_parry(a), to_parry(b), radius)
}

fn distance(a: &dyn Shape, b: &dyn Shape) -> f64 {
    let identity = Pose::identity();
    distance_posed(&identity, a, b)
}

/// Distance between `a` placed at `pose` and `b` given in the base frame.
fn distance_posed(pose: &Pose, a: &dyn Shape, b: &dyn Shape) -> f64 {
    query::distance(pose, a, &Pose::identity(), b).map_or(f64::INFINITY, |d| d.distance)
}

fn to_pose(frame: &Frame) -> Pose {
    Pose::new(
        to_parry(&frame.origin_mm),
        to_parry(&rotation_vector(&frame.rotation)),
    )
}

fn ball_at(centre: &Vector3<f64>, radius: f64) -> Capsule {
    // A zero-length capsule is a ball placed without a pose.
    capsule(centre, centre, radius)
}

impl Cell {
    /// Checks a configuration given its joint frames and tool frame (base frame,
    /// unloaded); returns the minimum clearance (mm) or the first rejection.
    pub fn check(&self, joints: &[Frame; MAX_JOINTS + 1], tool: &Frame) -> Result<f64, Rejection> {
        let links: Vec<(usize, Capsule, CapsuleMm)> = self
            .link_capsules
            .iter()
            .enumerate()
            .filter_map(|(i, c)| {
                c.map(|c| {
                    let frame = &joints[i + 1];
                    let base = CapsuleMm {
                        from: frame.transform_point(&c.from),
                        to: frame.transform_point(&c.to),
                        radius: c.radius,
                    };
                    (i + 1, capsule(&base.from, &base.to, c.radius), base)
                })
            })
            .collect();
        let mut clearance = f64::INFINITY;
        let mut require = |d: f64, why: Rejection| {
            clearance = clearance.min(d);
            if d <= self.safety_margin_mm {
                Err(why)
            } else {
                Ok(())
            }
        };

        // Links 2.. above the floor (link 1 stands on it).
        for (_, _, c) in links.iter().filter(|(link, _, _)| *link >= 2) {
            if c.from.z.min(c.to.z) - c.radius < self.floor_z_mm {
                return Err(Rejection::Floor);
            }
        }
        // Self-collision between non-adjacent links.
        for (i, (link_a, shape_a, _)) in links.iter().enumerate() {
            for (link_b, shape_b, _) in &links[i + 1..] {
                if link_b - link_a >= 2 {
                    require(distance(shape_a, shape_b), Rejection::SelfCollision)?;
                }
            }
        }
        let platform = Cuboid::new(to_parry(&self.platform_half_extents_mm));
        let platform_pose = to_pose(&tool.compose(&Frame {
            rotation: nalgebra::Matrix3::identity(),
            origin_mm: self.platform_centre,
        }));
        // The platform against the arm up to the forearm.
        for (link, shape, _) in &links {
            if *link <= 3 {
                require(
                    distance_posed(&platform_pose, &platform, shape),
                    Rejection::SelfCollision,
                )?;
            }
        }
        // Pulleys (the cable robot's frame) against links and platform.
        for anchor in &self.anchors {
            let pulley = ball_at(anchor, self.pulley_radius_mm);
            require(
                distance_posed(&platform_pose, &platform, &pulley),
                Rejection::FrameCollision,
            )?;
            for (_, shape, _) in &links {
                require(distance(shape, &pulley), Rejection::FrameCollision)?;
            }
        }
        // Cables against links up to the wrist (the last links carry the platform
        // the cables attach to).
        let cables: Vec<Capsule> = self
            .anchors
            .iter()
            .zip(&self.attachments)
            .map(|(anchor, attachment)| {
                capsule(
                    anchor,
                    &tool.transform_point(attachment),
                    self.cable_radius_mm,
                )
            })
            .collect();
        for cable in &cables {
            for (link, shape, _) in &links {
                if *link <= 4 {
                    require(distance(cable, shape), Rejection::CableCollision)?;
                }
            }
        }
        // Line of sight from the tracker to the SMR's surface.
        let smr = tool.origin_mm;
        let towards_tracker = (self.tracker - smr).normalize();
        let beam = capsule(
            &self.tracker,
            &(smr + towards_tracker * self.smr_radius_mm),
            0.0,
        );
        for (_, shape, _) in &links {
            require(distance(&beam, shape), Rejection::LineOfSight)?;
        }
        for cable in &cables {
            require(distance(&beam, cable), Rejection::LineOfSight)?;
        }
        Ok(clearance)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn posed_box_distance_matches_the_closed_form() {
        // A 100 mm cube turned 90° about z and moved to x = 500: its face is at 450.
        let frame = Frame {
            rotation: crate::robot::frame::rot_z(std::f64::consts::FRAC_PI_2),
            origin_mm: Vector3::new(500.0, 0.0, 0.0),
        };
        let cube = Cuboid::new(to_parry(&Vector3::repeat(50.0)));
        let ball = ball_at(&Vector3::new(300.0, 0.0, 0.0), 50.0);
        let d = distance_posed(&to_pose(&frame), &cube, &ball);
        assert!((d - 100.0).abs() < 1e-6, "{d}");
    }

    #[test]
    fn parry_distances_match_closed_forms() {
        let a = capsule(
            &Vector3::new(0.0, 0.0, 0.0),
            &Vector3::new(100.0, 0.0, 0.0),
            10.0,
        );
        let b = capsule(
            &Vector3::new(50.0, 50.0, -20.0),
            &Vector3::new(50.0, 50.0, 20.0),
            5.0,
        );
        assert!((distance(&a, &b) - 35.0).abs() < 1e-9);
        let ball = ball_at(&Vector3::new(200.0, 0.0, 0.0), 20.0);
        assert!((distance(&a, &ball) - 70.0).abs() < 1e-9);
    }
}
