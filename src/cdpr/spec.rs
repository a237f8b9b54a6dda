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

impl Default for CableRobotSpec {
    /// The geometry of `jobs/cdpr/default.toml`, designed for the paper's campaign
    /// (measurement workspace: a 500 mm cube centred at (900, 0, 900) mm in the base
    /// frame, robot base at the origin reaching in from −x) and the platform
    /// orientation it uses: the SMR axis (tool z) towards the tracker within 40°,
    /// the upright roll (tool x horizontal) within ±30° (`poses` stage):
    ///
    /// * frame anchors at the corners of a 1920 × 1860 mm box yawed 13° about the
    ///   vertical, centred on x = 900, y = 0, at floor level and at z = 1830 mm; the
    ///   yaw keeps the −x corners out of the arm's corridor;
    /// * platform: a 200 mm cube centred 120 mm along the tool's −z axis, so the SMR
    ///   (tool origin) sits 20 mm in front of its +z face;
    /// * pairing: on each level two cables go to front (+z) and two to back (−z)
    ///   corners, alternating, each crossing the platform in x or y. Chosen by a
    ///   local search over boxes and all 8! pairings (`jobs/cdpr/tools/design_frame.py`)
    ///   for the acceptance of the `wrenches` draws with cables clear of the arm and
    ///   the tracker's beam; unit tests check the ±120 N / ±10 N·m box at the
    ///   workspace centre and the acceptance over the campaign's orientations;
    /// * tensions in [10, 1000] N (a common winch rating), moment scale 100 mm.
    fn default() -> Self {
        CableRobotSpec {
            anchors_base_mm: vec![
                [174.0, -1122.0, 0.0],
                [2045.0, -690.0, 0.0],
                [1626.0, 1122.0, 0.0],
                [-245.0, 690.0, 0.0],
                [174.0, -1122.0, 1830.0],
                [2045.0, -690.0, 1830.0],
                [1626.0, 1122.0, 1830.0],
                [-245.0, 690.0, 1830.0],
            ],
            attachments_tool_mm: vec![
                [100.0, 100.0, -220.0],
                [-100.0, -100.0, -20.0],
                [100.0, -100.0, -220.0],
                [-100.0, 100.0, -20.0],
                [100.0, -100.0, -20.0],
                [-100.0, 100.0, -220.0],
                [100.0, 100.0, -20.0],
                [-100.0, -100.0, -220.0],
            ],
            min_tension_n: 10.0,
            max_tension_n: 1000.0,
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
    /// coordinates finite and within [`MAX_COORDINATE_MM`], `0 <= min_tension_n <
    /// max_tension_n <= MAX_TENSION_N` and `0 < moment_scale_mm <=
    /// MAX_COORDINATE_MM`: beyond those a value is a typo, not a cable robot. Errors are [`CdprError::InvalidSpec`] naming
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
                if !point
                    .iter()
                    .all(|v| v.is_finite() && v.abs() <= MAX_COORDINATE_MM)
                {
                    return Err(invalid(
                        format!("{name}[{i}]"),
                        format!(
                            "expected finite coordinates within ±{MAX_COORDINATE_MM} mm, found {point:?}"
                        ),
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
        if !(hi > lo && hi <= MAX_TENSION_N) {
            return Err(invalid(
                "max_tension_n".into(),
                format!(
                    "expected a tension > min_tension_n ({lo}) and at most {MAX_TENSION_N} N, found {hi}"
                ),
            ));
        }
        let scale = self.moment_scale_mm;
        if !(scale > 0.0 && scale <= MAX_COORDINATE_MM) {
            return Err(invalid(
                "moment_scale_mm".into(),
                format!("expected a length > 0 and at most {MAX_COORDINATE_MM} mm, found {scale}"),
            ));
        }
        Ok(())
    }
}

/// Largest coordinate or length of a cable robot that is not a typo (mm; 100 m).
pub const MAX_COORDINATE_MM: f64 = 1.0e5;
/// Largest cable tension that is not a typo (N; about 100 t).
pub const MAX_TENSION_N: f64 = 1.0e6;

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
        let text = DEFAULT_TOML.replacen("max_tension_n = 1000.0", "max_tension_n = \"a lot\"", 1);
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
        let text = DEFAULT_TOML.replacen("min_tension_n = 10.0", "min_tension_n = 1700.0", 1);
        let err = parse(&text).unwrap_err().to_string();
        assert!(
            err.contains("cdpr.toml") && err.contains("max_tension_n"),
            "{err}"
        );
    }
}
