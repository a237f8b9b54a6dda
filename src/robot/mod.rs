//! The robot model: robot file, the 42 parameters, the elasto-geometric forward
//! model, the analytic identification Jacobian and inverse kinematics. Pure maths on
//! small fixed-size types (nalgebra); no I/O besides reading the robot file, no tables.

pub mod file;
pub mod frame;
pub mod ik;
pub mod jacobian;
pub mod model;
pub mod params;
pub mod positioner;
pub mod track;

pub use file::RobotSpec;
pub use frame::Frame;
pub use jacobian::{BatchJacobian, ConfWrench, batch_jacobian, batch_predict};
pub use model::{MAX_JOINTS, Prediction, PreparedRobot, Robot, Wrench, joint_array};
pub use params::{
    BASE_PARAM_COUNT, JointParam, MAX_TARGETS, PARAM_COUNT, ParamId, ParamValues, Selection,
};

#[cfg(test)]
pub(crate) mod test_support {
    //! Shared fixtures for the model's unit tests: the shipped IRB 1600 and UR10
    //! files, the spec's truth parameters and random conf-wrench rows.
    use super::*;
    use rand::Rng;
    use std::path::Path;

    pub fn irb1600() -> Robot {
        let text = include_str!("../../jobs/robots/irb1600_145.toml");
        Robot::new(RobotSpec::parse(text, Path::new("irb1600_145.toml")).unwrap())
    }

    /// The IRB 1600 on a 3 m linear track along its base's x axis.
    pub fn irb1600_on_track() -> Robot {
        let text = format!(
            "{}\n[track]\ntravel_mm = [0.0, 3000.0]\n",
            include_str!("../../jobs/robots/irb1600_145.toml")
        );
        Robot::new(RobotSpec::parse(&text, Path::new("irb1600_track.toml")).unwrap())
    }

    /// The IRB 1600 with the shipped tilt-and-turn positioner in front of it.
    pub fn irb1600_with_positioner() -> Robot {
        let text = include_str!("../../jobs/robots/irb1600_145_positioner.toml");
        Robot::new(RobotSpec::parse(text, Path::new("irb1600_145_positioner.toml")).unwrap())
    }

    /// The IRB 1600 on the track with the positioner too: every slot of the
    /// model moves some row.
    pub fn irb1600_in_full_cell() -> Robot {
        let text = format!(
            "{}\n[track]\ntravel_mm = [0.0, 3000.0]\n",
            include_str!("../../jobs/robots/irb1600_145_positioner.toml")
        );
        Robot::new(RobotSpec::parse(&text, Path::new("irb1600_full_cell.toml")).unwrap())
    }

    /// The shipped Franka Emika Panda file: a seven-joint arm.
    pub fn panda() -> Robot {
        let text = include_str!("../../jobs/robots/panda.toml");
        Robot::new(RobotSpec::parse(text, Path::new("panda.toml")).unwrap())
    }

    /// The shipped six-axis gantry: three prismatic joints, then a wrist.
    pub fn gantry() -> Robot {
        let text = include_str!("../../jobs/robots/gantry.toml");
        Robot::new(RobotSpec::parse(text, Path::new("gantry.toml")).unwrap())
    }

    /// The shipped UR10 file: an arm without a spherical wrist.
    pub fn ur10() -> Robot {
        let text = include_str!("../../jobs/robots/ur10.toml");
        Robot::new(RobotSpec::parse(text, Path::new("ur10.toml")).unwrap())
    }

    pub fn truth_params(robot: &Robot) -> ParamValues {
        let text = include_str!("../../jobs/truth/irb1600_paper.toml");
        ParamValues::with_overrides(robot.spec(), text, Path::new("irb1600_paper.toml")).unwrap()
    }

    pub fn random_q(robot: &Robot, rng: &mut impl Rng) -> [f64; MAX_JOINTS] {
        robot.joint_vector(|i| {
            let [lo, hi] = robot.joint_limits(i);
            rng.random_range(lo..hi)
        })
    }

    /// Forces within ±120 N and moments within ±10 N·m, as in the paper.
    pub fn random_wrench(rng: &mut impl Rng) -> Wrench {
        Wrench::from_array(std::array::from_fn(|i| {
            let bound = if i < 3 { 120.0 } else { 10.0 };
            rng.random_range(-bound..bound)
        }))
    }
}
