//! Predicted-position uncertainty (issue #16, spec §7): how uncertain a
//! predicted tool position is because the identified parameters are, and
//! whether measured errors agree with it.
//!
//! The identification's covariance Σ (parameters' units, [`super::fit`]) is
//! propagated to each row linearly, `C = J·Σ·Jᵀ` (mm²), with `J` the row's
//! identification Jacobian over the identified parameters
//! ([`crate::robot::PreparedRobot::jacobian_row`], mm per parameter unit). Both
//! are in the same units, so a change of a parameter's unit or of which of two
//! dependent parameters carries a degree of freedom scales `J` and `Σ` inversely
//! and leaves `C` as it is. Measurement noise is not included: `C` is what a
//! better calibration could remove. A measured error is then judged against
//! `C + N`, `N` the fit's residual noise ([`within_ellipsoid`]).
//!
//! Knows nothing of tables: the stages read Σ from the `covariance` table.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use statrs::distribution::{ChiSquared, ContinuousCDF};

use super::stream;
use crate::robot::{ConfWrench, ParamId, ParamValues, Robot};

/// `columns·Σ·columnsᵀ`: the 3 × 3 covariance of a position whose Jacobian
/// columns (one per parameter) are `columns`, for the row-major `m × m` `Σ`.
/// Symmetric by construction (the upper triangle is mirrored).
pub fn propagate(columns: &[Vector3<f64>], covariance: &[f64]) -> Matrix3<f64> {
    let m = columns.len();
    debug_assert_eq!(covariance.len(), m * m, "Σ is m × m");
    // Σ·Jᵀ row by row: for each parameter i, Σ_ij·J_j summed over j.
    let mut out = Matrix3::zeros();
    for (i, column_i) in columns.iter().enumerate() {
        let weighted: Vector3<f64> = columns
            .iter()
            .zip(&covariance[i * m..(i + 1) * m])
            .map(|(column_j, s)| column_j * *s)
            .sum();
        out += column_i * weighted.transpose();
    }
    0.5 * (out + out.transpose())
}

/// `J·Σ·Jᵀ` (mm²) of each row's predicted position under `values`, with `Σ`
/// (row-major `m × m`, parameters' units) over the parameters `free`.
///
/// Cost: one identification-Jacobian row per row ([`crate::robot::jacobian`]),
/// in parallel chunks like [`crate::robot::batch_predict`], plus `O(m²)` per row.
pub fn position_covariances(
    robot: &Robot,
    values: &ParamValues,
    free: &[ParamId],
    covariance: &[f64],
    rows: &[ConfWrench],
) -> Vec<Matrix3<f64>> {
    let prepared = robot.prepare(values);
    rows.par_iter()
        .with_min_len(stream::CHUNK_ROWS)
        .map_init(
            || vec![Vector3::zeros(); free.len()],
            |columns, row| {
                prepared.jacobian_row(row, free, columns);
                propagate(columns, covariance)
            },
        )
        .collect()
}

/// The 95 % quantile of χ² with three degrees of freedom (7.814728): the
/// squared Mahalanobis radius of a 3-D normal's 95 % ellipsoid.
pub fn chi_squared_3_quantile(probability: f64) -> f64 {
    ChiSquared::new(3.0)
        .expect("three degrees of freedom")
        .inverse_cdf(probability)
}

/// Whether `error` lies inside the ellipsoid `eᵀ·covariance⁻¹·e ≤ radius²` (mm,
/// mm²); `None` when `covariance` is not positive definite (no ellipsoid).
pub fn within_ellipsoid(
    error: &Vector3<f64>,
    covariance: &Matrix3<f64>,
    radius_squared: f64,
) -> Option<bool> {
    let cholesky = covariance.cholesky()?;
    let whitened = cholesky.l().solve_lower_triangular(error)?;
    Some(whitened.norm_squared() <= radius_squared)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::test_support::{irb1600, random_q, random_wrench, truth_params};
    use rand::SeedableRng;
    use rand::rngs::StdRng;

    /// A linear model y = A·θ with A and Σ written out: A·Σ·Aᵀ by hand.
    #[test]
    fn a_linear_model_propagates_to_its_closed_form() {
        // A = [[1, 0], [0, 2], [1, 1]] (rows: x, y, z), Σ = [[4, 1], [1, 9]].
        let columns = [Vector3::new(1.0, 0.0, 1.0), Vector3::new(0.0, 2.0, 1.0)];
        let sigma = [4.0, 1.0, 1.0, 9.0];
        // A·Σ = [[4, 1], [2, 18], [5, 10]]; (A·Σ)·Aᵀ:
        let expected = Matrix3::new(4.0, 2.0, 5.0, 2.0, 36.0, 20.0, 5.0, 20.0, 15.0);
        let got = propagate(&columns, &sigma);
        assert!((got - expected).abs().max() < 1e-12, "{got}");
    }

    /// The tool position is affine in the world translation: its columns are the
    /// world frame's axes R, so R·Σ·Rᵀ exactly, whatever the pose.
    #[test]
    fn world_translation_covariance_is_rotated_into_the_world() {
        let robot = irb1600();
        let values = truth_params(&robot);
        let free: Vec<ParamId> = ["x_w", "y_w", "z_w"]
            .iter()
            .map(|n| ParamId::from_name(n).unwrap())
            .collect();
        let sigma_matrix = Matrix3::new(0.04, 0.01, -0.02, 0.01, 0.09, 0.003, -0.02, 0.003, 0.25);
        let sigma: Vec<f64> = (0..9).map(|k| sigma_matrix[(k / 3, k % 3)]).collect();
        let rotation = robot.prepare(&values).world_from_base.rotation;
        let expected = rotation * sigma_matrix * rotation.transpose();
        let mut rng = StdRng::seed_from_u64(3);
        let rows: Vec<ConfWrench> = (0..20)
            .map(|_| ConfWrench::new(random_q(&robot, &mut rng), random_wrench(&mut rng)))
            .collect();
        for c in position_covariances(&robot, &values, &free, &sigma, &rows) {
            assert!((c - expected).abs().max() < 1e-12, "{c} vs {expected}");
        }
    }

    #[test]
    fn the_ellipsoid_test_uses_the_mahalanobis_distance() {
        assert!((chi_squared_3_quantile(0.95) - 7.814_727_903).abs() < 1e-6);
        let c = Matrix3::from_diagonal(&Vector3::new(1.0, 4.0, 9.0));
        // (1/1 + 4/4 + 9/9) = 3 ≤ 7.81; (0 + 0 + 81/9) = 9 > 7.81.
        assert_eq!(
            within_ellipsoid(&Vector3::new(1.0, 2.0, 3.0), &c, 7.81),
            Some(true)
        );
        assert_eq!(
            within_ellipsoid(&Vector3::new(0.0, 0.0, 9.0), &c, 7.81),
            Some(false)
        );
        assert_eq!(
            within_ellipsoid(&Vector3::x(), &Matrix3::zeros(), 7.81),
            None
        );
    }
}
