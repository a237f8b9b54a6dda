//! A rigid frame (rotation + origin in millimetres) and the elementary rotations of
//! the MDH and eq. (3)/(4) conventions. Small and `Copy` on purpose: the forward model
//! composes a dozen of these per conf-wrench row in the hot path.

use nalgebra::{Matrix3, Vector3};

/// `parent_from_child`: maps child coordinates (mm) into the parent.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frame {
    pub rotation: Matrix3<f64>,
    pub origin_mm: Vector3<f64>,
}

impl Frame {
    pub fn identity() -> Self {
        Frame {
            rotation: Matrix3::identity(),
            origin_mm: Vector3::zeros(),
        }
    }

    /// `self · child`.
    // `#[inline]` here and below: called from other codegen units, a call
    // returned the frame through memory (7 % of a one-thread `identify`,
    // issue #31).
    #[inline]
    pub fn compose(&self, child: &Frame) -> Frame {
        Frame {
            rotation: self.rotation * child.rotation,
            origin_mm: self.origin_mm + self.rotation * child.origin_mm,
        }
    }

    #[inline]
    pub fn inverse(&self) -> Frame {
        let rt = self.rotation.transpose();
        Frame {
            rotation: rt,
            origin_mm: -(rt * self.origin_mm),
        }
    }

    #[inline]
    pub fn transform_point(&self, point_mm: &Vector3<f64>) -> Vector3<f64> {
        self.origin_mm + self.rotation * point_mm
    }

    /// Column `axis` (0 = x, 1 = y, 2 = z) of the rotation: that axis in the parent.
    #[inline]
    pub fn axis(&self, axis: usize) -> Vector3<f64> {
        self.rotation.column(axis).into_owned()
    }

    /// The paper's eq. (3)/(4): `Rot(x,α)·Rot(y,β)·Rot(z,γ)·Trans(t)`, angles in radians.
    pub fn from_xyz_euler_then_translation(
        angles_rad: [f64; 3],
        translation_mm: Vector3<f64>,
    ) -> Frame {
        let rotation = rot_x(angles_rad[0]) * rot_y(angles_rad[1]) * rot_z(angles_rad[2]);
        Frame {
            rotation,
            origin_mm: rotation * translation_mm,
        }
    }

    /// Rotation angle (rad) between two frames' orientations.
    pub fn angle_to(&self, other: &Frame) -> f64 {
        rotation_vector(&(other.rotation * self.rotation.transpose())).norm()
    }
}

pub fn rot_x(angle_rad: f64) -> Matrix3<f64> {
    let (s, c) = angle_rad.sin_cos();
    Matrix3::new(1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c)
}

pub fn rot_y(angle_rad: f64) -> Matrix3<f64> {
    let (s, c) = angle_rad.sin_cos();
    Matrix3::new(c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c)
}

pub fn rot_z(angle_rad: f64) -> Matrix3<f64> {
    let (s, c) = angle_rad.sin_cos();
    Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
}

/// Axis-angle vector of a rotation matrix (rad). Uses atan2 of the skew and
/// symmetric parts, so it stays accurate for tiny angles (where `acos` of the
/// trace loses everything below ~1e-8 rad) and never returns NaN for a matrix that
/// is orthonormal only to rounding.
pub fn rotation_vector(rotation: &Matrix3<f64>) -> Vector3<f64> {
    let r = rotation;
    // sin(θ)·axis and cos(θ).
    let sin_axis = Vector3::new(
        r[(2, 1)] - r[(1, 2)],
        r[(0, 2)] - r[(2, 0)],
        r[(1, 0)] - r[(0, 1)],
    ) * 0.5;
    let cos = ((r.trace() - 1.0) * 0.5).clamp(-1.0, 1.0);
    let sin = sin_axis.norm();
    let angle = sin.atan2(cos);
    if cos > -0.5 {
        if sin < 1e-300 {
            return Vector3::zeros();
        }
        return sin_axis * (angle / sin);
    }
    // Near π the skew part vanishes: take the axis from the symmetric part
    // (R + Rᵀ)/2 = cos·I + (1 - cos)·a·aᵀ, its largest diagonal entry first.
    let symmetric = (r + r.transpose()) * 0.5 - Matrix3::identity() * cos;
    let k = (0..3)
        .max_by(|&a, &b| symmetric[(a, a)].total_cmp(&symmetric[(b, b)]))
        .unwrap_or(0);
    let mut axis: Vector3<f64> = symmetric.column(k).into_owned();
    axis /= axis.norm();
    if axis.dot(&sin_axis) < 0.0 {
        axis = -axis;
    }
    axis * angle
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn compose_with_inverse_is_identity() {
        let f =
            Frame::from_xyz_euler_then_translation([0.3, -0.2, 1.1], Vector3::new(10.0, -5.0, 2.0));
        let id = f.compose(&f.inverse());
        assert!((id.rotation - Matrix3::identity()).norm() < 1e-14);
        assert!(id.origin_mm.norm() < 1e-12);
    }

    #[test]
    fn rotation_vector_recovers_tiny_medium_and_near_pi_angles() {
        let axis = Vector3::new(1.0, -2.0, 0.5).normalize();
        for angle in [1e-12, 1e-7, 0.7, 2.5, std::f64::consts::PI - 1e-9] {
            let r =
                *nalgebra::Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(axis), angle)
                    .matrix();
            let v = rotation_vector(&r);
            assert!(
                (v - axis * angle).norm() < 1e-12 * angle.max(1.0) + 1e-20,
                "{angle}: {v:?}"
            );
        }
        let v = rotation_vector(&(rot_z(0.7) * rot_x(0.0)));
        assert!((v - Vector3::new(0.0, 0.0, 0.7)).norm() < 1e-14);
    }
}
