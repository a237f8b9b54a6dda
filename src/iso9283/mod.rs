//! ISO 9283 pose characteristics (issue #16): the standard's test cube and the
//! statistics of §7.2 (pose accuracy AP and repeatability RP, positions only)
//! and §7.3 (distance accuracy AD and repeatability RD). Pure maths on points in
//! millimetres; no tables. The stages `iso_cube` and `iso9283` read and write
//! the tables around it.
//!
//! Why a module of its own: the standard's definitions (where the points sit,
//! which divisor, what "barycentre" means) are the contract a customer checks a
//! robot against, so they live in one place, tested against hand-computed
//! values, and no stage re-derives them.
//!
//! Positions only: with one SMR the tracker measures no orientation, so the
//! orientation parts of AP and RP (the standard's APa, APb, APc, RPa, RPb,
//! RPc) are not computed.

use nalgebra::{Matrix3, Vector3};

use crate::robot::frame::{rot_x, rot_y, rot_z};

/// The five test points of the standard, in its numbering.
pub const POINTS: [&str; 5] = ["P1", "P2", "P3", "P4", "P5"];

/// The order of one cycle (indices into [`POINTS`]): ISO 9283 §7.2.1 starts
/// at P1 and moves successively to P5, P4, P3, P2, P1, so the cycles repeated
/// back to back approach every point from the same neighbour (unidirectional
/// approach).
pub const CYCLE_ORDER: [usize; 5] = [4, 3, 2, 1, 0];

/// Where P2–P5 sit on the diagonals of the measuring plane: this fraction of
/// the diagonal from their corners (the standard allows (10 ± 2) %).
pub const CORNER_FRACTION: f64 = 0.1;

/// Index of a point name (`P1` … `P5`) in [`POINTS`].
pub fn point_index(name: &str) -> Option<usize> {
    POINTS.iter().position(|p| *p == name)
}

/// The test cube in some parent frame (the robot base or the tracker's world).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cube {
    pub centre_mm: Vector3<f64>,
    pub edge_mm: f64,
    /// parent ← cube.
    pub rotation: Matrix3<f64>,
}

impl Cube {
    /// A cube whose orientation is `Rot(x, α)·Rot(y, β)·Rot(z, γ)` (deg), the
    /// convention of `targets` (spec §7).
    pub fn new(centre_mm: [f64; 3], edge_mm: f64, orientation_deg: [f64; 3]) -> Cube {
        let [a, b, c] = orientation_deg.map(f64::to_radians);
        Cube {
            centre_mm: Vector3::from(centre_mm),
            edge_mm,
            rotation: rot_x(a) * rot_y(b) * rot_z(c),
        }
    }

    /// The corners of the measuring plane in cube coordinates, around the
    /// rectangle: C1 (−,−,−), C2 (+,−,−), C7 (+,+,+), C8 (−,+,+). The plane
    /// holds the cube's bottom edge along x at y = −edge/2 and the top edge
    /// along x at y = +edge/2, so it is a diagonal plane; C1–C7 and C2–C8 are
    /// its diagonals, each as long as the cube's space diagonal (edge·√3).
    fn plane_corners(&self) -> [Vector3<f64>; 4] {
        let h = self.edge_mm / 2.0;
        [
            Vector3::new(-h, -h, -h),
            Vector3::new(h, -h, -h),
            Vector3::new(h, h, h),
            Vector3::new(-h, h, h),
        ]
    }

    /// P1 … P5 in the parent frame: P1 the centre (where the diagonals cross),
    /// P2, P3, P4, P5 on the diagonals at [`CORNER_FRACTION`] of the diagonal
    /// from C1, C2, C7, C8. P2–P4 and P3–P5 lie on the same diagonal, so
    /// |P2P4| = (1 − 2·0.1)·edge·√3.
    pub fn points_mm(&self) -> [Vector3<f64>; 5] {
        let corners = self.plane_corners();
        let mut points = [Vector3::zeros(); 5];
        for (k, corner) in corners.iter().enumerate() {
            // The opposite corner is −corner: the diagonal runs through the centre.
            let towards_centre = corner + (-corner - corner) * CORNER_FRACTION;
            points[k + 1] = towards_centre;
        }
        points.map(|p| self.centre_mm + self.rotation * p)
    }
}

/// Why a statistic cannot be computed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum IsoError {
    #[error("{n} cycle(s); a repeatability needs at least 2 (the n − 1 divisor)")]
    TooFewCycles { n: usize },
    /// A result that is not a finite number (positions beyond what a float
    /// squares without overflow): never written as a statistic.
    #[error("{name} is {value}, not a finite number; the positions are not readings of a robot")]
    NonFinite { name: &'static str, value: f64 },
}

/// `Ok(values)` when every named value is finite, else the first that is not.
fn finite(values: &[(&'static str, f64)]) -> Result<(), IsoError> {
    match values.iter().find(|(_, v)| !v.is_finite()) {
        Some(&(name, value)) => Err(IsoError::NonFinite { name, value }),
        None => Ok(()),
    }
}

/// Pose accuracy and repeatability of one point (ISO 9283 §7.2.1, §7.2.2), positions only.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseCharacteristics {
    /// Cycles measured.
    pub n: usize,
    /// AP_P = |barycentre − commanded|.
    pub ap_mm: f64,
    /// Its components x̄ − x_c, ȳ − y_c, z̄ − z_c (signed).
    pub ap_xyz_mm: Vector3<f64>,
    /// RP_l = l̄ + 3·S_l, l_j the distance of attained position j from the
    /// barycentre, S_l with the n − 1 divisor.
    pub rp_mm: f64,
}

/// AP and RP of one point from its commanded position and the positions
/// attained in n ≥ 2 cycles.
pub fn pose_characteristics(
    commanded_mm: &Vector3<f64>,
    attained_mm: &[Vector3<f64>],
) -> Result<PoseCharacteristics, IsoError> {
    let n = attained_mm.len();
    if n < 2 {
        return Err(IsoError::TooFewCycles { n });
    }
    let barycentre = attained_mm.iter().sum::<Vector3<f64>>() / n as f64;
    let ap_xyz_mm = barycentre - commanded_mm;
    let l: Vec<f64> = attained_mm
        .iter()
        .map(|p| (p - barycentre).norm())
        .collect();
    let (mean, std) = mean_and_sample_std(&l);
    let c = PoseCharacteristics {
        n,
        ap_mm: ap_xyz_mm.norm(),
        ap_xyz_mm,
        rp_mm: mean + 3.0 * std,
    };
    finite(&[
        ("AP", c.ap_mm),
        ("APx", c.ap_xyz_mm.x),
        ("APy", c.ap_xyz_mm.y),
        ("APz", c.ap_xyz_mm.z),
        ("RP", c.rp_mm),
    ])?;
    Ok(c)
}

/// Distance accuracy and repeatability between two points (ISO 9283 §7.3).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DistanceCharacteristics {
    /// Cycles in which both points were measured.
    pub n: usize,
    /// Mean attained distance D̄.
    pub mean_mm: f64,
    /// AD = |D̄ − D_c|.
    pub ad_mm: f64,
    /// RD = 3·S_D, S_D with the n − 1 divisor (the standard writes ±RD).
    pub rd_mm: f64,
}

/// AD and RD from the commanded distance and the distances attained in n ≥ 2 cycles.
pub fn distance_characteristics(
    commanded_mm: f64,
    attained_mm: &[f64],
) -> Result<DistanceCharacteristics, IsoError> {
    let n = attained_mm.len();
    if n < 2 {
        return Err(IsoError::TooFewCycles { n });
    }
    let (mean_mm, std) = mean_and_sample_std(attained_mm);
    let c = DistanceCharacteristics {
        n,
        mean_mm,
        ad_mm: (mean_mm - commanded_mm).abs(),
        rd_mm: 3.0 * std,
    };
    finite(&[
        ("mean distance", c.mean_mm),
        ("AD", c.ad_mm),
        ("RD", c.rd_mm),
    ])?;
    Ok(c)
}

/// Mean and standard deviation with the n − 1 divisor (n ≥ 2).
fn mean_and_sample_std(values: &[f64]) -> (f64, f64) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let sum_sq = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>();
    (mean, (sum_sq / (n - 1.0)).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue #16's hand-computed case (checked with numpy).
    #[test]
    fn pose_characteristics_match_the_hand_values() {
        let attained = [
            Vector3::new(0.10, 0.0, 0.0),
            Vector3::new(0.0, 0.10, 0.02),
            Vector3::new(0.04, 0.0, 0.10),
            Vector3::new(0.06, -0.04, 0.02),
        ];
        let c = pose_characteristics(&Vector3::zeros(), &attained).unwrap();
        assert_eq!(c.n, 4);
        assert!((c.ap_mm - 0.062849).abs() < 5e-7, "{}", c.ap_mm);
        assert!((c.rp_mm - 0.128742).abs() < 5e-7, "{}", c.rp_mm);
        assert!((c.ap_xyz_mm - Vector3::new(0.05, 0.015, 0.035)).norm() < 1e-15);
    }

    #[test]
    fn distance_characteristics_match_the_hand_values() {
        let c = distance_characteristics(400.0, &[400.00, 400.02, 399.99]).unwrap();
        assert!((c.ad_mm - 0.003333).abs() < 5e-7, "{}", c.ad_mm);
        assert!((c.rd_mm - 0.045826).abs() < 5e-7, "{}", c.rd_mm);
    }

    #[test]
    fn a_result_that_overflows_is_an_error_not_a_number() {
        let attained = [Vector3::zeros(), Vector3::new(1e300, 0.0, 0.0)];
        assert!(matches!(
            pose_characteristics(&Vector3::zeros(), &attained),
            Err(IsoError::NonFinite { .. })
        ));
        assert!(matches!(
            distance_characteristics(0.0, &[f64::MAX, f64::MAX]),
            Err(IsoError::NonFinite { .. })
        ));
    }

    #[test]
    fn one_cycle_is_refused() {
        assert_eq!(
            pose_characteristics(&Vector3::zeros(), &[Vector3::zeros()]),
            Err(IsoError::TooFewCycles { n: 1 })
        );
        assert_eq!(
            distance_characteristics(1.0, &[]),
            Err(IsoError::TooFewCycles { n: 0 })
        );
    }

    #[test]
    fn cube_points_lie_on_the_diagonal_plane_at_a_tenth_of_the_diagonal() {
        let cube = Cube::new([900.0, -100.0, 700.0], 500.0, [10.0, -20.0, 30.0]);
        let p = cube.points_mm();
        assert!((p[0] - cube.centre_mm).norm() < 1e-12);
        assert!(((p[1] - p[3]).norm() - 692.820).abs() < 5e-4);
        assert!(((p[2] - p[4]).norm() - 692.820).abs() < 5e-4);
        // Coplanar: P3, P4, P5 are in the plane through P1 spanned by P2 − P1 and P3 − P1.
        let normal = (p[1] - p[0]).cross(&(p[2] - p[0])).normalize();
        for point in &p {
            assert!((point - p[0]).dot(&normal).abs() < 1e-9);
        }
        // 10 % of the diagonal (edge·√3) from the corners.
        let diagonal = 500.0 * 3f64.sqrt();
        let h = 250.0;
        let corners = [
            Vector3::new(-h, -h, -h),
            Vector3::new(h, -h, -h),
            Vector3::new(h, h, h),
            Vector3::new(-h, h, h),
        ];
        for (k, corner) in corners.iter().enumerate() {
            let corner = cube.centre_mm + cube.rotation * corner;
            assert!(((p[k + 1] - corner).norm() - 0.1 * diagonal).abs() < 1e-9);
        }
        // P2 and P4 on one diagonal, P1 between them.
        assert!(((p[1] + p[3]) / 2.0 - p[0]).norm() < 1e-9);
    }

    #[test]
    fn point_names_round_trip() {
        for (k, name) in POINTS.iter().enumerate() {
            assert_eq!(point_index(name), Some(k));
        }
        assert_eq!(point_index("P6"), None);
    }
}
