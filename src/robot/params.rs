//! The 42 calibration parameters (`../shared/spec/model.md` §4): names, units, a
//! full value set, and a selection of which are free.
//!
//! A seventh joint (issue #30) extends the 42 by their rule: `dtheta7, dalpha7,
//! da7, dd7, k7`, in slots after all others so a six-joint arm's columns keep
//! their order.
//!
//! Several targets (spec §7): each target (SMR nest) has its own flange → target
//! translation. Target 0 uses `x_t, y_t, z_t`; targets 1.. have slots of their own
//! after the 42, so a value set stays a fixed-size, copyable array. How a target
//! translation is named in a table (`x_t[nest2]`) is the table layer's business.
//!
//! Values are stored as the spec's table shows them: world and tool parameters are
//! absolute (x_w = 1326 mm), all others are errors added to the robot file's nominal
//! MDH values, and compliances are in deg/(N·m). The index order is the spec's table
//! order and is the column order of every identification Jacobian.

use std::fmt;
use std::path::{Path, PathBuf};

use super::file::{RobotSpec, TransformSpec};

/// Number of candidate parameters of a one-target cell (spec §4).
pub const BASE_PARAM_COUNT: usize = 42;

/// Targets (SMR nests) one calibration can fit jointly.
pub const MAX_TARGETS: usize = 8;

/// Slots of the 42 and the further targets' translations.
const TARGETED_PARAM_COUNT: usize = BASE_PARAM_COUNT + 3 * (MAX_TARGETS - 1);

/// Highest order of the transmission-error harmonics a joint can carry
/// (`eg_harmonic`): once, twice and three times per output turn.
pub const MAX_HARMONIC_ORDER: usize = 3;

/// Slots of the joint-error terms beyond the paper (issue #29): a backlash per
/// joint, then per joint and order a sine and a cosine coefficient.
const JOINT_TERM_COUNT: usize = MAX_JOINTS + 2 * MAX_JOINTS * MAX_HARMONIC_ORDER;

/// First slot of the track's error terms (issue #30).
const TRACK_START: usize = TARGETED_PARAM_COUNT + JOINT_TERM_COUNT;

/// First slot of the positioner's terms (issue #30).
const POSITIONER_START: usize = TRACK_START + TRACK_TERM_COUNT;

/// First slot of a seventh joint's MDH errors and compliance (issue #30):
/// after every other slot, so a six-joint arm's slots keep their order.
const SEVENTH_JOINT_START: usize = POSITIONER_START + POSITIONER_TERM_COUNT;

/// A seventh joint's `dtheta7, dalpha7, da7, dd7, k7`.
const SEVENTH_JOINT_COUNT: usize = 5;

/// Value slots: the 42, one translation triple per further target, the
/// joint-error terms, the track's error terms, the positioner's, then a
/// seventh joint's.
pub const PARAM_COUNT: usize = SEVENTH_JOINT_START + SEVENTH_JOINT_COUNT;

/// Names of a seventh joint's slots, in slot order (the rule of the 42:
/// kind, then the joint's number).
const SEVENTH_JOINT_NAMES: [&str; SEVENTH_JOINT_COUNT] = ["dtheta7", "dalpha7", "da7", "dd7", "k7"];

use super::model::MAX_JOINTS;
use super::positioner::{POSITIONER_TERM_COUNT, PositionerTerm};
use super::track::{TRACK_TERM_COUNT, TrackTerm};

/// One of the parameters, by its slot: the spec's 42 in its order, then the
/// translations of targets 1.. .
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct ParamId(u8);

/// A joint's MDH error or compliance, in the order of the 42's blocks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JointParam {
    Theta = 0,
    Alpha = 1,
    A = 2,
    D = 3,
    Compliance = 4,
}

/// What a parameter is, for the Jacobian and for display.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParamKind {
    /// World ← base translation along axis 0, 1, 2 (mm).
    WorldTranslation(usize),
    /// World ← base rotation, eq. (3) order x, y, z (deg).
    WorldRotation(usize),
    /// Flange → tool translation of one target along axis 0, 1, 2 (mm).
    ToolTranslation { target: usize, axis: usize },
    /// Flange → tool rotation, eq. (4) order x, y, z (deg).
    ToolRotation(usize),
    /// Joint offset error of joint 0..6 (deg).
    Theta(usize),
    /// Twist error (deg).
    Alpha(usize),
    /// Length error (mm).
    A(usize),
    /// Offset error (mm).
    D(usize),
    /// Joint compliance (deg/(N·m)).
    Compliance(usize),
    /// Half the dead band of joint 0..6 (deg): the joint sits this far past its
    /// command in the direction it approached from (`dir1..dir6`, spec §8).
    Backlash(usize),
    /// Coefficient (deg) of `sin(order·q)` (or `cos`) in the transmission
    /// error of `joint`, q its reading.
    Harmonic {
        joint: usize,
        order: usize,
        cosine: bool,
    },
    /// A coefficient of the track's errors along its travel (mm or deg).
    Track(TrackTerm),
    /// The positioner's base frame or an error of one of its axes.
    Positioner(PositionerTerm),
}

const NAMES: [&str; BASE_PARAM_COUNT] = [
    "x_w", "y_w", "z_w", "alpha_w", "beta_w", "gamma_w", "x_t", "y_t", "z_t", "alpha_t", "beta_t",
    "gamma_t", "dtheta1", "dtheta2", "dtheta3", "dtheta4", "dtheta5", "dtheta6", "dalpha1",
    "dalpha2", "dalpha3", "dalpha4", "dalpha5", "dalpha6", "da1", "da2", "da3", "da4", "da5",
    "da6", "dd1", "dd2", "dd3", "dd4", "dd5", "dd6", "k1", "k2", "k3", "k4", "k5", "k6",
];

/// Names of the translations of targets 1.. when no target ids are known.
static TARGET_NAMES: std::sync::LazyLock<Vec<String>> = std::sync::LazyLock::new(|| {
    (1..MAX_TARGETS)
        .flat_map(|target| ["x_t", "y_t", "z_t"].map(|axis| format!("{axis}[#{target}]")))
        .collect()
});

/// Names of the joint-error terms, in slot order: `backlash1..6`, then per joint
/// and order `sin{n}q{j}` and `cos{n}q{j}` (the coefficient of sin(n·q_j)).
static JOINT_TERM_NAMES: std::sync::LazyLock<Vec<String>> = std::sync::LazyLock::new(|| {
    (0..JOINT_TERM_COUNT)
        .map(
            |slot| match ParamId((TARGETED_PARAM_COUNT + slot) as u8).kind() {
                ParamKind::Backlash(joint) => format!("backlash{}", joint + 1),
                ParamKind::Harmonic {
                    joint,
                    order,
                    cosine,
                } => format!(
                    "{}{order}q{}",
                    if cosine { "cos" } else { "sin" },
                    joint + 1
                ),
                other => unreachable!("slot {slot} is a joint term, not {other:?}"),
            },
        )
        .collect()
});

/// Names of the track's error terms, in slot order.
static TRACK_TERM_NAMES: std::sync::LazyLock<Vec<String>> = std::sync::LazyLock::new(|| {
    (0..TRACK_TERM_COUNT)
        .map(|slot| TrackTerm::of_slot(slot).name())
        .collect()
});

/// Names of the positioner's terms, in slot order.
static POSITIONER_TERM_NAMES: std::sync::LazyLock<Vec<String>> = std::sync::LazyLock::new(|| {
    (0..POSITIONER_TERM_COUNT)
        .map(|slot| PositionerTerm::of_slot(slot).name())
        .collect()
});

/// Tool-translation parameter names by axis.
pub const TOOL_TRANSLATION_NAMES: [&str; 3] = ["x_t", "y_t", "z_t"];

impl ParamId {
    /// The spec's 42 in its order.
    pub fn all() -> impl Iterator<Item = ParamId> {
        (0..BASE_PARAM_COUNT as u8).map(ParamId)
    }

    /// The 42 of an arm with `joints` joints (6 or 7): a seventh joint adds
    /// `dtheta7, dalpha7, da7, dd7, k7` after them.
    pub fn of_arm(joints: usize) -> impl Iterator<Item = ParamId> {
        let seventh = if joints > 6 { SEVENTH_JOINT_COUNT } else { 0 };
        ParamId::all()
            .chain((SEVENTH_JOINT_START..SEVENTH_JOINT_START + seventh).map(|i| ParamId(i as u8)))
    }

    /// The arm's parameters ([`Self::of_arm`]), then the terms of the robot
    /// file's track (to its polynomial order) and of its positioner when it
    /// has them: every parameter of the cell's geometry and compliance, for
    /// rank analyses and designs.
    pub fn of_robot(spec: &RobotSpec) -> impl Iterator<Item = ParamId> + use<> {
        let order = spec.track.map_or(0, |t| t.polynomial_order);
        let axes = spec.positioner.as_ref().map(|p| p.axes.len());
        ParamId::of_arm(spec.joints.len())
            .chain(ParamId::track_terms(order))
            .chain(axes.into_iter().flat_map(ParamId::positioner_terms))
    }

    /// The positioner's base and the errors of its first `axes` axes, in
    /// slot order.
    pub fn positioner_terms(axes: usize) -> impl Iterator<Item = ParamId> {
        (0..POSITIONER_TERM_COUNT)
            .filter(move |slot| {
                PositionerTerm::of_slot(*slot)
                    .axis()
                    .is_none_or(|k| k < axes)
            })
            .map(|slot| ParamId((POSITIONER_START + slot) as u8))
    }

    /// The parameter of one positioner term.
    pub fn positioner(term: PositionerTerm) -> ParamId {
        ParamId((POSITIONER_START + term.slot()) as u8)
    }

    /// The 42 and the translations of targets 1..`targets`, then a seventh
    /// joint's parameters when the arm has `joints` = 7.
    pub fn all_with_targets(joints: usize, targets: usize) -> impl Iterator<Item = ParamId> {
        let extra = 3 * targets.clamp(1, MAX_TARGETS).saturating_sub(1);
        (0..(BASE_PARAM_COUNT + extra) as u8)
            .map(ParamId)
            .chain(ParamId::of_arm(joints).skip(BASE_PARAM_COUNT))
    }

    /// The parameter of `kind` (theta, alpha, a, d or compliance) of `joint`
    /// (0-based): slots 12.. of the 42 for joints 1–6, a seventh joint's
    /// after every other slot.
    pub fn of_joint(kind: JointParam, joint: usize) -> ParamId {
        assert!(joint < MAX_JOINTS, "joint {joint}");
        let k = kind as usize;
        if joint < 6 {
            ParamId((12 + 6 * k + joint) as u8)
        } else {
            ParamId((SEVENTH_JOINT_START + k) as u8)
        }
    }

    /// The backlash of each of the first `joints` joints, in joint order.
    pub fn backlashes(joints: usize) -> impl Iterator<Item = ParamId> {
        (0..joints.min(MAX_JOINTS)).map(|joint| ParamId((TARGETED_PARAM_COUNT + joint) as u8))
    }

    /// The sine and cosine coefficients of each of the first `joints` joints
    /// at `orders` (each in 1..=[`MAX_HARMONIC_ORDER`]; others are skipped).
    pub fn harmonics(joints: usize, orders: &[usize]) -> impl Iterator<Item = ParamId> + '_ {
        (0..joints.min(MAX_JOINTS)).flat_map(move |joint| {
            orders
                .iter()
                .filter(|o| (1..=MAX_HARMONIC_ORDER).contains(*o))
                .flat_map(move |order| {
                    [false, true].map(|cosine| ParamId::harmonic(joint, *order, cosine))
                })
        })
    }

    /// The coefficient of `sin(order·q_joint)` (or `cos`).
    pub fn harmonic(joint: usize, order: usize, cosine: bool) -> ParamId {
        assert!(
            joint < MAX_JOINTS && (1..=MAX_HARMONIC_ORDER).contains(&order),
            "joint {joint} order {order}"
        );
        let slot = MAX_JOINTS + 2 * (joint * MAX_HARMONIC_ORDER + order - 1) + usize::from(cosine);
        ParamId((TARGETED_PARAM_COUNT + slot) as u8)
    }

    /// Every joint-error term, in slot order.
    pub fn joint_terms() -> impl Iterator<Item = ParamId> {
        (TARGETED_PARAM_COUNT..TRACK_START).map(|i| ParamId(i as u8))
    }

    /// The track's error terms up to polynomial order `order`, in slot order.
    pub fn track_terms(order: usize) -> impl Iterator<Item = ParamId> {
        (0..TRACK_TERM_COUNT)
            .filter(move |slot| TrackTerm::of_slot(*slot).order() <= order)
            .map(|slot| ParamId((TRACK_START + slot) as u8))
    }

    /// The parameter of one track term.
    pub fn track(term: TrackTerm) -> ParamId {
        ParamId((TRACK_START + term.slot()) as u8)
    }

    /// The translation of `target` (0-based) along `axis`.
    pub fn target_translation(target: usize, axis: usize) -> ParamId {
        assert!(
            target < MAX_TARGETS && axis < 3,
            "target {target} axis {axis}"
        );
        if target == 0 {
            ParamId((6 + axis) as u8)
        } else {
            ParamId((BASE_PARAM_COUNT + 3 * (target - 1) + axis) as u8)
        }
    }

    pub fn index(self) -> usize {
        self.0 as usize
    }

    pub fn from_index(index: usize) -> Option<ParamId> {
        (index < PARAM_COUNT).then_some(ParamId(index as u8))
    }

    /// One of the 42 or a joint-error term by its name (a further target's
    /// translation is named by the table layer).
    pub fn from_name(name: &str) -> Option<ParamId> {
        NAMES
            .iter()
            .position(|n| *n == name)
            .map(|i| ParamId(i as u8))
            .or_else(|| {
                SEVENTH_JOINT_NAMES
                    .iter()
                    .position(|n| *n == name)
                    .map(|slot| ParamId((SEVENTH_JOINT_START + slot) as u8))
            })
            .or_else(|| {
                JOINT_TERM_NAMES
                    .iter()
                    .position(|n| n == name)
                    .map(|slot| ParamId((TARGETED_PARAM_COUNT + slot) as u8))
            })
            .or_else(|| {
                TRACK_TERM_NAMES
                    .iter()
                    .position(|n| n == name)
                    .map(|slot| ParamId((TRACK_START + slot) as u8))
            })
            .or_else(|| {
                POSITIONER_TERM_NAMES
                    .iter()
                    .position(|n| n == name)
                    .map(|slot| ParamId((POSITIONER_START + slot) as u8))
            })
    }

    /// Every name [`Self::from_name`] knows, for suggestions.
    pub fn known_names() -> impl Iterator<Item = &'static str> {
        NAMES
            .iter()
            .copied()
            .chain(JOINT_TERM_NAMES.iter().map(String::as_str))
            .chain(TRACK_TERM_NAMES.iter().map(String::as_str))
            .chain(POSITIONER_TERM_NAMES.iter().map(String::as_str))
            .chain(SEVENTH_JOINT_NAMES)
    }

    /// The spec's name; a further target's translation is `x_t[#k]` until a table
    /// names it by its target id.
    pub fn name(self) -> &'static str {
        let i = self.index();
        match NAMES.get(i) {
            Some(name) => name,
            None if i < TARGETED_PARAM_COUNT => &TARGET_NAMES[i - BASE_PARAM_COUNT],
            None if i < TRACK_START => &JOINT_TERM_NAMES[i - TARGETED_PARAM_COUNT],
            None if i < POSITIONER_START => &TRACK_TERM_NAMES[i - TRACK_START],
            None if i < SEVENTH_JOINT_START => &POSITIONER_TERM_NAMES[i - POSITIONER_START],
            None => SEVENTH_JOINT_NAMES[i - SEVENTH_JOINT_START],
        }
    }

    // Inlined: the Jacobian asks for it several times per column and row
    // (`#[inline]` alone left it a call, 2.8 % of a pass, issue #31).
    #[inline(always)]
    pub fn kind(self) -> ParamKind {
        let i = self.index();
        match i {
            0..=2 => ParamKind::WorldTranslation(i),
            3..=5 => ParamKind::WorldRotation(i - 3),
            6..=8 => ParamKind::ToolTranslation {
                target: 0,
                axis: i - 6,
            },
            9..=11 => ParamKind::ToolRotation(i - 9),
            12..=17 => ParamKind::Theta(i - 12),
            18..=23 => ParamKind::Alpha(i - 18),
            24..=29 => ParamKind::A(i - 24),
            30..=35 => ParamKind::D(i - 30),
            36..=41 => ParamKind::Compliance(i - 36),
            _ if i >= SEVENTH_JOINT_START => match i - SEVENTH_JOINT_START {
                0 => ParamKind::Theta(6),
                1 => ParamKind::Alpha(6),
                2 => ParamKind::A(6),
                3 => ParamKind::D(6),
                _ => ParamKind::Compliance(6),
            },
            _ if i >= POSITIONER_START => {
                ParamKind::Positioner(PositionerTerm::of_slot(i - POSITIONER_START))
            }
            _ if i >= TRACK_START => ParamKind::Track(TrackTerm::of_slot(i - TRACK_START)),
            _ if i >= TARGETED_PARAM_COUNT + MAX_JOINTS => {
                let slot = i - TARGETED_PARAM_COUNT - MAX_JOINTS;
                ParamKind::Harmonic {
                    joint: slot / (2 * MAX_HARMONIC_ORDER),
                    order: 1 + (slot % (2 * MAX_HARMONIC_ORDER)) / 2,
                    cosine: slot % 2 == 1,
                }
            }
            _ if i >= TARGETED_PARAM_COUNT => ParamKind::Backlash(i - TARGETED_PARAM_COUNT),
            _ => ParamKind::ToolTranslation {
                target: 1 + (i - BASE_PARAM_COUNT) / 3,
                axis: (i - BASE_PARAM_COUNT) % 3,
            },
        }
    }

    /// The joint (0-based) an MDH error, compliance or joint-error term
    /// belongs to; `None` for frames, tracks and positioners.
    #[inline(always)]
    pub fn joint(self) -> Option<usize> {
        match self.kind() {
            ParamKind::Theta(i)
            | ParamKind::Alpha(i)
            | ParamKind::A(i)
            | ParamKind::D(i)
            | ParamKind::Compliance(i)
            | ParamKind::Backlash(i)
            | ParamKind::Harmonic { joint: i, .. } => Some(i),
            _ => None,
        }
    }

    /// The unit string of the parameters table on an arm whose joints
    /// `prismatic` marks: a prismatic joint's compliance is mm/N and its
    /// backlash mm; every other unit is [`Self::unit`]'s.
    pub fn unit_on(self, prismatic: &[bool; crate::robot::MAX_JOINTS]) -> &'static str {
        match self.kind() {
            ParamKind::Compliance(i) if prismatic[i] => "mm/N",
            ParamKind::Backlash(i) if prismatic[i] => "mm",
            _ => self.unit(),
        }
    }

    /// The unit string of the parameters table (an arm of revolute joints).
    pub fn unit(self) -> &'static str {
        match self.kind() {
            ParamKind::WorldTranslation(_)
            | ParamKind::ToolTranslation { .. }
            | ParamKind::A(_)
            | ParamKind::D(_) => "mm",
            ParamKind::WorldRotation(_)
            | ParamKind::ToolRotation(_)
            | ParamKind::Theta(_)
            | ParamKind::Alpha(_)
            | ParamKind::Backlash(_)
            | ParamKind::Harmonic { .. } => "deg",
            ParamKind::Compliance(_) => "deg/(N·m)",
            ParamKind::Track(term) => term.unit(),
            ParamKind::Positioner(term) => term.unit(),
        }
    }

    /// A term of the positioner (its base or an axis's error).
    pub fn is_positioner_term(self) -> bool {
        matches!(self.kind(), ParamKind::Positioner(_))
    }

    /// A coefficient of the track's errors.
    pub fn is_track_term(self) -> bool {
        matches!(self.kind(), ParamKind::Track(_))
    }

    pub fn is_compliance(self) -> bool {
        matches!(self.kind(), ParamKind::Compliance(_))
    }

    /// A backlash or transmission-error harmonic (issue #29): an angle added to
    /// the joint's reading like a compliance deflection.
    pub fn is_joint_term(self) -> bool {
        matches!(
            self.kind(),
            ParamKind::Backlash(_) | ParamKind::Harmonic { .. }
        )
    }

    pub fn is_tool_rotation(self) -> bool {
        matches!(self.kind(), ParamKind::ToolRotation(_))
    }

    pub fn is_tool_translation(self) -> bool {
        matches!(self.kind(), ParamKind::ToolTranslation { .. })
    }

    pub fn is_world(self) -> bool {
        matches!(
            self.kind(),
            ParamKind::WorldTranslation(_) | ParamKind::WorldRotation(_)
        )
    }
}

impl fmt::Display for ParamId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A value for each parameter slot (unused target slots hold the nominal tool).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParamValues(pub [f64; PARAM_COUNT]);

impl ParamValues {
    /// The robot file's nominal values: its world and tool transforms, zero errors,
    /// zero compliance.
    pub fn nominal(robot: &RobotSpec) -> Self {
        let mut values = [0.0; PARAM_COUNT];
        let put = |values: &mut [f64; PARAM_COUNT], start: usize, t: &TransformSpec| {
            values[start..start + 6].copy_from_slice(&[
                t.x_mm,
                t.y_mm,
                t.z_mm,
                t.alpha_deg,
                t.beta_deg,
                t.gamma_deg,
            ]);
        };
        put(&mut values, 0, &robot.world);
        put(&mut values, 6, &robot.tool);
        for target in 1..MAX_TARGETS {
            for axis in 0..3 {
                values[ParamId::target_translation(target, axis).index()] = values[6 + axis];
            }
        }
        if let Some(positioner) = &robot.positioner {
            for slot in 0..POSITIONER_TERM_COUNT {
                let term = PositionerTerm::of_slot(slot);
                values[ParamId::positioner(term).index()] = term.nominal(positioner);
            }
        }
        ParamValues(values)
    }

    pub fn get(&self, id: ParamId) -> f64 {
        self.0[id.index()]
    }

    pub fn set(&mut self, id: ParamId, value: f64) {
        self.0[id.index()] = value;
    }

    /// These values with `target`'s tool translation in target 0's slots
    /// (`x_t, y_t, z_t`), so that everything that evaluates target 0 (inverse
    /// kinematics, [`crate::robot::Robot::tool_in_world`], the chains) evaluates
    /// that target's tool. The targets share the tool rotation (spec §7), so
    /// the translation is all that differs. Target 0 gives the values unchanged.
    pub fn aimed_at(&self, target: usize) -> ParamValues {
        let mut values = *self;
        for axis in 0..3 {
            values.0[ParamId::target_translation(0, axis).index()] =
                self.0[ParamId::target_translation(target, axis).index()];
        }
        values
    }

    /// Nominal values with some replaced by a TOML file of `name = value` lines
    /// (e.g. a simulator's truth); `path` is only used in error messages.
    pub fn with_overrides(
        robot: &RobotSpec,
        text: &str,
        path: &Path,
    ) -> Result<Self, ParamFileError> {
        let error = |message: String| ParamFileError {
            path: path.to_path_buf(),
            message,
        };
        let table: toml::Table =
            toml::from_str(text).map_err(|e| error(crate::toml_error::describe(&e, text)))?;
        let mut values = Self::nominal(robot);
        for (name, value) in &table {
            let id = ParamId::from_name(name).ok_or_else(|| {
                error(format!(
                    "unknown parameter `{name}`{}",
                    crate::suggest::did_you_mean(name, NAMES)
                ))
            })?;
            let number = match value {
                toml::Value::Float(f) => *f,
                toml::Value::Integer(i) => *i as f64,
                other => {
                    return Err(error(format!(
                        "parameter `{name}`: expected a number, found {}",
                        other.type_str()
                    )));
                }
            };
            if !number.is_finite() {
                return Err(error(format!(
                    "parameter `{name}`: expected a finite number"
                )));
            }
            values.set(id, number);
        }
        Ok(values)
    }

    pub fn load_overrides(robot: &RobotSpec, path: &Path) -> Result<Self, ParamFileError> {
        let text = std::fs::read_to_string(path).map_err(|e| ParamFileError {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        Self::with_overrides(robot, &text, path)
    }
}

/// A parameter-value file that could not be used.
#[derive(Debug, thiserror::Error)]
#[error("parameter file {path}: {message}")]
pub struct ParamFileError {
    pub path: PathBuf,
    pub message: String,
}

/// The parameters left free in an identification, in the spec's order.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Selection(Vec<ParamId>);

impl Selection {
    pub fn new(mut ids: Vec<ParamId>) -> Self {
        ids.sort();
        ids.dedup();
        Selection(ids)
    }

    /// The 32 parameters the spec lists as identifiable from positions (§4).
    pub fn spec_identifiable() -> Self {
        let dependent = [
            "dtheta1", "dtheta6", "dalpha1", "da1", "dd1", "dd3", "dd6", "alpha_t", "beta_t",
            "gamma_t",
        ];
        Selection(
            ParamId::all()
                .filter(|id| !dependent.contains(&id.name()))
                .collect(),
        )
    }

    pub fn ids(&self) -> &[ParamId] {
        &self.0
    }

    pub fn len(&self) -> usize {
        self.0.len()
    }

    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_are_unique() {
        for id in ParamId::all() {
            assert_eq!(ParamId::from_name(id.name()), Some(id));
        }
        let mut names: Vec<_> = NAMES.to_vec();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), BASE_PARAM_COUNT);
    }

    #[test]
    fn spec_selection_has_32_parameters_with_all_compliances() {
        let selection = Selection::spec_identifiable();
        assert_eq!(selection.len(), 32);
        assert_eq!(
            selection.ids().iter().filter(|p| p.is_compliance()).count(),
            6
        );
    }

    #[test]
    fn target_translations_have_slots_of_their_own() {
        assert_eq!(ParamId::target_translation(0, 2).name(), "z_t");
        let id = ParamId::target_translation(3, 1);
        assert_eq!(id.kind(), ParamKind::ToolTranslation { target: 3, axis: 1 });
        assert_eq!(id.name(), "y_t[#3]");
        assert_eq!(id.unit(), "mm");
        assert_eq!(ParamId::from_index(id.index()), Some(id));
        assert_eq!(ParamId::all_with_targets(6, 1).count(), 42);
        assert_eq!(ParamId::all_with_targets(6, 3).count(), 48);
        assert_eq!(
            ParamId::target_translation(MAX_TARGETS - 1, 2).index(),
            TARGETED_PARAM_COUNT - 1
        );
    }

    #[test]
    fn joint_terms_have_slots_names_and_kinds_of_their_own() {
        let terms: Vec<ParamId> = ParamId::joint_terms().collect();
        assert_eq!(
            terms.len(),
            MAX_JOINTS + 2 * MAX_JOINTS * MAX_HARMONIC_ORDER
        );
        assert_eq!(terms.last().unwrap().index(), TRACK_START - 1);
        // The track's terms follow, then the positioner's, then a seventh joint's.
        let track: Vec<ParamId> = ParamId::track_terms(3).collect();
        assert_eq!(track.len(), TRACK_TERM_COUNT);
        assert_eq!(track.last().unwrap().index(), POSITIONER_START - 1);
        let positioner: Vec<ParamId> = ParamId::positioner_terms(2).collect();
        assert_eq!(positioner.len(), POSITIONER_TERM_COUNT);
        assert_eq!(positioner.last().unwrap().index(), SEVENTH_JOINT_START - 1);
        assert_eq!(ParamId::of_arm(7).last().unwrap().index(), PARAM_COUNT - 1);
        assert_eq!(ParamId::positioner_terms(1).count(), 10);
        assert!(positioner.iter().all(|p| p.is_positioner_term()));
        assert_eq!(ParamId::from_name("dalpha_p2"), Some(positioner[11]));
        assert_eq!(positioner[2].name(), "z_p");
        assert_eq!(positioner[12].unit(), "mm");
        assert_eq!(ParamId::track_terms(1).count(), 6);
        assert!(
            track
                .iter()
                .all(|t| t.is_track_term() && !t.is_joint_term())
        );
        assert_eq!(
            ParamId::from_name("track_pitch2").map(|t| t.unit()),
            Some("deg")
        );
        assert_eq!(ParamId::from_name("track_z3").map(|t| t.unit()), Some("mm"));
        let mut names: Vec<&str> = terms.iter().map(|t| t.name()).collect();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), terms.len());
        for id in &terms {
            assert!(id.is_joint_term() && !id.is_compliance());
            assert_eq!(ParamId::from_name(id.name()), Some(*id));
            assert_eq!(id.unit(), "deg");
        }
        assert_eq!(ParamId::backlashes(6).nth(2).unwrap().name(), "backlash3");
        let h = ParamId::harmonic(3, 2, true);
        assert_eq!(h.name(), "cos2q4");
        assert_eq!(
            h.kind(),
            ParamKind::Harmonic {
                joint: 3,
                order: 2,
                cosine: true
            }
        );
        assert_eq!(ParamId::harmonics(6, &[1, 2]).count(), 24);
        assert_eq!(ParamId::harmonics(6, &[9]).count(), 0);
        // The 42 and the targets keep their slots.
        assert_eq!(ParamId::target_translation(7, 2).index(), 62);
    }

    #[test]
    fn units_follow_the_spec() {
        assert_eq!(ParamId::from_name("x_w").unwrap().unit(), "mm");
        assert_eq!(ParamId::from_name("gamma_t").unwrap().unit(), "deg");
        assert_eq!(ParamId::from_name("dd6").unwrap().unit(), "mm");
        assert_eq!(ParamId::from_name("k3").unwrap().unit(), "deg/(N·m)");
    }
}
