//! The robot file: a TOML description of one serial arm (nominal geometry, joint
//! limits, link inertia, payload, nominal world and tool transforms, optional
//! collision capsules).
//!
//! Parsing is strict: unknown keys are errors and every error names the key path
//! (`joints[2].a_mm`) and what was expected, because a silently ignored typo in a
//! robot file spoils a whole calibration. Values are in the units their names carry;
//! conversion to radians and metres happens in [`super::model`], nowhere else.

use std::path::{Path, PathBuf};

use schemars::JsonSchema;

use super::model::MAX_JOINTS;
use crate::toml_error::StrictError;
use serde::{Deserialize, Serialize};

/// How a joint moves: about its z axis, or along it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum JointKind {
    /// The joint value (deg) is added to the MDH angle θ.
    #[default]
    Revolute,
    /// The joint value (mm) is added to the MDH offset d; θ is fixed.
    Prismatic,
}

impl JointKind {
    fn is_revolute(&self) -> bool {
        *self == JointKind::Revolute
    }

    /// The unit of the joint's value, as table columns and messages spell it.
    pub fn unit(self) -> &'static str {
        match self {
            JointKind::Revolute => "deg",
            JointKind::Prismatic => "mm",
        }
    }
}

/// One joint (Craig's modified DH, `../shared/spec/model.md` §1) and the
/// link it moves: revolute (the default) or prismatic (`kind = "prismatic"`,
/// a gantry's axes).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct JointSpec {
    /// Revolute (default) or prismatic. Skipped when revolute, so files
    /// without it keep their content hash.
    #[serde(default, skip_serializing_if = "JointKind::is_revolute")]
    pub kind: JointKind,
    /// Twist about the previous x axis, degrees.
    pub alpha_deg: f64,
    /// Length along the previous x axis, millimetres.
    pub a_mm: f64,
    /// Constant added to the joint command to get the MDH angle, degrees;
    /// a prismatic joint's fixed MDH angle.
    pub theta_offset_deg: f64,
    /// Offset along the joint's z axis, millimetres; for a prismatic joint,
    /// added to its travel.
    pub d_mm: f64,
    /// Software joint limits `[min, max]` of a revolute joint, degrees.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub limits_deg: Option<[f64; 2]>,
    /// Software joint limits `[min, max]` of a prismatic joint's travel,
    /// millimetres.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub limits_mm: Option<[f64; 2]>,
    /// Mass of the link this joint moves, kilograms.
    pub link_mass_kg: f64,
    /// Centre of gravity of that link in the joint's own frame, millimetres.
    pub link_cog_mm: [f64; 3],
    /// Collision shape of the link in the joint's frame (for pose generation).
    #[serde(default)]
    pub capsule: Option<CapsuleSpec>,
    /// Highest joint speed from the vendor's data sheet, degrees per second.
    /// Optional; only the URDF export uses it (`<limit velocity>`), and says
    /// so where it is absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_velocity_deg_s: Option<f64>,
    /// Highest joint torque from the vendor's data sheet, newton metres.
    /// Optional; only the URDF export uses it (`<limit effort>`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_torque_nm: Option<f64>,
    /// Motor turns per joint turn of the reducer (for example 121 for an RV
    /// reducer). Optional; only the simulator uses it, for transmission
    /// errors at the motor's rate (`transmission_error_motor_deg`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gear_ratio: Option<f64>,
    /// Encoder pulses per degree of this axis as the controller counts them,
    /// signed (a Yaskawa controller's pulse ratio). Optional; only Yaskawa
    /// jobs in joint form (`POSTYPE PULSE`) need it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pulses_per_deg: Option<f64>,
}

impl JointSpec {
    /// Software limits `[min, max]` in the joint's unit (deg, or mm for a
    /// prismatic joint); validation makes sure the kind's key is there.
    pub fn limits(&self) -> [f64; 2] {
        match self.kind {
            JointKind::Revolute => self.limits_deg,
            JointKind::Prismatic => self.limits_mm,
        }
        .unwrap_or_default()
    }

    /// The limits' key for this kind of joint (for messages).
    pub fn limits_key(&self) -> &'static str {
        match self.kind {
            JointKind::Revolute => "limits_deg",
            JointKind::Prismatic => "limits_mm",
        }
    }

    /// The first key this joint's kind does not allow, and why: a revolute
    /// joint's limits are in degrees, a prismatic one's in millimetres, and
    /// the data-sheet values in degrees or N·m have no prismatic meaning.
    fn kind_problem(&self) -> Option<(&'static str, String)> {
        let (wanted, unwanted) = match self.kind {
            JointKind::Revolute => (&self.limits_deg, ("limits_mm", self.limits_mm.is_some())),
            JointKind::Prismatic => (&self.limits_mm, ("limits_deg", self.limits_deg.is_some())),
        };
        if unwanted.1 {
            return Some((
                unwanted.0,
                format!(
                    "a {} joint's limits are `{}`; remove `{}`",
                    self.kind_name(),
                    self.limits_key(),
                    unwanted.0
                ),
            ));
        }
        if wanted.is_none() {
            return Some((
                self.limits_key(),
                format!(
                    "expected the {} joint's limits [min, max]",
                    self.kind_name()
                ),
            ));
        }
        if self.kind == JointKind::Prismatic {
            let degree_keys = [
                ("max_velocity_deg_s", self.max_velocity_deg_s.is_some()),
                ("max_torque_nm", self.max_torque_nm.is_some()),
                ("gear_ratio", self.gear_ratio.is_some()),
                ("pulses_per_deg", self.pulses_per_deg.is_some()),
            ];
            if let Some((key, _)) = degree_keys.iter().find(|(_, present)| *present) {
                return Some((
                    key,
                    "is a revolute joint's value (degrees, N·m, turns); a prismatic joint has none: remove it".into(),
                ));
            }
        }
        None
    }

    fn kind_name(&self) -> &'static str {
        match self.kind {
            JointKind::Revolute => "revolute",
            JointKind::Prismatic => "prismatic",
        }
    }
}

/// A capsule: the set of points within `radius_mm` of the segment `from_mm`–`to_mm`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CapsuleSpec {
    pub from_mm: [f64; 3],
    pub to_mm: [f64; 3],
    pub radius_mm: f64,
}

/// A rigid transform written as the paper's eq. (3)/(4): `Rot(x,α)·Rot(y,β)·Rot(z,γ)·Trans(x,y,z)`.
/// The default is the identity.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct TransformSpec {
    pub x_mm: f64,
    pub y_mm: f64,
    pub z_mm: f64,
    pub alpha_deg: f64,
    pub beta_deg: f64,
    pub gamma_deg: f64,
}

/// A load carried by the tool, with its centre of gravity in the tool frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PayloadSpec {
    pub mass_kg: f64,
    pub cog_mm: [f64; 3],
}

/// How the controller numbers the joints where it differs from the robot
/// file (optional `[controller]` table); only the programs use it.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ControllerSpec {
    /// The controller's J3 is `q3 + j3_from_j2 · q2` (robot-file degrees):
    /// 1 or −1 on FANUC arms, whose J3 is the forearm's angle from the
    /// horizontal (the sign that keeps the forearm's direction when J2 alone
    /// moves); 0 (the default) where J3 is measured from the upper arm (ABB,
    /// KUKA, Yaskawa, Universal Robots).
    #[serde(default)]
    pub j3_from_j2: f64,
}

impl ControllerSpec {
    fn is_default(&self) -> bool {
        *self == ControllerSpec::default()
    }
}

/// The whole robot file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct RobotSpec {
    /// Human-readable model name, e.g. "ABB IRB 1600-6/1.45".
    pub name: String,
    /// Gravity in the base frame, m/s².
    #[serde(default = "default_gravity")]
    pub gravity_mps2: [f64; 3],
    /// Six or seven joints, base to flange (MDH), revolute or prismatic. A
    /// seventh joint's parameters are `dtheta7, dalpha7, da7, dd7, k7`, and
    /// its column `q7_deg`; a prismatic joint's column is `q{i}_mm`.
    #[schemars(length(min = 6, max = 7))]
    pub joints: Vec<JointSpec>,
    /// Nominal world (tracker) ← base transform. Optional: identification registers
    /// the frames onto the measurements in closed form (spec §7), so a tracker
    /// standing wherever it was put needs no values here (identity when absent).
    #[serde(default)]
    pub world: TransformSpec,
    /// Whether the file has a `[world]` table (stages that place the tracker
    /// from it need one); set by [`RobotSpec::parse`].
    #[serde(skip)]
    pub has_world: bool,
    /// The file it was read from, for messages; set by [`RobotSpec::parse`].
    #[serde(skip)]
    pub path: PathBuf,
    /// Nominal flange → tool (SMR) transform; its translation is registered like
    /// the world frame (identity when absent).
    #[serde(default)]
    pub tool: TransformSpec,
    #[serde(default = "no_payload")]
    pub payload: PayloadSpec,
    /// The controller's joint numbering, where it is not the robot file's.
    /// Skipped when default, so files without it keep their content hash.
    #[serde(default, skip_serializing_if = "ControllerSpec::is_default")]
    pub controller: ControllerSpec,
    /// A linear track carrying the arm (optional); rows then record the
    /// carriage's position `e1_mm`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub track: Option<super::track::TrackSpec>,
    /// A one- or two-axis positioner carrying the work (optional); rows
    /// then record its axes' values `p1_deg`, `p2_deg`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub positioner: Option<super::positioner::PositionerSpec>,
}

fn default_gravity() -> [f64; 3] {
    [0.0, 0.0, -9.81]
}

fn no_payload() -> PayloadSpec {
    PayloadSpec {
        mass_kg: 0.0,
        cog_mm: [0.0; 3],
    }
}

/// Why a robot file was rejected.
#[derive(Debug, thiserror::Error)]
pub enum RobotFileError {
    #[error("cannot read robot file {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("robot file {path}: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("robot file {path}: key `{key}`: {message}")]
    Invalid {
        path: PathBuf,
        key: String,
        message: String,
    },
}

impl RobotSpec {
    /// Reads and validates a robot file.
    pub fn load(path: &Path) -> Result<Self, RobotFileError> {
        let text = std::fs::read_to_string(path).map_err(|source| RobotFileError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(&text, path)
    }

    /// Parses robot-file text; `path` is only used in error messages.
    pub fn parse(text: &str, path: &Path) -> Result<Self, RobotFileError> {
        let spec: RobotSpec = crate::toml_error::from_str_strict(text).map_err(|e| match e {
            StrictError::Syntax(message) => RobotFileError::Parse {
                path: path.to_path_buf(),
                message,
            },
            StrictError::Invalid { key, message } => RobotFileError::Invalid {
                path: path.to_path_buf(),
                key,
                message,
            },
        })?;
        let mut spec = spec;
        spec.path = path.to_path_buf();
        spec.has_world = text
            .parse::<toml::Table>()
            .is_ok_and(|table| table.contains_key("world"));
        spec.validate(path)?;
        Ok(spec)
    }

    /// Every number finite and within what a real arm can have, limits ordered,
    /// masses and radii positive: a value beyond [`MAX_LENGTH_MM`] or a limit
    /// beyond [`MAX_JOINT_TRAVEL_DEG`] is a typo, and a typo in a robot file spoils
    /// every stage after it.
    fn validate(&self, path: &Path) -> Result<(), RobotFileError> {
        let invalid = |key: String, message: String| RobotFileError::Invalid {
            path: path.to_path_buf(),
            key,
            message,
        };
        if !(6..=MAX_JOINTS).contains(&self.joints.len()) {
            return Err(invalid(
                "joints".into(),
                format!(
                    "expected 6 or {MAX_JOINTS} joints (a six- or seven-axis arm), found {}",
                    self.joints.len()
                ),
            ));
        }
        let mut checks: Vec<(String, &[f64], Bound)> = vec![
            ("gravity_mps2".into(), &self.gravity_mps2, Bound::Gravity),
            (
                "payload.mass_kg".into(),
                std::slice::from_ref(&self.payload.mass_kg),
                Bound::Mass,
            ),
            ("payload.cog_mm".into(), &self.payload.cog_mm, Bound::Length),
        ];
        for (name, frame) in [("world", &self.world), ("tool", &self.tool)] {
            checks.push((
                format!("{name}.x_mm"),
                std::slice::from_ref(&frame.x_mm),
                Bound::Length,
            ));
            checks.push((
                format!("{name}.y_mm"),
                std::slice::from_ref(&frame.y_mm),
                Bound::Length,
            ));
            checks.push((
                format!("{name}.z_mm"),
                std::slice::from_ref(&frame.z_mm),
                Bound::Length,
            ));
            checks.push((
                format!("{name}.alpha_deg"),
                std::slice::from_ref(&frame.alpha_deg),
                Bound::Angle,
            ));
            checks.push((
                format!("{name}.beta_deg"),
                std::slice::from_ref(&frame.beta_deg),
                Bound::Angle,
            ));
            checks.push((
                format!("{name}.gamma_deg"),
                std::slice::from_ref(&frame.gamma_deg),
                Bound::Angle,
            ));
        }
        for (i, joint) in self.joints.iter().enumerate() {
            let key = |name: &str| format!("joints[{i}].{name}");
            checks.push((
                key("alpha_deg"),
                std::slice::from_ref(&joint.alpha_deg),
                Bound::Angle,
            ));
            checks.push((
                key("a_mm"),
                std::slice::from_ref(&joint.a_mm),
                Bound::Length,
            ));
            checks.push((
                key("theta_offset_deg"),
                std::slice::from_ref(&joint.theta_offset_deg),
                Bound::Angle,
            ));
            checks.push((
                key("d_mm"),
                std::slice::from_ref(&joint.d_mm),
                Bound::Length,
            ));
            if let Some((name, message)) = joint.kind_problem() {
                return Err(invalid(key(name), message));
            }
            match (&joint.limits_deg, &joint.limits_mm) {
                (Some(limits), _) => checks.push((key("limits_deg"), limits, Bound::Travel)),
                (_, Some(limits)) => checks.push((key("limits_mm"), limits, Bound::Length)),
                (None, None) => {}
            }
            checks.push((
                key("link_mass_kg"),
                std::slice::from_ref(&joint.link_mass_kg),
                Bound::Mass,
            ));
            checks.push((key("link_cog_mm"), &joint.link_cog_mm, Bound::Length));
            if let Some(speed) = &joint.max_velocity_deg_s {
                checks.push((
                    key("max_velocity_deg_s"),
                    std::slice::from_ref(speed),
                    Bound::Speed,
                ));
            }
            if let Some(torque) = &joint.max_torque_nm {
                checks.push((
                    key("max_torque_nm"),
                    std::slice::from_ref(torque),
                    Bound::Torque,
                ));
            }
            if let Some(ratio) = &joint.gear_ratio {
                checks.push((
                    key("gear_ratio"),
                    std::slice::from_ref(ratio),
                    Bound::GearRatio,
                ));
            }
            if let Some(pulses) = &joint.pulses_per_deg {
                checks.push((
                    key("pulses_per_deg"),
                    std::slice::from_ref(pulses),
                    Bound::PulseRatio,
                ));
            }
            if let Some(capsule) = &joint.capsule {
                checks.push((key("capsule.from_mm"), &capsule.from_mm, Bound::Length));
                checks.push((key("capsule.to_mm"), &capsule.to_mm, Bound::Length));
                checks.push((
                    key("capsule.radius_mm"),
                    std::slice::from_ref(&capsule.radius_mm),
                    Bound::Radius,
                ));
            }
        }
        for (key, values, bound) in checks {
            if let Some(expected) = values.iter().find_map(|v| bound.violated_by(*v)) {
                let found = match values {
                    [one] => format!("{one}"),
                    many => format!("{many:?}"),
                };
                return Err(invalid(key, format!("expected {expected}, found {found}")));
            }
        }
        if let Some(track) = &self.track {
            let [lo, hi] = track.travel_mm;
            if !(lo.is_finite()
                && hi.is_finite()
                && lo < hi
                && lo.abs().max(hi.abs()) <= MAX_LENGTH_MM)
            {
                return Err(invalid(
                    "track.travel_mm".into(),
                    format!(
                        "expected [min, max] with min < max within ±{MAX_LENGTH_MM} mm, found [{lo}, {hi}]"
                    ),
                ));
            }
            if let Some(expected) = track
                .pulses_per_mm
                .and_then(|ratio| Bound::PulseRatio.violated_by(ratio))
            {
                return Err(invalid(
                    "track.pulses_per_mm".into(),
                    format!(
                        "expected {expected}, found {}",
                        track.pulses_per_mm.unwrap_or_default()
                    ),
                ));
            }
            if !(1..=super::track::MAX_TRACK_ORDER).contains(&track.polynomial_order) {
                return Err(invalid(
                    "track.polynomial_order".into(),
                    format!(
                        "expected 1 to {}, found {}",
                        super::track::MAX_TRACK_ORDER,
                        track.polynomial_order
                    ),
                ));
            }
        }
        if let Some(positioner) = &self.positioner {
            positioner_problem(positioner).map_or(Ok(()), |(key, message)| {
                Err(invalid(format!("positioner.{key}"), message))
            })?;
        }
        if ![-1.0, 0.0, 1.0].contains(&self.controller.j3_from_j2) {
            return Err(invalid(
                "controller.j3_from_j2".into(),
                format!(
                    "expected -1, 0 or 1 (the controller's J3 is q3 + j3_from_j2 * q2), found {}",
                    self.controller.j3_from_j2
                ),
            ));
        }
        for (i, joint) in self.joints.iter().enumerate() {
            let [lo, hi] = joint.limits();
            if lo >= hi {
                return Err(invalid(
                    format!("joints[{i}].{}", joint.limits_key()),
                    format!("expected [min, max] with min < max, found [{lo}, {hi}]"),
                ));
            }
        }
        Ok(())
    }

    /// Which joints are prismatic, as a joint vector's mask.
    pub fn prismatic_joints(&self) -> [bool; MAX_JOINTS] {
        std::array::from_fn(|i| {
            self.joints
                .get(i)
                .is_some_and(|j| j.kind == JointKind::Prismatic)
        })
    }

    /// The joint values the controller shows for the robot-file command
    /// `q_deg` (deg): the same but for a FANUC-style J3 (`[controller]`).
    pub fn controller_joints_deg(&self, q_deg: &[f64; MAX_JOINTS]) -> [f64; MAX_JOINTS] {
        let mut controller = *q_deg;
        controller[2] += self.controller.j3_from_j2 * q_deg[1];
        controller
    }

    /// The robot-file command of the controller's joint values (deg): the
    /// inverse of [`RobotSpec::controller_joints_deg`].
    pub fn robot_file_joints_deg(&self, controller_deg: &[f64; MAX_JOINTS]) -> [f64; MAX_JOINTS] {
        let mut q_deg = *controller_deg;
        q_deg[2] -= self.controller.j3_from_j2 * controller_deg[1];
        q_deg
    }

    /// Blake3 hash of the canonical form (so whitespace or comment edits do not
    /// invalidate caches, but any value change does).
    pub fn content_hash(&self) -> String {
        let canonical = serde_json::to_vec(self).expect("robot spec serialises to JSON");
        blake3::hash(&canonical).to_hex().to_string()
    }
}

/// Largest length in a robot file that is not a typo (mm; 100 m).
pub const MAX_LENGTH_MM: f64 = 1.0e5;
/// Largest joint travel from zero that is not a typo (deg; 100 turns, beyond the
/// endless sixth axes of some arms).
pub const MAX_JOINT_TRAVEL_DEG: f64 = 36_000.0;
/// Largest link or payload mass that is not a typo (kg).
const MAX_MASS_KG: f64 = 1.0e5;
/// Largest gravity component that is not a typo (m/s²).
const MAX_GRAVITY_MPS2: f64 = 100.0;
/// Largest joint speed that is not a typo (deg/s; an industrial wrist axis
/// turns at most about 1000°/s).
const MAX_JOINT_SPEED_DEG_S: f64 = 10_000.0;
/// Largest joint torque that is not a typo (N·m; the largest arms' base axes
/// stay below 1e5).
const MAX_JOINT_TORQUE_NM: f64 = 1.0e6;
/// Largest reducer ratio that is not a typo (harmonic drives reach 160,
/// cascaded reducers a few hundred).
const MAX_GEAR_RATIO: f64 = 10_000.0;
/// Largest pulse ratio that is not a typo (pulses per degree of the axis).
const MAX_PULSES_PER_DEG: f64 = 1.0e6;

/// The first problem of a `[positioner]` table: its key (below
/// `positioner.`) and what was expected.
fn positioner_problem(spec: &super::positioner::PositionerSpec) -> Option<(String, String)> {
    use super::positioner::{MAX_POSITIONER_AXES, MAX_POSITIONER_NESTS};
    if !(1..=MAX_POSITIONER_AXES).contains(&spec.axes.len()) {
        return Some((
            "axes".into(),
            format!(
                "expected 1 to {MAX_POSITIONER_AXES} axes, found {}",
                spec.axes.len()
            ),
        ));
    }
    let b = &spec.base;
    let mut checks: Vec<(String, f64, Bound)> = vec![
        ("base.x_mm".into(), b.x_mm, Bound::Length),
        ("base.y_mm".into(), b.y_mm, Bound::Length),
        ("base.z_mm".into(), b.z_mm, Bound::Length),
        ("base.alpha_deg".into(), b.alpha_deg, Bound::Angle),
        ("base.beta_deg".into(), b.beta_deg, Bound::Angle),
        ("base.gamma_deg".into(), b.gamma_deg, Bound::Angle),
    ];
    for (k, axis) in spec.axes.iter().enumerate() {
        let key = |name: &str| format!("axes[{k}].{name}");
        checks.push((key("alpha_deg"), axis.alpha_deg, Bound::Angle));
        checks.push((key("a_mm"), axis.a_mm, Bound::Length));
        checks.push((key("theta_offset_deg"), axis.theta_offset_deg, Bound::Angle));
        checks.push((key("d_mm"), axis.d_mm, Bound::Length));
        checks.push((key("limits_deg"), axis.limits_deg[0], Bound::Travel));
        checks.push((key("limits_deg"), axis.limits_deg[1], Bound::Travel));
        if let Some(ratio) = axis.pulses_per_deg {
            checks.push((key("pulses_per_deg"), ratio, Bound::PulseRatio));
        }
    }
    if let Some((key, value, expected)) = checks
        .into_iter()
        .find_map(|(key, value, bound)| bound.violated_by(value).map(|e| (key, value, e)))
    {
        return Some((key, format!("expected {expected}, found {value}")));
    }
    if let Some((k, [lo, hi])) = spec
        .axes
        .iter()
        .map(|a| a.limits_deg)
        .enumerate()
        .find(|(_, [lo, hi])| lo >= hi)
    {
        return Some((
            format!("axes[{k}].limits_deg"),
            format!("expected [min, max] with min < max, found [{lo}, {hi}]"),
        ));
    }
    if !(1..=MAX_POSITIONER_NESTS).contains(&spec.nests.len()) {
        return Some((
            "nests".into(),
            format!(
                "expected the target ids of 1 to {MAX_POSITIONER_NESTS} SMR nests on the table, found {}",
                spec.nests.len()
            ),
        ));
    }
    for (k, nest) in spec.nests.iter().enumerate() {
        if nest.trim().is_empty() || nest.trim() != nest {
            return Some((
                format!("nests[{k}]"),
                format!("expected a target id without surrounding spaces, found {nest:?}"),
            ));
        }
        if spec.nests[..k].contains(nest) {
            return Some((
                format!("nests[{k}]"),
                format!("the nest {nest:?} is listed twice"),
            ));
        }
    }
    None
}

/// What a number of the robot file must satisfy besides being finite.
#[derive(Debug, Clone, Copy)]
enum Bound {
    Length,
    Angle,
    Travel,
    Mass,
    Radius,
    Gravity,
    Speed,
    Torque,
    GearRatio,
    PulseRatio,
}

impl Bound {
    /// What was expected, when `value` breaks the bound.
    fn violated_by(self, value: f64) -> Option<String> {
        let (ok, expected) = match self {
            Bound::Length => (
                value.abs() <= MAX_LENGTH_MM,
                format!("a length within ±{MAX_LENGTH_MM} mm"),
            ),
            Bound::Angle => (value.abs() <= 360.0, "an angle within ±360°".to_string()),
            Bound::Travel => (
                value.abs() <= MAX_JOINT_TRAVEL_DEG,
                format!("joint limits within ±{MAX_JOINT_TRAVEL_DEG}°"),
            ),
            Bound::Mass => (
                (0.0..=MAX_MASS_KG).contains(&value),
                format!("a mass >= 0 and at most {MAX_MASS_KG} kg"),
            ),
            Bound::Radius => (
                value > 0.0 && value <= MAX_LENGTH_MM,
                format!("a radius > 0 and at most {MAX_LENGTH_MM} mm"),
            ),
            Bound::Gravity => (
                value.abs() <= MAX_GRAVITY_MPS2,
                format!("components within ±{MAX_GRAVITY_MPS2} m/s²"),
            ),
            // Zero would tell a planner the joint cannot move.
            Bound::Speed => (
                value > 0.0 && value <= MAX_JOINT_SPEED_DEG_S,
                format!("a joint speed > 0 and at most {MAX_JOINT_SPEED_DEG_S} deg/s"),
            ),
            Bound::Torque => (
                value > 0.0 && value <= MAX_JOINT_TORQUE_NM,
                format!("a joint torque > 0 and at most {MAX_JOINT_TORQUE_NM} N·m"),
            ),
            // Below 1 the "reducer" would speed the joint up; industrial
            // reducers stay below a few hundred.
            Bound::GearRatio => (
                (1.0..=MAX_GEAR_RATIO).contains(&value),
                format!("a gear ratio (motor turns per joint turn) from 1 to {MAX_GEAR_RATIO}"),
            ),
            // Signed; encoders count from tens to a few thousand pulses per
            // degree of the axis.
            Bound::PulseRatio => (
                (1.0..=MAX_PULSES_PER_DEG).contains(&value.abs()),
                format!(
                    "encoder pulses per degree, signed, of magnitude 1 to {MAX_PULSES_PER_DEG}"
                ),
            ),
        };
        // NaN fails every comparison above, so it lands here too.
        (!ok).then_some(expected)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::joint_array;

    const IRB1600: &str = include_str!("../../jobs/robots/irb1600_145.toml");

    #[test]
    fn shipped_robot_file_parses() {
        let spec = RobotSpec::parse(IRB1600, Path::new("irb1600_145.toml")).unwrap();
        assert_eq!(spec.joints.len(), 6);
        assert_eq!(spec.joints[0].d_mm, 486.5);
        assert_eq!(spec.world.x_mm, 1326.0);
    }

    #[test]
    fn unknown_key_is_named() {
        let text = IRB1600.replacen("a_mm = 150.0", "a_mn = 150.0", 1);
        let err = RobotSpec::parse(&text, Path::new("r.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("joints[1]"), "{err}");
        assert!(err.contains("a_mn"), "{err}");
    }

    #[test]
    fn wrong_type_is_named_with_key_path() {
        let text = IRB1600.replacen("d_mm = 486.5", "d_mm = \"tall\"", 1);
        let err = RobotSpec::parse(&text, Path::new("r.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("joints[0].d_mm"), "{err}");
        assert!(err.contains("line"), "{err}");
    }

    #[test]
    fn the_controller_section_is_optional_checked_and_keeps_old_hashes() {
        let plain = RobotSpec::parse(IRB1600, Path::new("r.toml")).unwrap();
        assert_eq!(plain.controller.j3_from_j2, 0.0);
        let q = [10.0, 20.0, -30.0, 40.0, 50.0, 60.0];
        assert_eq!(
            plain.controller_joints_deg(&joint_array(&q)),
            joint_array(&q)
        );
        // An explicit default is the same robot, with the same cache key.
        let explicit = RobotSpec::parse(
            &format!("{IRB1600}\n[controller]\nj3_from_j2 = 0.0\n"),
            Path::new("r.toml"),
        )
        .unwrap();
        assert_eq!(explicit.content_hash(), plain.content_hash());
        let fanuc = RobotSpec::parse(
            &format!("{IRB1600}\n[controller]\nj3_from_j2 = 1.0\n"),
            Path::new("r.toml"),
        )
        .unwrap();
        assert_ne!(fanuc.content_hash(), plain.content_hash());
        assert_eq!(
            fanuc.controller_joints_deg(&joint_array(&q)),
            [10.0, 20.0, -10.0, 40.0, 50.0, 60.0, 0.0]
        );
        assert_eq!(
            fanuc.robot_file_joints_deg(&fanuc.controller_joints_deg(&joint_array(&q))),
            joint_array(&q)
        );
        let err = RobotSpec::parse(
            &format!("{IRB1600}\n[controller]\nj3_from_j2 = 0.5\n"),
            Path::new("r.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("controller.j3_from_j2") && err.contains("-1, 0 or 1"),
            "{err}"
        );
        let text = IRB1600.replacen(
            "max_velocity_deg_s = 150.0",
            "max_velocity_deg_s = 150.0\npulses_per_deg = 0.2",
            1,
        );
        let err = RobotSpec::parse(&text, Path::new("r.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("joints[0].pulses_per_deg"), "{err}");
        let text = IRB1600.replacen(
            "max_velocity_deg_s = 150.0",
            "max_velocity_deg_s = 150.0\npulses_per_deg = -1341.5",
            1,
        );
        let spec = RobotSpec::parse(&text, Path::new("r.toml")).unwrap();
        assert_eq!(spec.joints[0].pulses_per_deg, Some(-1341.5));
    }

    #[test]
    fn a_track_s_keys_are_checked_naming_them() {
        let parse = |track: &str| {
            RobotSpec::parse(
                &format!("{IRB1600}\n[track]\n{track}\n"),
                Path::new("r.toml"),
            )
        };
        for (track, key) in [
            ("travel_mm = [3000.0, 0.0]", "track.travel_mm"),
            ("travel_mm = [0.0, 1e9]", "track.travel_mm"),
            (
                "travel_mm = [0.0, 3000.0]\npolynomial_order = 4",
                "track.polynomial_order",
            ),
            (
                "travel_mm = [0.0, 3000.0]\npulses_per_mm = 0.001",
                "track.pulses_per_mm",
            ),
        ] {
            let err = parse(track).unwrap_err().to_string();
            assert!(err.contains(key), "{track}: {err}");
        }
        let spec = parse("travel_mm = [0.0, 3000.0]\npulses_per_mm = -812.5").unwrap();
        assert_eq!(spec.track.and_then(|t| t.pulses_per_mm), Some(-812.5));
    }

    /// A tilt-and-turn positioner's table, with `{}` replaced by one change.
    const POSITIONER: &str = r#"
[positioner]
base = { x_mm = 1200.0, y_mm = 0.0, z_mm = 400.0, alpha_deg = 90.0, beta_deg = 0.0, gamma_deg = 0.0 }
nests = ["table_a", "table_b"]
[[positioner.axes]]
alpha_deg = 0.0
a_mm = 0.0
theta_offset_deg = 0.0
d_mm = 0.0
limits_deg = [-95.0, 95.0]
[[positioner.axes]]
alpha_deg = -90.0
a_mm = 0.0
theta_offset_deg = 0.0
d_mm = 350.0
limits_deg = [-360.0, 360.0]
"#;

    #[test]
    fn a_positioner_s_keys_are_checked_naming_them() {
        let parse =
            |text: &str| RobotSpec::parse(&format!("{IRB1600}\n{text}"), Path::new("r.toml"));
        let spec = parse(POSITIONER).unwrap();
        let positioner = spec.positioner.unwrap();
        assert_eq!(positioner.axes.len(), 2);
        assert_eq!(positioner.nests, ["table_a", "table_b"]);
        for (from, to, key) in [
            ("d_mm = 350.0", "d_mm = 3.5e9", "positioner.axes[1].d_mm"),
            (
                "[-95.0, 95.0]",
                "[95.0, -95.0]",
                "positioner.axes[0].limits_deg",
            ),
            ("\"table_b\"]", "\"table_a\"]", "positioner.nests[1]"),
            (
                "nests = [\"table_a\", \"table_b\"]",
                "nests = []",
                "positioner.nests",
            ),
            (
                "alpha_deg = 90.0",
                "alpha_deg = 900.0",
                "positioner.base.alpha_deg",
            ),
            ("d_mm = 0.0\n", "d_mm = 0.0\nspeed = 1\n", "speed"),
            (
                "d_mm = 350.0\n",
                "d_mm = 350.0\npulses_per_deg = 0.0\n",
                "positioner.axes[1].pulses_per_deg",
            ),
        ] {
            assert!(POSITIONER.contains(from), "{from}");
            let err = parse(&POSITIONER.replacen(from, to, 1))
                .unwrap_err()
                .to_string();
            assert!(err.contains(key), "{to}: {err}");
        }
        let three_axes = format!(
            "{POSITIONER}[[positioner.axes]]\nalpha_deg = 0.0\na_mm = 0.0\ntheta_offset_deg = 0.0\nd_mm = 0.0\nlimits_deg = [-1.0, 1.0]\n"
        );
        let err = parse(&three_axes).unwrap_err().to_string();
        assert!(
            err.contains("positioner.axes") && err.contains("1 to 2"),
            "{err}"
        );
    }

    #[test]
    fn world_and_tool_may_be_left_out() {
        let start = IRB1600.find("[world]").unwrap();
        let end = IRB1600[start..]
            .find("[payload]")
            .map_or(IRB1600.len(), |e| start + e);
        let text = format!("{}{}", &IRB1600[..start], &IRB1600[end..]);
        assert!(!text.contains("[tool]"), "{text}");
        let spec = RobotSpec::parse(&text, Path::new("r.toml")).unwrap();
        assert_eq!(spec.world, TransformSpec::default());
        assert_eq!(spec.tool.z_mm, 0.0);
    }

    #[test]
    fn joint_speed_and_torque_are_optional_and_checked() {
        let spec = RobotSpec::parse(IRB1600, Path::new("r.toml")).unwrap();
        assert_eq!(spec.joints[0].max_velocity_deg_s, Some(150.0));
        assert_eq!(spec.joints[0].max_torque_nm, None);
        let text = IRB1600.replacen("max_velocity_deg_s = 150.0", "max_velocity_deg_s = 0.0", 1);
        let err = RobotSpec::parse(&text, Path::new("r.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("joints[0].max_velocity_deg_s") && err.contains("> 0"),
            "{err}"
        );
        let text = IRB1600.replacen(
            "max_velocity_deg_s = 150.0",
            "max_velocity_deg_s = 150.0\nmax_torque_nm = -3.0",
            1,
        );
        let err = RobotSpec::parse(&text, Path::new("r.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("joints[0].max_torque_nm"), "{err}");
    }

    #[test]
    fn a_gear_ratio_is_optional_and_checked() {
        let with = |ratio: &str| {
            let text = IRB1600.replacen(
                "max_velocity_deg_s = 150.0",
                &format!("max_velocity_deg_s = 150.0\ngear_ratio = {ratio}"),
                1,
            );
            RobotSpec::parse(&text, Path::new("r.toml"))
        };
        assert_eq!(with("121.0").unwrap().joints[0].gear_ratio, Some(121.0));
        for bad in ["0.5", "nan", "1e6"] {
            let err = with(bad).unwrap_err().to_string();
            assert!(
                err.contains("joints[0].gear_ratio") && err.contains("from 1 to"),
                "{bad}: {err}"
            );
        }
    }

    #[test]
    fn a_file_without_speeds_hashes_as_before_they_existed() {
        // Absent optional keys are not serialised: adding them to the format
        // must not change the cache key of every robot file.
        let spec = RobotSpec::parse(IRB1600, Path::new("r.toml")).unwrap();
        let json = serde_json::to_string(&spec).unwrap();
        assert!(!json.contains("max_torque_nm"), "{json}");
    }

    #[test]
    fn bad_limits_are_named() {
        let text = IRB1600.replacen(
            "limits_deg = [-180.0, 180.0]",
            "limits_deg = [10.0, -10.0]",
            1,
        );
        let err = RobotSpec::parse(&text, Path::new("r.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("joints[0].limits_deg"), "{err}");
    }
}
