//! Observability indices of an identification Jacobian J (3n rows for n conf-wrench
//! combinations, m scaled columns) from its singular values σ1 ≥ … ≥ σm. The
//! numbering O1–O5 is Sun & Hollerbach's ("Observability index selection for robot
//! calibration", ICRA 2008), who compare them:
//!
//! * O1, Borm & Menq (IJRR 10(1), 1991): (σ1·…·σm)^(1/m)/√n — paper eq. (26), the
//!   paper's choice; maximising it is D-optimality, max det(JᵀJ).
//! * O2, Driels & Pathre (J. Robotic Systems 7(2), 1990): the inverse condition
//!   number σm/σ1.
//! * O3, Nahvi, Hollerbach & Hayward (ICRA 1994): the smallest singular value σm
//!   (E-optimality).
//! * O4, Nahvi & Hollerbach (ICRA 1996), the noise amplification index σm²/σ1.
//! * O5, Sun & Hollerbach (ICRA 2008): 1/(1/σ1 + … + 1/σm).
//!
//! Only O1 carries the 1/√n of the literature; all are 0 for a rank-deficient J.
//! The values depend on the column scaling (spec §5): callers state it.

use nalgebra::DMatrix;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

/// Which observability index a selection maximises.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, JsonSchema)]
pub enum Criterion {
    /// Borm & Menq: (σ1·…·σm)^(1/m)/√n, the paper's eq. (26).
    #[default]
    O1,
    /// Driels & Pathre: σmin/σmax.
    O2,
    /// Nahvi, Hollerbach & Hayward: σmin.
    O3,
    /// Nahvi & Hollerbach: σmin²/σmax.
    O4,
    /// Sun & Hollerbach: 1/Σ(1/σi).
    O5,
}

impl Criterion {
    pub fn name(self) -> &'static str {
        match self {
            Criterion::O1 => "O1",
            Criterion::O2 => "O2",
            Criterion::O3 => "O3",
            Criterion::O4 => "O4",
            Criterion::O5 => "O5",
        }
    }

    /// The index from the singular values (any order) of the Jacobian of `n`
    /// combinations; 0 when one of them is 0.
    pub fn evaluate(self, singular_values: &[f64], n: usize) -> f64 {
        let smallest = singular_values
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min);
        let largest = singular_values.iter().copied().fold(0.0, f64::max);
        // Also catches an empty list (smallest = ∞ is not finite) and NaN.
        if !(smallest > 0.0 && smallest.is_finite()) {
            return 0.0;
        }
        match self {
            Criterion::O1 => {
                let m = singular_values.len() as f64;
                let mean_ln = singular_values.iter().map(|s| s.ln()).sum::<f64>() / m;
                mean_ln.exp() / (n as f64).sqrt()
            }
            Criterion::O2 => smallest / largest,
            Criterion::O3 => smallest,
            Criterion::O4 => smallest * smallest / largest,
            Criterion::O5 => 1.0 / singular_values.iter().map(|s| 1.0 / s).sum::<f64>(),
        }
    }

    /// The index from the information matrix M = JᵀJ, whose eigenvalues are σ².
    /// Cost: one m×m symmetric eigendecomposition (cheaper than the SVD of J).
    pub fn evaluate_information(self, info: &DMatrix<f64>, n: usize) -> f64 {
        let singular_values: Vec<f64> = info
            .symmetric_eigenvalues()
            .iter()
            .map(|l| l.max(0.0).sqrt())
            .collect();
        self.evaluate(&singular_values, n)
    }
}

/// O1 from ln det(JᵀJ) = Σ ln σi²: exp(ln det / 2m)/√n.
pub fn o1_from_log_det(log_det: f64, m: usize, n: usize) -> f64 {
    (log_det / (2.0 * m as f64)).exp() / (n as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_index_matches_its_definition_on_known_singular_values() {
        let sigma = [4.0, 2.0, 0.5];
        let n = 4;
        let o1 = (4.0f64 * 2.0 * 0.5).powf(1.0 / 3.0) / 2.0;
        assert!((Criterion::O1.evaluate(&sigma, n) - o1).abs() < 1e-15);
        assert_eq!(Criterion::O2.evaluate(&sigma, n), 0.125);
        assert_eq!(Criterion::O3.evaluate(&sigma, n), 0.5);
        assert_eq!(Criterion::O4.evaluate(&sigma, n), 0.0625);
        assert!((Criterion::O5.evaluate(&sigma, n) - 1.0 / 2.75).abs() < 1e-15);
        for c in [Criterion::O1, Criterion::O3, Criterion::O5] {
            assert_eq!(c.evaluate(&[1.0, 0.0], 2), 0.0);
            assert_eq!(c.evaluate(&[], 2), 0.0);
        }
    }
}
