//! The CDPR spec: where the eight cables are anchored on the frame and attached on
//! the platform, and the tension limits. Parsing is strict like the robot file
//! ([`crate::robot::file`]): unknown keys are errors and every error names the key.

use std::path::Path;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::CdprError;

/// Number of cables of the CDPR (fixed: the module's capacity-margin and tests assume
/// a redundantly constrained 6-DOF robot with eight cables).
pub const CABLE_COUNT: usize = 8;

/// Geometry and tension limits of the eight-cable CDPR. Cable `i` runs from
/// `anchors_base_mm[i]` to `attachments_tool_mm[i]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CableRobotSpec {
    /// Cable exit points on the fixed frame, in the robot BASE frame, millimetres.
    /// Exactly eight.
    pub anchors_base_mm: Vec<[f64; 3]>,
    /// Cable attachment points on the platform (a cube rigidly fixed to the tool), in
    /// the TOOL frame (origin = SMR centre), millimetres. Exactly eight.
    pub attachments_tool_mm: Vec<[f64; 3]>,
    /// Lowest admissible cable tension (keeps cables taut), newtons, `>= 0`.
    pub min_tension_n: f64,
    /// Highest admissible cable tension, newtons, `> min_tension_n`.
    pub max_tension_n: f64,
    /// Characteristic length putting moments on the scale of forces for the capacity
    /// margin: moments are divided by `moment_scale_mm / 1000` (m), so a margin of
    /// 1 N means 1 N of force or `moment_scale_mm / 1000` N·m of moment. `> 0`.
    pub moment_scale_mm: f64,
}

/// Half-extents of the default geometry (see [`CableRobotSpec::default`]).
const FRAME_X_MM: [f64; 2] = [0.0, 1800.0];
const FRAME_Y_MM: f64 = 900.0;
const FRAME_Z_MM: [f64; 2] = [100.0, 1700.0];
const PLATFORM_HALF_MM: f64 = 100.0;
const PLATFORM_CENTRE_Z_MM: f64 = -120.0;

impl Default for CableRobotSpec {
    /// A representative geometry for the paper's setup (measurement workspace: a
    /// 500 mm cube centred at (900, 0, 900) mm in the base frame, robot base at the
    /// origin reaching in from −x):
    ///
    /// * frame anchors at the corners of a box x ∈ [0, 1800], y ∈ [−900, 900],
    ///   z ∈ [100, 1700] mm around the workspace centre; the −x face is open between
    ///   its corner posts (900 mm either side of the arm's plane y = 0);
    /// * platform: a 200 mm cube centred 120 mm along the tool's −z axis, so the SMR
    ///   (tool origin) sits 20 mm above the middle of its +z face;
    /// * crossed pairing: bottom anchors go to top platform corners and top anchors to
    ///   bottom corners, four of them also crossed in x. The pairing is the best of
    ///   all 8! pairings by the worst-case scale of the ±120 N / ±10 N·m wrench box
    ///   that fits in the available wrench set, over the workspace corners, its centre
    ///   and a tilted tool (it fits scaled by ≥ 1.17 at those poses, by 2.5 at the
    ///   centre; a unit test checks the unscaled box), subject to the −x cables
    ///   staying on their own side of y = 0;
    /// * tensions in [10, 600] N, moment scale 100 mm.
    fn default() -> Self {
        let [x0, x1] = FRAME_X_MM;
        let y = FRAME_Y_MM;
        let [z0, z1] = FRAME_Z_MM;
        let h = PLATFORM_HALF_MM;
        let top = PLATFORM_CENTRE_Z_MM + h;
        let bottom = PLATFORM_CENTRE_Z_MM - h;
        CableRobotSpec {
            anchors_base_mm: vec![
                [x0, -y, z0],
                [x1, -y, z0],
                [x1, y, z0],
                [x0, y, z0],
                [x0, -y, z1],
                [x1, -y, z1],
                [x1, y, z1],
                [x0, y, z1],
            ],
            attachments_tool_mm: vec![
                [h, -h, top],
                [-h, -h, top],
                [h, h, top],
                [-h, h, top],
                [-h, -h, bottom],
                [h, -h, bottom],
                [-h, h, bottom],
                [h, h, bottom],
            ],
            min_tension_n: 10.0,
            max_tension_n: 600.0,
            moment_scale_mm: 100.0,
        }
    }
}

impl CableRobotSpec {
    /// Reads and validates a CDPR file.
    pub fn load(path: &Path) -> Result<Self, CdprError> {
        let text = std::fs::read_to_string(path).map_err(|source| CdprError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(&text, path)
    }

    /// Parses and validates CDPR-file text; `path` is only used in error messages.
    pub fn parse(text: &str, path: &Path) -> Result<Self, CdprError> {
        use crate::toml_error::StrictError;
        let spec: CableRobotSpec =
            crate::toml_error::from_str_strict(text).map_err(|e| match e {
                StrictError::Syntax(message) => CdprError::Parse {
                    path: path.to_path_buf(),
                    message,
                },
                StrictError::Invalid { key, message } => CdprError::InvalidFile {
                    path: path.to_path_buf(),
                    key,
                    message,
                },
            })?;
        spec.validate().map_err(|e| match e {
            CdprError::InvalidSpec { key, message } => CdprError::InvalidFile {
                path: path.to_path_buf(),
                key,
                message,
            },
            other => other,
        })?;
        Ok(spec)
    }

    /// Checks counts and ranges: exactly eight anchors and eight attachments, all
    /// coordinates finite, `0 <= min_tension_n < max_tension_n` (finite) and
    /// `moment_scale_mm > 0` (finite). Errors are [`CdprError::InvalidSpec`] naming
    /// the key, e.g. `anchors_base_mm[3]`.
    pub fn validate(&self) -> Result<(), CdprError> {
        let invalid = |key: String, message: String| CdprError::InvalidSpec { key, message };
        for (name, points) in [
            ("anchors_base_mm", &self.anchors_base_mm),
            ("attachments_tool_mm", &self.attachments_tool_mm),
        ] {
            if points.len() != CABLE_COUNT {
                return Err(invalid(
                    name.into(),
                    format!(
                        "expected exactly {CABLE_COUNT} points, found {}",
                        points.len()
                    ),
                ));
            }
            for (i, point) in points.iter().enumerate() {
                if !point.iter().all(|v| v.is_finite()) {
                    return Err(invalid(
                        format!("{name}[{i}]"),
                        format!("expected finite coordinates, found {point:?}"),
                    ));
                }
            }
        }
        let (lo, hi) = (self.min_tension_n, self.max_tension_n);
        if !(lo.is_finite() && lo >= 0.0) {
            return Err(invalid(
                "min_tension_n".into(),
                format!("expected a finite tension >= 0, found {lo}"),
            ));
        }
        if !(hi.is_finite() && hi > lo) {
            return Err(invalid(
                "max_tension_n".into(),
                format!("expected a finite tension > min_tension_n ({lo}), found {hi}"),
            ));
        }
        let scale = self.moment_scale_mm;
        if !(scale.is_finite() && scale > 0.0) {
            return Err(invalid(
                "moment_scale_mm".into(),
                format!("expected a finite length > 0, found {scale}"),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DEFAULT_TOML: &str = include_str!("../../jobs/cdpr/default.toml");

    fn parse(text: &str) -> Result<CableRobotSpec, CdprError> {
        CableRobotSpec::parse(text, Path::new("cdpr.toml"))
    }

    #[test]
    fn shipped_default_file_is_the_default_spec() {
        let spec = parse(DEFAULT_TOML).unwrap();
        assert_eq!(spec, CableRobotSpec::default());
    }

    #[test]
    fn default_spec_is_valid() {
        CableRobotSpec::default().validate().unwrap();
    }

    #[test]
    fn unknown_key_is_named() {
        let text = DEFAULT_TOML.replacen("min_tension_n", "min_tenson_n", 1);
        let err = parse(&text).unwrap_err().to_string();
        assert!(err.contains("min_tenson_n"), "{err}");
    }

    #[test]
    fn wrong_type_is_named_with_key_path() {
        let text = DEFAULT_TOML.replacen("max_tension_n = 600.0", "max_tension_n = \"a lot\"", 1);
        let err = parse(&text).unwrap_err().to_string();
        assert!(err.contains("max_tension_n"), "{err}");
        assert!(err.contains("line"), "{err}");
    }

    #[test]
    fn wrong_counts_and_ranges_are_named() {
        let mut spec = CableRobotSpec::default();
        spec.anchors_base_mm.pop();
        let err = spec.validate().unwrap_err().to_string();
        assert!(
            err.contains("`anchors_base_mm`") && err.contains("found 7"),
            "{err}"
        );

        let mut spec = CableRobotSpec::default();
        spec.attachments_tool_mm[5][1] = f64::NAN;
        let err = spec.validate().unwrap_err().to_string();
        assert!(err.contains("attachments_tool_mm[5]"), "{err}");

        let spec = CableRobotSpec {
            min_tension_n: -1.0,
            ..CableRobotSpec::default()
        };
        let err = spec.validate().unwrap_err().to_string();
        assert!(err.contains("min_tension_n"), "{err}");

        let mut spec = CableRobotSpec::default();
        spec.max_tension_n = spec.min_tension_n;
        let err = spec.validate().unwrap_err().to_string();
        assert!(err.contains("max_tension_n"), "{err}");

        let spec = CableRobotSpec {
            moment_scale_mm: 0.0,
            ..CableRobotSpec::default()
        };
        let err = spec.validate().unwrap_err().to_string();
        assert!(err.contains("moment_scale_mm"), "{err}");
    }

    #[test]
    fn range_error_in_a_file_names_file_and_key() {
        let text = DEFAULT_TOML.replacen("min_tension_n = 10.0", "min_tension_n = 700.0", 1);
        let err = parse(&text).unwrap_err().to_string();
        assert!(
            err.contains("cdpr.toml") && err.contains("max_tension_n"),
            "{err}"
        );
    }
}
