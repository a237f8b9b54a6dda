//! The 42 calibration parameters (`../shared/spec/model.md` §4): names, units, a
//! full value set, and a selection of which are free.
//!
//! Values are stored as the spec's table shows them: world and tool parameters are
//! absolute (x_w = 1326 mm), all others are errors added to the robot file's nominal
//! MDH values, and compliances are in deg/(N·m). The index order is the spec's table
//! order and is the column order of every identification Jacobian.

use std::fmt;
use std::path::{Path, PathBuf};

use super::file::{RobotSpec, TransformSpec};

/// Number of candidate parameters.
pub const PARAM_COUNT: usize = 42;

/// One of the 42 parameters, by its index in the spec's order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct ParamId(u8);

/// What a parameter is, for the Jacobian and for display.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParamKind {
    /// World ← base translation along axis 0, 1, 2 (mm).
    WorldTranslation(usize),
    /// World ← base rotation, eq. (3) order x, y, z (deg).
    WorldRotation(usize),
    /// Flange → tool translation (mm).
    ToolTranslation(usize),
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
}

const NAMES: [&str; PARAM_COUNT] = [
    "x_w", "y_w", "z_w", "alpha_w", "beta_w", "gamma_w", "x_t", "y_t", "z_t", "alpha_t", "beta_t",
    "gamma_t", "dtheta1", "dtheta2", "dtheta3", "dtheta4", "dtheta5", "dtheta6", "dalpha1",
    "dalpha2", "dalpha3", "dalpha4", "dalpha5", "dalpha6", "da1", "da2", "da3", "da4", "da5",
    "da6", "dd1", "dd2", "dd3", "dd4", "dd5", "dd6", "k1", "k2", "k3", "k4", "k5", "k6",
];

impl ParamId {
    /// All 42 in the spec's order.
    pub fn all() -> impl Iterator<Item = ParamId> {
        (0..PARAM_COUNT as u8).map(ParamId)
    }

    pub fn index(self) -> usize {
        self.0 as usize
    }

    pub fn from_index(index: usize) -> Option<ParamId> {
        (index < PARAM_COUNT).then_some(ParamId(index as u8))
    }

    pub fn from_name(name: &str) -> Option<ParamId> {
        NAMES
            .iter()
            .position(|n| *n == name)
            .map(|i| ParamId(i as u8))
    }

    pub fn name(self) -> &'static str {
        NAMES[self.index()]
    }

    pub fn kind(self) -> ParamKind {
        let i = self.index();
        match i {
            0..=2 => ParamKind::WorldTranslation(i),
            3..=5 => ParamKind::WorldRotation(i - 3),
            6..=8 => ParamKind::ToolTranslation(i - 6),
            9..=11 => ParamKind::ToolRotation(i - 9),
            12..=17 => ParamKind::Theta(i - 12),
            18..=23 => ParamKind::Alpha(i - 18),
            24..=29 => ParamKind::A(i - 24),
            30..=35 => ParamKind::D(i - 30),
            _ => ParamKind::Compliance(i - 36),
        }
    }

    /// The unit string of the parameters table.
    pub fn unit(self) -> &'static str {
        match self.kind() {
            ParamKind::WorldTranslation(_)
            | ParamKind::ToolTranslation(_)
            | ParamKind::A(_)
            | ParamKind::D(_) => "mm",
            ParamKind::WorldRotation(_)
            | ParamKind::ToolRotation(_)
            | ParamKind::Theta(_)
            | ParamKind::Alpha(_) => "deg",
            ParamKind::Compliance(_) => "deg/(N·m)",
        }
    }

    pub fn is_compliance(self) -> bool {
        matches!(self.kind(), ParamKind::Compliance(_))
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

/// A value for each of the 42 parameters.
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
        ParamValues(values)
    }

    pub fn get(&self, id: ParamId) -> f64 {
        self.0[id.index()]
    }

    pub fn set(&mut self, id: ParamId, value: f64) {
        self.0[id.index()] = value;
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
        assert_eq!(names.len(), PARAM_COUNT);
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
    fn units_follow_the_spec() {
        assert_eq!(ParamId::from_name("x_w").unwrap().unit(), "mm");
        assert_eq!(ParamId::from_name("gamma_t").unwrap().unit(), "deg");
        assert_eq!(ParamId::from_name("dd6").unwrap().unit(), "mm");
        assert_eq!(ParamId::from_name("k3").unwrap().unit(), "deg/(N·m)");
    }
}
