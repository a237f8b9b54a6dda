//! `egcal frame`: a world (or tool) frame in both conventions, because the one
//! egcal stores is not the one most people type.
//!
//! egcal's world frame (spec eq. (3), the robot file's `[world]`, the
//! parameters `x_w … gamma_w`) is `Rot(x, α)·Rot(y, β)·Rot(z, γ)·Trans(x_w, y_w,
//! z_w)`: the translation is applied *after* the rotation, in the rotated axes,
//! so `(x_w, y_w, z_w)` is **not** the robot base's origin in tracker
//! coordinates; that origin is `R·(x_w, y_w, z_w)`. Tracker software, robot
//! controllers and most people write a frame as `Trans·Rot`: the origin in the
//! parent's coordinates, then the angles. The angles mean the same in both
//! (world ← base = Rot(x, α)·Rot(y, β)·Rot(z, γ)); only the three lengths
//! differ. The tool frame (`[tool]`, eq. (4)) is the same kind of product.
//!
//! This module only converts and formats; `commands::frame` loads the robot
//! file or parameters table and calls it.

use nalgebra::{Matrix3, Vector3};

use std::path::Path;

use super::CommandError;
use crate::robot::file::MAX_LENGTH_MM;
use crate::robot::frame::{rot_x, rot_y, rot_z};
use crate::robot::{Frame, RobotSpec};
use crate::table::{self, TableError};

const DEG: f64 = std::f64::consts::PI / 180.0;

/// Six numbers of a frame: three lengths (mm) and the XYZ angles (deg).
pub type SixNumbers = [f64; 6];

fn rotation(angles_deg: [f64; 3]) -> Matrix3<f64> {
    rot_x(angles_deg[0] * DEG) * rot_y(angles_deg[1] * DEG) * rot_z(angles_deg[2] * DEG)
}

/// egcal's `Rot·Trans` numbers (`x_w, y_w, z_w, alpha_w, beta_w, gamma_w`) →
/// the child's origin in the parent frame and the same angles (`Trans·Rot`).
pub fn origin_and_angles(rot_trans: SixNumbers) -> SixNumbers {
    let [x, y, z, a, b, c] = rot_trans;
    let origin = rotation([a, b, c]) * Vector3::new(x, y, z);
    [origin.x, origin.y, origin.z, a, b, c]
}

/// The inverse of [`origin_and_angles`]: a child's origin in the parent frame
/// and its XYZ angles → egcal's `Rot·Trans` numbers (what `[world]` or
/// `x_w … gamma_w` take).
pub fn rot_trans_of(origin_and_angles: SixNumbers) -> SixNumbers {
    let [x, y, z, a, b, c] = origin_and_angles;
    let translation = rotation([a, b, c]).transpose() * Vector3::new(x, y, z);
    [translation.x, translation.y, translation.z, a, b, c]
}

/// The frame itself (parent ← child).
fn frame_of(rot_trans: SixNumbers) -> Frame {
    let [x, y, z, a, b, c] = rot_trans;
    Frame::from_xyz_euler_then_translation([a * DEG, b * DEG, c * DEG], Vector3::new(x, y, z))
}

/// Text of one frame in both conventions, `parent ← child` named by
/// `parent` and `child` (e.g. "tracker", "base"), with `names` the six
/// parameter names of egcal's numbers.
pub fn describe(
    title: &str,
    parent: &str,
    child: &str,
    names: [&str; 6],
    rot_trans: SixNumbers,
) -> String {
    let [ox, oy, oz, a, b, c] = origin_and_angles(rot_trans);
    let frame = frame_of(rot_trans);
    let inverse = frame.inverse();
    let r = frame.rotation;
    let [x, y, z, ..] = rot_trans;
    let mut out = format!("{title}\n");
    out.push_str(&format!(
        "  egcal (Rot·Trans, spec eq. (3)/(4)): {} = {x:.4} mm, {} = {y:.4} mm, {} = {z:.4} mm, {} = {a:.6} deg, {} = {b:.6} deg, {} = {c:.6} deg\n",
        names[0], names[1], names[2], names[3], names[4], names[5]
    ));
    out.push_str(&format!(
        "  {child} origin in the {parent} frame (Trans·Rot): x = {ox:.4} mm, y = {oy:.4} mm, z = {oz:.4} mm; {parent} ← {child} = Rot(x, {a:.6}°)·Rot(y, {b:.6}°)·Rot(z, {c:.6}°)\n"
    ));
    out.push_str(&format!(
        "  {child} axes in the {parent} frame (columns of the rotation): x = [{:.6}, {:.6}, {:.6}], y = [{:.6}, {:.6}, {:.6}], z = [{:.6}, {:.6}, {:.6}]\n",
        r[(0, 0)], r[(1, 0)], r[(2, 0)], r[(0, 1)], r[(1, 1)], r[(2, 1)], r[(0, 2)], r[(1, 2)], r[(2, 2)]
    ));
    out.push_str(&format!(
        "  {parent} origin in the {child} frame: x = {:.4} mm, y = {:.4} mm, z = {:.4} mm\n",
        inverse.origin_mm.x, inverse.origin_mm.y, inverse.origin_mm.z
    ));
    out
}

/// Names of the world frame's parameters.
pub const WORLD_NAMES: [&str; 6] = ["x_w", "y_w", "z_w", "alpha_w", "beta_w", "gamma_w"];
/// Names of the tool frame's parameters.
pub const TOOL_NAMES: [&str; 6] = ["x_t", "y_t", "z_t", "alpha_t", "beta_t", "gamma_t"];

/// `egcal frame`: the world and tool frames of a robot file (or of one model
/// of a parameters table) in both conventions ([`frame`]); or, given the base
/// origin in the tracker frame and its angles, the `[world]` numbers.
pub fn frame_command(
    robot_file: Option<&Path>,
    params: Option<&Path>,
    model: &str,
    origin_in_tracker: Option<&[f64]>,
) -> Result<String, CommandError> {
    if let Some(numbers) = origin_in_tracker {
        let numbers: SixNumbers = numbers.try_into().map_err(|_| {
            CommandError::Usage(format!(
                "--origin-in-tracker takes 6 numbers (x_mm y_mm z_mm rx_deg ry_deg rz_deg), found {}",
                numbers.len()
            ))
        })?;
        // The same bounds a robot file's `[world]` is held to: the numbers this
        // prints must load.
        let names = ["x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg"];
        for (k, (name, value)) in names.iter().zip(numbers).enumerate() {
            let (ok, expected) = if k < 3 {
                (
                    value.abs() <= MAX_LENGTH_MM,
                    format!("a finite length within ±{MAX_LENGTH_MM} mm"),
                )
            } else {
                (value.abs() <= 360.0, "a finite angle within ±360°".into())
            };
            if !ok {
                return Err(CommandError::Usage(format!(
                    "--origin-in-tracker: value {} ({name}) is {}, expected {expected}",
                    k + 1,
                    crate::calibration::row_checks::compact(value)
                )));
            }
        }
        let [x, y, z, a, b, c] = rot_trans_of(numbers);
        return Ok(format!(
            "[world] for a base whose origin is at ({}, {}, {}) mm in the tracker frame, rotated Rot(x, {a}°)·Rot(y, {b}°)·Rot(z, {c}°):\n\n[world]\nx_mm = {x:.6}\ny_mm = {y:.6}\nz_mm = {z:.6}\nalpha_deg = {a}\nbeta_deg = {b}\ngamma_deg = {c}\n",
            numbers[0], numbers[1], numbers[2]
        ));
    }
    let robot_file = robot_file
        .ok_or_else(|| CommandError::Usage("give --robot, or --origin-in-tracker".into()))?;
    let spec = RobotSpec::load(robot_file)?;
    let (values, source) = parameter_values(&spec, robot_file, params, model)?;
    let six = |start: usize| -> SixNumbers { std::array::from_fn(|k| values.0[start + k]) };
    Ok(format!(
        "{}\n{}",
        describe(
            &format!("world frame (tracker ← base), {source}:"),
            "tracker",
            "base",
            WORLD_NAMES,
            six(0),
        ),
        describe(
            "tool frame (flange ← tool; with several targets, the first target's translation):",
            "flange",
            "tool",
            TOOL_NAMES,
            six(6),
        )
    ))
}

/// The parameter values of a robot file (nominal), or of one model of a
/// parameters table, and words naming which.
pub(super) fn parameter_values(
    spec: &RobotSpec,
    robot_file: &Path,
    params: Option<&Path>,
    model: &str,
) -> Result<(crate::robot::ParamValues, String), CommandError> {
    match params {
        None => Ok((
            crate::robot::ParamValues::nominal(spec),
            format!("robot file {}", robot_file.display()),
        )),
        Some(path) => {
            let wanted: table::parameters::ModelName =
                model.parse().map_err(CommandError::Usage)?;
            let df = table::read_parquet(path)?;
            let set = table::parameters::from_frame(&df, path, spec)?
                .into_iter()
                .find(|s| s.model == wanted)
                .ok_or_else(|| {
                    CommandError::Table(Box::new(TableError::BadValue {
                        file: path.to_path_buf(),
                        column: "model".into(),
                        row: 0,
                        message: format!("no rows for model `{wanted}`"),
                    }))
                })?;
            Ok((set.values, format!("model {wanted} of {}", path.display())))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A hand-computed case: [world] x_w = 1000, others 0 but gamma_w = 90°.
    /// Rot(z, 90°) maps x to y, so the base origin is at (0, 1000, 0) in the
    /// tracker frame, not at (1000, 0, 0).
    #[test]
    fn a_quarter_turn_moves_the_origin_onto_the_other_axis() {
        let origin = origin_and_angles([1000.0, 0.0, 0.0, 0.0, 0.0, 90.0]);
        assert!((origin[0] - 0.0).abs() < 1e-9, "{origin:?}");
        assert!((origin[1] - 1000.0).abs() < 1e-9, "{origin:?}");
        assert_eq!(origin[5], 90.0);
        let back = rot_trans_of(origin);
        assert!((back[0] - 1000.0).abs() < 1e-9 && back[1].abs() < 1e-9);
    }

    /// Both conventions describe one frame: the point (0, 0, 0) of the child
    /// lands on the printed origin, for arbitrary numbers.
    #[test]
    fn the_printed_origin_is_where_the_frame_puts_the_child_origin() {
        let rot_trans = [1326.0, -412.5, 87.0, 12.0, -35.0, 170.0];
        let origin = origin_and_angles(rot_trans);
        let frame = frame_of(rot_trans);
        let mapped = frame.transform_point(&Vector3::zeros());
        for axis in 0..3 {
            assert!((mapped[axis] - origin[axis]).abs() < 1e-9);
        }
        let back = rot_trans_of(origin);
        for k in 0..6 {
            assert!((back[k] - rot_trans[k]).abs() < 1e-9, "{back:?}");
        }
        let text = describe("world", "tracker", "base", WORLD_NAMES, rot_trans);
        assert!(text.contains("x_w = 1326.0000 mm"), "{text}");
        assert!(
            text.contains(&format!("x = {:.4} mm, y = {:.4} mm", origin[0], origin[1])),
            "{text}"
        );
    }
}
