//! The cable-driven parallel robot (CDPR) that loads the arm during elasto-geometric
//! calibration: eight cables run from anchors on a fixed frame to the corners of a
//! cube platform rigidly attached to the robot's tool, and their tensions apply a
//! chosen wrench to the tool.
//!
//! What this module does:
//! * [`CableRobotSpec`]: the CDPR geometry and tension limits, parsed strictly from
//!   TOML (`jobs/cdpr/default.toml` holds the default) and validated with errors that
//!   name the key.
//! * [`structure_matrix`]: the 6×8 wrench matrix (Roberts et al. 1998; Pott,
//!   *Cable-Driven Parallel Robots*, 2018, §3) mapping cable tensions to the wrench
//!   on the platform, in tool axes at the tool origin.
//! * [`check_wrench`]: whether a wrench is achievable with tensions inside
//!   `[min_tension_n, max_tension_n]` (a QP solved with Clarabel, which also returns
//!   the minimum-norm tension distribution), and the capacity margin — the signed
//!   distance to the boundary of the available wrench set — by the hyperplane-shifting
//!   method (Gouttefarde & Krut, "Characterization of parallel manipulator available
//!   wrench set facets", ARK 2010; Guay, Cardou, Cruz-Ruiz & Caro, "Measuring how well
//!   a structure supports varying external wrenches", 2014).
//!
//! What it does not do: cable sag, elasticity or pulley geometry (cables are massless
//! straight lines from anchor point to attachment point), the platform's own weight
//! (add it to the requested wrench if it matters), cable–cable, cable–platform or
//! cable–robot interference, or dynamics. Lengths are millimetres in the spec and in
//! [`crate::robot::frame::Frame`]; moments are N·m.

mod error;
mod solver;
mod spec;
mod wrench;

pub use error::CdprError;
pub use spec::{CABLE_COUNT, CableRobotSpec};
pub use wrench::{AvailableWrenchSet, Feasibility, check_wrench, structure_matrix};
